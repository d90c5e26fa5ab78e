"""The tank model's mathematics on the analytic fluid: conservation, exact solutions, gradients."""

import math

import pytest
import torch

from tankode.analytic import (
    AnalyticFluid, AnalyticFluidParams, adiabatic_vent_p, analytic_state, relaxation_rate_per_s, wall_heating_T_w,
)
from tankode.closures import ConstantClosure, ReferenceClosure
from tankode.errors import SimulationError
from tankode.forcing import Forcing
from tankode.geometry import geometry_from_spec
from tankode.integrate import integrate, state_scale
from tankode.model import TankModel
from tankode.solver import AdaptiveRK, NoGradient

CW = 2.0e5  # J/K, small so the wall moves visibly in an hour
TIGHT = AdaptiveRK(rtol=1e-10, atol=1e-12)


def _tank(fluid=None, closure=None, p=3e5, T_v=30.0, T_l=20.5, T_w=25.0, fill=0.6, bulk=None):
    # No bulk phase change unless asked: these cases check the balances against exact solutions.
    fluid = fluid or AnalyticFluid()
    geom = geometry_from_spec({"shape": "vertical_cylinder", "radius_m": 0.9, "height_m": 2.2})
    model = TankModel(fluid, geom, closure or ReferenceClosure(), CW, bulk=bulk)
    s0 = analytic_state(fluid, geom, p, T_v, T_l, T_w, fill)
    return model, s0, geom


def _run(model, s0, geom, forcing, t_end=3600.0, n=61, solver=TIGHT):
    t = torch.linspace(0, t_end, n, dtype=torch.float64)
    states, stats = integrate(model, s0, [(0.0, t_end)], lambda t0, s: forcing, t, state_scale(s0, geom.volume_m3),
                              solver, NoGradient())
    return t, states[0], stats


def test_closed_tank_conserves_mass_volume_and_energy():
    model, s0, geom = _tank(closure=ReferenceClosure())
    forcing = Forcing.rest(1, slosh_amplitude_m=0.01, slosh_frequency_Hz=0.55)
    t, s, _ = _run(model, s0, geom, forcing)
    mass = s[:, 0] + s[:, 1]
    assert (mass - mass[0]).abs().max() / mass[0] < 1e-9
    vol = s[:, 5] + s[:, 6]
    assert (vol - float(geom.volume_m3)).abs().max() / vol[0] < 1e-12
    E = model.total_energy_J(s[None])[0]
    # Energy is a nonlinear invariant: conserved to the solver's tolerance, not to round-off.
    assert (E - E[0]).abs().max() / (mass[0] * 4.46e5) < 1e-8
    # ...and something did happen: phase change moved mass between the phases.
    assert (s[:, 0] - s[0, 0]).abs().max() > 1e-3


def test_energy_change_equals_inflow_enthalpy_and_heat():
    model, s0, geom = _tank(closure=ReferenceClosure())
    f = Forcing.rest(1, mdot_v_in_kg_s=3e-3, h_v_in_J_per_kg=5.2e5, mdot_l_in_kg_s=0.02, h_l_in_J_per_kg=2.0e3,
                     Q_aw_W=150.0, slosh_amplitude_m=0.005, slosh_frequency_Hz=0.5)
    t, s, _ = _run(model, s0, geom, f)
    E = model.total_energy_J(s[None])[0]
    expected = (3e-3 * 5.2e5 + 0.02 * 2.0e3 + 150.0) * t
    assert torch.allclose(E - E[0], expected, rtol=1e-7, atol=1e-3 * 4.46e5 * 1e-4)
    mass = s[:, 0] + s[:, 1]
    assert torch.allclose(mass - mass[0], (3e-3 + 0.02) * t, rtol=1e-10, atol=1e-9)


