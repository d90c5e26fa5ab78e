"""The bounded, mini-batch L-BFGS wrapper: scipy's L-BFGS-B optima, batches, history, exact resume."""

import io
import math

import numpy as np
import pytest
import torch
from scipy.optimize import minimize

from trainers.lbfgs import Box, BoundedLBFGS, MiniBatch, OverlapBatches, ResetHistory, StepResult, StopStep, uniform_box
from trainers.lbfgs import _Fold

F64 = torch.float64


# ----------------------------------------------------------------------------------------------
# The bound-respecting map
# ----------------------------------------------------------------------------------------------


def test_fold_maps_every_latent_value_into_the_box_c1_smoothly():
    lo, hi = torch.tensor([-1.0, 0.2]), torch.tensor([2.0, 0.3])
    fold = _Fold(lo.to(F64), hi.to(F64))
    z = torch.linspace(-20.0, 20.0, 80_001, dtype=F64)[:, None].expand(-1, 2)
    w, slope = fold.w(z), fold.slope(z)
    assert bool(((w >= fold.lo) & (w <= fold.hi)).all())
    assert torch.allclose(w.min(0).values, fold.lo, atol=1e-9) and torch.allclose(w.max(0).values, fold.hi, atol=1e-9)
    # slope is the derivative (central differences), and it is continuous (C1): no jumps.
    h = 1e-6
    fd = (fold.w(z + h) - fold.w(z - h)) / (2 * h)
    assert (fd - slope).abs().max() < h / fold.eps.min()  # O(h) only where the curvature jumps (cap ends)
    assert (slope[1:] - slope[:-1]).abs().max() < 2 * (z[1, 0] - z[0, 0]) / fold.eps.min()
    # Away from the caps the fold is the identity, and z_of inverts it on the first fold.
    inner = torch.tensor([[0.5, 0.25]], dtype=F64)
    assert torch.allclose(fold.w(inner), inner, rtol=0, atol=1e-15)
    ws = fold.lo + (fold.hi - fold.lo) * torch.tensor([[1e-9], [0.01], [0.3], [0.99], [1 - 1e-9]], dtype=F64)
    assert torch.allclose(fold.w(fold.z_of(ws)), ws, rtol=1e-12, atol=1e-15)
    # Exactly on a bound at the tips of the caps (z0 and z0 + P), with zero slope there.
    tips = torch.stack([fold.z0, fold.z0 + fold.P])
    assert torch.equal(fold.w(tips), torch.stack([fold.lo, fold.hi]))
    assert fold.slope(tips).abs().max() < 1e-12


# ----------------------------------------------------------------------------------------------
# Against scipy's L-BFGS-B on bound-constrained analytic problems
# ----------------------------------------------------------------------------------------------


def _scipy(f, x0, lo, hi):
    """scipy L-BFGS-B run to (near) machine precision, same history size as ours."""
    def fg(x):
        t = torch.tensor(x, dtype=F64, requires_grad=True)
        v = f(t)
        v.backward()
        return v.item(), t.grad.numpy()
    return minimize(fg, x0, jac=True, method="L-BFGS-B", bounds=list(zip(lo, hi)),
                    options=dict(maxcor=10, ftol=1e-16, gtol=1e-14, maxiter=10_000, maxfun=10_000))


def _ours(f, x0, lo, hi):
    """Our optimiser, one long step; the closure records how far inside the box every evaluation was."""
    x = torch.tensor(x0, dtype=F64, requires_grad=True)
    lo_t, hi_t = torch.tensor(lo, dtype=F64), torch.tensor(hi, dtype=F64)
    margin = []

    def closure():
        margin.append(min(float((x.detach() - lo_t).min()), float((hi_t - x.detach()).min())))
        return f(x)

    opt = BoundedLBFGS({"x": x}, {"x": Box(lo_t, hi_t)}, max_iter=1000, max_eval=2000, history_size=10,
                       tolerance_grad=1e-10, tolerance_change=1e-16)
    res = opt.step(closure)
    assert res.n_evals == len(margin)
    return x.detach().numpy(), res, min(margin)


