"""Independent 0D simulator of a cryogenic storage tank, for any CoolProp pure fluid.

``cryo_sim`` writes synthetic "measured" runs in the project's interchange format
(``shared/data-format.md``: ``NAME.json`` + ``NAME.csv``) plus a truth sidecar
(``NAME.truth.json``). It exists to test tankode *blindly*: it shares **no code** with
``tankode`` (nor with ``tests/nodal_sim.py`` or ``tests/independent_sim.py``); its
formulation, heat-transfer laws, geometry, numerics and writer are its own, and it handles
fluids other than hydrogen (at least ``ParaHydrogen``, ``Nitrogen``, ``Methane``,
``Oxygen`` and ``Argon``; any CoolProp pure fluid whose triple-point pressure is below
0.95 atm, e.g. also ``Hydrogen``, ``Neon``, ``CarbonMonoxide``, ``Ethane``, ``Krypton``).

Control volumes and state (all SI)
----------------------------------
``y = (m_v, U_v, n_He, m_s, U_s, m_b, U_b, E_wet, E_dry, C_wet, M_bnd, N_bnd, E_bnd)``:

* ullage: fluid mass ``m_v``, internal energy ``U_v`` of the whole gas (fluid + helium),
  helium amount ``n_He`` [mol] (ideal monatomic gas, ``c_v = 3/2 R``, at the ullage
  temperature; Dalton's law: the fluid sees its partial pressure ``p_f``);
* liquid: a thin *surface layer* (``m_s, U_s``; its mass is relaxed to ``SURFACE_FRACTION``
  = 3 % of the liquid mass with a 20 s time constant, so its thickness is a fixed fraction of
  the liquid depth; the re-gridding mass carries the upwind layer's enthalpy) over a well-mixed
  *bulk* (``m_b, U_b``);
* wall: a wetted node and a dry node with energies ``E = C T``; the wetted capacity ``C_wet``
  is a state relaxed (10 s) towards ``C_w (0.02 + 0.96 A_wet / A_wall)``: capacity that
  moves between the nodes carries the donor node's temperature (smoothly upwinded), so the
  wall energy is conserved exactly while its split follows the level;
* ``M_bnd, N_bnd, E_bnd``: quadratures of what crossed the tank boundary (fluid mass,
  helium, energy). They do not feed back; they give the closure check.

Every right-hand-side call recovers the thermodynamic state algebraically: the unknowns
``(p, T_v)`` and, for each liquid volume, ``(T, rho)`` solve ``u_l(T, rho) = U/m``,
``p_l(T, rho) = p``, ``m_v u_v(T_v, rho_v) + n c_v,He T_v = U_v``,
``p_f(T_v, rho_v) + n R T_v / V_v = p`` with ``V_v = V - m_s/rho_s - m_b/rho_b``
(nested Newton, warm-started, converged to round-off). The equation of state is CoolProp
HEOS evaluated through the low-level ``AbstractState`` with ``(rho, T)`` inputs and the
phase *imposed* (explicit Helmholtz energy, no flash; metastable superheated liquid and
subcooled vapour are single-phase states), so the reported temperatures are exactly those
of the equation of state at the integrated mass and energy. Saturation properties
(``T_sat(p)``, ``h_l,sat``, ``h_v,sat``, surface tension) and saturated-liquid transport
properties are pre-tabulated at start-up as cubic splines (in ``ln p`` and ``T``); vapour
transport properties come from CoolProp at the film temperature. For fluids without a CoolProp
transport model (e.g. Neon, CarbonMonoxide) viscosity and conductivity come from one-parameter
corresponding states with argon (``mu Tc^(1/6) M^(-1/2) Pc^(-2/3)`` and
``k Tc^(1/6) M^(1/2) Pc^(-2/3)`` as functions of ``T/Tc`` and ``rho/rho_c``; about 10-15 %
for liquid neon and carbon monoxide); the truth file names the source. The ``p dV`` work between
the ullage and each liquid volume follows from a small linear system (rigid tank:
``dV_v + dV_s + dV_b = 0``) built from the same EOS derivatives; it enters the volumes
with opposite signs, so the total energy changes only by the boundary terms.

Interface and phase change
--------------------------
* Interface at ``T_i = T_sat(p_f)`` (fluid partial pressure). ``Q_vi = h_vi A_i (T_v - T_i)``,
  ``Q_li = h_li A_i (T_s - T_i)``, ``J = (Q_vi + Q_li) / (h_v,sat - h_l,sat)`` evaporates
  from the surface layer (``J < 0`` condenses into it).
* Bulk boiling / flashing: a liquid volume superheated above ``T_sat(p)`` (total pressure)
  releases vapour at ``h_v,sat(p)`` at ``m c_p r(T - T_sat) / (tau_flash L)``,
  ``tau_flash = 40 s``; a subcooled ullage condenses fog at ``(m_v c_p,v + n c_p,He)
  r(T_i - T_v) / (tau_fog L)``, ``tau_fog = 25 s``, the droplets (``h_l,sat``) rain into the
  surface layer. ``r`` is a C1 ramp (quadratic up to 0.02 K).
* Nucleate boiling on the wetted wall when ``T_wet > T_sat(p) + 1 K`` (smooth switch over
  0.5 K): Rohsenow (1952) ``q = mu_l L sqrt(g (rho_l - rho_v) / sigma)
  (c_p,l dT / (C_sf L Pr_l^1.7))^3``, ``C_sf = 0.013``, capped smoothly by Zuber's critical
  heat flux; the vapour (``h_v,sat(p)``) goes to the ullage, the liquid loses its own
  enthalpy.

Heat-transfer laws (this module's own choices)
----------------------------------------------
Properties at the film temperature (liquid: saturated-liquid splines; vapour: CoolProp at
the ullage partial pressure, helium ignored in transport). ``|dT|`` in Rayleigh numbers is
regularised as ``sqrt(dT^2 + (0.02 K)^2)``; stable/unstable switches are ``tanh`` blends.

* Wall-liquid and wall-vapour, vertical surfaces: Churchill & Chu (1975), all Rayleigh
  numbers, ``Nu_L = (0.825 + 0.387 Ra_L^(1/6) / (1 + (0.492/Pr)^(9/16))^(8/27))^2`` with
  ``L`` the wetted height (the level) or the dry height (``H - level``). Curved walls
  (heads, spheres, horizontal cylinders) are treated as vertical with that length. The flat
  bottom/top of a ``vertical_cylinder`` use horizontal-plate laws (McAdams/Lloyd-Moran:
  unstable ``0.54 Ra^(1/4)`` / ``0.15 Ra^(1/3)``, stable ``0.27 Ra^(1/4)``, ``L = R/2``).
  Of the wall-to-liquid heat from a warmer wall, 40 % is deposited in the surface layer (the
  rising boundary layer), the rest in the bulk.
* Liquid side of the interface: Globe & Dropkin (1959), ``Nu = 0.069 Ra^(1/3) Pr^0.074``
  (``L = sqrt(4 A_i / pi)``) when the surface layer is warmer than the interface (cooled
  from above: unstable), plus conduction ``2 k / delta_s`` over half the layer thickness.
* Vapour side of the interface: natural convection with the tank diameter ``D``:
  ``Nu_D = 0.27 Ra_D^(1/4)`` (warm gas over a cold surface: stable) or ``0.15 Ra_D^(1/3)``
  (unstable), plus ``Nu = 1`` conduction.
* Surface layer - bulk: conduction ``2 k / delta_s`` plus Globe-Dropkin when the layer is
  colder than the bulk (overturning).
* Sloshing (lateral excitation ``A0``, ``f``; ``omega = 2 pi f``): every interface and
  layer coefficient is multiplied by ``1 + 4e-3 S`` and the wall coefficients by
  ``1 + 1e-3 S`` with ``S = (A0 omega D / nu)^(1/2) g(omega / omega_1)``,
  ``g(r) = r^2 / sqrt((1 - r^2)^2 + (2 zeta r)^2)``, ``zeta = 0.08`` (forced linear
  oscillator: no relative motion at low frequency, resonance at the first mode, tank
  moving under a still liquid at high frequency). First mode: upright cylinder
  ``omega_1^2 = 1.841 g / R tanh(1.841 h / R)`` (Abramson, NASA SP-106, 1966) with the
  equivalent depth ``h = V_l / (pi R^2)``; sphere: the same with ``R_eq = sqrt(A_i/pi)``,
  ``h = V_l / A_i``; horizontal cylinder (transverse): rectangular basin
  ``omega_1^2 = (pi g / w) tanh(pi d / w)`` with the free-surface width ``w`` and
  ``d = V_l / A_i``.
* Wall conduction between the nodes: ``G = k_w t_w P / L_c`` (``P`` the contact-line
  length at the level, ``L_c`` half the height, or ``pi R / 2`` around a horizontal cylinder
  or a sphere); ``t_w`` and ``k_w`` from the wall material (steel or aluminium, rough
  cryogenic values).
* Ambient heat ``Q_aw`` (plus a hidden wall heat leak) enters the wall, split between the
  wetted and dry nodes by area.

Operations and hidden mechanisms
--------------------------------
Vapour injection at ``h(p_v_in, T_v_in)`` into the ullage; venting of ullage gas at ullage
conditions (the metered flow is the mixture's mass; helium leaves in proportion to its mass
fraction); liquid fill at ``h(p, T_l_in)`` into the bulk (CoolProp at the segment's initial
pressure, then ``(dh/dp)_T = (1 - T beta)/rho`` for the pressure change during the segment);
drain from the bulk; sloshing; ``Q_aw``. Hidden mechanisms (:data:`MECHANISMS`, 0 = absent,
the CSV holds what the operator *thinks* happened): heat leaks into the liquid (bulk), the
vapour or the wall; unmetered vapour/liquid leaks; an inflow meter bias (true inflows =
``(1 + b)`` x metered); pressure and liquid-temperature sensor biases; helium in the ullage
(the metadata's initial pressure is the total pressure); a wall-capacity error (true
``C_w = (1 + e)`` x metadata). With ``--wall-capacity-unknown`` the metadata's wall heat
capacity is ``null``.

Scenarios
---------
``random_SEED`` draws a plausible tank and schedule (fluid among the five above unless
given, any of the four shapes, 0.5-60 m3, fill 0.2-0.9, pressure 1.05 x normal boiling
.. 0.35 x critical, 4-8 phases of 5-25 min, 1-2 h). Phases are *targets* (a pressure rise,
a pressure drop, a level change, a sloshing amplitude and frequency ratio); the metered
rates are fixed by an operator policy from the nominal (mechanism-free) state at the phase
start, so a run with a mechanism uses exactly the same metered schedule as without. Soft
bounds are terminal events: pressure above 0.93 x 0.6 x critical (inflows stop; at rest a
relief vent opens and doubles at each further 1 % rise), pressure below 1.03 x
max(0.5 x normal boiling, 1.3 x triple) (vent and drain stop), fill above 94 % (fill stops)
or below 6 % (drain stops); the truth file lists every such change and the CSV holds the
schedule as executed. Hard limits (fluid partial pressure above 0.88 x critical or below
1.1 x triple, fill outside 1-98.5 %) raise :class:`SimulationError`. Named scenarios:
``ln2_dewar``, ``lch4_sphere``, ``lh2_hcyl`` (see :data:`NAMED_SCENARIOS`; ``--fluid``
re-targets them, their pressures and temperatures being relative to the fluid's).

Sensors: ``p_v`` (total pressure), ``T_v``, ``T_l`` (mass average of both layers), ``T_w``
(capacity average of the wall), ``H_l`` (level); ``p_v, T_v, T_l, H_l`` every 10 s, ``T_w``
every 30 s (empty cells in between), Gaussian noise ``--noise none|low|high`` (low: 300 Pa,
0.05 K, 1 mm; high: 2000 Pa, 0.2 K, 5 mm; ``none`` writes exact readings and the low
``noise_std``). Input rows at every schedule change, every input column filled on every row.
The metadata ``initial`` block is the noise-free reading at ``t = 0`` (biases and helium
included), the tank block the nominal (metadata) wall capacity.

Integration: ``scipy.integrate.solve_ivp(method="LSODA")``, restarted at every schedule
change, ``rtol = 1e-8``, ``max_step = 60 s``; linear multistep methods preserve the linear
invariants (total mass, helium, total energy minus the boundary quadratures) to round-off,
which the truth file reports as the closure error (measured: below 1e-13 of the mass and
energy that crossed the boundary). Against ``rtol = 1e-10`` the pressure agrees to a few Pa
and the temperatures to 1e-4 K. A two-hour run takes well under a second on one core.

References: S. W. Churchill & H. H. S. Chu, Int. J. Heat Mass Transfer 18 (1975) 1323;
S. Globe & D. Dropkin, J. Heat Transfer 81 (1959) 24; W. M. Rohsenow, Trans. ASME 74 (1952)
969; N. Zuber, AEC Report AECU-4439 (1959); H. N. Abramson (ed.), NASA SP-106 (1966);
W. H. McAdams, Heat Transmission (1954); CoolProp: I. H. Bell et al., Ind. Eng. Chem. Res. 53
(2014) 2498.

Limits (deliberate)
-------------------
One pressure (no hydrostatic head); two liquid volumes only (no continuous thermal
stratification); the ullage is well mixed; sloshing changes transfer coefficients only
(no mechanical energy, no level or interface-area change); helium is ideal, does not
dissolve and is ignored in transport properties; nucleate-boiling bubbles do not condense in a
subcooled bulk; the wall capacity is constant (``c_w`` at the initial wall temperature);
correlations for vertical plates are used on curved walls; valid for fluid partial pressures
between about 1.3 x the triple-point pressure and 0.9 x the critical pressure.

Command line::

    python tests/cryo_sim.py SCENARIO [--fluid F] [--mechanism NAME=VALUE ...]
        [--noise low|high|none] [--seed N] [--out DIR] [--name NAME] [--duration S]
        [--wall-capacity-unknown] [--list]
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

import CoolProp.CoolProp as CP
import numpy as np
from scipy.integrate import solve_ivp
from scipy.interpolate import CubicSpline

__all__ = [
    "FLUIDS",
    "SHAPES",
    "OPERATIONS",
    "MECHANISMS",
    "NOISE_LEVELS",
    "NAMED_SCENARIOS",
    "OBS_COLUMNS",
    "INPUT_COLUMNS",
    "SimulationError",
    "FluidProps",
    "Geometry",
    "fluid_props",
    "named_scenario",
    "random_scenario",
    "resolve_scenario",
    "simulate",
    "simulate_run",
    "main",
]

SIMULATOR = "tests/cryo_sim.py"

# ------------------------------------------------------------------------------- constants
G = 9.80665
R_GAS = 8.314462618
M_HE = 4.002602e-3  # kg/mol
CV_HE = 1.5 * R_GAS  # J/(mol K)
CP_HE = 2.5 * R_GAS
P_NBP = 101325.0

FLUIDS = ("ParaHydrogen", "Nitrogen", "Methane", "Oxygen", "Argon")
SHAPES = ("vertical_cylinder", "vertical_cylinder_elliptical_heads", "sphere", "horizontal_cylinder")
OPERATIONS = ("rest", "pressurize", "vent", "fill", "drain", "slosh")

OBS_COLUMNS = ("p_v_Pa", "T_v_K", "T_l_K", "T_w_K", "H_l_m")
NOISE_KEYS = ("p_v", "T_v", "T_l", "T_w", "H_l")
INPUT_COLUMNS = ("mdot_v_in_kg_s", "T_v_in_K", "p_v_in_Pa", "mdot_v_out_kg_s", "mdot_l_in_kg_s", "T_l_in_K",
                 "mdot_l_out_kg_s", "slosh_amplitude_m", "slosh_frequency_Hz", "Q_aw_W")
NOISE_LEVELS = {
    "low": {"p_v": 300.0, "T_v": 0.05, "T_l": 0.05, "T_w": 0.05, "H_l": 0.001},
    "high": {"p_v": 2000.0, "T_v": 0.2, "T_l": 0.2, "T_w": 0.2, "H_l": 0.005},
}
SAMPLE_DT_S = 10.0  # p_v, T_v, T_l, H_l
SAMPLE_DT_WALL_S = 30.0  # T_w

MECHANISMS = {
    "heat_leak_liquid_W": "extra heat into the bulk liquid [W]",
    "heat_leak_vapor_W": "extra heat into the ullage gas [W]",
    "heat_leak_wall_W": "extra heat into the wall (split by area) [W]",
    "vapor_leak_kg_s": "unmetered loss of ullage gas at ullage state [kg/s]",
    "liquid_leak_kg_s": "unmetered loss of bulk liquid [kg/s]",
    "inflow_meter_bias": "true inflows = (1 + b) x metered (vapour and liquid) [-]",
    "pressure_sensor_bias_Pa": "added to the pressure sensor [Pa]",
    "temperature_sensor_bias_K": "added to the liquid temperature sensor T_l [K]",
    "helium_mol": "helium in the ullage (ideal, monatomic, at T_v) [mol]",
    "wall_heat_capacity_error": "true C_w = (1 + e) x metadata's [-]",
}

# model parameters
SURFACE_FRACTION = 0.03  # surface layer mass / liquid mass
TAU_REGRID_S = 20.0
TAU_FLASH_S = 40.0
TAU_FOG_S = 25.0
TAU_CAPACITY_S = 10.0
CAP_FLOOR = 0.02  # fraction of C_w kept on each wall node
BL_CARRY = 0.4  # fraction of the wall-to-liquid heat deposited in the surface layer
DT_REG_K = 0.02
RAMP_K = 0.02
SWITCH_K = 0.05
C_SLOSH_FLUID = 4e-3
C_SLOSH_WALL = 1e-3
ZETA_SLOSH = 0.08
NB_ONSET_K = 1.0
NB_SWITCH_K = 0.5
ROHSENOW_CSF = 0.013
ROHSENOW_N = 1.7
L_MIN_M = 0.02
RTOL = 1e-8  # solve_ivp relative tolerance

# wall materials: rough cryogenic data (order of magnitude, after NIST cryogenic material
# properties): density, specific heat c(T) and conductivity k(T)
_MATERIALS = {
    "steel": {"rho": 7900.0,
              "T": (4.0, 20.0, 40.0, 60.0, 77.0, 100.0, 150.0, 200.0, 300.0),
              "c": (2.0, 12.0, 60.0, 130.0, 195.0, 255.0, 345.0, 400.0, 480.0),
              "k": (0.3, 2.0, 4.5, 6.5, 8.0, 9.2, 11.5, 13.0, 15.0), "allow_Pa": 140e6, "t_min": 0.003},
    "aluminium": {"rho": 2700.0,
                  "T": (4.0, 20.0, 40.0, 60.0, 77.0, 100.0, 150.0, 200.0, 300.0),
                  "c": (0.3, 9.0, 75.0, 190.0, 335.0, 480.0, 680.0, 790.0, 900.0),
                  "k": (5.0, 40.0, 70.0, 85.0, 95.0, 110.0, 130.0, 140.0, 155.0), "allow_Pa": 70e6,
                  "t_min": 0.004},
}


class SimulationError(RuntimeError):
    """The integration or the state recovery failed (the message names time and state)."""


# ------------------------------------------------------------------------------- small maths
def _ramp(x: float) -> float:
    """C1 ramp: 0 below 0, quadratic up to RAMP_K, then linear."""
    if x <= 0.0:
        return 0.0
    if x < RAMP_K:
        return 0.5 * x * x / RAMP_K
    return x - 0.5 * RAMP_K


def _switch(x: float, w: float = SWITCH_K) -> float:
    """Smooth step from 0 (x << -w) to 1 (x >> w)."""
    return 0.5 * (1.0 + math.tanh(x / w))


def _smoothstep(x: float) -> float:
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    return x * x * (3.0 - 2.0 * x)


class _USpline:
    """Cubic spline on a uniform grid with several outputs, fast scalar evaluation."""

    def __init__(self, x: np.ndarray, Y: np.ndarray):
        x = np.asarray(x, float)
        Y = np.asarray(Y, float)
        if Y.ndim == 1:
            Y = Y[:, None]
        cs = CubicSpline(x, Y, axis=0)
        self.x0 = float(x[0])
        self.x1 = float(x[-1])
        self.dx = float(x[1] - x[0])
        self.n = len(x) - 1
        self.c = np.ascontiguousarray(np.transpose(cs.c, (1, 0, 2)))  # (n, 4, k)

    def __call__(self, x: float) -> np.ndarray:
        i = int((x - self.x0) / self.dx)
        i = 0 if i < 0 else (self.n - 1 if i >= self.n else i)
        t = x - (self.x0 + i * self.dx)
        c = self.c[i]
        return ((c[0] * t + c[1]) * t + c[2]) * t + c[3]


# ------------------------------------------------------------------------------- fluid
class FluidProps:
    """Equation of state (CoolProp HEOS, imposed phase) and start-up tables of one fluid."""

    def __init__(self, name: str):
        try:
            probe = CP.AbstractState("HEOS", name)
        except ValueError as e:
            raise ValueError(f"unknown CoolProp fluid {name!r}: {e}") from None
        if len(probe.fluid_names()) != 1:
            raise ValueError(f"{name!r} is not a pure fluid")
        self.name = name
        self.M = probe.molar_mass()
        self.T_c = probe.T_critical()
        self.p_c = probe.p_critical()
        self.T_trip = max(probe.Ttriple(), probe.Tmin())
        probe.update(CP.QT_INPUTS, 0.0, self.T_trip)
        self.p_trip = probe.p()
        if self.p_trip >= 0.95 * P_NBP:
            raise ValueError(f"{name}: triple-point pressure {self.p_trip:.4g} Pa is not below 1 atm; "
                             f"this simulator needs a liquid that boils at about 1 atm")
        probe.update(CP.PQ_INPUTS, P_NBP, 0.0)
        self.T_nbp = probe.T()
        self.R_s = R_GAS / self.M
        # soft bounds of the runs
        self.p_min = max(0.5 * P_NBP, 1.3 * self.p_trip)
        self.p_max = 0.6 * self.p_c
        # equation-of-state states, phase imposed (explicit Helmholtz, no flash)
        self.vap = CP.AbstractState("HEOS", name)
        self.vap.specify_phase(CP.iphase_gas)
        self.liq = CP.AbstractState("HEOS", name)
        self.liq.specify_phase(CP.iphase_liquid)
        self.film = CP.AbstractState("HEOS", name)
        self.film.specify_phase(CP.iphase_gas)
        # transport: CoolProp's, or one-parameter corresponding states from argon when CoolProp
        # has no model (viscosity x Tc^(1/6) M^(-1/2) Pc^(-2/3) and conductivity x Tc^(1/6)
        # M^(1/2) Pc^(-2/3) are functions of (T/Tc, rho/rhoc) only)
        self.rho_c = probe.rhomass_critical()
        self.transport = "CoolProp"
        self._ref: FluidProps | None = None
        try:
            self.film.update(CP.PT_INPUTS, P_NBP, 1.5 * self.T_nbp)
            self.film.conductivity()
            self.film.viscosity()
        except ValueError:
            if name == _TRANSPORT_REFERENCE:
                raise
            self._ref = fluid_props(_TRANSPORT_REFERENCE)
            r = self._ref
            self.transport = f"corresponding states from {_TRANSPORT_REFERENCE} (CoolProp has no transport model)"

            def xi_mu(fl):
                return fl.T_c ** (1 / 6) * (fl.M * 1e3) ** -0.5 * fl.p_c ** (-2 / 3)

            def xi_k(fl):
                return fl.T_c ** (1 / 6) * (fl.M * 1e3) ** 0.5 * fl.p_c ** (-2 / 3)
            self._mu_scale = xi_mu(r) / xi_mu(self)
            self._k_scale = xi_k(r) / xi_k(self)
        self._build_tables(probe)

    def _build_tables(self, probe) -> None:
        # saturation in ln p: T_sat, h_l, h_v, rho_l, rho_v, sigma
        p_lo = self.p_trip * 1.0005
        p_hi = 0.92 * self.p_c
        lnp = np.linspace(math.log(p_lo), math.log(p_hi), 500)
        rows = []
        for lp in lnp:
            p = math.exp(lp)
            probe.update(CP.PQ_INPUTS, p, 0.0)
            T, hl, rl = probe.T(), probe.hmass(), probe.rhomass()
            try:
                sig = probe.surface_tension()
            except ValueError:
                sig = float("nan")
            probe.update(CP.PQ_INPUTS, p, 1.0)
            rows.append((T, hl, probe.hmass(), rl, probe.rhomass(), sig))
        sat = np.array(rows)
        if not np.all(np.isfinite(sat[:, 5])):  # no surface-tension model: Brock & Bird (1955)
            pc_bar, Tbr = self.p_c / 1e5, self.T_nbp / self.T_c
            Q = 0.1196 * (1.0 + Tbr * math.log(pc_bar / 1.01325) / (1.0 - Tbr)) - 0.279
            sat[:, 5] = 1e-3 * pc_bar ** (2 / 3) * self.T_c ** (1 / 3) * Q * (1.0 - sat[:, 0] / self.T_c) ** (11 / 9)
        self.sat_lnp = _USpline(lnp, sat)
        self.T_sat_max = float(sat[-1, 0])
        # saturated liquid along T: k, mu, cp, rho, beta, h_sat, p_sat, (dh/dp)_T
        Ts = np.linspace(self.T_trip + 1e-3, self.T_sat_max, 400)
        rows = []
        for T in Ts:
            probe.update(CP.QT_INPUTS, 0.0, T)
            rho, psat, hl = probe.rhomass(), probe.p(), probe.hmass()
            self.liq.update(CP.DmassT_INPUTS, rho, T)
            beta = self.liq.isobaric_expansion_coefficient()
            if self._ref is None:
                k, mu = self.liq.conductivity(), self.liq.viscosity()
            else:
                kr, mur = self._ref.liquid_film(T * self._ref.T_c / self.T_c)[:2]
                k, mu = float(kr) * self._k_scale, float(mur) * self._mu_scale
            rows.append((k, mu, self.liq.cpmass(), rho, beta, hl, psat, (1.0 - T * beta) / rho))
        self.liq_T = _USpline(Ts, np.array(rows))

    # ---- saturation
    def sat(self, p: float) -> np.ndarray:
        """(T_sat, h_l,sat, h_v,sat, rho_l,sat, rho_v,sat, sigma) at pressure p."""
        return self.sat_lnp(math.log(p))

    def T_sat(self, p: float) -> float:
        return float(self.sat(p)[0])

    def p_sat(self, T: float) -> float:
        return float(self.liq_T(T)[6])

    def liquid_film(self, T: float) -> np.ndarray:
        """Saturated-liquid (k, mu, cp, rho, beta, h_sat, p_sat, dh/dp) at T."""
        return self.liq_T(min(max(T, self.T_trip + 1e-3), self.T_sat_max))

    # ---- equation of state, (T, rho) inputs
    def vapour(self, T: float, rho: float) -> tuple[float, float, float, float, float, float]:
        """(u, p, c_v, du/drho|T, dp/dT|rho, dp/drho|T) of the gas phase."""
        A = self.vap
        A.update(CP.DmassT_INPUTS, rho, T)
        return (A.umass(), A.p(), A.cvmass(), A.first_partial_deriv(CP.iUmass, CP.iDmass, CP.iT),
                A.first_partial_deriv(CP.iP, CP.iT, CP.iDmass), A.first_partial_deriv(CP.iP, CP.iDmass, CP.iT))

    def liquid(self, T: float, rho: float) -> tuple[float, float, float, float, float, float]:
        A = self.liq
        A.update(CP.DmassT_INPUTS, rho, T)
        return (A.umass(), A.p(), A.cvmass(), A.first_partial_deriv(CP.iUmass, CP.iDmass, CP.iT),
                A.first_partial_deriv(CP.iP, CP.iT, CP.iDmass), A.first_partial_deriv(CP.iP, CP.iDmass, CP.iT))

    def vapour_film(self, T: float, rho: float) -> tuple[float, float, float, float, float]:
        """(k, mu, cp, rho, beta) of the gas at (T, rho)."""
        A = self.film
        A.update(CP.DmassT_INPUTS, rho, T)
        if self._ref is None:
            return A.conductivity(), A.viscosity(), A.cpmass(), rho, A.isobaric_expansion_coefficient()
        r = self._ref
        k, mu = r.vapour_film(T * r.T_c / self.T_c, rho * r.rho_c / self.rho_c)[:2]
        return k * self._k_scale, mu * self._mu_scale, A.cpmass(), rho, A.isobaric_expansion_coefficient()

    # ---- (p, T) states, set-up only
    def rho_pT(self, p: float, T: float, phase: str) -> float:
        A = self.vap if phase == "gas" else self.liq
        A.update(CP.PT_INPUTS, p, T)
        return A.rhomass()

    def h_gas_pT(self, p: float, T: float) -> float:
        self.vap.update(CP.PT_INPUTS, p, T)
        return self.vap.hmass()


_FLUID_CACHE: dict[str, FluidProps] = {}
_TRANSPORT_REFERENCE = "Argon"


def fluid_props(name: str) -> FluidProps:
    if name not in _FLUID_CACHE:
        _FLUID_CACHE[name] = FluidProps(name)
    return _FLUID_CACHE[name]


# ------------------------------------------------------------------------------- geometry
class Geometry:
    """Volume <-> level, interface area, wetted/dry wall areas of the four tank shapes."""

    def __init__(self, tank: Mapping[str, Any]):
        shape = tank["shape"]
        self.shape = shape
        if shape == "vertical_cylinder":
            R, H = float(tank["radius_m"]), float(tank["height_m"])
            self.R, self.H = R, H
            self.V = math.pi * R * R * H
            self.A_wall = 2 * math.pi * R * R + 2 * math.pi * R * H
            self.L_cond = 0.5 * H
        elif shape == "vertical_cylinder_elliptical_heads":
            R, L, a = float(tank["radius_m"]), float(tank["cylinder_length_m"]), float(tank["head_aspect"])
            b = R / a
            self.R, self.L, self.b = R, L, b
            self.H = L + 2 * b
            self.k2 = (R * R - b * b) / b ** 4
            self.V_head = 2.0 / 3.0 * math.pi * R * R * b
            self.A_head = 2 * math.pi * R * self._F(b)
            self.V = 2 * self.V_head + math.pi * R * R * L
            self.A_wall = 2 * self.A_head + 2 * math.pi * R * L
            self.L_cond = 0.5 * self.H
        elif shape == "sphere":
            R = float(tank["radius_m"])
            self.R, self.H = R, 2 * R
            self.V = 4.0 / 3.0 * math.pi * R ** 3
            self.A_wall = 4 * math.pi * R * R
            self.L_cond = 0.5 * math.pi * R
        elif shape == "horizontal_cylinder":
            R, L = float(tank["radius_m"]), float(tank["cylinder_length_m"])
            self.R, self.L, self.H = R, L, 2 * R
            self.V = math.pi * R * R * L
            self.A_wall = 2 * math.pi * R * R + 2 * math.pi * R * L
            self.L_cond = 0.5 * math.pi * R
        else:
            raise ValueError(f"unknown tank shape {shape!r}; known: {', '.join(SHAPES)}")
        self.D = 2 * self.R
        self._h = 0.5 * self.H

    def _F(self, w: float) -> float:
        """Antiderivative of the head's area integrand, in w = distance from the head's equator."""
        k2 = self.k2
        if abs(k2) * self.b ** 2 < 1e-12:
            return w
        if k2 > 0:
            k = math.sqrt(k2)
            return 0.5 * (w * math.sqrt(1 + k2 * w * w) + math.asinh(k * w) / k)
        k = math.sqrt(-k2)
        return 0.5 * (w * math.sqrt(max(0.0, 1 - k * k * w * w)) + math.asin(min(1.0, k * w)) / k)

    def _head_zone(self, z: float) -> tuple[float, float, float]:
        """Bottom head filled to height z from its apex: volume, section area, zone area."""
        R, b = self.R, self.b
        V = math.pi * R * R * (z * z / b - z ** 3 / (3 * b * b))
        A_i = math.pi * R * R * max(0.0, 2 * z / b - z * z / (b * b))
        A_z = 2 * math.pi * R * (self._F(b) - self._F(b - z))
        return V, A_i, A_z

    def at(self, h: float) -> tuple[float, float, float, float, float]:
        """(V_l, A_i, A_wet, contact perimeter, free-surface width) at level h."""
        h = min(max(h, 0.0), self.H)
        s = self.shape
        if s == "vertical_cylinder":
            R = self.R
            return (math.pi * R * R * h, math.pi * R * R, math.pi * R * R + 2 * math.pi * R * h, 2 * math.pi * R,
                    2 * R)
        if s == "sphere":
            R = self.R
            c2 = max(0.0, 2 * R * h - h * h)
            return (math.pi * h * h * (3 * R - h) / 3.0, math.pi * c2, 2 * math.pi * R * h,
                    2 * math.pi * math.sqrt(c2), 2 * math.sqrt(c2))
        if s == "horizontal_cylinder":
            R, L = self.R, self.L
            c = math.sqrt(max(0.0, 2 * R * h - h * h))
            th = math.acos(min(1.0, max(-1.0, (R - h) / R)))
            S = R * R * th - (R - h) * c
            return L * S, 2 * L * c, 2 * S + 2 * R * th * L, 2 * L + 4 * c, 2 * c
        # elliptical heads
        R, b, L = self.R, self.b, self.L
        if h <= b:
            V, A_i, A_z = self._head_zone(h)
            return V, A_i, A_z, 2 * math.sqrt(A_i / math.pi) * math.pi, 2 * math.sqrt(A_i / math.pi)
        if h <= b + L:
            return (self.V_head + math.pi * R * R * (h - b), math.pi * R * R,
                    self.A_head + 2 * math.pi * R * (h - b), 2 * math.pi * R, 2 * R)
        V, A_i, A_z = self._head_zone(self.H - h)
        return (self.V - V, A_i, self.A_wall - A_z, 2 * math.pi * math.sqrt(A_i / math.pi),
                2 * math.sqrt(A_i / math.pi))

    def level(self, V_l: float) -> float:
        """Level of the liquid volume V_l (safeguarded Newton, warm-started)."""
        lo, hi = 0.0, self.H
        h = min(max(self._h, 0.0), self.H)
        tol = 1e-13 * self.V
        for _ in range(100):
            V, A_i = self.at(h)[:2]
            f = V - V_l
            if abs(f) <= tol:
                break
            if f > 0:
                hi = h
            else:
                lo = h
            hn = h - f / A_i if A_i > 0 else 0.5 * (lo + hi)
            if not (lo < hn < hi):
                hn = 0.5 * (lo + hi)
            if abs(hn - h) < 1e-15 * self.H:
                h = hn
                break
            h = hn
        self._h = h
        return h

    def surfaces(self, h: float, A_wet: float) -> tuple[list, list]:
        """Natural-convection surfaces: wet and dry lists of (area, kind, length)."""
        H = self.H
        if self.shape == "vertical_cylinder":
            R = self.R
            base = math.pi * R * R
            return ([(2 * math.pi * R * h, "vertical", max(h, L_MIN_M)), (base, "floor", 0.5 * R)],
                    [(2 * math.pi * R * (H - h), "vertical", max(H - h, L_MIN_M)), (base, "ceiling", 0.5 * R)])
        return ([(A_wet, "vertical", max(h, L_MIN_M))], [(self.A_wall - A_wet, "vertical", max(H - h, L_MIN_M))])

    def omega1(self, h: float, V_l: float, A_i: float, width: float) -> float:
        """First lateral sloshing mode [rad/s] at level h (see the module docstring)."""
        if self.shape == "horizontal_cylinder":
            w = max(width, 1e-3)
            d = V_l / max(A_i, 1e-9)
            return math.sqrt(math.pi * G / w * math.tanh(math.pi * d / w))
        if self.shape == "sphere":
            Req = math.sqrt(max(A_i, 1e-9) / math.pi)
            d = V_l / max(A_i, 1e-9)
        else:
            Req = self.R
            d = V_l / (math.pi * self.R ** 2)
        return math.sqrt(1.841 * G / Req * math.tanh(1.841 * d / Req))

    def tank_dims(self) -> dict[str, float]:
        s = self.shape
        if s == "vertical_cylinder":
            return {"radius_m": self.R, "height_m": self.H}
        if s == "vertical_cylinder_elliptical_heads":
            return {"radius_m": self.R, "cylinder_length_m": self.L, "head_aspect": self.R / self.b}
        if s == "sphere":
            return {"radius_m": self.R}
        return {"radius_m": self.R, "cylinder_length_m": self.L}


def _tank_from_volume(shape: str, V: float, ratio: float, head_aspect: float = 2.0) -> dict[str, Any]:
    """Tank dimensions of volume V; ratio = height/diameter or straight length/diameter."""
    if shape == "vertical_cylinder":
        R = (V / (2 * math.pi * ratio)) ** (1 / 3)
        return {"shape": shape, "radius_m": R, "height_m": 2 * R * ratio}
    if shape == "vertical_cylinder_elliptical_heads":
        R = (V / (math.pi * (2 * ratio + 4.0 / (3.0 * head_aspect)))) ** (1 / 3)
        return {"shape": shape, "radius_m": R, "cylinder_length_m": 2 * R * ratio, "head_aspect": head_aspect}
    if shape == "sphere":
        return {"shape": shape, "radius_m": (3 * V / (4 * math.pi)) ** (1 / 3)}
    if shape == "horizontal_cylinder":
        R = (V / (2 * math.pi * ratio)) ** (1 / 3)
        return {"shape": shape, "radius_m": R, "cylinder_length_m": 2 * R * ratio}
    raise ValueError(f"unknown tank shape {shape!r}")


def _wall_capacity(material: str, thickness_m: float, area_m2: float, T_K: float) -> tuple[float, float]:
    """(C_w [J/K], k_w [W/(m K)]) of a shell at temperature T."""
    m = _MATERIALS[material]
    c = float(np.interp(T_K, m["T"], m["c"]))
    k = float(np.interp(T_K, m["T"], m["k"]))
    return m["rho"] * thickness_m * area_m2 * c, k


# ------------------------------------------------------------------------------- heat transfer
def _rayleigh(beta: float, dT: float, L: float, nu: float, alpha: float) -> float:
    return G * abs(beta) * math.sqrt(dT * dT + DT_REG_K * DT_REG_K) * L ** 3 / (nu * alpha)


def _nu_churchill_chu(Ra: float, Pr: float) -> float:
    return (0.825 + 0.387 * Ra ** (1.0 / 6.0) / (1.0 + (0.492 / Pr) ** (9.0 / 16.0)) ** (8.0 / 27.0)) ** 2


def _nu_plate(Ra: float, w_unstable: float) -> float:
    unstable = ((0.54 * Ra ** 0.25) ** 6 + (0.15 * Ra ** (1.0 / 3.0)) ** 6) ** (1.0 / 6.0)
    stable = 0.27 * Ra ** 0.25
    return w_unstable * unstable + (1.0 - w_unstable) * stable + 1.0


def _wall_h(surfaces: list, props: tuple, dT: float, wall_above: bool) -> float:
    """Sum of h A over the surfaces [W/K]; dT = T_wall - T_fluid.

    ``wall_above``: the flat plate of kind 'ceiling' is above the fluid, 'floor' below."""
    k, mu, cp, rho, beta = props
    nu = mu / rho
    alpha = k / (rho * cp)
    Pr = nu / alpha
    hA = 0.0
    for area, kind, L in surfaces:
        if area <= 0.0:
            continue
        Ra = _rayleigh(beta, dT, L, nu, alpha)
        if kind == "vertical":
            Nu = _nu_churchill_chu(Ra, Pr)
        elif kind == "floor":  # heated from below when the wall is warmer: unstable
            Nu = _nu_plate(Ra, _switch(dT))
        else:  # ceiling: a warmer wall above the gas is stable
            Nu = _nu_plate(Ra, _switch(-dT))
        hA += Nu * k / L * area
    return hA


def _slosh_intensity(A0: float, freq: float, D: float, nu: float, omega1: float) -> float:
    if A0 <= 0.0 or freq <= 0.0:
        return 0.0
    om = 2 * math.pi * freq
    r = om / omega1
    g = r * r / math.sqrt((1 - r * r) ** 2 + (2 * ZETA_SLOSH * r) ** 2)
    return math.sqrt(A0 * om * D / nu) * g


# ------------------------------------------------------------------------------- the model
class _Model:
    """Right-hand side, state recovery and sensors of one tank with its mechanisms."""

    NY = 13

    def __init__(self, sc: Mapping[str, Any], mech: Mapping[str, float]):
        self.sc = sc
        self.fp = fluid_props(sc["fluid"])
        self.geom = Geometry(sc["tank"])
        self.mech = {k: float(mech.get(k, 0.0)) for k in MECHANISMS}
        self.C_meta = float(sc["wall"]["C_w_J_per_K"])
        self.C_w = self.C_meta * (1.0 + self.mech["wall_heat_capacity_error"])
        if self.C_w <= 0:
            raise ValueError("wall_heat_capacity_error must be > -1")
        self.k_w = float(sc["wall"]["k_w_W_per_mK"])
        self.t_w = float(sc["wall"]["thickness_m"])
        self.nfev = 0
        self.max_nfev = 400_000
        self.inputs: dict[str, float] = {c: 0.0 for c in INPUT_COLUMNS}
        self.h_vin = 0.0
        self.h_lin0, self.dh_lin, self.p_lin0 = 0.0, 0.0, 0.0
        self._guess: list[float] = []
        self.y0 = self._initial_state()

    # ---- initial state
    def _initial_state(self) -> np.ndarray:
        fp, g, ini = self.fp, self.geom, self.sc["initial"]
        p0, T_l, T_v = float(ini["p_Pa"]), float(ini["T_l_K"]), float(ini["T_v_K"])
        fill = float(ini["fill_ratio"])
        n = self.mech["helium_mol"]
        V_l = fill * g.V
        V_v = g.V - V_l
        p_he = n * R_GAS * T_v / V_v
        p_f = p0 - p_he
        if p_f < 1.3 * fp.p_trip or p_f < 0.25 * p0:
            raise ValueError(f"helium_mol={n}: helium partial pressure {p_he:.4g} Pa leaves too little "
                             f"{fp.name} in the ullage at p = {p0:.4g} Pa")
        rho_l = fp.rho_pT(p0, T_l, "liquid")
        rho_v = fp.rho_pT(p_f, T_v, "gas")
        m_l = rho_l * V_l
        m_s, m_b = SURFACE_FRACTION * m_l, (1 - SURFACE_FRACTION) * m_l
        u_l = fp.liquid(T_l, rho_l)[0]
        m_v = rho_v * V_v
        U_v = m_v * fp.vapour(T_v, rho_v)[0] + n * CV_HE * T_v
        h = g.level(V_l)
        A_wet = g.at(h)[2]
        C_wet = self.C_w * (CAP_FLOOR + (1 - 2 * CAP_FLOOR) * A_wet / g.A_wall)
        E_wet = C_wet * float(ini["T_wet_K"])
        E_dry = (self.C_w - C_wet) * float(ini["T_dry_K"])
        self._guess = [p0, T_v, T_l, rho_l, T_l, rho_l]
        self.helium_p0 = p_he
        self.p_f0 = p_f
        return np.array([m_v, U_v, n, m_s, m_s * u_l, m_b, m_b * u_l, E_wet, E_dry, C_wet, 0.0, 0.0, 0.0])

    # ---- state recovery
    def _liquid_solve(self, u_t: float, p: float, T: float, rho: float):
        fp = self.fp
        for _ in range(60):
            u, pl, cv, u_r, p_T, p_r = fp.liquid(T, rho)
            r1, r2 = u - u_t, pl - p
            det = cv * p_r - u_r * p_T
            dT = -(r1 * p_r - u_r * r2) / det
            dr = -(cv * r2 - p_T * r1) / det
            dT = max(-5.0, min(5.0, dT))
            dr = max(-0.05 * rho, min(0.05 * rho, dr))
            T += dT
            rho += dr
            if abs(dT) < 1e-10 and abs(dr) < 1e-13 * rho:
                return T, rho, (u, pl, cv, u_r, p_T, p_r), cv / det
        raise SimulationError(f"liquid state recovery failed (u={u_t}, p={p})")

    def recover(self, y: np.ndarray) -> dict[str, Any]:
        fp, V = self.fp, self.geom.V
        m_v, U_v, n, m_s, U_s, m_b, U_b = (float(v) for v in y[:7])
        if not (m_v > 0 and m_s > 0 and m_b > 0):
            raise SimulationError(f"non-positive mass in state {y[:7]}")
        n = max(n, 0.0)
        p, T_v, T_s, r_s, T_b, r_b = self._guess
        u_s, u_b = U_s / m_s, U_b / m_b
        for _ in range(60):
            T_s, r_s, ls, dr_s = self._liquid_solve(u_s, p, T_s, r_s)
            T_b, r_b, lb, dr_b = self._liquid_solve(u_b, p, T_b, r_b)
            V_v = V - m_s / r_s - m_b / r_b
            if V_v <= 1e-6 * V:
                raise SimulationError(f"ullage volume vanished (V_v={V_v:.4g} m3)")
            rho_v = m_v / V_v
            vs = fp.vapour(T_v, rho_v)
            u, p_f, cv, u_r, p_T, p_r = vs
            p_he = n * R_GAS * T_v / V_v
            r1 = m_v * u + n * CV_HE * T_v - U_v
            r2 = p_f + p_he - p
            dVv_dp = m_s / (r_s * r_s) * dr_s + m_b / (r_b * r_b) * dr_b
            drv_dp = -rho_v / V_v * dVv_dp
            J11 = m_v * cv + n * CV_HE
            J12 = m_v * u_r * drv_dp
            J21 = p_T + n * R_GAS / V_v
            J22 = p_r * drv_dp - p_he / V_v * dVv_dp - 1.0
            det = J11 * J22 - J12 * J21
            dT = -(r1 * J22 - J12 * r2) / det
            dp = -(J11 * r2 - J21 * r1) / det
            dT = max(-0.3 * T_v, min(0.3 * T_v, dT))
            dp = max(-0.3 * p, min(0.3 * p, dp))
            small = abs(dp) < 1e-11 * p + 1e-7 and abs(dT) < 1e-11 * T_v
            if small:
                break
            T_v += dT
            p += dp
            if p <= 0 or T_v <= 0:
                raise SimulationError(f"state recovery diverged (p={p}, T_v={T_v})")
        else:
            raise SimulationError(f"state recovery did not converge (p={p}, T_v={T_v})")
        p_tot = p_f + p_he  # consistent with the last evaluation
        self._guess = [p_tot, T_v, T_s, r_s, T_b, r_b]
        return {"p": p_tot, "p_f": p_f, "p_he": p_he, "T_v": T_v, "rho_v": rho_v, "V_v": V_v, "vap": vs,
                "T_s": T_s, "rho_s": r_s, "liq_s": ls, "T_b": T_b, "rho_b": r_b, "liq_b": lb,
                "m_v": m_v, "n": n, "m_s": m_s, "m_b": m_b}

    # ---- inputs of a segment
    def set_inputs(self, inputs: Mapping[str, float], p_now: float) -> None:
        self.inputs = {c: float(inputs.get(c, 0.0)) for c in INPUT_COLUMNS}
        if self.inputs["mdot_v_in_kg_s"] > 0:
            p_in = self.inputs["p_v_in_Pa"] or p_now
            self.h_vin = self.fp.h_gas_pT(p_in, self.inputs["T_v_in_K"])
        else:
            self.h_vin = 0.0
        # liquid inflow at h(p, T_l_in): exact at the segment's initial pressure, first order in
        # the pressure change during the segment ((dh/dp)_T = (1 - T beta) / rho)
        self.h_lin0, self.dh_lin, self.p_lin0 = 0.0, 0.0, p_now
        if self.inputs["mdot_l_in_kg_s"] > 0:
            A = self.fp.liq
            A.update(CP.PT_INPUTS, p_now, self.inputs["T_l_in_K"])
            self.h_lin0 = A.hmass()
            self.dh_lin = (1.0 - self.inputs["T_l_in_K"] * A.isobaric_expansion_coefficient()) / A.rhomass()

    # ---- right-hand side
    def rhs(self, t: float, y: np.ndarray) -> np.ndarray:
        self.nfev += 1
        if self.nfev > self.max_nfev:
            raise SimulationError(f"more than {self.max_nfev} right-hand-side calls (t={t:.1f} s)")
        fp, geo, mech, inp = self.fp, self.geom, self.mech, self.inputs
        st = self.recover(y)
        E_wet, E_dry, C_wet = float(y[7]), float(y[8]), float(y[9])
        p, p_f, T_v, rho_v, V_v = st["p"], st["p_f"], st["T_v"], st["rho_v"], st["V_v"]
        m_v, n, m_s, m_b = st["m_v"], st["n"], st["m_s"], st["m_b"]
        T_s, T_b, rho_s, rho_b = st["T_s"], st["T_b"], st["rho_s"], st["rho_b"]
        u_v, _, cv_v, ur_v, pT_v, pr_v = st["vap"]
        u_s, _, cv_s, ur_s, pT_s, pr_s = st["liq_s"]
        u_b, _, cv_b, ur_b, pT_b, pr_b = st["liq_b"]
        h_v = u_v + p_f / rho_v
        h_s = u_s + p / rho_s
        h_b = u_b + p / rho_b
        cp_v = cv_v + T_v * pT_v * pT_v / (rho_v * rho_v * pr_v)
        cp_s = cv_s + T_s * pT_s * pT_s / (rho_s * rho_s * pr_s)
        cp_b = cv_b + T_b * pT_b * pT_b / (rho_b * rho_b * pr_b)

        # geometry
        V_l = geo.V - V_v
        lev = geo.level(V_l)
        _, A_i, A_wet, P_c, width = geo.at(lev)
        wet_s, dry_s = geo.surfaces(lev, A_wet)
        C_dry = self.C_w - C_wet
        T_wet, T_dry = E_wet / C_wet, E_dry / C_dry

        # saturation
        sat_i = fp.sat(p_f)
        T_i, hl_i, hv_i, rl_i, rv_i, sig_i = (float(v) for v in sat_i)
        if n > 0:
            sat_p = fp.sat(p)
            T_sp, hl_p, hv_p, rl_p, rv_p, sig_p = (float(v) for v in sat_p)
        else:
            T_sp, hl_p, hv_p, rl_p, rv_p, sig_p = T_i, hl_i, hv_i, rl_i, rv_i, sig_i
        L_i = hv_i - hl_i
        L_p = hv_p - hl_p

        # sloshing
        A0, fr = inp["slosh_amplitude_m"], inp["slosh_frequency_Hz"]
        sloshing = A0 > 0 and fr > 0
        om1 = geo.omega1(lev, V_l, A_i, width) if sloshing else 1.0

        # liquid properties
        k_b, mu_b, cpf_b, rhof_b, beta_b = (float(v) for v in fp.liquid_film(T_b)[:5])
        nu_b = mu_b / rhof_b
        S_l = _slosh_intensity(A0, fr, geo.D, nu_b, om1) if sloshing else 0.0
        f_li = 1.0 + C_SLOSH_FLUID * S_l
        f_wl = 1.0 + C_SLOSH_WALL * S_l

        # wall - liquid (bulk temperature), film properties
        Tf = min(0.5 * (T_wet + T_b), T_sp)
        props_wl = tuple(float(v) for v in fp.liquid_film(Tf)[:5])
        Q_wl = _wall_h(wet_s, props_wl, T_wet - T_b, False) * f_wl * (T_wet - T_b)
        chi = BL_CARRY * _switch(T_wet - T_b)

        # nucleate boiling on the wetted wall (Rohsenow, Zuber cap)
        dTe = T_wet - T_sp
        Q_nb = 0.0
        sw_nb = _smoothstep((dTe - NB_ONSET_K) / NB_SWITCH_K)
        if sw_nb > 0.0:
            k_p, mu_p, cpl_p, rhol_p = (float(v) for v in fp.liquid_film(T_sp)[:4])
            Pr_p = mu_p * cpl_p / k_p
            sig = max(sig_p, 1e-6)
            q_r = mu_p * L_p * math.sqrt(G * (rhol_p - rv_p) / sig) * (
                cpl_p * dTe / (ROHSENOW_CSF * L_p * Pr_p ** ROHSENOW_N)) ** 3
            q_max = 0.131 * L_p * math.sqrt(rv_p) * (sig * G * (rhol_p - rv_p)) ** 0.25
            Q_nb = sw_nb * q_r / (1.0 + q_r / q_max) * A_wet
        J_nb = Q_nb / (hv_p - h_b)

        # wall - vapour
        Tfv = max(0.5 * (T_dry + T_v), T_i)
        props_wv = fp.vapour_film(Tfv, rho_v * T_v / Tfv)
        nu_v = props_wv[1] / props_wv[3]
        S_v = _slosh_intensity(A0, fr, geo.D, nu_v, om1) if sloshing else 0.0
        f_vi = 1.0 + C_SLOSH_FLUID * S_v
        f_wv = 1.0 + C_SLOSH_WALL * S_v
        Q_wv = _wall_h(dry_s, props_wv, T_dry - T_v, True) * f_wv * (T_dry - T_v)

        # interface, vapour side (length: tank diameter)
        Tfi = max(0.5 * (T_v + T_i), T_i)
        kf, muf, cpf, rhof, betaf = fp.vapour_film(Tfi, rho_v * T_v / Tfi)
        nuf, alf = muf / rhof, kf / (rhof * cpf)
        Ra = _rayleigh(betaf, T_v - T_i, geo.D, nuf, alf)
        wu = _switch(T_i - T_v)
        Nu = wu * 0.15 * Ra ** (1.0 / 3.0) + (1 - wu) * 0.27 * Ra ** 0.25 + 1.0
        Q_vi = Nu * kf / geo.D * f_vi * A_i * (T_v - T_i)

        # interface, liquid side (Globe-Dropkin) and surface layer - bulk
        delta_s = m_s / rho_s / A_i
        k_i, mu_i, cp_i, rho_i, beta_i = (float(v) for v in fp.liquid_film(0.5 * (T_s + T_i))[:5])
        nu_i, al_i = mu_i / rho_i, k_i / (rho_i * cp_i)
        D_i = math.sqrt(4 * A_i / math.pi)
        Ra = _rayleigh(beta_i, T_s - T_i, D_i, nu_i, al_i)
        h_gd = 0.069 * Ra ** (1.0 / 3.0) * (nu_i / al_i) ** 0.074 * k_i / D_i
        h_li = (_switch(T_s - T_i) * h_gd + 2 * k_i / delta_s) * f_li
        Q_li = h_li * A_i * (T_s - T_i)
        al_b = k_b / (rhof_b * cpf_b)
        Ra = _rayleigh(beta_b, T_b - T_s, D_i, nu_b, al_b)
        h_gd = 0.069 * Ra ** (1.0 / 3.0) * (nu_b / al_b) ** 0.074 * k_b / D_i
        h_sb = (_switch(T_b - T_s) * h_gd + 2 * k_b / delta_s) * f_li
        Q_sb = h_sb * A_i * (T_s - T_b)

        J = (Q_vi + Q_li) / L_i

        # bulk phase change
        J_fs = m_s * cp_s * _ramp(T_s - T_sp) / (TAU_FLASH_S * L_p)
        J_fb = m_b * cp_b * _ramp(T_b - T_sp) / (TAU_FLASH_S * L_p)
        J_fog = (m_v * cp_v + n * CP_HE) * _ramp(T_i - T_v) / (TAU_FOG_S * L_i)

        # surface-layer re-gridding
        m_tgt = SURFACE_FRACTION * (m_s + m_b)
        m_rg = (m_tgt - m_s) / TAU_REGRID_S
        w = _switch(m_rg, 1e-4 * m_tgt / TAU_REGRID_S)
        h_up = w * h_b + (1 - w) * h_s

        # wall conduction and capacity transfer
        Q_cond = self.k_w * self.t_w * P_c / geo.L_cond * (T_dry - T_wet)
        C_tgt = self.C_w * (CAP_FLOOR + (1 - 2 * CAP_FLOOR) * A_wet / geo.A_wall)
        dC = (C_tgt - C_wet) / TAU_CAPACITY_S
        w = _switch(dC, 1e-6 * self.C_w / TAU_CAPACITY_S)
        T_up = w * T_dry + (1 - w) * T_wet

        # boundary flows (true values)
        b = mech["inflow_meter_bias"]
        m_vin = (1 + b) * inp["mdot_v_in_kg_s"]
        m_lin = (1 + b) * inp["mdot_l_in_kg_s"]
        h_lin = self.h_lin0 + self.dh_lin * (p - self.p_lin0) if m_lin > 0 else 0.0
        m_vout = inp["mdot_v_out_kg_s"] + mech["vapor_leak_kg_s"]
        m_lout = inp["mdot_l_out_kg_s"] + mech["liquid_leak_kg_s"]
        w_f = m_v / (m_v + n * M_HE)
        out_f = w_f * m_vout
        out_he = (1 - w_f) * m_vout / M_HE
        Q_aw = inp["Q_aw_W"] + mech["heat_leak_wall_W"]
        a_wet = A_wet / geo.A_wall
        Q_lv, Q_ll = mech["heat_leak_vapor_W"], mech["heat_leak_liquid_W"]

        # mass and non-work energy rates
        md_v = m_vin - out_f + J + J_fs + J_fb + J_nb - J_fog
        nd = -out_he
        md_s = -J - J_fs + J_fog + m_rg
        md_b = m_lin - m_lout - J_fb - J_nb - m_rg
        F_v = (m_vin * self.h_vin - out_f * h_v - out_he * CP_HE * T_v - Q_vi + J * hv_i
               + (J_fs + J_fb + J_nb) * hv_p - J_fog * hl_i + Q_wv + Q_lv)
        F_s = -Q_li - J * hl_i - J_fs * hv_p + J_fog * hl_i + m_rg * h_up + chi * Q_wl - Q_sb
        F_b = (m_lin * h_lin - m_lout * h_b - J_fb * hv_p - J_nb * h_b - m_rg * h_up + (1 - chi) * Q_wl + Q_sb
               + Q_ll)

        # p dV work: rigid tank, linear system in (dT_v/dt, dp/dt)
        c_s, d_s = self._layer_rates(m_s, rho_s, p, cv_s, ur_s, pT_s, pr_s, F_s, md_s, h_s)
        c_b, d_b = self._layer_rates(m_b, rho_b, p, cv_b, ur_b, pT_b, pr_b, F_b, md_b, h_b)
        e, f = -(c_s + c_b), -(d_s + d_b)
        r0 = (md_v - rho_v * e) / V_v
        r1 = -rho_v * f / V_v
        A11 = m_v * cv_v + n * CV_HE
        A12 = m_v * ur_v * r1 + p * f
        B1 = F_v - md_v * u_v - nd * CV_HE * T_v - m_v * ur_v * r0 - p * e
        A21 = -(pT_v + n * R_GAS / V_v)
        A22 = 1.0 - pr_v * r1 + n * R_GAS * T_v * f / V_v ** 2
        B2 = pr_v * r0 + R_GAS * nd * T_v / V_v - n * R_GAS * T_v * e / V_v ** 2
        pdot = (A11 * B2 - A21 * B1) / (A11 * A22 - A12 * A21)
        Vd_s = c_s + d_s * pdot
        Vd_b = c_b + d_b * pdot
        Vd_v = -(Vd_s + Vd_b)

        dy = np.empty(self.NY)
        dy[0] = md_v
        dy[1] = F_v - p * Vd_v
        dy[2] = nd
        dy[3] = md_s
        dy[4] = F_s - p * Vd_s
        dy[5] = md_b
        dy[6] = F_b - p * Vd_b
        dy[7] = a_wet * Q_aw - Q_wl - Q_nb + Q_cond + dC * T_up
        dy[8] = (1 - a_wet) * Q_aw - Q_wv - Q_cond - dC * T_up
        dy[9] = dC
        dy[10] = m_vin + m_lin - out_f - m_lout
        dy[11] = nd
        dy[12] = (Q_aw + Q_lv + Q_ll + m_vin * self.h_vin + m_lin * h_lin - out_f * h_v - out_he * CP_HE * T_v
                  - m_lout * h_b)
        self.last = {"J": J, "Q_vi": Q_vi, "Q_li": Q_li, "Q_wl": Q_wl, "Q_wv": Q_wv, "Q_nb": Q_nb, "J_fog": J_fog,
                     "J_flash": J_fs + J_fb, "pdot": pdot}
        return dy

    @staticmethod
    def _layer_rates(m, rho, p, cv, u_r, p_T, p_r, F, md, h):
        """dV/dt = c + d dp/dt of a liquid volume (energy equation in enthalpy form)."""
        v_T = p_T / (rho * rho * p_r)
        v_p = -1.0 / (rho * rho * p_r)
        cp = cv - u_r * p_T / p_r + p * v_T
        q = u_r / p_r + p * v_p
        a = (F - md * h) / (m * cp)
        bb = -q / cp
        return md / rho + m * v_T * a, m * (v_T * bb + v_p)

    # ---- sensors and totals
    def observe(self, y: np.ndarray) -> dict[str, float]:
        st = self.recover(y)
        V_l = self.geom.V - st["V_v"]
        lev = self.geom.level(V_l)
        m_l = st["m_s"] + st["m_b"]
        return {"p": st["p"], "p_f": st["p_f"], "p_he": st["p_he"], "T_v": st["T_v"],
                "T_l": (st["m_s"] * st["T_s"] + st["m_b"] * st["T_b"]) / m_l, "T_s": st["T_s"], "T_b": st["T_b"],
                "T_w": (float(y[7]) + float(y[8])) / self.C_w, "T_wet": float(y[7]) / float(y[9]),
                "T_dry": float(y[8]) / (self.C_w - float(y[9])), "level": lev, "fill": V_l / self.geom.V,
                "m_v": st["m_v"], "m_l": m_l, "n_he": st["n"]}

    def totals(self, y: np.ndarray) -> tuple[float, float, float]:
        """(fluid mass, helium mol, energy) in the tank, wall included."""
        return (float(y[0] + y[3] + y[5]), float(y[2]), float(y[1] + y[4] + y[6] + y[7] + y[8]))


# ------------------------------------------------------------------------------- scenarios
def _p_init_range(fp: FluidProps) -> tuple[float, float]:
    lo = max(1.05 * P_NBP, 0.8e5, 1.6 * fp.p_trip)
    return lo, max(lo * 1.1, 0.35 * fp.p_c)


def _build_scenario(name: str, fluid: str, tank: dict, material: str, thickness_m: float, q_W_m2: float,
                    fill: float, p0: float, subcool_K: float, superheat_K: float, dry_extra_K: float,
                    wet_extra_K: float, phases: list[dict]) -> dict[str, Any]:
    fp = fluid_props(fluid)
    geo = Geometry(tank)
    lo, hi = _p_init_range(fp)
    p0 = min(max(p0, lo), hi)
    T_sat = fp.T_sat(p0)
    T_l = max(T_sat - subcool_K, fp.T_trip + 0.5)
    T_v = T_sat + superheat_K
    T_wet, T_dry = T_l + wet_extra_K, T_v + dry_extra_K
    h = geo.level(fill * geo.V)
    a_wet = geo.at(h)[2] / geo.A_wall
    T_w_mean = a_wet * T_wet + (1 - a_wet) * T_dry
    C_w, k_w = _wall_capacity(material, thickness_m, geo.A_wall, T_w_mean)
    return {
        "name": name, "fluid": fluid, "tank": {"shape": tank["shape"], **geo.tank_dims()},
        "wall": {"material": material, "thickness_m": thickness_m, "C_w_J_per_K": C_w, "k_w_W_per_mK": k_w},
        "Q_aw_W": q_W_m2 * geo.A_wall, "heat_flux_W_m2": q_W_m2,
        "initial": {"p_Pa": p0, "T_l_K": T_l, "T_v_K": T_v, "T_wet_K": T_wet, "T_dry_K": T_dry, "fill_ratio": fill},
        "phases": phases,
        "duration_s": float(sum(ph["duration_s"] for ph in phases)),
    }


def _ln2_dewar(fluid: str | None) -> dict[str, Any]:
    tank = _tank_from_volume("vertical_cylinder_elliptical_heads", 2.0, 1.15, 2.0)
    phases = [{"kind": "rest", "duration_s": 1200.0},
              {"kind": "vent", "duration_s": 600.0, "p_frac": 0.8},
              {"kind": "rest", "duration_s": 900.0},
              {"kind": "drain", "duration_s": 600.0, "dfill": 0.2},
              {"kind": "rest", "duration_s": 900.0}]
    return _build_scenario("ln2_dewar", fluid or "Nitrogen", tank, "steel", 0.005, 3.0, 0.7, 1.38 * P_NBP,
                           1.0, 4.0, 2.0, 0.05, phases)


def _lch4_sphere(fluid: str | None) -> dict[str, Any]:
    tank = _tank_from_volume("sphere", 30.0, 1.0)
    phases = [{"kind": "rest", "duration_s": 600.0},
              {"kind": "pressurize", "duration_s": 900.0, "dp_frac": 0.4, "T_in_factor": 1.6},
              {"kind": "rest", "duration_s": 600.0},
              {"kind": "slosh", "duration_s": 900.0, "amp_m": 0.01, "freq_ratio": 1.0},
              {"kind": "fill", "duration_s": 1200.0, "dfill": 0.15, "subcool_K": 2.0},
              {"kind": "rest", "duration_s": 600.0}]
    return _build_scenario("lch4_sphere", fluid or "Methane", tank, "aluminium", 0.008, 2.0, 0.55, 2.0 * P_NBP,
                           2.0, 5.0, 2.0, 0.05, phases)


def _lh2_hcyl(fluid: str | None) -> dict[str, Any]:
    tank = {"shape": "horizontal_cylinder", "radius_m": 0.9, "cylinder_length_m": 8.0 / (math.pi * 0.81)}
    phases = [{"kind": "rest", "duration_s": 600.0},
              {"kind": "drain", "duration_s": 900.0, "dfill": 0.2},
              {"kind": "rest", "duration_s": 600.0},
              {"kind": "vent", "duration_s": 600.0, "p_frac": 0.75},
              {"kind": "slosh", "duration_s": 1200.0, "amp_m": 0.005, "freq_ratio": 0.9},
              {"kind": "rest", "duration_s": 600.0}]
    return _build_scenario("lh2_hcyl", fluid or "ParaHydrogen", tank, "steel", 0.006, 5.0, 0.6, 2.0 * P_NBP,
                           0.5, 3.0, 2.0, 0.05, phases)


NAMED_SCENARIOS = {
    "ln2_dewar": ("Nitrogen, 2 m3 vertical cylinder with 2:1 elliptical heads, steel; self-pressurisation, "
                  "vent, drain", _ln2_dewar),
    "lch4_sphere": ("Methane, 30 m3 sphere, aluminium; warm-gas pressurisation, sloshing near resonance, fill",
                    _lch4_sphere),
    "lh2_hcyl": ("ParaHydrogen, 8 m3 horizontal cylinder, steel; drain, vent, sloshing", _lh2_hcyl),
}


def named_scenario(name: str, fluid: str | None = None) -> dict[str, Any]:
    if name not in NAMED_SCENARIOS:
        raise ValueError(f"unknown scenario {name!r}; known: {', '.join(NAMED_SCENARIOS)}, random_SEED")
    return NAMED_SCENARIOS[name][1](fluid)


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


def random_scenario(seed: int, fluid: str | None = None, ops: Sequence[str] | None = None,
                    phase_s: tuple[float, float] = (300.0, 1500.0),
                    total_s: tuple[float, float] = (3600.0, 7200.0)) -> dict[str, Any]:
    """A random, physically plausible tank and schedule (deterministic in ``seed``).

    ``ops``: the phase kinds in order (default: 4-8 phases drawn from :data:`OPERATIONS`);
    ``phase_s``: the range of phase durations; ``total_s``: the range of the total duration
    (ignored when ``ops`` is given)."""
    rng = np.random.default_rng([int(seed), 20240611])
    drawn_fluid = str(rng.choice(FLUIDS))  # always drawn: a given fluid keeps the same tank and schedule
    fl = fluid or drawn_fluid
    fp = fluid_props(fl)
    shape = str(rng.choice(SHAPES))
    V = math.exp(rng.uniform(math.log(0.5), math.log(60.0)))
    if shape == "vertical_cylinder":
        tank = _tank_from_volume(shape, V, rng.uniform(0.8, 3.0))
    elif shape == "vertical_cylinder_elliptical_heads":
        tank = _tank_from_volume(shape, V, rng.uniform(0.3, 2.5), float(rng.choice([2.0, 2.0, 1.5, 3.0])))
    elif shape == "sphere":
        tank = _tank_from_volume(shape, V, 1.0)
    else:
        tank = _tank_from_volume(shape, V, rng.uniform(1.5, 4.0))
    material = "steel" if rng.random() < 0.6 else "aluminium"
    geo = Geometry(tank)
    mat = _MATERIALS[material]
    t_factor = rng.uniform(1.0, 1.5)
    q = math.exp(rng.uniform(math.log(1.0), math.log(10.0)))
    fill = rng.uniform(0.2, 0.9)
    lo, hi = _p_init_range(fp)
    p0 = math.exp(rng.uniform(math.log(lo), math.log(hi)))
    p_design = min(max(2.0 * p0, 4e5), fp.p_max)  # shell designed for twice the initial pressure
    thickness = max(mat["t_min"], 1.5 * p_design * geo.R / mat["allow_Pa"]) * t_factor
    subcool = rng.uniform(0.0, 0.05) if rng.random() < 0.35 else rng.uniform(0.2, 3.0)
    superheat = rng.uniform(0.0, 8.0)
    dry_extra, wet_extra = rng.uniform(0.0, 3.0), rng.uniform(0.0, 0.2)
    if ops is not None:
        kinds = [str(k) for k in ops]
        bad = [k for k in kinds if k not in OPERATIONS]
        if bad:
            raise ValueError(f"unknown operations {bad}; known: {OPERATIONS}")
        durs = [10.0 * round(rng.uniform(*phase_s) / 10.0) for _ in kinds]
    else:
        for _ in range(10000):
            n = int(rng.integers(4, 9))
            durs = [10.0 * round(rng.uniform(*phase_s) / 10.0) for _ in range(n)]
            if total_s[0] <= sum(durs) <= total_s[1]:
                break
        weights = np.array([0.25, 0.15, 0.2, 0.12, 0.13, 0.15])
        kinds = [str(k) for k in rng.choice(OPERATIONS, size=len(durs), p=weights / weights.sum())]
    phases = [_draw_phase(k, d, rng) for k, d in zip(kinds, durs)]
    return _build_scenario(f"random_{seed}", fl, tank, material, float(thickness), q, fill, p0, subcool, superheat,
                           dry_extra, wet_extra, phases)


def resolve_scenario(scenario: str | Mapping[str, Any], fluid: str | None = None) -> dict[str, Any]:
    if isinstance(scenario, Mapping):
        sc = copy.deepcopy(dict(scenario))
        if fluid and fluid != sc["fluid"]:
            raise ValueError("pass the fluid to random_scenario/named_scenario, not with a scenario dict")
        return sc
    if scenario.startswith("random_"):
        try:
            seed = int(scenario.split("_", 1)[1])
        except ValueError:
            raise ValueError(f"random scenarios are named random_SEED (an integer), got {scenario!r}") from None
        return random_scenario(seed, fluid=fluid)
    return named_scenario(scenario, fluid)


# ------------------------------------------------------------------------------- operator policy
def _plan_inputs(model: _Model, y: np.ndarray, ph: Mapping[str, Any], dur: float, Q_aw: float) -> dict[str, float]:
    """Metered inputs of a phase from the (nominal) state at its start."""
    fp, geo = model.fp, model.geom
    inp = {c: 0.0 for c in INPUT_COLUMNS}
    inp["Q_aw_W"] = Q_aw
    o = model.observe(y)
    st = model.recover(y)
    p, T_v, V_v = st["p"], st["T_v"], st["V_v"]
    kind = ph["kind"]
    dur = max(dur, 1.0)
    if kind == "pressurize":
        p1 = min(p * (1 + ph["dp_frac"]), 0.5 * fp.p_c)
        if p1 > p * 1.02:
            p_in = min(1.25 * p1, 0.75 * fp.p_c)
            T_in = ph["T_in_factor"] * fp.T_sat(p)
            T_in = max(min(T_in, 300.0), fp.T_sat(p_in) + 10.0)
            # adiabatic filling of the ullage with hot gas (ideal-gas estimate), plus 50 % for losses
            fp.vap.update(CP.DmassT_INPUTS, st["rho_v"], T_v)
            gamma = fp.vap.cpmass() / fp.vap.cvmass()
            dm = 1.5 * (p1 - p) * V_v / (gamma * fp.R_s * T_in)
            if dm > 0:
                inp.update(mdot_v_in_kg_s=dm / dur, T_v_in_K=T_in, p_v_in_Pa=p_in)
    elif kind == "vent":
        p1 = max(p * ph["p_frac"], 1.2 * fp.p_min)
        if p1 < 0.97 * p:
            rho1 = fp.rho_pT(max(p1 - st["p_he"], 1.1 * fp.p_trip), T_v, "gas")
            dm = V_v * max(st["rho_v"] - rho1, 0.0)
            T1 = fp.T_sat(p1)
            for m, T in ((st["m_s"], st["T_s"]), (st["m_b"], st["T_b"])):
                r = fp.liquid_film(T)
                dm += m * float(r[2]) * max(T - T1, 0.0) / (fp.sat(p1)[2] - fp.sat(p1)[1])
            dm *= (1 + st["n"] * M_HE / st["m_v"])
            if dm > 0:
                inp["mdot_v_out_kg_s"] = dm / dur
    elif kind == "fill":
        dfill = min(ph["dfill"], 0.9 - o["fill"])
        if dfill > 0.01:
            T_in = max(min(fp.T_sat(p) - ph["subcool_K"], fp.T_sat(0.45 * fp.p_c)), fp.T_trip + 1.0)
            rho_in = fp.rho_pT(p, T_in, "liquid")
            inp.update(mdot_l_in_kg_s=rho_in * dfill * geo.V / dur, T_l_in_K=T_in)
    elif kind == "drain":
        dfill = min(ph["dfill"], o["fill"] - 0.1)
        if dfill > 0.01:
            inp["mdot_l_out_kg_s"] = st["rho_b"] * dfill * geo.V / dur
    elif kind == "slosh":
        V_l = geo.V - V_v
        lev = geo.level(V_l)
        _, A_i, _, _, width = geo.at(lev)
        om1 = geo.omega1(lev, V_l, A_i, width)
        inp.update(slosh_amplitude_m=ph["amp_m"], slosh_frequency_Hz=ph["freq_ratio"] * om1 / (2 * math.pi))
    elif kind != "rest":
        raise ValueError(f"unknown phase kind {kind!r}")
    return inp


# ------------------------------------------------------------------------------- integration

def _event_function(model: _Model, name: str, threshold: float):
    """A terminal solve_ivp event: a soft bound (NAME, threshold) or a hard validity limit."""
    fp, V = model.fp, model.geom.V

    if name == "p_high":
        def fn(t, y):
            return model.recover(y)["p"] - threshold
        fn.direction = 1
    elif name == "p_low":
        def fn(t, y):
            return model.recover(y)["p"] - threshold
        fn.direction = -1
    elif name == "fill_high":
        def fn(t, y):
            return (V - model.recover(y)["V_v"]) / V - threshold
        fn.direction = 1
    elif name == "fill_low":
        def fn(t, y):
            return (V - model.recover(y)["V_v"]) / V - threshold
        fn.direction = -1
    elif name == "hard_p_high":
        def fn(t, y):
            return model.recover(y)["p_f"] - 0.88 * fp.p_c
        fn.direction = 1
    elif name == "hard_p_low":
        def fn(t, y):
            return model.recover(y)["p_f"] - 1.1 * fp.p_trip
        fn.direction = -1
    elif name == "hard_fill":
        def fn(t, y):
            f = (V - model.recover(y)["V_v"]) / V
            return min(f - 0.01, 0.985 - f)
        fn.direction = -1
    else:
        raise ValueError(name)
    fn.terminal = True
    return fn


def _integrate(model: _Model, sc: Mapping[str, Any], duration: float, phases: list[dict] | None,
               fixed: list[dict] | None) -> dict[str, Any]:
    """Integrate over the schedule; ``phases`` (planning) or ``fixed`` segments (replay)."""
    fp = model.fp
    p_hi, p_lo = 0.93 * fp.p_max, 1.03 * fp.p_min
    samples = np.arange(0.0, duration + 1e-9, SAMPLE_DT_S)
    y = model.y0.copy()
    scale_m = float(y[0] + y[3] + y[5])
    L_nbp = float(fp.sat(P_NBP)[2] - fp.sat(P_NBP)[1])
    scale_U = scale_m * L_nbp
    atol = np.array([1e-9 * scale_m, 1e-9 * scale_U, 1e-9 * max(float(y[2]), 1e-3), 1e-9 * scale_m,
                     1e-9 * scale_U, 1e-9 * scale_m, 1e-9 * scale_U, 1e-9 * model.C_w * 20,
                     1e-9 * model.C_w * 20, 1e-9 * model.C_w, 1e-6 * scale_m, 1e-6 * max(float(y[2]), 1e-3),
                     1e-6 * scale_U])
    rtol = RTOL

    plan = fixed if fixed is not None else []
    if fixed is None:
        t0 = 0.0
        for ph in phases:
            if t0 >= duration - 1e-9:
                break
            plan.append({"t0": t0, "t1": min(t0 + ph["duration_s"], duration), "phase": ph})
            t0 += ph["duration_s"]
        if plan and plan[-1]["t1"] < duration - 1e-9:
            plan.append({"t0": plan[-1]["t1"], "t1": duration, "phase": {"kind": "rest", "duration_s": 0.0}})
    executed: list[dict] = []
    changes: list[dict] = []
    ys: dict[float, np.ndarray] = {}
    t = 0.0
    for seg in plan:
        t_end = min(seg["t1"], duration)
        if t_end <= t + 1e-9:
            continue
        if fixed is None:
            inputs = _plan_inputs(model, y, seg["phase"], t_end - t, sc["Q_aw_W"])
            kind = seg["phase"]["kind"]
        else:
            inputs = dict(seg["inputs"])
            kind = seg["kind"]
        # soft bounds (thresholds re-armed after each firing) and hard validity limits
        thr = {"p_high": p_hi, "p_low": p_lo, "fill_high": 0.94, "fill_low": 0.06}
        n_fired = 0
        while t < t_end - 1e-9:
            p_now = model.recover(y)["p"]
            model.set_inputs(inputs, p_now)
            evs, names = [], []
            for nm in ("p_high", "p_low", "fill_high", "fill_low", "hard_p_high", "hard_p_low", "hard_fill"):
                if nm in thr or nm.startswith("hard"):
                    fn = _event_function(model, nm, thr.get(nm, 0.0))
                    evs.append(fn)
                    names.append(nm)
            t_eval = [s for s in samples if t - 1e-9 <= s < t_end - 1e-9]
            t_eval.append(t_end)
            try:
                sol = solve_ivp(model.rhs, (t, t_end), y, method="LSODA", t_eval=t_eval, events=evs, rtol=rtol,
                                atol=atol, max_step=60.0)
            except SimulationError as e:
                raise SimulationError(f"{e} (segment starting at t={t:.1f} s, inputs {inputs})") from None
            if sol.status == -1:
                raise SimulationError(f"integration failed at t={sol.t[-1] if sol.t.size else t:.1f} s: "
                                      f"{sol.message}")
            for k, tk in enumerate(sol.t):
                if tk < t_end - 1e-9 or abs(tk - duration) < 1e-9:
                    ys[float(tk)] = sol.y[:, k].copy()
            if sol.status != 1:
                y = sol.y[:, -1].copy()
                executed.append({"t0": t, "t1": t_end, "kind": kind, "inputs": dict(inputs)})
                t = t_end
                continue
            k_ev = next(i for i, te in enumerate(sol.t_events) if te.size)
            te = float(sol.t_events[k_ev][0])
            y = sol.y_events[k_ev][0].copy()
            name = names[k_ev]
            o = model.observe(y)
            if name.startswith("hard"):
                raise SimulationError(f"the run left the model's validity range at t={te:.1f} s ({name}: "
                                      f"p={o['p']:.6g} Pa, p_f={o['p_f']:.6g} Pa, fill={o['fill']:.4f}; "
                                      f"inputs {inputs})")
            n_fired += 1
            if n_fired > 40:
                raise SimulationError(f"more than 40 bound events in the phase ending at {t_end:.1f} s")
            if te > t + 1e-9:
                executed.append({"t0": t, "t1": te, "kind": kind, "inputs": dict(inputs)})
            new = dict(inputs)
            action = "none"
            if name == "p_high":
                if new["mdot_v_in_kg_s"] > 0 or new["mdot_l_in_kg_s"] > 0:
                    new.update(mdot_v_in_kg_s=0.0, T_v_in_K=0.0, p_v_in_Pa=0.0, mdot_l_in_kg_s=0.0, T_l_in_K=0.0)
                    action = "stopped the inflows"
                else:
                    relief = 0.3 * (o["m_v"] + o["n_he"] * M_HE) / max(t_end - te, 300.0)
                    new["mdot_v_out_kg_s"] = max(2 * new["mdot_v_out_kg_s"], relief)
                    action = f"relief vent {new['mdot_v_out_kg_s']:.4g} kg/s"
                thr["p_high"] = 1.01 * o["p"]
                thr["p_low"] = min(thr.get("p_low", p_lo), p_lo)
            elif name == "p_low":
                if new["mdot_v_out_kg_s"] > 0 or new["mdot_l_out_kg_s"] > 0:
                    new.update(mdot_v_out_kg_s=0.0, mdot_l_out_kg_s=0.0)
                    action = "stopped the vent/drain"
                    thr["p_low"] = 0.98 * o["p"]
                else:
                    del thr["p_low"]
            elif name == "fill_high":
                if new["mdot_l_in_kg_s"] > 0:
                    new.update(mdot_l_in_kg_s=0.0, T_l_in_K=0.0)
                    action = "stopped the fill"
                    thr["fill_high"] = o["fill"] + 0.01
                else:
                    del thr["fill_high"]
            elif name == "fill_low":
                if new["mdot_l_out_kg_s"] > 0:
                    new["mdot_l_out_kg_s"] = 0.0
                    action = "stopped the drain"
                    thr["fill_low"] = o["fill"] - 0.01
                else:
                    del thr["fill_low"]
            changes.append({"t_s": te, "event": name, "action": action})
            inputs = new
            t = te
    return {"executed": executed, "changes": changes, "ys": ys, "y_end": y}


# ------------------------------------------------------------------------------- driver
def _check_mechanisms(mechanisms: Mapping[str, float] | None) -> dict[str, float]:
    mech = dict(mechanisms or {})
    unknown = sorted(set(mech) - set(MECHANISMS))
    if unknown:
        raise ValueError(f"unknown mechanisms {unknown}; known: {', '.join(MECHANISMS)}")
    out = {k: float(v) for k, v in mech.items()}
    for k in ("vapor_leak_kg_s", "liquid_leak_kg_s", "helium_mol"):
        if out.get(k, 0.0) < 0:
            raise ValueError(f"{k} must be >= 0")
    if out.get("inflow_meter_bias", 0.0) <= -1:
        raise ValueError("inflow_meter_bias must be > -1")
    return out


def simulate(scenario: str | Mapping[str, Any], mechanisms: Mapping[str, float] | None = None, *,
             fluid: str | None = None, duration_s: float | None = None) -> dict[str, Any]:
    """Noise-free truth: the resolved scenario, the executed schedule, sampled states."""
    wall0 = time.perf_counter()
    sc = resolve_scenario(scenario, fluid)
    mech = _check_mechanisms(mechanisms)
    duration = float(duration_s if duration_s is not None else sc["duration_s"])
    if duration <= 0:
        raise ValueError("duration must be > 0")
    nominal = _Model(sc, {})
    res = _integrate(nominal, sc, duration, sc["phases"], None)
    nfev = nominal.nfev
    model = nominal
    if any(v != 0.0 for v in mech.values()):
        model = _Model(sc, mech)
        fixed = [dict(seg) for seg in res["executed"]]
        res = _integrate(model, sc, duration, None, fixed)
        nfev += model.nfev
    times = np.array(sorted(res["ys"]))
    Y = np.array([res["ys"][t] for t in times])
    obs = [model.observe(y) for y in Y]
    M0, N0, E0 = model.totals(model.y0)
    err_m = np.array([model.totals(y)[0] - M0 - y[10] for y in Y])
    err_n = np.array([model.totals(y)[1] - N0 - y[11] for y in Y])
    err_e = np.array([model.totals(y)[2] - E0 - y[12] for y in Y])
    # scales: mass and energy that moved through the tank or its boundary
    fp = model.fp
    L_nbp = float(fp.sat(P_NBP)[2] - fp.sat(P_NBP)[1])
    moved = sum((s["t1"] - s["t0"]) * (s["inputs"]["mdot_v_in_kg_s"] + s["inputs"]["mdot_v_out_kg_s"]
                                        + s["inputs"]["mdot_l_in_kg_s"] + s["inputs"]["mdot_l_out_kg_s"])
                for s in res["executed"])
    heat = sum((s["t1"] - s["t0"]) * abs(s["inputs"]["Q_aw_W"]) for s in res["executed"])
    scale_m = M0 + moved
    scale_e = heat + (moved + 0.01 * M0) * L_nbp
    return {"scenario": sc, "mechanisms": mech, "model": model, "times": times, "Y": Y, "obs": obs,
            "executed": res["executed"], "changes": res["changes"], "duration_s": duration,
            "closure": {"mass_kg_max_abs": float(np.max(np.abs(err_m))),
                        "mass_rel": float(np.max(np.abs(err_m)) / scale_m),
                        "helium_mol_max_abs": float(np.max(np.abs(err_n))),
                        "energy_J_max_abs": float(np.max(np.abs(err_e))),
                        "energy_rel": float(np.max(np.abs(err_e)) / scale_e),
                        "energy_scale_J": scale_e, "mass_scale_kg": scale_m},
            "nfev": nfev, "wall_time_s": time.perf_counter() - wall0}


def _fmt(v: float) -> str:
    return repr(float(v))


def simulate_run(scenario: str | Mapping[str, Any], mechanisms: Mapping[str, float] | None = None,
                 noise: str = "low", seed: int = 0, out_dir: str | pathlib.Path = ".", name: str | None = None,
                 fluid: str | None = None, duration_s: float | None = None,
                 wall_capacity_unknown: bool = False) -> dict[str, pathlib.Path]:
    """Simulate and write ``NAME.json``, ``NAME.csv`` and ``NAME.truth.json``.

    Args:
        scenario: a named scenario (:data:`NAMED_SCENARIOS`), ``random_SEED``, or a scenario
            dict from :func:`random_scenario` / :func:`named_scenario`.
        mechanisms: hidden mechanisms, ``{name: value}`` (see :data:`MECHANISMS`).
        noise: ``"none"``, ``"low"`` or ``"high"`` (``"none"`` writes the low ``noise_std``).
        seed: seeds the sensor noise.
        out_dir: folder (created if needed).
        name: run name (default ``cryo_<scenario>``).
        fluid: CoolProp fluid overriding the scenario's.
        duration_s: shorten (or extend with rest) the scenario.
        wall_capacity_unknown: write ``null`` for the wall heat capacity.

    Returns ``{"json": path, "csv": path, "truth": path}``.
    """
    if noise not in ("none", "low", "high"):
        raise ValueError(f"noise must be none, low or high, got {noise!r}")
    res = simulate(scenario, mechanisms, fluid=fluid, duration_s=duration_s)
    sc, model, mech = res["scenario"], res["model"], res["mechanisms"]
    duration = res["duration_s"]
    std = NOISE_LEVELS["low" if noise == "none" else noise]
    rng = np.random.default_rng(seed)
    times, obs = res["times"], res["obs"]
    bias_p = mech.get("pressure_sensor_bias_Pa", 0.0)
    bias_T = mech.get("temperature_sensor_bias_K", 0.0)
    true_ch = {"p_v_Pa": np.array([o["p"] for o in obs]) + bias_p,
               "T_v_K": np.array([o["T_v"] for o in obs]),
               "T_l_K": np.array([o["T_l"] for o in obs]) + bias_T,
               "T_w_K": np.array([o["T_w"] for o in obs]),
               "H_l_m": np.array([o["level"] for o in obs])}
    measured: dict[str, dict[float, float]] = {}
    for ch, key in zip(OBS_COLUMNS, NOISE_KEYS):
        dt = SAMPLE_DT_WALL_S if ch == "T_w_K" else SAMPLE_DT_S
        sel = np.array([abs(t / dt - round(t / dt)) < 1e-9 for t in times])
        vals = true_ch[ch][sel]
        if noise != "none":
            vals = vals + rng.normal(0.0, std[key], size=vals.size)
        if ch == "H_l_m":
            vals = np.maximum(vals, 0.0)
        measured[ch] = dict(zip(times[sel].tolist(), vals.tolist()))

    executed = res["executed"]
    used = [c for c in INPUT_COLUMNS if any(s["inputs"][c] != 0.0 for s in executed)]
    rows_t = sorted(set(times.tolist()) | {float(s["t0"]) for s in executed})
    run_name = name or f"cryo_{sc['name']}"
    out = pathlib.Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    csv_path = out / f"{run_name}.csv"
    with open(csv_path, "w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(["t_s", *OBS_COLUMNS, *used])
        k = 0
        for t in rows_t:
            while k + 1 < len(executed) and executed[k + 1]["t0"] <= t + 1e-12:
                k += 1
            row = [_fmt(t)]
            for ch in OBS_COLUMNS:
                v = measured[ch].get(t)
                row.append("" if v is None else _fmt(v))
            row.extend(_fmt(executed[k]["inputs"][c]) for c in used)
            w.writerow(row)

    o0 = obs[0]
    tank = {**sc["tank"], "volume_m3": model.geom.V,
            "wall_heat_capacity_J_per_K": None if wall_capacity_unknown else model.C_meta}
    meta = {
        "name": run_name,
        "fluid": sc["fluid"],
        "source": f"{SIMULATOR}: independent 0D multi-fluid tank simulator (CoolProp HEOS), scenario {sc['name']}",
        "tank": tank,
        "initial": {"p_v_Pa": o0["p"] + bias_p, "T_v_K": o0["T_v"], "T_l_K": o0["T_l"] + bias_T, "T_w_K": o0["T_w"],
                    "fill_ratio": o0["fill"]},
        "noise_std": {k: std[k] for k in NOISE_KEYS},
        "duration_s": duration,
        "timeseries": csv_path.name,
    }
    json_path = out / f"{run_name}.json"
    json_path.write_text(json.dumps(meta, indent=2) + "\n")

    def summary(key):
        v = np.array([o[key] for o in obs])
        return {"min": float(v.min()), "max": float(v.max()), "final": float(v[-1])}

    truth = {
        "simulator": SIMULATOR,
        "scenario": sc,
        "mechanisms": {k: mech.get(k, 0.0) for k in MECHANISMS},
        "noise": noise,
        "seed": seed,
        "transport_properties": model.fp.transport,
        "wall_heat_capacity_true_J_per_K": model.C_w,
        "wall_heat_capacity_metadata_J_per_K": model.C_meta,
        "wall_heat_capacity_written": not wall_capacity_unknown,
        "initial_true": {"p_Pa": o0["p"], "p_fluid_Pa": o0["p_f"], "p_helium_Pa": o0["p_he"], "T_v_K": o0["T_v"],
                         "T_l_K": o0["T_l"], "T_w_K": o0["T_w"], "T_wet_K": o0["T_wet"], "T_dry_K": o0["T_dry"],
                         "fill_ratio": o0["fill"], "level_m": o0["level"], "m_v_kg": o0["m_v"], "m_l_kg": o0["m_l"],
                         "helium_mol": o0["n_he"]},
        "final_true": {"p_Pa": obs[-1]["p"], "p_helium_Pa": obs[-1]["p_he"], "T_v_K": obs[-1]["T_v"],
                       "T_l_K": obs[-1]["T_l"], "T_w_K": obs[-1]["T_w"], "fill_ratio": obs[-1]["fill"],
                       "level_m": obs[-1]["level"], "m_v_kg": obs[-1]["m_v"], "m_l_kg": obs[-1]["m_l"],
                       "helium_mol": obs[-1]["n_he"]},
        "summary": {k: summary(k) for k in ("p", "T_v", "T_l", "T_w", "level", "fill", "p_he")},
        "schedule": [{"t0_s": s["t0"], "t1_s": s["t1"], "kind": s["kind"],
                      "inputs": {c: v for c, v in s["inputs"].items() if v != 0.0}} for s in executed],
        "schedule_changes": res["changes"],
        "closure": res["closure"],
        "rhs_calls": res["nfev"],
        "wall_time_s": res["wall_time_s"],
    }
    truth_path = out / f"{run_name}.truth.json"
    truth_path.write_text(json.dumps(truth, indent=2) + "\n")
    return {"json": json_path, "csv": csv_path, "truth": truth_path}


# ------------------------------------------------------------------------------- command line
def _parse_mechanism(text: str) -> tuple[str, float]:
    if "=" not in text:
        raise argparse.ArgumentTypeError(f"--mechanism needs NAME=VALUE, got {text!r}")
    k, v = text.split("=", 1)
    if k not in MECHANISMS:
        raise argparse.ArgumentTypeError(f"unknown mechanism {k!r}; known: {', '.join(MECHANISMS)}")
    try:
        return k, float(v)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--mechanism {k}: {v!r} is not a number") from None


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="Independent 0D multi-fluid cryogenic tank simulator: writes runs in "
                                             "the interchange format (NAME.json, NAME.csv, NAME.truth.json).")
    ap.add_argument("scenario", nargs="?", help="a named scenario (see --list) or random_SEED")
    ap.add_argument("--list", action="store_true", help="list the scenarios, mechanisms and fluids, and exit")
    ap.add_argument("--fluid", help="CoolProp fluid (overrides the scenario's)")
    ap.add_argument("--mechanism", action="append", default=[], type=_parse_mechanism, metavar="NAME=VALUE",
                    help="hidden mechanism (repeatable)")
    ap.add_argument("--noise", default="low", choices=("none", "low", "high"))
    ap.add_argument("--seed", type=int, default=0, help="seed of the sensor noise")
    ap.add_argument("--out", default=".", help="output folder")
    ap.add_argument("--name", help="run name (default cryo_SCENARIO)")
    ap.add_argument("--duration", type=float, help="duration [s] (shortens the scenario)")
    ap.add_argument("--wall-capacity-unknown", action="store_true", help="write null for the wall heat capacity")
    args = ap.parse_args(argv)
    if args.list:
        for k, (desc, _) in NAMED_SCENARIOS.items():
            print(f"{k:14s} {desc}")
        print(f"{'random_SEED':14s} a random plausible tank and schedule (fluid among {', '.join(FLUIDS)})")
        print("mechanisms: " + ", ".join(MECHANISMS))
        return 0
    if not args.scenario:
        ap.error("SCENARIO is required (or --list)")
    try:
        paths = simulate_run(args.scenario, dict(args.mechanism), noise=args.noise, seed=args.seed,
                             out_dir=args.out, name=args.name, fluid=args.fluid, duration_s=args.duration,
                             wall_capacity_unknown=args.wall_capacity_unknown)
    except (ValueError, SimulationError) as e:
        print(f"cryo_sim: error: {e}", file=sys.stderr)
        return 2
    truth = json.loads(paths["truth"].read_text())
    s, c = truth["summary"], truth["closure"]
    print(f"wrote {paths['json']} ({truth['scenario']['fluid']}, {truth['wall_time_s']:.2f} s, "
          f"{truth['rhs_calls']} rhs calls; p {s['p']['min']:.0f}..{s['p']['max']:.0f} Pa, "
          f"fill {s['fill']['min']:.3f}..{s['fill']['max']:.3f}; closure mass {c['mass_rel']:.1e}, "
          f"energy {c['energy_rel']:.1e})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
