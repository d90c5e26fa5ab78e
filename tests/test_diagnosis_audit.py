"""Inventory audit and verdict: closed-form inventories, the decision rules, consistency, errors.

The audit reconstructs a tank's mass and energy from its sensors and sets them against the
metered inputs (``tankode.diagnosis.audit``); the verdict combines it with the dynamic search
(``tankode.diagnosis.verdict``). Runs of another simulator are in ``test_diagnosis_foreign.py``.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from tankode import get_case, simulate
from tankode.diagnosis.audit import (AuditConfig, Estimate, Hypothesis, _kind, _metered, _name, _phases, _smooth,
                                     audit_run)
from tankode.diagnosis.diagnose import Candidate, Thresholds
from tankode.diagnosis.verdict import Inventory, audit_consistency, decide
from tankode.mechanisms import make_mechanism
from tankode.schedule import Schedule
from tankode.synthetic import solution_to_runs


_SOLUTIONS: dict = {}


def _case(case: str, mechanisms=(), noise: str = "clean", seed: int = 0, noise_scale: float = 0.01):
    """A run of tankode's own model; clean readings weighed by ``noise_scale`` of the low noise level."""
    key = (case, tuple((m.id, tuple(sorted(m.values_dict().items()))) for m in mechanisms))
    run = get_case(case)
    if key not in _SOLUTIONS:
        _SOLUTIONS[key] = simulate(run, mechanisms=list(mechanisms))
    (data,) = solution_to_runs(run, _SOLUTIONS[key], noise=noise, seed=seed)
    if noise == "clean":
        data = dataclasses.replace(data, noise_std={k: v * noise_scale for k, v in data.noise_std.items()})
    return data


# -- the pieces, against closed forms -------------------------------------------------------------


def test_smoothing_of_a_line_is_least_squares_with_its_covariance():
    rng = np.random.default_rng(0)
    t = np.linspace(0.0, 600.0, 121)
    sigma = 2.0
    y = 5.0 + 0.01 * t + sigma * rng.standard_normal(len(t))
    knots = np.array([0.0, 600.0])  # two knots: no curvature to penalise, plain weighted least squares
    vals, cov = _smooth(t, y, sigma, knots, 1e-3)
    B = np.stack([1 - t / 600.0, t / 600.0], axis=1)
    expected_cov = np.linalg.inv(B.T @ B) * sigma**2
    np.testing.assert_allclose(cov, expected_cov, rtol=1e-8)
    np.testing.assert_allclose(vals, np.linalg.lstsq(B, y, rcond=None)[0], rtol=1e-8)
    assert _smooth(t[:2], y[:2], sigma, knots, 1e-3) is None  # under three samples: no fit


def test_a_short_vent_merged_into_the_next_phase_is_still_metered_exactly():
    """A 100 s vent joins the hold after it (phases under 240 s merge); its 1 kg and the heat load are
    integrated piece by piece, with the ullage enthalpy interpolated between the knots."""
    sched = Schedule.from_steps([(0.0, {"mdot_v_out_kg_s": 0.01, "Q_aw_W": 50.0}), (100.0, {"mdot_v_out_kg_s": 0.0})])
    run = dataclasses.replace(get_case("case3"), inputs=sched, duration_s=600.0)
    assert _phases(run, 240.0) == [(0.0, 600.0)]
    knots = np.array([0.0, 300.0, 600.0])
    h_v = np.array([4.0e5, 4.3e5, 4.6e5])  # J/kg, linear in time: 4e5 + 100 t
    met = _metered(None, sched, knots, np.full(3, 2e5), h_v, np.zeros(3))
    np.testing.assert_allclose(met["M"], [0.0, -1.0, -1.0])
    vent_energy = 0.01 * (4.0e5 * 100.0 + 100.0 * 100.0**2 / 2)  # integral of 0.01 h_v(t) over the vent
    np.testing.assert_allclose(met["E"], [0.0, -vent_energy + 50.0 * 300.0, -vent_energy + 50.0 * 600.0])
    np.testing.assert_allclose(met["Hv"][-1], 4.3e5 * 600.0)  # a leak's enthalpy: the integral of h_v


