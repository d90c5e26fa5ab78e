"""The wall as two nodes, the dry part above the liquid and the wetted part below, with heat capacity."""

from __future__ import annotations

import torch

from .base import Mechanism, Param, StateVar

# Each node keeps at least this share of the wall's capacity, so that a nearly full or nearly
# empty tank does not divide by a vanishing node (its temperature then follows the other's).
_MIN_SHARE = 0.02


def _area_shares(A_wv_m2, A_wl_m2):
    """(a_d, a_w, A_w): the dry and wetted shares of the wall's area, each at least ``_MIN_SHARE``."""
    A_w = A_wv_m2 + A_wl_m2
    a_d = (A_wv_m2 / A_w).clamp(_MIN_SHARE, 1 - _MIN_SHARE)
    return a_d, 1 - a_d, A_w


def _smooth_positive(x, eps):
    return 0.5 * (x + torch.sqrt(x * x + eps * eps))


class TwoNodeWall(Mechanism):
    """The dry and the wetted wall at their own temperatures, tied by conduction along the shell.

    Physics. The baseline's wall is one lump at ``T_w``. In a real tank the wall above the
    liquid (area ``A_wv``, capacity ``C_d = a_d C_w`` with ``a_d = A_wv / A_w``) receives its
    share of the ambient heat, ``a_d Q_aw``, and gives it to the ullage, while the wetted wall
    (``C_ww = a_w C_w``, ``a_w = 1 - a_d``) is held near the liquid's temperature; the two
    exchange heat only by conduction along the shell across the liquid line, ``G (T_d - T_ww)``
    with ``G = 2 L_c^2 / (R_s A_w)``, the conductance of a strip of width ``L_c`` (the liquid
    line) between the nodes' centroids, ``A_w / (2 L_c)`` apart on average; ``R_s = 1 / (k t)``
    is the shell's sheet resistance (K/W; aluminium of 10 mm at 20 K about 5-10, stainless steel
    of 3 mm about 150-300). Own state: ``x = T_d - T_ww`` (K). ``T_w``, the model's wall state,
    stays the capacity-weighted mean ``a_d T_d + a_w T_ww``, which is what a wall sensor
    averaging over the wall reads; the nodes are ``T_d = T_w + a_w x`` and ``T_ww = T_w - a_d x``.

    The ullage receives ``h_wv A_wv (T_d - T_v)`` and the liquid ``h_wl A_wl (T_ww - T_l)``
    instead of the lump's, each coefficient computed by the closure on the node its phase touches
    (``wall_node_offsets_K``, ``ClosureInputs.wall_temperatures_K``), i.e.
    ``q_v = h_wv A_wv a_w x`` and ``q_l = -h_wl A_wl a_d x`` beyond the baseline, which the lump
    gives up (``q_w = -(q_v + q_l)``): energy is conserved. As the level moves, wall material
    changes node with its temperature: a rising level turns dry wall
    at ``T_d`` into wetted wall, a falling one wetted wall at ``T_ww`` into dry (the mixing of
    ``tests/nodal_sim.py``-like nodal models, here written for the difference ``x``)::

        C_d dT_d/dt  = a_d Q_aw - h_wv A_wv (T_d - T_v) - G x + min(r, 0) x
        C_ww dT_ww/dt = a_w Q_aw - h_wl A_wl (T_ww - T_l) + G x + max(r, 0) x,   r = C_w dA_wl/dt / A_w

    ``R_s = 0`` is the baseline (a perfectly conducting lump: ``x`` stays 0).

    Signature: under a heat load the dry wall warms above the wetted wall and holds the ullage
    superheated, most at low fill; a warm gas injection heats the dry wall, which then gives
    the heat back to the ullage over minutes to hours; ``T_w`` (the mean) lags the liquid.

    Start. A wall sensor (the run format's ``T_w``) reads the mean, not the split between the
    nodes. ``start_share`` ``c`` (in [0, 1], an ``initial`` parameter) places it::

        T_ww(0) = T_w - c (T_w - T_l),   T_d(0) = T_w + c (a_w / a_d) (T_w - T_l),

    i.e. ``x(0) = c (T_w - T_l) / a_d``: at 0 the wall starts uniform (a lumped wall, as the
    paper's cases have it), at 1 the wetted wall starts at the liquid's temperature and the dry
    wall holds the rest of the measured mean (a tank at rest under a heat load, where the
    liquid's convection holds the wetted wall within a fraction of a kelvin of it). The mean is
    the sensor's in every case. Which one a tank has is for its data to say: the assimilation
    fits its first window from both ends and keeps the split only where it fits clearly better
    (``trainers.assimilate.Assimilator._place_wall_start``; measured in ``experiments/README.md``,
    section 5).

    Limits: one node per part (no profile along the wall); the ambient flux uniform over the
    wall; other mechanisms' heat into the wall goes to the mean, not to a node; each node keeps
    at least 2 % of the capacity, so at a nearly full tank ``x(0)`` is at most 50 times the
    wall's excess over the liquid.
    """

    id = "two_node_wall"
    model_form = True
    alternative_to = ("dry_wall_node",)
    params = (Param("R_sheet_K_per_W", "K/W", 0.0, 1.0e4, 10.0),
              Param("start_share", "1", 0.0, 1.0, 1.0, initial=True))
    signature = "T_v above T_l under a heat load and after warm-gas injection; T_w (the mean) lags"
    states = (StateVar("dT_dry_wet_K", "K", 1.0),)

    def _shares(self, fluxes):
        """(a_d, a_w, A_w) from anything with the two wall areas (``Fluxes``, ``Start``)."""
        return _area_shares(fluxes.A_wv_m2, fluxes.A_wl_m2)

    def initial_state(self, s0, start):
        a_d = self._shares(start)[0]
        R_s, share = self.param(0, a_d), self.param(1, a_d)
        x0 = torch.where(R_s > 0, share * (s0[..., 4] - start.T_l_K) / a_d, torch.zeros_like(a_d))
        return x0.unsqueeze(-1)

    def wall_node_offsets_K(self, z, A_wv_m2, A_wl_m2):
        a_d, a_w, _ = _area_shares(A_wv_m2, A_wl_m2)
        x = z[..., 0]
        return a_w * x, -a_d * x

    def heat_W(self, s, forcing, fluxes, z):
        x = z[..., 0]
        a_d, a_w, _ = self._shares(fluxes)
        q_v = fluxes.theta_W_m2K[..., 2] * fluxes.A_wv_m2 * a_w * x
        q_l = -fluxes.theta_W_m2K[..., 3] * fluxes.A_wl_m2 * a_d * x
        return q_v, q_l, -(q_v + q_l)

    def state_derivative(self, z, s, forcing, fluxes, liquid, tank_rate):
        x = z[..., 0]
        R_s = self.param(0, x)
        a_d, a_w, A_w = self._shares(fluxes)
        C_w = fluxes.C_w_J_per_K
        T_w, T_v, T_l = s[..., 4], fluxes.T_v_K, fluxes.T_l_K
        T_d, T_ww = T_w + a_w * x, T_w - a_d * x
        G = 2 * fluxes.L_c_m**2 / (torch.where(R_s > 0, R_s, 1.0) * A_w)
        # material changing node: r = d(C_ww)/dt, from the level's motion dH/dt = (dV_l/dt) / A_i
        r = C_w * fluxes.dA_wl_dH_m * tank_rate[..., 6] / fluxes.A_i_m2 / A_w
        eps = 1e-6 * C_w / 3600.0  # a rounding of the switch far below any real level rate's
        rise, fall = _smooth_positive(r, eps), -_smooth_positive(-r, eps)
        dT_d = (a_d * forcing.Q_aw_W - fluxes.theta_W_m2K[..., 2] * fluxes.A_wv_m2 * (T_d - T_v) - G * x
                + fall * x) / (a_d * C_w)
        dT_ww = (a_w * forcing.Q_aw_W - fluxes.theta_W_m2K[..., 3] * fluxes.A_wl_m2 * (T_ww - T_l) + G * x
                 + rise * x) / (a_w * C_w)
        dx = torch.where(R_s > 0, dT_d - dT_ww, torch.zeros_like(x))
        return torch.stack([dx], dim=-1)


__all__ = ["TwoNodeWall"]
