"""The ROS34PW2 Rosenbrock-W solver: accuracy on stiff analytic problems, gradients, budget, tanks."""

import json
import math

import numpy as np
import pytest
import torch

from finite_differences import central_difference
from mhtb_data import MHTB, needs_mhtb
from tankode.cases import case1
from tankode.closures import ConstantClosure
from tankode.errors import SimulationError
from tankode.integrate import integrate
from tankode.rosenbrock import rosenbrock_solve
from tankode.run_io import read_run
from tankode.simulation import simulate
from tankode.solver import LSODA, Adjoint, Backprop, Checkpointed, NoGradient, Rosenbrock
from tankode.synthetic import solution_to_runs
from trainers.assimilate import AssimilationConfig, Assimilator
from trainers.cost import Window, cost

# A stiff linear system with a slow and a fast mode (eigenvalues -1 and -1e4), not diagonal, so
# that the fast mode couples into both components: y(t) = expm(A t) y0 exactly.
_A = torch.tensor([[-5000.5, 4999.5], [4999.5, -5000.5]], dtype=torch.float64)


class _Linear:
    def __init__(self):
        self.n = 0

    def __call__(self, t, z):  # z (env, 2)
        self.n += 1
        return z @ _A.T


def test_stiff_linear_system_matches_the_matrix_exponential_and_converges():
    """Errors fall with the tolerance (third order: 1e-6 -> 1e-9 gains >= 100x) and stay at the
    tolerance's size; the fast mode (time constant 1e-4 s) does not hold the steps to its scale:
    the 2 s run takes a few hundred right-hand sides (an explicit solver needs ~4e4)."""
    ts = torch.tensor([0.0, 0.5, 2.0], dtype=torch.float64)
    y0 = torch.tensor([[1.0, 0.0]], dtype=torch.float64)
    exact = torch.stack([y0 @ torch.linalg.matrix_exp(_A * t).T for t in ts])  # (3, 1, 2)
    errors, evals = [], []
    for tol in (1e-6, 1e-9):
        f = _Linear()
        y = rosenbrock_solve(f, y0, ts, rtol=tol, atol=tol)
        errors.append(float((y[1:] - exact[1:]).abs().max()))
        evals.append(f.n)
    assert errors[0] < 1e-5 and errors[1] < 1e-8, errors
    assert errors[1] < errors[0] / 100, errors
    assert evals[0] < 600, evals


def test_a_fleet_restarts_with_the_last_jacobian_at_fewer_evaluations_and_the_same_states():
    """32 jittered tanks (four light walls) over 10 minutes: the batched ODE restarts at every
    tank's input change. Starting each segment with the previous segment's Jacobian (a W-method
    keeps its order with a stale one) takes fewer right-hand sides than cold restarts, and the
    states agree within a tenth of the lowest example noise (300 Pa, 0.05 K). Fails if the warm
    start is ignored (same count) or spoils the solution."""
    from tankode.fleet import Fleet
    from tankode.integrate import state_scale
    from tankode.model import TankModel
    from trainers.fleet_bench import FleetSpec, jittered_runs

    runs = jittered_runs(FleetSpec(32))
    fleet = Fleet.from_runs(runs)
    model = TankModel(fleet.fluid, fleet.geometry, AssimilationConfig().agent(0), fleet.wall_heat_capacity_J_per_K, ())
    segments = fleet.segments(0.0, 600.0)
    assert len(segments) >= 10
    ts = torch.linspace(0.0, 600.0, 61, dtype=torch.float64)
    out = {}
    with torch.no_grad():
        s0 = model.initial_state(fleet.initial_state(model.mechanisms))
        scale = state_scale(s0, fleet.geometry.volume_m3, model.extra_state_scales)
        for warm in (False, True):
            states, stats = integrate(model, s0, segments, fleet.forcing, ts, scale,
                                      Rosenbrock(1e-5, 1e-7, warm_start=warm), NoGradient())
            out[warm] = (model.observe(states), stats.n_rhs_evals)
    (y_cold, n_cold), (y_warm, n_warm) = out[False], out[True]
    assert n_warm < 0.92 * n_cold, (n_warm, n_cold)
    diff = (y_cold - y_warm).abs().amax(dim=(0, 1))  # (5,): p, T_v, T_l, T_w, H_l
    assert float(diff[0]) < 30.0 and float(diff[1:4].max()) < 0.005 and float(diff[4]) < 1e-4, diff


