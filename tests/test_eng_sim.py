"""Fast checks of the engineering-property tank simulator (tests/eng_sim.py).

Conservation, the written files (read back with the standard library and numpy only), the
hidden mechanisms and the engineering saturation curve against CoolProp reference points
(hard-coded here: neither the simulator nor this file uses CoolProp or tankode).
"""

from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest

import eng_sim as es

OBS = ("p_v_Pa", "T_v_K", "T_l_K", "T_w_K", "H_l_m")
INPUTS = ("mdot_v_in_kg_s", "T_v_in_K", "p_v_in_Pa", "mdot_v_out_kg_s", "mdot_l_in_kg_s", "T_l_in_K",
          "mdot_l_out_kg_s", "slosh_amplitude_m", "slosh_frequency_Hz", "Q_aw_W")

# CoolProp 8.0 saturation temperatures (p [Pa], T_sat [K]), taken offline
T_SAT_REF = {
    "ParaHydrogen": ((70000.0, 19.085), (150000.0, 21.671), (300000.0, 24.566), (500000.0, 27.112)),
    "Hydrogen": ((70000.0, 19.178), (150000.0, 21.774), (300000.0, 24.683), (500000.0, 27.243)),
    "Nitrogen": ((70000.0, 74.349), (200000.0, 83.626), (500000.0, 93.995), (1000000.0, 103.747)),
    "Oxygen": ((70000.0, 86.794), (200000.0, 97.236), (500000.0, 108.806), (1000000.0, 119.621)),
    "Methane": ((70000.0, 107.36), (200000.0, 120.622), (500000.0, 135.351), (1000000.0, 149.139)),
}


def _read(paths):
    meta = json.loads(paths["json"].read_text())
    with open(paths["csv"], newline="") as fh:
        rows = list(csv.reader(fh))
    return meta, rows[0], rows[1:], json.loads(paths["truth"].read_text())


@pytest.mark.parametrize("fluid", es.FLUIDS)
def test_closure_every_operation(fluid):
    sc = es.random_scenario(3, fluid, ops=("rest", "pressurize", "vent", "fill", "drain", "slosh"), phase_s=200.0)
    mech = {"heat_leak_liquid_W": 5.0, "heat_leak_vapor_W": 2.0, "heat_leak_wall_W": 3.0, "liquid_leak_kg_s": 1e-3,
            "vapor_leak_kg_s": 1e-5, "inflow_meter_bias": 0.05, "helium_mol": 2.0}
    res = es.simulate(sc, mech)
    c = res["closure"]
    assert c["mass_rel"] < 1e-9 and c["energy_rel"] < 1e-9, c
    active = {s["kind"] for s in res["executed"] if any(v for k, v in s["inputs"].items() if k != "Q_aw_W")}
    assert {"pressurize", "vent", "fill", "drain", "slosh"} <= active, res["executed"]
    p = np.array([o["p"] for o in res["obs"]])
    assert 0.6e5 < p.min() and p.max() < es.FLUID_DATA[fluid]["p_max"] * 1.1
    assert res["wall_time_s"] < 5.0


