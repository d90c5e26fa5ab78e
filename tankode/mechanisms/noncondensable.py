"""An inert, non-condensable gas (e.g. helium pressurant) in the ullage."""

from __future__ import annotations

from .base import Mechanism, Param

R_J_PER_MOLK = 8.314462618


class NoncondensableGas(Mechanism):
    """n moles of an ideal inert gas in the ullage, at the ullage temperature.

    Physics: the sensor reads the total pressure ``p_H2 + n R T_v / V_v``; the hydrogen (the
    model's state) is at its partial pressure, which sets the interface saturation (Dalton).
    The liquid bears the total, so its bulk boils (``tankode.bulk``, ``saturated_boiling``)
    past saturation at the total pressure, not at the hydrogen's: a liquid saturated at the
    total pressure under helium evaporates through its surface and does not flash. The run's
    initial pressure is a total, so the initial hydrogen pressure is the reading minus the
    inert partial pressure at (T_v0, V_v0).

    Limits: the inert gas's heat capacity (n c_v, ~12 J/K per mol of He against m_v c_v of
    several kJ/K) and its share of the volume work are neglected (``tests/nodal_sim.py``'s
    4.9 m3 tank with 200 mol, 13 % of its pressure, ends its first 30 minutes 0.06 kPa higher
    without the helium's heat capacity, of an 18 kPa rise), and the liquid's energy and density
    are taken at the hydrogen pressure (they barely depend on the pressure). ``n`` is constant:
    vents remove hydrogen only, where a real vent takes the gas in proportion to its mole
    fraction (the inventory audit measures that share, ``tankode.diagnosis.audit_run``).

    Signature: a pressure offset that grows with T_v and shrinks as the ullage grows; with T_v
    and V_v constant it cannot be told from a sensor bias.
    """

    id = "noncondensable_gas"
    params = (Param("n_mol", "mol", 0.0, 1.0e5, 10.0),)
    signature = "pressure offset proportional to T_v / V_v"

    def pressure_offset_Pa(self, T_v_K, V_v_m3):
        return self.inert_pressure_Pa(T_v_K, V_v_m3)

    def inert_pressure_Pa(self, T_v_K, V_v_m3):
        return self.param(0, T_v_K) * R_J_PER_MOLK * T_v_K / V_v_m3


__all__ = ["NoncondensableGas", "R_J_PER_MOLK"]
