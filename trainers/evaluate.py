"""Judge an agent: predictions from initial state and inputs, RMSE against truth, identified h."""

from __future__ import annotations


import torch

from tankode.closures import ReferenceClosure
from tankode.fleet import Fleet
from tankode.model import TankModel
from tankode.simulation import simulate

from .cost import CHANNELS, Window, cost_terms


def rmse_by_channel(pred_obs: torch.Tensor, truth_obs: torch.Tensor) -> dict[str, float]:
    """RMSE per observation channel of ``(T, 5)`` predictions against ``(T, 5)`` truth (SI units)."""
    err = (pred_obs - truth_obs).detach()
    return {c: float(err[:, i].pow(2).mean().sqrt()) for i, c in enumerate(CHANNELS)}


def validation_cost(closure, runs) -> dict:
    """J of a closure's prediction of whole runs (from their initial state and inputs) against their data.

    Returns the total (mean over runs, as the training cost) and the per-run, per-channel terms.
    """
    runs = list(runs)
    sol = simulate(runs, closure, t_eval=None)
    fleet = Fleet.from_runs(runs)
    w = Window.from_runs(runs, fleet.t0_s - 1e-9, fleet.t_end_s)
    idx = torch.searchsorted(sol.t_s, w.t_s)
    terms = cost_terms(sol.observations[:, idx], w)
    return {"J": float(terms.sum() / len(runs)), "terms": terms.tolist(), "runs": [r.name for r in runs]}


def closure_inputs_along(model: TankModel, fleet: Fleet, t_s: torch.Tensor, states: torch.Tensor) -> list:
    """What the closure sees at each of ``states`` ``(env, T, 7)`` at times ``t_s`` ``(T,)``: T ``ClosureInputs``.

    Detached: the inputs depend on the states and the forcing, not on the closure's weights.
    """
    with torch.no_grad():
        return [model.closure_inputs(states[:, k], model.applied_forcing(fleet.forcing(t, states[:, k])))
                for k, t in enumerate(t_s.tolist())]


def theta_along(model: TankModel, fleet: Fleet, t_s: torch.Tensor, states: torch.Tensor) -> torch.Tensor:
    """Coefficients ``(env, T, 4)`` (W/(m^2 K)) the model's closure gives along ``states`` ``(env, T, 7)``."""
    with torch.no_grad():
        return torch.stack([model.closure(x) for x in closure_inputs_along(model, fleet, t_s, states)], dim=1)


def closure_along(closure, runs, solution) -> torch.Tensor:
    """Coefficients ``(env, T, 4)`` a closure gives along a simulated trajectory (W/(m^2 K))."""
    fleet = Fleet.from_runs(runs)
    model = TankModel(fleet.fluid, fleet.geometry, closure, fleet.wall_heat_capacity_J_per_K)
    return theta_along(model, fleet, solution.t_s, solution.states)


def identification_error(closure, runs, truth_solution, during) -> dict:
    """Relative error of each learned coefficient against the reference along the true trajectory.

    Args:
        closure: the learned closure.
        runs: the runs of ``truth_solution``.
        truth_solution: the reference simulation (the synthetic truth).
        during: bool ``(T,)`` mask of the times to judge (e.g. the sloshing phases).

    Returns:
        per coefficient: mean and max of |h_learned - h_ref| / h_ref over ``during``.
    """
    learned = closure_along(closure, runs, truth_solution)[0]
    ref = closure_along(ReferenceClosure(), runs, truth_solution)[0]
    rel = ((learned - ref).abs() / ref)[during]
    names = ("h_vi", "h_li", "h_wv", "h_wl")
    return {n: {"mean_rel_err": float(rel[:, i].mean()), "max_rel_err": float(rel[:, i].max())}
            for i, n in enumerate(names)}


__all__ = ["rmse_by_channel", "validation_cost", "closure_inputs_along", "theta_along", "closure_along", "identification_error"]
