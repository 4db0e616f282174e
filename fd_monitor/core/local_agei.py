"""AGEI's decisions where they are used, for when the ``agei`` node's are lost.

In the fused :class:`~fd_monitor.core.monitor.Monitor` AGEI runs in process; in the
four-process chain it is a peer (the ``agei`` node) whose decisions reach the observer (the
guard trigger, ``fd/guard_event``) and the detector (the threshold override,
``fd/threshold_override``) one sample later. When that peer is away (killed, restarting, not
started) the join gives those inputs their initial values: no trigger, no override. Across an
autonomous guard crossing that leaves the observer in the old mode (``q^ != q``) with the
nominal threshold (19) in force, which the paper guarantees only for ``q^ = q``
(Heracleous et al., Sec. 3.2-3.3): a false alarm on the residuals the guard affects.

:class:`LocalAgei` computes what the ``agei`` node computes, with the same code, from what
the consuming node already has:

* AGEI's inputs at k are ``q^_k``, ``w_k = H[y~]_k``, ``r_k`` and the nominal threshold
  ``r_bar_k`` (eq. 10, 14, 19). The detector has all four (:meth:`LocalAgei.decide`). The
  observer has ``q^_k``, ``x^_k`` and ``y~_k``, from which :class:`ResidualDetector` gives the
  other three (:meth:`LocalAgei.observe`): ``w``, ``r`` and ``r_bar`` do not depend on the
  override (it only moves ``R``), so the observer's copy of the detector computes exactly the
  detector node's numbers.
* :class:`~fd_monitor.core.agei.Agei` (eq. 20-22, Fig. 3) then decides the trigger and the
  override for k + 1, bit for bit what the ``agei`` node decides while both have processed
  the same samples with the same restarts (its state is its phase, row and hold count).

The node runs it at every sample (its state must follow the run: the residual filters'
history and AGEI's phase) and uses its decision only for a sample whose AGEI feedback is
absent. So while the ``agei`` node is there nothing changes, and while it is away the chain
computes what the fused monitor computes: the mode switch at the crossing, the widened
threshold ``r_bar*`` (eq. 22) around it, the nominal one elsewhere.
"""

from __future__ import annotations

from collections.abc import Sequence

from fd_monitor.core.agei import Agei
from fd_monitor.core.detector import ResidualDetector
from fd_monitor.core.hybrid_observer import NO_TRIGGER
from fd_monitor.core.thresholds import DiagnosisGains
from fd_monitor.model.system import System

__all__ = ["LocalAgei"]


class LocalAgei:
    """AGEI run by a node that uses its decisions (observer, detector).

    Parameters
    ----------
    system : System
    gains : DiagnosisGains
    residuals : bool
        True: the node has no residuals of its own (the observer): :meth:`observe` computes
        them with a :class:`ResidualDetector`. False: the node passes them to :meth:`decide`.

    Attributes
    ----------
    trigger : int
        The guard trigger for the next sample (``NO_TRIGGER``: none), as the ``agei`` node
        would publish it.
    override : list of float or None
        (ny,) the threshold override for the next sample (NaN: none on that channel; None:
        no row active), as ``Monitor`` passes it to the detector.
    mode_uncertain : bool
        AGEI's ``mode_uncertain`` after the last sample.
    phase, row : int
        AGEI's phase and row after the last sample.
    """

    def __init__(self, system: System, gains: DiagnosisGains, *, residuals: bool) -> None:
        self.agei = Agei(system, gains)
        self.detector = ResidualDetector(system, gains) if residuals else None
        self.reset()

    def reset(self) -> None:
        """A new run (the node's restart): AGEI back to monitoring, filters empty."""
        self.agei.reset()
        if self.detector is not None:
            self.detector.reset()
        self.trigger = NO_TRIGGER
        self.override: list[float] | None = None
        self.mode_uncertain = False
        self.phase, self.row = self.agei._phase1, self.agei._row1

    def bridge(self) -> None:
        """A bridged gap (:meth:`Monitor.bridge <fd_monitor.core.monitor.Monitor.bridge>`):
        the residual filters start again, AGEI keeps its phase and its decision in force."""
        if self.detector is not None:
            self.detector.reset()

    def decide(self, k: int, mode: int, w: Sequence[float], residual: Sequence[float],
               nominal: Sequence[float]) -> None:
        """AGEI at sample k on the detector's ``q^_k``, ``w_k``, ``r_k``, ``r_bar_k`` (each
        (ny,), output units): sets :attr:`trigger` and :attr:`override` for k + 1."""
        ag, ov = self.agei.step1(k, mode, w, residual, nominal)
        self.trigger = int(ag.trigger)
        self.override = ov if ag.row >= 0 else None
        self.mode_uncertain = bool(ag.mode_uncertain)
        self.phase, self.row = int(ag.phase), int(ag.row)

    def observe(self, k: int, mode: int, y_tilde: list[float], x_hat: list[float]) -> None:
        """The observer's ``q^_k``, ``y~_k`` (ny,) and ``x^_k`` (n,) at sample k: the
        residuals as the detector computes them (eq. 10-14, 19), then :meth:`decide`."""
        assert self.detector is not None, "LocalAgei(residuals=False) has no residuals"
        _, r, w, nominal, _ = self.detector.step1(k, y_tilde, x_hat, mode, None)
        self.decide(k, mode, w, r, nominal)
