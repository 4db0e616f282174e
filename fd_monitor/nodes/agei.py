"""``agei``: autonomous guard event identification (Heracleous et al., Sec. 3.3) as a node.

Joins, per sample k: ``/fd/state_estimate`` (q^_k), ``/fd/residual`` (r_k, w_k) and
``/fd/threshold`` (the nominal threshold at k). Publishes, stamped k + 1 (the sample they are
used at): ``/fd/guard_event`` (``trigger``: guard index or -1, ``phase``, ``row``,
``mode_uncertain``) for the
observer and ``/fd/threshold_override`` (per output; NaN = none) for the detector.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from fd_monitor.core.agei import Agei
from fd_monitor.core.thresholds import as_gains
from fd_monitor.nodes.common import OK, NodeUsage, Param, run_node
from fd_monitor.nodes.fd_node import COMMON_PARAMS, FdNode, Input
from fd_monitor.wire.topics import state_labels

__all__ = ["AgeiNode", "USAGE", "main"]

PARAMS = (
    Param("enabled", True, "false: the ablation without AGEI (never triggers, no override)"),
)

USAGE = NodeUsage(
    "agei", "agei: autonomous guard event identification (thresholds gain files only).",
    (*COMMON_PARAMS, *PARAMS),
    subscribes=(("/fd/state_estimate", "q^_k from observer"),
                ("/fd/residual", "r_k, w_k from detector"),
                ("/fd/threshold", "nominal threshold at k from detector")),
    publishes=(("/fd/guard_event", "trigger, phase, row, mode_uncertain (stamp k + 1)"),
               ("/fd/threshold_override", "override per output, NaN = none (stamp k + 1)"),
               ("/diagnostics", "input and tracker status")))


class AgeiNode(FdNode):
    """AGEI node.

    Parameters
    ----------
    agei : Agei, optional
        Default: built from the gain file.
    system, gains, qos, **kwargs
        See :class:`~fd_monitor.nodes.fd_node.FdNode`.
    """

    outputs = ("fd/guard_event", "fd/threshold_override")

    def __init__(self, agei: Agei | None = None, system=None, gains=None, qos=None,
                 node_name: str = "agei", **kwargs: Any) -> None:
        self._agei_arg = agei
        super().__init__(node_name, PARAMS, system, gains, qos, **kwargs)

    def setup(self) -> None:
        """Publishers, AGEI and inputs (at configure)."""
        self.start_runtime()
        self._start(self._agei_arg)

    def build_core(self, gains: Any) -> None:
        """A new AGEI for another gain file (runtime swap)."""
        self.agei = Agei(self.system, as_gains(self.system, gains), enabled=self.params.enabled)

    runtimes: Mapping[str, str] = {"thresholds": "_thresholds_only"}

    def _thresholds_only(self) -> None:
        """The sensor-bias chain's runtime (any other method is refused at start)."""

    def _start(self, agei: Agei | None) -> None:
        s = self.system
        self.agei = (agei if agei is not None
                     else Agei(s, as_gains(s, self.gain_file), enabled=self.params.enabled))
        self.pub_guard = self.publisher("fd/guard_event")
        self.pub_override = self.publisher("fd/threshold_override")
        self.diag.add("tracker", self.params.stale_timeout)
        o = s.outputs
        self.start_inputs([
            Input("est", "fd/state_estimate", state_labels(s), sequence=True),
            Input("residual", "fd/residual", (*(f"r:{n}" for n in o), *(f"w:{n}" for n in o))),
            Input("threshold", "fd/threshold",
                  (*(f"R:{n}" for n in o), *(f"rbar:{n}" for n in o))),
        ])

    def reset(self) -> None:
        """Back to monitoring (Monitor.reset)."""
        self.agei.reset()

    def process(self, k: int, inputs: dict[str, Any]) -> None:
        """q^_k, w_k, r_k, nominal_k -> trigger and override for k + 1."""
        ny = self.system.ny
        mode = int(inputs["est"][0])
        r, w = inputs["residual"][:ny], inputs["residual"][ny:]
        out = self.agei.step(k, mode, w, r, inputs["threshold"][ny:])
        pay = out.payloads(self.system)
        for pub, topic in ((self.pub_guard, "/fd/guard_event"),
                           (self.pub_override, "/fd/threshold_override")):
            labels, values = pay[topic]
            self.publish_array(pub, labels, k + 1, values)
        self.diag.update("tracker", OK, f"phase {out.phase}", {
            "sample": k, "trigger": out.trigger, "phase": out.phase, "row": out.row,
            **self.gain_values()})


def main(args: Sequence[str] | None = None) -> int:
    """Run the AGEI node."""
    return run_node(AgeiNode, args, prog="agei", usage=[USAGE])


if __name__ == "__main__":
    import sys

    sys.exit(main())
