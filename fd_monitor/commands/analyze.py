"""``python -m fd_monitor analyze BAG --gains GAINS [--json]``: the diagnosis chain offline.

Reads ``/plant/u`` and ``/plant/y`` (and ``/plant/truth`` when present) from a rosbag2 bag,
runs the gain file's runtime over every sample (no ROS) -- any method: the runtime comes from
the registry :func:`fd_monitor.core.methods.runtime_for` (``thresholds``, ``qb``, ``hinf_sc``,
``hminus_switched``), its side signals from ``/plant/rho`` or ``/plant/mode`` when it needs
them -- and prints

* alarms: one entry per alarm episode and channel (``channel``, ``first_sample``, ``time``,
  ``last_sample``, ``samples``);
* the first detection (sample, time), the estimated mode transitions and, when the bag has
  truth, the true ones;
* isolated sensors and the final bias estimate sigma^.

An alarm episode during which the runtime was outside the region its certificate covers (the
estimated state or an input outside ``results.envelope``; an LPV bank's rho outside its design
box; a switching signal naming a mode the design does not have) is marked
``outside_certified_region: true`` with ``outside_detail`` (which variable, by how much); the
alarm is raised all the same, it is just not covered by the design's guarantee.

The JSON (``--json``) has at least ``alarms`` (list of ``{channel, first_sample, time}``),
``isolated`` (channel names) and ``bias_estimate`` (``{channel: value}``).

The plant is the one the gain file was designed for: a shipped plant by its name, or the
plant file the gain file records (``system.file``, written by the designers for a plant that
is not shipped, e.g. an identified one); ``--system`` gives a plant file explicitly. The bag's
channel names must match it.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np

from fd_monitor.analysis.integrity import add_strict_flag, describe, enforce_strict
from fd_monitor.analysis.offline import BagRun, BagScan, InputReport, run_bag, run_runtime
from fd_monitor.analysis.summary import analyze_run
from fd_monitor.commands._common import add_json_flag, print_json, print_table
from fd_monitor.commands.fleet import add_fleet_arguments, is_fleet, run_fleet
from fd_monitor.core.methods import runtime_for
from fd_monitor.model.errors import BagError
from fd_monitor.model.system import System
from fd_monitor.wire.topics import PLANT_TRUTH, PLANT_U, PLANT_Y

__all__ = ["add_arguments", "run", "analyze_arrays", "analyze_bag"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """BAG ..., --gains, --system, --no-agei, --json, --strict, the many-bag options."""
    parser.add_argument("bag", metavar="BAG", nargs="+",
                        help="rosbag2 folder with /plant/u and /plant/y; several BAGs, a "
                             "folder of bags or a glob pattern: the many-bag run "
                             "(doc/howto/fleet.md)")
    parser.add_argument("--gains", required=True, metavar="GAINS",
                        help="gain file of any method (path or name in config/gains/)")
    parser.add_argument("--system", default=None, metavar="SYSTEM",
                        help="plant file (default: the plant the gain file records: its "
                             "plant file, or a shipped plant by name)")
    parser.add_argument("--adapter", default=None, metavar="MAP",
                        help="read u and y from a robot's own topics (JointState, Odometry, "
                             "Twist, Float64, ...) through this adapter file "
                             "(config/adapters/) instead of /plant/u and /plant/y")
    parser.add_argument("--no-agei", action="store_true",
                        help="ablation: run without the AGEI module")
    add_json_flag(parser)
    add_strict_flag(parser)
    add_fleet_arguments(parser)


def analyze_arrays(system: System, gains: Any, k: np.ndarray, u: np.ndarray, y: np.ndarray,
                   true_mode: np.ndarray | None = None, agei: bool = True,
                   side: dict[str, np.ndarray] | None = None) -> dict[str, Any]:
    """Run the gain file's runtime (:func:`~fd_monitor.core.methods.runtime_for`) over arrays
    and summarise.

    Parameters
    ----------
    system : System
    gains : GainFile or DiagnosisGains
    k : numpy.ndarray
        (K,) sample indices (a hole is bridged or restarts the monitor, as in a bag).
    u : numpy.ndarray
        (K, nu) inputs.
    y : numpy.ndarray
        (K, ny) measurements.
    true_mode : numpy.ndarray, optional
        (K,) true mode indices.
    agei : bool
        ``thresholds`` only (False: the ablation without AGEI).
    side : dict, optional
        The runtime's side signals, name -> (K, ...) array (``rho``, ``mode``).

    Returns
    -------
    dict
        As :func:`fd_monitor.analysis.summary.analyze_run`.

    Raises
    ------
    MessageError
        An invalid sample (its index is named); nothing after it is processed.
    """
    from fd_monitor.wire.bag_reader import TopicArrays

    ks = [int(v) for v in np.asarray(k).reshape(-1)]
    us = dict(zip(ks, np.asarray(u, dtype=float).reshape(len(ks), -1)))
    ys = dict(zip(ks, np.asarray(y, dtype=float).reshape(len(ks), -1)))
    rep = InputReport()
    rt = runtime_for(system, gains, **({} if agei else {"agei": False}))
    sides = {n: dict(zip(ks, np.asarray(v))) for n, v in (side or {}).items()}
    fields = run_runtime(rt, ks, us, ys, rep, sides)
    truth = None
    if true_mode is not None:
        truth = TopicArrays(PLANT_TRUTH.absolute, ("mode",), np.asarray(ks),
                            np.asarray(true_mode, float).reshape(-1, 1), np.zeros(len(ks)))
    run = BagRun(bag="<arrays>", gains=str(getattr(gains, "path", "<gains>")), system=system,
                 truth=truth, inputs=rep, **fields)
    return analyze_run(run)


def analyze_bag(bag: str, gains_source: str, system_source: str | None = None,
                agei: bool = True, adapter: str | None = None,
                loaded: tuple[Any, System] | None = None) -> dict[str, Any]:
    """Run the gain file's monitor over a bag (:func:`fd_monitor.analysis.offline.run_bag`) and
    summarise (:func:`fd_monitor.analysis.summary.analyze_run`).

    Bad input messages (NaN/Inf, wrong length, duplicates, out-of-order stamps, holes) are
    reported in ``input_errors`` and ``restarts``, never fatal. ``loaded``: the gain file
    and plant already loaded and verified from these sources (a fleet worker's cache,
    :func:`fd_monitor.commands.fleet.load_gains_cached`), not read again.

    Raises
    ------
    BagError
        Missing bag or topic, channels that do not match the plant.
    GainFileError
        Gain file missing, for another plant, or its certificate fails.
    """
    from fd_monitor.core.methods import load_gains
    from fd_monitor.model.system import gain_system

    if loaded is None:
        raw = load_gains(gains_source, verify=False)
        system = gain_system(raw, system_source)
        loaded = load_gains(gains_source, system), system   # plant SHA-256, certificate
    gains, system = loaded
    if not Path(bag).exists():
        raise BagError(f"{bag}: no such bag")
    if adapter is not None:                     # the robot's topics (wire/adapters.py)
        run = run_bag(bag, gains, system=system, agei=agei, adapter=adapter, keep="summary")
        return {"bag": str(bag), "gains": str(gains.path), "plant": system.name,
                "method": gains.method, "agei": agei, "adapter": str(adapter),
                **analyze_run(run), "integrity": run.integrity}

    def checks(scan: BagScan) -> None:
        present = scan.present
        needed = [PLANT_Y.absolute] + ([PLANT_U.absolute] if system.nu else [])
        for t in needed:
            if t not in present:
                raise BagError(f"{bag}: topic {t} missing (topics: "
                               f"{', '.join(sorted(present)) or 'none'})")
        # A bag of another plant would have every message rejected: say so at once.
        for t, names, what in ((PLANT_U.absolute, system.inputs, "inputs"),
                               (PLANT_Y.absolute, system.outputs, "outputs")):
            labels = scan.first_labels(t) if t in present else None
            if labels and tuple(labels) != tuple(names):
                raise BagError(f"{bag}: {t} has channels {list(labels)} but plant "
                               f"{system.name} (gain file {gains.path}) has {what} "
                               f"{list(names)}: wrong gain file for this bag?")

    # one pass over the bag, in chunks; only what the summary reads is kept
    run = run_bag(bag, gains, system=system, agei=agei, keep="summary", checks=checks)
    return {"bag": str(bag), "gains": str(gains.path), "plant": system.name,
            "method": gains.method, "agei": agei, **analyze_run(run),
            "integrity": run.integrity}


def samples_line(doc: dict[str, Any]) -> str:
    """``analyze``'s one line on samples: present, used, skipped per reason, held."""
    c = doc["sample_counts"]
    why = ", ".join(f"{n} {k}" for k, n in c["skipped"].items())
    held = doc["time_base"].get("held", {})
    return (f"samples: {c['present']} present, {c['used']} used, "
            + (f"skipped: {why}" if why else "none skipped")
            + ("; held from an earlier sample: " + ", ".join(f"{ch} {n}"
                                                               for ch, n in held.items())
               if held else ""))


