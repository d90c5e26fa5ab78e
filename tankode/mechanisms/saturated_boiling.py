"""A share of the liquid that boils as soon as it passes saturation, not at the bulk's superheat."""

from __future__ import annotations

from ..bulk import BulkPhaseChange
from .base import Mechanism, Param

# K past saturation at which the boiling share flashes. A lumped liquid that boils holds its
# temperature within this of T_sat(p), so the threshold is a pressure bias of the model of
# THRESHOLD_K * dp_sat/dT (LH2 at 1-3 bar: 40-75 kPa/K): 0.01 K keeps it at 0.4-0.8 kPa, about
# one sensor sigma, where 0.05 K put it at 2-4 kPa. The softplus onset is a tenth of it, so a
# liquid sitting at saturation sees exp(-10) of the onset width (1e-3 K) and stays put; the
# surrogate's saturation temperature is accurate to 4e-4 K at 20 K.
THRESHOLD_K = 0.01


class SaturatedBoiling(Mechanism):
    """Liquid flashing at saturation: the share of the liquid that does not superheat.

    Physics. The baseline's liquid flashes in its bulk only ``flash_threshold_K`` (0.2 K) past
    saturation at the ullage pressure (``tankode.bulk``): a superheat that nucleate boiling on
    the wall needs. A depressurised tank's liquid surface and the liquid against a warm wall
    boil at saturation, and tanks differ in how much of the lumped liquid that is: a thin
    surface layer over a subcooled bulk, or a well-stirred liquid that follows ``T_sat(p)``
    through a vent or a drain. The share ``c`` (in [0, 1]) of the liquid that boils at
    ``THRESHOLD_K`` past saturation adds, beside the bulk's flash,

        J = c m_l c_p,l sp(T_l - T_sat - THRESHOLD_K) / (L tau)

    (``tankode.bulk.BulkPhaseChange`` with ``THRESHOLD_K`` and the bulk's ``tau_s``; flash vapour
    leaves the liquid as saturated vapour, so total mass and energy are unchanged). At ``c = 1``
    the liquid relaxes to saturation as fast as the bulk's flash does past its threshold; at
    ``c = 0`` it is the baseline.

    Signature: through a vent or a drain the liquid's temperature follows ``T_sat(p)`` within a
    few hundredths of a kelvin and the pressure levels off sooner than the baseline's, which
    lets the liquid superheat first; nothing changes while the liquid is below saturation.

    It shapes the model's phase change, not the tank's inventory: the assimilation trains it
    with the agent (``AssimilationConfig.boiling``); it is not a diagnosis candidate by default.

    Limits: one share for the whole run (the layer that boils does not thin or thicken); the
    boiling share cools with the bulk (no separate surface temperature).
    """

    id = "saturated_boiling"
    model_form = True
    params = (Param("share", "1", 0.0, 1.0, 0.1),)
    signature = "through a vent or a drain T_l follows T_sat(p) and the pressure levels off sooner"

    _BOILING = BulkPhaseChange(flash_threshold_K=THRESHOLD_K)

    def flash_kg_s(self, m_v, m_l, vapor, liquid, z, T_boil_K):
        return self.param(0, m_l) * self._BOILING.flash_kg_s(m_l, vapor, liquid, T_boil_K=T_boil_K)


__all__ = ["SaturatedBoiling"]
