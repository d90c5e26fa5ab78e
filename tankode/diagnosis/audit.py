"""Inventory audit: the tank's mass and energy from its sensors, reconciled with the metered inputs.

Heat and mass exchanged between the ullage, the liquid and the wall cancel in the whole tank's
balances, so the inventory says what entered or left the tank without any heat-transfer law
(data reconciliation and gross-error detection on the mass and energy balances, as process
engineering does it; e.g. Narasimhan & Jordache, *Data Reconciliation and Gross Error
Detection*, 2000). Per run:

1. **Smooth each sensor.** Each measured channel (p_v, T_v, T_l, T_w, H_l) is fitted, per
   operating phase (constant metered inputs), by a piecewise-linear curve with knots every
   ``knot_s`` seconds (weighted least squares with the run's ``noise_std``; a weak curvature
   penalty keeps knots without samples defined). The fit's covariance carries the sensor noise.
2. **Reconstruct the inventory** at the knots with the reference equation of state (CoolProp,
   not the model's surrogate): ``M = rho_v(p, T_v) V_v + rho_l(p, T_l) V_l`` and
   ``E = m_v u_v + m_l u_l + C_w T_w``, the liquid volume from the level (``V_l(H_l)``). Each
   phase is evaluated on its own branch; an ullage reading colder than saturation is evaluated
   at saturation (and reported, step 5). The covariance of (M, E) follows by linearisation.
3. **Subtract the metered inventory**: the integrals of the inflows and outflows (vents at the
   ullage's enthalpy, drains at the liquid's, inflows at their metered states) and of ``Q_aw``.
   What remains, ``r(t)``, is what the meters did not see.
4. **Estimate the unmetered rates** by generalised least squares of ``r(t)`` on a straight line
   in each phase (mass in kg/s, heat in W) and over the run. The energy fit also estimates a
   correction of the wall heat capacity where the wall temperature is measured and changes (a
   stated ``C_w`` that is wrong shows as heat proportional to ``dT_w/dt``; an unknown one gets a
   prior of ``wall_capacity_prior`` relative). Where the straight line does not fit within the
   noise (a fast transient, a state the sensors resolve badly), the standard errors are scaled
   by the Birge ratio ``sqrt(chi2/dof)``: model error widens the interval instead of naming a leak.
5. **Test the sensors' thermodynamic consistency**: a pure ullage cannot stay colder than
   saturation at its pressure, nor a liquid warmer. A persistent violation beyond the noise is
   evidence of an inert gas (its partial pressure at least ``p - p_sat(T_v)``) or of a biased
   pressure or temperature sensor; it is reported, never a reason to stop.
6. **Name what the balances show** (``InventoryFinding``): unmetered heat (its location is not
   observable in the whole-tank balance: it is named with the places it may enter), unmetered
   mass loss, classified by the enthalpy it carries (``h_v``: a vapour leak; ``h_l``: a liquid
   leak) when one hypothesis explains both balances and the others are rejected, an inflow meter
   bias when the unmetered mass follows the metered inflows, a wall heat capacity error.

Without a level sensor the mass balance is not observable: the liquid volume is then taken from
the metered mass (no leak assumed) and only the energy balance is audited. Without a wall
temperature the wall's energy is taken to follow the liquid's temperature, with an uncertainty
of half the ullage-liquid temperature change times the heat capacity.

Limits: each phase is treated as well mixed at its mass-averaged temperature (what the format's
sensors report); a stratified phase read by one sensor is a bias the audit cannot see. Rates are
assumed constant over a phase (the run-wide estimate assumes them constant over the run; a test
of that is reported as ``chi2_between_phases``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..run import NOISE_KEYS, OBS_CHANNELS, Run
from ..schedule import INPUT_NAMES

_CH = {c: i for i, c in enumerate(OBS_CHANNELS)}
_IN = {n: i for i, n in enumerate(INPUT_NAMES)}


@dataclass(frozen=True)
class AuditConfig:
    """How the inventory audit smooths, tests and names (module docstring)."""

    # s; knot spacing of each channel's piecewise-linear fit: resolves a tank's minute-scale
    # transients while averaging ~dozens of samples per knot at typical 5-20 s sampling.
    knot_s: float = 300.0
    # s; shorter operating phases are merged into the next (their rate is not resolved alone).
    min_phase_s: float = 240.0
    # A rate is named when it is this many standard errors from zero (gross-error test).
    z_name: float = 5.0
    # Hypotheses explaining both balances are told apart when the others' chi2 is this much larger.
    chi2_separation: float = 9.0
    # Relative prior standard deviation of a wall heat capacity the run does not state.
    wall_capacity_prior: float = 0.5
    # Relative weight of the curvature penalty (per knot, in units of the channel's noise).
    smoothing: float = 1e-3

    def __post_init__(self):
        for name in ("knot_s", "min_phase_s", "z_name", "chi2_separation", "wall_capacity_prior", "smoothing"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"AuditConfig.{name} must be finite and > 0, got {v}")


@dataclass(frozen=True)
class Estimate:
    """A value with its standard error (SI units of what it estimates)."""

    value: float
    std: float

    @property
    def z(self) -> float:
        """value / std (0 where the std is not finite)."""
        return self.value / self.std if self.std > 0 and math.isfinite(self.std) else 0.0

    def __str__(self) -> str:
        return f"{self.value:.3g} +- {self.std:.2g}"


@dataclass(frozen=True)
class PhaseAudit:
    """Unmetered rates over one operating phase ``[t0_s, t1_s]``."""

    t0_s: float
    t1_s: float
    kind: str  # the operations of the phase, e.g. "vent", "hold", "vapour inflow, sloshing"
    mass_kg_s: Estimate | None  # None: no level sensor
    heat_W: Estimate
    inflow_kg_s: float  # metered inflow (vapour + liquid) during the phase
    inflow_enthalpy_J_per_kg: float  # their mean specific enthalpy (0 without inflow)
    h_v_J_per_kg: float  # mean enthalpy of the ullage and of the liquid over the phase: what a leak carries
    h_l_J_per_kg: float
    birge_mass: float  # sqrt(chi2 / dof) of the straight line (1 = fits within the noise)
    birge_heat: float


@dataclass(frozen=True)
class InventoryFinding:
    """What the balances show: a name (a mechanism id or a group), the estimate, and what it may be."""

    name: str  # "unmetered_heat", "vapor_leak", "liquid_leak", "unmetered_mass", "inflow_meter_bias",
    #            "wall_heat_capacity_error", "inert_gas_or_sensor_bias"
    estimate: Estimate | None
    unit: str
    candidates: tuple[str, ...]  # mechanism ids the finding is consistent with
    sentence: str


@dataclass(frozen=True)
class RunAudit:
    """The audit of one run (module docstring)."""

    run: str
    phases: tuple[PhaseAudit, ...]
    mass_kg_s: Estimate | None
    heat_W: Estimate
    wall_capacity_factor: Estimate | None  # true C_w / stated (or assumed) C_w
    chi2_between_phases: float  # of the run-wide heat estimate against the phases' (dof = phases - 1)
    consistency: tuple[str, ...]
    findings: tuple[InventoryFinding, ...]
    series: dict = field(repr=False)  # t_s, residual mass / energy and their std, for the figure

    def summary(self) -> str:
        """One paragraph: the run-wide rates and what is named."""
        mass = f"unmetered mass {self.mass_kg_s} kg/s" if self.mass_kg_s else "no level sensor: mass not audited"
        named = "; ".join(f.sentence for f in self.findings) or "nothing unmetered beyond the noise"
        return f"{self.run}: {mass}, unmetered heat {self.heat_W} W. {named}"


# ----------------------------------------------------------------------------- smoothing
def _phases(run: Run, min_phase_s: float) -> list[tuple[float, float]]:
    cuts = [run.t0_s, *[float(t) for t in run.inputs.breakpoints(run.t0_s, run.t_end_s)], run.t_end_s]
    spans = [(a, b) for a, b in zip(cuts[:-1], cuts[1:]) if b > a]
    merged: list[list[float]] = []
    for a, b in spans:
        if merged and (merged[-1][1] - merged[-1][0] < min_phase_s):
            merged[-1][1] = b  # a short phase joins the next
        else:
            merged.append([a, b])
    if len(merged) > 1 and merged[-1][1] - merged[-1][0] < min_phase_s:
        merged[-2][1] = merged[-1][1]
        merged.pop()
    return [(a, b) for a, b in merged]


def _hat_basis(t: np.ndarray, knots: np.ndarray) -> np.ndarray:
    """Piecewise-linear (hat) basis ``(len(t), len(knots))``."""
    B = np.zeros((len(t), len(knots)))
    j = np.clip(np.searchsorted(knots, t, side="right") - 1, 0, len(knots) - 2)
    w = (t - knots[j]) / (knots[j + 1] - knots[j])
    B[np.arange(len(t)), j] = 1 - w
    B[np.arange(len(t)), j + 1] = w
    return B


def _smooth(t: np.ndarray, y: np.ndarray, sigma: float, knots: np.ndarray, smoothing: float):
    """Values at the knots and their covariance, or None when the channel has under 3 samples."""
    if len(t) < 3:
        return None
    B = _hat_basis(t, knots) / sigma
    n = len(knots)
    D = np.diff(np.eye(n), 2, axis=0) if n >= 3 else np.zeros((0, n))
    A = B.T @ B + smoothing * D.T @ D + 1e-12 * np.eye(n)
    cov = np.linalg.inv(A)
    return cov @ (B.T @ (y / sigma)), cov


def _knots(a: float, b: float, spacing: float) -> np.ndarray:
    n = max(2, int(round((b - a) / spacing)) + 1)
    return np.linspace(a, b, n)


# ----------------------------------------------------------------------------- thermodynamics
class _Thermo:
    """CoolProp states of the two phases, each on its own branch (a too-cold ullage at saturation)."""

    def __init__(self, fluid: str):
        from ..properties import CoolPropFluid

        self.ref = CoolPropFluid(fluid)

    def T_sat(self, p: float) -> float:
        return float(self.ref.saturation(p)["T_sat"])

    def phase(self, p: float, T: float, phase: str) -> tuple[float, float, float]:
        """(rho, u, h) of ``phase`` at (p, T); a state past the branch's end is taken at saturation."""
        T_sat = self.T_sat(p)
        if phase == "vapor" and T < T_sat:
            T = T_sat
        if phase == "liquid" and T > T_sat:
            T = T_sat
        try:
            s = self.ref.state_pT(p, T, phase)
        except ValueError:
            s = self.ref.state_pT(p, T_sat, phase)
        return float(s["rho"]), float(s["u"]), float(s["h"])


