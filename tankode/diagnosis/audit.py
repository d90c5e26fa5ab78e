"""Inventory audit: the tank's mass and energy from its sensors, reconciled with the metered inputs.

Heat and mass exchanged between the ullage, the liquid and the wall cancel in the whole tank's
balances, so the inventory says what entered or left the tank without any heat-transfer law
(data reconciliation and gross-error detection on the mass and energy balances, as process
engineering does it; e.g. Narasimhan & Jordache, *Data Reconciliation and Gross Error
Detection*, 2000). Per run:

1. **Smooth each sensor.** Each measured channel (p_v, T_v, T_l, T_w, H_l) is fitted, per
   operating phase, by a piecewise-linear curve with knots every ``knot_s`` seconds (weighted
   least squares with the run's ``noise_std``; a weak curvature penalty, in units of the
   channel's noise, keeps knots without samples defined). The fit's covariance carries the
   sensor noise. A phase is a span of constant metered inputs; phases shorter than
   ``min_phase_s`` join the next one (their metered flows are still integrated exactly).
2. **Reconstruct the inventory** at the knots with the reference equation of state (CoolProp
   HEOS, not the model's surrogate): ``M = m_v + m_l`` and ``E = m_v u_v + m_l u_l + C_w T_w``,
   the liquid volume from the level (``V_l(H_l)``), the ullage volume the rest of the tank.
   The liquid is evaluated on its own branch at ``(p, T_l)`` (metastable when superheated);
   the ullage's hydrogen at ``(p, T_v)``, or, where the ullage reads colder than saturation,
   as saturated vapour at ``T_v`` (hydrogen cannot exceed its saturation pressure; the rest
   of the reading is reported, step 5). The covariance of (M, E) follows by linearisation.
3. **Subtract the metered inventory**: the integrals of the inflows and outflows (vents at the
   ullage's enthalpy, drains at the liquid's, inflows at their metered states) and of ``Q_aw``.
   What remains, ``r(t)``, is what the meters did not see.
4. **Estimate the unmetered rates.** Per phase, a straight line through ``r(t)`` by generalised
   least squares gives the phase's unmetered mass (kg/s) and heat (W). Over the run, one joint
   GLS of the mass and energy residuals of every phase (their cross-covariance included, an
   intercept per phase) estimates a constant unmetered mass rate and heat together with two
   nuisances: a correction of the wall heat capacity (a stated ``C_w`` that is wrong shows as
   heat proportional to ``dT_w/dt``; prior ``wall_capacity_prior`` relative where the run states
   ``C_w``; free where it does not, the balances then estimate it) and an offset of the liquid temperature sensor
   (it shows wherever the liquid mass changes, and in the enthalpy drains are metered at, which
   is taken at the measured ``T_l``; prior ``liquid_bias_prior_K``), and the property model's
   uncertainty: data written with another model of the fluid than the reference (an engineering
   one: an Antoine saturation curve, a liquid density linear in temperature alone, constant
   heat capacities, a virial vapour, Watson's latent heat) differ from it by a few per cent in
   each property, which the inventory reads as unmetered mass and heat (a compressibility left
   out reads as a leak under a pressurisation, a constant heat capacity as heat wherever the
   liquid warms). Each such difference is a perturbation of the reference equation of state
   (``_PerturbedThermo``: the liquid's expansion and compressibility, its heat capacity, its
   energy's pressure dependence (an energy of temperature alone reads as heat leaving under a
   pressurisation and entering under a vent), the vapour's heat capacity, the vapour's energy
   against the liquid's) applied to the inventory
   and to every metered flow alike, with a prior in ``AuditConfig``. Where a straight
   line does not fit a phase within the noise (a fast transient, a state the sensors resolve
   badly), that phase's covariance is scaled by its Birge ratio ``sqrt(chi2/dof)``, and the
   joint fit's standard errors by the joint fit's own: model error widens the interval
   instead of naming a leak.
5. **Test the sensors' thermodynamic consistency**: a pure ullage cannot stay colder than
   saturation at its pressure, nor a liquid warmer. A violation beyond the noise at
   ``consistency_share`` or more of the audit times is evidence of an inert gas (its partial
   pressure at least ``p - p_sat(T_v)``) or of a biased pressure or temperature sensor, where the
   ullage reads ``saturation_margin_K`` or more below saturation (another model of the fluid
   places saturation up to about 1 K from the reference's); it is
   reported, never a reason to stop. Shorter violations (a sloshing transient) are listed. The
   other way round, a liquid whose median reading over the run lies ``consistency_margin_K``
   above saturation at the measured pressure rules an inert gas out (it would lower the
   hydrogen's partial pressure and hold the liquid below ``T_sat(p)``): the dynamic search may
   then not name one (``RunAudit.inert_gas_excluded``). Where neither holds and no gas is vented
   (or no level sensor reads what the vents carry), the balances cannot measure an inert gas
   either (step 6), and the audit says so (``RunAudit.inert_gas_unmeasured``), as does a verdict
   of no cause: such a tank may hold helium at any share of its pressure these sensors do not
   show.
6. **Name what the balances show** (``InventoryFinding``) by gross-error detection: each
   single cause is a hypothesis with its own signature in the two balances: unmetered heat
   ``(0, Q t)``; a vapour leak ``-(L t, L integral h_v dt)``; a liquid leak ``-(L t, L integral
   h_l dt)``; an inflow meter bias ``beta x`` (metered inflow mass, its enthalpy); ``n`` mol of
   inert gas (helium) in a vented ullage ``n (M_He - M_f) (integral f dt, integral f h_v dt)``
   with ``f = mdot_v_out / m_v`` the ullage's vented share per second, decayed by
   ``exp(-integral f dt)`` as the gas leaves: the sensors count each mole of helium as a mole
   of the fluid (same p, T), a vent meters it at its own molar mass, so each mole vented
   leaves ``M_He - M_f`` (2 g for hydrogen) more metered mass than inventory, at the ullage's
   enthalpy (for ideal gases the energy follows exactly). It is fitted only where gas is
   vented, with a level sensor, and where the saturation test does not rule a gas out, and is
   admissible only positive and with a partial pressure at the start, ``n R T_v / V_v``, within
   three standard errors of ``p - p_sat(T_l)``. The vented share is taken on the inventory's
   mass, which counts the helium at the fluid's molar mass: the fitted amount is low by about
   ``1 / (1 + x (M_He / M_f - 1))`` at helium mole fraction ``x``, which the estimate corrects
   at the start's ullage (``_inert_amount``). The standard errors and chi2 of every fit are
   scaled by the free fit's Birge ratio, or by the best single cause's where the free fit's is
   ``birge_gap`` times larger: the free fit's constant rates cannot follow a cause proportional
   to a metered flow, so its misfit then measures the cause, not the noise. A cause whose mass
   the meters would carry must be borne out by the mass balance alone
   (``Hypothesis.mass_disagrees``): a leak's or a meter bias's mass-only fit within three
   combined standard errors of the joint one, a meter bias's two standard errors from zero on
   its side (energy alone mimics it where a wall no sensor reads stores heat). The best
   hypothesis is named when its rate is ``z_name`` standard errors from zero (``z_name_properties``
   where the property model's uncertainty is allowed for, step 4, and then only if the fit with
   the reference's properties alone also puts it ``z_name`` out), it explains both
   balances (its chi2 within ``chi2_separation`` of the free mass-and-heat fit) and every other
   hypothesis is worse by ``chi2_separation`` or more. Unmetered heat is named with the three
   places it may enter (the whole-tank balance cannot locate it); hypotheses that cannot be
   told apart are listed together. A wrong wall heat capacity competes as one more hypothesis
   (its correction freed from the prior); where the wall warms or cools at a steady rate, a
   constant unmetered heat with the stated capacity held explains the balances as well (the
   heat's own fit spends the wall's prior on it and reads ~0), and the two are listed together,
   the heat as measured at the stated capacity. Where a leak explains best but has rivals, or
   leaks are rivalled only by each other and by heat leaving the tank (the energy they carry
   resolved, a large tank's level too noisy for the mass), the finding is an unmetered mass loss
   at the best-fitting leak's rate, with every rival's reading; a liquid temperature offset
   ``z_name`` standard errors from zero under the chosen explanation is named as a biased liquid
   temperature sensor, unless the liquid it implies would sit ``saturation_margin_K`` or more
   above saturation (median).

Without a level sensor the mass balance is not observable: the liquid volume is then taken from
the metered mass (no leak assumed) and only the energy balance is audited. Without a wall
temperature the wall's energy is taken to follow the liquid's temperature, with an uncertainty
of half the ullage-liquid temperature change times the heat capacity at each knot, and a steady
storage over each phase as a nuisance (prior: the heat capacity times half the widest
ullage-liquid gap, over the phase's length), which a heavy wall's unseen warming needs.

Limits: each phase is treated as well mixed at its measured temperature (a stratified phase read
by one sensor is a bias the audit sees only as the liquid offset above); rates are constant over
the run (``chi2_between_phases`` tests the heat's constancy across phases); the hydrogen is
pure (an inert gas is seen through the saturation test, step 5, and the mass its vents meter,
step 6: about 2 g per mole of helium vented, so only a tank that vents much of its helium shows
it beyond the level's noise); a vent meter that reads high has the inert gas's signature. The
audit cannot tell
where unmetered heat enters: wall, liquid or ullage.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from ..mechanisms.noncondensable import R_J_PER_MOLK
from ..run import NOISE_KEYS, OBS_CHANNELS, Run
from ..schedule import INPUT_NAMES

_CH = {c: i for i, c in enumerate(OBS_CHANNELS)}
_IN = {n: i for i, n in enumerate(INPUT_NAMES)}
# J/kg: energy residuals are divided by this in the joint fit, so that kg and J/H_REF rows are of
# similar size (the fit itself does not depend on it).
_H_REF = 1.0e5
# Central-difference steps of the inventory's Jacobian in each channel (well below the noise,
# well above CoolProp's round-off).
_STEP = {"p_v_Pa": 50.0, "T_v_K": 0.01, "T_l_K": 0.005, "T_w_K": 0.01, "H_l_m": 1e-4}
HYPOTHESES = ("heat", "vapor_leak", "liquid_leak", "inflow_meter_bias", "wall_heat_capacity_error", "noncondensable_gas")
# kg/mol; the inert gas the audit tests for (helium, the pressurant of cryogenic tanks).
M_INERT_KG_PER_MOL = 4.002602e-3
HEAT_CANDIDATES = ("heat_leak_wall", "heat_leak_liquid", "heat_leak_vapor")
# The unmetered heat with the wall's heat capacity held at the stated one (no wall correction): the
# rival of a wrong wall heat capacity where the wall warms or cools at a steady rate (step 6).
HEAT_AT_STATED_WALL = "heat_at_stated_wall"


# The equation of state's perturbations the audit carries as nuisances, and their priors' fields.
PROPERTY_PRIORS = {"rho_l": "liquid_density_prior", "rho_l_T": "liquid_expansion_prior",
                    "rho_l_p": "liquid_compressibility_prior", "u_l_p": "liquid_energy_pressure_prior",
                    "c_l": "liquid_heat_capacity_prior", "rho_v": "vapor_density_prior",
                    "c_v": "vapor_heat_capacity_prior", "latent": "latent_heat_prior"}


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
    # Where the property model's uncertainty is allowed for (the property priors below), the
    # audit names at this many standard errors, and only what also stands z_name out with the
    # reference's properties: a rate another model of the fluid explains is not named, while
    # data written with the reference's properties keep most of what z_name alone names (the
    # nuisances widen every interval; experiments/README.md, section 6).
    z_name_properties: float = 4.0
    # Hypotheses are told apart when the others' chi2 is this much larger (3 sigma for one parameter).
    chi2_separation: float = 9.0
    # The fits are scaled by the best single cause's Birge ratio instead of the free fit's where
    # the free fit's is this many times larger (an inflow meter's bias on a fast fill: 17 against
    # 1.0). Model error alone (another model of the fluid, a transient) leaves the free fit and
    # every cause within a factor of about two of each other (2.2 against 1.1 on an engineering
    # simulator's small warm fill with nothing hidden).
    birge_gap: float = 3.0
    # Relative prior standard deviation of the wall heat capacity the run states (a stated value
    # is a drawing's mass times a handbook c_p: a quarter covers the alloy's c_p at cryogenic
    # temperatures and the fittings). A capacity the run does not state has no prior: tankode's
    # aluminium-shell guess (``tankode.wall``) can be off by a factor of 50 on another
    # simulator's tank, so the balances estimate it and no "wrong capacity" is competed.
    wall_capacity_prior: float = 0.25
    # K; prior standard deviation of the liquid temperature sensor's offset (a weak prior: it
    # only keeps the offset defined where the liquid mass never changes).
    liquid_bias_prior_K: float = 2.0
    # Property-model uncertainty (step 4): prior standard deviations of perturbations of the
    # reference equation of state, for data written with another model of the fluid (an
    # engineering one: saturation within about 1 K, liquid density within about 1 %, a constant
    # liquid heat capacity, a virial vapour, Watson's latent heat); 0 trusts that property.
    # Relative liquid density. A scale error changes the inventory with the liquid's mass, like a
    # meter bias on every fill and a leak in every boil-off, and through a drain like a liquid
    # thermometer's offset (the density's slope with temperature): an engineering model's
    # normal hydrogen drained 190 kg read as a -0.35 K thermometer bias with this prior at 0. Half
    # a per cent stops that and keeps meter biases of 12-18 % named (experiments/README.md,
    # section 6).
    liquid_density_prior: float = 0.005
    # The liquid's thermal expansion about the initial T_l, relative to the reference's (a linear
    # fit to a curved rho_l(T)).
    liquid_expansion_prior: float = 0.3
    # The liquid's compressibility about the initial pressure, relative to the reference's (a
    # density of temperature alone neglects it: 0.2 % per bar for hydrogen at 21 K).
    liquid_compressibility_prior: float = 1.0
    # The liquid's energy's pressure dependence at constant temperature, (du/dp)_T = -v (T beta -
    # p kappa), relative to the reference's (an energy of temperature alone, c_l (T - T_0),
    # neglects it: -150 J/kg per bar for methane at 134 K, -520 J/kg per bar for para-hydrogen
    # at 21 K).
    liquid_energy_pressure_prior: float = 1.0
    # Relative liquid heat capacity about the initial T_l (a constant c_l fitted over a run's
    # range: 5-10 % off; hydrogen's varies by a fifth between 20 and 23 K).
    liquid_heat_capacity_prior: float = 0.10
    # Relative vapour density (ideal or second-virial vapour near saturation: 3-7 % off). 0, as
    # the liquid density's scale, for the same reason.
    vapor_density_prior: float = 0.0
    # Relative vapour heat capacity about the initial T_v (a constant c_v: 10-15 % off).
    vapor_heat_capacity_prior: float = 0.10
    # The vapour's energy against the liquid's, in units of the latent heat at the initial
    # pressure (Watson's relation or a constant latent heat: a few % off).
    latent_heat_prior: float = 0.05
    # Relative weight of the curvature penalty (per knot, in units of the channel's noise).
    smoothing: float = 1e-3
    # Share of the audit times at which a saturation violation must hold to be evidence.
    consistency_share: float = 0.5
    # K; a liquid reading warmer than saturation must exceed this as well as three standard
    # errors (it only rules an inert gas out, step 5).
    consistency_margin_K: float = 0.05
    # K; how far from the reference's saturation data written with another model of the fluid may
    # place it (about 1 K for an engineering model): an ullage reading colder than saturation by
    # more (and by three standard errors) is evidence of an inert gas or a biased sensor, and a
    # liquid thermometer offset is not named where the liquid it implies would sit more than
    # this above saturation (no pure liquid stays there).
    saturation_margin_K: float = 1.0

    def __post_init__(self):
        for name in ("knot_s", "min_phase_s", "z_name", "z_name_properties", "chi2_separation", "birge_gap",
                     "wall_capacity_prior",
                     "liquid_bias_prior_K", "smoothing", "consistency_share", "consistency_margin_K", "saturation_margin_K"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"AuditConfig.{name} must be finite and > 0, got {v}")
        for name in PROPERTY_PRIORS.values():
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"AuditConfig.{name} must be finite and >= 0, got {v}")
        if self.consistency_share > 1:
            raise ValueError(f"AuditConfig.consistency_share must be in (0, 1], got {self.consistency_share}")

    def trusting_properties(self) -> "AuditConfig":
        """This configuration with every property prior 0: for data written with the reference's
        properties (tankode's own runs; its surrogate is fitted to CoolProp)."""
        return dataclasses.replace(self, **{attr: 0.0 for attr in PROPERTY_PRIORS.values()})


@dataclass(frozen=True)
class Estimate:
    """A value with its standard error (SI units of what it estimates)."""

    value: float
    std: float

    @property
    def z(self) -> float:
        """value / std (0 where the std is not finite or 0)."""
        return self.value / self.std if self.std > 0 and math.isfinite(self.std) else 0.0

    def __str__(self) -> str:
        return f"{self.value:.3g} +- {self.std:.2g}"

    def to_json(self) -> dict:
        return {"value": self.value, "std": self.std}


@dataclass(frozen=True)
class PhaseAudit:
    """Unmetered rates over one operating phase ``[t0_s, t1_s]`` (a straight line each)."""

    t0_s: float
    t1_s: float
    kind: str  # the operations of the phase, e.g. "vent", "hold", "vapour inflow, sloshing"
    mass_kg_s: Estimate | None  # None: no level sensor
    heat_W: Estimate
    inflow_kg_s: float  # mean metered inflow (vapour + liquid) during the phase
    h_v_J_per_kg: float  # mean enthalpy of the ullage and of the liquid over the phase: what a leak carries
    h_l_J_per_kg: float
    birge_mass: float  # sqrt(chi2 / dof) of the straight line (1 = fits within the noise)
    birge_heat: float

    def to_json(self) -> dict:
        return {"t0_s": self.t0_s, "t1_s": self.t1_s, "kind": self.kind,
                "mass_kg_s": self.mass_kg_s.to_json() if self.mass_kg_s else None, "heat_W": self.heat_W.to_json(),
                "inflow_kg_s": self.inflow_kg_s, "h_v_J_per_kg": self.h_v_J_per_kg, "h_l_J_per_kg": self.h_l_J_per_kg,
                "birge_mass": self.birge_mass, "birge_heat": self.birge_heat}


@dataclass(frozen=True)
class Hypothesis:
    """One single-cause explanation of both balances, fitted over the run.

    ``chi2`` is in units of the joint fit's Birge-scaled covariance (comparable across
    hypotheses); ``estimate`` is its rate (W, kg/s lost, or the relative inflow bias).
    """

    name: str
    chi2: float
    estimate: Estimate
    z: float  # the rate's distance from "absent" in standard errors (for the wall: (factor - 1) / std)
    # Why the mass balance alone contradicts this mass-carrying cause ("" where it does not, or it
    # carries no mass): such a cause is not named (``_mass_disagrees``).
    mass_disagrees: str = ""

    def to_json(self) -> dict:
        return {"name": self.name, "chi2": self.chi2, "estimate": self.estimate.to_json(), "z": self.z,
                "mass_disagrees": self.mass_disagrees}


@dataclass(frozen=True)
class InventoryFinding:
    """What the balances show: a name (a mechanism id or a group), the estimate, and what it may be.

    ``name``: ``unmetered_heat`` (candidates: the three heat leaks where it enters, none where
    it leaves; or the hypotheses not told apart), ``vapor_leak``, ``liquid_leak``,
    ``inflow_meter_bias``, ``unmetered_mass`` (candidates: the hypotheses not told apart),
    ``wall_heat_capacity_error``, ``temperature_sensor_bias`` (the liquid temperature reading's
    offset: a biased sensor, or one sitting in a layer unlike the bulk),
    ``inert_gas_or_sensor_bias`` (a persistently cold ullage reading). ``fit``: the fit its
    estimate comes from (a hypothesis of ``RunAudit.hypotheses``, ``"mass"`` for the free fit's
    mass rate; ``""`` where the balances do not rate it), which the strict check reads too.
    """

    name: str
    estimate: Estimate | None
    unit: str
    candidates: tuple[str, ...]  # mechanism ids the finding is consistent with
    sentence: str
    fit: str = ""

    def to_json(self) -> dict:
        return {"name": self.name, "estimate": self.estimate.to_json() if self.estimate else None, "unit": self.unit,
                "candidates": list(self.candidates), "sentence": self.sentence}


@dataclass(frozen=True)
class RunAudit:
    """The audit of one run (module docstring).

    Attributes:
        run: the run's name.
        phases: per-phase straight-line estimates.
        mass_kg_s, heat_W: run-wide unmetered mass rate (kg/s, + = gained) and heat (W, + =
            entering) from the joint fit with both free; mass is None without a level sensor.
        wall_capacity_factor: true C_w / stated (or assumed) C_w, as ``liquid_offset_K``; None
            where T_w is not measured or never changes.
        wall_heat_capacity_J_per_K: the stated (or assumed) C_w the factor multiplies (J/K).
        wall_capacity_stated: False where the run does not state C_w: the factor is then the
            balances' estimate of an unknown, not a finding.
        liquid_offset_K: the liquid temperature reading's offset from what the balances need
            (estimated with the hypothesis the findings rest on, or with both rates free).
        hypotheses: the single-cause fits of step 6, by name.
        birge: the Birge ratio the joint fits are scaled by (the free fit's, or the best single
            cause's where the free fit's is ``birge_gap`` times larger; step 6).
        chi2_between_phases: of the phases' heat estimates against their weighted mean.
        consistency: sentences of step 5; ``inert_partial_pressure_Pa`` its lower bound where
            the ullage reads persistently colder than saturation (None otherwise).
        liquid_superheat_K: the median over the audit times of ``T_l - T_sat(p)`` (K): above
            ``consistency_margin_K`` the liquid reads warmer than saturation at the measured
            pressure on most of the run, which an inert gas contradicts (it lowers the
            hydrogen's partial pressure and with it the liquid surface's temperature).
        inert_gas_excluded: why the readings rule an inert gas out ("" where they do not).
        inert_gas_unmeasured: why the readings neither show nor rule out an inert gas, where the
            balances cannot measure one (no gas vented, or no level sensor) and the saturation
            test neither sees nor excludes one ("" otherwise). The liquid's subcooling is no
            measure of it: a pressurised liquid sits well below saturation with no gas at all,
            and a liquid under helium can sit above saturation at the fluid's partial pressure
            (its surface cooled by evaporation).
        findings: what is named (step 6).
        withheld: sentences of what step 6 does not name because only one of its two explanations
            (with the reference's properties, and with another model of the fluid allowed for)
            would.
        series: ``t_s`` and the measured and metered mass (kg) and energy (J) with the measured
            ones' standard errors, for the figure.
    """

    run: str
    phases: tuple[PhaseAudit, ...]
    mass_kg_s: Estimate | None
    heat_W: Estimate
    wall_capacity_factor: Estimate | None
    liquid_offset_K: Estimate
    hypotheses: dict
    birge: float
    chi2_between_phases: float
    consistency: tuple[str, ...]
    inert_partial_pressure_Pa: float | None
    liquid_superheat_K: float
    inert_gas_excluded: str
    findings: tuple[InventoryFinding, ...]
    withheld: tuple[str, ...]
    series: dict = field(repr=False)
    wall_heat_capacity_J_per_K: float | None = None
    wall_capacity_stated: bool = True
    inert_gas_unmeasured: str = ""

    @property
    def wall_heat_capacity(self) -> Estimate | None:
        """The wall heat capacity the balances read (J/K), or None where they do not read it."""
        if self.wall_capacity_factor is None or self.wall_heat_capacity_J_per_K is None:
            return None
        c = self.wall_heat_capacity_J_per_K
        return Estimate(self.wall_capacity_factor.value * c, self.wall_capacity_factor.std * c)

    def wall_capacity_sentence(self) -> str:
        """The balances' reading of the wall heat capacity in words; "" where they do not read it.

        A stated capacity is read as a factor on it. An unstated one is given in J/K where the
        reading is positive and within ``WALL_READING_REL_STD``; otherwise the sentence says the
        balances do not read it (a heat capacity is positive: a reading at or below zero, or this
        loose, carries no value to report).
        """
        if self.wall_capacity_factor is None:
            return ""
        f = self.wall_capacity_factor
        if self.wall_capacity_stated:
            return f"wall heat capacity {f.value:.3g} +- {f.std:.2g} x stated"
        c = self.wall_heat_capacity
        if wall_reading(self) is None:
            return (f"wall heat capacity not stated by the run and not read by the balances ({c.value:.3g} +- "
                    f"{c.std:.2g} J/K is no positive reading within {WALL_READING_REL_STD:.0%})")
        return f"wall heat capacity (not stated by the run) {c.value:.3g} +- {c.std:.2g} J/K"

    def finding(self, name: str) -> InventoryFinding | None:
        """The finding called ``name``, or None."""
        return next((f for f in self.findings if f.name == name), None)

    def summary(self) -> str:
        """One paragraph: the run-wide rates and what is named."""
        mass = f"unmetered mass {self.mass_kg_s} kg/s" if self.mass_kg_s else "no level sensor: mass not audited"
        named = "; ".join(f.sentence for f in self.findings) or "nothing unmetered beyond the noise"
        return f"{self.run}: {mass}, unmetered heat {self.heat_W} W. {named}"

    def to_json(self) -> dict:
        return {
            "run": self.run, "phases": [p.to_json() for p in self.phases],
            "mass_kg_s": self.mass_kg_s.to_json() if self.mass_kg_s else None, "heat_W": self.heat_W.to_json(),
            "wall_capacity_factor": self.wall_capacity_factor.to_json() if self.wall_capacity_factor else None,
            "wall_heat_capacity_J_per_K": self.wall_heat_capacity_J_per_K, "wall_capacity_stated": self.wall_capacity_stated,
            "liquid_offset_K": self.liquid_offset_K.to_json(),
            "hypotheses": {k: h.to_json() for k, h in self.hypotheses.items()}, "birge": self.birge,
            "chi2_between_phases": self.chi2_between_phases, "consistency": list(self.consistency),
            "inert_partial_pressure_Pa": self.inert_partial_pressure_Pa, "liquid_superheat_K": self.liquid_superheat_K,
            "inert_gas_excluded": self.inert_gas_excluded, "inert_gas_unmeasured": self.inert_gas_unmeasured,
            "findings": [f.to_json() for f in self.findings], "withheld": list(self.withheld),
        }


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
    """Values at the knots and their covariance, or None when the channel has under 3 samples.

    Weighted least squares on the hat basis; the penalty ``smoothing * sum (second difference /
    sigma)^2`` only defines knots that no sample constrains.
    """
    if len(t) < 3:
        return None
    B = _hat_basis(t, knots) / sigma
    n = len(knots)
    D = np.diff(np.eye(n), 2, axis=0) / sigma if n >= 3 else np.zeros((0, n))
    A = B.T @ B + smoothing * D.T @ D + 1e-12 * np.eye(n) / sigma**2
    cov = np.linalg.inv(A)
    return cov @ (B.T @ (y / sigma)), cov


def _knots(a: float, b: float, spacing: float) -> np.ndarray:
    n = max(2, int(round((b - a) / spacing)) + 1)
    return np.linspace(a, b, n)


# ----------------------------------------------------------------------------- thermodynamics
class _Thermo:
    """CoolProp HEOS states of each phase on its own branch (module docstring, step 2)."""

    def __init__(self, fluid: str):
        import CoolProp

        self._cp = CoolProp
        self.name = fluid
        self._sat = CoolProp.AbstractState("HEOS", fluid)
        self._gas = CoolProp.AbstractState("HEOS", fluid)
        self._gas.specify_phase(CoolProp.iphase_gas)
        self._liq = CoolProp.AbstractState("HEOS", fluid)
        self._liq.specify_phase(CoolProp.iphase_liquid)
        self.molar_mass_kg_per_mol = self._sat.molar_mass()

    def T_sat(self, p: float) -> float:
        self._sat.update(self._cp.PQ_INPUTS, p, 0.0)
        return self._sat.T()

    def p_sat(self, T: float) -> float:
        self._sat.update(self._cp.QT_INPUTS, 0.0, T)
        return self._sat.p()

    def vapor(self, p: float, T: float) -> tuple[float, float, float]:
        """(rho, u, h) of the ullage's hydrogen: at (p, T), or saturated vapour at T below saturation."""
        if T <= self.T_sat(p):
            self._sat.update(self._cp.QT_INPUTS, 1.0, T)
            s = self._sat
        else:
            self._gas.update(self._cp.PT_INPUTS, p, T)
            s = self._gas
        return s.rhomass(), s.umass(), s.hmass()

    def liquid(self, p: float, T: float) -> tuple[float, float, float]:
        """(rho, u, h) of the liquid at (p, T) on the liquid branch; saturated liquid at p where that fails."""
        try:
            self._liq.update(self._cp.PT_INPUTS, p, T)
            s = self._liq
        except ValueError:
            self._sat.update(self._cp.PQ_INPUTS, p, 0.0)
            s = self._sat
        return s.rhomass(), s.umass(), s.hmass()

    def vapor_enthalpy(self, p: float, T: float) -> float:
        """h of injected vapour at its metered state (on the vapour branch)."""
        return self.vapor(p, T)[2]

    def liquid_enthalpy(self, p: float, T: float) -> float:
        return self.liquid(p, T)[2]


class _PerturbedThermo:
    """The reference states with one property perturbed by ``step`` (a ``PROPERTY_PRIORS`` key).

    ``rho_l``: rho_l (1 + step); ``rho_l_T``: rho_l (1 - step beta0 (T - T_l0)); ``rho_l_p``:
    rho_l (1 + step kappa0 (p - p0)); ``c_l``: u_l + step c_l0 (T - T_l0); ``u_l_p``: u_l + step
    dudp0 (p - p0); ``rho_v``: rho_v (1 +
    step); ``c_v``: u_v + step c_v0 (T - T_v0); ``latent``: u_v + step L0 (``_PropertyRef``).
    Enthalpies follow as ``u + p / rho``, so the inventory and every metered flow see the same
    equation of state.
    """

    def __init__(self, base: _Thermo, name: str, step: float, ref: "_PropertyRef"):
        self.base, self.name, self.step, self.ref = base, name, step, ref
        self.molar_mass_kg_per_mol = base.molar_mass_kg_per_mol

    def vapor(self, p: float, T: float) -> tuple[float, float, float]:
        rho, u, _ = self.base.vapor(p, T)
        if self.name == "rho_v":
            rho *= 1 + self.step
        elif self.name == "c_v":
            u += self.step * self.ref.c_v0 * (T - self.ref.T_v0)
        elif self.name == "latent":
            u += self.step * self.ref.L0
        return rho, u, u + p / rho

    def liquid(self, p: float, T: float) -> tuple[float, float, float]:
        rho, u, _ = self.base.liquid(p, T)
        if self.name == "rho_l":
            rho *= 1 + self.step
        elif self.name == "rho_l_T":
            rho *= 1 - self.step * self.ref.beta0 * (T - self.ref.T_l0)
        elif self.name == "rho_l_p":
            rho *= 1 + self.step * self.ref.kappa0 * (p - self.ref.p0)
        elif self.name == "c_l":
            u += self.step * self.ref.c_l0 * (T - self.ref.T_l0)
        elif self.name == "u_l_p":
            u += self.step * self.ref.dudp0 * (p - self.ref.p0)
        return rho, u, u + p / rho

    def vapor_enthalpy(self, p: float, T: float) -> float:
        return self.vapor(p, T)[2]

    def liquid_enthalpy(self, p: float, T: float) -> float:
        return self.liquid(p, T)[2]


class _PropertyRef(NamedTuple):
    """Where the property perturbations are anchored: the run's initial state."""

    p0: float  # Pa
    T_l0: float  # K
    T_v0: float  # K
    beta0: float  # 1/K, the liquid's -(1/rho) drho/dT there
    kappa0: float  # 1/Pa, the liquid's (1/rho) drho/dp there
    c_l0: float  # J/(kg K), du_l/dT there
    dudp0: float  # J/(kg Pa), the liquid's (du/dp)_T there
    c_v0: float  # J/(kg K), du_v/dT there
    L0: float  # J/kg, h_v,sat - h_l,sat at the initial pressure

    @classmethod
    def at(cls, thermo: _Thermo, p: float, T_l: float, T_v: float) -> "_PropertyRef":
        dT, dp = 0.01, 100.0
        (rl, ul, _), (rl_T, ul_T, _) = thermo.liquid(p, T_l - dT), thermo.liquid(p, T_l + dT)
        rho, beta = 0.5 * (rl + rl_T), -(rl_T - rl) / (rl + rl_T) / dT
        (rp, up, _), (rm, um, _) = thermo.liquid(p + dp, T_l), thermo.liquid(p - dp, T_l)
        kappa = (rp - rm) / (2 * dp * rho)
        c_v = (thermo.vapor(p, T_v + dT)[1] - thermo.vapor(p, T_v - dT)[1]) / (2 * dT)
        T_sat = thermo.T_sat(p)
        L0 = thermo.vapor(p, T_sat + 1e-3)[2] - thermo.liquid(p, T_sat - 1e-3)[2]
        return cls(p, T_l, T_v, beta, kappa, (ul_T - ul) / (2 * dT), (up - um) / (2 * dp), c_v, L0)


def _inventory(thermo: _Thermo, V_tank: float, x: np.ndarray, V_l: float, C_w: float, wall_T: float):
    """(M, E, h_v, h_l, m_v) at channel values ``x`` (p, T_v, T_l, T_w, H_l) with liquid volume ``V_l``."""
    p, T_v, T_l = x[0], x[1], x[2]
    rv, uv, hv = thermo.vapor(p, T_v)
    rl, ul, hl = thermo.liquid(p, T_l)
    m_v, m_l = rv * (V_tank - V_l), rl * V_l
    return m_v + m_l, m_v * uv + m_l * ul + C_w * wall_T, hv, hl, m_v


def _liquid_volume_for_mass(thermo: _Thermo, V_tank: float, x: np.ndarray, M: float) -> float:
    rv = thermo.vapor(x[0], x[1])[0]
    rl = thermo.liquid(x[0], x[2])[0]
    return float(np.clip((M - rv * V_tank) / (rl - rv), 0.0, V_tank))


def _gls(X: np.ndarray, r: np.ndarray, C: np.ndarray):
    """Generalised least squares: coefficients, their covariance, chi2 and dof."""
    n, k = X.shape
    C = C + np.eye(n) * 1e-10 * max(float(np.trace(C)) / n, 1e-300)
    L = np.linalg.cholesky(C)
    Xw = np.linalg.solve(L, X)
    rw = np.linalg.solve(L, r)
    # From the whitened design's SVD, not the pseudo-inverse of its normal matrix: squaring the
    # condition number there (a kilowatt prior beside gram-per-second rates reaches 1e15) cut
    # the weakest direction and reported its variance as nil.
    U, sv, Vt = np.linalg.svd(Xw, full_matrices=False)
    keep = sv > sv[0] * max(n, k) * np.finfo(float).eps
    inv = np.where(keep, 1.0 / np.where(keep, sv, 1.0), 0.0)
    coef = Vt.T @ (inv * (U.T @ rw))
    cov = (Vt.T * inv**2) @ Vt
    res = rw - Xw @ coef
    return coef, cov, float(res @ res), max(n - k, 1)


def _birge(chi2: float, dof: int) -> float:
    return max(1.0, math.sqrt(chi2 / dof))


def _kind(sched, a: float, b: float) -> str:
    """The operations of the phase ``[a, b]`` (s), every one that runs in it: a short hold merged
    into the drain after it (``_phases``) is a drain."""
    us = [sched.at(t) for t in (a, *sched.breakpoints(a, b))]
    parts = [name for name, key in (("vapour inflow", "mdot_v_in_kg_s"), ("vent", "mdot_v_out_kg_s"),
                                    ("liquid inflow", "mdot_l_in_kg_s"), ("drain", "mdot_l_out_kg_s"),
                                    ("sloshing", "slosh_amplitude_m")) if any(u[_IN[key]] > 0 for u in us)]
    return ", ".join(parts) or "hold"


# ----------------------------------------------------------------------------- one phase
@dataclass
class _PhaseData:
    """Everything the run-wide fit needs from one phase (knot times relative to the phase start)."""

    tt: np.ndarray
    rM: np.ndarray | None  # None: no level sensor
    rE: np.ndarray
    C: np.ndarray  # covariance of [M; E / H_REF] (or of E / H_REF alone), Birge-scaled
    J_Tl: np.ndarray  # d[M; E / H_REF] / dT_l at the knots (a liquid sensor offset's signature)
    wall: np.ndarray  # -C_w T_w / H_REF at the knots (a wall capacity correction's signature), 0 without T_w
    cols: dict  # hypothesis signatures [M; E / H_REF] at the knots
    props: dict  # property perturbations' signatures [M; E / H_REF] at the knots, per unit perturbation
    drift_W: float = 0.0  # without T_w: prior std (W) of the wall's unseen storage, steady over the phase


def _metered(thermo: _Thermo, sched, knots: np.ndarray, p_k: np.ndarray, hv_k: np.ndarray, hl_k: np.ndarray,
             mv_k: np.ndarray | None = None, vented: float = 0.0):
    """Cumulative metered mass and energy at the knots, and the hypotheses' cumulative signatures.

    The schedule's pieces inside each knot interval are integrated exactly; the ullage's and the
    liquid's enthalpies (vent, drain, leaks), its mass ``mv_k`` (the vented share) and the
    pressure (liquid fill) are interpolated linearly between the knots (trapezoid on each piece).
    ``vent_M`` and ``vent_E`` integrate the vented share of the ullage per second, ``mdot_v_out /
    m_v``, and its enthalpy flow, each decayed by ``exp(-vented share so far)``: the inert gas's
    signature per mole (module docstring); ``vented`` is the share vented before ``knots[0]``.
    """
    n = len(knots)
    out = {k: np.zeros(n) for k in ("M", "E", "in_M", "in_E", "Hv", "Hl", "inflow_time", "vent_M", "vent_E")}
    for k in range(n - 1):
        acc = dict.fromkeys(out, 0.0)
        for s0, s1, u in sched.segments(knots[k], knots[k + 1]):
            dt = s1 - s0
            w0, w1 = ((s0 - knots[k]) / (knots[k + 1] - knots[k]), (s1 - knots[k]) / (knots[k + 1] - knots[k]))
            hv = 0.5 * ((1 - w0) * hv_k[k] + w0 * hv_k[k + 1] + (1 - w1) * hv_k[k] + w1 * hv_k[k + 1])
            hl = 0.5 * ((1 - w0) * hl_k[k] + w0 * hl_k[k + 1] + (1 - w1) * hl_k[k] + w1 * hl_k[k + 1])
            wm = 0.5 * (w0 + w1)
            p_mid = (1 - wm) * p_k[k] + wm * p_k[k + 1]
            m_vin, m_vout = u[_IN["mdot_v_in_kg_s"]], u[_IN["mdot_v_out_kg_s"]]
            m_lin, m_lout = u[_IN["mdot_l_in_kg_s"]], u[_IN["mdot_l_out_kg_s"]]
            h_vin = thermo.vapor_enthalpy(u[_IN["p_v_in_Pa"]], u[_IN["T_v_in_K"]]) if m_vin > 0 else 0.0
            h_lin = thermo.liquid_enthalpy(p_mid, u[_IN["T_l_in_K"]]) if m_lin > 0 else 0.0
            acc["M"] += (m_vin + m_lin - m_vout - m_lout) * dt
            acc["E"] += (m_vin * h_vin + m_lin * h_lin - m_vout * hv - m_lout * hl + u[_IN["Q_aw_W"]]) * dt
            acc["in_M"] += (m_vin + m_lin) * dt
            acc["in_E"] += (m_vin * h_vin + m_lin * h_lin) * dt
            acc["inflow_time"] += dt if m_vin + m_lin > 0 else 0.0
            acc["Hv"] += hv * dt
            acc["Hl"] += hl * dt
            if m_vout > 0 and mv_k is not None:
                share = m_vout * dt / ((1 - wm) * mv_k[k] + wm * mv_k[k + 1])
                left = math.exp(-vented) * (1.0 - math.exp(-share)) / share  # mean of the decay over the piece
                acc["vent_M"] += share * left
                acc["vent_E"] += share * left * hv
                vented += share
        for key in out:
            out[key][k + 1] = out[key][k] + acc[key]
    out["vented"] = vented
    return out


def _audit_phase(run: Run, a: float, b: float, thermo: _Thermo, geometry, V_tank: float, C_w: float,
                 has_level: bool, has_wall: bool, M_start: float | None, vented: float, config: AuditConfig,
                 perturbed: tuple = ()):
    """One phase: (PhaseAudit, _PhaseData, figure rows, consistency rows, the last knot's M, the
    share of the ullage vented by its end), or None; ``vented``: that share at its start;
    ``perturbed``: ``_PerturbedThermo`` states whose residuals give the property nuisances."""
    obs = run.observations
    spacing = config.knot_s
    for c in ("p_v_Pa", "T_v_K", "T_l_K") + (("H_l_m",) if has_level else ()) + (("T_w_K",) if has_wall else ()):
        tc, _ = obs.channel(c)
        tc = tc[(tc >= a) & (tc <= b)]
        if len(tc) >= 2:  # knots no closer than three samples of the sparsest channel the audit needs
            spacing = max(spacing, 3 * float(np.median(np.diff(tc))))
    knots = _knots(a, b, spacing)
    fits = {}
    for c in OBS_CHANNELS:
        tc, yc = obs.channel(c)
        sel = (tc >= a) & (tc <= b)
        fits[c] = _smooth(tc[sel], yc[sel], run.noise_std[NOISE_KEYS[_CH[c]]], knots, config.smoothing) \
            if c in obs.measured_channels else None
    if any(fits[c] is None for c in ("p_v_Pa", "T_v_K", "T_l_K")):
        return None  # too few samples in this phase to audit it
    level_ok = has_level and fits["H_l_m"] is not None
    wall_ok = has_wall and fits["T_w_K"] is not None
    n = len(knots)
    vals = np.zeros((n, 5))
    covs = [np.zeros((n, n)) for _ in range(5)]
    for c, j in _CH.items():
        if fits[c] is not None:
            vals[:, j], covs[j] = fits[c]

    import torch

    def volumes(H: np.ndarray) -> np.ndarray:
        return geometry.volume_at_level(torch.as_tensor(H, dtype=torch.float64)).numpy().astype(float)

    # Metered mass at the knots, for the liquid volume without a level sensor (no leak assumed).
    sched = run.inputs
    metered_M = np.concatenate([[0.0], np.cumsum([sum((s[2][_IN["mdot_v_in_kg_s"]] + s[2][_IN["mdot_l_in_kg_s"]]
                                                       - s[2][_IN["mdot_v_out_kg_s"]] - s[2][_IN["mdot_l_out_kg_s"]])
                                                      * (s[1] - s[0]) for s in sched.segments(k0, k1))
                                                  for k0, k1 in zip(knots[:-1], knots[1:])])])
    if not level_ok and M_start is None:
        x0 = vals[0]
        M_start = _inventory(thermo, V_tank, x0, run.initial.fill_ratio * V_tank, C_w, x0[3] if wall_ok else x0[2])[0]
    V_l = volumes(vals[:, 4]) if level_ok else np.array(
        [_liquid_volume_for_mass(thermo, V_tank, vals[k], M_start + metered_M[k]) for k in range(n)])
    Ms, Es, hvs, hls, dhl, mvs = np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n)
    Jm, Je = np.zeros((n, 5)), np.zeros((n, 5))
    for k in range(n):
        x = vals[k]
        Ms[k], Es[k], hvs[k], hls[k], mvs[k] = _inventory(thermo, V_tank, x, V_l[k], C_w, x[3] if wall_ok else x[2])
        for j, c in enumerate(OBS_CHANNELS):
            if fits[c] is None or (c == "H_l_m" and not level_ok) or (c == "T_w_K" and not wall_ok):
                continue
            step = _STEP[c]
            xp, xm = x.copy(), x.copy()
            xp[j] += step
            xm[j] -= step
            Vp, Vm = (volumes(np.array([xp[4], xm[4]])) if c == "H_l_m" else (V_l[k], V_l[k]))
            Mp, Ep, _, hlp, _ = _inventory(thermo, V_tank, xp, float(Vp), C_w, xp[3] if wall_ok else xp[2])
            Mm, Em, _, hlm, _ = _inventory(thermo, V_tank, xm, float(Vm), C_w, xm[3] if wall_ok else xm[2])
            Jm[k, j], Je[k, j] = (Mp - Mm) / (2 * step), (Ep - Em) / (2 * step)
            if c == "T_l_K":
                dhl[k] = (hlp - hlm) / (2 * step)
    met = _metered(thermo, sched, knots, vals[:, 0], hvs, hls, mvs, vented)
    # A liquid sensor offset also shifts the enthalpy the drains are metered at (they leave at the
    # measured T_l): its signature in the residual is the inventory's change less that of the
    # metered energy (linear in hl, so one unit offset of hl by dh_l/dT_l gives it exactly).
    J_Tl_E = Je[:, 2] - (_metered(thermo, sched, knots, vals[:, 0], hvs, hls + dhl)["E"] - met["E"])
    rM, rE = Ms - Ms[0] - met["M"], Es - Es[0] - met["E"]
    # The property nuisances: the same residual under each perturbed equation of state.
    props = {}
    for th in perturbed:
        inv = np.array([_inventory(th, V_tank, vals[k], V_l[k], C_w, vals[k, 3] if wall_ok else vals[k, 2])
                        for k in range(n)])
        met_p = _metered(th, sched, knots, vals[:, 0], inv[:, 2], inv[:, 3])
        props[th.name] = ((inv[:, 0] - inv[0, 0] - met_p["M"] - rM) / th.step,
                          (inv[:, 1] - inv[0, 1] - met_p["E"] - rE) / th.step / _H_REF)
    # Covariances of (M, E) from the channels' (independent) fit covariances.
    CM = sum(np.outer(Jm[:, j], Jm[:, j]) * covs[j] for j in range(5))
    CE = sum(np.outer(Je[:, j], Je[:, j]) * covs[j] for j in range(5))
    CME = sum(np.outer(Jm[:, j], Je[:, j]) * covs[j] for j in range(5))
    drift_W = 0.0
    if not wall_ok:
        # The wall's energy taken to follow the liquid, give or take half the change of the
        # ullage-liquid gap at each knot; and give or take a steady drift over the phase
        # (``_PhaseData.drift_W``): a wall that lags its fluids keeps lagging (a heavy wall warming
        # through a hold stores part of the metered heat load), which a per-knot spread averages
        # out of the rate. The drift's std is half the widest ullage-liquid gap over the phase's
        # length (the wall stays between its fluids within about that).
        gap = C_w * 0.5 * np.abs((vals[:, 1] - vals[0, 1]) - (vals[:, 2] - vals[0, 2]))
        CE = CE + np.diag(gap**2 + (1e-6 * C_w) ** 2)
        drift_W = C_w * 0.5 * float(np.max(np.abs(vals[:, 1] - vals[:, 2]))) / max(b - a, 1.0)
    tt = knots - a
    X = np.stack([np.ones(n), tt], axis=1)
    mass_est, birge_m = None, 1.0
    if level_ok:
        cm, vm, chi_m, dof_m = _gls(X, rM, CM)
        birge_m = _birge(chi_m, dof_m)
        mass_est = Estimate(float(cm[1]), float(math.sqrt(max(vm[1, 1], 0.0))) * birge_m)
    ce, ve, chi_e, dof_e = _gls(X, rE, CE)
    birge_e = _birge(chi_e, dof_e)
    heat_est = Estimate(float(ce[1]), math.hypot(float(math.sqrt(max(ve[1, 1], 0.0))) * birge_e, drift_W))
    inflow = met["in_M"][-1] / (b - a)
    phase = PhaseAudit(a, b, _kind(sched, a, b), mass_est, heat_est, float(inflow),
                       float(hvs.mean()), float(hls.mean()), birge_m, birge_e)
    # The joint (mass, energy / H_REF) block, each part scaled by its line's Birge ratio.
    E_scale = birge_e / _H_REF
    wall = -C_w * (vals[:, 3] if wall_ok else np.zeros(n)) / _H_REF
    zeros = np.zeros(n)
    # Per mole of inert gas in the ullage: the sensors count it as the fluid (same moles at the
    # same p, T), and a vent meters it at its own molar mass (module docstring).
    dM = M_INERT_KG_PER_MOL - thermo.molar_mass_kg_per_mol
    sig = {"heat": (zeros, tt / _H_REF), "vapor_leak": (-tt, -met["Hv"] / _H_REF),
           "liquid_leak": (-tt, -met["Hl"] / _H_REF), "inflow_meter_bias": (met["in_M"], met["in_E"] / _H_REF),
           "noncondensable_gas": (dM * met["vent_M"], dM * met["vent_E"] / _H_REF), "mass": (tt, zeros)}
    if level_ok:
        C = np.block([[CM * birge_m**2, CME * birge_m * E_scale], [CME.T * birge_m * E_scale, CE * E_scale**2]])
        data = _PhaseData(tt, rM, rE, C, np.concatenate([Jm[:, 2], J_Tl_E / _H_REF]),
                          np.concatenate([zeros, wall]), {k: np.concatenate(v) for k, v in sig.items()},
                          {k: np.concatenate(v) for k, v in props.items()}, drift_W)
    else:
        data = _PhaseData(tt, None, rE, CE * E_scale**2, J_Tl_E / _H_REF, wall, {k: v[1] for k, v in sig.items()},
                          {k: v[1] for k, v in props.items()}, drift_W)
    fig = {"t_s": knots, "M": Ms, "M_std": np.sqrt(np.clip(np.diag(CM), 0, None)) if level_ok else np.full(n, np.nan),
           "E": Es, "E_std": np.sqrt(np.clip(np.diag(CE), 0, None)), "metered_M": met["M"], "metered_E": met["E"],
           "level_ok": level_ok}
    # Step 5: saturation consistency at the knots.
    cons = []
    for k in range(n):
        p, T_v, T_l = vals[k, 0], vals[k, 1], vals[k, 2]
        T_sat = thermo.T_sat(p)
        dTdp = (thermo.T_sat(p + 100.0) - thermo.T_sat(p - 100.0)) / 200.0
        sv = math.sqrt(covs[1][k, k] + covs[0][k, k] * dTdp**2)
        sl = math.sqrt(covs[2][k, k] + covs[0][k, k] * dTdp**2)
        cons.append((knots[k], p, T_v, T_l, T_sat, T_v < T_sat - max(3 * sv, config.saturation_margin_K),
                     T_l > T_sat + max(3 * sl, config.consistency_margin_K)))
    return phase, data, fig, cons, (Ms[-1] if not level_ok else None), met["vented"]


