"""A fixed window's initial state estimated jointly with the agent (4D-Var's background term).

A fixed window k > 0 starts, by default, from the state the model itself carried to ``t_k``
with the previous window's agent. Where that agent was wrong the state has drifted (the level
moves ~7 mm, seven times its high noise, per 0.3 K of liquid temperature), and the window's
update then bends the closure to explain an offset that no coefficient caused. Here the start
is instead

    s_start = s_model + M delta,        delta (env, 5), in units of each channel's noise std,

with ``M`` the sensitivity of the tank state to the five observed quantities (p_v, T_v, T_l,
T_w, H_l) at the model's state, so that an offset keeps both phases at one pressure to first
order. ``delta`` is fitted with the weights, and the cost gains the background term

    J_b = 1/(2N) sum_env sum_c (delta_c / beta)^2 / n_c,

the negative log-prior of a Gaussian with std ``beta`` noise sigmas around the carried state,
divided like J by each channel's sample count ``n_c`` (J is a time average: J ~ NLL / n). The
carried state is therefore worth ``1 / beta^2`` samples per channel: with beta = 1 the window's
60 samples decide the offset, and an offset a window's data do not resolve stays at 0.

Limits: the map ``M`` is linear (central differences of CoolProp over +-1 sigma); unmeasured
channels and mechanism states (a surface layer's excess) are not adjusted; the estimate
changes the masses (an offset of the level or the liquid temperature at fixed pressure moves
liquid in or out of the tank): it is a state estimate, not a mass balance.
"""

from __future__ import annotations

import torch
from torch import Tensor

from tankode.state import N_STATE

from .cost import N_CHANNELS, Window


def state_sensitivity(fleet, model, s_model: Tensor, sigma: Tensor) -> Tensor:
    """``M`` ``(env, 7, 5)``: change of the tank state per +1 sigma of each observed quantity.

    Central differences of ``fleet.state_from`` (CoolProp) around the model's own observation
    of ``s_model``, with the hydrogen pressure (a mechanism's sensor offset excluded). A channel
    with ``sigma == 0`` (unmeasured) gets a zero column.

    Args:
        fleet: the runs' ``Fleet`` (geometry, reference fluid).
        model: the ``TankModel`` (observation operator).
        s_model: ``(env, n_state)`` the carried state.
        sigma: ``(env, 5)`` noise std of each channel (Pa, K, K, K, m).
    """
    with torch.no_grad():
        tank = s_model[:, :N_STATE]
        m_v, _, u_v, _, _, V_v, _ = tank.unbind(-1)
        y0 = model.observe(s_model).clone()  # (env, 5)
        y0[:, 0] = model.fluid.vapor(u_v, m_v / V_v).p  # the hydrogen's pressure, not the sensor's
        cols = []
        for c in range(N_CHANNELS):
            step = torch.zeros_like(y0)
            step[:, c] = sigma[:, c]
            pair = []
            for y in (y0 + step, y0 - step):
                V_l = fleet.geometry.volume_at_level(y[:, 4])
                pair.append(fleet.state_from(*(y[:, i].numpy() for i in range(4)), V_l.numpy()))
            cols.append(0.5 * (pair[0] - pair[1]))  # (env, 7)
        return torch.stack(cols, dim=-1)  # (env, 7, 5)


class StartEstimate:
    """The fitted offset of one fixed window's initial state and its background cost.

    Args:
        fleet, model: as for :func:`state_sensitivity`.
        s_model: ``(env, n_state)`` the state the model carried to the window's start.
        window: the window's observations (noise std and sample counts per channel).
        prior_sigmas: ``beta``, the background std of the carried state in noise sigmas; > 0.

    Attributes:
        delta: ``(env, 5)`` the offset in noise sigmas, a leaf tensor to train (starts at 0).
    """

    def __init__(self, fleet, model, s_model: Tensor, window: Window, prior_sigmas: float):
        if not prior_sigmas > 0:
            raise ValueError(f"prior_sigmas must be > 0 noise sigmas, got {prior_sigmas}")
        self.s_model = s_model.detach()
        self.measured = window.inv_var > 0  # (env, 5)
        sigma = torch.where(self.measured, window.inv_var.clamp_min(1e-300).rsqrt(), torch.zeros_like(window.inv_var))
        self.n = (window.weights > 0).sum(1).clamp_min(1).double()  # (env, 5) samples per channel
        self.M = state_sensitivity(fleet, model, self.s_model, sigma)  # (env, 7, 5)
        self.prior_sigmas = float(prior_sigmas)
        self.delta = torch.zeros_like(window.inv_var, requires_grad=True)

    @property
    def offset(self) -> Tensor:
        """``(env, 5)`` the offset in noise sigmas that acts: ``delta`` on the measured channels, 0 elsewhere."""
        return self.delta * self.measured

    def state(self) -> Tensor:
        """The window's initial state ``(env, n_state)`` for the current ``delta``."""
        tank = self.s_model[:, :N_STATE] + torch.einsum("esc,ec->es", self.M, self.offset)
        return torch.cat([tank, self.s_model[:, N_STATE:]], dim=-1)

    def penalty(self) -> Tensor:
        """``J_b`` (dimensionless scalar), on the scale of the window cost J."""
        return 0.5 * ((self.offset / self.prior_sigmas) ** 2 / self.n).sum() / self.delta.shape[0]


__all__ = ["StartEstimate", "state_sensitivity"]
