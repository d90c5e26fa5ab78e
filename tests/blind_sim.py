"""blind_sim: a seventh independent 0-D cryogenic tank simulator (numpy, scipy, CoolProp only).

Written blind: from the run format (``shared/data-format.md``) alone, without reading tankode or
the other simulators, as a user's own simulator would be. It imports nothing from tankode.

Model (its own choices):
  * ullage: one well-mixed node (the fluid's vapour plus optional helium, ideal gas at T_v);
  * liquid: one well-mixed node, saturated-liquid property tables in T (incompressible in p);
  * interface at T_sat(partial pressure of the fluid); evaporation from the interface heat
    balance; bulk flashing of the liquid when it is superheated by more than 0.3 K (tau = 20 s);
  * wall: two nodes (dry, wetted), the heat capacity shared by area, wall material moved between
    the nodes as the level moves, carrying its temperature; conduction G between the nodes;
  * heat transfer: Churchill-Chu vertical plates (walls), a stable interface Nu = 0.27 Ra^1/4,
    an unstable one Globe-Dropkin Nu = 0.069 Ra^1/3 Pr^0.074; sloshing multiplies the interface
    and wetted-wall coefficients by 1 + 30 (A omega)^0.75;
  * hidden mechanisms (``hidden``): Q_liq_W, Q_ull_W, Q_wall_W, vapor_leak_kg_s,
    liquid_leak_kg_s, inflow_bias (written inflow = (1 + b) true), helium_frac (share of the
    initial ullage pressure), T_l_bias_K (sensor), and a written wall heat capacity other than
    the true one (``wall_C_written``, or None: unknown).

Mass and energy close to 1e-7 J and 1e-12 kg (``NAME.truth.json``). ``SCENARIOS``: its named
runs (N: nothing hidden, M: an inventory mechanism, O: others).

    python tests/blind_sim.py NAME [NAME ...] --out DIR
"""
import argparse
import json
import math
import os
import sys

import numpy as np
from scipy.integrate import solve_ivp
import CoolProp
import CoolProp.CoolProp as CP

R_U = 8.314462618
G = 9.81


# ---------------------------------------------------------------- geometry
class Geometry:
    def __init__(self, tank):
        self.tank = tank
        s = tank["shape"]
        R = tank["radius_m"]
        n = 40001
        if s == "horizontal_cylinder":
            L = tank["cylinder_length_m"]
            self.Htot = 2 * R
            z = np.linspace(0, 2 * R, n)
            th = np.arccos(np.clip((R - z) / R, -1, 1))
            seg = R * R * th - (R - z) * np.sqrt(np.clip(2 * R * z - z * z, 0, None))
            self.V = L * seg
            self.Awet = L * R * 2 * th + 2 * seg
            self.Ai = L * 2 * np.sqrt(np.clip(2 * R * z - z * z, 0, None))
            self.Atot = 2 * math.pi * R * L + 2 * math.pi * R * R
        else:
            if s == "vertical_cylinder":
                Hc = tank["height_m"]; self.Htot = Hc
                z = np.linspace(0, Hc, n); r = np.full(n, R); bottom = math.pi * R * R; top = bottom
            elif s == "sphere":
                self.Htot = 2 * R
                z = np.linspace(0, 2 * R, n); r = np.sqrt(np.clip(R * R - (R - z) ** 2, 0, None))
                bottom = top = 0.0
            elif s == "vertical_cylinder_elliptical_heads":
                Lc = tank["cylinder_length_m"]; d = R / tank["head_aspect"]
                self.Htot = Lc + 2 * d
                z = np.linspace(0, self.Htot, n)
                r = np.where(z < d, R * np.sqrt(np.clip(1 - ((d - z) / d) ** 2, 0, None)),
                             np.where(z > d + Lc, R * np.sqrt(np.clip(1 - ((z - d - Lc) / d) ** 2, 0, None)), R))
                bottom = top = 0.0
            else:
                raise ValueError(s)
            dz = np.diff(z)
            # exact volume of each slice as frustum
            dV = math.pi * dz * (r[:-1] ** 2 + r[:-1] * r[1:] + r[1:] ** 2) / 3
            dA = math.pi * (r[:-1] + r[1:]) * np.sqrt(dz ** 2 + (r[1:] - r[:-1]) ** 2)
            self.V = np.concatenate([[0], np.cumsum(dV)])
            self.Awet = bottom + np.concatenate([[0], np.cumsum(dA)])
            self.Ai = math.pi * r ** 2
            self.Atot = self.Awet[-1] + top
        self.z = z
        self.Vtot = self.V[-1]

    def H_of_V(self, V):
        return float(np.interp(V, self.V, self.z))

    def at(self, H):
        return float(np.interp(H, self.z, self.Awet)), float(np.interp(H, self.z, self.Ai))


def analytic_volume(tank):
    s = tank["shape"]; R = tank["radius_m"]
    if s == "vertical_cylinder":
        return math.pi * R * R * tank["height_m"]
    if s == "sphere":
        return 4 / 3 * math.pi * R ** 3
    if s == "horizontal_cylinder":
        return math.pi * R * R * tank["cylinder_length_m"]
    d = R / tank["head_aspect"]
    return math.pi * R * R * tank["cylinder_length_m"] + 4 / 3 * math.pi * R * R * d


