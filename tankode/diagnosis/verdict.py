"""The verdict: what the diagnosis names, from the inventory audit first and the dynamic search second.

The inventory audit (``audit.py``) measures what entered or left the tank without a heat-transfer
law; the dynamic search (``diagnose.py``) compares the model's predictions, and is only as good as
the model's heat transfer is for the tank. The verdict therefore rests on the audit wherever the
audit can decide, and lets the dynamic search speak only where the model follows the data.

Mechanisms are of two kinds:

* **Inventory mechanisms** change what the whole tank holds: heat leaks into the liquid, the
  ullage or the wall; vapour and liquid leaks; a biased inflow meter (and a wrong wall heat
  capacity or a liquid temperature offset, which the audit estimates alongside). The audit
  decides them: a single cause whose signature is ``z_name`` (5) standard errors from zero and
  that the other single causes cannot match is named with the audit's estimate. Unmetered heat
  is named as the measured quantity with the places it may enter (wall, liquid, ullage); the
  dynamic search may narrow that list to one (``locate``) only where it clearly separates them.
* **Other mechanisms** (sensor biases, an inert gas, stratification, the dry wall's share) leave
  the inventory unchanged; only the dynamic search can name them.
* **The model's form.** A tank's own physics that the baseline lacks (a dry wall that heats the
  ullage, a stratified liquid: ``Mechanism.model_form``) is not a cause: another simulator's
  tank or a real one with nothing wrong has it. Where the dynamic search names one, the
  verdict is ``model_form`` (no cause), and the extended model carries the mechanism.

The dynamic search names a candidate only if it clears ``Thresholds`` (``diagnose.py``) and two
more conditions:

* **adequate**: with the candidate, the model predicts the held-out data within
  ``Thresholds.adequate`` times the noise floor (its held-out loss). On another simulator's tank
  the calibrated baseline can miss by 20-40 sigma; a mechanism that removes part of that misfit
  explains model-form error, not a cause.
* **consistent with the audit**: the candidate's rate (a heat leak's W, a leak's kg/s, an inflow
  bias, a wall capacity factor) lies within ``AUDIT_SIGMAS`` standard errors of the audit's
  estimate, widened by the 25 % accuracy a named estimate must have. A candidate whose rate the
  audit excludes (e.g. 150 W named where the audit measures 0 +- 16 W) is ruled out.

An ullage that reads persistently colder than saturation is evidence of an inert gas or a
biased sensor: where the dynamic search does not name one of the two, the verdict names the
measured partial-pressure bound with both candidates. A liquid that reads warmer than
saturation over most of the run rules an inert gas out: the gas would lower the hydrogen's
partial pressure and with it the liquid's temperature, so a model that needs one there is
compensating something else (another simulator's liquid that superheats at rest, for one).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from ..mechanisms import MECHANISMS
from .audit import HEAT_CANDIDATES, Estimate, RunAudit

# Inventory mechanisms and the audit hypothesis that measures each (the value a dynamic fit's
# first parameter is compared with; the wall's is its factor minus 1).
AUDIT_HYPOTHESIS = {"heat_leak_liquid": "heat", "heat_leak_vapor": "heat", "heat_leak_wall": "heat",
                    "vapor_leak": "vapor_leak", "liquid_leak": "liquid_leak", "inflow_meter_bias": "inflow_meter_bias",
                    "wall_heat_capacity_error": "wall_heat_capacity_error", "noncondensable_gas": "noncondensable_gas"}
INVENTORY = ("heat_leak_liquid", "heat_leak_vapor", "heat_leak_wall", "vapor_leak", "liquid_leak", "inflow_meter_bias")
# Standard errors of the audit's estimate within which a dynamic estimate must lie.
AUDIT_SIGMAS = 3.0
# Relative accuracy allowed on top of that (the accuracy a named estimate must have).
AUDIT_RELATIVE = 0.25
_UNITS = {"heat": "W", "vapor_leak": "kg/s", "liquid_leak": "kg/s", "inflow_meter_bias": "relative",
          "wall_heat_capacity_error": "x stated", "temperature_sensor_bias": "K", "noncondensable_gas": "mol"}


@dataclass(frozen=True)
class Verdict:
    """What the diagnosis names.

    Attributes:
        kind: ``"cause"`` (one mechanism named), ``"unresolved"`` (a measured quantity whose
            candidates the data do not tell apart), ``"model_form"`` (no cause; a mechanism of
            the tank's build, ``Mechanism.model_form``, that the baseline lacks: the extended
            model carries it) or ``"none"``.
        name: the mechanism id (a cause or the model's form), the finding's name (``unmetered_heat``,
            ``unmetered_mass``, ``inert_gas_or_sensor_bias``), or None.
        estimate: the named quantity with its standard error, in ``unit``; None where unmeasured.
        candidates: the mechanisms the verdict is consistent with (one for a cause).
        source: ``"inventory audit"``, ``"dynamic search"`` or ``"inventory audit, located by
            the dynamic search"``.
        sentence: the verdict in words.
        notes: why candidates were ruled out or not narrowed; with "none", what the balances could
            not measure (an inert gas where no gas is vented).
    """

    kind: str
    name: str | None
    estimate: Estimate | None
    unit: str
    candidates: tuple[str, ...]
    source: str
    sentence: str
    notes: tuple[str, ...] = field(default=())

    @property
    def named(self) -> str | None:
        """The mechanism the extended model adds: a cause's or the model's form's id, else None."""
        return self.name if self.kind in ("cause", "model_form") else None

    def to_json(self) -> dict:
        return {"kind": self.kind, "name": self.name, "estimate": self.estimate.to_json() if self.estimate else None,
                "unit": self.unit, "candidates": list(self.candidates), "source": self.source,
                "sentence": self.sentence, "notes": list(self.notes)}


NONE = Verdict("none", None, None, "", (), "", "no cause: nothing unmetered beyond the noise, and no candidate "
                                                  "mechanism explains the data with the required evidence")
# Where no run could be audited (its sensors do not give the inventory): nothing is said of it.
NONE_UNAUDITED = Verdict("none", None, None, "", (), "", "no cause: the inventory was not audited (no run measures "
                                                             "p_v, T_v and T_l), and no candidate mechanism explains "
                                                             "the data with the required evidence")


@dataclass(frozen=True)
class Inventory:
    """The audits of a tank's runs, combined (one cause shared by the runs).

    Attributes:
        audits: one ``RunAudit`` per run that could be audited.
        cause: a single cause the audits name (a mechanism id, or ``temperature_sensor_bias``).
        estimate: its estimate (inverse-variance mean over the runs), in ``unit``.
        unresolved: the finding's name when the audits measure something whose candidates they
            do not tell apart (``unmetered_heat``, ``unmetered_mass``), with ``candidates``.
        inert_Pa: the inert gas's partial-pressure lower bound where an ullage reads
            persistently colder than saturation.
        sentences: the audits' findings in words.
    """

    audits: tuple[RunAudit, ...]
    cause: str | None = None
    estimate: Estimate | None = None
    unit: str = ""
    unresolved: str | None = None
    candidates: tuple[str, ...] = ()
    inert_Pa: float | None = None
    sentences: tuple[str, ...] = ()

    def rate(self, hypothesis: str) -> Estimate | None:
        """The audits' combined estimate of one hypothesis's rate (None where no run has it)."""
        ests = [a.hypotheses[hypothesis].estimate for a in self.audits if hypothesis in a.hypotheses]
        return _combine(ests)


def _combine(ests: list[Estimate]) -> Estimate | None:
    ests = [e for e in ests if e.std > 0 and math.isfinite(e.std)]
    if not ests:
        return None
    w = np.array([1 / e.std**2 for e in ests])
    v = np.array([e.value for e in ests])
    return Estimate(float((w * v).sum() / w.sum()), float(1 / math.sqrt(w.sum())))


def inventory(audits: list[RunAudit]) -> Inventory:
    """Combine the runs' findings: one single cause all naming runs agree on, or what they measure."""
    audits = tuple(audits)
    sentences = tuple((f"{a.run}: " if len(audits) > 1 else "") + f.sentence for a in audits for f in a.findings)
    inert = [a.inert_partial_pressure_Pa for a in audits if a.inert_partial_pressure_Pa is not None]
    inert_Pa = float(min(inert)) if inert else None
    singles = {f.name for a in audits for f in a.findings
               if f.name in ("vapor_leak", "liquid_leak", "inflow_meter_bias", "wall_heat_capacity_error",
                             "temperature_sensor_bias", "noncondensable_gas")}
    groups = [f for a in audits for f in a.findings if f.name in ("unmetered_heat", "unmetered_mass")]
    base = Inventory(audits, inert_Pa=inert_Pa, sentences=sentences)
    if len(singles) == 1 and not groups:
        (name,) = singles
        if name == "temperature_sensor_bias":
            est = _combine([a.liquid_offset_K for a in audits if a.finding(name) is not None])
        else:
            est = _combine([a.hypotheses[name].estimate for a in audits if a.finding(name) is not None])
        return Inventory(audits, name, est, _UNITS[name], None, (name,), inert_Pa, sentences)
    if singles or groups:
        cands = tuple(dict.fromkeys(c for a in audits for f in a.findings
                                    if f.name in singles | {"unmetered_heat", "unmetered_mass"} for c in f.candidates))
        masses = [f for f in groups if f.name == "unmetered_mass"]
        name = "unmetered_mass" if masses or any(s in singles for s in ("vapor_leak", "liquid_leak")) else "unmetered_heat"
        est = _combine([f.estimate for f in groups if f.name == name and f.estimate is not None])
        if est is None and name == "unmetered_mass":  # leaks named beside another single (a thermometer's bias)
            est = _combine([Estimate(-f.estimate.value, f.estimate.std) for a in audits for f in a.findings
                            if f.name in ("vapor_leak", "liquid_leak")])
        return Inventory(audits, None, est, "kg/s" if name == "unmetered_mass" else "W", name, cands, inert_Pa, sentences)
    return base


def audit_consistency(mechanism: str, value: float, inv: Inventory) -> tuple[bool, str]:
    """Whether a dynamic estimate of an inventory mechanism is within what the audit measured.

    Returns ``(consistent, reason)``; mechanisms the audit does not measure are consistent. An
    inert gas is ruled out where a run's liquid reads warmer than saturation at the measured
    pressure on most of the run (``RunAudit.inert_gas_excluded``), and is measured (in mol) where
    gas is vented.
    """
    if mechanism == "noncondensable_gas":
        why = [f"{a.run}: {a.inert_gas_excluded}" if len(inv.audits) > 1 else a.inert_gas_excluded
               for a in inv.audits if a.inert_gas_excluded]
        if why:
            return False, "ruled out by the saturation test: " + "; ".join(why)
    hyp = AUDIT_HYPOTHESIS.get(mechanism)
    if hyp is None:
        return True, ""
    est = inv.rate(hyp)
    if est is None:
        return True, ""
    audit_value = est.value - 1.0 if hyp == "wall_heat_capacity_error" else est.value
    tol = AUDIT_SIGMAS * est.std + AUDIT_RELATIVE * abs(value)
    if abs(value - audit_value) <= tol:
        return True, ""
    shown = f"{est.value:.3g} +- {est.std:.2g}"
    return False, (f"ruled out by the inventory audit: {value:.3g} where the balances measure {shown} "
                   f"{_UNITS[hyp]}{' (factor)' if hyp == 'wall_heat_capacity_error' else ''}")


def decide(inv: Inventory, ranking, thresholds) -> Verdict:
    """The verdict from the combined audit and the dynamic ranking (module docstring).

    ``ranking``: the diagnosis's ``Candidate`` list, best first; a candidate may be named only if
    ``passes`` (every ``Thresholds`` rule, adequacy and audit consistency included).
    """
    from .forward import mechanism_params

    named = [c for c in ranking if c.passes]
    if inv.cause is not None:
        e = inv.estimate
        return Verdict("cause", inv.cause, e, inv.unit, (inv.cause,), "inventory audit", "; ".join(inv.sentences))
    if inv.unresolved is not None:
        cands = inv.candidates
        among = [c for c in named if c.mechanism in cands]
        notes = []
        if among:
            first = among[0]
            close = [c.mechanism for c in among[1:] if c.delta_bic - first.delta_bic < thresholds.alternative_bic]
            unrefit = [m for m in cands if m != first.mechanism and not any(c.mechanism == m and c.refit for c in ranking)]
            if not close and not unrefit:
                p = first.params
                name, value = next(iter(p.items()))
                e = Estimate(value, first.params_std[name])
                unit = mechanism_params(first.mechanism)[0].unit
                return Verdict("cause", first.mechanism, e, unit, (first.mechanism,),
                               "inventory audit, located by the dynamic search",
                               f"{_fmt(e, unit)} entering {_places((first.mechanism,))}: the balances measure "
                               f"{_fmt(inv.estimate, inv.unit)} of unmetered heat, and the dynamic model, which "
                               f"follows the data within the noise with it there, puts it there (dBIC "
                               f"{first.delta_bic:.0f}; the other places are worse by more than "
                               f"{thresholds.alternative_bic:g} or fail the thresholds)")
            notes.append(f"the dynamic search does not separate {first.mechanism} from "
                         f"{', '.join(close + unrefit)}")
        else:
            notes.append("the dynamic search names none of the candidates (see the candidates' reasons)")
        what = "unmetered heat" if inv.unresolved == "unmetered_heat" else "unmetered mass"
        if inv.unresolved == "unmetered_heat":
            heat = [c for c in cands if c in HEAT_CANDIDATES]
            others = [c for c in cands if c not in HEAT_CANDIDATES and c != "wall_heat_capacity_error"]
            leaving = inv.estimate is not None and inv.estimate.value < 0
            parts = (["entering " + _places(heat)] if heat else
                     ["leaving the tank (a metered heat load above the true one, or a loss the balances do not "
                      "attribute)"] if leaving else [])
            if others:  # rival single causes in their own units (a leak, a meter bias)
                parts.append("or " + " or ".join(others))
            if "wall_heat_capacity_error" in cands:  # the heat is measured at the stated capacity (audit.py, step 6)
                parts = ["at the stated wall heat capacity", *parts, "or a wall heat capacity other than the stated one"]
            where = ", ".join(parts)
        else:
            where = "carried by " + " or ".join(cands)
        return Verdict("unresolved", inv.unresolved, inv.estimate, inv.unit, cands, "inventory audit",
                       f"{what} {_fmt(inv.estimate, inv.unit)}, {where}"
                       + (": the data do not tell these apart" if cands else ""),
                       tuple(notes))
    if inv.inert_Pa is not None:
        gas = [c for c in named if c.mechanism in ("noncondensable_gas", "pressure_sensor_bias")]
        if gas:
            return _dynamic(gas[0])
        e = Estimate(inv.inert_Pa, float("nan"))
        return Verdict("unresolved", "inert_gas_or_sensor_bias", e, "Pa", ("noncondensable_gas", "pressure_sensor_bias"),
                       "inventory audit",
                       f"the ullage reads persistently colder than saturation: an inert gas with a partial pressure of "
                       f"at least {inv.inert_Pa:.4g} Pa, or a biased pressure sensor (the dynamic search names neither)")
    if named:
        return _dynamic(named[0])
    if not inv.audits:
        return NONE_UNAUDITED
    # "No cause" must not read as "no inert gas" where the balances cannot see one.
    unmeasured = tuple((f"{a.run}: " if len(inv.audits) > 1 else "") + a.inert_gas_unmeasured
                       for a in inv.audits if a.inert_gas_unmeasured)
    return dataclasses.replace(NONE, notes=unmeasured) if unmeasured else NONE


def _dynamic(c) -> Verdict:
    """A cause, or for a mechanism of the tank's build (``Mechanism.model_form``) the model's form."""
    from .forward import mechanism_params

    name, value = next(iter(c.params.items()))
    e = Estimate(value, c.params_std[name])
    unit = mechanism_params(c.mechanism)[0].unit
    evidence = (f"{name} = {_fmt(e, unit)}; with it the model predicts the held-out data within the noise "
                f"(held-out gain {c.heldout_gain:.2f}, dBIC {c.delta_bic:.0f})")
    mechanism = MECHANISMS[c.mechanism]
    if mechanism.model_form:
        return Verdict("model_form", c.mechanism, e, unit, (c.mechanism,), "dynamic search",
                       f"no cause: nothing unmetered beyond the noise and no fault; the tank has physics the "
                       f"baseline model lacks, {c.mechanism} ({mechanism.signature}): {evidence}")
    return Verdict("cause", c.mechanism, e, unit, (c.mechanism,), "dynamic search", evidence)


_PLACE = {"heat_leak_wall": "the wall", "heat_leak_liquid": "the liquid", "heat_leak_vapor": "the ullage"}


def _places(cands) -> str:
    names = [_PLACE.get(c, c) for c in cands]
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " or " + names[-1]


def _fmt(e: Estimate | None, unit: str) -> str:
    if e is None:
        return "(not measured)"
    std = f" +- {e.std:.2g}" if math.isfinite(e.std) else ""
    return f"{e.value:.3g}{std} {unit if unit != '1' else ''}".rstrip()  # "1": dimensionless


__all__ = ["Verdict", "Inventory", "inventory", "decide", "audit_consistency", "INVENTORY", "HEAT_CANDIDATES"]
