"""Plant simulator: step-based, seeded, vectorised over a batch of runs.

One sample ``k`` (time ``t_k = k Ts``) of every run, in this order:

1. fault signals ``f_k`` from the scenario (``beta(k - K0)``); a ``state_jump`` fault adds
   the change of its signal to its state;
2. ``y_k = C_q x_k + E_q w_k + v_k`` plus sensor biases and process faults' ``E f``, with
   ``w_k``, ``v_k`` drawn within their bounds;
3. ``u_k`` from the input profiles (a PI controller reads ``y_k``); actuator faults change the
   applied input only (the published ``u_k`` is the command);
4. controlled guards on ``u_k``, then ``x_{k+1} = f(q_k, x_k, u_k + f_a) + eta_k`` with
   ``|eta_i| <= uncertainty_i(q_k)``, then autonomous guards on ``x_{k+1}``: ``q_{k+1}``.

So an autonomous guard fires at the first sample whose state satisfies it, and a controlled
guard takes effect at the sample after the input that enables it. A scenario's
``switching.schedule`` replaces the guards: ``q_k`` is the scheduled mode at ``t_k``;
``switching.random`` switches each run at dwell times drawn from its own generator.

The scheduling signal ``rho_k`` of a scenario (a profile of time, or a map of the true
state, thesis eq. 7.19) is recorded with the truth; a parameter-dependent plant (``A_rho``,
``B_rho``) is integrated with it inside the sample (:meth:`SampledPlant.step`). The truth of
a sample (:func:`truth_values`; labels: :data:`fd_monitor.wire.topics.PLANT_TRUTH`) is
``mode``, ``x.<state>``, ``f.<fault>`` and ``rho.<name>``.

Each run has its own generator, seeded from ``SeedSequence(seed)``; noise is drawn in blocks
of :data:`BLOCK` samples in a fixed order (w, v, eta), so a run is the same whichever batch it
is in. Time is an argument: nothing here reads a clock.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fd_monitor.core.plant import SampledPlant
from fd_monitor.model.nonlinear import SCHEDULING_MAPS
from fd_monitor.model.scenario import PIController, Profile, Scenario

__all__ = ["BLOCK", "PlantSimulator", "Sample", "Trajectory", "simulate", "simulate_batch",
           "truth_values", "measured_layout", "measured_signals",
           "measured_values"]

BLOCK = 256


@dataclass(frozen=True)
class Sample:
    """One sample of a batch of N runs.

    Attributes
    ----------
    k : int
        Sample index.
    t : float
        Time, s.
    u : numpy.ndarray
        (N, nu) commanded inputs.
    y : numpy.ndarray
        (N, ny) measurements.
    x : numpy.ndarray
        (N, n) true states.
    mode : numpy.ndarray
        (N,) true modes.
    faults : numpy.ndarray
        (N, nf) fault signals per plant fault channel.
    rho : numpy.ndarray
        (N, d) scheduling parameters (d = 0 without a scenario ``scheduling``).
    """

    k: int
    t: float
    u: np.ndarray
    y: np.ndarray
    x: np.ndarray
    mode: np.ndarray
    faults: np.ndarray
    rho: np.ndarray = field(default_factory=lambda: np.zeros((1, 0)))


@dataclass(frozen=True)
class Trajectory:
    """A simulated batch: arrays indexed [run, sample, channel].

    Attributes
    ----------
    scenario : Scenario
    seeds : tuple of int
    k : numpy.ndarray
        (K,) sample indices.
    t : numpy.ndarray
        (K,) times, s.
    u : numpy.ndarray
        (N, K, nu)
    y : numpy.ndarray
        (N, K, ny)
    x : numpy.ndarray
        (N, K, n)
    mode : numpy.ndarray
        (N, K) int
    faults : numpy.ndarray
        (N, K, nf)
    rho : numpy.ndarray
        (N, K, d) scheduling parameters (d = 0 without a scenario ``scheduling``).
    """

    scenario: Scenario
    seeds: tuple[int, ...]
    k: np.ndarray
    t: np.ndarray
    u: np.ndarray
    y: np.ndarray
    x: np.ndarray
    mode: np.ndarray
    faults: np.ndarray
    rho: np.ndarray = field(default_factory=lambda: np.zeros((1, 0, 0)))


def _unit(rng: np.random.Generator, shape: tuple[int, ...], dist: str) -> np.ndarray:
    if dist == "extreme":
        return rng.choice(np.array([-1.0, 1.0]), size=shape)
    return rng.uniform(-1.0, 1.0, size=shape)


class PlantSimulator:
    """Simulate ``len(seeds)`` runs of a scenario in lock step.

    Parameters
    ----------
    scenario : Scenario
    seeds : sequence of int, optional
        One per run; default ``[scenario.seed]``.
    """

    def __init__(self, scenario: Scenario, seeds: Sequence[int] | None = None) -> None:
        self.scenario = scenario
        self.system = sys_ = scenario.system
        self.plant = SampledPlant(sys_)
        self.seeds = tuple(int(s) for s in (seeds if seeds is not None else [scenario.seed]))
        N = self.N = len(self.seeds)
        self.dt = sys_.sample_time
        self._rngs = [np.random.default_rng(np.random.SeedSequence(s)) for s in self.seeds]
        self.k = 0
        self.x = np.tile(scenario.initial_state, (N, 1)).astype(float)
        self.q = np.full(N, scenario.initial_mode, dtype=int)
        self._integral = np.zeros((N, sys_.nu))
        self._prev_faults = np.zeros((N, len(sys_.faults)))
        self._unc = np.array([m.uncertainty for m in sys_.modes])  # (modes, n)
        self._block_start = -BLOCK
        self._w = self._v = self._eta = np.zeros((N, BLOCK, 0))
        kinds = [f.kind for f in sys_.faults]
        self._idx = {kind: [i for i, k in enumerate(kinds) if k == kind] for kind in set(kinds)}
        self._proc_cols = self._idx.get("process", [])
        dwell = scenario.switching_dwell
        # Random switching draws from generators of their own (the noise stays the same).
        self._sw_rngs = ([np.random.default_rng(np.random.SeedSequence([s, 1]))
                          for s in self.seeds] if dwell is not None else [])
        self._next_switch = np.array([r.uniform(*dwell) for r in self._sw_rngs]) \
            if dwell is not None else np.zeros(0)
        sched = scenario.scheduling
        self._rho_map = (SCHEDULING_MAPS[sched.state_map]
                         if sched is not None and sched.state_map is not None else None)

    def rho(self, t: float, x: np.ndarray) -> np.ndarray:
        """(M, d) scheduling parameters at time ``t`` (s) for states ``x`` (M, n)."""
        sched = self.scenario.scheduling
        if sched is None:
            return np.zeros((x.shape[0], 0))
        if self._rho_map is not None:
            params = dict(sched.params)
            return np.array([self._rho_map(xi, params) for xi in x], dtype=float).reshape(
                x.shape[0], len(sched.names))
        values = [p.value(t) for p in sched.profiles]
        if x.shape[0] == 1:
            # one run (the usual case): a plain (1, d) array; np.broadcast_to costs more than
            # the whole right-hand side it feeds, 40 times per sample under RK4
            return np.array([values], dtype=float)
        return np.broadcast_to(np.array(values, dtype=float),
                               (x.shape[0], len(sched.profiles)))

    def _random_switch(self, t: float) -> None:
        dwell = self.scenario.switching_dwell
        assert dwell is not None
        n_modes = len(self.system.modes)
        for i, rng in enumerate(self._sw_rngs):
            if t >= self._next_switch[i] - 1e-9 * self.dt:
                j = int(rng.integers(n_modes - 1))
                self.q[i] = j + (j >= self.q[i])          # one of the other modes
                self._next_switch[i] += rng.uniform(*dwell)

    def _scheduled_mode(self, t: float) -> int | None:
        sw = self.scenario.switching
        if sw is None:
            return None
        q = None
        for tk, qk in sw:
            if t >= tk:
                q = qk
        return self.scenario.initial_mode if q is None else q

    def _draw(self) -> None:
        sys_, sc = self.system, self.scenario
        w, v, eta = [], [], []
        for rng in self._rngs:
            w.append(_unit(rng, (BLOCK, sys_.nw), sc.noise_distribution))
            v.append(_unit(rng, (BLOCK, sys_.ny), sc.noise_distribution))
            eta.append(_unit(rng, (BLOCK, sys_.n), sc.uncertainty_distribution))
        self._w = np.asarray(w) * (sys_.disturbance_bound * sc.noise_scale)
        self._v = np.asarray(v) * (sys_.measurement_noise * sc.noise_scale)
        self._eta = np.asarray(eta) * sc.uncertainty_scale
        self._block_start = self.k

    def fault_signals(self, t: float) -> np.ndarray:
        """(nf,) value of every fault channel's signal at time ``t`` (absolute ones only)."""
        f = np.zeros(len(self.system.faults))
        for ev in self.scenario.faults:
            if not ev.relative:
                f[ev.channel] += float(ev.beta(t, self.dt))
        return f

    def step(self) -> Sample:
        """Produce sample ``k`` of every run and advance the plant to ``k + 1``."""
        sys_, sc, N = self.system, self.scenario, self.N
        k, t = self.k, self.k * self.dt
        if k - self._block_start >= BLOCK:
            self._draw()
        j = k - self._block_start
        w, v, eta = self._w[:, j], self._v[:, j], self._eta[:, j]

        q_forced = self._scheduled_mode(t)
        if q_forced is not None:
            self.q[:] = q_forced
        elif self._sw_rngs:
            self._random_switch(t)
        imposed = q_forced is not None or bool(self._sw_rngs)   # no guards then
        faults = np.tile(self.fault_signals(t), (N, 1))
        for i in self._idx.get("state_jump", []):
            self.x[:, sys_.faults[i].index] += faults[:, i] - self._prev_faults[:, i]
        y = self.plant.output(self.q, self.x, w) + v
        for i in self._idx.get("sensor_bias", []):
            y[:, sys_.faults[i].index] += faults[:, i]
        for i in self._proc_cols:
            Eo = sys_.faults[i].E
            if Eo is not None:
                y += faults[:, i:i + 1] * Eo  # process fault's output part y += E f

        u = np.empty((N, sys_.nu))
        for i, src in enumerate(sc.inputs):
            if isinstance(src, Profile):
                u[:, i] = src.value(t)
            else:
                u[:, i] = self._pi(i, src, t, y)
        u_applied = u.copy()
        for ev in sc.faults:
            ch = sys_.faults[ev.channel]
            if ch.kind == "actuator" and ev.relative:
                b = float(ev.beta(t, self.dt))
                faults[:, ev.channel] += -b * u[:, ch.index]
        for i in self._idx.get("actuator", []):
            u_applied[:, sys_.faults[i].index] += faults[:, i]

        params_delta: dict[str, np.ndarray] = {}
        for i in self._idx.get("parameter", []):
            name = sys_.faults[i].parameter
            if name is not None:
                params_delta[name] = faults[:, i]
        q_mid = self.q if imposed else self.plant.next_mode(self.q, self.x, u, "controlled")
        rho = self.rho(t, self.x)
        x_next = self.plant.step(self.q, self.x, u_applied, w,
                                 faults[:, self._proc_cols] if self._proc_cols else None,
                                 params_delta or None, self.rho, t)
        x_next += eta * self._unc[self.q]
        sample = Sample(k, t, u, y, self.x.copy(), self.q.copy(), faults, rho)
        if not imposed:
            self.q = self.plant.next_mode(q_mid, x_next, u, "autonomous")
        self.x = x_next
        self._prev_faults = faults
        self.k += 1
        return sample

    def _pi(self, i: int, c: PIController, t: float, y: np.ndarray) -> np.ndarray:
        e = c.reference.value(t) - y[:, c.output]
        raw = c.kp * e + c.ki * (self._integral[:, i] + e * self.dt)
        u = np.clip(raw, c.lo, c.hi)
        # Conditional integration: the integral only grows while the output is unsaturated.
        free = raw == u
        self._integral[free, i] += e[free] * self.dt
        return u


