"""Live throughput and latency on this machine: raw rclpy, the fused ``monitor``, the chain.

All over DDS on loopback (isolated ROS_DOMAIN_ID), in one run, side by side:

* **raw rclpy**: a driver process publishes stamped Float64MultiArray messages (3 values, like
  /plant/y, reliable QoS of fd_monitor) to a subscriber in this process: the ceiling.
* **monitor (fused)**: ``python -m fd_monitor run monitor`` (one node, one join, one
  ``Monitor.step`` per sample); the driver publishes /plant/u and /plant/y (the demo scenario,
  consecutive stamps across rates), this process subscribes to /fd/alarm.
* **chain (4 processes)**: observer, detector, agei, bias_estimator as
  four processes, same driver and receiver.
* optionally (``--layouts ... monitor_chain``) the four nodes in one process
  (``monitor --ros-args -p layout:=nodes``).

For each rate the driver (its own process, paced by sleeping until each sample is due: no
core spent busy-waiting, no GIL shared with the receiver) sends ``rate x seconds`` samples and
reports its send times (CLOCK_MONOTONIC, the same clock here). Latency is y_k published ->
alarm_k received (raw: message k). A run at a rate **counts** only when, over the whole run,

* nothing is lost (every sample's output arrived), and
* every sample's latency stays under the stated bounds: p99 <= ``--p99-ms`` (default 5 ms)
  and max <= ``--max-ms`` (default 20 ms). A backlog, however early it forms and however
  well it drains, pushes its samples' latency over these bounds: it cannot count.

Each rate is run ``--repeat`` times (default 3); the figures printed are the medians of the
repeats and the rate counts when the median run counts (at least 2 of 3). A layout stops at
its first rate that does not count (``--keep-going``: it measures every rate). ``cpu us``
is the CPU time (user + system) all node processes spent per sample during the rate (from
/proc): what a sample costs, whatever the load. The floor is the ``raw`` layout (rclpy
alone, same driver, same receiver). The 1-minute load average is printed with each figure
(the machine may be shared).

``--driver-qos default`` makes the driver publish with ROS's default QoS (reliable,
volatile, keep last 10: what a robot's driver usually does) instead of fd_monitor's data
QoS.

Run: ``.venv/bin/python benchmarks/bench_pipeline.py [--rates 250 500 1000 2000 3000 4000]
[--seconds 2.5] [--repeat 3] [--p99-ms 5] [--max-ms 20] [--driver-qos fd|default]
[--layouts raw fused chain] [--json]``.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import select
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

#: Driver process: ``python -c DRIVER raw|plant <total samples>``. Reads ``go <rate> <n>``
#: lines on stdin, sends n samples at rate, answers one JSON line of send times; ``stop``
#: ends it.
DRIVER = r"""
import json, sys, time
import rclpy
from std_msgs.msg import Float64MultiArray
from fd_monitor.nodes.pacing import use_dds_profile
from fd_monitor.nodes.qos import data_pub_qos
from fd_monitor.wire.conversions import to_msg
from fd_monitor.wire.topics import PLANT_U, PLANT_Y
use_dds_profile(); rclpy.init()
mode, total = sys.argv[1], int(sys.argv[2])
if sys.argv[4] == "default":
    from rclpy.qos import QoSProfile
    data_pub_qos = lambda: QoSProfile(depth=10)   # ROS default: reliable, volatile, depth 10
node = rclpy.create_node("bench_driver")
if mode == "raw":
    pubs = [node.create_publisher(Float64MultiArray, "/bench/raw", data_pub_qos())]
    u = y = [[0.0, 0.0, 0.0]] * total
    lab_u = lab_y = ("a", "b", "c")
else:
    from fd_monitor.core.simulator import simulate
    from fd_monitor.model.scenario import load_scenario
    sc = load_scenario("three_tank_bias_h1")
    tr = simulate(sc, None, total)
    u, y = tr.u[0].tolist(), tr.y[0].tolist()
    lab_u, lab_y = sc.system.inputs, sc.system.outputs
    pubs = [node.create_publisher(Float64MultiArray, t, data_pub_qos())
            for t in (PLANT_U.absolute, PLANT_Y.absolute)]