def _inventory(thermo: _Thermo, V_tank: float, x: np.ndarray, V_l: float, C_w: float, wall_T: float):
    """(M, E, m_v, h_v, h_l) at the channel values ``x`` (p, T_v, T_l, T_w, H_l) with liquid volume ``V_l``."""
    p, T_v, T_l = x[0], x[1], x[2]
    rv, uv, hv = thermo.phase(p, T_v, "vapor")
    rl, ul, hl = thermo.phase(p, T_l, "liquid")
    m_v, m_l = rv * (V_tank - V_l), rl * V_l
    return m_v + m_l, m_v * uv + m_l * ul + C_w * wall_T, hv, hl


def _gls(X: np.ndarray, r: np.ndarray, C: np.ndarray):
    """Generalised least squares: coefficients, their covariance, chi2 and dof."""
    n, k = X.shape
    C = C + np.eye(n) * 1e-12 * max(float(np.trace(C)) / n, 1e-300)
    L = np.linalg.cholesky(C)
    Xw = np.linalg.solve(L, X)
    rw = np.linalg.solve(L, r)
    coef, *_ = np.linalg.lstsq(Xw, rw, rcond=None)
    cov = np.linalg.pinv(Xw.T @ Xw)
    res = rw - Xw @ coef
    return coef, cov, float(res @ res), max(n - k, 1)


