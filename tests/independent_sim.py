"""Independent cryogenic-tank simulator for blind tests of tankode's diagnosis.

This module simulates liquid-hydrogen tanks and writes the runs in the interchange format
(``shared/data-format.md``), optionally with one hidden *mechanism* (a heat leak, a mass
leak, a sensor bias, ...). It deliberately shares **nothing** with tankode: it does not
import it, and it has its own formulation, numerics, property calls, heat-transfer
correlations, geometry and writer, so that a diagnosis that works on these runs is not
merely recognising its own model.

Formulation (0D, three volumes: ullage vapour, liquid, wall)
------------------------------------------------------------
State ``y = (p_g, T_v, T_l, T_w, m_v, m_l, E_ext, M_ext)``:

* ``p_g`` is the partial pressure of hydrogen in the ullage; with no inert gas it is the
  tank pressure ``p``. ``T_v``, ``T_l``, ``T_w`` are the bulk vapour, liquid and wall
  temperatures, ``m_v``, ``m_l`` the hydrogen masses. ``E_ext`` and ``M_ext`` are
  quadratures of what crossed the boundary (enthalpy flows + heat, and mass); they do not
  feed back and exist for the conservation checks.
* Each phase is a real fluid (CoolProp HEOS ``ParaHydrogen``) evaluated at ``(p, T)`` with
  its phase *imposed*, so slightly subcooled vapour or superheated liquid are metastable
  single-phase states rather than two-phase mixtures.
* Energy balances in enthalpy form: for a phase of mass ``m`` and volume ``V``,
  ``m c_p dT/dt = A + V T beta dp/dt`` where ``A = sum m_in (h_in - h) + Q`` (outflows at
  the phase's own enthalpy drop out). The pressure rate follows from the rigid-tank
  condition ``dV_v/dt + dV_l/dt = 0`` with ``dV/dt = mdot/rho + V (beta dT/dt - kappa_T
  dp/dt)``. These relations, plus the inert-gas relations, form a 6x6 linear system for
  ``(dp_g, dT_v, dT_l, dp, dV_v, dV_l)/dt`` solved at every right-hand-side call. The
  volume constraint is not a state; its (tiny) drift is removed by a Baumgarte term with
  time constant ``_TAU_VOLUME_S``.
* Interface at ``T_sat(p_g)``; ``J = (Q_vi + Q_li) / (h_v,sat - h_l,sat)`` evaporates
  (``J < 0`` condenses); evaporated mass leaves the liquid at ``h_l,sat`` and enters the
  vapour at ``h_v,sat`` (so the interface stores no energy).
* Wall: one lumped node, ``C_w dT_w/dt = Q_aw - Q_wv - Q_wl`` (+ a wall heat leak).
* Integration: ``scipy.integrate.solve_ivp`` (LSODA, rtol 1e-8), restarted at every
  change of the inputs, ``max_step`` bounded; a failure raises :class:`SimulationError`.

Heat-transfer correlations (this module's own choices)
------------------------------------------------------
Properties for the correlations are taken from CoolProp at the film temperature.

* wall-vapour and wall-liquid: turbulent natural convection on vertical surfaces
  (McAdams), ``Nu_L = 0.13 Ra_L^(1/3)``, i.e. ``h = 0.13 k (g beta |dT| / (nu alpha))^(1/3)``
  (independent of the height);
* liquid side of the interface: ``Nu_L = 0.15 Ra_L^(1/3)`` (horizontal surface), at the
  film temperature between the liquid and the interface;
* vapour side of the interface: ``Nu_L = 0.27 Ra_L^(1/4)`` with ``L = sqrt(A_i)``
  (horizontal surface, stable side: weak, a few W/m2K);
* a small constant floor is added to each coefficient, and ``|dT|`` is regularised as
  ``sqrt(dT^2 + (0.01 K)^2)`` so that the fluxes are smooth through ``dT = 0``;
* sloshing (amplitude ``A0``, frequency ``f``, velocity scale ``v_s = 2 pi f A0``)
  multiplies the interface coefficients by ``1 + c (v_s / 0.01 m/s)^0.8`` with ``c = 1.2``
  (liquid side) and ``c = 0.5`` (vapour side); the wall coefficients are unchanged.

Simplifications (deliberate)
----------------------------
* One wall node (no wet/dry wall split, no conduction along the wall); no nucleate boiling
  on the wall (natural convection only, even when ``T_w > T_sat``).
* Bulk phases are well mixed (no stratification except the optional mechanism); the
  sloshing only enhances the interface coefficients: no mechanical energy input, no level
  disturbance.
* Hydrostatic pressure differences are neglected (one pressure for the whole tank).
* The inert gas (``noncondensable_gas``) is an ideal monatomic gas (helium, ``c_v = 3/2 R``)
  at ``T_v`` that occupies the whole ullage; it does not dissolve, and the vent removes only
  hydrogen (the inert amount stays constant).

Hidden mechanisms (one parameter each, 0 = absent)
--------------------------------------------------
See :data:`MECHANISMS`. ``pressure_sensor_bias`` and ``noncondensable_gas`` also shift the
initial pressure written in the metadata (the metadata holds what the sensors read).

Output convention
-----------------
The metadata ``initial`` block is the noise-free sensor reading at ``t0 = 0``; the nominal
(metered) wall heat capacity is written; the CSV holds asynchronous noisy samples (pressure
every 5 s; T_v, T_l, T_w every 15 s at phase offsets 1, 1.5 and 2 s; level every 10 s at 3 s;
a fraction of samples dropped at random) and the metered, piecewise-constant inputs.

Run ``python tests/independent_sim.py`` to re-measure the signature table behind
:data:`SUGGESTED_MAGNITUDE` (noise-free runs with and without each mechanism).
"""

from __future__ import annotations

import csv
import json
import math
import pathlib
import time
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import CoolProp as CP
import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

__all__ = [
    "SCENARIOS",
    "SUGGESTED_MAGNITUDE",
    "SCENARIO_FOR",
    "DEFAULT_NOISE",
    "MECHANISMS",
    "Mechanism",
    "SimulationError",
    "TankModel",
    "Trajectory",
    "make_geometry",
    "simulate_truth",
    "simulate_run",
    "signature",
    "signature_diffs",
    "suggested_magnitude",
]

FLUID = "ParaHydrogen"
R_GAS = 8.314462618  # J/(mol K)
CV_INERT = 1.5 * R_GAS  # J/(mol K), monatomic ideal gas (helium)
G = 9.80665  # m/s2

_RTOL = 1e-8
_MAX_STEP_S = 20.0
_TAU_VOLUME_S = 30.0  # Baumgarte relaxation time of the volume-constraint drift

# Sloshing enhancement of the interface coefficients (this module's own design).
_SLOSH_V_REF = 0.01  # m/s
_SLOSH_C_LIQ = 1.2
_SLOSH_C_VAP = 0.5
_SLOSH_EXP = 0.8

# Floors added to the heat-transfer coefficients [W/(m2 K)] and the |dT| regularisation [K].
_H_FLOOR = {"wv": 1.0, "wl": 10.0, "li": 20.0, "vi": 0.5}
_DT_EPS = 0.01

