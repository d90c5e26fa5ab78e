"""Piecewise integration of the tank model over input segments, with bounded work."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import torch
from torch import Tensor, nn
from torchdiffeq import odeint, odeint_adjoint

from .forcing import Forcing
from .rosenbrock import rosenbrock_solve
from .solver import LSODA, AdaptiveRK, Adjoint, Backprop, Checkpointed, NoGradient, Rosenbrock
from .state import STATE_NAMES


class SimulationError(RuntimeError):
    """The solver failed; carries the time (s) and the state where it was last evaluated.

    ``names``: the state's component names (``TankModel.state_names``, which names the
    mechanisms' own states); without them, components beyond the tank's 7 print as ``extra_<i>``.
    """

    def __init__(self, message: str, t_s: float | None = None, state: Tensor | None = None,
                 names: tuple[str, ...] | None = None):
        where = ""
        if t_s is not None:
            where = f" at t = {t_s:.6g} s"
        if state is not None:
            rows = []
            n = state.shape[-1]
            if names is None or len(names) != n:
                names = STATE_NAMES + tuple(f"extra_{i}" for i in range(n - len(STATE_NAMES)))
            for e, row in enumerate(state.detach().reshape(-1, n).tolist()):
                rows.append(f"env {e}: " + ", ".join(f"{k}={v:.6g}" for k, v in zip(names, row)))
            where += " in state\n  " + "\n  ".join(rows)
        super().__init__(message + where)
        self.t_s = t_s
        self.state = state


def _solve_segment(func: nn.Module, z0: Tensor, ts: Tensor, solver, gradient, model: nn.Module) -> Tensor:
    """Scaled states ``(len(ts), env, 7)`` of one segment with the chosen solver and gradient."""
    if isinstance(solver, LSODA):
        return _lsoda(func, z0, ts, solver)
    if isinstance(solver, Rosenbrock):
        def solve(f, z, t):
            return rosenbrock_solve(f, z, t, solver.rtol, solver.atol)
    else:
        def solve(f, z, t):
            return odeint(f, z, t, rtol=solver.rtol, atol=solver.atol, method=solver.method)
    if isinstance(gradient, Checkpointed):
        return _checkpointed(func, z0, ts, solve)
    if isinstance(gradient, Adjoint):  # AdaptiveRK only: integrate() refuses Rosenbrock's
        # The backward pass restarts at every output time (the cost's jumps). Starting each
        # restart at the output spacing instead of torchdiffeq's cold initial-step guess cuts
        # the adjoint's evaluations ~4x (1560 -> 420 on a 60-sample window) at equal accuracy;
        # the step controller still shrinks it where the adjoint is stiff. The seminorm leaves
        # the parameter adjoints out of the error norm (Kidger, Chen & Lyons 2021).
        gaps = ts[1:] - ts[:-1]
        options = {"norm": "seminorm", "first_step": float(gaps.median()) if len(gaps) else None}
        return odeint_adjoint(
            func, z0, ts, rtol=solver.rtol, atol=solver.atol, method=solver.method,
            adjoint_rtol=gradient.rtol or solver.rtol, adjoint_atol=gradient.atol or solver.atol,
            adjoint_params=tuple(p for p in model.parameters() if p.requires_grad),
            adjoint_options=options,
        )
    return solve(func, z0, ts)


def _checkpointed(func: nn.Module, z0: Tensor, ts: Tensor, solve: Callable) -> Tensor:
    """``solve(func, z, ts)`` over each output interval under ``torch.utils.checkpoint`` (``Checkpointed()``).

    The recomputation in the backward pass repeats the forward steps exactly (same input, same
    deterministic step controller). Each interval starts its step size afresh; the controller
    finds it in two evaluations. The segment's evaluation budget is charged by the forward pass
    only: a recomputation runs with the count the interval started from, so a segment that
    needed more than half the budget does not fail in its backward pass.
    """
    from torch.utils.checkpoint import checkpoint

    started_at: dict[int, int] = {}  # interval -> the segment's evaluations before its forward run

    def interval(z: Tensor, pair: Tensor, i: int) -> Tensor:
        if i not in started_at:
            started_at[i] = func._segment_evals
            return solve(func, z, pair)[-1]
        spent, func._segment_evals = func._segment_evals, started_at[i]
        try:
            return solve(func, z, pair)[-1]
        finally:
            func._segment_evals = spent

    out, z = [z0], z0
    for i in range(len(ts) - 1):
        z = checkpoint(interval, z, ts[i:i + 2], i, use_reentrant=False)
        out.append(z)
    return torch.stack(out)


def _lsoda(func: nn.Module, z0: Tensor, ts: Tensor, solver: LSODA) -> Tensor:
    """SciPy LSODA on the flattened batch; returns ``(len(ts), env, 7)`` like torchdiffeq."""
    from scipy.integrate import solve_ivp

    shape = z0.shape

    def rhs(t, z):
        return func(torch.tensor(t, dtype=torch.float64), torch.from_numpy(z).reshape(shape)).reshape(-1).numpy()

    t_np = ts.numpy()
    # The environments do not interact, so the flattened Jacobian is block diagonal with blocks
    # of the state's width: telling LSODA its band makes each finite-difference Jacobian cost
    # 2 * width - 1 right-hand sides instead of env * width (8 variants of a tank with one
    # mechanism state: 15 instead of 64). The batch still shares one step sequence, so variants
    # whose trajectories differ still cost more steps than one tank alone.
    width = shape[-1]
    band = {"lband": width - 1, "uband": width - 1} if z0.numel() > 2 * width - 1 else {}
    sol = solve_ivp(rhs, (float(t_np[0]), float(t_np[-1])), z0.reshape(-1).numpy(), method="LSODA",
                    t_eval=t_np, rtol=solver.rtol, atol=solver.atol, **band)
    if sol.status != 0:
        raise RuntimeError(f"LSODA: {sol.message}")
    return torch.from_numpy(sol.y.T.copy()).reshape(len(t_np), *shape)


@dataclass
class _Counter:
    n_evals: int = 0
    last_t: float | None = None
    last_s: Tensor | None = None


class _ScaledRHS(nn.Module):
    """dz/dt of the scaled state z = s / scale for one segment's constant forcing."""

    def __init__(self, model: nn.Module, forcing: Forcing, scale: Tensor, counter: _Counter, max_evals: int):
        super().__init__()
        self.model = model
        self.forcing = forcing
        self.scale = scale
        self.counter = counter
        self.max_evals = max_evals
        self._segment_evals = 0
        self.names = getattr(model, "state_names", None)  # analytic test models have none

    def forward(self, t: Tensor, z: Tensor) -> Tensor:
        s = z * self.scale
        self.counter.n_evals += 1
        self._segment_evals += 1
        self.counter.last_t = float(t.detach())
        self.counter.last_s = s.detach()
        if self._segment_evals > self.max_evals:
            raise SimulationError(f"solver exceeded {self.max_evals} right-hand-side evaluations in one segment",
                                  self.counter.last_t, self.counter.last_s, self.names)
        # The adjoint's backward solve calls this outside integrate()'s own error handling, so a
        # failure here must already be a SimulationError: the trainers reject such a trial point
        # (a NaN state reaching the geometry once crashed a whole multi-environment study).
        if not torch.isfinite(s).all():
            raise SimulationError("non-finite state reached the right-hand side", float(t.detach()), s.detach(),
                                  self.names)
        try:
            ds = self.model(t, s, self.forcing)
        except (AssertionError, ValueError) as err:
            raise SimulationError(f"right-hand side failed: {str(err).splitlines()[0]}", float(t.detach()),
                                  s.detach(), self.names) from err
        return ds / self.scale