# ---------------------------------------------------------------- the simulator
class Tank:
    def __init__(self, cfg):
        self.cfg = cfg
        self.fluid = cfg["fluid"]
        self.geo = Geometry(cfg["tank"])
        self.AS = CoolProp.AbstractState("HEOS", self.fluid)
        self.ASv = CoolProp.AbstractState("HEOS", self.fluid)
        self.M = CP.PropsSI("molar_mass", self.fluid)
        Tt = CP.PropsSI("Ttriple", self.fluid) + 0.2
        Tc = CP.PropsSI("Tcrit", self.fluid)
        Ts = np.linspace(Tt, Tc * 0.93, 600)
        tab = {k: [] for k in ("u", "rho", "cp", "k", "mu", "beta", "p", "hg")}
        for T in Ts:
            self.AS.update(CoolProp.QT_INPUTS, 0.0, T)
            tab["u"].append(self.AS.umass()); tab["rho"].append(self.AS.rhomass())
            tab["cp"].append(self.AS.cpmass()); tab["k"].append(self.AS.conductivity())
            tab["mu"].append(self.AS.viscosity()); tab["p"].append(self.AS.p())
            try:
                tab["beta"].append(self.AS.isobaric_expansion_coefficient())
            except Exception:
                tab["beta"].append(np.nan)
            self.AS.update(CoolProp.QT_INPUTS, 1.0, T)
            tab["hg"].append(self.AS.hmass())
        self.Ts = Ts
        self.tab = {k: np.array(v) for k, v in tab.items()}
        b = self.tab["beta"]
        if np.any(np.isnan(b)):
            rho = self.tab["rho"]; self.tab["beta"] = -np.gradient(rho, Ts) / rho
        self.lnp = np.log(self.tab["p"])
        self.C = cfg["wall_C"]
        self.G_dw = cfg.get("G_dw", 2.0)
        self.hid = cfg.get("hidden", {})
        self.nHe = 0.0

    # liquid from u
    def liq(self, u):
        T = float(np.interp(u, self.tab["u"], self.Ts))
        dTdu = float(np.interp(T, self.Ts, np.gradient(self.Ts, self.tab["u"])))
        g = lambda k: float(np.interp(T, self.Ts, self.tab[k]))
        return T, dTdu, g

    def Tsat(self, p):
        return float(np.interp(math.log(p), self.lnp, self.Ts))

    def vapour(self, m_v, U_v, V_v, T_guess):
        rho = m_v / V_v
        if self.nHe == 0.0:
            self.ASv.update(CoolProp.DmassUmass_INPUTS, rho, U_v / m_v)
            return self.ASv.T(), self.ASv.p(), self.ASv.p()
        cvHe = 1.5 * R_U * self.nHe
        T = T_guess
        for _ in range(30):
            self.ASv.update(CoolProp.DmassT_INPUTS, rho, T)
            f = m_v * self.ASv.umass() + cvHe * T - U_v
            cv = m_v * self.ASv.cvmass() + cvHe
            dT = -f / cv
            T += dT
            if abs(dT) < 1e-9:
                break
        self.ASv.update(CoolProp.DmassT_INPUTS, rho, T)
        pf = self.ASv.p()
        return T, pf + self.nHe * R_U * T / V_v, pf

    def slosh_factor(self, inp):
        A = inp.get("slosh_amplitude_m", 0.0); f = inp.get("slosh_frequency_Hz", 0.0)
        return 1.0 + 30.0 * (A * 2 * math.pi * f) ** 0.75

    def h_vertical(self, k, mu, cp, rho, beta, dT, L):
        L = max(L, 0.05)
        nu = mu / rho; alpha = k / (rho * cp); Pr = nu / alpha
        Ra = G * abs(beta) * abs(dT) * L ** 3 / (nu * alpha) + 1e-3
        Nu = (0.825 + 0.387 * Ra ** (1 / 6) / (1 + (0.492 / Pr) ** (9 / 16)) ** (8 / 27)) ** 2
        return Nu * k / L

    def h_horizontal(self, k, mu, cp, rho, beta, dT, L, unstable):
        L = max(L, 0.05)
        nu = mu / rho; alpha = k / (rho * cp); Pr = nu / alpha
        Ra = G * abs(beta) * abs(dT) * L ** 3 / (nu * alpha) + 1e-3
        Nu = 0.069 * Ra ** (1 / 3) * Pr ** 0.074 if unstable else 0.27 * Ra ** 0.25
        return max(Nu, 1.0) * k / L

    def rhs_parts(self, t, y, inp):
        m_v, U_v, m_l, U_l, E_d, E_w = y[:6]
        self.nHe = y[8]
        hid = self.hid
        u_l = U_l / m_l
        T_l, dTdu, gl = self.liq(u_l)
        rho_l = gl("rho")
        V_l = m_l / rho_l
        V_v = self.geo.Vtot - V_l
        T_v, p, p_f = self.vapour(m_v, U_v, V_v, getattr(self, "_Tv", 25.0))
        self._Tv = T_v
        H = self.geo.H_of_V(V_l)
        Awet, Ai = self.geo.at(H)
        Adry = self.geo.Atot - Awet
        f_wet = Awet / self.geo.Atot
        C = self.C
        Cw = C * f_wet; Cd = C - Cw
        T_ww = E_w / Cw if Cw > 1e-9 else E_d / max(Cd, 1e-9)
        T_d = E_d / Cd if Cd > 1e-9 else T_ww
        Ts = self.Tsat(p_f)
        sf = self.slosh_factor(inp)
        # vapour transport props at film temperature
        Tfv = 0.5 * (T_v + T_d)
        try:
            self.AS.update(CoolProp.PT_INPUTS, p_f, max(Tfv, Ts + 0.05))
            kv, muv, cpv, rhov = self.AS.conductivity(), self.AS.viscosity(), self.AS.cpmass(), self.AS.rhomass()
        except Exception:
            self.AS.update(CoolProp.QT_INPUTS, 1.0, Ts)
            kv, muv, cpv, rhov = self.AS.conductivity(), self.AS.viscosity(), self.AS.cpmass(), self.AS.rhomass()
        betav = 1.0 / max(Tfv, 1.0)
        Lv = max(self.geo.Htot - H, 0.05)
        h_wv = self.h_vertical(kv, muv, cpv, rhov, betav, T_d - T_v, Lv)
        h_vi = sf * self.h_horizontal(kv, muv, cpv, rhov, betav, T_v - Ts, math.sqrt(max(Ai, 1e-3)), T_v < Ts)
        kl, mul, cpl, betal = gl("k"), gl("mu"), gl("cp"), gl("beta")
        h_wl = sf * self.h_vertical(kl, mul, cpl, rho_l, betal, T_ww - T_l, max(H, 0.05))
        h_li = sf * self.h_horizontal(kl, mul, cpl, rho_l, betal, Ts - T_l, math.sqrt(max(Ai, 1e-3)), T_l > Ts)
        Q_wv = h_wv * Adry * (T_d - T_v)
        Q_wl = h_wl * Awet * (T_ww - T_l)
        Q_vi = h_vi * Ai * (T_v - Ts)
        Q_il = h_li * Ai * (Ts - T_l)
        h_l = u_l + p / rho_l
        self.AS.update(CoolProp.QT_INPUTS, 1.0, Ts)
        h_gs = self.AS.hmass()
        mdot_e = (Q_vi - Q_il) / (h_gs - h_l)
        # bulk flash
        sup = T_l - (Ts + 0.3)
        mdot_b = m_l * cpl * sup / ((h_gs - h_l) * 20.0) if sup > 0 else 0.0
        # vapour enthalpy (mixture incl. helium: only fluid part leaves in our ops)
        h_v = (U_v - 1.5 * R_U * self.nHe * T_v) / m_v + p_f / (m_v / V_v)
        # inputs
        mvi = inp.get("mdot_v_in_kg_s", 0.0); mvo = inp.get("mdot_v_out_kg_s", 0.0)
        mli = inp.get("mdot_l_in_kg_s", 0.0) / (1.0 + hid.get("inflow_bias", 0.0))
        mlo = inp.get("mdot_l_out_kg_s", 0.0)
        mvo_mix = mvo + hid.get("vapor_leak_kg_s", 0.0)
        mHe = self.nHe * 4.0026e-3
        wHe = mHe / (mHe + m_v)
        mvo_tot = mvo_mix * (1 - wHe)          # fluid part of the vented mixture
        ndot_He = -mvo_mix * wHe / 4.0026e-3   # helium moles leaving
        Hdot_He = ndot_He * 2.5 * R_U * T_v    # helium enthalpy leaving (negative)
        mlo_tot = mlo + hid.get("liquid_leak_kg_s", 0.0)
        h_vin = 0.0
        if mvi > 0:
            h_vin = CP.PropsSI("H", "T", inp["T_v_in_K"], "P", inp["p_v_in_Pa"], self.fluid)
        h_lin = 0.0
        if mli > 0:
            Tin = inp["T_l_in_K"]
            try:
                h_lin = CP.PropsSI("H", "T", Tin, "P", max(p, CP.PropsSI("P", "T", Tin, "Q", 0, self.fluid) * 1.0001), self.fluid)
            except Exception:
                h_lin = CP.PropsSI("H", "T", Tin, "Q", 0, self.fluid)
        Q_aw = inp.get("Q_aw_W", 0.0) + hid.get("Q_wall_W", 0.0)
        Qamb_d = Q_aw * (1 - f_wet); Qamb_w = Q_aw * f_wet
        Q_dw = self.G_dw * (T_d - T_ww)
        dm_l = mli - mlo_tot - mdot_e - mdot_b
        dm_v = mvi - mvo_tot + mdot_e + mdot_b
        # liquid energy without work; then solve for work term
        R_l = (Q_wl + Q_il + hid.get("Q_liq_W", 0.0) + mli * h_lin - mlo_tot * h_l
               - mdot_e * h_l - mdot_b * h_gs)
        # V_l = m_l / rho(T(u)); dV = dm/rho - m/rho^2 rho' dT/du (dU - u dm)/m
        drho = float(np.interp(T_l, self.Ts, np.gradient(self.tab["rho"], self.Ts)))
        a = dm_l / rho_l + (1.0 / rho_l ** 2) * drho * dTdu * u_l * dm_l
        b = -(1.0 / rho_l ** 2) * drho * dTdu
        dU_l = (R_l - p * a) / (1 + p * b)
        dV_l = a + b * dU_l
        dU_v = (Q_wv - Q_vi + hid.get("Q_ull_W", 0.0) + mvi * h_vin - mvo_tot * h_v
                + mdot_e * h_gs + mdot_b * h_gs + p * dV_l + Hdot_He)
        # wall: level motion moves material between nodes
        Awet2, _ = self.geo.at(self.geo.H_of_V(V_l + 1e-4 * abs(V_l)))
        dAdV = (Awet2 - Awet) / (1e-4 * abs(V_l)) if V_l > 0 else 0.0
        dfw = dAdV * dV_l / self.geo.Atot
        J = C * dfw * (T_d if dfw > 0 else T_ww)
        dE_d = Qamb_d - Q_wv - Q_dw - J
        dE_w = Qamb_w - Q_wl + Q_dw + J
        # boundary energy in (for conservation check)
        dE_b = (Q_aw + hid.get("Q_liq_W", 0.0) + hid.get("Q_ull_W", 0.0) + mvi * h_vin
                - mvo_tot * h_v + mli * h_lin - mlo_tot * h_l + Hdot_He)
        dM_b = mvi - mvo_tot + mli - mlo_tot
        obs = dict(p=p, T_v=T_v, T_l=T_l, T_w=(E_d + E_w) / C, H=H, T_d=T_d, T_ww=T_ww, Ts=Ts,
                   V_l=V_l, mdot_e=mdot_e, mdot_b=mdot_b, nHe=self.nHe, p_f=p_f)
        return np.array([dm_v, dU_v, dm_l, dU_l, dE_d, dE_w, dE_b, dM_b, ndot_He]), obs

    def rhs(self, t, y, inp):
        return self.rhs_parts(t, y, inp)[0]

    def initial_state(self, ini):
        p0, Tv0, Tl0, fill = ini["p_v_Pa"], ini["T_v_K"], ini["T_l_K"], ini["fill_ratio"]
        Vl = fill * self.geo.Vtot; Vv = self.geo.Vtot - Vl
        self.AS.update(CoolProp.QT_INPUTS, 0.0, Tl0)
        rho_l = self.AS.rhomass(); u_l = self.AS.umass()
        m_l = rho_l * Vl
        he = self.hid.get("helium_frac", 0.0)
        pf = p0 * (1 - he)
        self.nHe = he * p0 * Vv / (R_U * Tv0)
        self.AS.update(CoolProp.PT_INPUTS, pf, Tv0)
        m_v = self.AS.rhomass() * Vv
        U_v = m_v * self.AS.umass() + 1.5 * R_U * self.nHe * Tv0
        H = self.geo.H_of_V(Vl)
        Awet, _ = self.geo.at(H)
        fwet = Awet / self.geo.Atot
        E_d = self.C * (1 - fwet) * ini["T_wd_K"]
        E_w = self.C * fwet * ini["T_ww_K"]
        return np.array([m_v, U_v, m_l, m_l * u_l, E_d, E_w, 0.0, 0.0, self.nHe])


