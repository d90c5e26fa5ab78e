"""A warm surface layer that the wall's boundary layer thickens (the classic stratification picture)."""

from __future__ import annotations

import torch

from .base import Param, StateVar
from .boundary_layer import BoundaryLayerStratification


class GrowingLayer(BoundaryLayerStratification):
    """A warm surface layer fed by the wetted wall's boundary layer, which piles up under it and thickens it.

    Physics. As in ``boundary_layer_stratification`` the wall's heat rises in a turbulent
    natural-convection boundary layer (flow ``mdot_bl``, Eckert & Jackson) and a share ``phi``
    of it stays in a layer under the interface, whose excess over the bulk is ``x``; but the
    liquid the boundary layer delivers is not mixed back into the bulk: it spreads under the
    surface and thickens the layer, as in the stratification models of Tellep & Harper and of
    Bailey et al. (the warm layer grows downward while the bulk stays at its temperature). With
    ``c`` the share of ``mdot_bl`` that reaches the layer and ``delta_0`` its thickness at the
    start, the layer's excess energy ``E = rho_l c_p,l A_i delta x`` and thickness ``delta``::

        dE/dt = phi Q_wl - Q_li,          d delta/dt = c mdot_bl / (rho_l A_i),

    that is ``dx/dt = (phi Q_wl - Q_li) / C_s - x (d delta/dt) / delta`` with
    ``C_s = rho_l c_p,l A_i delta``: the same equation as ``boundary_layer_stratification``,
    whose layer keeps its thickness and hands the delivered liquid on to the bulk, but with a
    thickness that grows, so the layer's heat capacity grows with the time the tank has been
    self-pressurising. A long test at a low heat load then has a thicker, cooler layer than a
    short one at a high load, with the same two parameters.

    States: ``x`` (K) and ``delta - delta_0`` (m, 0 at the start). Parameters:
    ``inv_thickness_1_per_m`` = 1/delta_0 (presence: 0 = absent), ``wall_share`` = phi,
    ``entrainment_share`` = c (0: the layer keeps its initial thickness and never renews).

    Signature: as ``boundary_layer_stratification``, with a pressure rise that slows as the
    layer thickens.

    Limits: the interface sees ``T_l + x`` with ``T_l`` the mass-averaged liquid temperature,
    not the bulk's (the bulk is colder by ``x`` times the layer's share of the liquid): right
    for a layer much thinner than the liquid, an overestimate of the surface temperature when
    it is not; the layer's liquid does not drain back into the bulk; the flow is a vertical
    plate's (see ``boundary_layer_stratification``); no sloshing erosion.

    On the MHTB self-pressurisation tests this layer and the one of fixed thickness predict the
    held-out test's pressure alike, and calibrated on the low-fill test the entrainment goes to
    0 (the fixed layer): those tests do not tell the two layer laws apart (figures in
    ``experiments/README.md``).
    """

    id = "growing_layer"
    params = (
        Param("inv_thickness_1_per_m", "1/m", 0.0, 1000.0, 50.0),
        Param("wall_share", "1", 0.0, 1.0, 0.1),
        Param("entrainment_share", "1", 0.0, 1.0, 1e-2),
    )
    signature = "pressure above the model growing over hours and slowing as the layer thickens, bulk liquid unchanged"
    states = (StateVar("dT_layer_K", "K", 1.0), StateVar("grown_m", "m", 0.01))

    def _growth(self, x, s, fluxes, liquid, inv_delta):
        """``d delta/dt`` (m/s), ``(env,)``: the share ``c`` of the boundary layer's flow piling up under the surface."""
        return self._flow(x, s, fluxes, liquid)

    def state_derivative(self, z, s, forcing, fluxes, liquid, tank_rate):
        x, grown = z[..., 0], z[..., 1]  # (env,)
        inv0 = self.param(0, x)
        inv_delta = inv0 / (1.0 + inv0 * grown)  # 1/(delta_0 + grown); 0 when absent
        growth = self._growth(x, s, fluxes, liquid, inv_delta)  # m/s
        # absent (1/delta_0 = 0): the layer is the whole liquid, nothing to grow or track
        growth = torch.where(inv0 > 0, growth, torch.zeros_like(growth))
        return torch.stack([inv_delta * (self._source(x, s, fluxes, liquid) - growth * x), growth], dim=-1)


__all__ = ["GrowingLayer"]
