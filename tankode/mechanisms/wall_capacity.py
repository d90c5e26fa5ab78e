"""A wrong wall heat capacity: the true m_w c_w is (1 + eps) times the nominal one."""

from __future__ import annotations

from .base import Mechanism, Param


class WallHeatCapacityError(Mechanism):
    """The wall's true heat capacity is ``(1 + eps) m_w c_w`` (estimated or mis-specified wall).

    Signature: only while the wall temperature changes: T_w relaxes faster (eps < 0) or more
    slowly (eps > 0) towards the fluid than the model says, and the fluid sees the wall's
    heat release with that time constant. A wall at steady temperature shows nothing.
    """

    id = "wall_heat_capacity_error"
    params = (Param("eps", "1", -0.9, 9.0, 0.1),)
    signature = "T_w transients faster or slower than modelled"

    def wall_capacity_factor(self):
        return 1.0 + self.param(0)


__all__ = ["WallHeatCapacityError"]