def test_a_short_hold_merged_into_a_drain_is_labelled_by_the_drain():
    """A phase is labelled by every operation in it, not by its first instant: 100 s of hold merged
    into the drain after it is a drain phase."""
    sched = Schedule.from_steps([(0.0, {"Q_aw_W": 50.0}), (100.0, {"mdot_l_out_kg_s": 0.3}),
                                 (400.0, {"mdot_l_out_kg_s": 0.3, "slosh_amplitude_m": 0.01,
                                          "slosh_frequency_Hz": 0.5})])
    assert _kind(sched, 0.0, 600.0) == "drain, sloshing"
    assert _kind(sched, 0.0, 100.0) == "hold"


def test_the_inert_gas_column_is_the_share_of_the_gas_vented():
    """Per mole in the ullage at the start, the moles a vent takes: with m_v and h_v constant,
    ``1 - exp(-mdot t / m_v)`` (the gas leaves in proportion to what is left), across pieces,
    knots and a share vented before the first knot; zero where nothing is vented."""
    sched = Schedule.from_steps([(0.0, {}), (100.0, {"mdot_v_out_kg_s": 0.01}), (700.0, {"mdot_v_out_kg_s": 0.0})])
    knots = np.array([0.0, 300.0, 600.0, 900.0])
    m_v, h_v = 3.0, 4.5e5
    met = _metered(None, sched, knots, np.full(4, 2e5), np.full(4, h_v), np.zeros(4), np.full(4, m_v))
    vented = 0.01 * np.clip(knots - 100.0, 0.0, 600.0) / m_v
    np.testing.assert_allclose(met["vent_M"], 1.0 - np.exp(-vented), rtol=1e-12)
    np.testing.assert_allclose(met["vent_E"], h_v * (1.0 - np.exp(-vented)), rtol=1e-12)
    assert met["vented"] == pytest.approx(vented[-1])
    later = _metered(None, sched, knots, np.full(4, 2e5), np.full(4, h_v), np.zeros(4), np.full(4, m_v), vented=0.5)
    np.testing.assert_allclose(later["vent_M"], np.exp(-0.5) * met["vent_M"], rtol=1e-12)


def test_tankode_own_heat_leak_and_wall_capacity_are_measured_in_closed_form():
    """Tankode's model conserves m_v u_v + m_l u_l + C_w T_w up to the metered flows, so its clean
    readings must give the hidden heat and the true wall capacity: 500 W into the wall with a wall
    1.5 times the stated one, and a 0.5 g/s vapour leak. Its runs are written with the reference's
    properties (the surrogate is fitted to them), so the closed form is checked without the
    property model's uncertainty the audit allows by default."""
    config = AuditConfig().trusting_properties()
    heat = audit_run(_case("case3", [make_mechanism("heat_leak_wall", Q_W=500.0),
                                     make_mechanism("wall_heat_capacity_error", eps=0.5)]), config)
    named = heat.finding("unmetered_heat")
    assert named is not None and named.estimate.value == pytest.approx(500.0, rel=0.02), heat.summary()
    assert named.candidates == ("heat_leak_wall", "heat_leak_liquid", "heat_leak_vapor")
    assert heat.wall_capacity_factor.value == pytest.approx(1.5, rel=0.02)
    leak = audit_run(_case("case3", [make_mechanism("vapor_leak", mdot_kg_s=5e-4)]), config)
    found = leak.finding("vapor_leak")
    assert found is not None and found.estimate.value == pytest.approx(5e-4, rel=0.02), leak.summary()
    # the leak carries the ullage's enthalpy: the free fit's heat is the leak times h_v (~ -0.49 MJ/kg)
    assert leak.heat_W.value / leak.mass_kg_s.value == pytest.approx(leak.phases[0].h_v_J_per_kg, rel=0.1)


