"""Guaranteed bounds of the nonlinear remainder over a declared envelope (Assumption 4).

The remainder of the sensor-bias chain (see :mod:`fd_monitor.design.thresholds`) is
``rho(x, v) = f(x + v) - f(x) - A_q v`` for every state x of the envelope box of mode q and
every noise ``|v_j| <= v_bar_j``. Its bound ``rho_bar`` is computed here as a *bound*, not a
sample:

* linear modes: ``rho = (A_d - A_q) v`` exactly, ``rho_bar = |A_d - A_q| v_bar`` (0 when A_q
  is the mode's own matrix, which the designer uses);
* nonlinear models with an enclosure (``three_tank``): interval arithmetic over a grid of
  boxes covering the envelope. Each intermediate quantity a of one RK4 step carries
  (i) an interval enclosing a(x) over the box and (ii) an affine form ``L v + [r_lo, r_hi]``
  enclosing its change ``a(x + v) - a(x)`` for every v of the noise box (a first-order
  Taylor model in v: keeping v symbolic is what lets ``- A_q v`` cancel the linear part
  instead of doubling it). Sums and constant factors are exact on the affine form. The
  Torricelli square roots use the mean-value form ``phi(z + d) - phi(z) = phi'(xi) d`` with
  an interval enclosure of phi' over the hull of z and z + d where that hull stays away from
  the singular point of sqrt; where it does not (levels equal within the noise, a tank
  near empty, h3 at the upper pipe), phi' is unbounded, and the exact range of
  ``phi(z + d) - phi(z)`` over the box is used instead (both square-root forms are monotone,
  and the difference is unimodal in z: its extremes are at the box ends or at one known
  interior point). Per box ``|rho_i| <= sum_j |L_ij - A_q,ij| v_bar_j + max|r_i|``; the
  maximum over the boxes is the bound, plus 1e-12 for floating-point rounding;
* other nonlinear models: the maximum over ``samples`` points of the box (half the noise at
  the box's vertices) times ``1 + margin``: a *sample*, labelled so in the gain file.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from fd_monitor.model.nonlinear import get_model

__all__ = ["DiffForm", "remainder_bound", "jacobian_centre", "ENCLOSURES", "box_grid"]

#: added to every interval bound for floating-point rounding (levels ~1 m, ~100 operations)
ROUNDING = 1e-12


@dataclass(frozen=True)
class DiffForm:
    """Enclosure of a scalar a over N boxes: a(x) in [lo, hi], a(x+v) - a(x) in L v + [rlo, rhi].

    Attributes
    ----------
    lo, hi : numpy.ndarray
        (N,) value range over the box.
    L : numpy.ndarray
        (N, m) coefficients of the noise v (m noise components).
    rlo, rhi : numpy.ndarray
        (N,) remainder interval of the change.
    """

    lo: np.ndarray
    hi: np.ndarray
    L: np.ndarray
    rlo: np.ndarray
    rhi: np.ndarray

    def __add__(self, o: DiffForm) -> DiffForm:
        return DiffForm(self.lo + o.lo, self.hi + o.hi, self.L + o.L, self.rlo + o.rlo,
                        self.rhi + o.rhi)

    def __sub__(self, o: DiffForm) -> DiffForm:
        return DiffForm(self.lo - o.hi, self.hi - o.lo, self.L - o.L, self.rlo - o.rhi,
                        self.rhi - o.rlo)

    def scale(self, c: float) -> DiffForm:
        """c a for a constant c."""
        if c >= 0.0:
            return DiffForm(c * self.lo, c * self.hi, c * self.L, c * self.rlo, c * self.rhi)
        return DiffForm(c * self.hi, c * self.lo, c * self.L, c * self.rhi, c * self.rlo)

    def shift(self, c: float) -> DiffForm:
        """a + c for a constant c (the change is unchanged)."""
        return DiffForm(self.lo + c, self.hi + c, self.L, self.rlo, self.rhi)

    def change_range(self, v_bar: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N,) lower and upper ends of the change over the noise box |v| <= v_bar."""
        w = np.abs(self.L) @ v_bar
        return self.rlo - w, self.rhi + w


def constant(lo: np.ndarray, hi: np.ndarray, m: int) -> DiffForm:
    """A quantity the noise does not change (an input): value in [lo, hi], change 0."""
    z = np.zeros_like(lo)
    return DiffForm(lo, hi, np.zeros((lo.size, m)), z, z.copy())


