"""Instrument errors: a biased pressure sensor, a biased liquid thermometer and a biased inflow meter."""

from __future__ import annotations

from .base import Mechanism, Param


class PressureSensorBias(Mechanism):
    """The pressure sensor reads p + b (Pa), also at t0 (the run's initial pressure).

    Physics: none changes; the observation operator adds b, and the initial state is built
    from the initial reading minus b. Signature: a constant pressure offset, visible from the
    first samples, with no matching temperature change (a wrong pressure would move T_sat
    and hence the phase change).
    """

    id = "pressure_sensor_bias"
    params = (Param("bias_Pa", "Pa", -1.0e5, 1.0e5, 1.0e3),)
    signature = "constant pressure offset from t0, temperatures consistent with the unbiased pressure"

    def pressure_offset_Pa(self, T_v_K, V_v_m3):
        return self.param(0, T_v_K)


class TemperatureSensorBias(Mechanism):
    """The liquid thermometer reads T_l + b (K), also at t0 (the run's initial liquid temperature).

    Physics: none changes; the observation operator adds b to the liquid's temperature, and the
    initial state is built from the initial reading minus b. A liquid that reads above
    saturation at the initial pressure of a quiescent tank (it would be boiling) is the classic
    sign: the NASA MHTB tests' thermometers read 0.05-0.10 K above para-hydrogen's saturation
    at their start (``experiments/mhtb_rotations.py``). The inventory audit estimates the same
    offset (``tankode.diagnosis.audit``), which names ``temperature_sensor_bias``.

    Signature: a constant liquid temperature offset from t0; a liquid start b away from the
    reading changes the interface's condensation or evaporation at first, hence the pressure.
    """

    id = "temperature_sensor_bias"
    params = (Param("bias_K", "K", -5.0, 5.0, 0.1),)
    signature = "constant liquid temperature offset from t0; the early pressure as if the liquid started b away"

    def liquid_temperature_offset_K(self, T_l_K):
        return self.param(0, T_l_K)


class InflowMeterBias(Mechanism):
    """The true vapour and liquid inflows are (1 + beta) times the metered ones.

    Signature: only while something flows in: the pressure (injection) or the level (fill)
    moves faster or slower than the metered flow explains, and the error stays afterwards.
    """

    id = "inflow_meter_bias"
    params = (Param("beta", "1", -0.5, 1.0, 0.05),)
    signature = "mismatch that appears during injection or fill and persists after"

    def adjust_forcing(self, forcing):
        f = 1.0 + self.param(0)
        return forcing._replace(mdot_v_in_kg_s=forcing.mdot_v_in_kg_s * f, mdot_l_in_kg_s=forcing.mdot_l_in_kg_s * f)


__all__ = ["PressureSensorBias", "TemperatureSensorBias", "InflowMeterBias"]