def simulate_batch(scenario: Scenario, seeds: Sequence[int],
                   n_samples: int | None = None) -> Trajectory:
    """Simulate one run per seed; arrays are [run, sample, channel].

    Parameters
    ----------
    scenario : Scenario
    seeds : sequence of int
    n_samples : int, optional
        Default ``scenario.n_samples``.
    """
    sim = PlantSimulator(scenario, seeds)
    K = scenario.n_samples if n_samples is None else n_samples
    sys_ = scenario.system
    N = sim.N
    u = np.empty((N, K, sys_.nu))
    y = np.empty((N, K, sys_.ny))
    x = np.empty((N, K, sys_.n))
    q = np.empty((N, K), dtype=int)
    f = np.empty((N, K, len(sys_.faults)))
    r = np.empty((N, K, len(scenario.rho_names)))
    for k in range(K):
        s = sim.step()
        u[:, k], y[:, k], x[:, k], q[:, k], f[:, k] = s.u, s.y, s.x, s.mode, s.faults
        r[:, k] = s.rho
    ks = np.arange(K)
    return Trajectory(scenario, sim.seeds, ks, ks * sys_.sample_time, u, y, x, q, f, r)


def simulate(scenario: Scenario, seed: int | None = None,
             n_samples: int | None = None) -> Trajectory:
    """Simulate a single run (batch of one); default seed: the scenario's.

    Examples
    --------
    >>> from fd_monitor.model.scenario import load_scenario
    >>> traj = simulate(load_scenario("three_tank_bias_h1"), n_samples=20)
    >>> traj.y.shape                        # [run, sample, output]
    (1, 20, 3)
    >>> bool((simulate(load_scenario("three_tank_bias_h1"), n_samples=20).y == traj.y).all())
    True
    """
    return simulate_batch(scenario, [scenario.seed if seed is None else seed], n_samples)