INPUT_COLS = ["mdot_v_in_kg_s", "T_v_in_K", "p_v_in_Pa", "mdot_v_out_kg_s", "mdot_l_in_kg_s",
              "T_l_in_K", "mdot_l_out_kg_s", "slosh_amplitude_m", "slosh_frequency_Hz", "Q_aw_W"]


def simulate(cfg, outdir):
    tank = Tank(cfg)
    ini = cfg["initial"]
    y0 = tank.initial_state(ini)
    E0 = y0[1] + y0[3] + y0[4] + y0[5]; M0 = y0[0] + y0[2]
    segs = cfg["segments"]  # list of (t_start, inputs dict)
    T_end = cfg["duration_s"]
    rates = cfg.get("rates", {"p": 5, "T_v": 10, "T_l": 10, "T_w": 10, "H": 5})
    t_obs = sorted(set(np.round(np.concatenate([np.arange(0, T_end + 1e-9, r) for r in rates.values()]), 6)))
    t_obs = np.array(t_obs)
    bounds = [s[0] for s in segs] + [T_end]
    ts_all, ys_all = [], []
    y = y0
    for i, (t0, inp) in enumerate(segs):
        t1 = bounds[i + 1]
        last = i == len(segs) - 1
        te = t_obs[(t_obs >= t0) & ((t_obs <= t1) if last else (t_obs < t1))]
        # one integration per segment: its end (the next segment's start) is taken from the
        # same solution's dense output, not from a second integration
        sol = solve_ivp(tank.rhs, (t0, t1), y, method="LSODA", args=(inp,), dense_output=True,
                        rtol=1e-8, atol=np.abs(y) * 1e-9 + 1e-12, max_step=20.0)
        if not sol.success:
            raise RuntimeError(sol.message)
        ts_all.append(te); ys_all.append(sol.sol(te).T if len(te) else np.empty((0, len(y))))
        y = sol.y[:, -1]
    ts = np.concatenate(ts_all); Y = np.concatenate(ys_all)
    # conservation check
    E1 = y[1] + y[3] + y[4] + y[5]; M1 = y[0] + y[2]
    cons = dict(energy_err_J=float(E1 - E0 - y[6]), energy_in_J=float(y[6]),
                mass_err_kg=float(M1 - M0 - y[7]), mass_in_kg=float(y[7]), m0=float(M0))
    obs = []
    seg_t = np.array([s[0] for s in segs])
    for t, yy in zip(ts, Y):
        inp = segs[int(np.searchsorted(seg_t, t, side="right") - 1)][1]
        obs.append(tank.rhs_parts(t, yy, inp)[1])
    rng = np.random.default_rng(cfg.get("seed", 0))
    ns = cfg["noise_std"]
    hid = cfg.get("hidden", {})
    name = cfg["name"]
    rows = []
    for t, o in zip(ts, obs):
        inp = segs[int(np.searchsorted(seg_t, t, side="right") - 1)][1]
        r = {"t_s": t}
        def on(ch):
            if ch not in rates:
                return False
            return abs(t / rates[ch] - round(t / rates[ch])) < 1e-6
        r["p_v_Pa"] = o["p"] + rng.normal(0, ns["p_v"]) if on("p") and "p_v" in ns else None
        r["T_v_K"] = o["T_v"] + rng.normal(0, ns["T_v"]) if on("T_v") and "T_v" in ns else None
        r["T_l_K"] = o["T_l"] + hid.get("T_l_bias_K", 0.0) + rng.normal(0, ns["T_l"]) if on("T_l") and "T_l" in ns else None
        r["T_w_K"] = o["T_w"] + rng.normal(0, ns["T_w"]) if on("T_w") and "T_w" in ns else None
        r["H_l_m"] = o["H"] + rng.normal(0, ns["H_l"]) if on("H") and "H_l" in ns else None
        for c in INPUT_COLS:
            r[c] = inp.get(c, 0.0)
        rows.append(r)
    # make sure a row exists at every segment start (inputs change there)
    have = set(np.round(ts, 6))
    for t0, inp in segs:
        if round(t0, 6) not in have:
            r = {"t_s": t0, "p_v_Pa": None, "T_v_K": None, "T_l_K": None, "T_w_K": None, "H_l_m": None}
            for c in INPUT_COLS:
                r[c] = inp.get(c, 0.0)
            rows.append(r)
    rows.sort(key=lambda r: r["t_s"])
    os.makedirs(outdir, exist_ok=True)
    cols = ["t_s", "p_v_Pa", "T_v_K", "T_l_K", "T_w_K", "H_l_m"] + INPUT_COLS
    with open(os.path.join(outdir, name + ".csv"), "w") as f:
        f.write(",".join(cols) + "\n")
        for r in rows:
            f.write(",".join("" if r[c] is None else repr(float(r[c])) for c in cols) + "\n")
    Cw = cfg.get("wall_C_written", "same")
    Cw = cfg["wall_C"] if Cw == "same" else Cw
    tankmeta = dict(cfg["tank"]); tankmeta["wall_heat_capacity_J_per_K"] = Cw
    o0 = obs[0]
    meta = {"name": name, "fluid": cfg["fluid"],
            "source": "blind_sim.py (independent two-node-wall 0-D simulator)",
            "tank": tankmeta,
            "initial": {"p_v_Pa": o0["p"], "T_v_K": o0["T_v"], "T_l_K": o0["T_l"] + hid.get("T_l_bias_K", 0.0),
                        "T_w_K": o0["T_w"], "fill_ratio": o0["V_l"] / tank.geo.Vtot},
            "noise_std": ns, "duration_s": T_end, "timeseries": name + ".csv"}
    with open(os.path.join(outdir, name + ".json"), "w") as f:
        json.dump(meta, f, indent=1)
    truth = {"hidden": hid, "wall_C_true": cfg["wall_C"], "conservation": cons,
             "volume_table": tank.geo.Vtot, "volume_analytic": analytic_volume(cfg["tank"]),
             "final": {k: float(v) for k, v in obs[-1].items()},
             "initial": {k: float(v) for k, v in obs[0].items()}}
    with open(os.path.join(outdir, name + ".truth.json"), "w") as f:
        json.dump(truth, f, indent=1)
    return truth


