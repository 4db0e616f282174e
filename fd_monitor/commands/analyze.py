"""``python -m fd_monitor analyze BAG --gains GAINS [--json]``: the diagnosis chain offline.

Reads ``/plant/u`` and ``/plant/y`` (and ``/plant/truth`` when present) from a rosbag2 bag,
runs the core :class:`~fd_monitor.core.monitor.Monitor` over every sample (no ROS), and prints

* alarms: one entry per alarm episode and channel (``channel``, ``first_sample``, ``time``,
  ``last_sample``, ``samples``);
* the first detection (sample, time), the estimated mode transitions and, when the bag has
  truth, the true ones;
* isolated sensors and the final bias estimate sigma^.

The JSON (``--json``) has at least ``alarms`` (list of ``{channel, first_sample, time}``),
``isolated`` (channel names) and ``bias_estimate`` (``{channel: value}``).

The plant is the one the gain file was designed for (``--system`` to give a plant file
explicitly); the bag's channel names must match it.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from typing import Any

import numpy as np

from fd_monitor.commands._common import add_json_flag, print_json, print_table
from fd_monitor.errors import BagError, GainFileError, MessageError
from fd_monitor.system import System

__all__ = ["add_arguments", "run", "analyze_arrays", "analyze_bag"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """BAG, --gains, --system, --no-agei, --json."""
    parser.add_argument("bag", metavar="BAG", help="rosbag2 folder with /plant/u and /plant/y")
    parser.add_argument("--gains", required=True, metavar="GAINS",
                        help="'thresholds' gain file (path or name in config/gains/)")
    parser.add_argument("--system", default=None, metavar="SYSTEM",
                        help="plant file (default: the plant named in the gain file)")
    parser.add_argument("--no-agei", action="store_true",
                        help="ablation: run without the AGEI module")
    add_json_flag(parser)


def _episodes(flags: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) index pairs of the True runs of a 1-D bool array."""
    f = np.concatenate([[False], flags.astype(bool), [False]])
    d = np.diff(f.astype(int))
    starts = np.nonzero(d == 1)[0]
    ends = np.nonzero(d == -1)[0] - 1
    return list(zip(starts.tolist(), ends.tolist()))


def _transitions(k: np.ndarray, modes: np.ndarray, names: Sequence[str],
                 dt: float) -> list[dict[str, Any]]:
    out = []
    for j in np.nonzero(np.diff(modes) != 0)[0] + 1:
        a, b = int(modes[j - 1]), int(modes[j])
        out.append({"sample": int(k[j]), "time": float(k[j] * dt),
                    "from": names[a] if 0 <= a < len(names) else str(a),
                    "to": names[b] if 0 <= b < len(names) else str(b)})
    return out


def analyze_arrays(system: System, gains: Any, k: np.ndarray, u: np.ndarray, y: np.ndarray,
                   true_mode: np.ndarray | None = None, agei: bool = True) -> dict[str, Any]:
    """Run the :class:`Monitor` over arrays and summarise.

    Parameters
    ----------
    system : System
    gains : GainFile or DiagnosisGains
    k : numpy.ndarray
        (K,) consecutive sample indices.
    u : numpy.ndarray
        (K, nu) inputs.
    y : numpy.ndarray
        (K, ny) measurements.
    true_mode : numpy.ndarray, optional
        (K,) true mode indices (from ``/plant/truth``).
    agei : bool

    Returns
    -------
    dict
        ``alarms``, ``detection``, ``transitions_estimated``, ``transitions_true`` (or None),
        ``isolated``, ``bias_estimate``, ``samples``, ``mode_agreement`` (or None).

    Raises
    ------
    MessageError
        An invalid sample (its index is named); nothing after it is processed.
    """
    from fd_monitor.core.monitor import Monitor

    mon = Monitor(system, gains, agei=agei)
    K = int(np.asarray(k).size)
    dt = system.sample_time
    alarm = np.zeros((K, system.ny), dtype=bool)
    mode = np.zeros(K, dtype=int)
    last = None
    for j in range(K):
        try:
            last = mon.step(int(k[j]), u[j], y[j])
        except MessageError as exc:
            raise MessageError(f"bag sample {j}: {exc}") from None
        alarm[j] = last.detector.alarm
        mode[j] = last.mode
    alarms = []
    for i, name in enumerate(system.outputs):
        for a, b in _episodes(alarm[:, i]):
            alarms.append({"channel": name, "first_sample": int(k[a]),
                           "time": float(k[a] * dt), "last_sample": int(k[b]),
                           "samples": int(b - a + 1)})
    alarms.sort(key=lambda e: (e["first_sample"], e["channel"]))
    names = system.mode_names
    sigma = last.estimator.sigma_hat if last is not None else np.zeros(system.ny)
    iso = last.estimator.isolated if last is not None else np.zeros(system.ny, bool)
    kd = int(last.estimator.k_detect) if last is not None else -1
    doc: dict[str, Any] = {
        "samples": K,
        "alarms": alarms,
        "detection": None if kd < 0 else {"sample": kd, "time": kd * dt},
        "transitions_estimated": _transitions(k, mode, names, dt),
        "transitions_true": None if true_mode is None else _transitions(k, true_mode, names,
                                                                        dt),
        "mode_agreement": None if true_mode is None else float(np.mean(true_mode == mode)),
        "isolated": [n for n, f in zip(system.outputs, iso) if f],
        "bias_estimate": {n: float(v) for n, v in zip(system.outputs, sigma)},
    }
    return doc


