"""Monte Carlo campaigns: false-alarm rate, detection rate and detection delay.

A campaign simulates ``runs`` seeded runs of each scenario (vectorised, in chunks of runs so
memory stays bounded), replays them through the detection method of a gain file, and reduces
the alarms to metrics. The method's batch runner is its runtime's
:meth:`~fd_monitor.core.runtime.Runtime.run_batch`, looked up by the gain file's ``method`` in
the one runtime registry (:data:`fd_monitor.core.methods.RUNTIMES`), so every method runs;
every runner has the signature
``run_batch(system, gains, traj, **options) -> fd_monitor.core.batch.BatchResult``. A
runtime's side signals come from the trajectory's arrays of the same name (``mode``: the
true, measured switching signal; ``rho`` when the simulator provides it).

A scenario simulates its own plant P; the gain file may be for P or for a model of P (an
identified plant with P's inputs, outputs and sample time, :func:`monitored_plant`), whose
monitor then reads P's simulated measurements.

Metrics, per scenario, variant (runner options) and threshold scale rho:

* ``false_alarm_rate`` -- fraction of runs with any alarm (selected channels) at a time
  ``t >= transient`` and before the first fault onset (the whole run if fault free);
* ``detection_rate`` -- fraction of runs with an alarm at some ``t >= onset`` (faulty
  scenarios only; the onset is the earliest fault event of the scenario);
* ``delay_mean_s``, ``delay_median_s``, ``delay_max_s`` -- first alarm at or after the onset,
  minus the onset, over the detected runs, s.

Threshold sweeps (``rhos``) need a runner whose alarms are ``residual > rho * threshold``
(it sets ``extra["threshold_scalable"]``); the runner is then called once and every rho is
evaluated from the same signals.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, TextIO

import numpy as np

from fd_monitor.core.batch import BatchResult
from fd_monitor.core.methods import RUNTIMES, runtime_class, runtime_for
from fd_monitor.core.simulator import simulate_batch
from fd_monitor.model.errors import FdMonitorError, GainFileError
from fd_monitor.model.gains import GainFile
from fd_monitor.model.scenario import Scenario
from fd_monitor.model.system import System

__all__ = ["CampaignRow", "ProgressBar", "get_runner", "monitored_plant", "run_campaign"]


def get_runner(method: str) -> Callable[..., BatchResult]:
    """The batch runner of ``method`` (its runtime's ``run_batch``); GainFileError naming the
    known methods."""
    if method not in RUNTIMES:
        raise GainFileError(f"method {method!r}: no batch runner for evaluation; known: "
                            f"{sorted(RUNTIMES)}")
    return runtime_class(method).run_batch


class ProgressBar:
    """A plain-text progress bar on a stream (stderr by default); silent when disabled."""

    def __init__(self, total: int, label: str = "", stream: TextIO | None = None,
                 enabled: bool = True, width: int = 30) -> None:
        self.total, self.label, self.width = max(total, 1), label, width
        self.stream = sys.stderr if stream is None else stream
        self.enabled = enabled
        self.done = 0

    def update(self, n: int = 1, note: str = "") -> None:
        """Advance by ``n`` units and redraw."""
        self.done = min(self.done + n, self.total)
        if not self.enabled:
            return
        fill = round(self.width * self.done / self.total)
        self.stream.write(f"\r{self.label} [{'#' * fill}{'.' * (self.width - fill)}] "
                          f"{self.done}/{self.total} {note}".ljust(self.width + 40))
        if self.done >= self.total:
            self.stream.write("\n")
        self.stream.flush()


@dataclass
class CampaignRow:
    """Metrics of one (scenario, variant, rho) cell.

    Attributes
    ----------
    scenario, variant : str
    rho : float or None
        Threshold scale (None: the runner's own thresholds).
    runs : int
    false_alarm_rate : float
        Fraction in [0, 1].
    detection_rate : float or None
        Fraction in [0, 1]; None for a fault-free scenario.
    delay_mean_s, delay_median_s, delay_max_s : float or None
        Over detected runs, s.
    onset_s : float or None
    """

    scenario: str
    variant: str
    rho: float | None
    runs: int
    false_alarm_rate: float
    detection_rate: float | None = None
    delay_mean_s: float | None = None
    delay_median_s: float | None = None
    delay_max_s: float | None = None
    onset_s: float | None = None
    delays: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)

    def as_dict(self) -> dict[str, Any]:
        """Plain mapping (no per-run arrays) for JSON."""
        return {k: v for k, v in self.__dict__.items() if k != "delays"}


def monitored_plant(gains: GainFile, scenario: Scenario, system: System | None = None
                    ) -> System:
    """The plant whose monitor runs on a scenario's simulated measurements.

    The rule: a scenario written for plant P runs on a gain file of P, or of a model of P
    (an identified plant M) when M has P's inputs, outputs (names, in order) and sample time;
    P is simulated (the truth), M's monitor reads P's u and y.

    Parameters
    ----------
    gains : GainFile
    scenario : Scenario
        Simulates P = ``scenario.system``.
    system : System, optional
        The gain file's plant M when it is not P (:func:`fd_monitor.model.system.gain_system`).

    Raises
    ------
    GainFileError
        One line: the gain file is for neither P nor a model with P's channels, or its
        method needs a side signal (``mode``, ``rho``) that only P's simulation knows.
    """
    plant = scenario.system
    if plant.sha256 == gains.system_sha256:
        return plant
    where = f"{gains.path}: designed for {gains.system_name}, scenario {scenario.name} is for " \
            f"{plant.name}"
    if system is None or system.sha256 != gains.system_sha256:
        raise GainFileError(f"{where} (a gain file of a model of {plant.name} runs on its "
                            f"scenarios when the model's plant file is found: give it with "
                            f"--system)")
    mine: tuple[Any, ...] = (tuple(system.inputs), tuple(system.outputs), system.sample_time)
    theirs: tuple[Any, ...] = (tuple(plant.inputs), tuple(plant.outputs), plant.sample_time)
    for what, a, b in zip(("inputs", "outputs", "sample times"), mine, theirs):
        if a != b:
            raise GainFileError(f"{where}, and their {what} differ ({system.name}: {a}, "
                                f"{plant.name}: {b}): not a model of it")
    side = runtime_for(system, gains).side_inputs
    if side:
        raise GainFileError(f"{where}: method {gains.method!r} reads {', '.join(side)} from "
                            f"the simulation, which is {plant.name}'s, not {system.name}'s")
    return system


def _onset(scenario: Scenario) -> float | None:
    return min((ev.time for ev in scenario.faults), default=None)


def _select(result: BatchResult, channels: Sequence[str] | None) -> np.ndarray:
    if not channels:
        return np.arange(len(result.channels))
    missing = [c for c in channels if c not in result.channels]
    if missing:
        raise FdMonitorError(f"--channels: {missing} not among the method's alarm channels "
                             f"{list(result.channels)}")
    return np.array([result.channels.index(c) for c in channels])


def _first_true(a: np.ndarray) -> np.ndarray:
    """Index of the first True along axis 1 of an (N, K) array, -1 where there is none."""
    idx = np.argmax(a, axis=1)
    return np.where(a.any(axis=1), idx, -1)


def run_campaign(gains: GainFile, scenarios: Sequence[Scenario], runs: int, *,
                 seed0: int = 0, chunk: int = 250, rhos: Sequence[float] | None = None,
                 transient: float = 0.0, channels: Sequence[str] | None = None,
                 variants: Mapping[str, Mapping[str, Any]] | None = None,
                 progress: bool = True, stream: TextIO | None = None,
                 system: System | None = None) -> list[CampaignRow]:
    """Simulate and evaluate a Monte Carlo campaign.

    Parameters
    ----------
    gains : GainFile
        Loaded (and verified) gain file for the scenarios' plant, or for a model of it
        (:func:`monitored_plant`).
    scenarios : sequence of Scenario
        Each simulates its own plant.
    runs : int
        Runs per scenario; run i uses seed ``seed0 + i`` (the same seeds in every scenario).
    chunk : int
        Runs simulated at once (memory ~ chunk * samples * channels * 8 bytes per array).
    rhos : sequence of float, optional
        Threshold scales to sweep (runners with scalable thresholds).
    transient : float
        Alarms before this time (s) are ignored.
    channels : sequence of str, optional
        Alarm channels that count (default: all).
    variants : mapping, optional
        Label -> runner keyword options; default ``{method: {}}``.
    progress : bool
        Draw a progress bar on ``stream`` (stderr).
    system : System, optional
        The gain file's plant when it is not the scenarios' (an identified model of it).

    Returns
    -------
    list of CampaignRow

    Raises
    ------
    GainFileError
        A scenario the gain file cannot monitor (:func:`monitored_plant`).
    """
    if runs < 1:
        raise FdMonitorError(f"--runs: expected >= 1, got {runs}")
    runner = get_runner(gains.method)
    variants = dict(variants or {gains.method: {}})
    rho_list: list[float | None] = list(rhos) if rhos else [None]
    monitors = {sc.name: monitored_plant(gains, sc, system) for sc in scenarios}
    n_chunks = -(-runs // chunk)
    bar = ProgressBar(n_chunks * len(scenarios) * len(variants), "evaluate", stream, progress)
    rows: list[CampaignRow] = []
    for sc in scenarios:
        fa, first = _scenario_alarms(runner, gains, sc, runs, seed0, chunk, variants, rhos,
                                     transient, channels, bar, monitors[sc.name])
        rows += [_row(sc, label, rho, runs, fa[(label, j)], first.get((label, j)))
                 for label in variants for j, rho in enumerate(rho_list)]
    return rows


def _scenario_alarms(runner: Callable[..., BatchResult], gains: GainFile, sc: Scenario,
                     runs: int, seed0: int, chunk: int,
                     variants: Mapping[str, Mapping[str, Any]], rhos: Sequence[float] | None,
                     transient: float, channels: Sequence[str] | None, bar: ProgressBar,
                     monitor: System | None = None
                     ) -> tuple[dict[tuple[str, int], list[np.ndarray]],
                                dict[tuple[str, int], list[np.ndarray]]]:
    """Simulate one scenario's runs chunk by chunk and run every variant on them.

    monitor : System, optional
        The gain file's plant (default: the scenario's, :func:`monitored_plant`).

    Returns
    -------
    (dict, dict)
        (variant, rho index) -> per chunk: (runs,) bool "false alarm" (any alarm in
        ``[transient, onset)``), and (runs,) index of the first alarm at or after the onset
        (-1: none; faulty scenarios only).
    """
    fa: dict[tuple[str, int], list[np.ndarray]] = {}
    first: dict[tuple[str, int], list[np.ndarray]] = {}
    for c in range(-(-runs // chunk)):
        seeds = list(range(seed0 + c * chunk, seed0 + min((c + 1) * chunk, runs)))
        got = chunk_alarms(runner, gains, sc, seeds, variants, rhos, transient, channels,
                           monitor, bar)
        for key, (f, d) in got.items():
            fa.setdefault(key, []).append(f)
            if d is not None:
                first.setdefault(key, []).append(d)
    return fa, first


def chunk_alarms(runner: Callable[..., BatchResult], gains: GainFile, sc: Scenario,
                 seeds: Sequence[int], variants: Mapping[str, Mapping[str, Any]],
                 rhos: Sequence[float] | None, transient: float,
                 channels: Sequence[str] | None, monitor: System | None = None,
                 bar: ProgressBar | None = None
                 ) -> dict[tuple[str, int], tuple[np.ndarray, np.ndarray | None]]:
    """Simulate one chunk of a scenario's runs (one per seed) and run every variant on it.

    A run's numbers depend only on its seed (each run has its own generator), so a
    campaign cut into the same chunks gives the same numbers wherever the chunks run.

    Returns
    -------
    dict
        (variant, rho index) -> ((runs,) bool "false alarm" (any alarm in
        ``[transient, onset)``), (runs,) index of the first alarm at or after the onset, -1:
        none; None for a fault-free scenario).
    """
    rho_list: list[float | None] = list(rhos) if rhos else [None]
    dt = sc.system.sample_time
    onset = _onset(sc)
    k_tr = round(transient / dt)
    k_on = sc.n_samples if onset is None else round(onset / dt)
    out: dict[tuple[str, int], tuple[np.ndarray, np.ndarray | None]] = {}
    traj = simulate_batch(sc, list(seeds))
    for label, opts in variants.items():
        res = runner(monitor or sc.system, gains, traj, **dict(opts))
        sel = _select(res, channels)
        if rhos:
            if not (res.extra.get("threshold_scalable") and res.residual is not None
                    and res.threshold is not None):
                raise FdMonitorError(f"--rho: method {gains.method!r} has no scalable "
                                     f"thresholds; evaluate it without --rho")
            thr = np.broadcast_to(res.threshold, res.residual.shape)[..., sel]
            with np.errstate(divide="ignore", invalid="ignore"):
                ratio = (res.residual[..., sel] / thr).max(axis=2)  # (N, K)
        for j, rho in enumerate(rho_list):
            # asarray: numpy's stubs type a reduction as a scalar or an array
            alarm = np.asarray((ratio > rho) if rho is not None
                               else res.alarm[..., sel].any(axis=2))
            out[(label, j)] = (np.asarray(alarm[:, k_tr:k_on].any(axis=1)),
                               None if onset is None else _first_true(alarm[:, k_on:]))
        if bar is not None:
            bar.update(1, f"{sc.name} {label}")
    return out


def _row(sc: Scenario, label: str, rho: float | None, runs: int, fa: list[np.ndarray],
         first: list[np.ndarray] | None) -> CampaignRow:
    """The metrics of one (scenario, variant, rho) cell from :func:`_scenario_alarms`."""
    onset = _onset(sc)
    row = CampaignRow(sc.name, label, rho, runs, float(np.concatenate(fa).mean()),
                      onset_s=onset)
    if onset is not None and first is not None:
        f = np.concatenate(first)
        det = f >= 0
        row.detection_rate = float(det.mean())
        if det.any():
            d = f[det] * sc.system.sample_time
            row.delays = d
            row.delay_mean_s = float(d.mean())
            row.delay_median_s = float(np.median(d))
            row.delay_max_s = float(d.max())
    return row
