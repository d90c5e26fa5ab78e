"""Tests of the stratified (layered) tank simulator ``tests/layer_sim.py``."""

from __future__ import annotations

import copy
import json
import math

import numpy as np
import pytest

import layer_sim as L


def _scenario(name: str = "lh2_upright", phases=None, Q_aw=None, **initial):
    sc = copy.deepcopy(L.named_scenario(name))
    if phases is not None:
        sc["phases"] = [dict(p) for p in phases]
        sc["duration_s"] = float(sum(p["duration_s"] for p in phases))
    if Q_aw is not None:
        sc["Q_aw_W"] = float(Q_aw)
    sc["initial"].update(initial)
    return sc


OPS = [{"kind": "rest", "duration_s": 60.0},
       {"kind": "pressurize", "duration_s": 120.0, "dp_frac": 0.2, "T_in_factor": 2.0},
       {"kind": "vent", "duration_s": 120.0, "p_frac": 0.85},
       {"kind": "fill", "duration_s": 120.0, "dfill": 0.05, "subcool_K": 1.0},
       {"kind": "drain", "duration_s": 120.0, "dfill": 0.05},
       {"kind": "slosh", "duration_s": 120.0, "amp_m": 0.01, "freq_ratio": 1.0}]


@pytest.mark.parametrize("mech", [{}, {"helium_mol": 30.0, "vapor_leak_kg_s": 1e-4, "liquid_leak_kg_s": 0.01,
                                       "heat_leak_liquid_W": 20.0, "heat_leak_vapor_W": 5.0,
                                       "heat_leak_wall_W": 10.0, "inflow_meter_bias": 0.1}])
def test_mass_and_energy_close(mech):
    res = L.simulate(_scenario(phases=OPS), mech)
    kinds = {s["kind"] for s in res["executed"]}
    assert {"pressurize", "vent", "fill", "drain", "slosh"} <= kinds
    c = res["closure"]
    assert c["mass_rel"] < 1e-8
    assert c["energy_rel"] < 1e-8
    assert c["helium_mol_max_abs"] < 1e-8 * max(mech.get("helium_mol", 0.0), 1.0)
    if mech:
        o0, o1 = res["obs"][0], res["obs"][-1]
        assert 0 < o1["n_he"] < o0["n_he"]  # helium left with the vented gas


def test_closed_tank_at_rest_stays_put():
    fl = L.get_fluid("ParaHydrogen")
    p0 = 1.6 * L.ATM
    T_sat = float(fl.T_sat(p0))
    sc = _scenario(phases=[{"kind": "rest", "duration_s": 1200.0}], Q_aw=0.0, p_Pa=p0, T_l_K=T_sat, T_v_K=T_sat,
                   dry_extra_K=0.0, wet_extra_K=0.0)
    res = L.simulate(sc)
    p = np.array([o["p"] for o in res["obs"]])
    assert np.max(np.abs(p - p[0])) < 50.0  # far below the low noise (300 Pa)
    T_l = np.array([o["T_l"] for o in res["obs"]])
    assert np.max(np.abs(T_l - T_l[0])) < 1e-3
    assert res["closure"]["energy_rel"] < 1e-8


def _spread(res):
    T = res["obs"][-1]["T_l_layers"]
    return T[-1] - T[0]


def test_stratification_and_slosh_mixing():
    base = dict(Q_aw=600.0, T_l_K=21.0)
    calm = L.simulate(_scenario(phases=[{"kind": "rest", "duration_s": 1800.0}], **base))
    slosh = L.simulate(_scenario(phases=[{"kind": "slosh", "duration_s": 1800.0, "amp_m": 0.02, "freq_ratio": 1.0}],
                                 **base))
    T = calm["obs"][-1]["T_l_layers"]
    assert T[-1] > T[0] + 0.1  # heated from the wall: warm liquid on top
    assert all(b >= a - 1e-3 for a, b in zip(T[:-1], T[1:]))  # stable stratification
    assert _spread(slosh) < 0.5 * _spread(calm)


