"""The labels of the chain's own topics, declared once for the nodes that publish and read them.

Each function gives the ``layout.dim[0].label`` of a ``Float64MultiArray`` topic for a plant;
publishers write it and subscribers decode by it (:mod:`fd_monitor.wire.conversions`).
"""

from __future__ import annotations

from typing import Any

__all__ = ["GUARD_LABELS", "bias_labels", "state_labels"]


def state_labels(system: Any) -> tuple[str, ...]:
    """Labels of ``fd/state_estimate``: ObserverOutput.payload, then ``restart``."""
    return ("mode", *system.states, *(f"y~{o}" for o in system.outputs), "restart")


def bias_labels(system: Any) -> tuple[str, ...]:
    """Labels of ``fd/bias_estimate`` (BiasOutput.payload)."""
    o = system.outputs
    return (*o, *(f"iso:{n}" for n in o), "active", "k_detect")


#: Labels of ``fd/guard_event`` (AGEI's guard decision).
GUARD_LABELS = ("trigger", "phase", "row", "mode_uncertain")
