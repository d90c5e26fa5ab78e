"""Engineering-property 0D tank simulator: an independent "truth" that does NOT use CoolProp.

Writes runs in the interchange format (``shared/data-format.md``: ``NAME.json`` + ``NAME.csv``)
plus ``NAME.truth.json``, with ``tests/cryo_sim.py``'s interface (command line, mechanisms,
sampling, noise), but shares no code with ``tankode`` or the other simulators and replaces the
reference equation of state by an *engineering property model*, to measure how tankode
(CoolProp inside) reacts to property-model differences. ``fluid`` is the CoolProp name.

Property model (ParaHydrogen, Hydrogen, Nitrogen, Oxygen, Methane; fitted once, offline)
-----------------------------------------------------------------------------------
* ``ln p_sat = A - B / (T + C)`` (Antoine) through three handbook anchors: triple point,
  normal boiling point, critical point (T rounded to 0.1 K, p to 3 digits).
* Latent heat: Watson, ``L = L_nbp ((Tc - T) / (Tc - T_nbp))^0.38``.
* Liquid: incompressible, ``rho_l = rho_nbp + s (T - T_nbp)`` (minimax line over the range),
  ``u_l = c_l (T - T_nbp)``, ``c_l`` constant (CoolProp's c_p at the range's mid pressure).
* Vapour: ``v = R T / p + B(T)`` (second virial), ``B`` from Pitzer-Abbott with ``Tc, pc,
  omega``; for hydrogen Prausnitz's quantum-corrected ``Tc = 43.6 / (1 + 21.8 / (M T))`` K,
  ``pc = 20.5 / (1 + 44.2 / (M T))`` bar, ``omega = 0``. Constant ideal-gas ``c_v``: 1.5 R
  (hydrogens), 2.5 R (N2, O2), 3.0 R (CH4); ``u_v = u_0 + c_v (T - T_nbp) - T B' p`` (exact for
  this equation of state); ``u_0`` makes ``h_v - h_l = L`` at the normal boiling point.
  Constant c_l, constant c_v and Watson cannot agree elsewhere: the interface uses Watson's
  ``L`` and the evaporating liquid leaves at ``h_v,sat - L`` (energy conserved exactly; the
  small difference to the liquid's own enthalpy stays in the liquid).
* Transport: constant ``k``, ``mu`` per phase (liquid at the NBP, gas at 1.5 T_nbp, 1 atm).

Deviation from CoolProp 8.0 (measured offline, p = 0.5 .. 5.5 bar for hydrogen, 0.5 .. 12 bar
for the others; density and c_p of the vapour at saturation / 5 K above it):

======  ==============  ============  =======  ============  ============  ====================
fluid   T_sat [K]       L Watson [%]  rho_l %  rho_v,sat %   c_p,v %       c_l vs CP [kJ/kg/K]
======  ==============  ============  =======  ============  ============  ====================
p-H2    -0.15 .. +0.08  -9.6 .. +4.5  +-0.9    -7.0 .. +0.1  -8.1 .. -0.2  10.9 vs 8.6 .. 17.7
n-H2    -0.18 .. +0.09  -9.7 .. +4.3  +-0.9    -7.0 .. +0.0  -8.8 .. -0.5  10.9 vs 8.7 .. 17.5
N2      -0.47 .. +0.11  -1.8 .. +0.7  +-0.7    -5.6 .. +0.0  -16 .. -0.3   2.10 vs 2.02 .. 2.55
O2      -0.70 .. +0.13  -2.5 .. +0.8  +-0.5    -3.1 .. +0.1  -10 .. +0.6   1.74 vs 1.69 .. 1.98
CH4     -0.69 .. +0.10  -3.4 .. +1.0  +-0.5    -3.8 .. -0.1  -13 .. -1.2   3.58 vs 3.43 .. 4.15
======  ==============  ============  =======  ============  ============  ====================

(10 K above saturation the vapour density is within 0.2 % for hydrogen, 2 % for the others.
The model's ``h_v - h_l`` exceeds Watson's L by up to 18 % for hydrogen at 5.5 bar, 5-7 % for
the others at 12 bar: that enthalpy stays in the liquid.)

State and balances
------------------
``y = (m_v, U_v, n_He, m_l, U_l, E_wet, E_dry, tau, M_bnd, E_bnd)``: ullage (fluid + ideal
monatomic helium, Dalton: the interface sees the fluid's partial pressure), well-mixed liquid,
two wall nodes (wetted capacity ``C_w (0.01 + 0.98 A_wet / A_wall)``; capacity that moves with
the level carries the upwind node's temperature), ``tau`` the age of the liquid's thermal
boundary layer, and quadratures of what crossed the boundary. ``T_l`` is explicit, ``T_v`` a
scalar Newton solve; ``p dV`` work moves between liquid and ullage with opposite signs. Mass
and energy are linear invariants, so LSODA closes them to round-off (reported in the truth).

Heat and mass transfer (own laws)
---------------------------------
* Wall-gas and wall-liquid: vertical turbulent natural convection ``Nu_L = 1 + 0.13 Ra^(1/3)``.
* Interface, gas side: ``0.27 Ra^(1/4)`` (stable, warm gas above) or ``0.15 Ra^(1/3)``,
  length ``A_i / P_i``, plus 0.5. Liquid side: conduction into a thermal boundary layer,
  ``h = k / delta``, ``delta = sqrt(pi alpha tau)`` (capped by half the depth),
  ``d tau / dt = 1 - r tau``, mixing rate ``r = sqrt(E) + 30 mdot_l,in / m_l`` (sloshing and
  fill reset it); plus ``0.15 Ra^(1/3)`` when the liquid is warmer than the interface.
* Sloshing ``E = A0 omega^2 / g``: interface coefficients x ``(1 + 15 sqrt(E))``, wall x
  ``(1 + 3 sqrt(E))``.
* ``J = (Q_vi - Q_il) / L(T_i)``, ``T_i = T_sat(p_fluid)``. Flashing above ``T_sat(p)``:
  ``m_l c_l r(T_l - T_sat) / (30 s L)``; fog below ``T_i``: ``(m_v c_p + n c_p,He)
  r(T_i - T_v) / (20 s L)`` (``r`` a C1 ramp over 0.05 K).
* Wall nodes exchange ``k_w t_w P / (H / 3)`` (``P`` the contact line); ``Q_aw`` and the
  hidden wall leak are split by area.

Operations follow cryo_sim: phases are targets turned into metered rates by an operator on the
nominal state; a run with mechanisms replays the nominal schedule; soft bounds (fill 0.05-0.95,
pressure 0.7 bar .. 0.95 ``p_max``) are terminal events that stop flows or open a relief vent;
hard limits raise :class:`SimulationError`. Vents are metered at ullage conditions (mixture
mass), drains at liquid conditions. Sensors: ``p_v, T_v, T_l, H_l`` every 10 s, ``T_w``
(capacity mean) every 20 s. ``solve_ivp(LSODA, rtol=1e-8, max_step=60 s)``.

Command line::

    python tests/eng_sim.py SCENARIO|random_SEED [--fluid F] [--mechanism NAME=VALUE ...]
        [--noise none|low|high] [--seed N] [--out DIR] [--name N] [--duration S] [--list]
"""

from __future__ import annotations

import argparse
import copy
import csv
import json
import math
import pathlib
import sys
import time
from typing import Any, Mapping, Sequence

import numpy as np
from scipy.integrate import solve_ivp

SIMULATOR = "tests/eng_sim.py"
G = 9.80665
RU = 8.314462618
M_HE = 4.002602e-3
P_LOW = 0.7e5  # soft lower bound of the pressure (vent and drain stop)
P_HARD_LOW = 0.3e5
FLASH_TAU_S, FOG_TAU_S, RAMP_K = 30.0, 20.0, 0.05
TAU0_S = 1800.0  # initial age of the liquid thermal boundary layer
C_SLOSH_I, C_SLOSH_W, C_MIX_FILL = 15.0, 3.0, 30.0
RTOL = 1e-8

