"""Test configuration: isolate DDS and ROS logs for the whole run.

Every test run gets its own ROS_DOMAIN_ID and localhost-only discovery, so tests never see
(or disturb) another ROS graph on the machine; ROS logs go to a temporary folder.
"""

from __future__ import annotations

import os
import random
import sys
import tempfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent

# A domain nobody else on this (shared) machine is using: another test run or a user's ROS
# graph in the same domain would feed our nodes and count as subscribers. The probe runs in a
# child process so that this process's rclpy has not started yet.
_PROBE = """
import sys, time, rclpy
from rclpy.node import Node
rclpy.init()
node = Node("fd_monitor_domain_probe")
end = time.monotonic() + 1.5
while time.monotonic() < end:   # discovery of other participants (graph poll, bounded)
    rclpy.spin_once(node, timeout_sec=0.1)
others = [n for n, _ in node.get_node_names_and_namespaces() if n != node.get_name()]
sys.exit(1 if others else 0)
"""


def _free_domain() -> str:
    """A random ROS_DOMAIN_ID in 1..100 with no other ROS node in it on this machine."""
    import subprocess

    rng = random.SystemRandom()
    domain = rng.randint(1, 100)
    for _ in range(5):
        env = {**os.environ, "ROS_DOMAIN_ID": str(domain)}
        try:
            if subprocess.run([sys.executable, "-c", _PROBE], env=env, timeout=30,
                              capture_output=True).returncode == 0:
                break
        except subprocess.TimeoutExpired:
            pass
        domain = rng.randint(1, 100)
    return str(domain)


# Set before any rclpy import (the RMW reads them at init).
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.pop("ROS_LOCALHOST_ONLY", None)
os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
# UDP on loopback only: Fast DDS's shared-memory transport can hang at start on segments a
# killed process left in /dev/shm (tests kill processes on purpose).
os.environ.setdefault("FASTDDS_BUILTIN_TRANSPORTS", "UDPv4")
if "ROS_DOMAIN_ID" not in os.environ:
    try:
        import importlib.util

        ros = importlib.util.find_spec("rclpy") is not None
    except (ImportError, ValueError):
        ros = False
    os.environ["ROS_DOMAIN_ID"] = (_free_domain() if ros
                                   else str(random.SystemRandom().randint(1, 100)))
os.environ.setdefault("ROS_LOG_DIR", tempfile.mkdtemp(prefix="fd_monitor_roslog_"))
os.environ.setdefault("MPLBACKEND", "Agg")
os.environ.pop("FD_MONITOR_CONFIG", None)


@pytest.fixture(scope="session")
def repo() -> Path:
    """The repository root."""
    return REPO


@pytest.fixture(scope="session")
def python() -> str:
    """The interpreter running the tests (the project's .venv under scripts/test.sh)."""
    return sys.executable