def _compare(f, x0, lo, hi):
    ref = _scipy(f, x0, lo, hi)
    x, res, margin = _ours(f, x0, lo, hi)
    assert margin >= 0.0, "a closure evaluation saw a parameter outside its box"
    np.testing.assert_allclose(x, ref.x, rtol=1e-6, atol=1e-6)
    assert abs(res.loss_after - ref.fun) <= 1e-10 * max(1.0, abs(ref.fun))
    assert res.loss_after == pytest.approx(float(f(torch.tensor(x, dtype=F64))), abs=0)
    assert res.proj_grad_norm < 1e-5
    return ref, x, res


def _quadratic_with_known_optimum(seed=0, n=8):
    """A strictly convex quadratic on a per-coordinate box, built so the optimum x* is known: coordinates 0, 1 on
    their lower bound, 2, 3 on their upper bound (gradient pointing out of the box), the rest inside."""
    g = torch.Generator().manual_seed(seed)
    q, _ = torch.linalg.qr(torch.randn(n, n, generator=g, dtype=F64))
    a = q @ torch.diag(torch.linspace(1.0, 20.0, n, dtype=F64)) @ q.T
    lo = -1.0 - 0.1 * torch.arange(n, dtype=F64)
    hi = 1.0 + 0.2 * torch.arange(n, dtype=F64)
    x_star = 0.4 * (2 * torch.rand(n, generator=g, dtype=F64) - 1)
    x_star[:2], x_star[2:4] = lo[:2], hi[2:4]
    grad_star = torch.zeros(n, dtype=F64)
    grad_star[:4] = torch.tensor([0.7, 1.3, -0.9, -2.0], dtype=F64)  # KKT: >0 at lower, <0 at upper
    # = 0.5 x'Ax - b'x + const with b = A x* - grad*, written around x* so that f(x*) = 0 and the
    # loss keeps its relative precision near the optimum.
    def f(x):
        e = x - x_star
        return 0.5 * e @ a @ e + grad_star @ e
    return f, lo.numpy(), hi.numpy(), x_star.numpy()


def test_quadratic_with_optima_on_lower_and_upper_bounds_and_inside():
    f, lo, hi, x_star = _quadratic_with_known_optimum()
    ref, x, res = _compare(f, np.zeros(len(lo)), lo, hi)
    np.testing.assert_allclose(x, x_star, rtol=0, atol=1e-8)  # the exact KKT point, not only scipy's
    np.testing.assert_allclose(ref.x, x_star, rtol=0, atol=1e-8)
    assert (res.at_lower, res.at_upper) == (2, 2)
    assert res.n_iters <= 3 * ref.nit + 10


@pytest.mark.parametrize("lo, hi, active", [
    ([-1.5, -0.5], [0.5, 2.0], (0, 1)),   # (1, 1) excluded: optimum (0.5, 0.25) on the upper x bound
    ([-1.5, -0.5], [0.5, 0.2], (0, 1)),   # x free, y on its upper bound
    ([-2.0, -2.0], [2.0, 2.0], (0, 0)),   # (1, 1) inside
])
def test_box_constrained_rosenbrock(lo, hi, active):
    def rosen(x):
        return (1 - x[0]) ** 2 + 100 * (x[1] - x[0] ** 2) ** 2
    ref, x, res = _compare(rosen, np.array([-1.2, 0.1]), np.array(lo), np.array(hi))
    assert (res.at_lower, res.at_upper) == active
    assert res.n_iters <= 3 * ref.nit + 10