def _region_cell(a: dict[str, Any]) -> str:
    if "outside_certified_region" not in a:
        return "n/a (no region in gain file)"
    return f"OUTSIDE: {a['outside_detail']}" if a["outside_certified_region"] else "inside"


def run(args: argparse.Namespace) -> int:
    """Analyse and print."""
    if is_fleet(args):
        return run_fleet(args, analyze_bag)
    args.bag = args.bag[0]
    doc = analyze_bag(args.bag, args.gains, args.system, agei=not args.no_agei,
                      adapter=args.adapter)
    if args.json:
        print_json(doc)
        enforce_strict(doc["integrity"], args.bag, args.strict)
        return 0
    det = doc["detection"]
    print(f"analyze {doc['bag']} with {doc['gains']} ({doc['method']}, plant {doc['plant']}, "
          f"{doc['samples']} samples, AGEI {'on' if doc['agei'] else 'off'})")
    first = "none" if det is None else f"sample {det['sample']} (t = {det['time']:.1f} s)"
    print(f"first detection: {first}")
    print(samples_line(doc))
    print(f"integrity: {describe(doc['integrity'])}")
    if doc["time_base"].get("sample_time_note"):
        print(doc["time_base"]["sample_time_note"])
    print()
    if doc["alarms"]:
        print_table([(a["channel"], a["first_sample"], f"{a['time']:.1f}", a["last_sample"],
                      a["samples"], _region_cell(a)) for a in doc["alarms"]],
                    header=("channel", "first_sample", "time_s", "last_sample", "samples",
                            "certified_region"),
                    title="alarms")
    else:
        print("alarms: none")
    print()
    est = doc["transitions_estimated"]
    tru = doc["transitions_true"]
    rows = [("estimated", t["sample"], f"{t['time']:.1f}", t["from"], t["to"]) for t in est]
    if tru is not None:
        rows += [("true", t["sample"], f"{t['time']:.1f}", t["from"], t["to"]) for t in tru]
    if rows:
        rows.sort(key=lambda r: (r[1], r[0]))
        print_table(rows, header=("mode", "sample", "time_s", "from", "to"),
                    title="mode transitions")
    if doc["mode_agreement"] is not None:
        print(f"mode estimate agrees with truth on {100 * doc['mode_agreement']:.2f} % "
              f"of samples")
    if doc["input_errors"]:
        print()
        print_table([(e["kind"], e["topic"], e["sample"], e["message"])
                     for e in doc["input_errors"]],
                    header=("input error", "topic", "sample", "message"),
                    title="bad input (left out; the monitor bridged holes at samples "
                          f"{doc.get('bridges') or 'none'} and restarted at samples "
                          f"{doc['restarts'] or 'none'})")
    if doc["bias_estimate"]:      # hinf_sc and hminus_switched estimate no bias
        print()
        print_table([(n, f"{v:+.6f}", "yes" if n in doc["isolated"] else "no")
                     for n, v in doc["bias_estimate"].items()],
                    header=("sensor", "bias_estimate", "isolated"), title="sensor biases")
    enforce_strict(doc["integrity"], args.bag, args.strict)
    return 0
