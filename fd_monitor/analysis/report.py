"""Reports: PNG figures and a one-page ``summary.md`` for a bag, or for a Monte Carlo campaign.

Bag report (:func:`bag_report`), from :func:`fd_monitor.analysis.offline.run_bag` (any gain-file
method: the runtime comes from :func:`fd_monitor.core.methods.runtime_for`):

* ``residuals.png`` -- per alarm channel, the filtered residual against the threshold in force
  (``+-R_k``; ``qb``, ``hinf_sc``, ``hminus_switched``: the compared magnitude against its
  bound), alarm periods shaded, the fault onset marked (from ``/plant/truth``), the transient
  greyed;
* ``modes.png`` -- true and estimated mode over time;
* ``bias.png`` (methods that estimate a bias) -- the bias estimate against the true bias
  (``thresholds``: sigma^ per sensor; ``qb``: the fault-model states with their guaranteed
  band ``+-sqrt((P^-1)_jj)``);
* ``qb_bound.png`` (QB gain files) -- the error ellipsoid ``e' P e`` against its bound 1 and
  every ``|e_j|`` against ``sqrt((P^-1)_jj)``, with the true state (Alessandri et al. eq. 6);
* ``summary.md`` -- the summary table, the ``expected.yaml`` check when the bag has one, the
  figures.

Campaign report (:func:`campaign_report`), from :func:`fd_monitor.analysis.evaluate.run_campaign`:
``summary.md`` with the metrics table, ``detection.png`` (detection rate and delay against the
fault magnitude) and ``false_alarms.png`` (false-alarm rate per scenario and variant, or
against the threshold scale rho).

matplotlib runs with the Agg backend; nothing here imports rclpy.

Why one module of ~520 lines: the four bag figures and the campaign report share their axes
helpers and the summary page; most lines are matplotlib calls, one figure per function.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from fd_monitor.analysis.expectations import check_expected
from fd_monitor.analysis.library import expected_path, load_expected
from fd_monitor.analysis.offline import run_bag
from fd_monitor.analysis.summary import episodes, summarize_run, truth_at, truth_facts
from fd_monitor.core.methods import load_gains
from fd_monitor.model.errors import BagError, FdMonitorError
from fd_monitor.model.system import gain_system

__all__ = ["bag_report", "campaign_report", "figure_residuals", "figure_modes", "figure_bias",
           "figure_qb_bound"]

_ALARM = "#d62728"
_TRANSIENT = "0.85"


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def _onsets(run: Any) -> list[tuple[str, float]]:
    """(fault name, onset time s) of every fault channel that is ever non-zero in the truth."""
    if run.truth is None:
        return []
    dt = float(run.system.sample_time)
    return [(name, f["onset_sample"] * dt)
            for name, f in truth_facts(run.truth, run.system)["faults"].items()]


def _decorate(ax: Any, run: Any, t: np.ndarray, alarm: np.ndarray | None,
              label_once: dict[str, bool]) -> None:
    """Alarm shading, fault onsets and the transient on one axis."""
    dt = float(run.system.sample_time)
    if run.transient > 0:
        ax.axvspan(t[0] if t.size else 0.0, run.transient, color=_TRANSIENT, alpha=0.6, lw=0,
                   label=None if label_once.get("tr") else "transient (not evaluated)")
        label_once["tr"] = True
    if alarm is not None and t.size:
        half = max(dt / 2, 0.002 * float(t[-1] - t[0]))  # short alarms stay visible
        for a, b in episodes(alarm):
            ax.axvspan(t[a] - half, t[b] + half, color=_ALARM, alpha=0.3, lw=0,
                       label=None if label_once.get("al") else "alarm period")
            label_once["al"] = True
    for name, t0 in _onsets(run):
        ax.axvline(t0, color="k", ls="--", lw=1.0,
                   label=None if label_once.get(name) else f"fault onset ({name})")
        label_once[name] = True


def figure_residuals(run: Any, path: str | Path) -> Path:
    """Per alarm channel: residual against the threshold in force, alarms shaded.

    Parameters
    ----------
    run : fd_monitor.analysis.offline.BagRun
    path : str or pathlib.Path
        PNG to write.
    """
    plt = _plt()
    m = len(run.channels)
    fig, axes = plt.subplots(m, 1, figsize=(10, 1.9 * m + 1.0), sharex=True, squeeze=False)
    t = run.t
    magnitude = not run.signed          # |signal| against a positive bound (log scale)
    for i, (c, unit) in enumerate(zip(run.channels, run.units)):
        ax = axes[i, 0]
        seen: dict[str, bool] = {}
        _decorate(ax, run, t, run.alarm[:, i], seen)
        sig, thr = run.signal[:, i], run.threshold[:, i]
        if magnitude:
            ax.plot(t, sig, lw=0.8, color="C0", label="|signal|")
            ax.plot(t, thr, lw=1.2, color="C1", label="bound in force")
            ax.set_yscale("log")
        else:
            ax.plot(t, sig, lw=0.8, color="C0", label="filtered residual r")
            ax.plot(t, thr, lw=1.2, color="C1", label="threshold +-R in force")
            ax.plot(t, -thr, lw=1.2, color="C1")
            lim = 4.0 * float(np.nanmax(thr)) if thr.size else 1.0
            lo, hi = float(np.nanmin(sig, initial=0.0)), float(np.nanmax(sig, initial=0.0))
            ax.set_ylim(max(lo * 1.05, -lim), min(hi * 1.05, lim) if hi > 0 else lim)
            ax.set_ylim(min(ax.get_ylim()[0], -1.3 * float(np.nanmax(thr))),
                        max(ax.get_ylim()[1], 1.3 * float(np.nanmax(thr))))
        ax.set_ylabel(f"{c} [{unit}]")
        ax.grid(True, alpha=0.3)
    axes[-1, 0].set_xlabel("time [s]")
    what = (f"{run.method} detection signals against their bounds" if magnitude
            else "filtered residuals against the threshold in force")
    _legend(fig, axes, f"{Path(run.bag).name}: {what}")
    return _save(fig, path)


def _true_modes(run: Any) -> np.ndarray | None:
    if run.truth is None or "mode" not in run.truth.labels:
        return None
    return truth_at(run.truth, run.k, ["mode"])[:, 0]


def figure_modes(run: Any, path: str | Path) -> Path:
    """True and estimated mode over time."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(10, 3.2))
    t = run.t
    names = run.system.mode_names
    seen: dict[str, bool] = {}
    _decorate(ax, run, t, None, seen)
    tm = _true_modes(run)
    if tm is not None:
        ax.step(t, tm, where="post", lw=3.0, color="0.6", label="true mode")
    ax.step(t, run.mode_hat, where="post", lw=1.2, color="C0", label="estimated mode")
    ax.set_yticks(range(len(names)), list(names))
    ax.set_ylim(-0.5, len(names) - 0.5)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("mode")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper right", fontsize=8)
    ax.set_title(f"{Path(run.bag).name}: true and estimated mode")
    fig.tight_layout()
    return _save(fig, path)


