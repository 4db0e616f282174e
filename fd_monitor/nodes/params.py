"""Node parameters: one declaration each (:class:`Param`: default, description, range,
choices), declared with their descriptors in one place (:func:`declare_parameters`).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any

import rclpy
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.node import Node

from fd_monitor.model.errors import FdMonitorError

__all__ = ["Param", "declare_parameters"]


@dataclass(frozen=True)
class Param:
    """One node parameter: name, default (fixes the type), description, range.

    Attributes
    ----------
    name : str
    default : bool, int, float, str or list
    description : str
    read_only : bool
        Read at start only (changing it later would have no effect).
    low, high : float, optional
        Inclusive range of a numeric parameter.
    choices : tuple of str
        The values a string parameter may take (empty: any), checked at declaration,
        before the node configures.
    """

    name: str
    default: Any
    description: str
    read_only: bool = True
    low: float | None = None
    high: float | None = None
    choices: tuple[str, ...] = ()

    def descriptor(self) -> ParameterDescriptor:
        """The ParameterDescriptor declared with the parameter."""
        d = ParameterDescriptor(name=self.name, description=self.description,
                                read_only=self.read_only)
        if self.low is not None and self.high is not None:
            if isinstance(self.default, bool):
                pass
            elif isinstance(self.default, int):
                d.integer_range = [IntegerRange(from_value=int(self.low),
                                                to_value=int(self.high), step=0)]
            elif isinstance(self.default, float):
                d.floating_point_range = [FloatingPointRange(from_value=float(self.low),
                                                             to_value=float(self.high),
                                                             step=0.0)]
        return d


def declare_parameters(node: Node, params: Iterable[Param]) -> SimpleNamespace:
    """Declare every parameter with its descriptor; return their values as attributes.

    A parameter the node's parameter files (or ``-p``) set that it does not declare is
    warned about once, all named in one line (a typo would otherwise be ignored).

    Raises
    ------
    FdMonitorError
        One line naming the node and the parameter when an override has the wrong type, is
        out of range (e.g. ``rate_factor:=1`` for a double: write ``1.0``) or not one of
        its ``choices``.
    """
    out = SimpleNamespace()
    params = tuple(params)
    declared = {p.name for p in params}
    unknown = sorted(n for n in getattr(node, "_parameter_overrides", {})
                     if n not in declared and not node.has_parameter(n)
                     and n not in _ROS_PARAMETERS and not n.startswith("qos_overrides."))
    if unknown:
        node.get_logger().warning(
            f"parameter file sets {', '.join(unknown)}, which node {node.get_name()} does not "
            f"declare: ignored (a typo? `--help` lists its parameters)")
    for p in params:
        try:
            node.declare_parameter(p.name, p.default, p.descriptor())
        except rclpy.exceptions.ParameterException as exc:
            raise FdMonitorError(f"node {node.get_name()}: parameter {p.name}: {exc} "
                                 f"(expected {type(p.default).__name__}, default "
                                 f"{p.default!r})") from None
        value = node.get_parameter(p.name).value
        if p.choices and value not in p.choices:
            raise FdMonitorError(f"node {node.get_name()}: parameter {p.name}: {value!r}: "
                                 f"expected one of {', '.join(p.choices)}")
        setattr(out, p.name, value)
    return out


#: Parameters rclpy itself declares on every node, and the process parameter ``robots`` the
#: executable reads before it makes its nodes (``-p`` and ``/**`` reach every node): not a
#: typo when a file sets them.
_ROS_PARAMETERS = frozenset({"use_sim_time", "start_type_description_service", "robots"})