# ----------------------------------------------------------------------------- the audit
def audit_run(run: Run, config: AuditConfig = AuditConfig(), wall_heat_capacity_J_per_K: float | None = None,
              wall_capacity_assumed: bool = False) -> RunAudit:
    """Audit one run's mass and energy (module docstring).

    Args:
        run: a measured run (p_v, T_v and T_l measured; H_l and T_w where available).
        config: an ``AuditConfig``.
        wall_heat_capacity_J_per_K: m_w c_w (J/K); the run's when None (and an aluminium-shell
            estimate when the run states none, ``tankode.wall``).
        wall_capacity_assumed: the value is an estimate (its correction is free, estimated by the
            balances, and a wrong wall heat capacity is not a hypothesis).

    Raises:
        ValueError: the run does not measure p_v, T_v and T_l, or no phase has enough samples.
    """
    from ..wall import resolve_wall_heat_capacity

    missing = [c for c in ("p_v_Pa", "T_v_K", "T_l_K") if c not in run.observations.measured_channels]
    if missing:
        raise ValueError(f"run {run.name!r}: the inventory audit needs p_v_Pa, T_v_K and T_l_K measured; {missing} are not")
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
    ini = run.initial
    ref = _PropertyRef.at(thermo, ini.p_v_Pa, ini.T_l_K, ini.T_v_K)
    perturbed = tuple(_PerturbedThermo(thermo, name, getattr(config, attr), ref)
                      for name, attr in PROPERTY_PRIORS.items() if getattr(config, attr) > 0)

    phases, datas, figs, cons = [], [], [], []
    M_end, vented = None, 0.0
    for a, b in _phases(run, config.min_phase_s):
        got = _audit_phase(run, a, b, thermo, geometry, V_tank, C_w, has_level, has_wall, M_end, vented, config,
                           perturbed)
        if got is None:
            continue
        phase, data, fig, c, M_end, vented = got
        phases.append(phase), datas.append(data), figs.append(fig), cons.extend(c)
    if not phases:
        raise ValueError(f"run {run.name!r}: no operating phase has enough samples of p_v, T_v and T_l to audit")
    mass_level = all(d.rM is not None for d in datas)
    if not mass_level:  # a phase without level samples: audit the energy alone everywhere
        datas = [_energy_only(d) for d in datas]
    consistency, inert = _consistency(thermo, cons, config)
    superheat = float(np.median([r[3] - r[4] for r in cons]))
    excluded = ""
    if superheat > config.consistency_margin_K:
        excluded = (f"the liquid reads a median {superheat:.2f} K warmer than saturation at the measured pressure; an "
                    "inert gas would hold it below (it lowers the hydrogen's partial pressure)")
    # Two explanations: with the reference's properties (strict) and with the property model's
    # uncertainty allowed (robust, where any property prior is on). The robust one reports and
    # names, at z_name_properties; what it names must also stand z_name out in the strict one.
    ullage = _Ullage(ini.p_v_Pa, ini.T_v_K, (1.0 - ini.fill_ratio) * V_tank, ini.p_v_Pa - thermo.p_sat(ini.T_l_K))
    heavier = M_INERT_KG_PER_MOL / thermo.molar_mass_kg_per_mol
    strict = _inert_amount(_explain(_RunFit(datas, has_wall, wall_capacity_assumed, config, properties=False),
                                    mass_level, excluded), ullage, heavier)
    fit = _RunFit(datas, has_wall, wall_capacity_assumed, config, properties=True)
    robust = fit.has_properties
    general, sols, hyps = _inert_amount(_explain(fit, mass_level, excluded), ullage, heavier) if robust else strict
    B = general.birge
    mass = Estimate(*general.rate("mass")) if mass_level else None
    heat = Estimate(*general.rate("heat"))
    per = [p.heat_W for p in phases]
    w = np.array([1 / e.std**2 for e in per])
    v = np.array([e.value for e in per])
    chi2_between = float((w * (v - (w * v).sum() / w.sum()) ** 2).sum())
    naming = dataclasses.replace(config, z_name=config.z_name_properties) if robust else config
    findings, chosen = _name(mass, heat, hyps, general.chi2 / B**2, inert, consistency, naming, mass_level, ullage)
    # The nuisances as the explanation the findings rest on estimates them.
    s, offset = _resting((general, sols, hyps), chosen)
    cw = Estimate(1.0 + s.value("wall"), s.std("wall", B)) if fit.use_wall else None
    z_strict = _strict_z(strict, chosen)
    findings[:0] = _thermometer(offset, superheat, config)
    kept, withheld = [], []
    for f in findings:
        z = z_strict(f)
        if z is None or abs(z) >= config.z_name:
            kept.append(f)
        else:
            withheld.append(f"{f.name} ({f.estimate}) stands {abs(f.estimate.z):.1f} standard errors out where "
                            f"another model of the fluid is allowed for, but {abs(z):.1f} with the reference's "
                            f"properties ({config.z_name:g} needed): not named")
    if robust:  # and what the reference's properties alone would name, but another model explains
        general_s, sols_s, hyps_s = strict
        B_s = general_s.birge
        mass_s = Estimate(*general_s.rate("mass")) if mass_level else None
        named = {f.name for f in findings}
        found, chosen_s = _name(mass_s, Estimate(*general_s.rate("heat")), hyps_s, general_s.chi2 / B_s**2, inert,
                                consistency, config, mass_level, ullage)
        for f in _thermometer(_resting(strict, chosen_s)[1], superheat, config) + found:
            if f.name not in named:
                withheld.append(f"{f.name} ({f.estimate}) stands {abs(f.estimate.z):.1f} standard errors out with the "
                                "reference's properties, but another model of the fluid explains it (AuditConfig's "
                                "property priors): not named")
    series = _series(figs)
    unmeasured = ""
    if inert is None and not excluded and not (fit.has_vent and mass_level):
        why = "no gas is vented" if not fit.has_vent else "no level sensor reads the mass its vents carry"
        unmeasured = (f"an inert gas (helium) is not measurable in this run: {why}, and the ullage does not read "
                      "persistently colder than saturation, so these readings neither show nor rule out one")
    return RunAudit(run.name, tuple(phases), mass, heat, cw, offset, hyps, B, chi2_between,
                    tuple(s for s, _ in consistency), inert, superheat, excluded, tuple(kept), tuple(withheld), series,
                    C_w, not wall_capacity_assumed, unmeasured)


