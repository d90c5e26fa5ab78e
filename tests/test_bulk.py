"""Bulk phase change (tankode.bulk): its rate law, the balances with it on, and a foreign vent."""

import math
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch

from tankode.analytic import AnalyticFluid, analytic_state
from tankode.bulk import BulkPhaseChange
from tankode.closures import ConstantClosure
from tankode.forcing import Forcing
from tankode.geometry import geometry_from_spec
from tankode.integrate import integrate, state_scale
from tankode.model import TankModel
from tankode.solver import AdaptiveRK, NoGradient

NODAL_SIM = Path(__file__).resolve().parent / "nodal_sim.py"


def _phases(T_v, T_l, T_sat=21.0):
    one = torch.ones(1, dtype=torch.float64)
    pv = SimpleNamespace(T=T_v * one, T_sat=T_sat * one, cp=1.2e4 * one, h_vsat=4.5e5 * one, h_lsat=1.0e3 * one)
    pl = SimpleNamespace(T=T_l * one, cp=9.7e3 * one)
    return pv, pl


@pytest.mark.parametrize("threshold", [0.05, 0.2, 1.0])
def test_a_phase_at_saturation_does_not_change_phase_whatever_the_threshold(threshold):
    bulk = BulkPhaseChange(flash_threshold_K=threshold, fog_threshold_K=threshold)
    m = torch.tensor([100.0], dtype=torch.float64)
    fog, flash = bulk.rates_kg_s(m, m, *_phases(21.0, 21.0))
    # The softplus tail at saturation: width * exp(-1/onset_share), in kelvin of excess.
    tail_K = bulk.onset_share * threshold * math.exp(-1.0 / bulk.onset_share)
    for J, cp in ((fog, 1.2e4), (flash, 9.7e3)):
        excess_K = float(J) * (4.5e5 - 1.0e3) * bulk.tau_s / (100.0 * cp)
        assert excess_K == pytest.approx(tail_K, rel=1e-3)


def test_the_rate_relaxes_the_excess_past_each_threshold_with_tau():
    bulk = BulkPhaseChange()
    m_v, m_l = torch.tensor([5.0], dtype=torch.float64), torch.tensor([200.0], dtype=torch.float64)
    L = 4.5e5 - 1.0e3
    fog, flash = bulk.rates_kg_s(m_v, m_l, *_phases(21.0 - bulk.fog_threshold_K - 0.4, 21.0 + bulk.flash_threshold_K + 0.3))
    def excess(x, threshold):  # softplus of width onset_share * threshold: x plus its smooth onset
        w = bulk.onset_share * threshold
        return w * math.log1p(math.exp(x / w))

    assert float(fog) == pytest.approx(5.0 * 1.2e4 * excess(0.4, bulk.fog_threshold_K) / (L * bulk.tau_s), rel=1e-9)
    assert float(flash) == pytest.approx(200.0 * 9.7e3 * excess(0.3, bulk.flash_threshold_K) / (L * bulk.tau_s), rel=1e-9)
    assert excess(0.3, bulk.flash_threshold_K) == pytest.approx(0.3, rel=1e-6)  # past the onset: linear
    # The liquid flashes at a smaller excess than the vapour fogs (the module's reasons).
    assert bulk.flash_threshold_K < bulk.fog_threshold_K


@pytest.mark.parametrize("field", ["flash_threshold_K", "fog_threshold_K", "tau_s", "onset_share"])
def test_bad_constants_are_named(field):
    with pytest.raises(ValueError, match=field):
        BulkPhaseChange(**{field: 0.0})