MECHANISMS: dict[str, str] = {
    "heat_leak_liquid": "Q [W] added to the liquid energy balance",
    "heat_leak_vapor": "Q [W] added to the ullage energy balance",
    "heat_leak_wall": "Q [W] added to the wall energy balance",
    "vapor_leak": "unmetered vapour loss [kg/s] at ullage enthalpy",
    "liquid_leak": "unmetered liquid loss [kg/s] at liquid enthalpy",
    "pressure_sensor_bias": "b [Pa]: the pressure sensor reads p + b",
    "wall_heat_capacity_error": "eps: the true wall heat capacity is (1 + eps) x the metadata value",
    "noncondensable_gas": "n [mol] of helium in the ullage; p_sensor = p_H2 + n R T_v / V_v",
    "thermal_stratification": "dT [K]: warm liquid surface layer, Q_li = h_li A_i (T_l + dT - T_sat)",
    "inflow_meter_bias": "beta: the true inflows are (1 + beta) x the metered values",
}

INPUT_COLUMNS: tuple[str, ...] = (
    "mdot_v_in_kg_s",
    "T_v_in_K",
    "p_v_in_Pa",
    "mdot_v_out_kg_s",
    "mdot_l_in_kg_s",
    "T_l_in_K",
    "mdot_l_out_kg_s",
    "slosh_amplitude_m",
    "slosh_frequency_Hz",
    "Q_aw_W",
)
OBS_COLUMNS: tuple[str, ...] = ("p_v_Pa", "T_v_K", "T_l_K", "T_w_K", "H_l_m")
NOISE_KEYS: tuple[str, ...] = ("p_v", "T_v", "T_l", "T_w", "H_l")
DEFAULT_NOISE: dict[str, float] = {"p_v": 2000.0, "T_v": 0.2, "T_l": 0.2, "T_w": 0.2, "H_l": 0.0005}

# Sampling: channel -> (period [s], phase offset [s]).
SAMPLING: dict[str, tuple[float, float]] = {
    "p_v_Pa": (5.0, 0.0),
    "T_v_K": (15.0, 1.0),
    "T_l_K": (15.0, 1.5),
    "T_w_K": (15.0, 2.0),
    "H_l_m": (10.0, 3.0),
}
DEFAULT_DROPOUT = 0.01


class SimulationError(RuntimeError):
    """The integration failed (or left the range where the model is valid)."""


# =============================================================================== geometry
class _Geometry:
    """Closed-form level/volume/area relations of one tank shape (metres)."""

    volume: float
    height: float  # maximum liquid level
    wall_area: float

    def liquid_volume(self, h: float) -> float:
        raise NotImplementedError

    def interface_area(self, h: float) -> float:
        raise NotImplementedError

    def wetted_area(self, h: float) -> float:
        raise NotImplementedError

    def level(self, v_l: float) -> float:
        """Liquid level [m] for a liquid volume [m3] (root of the monotone V_l(h))."""
        v_l = min(max(v_l, 0.0), self.volume)
        if v_l <= 0.0:
            return 0.0
        if v_l >= self.volume:
            return self.height
        return float(brentq(lambda h: self.liquid_volume(h) - v_l, 0.0, self.height, xtol=1e-13, rtol=1e-15))


class _Sphere(_Geometry):
    def __init__(self, radius_m: float):
        self.r = float(radius_m)
        self.volume = 4.0 / 3.0 * math.pi * self.r**3
        self.height = 2.0 * self.r
        self.wall_area = 4.0 * math.pi * self.r**2

    def liquid_volume(self, h: float) -> float:
        return math.pi * h * h * (3.0 * self.r - h) / 3.0

    def interface_area(self, h: float) -> float:
        return math.pi * h * (2.0 * self.r - h)

    def wetted_area(self, h: float) -> float:
        return 2.0 * math.pi * self.r * h


class _HorizontalCylinder(_Geometry):
    """Horizontal axis, flat ends: the liquid cross-section is a circular segment."""

    def __init__(self, radius_m: float, cylinder_length_m: float):
        self.r = float(radius_m)
        self.length = float(cylinder_length_m)
        self.volume = math.pi * self.r**2 * self.length
        self.height = 2.0 * self.r
        self.wall_area = 2.0 * math.pi * self.r * self.length + 2.0 * math.pi * self.r**2

    def _segment(self, h: float) -> tuple[float, float]:
        """(segment area, half angle) of the wetted circular segment of depth h."""
        c = min(max((self.r - h) / self.r, -1.0), 1.0)
        theta = math.acos(c)
        return self.r**2 * (theta - c * math.sqrt(max(1.0 - c * c, 0.0))), theta

    def liquid_volume(self, h: float) -> float:
        return self._segment(h)[0] * self.length

    def interface_area(self, h: float) -> float:
        return 2.0 * math.sqrt(max(h * (2.0 * self.r - h), 0.0)) * self.length

    def wetted_area(self, h: float) -> float:
        seg, theta = self._segment(h)
        return 2.0 * self.r * theta * self.length + 2.0 * seg


class _VerticalCylinder(_Geometry):
    """Vertical axis, flat ends."""

    def __init__(self, radius_m: float, height_m: float):
        self.r = float(radius_m)
        self.height = float(height_m)
        self.base = math.pi * self.r**2
        self.volume = self.base * self.height
        self.wall_area = 2.0 * math.pi * self.r * self.height + 2.0 * self.base

    def liquid_volume(self, h: float) -> float:
        return self.base * h

    def interface_area(self, h: float) -> float:
        return self.base

    def wetted_area(self, h: float) -> float:
        return self.base + 2.0 * math.pi * self.r * h

    def level(self, v_l: float) -> float:
        return min(max(v_l, 0.0), self.volume) / self.base


def make_geometry(tank: Mapping[str, Any]) -> _Geometry:
    """Geometry from a tank description (``shape`` and its dimensions, as in the format)."""
    shape = tank["shape"]
    if shape == "sphere":
        return _Sphere(tank["radius_m"])
    if shape == "horizontal_cylinder":
        return _HorizontalCylinder(tank["radius_m"], tank["cylinder_length_m"])
    if shape == "vertical_cylinder":
        return _VerticalCylinder(tank["radius_m"], tank["height_m"])
    raise ValueError(f"unsupported tank shape {shape!r} (sphere, horizontal_cylinder, vertical_cylinder)")


# =============================================================================== properties
@dataclass
class _Phase:
    rho: float
    h: float
    cp: float
    beta: float  # isobaric expansion coefficient [1/K]
    kappa: float  # isothermal compressibility [1/Pa]


