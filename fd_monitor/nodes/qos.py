"""QoS of the nodes' data path, ``/diagnostics`` and rclpy's event handlers.

QoS and the lossless data path
------------------------------
Data topics (``plant/*``, ``fd/*``, relative to the node's namespace) are RELIABLE and
VOLATILE: publishers keep the last ``qos_depth`` samples for repairs only, a subscriber that
joins late gets nothing old (as with ROS's default profile). Subscriptions are KEEP_ALL,
RELIABLE, VOLATILE, so they meet ROS's default publishers (reliable, volatile) losslessly;
when a best-effort publisher (the sensor-data profile) appears, the incompatible-QoS event
names RELIABILITY and :class:`DataInput` re-creates the subscription as best effort (logged and
reported on ``/diagnostics``), which meets both kinds. Every policy can be overridden per
topic with ROS's ``qos_overrides.<topic>.subscription.<policy>`` parameters (then no
automatic switch happens). Sources that run flat out (``plant_sim`` with ``rate_factor:
0.0``, ``replay --rate 0``) wait until the expected subscribers are matched, then pace by
acknowledgements: after every ``ack_window`` (< ``qos_depth``) samples they block in
``Publisher.wait_for_all_acked`` so no unacknowledged sample is ever overwritten in the
writer's history. Together: no sample is lost, whatever the rate.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSPolicyKind,
    QoSProfile,
    ReliabilityPolicy,
)

__all__ = ["DEFAULT_DEPTH", "data_pub_qos", "data_sub_qos", "diagnostics_qos",
           "incompatible_text", "pub_events", "sub_events"]


DEFAULT_DEPTH = 1000


def pub_events(incompatible: Callable[[Any], None] | None = None) -> dict[str, Any]:
    """``create_publisher`` keywords: only the incompatible-QoS handler, if given.

    rclpy's default handlers are off: each handler is one more entity in every wait set the
    executor builds, and rebuilding wait sets is most of a Python node's per-message cost.
    """
    return {"event_callbacks": PublisherEventCallbacks(incompatible_qos=incompatible,
                                                        use_default_callbacks=False)}


def sub_events(incompatible: Callable[[Any], None] | None = None) -> dict[str, Any]:
    """``create_subscription`` keywords: only the incompatible-QoS handler, if given."""
    return {"event_callbacks": SubscriptionEventCallbacks(incompatible_qos=incompatible,
                                                           use_default_callbacks=False)}


def data_pub_qos(depth: int = DEFAULT_DEPTH) -> QoSProfile:
    """Publisher QoS of the data path: reliable, volatile, keep last ``depth``."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=int(depth),
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


def data_sub_qos(reliable: bool = True) -> QoSProfile:
    """Subscriber QoS of the data path: volatile; reliable keep-all (no drops), or best effort
    keep last :data:`DEFAULT_DEPTH` (meets best-effort publishers too)."""
    if reliable:
        return QoSProfile(history=HistoryPolicy.KEEP_ALL, depth=1,
                          reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.VOLATILE)
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=DEFAULT_DEPTH,
                      reliability=ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.VOLATILE)


def incompatible_text(topic: str, side: str, info: Any) -> str:
    """One line for an incompatible-QoS event (``side``: "publisher" or "subscription")."""
    try:
        policy = QoSPolicyKind(int(info.last_policy_kind)).name
    except ValueError:
        policy = str(info.last_policy_kind)
    other = "a subscription" if side == "publisher" else "a publisher"
    return (f"{topic}: QoS incompatible with {other} (policy {policy}; "
            f"{int(info.total_count)} so far): our {side} cannot talk to it")

def diagnostics_qos() -> QoSProfile:
    """``/diagnostics`` QoS: reliable, volatile, keep last 100 (like diagnostic_updater)."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)
