"""A warm liquid surface layer with its own temperature, fed by the wall's boundary layer."""

from __future__ import annotations

import torch

from .base import Mechanism, Param, StateVar


class SurfaceLayer(Mechanism):
    """A thin liquid layer under the interface, warmer than the bulk by a state ``x`` (K).

    Physics. A share ``phi`` of the heat entering the liquid through the wetted wall rises in
    the wall's boundary layer and spreads under the interface instead of mixing into the
    bulk; heat the interface gives to (or takes from) the liquid stays in that layer too,
    because warm liquid on top is stably stratified. The layer, of thickness ``delta`` (heat
    capacity ``C_s = rho_l c_p,l A_i delta``), mixes into the bulk at the rate ``k``::

        dx/dt = (phi Q_wl - Q_li) / C_s - k x,     Q_li = h_li A_i (T_l + x - T_sat),

    so the interface sees the layer's temperature ``T_l + x``: a warm layer takes the
    subcooling away from the surface, less vapour condenses and the pressure rises faster.
    The layer is part of the liquid: its excess is already in ``u_l`` (the measured, mass-
    averaged ``T_l``), so energy is conserved and the liquid's balance is unchanged. The
    state starts at 0 (a mixed liquid at the start of the run).

    Parameters. ``inv_thickness_1_per_m`` = 1/delta (0: a layer as thick as the bulk, i.e.
    absent; then ``x`` stays 0 whatever the others), ``wall_share`` = phi (0: the wall's heat
    mixes into the bulk, the layer holds only the interface's) and ``mixing_rate_1_per_s`` =
    k (0: the layer never mixes; 1/k is its mixing time). Without ``phi`` a warm wall would
    drive a thin layer tens of kelvin above saturation (12 kW into a 5 cm layer in case 1);
    the interface's share alone settles at saturation (no more condensation).

    Signature: pressure above the model that grows over hours while the bulk liquid
    temperature follows the baseline's (the layer is too thin to move the average); strong
    when the liquid is subcooled, the interface's heat then staying at the top.

    Limits: the share ``phi`` is constant (a boundary layer's delivery to the surface depends
    on the wall's superheat and the fill); the layer's own temperature change relative to the
    bulk neglects the bulk's warming (``C_s`` << ``m_l c_p,l``); sloshing does not erase it
    unless ``k`` is fitted to it; the interface's mass exchange carries no layer enthalpy. The
    wall-fed source is the product of ``1/delta`` and ``phi``, so at 0 (where the score test
    and a fit from 0 look) it has no slope: they see only the interface's part (on the
    MHTB tests none at all: score 0, a fit from 0 stays there); start a fit from a layer.
    """

    id = "surface_layer"
    model_form = True
    params = (
        Param("inv_thickness_1_per_m", "1/m", 0.0, 1000.0, 50.0),
        Param("wall_share", "1", 0.0, 1.0, 0.1),
        Param("mixing_rate_1_per_s", "1/s", 0.0, 1e-2, 1e-4),
    )
    signature = "pressure above the model growing over hours, bulk liquid temperature unchanged"
    states = (StateVar("dT_layer_K", "K", 1.0),)

    def interface_offset_K(self, z):
        return z[..., 0]

    def state_derivative(self, z, s, forcing, fluxes, liquid, tank_rate):
        x = z[..., 0]  # (env,)
        rho_l = s[..., 1] / s[..., 6]
        inv_c_s = self.param(0, x) / (rho_l * liquid.cp * fluxes.A_i_m2)  # 1/C_s, K/J
        dx = inv_c_s * (self.param(1, x) * fluxes.Q_wl_W - fluxes.Q_li_W) - self.param(2, x) * x
        return torch.stack([dx], dim=-1)


__all__ = ["SurfaceLayer"]
