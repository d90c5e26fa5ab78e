"""Nodal cryogenic-tank simulator: a second, independent source of synthetic "measured" runs.

Purpose
-------
This module simulates liquid-hydrogen tanks from physics that tankode did not write, and
writes the results in the run interchange format (``shared/data-format.md``) so that
tankode's learned closures and its diagnosis can be tested *blindly*. It imports neither
``tankode``, ``trainers`` nor the first independent simulator (``tests/independent_sim.py``);
its formulation, heat-transfer laws, wall model and numerics all differ from both.

Formulation (0-D nodal model, conservative variables)
-----------------------------------------------------
State ``y`` (all SI):

* ``m_v`` [kg], ``U_g`` [J]: hydrogen mass in the ullage and the internal energy of the whole
  ullage gas (hydrogen + helium); ``n_He`` [mol]: helium in the ullage (hidden mechanism);
* ``m_k``, ``U_k`` for ``k = 0 .. N-1``: mass and internal energy of each liquid layer
  (``k = 0`` is the surface layer, ``N-1`` the bottom/bulk layer; ``N = liquid_layers``);
* ``E_wet``, ``E_dry`` [J]: energies ``C_node T_node`` of the wetted and the dry wall node
  (``wall_nodes=1``: one node ``E_w``);
* five quadratures of what crossed the boundary (they do not feed back): hydrogen mass in and
  out, enthalpy in and out (helium included), heat in.

Nothing else is integrated. Each right-hand-side call recovers the thermodynamic state
*algebraically*: unknowns ``z = (T_v, rho_0, T_0, ..., rho_{N-1}, T_{N-1})`` solve

    m_v u(rho_v, T_v) + n_He c_v,He T_v = U_g,        rho_v = m_v / (V - sum_k m_k / rho_k)
    u(rho_k, T_k) = U_k / m_k                        (each layer)
    p(rho_k, T_k) = p(rho_v, T_v) + n_He R T_v / V_v (each layer: one pressure, the rigid tank)

by Newton's method (warm-started, analytic Jacobian from CoolProp's partial derivatives,
iterated to machine precision). All CoolProp calls in the recovery use ``(rho, T)`` inputs
with the phase *imposed*: the Helmholtz equation of state is then explicit (no flash), so
slightly subcooled vapour and superheated liquid are metastable single-phase states, and the
recovered state is a smooth function of ``y``. The moving-boundary work ``p dV`` that each
phase does on the others needs the volume rates ``dV_k/dt``; they follow from the implicit
function theorem on the same system (``dz/dt = -F_z^-1 F_y dy/dt``), which is linear in the
unknown volume rates and solved as an ``N x N`` system. Because the work terms enter the
phases with opposite signs, the total energy ``U_g + sum U_k + E_wet + E_dry`` changes only
by the boundary terms; mass and energy are therefore conserved to round-off by the right-hand
side, and BDF preserves these linear invariants (the tests check them against the quadratures).

Fluid: CoolProp ``HEOS::ParaHydrogen`` (Leachman et al. 2009). ``property_model=
"normal_hydrogen"`` computes everything with CoolProp ``Hydrogen`` (normal hydrogen, 3:1
ortho:para) while the written run still says ParaHydrogen: a realistic property mismatch
(saturation temperatures differ by about 0.1 K).

Interface and phase change
--------------------------
* The interface is at ``T_s = T_sat(p_H2)`` (hydrogen partial pressure). With
  ``Q_vi = h_vi A_i (T_v - T_s)`` and ``Q_li = h_li A_i (T_0 - T_s)`` (surface layer),
  ``J = (Q_vi + Q_li) / (h_v,sat - h_l,sat)`` evaporates (``J < 0`` condenses); the mass leaves
  the liquid at ``h_l,sat`` and enters the vapour at ``h_v,sat`` (the interface stores nothing).
* Bulk phase change (``bulk_phase_change=True``, default), physics tankode lacks: a liquid
  layer superheated above ``T_sat(p)`` flashes at ``J_f = m_k c_p,k r(T_k - T_sat(p)) /
  (tau_flash L(p))`` (vapour leaves the layer at ``h_v,sat(p)`` and joins the ullage); a
  subcooled ullage condenses as fog, ``J_fog = m_v c_p,v r(T_s - T_v) / (tau_fog L(p_H2))``
  (droplets at ``h_l,sat`` rain into the surface layer). ``r`` is a C1 ramp (0 below 0,
  quadratic up to 0.02 K, then linear); ``tau_flash = tau_fog = 30 s``.

Wall (``wall_nodes=2``, default)
--------------------------------
A wetted node and a dry node whose areas follow the level. The heat capacity is split by area
with 1 % of it kept on each node (flanges, supports; it keeps both nodes finite):
``C_wet = C_w (0.01 + 0.98 A_wl / A_w)``. When the level moves, capacity ``dC_wet/dt = 0.98
C_w (dA_wl/dh) (dh/dt) / A_w`` changes node *with its temperature* (the upwind node's,
smoothly blended through ``dh/dt = 0``), so the wall energy is exactly conserved; ``dh/dt``
is the exact level rate from the volume rates above. The nodes exchange heat by conduction
along the wall, ``G = k_w t_w L_c / l`` with ``L_c`` the contact-line length, ``t_w = 10 mm``,
``k_w = 15 W/(m K)`` (aluminium alloy 5083 near 20-30 K, order of magnitude, NIST cryogenic
material data) and ``l = H/2`` (distance between the node centroids of a half-full tank).
The ambient heat ``Q_aw`` (and a hidden wall heat leak) is split like the capacity. The
reported ``T_w`` is the capacity-averaged wall temperature. ``wall_nodes=1``: one lumped node.

Heat-transfer laws (``law=``)
-----------------------------
``|dT|`` is regularised as ``sqrt(dT^2 + (0.02 K)^2)`` and small floors are added to every
coefficient (0.5, 2, 0.2, 2 W/(m2 K) for wall-vapour, wall-liquid, vapour-interface,
liquid-interface), so the right-hand side stays smooth.

* ``"paper_printed"``: the Marques-Ahizi-Mendez correlations as printed. Each interface side
  ``x in {v, l}``: ``h_xi = Nu_x k_x / R``, ``Nu_x = 2 + 0.1 Ra_x^(1/3) + 3 (Re_s/4000)^0.8
  Pr_x^(1/3)`` with ``Ra_x = g beta_x |T_w - T_x| R^3 / (nu_x alpha_x)`` on the *wall-phase*
  temperature difference (both sides, vapour included, no stability switch),
  ``Re_s = 2 pi f_e A0 R / nu_x``, bulk-phase properties, ``R`` the tank radius; the wall
  coefficients are proportional: ``h_wv = 20 h_vi``, ``h_wl = 10 h_li``. (A warm ullage over
  a colder wall then cools within minutes: ``h_wv`` is several 100 W/(m2 K).)
* ``"mcadams"``: McAdams natural convection on all four surfaces (McAdams, *Heat Transmission*,
  1954, as tabulated in Incropera & DeWitt, *Fundamentals of Heat and Mass Transfer*, ch. 9),
  properties at the film temperature (CoolProp, phase imposed; the liquid film is soft-capped
  at ``T_sat(p) + 1 K``, the vapour film soft-floored at ``T_s - 0.5 K``). Vertical walls: ``Nu_L = 0.59 Ra^(1/4)``
  (laminar) and ``0.10 Ra^(1/3)`` (turbulent), blended as ``(a^6 + b^6)^(1/6)``; ``L`` is the
  wetted height (level) or the dry height (``H - level``), floored at 2 cm. Interface,
  ``L = A_i / P_i`` (area over perimeter): unstable side (liquid warmer than the interface, or
  vapour colder) ``0.54 Ra^(1/4)`` / ``0.15 Ra^(1/3)``, stable side ``0.27 Ra^(1/4)``,
  switched by ``0.5 (1 + tanh(dT / 0.05 K))``. Sloshing multiplies the interface
  coefficients by ``1 + 0.4 (Re_wave / 1e4)^0.6`` with ``Re_wave = 2 pi f_e A0 R / nu_x``.
* ``"slosh_energy"``: at rest as ``mcadams`` (without its sloshing factor); sloshing acts
  through an interface effective diffusivity (in the spirit of Das & Hopfinger 2009 and
  Ludwig, Dreyer & Hopfinger 2013): the first-mode wave height from linear potential theory
  ``b = A0 Gamma r^2 / sqrt((1 - r^2)^2 + (2 zeta r)^2)``, ``r = f_e / f_11``,
  ``f_11 = sqrt(g xi / R_s tanh(xi H_s / R_s)) / (2 pi)``, ``xi = 1.8412``,
  ``Gamma = 2 xi tanh(xi H_s/R_s) / (xi^2 - 1)`` (wall elevation of the (1,1) mode of an
  upright flat-bottomed cylinder, derived from the modal expansion of ``r cos(theta)``),
  ``zeta = 0.07``; ``R_s = sqrt(A_i / pi)`` and ``H_s = V_l / A_i`` (equivalent upright
  cylinder of other shapes), ``b`` saturated smoothly at ``0.2 R_s`` (wave breaking). Then
  ``alpha_eff - alpha = alpha C (b/R_s)^2 Re_b`` with ``Re_b = 2 pi f_e b R_s / nu`` and
  ``C = 0.01``, and ``h_slosh = rho c_p sqrt((alpha_eff - alpha) f_e)`` is added to each
  interface side; wall coefficients are multiplied by ``1 + 10 b / R_s``. For the 13.6 m3
  scenario at ``A0 = 1 cm``, ``f_e = 0.5 Hz``: ``b ~ 3 cm``, ``h_slosh,l ~ 350 W/(m2 K)``,
  ``h_slosh,v ~ 15 W/(m2 K)``.
* ``"constant"`` (for analytic tests): fixed ``h_constant = (h_wv, h_wl, h_vi, h_li)``.

Thermal stratification (``liquid_layers=N``, default 1 = well mixed)
--------------------------------------------------------------------
The top ``N-1`` layers share ``surface_layer_fraction`` (10 %) of the liquid mass, the bottom
layer holds the rest. The wall heats the liquid through a boundary layer that rises: the
wall-liquid heat (computed on the bottom/bulk layer's temperature) is deposited in the surface
layer when the wall is warmer (in the bottom layer when colder, smoothly switched). The
interface exchanges with the surface layer; fill, drain and leaks act on the bottom layer; a
hidden liquid heat leak is split by mass. Adjacent layers exchange mass ``rho A_i w`` both ways
(net zero), with ``w = alpha_l / delta + 0.02 (2 pi f_e A0) + 1e-3 m/s r(T_below - T_above)/1 K``
(diffusion, sloshing-driven mixing, overturning when the upper layer is colder). A re-gridding
flux relaxes the layer masses to their target fractions with a 20 s time constant, carrying the
upwind layer's enthalpy. Everything is conservative. The reported ``T_l`` is the mass-averaged
liquid temperature.

Operations (metered inputs) and hidden mechanisms
-------------------------------------------------
Vapour injection at ``h(p_v_in, T_v_in)``; venting of ullage gas at ullage conditions (the
metered flow is the mixture's mass; with helium present the vented gas has the ullage's
composition, so helium leaves in proportion to its mole fraction, ``vent_removes_helium=True``,
or only hydrogen leaves, ``False``); liquid fill at
``h(p, T_l_in)`` into the bottom layer; drain from the bottom layer; ``Q_aw`` on the wall;
sloshing ``(A0, f_e)``. Hidden mechanisms (:class:`Mechanisms`, 0 = absent; the CSV holds what
the operator *thinks* happened): ``heat_leak_liquid_W``, ``heat_leak_vapor_W``,
``heat_leak_wall_W``, ``vapor_leak_kg_s`` (ullage gas, like a vent), ``liquid_leak_kg_s``,
``inflow_meter_bias`` (true inflows = ``(1 + b)`` x metered), ``pressure_sensor_bias_Pa``,
``temperature_sensor_bias_K`` (on ``temperature_bias_channel``), ``noncondensable_mol``
(helium, ideal monatomic gas at ``T_v`` in the ullage; sensors read the total pressure; it does
not dissolve; the scenario's initial pressure is the *total* pressure, the hydrogen partial
pressure is lower), ``wall_heat_capacity_error`` (true ``C_w = (1 + e)`` x metadata), plus
stratification through ``liquid_layers``. Sensor biases also bias the metadata ``initial``
block (it holds what the sensors read at ``t0``).

Simplifications (deliberate)
----------------------------
One pressure in the tank (no hydrostatic head); no nucleate boiling on the wall; natural
convection correlations of vertical plates are used for curved walls (spheres, horizontal
cylinders) with the wetted/dry vertical extents as lengths; sloshing changes transfer
coefficients only (no mechanical energy, no level disturbance, no interface-area change);
helium is ideal and does not dissolve; wall conduction is one lumped conductance.

Integration
-----------
``scipy.integrate.solve_ivp(method="BDF")`` (stiff: light walls), restarted at every change of
the inputs, with a finite-difference Jacobian over the dynamic states only, ``rtol = 1e-7``,
``max_step = 120 s`` and at most ``max_rhs`` right-hand-side calls; a failure raises
:class:`SimulationError` naming the time and the state. The model is valid for hydrogen partial
pressures between 1.2 x the triple-point pressure (8.4 kPa) and 0.98 x the critical pressure
(12.6 bar): the interface needs a saturation state. With the default ``rtol = 1e-7`` the
trajectories agree with ``rtol = 1e-10`` to about 0.5 Pa and 1e-4 K (measured), far below the
sensor noise.

Output
------
:func:`simulate_run` writes ``NAME.json`` + ``NAME.csv`` (metadata ``initial`` = noise-free,
biased sensor readings at ``t0``; ``noise_std`` of each channel; asynchronous noisy samples:
pressure every 5 s, ``T_v`` every 10 s at 2 s, ``T_l`` every 15 s at 4 s, ``T_w`` every 20 s at
6 s, level every 10 s at 7 s; metered inputs on their change rows only) and the truth in a
sidecar ``NAME.truth.json`` (law, mechanisms, options, true wall capacity), which tankode does
not read. Command line: ``python tests/nodal_sim.py --list`` or
``python tests/nodal_sim.py SCENARIO --law mcadams --out DIR [--mechanism NAME=VALUE ...]``.
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
from dataclasses import asdict, dataclass, field, fields
from typing import Any, Mapping, Sequence

import CoolProp as CP
import numpy as np
from scipy.integrate import solve_ivp

__all__ = [
    "INPUT_COLUMNS",
    "LAWS",
    "MECHANISM_NAMES",
    "NOISE_LEVELS",
    "OBS_COLUMNS",
    "SCENARIOS",
    "Mechanisms",
    "NodalTank",
    "Options",
    "SimulationError",
    "Trajectory",
    "make_shape",
    "random_scenario",
    "resolve_scenario",
    "simulate",
    "simulate_run",
]

RUN_FLUID = "ParaHydrogen"  # what the written run says, whatever the property model
R_GAS = 8.314462618  # J/(mol K)
CV_HE = 1.5 * R_GAS  # J/(mol K): helium, ideal monatomic gas
M_HE = 4.002602e-3  # kg/mol
G = 9.80665  # m/s2

LAWS: tuple[str, ...] = ("paper_printed", "mcadams", "slosh_energy", "constant")
PROPERTY_MODELS: dict[str, str] = {"reference": "ParaHydrogen", "normal_hydrogen": "Hydrogen"}

INPUT_COLUMNS: tuple[str, ...] = (
    "mdot_v_in_kg_s", "T_v_in_K", "p_v_in_Pa", "mdot_v_out_kg_s", "mdot_l_in_kg_s", "T_l_in_K",
    "mdot_l_out_kg_s", "slosh_amplitude_m", "slosh_frequency_Hz", "Q_aw_W",
)
OBS_COLUMNS: tuple[str, ...] = ("p_v_Pa", "T_v_K", "T_l_K", "T_w_K", "H_l_m")
NOISE_KEYS: tuple[str, ...] = ("p_v", "T_v", "T_l", "T_w", "H_l")
NOISE_LEVELS: dict[str, dict[str, float]] = {
    "low": {"p_v": 300.0, "T_v": 0.05, "T_l": 0.05, "T_w": 0.05, "H_l": 0.001},
    "high": {"p_v": 2000.0, "T_v": 0.2, "T_l": 0.2, "T_w": 0.2, "H_l": 0.005},
}
# Sampling of each channel: (period [s], phase offset [s]); asynchronous on purpose.
SAMPLING: dict[str, tuple[float, float]] = {
    "p_v_Pa": (5.0, 0.0), "T_v_K": (10.0, 2.0), "T_l_K": (15.0, 4.0), "T_w_K": (20.0, 6.0), "H_l_m": (10.0, 7.0),
}

# Regularisation and floors of the heat-transfer laws.
_DT_EPS = 0.02  # K, |dT| -> sqrt(dT^2 + eps^2)
_H_FLOOR = {"wv": 0.5, "wl": 2.0, "vi": 0.2, "li": 2.0}  # W/(m2 K)
_RAMP_EPS = 0.02  # K, width of the quadratic start of the flash/fog ramp
_WALL_EPS = 0.01  # share of the wall capacity that stays with each node
_XI11 = 1.8412  # first root of J1'
_NEWTON_RTOL = 1e-9

# paper_printed constants
_PAPER_NU0, _PAPER_CNAT, _PAPER_CS = 2.0, 0.1, 3.0
_PAPER_WALL_V, _PAPER_WALL_L = 20.0, 10.0
# mcadams sloshing factor
_MCA_SLOSH_C, _MCA_SLOSH_EXP, _MCA_RE_REF = 0.4, 0.6, 1e4
# slosh_energy constants
_SE_ZETA, _SE_C, _SE_WALL, _SE_BCAP = 0.07, 0.01, 10.0, 0.2
# liquid-layer exchange
_MIX_SLOSH, _MIX_OVERTURN, _TAU_GRID = 0.02, 1e-3, 20.0


class SimulationError(RuntimeError):
    """The integration failed or left the range where the model is valid."""


# =============================================================================== smooth helpers
def _soft_abs(x: float) -> float:
    return math.sqrt(x * x + _DT_EPS * _DT_EPS)


def _ramp(x: float, eps: float = _RAMP_EPS) -> float:
    """C1 ramp: 0 for x <= 0, x^2/(2 eps) up to eps, x - eps/2 beyond."""
    if x <= 0.0:
        return 0.0
    if x < eps:
        return 0.5 * x * x / eps
    return x - 0.5 * eps


def _softplus(x: float) -> float:
    return x + math.log1p(math.exp(-x)) if x > 0 else math.log1p(math.exp(x))


def _soft_min(x: float, cap: float, width: float) -> float:
    """Smooth min(x, cap)."""
    return cap - width * _softplus((cap - x) / width)


def _soft_max(x: float, floor: float, width: float) -> float:
    """Smooth max(x, floor)."""
    return floor + width * _softplus((x - floor) / width)


def _blend6(a: float, b: float) -> float:
    """Smooth max of two positive Nusselt numbers."""
    return (a**6 + b**6) ** (1.0 / 6.0)


def _step(x: float, width: float) -> float:
    """Smooth Heaviside 0.5 (1 + tanh(x / width))."""
    return 0.5 * (1.0 + math.tanh(x / width))


# =============================================================================== geometry
class Shape:
    """Level/volume/area relations of one tank shape.

    Levels ``h`` [m] are measured from the lowest inner point. ``interface_area(h) = dV/dh``,
    ``wetted_perimeter(h) = dA_wl/dh`` [m], ``contact_line(h)``: perimeter of the free surface [m].
    """

    kind: str = ""
    radius: float
    height: float
    volume: float
    wall_area: float

    def liquid_volume(self, h: float) -> float:  # pragma: no cover - interface
        raise NotImplementedError

    def interface_area(self, h: float) -> float:  # pragma: no cover
        raise NotImplementedError

    def wetted_area(self, h: float) -> float:  # pragma: no cover
        raise NotImplementedError

    def wetted_perimeter(self, h: float) -> float:  # pragma: no cover
        raise NotImplementedError

    def contact_line(self, h: float) -> float:  # pragma: no cover
        raise NotImplementedError

    def level(self, v_l: float, guess: float | None = None) -> float:
        """Level [m] holding the liquid volume ``v_l`` [m3]: safeguarded Newton on ``V(h)``."""
        H = self.height
        v = min(max(v_l, 0.0), self.volume)
        lo, hi = 0.0, H
        h = guess if guess is not None and 0.0 < guess < H else H * v / self.volume
        for _ in range(100):
            f = self.liquid_volume(h) - v
            if f > 0.0:
                hi = h
            else:
                lo = h
            a = self.interface_area(h)
            h_new = h - f / a if a > 0.0 else 0.5 * (lo + hi)
            if not (lo <= h_new <= hi):
                h_new = 0.5 * (lo + hi)
            if abs(h_new - h) <= 1e-14 * H:
                return h_new
            h = h_new
        return h


class VerticalCylinder(Shape):
    """Upright cylinder with flat ends (the bottom is always wet, the lid always dry)."""

    kind = "vertical_cylinder"

    def __init__(self, radius_m: float, height_m: float):
        self.radius, self.height = float(radius_m), float(height_m)
        self.base = math.pi * self.radius**2
        self.volume = self.base * self.height
        self.wall_area = 2.0 * self.base + 2.0 * math.pi * self.radius * self.height

    def liquid_volume(self, h: float) -> float:
        return self.base * h

    def interface_area(self, h: float) -> float:
        return self.base

    def wetted_area(self, h: float) -> float:
        return self.base + 2.0 * math.pi * self.radius * h

    def wetted_perimeter(self, h: float) -> float:
        return 2.0 * math.pi * self.radius

    def contact_line(self, h: float) -> float:
        return 2.0 * math.pi * self.radius

    def level(self, v_l: float, guess: float | None = None) -> float:
        return min(max(v_l, 0.0), self.volume) / self.base


class Sphere(Shape):
    kind = "sphere"

    def __init__(self, radius_m: float):
        self.radius = float(radius_m)
        self.height = 2.0 * self.radius
        self.volume = 4.0 / 3.0 * math.pi * self.radius**3
        self.wall_area = 4.0 * math.pi * self.radius**2

    def liquid_volume(self, h: float) -> float:
        return math.pi * h * h * (3.0 * self.radius - h) / 3.0

    def interface_area(self, h: float) -> float:
        return math.pi * h * (2.0 * self.radius - h)

    def wetted_area(self, h: float) -> float:
        return 2.0 * math.pi * self.radius * h

    def wetted_perimeter(self, h: float) -> float:
        return 2.0 * math.pi * self.radius

    def contact_line(self, h: float) -> float:
        return 2.0 * math.pi * math.sqrt(max(h * (2.0 * self.radius - h), 0.0))


class HorizontalCylinder(Shape):
    """Horizontal axis, flat circular ends: the liquid section is a circular segment."""

    kind = "horizontal_cylinder"

    def __init__(self, radius_m: float, cylinder_length_m: float):
        self.radius, self.length = float(radius_m), float(cylinder_length_m)
        self.height = 2.0 * self.radius
        self.volume = math.pi * self.radius**2 * self.length
        self.wall_area = 2.0 * math.pi * self.radius * self.length + 2.0 * math.pi * self.radius**2

    def _half_chord(self, h: float) -> float:
        return math.sqrt(max(h * (2.0 * self.radius - h), 0.0))

    def _segment(self, h: float) -> tuple[float, float]:
        """(segment area [m2], half-angle [rad]) of the liquid section at level h."""
        R = self.radius
        c = min(max((R - h) / R, -1.0), 1.0)
        theta = math.acos(c)
        return R * R * theta - (R - h) * self._half_chord(h), theta

    def liquid_volume(self, h: float) -> float:
        return self._segment(h)[0] * self.length

    def interface_area(self, h: float) -> float:
        return 2.0 * self._half_chord(h) * self.length

    def wetted_area(self, h: float) -> float:
        seg, theta = self._segment(h)
        return 2.0 * self.radius * theta * self.length + 2.0 * seg

    def wetted_perimeter(self, h: float) -> float:
        w = self._half_chord(h)
        return (2.0 * self.radius * self.length / w if w > 0 else math.inf) + 4.0 * w

    def contact_line(self, h: float) -> float:
        w = self._half_chord(h)
        return (2.0 * self.length + 4.0 * w) if w > 0 else 0.0


class EllipticalHeads(Shape):
    """Upright cylinder (straight part ``L``) closed by two semi-ellipsoidal heads of depth
    ``d = R / head_aspect``. Head areas use the closed-form antiderivative of
    ``dA/dz = (2 pi R / d) sqrt(d^2 + (a^2 - 1) (z - d)^2)``."""

    kind = "vertical_cylinder_elliptical_heads"

    def __init__(self, radius_m: float, cylinder_length_m: float, head_aspect: float):
        self.radius, self.length = float(radius_m), float(cylinder_length_m)
        self.aspect = float(head_aspect)
        self.d = self.radius / self.aspect
        self.height = self.length + 2.0 * self.d
        self._c = self.aspect**2 - 1.0
        R, d = self.radius, self.d
        self._v_head = 2.0 / 3.0 * math.pi * R * R * d
        self._a_head = self._head_area(d)
        self.volume = 2.0 * self._v_head + math.pi * R * R * self.length
        self.wall_area = 2.0 * self._a_head + 2.0 * math.pi * R * self.length

    def _phi(self, s: float) -> float:
        """Antiderivative of sqrt(d^2 + c s^2) in s."""
        d, c = self.d, self._c
        q = math.sqrt(max(d * d + c * s * s, 0.0))
        if abs(c) < 1e-12:
            return d * s
        if c > 0:
            rc = math.sqrt(c)
            return 0.5 * s * q + d * d / (2.0 * rc) * math.asinh(rc * s / d)
        rc = math.sqrt(-c)
        return 0.5 * s * q + d * d / (2.0 * rc) * math.asin(min(max(rc * s / d, -1.0), 1.0))

    def _head_area(self, z: float) -> float:
        """Wall area of the bottom head below height z in [0, d]."""
        return 2.0 * math.pi * self.radius / self.d * (self._phi(z - self.d) - self._phi(-self.d))

    def _head_volume(self, z: float) -> float:
        return math.pi * self.radius**2 / self.d**2 * (self.d * z * z - z**3 / 3.0)

    def _r2(self, z: float) -> float:
        """Squared radius of the section of the bottom head at height z in [0, d]."""
        return self.radius**2 * z * (2.0 * self.d - z) / self.d**2

    def _head_perimeter(self, z: float) -> float:
        return 2.0 * math.pi * self.radius / self.d * math.sqrt(self.d**2 + self._c * (z - self.d) ** 2)

    def _clamp(self, h: float) -> float:
        return min(max(h, 0.0), self.height)

    def liquid_volume(self, h: float) -> float:
        h = self._clamp(h)
        d, L = self.d, self.length
        if h <= d:
            return self._head_volume(h)
        if h <= d + L:
            return self._v_head + math.pi * self.radius**2 * (h - d)
        return self.volume - self._head_volume(self.height - h)

    def interface_area(self, h: float) -> float:
        h = self._clamp(h)
        d, L = self.d, self.length
        if h <= d:
            return math.pi * self._r2(h)
        if h <= d + L:
            return math.pi * self.radius**2
        return math.pi * self._r2(self.height - h)

    def wetted_area(self, h: float) -> float:
        h = self._clamp(h)
        d, L = self.d, self.length
        if h <= d:
            return self._head_area(h)
        if h <= d + L:
            return self._a_head + 2.0 * math.pi * self.radius * (h - d)
        return self.wall_area - self._head_area(self.height - h)

    def wetted_perimeter(self, h: float) -> float:
        h = self._clamp(h)
        d, L = self.d, self.length
        if h <= d:
            return self._head_perimeter(h)
        if h <= d + L:
            return 2.0 * math.pi * self.radius
        return self._head_perimeter(self.height - h)

    def contact_line(self, h: float) -> float:
        return 2.0 * math.sqrt(math.pi * self.interface_area(h))


def make_shape(tank: Mapping[str, Any]) -> Shape:
    """Shape from a tank description in the interchange format (``shape`` and dimensions)."""
    kind = tank["shape"]
    if kind == "vertical_cylinder":
        return VerticalCylinder(tank["radius_m"], tank["height_m"])
    if kind == "sphere":
        return Sphere(tank["radius_m"])
    if kind == "horizontal_cylinder":
        return HorizontalCylinder(tank["radius_m"], tank["cylinder_length_m"])
    if kind == "vertical_cylinder_elliptical_heads":
        return EllipticalHeads(tank["radius_m"], tank["cylinder_length_m"], tank["head_aspect"])
    raise ValueError(f"unknown tank shape {kind!r}")


# =============================================================================== options
MECHANISM_NAMES: tuple[str, ...] = (
    "heat_leak_liquid_W", "heat_leak_vapor_W", "heat_leak_wall_W", "vapor_leak_kg_s", "liquid_leak_kg_s",
    "inflow_meter_bias", "pressure_sensor_bias_Pa", "temperature_sensor_bias_K", "noncondensable_mol",
    "wall_heat_capacity_error",
)


@dataclass(frozen=True)
class Mechanisms:
    """Hidden mechanisms (0 = absent). Units are in the names.

    ``temperature_sensor_bias_K`` acts on the channel ``temperature_bias_channel``
    (``"T_v"``, ``"T_l"`` or ``"T_w"``).
    """

    heat_leak_liquid_W: float = 0.0
    heat_leak_vapor_W: float = 0.0
    heat_leak_wall_W: float = 0.0
    vapor_leak_kg_s: float = 0.0
    liquid_leak_kg_s: float = 0.0
    inflow_meter_bias: float = 0.0
    pressure_sensor_bias_Pa: float = 0.0
    temperature_sensor_bias_K: float = 0.0
    noncondensable_mol: float = 0.0
    wall_heat_capacity_error: float = 0.0
    temperature_bias_channel: str = "T_l"

    def __post_init__(self) -> None:
        if self.temperature_bias_channel not in ("T_v", "T_l", "T_w"):
            raise ValueError(f"temperature_bias_channel must be T_v, T_l or T_w, got {self.temperature_bias_channel!r}")
        for name in ("vapor_leak_kg_s", "liquid_leak_kg_s", "noncondensable_mol"):
            if getattr(self, name) < 0:
                raise ValueError(f"mechanism {name} must be >= 0")
        if self.wall_heat_capacity_error <= -1.0 or self.inflow_meter_bias <= -1.0:
            raise ValueError("wall_heat_capacity_error and inflow_meter_bias must be > -1")

    @classmethod
    def from_mapping(cls, m: Mapping[str, Any] | None) -> "Mechanisms":
        if m is None:
            return cls()
        if isinstance(m, Mechanisms):
            return m
        known = {f.name for f in fields(cls)}
        unknown = set(m) - known
        if unknown:
            raise ValueError(f"unknown mechanisms {sorted(unknown)}; known: {', '.join(sorted(known))}")
        return cls(**{k: (v if k == "temperature_bias_channel" else float(v)) for k, v in m.items()})

    def active(self) -> dict[str, Any]:
        """The mechanisms that are present (non-zero)."""
        out: dict[str, Any] = {k: getattr(self, k) for k in MECHANISM_NAMES if getattr(self, k) != 0.0}
        if self.temperature_sensor_bias_K != 0.0:
            out["temperature_bias_channel"] = self.temperature_bias_channel
        return out


@dataclass(frozen=True)
class Options:
    """Model and numerics options (see the module docstring for the physics)."""

    law: str = "mcadams"
    wall_nodes: int = 2
    liquid_layers: int = 1
    property_model: str = "reference"
    bulk_phase_change: bool = True
    tau_flash_s: float = 30.0
    tau_fog_s: float = 30.0
    wall_thickness_m: float = 0.010
    wall_conductivity_W_mK: float = 15.0
    surface_layer_fraction: float = 0.1
    vent_removes_helium: bool = True
    h_constant: tuple[float, float, float, float] = (20.0, 100.0, 5.0, 100.0)  # law="constant": wv, wl, vi, li
    rtol: float = 1e-7
    max_step_s: float = 120.0
    max_rhs: int = 400_000

    def __post_init__(self) -> None:
        if self.law not in LAWS:
            raise ValueError(f"unknown law {self.law!r}; known: {', '.join(LAWS)}")
        if self.wall_nodes not in (1, 2):
            raise ValueError("wall_nodes must be 1 or 2")
        if not 1 <= self.liquid_layers <= 8:
            raise ValueError("liquid_layers must be 1..8")
        if self.property_model not in PROPERTY_MODELS:
            raise ValueError(f"unknown property_model {self.property_model!r}; known: {', '.join(PROPERTY_MODELS)}")
        object.__setattr__(self, "h_constant", tuple(float(v) for v in self.h_constant))


# =============================================================================== fluid
class _Fluid:
    """CoolProp states, one per role so that each keeps its imposed phase."""

    def __init__(self, name: str):
        self.name = name

        def state(phase: int | None) -> Any:
            st = CP.AbstractState("HEOS", name)
            if phase is not None:
                st.specify_phase(phase)
            return st

        self.gas, self.liq = state(CP.iphase_gas), state(CP.iphase_liquid)
        self.gas_film, self.liq_film = state(CP.iphase_gas), state(CP.iphase_liquid)
        self.sat = state(None)
        self.free = state(None)
        self._sat_cache: tuple[float, tuple[float, float, float]] = (-1.0, (0.0, 0.0, 0.0))
        self.p_triple = self.sat.trivial_keyed_output(CP.iP_triple)
        self.p_crit = self.sat.p_critical()

    @staticmethod
    def eos(st: Any, rho: float, T: float) -> tuple[float, float, float, float, float, float]:
        """(p, u, c_v, dp/drho|T, dp/dT|rho, du/drho|T) at (rho, T): explicit Helmholtz evaluation."""
        st.update(CP.DmassT_INPUTS, rho, T)
        return (st.p(), st.umass(), st.cvmass(), st.first_partial_deriv(CP.iP, CP.iDmass, CP.iT),
                st.first_partial_deriv(CP.iP, CP.iT, CP.iDmass), st.first_partial_deriv(CP.iUmass, CP.iDmass, CP.iT))

    def saturation(self, p: float) -> tuple[float, float, float]:
        """(T_sat, h_l,sat, h_v,sat) at pressure p [Pa]."""
        if p == self._sat_cache[0]:
            return self._sat_cache[1]
        self.sat.update(CP.PQ_INPUTS, p, 0.0)
        out = (self.sat.T(), self.sat.saturated_liquid_keyed_output(CP.iHmass),
               self.sat.saturated_vapor_keyed_output(CP.iHmass))
        self._sat_cache = (p, out)
        return out

    def p_sat(self, T: float) -> float:
        self.sat.update(CP.QT_INPUTS, 0.0, T)
        return self.sat.p()

    def density(self, p: float, T: float, liquid: bool) -> float:
        st = self.liq_film if liquid else self.gas_film
        st.update(CP.PT_INPUTS, p, T)
        return st.rhomass()

    def h_free(self, p: float, T: float) -> float:
        """Enthalpy at (p, T) without an imposed phase (injected gas)."""
        self.free.update(CP.PT_INPUTS, p, T)
        return self.free.hmass()

    def h_liquid(self, p: float, T: float) -> float:
        self.liq_film.update(CP.PT_INPUTS, p, T)
        return self.liq_film.hmass()

    @staticmethod
    def _transport(st: Any) -> tuple[float, float, float, float, float, float]:
        """(k, nu, alpha, |beta|, rho, c_p) of the state ``st`` holds."""
        rho, cp, k = st.rhomass(), st.cpmass(), st.conductivity()
        return k, st.viscosity() / rho, k / (rho * cp), abs(st.isobaric_expansion_coefficient()), rho, cp

    def film(self, p: float, T: float, liquid: bool) -> tuple[float, float, float, float, float, float]:
        st = self.liq_film if liquid else self.gas_film
        st.update(CP.PT_INPUTS, p, T)
        return self._transport(st)

    def bulk(self, rho: float, T: float, liquid: bool) -> tuple[float, float, float, float, float, float]:
        st = self.liq_film if liquid else self.gas_film
        st.update(CP.DmassT_INPUTS, rho, T)
        return self._transport(st)


# =============================================================================== the model
@dataclass
class _Alg:
    """Algebraic state recovered from y (one right-hand-side call)."""

    T_v: float
    rho_v: float
    V_v: float
    p_h2: float
    p_he: float
    p: float
    u_v: float
    cp_v: float
    rho: np.ndarray  # liquid layers
    T: np.ndarray
    u: np.ndarray
    cp: np.ndarray
    V: np.ndarray
    K: np.ndarray | None  # F_z^-1 F_s


class NodalTank:
    """Right-hand side, algebraic recovery and observation of one tank."""

    def __init__(self, tank: Mapping[str, Any], options: Options = Options(), mechanisms: Mechanisms = Mechanisms()):
        self.tank = dict(tank)
        self.opt = options
        self.mech = mechanisms
        self.shape = make_shape(tank)
        self.fluid = _Fluid(PROPERTY_MODELS[options.property_model])
        self.C_meta = float(tank["wall_heat_capacity_J_per_K"])
        self.C_w = (1.0 + mechanisms.wall_heat_capacity_error) * self.C_meta
        N = self.N = options.liquid_layers
        self.nw = options.wall_nodes
        if N == 1:
            self.frac = np.array([1.0])
        else:
            fs = options.surface_layer_fraction
            self.frac = np.array([fs / (N - 1)] * (N - 1) + [1.0 - fs])
        self.cumfrac = np.cumsum(self.frac)
        # layout of y
        self.i_mv, self.i_Ug, self.i_n = 0, 1, 2
        self.i_m = slice(3, 3 + N)
        self.i_U = slice(3 + N, 3 + 2 * N)
        self.i_E = slice(3 + 2 * N, 3 + 2 * N + self.nw)
        q0 = 3 + 2 * N + self.nw
        self.i_Min, self.i_Mout, self.i_Hin, self.i_Hout, self.i_Q = range(q0, q0 + 5)
        self.n_state = q0 + 5
        self.n_dyn = q0
        self.ns = 3 + 2 * N  # algebra-relevant states
        self.G_cond = options.wall_conductivity_W_mK * options.wall_thickness_m / (0.5 * self.shape.height)
        self._z: np.ndarray | None = None
        self._h_guess: float | None = None
        self.n_rhs = 0
        self.t_now = 0.0
        self.y_now = np.zeros(self.n_state)
        self.set_inputs({})

    # ------------------------------------------------------------------ inputs
    def set_inputs(self, metered: Mapping[str, float]) -> None:
        """Set the metered inputs of one segment; the true flows include the mechanisms."""
        g = {c: float(metered.get(c, 0.0)) for c in INPUT_COLUMNS}
        self.metered = g
        mech = self.mech
        self.mv_in = (1.0 + mech.inflow_meter_bias) * g["mdot_v_in_kg_s"]
        self.ml_in = (1.0 + mech.inflow_meter_bias) * g["mdot_l_in_kg_s"]
        self.mg_out = g["mdot_v_out_kg_s"] + mech.vapor_leak_kg_s  # ullage gas (mixture) out
        self.ml_out = g["mdot_l_out_kg_s"] + mech.liquid_leak_kg_s
        self.h_v_in = self.fluid.h_free(g["p_v_in_Pa"], g["T_v_in_K"]) if self.mv_in > 0 else 0.0
        self.T_l_in = g["T_l_in_K"]
        if self.ml_in > 0 and not self.T_l_in > 0:
            raise SimulationError("liquid fill without T_l_in_K")
        self.Q_wall = g["Q_aw_W"] + mech.heat_leak_wall_W
        self.A0, self.f_e = g["slosh_amplitude_m"], g["slosh_frequency_Hz"]

    # ------------------------------------------------------------------ initial state
    def initial_state(self, p: float, T_v: float, T_l: float, T_w: float, fill: float,
                      T_w_dry: float | None = None) -> np.ndarray:
        """State vector at t0 from the true total pressure [Pa], temperatures [K] and liquid volume
        fraction; ``T_w_dry`` (default ``T_w``) starts the dry wall node at another temperature."""
        if not 0.0 < fill < 1.0:
            raise ValueError(f"fill ratio {fill} must be in (0, 1)")
        V = self.shape.volume
        V_l, V_v = fill * V, (1.0 - fill) * V
        n = self.mech.noncondensable_mol
        p_he = n * R_GAS * T_v / V_v
        p_h2 = p - p_he
        if p_h2 < 0.5 * p:
            raise ValueError(f"{n} mol of helium make {p_he:.0f} Pa, more than half the pressure {p:.0f} Pa")
        fl = self.fluid
        rho_v = fl.density(p_h2, T_v, liquid=False)
        rho_l = fl.density(p, T_l, liquid=True)
        m_v = rho_v * V_v
        _, u_v, *_ = fl.eos(fl.gas, rho_v, T_v)
        _, u_l, *_ = fl.eos(fl.liq, rho_l, T_l)
        y = np.zeros(self.n_state)
        y[self.i_mv] = m_v
        y[self.i_Ug] = m_v * u_v + n * CV_HE * T_v
        y[self.i_n] = n
        m_l = rho_l * V_l
        y[self.i_m] = m_l * self.frac
        y[self.i_U] = m_l * self.frac * u_l
        if self.nw == 2:
            phi = self._wet_share(self.shape.wetted_area(self.shape.level(V_l)))
            y[self.i_E] = (self.C_w * phi * T_w, self.C_w * (1.0 - phi) * (T_w if T_w_dry is None else T_w_dry))
        else:
            y[self.i_E] = self.C_w * T_w
        z = np.empty(1 + 2 * self.N)
        z[0], z[1::2], z[2::2] = T_v, rho_l, T_l
        self._z = z
        self._h_guess = None
        return y

    def _wet_share(self, A_wl: float) -> float:
        return _WALL_EPS + (1.0 - 2.0 * _WALL_EPS) * A_wl / self.shape.wall_area

    # ------------------------------------------------------------------ algebraic recovery
    def _recover(self, y: np.ndarray, need_K: bool = True) -> _Alg:
        """Solve for (T_v, rho_k, T_k) from the conserved variables (Newton, machine precision)."""
        N, V, fl = self.N, self.shape.volume, self.fluid
        m_v, U_g, n = float(y[self.i_mv]), float(y[self.i_Ug]), float(y[self.i_n])
        m = np.asarray(y[self.i_m], dtype=float)
        U = np.asarray(y[self.i_U], dtype=float)
        if not (m_v > 0 and np.all(m > 0) and n >= 0):
            raise SimulationError(f"masses left the physical range: m_v={m_v:.6g} kg, m_l={m.tolist()} kg, "
                                  f"n_He={n:.6g} mol")
        assert self._z is not None
        z = self._z.copy()
        nz = 1 + 2 * N
        F = np.empty(nz)
        Fz = np.zeros((nz, nz))
        lay = np.empty((N, 6))
        converged = False
        for it in range(60):
            T_v = z[0]
            rho, T = z[1::2], z[2::2]
            if not (T_v > 1.0 and np.all(rho > 0) and np.all(T > 1.0)):
                raise SimulationError(f"state recovery diverged: T_v={T_v:.6g}, rho_l={rho.tolist()}, T_l={T.tolist()}")
            V_l = float(np.sum(m / rho))
            V_v = V - V_l
            if V_v <= 1e-9 * V:
                raise SimulationError(f"the liquid fills the tank (V_l={V_l:.6g} of {V:.6g} m3)")
            rho_v = m_v / V_v
            p_v, u_v, cv_v, pr_v, pT_v, ur_v = fl.eos(fl.gas, rho_v, T_v)
            for k in range(N):
                lay[k] = fl.eos(fl.liq, rho[k], T[k])
            p_he = n * R_GAS * T_v / V_v
            S0 = m_v * cv_v + n * CV_HE
            F[0] = (m_v * u_v + n * CV_HE * T_v - U_g) / S0
            F[1::2] = (lay[:, 1] - U / m) / lay[:, 2]
            F[2::2] = (lay[:, 0] - p_v - p_he) / lay[:, 3]
            # Jacobian (rows scaled like F)
            dVv = m / rho**2  # dV_v/drho_j
            g = -(rho_v / V_v) * dVv  # drho_v/drho_j
            Fz[:] = 0.0
            Fz[0, 0] = 1.0
            Fz[0, 1::2] = m_v * ur_v * g / S0
            for k in range(N):
                pr_k = lay[k, 3]
                Fz[1 + 2 * k, 1 + 2 * k] = lay[k, 5] / lay[k, 2]
                Fz[1 + 2 * k, 2 + 2 * k] = 1.0
                Fz[2 + 2 * k, 0] = (-pT_v - n * R_GAS / V_v) / pr_k
                Fz[2 + 2 * k, 1::2] = (-pr_v * g + p_he / V_v * dVv) / pr_k
                Fz[2 + 2 * k, 1 + 2 * k] += 1.0
                Fz[2 + 2 * k, 2 + 2 * k] = lay[k, 4] / pr_k
            if converged:
                break
            try:
                dz = np.linalg.solve(Fz, F)
            except np.linalg.LinAlgError as e:
                raise SimulationError(f"singular state recovery: {e}") from None
            # damping: at most 20 % of a density or temperature per step
            rel = np.abs(dz) / np.abs(z)
            worst = float(np.max(rel))
            if worst > 0.2:
                dz *= 0.2 / worst
            z -= dz
            converged = worst < _NEWTON_RTOL
        else:
            raise SimulationError(f"state recovery did not converge (last relative step {worst:.3g})")
        self._z = z
        rho, T = z[1::2].copy(), z[2::2].copy()
        T_v = float(z[0])
        cp_v = cv_v + T_v * pT_v**2 / (rho_v**2 * pr_v)
        cp = lay[:, 2] + T * lay[:, 4] ** 2 / (rho**2 * lay[:, 3])
        K = None
        if need_K:
            ns = self.ns
            Fs = np.zeros((nz, ns))
            # columns: m_v, U_g, n, m_0..m_{N-1}, U_0..U_{N-1}
            Fs[0, 0] = (u_v + m_v * ur_v / V_v) / S0
            Fs[0, 1] = -1.0 / S0
            Fs[0, 2] = CV_HE * T_v / S0
            Fs[0, 3:3 + N] = m_v * ur_v * rho_v / (V_v * rho) / S0
            for k in range(N):
                cv_k, pr_k = lay[k, 2], lay[k, 3]
                Fs[1 + 2 * k, 3 + k] = U[k] / m[k] ** 2 / cv_k
                Fs[1 + 2 * k, 3 + N + k] = -1.0 / (m[k] * cv_k)
                Fs[2 + 2 * k, 0] = -pr_v / V_v / pr_k
                Fs[2 + 2 * k, 2] = -R_GAS * T_v / V_v / pr_k
                Fs[2 + 2 * k, 3:3 + N] = (-pr_v * rho_v / (V_v * rho) - p_he / (V_v * rho)) / pr_k
            K = np.linalg.solve(Fz, Fs)
        return _Alg(T_v=T_v, rho_v=rho_v, V_v=V_v, p_h2=p_v, p_he=p_he, p=p_v + p_he, u_v=u_v, cp_v=cp_v,
                    rho=rho, T=T, u=lay[:, 1].copy(), cp=cp, V=m / rho, K=K)

    # ------------------------------------------------------------------ heat-transfer laws
    def _coefficients(self, a: _Alg, T_ww: float, T_wd: float, T_s: float, T_sp: float, level: float,
                      A_i: float, L_c: float, V_l: float) -> tuple[float, float, float, float]:
        """(h_wv, h_wl, h_vi, h_li) [W/(m2 K)] by the selected law."""
        law = self.opt.law
        T_top, T_bot = float(a.T[0]), float(a.T[-1])
        if law == "constant":
            return self.opt.h_constant
        fl, A0, f_e = self.fluid, self.A0, self.f_e
        R = self.shape.radius
        if law == "paper_printed":
            kv, nuv, alv, bev, _, _ = fl.bulk(a.rho_v, a.T_v, liquid=False)
            kl, nul, all_, bel, _, _ = fl.bulk(float(a.rho[-1]), T_bot, liquid=True)
            out = []
            for k, nu, al, be, dT in ((kv, nuv, alv, bev, T_wd - a.T_v), (kl, nul, all_, bel, T_ww - T_bot)):
                Ra = G * be * _soft_abs(dT) * R**3 / (nu * al)
                Re_s = 2.0 * math.pi * f_e * A0 * R / nu
                Nu = (_PAPER_NU0 + _PAPER_CNAT * Ra ** (1.0 / 3.0)
                      + _PAPER_CS * (Re_s / 4000.0) ** 0.8 * (nu / al) ** (1.0 / 3.0))
                out.append(Nu * k / R)
            h_vi, h_li = out
            return (_PAPER_WALL_V * h_vi + _H_FLOOR["wv"], _PAPER_WALL_L * h_li + _H_FLOOR["wl"],
                    h_vi + _H_FLOOR["vi"], h_li + _H_FLOOR["li"])
        # McAdams natural convection (mcadams and slosh_energy at rest)
        H = self.shape.height
        L_wet = _soft_max(level, 0.02, 0.005)
        L_dry = _soft_max(H - level, 0.02, 0.005)
        T_fv = _soft_max(0.5 * (T_wd + a.T_v), T_s - 0.5, 0.1)
        kv, nuv, alv, bev, rhov_f, cpv_f = fl.film(a.p_h2, T_fv, liquid=False)
        dT = T_wd - a.T_v
        Ra = G * bev * _soft_abs(dT) * L_dry**3 / (nuv * alv)
        h_wv = _blend6(0.59 * Ra**0.25, 0.10 * Ra ** (1.0 / 3.0)) * kv / L_dry
        T_fl = _soft_min(0.5 * (T_ww + T_bot), T_sp + 1.0, 0.1)
        kl, nul, all_, bel, _, _ = fl.film(a.p, T_fl, liquid=True)
        Ra = G * bel * _soft_abs(T_ww - T_bot) * L_wet**3 / (nul * all_)
        h_wl = _blend6(0.59 * Ra**0.25, 0.10 * Ra ** (1.0 / 3.0)) * kl / L_wet
        L_i = max(A_i / max(L_c, 1e-9), 0.01)
        # interface, vapour side: unstable when the vapour is colder than the interface
        T_f = _soft_max(0.5 * (a.T_v + T_s), T_s - 0.5, 0.1)
        kvi, nuvi, alvi, bevi, rhovi, cpvi = fl.film(a.p_h2, T_f, liquid=False)
        dT = a.T_v - T_s
        Ra = G * bevi * _soft_abs(dT) * L_i**3 / (nuvi * alvi)
        w_u = _step(-dT, 0.05)
        Nu = w_u * _blend6(0.54 * Ra**0.25, 0.15 * Ra ** (1.0 / 3.0)) + (1.0 - w_u) * 0.27 * Ra**0.25
        h_vi = Nu * kvi / L_i
        # interface, liquid side: unstable when the liquid is warmer than the interface
        T_f = _soft_min(0.5 * (T_top + T_s), T_sp + 1.0, 0.1)
        kli, nuli, alli, beli, rholi, cpli = fl.film(a.p, T_f, liquid=True)
        dT = T_top - T_s
        Ra = G * beli * _soft_abs(dT) * L_i**3 / (nuli * alli)
        w_u = _step(dT, 0.05)
        Nu = w_u * _blend6(0.54 * Ra**0.25, 0.15 * Ra ** (1.0 / 3.0)) + (1.0 - w_u) * 0.27 * Ra**0.25
        h_li = Nu * kli / L_i
        if A0 > 0.0 and f_e > 0.0:
            if law == "mcadams":
                vR = 2.0 * math.pi * f_e * A0 * R  # Re_wave = vR / nu
                h_vi *= 1.0 + _MCA_SLOSH_C * (vR / nuvi / _MCA_RE_REF) ** _MCA_SLOSH_EXP
                h_li *= 1.0 + _MCA_SLOSH_C * (vR / nuli / _MCA_RE_REF) ** _MCA_SLOSH_EXP
            else:  # slosh_energy
                b, R_s = self.wave_height(A_i, V_l)
                if b > 0.0:
                    for side in ("v", "l"):
                        nu, al, rho, cp = (nuvi, alvi, rhovi, cpvi) if side == "v" else (nuli, alli, rholi, cpli)
                        Re_b = 2.0 * math.pi * f_e * b * R_s / nu
                        h_s = rho * cp * math.sqrt(al * _SE_C * (b / R_s) ** 2 * Re_b * f_e)
                        if side == "v":
                            h_vi += h_s
                        else:
                            h_li += h_s
                    wall = 1.0 + _SE_WALL * b / R_s
                    h_wv *= wall
                    h_wl *= wall
        return (h_wv + _H_FLOOR["wv"], h_wl + _H_FLOOR["wl"], h_vi + _H_FLOOR["vi"], h_li + _H_FLOOR["li"])

    def wave_height(self, A_i: float, V_l: float) -> tuple[float, float]:
        """(first-mode wave height b [m], equivalent plan radius R_s [m]) under the current sloshing."""
        R_s = math.sqrt(A_i / math.pi)
        if not (self.A0 > 0 and self.f_e > 0 and R_s > 0):
            return 0.0, R_s
        H_s = max(V_l / A_i, 1e-3)
        th = math.tanh(_XI11 * H_s / R_s)
        f11 = math.sqrt(G * _XI11 / R_s * th) / (2.0 * math.pi)
        r = self.f_e / f11
        gamma = 2.0 * _XI11 * th / (_XI11**2 - 1.0)
        b = self.A0 * gamma * r * r / math.sqrt((1.0 - r * r) ** 2 + (2.0 * _SE_ZETA * r) ** 2)
        cap = _SE_BCAP * R_s
        return cap * math.tanh(b / cap), R_s

    # ------------------------------------------------------------------ right-hand side
    def evaluate(self, y: np.ndarray, full: bool = False) -> tuple[np.ndarray, dict[str, float]]:
        """dy/dt and (if ``full``) the diagnostics of state ``y``."""
        N, sh, fl, mech, opt = self.N, self.shape, self.fluid, self.mech, self.opt
        a = self._recover(y)
        m_v, n = float(y[self.i_mv]), float(y[self.i_n])
        m = np.asarray(y[self.i_m], dtype=float)
        V_l = float(np.sum(a.V))
        level = sh.level(V_l, self._h_guess)
        self._h_guess = level
        A_i, A_wl = sh.interface_area(level), sh.wetted_area(level)
        A_wv = sh.wall_area - A_wl
        P_w, L_c = sh.wetted_perimeter(level), sh.contact_line(level)
        # wall nodes
        E = np.asarray(y[self.i_E], dtype=float)
        if self.nw == 2:
            phi = self._wet_share(A_wl)
            C_wet = self.C_w * phi
            T_ww, T_wd = E[0] / C_wet, E[1] / (self.C_w - C_wet)
        else:
            phi = A_wl / sh.wall_area
            T_ww = T_wd = E[0] / self.C_w
        if a.p_h2 < 1.2 * fl.p_triple or a.p > 0.98 * fl.p_crit:
            raise SimulationError(f"pressure out of the model's range: p_H2={a.p_h2:.6g} Pa, p={a.p:.6g} Pa")
        T_s, h_ls, h_vs = fl.saturation(a.p_h2)
        T_sp, h_lsp, h_vsp = fl.saturation(a.p) if n > 0 else (T_s, h_ls, h_vs)
        h_wv, h_wl, h_vi, h_li = self._coefficients(a, T_ww, T_wd, T_s, T_sp, level, A_i, L_c, V_l)
        T_top, T_bot = float(a.T[0]), float(a.T[-1])
        Q_wv = h_wv * A_wv * (T_wd - a.T_v)
        Q_wl = h_wl * A_wl * (T_ww - T_bot)
        Q_vi = h_vi * A_i * (a.T_v - T_s)
        Q_li = h_li * A_i * (T_top - T_s)
        L_s = h_vs - h_ls
        J = (Q_vi + Q_li) / L_s
        if opt.bulk_phase_change:
            L_p = h_vsp - h_lsp
            J_f = np.array([m[k] * a.cp[k] * _ramp(a.T[k] - T_sp) for k in range(N)]) / (opt.tau_flash_s * L_p)
            J_fog = m_v * a.cp_v * _ramp(T_s - a.T_v) / (opt.tau_fog_s * L_s)
        else:
            J_f = np.zeros(N)
            J_fog = 0.0
        # boundary flows
        h_v = a.u_v + a.p_h2 / a.rho_v  # hydrogen enthalpy in the ullage (at its partial pressure)
        h_he = 2.5 * R_GAS * a.T_v  # J/mol
        if n > 0 and opt.vent_removes_helium:
            x_h2 = m_v / (m_v + n * M_HE)
            mdot_h2_out = self.mg_out * x_h2
            ndot_he = self.mg_out * (1.0 - x_h2) / M_HE
        else:
            mdot_h2_out, ndot_he = self.mg_out, 0.0
        h_bot = float(a.u[-1] + a.p / a.rho[-1])
        h_l_in = fl.h_liquid(a.p, self.T_l_in) if self.ml_in > 0 else 0.0
        Jf_sum = float(np.sum(J_f))
        dm_v = self.mv_in - mdot_h2_out + J + Jf_sum - J_fog
        A_g = (self.mv_in * self.h_v_in - mdot_h2_out * h_v - ndot_he * h_he + J * h_vs + Jf_sum * h_vsp
               - J_fog * h_ls + Q_wv - Q_vi + mech.heat_leak_vapor_W)
        dm = -J_f.copy()
        A_l = -J_f * h_vsp + mech.heat_leak_liquid_W * m / np.sum(m)
        # interface, fog and wall boundary layer on the layers
        dm[0] += -J + J_fog
        A_l[0] += -J * h_ls - Q_li + J_fog * h_ls
        w_top = _step(T_ww - T_bot, 0.05) if N > 1 else 1.0
        A_l[0] += w_top * Q_wl
        A_l[-1] += (1.0 - w_top) * Q_wl
        dm[-1] += self.ml_in - self.ml_out
        A_l[-1] += self.ml_in * h_l_in - self.ml_out * h_bot
        if N > 1:
            h_k = a.u + a.p / a.rho
            m_tot = float(np.sum(m))
            cum = np.cumsum(m)
            alpha_l = 0.0
            for k in range(N - 1):
                # mixing exchange (net mass zero)
                if k == 0:
                    kl, nul, alpha_l, *_ = fl.bulk(float(a.rho[-1]), T_bot, liquid=True)
                delta = 0.5 * (a.V[k] + a.V[k + 1]) / A_i
                w = (alpha_l / delta + _MIX_SLOSH * 2.0 * math.pi * self.f_e * self.A0
                     + _MIX_OVERTURN * _ramp(a.T[k + 1] - a.T[k], 0.05))
                x = 0.5 * (a.rho[k] + a.rho[k + 1]) * A_i * w
                A_l[k] += x * (h_k[k + 1] - h_k[k])
                A_l[k + 1] -= x * (h_k[k + 1] - h_k[k])
                # re-gridding flux (positive downward), upwind enthalpy
                Fk = (cum[k] - self.cumfrac[k] * m_tot) / _TAU_GRID
                scale = 1e-6 * m_tot / _TAU_GRID
                h_up = 0.5 * (h_k[k] + h_k[k + 1]) + 0.5 * (h_k[k] - h_k[k + 1]) * math.tanh(Fk / scale)
                dm[k] -= Fk
                dm[k + 1] += Fk
                A_l[k] -= Fk * h_up
                A_l[k + 1] += Fk * h_up
        # work: solve for the layer volume rates w_k (dV_k/dt), see the module docstring
        K = a.K
        assert K is not None
        sdot0 = np.empty(self.ns)
        sdot0[0], sdot0[1], sdot0[2] = dm_v, A_g, -ndot_he
        sdot0[3:3 + N] = dm
        sdot0[3 + N:] = A_l
        D = (m / a.rho**2)[:, None] * K[1::2, :]
        D[np.arange(N), 3 + np.arange(N)] += 1.0 / a.rho
        B = np.zeros((self.ns, N))
        B[1, :] = a.p
        B[3 + N + np.arange(N), np.arange(N)] = -a.p
        wvol = np.linalg.solve(np.eye(N) - D @ B, D @ sdot0)
        sdot = sdot0 + B @ wvol
        # wall
        Q_amb = self.Q_wall
        dy = np.zeros(self.n_state)
        dy[:self.ns] = sdot
        dh = float(np.sum(wvol)) / A_i if A_i > 0 else 0.0
        if self.nw == 2:
            Q_c = self.G_cond * L_c * (T_wd - T_ww)
            Cdot = self.C_w * (1.0 - 2.0 * _WALL_EPS) * P_w * dh / sh.wall_area if math.isfinite(P_w) else 0.0
            T_up = 0.5 * (T_ww + T_wd) + 0.5 * (T_wd - T_ww) * math.tanh(Cdot / (1e-6 * self.C_w))
            dy[self.i_E.start] = phi * Q_amb - Q_wl + Q_c + Cdot * T_up
            dy[self.i_E.start + 1] = (1.0 - phi) * Q_amb - Q_wv - Q_c - Cdot * T_up
        else:
            dy[self.i_E.start] = Q_amb - Q_wl - Q_wv
        # quadratures
        dy[self.i_Min] = self.mv_in + self.ml_in
        dy[self.i_Mout] = mdot_h2_out + self.ml_out
        dy[self.i_Hin] = self.mv_in * self.h_v_in + self.ml_in * h_l_in
        dy[self.i_Hout] = mdot_h2_out * h_v + ndot_he * h_he + self.ml_out * h_bot
        dy[self.i_Q] = Q_amb + mech.heat_leak_vapor_W + mech.heat_leak_liquid_W
        diag: dict[str, float] = {}
        if full:
            diag = dict(p=a.p, p_h2=a.p_h2, T_s=T_s, T_v=a.T_v, T_top=T_top, T_bot=T_bot, T_ww=T_ww, T_wd=T_wd,
                        level=level, A_i=A_i, A_wl=A_wl, A_wv=A_wv, h_wv=h_wv, h_wl=h_wl, h_vi=h_vi, h_li=h_li,
                        Q_wv=Q_wv, Q_wl=Q_wl, Q_vi=Q_vi, Q_li=Q_li, J=J, J_flash=Jf_sum, J_fog=J_fog,
                        dV_l=float(np.sum(wvol)), dh=dh)
        return dy, diag

    def rhs(self, t: float, y: np.ndarray) -> np.ndarray:
        self.n_rhs += 1
        self.y_now = y
        if self.n_rhs > self.opt.max_rhs:
            raise SimulationError(f"more than {self.opt.max_rhs} right-hand-side evaluations (t = {t:.6g} s)")
        self.t_now = t
        return self.evaluate(y)[0]

    def jac(self, t: float, y: np.ndarray) -> np.ndarray:
        """Forward-difference Jacobian over the dynamic states (the quadrature columns are zero)."""
        f0 = self.rhs(t, y)
        z0 = None if self._z is None else self._z.copy()
        Jm = np.zeros((self.n_state, self.n_state))
        for j in range(self.n_dyn):
            if j == self.i_n and y[j] == 0.0:
                continue  # helium absent: no perturbation into negative amounts
            d = 1e-7 * max(abs(y[j]), self._scale[j])
            yj = y.copy()
            yj[j] += d
            Jm[:, j] = (self.rhs(t, yj) - f0) / d
        self._z = z0
        return Jm

    # ------------------------------------------------------------------ observation
    def observe(self, y: np.ndarray) -> dict[str, Any]:
        """True (noise- and bias-free) quantities of state ``y``."""
        a = self._recover(y, need_K=False)
        sh = self.shape
        V_l = float(np.sum(a.V))
        level = sh.level(V_l, self._h_guess)
        m = np.asarray(y[self.i_m], dtype=float)
        E = np.asarray(y[self.i_E], dtype=float)
        if self.nw == 2:
            C_wet = self.C_w * self._wet_share(sh.wetted_area(level))
            T_wn = [E[0] / C_wet, E[1] / (self.C_w - C_wet)]
        else:
            T_wn = [E[0] / self.C_w]
        return dict(p=a.p, p_h2=a.p_h2, T_v=a.T_v, T_l=float(np.sum(m * a.T) / np.sum(m)), T_layers=a.T.copy(),
                    T_w=float(np.sum(E) / self.C_w), T_w_nodes=T_wn, level=level, fill=V_l / sh.volume,
                    V_v=a.V_v, V_l=V_l, rho_v=a.rho_v, rho_l=a.rho.copy())

    def sensors(self, obs: Mapping[str, Any]) -> dict[str, float]:
        """What the sensors read (biased, noise-free) for the observation ``obs``."""
        mech = self.mech
        out = {"p_v_Pa": obs["p"] + mech.pressure_sensor_bias_Pa, "T_v_K": obs["T_v"], "T_l_K": obs["T_l"],
               "T_w_K": obs["T_w"], "H_l_m": obs["level"]}
        out[mech.temperature_bias_channel + "_K"] += mech.temperature_sensor_bias_K
        return out

    def set_scale(self, y0: np.ndarray) -> None:
        """Typical magnitudes of the states (finite-difference steps and absolute tolerances)."""
        M = float(y0[self.i_mv] + np.sum(y0[self.i_m]))
        s = np.empty(self.n_state)
        # per phase: the ullage holds a small share of the mass, and its energy must be as accurate
        s[self.i_mv] = max(float(y0[self.i_mv]), 1e-3 * M)
        s[self.i_Ug] = s[self.i_mv] * 1e5  # ~ c_v T
        s[self.i_n] = max(float(y0[self.i_n]), 1.0)
        s[self.i_m] = np.maximum(np.asarray(y0[self.i_m]), 1e-3 * M)
        s[self.i_U] = s[self.i_m] * 1e5
        s[self.i_E] = self.C_w * 20.0
        s[self.i_Min] = s[self.i_Mout] = M
        s[self.i_Hin] = s[self.i_Hout] = M * 5e5
        s[self.i_Q] = M * 5e5
        self._scale = s

    def energy(self, y: np.ndarray) -> float:
        """Total energy of fluid (+ helium) and wall [J]."""
        return float(y[self.i_Ug] + np.sum(y[self.i_U]) + np.sum(y[self.i_E]))

    def mass(self, y: np.ndarray) -> float:
        """Total hydrogen mass [kg]."""
        return float(y[self.i_mv] + np.sum(y[self.i_m]))


# =============================================================================== scenarios
def _tsat(p: float, fluid: str = "ParaHydrogen") -> float:
    return float(CP.CoolProp.PropsSI("T", "P", p, "Q", 0, fluid))


def _scenario(name: str, description: str, tank: dict, p: float, T_v: float, T_l: float | None, T_w: float,
              fill: float, duration: float, steps: list) -> dict[str, Any]:
    """One scenario (``T_l=None``: saturated at ``p``)."""
    return {"name": name, "description": description, "tank": tank,
            "initial": {"p_Pa": p, "T_v_K": T_v, "T_l_K": _tsat(p) if T_l is None else T_l, "T_w_K": T_w,
                        "fill_ratio": fill},
            "duration_s": duration, "steps": steps}


def _gh2(mdot: float, T: float = 60.0, p: float = 6e5) -> dict[str, float]:
    return {"mdot_v_in_kg_s": mdot, "T_v_in_K": T, "p_v_in_Pa": p}


_OFF_IN = {"mdot_v_in_kg_s": 0.0}
_NO_SLOSH = {"slosh_amplitude_m": 0.0, "slosh_frequency_Hz": 0.0}

# A scenario: {"name", "description", "tank": interchange-format tank (nominal wall capacity),
# "initial": {"p_Pa" (true total pressure), "T_v_K", "T_l_K", "T_w_K", "fill_ratio", optional
# "T_w_dry_K"}, "duration_s", "steps": [(t_s, {input column: value}), ...]}; each step sets the
# inputs it names and keeps the others (all 0 before they are first set); the first step is at 0.
SCENARIOS: dict[str, dict[str, Any]] = {}
for _sc in [
    _scenario(
        "upright_13m3", "13.6 m3 upright cylinder, 500 W: self-pressurisation, warm-gas pressurisation, hold, "
        "sloshing, vent, drain (2 h)",
        {"shape": "vertical_cylinder", "radius_m": 1.2, "height_m": 3.0, "wall_heat_capacity_J_per_K": 5.0e5},
        1.2e5, 22.0, None, 21.5, 0.5, 7200.0,
        [(0.0, {"Q_aw_W": 500.0}),
         (600.0, _gh2(0.010)),
         (1200.0, _OFF_IN),
         (2400.0, {"slosh_amplitude_m": 0.01, "slosh_frequency_Hz": 0.5}),
         (3600.0, {**_NO_SLOSH, "mdot_v_out_kg_s": 0.004}),
         (4500.0, {"mdot_v_out_kg_s": 0.0, "mdot_l_out_kg_s": 0.2}),
         (5700.0, {"mdot_l_out_kg_s": 0.0})]),
    _scenario(
        "tank_4p9m3", "4.9 m3 upright cylinder, 150 W: self-pressurisation, vents, liquid top-up, sloshing (2 h)",
        {"shape": "vertical_cylinder", "radius_m": 0.8, "height_m": 2.437, "wall_heat_capacity_J_per_K": 2.0e5},
        1.5e5, 23.0, None, 22.0, 0.6, 7200.0,
        [(0.0, {"Q_aw_W": 150.0}),
         (1800.0, {"mdot_v_out_kg_s": 0.002}),
         (2400.0, {"mdot_v_out_kg_s": 0.0, "mdot_l_in_kg_s": 0.05, "T_l_in_K": 20.5}),
         (3000.0, {"mdot_l_in_kg_s": 0.0}),
         (3600.0, {"slosh_amplitude_m": 0.005, "slosh_frequency_Hz": 0.7}),
         (4800.0, _NO_SLOSH),
         (5400.0, {"mdot_v_out_kg_s": 0.0015}),
         (6000.0, {"mdot_v_out_kg_s": 0.0})]),
    _scenario(
        "sphere_4m3", "4.2 m3 sphere, 300 W: warm-gas pressurisation, vent, sloshing (1.5 h)",
        {"shape": "sphere", "radius_m": 1.0, "wall_heat_capacity_J_per_K": 3.0e5},
        1.3e5, 23.0, None, 22.0, 0.7, 5400.0,
        [(0.0, {"Q_aw_W": 300.0}),
         (300.0, _gh2(0.004, 50.0)),
         (1200.0, _OFF_IN),
         (2100.0, {"mdot_v_out_kg_s": 0.003}),
         (2700.0, {"mdot_v_out_kg_s": 0.0, "slosh_amplitude_m": 0.008, "slosh_frequency_Hz": 0.6}),
         (3900.0, _NO_SLOSH)]),
    _scenario(
        "hcyl_drain_fill", "10.2 m3 horizontal cylinder, 400 W: drain, hold, fill with venting (2 h)",
        {"shape": "horizontal_cylinder", "radius_m": 0.9, "cylinder_length_m": 4.0,
         "wall_heat_capacity_J_per_K": 4.0e5},
        1.4e5, 24.0, None, 22.5, 0.6, 7200.0,
        [(0.0, {"Q_aw_W": 400.0}),
         (600.0, {"mdot_l_out_kg_s": 0.15}),
         (1800.0, {"mdot_l_out_kg_s": 0.0}),
         (3000.0, {"mdot_l_in_kg_s": 0.12, "T_l_in_K": 20.3, "mdot_v_out_kg_s": 0.0015}),
         (4800.0, {"mdot_l_in_kg_s": 0.0, "mdot_v_out_kg_s": 0.0})]),
    _scenario(
        "ellipsoidal_light_wall", "6.8 m3 upright cylinder with 2:1 elliptical heads and a light wall "
        "(2e4 J/K, stiff), 200 W: pressurisation, vent, sloshing (1 h)",
        {"shape": "vertical_cylinder_elliptical_heads", "radius_m": 1.0, "cylinder_length_m": 1.5, "head_aspect": 2.0,
         "wall_heat_capacity_J_per_K": 2.0e4},
        1.2e5, 22.0, None, 21.0, 0.5, 3600.0,
        [(0.0, {"Q_aw_W": 200.0}),
         (300.0, _gh2(0.006, 45.0)),
         (900.0, _OFF_IN),
         (1500.0, {"mdot_v_out_kg_s": 0.004}),
         (2100.0, {"mdot_v_out_kg_s": 0.0, "slosh_amplitude_m": 0.008, "slosh_frequency_Hz": 0.55}),
         (3000.0, _NO_SLOSH)]),
    _scenario(
        "large_1600m3_drain", "1600 m3 sphere, 20 kW on the wall, drained at 10 kg/s from a subcooled state: the "
        "ullage expands and the pressure falls below 0.7 bar (1.5 h)",
        {"shape": "sphere", "radius_m": 7.26, "wall_heat_capacity_J_per_K": 2.0e7},
        1.1e5, 21.0, 18.4, 20.5, 0.8, 5400.0,
        [(0.0, {"Q_aw_W": 20000.0, "mdot_l_out_kg_s": 10.0})]),
    _scenario(
        "wide_span_0p5_10bar", "1.2 m3 upright cylinder: vent down to 0.5 bar, pressurise with warm gas to 10 bar, "
        "hold, vent back down (1.5 h); calibrated for the default options (with a stratified liquid the "
        "pressurisation passes the near-critical limit, without bulk flash the first vent empties the ullage)",
        {"shape": "vertical_cylinder", "radius_m": 0.5, "height_m": 1.5, "wall_heat_capacity_J_per_K": 1.0e5},
        0.6e5, 19.5, None, 19.0, 0.5, 5400.0,
        [(0.0, {"Q_aw_W": 60.0, "mdot_v_out_kg_s": 0.0007}),
         (900.0, {"mdot_v_out_kg_s": 0.0, **_gh2(0.005, 40.0, 1.2e6)}),
         (2250.0, _OFF_IN),
         (3300.0, {"mdot_v_out_kg_s": 0.006}),
         (4200.0, {"mdot_v_out_kg_s": 0.0})]),
    # The same three tanks with their operations run twice in an hour: the last 30 % (from 42
    # minutes) repeats operations the first 70 % showed, so a forecast from the split asks the
    # agent to carry what it learned, not to extrapolate to an operation it never saw.
    _scenario(
        "upright_cycles", "13.6 m3 upright cylinder, 500 W: pressurisation, sloshing, vent, drain, twice (1 h)",
        {"shape": "vertical_cylinder", "radius_m": 1.2, "height_m": 3.0, "wall_heat_capacity_J_per_K": 5.0e5},
        1.2e5, 22.0, None, 21.5, 0.5, 3600.0,
        [(0.0, {"Q_aw_W": 500.0}), (300.0, _gh2(0.010)), (600.0, _OFF_IN),
         (900.0, {"slosh_amplitude_m": 0.01, "slosh_frequency_Hz": 0.5}), (1200.0, {**_NO_SLOSH, "mdot_v_out_kg_s": 0.004}),
         (1500.0, {"mdot_v_out_kg_s": 0.0, "mdot_l_out_kg_s": 0.2}), (1800.0, {"mdot_l_out_kg_s": 0.0}),
         (2100.0, _gh2(0.010)), (2400.0, _OFF_IN),
         (2700.0, {"slosh_amplitude_m": 0.01, "slosh_frequency_Hz": 0.5}), (3000.0, {**_NO_SLOSH, "mdot_v_out_kg_s": 0.004}),
         (3300.0, {"mdot_v_out_kg_s": 0.0, "mdot_l_out_kg_s": 0.2})]),
    _scenario(
        "sphere_cycles", "4.2 m3 sphere, 300 W: pressurisation, vent, sloshing, fill, twice (1 h)",
        {"shape": "sphere", "radius_m": 1.0, "wall_heat_capacity_J_per_K": 3.0e5},
        1.3e5, 23.0, None, 22.0, 0.6, 3600.0,
        [(0.0, {"Q_aw_W": 300.0}), (300.0, _gh2(0.004, 50.0)), (600.0, _OFF_IN), (900.0, {"mdot_v_out_kg_s": 0.003}),
         (1200.0, {"mdot_v_out_kg_s": 0.0, "slosh_amplitude_m": 0.008, "slosh_frequency_Hz": 0.6}),
         (1500.0, {**_NO_SLOSH, "mdot_l_in_kg_s": 0.03, "T_l_in_K": 20.5}), (1800.0, {"mdot_l_in_kg_s": 0.0}),
         (2100.0, _gh2(0.004, 50.0)), (2400.0, _OFF_IN), (2700.0, {"mdot_v_out_kg_s": 0.003}),
         (3000.0, {"mdot_v_out_kg_s": 0.0, "slosh_amplitude_m": 0.008, "slosh_frequency_Hz": 0.6}),
         (3300.0, {**_NO_SLOSH, "mdot_l_in_kg_s": 0.03, "T_l_in_K": 20.5})]),
    _scenario(
        "hcyl_cycles", "10.2 m3 horizontal cylinder, 400 W: drain, pressurisation, sloshing, fill with venting, "
        "twice (1 h)",
        {"shape": "horizontal_cylinder", "radius_m": 0.9, "cylinder_length_m": 4.0,
         "wall_heat_capacity_J_per_K": 4.0e5},
        1.4e5, 24.0, None, 22.5, 0.6, 3600.0,
        [(0.0, {"Q_aw_W": 400.0}), (300.0, {"mdot_l_out_kg_s": 0.15}),
         (600.0, {"mdot_l_out_kg_s": 0.0, **_gh2(0.006, 50.0)}),
         (900.0, {**_OFF_IN, "slosh_amplitude_m": 0.008, "slosh_frequency_Hz": 0.5}),
         (1200.0, {**_NO_SLOSH, "mdot_l_in_kg_s": 0.12, "T_l_in_K": 20.3, "mdot_v_out_kg_s": 0.0015}),
         (1500.0, {"mdot_l_in_kg_s": 0.0, "mdot_v_out_kg_s": 0.0}),
         (2100.0, {"mdot_l_out_kg_s": 0.15}), (2400.0, {"mdot_l_out_kg_s": 0.0, **_gh2(0.006, 50.0)}),
         (2700.0, {**_OFF_IN, "slosh_amplitude_m": 0.008, "slosh_frequency_Hz": 0.5}),
         (3000.0, {**_NO_SLOSH, "mdot_l_in_kg_s": 0.12, "T_l_in_K": 20.3, "mdot_v_out_kg_s": 0.0015}),
         (3300.0, {"mdot_l_in_kg_s": 0.0, "mdot_v_out_kg_s": 0.0})]),
]:
    SCENARIOS[_sc["name"]] = _sc


def random_scenario(seed: int) -> dict[str, Any]:
    """A physically plausible random tank and schedule (fleet studies).

    Shape uniform over the four, volume log-uniform in 1-200 m3, fill 0.2-0.9, wall capacity
    5e3-3e4 J/K per m2 of wall, pressure 1.1-3 bar with a slightly subcooled liquid and a
    superheated ullage, ambient heat 2-15 W/m2; 1-2 h of 4-8 segments drawn from hold,
    pressurisation (0.3-1 kg of 30-80 K gas per m3 of ullage), vent (0.1-0.4 kg per m3 of
    ullage), fill, drain (sized to keep the fill ratio in 0.12-0.88 before thermal expansion),
    sloshing (near the first sloshing mode) and heat changes.
    """
    rng = np.random.default_rng(seed)
    kinds = ["vertical_cylinder", "vertical_cylinder_elliptical_heads", "sphere", "horizontal_cylinder"]
    kind = kinds[int(rng.integers(4))]
    V = float(np.exp(rng.uniform(math.log(1.0), math.log(200.0))))
    if kind == "sphere":
        tank: dict[str, Any] = {"shape": kind, "radius_m": round((3 * V / (4 * math.pi)) ** (1 / 3), 4)}
    elif kind == "vertical_cylinder":
        ar = rng.uniform(1.0, 3.0)  # H / (2R)
        R = (V / (2 * math.pi * ar)) ** (1 / 3)
        tank = {"shape": kind, "radius_m": round(R, 4), "height_m": round(2 * R * ar, 4)}
    elif kind == "horizontal_cylinder":
        ar = rng.uniform(1.5, 4.0)  # L / (2R)
        R = (V / (2 * math.pi * ar)) ** (1 / 3)
        tank = {"shape": kind, "radius_m": round(R, 4), "cylinder_length_m": round(2 * R * ar, 4)}
    else:
        ar, asp = rng.uniform(0.5, 2.5), float(rng.choice([1.0, 1.5, 2.0, 3.0]))
        R = (V / (math.pi * (2 * ar + 4 / (3 * asp)))) ** (1 / 3)
        tank = {"shape": kind, "radius_m": round(R, 4), "cylinder_length_m": round(2 * R * ar, 4), "head_aspect": asp}
    sh = make_shape(tank)
    V = sh.volume
    tank["wall_heat_capacity_J_per_K"] = float(f"{sh.wall_area * rng.uniform(5e3, 3e4):.3g}")
    fill = float(rng.uniform(0.2, 0.9))
    p0 = float(rng.uniform(1.1e5, 3.0e5))
    T_sat = _tsat(p0)
    T_l = T_sat - float(rng.uniform(0.0, 0.8))
    T_v = T_sat + float(rng.uniform(0.5, 6.0))
    T_w = T_sat + float(rng.uniform(0.0, 3.0))
    q = sh.wall_area * float(rng.uniform(2.0, 15.0))
    duration = float(rng.choice([3600.0, 5400.0, 7200.0]))
    n_seg = int(rng.integers(4, 9))
    bounds = np.sort(rng.uniform(0.05, 0.95, n_seg - 1)) * duration
    times = [0.0] + [float(round(t, 0)) for t in bounds]
    steps: list[tuple[float, dict[str, float]]] = [(0.0, {"Q_aw_W": round(q, 1)})]
    rho_l = 70.0
    f_est = fill
    R_s = sh.radius
    f11 = math.sqrt(G * _XI11 / R_s * math.tanh(_XI11 * 0.5)) / (2 * math.pi)
    reset = {"mdot_v_in_kg_s": 0.0, "mdot_v_out_kg_s": 0.0, "mdot_l_in_kg_s": 0.0, "mdot_l_out_kg_s": 0.0,
             "slosh_amplitude_m": 0.0, "slosh_frequency_Hz": 0.0}
    for i in range(1, len(times)):
        t0 = times[i]
        t1 = times[i + 1] if i + 1 < len(times) else duration
        dt = max(t1 - t0, 1.0)
        op = str(rng.choice(["hold", "press", "vent", "fill", "drain", "slosh", "heat"]))
        ch: dict[str, float] = dict(reset)
        v_ullage = (1.0 - f_est) * V
        if op == "press":  # adds 0.3-1 kg per m3 of ullage over the segment (about +0.5 to +2 bar)
            mdot = v_ullage * rng.uniform(0.3, 1.0) / dt
            ch.update(_gh2(float(f"{mdot:.3g}"), float(rng.uniform(30.0, 80.0)), 8e5))
        elif op == "vent":  # removes 0.1-0.4 kg per m3 of ullage over the segment
            ch["mdot_v_out_kg_s"] = float(f"{v_ullage * rng.uniform(0.1, 0.4) / dt:.3g}")
        elif op == "fill":
            dfill = min(0.88 - f_est, 0.15)
            if dfill > 0.02:
                ch["mdot_l_in_kg_s"] = float(f"{dfill * V * rho_l / dt:.3g}")
                ch["T_l_in_K"] = round(T_sat - float(rng.uniform(0.0, 1.5)), 2)
                f_est += dfill
        elif op == "drain":
            dfill = min(f_est - 0.12, 0.15)
            if dfill > 0.02:
                ch["mdot_l_out_kg_s"] = float(f"{dfill * V * rho_l / dt:.3g}")
                f_est -= dfill
        elif op == "slosh":
            ch["slosh_amplitude_m"] = round(float(rng.uniform(0.002, 0.02)) * max(R_s, 0.5), 4)
            ch["slosh_frequency_Hz"] = round(f11 * float(rng.uniform(0.5, 1.2)), 3)
        elif op == "heat":
            ch["Q_aw_W"] = round(q * float(rng.uniform(0.3, 3.0)), 1)
        steps.append((t0, ch))
    return _scenario(f"random_{seed}", f"random tank {kind} {V:.1f} m3 (seed {seed})", tank, p0, T_v, T_l, T_w, fill,
                     duration, steps)


def resolve_scenario(scenario: str | Mapping[str, Any]) -> dict[str, Any]:
    """A scenario by name (``SCENARIOS`` key or ``random_SEED``) or as a mapping."""
    if isinstance(scenario, Mapping):
        return copy.deepcopy(dict(scenario))
    if scenario in SCENARIOS:
        return copy.deepcopy(SCENARIOS[scenario])
    if scenario.startswith("random_") and scenario[7:].isdigit():
        return random_scenario(int(scenario[7:]))
    raise KeyError(f"unknown scenario {scenario!r}; known: {', '.join(SCENARIOS)}, random_SEED")


def segments(steps: Sequence[tuple[float, Mapping[str, float]]],
             duration: float) -> list[tuple[float, float, dict[str, float]]]:
    """Expand steps (each sets some inputs, keeps the others) into (t0, t1, full metered inputs)."""
    cur = {c: 0.0 for c in INPUT_COLUMNS}
    out: list[tuple[float, float, dict[str, float]]] = []
    steps = [s for s in steps if s[0] < duration]
    if not steps or steps[0][0] != 0.0:
        raise ValueError("the first step must be at t = 0")
    for i, (t, ch) in enumerate(steps):
        unknown = set(ch) - set(INPUT_COLUMNS)
        if unknown:
            raise ValueError(f"unknown inputs {sorted(unknown)} at t = {t}")
        cur = {**cur, **{k: float(v) for k, v in ch.items()}}
        t1 = steps[i + 1][0] if i + 1 < len(steps) else duration
        if t1 <= t:
            raise ValueError("step times must increase")
        out.append((float(t), float(t1), dict(cur)))
    return out


# =============================================================================== simulation
@dataclass
class Trajectory:
    """Clean (noise-free) truth at the requested times. Arrays have the length of ``t``."""

    t: np.ndarray
    y: np.ndarray  # (n_t, n_state)
    p: np.ndarray  # true total pressure [Pa]
    p_h2: np.ndarray
    T_v: np.ndarray
    T_l: np.ndarray  # mass-averaged
    T_layers: np.ndarray  # (n_t, N)
    T_w: np.ndarray  # capacity-averaged
    T_w_nodes: np.ndarray  # (n_t, wall_nodes): wet, dry
    level: np.ndarray
    fill: np.ndarray
    mass: np.ndarray  # hydrogen in the tank [kg]
    energy: np.ndarray  # fluid + helium + wall [J]
    n_he: np.ndarray
    M_in: np.ndarray
    M_out: np.ndarray
    H_in: np.ndarray
    H_out: np.ndarray
    Q_in: np.ndarray
    sensors: dict[str, np.ndarray]  # biased, noise-free readings per CSV column
    n_rhs: int
    wall_time_s: float
    model: NodalTank = field(repr=False)

    def mass_balance_error(self) -> np.ndarray:
        """m(t) - m(0) - (M_in - M_out) [kg]."""
        return self.mass - self.mass[0] - (self.M_in - self.M_out)

    def energy_balance_error(self) -> np.ndarray:
        """E(t) - E(0) - (H_in - H_out + Q) [J]."""
        return self.energy - self.energy[0] - (self.H_in - self.H_out + self.Q_in)


def simulate(scenario: str | Mapping[str, Any], law: str = "mcadams", mechanisms: Mapping[str, Any] | None = None,
             t_eval: Sequence[float] | np.ndarray | None = None, duration_s: float | None = None,
             **options: Any) -> Trajectory:
    """Integrate a scenario; return the truth at ``t_eval`` (default: every 10 s).

    Args:
        scenario: a key of :data:`SCENARIOS`, ``"random_SEED"`` or a scenario mapping.
        law: heat-transfer law (:data:`LAWS`).
        mechanisms: hidden mechanisms (:class:`Mechanisms` fields).
        t_eval: output times [s] within ``[0, duration]``.
        duration_s: shorten (or lengthen) the scenario.
        **options: :class:`Options` fields.
    """
    sc = resolve_scenario(scenario)
    opt = Options(law=law, **options)
    mech = Mechanisms.from_mapping(mechanisms)
    duration = float(duration_s if duration_s is not None else sc["duration_s"])
    model = NodalTank(sc["tank"], opt, mech)
    ini = sc["initial"]
    y = model.initial_state(ini["p_Pa"], ini["T_v_K"], ini["T_l_K"], ini["T_w_K"], ini["fill_ratio"],
                            ini.get("T_w_dry_K"))
    model.set_scale(y)
    atol = 1e-2 * opt.rtol * model._scale
    te = np.arange(0.0, duration + 1e-9, 10.0) if t_eval is None else np.asarray(t_eval, dtype=float)
    if te.size == 0 or te[0] < 0 or te[-1] > duration + 1e-9 or np.any(np.diff(te) <= 0):
        raise ValueError("t_eval must be increasing within [0, duration]")
    ys: list[np.ndarray] = []
    ts: list[np.ndarray] = []
    t0_wall = time.perf_counter()
    segs = segments(sc["steps"], duration)
    for i, (ta, tb, inputs) in enumerate(segs):
        model.set_inputs(inputs)
        last = i == len(segs) - 1
        sel = te[(te >= ta) & ((te < tb) | (last & (te <= tb)))]
        try:
            # t_eval always ends at tb: the next segment starts from the state there
            t_ev = np.concatenate([sel[sel < tb], [tb]])
            sol = solve_ivp(model.rhs, (ta, tb), y, method="BDF", jac=model.jac, rtol=opt.rtol, atol=atol,
                            max_step=opt.max_step_s, t_eval=t_ev, first_step=0.1)
        except SimulationError as e:
            raise SimulationError(f"t = {model.t_now:.6g} s: {e}; {_describe(model, model.y_now)}") from None
        except ValueError as e:  # CoolProp failures
            raise SimulationError(f"t = {model.t_now:.6g} s: property evaluation failed ({e}); "
                                  f"{_describe(model, model.y_now)}") from None
        if sol.status != 0:
            raise SimulationError(f"t = {float(sol.t[-1]):.6g} s: integration failed ({sol.message}); "
                                  f"{_describe(model, sol.y[:, -1])}")
        keep = np.isin(sol.t, sel)
        if keep.any():
            ts.append(sol.t[keep])
            ys.append(sol.y.T[keep])
        y = sol.y[:, -1].copy()
    wall = time.perf_counter() - t0_wall
    t_all = np.concatenate(ts)
    Y = np.concatenate(ys)
    obs = [model.observe(yy) for yy in Y]
    sens = [model.sensors(o) for o in obs]

    def col(key: str) -> np.ndarray:
        return np.array([o[key] for o in obs], dtype=float)

    return Trajectory(
        t=t_all, y=Y, p=col("p"), p_h2=col("p_h2"), T_v=col("T_v"), T_l=col("T_l"),
        T_layers=np.array([o["T_layers"] for o in obs]), T_w=col("T_w"),
        T_w_nodes=np.array([o["T_w_nodes"] for o in obs]),
        level=col("level"), fill=col("fill"), mass=np.array([model.mass(yy) for yy in Y]),
        energy=np.array([model.energy(yy) for yy in Y]), n_he=Y[:, model.i_n].copy(),
        M_in=Y[:, model.i_Min].copy(), M_out=Y[:, model.i_Mout].copy(), H_in=Y[:, model.i_Hin].copy(),
        H_out=Y[:, model.i_Hout].copy(), Q_in=Y[:, model.i_Q].copy(),
        sensors={c: np.array([s[c] for s in sens]) for c in OBS_COLUMNS}, n_rhs=model.n_rhs, wall_time_s=wall,
        model=model)


def _describe(model: NodalTank, y: np.ndarray) -> str:
    """A readable summary of a state (for error messages)."""
    try:
        o = model.observe(y)
        return (f"state: p={o['p']:.6g} Pa, T_v={o['T_v']:.5g} K, T_l={o['T_l']:.5g} K, T_w={o['T_w']:.5g} K, "
                f"fill={o['fill']:.4g}, m_v={y[model.i_mv]:.6g} kg, m_l={float(np.sum(y[model.i_m])):.6g} kg")
    except Exception:  # noqa: BLE001 - the state may be unrecoverable; show the raw vector
        return f"state vector: {np.array2string(np.asarray(y[:model.n_dyn]), precision=6)}"


# =============================================================================== writer
def _fmt(v: float) -> str:
    return repr(float(v))


def sample_times(duration: float) -> dict[str, np.ndarray]:
    """Nominal sample times of each CSV observation column."""
    return {c: np.arange(off, duration + 1e-9, per) for c, (per, off) in SAMPLING.items()}


def simulate_run(scenario: str | Mapping[str, Any], law: str = "mcadams", mechanisms: Mapping[str, Any] | None = None,
                 noise: str = "low", seed: int = 0, out_dir: str | pathlib.Path | None = None,
                 name: str | None = None, duration_s: float | None = None, **options: Any) -> dict[str, Any]:
    """Simulate a scenario and (if ``out_dir``) write it in the interchange format.

    Args:
        scenario: a key of :data:`SCENARIOS`, ``"random_SEED"`` or a scenario mapping.
        law: heat-transfer law (:data:`LAWS`).
        mechanisms: hidden mechanisms, e.g. ``{"vapor_leak_kg_s": 1e-4}``.
        noise: ``"low"``, ``"high"`` (see :data:`NOISE_LEVELS`) or ``"none"`` (exact readings;
            ``noise_std`` still holds the ``low`` values, since the format needs positive ones).
        seed: seeds the sensor noise.
        out_dir: folder to write ``NAME.json``, ``NAME.csv`` and ``NAME.truth.json`` into.
        name: run name (default ``nodal_<scenario>_<law>_s<seed>``).
        duration_s: shorten the scenario.
        **options: :class:`Options` fields (``wall_nodes``, ``liquid_layers``, ``property_model``, ...).

    Returns:
        ``{"json", "csv", "truth"}`` paths (None without ``out_dir``), ``"trajectory"`` (the clean
        :class:`Trajectory` at the sample times), ``"observations"`` ({column: (t, values)}),
        ``"metadata"`` (the run's JSON content) and ``"truth_record"`` (the sidecar's content).
    """
    sc = resolve_scenario(scenario)
    if noise not in ("low", "high", "none"):
        raise ValueError(f"noise must be low, high or none, got {noise!r}")
    std = NOISE_LEVELS["low" if noise == "none" else noise]
    duration = float(duration_s if duration_s is not None else sc["duration_s"])
    times = sample_times(duration)
    segs = segments(sc["steps"], duration)
    change_t = [s[0] for s in segs]
    grid = np.unique(np.concatenate([[0.0], *times.values()]))
    traj = simulate(sc, law=law, mechanisms=mechanisms, t_eval=grid, duration_s=duration, **options)
    rng = np.random.default_rng(seed)
    observations: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for col, key in zip(OBS_COLUMNS, NOISE_KEYS):
        idx = np.searchsorted(grid, times[col])
        vals = traj.sensors[col][idx].copy()
        if noise != "none":
            vals = vals + rng.normal(0.0, std[key], size=vals.size)
        if col == "H_l_m":
            vals = np.maximum(vals, 0.0)
        observations[col] = (times[col], vals)

    model = traj.model
    sens0 = {c: float(traj.sensors[c][0]) for c in OBS_COLUMNS}
    run_name = name or f"nodal_{sc.get('name', 'custom')}_{law}_s{seed}"
    tank_meta = dict(sc["tank"])
    tank_meta["volume_m3"] = model.shape.volume
    meta = {
        "name": run_name,
        "fluid": RUN_FLUID,
        "source": f"tests/nodal_sim.py law={law}",
        "tank": tank_meta,
        "initial": {"p_v_Pa": sens0["p_v_Pa"], "T_v_K": sens0["T_v_K"], "T_l_K": sens0["T_l_K"],
                    "T_w_K": sens0["T_w_K"], "fill_ratio": float(traj.fill[0])},
        "noise_std": dict(zip(NOISE_KEYS, (std[k] for k in NOISE_KEYS))),
        "duration_s": duration,
        "timeseries": f"{run_name}.csv",
    }
    opt = model.opt
    truth = {
        "simulator": "tests/nodal_sim.py",
        "scenario": sc.get("name", "custom"),
        "law": law,
        "mechanisms": model.mech.active(),
        "options": {k: v for k, v in asdict(opt).items() if k != "law"},
        "wall_heat_capacity_true_J_per_K": model.C_w,
        "wall_heat_capacity_metadata_J_per_K": model.C_meta,
        "noise": noise,
        "seed": seed,
        "initial_true": {"p_Pa": float(traj.p[0]), "p_H2_Pa": float(traj.p_h2[0]), "T_v_K": float(traj.T_v[0]),
                         "T_l_K": float(traj.T_l[0]), "T_w_K": float(traj.T_w[0]), "fill_ratio": float(traj.fill[0]),
                         "helium_mol": float(traj.n_he[0])},
        "final_true": {"p_Pa": float(traj.p[-1]), "T_v_K": float(traj.T_v[-1]), "T_l_K": float(traj.T_l[-1]),
                       "T_w_K": float(traj.T_w[-1]), "fill_ratio": float(traj.fill[-1])},
        "n_rhs": traj.n_rhs,
        "wall_time_s": traj.wall_time_s,
    }
    out: dict[str, Any] = {"json": None, "csv": None, "truth": None, "trajectory": traj,
                           "observations": observations, "metadata": meta, "truth_record": truth}
    if out_dir is None:
        return out
    d = pathlib.Path(out_dir)
    d.mkdir(parents=True, exist_ok=True)
    used = [c for c in INPUT_COLUMNS if any(s[2][c] != 0.0 for s in segs)]
    rows_t = np.unique(np.concatenate([grid, np.array(change_t)]))
    obs_at = {c: dict(zip(t.tolist(), v.tolist())) for c, (t, v) in observations.items()}
    seg_at = {s[0]: s[2] for s in segs}
    csv_path = d / f"{run_name}.csv"
    with open(csv_path, "w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(["t_s", *OBS_COLUMNS, *used])
        for t in rows_t.tolist():
            row = [_fmt(t)]
            for c in OBS_COLUMNS:
                v = obs_at[c].get(t)
                row.append("" if v is None else _fmt(v))
            inp = seg_at.get(t)
            row.extend((_fmt(inp[c]) if inp is not None else "") for c in used)
            w.writerow(row)
    json_path = d / f"{run_name}.json"
    json_path.write_text(json.dumps(meta, indent=2) + "\n")
    truth_path = d / f"{run_name}.truth.json"
    truth_path.write_text(json.dumps(truth, indent=2) + "\n")
    out.update(json=json_path, csv=csv_path, truth=truth_path)
    return out


# =============================================================================== command line
def _parse_mechanism(text: str) -> tuple[str, Any]:
    if "=" not in text:
        raise argparse.ArgumentTypeError(f"--mechanism needs NAME=VALUE, got {text!r}")
    k, v = text.split("=", 1)
    return (k, v) if k == "temperature_bias_channel" else (k, float(v))


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="Nodal LH2 tank simulator (independent of tankode): writes runs "
                                             "in the interchange format.")
    ap.add_argument("scenario", nargs="?", help="scenario name (see --list) or random_SEED")
    ap.add_argument("--list", action="store_true", help="list the scenarios and exit")
    ap.add_argument("--law", default="mcadams", choices=LAWS)
    ap.add_argument("--out", help="output folder")
    ap.add_argument("--name", help="run name")
    ap.add_argument("--mechanism", action="append", default=[], type=_parse_mechanism, metavar="NAME=VALUE",
                    help=f"hidden mechanism ({', '.join(MECHANISM_NAMES)}, temperature_bias_channel)")
    ap.add_argument("--noise", default="low", choices=("low", "high", "none"))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--wall-nodes", type=int, default=2, choices=(1, 2))
    ap.add_argument("--liquid-layers", type=int, default=1)
    ap.add_argument("--property-model", default="reference", choices=tuple(PROPERTY_MODELS))
    ap.add_argument("--no-bulk-phase-change", action="store_true")
    ap.add_argument("--duration", type=float, help="shorten the scenario [s]")
    args = ap.parse_args(argv)
    if args.list:
        for k, sc in SCENARIOS.items():
            print(f"{k:26s} {sc['description']}")
        print(f"{'random_SEED':26s} random_scenario(SEED): a random plausible tank and schedule")
        return 0
    if not args.scenario or not args.out:
        ap.error("SCENARIO and --out are required (or --list)")
    res = simulate_run(args.scenario, law=args.law, mechanisms=dict(args.mechanism), noise=args.noise, seed=args.seed,
                       out_dir=args.out, name=args.name, duration_s=args.duration, wall_nodes=args.wall_nodes,
                       liquid_layers=args.liquid_layers, property_model=args.property_model,
                       bulk_phase_change=not args.no_bulk_phase_change)
    tr = res["trajectory"]
    print(f"wrote {res['json']} ({tr.wall_time_s:.2f} s, {tr.n_rhs} rhs calls, "
          f"p {tr.p.min():.0f}..{tr.p.max():.0f} Pa)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