def test_tankode_own_run_with_nothing_hidden_names_nothing_at_its_sensor_noise():
    a = audit_run(_case("case3", noise="low", seed=12))
    assert a.findings == (), a.summary()
    assert abs(a.heat_W.z) < 3 and abs(a.mass_kg_s.z) < 3
    assert np.isfinite(a.series["mass_kg"]).all() and len(a.series["t_s"]) == len(a.series["energy_metered_J"])


def test_an_ullage_reading_persistently_colder_than_saturation_bounds_an_inert_gas():
    """T_v read 6 K low everywhere (case 3's ullage is at most 5 K above saturation): a pure vapour
    cannot be that cold, so an inert gas (or a biased sensor) must carry at least p - p_sat(T_v);
    the same cold spell for five minutes is only a transient."""
    import CoolProp.CoolProp as CP

    data = _case("case3", noise_scale=1.0)
    obs = data.observations
    values = obs.values.copy()
    values[:, 1] -= 6.0  # the T_v_K column
    cold = dataclasses.replace(data, observations=dataclasses.replace(obs, values=values))
    a = audit_run(cold)
    finding = a.finding("inert_gas_or_sensor_bias")
    assert finding is not None and set(finding.candidates) == {"noncondensable_gas", "pressure_sensor_bias"}
    t_p, p = cold.observations.channel("p_v_Pa")
    t_v, T_v = cold.observations.channel("T_v_K")
    bound = np.median(np.interp(t_v, t_p, p) - np.array([CP.PropsSI("P", "T", T, "Q", 0, "ParaHydrogen") for T in T_v]))
    assert finding.estimate.value == pytest.approx(bound, rel=0.1)
    assert a.inert_partial_pressure_Pa == finding.estimate.value
    # the same 6 K for five minutes only
    values = obs.values.copy()
    spell = (obs.t_s > 1200.0) & (obs.t_s < 1500.0)
    values[spell, 1] -= 6.0
    brief = audit_run(dataclasses.replace(data, observations=dataclasses.replace(obs, values=values)))
    assert brief.finding("inert_gas_or_sensor_bias") is None
    assert any("a transient, not persistent enough" in s for s in brief.consistency), brief.consistency


def test_the_audit_refuses_a_run_without_the_channels_it_needs_in_one_line():
    data = _case("case3", noise_scale=1.0)
    obs = data.observations
    values = obs.values.copy()
    values[:, 2] = np.nan  # no liquid temperature
    run = dataclasses.replace(data, observations=dataclasses.replace(obs, values=values))
    with pytest.raises(ValueError, match=r"^run 'case3': the inventory audit needs p_v_Pa, T_v_K and T_l_K measured; "
                                         r"\['T_l_K'\] are not$"):
        audit_run(run)
    with pytest.raises(ValueError, match="AuditConfig.consistency_share must be in"):
        AuditConfig(consistency_share=1.5)
    with pytest.raises(ValueError, match="AuditConfig.knot_s must be finite and > 0"):
        AuditConfig(knot_s=0.0)


# -- the decision rules ---------------------------------------------------------------------------


def _hyps(**chi2_estimate_z):
    return {k: Hypothesis(k, c, Estimate(v, s), v / s) for k, (c, v, s) in chi2_estimate_z.items()}


