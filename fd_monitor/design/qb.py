"""QB observer design: Theorems 1-2 of Alessandri, Boem & Parisini, made well-posed.

``python -m fd_monitor design qb SYSTEM -o GAINS [--beta B] [--json]``

LMIs. Continuous time, per mode i (Theorem 1 for one mode, Theorem 2 with a common P)::

    (14a)  [ A_i'P - C_i'Y_i' + P A_i - Y_i C_i + beta P    P D_i - Y_i E_i ]  < 0
           [                  *                             -diag(alpha)    ]
    (14b)  sum_j alpha_j - beta <= 0,          L_i = P^-1 Y_i,

and in discrete time the counterpart derived in :mod:`fd_monitor.core.qb` (same S-procedure
argument on ``V(e_{k+1}) - V(e_k)``)::

    [ -(1-beta) P        0           (P A_i - Y_i C_i)' ]
    [      0       -diag(alpha)      (P D_i - Y_i E_i)' ]  < 0,  sum alpha <= beta,  0 < beta < 1.
    [ P A_i - Y_i C_i   P D_i - Y_i E_i        -P       ]

Procedure (Table I of the paper, made well-posed). The printed procedure has two faults:
step 1 (max beta s.t. eq. 10) is unbounded when the gains can place the error poles anywhere
(here the modes differ only by output injection), and the stop test ``|L_k - L_{k-1}| < eps``
compares gains that are not unique (each optimum has a set of optimal gains), so the loop
wanders. This designer instead

1. solves step 5 -- ``max lambda s.t. P >= lambda I, (14a), (14b)`` at fixed beta, an SDP in
   (P, Y_i, alpha, lambda) -- as one DPP-parametrised cvxpy problem re-solved over beta;
2. maximises ``lambda*(beta)`` (so minimises rho_max = 1/sqrt(lambda_min(P)), eq. 6) by a 1-D
   search over beta: a log-spaced grid (continuous time 1e-4 .. 1e4 1/s, a decade apart;
   discrete time 1e-4 .. 0.999), then a bounded Brent search in log(beta) (tolerance 0.01)
   between the neighbours of the best grid point. ``--beta B`` skips the search. No
   normalisation of P is needed: step 5 is bounded because the (2, 2) block
   ``-diag(alpha)`` with ``sum alpha <= beta`` does not scale with P;
3. breaks the tie among optimal gains: minimise ``|(Y_1, ..., Y_s)|_F`` (``Y_i = P L_i``)
   subject to the same LMIs, ``P >= (1 - slack) lambda* I`` and ``|P - P*|_F <= slack |P*|_F``
   (``slack`` = 1e-4: P and rho_max stay within 1e-4 relative of step 5's optimum P*). The
   objective is strictly convex in Y_i, so the gains are unique (minimum-norm gains). Fixing
   P at the optimum instead leaves a set of gains that is often a single point on the LMI's
   boundary, which the solver reaches only inaccurately. If this step is not optimal, the
   verified step-5 solution is kept and the gain file's ``solver.tie_break`` says so;
4. verifies the answer itself (not trusting the solver): P > 0, the LMIs evaluated at
   (P, L_i, alpha, beta) negative definite, ``sum alpha <= beta``, ``A_i - L_i C_i`` Hurwitz
   (Schur), and writes them to the gain file's certificate, which the loader recomputes.

Strict inequalities are imposed with a margin (``--margin``, default 1e-6): ``-M_i >= margin I``,
``alpha_j >= margin`` and ``lambda_min(P) >= margin`` (so rho_max below 1/sqrt(margin) = 1000
state units; rescale the plant's states if its errors are larger).
"""

from __future__ import annotations

import argparse
import math
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cvxpy as cp
import numpy as np
from scipy.optimize import minimize_scalar

from fd_monitor.core.qb import (
    QBModel,
    default_fault_states,
    lmi_blocks,
    qb_bounds,
    qb_model,
    spectral_abscissa,
    unobservable_unstable,
)
from fd_monitor.errors import DesignError
from fd_monitor.gains import save_gains
from fd_monitor.paths import default_gain_path
from fd_monitor.system import System, load_system