def _thermometer(offset: Estimate, superheat: float, config: AuditConfig) -> list[InventoryFinding]:
    """The liquid thermometer's bias as a finding, where its offset stands ``z_name`` out and the liquid
    it implies does not sit ``saturation_margin_K`` above saturation (median ``superheat`` read)."""
    if abs(offset.z) < config.z_name or superheat - offset.value > config.saturation_margin_K:
        return []
    return [InventoryFinding(
        "temperature_sensor_bias", offset, "K", ("temperature_sensor_bias",),
        f"the liquid temperature reads {offset.value:+.3g} +- {offset.std:.2g} K off the temperature the liquid's "
        "mass and energy changes need: a biased liquid temperature sensor (or one sitting in a layer warmer or "
        "colder than the bulk)")]


def _resting(explanation, chosen: str) -> tuple["_Solution", Estimate]:
    """The fit the findings rest on (``chosen``'s hypothesis, or the free fit where none is chosen)
    and the liquid temperature offset it estimates; ``explanation`` is ``_explain``'s."""
    general, sols, _ = explanation
    s = sols[chosen] if chosen in sols else general
    return s, Estimate(s.value("T_l"), s.std("T_l", general.birge))


def _strict_z(strict, chosen: str):
    """``finding -> z`` in the strict explanation, from the fit the finding's estimate comes from
    (``InventoryFinding.fit``; None for what the balances do not rate)."""
    general, _, hyps = strict
    offset = _resting(strict, chosen)[1]

    def z(f: InventoryFinding) -> float | None:
        if f.name == "temperature_sensor_bias":
            return offset.z
        if f.fit == "mass":
            value, std = general.rate("mass", general.birge)
            return value / std if std > 0 else 0.0
        return hyps[f.fit].z if f.fit in hyps else None
    return z