def state_scale(s0: Tensor, tank_volume_m3: Tensor, extra_scales: tuple[float, ...] = ()) -> Tensor:
    """Per-environment scales of the state components, ``(env, 7 + len(extra_scales))`` (see ``AdaptiveRK``).

    ``s0`` ``(env, >= 7)``: the initial state, whose first 7 components set the tank's scales;
    ``extra_scales``: the mechanisms' own states' units (``TankModel.extra_state_scales``).
    """
    m = s0[..., 0] + s0[..., 1]
    du = (s0[..., 2] - s0[..., 3]).abs().clamp_min(1e3)
    V = tank_volume_m3.expand_as(m)
    extra = [torch.full_like(m, float(x)) for x in extra_scales]
    return torch.stack([m, m, du, du, s0[..., 4], V, V, *extra], dim=-1).detach()


@dataclass(frozen=True)
class IntegrationStats:
    """Work done by the solver: right-hand-side evaluations and segments."""

    n_rhs_evals: int
    n_segments: int


def integrate(
    model: nn.Module,
    s0: Tensor,
    segments: list[tuple[float, float]],
    forcing: Callable[[float, Tensor], Forcing],
    t_eval: Tensor,
    scale: Tensor,
    solver: AdaptiveRK | LSODA | Rosenbrock = AdaptiveRK(),
    gradient=NoGradient(),
) -> tuple[Tensor, IntegrationStats]:
    """Integrate ``model`` from ``s0`` across ``segments`` and return states at ``t_eval``.

    The solver restarts at every segment boundary (an input discontinuity), so it never steps
    across a jump in the forcing.

    Args:
        model: ``model(t, s, forcing) -> ds/dt``, ``s`` shaped ``(env, 7)``.
        s0: initial state ``(env, 7)`` at ``segments[0][0]``.
        segments: contiguous ``(t_start_s, t_end_s)`` covering the horizon; inputs are
            constant inside each.
        forcing: ``forcing(t_start_s, s_start) -> Forcing`` for a segment starting in state
            ``s_start`` ``(env, 7)`` (inflow enthalpies may depend on the tank pressure).
        t_eval: output times (s), sorted, inside ``[t_start, t_end]``, shape ``(T,)``.
        scale: ``(env, 7)`` state scales (``state_scale``).
        solver: ``AdaptiveRK`` (any gradient), ``LSODA`` (stiff-capable, ``NoGradient`` only) or
            ``Rosenbrock`` (stiff-capable, any gradient but ``Adjoint``).
        gradient: ``NoGradient()``, ``Backprop()``, ``Checkpointed()`` or ``Adjoint()``.

    Returns:
        states ``(env, T, 7)`` at ``t_eval`` and the ``IntegrationStats``.

    Raises:
        SimulationError: the solver failed or exceeded its evaluation budget; the message
            names the time and the state.
    """
    if not segments:
        raise ValueError("integrate needs at least one segment")
    t_start, t_end = segments[0][0], segments[-1][1]
    t_eval = torch.as_tensor(t_eval, dtype=torch.float64)
    if t_eval.dim() != 1 or len(t_eval) == 0:
        raise ValueError("t_eval must be a non-empty 1-D tensor of times in s")
    if (t_eval[1:] <= t_eval[:-1]).any():
        raise ValueError("t_eval must be strictly increasing")
    if t_eval[0] < t_start - 1e-9 or t_eval[-1] > t_end + 1e-9:
        raise ValueError(f"t_eval must lie in [{t_start}, {t_end}] s, got [{float(t_eval[0])}, {float(t_eval[-1])}]")
    for (a0, a1), (b0, _) in zip(segments[:-1], segments[1:]):
        if a1 != b0:
            raise ValueError(f"segments must be contiguous: one ends at {a1} s, the next starts at {b0} s")

    if not isinstance(gradient, (NoGradient, Backprop, Checkpointed, Adjoint)):
        raise TypeError(f"gradient must be NoGradient(), Backprop(), Checkpointed() or Adjoint(), got {gradient!r}")
    if isinstance(solver, LSODA) and not isinstance(gradient, NoGradient):
        raise ValueError("the LSODA solver is forward only; use AdaptiveRK() or Rosenbrock() with gradients")
    if isinstance(solver, Rosenbrock) and isinstance(gradient, Adjoint):
        raise ValueError("the Rosenbrock solver has no continuous adjoint; use Backprop() or Checkpointed()")
    counter = _Counter()
    names = getattr(model, "state_names", None)
    outputs: list[Tensor] = []
    if float(t_eval[0]) <= t_start + 1e-9:
        outputs.append(s0[:, None, :])
    s = s0
    grad_ctx = torch.no_grad() if isinstance(gradient, NoGradient) else torch.enable_grad()
    with grad_ctx:
        for t0, t1 in segments:
            inner = t_eval[(t_eval > t0 + 1e-9) & (t_eval < t1 - 1e-9)]
            ts = torch.cat([torch.tensor([t0], dtype=torch.float64), inner, torch.tensor([t1], dtype=torch.float64)])
            func = _ScaledRHS(model, forcing(t0, s.detach()), scale, counter, solver.max_rhs_evals)
            z0 = s / scale
            try:
                z = _solve_segment(func, z0, ts, solver, gradient, model)
            except SimulationError:
                raise
            except (AssertionError, RuntimeError, ValueError) as err:  # StepFailure is a RuntimeError with its time
                raise SimulationError(f"ODE solver failed in segment [{t0:.6g}, {t1:.6g}] s: {err}",
                                      getattr(err, "t_s", counter.last_t), counter.last_s, names) from err
            traj = (z * scale).permute(1, 0, 2)  # (env, len(ts), 7)
            if not torch.isfinite(traj).all():
                raise SimulationError(f"non-finite state in segment [{t0:.6g}, {t1:.6g}] s", counter.last_t,
                                      counter.last_s, names)
            outputs.append(traj[:, 1:-1])
            if bool(((t_eval - t1).abs() < 1e-9).any()):
                outputs.append(traj[:, -1:])
            s = traj[:, -1]
    states = torch.cat(outputs, dim=1)
    if states.shape[1] != len(t_eval):
        raise AssertionError(f"internal: {states.shape[1]} outputs for {len(t_eval)} requested times")
    return states, IntegrationStats(counter.n_evals, len(segments))


__all__ = ["integrate", "SimulationError", "IntegrationStats", "state_scale"]
