"""Design-time thresholds of an H-infinity residual-generator bank (thesis 4.17).

Two ways to set the threshold of each generator of a ``hinf_sc`` bank: from the attenuation
bounds and stated signal levels (:func:`bound_thresholds`), or from the residuals of
fault-free simulated runs (:func:`monte_carlo_thresholds`, on the scenario
:func:`fault_free_scenario` loads; ``hminus_switched`` uses both too). numpy only.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from fd_monitor.model.errors import DesignError, ScenarioError
from fd_monitor.model.scenario import Scenario, load_scenario
from fd_monitor.model.system import System

__all__ = ["bound_thresholds", "fault_free_scenario", "monte_carlo_thresholds"]


def bound_thresholds(results: Mapping[str, Any], levels: Mapping[str, float],
                     margin: float = 1.0) -> np.ndarray:
    """Thresholds from the attenuation bounds and stated signal levels.

    ``J_i = margin * (gamma_nuis,i l_nuis + gamma_dist,i l_dist + gamma_noise,i l_noise)``,
    the bound (4.17) on the RMS of ``r_i`` when the nuisance faults, disturbances and noise
    have RMS levels ``l_*`` (an H-infinity norm bounds the RMS gain); ``margin`` covers the
    peak-to-RMS ratio of the residual.

    Returns
    -------
    numpy.ndarray
        (n_gen,) thresholds, output units.
    """
    out = []
    for g in results["generators"]:
        g2 = dict(g.get("gamma2") or {})
        out.append(margin * sum(np.sqrt(max(float(g2.get(k, 0.0)), 0.0))
                                * float(levels.get(k, 0.0))
                                for k in ("nuisance", "disturbance", "noise")))
    return np.asarray(out)


def monte_carlo_thresholds(norms: np.ndarray, settle: int = 0,
                           margin: float = 1.2) -> np.ndarray:
    """Thresholds from fault-free runs: ``margin * max |r_i|`` after ``settle`` samples.

    Parameters
    ----------
    norms : numpy.ndarray
        (runs, K, n_gen) residual norms of fault-free runs.
    """
    a = np.asarray(norms, dtype=float)
    if a.ndim == 2:
        a = a[None]
    return margin * a[:, settle:, :].max(axis=(0, 1))


def fault_free_scenario(ctx: Any, name: Any, system: System, origin: Any,
                        section: str) -> Scenario:
    """The fault-free scenario of a Monte Carlo threshold (``scenario`` of the design file's
    threshold ``section``); one-line errors naming the file and the key.

    Parameters
    ----------
    ctx : Checker
        The section's checker (:func:`fd_monitor.design._lmi_common.design_checker`).
    name : object
        The ``scenario`` value: a scenario name or path.
    """
    if not isinstance(name, str):
        ctx.fail("scenario", "a fault-free scenario name or path", name)
    try:
        sc = load_scenario(name, system)
    except ScenarioError as exc:
        raise DesignError(f"{origin}: {section}.scenario: {exc}") from None
    if sc.faults:
        ctx.fail("scenario", "a fault-free scenario (no faults)", name)
    return sc