def figure_bias(run: Any, path: str | Path) -> Path:
    """Bias estimate against the true bias, per sensor (or fault-model state)."""
    plt = _plt()
    names = list(run.estimate)
    fig, axes = plt.subplots(len(names), 1, figsize=(10, 1.9 * len(names) + 1.0),
                             sharex=True, squeeze=False)
    t = run.t
    qb = run.estimate_kind == "state"   # fault-model states against the true state
    for i, n in enumerate(names):
        ax = axes[i, 0]
        seen: dict[str, bool] = {}
        _decorate(ax, run, t, None, seen)
        true = None
        if run.truth is not None:
            if qb:
                true = truth_at(run.truth, run.k, [f"x.{n}"])[:, 0]
            else:
                labs = [f"f.{f.name}" for f in run.system.faults
                        if f.kind == "sensor_bias" and run.system.outputs[f.index] == n]
                labs = [lab for lab in labs if lab in run.truth.labels]
                if labs:
                    true = truth_at(run.truth, run.k, labs).sum(axis=1)
                else:
                    true = np.zeros(len(t))
        if true is not None:
            ax.plot(t, true, lw=2.5, color="0.6", label="true bias")
        if "component_bound" in run.qb:
            j = run.system.states.index(n)
            b = float(run.qb["component_bound"][j])
            ax.fill_between(t, run.estimate[n] - b, run.estimate[n] + b, color="C0",
                            alpha=0.15, lw=0, label="estimate +- sqrt((P^-1)_jj)")
        ax.plot(t, run.estimate[n], lw=1.0, color="C0",
                label="estimate x^" if qb else "estimate sigma^")
        if run.isolated is not None:
            j = list(run.system.outputs).index(n)
            iso = run.isolated[:, j]
            if iso.any():
                ax.axvline(t[int(np.argmax(iso))], color="C2", lw=1.2,
                           label="isolated from here")
        unit = "-" if qb else run.units[0]
        ax.set_ylabel(f"{n} [{unit}]")
        ax.grid(True, alpha=0.3)
    axes[-1, 0].set_xlabel("time [s]")
    _legend(fig, axes, f"{Path(run.bag).name}: " + (
        "fault-model states (biases) estimated by the QB observer" if qb
        else "sensor-bias estimate sigma^ against the true bias"))
    return _save(fig, path)