__all__ = ["QBDesign", "QBProblem", "design_qb", "add_arguments", "run"]

SOLVER = cp.CLARABEL
_GRID_CONT = np.logspace(-4, 4, 9)
_GRID_DISC = np.concatenate([np.logspace(-4, -0.5, 8), [0.5, 0.7, 0.85, 0.95, 0.99, 0.999]])


@dataclass
class QBDesign:
    """Result of :func:`design_qb`.

    Attributes
    ----------
    model : QBModel
    P : numpy.ndarray
        (n, n) Lyapunov matrix of the ellipsoid ``e' P e <= 1``, 1/state units^2.
    L : numpy.ndarray
        (s, n, ny) gains per mode.
    alpha : numpy.ndarray
        (q,)
    beta : float
    bounds : dict
        :func:`fd_monitor.core.qb.qb_bounds` of P.
    lmi_max_eig : list of float
        (s,) max eigenvalue of each LMI at the solution (< 0).
    spectral_abscissa : list of float
        (s,) of ``A_i - L_i C_i`` (continuous: max Re; discrete: max |.|).
    search : list of tuple
        (beta, lambda*(beta) or nan, status) for every step-5 solve.
    solver : dict
        Name, status, total solve time, number of solves.
    """

    model: QBModel
    P: np.ndarray
    L: np.ndarray
    alpha: np.ndarray
    beta: float
    bounds: dict[str, Any]
    lmi_max_eig: list[float]
    spectral_abscissa: list[float]
    search: list[tuple[float, float, str]] = field(default_factory=list)
    solver: dict[str, Any] = field(default_factory=dict)

    @property
    def rho_max(self) -> float:
        """1/sqrt(lambda_min(P)) (eq. 6), state units."""
        return float(self.bounds["rho_max"])


def _sym(M: Any) -> Any:
    return 0.5 * (M + M.T)


class QBProblem:
    """Step 5 of Table I as a DPP problem: ``max lambda`` at a given beta (a cvxpy Parameter).

    Parameters
    ----------
    model : QBModel
    margin : float
        Strictness margin of the LMIs.
    """

    def __init__(self, model: QBModel, margin: float = 1e-6) -> None:
        self.model = model
        n, ny, q, s = model.n, model.C.shape[1], model.q, model.s
        self.beta = cp.Parameter(nonneg=True, name="beta")
        self.P = cp.Variable((n, n), symmetric=True, name="P")
        self.Y = [cp.Variable((n, ny), name=f"Y{i}") for i in range(s)]
        self.alpha = cp.Variable(q, name="alpha")
        self.lam = cp.Variable(name="lam")
        cons = [self.P >> self.lam * np.eye(n), self.lam >= margin, self.alpha >= margin,
                cp.sum(self.alpha) <= self.beta]
        cons += [-_sym(M) >> margin * np.eye(M.shape[0])
                 for M in _lmis(model, self.P, self.Y, self.alpha, self.beta)]
        self.problem = cp.Problem(cp.Maximize(self.lam), cons)
        self.solves = 0
        self.solve_time = 0.0

    def solve(self, beta: float) -> tuple[float, str]:
        """Solve at ``beta``; return ``(lambda*, status)`` (lambda* nan unless optimal)."""
        self.beta.value = beta
        t0 = time.perf_counter()
        try:
            with warnings.catch_warnings():
                # cvxpy warns on inaccurate solutions; the status is checked below instead.
                warnings.simplefilter("ignore", UserWarning)
                self.problem.solve(solver=SOLVER)
            status = str(self.problem.status)
        except cp.error.SolverError as exc:
            status = f"solver_error ({str(exc).splitlines()[0][:80]})"
        self.solve_time += time.perf_counter() - t0
        self.solves += 1
        if status != cp.OPTIMAL or self.lam.value is None:
            return math.nan, status
        return float(self.lam.value), status