def _ssqrt(z: np.ndarray) -> np.ndarray:
    return np.sign(z) * np.sqrt(np.abs(z))


def _rsqrt(z: np.ndarray) -> np.ndarray:
    return np.sqrt(np.maximum(z, 0.0))


def _sqrt_form(a: DiffForm, v_bar: np.ndarray, signed: bool) -> DiffForm:
    """Enclosure of ``sign(a) sqrt|a|`` (signed) or ``sqrt(max(a, 0))``."""
    phi = _ssqrt if signed else _rsqrt
    dl, du = a.change_range(v_bar)
    lo, hi = phi(a.lo), phi(a.hi)                       # both are nondecreasing
    # exact range of phi(z + d) - phi(z) over z in [lo, hi], d in [dl, du]: nondecreasing in
    # d; in z unimodal with the extreme at -d/2 (signed) or at 0 / -d (sqrt(max(., 0))).
    def ends(d: np.ndarray, pick: Callable[..., np.ndarray]) -> np.ndarray:
        cands = [a.lo, a.hi]
        cands += [np.clip(-0.5 * d, a.lo, a.hi)] if signed else \
            [np.clip(np.zeros_like(d), a.lo, a.hi), np.clip(-d, a.lo, a.hi)]
        vals = [phi(z + d) - phi(z) for z in cands]
        return np.asarray(pick(np.stack(vals), axis=0))

    e_lo, e_hi = ends(dl, np.min), ends(du, np.max)
    # mean-value form where the hull of z and z + d avoids the singular point
    x_lo, x_hi = a.lo + np.minimum(dl, 0.0), a.hi + np.maximum(du, 0.0)
    if signed:
        smooth = (x_lo > 0.0) | (x_hi < 0.0)
        m1 = np.where(x_lo > 0.0, x_lo, -x_hi)
        m2 = np.where(x_lo > 0.0, x_hi, -x_lo)
        mid = np.abs(0.5 * (a.lo + a.hi))
    else:
        smooth = x_lo > 0.0
        m1, m2, mid = x_lo, x_hi, 0.5 * (a.lo + a.hi)
    with np.errstate(divide="ignore", invalid="ignore"):
        p_lo = np.where(smooth, 0.5 / np.sqrt(np.where(smooth, m2, 1.0)), 0.0)
        p_hi = np.where(smooth, 0.5 / np.sqrt(np.where(smooth, m1, 1.0)), 0.0)
        c = np.where(smooth, 0.5 / np.sqrt(np.where(smooth, np.maximum(mid, m1), 1.0)), 0.0)
    # (phi'(xi) - c) d with phi'(xi) - c in [p_lo - c, p_hi - c], d in [dl, du]
    prods = np.stack([(p_lo - c) * dl, (p_lo - c) * du, (p_hi - c) * dl, (p_hi - c) * du])
    r_lo = c * a.rlo + prods.min(axis=0)
    r_hi = c * a.rhi + prods.max(axis=0)
    L = c[:, None] * a.L
    # keep whichever enclosure of the change is narrower
    w_mv = 2.0 * (np.abs(L) @ v_bar) + (r_hi - r_lo)
    use_mv = smooth & (w_mv < e_hi - e_lo)
    L = np.where(use_mv[:, None], L, 0.0)
    r_lo = np.where(use_mv, r_lo, e_lo)
    r_hi = np.where(use_mv, r_hi, e_hi)
    return DiffForm(lo, hi, L, r_lo, r_hi)


