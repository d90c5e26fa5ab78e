"""Adjoint vs backprop vs checkpointed backprop vs central finite differences of the assimilation cost."""

import pytest
import torch

from finite_differences import central_difference
from tankode.cases import case1
from tankode.closures import ConstantClosure, MLPClosure, MLPConfig
from tankode.mechanisms import make_mechanism
from tankode.simulation import simulate
from tankode.solver import Adjoint, Backprop, Checkpointed, NoGradient
from tankode.synthetic import solution_to_runs
from trainers.assimilate import AssimilationConfig, Assimilator
from trainers.cost import Window, cost

TIGHT = dict(rtol=1e-10, atol=1e-12)


@pytest.fixture(scope="module")
def data():
    run = case1()
    (obs,) = solution_to_runs(run, simulate(run), noise="high", seed=0)
    return obs


def _setup(data, closure, t0=600.0, t1=780.0, mechanisms=()):
    """A 3-minute window starting with sloshing, integrated from the state at t0."""
    a = Assimilator([data], AssimilationConfig.paper(**TIGHT), closure=closure, mechanisms=mechanisms)
    with torch.no_grad():
        s_start = a.predict(a.s0, 0.0, torch.tensor([0.0, t0], dtype=torch.float64), NoGradient())[:, -1]
    w = Window.from_runs(a.fleet.runs, t0, t1)
    t_eval = torch.cat([torch.tensor([t0], dtype=torch.float64), w.t_s])

    def J(gradient):
        return cost(a.model.observe(a.predict(s_start, t0, t_eval, gradient)[:, 1:]), w)

    return a, J


def _grad(a, J, gradient):
    for p in a.closure.parameters():
        p.grad = None
    J(gradient).backward()
    return torch.cat([p.grad.reshape(-1) for p in a.closure.parameters()])


def _rel(a, b):
    return float((a - b).norm() / b.norm())


def _check_constant_closure(a, J, closure):
    g_bp = _grad(a, J, Backprop())
    g_adj = _grad(a, J, Adjoint())
    fd = central_difference(lambda: J(NoGradient()), closure.theta)
    assert float(fd.norm()) > 1e-3  # a real slope, not a flat cost
    assert _rel(g_bp, fd) < 1e-4
    assert _rel(g_adj, fd) < 1e-4
    assert _rel(g_adj, g_bp) < 1e-4
    return g_adj


def test_checkpointed_gradient_is_backprops(data):
    """Checkpointed() recomputes each output interval's steps in the backward pass and gives the
    exact gradient of its own discrete solution, which restarts the step controller at each output
    time: Backprop's gradient to the solver's tolerance (closure and initial state; measured
    1.7e-8 at rtol 1e-10), with a graph that keeps none of the solver's steps."""
    closure = ConstantClosure([2.0, 15.0, 40.0, 150.0], trainable=True)
    a, J = _setup(data, closure)
    g_bp = _grad(a, J, Backprop())
    g_ck = _grad(a, J, Checkpointed())
    assert float(g_bp.norm()) > 1e-3 and _rel(g_ck, g_bp) < 1e-6
    from trainers.bench import _saved_bytes

    t0, w = 600.0, Window.from_runs(a.fleet.runs, 600.0, 780.0)
    t_eval = torch.cat([torch.tensor([t0], dtype=torch.float64), w.t_s])
    with torch.no_grad():
        s_start = a.predict(a.s0, 0.0, torch.tensor([0.0, t0], dtype=torch.float64), NoGradient())[:, -1]
    s_start.requires_grad_(True)
    grads = {}
    for gradient in (Backprop(), Checkpointed()):
        out = a.model.observe(a.predict(s_start, t0, t_eval, gradient)[:, 1:])
        (grads[type(gradient).__name__],) = torch.autograd.grad(cost(out, w), s_start)
    assert float(grads["Backprop"].norm()) > 0 and _rel(grads["Checkpointed"], grads["Backprop"]) < 1e-6
    sizes = {type(g).__name__: _saved_bytes(lambda g=g: J(g)) for g in (Backprop(), Checkpointed())}
    assert sizes["Checkpointed"] < 0.2 * sizes["Backprop"], sizes