FLUIDS = ("ParaHydrogen", "Hydrogen", "Nitrogen", "Oxygen", "Methane")
SHAPES = ("vertical_cylinder", "vertical_cylinder_elliptical_heads", "sphere", "horizontal_cylinder")
OPERATIONS = ("rest", "pressurize", "vent", "fill", "drain", "slosh")
OBS_COLUMNS = ("p_v_Pa", "T_v_K", "T_l_K", "T_w_K", "H_l_m")
NOISE_KEYS = ("p_v", "T_v", "T_l", "T_w", "H_l")
INPUT_COLUMNS = ("mdot_v_in_kg_s", "T_v_in_K", "p_v_in_Pa", "mdot_v_out_kg_s", "mdot_l_in_kg_s", "T_l_in_K",
                 "mdot_l_out_kg_s", "slosh_amplitude_m", "slosh_frequency_Hz", "Q_aw_W")
NOISE_LEVELS = {"low": {"p_v": 300.0, "T_v": 0.05, "T_l": 0.05, "T_w": 0.05, "H_l": 0.001},
                "high": {"p_v": 2000.0, "T_v": 0.2, "T_l": 0.2, "T_w": 0.2, "H_l": 0.005}}
SAMPLE_DT_S, SAMPLE_DT_WALL_S = 10.0, 20.0
MECHANISMS = {
    "heat_leak_liquid_W": "extra heat into the liquid [W]",
    "heat_leak_vapor_W": "extra heat into the ullage gas [W]",
    "heat_leak_wall_W": "extra heat into the wall (split by area) [W]",
    "vapor_leak_kg_s": "unmetered loss of ullage gas at ullage state [kg/s]",
    "liquid_leak_kg_s": "unmetered loss of liquid [kg/s]",
    "inflow_meter_bias": "true inflows = (1 + b) x metered (vapour and liquid) [-]",
    "pressure_sensor_bias_Pa": "added to the pressure sensor [Pa]",
    "temperature_sensor_bias_K": "added to the liquid temperature sensor T_l [K]",
    "helium_mol": "helium in the ullage (ideal, monatomic, at T_v) [mol]",
    "wall_heat_capacity_error": "true C_w = (1 + e) x metadata's [-]",
}

# Engineering data: handbook constants, offline fits (see the module docstring).
# antoine: ln(p/Pa) = A - B/(T + C); rho_l = rho_nbp + drho (T - T_nbp); cv in units of R.
FLUID_DATA: dict[str, dict[str, Any]] = {
    "ParaHydrogen": dict(M=2.01588e-3, Tc=32.938, pc=1.2858e6, omega=-0.219, T_nbp=20.271, L_nbp=4.461e5,
                         antoine=(19.14437, 191.2947, 4.7994), rho_nbp=70.72, drho=-1.4183, c_l=10905.0,
                         cv_R=1.5, quantum=True, k_l=0.101, mu_l=1.35e-5, k_v=0.0245, mu_v=1.54e-6, p_max=5.5e5),
    "Hydrogen": dict(M=2.01588e-3, Tc=33.145, pc=1.2964e6, omega=-0.219, T_nbp=20.369, L_nbp=4.487e5,
                     antoine=(19.08118, 187.9722, 4.4696), rho_nbp=70.75, drho=-1.4078, c_l=10880.0,
                     cv_R=1.5, quantum=True, k_l=0.104, mu_l=1.35e-5, k_v=0.0247, mu_v=1.55e-6, p_max=5.5e5),
    "Nitrogen": dict(M=28.0135e-3, Tc=126.19, pc=3.3958e6, omega=0.0372, T_nbp=77.355, L_nbp=1.992e5,
                     antoine=(20.41923, 664.2170, -2.7383), rho_nbp=807.28, drho=-5.3359, c_l=2097.0,
                     cv_R=2.5, quantum=False, k_l=0.145, mu_l=1.61e-4, k_v=0.0109, mu_v=7.99e-6, p_max=12e5),
    "Oxygen": dict(M=31.9988e-3, Tc=154.58, pc=5.0464e6, omega=0.0222, T_nbp=90.188, L_nbp=2.131e5,
                   antoine=(20.64237, 781.7753, -4.4743), rho_nbp=1142.01, drho=-5.6002, c_l=1735.0,
                   cv_R=2.5, quantum=False, k_l=0.151, mu_l=1.95e-4, k_v=0.0124, mu_v=1.03e-5, p_max=12e5),
    "Methane": dict(M=16.0428e-3, Tc=190.56, pc=4.5992e6, omega=0.0114, T_nbp=111.67, L_nbp=5.108e5,
                    antoine=(20.67194, 1007.6188, -1.5664), rho_nbp=422.70, drho=-1.6741, c_l=3584.0,
                    cv_R=3.0, quantum=False, k_l=0.184, mu_l=1.17e-4, k_v=0.018, mu_v=6.63e-6, p_max=12e5),
}

# wall materials (rough cryogenic values): density, c(T) and k(T) at T_TAB
T_TAB = (20.0, 40.0, 60.0, 80.0, 100.0, 120.0, 150.0)
MATERIALS = {"steel": (7900.0, (12.0, 60.0, 130.0, 200.0, 255.0, 295.0, 345.0),
                       (2.0, 4.5, 6.5, 8.0, 9.0, 10.0, 11.5)),
             "aluminium": (2700.0, (9.0, 75.0, 190.0, 340.0, 480.0, 560.0, 660.0),
                           (35.0, 60.0, 75.0, 85.0, 95.0, 105.0, 115.0))}


class SimulationError(RuntimeError):
    """The integration failed or left the model's validity range."""


def _ramp(x: float) -> float:
    if x <= 0.0:
        return 0.0
    return 0.5 * x * x / RAMP_K if x < RAMP_K else x - 0.5 * RAMP_K


def _blend(x: float, w: float = 0.1) -> float:
    return 0.5 * (1.0 + math.tanh(x / w))


# ----------------------------------------------------------------------------- properties
class EngFluid:
    """The engineering property model of one fluid (no CoolProp)."""

    def __init__(self, name: str):
        if name not in FLUID_DATA:
            raise ValueError(f"unknown fluid {name!r}; known: {', '.join(FLUIDS)}")
        d = FLUID_DATA[name]
        self.name, self.d = name, d
        self.M, self.Tc, self.pc, self.omega = d["M"], d["Tc"], d["pc"], d["omega"]
        self.Rs = RU / self.M
        self.cv = d["cv_R"] * self.Rs
        self.cp_v = self.cv + self.Rs
        self.T_nbp, self.L_nbp, self.c_l = d["T_nbp"], d["L_nbp"], d["c_l"]
        self.A, self.B, self.C = d["antoine"]
        self.p_max = d["p_max"]
        self.u0 = 0.0
        p_n = self.p_sat(self.T_nbp)
        self.u0 = self.L_nbp + self.h_l(self.T_nbp, p_n) - self.h_v_Tp(self.T_nbp, p_n)

    # saturation and latent heat
    def T_sat(self, p: float) -> float:
        return self.B / (self.A - math.log(max(p, 1.0))) - self.C

    def p_sat(self, T: float) -> float:
        return math.exp(self.A - self.B / (T + self.C))

    def L(self, T: float) -> float:
        x = max(self.Tc - T, 0.02 * self.Tc) / (self.Tc - self.T_nbp)
        return self.L_nbp * x ** 0.38

    # liquid
    def rho_l(self, T: float) -> float:
        return self.d["rho_nbp"] + self.d["drho"] * (T - self.T_nbp)

    def h_l(self, T: float, p: float) -> float:
        return self.c_l * (T - self.T_nbp) + p / self.rho_l(T)

    # vapour: second virial coefficient per unit mass and its T-derivative (complex step)
    def _B(self, T):
        if self.d["quantum"]:
            Mg = self.M * 1e3
            Tc, pc, om = 43.6 / (1 + 21.8 / (Mg * T)), 20.5e5 / (1 + 44.2 / (Mg * T)), 0.0
        else:
            Tc, pc, om = self.Tc, self.pc, self.omega
        Tr = T / Tc
        return RU * Tc / pc * (0.083 - 0.422 / Tr ** 1.6 + om * (0.139 - 0.172 / Tr ** 4.2)) / self.M

    def virial(self, T: float) -> tuple[float, float]:
        z = self._B(complex(T, 1e-20))
        return z.real, z.imag / 1e-20

    def vapour(self, T: float, v: float) -> tuple[float, float, float]:
        """(p, u, h) of the gas at temperature T and specific volume v."""
        B, dB = self.virial(T)
        p = self.Rs * T / (v - B)
        u = self.u0 + self.cv * (T - self.T_nbp) - T * dB * p
        return p, u, u + p * v

    def v_Tp(self, T: float, p: float) -> float:
        return self.Rs * T / p + self.virial(T)[0]

    def h_v_Tp(self, T: float, p: float) -> float:
        return self.vapour(T, self.v_Tp(T, p))[2]


