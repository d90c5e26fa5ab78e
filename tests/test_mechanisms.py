"""Mechanisms: bounds, absent at 0, conservation with them as external inputs, sensor effects."""

import json
import math

import numpy as np
import pytest
import torch

from tankode import get_case, simulate
from tankode.analytic import AnalyticFluid, analytic_state
from tankode.closures import ReferenceClosure, ScaledClosure
from tankode.errors import SimulationError
from tankode.forcing import Forcing
from tankode.geometry import geometry_from_spec
from tankode.integrate import integrate, state_scale
from tankode.mechanisms import MECHANISMS, make_mechanism, mechanisms_from_spec, mechanisms_spec
from tankode.mechanisms.noncondensable import R_J_PER_MOLK
from tankode.model import TankModel
from tankode.saved import load_model, save_model
from tankode.solver import AdaptiveRK, NoGradient

CW = 2.0e5
TIGHT = AdaptiveRK(rtol=1e-10, atol=1e-12)


def _tank(mechanisms=()):
    fluid = AnalyticFluid()
    geom = geometry_from_spec({"shape": "vertical_cylinder", "radius_m": 0.9, "height_m": 2.2})
    model = TankModel(fluid, geom, ReferenceClosure(), CW, mechanisms)
    return model, analytic_state(fluid, geom, 3e5, 30.0, 20.5, 25.0, 0.6), geom


def _run(model, s0, geom, forcing, t_end=1800.0, n=31):
    t = torch.linspace(0, t_end, n, dtype=torch.float64)
    s0 = model.initial_state(s0)  # (1, n_state)
    states, _ = integrate(model, s0, [(0.0, t_end)], lambda t0, s: forcing, t,
                          state_scale(s0, geom.volume_m3, model.extra_state_scales), TIGHT, NoGradient())
    return t, states[0]


def test_every_mechanism_is_documented_bounded_and_absent_at_zero():
    model0, s0, _ = _tank()
    f = Forcing.rest(1, mdot_v_in_kg_s=2e-3, h_v_in_J_per_kg=5e5, slosh_amplitude_m=0.01, slosh_frequency_Hz=0.5)
    ref = model0(torch.tensor(0.0), s0, f)
    for mid, cls in MECHANISMS.items():
        m = make_mechanism(mid)
        assert cls.__doc__ and m.signature and m.params
        # value 0 = absent: the right-hand side and the observations are the baseline's exactly,
        # and a mechanism's own states start at 0 and stay there
        model, _, _ = _tank([m])
        s = model.initial_state(s0)  # (1, 7 + own states)
        assert s.shape == (1, 7 + len(m.states)) and torch.equal(s[:, 7:], torch.zeros(1, len(m.states))), mid
        ds = model(torch.tensor(0.0), s, f)
        assert torch.equal(ds[:, :7], ref) and torch.equal(ds[:, 7:], torch.zeros(1, len(m.states))), mid
        assert torch.equal(model.observe(s), model0.observe(s0)), mid
        p = m.params[0]
        with pytest.raises(ValueError, match=rf"{p.name} = .* outside its allowed range"):
            make_mechanism(mid, **{p.name: p.upper * 2 + 1})
    with pytest.raises(ValueError, match="unknown mechanism 'warp_drive'"):
        make_mechanism("warp_drive")
    with pytest.raises(ValueError, match="has no parameter"):
        make_mechanism("vapor_leak", Q_W=3.0)


def test_heat_leaks_add_exactly_their_power_to_the_energy():
    for mid in ("heat_leak_liquid", "heat_leak_vapor", "heat_leak_wall"):
        model, s0, geom = _tank([make_mechanism(mid, Q_W=400.0)])
        t, s = _run(model, s0, geom, Forcing.rest(1))
        E = model.total_energy_J(s[None])[0]
        assert torch.allclose(E - E[0], 400.0 * t, rtol=1e-7, atol=1e-2), mid
        mass = s[:, 0] + s[:, 1]
        assert (mass - mass[0]).abs().max() / mass[0] < 1e-9


def test_dry_wall_heating_moves_the_dry_walls_share_of_the_ambient_heat_into_the_vapour():
    model0, s0, geom = _tank()
    model, _, _ = _tank([make_mechanism("dry_wall_heating", phi=0.6)])
    f = Forcing.rest(1, Q_aw_W=500.0)
    t0 = torch.tensor(0.0)
    d0, d = model0(t0, s0, f), model(t0, s0, f)
    A_wl, A_wv = geom.wetted_areas_m2(geom.level_at_volume(s0[:, 6]))
    q = 0.6 * 500.0 * A_wv / (A_wl + A_wv)  # (1,) W
    assert 50.0 < float(q) < 250.0  # 40 % of the wall is dry at 60 % fill

    def vapour_heat_in(ds):  # d(m_v u_v)/dt + p dV_v/dt: the vapour's heat and enthalpy inflow (W)
        p = model0.observe(s0)[:, 0]
        return ds[:, 0] * s0[:, 2] + s0[:, 0] * ds[:, 2] + p * ds[:, 5]

    assert torch.allclose(CW * (d[:, 4] - d0[:, 4]), -q, rtol=1e-12)
    assert torch.allclose(vapour_heat_in(d) - vapour_heat_in(d0), q, rtol=1e-9)
    # an internal redistribution: the total energy still gains exactly Q_aw
    t, s = _run(model, s0, geom, f)
    E = model.total_energy_J(s[None])[0]
    assert torch.allclose(E - E[0], 500.0 * t, rtol=1e-7, atol=1e-2)
    # and the ullage ends warmer than the baseline's
    _, sb = _run(model0, s0, geom, f)
    assert model.observe(s[-1:])[0, 1] > model0.observe(sb[-1:])[0, 1] + 0.1


