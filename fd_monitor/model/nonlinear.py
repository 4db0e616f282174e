"""Named nonlinear models: discrete-time maps ``x_{k+1} = f(x_k, u_k; params)``.

A plant file's nonlinear mode names one of these (``model: three_tank``) with its
parameters. Each model is vectorised over leading axes: ``x`` of shape (..., n) and ``u`` of
shape (..., nu) give (..., n), so Monte Carlo campaigns step many runs at once. Parameters
are floats or arrays broadcastable to the leading shape (a ``parameter`` fault makes one run's
parameter differ from another's).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np

__all__ = ["NonlinearModel", "get_model", "register_model", "GRAVITY",
           "SCHEDULING_MAPS"]

GRAVITY = 9.81  # m/s^2

Params = Mapping[str, "float | np.ndarray"]


@dataclass(frozen=True)
class NonlinearModel:
    """A named discrete-time nonlinear model.

    Attributes
    ----------
    name : str
    n_states, n_inputs : int
    param_names : tuple of str
    step : callable
        ``step(x, u, params, dt) -> x_next``; x (..., n), u (..., nu), dt in s.
    rhs : callable or None
        ``rhs(x, u, params) -> dx/dt`` of the underlying ODE, where there is one.
    defaults : dict
        Parameter defaults (a plant file may omit these).
    description : str
    ranges : dict
        Parameter name -> ``(low, high, low_open)``: the physical range a plant file's value
        must lie in (``low < v`` when ``low_open``, else ``low <= v``; ``v <= high``).
    step_floats : callable or None
        ``step_floats(x, u, params, dt) -> x_next`` for one run on Python floats (x, u and
        the result sequences of floats, params floats): the single-stream fast path, the
        same IEEE operations in the same order as ``step`` (bit-identical).
    """

    name: str
    n_states: int
    n_inputs: int
    param_names: tuple[str, ...]
    step: Callable[[np.ndarray, np.ndarray, Params, float], np.ndarray]
    rhs: Callable[[np.ndarray, np.ndarray, Params], np.ndarray] | None = None
    defaults: Mapping[str, float] = field(default_factory=dict)
    description: str = ""
    ranges: Mapping[str, tuple[float, float, bool]] = field(default_factory=dict)
    step_floats: Callable[[Sequence[float], Sequence[float], Mapping[str, float], float],
                          list[float]] | None = None
    compile_floats: Callable[[Mapping[str, float], float], Callable[
        [Sequence[float], Sequence[float]], list[float]]] | None = None


_REGISTRY: dict[str, NonlinearModel] = {}


def register_model(model: NonlinearModel) -> NonlinearModel:
    """Add ``model`` to the registry (a name may be registered once)."""
    if model.name in _REGISTRY:
        raise ValueError(f"model {model.name!r} is already registered")
    _REGISTRY[model.name] = model
    return model


def get_model(name: str) -> NonlinearModel:
    """Return the model ``name``; ``KeyError`` with the known names if there is none."""
    try:
        return _REGISTRY[name]
    except KeyError:
        raise KeyError(f"a known nonlinear model: {sorted(_REGISTRY)} (unknown model "
                       f"{name!r})") from None


def rk4(rhs: Callable[[np.ndarray, np.ndarray, Params], np.ndarray], x: np.ndarray,
        u: np.ndarray, params: Params, dt: float, substeps: int) -> np.ndarray:
    """Classical fourth-order Runge-Kutta over ``dt`` in ``substeps`` equal steps, u held."""
    h = dt / substeps
    for _ in range(substeps):
        k1 = rhs(x, u, params)
        k2 = rhs(x + 0.5 * h * k1, u, params)
        k3 = rhs(x + 0.5 * h * k2, u, params)
        k4 = rhs(x + h * k3, u, params)
        x = x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    return x


# --------------------------------------------------------------------------------------
# three_tank: T1 - T3 - T2 in series, outflow at T2 (thesis Sec. 7.2, eq. 7.11), plus a
# switched bypass valve T1-T3 and an upper pipe T3 -> T2 at height h_upper.


def _signed_flow(area: float | np.ndarray, dh: np.ndarray, g: float | np.ndarray) -> np.ndarray:
    """Torricelli flow s(dh) S sqrt(2 g |dh|) (thesis eq. 7.11-7.12), m^3/s."""
    return area * np.sign(dh) * np.sqrt(2.0 * g * np.abs(dh))


def _three_tank_rhs(x: np.ndarray, u: np.ndarray, p: Params) -> np.ndarray:
    h1, h2, h3 = x[..., 0], x[..., 1], x[..., 2]
    # Pumps cannot run backwards; levels cannot be negative in the outflow laws.
    q1 = np.maximum(u[..., 0], 0.0)
    q2 = np.maximum(u[..., 1], 0.0)
    g = p["g"]
    q13 = _signed_flow(p["pipe_area"] + p["bypass_area"], h1 - h3, g)
    q32 = _signed_flow(p["pipe_area"], h3 - h2, g)
    # Upper pipe: an overflow from T3 into T2 at height h_upper, carrying flow only while
    # h3 is above it (its area is zero in the modes where it is dry).
    q32u = p["upper_area"] * np.sqrt(2.0 * g * np.maximum(h3 - p["h_upper"], 0.0))
    q20 = p["outflow_area"] * np.sqrt(2.0 * g * np.maximum(h2, 0.0))
    l1 = p["leak_area_1"] * np.sqrt(2.0 * g * np.maximum(h1, 0.0))
    l2 = p["leak_area_2"] * np.sqrt(2.0 * g * np.maximum(h2, 0.0))
    l3 = p["leak_area_3"] * np.sqrt(2.0 * g * np.maximum(h3, 0.0))
    a = p["tank_area"]
    dh1 = (q1 - q13 - l1) / a
    dh2 = (q2 + q32 + q32u - q20 - l2) / a
    dh3 = (q13 - q32 - q32u - l3) / a
    return np.stack([dh1, dh2, dh3], axis=-1)


def _three_tank_step(x: np.ndarray, u: np.ndarray, p: Params, dt: float) -> np.ndarray:
    # One run: floats, or the observer's per-run parameter arrays of size 1. union-attr:
    # after `type(v) is float` fails, v may still be a float subclass for mypy, so the union
    # keeps float and `v.size` is flagged (the exact-type test is the cheap one here).
    if x.size == 3 and all(type(v) is float or v.size == 1 for v in p.values()):  # type: ignore[union-attr]
        return _three_tank_step_scalar(x, u, p, dt)
    return rk4(_three_tank_rhs, x, u, p, dt, int(p["substeps"]))


def _three_tank_step_scalar(x: np.ndarray, u: np.ndarray, p: Params, dt: float) -> np.ndarray:
    """One run of :func:`_three_tank_step` on Python floats (see :func:`_three_tank_floats`)."""
    # union-attr: as in _three_tank_step, `type(v) is not float` leaves float in the union.
    f = {k: v if type(v) is float else v.item() for k, v in p.items()}  # type: ignore[union-attr]
    return np.array(_three_tank_floats(x.reshape(-1).tolist(), u.reshape(-1).tolist(), f,
                                       dt)).reshape(x.shape)


def _three_tank_floats(x: Sequence[float], u: Sequence[float], f: Mapping[str, float],
                       dt: float) -> list[float]:
    """One run of :func:`_three_tank_step` on Python floats: x (3,), u (3,) -> x_next (3,).

    A single stream (the observer and the estimator in a node, offline analysis of one bag)
    pays numpy's per-call overhead on 3-element arrays ~20 times per RK4 stage; plain floats
    are an order of magnitude faster. Every operation is the same IEEE operation in the same
    order as the vectorised path (sqrt is correctly rounded in both), so the results are
    bit-identical to it — a test checks.
    """
    pipe, byp, upper, h_up = f["pipe_area"], f["bypass_area"], f["upper_area"], f["h_upper"]
    out, a, g = f["outflow_area"], f["tank_area"], f["g"]
    la1, la2, la3 = f["leak_area_1"], f["leak_area_2"], f["leak_area_3"]
    a13 = pipe + byp
    q1 = max(float(u[0]), 0.0)
    q2 = max(float(u[1]), 0.0)
    g2 = 2.0 * g
    sqrt = math.sqrt

    def rhs(h1: float, h2: float, h3: float) -> tuple[float, float, float]:
        # inline forms of sign(d) and max(v, 0.0) (the same values; calls cost here)
        d13 = h1 - h3
        d32 = h3 - h2
        q13 = a13 * (1.0 if d13 > 0.0 else (-1.0 if d13 < 0.0 else 0.0)) * sqrt(g2 * abs(d13))
        q32 = pipe * (1.0 if d32 > 0.0 else (-1.0 if d32 < 0.0 else 0.0)) * sqrt(g2 * abs(d32))
        v = h3 - h_up
        q32u = upper * sqrt(g2 * (0.0 if v < 0.0 else v))
        p1, p2, p3 = (0.0 if h1 < 0.0 else h1), (0.0 if h2 < 0.0 else h2), \
            (0.0 if h3 < 0.0 else h3)
        q20 = out * sqrt(g2 * p2)
        l1 = la1 * sqrt(g2 * p1)
        l2 = la2 * sqrt(g2 * p2)
        l3 = la3 * sqrt(g2 * p3)
        return ((q1 - q13 - l1) / a, (q2 + q32 + q32u - q20 - l2) / a,
                (q13 - q32 - q32u - l3) / a)

    h1, h2, h3 = float(x[0]), float(x[1]), float(x[2])
    substeps = int(f["substeps"])
    h = dt / substeps
    c = 0.5 * h
    w = h / 6.0
    for _ in range(substeps):
        a1, b1, c1 = rhs(h1, h2, h3)
        a2, b2, c2 = rhs(h1 + c * a1, h2 + c * b1, h3 + c * c1)
        a3, b3, c3 = rhs(h1 + c * a2, h2 + c * b2, h3 + c * c2)
        a4, b4, c4 = rhs(h1 + h * a3, h2 + h * b3, h3 + h * c3)
        h1 = h1 + w * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
        h2 = h2 + w * (b1 + 2.0 * b2 + 2.0 * b3 + b4)
        h3 = h3 + w * (c1 + 2.0 * c2 + 2.0 * c3 + c4)
    return [h1, h2, h3]


def _three_tank_compile(f: Mapping[str, float], dt: float
                        ) -> Callable[[Sequence[float], Sequence[float]], list[float]]:
    """:func:`_three_tank_floats` for one parameter set, compiled once: ``step(x, u)``.

    What depends only on the parameters is done here, not per sample: the constants are
    written into the code (``repr`` round-trips exactly), the four RK4 stages are inlined
    (no call per stage), and a flow whose area is +0.0 (a dry upper pipe, no leak) is the
    constant +0.0 it always evaluates to (``0.0 * sqrt(v)``, v finite and >= 0) instead of a
    square root. Every remaining operation is the one :func:`_three_tank_floats` does, in
    the same order, so the result is bit-identical for finite inputs (a test checks it on
    every shipped three_tank mode); the sign of Torricelli's flow is taken by branches
    that give the same products (``a * 1.0 == a``, ``a * -1.0 == -a``).
    """
    pipe, byp, upper, h_up = (float(f[k]) for k in ("pipe_area", "bypass_area",
                                                     "upper_area", "h_upper"))
    out, a, g = float(f["outflow_area"]), float(f["tank_area"]), float(f["g"])
    la = [float(f[f"leak_area_{i}"]) for i in (1, 2, 3)]
    a13 = pipe + byp
    g2 = 2.0 * g
    substeps = int(f["substeps"])
    h = dt / substeps
    c = 0.5 * h
    w = h / 6.0

    def flow(name: str, area: float, d: str) -> list[str]:
        # area * sign(d) * sqrt(g2 * |d|), the product taken left to right as the original
        return [f"if {d} > 0.0:", f"    {name} = {area!r} * sqrt({g2!r} * {d})",
                f"elif {d} < 0.0:", f"    {name} = {-area!r} * sqrt({g2!r} * -{d})",
                "else:", f"    {name} = {area * 0.0!r} * sqrt({g2!r} * abs({d}))"]

    def zero(v: float) -> bool:
        return v == 0.0

    def root_term(name: str, area: float, v: str) -> str:
        # area * sqrt(v), v >= 0 (or -0.0, inf, NaN): with a zero area, area * v has the
        # same bits (sqrt keeps v's sign, zero, infinity and NaN) without the square root
        if zero(area):
            return f"{name} = {area!r} * {v}"
        return f"{name} = {area!r} * sqrt({v})"

    def rhs(s: str, h1: str, h2: str, h3: str) -> list[str]:
        L = [f"d13 = {h1} - {h3}", f"d32 = {h3} - {h2}"]
        L += flow("q13", a13, "d13") + flow("q32", pipe, "d32")
        L += [f"v = {h3} - {h_up!r}",
              root_term("q32u", upper, f"({g2!r} * (0.0 if v < 0.0 else v))")]
        L += [f"p1 = 0.0 if {h1} < 0.0 else {h1}", f"p2 = 0.0 if {h2} < 0.0 else {h2}",
              f"p3 = 0.0 if {h3} < 0.0 else {h3}"]
        L += [root_term("q20", out, f"({g2!r} * p2)")]
        L += [root_term(f"l{i}", ai, f"({g2!r} * p{i})") for i, ai in zip((1, 2, 3), la)]
        L += [f"a{s} = (q1 - q13 - l1) / {a!r}",
              f"b{s} = (q2 + q32 + q32u - q20 - l2) / {a!r}",
              f"c{s} = (q13 - q32 - q32u - l3) / {a!r}"]
        return L

    body = ["h1, h2, h3 = x[0], x[1], x[2]",
            "q1 = u[0]", "if 0.0 > q1:", "    q1 = 0.0",
            "q2 = u[1]", "if 0.0 > q2:", "    q2 = 0.0"]
    # one substep (the shipped modes): its body without the loop
    body += [f"for _ in range({substeps}):"] if substeps != 1 else ["if True:"]
    stages = rhs("1", "h1", "h2", "h3")
    for s, prev, step in (("2", "1", c), ("3", "2", c), ("4", "3", h)):
        # the stage's state, computed once as the argument of rhs() is
        stages += [f"x1 = h1 + {step!r} * a{prev}", f"x2 = h2 + {step!r} * b{prev}",
                   f"x3 = h3 + {step!r} * c{prev}", *rhs(s, "x1", "x2", "x3")]
    stages += [f"h1 = h1 + {w!r} * (a1 + 2.0 * a2 + 2.0 * a3 + a4)",
               f"h2 = h2 + {w!r} * (b1 + 2.0 * b2 + 2.0 * b3 + b4)",
               f"h3 = h3 + {w!r} * (c1 + 2.0 * c2 + 2.0 * c3 + c4)"]
    body += ["    " + s for s in stages] + ["return [h1, h2, h3]"]
    src = "def step(x, u, sqrt=sqrt):\n" + "\n".join("    " + s for s in body) + "\n"
    ns: dict[str, Any] = {"sqrt": math.sqrt}
    exec(src, ns)
    return cast(Callable[[Sequence[float], Sequence[float]], list[float]], ns["step"])


register_model(NonlinearModel(
    name="three_tank",
    n_states=3,
    n_inputs=3,
    param_names=("tank_area", "pipe_area", "outflow_area", "bypass_area", "upper_area",
                 "h_upper", "leak_area_1", "leak_area_2", "leak_area_3", "g", "substeps"),
    step=_three_tank_step,
    rhs=_three_tank_rhs,
    step_floats=_three_tank_floats,
    compile_floats=_three_tank_compile,
    defaults={"leak_area_1": 0.0, "leak_area_2": 0.0, "leak_area_3": 0.0, "g": GRAVITY,
              "substeps": 1.0},
    description=(
        "Levels h1, h2, h3 (m) of tanks T1, T2, T3 (T1 - T3 - T2 in series, outflow at T2); "
        "inputs q1, q2 (pump flows, m^3/s) and the bypass valve command (unused by the "
        "dynamics: the valve's state is the mode). Torricelli flows (thesis eq. 7.11); the "
        "discrete map is classical RK4 over one sample in 'substeps' steps."),
    # A zero or negative tank area divides by zero or runs the levels backwards; areas and
    # heights are >= 0; RK4 substeps are a positive count (1000 is already 0.1 ms at 0.1 s).
    ranges={"tank_area": (0.0, 1.0e3, True), "pipe_area": (0.0, 1.0e3, False),
            "outflow_area": (0.0, 1.0e3, False), "bypass_area": (0.0, 1.0e3, False),
            "upper_area": (0.0, 1.0e3, False), "h_upper": (0.0, 1.0e3, False),
            "leak_area_1": (0.0, 1.0e3, False), "leak_area_2": (0.0, 1.0e3, False),
            "leak_area_3": (0.0, 1.0e3, False), "g": (0.0, 1.0e3, True),
            "substeps": (1.0, 1.0e3, False)},
))


def _three_tank_sqrt(y: np.ndarray, params: Mapping[str, Any]) -> np.ndarray:
    """rho = [1/sqrt|h1 - h3|, 1/sqrt|h3 - h2|, 1/sqrt h2] of thesis eq. 7.19 (levels in m)."""
    floor = float(params.get("min_difference", 1e-3))
    h1, h2, h3 = float(y[0]), float(y[1]), float(y[2])
    # math.sqrt: the same correctly rounded IEEE square root as np.sqrt, without a numpy
    # call per value (an LPV bank schedules at every sample)
    return np.array([1.0 / math.sqrt(max(abs(h1 - h3), floor)),
                     1.0 / math.sqrt(max(abs(h3 - h2), floor)),
                     1.0 / math.sqrt(max(h2, floor))])


#: Named maps ``(y, params) -> rho`` that schedule an LPV bank from its measurements.
SCHEDULING_MAPS: dict[str, Callable[[np.ndarray, Mapping[str, Any]], np.ndarray]] = {
    "three_tank_sqrt": _three_tank_sqrt,
}


# --------------------------------------------------------------------------------------
# dc_motor: a motor (or a robot joint's drive) with viscous and Coulomb friction, effort
# (torque) commanded; the worked example of doc/tutorial/own-robot.md.


def _dc_motor_rhs(x: np.ndarray, u: np.ndarray, p: Params) -> np.ndarray:
    w = x[..., 0]
    # Coulomb friction Fc sign(w), smoothed over coulomb_width (rad/s) so RK4 stays accurate
    friction = p["viscous"] * w + p["coulomb"] * np.tanh(w / p["coulomb_width"])
    return ((u[..., 0] - friction) / p["inertia"])[..., None]


def _dc_motor_step(x: np.ndarray, u: np.ndarray, p: Params, dt: float) -> np.ndarray:
    return rk4(_dc_motor_rhs, x, u, p, dt, int(p["substeps"]))


register_model(NonlinearModel(
    name="dc_motor",
    n_states=1,
    n_inputs=1,
    param_names=("inertia", "viscous", "coulomb", "coulomb_width", "substeps"),
    step=_dc_motor_step,
    rhs=_dc_motor_rhs,
    defaults={"coulomb_width": 0.01, "substeps": 4.0},
    description=(
        "Angular velocity w (rad/s) of a motor shaft of inertia J (kg m^2) driven by the "
        "effort tau (N m) against viscous (b w) and Coulomb (Fc sign w, smoothed as "
        "Fc tanh(w / coulomb_width)) friction: J dw/dt = tau - b w - Fc tanh(w / width); "
        "the discrete map is classical RK4 over one sample in 'substeps' steps."),
    ranges={"inertia": (0.0, 1.0e6, True), "viscous": (0.0, 1.0e6, False),
            "coulomb": (0.0, 1.0e6, False), "coulomb_width": (0.0, 1.0e6, True),
            "substeps": (1.0, 1.0e3, False)},
))
