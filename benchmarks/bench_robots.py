"""N robots' monitors at 100 Hz on this machine: latency, CPU and memory per robot.

For each N (default 1, 8, 16, 32): N robots' monitors (the fused node, three_tank
thresholds gain file, namespaces ``/robot0`` ... ``/robot<N-1>``), a process each or M to a
process (``--per-process``); one driver process
publishes every robot's ``plant/u`` and ``plant/y`` at ``--rate`` Hz (default 100; the demo
scenario, stamped) for ``--seconds`` s; this process subscribes to every robot's
``fd/alarm`` (the only output subscribed: the monitor builds no message nobody subscribes
to) and records each sample's arrival.

Printed per N (the 1-minute load average with each line):

* latency y_k published -> alarm_k received over all robots and samples: p50, p99, max (ms);
  ``missing``: outputs that never arrived;
* ``cpu/sample``: CPU time (user + system, /proc) of the N monitor processes during the run,
  per robot and sample, us, and as ``% core`` per robot (cpu seconds / run seconds / N);
  the issue's goal is <= 300 us per sample (3 % of a core at 100 Hz);
* RSS per process, MB (mean and max; goal <= 50 MB);
* the floors (``--floor``): a bare rclpy process with the same two subscriptions at the same
  rate, measured the same way, in the variants of :data:`FLOORS` (SingleThreadedExecutor or
  EventsExecutor in a spin_once loop; message objects, serialized bytes, bytes decoded by the
  project's RawDecoder, plus one publication per sample; rclpy alone, numpy, the monitor's
  imports): what any Python ROS node receiving u and y costs here, and what each choice
  costs;
* below each row, the first process's CPU per sample by thread name (the Python main thread,
  Fast DDS's threads).

Robots per process (``--per-process M ...``, one layout per value, run side by side for each
N): 1 (default) is a ``monitor`` process per robot; M > 1 hosts M robots in each process
(``monitor --ros-args -p robots:=[robot0, ...]``: one executor and one DDS participant per
process), so N = 32 with M = 16 is two processes. RSS is then also printed per robot (the
processes' RSS over the robots they host), and the threads' CPU per sample of the first
process's robots. ``--subscribe supervisor`` (beside or instead of ``alarm``): the receiver
subscribes to what a fleet supervisor reads, every robot's ``fd/fault`` and ``/diagnostics``,
plus the first robot's ``fd/alarm`` for the latency (so the other robots publish no data
topic per sample).

Side by side (``--tree LABEL=DIR``, repeatable): the monitors of each N are also run from
another source tree (e.g. the base commit, ``git archive BASE | tar -x -C DIR``) on
``PYTHONPATH``, alternating with this tree, each ``--repeat`` times; the best run of each tree
(least CPU per sample) is printed last, with its load. ``--profile FILE``: the first monitor
runs under cProfile during the measured window only (enabled on SIGUSR1, written to FILE on
SIGUSR2: start-up is left out; the profiler's own cost inflates its CPU figures).
``--path SAMPLES``: the monitor node's own Python path per sample without DDS
(:data:`NODE_PATH`: its subscription callbacks called directly), back to back (``warm``) and
one sample every 1/rate s (``paced``, as live), per tree: the figure a change to the node's
Python is seen in without the 10-30 % run-to-run noise of the DDS figures.

DDS configurations side by side (``--dds LABEL=SPEC``, repeatable; :func:`dds_variants`): a
Fast DDS profile file and/or environment variables per variant (``benchmarks/dds/*.xml``),
against the nodes' profile, ``--repeat`` rounds alternating; the floors of
:data:`DDS_FLOORS` (with ``--floor``) and the monitors of each N; best of each printed with
the main-thread / DDS-thread split, RSS and PSS.

Run: ``.venv/bin/python benchmarks/bench_robots.py [--robots 1 8 16 32] [--rate 100]
[--seconds 10] [--per-process 1 16] [--subscribe alarm supervisor] [--floor]
[--tree before=DIR] [--repeat 3] [--profile FILE] [--path 500]
[--dds hb100=benchmarks/dds/hb100.xml]``.
Isolated ROS_DOMAIN_ID, loopback discovery.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

#: ``python -c DRIVER <robots> <rate> <seconds>``: waits for every robot's subscriber, prints
#: ``ready``, then on ``go`` sends and prints one JSON line of send times per sample.
DRIVER = r"""
import json, sys, time
import rclpy
from std_msgs.msg import Float64MultiArray
from fd_monitor.nodes.pacing import use_dds_profile
from fd_monitor.nodes.qos import data_pub_qos
from fd_monitor.wire.conversions import to_msg
from fd_monitor.wire.topics import PLANT_U, PLANT_Y
from fd_monitor.core.simulator import simulate
from fd_monitor.model.scenario import load_scenario
use_dds_profile(); rclpy.init()
N, rate, secs = int(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3])
node = rclpy.create_node("robots_driver")
sc = load_scenario("three_tank_bias_h1")
K = int(rate * secs)
tr = simulate(sc, None, K + 20)
u, y = tr.u[0].tolist(), tr.y[0].tolist()
# serialized once per sample (every robot gets the same u_k, y_k): the driver's own cost per
# message is one publish of bytes, so 32 robots' 6,400 messages/s leave the cores to the
# monitors
from rclpy.serialization import serialize_message
su = [serialize_message(to_msg(sc.system.inputs, k, u[k])) for k in range(K + 10)]
sy = [serialize_message(to_msg(sc.system.outputs, k, y[k])) for k in range(K + 10)]
pubs = [(node.create_publisher(Float64MultiArray, f"/robot{i}{PLANT_U.absolute}", data_pub_qos()),
         node.create_publisher(Float64MultiArray, f"/robot{i}{PLANT_Y.absolute}", data_pub_qos()))
        for i in range(N)]
