"""A data-path subscription that meets reliable and best-effort volatile publishers, and
the DDS MessageInfo under either executor.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from rclpy.node import Node
from rclpy.qos import (
    QoSPolicyKind,
    QoSProfile,
    ReliabilityPolicy,
)
from rclpy.qos_overriding_options import QoSOverridingOptions

from fd_monitor.nodes.qos import (
    data_sub_qos,
    incompatible_text,
    sub_events,
)

__all__ = ["DataInput", "with_message_info"]


def with_message_info(sub: Any) -> None:
    """Have ``sub``'s executor pass the DDS MessageInfo with each message.

    rclpy picks the callback form from its signature, and a two-argument callback is what
    breaks its EventsExecutor in these wheels (``SystemError: null argument to internal
    routine``): that executor calls a MessageInfo subscription's callback with ONE argument,
    the tuple ``(msg, info)``, where the SingleThreadedExecutor passes two. So the callback
    takes ``*args`` (one argument: rclpy chooses message-only) and the subscription is then
    marked as wanting the MessageInfo (``_callback_type``, which both executors read at every
    message). Tested: ``test_nodes_chain`` (plain u, y published in a burst, paired by
    their source timestamps under the EventsExecutor).
    """
    sub._callback_type = type(sub).CallbackType.WithMessageInfo


class DataInput:
    """A data-path subscription that meets reliable and best-effort volatile publishers.

    Starts reliable, keep-all (lossless with acknowledgement pacing). ``qos_overrides``
    parameters (``qos_overrides.<topic>.subscription.reliability|history|depth``) apply at
    creation. When a publisher is incompatible on RELIABILITY (a best-effort publisher) and
    the user did not override the reliability, the subscription is re-created best effort;
    every incompatibility is passed to ``report`` (one line naming topic and policy).

    Parameters
    ----------
    node : rclpy.node.Node
    msg_type : type
    topic : str
        As given to ``create_subscription`` (relative names resolve in the namespace).
    callback : callable
    report : callable
        Called with one line per incompatible-QoS event or switch.
    raw : bool
        Serialized messages (record).
    with_info : bool
        ``callback(msg, info)`` with the DDS MessageInfo (``source_timestamp``, ns), under
        either executor (:func:`with_message_info`); else ``callback(msg)``.
    switched : callable, optional
        Called (no argument) once the switch to best effort is done: the incompatibility
        is handled.
    """

    def __init__(self, node: Node, msg_type: Any, topic: str, callback: Callable[..., None],
                 report: Callable[[str], None], raw: bool = False,
                 with_info: bool = False, switched: Callable[[], None] | None = None) -> None:
        self.node, self.msg_type, self.topic = node, msg_type, topic
        self.callback, self.report, self.raw = callback, report, raw
        self.switched = switched
        self.with_info = with_info
        self.name = node.resolve_topic_name(topic)
        want = data_sub_qos()
        self.sub = self._create(want, qos_overriding_options=(
            QoSOverridingOptions.with_default_policies()))
        self.reliable = self.sub.qos_profile.reliability == ReliabilityPolicy.RELIABLE
        #: True when the user set the reliability (no automatic switch).
        self.overridden = self.sub.qos_profile.reliability != want.reliability
        self._switch_timer: Any = None

    def _on_incompatible(self, info: Any) -> None:
        line = incompatible_text(self.name, "subscription", info)
        policy = int(info.last_policy_kind)
        if (policy == QoSPolicyKind.RELIABILITY and self.reliable and not self.overridden
                and self._switch_timer is None):
            line += "; switching to best effort (meets every publisher)"
            # Not inside the subscription's own event callback: on the next executor turn.
            self._switch_timer = self.node.create_timer(0.0, self._switch)
        self.report(line)

    def _switch(self) -> None:
        self.node.destroy_timer(self._switch_timer)
        old = self.sub
        self.sub = self._create(data_sub_qos(reliable=False))
        self.node.destroy_subscription(old)
        self.reliable = False
        self._switch_timer = None
        if self.switched is not None:
            self.switched()

    def _create(self, qos: QoSProfile, **kwargs: Any) -> Any:
        if not self.with_info:
            return self.node.create_subscription(self.msg_type, self.topic, self.callback, qos,
                                                 raw=self.raw, **kwargs,
                                                 **sub_events(self._on_incompatible))
        callback = self.callback

        def deliver(*args: Any) -> None:
            # SingleThreadedExecutor: (msg, info); EventsExecutor: ((msg, info),)
            callback(*(args if len(args) == 2 else args[0]))
        sub = self.node.create_subscription(self.msg_type, self.topic, deliver, qos,
                                           raw=self.raw, **kwargs,
                                           **sub_events(self._on_incompatible))
        with_message_info(sub)
        return sub

    def destroy(self) -> None:
        """Destroy the subscription (lifecycle cleanup)."""
        if self._switch_timer is not None:
            self.node.destroy_timer(self._switch_timer)
        self.node.destroy_subscription(self.sub)
