"""``python -m fd_monitor validate FILE``: check a plant file, a scenario or an adapter file and
summarise it.

An adapter file (:mod:`fd_monitor.wire.adapters`: ``inputs``/``outputs`` lists of
``{channel, topic, type, ...}`` mappings) is recognised by its content, or named with
``--adapter``, and checked on its own (:func:`~fd_monitor.wire.adapters.parse_adapter`); with
``--bag BAG`` it is a dry run of the offline reader
(:func:`~fd_monitor.wire.adapters.read_adapted`, the nodes' time base) over the bag: how its
messages pair into samples (per topic its role and what times it, its messages; the first
samples), the sample time used and where it came from, the samples present and used and
their k range, every gap (reason, channel, k run), held sample, new run and message left out,
with counts per reason. ``--system`` checks the mapping against a plant (and takes its sample
time); ``--sample-time`` overrides it.
"""

from __future__ import annotations

import argparse
from collections import Counter
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from fd_monitor.commands._common import add_json_flag, number, print_json, print_table
from fd_monitor.model.errors import FdMonitorError, ScenarioError, SystemFileError
from fd_monitor.model.scenario import Scenario, load_scenario
from fd_monitor.model.system import System, load_system
from fd_monitor.model.yaml_io import read_yaml

__all__ = ["adapter_dry_run", "adapter_summary", "add_arguments", "run", "system_summary"]

