"""Fast checks of the kinetic-interface tank simulator (tests/kinetic_sim.py).

Closure with every operation and every hidden mechanism, the written files, the effect of each
mechanism, determinism. Uses only numpy and the standard library besides the simulator.
"""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

import kinetic_sim as ks

OBS = ("p_v_Pa", "T_v_K", "T_l_K", "T_w_K", "H_l_m")
ALL_MECH = {"heat_leak_liquid_W": 5.0, "heat_leak_vapor_W": 2.0, "heat_leak_wall_W": 3.0, "vapor_leak_kg_s": 1e-5,
            "liquid_leak_kg_s": 1e-3, "inflow_meter_bias": 0.05, "pressure_sensor_bias_Pa": 400.0,
            "temperature_sensor_bias_K": 0.2, "helium_mol": 2.0, "wall_heat_capacity_error": 0.3}


def _all_ops(spray: bool, fluid: str = "ParaHydrogen") -> dict:
    sc = ks._named("lh2_light_wall") if fluid == "ParaHydrogen" else ks._named("ln2_hcyl")
    sc["spray"] = spray
    if fluid == "ParaHydrogen":
        ph = [ks._phase("pressurize", 60, mdot_v_in_kg_s=7e-4, T_v_in_K=90.0, p_v_in_Pa=4e5),
              ks._phase("vent", 60, mdot_v_out_kg_s=5e-4),
              ks._phase("fill", 60, mdot_l_in_kg_s=0.05, T_l_in_K=20.0),
              ks._phase("drain", 60, mdot_l_out_kg_s=0.08),
              ks._phase("slosh", 60, slosh_amplitude_m=0.02, slosh_frequency_Hz=1.0)]
    else:
        ph = [ks._phase("pressurize", 60, mdot_v_in_kg_s=5e-3, T_v_in_K=200.0, p_v_in_Pa=4e5),
              ks._phase("vent", 60, mdot_v_out_kg_s=4e-3),
              ks._phase("fill", 60, mdot_l_in_kg_s=1.0, T_l_in_K=77.0),
              ks._phase("drain", 60, mdot_l_out_kg_s=1.0),
              ks._phase("slosh", 60, slosh_amplitude_m=0.02, slosh_frequency_Hz=0.7)]
    sc["phases"] = ph
    return sc


@pytest.mark.parametrize("spray,fluid", [(True, "ParaHydrogen"), (False, "ParaHydrogen"), (True, "Nitrogen")])
def test_closure_every_operation_and_mechanism(spray, fluid):
    res = ks.simulate(_all_ops(spray, fluid), ALL_MECH)
    c = res["closure"]
    assert c["mass_rel"] < 1e-8 and c["energy_rel"] < 1e-8, c
    kinds = {s["kind"] for s in res["executed"]}
    assert {"pressurize", "vent", "fill", "drain", "slosh"} <= kinds
    assert res["wall_time_s"] < 10.0


def _read(paths):
    meta = json.loads(paths["json"].read_text())
    with open(paths["csv"], newline="") as fh:
        rows = list(csv.reader(fh))
    return meta, rows[0], rows[1:], json.loads(paths["truth"].read_text())


def test_files_parse(tmp_path):
    paths = ks.simulate_run("lh2_sphere_spray", {"helium_mol": 1.0}, noise="low", out_dir=tmp_path,
                            duration_s=900.0, wall_capacity_unknown=True)
    meta, header, body, truth = _read(paths)
    assert set(meta) == {"name", "fluid", "source", "tank", "initial", "noise_std", "duration_s", "timeseries"}
    assert meta["timeseries"] == paths["csv"].name and meta["fluid"] == "ParaHydrogen"
    assert meta["tank"]["wall_heat_capacity_J_per_K"] is None
    assert abs(meta["tank"]["volume_m3"] - 5.0) < 0.05
    assert set(meta["noise_std"]) == {"p_v", "T_v", "T_l", "T_w", "H_l"}
    assert header[0] == "t_s" and tuple(header[1:6]) == OBS
    allowed = set(OBS) | set(ks.INPUT_COLUMNS)
    assert set(header[1:]) <= allowed
    t = np.array([float(r[0]) for r in body])
    assert np.all(np.diff(t) > 0) and t[0] == 0.0 and abs(t[-1] - 900.0) < 1e-9
    for r in body:
        assert len(r) == len(header)
        for v in r[1:]:
            if v:
                float(v)
    tw = [float(r[0]) for r in body if r[4]]
    assert all(abs(x / 30 - round(x / 30)) < 1e-9 for x in tw)
    assert len([r for r in body if r[1]]) == 91
    assert truth["simulator"] == "tests/kinetic_sim.py"
    assert set(truth["mechanisms"]) == set(ks.MECHANISMS) and truth["mechanisms"]["helium_mol"] == 1.0
    assert truth["closure"]["mass_rel"] < 1e-8 and truth["closure"]["energy_rel"] < 1e-8
    assert truth["scenario"]["spray"] is True and truth["scenario"]["phases"]
    with open(paths["truth_csv"], newline="") as fh:
        trows = list(csv.reader(fh))
    assert trows[0][:6] == ["t_s", *OBS] and len(trows) == 92