def _three_tank_enclosure(params: Mapping[str, float], dt: float, x_lo: np.ndarray,
                          x_hi: np.ndarray, u_lo: np.ndarray, u_hi: np.ndarray,
                          v_bar: np.ndarray) -> list[DiffForm]:
    """Enclosures of the three components of :func:`fd_monitor.model.nonlinear` ``three_tank``'s
    RK4 step over N boxes: x (N, 3), u (N, 3) ranges, noise on the three levels."""
    N, m = x_lo.shape[0], 3
    s2g = math.sqrt(2.0 * float(params["g"]))
    a_t = float(params["tank_area"])
    c13 = (float(params["pipe_area"]) + float(params["bypass_area"])) * s2g
    c32 = float(params["pipe_area"]) * s2g
    cu = float(params["upper_area"]) * s2g
    co = float(params["outflow_area"]) * s2g
    leaks = [float(params[f"leak_area_{i}"]) * s2g for i in (1, 2, 3)]
    h_up = float(params["h_upper"])
    q1 = constant(np.maximum(u_lo[:, 0], 0.0), np.maximum(u_hi[:, 0], 0.0), m)
    q2 = constant(np.maximum(u_lo[:, 1], 0.0), np.maximum(u_hi[:, 1], 0.0), m)
    zero = constant(np.zeros(N), np.zeros(N), m)

    def root(a: DiffForm, c: float, signed: bool) -> DiffForm:
        return zero if c == 0.0 else _sqrt_form(a, v_bar, signed).scale(c)

    def rhs(h: list[DiffForm]) -> list[DiffForm]:
        h1, h2, h3 = h
        q13 = root(h1 - h3, c13, True)
        q32 = root(h3 - h2, c32, True)
        q32u = root(h3.shift(-h_up), cu, False)
        q20 = root(h2, co, False)
        lk = [root(hi, c, False) for hi, c in zip(h, leaks)]
        return [(q1 - q13 - lk[0]).scale(1.0 / a_t),
                (q2 + q32 + q32u - q20 - lk[1]).scale(1.0 / a_t),
                (q13 - q32 - q32u - lk[2]).scale(1.0 / a_t)]

    def axpy(x: list[DiffForm], c: float, k: list[DiffForm]) -> list[DiffForm]:
        return [xi + ki.scale(c) for xi, ki in zip(x, k)]

    eye = np.eye(m)
    x = [DiffForm(x_lo[:, j], x_hi[:, j], np.repeat(eye[j][None], N, axis=0), np.zeros(N),
                  np.zeros(N)) for j in range(m)]
    sub = int(params.get("substeps", 1))
    h = dt / sub
    for _ in range(sub):
        k1 = rhs(x)
        k2 = rhs(axpy(x, 0.5 * h, k1))
        k3 = rhs(axpy(x, 0.5 * h, k2))
        k4 = rhs(axpy(x, h, k3))
        x = [xi + (a + b.scale(2.0) + c.scale(2.0) + d).scale(h / 6.0)
             for xi, a, b, c, d in zip(x, k1, k2, k3, k4)]
    return x


#: model name -> enclosure(params, dt, x_lo, x_hi, u_lo, u_hi, v_bar) -> per-state DiffForm
ENCLOSURES: dict[str, Callable[..., list[DiffForm]]] = {"three_tank": _three_tank_enclosure}