_FLUIDS: dict[str, EngFluid] = {}


def fluid(name: str) -> EngFluid:
    if name not in _FLUIDS:
        _FLUIDS[name] = EngFluid(name)
    return _FLUIDS[name]


# ----------------------------------------------------------------------------- geometry
class Tank:
    """Level <-> volume (exact), interface and wetted areas of the format's four shapes."""

    def __init__(self, tank: Mapping[str, Any]):
        self.shape = s = tank["shape"]
        R = self.R = float(tank["radius_m"])
        if s == "vertical_cylinder":
            self.H = float(tank["height_m"])
            self.V = math.pi * R * R * self.H
            self.A_wall = 2 * math.pi * R * (R + self.H)
        elif s == "vertical_cylinder_elliptical_heads":
            self.Lc = float(tank["cylinder_length_m"])
            self.b = R / float(tank.get("head_aspect", 2.0))
            self.k2 = (R * R - self.b ** 2) / self.b ** 4
            self.H = self.Lc + 2 * self.b
            self.V_head = 2.0 / 3.0 * math.pi * R * R * self.b
            self.A_head = self._zone(self.b)[2]
            self.V = 2 * self.V_head + math.pi * R * R * self.Lc
            self.A_wall = 2 * self.A_head + 2 * math.pi * R * self.Lc
        elif s == "sphere":
            self.H = 2 * R
            self.V = 4.0 / 3.0 * math.pi * R ** 3
            self.A_wall = 4 * math.pi * R * R
        elif s == "horizontal_cylinder":
            self.Lc = float(tank["cylinder_length_m"])
            self.H = 2 * R
            self.V = math.pi * R * R * self.Lc
            self.A_wall = 2 * math.pi * R * (R + self.Lc)
        else:
            raise ValueError(f"unknown tank shape {s!r}; known: {', '.join(SHAPES)}")
        self._h = 0.5 * self.H

    def _arc(self, w: float) -> float:
        """Integral of sqrt(1 + k2 w^2) dw from 0 to w (meridian length factor of the head)."""
        k2 = self.k2
        if abs(k2) * self.b ** 2 < 1e-12:
            return w
        k = math.sqrt(abs(k2))
        s = math.sqrt(max(1 + k2 * w * w, 0.0))
        return 0.5 * (w * s + (math.asinh(k * w) if k2 > 0 else math.asin(min(k * w, 1.0))) / k)

    def _zone(self, z: float) -> tuple[float, float, float, float]:
        """Head filled to z from its apex: volume, section, wall area, d(area)/dz."""
        R, b = self.R, self.b
        w = b - z
        return (math.pi * R * R * (z * z / b - z ** 3 / (3 * b * b)), math.pi * R * R * (2 * z / b - z * z / b / b),
                2 * math.pi * R * (self._arc(b) - self._arc(w)),
                2 * math.pi * R * math.sqrt(max(1 + self.k2 * w * w, 0.0)))

    def section(self, h: float) -> tuple[float, float, float, float, float]:
        """(V_l, A_i, A_wet, dA_wet/dh, contact-line length) at level h."""
        h = min(max(h, 0.0), self.H)
        R, s = self.R, self.shape
        if s == "vertical_cylinder":
            return math.pi * R * R * h, math.pi * R * R, math.pi * R * (R + 2 * h), 2 * math.pi * R, 2 * math.pi * R
        if s == "sphere":
            a = max(2 * R * h - h * h, 0.0)
            return (math.pi * h * h * (R - h / 3), math.pi * a, 2 * math.pi * R * h, 2 * math.pi * R,
                    2 * math.pi * math.sqrt(a))
        if s == "horizontal_cylinder":
            L = self.Lc
            c = math.sqrt(max(2 * R * h - h * h, 0.0))
            th = math.acos(max(-1.0, min(1.0, 1 - h / R)))
            S = R * R * th - (R - h) * c
            return L * S, 2 * c * L, 2 * S + 2 * R * th * L, 4 * c + 2 * R * L / max(c, 1e-9), 2 * L + 4 * c
        b, L = self.b, self.Lc
        if h <= b:
            V, A_i, A_w, dA = self._zone(h)
            return V, A_i, A_w, dA, 2 * math.sqrt(math.pi * A_i)
        if h <= b + L:
            return (self.V_head + math.pi * R * R * (h - b), math.pi * R * R,
                    self.A_head + 2 * math.pi * R * (h - b), 2 * math.pi * R, 2 * math.pi * R)
        V, A_i, A_w, dA = self._zone(self.H - h)
        return self.V - V, A_i, self.A_wall - A_w, dA, 2 * math.sqrt(math.pi * A_i)

    def level(self, V_l: float) -> float:
        lo, hi, h = 0.0, self.H, self._h
        for _ in range(80):
            V, A_i = self.section(h)[:2]
            f = V - V_l
            if abs(f) < 1e-14 * self.V:
                break
            lo, hi = (lo, h) if f > 0 else (h, hi)
            hn = h - f / A_i if A_i > 0 else 0.5 * (lo + hi)
            if not lo < hn < hi:
                hn = 0.5 * (lo + hi)
            if abs(hn - h) < 1e-15 * self.H:
                h = hn
                break
            h = hn
        self._h = h
        return h

    def omega1(self, h: float) -> float:
        """First lateral sloshing mode [rad/s] (equivalent circular or rectangular basin)."""
        V_l, A_i = self.section(h)[:2]
        A_i = max(A_i, 1e-6)
        d = V_l / A_i
        if self.shape == "horizontal_cylinder":
            w = A_i / self.Lc
            return math.sqrt(math.pi * G / w * math.tanh(math.pi * d / w))
        Re = math.sqrt(A_i / math.pi)
        return math.sqrt(1.841 * G / Re * math.tanh(1.841 * d / Re))

    def dims(self) -> dict[str, float]:
        if self.shape == "vertical_cylinder":
            return {"radius_m": self.R, "height_m": self.H}
        if self.shape == "vertical_cylinder_elliptical_heads":
            return {"radius_m": self.R, "cylinder_length_m": self.Lc, "head_aspect": self.R / self.b}
        if self.shape == "sphere":
            return {"radius_m": self.R}
        return {"radius_m": self.R, "cylinder_length_m": self.Lc}


def tank_of_volume(shape: str, V: float, aspect: float) -> dict[str, Any]:
    """Dimensions for volume V; aspect = straight length (or height) / diameter."""
    if shape == "sphere":
        return {"shape": shape, "radius_m": (0.75 * V / math.pi) ** (1 / 3)}
    if shape == "vertical_cylinder_elliptical_heads":
        R = (V / (math.pi * (2 * aspect + 2.0 / 3.0))) ** (1 / 3)
        return {"shape": shape, "radius_m": R, "cylinder_length_m": 2 * R * aspect, "head_aspect": 2.0}
    R = (V / (2 * math.pi * aspect)) ** (1 / 3)
    key = "height_m" if shape == "vertical_cylinder" else "cylinder_length_m"
    return {"shape": shape, "radius_m": R, key: 2 * R * aspect}