def test_null_run_deterministic(tmp_path):
    a = ks.simulate_run("lh2_light_wall", None, noise="none", out_dir=tmp_path / "a", duration_s=300.0)
    b = ks.simulate_run("lh2_light_wall", None, noise="none", out_dir=tmp_path / "b", duration_s=300.0)
    assert a["csv"].read_text() == b["csv"].read_text()
    assert a["json"].read_text() == b["json"].read_text()


def _short(mech, duration=300.0):
    sc = ks._named("lh2_light_wall")
    sc["phases"] = [ks._phase("rest", 100), ks._phase("pressurize", 60, mdot_v_in_kg_s=7e-4, T_v_in_K=90.0,
                                                      p_v_in_Pa=4e5),
                    ks._phase("fill", 60, mdot_l_in_kg_s=0.02, T_l_in_K=20.0)]
    return ks.simulate(sc, mech, duration_s=duration)


@pytest.fixture(scope="module")
def base():
    return _short({})


def test_sensor_biases_shift_only_their_channel(base, tmp_path):
    ref = ks.simulate_run("lh2_light_wall", None, noise="none", out_dir=tmp_path / "r", duration_s=300.0)
    bia = ks.simulate_run("lh2_light_wall", {"pressure_sensor_bias_Pa": 700.0, "temperature_sensor_bias_K": 0.3},
                          noise="none", out_dir=tmp_path / "b", duration_s=300.0)
    _, h, r0, _ = _read(ref)
    _, _, r1, _ = _read(bia)
    for a, b in zip(r0, r1):
        for j, col in enumerate(h):
            if not a[j]:
                assert not b[j]
                continue
            d = float(b[j]) - float(a[j])
            want = 700.0 if col == "p_v_Pa" else 0.3 if col == "T_l_K" else 0.0
            assert abs(d - want) < 1e-9 * max(1.0, abs(float(a[j]))), (col, d)


def test_vapor_leak_removes_its_integral(base):
    r = _short({"vapor_leak_kg_s": 2e-5})
    m0 = base["obs"][-1]["m_l"] + base["obs"][-1]["m_v"]
    m1 = r["obs"][-1]["m_l"] + r["obs"][-1]["m_v"]
    assert abs((m0 - m1) - 2e-5 * 300.0) < 1e-6 * m0


def test_liquid_leak_and_meter_bias(base):
    r = _short({"liquid_leak_kg_s": 1e-3})
    m0 = base["obs"][-1]["m_l"] + base["obs"][-1]["m_v"]
    m1 = r["obs"][-1]["m_l"] + r["obs"][-1]["m_v"]
    assert abs((m0 - m1) - 0.3) < 1e-6 * m0
    r = _short({"inflow_meter_bias": 0.1})
    m1 = r["obs"][-1]["m_l"] + r["obs"][-1]["m_v"]
    assert abs((m1 - m0) - 0.1 * (7e-4 * 60 + 0.02 * 60)) < 1e-6 * m0


def test_heat_leaks_and_helium_and_wall(base):
    o0 = base["obs"][-1]
    ol = _short({"heat_leak_liquid_W": 50.0})["obs"][-1]
    assert ol["T_l"] > o0["T_l"] + 1e-3
    ov = _short({"heat_leak_vapor_W": 20.0})["obs"][-1]
    assert ov["T_v"] > o0["T_v"] + 1e-2 and ov["p"] > o0["p"]
    ow = _short({"heat_leak_wall_W": 50.0})["obs"][-1]
    assert ow["T_w"] > o0["T_w"] + 1e-2
    rh = _short({"helium_mol": 3.0})
    assert abs(rh["obs"][0]["p"] - base["obs"][0]["p"]) < 1.0          # same initial total pressure
    assert rh["obs"][0]["p_he"] > 1e3 and abs(rh["obs"][-1]["n_he"] - 3.0) < 1e-9
    rc = _short({"wall_heat_capacity_error": 1.0})
    assert rc["model"].C_w == pytest.approx(2 * base["model"].C_w)
    assert abs(rc["obs"][-1]["T_w"] - o0["T_w"]) > 1e-2


def test_interface_not_at_saturation(base):
    gaps = [abs(o["T_i"] - o["T_sat_pf1"]) for o in base["obs"][1:]]
    assert max(gaps) > 1e-3


def test_random_scenarios_plausible():
    for seed in (11, 12):
        sc = ks.resolve_scenario(f"random_{seed}")
        assert 4 <= len(sc["phases"]) <= 8 and 3600 <= sc["duration_s"] <= 7200
        assert 0.2 <= sc["initial"]["fill_ratio"] <= 0.9


def test_geometry_volumes():
    for tank in ({"shape": "vertical_cylinder", "radius_m": 0.5, "height_m": 2.0},
                 {"shape": "sphere", "radius_m": 1.0},
                 {"shape": "horizontal_cylinder", "radius_m": 0.8, "cylinder_length_m": 3.0},
                 {"shape": "vertical_cylinder_elliptical_heads", "radius_m": 1.0, "cylinder_length_m": 1.0,
                  "head_aspect": 2.0}):
        g = ks.Geometry(tank)
        assert abs(g.vol(g.H)[0] - g.V) < 1e-9 * g.V
        for f in (0.1, 0.5, 0.9):
            assert abs(g.vol(g.level(f * g.V))[0] - f * g.V) < 1e-9 * g.V
        assert abs(g.band_A.sum() - g.A) < 1e-9 * g.A and np.all(g.band_A > 0)