def test_30d_convex_problem_with_many_active_bounds():
    g = torch.Generator().manual_seed(0)
    n = 30
    m, c = torch.randn(40, n, generator=g, dtype=F64), torch.randn(40, generator=g, dtype=F64)
    centre = 2 * torch.randn(n, generator=g, dtype=F64)
    lo = (-1 - 0.5 * torch.rand(n, generator=g, dtype=F64)).numpy()
    hi = (1 + 0.5 * torch.rand(n, generator=g, dtype=F64)).numpy()

    def f(x):
        return torch.nn.functional.softplus(m @ x - c).sum() + 0.15 * ((x - centre) ** 2).sum()
    ref, x, res = _compare(f, np.zeros(n), lo, hi)
    assert res.at_lower >= 3 and res.at_upper >= 3 and res.at_lower + res.at_upper < n
    assert res.n_iters <= 3 * ref.nit + 10


def test_20d_chained_rosenbrock_with_bounds():
    n = 20
    lo, hi = np.full(n, -2.0), np.full(n, 2.0)
    hi[::4], lo[2::4] = 0.7, 1.2  # excludes the unconstrained optimum (1, ..., 1)

    def rosen(x):
        return (100 * (x[1:] - x[:-1] ** 2) ** 2 + (1 - x[:-1]) ** 2).sum()
    ref, x, res = _compare(rosen, np.clip(np.full(n, 0.5), lo + 0.01, hi - 0.01), lo, hi)
    assert res.at_lower >= 1 and res.at_upper >= 1
    assert res.n_iters <= 5 * ref.nit + 10


def test_full_batch_steps_continue_the_history_and_reach_the_optimum():
    f, lo, hi, x_star = _quadratic_with_known_optimum(seed=1)
    x = torch.zeros(len(lo), dtype=F64, requires_grad=True)
    opt = BoundedLBFGS({"x": x}, {"x": Box(torch.tensor(lo), torch.tensor(hi))}, max_iter=4,
                       tolerance_grad=1e-12, tolerance_change=1e-16)
    results = [opt.step(lambda: f(x)) for _ in range(25)]
    assert opt.state_dict()["lbfgs_state"][0]["n_iter"] == sum(r.n_iters for r in results)
    assert max(r.n_pairs for r in results) == 10  # pairs accumulate over steps up to history_size
    assert all(r.loss_after <= r.loss_before for r in results)
    np.testing.assert_allclose(x.detach().numpy(), x_star, atol=1e-8, rtol=0)


# ----------------------------------------------------------------------------------------------
# Mini-batches
# ----------------------------------------------------------------------------------------------


def _least_squares(n=200, d=5, noise=0.0, seed=0, col_scale=None):
    g = torch.Generator().manual_seed(seed)
    a = torch.randn(n, d, generator=g, dtype=F64)
    if col_scale is not None:
        a = a * col_scale
    theta_true = torch.linspace(-1.0, 1.0, d, dtype=F64)
    y = a @ theta_true + noise * torch.randn(n, generator=g, dtype=F64)
    theta_full = torch.linalg.lstsq(a, y).solution
    return a, y, theta_full


def _ls_opt(a, y, batch, max_iter, theta0=None):
    theta = torch.full((a.shape[1],), 0.1, dtype=F64) if theta0 is None else theta0.clone()
    theta.requires_grad_(True)
    opt = BoundedLBFGS({"theta": theta}, {"theta": Box(-3.0, 3.0)}, max_iter=max_iter,
                       tolerance_grad=1e-12, tolerance_change=1e-16, batch=batch)
    masks = []

    def closure(mask):
        masks.append(mask.clone())
        return ((a[mask] @ theta - y[mask]) ** 2).mean()
    return theta, opt, closure, masks


@pytest.mark.parametrize("fraction, expected", [(0.8, 160), (0.5, 100), (0.2, 40), (0.05, 10)])
def test_batch_masks_have_the_fraction_and_are_reproducible(fraction, expected):
    def draws(seed):
        batch = MiniBatch(fraction, 200, seed=seed)
        theta, opt, closure, masks = _ls_opt(*_least_squares()[:2], batch, max_iter=2)
        out = []
        for _ in range(4):
            r = opt.step(closure)
            assert all(torch.equal(m, opt.mask) for m in masks[-r.n_evals:])  # every call saw this step's batch
            assert r.batch_fraction == expected / 200
            out.append(opt.mask)
        return out
    a, b, c = draws(0), draws(0), draws(1)
    assert all(int(m.sum()) == expected and m.dtype == torch.bool and m.shape == (200,) for m in a)
    assert all(torch.equal(m, n) for m, n in zip(a, b))
    assert not all(torch.equal(m, n) for m, n in zip(a, c))
    assert not torch.equal(a[0], a[1])


