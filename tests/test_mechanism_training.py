"""Mechanism parameters trained with the agent (``AssimilationConfig.train_mechanisms``)."""

from __future__ import annotations

import json

import pytest
import torch

from finite_differences import central_difference
from tankode.closures import ConstantClosure
from tankode.mechanisms import make_mechanism
from tankode.run import InitialState, Run, TankSpec
from tankode.schedule import Schedule
from tankode.simulation import simulate
from tankode.solver import Adjoint, Backprop, Checkpointed
from tankode.synthetic import solution_to_runs
from trainers.assimilate import AssimilationConfig, Assimilator
from trainers.cost import Window, cost

TRUTH = ConstantClosure([50.0, 200.0, 500.0, 1000.0])  # W/(m^2 K); known and fixed: the mechanisms are the unknowns
HIDDEN = {"heat_leak_vapor": {"Q_W": 400.0}, "wall_heat_capacity_error": {"eps": 0.6}}


def _run(duration=300.0):
    return Run(
        name="leaky", fluid="ParaHydrogen",
        tank=TankSpec.from_dict({"shape": "vertical_cylinder", "radius_m": 0.9, "height_m": 2.2,
                                 "wall_heat_capacity_J_per_K": 2.0e5}),
        initial=InitialState(p_v_Pa=2.0e5, T_v_K=24.0, T_l_K=22.5, T_w_K=23.5, fill_ratio=0.6),
        duration_s=duration, inputs=Schedule.from_steps([(0, {})], t_end=duration),
    )


START = {"heat_leak_vapor": {"Q_W": 10.0}, "wall_heat_capacity_error": {"eps": 0.0}}  # strictly inside the bounds


def _assimilator(data, iters=20, start=START, **cfg):
    """One growing window over the whole run, the closure known, ``start``'s mechanisms trained."""
    mechanisms = tuple(make_mechanism(mid, **v) for mid, v in start.items())
    config = AssimilationConfig.paper(window_s=1e9, mode="growing", iters=iters, gradient=Backprop(),
                                      train_mechanisms=tuple(start), **cfg)
    return Assimilator([data], config, closure=TRUTH, mechanisms=mechanisms)


def _clean_run_with(hidden: dict):
    """The run simulated with the ``hidden`` mechanisms, clean observations."""
    mechanisms = tuple(make_mechanism(mid, **v) for mid, v in hidden.items())
    (d,) = solution_to_runs(_run(), simulate(_run(), TRUTH, mechanisms=mechanisms), noise="clean")
    return d


@pytest.fixture(scope="module")
def data():
    return _clean_run_with(HIDDEN)


@pytest.mark.parametrize("gradient", [Backprop(), Adjoint(), Checkpointed()], ids=lambda g: type(g).__name__)
def test_gradient_in_a_mechanism_parameter_matches_central_differences(data, gradient):
    """d J / d (value / scale) through the trained mechanisms, by every gradient strategy, against
    central differences (the adjoint differentiates only the model's registered parameters)."""
    # Tight tolerances: the wall (23.5 K) heats the liquid past saturation into the flash's onset
    # (tankode.bulk, 0.02 K wide), and at the training tolerances the step selection makes the
    # central difference itself noisy at 1e-4.
    a = _assimilator(data, rtol=1e-10, atol=1e-12)
    (_, xi_leak), (_, xi_wall) = a.trained.named()
    with torch.no_grad():
        xi_leak.fill_(2.0)  # 200 W, eps 0.2: away from the truth and from 0, where the steps are relative
        xi_wall.fill_(2.0)
    window = Window.from_runs(a.fleet.runs, a.fleet.t0_s - 1e-9, a.fleet.t_end_s)
    t_eval = window.t_s

    def J():
        return cost(a.model.observe(a.predict(a.s0, a.fleet.t0_s, t_eval, gradient)), window)

    J().backward()
    for xi in (xi_leak, xi_wall):
        fd = central_difference(J, xi)
        assert torch.allclose(xi.grad, fd, rtol=1e-5), (xi.grad.item(), fd.item())