def analyze_bag(bag: str, gains_source: str, system_source: str | None = None,
                agei: bool = True) -> dict[str, Any]:
    """Read a bag and run :func:`analyze_arrays`; checks the bag matches the gain file's plant.

    Raises
    ------
    BagError
        Missing bag or topic, channels that do not match the plant, non-consecutive stamps.
    GainFileError
        Gain file missing, not ``thresholds``, for another plant, or its certificate fails.
    """
    from fd_monitor.bags import bag_topics, read_bag
    from fd_monitor.gains import load_gains
    from fd_monitor.system import load_system

    raw = load_gains(gains_source, verify=False)
    if raw.method != "thresholds":
        raise GainFileError(f"{raw.path}: method {raw.method!r}: analyze needs a "
                            f"'thresholds' gain file (python -m fd_monitor design thresholds "
                            f"{raw.system_name})")
    system = load_system(system_source or raw.system_name)
    gains = load_gains(gains_source, system)   # plant SHA-256 and certificate
    present = bag_topics(bag)
    for t in ("/plant/u", "/plant/y"):
        if t not in present:
            raise BagError(f"{bag}: topic {t} missing (topics: "
                           f"{', '.join(sorted(present)) or 'none'})")
    want = ["/plant/u", "/plant/y"] + (["/plant/truth"] if "/plant/truth" in present else [])
    arr = read_bag(bag, want)
    U, Y = arr["/plant/u"], arr["/plant/y"]
    for ta, names, what in ((U, system.inputs, "inputs"), (Y, system.outputs, "outputs")):
        if tuple(ta.labels) != tuple(names):
            raise BagError(f"{bag}: {ta.topic} has channels {list(ta.labels)} but plant "
                           f"{system.name} (gain file {gains.path}) has {what} {list(names)}: "
                           f"wrong gain file for this bag?")
    ks = np.intersect1d(U.stamps, Y.stamps)
    if ks.size == 0:
        raise BagError(f"{bag}: /plant/u and /plant/y share no sample stamp")
    if np.any(np.diff(ks) != 1):
        gap = int(ks[np.nonzero(np.diff(ks) != 1)[0][0]])
        raise BagError(f"{bag}: samples are not consecutive after stamp {gap} (a message of "
                       f"/plant/u or /plant/y is missing)")
    iu = np.searchsorted(U.stamps, ks)
    iy = np.searchsorted(Y.stamps, ks)
    true_mode = None
    if "/plant/truth" in arr:
        T = arr["/plant/truth"]
        if "mode" in T.labels and np.all(np.isin(ks, T.stamps)):
            true_mode = T.column("mode")[np.searchsorted(T.stamps, ks)].astype(int)
    doc = analyze_arrays(system, gains, ks, U.values[iu], Y.values[iy], true_mode, agei)
    return {"bag": str(bag), "gains": str(gains.path), "plant": system.name,
            "agei": agei, **doc}


def run(args: argparse.Namespace) -> int:
    """Analyse and print."""
    doc = analyze_bag(args.bag, args.gains, args.system, agei=not args.no_agei)
    if args.json:
        print_json(doc)
        return 0
    det = doc["detection"]
    print(f"analyze {doc['bag']} with {doc['gains']} (plant {doc['plant']}, "
          f"{doc['samples']} samples, AGEI {'on' if doc['agei'] else 'off'})")
    first = "none" if det is None else f"sample {det['sample']} (t = {det['time']:.1f} s)"
    print(f"first detection: {first}")
    print()
    if doc["alarms"]:
        print_table([(a["channel"], a["first_sample"], f"{a['time']:.1f}", a["last_sample"],
                      a["samples"]) for a in doc["alarms"]],
                    header=("channel", "first_sample", "time_s", "last_sample", "samples"),
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
    print()
    print_table([(n, f"{v:+.6f}", "yes" if n in doc["isolated"] else "no")
                 for n, v in doc["bias_estimate"].items()],
                header=("sensor", "bias_estimate", "isolated"), title="sensor biases")
    return 0
