"""Quadratic-boundedness (QB) observers at run time: hybrid Luenberger observer and QB detection.

Alessandri, Boem & Parisini, "Model-based fault detection and estimation for LTI and PWA
systems by using quadratic boundedness". The designer (:mod:`fd_monitor.design.qb`) solves the
LMIs; the model is :mod:`fd_monitor.core.qb_model`, the certificate
:mod:`fd_monitor.core.qb_certificate`; this module (numpy/scipy only) runs them:

* :class:`QBObserver` -- the hybrid Luenberger observer (13a)-(13b), discretised exactly (ZOH
  with u and y held over the sample) when the design is continuous;
* :class:`QBDetector` -- alarms when a fault-model state estimate leaves its bound (eq. 8, or
  the per-component bound) or a residual leaves its bound (eq. 11, or the per-output bound);
* :func:`run_batch` -- both, vectorised over a batch of simulated runs (also with a hybrid
  Kalman filter as the estimator, for the paper's comparison).

Discrete-time counterpart (plants given in discrete time). With ``e_{k+1} = Phi e_k + G w_k``,
``Phi = A - L C``, ``G = D - L E``, QB asks ``V(e_{k+1}) < V(e_k)`` whenever ``V(e_k) >= 1``
and ``w_j^2 <= 1``, ``V(e) = e' P e``. The S-procedure (multipliers beta, alpha_j >= 0) gives
the sufficient condition ``V(e_{k+1}) - (1 - beta) V(e_k) - sum alpha_j w_j^2 + (sum alpha_j -
beta) < 0`` for all (e, w), i.e. ``sum alpha_j <= beta`` and
``[Phi'P Phi - (1-beta) P, Phi'P G; G'P Phi, G'P G - diag(alpha)] < 0``; a Schur complement
with ``Y = P L`` makes it the LMI ::

    [ -(1-beta) P        0           (PA - YC)' ]
    [      0       -diag(alpha)      (PD - YE)' ]  < 0,   sum_j alpha_j - beta <= 0,  0 < beta < 1.
    [  PA - YC        PD - YE            -P     ]

It gives ``V(e_{k+1}) <= (1-beta) V(e_k) + beta`` so the ellipsoid ``e'Pe <= 1`` is positively
invariant and attractive, and (6), (8), (11) hold as in continuous time.

Why one module of ~520 lines: the QB observer, its detector and the batch and stress
runs that the certificate tests drive are one runtime; the observer class alone is 150 lines.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from fd_monitor.core.batch import BatchResult
from fd_monitor.core.filters import linear_map
from fd_monitor.core.gap import gap_values
from fd_monitor.core.kalman import kalman_gains
from fd_monitor.core.plant import SampledPlant, zoh
from fd_monitor.core.plausibility import Plausibility
from fd_monitor.core.qb_certificate import gains_matrices, gains_model
from fd_monitor.core.qb_model import QBModel, default_fault_states, qb_model
from fd_monitor.model.system import System

__all__ = [
    "observer_matrices",
    "QBObserver",
    "QBDetector",
    "run_batch",
    "STRESS_POLICIES",
    "stress_runs",
]


def observer_matrices(model: QBModel, L: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Per-mode update ``x_{k+1} = Phi_i x_k + Gam_i [u_k; y_k; 1]`` of the observer (13a).

    Continuous designs are discretised exactly (zero-order hold: u and y held over the
    sample): ``Phi_i = e^{(A_i - L_i C_i) dt}``, ``Gam_i = int_0^dt e^{(A_i - L_i C_i) s} ds
    [B_i, L_i, c_i]``. Discrete designs: ``Phi_i = A_i - L_i C_i``, ``Gam_i = [B_i, L_i, c_i]``.

    Parameters
    ----------
    model : QBModel
    L : numpy.ndarray
        (s, n, ny) gains.
    dt : float
        Sample time, s.

    Returns
    -------
    Phi : numpy.ndarray
        (s, n, n)
    Gam : numpy.ndarray
        (s, n, nu + ny + 1)
    """
    Phis, Gams = [], []
    for i in range(model.s):
        F = model.A[i] - L[i] @ model.C[i]
        G = np.column_stack([model.B[i], L[i], model.offset[i]])
        if model.time == "continuous":
            Phi, Gam = zoh(F, G, dt)
            Phis.append(Phi)
            Gams.append(Gam)
        else:
            Phis.append(F)
            Gams.append(G)
    return np.array(Phis), np.array(Gams)


