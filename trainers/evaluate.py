"""Judge an agent: predictions from initial state and inputs, RMSE against truth, identified h."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from tankode.closures import ReferenceClosure
from tankode.fleet import Fleet
from tankode.model import TankModel
from tankode.run import NOISE_KEYS
from tankode.simulation import simulate
from tankode.solver import NoGradient

from .cost import CHANNELS, Window, cost_terms


def rmse_by_channel(pred_obs: torch.Tensor, truth_obs: torch.Tensor) -> dict[str, float]:
    """RMSE per observation channel of ``(T, 5)`` predictions against ``(T, 5)`` truth (SI units)."""
    err = (pred_obs - truth_obs).detach()
    return {c: float(err[:, i].pow(2).mean().sqrt()) for i, c in enumerate(CHANNELS)}


def validation_cost(closure, runs, mechanisms=()) -> dict:
    """J of a model's prediction of whole runs (from their initial state and inputs) against their data.

    ``closure`` and ``mechanisms`` are the model (``mechanisms``: e.g. the two-node wall an
    ``Assimilator`` trained with, ``tuple(assimilator.model.mechanisms)``; a model must be scored
    with the physics it was trained in). Returns the total (mean over runs, as the training
    cost) and the per-run, per-channel terms.
    """
    runs = list(runs)
    sol = simulate(runs, closure, t_eval=None, mechanisms=mechanisms)
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





def rmse_sigmas(run, t_s: torch.Tensor, observations: torch.Tensor, t0_s: float, t1_s: float,
                env: int = 0) -> dict[str, float]:
    """RMSE of predicted ``observations`` ``(env, T, 5)`` at ``t_s`` ``(T,)`` (environment ``env``,
    linearly interpolated) against ``run``'s samples in ``[t0_s, t1_s]``, per measured channel, in
    units of the channel's ``noise_std`` (1 = the noise)."""
    t = t_s.numpy()
    out = {}
    for j, (c, k) in enumerate(zip(CHANNELS, NOISE_KEYS)):
        tt, v = run.observations.channel(c)
        sel = (tt >= t0_s) & (tt <= t1_s)
        if sel.any():
            pred = np.interp(tt[sel], t, observations[env, :, j].numpy())
            out[c] = float(np.sqrt(np.mean((pred - v[sel]) ** 2)) / run.noise_std[k])
    return out


@dataclass(frozen=True)
class HoldOut:
    """An agent trained on a run's first part and judged on its remainder (``hold_out``).

    Attributes:
        run: the run's name. split_s: the time (s) the training data end.
        held_out: RMSE per channel over the remainder, in noise sigmas, of the forecast from
            the state the assimilation carried to the split (``AssimilationResult.state_end``)
            with the final agent and no refit: what a real-time twin predicts when its data stop.
        cost_windows: the mean over the windows of each window's J after its update (the
            training part as the stream fitted it, each window from its carried state).
        fit, held_out_from_start: RMSE per channel over the training part and over the
            remainder of the final agent simulated from the run's start (a stricter check: one
            agent for every regime of the training part, the state carried by it alone).
        cost_fit: the cost J of that simulation over the training part; ``floor`` is J at the
            noise (0.5 per measured channel).
        window_wall_s: each window update's wall time (s); ``window_s`` the windows' length.
        mechanisms: trained mechanism values ({id: {parameter: value}}).
    """

    run: str
    split_s: float
    held_out: dict
    cost_windows: float
    fit: dict
    held_out_from_start: dict
    cost_fit: float
    floor: float
    window_wall_s: tuple
    window_s: float
    mechanisms: dict

    @property
    def real_time_factors(self) -> tuple[float, ...]:
        """Window length over each window update's wall time."""
        return tuple(self.window_s / max(w, 1e-9) for w in self.window_wall_s)


def hold_out(run, config, split: float = 0.7, closure=None, on_window=None) -> HoldOut:
    """Train an agent on the first ``split`` of ``run`` with ``config`` and judge it (``HoldOut``):
    the forecast of the remainder from the state the assimilation carried to the split, and the
    whole run simulated from its start with the trained model."""
    from .assimilate import Assimilator

    t_split = run.t0_s + split * (run.t_end_s - run.t0_s)
    assimilator = Assimilator([run.until(t_split)], config, closure=closure)
    result = assimilator.run(on_window=on_window)
    mechanisms = tuple(assimilator.model.mechanisms)
    forecaster = Assimilator([run], config, closure=result.closure, mechanisms=mechanisms)
    t_eval = torch.cat([torch.tensor([t_split], dtype=torch.float64),
                        torch.arange(t_split + 30.0, run.t_end_s, 30.0, dtype=torch.float64),
                        torch.tensor([run.t_end_s], dtype=torch.float64)]).unique()
    with torch.no_grad():
        states = forecaster.predict(result.state_end, t_split, t_eval, NoGradient())
        forecast = forecaster.model.observe(states)
    sol = simulate(run, result.closure, mechanisms=mechanisms, output_dt_s=30.0)
    fit = rmse_sigmas(run, sol.t_s, sol.observations, run.t0_s, t_split)
    w = Window.from_runs([run], run.t0_s - 1e-9, t_split)
    idx = torch.searchsorted(sol.t_s, w.t_s)
    cost_fit = float(cost_terms(sol.observations[:, idx], w).sum())
    cost_windows = float(np.mean([r.cost_after for r in result.reports]))
    return HoldOut(run.name, t_split, rmse_sigmas(run, t_eval, forecast, t_split, run.t_end_s), cost_windows, fit,
                   rmse_sigmas(run, sol.t_s, sol.observations, t_split, run.t_end_s), cost_fit, 0.5 * len(fit),
                   tuple(r.wall_s for r in result.reports), config.window_s,
                   {m.id: m.values_dict() for m in mechanisms})


__all__ = ["rmse_by_channel", "validation_cost", "closure_inputs_along", "theta_along", "closure_along",
           "identification_error", "rmse_sigmas", "HoldOut", "hold_out"]