# ---------------------------------------------------------------- scenarios
def tsat(fl, p): return CP.PropsSI("T", "P", p, "Q", 0, fl)

NS_H2 = {"p_v": 300.0, "T_v": 0.05, "T_l": 0.03, "T_w": 0.05, "H_l": 0.001}
VC5 = {"shape": "vertical_cylinder", "radius_m": 0.9, "height_m": 1.965}   # 5.0 m3

def base(name, fluid, tank, p0, fill, C, dur, segs, hidden=None, dTv=1.5, dTl=-0.1, dTwd=3.0, dTww=0.1,
         ns=NS_H2, rates=None, seed=0, Cw="same"):
    Ts = tsat(fluid, p0)
    he = (hidden or {}).get("helium_frac", 0.0)
    Tl0 = tsat(fluid, p0 * (1 - he)) + dTl
    return dict(name=name, fluid=fluid, tank=tank, wall_C=C, wall_C_written=Cw, duration_s=dur,
                initial=dict(p_v_Pa=p0, T_v_K=Ts + dTv, T_l_K=Tl0, T_wd_K=Ts + dTwd, T_ww_K=Tl0 + dTww,
                             fill_ratio=fill),
                segments=segs, hidden=hidden or {}, noise_std=ns, seed=seed,
                rates=rates or {"p": 5, "T_v": 10, "T_l": 10, "T_w": 10, "H": 5})

