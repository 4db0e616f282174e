"""``observer``: the hybrid automaton observer (Heracleous et al., eq. 5-7) as a node.

Joins, per sample k: ``/plant/u`` (u_k), ``/plant/y`` (y_k) (plain messages from a driver
are accepted and stamped on arrival), ``/fd/bias_estimate`` (sigma^_k, published by the
bias estimator at k - 1, stamped k) and ``/fd/guard_event`` (the AGEI trigger decided at
k - 1, stamped k). Publishes ``/fd/state_estimate`` (stamp k): ``mode``, x^_k (states) and
y~_k = y_k - sigma^_k (``y~<output>``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from fd_monitor.core.hybrid_observer import NO_TRIGGER, HybridObserver
from fd_monitor.nodes.common import OK, run_node
from fd_monitor.nodes.fd_node import FdNode, Input

__all__ = ["ObserverNode", "bias_labels", "main"]


def bias_labels(system: Any) -> tuple[str, ...]:
    """Labels of ``/fd/bias_estimate`` (BiasOutput.payload)."""
    o = system.outputs
    return (*o, *(f"iso:{n}" for n in o), "active", "k_detect")


GUARD_LABELS = ("trigger", "phase", "row")


class ObserverNode(FdNode):
    """Hybrid observer node.

    Parameters
    ----------
    observer : HybridObserver, optional
        Default: built for the ``system`` parameter.
    system, gains, qos, **kwargs
        See :class:`~fd_monitor.nodes.fd_node.FdNode`.
    """

    def __init__(self, observer: HybridObserver | None = None, system=None, gains=None,
                 qos=None, node_name: str = "observer", **kwargs: Any) -> None:
        super().__init__(node_name, (), system, gains, qos, **kwargs)
        s = self.system
        self.observer = observer if observer is not None else HybridObserver(s)
        self.pub = self.publisher("/fd/state_estimate")
        self.diag.add("estimate", self.params.stale_timeout)
        blab = bias_labels(s)
        self.start_inputs([
            Input("u", "/plant/u", s.inputs, plain_ok=True),
            Input("y", "/plant/y", s.outputs, plain_ok=True),
            Input("sigma", "/fd/bias_estimate", blab, initial=np.zeros(len(blab))),
            Input("guard", "/fd/guard_event", GUARD_LABELS,
                  initial=np.array([float(NO_TRIGGER), 0.0, 0.0])),
        ])

    def process(self, k: int, inputs: dict[str, Any]) -> None:
        """u_k, y_k, sigma^_k, trigger -> (q^_k, x^_k, y~_k)."""
        ny = self.system.ny
        out = self.observer.step(k, inputs["u"], inputs["y"], inputs["sigma"][:ny],
                                 int(inputs["guard"][0]))
        labels, values = out.payload(self.system)
        self.publish_array(self.pub, labels, k, values)
        self.diag.update("estimate", OK, f"mode {self.system.mode_names[out.mode]}",
                         {"sample": k, "mode": self.system.mode_names[out.mode],
                          "x_hat": out.x_hat, **self.gain_values()})


def main(args: Sequence[str] | None = None) -> int:
    """Run the observer node."""
    return run_node(ObserverNode, args, prog="observer")


if __name__ == "__main__":
    import sys

    sys.exit(main())
