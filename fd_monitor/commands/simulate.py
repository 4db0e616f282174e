"""``python -m fd_monitor simulate SCENARIO -o BAGDIR``: simulate a scenario into an MCAP bag.

Runs the core simulator (no ROS) and writes ``/plant/u``, ``/plant/y`` and ``/plant/truth``
exactly as the ``plant_sim`` node publishes them (same labels, stamps and values for the
same scenario and seed), with bag timestamps t_k = k Ts. The truth carries the true mode,
state, fault signals and the scheduling parameters (``rho.<name>``) of an LPV scenario.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from pathlib import Path

from fd_monitor.commands._common import add_json_flag, count, emit, number, print_json, print_table
from fd_monitor.model.errors import ScenarioError

__all__ = ["add_arguments", "run", "simulate_to_bag"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """SCENARIO, -o, --seed, --duration, --json."""
    parser.add_argument("scenario", metavar="SCENARIO", nargs="?",
                        help="scenario file, or the name of a shipped scenario "
                             "(config/scenarios/)")
    parser.add_argument("-o", "--output", metavar="BAGDIR", default=None,
                        help="bag folder to create (must not exist)")
    parser.add_argument("--library", metavar="LIBRARY", default=None,
                        help="instead of SCENARIO: regenerate every bag of a bag library "
                             "(bags/library.yaml) in place, expected.yaml kept (unless "
                             "--expected)")
    parser.add_argument("--only", nargs="+", default=None, metavar="NAME",
                        help="with --library: only these bags")
    parser.add_argument("--expected", action="store_true",
                        help="with --library: also (re)write each bag's expected.yaml from "
                             "`analyze` of the new bag and its truth")
    parser.add_argument("--seed", type=count(0), default=None,
                        help="random seed (default: the scenario's)")
    parser.add_argument("--duration", type=number(0, low_open=True), default=None,
                        help="s of plant time (default: the scenario's)")
    parser.add_argument("--adapter", metavar="MAP", default=None,
                        help="write u and y as the robot's messages on the topics of this "
                             "adapter file (config/adapters/) instead of /plant/u, /plant/y")
    add_json_flag(parser)


def simulate_to_bag(scenario_source: str, output: str | Path, seed: int | None = None,
                    duration: float | None = None, adapter: str | None = None) -> dict:
    """Simulate and write the bag; return a summary mapping.

    With ``adapter`` (an adapter file, :mod:`fd_monitor.wire.adapters`) u and y are written
    as the robot's messages on its topics (header stamps t_k) instead of ``/plant/u`` and
    ``/plant/y``; the truth and side signals stay.
    """
    from fd_monitor.analysis.generate import check_bag_size, simulate_bag
    from fd_monitor.model.scenario import check_horizon, load_scenario

    sc = load_scenario(scenario_source)
    if seed is not None and seed < 0:
        raise ScenarioError(f"--seed {seed}: expected an integer >= 0")
    if duration is not None and not math.isfinite(duration):
        raise ScenarioError(f"--duration {duration}: expected a finite number of s")
    if duration is not None:
        check_horizon(sc.system, duration, "--duration", ScenarioError)
    check_bag_size(sc.system, sc.duration if duration is None else duration,
                   "--duration" if duration is not None else f"{sc.source}: duration",
                   ScenarioError)
    if duration is not None and duration < sc.system.sample_time:
        raise ScenarioError(f"--duration {duration}: expected at least one sample "
                            f"({sc.system.sample_time} s)")
    dt = sc.system.sample_time
    K = sc.n_samples if duration is None else max(1, round(duration / dt))
    sys_ = sc.system
    if adapter is None:
        path, topics = simulate_bag(output, sc, seed, K)
    else:
        from fd_monitor.wire.adapters import load_adapter

        path, topics = simulate_bag(output, sc, seed, K,
                                    load_adapter(adapter).for_system(sys_))
    return {"bag": str(path), "scenario": sc.name, "system": sys_.name,
            "seed": sc.seed if seed is None else seed, "samples": K, "sample_time": dt,
            "duration": K * dt, "topics": list(topics),
            "faults": [{"channel": sys_.faults[f.channel].name, "time": f.time,
                        "magnitude": f.magnitude, "profile": f.profile}
                       for f in sc.faults]}


def run(args: argparse.Namespace) -> int:
    """Simulate and print a summary."""
    if args.library is not None:
        return _simulate_library(args.library, args.only, args.json, args.expected)
    if args.expected:
        raise ScenarioError("--expected: only with --library")
    if args.scenario is None or args.output is None:
        raise ScenarioError("give SCENARIO and -o BAGDIR (or --library LIBRARY)")
    summary = simulate_to_bag(args.scenario, args.output, args.seed, args.duration,
                              args.adapter)
    if args.json:
        emit(summary, True)
    else:
        flat = dict(summary)
        flat["topics"] = ", ".join(summary["topics"])
        flat["faults"] = "; ".join(f"{f['channel']} {f['profile']} {f['magnitude']:g} at "
                                   f"{f['time']:g} s" for f in summary["faults"]) or "none"
        emit(flat, False, title=f"simulated {summary['scenario']} -> {summary['bag']}")
    return 0


def _simulate_library(library: str | Path, only: Sequence[str] | None, as_json: bool,
                      expected: bool = False) -> int:
    """``python -m fd_monitor simulate --library LIBRARY [--only NAME...] [--expected]``:
    rebuild bags (and their ``expected.yaml``)."""
    from fd_monitor.analysis.expectations import library_expected
    from fd_monitor.analysis.generate import generate_library
    from fd_monitor.analysis.library import load_library

    lib = load_library(library)
    rows = generate_library(lib, only)
    if expected:
        for r in rows:
            library_expected(lib[r["name"]])
    if as_json:
        print_json({"library": str(lib.path), "bags": rows})
    else:
        print_table([(r["name"], r["samples"], f"{r['bytes'] / 1e3:.0f} kB", r["folder"])
                     for r in rows], header=("bag", "samples", "size", "folder"),
                    title=f"regenerated {len(rows)} bag(s) of {lib.path}")
    return 0
