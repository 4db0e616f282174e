"""A chain node's stand-in for a lost ``agei`` node (observer: the guard trigger; detector: the
threshold override; bias estimator: ``mode_uncertain``): :class:`AgeiFallback`, its parameter
and its ``agei`` status.

The node runs :class:`~fd_monitor.core.local_agei.LocalAgei` at every sample and uses its
decision for a sample whose AGEI feedback is absent -- the join gave that input its initial
value because its publisher is lost or not there (``doc/howto/overload-and-recovery.md``);
the bias estimator's is an optional input, None when absent.
A restart sample is not an absence: every node starts a run with no trigger and no override,
and so does the local AGEI.
"""

from __future__ import annotations

from typing import Any

from fd_monitor.core.local_agei import LocalAgei
from fd_monitor.core.thresholds import as_gains
from fd_monitor.nodes.diagnostics import OK, WARN
from fd_monitor.nodes.params import Param

__all__ = ["AGEI_FALLBACK", "AgeiFallback"]

#: Of the observer, the detector and the bias estimator (the consumers of AGEI's decisions).
AGEI_FALLBACK = Param(
    "agei_fallback", True, "while the agei node's decisions are absent (agei killed, "
    "restarting or not started) decide them with this node's own copy of AGEI (the same code "
    "on the same numbers: the guard events and thresholds agei would send); false: go on "
    "without them (no trigger, no override, mode certain: a guard crossing then leaves the "
    "mode estimate in the old mode and can alarm)")


class AgeiFallback:
    """The node side of the local AGEI: which decision a sample uses, and the ``agei``
    status (OK while the agei node's decisions come, WARN while they are absent).

    Parameters
    ----------
    node : FdNode
        Configured (``diag``, ``get_logger``, ``params.agei_fallback``, ``system``,
        ``gain_file``); the status is added to its diagnostics.
    residuals : bool
        The node has no residuals of its own (observer, bias estimator): the local copy
        computes them (:class:`LocalAgei` ``residuals``).
    initial : object
        The feedback input's initial value, as given to the join: an absent decision is
        that very object (the join fills it in; a received message is a new array).
    what : str
        What the node takes from AGEI, for the status (``"guard events"``, ``"thresholds"``).

    Attributes
    ----------
    local : LocalAgei or None
        None: ``agei_fallback`` false (absent decisions stay at their initial value).
    """

    def __init__(self, node: Any, residuals: bool, initial: object, what: str) -> None:
        self.node, self.residuals, self.initial, self.what = node, residuals, initial, what
        self.local = self._copy(node.gain_file) if node.params.agei_fallback else None
        self.absent_since: int | None = None
        node.diag.add("agei", follows="input", message=f"{what} from agei")

    def _copy(self, gains: Any) -> LocalAgei:
        s = self.node.system
        return LocalAgei(s, as_gains(s, gains), residuals=self.residuals)

    def new_gains(self, gains: Any) -> None:
        """A gain-file swap: a new local copy for ``gains`` (none while the fallback is off)."""
        if self.local is not None:
            self.local = self._copy(gains)

    def reset(self) -> None:
        """The node's restart (:meth:`LocalAgei.reset`)."""
        if self.local is not None:
            self.local.reset()

    def bridge(self) -> None:
        """A bridged gap (:meth:`LocalAgei.bridge`)."""
        if self.local is not None:
            self.local.bridge()

    def absent(self, k: int, value: object, restarting: bool) -> bool:
        """Sample k's AGEI feedback ``value`` is absent (lost, or no publisher); reported on
        the ``agei`` status when that changes."""
        gone = value is self.initial and not restarting
        if gone and self.absent_since is None:
            self.absent_since = k
            self._report(WARN, self._lost_text())
        elif not gone and self.absent_since is not None and not restarting:
            self.absent_since = None
            self._report(OK, f"{self.what} from agei again")
        return gone

    def _lost_text(self) -> str:
        own = (f"{self.what} from this node's own AGEI (the same code on the same "
               f"numbers)" if self.local is not None else
               f"no {self.what} (agei_fallback false: a guard crossing can alarm)")
        return f"agei decisions absent since sample {self.absent_since} (lost or no " \
               f"publisher): {own}"

    def _report(self, level: bytes, message: str) -> None:
        # one call site per severity: rclpy refuses a severity change at one call site
        if level == WARN:
            self.node.get_logger().warning(message)
        else:
            self.node.get_logger().info(message)
        self.node.diag.update("agei", level, message,
                              {"absent_since": "" if self.absent_since is None
                               else self.absent_since,
                               "fallback": self.local is not None})

    @property
    def note(self) -> str:
        """A mark for the node's alarms while AGEI is absent ('' otherwise)."""
        if self.absent_since is None:
            return ""
        return " (agei absent: own AGEI)" if self.local is not None else " (agei absent)"