def _as_array(x: Any, shape: tuple[int, ...], what: str) -> np.ndarray:
    a = np.asarray(x, dtype=float)
    if a.shape != shape:
        raise ValueError(f"{what}: expected shape {shape}, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{what}: NaN or Inf")
    return a


class QBObserver:
    """Hybrid Luenberger observer (13a)-(13b) for one run, step by step.

    ``step(k, u, y)`` takes the measurement of sample k and returns the estimate at sample k
    (the prediction from samples < k, which is what the QB bounds hold for) and the mode used;
    it then advances to k + 1: ``x_{k+1} = Phi_m x_k + Gam_m [u_k; y_k; 1]`` and the mode is
    predicted from the estimate through the plant's guards (13b): controlled guards on
    ``u_k``, then autonomous guards on ``x_{k+1}``.

    Parameters
    ----------
    system : System
    gains : GainFile
        A QB gain file (``method: qb``) for ``system``.
    x0 : numpy.ndarray, optional
        (n,) initial estimate; default zeros.
    mode0 : int, optional
        Initial mode estimate; default the plant's initial mode.
    L : numpy.ndarray, optional
        (s, n, ny) gains overriding the file's (used by the Kalman baseline).
    """

    def __init__(self, system: System, gains: Any, x0: np.ndarray | None = None,
                 mode0: int | None = None, L: np.ndarray | None = None,
                 matrices: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        self.system = system
        self.model = gains_model(system, gains.results) if gains is not None else qb_model(system)
        if matrices is None:
            if L is None:
                L = gains_matrices(system, gains.results)[1]
            matrices = observer_matrices(self.model, L, system.sample_time)
        self.Phi, self.Gam = matrices
        self._plant = SampledPlant(system)
        self.x = (np.zeros(system.n) if x0 is None
                  else _as_array(x0, (system.n,), "x0")).copy()
        self.mode = system.initial_mode if mode0 is None else int(mode0)
        self.k: int | None = None
        self.plausibility = Plausibility(system)
        self._held: tuple[Any, Any] | None = None
        self._f1: list[tuple[Any, Any, Any]] | None = None

    def _floats(self) -> list[tuple[Any, Any, Any]]:
        """Per mode ``x -> Phi x``, ``z -> Gam z`` and ``x -> C x`` on Python floats (built
        at the first single-stream step)."""
        if self._f1 is None:
            def lm(M: np.ndarray) -> Any:
                return linear_map([[(M[i, j], j) for j in range(M.shape[1])]
                                   for i in range(M.shape[0])])
            self._f1 = [(lm(self.Phi[q]), lm(self.Gam[q]), lm(self.model.C[q]))
                        for q in range(self.Phi.shape[0])]
        return self._f1

    def step1(self, k: int, u: list[float], y: list[float]
              ) -> tuple[int, np.ndarray, list[float]]:
        """:meth:`step` of validated Python floats (one stream): (mode, x^ (n,), r (ny,) as
        floats). The same recursion as :meth:`step` summed left to right in Python
        (numpy's matrix-vector products may round differently in the last bit)."""
        if self.k is not None and k != self.k + 1:
            raise ValueError(f"QBObserver.step: sample {k} after {self.k}: samples must be "
                             f"consecutive (reset the observer after a gap)")
        self.plausibility.check(k, u, y)
        mode, x = self.mode, self.x
        fphi, fgam, fc = self._floats()[mode]
        xl = x.tolist()
        r = [a - b for a, b in zip(y, fc(xl))]
        xn = [a + b for a, b in zip(fphi(xl), fgam(u + y + [1.0]))]
        q = self._plant.next_mode1(mode, (), u, "controlled")
        q = self._plant.next_mode1(q, xn, u, "autonomous")
        self.x, self.mode = np.array(xn), q
        self.k, self._held = k, (u, y)
        return mode, x, r

    @property
    def channels(self) -> tuple[str, ...]:
        """Names of the published estimate: ``mode`` then the states."""
        return ("mode", *self.system.states)

    def step(self, k: int, u: Any, y: Any) -> tuple[int, np.ndarray]:
        """Process sample ``k``.

        Parameters
        ----------
        k : int
            Sample index; must increase by one per call (a gap raises ValueError).
        u : array_like
            (nu,) inputs at sample k.
        y : array_like
            (ny,) measurements at sample k, output units.

        Returns
        -------
        mode_hat : int
            Estimated mode at sample k.
        x_hat : numpy.ndarray
            (n,) state estimate at sample k, state units.
        """
        sys_ = self.system
        if self.k is not None and k != self.k + 1:
            raise ValueError(f"QBObserver.step: sample {k} after {self.k}: samples must be "
                             f"consecutive (reset the observer after a gap)")
        if type(u) is np.ndarray and type(y) is np.ndarray and u.dtype == y.dtype == float \
                and u.shape == (sys_.nu,) and y.shape == (sys_.ny,) \
                and all(map(math.isfinite, u.tolist() + y.tolist())):
            uu, yy = u, y                        # validated by the caller (the runtime)
        else:
            uu = _as_array(u, (sys_.nu,), "u")
            yy = _as_array(y, (sys_.ny,), "y")
        # Range test only: the estimate converges from x0, it is no one-sample prediction.
        self.plausibility.check(k, uu, yy)
        mode, x = self.mode, self.x.copy()
        self._advance(uu, yy)
        self.k, self._held = k, (uu, yy)
        return mode, x

    def _advance(self, uu: np.ndarray, yy: np.ndarray) -> None:
        """x_{k+1} and the mode of k + 1 from (u_k, y_k) (13a)-(13b), on the float maps of
        :meth:`step1`: one recursion for every caller (node, runtime, bridge), so the observer
        node and the offline runtime give the same bits."""
        mode = self.mode
        fphi, fgam, _ = self._floats()[mode]
        ul, yl = uu.tolist(), yy.tolist()
        xn = [a + b for a, b in zip(fphi(self.x.tolist()), fgam(ul + yl + [1.0]))]
        # the plant's guards on one run (SampledPlant.next_mode's comparisons, on floats)
        q = self._plant.next_mode1(mode, (), ul, "controlled")
        q = self._plant.next_mode1(q, xn, ul, "autonomous")
        self.x, self.mode = np.array(xn), q

    def bridge(self, k: int, u: Any, y: Any) -> None:
        """The next sample is ``(k, u_k, y_k)``, those between are lost: predict through the
        gap, (13a)-(13b) once per lost sample on u and y interpolated between the last
        sample and this one (:mod:`fd_monitor.core.gap`), so x^ -- the fault-model states
        with it -- and the mode estimate carry over. Nothing before the first sample; an
        implausible sample raises before anything changes.
        """
        uu = _as_array(u, (self.system.nu,), "u")
        yy = _as_array(y, (self.system.ny,), "y")
        self.plausibility.check(k, uu, yy)
        if self.k is None or self._held is None or int(k) <= self.k + 1:
            return
        u0, y0 = self._held
        missing = int(k) - self.k - 1
        for uj, yj in zip(gap_values(u0, uu, missing), gap_values(y0, yy, missing)):
            self._advance(uj, yj)
        self.k = int(k) - 1

    def residual(self, mode: int, x_hat: np.ndarray, y: Any) -> np.ndarray:
        """(ny,) residual ``r = y - C_mode x_hat`` (Remark 1), output units, summed as
        :meth:`step1` sums it (the detector node computes it from the published x^)."""
        fc = self._floats()[mode][2]
        return np.array([a - b for a, b in zip(np.asarray(y, dtype=float).tolist(),
                                               fc(np.asarray(x_hat, dtype=float).tolist()))])


class QBDetector:
    """QB fault detection: compare estimates and residuals with guaranteed bounds times rho.

    Channels, in order: one per fault-model state ``j`` (its name):
    ``|x_hat_j - x_nom_j| > rho * bound_j`` with ``bound_j = sqrt((P^-1)_jj)`` (per-component
    bound, ``state_bound="component"``) or ``rho_max`` (eq. 8, ``state_bound="rho_max"``);
    ``fault_norm``: ``|x_hat_F - x_nom_F| > rho * rho_max`` (eq. 8 on the fault-model states);
    one per output ``r_<name>``: ``|r_i| > rho * output_bound_i``; ``r_norm``: ``|r| > rho *
    r_max`` (eq. 11). Bounds hold after the transient of the observer (eq. 5).

    Parameters
    ----------
    system : System
    gains : GainFile
        A QB gain file for ``system``.
    rho : float
        Threshold scale (Table II's rho); 1 gives the guaranteed bounds.
    state_bound : str
        ``"component"`` or ``"rho_max"``.
    """

    def __init__(self, system: System, gains: Any, rho: float = 1.0,
                 state_bound: str = "component") -> None:
        if state_bound not in ("component", "rho_max"):
            raise ValueError(f"state_bound: expected 'component' or 'rho_max', got "
                             f"{state_bound!r}")
        if not rho > 0:
            raise ValueError(f"rho: expected > 0, got {rho}")
        res = gains.results
        self.system = system
        self.rho = float(rho)
        names = list(res.get("fault_states", default_fault_states(system)))
        self.fault_idx = np.array([system.states.index(s) for s in names], dtype=int)
        nominal = res.get("fault_nominal")
        self.nominal = (np.asarray(nominal, dtype=float).reshape(-1) if nominal is not None
                        else system.initial_state[self.fault_idx])
        rho_max = float(res["rho_max"])
        comp = np.asarray(res["component_bound"], dtype=float)
        self.state_bounds = (comp[self.fault_idx] if state_bound == "component"
                             else np.full(len(names), rho_max))
        self.rho_max = rho_max
        self.output_bound = np.atleast_2d(np.asarray(res["output_bound"], dtype=float))
        self.r_max = np.atleast_1d(np.asarray(res["r_max"], dtype=float))
        self.channels: tuple[str, ...] = (*names, "fault_norm",
                                          *(f"r_{o}" for o in system.outputs), "r_norm")

    def bounds(self, mode: int | np.ndarray) -> np.ndarray:
        """Unscaled thresholds per channel: (n_channels,) for one mode, (N, n_channels) for a
        batch of modes (N,)."""
        m = np.asarray(mode)
        nf = len(self.fault_idx)
        head = np.concatenate([self.state_bounds, [self.rho_max]])
        if m.ndim == 0:
            return np.concatenate([head, self.output_bound[int(m)], [self.r_max[int(m)]]])
        return np.column_stack([np.tile(head, (m.shape[0], 1)), self.output_bound[m],
                                self.r_max[m]]).reshape(m.shape[0], nf + 2 + self.system.ny)

    def signals(self, x_hat: np.ndarray, residual: np.ndarray) -> np.ndarray:
        """Compared signals per channel (absolute values): x_hat (..., n), residual (..., ny)
        -> (..., n_channels)."""
        d = x_hat[..., self.fault_idx] - self.nominal
        return np.concatenate([np.abs(d), np.linalg.norm(d, axis=-1, keepdims=True),
                               np.abs(residual),
                               np.linalg.norm(residual, axis=-1, keepdims=True)], axis=-1)

    def step(self, x_hat: Any, residual: Any, mode: int = 0) -> np.ndarray:
        """Alarms of one sample.

        Parameters
        ----------
        x_hat : array_like
            (n,) state estimate at the sample.
        residual : array_like
            (ny,) residual ``y - C x_hat``.
        mode : int
            Estimated mode (selects the residual bounds of that mode's C and E).

        Returns
        -------
        numpy.ndarray
            (n_channels,) bool alarm per channel (see :attr:`channels`).
        """
        sig = self.signals(np.asarray(x_hat, dtype=float), np.asarray(residual, dtype=float))
        return np.asarray(sig > self.rho * self.bounds(mode))


def run_batch(system: System, gains: Any, traj: Any, *, rho: float = 1.0,
              state_bound: str = "component", estimator: str = "qb",
              kalman: Mapping[str, Any] | None = None,
              x0: np.ndarray | None = None) -> BatchResult:
    """Run the hybrid observer and the QB detector over a batch of simulated runs.

    Parameters
    ----------
    system : System
    gains : GainFile
        QB gain file for ``system`` (its bounds are the thresholds).
    traj : Trajectory
        Simulated batch: ``u`` (N, K, nu), ``y`` (N, K, ny).
    rho : float
        Threshold scale.
    state_bound : str
        See :class:`QBDetector`.
    estimator : str
        ``"qb"`` (the designed hybrid Luenberger observer) or ``"kalman"`` (the hybrid Kalman
        filter baseline of :mod:`fd_monitor.core.kalman`, same mode predictor and thresholds).
    kalman : mapping, optional
        Keyword arguments of :func:`fd_monitor.core.kalman.kalman_gains`.
    x0 : numpy.ndarray, optional
        (n,) initial estimate of every run; default zeros.

    Returns
    -------
    BatchResult
        ``alarm`` (N, K, n_channels); ``residual`` the compared signals; ``threshold``
        (N, K, n_channels) the unscaled bounds (``alarm = residual > rho * threshold``;
        ``extra["threshold_scalable"]`` is True); ``x_hat`` (N, K, n); ``mode_hat`` (N, K).
    """
    model = gains_model(system, gains.results)
    if estimator == "qb":
        L = gains_matrices(system, gains.results)[1]
        Phi, Gam = observer_matrices(model, L, system.sample_time)
    elif estimator == "kalman":
        Phi, Gam = kalman_gains(system, **dict(kalman or {})).matrices
    else:
        raise ValueError(f"estimator: expected 'qb' or 'kalman', got {estimator!r}")
    det = QBDetector(system, gains, rho=rho, state_bound=state_bound)
    u, y = np.asarray(traj.u, dtype=float), np.asarray(traj.y, dtype=float)
    N, K = y.shape[:2]
    plant = SampledPlant(system)
    xh = np.zeros((N, system.n)) if x0 is None else np.tile(np.asarray(x0, float), (N, 1))
    qh = np.full(N, system.initial_mode, dtype=int)
    X = np.empty((N, K, system.n))
    Q = np.empty((N, K), dtype=int)
    r = np.empty((N, K, system.ny))
    n, ny, s = system.n, system.ny, model.s
    # One matmul per sample for every mode at once: [x; u; y; 1] -> (x_next, C x) per mode,
    # then pick each run's mode; cheaper than gathering a matrix per run.
    M = np.concatenate([np.concatenate([Phi, Gam], axis=2),
                        np.concatenate([model.C, np.zeros((s, ny, Gam.shape[2]))], axis=2)],
                       axis=1)                                   # (s, n + ny, n + nu + ny + 1)
    MT = M.reshape(s * (n + ny), -1).T
    v = np.empty((N, MT.shape[0]))
    v[:, -1] = 1.0
    rows = np.arange(N)
    has_controlled = any(g.kind == "controlled" for g in system.guards)
    for k in range(K):
        X[:, k], Q[:, k] = xh, qh
        v[:, :n], v[:, n:n + system.nu], v[:, n + system.nu:-1] = xh, u[:, k], y[:, k]
        out = (v @ MT).reshape(N, s, n + ny)[rows, qh]
        r[:, k] = y[:, k] - out[:, n:]
        xn = out[:, :n]
        qm = plant.next_mode(qh, xh, u[:, k], "controlled") if has_controlled else qh
        qh = plant.next_mode(qm, xn, u[:, k], "autonomous")
        xh = xn
    sig = det.signals(X, r)
    thr = det.bounds(Q.reshape(-1)).reshape(N, K, -1)
    return BatchResult(alarm=sig > rho * thr, channels=det.channels, residual=sig,
                       threshold=thr, x_hat=X, mode_hat=Q,
                       extra={"threshold_scalable": True, "estimator": estimator,
                              "rho": rho, "state_bound": state_bound})


#: Disturbance policies of :func:`stress_runs`.
STRESS_POLICIES = ("uniform", "extreme", "held", "adversarial")


def stress_runs(system: System, gains: Any, policy: str, n_runs: int, n_samples: int,
                seed: int = 0, hold_prob: float = 0.002) -> dict[str, np.ndarray]:
    """Fault-free sampled runs of an autonomous plant under extreme disturbance policies.

    The plant is the exact sampled plant (:class:`~fd_monitor.core.plant.SampledPlant`,
    ``y_k = C x_k + E w_k``, w held over each sample), started from the plant file's initial
    state, with the unit-bounded disturbance ``w_k`` (the plant's w times its bound) drawn by
    ``policy``:

    * ``uniform``: uniform in the box, redrawn every sample (the simulator's default);
    * ``extreme``: a random vertex of the box every sample;
    * ``held``: a random vertex held, switched to another random vertex with probability
      ``hold_prob`` per sample (slow switching lets the state settle at the box's extremes);
    * ``adversarial``: the vertex that maximises ``V(e_{k+1}) = e_{k+1}'P e_{k+1}`` of the
      gain file's observer as it runs (true next state minus the runtime's next estimate,
      for every vertex), greedy.

    Parameters
    ----------
    system : System
        Autonomous plant (no inputs) with linear modes.
    gains : GainFile
        QB gain file (its observer is the one attacked by ``adversarial``).
    policy : str
        One of :data:`STRESS_POLICIES`.
    n_runs, n_samples : int
    seed : int

    Returns
    -------
    dict
        ``x`` (N, K, n) true states, ``y`` (N, K, ny), ``u`` (N, K, 0), ``mode`` (N, K) true
        modes, ``w`` (N, K, nw) unit-bounded disturbances.
    """
    if policy not in STRESS_POLICIES:
        raise ValueError(f"policy: expected one of {STRESS_POLICIES}, got {policy!r}")
    if system.nu:
        raise ValueError(f"stress_runs: plant {system.name} has inputs; only autonomous plants")
    model = gains_model(system, gains.results)
    P, L, _, _ = gains_matrices(system, gains.results)
    Phi, Gam = observer_matrices(model, L, system.sample_time)
    plant = SampledPlant(system)
    rng = np.random.default_rng(np.random.SeedSequence(seed))
    N, K, n, nw = n_runs, n_samples, system.n, len(system.disturbances)
    wbar = np.asarray(system.disturbance_bound, dtype=float)
    verts = np.array(np.meshgrid(*([[-1.0, 1.0]] * nw), indexing="ij")).reshape(nw, -1).T
    x = np.tile(system.initial_state, (N, 1)).astype(float)
    q = np.full(N, system.initial_mode, dtype=int)
    xh, qh = np.zeros((N, n)), q.copy()
    u0 = np.zeros((N, 0))
    held = verts[rng.integers(len(verts), size=N)]
    out = {"x": np.empty((N, K, n)), "y": np.empty((N, K, system.ny)),
           "u": np.empty((N, K, 0)), "mode": np.empty((N, K), dtype=int),
           "w": np.empty((N, K, nw))}
    for k in range(K):
        if policy == "adversarial":
            w = verts[_adversarial_vertex(plant, P, Phi, Gam, verts * wbar, q, x, qh, xh)]
        else:
            w = _random_disturbance(policy, rng, verts, held, hold_prob, N)
        y = plant.output(q, x, w * wbar)
        out["x"][:, k], out["y"][:, k], out["mode"][:, k], out["w"][:, k] = x, y, q, w
        z = np.concatenate([y, np.ones((N, 1))], axis=1)
        xh_next = np.einsum("nij,nj->ni", Phi[qh], xh) + np.einsum("nij,nj->ni", Gam[qh], z)
        qh = plant.next_mode(qh, xh_next, u0, "autonomous")
        xh = xh_next
        x_next = plant.step(q, x, u0, w * wbar)
        q = plant.next_mode(q, x_next, u0, "autonomous")
        x = x_next
    return out


def _random_disturbance(policy: str, rng: np.random.Generator, verts: np.ndarray,
                        held: np.ndarray, hold_prob: float, N: int) -> np.ndarray:
    """(N, nw) unit-bounded disturbance of one sample under ``uniform``, ``extreme`` or
    ``held`` (updates ``held`` (N, nw) in place); ``verts`` (2^nw, nw) the box's vertices."""
    if policy == "uniform":
        return rng.uniform(-1.0, 1.0, size=(N, verts.shape[1]))
    if policy == "extreme":
        return verts[rng.integers(len(verts), size=N)]
    sw = rng.random(N) < hold_prob
    held[sw] = verts[rng.integers(len(verts), size=int(sw.sum()))]
    return held


def _adversarial_vertex(plant: SampledPlant, P: np.ndarray, Phi: np.ndarray, Gam: np.ndarray,
                        wv1: np.ndarray, q: np.ndarray, x: np.ndarray, qh: np.ndarray,
                        xh: np.ndarray) -> np.ndarray:
    """(N,) index of the disturbance vertex (rows of ``wv1`` (nv, nw), scaled by the bound)
    that maximises ``V(e_{k+1}) = e_{k+1}' P e_{k+1}``: for every run and vertex, the next
    true state minus the observer's next estimate (the runtime's map), greedy."""
    N, nv = x.shape[0], wv1.shape[0]
    wv = np.tile(wv1, (N, 1))
    qv, xv = np.repeat(q, nv), np.repeat(x, nv, axis=0)
    yv = plant.output(qv, xv, wv)
    zv = np.concatenate([yv, np.ones((N * nv, 1))], axis=1)
    qhv = np.repeat(qh, nv)
    ev = (plant.step(qv, xv, np.zeros((N * nv, 0)), wv)
          - np.einsum("nij,nj->ni", Phi[qhv], np.repeat(xh, nv, axis=0))
          - np.einsum("nij,nj->ni", Gam[qhv], zv))
    Vv = np.einsum("ni,ij,nj->n", ev, P, ev).reshape(N, nv)
    return np.asarray(Vv.argmax(axis=1))