def test_a_single_cause_is_named_only_when_significant_explaining_and_unrivalled():
    config = AuditConfig()
    heat, mass = Estimate(10.0, 20.0), Estimate(-5e-4, 2e-5)
    # a vapour leak at 25 sigma, the others worse by far: named
    h = _hyps(heat=(900.0, -250.0, 8.0), vapor_leak=(20.0, 5e-4, 1e-5), liquid_leak=(300.0, 7e-4, 2e-5))
    found, chosen = _name(mass, heat, h, 19.0, None, [], config, True)
    assert [f.name for f in found] == ["vapor_leak"] and chosen == "vapor_leak"
    # the liquid leak within 9 of it, its own rate resolved: not told apart, both listed
    h = _hyps(heat=(900.0, -250.0, 8.0), vapor_leak=(20.0, 5e-4, 1e-5), liquid_leak=(25.0, 7e-4, 2e-5))
    found, chosen = _name(mass, heat, h, 19.0, None, [], config, True)
    assert [(f.name, f.candidates) for f in found] == [("unmetered_mass", ("vapor_leak", "liquid_leak"))]
    assert chosen == ""
    # a rival whose rate is ~0 there only says a nuisance could absorb it: not a rival
    h = _hyps(heat=(900.0, -250.0, 8.0), vapor_leak=(20.0, 5e-4, 1e-5), liquid_leak=(25.0, 1e-5, 2e-5))
    assert [f.name for f in _name(mass, heat, h, 19.0, None, [], config, True)[0]] == ["vapor_leak"]
    # a resolved rate that does not explain both balances (chi2 far above the free fit): not named as one cause
    h = _hyps(heat=(900.0, -250.0, 8.0), vapor_leak=(60.0, 5e-4, 1e-5), liquid_leak=(300.0, 7e-4, 2e-5))
    found, _ = _name(mass, heat, h, 19.0, None, [], config, True)
    assert found[0].name == "unmetered_mass" and set(found[0].candidates) >= {"vapor_leak", "liquid_leak"}
    # a rate resolved only where it does not explain, the free mass and heat unresolved: model or
    # sensor error, nothing (another simulator's liquid thermometer 0.5 K high along a drain)
    h = _hyps(heat=(40.6, 25.4, 3.0), wall_heat_capacity_error=(110.3, 0.33, 0.071))
    assert _name(Estimate(4e-5, 1.2e-5), Estimate(8.8, 5.9), h, 29.0, None, [], config, True)[0] == []
    # below 5 sigma: nothing
    h = _hyps(heat=(20.0, 40.0, 10.0), vapor_leak=(20.5, 2e-5, 1e-5))
    assert _name(Estimate(-2e-5, 1e-5), Estimate(40.0, 10.0), h, 19.0, None, [], config, True)[0] == []


def test_a_wall_capacity_that_a_steady_heat_at_the_stated_capacity_matches_is_not_named_alone():
    """The wall's correction (freed) at 8 standard errors is best, and the heat's own fit reads ~0
    because the wall's prior absorbs it; with the stated capacity held, 290 +- 20 W explains the
    balances within ``chi2_separation``: both are listed, with the heat at the stated capacity.
    Where the stated-capacity heat explains worse by more, the wall alone is named."""
    config = AuditConfig()
    wall = Hypothesis("wall_heat_capacity_error", 33.6, Estimate(0.66, 0.042), -8.0)
    h = _hyps(heat=(34.5, 82.0, 85.0), heat_at_stated_wall=(36.0, 290.0, 20.0))
    h["wall_heat_capacity_error"] = wall
    (found,), chosen = _name(None, Estimate(84.0, 88.0), h, 33.0, None, [], config, False)
    assert found.name == "unmetered_heat" and found.estimate == Estimate(290.0, 20.0) and chosen == ""
    assert found.candidates == ("heat_leak_wall", "heat_leak_liquid", "heat_leak_vapor", "wall_heat_capacity_error")
    h["heat_at_stated_wall"] = Hypothesis("heat_at_stated_wall", 60.0, Estimate(290.0, 20.0), 14.5)
    (found,), chosen = _name(None, Estimate(84.0, 88.0), h, 33.0, None, [], config, False)
    assert found.name == "wall_heat_capacity_error" and chosen == "wall_heat_capacity_error"


def test_leaks_told_apart_from_heat_leaving_by_neither_balance_are_stated_in_the_leaks_unit():
    """Heat leaving the tank is best (8 standard errors) and a vapour and a liquid leak explain the
    balances within ``chi2_separation`` with the mass unresolved: a mass loss at the best leak's
    rate, its fit recorded for the strict check."""
    config = AuditConfig()
    h = _hyps(heat=(26.4, -518.0, 64.0), vapor_leak=(27.5, 5.4e-4, 6.7e-5), liquid_leak=(32.1, 9.7e-4, 1.2e-4))
    (found,), chosen = _name(Estimate(-1e-4, 3.8e-4), Estimate(-472.0, 185.0), h, 26.0, None, [], config, True)
    assert (found.name, found.unit, found.candidates, found.fit) == ("unmetered_mass", "kg/s",
                                                                     ("vapor_leak", "liquid_leak"), "vapor_leak")
    assert found.estimate == Estimate(-5.4e-4, 6.7e-5) and chosen == ""


