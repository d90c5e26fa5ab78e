"""The paper's environments on the real-fluid surrogate: behaviour, conservation, batching."""

import numpy as np
import pytest
import torch

from tankode.cases import CASES, case1
from tankode.fleet import Fleet
from tankode.model import TankModel
from tankode.closures import ReferenceClosure
from tankode.run_io import read_run
from tankode.simulation import simulate
from tankode.state import STATE_NAMES

from mhtb_data import MHTB, needs_mhtb


@pytest.fixture(scope="module")
def case1_solution():
    return simulate(case1())


def _p_at(sol, t):
    k = int(torch.argmin((sol.t_s - t).abs()))
    return float(sol.observations[0, k, 0])


def test_case1_behaves_as_the_paper_describes(case1_solution):
    sol = case1_solution
    p_rest, p_sloshed, p_injected = _p_at(sol, 600), _p_at(sol, 1800), _p_at(sol, 2160)
    # A visible pressure drop under 20 minutes of moderate sloshing (several times the 4 kPa high noise)...
    assert p_rest - p_sloshed > 0.5e5
    # ...that 6 minutes of 4.2 g/s vapour injection recovers.
    assert p_injected > p_rest
    # At rest the pressure moves far less than under sloshing.
    assert abs(_p_at(sol, 0) - p_rest) < 0.5 * (p_rest - p_sloshed)


def test_case1_closed_tank_phases_conserve_mass_and_volume(case1_solution):
    s = case1_solution.states[0]
    t = case1_solution.t_s
    closed = (t <= 1800) | (t >= 2160)  # outside the injection
    mass = s[:, 0] + s[:, 1]
    before = mass[t <= 1800]
    after = mass[t >= 2160]
    assert (before - before[0]).abs().max() / before[0] < 1e-9
    assert (after - after[0]).abs().max() / after[0] < 1e-9
    assert after[0] - before[-1] == pytest.approx(4.2e-3 * 360, rel=1e-8)
    vol = s[:, 5] + s[:, 6]
    assert (vol - vol[0]).abs().max() / vol[0] < 1e-12
    assert closed.any()


def test_energy_balance_with_the_surrogate():
    """Closed and sloshing: energy constant to solver tolerance; with injection: rises by mdot h_in t."""
    run = case1()
    fleet = Fleet.from_runs([run])
    sol = simulate(fleet)
    model = TankModel(fleet.fluid, fleet.geometry, ReferenceClosure(), fleet.wall_heat_capacity_J_per_K)
    E = model.total_energy_J(sol.states)[0]
    t = sol.t_s
    scale = float(sol.states[0, 0, 0] + sol.states[0, 0, 1]) * 4.4e5  # total mass x latent heat
    k1800, k2160 = int(torch.argmin((t - 1800).abs())), int(torch.argmin((t - 2160).abs()))
    assert (E[: k1800 + 1] - E[0]).abs().max() / scale < 1e-6
    assert (E[k2160:] - E[k2160]).abs().max() / scale < 1e-6
    h_in = fleet.reference.state_pT(np.array([6.0e5]), np.array([32.0]), "vapor")["h"][0]
    assert float(E[k2160] - E[k1800]) == pytest.approx(4.2e-3 * 360 * h_in, rel=1e-6)


@pytest.mark.parametrize("name", sorted(CASES))
def test_every_case_simulates_inside_the_surrogate_domain(name):
    sol = simulate(CASES[name]())
    assert sol.status == "success"
    assert torch.isfinite(sol.observations).all()
    assert sol.stats.n_rhs_evals < 20_000


def test_batched_fleet_matches_single_runs():
    runs = [CASES["case1"](), CASES["case5"]()]
    both = simulate(runs)
    for e, run in enumerate(runs):
        one = simulate(run, t_eval=both.t_s)
        # Adaptive steps are shared across the batch, so agreement is to solver tolerance.
        assert torch.allclose(both.observations[e], one.observations[0], rtol=1e-5, atol=1e-6)


@needs_mhtb
def test_stiff_batch_shares_lsoda_jacobians_and_matches_single_runs():
    # MHTB's light aluminium wall makes the ODE stiff, so LSODA switches to BDF and estimates
    # Jacobians by finite differences. The environments do not interact; with the block band
    # declared, each Jacobian costs 2 * 7 - 1 right-hand sides whatever the batch. Measured on
    # this hour: one tank 190 evaluations, four 250 with the band and 400 without.
    run = read_run(MHTB / "P263981D.json").until(3600.0)
    one = simulate(run)
    four = simulate([run] * 4, t_eval=one.t_s)
    assert four.stats.n_rhs_evals < 1.6 * one.stats.n_rhs_evals
    for e in range(4):
        assert torch.allclose(four.observations[e], one.observations[0], rtol=1e-5, atol=1e-6)


def test_gradcheck_rhs_through_the_real_surrogate():
    """The right-hand side with the fitted surrogate and the reference closure, w.r.t. the state."""
    from tankode.forcing import Forcing

    fleet = Fleet.from_runs([case1()])
    model = TankModel(fleet.fluid, fleet.geometry, ReferenceClosure(), fleet.wall_heat_capacity_J_per_K)
    s0 = fleet.initial_state()
    scale = s0.abs()
    f = Forcing.rest(1, slosh_amplitude_m=0.01, slosh_frequency_Hz=0.57, mdot_v_in_kg_s=2e-3, h_v_in_J_per_kg=4.6e5)
    z = torch.ones_like(s0, requires_grad=True)
    # Scaled state and outputs so one eps suits every component; the surrogate's ~1e-9 relative
    # rounding noise (large cancelling RBF weights) needs eps ~1e-5 and tolerances to match.
    out_scale = model(torch.tensor(0.0), s0, f).abs().detach() + 1e-12
    torch.autograd.gradcheck(lambda x: model(torch.tensor(0.0), x * scale, f) / out_scale, (z,), eps=1e-5,
                             atol=1e-4, rtol=1e-3)


