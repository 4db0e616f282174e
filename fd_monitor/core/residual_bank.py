"""Runtime of a bank of H-infinity residual generators with a sensitivity constraint.

Runs what ``python -m fd_monitor design hinf_sc`` writes (thesis ch. 4-7): one observer-based
residual generator per fault (thesis eq. 4.5-4.7, 5.8-5.10, 6.9-6.14)::

    dxhat/dt = A(rho) xhat + B(rho) u + L(rho) (y - C xhat),     r = H (y - C xhat)

with ``A(rho) = A0 + sum_j rho_j A_j`` and ``L(rho) = L0 + sum_j rho_j L_j`` (LPV, thesis
ch. 6); an LTI generator has no parameters, and the generator of an uncertain plant
(thesis ch. 5) runs on the nominal ``A0`` only. The continuous-time observer is run at the
plant's sample time ``Ts`` with the input held over a sample (zero-order hold):

* ``exact`` discretisation: ``xhat+ = Ad xhat + Bd u + Ld (y - C xhat)`` with
  ``[Ad, Bd, Ld] = zoh(A, [B, L], Ts)``, so the fault-free error of an LTI plant with
  piecewise-constant input obeys ``e+ = (Ad - Ld C) e`` exactly (no false residual from the
  input); used when ``Ad - Ld C`` is Schur;
* ``hold`` discretisation: ``xhat+ = zoh(A - L C, [B, L], Ts)`` applied to ``(u, y)``, stable
  whenever ``A - L C`` is Hurwitz; used otherwise (fast observer poles, ``|eig| Ts > 1``).

The residual of generator ``i`` is evaluated by its Euclidean norm ``||r_i||`` and compared
with its threshold; an alarm of generator ``i`` isolates fault ``i``.

**Two paths, one arithmetic.** :meth:`ResidualBank.step_reference` is the definition: an
LPV bank re-discretises every generator at the sample's ``rho`` (``expm``, the stability
check). :meth:`ResidualBank.step` (the default, ``fast=True``) does no per-sample work that
depends only on the gain file: every generator's one-step map
``[x^+; r] = Phi(rho) [x^; u; y]`` is precomputed, for an LPV bank as the degree-N Taylor
polynomial of the discretisation in ``rho - centre`` (:class:`DiscretisationPolynomial`),
and all generators step in one matrix product. The polynomial's error on the entries of
``Phi`` is bounded a priori (:attr:`DiscretisationPolynomial.bound`, at most
:data:`TABLE_TOL`); a gain file for which that bound is not reached at degree
:data:`MAX_DEGREE`, whose gain is not affine in rho (an affine Lyapunov matrix), or whose
``auto`` choice (exact or hold) is not the same over the whole box, runs the reference
path at every sample. The fast path equals the reference to summation order (LTI and
uncertain banks) and to :data:`TABLE_TOL` times the size of ``[x^; u; y]`` (LPV banks):
``test/test_fast_paths.py`` checks it on every shipped gain file. The model and the
generators are :mod:`fd_monitor.core.hinf_model`; the certificate the loader re-verifies is
:mod:`fd_monitor.core.hinf_certificate`.

Why one module of ~550 lines: the bank and its fast path (the discretisation polynomial,
its a-priori bound) are one runtime, with the reference step kept beside the fast one.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from fd_monitor.core.hinf_model import Generator, bank_results, parse_bank
from fd_monitor.core.plant import zoh
from fd_monitor.model.nonlinear import SCHEDULING_MAPS
from fd_monitor.model.system import System

__all__ = ["DiscretisationPolynomial", "MAX_DEGREE", "ResidualBank", "TABLE_TOL"]

#: Largest a-priori error accepted on an entry of a generator's discretised map
#: ``[Ad - Ld C, Bd, Ld]`` from its polynomial in rho (units of the map: state per state,
#: input or output). With states, inputs and outputs of order 1 this moves a prediction by
#: about 1e-11, a millionth of the smallest threshold of the shipped banks (1.1e-5).
TABLE_TOL = 1e-12

#: Highest total degree of the polynomial in rho tried before falling back to the
#: reference path.
MAX_DEGREE = 8

#: Points per axis of the grid on which the ``auto`` choice (exact or hold) is checked to
#: be the same over the parameter box (and 1e-6 away from the reference's cut).
CHOICE_GRID = 5


def _expm_small(M: np.ndarray) -> np.ndarray:
    """Matrix exponential by scaling and squaring of an order-16 Taylor series.

    For the small matrices of a bank re-discretised at every sample (LPV) this is several
    times faster than ``scipy.linalg.expm`` (no Pade solve, no norm estimates); after
    scaling ``||M / 2^s||_1 <= 1/2``, so the truncation error is below ``0.5^17 / 17!``
    (relative, ~1e-20) before squaring.
    """
    nrm = float(np.abs(M).sum(axis=0).max())
    s = max(0, int(np.ceil(np.log2(nrm / 0.5)))) if nrm > 0.5 else 0
    X = M / (2.0 ** s)
    E = np.eye(M.shape[0])
    T = np.eye(M.shape[0])
    for k in range(1, 17):
        T = T @ X / k
        E = E + T
    for _ in range(s):
        E = E @ E
    return E


def _monomials(d: int, degree: int) -> list[tuple[int, ...]]:
    """Exponents of the monomials in d variables of total degree <= ``degree``, by degree."""
    out: list[tuple[int, ...]] = []
    for deg in range(degree + 1):
        for c in itertools.combinations_with_replacement(range(d), deg):
            e = [0] * d
            for j in c:
                e[j] += 1
            out.append(tuple(e))
    return out


def _monomial_function(exponents: np.ndarray) -> Any:
    """``f(d_1, ..., d_d) -> [prod_j d_j^e_ij for each row i]`` as one compiled expression
    (powers computed once): a Python loop over the monomials costs several times more."""
    d = exponents.shape[1]
    args = [f"d{j}" for j in range(d)]
    top = int(exponents.max()) if exponents.size else 0
    pows = [f"{a}_{k} = {a}_{k - 1} * {a}" if k > 1 else f"{a}_1 = {a}"
            for a in args for k in range(1, top + 1)]
    terms = [" * ".join(f"{args[j]}_{e}" for j, e in enumerate(row) if e) or "1.0"
             for row in exponents.tolist()]
    src = (f"def f({', '.join(args)}):\n" + "".join(f"    {p}\n" for p in pows)
           + f"    return [{', '.join(terms)}]\n")
    scope: dict[str, Any] = {}
    exec(src, scope)        # generated from integers only: no outside text
    return scope["f"]


def _inf_norm(M: np.ndarray) -> float:
    """Induced infinity norm (largest absolute row sum)."""
    return float(np.abs(M).sum(axis=-1).max()) if M.size else 0.0


#: Scalings tried for the bound (see :func:`_scaled_bound`).
_SCALES = (1.0, 0.5, 0.2, 0.1, 0.05, 0.02, 0.01)


def _scaled_bound(Mc: np.ndarray, Mj: np.ndarray, half: np.ndarray, dt: float, degree: int,
                  n: int, scale: float, C: np.ndarray | None) -> float:
    """A-priori bound on the entries of ``[Ad, Bd, Ld]`` (or, with ``C``, of
    ``[Ad - Ld C, Bd, Ld]``) from the degree-N polynomial.

    :class:`DiscretisationPolynomial`'s bound holds for any similar matrix
    ``D^-1 M D``, ``D = diag(I_n, s I)``: it scales the input columns of ``M`` by ``s``
    (smaller norms, a smaller exponential factor) and the error of an input column of the
    exponential by ``1 / s``. The smallest over a few ``s`` is taken.
    """
    D = np.ones(Mc.shape[0])
    D[n:] = scale
    Ms = Mc * D[None, :] / D[:, None]
    Mjs = Mj * D[None, None, :] / D[None, :, None]
    spread = dt * sum(float(h) * _inf_norm(m) for h, m in zip(half, Mjs))
    mu = dt * _inf_norm(Ms) + spread
    b = spread ** (degree + 1) / math.factorial(degree + 1) * math.exp(mu)
    # entry (i, j) of exp(M) - poly is d_i / d_j times that of the scaled one
    b_input = b / scale
    if C is None:
        return max(b, b_input)
    return b + b_input * _inf_norm(C)


class DiscretisationPolynomial:
    """``exp(Ts M(rho))`` of an affine ``M(rho)`` as a polynomial in ``delta = rho - c``.

    ``M(rho) = M_c + sum_j delta_j M_j`` (r, r) with ``c`` the centre of the parameter box
    and ``h`` its half-widths. The coefficients are the exact Taylor coefficients of total
    degree <= N (truncated polynomial arithmetic through scaling and squaring; round-off
    aside). Along the segment ``c -> rho``, ``f(t) = exp(Ts (M_c + t Delta))`` has
    ``||f^(k)(t)|| <= (Ts ||Delta||)^k exp(Ts mu)`` (expand the series and count the k
    factors Delta among each power), so Taylor's remainder gives on the whole box::

        ||exp(Ts M(rho)) - poly(delta)||_inf <= (Ts sum_j h_j ||M_j||)^(N+1) / (N+1)!
                                                 * exp(Ts mu),
        mu = ||M_c|| + sum_j h_j ||M_j||                      (induced inf-norms)

    Parameters
    ----------
    Mc : numpy.ndarray
        (r, r) ``M`` at the centre, 1/s.
    Mj : numpy.ndarray
        (d, r, r) affine parts, 1/s per unit of rho_j.
    half : numpy.ndarray
        (d,) half-widths of the box.
    dt : float
        Ts, s.
    degree : int
        N.

    Attributes
    ----------
    coef : numpy.ndarray
        (n_mono, r, r) coefficients, monomials in :attr:`exponents` order.
    exponents : numpy.ndarray
        (n_mono, d) int.
    bound : float
        The a-priori bound above (entries of the exponential, inf-norm of a row).
    """

    def __init__(self, Mc: np.ndarray, Mj: np.ndarray, half: np.ndarray, dt: float,
                 degree: int) -> None:
        d, r = Mj.shape[0], Mc.shape[0]
        mono = _monomials(d, degree)
        index = {e: i for i, e in enumerate(mono)}
        deg = [sum(e) for e in mono]
        # products: for monomial i, the monomials j it may multiply and where they land
        self._pairs = []
        for i, ei in enumerate(mono):
            js = [j for j, ej in enumerate(mono) if deg[i] + deg[j] <= degree]
            ks = [index[tuple(a + b for a, b in zip(ei, mono[j]))] for j in js]
            self._pairs.append((i, np.array(js), np.array(ks)))
        self.exponents = np.array(mono, dtype=int).reshape(len(mono), d)
        spread = dt * sum(float(h) * _inf_norm(m) for h, m in zip(half, Mj))
        mu = dt * _inf_norm(Mc) + spread
        self.bound = spread ** (degree + 1) / math.factorial(degree + 1) * math.exp(mu)
        s = max(0, math.ceil(math.log2(mu / 0.5))) if mu > 0.5 else 0
        X = np.zeros((len(mono), r, r))
        X[0] = dt * Mc / 2.0 ** s
        for j in range(d):
            X[index[tuple(int(a == j) for a in range(d))]] = dt * Mj[j] / 2.0 ** s
        E = np.zeros_like(X)
        E[0] = np.eye(r)
        term = E.copy()
        for m in range(1, 19):              # ||X|| <= 1/2: 0.5^19 / 19! ~ 1e-23
            term = self._mul(term, X) / m
            E = E + term
        for _ in range(s):
            E = self._mul(E, E)
        self.coef = E

    def _mul(self, P: np.ndarray, Q: np.ndarray) -> np.ndarray:
        """Product of two matrix polynomials, truncated to the degree."""
        out = np.zeros_like(P)
        for i, js, ks in self._pairs:
            out[ks] += P[i] @ Q[js]
        return out


class ResidualBank:
    """Step-based runtime of a bank of residual generators (one per fault).

    Parameters
    ----------
    system : System
        The plant (its sample time is the step of the bank).
    gains : GainFile or mapping
        A loaded ``hinf_sc`` gain file (or its ``results`` mapping).
    thresholds : sequence of float, optional
        Per generator, in output units; default ``results.thresholds`` (or +inf).
    discretisation : str
        ``auto`` (``exact`` when stable, else ``hold``), ``exact`` or ``hold``.
    fast : bool
        True (default): :meth:`step` runs the precomputed maps (module docstring);
        False: :meth:`step` is :meth:`step_reference`.

    Attributes
    ----------
    faults : tuple of str
        The fault of each generator, in order.
    xhat : numpy.ndarray
        (n_gen, n) observer states x^_k (a view: write into it, do not rebind it).
    fast : bool
        The fast path is in use (False also when the gain file does not allow it:
        :attr:`fallback` says why).
    fallback : str
        Why the reference path runs although ``fast`` was asked ("" when it does not).
    table_bound : float
        A-priori bound on any entry of a generator's map ``[Ad - Ld C, Bd, Ld]`` taken from
        the polynomial in rho instead of the exact discretisation (0 for LTI and uncertain
        banks, whose maps are computed once exactly).
    table_degree : int
        Degree of that polynomial (0: none).
    """

    def __init__(self, system: System, gains: Any, thresholds: Sequence[float] | None = None,
                 discretisation: str = "auto", fast: bool = True) -> None:
        results = bank_results(gains)
        self.kind, self.model, self.generators = parse_bank(results)
        self.dt = float(system.sample_time)
        self.faults = tuple(g.fault for g in self.generators)
        n_gen = len(self.generators)
        th = thresholds if thresholds is not None else results.get("thresholds")
        self.thresholds = (np.full(n_gen, np.inf) if th is None
                           else np.asarray(th, dtype=float).reshape(n_gen))
        if discretisation not in ("auto", "exact", "hold"):
            raise ValueError(f"discretisation: expected auto, exact or hold, got "
                             f"{discretisation!r}")
        self._disc_mode = discretisation
        model = self.model
        n, p, nu = model.n, model.C.shape[0], model.B0.shape[1]
        self._n, self._p, self._r = n, p, n + nu + p
        # [x^; u; y] per generator: the state lives in the first n columns
        self._Z = np.zeros((n_gen, self._r))
        self.xhat = self._Z[:, :n]
        self._Z3 = self._Z[:, :, None]
        self._R = np.zeros((n_gen, p))
        self._lti = [self._discretise(g, None) for g in self.generators] \
            if self.kind != "lpv" else []
        self.discretisation = [d[3] for d in self._lti]
        self.table_bound, self.table_degree, self.fallback = 0.0, 0, ""
        self._coef: np.ndarray | None = None
        self._coefT: np.ndarray | None = None
        self._phi: np.ndarray | None = None
        if fast:
            if self.kind == "lpv":
                self._build_table()
            else:
                self._phi = np.stack([self._augmented(*m[:3], g)
                                      for g, m in zip(self.generators, self._lti)])
        self.fast = self._phi is not None or self._coef is not None

    # -- the reference: discretised at every sample ----------------------------------------

    def _discretise(self, g: Generator, rho: np.ndarray | None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
        A = self.model.A0 if g.kind == "uncertain" else self.model.A(rho)
        B = self.model.B(None if g.kind == "uncertain" else rho)
        L = g.L(rho)
        C = self.model.C
        nu = B.shape[1]
        fast = rho is not None  # LPV: re-discretised at every sample
        if self._disc_mode in ("auto", "exact"):
            Ad, G = zoh(A, np.hstack([B, L]), self.dt, _expm_small if fast else None)
            Bd, Ld = G[:, :nu], G[:, nu:]
            if self._disc_mode == "exact" or \
                    np.abs(np.linalg.eigvals(Ad - Ld @ C)).max() < 1.0 - 1e-9:
                return Ad - Ld @ C, Bd, Ld, "exact"
        Ad, G = zoh(A - L @ C, np.hstack([B, L]), self.dt,
                    _expm_small if fast else None)
        return Ad, G[:, :nu], G[:, nu:], "hold"

    # -- the fast path: precomputed maps ---------------------------------------------------

    def _augmented(self, Ad: np.ndarray, Bd: np.ndarray, Ld: np.ndarray,
                   g: Generator) -> np.ndarray:
        """(n + p, r) ``[[Ad, Bd, Ld], [-H C, 0, H]]``: ``[x^+; r] = . [x^; u; y]``."""
        n, p = self._n, self._p
        out = np.zeros((n + p, self._r))
        out[:n] = np.hstack([Ad, Bd, Ld])
        out[n:, :n] = -g.H @ self.model.C
        out[n:, self._r - p:] = g.H
        return out

    def _build_table(self) -> None:
        """The polynomial in rho of every generator's map, or :attr:`fallback` set."""
        model, gens = self.model, self.generators
        if any(g.affine for g in gens):
            self.fallback = "a gain L(rho) not affine in rho (affine Lyapunov matrix)"
            return
        lo, hi = model.rho_min, model.rho_max
        c, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
        found = self._disc_mode if self._disc_mode != "auto" else \
            self._uniform_choice(c, half)
        if found is None:
            self.fallback = ("the exact/hold choice is not the same over the parameter box "
                             "(checked on a grid)")
            return
        choice: str = found
        n, nu, p, r = self._n, model.B0.shape[1], self._p, self._r
        C = model.C
        mats = self._table_mats(c, choice)
        degree, bound = 0, 0.0
        for Mc, Mj in mats:
            for deg in range(1, MAX_DEGREE + 1):
                b = min(_scaled_bound(Mc, Mj, half, self.dt, deg, n, sc, C if
                                      choice == "exact" else None) for sc in _SCALES)
                if b <= TABLE_TOL:
                    degree, bound = max(degree, deg), max(bound, b)
                    break
            else:
                self.fallback = (f"the polynomial in rho does not reach {TABLE_TOL:g} by "
                                 f"degree {MAX_DEGREE}")
                return
        tables = [(DiscretisationPolynomial(Mc, Mj, half, self.dt, degree), g)
                  for (Mc, Mj), g in zip(mats, gens)]
        # a lower degree for one generator: its bound at the common degree is smaller still
        self.table_bound = max(
            min(_scaled_bound(Mc, Mj, half, self.dt, degree, n, sc,
                              C if choice == "exact" else None) for sc in _SCALES)
            for Mc, Mj in mats)
        coef = []
        for t, g in tables:
            E = t.coef[:, :n]                                 # (n_mono, n, r)
            if choice == "exact":
                E = E.copy()
                E[:, :, :n] = E[:, :, :n] - E[:, :, n + nu:] @ C
            aug = np.zeros((E.shape[0], n + p, r))
            aug[:, :n] = E
            aug[0] = aug[0] + self._augmented(np.zeros((n, n)), np.zeros((n, nu)),
                                               np.zeros((n, p)), g)
            coef.append(aug)
        self._exponents = tables[0][0].exponents
        self.table_degree = degree
        self._coef = np.stack(coef, axis=1).reshape(len(self._exponents), -1)
        self._centre = c.tolist()
        # every entry of every map: one product of the coefficients with the monomials
        self._coefT = np.ascontiguousarray(self._coef.T)
        self._mono_fn = _monomial_function(self._exponents)
        self.discretisation = [choice] * len(gens)

    def _table_mats(self, c: np.ndarray, choice: str
                    ) -> list[tuple[np.ndarray, np.ndarray]]:
        """(M_c, M_j) of every generator (see :class:`DiscretisationPolynomial`)."""
        model, n, p, r = self.model, self._n, self._p, self._r
        nu = model.B0.shape[1]
        C = model.C
        Bj = model.B_rho if model.B_rho.shape[0] else np.zeros((model.d, n, nu))
        out = []
        for g in self.generators:
            Lj = g.L_rho if g.L_rho.shape[0] else np.zeros((model.d, n, p))
            Ac, Bc, Lc = model.A(c), model.B(c), g.L(c)
            Aj = model.A_rho
            if choice == "hold":
                Ac, Aj = Ac - Lc @ C, model.A_rho - Lj @ C
            Mc = np.zeros((r, r))
            Mc[:n] = np.hstack([Ac, Bc, Lc])
            Mj = np.zeros((model.d, r, r))
            Mj[:, :n] = np.concatenate([Aj, Bj, Lj], axis=2)
            out.append((Mc, Mj))
        return out

    def _uniform_choice(self, c: np.ndarray, half: np.ndarray) -> str | None:
        """``exact`` or ``hold`` when the reference picks it at every point of a
        CHOICE_GRID^d grid of the box, 1e-6 away from its cut; else None."""
        axes = [np.linspace(a - h, a + h, CHOICE_GRID) for a, h in zip(c, half)]
        radii = []
        for point in itertools.product(*axes):
            rho = np.array(point, dtype=float)
            for g in self.generators:
                A, B, L = self.model.A(rho), self.model.B(rho), g.L(rho)
                Ad, G = zoh(A, np.hstack([B, L]), self.dt, _expm_small)
                Ld = G[:, B.shape[1]:]
                radii.append(float(np.abs(np.linalg.eigvals(Ad - Ld @ self.model.C)).max()))
        if max(radii) < 1.0 - 1e-6:
            return "exact"
        if min(radii) > 1.0 - 1e-9 + 1e-6:
            return "hold"
        return None

    # -- stepping ------------------------------------------------------------------------

    @property
    def residuals(self) -> list[np.ndarray]:
        """The residual vectors ``r_i`` (p,) of the last step."""
        return list(self._R.copy())

    def reset(self, xhat0: np.ndarray | None = None) -> None:
        """Set every observer state to ``xhat0`` (n,) (default zeros)."""
        self.xhat[:] = 0.0 if xhat0 is None else np.asarray(xhat0, dtype=float)

    def schedule(self, y: np.ndarray) -> np.ndarray:
        """Parameter ``rho`` (d,) from the measurement by the bank's scheduling map, clipped to
        the design box; ``ValueError`` when the bank has none."""
        sched = self.model.scheduling
        if not sched:
            raise ValueError("this LPV bank needs the measured parameter rho (no scheduling "
                             "map in its gain file)")
        rho = SCHEDULING_MAPS[str(sched["map"])](np.asarray(y, dtype=float),
                                                  dict(sched.get("params") or {}))
        return np.clip(rho, self.model.rho_min, self.model.rho_max)

    def step(self, k: int, u: np.ndarray, y: np.ndarray,
             rho: np.ndarray | None = None) -> np.ndarray:
        """Process sample ``k``: residuals from ``y_k``, then advance every observer.

        Parameters
        ----------
        k : int
            Sample index (time ``k Ts``; kept for the caller's bookkeeping).
        u : numpy.ndarray
            (nu,) input applied over ``[k Ts, (k+1) Ts)``.
        y : numpy.ndarray
            (p,) measurement at ``k Ts``.
        rho : numpy.ndarray, optional
            (d,) measured parameter of an LPV bank (clipped to the design box); when
            omitted an LPV bank computes it from ``y`` with its scheduling map.

        Returns
        -------
        numpy.ndarray
            (n_gen,) residual norms ``||r_i||`` (output units).
        """
        if not self.fast:
            return self.step_reference(k, u, y, rho)
        uy = np.concatenate([np.asarray(u, dtype=float).reshape(-1),
                             np.asarray(y, dtype=float).reshape(-1)])
        if not np.isfinite(uy).all():
            raise ValueError(f"sample {k}: u and y must be finite")
        if self._coef is None:
            phi = self._phi
        else:
            model = self.model
            r_ = self.schedule(uy[uy.size - self._p:]) if rho is None else np.clip(
                np.asarray(rho, dtype=float).reshape(-1), model.rho_min, model.rho_max)
            phi = self.map_at(r_.tolist())
        return self._advance(phi, uy)

    def map_at(self, rho: Sequence[float]) -> np.ndarray:
        """(n_gen, n + p, r) every generator's one-step map at ``rho`` (d,) in the box, from
        the polynomial (``[x^+; r] = map [x^; u; y]``)."""
        assert self._coefT is not None
        mono = np.array(self._mono_fn(*[float(v) - c for v, c in zip(rho, self._centre)]))
        return (self._coefT @ mono).reshape(len(self.generators), self._n + self._p,
                                            self._r)

    def advance(self, uy: list[float], rho: list[float] | None) -> np.ndarray:
        """The fast step on validated numbers: ``uy`` = u_k then y_k as floats (finite),
        ``rho`` (d,) inside the box (LPV; None for LTI and uncertain banks) -> (n_gen,)
        residual norms. Only when :attr:`fast`."""
        return self._advance(self._phi if rho is None else self.map_at(rho), uy)

    def _advance(self, phi: Any, uy: Any) -> np.ndarray:
        """One step of every generator with the maps ``phi`` (n_gen, n + p, r)."""
        n = self._n
        Z = self._Z
        Z[:, n:] = uy
        out = np.matmul(phi, self._Z3)[:, :, 0]
        Z[:, :n] = out[:, :n]
        R = self._R = out[:, n:]
        return np.sqrt((R * R).sum(axis=1))

    def step_reference(self, k: int, u: np.ndarray, y: np.ndarray,
                       rho: np.ndarray | None = None) -> np.ndarray:
        """:meth:`step` as defined: every generator re-discretised at ``rho`` (LPV) and
        stepped on its own (the fast path is tested against it)."""
        u = np.asarray(u, dtype=float).reshape(-1)
        y = np.asarray(y, dtype=float).reshape(-1)
        if not (np.all(np.isfinite(u)) and np.all(np.isfinite(y))):
            raise ValueError(f"sample {k}: u and y must be finite")
        C = self.model.C
        if self.kind == "lpv":
            r_ = self.schedule(y) if rho is None else np.clip(
                np.asarray(rho, dtype=float).reshape(-1), self.model.rho_min,
                self.model.rho_max)
            mats = [self._discretise(g, r_) for g in self.generators]
            self.discretisation = [m[3] for m in mats]
        else:
            mats = self._lti
        norms = np.empty(len(self.generators))
        for i, (g, (Ad, Bd, Ld, _how)) in enumerate(zip(self.generators, mats)):
            innov = y - C @ self.xhat[i]
            r = g.H @ innov
            self._R[i] = r
            norms[i] = float(np.linalg.norm(r))
            self.xhat[i] = Ad @ self.xhat[i] + Bd @ u + Ld @ y
        return norms

    def alarms(self, norms: np.ndarray) -> np.ndarray:
        """(n_gen,) bool: ``||r_i|| > threshold_i``."""
        return np.asarray(norms) > self.thresholds

    def run(self, u: np.ndarray, y: np.ndarray, rho: np.ndarray | None = None) -> np.ndarray:
        """Run over a whole record: u (K, nu), y (K, p), rho (K, d) -> norms (K, n_gen)."""
        K = y.shape[0]
        out = np.empty((K, len(self.generators)))
        for k in range(K):
            out[k] = self.step(k, u[k], y[k], None if rho is None else rho[k])
        return out
