"""Banks of H-infinity residual generators with a sensitivity constraint (thesis ch. 4-7).

Runtime (numpy/scipy only) of what ``python -m fd_monitor design hinf_sc`` writes: one
observer-based residual generator per fault (thesis eq. 4.5-4.7, 5.8-5.10, 6.9-6.14)::

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

:func:`check_certificate` re-verifies a gain file from its stored model and gains, without
any solver: the eigenvector constraint ``(A(v) - L(v) C) V = lambda V`` (4.37), the
bounded-real LMI at every vertex ``v`` of the parameter box (4.23 / 5.45 / 6.40, see
:func:`lmi_matrix`), ``P > 0``, the LMI pole region (4.66) when one was imposed, and the
consistency of the model with the plant file.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.linalg import expm

from fd_monitor.model.errors import GainFileError
from fd_monitor.model.nonlinear import SCHEDULING_MAPS
from fd_monitor.model.system import System

__all__ = [
    "AffineModel",
    "Generator",
    "ResidualBank",
    "bound_thresholds",
    "check_certificate",
    "check_generator",
    "generator_ss",
    "lmi_matrix",
    "monte_carlo_thresholds",
    "region_matrix",
    "rk4_step",
    "simulate_affine_plant",
    "vertices",
]

#: Tolerance on the eigenvector constraint, relative to ``||A|| + |lambda|``.
EIGVEC_RTOL = 1e-7


# --------------------------------------------------------------------------------------
# model and generators


def _stack(v: Any, tail: tuple[int, ...]) -> np.ndarray:
    """(d, *tail) array from a stored list of matrices (possibly empty)."""
    if v is None or (isinstance(v, list) and len(v) == 0):
        return np.zeros((0, *tail))
    a = np.asarray(v, dtype=float)
    return a.reshape((-1, *tail))


@dataclass(frozen=True)
class AffineModel:
    """Affine parameter-dependent plant model of a bank (thesis eq. 5.2, 6.5).

    Attributes
    ----------
    A0 : numpy.ndarray
        (n, n) nominal state matrix, 1/s.
    A_rho : numpy.ndarray
        (d, n, n) affine parts ``A_j``.
    B0 : numpy.ndarray
        (n, nu) nominal input matrix.
    B_rho : numpy.ndarray
        (d, n, nu) affine parts ``B_j``.
    C : numpy.ndarray
        (p, n) output matrix.
    rho_min, rho_max : numpy.ndarray
        (d,) bounds of the parameter box.
    rho_names : tuple of str
    scheduling : dict or None
        ``{map, params}``: how an LPV bank computes ``rho`` from ``y`` when it is not given.
    rate_min, rate_max : numpy.ndarray or None
        (d,) bounds of ``d rho / dt``, 1/s (thesis 6.52): only for affine Lyapunov functions.
    """

    A0: np.ndarray
    A_rho: np.ndarray
    B0: np.ndarray
    B_rho: np.ndarray
    C: np.ndarray
    rho_min: np.ndarray
    rho_max: np.ndarray
    rho_names: tuple[str, ...] = ()
    scheduling: Mapping[str, Any] | None = None
    rate_min: np.ndarray | None = None
    rate_max: np.ndarray | None = None

    @property
    def n(self) -> int:
        """Number of states."""
        return int(self.A0.shape[0])

    @property
    def d(self) -> int:
        """Number of parameters."""
        return int(self.A_rho.shape[0])

    def A(self, rho: np.ndarray | None = None) -> np.ndarray:
        """(n, n) ``A(rho) = A0 + sum rho_j A_j``."""
        if rho is None or self.d == 0:
            return self.A0
        return self.A0 + np.tensordot(np.asarray(rho, dtype=float), self.A_rho, axes=1)

    def B(self, rho: np.ndarray | None = None) -> np.ndarray:
        """(n, nu) ``B(rho) = B0 + sum rho_j B_j``."""
        if rho is None or self.d == 0 or self.B_rho.shape[0] == 0:
            return self.B0
        return self.B0 + np.tensordot(np.asarray(rho, dtype=float), self.B_rho, axes=1)

    @classmethod
    def from_results(cls, m: Mapping[str, Any]) -> AffineModel:
        """Build from the ``results.model`` mapping of a gain file."""
        A0 = np.atleast_2d(np.asarray(m["A0"], dtype=float))
        n = A0.shape[0]
        C = np.atleast_2d(np.asarray(m["C"], dtype=float))
        B0 = np.asarray(m.get("B0", np.zeros((n, 0))), dtype=float).reshape(n, -1)
        A_rho = _stack(m.get("A_rho"), (n, n))
        B_rho = _stack(m.get("B_rho"), (n, B0.shape[1]))
        d = A_rho.shape[0]
        rmin = np.asarray(m.get("rho_min", np.zeros(d)), dtype=float).reshape(d)
        rmax = np.asarray(m.get("rho_max", np.zeros(d)), dtype=float).reshape(d)
        names = tuple(str(s) for s in (m.get("rho_names") or []))
        sched = m.get("scheduling") or None
        rates = [None if m.get(k) is None else np.asarray(m[k], dtype=float).reshape(d)
                 for k in ("rate_min", "rate_max")]
        return cls(A0, A_rho, B0, B_rho, C, rmin, rmax, names, sched, rates[0], rates[1])


def vertices(rho_min: np.ndarray, rho_max: np.ndarray) -> list[np.ndarray]:
    """The 2^d corners of the parameter box (thesis eq. 5.4, 6.4); ``[[]]`` when d = 0."""
    d = len(rho_min)
    if d == 0:
        return [np.zeros(0)]
    return [np.array(c, dtype=float) for c in itertools.product(*zip(rho_min, rho_max))]


@dataclass(frozen=True)
class Generator:
    """One residual generator of a bank.

    Attributes
    ----------
    fault : str
        The fault it isolates.
    kind : str
        ``lti``, ``lpv`` or ``uncertain``.
    lam : float
        Assigned eigenvalue lambda, 1/s (nan for a pure attenuation design).
    V : numpy.ndarray
        (n, q) eigenvector directions ``A^k F_i`` (or ``[F_pa, A F_pa]`` of a sensor fault).
    Fhat : numpy.ndarray
        (n, m) nuisance fault directions.
    Dw, Ew : numpy.ndarray
        (n, nw), (p, nw) disturbance to state and to output.
    Dn : numpy.ndarray
        (p, nn) noise to output.
    H : numpy.ndarray
        (p, p) projection (4.55).
    L0 : numpy.ndarray
        (n, p)
    L_rho : numpy.ndarray
        (d, n, p)
    P : numpy.ndarray
        (n, n) Lyapunov matrix; for ``uncertain`` the (2n, 2n) ``diag(P1, P2)`` (5.29).
    gamma2 : dict
        Squared attenuation bounds ``{nuisance, disturbance, noise}`` (4.22).
    region : list of (numpy.ndarray, numpy.ndarray)
        LMI-region characteristic matrices ``(Lr, Mr)`` (2.26), possibly empty.
    P_rho : numpy.ndarray
        (d, n, n) affine parts of ``P(rho) = P + sum rho_j P_j`` (thesis 6.54, affine
        quadratic stability); empty (0, n, n) for a common P.
    K_rho : numpy.ndarray
        (d + 1, n, p) with an affine P: ``K(rho) = K_0 + sum rho_j K_j`` (times the projection
        ``I - C V (C V)^+``), the gain being ``L(rho) = L0 + sum rho_j L_j + P(rho)^-1
        K(rho)``; empty otherwise.
    """

    fault: str
    kind: str
    lam: float
    V: np.ndarray
    Fhat: np.ndarray
    Dw: np.ndarray
    Ew: np.ndarray
    Dn: np.ndarray
    H: np.ndarray
    L0: np.ndarray
    L_rho: np.ndarray
    P: np.ndarray
    gamma2: Mapping[str, float]
    region: tuple[tuple[np.ndarray, np.ndarray], ...] = ()
    P_rho: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 0)))
    K_rho: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 0)))

    @property
    def affine(self) -> bool:
        """True for an affine Lyapunov function ``P(rho)`` (thesis 6.4)."""
        return self.P_rho.shape[0] > 0

    def Pm(self, rho: np.ndarray | None = None) -> np.ndarray:
        """(n, n) ``P(rho) = P + sum rho_j P_j`` (P for a common Lyapunov matrix)."""
        if rho is None or not self.affine:
            return self.P
        return self.P + np.tensordot(np.asarray(rho, dtype=float), self.P_rho, axes=1)

    def L(self, rho: np.ndarray | None = None) -> np.ndarray:
        """(n, p) gain ``L(rho) = L0 + sum rho_j L_j`` (6.10); with an affine P(rho) plus
        ``P(rho)^-1 K(rho)`` (6.67: ``K(rho) = P(rho) Lbar(rho)`` affine)."""
        if not self.affine and (rho is None or self.L_rho.shape[0] == 0):
            return self.L0
        r = np.zeros(self.P_rho.shape[0]) if rho is None else np.asarray(rho, dtype=float)
        L = self.L0 + np.tensordot(r, self.L_rho, axes=1)
        if self.affine:
            K = self.K_rho[0] + np.tensordot(r, self.K_rho[1:], axes=1)
            L = L + np.linalg.solve(self.Pm(r), K)
        return L

    @classmethod
    def from_results(cls, g: Mapping[str, Any], kind: str, n: int, p: int) -> Generator:
        """Build from one entry of ``results.generators``."""
        def mat(key: str, rows: int) -> np.ndarray:
            v = g.get(key)
            if v is None or (isinstance(v, list) and not v):
                return np.zeros((rows, 0))
            return np.asarray(v, dtype=float).reshape(rows, -1)

        region = tuple((np.atleast_2d(np.asarray(r["L"], dtype=float)),
                        np.atleast_2d(np.asarray(r["M"], dtype=float)))
                       for r in (g.get("region") or []))
        g2 = {k: float(v) for k, v in dict(g.get("gamma2") or {}).items()}
        lam = g.get("lambda")
        return cls(str(g["fault"]), kind, float("nan") if lam is None else float(lam),
                   mat("V", n), mat("Fhat", n), mat("Dw", n), mat("Ew", p), mat("Dn", p),
                   np.asarray(g["H"], dtype=float).reshape(p, p),
                   np.asarray(g["L0"], dtype=float).reshape(n, p),
                   _stack(g.get("L_rho"), (n, p)),
                   np.atleast_2d(np.asarray(g["P"], dtype=float)), g2, region,
                   _stack(g.get("P_rho"), (n, n)), _stack(g.get("K_rho"), (n, p)))


def _results(gains: Any) -> Mapping[str, Any]:
    return gains.results if hasattr(gains, "results") else gains


def parse_bank(results: Mapping[str, Any]) -> tuple[str, AffineModel, list[Generator]]:
    """(kind, model, generators) of the ``results`` of a ``hinf_sc`` gain file."""
    kind = str(results["kind"])
    if kind not in ("lti", "lpv", "uncertain"):
        raise ValueError(f"results.kind: expected lti, lpv or uncertain, got {kind!r}")
    model = AffineModel.from_results(results["model"])
    gens = [Generator.from_results(g, kind, model.n, model.C.shape[0])
            for g in results["generators"]]
    return kind, model, gens


# --------------------------------------------------------------------------------------
# LMIs evaluated with numpy (the designer's independent check and the loader's)


def lmi_matrix(model: AffineModel, gen: Generator, rho: np.ndarray,
               rho_dot: np.ndarray | None = None) -> np.ndarray:
    """The bounded-real LMI matrix of a generator at the parameter value ``rho``.

    With an affine Lyapunov function (thesis 6.4) P is ``P(rho)`` and the (1,1) block gets
    ``+ sum rho_dot_j P_j`` (dP/dt, 6.56, 6.66), ``rho_dot`` a rate (default zero).

    ``lti`` / ``lpv`` (thesis 4.20/4.23 with the affine gain of 6.40, one joint LMI with a
    bound per input group)::

        [[Acl' P + P Acl + (HC)'HC,  P Bcl + (HC)'H Wout],
         [*,                         Wout'H'H Wout - Gamma]]  < 0

    with ``Acl = A(rho) - L(rho) C``, inputs ``W = [Fhat, Dw, 0]`` to the state and
    ``Wout = [0, Ew, Dn]`` to the output, ``Bcl = W - L(rho) Wout`` and
    ``Gamma = diag(g_nuis I, g_dist I, g_noise I)``. ``uncertain`` (thesis 5.30/5.45, state
    ``[x; e]``, ``P = diag(P1, P2)``, ``gamma = sqrt(g_nuis)``)::

        [[A'P1 + P1 A, (A - A0)'P2, P1 Fhat, 0    ],
         [*,  Acl'P2 + P2 Acl,      P2 Fhat, (HC)'],
         [*,  *,                    -gamma,  0    ],
         [*,  *,                    0,       -gamma]]  < 0,   Acl = A0 - L C

    Returns
    -------
    numpy.ndarray
        Symmetric matrix; negative definite when the certificate holds at ``rho``.
    """
    C, H = model.C, gen.H
    HC = H @ C
    A = model.A(rho)
    if gen.kind == "uncertain":
        n = model.n
        P1, P2 = gen.P[:n, :n], gen.P[n:, n:]
        Acl = model.A0 - gen.L0 @ C
        g = float(np.sqrt(max(gen.gamma2.get("nuisance", 0.0), 0.0)))
        m = gen.Fhat.shape[1]
        p = C.shape[0]
        M = np.zeros((2 * n + m + p, 2 * n + m + p))
        M[:n, :n] = A.T @ P1 + P1 @ A
        M[:n, n:2 * n] = (A - model.A0).T @ P2
        M[:n, 2 * n:2 * n + m] = P1 @ gen.Fhat
        M[n:2 * n, n:2 * n] = Acl.T @ P2 + P2 @ Acl
        M[n:2 * n, 2 * n:2 * n + m] = P2 @ gen.Fhat
        M[n:2 * n, 2 * n + m:] = HC.T
        M[2 * n:, 2 * n:] = -g * np.eye(m + p)
        return np.triu(M) + np.triu(M, 1).T
    L = gen.L(rho)
    P = gen.Pm(rho)
    Acl = A - L @ C
    m, nw, nn = gen.Fhat.shape[1], gen.Dw.shape[1], gen.Dn.shape[1]
    n, p = model.n, C.shape[0]
    W = np.hstack([gen.Fhat, gen.Dw, np.zeros((n, nn))])
    Wout = np.hstack([np.zeros((p, m)), gen.Ew, gen.Dn])
    Bcl = W - L @ Wout
    gam = np.concatenate([np.full(m, gen.gamma2.get("nuisance", 0.0)),
                          np.full(nw, gen.gamma2.get("disturbance", 0.0)),
                          np.full(nn, gen.gamma2.get("noise", 0.0))])
    HW = H @ Wout
    dP = (np.tensordot(np.asarray(rho_dot, dtype=float), gen.P_rho, axes=1)
          if gen.affine and rho_dot is not None else 0.0)
    top = np.hstack([Acl.T @ P + P @ Acl + dP + HC.T @ HC, P @ Bcl + HC.T @ HW])
    bot = np.hstack([(P @ Bcl + HC.T @ HW).T, HW.T @ HW - np.diag(gam)])
    M = np.vstack([top, bot])
    return 0.5 * (M + M.T)


def region_matrix(model: AffineModel, gen: Generator, rho: np.ndarray,
                  Lr: np.ndarray, Mr: np.ndarray) -> np.ndarray:
    """LMI-region matrix ``Lr (x) P + Mr (x) (P Acl) + Mr' (x) (P Acl)'`` (thesis 2.28, 4.66).

    ``Acl = A(rho) - L(rho) C`` (``A0 - L C`` with ``P2`` for an uncertain bank).
    """
    if gen.kind == "uncertain":
        n = model.n
        P = gen.P[n:, n:]
        Acl = model.A0 - gen.L0 @ model.C
    else:
        P = gen.Pm(rho)
        Acl = model.A(rho) - gen.L(rho) @ model.C
    PA = P @ Acl
    M = np.kron(Lr, P) + np.kron(Mr, PA) + np.kron(Mr.T, PA.T)
    return 0.5 * (M + M.T)


def check_generator(model: AffineModel, gen: Generator) -> dict[str, Any]:
    """Recompute a generator's certificate; raise ``GainFileError`` when it does not hold.

    Returns
    -------
    dict
        ``lmi_max_eig`` (per vertex), ``p_min_eig``, ``closed_loop_max_real`` (per vertex),
        ``eigvec_residual``, ``region_max_eig`` (per vertex, empty without a region).
    """
    name = gen.fault
    verts = vertices(model.rho_min, model.rho_max)
    if gen.affine:
        return _check_affine(model, gen)
    p_min = float(np.linalg.eigvalsh(0.5 * (gen.P + gen.P.T)).min())
    if not p_min > 0:
        raise GainFileError(f"generator {name!r}: P is not positive definite "
                            f"(min eigenvalue {p_min:.3e})")
    lmi_max, cl_max, reg_max = [], [], []
    eig_res = 0.0
    for v in verts:
        lm = float(np.linalg.eigvalsh(lmi_matrix(model, gen, v)).max())
        lmi_max.append(lm)
        if not lm < 0:
            raise GainFileError(f"generator {name!r}: the bounded-real LMI does not hold at "
                                f"rho = {v.tolist()} (max eigenvalue {lm:.3e} >= 0)")
        A_obs = model.A0 if gen.kind == "uncertain" else model.A(v)
        L = gen.L(None if gen.kind == "uncertain" else v)
        cl, res = _closed_loop_at(name, gen, v, A_obs, L, model.C)
        cl_max.append(cl)
        eig_res = max(eig_res, res)
        for Lr, Mr in gen.region:
            rm = float(np.linalg.eigvalsh(region_matrix(model, gen, v, Lr, Mr)).max())
            reg_max.append(rm)
            if rm > 1e-9 * max(1.0, float(np.abs(gen.P).max())):
                raise GainFileError(f"generator {name!r}: the pole-region LMI (4.66) does "
                                    f"not hold at rho = {v.tolist()} (max eigenvalue "
                                    f"{rm:.3e})")
    if eig_res > EIGVEC_RTOL:
        raise GainFileError(f"generator {name!r}: the eigenvector constraint (4.37) "
                            f"(A - L C) V = lambda V does not hold (relative residual "
                            f"{eig_res:.3e})")
    H = gen.H
    if np.linalg.norm(H @ H - H) > 1e-8 or np.linalg.norm(H - H.T) > 1e-8:
        raise GainFileError(f"generator {name!r}: H is not an orthogonal projection (4.55)")
    return {"lmi_max_eig": lmi_max, "p_min_eig": p_min, "closed_loop_max_real": cl_max,
            "eigvec_residual": eig_res, "region_max_eig": reg_max}


def _second_difference(f: Callable[[np.ndarray], np.ndarray], rho: np.ndarray,
                       j: int) -> np.ndarray:
    """``f(rho + e_j) + f(rho - e_j) - 2 f(rho)``: twice the rho_j^2 coefficient of a matrix
    function quadratic in rho (exact up to round-off)."""
    e = np.zeros_like(rho)
    e[j] = 1.0
    return f(rho + e) + f(rho - e) - 2.0 * f(rho)


def _check_affine(model: AffineModel, gen: Generator) -> dict[str, Any]:
    """Certificate of a generator with an affine Lyapunov function ``P(rho)`` (thesis 6.4).

    Checks, from the stored numbers alone: ``P(v) > 0`` at every vertex v (then on the box,
    P being affine); the bounded-real LMI (4.23 with ``P(rho)`` and ``dP/dt = sum rho_dot_j
    P_j``, thesis 6.66) negative definite at every (vertex, rate vertex); multi-convexity
    (its second derivative along each rho_j, twice the rho_j^2 coefficient, positive
    semidefinite, as (6.63)/(6.66) require), so negativity at the vertices implies it on
    the whole box; the same for the pole-region LMI; A(v) - L(v) C Hurwitz and the
    eigenvector constraint at every vertex.
    """
    name = gen.fault
    if model.rate_min is None or model.rate_max is None:
        raise GainFileError(f"generator {name!r}: affine P(rho) without rate bounds "
                            f"(results.model.rate_min / rate_max)")
    verts = vertices(model.rho_min, model.rho_max)
    rates = vertices(model.rate_min, model.rate_max)
    scale = max(1.0, float(np.abs(gen.P).max()))
    p_min = min(float(np.linalg.eigvalsh(gen.Pm(v)).min()) for v in verts)
    if not p_min > 0:
        raise GainFileError(f"generator {name!r}: P(rho) is not positive definite at a vertex "
                            f"(min eigenvalue {p_min:.3e})")
    lmi_max, cl_max, reg_max, convex_min = [], [], [], []
    eig_res = 0.0
    for v in verts:
        lm = max(float(np.linalg.eigvalsh(lmi_matrix(model, gen, v, k)).max()) for k in rates)
        lmi_max.append(lm)
        if not lm < 0:
            raise GainFileError(f"generator {name!r}: the bounded-real LMI (6.66) does not "
                                f"hold at rho = {v.tolist()} (max eigenvalue {lm:.3e} >= 0)")
        cl, res = _closed_loop_at(name, gen, v, model.A(v), gen.L(v), model.C)
        cl_max.append(cl)
        eig_res = max(eig_res, res)
        for Lr, Mr in gen.region:
            rm = float(np.linalg.eigvalsh(region_matrix(model, gen, v, Lr, Mr)).max())
            reg_max.append(rm)
            if rm > 1e-9 * scale:
                raise GainFileError(f"generator {name!r}: the pole-region LMI (4.66) does "
                                    f"not hold at rho = {v.tolist()} (max eigenvalue {rm:.3e})")
    mid = 0.5 * (model.rho_min + model.rho_max)
    def brl(r: np.ndarray) -> np.ndarray:
        return lmi_matrix(model, gen, r)

    def region_at(Lr: np.ndarray, Mr: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
        return lambda r: region_matrix(model, gen, r, Lr, Mr)

    fns = [brl, *(region_at(Lr, Mr) for Lr, Mr in gen.region)]
    for j in range(model.d):
        for f in fns:
            cmin = float(np.linalg.eigvalsh(_second_difference(f, mid, j)).min())
            convex_min.append(cmin)
            if cmin < -1e-7 * scale:
                raise GainFileError(f"generator {name!r}: multi-convexity fails along "
                                    f"{model.rho_names[j] if model.rho_names else j} "
                                    f"(second derivative min eigenvalue {cmin:.3e} < 0)")
    if eig_res > EIGVEC_RTOL:
        raise GainFileError(f"generator {name!r}: the eigenvector constraint (4.37) "
                            f"(A - L C) V = lambda V does not hold (relative residual "
                            f"{eig_res:.3e})")
    return {"lmi_max_eig": lmi_max, "p_min_eig": p_min, "closed_loop_max_real": cl_max,
            "eigvec_residual": eig_res, "region_max_eig": reg_max,
            "multiconvex_min_eig": convex_min}


def _closed_loop_at(name: str, gen: Any, v: np.ndarray, A_obs: np.ndarray, L: np.ndarray,
                    C: np.ndarray) -> tuple[float, float]:
    """At vertex ``v``: the largest real part of eig(A - L C) (refused unless < 0) and the
    relative residual of the assigned eigenstructure (0 when there is none)."""
    Acl = A_obs - L @ C
    cl = float(np.linalg.eigvals(Acl).real.max())
    if not cl < 0:
        raise GainFileError(f"generator {name!r}: A - L C is not Hurwitz at rho = "
                            f"{v.tolist()} (max real part {cl:.3e})")
    if not (np.isfinite(gen.lam) and gen.V.shape[1]):
        return cl, 0.0
    res = np.linalg.norm(Acl @ gen.V - gen.lam * gen.V)
    return cl, float(res / ((np.linalg.norm(A_obs) + abs(gen.lam)) * np.linalg.norm(gen.V)))


def check_certificate(system: System, gains: Any) -> dict[str, Any]:
    """Re-verify an ``hinf_sc`` gain file against ``system``; ``GainFileError`` if it fails.

    Checks that the stored model matches the plant (sizes, ``C``; ``A0`` and ``B0`` for a
    linear continuous-time plant) and every generator's certificate (:func:`check_generator`).
    """
    results = _results(gains)
    _kind, model, gens = parse_bank(results)
    if model.C.shape != (system.ny, system.n):
        raise GainFileError(f"model.C: expected {system.ny}x{system.n} (the plant's outputs "
                            f"x states), got {model.C.shape[0]}x{model.C.shape[1]}")
    mode = system.modes[0]
    if not np.allclose(model.C, mode.C, rtol=1e-12, atol=1e-12):
        raise GainFileError("model.C differs from the plant's C")
    if mode.dynamics == "linear" and mode.time == "continuous":
        assert mode.A is not None
        if not np.allclose(model.A0, mode.A, rtol=1e-12, atol=1e-12):
            raise GainFileError("model.A0 differs from the plant's A (mode "
                                f"{mode.name!r})")
        if model.B0.shape == mode.B.shape and not np.allclose(model.B0, mode.B, rtol=1e-12,
                                                              atol=1e-12):
            raise GainFileError(f"model.B0 differs from the plant's B (mode {mode.name!r})")
    if model.B0.shape[1] != system.nu:
        raise GainFileError(f"model.B0: expected {system.nu} input columns, got "
                            f"{model.B0.shape[1]}")
    if not gens:
        raise GainFileError("results.generators: expected at least one generator")
    return {g.fault: check_generator(model, g) for g in gens}


# --------------------------------------------------------------------------------------
# frequency analysis helpers


def generator_ss(model: AffineModel, gen: Generator, B_in: np.ndarray, D_in: np.ndarray,
                 rho: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Continuous-time state-space map from an input entering the plant to a residual.

    The input enters the state through ``B_in`` (n, m) and the output through ``D_in``
    (p, m). For ``lti`` / ``lpv`` generators (frozen ``rho``)::

        de/dt = (A - L C) e + (B_in - L D_in) w,   r = H C e + H D_in w        (4.10, 4.72)

    For ``uncertain`` generators the extended state ``[x; e]`` of (5.14)/(5.60)::

        A_ext = [[A(rho), 0], [A(rho) - A0, A0 - L C]], B_ext = [B_in; B_in - L D_in],
        C_ext = [H C, ... ] -> r = [0, H C] [x; e] + H D_in w

    Returns
    -------
    A, B, C, D : numpy.ndarray
    """
    C, H = model.C, gen.H
    if gen.kind == "uncertain":
        n = model.n
        A = model.A(rho)
        L = gen.L0
        Aext = np.block([[A, np.zeros((n, n))], [A - model.A0, model.A0 - L @ C]])
        Bext = np.vstack([B_in, B_in - L @ D_in])
        Cext = np.hstack([np.zeros((H.shape[0], n)), H @ C])
        return Aext, Bext, Cext, H @ D_in
    L = gen.L(rho)
    return model.A(rho) - L @ C, B_in - L @ D_in, H @ C, H @ D_in


# --------------------------------------------------------------------------------------
# runtime


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


def _disc(A: np.ndarray, G: np.ndarray, dt: float, fast: bool = False
          ) -> tuple[np.ndarray, np.ndarray]:
    n, m = G.shape
    M = np.zeros((n + m, n + m))
    M[:n, :n] = A
    M[:n, n:] = G
    Md = _expm_small(M * dt) if fast else expm(M * dt)
    return Md[:n, :n], Md[:n, n:]


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

    Attributes
    ----------
    faults : tuple of str
        The fault of each generator, in order.
    residuals : list of numpy.ndarray
        The residual vectors ``r_i`` (p,) of the last step.
    """

    def __init__(self, system: System, gains: Any, thresholds: Sequence[float] | None = None,
                 discretisation: str = "auto") -> None:
        results = _results(gains)
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
        n = self.model.n
        self.xhat = np.zeros((n_gen, n))
        self.residuals: list[np.ndarray] = [np.zeros(self.model.C.shape[0])] * n_gen
        self._lti = [self._discretise(g, None) for g in self.generators] \
            if self.kind != "lpv" else []
        self.discretisation = [d[3] for d in self._lti]

    def _discretise(self, g: Generator, rho: np.ndarray | None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
        A = self.model.A0 if g.kind == "uncertain" else self.model.A(rho)
        B = self.model.B(None if g.kind == "uncertain" else rho)
        L = g.L(rho)
        C = self.model.C
        nu = B.shape[1]
        fast = rho is not None  # LPV: re-discretised at every sample
        if self._disc_mode in ("auto", "exact"):
            Ad, G = _disc(A, np.hstack([B, L]), self.dt, fast)
            Bd, Ld = G[:, :nu], G[:, nu:]
            if self._disc_mode == "exact" or \
                    np.abs(np.linalg.eigvals(Ad - Ld @ C)).max() < 1.0 - 1e-9:
                return Ad - Ld @ C, Bd, Ld, "exact"
        Ad, G = _disc(A - L @ C, np.hstack([B, L]), self.dt, fast)
        return Ad, G[:, :nu], G[:, nu:], "hold"

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
            self.residuals[i] = r
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


# --------------------------------------------------------------------------------------
# thresholds


def bound_thresholds(results: Mapping[str, Any], levels: Mapping[str, float],
                     margin: float = 1.0) -> np.ndarray:
    """Thresholds from the attenuation bounds and stated signal levels.

    ``J_i = margin * (gamma_nuis,i l_nuis + gamma_dist,i l_dist + gamma_noise,i l_noise)``,
    the bound (4.17) on the RMS of ``r_i`` when the nuisance faults, disturbances and noise
    have RMS levels ``l_*`` (an H-infinity norm bounds the RMS gain); ``margin`` covers the
    peak-to-RMS ratio of the residual.

    Returns
    -------
    numpy.ndarray
        (n_gen,) thresholds, output units.
    """
    out = []
    for g in results["generators"]:
        g2 = dict(g.get("gamma2") or {})
        out.append(margin * sum(np.sqrt(max(float(g2.get(k, 0.0)), 0.0))
                                * float(levels.get(k, 0.0))
                                for k in ("nuisance", "disturbance", "noise")))
    return np.asarray(out)


def monte_carlo_thresholds(norms: np.ndarray, settle: int = 0,
                           margin: float = 1.2) -> np.ndarray:
    """Thresholds from fault-free runs: ``margin * max |r_i|`` after ``settle`` samples.

    Parameters
    ----------
    norms : numpy.ndarray
        (runs, K, n_gen) residual norms of fault-free runs.
    """
    a = np.asarray(norms, dtype=float)
    if a.ndim == 2:
        a = a[None]
    return margin * a[:, settle:, :].max(axis=(0, 1))


# --------------------------------------------------------------------------------------
# simulation of an affine-parameter plant (uncertain / LPV examples)


def simulate_affine_plant(model: AffineModel, t: np.ndarray,
                          u: Callable[[float], np.ndarray],
                          rho: Callable[[float], np.ndarray],
                          F: np.ndarray, f: Callable[[float], np.ndarray],
                          x0: np.ndarray | None = None, substeps: int = 10
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Simulate ``dx/dt = A(rho(t)) x + B(rho(t)) u + F f(t)``, ``y = C x`` with RK4.

    The input ``u`` is held over each sample (zero-order hold, as the bank assumes);
    ``rho(t)`` and ``f(t)`` are evaluated inside the sample.

    Parameters
    ----------
    t : numpy.ndarray
        (K,) equally spaced sample times, s.
    u, rho, f : callable
        ``t -> (nu,)``, ``t -> (d,)``, ``t -> (nf,)``.
    F : numpy.ndarray
        (n, nf) fault directions.

    Returns
    -------
    x : (K, n), y : (K, p), u : (K, nu), rho : (K, d)
    """
    n = model.n
    K = t.size
    dt = float(t[1] - t[0]) if K > 1 else 1.0
    x = np.zeros(n) if x0 is None else np.asarray(x0, dtype=float).copy()
    xs = np.empty((K, n))
    us = np.empty((K, model.B0.shape[1]))
    rs = np.empty((K, model.d))

    for k in range(K):
        xs[k] = x
        uk = np.asarray(u(t[k]), dtype=float)
        us[k] = uk
        rs[k] = rho(t[k])

        def rhs(tt: float, xx: np.ndarray, uk: np.ndarray = uk) -> np.ndarray:
            r = rho(tt)
            return model.A(r) @ xx + model.B(r) @ uk + F @ f(tt)

        x = rk4_step(rhs, float(t[k]), x, dt, substeps)
    return xs, xs @ model.C.T, us, rs


def rk4_step(rhs: Callable[[float, np.ndarray], np.ndarray], t: float, x: np.ndarray,
             dt: float, substeps: int = 10) -> np.ndarray:
    """Advance ``dx/dt = rhs(t, x)`` from ``t`` over one sample ``dt`` by ``substeps`` classical
    Runge-Kutta steps (the integrator of :func:`simulate_affine_plant` and of the plant
    simulator's parameter-dependent modes).

    Parameters
    ----------
    rhs : callable
        ``(t, x) -> dx/dt`` of the same shape as ``x``.
    x : numpy.ndarray
        State at ``t``: (n,) or a batch (N, n).
    dt : float
        Sample time, s.

    Returns
    -------
    numpy.ndarray
        State at ``t + dt``, shape of ``x``.
    """
    h = dt / substeps
    tt = t
    for _ in range(substeps):
        k1 = rhs(tt, x)
        k2 = rhs(tt + h / 2, x + h / 2 * k1)
        k3 = rhs(tt + h / 2, x + h / 2 * k2)
        k4 = rhs(tt + h, x + h * k3)
        x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        tt += h
    return x