need = int(sys.argv[3])
while any(p.get_subscription_count() < need for p in pubs):
    time.sleep(0.02)   # discovery (the graph is updated by rmw threads)
print("ready", flush=True)
k = 0
for line in sys.stdin:
    cmd = line.split()
    if cmd[0] != "go":
        break
    rate, n = float(cmd[1]), int(cmd[2])
    sent = []
    t0 = time.perf_counter()
    for i in range(n):
        due = t0 + i / rate
        now = time.perf_counter()
        if now < due:
            time.sleep(due - now)
        if len(pubs) == 2:
            pubs[0].publish(to_msg(lab_u, k, u[k]))
        sent.append(time.perf_counter())
        pubs[-1].publish(to_msg(lab_y, k, y[k]))
        k += 1
    print(json.dumps({"first": k - n, "sent": sent}), flush=True)
"""

LAYOUTS = {
    "raw": ("raw rclpy (2 processes)", []),
    "fused": ("monitor, fused (1 node)", [["monitor"]]),
    "chain": ("chain (4 processes)", [["observer"], ["detector"], ["agei"], ["bias_estimator"]]),
    "monitor_chain": ("monitor, layout:=nodes (1 process)",
                      [["monitor", "--ros-args", "-p", "layout:=nodes"]]),
}


def env() -> dict[str, str]:
    from fd_monitor.nodes.pacing import use_dds_profile

    use_dds_profile()
    e = dict(os.environ)
    e.setdefault("ROS_DOMAIN_ID", str(random.SystemRandom().randint(1, 100)))
    e["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    e.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
    e.setdefault("ROS_LOG_DIR", "/tmp/fd_monitor_bench_logs")
    e["PYTHONPATH"] = str(REPO) + os.pathsep + e.get("PYTHONPATH", "")
    os.environ.update({k: e[k] for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE",
                                         "RMW_IMPLEMENTATION", "ROS_LOG_DIR")})
    return e


def load() -> float:
    return os.getloadavg()[0]


def cpu_seconds(procs: list[subprocess.Popen]) -> float:
    """User + system CPU time (s) the node processes have used so far (/proc)."""
    tick = os.sysconf("SC_CLK_TCK")
    total = 0.0
    for p in procs:
        try:
            fields = Path(f"/proc/{p.pid}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        total += (int(fields[11]) + int(fields[12])) / tick   # utime, stime
    return total


class Receiver:
    """A subscriber in this process recording the arrival time of each stamp."""

    def __init__(self, topic: str) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from std_msgs.msg import Float64MultiArray

        from fd_monitor.nodes.qos import data_sub_qos

        self.node = rclpy.create_node(f"bench_rx_{topic.strip('/').replace('/', '_')}")
        self.arrivals: dict[int, float] = {}
        self.node.create_subscription(Float64MultiArray, topic, self._cb, data_sub_qos())
        self.ex = SingleThreadedExecutor()
        self.ex.add_node(self.node)

    def _cb(self, msg) -> None:
        self.arrivals[int(msg.data[0])] = time.perf_counter()

    def spin_until(self, cond, timeout: float) -> bool:
        deadline = time.perf_counter() + timeout
        while not cond():
            if time.perf_counter() > deadline:
                return False
            self.ex.spin_once(timeout_sec=0.01)
        return True

    def close(self) -> None:
        self.ex.shutdown()
        self.node.destroy_node()


def _line(proc: subprocess.Popen, rx: Receiver, timeout: float) -> str | None:
    """The driver's next stdout line, spinning the receiver meanwhile."""
    assert proc.stdout is not None
    out: list[str] = []

    def ready() -> bool:
        if select.select([proc.stdout], [], [], 0)[0]:
            out.append(proc.stdout.readline())
            return True
        return proc.poll() is not None

    rx.spin_until(ready, timeout)
    return out[0] if out else None