def test_dry_wall_node_balances_its_heat_and_spans_the_lump_to_the_insulated_dry_wall():
    model0, s0, geom = _tank()
    f = Forcing.rest(1, Q_aw_W=500.0)
    f0, _, _ = model0.fluxes(s0, f)
    A_wv, L_c, hA = f0.A_wv_m2, f0.L_c_m, f0.theta_W_m2K[:, 2] * f0.A_wv_m2  # (1,)
    assert torch.allclose(L_c, torch.tensor([2 * math.pi * 0.9], dtype=torch.float64), rtol=1e-12)  # a disc's rim
    Q_d = 500.0 * A_wv / (A_wv + f0.A_wl_m2)
    T_w, T_v = s0[:, 4], f0.T_v_K

    def moved(R_s):  # heat the node moves from the lump to the vapour (W), and the lump's change
        model, _, _ = _tank([make_mechanism("dry_wall_node", R_sheet_K_per_W=R_s)])
        q_v, q_l, q_w = model.extra_heat_W(s0, f, f0)
        assert q_l == 0.0 and torch.equal(q_w, -q_v)
        return q_v

    for R_s in (0.5, 10.0, 300.0):
        # the node's own balance: what reaches it leaves by the ullage and by conduction
        x = make_mechanism("dry_wall_node").node_excess_K(R_s, f0, 500.0)  # T_d - T_w
        G = 3.0 * L_c**2 / (A_wv * R_s)
        assert torch.allclose(Q_d, hA * (T_w + x - T_v) + G * x, rtol=1e-12)
        assert torch.allclose(moved(R_s), hA * x, rtol=1e-12)  # the ullage sees T_d instead of T_w
    # a good conductor is the baseline's lump; an insulating shell sends the dry wall's whole load to
    # the ullage and cuts it from the lump (Q_wv: the lump's exchange with the ullage)
    # (linear in R_s near 0: the slope the diagnosis' score test sees)
    assert torch.allclose(moved(1e-9) / 1e-9, hA * A_wv * (Q_d - f0.Q_wv_W) / (3.0 * L_c**2), rtol=1e-6)
    assert torch.allclose(moved(1e3), Q_d - f0.Q_wv_W, rtol=2e-3)
    # an internal redistribution: the total energy gains exactly Q_aw; the ullage ends warmer
    model, _, _ = _tank([make_mechanism("dry_wall_node", R_sheet_K_per_W=10.0)])
    t, s = _run(model, s0, geom, f)
    E = model.total_energy_J(s[None])[0]
    assert torch.allclose(E - E[0], 500.0 * t, rtol=1e-7, atol=1e-2)
    _, sb = _run(model0, s0, geom, f)
    assert model.observe(s[-1:])[0, 1] > model0.observe(sb[-1:])[0, 1] + 0.1


def test_closed_tank_stays_conservative_with_stratification_and_wall_capacity_error():
    model, s0, geom = _tank([make_mechanism("thermal_stratification", dT_K=0.8),
                             make_mechanism("wall_heat_capacity_error", eps=0.5)])
    t, s = _run(model, s0, geom, Forcing.rest(1, slosh_amplitude_m=0.01, slosh_frequency_Hz=0.5))
    E = model.total_energy_J(s[None])[0]
    assert (E - E[0]).abs().max() / (float(s[0, 0] + s[0, 1]) * 4.46e5) < 1e-8
    # both act: the run differs from the baseline's
    base, _, _ = _tank()
    _, sb = _run(base, s0, geom, Forcing.rest(1, slosh_amplitude_m=0.01, slosh_frequency_Hz=0.5))
    assert (s[-1, 0] - sb[-1, 0]).abs() > 1e-2 and (s[-1, 4] - sb[-1, 4]).abs() > 1e-3