def figure_qb_bound(run: Any, path: str | Path) -> Path:
    """QB ellipsoid bound: ``e' P e`` against 1 and ``|e_j|`` against ``sqrt((P^-1)_jj)``."""
    if "V" not in run.qb:
        raise FdMonitorError(f"{run.bag}: the QB bound figure needs /plant/truth (the true "
                             f"state) in the bag")
    plt = _plt()
    n = run.system.n
    fig, axes = plt.subplots(n + 1, 1, figsize=(10, 1.7 * (n + 1) + 1.0), sharex=True,
                             squeeze=False)
    t = run.t
    ax = axes[0, 0]
    seen: dict[str, bool] = {}
    _decorate(ax, run, t, None, seen)
    ax.semilogy(t, np.maximum(run.qb["V"], 1e-12), lw=0.9, color="C0",
                label="V(e) = e' P e (true error)")
    ax.axhline(1.0, color="C1", lw=1.4, label="QB bound V = 1 (ellipsoid)")
    ax.set_ylabel("e' P e [-]")
    ax.grid(True, alpha=0.3, which="both")
    for j, s in enumerate(run.system.states):
        ax = axes[j + 1, 0]
        seen = {}
        _decorate(ax, run, t, None, seen)
        ax.plot(t, np.abs(run.qb["error"][:, j]), lw=0.8, color="C2",
                label="|e_j| (true state minus estimate)")
        ax.axhline(float(run.qb["component_bound"][j]), color="C3", lw=1.4,
                   label="component bound sqrt((P^-1)_jj)")
        ax.set_yscale("log")
        ax.set_ylabel(f"|e_{s}| [-]")
        ax.grid(True, alpha=0.3, which="both")
    axes[-1, 0].set_xlabel("time [s]")
    _legend(fig, axes, f"{Path(run.bag).name}: QB error ellipsoid bound against the "
                       f"estimation error (eq. 6)")
    return _save(fig, path)


def _legend(fig: Any, axes: Any, title: str) -> None:
    """One legend for the whole figure, under the title (never over the data)."""
    seen: dict[str, Any] = {}
    for ax in np.ravel(axes):
        for h, lab in zip(*ax.get_legend_handles_labels()):
            seen.setdefault(lab, h)
    ncol = min(len(seen), 4 if max(map(len, seen), default=0) < 28 else 3) or 1
    rows = -(-len(seen) // ncol)
    h = float(fig.get_figheight())
    fig.suptitle(title, y=1 - 0.12 / h)
    fig.legend(list(seen.values()), list(seen), loc="upper center", ncol=ncol, fontsize=8,
               bbox_to_anchor=(0.5, 1 - 0.42 / h), frameon=False)
    fig.tight_layout(rect=(0, 0, 1, 1 - (0.5 + 0.2 * rows) / h))


def _save(fig: Any, path: str | Path) -> Path:
    p = Path(path)
    fig.savefig(p, dpi=110)
    _plt().close(fig)
    return p


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v)


def _md_table(rows: Sequence[Sequence[Any]], header: Sequence[str]) -> list[str]:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(_fmt(c) for c in r) + " |" for r in rows]
    return out