class _Props:
    """CoolProp HEOS states, one per role, so that each keeps its imposed phase and warm start."""

    def __init__(self, fluid: str = FLUID):
        self.gas = CP.AbstractState("HEOS", fluid)
        self.gas.specify_phase(CP.iphase_gas)
        self.liq = CP.AbstractState("HEOS", fluid)
        self.liq.specify_phase(CP.iphase_liquid)
        self.gas_film = CP.AbstractState("HEOS", fluid)
        self.gas_film.specify_phase(CP.iphase_gas)
        self.liq_film = CP.AbstractState("HEOS", fluid)
        self.liq_film.specify_phase(CP.iphase_liquid)
        self.aux = CP.AbstractState("HEOS", fluid)  # saturation and unconstrained flashes
        self.molar_mass = self.aux.molar_mass()

    @staticmethod
    def _phase(st: Any, p: float, T: float) -> _Phase:
        st.update(CP.PT_INPUTS, p, T)
        return _Phase(st.rhomass(), st.hmass(), st.cpmass(), st.isobaric_expansion_coefficient(),
                      st.isothermal_compressibility())

    def vapour(self, p: float, T: float) -> _Phase:
        return self._phase(self.gas, p, T)

    def liquid(self, p: float, T: float) -> _Phase:
        return self._phase(self.liq, p, T)

    def liquid_h(self, p: float, T: float) -> float:
        self.liq_film.update(CP.PT_INPUTS, p, T)
        return self.liq_film.hmass()

    def saturation(self, p: float) -> tuple[float, float, float]:
        """(T_sat, h_l,sat, h_v,sat) at pressure p."""
        self.aux.update(CP.PQ_INPUTS, p, 0.0)
        return (self.aux.T(), self.aux.saturated_liquid_keyed_output(CP.iHmass),
                self.aux.saturated_vapor_keyed_output(CP.iHmass))

    def saturation_T(self, T: float) -> float:
        self.aux.update(CP.QT_INPUTS, 0.0, T)
        return self.aux.p()

    def gas_h(self, p: float, T: float) -> float:
        """Enthalpy of the injected gas (unconstrained flash: must be a vapour state)."""
        self.aux.update(CP.PT_INPUTS, p, T)
        return self.aux.hmass()

    @staticmethod
    def _convection_group(st: Any, p: float, T: float) -> tuple[float, float]:
        """(k, g |beta| / (nu alpha)) at (p, T): the natural-convection property group."""
        st.update(CP.PT_INPUTS, p, T)
        rho, mu, k, cp = st.rhomass(), st.viscosity(), st.conductivity(), st.cpmass()
        beta = abs(st.isobaric_expansion_coefficient())
        nu = mu / rho
        alpha = k / (rho * cp)
        return k, G * beta / (nu * alpha)

    def gas_group(self, p: float, T: float) -> tuple[float, float]:
        return self._convection_group(self.gas_film, p, T)

    def liquid_group(self, p: float, T: float) -> tuple[float, float]:
        return self._convection_group(self.liq_film, p, T)


def _soft_abs(x: float) -> float:
    return math.sqrt(x * x + _DT_EPS * _DT_EPS)


def _soft_min(x: float, cap: float, width: float = 0.05) -> float:
    """Smooth min(x, cap)."""
    z = (x - cap) / width
    return cap - width * (math.log1p(math.exp(-z)) if z > 0 else -z + math.log1p(math.exp(z)))


def _soft_max(x: float, floor: float, width: float = 0.05) -> float:
    return -_soft_min(-x, -floor, width)


def slosh_factor(amplitude_m: float, frequency_hz: float, c: float) -> float:
    """Sloshing enhancement ``1 + c (2 pi f A0 / v_ref)^0.8`` of an interface coefficient."""
    v = 2.0 * math.pi * frequency_hz * amplitude_m
    return 1.0 + c * (v / _SLOSH_V_REF) ** _SLOSH_EXP if v > 0 else 1.0


# =============================================================================== model
@dataclass
class Mechanism:
    """Hidden-mechanism parameters (all 0 = nominal tank)."""

    heat_leak_liquid: float = 0.0
    heat_leak_vapor: float = 0.0
    heat_leak_wall: float = 0.0
    vapor_leak: float = 0.0
    liquid_leak: float = 0.0
    pressure_sensor_bias: float = 0.0
    wall_heat_capacity_error: float = 0.0
    noncondensable_gas: float = 0.0
    thermal_stratification: float = 0.0
    inflow_meter_bias: float = 0.0

    @classmethod
    def one(cls, mechanism: str | None, value: float) -> "Mechanism":
        if mechanism is None or mechanism == "none":
            return cls()
        if mechanism not in MECHANISMS:
            raise ValueError(f"unknown mechanism {mechanism!r}; known: {', '.join(MECHANISMS)}")
        return cls(**{mechanism: float(value)})


@dataclass
class _Inputs:
    """One constant segment of the metered inputs."""

    values: dict[str, float]

    def __getitem__(self, name: str) -> float:
        return self.values.get(name, 0.0)


@dataclass
class Diagnostics:
    """Derived quantities of one state (for outputs and checks)."""

    p: float  # total (liquid) pressure [Pa]
    p_g: float  # hydrogen partial pressure [Pa]
    T_sat: float
    V_v: float
    V_l: float
    level: float
    A_i: float
    A_wl: float
    A_wv: float
    h_wv: float
    h_wl: float
    h_vi: float
    h_li: float
    Q_wv: float
    Q_wl: float
    Q_vi: float
    Q_li: float
    J: float
    energy: float  # total energy of vapour + inert gas + liquid + wall [J]
    mass: float  # hydrogen mass [kg]


N_STATE = 8
_IDX = dict(p_g=0, T_v=1, T_l=2, T_w=3, m_v=4, m_l=5, E_ext=6, M_ext=7)