@pytest.mark.parametrize("fraction", [0.5, 0.2])
def test_reset_history_converges_to_the_full_data_optimum(fraction):
    # Noisy data: each batch's optimum differs from the full-data one by ~ noise / sqrt(batch);
    # with 0.01 noise and >= 40 samples that is < 3e-3, so 1e-2 is the stated tolerance.
    a, y, theta_full = _least_squares(noise=0.01)
    theta, opt, closure, masks = _ls_opt(a, y, MiniBatch(fraction, 200, seed=3), max_iter=5)
    err0 = float((theta.detach() - theta_full).abs().max())
    for _ in range(10):
        r = opt.step(closure)
        # History reset at every batch change: torch's iteration counter restarted with this batch,
        # and the pairs all come from this step's iterations.
        state = opt.state_dict()["lbfgs_state"][0]
        assert state["n_iter"] == r.n_iters
        assert r.n_pairs <= r.n_iters - 1
    err = float((theta.detach() - theta_full).abs().max())
    assert err0 > 0.9 and err < 1e-2
    # With consistent (noise-free) data every batch has the same optimum: convergence is exact.
    a, y, theta_full = _least_squares(noise=0.0)
    theta, opt, closure, _ = _ls_opt(a, y, MiniBatch(fraction, 200, seed=3), max_iter=5)
    for _ in range(10):
        opt.step(closure)
    np.testing.assert_allclose(theta.detach().numpy(), theta_full.numpy(), atol=1e-8, rtol=0)


def test_a_step_solves_its_batch_problem():
    # With enough iterations per step, the iterate is the minimiser of that step's batch loss.
    a, y, _ = _least_squares(noise=0.1)
    theta, opt, closure, _ = _ls_opt(a, y, MiniBatch(0.2, 200, seed=5), max_iter=100)
    for _ in range(3):
        opt.step(closure)
        m = opt.mask
        batch_opt = torch.linalg.lstsq(a[m], y[m]).solution
        np.testing.assert_allclose(theta.detach().numpy(), batch_opt.numpy(), atol=1e-7, rtol=0)


def _w_of_z(z, lo=-3.0, hi=3.0):
    # Away from the caps (5 % of the box width at each bound) the fold is the identity.
    cap = 0.05 * (hi - lo)
    assert bool((z > lo + cap / 2).all() and (z < hi - cap / 2).all())
    return z


def test_overlap_batches_share_samples_and_bridge_with_the_overlap_gradient():
    a, y, theta_full = _least_squares(noise=0.0)
    batch = MiniBatch(0.2, 200, seed=7, history=OverlapBatches(overlap=0.5))
    # max_iter=1 is multi-batch L-BFGS proper: one iteration per batch, so every curvature pair in
    # the history comes from an overlap (none from within a step).
    theta, opt, closure, masks = _ls_opt(a, y, batch, max_iter=1)
    opt.step(closure)
    n_pairs = 0
    for _ in range(60):
        before = opt.state_dict()
        prev = opt.mask
        n_calls = len(masks)
        r = opt.step(closure)
        new = opt.mask
        assert int(new.sum()) == 40 and int((prev & new).sum()) == 20
        # The newest pair is (s, g_O(z1) - g_O(z1 - s)) on the overlap, recomputed here directly.
        st = before["lbfgs_state"][0]
        z1 = before["latent"][0]
        z0 = z1 - st["d"] * st["t"]
        o = prev & new

        def grad_o(z):
            z = z.clone().requires_grad_(True)
            ((a[o] @ _w_of_z(z) - y[o]) ** 2).mean().backward()
            return z.grad
        y_ref, s_ref = grad_o(z1) - grad_o(z0), z1 - z0
        after = opt.state_dict()["lbfgs_state"][0]
        if float(y_ref @ s_ref) > 1e-10:
            n_pairs = min(n_pairs + 1, 10)
            # y is a difference of gradients: compare at the rounding level of the gradients themselves.
            torch.testing.assert_close(after["old_dirs"][-1], y_ref, rtol=1e-9, atol=1e-13)
            torch.testing.assert_close(after["old_stps"][-1], s_ref, rtol=0, atol=0)
        assert r.n_pairs == n_pairs == len(after["old_dirs"])  # kept across batches, nothing else added
        # Two closure calls on the overlap, then the step's own calls on the new batch, all counted.
        calls = masks[n_calls:]
        assert r.n_evals == len(calls) >= 3
        assert torch.equal(calls[0], o) and torch.equal(calls[1], o)
        assert all(torch.equal(m, new) for m in calls[2:])
    assert n_pairs == 10
    np.testing.assert_allclose(theta.detach().numpy(), theta_full.numpy(), atol=1e-8, rtol=0)