#: Lines of skips and holes the human output lists (``--json`` lists every one).
_LIST_MAX = 40
#: Samples the dry run shows (the pairing of the first messages).
_FIRST = 5


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``validate``."""
    parser.add_argument("file", metavar="FILE",
                        help="plant file or scenario file (a path, or a shipped name)")
    parser.add_argument("--scenario", action="store_true",
                        help="treat FILE as a scenario (automatic for files with a "
                             "'system:' key or shipped scenario names)")
    parser.add_argument("--adapter", action="store_true",
                        help="treat FILE as an adapter file, or a shipped adapter name "
                             "(automatic for files whose inputs/outputs are "
                             "{channel, topic, type} mappings)")
    parser.add_argument("--bag", default=None, metavar="BAG",
                        help="adapter files: dry run over this robot bag (how its messages "
                             "pair into samples; holes and skips with counts per reason)")
    parser.add_argument("--system", default=None, metavar="SYSTEM",
                        help="adapter files: check the mapping against this plant (its "
                             "inputs, outputs and sample time)")
    parser.add_argument("--sample-time", type=number(0, low_open=True), default=None, metavar="S",
                        help="adapter dry run: sample time, s (default: the plant's with "
                             "--system, else from the clock's stamps)")
    add_json_flag(parser)


def system_summary(system: System) -> dict[str, Any]:
    """Summary of a plant: sizes, modes, guards, bounds and its SHA-256."""
    return {
        "name": system.name,
        "file": system.source,
        "sha256": system.sha256,
        "sample_time": system.sample_time,
        "states": list(system.states),
        "inputs": list(system.inputs),
        "outputs": list(system.outputs),
        "disturbances": list(system.disturbances),
        "modes": [{"name": m.name, "dynamics": m.dynamics,
                   "time": m.time if m.dynamics == "linear" else "discrete",
                   "model": m.model,
                   "max_uncertainty": float(np.max(m.uncertainty, initial=0.0))}
                  for m in system.modes],
        "guards": [{"name": g.name, "kind": g.kind, "from": system.modes[g.source].name,
                    "to": system.modes[g.target].name,
                    "when": " and ".join(f"{c.var} {c.op} {c.value:g}" for c in g.conditions)}
                   for g in system.guards],
        "faults": [{"name": f.name, "kind": f.kind} for f in system.faults],
        "measurement_noise": system.measurement_noise,
        "disturbance_bound": system.disturbance_bound,
        "initial": {"mode": system.modes[system.initial_mode].name,
                    "state": system.initial_state},
    }


def _scenario_summary(sc: Scenario) -> dict[str, Any]:
    return {
        "scenario": sc.name,
        "file": sc.source,
        "system": sc.system.name,
        "system_sha256": sc.system.sha256,
        "duration": sc.duration,
        "samples": sc.n_samples,
        "seed": sc.seed,
        "faults": [{"channel": sc.system.faults[f.channel].name, "profile": f.profile,
                    "time": f.time, "magnitude": f.magnitude} for f in sc.faults],
    }


def _is_scenario(source: str) -> bool:
    p = Path(source)
    if p.is_file():
        data = read_yaml(p, ScenarioError)
        return isinstance(data, dict) and "system" in data and "modes" not in data
    try:
        load_system(source)
        return False
    except SystemFileError as exc:
        try:
            load_scenario(source)
        except ScenarioError:
            raise SystemFileError(f"{source}: neither a shipped plant nor a shipped scenario "
                                  f"({exc})") from None
        return True


def _is_adapter_file(source: str) -> bool:
    """Whether ``source`` is a file that reads as an adapter file: ``inputs``/``outputs``
    lists of mappings, or those keys without a plant's ``name``/``modes`` or a scenario's
    ``system`` (a broken adapter file is then checked as one, and its error names the key)."""
    p = Path(source)
    if not p.is_file():
        return False
    doc = read_yaml(p, SystemFileError)
    if not isinstance(doc, Mapping):
        return False
    lists = [doc[r] for r in ("inputs", "outputs") if isinstance(doc.get(r), list)]
    if any(isinstance(e, Mapping) for lst in lists for e in lst):
        return True
    return bool({"inputs", "outputs"} & set(doc)) and not {"name", "modes", "system"} & set(doc)


def adapter_summary(adapter: Any) -> dict[str, Any]:
    """An adapter file's channels and topics: per channel its role, topic, type, field,
    ``max_hold`` (s) and ``decimate``; per topic whether it phases the grid (the clock) and
    what times it (header stamp or receive time); ``wait`` (s)."""
    from fd_monitor.wire.adapters import ADAPTER_TYPES

    return {
        "file": adapter.source,
        "clock_topic": adapter.clock_topic,
        "channels": [{"channel": c.name, "role": role, "topic": c.topic, "type": c.msgtype,
                      "field": c.where[len(c.topic):],
                      "max_hold": default if c.max_hold is None else c.max_hold,
                      "decimate": c.decimate}
                     for role, chans, default in (
                         ("input", adapter.inputs, adapter.hold_inputs),
                         ("output", adapter.outputs, adapter.hold_outputs)) for c in chans],
        "wait": adapter.wait,
        "topics": [{"topic": t, "type": ty,
                    "role": "clock (grid phase)" if t == adapter.clock_topic else "sampled",
                    "time": "header.stamp" if ADAPTER_TYPES[ty][0] else "receive time"}
                   for t, ty in adapter.topics.items()],
    }


def adapter_dry_run(adapter: Any, bag: str, system: Any = None,
                    sample_time: float | None = None) -> dict[str, Any]:
    """How a robot bag's messages pair into samples through ``adapter``: the offline reader
    (:func:`~fd_monitor.wire.adapters.read_adapted`, the live nodes' time base) run and
    described.

    Returns
    -------
    dict
        ``bag``; ``messages`` (topic -> messages the reader took); ``sample_time`` (s) and
        ``sample_time_note`` (where it came from); ``samples_present`` (grid samples from
        the first to the last), ``samples_used`` (with a value of every channel), ``k_first``,
        ``k_last``; ``gaps`` (``[{reason, channel, first, last, samples}]``: runs of samples
        not usable, ``stale`` or ``no_value``); ``held`` (channel -> samples that used a
        held value); ``new_runs`` (first sample of each); ``skipped`` (``[{kind, message}]``:
        messages left out and the first note of each kind); ``counts`` (reason -> count:
        gap samples per reason, messages per kind, new runs); ``first_samples``
        (``[{k, t, u, y}]``, t in s since the first sample).
    """
    from fd_monitor.analysis.offline import stamp_runs
    from fd_monitor.wire.adapters import read_adapted

    if not Path(bag).exists():
        raise FdMonitorError(f"--bag {bag}: no such bag")
    s = read_adapted(bag, adapter, sample_time=sample_time, system=system)
    by: dict[tuple[str, str], list[int]] = {}
    for k, reason, channel in s.gaps:
        by.setdefault((reason, channel), []).append(int(k))
    gaps = [{"reason": r, "channel": c, "first": a, "last": b, "samples": b - a + 1}
            for (r, c), ks in sorted(by.items()) for a, b in stamp_runs(sorted(set(ks)))]
    gap_ks = sorted({int(k) for k, _r, _c in s.gaps})
    # samples per gap reason (a sample with two stale channels counts once), messages per
    # kind: per topic (late, duplicate, stray, decimated) and the bad ones (by their kind)
    counts: Counter[str] = Counter(r for _k, r in {(int(k), r) for k, r, _c in s.gaps})
    for key, val in s.counts.items():
        if key in ("samples", "gaps", "held", "new_runs", "messages") or \
                not isinstance(val, Mapping):
            continue
        for name, n in val.items():
            counts[name if key == "bad_messages" else key] += int(n)
    if s.new_runs:
        counts["new_run"] = len(s.new_runs)
    k_all = [int(k) for k in s.k] + gap_ks
    return {
        "bag": str(bag),
        "messages": dict(s.counts.get("messages", {})),
        "sample_time": float(s.sample_time),
        "sample_time_note": s.sample_time_note,
        "samples_present": len(s.k) + len(gap_ks),
        "samples_used": len(s.k),
        "k_first": min(k_all),
        "k_last": max(k_all),
        "gaps": gaps,
        "held": dict(s.counts.get("held", {})),
        "new_runs": [int(k) for k in s.new_runs],
        "skipped": [{"kind": kind, "message": line} for kind, line in s.errors],
        "counts": dict(sorted(counts.items())),
        "first_samples": [{"k": int(s.k[i]), "t": float(s.t[i]),
                           "u": dict(zip(s.inputs, map(float, s.u[i]))),
                           "y": dict(zip(s.outputs, map(float, s.y[i])))}
                          for i in range(min(_FIRST, len(s.k)))],
    }


def _columns(adapter: Any) -> list[str]:
    """Column names of u then y: ``u.effort``, ``y.velocity``."""
    return [f"u.{c.name}" for c in adapter.inputs] + [f"y.{c.name}" for c in adapter.outputs]


def _validate_adapter(args: argparse.Namespace) -> int:
    """``validate ADAPTER.yaml [--system SYSTEM] [--bag BAG]``."""
    from fd_monitor.wire.adapters import load_adapter

    ad = load_adapter(args.file)
    system = None
    if args.system is not None:
        system = load_system(args.system)
        ad = ad.for_system(system)
    if args.sample_time is not None and not 0 < args.sample_time < float("inf"):
        raise FdMonitorError(f"--sample-time {args.sample_time}: expected a number > 0 (s)")
    summary = adapter_summary(ad)
    dry = None if args.bag is None else adapter_dry_run(ad, args.bag, system,
                                                        args.sample_time)
    if args.json:
        print_json({"valid": True, **summary, **({} if system is None else
                                                 {"system": system.name}),
                    **({} if dry is None else {"dry_run": dry})})
        return 0
    print(f"valid adapter {ad.source}: {len(ad.inputs)} input(s), {len(ad.outputs)} "
          f"output(s)" + ("" if system is None else f", the channels of plant {system.name}")
          + f"; clock topic (grid phase) {ad.clock_topic}")
    print()
    print_table([(c["channel"], c["role"], c["topic"], c["type"], c["field"],
                  f"{c['max_hold']:g}", c["decimate"]) for c in summary["channels"]],
                header=("channel", "role", "topic", "type", "field", "max_hold_s",
                        "decimate"))
    if dry is None:
        return 0
    print()
    print(f"dry run over {dry['bag']}: every channel sampled onto the grid k Ts phased on "
          f"{ad.clock_topic} (the value in force at each grid instant; held up to max_hold)")
    print_table([(t["topic"], t["role"], t["time"], dry["messages"].get(t["topic"], 0))
                 for t in summary["topics"]], header=("topic", "role", "time", "messages"))
    print()
    print_table([(f["k"], f"{f['t']:.6f}",
                  *(f"{v:.6g}" for v in (*f["u"].values(), *f["y"].values())))
                 for f in dry["first_samples"]],
                header=("k", "t_s", *_columns(ad)), title="first samples")
    print()
    print(dry["sample_time_note"])
    print(f"samples: {dry['samples_present']} present (k {dry['k_first']}..{dry['k_last']}), "
          f"{dry['samples_used']} used; "
          + (", ".join(f"{n} {r}" for r, n in dry["counts"].items()) or "nothing skipped")
          + "".join(f"; {n} held ({c})" for c, n in dry["held"].items()))
    rows = ([(g["reason"], f"{g['channel']}: k {g['first']}..{g['last']} ({g['samples']} "
                           f"sample{'s' if g['samples'] > 1 else ''})") for g in dry["gaps"]]
            + [("new_run", f"a new run from k {k}") for k in dry["new_runs"]]
            + [(e["kind"], e["message"]) for e in dry["skipped"]])
    if rows:
        print()
        print_table(rows[:_LIST_MAX], header=("reason", "what"))
        if len(rows) > _LIST_MAX:
            print(f"... and {len(rows) - _LIST_MAX} more (--json lists every one)")
    return 0


def run(args: argparse.Namespace) -> int:
    """Validate and print; errors propagate as one-line FdMonitorError messages."""
    if args.adapter or (not args.scenario and _is_adapter_file(args.file)):
        return _validate_adapter(args)
    for flag, given in (("--bag", args.bag), ("--system", args.system),
                        ("--sample-time", args.sample_time)):
        if given is not None:
            raise FdMonitorError(f"{flag}: only for an adapter file ({args.file} is not one; "
                                 f"--adapter to read it as one)")
    if args.scenario or _is_scenario(args.file):
        sc = load_scenario(args.file)
        summary = _scenario_summary(sc)
        if args.json:
            print_json({"valid": True, **summary})
            return 0
        print(f"valid scenario {sc.name} ({sc.source}) for plant {sc.system.name} "
              f"{sc.system.sha256[:12]}: {sc.duration:g} s = {sc.n_samples} samples, "
              f"seed {sc.seed}")
        print_table([(f["channel"], f["profile"], f["time"], f["magnitude"])
                     for f in summary["faults"]], header=("fault", "profile", "time [s]",
                                                          "magnitude"))
        return 0
    system = load_system(args.file)
    summary = system_summary(system)
    if args.json:
        print_json({"valid": True, **summary})
        return 0
    print(f"valid plant {system.name} ({system.source})")
    print(f"sha256 {system.sha256}")
    print(f"{system.n} states {list(system.states)}, {system.nu} inputs "
          f"{list(system.inputs)}, {system.ny} outputs {list(system.outputs)}, "
          f"{system.nw} disturbances; Ts = {system.sample_time:g} s")
    print()
    print_table([(m["name"], m["dynamics"], m["time"], m["model"] or "-",
                  m["max_uncertainty"]) for m in summary["modes"]],
                header=("mode", "dynamics", "time", "model", "max |eta|"))
    if summary["guards"]:
        print()
        print_table([(g["name"], g["kind"], g["from"], g["to"], g["when"])
                     for g in summary["guards"]],
                    header=("guard", "kind", "from", "to", "when"))
    if summary["faults"]:
        print()
        print_table([(f["name"], f["kind"]) for f in summary["faults"]],
                    header=("fault channel", "kind"))
    return 0