def bag_report(bag: str | Path, out_dir: str | Path, gains: str | Path | None = None, *,
               transient: float | None = None, expected: str | Path | None = None,
               system: str | Path | None = None, adapter: str | Path | None = None
               ) -> dict[str, Any]:
    """Figures and ``summary.md`` of one bag.

    Parameters
    ----------
    bag : str or pathlib.Path
        Bag folder.
    out_dir : str or pathlib.Path
        Created if needed.
    gains : str or pathlib.Path, optional
        Gain file; default the ``gains`` named by the bag's ``expected.yaml``.
    transient : float, optional
        s; default the ``expected.yaml``'s (0 without one).
    expected : str or pathlib.Path, optional
        Expected results to check; default ``<bag>/expected.yaml`` when it exists.
    system : str or pathlib.Path, optional
        Plant file or shipped name; default the gain file's plant
        (:func:`fd_monitor.model.gains.gain_system`).
    adapter : str or pathlib.Path, optional
        Adapter file: read u and y from the robot's own topics
        (:func:`fd_monitor.wire.adapters.read_adapted`), as ``analyze --adapter``.

    Returns
    -------
    dict
        ``summary`` (the analysis summary), ``figures`` (paths), ``summary_md`` (path),
        ``expected_failures`` (list, or None without expectations).
    """

    bagp = Path(bag)
    if not bagp.exists():
        raise BagError(f"{bagp}: no such bag")
    exp_doc = None
    exp_file = Path(expected) if expected is not None else expected_path(bagp)
    if exp_file.is_file():
        exp_doc = load_expected(exp_file)
    elif expected is not None:
        raise FdMonitorError(f"{exp_file}: expected results not found")
    if gains is None:
        if exp_doc is None or "gains" not in exp_doc:
            raise FdMonitorError(f"{bagp}: no --gains given and no expected.yaml naming them")
        gains = str(exp_doc["gains"])
    if transient is None:
        transient = float(exp_doc.get("transient", 0.0)) if exp_doc else 0.0
    plant = None
    if system is not None:
        plant = gain_system(load_gains(gains, verify=False), system)
    run = run_bag(bagp, gains, transient=transient, system=plant, adapter=adapter)
    summary = summarize_run(run)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    figs = {"residuals": figure_residuals(run, out / "residuals.png"),
            "modes": figure_modes(run, out / "modes.png"),
            **({"bias": figure_bias(run, out / "bias.png")} if run.estimate else {})}
    if "V" in run.qb:
        figs["qb_bound"] = figure_qb_bound(run, out / "qb_bound.png")
    fails = check_expected(exp_doc, summary) if exp_doc is not None else None
    md = _bag_markdown(run, summary, figs, fails, exp_file if exp_doc is not None else None,
                       adapter)
    (out / "summary.md").write_text(md, encoding="utf-8")
    return {"summary": summary, "figures": {k: str(v) for k, v in figs.items()},
            "summary_md": str(out / "summary.md"), "expected_failures": fails,
            "integrity": run.integrity}


