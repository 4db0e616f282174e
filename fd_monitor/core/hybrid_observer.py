"""Hybrid automaton observer (Heracleous et al., eq. 5-7).

Per sample k the observer receives ``u_k``, ``y_k``, the bias estimate ``sigma^_k`` (from the
estimator at k - 1) and the autonomous-guard trigger decided by AGEI at k - 1, and

1. completes its mode: ``q^_k = trigger(q_mid_k)``, where ``q_mid_k`` are the controlled guards
   on ``u_{k-1}`` applied to ``q^_{k-1}`` (prepared at k - 1); the trigger names a guard of the
   AGEI matrix and is applied when ``q_mid_k`` is its enabling mode (or the same condition
   leaves ``q_mid_k``: the parallel composition of eq. 7);
2. outputs ``(q^_k, x^_k)`` and the compensated measurement ``y~_k = y_k - sigma^_k``;
3. prepares ``x^_{k+1} = f(q^_k, y~_k, u_k)`` (eq. 6) and ``q_mid_{k+1}`` (controlled guards on
   ``u_k``). Autonomous guards are never evaluated here: only AGEI triggers them.

The first sample initialises ``x^ = y~`` (the paper's ``x^_0 = y_0``) and ``q^`` to the plant's
initial mode (or ``initial_mode``).

Everything is batched over N runs; with ``batch=None`` the public :meth:`HybridObserver.step`
takes and returns 1-D arrays (the node / :class:`~fd_monitor.core.monitor.Monitor` case).
"""

from __future__ import annotations

import math
import operator
from collections.abc import Callable, Sequence
from typing import Any, cast

import numpy as np

from fd_monitor.core.envelope import CertifiedRegion
from fd_monitor.core.filters import as_floats
from fd_monitor.core.lazy import LazyArray, Output
from fd_monitor.core.plant import SampledPlant
from fd_monitor.core.plausibility import Plausibility
from fd_monitor.model.nonlinear import get_model
from fd_monitor.model.system import System

__all__ = ["HybridObserver", "ModeDynamics", "ObserverOutput", "NO_TRIGGER"]

#: Trigger value meaning "no autonomous guard event".
NO_TRIGGER = -1


#: Compiled single-stream steps by (model, dt, parameters): see ModeDynamics.
_COMPILED: dict[tuple[Any, ...], Callable[[Sequence[float], Sequence[float]], list[float]]] = {}