def _lmis(model: QBModel, P: Any, Y: list[Any], alpha: Any, beta: Any) -> list[Any]:
    """The LMI matrices of every mode as cvxpy expressions (affine in P, Y_i, alpha)."""
    out = []
    for i in range(model.s):
        A, C, D, E = model.A[i], model.C[i], model.D[i], model.E[i]
        PA = P @ A - Y[i] @ C
        PG = P @ D - Y[i] @ E
        if model.time == "continuous":
            out.append(cp.bmat([[PA.T + PA + beta * P, PG], [PG.T, -cp.diag(alpha)]]))
        else:
            n, q = model.n, model.q
            out.append(cp.bmat([[-(1 - beta) * P, np.zeros((n, q)), PA.T],
                                [np.zeros((q, n)), -cp.diag(alpha), PG.T],
                                [PA, PG, -P]]))
    return out


def check_detectable(system: System, model: QBModel) -> None:
    """Raise DesignError naming the first mode whose (A_i, C_i) is not detectable."""
    for i, name in enumerate(model.mode_names):
        bad = unobservable_unstable(model.A[i], model.C[i], model.time)
        if bad:
            ev = ", ".join(f"{z.real:.4g}{z.imag:+.4g}j" if abs(z.imag) > 1e-12
                           else f"{z.real:.4g}" for z in bad)
            kind = "Re >= 0" if model.time == "continuous" else "|z| >= 1"
            raise DesignError(f"plant {system.name}: mode {name!r}: (A, C) is not detectable "
                              f"(unobservable eigenvalue(s) {ev} with {kind}); no gain L makes "
                              f"A - L C stable, so the LMIs (14a) have no solution")


class _MinNormProblem:
    """Tie-break: ``min |(Y_1, ..., Y_s)|_F`` (Y_i = P L_i) s.t. the LMIs and
    ``P >= (1 - slack) lambda* I``, at beta and lambda* (cvxpy Parameters).

    Fixing P at the optimum leaves a set of gains that is often a single point on the LMI's
    boundary (numerically ill-posed); keeping P free with lambda_min(P) within ``slack`` of the
    optimum (and P within ``slack`` of it) gives a well-posed problem whose strictly convex
    objective makes the gains unique.
    The problem is posed in ``P / lambda*``, ``Y / lambda*``, ``alpha / lambda*`` (the LMIs
    are homogeneous in (P, Y, alpha) once (14b) reads ``sum alpha <= beta``), so its numbers
    are of order one whatever the plant's units.
    """

    def __init__(self, model: QBModel, margin: float) -> None:
        n, ny = model.n, model.C.shape[1]
        self.beta = cp.Parameter(nonneg=True, name="beta")
        self.beta_scaled = cp.Parameter(nonneg=True, name="beta_over_lambda")
        self.lam_lb = cp.Parameter(nonneg=True, name="lam_lb")
        self.margin = cp.Parameter(nonneg=True, name="margin_over_lambda")
        self.margin_value = margin
        self.P = cp.Variable((n, n), symmetric=True, name="P")
        self.Y = [cp.Variable((n, ny), name=f"Y{i}") for i in range(model.s)]
        self.alpha = cp.Variable(model.q, name="alpha")
        self.P_ref = cp.Parameter((n, n), symmetric=True, name="P_over_lambda")
        self.radius = cp.Parameter(nonneg=True, name="radius")
        cons = [self.P >> self.lam_lb * np.eye(n), self.alpha >= self.margin,
                cp.sum(self.alpha) <= self.beta_scaled,
                cp.norm(self.P - self.P_ref, "fro") <= self.radius]
        cons += [-_sym(M) >> self.margin * np.eye(M.shape[0])
                 for M in _lmis(model, self.P, self.Y, self.alpha, self.beta)]
        # One second-order cone (the Frobenius norm of all Y_i): same minimiser as
        # sum |Y_i|_F^2 and better conditioned for the solver.
        self.problem = cp.Problem(
            cp.Minimize(cp.norm(cp.hstack([cp.vec(Y, order="F") for Y in self.Y]), 2)), cons)

    def solve(self, beta: float, lam: float, slack: float, P_opt: np.ndarray) -> tuple[
            np.ndarray, np.ndarray, np.ndarray, str]:
        """Return ``(P, L (s, n, ny), alpha, status)`` in the plant's units."""
        self.beta.value, self.beta_scaled.value = beta, beta / lam
        self.P_ref.value = P_opt / lam
        self.radius.value = slack * float(np.linalg.norm(P_opt / lam))
        self.lam_lb.value = 1.0 - slack
        self.margin.value = self.margin_value / lam  # the same margin in the plant's units
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)
                self.problem.solve(solver=SOLVER)
        except cp.error.SolverError as exc:
            return (np.zeros(0), np.zeros(0), np.zeros(0),
                    f"solver_error ({str(exc).splitlines()[0][:80]})")
        if self.problem.status != cp.OPTIMAL:
            return np.zeros(0), np.zeros(0), np.zeros(0), str(self.problem.status)
        P = _sym(np.asarray(self.P.value))
        L = np.array([np.linalg.solve(P, Y.value) for Y in self.Y])
        return lam * P, L, lam * np.asarray(self.alpha.value), str(self.problem.status)


