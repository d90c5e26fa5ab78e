"""Checks of the independent test simulator (tests/independent_sim.py).

The simulator must stay independent of tankode: only the read-back test imports tankode.
Simulations here are short (a few hundred seconds) to keep the file fast.
"""

from __future__ import annotations

import ast
import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest

import independent_sim as sim

HERE = Path(__file__).resolve().parent


def _closed_scenario(duration: float = 600.0) -> dict:
    """A closed tank (no inputs at all) starting out of equilibrium (warm wall, warm ullage)."""
    return {
        "name": "closed",
        "tank": {"shape": "sphere", "radius_m": 0.9, "wall_heat_capacity_J_per_K": 3.0e5},
        "initial": {"p_Pa": 2.0e5, "T_v_K": 26.0, "T_l_K": 22.2, "T_w_K": 24.5, "fill_ratio": 0.55},
        "duration_s": duration,
        "steps": [(0.0, {})],
    }


def test_does_not_import_tankode():
    tree = ast.parse((HERE / "independent_sim.py").read_text())
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(a.name.split(".")[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            names.add((node.module or "").split(".")[0])
    assert "tankode" not in names
    assert names <= {"__future__", "argparse", "csv", "json", "math", "pathlib", "time", "dataclasses", "typing",
                     "CoolProp", "numpy", "scipy", "sys"}


@pytest.mark.parametrize("shape", [
    {"shape": "sphere", "radius_m": 1.1},
    {"shape": "horizontal_cylinder", "radius_m": 0.8, "cylinder_length_m": 3.0},
    {"shape": "vertical_cylinder", "radius_m": 0.7, "height_m": 2.5},
])
def test_geometry_closed_forms(shape):
    g = sim.make_geometry(shape)
    assert g.liquid_volume(g.height) == pytest.approx(g.volume, rel=1e-12)
    flat_ends = shape["shape"] == "vertical_cylinder"  # the bottom is always wet, the lid always dry
    assert g.wetted_area(g.height) == pytest.approx(g.wall_area - (g.base if flat_ends else 0.0), rel=1e-12)
    assert g.wetted_area(0.0) == pytest.approx(g.base if flat_ends else 0.0, abs=1e-12)
    hs = np.linspace(0.05, 0.95, 7) * g.height
    for h in hs:
        assert g.level(g.liquid_volume(h)) == pytest.approx(h, rel=1e-10)
        # dV/dh equals the interface area (numerical derivative).
        d = 1e-6 * g.height
        assert (g.liquid_volume(h + d) - g.liquid_volume(h - d)) / (2 * d) == pytest.approx(g.interface_area(h), rel=1e-6)


@pytest.mark.parametrize("mechanism,value", [(None, 0.0), ("noncondensable_gas", 150.0), ("thermal_stratification", 0.3)])
def test_closed_tank_conserves_mass_and_energy(mechanism, value):
    tr = sim.simulate_truth(_closed_scenario(), mechanism, value, t_eval=np.arange(0.0, 601.0, 10.0))
    assert np.all(tr.M_ext == 0.0) and np.all(tr.E_ext == 0.0)
    assert np.max(np.abs(tr.mass - tr.mass[0])) / tr.mass[0] < 1e-8
    # Energy moved inside the tank: the wall alone gives up C_w * dT_w (a few 1e5 J).
    moved = 3.0e5 * abs(tr.T_w[-1] - tr.T_w[0])
    assert moved > 1e5
    assert np.max(np.abs(tr.energy - tr.energy[0])) < 1e-6 * moved
    assert tr.max_volume_error < 1e-7
    # Something really happened: evaporation/condensation and a pressure change.
    assert np.ptp(tr.p) > 1e3


def test_vent_and_heat_leak_energy_balance():
    sc = _closed_scenario(duration=800.0)
    sc["steps"] = [(0.0, {"Q_aw_W": 300.0}), (200.0, {"mdot_v_out_kg_s": 1.5e-3}), (600.0, {"mdot_v_out_kg_s": 0.0})]
    t = np.arange(0.0, 801.0, 1.0)
    tr = sim.simulate_truth(sc, "heat_leak_liquid", 120.0, t_eval=t)
    # Mass: exactly what was vented.
    vented = 1.5e-3 * 400.0
    assert tr.mass[0] - tr.mass[-1] == pytest.approx(vented, rel=1e-9)
    # Energy: the integrated boundary terms carried along by the solver...
    assert np.max(np.abs(tr.energy - tr.energy[0] - tr.E_ext)) < 1.0  # J, out of MJ exchanged
    # ...and an independent trapezoid of vent enthalpy and heat on the 1 s output grid.
    props = sim._Props()
    h_v = np.array([props.vapour(pg, Tv).h for pg, Tv in zip(tr.extra["p_g"], tr.T_v)])
    # The vent runs on [200, 600] s: trapezoid over the 1 s intervals inside it.
    on = (t >= 200.0) & (t <= 600.0)
    inside = on[1:] & on[:-1]
    flow = 1.5e-3 * np.concatenate([[0.0], np.cumsum(0.5 * (h_v[1:] + h_v[:-1]) * np.diff(t) * inside)])
    heat = (300.0 + 120.0) * t
    dE = tr.energy - tr.energy[0]
    assert np.max(np.abs(dE - (heat - flow))) < 1e-5 * (heat[-1] + flow[-1])


def test_inflow_meter_bias_scales_the_true_inflow():
    sc = _closed_scenario(duration=300.0)
    sc["steps"] = [(0.0, {"mdot_l_in_kg_s": 0.02, "T_l_in_K": 21.5,
                          "mdot_v_in_kg_s": 1e-3, "T_v_in_K": 45.0, "p_v_in_Pa": 5e5})]
    for beta in (0.0, 0.25):
        tr = sim.simulate_truth(sc, "inflow_meter_bias", beta, t_eval=np.array([0.0, 300.0]))
        assert tr.mass[-1] - tr.mass[0] == pytest.approx((1 + beta) * 0.021 * 300.0, rel=1e-9)
        assert tr.energy[-1] - tr.energy[0] == pytest.approx(tr.E_ext[-1], abs=1.0)


def test_sensor_readings_and_metadata(tmp_path):
    p_json = sim.simulate_run("sphere_vent", "pressure_sensor_bias", 5000.0, out_dir=tmp_path, noise_free=True,
                              dropout=0.0, duration_s=300.0, name="bias")
    meta = json.loads(p_json.read_text())
    ini = sim.SCENARIOS["sphere_vent"]["initial"]
    assert meta["initial"]["p_v_Pa"] == pytest.approx(ini["p_Pa"] + 5000.0, rel=1e-12)
    assert meta["initial"]["fill_ratio"] == pytest.approx(ini["fill_ratio"], rel=1e-12)
    assert meta["tank"]["wall_heat_capacity_J_per_K"] == sim.SCENARIOS["sphere_vent"]["tank"]["wall_heat_capacity_J_per_K"]
    assert "mechanism=pressure_sensor_bias value=5000.0" in meta["source"]
    # He raises the sensor reading by n R T_v / V_v at t0.
    p_json = sim.simulate_run("sphere_vent", "noncondensable_gas", 100.0, out_dir=tmp_path, noise_free=True,
                              duration_s=100.0, name="he")
    V_v = (1 - ini["fill_ratio"]) * sim.make_geometry(sim.SCENARIOS["sphere_vent"]["tank"]).volume
    p_he = 100.0 * sim.R_GAS * ini["T_v_K"] / V_v
    assert json.loads(p_json.read_text())["initial"]["p_v_Pa"] == pytest.approx(ini["p_Pa"] + p_he, rel=1e-9)


def _read_csv(path: Path) -> tuple[list[str], list[list[str]]]:
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    return rows[0], rows[1:]


def test_run_reads_back_with_tankode(tmp_path):
    from tankode import read_run  # the only tankode import of the simulator's tests

    p_json = sim.simulate_run("hcyl_drain_fill", "liquid_leak", 3e-4, seed=3, out_dir=tmp_path, duration_s=600.0)
    run = read_run(p_json)
    meta = json.loads(p_json.read_text())
    header, rows = _read_csv(p_json.with_suffix(".csv"))
    assert run.fluid == "ParaHydrogen"
    assert run.tank.shape == "horizontal_cylinder"
    assert run.duration_s == 600.0
    assert run.initial.p_v_Pa == meta["initial"]["p_v_Pa"]
    assert dict(run.noise_std) == sim.DEFAULT_NOISE
    # Observations: every written cell, bit-exact, at its own time stamp.
    for ch in sim.OBS_COLUMNS:
        j = header.index(ch)
        t_w = np.array([float(r[0]) for r in rows if r[j] != ""])
        v_w = np.array([float(r[j]) for r in rows if r[j] != ""])
        t_r, v_r = run.observations.channel(ch)
        np.testing.assert_array_equal(t_r, t_w)
        np.testing.assert_array_equal(v_r, v_w)
        period, offset = sim.SAMPLING[ch]
        nominal = np.arange(offset, 600.0 + 1e-9, period)
        assert set(t_w) <= set(nominal) and t_w.size >= 0.9 * nominal.size  # dropouts only
    # Channels are asynchronous: pressure and temperatures never share a row.
    jp, jt = header.index("p_v_Pa"), header.index("T_v_K")
    assert not any(r[jp] and r[jt] for r in rows)
    # Inputs: the metered schedule (drain from 300 s), piecewise constant; the leak is hidden.
    assert run.inputs.t0_s == 0.0
    for t, drain in [(0.0, 0.0), (299.0, 0.0), (300.0, 0.08), (599.0, 0.08)]:
        assert run.inputs.get("mdot_l_out_kg_s", t) == drain
        assert run.inputs.get("Q_aw_W", t) == 300.0
    # Noise is there and of the right size (pressure: residual to the truth).
    tr = sim.simulate_truth("hcyl_drain_fill", "liquid_leak", 3e-4, t_eval=run.observations.channel("p_v_Pa")[0],
                            duration_s=600.0)
    res = run.observations.channel("p_v_Pa")[1] - tr.p_sensor
    assert 1500.0 < np.std(res) < 2500.0 and abs(np.mean(res)) < 500.0


def test_suggested_magnitudes_cover_every_mechanism():
    assert set(sim.SCENARIO_FOR) == set(sim.MECHANISMS)
    for mech, sc in sim.SCENARIO_FOR.items():
        assert sc in sim.SCENARIOS
        assert sim.suggested_magnitude(mech) == sim.SUGGESTED_MAGNITUDE[(sc, mech)]
    for (sc, mech), v in ((k, v) for k, v in sim.SUGGESTED_MAGNITUDE.items() if isinstance(k, tuple)):
        assert sc in sim.SCENARIOS and mech in sim.MECHANISMS and math.isfinite(v) and v > 0


def test_signature_of_a_suggested_magnitude_is_a_few_sigma():
    sc = "small_selfpress"
    mech = "heat_leak_vapor"
    sig = sim.signature(sc, mech, sim.SUGGESTED_MAGNITUDE[(sc, mech)])
    top = max(rms for rms, _ in sig.values())
    assert 2.0 <= top <= 6.0