def stats(what: str, rate: float, sent: list[float], first: int, rx: Receiver,
          p99_ms: float, max_ms: float) -> dict:
    """Figures of one run at one rate, and whether it counts (module docstring)."""
    ks = range(first, first + len(sent))
    got = [k for k in ks if k in rx.arrivals]
    lat = np.array([rx.arrivals[k] - sent[k - first] for k in got]) * 1e3
    row: dict = {"what": what, "rate_hz": rate, "samples": len(sent),
                 "missing": len(sent) - len(got), "load": round(load(), 2)}
    if lat.size:
        row.update(p50_ms=float(np.median(lat)), p99_ms=float(np.percentile(lat, 99)),
                   max_ms=float(lat.max()))
    else:
        row.update(p50_ms=None, p99_ms=None, max_ms=None)
    row["counts"] = bool(row["missing"] == 0 and lat.size
                         and row["p99_ms"] <= p99_ms and row["max_ms"] <= max_ms)
    return row


def median_row(runs: list[dict]) -> dict:
    """The median of each figure over the repeats of one rate; counts when the median run
    does (more than half of the runs)."""
    out = dict(runs[-1])
    for key in ("missing", "p50_ms", "p99_ms", "max_ms", "node_cpu_us", "load"):
        vals = [r[key] for r in runs if r.get(key) is not None]
        out[key] = float(np.median(vals)) if vals else None
    out["repeats"] = len(runs)
    out["counted_runs"] = sum(bool(r["counts"]) for r in runs)
    out["counts"] = out["counted_runs"] * 2 > len(runs)
    return out


