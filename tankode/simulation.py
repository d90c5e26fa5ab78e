"""One entry point for forward simulation: ``simulate(runs) -> Solution``."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import torch
from torch import Tensor

from .closures import Closure, ReferenceClosure
from .errors import ImpossibleState, SimulationError, StateLeftDomain
from .fleet import Fleet
from .integrate import IntegrationStats, integrate, state_scale
from .mechanisms import applied_to_walls
from .model import TankModel
from .run import OBS_CHANNELS as OBS_NAMES
from .solver import LSODA, AdaptiveRK, NoGradient
from .threads import single_threaded


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
        wall_heat_capacity_J_per_K: m_w c_w used for each environment (J/K): the run's, or
            the estimate where the run gives none.
    """

    t_s: Tensor
    states: Tensor
    observations: Tensor
    status: str
    stats: IntegrationStats
    wall_time_s: float
    notes: tuple[str, ...] = field(default=())
    wall_heat_capacity_J_per_K: tuple[float, ...] = field(default=())

    @property
    def real_time_factor(self) -> float:
        """Simulated seconds per wall-clock second."""
        return float(self.t_s[-1] - self.t_s[0]) / max(self.wall_time_s, 1e-12)


# Output times of one simulation at most: 10 million states of 7 float64 per tank is 560 MB, a
# day at 10 ms; beyond it an output grid exhausts memory before the solver starts.
MAX_OUTPUT_TIMES = 1e7


def output_times(fleet: Fleet, dt_s: float | None, t_eval=None) -> Tensor:
    """Output grid: ``t_eval`` if given, else every ``dt_s`` plus the runs' observation times."""
    t0, t1 = fleet.t0_s, fleet.t_end_s
    if t_eval is not None:
        return torch.tensor(np.asarray(t_eval, dtype=float))  # a copy: run arrays are read-only
    if dt_s is None or not dt_s > 0:
        raise ValueError(f"output_dt_s must be > 0 s, got {dt_s}")
    if (t1 - t0) / dt_s > MAX_OUTPUT_TIMES:
        raise ValueError(f"output_dt_s = {dt_s:g} s gives {(t1 - t0) / dt_s:.3g} output times over the run's "
                         f"{t1 - t0:g} s, more than {MAX_OUTPUT_TIMES:.0e}: choose a longer spacing (--dt)")
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
        SimulationError: the solver failed or the tank reached a state it cannot go on from (an
            empty ullage, a dry tank): the message names the run, the cause, the time and the
            state. A trajectory that leaves its property domain is simulated again on the next
            tier that holds it (``Fleet.on_next_tier``, with a note); beyond them all,
            ``StateLeftDomain``.
    """
    fleet = runs if isinstance(runs, Fleet) else Fleet.from_runs(runs, surrogate)
    closure = ReferenceClosure() if closure is None else closure
    mechanisms, learned = applied_to_walls(mechanisms, [r.name for r in fleet.runs], fleet.walls)
    notes = ()
    while True:
        try:
            states, obs, t_out, stats, wall = _run(fleet, closure, mechanisms, output_dt_s, t_eval, solver,
                                                   check_domain)
            break
        except StateLeftDomain as err:
            # A run that leaves its tier gets the next that holds it (the trajectory is not known
            # before it is simulated); one given a surrogate or a fleet does not. Tiers are only
            # walked forwards, so this ends.
            d0 = fleet.fluid.domain
            wider = None if surrogate is not None or isinstance(runs, Fleet) else fleet.on_next_tier(err.state)
            if wider is None:
                raise
            fleet = wider
            notes += (f"the trajectory left the property domain of {d0.extent()} at t = {err.t_s:.6g} s; "
                      f"simulated on the one of {fleet.fluid.domain.extent()}",)
    notes += fleet.wall_notes() + learned
    return Solution(t_out, states, obs, "success", stats, wall, notes, tuple(w.value_J_per_K for w in fleet.walls))


def _run(fleet: Fleet, closure, mechanisms, output_dt_s, t_eval, solver, check_domain):
    """(states, observations, t_out, stats, wall time) of one simulation of ``fleet``; errors named with their run."""
    model = TankModel(fleet.fluid, fleet.geometry, closure, fleet.wall_heat_capacity_J_per_K, mechanisms)
    s0 = model.initial_state(fleet.initial_state(model.mechanisms))  # (env, n_state)
    t_out = output_times(fleet, output_dt_s, t_eval)
    start = time.perf_counter()
    try:
        states, stats = integrate(model, s0, fleet.segments(fleet.t0_s, fleet.t_end_s), fleet.forcing, t_out,
                                  state_scale(s0, fleet.geometry.volume_m3, model.extra_state_scales), solver,
                                  NoGradient())
    except SimulationError as err:
        raise in_context(err, fleet) from err
    wall = time.perf_counter() - start
    with torch.no_grad():
        obs = model.observe(states)
    if check_domain:
        _check_domain(fleet, t_out, states, model.state_names)
    return states, obs, t_out, stats, wall


def in_context(err: SimulationError, fleet: Fleet) -> SimulationError:
    """``err`` with the run it happened in and, for an impossible state, what the run did to get there."""
    cause = err.__cause__
    if not isinstance(cause, ImpossibleState) or err.t_s is None:
        return err
    run = fleet.runs[cause.env]
    u = run.inputs.as_dict(err.t_s)
    context = []
    if cause.kind == "ullage":
        if run.initial.fill_ratio > 0.95:
            context.append(f"the run starts {run.initial.fill_ratio:g} full, which leaves almost no vapour")
        for name, what in (("mdot_l_in_kg_s", "liquid inflow"), ("mdot_v_out_kg_s", "vent")):
            if u[name] > 0:
                context.append(f"its {what} is {u[name]:g} kg/s")
    elif cause.kind == "dry":
        if u["mdot_l_out_kg_s"] > 0:
            context.append(f"its drain of {u['mdot_l_out_kg_s']:g} kg/s emptied it")
    elif cause.kind == "wall":
        context.append(f"its ambient heat Q_aw_W is {u['Q_aw_W']:g} W")
    elif cause.kind == "domain":
        if err.state is not None:
            V_v, V_l = (float(x) for x in err.state.reshape(-1, err.state.shape[-1])[cause.env, 5:7])
            share = V_v / (V_v + V_l)
            if share < 0.02:
                context.append(f"the ullage is nearly gone ({share:.2%} of the tank): the liquid fills the tank")
            elif share > 0.98:
                context.append(f"the tank is nearly dry ({1 - share:.2%} of it liquid)")
        if u["mdot_v_in_kg_s"] > 0:
            context.append(f"its vapour inflow is {u['mdot_v_in_kg_s']:g} kg/s")
    message = f"run {run.name!r}: {cause.cause}" + (f" ({'; '.join(context)})" if context else "")
    out = type(err)(message, err.t_s, err.state)
    return out


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
            d = fleet.fluid.domain
            props = fleet.fluid.props(phase, u[env, k], rho[env, k])
            raise StateLeftDomain(
                f"run {fleet.runs[env].name!r}: the {phase} state left the property surrogate's fitted domain at "
                f"p = {float(props.p):.4g} Pa, T = {float(props.T):.4g} K (saturation {float(props.T_sat):.4g} K; "
                f"the domain: {d.p_min_Pa:.4g} to {d.p_max_Pa:.4g} Pa, the vapour up to {d.T_v_max_K:.4g} K, "
                f"{float(d.margin_K(props.T_sat)):.2g} K past saturation on either side there)",
                float(t[k]), states[env, k][None], names,
            )


__all__ = ["simulate", "Solution", "output_times", "OBS_NAMES"]
