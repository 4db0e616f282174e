"""Certificate of an H-infinity residual-generator bank, re-verified with numpy alone.

:func:`check_certificate` re-verifies a ``hinf_sc`` gain file from its stored model and
gains, without any solver: the eigenvector constraint ``(A(v) - L(v) C) V = lambda V``
(4.37), the bounded-real LMI at every vertex ``v`` of the parameter box (4.23 / 5.45 / 6.40,
see :func:`lmi_matrix`), ``P > 0``, the LMI pole region (4.66) when one was imposed, and the
consistency of the model with the plant file. The designer (:mod:`fd_monitor.design.hinf_sc`)
runs the same checks on its own result (:func:`check_generator`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from fd_monitor.core.hinf_model import (
    AffineModel,
    Generator,
    bank_results,
    parse_bank,
    vertices,
)
from fd_monitor.model.errors import GainFileError
from fd_monitor.model.system import System

__all__ = ["EIGVEC_RTOL", "check_certificate", "check_generator", "lmi_matrix",
           "region_matrix"]

#: Tolerance on the eigenvector constraint, relative to ``||A|| + |lambda|``.
EIGVEC_RTOL = 1e-7


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
    if gen.kind == "uncertain":
        return _lmi_uncertain(model, gen, rho)
    C, H = model.C, gen.H
    HC = H @ C
    A = model.A(rho)
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


def _lmi_uncertain(model: AffineModel, gen: Generator, rho: np.ndarray) -> np.ndarray:
    """The LMI (5.30/5.45) of an ``uncertain`` generator at ``rho`` (see :func:`lmi_matrix`)."""
    C = model.C
    HC = gen.H @ C
    A = model.A(rho)
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
        reg_max += _region_at(model, gen, v)
    _check_eigvec(name, eig_res)
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
        reg_max += _region_at(model, gen, v)
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
    _check_eigvec(name, eig_res)
    return {"lmi_max_eig": lmi_max, "p_min_eig": p_min, "closed_loop_max_real": cl_max,
            "eigvec_residual": eig_res, "region_max_eig": reg_max,
            "multiconvex_min_eig": convex_min}


def _region_at(model: AffineModel, gen: Generator, v: np.ndarray) -> list[float]:
    """Largest eigenvalue of each pole-region LMI (4.66) at vertex ``v``; refused above
    ``1e-9 max(1, max |P|)``."""
    out = []
    for Lr, Mr in gen.region:
        rm = float(np.linalg.eigvalsh(region_matrix(model, gen, v, Lr, Mr)).max())
        out.append(rm)
        if rm > 1e-9 * max(1.0, float(np.abs(gen.P).max())):
            raise GainFileError(f"generator {gen.fault!r}: the pole-region LMI (4.66) does "
                                f"not hold at rho = {v.tolist()} (max eigenvalue {rm:.3e})")
    return out


def _check_eigvec(name: str, eig_res: float) -> None:
    """Refuse a relative residual of the eigenvector constraint (4.37) above the tolerance."""
    if eig_res > EIGVEC_RTOL:
        raise GainFileError(f"generator {name!r}: the eigenvector constraint (4.37) "
                            f"(A - L C) V = lambda V does not hold (relative residual "
                            f"{eig_res:.3e})")


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
    results = bank_results(gains)
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
