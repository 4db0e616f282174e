"""The sensor-bias diagnosis chain composed: observer -> detector -> AGEI -> estimator.

Per sample k with ``(u_k, y_k)`` (Heracleous et al., Fig. 2):

1. :class:`~fd_monitor.core.hybrid_observer.HybridObserver` uses ``y~_k = y_k - sigma^_k``
   (``sigma^_k`` from the estimator at k - 1) and the AGEI trigger decided at k - 1, outputs
   ``(q^_k, x^_k, y~_k)`` and prepares ``x^_{k+1} = f(q^_k, y~_k, u_k)`` (eq. 6).
2. :class:`~fd_monitor.core.detector.ResidualDetector`: ``r_k = H[y~]_k - H[x^]_k``, threshold
   ``R_k`` (nominal for q^_k, or the AGEI override decided at k - 1), ``alarm_k``.
3. :class:`~fd_monitor.core.agei.Agei`: from ``q^_k``, ``w_k = H[y~]_k``, ``r_k`` and the
   nominal threshold decides the guard trigger and the threshold override (used at k + 1).
4. :class:`~fd_monitor.core.bias_estimator.BiasEstimator`: starts at the first alarm; from
   ``(k, u_k, y_k, q^_k, alarm_k, mode_uncertain_k)`` (the last from AGEI at k) produces
   ``sigma^_{k+1}`` and isolation flags.

Feedback edges (AGEI -> observer, AGEI -> detector, estimator -> observer) have exactly one
sample of delay, and every component is a deterministic function of its inputs and its own
past, so five processes joining messages on the sample stamp compute the same bits as
:meth:`Monitor.step` (each component's arithmetic does not depend on the batch size either:
:func:`run_batch` gives the same numbers per run).

Each output's ``payload()`` gives its values by field name (no topic, no label):

==============  ==========================================================================
output          fields
==============  ==========================================================================
ObserverOutput  mode, x_hat (states), y_tilde
DetectorOutput  residual, w, threshold (in force), nominal, alarm (0/1)
AgeiOutput      trigger (guard index or -1), phase, row, mode_uncertain, override (NaN = none)
BiasOutput      sigma_hat (sigma^_{k+1}), isolated, active, k_detect
==============  ==========================================================================

The topics carrying them, and their labels, are declared in :mod:`fd_monitor.wire.topics`.

Invalid samples (NaN/Inf, wrong length, non-consecutive k) raise
:class:`~fd_monitor.model.errors.MessageError` from :func:`validate_sample` before any state
changes.
"""

from __future__ import annotations

from math import isfinite
from typing import Any

import numpy as np

from fd_monitor.core.agei import Agei, AgeiOutput
from fd_monitor.core.batch import BatchResult
from fd_monitor.core.bias_estimator import BiasEstimator, BiasOutput
from fd_monitor.core.detector import DetectorOutput, ResidualDetector, no_override
from fd_monitor.core.hybrid_observer import NO_TRIGGER, HybridObserver, ObserverOutput
from fd_monitor.core.lazy import Output
from fd_monitor.core.thresholds import DiagnosisGains, as_gains
from fd_monitor.model.errors import MessageError
from fd_monitor.model.system import System

#: numpy's float64 dtype (the usual object: an identity test; others compare by value)
_F64 = np.dtype(np.float64)

__all__ = ["Monitor", "MonitorOutput", "BatchMonitor", "run_batch", "sample_floats",
           "validate_sample", "validate_vector"]


