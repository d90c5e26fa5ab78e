"""field_sim: a 0-D cryogenic tank simulator with a height-resolved wall.

Model
-----
Control volumes: one well-mixed ullage (the fluid's vapour plus an optional inert helium
share), one well-mixed liquid, and a wall of three nodes along the tank's height (bottom,
middle and top thirds of the height; a flat end belongs to the band it lies in).  The
conserved state is ``[m_v, U_v, m_l, U_l, T_w0, T_w1, T_w2, m_He]``; two integrated
counters (metered+hidden mass in, energy in) measure the balances' closure.

Laws
----
* Properties: CoolProp's Helmholtz EOS evaluated directly in (rho, T) with the phase
  imposed (vapour = gas, liquid = liquid); temperatures and the volume split are recovered
  from (m, U) by a 3x3 Newton solve: u_v(T_v, rho_v) and u_l(T_l, rho_l) match, the
  liquid's pressure equals the ullage's (fluid partial pressure + helium, Dalton; helium an
  ideal monatomic gas, u = 3/2 R T), V_v + V_l = V.
* Interface: at T_sat of the fluid's partial pressure; heat from each side by
  conduction-limited penetration theory, h = k / sqrt(pi alpha tau), with a surface renewal
  time tau = tau0 / E^2; evaporation = (Q_vi + Q_li) / (h_g - h_f) at T_sat.
* Wall to fluid: each wall node exchanges with the liquid over its wetted area and with
  the vapour over its dry area (the boundary moves with the level): h = max(0.59 Ra^1/4 k/L,
  0.11 Ra^1/3 k/L, 0.5), transport properties tabulated along T (vapour at the initial
  pressure, liquid at saturation) at the film temperature.  Axial conduction G_ax between
  adjacent nodes.  Ambient heat Q_aw enters the nodes by area, either a constant or a
  multilayer-insulation law Q_aw = k_eff (T_amb^n - Tbar_w^n) updated every 60 s and held
  (written to the CSV, so it stays metered).
* Sloshing: a resonant enhancement E = 1 + C_s (A0/R_s) r^2 / sqrt((1-r^2)^2 + (2 zeta r)^2),
  r = f_e / f_11, f_11 from the first antisymmetric mode of the free surface
  (xi = 1.8412, depth and the surface's equivalent radius); E multiplies the interface
  coefficients and 1 + 0.3 (E - 1) the wall ones.
* Bulk phase change: a liquid more than 0.1 K above T_sat(p) boils in its bulk (relaxation
  time 5 s, vapour leaves at h_g), an ullage more than 0.2 K below T_sat(p_partial) fogs
  (condensate at h_f).
* Operations: vapour injection at h(T_v_in, p_v_in), vent at ullage state (helium leaves
  with its mass share of the vented mass), liquid fill at h(T_l_in, p), drain at liquid
  state, a relief valve (opens above p_set, closes below p_reset; every opening and closing
  is a row of ``mdot_v_out_kg_s``), sloshing, heat-load steps.
* Hidden mechanisms (one per run, truth in NAME.truth.json): Q_liquid_W, Q_ullage_W,
  Q_wall_W (by area), vapor_leak_kg_s, liquid_leak_kg_s, inflow_meter_bias (written inflow =
  (1+b) x true), helium_share (of the initial ullage pressure), T_l_sensor_bias_K,
  p_sensor_bias_Pa, wall_capacity_written_factor.

Sensors: p_v (total pressure), T_v and T_l (the phases' temperatures), T_w (the area-averaged
wall temperature, i.e. the mass average since capacity is by area), H_l (level).  Each channel
has its own irregular sampling period (jitter +-30 %); a cell is empty where a channel is not
sampled; Gaussian noise of the written std.  Inputs are written only on the rows where they
change (the format's piecewise-constant rule), all input columns at once.

Command line::

    python tests/field_sim.py NAME [NAME ...] --out DIR   # NAME.json, NAME.csv, NAME.truth.json
    python tests/field_sim.py --list
    python tests/field_sim.py all --out DIR

Uses only numpy, scipy and CoolProp.
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import os
import sys
import time

import numpy as np
import CoolProp.CoolProp as CP
from scipy.integrate import solve_ivp

G = 9.81
R_HE = 8.314462618 / 4.002602e-3
CV_HE = 1.5 * R_HE
CP_HE = 2.5 * R_HE
INPUTS = ["mdot_v_in_kg_s", "T_v_in_K", "p_v_in_Pa", "mdot_v_out_kg_s", "mdot_l_in_kg_s",
          "T_l_in_K", "mdot_l_out_kg_s", "slosh_amplitude_m", "slosh_frequency_Hz", "Q_aw_W"]
OBS = ["p_v_Pa", "T_v_K", "T_l_K", "T_w_K", "H_l_m"]
NOISE_KEY = {"p_v_Pa": "p_v", "T_v_K": "T_v", "T_l_K": "T_l", "T_w_K": "T_w", "H_l_m": "H_l"}


# ----------------------------------------------------------------------------- geometry
class Geometry:
    """Tables of liquid volume, wetted wall area and free-surface area against level."""

    def __init__(self, shape: dict, n: int = 4001):
        kind = shape["shape"]
        R = shape["radius_m"]
        if kind == "horizontal_cylinder":
            L = shape["cylinder_length_m"]
            H = 2 * R
            z = np.linspace(0, H, n)
            c = np.clip((R - z) / R, -1, 1)
            seg = R * R * np.arccos(c) - (R - z) * np.sqrt(np.maximum(2 * R * z - z * z, 0))
            V = L * seg
            A = L * 2 * R * np.arccos(c) + 2 * seg
            width = 2 * np.sqrt(np.maximum(R * R - (z - R) ** 2, 0))
            Ai = L * width
            self.radius_surface = np.sqrt(np.maximum(Ai, 1e-9) / math.pi)
        else:
            if kind == "vertical_cylinder":
                H = shape["height_m"]
                z = np.linspace(0, H, n)
                r = np.full(n, R)
                flat_bot, flat_top = math.pi * R * R, math.pi * R * R
            elif kind == "sphere":
                H = 2 * R
                z = np.linspace(0, H, n)
                r = np.sqrt(np.maximum(R * R - (z - R) ** 2, 0))
                flat_bot = flat_top = 0.0
            elif kind == "vertical_cylinder_elliptical_heads":
                Lc = shape["cylinder_length_m"]
                b = R / shape["head_aspect"]
                H = Lc + 2 * b
                z = np.linspace(0, H, n)
                zz = np.where(z < b, b - z, np.where(z > b + Lc, z - b - Lc, 0.0))
                r = R * np.sqrt(np.maximum(1 - (zz / b) ** 2, 0))
                flat_bot = flat_top = 0.0
            else:
                raise ValueError(f"unknown shape {kind}")
            dz = np.diff(z)
            dV = math.pi * dz * (r[:-1] ** 2 + r[:-1] * r[1:] + r[1:] ** 2) / 3
            dA = math.pi * (r[:-1] + r[1:]) * np.sqrt(dz ** 2 + np.diff(r) ** 2)
            V = np.concatenate([[0], np.cumsum(dV)])
            A = flat_bot + np.concatenate([[0], np.cumsum(dA)])
            A[-1] += flat_top
            Ai = math.pi * r ** 2
            self.radius_surface = np.maximum(r, 1e-4)
        self.z, self.V, self.A, self.Ai, self.H = z, V, A, Ai, H
        self.volume = V[-1]
        self.area = A[-1]
        self.bands = np.array([0, H / 3, 2 * H / 3, H])
        Ab = np.interp(self.bands, z, A)
        Ab[0], Ab[-1] = 0.0, A[-1]
        self.node_area = np.diff(Ab)
        self._Ab = Ab

    def level(self, Vl):
        return float(np.interp(Vl, self.V, self.z))

    def wetted(self, h):
        """Wetted area of each wall node at level h."""
        Ah = float(np.interp(h, self.z, self.A)) if h > 0 else 0.0
        return np.clip(Ah - self._Ab[:-1], 0, self.node_area)

    def surface(self, h):
        return float(np.interp(h, self.z, self.Ai)), float(np.interp(h, self.z, self.radius_surface))


# ----------------------------------------------------------------------------- properties
class Fluid:
    def __init__(self, name: str, p_ref: float, T_hi: float):
        self.name = name
        self.gas = CP.AbstractState("HEOS", name)
        self.gas.specify_phase(CP.iphase_gas)
        self.liq = CP.AbstractState("HEOS", name)
        self.liq.specify_phase(CP.iphase_liquid)
        self.liq_in = CP.AbstractState("HEOS", name)
        self.liq_in.specify_phase(CP.iphase_liquid)
        sat = CP.AbstractState("HEOS", name)
        ptr = max(CP.PropsSI("ptriple", name), 1e3) * 1.05
        pc = CP.PropsSI("pcrit", name)
        self.lp = np.linspace(math.log(ptr), math.log(0.97 * pc), 600)
        Ts, hf, hg = [], [], []
        for lp in self.lp:
            sat.update(CP.PQ_INPUTS, math.exp(lp), 0)
            Ts.append(sat.T()); hf.append(sat.hmass())
            sat.update(CP.PQ_INPUTS, math.exp(lp), 1)
            hg.append(sat.hmass())
        self.Ts, self.hf, self.hg = map(np.array, (Ts, hf, hg))
        # transport tables along T: vapour at p_ref, liquid at saturation
        Tsr = self.Tsat(p_ref)
        self.Tvt = np.linspace(Tsr + 0.05, max(T_hi, Tsr + 5), 120)
        self.vap = self._table(self.Tvt, lambda T: (CP.iphase_gas, CP.PT_INPUTS, p_ref, T))
        Tlo = self.Ts[0] + 0.1
        self.Tlt = np.linspace(Tlo, min(Tsr + 8, 0.95 * CP.PropsSI("Tcrit", name)), 80)
        self.liqt = self._table(self.Tlt, lambda T: (None, CP.QT_INPUTS, 0, T))

    def _table(self, Ts, spec):
        a = CP.AbstractState("HEOS", self.name)
        rows = []
        for T in Ts:
            ph, inp, x, y = spec(T)
            if ph is not None:
                a.specify_phase(ph)
            a.update(inp, x, y)
            k, mu, rho, cp = a.conductivity(), a.viscosity(), a.rhomass(), a.cpmass()
            beta = a.isobaric_expansion_coefficient()
            rows.append((k, mu / rho, k / (rho * cp), beta))
        return np.array(rows)

    def Tsat(self, p):
        return float(np.interp(math.log(max(p, 1.0)), self.lp, self.Ts))

    def sat_h(self, p):
        lp = math.log(max(p, 1.0))
        return float(np.interp(lp, self.lp, self.hf)), float(np.interp(lp, self.lp, self.hg))

    def transport(self, phase, T):
        Tt, tab = (self.Tvt, self.vap) if phase == "v" else (self.Tlt, self.liqt)
        return [float(np.interp(T, Tt, tab[:, i])) for i in range(4)]

    @staticmethod
    def state(a, rho, T):
        a.update(CP.DmassT_INPUTS, rho, T)
        return (a.p(), a.umass(), a.cvmass(), a.first_partial_deriv(CP.iUmass, CP.iDmass, CP.iT),
                a.first_partial_deriv(CP.iP, CP.iT, CP.iDmass), a.first_partial_deriv(CP.iP, CP.iDmass, CP.iT))

    def h_pt(self, a, p, T):
        a.update(CP.PT_INPUTS, p, T)
        return a.hmass()


def h_coef(props, dT, L):
    """Vertical-wall natural convection, laminar/turbulent (0.59 Ra^1/4, 0.11 Ra^1/3)."""
    k, nu, al, beta = props
    ra = G * abs(beta) * abs(dT) * L ** 3 / (nu * al) + 1e-12
    return max(0.59 * ra ** 0.25 * k / L, 0.11 * ra ** (1 / 3) * k / L, 0.5)


# ----------------------------------------------------------------------------- the tank
class Tank:
    def __init__(self, sc: dict):
        self.sc = sc
        self.geo = Geometry(sc["tank"])
        self.V = self.geo.volume
        self.fl = Fluid(sc["fluid"], sc["p0"], sc.get("T_hi", 2.5 * CP.PropsSI("Tcrit", sc["fluid"])))
        self.C = sc["C_w"] * self.geo.node_area / self.geo.area
        self.G_ax = sc.get("G_ax", 2.0)
        self.tau0 = sc.get("tau0", 300.0)
        self.hidden = sc.get("hidden", {})
        self.guess = None
        self.inp = {}

    # -- state recovery
    def solve(self, y):
        m_v, U_v, m_l, U_l = y[0], y[1], y[2], y[3]
        m_he = y[7]
        fl = self.fl
        x = np.array(self.guess) if self.guess is not None else np.array([30.0, 20.0, 0.5 * self.V])
        for it in range(60):
            Tv, Tl, Vl = x
            Vv = self.V - Vl
            rv, rl = m_v / Vv, m_l / Vl
            pv, uv, cvv, dudr_v, dpdT_v, dpdr_v = fl.state(fl.gas, rv, Tv)
            pl, ul, cvl, dudr_l, dpdT_l, dpdr_l = fl.state(fl.liq, rl, Tl)
            phe = m_he * R_HE * Tv / Vv
            r = np.array([m_v * uv + m_he * CV_HE * Tv - U_v, m_l * ul - U_l, pv + phe - pl])
            J = np.array([
                [m_v * cvv + m_he * CV_HE, 0.0, m_v * dudr_v * rv / Vv],
                [0.0, m_l * cvl, -m_l * dudr_l * rl / Vl],
                [dpdT_v + m_he * R_HE / Vv, -dpdT_l, dpdr_v * rv / Vv + phe / Vv + dpdr_l * rl / Vl]])
            dx = np.linalg.solve(J, -r)
            lim = np.array([0.2 * x[0], 0.2 * x[1], 0.05 * min(Vl, Vv)])
            s = min(1.0, float(np.min(lim / (np.abs(dx) + 1e-300))))
            x = x + s * dx
            if abs(dx[0]) < 1e-9 * x[0] and abs(dx[1]) < 1e-9 * x[1] and abs(dx[2]) < 1e-12 * self.V:
                break
        else:
            raise RuntimeError(f"state recovery did not converge: {r}")
        self.guess = x.copy()
        Tv, Tl, Vl = x
        Vv = self.V - Vl
        rv, rl = m_v / Vv, m_l / Vl
        fl.gas.update(CP.DmassT_INPUTS, rv, Tv)
        fl.liq.update(CP.DmassT_INPUTS, rl, Tl)
        pv, pl = fl.gas.p(), fl.liq.p()
        return dict(Tv=Tv, Tl=Tl, Vl=Vl, Vv=Vv, rv=rv, rl=rl, pv=pv, p=pl,
                    phe=m_he * R_HE * Tv / Vv, uv=fl.gas.umass(), ul=fl.liq.umass(),
                    hv=fl.gas.hmass(), hl=fl.liq.hmass())

    def slosh_E(self, h):
        A0, fe = self.inp.get("slosh_amplitude_m", 0.0), self.inp.get("slosh_frequency_Hz", 0.0)
        if A0 <= 0 or fe <= 0:
            return 1.0, 0.0
        _, Rs = self.geo.surface(h)
        xi = 1.8412
        f11 = math.sqrt(G * xi / Rs * math.tanh(xi * max(h, 1e-3) / Rs)) / (2 * math.pi)
        r = fe / f11
        amp = r * r / math.sqrt((1 - r * r) ** 2 + (2 * 0.05 * r) ** 2)
        return 1.0 + self.sc.get("C_slosh", 60.0) * (A0 / Rs) * amp, f11

    # -- right-hand side
    def rhs(self, t, y):
        s = self.solve(y)
        fl, inp, hid = self.fl, self.inp, self.hidden
        m_v, m_l, m_he = y[0], y[2], y[7]
        Tw = y[4:7]
        h = self.geo.level(s["Vl"])
        Ai, _ = self.geo.surface(h)
        E, _ = self.slosh_E(h)
        Ew = 1.0 + 0.3 * (E - 1.0)
        p_part = max(s["p"] - s["phe"], 10.0)
        Ts = fl.Tsat(p_part)
        hf, hg = fl.sat_h(p_part)
        tau = self.tau0 / E ** 2
        kv, nuv, alv, bv = fl.transport("v", 0.5 * (s["Tv"] + Ts))
        kl, nul, all_, bl = fl.transport("l", 0.5 * (s["Tl"] + Ts))
        h_vi = kv / math.sqrt(math.pi * alv * tau)
        h_li = kl / math.sqrt(math.pi * all_ * tau)
        Q_vi = h_vi * Ai * (s["Tv"] - Ts)          # vapour -> interface
        Q_li = h_li * Ai * (s["Tl"] - Ts)          # liquid -> interface
        m_evap = (Q_vi + Q_li) / (hg - hf)
        # wall
        wet = self.geo.wetted(h)
        dry = self.geo.node_area - wet
        Lv, Ll = max(self.geo.H - h, 0.05), max(h, 0.05)
        Q_wl = np.zeros(3); Q_wv = np.zeros(3)
        for j in range(3):
            if wet[j] > 0:
                pl_ = fl.transport("l", 0.5 * (Tw[j] + s["Tl"]))
                Q_wl[j] = Ew * h_coef(pl_, Tw[j] - s["Tl"], Ll) * wet[j] * (Tw[j] - s["Tl"])
            if dry[j] > 0:
                pv_ = fl.transport("v", 0.5 * (Tw[j] + s["Tv"]))
                Q_wv[j] = Ew * h_coef(pv_, Tw[j] - s["Tv"], Lv) * dry[j] * (Tw[j] - s["Tv"])
        Q_aw = inp.get("Q_aw_W", 0.0)
        Q_wall_hidden = hid.get("Q_wall_W", 0.0)
        share = self.geo.node_area / self.geo.area
        cond = np.zeros(3)
        cond[0] = self.G_ax * (Tw[1] - Tw[0])
        cond[1] = self.G_ax * (Tw[0] - Tw[1]) + self.G_ax * (Tw[2] - Tw[1])
        cond[2] = self.G_ax * (Tw[1] - Tw[2])
        dTw = ((Q_aw + Q_wall_hidden) * share + cond - Q_wl - Q_wv) / self.C
        # bulk phase change
        Tsat_tot = fl.Tsat(s["p"])
        hf_t, hg_t = fl.sat_h(s["p"])
        m_boil = 0.0
        if s["Tl"] > Tsat_tot + 0.1:
            m_boil = m_l * fl.liq.cvmass() * (s["Tl"] - Tsat_tot - 0.1) / (5.0 * (hg_t - hf_t))
        m_fog = 0.0
        if s["Tv"] < Ts - 0.2:
            m_fog = m_v * fl.gas.cvmass() * (Ts - 0.2 - s["Tv"]) / (5.0 * (hg - hf))
        # operations (true flows)
        bias = hid.get("inflow_meter_bias", 0.0)
        mvi = inp.get("mdot_v_in_kg_s", 0.0) / (1 + bias)
        mli = inp.get("mdot_l_in_kg_s", 0.0) / (1 + bias)
        mvo = inp.get("mdot_v_out_kg_s", 0.0) + hid.get("vapor_leak_kg_s", 0.0)
        mlo = inp.get("mdot_l_out_kg_s", 0.0) + hid.get("liquid_leak_kg_s", 0.0)
        h_vin = self.h_vin if mvi > 0 else 0.0
        h_lin = fl.h_pt(fl.liq_in, s["p"], inp["T_l_in_K"]) if mli > 0 else 0.0
        w_he = m_he / (m_he + m_v)                     # mass share of helium in the vent
        dm_v = m_evap + m_boil - m_fog + mvi - mvo * (1 - w_he)
        dm_he = -mvo * w_he
        dm_l = -m_evap - m_boil + m_fog + mli - mlo
        Qv_hid, Ql_hid = hid.get("Q_ullage_W", 0.0), hid.get("Q_liquid_W", 0.0)
        dU_v = (m_evap * hg - Q_vi + m_boil * hg_t - m_fog * hf + Q_wv.sum() + mvi * h_vin
                - mvo * (1 - w_he) * s["hv"] - mvo * w_he * CP_HE * s["Tv"] + Qv_hid)
        dU_l = (-m_evap * hf - Q_li - m_boil * hg_t + m_fog * hf + Q_wl.sum() + mli * h_lin
                - mlo * s["hl"] + Ql_hid)
        dM_in = mvi + mli - mvo - mlo
        dE_in = (mvi * h_vin + mli * h_lin - mvo * (1 - w_he) * s["hv"] - mvo * w_he * CP_HE * s["Tv"]
                 - mlo * s["hl"] + Q_aw + Q_wall_hidden + Qv_hid + Ql_hid)
        return np.array([dm_v, dU_v, dm_l, dU_l, dTw[0], dTw[1], dTw[2], dm_he, dM_in, dE_in])

    def energy(self, y):
        s = self.solve(y)
        fl = self.fl
        fl.gas.update(CP.DmassT_INPUTS, s["rv"], s["Tv"]); fl.liq.update(CP.DmassT_INPUTS, s["rl"], s["Tl"])
        return y[0] * fl.gas.umass() + y[7] * CV_HE * s["Tv"] + y[2] * fl.liq.umass() + float(self.C @ y[4:7])


# ----------------------------------------------------------------------------- running
def sample_times(rng, period, T_end):
    t, out = 0.0, [0.0]
    while True:
        t += period * (1 + rng.uniform(-0.3, 0.3))
        if t >= T_end:
            break
        out.append(round(t, 2))
    if T_end - out[-1] > 0.05:
        out.append(float(T_end))
    return out


def inputs_at(sc, t):
    d = {k: 0.0 for k in INPUTS}
    d["Q_aw_W"] = sc.get("Q_aw", 0.0)
    for t0, t1, ops in sc.get("ops", []):
        if t0 <= t < t1:
            d.update(ops)
    return d


def simulate(sc: dict):
    tank = Tank(sc)
    fl, geo = tank.fl, tank.geo
    rng = np.random.default_rng(sc.get("seed", 0))
    T_end = float(sc["duration"])
    he = sc.get("hidden", {}).get("helium_share", 0.0)
    p0 = sc["p0"]
    p_part0 = p0 * (1 - he)
    Tl0 = fl.Tsat(p_part0) - sc.get("subcool", 0.3)
    Tv0 = fl.Tsat(p_part0) + sc.get("superheat", 3.0)
    fl.liq.update(CP.PT_INPUTS, p0, Tl0); rl = fl.liq.rhomass(); ul = fl.liq.umass()
    fl.gas.update(CP.PT_INPUTS, p_part0, Tv0); rv = fl.gas.rhomass(); uv = fl.gas.umass()
    Vl = sc["fill"] * tank.V
    Vv = tank.V - Vl
    m_he = he * p0 * Vv / (R_HE * Tv0)
    Tw0 = Tl0 + np.array(sc.get("wall_offsets", [0.5, 2.0, 5.0]))
    y = np.array([rv * Vv, rv * Vv * uv + m_he * CV_HE * Tv0, rl * Vl, rl * Vl * ul,
                  Tw0[0], Tw0[1], Tw0[2], m_he, 0.0, 0.0])
    tank.guess = [Tv0, Tl0, Vl]
    tank.x0 = (Tv0, Tl0, Vl)
    M0 = y[0] + y[2] + y[7]
    E0 = tank.energy(y)

    # sensor schedules
    samp = sc.get("sampling", {"p_v_Pa": 1.0, "T_v_K": 5.0, "T_l_K": 5.0, "T_w_K": 10.0, "H_l_m": 30.0})
    sched = {ch: set(sample_times(rng, per, T_end)) for ch, per in samp.items() if per}
    # breakpoints of the schedule (operations, MLI updates)
    bps = {0.0, T_end}
    for t0, t1, _ in sc.get("ops", []):
        bps.update([float(min(t0, T_end)), float(min(t1, T_end))])
    mli = sc.get("mli")
    if mli:
        bps.update(np.arange(0.0, T_end, mli.get("every", 60.0)).tolist())
    bps = sorted(b for b in bps if b <= T_end)
    obs_times = sorted(set().union(*sched.values()))
    relief = sc.get("relief")
    valve_open = False
    mli_ticks = set(np.round(np.arange(0.0, T_end, mli.get("every", 60.0)), 3).tolist()) if mli else set()
    q_mli = 0.0
    rows = {}          # t -> state
    input_rows = []    # (t, inputs)
    t = 0.0
    last_inputs = None
    n_rhs = [0]

    def f(tt, yy):
        n_rhs[0] += 1
        return tank.rhs(tt, yy)

    def atol(yy):
        return np.abs(yy) * 1e-10 + 1e-12

    while t < T_end - 1e-9:
        nxt = next(b for b in bps if b > t + 1e-9)
        inp = inputs_at(sc, t)
        if mli:
            if round(t, 3) in mli_ticks or last_inputs is None:
                Twbar = float(tank.C @ y[4:7]) / float(tank.C.sum())
                q_mli = round(mli["k_eff"] * (mli["T_amb"] ** mli["n"] - Twbar ** mli["n"]), 4)
            inp["Q_aw_W"] = q_mli
        if relief:
            p_now = tank.solve(y)["p"]
            if not valve_open and p_now >= relief["p_set"]:
                valve_open = True
            elif valve_open and p_now <= relief["p_reset"]:
                valve_open = False
            if valve_open:
                inp["mdot_v_out_kg_s"] += relief["mdot"]
        if last_inputs is None or inp != last_inputs:
            input_rows.append((round(t, 3), dict(inp)))
            last_inputs = dict(inp)
        tank.inp = inp
        if inp["mdot_v_in_kg_s"] > 0:
            tank.h_vin = fl.h_pt(fl.gas, inp["p_v_in_Pa"], inp["T_v_in_K"])
        events = None
        if relief:
            thr = relief["p_reset"] if valve_open else relief["p_set"]

            def ev(tt, yy, thr=thr):
                return tank.solve(yy)["p"] - thr
            ev.terminal = True
            ev.direction = -1 if valve_open else 1
            events = [ev]
        te = [o for o in obs_times if t - 1e-9 <= o <= nxt + 1e-9]
        sol = solve_ivp(f, (t, nxt), y, method="LSODA", t_eval=te or None, events=events,
                        rtol=1e-9, atol=atol(y), first_step=min(0.5, nxt - t))
        if sol.status < 0:
            raise RuntimeError(f"{sc['name']}: integration failed at t={t}: {sol.message}")
        for tt, yy in zip(sol.t, sol.y.T):
            rows[round(float(tt), 3)] = yy.copy()
        if sol.status == 1:     # the valve's threshold: it toggles at the next 0.01 s
            t_ev = float(sol.t_events[0][0])
            y = sol.y_events[0][0].copy()
            t_new = min(math.ceil(t_ev * 100 + 1e-6) / 100, nxt)
            if t_new > t_ev + 1e-9:
                s2 = solve_ivp(f, (t_ev, t_new), y, method="LSODA", rtol=1e-9, atol=atol(y))
                y = s2.y[:, -1].copy()
            t = t_new
            rows[round(t, 3)] = y.copy()
            valve_open = not valve_open
        else:
            y = sol.y[:, -1].copy()
            t = nxt
    rows[round(T_end, 3)] = y.copy()
    return tank, rows, input_rows, sched, (M0, E0), n_rhs[0]


# ----------------------------------------------------------------------------- writing
def write_run(sc, out):
    t_start = time.time()
    tank, rows, input_rows, sched, (M0, E0), n_rhs = simulate(sc)
    geo = tank.geo
    rng = np.random.default_rng(sc.get("seed", 0) + 1000)
    hid = sc.get("hidden", {})
    noise = {"p_v_Pa": 300.0, "T_v_K": 0.05, "T_l_K": 0.05, "T_w_K": 0.1, "H_l_m": 0.002}
    noise.update(sc.get("noise", {}))
    channels = [c for c in OBS if c in sched]
    bias = {"p_v_Pa": hid.get("p_sensor_bias_Pa", 0.0), "T_l_K": hid.get("T_l_sensor_bias_K", 0.0)}
    # closure
    errs_m, errs_e, errs_v = [], [], []
    truth_series = {}
    tank.guess = list(tank.x0)
    for t in sorted(rows):
        y = rows[t]
        s = tank.solve(y)
        M = y[0] + y[2] + y[7]
        errs_m.append(abs(M - (M0 + y[8])) / M0)
        E = tank.energy(y)
        errs_e.append(abs(E - (E0 + y[9])) / max(abs(E0), abs(E), 1.0))
        errs_v.append(abs(s["pv"] + s["phe"] - s["p"]))
        truth_series[t] = {"p_v_Pa": s["p"], "T_v_K": s["Tv"], "T_l_K": s["Tl"],
                           "T_w_K": float(tank.C @ y[4:7]) / float(tank.C.sum()),
                           "H_l_m": geo.level(s["Vl"])}
    in_times = {t for t, _ in input_rows}
    all_t = sorted(set(rows) | in_times)
    sched_r = {c: {round(x, 3) for x in v} for c, v in sched.items()}
    inp_map = dict(input_rows)
    name = sc["name"]
    os.makedirs(out, exist_ok=True)
    cols = ["t_s"] + channels + INPUTS
    with open(os.path.join(out, name + ".csv"), "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(cols)
        for t in all_t:
            row = [f"{t:.3f}".rstrip("0").rstrip(".") if t else "0"]
            for c in channels:
                if t in sched_r[c] and t in truth_series:
                    v = truth_series[t][c] + bias.get(c, 0.0) + rng.normal(0, noise[c])
                    row.append(f"{v:.6g}" if c != "p_v_Pa" else f"{v:.2f}")
                else:
                    row.append("")
            if t in inp_map:
                for c in INPUTS:
                    row.append(repr(float(inp_map[t][c])))
            else:
                row += [""] * len(INPUTS)
            w.writerow(row)
    s0 = truth_series[0.0]
    wall_written = sc["C_w"] * hid.get("wall_capacity_written_factor", 1.0)
    tank_meta = dict(sc["tank"])
    tank_meta["wall_heat_capacity_J_per_K"] = None if sc.get("wall_null") else wall_written
    if sc.get("write_volume"):
        tank_meta["volume_m3"] = round(tank.V, 4)
    initial = {"p_v_Pa": round(s0["p_v_Pa"] + bias["p_v_Pa"], 2), "T_v_K": round(s0["T_v_K"], 4),
               "T_l_K": round(s0["T_l_K"] + bias["T_l_K"], 4), "fill_ratio": sc["fill"]}
    if "T_w_K" in channels or not sc.get("omit_initial_Tw"):
        initial["T_w_K"] = round(s0["T_w_K"], 4)
    meta = {"name": name, "fluid": sc["fluid"],
            "source": "field_sim: 0-D tank, three-node height-resolved wall, penetration-theory interface",
            "tank": tank_meta, "initial": initial,
            "noise_std": {NOISE_KEY[c]: noise[c] for c in channels},
            "duration_s": float(sc["duration"]), "timeseries": name + ".csv"}
    with open(os.path.join(out, name + ".json"), "w") as fh:
        json.dump(meta, fh, indent=2)
    yl = rows[max(rows)]
    mech = next(iter(hid), None)
    truth = {"name": name, "mechanism": mech, "value": hid.get(mech) if mech else None,
             "hidden": hid, "true_wall_heat_capacity_J_per_K": sc["C_w"],
             "volume_m3": tank.V, "wall_area_m2": geo.area, "node_area_m2": geo.node_area.tolist(),
             "closure": {"mass_rel_max": max(errs_m), "energy_rel_max": max(errs_e),
                         "pressure_mismatch_Pa_max": max(errs_v), "energy_abs_J_max": max(errs_e) * max(abs(E0), 1.0), "mass_final_kg": float(yl[0] + yl[2] + yl[7]),
                         "mass_in_net_kg": float(yl[8])},
             "n_vent_toggles": sum(1 for i in range(1, len(input_rows))
                                   if input_rows[i][1]["mdot_v_out_kg_s"] != input_rows[i - 1][1]["mdot_v_out_kg_s"]),
             "final": truth_series[max(truth_series)], "n_rows": len(all_t), "n_rhs": n_rhs,
             "wall_time_s": round(time.time() - t_start, 1), "scenario": {k: v for k, v in sc.items() if k != "ops"},
             "ops": sc.get("ops", [])}
    with open(os.path.join(out, name + ".truth.json"), "w") as fh:
        json.dump(truth, fh, indent=2, default=float)
    return truth


# ----------------------------------------------------------------------------- scenarios
VC = {"shape": "vertical_cylinder", "radius_m": 0.9, "height_m": 2.2}
SPH = {"shape": "sphere", "radius_m": 1.5}
ELL = {"shape": "vertical_cylinder_elliptical_heads", "radius_m": 1.525, "cylinder_length_m": 1.9, "head_aspect": 2.0}
HCY = {"shape": "horizontal_cylinder", "radius_m": 1.0, "cylinder_length_m": 4.0}
PH2 = "ParaHydrogen"
SAMP_FAST = {"p_v_Pa": 1.0, "T_v_K": 5.0, "T_l_K": 5.0, "T_w_K": 10.0, "H_l_m": 30.0}
SAMP_NOWALL = {"p_v_Pa": 2.0, "T_v_K": 7.0, "T_l_K": 9.0, "H_l_m": 30.0}
SAMP_SLOW = {"p_v_Pa": 5.0, "T_v_K": 10.0, "T_l_K": 10.0, "T_w_K": 20.0, "H_l_m": 60.0}
SAMP_NOLEVEL = {"p_v_Pa": 1.0, "T_v_K": 6.0, "T_l_K": 6.0, "T_w_K": 8.0}


def _sc(name, **kw):
    d = dict(name=name, fluid=PH2, tank=VC, p0=1.5e5, fill=0.6, duration=3600, C_w=3e5, Q_aw=120.0,
             sampling=SAMP_FAST, seed=abs(hash(name)) % 1000)
    d.update(kw)
    return d


def _press(t0, t1, mdot, T, p=6e5):
    return (t0, t1, {"mdot_v_in_kg_s": mdot, "T_v_in_K": T, "p_v_in_Pa": p})


SCENARIOS = {s["name"]: s for s in [
    # ---- nothing hidden
    _sc("null_vcyl_selfpress", Q_aw=150.0),
    _sc("null_sphere_relief", tank=SPH, p0=2.39e5, duration=2400, fill=0.5, C_w=5e5,
        mli={"k_eff": 2e-3, "n": 2.2, "T_amb": 300.0}, Q_aw=0.0,
        relief={"p_set": 2.4e5, "p_reset": 2.38e5, "mdot": 0.004}, subcool=0.05, superheat=1.0),
    _sc("null_ell_press_drain", tank=ELL, p0=1.3e5, duration=3600, fill=0.7, C_w=8e5, Q_aw=60.0,
        sampling=SAMP_NOWALL, omit_initial_Tw=True,
        ops=[_press(300, 900, 0.004, 80.0), (1500, 3000, {"mdot_l_out_kg_s": 0.3})]),
    _sc("null_hcyl_fill", fluid="Hydrogen", tank=HCY, p0=2.0e5, fill=0.35, duration=2400, Q_aw=200.0,
        write_volume=True, ops=[(400, 1900, {"mdot_l_in_kg_s": 0.25, "T_l_in_K": 19.0})]),
    _sc("null_n2_slosh", fluid="Nitrogen", tank={"shape": "vertical_cylinder", "radius_m": 0.5, "height_m": 1.2},
        p0=1.6e5, fill=0.55, duration=1800, C_w=1.5e5, Q_aw=80.0, superheat=4.0,
        noise={"p_v_Pa": 200.0, "T_v_K": 0.1, "T_l_K": 0.1},
        ops=[(900, 1500, {"slosh_amplitude_m": 0.01, "slosh_frequency_Hz": 0.9})]),
    _sc("null_ch4_vent", fluid="Methane", tank={"shape": "vertical_cylinder_elliptical_heads", "radius_m": 0.8,
                                                 "cylinder_length_m": 1.0, "head_aspect": 2.0},
        p0=2.0e5, fill=0.5, duration=3600, C_w=4e5, Q_aw=250.0, sampling=SAMP_NOLEVEL,
        ops=[(1200, 1800, {"mdot_v_out_kg_s": 0.004})]),
    _sc("null_big_sphere", tank={"shape": "sphere", "radius_m": 3.628}, duration=14400, fill=0.8, C_w=4e6,
        p0=1.2e5, mli={"k_eff": 1.5e-3, "n": 2.2, "T_amb": 290.0, "every": 300.0}, Q_aw=0.0,
        sampling=SAMP_SLOW, noise={"p_v_Pa": 500.0}),
    _sc("null_o2_drain", fluid="Oxygen", tank={"shape": "vertical_cylinder", "radius_m": 0.4, "height_m": 1.0},
        p0=2.0e5, fill=0.7, duration=1200, C_w=6e4, Q_aw=40.0, wall_null=True, superheat=5.0,
        ops=[(200, 700, {"mdot_l_out_kg_s": 0.3}), _press(700, 1000, 0.003, 150.0, 4e5)]),
    _sc("null_wallnull_nowallsensor", tank=SPH, p0=1.8e5, fill=0.45, duration=1800, C_w=4e5, Q_aw=180.0,
        wall_null=True, sampling=SAMP_NOWALL, omit_initial_Tw=True,
        ops=[(600, 1200, {"mdot_l_out_kg_s": 0.15})]),
    # ---- inventory mechanisms
    _sc("inv_Qliquid_vcyl", Q_aw=100.0, hidden={"Q_liquid_W": 300.0}),
    _sc("inv_Qullage_sphere", tank=SPH, p0=1.4e5, fill=0.5, C_w=5e5, hidden={"Q_ullage_W": 200.0},
        ops=[_press(300, 700, 0.003, 60.0)]),
    _sc("inv_Qwall_ell", tank=ELL, p0=1.3e5, fill=0.5, duration=5400, C_w=8e5, Q_aw=80.0,
        hidden={"Q_wall_W": 400.0}, sampling=SAMP_SLOW),
    _sc("inv_vleak_relief_vcyl", p0=2.45e5, duration=2400, Q_aw=500.0, subcool=0.05, superheat=1.0,
        relief={"p_set": 2.5e5, "p_reset": 2.48e5, "mdot": 0.005}, hidden={"vapor_leak_kg_s": 5e-5}),
    _sc("inv_vleak_sphere_vent", tank=SPH, p0=2.0e5, fill=0.5, C_w=5e5, Q_aw=200.0,
        ops=[(600, 1200, {"mdot_v_out_kg_s": 0.004}), (2000, 2600, {"mdot_v_out_kg_s": 0.004})],
        hidden={"vapor_leak_kg_s": 4e-5}),
    _sc("inv_lleak_hcyl_drain", tank=HCY, p0=1.8e5, fill=0.6, duration=2400, Q_aw=150.0,
        ops=[(300, 2100, {"mdot_l_out_kg_s": 0.05})], hidden={"liquid_leak_kg_s": 5e-4}),
    _sc("inv_lleak_vcyl_hold", p0=1.6e5, hidden={"liquid_leak_kg_s": 3e-4}),
    _sc("inv_fillbias_ell", tank=ELL, p0=1.6e5, fill=0.3, duration=2400, C_w=8e5, Q_aw=100.0,
        ops=[(300, 1800, {"mdot_l_in_kg_s": 0.3, "T_l_in_K": 19.0})], hidden={"inflow_meter_bias": 0.15}),
    _sc("inv_injbias_sphere_nH2", fluid="Hydrogen", tank=SPH, p0=1.3e5, fill=0.5, duration=2400, C_w=5e5,
        ops=[_press(300, 1500, 0.004, 100.0)], hidden={"inflow_meter_bias": -0.12}),
    _sc("inv_Qliquid_n2", fluid="Nitrogen", tank={"shape": "vertical_cylinder", "radius_m": 0.6, "height_m": 1.8},
        p0=1.4e5, fill=0.6, C_w=2e5, Q_aw=100.0, superheat=3.0, noise={"T_v_K": 0.1, "T_l_K": 0.05},
        hidden={"Q_liquid_W": 200.0}),
    # ---- others
    _sc("oth_helium_relief_vcyl", p0=2.45e5, duration=2400, Q_aw=500.0, subcool=0.05, superheat=1.0,
        relief={"p_set": 2.5e5, "p_reset": 2.48e5, "mdot": 0.005}, hidden={"helium_share": 0.15}),
    _sc("oth_helium_sphere_vent", tank=SPH, p0=2.0e5, fill=0.5, C_w=5e5, Q_aw=200.0,
        ops=[(600, 1500, {"mdot_v_out_kg_s": 0.005}), (2200, 3000, {"mdot_v_out_kg_s": 0.005})],
        hidden={"helium_share": 0.12}),
    _sc("oth_Tlbias_hcyl_drain", tank=HCY, p0=1.6e5, fill=0.6, duration=2400, Q_aw=150.0,
        ops=[(300, 1500, {"mdot_l_out_kg_s": 0.2})], hidden={"T_l_sensor_bias_K": 0.5}),
    _sc("oth_pbias_vcyl", Q_aw=150.0, hidden={"p_sensor_bias_Pa": 2000.0}),
    _sc("oth_wall2x_sphere_press", tank=SPH, p0=1.3e5, fill=0.4, C_w=6e5, Q_aw=100.0,
        ops=[_press(300, 1200, 0.005, 120.0)], hidden={"wall_capacity_written_factor": 2.0}),
]}
# relief-valve run short enough to assimilate
SCENARIOS["null_relief_short"] = _sc("null_relief_short", p0=2.45e5, duration=1200, Q_aw=500.0, subcool=0.05,
                                     superheat=1.0, relief={"p_set": 2.5e5, "p_reset": 2.48e5, "mdot": 0.005})


def main(argv=None):
    ap = argparse.ArgumentParser(description="field_sim: write tank runs with hidden mechanisms")
    ap.add_argument("names", nargs="*")
    ap.add_argument("--out", default="field_runs")
    ap.add_argument("--list", action="store_true")
    a = ap.parse_args(argv)
    if a.list or not a.names:
        for n, s in SCENARIOS.items():
            print(f"{n:32s} {s['fluid']:13s} {s['tank']['shape']:36s} {s['duration']:6.0f} s  hidden={s.get('hidden', {})}")
        return 0
    names = list(SCENARIOS) if a.names == ["all"] else a.names
    for n in names:
        if n not in SCENARIOS:
            print(f"unknown scenario {n}", file=sys.stderr)
            return 2
        tr = write_run(SCENARIOS[n], a.out)
        c = tr["closure"]
        print(f"{n}: {tr['n_rows']} rows, {tr['wall_time_s']} s, mass {c['mass_rel_max']:.1e}, "
              f"energy {c['energy_rel_max']:.1e}, dp {c['pressure_mismatch_Pa_max']:.1e} Pa, vents {tr['n_vent_toggles']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
