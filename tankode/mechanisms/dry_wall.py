"""A dry wall that heats the ullage: ambient heat above the liquid line goes to the vapour, not the lump."""

from __future__ import annotations

from .base import Mechanism, Param


class DryWallHeating(Mechanism):
    """A fraction phi of the ambient heat falling on the dry wall heats the ullage directly.

    Physics. The baseline's wall is one lump at ``T_w``: the ambient heat ``Q_aw`` falling on
    the wall above the liquid (the dry wall, area ``A_wv`` of ``A_w``) enters the lump, which
    the liquid holds near its own temperature, so most of it ends in the liquid. In a large
    tank the shell is thin and conducts poorly at 20 K: the dry wall runs warmer than the
    wetted wall and its heat rises with the ullage's boundary layer (and through top
    penetrations) into the ullage, the classic self-pressurisation picture of a superheated
    ullage over a near-saturated liquid. A fraction ``phi`` of the dry wall's share of the
    ambient heat goes into the vapour instead of the lump::

        q_v = phi Q_aw A_wv / A_w,    q_w = -q_v,    q_l = 0,

    an internal redistribution (energy is conserved). ``phi = 0`` is the baseline; ``Q_aw`` is
    the applied forcing's (a ``heat_leak_wall`` is not redistributed). The lump still exchanges
    ``Q_wv`` with the vapour: the closure's ``h_wv`` decides how strongly the cold lump pulls
    the ullage back.

    Signature: under a heat load the ullage superheats and the pressure rises faster than the
    baseline allows, the more so at low fill (large dry area); the wall and the liquid warm
    more slowly. Without ambient heat it does nothing.

    Limits: the dry wall's own temperature and heat capacity and the axial profiles of ullage
    and wall are not resolved; phi is constant while the level (and so the dry area) changes.
    """

    id = "dry_wall_heating"
    model_form = True
    params = (Param("phi", "1", 0.0, 1.0, 0.1),)
    signature = "T_v and pressure rise faster under a heat load, most at low fill; T_w and T_l lag"

    def heat_W(self, s, forcing, fluxes, z):
        dry_share = fluxes.A_wv_m2 / (fluxes.A_wv_m2 + fluxes.A_wl_m2)  # (env,)
        q = self.param(0, fluxes.Q_wv_W) * forcing.Q_aw_W * dry_share  # (env,)
        return q, 0.0, -q


__all__ = ["DryWallHeating"]