class TankModel:
    """Right-hand side of the three-volume model for one tank and mechanism."""

    def __init__(self, tank: Mapping[str, Any], mech: Mechanism, props: _Props | None = None):
        self.geom = make_geometry(tank)
        self.mech = mech
        self.props = props or _Props()
        c_nominal = float(tank["wall_heat_capacity_J_per_K"])
        self.c_wall = (1.0 + mech.wall_heat_capacity_error) * c_nominal
        self.n_inert = mech.noncondensable_gas
        self.inputs = _Inputs({})
        self._h_v_in = 0.0
        self.n_rhs = 0

    # ------------------------------------------------------------------ inputs
    def set_inputs(self, values: Mapping[str, float]) -> None:
        self.inputs = _Inputs(dict(values))
        if self.inputs["mdot_v_in_kg_s"] > 0:
            self._h_v_in = self.props.gas_h(self.inputs["p_v_in_Pa"], self.inputs["T_v_in_K"])
        else:
            self._h_v_in = 0.0

    # ------------------------------------------------------------------ initial state
    def initial_state(self, p_h2: float, T_v: float, T_l: float, T_w: float, fill_ratio: float) -> np.ndarray:
        """State at t0 from the hydrogen pressure, temperatures and liquid volume fraction."""
        V = self.geom.volume
        V_l = fill_ratio * V
        V_v = V - V_l
        vap = self.props.vapour(p_h2, T_v)
        p = p_h2 + self.n_inert * R_GAS * T_v / V_v
        liq = self.props.liquid(p, T_l)
        y = np.zeros(N_STATE)
        y[:6] = (p_h2, T_v, T_l, T_w, vap.rho * V_v, liq.rho * V_l)
        return y

    # ------------------------------------------------------------------ closures
    def _coefficients(self, p: float, p_g: float, T_v: float, T_l: float, T_w: float, T_s: float,
                      T_surf_l: float, A_i: float) -> tuple[float, float, float, float]:
        """(h_wv, h_wl, h_vi, h_li) [W/(m2 K)]."""
        pr = self.props
        # Wall - vapour: vertical-surface turbulent natural convection (McAdams).
        T_f = _soft_max(0.5 * (T_w + T_v), T_s + 0.2)
        k, grp = pr.gas_group(p_g, T_f)
        h_wv = 0.13 * k * (grp * _soft_abs(T_w - T_v)) ** (1.0 / 3.0) + _H_FLOOR["wv"]
        # Wall - liquid: same correlation (film kept below the metastable limit).
        T_f = _soft_min(0.5 * (T_w + T_l), T_s + 1.0)
        k, grp = pr.liquid_group(p, T_f)
        h_wl = 0.13 * k * (grp * _soft_abs(T_w - T_l)) ** (1.0 / 3.0) + _H_FLOOR["wl"]
        # Liquid side of the interface: horizontal surface, Nu = 0.15 Ra^(1/3).
        T_f = _soft_min(0.5 * (T_surf_l + T_s), T_s + 1.0)
        k, grp = pr.liquid_group(p, T_f)
        h_li = 0.15 * k * (grp * _soft_abs(T_surf_l - T_s)) ** (1.0 / 3.0)
        # Vapour side of the interface: Nu = 0.27 Ra^(1/4), L = sqrt(A_i).
        T_f = _soft_max(0.5 * (T_v + T_s), T_s + 0.2)
        k, grp = pr.gas_group(p_g, T_f)
        L = max(math.sqrt(A_i), 0.05)
        h_vi = 0.27 * k * (grp * _soft_abs(T_v - T_s) / L) ** 0.25
        A0, f = self.inputs["slosh_amplitude_m"], self.inputs["slosh_frequency_Hz"]
        h_li = h_li * slosh_factor(A0, f, _SLOSH_C_LIQ) + _H_FLOOR["li"]
        h_vi = h_vi * slosh_factor(A0, f, _SLOSH_C_VAP) + _H_FLOOR["vi"]
        return h_wv, h_wl, h_vi, h_li

    # ------------------------------------------------------------------ core
    def _evaluate(self, y: np.ndarray) -> tuple[np.ndarray, Diagnostics]:
        p_g, T_v, T_l, T_w, m_v, m_l = (float(v) for v in y[:6])
        if not (p_g > 0 and m_v > 0 and m_l > 0 and T_v > 0 and T_l > 0):
            raise SimulationError(f"state left the physical range: p_g={p_g}, m_v={m_v}, m_l={m_l}, T_v={T_v}, T_l={T_l}")
        mech, inp, pr, geom = self.mech, self.inputs, self.props, self.geom
        vap = pr.vapour(p_g, T_v)
        V_v = m_v / vap.rho
        p_in = self.n_inert * R_GAS * T_v / V_v  # inert partial pressure
        p = p_g + p_in
        liq = pr.liquid(p, T_l)
        V_l = m_l / liq.rho
        level = geom.level(V_l)
        A_i = geom.interface_area(level)
        A_wl = geom.wetted_area(level)
        A_wv = geom.wall_area - A_wl
        T_s, h_ls, h_vs = pr.saturation(p_g)

        T_surf_l = T_l + mech.thermal_stratification
        h_wv, h_wl, h_vi, h_li = self._coefficients(p, p_g, T_v, T_l, T_w, T_s, T_surf_l, A_i)
        Q_wv = h_wv * A_wv * (T_w - T_v)
        Q_wl = h_wl * A_wl * (T_w - T_l)
        Q_vi = h_vi * A_i * (T_v - T_s)
        Q_li = h_li * A_i * (T_surf_l - T_s)
        J = (Q_vi + Q_li) / (h_vs - h_ls)

        scale_in = 1.0 + mech.inflow_meter_bias
        mv_in = scale_in * inp["mdot_v_in_kg_s"]
        ml_in = scale_in * inp["mdot_l_in_kg_s"]
        mv_out = inp["mdot_v_out_kg_s"] + mech.vapor_leak
        ml_out = inp["mdot_l_out_kg_s"] + mech.liquid_leak
        h_l_in = pr.liquid_h(p, inp["T_l_in_K"]) if ml_in > 0 else 0.0

        dm_v = mv_in - mv_out + J
        dm_l = ml_in - ml_out - J
        A_v = mv_in * (self._h_v_in - vap.h) + J * (h_vs - vap.h) + Q_wv - Q_vi + mech.heat_leak_vapor
        A_l = ml_in * (h_l_in - liq.h) - J * (h_ls - liq.h) + Q_wl - Q_li + mech.heat_leak_liquid
        dT_w = (inp["Q_aw_W"] + mech.heat_leak_wall - Q_wv - Q_wl) / self.c_wall

        # Linear system for x = (dp_g, dT_v, dT_l, dp, dV_v, dV_l).
        n_cv = self.n_inert * CV_INERT
        M = np.zeros((6, 6))
        b = np.zeros(6)
        # ullage energy (hydrogen + inert gas; work done at the total pressure)
        M[0, 0] = -V_v * T_v * vap.beta
        M[0, 1] = m_v * vap.cp + n_cv
        M[0, 4] = p_in
        b[0] = A_v
        # ullage volume
        M[1, 0] = V_v * vap.kappa
        M[1, 1] = -V_v * vap.beta
        M[1, 4] = 1.0
        b[1] = dm_v / vap.rho
        # total pressure = hydrogen + inert (ideal gas at T_v in V_v)
        M[2, 0] = -1.0
        M[2, 1] = -p_in / T_v
        M[2, 3] = 1.0
        M[2, 4] = p_in / V_v
        # liquid energy
        M[3, 2] = m_l * liq.cp
        M[3, 3] = -V_l * T_l * liq.beta
        b[3] = A_l
        # liquid volume
        M[4, 2] = -V_l * liq.beta
        M[4, 3] = V_l * liq.kappa
        M[4, 5] = 1.0
        b[4] = dm_l / liq.rho
        # rigid tank (with drift relaxation)
        M[5, 4] = 1.0
        M[5, 5] = 1.0
        b[5] = -(V_v + V_l - geom.volume) / _TAU_VOLUME_S
        # column scaling keeps the pivoting well posed (pressures ~1e5, volumes ~1).
        scale = np.array([1e4, 1.0, 1.0, 1e4, 1.0, 1.0])
        x = np.linalg.solve(M * scale, b) * scale

        dy = np.empty(N_STATE)
        dy[0] = x[0]
        dy[1] = x[1]
        dy[2] = x[2]
        dy[3] = dT_w
        dy[4] = dm_v
        dy[5] = dm_l
        dy[6] = (mv_in * self._h_v_in + ml_in * h_l_in - mv_out * vap.h - ml_out * liq.h
                 + inp["Q_aw_W"] + mech.heat_leak_wall + mech.heat_leak_vapor + mech.heat_leak_liquid)
        dy[7] = mv_in + ml_in - mv_out - ml_out

        energy = (m_v * (vap.h - p_g / vap.rho) + n_cv * T_v + m_l * (liq.h - p / liq.rho)
                  + self.c_wall * T_w)
        diag = Diagnostics(p=p, p_g=p_g, T_sat=T_s, V_v=V_v, V_l=V_l, level=level, A_i=A_i, A_wl=A_wl, A_wv=A_wv,
                           h_wv=h_wv, h_wl=h_wl, h_vi=h_vi, h_li=h_li, Q_wv=Q_wv, Q_wl=Q_wl, Q_vi=Q_vi, Q_li=Q_li,
                           J=J, energy=energy, mass=m_v + m_l)
        return dy, diag

    def rhs(self, t: float, y: np.ndarray) -> np.ndarray:
        self.n_rhs += 1
        return self._evaluate(y)[0]

    def diagnostics(self, y: np.ndarray) -> Diagnostics:
        return self._evaluate(y)[1]