def test_surface_layer_state_follows_its_equation_and_conserves_energy():
    inv_delta, phi, k = 50.0, 0.3, 2e-4  # a 2 cm layer taking 30 % of the wall's heat, mixing in 1.4 h
    layer = make_mechanism("surface_layer", inv_thickness_1_per_m=inv_delta, wall_share=phi, mixing_rate_1_per_s=k)
    model, s0, geom = _tank([layer])
    assert model.n_state == 8 and model.state_names[-1] == "surface_layer.dT_layer_K"
    f = Forcing.rest(1, Q_aw_W=300.0)
    # The layer's rate against the equation of its docstring, evaluated here from the model's flows.
    s = torch.cat([s0, torch.tensor([[0.4]], dtype=torch.float64)], dim=-1)  # (1, 8): layer 0.4 K warm
    fl, _, pl = model.fluxes(s, f)
    base, _, _ = _tank()
    fl0, _, _ = base.fluxes(s0, f)
    h_li = fl.theta_W_m2K[0, 1]
    # the interface sees the layer: Q_li grows by h_li A_i x
    assert float(fl.Q_li_W[0] - fl0.Q_li_W[0]) == pytest.approx(float(h_li * fl.A_i_m2[0] * 0.4), rel=1e-12)
    C_s = float(s0[0, 1] / s0[0, 6] * pl.cp[0] * fl.A_i_m2[0]) / inv_delta
    expected = float(phi * fl.Q_wl_W[0] - fl.Q_li_W[0]) / C_s - k * 0.4
    assert float(model(torch.tensor(0.0), s, f)[0, 7]) == pytest.approx(expected, rel=1e-12)
    assert abs(expected) > 1e-5  # the check is not vacuous
    # Integrated: energy changes only by the ambient heat, mass is conserved, the layer warms.
    t, traj = _run(model, s0, geom, f)
    E = model.total_energy_J(traj[None])[0]
    assert torch.allclose(E - E[0], 300.0 * t, rtol=1e-8, atol=1e-2)
    mass = traj[:, 0] + traj[:, 1]
    assert (mass - mass[0]).abs().max() / mass[0] < 1e-10
    assert float(traj[-1, 7]) > 0.05
    # A warm surface condenses less vapour than the baseline: more vapour, higher pressure.
    _, tb = _run(base, s0, geom, f)
    assert float(traj[-1, 0] - tb[-1, 0]) > 0 and float(model.observe(traj[-1:])[0, 0] - base.observe(tb[-1:])[0, 0]) > 0


def test_leaks_and_meter_bias_move_the_mass_they_say():
    model, s0, geom = _tank([make_mechanism("vapor_leak", mdot_kg_s=1e-3), make_mechanism("liquid_leak", mdot_kg_s=5e-3),
                             make_mechanism("inflow_meter_bias", beta=0.2)])
    t, s = _run(model, s0, geom, Forcing.rest(1, mdot_v_in_kg_s=2e-3, h_v_in_J_per_kg=5e5))
    mass = s[:, 0] + s[:, 1]
    assert torch.allclose(mass - mass[0], (2e-3 * 1.2 - 1e-3 - 5e-3) * t, rtol=1e-8, atol=1e-8)


def test_sensor_offsets_enter_the_observation_and_the_initial_state():
    run = get_case("case4").until(600.0)
    n = 300.0
    sol = simulate(run, mechanisms=[make_mechanism("noncondensable_gas", n_mol=n)], output_dt_s=60.0)
    base = simulate(run, output_dt_s=60.0)
    # The run's initial pressure is a sensor reading: both read it at t0, the hydrogen in the
    # mechanism's tank is below it by n R T_v / V_v.
    assert float(sol.observations[0, 0, 0]) == pytest.approx(run.initial.p_v_Pa, rel=1e-6)
    s = sol.states[0, 0]
    p_inert = n * R_J_PER_MOLK * run.initial.T_v_K / float(s[5])
    assert float(base.states[0, 0, 0] - s[0]) > 0  # less hydrogen vapour
    from tankode import Fleet

    model = TankModel(Fleet.from_runs(run).fluid, Fleet.from_runs(run).geometry, ReferenceClosure(), 2.44e6)
    # (the observation takes T_v from the surrogate, within 7e-5 of CoolProp's)
    assert float(sol.observations[0, 0, 0] - model.observe(s[None])[0, 0]) == pytest.approx(p_inert, rel=1e-4)
    bias = simulate(run, mechanisms=[make_mechanism("pressure_sensor_bias", bias_Pa=-5e3)], output_dt_s=60.0)
    assert float(bias.observations[0, 0, 0]) == pytest.approx(run.initial.p_v_Pa, rel=1e-6)
    # More inert gas than the reading allows is an infeasible parameter, not a bad run: a
    # SimulationError (which a fit rejects as a trial point) at the start, naming the pressure.
    too_much = 1.01 * run.initial.p_v_Pa * float(s[5]) / (R_J_PER_MOLK * run.initial.T_v_K)
    with pytest.raises(SimulationError, match=r"initial hydrogen pressure \[-.*\] Pa is not positive.* at t = 0 s"):
        simulate(run, mechanisms=[make_mechanism("noncondensable_gas", n_mol=too_much)], output_dt_s=60.0)
    # A liquid thermometer reading b high: the reading at t0 is the run's, the liquid starts b
    # colder, and every reading is the liquid's own temperature plus b.
    b = 0.3
    hot = simulate(run, mechanisms=[make_mechanism("temperature_sensor_bias", bias_K=b)], output_dt_s=60.0)
    assert float(hot.observations[0, 0, 2]) == pytest.approx(run.initial.T_l_K, abs=2e-4)  # the surrogate's T
    assert float(base.states[0, 0, 3] - hot.states[0, 0, 3]) > 0  # less internal energy in the liquid
    assert torch.allclose(hot.observations[0, :, 2] - model.observe(hot.states)[0, :, 2],
                          torch.full_like(hot.observations[0, :, 2], b), atol=1e-9)