def test_unmetered_heat_is_named_with_the_places_it_may_enter_and_heat_leaving_with_none():
    config = AuditConfig()
    h = _hyps(heat=(20.0, 400.0, 15.0), vapor_leak=(500.0, -8e-4, 3e-5), liquid_leak=(700.0, -1e-3, 5e-5))
    (found,), _ = _name(Estimate(1e-5, 2e-5), Estimate(400.0, 20.0), h, 19.0, None, [], config, True)
    assert found.name == "unmetered_heat" and found.candidates == ("heat_leak_wall", "heat_leak_liquid", "heat_leak_vapor")
    assert "cannot tell apart" in found.sentence
    h = _hyps(heat=(20.0, -300.0, 15.0))
    (found,), _ = _name(None, Estimate(-300.0, 20.0), h, 20.0, None, [], config, False)
    assert found.candidates == () and "leaving the tank" in found.sentence and "no level sensor" in found.sentence


def _cand(mechanism, passes=True, delta_bic=-100.0, value=1.0, refit=True):
    return Candidate(mechanism, score=1.0, score_rank=1, refit=refit, passes=passes, delta_bic=delta_bic,
                     params={"x": value}, params_std={"x": 0.1 * abs(value)}, heldout_gain=0.5, adequate=passes)


def test_the_verdict_locates_unmetered_heat_only_where_the_dynamic_search_separates_the_places():
    inv = Inventory((), unresolved="unmetered_heat", estimate=Estimate(400.0, 20.0), unit="W",
                    candidates=("heat_leak_wall", "heat_leak_liquid", "heat_leak_vapor"))
    th = Thresholds()
    ranking = [_cand("heat_leak_liquid", value=390.0), _cand("heat_leak_wall", passes=False, delta_bic=-40.0),
               _cand("heat_leak_vapor", passes=False, delta_bic=-20.0)]
    v = decide(inv, ranking, th)
    assert (v.kind, v.name, v.source) == ("cause", "heat_leak_liquid", "inventory audit, located by the dynamic search")
    # the wall also passes within 10 of it in dBIC: not separated, all three listed
    ranking[1] = _cand("heat_leak_wall", delta_bic=-95.0)
    v = decide(inv, ranking, th)
    assert (v.kind, v.name, v.candidates) == ("unresolved", "unmetered_heat", inv.candidates)
    assert "400 +- 20 W, entering the wall, the liquid or the ullage" in v.sentence
    # one place never refitted: not separated either
    ranking = [_cand("heat_leak_liquid", value=390.0), _cand("heat_leak_wall", passes=False, refit=False)]
    assert decide(inv, ranking, th).kind == "unresolved"
    # a passing candidate of another kind does not replace what the audit measured
    assert decide(inv, [_cand("pressure_sensor_bias")], th).name == "unmetered_heat"


def test_the_verdict_words_heat_leaving_the_tank_and_a_wall_capacity_among_the_candidates():
    """Heat leaving the tank has no place to enter (no candidates); a wall heat capacity among the
    candidates is no place either, and the heat is the one at the stated capacity."""
    th = Thresholds()
    v = decide(Inventory((), unresolved="unmetered_heat", estimate=Estimate(-300.0, 20.0), unit="W"), [], th)
    assert v.kind == "unresolved" and v.candidates == () and "leaving the tank" in v.sentence
    cands = ("heat_leak_wall", "heat_leak_liquid", "heat_leak_vapor", "wall_heat_capacity_error")
    v = decide(Inventory((), unresolved="unmetered_heat", estimate=Estimate(270.0, 36.0), unit="W", candidates=cands),
               [], th)
    assert v.candidates == cands and v.sentence.startswith(
        "unmetered heat 270 +- 36 W, at the stated wall heat capacity, entering the wall, the liquid or the ullage, "
        "or a wall heat capacity other than the stated one"), v.sentence