# =============================================================================== scenarios
# Each scenario: tank (with the NOMINAL wall heat capacity), initial hydrogen state, duration
# and the metered schedule as steps (t, {input: value}) that set the named inputs from t on and
# keep the others (every input is 0 until set).
SCENARIOS: dict[str, dict[str, Any]] = {
    "sphere_vent": {
        "description": "sphere R=1.0 m, 50 % full at 2 bar; ambient heat 350 W self-pressurises, "
                       "a 10-minute vent, then a quiet period with a lower heat load",
        "tank": {"shape": "sphere", "radius_m": 1.0, "wall_heat_capacity_J_per_K": 4.0e5},
        "initial": {"p_Pa": 2.0e5, "T_v_K": 25.5, "T_l_K": 22.3, "T_w_K": 24.5, "fill_ratio": 0.5},
        "duration_s": 3600.0,
        "steps": [
            (0.0, {"Q_aw_W": 350.0}),
            (900.0, {"mdot_v_out_kg_s": 1.0e-3}),
            (1500.0, {"mdot_v_out_kg_s": 0.0}),
            (2400.0, {"Q_aw_W": 150.0}),
        ],
    },
    "hcyl_drain_fill": {
        "description": "horizontal cylinder R=0.8 m, L=3 m, 70 % full at 3 bar; a liquid drain, a "
                       "refill with slightly colder liquid, then sloshing",
        "tank": {"shape": "horizontal_cylinder", "radius_m": 0.8, "cylinder_length_m": 3.0,
                 "wall_heat_capacity_J_per_K": 1.2e6},
        "initial": {"p_Pa": 3.0e5, "T_v_K": 27.5, "T_l_K": 24.0, "T_w_K": 26.0, "fill_ratio": 0.7},
        "duration_s": 3600.0,
        "steps": [
            (0.0, {"Q_aw_W": 300.0}),
            (300.0, {"mdot_l_out_kg_s": 0.08}),
            (1200.0, {"mdot_l_out_kg_s": 0.0}),
            (1500.0, {"mdot_l_in_kg_s": 0.08, "T_l_in_K": 23.0}),
            (2400.0, {"mdot_l_in_kg_s": 0.0}),
            (2700.0, {"slosh_amplitude_m": 0.008, "slosh_frequency_Hz": 0.6}),
        ],
    },
    "vcyl_press_hold_vent": {
        "description": "vertical cylinder R=0.7 m, H=2.5 m, 40 % full at 1.6 bar; pressurisation "
                       "with warm (50 K) hydrogen gas, a hold, a vent, a final hold",
        "tank": {"shape": "vertical_cylinder", "radius_m": 0.7, "height_m": 2.5,
                 "wall_heat_capacity_J_per_K": 8.0e5},
        "initial": {"p_Pa": 1.6e5, "T_v_K": 24.5, "T_l_K": 21.4, "T_w_K": 23.5, "fill_ratio": 0.4},
        "duration_s": 3600.0,
        "steps": [
            (0.0, {"Q_aw_W": 150.0}),
            (120.0, {"mdot_v_in_kg_s": 2.0e-3, "T_v_in_K": 50.0, "p_v_in_Pa": 6.0e5}),
            (900.0, {"mdot_v_in_kg_s": 0.0}),
            (2400.0, {"mdot_v_out_kg_s": 1.5e-3}),
            (3000.0, {"mdot_v_out_kg_s": 0.0}),
        ],
    },
    "small_selfpress": {
        "description": "small vertical cylinder R=0.5 m, H=1.3 m (~1 m3), 60 % full at 1.2 bar, "
                       "self-pressurising under a 250 W heat load (hold only)",
        "tank": {"shape": "vertical_cylinder", "radius_m": 0.5, "height_m": 1.3,
                 "wall_heat_capacity_J_per_K": 1.5e5},
        "initial": {"p_Pa": 1.2e5, "T_v_K": 23.0, "T_l_K": 20.5, "T_w_K": 22.5, "fill_ratio": 0.6},
        "duration_s": 3600.0,
        "steps": [(0.0, {"Q_aw_W": 250.0})],
    },
}


def _expand_steps(steps: Sequence[tuple[float, Mapping[str, float]]], duration: float
                  ) -> list[tuple[float, float, dict[str, float]]]:
    """Steps -> [(t_start, t_end, full input dict)] over [0, duration]."""
    current = {name: 0.0 for name in INPUT_COLUMNS}
    out: list[tuple[float, float, dict[str, float]]] = []
    times = [float(t) for t, _ in steps]
    if times[0] != 0.0 or any(b <= a for a, b in zip(times, times[1:])) or times[-1] >= duration:
        raise ValueError(f"step times must start at 0, increase strictly and stay below {duration}: {times}")
    for k, (t, change) in enumerate(steps):
        for name, v in change.items():
            if name not in current:
                raise ValueError(f"unknown input {name!r}")
            current[name] = float(v)
        t_end = times[k + 1] if k + 1 < len(times) else duration
        out.append((float(t), t_end, dict(current)))
    return out


def _resolve(scenario: str | Mapping[str, Any]) -> dict[str, Any]:
    if isinstance(scenario, str):
        if scenario not in SCENARIOS:
            raise KeyError(f"unknown scenario {scenario!r}; known: {', '.join(SCENARIOS)}")
        return dict(SCENARIOS[scenario], name=scenario)
    return dict(scenario)


# =============================================================================== integration
@dataclass
class Trajectory:
    """Noise-free truth on a time grid, plus what the sensors would read (no noise)."""

    t: np.ndarray
    y: np.ndarray  # (N_STATE, len(t))
    p: np.ndarray  # total pressure [Pa]
    p_sensor: np.ndarray  # pressure-sensor reading without noise (incl. bias) [Pa]
    T_v: np.ndarray
    T_l: np.ndarray
    T_w: np.ndarray
    level: np.ndarray
    fill_ratio: np.ndarray
    energy: np.ndarray
    mass: np.ndarray
    E_ext: np.ndarray
    M_ext: np.ndarray
    n_rhs: int
    wall_s: float
    max_volume_error: float  # max |V_v + V_l - V| / V on the grid
    extra: dict[str, np.ndarray] = field(default_factory=dict)

    def channel(self, name: str) -> np.ndarray:
        return {"p_v_Pa": self.p_sensor, "T_v_K": self.T_v, "T_l_K": self.T_l, "T_w_K": self.T_w,
                "H_l_m": self.level}[name]