def test_a_saturated_start_takes_a_reading_above_saturation_down_to_it_and_leaves_a_subcooled_one():
    import dataclasses

    import CoolProp.CoolProp as CP

    run = get_case("case1").until(300.0)
    T_sat = CP.PropsSI("T", "P", run.initial.p_v_Pa, "Q", 0, run.fluid)
    hot = run.replace(initial=dataclasses.replace(run.initial, T_l_K=T_sat + 0.1))
    for share, expected in ((1.0, T_sat), (0.5, T_sat + 0.05), (0.0, T_sat + 0.1)):
        sol = simulate(hot, mechanisms=[make_mechanism("saturated_start", share=share)], output_dt_s=60.0)
        # the liquid's own temperature at t0 (the observation, within the surrogate's 2e-4 K)
        assert float(sol.observations[0, 0, 2]) == pytest.approx(expected, abs=3e-4), share
    cold = simulate(run, mechanisms=[make_mechanism("saturated_start", share=1.0)], output_dt_s=60.0)
    assert run.initial.T_l_K < T_sat
    assert float(cold.observations[0, 0, 2]) == pytest.approx(run.initial.T_l_K, abs=3e-4)


def test_per_environment_values_match_separate_runs():
    run = get_case("case3").until(900.0)
    values = [[0.0], [2e-4], [5e-4]]
    m = make_mechanism("vapor_leak")
    m.set_values(values)
    batched = simulate([run] * 3, mechanisms=[m], output_dt_s=60.0).observations
    for e, v in enumerate(values):
        one = simulate(run, mechanisms=[make_mechanism("vapor_leak", mdot_kg_s=v[0])], output_dt_s=60.0).observations
        assert torch.allclose(batched[e], one[0], rtol=1e-5)


def test_saved_model_round_trips_closure_factors_and_mechanisms(tmp_path):
    closure = ScaledClosure(ReferenceClosure(), torch.tensor([1.0, 1.5, 0.7, 1.1], dtype=torch.float64), 0.3)
    mechs = [make_mechanism("heat_leak_wall", Q_W=120.0), make_mechanism("pressure_sensor_bias", bias_Pa=-800.0)]
    save_model(tmp_path / "m", closure, "ParaHydrogen", {"x": 1}, mechanisms=mechs)
    c2, m2, meta = load_model(tmp_path / "m")
    assert torch.equal(c2.factors, closure.factors) and float(c2.stable_mixing) == 0.3
    spec = json.loads((tmp_path / "m" / "model.json").read_text())
    del spec["closure"]["stable_mixing"]  # a model saved before the share existed
    (tmp_path / "m" / "model.json").write_text(json.dumps(spec))
    assert float(load_model(tmp_path / "m")[0].stable_mixing) == 0.0
    assert mechanisms_spec(m2) == mechanisms_spec(mechs)
    assert mechanisms_from_spec(mechanisms_spec(mechs))[0].values_dict() == {"Q_W": 120.0}
    bad = tmp_path / "m" / "model.json"
    bad.write_text(bad.read_text().replace('"Q_W": 120.0', '"Q_W": -5.0'))
    with pytest.raises(ValueError, match=r"model.json: mechanisms: .*Q_W = -5 W is outside"):
        load_model(tmp_path / "m")
    assert math.isfinite(meta["info"]["x"])
    assert np.isfinite(float(c2.factors.sum()))


def test_eckert_jackson_flow_is_the_integral_of_its_profile_and_scales_as_it_should():
    from scipy.integrate import quad

    from tankode.mechanisms.boundary_layer import eckert_jackson_flow_kg_s

    t = lambda v: torch.tensor(v, dtype=torch.float64)  # noqa: E731
    rho, mu, cp, k, beta = 70.8, 1.3e-5, 9700.0, 0.1, 0.016  # LH2 near 21 K
    dT, L, width = 0.1, 1.0, 2.0
    flow = float(eckert_jackson_flow_kg_s(t(rho), t(mu), t(cp), t(k), t(beta), t(dT), t(L), t(width)))
    # Independently: Eckert & Jackson's thickness and velocity scale, the profile integrated numerically.
    nu, pr = mu / rho, mu * cp / k
    gr = 9.80665 * beta * dT * L**3 / nu**2
    delta = 0.565 * L * gr**-0.1 * pr ** (-8 / 15) * (1 + 0.494 * pr ** (2 / 3)) ** 0.1
    u1 = 1.185 * nu / L * gr**0.5 * (1 + 0.494 * pr ** (2 / 3)) ** -0.5
    integral, _ = quad(lambda eta: eta ** (1 / 7) * (1 - eta) ** 4, 0.0, 1.0)
    assert flow == pytest.approx(rho * u1 * delta * integral * width, rel=1e-3)  # dT smoothing: 5e-5
    # Taller walls and larger differences carry more: L^1.2, dT^0.4; linear in the width.
    f = lambda **kw: float(eckert_jackson_flow_kg_s(*(t(v) for v in {**dict(rho=rho, mu=mu, cp=cp, k=k, beta=beta,  # noqa: E731
                                                                  dT=dT, L=L, w=width), **kw}.values())))
    assert f(L=2.0) / flow == pytest.approx(2**1.2, rel=1e-9)
    assert f(dT=0.4) / flow == pytest.approx(4**0.4, rel=1e-3)
    assert f(w=3.0) / flow == pytest.approx(1.5, rel=1e-12)
    assert f(dT=-0.1) == pytest.approx(flow, rel=1e-12)  # a cold wall's downward layer renews as much