def bench(layout: str, rates: list[float], seconds: float, e: dict[str, str],
          repeat: int = 3, p99_ms: float = 5.0, max_ms: float = 20.0,
          driver_qos: str = "fd", keep_going: bool = False) -> list[dict]:
    """Every rate of one layout, ``repeat`` runs each, until a rate does not count."""
    what, nodes = LAYOUTS[layout]
    raw = layout == "raw"
    total = repeat * sum(int(r * seconds) for r in rates) + 100
    procs = [subprocess.Popen([sys.executable, "-m", "fd_monitor", "run", *n], env=e,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
             for n in nodes]
    from fd_monitor.wire.topics import ALARM

    rx = Receiver("/bench/raw" if raw else ALARM.absolute)
    # subscribers of /plant/u and /plant/y: fused 1, chain observer + bias_estimator
    need = 1 if layout in ("raw", "fused") else 2
    drv = subprocess.Popen([sys.executable, "-c", DRIVER, "raw" if raw else "plant",
                            str(total), str(need), driver_qos], env=e, stdin=subprocess.PIPE,
                           stdout=subprocess.PIPE, text=True)
    assert drv.stdin is not None
    out: list[dict] = []
    try:
        if _line(drv, rx, 60.0) is None:
            raise RuntimeError(f"{what}: the driver found no subscriber in 60 s")
        if not raw:
            rx.spin_until(lambda: rx.node.count_publishers(ALARM.absolute) >= 1, 60.0)
        # warm-up: every link matched (outputs before that are lost: volatile) and samples
        # through, before anything is measured
        deadline = time.monotonic() + 60.0
        while True:
            drv.stdin.write("go 50 10\n")
            drv.stdin.flush()
            line = _line(drv, rx, 30.0)
            last = json.loads(line)["first"] + 9 if line else -1
            if rx.spin_until(lambda last=last: last in rx.arrivals, 1.0):
                break
            if time.monotonic() > deadline:
                raise RuntimeError(f"{what}: warm-up samples did not come through in 60 s")
        for rate in rates:
            n = int(rate * seconds)
            runs: list[dict] = []
            for _ in range(repeat):
                cpu0 = cpu_seconds(procs)
                drv.stdin.write(f"go {rate} {n}\n")
                drv.stdin.flush()
                line = _line(drv, rx, seconds * 3 + 30.0)
                if line is None:
                    break
                burst = json.loads(line)
                ks = range(burst["first"], burst["first"] + n)
                # the rate's outputs, or 2 s after its last sample (it did not keep up)
                rx.spin_until(lambda ks=ks: all(k in rx.arrivals for k in ks),
                              max(0.0, burst["sent"][-1] + 2.0 - time.perf_counter()))
                runs.append(stats(what, rate, burst["sent"], burst["first"], rx, p99_ms,
                                  max_ms))
                # CPU the node processes spent per sample (all of them together), us
                runs[-1]["node_cpu_us"] = ((cpu_seconds(procs) - cpu0) / n * 1e6
                                           if procs else None)
                # let a backlog of this run drain before the next one starts
                rx.spin_until(lambda: False, 0.5)
            if not runs:
                break
            out.append(median_row(runs))
            print(_fmt(out[-1]), flush=True)
            if not out[-1]["counts"] and not keep_going:
                break
    finally:
        try:
            drv.stdin.write("stop\n")
            drv.stdin.flush()
        except OSError:
            pass
        for p in [drv, *procs]:
            p.terminate()
        for p in [drv, *procs]:
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                p.kill()
        rx.close()
    return out


def _fmt(r: dict) -> str:
    def f(v, spec=".2f"):
        return "-" if v is None else format(v, spec)

    return (f"{r['what']:34} {r['rate_hz']:7g} {r['samples']:7d} {f(r['missing'], '.0f'):>5} "
            f"{f(r['p50_ms']):>7} {f(r['p99_ms']):>7} {f(r['max_ms']):>8} "
            f"{f(r.get('node_cpu_us'), '.0f'):>7}  {r['counts']!s:5} "
            f"({r['counted_runs']}/{r['repeats']})  load {r['load']:.2f}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rates", type=float, nargs="+",
                    default=[250, 500, 1000, 2000, 3000, 4000])
    ap.add_argument("--seconds", type=float, default=2.5, help="s per rate")
    ap.add_argument("--layouts", nargs="+", default=["raw", "fused", "chain"],
                    choices=sorted(LAYOUTS))
    ap.add_argument("--repeat", type=int, default=3, help="runs per rate (median reported)")
    ap.add_argument("--p99-ms", type=float, default=5.0, help="bound on the p99 latency, ms")
    ap.add_argument("--max-ms", type=float, default=20.0, help="bound on every latency, ms")
    ap.add_argument("--driver-qos", choices=("fd", "default"), default="fd",
                    help="the driver's publishers: fd_monitor's data QoS, or ROS's default "
                         "(reliable, volatile, depth 10)")
    ap.add_argument("--keep-going", action="store_true",
                    help="measure every rate even after one that does not count")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    e = env()
    import rclpy

    rclpy.init()
    rows: list[dict] = []
    if not args.json:
        print(f"load average {load():.2f} (1 min, {os.cpu_count()} cores); driver QoS "
              f"{args.driver_qos}; a rate counts: nothing lost, p99 <= {args.p99_ms:g} ms and "
              f"max <= {args.max_ms:g} ms over the run, in the median of {args.repeat} runs; "
              f"floor: raw rclpy")
        print(f"{'what':34} {'rate Hz':>7} {'samples':>7} {'miss':>5} {'p50 ms':>7} "
              f"{'p99 ms':>7} {'max ms':>8} {'cpu us':>7}  counts")
    try:
        for layout in args.layouts:
            rows += bench(layout, args.rates, args.seconds, e, args.repeat, args.p99_ms,
                          args.max_ms, args.driver_qos, args.keep_going)
    finally:
        rclpy.try_shutdown()
    best = {w: max([r["rate_hz"] for r in rows if r["what"] == w and r["counts"]],
                   default=0.0) for w in dict.fromkeys(r["what"] for r in rows)}
    if args.json:
        json.dump({"rows": rows, "highest_counting_hz": best}, sys.stdout, indent=2)
        print()
        return 0
    for w, v in best.items():
        print(f"highest rate that counts (lossless, p99 <= {args.p99_ms:g} ms, max <= "
              f"{args.max_ms:g} ms; median of {args.repeat}), {w}: {v:g} Hz")
    print(f"load average {load():.2f} after")
    return 0


if __name__ == "__main__":
    sys.exit(main())