def _birge(chi2: float, dof: int) -> float:
    return max(1.0, math.sqrt(chi2 / dof))


def _kind(u: np.ndarray) -> str:
    parts = [name for name, on in (("vapour inflow", u[_IN["mdot_v_in_kg_s"]] > 0), ("vent", u[_IN["mdot_v_out_kg_s"]] > 0),
                                    ("liquid inflow", u[_IN["mdot_l_in_kg_s"]] > 0), ("drain", u[_IN["mdot_l_out_kg_s"]] > 0),
                                    ("sloshing", u[_IN["slosh_amplitude_m"]] > 0)) if on]
    return ", ".join(parts) or "hold"


# ----------------------------------------------------------------------------- the audit
def audit_run(run: Run, config: AuditConfig = AuditConfig(), wall_heat_capacity_J_per_K: float | None = None,
              wall_capacity_assumed: bool = False) -> RunAudit:
    """Audit one run's mass and energy (module docstring).

    Args:
        run: a measured run (p_v, T_v and T_l measured; H_l and T_w where available).
        config: an ``AuditConfig``.
        wall_heat_capacity_J_per_K: m_w c_w (J/K); the run's when None (and an aluminium-shell
            estimate when the run states none, ``tankode.wall``).
        wall_capacity_assumed: the value is an estimate (gets the ``wall_capacity_prior``).

    Raises:
        ValueError: the run does not measure p_v, T_v and T_l (the inventory needs them).
    """
    from ..wall import resolve_wall_heat_capacity

    missing = [c for c in ("p_v_Pa", "T_v_K", "T_l_K") if c not in run.observations.measured_channels]
    if missing:
        raise ValueError(f"run {run.name!r}: the inventory audit needs p_v_Pa, T_v_K and T_l_K measured, not {missing}")
    geometry = run.tank.geometry()
    V_tank = float(geometry.volume_m3)
    if wall_heat_capacity_J_per_K is None:
        w = resolve_wall_heat_capacity(run.tank.wall_heat_capacity_J_per_K, float(geometry.wall_area_m2),
                                       run.initial.T_w0_K)
        C_w, wall_capacity_assumed = w.value_J_per_K, w.assumed
    else:
        C_w = float(wall_heat_capacity_J_per_K)
    has_level = "H_l_m" in run.observations.measured_channels
    has_wall = "T_w_K" in run.observations.measured_channels
    thermo = _Thermo(run.fluid)
    sched = run.inputs

    def volume_at(H: float) -> float:
        import torch

        return float(geometry.volume_at_level(torch.tensor(H, dtype=torch.float64)))

    phases, rows_M, rows_E = [], [], []
    series = {k: [] for k in ("t_s", "mass_kg", "mass_std", "energy_J", "energy_std")}
    consistency_cold, consistency_hot = [], []
    M_prev_end = None
    for a, b in _phases(run, config.min_phase_s):
        t_obs = run.observations.t_s
        # Knots no closer than three samples of the sparsest channel the audit needs.
        spacing = config.knot_s
        for c in ("p_v_Pa", "T_v_K", "T_l_K") + (("H_l_m",) if has_level else ()) + (("T_w_K",) if has_wall else ()):
            tc, _ = run.observations.channel(c)
            tc = tc[(tc >= a) & (tc <= b)]
            if len(tc) >= 2:
                spacing = max(spacing, 3 * float(np.median(np.diff(tc))))
        knots = _knots(a, b, spacing)
        fits = {}
        for c in OBS_CHANNELS:
            tc, yc = run.observations.channel(c)
            sel = (tc >= a) & (tc <= b)
            fits[c] = _smooth(tc[sel], yc[sel], run.noise_std[NOISE_KEYS[_CH[c]]], knots, config.smoothing) \
                if c in run.observations.measured_channels else None
        if any(fits[c] is None for c in ("p_v_Pa", "T_v_K", "T_l_K")):
            continue  # too few samples in this phase to audit it
        level_ok = has_level and fits["H_l_m"] is not None
        wall_ok = has_wall and fits["T_w_K"] is not None
        u = sched.at(a)
        n = len(knots)
        vals = np.zeros((n, 5))
        covs = [np.zeros((n, n)) for _ in range(5)]
        for c, j in _CH.items():
            if fits[c] is not None:
                vals[:, j], covs[j] = fits[c]
        # Metered mass flows in the phase (constant) and the inflow enthalpies.
        m_vin, m_vout = u[_IN["mdot_v_in_kg_s"]], u[_IN["mdot_v_out_kg_s"]]
        m_lin, m_lout = u[_IN["mdot_l_in_kg_s"]], u[_IN["mdot_l_out_kg_s"]]
        h_vin = thermo.ref.state_pT(u[_IN["p_v_in_Pa"]], u[_IN["T_v_in_K"]], "vapor")["h"].item() if m_vin > 0 else 0.0
        # Liquid volume: from the level, or (no level sensor) from the metered mass.
        M_meter0 = None
        if not level_ok:
            if M_prev_end is None:
                x0 = vals[0]
                V_l0 = run.initial.fill_ratio * V_tank
                M_meter0 = _inventory(thermo, V_tank, x0, V_l0, C_w, x0[3] if wall_ok else x0[2])[0]
        Ms, Es, hvs, hls, Jm, Je = [], [], [], [], [], []
        dt_k = np.diff(knots, prepend=knots[0])
        cum_M_k = 0.0
        for k in range(n):
            x = vals[k].copy()
            wall_T = x[3] if wall_ok else x[2]
            if k > 0:
                cum_M_k += (m_vin + m_lin - m_vout - m_lout) * dt_k[k]
            if level_ok:
                V_l = volume_at(x[4])
            else:
                target = (M_meter0 if M_meter0 is not None else M_prev_end) + cum_M_k
                V_l = _liquid_volume_for_mass(thermo, V_tank, x, target)
            M, E, hv, hl = _inventory(thermo, V_tank, x, V_l, C_w, wall_T)
            Ms.append(M), Es.append(E), hvs.append(hv), hls.append(hl)
            # Jacobian of (M, E) in the channels by central differences.
            gm, ge = np.zeros(5), np.zeros(5)
            for j, c in enumerate(OBS_CHANNELS):
                if fits[c] is None or (c == "H_l_m" and not level_ok) or (c == "T_w_K" and not wall_ok):
                    continue
                step = {"p_v_Pa": 50.0, "T_v_K": 0.01, "T_l_K": 0.005, "T_w_K": 0.01, "H_l_m": 1e-4}[c]
                xp, xm = x.copy(), x.copy()
                xp[j] += step
                xm[j] -= step
                V_p = volume_at(xp[4]) if level_ok else V_l
                V_m = volume_at(xm[4]) if level_ok else V_l
                Mp, Ep, _, _ = _inventory(thermo, V_tank, xp, V_p, C_w, xp[3] if wall_ok else xp[2])
                Mm, Em, _, _ = _inventory(thermo, V_tank, xm, V_m, C_w, xm[3] if wall_ok else xm[2])
                gm[j], ge[j] = (Mp - Mm) / (2 * step), (Ep - Em) / (2 * step)
            Jm.append(gm), Je.append(ge)
        Ms, Es, Jm, Je = np.array(Ms), np.array(Es), np.array(Jm), np.array(Je)
        hvs, hls = np.array(hvs), np.array(hls)
        # Metered cumulative inventory over the phase (trapezoid for state-dependent enthalpies).
        flow_M = np.full(n, m_vin + m_lin - m_vout - m_lout)
        h_lin = np.array([thermo.ref.state_pT(vals[k, 0], u[_IN["T_l_in_K"]], "liquid")["h"].item()
                          for k in range(n)]) if m_lin > 0 else np.zeros(n)
        flow_E = m_vin * h_vin + m_lin * h_lin - m_vout * hvs - m_lout * hls + u[_IN["Q_aw_W"]]
        cumM = np.concatenate([[0.0], np.cumsum(0.5 * (flow_M[1:] + flow_M[:-1]) * np.diff(knots))])
        cumE = np.concatenate([[0.0], np.cumsum(0.5 * (flow_E[1:] + flow_E[:-1]) * np.diff(knots))])
        rM = Ms - Ms[0] - cumM
        rE = Es - Es[0] - cumE
        CM = sum(np.outer(Jm[:, j], Jm[:, j]) * covs[j] for j in range(5))
        CE = sum(np.outer(Je[:, j], Je[:, j]) * covs[j] for j in range(5))
        if not wall_ok:  # the wall's energy taken to follow the liquid: half the ullage-liquid gap as its std
            gap = C_w * 0.5 * np.abs((vals[:, 1] - vals[0, 1]) - (vals[:, 2] - vals[0, 2]))
            CE = CE + np.diag(gap**2)
        tt = knots - a
        X = np.stack([np.ones(n), tt], axis=1)
        mass_est = None
        birge_m = 1.0
        if level_ok:
            cm, vm, chi_m, dof_m = _gls(X, rM, CM)
            birge_m = _birge(chi_m, dof_m)
            mass_est = Estimate(float(cm[1]), float(math.sqrt(max(vm[1, 1], 0.0))) * birge_m)
            rows_M.append((X, rM, CM))
        ce, ve, chi_e, dof_e = _gls(X, rE, CE)
        birge_e = _birge(chi_e, dof_e)
        heat_est = Estimate(float(ce[1]), float(math.sqrt(max(ve[1, 1], 0.0))) * birge_e)
        dT_w = (vals[:, 3] - vals[0, 3]) if wall_ok else np.zeros(n)
        rows_E.append((tt, rE, CE, C_w * dT_w, birge_e))
        m_in = m_vin + m_lin
        phases.append(PhaseAudit(a, b, _kind(u), mass_est, heat_est, float(m_in),
                                 float((m_vin * h_vin + m_lin * float(h_lin.mean())) / m_in) if m_in > 0 else 0.0,
                                 float(hvs.mean()), float(hls.mean()), birge_m, birge_e))
        # Figure: residuals since the run's start (phases joined at their ends).
        offM = series["mass_kg"][-1] if series["mass_kg"] else 0.0
        offE = series["energy_J"][-1] if series["energy_J"] else 0.0
        series["t_s"].extend(knots.tolist())
        series["mass_kg"].extend((offM + rM).tolist() if level_ok else [float("nan")] * n)
        series["mass_std"].extend(np.sqrt(np.clip(np.diag(CM), 0, None)).tolist() if level_ok else [float("nan")] * n)
        series["energy_J"].extend((offE + rE).tolist())
        series["energy_std"].extend(np.sqrt(np.clip(np.diag(CE), 0, None)).tolist())
        M_prev_end = Ms[-1]
        # Step 5: thermodynamic consistency at the knots.
        for k in range(n):
            p, T_v, T_l = vals[k, 0], vals[k, 1], vals[k, 2]
            T_sat = thermo.T_sat(p)
            sv = math.sqrt(covs[1][k, k] + (covs[0][k, k] * _dTsat_dp(thermo, p) ** 2))
            sl = math.sqrt(covs[2][k, k] + (covs[0][k, k] * _dTsat_dp(thermo, p) ** 2))
            if T_v < T_sat - max(3 * sv, 0.05):
                consistency_cold.append((knots[k], T_sat - T_v, p, T_v))
            if T_l > T_sat + max(3 * sl, 0.05):
                consistency_hot.append((knots[k], T_l - T_sat, p, T_l))
    if not phases:
        raise ValueError(f"run {run.name!r}: no operating phase has enough samples of p_v, T_v and T_l to audit")

    mass = _combine([p.mass_kg_s for p in phases]) if has_level else None
    heat_run, cw_factor, chi2_between = _run_heat(rows_E, phases, C_w, wall_capacity_assumed, config)
    consistency = _consistency_sentences(thermo, consistency_cold, consistency_hot, series)
    findings = _name(run, phases, mass, heat_run, cw_factor, consistency_cold, thermo, config, has_level)
    return RunAudit(run.name, tuple(phases), mass, heat_run, cw_factor, chi2_between, tuple(consistency),
                    tuple(findings), {k: np.asarray(v) for k, v in series.items()})