while any(p.get_subscription_count() < 1 for pair in pubs for p in pair):
    time.sleep(0.05)
print("ready", flush=True)
sys.stdin.readline()
# 10 warm-up samples (every link through), then K measured ones
sent = []
t0 = time.perf_counter()
for k in range(K + 10):
    due = t0 + k / rate
    d = due - time.perf_counter()
    if d > 0:
        time.sleep(d)
    row = []
    mu, my = su[k], sy[k]
    for pu, py in pubs:
        pu.publish(mu)
        row.append(time.perf_counter())
        py.publish(my)
    sent.append(row)
print(json.dumps({"sent": sent}), flush=True)
"""

#: A bare rclpy node with the monitor's two subscriptions (the floor):
#: ``python -c BARE <executor> <messages> <imports>`` with executor ``events`` (rclpy's
#: EventsExecutor in a spin_once loop, as the monitor), ``until`` (its
#: ``spin_until_future_complete``: the C++ loop, no Python turn per event; in these wheels
#: it polls, a whole core busy, as its ``spin()`` does) or ``single``
#: (SingleThreadedExecutor.spin); messages ``msg`` (deserialized message objects), ``raw``
#: (serialized bytes, not read), ``decode`` (serialized, decoded by the project's
#: RawDecoder as the monitor does), ``publish`` (decode, and publish one serialized
#: 2-value message per y: what the monitor's fd/alarm costs at least); imports ``ros`` (rclpy
#: and the messages only), ``numpy``, ``monitor`` (everything the monitor imports).
BARE = r"""
import sys
executor, messages, imports = sys.argv[1:4]
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64MultiArray
if imports == "numpy":
    import numpy
if imports == "monitor" or messages in ("decode", "publish"):
    import fd_monitor.nodes.monitor
# the DDS profile: inherited from the benchmark's environment (env())
rclpy.init()
n = rclpy.create_node("bare", namespace="/robot0")
# the monitor's data QoS (data_sub_qos / data_pub_qos), without importing fd_monitor
qos = QoSProfile(history=HistoryPolicy.KEEP_ALL, depth=1,
                 reliability=ReliabilityPolicy.RELIABLE)
pub_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                     reliability=ReliabilityPolicy.RELIABLE)
cb = lambda m: None
if messages in ("decode", "publish"):
    from functools import partial
    from rclpy.serialization import deserialize_message
    from fd_monitor.nodes.serialized import SerializedArray
    from fd_monitor.wire.conversions import RawDecoder
    dec = {t: RawDecoder(partial(deserialize_message, message_type=Float64MultiArray))
           for t in "uy"}
    cb_u = lambda raw: dec["u"].decode(raw)
    if messages == "publish":
        pub = n.create_publisher(Float64MultiArray, "fd/alarm", pub_qos)
        enc = SerializedArray(["h1", "h2"])
        def cb_y(raw):
            d = dec["y"].decode(raw)
            pub.publish(enc.encode(d.stamp, [0.0, 0.0]))
    else:
        cb_y = lambda raw: dec["y"].decode(raw)
