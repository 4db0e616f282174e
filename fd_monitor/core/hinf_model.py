"""The model and the generators of an H-infinity residual-generator bank (thesis ch. 4-7).

What a ``hinf_sc`` gain file stores, as typed objects: the affine parameter-dependent plant
model ``A(rho) = A0 + sum_j rho_j A_j`` (:class:`AffineModel`, thesis eq. 5.2, 6.5), one
observer-based residual generator per fault (:class:`Generator`, thesis eq. 4.5-4.7,
5.8-5.10, 6.9-6.14), the vertices of the parameter box and the state-space map from a plant
input to a residual (:func:`generator_ss`). The runtime is
:mod:`fd_monitor.core.residual_bank`, the certificate :mod:`fd_monitor.core.hinf_certificate`.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["AffineModel", "Generator", "bank_results", "generator_ss", "parse_bank",
           "vertices"]

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


def bank_results(gains: Any) -> Mapping[str, Any]:
    """The ``results`` mapping of a loaded gain file (or the mapping itself)."""
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
# state-space map of a generator (frequency analysis)


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