def test_gradient_is_the_exact_sensitivity_of_the_stiff_system():
    """Backprop through the steps with the Jacobian frozen (a W-method) gives d y(T) / d y0 =
    expm(A T) to the tolerance, both columns, fast mode included."""
    T = 0.05
    exact = torch.linalg.matrix_exp(_A * T)
    rows = []
    for i in range(2):
        y0 = torch.tensor([[1.0, 0.3]], dtype=torch.float64, requires_grad=True)
        y = rosenbrock_solve(_Linear(), y0, torch.tensor([0.0, T], dtype=torch.float64), rtol=1e-10, atol=1e-12)
        (g,) = torch.autograd.grad(y[-1, 0, i], y0)
        rows.append(g[0])
    assert torch.allclose(torch.stack(rows), exact, rtol=0, atol=1e-8)


def test_dense_outputs_do_not_shorten_the_steps():
    """Outputs come from the Hermite interpolant of the step spanning them: 200 output times cost
    no more right-hand sides than 2, and the interpolated values are within tolerance."""
    y0 = torch.tensor([[1.0, 0.0]], dtype=torch.float64)
    few, many = _Linear(), _Linear()
    rosenbrock_solve(few, y0, torch.tensor([0.0, 2.0], dtype=torch.float64), rtol=1e-8, atol=1e-8)
    ts = torch.linspace(0.0, 2.0, 200, dtype=torch.float64)
    y = rosenbrock_solve(many, y0, ts, rtol=1e-8, atol=1e-8)
    assert many.n <= few.n + 10
    exact = torch.stack([y0 @ torch.linalg.matrix_exp(_A * t).T for t in ts])
    assert float((y - exact).abs().max()) < 1e-6


def test_the_budget_ends_the_solve_with_time_and_state():
    run = case1().until(600.0)
    with pytest.raises(SimulationError, match="exceeded 30 right-hand-side evaluations") as err:
        simulate(run, solver=Rosenbrock(max_rhs_evals=30))
    assert err.value.t_s is not None and "m_v" in str(err.value)


def test_no_adjoint():
    with pytest.raises(ValueError, match="no continuous adjoint"):
        AssimilationConfig(integrator="rosenbrock", gradient=Adjoint())
    with pytest.raises(ValueError, match="integrator must be one of"):
        AssimilationConfig(integrator="euler")
    cfg = AssimilationConfig(integrator="rosenbrock", gradient=Backprop())
    assert AssimilationConfig.from_json(cfg.to_json()) == cfg
    old = json.loads(AssimilationConfig.paper().to_json())
    for key in ("integrator", "wall", "agent_base"):  # a checkpoint written before these existed
        del old[key]
    old_defaults = AssimilationConfig.paper()
    assert AssimilationConfig.from_json(json.dumps(old)) == old_defaults
    run = case1().until(60.0)
    a = Assimilator([run], AssimilationConfig())
    with pytest.raises(ValueError, match="no continuous adjoint"):
        integrate(a.model, a.s0, [(0.0, 60.0)], a.fleet.forcing, torch.tensor([60.0], dtype=torch.float64), a.scale,
                  Rosenbrock(), Adjoint())


def test_case1_matches_the_reference_simulation():
    """On case 1's hour (sloshing, injection, venting) the tank agrees with LSODA to the tolerance."""
    run = case1()
    ref = simulate(run, solver=LSODA(rtol=1e-10, atol=1e-12)).observations[0]
    sol = simulate(run, solver=Rosenbrock(rtol=1e-8, atol=1e-10))
    d = (sol.observations[0] - ref).abs().amax(dim=0)  # (5,) p [Pa], T_v, T_l, T_w [K], H_l [m]
    assert float(d[0]) < 1.0 and float(d[1:4].max()) < 1e-4 and float(d[4]) < 1e-7, d


