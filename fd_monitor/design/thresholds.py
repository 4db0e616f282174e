"""Design of filters, thresholds, AGEI matrix and bias-estimator gains (Heracleous et al.).

``python -m fd_monitor design thresholds SYSTEM -o GAINS [--json] [options]``

Plant class: ``x_{k+1} = f(q_k, x_k, u_k) + eta_k``, ``y_k = x_k + v_k (+ sigma)`` (eq. 3),
``|v_i| <= v_bar_i``, ``|eta_i| <= eta_bar_i(q)``; observer ``x^_{k+1} = f(q^_k, y~_k, u_k)``
(eq. 6) with ``x^_0 = y~_0``; residual ``r = H[y~] - H[x^]`` (eq. 14).

Threshold derivation (why not eq. 19 term by term)
--------------------------------------------------
By linearity ``r = H[e]`` with the one-step prediction error ``e_k = y~_k - x^_k`` (``e_0 = 0``).
Fault-free and with ``q^ = q``::

    e_k = v_k - [f(q, x_{k-1} + v_{k-1}, u) - f(q, x_{k-1}, u)] + eta_{k-1}
        = v_k - A_q v_{k-1} - rho_{k-1} + eta_{k-1},

where ``A_q`` is the linear part of mode q (exact for linear modes; the Jacobian at the centre of
the mode's operating region for nonlinear ones) and ``rho = f(x + v) - f(x) - A_q v`` the
nonlinear remainder. Hence (eq. 16 with the noise kept as one sequence)::

    r_{i,k} = sum_m sum_l (delta_il h(m) - A_q,il h(m-1)) v_{l,k-m}
              + H_p[eta_i - rho_i]_k

    |r_{i,k}| <= sum_l v_bar_l || delta_il h - A_q,il h_p ||_1          (exact l1 norm, "noise_l1")
                 + H_p_bar[eta_bar_i(q^) + rho_bar_i(q^)]_k              (eq. 19's H_p_bar term)

The noise enters twice (v_k through H[y], v_{k-1} through f(y_{k-1})); for a low-pass H with
``H(1) = 1`` and ``A_q ~ I`` the two contributions nearly cancel: the l1 norm of
``h - A h_p`` is about ``2 max|h|`` (``2/L`` for a moving average of L samples), while bounding
them separately (eq. 19: ``v_F_bar = ||h||_1 v_bar`` plus ``Delta-f_bar >= ||h_p||_1 |A| v_bar``)
gives about ``2 ||h||_1 v_bar = 2 v_bar`` whatever the filter. The combined bound is exact (tight)
for the linear part and guaranteed; ``rho_bar`` is the paper's Monte Carlo bound (Assumption 4)
applied to the small remainder only: the maximum of |rho| over ``mc_samples`` samples of states
in the operating region, inputs seen there and noise in the box (half of them at its vertices),
times ``(1 + mc_margin)``. ``r_bar_separate`` (eq. 19 term by term) is written for comparison.

Operating region (Assumption 1): the states and inputs of fault-free simulations of the design
scenarios (``--scenario``, default every shipped ``<plant>_*`` scenario, faults removed), per
mode, widened by ``--tube`` (state units) and clipped to the mode's invariant (the negation of
its single-condition autonomous guards). When the plant file declares an ``envelope``, the
inputs are drawn uniformly from its input ranges instead of the design runs' values: a user's
controller drives other inputs than the design scenarios' (a bias on a controlled output moves
the pump command), and the stored region then covers them. The gain file stores the region
sampled (``results.envelope``, ``source: scenarios``): per mode, the bounding box of the
widened states and the input ranges drawn from (``input_source``).

Filter: a moving average of L samples by default; with it a bias step sigma appears in r as
``sigma h(t)`` while the noise bound is ``2 v_bar / L + L-independent terms``, and the model part
costs ``||h_p_bar||_1 (eta_bar + rho_bar)``; L is the largest length with
``L max_q (eta_bar + rho_bar) <= kappa 2 v_bar`` (``kappa`` = 0.25, the model part at most a quarter
of the noise part) capped by ``--max-window`` seconds (``/ Ts``). ``--filter iir --pole p`` gives
the first-order filter ``(1 - p)/(1 - p z^-1)``. ``H_p_bar = |h_p|`` (exact majorant, truncated
where the tail is below 1e-12 for IIR).

AGEI (eq. 20-22): one row per autonomous guard ``x_i op xi`` from q^ to q*; ``Xi^± = (1 ± delta)
|H(1) xi|``; the affected residuals are those where the mode mismatch ``mu = f(q*, x) - f(q^, x)``
is not negligible (> 1 % of its largest component) in the guard band; the band ``d_band`` is 1.5
times the distance past the guard at which ``|mu_i| >= 2 r_bar_i`` for some affected i (beyond it
the event is recognised for sure, since ``|r_i| >= |H[mu_i]| - r_bar_i > r_bar_i``);
``r_bar* = max(r_bar(q^), r_bar(q*)) + ||h_p_bar||_1 mu_bar`` with ``mu_bar`` the Monte Carlo
bound (with margin) of |mu| over the band. Hold length K = settling length of h.

Estimator (eq. 23-26): ``Lambda = lambda I`` (small: trust the model), ``Gamma = gamma I``
(learning time constant ~1/gamma samples), started from the presmoother's fault-free state (see
:mod:`fd_monitor.core.bias_estimator`). Certified: Lambda Schur, Gamma SPD, the linearised error
dynamics ``[[J_q - Lambda, -Lambda], [-Gamma, I - Gamma]]`` Schur at every mode's Jacobian J_q.
Isolation threshold: the l1 bound of the map (v, eta) -> sigma~_i of the linearised error
dynamics plus the peak response to the presmoother's initial-error bound (worst mode): a healthy
sensor's |sigma^_i| stays below it (to first order). Isolation delay: samples for the response
of sigma~ to a unit bias to fall below 5 % (worst mode).

Why one module of ~680 lines: the Heracleous et al. design is one pipeline over one plant
(filters, thresholds, AGEI matrix, estimator gains); the envelope bounds are already in
``envelope.py``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from fd_monitor.core.filters import (
    FilterSpec,
    first_order,
    impulse_response,
    moving_average,
    settling_length,
)
from fd_monitor.core.plant import SampledPlant
from fd_monitor.core.simulator import simulate_batch
from fd_monitor.core.thresholds import DEFAULT_DELTA, estimator_error_matrix, noise_l1_bound
from fd_monitor.design.envelope import jacobian_centre, remainder_bound
from fd_monitor.model.errors import DesignError
from fd_monitor.model.paths import config_dirs
from fd_monitor.model.scenario import Scenario, load_scenario
from fd_monitor.model.system import System

__all__ = ["design_thresholds", "default_scenarios"]

_NEG = {">": "<=", ">=": "<", "<": ">=", "<=": ">", "==": None}


def default_scenarios(system: System) -> list[str]:
    """Shipped scenarios ``<plant>_*.yaml`` of ``system`` (design region), each name once: the
    first config folder holding it wins, as for every shipped name (``$FD_MONITOR_CONFIG``
    before the checkout's)."""
    found: dict[str, str] = {}
    for d in config_dirs():
        sd = d / "scenarios"
        if sd.is_dir():
            for p in sorted(sd.glob(f"{system.name}_*.yaml")):
                found.setdefault(p.name, str(p))
    return [found[n] for n in sorted(found)]


def _jacobian(plant: SampledPlant, q: int, x: np.ndarray, u: np.ndarray,
              eps: float = 1e-7) -> np.ndarray:
    n = x.size
    X = np.repeat(x[None], 2 * n, axis=0)
    for j in range(n):
        X[2 * j, j] += eps
        X[2 * j + 1, j] -= eps
    F = plant.step(np.full(2 * n, q), X, np.repeat(u[None], 2 * n, axis=0))
    return np.asarray(((F[0::2] - F[1::2]) / (2 * eps)).T)


def _clip_invariant(system: System, q: int, x: np.ndarray, gap: float) -> np.ndarray:
    """Move sampled states into mode q's invariant (negated single-condition guards)."""
    x = x.copy()
    for g in system.guards_from(q, "autonomous"):
        if len(g.conditions) != 1:
            continue
        c = g.conditions[0]
        neg = _NEG[c.op]
        if neg in ("<=", "<"):
            x[:, c.index] = np.minimum(x[:, c.index], c.value - (gap if neg == "<" else 0.0))
        elif neg in (">", ">="):
            x[:, c.index] = np.maximum(x[:, c.index], c.value + (gap if neg == ">" else 0.0))
    return x


def _region(system: System, scenarios: Sequence[str], seeds: int) -> dict[str, Any]:
    """Fault-free simulated states/inputs per mode of the design scenarios."""
    X, U, Q = [], [], []
    used = []
    for name in scenarios:
        sc: Scenario = load_scenario(name)
        if sc.system.sha256 != system.sha256:
            continue
        sc = replace(sc, faults=())
        tr = simulate_batch(sc, list(range(seeds)))
        X.append(tr.x.reshape(-1, system.n))
        U.append(tr.u.reshape(-1, system.nu))
        Q.append(tr.mode.ravel())
        used.append(sc.name)
    if not X:
        raise DesignError(f"no design scenario for plant {system.name} (pass --scenario)")
    return {"x": np.concatenate(X), "u": np.concatenate(U), "q": np.concatenate(Q),
            "scenarios": used}


def _declared_region(system: System, rng: np.random.Generator, M: int) -> dict[str, Any]:
    """Uniform samples of every mode's declared box (the AGEI band and reach use them)."""
    env = system.envelope
    assert env is not None
    s = len(system.modes)
    X = np.concatenate([rng.uniform(env.state_lo[q], env.state_hi[q], (M, system.n))
                        for q in range(s)])
    U = np.concatenate([rng.uniform(env.input_lo[q], env.input_hi[q], (M, system.nu))
                        for q in range(s)])
    return {"x": X, "u": U, "q": np.repeat(np.arange(s), M), "scenarios": []}


def _certified_region(system: System, reg: dict[str, Any], tube: float,
                      source: str) -> dict[str, Any]:
    """Per-mode boxes the gain file certifies: the declared ones, or the bounding box of the
    design runs widened by ``tube`` (the region the sampled bounds were taken over), with the
    declared input ranges when the plant declares an envelope (:func:`_input_box`)."""
    if source == "declared":
        env = system.envelope
        assert env is not None
        return {"source": "declared", "state_lo": env.state_lo, "state_hi": env.state_hi,
                "input_lo": env.input_lo, "input_hi": env.input_hi}
    s = len(system.modes)
    out: dict[str, Any] = {"source": "scenarios", "state_lo": np.zeros((s, system.n)),
           "state_hi": np.zeros((s, system.n)), "input_lo": np.zeros((s, system.nu)),
           "input_hi": np.zeros((s, system.nu))}
    for q in range(s):
        sel = reg["q"] == q
        if not np.any(sel):
            sel = np.ones_like(sel)
        out["state_lo"][q] = reg["x"][sel].min(axis=0) - tube
        out["state_hi"][q] = reg["x"][sel].max(axis=0) + tube
        out["input_lo"][q] = reg["u"][sel].min(axis=0)
        out["input_hi"][q] = reg["u"][sel].max(axis=0)
    box = _input_box(system, source)
    if box is not None:
        out["input_lo"], out["input_hi"] = box
    out["input_source"] = "scenarios" if box is None else "declared"
    return out


def _input_box(system: System, source: str) -> tuple[np.ndarray, np.ndarray] | None:
    """(s, nu) input ranges the scenario design samples from: the plant's declared envelope
    (None without one, or for the declared design, which samples its own boxes)."""
    if source != "scenarios" or system.envelope is None:
        return None
    return (np.array(system.envelope.input_lo, dtype=float),
            np.array(system.envelope.input_hi, dtype=float))


def _sample(rng: np.random.Generator, reg: dict[str, Any], system: System, q: int, M: int,
            tube: float) -> tuple[np.ndarray, np.ndarray]:
    sel = np.nonzero(reg["q"] == q)[0]
    if sel.size == 0:
        sel = np.arange(reg["q"].size)
    i = rng.choice(sel, M)
    x = reg["x"][i] + rng.uniform(-tube, tube, (M, system.n))
    return _clip_invariant(system, q, x, 1e-9), reg["u"][i]


def _noise(rng: np.random.Generator, v_bar: np.ndarray, M: int) -> np.ndarray:
    ny = v_bar.size
    vert = rng.choice(np.array([-1.0, 1.0]), (M, ny))
    unif = rng.uniform(-1.0, 1.0, (M, ny))
    return np.where(rng.random((M, 1)) < 0.5, vert, unif) * v_bar


@dataclass(frozen=True)
class _Sampling:
    """What the Monte Carlo bounds sample from: the operating region (``reg``: states ``x``,
    inputs ``u``, modes ``q`` of the design runs or of the declared boxes), its widening
    ``tube`` (state units), the noise box ``v_bar`` and the one generator every draw uses (so
    the order of the draws below is part of the design's reproducibility)."""

    system: System
    plant: SampledPlant
    reg: dict[str, Any]
    rng: np.random.Generator
    tube: float
    v_bar: np.ndarray
    samples: int
    margin: float
    envelope: str
    inputs: tuple[np.ndarray, np.ndarray] | None = None
    input_rng: np.random.Generator | None = None

    def states(self, q: int, M: int, tube: float | None = None
               ) -> tuple[np.ndarray, np.ndarray]:
        """(M, n) states and (M, nu) inputs of mode q (see :func:`_sample`); with ``inputs``
        ((s, nu) ranges) the inputs are uniform in mode q's range instead, drawn from
        ``input_rng`` so that the states' draws are the same either way."""
        x, u = _sample(self.rng, self.reg, self.system, q, M,
                       self.tube if tube is None else tube)
        if self.inputs is not None:
            assert self.input_rng is not None
            u = self.input_rng.uniform(self.inputs[0][q], self.inputs[1][q], u.shape)
        return x, u

    def noise(self, M: int) -> np.ndarray:
        """(M, ny) noise in the box, half of it at its vertices."""
        return _noise(self.rng, self.v_bar, M)

    def step(self, q: int, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """``f(q, x, u)`` of a batch (M, n), (M, nu) all in mode q."""
        return np.asarray(self.plant.step(np.full(x.shape[0], q), x, u))


def _measured_noise(system: System) -> np.ndarray:
    """(ny,) noise bound v_bar; ``DesignError`` unless the plant is full-state measured."""
    n = system.n
    if system.ny != n or not all(np.allclose(m.C, np.eye(n)) for m in system.modes):
        raise DesignError(f"{system.name}: the sensor-bias chain (Heracleous et al.) needs "
                          f"full-state measurements y = x + v (C = I in every mode)")
    v_bar = np.asarray(system.measurement_noise, dtype=float)
    if not np.all(v_bar > 0):
        raise DesignError(f"{system.name}: bounds.measurement_noise must be > 0 for every output")
    return v_bar


def _operating_region(system: System, envelope: str, scenarios: Sequence[str] | None,
                      seeds: int, tube: float | None, v_bar: np.ndarray,
                      rng: np.random.Generator, mc_samples: int
                      ) -> tuple[dict[str, Any], float]:
    """(region samples, tube) of ``--envelope scenarios`` or ``declared`` (Assumption 1)."""
    if envelope == "declared":
        if system.envelope is None:
            raise DesignError(f"{system.source}: --envelope declared needs an 'envelope:' "
                              f"section in the plant file (state and input ranges)")
        return _declared_region(system, rng, min(mc_samples, 50000)), 0.0
    if envelope == "scenarios":
        scen = list(scenarios) if scenarios else default_scenarios(system)
        return (_region(system, scen, seeds),
                float(20.0 * v_bar.max() if tube is None else tube))
    raise DesignError(f"--envelope: expected scenarios or declared, got {envelope!r}")


def _remainders(smp: _Sampling, region: dict[str, Any], box_width: float
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
    """Linear parts and remainder bounds per mode (Monte Carlo, Assumption 4).

    Returns
    -------
    A : (s, n, n) linear part A_q; rho_bar, sep_bar : (s, ny) bounds of the remainder and of
    the whole noise response ``f(x + v) - f(x)`` (eq. 19 term by term); how : per mode, how
    rho_bar was bounded.
    """
    system, plant = smp.system, smp.plant
    s, n, ny = len(system.modes), system.n, system.ny
    M, margin = smp.samples, smp.margin
    A = np.zeros((s, n, n))
    rho_bar = np.zeros((s, ny))
    sep_bar = np.zeros((s, ny))
    for q in range(s):
        x, u = smp.states(q, M)
        A[q] = _jacobian(plant, q, x.mean(axis=0), u.mean(axis=0))
        v = smp.noise(M)
        d = smp.step(q, x + v, u) - smp.step(q, x, u)
        rho_bar[q] = (1.0 + margin) * np.abs(d - v @ A[q].T).max(axis=0)
        sep_bar[q] = (1.0 + margin) * np.abs(d).max(axis=0)
    how: list[dict[str, Any]] = [{"method": "sampled", "samples": M, "margin": margin}] * s
    if smp.envelope == "declared":
        # a bound over the declared boxes; A_q the centre of the hull of the Jacobian
        # enclosures (minimises max |J - A_q| entrywise), the mode's own matrix if linear
        how = []
        for q in range(s):
            lo, hi = region["state_lo"][q], region["state_hi"][q]
            ulo, uhi = region["input_lo"][q], region["input_hi"][q]
            A[q] = jacobian_centre(system, plant, q, lo, hi, ulo, uhi, smp.v_bar, box_width,
                                   A[q])
            rho_bar[q], h_q = remainder_bound(system, plant, q, A[q], lo, hi, ulo, uhi,
                                              smp.v_bar, box_width=box_width, samples=M,
                                              margin=margin, rng=smp.rng)
            how.append({"mode": system.modes[q].name, **h_q})
    return A, rho_bar, sep_bar, how


def _residual_filter(system: System, filter_kind: str, length: int | None,
                     pole: float | None, kappa: float, max_window: float, v_bar: np.ndarray,
                     b: np.ndarray) -> tuple[FilterSpec, int | None, float | None]:
    """(filter, length, pole): the moving average of the automatic length rule (module doc)
    or of ``length``, or the first-order filter of ``pole``; ``b`` (s, ny) is
    ``eta_bar + rho_bar``."""
    if filter_kind == "fir":
        if length is None:
            # no model error at all (an exact linear model): only the window limits L
            L_noise = (math.floor(kappa * 2.0 * v_bar.min() / b.max()) if b.max() > 0
                       else 2**31)
            L_time = round(max_window / system.sample_time)
            length = max(1, min(L_noise, L_time))
        return moving_average(int(length)), length, pole
    if filter_kind == "iir":
        if pole is None:
            L = round(max_window / system.sample_time)
            pole = 1.0 - 2.0 / (L + 1.0)   # same noise bandwidth as a window of L samples
        return first_order(float(pole)), length, pole
    raise DesignError(f"--filter: expected fir or iir, got {filter_kind!r}")


def _agei_row(smp: _Sampling, j: int, A: np.ndarray, r_bar: np.ndarray, spec: FilterSpec,
              l1_hpbar: float, delta: float) -> dict[str, Any]:
    """The AGEI row (eq. 20-22) of autonomous guard ``j``: affected residuals, band and
    ``r_bar*`` from the mode mismatch sampled past the guard."""
    system, rng, tube = smp.system, smp.rng, smp.tube
    ny = system.ny
    g = system.guards[j]
    if len(g.conditions) != 1:
        raise DesignError(f"guard {g.name!r}: AGEI supports one enabling condition per "
                          f"autonomous guard")
    c = g.conditions[0]
    qh, qs = g.source, g.target
    rb = np.maximum(r_bar[qh], r_bar[qs])
    side = 1.0 if c.op in (">", ">=") else -1.0
    x, u = smp.states(qh, smp.samples)

    def mism(dist: np.ndarray, x: np.ndarray = x, u: np.ndarray = u) -> np.ndarray:
        xx = x.copy()
        xx[:, c.index] = c.value + side * dist
        return smp.step(qs, xx, u) - smp.step(qh, xx, u)

    # affected residuals: where the mismatch is not negligible 1 mm.. 10 cm past the guard
    sub = slice(0, min(5000, x.shape[0]))
    probe = np.abs(mism(np.full(x.shape[0], 0.1 * tube)))
    scale = probe.max(axis=0)
    if scale.max() <= 1e-3 * float(rb.min()):
        # the two modes' models agree past the guard: no mismatch, nothing to override;
        # AGEI executes the event when the filtered measurement satisfies the condition
        affected = np.arange(0)
        d_band = 0.0
        mu_bar_aff = np.zeros(ny)
    else:
        affected = np.nonzero(scale > 0.01 * scale.max())[0]
        d_rec = None
        for dist in np.geomspace(1e-4, 10.0, 200):
            mu = np.abs(mism(np.full(x.shape[0], dist)[sub], x[sub], u[sub]))[:, affected]
            if np.all(np.any(mu >= 2.0 * rb[affected], axis=1)):
                d_rec = float(dist)
                break
        if d_rec is None and smp.envelope == "declared":
            # the event never stands out of the noise in the envelope: AGEI stays in
            # its expecting phase past the guard, r_bar_star covers the whole reach
            d_rec = math.inf
        if d_rec is None:
            raise DesignError(f"guard {g.name!r}: the mode mismatch never exceeds twice "
                              f"the nominal threshold within 10 state units")
        # never wider than the operating region reaches past the guard (Assumption 1)
        beyond = side * (smp.reg["x"][:, c.index] - c.value)
        reach = float(max(beyond.max(), 0.0)) + tube
        d_band = min(1.5 * d_rec, reach)
        mu = np.abs(mism(np.asarray(rng.uniform(0.0, d_band, x.shape[0]))))
        v = smp.noise(x.shape[0])
        xx = x.copy()
        xx[:, c.index] = c.value + side * rng.uniform(0.0, d_band, x.shape[0])
        mu_n = np.abs(smp.step(qs, xx, u) - smp.step(qh, xx + v, u) + v @ A[qh].T)
        mu_bar = (1.0 + smp.margin) * np.maximum(mu.max(axis=0), mu_n.max(axis=0))
        mu_bar_aff = np.zeros(ny)
        mu_bar_aff[affected] = mu_bar[affected]
    star = rb + l1_hpbar * mu_bar_aff
    dc = spec.dc_gain
    return {
        "guard": j, "name": g.name, "enabling_mode": system.modes[qh].name,
        "target_mode": system.modes[qs].name, "state": system.states[c.index],
        "op": c.op, "value": c.value, "output": system.outputs[c.index],
        "affected": [system.outputs[i] for i in affected],
        "xi_minus": (1.0 - delta) * abs(dc * c.value),
        "xi_plus": (1.0 + delta) * abs(dc * c.value),
        "band": d_band, "mismatch_bar": mu_bar_aff, "r_bar_star": star,
    }


def _estimator_jacobians(smp: _Sampling) -> np.ndarray:
    """(s, n, n) Jacobians the estimator is certified on: at the mean sampled state and input
    of each mode; ``declared``: the mean Jacobian over the envelope (its centre, three equal
    levels, is where the Torricelli flows are singular)."""
    s = len(smp.system.modes)
    if smp.envelope == "declared":
        return np.array([np.mean([_jacobian(smp.plant, q, x, u) for x, u in
                                  zip(*smp.states(q, 200, 0.0))], axis=0)
                         for q in range(s)])
    return np.array([_jacobian(smp.plant, q, *[a.mean(axis=0) for a in smp.states(q, 2000)])
                     for q in range(s)])


def _presmoother_error_bound(Js: np.ndarray, alpha: float, v_bar: np.ndarray, D: int
                             ) -> np.ndarray:
    """(n,) error bound of the presmoother's state at K_d, worst mode: l1 of its noise map
    and the D-step open-loop propagation."""
    n = Js.shape[1]
    x0_bar = np.zeros(n)
    for J in Js:
        Ez = (1.0 - alpha) * J
        acc = np.zeros(n)
        Ek = np.eye(n)
        for _ in range(20000):
            acc += np.abs(Ek * alpha) @ v_bar
            Ek = Ek @ Ez
            if np.abs(Ek).max() < 1e-12:
                break
        Jd = np.linalg.matrix_power(J, D)
        x0_bar = np.maximum(x0_bar, np.abs(Jd) @ acc)
    return x0_bar


def _estimator_bounds(system: System, Js: np.ndarray, Lam: np.ndarray, Gam: np.ndarray,
                      v_bar: np.ndarray, eta_bar: np.ndarray, x0_bar: np.ndarray
                      ) -> tuple[list[float], np.ndarray, np.ndarray, int]:
    """Certify the estimator (eq. 23-26) on every mode's Jacobian and bound sigma~.

    Returns
    -------
    radii : per mode, the spectral radius of the error dynamics (``DesignError`` unless < 1);
    iso_bound : (ny,) l1 bound of (v) -> sigma~ plus the peak response to ``x0_bar``;
    eta_drift : (ny,) l1 bound of eta -> sigma~; settle : samples for the response of
    sigma~ to a unit bias to fall below 5 % (worst mode).
    """
    n, ny = system.n, system.ny
    radii = []
    iso_bound = np.zeros(ny)
    eta_drift = np.zeros(ny)
    settle = 0
    Bv = np.vstack([Lam, Gam])
    Be = np.vstack([-np.eye(n), np.zeros((n, n))])
    for q, J in enumerate(Js):
        E = estimator_error_matrix(J, Lam, Gam)
        sr = float(np.max(np.abs(np.linalg.eigvals(E))))
        radii.append(sr)
        if not sr < 1.0:
            raise DesignError(f"estimator error dynamics not Schur in mode "
                              f"{system.modes[q].name} (spectral radius {sr})")
        # l1 norm of (v, eta) -> sigma~ and the response to the initial state error
        acc = np.zeros(ny)
        acc_eta = np.zeros(ny)
        peak = np.zeros(ny)
        Ek = np.eye(2 * n)
        t_settle = 0
        for t in range(200000):
            acc += np.abs((Ek @ Bv)[n:]) @ v_bar
            acc_eta += np.abs((Ek @ Be)[n:]) @ eta_bar[q]
            peak = np.maximum(peak, np.abs(Ek[n:, :n]) @ x0_bar)
            # response of sigma~ to sigma~_0 = -e_i (unit bias), worst component
            resp = np.abs(Ek[n:, n:]).max(axis=0)
            if resp.max() > 0.05:
                t_settle = t + 1
            if t > t_settle + 64 and np.abs(Ek).max() < 1e-9:
                break
            Ek = E @ Ek
        iso_bound = np.maximum(iso_bound, acc + peak)
        eta_drift = np.maximum(eta_drift, acc_eta)
        settle = max(settle, t_settle)
    return radii, iso_bound, eta_drift, settle


def design_thresholds(system: System, *, scenarios: Sequence[str] | None = None,
                      seeds: int = 4, tube: float | None = None, mc_samples: int = 200000,
                      mc_margin: float = 0.25, mc_seed: int = 0, filter_kind: str = "fir",
                      length: int | None = None, pole: float | None = None,
                      kappa: float = 0.25, max_window: float = 2.0,
                      delta: float = DEFAULT_DELTA, gamma: float = 0.02, lam: float = 1e-3,
                      alpha: float = 0.02, init: str = "presmoother",
                      M_sigma: float | None = None, isolation_factor: float = 1.0,
                      envelope: str = "scenarios", box_width: float = 0.01
                      ) -> dict[str, Any]:
    """Design everything; return ``{parameters, results, certificate, summary}``.

    Parameters
    ----------
    system : System
        Full-state measured (C = I in every mode).
    scenarios : sequence of str, optional
        Design scenarios (operating region); default :func:`default_scenarios`.
    seeds : int
        Fault-free runs per scenario.
    tube : float, optional
        Widening of the region, state units; default 20 max(v_bar).
    mc_samples, mc_margin, mc_seed : int, float, int
        Monte Carlo bounds: samples per mode, relative margin, seed.
    filter_kind, length, pole : str, int, float
        ``fir`` (moving average of ``length``; default automatic) or ``iir`` (first order).
    kappa, max_window : float
        Automatic length rule (see module doc); window in s.
    delta : float
        AGEI band (eq. 21).
    gamma, lam : float
        Estimator gains Gamma = gamma I, Lambda = lam I.
    alpha : float
        Presmoother gain.
    init : str
        ``presmoother`` or ``measurement`` (the paper's x^s_{K_d} = y_{K_d}).
    M_sigma : float, optional
        Projection radius; default 100 max(v_bar).
    isolation_factor : float
        Isolation threshold = factor x the l1 noise bound of sigma~.
    envelope : str
        ``scenarios`` (the region of the simulated design runs, bounds sampled) or
        ``declared`` (the plant file's ``envelope``: rho_bar bounded over it, see
        :mod:`fd_monitor.design.envelope`; ``scenarios``, ``seeds`` and ``tube`` unused).
    box_width : float
        ``declared``: side of the grid boxes of the interval bound, state units.
    """
    t0 = time.perf_counter()
    s = len(system.modes)
    v_bar = _measured_noise(system)
    plant = SampledPlant(system)
    eta_bar = np.array([m.uncertainty for m in system.modes], dtype=float)
    rng = np.random.default_rng(mc_seed)
    reg, tube = _operating_region(system, envelope, scenarios, seeds, tube, v_bar, rng,
                                  mc_samples)
    region = _certified_region(system, reg, tube, envelope)
    smp = _Sampling(system, plant, reg, rng, tube, v_bar, mc_samples, mc_margin, envelope,
                    _input_box(system, envelope), np.random.default_rng([mc_seed, 1]))
    A, rho_bar, sep_bar, how = _remainders(smp, region, box_width)
    b = eta_bar + rho_bar

    # ---- filter and residual bounds (module doc)
    spec, length, pole = _residual_filter(system, filter_kind, length, pole, kappa,
                                          max_window, v_bar, b)
    K_h = settling_length(spec, 1e-12) + 1
    h = impulse_response(spec, K_h)
    h_p = np.concatenate([[0.0], h[:-1]])
    h_p_bar = np.abs(h_p)
    hold = settling_length(spec, 1e-6)
    l1_hpbar = float(h_p_bar.sum())
    noise_l1 = np.array([noise_l1_bound(h, A[q], v_bar) for q in range(s)])
    r_bar = noise_l1.max(axis=0)[None, :] + l1_hpbar * b
    v_F = float(np.abs(h).sum()) * v_bar
    r_sep = v_F[None, :] + float(np.abs(h_p).sum()) * (sep_bar + eta_bar)

    rows = [_agei_row(smp, j, A, r_bar, spec, l1_hpbar, delta)
            for j, g in enumerate(system.guards) if g.kind == "autonomous"]

    # ---- estimator (eq. 23-26): diagonal gains, certified on every mode's Jacobian
    Js = _estimator_jacobians(smp)
    Lam = lam * np.eye(system.n)
    Gam = gamma * np.eye(system.n)
    D = int(2 * hold + 2)
    # x~_{K_d} = sigma + v with init "measurement": the bias itself, not a noise term
    x0_bar = (np.zeros(system.n) if init == "measurement"
              else _presmoother_error_bound(Js, alpha, v_bar, D))
    radii, iso_bound, eta_drift, settle = _estimator_bounds(system, Js, Lam, Gam, v_bar,
                                                           eta_bar, x0_bar)
    M_sig = float(100.0 * v_bar.max() if M_sigma is None else M_sigma)

    results: dict[str, Any] = {
        "mode_names": list(system.mode_names), "output_names": list(system.outputs),
        "filter": {"kind": spec.kind, "b": spec.b, "a": spec.a},
        "impulse": {"h": h, "h_p": h_p, "h_p_bar": h_p_bar},
        "hold_steps": int(hold),
        "noise_bound": v_bar, "v_F_bar": v_F,
        "noise_l1": noise_l1, "eta_bar": eta_bar, "remainder_bar": rho_bar,
        "r_bar": r_bar, "r_bar_separate": r_sep,
        "agei": {"delta": float(delta), "rows": rows},
        "envelope": {**region, "remainder": how,
                     "mismatch": {"method": "sampled", "samples": mc_samples,
                                  "margin": mc_margin}},
        "estimator": {"Lambda": Lam, "Gamma": Gam, "M_sigma": M_sig,
                      "isolation_threshold": isolation_factor * iso_bound,
                      "isolation_delay": int(settle), "init": init,
                      "presmoother_gain": alpha, "presmoother_delay": D,
                      "initial_error_bound": x0_bar,
                      "uncertainty_drift_bound": eta_drift},
    }
    certificate = {
        "linear_part": A, "jacobians": Js,
        "filter_spectral_radius": spec.spectral_radius(),
        "estimator_spectral_radius": radii,
        "Lambda_spectral_radius": float(np.max(np.abs(np.linalg.eigvals(Lam)))),
        "Gamma_min_eig": float(np.min(np.linalg.eigvalsh(Gam))),
        "checks": ["filter stable", "h, h_p from coefficients", "h_p_bar >= |h_p|",
                   "noise_l1 >= exact l1 of delta h - A_q h_p", "r_bar >= parts",
                   "r_bar_star >= r_bar", "AGEI rows = autonomous guards",
                   "Lambda Schur", "Gamma SPD", "estimator error dynamics Schur per mode"],
    }
    parameters = {
        "envelope": envelope, "box_width": box_width if envelope == "declared" else None,
        "scenarios": reg["scenarios"], "seeds_per_scenario": seeds, "tube": tube,
        "mc_samples": mc_samples, "mc_margin": mc_margin, "mc_seed": mc_seed,
        "filter": filter_kind, "length": None if filter_kind != "fir" else int(length or 0),
        "pole": pole, "kappa": kappa, "max_window_s": max_window, "delta": delta,
        "gamma": gamma, "lambda": lam,
        "presmoother_gain": alpha, "estimator_init": init, "M_sigma": M_sig,
        "isolation_factor": isolation_factor,
    }
    elapsed = time.perf_counter() - t0
    summary = _summary(system, results, certificate, envelope, elapsed)
    return {"parameters": parameters, "results": results, "certificate": certificate,
            "summary": summary, "solver": {"name": "numpy/scipy (DARE, Monte Carlo)",
                                           "status": "optimal", "time_s": elapsed}}


def _summary(system: System, results: dict[str, Any], certificate: dict[str, Any],
             envelope: str, elapsed: float) -> dict[str, Any]:
    """The designer's printed summary, read from the gain-file contents (lists, per mode)."""
    names = system.mode_names
    flt, est = results["filter"], results["estimator"]

    def per_mode(a: np.ndarray) -> dict[str, list[float]]:
        return {m: a[q].tolist() for q, m in enumerate(names)}

    return {
        "plant": system.name, "filter": f"{flt['kind']} b[{flt['b'].size}] a[{flt['a'].size}]",
        "hold_steps": results["hold_steps"], "v_F_bar": results["v_F_bar"].tolist(),
        "r_bar": per_mode(results["r_bar"]),
        "r_bar_separate_eq19": per_mode(results["r_bar_separate"]),
        "agei": [{"guard": r["name"], "affected": r["affected"], "band": r["band"],
                  "r_bar_star": np.asarray(r["r_bar_star"]).tolist()}
                 for r in results["agei"]["rows"]],
        "isolation_threshold": est["isolation_threshold"].tolist(),
        "isolation_delay": est["isolation_delay"],
        "estimator_spectral_radius": max(certificate["estimator_spectral_radius"]),
        "uncertainty_drift_bound": est["uncertainty_drift_bound"].tolist(),
        "envelope": envelope,
        "remainder_bar": per_mode(results["remainder_bar"]),
        "remainder_method": sorted({h["method"] for h in results["envelope"]["remainder"]}),
        "design_time_s": elapsed,
    }