def _fail_search(system: System, search: list[tuple[float, float, str]]) -> DesignError:
    statuses = sorted({s for _, _, s in search})
    if all(s in (cp.INFEASIBLE, cp.INFEASIBLE_INACCURATE) for s in statuses):
        betas = f"{search[0][0]:g} .. {search[-1][0]:g}" if len(search) > 1 else f"{search[0][0]:g}"
        return DesignError(
            f"plant {system.name}: LMIs (14a)-(14b) infeasible for every beta tried ({betas}): "
            f"no common P exists for these modes; try another --beta, fewer modes, or check "
            f"that the modes' dynamics can share one quadratic Lyapunov function")
    return DesignError(
        f"plant {system.name}: solver {SOLVER} failed (status {', '.join(statuses)}); try "
        f"--beta to fix beta, a larger --margin, or rescale the plant's states to similar "
        f"magnitudes")


def design_qb(system: System, beta: float | None = None, *, margin: float = 1e-6,
              xatol: float = 1e-2, slack: float = 1e-4) -> QBDesign:
    """Design the QB (hybrid) Luenberger observer of ``system``.

    Parameters
    ----------
    system : System
        Linear (affine) modes, all continuous or all discrete time.
    beta : float, optional
        Fixed S-procedure multiplier (1/s in continuous time); default: searched to minimise
        rho_max.
    margin : float
        Strictness margin of the LMIs.
    xatol : float
        Tolerance of the search in log(beta).
    slack : float
        Relative give on lambda_min(P) allowed to the minimum-norm tie-break (rho_max grows by
        at most a factor 1/sqrt(1 - slack)).

    Returns
    -------
    QBDesign

    Raises
    ------
    DesignError
        Nonlinear modes, a mode that is not detectable (named), infeasible LMIs, a solver
        failure (with its status and what to try), or a result that fails verification.
    """
    model = qb_model(system)
    check_detectable(system, model)
    err: DesignError | None = None
    # The solver meets the LMIs to its own tolerance; when the verified point misses the
    # margin, solve again with a ten times larger margin (twice at most).
    for m in (margin, 10 * margin, 100 * margin):
        try:
            return _design(system, model, beta, m, xatol, slack)
        except _NotVerifiedError as exc:
            err = exc
    assert err is not None
    raise DesignError(str(err))


class _NotVerifiedError(DesignError):
    """The solver's point failed the independent check (retried with a larger margin)."""