def test_checkpointed_recomputation_is_not_charged_to_the_budget(data):
    """The backward pass re-runs every interval: with a per-segment budget of 1.5 times what the
    forward pass needs, the gradient still comes (charged twice, it would exceed the budget)."""
    from tankode.integrate import integrate
    from tankode.solver import AdaptiveRK

    closure = ConstantClosure([2.0, 15.0, 40.0, 150.0], trainable=True)
    a, _ = _setup(data, closure)
    seg, t_eval = [(600.0, 720.0)], torch.linspace(600.0, 720.0, 7, dtype=torch.float64)
    with torch.no_grad():
        s_start = a.predict(a.s0, 0.0, torch.tensor([0.0, 600.0], dtype=torch.float64), NoGradient())[:, -1]
    n = integrate(a.model, s_start, seg, a.fleet.forcing, t_eval, a.scale, AdaptiveRK(**TIGHT), Checkpointed())[1].n_rhs_evals
    solver = AdaptiveRK(**TIGHT, max_rhs_evals=int(1.5 * n))
    states, _ = integrate(a.model, s_start, seg, a.fleet.forcing, t_eval, a.scale, solver, Checkpointed())
    (g,) = torch.autograd.grad(states[..., 1].sum(), closure.theta)
    assert torch.isfinite(g).all() and float(g.abs().max()) > 0


def test_constant_closure_gradient_adjoint_backprop_fd(data):
    closure = ConstantClosure([2.0, 15.0, 40.0, 150.0], trainable=True)
    a, J = _setup(data, closure)
    _check_constant_closure(a, J, closure)


def test_gradient_through_a_mechanism_state_adjoint_backprop_fd(data):
    """The adjoint carries a mechanism's own state (a surface layer's excess, an 8th component)."""
    layer = make_mechanism("surface_layer", inv_thickness_1_per_m=500.0)  # a 2 mm layer, no mixing
    closure = ConstantClosure([2.0, 15.0, 40.0, 150.0], trainable=True)
    a, J = _setup(data, closure, mechanisms=[layer])
    assert a.s0.shape == (1, 8)
    g = _check_constant_closure(a, J, closure)
    # the layer changes the gradient: the check above is not the baseline's again
    b, Jb = _setup(data, ConstantClosure([2.0, 15.0, 40.0, 150.0], trainable=True))
    assert _rel(g, _grad(b, Jb, Backprop())) > 1e-3


def test_mlp_directional_derivatives_adjoint_backprop_fd(data):
    mlp = MLPClosure(MLPConfig(seed=1))
    with torch.no_grad():  # leave the zero-initialised last layer so every weight matters
        for p in mlp.parameters():
            p.add_(0.05 * torch.randn(p.shape, generator=torch.Generator().manual_seed(p.numel()), dtype=torch.float64))
    a, J = _setup(data, mlp)
    g_bp = _grad(a, J, Backprop())
    g_adj = _grad(a, J, Adjoint())
    assert _rel(g_adj, g_bp) < 1e-4
    params = list(mlp.parameters())
    w0 = [p.detach().clone() for p in params]
    gen = torch.Generator().manual_seed(7)
    for _ in range(3):
        v = [torch.randn(p.shape, generator=gen, dtype=torch.float64) for p in params]
        h = 1e-5
        vals = []
        with torch.no_grad():
            for sign in (1, -1):
                for p, p0, d in zip(params, w0, v):
                    p.copy_(p0 + sign * h * d)
                vals.append(float(J(NoGradient())))
            for p, p0 in zip(params, w0):
                p.copy_(p0)
        fd = (vals[0] - vals[1]) / (2 * h)
        vflat = torch.cat([d.reshape(-1) for d in v])
        assert abs(fd) > 1e-6
        assert float(g_bp @ vflat) == pytest.approx(fd, rel=1e-4)
        assert float(g_adj @ vflat) == pytest.approx(fd, rel=1e-4)


def test_adjoint_rejects_lsoda():
    from tankode.integrate import integrate
    from tankode.solver import LSODA

    with pytest.raises(ValueError, match="forward only"):
        integrate(None, torch.zeros(1, 7), [(0.0, 1.0)], None, torch.tensor([1.0]), torch.ones(1, 7), LSODA(),
                  Adjoint())


def test_a_failure_in_the_adjoint_backward_pass_is_a_simulation_error(data):
    """The backward solve runs outside integrate(): a bad state there must still be a SimulationError
    (which the trainers reject as an infeasible trial point), naming the time, not a bare ValueError."""
    from tankode.errors import SimulationError

    class FailsBackward(ConstantClosure):
        armed = False

        def forward(self, x):
            if self.armed:
                raise ValueError("level_at_volume got liquid volume(s) outside [0, tank volume]")
            return super().forward(x)

    closure = FailsBackward([2.0, 15.0, 40.0, 150.0], trainable=True)
    a, J = _setup(data, closure, t1=660.0)
    loss = J(Adjoint())
    closure.armed = True
    with pytest.raises(SimulationError, match=r"right-hand side failed: level_at_volume.*at t = "):
        loss.backward()
