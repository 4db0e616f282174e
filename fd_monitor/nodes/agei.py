"""``agei``: autonomous guard event identification (Heracleous et al., Sec. 3.3) as a node.

Joins, per sample k: ``/fd/state_estimate`` (q^_k), ``/fd/residual`` (r_k, w_k) and
``/fd/threshold`` (the nominal threshold at k). Publishes, stamped k + 1 (the sample they are
used at): ``/fd/guard_event`` (``trigger``: guard index or -1, ``phase``, ``row``,
``mode_uncertain``) for the
observer and ``/fd/threshold_override`` (per output; NaN = none) for the detector.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

from rclpy.qos import QoSProfile

from fd_monitor.core.agei import Agei
from fd_monitor.core.thresholds import as_gains
from fd_monitor.model.gains import GainFile
from fd_monitor.model.system import System
from fd_monitor.nodes.chain_params import COMMON_PARAMS
from fd_monitor.nodes.diagnostics import OK
from fd_monitor.nodes.fd_node import FdNode
from fd_monitor.nodes.inputs import Input
from fd_monitor.nodes.params import Param
from fd_monitor.nodes.process import run_node
from fd_monitor.nodes.usage import NodeUsage
from fd_monitor.wire.topics import (
    DIAGNOSTICS,
    GUARD_EVENT,
    RESIDUAL,
    STATE_ESTIMATE,
    THRESHOLD,
    THRESHOLD_OVERRIDE,
)

__all__ = ["AgeiNode", "USAGE", "main"]

PARAMS = (
    Param("enabled", True, "false: the ablation without AGEI (never triggers, no override)"),
)

USAGE = NodeUsage(
    "agei", "agei: autonomous guard event identification (thresholds gain files only).",
    (*COMMON_PARAMS, *PARAMS),
    subscribes=((STATE_ESTIMATE, "q^_k from observer"),
                (RESIDUAL, "r_k, w_k from detector"),
                (THRESHOLD, "nominal threshold at k from detector")),
    publishes=((GUARD_EVENT, "trigger, phase, row, mode_uncertain (stamp k + 1)"),
               (THRESHOLD_OVERRIDE, "override per output, NaN = none (stamp k + 1)"),
               (DIAGNOSTICS, "input and tracker status")))


class AgeiNode(FdNode):
    """AGEI node.

    Parameters
    ----------
    agei : Agei, optional
        Default: built from the gain file.
    system, gains, qos, **kwargs
        See :class:`~fd_monitor.nodes.fd_node.FdNode`.
    """

    outputs = (GUARD_EVENT, THRESHOLD_OVERRIDE)

    def __init__(self, agei: Agei | None = None, system: System | None = None,
                 gains: GainFile | None = None, qos: QoSProfile | None = None,
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

    def _thresholds_only(self) -> None:
        """The sensor-bias chain's runtime (any other method is refused at start)."""

    runtimes: Mapping[str, Callable[[Any], None]] = {"thresholds": _thresholds_only}

    def _start(self, agei: Agei | None) -> None:
        s = self.system
        self.agei = (agei if agei is not None
                     else Agei(s, as_gains(s, self.gain_file), enabled=self.params.enabled))
        self._out = [(self.publisher(t), t.layout(s)) for t in self.outputs]
        self.diag.add("tracker", self.params.stale_timeout)
        inputs = [Input.of("est", STATE_ESTIMATE, s, sequence=True),
                  Input.of("residual", RESIDUAL, s), Input.of("threshold", THRESHOLD, s)]
        # the fields read, resolved once: q^, r, w, the nominal threshold
        est, res, thr = (i.layout.index for i in inputs if i.layout is not None)
        self._i = (est["mode"], res["residual"], res["w"], thr["nominal"])
        self.start_inputs(inputs)

    def reset(self) -> None:
        """Back to monitoring (Monitor.reset)."""
        self.agei.reset()

    def process(self, k: int, inputs: dict[str, Any]) -> None:
        """q^_k, w_k, r_k, nominal_k -> trigger and override for k + 1."""
        i_mode, i_r, i_w, i_nominal = self._i
        res = inputs["residual"]
        out = self.agei.step(k, int(inputs["est"][i_mode]), res[i_w], res[i_r],
                             inputs["threshold"][i_nominal])
        pay = out.payload()
        for pub, lay in self._out:
            self.publish_array(pub, lay.labels, k + 1, lay.encode(pay))
        self.diag.update("tracker", OK, f"phase {out.phase}", {
            "sample": k, "trigger": out.trigger, "phase": out.phase, "row": out.row,
            **self.gain_values()})


def main(args: Sequence[str] | None = None) -> int:
    """Run the AGEI node."""
    return run_node(AgeiNode, args, prog="agei", usage=[USAGE])


if __name__ == "__main__":
    import sys

    sys.exit(main())
