"""Fast checks of the height-resolved-wall tank simulator (tests/field_sim.py).

Its balances close with every operation it writes, and its multi-rate files (empty cells where
a channel is not sampled, inputs on the rows where they change) read as the format says.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import field_sim
from tankode import read_run


@pytest.mark.parametrize("scenario", ["null_relief_short", "inv_fillbias_ell", "oth_helium_relief_vcyl"])
def test_mass_energy_and_pressure_close_and_the_run_reads_back(tmp_path, scenario):
    truth = field_sim.write_run(field_sim.SCENARIOS[scenario], str(tmp_path))
    c = truth["closure"]
    assert c["mass_rel_max"] < 1e-10 and c["energy_rel_max"] < 1e-10 and c["pressure_mismatch_Pa_max"] < 1e-3, c
    run = read_run(tmp_path / f"{scenario}.json")
    meta = json.loads((tmp_path / f"{scenario}.json").read_text())
    assert set(run.observations.measured_channels) == {f"{k}_{u}" for k, u in (
        ("p_v", "Pa"), ("T_v", "K"), ("T_l", "K"), ("T_w", "K"), ("H_l", "m")) if k in meta["noise_std"]}
    # channels sampled at their own rates: the pressure more often than the level
    t_p, _ = run.observations.channel("p_v_Pa")
    if "H_l" in meta["noise_std"]:
        t_h, _ = run.observations.channel("H_l_m")
        assert len(t_p) > 3 * len(t_h)
    assert np.all(np.diff(t_p) > 0)
    if scenario == "null_relief_short":  # the relief valve: every opening and closing a row
        assert truth["n_vent_toggles"] >= 20
        vent = run.inputs.change_times()
        assert len(vent) >= truth["n_vent_toggles"]


def test_scenarios_have_one_hidden_mechanism_at_most():
    for name, sc in field_sim.SCENARIOS.items():
        assert len(sc.get("hidden", {})) <= 1, name
