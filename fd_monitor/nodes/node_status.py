"""The two statuses every chain node reports about itself: ``input`` and ``ros graph``.

- :class:`InputStatus`: OK ``receiving`` while input is joined; WARN with the de-duplicated
  reasons of the bad messages and the input policy's warnings (holes, bridges, new runs,
  shed load), each logged (throttled: one line per ``log_throttle`` s with the count of the
  others); its values count what was processed, lost, bridged and shed (and the adapter's
  time-base counts).
- :class:`GraphStatus`: the standing ROS-graph problems (incompatible QoS, another publisher
  on our outputs, a refused gain file), each until its cause is cleared; OK without one.

Both are held by the node (:class:`~fd_monitor.nodes.fd_node.FdNode`), built at configure
from its ``diag``, logger and parameters.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import Any

from fd_monitor.nodes.diagnostics import MAX_MESSAGE, OK, WARN, Diagnostics

__all__ = ["GRAPH_OK", "GraphStatus", "InputStatus", "WARN_ONLY", "shed_rule"]

#: The ``ros graph`` status without a standing problem.
GRAPH_OK = "no QoS incompatibility, no other publisher on our outputs"

#: Input-policy reports that are warnings, not dropped messages (wire.stream kinds).
WARN_ONLY = frozenset(("out_of_order", "hole", "bridge", "feedback_lost", "new_run",
                       "shed", "feedback_back"))


def shed_rule(j: Any) -> str:
    """The load-shedding rule in force (:class:`~fd_monitor.wire.join.StampJoin`), one line
    for the ``input`` status: which backlog is shed, which is a batch."""
    if j.max_lag is None:
        return "never shed (max_lag 0)"
    rule = (f"unmarked backlog older than {j.max_lag:g} s shed; marked (batch) processed "
            f"completely")
    if j.batch_pace:
        rule += f"; unmarked faster than {j.batch_pace:g} x real time too (batch_pace)"
    return rule


class InputStatus:
    """The ``input`` status of a node and its bad-input log lines.

    Parameters
    ----------
    diag : Diagnostics
        Has the ``input`` channel; the reasons start again after each publication.
    logger : rclpy logger
    log_throttle : callable
        () -> s between two bad-input log lines (a parameter settable at runtime).
    processed : callable
        () -> samples processed so far.
    """

    def __init__(self, diag: Diagnostics, logger: Any, log_throttle: Callable[[], float],
                 processed: Callable[[], int]) -> None:
        self.diag, self.logger = diag, logger
        self.log_throttle, self.processed = log_throttle, processed
        self.bad_messages = 0
        self.holes = 0
        #: the stamp join (:class:`~fd_monitor.wire.join.StampJoin`) and the adapter's join
        #: (:class:`~fd_monitor.wire.adapters.AdapterJoin`, or None), set with the inputs
        self.join: Any = None
        self.adapter_join: Any = None
        # Reasons of the bad messages since the last /diagnostics publication, each once.
        self.reasons: list[str] = []
        self.last_bad = -float("inf")
        self._last_log = -float("inf")
        self._suppressed = 0
        diag.on_publish.append(self.reasons.clear)

    def bad_input(self, reason: str) -> None:
        """Log a rejected message and report it on /diagnostics (WARN); keep running."""
        self.bad_messages += 1
        self.warn(reason)

    def note(self, kind: str, line: str, stamp: Any = None) -> None:
        """A report of the input policy (:class:`~fd_monitor.wire.stream.InputStream`):
        out of order, holes and new runs are warnings; the others are dropped messages."""
        if kind == "hole":
            self.holes += 1
        if kind in WARN_ONLY:
            self.warn(line)
        else:
            self.bad_input(line)

    def warn(self, reason: str) -> None:
        """Log ``reason`` (throttled) and report it on the ``input`` channel (WARN)."""
        now = time.monotonic()
        self.last_bad = now
        if now - self._last_log >= self.log_throttle():
            more = (f" (and {self._suppressed} more bad-input lines in the last "
                    f"{now - self._last_log:.1f} s)" if self._suppressed else "")
            self.logger.warning(reason + more)
            self._last_log, self._suppressed = now, 0
        else:
            self._suppressed += 1
        reasons = self.reasons
        if reason not in reasons and len(reasons) < 10:
            reasons.append(reason)
        # every reason of this period when they fit in a status line, else the latest (all
        # of them in the values)
        message = "; ".join(reasons)
        if len(message) > MAX_MESSAGE and len(reasons) > 1:
            message = f"{reason} (and {len(reasons) - 1} more: see reasons)"
        j = self.join
        self.diag.update("input", WARN, message,
                         {"reasons": "; ".join(reasons),
                          "bad_messages": self.bad_messages, "holes": self.holes,
                          "bridged": j.bridges, "restarted": j.restarts,
                          "new_runs": j.new_runs, "processed": self.processed(),
                          **self.load_counts(), "last_warning": reason,
                          **self.time_base()})

    def ok(self) -> None:
        """An input was joined: OK ``receiving``, or the WARN of recent bad input kept (then
        and between full reports the channel is only marked fresh)."""
        diag = self.diag
        level = diag.level("input")
        if level == WARN and time.monotonic() - self.last_bad < diag.period:
            diag.touch("input")
            return
        processed = self.processed()
        if level != OK or processed % 50 == 0:
            j = self.join
            diag.update("input", OK, "receiving", {
                "bad_messages": self.bad_messages, "processed": processed,
                "holes": self.holes, "bridged": j.bridges,
                "restarted": j.restarts, "new_runs": j.new_runs,
                "next_sample": j.k_next, "waiting_for": j.waiting_for(),
                **self.load_counts(), **self.time_base()})
        else:
            diag.touch("input")

    def load_counts(self) -> dict[str, Any]:
        """Load shed and lost feedback (wire/join.py), for the ``input`` status."""
        j = self.join
        return {"shed_samples": j.shed, "shed_episodes": j.shed_episodes,
                "batch_waits": j.batch_waits, "pace_waits": j.pace_waits,
                "shed_rule": shed_rule(j),
                "feedback_lost": j.feedback_losses,
                "feedback_not_waited_for": ",".join(sorted(j.lost_feedback)) or "none"}

    def time_base(self) -> dict[str, Any]:
        """The adapter's time-base counts (held samples, gaps, late/duplicate/decimated
        messages) for the ``input`` status; empty without an adapter."""
        if self.adapter_join is None:
            return {}
        c = self.adapter_join.counts()
        out: dict[str, Any] = {"grid_samples": c["samples"]}
        for key in ("held", "late", "duplicate", "stray", "decimated"):
            for what, n in c.get(key, {}).items():
                out[f"{key} {what}"] = n
        for reason, per in c["gaps"].items():
            for ch, n in per.items():
                out[f"gap {reason} {ch}"] = n
        return out


class GraphStatus:
    """The ``ros graph`` status: standing ROS-graph problems, each by its cause.

    Parameters
    ----------
    diag : Diagnostics
        Has the ``ros graph`` channel.
    logger : rclpy logger
    """

    def __init__(self, diag: Diagnostics, logger: Any) -> None:
        self.diag, self.logger = diag, logger
        #: standing problems, by cause (cleared when the cause goes away)
        self.notes: dict[str, str] = {}
        #: inputs switched to best effort (handled: reported in the values, not a WARN)
        self.best_effort: list[str] = []

    def note(self, line: str, cause: str | None = None) -> None:
        """Log a ROS-graph problem (QoS, another publisher, a refused gain file) and report
        it (WARN) until its ``cause`` (default: the line) is cleared."""
        self.logger.warning(line)
        self.notes[cause or line] = line
        self.report()

    def clear(self, cause: str) -> None:
        """The problem of ``cause`` is gone (a valid gain file set, a switch done, the other
        publisher left): the status goes back to OK when none is left."""
        if self.notes.pop(cause, None) is not None:
            self.report()

    def switched(self, topic: str) -> None:
        """A subscription met a best-effort publisher by switching: handled, not a WARN."""
        self.logger.info(f"{topic}: subscription now best effort (meets every publisher)")
        self.best_effort.append(topic)
        self.clear(f"qos {topic}")

    def check_outputs(self, pubs: Sequence[Any], me: tuple[str, str],
                      publishers_of: Callable[[str], Sequence[Any]]) -> None:
        """Warn while another node publishes on one of our output topics ``pubs`` (a second
        monitor); the warning clears when it left. ``me``: (namespace, name) of our node;
        ``publishers_of``: the node's ``get_publishers_info_by_topic``."""
        for pub in pubs:
            others = [f"{i.node_namespace.rstrip('/')}/{i.node_name}"
                      for i in publishers_of(pub.topic_name)
                      if (i.node_namespace, i.node_name) != me]
            cause = f"also {pub.topic_name}"
            if others:
                line = (f"{pub.topic_name}: also published by {', '.join(sorted(others))} "
                        f"(a second monitor on the same topics? its outputs mix with ours)")
                if self.notes.get(cause) != line:
                    self.note(line, cause)
            else:
                self.clear(cause)

    def report(self) -> None:
        """Publish the status as it stands (also after activation)."""
        notes = list(self.notes.values())
        values: dict[str, Any] = ({"best_effort_inputs": ", ".join(self.best_effort)}
                                  if self.best_effort else {})
        if notes:
            # all of them when they fit in a status line, else the latest (all in values)
            message = "; ".join(notes)
            if len(message) > MAX_MESSAGE and len(notes) > 1:
                message = f"{notes[-1]} (and {len(notes) - 1} more: see problem 1, ...)"
            values.update({f"problem {i + 1}": n for i, n in enumerate(notes)})
            self.diag.update("ros graph", WARN, message, values)
        else:
            self.diag.update("ros graph", OK, GRAPH_OK + (
                " (some inputs switched to best effort)" if self.best_effort else ""), values)