def _design(system: System, model: QBModel, beta: float | None, margin: float, xatol: float,
            slack: float) -> QBDesign:
    if beta is not None and (not beta > 0 or (model.time == "discrete" and beta >= 1)):
        lim = "0 < beta < 1 in discrete time" if model.time == "discrete" else "beta > 0"
        raise DesignError(f"--beta: expected {lim}, got {beta}")
    prob = QBProblem(model, margin)
    search: list[tuple[float, float, str]] = []

    def lam_at(b: float) -> float:
        v, st = prob.solve(b)
        search.append((b, v, st))
        return v

    if beta is None:
        grid = _GRID_CONT if model.time == "continuous" else _GRID_DISC
        vals = np.array([lam_at(float(b)) for b in grid])
        if not np.any(np.isfinite(vals)):
            raise _fail_search(system, search)
        j = int(np.nanargmax(np.where(np.isfinite(vals), vals, -np.inf)))
        lo = math.log(grid[max(j - 1, 0)])
        hi = math.log(grid[min(j + 1, len(grid) - 1)])
        best_b, best_v = float(grid[j]), float(vals[j])
        if hi > lo:
            res = minimize_scalar(
                lambda lb: -(v if np.isfinite(v := lam_at(math.exp(lb))) else -1.0),
                bounds=(lo, hi), method="bounded", options={"xatol": xatol})
            if -float(res.fun) > best_v:
                best_b = math.exp(float(res.x))
        beta = best_b
    lam_opt, status = prob.solve(beta)
    search.append((beta, lam_opt, status))
    if not np.isfinite(lam_opt):
        raise _fail_search(system, [search[-1]])
    P1 = _sym(np.asarray(prob.P.value))
    L1 = np.array([np.linalg.solve(P1, Y.value) for Y in prob.Y])
    alpha1 = np.asarray(prob.alpha.value)
    P, L, alpha, st2 = _MinNormProblem(model, margin).solve(beta, lam_opt, slack, P1)
    tie_break = "minimum-norm"
    if st2 == cp.OPTIMAL:
        try:
            return _verified(system, model, P, L, _fit_alpha(alpha, beta), beta, search, prob,
                             tie_break)
        except _NotVerifiedError as exc:
            st2 = f"not verified ({exc})"
    # The tie-break is a refinement: when its solve is not optimal (or its point fails the
    # check) the verified optimum of step 5 is kept and the gain file says so.
    return _verified(system, model, P1, L1, _fit_alpha(alpha1, beta), beta, search, prob,
                     f"none (tie-break step: {st2})")


def _fit_alpha(alpha: np.ndarray, beta: float) -> np.ndarray:
    """Rounding in the solver may leave sum(alpha) a hair above beta; shrinking alpha keeps
    (14b) exact and moves the LMI by far less than its margin (checked after)."""
    if alpha.sum() > beta:
        alpha = alpha * (beta / alpha.sum()) * (1 - 1e-12)
    return alpha


def _verified(system: System, model: QBModel, P: np.ndarray, L: np.ndarray,
              alpha: np.ndarray, beta: float, search: list[tuple[float, float, str]],
              prob: QBProblem, tie_break: str) -> QBDesign:
    if float(np.linalg.eigvalsh(P)[0]) <= 0:
        raise DesignError(f"plant {system.name}: verification failed: P not positive definite")
    if np.any(alpha <= 0) or alpha.sum() > beta:
        raise DesignError(f"plant {system.name}: verification failed: (14b) sum(alpha) - beta "
                          f"= {alpha.sum() - beta:.3g}")
    eigs = [float(np.linalg.eigvalsh(M)[-1]) for M in lmi_blocks(model, P, L, alpha, beta)]
    absc = [spectral_abscissa(model.A[i] - L[i] @ model.C[i], model.time)
            for i in range(model.s)]
    for name, e, a in zip(model.mode_names, eigs, absc):
        if e >= 0:
            raise _NotVerifiedError(f"plant {system.name}: verification failed: mode {name!r}: LMI "
                              f"max eigenvalue {e:.3g} >= 0 at the solver's point; try a larger "
                              f"--margin")
        if (model.time == "continuous" and a >= 0) or (model.time == "discrete" and a >= 1):
            raise DesignError(f"plant {system.name}: verification failed: mode {name!r}: "
                              f"A - L C not stable (spectral abscissa {a:.4g})")
    solver = {"name": str(SOLVER), "status": "optimal", "time_s": round(prob.solve_time, 6),
              "solves": prob.solves + 1, "tie_break": tie_break}
    return QBDesign(model, P, L, alpha, float(beta), qb_bounds(model, P), eigs, absc, search,
                    solver)