def _explain(fit: "_RunFit", mass_level: bool, excluded: str):
    """The free fit (unmetered mass and heat), and each single-cause hypothesis's fit and summary.

    Every fit's standard errors and chi2 are scaled by one Birge ratio (``general.birge``): the
    free fit's, or the best single cause's where the free fit's is ``AuditConfig.birge_gap``
    times larger. The free fit's constant rates cannot follow a cause proportional to a metered
    flow (an inflow meter's bias on a fast fill: the free fit's Birge ratio 17, the bias's 1.0),
    and scaling by theirs would hide the cause that explains the balances within their noise.
    """
    general = fit.solve(["mass", "heat"] if mass_level else ["heat"])
    sols, hyps = {}, {}
    for name in HYPOTHESES:
        if name == "inflow_meter_bias" and not fit.has_inflow:
            continue
        if name in ("vapor_leak", "liquid_leak", "inflow_meter_bias", "noncondensable_gas") and not mass_level:
            continue
        # An inert gas shows only where gas is vented, and not where the liquid rules it out.
        if name == "noncondensable_gas" and (not fit.has_vent or excluded):
            continue
        if name == "wall_heat_capacity_error" and not fit.stated_wall:
            continue
        sols[name] = fit.solve([name])
    if fit.stated_wall:
        sols[HEAT_AT_STATED_WALL] = fit.solve(["heat"], stated_wall=True)
    # The mass check at the free fit's scale (the wider interval), before any rescaling: a cause
    # the mass balance does not bear out sets no scale.
    disagrees = {name: _mass_disagrees(fit, name, *s.rate(name, general.birge))
                 for name, s in sols.items() if name in _MASS_CARRYING}
    best = min([s.birge for name, s in sols.items() if not disagrees.get(name)], default=general.birge)
    if general.birge >= fit.config.birge_gap * best:
        general.birge = best
    B = general.birge
    for name, s in sols.items():
        value, std = s.rate("heat" if name == HEAT_AT_STATED_WALL else name, B)
        shown = 1.0 + value if name == "wall_heat_capacity_error" else value
        hyps[name] = Hypothesis(name, s.chi2 / B**2, Estimate(shown, std), value / std if std > 0 else 0.0,
                                disagrees.get(name, ""))
    return general, sols, hyps