def _bag_markdown(run: Any, s: Mapping[str, Any], figs: Mapping[str, Path],
                  fails: list[str] | None, exp_file: Path | None,
                  adapter: str | Path | None = None) -> str:
    dt = float(run.system.sample_time)
    lines = [f"# Report: bag `{Path(run.bag).resolve()}`", "",
             f"Plant `{run.system.name}`, gain file `{run.gains}` (method `{run.method}`), "
             f"{s['samples']} samples at Ts = {dt:g} s"
             + (f", transient {run.transient:g} s not evaluated" if run.transient else "")
             + " (the offline run of `python -m fd_monitor analyze`: "
               "`fd_monitor.analysis.offline.run_bag`)"
             + (f"; u and y read from the robot's topics through adapter `{adapter}`."
                if adapter is not None else "."), ""]
    onsets = _onsets(run)
    alarms = {a["channel"]: a for a in s["alarms"]}
    rows = []
    for c in run.channels:
        a = alarms.get(c)
        rows.append([c, "-" if a is None else a["first_sample"],
                     "-" if a is None else f"{a['first_sample'] * dt:.2f}",
                     "yes" if c in s.get("isolated", []) else "no",
                     _fmt(float(s["bias_estimate"][c])) if c in s["bias_estimate"] else "-"])
    lines += ["## Summary", ""]
    lines += _md_table(rows, ["channel", "first alarm (sample)", "first alarm (s)", "isolated",
                              "final bias estimate"])
    lines += ["", "- fault onsets (truth): " + (", ".join(
        f"{n} at {t:.2f} s" for n, t in onsets) or "none (fault free)"),
        f"- estimated mode sequence: {' -> '.join(s.get('modes', []))}"]
    if run.integrity:           # the bag-reading contract (fd_monitor.analysis.integrity)
        from fd_monitor.wire.input_checks import describe

        lines.append(f"- input integrity: {describe(run.integrity)}")
    if s.get("input_errors"):
        lines.append("- input errors: " + "; ".join(
            f"{k}: {v}" for k, v in s["input_errors"].items()))
        lines.append(f"- monitor restarts at samples: {s.get('restarts', [])}; bridged holes "
                     f"(memory kept) at samples: {s.get('bridges', [])}")
    if fails is not None:
        lines += ["", f"## Expected results (`{exp_file}`)", ""]
        lines += ["All expectations hold."] if not fails else \
            ["**FAILED:**", ""] + [f"- {f}" for f in fails]
    titles = {"residuals": "Residuals and thresholds", "modes": "Modes",
              "bias": "Bias estimates", "qb_bound": "QB error ellipsoid bound"}
    lines += ["", "## Figures", ""]
    for k, p in figs.items():
        lines += [f"### {titles.get(k, k)}", "", f"![{k}]({Path(p).name})", ""]
    return "\n".join(lines)


# --------------------------------------------------------------------------------------
# campaigns


def _magnitude(sc: Any) -> float | None:
    return float(abs(sc.faults[0].magnitude)) if sc.faults else None


