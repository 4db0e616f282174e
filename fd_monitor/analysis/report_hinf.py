"""Singular-value plots of residual generators (matplotlib, Agg backend).

``design hinf_sc ... --plot DIR`` and ``design hminus_switched ... --plot DIR`` call these:
fault -> residual and nuisance -> residual maps (thesis Fig. 4.4, 5.1-5.4, 7.4-7.6;
Farhat & Koenig Fig. 3) and mu(lambda) (thesis Fig. 4.2-4.3, 7.1-7.3, 7.8).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from fd_monitor.core.freq import sigma_db
from fd_monitor.core.generalized_observer import residual_ss
from fd_monitor.core.hinf_model import generator_ss, parse_bank
from fd_monitor.model.system import System

__all__ = ["plot_bank", "plot_switched"]

OMEGA = np.logspace(-3, 3, 400)


def _fault_inputs(system: System, results: Mapping[str, Any]) -> dict[str, tuple[np.ndarray,
                                                                                np.ndarray]]:
    """Per generator fault: (B_in (n,1), D_in (p,1)): the first column of its direction."""
    out = {}
    _kind, model, gens = parse_bank(results)
    for g in gens:
        out[g.fault] = (g.V[:, :1], np.zeros((model.C.shape[0], 1)))
    for f in system.faults:
        if f.kind == "sensor_bias" and f.name in out:
            E = np.zeros((model.C.shape[0], 1))
            E[f.index, 0] = 1.0
            out[f.name] = (np.zeros((model.n, 1)), E)
    return out


def _label(ax: Any, title: str, xlabel: str, ylabel: str) -> None:
    """Title, axis labels and a log grid."""
    ax.set_title(title)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(True, which="both", alpha=0.3)


def _save(fig: Any, path: Path) -> Path:
    """Lay out, write (PNG, 110 dpi) and close a figure."""
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_bank(system: System, results: Mapping[str, Any], outdir: str | Path) -> list[Path]:
    """One figure per generator (sigma of every fault -> r_i) and one of mu(lambda)."""
    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    kind, model, gens = parse_bank(results)
    ins = _fault_inputs(system, results)
    rhos = [None] if kind == "lti" else [model.rho_min, 0.5 * (model.rho_min + model.rho_max),
                                          model.rho_max]
    files = []
    for g in gens:
        fig, ax = plt.subplots(figsize=(6.4, 4.2))
        for rho in rhos:
            tag = "" if rho is None else f", rho={np.round(rho, 3).tolist()}"
            for name, (Bi, Di) in ins.items():
                A, B, C, D = generator_ss(model, g, Bi, Di, rho)
                s = sigma_db(A, B, C, D, OMEGA)[:, 0]
                ls = "-" if name == g.fault else "--"
                ax.semilogx(OMEGA, s, ls, label=f"{name} -> r_{g.fault}{tag}")
        _label(ax, f"{system.name}: residual generator for {g.fault} (lambda = {g.lam:g})",
               "frequency omega (rad/s)", "singular value (dB)")
        ax.legend(fontsize=7)
        files.append(_save(fig, out / f"{system.name}_sigma_{g.fault}.png"))
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for g in results["generators"]:
        mg = g.get("mu_grid") or {}
        lam = np.asarray(mg.get("lambda", []), dtype=float)
        mu = np.asarray(mg.get("mu", []), dtype=float)
        if lam.size > 1:
            ax.semilogy(lam, mu, "o-", ms=3, label=f"mu_{g['fault']}")
        elif lam.size == 1:  # a fixed lambda (no grid): one point per generator
            ax.semilogy(lam, mu, "s", label=f"mu_{g['fault']} (fixed lambda)")
    _label(ax, f"{system.name}: performance ratio mu(lambda) (4.35)", "lambda (1/s)",
           "mu (dimensionless)")
    if ax.get_lines():
        ax.legend()
    files.append(_save(fig, out / f"{system.name}_mu.png"))
    return files


def plot_switched(system: System, results: Mapping[str, Any], outdir: str | Path
                  ) -> list[Path]:
    """sigma_min of T_rf per mode, every stored design on one panel per mode (F & K Fig. 3).

    ``stability`` (LMI 26 only, "SO" in the paper) and ``hminus`` (loop-shaped, "FDO") are
    drawn in dB over 1e-3 rad/s .. Nyquist, with the report frequencies marked.
    """
    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    dt = float(results["sample_time"])
    w = np.logspace(-3, np.log10(0.999 * np.pi / dt), 300)
    nm = len(system.modes)
    fig, axes = plt.subplots(1, nm, figsize=(5.2 * nm, 4.2), squeeze=False)
    styles = {"stability": ("--", "stability only (26), SO"),
              "hminus": ("-", "H-minus loop-shaped (44), FDO")}
    for i, ax in enumerate(axes[0]):
        for name, obs in results["observers"].items():
            A, B, C, D = residual_ss(obs, i)
            ls, lab = styles.get(name, (":", name))
            ax.semilogx(w, sigma_db(A, B, C, D, w, dt)[:, -1], ls, label=lab)
        for wk in (1e-3, 1e-2, 1e-1, 1.0):
            ax.axvline(wk, color="0.8", lw=0.6)
        _label(ax, f"{system.name}: T_rf, {system.modes[i].name}",
               "frequency omega (rad/s)", "minimum singular value (dB)")
        ax.legend(fontsize=8)
    return [_save(fig, out / f"{system.name}_trf.png")]