def test_domain_is_checked_over_each_runs_own_span_only():
    # A fleet integrates every run to the longest one's end: a short run's state past its own
    # end is not scored and must not fail the simulation; within its span it must.
    from tankode.errors import SimulationError
    from tankode.simulation import _check_domain

    fleet = Fleet.from_runs([case1().until(600.0), case1()])
    t = torch.tensor([0.0, 300.0, 600.0, 1200.0], dtype=torch.float64)
    states = fleet.initial_state()[:, None, :].repeat(1, 4, 1)  # (env, T, 7)
    states[0, 3, 2] = 5e6  # short run, after its end: a vapour energy far outside the domain
    _check_domain(fleet, t, states, STATE_NAMES)
    states[0, 2, 2] = 5e6  # at its last scored time
    with pytest.raises(SimulationError, match="run 'case1': the vapor state left"):
        _check_domain(fleet, t, states, STATE_NAMES)


def test_a_failed_simulation_names_the_mechanisms_own_states():
    # The error prints the state where the solver stopped; a mechanism's own state must be
    # printed by its name, as TankModel.state_names gives it, not as an anonymous extra.
    from tankode.errors import SimulationError
    from tankode.integrate import integrate, state_scale
    from tankode.mechanisms import MECHANISMS
    from tankode.solver import AdaptiveRK, NoGradient

    fleet = Fleet.from_runs([case1().until(60.0)])
    layer = MECHANISMS["surface_layer"](inv_thickness_1_per_m=100.0, wall_share=1.0, mixing_rate_1_per_s=0.0)
    model = TankModel(fleet.fluid, fleet.geometry, ReferenceClosure(), fleet.wall_heat_capacity_J_per_K, (layer,))
    s0 = model.initial_state(fleet.initial_state(model.mechanisms))  # (env, 8)
    s0[0, 7] = float("nan")  # the layer's excess: non-finite, so the first evaluation must fail
    t = torch.tensor([0.0, 60.0], dtype=torch.float64)
    with pytest.raises(SimulationError, match=r"surface_layer\.dT_layer_K=nan") as err:
        integrate(model, s0, fleet.segments(0.0, 60.0), fleet.forcing, t,
                  state_scale(s0, fleet.geometry.volume_m3, model.extra_state_scales), AdaptiveRK(), NoGradient())
    assert "extra_0" not in str(err.value)


@pytest.mark.parametrize("fluid,p_Pa", [("Nitrogen", 1.3e5), ("Methane", 1.5e5), ("Argon", 1.1e5)])
def test_a_tank_of_another_fluid_simulates_on_its_own_surrogate_and_conserves_mass_and_energy(fluid, p_Pa, tmp_path):
    """The format allows any CoolProp fluid: its run gets a surrogate on the fluid's storage tier
    (``tankode.properties.default_domain``) and the tank's balances hold as for hydrogen: a closed
    tank keeps its mass and gains exactly the wall's heat load, while phase change moves mass."""
    import json

    import CoolProp.CoolProp as CP

    from tankode.properties import default_domain

    T_sat = CP.PropsSI("T", "P", p_Pa, "Q", 0, fluid)
    meta = {"name": "other", "fluid": fluid, "source": "crafted", "timeseries": "other.csv",
            "tank": {"shape": "sphere", "radius_m": 0.8, "wall_heat_capacity_J_per_K": 1.0e5},
            "initial": {"p_v_Pa": p_Pa, "T_v_K": T_sat + 4.0, "T_l_K": T_sat - 0.5, "T_w_K": T_sat + 2.0,
                        "fill_ratio": 0.5}, "noise_std": {"p_v": 300.0}, "duration_s": 1800.0}
    (tmp_path / "other.json").write_text(json.dumps(meta))
    (tmp_path / "other.csv").write_text(f"t_s,p_v_Pa,Q_aw_W,slosh_amplitude_m,slosh_frequency_Hz\n0,{p_Pa},250,0,0\n"
                                        f"900,{p_Pa},,0.005,0.6\n1800,{p_Pa},,,\n")
    run = read_run(tmp_path / "other.json")
    fleet = Fleet.from_runs([run])
    assert fleet.fluid.domain == default_domain(fluid)
    sol = simulate(fleet)
    s, t = sol.states[0], sol.t_s
    mass = s[:, 0] + s[:, 1]
    assert float((mass - mass[0]).abs().max() / mass[0]) < 1e-9
    model = TankModel(fleet.fluid, fleet.geometry, ReferenceClosure(), fleet.wall_heat_capacity_J_per_K)
    E = model.total_energy_J(sol.states)[0]
    scale = float(mass[0]) * 2.0e5  # total mass x a latent heat of this order
    assert float((E - E[0] - 250.0 * t).abs().max()) / scale < 1e-6
    assert float((s[:, 0] - s[0, 0]).abs().max()) > 1e-3 * float(s[0, 0])  # phase change happened