class ModeDynamics:
    """``f(q, x, u)`` for a batch with per-run modes, in one model call when possible.

    When every mode is a nonlinear mode of the same model (three_tank), the parameters are
    gathered per run from a (modes,) table and the model is called once on the whole batch
    (exactly the per-mode values, elementwise arithmetic: the same bits as
    :meth:`SampledPlant.step` mode by mode). Otherwise it defers to :class:`SampledPlant`.

    Parameters
    ----------
    system : System
    """

    def __init__(self, system: System) -> None:
        self.plant = SampledPlant(system)
        self.dt = system.sample_time
        models = {m.model for m in system.modes}
        self._model = None
        if all(m.dynamics == "nonlinear" for m in system.modes) and len(models) == 1 and \
                all(m.D.size == 0 or not np.any(m.D) for m in system.modes):
            name = next(iter(models))
            assert name is not None
            self._model = get_model(name)
            keys = set().union(*(m.params.keys() for m in system.modes))
            self._table = {k: np.array([float(m.params[k]) for m in system.modes])
                           for k in keys}
            # scalars where every mode agrees (e.g. 'substeps' must stay a scalar)
            self._const = {k: float(v[0]) for k, v in self._table.items() if np.all(v == v[0])}
        # single-stream fast path: the model on floats with each mode's parameters
        self._floats = None if self._model is None else self._model.step_floats
        self._mode_params = [{k: float(v[q]) for k, v in self._table.items()}
                             for q in range(len(system.modes))] if self._floats else []
        # ... compiled once per mode where the model can (the parameters' work done here)
        comp = None if self._model is None else self._model.compile_floats
        self._steps1 = []
        if comp is not None and self._model is not None:
            for p in self._mode_params:
                # compiled once per process and parameter set (observer and estimator share)
                key = (self._model.name, self.dt, tuple(sorted(p.items())))
                if key not in _COMPILED:
                    _COMPILED[key] = comp(p, self.dt)
                self._steps1.append(_COMPILED[key])
        if self._model is None and not self._steps1:
            self._steps1 = _scalar_linear_steps(self.plant)

    def __call__(self, q: np.ndarray, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """(N,) int modes, (N, n) states, (N, nu) inputs -> (N, n) next states."""
        if self._model is None:
            return self.plant.step(q, x, u)
        p: dict[str, float | np.ndarray] = dict(self._const)
        for k, v in self._table.items():
            if k not in self._const:
                p[k] = v[q]
        return self._model.step(x, u, p, self.dt)

    def step1(self, q: int, x: Sequence[float], u: Sequence[float]) -> list[float]:
        """One run on Python floats: mode q, state (n,), input (nu,) -> next state (n,).

        The model's ``step_floats`` when it has one (bit-identical to the batch call),
        else the batch call on a batch of one.
        """
        if self._steps1:
            return self._steps1[q](x, u)
        if self._floats is not None:
            return self._floats(x, u, self._mode_params[q], self.dt)
        return list(self(np.array([q]), np.array([x], dtype=float).reshape(1, -1),
                         np.array([u], dtype=float).reshape(1, -1))[0].tolist())



def excess_map(lo: Sequence[float], hi: Sequence[float]
               ) -> Callable[[Sequence[float]], list[float]]:
    """``f(z) = [z_i - min(max(z_i, lo_i), hi_i)]`` (the signed excess over a box), compiled
    once with the bounds as constants: ``a if a > v else v`` is what ``max(v, a)`` returns
    (``b if b < m else m`` for ``min(m, b)``), NaN included; an infinite bound is no test."""
    terms = []
    for i, (a, b) in enumerate(zip(lo, hi)):
        m = f"z[{i}]" if a == -math.inf else f"({a!r} if {a!r} > z[{i}] else z[{i}])"
        terms.append(f"z[{i}] - {m}" if b == math.inf else
                     f"z[{i}] - ({b!r} if {b!r} < (m := {m}) else m)")
    fn = eval(f"lambda z: [{', '.join(terms) or ''}]", {"inf": math.inf})
    return cast(Callable[[Sequence[float]], list[float]], fn)


def _scalar_linear_steps(plant: SampledPlant) -> list[Callable[[Sequence[float],
                                                                 Sequence[float]], list[float]]]:
    """Per mode ``step(x, u) = [Ad x + Bd u + cd]`` on Python floats for a plant of one state
    and at most one input whose modes are all linear and constant ([] otherwise).

    :meth:`SampledPlant.step` computes ``x @ Ad.T + u @ Bd.T + cd`` (no disturbance, no
    process fault in the observer): with one state and one input each product is a single
    multiplication, so there is no summation order to match and the float form has the batch
    path's bits (``x * a + u * b + c``; ``+ 0.0`` for ``u @ Bd.T`` without inputs) without
    its numpy calls. Larger linear modes keep the batch path (a matrix product's summation
    order is the BLAS library's).
    """
    s = plant.system
    if s.n != 1 or s.nu > 1 or any(m.Ad is None for m in plant.modes) or any(plant.lpv_modes):
        return []
    steps = []
    for dm in plant.modes:
        assert dm.Ad is not None
        a, c = float(dm.Ad[0, 0]), float(dm.cd[0])
        bu = f"u[0] * {float(dm.Bd[0, 0])!r}" if s.nu else "0.0"
        fn = eval(f"lambda x, u: [x[0] * {a!r} + {bu} + {c!r}]", {"inf": math.inf,
                                                                   "nan": math.nan})
        steps.append(cast(Callable[[Sequence[float], Sequence[float]], list[float]], fn))
    return steps


def _controlled_map(q: int, guards: Sequence[tuple[int, Sequence[tuple[int, Any, float]]]]
                    ) -> Callable[[Sequence[float]], int]:
    """``u -> q_mid`` of mode q: its controlled guards ``(target, [(index, op, value)])`` in
    file order as one compiled function (the comparisons of ``_OPS``, constants by repr)."""
    sym = {operator.lt: "<", operator.le: "<=", operator.gt: ">", operator.ge: ">="}
    lines = ["def nq(u):"]
    for target, conds in guards:
        if target == q:
            continue                                   # a self-loop leaves q as it is
        test = " and ".join(f"u[{i}] {sym.get(op, '==')} {v!r}" for i, op, v in conds)
        lines.append(f"    if {test or 'True'}:\n        return {int(target)}")
    lines.append(f"    return {int(q)}")
    ns: dict[str, Any] = {"inf": math.inf, "nan": math.nan}
    exec("\n".join(lines) + "\n", ns)
    return cast(Callable[[Sequence[float]], int], ns["nq"])


#: A guard condition's comparison by its ``op`` (anything else: ``==``, as
#: :meth:`~fd_monitor.core.plant.SampledPlant.next_mode` compares).
_OPS = {"<": operator.lt, "<=": operator.le, ">": operator.gt, ">=": operator.ge}


class ObserverOutput(Output):
    """Observer output at sample k (published as the state estimate).

    Attributes
    ----------
    k : int
        Sample index.
    mode : int or numpy.ndarray
        q^_k: mode index (batch: (N,) int).
    x_hat : numpy.ndarray
        (n,) x^_k, state units (batch: (N, n)).
    y_tilde : numpy.ndarray
        (ny,) y~_k = y_k - sigma^_k, output units (batch: (N, ny)).
    outside : numpy.ndarray or None
        (n + nu,) how far x^_k and u_k are outside the gain file's certified region of q^_k
        (:meth:`~fd_monitor.core.envelope.CertifiedRegion.excess`: 0 inside, signed); None
        without a region (single stream only).

    :meth:`payload` names the fields (:mod:`fd_monitor.wire.topics`: their topic).
    """

    __slots__ = ("_outside", "_x_hat", "_y_tilde", "k", "mode")
    #: the keys of :meth:`payload`, in its order
    payload_names = ("mode", "x_hat", "y_tilde")
    FIELDS = ("k", "mode", "x_hat", "y_tilde", "outside")
    x_hat = LazyArray()
    y_tilde = LazyArray()
    outside = LazyArray()

    def __init__(self, k: int, mode: int | np.ndarray, x_hat: Any, y_tilde: Any,
                 outside: Any = None) -> None:
        self.k, self.mode, self._x_hat, self._y_tilde = k, mode, x_hat, y_tilde
        self._outside = outside

    def payload(self) -> dict[str, Any]:
        """Field name -> value: ``mode``, ``x_hat``, ``y_tilde``."""
        return {"mode": self.mode, "x_hat": self.x_hat, "y_tilde": self.y_tilde}


class HybridObserver:
    """The hybrid automaton observer of eq. 5-7.

    Parameters
    ----------
    system : System
        Full-state measured plant (y = x + v).
    batch : int or None
        None: single stream (1-D arrays); N: N runs in lock step ((N, .) arrays).
    initial_mode : int, optional
        q^_0; default the plant's initial mode.
    region : CertifiedRegion, optional
        The gain file's certified region: :attr:`ObserverOutput.outside` is filled from it.
    """

    def __init__(self, system: System, *, batch: int | None = None,
                 initial_mode: int | None = None, region: CertifiedRegion | None = None) -> None:
        self.system = system
        self.region = region
        self.plant = SampledPlant(system)
        self.f = ModeDynamics(system)
        self.batch = batch
        self.N = 1 if batch is None else int(batch)
        self.initial_mode = system.initial_mode if initial_mode is None else int(initial_mode)
        self.plausibility = Plausibility(system)
        # trigger table: for guard j (autonomous) and current mode m, the guard to apply
        s = len(system.modes)
        self._trig = np.full((len(system.guards) + 1, s), -1, dtype=int)
        for j, g in enumerate(system.guards):
            if g.kind != "autonomous":
                continue
            for m in range(s):
                for g2 in system.guards_from(m, "autonomous"):
                    if g2.conditions == g.conditions:
                        self._trig[j, m] = g2.target
                        break
        # single stream (floats): controlled guards (source, target, conditions) in file
        # order; C_q rows (None where C_q = I); the certified box per mode
        self._controlled = [(g.source, g.target, [(c.index, c.op, float(c.value))
                                                  for c in g.conditions])
                            for g in system.guards if g.kind == "controlled"]
        # ... per source mode, in file order, with the comparison as a function
        self._controlled1 = [[(t, [(i, _OPS.get(op, operator.eq), v) for i, op, v in conds])
                              for src, t, conds in self._controlled if src == q]
                             for q in range(s)]
        # ... compiled: q_mid_{k+1} = the target of the first guard whose test holds on u_k
        # and leaves q (a self-loop changes nothing; a later guard may still apply), else q
        self._next1 = [_controlled_map(q, g) for q, g in enumerate(self._controlled1)]
        self._C = [None if m.C.shape[0] == m.C.shape[1] and np.array_equal(m.C, np.eye(
            m.C.shape[0])) else m.C for m in system.modes]
        r = region
        self._box = [] if r is None else [
            (r.state_lo[q].tolist() + r.input_lo[q].tolist(),
             r.state_hi[q].tolist() + r.input_hi[q].tolist()) for q in range(s)]
        self._excess1 = [excess_map(lo, hi) for lo, hi in self._box]
        self._trig1 = self._trig.tolist()
        self._steps1 = self.f._steps1            # compiled f(q, x, u) per mode ([]: none)
        self._enter0 = self.plausibility.compensator(False)
        self._enter1 = self.plausibility.compensator(True)
        self.reset()

    def reset(self) -> None:
        """Back to the state before the first sample."""
        self.k_next: int | None = None
        self.q_mid = np.full(self.N, self.initial_mode, dtype=int)
        self.x_next = np.zeros((self.N, self.system.n))
        # single stream
        self._q_mid1 = self.initial_mode
        self._x_next1: list[float] = []

    def bridge(self) -> None:
        """Samples were lost: the next one re-initialises ``x^ = y~`` (as the first does,
        with the bias estimate in force), no one-step plausibility test across the gap; the
        mode estimate is kept."""
        self.k_next = None

    def step1(self, k: int, u: list[float], y: list[float], sg: list[float], trigger: int
              ) -> tuple[ObserverOutput, list[float], list[float]]:
        """Single stream on Python floats: the arithmetic of :meth:`step_batch` for one run.

        Returns the output and its x^_k and y~_k as lists (for the next component).
        """
        q_mid = self._q_mid1
        # Refuse an implausible sample before any state changes (core/plausibility.py); the
        # usual case (C = I) in one compiled test that also gives y~ = y - sigma^.
        first = self.k_next is None
        y_pred = None
        if first:
            y_t = self._enter0(y, u, sg)
        elif self._C[q_mid] is None:
            y_t = self._enter1(y, u, sg, self._x_next1)
            if y_t is None:
                y_pred = [a + b for a, b in zip(self._x_next1, sg)]
        else:
            y_t = None
            C = self._C[q_mid]
            y_pred = [a + b for a, b in zip((C @ np.array(self._x_next1)).tolist(), sg)]
        if y_t is None:
            self.plausibility.check(k, u, y, y_pred)
            y_t = [a - b for a, b in zip(y, sg)]
        q = q_mid
        if trigger >= 0:
            tgt = self._trig1[trigger][q_mid]
            if tgt >= 0:
                q = tgt
        x_hat = y_t if first else self._x_next1
        steps = self._steps1
        self._x_next1 = steps[q](y_t, u) if steps else self.f.step1(q, y_t, u)
        self._q_mid1 = self._next1[q](u)
        self.k_next = k + 1
        out = self._excess1[q](x_hat + u) if self._excess1 else None
        return ObserverOutput(k, q, x_hat, y_t, out), x_hat, y_t

    def _apply_trigger(self, q: np.ndarray, trigger: np.ndarray) -> np.ndarray:
        t = np.where(trigger >= 0, trigger, len(self.system.guards))
        tgt = self._trig[t, q]
        return np.where(tgt >= 0, tgt, q)

    def step_batch(self, k: int, u: np.ndarray, y: np.ndarray, sigma_hat: np.ndarray,
                   trigger: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Batched step; arrays (N, nu), (N, ny), (N, ny), (N,) int -> (q^, x^, y~).

        Inputs are assumed validated (see :func:`fd_monitor.core.monitor.validate_sample`).
        """
        y_t = y - sigma_hat
        q = self._apply_trigger(self.q_mid, trigger)
        if self.k_next is None:
            x_hat = y_t.copy()
        else:
            x_hat = self.x_next
        self.x_next = self.f(q, y_t, u)
        self.q_mid = self.plant.next_mode(q, y_t, u, "controlled")
        self.k_next = k + 1
        return q, x_hat, y_t

    def step(self, k: int, u: np.ndarray, y: np.ndarray, sigma_hat: np.ndarray,
             trigger: int | np.ndarray = NO_TRIGGER) -> ObserverOutput:
        """Process sample k.

        Parameters
        ----------
        k : int
            Sample index (consecutive: k of the previous call + 1).
        u : numpy.ndarray
            (nu,) inputs u_k (batch: (N, nu)).
        y : numpy.ndarray
            (ny,) measurements y_k, output units (batch: (N, ny)).
        sigma_hat : numpy.ndarray
            (ny,) sigma^_k from the estimator at k - 1 (zeros before detection).
        trigger : int
            Guard index decided by AGEI at k - 1, or ``NO_TRIGGER`` (batch: (N,) int).

        Returns
        -------
        ObserverOutput

        Raises
        ------
        MessageError
            Single stream: an implausible sample (outside the plant's ``limits`` or far
            from the prediction, :mod:`fd_monitor.core.plausibility`); no state has changed.
        """
        if self.batch is None:
            return self.step1(k, as_floats(u), as_floats(y), as_floats(sigma_hat), int(trigger))[0]
        q, x, yt = self.step_batch(k, u, y, sigma_hat, np.asarray(trigger, dtype=int))
        return ObserverOutput(k, q, x.copy(), yt)
