"""A ROS domain of one's own on a shared machine (the demo and the test suite).

Another ROS graph in the same ``ROS_DOMAIN_ID`` (a second demo, a test run, a user's robot)
would feed our nodes and count as their subscribers. :func:`free_domain` picks a random id in
1..100 (higher ones collide with ephemeral ports) in which a probe, run in a child process so
the caller's rclpy need not be started, sees no other node. Importing this module does not
import rclpy.
"""

from __future__ import annotations

import os
import random
import subprocess
import sys
from collections.abc import Mapping

__all__ = ["free_domain"]

#: Child process: exit 1 when another node shows up within 1.5 s (discovery, bounded poll).
_PROBE = """
import sys, time, rclpy
from rclpy.node import Node
rclpy.init()
node = Node("fd_monitor_domain_probe")
end = time.monotonic() + 1.5
while time.monotonic() < end:
    rclpy.spin_once(node, timeout_sec=0.1)
others = [n for n, _ in node.get_node_names_and_namespaces() if n != node.get_name()]
sys.exit(1 if others else 0)
"""


def free_domain(env: Mapping[str, str] | None = None, tries: int = 5) -> int:
    """A random ROS_DOMAIN_ID in 1..100 with no other ROS node in it on this machine.

    Parameters
    ----------
    env : mapping, optional
        Environment of the probe (discovery range, RMW); default ``os.environ``.
    tries : int
        Domains probed at most (about 2 s each); the last one is returned if all are busy.
    """
    rng = random.SystemRandom()
    base = dict(os.environ if env is None else env)
    domain = rng.randint(1, 100)
    for _ in range(max(1, tries)):
        try:
            if subprocess.run([sys.executable, "-c", _PROBE],
                              env={**base, "ROS_DOMAIN_ID": str(domain)}, timeout=30,
                              capture_output=True).returncode == 0:
                return domain
        except subprocess.TimeoutExpired:
            pass
        domain = rng.randint(1, 100)
    return domain