def Q(w): return {"Q_aw_W": w}

SCENARIOS = {}
# ---- nulls
SCENARIOS["N1_vcyl_selfpress"] = base("N1_vcyl_selfpress", "ParaHydrogen", VC5, 1.2e5, 0.6, 8e5, 3600, [(0, Q(300.0))], seed=1)
SCENARIOS["N2_sphere_vent"] = base("N2_sphere_vent", "ParaHydrogen", {"shape": "sphere", "radius_m": 1.35}, 1.5e5, 0.5, 1.5e6, 4200,
    [(0, Q(500.0)), (2400, {"Q_aw_W": 500.0, "mdot_v_out_kg_s": 2.0e-3}), (3300, Q(500.0))], seed=2,
    rates={"p": 4, "T_v": 8, "T_l": 8, "T_w": 8, "H": 4})
SCENARIOS["N3_hcyl_press_drain"] = base("N3_hcyl_press_drain", "ParaHydrogen",
    {"shape": "horizontal_cylinder", "radius_m": 1.2, "cylinder_length_m": 4.4}, 1.3e5, 0.7, 3e6, 4800,
    [(0, Q(800.0)), (600, {"Q_aw_W": 800.0, "mdot_v_in_kg_s": 3e-3, "T_v_in_K": 120.0, "p_v_in_Pa": 5e5}),
     (1500, Q(800.0)), (2700, {"Q_aw_W": 800.0, "mdot_l_out_kg_s": 0.12}), (3900, Q(800.0))], seed=3,
    ns={"p_v": 400.0, "T_v": 0.08, "T_l": 0.05, "T_w": 0.1, "H_l": 0.001})
