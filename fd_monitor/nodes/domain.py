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
from collections.abc import Mapping, MutableMapping, Sequence

__all__ = ["die_with_parent", "domain_is_free", "free_domain", "hold_domain", "isolate_env"]

#: Child process: exit 1 when another participant shows up within 3 s (measured here:
#: discovery takes 0.05-2.4 s on loopback; a node's name may come after its topics).
_PROBE = """
import sys, time, rclpy
from rclpy.node import Node
rclpy.init()
node = Node("fd_monitor_domain_probe")
end = time.monotonic() + 3.0
while time.monotonic() < end:
    rclpy.spin_once(node, timeout_sec=0.05)
    others = [n for n in node.get_node_names() if n != node.get_name()]
    if others or node.count_publishers("/rosout") > 1:
        sys.exit(1)
sys.exit(0)
"""


#: Child process: one idle node, so a probe of another run sees this domain as taken.
_ANCHOR = """
import time, rclpy
from rclpy.node import Node
rclpy.init()                 # SIGTERM/SIGINT shut the context down: a clean exit follows
node = Node("fd_monitor_domain_anchor")
print("ready", flush=True)
while rclpy.ok():
    time.sleep(0.2)
node.destroy_node()          # its participant leaves the graph now, not at lease expiry
rclpy.try_shutdown()
"""


def die_with_parent() -> None:
    """In a child process (``preexec_fn``): get SIGTERM when the parent dies, even by
    SIGKILL (Linux), so no node outlives the run that started it."""
    if sys.platform.startswith("linux"):
        import ctypes
        import signal

        ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGTERM))  # PR_SET_PDEATHSIG


def hold_domain(env: Mapping[str, str] | None = None) -> subprocess.Popen:
    """Keep ``env``'s ROS domain visibly taken while a run uses it.

    A run (a test session, a demo) that has no node alive for a moment -- between two tests
    -- would look free to :func:`free_domain` of another run on the machine. This starts an
    idle node there (``fd_monitor_domain_anchor``), which dies with the caller; terminate it
    when the run ends.

    Returns
    -------
    subprocess.Popen
        The anchor process (its first line of output is ``ready``).
    """
    p = subprocess.Popen([sys.executable, "-c", _ANCHOR],
                         env=dict(os.environ if env is None else env),
                         stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                         preexec_fn=die_with_parent)
    assert p.stdout is not None
    p.stdout.readline()                  # the node exists (or the child failed: EOF)
    return p


def domain_is_free(domain: int, env: Mapping[str, str] | None = None) -> bool:
    """Whether a probe node in ``domain`` sees no other ROS node within 3 s."""
    base = dict(os.environ if env is None else env)
    try:
        return subprocess.run([sys.executable, "-c", _PROBE],
                              env={**base, "ROS_DOMAIN_ID": str(domain)}, timeout=30,
                              capture_output=True).returncode == 0
    except subprocess.TimeoutExpired:
        return False


def free_domain(env: Mapping[str, str] | None = None, tries: int = 5,
                candidates: Sequence[int] | None = None) -> int:
    """A random ROS_DOMAIN_ID in 1..100 with no other ROS node in it on this machine.

    Parameters
    ----------
    env : mapping, optional
        Environment of the probe (discovery range, RMW); default ``os.environ``.
    tries : int
        Domains probed at most (3 s each when free); the last one is returned if all
        are taken.
    candidates : sequence of int, optional
        The ids to draw from (default 1..100): parallel test workers draw from disjoint
        sets, so two of them probing at the same moment cannot both take one id.
    """
    pool = list(range(1, 101) if candidates is None else candidates)
    rng = random.SystemRandom()
    domain = rng.choice(pool)
    for _ in range(max(1, tries)):
        if domain_is_free(domain, env):
            return domain
        domain = rng.choice(pool)
    return domain


def isolate_env(env: MutableMapping[str, str], keep_domain: bool = False,
                candidates: Sequence[int] | None = None) -> MutableMapping[str, str]:
    """Make ``env`` a DDS environment of its own on this machine (the demo, the test suite).

    Discovery on localhost only (``ROS_AUTOMATIC_DISCOVERY_RANGE``; the deprecated
    ``ROS_LOCALHOST_ONLY`` removed), Fast DDS unless another RMW is chosen, and a
    ``ROS_DOMAIN_ID`` nobody else uses (:func:`free_domain`). Set it before rclpy starts in
    any process of that environment (the RMW reads it at init).

    Parameters
    ----------
    env : mutable mapping
        Changed in place (``os.environ`` or a child's copy).
    keep_domain : bool
        Keep a ``ROS_DOMAIN_ID`` already set (a test run given its domain).
    candidates : sequence of int, optional
        Ids :func:`free_domain` may choose from (default 1..100).

    Returns
    -------
    mutable mapping
        ``env``.
    """
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env.pop("ROS_LOCALHOST_ONLY", None)
    env.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
    if not (keep_domain and "ROS_DOMAIN_ID" in env):
        env["ROS_DOMAIN_ID"] = str(free_domain(env, candidates=candidates))
    return env