# Causes whose mass the balances meter: the mass balance alone must not contradict them.
_MASS_CARRYING = ("vapor_leak", "liquid_leak", "inflow_meter_bias")


def _mass_disagrees(fit: "_RunFit", name: str, value: float, std: float) -> str:
    """Why the mass balance alone does not bear out the joint fit's rate ``value`` +- ``std`` of
    the mass-carrying cause ``name``, or "": its own fit on the mass rows differs from the joint
    one by more than three combined standard errors (leaks and meter bias), or, for an inflow
    meter's bias (a mass the meter misreads), stands less than two standard errors from zero on
    the joint one's side (its support, one-sided).

    Energy alone can mimic such a cause: a wall no sensor reads stores the heat of 300 K gas
    injected into a cold ullage, and the energy balance then reads the injection as 77 % short
    (an inflow meter's bias, 11 standard errors) where the mass balance reads +0.09 +- 0.37.
    """
    s = fit.solve([name], rows="mass")
    if s is None:
        return ""
    v, sd = s.rate(name)
    said = f"the mass balance alone reads {v:.3g} +- {sd:.2g} against the joint {value:.3g} +- {std:.2g}"
    if abs(v - value) > 3.0 * math.hypot(sd, std):
        return said
    if name == "inflow_meter_bias" and not (v * value > 0 and abs(v) >= 2.0 * sd):
        return said + ": the energy balance alone carries it, which model error in energy (a wall no sensor reads) can"
    return ""


