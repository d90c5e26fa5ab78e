"""Bulk phase change: a phase pushed past saturation condenses or boils in its volume.

The interface exchange (``tankode.model``) moves mass only through the liquid surface. A phase
driven past saturation in its bulk does not wait for it: a quickly expanding ullage (a drain, a
vent) subcools and forms fog, a quickly depressurised liquid superheats and flashes. Without
this the 0D model carries such states past the ends of the single-phase branches, and a vented
tank's pressure falls on while the data's levels off on the liquid's boiling.

For each phase, beyond a metastable threshold past saturation (``flash_threshold_K`` for the
liquid, ``fog_threshold_K`` for the vapour), mass changes phase in the bulk at the rate that
relaxes the excess with time constant ``tau_s``::

    J_fog   = m_v c_p,v sp(T_sat - T_v - fog_threshold) / (L tau)     (vapour -> liquid)
    J_flash = m_l c_p,l sp(T_l - T_sat - flash_threshold) / (L tau)   (liquid -> vapour)

with ``sp`` a softplus whose width is ``onset_share`` of the threshold (smooth onset, and a phase
at saturation sees ``exp(-1 / onset_share)`` of the width, whatever the threshold) and
``L = h_v,sat - h_l,sat``. Fog leaves the ullage as saturated liquid (``h_l,sat``: its latent
heat stays in the vapour, which warms back towards saturation) and joins the liquid; flash
vapour leaves the liquid as saturated vapour (``h_v,sat``: the liquid gives up the latent heat)
and joins the ullage. Total mass and energy are unchanged by either.

Why the two thresholds differ: a liquid in a tank boils on the wall's and the surface's
nucleation sites at a small superheat (a tenth of a kelvin or two); the lumped liquid stands
for its surface layer too, which flashes first when the ullage is vented. Vapour condenses on
the wall and the interface through the closure's coefficients; fog in the bulk needs a larger
supersaturation, and the threshold keeps the closure, not fog, in charge of an ullage cooled
onto a colder wall by a few tenths of a kelvin.

Limits: one relaxation time for nucleation and growth, no droplet or bubble populations, fog
that joins the liquid at once (no rain-out delay); the thresholds stand for the nucleation
superheat and supersaturation, engineering values, not measured ones. How much of a tank's
liquid boils at saturation instead differs between tanks; the assimilation learns it from the
data (``tankode.mechanisms.SaturatedBoiling``, ``AssimilationConfig.boiling``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor


# Share of the property domain's metastable margin a threshold may take (rates_kg_s).
MARGIN_SHARE = 2.0 / 3.0


@dataclass(frozen=True)
class BulkPhaseChange:
    """Constants of the bulk relaxation (module docstring); ``None`` in ``TankModel`` turns it off."""

    # K of liquid superheat before the liquid flashes in bulk: nucleate boiling on the wall and
    # the vented surface starts at a few tenths of a kelvin; above the scatter of a window's
    # start set from measured p and T_l, so a measured start at saturation does not flash.
    flash_threshold_K: float = 0.2
    # K of vapour subcooling before fog forms in the bulk: a supersaturated vapour keeps its
    # phase longer than a superheated liquid (module docstring), and an ullage cooled onto a
    # colder wall stays the closure's to condense.
    fog_threshold_K: float = 1.0
    # s; relaxation time of the excess: fast against a tank's minutes-scale operations.
    tau_s: float = 10.0
    # softplus width as a share of the threshold: the onset is smooth over a tenth of it, and a
    # phase at saturation sees exp(-10) of the width.
    onset_share: float = 0.1

    def __post_init__(self):
        for name in ("flash_threshold_K", "fog_threshold_K", "tau_s", "onset_share"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"BulkPhaseChange.{name} must be finite and > 0, got {v}")

    def rates_kg_s(self, m_v: Tensor, m_l: Tensor, pv, pl, margin_K=None, T_boil_K=None) -> tuple[Tensor, Tensor]:
        """(J_fog, J_flash) in kg/s, each ``(env,)`` and >= 0, from the phases' masses and properties.

        ``margin_K``: how far past saturation the phases' branches reach (the property domain's
        metastable margin, which narrows towards the critical point): each threshold is capped
        at two thirds of it, so the bulk relaxation starts before a state leaves its branch.
        ``T_boil_K``: the liquid's boiling point ``(env,)``, saturation at the pressure it bears
        (with an inert gas in the ullage, the total; ``pv.T_sat`` by default).
        """
        fog = self._excess(pv.T_sat - pv.T, self.fog_threshold_K, margin_K)
        return (m_v * pv.cp * fog / ((pv.h_vsat - pv.h_lsat) * self.tau_s),
                self.flash_kg_s(m_l, pv, pl, margin_K, T_boil_K))

    def flash_kg_s(self, m_l: Tensor, pv, pl, margin_K=None, T_boil_K=None) -> Tensor:
        """J_flash in kg/s, ``(env,)`` and >= 0: ``rates_kg_s``'s second term alone."""
        # Saturation at the ullage's pressure: the liquid's own p(u, rho) is steep and only its
        # derivatives drive the model (tankode.model, "Volume split").
        flash = self._excess(pl.T - (pv.T_sat if T_boil_K is None else T_boil_K), self.flash_threshold_K, margin_K)
        return m_l * pl.cp * flash / ((pv.h_vsat - pv.h_lsat) * self.tau_s)

    def _excess(self, past_K: Tensor, threshold_K: float, margin_K) -> Tensor:
        """Smooth ``max(past - threshold, 0)`` in K, the threshold capped by the margin."""
        threshold = threshold_K if margin_K is None else torch.clamp(MARGIN_SHARE * margin_K, max=threshold_K)
        width = self.onset_share * threshold
        return width * torch.nn.functional.softplus((past_K - threshold) / width)


__all__ = ["BulkPhaseChange"]