def test_files_parse(tmp_path):
    mech = {"pressure_sensor_bias_Pa": 500.0, "temperature_sensor_bias_K": 0.3}
    paths = es.simulate_run("lh2_small", mech, noise="low", out_dir=tmp_path, duration_s=1500.0)
    meta, header, body, truth = _read(paths)
    assert meta["fluid"] == "Hydrogen" and meta["timeseries"] == paths["csv"].name
    assert set(meta) == {"name", "fluid", "source", "tank", "initial", "noise_std", "duration_s", "timeseries"}
    tank = meta["tank"]
    assert tank["shape"] == "vertical_cylinder"
    assert tank["volume_m3"] == pytest.approx(math.pi * tank["radius_m"] ** 2 * tank["height_m"], rel=1e-12)
    assert tank["wall_heat_capacity_J_per_K"] > 0
    assert meta["noise_std"] == {"p_v": 300.0, "T_v": 0.05, "T_l": 0.05, "T_w": 0.05, "H_l": 0.001}
    ini, tru = meta["initial"], truth["initial_true"]
    assert ini["p_v_Pa"] == pytest.approx(tru["p_Pa"] + 500.0) and ini["T_l_K"] == pytest.approx(tru["T_l_K"] + 0.3)
    assert header[0] == "t_s" and set(header[1:]) <= set(OBS) | set(INPUTS) and set(OBS) <= set(header)
    t = np.array([float(r[0]) for r in body])
    assert np.all(np.diff(t) > 0) and t[-1] == pytest.approx(1500.0)
    col = {h: [r[i] for r in body] for i, h in enumerate(header)}
    tw = [float(x) for x, s in zip(col["T_w_K"], t) if x != ""]
    assert len(tw) == 1500 // 20 + 1
    assert all(x != "" for x in col["Q_aw_W"]) and all(x != "" for x in col["mdot_l_out_kg_s"])
    p = np.array([float(x) for x in col["p_v_Pa"] if x != ""])
    assert len(p) == 151 and abs(p[0] - ini["p_v_Pa"]) < 3000.0
    assert truth["closure"]["mass_rel"] < 1e-9 and truth["closure"]["energy_rel"] < 1e-9
    assert any(s["kind"] == "drain" and s["inputs"].get("mdot_l_out_kg_s", 0) > 0 for s in truth["schedule"])


def test_mechanisms_act():
    base = es.simulate("lh2_upright", duration_s=1200.0)
    leak = es.simulate("lh2_upright", {"vapor_leak_kg_s": 2e-4}, duration_s=1200.0)
    assert leak["obs"][-1]["p"] < base["obs"][-1]["p"] - 2000.0
    hot = es.simulate("lh2_upright", {"heat_leak_liquid_W": 200.0}, duration_s=1200.0)
    assert hot["obs"][-1]["T_l"] > base["obs"][-1]["T_l"] + 0.01
    drain = es.simulate("lh2_upright", {"liquid_leak_kg_s": 0.01}, duration_s=1200.0)
    assert drain["obs"][-1]["level"] < base["obs"][-1]["level"] - 0.01
    # the replayed schedule is the nominal one
    assert [s["inputs"] for s in leak["executed"]] == [s["inputs"] for s in base["executed"]]


def test_helium_raises_pressure_at_same_inventory():
    sc = es.resolve_scenario("ln2_hcyl")
    model = es.Model(sc, {})
    y = model.y0.copy()
    st0 = model.recover(y)
    n = 20.0
    y[2] = n
    y[1] += 1.5 * es.RU * n * st0["T_v"]  # helium added at the ullage temperature
    st1 = model.recover(y)
    assert st1["T_v"] == pytest.approx(st0["T_v"], rel=1e-9) and st1["p_f"] == pytest.approx(st0["p_f"], rel=1e-9)
    assert st1["p"] - st0["p"] == pytest.approx(n * es.RU * st0["T_v"] / st0["V_v"], rel=1e-9)
    # in a run, helium stays in the ullage and the written pressure is the total
    res = es.simulate("ln2_hcyl", {"helium_mol": n}, duration_s=600.0)
    assert res["obs"][0]["p_he"] > 1000.0
    assert res["obs"][0]["p"] == pytest.approx(sc["initial"]["p_Pa"], rel=1e-9)


@pytest.mark.parametrize("fluid", es.FLUIDS)
def test_saturation_curve_within_one_kelvin(fluid):
    fl = es.fluid(fluid)
    for p, T in T_SAT_REF[fluid]:
        assert abs(fl.T_sat(p) - T) < 1.0, (p, fl.T_sat(p), T)
        assert fl.p_sat(fl.T_sat(p)) == pytest.approx(p, rel=1e-12)
    # energy reference: h_v - h_l = L at the normal boiling point
    T, p = fl.T_nbp, fl.p_sat(fl.T_nbp)
    assert fl.h_v_Tp(T, p) - fl.h_l(T, p) == pytest.approx(fl.L(T), rel=1e-12)


def test_cli(tmp_path, capsys):
    assert es.main(["lch4_sphere", "--out", str(tmp_path), "--duration", "600", "--noise", "high"]) == 0
    assert "closure mass" in capsys.readouterr().out
    assert es.main(["nope", "--out", str(tmp_path)]) == 2
    assert "eng_sim: error" in capsys.readouterr().err
