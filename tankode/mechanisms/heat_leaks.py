"""Unmodelled heat leaks into the liquid, the ullage or the wall (W)."""

from __future__ import annotations

from .base import Mechanism, Param

# Heat leaks are inflows (a cryogenic tank's surroundings are warmer); 10 kW bounds any
# leak that would leave a ground or flight tank of a few m^3 unnoticed for an hour.
_Q = Param("Q_W", "W", 0.0, 1.0e4, 100.0)


class HeatLeakLiquid(Mechanism):
    """A constant heat flow Q into the liquid (e.g. a warm pump, a support, a bottom penetration).

    Signature: the liquid warms faster than the wall and the closure explain; more of the
    interface flux evaporates, so the pressure rises (or falls more slowly) over the whole run.
    """

    id = "heat_leak_liquid"
    params = (_Q,)
    signature = "T_l drifts up; pressure rises slowly through evaporation"

    def heat_W(self, s, forcing, fluxes, z):
        return 0.0, self.param(0), 0.0


class HeatLeakVapor(Mechanism):
    """A constant heat flow Q into the ullage gas (e.g. a warm diffuser, a radiating vent line).

    Signature: fast, since the ullage's heat capacity is small: T_v and the pressure rise from
    the start, most strongly when the ullage is small.
    """

    id = "heat_leak_vapor"
    params = (_Q,)
    signature = "T_v and pressure rise from the start"

    def heat_W(self, s, forcing, fluxes, z):
        return self.param(0), 0.0, 0.0


class HeatLeakWall(Mechanism):
    """A constant heat flow Q into the wall beyond the metered ``Q_aw`` (insulation worse than assumed).

    Signature: the wall warms (or cools more slowly); the fluid follows with the wall's time
    constant, so T_w deviates first.
    """

    id = "heat_leak_wall"
    params = (_Q,)
    signature = "T_w drifts up first; T_v, T_l and pressure follow"

    def heat_W(self, s, forcing, fluxes, z):
        return 0.0, 0.0, self.param(0)


__all__ = ["HeatLeakLiquid", "HeatLeakVapor", "HeatLeakWall"]