def test_energy_change_with_outflows_matches_quadrature_of_enthalpy_flows():
    model, s0, geom = _tank(closure=ReferenceClosure())
    f = Forcing.rest(1, mdot_v_out_kg_s=2e-3, mdot_l_out_kg_s=0.05, Q_aw_W=80.0)
    t, s, _ = _run(model, s0, geom, f, t_end=1200.0, n=1201)
    fl, _, _ = model.fluxes(s, Forcing.rest(len(t)))
    out = 2e-3 * fl.h_v_J_per_kg + 0.05 * fl.h_l_J_per_kg  # (T,) enthalpy leaving, W
    dt = t[1] - t[0]
    integral = torch.cumsum(torch.cat([torch.zeros(1, dtype=torch.float64), 0.5 * (out[1:] + out[:-1]) * dt]), 0)
    E = model.total_energy_J(s[None])[0]
    expected = 80.0 * t - integral
    assert (E - E[0] - expected).abs().max() / (out.abs().max() * t[-1]) < 1e-6


def test_wall_heating_matches_closed_form():
    model, s0, geom = _tank(closure=ConstantClosure([0.0, 0.0, 0.0, 0.0]))
    t, s, _ = _run(model, s0, geom, Forcing.rest(1, Q_aw_W=500.0))
    assert torch.allclose(s[:, 4], wall_heating_T_w(t, 25.0, 500.0, CW), rtol=0, atol=1e-9)
    assert torch.allclose(s[:, :4], s0[0, :4].expand(len(t), 4), rtol=1e-12)


def test_adiabatic_vent_is_isentropic():
    fluid = AnalyticFluid(AnalyticFluidParams(bulk_modulus_Pa=1e12))  # a rigid liquid: the ullage volume is fixed
    model, s0, geom = _tank(fluid=fluid, closure=ConstantClosure([0.0, 0.0, 0.0, 0.0]))
    mdot = 2e-3
    t, s, _ = _run(model, s0, geom, Forcing.rest(1, mdot_v_out_kg_s=mdot), t_end=1800.0)
    p = fluid.vapor(s[:, 2], s[:, 0] / s[:, 5]).p
    exact = adiabatic_vent_p(t, float(p[0]), float(s0[0, 0]), mdot, fluid.gamma)
    assert float(exact[-1] / exact[0]) < 0.5  # a strong expansion, not a trivial check
    assert torch.allclose(p, exact, rtol=1e-6)


def test_wall_liquid_relaxation_rate():
    h = 40.0
    model, s0, geom = _tank(closure=ConstantClosure([0.0, 0.0, 0.0, h]))
    t, s, _ = _run(model, s0, geom, Forcing.rest(1))
    T_l = model.fluid.liquid(s[:, 3], s[:, 1] / s[:, 6]).T
    A_wl = geom.wetted_areas_m2(geom.level_at_volume(s0[0, 6]))[0]
    rate = relaxation_rate_per_s(h, float(A_wl), CW, float(s0[0, 1]), AnalyticFluidParams().c_l_J_per_kgK)
    dT = s[:, 4] - T_l
    assert torch.allclose(dT, dT[0] * torch.exp(-rate * t), rtol=1e-6)


def test_phase_change_direction():
    """Heat arriving at the interface evaporates; heat drawn from it condenses (the paper's sign slip)."""
    # Superheated vapour over saturated liquid, only h_vi on: evaporation, J > 0.
    model, s0, geom = _tank(closure=ConstantClosure([50.0, 0.0, 0.0, 0.0]), T_v=35.0)
    f, _, _ = model.fluxes(s0, Forcing.rest(1))
    assert f.Q_vi_W.item() > 0 and f.J_evap_kg_s.item() > 0
    ds = model(torch.tensor(0.0), s0, Forcing.rest(1))
    assert ds[0, 0] > 0 and ds[0, 1] < 0
    # Subcooled liquid, only h_li on: the liquid draws heat from the interface and vapour condenses.
    model, s0, geom = _tank(closure=ConstantClosure([0.0, 50.0, 0.0, 0.0]), T_l=18.0)
    f, _, _ = model.fluxes(s0, Forcing.rest(1))
    assert f.Q_li_W.item() < 0 and f.J_evap_kg_s.item() < 0
    assert math.isclose(f.J_evap_kg_s.item(), (f.Q_vi_W + f.Q_li_W).item() / (f.h_vsat_J_per_kg - f.h_lsat_J_per_kg).item())


