"""What a fixed-window update remembers of the windows before it: nothing, or a Laplace prior.

The paper's fixed windows train the agent on the newest window alone. One 10-minute window
of case 1 at high noise cannot tell the liquid side of the interface from the wall-vapour
exchange: with all four coefficients unknown, the Cramer-Rao standard deviation of a constant
multiplier on h_li is 0.29 to 1.4 (in ln h) in the sloshing windows, and h_li and h_wv are
correlated at -0.98 to -1.00. The information of all windows so far pins it to 0.06-0.29
(measured in experiments/README.md). ``Forget()`` (the paper) throws that information away at
every window; ``LaplaceMemory()`` carries it as a sequential Bayesian update would, in the
coefficients' space rather than the weights':

after window k's update, the agent's coefficients along the window's simulated trajectory
``theta_k(t)`` and the Gauss-Newton Hessian ``H_k`` ``(env, 4, 4)`` of that window's cost with
respect to window-constant log-multipliers on them (8 extra simulations of the window, central
differences) are kept. A later window m adds to its cost::

    P_m(w) = sum_k (T_k / T_m) 1/2 d_k(w)^T H_k d_k(w),
    d_k(w) = mean_t ln theta(w; s_k(t)) - mean_t ln theta_k(t)    (env, 4)

the Laplace approximation of window k's log-likelihood as a function of how the agent now
moves its coefficients on window k's states (``T_k / T_m`` converts window k's time-averaged
cost into window m's units). Only the directions the old data determined are held (e.g. h_wl
and h_li + h_wv), so the agent stays free where they said nothing.

Effect (figures in ``experiments/README.md``, ``identification.py --memory laplace`` and the
multi-environment study): it makes the real-time identification **worse** than ``Forget()``,
in the coefficients during sloshing and in the final agent's pressure RMSE, and the windows'
costs after the update stay above the noise floor: what the earlier windows determined is
determined *given the model's own starting state*, which carries the earlier agents' errors,
so the prior locks in coefficients that compensated a drifted state and fights the new data.
On the multi-environment study it helps or hurts depending on the seed and the training
environments, with no trend. ``Forget()`` (the paper's) stays the default.

Limits: the prior is on window means of ln theta, not on their shape within a window; the
states ``s_k`` are the model's, not the truth's; the Hessian is the one at the window's end,
not re-linearised; memory grows by one window's states (``(env, T, 7)``) per window.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from tankode.closures import ScaledClosure
from tankode.model import TankModel
from tankode.solver import NoGradient

from .cost import Window
from .evaluate import closure_inputs_along

# Step of the central differences in ln h: small against the 0.1-1 the data determine, large
# against the solver's relative tolerance (1e-6) so that the differences are not solver noise.
FD_STEP = 1e-3


@dataclass(frozen=True)
class Forget:
    """The paper's fixed windows: each update sees its own window's data only."""


@dataclass(frozen=True)
class LaplaceMemory:
    """Each update also pays for moving the coefficients the earlier windows determined (module docstring)."""


@dataclass
class WindowMemory:
    """What is kept of one window: states ``(env, T, 7)`` at ``t_s`` ``(T,)``, ``mean_log_theta`` ``(env, 4)``,
    ``hessian`` ``(env, 4, 4)`` and the window's length ``duration_s``."""

    t_s: Tensor
    states: Tensor
    mean_log_theta: Tensor
    hessian: Tensor
    duration_s: float

    def to_payload(self) -> dict:
        return {"t_s": self.t_s, "states": self.states, "mean_log_theta": self.mean_log_theta,
                "hessian": self.hessian, "duration_s": self.duration_s}

    @staticmethod
    def from_payload(d: dict) -> "WindowMemory":
        return WindowMemory(d["t_s"], d["states"], d["mean_log_theta"], d["hessian"], float(d["duration_s"]))


def mean_log_theta(closure, inputs: list) -> Tensor:
    """``(env, 4)`` mean over the stored times of ln h, differentiable in the closure's weights."""
    return torch.stack([closure(x).log() for x in inputs], dim=1).mean(1)


def remember(assimilator, s_start: Tensor, t_start: float, t_eval: Tensor, obs_index: Tensor, window: Window,
             states: Tensor, duration_s: float) -> WindowMemory:
    """The memory of a window just trained on: the agent's mean ln h along ``states`` and the cost's Hessian.

    ``states`` ``(env, T, 7)`` is the window's simulation at ``t_eval`` with the updated agent;
    ``duration_s`` the span its time-averaged cost averages over.
    """
    fleet, base = assimilator.fleet, assimilator.model
    n_env = fleet.n_env
    with torch.no_grad():
        mlt = mean_log_theta(base.closure, closure_inputs_along(base, fleet, t_eval, states))
        jac = []
        for j in range(4):
            cols = []
            for sign in (1.0, -1.0):
                factors = torch.ones(n_env, 4, dtype=torch.float64)
                factors[:, j] = float(np.exp(sign * FD_STEP))
                model = TankModel(fleet.fluid, fleet.geometry, ScaledClosure(base.closure, factors),
                                  fleet.wall_heat_capacity_J_per_K, base.mechanisms)
                st = assimilator.predict(s_start, t_start, t_eval, NoGradient(), model=model)
                cols.append(model.observe(st[:, obs_index]))  # (env, T_obs, 5)
            jac.append((cols[0] - cols[1]) / (2 * FD_STEP))
        jac = torch.stack(jac, dim=-1)  # (env, T_obs, 5, 4)
        # Gauss-Newton Hessian of J = mean_env sum 1/2 w inv_var e^2 (trainers/cost.py).
        # Missing samples have weight 0 (trainers/cost.py), so they add no information.
        wv = window.weights * window.inv_var[:, None, :] / n_env  # (env, T_obs, 5)
        hessian = torch.einsum("etci,etc,etcj->eij", jac, wv, jac)
    return WindowMemory(t_eval.clone(), states.detach().clone(), mlt, hessian, float(duration_s))


class Prior:
    """``P_m(w)`` of the module docstring over the remembered windows, for the window now trained on."""

    def __init__(self, assimilator, memories: list[WindowMemory]):
        self.closure = assimilator.closure
        self.memories = memories
        self.inputs = [closure_inputs_along(assimilator.model, assimilator.fleet, m.t_s, m.states) for m in memories]

    def __call__(self, duration_s: float) -> Tensor:
        total = torch.zeros((), dtype=torch.float64)
        for m, inputs in zip(self.memories, self.inputs):
            d = mean_log_theta(self.closure, inputs) - m.mean_log_theta  # (env, 4)
            total = total + 0.5 * (m.duration_s / duration_s) * torch.einsum("ei,eij,ej->", d, m.hessian, d)
        return total


# Command-line names of the strategies (``--memory``).
MEMORIES = {"forget": Forget, "laplace": LaplaceMemory}

__all__ = ["MEMORIES", "Forget", "LaplaceMemory", "WindowMemory", "Prior", "remember", "mean_log_theta"]