def test_boundary_layer_stratification_follows_its_equation_and_conserves_energy():
    from tankode.mechanisms.boundary_layer import eckert_jackson_flow_kg_s

    inv_delta, phi, c = 50.0, 0.8, 0.5  # a 2 cm layer, 80 % of the wall's heat, half the boundary layer's flow
    layer = make_mechanism("boundary_layer_stratification", inv_thickness_1_per_m=inv_delta, wall_share=phi,
                           renewal_share=c)
    model, s0, geom = _tank([layer])
    assert model.state_names[-1] == "boundary_layer_stratification.dT_layer_K"
    f = Forcing.rest(1, Q_aw_W=300.0)
    s0 = s0.clone()
    s0[0, 4] += 2.0  # a wall 2 K warmer than the start's, so that the boundary layer flows
    s = torch.cat([s0, torch.tensor([[0.4]], dtype=torch.float64)], dim=-1)  # (1, 8): layer 0.4 K warm
    fl, _, pl = model.fluxes(s, f)
    rho = s0[0, 1] / s0[0, 6]
    C_s = float(rho * pl.cp[0] * fl.A_i_m2[0]) / inv_delta
    flow = eckert_jackson_flow_kg_s(rho, pl.mu, pl.cp, pl.k, pl.beta, s0[:, 4] - fl.T_l_K, fl.H_l_m,
                                    fl.A_wl_m2 / fl.H_l_m)
    k_renew = float(c * flow[0] / (rho * fl.A_i_m2[0])) * inv_delta
    expected = float(phi * fl.Q_wl_W[0] - fl.Q_li_W[0]) / C_s - k_renew * 0.4
    assert float(model(torch.tensor(0.0), s, f)[0, 7]) == pytest.approx(expected, rel=1e-12)
    assert k_renew * 0.4 > 0.1 * abs(expected) and abs(expected) > 1e-5  # the renewal term counts; not vacuous
    # Integrated: energy changes only by the ambient heat, mass is conserved, and the layer, renewed
    # in about 2 minutes, sits at the quasi-steady excess (phi Q_wl - Q_li) / (c c_p mdot_bl) of
    # its docstring after 30 minutes (within 5 %: it lags the source, which falls as the wall cools
    # with a time constant of minutes; a renewal off by a factor of 2 would miss by 50 %).
    t, traj = _run(model, s0, geom, f)
    E = model.total_energy_J(traj[None])[0]
    assert torch.allclose(E - E[0], 300.0 * t, rtol=1e-8, atol=1e-2)
    mass = traj[:, 0] + traj[:, 1]
    assert (mass - mass[0]).abs().max() / mass[0] < 1e-10
    end = traj[-1:]  # (1, 8)
    fl, _, pl = model.fluxes(end, f)
    flow = eckert_jackson_flow_kg_s(end[0, 1] / end[0, 6], pl.mu, pl.cp, pl.k, pl.beta, end[:, 4] - fl.T_l_K,
                                    fl.H_l_m, fl.A_wl_m2 / fl.H_l_m)
    steady = float((phi * fl.Q_wl_W[0] - fl.Q_li_W[0]) / (c * pl.cp[0] * flow[0]))
    assert float(end[0, 7]) == pytest.approx(steady, rel=0.05) and float(end[0, 7]) > 0.1