else:
    cb_u = cb_y = cb
raw = messages != "msg"
n.create_subscription(Float64MultiArray, "plant/u", cb_u, qos, raw=raw)
n.create_subscription(Float64MultiArray, "plant/y", cb_y, qos, raw=raw)
try:
    if executor == "events":
        from rclpy.experimental import EventsExecutor
        ex = EventsExecutor(); ex.add_node(n)
        while rclpy.ok():
            ex.spin_once(timeout_sec=0.1)
    elif executor == "until":
        # the EventsExecutor's own C++ loop, until a future set at shutdown
        from rclpy.experimental import EventsExecutor
        from rclpy.task import Future
        ex = EventsExecutor(); ex.add_node(n)
        stop = Future()
        n.context.on_shutdown(lambda: stop.set_result(None))
        ex.spin_until_future_complete(stop)
    else:
        ex = SingleThreadedExecutor(); ex.add_node(n)
        ex.spin()
except BaseException:
    pass
"""

#: ``python -c PROFILED FILE <fd_monitor arguments>``: the fd_monitor CLI with cProfile on the
#: main thread (where rclpy's EventsExecutor runs every callback) between SIGUSR1 and SIGUSR2;
#: the statistics go to FILE at SIGUSR2.
PROFILED = r"""
import cProfile, signal, sys, time
out = sys.argv[1]
sys.argv = ["fd_monitor", *sys.argv[2:]]
prof = cProfile.Profile(time.thread_time)  # the main thread's CPU, not the wall clock
signal.signal(signal.SIGUSR1, lambda *a: prof.enable())
def stop(*a):
    prof.disable()
    prof.dump_stats(out)
signal.signal(signal.SIGUSR2, stop)
from fd_monitor.commands.cli import main
sys.exit(main())
"""

#: ``python -c NODE_PATH <samples> <rate>``: the monitor node's own Python path per sample,
#: without DDS delivery: a MonitorNode (three_tank thresholds, one in-process subscriber of
#: ``fd/alarm``) whose u and y subscription callbacks are called directly with the driver's
#: serialized messages; main-thread CPU (``time.thread_time``) per sample, best of 3 passes,
#: ``warm`` back to back and ``paced`` one sample every 1/rate s (as live: caches cold).
#: Prints one JSON line.
NODE_PATH = r"""
import json, sys, time
import rclpy
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from std_msgs.msg import Float64MultiArray
from fd_monitor.core.simulator import simulate
from fd_monitor.model.scenario import load_scenario
from fd_monitor.nodes.monitor import MonitorNode
from fd_monitor.wire.conversions import to_msg
n, rate = int(sys.argv[1]), float(sys.argv[2])
rclpy.init()
sc = load_scenario("three_tank_bias_h1")
K = 10 + 6 * n
tr = simulate(sc, None, K)
U = [serialize_message(to_msg(sc.system.inputs, k, tr.u[0][k].tolist())) for k in range(K)]
Y = [serialize_message(to_msg(sc.system.outputs, k, tr.y[0][k].tolist())) for k in range(K)]
node = MonitorNode(namespace="/robot0")
rx = rclpy.create_node("rx", namespace="/robot0")
rx.create_subscription(Float64MultiArray, "fd/alarm", lambda m: None, QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.BEST_EFFORT),
    raw=True)
alarm = [p for p in node.pubs if p.topic_name.endswith("/fd/alarm")][0]
t0 = time.monotonic()
while alarm.get_subscription_count() < 1 and time.monotonic() - t0 < 10:
    time.sleep(0.01)
cu, cy = node._data_inputs["u"].callback, node._data_inputs["y"].callback
for k in range(10):
    cu(U[k]); cy(Y[k])
