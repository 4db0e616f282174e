"""A level set and replaced within one burst interval still reaches /diagnostics."""

from __future__ import annotations

import pytest
from ros_util import ros_context

pytestmark = pytest.mark.ros


def test_a_warn_cleared_before_the_next_publication_is_published_first():
    from rclpy.node import Node

    from fd_monitor.nodes.diagnostics import OK, WARN, Diagnostics

    now = [0.0]
    with ros_context() as ctx:
        node = Node("diag_burst", context=ctx)
        diag = Diagnostics(node, "plant", period=1.0, clock=lambda: now[0])
        sent = []
        publish = diag._pub.publish
        diag._pub.publish = lambda arr: (sent.append([(s.level, s.message) for s in arr.status]),
                                         publish(arr))
        diag.add("input")                                # OK
        bad = "/plant/mode stamp 400: value mode is nan"
        diag.update("input", WARN, bad)                  # a level change: published at once
        assert sent == [[(WARN, bad)]]
        now[0] = 0.01
        diag.update("input", OK, "receiving")            # within 0.1 s: left for the burst
        assert len(sent) == 1
        now[0] = 0.02
        diag.update("input", WARN, bad)                  # the OK is replaced before it went
        assert sent[-1] == [(OK, "receiving")]           # out: published first
        now[0] = 0.03
        diag.update("input", OK, "receiving")            # and so is this WARN
        assert sent[-1] == [(WARN, bad)] and len(sent) == 3
        now[0] = 0.04
        diag.update("input", OK, "receiving again")      # no level change: nothing sent
        assert len(sent) == 3
        diag.destroy()
        node.destroy_node()
