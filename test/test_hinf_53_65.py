"""Thesis (Armeni) Sec. 5.3 (uncertain rho, vertex LMIs 5.45/5.50) and Sec. 6.5 (LPV, common
P and affine L(rho), LMIs 6.40): banks of two generators isolating overlapping actuator steps
at 30 s and 60 s while rho varies (5.3: rho(t) = sin(2 pi t); 6.5: rho1 = sin(0.62832 t),
rho2 = 0.4 cos(0.3142 t), see the plant file for the reading of 6.85)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("cvxpy")

from fd_monitor.core.freq import sigma
from fd_monitor.core.hinf_model import generator_ss, parse_bank
from fd_monitor.core.methods import load_gains
from fd_monitor.core.residual_bank import ResidualBank
from fd_monitor.model.system import load_system

GAINS = Path(__file__).resolve().parent.parent / "config" / "gains"
RHO = {
    "thesis_5_3": lambda t: np.array([np.sin(2 * np.pi * t)]),
    "thesis_6_5": lambda t: np.array([np.sin(0.62832 * t), 0.4 * np.cos(0.3142 * t)]),
}
#: Fixed thresholds (output units) for the simulations: the uncertainty-induced residual of
#: 5.3 with these inputs peaks near 0.011 (not bounded by 5.45, which attenuates the nuisance
#: fault only); the faults give ||H C F||/|lambda| ~ 0.7 and ~1.
THRESHOLD = 0.1


@pytest.mark.parametrize("name, kind", [("thesis_5_3", "uncertain"), ("thesis_6_5", "lpv")])
def test_design_takes_lpv_data_from_plant_and_verifies(name, kind, shipped_design):
    s = load_system(name)
    out = shipped_design(name, "hinf_sc")
    assert out["results"]["kind"] == kind
    _k, model, _gens = parse_bank(out["results"])
    np.testing.assert_array_equal(model.A_rho, s.modes[0].A_rho)
    assert model.rho_names == tuple(p.name for p in s.lpv)
    gf = load_gains(GAINS / f"{name}_hinf_sc.yaml", s)
    assert gf.certificate_status == "verified"


@pytest.mark.parametrize("name", ["thesis_5_3", "thesis_6_5"])
def test_singular_values_fig_5_1_to_5_3_and_6_1_to_6_3(name):
    """The nuisance fault is rejected at every frozen rho of the box (and at the figures'
    rho values), the own fault passes with its zero-frequency gain ||H C F|| / |lambda|."""
    s = load_system(name)
    gf = load_gains(GAINS / f"{name}_hinf_sc.yaml", s)
    _k, model, gens = parse_bank(gf.results)
    rhos = ([np.array([r]) for r in (0.0, 1.0, -1.0)] if name == "thesis_5_3" else
            [np.array(r) for r in ([0.5, 0.2], [-1.0, -0.2], [1.0, -0.4])])
    w = np.logspace(-3, 3, 120)
    p = model.C.shape[0]
    for i, g in enumerate(gens):
        own, other = model.B0[:, [i]], model.B0[:, [1 - i]]
        for rho in rhos:
            s_own = sigma(*generator_ss(model, g, own, np.zeros((p, 1)), rho), w)[:, 0]
            s_oth = sigma(*generator_ss(model, g, other, np.zeros((p, 1)), rho), w)[:, 0]
            dc = np.linalg.norm(g.H @ model.C @ own) / abs(g.lam)
            if g.kind == "lpv" or not rho.any():
                # eigenvector at every frozen rho (4.37); uncertain: at the nominal rho = 0
                assert s_own[0] == pytest.approx(dc, rel=1e-3)
            else:
                # 5.3: rho moves the plant off the observer's A0, so the own fault's gain
                # changes (the thesis' additional fault F_a2 = A1 F2, 5.66): measured 0.22 dc
                # for r2 at rho = +-1; still far above the rejected nuisance
                assert s_own[0] > 0.1 * dc
            assert s_oth.max() < 1e-3 * dc, (g.fault, rho)


@pytest.mark.parametrize("name", ["thesis_5_3", "thesis_6_5"])
def test_overlapping_steps_isolated_with_varying_rho(name, scenario_run):
    s = load_system(name)
    gf = load_gains(GAINS / f"{name}_hinf_sc.yaml", s)
    kind, _model, _g = parse_bank(gf.results)
    # the scenario: these inputs, RHO[name], unit actuator steps at 30 s and 60 s
    tr = scenario_run(f"{name}_overlap")             # simulate(load_scenario(...))
    t, y, u, rho = tr.t, tr.y[0], tr.u[0], tr.rho[0]
    np.testing.assert_allclose(rho, np.array([RHO[name](tt) for tt in t]), atol=1e-4)
    bank = ResidualBank(s, gf, thresholds=[THRESHOLD, THRESHOLD])
    r = bank.run(u, y, rho if kind == "lpv" else None)   # uncertain: rho is not measured
    al = r > bank.thresholds
    assert not al[t < 30].any()
    assert al[(t > 35), 0].all()                       # f1 from 30 s, r1 only ...
    assert not al[t < 60, 1].any()                     # ... r2 silent while only f1 acts
    assert al[(t > 65), 1].all()                       # f2 from 60 s: r2
    assert r[t > 35, 0].max() - r[t > 35, 0].min() < 0.05   # r1 is blind to f2 (overlap)