def _liquid_volume_for_mass(thermo: _Thermo, V_tank: float, x: np.ndarray, M: float) -> float:
    rv, _, _ = thermo.phase(x[0], x[1], "vapor")
    rl, _, _ = thermo.phase(x[0], x[2], "liquid")
    return float(np.clip((M - rv * V_tank) / (rl - rv), 0.0, V_tank))


def _dTsat_dp(thermo: _Thermo, p: float) -> float:
    return (thermo.T_sat(p + 100.0) - thermo.T_sat(p - 100.0)) / 200.0


def _combine(estimates) -> Estimate | None:
    est = [e for e in estimates if e is not None and e.std > 0 and math.isfinite(e.std)]
    if not est:
        return None
    w = np.array([1 / e.std**2 for e in est])
    v = np.array([e.value for e in est])
    mean = float((w * v).sum() / w.sum())
    std = float(1 / math.sqrt(w.sum()))
    chi2 = float((w * (v - mean) ** 2).sum())
    return Estimate(mean, std * _birge(chi2, max(len(est) - 1, 1)))


def _run_heat(rows_E, phases, C_w, assumed, config):
    """Run-wide unmetered heat and wall-capacity correction by one GLS over every phase."""
    n_ph = len(rows_E)
    blocks, rs, Xs = [], [], []
    use_wall = any(np.ptp(row[3]) > 0 for row in rows_E)
    k_extra = 2 if use_wall else 1
    for i, (tt, rE, CE, wall_term, birge) in enumerate(rows_E):
        X = np.zeros((len(tt), n_ph + k_extra))
        X[:, i] = 1.0
        X[:, n_ph] = tt
        if use_wall:
            X[:, n_ph + 1] = wall_term
        Xs.append(X)
        rs.append(rE)
        blocks.append(CE * birge**2)
    X = np.concatenate(Xs)
    r = np.concatenate(rs)
    C = np.zeros((len(r), len(r)))
    o = 0
    for B in blocks:
        C[o:o + len(B), o:o + len(B)] = B
        o += len(B)
    if use_wall:
        # A prior on the wall heat capacity's correction: tight where the run states it, wide where assumed.
        prior = config.wall_capacity_prior if assumed else 0.5 * config.wall_capacity_prior
        X = np.vstack([X, np.eye(1, n_ph + k_extra, n_ph + 1)])
        r = np.append(r, 0.0)
        C2 = np.zeros((len(r), len(r)))
        C2[:-1, :-1] = C
        C2[-1, -1] = prior**2
        C = C2
    coef, cov, chi2, dof = _gls(X, r, C)
    cov = cov * _birge(chi2, dof) ** 2  # the joint line's misfit widens both estimates
    heat = Estimate(float(coef[n_ph]), float(math.sqrt(max(cov[n_ph, n_ph], 0.0))))
    factor = Estimate(1.0 + float(coef[n_ph + 1]), float(math.sqrt(max(cov[n_ph + 1, n_ph + 1], 0.0)))) if use_wall else None
    per = [p.heat_W for p in phases]
    w = np.array([1 / e.std**2 for e in per])
    v = np.array([e.value for e in per])
    chi2_between = float((w * (v - (w * v).sum() / w.sum()) ** 2).sum())
    return heat, factor, chi2_between


