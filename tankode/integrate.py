"""Piecewise integration of the tank model over input segments, with bounded work."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import torch
from torch import Tensor, nn

from .errors import ImpossibleState, SimulationError, StateLeftDomain
from .forcing import Forcing
from .solver import LSODA, AdaptiveRK, Gradient, NoGradient, Rosenbrock


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
        # Solver state handed across input changes (tankode.rosenbrock.WarmStart): the previous
        # segment's end in, this one's end out. Solvers without a warm start ignore both.
        self.warm_start = None
        self.warm_end = None
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
        # (a NaN state reaching the geometry would otherwise end a whole multi-environment study).
        if not torch.isfinite(s).all():
            raise SimulationError("non-finite state reached the right-hand side", float(t.detach()), s.detach(),
                                  self.names)
        try:
            ds = self.model(t, s, self.forcing)
        except ImpossibleState as err:
            error = StateLeftDomain if err.kind == "domain" else SimulationError
            raise error(err.cause, float(t.detach()), s.detach(), self.names) from err
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
    gradient: Gradient = NoGradient(),
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

    if not isinstance(gradient, Gradient):
        raise TypeError(f"gradient must be NoGradient(), Backprop(), Checkpointed() or Adjoint(), got {gradient!r}")
    solver.check_gradient(gradient)
    counter = _Counter()
    names = getattr(model, "state_names", None)
    outputs: list[Tensor] = []
    # Times within 1e-9 s of a segment's end are that end's state, each of them: a caller's
    # grid may hold two such times (a sample and a segment edge computed from it by rounding).
    n_start = int((t_eval <= t_start + 1e-9).sum())
    if n_start:
        outputs.append(s0[:, None, :].expand(-1, n_start, -1))
    s = s0
    warm = None
    grad_ctx = torch.enable_grad() if gradient.differentiable else torch.no_grad()
    with grad_ctx:
        for t0, t1 in segments:
            inner = t_eval[(t_eval > t0 + 1e-9) & (t_eval < t1 - 1e-9)]
            ts = torch.cat([torch.tensor([t0], dtype=torch.float64), inner, torch.tensor([t1], dtype=torch.float64)])
            func = _ScaledRHS(model, forcing(t0, s.detach()), scale, counter, solver.max_rhs_evals)
            func.warm_start = warm
            z0 = s / scale
            try:
                z = gradient.solve(solver, func, z0, ts, model)
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
            n_end = int(((t_eval - t1).abs() < 1e-9).sum())
            if n_end:
                outputs.append(traj[:, -1:].expand(-1, n_end, -1))
            s = traj[:, -1]
            warm = func.warm_end
    states = torch.cat(outputs, dim=1)
    if states.shape[1] != len(t_eval):
        raise AssertionError(f"internal: {states.shape[1]} outputs for {len(t_eval)} requested times")
    return states, IntegrationStats(counter.n_evals, len(segments))


__all__ = ["integrate", "SimulationError", "IntegrationStats", "state_scale"]