def test_overlap_keeps_the_quasi_newton_scaling_that_reset_loses():
    # Same data, same batches' size, one iteration per batch: with the history reset every
    # iteration is a steepest-descent step; with overlap pairs it is a quasi-Newton step.
    # Columns scaled 0.2 .. 3: Hessian condition number ~ 225, where steepest descent crawls.
    a, y, theta_full = _least_squares(noise=0.0, col_scale=torch.linspace(0.2, 3.0, 5, dtype=F64))
    errs = {}
    for name, hist in (("reset", ResetHistory()), ("overlap", OverlapBatches(0.5))):
        theta, opt, closure, _ = _ls_opt(a, y, MiniBatch(0.2, 200, seed=2, history=hist), max_iter=1)
        for _ in range(40):
            opt.step(closure)
        errs[name] = float((theta.detach() - theta_full).abs().max())
    # (The overlap run stops near 2e-8 only because torch's tolerance_change test on g.d fires.)
    assert errs["overlap"] < 1e-7 and errs["reset"] > 0.5


def test_full_fraction_never_changes_the_batch():
    a, y, theta_full = _least_squares(noise=0.01)
    theta, opt, closure, masks = _ls_opt(a, y, MiniBatch(1.0, 200, history=OverlapBatches(0.5)), max_iter=3)
    results = [opt.step(closure) for _ in range(5)]
    assert all(bool(m.all()) for m in masks)
    assert opt.state_dict()["lbfgs_state"][0]["n_iter"] == sum(r.n_iters for r in results)
    np.testing.assert_allclose(theta.detach().numpy(), theta_full.numpy(), atol=1e-7, rtol=0)


# ----------------------------------------------------------------------------------------------
# Exact resume
# ----------------------------------------------------------------------------------------------


def _mlp(seed):
    torch.manual_seed(seed)
    return torch.nn.Sequential(torch.nn.Linear(1, 8), torch.nn.Tanh(), torch.nn.Linear(8, 1)).to(F64)


@pytest.mark.parametrize("batch", [
    None,
    MiniBatch(0.5, 64, seed=11),
    MiniBatch(0.2, 64, seed=11, history=OverlapBatches(0.5)),
])
def test_state_dict_round_trip_resumes_bit_identically(batch):
    t = torch.linspace(-1, 1, 64, dtype=F64)[:, None]
    target = torch.sin(3 * t)

    def make(seed):
        net = _mlp(seed)
        opt = BoundedLBFGS(net, uniform_box(net, -1.5, 1.5), max_iter=5, history_size=4, batch=batch)

        def closure(mask=None):
            m = slice(None) if mask is None else mask
            return ((net(t[m]) - target[m]) ** 2).mean()
        return net, opt, closure

    net, opt, closure = make(0)
    for _ in range(3):
        opt.step(closure)
    buf = io.BytesIO()
    torch.save(opt.state_dict(), buf)
    a = [opt.step(closure) for _ in range(3)]

    net_b, opt_b, closure_b = make(1)  # different initial weights: everything must come from the file
    buf.seek(0)
    opt_b.load_state_dict(torch.load(buf, weights_only=True))
    b = [opt_b.step(closure_b) for _ in range(3)]
    assert a == b
    for (name, p), (_, q) in zip(net.named_parameters(), net_b.named_parameters()):
        assert torch.equal(p, q), name
    assert a[-1].loss_after < a[0].loss_before
    assert all(p.abs().max() <= 1.5 for p in net.parameters())