out, k = {"warm": [], "paced": []}, 10
for _ in range(3):
    t = time.thread_time()
    for j in range(k, k + n):
        cu(U[j]); cy(Y[j])
    out["warm"].append((time.thread_time() - t) / n * 1e6)
    k += n
    tot = 0.0
    for j in range(k, k + n):
        time.sleep(1.0 / rate)
        t = time.thread_time()
        cu(U[j]); cy(Y[j])
        tot += time.thread_time() - t
    out["paced"].append(tot / n * 1e6)
    k += n
assert node.processed == k, node.processed
print(json.dumps({w: min(v) for w, v in out.items()}))
node.destroy_node(); rx.destroy_node(); rclpy.try_shutdown()
"""

#: The floor variants ``--floor`` measures: (executor, messages, imports).
FLOORS = (("single", "msg", "ros"), ("events", "msg", "ros"), ("events", "raw", "ros"),
          ("events", "raw", "numpy"), ("events", "decode", "monitor"),
          ("events", "publish", "monitor"), ("until", "publish", "monitor"))

#: The floors ``--dds`` measures under each DDS configuration (with ``--floor``).
DDS_FLOORS = (("events", "publish", "monitor"),)


def env() -> dict[str, str]:
    """An isolated ROS environment (random domain, loopback discovery)."""
    from fd_monitor.nodes.pacing import use_dds_profile

    use_dds_profile()
    e = dict(os.environ)
    e.setdefault("ROS_DOMAIN_ID", str(random.SystemRandom().randint(101, 200)))
    e["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    e.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
    e.setdefault("ROS_LOG_DIR", "/tmp/fd_monitor_bench_logs")
    e["PYTHONPATH"] = str(REPO) + os.pathsep + e.get("PYTHONPATH", "")
    os.environ.update({k: e[k] for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE",
                                         "RMW_IMPLEMENTATION", "ROS_LOG_DIR")})
    return e


def load() -> float:
    return os.getloadavg()[0]


def cpu_seconds(pids: list[int]) -> float:
    """User + system CPU seconds used so far by the processes (/proc)."""
    tick = os.sysconf("SC_CLK_TCK")
    total = 0.0
    for pid in pids:
        try:
            f = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        total += (int(f[11]) + int(f[12])) / tick
    return total


def thread_cpu(pid: int) -> dict[str, float]:
    """CPU seconds so far per thread name of a process (/proc/<pid>/task: the Python main
    thread, rclpy's executor, Fast DDS's receive/event/shm threads, ...), summed by name."""
    tick = os.sysconf("SC_CLK_TCK")
    out: dict[str, float] = {}
    try:
        tasks = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return out
    for t in tasks:
        try:
            raw = Path(f"/proc/{pid}/task/{t}/stat").read_text()
        except OSError:
            continue
        name = raw[raw.index("(") + 1:raw.rindex(")")]
        f = raw.rsplit(")", 1)[1].split()
        try:
            # the scheduler's ns count: a clock tick (10 ms) is 10 us per sample of a 10 s
            # run at 100 Hz, as much as the differences measured
            v = int(Path(f"/proc/{pid}/task/{t}/schedstat").read_text().split()[0]) * 1e-9
        except (OSError, ValueError, IndexError):
            v = (int(f[11]) + int(f[12])) / tick
        out[name] = out.get(name, 0.0) + v
    return out


def rss_mb(pid: int) -> float:
    """Resident set size of a process, MB (/proc)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def pss_mb(pid: int) -> float:
    """Proportional set size of a process, MB (/proc/<pid>/smaps_rollup)."""
    try:
        for line in Path(f"/proc/{pid}/smaps_rollup").read_text().splitlines():
            if line.startswith("Pss:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return float("nan")


def monitor_commands(n_robots: int, per_process: int) -> list[list[str]]:
    """The ``fd_monitor run monitor`` arguments of each process of an N-robot fleet:
    ``per_process`` 1, one process per robot (``-r __ns:=/robot<i>``); M > 1, robots
    ``robot0`` ... hosted M to a process (``-p robots:=[robot<i>, ...]``, one executor and one
    DDS participant per process; the last process takes the rest)."""
    if per_process <= 1:
        return [["run", "monitor", "--ros-args", "-r", f"__ns:=/robot{i}"]
                for i in range(n_robots)]
    return [["run", "monitor", "--ros-args", "-p",
             "robots:=[" + ", ".join(f"robot{i}" for i in range(a, min(a + per_process,
                                                                     n_robots))) + "]"]
            for a in range(0, n_robots, per_process)]


#: What the benchmark's receiver subscribes to (``--subscribe``): ``alarm`` every robot's
#: ``fd/alarm`` (latency of every robot and sample); ``supervisor`` what a fleet supervisor
#: reads, every robot's ``fd/fault`` and ``/diagnostics``, plus the first robot's
#: ``fd/alarm`` alone for the latency (one robot of N pays that one extra writer).
SUBSCRIBE = ("alarm", "supervisor")


def run_fleet(n_robots: int, rate: float, seconds: float, e: dict[str, str],
              floor: tuple[str, str, str] | None = None, tree: str | None = None,
              profile: str | None = None, per_process: int = 1,
              subscribe: str = "alarm") -> dict:
    """One N: start, drive, measure, stop. ``tree``: the monitors' source tree (first on
    ``PYTHONPATH``; default this one); ``profile``: cProfile the first monitor's measured
    window into this file; ``per_process``: robots per monitor process
    (:func:`monitor_commands`); ``subscribe``: one of :data:`SUBSCRIBE`."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from std_msgs.msg import Float64MultiArray

    from fd_monitor.nodes.fault import fault_qos
    from fd_monitor.nodes.process import _events_executor
    from fd_monitor.nodes.qos import data_sub_qos, diagnostics_qos
    from fd_monitor.wire.topics import ALARM, FAULT

    if profile and os.path.exists(profile):
        os.remove(profile)
    if floor:
        procs = [subprocess.Popen([sys.executable, "-c", BARE, *floor], env=e,
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    else:
        me = ({**e, "PYTHONPATH": tree + os.pathsep + e.get("PYTHONPATH", "")} if tree
              else e)
        cmds = monitor_commands(n_robots, per_process)
        procs = [subprocess.Popen([sys.executable,
                                   *(["-c", PROFILED, profile] if profile and i == 0
                                     else ["-m", "fd_monitor"]), *cmd],
                                  env=me, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
                 for i, cmd in enumerate(cmds)]
    node = rclpy.create_node(f"robots_rx_{n_robots}")
    arrivals: list[dict[int, float]] = [{} for _ in range(n_robots)]
    # the robots whose fd/alarm is received (latency), and the topics waited for at start
    timed = range(n_robots if subscribe == "alarm" else min(1, n_robots))
    awaited = [f"/robot{i}{ALARM.absolute}" for i in timed]
    if not floor:
        for i in timed:
            node.create_subscription(
                Float64MultiArray, f"/robot{i}{ALARM.absolute}",
                lambda m, a=arrivals[i]: a.__setitem__(int(m.data[0]), time.perf_counter()),
                data_sub_qos())
        if subscribe == "supervisor":
            got = {"fault": 0, "diagnostics": 0}

            def count(what: str) -> Callable[[Any], None]:
                return lambda m: got.__setitem__(what, got[what] + 1)
            for i in range(n_robots):
                node.create_subscription(Float64MultiArray, f"/robot{i}{FAULT.absolute}",
                                         count("fault"), fault_qos())
                awaited.append(f"/robot{i}{FAULT.absolute}")
            node.create_subscription(DiagnosticArray, "/diagnostics", count("diagnostics"),
                                     diagnostics_qos())
    ex = _events_executor()
    ex.add_node(node)
    drv = subprocess.Popen([sys.executable, "-c", DRIVER, str(n_robots), str(rate),
                            str(seconds)], env=e, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                           text=True)
    assert drv.stdin is not None and drv.stdout is not None
    row: dict = {"robots": n_robots, "floor": floor, "tree": tree}
    try:
        if drv.stdout.readline().strip() != "ready":
            raise RuntimeError("driver did not start")
        if not floor:
            deadline = time.monotonic() + 120
            while any(node.count_publishers(t) < 1 for t in awaited) \
                    and time.monotonic() < deadline:
                ex.spin_once(timeout_sec=0.05)
        time.sleep(2.0)                      # start-up CPU settles
        pids = [p.pid for p in procs]
        cpu0, t0 = cpu_seconds(pids), time.perf_counter()
        threads0 = thread_cpu(pids[0])
        if profile and not floor:
            procs[0].send_signal(signal.SIGUSR1)
        drv.stdin.write("go\n")
        drv.stdin.flush()
        import select
        line = ""
        while not line:
            if select.select([drv.stdout], [], [], 0)[0]:
                line = drv.stdout.readline()
            else:
                ex.spin_once(timeout_sec=0.01)
        end = time.perf_counter() + 2.0
        while time.perf_counter() < end:
            ex.spin_once(timeout_sec=0.01)
        cpu = cpu_seconds(pids) - cpu0
        if profile and not floor:
            procs[0].send_signal(signal.SIGUSR2)
            deadline = time.monotonic() + 30
            while not os.path.exists(profile) and time.monotonic() < deadline:
                time.sleep(0.1)
            time.sleep(0.5)                  # written
        threads = {n: v - threads0.get(n, 0.0) for n, v in thread_cpu(pids[0]).items()}
        wall = time.perf_counter() - t0 - 2.0
        sent = json.loads(line)["sent"][10:]
        K = len(sent)
        rows = [(i, k) for i in timed for k in range(10, 10 + K)]
        lat = np.array([arrivals[i][k] - sent[k - 10][i] for i, k in rows
                        if k in arrivals[i]]) * 1e3
        robots = n_robots if not floor else 1
        # robots of the first process (its threads' CPU is per sample of those)
        first = 1 if floor or per_process <= 1 else min(per_process, n_robots)
        rss = [rss_mb(p) for p in pids]
        row.update(samples=K, load=round(load(), 2),
                   missing=0 if floor else len(rows) - lat.size,
                   cpu_us_per_sample=cpu / robots / K * 1e6,
                   core_pct=100 * cpu / wall / robots,
                   rss_mb=[round(v, 1) for v in rss],
                   # process RSS shared among the robots it hosts
                   rss_per_robot=sum(rss) / robots, per_process=per_process,
                   subscribe=subscribe, processes=len(pids),
                   threads={n: round(v / K / first * 1e6) for n, v in
                            sorted(threads.items(), key=lambda kv: -kv[1]) if v > 0})
        if lat.size:
            row.update(p50_ms=float(np.median(lat)), p99_ms=float(np.percentile(lat, 99)),
                       max_ms=float(lat.max()))
        # PSS: a shared library's or shared segment's pages divided among the processes
        # that map them (RSS counts them whole in each); N x PSS is what N processes take
        row["pss_mb"] = [round(pss_mb(p), 1) for p in pids]
    finally:
        for p in [drv, *procs]:
            p.terminate()
        for p in [drv, *procs]:
            try:
                p.wait(15)
            except subprocess.TimeoutExpired:
                p.kill()
        ex.shutdown()
        node.destroy_node()
    return row


def node_path(samples: int, rate: float, e: dict[str, str], tree: str | None = None) -> dict:
    """The monitor node's Python path per sample without DDS (:data:`NODE_PATH`), us."""
    me = {**e, "PYTHONPATH": tree + os.pathsep + e.get("PYTHONPATH", "")} if tree else e
    out = subprocess.run([sys.executable, "-c", NODE_PATH, str(samples), str(rate)], env=me,
                         capture_output=True, text=True, check=True).stdout
    return dict(json.loads(out.strip().splitlines()[-1]), load=round(load(), 2))


def dds_variants(specs: list[str], e: dict[str, str]) -> list[tuple[str, dict[str, str]]]:
    """The DDS configurations of ``--dds LABEL=SPEC``: SPEC is comma-separated items, each a
    Fast DDS profile file (XML; relative to the working directory or this repository; it
    goes into ``FASTRTPS_DEFAULT_PROFILES_FILE`` and ``FASTDDS_DEFAULT_PROFILES_FILE``, so
    ``use_dds_profile`` keeps it as a user's profile) or ``VAR=VALUE`` (any environment
    variable, e.g. ``ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET``). The first configuration is
    ``nodes``: the environment as the nodes get it (``config/fastdds.xml``)."""
    out = [("nodes", e)]
    for spec in specs:
        label, _, items = spec.partition("=")
        me = dict(e)
        for item in filter(None, items.split(",")):
            if "=" in item:
                var, _, value = item.partition("=")
                me[var] = value
                continue
            xml = Path(item) if Path(item).is_file() else REPO / item
            if not xml.is_file():
                raise SystemExit(f"--dds {spec}: no profile file {item}")
            for var in ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE"):
                me[var] = str(xml.resolve())
        out.append((label, me))
    return out


def dds_side_by_side(args: argparse.Namespace, e: dict[str, str]) -> None:
    """``--dds``: every configuration of :func:`dds_variants` in turn, ``--repeat`` rounds
    (alternating, so a change of the machine's load hits them alike): the floors of
    :data:`DDS_FLOORS` (with ``--floor``) and the monitors of each ``--robots`` N. The
    environment goes to the driver and the measured processes; the receiver (this process)
    keeps the nodes' profile. Best run (least CPU per sample) of each printed last, with the
    first process's CPU per sample split main thread / Fast DDS threads (``dds.*``)."""
    variants = dds_variants(args.dds, e)
    best: dict[tuple, dict] = {}
    for _ in range(args.repeat):
        for label, me in variants:
            runs = [(1, f) for f in (DDS_FLOORS if args.floor else ())]
            runs += [(n, None) for n in args.robots]
            for n, floor in runs:
                # the first --per-process and --subscribe layout
                r = run_fleet(n, args.rate, args.seconds, me, floor=floor,
                              per_process=args.per_process[0], subscribe=args.subscribe[0])
                r["label"] = label
                print(_fmt(r), flush=True)
                key = (floor, n, label)
                if key not in best or r["cpu_us_per_sample"] < best[key]["cpu_us_per_sample"]:
                    best[key] = r
    print(f"best of {args.repeat} (least CPU per sample); first process, us per sample: "
          f"main thread ('python') / Fast DDS threads ('dds.*'):")
    for key in sorted(best, key=lambda k: (k[0] is None, k[0] or (), k[1])):
        r = best[key]
        th = r.get("threads", {})
        dds = sum(v for name, v in th.items() if name.startswith("dds."))
        what = f"floor {'/'.join(r['floor'])}" if r["floor"] else f"{r['robots']} monitors"
        print(f"{what + ' [' + r['label'] + ']':44} cpu {r['cpu_us_per_sample']:5.0f} us "
              f"(main {th.get('python', 0):4d}, dds {dds:4d})  missing "
              f"{r.get('missing', 0):4d}  p99 {r.get('p99_ms', float('nan')):6.2f} ms  "
              f"RSS {np.mean(r.get('rss_mb') or [float('nan')]):5.1f} MB  "
              f"PSS {np.mean(r.get('pss_mb') or [float('nan')]):5.1f} MB  "
              f"load {r['load']:.2f}", flush=True)


def _fmt(r: dict) -> str:
    def f(v, spec=".2f"):
        return "-" if v is None else format(v, spec)

    rss = r.get("rss_mb") or [float("nan")]
    # hosted: the processes the robots share (a process per robot: nothing), and the
    # supervisor's subscriptions
    hosted = ((f" in {r['processes']} proc" if r.get("per_process", 1) > 1 else "")
              + (" sup" if r.get("subscribe") == "supervisor" else ""))
    what = (f"floor {'/'.join(r['floor'])}" if r["floor"] else f"{r['robots']} monitors"
            + hosted + (f" [{r['label']}]" if r.get("label") else ""))
    per_thread = ", ".join(f"{n} {v}" for n, v in list(r.get("threads", {}).items())[:5])
    return (f"{what:28} {r.get('samples', 0):6d} {f(r.get('missing'), 'd'):>7} "
            f"{f(r.get('p50_ms')):>7} {f(r.get('p99_ms')):>7} {f(r.get('max_ms')):>7} "
            f"{f(r.get('cpu_us_per_sample'), '.0f'):>9} {f(r.get('core_pct'), '.1f'):>6} "
            f"{np.mean(rss):6.1f} {max(rss):6.1f} "
            f"{r.get('rss_per_robot', np.mean(rss)):6.1f}  load {r.get('load', load()):.2f}"
            + (f"\n{'':28} us/sample by thread (first process): {per_thread}"
               if per_thread else ""))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robots", type=int, nargs="*", default=[1, 8, 16, 32],
                    help="N of each fleet run (none: only --path/--floor)")
    ap.add_argument("--rate", type=float, default=100.0)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--floor", action="store_true", help="also measure a bare rclpy node")
    ap.add_argument("--tree", action="append", default=[], metavar="LABEL=DIR",
                    help="also run the monitors from source tree DIR (side by side)")
    ap.add_argument("--repeat", type=int, default=1,
                    help="runs per N and tree (alternating); the best is printed last")
    ap.add_argument("--profile", metavar="FILE",
                    help="cProfile the first monitor's measured window into FILE")
    ap.add_argument("--dds", action="append", default=[], metavar="LABEL=SPEC",
                    help="also run under another DDS configuration, side by side with the "
                         "nodes' (SPEC: a profile XML and/or VAR=VALUE, comma-separated; "
                         "repeatable; see dds_variants); only --floor's DDS_FLOORS and the "
                         "monitors are run")
    ap.add_argument("--per-process", type=int, nargs="+", default=[1], metavar="M",
                    help="robots per monitor process, one layout per value, run side by side "
                         "(1: a process per robot; M > 1: `monitor -p robots:=[...]`, M "
                         "robots on one executor and one DDS participant)")
    ap.add_argument("--subscribe", nargs="+", choices=SUBSCRIBE, default=["alarm"],
                    help="what the receiver subscribes to (alarm: every robot's fd/alarm; "
                         "supervisor: every robot's fd/fault and /diagnostics, the first "
                         "robot's fd/alarm for the latency); one row per value")
    ap.add_argument("--path", type=int, metavar="SAMPLES", default=0,
                    help="also time the monitor node's Python path without DDS, SAMPLES per "
                         "pass (warm and paced at --rate; per tree)")
    args = ap.parse_args()
    trees: list[tuple[str, str | None]] = [
        (t.split("=", 1)[0], str(Path(t.split("=", 1)[1]).resolve())) for t in args.tree]
    if trees:
        trees.append(("this", None))
    e = env()
    import rclpy

    rclpy.init()
    print(f"load average {load():.2f} (1 min, {os.cpu_count()} cores); {args.rate:g} Hz, "
          f"{args.seconds:g} s per N; per robot: cpu us per sample, % of a core, RSS MB")
    print(f"{'what':28} {'samples':>6} {'missing':>7} {'p50 ms':>7} {'p99 ms':>7} "
          f"{'max ms':>7} {'cpu us/s.':>9} {'%core':>6} {'RSS':>6} {'max':>6} {'/robot':>6}")
    try:
        if args.dds:
            dds_side_by_side(args, e)
            args.robots, args.floor, args.path = [], False, 0
        if args.path:
            for label, tree in trees or [("", None)]:
                r = node_path(args.path, args.rate, e, tree)
                print(f"node path{f' [{label}]' if label else '':22} warm {r['warm']:.0f} us, "
                      f"paced at {args.rate:g} Hz {r['paced']:.0f} us per sample (main "
                      f"thread, best of 3, no DDS delivery)  load {r['load']:.2f}", flush=True)
        if args.floor:
            for variant in FLOORS:
                print(_fmt(run_fleet(1, args.rate, args.seconds, e, floor=variant)),
                      flush=True)
        for n in args.robots:
            best: dict[tuple, dict] = {}
            for _ in range(args.repeat):
                for m in args.per_process:
                    for sub in args.subscribe:
                        for label, tree in trees or [("", None)]:
                            r = run_fleet(n, args.rate, args.seconds, e, tree=tree,
                                          profile=args.profile, per_process=m,
                                          subscribe=sub)
                            r["label"] = label
                            print(_fmt(r), flush=True)
                            key = (m, sub, label)
                            if (key not in best or r["cpu_us_per_sample"]
                                    < best[key]["cpu_us_per_sample"]):
                                best[key] = r
            if args.repeat > 1 or trees:
                print(f"best of {args.repeat} (least CPU per sample):")
                for r in best.values():
                    print(_fmt(r), flush=True)
    finally:
        rclpy.try_shutdown()
    print(f"load average {load():.2f} after")
    return 0


if __name__ == "__main__":
    sys.exit(main())
