"""``monitor``: the four chain nodes (observer, detector, agei, bias_estimator) on one
executor in one process, each with its own name, parameters and diagnostics; for a gain file
of another method (qb, hinf_sc, hminus_switched) the fused
:class:`~fd_monitor.nodes.runtime_node.RuntimeNode`."""

from __future__ import annotations

from collections.abc import Sequence

from fd_monitor.nodes import agei, bias_estimator, detector, observer, runtime_node
from fd_monitor.nodes.agei import AgeiNode
from fd_monitor.nodes.bias_estimator import BiasEstimatorNode
from fd_monitor.nodes.common import run_node
from fd_monitor.nodes.detector import DetectorNode
from fd_monitor.nodes.observer import ObserverNode
from fd_monitor.nodes.runtime_node import RuntimeNode, gain_method

__all__ = ["make_nodes", "main"]


def make_nodes(**kwargs) -> list:
    """The four chain nodes for a ``thresholds`` gain file; for any other method the fused
    :class:`~fd_monitor.nodes.runtime_node.RuntimeNode` (kwargs go to every node, e.g.
    ``context``).

    The observer, the chain's entry, is created last: by the time it subscribes to
    ``plant/y`` (what a source waits for) the other nodes already subscribe to ``plant/*``
    and to the observer's outputs, so none of them misses the first samples.
    """
    method = gain_method(**kwargs)
    if method is not None and method != "thresholds":
        return [RuntimeNode(**kwargs)]
    det, agei, est = DetectorNode(**kwargs), AgeiNode(**kwargs), BiasEstimatorNode(**kwargs)
    return [ObserverNode(**kwargs), det, agei, est]


def main(args: Sequence[str] | None = None) -> int:
    """Run the four nodes in one process."""
    return run_node(make_nodes, args, prog="monitor",
                    usage=[m.USAGE for m in (observer, detector, agei, bias_estimator,
                                             runtime_node)])


if __name__ == "__main__":
    import sys

    sys.exit(main())
