"""Bulk phase change: a phase pushed past saturation condenses or boils in its volume.

The interface exchange (``tankode.model``) moves mass only through the liquid surface. A phase
driven well past saturation in its bulk does not wait for it: a quickly expanding ullage (a
drain, a vent) subcools and forms fog, a quickly depressurised liquid superheats and flashes.
Without this the 0D model carries such states past the ends of the single-phase branches.

For each phase, beyond a metastable ``threshold_K`` past saturation, mass changes phase in the
bulk at the rate that relaxes the excess with time constant ``tau_s``::

    J_fog   = m_v c_p,v sp(T_sat - T_v - threshold) / (L tau)   (vapour -> liquid)
    J_flash = m_l c_p,l sp(T_l - T_sat - threshold) / (L tau)   (liquid -> vapour)

with ``sp`` a softplus of width ``width_K`` (smooth onset) and ``L = h_v,sat - h_l,sat``. Fog
leaves the ullage as saturated liquid (``h_l,sat``: its latent heat stays in the vapour, which
warms back towards saturation) and joins the liquid; flash vapour leaves the liquid as saturated
vapour (``h_v,sat``: the liquid gives up the latent heat) and joins the ullage. Total mass and
energy are unchanged by either.

Limits: one relaxation time for nucleation and growth, no droplet or bubble populations, fog
that joins the liquid at once (no rain-out delay); the threshold stands for the nucleation
superheat or supersaturation, an engineering value, not a measured one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor


# Share of the property domain's metastable margin the threshold may take (rates_kg_s).
MARGIN_SHARE = 2.0 / 3.0


@dataclass(frozen=True)
class BulkPhaseChange:
    """Constants of the bulk relaxation (module docstring); ``None`` in ``TankModel`` turns it off."""

    # K past saturation a phase holds as a metastable state before it changes phase in bulk:
    # about the nucleation superheat of liquid hydrogen, and above the 0.2 K sensor noise.
    threshold_K: float = 1.0
    # s; relaxation time of the excess: fast against a tank's minutes-scale operations.
    tau_s: float = 10.0
    # K; softplus width of the onset, so the right-hand side stays smooth.
    width_K: float = 0.1

    def __post_init__(self):
        for name in ("threshold_K", "tau_s", "width_K"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0) or (name != "threshold_K" and v == 0):
                raise ValueError(f"BulkPhaseChange.{name} must be finite and > 0 (threshold >= 0), got {v}")

    def rates_kg_s(self, m_v: Tensor, m_l: Tensor, pv, pl, margin_K=None) -> tuple[Tensor, Tensor]:
        """(J_fog, J_flash) in kg/s, each ``(env,)`` and >= 0, from the phases' masses and properties.

        ``margin_K``: how far past saturation the phases' branches reach (the property domain's
        metastable margin, which narrows towards the critical point): the threshold is capped at
        two thirds of it, so the bulk relaxation starts before a state leaves its branch, and the
        onset's width shrinks with the threshold, so that a phase at saturation stays untouched
        (the softplus tail there is ``exp(-threshold_K / width_K)`` of the width whatever the cap).
        """
        L = pv.h_vsat - pv.h_lsat
        if margin_K is None:
            threshold, w = self.threshold_K, self.width_K
        else:
            threshold = torch.clamp(MARGIN_SHARE * margin_K, max=self.threshold_K)
            w = self.width_K * threshold / self.threshold_K if self.threshold_K > 0 else self.width_K
        fog = w * torch.nn.functional.softplus((pv.T_sat - pv.T - threshold) / w)
        # Saturation at the ullage's pressure for both: the liquid's own p(u, rho) is steep and
        # only its derivatives drive the model (tankode.model, "Volume split").
        flash = w * torch.nn.functional.softplus((pl.T - pv.T_sat - threshold) / w)
        return m_v * pv.cp * fog / (L * self.tau_s), m_l * pl.cp * flash / (L * self.tau_s)


__all__ = ["BulkPhaseChange"]