def write_gain_file(path: str | Path, system: System, d: QBDesign,
                    fault_states: tuple[str, ...], parameters: dict[str, Any]) -> Path:
    """Write ``d`` as a QB gain file (results + certificate the loader re-verifies)."""
    idx = [system.states.index(s) for s in fault_states]
    results = {
        "time": d.model.time,
        "modes": list(system.mode_names),
        "L": {name: d.L[i] for i, name in enumerate(system.mode_names)},
        "P": d.P,
        "alpha": d.alpha,
        "alpha_channels": list(d.model.w_names),
        "beta": d.beta,
        "lambda_min": d.bounds["lambda_min"],
        "rho_max": d.bounds["rho_max"],
        "component_bound": d.bounds["component_bound"],
        "r_max": d.bounds["r_max"],
        "output_bound": d.bounds["output_bound"],
        "fault_states": list(fault_states),
        "fault_nominal": system.initial_state[idx],
    }
    cert = {
        "lmi": "(14a)-(14b)" if d.model.time == "continuous" else "discrete-time QB LMI",
        "lmi_max_eig": d.lmi_max_eig,
        "alpha_sum_minus_beta": float(d.alpha.sum() - d.beta),
        "P_min_eig": d.bounds["lambda_min"],
        "spectral_abscissa": d.spectral_abscissa,
    }
    return save_gains(path, "qb", system, parameters, results, cert, d.solver)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """QB options (SYSTEM, -o and --json are added by the design dispatcher)."""
    parser.add_argument("--beta", type=float, default=None,
                        help="fix the S-procedure multiplier beta (default: search for the "
                             "beta that minimises rho_max)")
    parser.add_argument("--margin", type=float, default=1e-6,
                        help="strictness margin of the LMIs (default 1e-6)")
    parser.add_argument("--fault-states", default=None, metavar="S1,S2",
                        help="states that model faults, monitored by the detector (default: "
                             "state_jump targets and states constant in every mode)")



def run(args: argparse.Namespace) -> int:
    """Design, verify, write the gain file and print a summary."""
    from fd_monitor.commands._common import emit

    system = load_system(args.system)
    if args.fault_states:
        fs = tuple(s.strip() for s in args.fault_states.split(",") if s.strip())
        unknown = [s for s in fs if s not in system.states]
        if unknown:
            raise DesignError(f"--fault-states: {unknown} are not states of {system.name} "
                              f"({', '.join(system.states)})")
    else:
        fs = default_fault_states(system)
    d = design_qb(system, args.beta, margin=args.margin)
    out = Path(args.output) if args.output else default_gain_path(system.name, "qb")
    params = {"beta": "search" if args.beta is None else args.beta, "margin": args.margin,
              "search": "grid + bounded Brent in log(beta), max lambda_min(P)",
              "tie_break": ("minimum |(P L_i)_i|_F, lambda_min(P) >= (1 - 1e-4) lambda*, "
                            "|P - P*|_F <= 1e-4 |P*|_F"),
              "fault_states": list(fs)}
    write_gain_file(out, system, d, fs, params)
    summary: dict[str, Any] = {
        "gain_file": str(out), "plant": system.name, "time": d.model.time,
        "beta": d.beta, "rho_max": d.rho_max, "lambda_min": d.bounds["lambda_min"],
        "alpha": np.round(d.alpha, 6).tolist(),
        "component_bound": dict(zip(system.states, np.round(d.bounds["component_bound"], 6)
                                    .tolist())),
        "r_max": float(np.max(d.bounds["r_max"])),
        "output_bound": dict(zip(system.outputs, np.round(np.max(d.bounds["output_bound"],
                                                                 axis=0), 6).tolist())),
        "lmi_max_eig": max(d.lmi_max_eig), "spectral_abscissa": max(d.spectral_abscissa),
        "solves": d.solver["solves"], "solve_time_s": d.solver["time_s"],
    }
    if args.json:
        summary["P"] = d.P
        summary["L"] = {n: d.L[i] for i, n in enumerate(system.mode_names)}
        summary["search"] = [{"beta": b, "lambda": v, "status": s} for b, v, s in d.search]
    emit(summary, args.json, title=f"QB design of {system.name} -> {out}")
    return 0