def test_hidden_heat_leak_and_wall_capacity_are_recovered_and_saved(data, tmp_path):
    """Two mechanisms hidden in clean data, started near absent, the closure known: one window's update
    recovers both within 1 %, reports them, and the saved model carries the trained values."""
    from tankode.saved import load_model, save_model

    a = _assimilator(data, iters=30)
    result = a.run()
    got = result.reports[-1].mechanisms
    assert got["heat_leak_vapor"]["Q_W"] == pytest.approx(400.0, rel=0.01), got
    assert got["wall_heat_capacity_error"]["eps"] == pytest.approx(0.6, rel=0.01), got
    assert result.reports[-1].cost_after < 1e-3 * result.reports[-1].cost_before
    # the mechanisms passed in hold the trained values, without a graph
    leak = a.model.mechanisms[0]
    assert not leak.value.requires_grad and leak.values_dict()["Q_W"] == pytest.approx(got["heat_leak_vapor"]["Q_W"])
    save_model(tmp_path / "m", TRUTH, data.fluid, mechanisms=a.model.mechanisms)
    _, mechanisms, _ = load_model(tmp_path / "m")
    assert {m.id: m.values_dict() for m in mechanisms} == got


# Mechanisms that offset the readings the first state is built from: 120 mol of helium carry
# 6.7 % of the 2 bar reading in the 60 % full tank; the liquid thermometer reads 0.3 K high.
READINGS = {"noncondensable_gas": {"n_mol": 120.0}, "temperature_sensor_bias": {"bias_K": 0.3}}


@pytest.fixture(scope="module")
def offset_data():
    return _clean_run_with(READINGS)


READINGS_START = {"noncondensable_gas": {"n_mol": 40.0}, "temperature_sensor_bias": {"bias_K": 0.1}}  # a third


def test_gradient_through_the_first_state_built_from_offset_readings(offset_data):
    """d J / d xi of an inert gas and a thermometer bias, whose values also set the first state
    (the hydrogen's pressure is the reading less the gas's, the liquid's temperature the reading
    less the bias), against central differences: the start's linearisation carries the slope."""
    a = _assimilator(offset_data, start=READINGS_START, rtol=1e-10, atol=1e-12)
    (_, xi_gas), (_, xi_bias) = a.trained.named()
    window = Window.from_runs(a.fleet.runs, a.fleet.t0_s - 1e-9, a.fleet.t_end_s)

    def J():
        a.trained.apply()
        return cost(a.model.observe(a.predict(a.start_state(), a.fleet.t0_s, window.t_s, Backprop())), window)

    J().backward()
    for xi in (xi_gas, xi_bias):
        # A step of 1e-3: the adaptive solver's steps move with xi, a noise of ~1e-9 in J that a
        # step of 1e-4 turns into 2e-5 in the slope (measured; 1e-3 and 3e-4 agree within 2e-6).
        fd = central_difference(J, xi, rel_step=1e-3)
        assert torch.allclose(xi.grad, fd, rtol=1e-5), (xi.grad.item(), fd.item())
    # without the start's slope, the gradient in the gas would be the sensor offset's alone
    with torch.no_grad():
        s_fixed = a.start_state()
    xi_gas.grad = None
    a.trained.apply()
    cost(a.model.observe(a.predict(s_fixed, a.fleet.t0_s, window.t_s, Backprop())), window).backward()
    assert not torch.allclose(xi_gas.grad, central_difference(J, xi_gas), rtol=0.1)


def test_inert_gas_and_thermometer_bias_trained_with_the_start_are_recovered(offset_data):
    """Hidden in clean data (the closure known), started at a third of their values: one update
    recovers both within 1 % and leaves the assimilator's first state built from them."""
    a = _assimilator(offset_data, iters=30, start=READINGS_START)
    result = a.run()
    got = result.reports[-1].mechanisms
    assert got["noncondensable_gas"]["n_mol"] == pytest.approx(120.0, rel=0.01), got
    assert got["temperature_sensor_bias"]["bias_K"] == pytest.approx(0.3, rel=0.01), got
    assert result.reports[-1].cost_after < 1e-3 * result.reports[-1].cost_before
    assert torch.equal(a.s0, a.start_state())


@pytest.mark.parametrize("ids,message", [
    (("vapor_leak",), "not among the model's mechanisms"),
    (("heat_leak_liquid",), "starts on its bound"),
])
def test_refused_mechanisms_say_why(data, ids, message):
    mechanisms = (make_mechanism("pressure_sensor_bias", bias_Pa=0.0), make_mechanism("heat_leak_liquid", Q_W=0.0))
    with pytest.raises(ValueError, match=message):
        Assimilator([data], AssimilationConfig.paper(train_mechanisms=ids), closure=TRUTH, mechanisms=mechanisms)


def test_config_validates_and_round_trips_train_mechanisms():
    from trainers.memory import LaplaceMemory

    cfg = AssimilationConfig.paper(train_mechanisms=("dry_wall_node",))
    assert AssimilationConfig.from_json(cfg.to_json()) == cfg
    with pytest.raises(ValueError, match="distinct mechanism ids"):
        AssimilationConfig.paper(train_mechanisms=("a", "a"))
    with pytest.raises(ValueError, match="distinct mechanism ids"):
        AssimilationConfig.paper(train_mechanisms=["dry_wall_node"])
    with pytest.raises(ValueError, match="Forget"):
        AssimilationConfig.paper(train_mechanisms=("dry_wall_node",), memory=LaplaceMemory())