def test_closure_gradient_matches_dopri5_and_finite_differences():
    """The gradient check of tests/test_gradients.py, for the Rosenbrock solver: on a 3-minute window of case 1 with
    sloshing, Backprop and Checkpointed through ROS34PW2 agree with central finite differences and
    with Backprop through dopri5 to 1e-4 relative (norm and direction; measured 3e-7 and 2.4e-6)."""
    run = case1()
    (data,) = solution_to_runs(run, simulate(run), noise="high", seed=0)
    closure = ConstantClosure([2.0, 15.0, 40.0, 150.0], trainable=True)
    t0, t1 = 600.0, 780.0
    grads = {}
    for integrator, gradients in (("dopri5", (Backprop(),)), ("rosenbrock", (Backprop(), Checkpointed()))):
        a = Assimilator([data], AssimilationConfig(rtol=1e-9, atol=1e-11, integrator=integrator, gradient=Backprop()),
                        closure=closure)
        with torch.no_grad():
            s_start = a.predict(a.s0, 0.0, torch.tensor([0.0, t0], dtype=torch.float64), NoGradient())[:, -1]
        w = Window.from_runs(a.fleet.runs, t0, t1)
        t_eval = torch.cat([torch.tensor([t0], dtype=torch.float64), w.t_s])

        def J(gradient, a=a, s_start=s_start, w=w, t_eval=t_eval):
            return cost(a.model.observe(a.predict(s_start, t0, t_eval, gradient)[:, 1:]), w)

        for gradient in gradients:
            closure.theta.grad = None
            J(gradient).backward()
            grads[(integrator, type(gradient).__name__)] = closure.theta.grad.clone()
        if integrator == "rosenbrock":
            fd = central_difference(lambda J=J: J(NoGradient()), closure.theta)
    ref = grads[("dopri5", "Backprop")]
    assert float(ref.norm()) > 1e-3
    for key in (("rosenbrock", "Backprop"), ("rosenbrock", "Checkpointed")):
        g = grads[key]
        assert float((g - ref).norm() / ref.norm()) < 1e-4, (key, g, ref)
        assert float((g - fd).norm() / fd.norm()) < 1e-4, (key, g, fd)


@needs_mhtb
def test_stiff_real_tank_is_integrated_in_few_steps_and_a_window_trains():
    """MHTB P263981D's light wall: ROS34PW2 follows LSODA over 2 h within 1 Pa and 1e-5 K in under
    1,500 right-hand sides (measured 1,333 at rtol 1e-8; dopri5 needs 22,274 at rtol 1e-6), and
    a 30-minute window of the untrained agent trains with Backprop (J falls), which the adjoint
    cannot (test_assimilate: the adjoint's backward pass turns the state NaN). Six iterations: with
    the boiling share trained from its start J falls from 8.5 to 4.5."""
    run = read_run(MHTB / "P263981D.json").until(7200.0)
    ref = simulate(run, solver=LSODA(rtol=1e-10, atol=1e-12))
    sol = simulate(run, solver=Rosenbrock(rtol=1e-8, atol=1e-10))
    d = (sol.observations[0] - ref.observations[0]).abs().amax(dim=0)
    assert float(d[0]) < 1.0 and float(d[1:4].max()) < 1e-5, d
    assert sol.stats.n_rhs_evals < 1500, sol.stats

    a = Assimilator([run.until(1800.0)], AssimilationConfig(window_s=1800.0, iters=6, integrator="rosenbrock",
                                                            gradient=Backprop()))
    report, _, _ = a.update(0, a.s0)
    assert report.note == "" and math.isfinite(report.cost_after) and report.cost_after < 0.6 * report.cost_before


def test_a_stage_outside_the_domain_rejects_the_step():
    """A stage outside the model's domain (here: a right-hand side that refuses y1 > 1.5) shrinks
    the step instead of ending the solve; the solution is the same as without the refusal."""
    class Guarded(_Linear):
        refused = 0

        def __call__(self, t, z):
            if float(z[..., 0].max()) > 1.5:
                self.refused += 1
                raise SimulationError("outside the domain", float(t), z)
            return super().__call__(t, z)

    ts = torch.tensor([0.0, 1.0], dtype=torch.float64)
    y0 = torch.tensor([[1.0, 2.0]], dtype=torch.float64)  # y1 relaxes from 1 towards 1.5 in 1e-4 s
    f = Guarded()
    y = rosenbrock_solve(f, y0, ts, rtol=1e-8, atol=1e-10, first_step=0.5)
    assert f.refused >= 1
    exact = y0 @ torch.linalg.matrix_exp(_A * 1.0).T
    np.testing.assert_allclose(y[-1].numpy(), exact.numpy(), atol=1e-8)