# ----------------------------------------------------------------------------------------------
# Errors
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("lower, upper, match", [
    (1.0, 0.0, r"lower < upper.*\[1.0, 0.0\]"),
    (0.0, 0.0, r"lower < upper"),
    (float("nan"), 1.0, "lower bound must be finite"),
    (0.0, float("inf"), "upper bound must be finite"),
    (torch.tensor([0.0, 2.0]), torch.tensor([1.0, 1.0]), r"\[2.0, 1.0\] at index \(1,\)"),
])
def test_invalid_boxes(lower, upper, match):
    with pytest.raises(ValueError, match=match):
        Box(lower, upper)


def test_invalid_parameters_and_bound_sets_are_named():
    x = torch.tensor([0.0, 0.5, 2.0], dtype=F64, requires_grad=True)
    with pytest.raises(ValueError, match=r"'x' starts outside its box: value 2.0 at index \(2,\), range \[-1.0, 1.0\]"):
        BoundedLBFGS({"x": x}, {"x": Box(-1.0, 1.0)})
    with pytest.raises(ValueError, match=r"'x' starts on its box"):
        BoundedLBFGS({"x": x}, {"x": Box(0.0, 3.0)})
    with pytest.raises(ValueError, match=r"'x'.*do not broadcast"):
        BoundedLBFGS({"x": x}, {"x": Box(torch.zeros(2), torch.ones(2))})
    with pytest.raises(ValueError, match=r"missing \['x'\], unknown \['y'\]"):
        BoundedLBFGS({"x": x}, {"y": Box(-5.0, 5.0)})
    with pytest.raises(ValueError, match="requires_grad"):
        BoundedLBFGS({"x": x.detach()}, {"x": Box(-5.0, 5.0)})
    with pytest.raises(ValueError, match="shares 0"):
        MiniBatch(0.01, 100, history=OverlapBatches(0.4))
    with pytest.raises(ValueError, match="new samples"):
        MiniBatch(0.8, 100, history=OverlapBatches(0.5))
    with pytest.raises(ValueError, match="fraction"):
        MiniBatch(0.0, 100)


def test_closure_misuse_and_non_finite_loss_leave_the_optimiser_valid():
    x = torch.tensor([0.3, -0.2], dtype=F64, requires_grad=True)
    opt = BoundedLBFGS({"x": x}, {"x": Box(-1.0, 1.0)}, max_iter=10)
    start = x.detach().clone()

    def calls_backward():
        loss = (x ** 2).sum()
        loss.backward()
        return loss
    with pytest.raises(RuntimeError, match="must not call backward"):
        opt.step(calls_backward)

    n = [0]

    def blows_up():  # fine at the start point, infinite at the first trial point
        n[0] += 1
        return (x ** 2).sum() * (1.0 if n[0] == 1 else float("inf"))
    with pytest.raises(FloatingPointError, match="non-finite"):
        opt.step(blows_up)
    assert torch.equal(x.detach(), start)  # not left at the trial point
    r = opt.step(lambda: ((x - 0.5) ** 2).sum())
    assert r.loss_after < 1e-12

    with torch.no_grad():
        x[0] = 0.1
    with pytest.raises(RuntimeError, match="'x' was changed outside"):
        opt.step(lambda: (x ** 2).sum())