class _Killed(Exception):
    pass


def test_interrupted_training_resumes_to_the_same_mechanism_values(data, tmp_path):
    """Two growing windows: stopped after the first (its checkpoint written) and resumed by a fresh
    assimilator, the trained values and weights end bit for bit where an uninterrupted run ends."""
    from tankode.closures import MLPClosure, MLPConfig

    def assimilator():
        mechanisms = tuple(make_mechanism(mid, **v) for mid, v in START.items())
        cfg = AssimilationConfig.paper(window_s=150.0, mode="growing", iters=4, gradient=Backprop(),
                                 train_mechanisms=tuple(HIDDEN))
        return Assimilator([data], cfg, closure=MLPClosure(MLPConfig(seed=0)), mechanisms=mechanisms)

    ref = assimilator()
    ref.run()

    def kill(report):
        raise _Killed

    with pytest.raises(_Killed):
        assimilator().run(checkpoint=tmp_path / "ck.pt", on_window=kill)
    resumed = assimilator()
    resumed.run(checkpoint=tmp_path / "ck.pt", resume=True)
    assert resumed.trained.values() == ref.trained.values() != START
    for (n, w), (_, w_ref) in zip(resumed.closure.state_dict().items(), ref.closure.state_dict().items()):
        assert torch.equal(w, w_ref), n


def _unstated_wall_run():
    """``_run`` with no wall heat capacity stated and 400 W entering the wall, so that it warms."""
    import dataclasses

    run = _run()
    tank = dataclasses.replace(run.tank, wall_heat_capacity_J_per_K=None)
    return dataclasses.replace(run, tank=tank, inputs=Schedule.from_steps([(0, {"Q_aw_W": 400.0})], t_end=300.0))


def test_a_wall_no_one_states_is_learned_on_a_log_scale():
    """A wall 40 times tankode's aluminium-shell estimate, in a run that states none: with the
    default ``unknown_wall="trained"`` the assimilation adds the log factor and one window recovers
    it within 1 % (the closure known); a run that states its wall, or ``unknown_wall="assumed"``,
    trains none."""
    import dataclasses
    import math

    from tankode.mechanisms import UNKNOWN_WALL_FACTOR_RANGE

    run = _unstated_wall_run()
    truth = (make_mechanism("unknown_wall_capacity", ln_factor=math.log(40.0)),)
    (data,) = solution_to_runs(run, simulate(run, TRUTH, mechanisms=truth), noise="clean")
    data = dataclasses.replace(data, tank=run.tank)  # the data state no wall either
    config = AssimilationConfig.paper(window_s=1e9, mode="growing", iters=30, gradient=Backprop(),
                                      unknown_wall="trained")
    a = Assimilator([data], config, closure=TRUTH)
    assert [m.id for m in a.trained.mechanisms] == ["unknown_wall_capacity"]
    assert UNKNOWN_WALL_FACTOR_RANGE[0] < 40.0 < UNKNOWN_WALL_FACTOR_RANGE[1]
    (report,) = a.run().reports
    # the decade walk before the update (Assimilator._scan_unknown_wall), then L-BFGS
    assert "heat capacity moved from 1 to 10 times" in report.note, report.note
    assert math.exp(report.mechanisms["unknown_wall_capacity"]["ln_factor"]) == pytest.approx(40.0, rel=0.01)
    assert not Assimilator([data], AssimilationConfig.paper(unknown_wall="assumed"), closure=TRUTH).trained.mechanisms
    stated = Assimilator([_clean_run_with({})], AssimilationConfig.paper(unknown_wall="trained"), closure=TRUTH)
    assert "unknown_wall_capacity" not in {m.id for m in stated.model.mechanisms}
    # the learned factor does not multiply a wall a run states: simulate drops it, and says so
    learned = simulate(_run(), TRUTH, mechanisms=truth)
    assert torch.equal(learned.states, simulate(_run(), TRUTH).states)
    assert any("is not applied: a run states its wall" in n for n in learned.notes), learned.notes
    # a configuration saved before the option existed kept the shell's estimate
    legacy = json.loads(AssimilationConfig().to_json())
    del legacy["unknown_wall"]
    assert AssimilationConfig.from_json(json.dumps(legacy)).unknown_wall == "assumed"
    with pytest.raises(ValueError, match="unknown_wall"):
        AssimilationConfig(unknown_wall="learned")
