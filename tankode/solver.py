"""Integration strategies: the ODE solver and how gradients flow through it."""

from __future__ import annotations

import math
from dataclasses import dataclass

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
            that stalls fails with the time and state instead of hanging.
    """

    method: str = "dopri5"
    rtol: float = 1e-7
    atol: float = 1e-9
    max_rhs_evals: int = 200_000

    def __post_init__(self):
        if self.method not in _METHODS:
            raise ValueError(f"AdaptiveRK.method must be one of {_METHODS}, got {self.method!r}")
        _check_budget(self)


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
    max_rhs_evals: int = 200_000

    def __post_init__(self):
        _check_budget(self)


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
    """

    rtol: float = 1e-6
    atol: float = 1e-8
    max_rhs_evals: int = 200_000

    def __post_init__(self):
        _check_budget(self)


@dataclass(frozen=True)
class NoGradient:
    """Forward only (no autograd graph): simulation, prediction, benchmarks."""


@dataclass(frozen=True)
class Backprop:
    """Differentiate through the solver's operations (``torchdiffeq.odeint``).

    Exact gradient of the discrete solution; memory grows with the number of solver steps.
    """


@dataclass(frozen=True)
class Checkpointed:
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


@dataclass(frozen=True)
class Adjoint:
    """Continuous adjoint (``torchdiffeq.odeint_adjoint``): memory independent of the step count.

    Attributes:
        rtol, atol: tolerances of the backward (adjoint) solve; None = the forward ones.
    """

    rtol: float | None = None
    atol: float | None = None


__all__ = ["AdaptiveRK", "LSODA", "Rosenbrock", "NoGradient", "Backprop", "Checkpointed", "Adjoint"]