def _inert_amount(explanation, ullage: "_Ullage", heavier: float):
    """``explanation`` with the inert gas's amount corrected for the linearisation of its vent
    signature (module docstring, step 6): the vented share is taken on the inventory's mass, which
    counts the gas at the fluid's molar mass, so the fitted amount ``n_lin`` is ``n / (1 + x (r -
    1))`` at mole fraction ``x = n R T_v / (V_v p)`` and molar-mass ratio ``r`` (``heavier``), i.e.
    ``n = n_lin / (1 - n_lin c)`` with ``c = R T_v (r - 1) / (V_v p)``, at the start's ullage. The
    correction is capped at a factor of two (``n_lin c <= 0.5``); the relative standard error, z
    and chi2 are the fit's."""
    general, sols, hyps = explanation
    h = hyps.get("noncondensable_gas")
    if h is None or h.estimate.value <= 0:
        return explanation
    c = R_J_PER_MOLK * ullage.T_v_K * (heavier - 1.0) / (ullage.V_v_m3 * ullage.p_Pa)
    k = max(1.0 - h.estimate.value * c, 0.5)
    e = Estimate(h.estimate.value / k, h.estimate.std / k)
    return general, sols, {**hyps, "noncondensable_gas": Hypothesis(h.name, h.chi2, e, h.z)}


