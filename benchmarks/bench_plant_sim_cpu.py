"""CPU used by a real-time ``plant_sim`` (user + system time of the process over a window).

Run: .venv/bin/python benchmarks/bench_plant_sim_cpu.py [--rate-factor 1.0] [--seconds 10]

Starts ``plant_sim`` on ``three_tank_bias_h1`` (Ts = 0.1 s, so 10 Hz at ``rate_factor``
1.0) on an isolated ROS domain, waits until it logs its start, lets it run 2 s, then reads
``utime + stime`` from ``/proc/<pid>/stat`` at the start and end of a ``--seconds`` window and
prints the share of one core it used.
"""

from __future__ import annotations

import argparse
import os
import random
import signal
import subprocess
import sys
import tempfile
import time


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of a process, s (fields 14 and 15 of /proc/<pid>/stat)."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rate-factor", type=float, default=1.0)
    ap.add_argument("--seconds", type=float, default=10.0)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as logs:
        env = dict(os.environ, ROS_DOMAIN_ID=os.environ.get("ROS_DOMAIN_ID",
                                                            str(random.randint(60, 101))),
                   ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_LOG_DIR=logs)
        proc = subprocess.Popen(
            [sys.executable, "-m", "fd_monitor", "run", "plant_sim", "--ros-args",
             "-p", f"rate_factor:={args.rate_factor!r}", "-p", "publish_truth:=true"],
            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        try:
            assert proc.stderr is not None
            for line in proc.stderr:  # the start line comes once the node is built
                if "samples of" in line:
                    break
            time.sleep(2.0)  # past start-up (imports, DDS discovery)
            c0, t0 = cpu_seconds(proc.pid), time.monotonic()
            time.sleep(args.seconds)
            c1, t1 = cpu_seconds(proc.pid), time.monotonic()
        finally:
            proc.send_signal(signal.SIGINT)
            proc.wait(timeout=30)
    share = (c1 - c0) / (t1 - t0)
    print(f"plant_sim rate_factor {args.rate_factor:g} (three_tank, Ts 0.1 s): "
          f"{c1 - c0:.2f} s CPU in {t1 - t0:.1f} s = {100 * share:.1f} % of one core")


if __name__ == "__main__":
    main()