def test_a_superheated_closed_tank_flashes_to_the_threshold_and_conserves_mass_and_energy():
    fluid = AnalyticFluid()
    geom = geometry_from_spec({"shape": "vertical_cylinder", "radius_m": 0.9, "height_m": 2.2})
    bulk = BulkPhaseChange()
    probe = analytic_state(fluid, geom, 2e5, 30.0, 20.0, 25.0, 0.6)[0]
    T_sat = float(fluid.vapor(probe[2:3], probe[0:1] / probe[5:6]).T_sat)
    s0 = analytic_state(fluid, geom, 2e5, 30.0, T_sat + 1.5, 25.0, 0.6)
    # Exchange switched off (tiny coefficients) so only the bulk relaxation acts.
    closure = ConstantClosure([1e-6, 1e-6, 1e-6, 1e-6])
    t = torch.linspace(0.0, 300.0, 31, dtype=torch.float64)
    out = {}
    for name, b in (("on", bulk), ("off", None)):
        model = TankModel(fluid, geom, closure, 2e5, bulk=b)
        states, _ = integrate(model, s0, [(0.0, 300.0)], lambda t0, s: Forcing.rest(1), t,
                              state_scale(s0, geom.volume_m3), AdaptiveRK(rtol=1e-10, atol=1e-12), NoGradient())
        s = states[0]
        pv = fluid.vapor(s[:, 2], s[:, 0] / s[:, 5])
        pl = fluid.liquid(s[:, 3], s[:, 1] / s[:, 6])
        out[name] = (s, model, pl.T - pv.T_sat)
    s, model, superheat = out["on"]
    assert float(out["off"][2][0]) > 1.0  # the start is superheated well past the threshold...
    assert float(out["off"][2][-1]) > 1.0  # ...and without bulk phase change it stays so
    # With it, the excess past the threshold is gone within a few tau (faster than tau: the flash
    # vapour raises the pressure and the saturation temperature), and the liquid stays superheated
    # below the threshold (the smooth onset's tail flashes on slowly; it never over-flashes).
    assert 0.0 < float(superheat[1]) <= bulk.flash_threshold_K * (1 + bulk.onset_share)
    assert 0.0 < float(superheat[-1]) < float(superheat[1])
    mass = s[:, 0] + s[:, 1]
    assert float((mass - mass[0]).abs().max() / mass[0]) < 1e-9
    E = model.total_energy_J(s[None])[0]
    assert float((E - E[0]).abs().max() / (mass[0] * 4.46e5)) < 1e-8
    assert float(s[-1, 0] - s[0, 0]) > 0.1  # vapour gained the flashed mass


def _vent_plateau_error_Pa(run, bulk):
    from trainers.assimilate import AssimilationConfig, Assimilator

    a = Assimilator([run], AssimilationConfig(boiling="bulk"))  # the bulk's flash alone
    a.model.bulk = bulk
    t = torch.arange(2400.0, 2701.0, 60.0, dtype=torch.float64)
    with torch.no_grad():
        states = a.predict(a.s0, 0.0, torch.cat([torch.zeros(1, dtype=torch.float64), t]), NoGradient())
        p_model = a.model.observe(states[:, 1:])[0, :, 0]
    tt, p = run.observations.channel("p_v_Pa")
    tt, p = torch.as_tensor(tt), torch.as_tensor(p)
    p_data = torch.stack([p[(tt - ti).abs().argmin()] for ti in t])
    return float((p_model - p_data).abs().max())


def test_a_foreign_sphere_vent_levels_off_on_the_liquid_boiling(tmp_path):
    """Another simulator's vent (tests/nodal_sim.py, McAdams truth): its liquid boils as the
    pressure falls and the pressure levels off; the untrained model follows it only with the
    liquid flashing at a small superheat (the data's last 5 minutes of venting)."""
    from tankode.run_io import read_run

    subprocess.run([sys.executable, str(NODAL_SIM), "sphere_4m3", "--law", "mcadams", "--out", str(tmp_path),
                    "--name", "sphere", "--noise", "low", "--seed", "5", "--duration", "2800"],
                   check=True, capture_output=True, text=True)
    run = read_run(tmp_path / "sphere.json")
    default = _vent_plateau_error_Pa(run, BulkPhaseChange())
    late = _vent_plateau_error_Pa(run, BulkPhaseChange(flash_threshold_K=1.0))
    assert default < 1.2e4 and late > 2.0e4, (default, late)