def _energy_only(d: _PhaseData) -> _PhaseData:
    if d.rM is None:
        return d
    n = len(d.tt)
    return _PhaseData(d.tt, None, d.rE, d.C[n:, n:], d.J_Tl[n:], d.wall[n:], {k: v[n:] for k, v in d.cols.items()},
                      {k: v[n:] for k, v in d.props.items()}, d.drift_W)


class _Solution:
    def __init__(self, names, coef, cov, chi2, dof, index):
        self.names, self.coef, self.cov, self.chi2, self.dof, self.index = names, coef, cov, chi2, dof, index
        self.birge = _birge(chi2, dof)

    def value(self, name: str) -> float:
        return float(self.coef[self.index[name]])

    def std(self, name: str, birge: float | None = None) -> float:
        i = self.index[name]
        return float(math.sqrt(max(self.cov[i, i], 0.0))) * (self.birge if birge is None else birge)

    def rate(self, name: str, birge: float | None = None) -> tuple[float, float]:
        return self.value(name), self.std(name, birge)


class _RunFit:
    """The joint GLS of every phase's residuals (module docstring, step 4) with chosen rate columns."""

    def __init__(self, datas: list[_PhaseData], has_wall: bool, assumed: bool, config: AuditConfig,
                 properties: bool = False):
        self.datas, self.config = datas, config
        self.use_wall = has_wall and any(np.ptp(d.wall) > 0 for d in datas)
        self.has_inflow = any(np.ptp(d.cols["inflow_meter_bias"]) > 0 for d in datas)
        self.has_vent = any(np.ptp(d.cols["noncondensable_gas"]) > 0 for d in datas)
        self.r = np.concatenate([np.concatenate([d.rM, d.rE / _H_REF]) if d.rM is not None else d.rE / _H_REF
                                 for d in datas])
        # Which of those rows are the mass balance's (``solve(rows="mass")``).
        self.mass_rows = np.concatenate([np.r_[np.ones(len(d.tt), bool), np.zeros(len(d.tt), bool)]
                                         if d.rM is not None else np.zeros(len(d.tt), bool) for d in datas])
        n = len(self.r)
        self.C = np.zeros((n, n))
        o = 0
        for d in datas:
            m = len(d.C)
            self.C[o:o + m, o:o + m] = d.C
            o += m
        # Intercepts: one per phase and balance.
        cols, o = [], 0
        for d in datas:
            blocks = 2 if d.rM is not None else 1
            for j in range(blocks):
                c = np.zeros(n)
                c[o + j * len(d.tt):o + (j + 1) * len(d.tt)] = 1.0
                cols.append(c)
            o += blocks * len(d.tt)
        self.base = cols
        self.nuisance = {"T_l": np.concatenate([d.J_Tl for d in datas])}
        self.prior = {"T_l": config.liquid_bias_prior_K}
        self.has_properties = False
        for name, attr in PROPERTY_PRIORS.items():
            if properties and getattr(config, attr) > 0:
                self.nuisance[name] = np.concatenate([d.props[name] for d in datas])
                self.prior[name] = getattr(config, attr)
                self.has_properties = True
        # Without a wall sensor, each phase's unseen wall storage: a steady power over the phase
        # (the heat's signature there), with its prior (``_PhaseData.drift_W``), in units of that
        # prior (unit-scaled, the GLS keeps its conditioning: a 10 kW prior in W left the heat's
        # variance to the pseudo-inverse's cut-off).
        o = 0
        for i, d in enumerate(datas):
            m = len(d.C)
            if d.drift_W > 0:
                c = np.zeros(n)
                c[o:o + m] = d.cols["heat"] * d.drift_W
                self.nuisance[f"wall_drift_{i}"], self.prior[f"wall_drift_{i}"] = c, 1.0
            o += m
        if self.use_wall:
            self.nuisance["wall"] = np.concatenate([d.wall for d in datas])
            if not assumed:  # an unstated capacity is free (AuditConfig.wall_capacity_prior)
                self.prior["wall"] = config.wall_capacity_prior
        # Only a stated capacity can be wrong, or be held at its value.
        self.stated_wall = self.use_wall and not assumed

    def column(self, name: str) -> np.ndarray:
        return np.concatenate([d.cols[name] for d in self.datas])

    def solve(self, rates: list[str], stated_wall: bool = False, rows: str = "all") -> _Solution | None:
        """Fit with the rate columns ``rates``; ``"wall_heat_capacity_error"`` frees the wall correction's
        prior, ``stated_wall`` drops the correction (the stated heat capacity taken as exact).
        ``rows="mass"`` fits the mass balance alone (None where no phase has one); columns it
        does not reach are held at 0 (their priors, or a tight one)."""
        free_wall = "wall_heat_capacity_error" in rates
        rates = [k for k in rates if k != "wall_heat_capacity_error"]
        nuisance = [k for k in self.nuisance if not (stated_wall and k == "wall")]
        names = nuisance + rates
        X = np.column_stack(self.base + [self.nuisance[k] for k in nuisance] + [self.column(k) for k in rates])
        r, C = self.r, self.C
        if rows == "mass":
            keep = self.mass_rows
            if not keep.any():
                return None
            X, r, C = X[keep], r[keep], C[np.ix_(keep, keep)]
        index = {k: len(self.base) + i for i, k in enumerate(names)}
        if free_wall:
            index["wall_heat_capacity_error"] = index["wall"]
        prior = {k: v for k, v in self.prior.items() if k in nuisance and not (free_wall and k == "wall")}
        k = X.shape[1]
        # Columns without a prior that these rows do not reach (the energy intercepts of a mass fit)
        # are held at 0 by a tight one: free, they would leave the normal matrix singular.
        prior_rows = [(index[n], v) for n, v in prior.items()]
        held = {j for j, _ in prior_rows}
        unreached = [j for j in range(k) if j not in held and not np.any(X[:, j])] if rows == "mass" else []
        prior_rows += [(j, 1e-6) for j in unreached]
        # Priors on the nuisances as pseudo-observations.
        P = np.zeros((len(prior_rows), k))
        for i, (j, _) in enumerate(prior_rows):
            P[i, j] = 1.0
        Xa = np.vstack([X, P])
        ra = np.concatenate([r, np.zeros(len(prior_rows))])
        Ca = np.zeros((len(ra), len(ra)))
        Ca[:len(r), :len(r)] = C
        Ca[len(r):, len(r):] = np.diag([v**2 for _, v in prior_rows])
        coef, cov, chi2, _ = _gls(Xa, ra, Ca)
        dof = max(len(r) - k + len(unreached), 1)
        return _Solution(names, coef, cov, chi2, dof, index)


def _series(figs) -> dict:
    """Measured and metered inventories over the run (the metered one starts at the first measurement)."""
    out = {k: [] for k in ("t_s", "mass_kg", "mass_std", "mass_metered_kg", "energy_J", "energy_std", "energy_metered_J")}
    offM = offE = None
    for f in figs:
        if offM is None:
            offM, offE = f["M"][0], f["E"][0]
        out["t_s"].extend(f["t_s"].tolist())
        out["mass_kg"].extend(f["M"].tolist() if f["level_ok"] else [float("nan")] * len(f["t_s"]))
        out["mass_std"].extend(f["M_std"].tolist())
        out["mass_metered_kg"].extend((offM + f["metered_M"]).tolist())
        out["energy_J"].extend(f["E"].tolist())
        out["energy_std"].extend(f["E_std"].tolist())
        out["energy_metered_J"].extend((offE + f["metered_E"]).tolist())
        offM, offE = offM + f["metered_M"][-1], offE + f["metered_E"][-1]
    return {k: np.asarray(v, float) for k, v in out.items()}


def _consistency(thermo: _Thermo, rows, config: AuditConfig) -> tuple[list[tuple[str, bool]], float | None]:
    """Sentences (with whether each is persistent) and the inert gas's partial-pressure lower bound."""
    out, inert = [], None
    n = len(rows)
    cold = [r for r in rows if r[5]]
    hot = [r for r in rows if r[6]]
    if cold:
        persistent = len(cold) >= config.consistency_share * n
        bound = [r[1] - thermo.p_sat(r[2]) for r in cold]
        t, p, T_v, _, T_sat, _, _ = max(cold, key=lambda r: r[4] - r[2])
        if persistent:
            inert = float(np.median(bound))
            out.append((f"the ullage reads colder than saturation at the measured pressure at {len(cold)} of {n} audit "
                        f"times, by up to {T_sat - T_v:.2f} K (t = {t:.0f} s): a pure vapour would condense; an inert "
                        f"gas with a partial pressure of at least {inert:.4g} Pa (median; {inert / p:.0%} of the "
                        "pressure), or a biased pressure or ullage temperature sensor", True))
        else:
            out.append((f"the ullage reads colder than saturation at {len(cold)} of {n} audit times (up to "
                        f"{T_sat - T_v:.2f} K at t = {t:.0f} s): a transient, not persistent enough to be evidence", False))
    if hot:
        persistent = len(hot) >= config.consistency_share * n
        t, p, _, T_l, T_sat, _, _ = max(hot, key=lambda r: r[3] - r[4])
        if persistent:
            out.append((f"the liquid reads warmer than saturation at the measured pressure at {len(hot)} of {n} audit "
                        f"times, by up to {T_l - T_sat:.2f} K (t = {t:.0f} s): a pressure sensor reading low or a "
                        "liquid temperature sensor reading high", True))
        else:
            out.append((f"the liquid reads warmer than saturation at {len(hot)} of {n} audit times (up to "
                        f"{T_l - T_sat:.2f} K at t = {t:.0f} s): a transient (superheat before flashing), not "
                        "persistent enough to be evidence", False))
    return out, inert


class _Ullage(NamedTuple):
    """The ullage at the start, for an inert gas: its partial pressure is stated from ``p_Pa``,
    ``T_v_K`` and ``V_v_m3``, and may not exceed ``room_Pa`` (the pressure less the liquid's
    saturation pressure: the liquid surface sits at saturation of the fluid's partial pressure)."""

    p_Pa: float
    T_v_K: float
    V_v_m3: float
    room_Pa: float

    def partial_pressure_Pa(self, n_mol: float) -> float:
        return n_mol * R_J_PER_MOLK * self.T_v_K / self.V_v_m3