def truth_values(traj: Trajectory | Sample, run: int = 0) -> np.ndarray:
    """``/plant/truth`` values of one run, columns mode, x (states), faults, rho (scheduling
    parameters): (K, m) of a
    :class:`Trajectory`, (m,) of a :class:`Sample` (what ``plant_sim`` publishes)."""
    mode = np.asarray(traj.mode[run], dtype=float)
    return np.concatenate([mode[..., None], traj.x[run], traj.faults[run], traj.rho[run]],
                          axis=-1)


def measured_layout(scenario: Scenario) -> dict[str, tuple[tuple[str, ...],
                                                              tuple[int, ...] | None]]:
    """What a monitor may measure besides u and y, by side-signal name: ``rho`` (the measured
    scheduling parameters of an LPV plant, thesis ch. 6) and ``mode`` (the mode of a
    plant whose switching no guard decides -- ``switching: arbitrary``, or several modes and
    no guards -- measured, as Farhat & Koenig assume, A.3).

    Returns
    -------
    dict
        Side-signal name (``rho``, ``mode``: the side signals of
        :mod:`fd_monitor.core.runtime`) -> (labels, columns of the scenario's rho, or None for
        the mode); empty for a plant with neither. Their topics:
        :func:`fd_monitor.wire.topics.side_topic`.
    """
    sys_ = scenario.system
    out: dict[str, tuple[tuple[str, ...], tuple[int, ...] | None]] = {}
    measured = {p.name for p in sys_.lpv if p.measured}
    cols = tuple(j for j, n in enumerate(scenario.rho_names) if n in measured)
    if cols:
        out["rho"] = (tuple(scenario.rho_names[j] for j in cols), cols)
    if len(sys_.modes) > 1 and (sys_.switching == "arbitrary" or not sys_.guards):
        # no guard decides the mode: it is exogenous, and the monitor must be told it
        out["mode"] = (("mode",), None)
    return out


def measured_values(cols: tuple[int, ...] | None, mode: Any, rho: Any) -> np.ndarray:
    """Values of one :func:`measured_layout` signal: ``rho[..., cols]``, or the mode as a
    column ((..., 1) float) when ``cols`` is None."""
    if cols is None:
        return np.asarray(mode, dtype=float)[..., None]
    return np.asarray(rho)[..., list(cols)]


def measured_signals(traj: Trajectory, run: int = 0) -> dict[str, tuple[tuple[str, ...],
                                                                          np.ndarray]]:
    """:func:`measured_layout` signals of one run: name -> (labels, (K, m) values)."""
    return {t: (labels, measured_values(cols, traj.mode[run], traj.rho[run]))
            for t, (labels, cols) in measured_layout(traj.scenario).items()}