SCENARIOS["N4_ell_N2_fill"] = base("N4_ell_N2_fill", "Nitrogen",
    {"shape": "vertical_cylinder_elliptical_heads", "radius_m": 0.8, "cylinder_length_m": 3.0, "head_aspect": 2.0},
    1.4e5, 0.35, 1.2e6, 3600,
    [(0, Q(600.0)), (900, {"Q_aw_W": 600.0, "mdot_l_in_kg_s": 0.6, "T_l_in_K": 78.0}), (2400, Q(600.0))], seed=4,
    dTv=3.0, dTwd=8.0, ns={"p_v": 400.0, "T_v": 0.1, "T_l": 0.05, "T_w": 0.1, "H_l": 0.001})
SCENARIOS["N5_vcyl_slosh_filldrain"] = base("N5_vcyl_slosh_filldrain", "ParaHydrogen",
    {"shape": "vertical_cylinder", "radius_m": 0.7, "height_m": 2.0}, 1.8e5, 0.55, 5e5, 5400,
    [(0, Q(250.0)), (900, {"Q_aw_W": 250.0, "slosh_amplitude_m": 0.02, "slosh_frequency_Hz": 0.6}),
     (1800, {"Q_aw_W": 250.0, "mdot_l_out_kg_s": 0.05}), (2700, Q(250.0)),
     (3300, {"Q_aw_W": 250.0, "mdot_l_in_kg_s": 0.05, "T_l_in_K": 20.3}), (4200, Q(250.0))], seed=5,
    dTv=2.0)
# ---- one mechanism, 5 m3 vertical cylinder
SCENARIOS["M1_Qliq400"] = base("M1_Qliq400", "ParaHydrogen", VC5, 1.2e5, 0.6, 8e5, 3600, [(0, Q(300.0))],
    hidden={"Q_liq_W": 400.0}, seed=11)
SCENARIOS["M2_Qull300"] = base("M2_Qull300", "ParaHydrogen", VC5, 1.2e5, 0.5, 8e5, 3600, [(0, Q(300.0))],
    hidden={"Q_ull_W": 300.0}, seed=12)