def box_grid(lo: np.ndarray, hi: np.ndarray, width: float,
             chunk: int = 50000) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Boxes of side <= ``width`` covering [lo, hi] (n,), yielded in chunks of (M, n) arrays."""
    cells = [max(1, math.ceil((b - a) / width - 1e-9)) for a, b in zip(lo, hi)]
    edges = [np.linspace(a, b, c + 1) for a, b, c in zip(lo, hi, cells)]
    total = int(np.prod(cells))
    for start in range(0, total, chunk):
        idx = np.array(np.unravel_index(np.arange(start, min(total, start + chunk)), cells)).T
        blo = np.column_stack([edges[j][idx[:, j]] for j in range(lo.size)])
        bhi = np.column_stack([edges[j][idx[:, j] + 1] for j in range(lo.size)])
        yield blo, bhi


def _box_enclosures(enc: Callable[..., list[DiffForm]], params: Mapping[str, float], dt: float,
                    x_lo: np.ndarray, x_hi: np.ndarray, u_lo: np.ndarray, u_hi: np.ndarray,
                    v_bar: np.ndarray, box_width: float
                    ) -> Iterator[tuple[int, list[DiffForm]]]:
    """(M, forms) per chunk of the grid boxes of [x_lo, x_hi]: the enclosures ``enc`` gives
    for M boxes at once, the input over its whole range [u_lo, u_hi]."""
    for blo, bhi in box_grid(x_lo, x_hi, box_width):
        M = blo.shape[0]
        yield M, enc(params, dt, blo, bhi, np.repeat(u_lo[None], M, axis=0),
                     np.repeat(u_hi[None], M, axis=0), v_bar)


def remainder_bound(system: Any, plant: Any, q: int, A: np.ndarray, x_lo: np.ndarray,
                    x_hi: np.ndarray, u_lo: np.ndarray, u_hi: np.ndarray, v_bar: np.ndarray,
                    *, box_width: float, samples: int, margin: float,
                    rng: np.random.Generator) -> tuple[np.ndarray, dict[str, Any]]:
    """Bound of |f(q, x + v, u) - f(q, x, u) - A v| over the box and |v| <= v_bar.

    Parameters
    ----------
    system : System
    plant : SampledPlant
    q : int
        Mode.
    A : numpy.ndarray
        (n, n) the linear part A_q used by the runtime's noise term.
    x_lo, x_hi, u_lo, u_hi : numpy.ndarray
        (n,), (nu,) envelope of mode q.
    v_bar : numpy.ndarray
        (n,) noise bound (y = x + v).
    box_width : float
        Side of the grid boxes (interval method), state units.
    samples, margin : int, float
        Sampled fallback for models without an enclosure.
    rng : numpy.random.Generator

    Returns
    -------
    rho_bar : numpy.ndarray
        (n,)
    how : dict
        ``{method: exact|interval|sampled, ...}`` for the gain file.
    """
    mode = system.modes[q]
    dm = plant.modes[q]
    if mode.dynamics != "nonlinear":
        assert dm.Ad is not None
        return np.abs(dm.Ad - A) @ v_bar, {"method": "exact"}
    enc = ENCLOSURES.get(str(mode.model))
    if enc is not None:
        params = {**get_model(str(mode.model)).defaults, **dict(mode.params)}
        best = np.zeros(system.n)
        boxes = 0
        for M, forms in _box_enclosures(enc, params, plant.dt, x_lo, x_hi, u_lo, u_hi, v_bar,
                                        box_width):
            for i, fi in enumerate(forms):
                b = np.abs(fi.L - A[i][None]) @ v_bar + np.maximum(np.abs(fi.rlo),
                                                                   np.abs(fi.rhi))
                best[i] = max(best[i], float(b.max()))
            boxes += M
        return best + ROUNDING, {"method": "interval", "boxes": boxes,
                                 "box_width": float(box_width)}
    x = rng.uniform(x_lo, x_hi, (samples, system.n))
    u = rng.uniform(u_lo, u_hi, (samples, system.nu))
    vert = rng.choice(np.array([-1.0, 1.0]), (samples, system.n))
    v = np.where(rng.random((samples, 1)) < 0.5, vert, rng.uniform(-1, 1, vert.shape)) * v_bar
    qq = np.full(samples, q)
    d = plant.step(qq, x + v, u) - plant.step(qq, x, u) - v @ A.T
    return (1.0 + margin) * np.abs(d).max(axis=0), {"method": "sampled", "samples": samples,
                                                     "margin": margin}


def jacobian_centre(system: Any, plant: Any, q: int, x_lo: np.ndarray, x_hi: np.ndarray,
                    u_lo: np.ndarray, u_hi: np.ndarray, v_bar: np.ndarray, box_width: float,
                    default: np.ndarray) -> np.ndarray:
    """The linear part A_q for a declared envelope: the centre of the hull of the noise
    coefficients L of the enclosures over every box (it minimises ``max |L - A_q|`` entrywise),
    the mode's matrix for a linear mode, ``default`` for a model without an enclosure.

    A Jacobian at one point is a poor choice over a whole envelope: at its centre the three
    levels are equal, where the Torricelli flows have an unbounded derivative.
    """
    mode = system.modes[q]
    if mode.dynamics != "nonlinear":
        assert plant.modes[q].Ad is not None
        return np.asarray(plant.modes[q].Ad, dtype=float)
    enc = ENCLOSURES.get(str(mode.model))
    if enc is None:
        return default
    params = {**get_model(str(mode.model)).defaults, **dict(mode.params)}
    n = system.n
    L_lo, L_hi = np.full((n, n), np.inf), np.full((n, n), -np.inf)
    for _M, forms in _box_enclosures(enc, params, plant.dt, x_lo, x_hi, u_lo, u_hi, v_bar,
                                     box_width):
        for i, fi in enumerate(forms):
            L_lo[i] = np.minimum(L_lo[i], fi.L.min(axis=0))
            L_hi[i] = np.maximum(L_hi[i], fi.L.max(axis=0))
    return np.asarray(0.5 * (L_lo + L_hi))
