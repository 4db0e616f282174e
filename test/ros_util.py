"""Helpers for tests that talk over real DDS: processes, in-process nodes, bounded waits.

Never sleep as a synchroniser: :func:`spin_until` spins an executor until a condition holds
or a deadline passes; :class:`Proc` always terminates (then kills) its process, even when the
test fails. The DDS isolation (ROS_DOMAIN_ID, localhost discovery) comes from conftest.py and
is inherited by every child process.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from fd_monitor.wire.topics import CHAIN_OUTPUTS

REPO = Path(__file__).resolve().parent.parent


def fd_env() -> dict[str, str]:
    """The environment for child processes (conftest's DDS isolation, the DDS profile)."""
    from fd_monitor.nodes.pacing import use_dds_profile

    use_dds_profile()
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    env["PYTHONUNBUFFERED"] = "1"
    return env


class Proc:
    """A child process (``python -m fd_monitor ...``) that is always cleaned up.

    Output goes to a temporary file (a full pipe would block the child); read it with
    :meth:`output`.
    """

    def __init__(self, args: Sequence[str], env: dict[str, str] | None = None) -> None:
        self.args = [sys.executable, "-m", "fd_monitor", *args]
        self._out = tempfile.TemporaryFile(mode="w+")
        self.p = subprocess.Popen(self.args, cwd=REPO, env=env or fd_env(), stdout=self._out,
                                  stderr=subprocess.STDOUT, text=True)

    def node_names(self) -> list[str]:
        """The ROS nodes this ``run <exe>`` process starts (empty for other commands)."""
        if "run" not in self.args:
            return []
        exe = self.args[self.args.index("run") + 1]
        chain = ["observer", "detector", "agei", "bias_estimator"]
        if exe == "monitor":
            # the fused node (any gain file), or the four chain nodes (thresholds only)
            gains = [a.split(":=", 1)[1] for a in self.args if a.startswith("gains:=")]
            thresholds = not gains or "thresholds" in gains[-1]
            four = "layout:=nodes" in self.args or "layout:=chain" in self.args
            return chain if thresholds and four else ["monitor"]
        return [exe]

    def wait(self, timeout: float) -> int:
        """Wait for the exit status (raises subprocess.TimeoutExpired)."""
        return self.p.wait(timeout)

    def signal(self, sig: int = signal.SIGINT) -> None:
        """Send a signal (SIGINT by default)."""
        if self.p.poll() is None:
            self.p.send_signal(sig)

    def output(self) -> str:
        """Everything the process printed so far (stdout and stderr)."""
        self._out.flush()
        self._out.seek(0)
        return self._out.read()

    def stop(self, timeout: float = 10.0) -> int | None:
        """Terminate, wait, kill on timeout; return the exit status."""
        if self.p.poll() is None:
            self.p.terminate()
            try:
                self.p.wait(timeout)
            except subprocess.TimeoutExpired:
                self.p.kill()
                self.p.wait(timeout)
        return self.p.returncode

    def __enter__(self) -> Proc:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
        self._out.close()


def run_cli(args: Sequence[str], timeout: float = 120.0) -> subprocess.CompletedProcess:
    """Run ``python -m fd_monitor ARGS`` to completion and capture its output."""
    return subprocess.run([sys.executable, "-m", "fd_monitor", *args], cwd=REPO, env=fd_env(),
                          capture_output=True, text=True, timeout=timeout)


def replay_through(procs: Sequence[Proc], rec: Proc, bag: Any, topics: Sequence[str],
                   wait_subscribers: int, timeout: float = 180.0, rate: float = 0.0) -> None:
    """Replay ``topics`` of ``bag`` flat out (or at ``rate`` x the recorded pace) into
    running node processes and wait until the recorder ``rec`` (started with ``--until``)
    has everything; stop all processes, always.

    Fails if replay or record fail, or if a node printed a traceback.
    """
    try:
        # Data topics are volatile: before the flat-out replay, every topic the recorder
        # records must show its publisher and the recorder in the graph.
        args = rec.args[rec.args.index("record") + 1:]
        recorded = [a for a in args[:args.index("-o")] if a.startswith("/fd/")]
        nodes = [n for p in procs for n in p.node_names()]
        assert wait_graph(recorded, 60.0, nodes), \
            f"nodes {nodes} or publishers of {recorded} not in the graph"
        rep = run_cli(["replay", str(bag), "--topics", *topics, "--rate", f"{rate:g}",
                       "--wait-subscribers", str(wait_subscribers)], timeout=timeout)
        assert rep.returncode == 0, rep.stderr
        try:
            status: int | str = rec.wait(timeout)
        except subprocess.TimeoutExpired:
            status = f"still running after {timeout} s"
        assert status == 0, (f"record: {status}\n" + rec.output()[-3000:]
                             + "".join(p.output()[-3000:] for p in procs))
    finally:
        for p in [rec, *procs]:
            p.stop()
    for p in procs:
        assert "Traceback" not in p.output(), p.output()


def wait_graph(topics: Sequence[str], timeout: float, nodes: Sequence[str] = (),
               recorder: str = "record", settle: float = 0.5) -> bool:
    """Poll the ROS graph until every node of ``nodes`` is in it, every topic has a
    publisher and ``recorder`` among its subscriptions, and every ``/fd/*`` endpoint count
    has stayed the same for ``settle`` s (the nodes' subscriptions all exist: data topics are
    volatile, a subscription that comes late misses data).
    """
    with ros_context() as ctx:
        from rclpy.node import Node

        node = Node("graph_probe", context=ctx)

        def counts() -> tuple:
            fd = sorted(t for t, _ in node.get_topic_names_and_types() if t.startswith("/fd/"))
            return tuple((t, node.count_publishers(t), node.count_subscribers(t)) for t in fd)

        def ready() -> bool:
            names = {n for n, _ in node.get_node_names_and_namespaces()}
            return set(nodes) <= names and all(node.count_publishers(t) >= 1
                       and any(i.node_name == recorder
                               for i in node.get_subscriptions_info_by_topic(t))
                       for t in topics)

        deadline = time.monotonic() + timeout
        try:
            last, since = None, time.monotonic()
            while time.monotonic() < deadline:
                now = counts()
                if now != last:
                    last, since = now, time.monotonic()
                elif ready() and time.monotonic() - since >= settle:
                    return True
                time.sleep(0.05)  # polling the graph, not synchronising messages
            return False
        finally:
            node.destroy_node()


@contextmanager
def ros_context(args: Sequence[str] | None = None) -> Iterator[Any]:
    """An initialised rclpy Context of its own (with command-line ``args``, e.g.
    ``--ros-args --params-file F``), shut down at the end."""
    from fd_monitor.nodes.pacing import use_dds_profile

    use_dds_profile()
    import rclpy

    ctx = rclpy.Context()
    rclpy.init(args=args, context=ctx)
    try:
        yield ctx
    finally:
        _destroy_nodes_of(ctx)
        rclpy.try_shutdown(context=ctx)
        ctx.destroy()


def _destroy_nodes_of(ctx: Any) -> None:
    """Destroy every node still alive in ``ctx``: a test that failed half way keeps its
    nodes referenced from its traceback (pytest keeps it for the report), and their
    publishers and subscriptions would otherwise stay in the graph of every later test."""
    import gc

    from rclpy.node import Node

    for obj in gc.get_objects():
        if isinstance(obj, Node) and obj.context is ctx:
            try:
                obj.destroy_node()
            except Exception:  # already destroyed: nothing to clean up
                pass


POLL = 0.02  # s between two looks at a spin_until condition


def spin_until(executor: Any, cond: Callable[[], bool], timeout: float,
               procs: Sequence[Proc] = ()) -> bool:
    """Spin ``executor`` until ``cond()`` holds (True) or ``timeout`` s pass (False).

    Stops early (False) when one of ``procs`` exited with a non-zero status.
    """
    deadline = time.monotonic() + timeout
    if cond():
        return True
    checked = time.monotonic()
    while time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
        # ``cond`` at most every POLL s, not after every callback: with a stream coming in,
        # a condition that looks over everything received made the wait quadratic.
        if time.monotonic() - checked >= POLL:
            if cond():
                return True
            checked = time.monotonic()
            for p in procs:
                if p.p.poll() not in (None, 0):
                    return cond()
    return cond()


class Collector:
    """A node recording decoded fd_monitor messages and /diagnostics, per topic.

    Parameters
    ----------
    context : rclpy.Context
    topics : sequence of str
        Float64MultiArray topics.
    diagnostics : bool
        Also subscribe to /diagnostics.
    """

    def __init__(self, context: Any, topics: Sequence[str], diagnostics: bool = False,
                 name: str = "collector") -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.node import Node
        from std_msgs.msg import Float64MultiArray

        from fd_monitor.nodes.qos import data_sub_qos, diagnostics_qos

        self.node = Node(name, context=context)
        self.msgs: dict[str, list[Any]] = {t: [] for t in topics}
        self.diagnostics: list[Any] = []
        self._decoded: dict[str, list[Any]] = {}
        self._statuses: dict[str, tuple[int, list[Any]]] = {}
        for t in topics:
            self.node.create_subscription(Float64MultiArray, t,
                                          lambda m, t=t: self.msgs[t].append(m),
                                          data_sub_qos())
        if diagnostics:
            self.node.create_subscription(DiagnosticArray, "/diagnostics",
                                          self.diagnostics.append, diagnostics_qos())

    def decoded(self, topic: str) -> list[Any]:
        """Decoded messages of a topic, in arrival order.

        Decoded once each (tests poll this in ``spin_until`` loops: decoding everything at
        every poll made a long wait quadratic in the messages received).
        """
        from fd_monitor.wire.conversions import decode

        done = self._decoded.setdefault(topic, [])
        msgs = self.msgs[topic]
        done.extend(decode(m, topic) for m in msgs[len(done):])
        return list(done)

    def statuses(self, name_part: str = "") -> list[Any]:
        """Every DiagnosticStatus received whose name contains ``name_part`` (filtered once
        per array and name part, for the same reason as :meth:`decoded`)."""
        seen, got = self._statuses.setdefault(name_part, (0, []))
        got.extend(s for a in self.diagnostics[seen:] for s in a.status if name_part in s.name)
        self._statuses[name_part] = (len(self.diagnostics), got)
        return list(got)


def status_text(status: Any) -> str:
    """A DiagnosticStatus's message with the texts a long one is moved to: ``detail`` (the
    full message) and ``reasons`` (every reason of the period)."""
    return " ".join([status.message, *(kv.value for kv in status.values
                                       if kv.key in ("detail", "reasons"))])


FD_TOPICS = [t.absolute for t in CHAIN_OUTPUTS]


def expected_payloads(outs: Sequence[Any]) -> dict[str, Any]:
    """The values the chain publishes on each topic for Monitor outputs (one run from 0):
    the components' payloads, encoded by field name with the topics' declarations."""
    import numpy as np

    from fd_monitor.model.system import load_system

    system = load_system("three_tank")
    layouts = {t.absolute: t.layout(system) for t in CHAIN_OUTPUTS}
    rows: dict[str, list] = {t: [] for t in FD_TOPICS}
    for o in outs:
        pays = (o.observer.payload(), o.detector.payload(), o.agei.payload(),
                o.estimator.payload())
        for t, lay in layouts.items():
            rows[t].append(lay.encode(*pays, restart=o.k == 0, bridge=False))
    return {t: np.array(v, dtype=float) for t, v in rows.items()}


def plain_msg(values: Any) -> Any:
    """A plain Float64MultiArray (no stamp, no labels), as a user's driver publishes it."""
    from std_msgs.msg import Float64MultiArray

    m = Float64MultiArray()
    m.data = [float(v) for v in values]
    return m


def biased_h1_run(n: int) -> tuple[Any, Any, Any, list[Any]]:
    """three_tank_bias_h1 (seed 2), n samples, +5 cm on y_h1 from sample 40 (alarms within
    the run): (system, u (n, nu), y (n, ny), the in-process Monitor's outputs)."""
    from fd_monitor.core.methods import load_gains
    from fd_monitor.core.monitor import Monitor
    from fd_monitor.core.simulator import simulate
    from fd_monitor.model.scenario import load_scenario
    from fd_monitor.model.system import load_system

    system = load_system("three_tank")
    traj = simulate(load_scenario("three_tank_bias_h1"), 2, n)
    u, y = traj.u[0], traj.y[0]
    y[40:] += [0.05, 0.0, 0.0]
    m = Monitor(system, load_gains("three_tank_thresholds", system))
    return system, u, y, [m.step(k, u[k], y[k]) for k in range(n)]
