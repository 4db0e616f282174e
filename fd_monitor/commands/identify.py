"""``python -m fd_monitor identify BAG [BAG ...] -o PLANT.yaml``: a plant file from bags.

Fits a discrete-time plant file (linear, affine or sparse affine modes; hybrid structure from
stated guards or a mode channel; noise and uncertainty bounds from held-out data; the operating
envelope the data covered) that ``validate``, ``design thresholds ... --envelope declared``,
``simulate`` and ``analyze`` accept. See :mod:`fd_monitor.analysis.identify`.
"""

from __future__ import annotations

import argparse
import math
import sys
from typing import Any

import numpy as np

from fd_monitor.analysis.identify import (
    ESTIMATORS,
    MODELS,
    PER_MODE,
    add_physical,
    identify_bags,
    plot_validation,
    write_plant,
)
from fd_monitor.analysis.integrity import add_strict_flag
from fd_monitor.commands._common import add_json_flag, number, print_json, print_table
from fd_monitor.core.identify import IdentificationError
from fd_monitor.wire.topics import PLANT_U, PLANT_Y

__all__ = ["add_arguments", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``identify``."""
    parser.add_argument("bags", nargs="+", metavar="BAG",
                        help="fault-free rosbag2 folders with the inputs and outputs")
    parser.add_argument("-o", "--output", required=True, metavar="PLANT",
                        help="plant file to write (YAML)")
    parser.add_argument("--force", action="store_true", help="overwrite an existing file")
    parser.add_argument("--holdout", nargs="+", default=[], metavar="BAG",
                        help="held-out bags for validation and the bounds (default: the last "
                             "--split of each fit bag)")
    parser.add_argument("--split", type=number(0, 1, low_open=True, high_open=True), default=0.3,
                        help="held-out fraction of each fit bag without --holdout (default 0.3)")
    parser.add_argument("--model", choices=MODELS, default="auto",
                        help="mode dynamics: linear (x+ = A x + B u), affine (+ offset), "
                             "sparse (STLSQ of the affine library), auto (every one with every "
                             "--estimator, the lowest held-out simulation error; default)")
    parser.add_argument("--modes", choices=PER_MODE, default="offset",
                        help="offset: the modes share A, B and differ by their offset (one "
                             "joint fit; default); full: each mode its own A, B, offset")
    parser.add_argument("--guard", action="append", default=[], metavar="COND",
                        help="a switching condition 'CHANNEL OP VALUE' (e.g. 'h3 > 0.35'; on "
                             "an output: autonomous, on an input: controlled); repeatable: one "
                             "mode per combination the data visit")
    parser.add_argument("--mode-topic", default=None, metavar="TOPIC[:CHANNEL]",
                        help="a Float64MultiArray topic whose channel holds the mode (integer)")
    parser.add_argument("--u-topic", default=PLANT_U.absolute,
                        help=f"inputs topic (default {PLANT_U.absolute})")
    parser.add_argument("--y-topic", default=PLANT_Y.absolute,
                        help=f"outputs topic (default {PLANT_Y.absolute})")
    parser.add_argument("--adapter", default=None, metavar="MAP",
                        help="message mapping for a robot's own message types (see "
                             "doc/tutorial/own-robot.md); replaces --u-topic/--y-topic")
    parser.add_argument("--name", default=None,
                        help="plant name (default: the output file's stem)")
    parser.add_argument("--sample-time", type=number(0, low_open=True), default=None,
                        help="s (default: from the bags' timestamps)")
    parser.add_argument("--margin", type=number(1), default=1.2,
                        help="factor on every bound, >= 1 (default 1.2)")
    parser.add_argument("--max-window", type=number(0, low_open=True), default=10.0,
                        help="longest moving-average window the uncertainty bound looks "
                             "through, s (default 10: a modelling error below the noise shows "
                             "only in averages)")
    parser.add_argument("--estimator", choices=ESTIMATORS, default="auto",
                        help="iv: lagged measurements as instruments (unbiased on noisy, "
                             "closed-loop data); ls: plain least squares; n4sid: subspace "
                             "(nfoursid; one mode, affine); auto (default): each, the lowest "
                             "held-out simulation error")
    parser.add_argument("--noise-bound", type=float, nargs="+", default=None, metavar="V",
                        help="measurement-noise bound from the sensors' datasheet (one per "
                             "output, or one for all; output units): stated as assumed "
                             "instead of measured; checked against the residuals")
    parser.add_argument("--sparsity", type=number(0, 1), default=0.01,
                        help="sparse: drop a term contributing less than this fraction of the "
                             "increment's spread (default 0.01)")
    parser.add_argument("--max-radius", type=number(0, low_open=True), default=None,
                        help="clip the eigenvalue magnitudes of each mode's A to this (e.g. "
                             "0.9999) and refit B and the offsets: a stable model for a plant "
                             "known to be stable (default: no clipping)")
    parser.add_argument("--exclude-input", action="append", default=[], metavar="INPUT",
                        help="leave an input out of the fit (repeatable)")
    parser.add_argument("--plot", default=None, metavar="PNG",
                        help="figure: held-out one-step prediction vs measurement, the "
                             "error within its stated bound, and the multi-step simulation "
                             "vs measurement")
    add_json_flag(parser)
    add_strict_flag(parser, also="or when a model-quality check warns (a weakly excited "
                                 "input, a noise bound below the residuals' spread, halves "
                                 "of the data that disagree); nothing is written")


def _progress() -> Any:
    """Progress lines on a terminal's stderr (none in a pipe: stderr then carries only
    warnings and errors)."""
    import sys

    if not sys.stderr.isatty():
        return None
    return lambda line: print(line, file=sys.stderr, flush=True)


def run(args: argparse.Namespace) -> int:
    """Identify, write the plant file (and plot), print the summary."""
    from pathlib import Path

    adapter: Any = None
    if args.adapter is not None:
        from fd_monitor.wire.adapters import load_adapter  # optional part (issue 14 item 2)

        adapter = load_adapter(args.adapter)
    out = Path(args.output)
    if out.exists() and not args.force:
        raise IdentificationError(f"{out}: exists (would overwrite; use --force)")
    name = args.name or out.stem.replace("-", "_").replace(".", "_")
    integrity: dict[str, Any] = {}         # bag -> what of it was not used
    res = identify_bags(args.bags, holdout=args.holdout, u_topic=args.u_topic,
                        y_topic=args.y_topic, mode_topic=args.mode_topic, adapter=adapter,
                        name=name, model=args.model, modes=args.modes, guards=args.guard,
                        margin=args.margin, split=args.split, max_window=args.max_window,
                        estimator=args.estimator, sparsity=args.sparsity,
                        sample_time=args.sample_time, exclude_inputs=args.exclude_input,
                        max_radius=args.max_radius, strict=args.strict, integrity=integrity,
                        progress=_progress(), stated_noise=args.noise_bound)
    add_physical(res, adapter)
    warns = res.summary["warnings"]
    if args.strict and warns:
        raise IdentificationError(f"--strict: {warns[0]} ({len(warns)} quality warning(s); "
                                  f"nothing written)")
    write_plant(res, out, force=args.force)
    for w in warns:
        print(f"WARNING: {w}", file=sys.stderr)
    if args.plot:
        plot_validation(res, args.plot)
    s = res.summary
    if args.json:
        # strict JSON: a quantity the data do not determine (an infinite standard error, a
        # diverging simulation) is null, not the non-standard Infinity
        print_json(_finite({"plant_file": str(out), "plot": args.plot, **s,
                            "integrity": integrity}))
        return 0
    print(f"identified {s['plant']} -> {out}: {s['model']} modes ({s['modes_structure']}), "
          f"estimator {s['estimator']}, Ts = {s['sample_time']:g} s")
    print(f"one-step samples: {s['fit_samples']} fit, {s['validation_samples']} held out "
          f"({s['holdout']})")
    print_quality(s)
    loop = s["closed_loop"]
    if loop["inputs"]:
        print("closed loop: " + ", ".join(f"{nm} (corr {loop['corr'][nm]:.3g})"
                                          for nm in loop["inputs"])
              + f" react(s) to the output noise (|corr(e_k, u_k+1)| > {loop['limit']:.3g})"
              + ("" if loop["least_squares_chosen_from"] else
                 ": least squares is biased there and its candidates are not chosen"))
    outs = s["outputs"]
    rows = [("fit RMS", *s["fit_rms"]), ("held-out RMS", *s["validation_rms"]),
            ("held-out max |e|", *s["validation_max_abs"]),
            (f"noise bound ({s['measurement_noise']['samples']} samples)",
             *s["measurement_noise"]["bound"])]
    for m in s["modes"]:
        rows.append((f"uncertainty {m['name']} ({m['uncertainty_samples']})",
                     *m["uncertainty"]))
        rows.append((f"one-step bound {m['name']}", *m["one_step_bound"]))
    print_table(rows, header=("per output", *outs))
    env = s["envelope"]
    print_table([(ch, lo, hi) for ch, (lo, hi) in [*env["states"].items(),
                                                   *env["inputs"].items()]],
                header=("envelope", "min", "max"))
    for m in s["modes"]:
        if m["spectral_radius"] >= 1.0:
            print(f"warning: mode {m['name']}: spectral radius {m['spectral_radius']:.6g} >= 1 "
                  f"(an unstable model; the thresholds designer's estimator needs a stable one: "
                  f"--max-radius clips it)")
    for m in s["not_covered"]:
        print(f"not covered: {m['mode']} ({m['fit_samples']} fit samples): no mode")
    if args.plot:
        print(f"plot: {args.plot}")
    return 0


def _pct(x: float) -> str:
    return "-" if x is None else ("diverges" if x < -1e6 else f"{x:.1f}")


def print_quality(s: dict[str, Any]) -> None:
    """The candidates, the quality and the excitation tables (issue 20)."""
    outs = s["outputs"]
    ls_out = not s["closed_loop"]["least_squares_chosen_from"]
    print_table([(f"{c['model']}/{c['estimator']}" + (" *" if c["chosen"] else "")
                  + (" (closed loop: not chosen)" if ls_out and c["estimator"] == "ls" else ""),
                  c["parameters"], c["validation_rms"],
                  *(_pct(f) for f in c["simulation_fit"])) for c in s["candidates"]],
                header=("candidate", "parameters", "held-out 1-step RMS",
                        *(f"sim fit % {o}" for o in outs)))
    q = s["quality"]
    sim = q["simulation"]
    print(f"held-out simulation ({sim['records']} record(s), {sim['samples']} samples, run free "
          f"from the first measurement): fit % (NRMSE, as MATLAB compare) "
          + ", ".join(f"{o} {_pct(f)}" for o, f in zip(outs, sim["fit_percent"])))
    ins = s["inputs"]
    for c in q["coefficients"]:
        rows = [(f"A[{outs[i]},{outs[j]}]", c["A"][i][j], c["se_A"][i][j])
                for i in range(len(outs)) for j in range(len(outs))]
        rows += [(f"B[{outs[i]},{ins[j]}]", c["B"][i][j], c["se_B"][i][j])
                 for i in range(len(outs)) for j in range(len(ins))
                 if ins[j] in s["fitted_inputs"]]
        print_table(rows, header=(f"coefficient ({c['mode']})", "estimate", "std error"))
        z = c["interval_z"]
        print_table([(f"{e['real']:.6g}{e['imag']:+.4g}j", e["se_real"], e["se_imag"],
                      f"[{e['interval_real'][0]:.6g}, {e['interval_real'][1]:.6g}]")
                     for e in c["eigenvalues"]],
                    header=("eigenvalue", "se real", "se imag",
                            f"{100 * c['interval_level']:.0f} % joint interval (real, "
                            f"+-{z:.3g} se)"))
        print(f"regression condition number (columns scaled): {c['condition_number']:.4g}, "
              f"rank {c['rank']} of {c['columns']} ({c['samples']} samples)"
              + ("; standard errors and eigenvalues of the regression before --max-radius "
                 "clipped it" if s.get("max_radius") is not None else ""))
    print_table([(e["input"], e["mode"], e["spread"], f"{100 * e['own_share']:.3g}",
                  e["pe_order"], _db(e["above_noise_db"]), f"{e['feedback_corr']:.3f}",
                  "inf" if e["gain_rel_se"] == float("inf") else
                  f"{100 * e['gain_rel_se']:.3g}", "WEAK" if e["weak"] else e["reason"])
                 for e in q["excitation"]],
                header=("excitation", "mode", "std", "own %", "PE order", "own / noise dB",
                        "corr(e, u+1)", "gain se %", "verdict"))
    print_table([(b["bound"], b["how"], b["samples"], f"{b['seconds']:.4g}")
                 for b in q["bounds"]], header=("bound", "how", "samples", "seconds"))
    print_table([(n["output"], n["bound"], n["hf_std"], f"{n['ratio']:.3g}",
                  "ok" if n["ok"] else "BELOW") for n in q["noise_check"]],
                header=("noise check", "bound", "hf std", "bound / std", "bound >= 1.5 std"))
    h = q["halves"]
    if "fit_first" in h:
        print("halves: sim fit % first " + ", ".join(_pct(f) for f in h["fit_first"])
              + ", second " + ", ".join(_pct(f) for f in h["fit_second"])
              + f"; largest difference {h['max_z']:.3g} se ({h['entry']}, critical "
              f"{h['z_critical']:.3g}): {h['verdict']}")
    else:
        print(f"halves: {h['verdict']}")
    for p in q.get("physical", []):
        if "inertia" in p:
            print(f"physical ({p['joint']}, mode {p['mode']}, input {p['input']}): inertia "
                  f"{p['inertia']:.6g}, damping {p['damping']:.6g}"
                  + (f", stiffness {p['stiffness']:.6g}" if "stiffness" in p else "")
                  + f", constant torque {p['constant_torque']:.6g} (couplings left out: "
                  f"largest {p['coupling_left_out']:.3g})")
        else:
            print(f"physical ({p['joint']}): {p.get('note', '')}")


def _db(x: float) -> str:
    if x == float("inf"):
        return "no feedback"
    if x < -99:
        return "none"
    return f"{x:.3g}"


def _finite(obj: Any) -> Any:
    """``obj`` with every non-finite float (and -1e300, a diverged fit) replaced by None."""
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _finite(obj.tolist())
    if isinstance(obj, (float, np.floating)):
        x = float(obj)
        return x if math.isfinite(x) and abs(x) < 1e299 else None
    return obj
