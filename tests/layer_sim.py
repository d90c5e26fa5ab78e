"""Independent *stratified* (multi-layer) simulator of a cryogenic tank, for CoolProp pure fluids.

``layer_sim`` writes synthetic "measured" runs in the project's interchange format
(``shared/data-format.md``: ``NAME.json`` + ``NAME.csv``) plus a truth sidecar
(``NAME.truth.json``). It is used to test tankode *blindly*: it shares **no code** with
``tankode`` nor with the other simulators of ``tests/`` (``cryo_sim``, ``nodal_sim``,
``independent_sim``). Its physics is deliberately different from theirs: a layered
(LH2Sim-like) model with a thermally stratified liquid, a stratified ullage and a wall
discretised along the height. Fluids: any CoolProp pure fluid with a triple-point pressure
well below one atmosphere (tested: ``ParaHydrogen``, ``Hydrogen``, ``Nitrogen``, ``Methane``,
``Oxygen``).

Control volumes and state (all SI)
----------------------------------
``y = (m_l[N_L], U_l[N_L], m_v[N_V], U_v[N_V], n_v[N_V], E_w[N_W], M_in, N_in, E_in)`` with
``N_L = 8`` liquid layers (bottom to top), ``N_V = 5`` ullage layers (bottom to top),
``N_W = 10`` wall nodes (horizontal bands of equal height, bottom to top):

* each liquid layer holds fluid mass ``m`` and internal energy ``U``. The liquid is described
  by saturated-liquid properties of its temperature (CoolProp, tabulated at start-up as cubic
  splines in ``T``): ``u(T) = u_sat,l(T)``, ``v(T) = 1/rho_sat,l(T)``, enthalpy
  ``h = u(T) + p v(T)`` at the tank pressure (compressed-liquid effects neglected). ``T`` is
  recovered from ``U/m`` by Newton iteration on the same spline, so ``U``, ``T`` and ``V``
  are mutually exact;
* each ullage layer holds fluid mass ``m``, energy ``U`` (fluid + helium) and helium amount
  ``n`` [mol] (ideal monatomic gas, ``c_v = 3/2 R``; Dalton's law: the fluid sees its partial
  pressure ``p - n R T / V``). The ullage pressure ``p`` is uniform (no hydrostatics); the
  fluid is real gas: CoolProp HEOS, low-level ``AbstractState`` with ``(rho, T)`` inputs and
  the gas phase imposed (explicit Helmholtz energy, metastable subcooled vapour allowed). Each
  right-hand side solves ``p``, every ``T_j`` and every ``rho_j`` from ``(m_j, U_j, n_j)`` and
  ``sum_j V_j = V_tank - sum_i V_l,i`` by a block Newton iteration (warm-started, converged
  to round-off);
* wall node ``k`` has energy ``E_k = C_k T_k``, ``C_k = C_w A_k / A_wall`` (its share of the
  wall area), and receives ``Q_aw A_k / A_wall``;
* ``M_in, N_in, E_in``: quadratures of the fluid mass, helium and energy that crossed the tank
  boundary (closure check only).

Layer geometry: the liquid layers are stacked bottom-up, then the ullage layers; the height of
every layer boundary follows from the cumulative volume below it through the level-volume
relation of the shape. Layers are *mass parcels* that are re-gridded towards equal volumes
(``V_l / N_L`` for the liquid, ``V_v / N_V`` for the ullage) by an upwind mass flux across each
boundary, ``F = (excess volume below the boundary) rho_donor / tau_rg``, ``tau_rg = 30 s``,
carrying the donor's enthalpy (and helium). Volume work: a liquid layer changes volume by
``dV = m v'(T) dT + v dm`` with ``dT = (X - h dm) / (m (u' + p v'))`` (``X`` the heat and
enthalpy inflow); the ullage takes the opposite total change, shared among its layers by the
linearised equal-pressure condition (each layer in the enthalpy form
``dH = X + V dp``, ``dV_j = c0_j + c1_j dp``, one scalar equation for ``dp/dt``).
Every exchange is written once with opposite signs in its two volumes, so total mass, helium
and energy change only by the boundary terms.

Heat-transfer laws (this module's own choices)
----------------------------------------------
Properties of the layer concerned (liquid: saturated-liquid splines; vapour: conductivity
and viscosity tabulated in ``T`` at 2 atm, or at 0.95 x the saturation pressure where that is
lower; ``c_p`` from the EOS, floored at ``5/2 R/M`` for metastable gas; ``beta = 1/T``). ``|dT|`` is regularised as ``sqrt(dT^2 + (0.01 K)^2)``; on/off switches are
``tanh`` blends, ramps ``r(x)`` are C1 (quadratic up to 0.02 K).

* Wall to fluid, per (wall node, layer) pair over their overlapping wall area: Eckert &
  Jackson (1951) natural convection on a vertical surface, turbulent
  ``Nu = 0.0246 Gr^(2/5) Pr^(7/15) (1 + 0.494 Pr^(2/3))^(-2/5)``, laminar
  ``Nu = 0.555 (Gr Pr)^(1/4)``, blended by ``tanh(ln(Gr / 1e9))``, with the wetted height
  (liquid) or the dry height (ullage) as length. On the wetted wall, heat from a wall warmer
  than the adjacent layer is carried by the rising boundary layer into the **top** liquid
  layer (fraction ``(1 + tanh(dT / 0.02 K)) / 2``), the rest goes to the adjacent layer. In
  the ullage each layer exchanges with its own dry wall segment.
* Between adjacent layers: conduction plus eddy diffusion,
  ``G = (k + rho c_p eps) A_h / dz`` (``A_h`` the horizontal section at the boundary, ``dz``
  the distance between layer centres), ``eps = eps_0 + C_eps nu S^0.8``, ``eps_0 = 1e-6 m2/s``
  (liquid) / ``1e-5 m2/s`` (ullage).
* Convective adjustment: a layer warmer than the one above it (liquid or ullage) mixes with it,
  ``Q = min(m c) r(T_below - T_above) / tau_adj``, ``tau_adj = 30 s``.
* Interface at ``T_i = T_sat(p_f)`` (fluid partial pressure of the bottom ullage layer).
  Vapour side: conduction ``k_v / (dz_v/2)`` plus, when the gas is colder than the interface
  (unstable), ``Nu = 0.13 Ra^(1/3)`` on ``L = sqrt(4 A_i / pi)`` (a McAdams-type turbulent
  horizontal-plate law). Liquid side: conduction ``k_l / (dz_l/2)`` into the top layer plus,
  when that layer is warmer than ``T_i`` (cooled from above), ``Nu = 0.13 Ra^(1/3)``.
  ``J = (Q_vi + Q_li) / (h_v,sat - h_l,sat)`` evaporates (``J < 0`` condenses) between the top
  liquid layer and the bottom ullage layer.
* Bulk flash: a liquid layer above ``T_sat(p)`` (total pressure) vaporises at
  ``m c r(T - T_sat) / (tau_f L)``, ``tau_f = 40 s``, the vapour (``h_v,sat(p)``) entering the
  bottom ullage layer. Fog: an ullage layer below ``T_sat`` of its partial pressure condenses
  at ``(m c_p + n c_p,He) r(T_sat - T) / (tau_c L)``, ``tau_c = 25 s``; the droplets
  (``h_l,sat``) join the top liquid layer.
* Sloshing (amplitude ``A0``, frequency ``f``, ``omega = 2 pi f``): a forcing Reynolds number
  ``S = A0 omega D / nu`` (``D = 2 R``) raises the eddy diffusivity (``C_eps = 0.1``),
  multiplies the interface coefficients by ``1 + 2e-3 S^(1/2)`` and the wall coefficients by
  ``1 + 5e-4 S^(1/2)`` (liquid ``nu`` for the liquid and the interface, vapour ``nu`` for the
  ullage). Strong sloshing therefore collapses the thermal stratification.
* Wall: axial conduction between adjacent nodes ``G = k_w t_w P / dz`` (``P`` the wall length
  of the horizontal cut at the node boundary, ``dz`` the node height); ``k_w`` and the wall
  capacity from rough cryogenic data of the material (304 stainless steel or 6061 aluminium)
  at the initial wall temperature, both constant.

Operations and hidden mechanisms
--------------------------------
Vapour injection at ``h(p_v_in, T_v_in)`` (CoolProp) into the top ullage layer; venting from
the top ullage layer (metered flow = mixture mass; helium leaves in proportion); liquid fill
at ``h = u(T_l_in) + p v(T_l_in)`` into the bottom liquid layer; drain from the bottom layer;
sloshing; ``Q_aw`` on the wall. Hidden mechanisms (:data:`MECHANISMS`, 0 = absent; the CSV
holds what the operator *thinks* happened): ``heat_leak_liquid_W`` (into the liquid layers
by mass), ``heat_leak_vapor_W`` (into the ullage layers by mass), ``heat_leak_wall_W`` (into
the wall nodes by area), ``vapor_leak_kg_s`` (unmetered, from the top ullage layer),
``liquid_leak_kg_s`` (unmetered, from the bottom liquid layer), ``inflow_meter_bias`` (true
inflows = ``(1 + b)`` x metered), ``pressure_sensor_bias_Pa``, ``temperature_sensor_bias_K``
(on ``T_l``), ``helium_mol`` (added to the ullage at a uniform partial pressure: the fluid
state is that of the scenario, the metadata's initial pressure is the total one),
``wall_heat_capacity_error`` (true ``C_w = (1 + e)`` x metadata). ``--wall-capacity-unknown``
writes ``null`` for the wall capacity. A run with mechanisms replays exactly the metered
schedule executed by the mechanism-free run.

Scenarios
---------
Phases are targets turned into metered rates by an operator policy from the state at the phase
start (pressurise by ``dp_frac``, vent to ``p_frac``, fill or drain by ``dfill``, slosh at
``amp_m`` and ``freq_ratio`` x the first lateral mode ``omega_1^2 = 1.841 g / R tanh(1.841 h / R)``).
Soft bounds (terminal events, the change is recorded and the CSV holds the schedule as
executed): pressure above ``0.6 p_c`` stops inflows and opens a relief vent until the
pressure is back below ``0.55 p_c``; pressure below ``max(0.55 p_nbp, 1.5 p_triple)`` stops
venting and draining; fill above 94 % stops filling, below 6 % stops draining. Hard limits
(a fluid partial pressure outside ``1.1 p_triple .. 0.9 p_c``, fill outside 1-98.5 %) raise
:class:`SimulationError`. Named (:data:`NAMED_SCENARIOS`): ``lh2_upright`` (15 m3 upright
cylinder with 2:1 heads: self-pressurisation, warm-gas pressurisation, vent, sloshing),
``ln2_sphere`` (5 m3 nitrogen sphere: fill, drain, vent), ``lh2_hcyl`` (8 m3 horizontal
cylinder: drain, top-up, heat load). ``random_SEED``: fluid among :data:`FLUIDS`, any of the
four shapes, 1-60 m3, fill 0.2-0.9, pressure ``1.05 p_nbp .. 0.35 p_c``, 3-6 phases of 5-25
min.

Sensors: ``p_v`` (total pressure), ``T_v`` and ``T_l`` (mass averages of the ullage and
liquid layers), ``T_w`` (capacity average of the wall), ``H_l`` (level from the liquid volume);
with ``--sensors point`` the temperatures are probes instead (the middle ullage layer, the second
liquid layer from the bottom, the wall band at mid-height: outside the run format, which defines
mass averages, as a real tank's single probes are);
every 10 s, ``T_w`` every 30 s (empty cells in between); Gaussian noise
``--noise none|low|high`` (low: 300 Pa, 0.05 K, 1 mm; high: 2000 Pa, 0.2 K, 5 mm; ``none``
writes exact readings with the low ``noise_std``).

Integration: ``scipy.integrate.solve_ivp(method="LSODA")``, restarted at every schedule
change, ``rtol = 1e-7``, ``max_step = 60 s``. The multistep method preserves the linear
invariants (total fluid mass, helium, total energy fluid + wall, minus the boundary
quadratures) to round-off; the truth file reports the closure errors relative to the mass and
energy that the tank held and exchanged (measured: about 1e-15). Against ``rtol = 1e-9``,
``lh2_upright`` agrees within 0.05 Pa and 2e-6 K; its 75 minutes take about 3 s on one core.

References: E. R. G. Eckert & T. W. Jackson, NACA Report 1015 (1951); W. H. McAdams, Heat
Transmission, 3rd ed. (1954); H. N. Abramson (ed.), NASA SP-106 (1966); stratified-tank
modelling after the LH2Sim approach (A. Petitpas, LLNL, 2018) and the layer models reviewed by
Al Ghafri et al., Energy Environ. Sci. 15 (2022) 2690; CoolProp: I. H. Bell et al., Ind. Eng.
Chem. Res. 53 (2014) 2498; wall data after the NIST cryogenic material properties.

Limits (deliberate)
-------------------
No hydrostatic head; liquid properties along saturation (no compressed-liquid correction);
helium is ideal, does not dissolve, does not diffuse between ullage layers (it moves with the
re-gridding flows) and is ignored in transport properties; sloshing adds no mechanical energy
and does not change the interface area; wall capacity and conductivity are constant; no
nucleate boiling on the wall; vertical-plate correlations are used on curved walls.

Command line::

    python tests/layer_sim.py SCENARIO|random_SEED [--fluid F] [--mechanism NAME=VALUE ...]
        [--noise none|low|high] [--seed N] [--out DIR] [--name NAME] [--duration S]
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

SIMULATOR = "tests/layer_sim.py"

GRAV = 9.80665
RU = 8.314462618  # J/(mol K)
MW_HE = 4.002602e-3  # kg/mol
CV_HE = 1.5 * RU
CP_HE = 2.5 * RU
ATM = 101325.0

N_LIQ = 8
N_VAP = 5
N_WALL = 10
# What the temperature sensors read: the layers' averages, or one probe per phase and the wall.
SENSORS = ("average", "point")

FLUIDS = ("ParaHydrogen", "Hydrogen", "Nitrogen", "Methane", "Oxygen")
SHAPES = ("vertical_cylinder", "vertical_cylinder_elliptical_heads", "sphere", "horizontal_cylinder")
PHASE_KINDS = ("rest", "pressurize", "vent", "fill", "drain", "slosh")

OBS_COLUMNS = ("p_v_Pa", "T_v_K", "T_l_K", "T_w_K", "H_l_m")
NOISE_KEYS = ("p_v", "T_v", "T_l", "T_w", "H_l")
INPUT_COLUMNS = ("mdot_v_in_kg_s", "T_v_in_K", "p_v_in_Pa", "mdot_v_out_kg_s", "mdot_l_in_kg_s", "T_l_in_K",
                 "mdot_l_out_kg_s", "slosh_amplitude_m", "slosh_frequency_Hz", "Q_aw_W")
NOISE_LEVELS = {
    "low": {"p_v": 300.0, "T_v": 0.05, "T_l": 0.05, "T_w": 0.05, "H_l": 0.001},
    "high": {"p_v": 2000.0, "T_v": 0.2, "T_l": 0.2, "T_w": 0.2, "H_l": 0.005},
}
DT_SAMPLE = 10.0
DT_SAMPLE_WALL = 30.0

MECHANISMS = {
    "heat_leak_liquid_W": "extra heat into the liquid (layers by mass) [W]",
    "heat_leak_vapor_W": "extra heat into the ullage gas (layers by mass) [W]",
    "heat_leak_wall_W": "extra heat into the wall (nodes by area) [W]",
    "vapor_leak_kg_s": "unmetered loss of ullage gas from the top layer [kg/s]",
    "liquid_leak_kg_s": "unmetered loss of liquid from the bottom layer [kg/s]",
    "inflow_meter_bias": "true inflows = (1 + b) x metered (vapour and liquid) [-]",
    "pressure_sensor_bias_Pa": "added to the pressure sensor [Pa]",
    "temperature_sensor_bias_K": "added to the liquid temperature sensor T_l [K]",
    "helium_mol": "helium in the ullage (ideal, monatomic) [mol]",
    "wall_heat_capacity_error": "true C_w = (1 + e) x metadata's [-]",
}

TAU_REGRID = 30.0
TAU_ADJUST = 30.0
TAU_FLASH = 40.0
TAU_FOG = 25.0
EPS0_LIQ = 1e-6
EPS0_VAP = 1e-5
C_EPS = 0.1
C_SLOSH_INTERFACE = 2e-3
C_SLOSH_WALL = 5e-4
RAMP_W = 0.02
DT_REG = 0.01
DZ_MIN = 2e-3
RTOL = 1e-7
MAX_STEP = 60.0

# rough cryogenic wall data (after the NIST cryogenic material properties): T [K], c [J/kg/K], k [W/m/K]
_WALL_DATA = {
    "steel": {"rho": 7950.0, "T": (10.0, 20.0, 40.0, 77.0, 100.0, 150.0, 200.0, 300.0),
              "c": (4.5, 12.5, 57.0, 205.0, 262.0, 352.0, 405.0, 477.0),
              "k": (0.8, 2.2, 4.9, 8.1, 9.3, 11.4, 12.8, 14.9), "t_min": 0.003, "stress": 130e6},
    "aluminium": {"rho": 2700.0, "T": (10.0, 20.0, 40.0, 77.0, 100.0, 150.0, 200.0, 300.0),
                  "c": (1.4, 8.8, 78.0, 335.0, 480.0, 683.0, 795.0, 897.0),
                  "k": (22.0, 42.0, 70.0, 93.0, 104.0, 126.0, 139.0, 155.0), "t_min": 0.004, "stress": 65e6},
}


class SimulationError(RuntimeError):
    """Integration or state recovery failed, or a hard validity limit was crossed."""


def _ramp(x):
    """C1 ramp: 0 below 0, x^2/(2w) up to w, x - w/2 beyond (works on arrays)."""
    x = np.asarray(x, dtype=float)
    return np.where(x <= 0.0, 0.0, np.where(x < RAMP_W, x * x / (2 * RAMP_W), x - 0.5 * RAMP_W))


def _absreg(x):
    return np.sqrt(np.asarray(x, dtype=float) ** 2 + DT_REG ** 2)


def _on(x, w):
    return 0.5 * (1.0 + np.tanh(np.asarray(x, dtype=float) / w))


# ------------------------------------------------------------------------------- fluid properties
class Fluid:
    """Saturation and saturated-liquid tables (splines) plus a HEOS gas-phase state."""

    def __init__(self, name: str, p_ref: float | None = None):
        try:
            self.name = name
            self.gas = CP.AbstractState("HEOS", name)
        except ValueError as e:
            raise ValueError(f"unknown CoolProp fluid {name!r}: {e}") from None
        g = self.gas
        self.M = g.molar_mass()
        self.Tc, self.pc = g.T_critical(), g.p_critical()
        self.T_trip = g.Ttriple()
        self.p_trip = CP.PropsSI("P", "T", self.T_trip, "Q", 0, name)
        if self.p_trip > 0.5 * ATM:
            raise ValueError(f"fluid {name!r}: triple-point pressure {self.p_trip:.0f} Pa is too high")
        g.specify_phase(CP.iphase_gas)
        self.sat_state = CP.AbstractState("HEOS", name)
        self.T_nbp = self._Tsat_direct(ATM)
        # saturation table in ln p
        lp = np.linspace(math.log(1.02 * self.p_trip), math.log(0.97 * self.pc), 240)
        Ts, hl, hv = [], [], []
        s = self.sat_state
        for x in lp:
            s.update(CP.PQ_INPUTS, math.exp(x), 0.0)
            Ts.append(s.T()); hl.append(s.hmass())
            s.update(CP.PQ_INPUTS, math.exp(x), 1.0)
            hv.append(s.hmass())
        self._sat = CubicSpline(lp, np.column_stack([Ts, hl, hv]))
        # saturated liquid in T
        T = np.linspace(self.T_trip + 0.02, self._Tsat_direct(0.95 * self.pc), 260)
        u, v, k, mu, cp, kv, muv = ([] for _ in range(7))
        pr = p_ref or 2 * ATM
        for t in T:
            s.update(CP.QT_INPUTS, 0.0, t)
            u.append(s.umass()); v.append(1.0 / s.rhomass()); k.append(s.conductivity())
            mu.append(s.viscosity()); cp.append(s.cpmass())
        self.T_liq = T
        self._liq = CubicSpline(T, np.column_stack([u, v]))
        self._liq_d = self._liq.derivative()
        self._liq_tr = CubicSpline(T, np.column_stack([k, mu, cp]))
        self._T_of_u = CubicSpline(np.array(u), T)
        # vapour transport near the reference pressure (gas side of saturation)
        Tg = np.linspace(self.T_trip + 0.5, max(320.0, 3 * self.Tc), 220)
        for t in Tg:
            pg = pr if t > self.Tc else min(pr, 0.95 * CP.PropsSI("P", "T", t, "Q", 1, name))
            s.update(CP.PT_INPUTS, pg, t)
            kv.append(s.conductivity()); muv.append(s.viscosity())
        self._vap_tr = CubicSpline(Tg, np.column_stack([kv, muv]))
        self.Tg_range = (Tg[0], Tg[-1])

    def _Tsat_direct(self, p: float) -> float:
        self.sat_state.update(CP.PQ_INPUTS, p, 0.0)
        return self.sat_state.T()

    def sat(self, p):
        """(T_sat, h_l,sat, h_v,sat) at pressure p (array or scalar)."""
        r = self._sat(np.log(np.clip(p, 1.02 * self.p_trip, 0.97 * self.pc)))
        return r[..., 0], r[..., 1], r[..., 2]

    def T_sat(self, p):
        return self.sat(p)[0]

    def p_sat(self, T: float) -> float:
        self.sat_state.update(CP.QT_INPUTS, 0.0, float(T))
        return self.sat_state.p()

    def liq(self, T):
        """u, v, du/dT, dv/dT of the liquid at T."""
        T = np.clip(T, self.T_liq[0], self.T_liq[-1])
        a, d = self._liq(T), self._liq_d(T)
        return a[..., 0], a[..., 1], d[..., 0], d[..., 1]

    def liq_T_of_u(self, u, T0=None):
        T = self._T_of_u(u) if T0 is None else np.array(T0, dtype=float)
        for _ in range(6):
            a = self._liq(T)
            du = self._liq_d(T)[..., 0]
            dT = (u - a[..., 0]) / du
            T = T + dT
            if np.max(np.abs(dT)) < 1e-13 * np.max(T):
                break
        return T

    def liq_transport(self, T):
        r = self._liq_tr(np.clip(T, self.T_liq[0], self.T_liq[-1]))
        return r[..., 0], r[..., 1], r[..., 2]

    def vap_transport(self, T):
        r = self._vap_tr(np.clip(T, *self.Tg_range))
        return r[..., 0], r[..., 1]

    def gas_rho(self, p: float, T: float) -> float:
        """Gas density at (p, T) by Newton on rho (gas phase imposed)."""
        g = self.gas
        rho = p * self.M / (RU * T)
        for _ in range(60):
            g.update(CP.DmassT_INPUTS, rho, T)
            f = g.p() - p
            d = g.first_partial_deriv(CP.iP, CP.iDmass, CP.iT)
            step = f / d
            rho_new = rho - step
            if rho_new <= 0:
                rho_new = 0.5 * rho
            if abs(rho_new - rho) < 1e-14 * rho:
                return rho_new
            rho = rho_new
        return rho

    def h_gas(self, p: float, T: float) -> float:
        self.gas.update(CP.DmassT_INPUTS, self.gas_rho(p, T), T)
        return self.gas.hmass()


_FLUID_CACHE: dict[tuple, Fluid] = {}


def get_fluid(name: str) -> Fluid:
    if name not in _FLUID_CACHE:
        _FLUID_CACHE[name] = Fluid(name, 2 * ATM)
    return _FLUID_CACHE[name]


# ------------------------------------------------------------------------------- geometry
class Shape:
    """Level-volume relation, horizontal sections and wall areas, by numerical integration."""

    NZ = 4001

    def __init__(self, tank: Mapping[str, Any]):
        sh = tank.get("shape")
        if sh not in SHAPES:
            raise ValueError(f"unknown tank shape {sh!r}; known: {', '.join(SHAPES)}")
        self.shape = sh
        R = float(tank["radius_m"])
        if R <= 0:
            raise ValueError("radius_m must be positive")
        self.R = R
        self.D = 2 * R
        if sh == "vertical_cylinder":
            H = float(tank["height_m"])
            self.dims = {"radius_m": R, "height_m": H}
        elif sh == "vertical_cylinder_elliptical_heads":
            Lc, ha = float(tank["cylinder_length_m"]), float(tank.get("head_aspect", 2.0))
            b = R / ha
            H = Lc + 2 * b
            self.dims = {"radius_m": R, "cylinder_length_m": Lc, "head_aspect": ha}
        elif sh == "sphere":
            H = 2 * R
            self.dims = {"radius_m": R}
        else:
            Lc = float(tank["cylinder_length_m"])
            H = 2 * R
            self.dims = {"radius_m": R, "cylinder_length_m": Lc}
        self.H = H
        z = np.linspace(0.0, H, self.NZ)
        zm = 0.5 * (z[1:] + z[:-1])
        dz = np.diff(z)
        if sh == "horizontal_cylinder":
            zc = np.clip(z, 0, 2 * R)
            w = 2 * np.sqrt(np.maximum(R * R - (zc - R) ** 2, 0.0))
            th = np.arccos(np.clip(1 - zc / R, -1, 1))
            seg = R * R * th - (R - zc) * np.sqrt(np.maximum(2 * R * zc - zc * zc, 0.0))
            Vc = Lc * seg
            Aw = 2 * Lc * R * th + 2 * seg
            self.Ah = Lc * w
            self.P = 2 * Lc + 2 * w
        else:
            def radius(zz):
                if sh == "vertical_cylinder":
                    return np.full_like(zz, R)
                if sh == "sphere":
                    return np.sqrt(np.maximum(R * R - (zz - R) ** 2, 0.0))
                r = np.full_like(zz, R)
                lo, hi = zz < b, zz > b + Lc
                r[lo] = R * np.sqrt(np.maximum(1 - ((b - zz[lo]) / b) ** 2, 0.0))
                r[hi] = R * np.sqrt(np.maximum(1 - ((zz[hi] - b - Lc) / b) ** 2, 0.0))
                return r
            r, rm = radius(z), radius(zm)
            f, fm = math.pi * r * r, math.pi * rm * rm
            Vc = np.concatenate([[0.0], np.cumsum(dz / 6 * (f[:-1] + 4 * fm + f[1:]))])
            # wall area: frusta through the grid points and the mid points
            zz = np.empty(2 * len(z) - 1)
            rr = np.empty_like(zz)
            zz[0::2], zz[1::2], rr[0::2], rr[1::2] = z, zm, r, rm
            dA = math.pi * (rr[1:] + rr[:-1]) * np.hypot(np.diff(rr), np.diff(zz))
            Aw = np.concatenate([[0.0], np.cumsum(dA)])[0::2]
            if sh == "vertical_cylinder":
                Aw = Aw + math.pi * R * R  # bottom plate belongs to z = 0
            self.Ah = f
            self.P = 2 * math.pi * r
        self.z = z
        self.Vcum = Vc
        self.V = float(Vc[-1])
        self.Awcum = Aw
        self.A_wall = float(Aw[-1] + (math.pi * R * R if sh == "vertical_cylinder" else 0.0))

    def level(self, V):
        return np.interp(V, self.Vcum, self.z)

    def area_h(self, z):
        return np.interp(z, self.z, self.Ah)

    def perimeter(self, z):
        return np.interp(z, self.z, self.P)

    def wall_below(self, z):
        """Wall area below z; 0 below the bottom, all of it above the top (end plates included)."""
        return np.interp(z, self.z, self.Awcum, left=0.0, right=self.A_wall)

    def tank_dims(self) -> dict[str, float]:
        return dict(self.dims)


def _tank_of_volume(shape: str, V: float, aspect: float, head_aspect: float = 2.0) -> dict[str, Any]:
    """A tank of the shape with volume V; aspect = straight length / diameter (or height / diameter)."""
    if shape == "vertical_cylinder":
        R = (V / (2 * math.pi * aspect)) ** (1 / 3)
        return {"shape": shape, "radius_m": R, "height_m": 2 * R * aspect}
    if shape == "vertical_cylinder_elliptical_heads":
        R = (V / (math.pi * (2 * aspect + 4 / (3 * head_aspect)))) ** (1 / 3)
        return {"shape": shape, "radius_m": R, "cylinder_length_m": 2 * R * aspect, "head_aspect": head_aspect}
    if shape == "sphere":
        return {"shape": shape, "radius_m": (3 * V / (4 * math.pi)) ** (1 / 3)}
    R = (V / (2 * math.pi * aspect)) ** (1 / 3)
    return {"shape": shape, "radius_m": R, "cylinder_length_m": 2 * R * aspect}


def _wall_props(material: str, thickness: float, area: float, T: float) -> tuple[float, float]:
    d = _WALL_DATA[material]
    c = float(np.interp(T, d["T"], d["c"]))
    k = float(np.interp(T, d["T"], d["k"]))
    return d["rho"] * thickness * area * c, k


# ------------------------------------------------------------------------------- correlations
def _nu_eckert_jackson(Gr, Pr):
    Gr = np.maximum(Gr, 1e-6)
    lam = 0.555 * (Gr * Pr) ** 0.25
    turb = 0.0246 * Gr ** 0.4 * Pr ** (7 / 15) * (1 + 0.494 * Pr ** (2 / 3)) ** (-0.4)
    w = _on(np.log(Gr / 1e9), 1.0)
    return (1 - w) * lam + w * turb


def _nu_plate(Ra):
    return 0.13 * np.maximum(Ra, 0.0) ** (1 / 3)


# ------------------------------------------------------------------------------- the model
class LayerModel:
    def __init__(self, sc: Mapping[str, Any], mech: Mapping[str, float]):
        self.sc = sc
        self.mech = {k: float(mech.get(k, 0.0)) for k in MECHANISMS}
        ini = sc["initial"]
        self.fl = get_fluid(sc["fluid"])
        self.geo = Shape(sc["tank"])
        self.C_meta = float(sc["wall"]["C_w_J_per_K"])
        self.C_w = self.C_meta * (1 + self.mech["wall_heat_capacity_error"])
        self.k_w = float(sc["wall"]["k_w_W_per_mK"])
        self.t_w = float(sc["wall"]["thickness_m"])
        geo = self.geo
        self.zw = np.linspace(0.0, geo.H, N_WALL + 1)
        zb = self.zw.copy()
        zb[0], zb[-1] = -1.0, geo.H + 1.0
        self.zw_ext = zb
        aw = np.diff(geo.wall_below(zb))
        self.a_wall = aw / aw.sum()
        self.C_node = self.C_w * self.a_wall
        dzw = geo.H / N_WALL
        self.G_wall = self.k_w * self.t_w * geo.perimeter(self.zw[1:-1]) / dzw
        self.nfev = 0
        self._cache_key = None
        self._cache = None
        self.inputs = {c: 0.0 for c in INPUT_COLUMNS}
        self.h_v_in = 0.0
        self._guess = None
        self.y0 = self._initial_state()

    # ---- layout
    @staticmethod
    def _split(y):
        a = 0
        out = []
        for n in (N_LIQ, N_LIQ, N_VAP, N_VAP, N_VAP, N_WALL, 1, 1, 1):
            out.append(y[a:a + n])
            a += n
        return out

    def _initial_state(self) -> np.ndarray:
        fl, geo, ini = self.fl, self.geo, self.sc["initial"]
        p_f = ini["p_Pa"]
        T_sat = float(fl.T_sat(p_f))
        T_l0 = ini["T_l_K"]
        V_l = ini["fill_ratio"] * geo.V
        u, v, _, _ = fl.liq(np.full(N_LIQ, T_l0))
        m_l = V_l / N_LIQ / v
        U_l = m_l * u
        V_v = geo.V - V_l
        frac = (np.arange(N_VAP) + 0.5) / N_VAP
        T_v = T_sat + 2 * (ini["T_v_K"] - T_sat) * frac
        Vj = np.full(N_VAP, V_v / N_VAP)
        n_tot = self.mech["helium_mol"]
        p_he = n_tot * RU / np.sum(Vj / T_v)
        n_v = p_he * Vj / (RU * T_v)
        rho = np.array([fl.gas_rho(p_f, t) for t in T_v])
        m_v = rho * Vj
        U_v = np.empty(N_VAP)
        for j in range(N_VAP):
            fl.gas.update(CP.DmassT_INPUTS, rho[j], T_v[j])
            U_v[j] = m_v[j] * fl.gas.umass() + n_v[j] * CV_HE * T_v[j]
        self._guess = (T_v.copy(), rho.copy(), p_f + p_he)
        # wall: wetted nodes slightly above the liquid, dry nodes graded towards the top
        level = float(geo.level(V_l))
        zc = 0.5 * (self.zw[1:] + self.zw[:-1])
        dry = np.clip((zc - level) / max(geo.H - level, 1e-6), 0.0, 1.0)
        T_node = np.where(zc < level, T_l0 + ini["wet_extra_K"],
                          ini["T_v_K"] + ini["dry_extra_K"] * dry)
        E_w = self.C_node * T_node
        return np.concatenate([m_l, U_l, m_v, U_v, n_v, E_w, [0.0, 0.0, 0.0]])

    # ---- state recovery
    def _solve_gas(self, m, U, n, Vv):
        fl = self.fl
        g = fl.gas
        T, rho, p = (self._guess[0].copy(), self._guess[1].copy(), float(self._guess[2]))
        for it in range(60):
            aT, arho, bT, brho = (np.empty(N_VAP) for _ in range(4))
            for j in range(N_VAP):
                try:
                    g.update(CP.DmassT_INPUTS, rho[j], T[j])
                except ValueError as e:
                    raise SimulationError(f"gas state recovery failed at T = {T[j]:.4g} K, "
                                          f"rho = {rho[j]:.4g} kg/m3: {e}") from None
                P = g.p()
                u = g.umass()
                cv = g.cvmass()
                u_r = g.first_partial_deriv(CP.iUmass, CP.iDmass, CP.iT)
                P_T = g.first_partial_deriv(CP.iP, CP.iT, CP.iDmass)
                P_r = g.first_partial_deriv(CP.iP, CP.iDmass, CP.iT)
                rU = m[j] * u + n[j] * CV_HE * T[j] - U[j]
                pj = P + n[j] * RU * T[j] * rho[j] / m[j]
                a11, a12 = m[j] * cv + n[j] * CV_HE, m[j] * u_r
                a21, a22 = P_T + n[j] * RU * rho[j] / m[j], P_r + n[j] * RU * T[j] / m[j]
                det = a11 * a22 - a12 * a21
                r1, r2 = -rU, p - pj
                aT[j], arho[j] = (a22 * r1 - a12 * r2) / det, (a11 * r2 - a21 * r1) / det
                bT[j], brho[j] = -a12 / det, a11 / det
            w = m / rho ** 2
            dp = (np.sum(m / rho) - Vv - np.sum(w * arho)) / np.sum(w * brho)
            dT = aT + bT * dp
            drho = arho + brho * dp
            lam = 1.0
            while np.any(rho + lam * drho <= 0) or np.any(np.abs(lam * dT) > 0.3 * T) or p + lam * dp <= 0:
                lam *= 0.5
                if lam < 1e-6:
                    raise SimulationError("gas state recovery failed (non-physical step)")
            T, rho, p = T + lam * dT, rho + lam * drho, p + lam * dp
            if lam == 1.0 and np.max(np.abs(dT) / T) < 1e-13 and abs(dp) < 1e-13 * p \
                    and np.max(np.abs(drho) / rho) < 1e-13:
                break
        else:
            raise SimulationError(f"gas state recovery did not converge (p = {p:.6g} Pa)")
        if not np.all(np.isfinite(T)) or not math.isfinite(p):
            raise SimulationError("gas state recovery gave non-finite values")
        self._guess = (T.copy(), rho.copy(), p)
        props = np.empty((N_VAP, 7))
        for j in range(N_VAP):
            g.update(CP.DmassT_INPUTS, rho[j], T[j])
            props[j] = (g.p(), g.hmass(), g.cpmass(), g.first_partial_deriv(CP.iHmass, CP.iT, CP.iDmass),
                        g.first_partial_deriv(CP.iHmass, CP.iDmass, CP.iT),
                        g.first_partial_deriv(CP.iP, CP.iT, CP.iDmass),
                        g.first_partial_deriv(CP.iP, CP.iDmass, CP.iT))
        return T, rho, p, props

    def state(self, y: np.ndarray) -> dict[str, Any]:
        key = y.tobytes()
        if key == self._cache_key:
            return self._cache
        fl, geo = self.fl, self.geo
        m_l, U_l, m_v, U_v, n_v, E_w, _, _, _ = self._split(y)
        if np.any(m_l <= 0) or np.any(m_v <= 0):
            raise SimulationError("a layer lost all its mass")
        Tl_prev = self._cache["T_l"] if self._cache is not None else None
        T_l = fl.liq_T_of_u(U_l / m_l, Tl_prev)
        u_l, v_l, du_l, dv_l = fl.liq(T_l)
        V_lay = m_l * v_l
        V_l = float(V_lay.sum())
        V_v = geo.V - V_l
        if V_v <= 0:
            raise SimulationError("the liquid fills the tank")
        n_pos = np.maximum(n_v, 0.0)
        T_v, rho_v, p, gp = self._solve_gas(m_v, U_v, n_pos, V_v)
        st = {"m_l": m_l, "U_l": U_l, "m_v": m_v, "U_v": U_v, "n_v": n_pos, "E_w": E_w, "T_l": T_l, "u_l": u_l,
              "v_l": v_l, "du_l": du_l, "dv_l": dv_l, "V_lay": V_lay, "V_l": V_l, "V_v": V_v, "T_v": T_v,
              "rho_v": rho_v, "p": p, "P_f": gp[:, 0], "h_f": gp[:, 1], "cp_v": gp[:, 2], "h_T": gp[:, 3],
              "h_r": gp[:, 4], "P_T": gp[:, 5], "P_r": gp[:, 6], "V_vlay": m_v / rho_v,
              "T_w": E_w / self.C_node}
        cumV = np.concatenate([[0.0], np.cumsum(V_lay), V_l + np.cumsum(st["V_vlay"])])
        zb = geo.level(np.clip(cumV, 0.0, geo.V))
        st["level"] = float(zb[N_LIQ])
        st["z_bounds"] = zb
        self._cache_key, self._cache = key, st
        return st

    # ---- observation
    def observe(self, y: np.ndarray) -> dict[str, Any]:
        st = self.state(y)
        fl = self.fl
        m_l, m_v = st["m_l"], st["m_v"]
        p_f0 = float(st["P_f"][0])
        return {"p": st["p"], "p_f": p_f0, "p_he": st["p"] - p_f0, "T_i": float(fl.T_sat(p_f0)),
                "T_v": float(np.sum(m_v * st["T_v"]) / m_v.sum()), "T_l": float(np.sum(m_l * st["T_l"]) / m_l.sum()),
                "T_w": float(st["E_w"].sum() / self.C_node.sum()), "level": st["level"],
                "fill": st["V_l"] / self.geo.V, "m_l": float(m_l.sum()), "m_v": float(m_v.sum()),
                "n_he": float(st["n_v"].sum()), "T_l_layers": st["T_l"].tolist(), "T_v_layers": st["T_v"].tolist(),
                "T_w_nodes": st["T_w"].tolist(), "P_f_min": float(st["P_f"].min()), "P_f_max": float(st["P_f"].max())}

    def totals(self, y: np.ndarray) -> tuple[float, float, float]:
        m_l, U_l, m_v, U_v, n_v, E_w, _, _, _ = self._split(y)
        return float(m_l.sum() + m_v.sum()), float(n_v.sum()), float(U_l.sum() + U_v.sum() + E_w.sum())

    # ---- operations
    def set_inputs(self, inputs: Mapping[str, float]) -> None:
        self.inputs = {c: float(inputs.get(c, 0.0)) for c in INPUT_COLUMNS}
        if self.inputs["mdot_v_in_kg_s"] > 0:
            self.h_v_in = self.fl.h_gas(self.inputs["p_v_in_Pa"], self.inputs["T_v_in_K"])
        else:
            self.h_v_in = 0.0

    def _slosh(self, nu):
        A0, f = self.inputs["slosh_amplitude_m"], self.inputs["slosh_frequency_Hz"]
        return A0 * 2 * math.pi * f * self.geo.D / nu

    # ---- right-hand side
    def rhs(self, t: float, y: np.ndarray) -> np.ndarray:
        self.nfev += 1
        st = self.state(y)
        fl, geo, mech, inp = self.fl, self.geo, self.mech, self.inputs
        p = st["p"]
        m_l, m_v, n_v = st["m_l"], st["m_v"], st["n_v"]
        T_l, T_v, T_w = st["T_l"], st["T_v"], st["T_w"]
        u_l, v_l = st["u_l"], st["v_l"]
        h_l = u_l + p * v_l
        k_l, mu_l, cp_l = fl.liq_transport(T_l)
        rho_l = 1.0 / v_l
        nu_l = mu_l / rho_l
        a_l = k_l / (rho_l * cp_l)
        beta_l = st["dv_l"] / v_l
        k_v, mu_v = fl.vap_transport(T_v)
        rho_v = st["rho_v"]
        cp_v = np.maximum(st["cp_v"], 2.5 * RU / fl.M)  # floor: metastable gas deep below saturation
        nu_v = mu_v / rho_v
        a_v = k_v / (rho_v * cp_v)
        beta_v = 1.0 / T_v
        hmix = st["h_f"] + n_v / m_v * CP_HE * T_v  # enthalpy of ullage gas per kg of fluid
        zb = st["z_bounds"]
        level = st["level"]
        dz_l = np.maximum(np.diff(zb[:N_LIQ + 1]), DZ_MIN)
        dz_v = np.maximum(np.diff(zb[N_LIQ:]), DZ_MIN)

        X_l = np.zeros(N_LIQ)
        md_l = np.zeros(N_LIQ)
        X_v = np.zeros(N_VAP)
        md_v = np.zeros(N_VAP)
        nd_v = np.zeros(N_VAP)
        dE = np.zeros(N_WALL)
        S_l = self._slosh(float(np.mean(nu_l)))
        S_v = self._slosh(float(np.mean(nu_v)))
        f_wall = 1 + C_SLOSH_WALL * math.sqrt(S_l)
        f_wall_v = 1 + C_SLOSH_WALL * math.sqrt(S_v)
        f_int = 1 + C_SLOSH_INTERFACE * math.sqrt(S_l)

        # boundary heat
        Qw_amb = inp["Q_aw_W"] + mech["heat_leak_wall_W"]
        dE += Qw_amb * self.a_wall
        X_l += mech["heat_leak_liquid_W"] * m_l / m_l.sum()
        X_v += mech["heat_leak_vapor_W"] * m_v / m_v.sum()
        dEin = Qw_amb + mech["heat_leak_liquid_W"] + mech["heat_leak_vapor_W"]

        # wall <-> fluid layers (overlapping wall areas)
        zlay = zb.copy()
        zlay[0], zlay[-1] = -1.0, geo.H + 1.0
        top = np.minimum.outer(self.zw_ext[1:], zlay[1:])
        bot = np.maximum.outer(self.zw_ext[:-1], zlay[:-1])
        A_ov = np.maximum(geo.wall_below(top) - geo.wall_below(bot), 0.0)  # (N_WALL, N_LIQ + N_VAP)
        dT_wl = T_w[:, None] - T_l[None, :]
        L_wet = max(level, 0.05)
        Gr = GRAV * beta_l[None, :] * _absreg(dT_wl) * L_wet ** 3 / nu_l[None, :] ** 2
        h_wl = _nu_eckert_jackson(Gr, (nu_l / a_l)[None, :]) * k_l[None, :] / L_wet * f_wall
        Q_wl = h_wl * A_ov[:, :N_LIQ] * dT_wl
        up = _on(dT_wl, 0.02)
        dE -= Q_wl.sum(axis=1)
        X_l += (Q_wl * (1 - up)).sum(axis=0)
        X_l[-1] += (Q_wl * up).sum()
        dT_wv = T_w[:, None] - T_v[None, :]
        L_dry = max(geo.H - level, 0.05)
        Gr = GRAV * beta_v[None, :] * _absreg(dT_wv) * L_dry ** 3 / nu_v[None, :] ** 2
        h_wv = _nu_eckert_jackson(Gr, (nu_v / a_v)[None, :]) * k_v[None, :] / L_dry * f_wall_v
        Q_wv = h_wv * A_ov[:, N_LIQ:] * dT_wv
        dE -= Q_wv.sum(axis=1)
        X_v += Q_wv.sum(axis=0)

        # wall axial conduction
        Qa = self.G_wall * (T_w[:-1] - T_w[1:])
        dE[:-1] -= Qa
        dE[1:] += Qa

        # liquid layer-to-layer: conduction, eddy diffusion, convective adjustment
        if N_LIQ > 1:
            zi = zb[1:N_LIQ]
            Ai = geo.area_h(zi)
            eps = EPS0_LIQ + C_EPS * nu_l * S_l ** 0.8
            rc = rho_l * cp_l
            keff = 0.5 * ((k_l + rc * eps)[:-1] + (k_l + rc * eps)[1:])
            G = keff * Ai / (0.5 * (dz_l[:-1] + dz_l[1:]))
            mc = m_l * cp_l
            Kadj = np.minimum(mc[:-1], mc[1:]) / TAU_ADJUST
            Q = G * (T_l[:-1] - T_l[1:]) + Kadj * _ramp(T_l[:-1] - T_l[1:])
            X_l[:-1] -= Q
            X_l[1:] += Q
        # ullage layer-to-layer
        if N_VAP > 1:
            zi = zb[N_LIQ + 1:-1]
            Ai = geo.area_h(zi)
            eps = EPS0_VAP + C_EPS * nu_v * S_v ** 0.8
            rc = rho_v * cp_v
            keff = 0.5 * ((k_v + rc * eps)[:-1] + (k_v + rc * eps)[1:])
            G = keff * Ai / (0.5 * (dz_v[:-1] + dz_v[1:]))
            mc = m_v * cp_v + n_v * CP_HE
            Kadj = np.minimum(mc[:-1], mc[1:]) / TAU_ADJUST
            Q = G * (T_v[:-1] - T_v[1:]) + Kadj * _ramp(T_v[:-1] - T_v[1:])
            X_v[:-1] -= Q
            X_v[1:] += Q

        # interface
        A_i = max(float(geo.area_h(level)), 1e-6)
        L_i = math.sqrt(4 * A_i / math.pi)
        P_f0 = st["P_f"][0]
        T_i, hl_s, hv_s = (float(x) for x in fl.sat(P_f0))
        lat = hv_s - hl_s
        dTv = T_v[0] - T_i
        Ra = GRAV * beta_v[0] * _absreg(dTv) * L_i ** 3 / (nu_v[0] * a_v[0])
        h_vi = (k_v[0] / (0.5 * dz_v[0]) + _on(-dTv, 0.05) * _nu_plate(Ra) * k_v[0] / L_i) * f_int
        dTl = T_l[-1] - T_i
        Ra = GRAV * abs(beta_l[-1]) * _absreg(dTl) * L_i ** 3 / (nu_l[-1] * a_l[-1])
        h_li = (k_l[-1] / (0.5 * dz_l[-1]) + _on(dTl, 0.05) * _nu_plate(Ra) * k_l[-1] / L_i) * f_int
        Q_vi = h_vi * A_i * dTv
        Q_li = h_li * A_i * dTl
        J = (Q_vi + Q_li) / lat
        X_v[0] += -Q_vi + J * hv_s
        md_v[0] += J
        X_l[-1] += -Q_li - J * hl_s
        md_l[-1] -= J

        # bulk flash of superheated liquid layers (total pressure)
        T_sp, hl_p, hv_p = (float(x) for x in fl.sat(p))
        lat_p = hv_p - hl_p
        flash = m_l * cp_l * _ramp(T_l - T_sp) / (TAU_FLASH * lat_p)
        X_l -= flash * hv_p
        md_l -= flash
        X_v[0] += flash.sum() * hv_p
        md_v[0] += flash.sum()
        # fog in subcooled ullage layers (their partial pressure)
        T_sj, hl_j, hv_j = fl.sat(st["P_f"])
        fog = (m_v * cp_v + n_v * CP_HE) * _ramp(T_sj - T_v) / (TAU_FOG * (hv_j - hl_j))
        X_v -= fog * hl_j
        md_v -= fog
        X_l[-1] += float(np.sum(fog * hl_j))
        md_l[-1] += float(fog.sum())

        # re-gridding towards equal volumes
        if N_LIQ > 1:
            exc = np.cumsum(st["V_lay"])[:-1] - np.arange(1, N_LIQ) * st["V_l"] / N_LIQ
            F = exc / TAU_REGRID
            don = np.where(F > 0, np.arange(N_LIQ - 1), np.arange(1, N_LIQ))
            Fm = F * rho_l[don]
            Fh = Fm * h_l[don]
            md_l[:-1] -= Fm
            md_l[1:] += Fm
            X_l[:-1] -= Fh
            X_l[1:] += Fh
        if N_VAP > 1:
            exc = np.cumsum(st["V_vlay"])[:-1] - np.arange(1, N_VAP) * st["V_v"] / N_VAP
            F = exc / TAU_REGRID
            don = np.where(F > 0, np.arange(N_VAP - 1), np.arange(1, N_VAP))
            Fm = F * rho_v[don]
            Fn = Fm * (n_v / m_v)[don]
            Fh = Fm * hmix[don]
            md_v[:-1] -= Fm
            md_v[1:] += Fm
            nd_v[:-1] -= Fn
            nd_v[1:] += Fn
            X_v[:-1] -= Fh
            X_v[1:] += Fh

        # operations and leaks
        bias = 1.0 + mech["inflow_meter_bias"]
        dMin = dNin = 0.0
        mvin = bias * inp["mdot_v_in_kg_s"]
        if mvin:
            md_v[-1] += mvin
            X_v[-1] += mvin * self.h_v_in
            dMin += mvin
            dEin += mvin * self.h_v_in
        vent = inp["mdot_v_out_kg_s"] + mech["vapor_leak_kg_s"]
        if vent:
            mix = m_v[-1] + n_v[-1] * MW_HE
            mf = vent * m_v[-1] / mix
            nf = vent * (n_v[-1] * MW_HE / mix) / MW_HE
            md_v[-1] -= mf
            nd_v[-1] -= nf
            X_v[-1] -= mf * st["h_f"][-1] + nf * CP_HE * T_v[-1]
            dMin -= mf
            dNin -= nf
            dEin -= mf * st["h_f"][-1] + nf * CP_HE * T_v[-1]
        mlin = bias * inp["mdot_l_in_kg_s"]
        if mlin:
            ui, vi, _, _ = fl.liq(inp["T_l_in_K"])
            hin = float(ui + p * vi)
            md_l[0] += mlin
            X_l[0] += mlin * hin
            dMin += mlin
            dEin += mlin * hin
        drain = inp["mdot_l_out_kg_s"] + mech["liquid_leak_kg_s"]
        if drain:
            md_l[0] -= drain
            X_l[0] -= drain * h_l[0]
            dMin -= drain
            dEin -= drain * h_l[0]

        # liquid: temperature and volume rates, p dV work
        dT_l = (X_l - h_l * md_l) / (m_l * (st["du_l"] + p * st["dv_l"]))
        dV_l = m_l * st["dv_l"] * dT_l + v_l * md_l
        dU_l = X_l - p * dV_l
        # ullage: equal-pressure condition gives dp/dt and each layer's volume change
        dVv = -float(dV_l.sum())
        a11 = m_v * st["h_T"] + n_v * CP_HE
        a12 = m_v * st["h_r"]
        a21 = st["P_T"] + n_v * RU * rho_v / m_v
        a22 = st["P_r"] + n_v * RU * T_v / m_v
        det = a11 * a22 - a12 * a21
        B10, B11 = -a21 / det, a11 / det
        Vj = st["V_vlay"]
        rH = X_v - st["h_f"] * md_v - CP_HE * T_v * nd_v
        rP = n_v * RU * T_v * rho_v / m_v ** 2 * md_v - RU * T_v * rho_v / m_v * nd_v
        c0 = md_v / rho_v - m_v / rho_v ** 2 * (B10 * rH + B11 * rP)
        c1 = -m_v / rho_v ** 2 * (B10 * Vj + B11)
        dp = (dVv - c0.sum()) / c1.sum()
        dU_v = X_v - p * (c0 + c1 * dp)
        out = np.concatenate([md_l, dU_l, md_v, dU_v, nd_v, dE, [dMin, dNin, dEin]])
        if not np.all(np.isfinite(out)):
            raise SimulationError(f"t = {t:.1f} s: non-finite rates (p = {p:.6g} Pa, T_l = {T_l.min():.4g}.."
                                  f"{T_l.max():.4g} K, T_v = {T_v.min():.4g}..{T_v.max():.4g} K)")
        return out


# ------------------------------------------------------------------------------- scenarios
def _p_range(fl: Fluid) -> tuple[float, float]:
    lo = max(1.05 * ATM, 1.6 * fl.p_trip)
    return lo, max(1.1 * lo, 0.35 * fl.pc)


def _make_scenario(name: str, fluid: str, tank: dict, material: str, thickness: float, q_W_m2: float, fill: float,
                   p0: float, subcool: float, superheat: float, dry_extra: float, wet_extra: float,
                   phases: list[dict]) -> dict[str, Any]:
    fl = get_fluid(fluid)
    lo, hi = _p_range(fl)
    p0 = float(min(max(p0, lo), hi))
    geo = Shape(tank)
    T_sat = float(fl.T_sat(p0))
    T_l = max(T_sat - subcool, fl.T_trip + 0.3)
    T_v = T_sat + superheat
    T_w_mean = fill * (T_l + wet_extra) + (1 - fill) * (T_v + 0.5 * dry_extra)
    C_w, k_w = _wall_props(material, thickness, geo.A_wall, T_w_mean)
    return {"name": name, "fluid": fluid, "tank": {"shape": geo.shape, **geo.tank_dims()},
            "wall": {"material": material, "thickness_m": thickness, "C_w_J_per_K": C_w, "k_w_W_per_mK": k_w},
            "Q_aw_W": q_W_m2 * geo.A_wall, "heat_flux_W_m2": q_W_m2,
            "initial": {"p_Pa": p0, "T_l_K": T_l, "T_v_K": T_v, "fill_ratio": fill, "wet_extra_K": wet_extra,
                        "dry_extra_K": dry_extra},
            "phases": phases, "duration_s": float(sum(ph["duration_s"] for ph in phases))}


def _sc_lh2_upright(fluid: str | None) -> dict[str, Any]:
    tank = {"shape": "vertical_cylinder_elliptical_heads", "radius_m": 1.3, "cylinder_length_m": 1.96,
            "head_aspect": 2.0}
    phases = [{"kind": "rest", "duration_s": 900.0},
              {"kind": "pressurize", "duration_s": 600.0, "dp_frac": 0.3, "T_in_factor": 2.0},
              {"kind": "rest", "duration_s": 600.0},
              {"kind": "vent", "duration_s": 600.0, "p_frac": 0.75},
              {"kind": "rest", "duration_s": 300.0},
              {"kind": "slosh", "duration_s": 900.0, "amp_m": 0.01, "freq_ratio": 0.9},
              {"kind": "rest", "duration_s": 600.0}]
    return _make_scenario("lh2_upright", fluid or "ParaHydrogen", tank, "aluminium", 0.008, 2.5, 0.6,
                          1.6 * ATM, 0.3, 4.0, 3.0, 0.05, phases)


def _sc_ln2_sphere(fluid: str | None) -> dict[str, Any]:
    tank = _tank_of_volume("sphere", 5.0, 1.0)
    phases = [{"kind": "rest", "duration_s": 600.0},
              {"kind": "fill", "duration_s": 900.0, "dfill": 0.2, "subcool_K": 2.0},
              {"kind": "rest", "duration_s": 600.0},
              {"kind": "drain", "duration_s": 900.0, "dfill": 0.3},
              {"kind": "vent", "duration_s": 600.0, "p_frac": 0.8},
              {"kind": "rest", "duration_s": 600.0}]
    return _make_scenario("ln2_sphere", fluid or "Nitrogen", tank, "steel", 0.006, 4.0, 0.5, 2.5 * ATM,
                          1.0, 5.0, 2.0, 0.05, phases)


def _sc_lh2_hcyl(fluid: str | None) -> dict[str, Any]:
    tank = _tank_of_volume("horizontal_cylinder", 8.0, 2.0)
    phases = [{"kind": "rest", "duration_s": 600.0},
              {"kind": "drain", "duration_s": 900.0, "dfill": 0.25},
              {"kind": "rest", "duration_s": 600.0},
              {"kind": "fill", "duration_s": 900.0, "dfill": 0.15, "subcool_K": 0.5},
              {"kind": "rest", "duration_s": 900.0}]
    return _make_scenario("lh2_hcyl", fluid or "ParaHydrogen", tank, "steel", 0.005, 5.0, 0.7, 2.0 * ATM,
                          0.2, 3.0, 2.0, 0.05, phases)


NAMED_SCENARIOS = {
    "lh2_upright": ("ParaHydrogen, 15 m3 upright cylinder with 2:1 heads, aluminium; self-pressurisation, "
                    "warm-gas pressurisation, vent, sloshing", _sc_lh2_upright),
    "ln2_sphere": ("Nitrogen, 5 m3 sphere, steel; fill with subcooled liquid, drain, vent", _sc_ln2_sphere),
    "lh2_hcyl": ("ParaHydrogen, 8 m3 horizontal cylinder, steel; drain, top-up, heat load", _sc_lh2_hcyl),
}


def _phase_draw(kind: str, dur: float, rng: np.random.Generator) -> dict[str, Any]:
    ph: dict[str, Any] = {"kind": kind, "duration_s": dur}
    if kind == "pressurize":
        ph.update(dp_frac=float(rng.uniform(0.1, 0.4)), T_in_factor=float(rng.uniform(1.3, 2.5)))
    elif kind == "vent":
        ph.update(p_frac=float(rng.uniform(0.65, 0.9)))
    elif kind == "fill":
        ph.update(dfill=float(rng.uniform(0.05, 0.2)), subcool_K=float(rng.uniform(0.0, 2.5)))
    elif kind == "drain":
        ph.update(dfill=float(rng.uniform(0.05, 0.25)))
    elif kind == "slosh":
        ph.update(amp_m=float(rng.uniform(0.003, 0.02)), freq_ratio=float(rng.uniform(0.5, 1.3)))
    return ph


def random_scenario(seed: int, fluid: str | None = None) -> dict[str, Any]:
    """A random plausible tank and schedule (deterministic in ``seed``)."""
    rng = np.random.default_rng([int(seed), 7331])
    fl_name = str(rng.choice(FLUIDS))
    fl_name = fluid or fl_name
    fl = get_fluid(fl_name)
    shape = str(rng.choice(SHAPES))
    V = math.exp(rng.uniform(math.log(1.0), math.log(60.0)))
    if shape == "vertical_cylinder":
        tank = _tank_of_volume(shape, V, rng.uniform(0.7, 2.5))
    elif shape == "vertical_cylinder_elliptical_heads":
        tank = _tank_of_volume(shape, V, rng.uniform(0.3, 2.0), float(rng.choice([2.0, 2.0, 1.5])))
    elif shape == "sphere":
        tank = _tank_of_volume(shape, V, 1.0)
    else:
        tank = _tank_of_volume(shape, V, rng.uniform(1.2, 3.5))
    material = "steel" if rng.random() < 0.55 else "aluminium"
    R = tank["radius_m"]
    lo, hi = _p_range(fl)
    p0 = math.exp(rng.uniform(math.log(lo), math.log(hi)))
    d = _WALL_DATA[material]
    thickness = max(d["t_min"], 2.0 * max(2 * p0, 3e5) * R / d["stress"]) * rng.uniform(1.0, 1.4)
    q = math.exp(rng.uniform(math.log(0.5), math.log(6.0)))
    fill = float(rng.uniform(0.2, 0.9))
    subcool = float(rng.uniform(0.0, 0.1) if rng.random() < 0.4 else rng.uniform(0.2, 2.0))
    superheat = float(rng.uniform(0.5, 8.0))
    dry_extra, wet_extra = float(rng.uniform(0.0, 3.0)), float(rng.uniform(0.0, 0.15))
    n = int(rng.integers(3, 7))
    durs = [10.0 * round(rng.uniform(300.0, 1500.0) / 10.0) for _ in range(n)]
    w = np.array([0.25, 0.15, 0.2, 0.12, 0.13, 0.15])
    kinds = [str(k) for k in rng.choice(PHASE_KINDS, size=n, p=w / w.sum())]
    phases = [_phase_draw(k, dd, rng) for k, dd in zip(kinds, durs)]
    return _make_scenario(f"random_{seed}", fl_name, tank, material, float(thickness), q, fill, p0, subcool,
                          superheat, dry_extra, wet_extra, phases)


def named_scenario(name: str, fluid: str | None = None) -> dict[str, Any]:
    if name not in NAMED_SCENARIOS:
        raise ValueError(f"unknown scenario {name!r}; known: {', '.join(NAMED_SCENARIOS)}, random_SEED")
    return NAMED_SCENARIOS[name][1](fluid)


def resolve_scenario(scenario: str | Mapping[str, Any], fluid: str | None = None) -> dict[str, Any]:
    if isinstance(scenario, Mapping):
        return copy.deepcopy(dict(scenario))
    if scenario.startswith("random_"):
        try:
            seed = int(scenario[len("random_"):])
        except ValueError:
            raise ValueError(f"random scenarios are named random_SEED (an integer), got {scenario!r}") from None
        return random_scenario(seed, fluid)
    return named_scenario(scenario, fluid)


# ------------------------------------------------------------------------------- operator and integration
def _bounds(fl: Fluid) -> dict[str, float]:
    return {"p_hi": 0.6 * fl.pc, "p_relief_off": 0.55 * fl.pc, "p_lo": max(0.55 * ATM, 1.5 * fl.p_trip),
            "fill_hi": 0.94, "fill_lo": 0.06}


def _plan(model: LayerModel, y: np.ndarray, ph: Mapping[str, Any], Q_aw: float) -> dict[str, float]:
    fl, geo = model.fl, model.geo
    st = model.state(y)
    inp = {c: 0.0 for c in INPUT_COLUMNS}
    inp["Q_aw_W"] = Q_aw
    p, V_v = st["p"], st["V_v"]
    fill = st["V_l"] / geo.V
    dur = max(float(ph["duration_s"]), 1.0)
    kind = ph["kind"]
    b = _bounds(fl)
    if kind == "pressurize":
        p1 = min(p * (1 + ph["dp_frac"]), 0.9 * b["p_hi"])
        if p1 > 1.02 * p:
            T_in = float(min(max(ph["T_in_factor"] * fl.T_sat(p), fl.T_sat(p) + 5.0), 300.0))
            p_in = min(1.3 * p1, 0.8 * fl.pc)
            dm = 1.3 * (p1 - p) * V_v * fl.M / (1.4 * RU * T_in)
            inp.update(mdot_v_in_kg_s=dm / dur, T_v_in_K=T_in, p_v_in_Pa=p_in)
    elif kind == "vent":
        p1 = max(p * ph["p_frac"], 1.1 * b["p_lo"])
        if p1 < 0.97 * p:
            rho_v = float(np.sum(st["m_v"]) / V_v)
            inp["mdot_v_out_kg_s"] = 1.0 * rho_v * V_v * (1 - p1 / p) / dur
    elif kind == "fill":
        df = min(ph["dfill"], 0.9 - fill)
        if df > 0.01:
            T_in = float(max(fl.T_sat(p) - ph["subcool_K"], fl.T_trip + 0.5))
            inp.update(mdot_l_in_kg_s=df * geo.V / float(fl.liq(T_in)[1]) / dur, T_l_in_K=T_in)
    elif kind == "drain":
        df = min(ph["dfill"], fill - 0.12)
        if df > 0.01:
            inp["mdot_l_out_kg_s"] = df * geo.V / float(st["v_l"][0]) / dur
    elif kind == "slosh":
        R, h = geo.R, max(st["level"], 0.05)
        om1 = math.sqrt(1.841 * GRAV / R * math.tanh(1.841 * h / R))
        inp.update(slosh_amplitude_m=float(ph["amp_m"]), slosh_frequency_Hz=ph["freq_ratio"] * om1 / (2 * math.pi))
    elif kind != "rest":
        raise ValueError(f"unknown phase kind {kind!r}")
    return {k: float(v) for k, v in inp.items()}


def _atol(model: LayerModel) -> np.ndarray:
    y0 = model.y0
    m_l, U_l, m_v, U_v, n_v, E_w, _, _, _ = model._split(y0)
    M = float(m_l.sum() + m_v.sum())
    lat = float(model.fl.sat(ATM)[2] - model.fl.sat(ATM)[1])
    sm = 1e-6 * M / (N_LIQ + N_VAP)
    se = sm * lat
    return np.concatenate([np.full(N_LIQ, sm), np.full(N_LIQ, se), np.full(N_VAP, sm), np.full(N_VAP, se),
                           np.full(N_VAP, 1e-6 * max(n_v.sum(), 1e-3)), 1e-6 * model.C_node * 10.0,
                           [sm, 1e-6, se]]) * 1e-2


def _check_hard(model: LayerModel, o: Mapping[str, Any], t: float) -> None:
    fl = model.fl
    if o["P_f_max"] > 0.9 * fl.pc or o["P_f_min"] < 1.1 * fl.p_trip:
        raise SimulationError(f"t = {t:.0f} s: fluid partial pressure {o['P_f_min']:.0f}..{o['P_f_max']:.0f} Pa "
                              f"outside the valid range")
    if not 0.01 <= o["fill"] <= 0.985:
        raise SimulationError(f"t = {t:.0f} s: fill ratio {o['fill']:.4f} outside 1-98.5 %")


def _integrate(model: LayerModel, sc: Mapping[str, Any], duration: float,
               fixed: list[dict] | None) -> dict[str, Any]:
    """Integrate phase by phase (or over a fixed executed schedule); returns states at sample times."""
    fl = model.fl
    bnd = _bounds(fl)
    atol = _atol(model)
    y = model.y0.copy()
    ys: dict[float, np.ndarray] = {0.0: y.copy()}
    executed: list[dict] = []
    changes: list[dict] = []

    if fixed is not None:
        segments = [(s["t0"], s["t1"], s["kind"], dict(s["inputs"])) for s in fixed]
    else:
        segments = []
        t = 0.0
        for ph in sc["phases"]:
            if t >= duration:
                break
            t1 = min(t + ph["duration_s"], duration)
            segments.append((t, t1, ph["kind"], ph))
            t = t1
        if t < duration:
            segments.append((t, duration, "rest", {"kind": "rest", "duration_s": duration - t}))

    def run_span(t0, t1, inputs, events):
        model.set_inputs(inputs)
        samples = np.arange(math.ceil(t0 / DT_SAMPLE - 1e-9) * DT_SAMPLE, t1 + 1e-9, DT_SAMPLE)
        samples = samples[(samples > t0 + 1e-9) & (samples < t1 - 1e-9)]
        t_eval = np.append(samples, t1)
        try:
            sol = solve_ivp(model.rhs, (t0, t1), y_now[0], method="LSODA", rtol=RTOL, atol=atol,
                            max_step=MAX_STEP, t_eval=t_eval, events=events or None)
        except SimulationError as e:
            raise SimulationError(f"t in [{t0:.0f}, {t1:.0f}] s: {e}") from None
        if sol.status < 0:
            raise SimulationError(f"integration failed in [{t0:.0f}, {t1:.0f}] s: {sol.message}")
        for k, tt in enumerate(sol.t):
            if abs(tt / DT_SAMPLE - round(tt / DT_SAMPLE)) < 1e-9:
                ys[float(round(tt / DT_SAMPLE) * DT_SAMPLE)] = sol.y[:, k].copy()
        if sol.status == 1:
            k = next(i for i, te in enumerate(sol.t_events) if len(te))
            return float(sol.t_events[k][0]), sol.y_events[k][0].copy(), k
        if not sol.t.size or sol.t[-1] < t1 - 1e-9:
            raise SimulationError(f"integration stopped before {t1:.0f} s")
        return t1, sol.y[:, -1].copy(), None

    def ev(fun, direction):
        def f(t, yy):
            return fun(model.state(yy))
        f.terminal = True
        f.direction = direction
        return f

    V = model.geo.V
    y_now = [y]
    for (t0, t1, kind, spec) in segments:
        if fixed is not None:
            tt, ynew, _ = run_span(t0, t1, spec, None)
            y_now[0] = ynew
            executed.append({"t0": t0, "t1": t1, "kind": kind, "inputs": spec})
            _check_hard(model, model.observe(ynew), t1)
            continue
        inputs = _plan(model, y_now[0], spec, sc["Q_aw_W"])
        relief = False
        t = t0
        while t < t1 - 1e-9:
            evs, names = [], []
            if inputs["mdot_v_in_kg_s"] > 0 or inputs["mdot_l_in_kg_s"] > 0 or not relief:
                evs.append(ev(lambda s: s["p"] - bnd["p_hi"], 1)); names.append("p_hi")
            if relief:
                evs.append(ev(lambda s: s["p"] - bnd["p_relief_off"], -1)); names.append("relief_off")
            if inputs["mdot_v_out_kg_s"] > 0 or inputs["mdot_l_out_kg_s"] > 0:
                evs.append(ev(lambda s: s["p"] - bnd["p_lo"], -1)); names.append("p_lo")
            if inputs["mdot_l_in_kg_s"] > 0:
                evs.append(ev(lambda s: s["V_l"] / V - bnd["fill_hi"], 1)); names.append("fill_hi")
            if inputs["mdot_l_out_kg_s"] > 0:
                evs.append(ev(lambda s: s["V_l"] / V - bnd["fill_lo"], -1)); names.append("fill_lo")
            te, ynew, k = run_span(t, t1, inputs, evs)
            if te > t + 1e-9:
                executed.append({"t0": t, "t1": te, "kind": kind, "inputs": dict(inputs)})
            y_now[0] = ynew
            _check_hard(model, model.observe(ynew), te)
            if k is None:
                t = te
                continue
            what = names[k]
            new = dict(inputs)
            if what == "p_hi":
                new.update(mdot_v_in_kg_s=0.0, T_v_in_K=0.0, p_v_in_Pa=0.0, mdot_l_in_kg_s=0.0, T_l_in_K=0.0)
                st = model.state(ynew)
                new["mdot_v_out_kg_s"] = max(new["mdot_v_out_kg_s"], 0.2 * float(st["m_v"].sum()) / 600.0)
                relief = True
            elif what == "relief_off":
                new["mdot_v_out_kg_s"] = 0.0
                relief = False
            elif what == "p_lo":
                new.update(mdot_v_out_kg_s=0.0, mdot_l_out_kg_s=0.0)
            elif what == "fill_hi":
                new.update(mdot_l_in_kg_s=0.0, T_l_in_K=0.0)
            elif what == "fill_lo":
                new["mdot_l_out_kg_s"] = 0.0
            changes.append({"t_s": te, "bound": what, "inputs": {c: v for c, v in new.items() if v != 0.0}})
            inputs = new
            # the event time need not be a sample time: nudge past it to avoid re-triggering
            t = te
    return {"ys": ys, "executed": executed, "changes": changes}


def _mechanisms(mech: Mapping[str, float] | None) -> dict[str, float]:
    out = {}
    for k, v in (mech or {}).items():
        if k not in MECHANISMS:
            raise ValueError(f"unknown mechanism {k!r}; known: {', '.join(MECHANISMS)}")
        v = float(v)
        if not math.isfinite(v):
            raise ValueError(f"mechanism {k} must be finite")
        out[k] = v
    if out.get("helium_mol", 0.0) < 0:
        raise ValueError("helium_mol must be >= 0")
    if out.get("wall_heat_capacity_error", 0.0) <= -0.9:
        raise ValueError("wall_heat_capacity_error must be > -0.9")
    return out


def simulate(scenario: str | Mapping[str, Any], mechanisms: Mapping[str, float] | None = None, *,
             fluid: str | None = None, duration_s: float | None = None) -> dict[str, Any]:
    """Simulate a scenario; returns the sampled states, observations, schedule and closure."""
    wall0 = time.perf_counter()
    mech = _mechanisms(mechanisms)
    sc = resolve_scenario(scenario, fluid)
    duration = float(sc["duration_s"] if duration_s is None else duration_s)
    if not duration > 0 or duration % DT_SAMPLE:
        raise ValueError(f"duration must be a positive multiple of {DT_SAMPLE:g} s, got {duration}")
    nominal = LayerModel(sc, {})
    res = _integrate(nominal, sc, duration, None)
    model, nfev = nominal, nominal.nfev
    if any(v != 0.0 for v in mech.values()):
        model = LayerModel(sc, mech)
        res = _integrate(model, sc, duration, [dict(s) for s in res["executed"]]) | {"changes": res["changes"]}
        nfev += model.nfev
    times = np.array(sorted(res["ys"]))
    Y = np.array([res["ys"][t] for t in times])
    obs = [model.observe(yy) for yy in Y]
    M0, N0, E0 = model.totals(model.y0)
    tot = np.array([model.totals(yy) for yy in Y])
    err_m = tot[:, 0] - M0 - Y[:, -3]
    err_n = tot[:, 1] - N0 - Y[:, -2]
    err_e = tot[:, 2] - E0 - Y[:, -1]
    fl = model.fl
    lat = float(fl.sat(ATM)[2] - fl.sat(ATM)[1])
    moved = sum((s["t1"] - s["t0"]) * (s["inputs"]["mdot_v_in_kg_s"] + s["inputs"]["mdot_v_out_kg_s"]
                                        + s["inputs"]["mdot_l_in_kg_s"] + s["inputs"]["mdot_l_out_kg_s"])
                for s in res["executed"])
    heat = sum((s["t1"] - s["t0"]) * abs(s["inputs"]["Q_aw_W"]) for s in res["executed"])
    scale_m = M0 + moved
    scale_e = heat + (moved + 0.01 * M0) * lat
    closure = {"mass_kg_max_abs": float(np.max(np.abs(err_m))), "mass_rel": float(np.max(np.abs(err_m)) / scale_m),
               "helium_mol_max_abs": float(np.max(np.abs(err_n))),
               "energy_J_max_abs": float(np.max(np.abs(err_e))), "energy_rel": float(np.max(np.abs(err_e)) / scale_e),
               "mass_scale_kg": scale_m, "energy_scale_J": scale_e,
               "note": "max over samples of |total(t) - total(0) - boundary quadrature(t)|; energy scale = "
                       "|Q_aw| t + (mass moved + 1 % of the initial mass) x latent heat at 1 atm"}
    return {"scenario": sc, "mechanisms": mech, "model": model, "times": times, "Y": Y, "obs": obs,
            "executed": res["executed"], "changes": res["changes"], "duration_s": duration, "closure": closure,
            "nfev": nfev, "wall_time_s": time.perf_counter() - wall0}


def _num(v: float) -> str:
    return repr(float(v))


def simulate_run(scenario: str | Mapping[str, Any], mechanisms: Mapping[str, float] | None = None,
                 noise: str = "low", seed: int = 0, out_dir: str | pathlib.Path = ".", name: str | None = None,
                 fluid: str | None = None, duration_s: float | None = None,
                 wall_capacity_unknown: bool = False, sensors: str = "average") -> dict[str, pathlib.Path]:
    """Simulate and write ``NAME.json``, ``NAME.csv`` and ``NAME.truth.json``; returns their paths.

    ``sensors``: ``"average"`` (the mass or capacity averages of the layers and wall nodes) or
    ``"point"`` (probes, as a real tank has them: ``T_v`` in the middle ullage layer, ``T_l`` in
    the second liquid layer from the bottom, ``T_w`` on the wall band at mid-height, which is dry
    or wetted as the level moves).
    """
    if noise not in ("none", "low", "high"):
        raise ValueError(f"noise must be none, low or high, got {noise!r}")
    if sensors not in SENSORS:
        raise ValueError(f"sensors must be one of {', '.join(SENSORS)}, got {sensors!r}")
    res = simulate(scenario, mechanisms, fluid=fluid, duration_s=duration_s)
    sc, model, mech, obs, times = res["scenario"], res["model"], res["mechanisms"], res["obs"], res["times"]
    # What the sensors read (the truth file keeps the layers' averages and the layers themselves).
    read = obs if sensors == "average" else [
        {**o, "T_v": o["T_v_layers"][N_VAP // 2], "T_l": o["T_l_layers"][1], "T_w": o["T_w_nodes"][N_WALL // 2]}
        for o in obs]
    std = NOISE_LEVELS["low" if noise == "none" else noise]
    rng = np.random.default_rng(seed)
    bp, bT = mech.get("pressure_sensor_bias_Pa", 0.0), mech.get("temperature_sensor_bias_K", 0.0)
    truth_ch = {"p_v_Pa": np.array([o["p"] for o in read]) + bp, "T_v_K": np.array([o["T_v"] for o in read]),
                "T_l_K": np.array([o["T_l"] for o in read]) + bT, "T_w_K": np.array([o["T_w"] for o in read]),
                "H_l_m": np.array([o["level"] for o in read])}
    meas: dict[str, dict[float, float]] = {}
    for ch, key in zip(OBS_COLUMNS, NOISE_KEYS):
        dt = DT_SAMPLE_WALL if ch == "T_w_K" else DT_SAMPLE
        sel = np.array([abs(t / dt - round(t / dt)) < 1e-9 for t in times])
        vals = truth_ch[ch][sel]
        if noise != "none":
            vals = vals + rng.normal(0.0, std[key], size=vals.size)
        if ch == "H_l_m":
            vals = np.maximum(vals, 0.0)
        meas[ch] = dict(zip(times[sel].tolist(), vals.tolist()))
    executed = res["executed"]
    used = [c for c in INPUT_COLUMNS if any(s["inputs"][c] != 0.0 for s in executed)]
    row_t = sorted(set(times.tolist()) | {float(s["t0"]) for s in executed})
    run_name = name or f"layer_{sc['name']}"
    out = pathlib.Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    csv_path = out / f"{run_name}.csv"
    with open(csv_path, "w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(["t_s", *OBS_COLUMNS, *used])
        seg = 0
        for t in row_t:
            while seg + 1 < len(executed) and executed[seg + 1]["t0"] <= t + 1e-12:
                seg += 1
            row = [_num(t)] + ["" if meas[ch].get(t) is None else _num(meas[ch][t]) for ch in OBS_COLUMNS]
            row += [_num(executed[seg]["inputs"][c]) for c in used]
            w.writerow(row)
    o0 = obs[0]
    tank = {**sc["tank"], "volume_m3": model.geo.V,
            "wall_heat_capacity_J_per_K": None if wall_capacity_unknown else model.C_meta}
    meta = {"name": run_name, "fluid": sc["fluid"],
            "source": f"{SIMULATOR}: independent stratified (layered) tank simulator, CoolProp, scenario {sc['name']}",
            "tank": tank,
            "initial": {"p_v_Pa": o0["p"] + bp, "T_v_K": read[0]["T_v"], "T_l_K": read[0]["T_l"] + bT,
                        "T_w_K": read[0]["T_w"], "fill_ratio": o0["fill"]},
            "noise_std": {k: std[k] for k in NOISE_KEYS}, "duration_s": res["duration_s"],
            "timeseries": csv_path.name}
    json_path = out / f"{run_name}.json"
    json_path.write_text(json.dumps(meta, indent=2) + "\n")

    def summ(k):
        v = np.array([o[k] for o in obs])
        return {"min": float(v.min()), "max": float(v.max()), "final": float(v[-1])}

    def snap(o):
        return {"p_Pa": o["p"], "p_fluid_Pa": o["p_f"], "p_helium_Pa": o["p_he"], "T_interface_K": o["T_i"],
                "T_v_K": o["T_v"], "T_l_K": o["T_l"], "T_w_K": o["T_w"], "fill_ratio": o["fill"],
                "level_m": o["level"], "m_v_kg": o["m_v"], "m_l_kg": o["m_l"], "helium_mol": o["n_he"],
                "T_liquid_layers_K": o["T_l_layers"], "T_ullage_layers_K": o["T_v_layers"],
                "T_wall_nodes_K": o["T_w_nodes"]}

    truth = {"simulator": SIMULATOR, "scenario": sc, "mechanisms": {k: mech.get(k, 0.0) for k in MECHANISMS},
             "noise": noise, "seed": seed, "sensors": sensors,
             "layers": {"liquid": N_LIQ, "ullage": N_VAP, "wall_nodes": N_WALL},
             "wall_heat_capacity_true_J_per_K": model.C_w, "wall_heat_capacity_metadata_J_per_K": model.C_meta,
             "wall_heat_capacity_written": not wall_capacity_unknown,
             "initial_true": snap(o0), "final_true": snap(obs[-1]),
             "summary": {k: summ(k) for k in ("p", "p_he", "T_v", "T_l", "T_w", "T_i", "level", "fill")},
             "schedule": [{"t0_s": s["t0"], "t1_s": s["t1"], "kind": s["kind"],
                           "inputs": {c: v for c, v in s["inputs"].items() if v != 0.0}} for s in executed],
             "schedule_changes": res["changes"], "closure": res["closure"], "rhs_calls": res["nfev"],
             "wall_time_s": res["wall_time_s"]}
    truth_path = out / f"{run_name}.truth.json"
    truth_path.write_text(json.dumps(truth, indent=2) + "\n")
    return {"json": json_path, "csv": csv_path, "truth": truth_path}


# ------------------------------------------------------------------------------- command line
def _mech_arg(text: str) -> tuple[str, float]:
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
    ap = argparse.ArgumentParser(description="Independent stratified (layered) cryogenic tank simulator: writes "
                                             "runs in the interchange format (NAME.json, NAME.csv, NAME.truth.json).")
    ap.add_argument("scenario", nargs="?", help="a named scenario (see --list) or random_SEED")
    ap.add_argument("--list", action="store_true", help="list the scenarios, mechanisms and fluids, and exit")
    ap.add_argument("--fluid", help="CoolProp fluid (overrides the scenario's)")
    ap.add_argument("--mechanism", action="append", default=[], type=_mech_arg, metavar="NAME=VALUE",
                    help="hidden mechanism (repeatable)")
    ap.add_argument("--noise", default="low", choices=("none", "low", "high"))
    ap.add_argument("--seed", type=int, default=0, help="seed of the sensor noise")
    ap.add_argument("--out", default=".", help="output folder")
    ap.add_argument("--name", help="run name (default layer_SCENARIO)")
    ap.add_argument("--duration", type=float, help="duration [s] (a multiple of 10 s)")
    ap.add_argument("--wall-capacity-unknown", action="store_true", help="write null for the wall heat capacity")
    ap.add_argument("--sensors", default="average", choices=SENSORS,
                    help="temperatures as layer averages (average) or as probes in one layer each (point)")
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
                             wall_capacity_unknown=args.wall_capacity_unknown, sensors=args.sensors)
    except (ValueError, SimulationError) as e:
        print(f"layer_sim: error: {e}", file=sys.stderr)
        return 2
    truth = json.loads(paths["truth"].read_text())
    s, c = truth["summary"], truth["closure"]
    print(f"wrote {paths['json']} ({truth['scenario']['fluid']}, {truth['wall_time_s']:.1f} s, "
          f"{truth['rhs_calls']} rhs calls; p {s['p']['min']:.0f}..{s['p']['max']:.0f} Pa, "
          f"fill {s['fill']['min']:.3f}..{s['fill']['max']:.3f}; closure mass {c['mass_rel']:.1e}, "
          f"energy {c['energy_rel']:.1e})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