def validate_vector(name: str, v: Any, length: int, k: int | None = None) -> np.ndarray:
    """Return ``v`` as a float (length,) array or raise :class:`MessageError`.

    Parameters
    ----------
    name : str
        What it is (for the message), e.g. ``"y"``.
    v : array_like
    length : int
        Expected number of values.
    k : int, optional
        Sample index (for the message).
    """
    at = f" at sample {k}" if k is not None else ""
    try:
        a = np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        raise MessageError(f"{name}{at}: expected {length} numbers, got {v!r:.60}") from None
    if a.ndim != 1 or a.shape[0] != length:
        raise MessageError(f"{name}{at}: expected {length} values, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        bad = [i for i in range(length) if not np.isfinite(a[i])]
        raise MessageError(f"{name}{at}: non-finite value (NaN/Inf) at index {bad}")
    return a


def validate_sample(system: System, k: Any, u: Any, y: Any,
                    expected_k: int | None = None) -> tuple[int, np.ndarray, np.ndarray]:
    """Check one sample ``(k, u_k, y_k)`` of ``system``; raise :class:`MessageError` if invalid.

    Parameters
    ----------
    system : System
    k : int
        Sample index (an integral number >= 0).
    u : array_like
        (nu,) inputs.
    y : array_like
        (ny,) measurements.
    expected_k : int, optional
        When given, k must equal it (consecutive samples: the observer's one-step prediction).

    Returns
    -------
    (int, numpy.ndarray, numpy.ndarray)
    """
    try:
        kf = float(k)
    except (TypeError, ValueError):
        raise MessageError(f"sample index: expected an integer, got {k!r}") from None
    if not np.isfinite(kf) or kf != int(kf) or kf < 0:
        raise MessageError(f"sample index: expected an integer >= 0, got {k!r}")
    ki = int(kf)
    if expected_k is not None and ki != expected_k:
        raise MessageError(f"sample index: expected {expected_k} (consecutive samples), got "
                           f"{ki}; call reset() to restart the monitor")
    return (ki, validate_vector("u", u, system.nu, ki), validate_vector("y", y, system.ny, ki))


class MonitorOutput(Output):
    """Everything the chain produces at sample k.

    Attributes
    ----------
    k : int
    observer : ObserverOutput
    detector : DetectorOutput
    agei : AgeiOutput
    estimator : BiasOutput
    """

    __slots__ = ("agei", "detector", "estimator", "k", "observer")
    FIELDS = ("k", "observer", "detector", "agei", "estimator")

    def __init__(self, k: int, observer: ObserverOutput, detector: DetectorOutput,
                 agei: AgeiOutput, estimator: BiasOutput) -> None:
        self.k, self.observer, self.detector, self.agei = k, observer, detector, agei
        self.estimator = estimator

    @property
    def alarm(self) -> np.ndarray:
        """(ny,) bool alarm flags at k."""
        return self.detector.alarm

    @property
    def outside(self) -> np.ndarray | None:
        """(n + nu,) excess of x^_k, u_k over the certified region (None: no region)."""
        return self.observer.outside

    @property
    def mode(self) -> int:
        """q^_k."""
        m = self.observer.mode
        return m if type(m) is int else int(np.asarray(m))

    @property
    def sigma_hat(self) -> np.ndarray:
        """(ny,) sigma^_{k+1}."""
        return self.estimator.sigma_hat


class Monitor:
    """The diagnosis chain for one stream of samples.

    Parameters
    ----------
    system : System
        Full-state measured plant (y = x + v).
    gains : DiagnosisGains or GainFile
        A ``thresholds`` gain file (loaded with :func:`fd_monitor.core.methods.load_gains`).
    agei : bool
        False: ablation without AGEI (the observer never executes autonomous transitions and
        the nominal thresholds are always used).
    """

    def __init__(self, system: System, gains: Any, agei: bool = True) -> None:
        self.system = system
        self.gains: DiagnosisGains = as_gains(system, gains)
        self.observer = HybridObserver(system, region=self.gains.region)
        self.detector = ResidualDetector(system, self.gains)
        self.agei = Agei(system, self.gains, enabled=agei)
        self.estimator = BiasEstimator(system, self.gains)
        self._nu, self._ny = system.nu, system.ny
        self.reset()

    def reset(self) -> None:
        """Restart from scratch (the next sample may have any k)."""
        for c in (self.observer, self.detector, self.agei, self.estimator):
            c.reset()
        self._k_next: int | None = None
        self._sigma = [0.0] * self.system.ny
        self._trigger = NO_TRIGGER
        self._override: list[float] | None = None     # AGEI's threshold override (None: none)

    def bridge(self, k: int, u: Any, y: Any) -> None:
        """The next sample is ``(k, u_k, y_k)``; the samples since the last one are lost (a
        short hole). :meth:`step` on it follows.

        * The observer re-initialises x^ from the next compensated measurement, ``x^_k =
          y_k - sigma^`` (the paper's ``x^_0 = y~_0``: bias-corrected, so an accommodated
          bias is not absorbed), keeping its mode estimate.
        * The residual filters start again in the steady state of their first input, as at
          the first sample (``r_k = 0``). Keeping their history instead breaks the
          cancellation of consecutive noise samples the thresholds rely on (``y~_k - x^_k``
          is 0 at the bridge, not ``v_k - J v_{k-1}``): on three_tank_bad_input the one
          bridged sample alarmed h3 five samples later.
        * AGEI keeps its phase (its override stays in force).
        * The estimator keeps sigma^, K_d and its isolation, and predicts its state through
          the gap (or, before detection, fills its delayed buffer): see
          :meth:`~fd_monitor.core.bias_estimator.BiasEstimator.bridge`.
        * The feedback in force (sigma^, trigger, override: what the last sample decided) is
          used at k.

        Nothing before the first sample.

        Raises
        ------
        MessageError
            A sample :meth:`step` would refuse (invalid; implausible: out of the plant's
            range); nothing has changed.
        """
        k, uu, yy = validate_sample(self.system, k, u, y)
        self.observer.plausibility.check(k, uu, yy)
        if self._k_next is None or k <= self._k_next:
            return                               # nothing before it, or nothing lost
        self.observer.bridge()
        self.detector.reset()
        self.estimator.bridge(k, uu, yy)
        self._k_next = k

    def step(self, k: int, u: Any, y: Any) -> MonitorOutput:
        """Process sample k.

        Parameters
        ----------
        k : int
            Sample index; consecutive after the first call (or :meth:`bridge`).
        u : array_like
            (nu,) inputs u_k.
        y : array_like
            (ny,) measurements y_k, output units.

        Returns
        -------
        MonitorOutput

        Raises
        ------
        MessageError
            Invalid sample; no state has changed.
        """
        # The components' single-stream paths on Python floats (``step1``): the arithmetic
        # of the batch path for one run, bit for bit, without numpy calls per sample.
        if type(k) is not int or k < 0 or (self._k_next is not None and k != self._k_next):
            k = validate_sample(self.system, k, u, y, self._k_next)[0]
        uf = sample_floats("u", u, self._nu, k)
        yf = sample_floats("y", y, self._ny, k)
        obs, x_hat, y_t = self.observer.step1(k, uf, yf, self._sigma, self._trigger)
        q: int = obs.mode                        # type: ignore[assignment]  # one stream: int
        det, r, w, nominal, alarm = self.detector.step1(k, y_t, x_hat, q, self._override)
        ag, ov = self.agei.step1(k, q, w, r, nominal)
        self._override = ov if ag.row >= 0 else None
        hold: bool = ag.mode_uncertain           # type: ignore[assignment]  # one stream
        if self.estimator._fast:
            est, self._sigma = self.estimator.step1(k, uf, yf, q, alarm, hold)
        else:
            est = self.estimator.step(k, np.array(uf), np.array(yf), q, det.alarm, hold)
            self._sigma = est.sigma_hat.tolist()
        self._trigger = ag.trigger               # type: ignore[assignment]  # one stream
        self._k_next = k + 1
        return MonitorOutput(k, obs, det, ag, est)


#: (float,) * n by n: the types of a list of n Python floats
_FLOATS: dict[int, tuple[type, ...]] = {}


def sample_floats(name: str, v: Any, length: int, k: int) -> list[float]:
    """``v`` as ``length`` finite Python floats, or :class:`MessageError` as
    :func:`validate_vector` words it (the single-stream runtimes' entry check: a float64
    array or a list of floats is taken without a numpy call per value)."""
    # Lists of exactly ``length`` Python floats, and float64 vectors of that shape, with a
    # finite sum (so no NaN/Inf) are taken without a check per value.
    tv = type(v)
    floats = _FLOATS.get(length) or _FLOATS.setdefault(length, (float,) * length)
    if tv is list and tuple(map(type, v)) == floats:
        out = [*v]
    elif tv is np.ndarray and v.dtype is _F64 and v.shape == (length,):
        out = v.tolist()
    elif tv is tuple and tuple(map(type, v)) == floats:
        out = list(v)
    else:
        return validate_vector(name, v, length, k).tolist()
    # a finite sum has no NaN/Inf term (a sum that overflows: each value checked)
    if not isfinite(sum(out)) and not all(map(isfinite, out)):
        validate_vector(name, v, length, k)         # raises, naming the index
    return out


class BatchMonitor:
    """N independent monitors in lock step (arrays (N, .)); same arithmetic as :class:`Monitor`.

    Parameters
    ----------
    system : System
    gains : DiagnosisGains or GainFile
    n_runs : int
    agei : bool
    """

    def __init__(self, system: System, gains: Any, n_runs: int, agei: bool = True) -> None:
        self.system = system
        self.gains = as_gains(system, gains)
        self.N = int(n_runs)
        self.observer = HybridObserver(system, batch=self.N)
        self.detector = ResidualDetector(system, self.gains, batch=self.N)
        self.agei = Agei(system, self.gains, batch=self.N, enabled=agei)
        self.estimator = BiasEstimator(system, self.gains, batch=self.N)
        self.sigma = np.zeros((self.N, system.ny))
        self.trigger = np.full(self.N, NO_TRIGGER, dtype=int)
        self.override = no_override(system.ny, self.N)

    def step(self, k: int, u: np.ndarray, y: np.ndarray) -> dict[str, np.ndarray]:
        """One sample of every run: u (N, nu), y (N, ny) (assumed finite) -> arrays by name.

        Names: the fields of :class:`MonitorOutput`'s parts, each (N, .): mode, x_hat, y_tilde
        (observer), residual, w, threshold, nominal, alarm (detector), trigger, override,
        phase, row, mode_uncertain (AGEI), sigma_hat, isolated, active, k_detect (estimator).
        """
        q, x_hat, y_t = self.observer.step_batch(k, u, y, self.sigma, self.trigger)
        r, w, R, nom, alarm = self.detector.step_batch(k, y_t, x_hat, q, self.override)
        trig, ov = self.agei.step_batch(k, q, w, r, nom)
        sig, iso = self.estimator.step_batch(k, u, y, q, alarm, self.agei.mode_uncertain())
        self.sigma, self.trigger, self.override = sig, trig, ov
        est = self.estimator
        return {"mode": q, "x_hat": x_hat, "residual": r, "threshold": R, "alarm": alarm,
                "sigma_hat": sig, "isolated": iso, "trigger": trig,
                "phase": self.agei.phase.copy(), "y_tilde": y_t, "w": w, "nominal": nom,
                "override": ov, "row": self.agei.row.copy(),
                "mode_uncertain": self.agei.mode_uncertain(), "active": est.active.copy(),
                "k_detect": est.k_detect.copy()}


def run_batch(system: System, gains: Any, traj: Any, *, agei: bool = True,
              keep: tuple[str, ...] = ("residual", "threshold", "x_hat", "mode", "sigma_hat",
                                       "isolated", "trigger", "phase")) -> BatchResult:
    """Run the chain over every run of a simulated :class:`~fd_monitor.core.simulator.Trajectory`.

    Parameters
    ----------
    system : System
    gains : DiagnosisGains or GainFile
    traj : Trajectory
        Arrays [run, sample, channel]: ``u`` (N, K, nu), ``y`` (N, K, ny); ``k`` (K,).
    agei : bool
        False: the ablation without AGEI.
    keep : tuple of str
        Per-sample arrays to keep (memory): any of residual, threshold, x_hat, mode, sigma_hat,
        isolated, trigger, phase.

    Returns
    -------
    BatchResult
        ``alarm`` (N, K, ny), ``channels`` = output names; ``residual``, ``threshold`` (N, K, ny),
        ``x_hat`` (N, K, n), ``mode_hat`` (N, K); ``extra``: ``sigma_hat``, ``isolated``
        (N, K, ny), ``trigger``, ``phase`` (N, K), ``k_detect`` (N,) (-1: never).
    """
    u = np.asarray(traj.u, dtype=float)
    y = np.asarray(traj.y, dtype=float)
    N, K = y.shape[:2]
    if not (np.all(np.isfinite(u)) and np.all(np.isfinite(y))):
        raise MessageError("run_batch: the trajectory contains NaN/Inf samples")
    ks = np.asarray(getattr(traj, "k", np.arange(K)), dtype=int)
    bm = BatchMonitor(system, gains, N, agei=agei)
    out: dict[str, np.ndarray] = {}
    alarm = np.zeros((N, K, system.ny), dtype=bool)
    for j in range(K):
        s = bm.step(int(ks[j]), u[:, j], y[:, j])
        alarm[:, j] = s["alarm"]
        for name in keep:
            v = s[name]
            if name not in out:
                out[name] = np.zeros((N, K, *v.shape[1:]), dtype=v.dtype)
            out[name][:, j] = v
    extra: dict[str, Any] = {n: out[n] for n in ("sigma_hat", "isolated", "trigger", "phase")
                             if n in out}
    extra["k_detect"] = bm.estimator.k_detect.copy()
    return BatchResult(alarm=alarm, channels=tuple(system.outputs),
                       residual=out.get("residual"), threshold=out.get("threshold"),
                       x_hat=out.get("x_hat"), mode_hat=out.get("mode"), extra=extra)