def test_a_liquid_under_an_inert_gas_boils_at_the_total_pressure_not_the_partial_one():
    """The interface sits at saturation of the fluid's partial pressure (Dalton), but a bubble in the
    liquid's bulk holds the fluid alone against the total pressure: a liquid 1 K past saturation at
    its fluid's pressure and 0.3 K below saturation at the total does not flash under the inert gas,
    and does without it. The boiling point is the fluid's saturation at the total pressure."""
    from tankode.mechanisms import make_mechanism
    from tankode.mechanisms.noncondensable import R_J_PER_MOLK

    fluid = AnalyticFluid()
    geom = geometry_from_spec({"shape": "vertical_cylinder", "radius_m": 0.9, "height_m": 2.2})
    probe = analytic_state(fluid, geom, 2e5, 30.0, 20.0, 25.0, 0.6)[0]
    pv0 = fluid.vapor(probe[2:3], probe[0:1] / probe[5:6])
    T_l = float(pv0.T_sat) + 1.0
    lo, hi = 2e5, 2e6  # the total pressure whose saturation is T_l + 0.3 K
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if float(fluid.saturation_K(torch.tensor([mid], dtype=torch.float64))) < T_l + 0.3 else (lo, mid)
    n_mol = (lo - float(pv0.p)) * float(probe[5]) / (R_J_PER_MOLK * float(pv0.T))
    s0 = analytic_state(fluid, geom, 2e5, 30.0, T_l, 25.0, 0.6)
    closure = ConstantClosure([1e-6, 1e-6, 1e-6, 1e-6])  # only the bulk relaxation acts
    t = torch.linspace(0.0, 300.0, 31, dtype=torch.float64)
    gained = {}
    for name, mechanisms in (("inert", (make_mechanism("noncondensable_gas", n_mol=n_mol),)), ("pure", ())):
        model = TankModel(fluid, geom, closure, 2e5, mechanisms)
        states, _ = integrate(model, s0, [(0.0, 300.0)], lambda t0, s: Forcing.rest(1), t,
                              state_scale(s0, geom.volume_m3), AdaptiveRK(rtol=1e-10, atol=1e-12), NoGradient())
        gained[name] = float(states[0, -1, 0] - states[0, 0, 0])
        if name == "inert":
            pv = fluid.vapor(s0[:, 2], s0[:, 0] / s0[:, 5])
            assert float(model.boiling_point_K(pv, s0[:, 5])) == pytest.approx(T_l + 0.3, abs=1e-6)
    assert gained["pure"] > 0.1  # kg flashed in 300 s
    assert abs(gained["inert"]) < 1e-3 * gained["pure"]


def test_with_another_simulators_own_coefficients_the_boiling_liquid_holds_its_pressure(tmp_path):
    """Physics outside the closure, on data tankode did not write: ``tests/nodal_sim.py`` with
    constant coefficients (its ``law="constant"``), simulated by tankode with the same four
    coefficients, its two-node wall and the whole liquid boiling at saturation (the other
    simulator's liquid flashes from saturation on). Through a pressurisation, a hold, a vent and
    sloshing the pressure stays within a sensor sigma (300 Pa) of the data; a boiling threshold
    of 0.05 K past saturation puts it 2-3 sigma low for the hour (the liquid must superheat that
    much, about 2 kPa of LH2 saturation pressure, before it boils)."""
    import tankode.mechanisms.saturated_boiling as sb
    from tankode.closures import MLPClosure, MLPConfig
    from tankode.mechanisms import make_mechanism
    from tankode.run_io import read_run
    from trainers.assimilate import AssimilationConfig, Assimilator
    from trainers.evaluate import rmse_sigmas

    subprocess.run([sys.executable, str(NODAL_SIM), "sphere_cycles", "--law", "constant", "--out", str(tmp_path),
                    "--name", "sphere", "--noise", "none", "--duration", "1500"],
                   check=True, capture_output=True, text=True)
    run = read_run(tmp_path / "sphere.json")
    # nodal_sim's h_constant (wv, wl, vi, li) = (20, 100, 5, 100) W/(m2 K) in tankode's order; its
    # wall conductance k t L_c / (H/2) as tankode's sheet resistance 2 L_c / (k t A_w / (H/2)).
    agent = MLPClosure(MLPConfig(base="constant", h_ref_W_m2K=(5.0, 100.0, 20.0, 100.0)))
    t = torch.arange(0.0, 1500.0, 15.0, dtype=torch.float64)

    def p_error_sigmas(threshold_K):
        saved = sb.SaturatedBoiling._BOILING
        sb.SaturatedBoiling._BOILING = BulkPhaseChange(flash_threshold_K=threshold_K)
        try:
            a = Assimilator([run], AssimilationConfig(boiling_share=0.99), closure=agent,
                            mechanisms=(make_mechanism("two_node_wall", R_sheet_K_per_W=6.4, start_share=0.0),))
            with torch.no_grad():
                obs = a.model.observe(a.predict(a.start_state(), 0.0, t, NoGradient()))
        finally:
            sb.SaturatedBoiling._BOILING = saved
        return rmse_sigmas(run, t, obs, 0.0, 1500.0)["p_v_Pa"]

    new, old = p_error_sigmas(sb.THRESHOLD_K), p_error_sigmas(0.05)
    assert new < 1.0 < 2.0 < old, (new, old)