def simulate_truth(scenario: str | Mapping[str, Any], mechanism: str | None = None, value: float = 0.0, *,
                   t_eval: np.ndarray | None = None, duration_s: float | None = None,
                   props: _Props | None = None) -> Trajectory:
    """Integrate a scenario (name or dict like :data:`SCENARIOS`) with one hidden mechanism.

    ``t_eval`` defaults to every second; ``duration_s`` may shorten the scenario (steps after
    it are dropped).
    """
    sc = _resolve(scenario)
    mech = Mechanism.one(mechanism, value)
    duration = float(duration_s if duration_s is not None else sc["duration_s"])
    steps = [s for s in sc["steps"] if s[0] < duration]
    segments = _expand_steps(steps, duration)
    if t_eval is None:
        t_eval = np.arange(0.0, duration + 0.5, 1.0)
    t_eval = np.asarray(t_eval, dtype=float)
    if t_eval[0] < 0 or t_eval[-1] > duration or (np.diff(t_eval) <= 0).any():
        raise ValueError("t_eval must be increasing within [0, duration]")

    model = TankModel(sc["tank"], mech, props)
    ini = sc["initial"]
    y = model.initial_state(ini["p_Pa"], ini["T_v_K"], ini["T_l_K"], ini["T_w_K"], ini["fill_ratio"])
    atol = np.array([1e-4, 1e-9, 1e-9, 1e-9, 1e-10 * y[4], 1e-10 * y[5], 1e-3, 1e-10 * y[5]])
    ys = np.empty((N_STATE, t_eval.size))
    diags: list[Diagnostics] = [None] * t_eval.size  # type: ignore[list-item]
    t_start = time.perf_counter()
    for ta, tb, values in segments:
        model.set_inputs(values)
        last = tb >= duration
        sel = (t_eval >= ta) & ((t_eval <= tb) if last else (t_eval < tb))
        te = t_eval[sel]
        te_ext = np.append(te, tb) if (te.size == 0 or te[-1] < tb) else te
        sol = None
        for method in ("LSODA", "BDF"):
            try:
                sol = solve_ivp(model.rhs, (ta, tb), y, method=method, t_eval=te_ext, rtol=_RTOL, atol=atol,
                                max_step=_MAX_STEP_S)
            except (ValueError, SimulationError) as exc:  # CoolProp raises ValueError
                sol = None
                err = f"{type(exc).__name__}: {exc}"
            else:
                err = sol.message
                if sol.success:
                    break
        if sol is None or not sol.success:
            raise SimulationError(f"integration failed in [{ta}, {tb}] s of {sc.get('name', 'scenario')} "
                                  f"(mechanism {mechanism}={value}): {err}")
        ys[:, sel] = sol.y[:, : te.size]
        y = sol.y[:, -1].copy()
        # Diagnostics with this segment's inputs (the coefficients depend on the sloshing).
        for k in np.flatnonzero(sel):
            diags[k] = model.diagnostics(ys[:, k])
    wall = time.perf_counter() - t_start

    p = np.array([d.p for d in diags])
    V = model.geom.volume
    return Trajectory(
        t=t_eval, y=ys, p=p, p_sensor=p + mech.pressure_sensor_bias,
        T_v=ys[1].copy(), T_l=ys[2].copy(), T_w=ys[3].copy(),
        level=np.array([d.level for d in diags]), fill_ratio=np.array([d.V_l / V for d in diags]),
        energy=np.array([d.energy for d in diags]), mass=np.array([d.mass for d in diags]),
        E_ext=ys[6].copy(), M_ext=ys[7].copy(), n_rhs=model.n_rhs, wall_s=wall,
        max_volume_error=float(max(abs(d.V_v + d.V_l - V) for d in diags) / V),
        extra={k: np.array([getattr(d, k) for d in diags])
               for k in ("p_g", "T_sat", "h_wv", "h_wl", "h_vi", "h_li", "Q_wv", "Q_wl", "Q_vi", "Q_li", "J")},
    )


# =============================================================================== sampling + writer
def sample_times(duration_s: float) -> dict[str, np.ndarray]:
    """Nominal sample times of each channel (before dropouts)."""
    out = {}
    for ch, (period, offset) in SAMPLING.items():
        out[ch] = np.arange(offset, duration_s + 1e-9, period)
    return out


def _fmt(v: float) -> str:
    return repr(float(v))


