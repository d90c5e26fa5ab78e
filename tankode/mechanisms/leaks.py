"""Unmetered mass losses: vapour (a leaking valve) and liquid (a leaking drain line)."""

from __future__ import annotations

from .base import Mechanism, Param


class VaporLeak(Mechanism):
    """Vapour lost at ullage conditions at a constant rate (kg/s), beyond the metered vent.

    Physics: an extra ``mdot_v_out``; it carries the ullage enthalpy, so it cools nothing
    but removes mass. Signature: the pressure falls relative to the model at a rate that
    grows with the ullage's smallness; temperatures barely change.
    """

    id = "vapor_leak"
    params = (Param("mdot_kg_s", "kg/s", 0.0, 0.05, 1.0e-4),)
    signature = "pressure falls steadily; temperatures nearly unaffected"

    def adjust_forcing(self, forcing):
        return forcing._replace(mdot_v_out_kg_s=forcing.mdot_v_out_kg_s + self.param(0))


class LiquidLeak(Mechanism):
    """Liquid lost at liquid conditions at a constant rate (kg/s), beyond the metered drain.

    Physics: an extra ``mdot_l_out`` at the liquid's enthalpy. Signature: the level falls
    linearly (at mdot / (rho_l A_i)); the growing ullage lowers the pressure slightly.
    """

    id = "liquid_leak"
    params = (Param("mdot_kg_s", "kg/s", 0.0, 0.5, 1.0e-3),)
    signature = "liquid level falls linearly; slight pressure drop"

    def adjust_forcing(self, forcing):
        return forcing._replace(mdot_l_out_kg_s=forcing.mdot_l_out_kg_s + self.param(0))


__all__ = ["VaporLeak", "LiquidLeak"]