def _check_growing_layer_run(model, s0, geom, f, phi, inv0, absent):
    """Integrate a layer of growing thickness (states x, grown) under ``f`` for 30 min and check its budget.

    The tank's energy changes only by the ambient heat (300 W); the layer's excess energy
    rho c_p A_i delta x is the heat delivered to it, the integral of phi Q_wl - Q_li (within 2 %:
    rho, c_p and A_i are taken as constant there, as the mechanism does); and with 1/delta_0 = 0
    (``absent``: the id and other parameters) both states stay at 0. Returns ``(t, traj)``.
    """
    from scipy.integrate import cumulative_trapezoid

    t, traj = _run(model, s0, geom, f, n=361)
    E = model.total_energy_J(traj[None])[0]
    assert torch.allclose(E - E[0], 300.0 * t, rtol=1e-8, atol=1e-2)
    src = []
    for row in traj:
        fr, _, _ = model.fluxes(row[None], f)
        src.append(float(phi * fr.Q_wl_W[0] - fr.Q_li_W[0]))
    delivered = cumulative_trapezoid(np.array(src), t.numpy(), initial=0.0)[-1]
    end = traj[-1]
    fr, _, pr = model.fluxes(end[None], f)
    excess = float(end[1] / end[6] * pr.cp[0] * fr.A_i_m2[0] * (1 / inv0 + end[8]) * end[7])
    assert excess == pytest.approx(delivered, rel=0.02) and delivered > 0
    mid, others = absent
    model0, _, _ = _tank([make_mechanism(mid, wall_share=1.0, **others)])
    d0 = model0(torch.tensor(0.0), torch.cat([s0, torch.zeros(1, 2, dtype=torch.float64)], dim=-1), f)[0]
    assert float(d0[7]) == 0.0 and float(d0[8]) == 0.0
    return t, traj


def test_growing_layer_follows_its_equations_and_its_excess_energy_is_the_delivered_heat():
    from tankode.mechanisms.boundary_layer import eckert_jackson_flow_kg_s

    inv0, phi, c = 50.0, 0.8, 0.5  # a 2 cm layer at the start, half the boundary layer's flow piles up under it
    layer = make_mechanism("growing_layer", inv_thickness_1_per_m=inv0, wall_share=phi, entrainment_share=c)
    model, s0, geom = _tank([layer])
    assert list(model.state_names[-2:]) == ["growing_layer.dT_layer_K", "growing_layer.grown_m"]
    f = Forcing.rest(1, Q_aw_W=300.0)
    s0 = s0.clone()
    s0[0, 4] += 2.0
    s = torch.cat([s0, torch.tensor([[0.4, 0.03]], dtype=torch.float64)], dim=-1)  # 0.4 K warm, 3 cm grown: 5 cm
    fl, _, pl = model.fluxes(s, f)
    rho = s0[0, 1] / s0[0, 6]
    flow = eckert_jackson_flow_kg_s(rho, pl.mu, pl.cp, pl.k, pl.beta, s0[:, 4] - fl.T_l_K, fl.H_l_m,
                                    fl.A_wl_m2 / fl.H_l_m)
    growth = float(c * flow[0] / (rho * fl.A_i_m2[0]))
    delta = 1 / inv0 + 0.03
    C_s = float(rho * pl.cp[0] * fl.A_i_m2[0]) * delta
    d = model(torch.tensor(0.0), s, f)[0]
    assert float(d[8]) == pytest.approx(growth, rel=1e-12)
    assert float(d[7]) == pytest.approx(float(phi * fl.Q_wl_W[0] - fl.Q_li_W[0]) / C_s - growth / delta * 0.4, rel=1e-12)
    assert growth / delta * 0.4 > 0.1 * abs(float(d[7]))  # the dilution by growth counts; not vacuous
    t, traj = _check_growing_layer_run(model, s0, geom, f, phi, inv0, ("growing_layer", {"entrainment_share": 1.0}))
    assert float(traj[-1, 8]) > 0.01  # grown by more than a centimetre in half an hour


def test_diffusive_layer_grows_as_a_conduction_depth_and_keeps_the_delivered_heat():
    from tankode.mechanisms.diffusive_layer import TOP_HAT_DIFFUSIVITY

    inv0, phi, a = 200.0, 0.8, 50.0  # a 5 mm layer at the start; eddy diffusivity 50x conduction's
    layer = make_mechanism("diffusive_layer", inv_thickness_1_per_m=inv0, wall_share=phi, diffusivity_factor=a)
    model, s0, geom = _tank([layer])
    assert list(model.state_names[-2:]) == ["diffusive_layer.dT_layer_K", "diffusive_layer.grown_m"]
    f = Forcing.rest(1, Q_aw_W=300.0)
    s0 = s0.clone()
    s0[0, 4] += 2.0
    s = torch.cat([s0, torch.tensor([[0.4, 0.015]], dtype=torch.float64)], dim=-1)  # 0.4 K warm, 2 cm thick
    fl, _, pl = model.fluxes(s, f)
    rho = s0[0, 1] / s0[0, 6]
    D = a * TOP_HAT_DIFFUSIVITY * float(pl.k[0] / (rho * pl.cp[0]))  # m^2/s
    delta = 1 / inv0 + 0.015
    C_s = float(rho * pl.cp[0] * fl.A_i_m2[0]) * delta
    d = model(torch.tensor(0.0), s, f)[0]
    assert float(d[8]) == pytest.approx(D / delta, rel=1e-12)
    assert float(d[7]) == pytest.approx(float(phi * fl.Q_wl_W[0] - fl.Q_li_W[0]) / C_s - D / delta**2 * 0.4, rel=1e-12)
    # Integrated: the thickness follows delta^2 = delta_0^2 + 2 D t (within 3 %: the liquid's
    # diffusivity drifts as it warms)
    t, traj = _check_growing_layer_run(model, s0, geom, f, phi, inv0, ("diffusive_layer", {"diffusivity_factor": 1.0}))
    grown = (1 / inv0 + traj[:, 8]) ** 2 - 1 / inv0**2  # (T,)
    assert float(grown[-1]) == pytest.approx(2 * D * 1800.0, rel=0.03) and float(traj[-1, 8]) > 0.005


