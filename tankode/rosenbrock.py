"""A differentiable, linearly implicit solver for stiff tanks: the ROS34PW2 Rosenbrock-W method.

Light walls (aluminium at 20 K) give the tank model wall time constants of seconds in runs of
hours. Explicit Runge-Kutta steps are then limited by stability, not accuracy, and an explicit
solver differentiated through its steps (or its adjoint, which re-integrates the stiff system
backwards and diverges) cannot train an agent on such a tank in real time. ROS34PW2 (Rang and
Angermann 2005, BIT 45, table of ROS34PW2) is L-stable, stiffly accurate, third order with an
embedded second-order solution, and a *W-method*: its order holds for any matrix in place of the
Jacobian. Two properties follow that make it fit autograd:

* The Jacobian is a finite-difference estimate taken without autograd (one right-hand side per
  state component, all environments at once) and treated as a constant. Differentiating the
  steps with that matrix frozen is differentiating a W-method step of the variational equations
  with an approximate Jacobian, which keeps its order: the gradient is the solution's to the
  solver's tolerance, with no second derivatives of the model and no backward re-integration.
* Each step needs four right-hand sides with autograd, whatever the stiffness. The Jacobian is
  taken at the call's start and renewed after ``_JACOBIAN_AGE`` accepted steps or on a
  rejection (a W-method keeps its order with a stale matrix; only its stability suffers, which
  shows as short steps that are all accepted).

One step of size h from (t, z), W = I - gamma h J (Hairer and Wanner's form, J frozen):

    W k_i = h f(z + sum_{j<i} alpha_ij k_j) + h J sum_{j<i} gamma_ij k_j,   i = 1..4
    z_new = z + sum_i b_i k_i,    error estimate sum_i (b_i - bhat_i) k_i

Limits: the model is taken as autonomous between input changes (the tank model is: its forcing
is constant in a segment), so no d f / d t term; forward differences make the Jacobian accurate
to about 1e-8 relative, which the W-method tolerates; no continuous adjoint (``Adjoint()`` is
refused).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from .errors import SimulationError

# ROS34PW2 (Rang and Angermann 2005): gamma, alpha_ij and gamma_ij (j < i), b and the embedded bhat.
_GAMMA = 0.435866521508459
_ALPHA = ((), (0.871733043016918,), (0.8445706001536942, -0.1129906423648419), (0.0, 0.0, 1.0))
_GAMMA_OFF = ((), (-0.871733043016918,), (-0.9033805701304408, 0.05418067238809533),
              (0.2421238070609535, -1.223250583904515, 0.5452602553351021))
_B = (0.2421238070609535, -1.223250583904515, 1.545260255335102, 0.435866521508459)
_B_HAT = (0.3781090314581937, -0.09604229221242318, 0.5, 0.2179332607542295)
_ORDER_HAT = 2  # the embedded solution's order: the error estimate is O(h^3)
_SAFETY, _MIN_FACTOR, _MAX_FACTOR = 0.9, 0.2, 5.0
_EXPONENT = -1.0 / (_ORDER_HAT + 1)
_MAX_REJECTS = 40  # consecutive rejections of one step before giving up (each shrinks h by 0.2 to 0.9)
# Accepted steps a Jacobian serves before a fresh one is taken. A W-method keeps its order with a
# stale matrix but not its damping of a fast mode whose rate has drifted since: the error
# control then holds the steps short without rejecting any, and the matrix is never renewed.
# Measured on 4 h of the MHTB tank with the two-node wall: 2,362 right-hand sides (about 470
# steps) with one Jacobian per call; renewing it every 5, 10 or 20 steps 1,085, 992 and 980
# (about 160-180 steps), every step 2,269. Each renewal costs n right-hand sides without autograd.
_JACOBIAN_AGE = 10


@dataclass(frozen=True)
class WarmStart:
    """Where a solve left off, for the next one to start from (the tank after an input change).

    A fleet's batched ODE restarts wherever any of its tanks' inputs change (516 times in a
    10-minute window of 1,024 tanks), and a fresh Jacobian costs n right-hand sides each time;
    the other tanks' Jacobians did not change, and a W-method keeps its order with the changed
    tank's stale one (a rejection renews it).

    Attributes:
        jacobian: the last Jacobian ``(env, n, n)`` of the scaled state (a constant, no graph).
        age: accepted steps it has served (renewed at ``_JACOBIAN_AGE``, as within one call).
    """

    jacobian: Tensor
    age: int = 0


class StepFailure(RuntimeError):
    """ROS34PW2 could not take a step: the step size collapsed; carries the time (s) of the failure."""

    def __init__(self, message: str, t_s: float):
        super().__init__(message)
        self.t_s = t_s


def _rms_norm(e: Tensor, z: Tensor, z_new: Tensor, rtol: float, atol: float) -> float:
    """Largest over environments of the RMS of ``e`` in units of the tolerance, ``e`` ``(env, n)``."""
    tol = atol + rtol * torch.maximum(z.abs(), z_new.abs())
    return float(((e / tol) ** 2).mean(dim=-1).sqrt().max())


def _factor(err: float) -> float:
    """The next step over this one for a scaled error ``err`` (inf: a stage left the model's domain)."""
    if not math.isfinite(err):
        return 0.25
    if err == 0:
        return _MAX_FACTOR
    return min(_MAX_FACTOR, max(_MIN_FACTOR, _SAFETY * err ** _EXPONENT))


def _jacobian(func, t: float, z: Tensor, f0: Tensor) -> Tensor:
    """Forward-difference Jacobian ``(env, n, n)`` of ``func`` at ``z`` ``(env, n)``, without autograd.

    Column j perturbs component j of every environment at once (the environments do not
    interact), so the cost is n right-hand sides.
    """
    n = z.shape[-1]
    t, z, f0 = torch.tensor(t, dtype=torch.float64), z.detach(), f0.detach()
    cols = []
    with torch.no_grad():
        for j in range(n):
            dz = 1.5e-8 * z[:, j].abs().clamp_min(1.0)  # (env,): sqrt(machine epsilon) on the scaled state
            zp = z.clone()
            zp[:, j] += dz
            cols.append((func(t, zp) - f0) / dz[:, None])
    return torch.stack(cols, dim=-1)


def _step(func, t: float, z: Tensor, f0: Tensor, h: float, J: Tensor, lu: Tensor, piv: Tensor) -> tuple[Tensor, Tensor]:
    """One ROS34PW2 step: the new state and the error estimate, both ``(env, n)``."""
    ks: list[Tensor] = []
    for i in range(4):
        if i == 0:
            f = f0
        else:
            zi = z + sum(a * k for a, k in zip(_ALPHA[i], ks) if a != 0.0)
            f = func(torch.tensor(t + h * sum(_ALPHA[i]), dtype=torch.float64), zi)
        rhs = h * f
        if i > 0:
            g = sum(c * k for c, k in zip(_GAMMA_OFF[i], ks))
            rhs = rhs + h * (J @ g[..., None])[..., 0]
        ks.append(torch.linalg.lu_solve(lu, piv, rhs[..., None])[..., 0])
    z_new = z + sum(b * k for b, k in zip(_B, ks))
    err = sum((b - bh) * k for b, bh, k in zip(_B, _B_HAT, ks))
    return z_new, err


def rosenbrock_solve(func, z0: Tensor, ts: Tensor, rtol: float, atol: float, first_step: float | None = None) -> Tensor:
    """States ``(len(ts), env, n)`` of ``rosenbrock_solve_warm`` started cold (see there)."""
    return rosenbrock_solve_warm(func, z0, ts, rtol, atol, first_step)[0]


def rosenbrock_solve_warm(func, z0: Tensor, ts: Tensor, rtol: float, atol: float, first_step: float | None = None,
                          warm: WarmStart | None = None) -> tuple[Tensor, WarmStart]:
    """Integrate ``dz/dt = func(t, z)`` with adaptive ROS34PW2 steps; states ``(len(ts), env, n)`` at ``ts``.

    Args:
        func: ``func(t, z) -> dz/dt``, ``t`` a 0-d float64 tensor, ``z`` ``(env, n)``. It may raise
            ``SimulationError`` for a state outside the model's domain: a trial stage that does
            so rejects the step (shrunk by 4) unless ``func`` reports its evaluation budget spent
            (``func._segment_evals > func.max_evals``), which ends the solve.
        z0: initial state ``(env, n)`` at ``ts[0]`` (may require grad).
        ts: output times (s), strictly increasing, ``(T,)``. The steps do not stop at them: the
            states there come from the cubic Hermite interpolant of the step that spans them
            (values and slopes at both ends), so dense outputs do not shorten the steps.
        rtol, atol: tolerances on ``z`` (RMS over components, worst environment).
        first_step: initial step (s); None = estimated from the initial slope.
        warm: where a previous call left off (``WarmStart``): its Jacobian serves as this
            call's first; None = a fresh one.

    Returns:
        ``(T, env, n)``, differentiable with respect to ``z0`` and ``func``'s parameters, and the
        ``WarmStart`` a next call continuing from ``ts[-1]`` may take.

    Raises:
        StepFailure: ``_MAX_REJECTS`` consecutive rejections (the step size collapsed).
    """
    def spent() -> bool:
        return getattr(func, "_segment_evals", 0) > getattr(func, "max_evals", math.inf)

    t_list = [float(x) for x in ts]
    t_end = t_list[-1]
    out = [z0]
    nxt = 1  # index of the next output time
    z = z0
    t = t_list[0]
    f0 = func(torch.tensor(t, dtype=torch.float64), z)
    if first_step is None:
        # Estimated afresh after an input change too: a jump in the forcing can start a fast
        # transient that the previous step would overshoot (measured: a carried step cost more
        # right-hand sides in rejections than it saved).
        d0 = float(z.detach().abs().max().clamp_min(1e-5))
        d1 = float(f0.detach().abs().max().clamp_min(1e-12))
        first_step = 0.01 * d0 / d1
    h = max(first_step, 1e-9 * max(abs(t), 1.0))
    eye = torch.eye(z.shape[-1], dtype=z.dtype)
    if warm is None:
        J, fresh, age = _jacobian(func, t, z, f0), True, 0
    elif warm.jacobian.shape != (*z.shape, z.shape[-1]):
        raise ValueError(f"warm start's Jacobian has shape {tuple(warm.jacobian.shape)}, the state {tuple(z.shape)}")
    else:
        # A W-method keeps its order with any matrix: the last call's Jacobian serves until the
        # first rejection or _JACOBIAN_AGE steps, as it would have within one call.
        J, fresh, age = warm.jacobian, False, warm.age
    while nxt < len(t_list):
        rejects = 0
        refused = None
        while True:
            last = t + h >= t_end - 1e-12 * max(abs(t_end), 1.0)
            step = t_end - t if last else h
            lu, piv = torch.linalg.lu_factor(eye - _GAMMA * step * J)  # (env, n, n), constant for autograd
            try:
                z_new, err_vec = _step(func, t, z, f0, step, J, lu, piv)
                err = _rms_norm(err_vec.detach(), z.detach(), z_new.detach(), rtol, atol)
                if not math.isfinite(err):
                    err = math.inf
                elif err <= 1.0:
                    f_new = func(torch.tensor(t + step, dtype=torch.float64), z_new)
            except SimulationError as failure:
                if spent():
                    raise
                refused = failure  # kept to say why the steps collapsed, if they do
                err = math.inf
            if err <= 1.0:
                break
            rejects += 1
            if rejects > _MAX_REJECTS:
                why = f"; the last trial stage: {refused.message}" if refused is not None else ""
                raise StepFailure(f"ROS34PW2: {rejects} consecutive step rejections, step size {step:.3g} s{why}", t)
            h = step * _factor(err)
            if not fresh:  # a stale Jacobian may be why: take a new one before shrinking further
                J, fresh, age = _jacobian(func, t, z, f0), True, 0
        t_new = t_end if last else t + step
        while nxt < len(t_list) and t_list[nxt] <= t_new:
            out.append(_hermite(t_list[nxt], t, z, f0, t_new, z_new, f_new))
            nxt += 1
        h = step * _factor(err)
        t, z, f0, fresh = t_new, z_new, f_new, False
        age += 1
        if age >= _JACOBIAN_AGE and nxt < len(t_list):
            J, fresh, age = _jacobian(func, t, z, f0), True, 0
    return torch.stack(out), WarmStart(J, age)


def _hermite(t_out: float, t0: float, z0: Tensor, f0: Tensor, t1: float, z1: Tensor, f1: Tensor) -> Tensor:
    """Cubic Hermite interpolant of a step at ``t_out`` (third order, as the step; differentiable)."""
    h = t1 - t0
    th = (t_out - t0) / h
    if th >= 1.0:
        return z1
    h00, h10 = 2 * th**3 - 3 * th**2 + 1, th**3 - 2 * th**2 + th
    h01, h11 = -2 * th**3 + 3 * th**2, th**3 - th**2
    return h00 * z0 + (h10 * h) * f0 + h01 * z1 + (h11 * h) * f1


__all__ = ["rosenbrock_solve", "rosenbrock_solve_warm", "StepFailure", "WarmStart"]
