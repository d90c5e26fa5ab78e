"""Wall heat capacity: the user's value, or a stated estimate when it is unknown."""

from __future__ import annotations

import math
from dataclasses import dataclass

# NIST cryogenic material properties, aluminium 6061-T6 specific heat, valid 4-300 K:
# log10(c_p) = sum_i a_i (log10 T)^i.
_AL6061_CP = (46.6467, -314.292, 866.662, -1298.3, 1162.27, -637.795, 210.351, -38.3094, 2.96344)
_AL_DENSITY_KG_M3 = 2700.0


def aluminium_cp_J_per_kgK(T_K: float) -> float:
    """Specific heat of aluminium 6061-T6 (NIST fit, 4-300 K)."""
    if not 4.0 <= T_K <= 300.0:
        raise ValueError(f"aluminium c_p fit is valid for 4 K <= T <= 300 K, got T = {T_K} K")
    x = math.log10(T_K)
    return 10.0 ** sum(a * x**i for i, a in enumerate(_AL6061_CP))


@dataclass(frozen=True)
class WallHeatCapacity:
    """The wall's lumped heat capacity m_w c_w and where it came from.

    Attributes:
        value_J_per_K: m_w c_w (J/K).
        assumed: True when the run did not give it and this is tankode's estimate.
        note: a sentence for reports saying how the value was obtained.
    """

    value_J_per_K: float
    assumed: bool
    note: str

    def __post_init__(self):
        if not (math.isfinite(self.value_J_per_K) and self.value_J_per_K > 0):
            raise ValueError(f"wall heat capacity must be a positive finite J/K value, got {self.value_J_per_K}")


# An aluminium shell of this thickness is a typical flight/ground LH2 tank wall (MHTB: Al 5083,
# about 12.7 mm); the estimate is only a starting point that diagnosis can correct (factor on m_w c_w).
ASSUMED_WALL_THICKNESS_M = 0.0127


def resolve_wall_heat_capacity(given_J_per_K: float | None, wall_area_m2: float, T_w_K: float) -> WallHeatCapacity:
    """Return the given m_w c_w, or estimate it for an aluminium shell when unknown.

    Args:
        given_J_per_K: the run's ``tank.wall_heat_capacity_J_per_K`` or None.
        wall_area_m2: total inner wall area of the tank (m^2).
        T_w_K: initial wall temperature (K), where the strongly T-dependent c_p is taken.

    Limits: the estimate freezes c_p at the initial wall temperature (c_p of aluminium grows
    roughly as T^3 at 20 K, so a wall warming by several kelvin has a larger true capacity).
    """
    if given_J_per_K is not None:
        return WallHeatCapacity(float(given_J_per_K), False, "given by the run")
    mass = wall_area_m2 * ASSUMED_WALL_THICKNESS_M * _AL_DENSITY_KG_M3
    cp = aluminium_cp_J_per_kgK(T_w_K)
    value = mass * cp
    note = (
        f"unknown in the run; assumed {value:.4g} J/K = aluminium shell of {wall_area_m2:.3g} m^2 x "
        f"{ASSUMED_WALL_THICKNESS_M * 1e3:.1f} mm x {_AL_DENSITY_KG_M3:.0f} kg/m^3 ({mass:.4g} kg) "
        f"x c_p(Al 6061, {T_w_K:.2f} K) = {cp:.3g} J/(kg K)"
    )
    return WallHeatCapacity(value, True, note)


__all__ = ["WallHeatCapacity", "resolve_wall_heat_capacity", "aluminium_cp_J_per_kgK", "ASSUMED_WALL_THICKNESS_M"]