def test_the_verdict_takes_the_audits_cause_and_names_dynamic_ones_only_when_nothing_is_unmetered():
    th = Thresholds()
    inv = Inventory((), cause="vapor_leak", estimate=Estimate(5e-4, 2e-5), unit="kg/s")
    v = decide(inv, [_cand("pressure_sensor_bias")], th)
    assert (v.kind, v.name, v.source) == ("cause", "vapor_leak", "inventory audit")
    v = decide(Inventory(()), [_cand("pressure_sensor_bias", value=8e3)], th)
    assert (v.kind, v.name, v.source) == ("cause", "pressure_sensor_bias", "dynamic search")
    none = decide(Inventory(()), [_cand("pressure_sensor_bias", passes=False)], th)
    assert none.kind == "none" and "the inventory was not audited" in none.sentence  # no run had the sensors
    # a cold ullage: the inert gas or the pressure bias if the dynamic search names one, else both listed
    cold = Inventory((), inert_Pa=2.0e4)
    assert decide(cold, [_cand("thermal_stratification")], th).name == "inert_gas_or_sensor_bias"
    assert decide(cold, [_cand("thermal_stratification"), _cand("noncondensable_gas")], th).name == "noncondensable_gas"


def test_the_tanks_own_physics_is_named_as_the_models_form_never_as_a_cause():
    from tankode.mechanisms import MECHANISMS

    th = Thresholds()
    form = {m for m, cls in MECHANISMS.items() if cls.model_form}
    assert {"dry_wall_heating", "dry_wall_node", "thermal_stratification", "surface_layer"} <= form
    assert not form & {"heat_leak_vapor", "vapor_leak", "pressure_sensor_bias", "noncondensable_gas",
                       "temperature_sensor_bias", "wall_heat_capacity_error", "inflow_meter_bias"}
    for m in ("dry_wall_heating", "dry_wall_node", "thermal_stratification"):
        v = decide(Inventory(()), [_cand(m, value=0.5)], th)
        assert (v.kind, v.name, v.candidates) == ("model_form", m, (m,)), v
        assert v.sentence.startswith("no cause:") and v.estimate.value == 0.5
    # a fault outranked by the model's form is not named, and what the audit measures still decides
    assert decide(Inventory(()), [_cand("dry_wall_heating"), _cand("pressure_sensor_bias")], th).kind == "model_form"
    inv = Inventory((), cause="vapor_leak", estimate=Estimate(5e-4, 2e-5), unit="kg/s")
    assert decide(inv, [_cand("dry_wall_heating")], th).name == "vapor_leak"


def test_a_dynamic_estimate_outside_the_audits_interval_is_ruled_out():
    from tankode.diagnosis.audit import RunAudit

    def audit(hyps):
        return RunAudit("r", (), None, Estimate(0.0, 16.0), None, Estimate(0.0, 1.0), hyps, 1.0, 0.0, (), None, 0.0, "", (), (), {})

    inv = Inventory((audit(_hyps(heat=(20.0, 2.0, 16.0))),))
    ok, why = audit_consistency("heat_leak_wall", 150.0, inv)
    assert not ok and why == "ruled out by the inventory audit: 150 where the balances measure 2 +- 16 W"
    # within 3 sigma plus 25 % of the estimate
    assert audit_consistency("heat_leak_wall", 2.0 + 3 * 16.0 + 0.2 * 60.0, inv)[0]
    # two runs: the inverse-variance mean of their estimates
    two = Inventory((audit(_hyps(heat=(20.0, 100.0, 10.0))), audit(_hyps(heat=(20.0, 200.0, 10.0)))))
    assert two.rate("heat").value == pytest.approx(150.0) and two.rate("heat").std == pytest.approx(10 / math.sqrt(2))
    # mechanisms the audit does not measure are not constrained by it
    assert audit_consistency("pressure_sensor_bias", 1e4, inv) == (True, "")
