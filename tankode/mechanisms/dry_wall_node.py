"""The dry wall as a node of its own, tied to the wetted wall by conduction along the shell."""

from __future__ import annotations

import torch

from .base import Mechanism, Param


class DryWallNode(Mechanism):
    """The wall above the liquid runs at its own temperature, set by conduction down the shell.

    Physics. The baseline's wall is one lump at ``T_w``, which the liquid holds near its own
    temperature; the ullage exchanges ``Q_wv = h_wv A_wv (T_w - T_v)`` with that lump, so an
    ullage warmer than the liquid is cooled by the whole wall. In a real tank the dry wall
    (area ``A_wv``) receives its share of the ambient heat, ``Q_d = Q_aw A_wv / A_w`` (uniform
    flux), and can get rid of it only into the ullage or by conduction along the shell, across
    the liquid line, into the wetted wall. A thin shell at 20 K conducts little, so the dry
    wall runs warmer than the wetted wall and holds the ullage superheated: the classic picture
    of a self-pressurising tank, with the ullage a few kelvin above the liquid.

    The dry wall is a node at ``T_d`` of negligible heat capacity (quasi-steady):

        Q_d = h_wv A_wv (T_d - T_v) + G (T_d - T_w),    G = 3 L_c^2 / (A_wv R_s),

    ``G`` the conductance of a uniformly heated strip of width ``L_c`` (the liquid line, the
    interface's perimeter) and length ``A_wv / L_c`` held at ``T_w`` at one end, for its mean
    temperature (``3 k t w / L``); ``R_s = 1 / (k_w t_w)`` the shell's sheet resistance, the
    parameter (K/W; an aluminium shell of 12.7 mm at 20 K, k_w of order 20-40 W/(m K), has
    ``R_s`` of 2-4 K/W, a stainless one of 3 mm about 300; each MHTB test alone fits 8.8 and
    9.6 K/W, ``experiments/README.md``). The ullage then receives
    ``h_wv A_wv (T_d - T_v)`` instead of ``h_wv A_wv (T_w - T_v)``, and the lump loses the
    same amount, an internal redistribution (energy is conserved, the node stores none)::

        q_v = h_wv A_wv (T_d - T_w) = h_wv A_wv R_s A_wv (Q_d - Q_wv) / (3 L_c^2 + R_s A_wv h_wv A_wv),
        q_w = -q_v,   q_l = 0.

    ``R_s = 0`` is the baseline (a perfectly conducting lump); ``R_s -> inf`` sends the whole
    dry-wall load into the ullage and cuts the ullage from the lump (``dry_wall_heating`` at
    ``phi = 1`` without the lump's pull). Unlike ``dry_wall_heating``'s constant share, the
    split follows the level: a low fill has a long dry wall (weak conduction, a warm ullage),
    a high fill a short one.

    Signature: the ullage stays superheated under a heat load (by ``Q_d / G``), most at low
    fill; without ambient heat it decays towards the wall lump as in the baseline, through the
    node. T_w (the lump, the wetted wall) and T_l warm more slowly.

    Limits: the node has no heat capacity (its time constant ``C_w A_wv / A_w / (h_wv A_wv + G)``
    is minutes for a light aluminium shell, MHTB's; for a heavy wall, like the paper's 2.44e6 J/K
    tank, transients of the dry wall are not resolved); a uniform ambient flux and the strip
    formula (exact for a straight wall, approximate over a head); no axial profile of the
    ullage or the wall.
    """

    id = "dry_wall_node"
    model_form = True
    alternative_to = ("two_node_wall",)
    params = (Param("R_sheet_K_per_W", "K/W", 0.0, 1.0e3, 10.0),)
    signature = "T_v stays above T_l under a heat load (most at low fill); pressure rises faster; T_w lags"

    def heat_W(self, s, forcing, fluxes, z):
        hA = fluxes.theta_W_m2K[..., 2] * fluxes.A_wv_m2  # h_wv A_wv, W/K  # (env,)
        q = hA * self.node_excess_K(self.param(0, fluxes.Q_wv_W), fluxes, forcing.Q_aw_W)
        return q, 0.0, -q

    @staticmethod
    def node_excess_K(R_s_K_per_W, fluxes, Q_aw_W):
        """``T_d - T_w`` (K) of the dry wall over the lump at ``fluxes``: ``q_v = h_wv A_wv (T_d - T_w)``."""
        A_wv, L_c = fluxes.A_wv_m2, fluxes.L_c_m  # (env,)
        hA = fluxes.theta_W_m2K[..., 2] * A_wv
        Q_d = Q_aw_W * A_wv / (A_wv + fluxes.A_wl_m2)
        num = R_s_K_per_W * A_wv * (Q_d - fluxes.Q_wv_W)
        den = 3.0 * L_c**2 + R_s_K_per_W * A_wv * hA
        # den = 0 only with R_s = 0 (absent) on a vanished liquid line: no redistribution then
        return torch.where(den > 0.0, num / torch.where(den > 0.0, den, 1.0), 0.0)


__all__ = ["DryWallNode"]