def test_pressures_stay_equal():
    """The volume split keeps dp_l/dt = dp_v/dt (the index-reduced constraint)."""
    fluid = AnalyticFluid(AnalyticFluidParams(beta_l_per_K=0.015))
    model, s0, geom = _tank(fluid=fluid, closure=ReferenceClosure())
    f = Forcing.rest(1, mdot_v_in_kg_s=3e-3, h_v_in_J_per_kg=5.2e5, slosh_amplitude_m=0.01, slosh_frequency_Hz=0.5)
    t, s, _ = _run(model, s0, geom, f)
    p_v = fluid.vapor(s[:, 2], s[:, 0] / s[:, 5]).p
    p_l = fluid.liquid(s[:, 3], s[:, 1] / s[:, 6]).p
    gap = p_l - p_v
    assert (p_v - p_v[0]).abs().max() > 1e4  # pressure moved a lot...
    assert (gap - gap[0]).abs().max() < 1e-3 * (p_v - p_v[0]).abs().max()  # ...and both phases followed


def test_gradcheck_rhs_wrt_state_and_closure_parameters():
    model, s0, geom = _tank(closure=ConstantClosure([5.0, 30.0, 100.0, 300.0]))
    f = Forcing.rest(1, slosh_amplitude_m=0.01, slosh_frequency_Hz=0.5, mdot_v_in_kg_s=1e-3, h_v_in_J_per_kg=5e5)
    s = s0.clone().requires_grad_(True)
    torch.autograd.gradcheck(lambda x: model(torch.tensor(0.0), x, f), (s,))
    theta = torch.tensor([5.0, 30.0, 100.0, 300.0], dtype=torch.float64, requires_grad=True)
    torch.autograd.gradcheck(lambda th: TankModel(model.fluid, geom, _ThetaClosure(th), CW)(torch.tensor(0.0), s0, f),
                             (theta,))


class _ThetaClosure(torch.nn.Module):
    """A closure returning a given (differentiable) theta tensor."""

    def __init__(self, theta):
        super().__init__()
        self.theta = theta

    def forward(self, x):
        return self.theta.expand(*x.T_v_K.shape, 4)


def test_gradcheck_reference_closure_through_state():
    model, s0, geom = _tank(closure=ReferenceClosure())
    f = Forcing.rest(1, slosh_amplitude_m=0.01, slosh_frequency_Hz=0.5)
    s = s0.clone().requires_grad_(True)
    torch.autograd.gradcheck(lambda x: model(torch.tensor(0.0), x, f), (s,))


def test_solver_budget_fails_with_time_and_state():
    model, s0, geom = _tank()
    with pytest.raises(SimulationError, match=r"at t = .* s in state\n  env 0: m_v_kg="):
        _run(model, s0, geom, Forcing.rest(1), solver=AdaptiveRK(rtol=1e-12, atol=1e-14, max_rhs_evals=50))


def test_every_requested_time_gets_its_state_when_two_lie_within_rounding_of_a_segment_edge():
    # a replayed segment's end computed from a sample time may differ from it by a rounding
    model, s0, geom = _tank()
    edge = 2341.5
    t = torch.tensor([0.0, 1e-13, 1000.0, edge, edge + 4.5e-13], dtype=torch.float64)
    states, _ = integrate(model, s0, [(0.0, 1000.0), (1000.0, edge + 4.5e-13)], lambda t0, s: Forcing.rest(1), t,
                          state_scale(s0, geom.volume_m3), TIGHT, NoGradient())
    assert states.shape == (1, 5, 7)
    assert torch.equal(states[:, 0], s0) and torch.equal(states[:, 1], s0) and torch.equal(states[:, 3], states[:, 4])
    assert not torch.equal(states[:, 2], states[:, 3])
