"""Thermal stratification of the liquid: a warm surface layer that feeds the interface."""

from __future__ import annotations

from .base import Mechanism, Param


class ThermalStratification(Mechanism):
    """The liquid at the interface is dT warmer than the (measured, mass-averaged) bulk.

    Physics: the liquid-side interface flux is ``h_li A_i (T_l + dT - T_sat)`` instead of
    ``h_li A_i (T_l - T_sat)``; the bulk liquid supplies it, so energy is conserved. A warm
    layer (heated from the wall's boundary layer, which rises along the wall) takes the
    subcooling away from the surface: less condensation, more evaporation.

    Signature: pressure higher than modelled, the more so when ``h_li`` is large (sloshing
    stirs the layer into the interface); the bulk liquid temperature lags slightly.

    Limits: the layer's thickness and its own dynamics are not resolved; dT is constant.
    """

    id = "thermal_stratification"
    model_form = True
    params = (Param("dT_K", "K", 0.0, 5.0, 0.1),)
    signature = "pressure above the model, growing when h_li is large"

    def interface_offset_K(self, z):
        return self.param(0)


__all__ = ["ThermalStratification"]