def simulate_run(scenario: str, mechanism: str | None = None, value: float = 0.0, *, seed: int = 0,
                 noise: dict | None = None, out_dir: str | pathlib.Path, name: str | None = None,
                 dropout: float = DEFAULT_DROPOUT, noise_free: bool = False,
                 duration_s: float | None = None) -> pathlib.Path:
    """Simulate a scenario with one hidden mechanism and write ``NAME.json`` + ``NAME.csv``.

    Args:
        scenario: a key of :data:`SCENARIOS`.
        mechanism: a key of :data:`MECHANISMS` or None (nominal tank).
        value: the mechanism's parameter (see :data:`MECHANISMS` for units).
        seed: seeds the noise and the dropouts.
        noise: per-channel standard deviations (keys ``p_v, T_v, T_l, T_w, H_l``) overriding
            :data:`DEFAULT_NOISE`; they are written as ``noise_std``.
        out_dir: folder to write into (created if needed).
        name: run name (default ``indep_<scenario>_<mechanism>_s<seed>``).
        dropout: probability that a sample is lost.
        noise_free: write the exact readings (``noise_std`` still holds the nominal values).
        duration_s: shorten the scenario.

    Returns the path of the JSON file.
    """
    sc = _resolve(scenario)
    std = dict(DEFAULT_NOISE)
    if noise:
        unknown = set(noise) - set(NOISE_KEYS)
        if unknown:
            raise ValueError(f"unknown noise keys {sorted(unknown)}; known: {NOISE_KEYS}")
        std.update({k: float(v) for k, v in noise.items()})
    if not all(v > 0 for v in std.values()):
        raise ValueError(f"noise standard deviations must be > 0 (use noise_free=True for exact readings): {std}")
    duration = float(duration_s if duration_s is not None else sc["duration_s"])
    times = sample_times(duration)
    rng = np.random.default_rng(seed)
    kept = {ch: t[rng.random(t.size) >= dropout] if dropout > 0 else t for ch, t in times.items()}
    t_grid = np.unique(np.concatenate([[0.0], *kept.values()]))
    traj = simulate_truth(sc, mechanism, value, t_eval=t_grid, duration_s=duration)

    obs: dict[str, dict[float, float]] = {}
    for ch, key in zip(OBS_COLUMNS, NOISE_KEYS):
        t_ch = kept[ch]
        idx = np.searchsorted(t_grid, t_ch)
        vals = traj.channel(ch)[idx]
        if not noise_free:
            vals = vals + rng.normal(0.0, std[key], size=vals.size)
        if ch == "H_l_m":
            vals = np.maximum(vals, 0.0)
        obs[ch] = dict(zip(t_ch.tolist(), vals.tolist()))

    # Metered schedule (the CSV holds metered values, never the mechanism's true flows).
    steps = [s for s in sc["steps"] if s[0] < duration]
    segments = _expand_steps(steps, duration)
    used = [c for c in INPUT_COLUMNS if any(seg[2][c] != 0.0 for seg in segments)]
    change_times = [seg[0] for seg in segments]
    rows_t = sorted(set(change_times) | set(t_grid.tolist()))

    run_name = name or f"indep_{sc.get('name', 'custom')}_{mechanism or 'none'}_s{seed}"
    out = pathlib.Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    csv_path = out / f"{run_name}.csv"
    header = ["t_s", *OBS_COLUMNS, *used]
    with open(csv_path, "w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(header)
        k = 0
        for t in rows_t:
            while k + 1 < len(segments) and segments[k + 1][0] <= t:
                k += 1
            row = [_fmt(t)]
            for ch in OBS_COLUMNS:
                v = obs[ch].get(t)
                row.append("" if v is None else _fmt(v))
            row.extend(_fmt(segments[k][2][c]) for c in used)
            w.writerow(row)

    ini = sc["initial"]
    meta = {
        "name": run_name,
        "fluid": FLUID,
        "source": f"independent test simulator (tests/independent_sim.py), mechanism={mechanism or 'none'} "
                  f"value={float(value)!r}",
        "tank": {**{k: v for k, v in sc["tank"].items()}, "volume_m3": make_geometry(sc["tank"]).volume},
        "initial": {"p_v_Pa": float(traj.p_sensor[0]), "T_v_K": float(ini["T_v_K"]), "T_l_K": float(ini["T_l_K"]),
                    "T_w_K": float(ini["T_w_K"]), "fill_ratio": float(traj.fill_ratio[0])},
        "noise_std": {k: std[k] for k in NOISE_KEYS},
        "duration_s": duration,
        "timeseries": csv_path.name,
    }
    json_path = out / f"{run_name}.json"
    json_path.write_text(json.dumps(meta, indent=2) + "\n")
    return json_path


# =============================================================================== signatures
def _sample_grid(duration_s: float) -> tuple[dict[str, np.ndarray], np.ndarray]:
    times = sample_times(duration_s)
    return times, np.unique(np.concatenate([[0.0], *times.values()]))


def signature_diffs(scenario: str, mechanism: str, value: float, *, baseline: Trajectory | None = None,
                    noise: Mapping[str, float] | None = None, props: _Props | None = None
                    ) -> dict[str, np.ndarray]:
    """{channel: (with - without) / noise_std} at the nominal sample times (noise-free runs)."""
    std = dict(DEFAULT_NOISE, **(noise or {}))
    times, t_grid = _sample_grid(float(SCENARIOS[scenario]["duration_s"]))
    base = baseline if baseline is not None else simulate_truth(scenario, t_eval=t_grid, props=props)
    pert = simulate_truth(scenario, mechanism, value, t_eval=t_grid, props=props)
    out = {}
    for ch, key in zip(OBS_COLUMNS, NOISE_KEYS):
        idx = np.searchsorted(t_grid, times[ch])
        out[ch] = (pert.channel(ch)[idx] - base.channel(ch)[idx]) / std[key]
    return out


def signature(scenario: str, mechanism: str, value: float, *, baseline: Trajectory | None = None,
              noise: Mapping[str, float] | None = None) -> dict[str, tuple[float, float]]:
    """{channel: (RMS, max)} of |with - without| at the nominal sample times, in noise-std units."""
    d = signature_diffs(scenario, mechanism, value, baseline=baseline, noise=noise)
    return {ch: (float(np.sqrt(np.mean(v * v))), float(np.max(np.abs(v)))) for ch, v in d.items()}


# Magnitudes measured with ``python tests/independent_sim.py`` (noise-free runs with and without
# the mechanism, differences at the nominal sample times in units of DEFAULT_NOISE): the RMS
# difference of the most affected channel is 3-5 sigma over the 3600 s run. Keys are
# (scenario, mechanism); a bare mechanism key is the value in SCENARIO_FOR[mechanism]. A pair
# that is absent does not show in that scenario (inflow_meter_bias without inflows).
SUGGESTED_MAGNITUDE: dict[Any, float] = {
    ('sphere_vent', 'heat_leak_liquid'): 220.0,
    ('sphere_vent', 'heat_leak_vapor'): 130.0,
    ('sphere_vent', 'heat_leak_wall'): 220.0,
    ('sphere_vent', 'vapor_leak'): 0.0002,
    ('sphere_vent', 'liquid_leak'): 0.0002,
    ('sphere_vent', 'pressure_sensor_bias'): 8000.0,
    ('sphere_vent', 'wall_heat_capacity_error'): 0.91,
    ('sphere_vent', 'noncondensable_gas'): 85.0,
    ('sphere_vent', 'thermal_stratification'): 0.2,
    ('hcyl_drain_fill', 'heat_leak_liquid'): 280.0,
    ('hcyl_drain_fill', 'heat_leak_vapor'): 190.0,
    ('hcyl_drain_fill', 'heat_leak_wall'): 300.0,
    ('hcyl_drain_fill', 'vapor_leak'): 0.0002,
    ('hcyl_drain_fill', 'liquid_leak'): 0.00027,
    ('hcyl_drain_fill', 'pressure_sensor_bias'): 8000.0,
    ('hcyl_drain_fill', 'wall_heat_capacity_error'): 0.5,
    ('hcyl_drain_fill', 'noncondensable_gas'): 80.0,
    ('hcyl_drain_fill', 'thermal_stratification'): 0.2,
    ('hcyl_drain_fill', 'inflow_meter_bias'): 0.012,
    ('vcyl_press_hold_vent', 'heat_leak_liquid'): 130.0,
    ('vcyl_press_hold_vent', 'heat_leak_vapor'): 100.0,
    ('vcyl_press_hold_vent', 'heat_leak_wall'): 150.0,
    ('vcyl_press_hold_vent', 'vapor_leak'): 0.00013,
    ('vcyl_press_hold_vent', 'liquid_leak'): 9.8e-05,
    ('vcyl_press_hold_vent', 'pressure_sensor_bias'): 8000.0,
    ('vcyl_press_hold_vent', 'wall_heat_capacity_error'): 0.77,
    ('vcyl_press_hold_vent', 'noncondensable_gas'): 93.0,
    ('vcyl_press_hold_vent', 'thermal_stratification'): 0.2,
    ('vcyl_press_hold_vent', 'inflow_meter_bias'): 0.14,
    ('small_selfpress', 'heat_leak_liquid'): 49.0,
    ('small_selfpress', 'heat_leak_vapor'): 50.0,
    ('small_selfpress', 'heat_leak_wall'): 52.0,
    ('small_selfpress', 'vapor_leak'): 4.1e-05,
    ('small_selfpress', 'liquid_leak'): 5.1e-05,
    ('small_selfpress', 'pressure_sensor_bias'): 8000.0,
    ('small_selfpress', 'wall_heat_capacity_error'): 1.3,
    ('small_selfpress', 'noncondensable_gas'): 17.0,
    ('small_selfpress', 'thermal_stratification'): 0.2,
}

# The scenario in which each mechanism is best told apart from the others (measured: largest
# sqrt(delta chi2) to the closest other mechanism, each at its best-fitting magnitude).
SCENARIO_FOR: dict[str, str] = {
    "heat_leak_liquid": "sphere_vent",
    "heat_leak_vapor": "small_selfpress",
    "heat_leak_wall": "sphere_vent",
    "vapor_leak": "vcyl_press_hold_vent",
    "liquid_leak": "sphere_vent",
    "pressure_sensor_bias": "hcyl_drain_fill",
    "wall_heat_capacity_error": "small_selfpress",
    "noncondensable_gas": "hcyl_drain_fill",
    "thermal_stratification": "hcyl_drain_fill",
    "inflow_meter_bias": "vcyl_press_hold_vent",
}
SUGGESTED_MAGNITUDE.update({m: SUGGESTED_MAGNITUDE[(sc, m)] for m, sc in SCENARIO_FOR.items()})


def suggested_magnitude(mechanism: str, scenario: str | None = None) -> float:
    """The suggested magnitude of a mechanism (in ``scenario`` or in its preferred one)."""
    if scenario is None:
        return SUGGESTED_MAGNITUDE[mechanism]
    return SUGGESTED_MAGNITUDE[(scenario, mechanism)]


# First guesses for the measurement (scaled to the target afterwards).
_TRIAL: dict[str, float] = {
    "heat_leak_liquid": 100.0,
    "heat_leak_vapor": 50.0,
    "heat_leak_wall": 100.0,
    "vapor_leak": 2e-4,
    "liquid_leak": 2e-4,
    "pressure_sensor_bias": 8000.0,
    "wall_heat_capacity_error": 0.5,
    "noncondensable_gas": 50.0,
    "thermal_stratification": 0.2,
    "inflow_meter_bias": 0.1,
}


def _measure(target_rms: float = 4.0, verbose: bool = True, scenarios: Sequence[str] | None = None,
             mechanisms: Sequence[str] | None = None) -> dict[tuple[str, str], dict[str, Any]]:
    """Find, per scenario and mechanism, the magnitude giving about ``target_rms`` sigma RMS on the
    most affected channel (secant on the magnitude; accepted within 3-5 sigma)."""
    results: dict[tuple[str, str], dict[str, Any]] = {}
    props = _Props()
    for sc in scenarios or SCENARIOS:
        _, t_grid = _sample_grid(float(SCENARIOS[sc]["duration_s"]))
        t0 = time.perf_counter()
        base = simulate_truth(sc, t_eval=t_grid, props=props)
        if verbose:
            print(f"# {sc}: baseline {time.perf_counter() - t0:.2f} s, {base.n_rhs} rhs calls, "
                  f"p {base.p.min():.0f}..{base.p.max():.0f} Pa, T_v {base.T_v.min():.2f}..{base.T_v.max():.2f} K, "
                  f"T_l {base.T_l.min():.3f}..{base.T_l.max():.3f} K, T_w {base.T_w.min():.2f}..{base.T_w.max():.2f} K, "
                  f"fill {base.fill_ratio.min():.3f}..{base.fill_ratio.max():.3f}", flush=True)
        for mech in mechanisms or MECHANISMS:
            value = SUGGESTED_MAGNITUDE.get((sc, mech), _TRIAL[mech])
            diffs: dict[str, np.ndarray] = {}
            wall = 0.0
            for _ in range(5):
                t0 = time.perf_counter()
                diffs = signature_diffs(sc, mech, value, baseline=base, props=props)
                wall = time.perf_counter() - t0
                top = max(float(np.sqrt(np.mean(v * v))) for v in diffs.values())
                if top < 1e-3 or 3.0 <= top <= 5.0:
                    break
                value = float(f"{value * target_rms / top:.2g}")
            sig = {ch: (float(np.sqrt(np.mean(v * v))), float(np.max(np.abs(v)))) for ch, v in diffs.items()}
            top = max(r for r, _ in sig.values())
            results[(sc, mech)] = {"value": value, "sig": sig, "diffs": diffs, "wall_s": wall, "shows": top >= 1.0}
            if verbose:
                cells = "  ".join(f"{ch[:3]} {r:5.2f}/{m:5.2f}" for ch, (r, m) in sig.items())
                print(f"{sc:22s} {mech:26s} {value:10.3g}  {cells}  ({wall:.2f} s)", flush=True)
    return results


def _separability(results: Mapping[tuple[str, str], Mapping[str, Any]]) -> dict[tuple[str, str], tuple[float, float, str]]:
    """Per (scenario, mechanism): (sqrt(chi2) to no mechanism, min sqrt(delta chi2) to another
    mechanism at its best-fitting magnitude (linearised), that closest mechanism)."""
    out: dict[tuple[str, str], tuple[float, float, str]] = {}
    scen = sorted({sc for sc, _ in results})
    for sc in scen:
        vecs = {m: np.concatenate([r["diffs"][ch] for ch in OBS_COLUMNS])
                for (s_, m), r in results.items() if s_ == sc and r["shows"]}
        for a, da in vecs.items():
            best, who = math.inf, ""
            for b, db in vecs.items():
                if b == a:
                    continue
                c = float(da @ db) / float(db @ db)
                res = float(np.linalg.norm(da - c * db))
                if res < best:
                    best, who = res, b
            out[(sc, a)] = (float(np.linalg.norm(da)), best, who)
    return out


def _report(results: Mapping[tuple[str, str], Mapping[str, Any]]) -> None:
    sep = _separability(results)
    print("\n| scenario | mechanism | value | " + " | ".join(f"{c} RMS/max" for c in OBS_COLUMNS)
          + " | sqrt(chi2) | closest other: sqrt(dchi2) |")
    print("|---" * (5 + len(OBS_COLUMNS)) + "|")
    for (sc, mech), r in results.items():
        if not r["shows"]:
            print(f"| {sc} | {mech} | - | does not show |")
            continue
        cells = " | ".join(f"{rms:.2f}/{mx:.2f}" for rms, mx in r["sig"].values())
        tot, best, who = sep[(sc, mech)]
        print(f"| {sc} | {mech} | {r['value']:.3g} | {cells} | {tot:.0f} | {who}: {best:.1f} |")
    print("\nSUGGESTED_MAGNITUDE.update({")
    for (sc, mech), r in results.items():
        if r["shows"]:
            print(f"    ({sc!r}, {mech!r}): {r['value']!r},")
    print("})")
    print("\n# best scenario per mechanism (largest distance to the closest other mechanism)")
    for mech in MECHANISMS:
        cands = [(sep[(sc, m)][1], sc) for (sc, m) in sep if m == mech]
        if cands:
            d, sc = max(cands)
            print(f"    {mech!r}: {sc!r},  # sqrt(dchi2) {d:.1f}")


if __name__ == "__main__":  # pragma: no cover - measurement script
    import argparse

    parser = argparse.ArgumentParser(description="Each hidden mechanism's magnitude that moves the most "
                                     "affected channel by about 4 sigma RMS, per scenario, and how far apart the "
                                     "mechanisms' signatures lie (the runs themselves: simulate_truth, or "
                                     "experiments/diagnosis_foreign.py --only independent).")
    parser.add_argument("scenarios", nargs="*", metavar="SCENARIO",
                        help=f"scenarios to measure (default: all): {', '.join(SCENARIOS)}")
    chosen = parser.parse_args().scenarios
    unknown = [sc for sc in chosen if sc not in SCENARIOS]
    if unknown:
        parser.error(f"unknown scenario {unknown[0]!r}; known: {', '.join(SCENARIOS)}")
    _report(_measure(scenarios=chosen or None))