SCENARIOS["M3_Qwall400"] = base("M3_Qwall400", "ParaHydrogen", VC5, 1.3e5, 0.6, 8e5, 3600,
    [(0, Q(300.0)), (1800, {"Q_aw_W": 300.0, "mdot_v_out_kg_s": 1.5e-3}), (2700, Q(300.0))],
    hidden={"Q_wall_W": 400.0}, seed=13)
SCENARIOS["M4_vleak0p5g"] = base("M4_vleak0p5g", "ParaHydrogen", VC5, 1.5e5, 0.6, 8e5, 3600, [(0, Q(300.0))],
    hidden={"vapor_leak_kg_s": 5e-4}, seed=14)
SCENARIOS["M5_lleak0p6g"] = base("M5_lleak0p6g", "ParaHydrogen", VC5, 1.2e5, 0.6, 8e5, 3600, [(0, Q(300.0))],
    hidden={"liquid_leak_kg_s": 6e-4}, seed=15)
SCENARIOS["M6_fillbias18"] = base("M6_fillbias18", "ParaHydrogen", VC5, 1.4e5, 0.3, 8e5, 3600,
    [(0, Q(300.0)), (900, {"Q_aw_W": 300.0, "mdot_l_in_kg_s": 0.08, "T_l_in_K": 20.5}), (2700, Q(300.0))],
    hidden={"inflow_bias": 0.18}, seed=16)
# ---- others
SCENARIOS["O1_helium15"] = base("O1_helium15", "ParaHydrogen", VC5, 1.4e5, 0.6, 8e5, 3600, [(0, Q(300.0))],
    hidden={"helium_frac": 0.15}, seed=21)
SCENARIOS["O2_Tlbias0p5"] = base("O2_Tlbias0p5", "ParaHydrogen", VC5, 1.2e5, 0.6, 8e5, 3600, [(0, Q(300.0))],
    hidden={"T_l_bias_K": 0.5}, seed=22)
SCENARIOS["O3_wallC_x1p5"] = base("O3_wallC_x1p5", "ParaHydrogen", VC5, 1.2e5, 0.6, 8e5, 3600,
    [(0, Q(300.0)), (1800, {"Q_aw_W": 300.0, "mdot_v_in_kg_s": 2e-3, "T_v_in_K": 200.0, "p_v_in_Pa": 4e5}), (2400, Q(300.0))],
    Cw=1.2e6, seed=23, dTwd=5.0)

# ---- fills with and without a meter bias, a drain, an unstated wall
FILL = [(0, Q(300.0)), (900, {"Q_aw_W": 300.0, "mdot_l_in_kg_s": 0.08, "T_l_in_K": 20.5}), (2700, Q(300.0))]
SCENARIOS["N6_fill_null"] = base("N6_fill_null", "ParaHydrogen", VC5, 1.4e5, 0.3, 8e5, 3600, FILL, seed=31)
SCENARIOS["M6b_fillbias15_slow"] = base("M6b_fillbias15_slow", "ParaHydrogen", VC5, 1.3e5, 0.4, 8e5, 5400,
    [(0, Q(300.0)), (900, {"Q_aw_W": 300.0, "mdot_l_in_kg_s": 0.03, "T_l_in_K": 20.6, "mdot_v_out_kg_s": 2e-3}), (3600, Q(300.0))],
    hidden={"inflow_bias": 0.15}, seed=32)
SCENARIOS["M8_fillbias_neg15"] = base("M8_fillbias_neg15", "ParaHydrogen", VC5, 1.4e5, 0.3, 8e5, 3600, FILL,
    hidden={"inflow_bias": -0.15}, seed=33)
SCENARIOS["M7_lleak_drain"] = base("M7_lleak_drain", "ParaHydrogen", VC5, 1.3e5, 0.7, 8e5, 3600,
    [(0, Q(300.0)), (1200, {"Q_aw_W": 300.0, "mdot_l_out_kg_s": 0.05}), (2400, Q(300.0))],
    hidden={"liquid_leak_kg_s": 8e-4}, seed=34)
SCENARIOS["N7_Cnull_vent"] = base("N7_Cnull_vent", "ParaHydrogen", VC5, 1.3e5, 0.6, 8e5, 3600,
    [(0, Q(300.0)), (1800, {"Q_aw_W": 300.0, "mdot_v_out_kg_s": 1.5e-3}), (2700, Q(300.0))], Cw=None, seed=35)
SCENARIOS["M9_Qliq250_Cnull"] = base("M9_Qliq250_Cnull", "ParaHydrogen", VC5, 1.3e5, 0.6, 8e5, 3600,
    [(0, Q(300.0)), (1800, {"Q_aw_W": 300.0, "mdot_v_out_kg_s": 1.5e-3}), (2700, Q(300.0))], Cw=None,
    hidden={"Q_liq_W": 250.0}, seed=36)

SCENARIOS["M6c_fastfill_vent_bias18"] = base("M6c_fastfill_vent_bias18", "ParaHydrogen", VC5, 1.4e5, 0.3, 8e5, 3600,
    [(0, Q(300.0)), (900, {"Q_aw_W": 300.0, "mdot_l_in_kg_s": 0.08, "T_l_in_K": 20.5, "mdot_v_out_kg_s": 4e-3}), (2700, Q(300.0))],
    hidden={"inflow_bias": 0.18}, seed=41)
