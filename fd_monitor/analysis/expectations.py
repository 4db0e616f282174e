"""Expected results of the bag library: check them, propose them, keep them honest.

:func:`analyze_summary` is the summary the regression suite checks (the offline run of
``analyze``, :func:`fd_monitor.analysis.summary.summarize_run`); :func:`check_expected`
compares it with a bag's ``expected.yaml`` (format: :mod:`fd_monitor.analysis.library`);
:func:`propose_expected` writes expectations from one analysis and the bag's truth;
:func:`check_truth` checks that expectations agree with the truth and the spec.

Nothing here imports rclpy.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from fd_monitor.analysis.library import BagSpec, LibraryError
from fd_monitor.analysis.offline import run_bag
from fd_monitor.analysis.summary import (
    Outputs,
    read_bag_truth,
    settled_modes,
    summarize,
    summarize_run,
    true_biases,
    truth_facts,
)
from fd_monitor.core.generalized_observer import GeneralizedObserver
from fd_monitor.core.methods import load_gains
from fd_monitor.core.residual_bank import ResidualBank
from fd_monitor.model.gains import to_plain
from fd_monitor.model.scenario import load_scenario
from fd_monitor.model.system import load_system
from fd_monitor.wire.bag_reader import read_bag
from fd_monitor.wire.topics import PLANT_TRUTH, PLANT_U, PLANT_Y, side_topic

__all__ = ["analyze_summary", "check_expected", "check_truth", "core_summary",
           "library_expected", "propose_expected", "write_expected"]


def analyze_summary(bag: str | Path, gains: str | Path, *,
                    transient: float = 0.0) -> dict[str, Any]:
    """The summary the regression suite checks: :func:`fd_monitor.analysis.offline.run_bag` (what
    ``python -m fd_monitor analyze`` runs, for every gain-file method alike)
    summarised by :func:`fd_monitor.analysis.summary.summarize_run`.

    Returns
    -------
    dict
        ``alarms`` (``{channel, first_sample, time}``, first alarm per channel at or after the
        transient), ``isolated``, ``bias_estimate``, ``modes`` (estimated mode sequence,
        repeats collapsed; a restart begins in the plant's initial mode), ``mode_segments``,
        ``input_errors`` (kind -> stamps), ``restarts`` (samples where the monitor restarted
        after a hole), ``bridges`` (where it bridged one), ``samples``.
    """
    return summarize_run(run_bag(bag, gains, transient=transient))


def check_expected(expected: Mapping[str, Any], summary: Mapping[str, Any]) -> list[str]:
    """Compare an analysis summary with expected results.

    Checks: no channel alarms before ``fault_onset_sample`` (when given: a false alarm);
    every channel of ``alarms`` alarms first at ``first_sample +- tolerance``; no
    channel of ``no_alarm`` alarms; ``isolated`` equals the isolated set; every
    ``bias_estimate`` is within its tolerance; ``modes`` equals the estimated mode sequence;
    ``input_errors`` (kind -> stamps) equals what was reported for those kinds and no other
    kind was reported; ``restarts`` and ``bridges`` equal the restart and bridge samples.

    Returns
    -------
    list of str
        One line per failed expectation (empty: all hold).
    """
    return [*_check_alarms(expected, summary), *_check_estimates(expected, summary),
            *_check_modes(expected, summary), *_check_inputs(expected, summary)]


def _check_alarms(expected: Mapping[str, Any], summary: Mapping[str, Any]) -> list[str]:
    """False alarms before the onset, first alarms within tolerance, ``no_alarm``."""
    fails: list[str] = []
    first = {a["channel"]: int(a["first_sample"]) for a in summary.get("alarms", [])}
    onset = expected.get("fault_onset_sample")
    for c, f in sorted(first.items()):
        if onset is not None and f < int(onset):
            fails.append(f"alarms.{c}: alarm at sample {f}, before the fault onset {onset} "
                         f"(false alarm)")
    for c, a in (expected.get("alarms") or {}).items():
        want, tol = int(a["first_sample"]), int(a["tolerance"])
        if c not in first:
            fails.append(f"alarms.{c}: expected a first alarm at sample {want} +- {tol}, "
                         f"got no alarm")
        elif abs(first[c] - want) > tol:
            fails.append(f"alarms.{c}: expected a first alarm at sample {want} +- {tol}, "
                         f"got {first[c]}")
    for c in expected.get("no_alarm") or []:
        if c in first:
            fails.append(f"no_alarm: channel {c} alarmed at sample {first[c]}")
    return fails


def _check_estimates(expected: Mapping[str, Any], summary: Mapping[str, Any]) -> list[str]:
    """The isolated set and the final bias estimates."""
    fails: list[str] = []
    if "isolated" in expected:
        got = sorted(summary.get("isolated", []))
        if got != sorted(expected["isolated"]):
            fails.append(f"isolated: expected {sorted(expected['isolated'])}, got {got}")
    est = summary.get("bias_estimate", {})
    for c, a in (expected.get("bias_estimate") or {}).items():
        if c not in est:
            fails.append(f"bias_estimate.{c}: no estimate reported")
        elif not abs(float(est[c]) - float(a["value"])) <= float(a["tolerance"]):
            fails.append(f"bias_estimate.{c}: expected {a['value']} +- {a['tolerance']}, "
                         f"got {float(est[c]):.6g}")
    return fails


def _check_modes(expected: Mapping[str, Any], summary: Mapping[str, Any]) -> list[str]:
    """The estimated mode sequence (runs shorter than ``mode_min_dwell`` dropped)."""
    if "modes" not in expected:
        return []
    dwell = int(expected.get("mode_min_dwell", 1))
    got_modes = list(summary.get("modes", []))
    if dwell > 1 and "mode_segments" in summary:
        got_modes = settled_modes(summary["mode_segments"], dwell)
    if got_modes == list(expected["modes"]):
        return []
    return [f"modes: expected {list(expected['modes'])}, got {got_modes}"
            + (f" (runs shorter than {dwell} samples dropped)" if dwell > 1 else "")]


def _check_inputs(expected: Mapping[str, Any], summary: Mapping[str, Any]) -> list[str]:
    """The input errors by kind and the restarts."""
    fails: list[str] = []
    if "input_errors" in expected:
        want_ie = {k: sorted(v) for k, v in (expected["input_errors"] or {}).items()}
        got_ie = {k: sorted(v) for k, v in (summary.get("input_errors") or {}).items()}
        for kind in sorted(set(want_ie) | set(got_ie)):
            if want_ie.get(kind, []) != got_ie.get(kind, []):
                fails.append(f"input_errors.{kind}: expected samples {want_ie.get(kind, [])}, "
                             f"got {got_ie.get(kind, [])}")
    for key in ("restarts", "bridges"):
        if key in expected and sorted(summary.get(key, [])) != sorted(expected[key]):
            fails.append(f"{key}: expected {sorted(expected[key])}, got "
                         f"{sorted(summary.get(key, []))}")
    return fails


def propose_expected(spec: BagSpec, summary: Mapping[str, Any], system: Any, *,
                     alarm_tolerance: int | None = None, bias_tolerance: float | None = None,
                     qb_min_dwell: int = 20) -> dict[str, Any]:
    """Expected results for a bag from one analysis and the bag's truth (to be reviewed).

    Physical quantities come from ``/plant/truth``, not from the analysis: the final bias
    estimate is expected at the true final bias (0 for healthy sensors), within
    ``bias_tolerance`` (``thresholds``; default 3 mm) or within the QB guarantee
    ``sqrt((P^-1)_jj)`` of that state (``qb``); the mode sequence is the true one. The first
    alarm samples (``alarm_tolerance``: 10 samples, 20 for ``qb``), the isolated set and the
    input errors are the analysis'; :func:`check_truth` then asserts they agree with the truth
    (no alarm before the onset, the faulty sensor isolated).
    """

    facts = truth_facts(read_bag_truth(spec.folder), system)
    # fault-model states estimated with a guaranteed band (qb): looser alarm tolerance
    qb = summary.get("estimate_kind") == "state"
    tol_k = alarm_tolerance if alarm_tolerance is not None else (20 if qb else 10)
    first = {a["channel"]: int(a["first_sample"]) for a in summary["alarms"]}
    channels = list(summary.get("channels") or system.outputs)
    doc: dict[str, Any] = {"bag": spec.name, "gains": spec.gains,
                           "description": spec.description}
    onsets = [f["onset_sample"] for f in facts["faults"].values()]
    if onsets:
        doc["fault_onset_sample"] = min(onsets)
    if spec.transient:
        doc["transient"] = spec.transient
    doc["alarms"] = {c: {"first_sample": first[c], "tolerance": tol_k}
                     for c in channels if c in first}
    doc["no_alarm"] = [c for c in channels if c not in first]
    if summary.get("isolates", True):     # a detect-only runtime states no isolated set
        doc["isolated"] = sorted(summary["isolated"])
    be: dict[str, Any] = {}
    if qb:
        gf = load_gains(spec.gains, system)
        comp = np.asarray(gf.results["component_bound"], dtype=float)
        tr = read_bag_truth(spec.folder)
        for name in summary["bias_estimate"]:
            j = system.states.index(name)
            be[name] = {"value": round(float(tr.column(f"x.{name}")[-1]), 6),
                        "tolerance": round(float(comp[j]), 6)}
        doc["mode_min_dwell"] = qb_min_dwell
    else:
        tol = bias_tolerance if bias_tolerance is not None else 0.003
        true_bias = true_biases(facts)
        for name in summary["bias_estimate"]:
            be[name] = {"value": round(float(true_bias.get(name, 0.0)), 6), "tolerance": tol}
    doc["bias_estimate"] = be
    doc["modes"] = list(facts["modes"])
    if spec.corruptions:
        doc["input_errors"] = dict(summary["input_errors"])
        doc["restarts"] = list(summary["restarts"])
        doc["bridges"] = list(summary.get("bridges", []))
    return doc


def core_summary(spec: BagSpec, system: Any = None) -> dict[str, Any]:
    """The summary of :func:`analyze_summary` computed with a method's core object directly
    (not its runtime) on the bag's ``/plant/u`` and ``/plant/y``, reduced by
    :func:`fd_monitor.analysis.summary.summarize` (a cross-check of the runtimes):

    * ``hinf_sc``: :class:`fd_monitor.core.residual_bank.ResidualBank` (the gain file's
      thresholds; an LPV bank schedules itself from the measurements, or reads the measured
      rho from ``/plant/rho`` when it has no scheduling map); channels are the
      generators' faults, alarm ``||r_i|| > J_i``; a generator alarming at the last sample
      isolates its fault;
    * ``hminus_switched``: :class:`fd_monitor.core.generalized_observer.GeneralizedObserver`
      with the true mode read from ``/plant/truth`` (the measured switching signal); one
      channel ``r_norm`` (``||r||`` against the gain file's threshold, +inf when it has none).

    Returns
    -------
    dict
        ``method``, ``channels``, ``alarms``, ``isolated``, ``bias_estimate`` (empty),
        ``modes`` (the plant's mode for a bank; the switching signal it was given for the
        switched observer), ``samples``, ``input_errors`` and ``restarts`` (empty: library
        bags of these methods carry no corruption).
    """

    if system is None:
        system = load_system(load_gains(spec.gains, verify=False).system_name)
    gf = load_gains(spec.gains, system)
    t_u, t_y, t_tr = PLANT_U.absolute, PLANT_Y.absolute, PLANT_TRUTH.absolute
    b = read_bag(spec.folder, [t_u, t_y, t_tr])
    u, y, tr = b[t_u], b[t_y], b[t_tr]
    k = np.asarray(y.stamps)
    if gf.method == "hinf_sc":
        bank = ResidualBank(system, gf)
        rho = None
        if bank.kind == "lpv" and not bank.model.scheduling:
            # measured rho without a scheduling map: the bag's side-signal topic
            t_rho = side_topic("rho").absolute
            rho = read_bag(spec.folder, [t_rho])[t_rho].values
        sig = bank.run(u.values, y.values, rho)
        alarm = sig > bank.thresholds
        channels = list(bank.faults)
        modes = np.full(len(k), system.initial_mode)    # a bank has one (LTI / LPV) mode
    elif gf.method == "hminus_switched":
        obs = GeneralizedObserver(system, gf)
        modes = tr.column("mode").astype(int)
        _, r = obs.run(u.values, y.values, modes)
        alarm = (np.linalg.norm(r, axis=1) > obs.threshold)[:, None]
        channels = ["r_norm"]
    else:
        raise LibraryError(f"bag {spec.name}: core_summary runs hinf_sc and hminus_switched "
                           f"gain files, not {gf.method!r} (use analyze_summary)")
    s = summarize(Outputs(k=k, dt=float(system.sample_time), channels=tuple(channels),
                          alarm=alarm, mode=modes, mode_names=tuple(system.mode_names),
                          isolated=alarm, isolation_channels=tuple(channels)),
                  spec.transient)
    return {"method": gf.method, "channels": channels, "alarms": s["alarms"],
            "isolated": s["isolated"], "bias_estimate": {}, "samples": s["samples"],
            "input_errors": {}, "restarts": [], "bridges": [], "modes": s["modes"]}


def library_expected(spec: BagSpec, *, write: bool = True) -> dict[str, Any]:
    """The ``expected.yaml`` of a library bag, from its documented command
    (``python -m fd_monitor simulate --library bags/library.yaml --expected``).

    :func:`propose_expected` from ``analyze``'s summary (:func:`analyze_summary`: the gain
    file's runtime, as the regression suite runs it) and the bag's ``/plant/truth`` read with
    the scenario's plant (its fault channels included); refused unless :func:`check_truth`
    agrees (no expected alarm before a fault, the faulty channel isolated, the true modes).
    The header says how the file was made and adds the spec's ``notes``.

    Parameters
    ----------
    spec : BagSpec
        A bag already generated in ``spec.folder``.
    write : bool
        Write ``spec.expected_file`` (False: only return the document).

    Raises
    ------
    LibraryError
        The proposal disagrees with the truth (one line per disagreement).
    """
    truth_system = load_scenario(spec.scenario).system
    summary = analyze_summary(spec.folder, spec.gains, transient=spec.transient)
    doc = propose_expected(spec, summary, truth_system)
    model_modes = load_system(load_gains(spec.gains, verify=False).system_name).mode_names
    if not set(truth_system.mode_names) <= set(model_modes):
        # the monitor runs an identified model whose modes are not the true plant's: the
        # true mode sequence is no expectation for it
        del doc["modes"]
    bad = check_truth(spec, doc, truth_system)
    if bad:
        raise LibraryError(f"bag {spec.name}: the proposed expectations disagree with the "
                           f"truth: {'; '.join(bad)}")
    checked = "test/test_regression.py (`analyze`)" + (
        " and test/test_regression_live.py (the live nodes)" if spec.live else "")
    header = (f"Expected results of bag {spec.name} (bags/library.yaml), checked by\n"
              f"{checked}.\n"
              "Written by `python -m fd_monitor simulate --library bags/library.yaml --expected`\n"
              "(fd_monitor.analysis.expectations.library_expected): fault onsets, bias values and\n"
              "the mode sequence are the bag's /plant/truth; first-alarm samples (within the\n"
              "stated tolerance, in samples) and the isolated set are `analyze`'s, checked\n"
              "against the truth.")
    if spec.notes:
        header += "\n" + spec.notes.rstrip()
    if write:
        write_expected(spec.expected_file, doc, header)
    return doc


def write_expected(path: str | Path, doc: Mapping[str, Any], header: str = "") -> Path:
    """Write an ``expected.yaml`` (flow style for short lists and mappings)."""
    import yaml

    lines = [f"# {h}" if h else "#" for h in header.splitlines()]
    body = yaml.safe_dump(to_plain(dict(doc)), sort_keys=False, default_flow_style=None,
                          width=96)
    p = Path(path)
    p.write_text("\n".join([*lines, body]) if lines else body, encoding="utf-8")
    return p


def check_truth(spec: BagSpec, expected: Mapping[str, Any], system: Any) -> list[str]:
    """Check that expected results agree with the bag's truth and spec (honest expectations).

    No expected first alarm is before the fault onset (no false alarm is expected);
    a fault-free bag expects no alarm; the isolated set, when stated (a detect-only method
    states none), is the set of biased sensors (or fault-model states, or faults); the
    expected bias values are the true final biases; the expected mode sequence is the true
    one (when stated: a monitor on an identified model has modes of its own); a corrupted bag
    expects exactly its corrupted stamps.

    Returns
    -------
    list of str
        One line per disagreement.
    """
    facts = truth_facts(read_bag_truth(spec.folder), system)
    out: list[str] = []
    onsets = [f["onset_sample"] for f in facts["faults"].values()]
    alarms = expected.get("alarms") or {}
    if not onsets and alarms:
        out.append(f"fault-free bag expects alarms {sorted(alarms)}")
    for c, a in alarms.items():
        if onsets and int(a["first_sample"]) < min(onsets):
            out.append(f"alarms.{c}: expected before the fault onset {min(onsets)}")
    targets = sorted({f["target"] for f in facts["faults"].values() if f["target"]})
    # a residual bank (hinf_sc) isolates faults by name, not by the channel they act on; a
    # detect-only method (hminus_switched: one channel ||r||) states no isolated set
    if "isolated" in expected and \
            sorted(expected["isolated"]) not in (targets, sorted(facts["faults"])):
        out.append(f"isolated {expected.get('isolated')} but the faulty channels are "
                   f"{targets} (faults {sorted(facts['faults'])})")
    if "modes" in expected and list(expected["modes"]) != facts["modes"]:
        out.append(f"modes {expected.get('modes')} but the true sequence is {facts['modes']}")
    true_bias = true_biases(facts)
    for c, a in (expected.get("bias_estimate") or {}).items():
        if c in system.outputs and abs(float(a["value"]) - true_bias.get(c, 0.0)) > 1e-6:
            out.append(f"bias_estimate.{c}: {a['value']} is not the true bias "
                       f"{true_bias.get(c, 0.0)}")
    if spec.corruptions:
        want: dict[str, list[Any]] = {}
        names = {"nan": "non_finite", "wrong_length": "wrong_length",
                 "duplicate": "duplicate", "out_of_order": "out_of_order"}
        for c in spec.corruptions:
            if c.kind == "gap":
                want.setdefault("missing", []).append([c.samples[0],
                                                       c.samples[0] + c.samples[1] - 1])
            else:
                want.setdefault(names[c.kind], []).extend(c.samples)
        got = {k: sorted(v) for k, v in (expected.get("input_errors") or {}).items()}
        if got != {k: sorted(v) for k, v in want.items()}:
            out.append(f"input_errors {got} but the corruptions are {want}")
    return out