def test_result_fields_are_consistent():
    x = torch.tensor([0.3], dtype=F64, requires_grad=True)
    opt = BoundedLBFGS({"x": x}, {"x": Box(0.0, 1.0)}, max_iter=50)
    r = opt.step(lambda: (x - 2.0).pow(2).sum())  # optimum on the upper bound, gradient -2 there
    assert isinstance(r, StepResult)
    assert x.item() == 1.0 and (r.at_lower, r.at_upper) == (0, 1)
    assert r.loss_before == pytest.approx(1.7 ** 2) and r.loss_after == 1.0
    assert r.proj_grad_norm == 0.0 and r.grad_norm < 1e-7
    assert math.isclose(r.batch_fraction, 1.0) and r.n_evals >= r.n_iters >= 1


def test_rejected_trial_points_make_the_line_search_backtrack():
    """A region where the loss cannot be evaluated (an ODE that blows up) is stepped around."""

    class Infeasible(RuntimeError):
        pass

    def problem():
        w = torch.tensor([0.0], dtype=torch.float64, requires_grad=True)
        seen = []

        def closure():
            seen.append(float(w.detach()))
            if seen[-1] > 1.5:  # the minimum at 2 lies beyond a wall the model cannot cross
                raise Infeasible("cannot integrate")
            return (w - 2.0).pow(2).sum()

        return w, seen, closure

    w, seen, closure = problem()
    opt = BoundedLBFGS({"w": w}, {"w": Box(-10.0, 10.0)}, max_iter=30, reject=(Infeasible,))
    res = opt.step(closure)
    assert 1.3 < float(w.detach()) <= 1.5  # as close to the optimum as the feasible region allows
    assert res.loss_after < 1.0 and any(v > 1.5 for v in seen)
    # Without the policy the same failure propagates and the step is undone.
    w, seen, closure = problem()
    opt = BoundedLBFGS({"w": w}, {"w": Box(-10.0, 10.0)}, max_iter=30)
    with pytest.raises(Infeasible):
        opt.step(closure)
    assert float(w.detach()) == 0.0


def test_a_closure_ends_the_step_at_the_best_point_it_evaluated():
    """StopStep (a spent time budget) ends the step at the lowest loss evaluated, with its gradient,
    the history cleared; at the first evaluation it propagates and the step is undone."""
    w = torch.tensor([0.0, 0.0], dtype=F64, requires_grad=True)
    seen = []

    def closure():
        if len(seen) == 6:
            raise StopStep("budget")
        loss = (w[0] - 3.0) ** 2 + 10.0 * (w[1] - w[0] ** 2) ** 2  # a curved valley: needs many calls
        seen.append((float(loss.detach()), w.detach().clone()))
        return loss

    opt = BoundedLBFGS({"w": w}, {"w": Box(-10.0, 10.0)}, max_iter=50)
    res = opt.step(closure)
    best_loss, best_w = min(seen, key=lambda e: e[0])
    assert res.stopped and res.n_evals == 6 and res.n_pairs == 0
    assert res.loss_after == best_loss < res.loss_before == seen[0][0]
    assert torch.equal(w.detach(), best_w)
    w_grad = 2 * (best_w[0] - 3.0) - 40.0 * best_w[0] * (best_w[1] - best_w[0] ** 2)
    assert res.grad_norm == pytest.approx(max(abs(float(w_grad)), abs(20.0 * float(best_w[1] - best_w[0] ** 2))),
                                          rel=1e-9)
    # The optimiser goes on from there.
    seen.clear()
    seen.append(None)  # never six again
    res = opt.step(lambda: (w[0] - 3.0) ** 2 + 10.0 * (w[1] - w[0] ** 2) ** 2)
    assert not res.stopped and res.loss_after < best_loss

    x = torch.tensor([0.5], dtype=F64, requires_grad=True)
    opt = BoundedLBFGS({"x": x}, {"x": Box(0.0, 1.0)}, max_iter=5)

    def at_once():
        raise StopStep("budget")

    with pytest.raises(StopStep):
        opt.step(at_once)
    assert x.item() == pytest.approx(0.5, abs=1e-12)
