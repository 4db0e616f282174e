"""One runtime contract for every gain-file method, found through one registry.

Every gain file's ``method`` has a :class:`Runtime` subclass, registered with its certificate
check, help line and designer in :data:`fd_monitor.core.methods.METHODS`; nodes, offline
analysis (:mod:`fd_monitor.analysis.offline`), reports and Monte Carlo campaigns
(:mod:`fd_monitor.analysis.evaluate`) all get theirs with
:func:`~fd_monitor.core.methods.runtime_for` and never branch on the method name. A runtime
has the same small interface for every method:

* :meth:`Runtime.reset` -- start again (the next sample may have any index);
* :meth:`Runtime.bridge` -- carry the run over lost samples (a short hole): the state
  estimate is carried over the gap, the fault memory (bias estimate, alarm and isolation
  history, mode estimate, AGEI phase) is kept;
* :meth:`Runtime.step` -- one sample ``(k, u_k, y_k)`` plus the method's side signals
  (``side``: ``{"rho": (d,)}`` scheduling variable, ``{"mode": int}`` switching signal) ->
  a frozen :class:`RuntimeOutput`: per-channel residual, threshold in force, alarm, the
  excess over the certified region (``outside``) and the method's estimates;
* :meth:`Runtime.run` -- a whole stream (a hole in the sample indices bridged up to
  ``max_gap`` samples, restarted beyond), the same arithmetic as :meth:`Runtime.step` sample
  by sample, as a :class:`RuntimeTrace`;
* :meth:`Runtime.run_batch` -- N simulated runs (a Monte Carlo campaign) as a
  :class:`~fd_monitor.core.batch.BatchResult`.

=================  ===========================================  =====================  ==========
method             what runs                                    side signals           outside
=================  ===========================================  =====================  ==========
thresholds         Monitor: hybrid observer, residual filter    none                   x^, u vs
                   and thresholds, AGEI, bias estimator                                envelope
qb                 QBObserver + QBDetector (LTI and PWA;        none                   x^, u vs
                   continuous or sampled design)                                       envelope
hinf_sc            ResidualBank (LTI, uncertain, LPV); one      rho (LPV without a     rho vs
                   generator per fault, ``||r_i||`` vs J_i      scheduling map)        [min, max]
hminus_switched    GeneralizedObserver, ``||r||`` vs threshold  mode (no guard and no  mode vs
                                                                ``mode`` input)        design
=================  ===========================================  =====================  ==========

``outside`` follows :attr:`fd_monitor.core.monitor.MonitorOutput.outside`: a signed excess
vector (0 inside, > 0 above, < 0 below, named by :attr:`Runtime.region_names`) or None when
the gain file states no region. An alarm outside the region is raised all the same; it is
only not covered by the design's guarantee.

numpy only (no rclpy, no cvxpy).

Why one module of ~900 lines: the runtime contract and the four method runtimes; the
registry moved to :mod:`fd_monitor.core.methods` (issue 22 item 1); a module per method is
deferred while the runtimes are being changed by other work.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from fd_monitor.core.batch import BatchResult
from fd_monitor.core.envelope import CertifiedRegion
from fd_monitor.core.gap import gap_values
from fd_monitor.core.generalized_observer import GeneralizedObserver
from fd_monitor.core.lazy import Fields, LazyArray, Output
from fd_monitor.core.monitor import Monitor, sample_floats, validate_sample
from fd_monitor.core.monitor import run_batch as monitor_run_batch
from fd_monitor.core.plant import SampledPlant
from fd_monitor.core.plausibility import Plausibility
from fd_monitor.core.qb import QBDetector, QBObserver
from fd_monitor.core.qb import run_batch as qb_run_batch
from fd_monitor.core.residual_bank import ResidualBank
from fd_monitor.model.errors import MessageError
from fd_monitor.model.nonlinear import SCHEDULING_MAPS
from fd_monitor.model.system import System

__all__ = ["HinfScRuntime", "HminusSwitchedRuntime", "QBRuntime", "Runtime",
           "RuntimeOutput", "RuntimeTrace", "ThresholdsRuntime"]


class RuntimeOutput(Output):
    """What a runtime produces at sample k.

    Attributes
    ----------
    k : int
        Sample index.
    residual : numpy.ndarray
        (m,) the signal each alarm channel compares with its threshold (channel units;
        :attr:`Runtime.units`).
    threshold : numpy.ndarray
        (m,) the threshold in force (+inf: the channel cannot alarm, e.g. no threshold in the
        gain file or before the thresholds are armed).
    alarm : numpy.ndarray
        (m,) bool alarm flag per channel.
    outside : numpy.ndarray or None
        (len(region_names),) signed excess over the certified region (0 inside); None when
        the gain file states no region.
    mode : int
        The mode the runtime used at k (estimated, measured or the only one).
    estimates : mapping
        The method's estimates at k, name -> array (e.g. ``x_hat`` (n,), ``sigma_hat``
        (ny,), ``isolated`` (ny,) bool, ``rho`` (d,)); see each runtime.
    core : object
        The core object's own output at k (e.g. :class:`~fd_monitor.core.monitor.MonitorOutput`),
        for nodes that publish more than the common fields; None when there is none.

    The arrays may be given as lists (made arrays on first read: :mod:`fd_monitor.core.lazy`).
    """

    __slots__ = (
        "_alarm",
        "_outside",
        "_residual",
        "_threshold",
        "core",
        "estimates",
        "k",
        "mode",
    )
    FIELDS = ("k", "residual", "threshold", "alarm", "outside", "mode", "estimates", "core")
    residual = LazyArray()
    threshold = LazyArray()
    alarm = LazyArray()
    outside = LazyArray()

    def __init__(self, k: int, residual: Any, threshold: Any, alarm: Any, outside: Any,
                 mode: int, estimates: Mapping[str, Any] | None = None,
                 core: Any = None) -> None:
        self.k, self._residual, self._threshold, self._alarm = k, residual, threshold, alarm
        self._outside, self.mode = outside, mode
        self.estimates: Mapping[str, Any] = {} if estimates is None else estimates
        self.core = core


class _ChainEstimates(Mapping[str, Any]):
    """:attr:`RuntimeOutput.estimates` of the ``thresholds`` runtime: read from the
    :class:`~fd_monitor.core.monitor.MonitorOutput` when asked (its arrays are made on first
    read)."""

    __slots__ = ("_o",)
    _NAMES = ("x_hat", "sigma_hat", "isolated")

    def __init__(self, o: Any) -> None:
        self._o = o

    def __getitem__(self, name: str) -> Any:
        if name == "x_hat":
            return self._o.observer.x_hat
        if name == "sigma_hat":
            return self._o.estimator.sigma_hat
        if name == "isolated":
            return self._o.estimator.isolated
        raise KeyError(name)

    def stored(self) -> tuple[tuple[str, Any], ...]:
        """(name, stored value) pairs: lists on a single stream, arrays not made."""
        ob, e = self._o.observer, self._o.estimator
        return (("x_hat", ob._x_hat), ("sigma_hat", e._sigma_hat), ("isolated", e._isolated))

    def __iter__(self) -> Iterator[str]:
        return iter(self._NAMES)

    def __len__(self) -> int:
        return len(self._NAMES)


@dataclass
class RuntimeTrace:
    """A whole stream run by :meth:`Runtime.run` (K processed samples).

    Attributes
    ----------
    k : numpy.ndarray
        (K,) processed sample indices (refused samples left out).
    residual, threshold : numpy.ndarray
        (K, m)
    alarm : numpy.ndarray
        (K, m) bool
    outside : numpy.ndarray or None
        (K, len(region_names)) or None.
    mode : numpy.ndarray
        (K,) int
    estimates : dict
        name -> (K, ...) stacked :attr:`RuntimeOutput.estimates`.
    restarts : list of int
        Samples at which the runtime restarted after a hole.
    bridges : list of int
        Samples at which the runtime bridged a hole (:meth:`Runtime.bridge`).
    """

    k: np.ndarray
    residual: np.ndarray
    threshold: np.ndarray
    alarm: np.ndarray
    outside: np.ndarray | None
    mode: np.ndarray
    estimates: dict[str, np.ndarray]
    restarts: list[int]
    bridges: list[int] = field(default_factory=list)


def _vector(name: str, v: Any, length: int, k: int) -> np.ndarray:
    """(length,) finite float array or :class:`MessageError` naming the sample."""
    try:
        a = np.asarray(v, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise MessageError(f"{name} at sample {k}: expected {length} numbers") from None
    if a.shape[0] != length:
        raise MessageError(f"{name} at sample {k}: expected {length} values, got {a.shape[0]}")
    if not np.all(np.isfinite(a)):
        raise MessageError(f"{name} at sample {k}: non-finite value (NaN/Inf)")
    return a


class Runtime:
    """The runtime of one gain-file method for one stream of samples (base class).

    Subclasses set the class attributes and implement :meth:`reset` and :meth:`step`.

    Attributes
    ----------
    method : str
        The gain-file ``method`` (class attribute; the registry key).
    SIDE_SIGNALS : tuple of str
        Side signals the method can take (class attribute).
    ESTIMATE_KIND : str
        What :meth:`bias_estimates` are: ``sensor_bias`` (per output), ``state`` (fault-model
        states, compared with the true state) or ``none`` (class attribute).
    SIGNED : bool
        True when the residual is signed and alarms at ``|r| > R`` (plots show +-R); False
        when it is a magnitude compared with a positive bound (class attribute).
    BATCH_OPTIONS : tuple of str
        Keyword options :meth:`run_batch` takes (class attribute; default: the
        constructor's).
    CHAIN : bool
        :meth:`payloads` are the diagnosis chain's (observer, detector, AGEI, estimator), so
        a live node publishes the four chain nodes' topics (class attribute; ``thresholds``).
    channels : tuple of str
        (m,) alarm channel names.
    units : tuple of str
        (m,) unit of each channel's residual.
    side_inputs : tuple of str
        The side signals this gain file needs at every step (a subset of SIDE_SIGNALS).
    region_names : tuple of str
        Names of the entries of ``outside`` (empty: no region).
    isolating : tuple of str
        Channels whose alarm isolates the fault they are named after (``qb``: the
        fault-model states; ``hinf_sc``: every generator); ``thresholds`` isolates with its
        estimator's flags instead (estimate ``isolated``).
    """

    method: ClassVar[str] = ""
    SIDE_SIGNALS: ClassVar[tuple[str, ...]] = ()
    ESTIMATE_KIND: ClassVar[str] = "none"
    SIGNED: ClassVar[bool] = False
    BATCH_OPTIONS: ClassVar[tuple[str, ...] | None] = None
    CHAIN: ClassVar[bool] = False

    channels: tuple[str, ...]
    units: tuple[str, ...]
    side_inputs: tuple[str, ...] = ()
    region_names: tuple[str, ...] = ()
    isolating: tuple[str, ...] = ()

    def __init__(self, system: System, gains: Any) -> None:
        self.system = system
        self.gains = gains

    def reset(self) -> None:
        """Restart from scratch (the next sample may have any index)."""
        raise NotImplementedError

    def bridge(self, k: int, u: Any, y: Any,
               side: Mapping[str, Any] | None = None) -> None:
        """The next sample is ``(k, u_k, y_k)``; the samples between the last one stepped and
        ``k`` are lost (a short hole): carry the run over them. :meth:`step` on the same
        sample follows.

        The state estimate is carried over the gap, per method: re-initialised from the
        next measurement (``thresholds``), or predicted through it by the observer's own
        update on u, y (and rho) interpolated between the last sample and this one
        (:mod:`fd_monitor.core.gap`). The fault memory survives: bias estimate, alarm and
        isolation history, the mode estimate, AGEI's phase. A bridge raises no alarm by
        itself (``hinf_sc``, ``hminus_switched``: after more than one lost sample the
        thresholds are armed again ``settle_s`` later, as after a start). Before any
        sample (or right after :meth:`reset`) it does nothing.

        Parameters
        ----------
        k : int
            The next sample's index (greater than the last one stepped).
        u, y, side
            The next sample's values, as :meth:`step` takes them.

        Raises
        ------
        MessageError
            A sample :meth:`step` would refuse (invalid, implausible, a side signal
            missing); nothing has changed.
        """
        raise NotImplementedError

    def step(self, k: int, u: Any, y: Any,
             side: Mapping[str, Any] | None = None) -> RuntimeOutput:
        """Process sample k.

        Parameters
        ----------
        k : int
            Sample index; consecutive after the first call (call :meth:`reset` or
            :meth:`bridge` after a hole).
        u : array_like
            (nu,) inputs u_k, input units.
        y : array_like
            (ny,) measurements y_k, output units.
        side : mapping, optional
            Side signals at k by name (:attr:`side_inputs` are required): ``rho`` (d,) the
            scheduling variable, ``mode`` the switching signal (mode index).

        Returns
        -------
        RuntimeOutput

        Raises
        ------
        MessageError
            Invalid sample or missing side signal (``ImplausibleError`` for an implausible
            one); no state has changed.
        """
        raise NotImplementedError

    def payloads(self, out: RuntimeOutput) -> tuple[Mapping[str, Any], ...]:
        """What a live node publishes of ``out``, by field name: ``residual``,
        ``threshold``, ``alarm`` (m,), ``mode``, ``x_hat`` (flattened; zero-length when the
        method has none)."""
        x_hat = out.estimates.get("x_hat")
        return ({"residual": out.residual, "threshold": out.threshold, "alarm": out.alarm,
                 "mode": out.mode,
                 "x_hat": np.zeros(0) if x_hat is None else np.ravel(x_hat)},)

    @property
    def side_labels(self) -> dict[str, tuple[str, ...]]:
        """Channel labels of each side signal (``rho``: the parameter names; ``mode``:
        ``("mode",)``), as their messages carry them."""
        return {"mode": ("mode",)}

    def bias_estimates(self, estimates: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        """The named estimates reported as ``bias_estimate``, from :attr:`RuntimeOutput.estimates`
        (one sample) or :attr:`RuntimeTrace.estimates` (stacked, (K, ...)): name -> () or
        (K,). Default none."""
        return {}

    def offline_extra(self, trace: RuntimeTrace, truth: Any) -> dict[str, Any]:
        """Method-specific figures of an offline run (default none); ``truth`` is the bag's
        recorded truth (:class:`~fd_monitor.wire.bag_reader.TopicArrays`) or None."""
        return {}

    @classmethod
    def options(cls) -> tuple[str, ...]:
        """Keyword options of the constructor (:func:`~fd_monitor.core.methods.runtime_for`;
        ``fast``, the choice of the reference path that the fast one is tested against, is
        the class's own)."""
        return tuple(p for p in inspect.signature(cls.__init__).parameters
                     if p not in ("self", "system", "gains", "fast"))

    @classmethod
    def batch_options(cls) -> tuple[str, ...]:
        """Keyword options of :meth:`run_batch` (``evaluate`` checks its flags with it)."""
        return cls.options() if cls.BATCH_OPTIONS is None else cls.BATCH_OPTIONS

    def _side(self, side: Mapping[str, Any] | None, name: str, k: int) -> Any:
        if side is None or name not in side or side[name] is None:
            raise MessageError(f"sample {k}: side signal {name!r} missing (method "
                               f"{self.method} on plant {self.system.name} needs "
                               f"{', '.join(self.side_inputs)})")
        return side[name]

    def run(self, k: Sequence[int] | np.ndarray, u: Any, y: Any,
            side: Mapping[str, Any] | None = None,
            on_refused: Callable[[int, MessageError], None] | None = None,
            max_gap: int = 0) -> RuntimeTrace:
        """Run a whole stream with :meth:`step`: a hole of at most ``max_gap`` samples is
        bridged (:meth:`bridge`), a longer one restarts (:meth:`reset`).

        Parameters
        ----------
        k : sequence of int
            (K,) increasing sample indices.
        u : array_like or mapping
            (K, nu) inputs, or a mapping index -> (nu,).
        y : array_like or mapping
            (K, ny) measurements, or a mapping index -> (ny,).
        side : mapping, optional
            name -> (K, ...) array or mapping index -> value, per side signal.
        on_refused : callable, optional
            Called with (k, error) for a sample :meth:`step` refuses (MessageError); the
            sample is left out, a lost sample like a hole's (the next one bridges or
            restarts). Without it the error propagates.
        max_gap : int
            Lost samples in a row that are bridged (the stream readers pass
            :data:`fd_monitor.wire.stream.MAX_GAP`, as the nodes do); 0: every hole
            restarts.

        Returns
        -------
        RuntimeTrace
        """
        ks = [int(v) for v in np.asarray(k).reshape(-1)]
        us, ys = _indexed(u, ks), _indexed(y, ks)
        sides = {n: _indexed(v, ks) for n, v in (side or {}).items()}
        outs: list[RuntimeOutput] = []
        restarts: list[int] = []
        bridges: list[int] = []
        prev: int | None = None
        for kk in ks:
            bridge = prev is not None and 0 < kk - prev - 1 <= max_gap
            if prev is not None and kk != prev + 1:
                if bridge:
                    bridges.append(kk)
                else:
                    self.reset()
                    restarts.append(kk)
            try:
                sd = {n: f(kk) for n, f in sides.items()} if sides else None
                if bridge:
                    self.bridge(kk, us(kk), ys(kk), sd)
                o = self.step(kk, us(kk), ys(kk), sd)
            except MessageError as exc:
                if on_refused is None:
                    raise
                # refused like a NaN message; prev stays behind: the next sample bridges the
                # longer gap or restarts
                on_refused(kk, exc)
                continue
            outs.append(o)
            prev = kk
        return self.stack(outs, restarts, bridges)

    def stack(self, outs: Sequence[RuntimeOutput], restarts: list[int],
              bridges: list[int] | None = None) -> RuntimeTrace:
        """The :class:`RuntimeTrace` of outputs of :meth:`step` in processing order (a caller
        that decides holes itself, e.g. the offline bag reader, steps and then stacks)."""
        m, K = len(self.channels), len(outs)
        fast = _stack_columns(outs, m, len(self.region_names) if self.region_names else None)
        if fast is not None:
            f_res, f_thr, f_alarm, f_outside, f_mode, f_est = fast
            return RuntimeTrace(np.array([o.k for o in outs], dtype=int), f_res, f_thr, f_alarm,
                                f_outside, f_mode, f_est, restarts, list(bridges or []))
        res, thr = np.zeros((K, m)), np.zeros((K, m))
        alarm = np.zeros((K, m), bool)
        mode = np.zeros(K, int)
        outside = None if not self.region_names else np.zeros((K, len(self.region_names)))
        est: dict[str, np.ndarray] = {}
        for j, o in enumerate(outs):
            # the stored values (a list is written into the row as its array would be)
            res[j], thr[j], alarm[j], mode[j] = o._residual, o._threshold, o._alarm, o.mode
            if outside is not None and o._outside is not None:
                outside[j] = o._outside
            e = o.estimates
            # the chain's stored lists written into the rows as their arrays would be
            for name, v in (e.stored() if type(e) is _ChainEstimates else e.items()):
                if name not in est:
                    a = np.asarray(v)
                    est[name] = np.zeros((K, *a.shape), dtype=a.dtype)
                est[name][j] = v
        return RuntimeTrace(np.array([o.k for o in outs], dtype=int), res, thr, alarm, outside,
                            mode, est, restarts, list(bridges or []))

    @classmethod
    def run_batch(cls, system: System, gains: Any, traj: Any, **options: Any) -> BatchResult:
        """Run N simulated runs (a Monte Carlo campaign).

        Parameters
        ----------
        system : System
        gains : GainFile
        traj : Trajectory
            ``u`` (N, K, nu), ``y`` (N, K, ny), ``k`` (K,); side signals as attributes of
            the same name, (N, K, ...) (``mode``: the true mode, the measured switching
            signal; ``rho`` when the trajectory carries it).
        **options
            The runtime's keyword options.

        Returns
        -------
        BatchResult
            ``alarm``, ``residual``, ``threshold`` (N, K, m), ``mode_hat`` (N, K); ``extra``
            ``outside`` (N, K, r) when the gain file has a region.
        """
        u, y = np.asarray(traj.u, dtype=float), np.asarray(traj.y, dtype=float)
        N, K = y.shape[:2]
        ks = np.asarray(getattr(traj, "k", np.arange(K)), dtype=int)
        rt = cls(system, gains, **options)
        missing = [s for s in rt.side_inputs if getattr(traj, s, None) is None]
        if missing:
            raise MessageError(f"run_batch: method {cls.method} on plant {system.name} needs "
                               f"side signal(s) {missing}, which the trajectory does not carry")
        traces = []
        for i in range(N):
            rt.reset()
            side = {s: np.asarray(getattr(traj, s))[i] for s in rt.side_inputs}
            traces.append(rt.run(ks, u[i], y[i], side or None))
        extra: dict[str, Any] = {}
        if rt.region_names:
            extra["outside"] = np.stack([np.asarray(t.outside) for t in traces])
        return BatchResult(alarm=np.stack([t.alarm for t in traces]), channels=rt.channels,
                           residual=np.stack([t.residual for t in traces]),
                           threshold=np.stack([t.threshold for t in traces]),
                           mode_hat=np.stack([t.mode for t in traces]), extra=extra)


def _settle_samples(system: System, gains: Any) -> int:
    """Samples after a (re)start before the thresholds are armed: the gain file's
    ``results.threshold_method.settle_s`` (Monte Carlo thresholds are taken after it), else 0."""
    res = gains.results if hasattr(gains, "results") else gains
    tm = res.get("threshold_method") if isinstance(res, Mapping) else None
    settle = float((tm or {}).get("settle_s", 0.0) or 0.0) if isinstance(tm, Mapping) else 0.0
    return round(settle / float(system.sample_time))


def _indexed(v: Any, ks: Sequence[int]) -> Callable[[int], Any]:
    """Sample index -> value, from a mapping or from an array aligned with ``ks``."""
    if isinstance(v, Mapping):
        return v.__getitem__
    a = np.asarray(v)
    pos = {kk: j for j, kk in enumerate(ks)}
    if a.shape[0] != len(ks):
        raise MessageError(f"expected {len(ks)} samples, got an array of shape {a.shape}")
    return lambda kk: a[pos[kk]]


# --------------------------------------------------------------------------------------
# thresholds: the Heracleous diagnosis chain


class ThresholdsRuntime(Runtime):
    """``thresholds``: :class:`~fd_monitor.core.monitor.Monitor` (observer, detector, AGEI,
    bias estimator).

    Channels: the outputs (signed filtered residual ``r`` against ``+-R``, output units).
    Estimates: ``x_hat`` (n,), ``sigma_hat`` (ny,) (sigma^_{k+1}), ``isolated`` (ny,) bool.
    ``outside``: x^_k and u_k against ``results.envelope`` (names: states then inputs).

    Parameters
    ----------
    system : System
    gains : GainFile or DiagnosisGains
    agei : bool
        False: the ablation without AGEI.
    """

    method = "thresholds"
    ESTIMATE_KIND = "sensor_bias"
    SIGNED = True
    BATCH_OPTIONS = ("agei", "keep")
    CHAIN = True

    def __init__(self, system: System, gains: Any, agei: bool = True) -> None:
        super().__init__(system, gains)
        self.agei = bool(agei)
        self.monitor = Monitor(system, gains, agei=agei)
        self.channels = tuple(system.outputs)
        self.units = tuple(system.output_units)
        region = self.monitor.gains.region
        self.region_names = () if region is None else region.names

    def reset(self) -> None:
        """See :meth:`Runtime.reset`."""
        self.monitor.reset()

    def bridge(self, k: int, u: Any, y: Any,
               side: Mapping[str, Any] | None = None) -> None:
        """:meth:`~fd_monitor.core.monitor.Monitor.bridge`: x^ re-initialised from the next
        compensated measurement (the paper's x^_0 = y~_0), the residual filters started
        again, the fault memory kept."""
        self.monitor.bridge(k, u, y)

    def step(self, k: int, u: Any, y: Any,
             side: Mapping[str, Any] | None = None) -> RuntimeOutput:
        """See :meth:`Runtime.step` (no side signal)."""
        o = self.monitor.step(k, u, y)
        d, ob = o.detector, o.observer
        # the stored values (lists on a single stream): an array is made when read
        return RuntimeOutput(o.k, d._residual, d._threshold, d._alarm, ob._outside, o.mode,
                             _ChainEstimates(o), o)

    def payloads(self, out: RuntimeOutput) -> tuple[Mapping[str, Any], ...]:
        """The chain's payloads: observer, detector, AGEI, estimator (``out.core``)."""
        o = out.core
        # read when a topic is published (the parts' payload() fields)
        return tuple(Fields(part, part.payload_names) for part in
                     (o.observer, o.detector, o.agei, o.estimator))

    def bias_estimates(self, estimates: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        """sigma^ per output."""
        sh = np.asarray(estimates.get("sigma_hat", np.zeros((0, self.system.ny))))
        return {name: sh[..., i] for i, name in enumerate(self.system.outputs)}

    @classmethod
    def run_batch(cls, system: System, gains: Any, traj: Any, **options: Any) -> BatchResult:
        """N runs in lock step (:func:`fd_monitor.core.monitor.run_batch`, same arithmetic)."""
        return monitor_run_batch(system, gains, traj, **options)


def _column(values: list[Any], shape: tuple[int, ...], dtype: Any) -> np.ndarray | None:
    """``values`` as one (K, *shape) array of ``dtype`` (one conversion in C), or None when
    they do not all have that shape (the caller then writes them row by row)."""
    try:
        a = np.array(values, dtype=dtype)
    except (ValueError, TypeError):
        return None
    return a if a.shape == (len(values), *shape) else None


def _stack_columns(outs: Sequence[Any], m: int, r: int | None) -> tuple[Any, ...] | None:
    """:meth:`Runtime.stack`'s arrays, a column at a time: (residual, threshold, alarm,
    outside, mode, estimates), the values :meth:`Runtime.stack` writes row by row, or None
    when a row would need that (another shape, an output without its region row)."""
    if not outs:
        return None
    res = _column([o._residual for o in outs], (m,), float)
    thr = _column([o._threshold for o in outs], (m,), float)
    alarm = _column([o._alarm for o in outs], (m,), bool)
    mode = _column([o.mode for o in outs], (), int)
    if res is None or thr is None or alarm is None or mode is None:
        return None
    outside = None
    if r is not None:
        rows = [o._outside for o in outs]
        if any(v is None for v in rows):
            return None
        outside = _column(rows, (r,), float)
        if outside is None:
            return None
    est: dict[str, np.ndarray] = {}
    columns: dict[str, list[Any]] = {}
    for o in outs:
        e = o.estimates
        for name, v in (e.stored() if type(e) is _ChainEstimates else e.items()):
            columns.setdefault(name, []).append(v)
    for name, vals in columns.items():
        if len(vals) != len(outs):               # an estimate missing at some sample
            return None
        first = np.asarray(vals[0])
        col = _column(vals, first.shape, first.dtype)
        if col is None:
            return None
        est[name] = col
    return res, thr, alarm, outside, mode, est


def _sumsq(v: Sequence[float]) -> float:
    """Sum of squares left to right (numpy's reduction of fewer than 8 terms)."""
    acc = 0.0
    for a in v:
        acc += a * a
    return acc


def _norm_unit(system: System) -> str:
    """Unit of a norm of the outputs: their common unit (plant file ``units``), else "-"."""
    units = set(system.output_units)
    return units.pop() if len(units) == 1 else "-"


# --------------------------------------------------------------------------------------
# qb: quadratic boundedness


class QBRuntime(Runtime):
    """``qb``: :class:`~fd_monitor.core.qb.QBObserver` and :class:`~fd_monitor.core.qb.QBDetector`
    (LTI and PWA plants; continuous-time or sampled design).

    Channels: :attr:`QBDetector.channels` (fault-model states, ``fault_norm``, ``r_<out>``,
    ``r_norm``), magnitudes against ``rho`` times their guaranteed bounds. Estimates:
    ``x_hat`` (n,). ``outside``: x^_k and u_k against ``results.envelope`` when the gain file
    states one (the shipped QB files do not: their bounds assume only ``|w_j| <= 1``, which is
    not measured), else None.

    Parameters
    ----------
    system : System
    gains : GainFile
    rho : float
        Threshold scale (1: the guaranteed bounds).
    state_bound : str
        ``component`` or ``rho_max`` (see :class:`~fd_monitor.core.qb.QBDetector`).
    """

    method = "qb"
    ESTIMATE_KIND = "state"
    BATCH_OPTIONS = ("rho", "state_bound", "estimator", "kalman", "x0")

    def __init__(self, system: System, gains: Any, rho: float = 1.0,
                 state_bound: str = "component") -> None:
        super().__init__(system, gains)
        self.detector = QBDetector(system, gains, rho=rho, state_bound=state_bound)
        self.channels = tuple(self.detector.channels)
        self.units = ("-",) * len(self.channels)
        self.region = CertifiedRegion.from_results(system, gains.results)
        self.region_names = () if self.region is None else self.region.names
        self.isolating = tuple(system.states[i] for i in self.detector.fault_idx)
        det = self.detector
        self._nominal = list(zip(det.fault_idx.tolist(), det.nominal.tolist()))
        self._floats = len(self._nominal) < 8 and system.ny < 8
        # thresholds per mode (read-only: every output of that mode shares them)
        self._thr = [det.rho * det.bounds(q) for q in range(len(system.modes))]
        for t in self._thr:
            t.flags.writeable = False
        self.reset()

    def reset(self) -> None:
        """A new observer (x^ = 0, the plant's initial mode)."""
        self.observer = QBObserver(self.system, self.gains)

    def bridge(self, k: int, u: Any, y: Any,
               side: Mapping[str, Any] | None = None) -> None:
        """The observer predicts through the gap (:meth:`~fd_monitor.core.qb.QBObserver.bridge`):
        x^ (the fault-model states with it) and the mode estimate carry over."""
        last = self.observer.k
        validate_sample(self.system, k, u, y)
        if last is not None and int(k) > last + 1:
            self.observer.bridge(int(k), u, y)

    def step(self, k: int, u: Any, y: Any,
             side: Mapping[str, Any] | None = None) -> RuntimeOutput:
        """See :meth:`Runtime.step` (no side signal)."""
        last = self.observer.k
        nxt = None if last is None else last + 1
        if type(k) is not int or k < 0 or (nxt is not None and k != nxt):
            k = validate_sample(self.system, k, u, y, nxt)[0]
        ul = sample_floats("u", u, self.system.nu, k)
        yl = sample_floats("y", y, self.system.ny, k)
        if self._floats:
            q, xh, rl = self.observer.step1(k, ul, yl)
            # QBDetector.signals on Python floats: |x^_F - x_nom|, its norm, |r|, ||r||
            # (each sum of squares left to right, as numpy reduces fewer than 8 terms)
            xl = xh.tolist()
            d = [xl[i] - c for i, c in self._nominal]
            sig = np.array([*map(abs, d), math.sqrt(_sumsq(d)), *map(abs, rl),
                            math.sqrt(_sumsq(rl))])
        else:
            q, xh = self.observer.step(k, np.array(ul), np.array(yl))
            sig = self.detector.signals(xh, self.observer.residual(q, xh, np.array(yl)))
        thr = self._thr[q]
        out = None if self.region is None else self.region.excess(q, xh, np.array(ul))
        return RuntimeOutput(k, sig, thr, sig > thr, out, int(q), {"x_hat": xh})

    def bias_estimates(self, estimates: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        """The fault-model states of x^."""
        xh = np.asarray(estimates.get("x_hat", np.zeros((0, self.system.n))))
        return {self.system.states[i]: xh[..., i] for i in self.detector.fault_idx}

    def offline_extra(self, trace: RuntimeTrace, truth: Any) -> dict[str, Any]:
        """``component_bound`` (n,), ``rho_max``, ``x_hat`` (K, n); with truth ``error``
        (K, n) and ``V`` (K,) = e' P e."""
        res = self.gains.results
        X = trace.estimates.get("x_hat", np.zeros((0, self.system.n)))
        qb: dict[str, Any] = {"component_bound": np.asarray(res["component_bound"], float),
                              "rho_max": float(res["rho_max"]), "x_hat": X}
        if truth is not None:
            idx = {int(s): i for i, s in enumerate(truth.stamps)}
            cols = [truth.labels.index(f"x.{s}") for s in self.system.states]
            x_true = np.full((len(trace.k), self.system.n), np.nan)
            for j, kk in enumerate(trace.k):
                i = idx.get(int(kk))
                if i is not None:
                    x_true[j] = truth.values[i, cols]
            e = x_true - X
            P = np.asarray(res["P"], dtype=float)
            qb["error"] = e
            qb["V"] = np.einsum("ki,ij,kj->k", e, P, e)
        return qb

    @classmethod
    def run_batch(cls, system: System, gains: Any, traj: Any, **options: Any) -> BatchResult:
        """Vectorised over runs (:func:`fd_monitor.core.qb.run_batch`, also the Kalman
        baseline)."""
        return qb_run_batch(system, gains, traj, **options)


# --------------------------------------------------------------------------------------
# hinf_sc: banks of H-infinity residual generators


class HinfScRuntime(Runtime):
    """``hinf_sc``: :class:`~fd_monitor.core.residual_bank.ResidualBank` (thesis ch. 4-7).

    Channels: one per generator, named by its fault; ``||r_i||`` (output units) against the
    gain file's ``results.thresholds`` (from its ``threshold_method``; +inf when the file has
    none), armed ``threshold_method.settle_s`` after every (re)start and every bridge of more
    than one lost sample (+inf before: the Monte Carlo thresholds were taken after that
    settling time). Every observer starts at
    ``x^ = C^+ y`` of the first sample. Estimates: ``x_hat`` (n_gen, n); ``rho`` (d,) in force
    (LPV).

    LPV banks take ``rho`` from the gain file's scheduling map of the measurements
    (``model.scheduling``, e.g. thesis 7.19) or, without one, from the side signal ``rho``
    (d,). ``outside``: ``rho - clip(rho, rho_min, rho_max)`` (names: the parameters) -- the
    generator runs at the clipped value, the certificate covers only the box. LTI and
    uncertain banks: None.

    Parameters
    ----------
    system : System
    gains : GainFile
    discretisation : str
        ``auto``, ``exact`` or ``hold`` (:class:`ResidualBank`).
    fast : bool
        True (default): the bank's precomputed maps (LPV: the polynomial in rho, error
        bound :attr:`ResidualBank.table_bound`); False: the reference, re-discretised at
        every sample (:meth:`ResidualBank.step_reference`).
    """

    method = "hinf_sc"
    SIDE_SIGNALS = ("rho",)

    def __init__(self, system: System, gains: Any, discretisation: str = "auto",
                 fast: bool = True) -> None:
        super().__init__(system, gains)
        self.bank = ResidualBank(system, gains, discretisation=discretisation, fast=fast)
        model = self.bank.model
        self.channels = tuple(self.bank.faults)
        self.isolating = self.channels          # generator i alarms: fault i isolated
        self.units = (_norm_unit(system),) * len(self.channels)
        self.lpv = self.bank.kind == "lpv"
        names = model.rho_names or tuple(f"rho{j + 1}" for j in range(model.d))
        self.region_names = tuple(names) if self.lpv else ()
        self.side_inputs = ("rho",) if self.lpv and not model.scheduling else ()
        self._rho_names = tuple(names)
        self.settle = _settle_samples(system, gains)
        self._Cpinv = np.linalg.pinv(model.C)
        self._plaus = Plausibility(system)
        self._rho_lo, self._rho_hi = model.rho_min.tolist(), model.rho_max.tolist()
        # the scheduling map and its parameters, looked up once (not per sample)
        sched = model.scheduling if self.lpv else None
        self._sched: tuple[Callable[..., Any], dict[str, Any]] | None = None if not sched \
            else (SCHEDULING_MAPS[str(sched["map"])], dict(sched.get("params") or {}))
        # thresholds in force, armed or not (read-only: every output shares them)
        self._thr = self.bank.thresholds.copy()
        self._thr_off = np.full(len(self.channels), np.inf)
        self._thr.flags.writeable = self._thr_off.flags.writeable = False
        self.reset()

    @property
    def side_labels(self) -> dict[str, tuple[str, ...]]:
        """``rho``: the bank's parameter names."""
        return {"rho": self._rho_names}

    def reset(self) -> None:
        """Observers re-initialised from the next measurement; thresholds re-armed."""
        self._k0: int | None = None
        self._k_next: int | None = None
        self._held: tuple[Any, Any, np.ndarray | None] | None = None

    def bridge(self, k: int, u: Any, y: Any,
               side: Mapping[str, Any] | None = None) -> None:
        """Every generator predicts through the gap on u, y (and rho) interpolated
        (:mod:`fd_monitor.core.gap`); after more than one lost sample the thresholds are
        armed again ``settle`` samples later (the interpolation error, decaying with the
        observer, is not covered by the thresholds)."""
        k, uu, yy = validate_sample(self.system, k, u, y)
        self._plaus.check(k, uu, yy)
        if self._k_next is None or self._held is None or k <= self._k_next:
            return
        rho = None
        if self.lpv:
            model = self.bank.model
            rho = np.clip(self._rho(k, yy, side), model.rho_min, model.rho_max)
        u0, y0, r0 = self._held
        missing = k - self._k_next
        rhos = (gap_values(r0, rho, missing) if r0 is not None and rho is not None
                else iter([None] * missing))
        for j, uj, yj, rj in zip(range(self._k_next, k), gap_values(u0, uu, missing),
                                 gap_values(y0, yy, missing), rhos):
            self.bank.step(j, uj, yj, rj)
        if missing > 1:
            self._k0 = k
        self._k_next = k

    def _rho(self, k: int, y: Any, side: Mapping[str, Any] | None) -> np.ndarray:
        model = self.bank.model
        if side is not None and side.get("rho") is not None:
            return _vector("rho", side["rho"], model.d, k)
        if model.scheduling:
            sched = model.scheduling
            return np.asarray(SCHEDULING_MAPS[str(sched["map"])](
                y, dict(sched.get("params") or {})), dtype=float)
        return _vector("rho", self._side(side, "rho", k), model.d, k)

    def step(self, k: int, u: Any, y: Any,
             side: Mapping[str, Any] | None = None) -> RuntimeOutput:
        """See :meth:`Runtime.step`; side ``rho`` (d,) for an LPV bank without a scheduling
        map (given, it overrides the map)."""
        bank = self.bank
        if not bank.fast:
            return self._step_reference(k, u, y, side)
        # the bank's fast path on Python floats: the checks of the reference, worded alike
        if type(k) is not int or k < 0 or (self._k_next is not None and k != self._k_next):
            k = validate_sample(self.system, k, u, y, self._k_next)[0]
        uf = sample_floats("u", u, self.system.nu, k)
        yf = sample_floats("y", y, self.system.ny, k)
        self._plaus.check(k, uf, yf)
        outside = rho = None
        rl: list[float] | None = None
        if self.lpv:
            sched = self._sched
            if sched is not None and (side is None or side.get("rho") is None):
                raw = np.asarray(sched[0](yf, sched[1]), dtype=float).tolist()  # as _rho
            else:
                raw = self._rho(k, yf, side).tolist()
            rl = [min(max(v, a), b) for v, a, b in zip(raw, self._rho_lo, self._rho_hi)]
            rho = np.array(rl)
            outside = [a - b for a, b in zip(raw, rl)]     # an array when read
        if self._k0 is None:
            bank.reset(self._Cpinv @ np.array(yf))
            self._k0 = k
        norms = bank.advance(uf + yf, rl)
        self._k_next = k + 1
        self._held = (uf, yf, rho)
        thr = self._thr if k - self._k0 >= self.settle else self._thr_off
        est: dict[str, Any] = {"x_hat": bank.xhat.copy()}
        if rho is not None:
            est["rho"] = rho
        return RuntimeOutput(k, norms, thr, norms > thr, outside, 0, est, bank)

    def _step_reference(self, k: int, u: Any, y: Any,
                        side: Mapping[str, Any] | None = None) -> RuntimeOutput:
        """:meth:`step` on numpy arrays (a bank without the fast path)."""
        k, uu, yy = validate_sample(self.system, k, u, y, self._k_next)
        self._plaus.check(k, uu, yy)
        outside = rho = None
        if self.lpv:
            raw = self._rho(k, yy, side)
            model = self.bank.model
            rho = np.clip(raw, model.rho_min, model.rho_max)
            outside = raw - rho
        if self._k0 is None:
            self.bank.reset(self._Cpinv @ yy)
            self._k0 = k
        norms = self.bank.step(k, uu, yy, rho)
        self._k_next = k + 1
        self._held = (uu, yy, rho)
        armed = k - self._k0 >= self.settle
        thr = self.bank.thresholds if armed else np.full(len(self.channels), np.inf)
        est: dict[str, Any] = {"x_hat": self.bank.xhat.copy()}
        if rho is not None:
            est["rho"] = rho
        return RuntimeOutput(k, norms, thr.copy(), norms > thr, outside, 0, est, self.bank)


# --------------------------------------------------------------------------------------
# hminus_switched: generalized observers of switched plants


class HminusSwitchedRuntime(Runtime):
    """``hminus_switched``: :class:`~fd_monitor.core.generalized_observer.GeneralizedObserver`
    (Farhat & Koenig).

    One channel ``r_norm``: ``||r_k||`` (output units) against the design's threshold
    (``observers.<design>.threshold``, written by the designer's Monte Carlo ``threshold``
    section; else ``results.threshold``; +inf when the gain file has none), armed
    ``results.threshold_method.settle_s`` after every (re)start and every bridge of more
    than one lost sample, as for ``hinf_sc``.
    Estimates: ``x_hat`` (n,), ``r`` (p,) the residual vector.

    The switching signal alpha(k), in order of precedence: the side signal ``mode`` when
    given; an input channel named ``mode``; the plant file's guards (controlled ones on u_k,
    autonomous ones on the model prediction ``A_q x^_k + B_q u_k`` of x_{k+1}) giving the mode
    at k + 1; the only mode of a one-mode plant. A plant with several modes and
    none of these (arbitrary switching, as Farhat & Koenig's) needs the side signal.
    ``outside``: (1,) ``mode - nearest design mode`` for a mode the design does not have
    (the observer then keeps the last valid mode), else 0.

    Parameters
    ----------
    system : System
    gains : GainFile
    design : str
        ``hminus`` (default) or ``stability``.
    threshold : float, optional
        Overrides the gain file's threshold, output units.
    """

    method = "hminus_switched"
    SIDE_SIGNALS = ("mode",)
    ESTIMATE_KIND = "none"

    def __init__(self, system: System, gains: Any, design: str = "hminus",
                 threshold: float | None = None) -> None:
        super().__init__(system, gains)
        self.observer = GeneralizedObserver(system, gains, design, threshold)
        self.n_modes = len(self.observer.modes)
        self.channels = ("r_norm",)
        self.units = (_norm_unit(system),)
        self.region_names = ("mode",)
        if "mode" in system.inputs:
            self.mode_source = "input"
        elif system.guards:
            self.mode_source = "guards"
        elif self.n_modes == 1:
            self.mode_source = "constant"
        else:
            self.mode_source = "side"
        self.side_inputs = ("mode",) if self.mode_source == "side" else ()
        self._plant = SampledPlant(system) if self.mode_source == "guards" else None
        self._plaus = Plausibility(system)
        self.settle = _settle_samples(system, gains)
        self.reset()

    def reset(self) -> None:
        """Observer state z = 0, the plant's initial mode; threshold re-armed."""
        self.observer.reset()
        self._mode = int(self.system.initial_mode)
        self._k0: int | None = None
        self._k_next: int | None = None
        self._held: tuple[np.ndarray, np.ndarray] | None = None

    def bridge(self, k: int, u: Any, y: Any,
               side: Mapping[str, Any] | None = None) -> None:
        """The observer predicts through the gap on u and y interpolated
        (:mod:`fd_monitor.core.gap`; the mode by the plant's guards, or held as last
        measured); after more than one lost sample the threshold is armed again ``settle``
        samples later."""
        k, uu, yy = validate_sample(self.system, k, u, y)
        self._plaus.check(k, uu, yy)
        self._measured_mode(k, uu, side)          # a missing side signal: refused here
        if self._k_next is None or self._held is None or k <= self._k_next:
            return
        u0, y0 = self._held
        missing = k - self._k_next
        for j, uj, yj in zip(range(self._k_next, k), gap_values(u0, uu, missing),
                             gap_values(y0, yy, missing)):
            if self.mode_source == "input":       # a mode is held, not interpolated
                i = self.system.inputs.index("mode")
                uj[i] = u0[i]
            self._advance(j, uj, yj)
        if missing > 1:
            self._k0 = k
        self._k_next = k

    def _measured_mode(self, k: int, uu: np.ndarray,
                       side: Mapping[str, Any] | None) -> float | None:
        if side is not None and side.get("mode") is not None:
            m = side["mode"]
            if isinstance(m, (int, float, np.integer, np.floating)) and math.isfinite(m):
                return float(m)                     # a plain number: no array needed
            v = _vector("mode", m, 1, k)
            return float(v[0])
        if self.mode_source == "input":
            return float(uu[self.system.inputs.index("mode")])
        if self.mode_source == "side":
            self._side(side, "mode", k)
        return None

    def _advance(self, k: int, uu: np.ndarray, yy: np.ndarray) -> np.ndarray:
        """One observer step in the current mode, then the mode of k + 1 (the plant's
        guards); returns r_k."""
        q = self._mode
        r = self.observer.step(k, uu, yy, q)
        if self._plant is not None:
            # the plant's guards give the mode of k + 1 as in the plant (controlled on u_k,
            # autonomous on x_{k+1}), here on the one-step model prediction of x^
            qa, xa, ua = np.array([q]), self.observer.xhat[None], uu[None]
            qn = self._plant.next_mode(qa, xa, ua, "controlled")
            x_pred = self._plant.step(qa, xa, ua)
            self._mode = int(self._plant.next_mode(qn, x_pred, ua, "autonomous")[0])
        return r

    def step(self, k: int, u: Any, y: Any,
             side: Mapping[str, Any] | None = None) -> RuntimeOutput:
        """See :meth:`Runtime.step`; side ``mode`` (mode index) when the plant has no
        switching rule."""
        if type(k) is not int or k < 0 or (self._k_next is not None and k != self._k_next):
            k = validate_sample(self.system, k, u, y, self._k_next)[0]
        uf = sample_floats("u", u, self.system.nu, k)
        yf = sample_floats("y", y, self.system.ny, k)
        self._plaus.check(k, uf, yf)
        uu, yy = np.array(uf), np.array(yf)
        m = self._measured_mode(k, uu, side)
        excess = 0.0
        if m is not None:
            # round half to even, as np.rint
            near = float(min(max(round(m), 0), self.n_modes - 1))
            excess = m - near
            if excess == 0.0:
                self._mode = int(near)
        q = self._mode
        if self._k0 is None:
            self._k0 = k
        r = self._advance(k, uu, yy)
        self._k_next = k + 1
        self._held = (uu, yy)
        nrm = float(np.linalg.norm(r))
        thr = self.observer.threshold if k - self._k0 >= self.settle else float("inf")
        return RuntimeOutput(k, np.array([nrm]), np.array([thr]), np.array([nrm > thr]),
                             np.array([excess]), q,
                             {"x_hat": self.observer.xhat.copy(), "r": r}, self.observer)