def _name(mass, heat, hyps, chi2_general, inert, consistency, config, mass_level, ullage: _Ullage | None = None):
    """The findings of the balances (module docstring, step 6) and the hypothesis they rest on ("" for none).

    ``ullage``: where given, an inert gas amount whose partial pressure exceeds ``ullage.room_Pa``
    by three standard errors is inadmissible, and a named one is stated as a partial pressure.
    """
    out: list[InventoryFinding] = []
    chosen = ""
    z, sep = config.z_name, config.chi2_separation
    note = "" if mass_level else " (no level sensor: an unmetered mass loss would read as heat too)"
    # A leak's rate is a loss (> 0), an amount of gas is positive: a fitted negative one is neither.
    admissible = [h for h in hyps.values() if h.name in HYPOTHESES and not h.mass_disagrees
                  and (h.name not in ("vapor_leak", "liquid_leak", "noncondensable_gas") or h.estimate.value > 0)]
    if ullage is not None:
        admissible = [h for h in admissible if h.name != "noncondensable_gas"
                      or ullage.partial_pressure_Pa(h.estimate.value - 3 * h.estimate.std) <= ullage.room_Pa]
    free_mass = mass is not None and abs(mass.z) >= z
    free_heat = abs(heat.z) >= z
    if admissible:
        best = min(admissible, key=lambda h: h.chi2)
        significant = abs(best.z) >= z
        explains = best.chi2 - chi2_general <= sep
        # A rival explains the data about as well with its own rate resolved (|z| >= 3); one whose rate
        # is ~0 there only says the nuisances (wall capacity prior, liquid offset) could explain it.
        rivals = [h for h in admissible if h is not best and h.chi2 - best.chi2 < sep and abs(h.z) >= 3]
        # A wall that warms or cools at a steady rate stores heat like a constant unmetered heat:
        # the heat's own fit then lets the wall correction's prior take it (its rate ~0), and only
        # with the stated heat capacity held does the heat stand as the wall's equal.
        stated = hyps.get(HEAT_AT_STATED_WALL)
        confounded = (best.name == "wall_heat_capacity_error" and stated is not None and stated.estimate.value > 0
                      and stated.chi2 - best.chi2 < sep and abs(stated.z) >= z)
        if significant and explains and confounded:
            w, e = best.estimate, stated.estimate
            out.append(InventoryFinding(
                "unmetered_heat", e, "W", HEAT_CANDIDATES + (best.name,),
                f"unmetered heat {e.value:.3g} +- {e.std:.2g} W entering the tank at the stated wall heat capacity, or "
                f"a wall that stores heat as {w.value:.3g} +- {w.std:.2g} times the stated heat capacity: the wall "
                f"changes temperature at a steady rate, so the balances do not tell a heat leak (into the wall, "
                f"the liquid or the ullage) from a wrong wall heat capacity{note}", HEAT_AT_STATED_WALL))
        elif significant and explains and not rivals:
            out.append(_single(best, note, ullage))
            chosen = best.name
        elif free_mass or free_heat or (significant and explains):
            # A single rate that is resolved only where it fails to explain the balances, while
            # the free mass and heat are not resolved, is model or sensor error (a biased liquid
            # thermometer shifts the inventory along a drain), not an unmetered flow: nothing.
            names = [best.name] + [h.name for h in rivals] if explains else [h.name for h in admissible]
            cands = tuple(c for nme in names for c in (_heat_candidates(heat) if nme == "heat" else (nme,)))
            listed = ", ".join(cands) or "no heat leak (heat leaves the tank)"
            leaks = [hyps[n] for n in names if n in ("vapor_leak", "liquid_leak")]
            # A leak that explains the balances best, or leaks rivalled only by each other and by heat
            # leaving the tank (the energy they carry resolved, the mass balance alone too weak to
            # tell them apart): the loss in the leaks' unit, the best-fitting leak's rate as the estimate.
            leak_first = explains and best.name in ("vapor_leak", "liquid_leak")
            only_leaks = leaks and not free_mass and not any(
                c in HEAT_CANDIDATES or c == "wall_heat_capacity_error" for c in cands)
            if leak_first or only_leaks:
                first = min(leaks, key=lambda h: h.chi2)
                readings = [_reading(hyps[n]) for n in sorted(names, key=lambda n: hyps[n].chi2)]
                out.append(InventoryFinding(
                    "unmetered_mass", Estimate(-first.estimate.value, first.estimate.std), "kg/s", cands,
                    f"unmetered mass loss: {', '.join(readings[:-1])} or {readings[-1]}, which the balances do not "
                    f"tell apart{note}", first.name))
            elif free_mass:
                kind = "loss" if mass.value < 0 else "gain"
                out.append(InventoryFinding(
                    "unmetered_mass", mass, "kg/s", cands,
                    f"unmetered mass {kind} of {abs(mass.value):.3g} +- {mass.std:.2g} kg/s with unmetered heat "
                    f"{heat.value:.3g} +- {heat.std:.2g} W beside it; the balances do not tell which of "
                    f"{listed} carries it", "mass"))
            else:
                # Where the wall's heat capacity is among the candidates, the heat is the one at the stated capacity.
                at_stated = "wall_heat_capacity_error" in cands and stated is not None
                e, at = (stated.estimate, " at the stated wall heat capacity") if at_stated else (heat, "")
                out.append(InventoryFinding(
                    "unmetered_heat", e, "W", cands,
                    f"unmetered heat {e.value:.3g} +- {e.std:.2g} W{at}{note}; the balances do not tell "
                    f"{listed} apart", HEAT_AT_STATED_WALL if at_stated else "heat"))
    persistent_cold = any(p and s.startswith("the ullage reads colder") for s, p in consistency)
    if persistent_cold:
        out.append(InventoryFinding("inert_gas_or_sensor_bias", Estimate(inert, float("nan")), "Pa",
                                    ("noncondensable_gas", "pressure_sensor_bias"),
                                    f"the ullage reads colder than saturation at the measured pressure: an inert gas "
                                    f"(partial pressure at least {inert:.4g} Pa) or a biased pressure or ullage "
                                    "temperature sensor"))
    return out, chosen


def _heat_candidates(heat: Estimate) -> tuple[str, ...]:
    """Where unmetered heat may enter; none for heat leaving the tank (heat leaks are inflows)."""
    return HEAT_CANDIDATES if heat.value > 0 else ()


def _reading(h: Hypothesis) -> str:
    """One hypothesis's reading in words, for a finding that lists rivals."""
    e = h.estimate
    if h.name in ("vapor_leak", "liquid_leak"):
        return f"a {'vapour' if h.name == 'vapor_leak' else 'liquid'} leak of {e.value:.3g} +- {e.std:.2g} kg/s"
    if h.name == "heat":
        where = ("entering the tank" if e.value > 0 else
                 "leaving the tank (a metered heat load above the true one)")
        return f"{abs(e.value):.3g} +- {e.std:.2g} W of heat {where}"
    if h.name == "inflow_meter_bias":
        return f"inflows {1 + e.value:.3g} (+- {e.std:.2g}) times the metered ones"
    if h.name == "wall_heat_capacity_error":
        return f"a wall storing {e.value:.3g} +- {e.std:.2g} times the stated heat capacity"
    return f"{e.value:.3g} +- {e.std:.2g} mol of inert gas"


def _single(h: Hypothesis, note: str = "", ullage: _Ullage | None = None) -> InventoryFinding:
    e = h.estimate
    if h.name == "noncondensable_gas":
        share = ""
        if ullage is not None:
            p_in = ullage.partial_pressure_Pa(e.value)
            share = f" (a partial pressure of {p_in:.3g} Pa at the start, {p_in / ullage.p_Pa:.0%} of the pressure)"
        return InventoryFinding(h.name, e, "mol", (h.name,),
                                f"{e.value:.3g} +- {e.std:.2g} mol of inert gas (helium) in the ullage{share}: the "
                                "vents meter more mass than the sensors' inventory loses, as a heavier gas counted as "
                                "the fluid's vapour leaves with them", h.name)
    if h.name == "wall_heat_capacity_error":
        return InventoryFinding(h.name, e, "x stated", (h.name,),
                                f"the wall stores heat as {e.value:.3g} +- {e.std:.2g} times the stated heat capacity: "
                                "the unmetered energy follows the wall temperature", h.name)
    if h.name == "heat":
        if e.value > 0:
            return InventoryFinding("unmetered_heat", e, "W", HEAT_CANDIDATES,
                                    f"unmetered heat {e.value:.3g} +- {e.std:.2g} W entering the tank: through the "
                                    f"wall, the liquid or the ullage, which the whole-tank balance cannot tell "
                                    f"apart{note}", h.name)
        return InventoryFinding("unmetered_heat", e, "W", (),
                                f"unmetered heat {e.value:.3g} +- {e.std:.2g} W leaving the tank: a metered heat load "
                                f"above the true one, or a loss the balances do not attribute{note}", h.name)
    if h.name == "inflow_meter_bias":
        return InventoryFinding("inflow_meter_bias", e, "relative", ("inflow_meter_bias",),
                                f"the true inflows are {1 + e.value:.3g} (+- {e.std:.2g}) times the metered ones: the "
                                "unmetered mass and energy follow the metered inflow", h.name)
    stream = "ullage" if h.name == "vapor_leak" else "liquid"
    return InventoryFinding(h.name, e, "kg/s", (h.name,),
                            f"unmetered mass loss of {e.value:.3g} +- {e.std:.2g} kg/s carrying the {stream}'s "
                            f"enthalpy: a {'vapour' if h.name == 'vapor_leak' else 'liquid'} leak", h.name)


# A wall heat capacity the run does not state is replaced by the audit's reading where the balances
# read it this well (relative standard error): tankode's aluminium-shell guess can be 50 times off.
WALL_READING_REL_STD = 0.3


def wall_reading(a: RunAudit) -> Estimate | None:
    """The audit's reading of a wall heat capacity its run does not state (J/K), where it is
    positive and within ``WALL_READING_REL_STD``; None otherwise (a stated capacity included)."""
    c = None if a.wall_capacity_stated else a.wall_heat_capacity
    return c if c is not None and c.value > 0 and c.std < WALL_READING_REL_STD * c.value else None


def with_audited_wall(run: Run, config: AuditConfig = AuditConfig()) -> tuple[Run, str | None]:
    """``run`` with an unstated wall heat capacity set to the inventory audit's reading, and a note.

    The run unchanged (and None) where it states its capacity, has no wall sensor, cannot be
    audited or the reading is not within ``WALL_READING_REL_STD``. The audit reads the whole
    run: a stream that starts with an unknown wall should state it once read.
    """
    if run.tank.wall_heat_capacity_J_per_K is not None or "T_w_K" not in run.observations.measured_channels:
        return run, None
    try:
        a = audit_run(run, config)
    except ValueError:
        return run, None
    c = wall_reading(a)
    if c is None:
        return run, None
    note = (f"{run.name}: the run states no wall heat capacity; the inventory audit of the whole run reads "
            f"{c.value:.4g} +- {c.std:.2g} J/K, used in its place")
    return dataclasses.replace(run, tank=dataclasses.replace(run.tank, wall_heat_capacity_J_per_K=c.value)), note


__all__ = ["AuditConfig", "Estimate", "Hypothesis", "PhaseAudit", "InventoryFinding", "RunAudit", "audit_run",
           "HYPOTHESES", "HEAT_CANDIDATES", "WALL_READING_REL_STD", "wall_reading", "with_audited_wall"]