def campaign_report(rows: Sequence[Any], scenarios: Sequence[Any], out_dir: str | Path, *,
                    gains: str = "", transient: float = 0.0) -> dict[str, Any]:
    """Figures and ``summary.md`` of a Monte Carlo campaign.

    Parameters
    ----------
    rows : sequence of fd_monitor.analysis.evaluate.CampaignRow
    scenarios : sequence of Scenario
        The campaign's scenarios (their first fault's magnitude is the x axis).
    out_dir : str or pathlib.Path
    gains : str
        Gain file (for the title).
    transient : float
        s (for the text).

    Returns
    -------
    dict
        ``figures`` and ``summary_md`` paths.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    by_name = {sc.name: sc for sc in scenarios}
    figs: dict[str, Path] = {}
    if any(r.detection_rate is not None for r in rows):
        figs["detection"] = _detection_figure(rows, by_name, gains, out / "detection.png")
    figs["false_alarms"] = _false_alarm_figure(rows, out / "false_alarms.png")
    md = _campaign_markdown(rows, by_name, figs, gains, transient)
    (out / "summary.md").write_text(md, encoding="utf-8")
    return {"figures": {k: str(v) for k, v in figs.items()},
            "summary_md": str(out / "summary.md")}


def _detection_figure(rows: Sequence[Any], by_name: Mapping[str, Any], gains: str,
                      path: Path) -> Path:
    """Detection rate and delay against the fault magnitude, a line per variant (and rho,
    and fault profile)."""
    plt = _plt()
    series: dict[str, list[Any]] = {}
    for r in rows:
        sc = by_name.get(r.scenario)
        prof = f" ({sc.faults[0].profile})" if sc is not None and sc.faults else ""
        key = r.variant + ("" if r.rho is None else f", rho={r.rho:g}") + prof
        series.setdefault(key, []).append(r)
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4))
    for key, rs in series.items():
        pts = sorted(((_magnitude(by_name[r.scenario]) or 0.0, r) for r in rs
                      if r.detection_rate is not None and r.scenario in by_name),
                     key=lambda p: p[0])
        if not pts:
            continue
        x = [p[0] for p in pts]
        a1.plot(x, [100 * p[1].detection_rate for p in pts], "o-", label=key)
        dm = [np.nan if p[1].delay_mean_s is None else p[1].delay_mean_s for p in pts]
        dx = [np.nan if p[1].delay_max_s is None else p[1].delay_max_s for p in pts]
        line, = a2.plot(x, dm, "o-", label=f"{key} mean")
        a2.plot(x, dx, "v--", color=line.get_color(), alpha=0.7, label=f"{key} max")
    a1.set_xlabel("fault magnitude |delta| [fault channel unit]")
    a1.set_ylabel("detection rate [%]")
    a1.set_ylim(-5, 105)
    a1.set_title("detection rate against fault magnitude")
    a2.set_xlabel("fault magnitude |delta| [fault channel unit]")
    a2.set_ylabel("detection delay [s]")
    a2.set_title("detection delay (detected runs)")
    for a in (a1, a2):
        a.grid(True, alpha=0.3)
        a.legend(fontsize=7)
    fig.suptitle(f"Monte Carlo campaign {gains}")
    fig.tight_layout()
    return _save(fig, path)


def _false_alarm_figure(rows: Sequence[Any], path: Path) -> Path:
    """False-alarm rate per scenario and variant (bars), or against the threshold scale rho
    (a sweep)."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(10, 4))
    rhos = sorted({r.rho for r in rows if r.rho is not None})
    if len(rhos) > 1:
        for sc_name in dict.fromkeys(r.scenario for r in rows):
            for var in dict.fromkeys(r.variant for r in rows):
                rs = sorted((r for r in rows if r.scenario == sc_name and r.variant == var
                             and r.rho is not None), key=lambda r: r.rho)
                if rs:
                    ax.plot([r.rho for r in rs], [100 * r.false_alarm_rate for r in rs], "o-",
                            label=f"{sc_name} ({var})")
        ax.set_xscale("log")
        ax.set_xlabel("threshold scale rho [-]")
        ax.set_title("false-alarm rate against the threshold scale")
    else:
        labels = [f"{r.scenario}\n{r.variant}" for r in rows]
        bars = ax.bar(range(len(rows)), [100 * r.false_alarm_rate for r in rows], color="C3",
                      label="runs with a false alarm")
        ax.bar_label(bars, [f"{100 * r.false_alarm_rate:.1f} % of {r.runs}" for r in rows],
                     fontsize=8)
        ax.set_xticks(range(len(rows)), labels, fontsize=7)
        ax.set_xlabel("scenario / variant")
        ax.set_title("false-alarm rate (any alarm before the fault onset)")
        ax.set_ylim(0, max(5.0, 110 * max((r.false_alarm_rate for r in rows), default=0)))
    ax.set_ylabel("false-alarm rate [%]")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    return _save(fig, path)


def _campaign_markdown(rows: Sequence[Any], by_name: Mapping[str, Any],
                       figs: Mapping[str, Path], gains: str, transient: float) -> str:
    """``summary.md`` of a campaign: the metrics table and the figures."""
    table = []
    for r in rows:
        mag = _magnitude(by_name[r.scenario]) if r.scenario in by_name else None
        table.append([r.scenario, "-" if mag is None else f"{mag:g}", r.variant,
                      "-" if r.rho is None else f"{r.rho:g}", r.runs,
                      f"{100 * r.false_alarm_rate:.1f}",
                      "-" if r.detection_rate is None else f"{100 * r.detection_rate:.1f}",
                      "-" if r.delay_mean_s is None else f"{r.delay_mean_s:.2f}",
                      "-" if r.delay_median_s is None else f"{r.delay_median_s:.2f}",
                      "-" if r.delay_max_s is None else f"{r.delay_max_s:.2f}"])
    lines = [f"# Monte Carlo campaign: `{gains}`", "",
             f"{rows[0].runs if rows else 0} runs per scenario; alarms before "
             f"{transient:g} s ignored. False alarm: any alarm before the fault onset (the "
             f"whole run when fault free); detection: an alarm at or after the onset; delay: "
             f"first alarm minus onset over the detected runs.", ""]
    lines += _md_table(table, ["scenario", "magnitude", "variant", "rho", "runs",
                               "false alarms %", "detected %", "delay mean s",
                               "delay median s", "delay max s"])
    lines += ["", "## Figures", ""]
    for k, p in figs.items():
        lines += [f"![{k}]({p.name})", ""]
    return "\n".join(lines)