def _consistency_sentences(thermo, cold, hot, series) -> list[str]:
    out = []
    if cold:
        t, dT, p, T_v = max(cold, key=lambda c: c[1])
        p_sat = _p_sat(thermo, T_v)
        out.append(f"the ullage reads colder than saturation at the measured pressure at {len(cold)} of "
                   f"{len(series['t_s'])} audit times, by up to {dT:.2f} K (t = {t:.0f} s): a pure vapour would "
                   f"condense; an inert gas with a partial pressure of at least {p - p_sat:.4g} Pa, or a biased "
                   "pressure or ullage temperature sensor")
    if hot:
        t, dT, p, T_l = max(hot, key=lambda c: c[1])
        out.append(f"the liquid reads warmer than saturation at the measured pressure at {len(hot)} of "
                   f"{len(series['t_s'])} audit times, by up to {dT:.2f} K (t = {t:.0f} s): a pressure sensor "
                   "reading low or a biased liquid temperature sensor")
    return out


def _p_sat(thermo: _Thermo, T: float) -> float:
    import CoolProp.CoolProp as CP

    return float(CP.PropsSI("P", "T", T, "Q", 0, thermo.ref.name))


def _name(run, phases, mass, heat, cw_factor, cold, thermo, config, has_level) -> list[InventoryFinding]:
    """The findings of the balances (module docstring, step 6)."""
    out: list[InventoryFinding] = []
    z = config.z_name
    heat_named = abs(heat.z) >= z
    mass_named = mass is not None and abs(mass.z) >= z
    if cw_factor is not None and abs(cw_factor.value - 1) / max(cw_factor.std, 1e-300) >= z:
        out.append(InventoryFinding("wall_heat_capacity_error", cw_factor, "x stated", ("wall_heat_capacity_error",),
                                    f"the wall stores heat as {cw_factor.value:.3g} +- {cw_factor.std:.2g} times "
                                    "the stated heat capacity"))
    if mass_named:
        # Which single mechanism explains both balances, phase by phase?
        hyps = _mass_hypotheses(phases)
        best = min(hyps, key=lambda h: hyps[h][0])
        others = sorted(hyps[h][0] - hyps[best][0] for h in hyps if h != best)
        rate, rate_std = hyps[best][1], hyps[best][2]
        if best == "inflow_meter_bias" and (not others or others[0] >= config.chi2_separation):
            out.append(InventoryFinding("inflow_meter_bias", Estimate(rate, rate_std), "relative",
                                        ("inflow_meter_bias",),
                                        f"the metered inflows are off by a factor {1 + rate:.3g} (+- {rate_std:.2g}): "
                                        "the unmetered mass follows the metered inflow"))
            return out
        if best in ("vapor_leak", "liquid_leak") and (not others or others[0] >= config.chi2_separation) \
                and not heat_named_after_leak(hyps, best, config):
            out.append(InventoryFinding(best, Estimate(-mass.value, mass.std), "kg/s", (best,),
                                        f"unmetered mass loss of {-mass.value:.3g} +- {mass.std:.2g} kg/s carrying "
                                        f"the {'ullage' if best == 'vapor_leak' else 'liquid'}'s enthalpy: a "
                                        f"{'vapour' if best == 'vapor_leak' else 'liquid'} leak"))
            return out
        kind = "loss" if mass.value < 0 else "gain"
        out.append(InventoryFinding("unmetered_mass", mass, "kg/s",
                                    ("vapor_leak", "liquid_leak", "inflow_meter_bias"),
                                    f"unmetered mass {kind} of {abs(mass.value):.3g} +- {mass.std:.2g} kg/s; which "
                                    "stream carries it is not resolved by the balances (with unmetered heat {heat} W "
                                    "beside it): a vapour or liquid leak, or a metered flow that is off".replace(
                                        "{heat}", f"{heat.value:.3g} +- {heat.std:.2g}")))
        return out
    if heat_named:
        where = "entering" if heat.value > 0 else "leaving"
        candidates = ("heat_leak_wall", "heat_leak_liquid", "heat_leak_vapor")
        note = "" if has_level else " (no level sensor: an unmetered mass loss would read as heat too)"
        out.append(InventoryFinding("unmetered_heat", heat, "W", candidates,
                                    f"unmetered heat {heat.value:.3g} +- {heat.std:.2g} W {where} the tank: through "
                                    f"the wall, the liquid or the ullage, which the whole-tank balance cannot tell apart{note}"))
    if cold:
        out.append(InventoryFinding("inert_gas_or_sensor_bias", None, "", ("noncondensable_gas", "pressure_sensor_bias"),
                                    "the ullage reads colder than saturation at the measured pressure: an inert gas or "
                                    "a biased pressure or temperature sensor"))
    return out


