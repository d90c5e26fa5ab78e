"""One entry point for forward simulation: ``simulate(runs) -> Solution``."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import torch
from torch import Tensor

from ._threads import single_threaded
from .closures import Closure, ReferenceClosure
from .fleet import Fleet
from .integrate import IntegrationStats, SimulationError, integrate, state_scale
from .model import TankModel
from .solver import LSODA, AdaptiveRK, NoGradient

OBS_NAMES = ("p_v_Pa", "T_v_K", "T_l_K", "T_w_K", "H_l_m")


@dataclass(frozen=True)
class Solution:
    """A simulated trajectory of every environment of a fleet.

    Attributes:
        t_s: output times ``(T,)`` (s).
        states: ``(env, T, 7)`` states ``[m_v, m_l, u_v, u_l, T_w, V_v, V_l]`` (``tankode.state``),
            followed by the mechanisms' own states if they have any (``TankModel.state_names``).
        observations: ``(env, T, 5)`` = h(s) = (p_v [Pa], T_v [K], T_l [K], T_w [K], H_l [m]).
        status: "success" (failures raise ``SimulationError`` instead of returning).
        stats: right-hand-side evaluations and segments.
        wall_time_s: wall-clock time of the integration (s).
        notes: what the simulation assumed (e.g. an estimated wall heat capacity).
    """

    t_s: Tensor
    states: Tensor
    observations: Tensor
    status: str
    stats: IntegrationStats
    wall_time_s: float
    notes: tuple[str, ...] = field(default=())

    @property
    def real_time_factor(self) -> float:
        """Simulated seconds per wall-clock second."""
        return float(self.t_s[-1] - self.t_s[0]) / max(self.wall_time_s, 1e-12)


def output_times(fleet: Fleet, dt_s: float | None, t_eval=None) -> Tensor:
    """Output grid: ``t_eval`` if given, else every ``dt_s`` plus the runs' observation times."""
    t0, t1 = fleet.t0_s, fleet.t_end_s
    if t_eval is not None:
        return torch.tensor(np.asarray(t_eval, dtype=float))  # a copy: run arrays are read-only
    if dt_s is None or not dt_s > 0:
        raise ValueError(f"output_dt_s must be > 0 s, got {dt_s}")
    grid = [np.arange(t0, t1, dt_s), [t1]]
    grid += [r.observations.t_s for r in fleet.runs]
    t = np.unique(np.concatenate(grid))
    return torch.as_tensor(t[(t >= t0) & (t <= t1)], dtype=torch.float64)


@single_threaded()  # small (env, 7) tensors: extra threads only contend (trainers/assimilate.py)
def simulate(
    runs,
    closure: Closure | None = None,
    *,
    surrogate=None,
    output_dt_s: float | None = 10.0,
    t_eval=None,
    solver: AdaptiveRK | LSODA = LSODA(),
    check_domain: bool = True,
    mechanisms=(),
) -> Solution:
    """Simulate runs (their initial state and inputs) with a closure; the forward model.

    Args:
        runs: a ``Run`` or a sequence of runs of one fluid and tank shape (a fleet); each
            becomes one environment of a batched ODE.
        closure: theta = g(s; w); the paper's correlations (``ReferenceClosure``) by default.
        surrogate: property surrogate; the cached default for the runs' fluid if None.
        output_dt_s: spacing (s) of the output grid, which also includes every observation time.
        t_eval: explicit output times (s), overriding ``output_dt_s``.
        solver: the ODE solver strategy; LSODA (stiff-capable) by default.
        check_domain: raise if the trajectory leaves the surrogate's fitted domain
            (results there would be extrapolation).
        mechanisms: extra physical effects (``tankode.mechanisms``) with their values; the
            observations then include their sensor effects (e.g. a pressure bias).

    Returns:
        A ``Solution``.

    Raises:
        SimulationError: the solver failed (message names the time and state) or the state
            left the surrogate domain.
    """
    fleet = runs if isinstance(runs, Fleet) else Fleet.from_runs(runs, surrogate)
    closure = ReferenceClosure() if closure is None else closure
    model = TankModel(fleet.fluid, fleet.geometry, closure, fleet.wall_heat_capacity_J_per_K, mechanisms)
    s0 = model.initial_state(fleet.initial_state(model.mechanisms))  # (env, n_state)
    t_out = output_times(fleet, output_dt_s, t_eval)
    start = time.perf_counter()
    states, stats = integrate(model, s0, fleet.segments(fleet.t0_s, fleet.t_end_s), fleet.forcing, t_out, state_scale(s0, fleet.geometry.volume_m3, model.extra_state_scales),
                              solver, NoGradient())
    wall = time.perf_counter() - start
    with torch.no_grad():
        obs = model.observe(states)
    if check_domain:
        _check_domain(fleet, t_out, states, model.state_names)
    notes = tuple(f"{r.name}: wall heat capacity {w.note}" for r, w in zip(fleet.runs, fleet.walls) if w.assumed)
    return Solution(t_out, states, obs, "success", stats, wall, notes)


def _check_domain(fleet: Fleet, t: Tensor, states: Tensor, names: tuple[str, ...]) -> None:
    rho_v = states[..., 0] / states[..., 5]
    rho_l = states[..., 1] / states[..., 6]
    # A fleet integrates every run to the longest one's end; a state past a run's own end
    # predicts nothing that is scored, so only each run's own span must stay in the domain.
    ends = torch.tensor([r.t_end_s for r in fleet.runs], dtype=t.dtype)
    past_end = t[None, :] > ends[:, None]  # (env, T)
    for phase, u, rho in (("vapor", states[..., 2], rho_v), ("liquid", states[..., 3], rho_l)):
        inside = fleet.fluid.contains(phase, u, rho) | past_end
        if not bool(inside.all()):
            env, k = (~inside).nonzero()[0].tolist()
            raise SimulationError(
                f"run {fleet.runs[env].name!r}: the {phase} state left the property surrogate's fitted domain "
                f"({fleet.fluid.domain}); widen the Domain (tankode.properties.Domain) and refit",
                float(t[k]), states[env, k][None], names,
            )


__all__ = ["simulate", "Solution", "output_times", "OBS_NAMES"]