# ----------------------------------------------------------------------------- the model
class Model:
    """Right-hand side, state recovery and sensors of one tank with its hidden mechanisms."""

    NY = 10

    def __init__(self, sc: Mapping[str, Any], mech: Mapping[str, float]):
        self.sc, self.fl, self.tank = sc, fluid(sc["fluid"]), Tank(sc["tank"])
        self.mech = {k: float(mech.get(k, 0.0)) for k in MECHANISMS}
        self.C_meta = float(sc["wall"]["C_w_J_per_K"])
        self.C_w = self.C_meta * (1.0 + self.mech["wall_heat_capacity_error"])
        if self.C_w <= 0:
            raise ValueError("wall_heat_capacity_error must be > -1")
        self.G_w = float(sc["wall"]["k_w_W_per_mK"]) * float(sc["wall"]["thickness_m"]) / (self.tank.H / 3.0)
        self.inputs = {c: 0.0 for c in INPUT_COLUMNS}
        self.h_vin, self.nfev, self._Tv = 0.0, 0, float(sc["initial"]["T_v_K"])
        self.y0 = self._initial()

    def _phi(self, A_wet: float) -> float:
        return 0.01 + 0.98 * A_wet / self.tank.A_wall

    def _initial(self) -> np.ndarray:
        fl, tk, ini = self.fl, self.tank, self.sc["initial"]
        p0, T_l, T_v, fill = (float(ini[k]) for k in ("p_Pa", "T_l_K", "T_v_K", "fill_ratio"))
        n = self.mech["helium_mol"]
        V_l = fill * tk.V
        V_v = tk.V - V_l
        p_f = p0 - n * RU * T_v / V_v
        if p_f < 0.3 * p0 or p_f < P_HARD_LOW:
            raise ValueError(f"helium_mol={n}: too little {fl.name} left in the ullage at p = {p0:.4g} Pa")
        v = fl.v_Tp(T_v, p_f)
        m_v, m_l = V_v / v, V_l * fl.rho_l(T_l)
        U_v = m_v * fl.vapour(T_v, v)[1] + 1.5 * RU * n * T_v
        phi = self._phi(tk.section(tk.level(V_l))[2])
        E_wet = phi * self.C_w * float(ini["T_wet_K"])
        E_dry = (1 - phi) * self.C_w * float(ini["T_dry_K"])
        return np.array([m_v, U_v, n, m_l, m_l * fl.c_l * (T_l - fl.T_nbp), E_wet, E_dry, TAU0_S, 0.0, 0.0])

    def recover(self, y: np.ndarray) -> dict[str, Any]:
        fl, tk = self.fl, self.tank
        m_v, U_v, n, m_l, U_l = (float(x) for x in y[:5])
        n = max(n, 0.0)
        if not (m_v > 0 and m_l > 0):
            raise SimulationError(f"non-positive mass (m_v={m_v:.4g}, m_l={m_l:.4g})")
        T_l = fl.T_nbp + U_l / (m_l * fl.c_l)
        rho_l = fl.rho_l(T_l)
        V_v = tk.V - m_l / rho_l
        if V_v <= 1e-4 * tk.V:
            raise SimulationError(f"ullage volume vanished (V_v={V_v:.4g} m3)")
        v = V_v / m_v
        T = self._Tv
        for _ in range(50):  # Newton on m_v u(T, v) + 1.5 n R T = U_v
            f0 = m_v * fl.vapour(T, v)[1] + 1.5 * RU * n * T - U_v
            dT = 1e-6 * T
            f1 = m_v * fl.vapour(T + dT, v)[1] + 1.5 * RU * n * (T + dT) - U_v
            step = -f0 * dT / (f1 - f0)
            step = max(-0.2 * T, min(0.2 * T, step))
            T += step
            if abs(step) < 1e-12 * T:
                break
        else:
            raise SimulationError(f"ullage temperature did not converge (T={T:.6g} K)")
        if not 0.5 * fl.T_nbp < T < 1000.0:
            raise SimulationError(f"ullage temperature out of range ({T:.4g} K)")
        self._Tv = T
        p_f, u_v, h_v = fl.vapour(T, v)
        p_he = n * RU * T / V_v
        lev = tk.level(tk.V - V_v)
        return {"m_v": m_v, "n": n, "m_l": m_l, "T_l": T_l, "rho_l": rho_l, "V_v": V_v, "v": v, "T_v": T,
                "p_f": p_f, "p_he": p_he, "p": p_f + p_he, "h_v": h_v, "level": lev, "fill": 1 - V_v / tk.V}

    def set_inputs(self, inputs: Mapping[str, float], p_now: float) -> None:
        self.inputs = {c: float(inputs.get(c, 0.0)) for c in INPUT_COLUMNS}
        i = self.inputs
        self.h_vin = self.fl.h_v_Tp(i["T_v_in_K"], i["p_v_in_Pa"] or p_now) if i["mdot_v_in_kg_s"] > 0 else 0.0

    def rhs(self, t: float, y: np.ndarray) -> np.ndarray:
        self.nfev += 1
        if self.nfev > 300_000:
            raise SimulationError(f"too many right-hand-side calls (t={t:.1f} s)")
        fl, tk, mech, inp = self.fl, self.tank, self.mech, self.inputs
        st = self.recover(y)
        m_v, n, m_l, T_l, rho_l = st["m_v"], st["n"], st["m_l"], st["T_l"], st["rho_l"]
        T_v, p, p_f, v = st["T_v"], st["p"], st["p_f"], st["v"]
        rho_v = 1.0 / v
        lev = st["level"]
        V_l, A_i, A_wet, dA_dh, P_c = tk.section(lev)
        A_i = max(A_i, 1e-6)
        phi = self._phi(A_wet)
        C_wet = phi * self.C_w
        T_wet, T_dry = float(y[5]) / C_wet, float(y[6]) / (self.C_w - C_wet)
        tau = max(float(y[7]), 1e-3)
        d = fl.d
        # saturation and enthalpies
        T_i = fl.T_sat(p_f)
        L_i = fl.L(T_i)
        h_vi = fl.h_v_Tp(T_i, p_f)
        h_ls = h_vi - L_i  # liquid-side enthalpy of the phase change (Watson)
        T_sp = fl.T_sat(p)
        h_l = fl.h_l(T_l, p)
        # sloshing intensity
        A0, fr = inp["slosh_amplitude_m"], inp["slosh_frequency_Hz"]
        E = A0 * (2 * math.pi * fr) ** 2 / G if A0 > 0 and fr > 0 else 0.0
        f_i, f_w = 1 + C_SLOSH_I * math.sqrt(E), 1 + C_SLOSH_W * math.sqrt(E)
        # gas and liquid transport groups (g beta / (nu alpha))
        a_v = d["k_v"] / (rho_v * fl.cp_v)
        gv = G / (0.5 * (T_v + T_i)) / (d["mu_v"] / rho_v * a_v)
        beta_l = -d["drho"] / rho_l
        a_l = d["k_l"] / (rho_l * fl.c_l)
        gl = G * beta_l / (d["mu_l"] / rho_l * a_l)

        def nu_wall(gg, dT, Lh):
            return 1.0 + 0.13 * (gg * math.sqrt(dT * dT + 1e-2) * Lh ** 3) ** (1 / 3)

        L_wet, L_dry = max(lev, 0.05), max(tk.H - lev, 0.05)
        Q_wl = f_w * nu_wall(gl, T_wet - T_l, L_wet) * d["k_l"] / L_wet * A_wet * (T_wet - T_l)
        Q_wv = f_w * nu_wall(gv, T_dry - T_v, L_dry) * d["k_v"] / L_dry * (tk.A_wall - A_wet) * (T_dry - T_v)
        # interface: gas side (stable 0.27 Ra^1/4, unstable 0.15 Ra^1/3), liquid side boundary layer
        Li = max(A_i / max(P_c, 1e-6), 0.02)
        dTv = T_v - T_i
        Ra = gv * math.sqrt(dTv * dTv + 1e-2) * Li ** 3
        ws = _blend(dTv)
        Nu = 0.5 + ws * 0.27 * Ra ** 0.25 + (1 - ws) * 0.15 * Ra ** (1 / 3)
        Q_vi = f_i * Nu * d["k_v"] / Li * A_i * dTv
        delta = 1.0 / math.sqrt(1.0 / (math.pi * a_l * tau) + 1.0 / (0.5 * V_l / A_i) ** 2)
        dTl = T_l - T_i
        Ra = gl * math.sqrt(dTl * dTl + 1e-2) * Li ** 3
        h_li = f_i * (d["k_l"] / delta + _blend(dTl) * 0.15 * Ra ** (1 / 3) * d["k_l"] / Li)
        Q_il = h_li * A_i * (T_i - T_l)
        J = (Q_vi - Q_il) / L_i
        # bulk phase change
        h_fl = fl.h_v_Tp(T_sp, p_f)
        J_fl = m_l * fl.c_l * _ramp(T_l - T_sp) / (FLASH_TAU_S * fl.L(T_sp))
        J_fog = (m_v * fl.cp_v + 2.5 * RU * n) * _ramp(T_i - T_v) / (FOG_TAU_S * L_i)
        # boundary flows (true values)
        b = mech["inflow_meter_bias"]
        m_vin, m_lin = (1 + b) * inp["mdot_v_in_kg_s"], (1 + b) * inp["mdot_l_in_kg_s"]
        h_lin = fl.h_l(inp["T_l_in_K"], p) if m_lin > 0 else 0.0
        m_out = inp["mdot_v_out_kg_s"] + mech["vapor_leak_kg_s"]
        w_f = m_v / (m_v + n * M_HE)
        out_f, out_n = w_f * m_out, (1 - w_f) * m_out / M_HE
        m_lout = inp["mdot_l_out_kg_s"] + mech["liquid_leak_kg_s"]
        Q_aw = inp["Q_aw_W"] + mech["heat_leak_wall_W"]
        a_wet = A_wet / tk.A_wall
        # balances
        md_v = m_vin - out_f + J + J_fl - J_fog
        md_l = m_lin - m_lout - J - J_fl + J_fog
        F_v = (m_vin * self.h_vin - out_f * st["h_v"] - out_n * 2.5 * RU * T_v - Q_vi + J * h_vi + J_fl * h_fl
               - J_fog * h_ls + Q_wv + mech["heat_leak_vapor_W"])
        F_l = (m_lin * h_lin - m_lout * h_l + Q_il - J * h_ls - J_fl * h_fl + J_fog * h_ls + Q_wl
               + mech["heat_leak_liquid_W"])
        s_l = -d["drho"] / rho_l ** 2  # d(1/rho)/dT
        Td_l = (F_l - h_l * md_l) / (m_l * (fl.c_l + p * s_l))
        Vd_l = md_l / rho_l + m_l * s_l * Td_l
        # wall: capacity follows the level, carried at the upwind node's temperature
        Cd = self.C_w * 0.98 * dA_dh / tk.A_wall * Vd_l / A_i
        T_up = T_dry if Cd > 0 else T_wet
        Q_c = self.G_w * P_c * (T_dry - T_wet)
        r_mix = math.sqrt(E) + C_MIX_FILL * m_lin / m_l
        dy = np.empty(self.NY)
        dy[0], dy[1], dy[2] = md_v, F_v + p * Vd_l, -out_n
        dy[3], dy[4] = md_l, F_l - p * Vd_l
        dy[5] = a_wet * Q_aw - Q_wl + Q_c + Cd * T_up
        dy[6] = (1 - a_wet) * Q_aw - Q_wv - Q_c - Cd * T_up
        dy[7] = 1.0 - r_mix * tau
        dy[8] = m_vin + m_lin - out_f - m_lout
        dy[9] = (Q_aw + mech["heat_leak_vapor_W"] + mech["heat_leak_liquid_W"] + m_vin * self.h_vin
                 + m_lin * h_lin - out_f * st["h_v"] - out_n * 2.5 * RU * T_v - m_lout * h_l)
        return dy

    def observe(self, y: np.ndarray) -> dict[str, float]:
        st = self.recover(y)
        phi = self._phi(self.tank.section(st["level"])[2])
        return {"p": st["p"], "p_f": st["p_f"], "p_he": st["p_he"], "T_v": st["T_v"], "T_l": st["T_l"],
                "T_w": float(y[5] + y[6]) / self.C_w, "T_wet": float(y[5]) / (phi * self.C_w),
                "T_dry": float(y[6]) / ((1 - phi) * self.C_w), "level": st["level"], "fill": st["fill"],
                "m_v": st["m_v"], "m_l": st["m_l"], "n_he": st["n"]}

    @staticmethod
    def totals(y: np.ndarray) -> tuple[float, float]:
        return float(y[0] + y[3]), float(y[1] + y[4] + y[5] + y[6])