def test_helium_partial_pressure():
    n_he = 40.0
    res = L.simulate(_scenario(phases=[{"kind": "rest", "duration_s": 300.0}]), {"helium_mol": n_he})
    fl = res["model"].fl
    o = res["obs"][-1]
    p_he_est = n_he * L.RU * o["T_v"] / (res["model"].geo.V * (1 - o["fill"]))
    excess = o["p"] - fl.p_sat(o["T_i"])
    assert p_he_est > 1000.0
    assert excess == pytest.approx(p_he_est, rel=0.15)
    # same fluid state as without helium: the total pressure is higher by about the helium partial pressure
    ref = L.simulate(_scenario(phases=[{"kind": "rest", "duration_s": 300.0}]))
    assert res["obs"][0]["p"] - ref["obs"][0]["p"] == pytest.approx(p_he_est, rel=0.15)


def test_written_run_is_read_by_tankode(tmp_path):
    import tankode

    paths = L.simulate_run(_scenario(phases=OPS), {"pressure_sensor_bias_Pa": 500.0}, noise="high", seed=3,
                           out_dir=tmp_path, name="lay")
    run = tankode.read_run(paths["json"])
    assert run is not None
    meta = json.loads(paths["json"].read_text())
    assert meta["tank"]["shape"] == "vertical_cylinder_elliptical_heads"
    truth = json.loads(paths["truth"].read_text())
    assert set(truth["mechanisms"]) == set(L.MECHANISMS)
    assert truth["closure"]["mass_rel"] < 1e-8 and truth["closure"]["energy_rel"] < 1e-8
    header = paths["csv"].read_text().splitlines()[0].split(",")
    assert header[:6] == ["t_s", *L.OBS_COLUMNS]
    assert set(header[6:]) <= set(L.INPUT_COLUMNS)
    paths = L.simulate_run("lh2_hcyl", noise="none", out_dir=tmp_path, name="hcyl", duration_s=300.0,
                           wall_capacity_unknown=True)
    tankode.read_run(paths["json"])
    assert json.loads(paths["json"].read_text())["tank"]["wall_heat_capacity_J_per_K"] is None


def test_point_sensors_read_one_layer_each(tmp_path):
    """``sensors="point"``: the written temperatures are the middle ullage layer's, the second liquid
    layer's and the mid-height wall band's (the truth's layers), not their averages."""
    import csv

    paths = L.simulate_run("lh2_upright", noise="none", out_dir=tmp_path, name="pt", duration_s=600.0, sensors="point")
    truth = json.loads(paths["truth"].read_text())
    assert truth["sensors"] == "point"
    last = truth["final_true"]
    row = list(csv.DictReader(paths["csv"].open()))[-1]
    assert float(row["T_v_K"]) == pytest.approx(last["T_ullage_layers_K"][L.N_VAP // 2], abs=1e-9)
    assert float(row["T_l_K"]) == pytest.approx(last["T_liquid_layers_K"][1], abs=1e-9)
    assert float(row["T_w_K"]) == pytest.approx(last["T_wall_nodes_K"][L.N_WALL // 2], abs=1e-9)
    assert float(row["T_v_K"]) != pytest.approx(last["T_v_K"], abs=1e-6)  # stratified: the probe is not the mean
    with pytest.raises(ValueError, match="sensors"):
        L.simulate_run("lh2_upright", out_dir=tmp_path, sensors="rake")


@pytest.mark.parametrize("shape", L.SHAPES)
def test_shapes_level_volume(shape):
    tank = L._tank_of_volume(shape, 10.0, 1.3)
    g = L.Shape(tank)
    assert g.V == pytest.approx(10.0, rel=2e-3)
    assert g.level(0.0) == pytest.approx(0.0, abs=1e-9)
    assert g.level(g.V) == pytest.approx(g.H)
    assert g.wall_below(g.H + 1) == pytest.approx(g.A_wall)
    if shape == "sphere":
        assert g.A_wall == pytest.approx(4 * math.pi * g.R ** 2, rel=1e-4)
        assert g.level(g.V / 2) == pytest.approx(g.R, rel=1e-6)


def test_cli(tmp_path, capsys):
    assert L.main(["ln2_sphere", "--duration", "120", "--out", str(tmp_path), "--mechanism",
                   "helium_mol=5"]) == 0
    assert (tmp_path / "layer_ln2_sphere.truth.json").exists()
    assert L.main(["no_such_scenario", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("layer_sim: error:")
    with pytest.raises(SystemExit):
        L.main(["ln2_sphere", "--mechanism", "nonsense=1"])
    assert L.main(["random_x"]) == 2
    assert L.main(["--list"]) == 0
