"""The parts of a plant: guard conditions, guards, fault channels, LPV parameters, modes and
the operating envelope (the :class:`~fd_monitor.model.system.System` holds them)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

__all__ = ["Condition", "Envelope", "FaultChannel", "Guard", "LPVParameter", "Mode"]


@dataclass(frozen=True)
class Condition:
    """One enabling condition ``var op value`` of a guard.

    Attributes
    ----------
    var : str
        State name (autonomous guard) or input name (controlled guard).
    index : int
        Index of ``var`` in the state vector or the input vector.
    op : str
        One of ``<``, ``<=``, ``>``, ``>=``, ``==``.
    value : float
        Threshold, in the unit of ``var``.
    """

    var: str
    index: int
    op: str
    value: float

    def holds(self, v: float) -> bool:
        """Return whether the condition holds for the value ``v`` of its variable."""
        if self.op == "<":
            return v < self.value
        if self.op == "<=":
            return v <= self.value
        if self.op == ">":
            return v > self.value
        if self.op == ">=":
            return v >= self.value
        return v == self.value


@dataclass(frozen=True)
class Guard:
    """A transition ``source -> target`` enabled when every condition holds.

    Attributes
    ----------
    name : str
    source, target : int
        Mode indices.
    kind : str
        ``"autonomous"`` (conditions on states) or ``"controlled"`` (conditions on inputs).
    conditions : tuple of Condition
    """

    name: str
    source: int
    target: int
    kind: str
    conditions: tuple[Condition, ...]

    def enabled(self, x: np.ndarray, u: np.ndarray) -> bool:
        """Return whether the guard's conditions hold for state ``x`` (n,) and input ``u`` (nu,)."""
        vec = x if self.kind == "autonomous" else u
        return all(c.holds(float(vec[c.index])) for c in self.conditions)


@dataclass(frozen=True)
class FaultChannel:
    """A place where a fault can enter the plant.

    Attributes
    ----------
    name : str
    kind : str
        ``sensor_bias`` (added to output ``index``), ``actuator`` (added to input ``index``),
        ``state_jump`` (state ``index`` jumps by the change of the fault signal), ``process``
        (``F f`` added to the state derivative or update), ``parameter`` (added to the
        nonlinear model parameter ``parameter``).
    index : int
        Output, input or state index; -1 for ``process`` and ``parameter``.
    F : numpy.ndarray or None
        (n,) direction of a ``process`` fault that enters every mode the same way; None for
        other kinds and for a mode-dependent direction (see ``F_modes``).
    parameter : str or None
        Parameter name of a ``parameter`` fault.
    F_modes : tuple of numpy.ndarray or None
        Per mode (in mode order), the (n,) direction of a mode-dependent ``process`` fault
        (zeros in the modes the file does not list); None otherwise.
    E : numpy.ndarray or None
        (ny,) output direction of a ``process`` fault (``y += E f``), when given.
    """

    name: str
    kind: str
    index: int = -1
    F: np.ndarray | None = None
    parameter: str | None = None
    F_modes: tuple[np.ndarray, ...] | None = None
    E: np.ndarray | None = None

    def direction(self, mode: int, n: int) -> np.ndarray:
        """(n,) state direction of a ``process`` fault in mode index ``mode`` (zeros for the
        other kinds)."""
        if self.F_modes is not None:
            return self.F_modes[mode]
        if self.F is not None:
            return self.F
        return np.zeros(n)


@dataclass(frozen=True)
class LPVParameter:
    """A scheduling (measured) or uncertain (unmeasured) parameter of an LPV plant.

    Attributes
    ----------
    name : str
    min, max : float
        Bounds of the parameter box (thesis 5.4, 6.4), dimensionless.
    measured : bool
        True: available to the residual generators (LPV, ch. 6); False: an uncertainty
        (ch. 5).
    """

    name: str
    min: float
    max: float
    measured: bool


@dataclass(frozen=True)
class Mode:
    """One discrete mode of the plant.

    Attributes
    ----------
    name : str
    dynamics : str
        ``"linear"`` or ``"nonlinear"``.
    time : str
        ``"continuous"`` or ``"discrete"`` (linear modes; nonlinear models are discrete maps).
    A : numpy.ndarray or None
        (n, n) state matrix (linear modes).
    B : numpy.ndarray
        (n, nu) input matrix.
    C : numpy.ndarray
        (ny, n) output matrix.
    D : numpy.ndarray
        (n, nw) disturbance-to-state matrix.
    E : numpy.ndarray
        (ny, nw) disturbance-to-output matrix.
    offset : numpy.ndarray
        (n,) affine term.
    uncertainty : numpy.ndarray
        (n,) bound on the additive modelling uncertainty of ``x_{k+1}``, state units.
    model : str or None
        Name of the nonlinear model.
    params : dict
        Parameters of the nonlinear model.
    A_rho : numpy.ndarray or None
        (d, n, n) affine parts of A of an LPV plant (``lpv`` key), when given.
    B_rho : numpy.ndarray or None
        (d, n, nu) affine parts of B, when given.
    """

    name: str
    dynamics: str
    time: str
    A: np.ndarray | None
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    E: np.ndarray
    offset: np.ndarray
    uncertainty: np.ndarray
    model: str | None = None
    params: Mapping[str, float] = field(default_factory=dict)
    A_rho: np.ndarray | None = None
    B_rho: np.ndarray | None = None

    def A_of(self, rho: np.ndarray | None) -> np.ndarray:
        """(n, n) ``A(rho) = A + sum_j rho_j A_j`` of a linear mode (``A`` when no A_rho)."""
        assert self.A is not None
        if rho is None or self.A_rho is None:
            return self.A
        return self.A + np.tensordot(np.asarray(rho, dtype=float), self.A_rho, axes=1)


@dataclass(frozen=True)
class Envelope:
    """Declared operating envelope: a box of states and inputs per mode (physical limits).

    Attributes
    ----------
    state_lo, state_hi : numpy.ndarray
        (s, n) state ranges per mode, state units.
    input_lo, input_hi : numpy.ndarray
        (s, nu) input ranges per mode, input units.
    """

    state_lo: np.ndarray
    state_hi: np.ndarray
    input_lo: np.ndarray
    input_hi: np.ndarray