# ----------------------------------------------------------------------------- scenarios
def _scenario(name: str, fl_name: str, tank: dict, material: str, t_w: float, q: float, fill: float,
              p0: float, subcool: float, superheat: float, dry_extra: float, phases: list) -> dict[str, Any]:
    fl, tk = fluid(fl_name), Tank(tank)
    T_s = fl.T_sat(p0)
    T_l, T_v = T_s - subcool, T_s + superheat
    T_dry = T_v + dry_extra
    a = tk.section(tk.level(fill * tk.V))[2] / tk.A_wall
    T_mean = a * T_l + (1 - a) * T_dry
    rho, c_tab, k_tab = MATERIALS[material]
    C_w = rho * t_w * tk.A_wall * float(np.interp(T_mean, T_TAB, c_tab))
    return {"name": name, "fluid": fl_name, "tank": {"shape": tank["shape"], **tk.dims()},
            "wall": {"material": material, "thickness_m": t_w, "C_w_J_per_K": C_w,
                     "k_w_W_per_mK": float(np.interp(T_mean, T_TAB, k_tab))},
            "Q_aw_W": q * tk.A_wall, "heat_flux_W_m2": q,
            "initial": {"p_Pa": p0, "T_l_K": T_l, "T_v_K": T_v, "T_wet_K": T_l + 0.05, "T_dry_K": T_dry,
                        "fill_ratio": fill},
            "phases": phases, "duration_s": float(sum(ph["duration_s"] for ph in phases))}


def _ph(kind: str, minutes: float, **kw) -> dict[str, Any]:
    return {"kind": kind, "duration_s": 60.0 * minutes, **kw}


def _lh2_upright(f):
    return _scenario("lh2_upright", f or "ParaHydrogen", tank_of_volume("vertical_cylinder_elliptical_heads", 6.0, 1.0),
                     "steel", 0.006, 10.0, 0.6, 1.6e5, 0.3, 3.0, 3.0,
                     [_ph("rest", 15), _ph("pressurize", 10, dp_frac=0.5, T_in_factor=2.0), _ph("rest", 15),
                      _ph("vent", 10, p_frac=0.7), _ph("slosh", 15, amp_m=0.01, freq_ratio=0.9), _ph("rest", 10)])


def _ln2_hcyl(f):
    return _scenario("ln2_hcyl", f or "Nitrogen", tank_of_volume("horizontal_cylinder", 12.0, 2.5), "steel", 0.008,
                     8.0, 0.7, 2.5e5, 1.0, 4.0, 3.0,
                     [_ph("drain", 15, dfill=0.25), _ph("rest", 15), _ph("fill", 15, dfill=0.2, subcool_K=3.0),
                      _ph("vent", 10, p_frac=0.75), _ph("rest", 10)])


def _lch4_sphere(f):
    return _scenario("lch4_sphere", f or "Methane", tank_of_volume("sphere", 25.0, 1.0), "aluminium", 0.01, 15.0,
                     0.5, 2.0e5, 0.5, 5.0, 2.0,
                     [_ph("rest", 25), _ph("vent", 10, p_frac=0.7), _ph("slosh", 20, amp_m=0.02, freq_ratio=1.0),
                      _ph("rest", 10)])


def _lh2_small(f):
    return _scenario("lh2_small", f or "Hydrogen", tank_of_volume("vertical_cylinder", 1.5, 1.2), "steel", 0.004,
                     20.0, 0.75, 1.3e5, 0.2, 2.0, 2.0,
                     [_ph("rest", 20), _ph("drain", 10, dfill=0.3), _ph("rest", 10),
                      _ph("fill", 10, dfill=0.15, subcool_K=1.0), _ph("rest", 10)])


NAMED_SCENARIOS = {
    "lh2_upright": ("ParaHydrogen, 6 m3 vertical cylinder with 2:1 heads: heat load, warm-gas pressurisation, "
                    "hold, vent, sloshing", _lh2_upright),
    "ln2_hcyl": ("Nitrogen, 12 m3 horizontal cylinder: drain, hold, fill, vent", _ln2_hcyl),
    "lch4_sphere": ("Methane, 25 m3 sphere: self-pressurisation, vent, sloshing", _lch4_sphere),
    "lh2_small": ("Hydrogen, 1.5 m3 flat vertical cylinder: self-pressurisation, drain, top-up", _lh2_small),
}


