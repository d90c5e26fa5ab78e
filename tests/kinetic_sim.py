"""Kinetic-interface tank simulator: an independent "truth" for tankode (shares no code with it).

Writes runs in the interchange format (``shared/data-format.md``: ``NAME.json`` + ``NAME.csv``)
plus ``NAME.truth.json`` and ``NAME.truth.csv`` (noise-free, bias-free physical series and
internal states), with the command line of ``tests/cryo_sim.py`` / ``tests/eng_sim.py``.

Physics (deliberately unlike the usual 0D tank model)
-----------------------------------------------------
* Interface mass transfer by kinetic theory (Hertz-Knudsen-Schrage)::

      mdot'' = 2 sigma / (2 - sigma) sqrt(M / (2 pi R)) (p_sat(T_i)/sqrt(T_i) - p_f/sqrt(T_v1))

  with an accommodation coefficient ``sigma`` per scenario (1e-3..1e-2); the interface
  temperature ``T_i`` solves the interface energy balance ``q_v + q_l = mdot L`` (Newton),
  so the interface is NOT at saturation of the ullage pressure. Interface coefficients:
  horizontal-plate correlations (stable ``Nu = 1 + 0.27 Ra^1/4``, unstable ``0.15 Ra^1/3``)
  with the temperature difference taken against ``T_sat(p_f)``.
* Two-zone ullage: a lower zone (fraction ``PHI_LOWER`` of the ullage volume, next to the
  interface) and an upper zone, each well mixed (fluid mass, energy, helium moles). They
  exchange mixture by (i) a pressure-equalising flow (time constant ``TAU_EQ``, central mixture weights) and
  (ii) an equal-mass buoyant exchange: weak when stable (upper warmer), ``0.05 sqrt(g H dT/T)``
  when unstable, plus sloshing ``0.5 A f``. Warm gas enters the upper zone; vent and vapour
  leak leave the upper zone. The liquid's p dV work goes to the zones by their volume share.
* Liquid: a well-mixed bulk plus a warm surface layer under the interface; a share ``CHI_LAYER``
  of the wall-to-liquid heat feeds the layer; entrainment bulk->layer keeps the layer near
  ``DELTA_LAYER`` thick, the layer mixes back at ``m_s (1/TAU_LAYER + K_SLOSH_MIX (A f)^1.5)``.
* Wall: ``N_BANDS`` axial bands of equal height, capacity by area share, axial conduction
  through the shell, each band exchanging with liquid / lower zone / upper zone over its
  wetted parts (Churchill-Chu vertical-plate correlation over the height of that phase);
  ``Q_aw`` and the hidden wall leak enter the bands by area.
* Sloshing multiplies the liquid-side interface and wall-liquid coefficients by
  ``1 + 40 (A f / sqrt(g R))^0.8`` and mixes the layer and the two ullage zones.
* Bulk boiling (liquid superheated above ``T_sat`` of the total pressure; relaxation 30 s,
  vapour to the lower zone) and fog (zone subcooled below ``T_sat`` of its partial pressure;
  relaxation 20 s, condensate rains into the layer).
* Operations: warm-gas pressurisation, vent, liquid fill (bottom fill into the bulk or a top
  spray whose droplets condense lower-zone vapour before joining the layer: the truth file's
  ``scenario.spray`` says which), drain from the bulk, sloshing, heat ingress, rest.
* Properties: CoolProp HEOS for the vapour (imposed gas phase, so metastable fog states stay
  defined), Chebyshev fits of CoolProp's saturation curve for ``p_sat``, saturated-liquid ``u``
  and ``rho`` (liquid p-independent); transport properties frozen at the initial state.
  Helium: ideal monatomic, Dalton; the metadata's initial pressure is the total pressure.

Numerics: ``solve_ivp(LSODA, rtol=1e-8)`` restarted at every schedule change. States are
masses, internal energies, helium moles and band temperatures plus two boundary quadratures;
every internal transfer is written once with opposite signs, so total mass and energy minus
what crossed the boundary are linear invariants (closure reported in the truth file).

Schedules: the mechanism-free run executes the plan with soft-bound events (pressure too high:
inflows stop / relief vent; too low: vent and drain stop; fill above 92 % or below 10 %);
the run with mechanisms replays exactly that executed (metered) schedule.

Sampling: p_v, T_v, T_l, H_l every 10 s; T_w every 30 s; input rows at every schedule change.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import pathlib
import sys
import time
from typing import Any, Mapping, Sequence

import numpy as np
from numpy.polynomial import chebyshev as _cheb
from scipy.integrate import solve_ivp

import CoolProp.CoolProp as CP

SIMULATOR = "tests/kinetic_sim.py"
FLUIDS = ("ParaHydrogen", "Nitrogen", "Oxygen", "Methane")
MECHANISMS = ("heat_leak_liquid_W", "heat_leak_vapor_W", "heat_leak_wall_W", "vapor_leak_kg_s",
              "liquid_leak_kg_s", "inflow_meter_bias", "pressure_sensor_bias_Pa",
              "temperature_sensor_bias_K", "helium_mol", "wall_heat_capacity_error")
OBS_COLUMNS = ("p_v_Pa", "T_v_K", "T_l_K", "T_w_K", "H_l_m")
NOISE_KEYS = ("p_v", "T_v", "T_l", "T_w", "H_l")
INPUT_COLUMNS = ("mdot_v_in_kg_s", "T_v_in_K", "p_v_in_Pa", "mdot_v_out_kg_s", "mdot_l_in_kg_s", "T_l_in_K",
                 "mdot_l_out_kg_s", "slosh_amplitude_m", "slosh_frequency_Hz", "Q_aw_W")
NOISE_LEVELS = {"low": {"p_v": 300.0, "T_v": 0.05, "T_l": 0.05, "T_w": 0.05, "H_l": 1e-3},
                "high": {"p_v": 2000.0, "T_v": 0.2, "T_l": 0.2, "T_w": 0.2, "H_l": 5e-3}}
SAMPLE_DT_S = 10.0
SAMPLE_DT_WALL_S = 30.0

R_GAS = 8.314462618
M_HE = 4.002602e-3
G = 9.80665
N_BANDS = 10
PHI_LOWER = 0.3          # lower ullage zone: this fraction of the ullage volume
TAU_EQ = 0.1             # s, pressure equalisation between the zones
CHI_LAYER = 0.6          # share of the wall->liquid heat that feeds the surface layer
DELTA_LAYER = 0.04       # m, layer thickness sustained by entrainment
TAU_LAYER = 1200.0       # s, layer renewal at rest
K_SLOSH_MIX = 6.0        # 1/s per (m/s)^1.5, layer mixing by sloshing
C_SLOSH, N_SLOSH = 40.0, 0.8
TAU_BOIL, TAU_FOG = 30.0, 20.0
SPRAY_EFF = 0.7
EPS_T = 0.02             # K, smoothing of max(x, 0)
P_LIMITS = {"ParaHydrogen": (0.8e5, 6.0e5)}
P_LIMITS_OTHER = (1.0e5, 10.0e5)
WALL_MATERIALS = {"aluminium": {"rho": 2700.0, "k_cold": 60.0, "k_warm": 120.0, "c_cold": 25.0, "c_warm": 400.0},
                  "steel": {"rho": 7900.0, "k_cold": 2.5, "k_warm": 8.0, "c_cold": 12.0, "c_warm": 230.0}}


class SimulationError(RuntimeError):
    """The state left the range the property model covers."""


def _sp(x: float, eps: float = EPS_T) -> float:
    """Smooth max(x, 0)."""
    return 0.5 * (x + math.sqrt(x * x + eps * eps))


# ----------------------------------------------------------------------------- properties
class _Cheb:
    """Chebyshev fit f(T) on [lo, hi], linear extension outside."""

    def __init__(self, T: np.ndarray, y: np.ndarray, lo: float, hi: float, deg: int = 20):
        self.lo, self.hi = lo, hi
        x = (2.0 * T - lo - hi) / (hi - lo)
        c = _cheb.chebfit(x, y, deg)
        self.c = [float(v) for v in c]
        self.dc = [float(v) * 2.0 / (hi - lo) for v in _cheb.chebder(c)]

    @staticmethod
    def _clen(c, x):
        b1 = b2 = 0.0
        x2 = 2.0 * x
        for ck in c[:0:-1]:
            b1, b2 = ck + x2 * b1 - b2, b1
        return c[0] + x * b1 - b2

    def __call__(self, T: float) -> tuple[float, float]:
        Tc = min(max(T, self.lo), self.hi)
        x = (2.0 * Tc - self.lo - self.hi) / (self.hi - self.lo)
        f, d = self._clen(self.c, x), self._clen(self.dc, x)
        return f + d * (T - Tc), d


class Fluid:
    def __init__(self, name: str):
        if name not in FLUIDS:
            raise ValueError(f"fluid must be one of {', '.join(FLUIDS)}, got {name!r}")
        self.name = name
        AS = CP.AbstractState("HEOS", name)
        self.M = AS.molar_mass()
        self.T_crit, self.p_crit, self.T_trip = AS.T_critical(), AS.p_critical(), AS.Ttriple()
        lo, hi = self.T_trip + 0.05, 0.93 * self.T_crit
        T = np.linspace(lo, hi, 400)
        lnp, ul, rl = [], [], []
        for t in T:
            AS.update(CP.QT_INPUTS, 0.0, float(t))
            lnp.append(math.log(AS.p()))
            ul.append(AS.umass())
            rl.append(AS.rhomass())
        self.T_lo, self.T_hi = lo, hi
        self._lnp = _Cheb(T, np.array(lnp), lo, hi)
        self._u = _Cheb(T, np.array(ul), lo, hi)
        self._rho = _Cheb(T, np.array(rl), lo, hi)
        self.gas = CP.AbstractState("HEOS", name)
        self.gas.specify_phase(CP.iphase_gas)
        self._tp = CP.AbstractState("HEOS", name)
        self.hks = math.sqrt(self.M / (2.0 * math.pi * R_GAS))
        AS.update(CP.PQ_INPUTS, 101325.0, 0.0)
        self.T_nbp = AS.T()

    def psat(self, T: float) -> tuple[float, float]:
        f, d = self._lnp(T)
        p = math.exp(f)
        return p, p * d

    def Tsat(self, p: float) -> float:
        lp = math.log(max(p, 1.0))
        T = self.T_nbp
        for _ in range(60):
            f, d = self._lnp(T)
            dT = (f - lp) / d
            T -= dT
            if abs(dT) < 1e-12 * T:
                break
        return T

    def liq(self, T: float) -> tuple[float, float, float, float]:
        """Saturated-liquid u, du/dT, rho, drho/dT at T."""
        u, du = self._u(T)
        r, dr = self._rho(T)
        return u, du, r, dr

    def liq_T(self, u: float, T: float) -> float:
        for _ in range(60):
            f, d = self._u(T)
            dT = (f - u) / d
            T -= dT
            if abs(dT) < 1e-12 * T:
                return T
        raise SimulationError(f"liquid temperature did not converge (u = {u})")

    def gas_rT(self, rho: float, T: float) -> tuple[float, float, float, float]:
        """Vapour p, u, cv, h at (rho, T) (HEOS, imposed gas phase)."""
        g = self.gas
        try:
            g.update(CP.DmassT_INPUTS, rho, T)
        except ValueError as e:
            raise SimulationError(f"{self.name} gas state rho={rho:.4g}, T={T:.4g}: {e}") from None
        return g.p(), g.umass(), g.cvmass(), g.hmass()

    def gas_rho_pT(self, p: float, T: float) -> float:
        g = self.gas
        g.update(CP.PT_INPUTS, p, T)
        return g.rhomass()

    def gas_h_pT(self, p: float, T: float) -> float:
        g = self.gas
        g.update(CP.PT_INPUTS, p, T)
        return g.hmass()

    def transport(self, p: float, T_l: float, T_v: float) -> dict[str, float]:
        a = self._tp
        a.update(CP.QT_INPUTS, 0.0, min(T_l, self.T_hi))
        liq = {"k": a.conductivity(), "mu": a.viscosity(), "cp": a.cpmass(), "rho": a.rhomass(),
               "beta": a.isobaric_expansion_coefficient()}
        a.specify_phase(CP.iphase_gas)
        a.update(CP.PT_INPUTS, p, T_v)
        vap = {"k": a.conductivity(), "mu": a.viscosity(), "cp": a.cpmass(), "rho": a.rhomass()}
        a.unspecify_phase()
        return {"liq": liq, "vap": vap}


_FLUID_CACHE: dict[str, Fluid] = {}


def get_fluid(name: str) -> Fluid:
    if name not in _FLUID_CACHE:
        _FLUID_CACHE[name] = Fluid(name)
    return _FLUID_CACHE[name]


# ----------------------------------------------------------------------------- geometry
class Geometry:
    """Exact tank geometry: liquid volume, interface area, wall area below a height."""

    def __init__(self, tank: Mapping[str, Any]):
        self.shape = tank["shape"]
        R = self.R = float(tank["radius_m"])
        pi = math.pi
        if self.shape == "vertical_cylinder":
            self.H = float(tank["height_m"])
            self.V = pi * R * R * self.H
            self.bottom, self.top = pi * R * R, pi * R * R
            self.A = 2 * pi * R * self.H + 2 * pi * R * R
        elif self.shape == "sphere":
            self.H = 2 * R
            self.V = 4.0 / 3.0 * pi * R ** 3
            self.bottom = self.top = 0.0
            self.A = 4 * pi * R * R
        elif self.shape == "horizontal_cylinder":
            self.L = float(tank["cylinder_length_m"])
            self.H = 2 * R
            self.V = pi * R * R * self.L
            self.bottom = self.top = 0.0
            self.A = 2 * pi * R * self.L + 2 * pi * R * R
        elif self.shape == "vertical_cylinder_elliptical_heads":
            self.Lc = float(tank["cylinder_length_m"])
            self.d = R / float(tank["head_aspect"])
            self.H = self.Lc + 2 * self.d
            self.Vh = 2.0 / 3.0 * pi * R * R * self.d
            self.V = 2 * self.Vh + pi * R * R * self.Lc
            self.bottom = self.top = 0.0
            t = np.linspace(0.0, pi / 2, 4001)
            dA = 2 * pi * R * np.sin(t) * np.sqrt((R * np.cos(t)) ** 2 + (self.d * np.sin(t)) ** 2)
            ds = np.sqrt((R * np.cos(t)) ** 2 + (self.d * np.sin(t)) ** 2)
            self._hz = self.d * (1 - np.cos(t))
            self._hA = np.concatenate([[0.0], np.cumsum(0.5 * (dA[1:] + dA[:-1]) * np.diff(t))])
            self._hs = np.concatenate([[0.0], np.cumsum(0.5 * (ds[1:] + ds[:-1]) * np.diff(t))])
            self.Ah = float(self._hA[-1])
            self.A = 2 * self.Ah + 2 * pi * R * self.Lc
        else:
            raise ValueError(f"unknown tank shape {self.shape!r}")
        if "volume_m3" in tank and tank["volume_m3"] is not None and abs(tank["volume_m3"] / self.V - 1) > 0.01:
            raise ValueError("tank.volume_m3 disagrees with the shape")
        self.edges = np.linspace(0.0, self.H, N_BANDS + 1)
        cum = [0.0] + [self.Fw(float(z)) for z in self.edges[1:-1]] + [self.A]
        self.cum = np.array(cum)
        self.band_A = np.diff(self.cum)
        s = np.array([self.arc(float(z)) for z in self.edges])
        self.band_s = np.maximum(np.diff(s), 1e-3)
        self.band_zc = 0.5 * (self.edges[1:] + self.edges[:-1])

    # liquid volume below h and its derivative (the cross-section)
    def vol(self, h: float) -> tuple[float, float]:
        R, pi = self.R, math.pi
        h = min(max(h, 0.0), self.H)
        if self.shape == "vertical_cylinder":
            return pi * R * R * h, pi * R * R
        if self.shape == "sphere":
            return pi * h * h * (3 * R - h) / 3.0, pi * h * (2 * R - h)
        if self.shape == "horizontal_cylinder":
            y = R - h
            w = math.sqrt(max(2 * R * h - h * h, 0.0))
            return self.L * (R * R * math.acos(max(-1.0, min(1.0, y / R))) - y * w), 2 * self.L * w
        d = self.d
        if h <= d:
            return pi * R * R / (d * d) * (d * h * h - h ** 3 / 3.0), pi * R * R / (d * d) * (2 * d * h - h * h)
        if h <= d + self.Lc:
            return self.Vh + pi * R * R * (h - d), pi * R * R
        v, a = self.vol(self.H - h)
        return self.V - v, a

    def level(self, V: float, guess: float | None = None) -> float:
        V = min(max(V, 0.0), self.V)
        lo, hi = 0.0, self.H
        h = guess if guess is not None and 0.0 < guess < self.H else self.H * V / self.V
        for _ in range(100):
            f, a = self.vol(h)
            f -= V
            if f > 0:
                hi = h
            else:
                lo = h
            hn = h - f / a if a > 0 else 0.5 * (lo + hi)
            if not (lo < hn < hi):
                hn = 0.5 * (lo + hi)
            if abs(hn - h) < 1e-14 * self.H:
                return hn
            h = hn
        return h

    def area_x(self, h: float) -> float:
        return self.vol(h)[1]

    def Fw(self, z: float) -> float:
        """Wall area below z (bottom end included, top end excluded)."""
        R, pi = self.R, math.pi
        z = min(max(z, 0.0), self.H)
        if self.shape == "vertical_cylinder":
            return self.bottom + 2 * pi * R * z
        if self.shape == "sphere":
            return 2 * pi * R * z
        if self.shape == "horizontal_cylinder":
            y = R - z
            w = math.sqrt(max(2 * R * z - z * z, 0.0))
            th = math.acos(max(-1.0, min(1.0, y / R)))
            return 2 * R * self.L * th + 2 * (R * R * th - y * w)
        d = self.d
        if z <= d:
            return float(np.interp(z, self._hz, self._hA))
        if z <= d + self.Lc:
            return self.Ah + 2 * pi * R * (z - d)
        return self.A - float(np.interp(self.H - z, self._hz, self._hA))

    def arc(self, z: float) -> float:
        """Meridian arc length of the wall from the bottom to height z."""
        R = self.R
        if self.shape == "vertical_cylinder":
            return z
        if self.shape in ("sphere", "horizontal_cylinder"):
            return R * math.acos(max(-1.0, min(1.0, (R - z) / R)))
        d = self.d
        hs = float(self._hs[-1])
        if z <= d:
            return float(np.interp(z, self._hz, self._hs))
        if z <= d + self.Lc:
            return hs + (z - d)
        return 2 * hs + self.Lc - float(np.interp(self.H - z, self._hz, self._hs))

    def band_split(self, z: float) -> np.ndarray:
        """Area of each band below height z."""
        c = self.Fw(z) if z < self.H else self.A
        return np.clip(c - self.cum[:-1], 0.0, self.band_A)


# ----------------------------------------------------------------------------- correlations
def _churchill_chu(dT: np.ndarray, L: float, k: float, nu: float, alpha: float, beta: float, Pr: float) -> np.ndarray:
    """h [W/m2K] of a vertical plate of height L (Churchill & Chu 1975, whole range)."""
    L = max(L, 0.02)
    Ra = G * beta * np.sqrt(dT * dT + EPS_T * EPS_T) * L ** 3 / (nu * alpha)
    Nu = (0.825 + 0.387 * Ra ** (1.0 / 6.0) / (1.0 + (0.492 / Pr) ** (9.0 / 16.0)) ** (8.0 / 27.0)) ** 2
    return Nu * k / L


def _horizontal(dT_stable: float, dT_unstable: float, L: float, k: float, nu: float, alpha: float,
                beta: float) -> float:
    """Horizontal surface: stable 0.27 Ra^1/4 (plus conduction), unstable 0.15 Ra^1/3."""
    c = G * beta * L ** 3 / (nu * alpha)
    Nu = 1.0 + 0.27 * (c * _sp(dT_stable)) ** 0.25 + 0.15 * (c * _sp(dT_unstable)) ** (1.0 / 3.0)
    return Nu * k / L


# ----------------------------------------------------------------------------- model
Y_MB, Y_UB, Y_MS, Y_US, Y_M1, Y_U1, Y_N1, Y_M2, Y_U2, Y_N2 = range(10)
Y_W = 10
Y_QM = Y_W + N_BANDS
Y_QE = Y_QM + 1
N_Y = Y_QE + 1


def _zero_inputs() -> dict[str, float]:
    return {c: 0.0 for c in INPUT_COLUMNS}


class Model:
    def __init__(self, sc: Mapping[str, Any], mech: Mapping[str, float]):
        self.sc = sc
        self.mech = {k: float(mech.get(k, 0.0)) for k in MECHANISMS}
        fl = self.fl = get_fluid(sc["fluid"])
        geo = self.geo = Geometry(sc["tank"])
        wall = sc["wall"]
        self.C_meta = float(wall["C_w_J_per_K"])
        self.C_w = self.C_meta * (1.0 + self.mech["wall_heat_capacity_error"])
        self.C_band = self.C_w * geo.band_A / geo.A
        kt = float(wall["k_W_per_mK"]) * float(wall["thickness_m"])
        A, s = geo.band_A, geo.band_s
        self.G_cond = 2.0 * kt * (A[1:] + A[:-1]) / (s[1:] + s[:-1]) ** 2
        self.sigma = float(sc["sigma"])
        self.K_hks = 2 * self.sigma / (2 - self.sigma) * fl.hks
        self.spray = bool(sc.get("spray", False))
        ini = sc["initial"]
        tr = fl.transport(ini["p_Pa"], ini["T_l_K"], ini["T_v_K"])
        L_, V_ = tr["liq"], tr["vap"]
        self.liq_tp = {"k": L_["k"], "nu": L_["mu"] / L_["rho"], "alpha": L_["k"] / (L_["rho"] * L_["cp"]),
                       "beta": max(L_["beta"], 1e-4), "Pr": L_["mu"] * L_["cp"] / L_["k"]}
        self.vap_tp = {"k": V_["k"], "nu": V_["mu"] / V_["rho"], "alpha": V_["k"] / (V_["rho"] * V_["cp"]),
                       "Pr": V_["mu"] * V_["cp"] / V_["k"]}
        self.transport = tr
        self.nfev = 0
        self._Tg = [ini["T_v_K"], ini["T_v_K"]]
        self._h = None
        self.y0 = self._initial_state()

    # ---- initial state
    def _initial_state(self) -> np.ndarray:
        fl, geo, ini = self.fl, self.geo, self.sc["initial"]
        p0, Tl, Tv, Tw = float(ini["p_Pa"]), float(ini["T_l_K"]), float(ini["T_v_K"]), float(ini["T_w_K"])
        Vl = float(ini["fill_ratio"]) * geo.V
        u, _, rho, _ = fl.liq(Tl)
        h = geo.level(Vl)
        ms = min(rho * geo.area_x(h) * DELTA_LAYER, 0.15 * rho * Vl)
        m_l = rho * Vl
        y = np.zeros(N_Y)
        y[Y_MB], y[Y_UB], y[Y_MS], y[Y_US] = m_l - ms, (m_l - ms) * u, ms, ms * u
        Vv = geo.V - Vl
        dz = min(0.4 * max(Tv - Tl, 0.0), 3.0)
        Ts = (Tv - dz * (1 - PHI_LOWER), Tv + dz * PHI_LOWER)
        n_he = self.mech["helium_mol"]
        for k, (Vk, Tk) in enumerate(((PHI_LOWER * Vv, Ts[0]), ((1 - PHI_LOWER) * Vv, Ts[1]))):
            nk = n_he * Vk / Vv
            pf = p0 - nk * R_GAS * Tk / Vk
            if pf < 0.3 * p0:
                raise ValueError(f"helium_mol={n_he}: too little {fl.name} left in the ullage")
            if Tk < fl.Tsat(pf):
                Tk = fl.Tsat(pf) + 0.05
            rho_v = fl.gas_rho_pT(pf, Tk)
            _, uv, _, _ = fl.gas_rT(rho_v, Tk)
            m = rho_v * Vk
            base = (Y_M1, Y_U1, Y_N1) if k == 0 else (Y_M2, Y_U2, Y_N2)
            y[base[0]], y[base[1]], y[base[2]] = m, m * uv + 1.5 * nk * R_GAS * Tk, nk
            self._Tg[k] = Tk
        # wall: wetted bands at T_l, rising above the level so that the area mean is T_w
        sh = np.maximum(0.0, (geo.band_zc - h) / max(geo.H - h, 1e-6))
        ms_ = float(np.sum(sh * geo.band_A) / geo.A)
        a = (Tw - Tl) / ms_ if ms_ > 1e-9 else 0.0
        a = min(a, 3.0 * max(Tv - Tl, 0.5))
        y[Y_W:Y_W + N_BANDS] = Tl + a * sh
        return y

    # ---- state decoding
    def _zone(self, k: int, m: float, U: float, n: float, V: float) -> dict[str, float]:
        fl = self.fl
        rho = m / V
        T = self._Tg[k]
        c_he = 1.5 * n * R_GAS
        for _ in range(60):
            p, u, cv, hh = fl.gas_rT(rho, T)
            f = m * u + c_he * T - U
            dT = f / (m * cv + c_he)
            T -= dT
            if T <= 0.5 * fl.T_trip:
                raise SimulationError(f"ullage zone temperature {T:.4g} K below range")
            if abs(dT) < 1e-12 * T:
                break
        p, u, cv, hh = fl.gas_rT(rho, T)
        self._Tg[k] = T
        p_he = n * R_GAS * T / V
        mt = m + n * M_HE
        return {"T": T, "m": m, "n": n, "V": V, "rho": rho, "p_f": p, "p_he": p_he, "p": p + p_he, "u": u,
                "cv": cv, "h_f": hh, "mt": mt, "y_f": m / mt, "y_n": n / mt,
                "h_mix": (m * hh + 2.5 * n * R_GAS * T) / mt}

    def decode(self, y: np.ndarray) -> dict[str, Any]:
        fl, geo = self.fl, self.geo
        mb, ms = y[Y_MB], y[Y_MS]
        if mb <= 0 or ms <= 0 or y[Y_M1] <= 0 or y[Y_M2] <= 0:
            raise SimulationError("a control volume emptied")
        Tb = fl.liq_T(y[Y_UB] / mb, self.sc["initial"]["T_l_K"])
        Ts = fl.liq_T(y[Y_US] / ms, Tb)
        ub, cb, rb, drb = fl.liq(Tb)
        us, cs, rs, drs = fl.liq(Ts)
        Vl = mb / rb + ms / rs
        Vv = geo.V - Vl
        if Vv <= 1e-4 * geo.V:
            raise SimulationError("tank overfilled")
        h = geo.level(Vl, self._h)
        self._h = h
        z1 = self._zone(0, y[Y_M1], y[Y_U1], y[Y_N1], PHI_LOWER * Vv)
        z2 = self._zone(1, y[Y_M2], y[Y_U2], y[Y_N2], (1 - PHI_LOWER) * Vv)
        zb = geo.level(Vl + PHI_LOWER * Vv)
        return {"Tb": Tb, "Ts": Ts, "b": (ub, cb, rb, drb), "s": (us, cs, rs, drs), "Vl": Vl, "Vv": Vv, "h": h,
                "zb": zb, "z1": z1, "z2": z2}

    # ---- right-hand side
    def rhs(self, t: float, y: np.ndarray, inp: Mapping[str, float]) -> np.ndarray:
        self.nfev += 1
        fl, geo, mech = self.fl, self.geo, self.mech
        d = self.decode(y)
        z1, z2 = d["z1"], d["z2"]
        Tb, Ts, h = d["Tb"], d["Ts"], d["h"]
        ub, cb, rb, drb = d["b"]
        us, cs, rs, drs = d["s"]
        p = z1["p"]
        Tw = y[Y_W:Y_W + N_BANDS]
        dy = np.zeros(N_Y)
        Ai = max(geo.area_x(h), 1e-4)
        # per-volume accumulators: [mass fluid, energy, helium]
        Fb = [0.0, 0.0]
        Fs = [0.0, 0.0]
        Z = [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]
        qm = qe = 0.0

        def mix_flow(mdot: float, src: int, dst: int | None):
            zs = (z1, z2)[src]
            a, e, n = mdot * zs["y_f"], mdot * zs["h_mix"], mdot * zs["y_n"]
            Z[src][0] -= a
            Z[src][1] -= e
            Z[src][2] -= n
            if dst is not None:
                Z[dst][0] += a
                Z[dst][1] += e
                Z[dst][2] += n
            return a + n * M_HE, e

        # sloshing
        A0, f0 = inp["slosh_amplitude_m"], inp["slosh_frequency_Hz"]
        Af = A0 * f0
        Fsl = 1.0 + C_SLOSH * (Af / math.sqrt(G * geo.R)) ** N_SLOSH if Af > 0 else 1.0
        # liquid enthalpies at the ullage pressure
        hb = ub + p / rb
        hs = us + p / rs
        # interface (kinetic) -------------------------------------------------------
        T_ref = fl.Tsat(z1["p_f"])
        Lc = max(math.sqrt(Ai) / 2, 0.05)
        vt, lt = self.vap_tp, self.liq_tp
        hv = _horizontal(z1["T"] - T_ref, T_ref - z1["T"], Lc, vt["k"], vt["nu"], vt["alpha"], 1.0 / z1["T"])
        hl = Fsl * _horizontal(T_ref - Ts, Ts - T_ref, Lc, lt["k"], lt["nu"], lt["alpha"], lt["beta"])
        _, _, _, hg_ref = fl.gas_rT(z1["rho"], T_ref)
        ul_r, _, rl_r, _ = fl.liq(T_ref)
        Lat = hg_ref - (ul_r + p / rl_r)
        KA = self.K_hks * Ai
        pv_term = z1["p_f"] / math.sqrt(z1["T"])
        Ti = T_ref
        lo, hi = fl.T_trip * 0.9, fl.T_crit
        for _ in range(80):
            ps, dps = fl.psat(Ti)
            sq = math.sqrt(Ti)
            md = KA * (ps / sq - pv_term)
            f = hv * Ai * (z1["T"] - Ti) + hl * Ai * (Ts - Ti) - md * Lat
            if f > 0:
                lo = Ti
            else:
                hi = Ti
            df = -(hv + hl) * Ai - KA * Lat * (dps / sq - 0.5 * ps / (Ti * sq))
            Tn = Ti - f / df
            if not (lo < Tn < hi):
                Tn = 0.5 * (lo + hi)
            if abs(Tn - Ti) < 1e-12 * Ti:
                Ti = Tn
                break
            Ti = Tn
        ps, _ = fl.psat(Ti)
        m_i = KA * (ps / math.sqrt(Ti) - pv_term)         # evaporation > 0
        uli, _, rli, _ = fl.liq(Ti)
        h_gi = uli + p / rli + Lat
        q_vi = hv * Ai * (z1["T"] - Ti)
        e_i = m_i * h_gi - q_vi                           # energy into the lower zone
        Z[0][0] += m_i
        Z[0][1] += e_i
        Fs[0] -= m_i
        Fs[1] -= e_i
        self._last_interface = (Ti, m_i)
        # wall --------------------------------------------------------------------
        a_l = geo.band_split(h)
        a_1 = geo.band_split(d["zb"]) - a_l
        a_2 = geo.band_A - a_l - a_1
        Hv = geo.H - h
        h_wl = Fsl * _churchill_chu(Tw - Tb, h, lt["k"], lt["nu"], lt["alpha"], lt["beta"], lt["Pr"])
        h_w1 = _churchill_chu(Tw - z1["T"], d["zb"] - h, vt["k"], vt["nu"], vt["alpha"], 1.0 / z1["T"], vt["Pr"])
        h_w2 = _churchill_chu(Tw - z2["T"], geo.H - d["zb"], vt["k"], vt["nu"], vt["alpha"], 1.0 / z2["T"],
                              vt["Pr"])
        q_l = h_wl * a_l * (Tw - Tb)
        q_1 = h_w1 * a_1 * (Tw - z1["T"])
        q_2 = h_w2 * a_2 * (Tw - z2["T"])
        Q_amb = (inp["Q_aw_W"] + mech["heat_leak_wall_W"]) * geo.band_A / geo.A
        qm_w = np.zeros(N_BANDS)
        cond = self.G_cond * (Tw[1:] - Tw[:-1])
        qm_w[:-1] += cond
        qm_w[1:] -= cond
        dy[Y_W:Y_W + N_BANDS] = (Q_amb - q_l - q_1 - q_2 + qm_w) / self.C_band
        QL = float(np.sum(q_l))
        Fb[1] += (1 - CHI_LAYER) * QL
        Fs[1] += CHI_LAYER * QL
        Z[0][1] += float(np.sum(q_1))
        Z[1][1] += float(np.sum(q_2))
        qe += inp["Q_aw_W"] + mech["heat_leak_wall_W"]
        # hidden heat leaks
        Fb[1] += mech["heat_leak_liquid_W"]
        Z[0][1] += PHI_LOWER * mech["heat_leak_vapor_W"]
        Z[1][1] += (1 - PHI_LOWER) * mech["heat_leak_vapor_W"]
        qe += mech["heat_leak_liquid_W"] + mech["heat_leak_vapor_W"]
        # layer <-> bulk ------------------------------------------------------------
        m_e = rb * Ai * DELTA_LAYER / TAU_LAYER
        m_m = y[Y_MS] * (1.0 / TAU_LAYER + K_SLOSH_MIX * Af ** 1.5)
        delta = max(y[Y_MS] / (rs * Ai), 1e-3)
        q_sb = lt["k"] * Ai * (Ts - Tb) / (0.5 * delta)
        Fb[0] += m_m - m_e
        Fs[0] += m_e - m_m
        Fb[1] += m_m * hs - m_e * hb + q_sb
        Fs[1] += m_e * hb - m_m * hs - q_sb
        # bulk boiling (superheat over T_sat of the total pressure) ------------------
        T_sat_p = fl.Tsat(p)
        _, _, _, hg_sat = fl.gas_rT(z1["rho"], T_sat_p)
        u_sat, _, r_sat, _ = fl.liq(T_sat_p)
        L_sat = max(hg_sat - (u_sat + p / r_sat), 1e3)
        for F, m_j, c_j, T_j in ((Fb, y[Y_MB], cb, Tb), (Fs, y[Y_MS], cs, Ts)):
            mb_ = m_j * c_j * _sp(T_j - T_sat_p) / (L_sat * TAU_BOIL)
            F[0] -= mb_
            F[1] -= mb_ * hg_sat
            Z[0][0] += mb_
            Z[0][1] += mb_ * hg_sat
        # fog in either zone -------------------------------------------------------
        for k, zk in enumerate((z1, z2)):
            Tsk = fl.Tsat(zk["p_f"])
            _, _, _, hgk = fl.gas_rT(zk["rho"], Tsk)
            uk, _, rk, _ = fl.liq(Tsk)
            Lk = max(hgk - (uk + p / rk), 1e3)
            mf = zk["m"] * zk["cv"] * _sp(Tsk - zk["T"]) / (Lk * TAU_FOG)
            hfk = uk + p / rk                  # fog droplets form at saturation of the partial pressure
            Z[k][0] -= mf
            Z[k][1] -= mf * hfk
            Fs[0] += mf
            Fs[1] += mf * hfk
        # ullage zone exchange ------------------------------------------------------
        K_eq = 1.0 / (TAU_EQ * p * (1.0 / z1["mt"] + 1.0 / z2["mt"]))
        m_eq = K_eq * (z2["p"] - z1["p"])              # > 0: from the upper into the lower zone
        th = 0.5   # central: the equalising flow is tiny, and upwinding it chatters (sliding mode)
        for k, wk in ((0, 1.0 - th), (1, th)):
            zs = (z1, z2)[k]
            a, e, n = m_eq * wk * zs["y_f"], m_eq * wk * zs["h_mix"], m_eq * wk * zs["y_n"]
            Z[0][0] += a
            Z[0][1] += e
            Z[0][2] += n
            Z[1][0] -= a
            Z[1][1] -= e
            Z[1][2] -= n
        Ab = max(geo.area_x(d["zb"]), 1e-4)
        Tm = 0.5 * (z1["T"] + z2["T"])
        dT12 = z1["T"] - z2["T"]
        w = 5e-4 / (1.0 + 0.5 * _sp(-dT12, 0.05)) + 0.05 * math.sqrt(G * max(Hv, 0.01) * _sp(dT12, 0.05) / Tm) \
            + 0.5 * Af
        m_x = 0.5 * (z1["rho"] + z2["rho"]) * Ab * w
        mix_flow(m_x, 0, 1)
        mix_flow(m_x, 1, 0)
        # operations ----------------------------------------------------------------
        bias = 1.0 + mech["inflow_meter_bias"]
        if inp["mdot_v_in_kg_s"] > 0:
            mv = bias * inp["mdot_v_in_kg_s"]
            hin = self._h_vin
            Z[1][0] += mv
            Z[1][1] += mv * hin
            qm += mv
            qe += mv * hin
        if inp["mdot_v_out_kg_s"] > 0:
            mt, e = mix_flow(inp["mdot_v_out_kg_s"], 1, None)
            qm -= mt
            qe -= e
        if mech["vapor_leak_kg_s"] > 0:
            mt, e = mix_flow(mech["vapor_leak_kg_s"], 1, None)
            qm -= mt
            qe -= e
        if inp["mdot_l_in_kg_s"] > 0:
            ml = bias * inp["mdot_l_in_kg_s"]
            Tin = inp["T_l_in_K"]
            uin, cin, rin, _ = fl.liq(Tin)
            hin = uin + p / rin
            qm += ml
            qe += ml * hin
            if self.spray:
                T1s = fl.Tsat(z1["p_f"])
                u1s, _, r1s, _ = fl.liq(T1s)
                mc = SPRAY_EFF * ml * cin * _sp(T1s - Tin) / max(z1["h_f"] - (u1s + p / r1s), 1e3)
                Z[0][0] -= mc
                Z[0][1] -= mc * z1["h_f"]
                Fs[0] += ml + mc
                Fs[1] += ml * hin + mc * z1["h_f"]
            else:
                Fb[0] += ml
                Fb[1] += ml * hin
        mout = inp["mdot_l_out_kg_s"] + mech["liquid_leak_kg_s"]
        if mout > 0:
            Fb[0] -= mout
            Fb[1] -= mout * hb
            qm -= mout
            qe -= mout * hb
        # p dV work of the liquid nodes (closed form of the implicit volume rate) ----
        Wtot = 0.0
        for F, m_j, u_j, c_j, r_j, dr_j in ((Fb, y[Y_MB], ub, cb, rb, drb), (Fs, y[Y_MS], us, cs, rs, drs)):
            V_U = -dr_j / (r_j * r_j * c_j)
            V_m = 1.0 / r_j + dr_j * u_j / (r_j * r_j * c_j)
            W = p * (V_m * F[0] + V_U * F[1]) / (1.0 + V_U * p)
            F[1] -= W
            Wtot += W
        Z[0][1] += PHI_LOWER * Wtot
        Z[1][1] += (1 - PHI_LOWER) * Wtot
        dy[Y_MB], dy[Y_UB], dy[Y_MS], dy[Y_US] = Fb[0], Fb[1], Fs[0], Fs[1]
        dy[Y_M1], dy[Y_U1], dy[Y_N1] = Z[0]
        dy[Y_M2], dy[Y_U2], dy[Y_N2] = Z[1]
        dy[Y_QM], dy[Y_QE] = qm, qe
        return dy

    # ---- phase set-up, observation, invariants
    def set_phase(self, inp: Mapping[str, float]) -> None:
        self._h_vin = 0.0
        if inp["mdot_v_in_kg_s"] > 0:
            self._h_vin = self.fl.gas_h_pT(inp["p_v_in_Pa"], inp["T_v_in_K"])

    def observe(self, y: np.ndarray) -> dict[str, float]:
        d = self.decode(y)
        z1, z2 = d["z1"], d["z2"]
        self.rhs(0.0, y, _zero_inputs())
        Ti, mi = self._last_interface
        Vv = d["Vv"]
        mb, ms = y[Y_MB], y[Y_MS]
        Tw = y[Y_W:Y_W + N_BANDS]
        return {"p": (z1["p"] * z1["V"] + z2["p"] * z2["V"]) / Vv,
                "T_v": (z1["mt"] * z1["T"] + z2["mt"] * z2["T"]) / (z1["mt"] + z2["mt"]),
                "T_l": (mb * d["Tb"] + ms * d["Ts"]) / (mb + ms),
                "T_w": float(np.sum(self.C_band * Tw) / np.sum(self.C_band)),
                "level": d["h"], "fill": d["Vl"] / self.geo.V,
                "p_f": (z1["p_f"] * z1["V"] + z2["p_f"] * z2["V"]) / Vv,
                "p_he": (z1["p_he"] * z1["V"] + z2["p_he"] * z2["V"]) / Vv,
                "T_v1": z1["T"], "T_v2": z2["T"], "p_1": z1["p"], "p_2": z2["p"], "T_lb": d["Tb"], "T_ls": d["Ts"],
                "T_i": Ti, "mdot_i": mi, "T_sat_pf1": self.fl.Tsat(z1["p_f"]), "m_l": mb + ms, "m_layer": ms,
                "m_v": z1["m"] + z2["m"], "n_he": z1["n"] + z2["n"], "T_w_bottom": float(Tw[0]),
                "T_w_top": float(Tw[-1])}

    def totals(self, y: np.ndarray) -> tuple[float, float]:
        M = y[Y_MB] + y[Y_MS] + y[Y_M1] + y[Y_M2] + M_HE * (y[Y_N1] + y[Y_N2])
        E = y[Y_UB] + y[Y_US] + y[Y_U1] + y[Y_U2] + float(np.sum(self.C_band * y[Y_W:Y_W + N_BANDS]))
        return M, E


# ----------------------------------------------------------------------------- integration
def _p_limits(fluid: str) -> tuple[float, float]:
    return P_LIMITS.get(fluid, P_LIMITS_OTHER)


def _integrate(model: Model, plan: list[dict[str, Any]], guards: bool, duration: float) -> dict[str, Any]:
    y = model.y0.copy()
    M0, _ = model.totals(y)
    scale = np.empty(N_Y)
    scale[[Y_MB, Y_MS, Y_M1, Y_M2]] = M0
    scale[[Y_UB, Y_US, Y_U1, Y_U2]] = M0 * 1e4
    scale[[Y_N1, Y_N2]] = max(model.mech["helium_mol"], 1e-3)
    scale[Y_W:Y_W + N_BANDS] = 1e2
    scale[Y_QM], scale[Y_QE] = M0 * 1e2, M0 * 1e6
    atol = 1e-10 * scale
    p_lo, p_hi = _p_limits(model.sc["fluid"])
    p_hi_g, p_lo_g = 0.95 * p_hi, 1.1 * p_lo
    p_close = p_hi_g - 0.1 * (p_hi_g - p_lo_g)
    grid = np.arange(0.0, duration + 1e-9, SAMPLE_DT_S)
    ys = {0.0: y.copy()}
    executed, changes = [], []
    queue = [dict(s) for s in plan]
    n_split = 0
    while queue:
        seg = queue.pop(0)
        t0, t1, inp, kind = seg["t0"], seg["t1"], seg["inputs"], seg["kind"]
        if t1 <= t0 + 1e-9:
            continue
        model.set_phase(inp)
        events, actions = [], []
        if guards and n_split < 40:
            def ev_p(t, yy, thr):
                return model.observe_p(yy) - thr
            if kind not in ("vent", "relief"):
                f = (lambda t, yy: ev_p(t, yy, p_hi_g))
                f.terminal, f.direction = True, 1.0
                events.append(f)
                actions.append("p_high")
            if kind in ("vent", "drain"):
                f = (lambda t, yy: ev_p(t, yy, p_lo_g))
                f.terminal, f.direction = True, -1.0
                events.append(f)
                actions.append("p_low")
            if kind == "relief":
                f = (lambda t, yy: ev_p(t, yy, p_close))
                f.terminal, f.direction = True, -1.0
                events.append(f)
                actions.append("relief_closed")
            if kind == "fill":
                f = (lambda t, yy: model.observe_fill(yy) - 0.92)
                f.terminal, f.direction = True, 1.0
                events.append(f)
                actions.append("fill_high")
            if kind == "drain":
                f = (lambda t, yy: model.observe_fill(yy) - 0.10)
                f.terminal, f.direction = True, -1.0
                events.append(f)
                actions.append("fill_low")
        te = grid[(grid > t0 + 1e-9) & (grid < t1 - 1e-9)]
        te = np.concatenate([te, [t1]])
        sol = solve_ivp(lambda t, yy: model.rhs(t, yy, inp), (t0, t1), y, method="LSODA", rtol=1e-8, atol=atol,
                        t_eval=te, events=events or None, max_step=60.0)
        if sol.status < 0:
            raise SimulationError(f"integration failed in {kind} at t={t0}: {sol.message}")
        for t, col in zip(sol.t, sol.y.T):
            if abs(t / SAMPLE_DT_S - round(t / SAMPLE_DT_S)) < 1e-9:
                ys[float(round(t, 6))] = col.copy()
        if sol.status == 1:
            i = next(k for k, e in enumerate(sol.t_events) if len(e))
            t_ev, y = float(sol.t_events[i][0]), sol.y_events[i][0].copy()
            executed.append({**seg, "t1": t_ev})
            base = {c: 0.0 for c in INPUT_COLUMNS}
            base["Q_aw_W"] = inp["Q_aw_W"]
            base["slosh_amplitude_m"], base["slosh_frequency_Hz"] = inp["slosh_amplitude_m"], inp["slosh_frequency_Hz"]
            if actions[i] == "p_high":
                o = model.observe(y)
                base["mdot_v_out_kg_s"] = 0.2 * (o["m_v"] + M_HE * o["n_he"]) / 300.0
                new_kind = "relief"
            else:
                new_kind = "rest"
            changes.append({"t_s": t_ev, "event": actions[i], "from": kind, "to": new_kind})
            queue.insert(0, {"t0": t_ev, "t1": t1, "kind": new_kind, "inputs": base})
            n_split += 1
        else:
            y = sol.y[:, -1].copy()
            executed.append(dict(seg))
    return {"ys": ys, "executed": executed, "changes": changes, "y_end": y}


def _observe_p(self: Model, y: np.ndarray) -> float:
    d = self.decode(y)
    return (d["z1"]["p"] * d["z1"]["V"] + d["z2"]["p"] * d["z2"]["V"]) / d["Vv"]


def _observe_fill(self: Model, y: np.ndarray) -> float:
    rb = self.fl.liq(self.fl.liq_T(y[Y_UB] / y[Y_MB], self.sc["initial"]["T_l_K"]))[2]
    rs = self.fl.liq(self.fl.liq_T(y[Y_US] / y[Y_MS], self.sc["initial"]["T_l_K"]))[2]
    return (y[Y_MB] / rb + y[Y_MS] / rs) / self.geo.V


Model.observe_p = _observe_p
Model.observe_fill = _observe_fill


# ----------------------------------------------------------------------------- scenarios
def _wall(material: str, C_w: float, area: float, cold: bool) -> dict[str, Any]:
    m = WALL_MATERIALS[material]
    c = m["c_cold"] if cold else m["c_warm"]
    k = m["k_cold"] if cold else m["k_warm"]
    t = C_w / (area * m["rho"] * c)
    t = min(max(t, 1e-3), 0.08)
    return {"material": material, "thickness_m": t, "k_W_per_mK": k, "C_w_J_per_K": C_w,
            "note": "C_w includes attached structure; thickness = C_w / (A rho c_nominal), clipped to 1-80 mm"}


def _phase(kind: str, dur: float, **kw: float) -> dict[str, Any]:
    return {"kind": kind, "duration_s": dur, **kw}


def _named(name: str) -> dict[str, Any]:
    if name == "lh2_sphere_spray":
        tank = {"shape": "sphere", "radius_m": (3 * 5.0 / (4 * math.pi)) ** (1 / 3)}
        return {"name": name, "fluid": "ParaHydrogen", "tank": tank, "wall_material": "aluminium", "C_w": 1.5e5,
                "sigma": 5e-3, "spray": True, "Q_aw_W": 40.0,
                "initial": {"p_Pa": 1.4e5, "T_l_K": 20.6, "T_v_K": 24.0, "T_w_K": 22.0, "fill_ratio": 0.5},
                "phases": [_phase("rest", 600), _phase("pressurize", 900, mdot_v_in_kg_s=2.5e-3, T_v_in_K=60.0,
                                                       p_v_in_Pa=4e5),
                           _phase("fill", 900, mdot_l_in_kg_s=0.05, T_l_in_K=20.0),
                           _phase("vent", 600, mdot_v_out_kg_s=1.5e-3),
                           _phase("slosh", 900, slosh_amplitude_m=0.02, slosh_frequency_Hz=0.7),
                           _phase("rest", 300)]}
    if name == "lh2_upright_drain":
        R, d = 1.35, 0.675
        Lc = (20.0 - 4.0 / 3.0 * math.pi * R * R * d) / (math.pi * R * R)
        tank = {"shape": "vertical_cylinder_elliptical_heads", "radius_m": R, "cylinder_length_m": Lc,
                "head_aspect": 2.0}
        return {"name": name, "fluid": "ParaHydrogen", "tank": tank, "wall_material": "steel", "C_w": 2.0e6,
                "sigma": 2e-3, "spray": False, "Q_aw_W": 80.0,
                "initial": {"p_Pa": 1.2e5, "T_l_K": 20.0, "T_v_K": 25.0, "T_w_K": 22.0, "fill_ratio": 0.8},
                "phases": [_phase("rest", 600),
                           _phase("pressurize", 900, mdot_v_in_kg_s=6e-3, T_v_in_K=80.0, p_v_in_Pa=5e5),
                           _phase("drain", 1200, mdot_l_out_kg_s=0.3, mdot_v_in_kg_s=6e-3, T_v_in_K=80.0,
                                  p_v_in_Pa=5e5),
                           _phase("rest", 900),
                           _phase("slosh", 900, slosh_amplitude_m=0.03, slosh_frequency_Hz=0.5)]}
    if name == "ln2_hcyl":
        R = 0.8
        tank = {"shape": "horizontal_cylinder", "radius_m": R, "cylinder_length_m": 8.0 / (math.pi * R * R)}
        return {"name": name, "fluid": "Nitrogen", "tank": tank, "wall_material": "steel", "C_w": 4e5,
                "sigma": 1e-2, "spray": False, "Q_aw_W": 150.0,
                "initial": {"p_Pa": 1.3e5, "T_l_K": 78.0, "T_v_K": 84.0, "T_w_K": 81.0, "fill_ratio": 0.6},
                "phases": [_phase("rest", 900), _phase("vent", 600, mdot_v_out_kg_s=4e-3),
                           _phase("fill", 900, mdot_l_in_kg_s=1.0, T_l_in_K=77.0), _phase("rest", 600),
                           _phase("drain", 900, mdot_l_out_kg_s=1.3), _phase("rest", 600)]}
    if name == "lh2_light_wall":
        R = 0.55
        tank = {"shape": "vertical_cylinder", "radius_m": R, "height_m": 1.5 / (math.pi * R * R)}
        return {"name": name, "fluid": "ParaHydrogen", "tank": tank, "wall_material": "aluminium", "C_w": 2e4,
                "sigma": 8e-3, "spray": False, "Q_aw_W": 25.0,
                "initial": {"p_Pa": 1.5e5, "T_l_K": 20.5, "T_v_K": 26.0, "T_w_K": 23.0, "fill_ratio": 0.7},
                "phases": [_phase("rest", 600),
                           _phase("pressurize", 600, mdot_v_in_kg_s=7e-4, T_v_in_K=90.0, p_v_in_Pa=4e5),
                           _phase("rest", 600), _phase("vent", 600, mdot_v_out_kg_s=5e-4),
                           _phase("slosh", 900, slosh_amplitude_m=0.01, slosh_frequency_Hz=1.0),
                           _phase("rest", 600)]}
    raise ValueError(f"unknown scenario {name!r}")


NAMED_SCENARIOS = {
    "lh2_sphere_spray": "5 m3 LH2 sphere: heat load, warm-gas pressurisation, top-spray fill, vent, sloshing",
    "lh2_upright_drain": "20 m3 upright LH2 cylinder, 2:1 heads, heavy steel wall: pressurise, drain, rest, slosh",
    "ln2_hcyl": "8 m3 horizontal LN2 cylinder: heat load, vent, bottom fill, drain",
    "lh2_light_wall": "1.5 m3 flat-ended LH2 cylinder, light aluminium wall: pressurise, vent, sloshing",
}


def random_scenario(seed: int, fluid: str | None = None) -> dict[str, Any]:
    rng = np.random.default_rng(seed)
    if fluid is None:
        fluid = str(rng.choice(FLUIDS, p=[0.7, 0.1, 0.1, 0.1]))
    fl = get_fluid(fluid)
    h2 = fluid == "ParaHydrogen"
    shape = str(rng.choice(["vertical_cylinder", "vertical_cylinder_elliptical_heads", "sphere",
                            "horizontal_cylinder"]))
    V = float(math.exp(rng.uniform(math.log(1.0), math.log(60.0))))
    if shape == "sphere":
        tank = {"shape": shape, "radius_m": (3 * V / (4 * math.pi)) ** (1 / 3)}
    elif shape == "vertical_cylinder":
        ar = rng.uniform(1.0, 2.5)                   # H / D
        R = (V / (2 * math.pi * ar)) ** (1 / 3)
        tank = {"shape": shape, "radius_m": R, "height_m": 2 * ar * R}
    elif shape == "horizontal_cylinder":
        ar = rng.uniform(1.5, 4.0)                   # L / D
        R = (V / (2 * math.pi * ar)) ** (1 / 3)
        tank = {"shape": shape, "radius_m": R, "cylinder_length_m": 2 * ar * R}
    else:
        ar, a = rng.uniform(0.5, 2.0), float(rng.choice([1.5, 2.0, 2.0, 3.0]))
        R = (V / (math.pi * (2 * ar + 4.0 / (3.0 * a)))) ** (1 / 3)
        tank = {"shape": shape, "radius_m": R, "cylinder_length_m": 2 * ar * R, "head_aspect": a}
    geo = Geometry(tank)
    V = geo.V
    C_w = float(math.exp(rng.uniform(math.log(1e4), math.log(2e6))) * min(max((geo.A / 30.0) ** 0.5, 0.5), 1.5))
    material = str(rng.choice(["aluminium", "steel"]))
    p_lo, p_hi = _p_limits(fluid)
    p0 = float(rng.uniform(1.1e5, 3.5e5 if h2 else 4.0e5))
    Tsat = fl.Tsat(p0)
    T_l = Tsat - (0.0 if rng.uniform() < 0.3 else rng.uniform(0.1, 1.2 if h2 else 3.0))
    T_v = Tsat + rng.uniform(1.0, 10.0)
    T_w = T_l + rng.uniform(0.3, 0.8) * (T_v - T_l)
    fill = float(rng.uniform(0.2, 0.9))
    area_q = rng.uniform(0.5, 4.0) if h2 else rng.uniform(1.0, 10.0)
    Q_aw = float(area_q * geo.A)
    while True:
        n = int(rng.integers(4, 9))
        durs = rng.uniform(300.0, 1500.0, size=n)
        if 3600.0 <= durs.sum() <= 7200.0:
            break
    phases, f_est = [], fill
    rho_l = fl.liq(T_l)[2]
    p_est = p0
    for dur in durs:
        dur = float(round(dur / 10.0) * 10.0)
        kind = str(rng.choice(["rest", "pressurize", "vent", "fill", "drain", "slosh"]))
        Vv = (1 - f_est) * V
        rho_v = fl.gas_rho_pT(p_est, T_v)
        if kind == "fill" and f_est > 0.75:
            kind = "drain"
        if kind == "drain" and f_est < 0.3:
            kind = "fill" if f_est < 0.75 else "rest"
        if kind == "pressurize" and p_est > 0.6 * p_hi:
            kind = "vent"
        if kind == "vent" and p_est < 1.5 * p_lo:
            kind = "pressurize"
        if kind == "rest":
            phases.append(_phase("rest", dur))
        elif kind == "pressurize":
            dp = rng.uniform(0.3e5, min(1.2e5, 0.7 * p_hi - p_est))
            T_in = Tsat + rng.uniform(15.0, 70.0) if h2 else min(Tsat + rng.uniform(30.0, 150.0), 290.0)
            mdot = 1.5 * dp * Vv * fl.M / (R_GAS * 0.5 * (T_in + T_v)) / dur
            phases.append(_phase("pressurize", dur, mdot_v_in_kg_s=mdot, T_v_in_K=T_in,
                                 p_v_in_Pa=float(min(p_hi, p_est + 2e5))))
            p_est += dp
        elif kind == "vent":
            frac = rng.uniform(0.1, 0.3) * (p_est - 1.2 * p_lo) / p_est
            phases.append(_phase("vent", dur, mdot_v_out_kg_s=frac * rho_v * Vv / dur))
            p_est -= frac * p_est
        elif kind == "fill":
            df = rng.uniform(0.05, min(0.15, 0.85 - f_est))
            phases.append(_phase("fill", dur, mdot_l_in_kg_s=df * V * rho_l / dur,
                                 T_l_in_K=Tsat - rng.uniform(0.3, 1.5 if h2 else 4.0)))
            f_est += df
        elif kind == "drain":
            df = rng.uniform(0.05, min(0.2, f_est - 0.2))
            phases.append(_phase("drain", dur, mdot_l_out_kg_s=df * V * rho_l / dur))
            f_est -= df
        else:
            h = geo.level(f_est * V)
            Rt = float(tank["radius_m"])
            f1 = math.sqrt(1.841 * G / Rt * math.tanh(1.841 * max(h, 0.05) / Rt)) / (2 * math.pi)
            phases.append(_phase("slosh", dur, slosh_amplitude_m=float(rng.uniform(0.005, 0.05)),
                                 slosh_frequency_Hz=float(f1 * rng.uniform(0.7, 1.1))))
    return {"name": f"random_{seed}", "fluid": fluid, "tank": tank, "wall_material": material, "C_w": C_w,
            "sigma": float(math.exp(rng.uniform(math.log(1e-3), math.log(1e-2)))),
            "spray": bool(rng.uniform() < 0.5), "Q_aw_W": Q_aw,
            "initial": {"p_Pa": p0, "T_l_K": float(T_l), "T_v_K": float(T_v), "T_w_K": float(T_w),
                        "fill_ratio": fill},
            "phases": phases}


def resolve_scenario(scenario: str | Mapping[str, Any], fluid: str | None = None) -> dict[str, Any]:
    if isinstance(scenario, str):
        if scenario.startswith("random_"):
            try:
                seed = int(scenario[len("random_"):])
            except ValueError:
                raise ValueError(f"bad random scenario {scenario!r}") from None
            sc = random_scenario(seed, fluid)
        elif scenario in NAMED_SCENARIOS:
            sc = _named(scenario)
            if fluid is not None and fluid != sc["fluid"]:
                raise ValueError(f"scenario {scenario} is defined for {sc['fluid']} only")
        else:
            raise ValueError(f"unknown scenario {scenario!r} (see --list)")
    else:
        sc = json.loads(json.dumps(scenario))
    if "wall" not in sc:
        geo = Geometry(sc["tank"])
        sc["wall"] = _wall(sc.pop("wall_material"), float(sc.pop("C_w")), geo.A, sc["fluid"] == "ParaHydrogen")
        sc["tank"]["volume_m3"] = geo.V
    sc.setdefault("duration_s", float(sum(p["duration_s"] for p in sc["phases"])))
    return sc


def _check_mechanisms(mech: Mapping[str, float] | None) -> dict[str, float]:
    out = {k: 0.0 for k in MECHANISMS}
    for k, v in (mech or {}).items():
        if k not in MECHANISMS:
            raise ValueError(f"unknown mechanism {k!r}; known: {', '.join(MECHANISMS)}")
        out[k] = float(v)
    for k in ("vapor_leak_kg_s", "liquid_leak_kg_s", "helium_mol"):
        if out[k] < 0:
            raise ValueError(f"{k} must be >= 0")
    if out["inflow_meter_bias"] <= -1 or out["wall_heat_capacity_error"] <= -1:
        raise ValueError("inflow_meter_bias and wall_heat_capacity_error must be > -1")
    return out


def _plan(sc: Mapping[str, Any], duration: float) -> list[dict[str, Any]]:
    plan, t0 = [], 0.0
    for ph in sc["phases"]:
        if t0 >= duration - 1e-9:
            break
        inp = {c: float(ph.get(c, 0.0)) for c in INPUT_COLUMNS}
        inp["Q_aw_W"] = float(ph.get("Q_aw_W", sc["Q_aw_W"]))
        t1 = min(t0 + float(ph["duration_s"]), duration)
        plan.append({"t0": t0, "t1": t1, "kind": ph["kind"], "inputs": inp})
        t0 = t1
    if t0 < duration - 1e-9:
        inp = {c: 0.0 for c in INPUT_COLUMNS}
        inp["Q_aw_W"] = float(sc["Q_aw_W"])
        plan.append({"t0": t0, "t1": duration, "kind": "rest", "inputs": inp})
    return plan


_SCHEDULE_CACHE: dict[str, tuple[list, list]] = {}   # mechanism-free executed schedules


def simulate(scenario: str | Mapping[str, Any], mechanisms: Mapping[str, float] | None = None, *,
             fluid_name: str | None = None, duration_s: float | None = None) -> dict[str, Any]:
    """Noise-free truth: scenario, executed schedule, sampled states and observations, closure."""
    w0 = time.perf_counter()
    sc = resolve_scenario(scenario, fluid_name)
    mech = _check_mechanisms(mechanisms)
    duration = float(duration_s if duration_s is not None else sc["duration_s"])
    if duration <= 0:
        raise ValueError("duration must be > 0")
    physical = [k for k in MECHANISMS if k not in ("pressure_sensor_bias_Pa", "temperature_sensor_bias_K")]
    key = json.dumps(sc, sort_keys=True) + f"|{duration!r}"
    nfev = 0
    if key in _SCHEDULE_CACHE and any(mech[k] != 0.0 for k in physical):
        executed, changes = _SCHEDULE_CACHE[key]
    else:
        model = Model(sc, {})
        res = _integrate(model, _plan(sc, duration), True, duration)
        nfev = model.nfev
        executed, changes = res["executed"], res["changes"]
        _SCHEDULE_CACHE[key] = (executed, changes)
    if any(mech[k] != 0.0 for k in physical):
        model = Model(sc, mech)
        res = _integrate(model, executed, False, duration)
        res["changes"] = changes
        nfev += model.nfev
    times = np.array(sorted(res["ys"]))
    Y = np.array([res["ys"][t] for t in times])
    obs = [model.observe(y) for y in Y]
    M0, E0 = model.totals(model.y0)
    err_m = np.array([model.totals(y)[0] - M0 - y[Y_QM] for y in Y])
    err_e = np.array([model.totals(y)[1] - E0 - y[Y_QE] for y in Y])
    moved = sum((s["t1"] - s["t0"]) * sum(s["inputs"][c] for c in ("mdot_v_in_kg_s", "mdot_v_out_kg_s",
                                                                   "mdot_l_in_kg_s", "mdot_l_out_kg_s"))
                for s in res["executed"])
    heat = sum((s["t1"] - s["t0"]) * abs(s["inputs"]["Q_aw_W"]) for s in res["executed"])
    u_scale = abs(model.fl.liq(model.fl.T_nbp)[0]) + model.fl.liq(model.fl.T_nbp)[1] * model.fl.T_nbp
    scale_m = M0 + moved
    scale_e = heat + scale_m * u_scale + abs(E0)
    return {"scenario": sc, "mechanisms": mech, "model": model, "times": times, "Y": Y, "obs": obs,
            "executed": res["executed"], "changes": res["changes"], "duration_s": duration, "nfev": nfev,
            "closure": {"mass_rel": float(np.max(np.abs(err_m)) / scale_m),
                        "energy_rel": float(np.max(np.abs(err_e)) / scale_e),
                        "mass_kg_max_abs": float(np.max(np.abs(err_m))),
                        "energy_J_max_abs": float(np.max(np.abs(err_e))), "mass_scale_kg": scale_m,
                        "energy_scale_J": scale_e},
            "wall_time_s": time.perf_counter() - w0}


# ----------------------------------------------------------------------------- writer
def simulate_run(scenario: str | Mapping[str, Any], mechanisms: Mapping[str, float] | None = None,
                 noise: str = "low", seed: int = 0, out_dir: str | pathlib.Path = ".", name: str | None = None,
                 fluid_name: str | None = None, duration_s: float | None = None,
                 wall_capacity_unknown: bool = False) -> dict[str, pathlib.Path]:
    """Simulate and write NAME.json, NAME.csv, NAME.truth.json, NAME.truth.csv; returns their paths."""
    if noise not in ("none", "low", "high"):
        raise ValueError(f"noise must be none, low or high, got {noise!r}")
    res = simulate(scenario, mechanisms, fluid_name=fluid_name, duration_s=duration_s)
    sc, model, mech, obs, times = res["scenario"], res["model"], res["mechanisms"], res["obs"], res["times"]
    std = NOISE_LEVELS["low" if noise == "none" else noise]
    rng = np.random.default_rng(seed)
    bp, bT = mech["pressure_sensor_bias_Pa"], mech["temperature_sensor_bias_K"]
    sensor = {"p_v_Pa": [o["p"] + bp for o in obs], "T_v_K": [o["T_v"] for o in obs],
              "T_l_K": [o["T_l"] + bT for o in obs], "T_w_K": [o["T_w"] for o in obs],
              "H_l_m": [o["level"] for o in obs]}
    meas: dict[str, dict[float, float]] = {}
    for ch, key in zip(OBS_COLUMNS, NOISE_KEYS):
        dt = SAMPLE_DT_WALL_S if ch == "T_w_K" else SAMPLE_DT_S
        sel = [i for i, t in enumerate(times) if abs(t / dt - round(t / dt)) < 1e-9]
        vals = np.array([sensor[ch][i] for i in sel])
        if noise != "none":
            vals = vals + rng.normal(0.0, std[key], size=vals.size)
        if ch == "H_l_m":
            vals = np.maximum(vals, 0.0)
        meas[ch] = {float(times[i]): float(v) for i, v in zip(sel, vals)}
    ex = res["executed"]
    used = [c for c in INPUT_COLUMNS if any(s["inputs"][c] != 0.0 for s in ex)]
    rows_t = sorted(set(float(t) for t in times) | {float(s["t0"]) for s in ex})
    run = name or f"kin_{sc['name']}"
    out = pathlib.Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    csv_path = out / f"{run}.csv"
    with open(csv_path, "w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(["t_s", *OBS_COLUMNS, *used])
        k = 0
        for t in rows_t:
            while k + 1 < len(ex) and ex[k + 1]["t0"] <= t + 1e-9:
                k += 1
            cells = [repr(t)] + ["" if meas[ch].get(t) is None else repr(meas[ch][t]) for ch in OBS_COLUMNS]
            w.writerow(cells + [repr(float(ex[k]["inputs"][c])) for c in used])
    o0, o1 = obs[0], obs[-1]
    tank = {k: v for k, v in sc["tank"].items()}
    tank["volume_m3"] = model.geo.V
    tank["wall_heat_capacity_J_per_K"] = None if wall_capacity_unknown else model.C_meta
    meta = {"name": run, "fluid": sc["fluid"],
            "source": f"{SIMULATOR}: independent tank simulator (kinetic Hertz-Knudsen-Schrage interface, "
                      f"two-zone ullage, liquid surface layer, banded wall), scenario {sc['name']}",
            "tank": tank,
            "initial": {"p_v_Pa": o0["p"] + bp, "T_v_K": o0["T_v"], "T_l_K": o0["T_l"] + bT, "T_w_K": o0["T_w"],
                        "fill_ratio": o0["fill"]},
            "noise_std": {k: std[k] for k in NOISE_KEYS}, "duration_s": res["duration_s"],
            "timeseries": csv_path.name}
    json_path = out / f"{run}.json"
    json_path.write_text(json.dumps(meta, indent=2) + "\n")
    truth_cols = ("p", "T_v", "T_l", "T_w", "level", "fill", "p_f", "p_he", "T_v1", "T_v2", "p_1", "p_2", "T_lb",
                  "T_ls", "T_i", "T_sat_pf1", "mdot_i", "m_l", "m_layer", "m_v", "n_he", "T_w_bottom", "T_w_top")
    names = {"p": "p_v_Pa", "T_v": "T_v_K", "T_l": "T_l_K", "T_w": "T_w_K", "level": "H_l_m"}
    tcsv = out / f"{run}.truth.csv"
    with open(tcsv, "w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(["t_s"] + [names.get(c, c) for c in truth_cols])
        for t, o in zip(times, obs):
            w.writerow([repr(float(t))] + [repr(float(o[c])) for c in truth_cols])

    def state(o):
        return {k: float(v) for k, v in o.items()}

    truth = {"simulator": SIMULATOR,
             "model": {"interface": "Hertz-Knudsen-Schrage, T_i from the interface energy balance",
                       "accommodation_sigma": model.sigma, "ullage": f"two zones, lower = {PHI_LOWER} of ullage",
                       "liquid": "bulk + surface layer", "wall_bands": N_BANDS, "spray_fill": model.spray,
                       "properties": "CoolProp HEOS vapour (imposed gas phase); Chebyshev fits of CoolProp "
                                     "saturation for p_sat, saturated-liquid u and rho",
                       "transport_reference": model.transport},
             "scenario": sc, "mechanisms": {k: mech.get(k, 0.0) for k in MECHANISMS}, "noise": noise, "seed": seed,
             "wall_heat_capacity_true_J_per_K": model.C_w, "wall_heat_capacity_metadata_J_per_K": model.C_meta,
             "wall_heat_capacity_written": not wall_capacity_unknown,
             "initial_true": state(o0), "final_true": state(o1),
             "summary": {k: {"min": float(min(o[k] for o in obs)), "max": float(max(o[k] for o in obs)),
                             "final": float(o1[k])} for k in ("p", "T_v", "T_l", "T_w", "level", "fill", "p_he")},
             "schedule": [{"t0_s": s["t0"], "t1_s": s["t1"], "kind": s["kind"],
                           "inputs": {c: v for c, v in s["inputs"].items() if v != 0.0}} for s in ex],
             "schedule_changes": res["changes"], "closure": res["closure"], "rhs_calls": res["nfev"],
             "wall_time_s": res["wall_time_s"], "truth_csv": tcsv.name,
             "truth_csv_note": "noise-free, bias-free physical values at every 10 s"}
    truth_path = out / f"{run}.truth.json"
    truth_path.write_text(json.dumps(truth, indent=2, default=float) + "\n")
    return {"json": json_path, "csv": csv_path, "truth": truth_path, "truth_csv": tcsv}


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
    ap = argparse.ArgumentParser(description="Kinetic-interface tank simulator: writes runs in the interchange "
                                             "format (NAME.json, NAME.csv, NAME.truth.json, NAME.truth.csv).")
    ap.add_argument("scenario", nargs="?", help="a named scenario (see --list) or random_SEED")
    ap.add_argument("--list", action="store_true", help="list scenarios, mechanisms and fluids, and exit")
    ap.add_argument("--fluid", help=f"fluid (CoolProp name), one of {', '.join(FLUIDS)}")
    ap.add_argument("--mechanism", action="append", default=[], type=_mechanism_arg, metavar="NAME=VALUE")
    ap.add_argument("--noise", default="low", choices=("none", "low", "high"))
    ap.add_argument("--seed", type=int, default=0, help="seed of the sensor noise")
    ap.add_argument("--out", default=".", help="output folder")
    ap.add_argument("--name", help="run name (default kin_SCENARIO)")
    ap.add_argument("--duration", type=float, help="duration [s]")
    ap.add_argument("--wall-capacity-unknown", action="store_true", help="write null for the wall heat capacity")
    args = ap.parse_args(argv)
    if args.list:
        for k, desc in NAMED_SCENARIOS.items():
            print(f"{k:18s} {desc}")
        print(f"{'random_SEED':18s} a random plausible tank and schedule (fluid among {', '.join(FLUIDS)})")
        print("mechanisms: " + ", ".join(MECHANISMS))
        return 0
    if not args.scenario:
        ap.error("SCENARIO is required (or --list)")
    try:
        paths = simulate_run(args.scenario, dict(args.mechanism), noise=args.noise, seed=args.seed,
                             out_dir=args.out, name=args.name, fluid_name=args.fluid, duration_s=args.duration,
                             wall_capacity_unknown=args.wall_capacity_unknown)
    except (ValueError, SimulationError) as e:
        print(f"kinetic_sim: error: {e}", file=sys.stderr)
        return 2
    tr = json.loads(paths["truth"].read_text())
    s, c = tr["summary"], tr["closure"]
    print(f"wrote {paths['json']} ({tr['scenario']['fluid']}, {tr['wall_time_s']:.2f} s, {tr['rhs_calls']} rhs "
          f"calls; p {s['p']['min']:.0f}..{s['p']['max']:.0f} Pa, fill {s['fill']['min']:.3f}..{s['fill']['max']:.3f}"
          f"; closure mass {c['mass_rel']:.1e}, energy {c['energy_rel']:.1e})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