def test_two_node_wall_start_share_splits_the_measured_mean_between_the_nodes():
    """start_share 0: a uniform wall; 1: the wetted node at the liquid's temperature and the dry
    node holding the rest of the sensor's mean; the mean, the energy and the observation stay
    the tank's; at R_s = 0 (absent) the share places nothing."""
    base, s0, geom = _tank()
    T_l = base.fluid.liquid(s0[:, 3], s0[:, 1] / s0[:, 6]).T
    T_w = s0[:, 4]
    A_wl, A_wv = geom.wetted_areas_m2(geom.level_at_volume(s0[:, 6]))
    a_d = A_wv / (A_wv + A_wl)
    for share in (0.0, 0.5, 1.0):
        model, _, _ = _tank([make_mechanism("two_node_wall", R_sheet_K_per_W=10.0, start_share=share)])
        s = model.initial_state(s0)
        x = s[:, -1]
        T_d, T_ww = T_w + (1 - a_d) * x, T_w - a_d * x
        assert torch.allclose(a_d * T_d + (1 - a_d) * T_ww, T_w, rtol=1e-12)  # the sensor's mean
        assert torch.allclose(T_ww, T_w - share * (T_w - T_l), rtol=1e-12)
        assert torch.equal(model.observe(s), base.observe(s0))
        assert torch.allclose(model.total_energy_J(s[None]), base.total_energy_J(s0[None]), rtol=1e-14)
    assert float(x) > 5.0  # 4.5 K of wall over liquid, 40 % dry: the dry node 6.8 K above the wetted
    absent, _, _ = _tank([make_mechanism("two_node_wall", R_sheet_K_per_W=0.0, start_share=1.0)])
    assert torch.equal(absent.initial_state(s0)[:, -1], torch.zeros(1, dtype=torch.float64))


def test_two_node_wall_each_phase_convects_on_the_node_it_touches():
    """The closure sees the dry node for the ullage and the wetted node for the liquid (their
    capacity-weighted mean is the sensor's T_w): natural convection on the wall then equals the
    lumped model's at a mean wall set to that node, and differs from it at the mean. A lump
    (R_s = 0) gives the mean to both."""
    from tankode.closures import NaturalConvectionClosure

    base, s0, geom = _tank()
    f = Forcing.rest(1)
    model, _, _ = _tank([make_mechanism("two_node_wall", R_sheet_K_per_W=10.0, start_share=1.0)])
    model.closure = base.closure = NaturalConvectionClosure()
    s = model.initial_state(s0)
    x_in = model.closure_inputs(s, f)
    T_dry, T_wet = x_in.wall_temperatures_K()
    A_wl, A_wv = geom.wetted_areas_m2(geom.level_at_volume(s0[:, 6]))
    a_d = A_wv / (A_wv + A_wl)
    assert torch.allclose(a_d * T_dry + (1 - a_d) * T_wet, s0[:, 4], rtol=1e-12)
    assert float(T_dry - T_wet) > 5.0
    theta = model.closure(x_in)

    def lumped_at(T_w):
        s_w = s0.clone()
        s_w[:, 4] = T_w
        return base.closure(base.closure_inputs(s_w, f))

    assert torch.allclose(theta[:, 2], lumped_at(T_dry)[:, 2], rtol=1e-12)  # h_wv on the dry node
    assert torch.allclose(theta[:, 3], lumped_at(T_wet)[:, 3], rtol=1e-12)  # h_wl on the wetted node
    assert torch.allclose(theta[:, :2], lumped_at(s0[:, 4])[:, :2], rtol=1e-12)  # the interface's as before
    assert not torch.allclose(theta[:, 2:], lumped_at(s0[:, 4])[:, 2:], rtol=1e-3)
    lump, _, _ = _tank([make_mechanism("two_node_wall", R_sheet_K_per_W=0.0)])
    x_lump = lump.closure_inputs(lump.initial_state(s0), f)
    assert all(torch.equal(T, s0[:, 4]) for T in x_lump.wall_temperatures_K())