def _draw_phase(kind: str, dur: float, rng: np.random.Generator) -> dict[str, Any]:
    ph: dict[str, Any] = {"kind": kind, "duration_s": dur}
    if kind == "pressurize":
        ph.update(dp_frac=float(rng.uniform(0.15, 0.5)), T_in_factor=float(rng.uniform(1.3, 2.5)))
    elif kind == "vent":
        ph.update(p_frac=float(rng.uniform(0.6, 0.85)))
    elif kind == "fill":
        ph.update(dfill=float(rng.uniform(0.05, 0.25)), subcool_K=float(rng.uniform(0.0, 3.0)))
    elif kind == "drain":
        ph.update(dfill=float(rng.uniform(0.05, 0.3)))
    elif kind == "slosh":
        ph.update(amp_m=float(rng.uniform(0.002, 0.02)), freq_ratio=float(rng.uniform(0.6, 1.4)))
    return ph


def random_scenario(seed: int, fluid_name: str | None = None, ops: Sequence[str] | None = None,
                    phase_s: float | None = None) -> dict[str, Any]:
    """A random plausible tank and schedule, deterministic in ``seed``; ``ops`` (with ``phase_s``
    seconds each) fixes the phase kinds."""
    rng = np.random.default_rng([int(seed), 7177])
    fl_name = str(rng.choice(FLUIDS))
    fl_name = fluid_name or fl_name
    shape = str(rng.choice(SHAPES))
    V = math.exp(rng.uniform(math.log(0.5), math.log(40.0)))
    aspect = 1.0 if shape == "sphere" else float(rng.uniform(0.6, 2.5) if shape != "horizontal_cylinder"
                                                 else rng.uniform(1.5, 4.0))
    material = "steel" if rng.random() < 0.6 else "aluminium"
    t_w = float(rng.uniform(0.003, 0.015))
    q = float(rng.uniform(5.0, 40.0))
    fill = float(rng.uniform(0.2, 0.85))
    hyd = "ydrogen" in fl_name
    p0 = float(rng.uniform(1.0e5, 4.0e5) if hyd else rng.uniform(1.2e5, 5.0e5))
    subcool = float(rng.uniform(0.0, 0.1) if rng.random() < 0.3 else rng.uniform(0.2, 2.0))
    superheat, dry_extra = float(rng.uniform(0.5, 8.0)), float(rng.uniform(0.0, 4.0))
    if ops is None:
        n = int(rng.integers(4, 8))
        total = float(rng.uniform(3600.0, 7200.0))
        w = rng.dirichlet(np.full(n, 4.0))
        durs = [max(300.0, 10.0 * round(total * x / 10.0)) for x in w]
        p = np.array([0.22, 0.16, 0.18, 0.14, 0.14, 0.16])
        kinds = [str(k) for k in rng.choice(OPERATIONS, size=n, p=p / p.sum())]
    else:
        kinds = [str(k) for k in ops]
        if set(kinds) - set(OPERATIONS):
            raise ValueError(f"unknown operations {sorted(set(kinds) - set(OPERATIONS))}; known: {OPERATIONS}")
        durs = [float(phase_s or 300.0)] * len(kinds)
    phases = [_draw_phase(k, dd, rng) for k, dd in zip(kinds, durs)]
    return _scenario(f"random_{seed}", fl_name, tank_of_volume(shape, V, aspect), material, t_w, q, fill, p0,
                     subcool, superheat, dry_extra, phases)


def resolve_scenario(scenario: str | Mapping[str, Any], fluid_name: str | None = None) -> dict[str, Any]:
    if isinstance(scenario, Mapping):
        return copy.deepcopy(dict(scenario))
    if scenario.startswith("random_"):
        try:
            seed = int(scenario[7:])
        except ValueError:
            raise ValueError(f"random scenarios are named random_SEED, got {scenario!r}") from None
        return random_scenario(seed, fluid_name)
    if scenario not in NAMED_SCENARIOS:
        raise ValueError(f"unknown scenario {scenario!r}; known: {', '.join(NAMED_SCENARIOS)}, random_SEED")
    if fluid_name is not None and fluid_name not in FLUID_DATA:
        raise ValueError(f"unknown fluid {fluid_name!r}; known: {', '.join(FLUIDS)}")
    return NAMED_SCENARIOS[scenario][1](fluid_name)


# ----------------------------------------------------------------------------- operator and integration
def _plan(model: Model, y: np.ndarray, ph: Mapping[str, Any], dur: float) -> dict[str, float]:
    """Metered inputs of a phase from the (nominal) state at its start."""
    fl, tk = model.fl, model.tank
    inp = {c: 0.0 for c in INPUT_COLUMNS}
    inp["Q_aw_W"] = float(model.sc["Q_aw_W"])
    st = model.recover(y)
    p, T_v, V_v, kind = st["p"], st["T_v"], st["V_v"], ph["kind"]
    if kind == "pressurize":
        p1 = min(p * (1 + ph["dp_frac"]), 0.85 * fl.p_max)
        if p1 > 1.02 * p:
            T_in = min(ph["T_in_factor"] * fl.T_sat(p), 60.0 if "ydrogen" in fl.name else 300.0)
            gamma = fl.cp_v / fl.cv
            dm = 1.4 * (p1 - p) * V_v / (gamma * fl.Rs * T_in)
            inp.update(mdot_v_in_kg_s=dm / dur, T_v_in_K=T_in, p_v_in_Pa=1.3 * p1)
    elif kind == "vent":
        p1 = max(p * ph["p_frac"], 1.2 * P_LOW)
        if p1 < 0.97 * p:
            gamma = fl.cp_v / fl.cv
            dm = V_v / st["v"] * (1 - (p1 / p) ** (1 / gamma))
            T1 = fl.T_sat(p1)
            dm += st["m_l"] * fl.c_l * max(st["T_l"] - T1, 0.0) / fl.L(T1)
            inp["mdot_v_out_kg_s"] = dm * (1 + st["n"] * M_HE / st["m_v"]) / dur
    elif kind == "fill":
        dfill = min(ph["dfill"], 0.88 - st["fill"])
        if dfill > 0.01 and p < 0.85 * fl.p_max:
            T_in = fl.T_sat(p) - ph["subcool_K"]
            inp.update(mdot_l_in_kg_s=fl.rho_l(T_in) * dfill * tk.V / dur, T_l_in_K=T_in)
    elif kind == "drain":
        dfill = min(ph["dfill"], st["fill"] - 0.1)
        if dfill > 0.01:
            inp["mdot_l_out_kg_s"] = st["rho_l"] * dfill * tk.V / dur
    elif kind == "slosh":
        inp.update(slosh_amplitude_m=ph["amp_m"], slosh_frequency_Hz=ph["freq_ratio"] * tk.omega1(st["level"])
                   / (2 * math.pi))
    elif kind != "rest":
        raise ValueError(f"unknown phase kind {kind!r}")
    return inp


def _events(model: Model, thr: Mapping[str, float]) -> tuple[list, list]:
    fl = model.fl

    def make(name, fn, direction):
        def ev(t, y):
            return fn(model.recover(y))
        ev.terminal, ev.direction = True, direction
        return name, ev

    pairs = []
    for name, val in thr.items():
        key = "p" if name.startswith("p_") else "fill"
        pairs.append(make(name, lambda s, k=key, v=val: s[k] - v, 1 if name.endswith("high") else -1))
    pairs.append(make("hard_p_high", lambda s: s["p_f"] - 0.75 * fl.pc, 1))
    pairs.append(make("hard_p_low", lambda s: s["p_f"] - P_HARD_LOW, -1))
    pairs.append(make("hard_fill", lambda s: min(s["fill"] - 0.01, 0.985 - s["fill"]), -1))
    return [p[0] for p in pairs], [p[1] for p in pairs]


