"""Integration strategies: the ODE solver and how gradients flow through it.

Each strategy carries its behaviour: a solver integrates one segment (``solver.solve``) and
says which gradients it supports (``solver.check_gradient``); a gradient strategy wraps a
solver's solve (``gradient.solve``). ``tankode.integrate`` composes them segment by segment.
Torch, torchdiffeq and SciPy are imported inside the methods, so that importing this module
(e.g. for command-line parsing) stays light.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from torch import Tensor, nn

_METHODS = ("dopri5", "bosh3", "dopri8", "adaptive_heun")


def _check_budget(solver) -> None:
    """Validate the tolerances and the evaluation budget shared by the solver strategies."""
    name = type(solver).__name__
    for field in ("rtol", "atol"):
        v = getattr(solver, field)
        if not (math.isfinite(v) and 0 < v < 1):
            raise ValueError(f"{name}.{field} must be in (0, 1), got {v}")
    if solver.max_rhs_evals < 10:
        raise ValueError(f"{name}.max_rhs_evals must be >= 10, got {solver.max_rhs_evals}")


@dataclass(frozen=True)
class AdaptiveRK:
    """An adaptive Runge-Kutta solver from torchdiffeq on the scaled state.

    The state is integrated as ``z = s / scale`` with per-environment scales (total mass for
    the masses, the initial latent-heat-sized energy gap |u_v - u_l| for the energies, the
    initial wall temperature, the tank volume for the volumes), so one ``rtol``/``atol`` pair
    means the same thing for every component.

    Attributes:
        method: torchdiffeq adaptive method; dopri5 (5th order, FSAL) is the default because
            the model is not stiff at the tolerances the studies need.
        rtol: relative tolerance (dimensionless).
        atol: absolute tolerance on the scaled state (dimensionless, ~ relative to the scale).
        max_rhs_evals: hard bound on right-hand-side evaluations per segment, so a solver
            that stalls fails with the time and state instead of hanging (50,000: a minute of
            work at most, over a hundred times what the runs in the tests need).
    """

    method: str = "dopri5"
    rtol: float = 1e-7
    atol: float = 1e-9
    max_rhs_evals: int = 50_000

    def __post_init__(self):
        if self.method not in _METHODS:
            raise ValueError(f"AdaptiveRK.method must be one of {_METHODS}, got {self.method!r}")
        _check_budget(self)

    def check_gradient(self, gradient: Gradient) -> None:
        """Every gradient strategy works with this solver."""

    def solve(self, func: nn.Module, z0: Tensor, ts: Tensor) -> Tensor:
        """States ``(len(ts), env, n)`` of ``dz/dt = func(t, z)`` from ``z0`` at ``ts[0]`` (``torchdiffeq.odeint``)."""
        from torchdiffeq import odeint

        return odeint(func, z0, ts, rtol=self.rtol, atol=self.atol, method=self.method)


@dataclass(frozen=True)
class LSODA:
    """SciPy's LSODA (Adams/BDF with automatic stiffness switching), forward only.

    Tanks with a light wall (e.g. aluminium at 20 K: m_w c_w ~ 1e4 J/K against wall
    conductances of 1e3-1e4 W/K) have sub-second wall time constants in runs of many hours:
    the ODE is stiff and an explicit solver is stability-limited (MHTB P263981D: dopri5 needs
    57,000 right-hand-side evaluations, LSODA 250). ``simulate`` uses LSODA by default;
    training needs gradients and uses ``AdaptiveRK`` or, on stiff tanks, ``Rosenbrock``.

    Attributes:
        rtol, atol: tolerances on the scaled state (as ``AdaptiveRK``).
        max_rhs_evals: hard bound on right-hand-side evaluations per segment.
    """

    rtol: float = 1e-7
    atol: float = 1e-9
    max_rhs_evals: int = 50_000

    def __post_init__(self):
        _check_budget(self)

    def check_gradient(self, gradient: Gradient) -> None:
        """Raise ``ValueError`` unless ``gradient`` is ``NoGradient()``: LSODA is forward only."""
        if gradient.differentiable:
            raise ValueError("the LSODA solver is forward only; use AdaptiveRK() or Rosenbrock() with gradients")

    def solve(self, func: nn.Module, z0: Tensor, ts: Tensor) -> Tensor:
        """SciPy LSODA on the flattened batch; states ``(len(ts), env, n)`` at ``ts`` like ``AdaptiveRK.solve``."""
        import torch
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
                        t_eval=t_np, rtol=self.rtol, atol=self.atol, **band)
        if sol.status != 0:
            raise RuntimeError(f"LSODA: {sol.message}")
        return torch.from_numpy(sol.y.T.copy()).reshape(len(t_np), *shape)


@dataclass(frozen=True)
class Rosenbrock:
    """ROS34PW2, a linearly implicit (Rosenbrock-W) solver for stiff tanks that autograd can differentiate.

    For tanks whose light wall makes the ODE stiff (``LSODA``'s case) when gradients are needed:
    L-stable, so steps follow accuracy instead of stability; four right-hand sides with autograd
    per step plus a finite-difference Jacobian without it (``tankode/rosenbrock.py``). Works
    with ``Backprop()`` (its steps are few on a stiff tank, so memory stays small) and
    ``Checkpointed()`` (which restarts the solver, Jacobian included, at every output time:
    dearer with dense samples); ``Adjoint()`` is refused (its backward
    re-integration is what diverges on stiff tanks). Third order: on a non-stiff tank at tight
    tolerances ``AdaptiveRK`` (dopri5, fifth order) takes fewer steps.

    Attributes:
        rtol, atol: tolerances on the scaled state (as ``AdaptiveRK``).
        max_rhs_evals: hard bound on right-hand-side evaluations per segment, Jacobians included.
        warm_start: start each segment with the previous segment's Jacobian
            (``tankode.rosenbrock.WarmStart``) instead of a fresh one (n right-hand sides). A
            fleet restarts at every tank's input change, and the other tanks' Jacobians have not
            changed; measured on 64 jittered tanks (30 segments in a 10-minute window, untrained
            agent), 17 % fewer right-hand sides. False: every segment starts cold.
    """

    rtol: float = 1e-6
    atol: float = 1e-8
    max_rhs_evals: int = 50_000
    warm_start: bool = True

    def __post_init__(self):
        _check_budget(self)

    def check_gradient(self, gradient: Gradient) -> None:
        """Raise ``ValueError`` for ``Adjoint()``: a Rosenbrock solve has no continuous adjoint."""
        if isinstance(gradient, Adjoint):
            raise ValueError("the Rosenbrock solver has no continuous adjoint; use Backprop() or Checkpointed()")

    def solve(self, func: nn.Module, z0: Tensor, ts: Tensor) -> Tensor:
        """States ``(len(ts), env, n)`` at ``ts`` (``tankode.rosenbrock.rosenbrock_solve_warm``).

        Starts from ``func.warm_start`` where ``integrate`` sets it (the previous segment's
        Jacobian, ``tankode.rosenbrock.WarmStart``) and leaves where it ended in ``func.warm_end``.
        """
        from .rosenbrock import rosenbrock_solve_warm

        warm = getattr(func, "warm_start", None) if self.warm_start else None
        states, func.warm_end = rosenbrock_solve_warm(func, z0, ts, self.rtol, self.atol, warm=warm)
        return states


class Gradient:
    """How gradients flow through a solve: the base of the gradient strategies below.

    ``differentiable``: whether the solve records an autograd graph (``integrate`` runs under
    ``torch.no_grad()`` otherwise).
    """

    differentiable = True

    def solve(self, solver, func: nn.Module, z0: Tensor, ts: Tensor, model: nn.Module) -> Tensor:
        """States ``(len(ts), env, n)`` of one segment by ``solver.solve``, differentiable as this strategy says.

        ``model``: the module whose trainable parameters the gradient is taken with respect to.
        """
        return solver.solve(func, z0, ts)


@dataclass(frozen=True)
class NoGradient(Gradient):
    """Forward only (no autograd graph): simulation, prediction, benchmarks."""

    differentiable = False


@dataclass(frozen=True)
class Backprop(Gradient):
    """Differentiate through the solver's operations (``torchdiffeq.odeint``).

    Exact gradient of the discrete solution; memory grows with the number of solver steps.
    """


@dataclass(frozen=True)
class Checkpointed(Gradient):
    """Differentiate through the solver's steps one output interval at a time, recomputing them.

    Each interval between consecutive output times is integrated under
    ``torch.utils.checkpoint``: the forward pass keeps only the state at the output times, and
    the backward pass re-runs one interval's steps with autograd and back-propagates through
    them (the "adaptive checkpoint adjoint" of Zhuang et al. 2020). The gradient is the exact
    gradient of its discrete solution, as ``Backprop()``'s, and so stable on stiff tanks, where
    ``Adjoint()``'s backward re-integration of the state diverges; since every interval restarts
    the step controller, that solution differs from one solve across the outputs at the solver's
    tolerance. Cost: about twice the forward work. Memory: one state per output time plus one
    interval's steps, which does not grow with a longer window at the same output spacing.
    """

    def solve(self, solver, func: nn.Module, z0: Tensor, ts: Tensor, model: nn.Module) -> Tensor:
        """``solver.solve`` over each output interval under ``torch.utils.checkpoint``.

        The recomputation in the backward pass repeats the forward steps exactly (same input,
        same deterministic step controller). Each interval starts its step size afresh; the
        controller finds it in two evaluations. The segment's evaluation budget
        (``func._segment_evals``) is charged by the forward pass only: a recomputation runs with
        the count the interval started from, so a segment that needed more than half the budget
        does not fail in its backward pass.
        """
        import torch
        from torch.utils.checkpoint import checkpoint

        started_at: dict[int, int] = {}  # interval -> the segment's evaluations before its forward run
        # Only the first interval takes the segment's warm start: every recomputation must see
        # what its forward run saw, and a Jacobian from the segment's start would serve later
        # intervals stale.
        warm = getattr(func, "warm_start", None)

        def interval(z: Tensor, pair: Tensor, i: int) -> Tensor:
            func.warm_start = warm if i == 0 else None
            if i not in started_at:
                started_at[i] = func._segment_evals
                return solver.solve(func, z, pair)[-1]
            spent, func._segment_evals = func._segment_evals, started_at[i]
            try:
                return solver.solve(func, z, pair)[-1]
            finally:
                func._segment_evals = spent

        out, z = [z0], z0
        for i in range(len(ts) - 1):
            z = checkpoint(interval, z, ts[i:i + 2], i, use_reentrant=False)
            out.append(z)
        return torch.stack(out)


@dataclass(frozen=True)
class Adjoint(Gradient):
    """Continuous adjoint (``torchdiffeq.odeint_adjoint``): memory independent of the step count.

    Needs a torchdiffeq solver (``AdaptiveRK``); ``LSODA`` and ``Rosenbrock`` refuse it.

    Attributes:
        rtol, atol: tolerances of the backward (adjoint) solve; None = the forward ones.
    """

    rtol: float | None = None
    atol: float | None = None

    def solve(self, solver: AdaptiveRK, func: nn.Module, z0: Tensor, ts: Tensor, model: nn.Module) -> Tensor:
        """``torchdiffeq.odeint_adjoint`` with ``solver``'s method and tolerances, adjoints of ``model``'s trainable parameters."""
        from torchdiffeq import odeint_adjoint

        # The backward pass restarts at every output time (the cost's jumps). Starting each
        # restart at the output spacing instead of torchdiffeq's cold initial-step guess saves
        # most of the adjoint's evaluations at equal accuracy; the step controller still shrinks
        # it where the adjoint is stiff. The seminorm leaves the parameter adjoints out of the
        # error norm (Kidger, Chen & Lyons 2021).
        gaps = ts[1:] - ts[:-1]
        options = {"norm": "seminorm", "first_step": float(gaps.median()) if len(gaps) else None}
        return odeint_adjoint(
            func, z0, ts, rtol=solver.rtol, atol=solver.atol, method=solver.method,
            adjoint_rtol=self.rtol or solver.rtol, adjoint_atol=self.atol or solver.atol,
            adjoint_params=tuple(p for p in model.parameters() if p.requires_grad),
            adjoint_options=options,
        )


__all__ = ["AdaptiveRK", "LSODA", "Rosenbrock", "Gradient", "NoGradient", "Backprop", "Checkpointed", "Adjoint"]
