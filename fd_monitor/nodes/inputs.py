"""The inputs a chain node declares: topic, expected labels, required or feedback, plain or
stamped, held or joined (:class:`Input`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from fd_monitor.wire.topics import Layout, Topic

__all__ = ["Input"]


@dataclass(frozen=True)
class Input:
    """One joined input of a node.

    Attributes
    ----------
    name : str
        Key in ``process``'s inputs.
    topic : str
        Relative topic name (resolved in the node's namespace).
    labels : tuple of str, optional
        Expected channel names (None: accept any, check ``size`` only).
    size : int, optional
    initial : object
        For feedback inputs: the value at the node's first sample; ``None`` = required.
    plain_ok : bool
        Accept unstamped messages (a user's driver).
    hold : bool
        A plain message is held (sample-and-hold): each plain message of the other plain
        inputs (``plant/y``) gets the latest held one published before it.
    allow_nan : bool
        NaN is a value (``fd/threshold_override``: no override).
    stamp_offset : int
        Joined at ``stamp + stamp_offset``: -1 for a feedback message (stamped k + 1) that
        is needed at the sample it was decided at (k).
    optional : bool
        Needed at the sample itself (not feedback) but the node can do without it: waited
        for while its publisher is matched, else (or lost, as feedback is) ``None`` in
        ``process`` (``fd/guard_event`` for the bias estimator, which then runs its own
        AGEI; downstream nodes only: :class:`~fd_monitor.wire.join.StampJoin` ``optional``).
    sequence : bool
        ``fd/state_estimate`` of the entry node: its stamps are the samples this node
        processes and its ``restart`` field flags a restart (downstream role of
        :class:`~fd_monitor.wire.join.StampJoin`).
    layout : Layout, optional
        The topic's layout for the plant (:meth:`of`): labels and field index table, built
        once; ``process`` reads the fields through it.
    """

    name: str
    topic: str
    labels: tuple[str, ...] | None = None
    size: int | None = None
    initial: Any = None
    plain_ok: bool = False
    hold: bool = False
    allow_nan: bool = False
    stamp_offset: int = 0
    optional: bool = False
    sequence: bool = False
    layout: Layout | None = None

    def __post_init__(self) -> None:
        if self.sequence and self.layout is None:
            raise ValueError(f"input {self.name}: a sequence input is read by field: give "
                             f"its layout (Input.of)")

    @classmethod
    def of(cls, name: str, topic: Topic, source: Any, **kwargs: Any) -> Input:
        """The input of a declared topic (:mod:`fd_monitor.wire.topics`) for a plant."""
        return cls.laid_out(name, topic, topic.layout(source), **kwargs)

    @classmethod
    def laid_out(cls, name: str, topic: Topic, layout: Layout, **kwargs: Any) -> Input:
        """The input of a declared topic with a given layout (a runtime's own labels)."""
        return cls(name, topic.name, layout.labels, layout=layout, **kwargs)