def _integrate(model: Model, duration: float, plan: list[dict], replay: bool) -> dict[str, Any]:
    fl = model.fl
    y = model.y0.copy()
    m0 = float(y[0] + y[3])
    sU = m0 * fl.L_nbp
    atol = np.array([1e-10 * m0, 1e-10 * sU, 1e-9 * max(float(y[2]), 1e-3), 1e-10 * m0, 1e-10 * sU,
                     1e-9 * model.C_w * 30, 1e-9 * model.C_w * 30, 1e-3, 1e-8 * m0, 1e-8 * sU])
    samples = np.arange(0.0, duration + 1e-9, SAMPLE_DT_S)
    ys: dict[float, np.ndarray] = {}
    executed, changes = [], []
    t = 0.0
    for seg in plan:
        t_end = min(seg["t1"], duration)
        if t_end <= t + 1e-9:
            continue
        inputs = dict(seg["inputs"]) if replay else _plan(model, y, seg["phase"], t_end - t)
        kind = seg["kind"] if replay else seg["phase"]["kind"]
        st = model.recover(y)  # soft bounds, armed beyond the current state
        thr = {"p_high": max(0.95 * fl.p_max, 1.01 * st["p"]), "p_low": min(P_LOW, 0.98 * st["p"]),
               "fill_high": max(0.95, st["fill"] + 0.005), "fill_low": min(0.05, st["fill"] - 0.005)}
        for _ in range(60):
            if t >= t_end - 1e-9:
                break
            model.set_inputs(inputs, model.recover(y)["p"])
            names, evs = _events(model, thr)
            t_eval = [s for s in samples if t - 1e-9 <= s < t_end - 1e-9] + [t_end]
            try:
                sol = solve_ivp(model.rhs, (t, t_end), y, method="LSODA", t_eval=t_eval, events=evs, rtol=RTOL,
                                atol=atol, max_step=60.0)
            except SimulationError as e:
                raise SimulationError(f"{e} (segment from t={t:.1f} s, {kind})") from None
            if sol.status == -1:
                raise SimulationError(f"integration failed at t={sol.t[-1]:.1f} s ({kind}): {sol.message}")
            for k, tk_ in enumerate(sol.t):
                if tk_ < t_end - 1e-9 or abs(tk_ - duration) < 1e-9:
                    ys[float(tk_)] = sol.y[:, k].copy()
            if sol.status == 0:
                executed.append({"t0": t, "t1": t_end, "kind": kind, "inputs": dict(inputs)})
                y, t = sol.y[:, -1].copy(), t_end
                break
            k_ev = next(i for i, te in enumerate(sol.t_events) if te.size)
            te, y, name = float(sol.t_events[k_ev][0]), sol.y_events[k_ev][0].copy(), names[k_ev]
            st = model.recover(y)
            if name.startswith("hard"):
                raise SimulationError(f"left the model's range at t={te:.1f} s ({name}: p={st['p']:.5g} Pa, "
                                      f"fill={st['fill']:.3f}, phase {kind})")
            if te > t + 1e-9:
                executed.append({"t0": t, "t1": te, "kind": kind, "inputs": dict(inputs)})
            new, action = dict(inputs), "none"
            if name == "p_high":
                if new["mdot_v_in_kg_s"] > 0 or new["mdot_l_in_kg_s"] > 0:
                    new.update(mdot_v_in_kg_s=0.0, T_v_in_K=0.0, p_v_in_Pa=0.0, mdot_l_in_kg_s=0.0, T_l_in_K=0.0)
                    action = "stopped the inflows"
                else:
                    relief = 0.02 * (st["m_v"] + st["n"] * M_HE) / 60.0
                    new["mdot_v_out_kg_s"] = max(2.0 * new["mdot_v_out_kg_s"], relief)
                    action = f"relief vent {new['mdot_v_out_kg_s']:.4g} kg/s"
                thr["p_high"] = 1.01 * st["p"]
            elif name == "p_low":
                if new["mdot_v_out_kg_s"] > 0 or new["mdot_l_out_kg_s"] > 0:
                    new.update(mdot_v_out_kg_s=0.0, mdot_l_out_kg_s=0.0)
                    action = "stopped the vent/drain"
                    thr["p_low"] = 0.98 * st["p"]
                else:
                    thr.pop("p_low")
            elif name == "fill_high":
                if new["mdot_l_in_kg_s"] > 0:
                    new.update(mdot_l_in_kg_s=0.0, T_l_in_K=0.0)
                    action = "stopped the fill"
                thr.pop("fill_high")
            else:
                if new["mdot_l_out_kg_s"] > 0:
                    new["mdot_l_out_kg_s"] = 0.0
                    action = "stopped the drain"
                thr.pop("fill_low")
            changes.append({"t_s": te, "event": name, "action": action})
            inputs, t = new, te
        else:
            raise SimulationError(f"too many bound events in the phase ending at {t_end:.1f} s")
    return {"ys": ys, "executed": executed, "changes": changes}


def _check_mechanisms(mech: Mapping[str, float] | None) -> dict[str, float]:
    out = {k: float(v) for k, v in (mech or {}).items()}
    bad = sorted(set(out) - set(MECHANISMS))
    if bad:
        raise ValueError(f"unknown mechanisms {bad}; known: {', '.join(MECHANISMS)}")
    for k in ("vapor_leak_kg_s", "liquid_leak_kg_s", "helium_mol"):
        if out.get(k, 0.0) < 0:
            raise ValueError(f"{k} must be >= 0")
    if out.get("inflow_meter_bias", 0.0) <= -1:
        raise ValueError("inflow_meter_bias must be > -1")
    return out


def simulate(scenario: str | Mapping[str, Any], mechanisms: Mapping[str, float] | None = None, *,
             fluid_name: str | None = None, duration_s: float | None = None) -> dict[str, Any]:
    """Noise-free truth: scenario, executed schedule, sampled states, closure."""
    w0 = time.perf_counter()
    sc = resolve_scenario(scenario, fluid_name)
    mech = _check_mechanisms(mechanisms)
    duration = float(duration_s if duration_s is not None else sc["duration_s"])
    if duration <= 0:
        raise ValueError("duration must be > 0")
    plan, t0 = [], 0.0
    for ph in sc["phases"]:
        plan.append({"t1": t0 + ph["duration_s"], "phase": ph})
        t0 += ph["duration_s"]
    if t0 < duration:
        plan.append({"t1": duration, "phase": {"kind": "rest", "duration_s": duration - t0}})
    model = Model(sc, {})
    res = _integrate(model, duration, plan, False)
    nfev = model.nfev
    if any(v != 0.0 for v in mech.values()):
        model = Model(sc, mech)
        res = _integrate(model, duration, res["executed"], True)
        nfev += model.nfev
    times = np.array(sorted(res["ys"]))
    Y = np.array([res["ys"][t] for t in times])
    obs = [model.observe(y) for y in Y]
    M0, E0 = model.totals(model.y0)
    err_m = np.array([model.totals(y)[0] - M0 - y[8] for y in Y])
    err_e = np.array([model.totals(y)[1] - E0 - y[9] for y in Y])
    moved = sum((s["t1"] - s["t0"]) * sum(s["inputs"][c] for c in ("mdot_v_in_kg_s", "mdot_v_out_kg_s",
                                                                   "mdot_l_in_kg_s", "mdot_l_out_kg_s"))
                for s in res["executed"])
    heat = sum((s["t1"] - s["t0"]) * abs(s["inputs"]["Q_aw_W"]) for s in res["executed"])
    scale_m, scale_e = M0 + moved, heat + (moved + 0.01 * M0) * model.fl.L_nbp
    return {"scenario": sc, "mechanisms": mech, "model": model, "times": times, "Y": Y, "obs": obs,
            "executed": res["executed"], "changes": res["changes"], "duration_s": duration, "nfev": nfev,
            "closure": {"mass_kg_max_abs": float(np.max(np.abs(err_m))), "mass_rel": float(np.max(np.abs(err_m))
                                                                                          / scale_m),
                        "energy_J_max_abs": float(np.max(np.abs(err_e))),
                        "energy_rel": float(np.max(np.abs(err_e)) / scale_e), "mass_scale_kg": scale_m,
                        "energy_scale_J": scale_e},
            "wall_time_s": time.perf_counter() - w0}


