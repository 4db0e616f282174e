"""Farhat & Koenig Sec. V: generalized minimal-order observer of a switched plant."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

pytest.importorskip("cvxpy")

from fd_monitor.core.generalized_observer import (
    GeneralizedObserver,
    check_certificate,
    simulate_switched,
)
from fd_monitor.core.methods import load_gains
from fd_monitor.design import hminus_switched
from fd_monitor.design._lmi_common import load_design_section
from fd_monitor.model.errors import DesignError, GainFileError
from fd_monitor.model.gains import save_gains
from fd_monitor.model.system import load_system

CFG = Path(__file__).resolve().parent.parent / "config" / "systems"


@pytest.fixture(scope="module")
def system():
    return load_system("farhat_koenig")


@pytest.fixture(scope="module")
def out(shipped_design):
    return shipped_design("farhat_koenig", "hminus_switched")


def test_printed_E_is_reported_infeasible(system):
    """E = [[10, 10, 4], [-200, 1, -10]] as printed: LMI (26) has no solution."""
    sec, origin, _ = load_design_section(system, "hminus_switched",
                                         CFG / "farhat_koenig_printed.design.yaml")
    assert sec["E"] == [[10.0, 10.0, 4.0], [-200.0, 1.0, -10.0]]
    with pytest.raises(DesignError, match=r"LMI \(26\) is infeasible"):
        hminus_switched.design(system, sec, origin)


def test_observer_constraints_6a_6c(system, out):
    res = out["results"]
    T = np.asarray(res["T"])
    for m, pm in zip(res["observers"]["stability"]["modes"], system.modes):
        F, G, M, N = (np.asarray(m[k]) for k in ("F", "G", "M", "N"))
        np.testing.assert_allclose(F @ T + G @ pm.C, T @ pm.A, atol=1e-10)   # (6a)
        np.testing.assert_allclose(M @ T + N @ pm.C, np.eye(3), atol=1e-10)  # (6c)
        assert np.abs(np.linalg.eigvals(F)).max() < 1.0
    assert T.shape == (2, 3)  # q = 2 as printed (E is 2 x 3)


def test_error_converges_under_random_switching(system, out):
    """Fault-free (10): eps+ = F_i eps converges for arbitrary switching (LMI 26)."""
    obs = GeneralizedObserver(system, out["results"], design="stability")
    A = [m.A for m in system.modes]
    B = [m.B for m in system.modes]
    C = [m.C for m in system.modes]
    Ef = [np.zeros((3, 1))] * 2
    Ff = [np.zeros((2, 1))] * 2
    rng = np.random.default_rng(7)
    for trial in range(5):
        modes = rng.integers(0, 2, size=400)
        if trial == 0:
            modes = np.arange(400) % 2  # switch at every sample
        x, y = simulate_switched(A, B, C, Ef, Ff, modes, np.array([1.0, 2.0, 3.0]))
        obs.reset()
        xh, r = obs.run(np.zeros((400, 0)), y, modes)
        err = np.linalg.norm(x - xh, axis=1)
        assert err[0] > 0.1
        assert err[-50:].max() < 1e-6 * err[0]
        assert np.abs(r[-50:]).max() < 1e-6


def test_fault_raises_residual(system, out):
    obs = GeneralizedObserver(system, out["results"], design="stability")
    sec, _, _ = load_design_section(system, "hminus_switched")
    Ef = [np.asarray(sec["fault"]["E_f"][m.name]) for m in system.modes]
    Ff = [np.asarray(sec["fault"]["F_f"])] * 2
    modes = np.random.default_rng(3).integers(0, 2, size=600)
    f = np.zeros((600, 1))
    f[300:] = 1.0
    _x, y = simulate_switched([m.A for m in system.modes], [m.B for m in system.modes],
                             [m.C for m in system.modes], Ef, Ff, modes, np.zeros(3), f=f)
    _, r = obs.run(np.zeros((600, 0)), y, modes)
    nr = np.linalg.norm(r, axis=1)
    assert nr[:300].max() < 1e-12 and nr[300:].min() > 1e-3


def test_hminus_raises_low_frequency_sensitivity(out):
    """Loop-shaped H-minus design vs stability only: sigma_min(T_rf) at 0.001, 0.01, 0.1 rad/s
    up by >= 10 dB in both modes (measured ~ +12.9 / +16.4 dB; margin 10 dB)."""
    assert out["summary"]["hminus_status"] == "optimal"
    sm = out["summary"]["sigma_min_db"]
    freqs = hminus_switched.FREQS
    for m in ("mode1", "mode2"):
        for k, w in enumerate(freqs):
            if w <= 0.1:
                assert sm["hminus"][m][k] >= sm["stability"][m][k] + 10.0, (m, w)
    # independent numpy check on a grid below 0.1 rad/s (core/freq.py)
    from fd_monitor.core.freq import sigma
    from fd_monitor.core.generalized_observer import residual_ss

    res = out["results"]
    w = np.logspace(-3, -1, 25)
    for i in range(2):
        s_h = sigma(*residual_ss(res["observers"]["hminus"], i), w, 0.1)[:, -1]
        s_s = sigma(*residual_ss(res["observers"]["stability"], i), w, 0.1)[:, -1]
        assert (20 * np.log10(s_h / s_s)).min() >= 10.0


def test_hminus_certificate_and_switched_decrease(system, out):
    """LMI (26) with decay 0.98 for every mode pair (numpy eigenvalues, tol 0) and the
    per-mode H-minus inequality (44a) at beta^2 > 0 with an indefinite P_aug."""
    obs = out["results"]["observers"]["hminus"]
    rho = obs["hminus"]["decay_rate"]
    for mi in obs["modes"]:
        F, Pi = np.asarray(mi["F"]), np.asarray(mi["P"])
        assert np.linalg.eigvalsh(Pi).min() > 0
        for mj in obs["modes"]:
            Pj = np.asarray(mj["P"])
            assert np.linalg.eigvalsh(F.T @ Pi @ F - rho ** 2 * Pj).max() < 0
    assert out["certificate"]["hminus"]["lmi44a_max_eig"]
    assert max(out["certificate"]["hminus"]["lmi44a_max_eig"]) < 0
    assert obs["hminus"]["beta2"] > 1.0  # beta > 1 (weighted index, measured 1.95)
    assert min(np.linalg.eigvalsh(np.asarray(m["P_aug"])).min() for m in obs["modes"]) < 0


def test_hminus_error_converges_under_random_switching(system, out):
    """Fault-free: the H-minus observer's error converges for random / every-sample switching
    (decay <= 0.98 per step: 800 samples give < 1e-6 of the initial error)."""
    obs = GeneralizedObserver(system, out["results"], design="hminus")
    A = [m.A for m in system.modes]
    C = [m.C for m in system.modes]
    Ef, Ff = [np.zeros((3, 1))] * 2, [np.zeros((2, 1))] * 2
    rng = np.random.default_rng(11)
    for trial in range(4):
        modes = rng.integers(0, 2, size=1000) if trial else np.arange(1000) % 2
        x, y = simulate_switched(A, [m.B for m in system.modes], C, Ef, Ff, modes,
                                 np.array([1.0, 2.0, 3.0]))
        obs.reset()
        xh, _ = obs.run(np.zeros((1000, 0)), y, modes)
        err = np.linalg.norm(x - xh, axis=1)
        assert err[0] > 0.1
        assert err[-50:].max() < 1e-6 * err[0]


def test_gain_file_verifies_and_detects_tampering(system, out, tmp_path):
    p = save_gains(tmp_path / "fk.yaml", "hminus_switched", system, out["parameters"],
                   out["results"], out["certificate"], out["solver"])
    assert load_gains(p, system).certificate_status == "verified"
    doc = yaml.safe_load(p.read_text())
    doc["results"]["observers"]["stability"]["modes"][0]["F"][0][0] += 0.5
    with pytest.raises(GainFileError, match=r"\(6a\)"):
        check_certificate(system, doc["results"])


def test_bad_design_file_keys(system):
    with pytest.raises(DesignError, match=r"hminus_switched\.E: expected a rx3 matrix"):
        hminus_switched.design(system, {"E": [[1, 2]], "fault": {}}, "x.yaml")
    with pytest.raises(DesignError, match=r"A\.2 fails"):
        hminus_switched.design(system, {"E": [[1.0, 0.0, 0.0]], "fault": {
            "E_f": {"mode1": [[0], [0], [1]], "mode2": [[0], [0], [1]]}, "F_f": [[0], [0]]}},
            "x.yaml")
