"""The diagnosis on runs tankode did not generate: an independent simulator's tanks and operations.

``tests/independent_sim.py`` has its own formulation, numerics, heat-transfer correlations and
tank shapes (a sphere, a horizontal cylinder, ...), and writes runs in the interchange format
with asynchronous, irregular sampling and dropouts. The calibrated baseline cannot reproduce its
heat transfer exactly, so these runs test that the diagnosis names the hidden mechanism, or
none, without being tuned to tankode's own data. Each takes 1-4 minutes: all are marked slow.
"""

from __future__ import annotations

import pytest

import independent_sim as ind
from tankode import read_run
from tankode.diagnosis import diagnose

NONE = [(scenario, None) for scenario in ind.SCENARIOS]
HIDDEN = [(scenario, mechanism) for mechanism, scenario in ind.SCENARIO_FOR.items()]
# Measured failures (experiments/README.md, "Diagnosis on another simulator's runs"); strict, so
# a fix shows up as an unexpected pass.
KNOWN_FAILURES = {
    ("small_selfpress", None): "names noncondensable_gas (38 mol, stable on held-out data: 36 mol): the other "
                               "simulator's liquid superheats 0.7 K at rest, which tankode's model family can only "
                               "reproduce with a lower hydrogen partial pressure",
    ("small_selfpress", "heat_leak_vapor"): "names heat_leak_vapor but estimates 32.8 W for 50 W (the closure "
                                            "multipliers take part of it)",
    ("sphere_vent", "heat_leak_wall"): "names heat_leak_liquid (194 W) over heat_leak_wall: the other simulator's "
                                       "wall is tied to its liquid (h_wl ~ 200 W/m2K), their signatures differ by "
                                       "dBIC ~ 60",
    ("vcyl_press_hold_vent", "vapor_leak"): "names none: the calibrated baseline misses this run's warm-gas "
                                            "pressurisation by far more than the leak's signature; the leak "
                                            "explains 8 % of the held-out misfit",
    ("hcyl_drain_fill", "pressure_sensor_bias"): "names none: the baseline misses the drain, fill and sloshing of "
                                                 "this run by ~25 sigma in pressure; nothing explains > 8 % of it",
    ("hcyl_drain_fill", "noncondensable_gas"): "names none: as for the sensor bias, the baseline's misfit of "
                                               "this run swamps the 80 mol; nothing explains > 7 % of it",
    ("hcyl_drain_fill", "thermal_stratification"): "names none: the baseline's misfit of this run swamps the "
                                                   "0.2 K layer; nothing explains > 9 % of it",
    ("vcyl_press_hold_vent", "inflow_meter_bias"): "names none: the baseline misses this run's warm-gas "
                                                   "pressurisation itself, so a meter bias on it cannot be told apart",
    ("small_selfpress", "wall_heat_capacity_error"): "names none: estimate eps 0.50 for 1.3, held-out gain 0.02 "
                                                     "(the closure multipliers absorb the wall transient)",
}


def _param(scenario, mechanism):
    marks = [pytest.mark.slow]
    if (scenario, mechanism) in KNOWN_FAILURES:
        marks.append(pytest.mark.xfail(reason=KNOWN_FAILURES[(scenario, mechanism)], strict=True))
    return pytest.param(scenario, mechanism, marks=marks, id=f"{scenario}-{mechanism or 'none'}")


@pytest.mark.parametrize("scenario,mechanism", [_param(*c) for c in HIDDEN + NONE])
def test_diagnosis_on_independent_runs(scenario, mechanism, tmp_path):
    value = ind.suggested_magnitude(mechanism, scenario) if mechanism else 0.0
    run = read_run(ind.simulate_run(scenario, mechanism, value, seed=0, out_dir=tmp_path))
    d = diagnose([run])
    summary = [(c.mechanism, round(c.delta_bic, 1), round(c.heldout_gain, 3), round(c.explained, 2), c.reasons)
               for c in d.ranking[:3]]
    assert d.cause == mechanism, summary
    if mechanism:
        (estimate,) = d.extended["params"].values()
        assert estimate == pytest.approx(value, rel=0.25), summary
        assert d.ranking[0].heldout_gain > 0
