"""Long fuzz run of every input reader: examples per target, outcomes, crashes.

Run: .venv/bin/python benchmarks/fuzz_inputs.py [--examples 2000] [--only plant decode ...]

The targets and strategies are the suite's (``test/test_fuzz.py``: plant, scenario, gain,
library, ``expected.yaml``, adapter, ROS parameter and design files, a bag's ``metadata.yaml``,
message decoding, the offline reader (``analyze``/``report``) and identify's reader on
generated streams, the offline reader and ``bag check`` on corrupted bag bytes, and every
numeric option of the command line); here each runs ``--examples`` random (not derandomised)
examples and every exception that is not an ``FdMonitorError`` is counted as a crash and
printed once per type and place, instead of stopping the run. Prints one row per target and the
total; exits 1 when there was a crash.
"""

from __future__ import annotations

import argparse
import sys
import time
import traceback
import warnings
from pathlib import Path
from typing import Any

from hypothesis import HealthCheck, given, settings

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "test"))

from test_fuzz import TARGETS, outcome

from fd_monitor.model.errors import FdMonitorWarning


def fuzz(name: str, examples: int) -> tuple[dict[str, int], dict[str, str], float]:
    """Run one target; (outcome counts, crash kind -> first example, seconds)."""
    strategy, target = TARGETS[name]
    counts = {"ok": 0, "error": 0, "crash": 0}
    seen: dict[str, str] = {}

    @settings(max_examples=examples, deadline=None, database=None,
              suppress_health_check=list(HealthCheck))
    @given(strategy)
    def run(value: Any) -> None:
        try:
            counts[outcome(target, value)] += 1
        except Exception as exc:
            counts["crash"] += 1
            tb = traceback.extract_tb(exc.__traceback__)[-1]
            key = f"{type(exc).__name__} at {Path(tb.filename).name}:{tb.lineno}"
            seen.setdefault(key, f"{exc!s:.200} <- {value!r:.300}")

    t0 = time.perf_counter()
    run()
    return counts, seen, time.perf_counter() - t0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--examples", type=int, default=2000, help="examples per target (2000)")
    ap.add_argument("--only", nargs="+", default=None, choices=list(TARGETS))
    args = ap.parse_args()
    # damage and integrity warnings are the expected answer to fuzzed bags, not news
    warnings.simplefilter("ignore", FdMonitorWarning)
    print(f"{'target':<20} {'examples':>8} {'ok':>7} {'refused':>8} {'crashes':>8} {'s':>7}")
    total = crashes_total = 0
    for name in args.only or list(TARGETS):
        counts, seen, secs = fuzz(name, args.examples)
        n = sum(counts.values())
        total += n
        crashes_total += counts["crash"]
        print(f"{name:<20} {n:>8} {counts['ok']:>7} {counts['error']:>8} "
              f"{counts['crash']:>8} {secs:>7.1f}", flush=True)
        for key, example in seen.items():
            print(f"    crash {key}: {example}")
    print(f"{'total':<20} {total:>8} {'':>7} {'':>8} {crashes_total:>8}")
    return 1 if crashes_total else 0


if __name__ == "__main__":
    sys.exit(main())
