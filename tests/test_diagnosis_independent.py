"""The diagnosis on runs tankode did not generate: an independent simulator's tanks and operations.

``tests/independent_sim.py`` has its own formulation, numerics, heat-transfer correlations and
tank shapes (a sphere, a horizontal cylinder, ...), and writes runs in the interchange format
with asynchronous, irregular sampling and dropouts. The calibrated baseline cannot reproduce its
heat transfer, so the verdict must rest on the inventory audit where the hidden mechanism changes
the inventory, and otherwise name the right mechanism or nothing. Each run takes 20-60 s: all are
marked slow (``test_diagnosis_foreign.py`` runs another simulator's tanks in the default run).
"""

from __future__ import annotations

import pytest

import independent_sim as ind
from verdict_checks import assert_right_or_silent
from tankode import read_run
from tankode.diagnosis import diagnose

NONE = [(scenario, None) for scenario in ind.SCENARIOS]
HIDDEN = [(scenario, mechanism) for mechanism, scenario in ind.SCENARIO_FOR.items()]


def _case(scenario, mechanism):
    return pytest.param(scenario, mechanism, marks=pytest.mark.slow, id=f"{scenario}-{mechanism or 'none'}")


@pytest.mark.parametrize("scenario,mechanism", [_case(*c) for c in HIDDEN + NONE])
def test_diagnosis_on_independent_runs_names_the_right_mechanism_or_nothing(scenario, mechanism, tmp_path):
    value = ind.suggested_magnitude(mechanism, scenario) if mechanism else 0.0
    run = read_run(ind.simulate_run(scenario, mechanism, value, seed=0, out_dir=tmp_path))
    assert_right_or_silent(diagnose([run]), mechanism, value)
