"""Sampled plant dynamics: every mode of a :class:`~fd_monitor.model.system.System` as a
discrete map.

Linear continuous-time modes are discretised exactly with a zero-order hold on the input,
the disturbance, the affine term and process faults (all held over the sample):
``Ad = e^{A Ts}``, ``Gd = int_0^Ts e^{A s} ds [B D offset F]``, computed from the matrix
exponential of the augmented matrix ``[[A, G], [0, 0]] Ts`` (Van Loan). Discrete-time modes
are used as written; nonlinear modes call their model's discrete map. Parameter-dependent
(LPV / uncertain) modes, ``A(rho) = A + sum_j rho_j A_j`` (``A_rho``, ``B_rho``), are
integrated per sample with the scheduling signal rho(t, x) the caller gives
(:meth:`SampledPlant.step`).

All functions take a batch: states (N, n), inputs (N, nu), modes (N,) int, so Monte Carlo
runs in one array pass per mode.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from fd_monitor.model.nonlinear import get_model
from fd_monitor.model.plant_parts import Mode
from fd_monitor.model.system import System

__all__ = ["LPV_SUBSTEPS", "DiscreteMode", "SampledPlant", "rk4_step", "zoh"]

#: Runge-Kutta substeps per sample of a continuous-time parameter-dependent mode.
LPV_SUBSTEPS = 10


def zoh(A: np.ndarray, G: np.ndarray, dt: float,
        exp: Callable[[np.ndarray], np.ndarray] | None = None
        ) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order-hold discretisation of ``dx/dt = A x + G v`` over ``dt``.

    Parameters
    ----------
    A : numpy.ndarray
        (n, n)
    G : numpy.ndarray
        (n, m)
    dt : float
        Sample time, s.
    exp : callable, optional
        Matrix exponential (default ``scipy.linalg.expm``); the residual bank passes a
        cheaper one for the small matrices it re-discretises at every sample.

    Returns
    -------
    Ad : numpy.ndarray
        (n, n) ``e^{A dt}``.
    Gd : numpy.ndarray
        (n, m) ``int_0^dt e^{A s} ds G``.
    """
    if exp is None:
        # imported here: scipy.linalg costs ~0.1-0.2 s to import, and a run that never
        # discretises a linear mode (analyze on three_tank) should not pay it
        from scipy.linalg import expm

        exp = expm
    n, m = G.shape
    M = np.zeros((n + m, n + m))
    M[:n, :n] = A
    M[:n, n:] = G
    Md = exp(M * dt)
    return Md[:n, :n], Md[:n, n:]


@dataclass(frozen=True)
class DiscreteMode:
    """One mode as a discrete map (linear part; nonlinear modes leave Ad as None).

    Attributes
    ----------
    Ad : numpy.ndarray or None
        (n, n)
    Bd : numpy.ndarray
        (n, nu)
    Dd : numpy.ndarray
        (n, nw)
    cd : numpy.ndarray
        (n,) affine term per sample.
    Fd : numpy.ndarray
        (n, n_process) columns for the process-fault channels of the plant.
    """

    Ad: np.ndarray | None
    Bd: np.ndarray
    Dd: np.ndarray
    cd: np.ndarray
    Fd: np.ndarray


