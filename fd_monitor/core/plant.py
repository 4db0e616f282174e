"""Sampled plant dynamics: every mode of a :class:`~fd_monitor.system.System` as a discrete map.

Linear continuous-time modes are discretised exactly with a zero-order hold on the input,
the disturbance, the affine term and process faults (all held over the sample):
``Ad = e^{A Ts}``, ``Gd = int_0^Ts e^{A s} ds [B D offset F]``, computed from the matrix
exponential of the augmented matrix ``[[A, G], [0, 0]] Ts`` (Van Loan). Discrete-time modes
are used as written; nonlinear modes call their model's discrete map.

All functions take a batch: states (N, n), inputs (N, nu), modes (N,) int, so Monte Carlo
runs in one array pass per mode.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm

from fd_monitor.core.models import get_model
from fd_monitor.system import Mode, System

__all__ = ["DiscreteMode", "SampledPlant", "zoh"]


def zoh(A: np.ndarray, G: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order-hold discretisation of ``dx/dt = A x + G v`` over ``dt``.

    Parameters
    ----------
    A : numpy.ndarray
        (n, n)
    G : numpy.ndarray
        (n, m)
    dt : float
        Sample time, s.

    Returns
    -------
    Ad : numpy.ndarray
        (n, n) ``e^{A dt}``.
    Gd : numpy.ndarray
        (n, m) ``int_0^dt e^{A s} ds G``.
    """
    n, m = G.shape
    M = np.zeros((n + m, n + m))
    M[:n, :n] = A
    M[:n, n:] = G
    Md = expm(M * dt)
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
        if any(m.A_rho is not None or m.B_rho is not None for m in system.modes):
            raise ValueError(f"plant {system.name!r} has parameter-dependent modes (A_rho/"
                             f"B_rho): the sampled plant simulates fixed matrices only; use "
                             f"fd_monitor.core.residual_bank.simulate_affine_plant")

        def f_of(q: int) -> np.ndarray:
            # (n, n_process): the process-fault directions in mode q (per-mode F allowed)
            if not self.process_faults:
                return np.zeros((system.n, 0))
            return np.column_stack([f.direction(q, system.n) for f in self.process_faults])

        self.modes = tuple(self._discretise(m, f_of(q)) for q, m in enumerate(system.modes))
        self._models = tuple(get_model(m.model) if m.model else None for m in system.modes)

    def _discretise(self, mode: Mode, F: np.ndarray) -> DiscreteMode:
        n = self.system.n
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
             params_delta: Mapping[str, np.ndarray] | None = None) -> np.ndarray:
        """Advance a batch of states by one sample.

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