def simulate_run(scenario: str | Mapping[str, Any], mechanisms: Mapping[str, float] | None = None,
                 noise: str = "low", seed: int = 0, out_dir: str | pathlib.Path = ".", name: str | None = None,
                 fluid_name: str | None = None, duration_s: float | None = None) -> dict[str, pathlib.Path]:
    """Simulate and write ``NAME.json``, ``NAME.csv``, ``NAME.truth.json``; returns their paths."""
    if noise not in ("none", "low", "high"):
        raise ValueError(f"noise must be none, low or high, got {noise!r}")
    res = simulate(scenario, mechanisms, fluid_name=fluid_name, duration_s=duration_s)
    sc, model, mech, obs, times = res["scenario"], res["model"], res["mechanisms"], res["obs"], res["times"]
    std = NOISE_LEVELS["low" if noise == "none" else noise]
    rng = np.random.default_rng(seed)
    bp, bT = mech.get("pressure_sensor_bias_Pa", 0.0), mech.get("temperature_sensor_bias_K", 0.0)
    true = {"p_v_Pa": [o["p"] + bp for o in obs], "T_v_K": [o["T_v"] for o in obs],
            "T_l_K": [o["T_l"] + bT for o in obs], "T_w_K": [o["T_w"] for o in obs],
            "H_l_m": [o["level"] for o in obs]}
    meas: dict[str, dict[float, float]] = {}
    for ch, key in zip(OBS_COLUMNS, NOISE_KEYS):
        dt = SAMPLE_DT_WALL_S if ch == "T_w_K" else SAMPLE_DT_S
        sel = [i for i, t in enumerate(times) if abs(t / dt - round(t / dt)) < 1e-9]
        vals = np.array([true[ch][i] for i in sel])
        if noise != "none":
            vals = vals + rng.normal(0.0, std[key], size=vals.size)
        if ch == "H_l_m":
            vals = np.maximum(vals, 0.0)
        meas[ch] = {float(times[i]): float(v) for i, v in zip(sel, vals)}
    ex = res["executed"]
    used = [c for c in INPUT_COLUMNS if any(s["inputs"][c] != 0.0 for s in ex)]
    rows_t = sorted(set(times.tolist()) | {float(s["t0"]) for s in ex})
    run = name or f"eng_{sc['name']}"
    out = pathlib.Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    csv_path = out / f"{run}.csv"
    with open(csv_path, "w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(["t_s", *OBS_COLUMNS, *used])
        k = 0
        for t in rows_t:
            while k + 1 < len(ex) and ex[k + 1]["t0"] <= t + 1e-12:
                k += 1
            cells = [repr(float(t))] + ["" if meas[ch].get(t) is None else repr(meas[ch][t]) for ch in OBS_COLUMNS]
            w.writerow(cells + [repr(float(ex[k]["inputs"][c])) for c in used])
    o0, o1 = obs[0], obs[-1]
    meta = {"name": run, "fluid": sc["fluid"],
            "source": f"{SIMULATOR}: independent 0D tank simulator with an engineering property model "
                      f"(Antoine/Watson/virial, no CoolProp), scenario {sc['name']}",
            "tank": {**sc["tank"], "volume_m3": model.tank.V, "wall_heat_capacity_J_per_K": model.C_meta},
            "initial": {"p_v_Pa": o0["p"] + bp, "T_v_K": o0["T_v"], "T_l_K": o0["T_l"] + bT, "T_w_K": o0["T_w"],
                        "fill_ratio": o0["fill"]},
            "noise_std": {k: std[k] for k in NOISE_KEYS}, "duration_s": res["duration_s"],
            "timeseries": csv_path.name}
    json_path = out / f"{run}.json"
    json_path.write_text(json.dumps(meta, indent=2) + "\n")

    def state(o):
        return {"p_Pa": o["p"], "p_fluid_Pa": o["p_f"], "p_helium_Pa": o["p_he"], "T_v_K": o["T_v"],
                "T_l_K": o["T_l"], "T_w_K": o["T_w"], "T_wet_K": o["T_wet"], "T_dry_K": o["T_dry"],
                "fill_ratio": o["fill"], "level_m": o["level"], "m_v_kg": o["m_v"], "m_l_kg": o["m_l"],
                "helium_mol": o["n_he"]}

    summ = {k: {"min": min(o[k] for o in obs), "max": max(o[k] for o in obs), "final": o1[k]}
            for k in ("p", "T_v", "T_l", "T_w", "level", "fill", "p_he")}
    truth = {"simulator": SIMULATOR, "property_model": {"kind": "engineering (Antoine, Watson, linear rho_l, "
                                                                "constant c_l, second-virial vapour)",
                                                        **{k: v for k, v in FLUID_DATA[sc["fluid"]].items()}},
             "scenario": sc, "mechanisms": {k: mech.get(k, 0.0) for k in MECHANISMS}, "noise": noise, "seed": seed,
             "wall_heat_capacity_true_J_per_K": model.C_w, "wall_heat_capacity_metadata_J_per_K": model.C_meta,
             "initial_true": state(o0), "final_true": state(o1), "summary": summ,
             "schedule": [{"t0_s": s["t0"], "t1_s": s["t1"], "kind": s["kind"],
                           "inputs": {c: v for c, v in s["inputs"].items() if v != 0.0}} for s in ex],
             "schedule_changes": res["changes"], "closure": res["closure"], "rhs_calls": res["nfev"],
             "wall_time_s": res["wall_time_s"]}
    truth_path = out / f"{run}.truth.json"
    truth_path.write_text(json.dumps(truth, indent=2) + "\n")
    return {"json": json_path, "csv": csv_path, "truth": truth_path}


# ----------------------------------------------------------------------------- command line
def _mechanism_arg(text: str) -> tuple[str, float]:
    k, sep, v = text.partition("=")
    if not sep or k not in MECHANISMS:
        raise argparse.ArgumentTypeError(f"--mechanism needs NAME=VALUE with NAME in {', '.join(MECHANISMS)}")
    try:
        return k, float(v)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--mechanism {k}: {v!r} is not a number") from None


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="Engineering-property 0D tank simulator (no CoolProp): writes runs "
                                             "in the interchange format (NAME.json, NAME.csv, NAME.truth.json).")
    ap.add_argument("scenario", nargs="?", help="a named scenario (see --list) or random_SEED")
    ap.add_argument("--list", action="store_true", help="list scenarios, mechanisms and fluids, and exit")
    ap.add_argument("--fluid", help=f"fluid (CoolProp name), one of {', '.join(FLUIDS)}")
    ap.add_argument("--mechanism", action="append", default=[], type=_mechanism_arg, metavar="NAME=VALUE")
    ap.add_argument("--noise", default="low", choices=("none", "low", "high"))
    ap.add_argument("--seed", type=int, default=0, help="seed of the sensor noise")
    ap.add_argument("--out", default=".", help="output folder")
    ap.add_argument("--name", help="run name (default eng_SCENARIO)")
    ap.add_argument("--duration", type=float, help="duration [s]")
    args = ap.parse_args(argv)
    if args.list:
        for k, (desc, _) in NAMED_SCENARIOS.items():
            print(f"{k:12s} {desc}")
        print(f"{'random_SEED':12s} a random plausible tank and schedule (fluid among {', '.join(FLUIDS)})")
        print("mechanisms: " + ", ".join(MECHANISMS))
        return 0
    if not args.scenario:
        ap.error("SCENARIO is required (or --list)")
    try:
        paths = simulate_run(args.scenario, dict(args.mechanism), noise=args.noise, seed=args.seed,
                             out_dir=args.out, name=args.name, fluid_name=args.fluid, duration_s=args.duration)
    except (ValueError, SimulationError) as e:
        print(f"eng_sim: error: {e}", file=sys.stderr)
        return 2
    tr = json.loads(paths["truth"].read_text())
    s, c = tr["summary"], tr["closure"]
    print(f"wrote {paths['json']} ({tr['scenario']['fluid']}, {tr['wall_time_s']:.2f} s, {tr['rhs_calls']} rhs "
          f"calls; p {s['p']['min']:.0f}..{s['p']['max']:.0f} Pa, fill {s['fill']['min']:.3f}..{s['fill']['max']:.3f}"
          f"; closure mass {c['mass_rel']:.1e}, energy {c['energy_rel']:.1e})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