def heat_named_after_leak(hyps, best, config) -> bool:
    """Whether the leak hypothesis leaves a significant heat residual (then the stream is not resolved)."""
    return hyps[best][3] >= config.z_name


def _mass_hypotheses(phases) -> dict:
    """chi2 of each single-mechanism hypothesis over the phases' (mass, heat) estimates, with its rate.

    Returns ``{name: (chi2, rate, rate_std, |z| of the heat left over)}``: a leak of constant rate L
    (kg/s) carries ``-L h`` of energy with ``h`` the ullage's or the liquid's enthalpy; an inflow bias
    ``b`` adds ``b mdot_in`` of mass and ``b mdot_in h_in`` of energy in the inflow phases only.
    """
    rows = [(p.mass_kg_s, p.heat_W, p) for p in phases if p.mass_kg_s is not None]
    out = {}
    for name in ("vapor_leak", "liquid_leak", "inflow_meter_bias"):
        A, y, w = [], [], []
        for m, e, p in rows:
            if name == "inflow_meter_bias":
                am, ae = p.inflow_kg_s, p.inflow_kg_s * p.inflow_enthalpy_J_per_kg
            else:
                h = _phase_enthalpy(p, name)
                am, ae = -1.0, -h
            A += [am, ae]
            y += [m.value, e.value]
            w += [1 / m.std**2, 1 / e.std**2]
        A, y, w = np.array(A), np.array(y), np.array(w)
        denom = float((w * A * A).sum())
        if denom <= 0:
            out[name] = (float("inf"), 0.0, float("inf"), 0.0)
            continue
        rate = float((w * A * y).sum() / denom)
        res = y - A * rate
        chi2 = float((w * res * res).sum())
        # heat left over: the energy rows' residual, as a z-score of their weighted mean
        we, re = w[1::2], res[1::2]
        z_left = abs(float((we * re).sum() / we.sum()) * math.sqrt(we.sum()))
        out[name] = (chi2, rate, float(1 / math.sqrt(denom)), z_left)
    return out


def _phase_enthalpy(p: PhaseAudit, name: str) -> float:
    return p.h_v_J_per_kg if name == "vapor_leak" else p.h_l_J_per_kg


__all__ = ["AuditConfig", "Estimate", "PhaseAudit", "InventoryFinding", "RunAudit", "audit_run"]