SCENARIOS["M6d_slowfill_novent_bias18"] = base("M6d_slowfill_novent_bias18", "ParaHydrogen", VC5, 1.3e5, 0.4, 8e5, 5400,
    [(0, Q(300.0)), (900, {"Q_aw_W": 300.0, "mdot_l_in_kg_s": 0.03, "T_l_in_K": 20.6}), (3600, Q(300.0))],
    hidden={"inflow_bias": 0.18}, seed=42)

# ---- helium and a thermometer with a vent or a drain, methane, warm gas, a sphere, nitrogen
SCENARIOS["O1b_helium15_vent"] = base("O1b_helium15_vent", "ParaHydrogen", VC5, 1.4e5, 0.6, 8e5, 3600,
    [(0, Q(300.0)), (1200, {"Q_aw_W": 300.0, "mdot_v_out_kg_s": 2e-3}), (2400, Q(300.0))],
    hidden={"helium_frac": 0.15}, seed=51)
SCENARIOS["O2b_Tlbias_drain"] = base("O2b_Tlbias_drain", "ParaHydrogen", VC5, 1.3e5, 0.7, 8e5, 3600,
    [(0, Q(300.0)), (1200, {"Q_aw_W": 300.0, "mdot_l_out_kg_s": 0.05}), (2400, Q(300.0))],
    hidden={"T_l_bias_K": 0.5}, seed=52)
SCENARIOS["N8_methane_hcyl_vent"] = base("N8_methane_hcyl_vent", "Methane",
    {"shape": "horizontal_cylinder", "radius_m": 1.0, "cylinder_length_m": 5.0}, 1.3e5, 0.65, 2.5e6, 4800,
    [(0, Q(1500.0)), (2400, {"Q_aw_W": 1500.0, "mdot_v_out_kg_s": 8e-3}), (3600, Q(1500.0))], seed=53,
    dTv=4.0, dTwd=8.0, ns={"p_v": 500.0, "T_v": 0.1, "T_l": 0.05, "T_w": 0.1, "H_l": 0.001})
SCENARIOS["N9_ell_press300K_Cnull"] = base("N9_ell_press300K_Cnull", "ParaHydrogen",
    {"shape": "vertical_cylinder_elliptical_heads", "radius_m": 1.2, "cylinder_length_m": 2.0, "head_aspect": 2.0},
    1.2e5, 0.5, 2e6, 3600,
    [(0, Q(400.0)), (600, {"Q_aw_W": 400.0, "mdot_v_in_kg_s": 4e-3, "T_v_in_K": 300.0, "p_v_in_Pa": 6e5}), (1500, Q(400.0))],
    Cw=None, seed=54, ns={"p_v": 300.0, "T_v": 0.05, "T_l": 0.03, "H_l": 0.001},
    rates={"p": 3, "T_v": 6, "T_l": 6, "H": 7})
SCENARIOS["M10_Qull500_sphere_vent"] = base("M10_Qull500_sphere_vent", "ParaHydrogen", {"shape": "sphere", "radius_m": 1.1}, 1.5e5, 0.55, 6e5, 3600,
    [(0, Q(200.0)), (1800, {"Q_aw_W": 200.0, "mdot_v_out_kg_s": 1.5e-3}), (2700, Q(200.0))],
    hidden={"Q_ull_W": 500.0}, seed=55)
SCENARIOS["M11_N2_vleak1g"] = base("M11_N2_vleak1g", "Nitrogen",
    {"shape": "vertical_cylinder_elliptical_heads", "radius_m": 0.8, "cylinder_length_m": 3.0, "head_aspect": 2.0},
    1.6e5, 0.5, 1.2e6, 3600, [(0, Q(600.0))], hidden={"vapor_leak_kg_s": 1e-3}, seed=56, dTv=3.0, dTwd=6.0,
    ns={"p_v": 400.0, "T_v": 0.1, "T_l": 0.05, "T_w": 0.1, "H_l": 0.001})

SCENARIOS["N9b_ell_press300K_Cstated"] = base("N9b_ell_press300K_Cstated", "ParaHydrogen",
    {"shape": "vertical_cylinder_elliptical_heads", "radius_m": 1.2, "cylinder_length_m": 2.0, "head_aspect": 2.0},
    1.2e5, 0.5, 2e6, 3600,
    [(0, Q(400.0)), (600, {"Q_aw_W": 400.0, "mdot_v_in_kg_s": 4e-3, "T_v_in_K": 300.0, "p_v_in_Pa": 6e5}), (1500, Q(400.0))],
    seed=57)

def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description="blind_sim: writes runs in the interchange format")
    ap.add_argument("names", nargs="+", help=f"scenarios: {', '.join(SCENARIOS)}")
    ap.add_argument("--out", required=True, help="output folder")
    args = ap.parse_args(argv)
    for n in args.names:
        simulate(SCENARIOS[n], args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