class SampledPlant:
    """The plant's modes as discrete maps with sample time ``system.sample_time``.

    Parameters
    ----------
    system : System
    """

    def __init__(self, system: System) -> None:
        self.system = system
        self.dt = system.sample_time
        self.process_faults = [f for f in system.faults if f.kind == "process"]
        #: per mode: True when A or B depend on the LPV parameters (A_rho / B_rho).
        self.lpv_modes = tuple(m.A_rho is not None or m.B_rho is not None
                               for m in system.modes)

        def f_of(q: int) -> np.ndarray:
            # (n, n_process): the process-fault directions in mode q (per-mode F allowed)
            if not self.process_faults:
                return np.zeros((system.n, 0))
            return np.column_stack([f.direction(q, system.n) for f in self.process_faults])

        self.modes = tuple(self._discretise(m, f_of(q)) for q, m in enumerate(system.modes))
        self._models = tuple(get_model(m.model) if m.model else None for m in system.modes)

    def _discretise(self, mode: Mode, F: np.ndarray) -> DiscreteMode:
        n = self.system.n
        if mode.A_rho is not None or mode.B_rho is not None:
            # Parameter-dependent: integrated per sample (step), nothing to precompute.
            return DiscreteMode(None, mode.B, mode.D, mode.offset, F)
        if mode.dynamics == "nonlinear":
            # Nonlinear maps are discrete already; process faults enter per sample as
            # dt * F f (an Euler step of the fault term), disturbances as D w.
            return DiscreteMode(None, mode.B, mode.D, np.zeros(n), self.dt * F)
        assert mode.A is not None
        if mode.time == "discrete":
            return DiscreteMode(mode.A, mode.B, mode.D, mode.offset, F)
        G = np.column_stack([mode.B, mode.D, mode.offset[:, None], F])
        Ad, Gd = zoh(mode.A, G, self.dt)
        nu, nw = mode.B.shape[1], mode.D.shape[1]
        return DiscreteMode(Ad, Gd[:, :nu], Gd[:, nu:nu + nw], Gd[:, nu + nw],
                            Gd[:, nu + nw + 1:])

    def step(self, q: np.ndarray, x: np.ndarray, u: np.ndarray, w: np.ndarray | None = None,
             f_process: np.ndarray | None = None,
             params_delta: Mapping[str, np.ndarray] | None = None,
             rho: Callable[[float, np.ndarray], np.ndarray] | None = None,
             t: float = 0.0) -> np.ndarray:
        """Advance a batch of states by one sample.

        A parameter-dependent mode (``A_rho`` / ``B_rho``) reads ``rho``: in continuous time
        ``dx/dt = A(rho) x + B(rho) u + D w + offset + F f`` is integrated over
        ``[t, t + Ts]`` by :func:`rk4_step` (10 substeps;
        ``rho`` evaluated inside the sample, ``u``, ``w``, ``f`` held); in discrete time
        ``x_{k+1} = A(rho_k) x_k + B(rho_k) u_k + D w_k + offset + F f_k``.

        Parameters
        ----------
        q : numpy.ndarray
            (N,) int mode of each run.
        x : numpy.ndarray
            (N, n) states.
        u : numpy.ndarray
            (N, nu) inputs (as applied, i.e. with actuator faults).
        w : numpy.ndarray, optional
            (N, nw) disturbances; zero if omitted.
        f_process : numpy.ndarray, optional
            (N, n_process) values of the process-fault channels.
        params_delta : mapping, optional
            Parameter name -> (N,) additive change (``parameter`` faults).
        rho : callable, optional
            ``(t, x) -> rho``: (M, n) states at time ``t`` (s) -> (M, d) parameters; required
            when a run is in a parameter-dependent mode.
        t : float
            Time of the sample, s.

        Returns
        -------
        numpy.ndarray
            (N, n) states at the next sample (without modelling uncertainty).
        """
        out = np.empty_like(x)
        for i in np.unique(q):
            sel = q == i
            dm = self.modes[int(i)]
            xs, us = x[sel], u[sel]
            mdl = self._models[int(i)]
            if self.lpv_modes[int(i)]:
                out[sel] = self._step_lpv(int(i), t, xs, us, rho,
                                          None if w is None else w[sel],
                                          None if f_process is None else f_process[sel])
                continue
            if mdl is None:
                assert dm.Ad is not None
                xn = xs @ dm.Ad.T + us @ dm.Bd.T + dm.cd
            else:
                p: dict[str, float | np.ndarray] = dict(self.system.modes[int(i)].params)
                if params_delta:
                    for name, d in params_delta.items():
                        p[name] = p[name] + d[sel]
                xn = mdl.step(xs, us, p, self.dt)
            if w is not None and dm.Dd.size:
                xn = xn + w[sel] @ dm.Dd.T
            if f_process is not None and dm.Fd.size:
                xn = xn + f_process[sel] @ dm.Fd.T
            out[sel] = xn
        return out

    def _step_lpv(self, q: int, t: float, x: np.ndarray, u: np.ndarray,
                  rho: Callable[[float, np.ndarray], np.ndarray] | None,
                  w: np.ndarray | None, f: np.ndarray | None) -> np.ndarray:
        m, dm = self.system.modes[q], self.modes[q]
        if rho is None:
            raise ValueError(f"plant {self.system.name!r}, mode {m.name!r}: parameter-dependent "
                             f"(A_rho/B_rho), give rho")
        assert m.A is not None
        A0, A_rho, B_rho = m.A, m.A_rho, m.B_rho
        held = np.broadcast_to(m.offset, x.shape).copy()
        if w is not None and m.D.size:
            held += w @ m.D.T
        if f is not None and dm.Fd.size:
            held += f @ dm.Fd.T

        A0T, uB = A0.T, u @ m.B.T                             # u is held over the sample

        def rhs(tt: float, xx: np.ndarray) -> np.ndarray:
            r = rho(tt, xx)                                   # (M, d)
            # A(rho) x = A0 x + sum_j rho_j A_j x (einsum: much cheaper than tensordot here)
            dx = xx @ A0T + uB + held
            if A_rho is not None:
                dx += np.einsum("md,dij,mj->mi", r, A_rho, xx)
            if B_rho is not None:
                dx += np.einsum("md,dij,mj->mi", r, B_rho, u)
            return dx

        if m.time == "discrete":
            return rhs(t, x)
        return rk4_step(rhs, t, x, self.dt, LPV_SUBSTEPS)

    def output(self, q: np.ndarray, x: np.ndarray, w: np.ndarray | None = None) -> np.ndarray:
        """Noise-free outputs ``C_q x + E_q w`` of a batch: (N,) modes, (N, n) states -> (N, ny)."""
        out = np.empty((x.shape[0], self.system.ny))
        for i in np.unique(q):
            sel = q == i
            m = self.system.modes[int(i)]
            y = x[sel] @ m.C.T
            if w is not None and m.E.size:
                y = y + w[sel] @ m.E.T
            out[sel] = y
        return out

    def next_mode1(self, q: int, x: Sequence[float], u: Sequence[float], kind: str) -> int:
        """:meth:`next_mode` of one run on Python numbers (the same comparisons): mode q,
        state (n,), input (nu,) -> the next mode."""
        vec = x if kind == "autonomous" else u
        for g in self.system.guards:
            if g.kind != kind or g.source != q:
                continue
            for c in g.conditions:
                v, op, val = vec[c.index], c.op, c.value
                if not (v < val if op == "<" else v <= val if op == "<=" else
                        v > val if op == ">" else v >= val if op == ">=" else v == val):
                    break
            else:
                return int(g.target)
        return q

    def next_mode(self, q: np.ndarray, x: np.ndarray, u: np.ndarray, kind: str) -> np.ndarray:
        """Apply the guards of ``kind`` once: (N,) modes, states (N, n), inputs (N, nu) -> (N,).

        The first guard of the current mode (file order) whose conditions hold fires.
        """
        qn = q.copy()
        for g in self.system.guards:
            if g.kind != kind:
                continue
            cand = (q == g.source) & (qn == q)
            if not cand.any():
                continue
            vec = x if kind == "autonomous" else u
            ok = cand.copy()
            for c in g.conditions:
                v = vec[:, c.index]
                if c.op == "<":
                    ok &= v < c.value
                elif c.op == "<=":
                    ok &= v <= c.value
                elif c.op == ">":
                    ok &= v > c.value
                elif c.op == ">=":
                    ok &= v >= c.value
                else:
                    ok &= v == c.value
            qn[ok] = g.target
        return qn


def rk4_step(rhs: Callable[[float, np.ndarray], np.ndarray], t: float, x: np.ndarray,
             dt: float, substeps: int = 10) -> np.ndarray:
    """Advance ``dx/dt = rhs(t, x)`` from ``t`` over one sample ``dt`` by ``substeps`` classical
    Runge-Kutta steps (the integrator of the parameter-dependent modes).

    Parameters
    ----------
    rhs : callable
        ``(t, x) -> dx/dt`` of the same shape as ``x``.
    x : numpy.ndarray
        State at ``t``: (n,) or a batch (N, n).
    dt : float
        Sample time, s.

    Returns
    -------
    numpy.ndarray
        State at ``t + dt``, shape of ``x``.
    """
    h = dt / substeps
    tt = t
    for _ in range(substeps):
        k1 = rhs(tt, x)
        k2 = rhs(tt + h / 2, x + h / 2 * k1)
        k3 = rhs(tt + h / 2, x + h / 2 * k2)
        k4 = rhs(tt + h, x + h * k3)
        x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        tt += h
    return x
