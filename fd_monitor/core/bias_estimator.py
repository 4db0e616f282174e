"""Adaptive sensor-bias estimator with projection (Heracleous et al., eq. 23-26).

Started at the first detection K_d (the first sample at which the detector raises any alarm)::

    x^s_{k+1} = f(q^_k, x^s_k, u_k) + Lambda eps_k,      x^s_{K_d} = y_{K_d}       (23)
    y^s_k     = x^s_k + sigma^_k                                                  (24)
    sigma^_{k+1} = sigma^_k + P[Gamma eps_k],            sigma^_{K_d} = 0          (25)
    eps_k = y_k - y^s_k

with the projection (26) onto the ball |sigma^| <= M_sigma. Before K_d, sigma^ = 0.

**Initial state (one deviation from the paper, stated).** With ``x^s_{K_d} = y_{K_d}`` the
initial state error equals the bias, and a bias is told apart from a state offset only through
the plant's own dynamics ``(I - J) sigma``: along three_tank's slowest mode (time constant about
285 s) that takes many minutes. With ``init = "presmoother"`` (the default written by the
designer) the estimator instead starts from a fault-free state estimate: a small-gain observer
``z <- f(q^, z + alpha (y - z), u)`` runs before detection on measurements delayed by D samples
(``D > `` the filter memory, so the bias, which can only be detected within the filter window
after it appears, has not entered z), and at K_d z is propagated through the D buffered
samples. ``init = "measurement"`` is the paper's ``x^s_{K_d} = y_{K_d}``.

**Mode uncertainty (an addition).** The estimator's model uses q^; while AGEI expects (or has
just executed) an event that the residuals can see, q^ may be wrong and the mismatch would be
learnt as a bias. At such samples (``hold``) sigma^ is kept and the estimator state is
re-anchored on the compensated measurement, ``x^s_{k+1} = f(q^_k, y_k - sigma^_k, u_k)``. This
makes operational the paper's assumption that learning happens between autonomous events.

**Isolation rule.** Sensor i is isolated as faulty at sample k when the estimator has run for
at least ``isolation_delay`` samples (the designed convergence time) and
``|sigma^_{i,k+1}| > isolation_threshold_i``; healthy sensors' estimates converge near zero
(within the designed noise-induced bound, below the threshold) and faulty ones do not. The flag
is evaluated every sample (not latched).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Sequence
from typing import Any, cast

import numpy as np

from fd_monitor.core.filters import as_floats, linear_map
from fd_monitor.core.gap import gap_values
from fd_monitor.core.hybrid_observer import ModeDynamics
from fd_monitor.core.lazy import LazyArray, Output
from fd_monitor.core.thresholds import DiagnosisGains
from fd_monitor.model.system import System

__all__ = ["BiasEstimator", "BiasOutput", "PREDICTION_CHECK", "project", "matvec"]

#: After a bridged gap the estimator's predicted state is kept when every output's error
#: ``eps`` moved by at most this many measurement-noise bounds since the sample before the
#: gap (two noise samples and the bias drift); else it is re-anchored
#: (:meth:`BiasEstimator.bridge`).
PREDICTION_CHECK = 3.0


def _matvec1(M: np.ndarray) -> Callable[[Sequence[float]], list[float]]:
    """``x -> M x`` on floats, each row summed as :func:`matvec` sums it (<= 7 terms)."""
    M = np.atleast_2d(M)
    return linear_map([[(M[i, j], j) for j in range(M.shape[1])] for i in range(M.shape[0])])


def _seq_sum(v: Sequence[float]) -> float:
    """Sum left to right (numpy's row sum of <= 7 terms, see matvec)."""
    acc = v[0]
    for a in v[1:]:
        acc += a
    return acc



def _learn_step(Lam: np.ndarray, Gam: np.ndarray, n: int, ny: int) -> Callable[..., Any]:
    """``f(y, xs, sg, fx, M) -> (eps, x^s_{k+1}, sigma^_{k+1} or None)``, compiled once:

    ``eps = y - xs - sg``, ``x^s_{k+1} = fx + Lambda eps``, and ``sigma^_{k+1} = sg +
    Gamma eps`` unless the projection (eq. 26) applies (``|sg| >= M`` and the step points
    outward: None, the caller projects). The single-stream step's operations in its order
    (each row of Lambda eps, Gamma eps, sg.sg and sg.step summed left to right, as
    :func:`_matvec1` and :func:`_seq_sum` do), so the same bits.
    """
    Lam, Gam = np.atleast_2d(Lam), np.atleast_2d(Gam)

    def row(M: np.ndarray, i: int) -> str:
        return " + ".join(f"({float(M[i, j])!r}) * e{j}" for j in range(M.shape[1]))

    L = [f"s{i} = sg[{i}]" for i in range(ny)]
    L += [f"e{i} = y[{i}] - xs[{i}] - s{i}" for i in range(ny)]
    L += [f"t{i} = {row(Gam, i)}" for i in range(Gam.shape[0])]
    eps = ", ".join(f"e{i}" for i in range(ny))
    xn = ", ".join(f"fx[{i}] + ({row(Lam, i)})" for i in range(Lam.shape[0]))
    norm2 = " + ".join(f"s{i} * s{i}" for i in range(ny)) or "0.0"
    out = " + ".join(f"s{i} * t{i}" for i in range(ny)) or "0.0"
    sig = ", ".join(f"s{i} + t{i}" for i in range(ny))
    L += [f"if sqrt({norm2}) >= M and {out} > 0.0:",
          f"    return [{eps}], [{xn}], None",
          f"return [{eps}], [{xn}], [{sig}]"]
    src = "def learn(y, xs, sg, fx, M):\n" + "\n".join("    " + a for a in L) + "\n"
    ns: dict[str, Any] = {"sqrt": math.sqrt, "inf": math.inf, "nan": math.nan}
    exec(src, ns)
    return cast(Callable[..., Any], ns["learn"])


def _frozen(a: np.ndarray) -> np.ndarray:
    """A read-only array (shared by every output that carries it)."""
    a.flags.writeable = False
    return a


def matvec(M: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Row-wise ``M x`` for X (N, m) -> (N, p), summed in a fixed order (N-independent bits).

    numpy sums a contiguous row of up to 7 terms left to right (8 and more pairwise): the
    single-stream float path relies on the former (checked by a test).
    """
    return np.asarray((M[None, :, :] * X[:, None, :]).sum(axis=2))


def project(sigma: np.ndarray, step: np.ndarray, Gamma: np.ndarray,
            M_sigma: float) -> np.ndarray:
    """Projection operator P_sigma of eq. 26 (batched).

    Parameters
    ----------
    sigma : numpy.ndarray
        (N, ny) sigma^_k.
    step : numpy.ndarray
        (N, ny) Gamma eps_k.
    Gamma : numpy.ndarray
        (ny, ny) SPD learning rate.
    M_sigma : float
        Radius of Theta_sigma.

    Returns
    -------
    numpy.ndarray
        (N, ny) the projected update.
    """
    norm = np.sqrt((sigma * sigma).sum(axis=1))
    outward = (sigma * step).sum(axis=1)  # sigma^T Gamma eps
    act = (norm >= M_sigma) & (outward > 0.0)
    if not act.any():
        return step
    s = sigma[act]
    Gs = matvec(Gamma, s)                 # Gamma sigma
    den = (s * Gs).sum(axis=1)            # sigma^T Gamma sigma
    out = step.copy()
    out[act] = step[act] - Gs * (outward[act] / den)[:, None]
    return out


class BiasOutput(Output):
    """Estimator output at sample k (published as the bias estimate).

    Attributes
    ----------
    k : int
    sigma_hat : numpy.ndarray
        (ny,) sigma^_{k+1}: the estimate the observer uses at k + 1, output units.
    isolated : numpy.ndarray
        (ny,) bool isolation flags.
    active : bool
        The estimator has started (k >= K_d).
    k_detect : int
        K_d, or -1 before the first detection.

    :meth:`payload` names the fields (:mod:`fd_monitor.wire.topics`: their topic).
    """

    __slots__ = ("_isolated", "_sigma_hat", "active", "k", "k_detect")
    #: the keys of :meth:`payload`, in its order
    payload_names = ("sigma_hat", "isolated", "active", "k_detect")
    FIELDS = ("k", "sigma_hat", "isolated", "active", "k_detect")
    sigma_hat = LazyArray()
    isolated = LazyArray()

    def __init__(self, k: int, sigma_hat: Any, isolated: Any, active: bool | np.ndarray,
                 k_detect: int | np.ndarray) -> None:
        self.k, self._sigma_hat, self._isolated = k, sigma_hat, isolated
        self.active, self.k_detect = active, k_detect

    def payload(self) -> dict[str, Any]:
        """Field name -> value: ``sigma_hat``, ``isolated``, ``active``, ``k_detect``."""
        return {"sigma_hat": self.sigma_hat, "isolated": self.isolated, "active": self.active,
                "k_detect": self.k_detect}


class BiasEstimator:
    """Adaptive sensor-bias estimator, eq. 23-26, with isolation.

    Parameters
    ----------
    system : System
    gains : DiagnosisGains
    batch : int or None
    """

    def __init__(self, system: System, gains: DiagnosisGains, *,
                 batch: int | None = None) -> None:
        self.system = system
        self.gains = gains
        self.f = ModeDynamics(system)
        self.batch = batch
        self.N = 1 if batch is None else int(batch)
        # Single stream on Python floats where numpy's row sums are sequential (<= 7 terms,
        # see matvec); each matrix row a fixed-order dot product.
        self._fast = batch is None and max(system.n, system.ny) <= 7
        if self._fast:
            self._Lam1 = _matvec1(gains.Lambda)
            self._Gam1 = _matvec1(gains.Gamma)
            self._iso_thr1 = np.ravel(gains.isolation_threshold).tolist()
            self._zeros1 = _frozen(np.zeros(system.ny))
            self._false1 = _frozen(np.zeros(system.ny, dtype=bool))
            self._learn1 = _learn_step(gains.Lambda, gains.Gamma, system.n, system.ny)
            self._iso1 = eval("lambda s: [" + ", ".join(
                f"abs(s[{i}]) > {t!r}" for i, t in enumerate(self._iso_thr1)) + "]",
                {"inf": math.inf, "nan": math.nan})
            self._no_iso1 = [False] * system.ny
            a, m = float(gains.presmoother_gain), min(system.n, system.ny)
            self._blend1 = eval("lambda z, y: [" + ", ".join(
                f"z[{i}] + {a!r} * (y[{i}] - z[{i}])" for i in range(m)) + "]",
                {"inf": math.inf, "nan": math.nan})
        self.reset()

    def reset(self) -> None:
        """Back to inactive, sigma^ = 0."""
        n, ny = self.system.n, self.system.ny
        self._active1, self._k_detect1 = False, -1
        self._xs1: list[float] = [0.0] * n
        self._sigma1: list[float] = [0.0] * ny
        self._z1: list[float] = []
        self._buf1: deque[tuple[list[float], list[float], int]] = deque()
        self.active = np.zeros(self.N, dtype=bool)
        self.k_detect = np.full(self.N, -1, dtype=int)
        self.x_s = np.zeros((self.N, n))
        self.sigma = np.zeros((self.N, ny))
        self.z = np.zeros((self.N, n))
        self._buf: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self._z_started = False
        #: the last sample stepped (None: none yet) and its (u, y, q^), for a bridge
        self._k_last: int | None = None
        self._last: tuple[Any, Any, Any] | None = None
        self._bridged = False
        self._eps1: list[float] | None = None       # eps of the last learning step
        self._eps: np.ndarray | None = None
        self._vbar = np.asarray(self.system.measurement_noise, dtype=float).reshape(-1)
        self._check1 = (PREDICTION_CHECK * self._vbar).tolist()

    def bridge(self, k: int, u: Any, y: Any) -> None:
        """The next sample is ``(k, u_k, y_k)``; those after the last one stepped are lost
        (a short hole).

        sigma^, K_d and the isolation survive. Active: the state x^s is predicted through
        the gap by the model, ``x^s <- f(q^, x^s, u)`` per lost sample (u interpolated,
        :mod:`fd_monitor.core.gap`; q^ the last one), without correction and without
        learning. At the next sample the prediction is checked: when some output's error
        ``eps = y - x^s - sigma^`` moved by more than :data:`PREDICTION_CHECK` noise bounds
        since the sample before the gap (an input the interpolation missed: a controller's
        step inside the gap), the state is re-anchored on the compensated measurement
        instead (the ``hold`` step: sigma^ kept), so the prediction error is not learnt as a
        bias. Re-anchoring after every gap instead makes a slow plant's estimator tell a
        state offset from a bias anew each time (three_tank_bias_h1 with one sample lost in
        13: all three sensors isolated); predicting always let a set-point step inside a
        10-sample hole of the DC motor be learnt as a 0.17 rad/s bias. Before detection: the
        pre-smoother's delayed buffer gets the interpolated samples, so it stays D samples
        long in time and z is predicted through the gap. Nothing before the first sample.

        Parameters
        ----------
        k : int
        u : array_like
            (nu,) u_k.
        y : array_like
            (ny,) y_k, output units.
        """
        if self._k_last is None or self._last is None:
            return
        missing = int(k) - self._k_last - 1
        if missing <= 0:
            return
        u0, y0, q0 = self._last
        pre = self.gains.estimator_init == "presmoother"
        self._bridged = True                      # the next step checks the prediction
        # batch: (N, .) arrays, the next sample broadcast to every run
        u1 = np.broadcast_to(np.asarray(u, dtype=float), np.shape(u0))
        y1 = np.broadcast_to(np.asarray(y, dtype=float), np.shape(y0))
        for uj, yj in zip(gap_values(u0, u1, missing), gap_values(y0, y1, missing)):
            if self._fast:
                if self._active1:
                    self._xs1 = self.f.step1(q0, self._xs1, uj.tolist())
                elif pre:
                    self._presmooth1(uj.tolist(), yj.tolist(), q0)
                continue
            act = self.active
            if act.any():
                self.x_s[act] = self.f(q0[act], self.x_s[act], uj[act])
            if pre and not act.all():
                self._presmooth(uj, yj, q0)
        self._k_last = int(k) - 1

    def step_batch(self, k: int, u: np.ndarray, y: np.ndarray, mode: np.ndarray,
                   alarm: np.ndarray, hold: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray]:
        """Batched step: (N, nu), (N, ny), (N,), (N, ny) bool, (N,) bool -> (sigma^, isolated)."""
        g = self.gains
        self._k_last, self._last = k, (u.copy(), y.copy(), mode.copy())
        if self._bridged:
            self._bridged = False
            if self._eps is not None and self.active.any():
                # after a bridged gap: re-anchor the active runs whose predicted state is
                # off (see bridge)
                moved = np.abs((y - self.x_s - self.sigma) - self._eps)
                off = self.active & (moved > PREDICTION_CHECK * self._vbar).any(axis=1)
                hold = off if hold is None else (hold | off)
        presmooth = g.estimator_init == "presmoother" and not self.active.all()
        if presmooth:
            self._presmooth(u, y, mode)
        start = ~self.active & alarm.any(axis=1)
        if start.any():
            self.active[start] = True
            self.k_detect[start] = k
            self.sigma[start] = 0.0
            if g.estimator_init == "presmoother":
                self.x_s[start] = self._propagate(start)
            else:
                self.x_s[start] = y[start]
        act = self.active
        if act.any():
            if act.all():
                xs, sg, yy, uu, qq = self.x_s, self.sigma, y, u, mode
            else:
                xs, sg, yy, uu, qq = self.x_s[act], self.sigma[act], y[act], u[act], mode[act]
            eps = yy - xs - sg
            if act.all():
                self._eps = eps.copy()
            x_next = self.f(qq, xs, uu) + matvec(g.Lambda, eps)
            s_next = sg + project(sg, matvec(g.Gamma, eps), g.Gamma, g.M_sigma)
            if hold is not None:
                hd = hold if act.all() else hold[act]
                if hd.any():
                    x_next[hd] = self.f(qq[hd], yy[hd] - sg[hd], uu[hd])
                    s_next[hd] = sg[hd]
            if act.all():
                self.x_s, self.sigma = x_next, s_next
            else:
                self.x_s[act], self.sigma[act] = x_next, s_next
        ran = act & (k - self.k_detect >= g.isolation_delay)
        isolated = ran[:, None] & (np.abs(self.sigma) > g.isolation_threshold[None, :])
        return self.sigma.copy(), isolated

    def step1(self, k: int, u: list[float], y: list[float], mode: int, alarm: Sequence[bool],
              hold: bool) -> tuple[BiasOutput, list[float]]:
        """Single stream on Python floats: the arithmetic of :meth:`step_batch` for one run.

        Returns the output and its sigma^_{k+1} as a list (for the observer at k + 1).
        Only when ``max(n, ny) <= 7`` (else :meth:`step` runs :meth:`step_batch`).
        """
        g = self.gains
        f = self.f.step1
        self._k_last, self._last = k, (u, y, mode)
        if self._bridged:
            self._bridged = False
            if self._active1 and self._eps1 is not None:
                # after a bridged gap: re-anchor if the predicted state is off (see bridge)
                hold = hold or any(
                    abs(a - b - c - e) > t for a, b, c, e, t in
                    zip(y, self._xs1, self._sigma1, self._eps1, self._check1))
        if g.estimator_init == "presmoother" and not self._active1:
            self._presmooth1(u, y, mode)
        if not self._active1 and any(alarm):
            self._active1, self._k_detect1 = True, k
            self._sigma1 = [0.0] * len(self._sigma1)
            if g.estimator_init == "presmoother":
                # open loop from z through the buffered samples up to (excluding) the newest
                x = self._z1
                for i, (uo, _, qo) in enumerate(self._buf1):
                    if i == len(self._buf1) - 1:
                        break
                    x = f(qo, x, uo)
                self._xs1 = list(x)
            else:
                self._xs1 = list(y)
        if not self._active1:
            return BiasOutput(k, self._zeros1, self._false1, False, -1), self._sigma1
        xs, sg = self._xs1, self._sigma1
        if hold:
            self._xs1 = f(mode, [a - b for a, b in zip(y, sg)], u)
        else:
            # eps, x^s_{k+1} and (inside the ball) sigma^_{k+1} in one compiled call
            st = self.f._steps1                  # the compiled model step, when there is one
            fx = st[mode](xs, u) if st else f(mode, xs, u)
            self._eps1, self._xs1, sig1 = self._learn1(y, xs, sg, fx, g.M_sigma)
            if sig1 is None:
                eps = self._eps1
                step = self._Gam1(eps)
                # projection (eq. 26), as project() does it for one run
                outward = _seq_sum([a * b for a, b in zip(sg, step)])
                Gs = self._Gam1(sg)
                c = outward / _seq_sum([a * b for a, b in zip(sg, Gs)])
                step = [a - b * c for a, b in zip(step, Gs)]
                sig1 = [a + b for a, b in zip(sg, step)]
            self._sigma1 = sig1
        sig = self._sigma1
        iso = self._iso1(sig) if k - self._k_detect1 >= g.isolation_delay else self._no_iso1
        return BiasOutput(k, sig, iso, True, self._k_detect1), sig

    def _presmooth1(self, u: list[float], y: list[float], mode: int) -> None:
        """Delayed small-gain observer (single stream): z estimates x at the oldest buffered
        sample."""
        g = self.gains
        if not self._z1:
            self._z1 = list(y)
        self._buf1.append((u, y, mode))
        if len(self._buf1) > g.presmoother_delay:
            uo, yo, qo = self._buf1.popleft()
            st = self.f._steps1
            zb = self._blend1(self._z1, yo)              # z + alpha (y - z), alpha written in
            self._z1 = st[qo](zb, uo) if st else self.f.step1(qo, zb, uo)

    def _presmooth(self, u: np.ndarray, y: np.ndarray, mode: np.ndarray) -> None:
        """Delayed small-gain observer: z estimates x at the oldest buffered sample."""
        D = self.gains.presmoother_delay
        if not self._z_started:
            self.z = y.copy()
            self._z_started = True
        self._buf.append((u.copy(), y.copy(), mode.copy()))
        if len(self._buf) > D:
            uo, yo, qo = self._buf.pop(0)
            a = self.gains.presmoother_gain
            self.z = self.f(qo, self.z + a * (yo - self.z), uo)

    def _propagate(self, sel: np.ndarray) -> np.ndarray:
        """Open-loop model from z through the buffered samples up to (excluding) the newest."""
        x = self.z[sel]
        for uo, _, qo in self._buf[:-1]:
            x = self.f(qo[sel], x, uo[sel])
        return np.asarray(x)

    def step(self, k: int, u: np.ndarray, y: np.ndarray, mode: int | np.ndarray,
             alarm: np.ndarray, mode_uncertain: bool | np.ndarray = False) -> BiasOutput:
        """Process sample k.

        Parameters
        ----------
        k : int
        u : numpy.ndarray
            (nu,) u_k.
        y : numpy.ndarray
            (ny,) raw measurement y_k (not compensated), output units.
        mode : int
            q^_k (observer).
        alarm : numpy.ndarray
            (ny,) bool alarm flags of the detector at k (the first alarm starts the estimator).
        mode_uncertain : bool
            ``AgeiOutput.mode_uncertain`` at k: hold sigma^ (see the module doc).

        Returns
        -------
        BiasOutput
        """
        if self._fast:
            return self.step1(k, as_floats(u), as_floats(y), int(mode), np.ravel(alarm).tolist(),
                              bool(np.asarray(mode_uncertain)))[0]
        if self.batch is None:
            s, iso = self.step_batch(k, np.asarray(u, float)[None], np.asarray(y, float)[None],
                                     np.array([int(np.asarray(mode))]),
                                     np.asarray(alarm, bool)[None],
                                     np.array([bool(np.asarray(mode_uncertain))]))
            return BiasOutput(k, s[0], iso[0], bool(self.active[0]), int(self.k_detect[0]))
        s, iso = self.step_batch(k, u, y, np.asarray(mode, int), np.asarray(alarm, bool),
                                 np.broadcast_to(np.asarray(mode_uncertain, bool), (self.N,)))
        return BiasOutput(k, s, iso, self.active.copy(), self.k_detect.copy())