def test_two_node_wall_nodes_follow_their_balances_and_the_tank_conserves_energy():
    """The dry node's balance holds at a state with the nodes apart (``T_d``, ``T_ww`` rebuilt
    from the model's ``dT_w`` and ``dx``); R_s = 0 is the baseline; a heat load warms the dry
    wall above the wetted one, the ullage above the baseline's, and the energy gains exactly Q_aw t."""
    Q = 500.0
    f = Forcing.rest(1, Q_aw_W=Q)
    model, s0, geom = _tank([make_mechanism("two_node_wall", R_sheet_K_per_W=10.0)])
    s = model.initial_state(s0).clone()
    s[:, -1] = 0.7  # x = T_d - T_ww, K
    ds = model(torch.tensor(0.0, dtype=torch.float64), s, f)
    fl, _, _ = model.fluxes(s, f)
    A_w = fl.A_wv_m2 + fl.A_wl_m2
    a_d = fl.A_wv_m2 / A_w
    a_w = 1 - a_d
    x, T_w = s[:, -1], s[:, 4]
    G = 2 * fl.L_c_m**2 / (10.0 * A_w)
    r = CW * fl.dA_wl_dH_m * ds[:, 6] / fl.A_i_m2 / A_w  # wall changing node as the level moves
    # T_w = a_d T_d + a_w T_ww with a_d falling at r / C_w as the level rises
    dT_d = ds[:, 4] + a_w * ds[:, -1] + r * x / CW
    dT_ww = ds[:, 4] - a_d * ds[:, -1] + r * x / CW
    h_wv, h_wl = fl.theta_W_m2K[:, 2], fl.theta_W_m2K[:, 3]
    dry = a_d * Q - h_wv * fl.A_wv_m2 * (T_w + a_w * x - fl.T_v_K) - G * x + torch.clamp(r, max=0) * x
    wet = a_w * Q - h_wl * fl.A_wl_m2 * (T_w - a_d * x - fl.T_l_K) + G * x + torch.clamp(r, min=0) * x
    assert torch.allclose(a_d * CW * dT_d, dry, rtol=1e-6)
    assert torch.allclose(a_w * CW * dT_ww, wet, rtol=1e-6)

    t, sr = _run(model, s0, geom, f)
    E = model.total_energy_J(sr[None])[0]
    assert torch.allclose(E - E[0], Q * t, rtol=1e-7, atol=1e-2)
    assert sr[-1, -1] > 0.05  # the dry wall runs warmer than the wetted wall
    base, _, _ = _tank()
    _, sb = _run(base, s0, geom, f)
    assert model.observe(sr[-1:])[0, 1] > base.observe(sb[-1:])[0, 1] + 0.05
    lump, _, _ = _tank([make_mechanism("two_node_wall", R_sheet_K_per_W=0.0)])
    _, s_lump = _run(lump, s0, geom, f)
    assert torch.allclose(s_lump[:, :7], sb, rtol=1e-9) and torch.all(s_lump[:, -1] == 0)


def test_saturated_boiling_flashes_its_share_of_the_liquid_past_saturation_and_conserves_mass_and_energy():
    from tankode.bulk import BulkPhaseChange
    from tankode.mechanisms.saturated_boiling import THRESHOLD_K

    fluid = AnalyticFluid()
    model0, at_3bar, geom = _tank()
    f = Forcing.rest(1)
    T_sat = float(model0.fluxes(at_3bar, f)[1].T_sat)
    # a liquid 0.15 K past saturation: below the bulk's 0.2 K threshold, past the boiling share's
    s0 = analytic_state(fluid, geom, 3e5, T_sat + 1.0, T_sat + 0.15, T_sat + 0.15, 0.6)
    _, pv, pl = model0.fluxes(s0, f)
    m_v, m_l = s0[:, 0], s0[:, 1]
    _, bulk = BulkPhaseChange(flash_threshold_K=THRESHOLD_K).rates_kg_s(m_v, m_l, pv, pl)
    assert float(bulk) > 0
    d0 = model0(torch.tensor(0.0), s0, f)
    for share in (0.3, 1.0):
        model, _, _ = _tank([make_mechanism("saturated_boiling", share=share)])
        d = model(torch.tensor(0.0), s0, f)
        # the share's flash moves liquid into the vapour as saturated vapour, beside the baseline's
        assert torch.allclose(d[:, 0] - d0[:, 0], share * bulk, rtol=1e-12)
        assert torch.allclose(d[:, 1] - d0[:, 1], -share * bulk, rtol=1e-12)
        assert torch.allclose(m_l * (d[:, 3] - d0[:, 3]) + s0[:, 3] * (d[:, 1] - d0[:, 1]) + pv.p * (d[:, 6] - d0[:, 6]),
                              -share * bulk * pv.h_vsat, rtol=1e-9)
    # integrated: a closed, insulated tank keeps its mass and energy, and its liquid ends nearer
    # saturation than the baseline's
    model, _, _ = _tank([make_mechanism("saturated_boiling", share=1.0)])
    t, s = _run(model, s0, geom, f, t_end=600.0)
    E = model.total_energy_J(s[None])[0]
    mass = s[:, 0] + s[:, 1]
    assert (E - E[0]).abs().max() / E[0].abs() < 1e-9 and (mass - mass[0]).abs().max() / mass[0] < 1e-9
    _, sb = _run(model0, s0, geom, f, t_end=600.0)

    def superheat(states):
        _, v, liq = model0.fluxes(states[-1:], f)
        return float(liq.T - v.T_sat)

    assert superheat(s) < 0.5 * superheat(sb) and superheat(s) < THRESHOLD_K + 0.02
