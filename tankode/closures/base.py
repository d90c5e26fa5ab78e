"""The closure interface: theta = g(s; w), the four heat transfer coefficients."""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor, nn

# Order of the four coefficients in theta (paper: theta_0..theta_3).
H_VI, H_LI, H_WV, H_WL = range(4)
THETA_NAMES = ("h_vi_W_m2K", "h_li_W_m2K", "h_wv_W_m2K", "h_wl_W_m2K")

GRAVITY_M_S2 = 9.80665


class ClosureInputs(NamedTuple):
    """What a closure may depend on, per environment (every field shaped ``(env,)``).

    Temperatures in K, densities in kg/m^3, lengths in m, frequency in Hz, masses in kg, mass
    flows in kg/s. ``vapor`` and ``liquid`` are the surrogate's ``PhaseProps`` of each phase
    (k, mu, cp, beta, ...). The four mass flows are the operations applied over the segment
    (``tankode.forcing.Forcing``): an inflow or outflow stirs the phase it crosses.

    ``T_w_K`` is the wall's mean (what a wall sensor reads); ``T_wv_K`` and ``T_wl_K`` are the
    temperatures of the wall the ullage and the liquid touch (a two-node wall's dry and wetted
    nodes, ``tankode.mechanisms.TwoNodeWall``), None where the wall is one lump
    (``wall_temperatures_K`` then gives the mean for both). A wall closure must convect on the
    temperature difference its own surface sees: after a warm-gas injection the dry wall is
    warmer than the ullage while the mean, held down by the wetted wall, is kelvins colder.
    """

    T_v_K: Tensor
    T_l_K: Tensor
    T_w_K: Tensor
    T_sat_K: Tensor
    rho_v_kg_m3: Tensor
    rho_l_kg_m3: Tensor
    vapor: NamedTuple
    liquid: NamedTuple
    H_l_m: Tensor
    radius_m: Tensor
    aspect_ratio: Tensor
    slosh_amplitude_m: Tensor
    slosh_frequency_Hz: Tensor
    m_v_kg: Tensor
    m_l_kg: Tensor
    mdot_v_in_kg_s: Tensor
    mdot_v_out_kg_s: Tensor
    mdot_l_in_kg_s: Tensor
    mdot_l_out_kg_s: Tensor
    T_wv_K: Tensor | None = None
    T_wl_K: Tensor | None = None

    def wall_temperatures_K(self) -> tuple[Tensor, Tensor]:
        """``(T_wall_vapour, T_wall_liquid)`` ``(env,)``: each phase's wall, the mean where not given."""
        return (self.T_w_K if self.T_wv_K is None else self.T_wv_K,
                self.T_w_K if self.T_wl_K is None else self.T_wl_K)


class Closure(nn.Module):
    """Base class: maps ``ClosureInputs`` to ``theta`` of shape ``(env, 4)`` in W/(m^2 K).

    Order: ``[h_vi, h_li, h_wv, h_wl]``: vapour-interface, liquid-interface, wall-vapour,
    wall-liquid. Implementations must return finite, positive coefficients for any state in
    the surrogate's domain, and be differentiable w.r.t. their parameters and the state.
    """

    def forward(self, x: ClosureInputs) -> Tensor:  # pragma: no cover - interface
        raise NotImplementedError


class ConstantClosure(Closure):
    """Fixed coefficients (for analytic test problems and sensitivity studies).

    Args:
        theta_W_m2K: four coefficients ``[h_vi, h_li, h_wv, h_wl]`` in W/(m^2 K), each >= 0.
        trainable: register them as a parameter (e.g. to identify constant h from data).
    """

    def __init__(self, theta_W_m2K, trainable: bool = False):
        super().__init__()
        theta = torch.as_tensor(theta_W_m2K, dtype=torch.float64)
        if theta.shape != (4,) or not torch.isfinite(theta).all() or (theta < 0).any():
            raise ValueError(f"theta_W_m2K must be 4 finite values >= 0 W/(m^2 K), got {theta_W_m2K!r}")
        if trainable:
            self.theta = nn.Parameter(theta)
        else:
            self.register_buffer("theta", theta)

    def forward(self, x: ClosureInputs) -> Tensor:
        return self.theta.expand(*x.T_v_K.shape, 4)


__all__ = ["Closure", "ClosureInputs", "ConstantClosure", "THETA_NAMES", "H_VI", "H_LI", "H_WV", "H_WL", "GRAVITY_M_S2"]
