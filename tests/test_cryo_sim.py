"""Fast checks of the multi-fluid tank simulator (tests/cryo_sim.py).

Conservation for every operation and each of the five fluids, self-pressurisation and venting,
the geometry, the hidden mechanisms and a round trip of the written files through a minimal
reader written here (the simulator shares no code with tankode, and this file does not import
tankode either). Every simulation is short; the file runs in well under 30 s.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import quad

import cryo_sim as cs

OBS = ("p_v_Pa", "T_v_K", "T_l_K", "T_w_K", "H_l_m")
INPUTS = ("mdot_v_in_kg_s", "T_v_in_K", "p_v_in_Pa", "mdot_v_out_kg_s", "mdot_l_in_kg_s", "T_l_in_K",
          "mdot_l_out_kg_s", "slosh_amplitude_m", "slosh_frequency_Hz", "Q_aw_W")
SHAPE_KEYS = {"vertical_cylinder": {"radius_m", "height_m"},
              "vertical_cylinder_elliptical_heads": {"radius_m", "cylinder_length_m", "head_aspect"},
              "sphere": {"radius_m"},
              "horizontal_cylinder": {"radius_m", "cylinder_length_m"}}
NOISE_KEYS = ("p_v", "T_v", "T_l", "T_w", "H_l")


# ----------------------------------------------------------------------------- minimal reader
def _shape_volume(tank: dict) -> float:
    """Closed-form volume of the format's shapes (independent of the simulator's geometry)."""
    R = tank["radius_m"]
    s = tank["shape"]
    if s == "vertical_cylinder":
        return math.pi * R * R * tank["height_m"]
    if s == "vertical_cylinder_elliptical_heads":
        depth = R / tank["head_aspect"]
        return math.pi * R * R * tank["cylinder_length_m"] + 4.0 / 3.0 * math.pi * R * R * depth
    if s == "sphere":
        return 4.0 / 3.0 * math.pi * R ** 3
    if s == "horizontal_cylinder":
        return math.pi * R * R * tank["cylinder_length_m"]
    raise AssertionError(f"unknown shape {s}")


def read_run(json_path: Path) -> dict:
    """Read a run with the format's rules only; raise AssertionError on any violation."""
    meta = json.loads(json_path.read_text())
    allowed = {"name", "fluid", "source", "tank", "initial", "noise_std", "duration_s", "timeseries"}
    assert set(meta) <= allowed, set(meta) - allowed
    for k in ("name", "fluid", "tank", "initial", "noise_std", "timeseries"):
        assert k in meta, k
    tank = meta["tank"]
    shape = tank["shape"]
    assert shape in SHAPE_KEYS
    extra = set(tank) - SHAPE_KEYS[shape] - {"shape", "volume_m3", "wall_heat_capacity_J_per_K"}
    assert not extra, extra
    assert SHAPE_KEYS[shape] <= set(tank)
    assert "wall_heat_capacity_J_per_K" in tank
    if "volume_m3" in tank:
        assert tank["volume_m3"] == pytest.approx(_shape_volume(tank), rel=0.01)
    ini = meta["initial"]
    assert set(ini) <= {"p_v_Pa", "T_v_K", "T_l_K", "T_w_K", "fill_ratio"}
    assert {"p_v_Pa", "T_v_K", "T_l_K", "fill_ratio"} <= set(ini)
    assert set(meta["noise_std"]) <= set(NOISE_KEYS)
    assert all(v > 0 for v in meta["noise_std"].values())

    csv_path = json_path.parent / meta["timeseries"]
    with open(csv_path, newline="") as fh:
        rows = list(csv.reader(fh))
    header, body = rows[0], rows[1:]
    assert header[0] == "t_s"
    assert len(set(header)) == len(header)
    unknown = set(header[1:]) - set(OBS) - set(INPUTS)
    assert not unknown, f"unknown columns {unknown}"
    cols: dict[str, list] = {h: [] for h in header}
    for row in body:
        assert len(row) == len(header)
        for h, cell in zip(header, row):
            cols[h].append(float(cell) if cell != "" else None)
    t = np.array(cols["t_s"], dtype=float)
    assert np.all(np.diff(t) > 0), "time stamps must be strictly increasing"
    obs = {}
    for h in OBS:
        if h in cols:
            mask = np.array([v is not None for v in cols[h]])
            obs[h] = (t[mask], np.array([v for v in cols[h] if v is not None]))
            assert NOISE_KEYS[OBS.index(h)] in meta["noise_std"], f"{h} measured without noise_std"
    inputs = {}
    for h in INPUTS:
        if h in cols:
            vals, last = [], 0.0
            for v in cols[h]:  # piecewise constant: an empty cell keeps the previous value
                last = last if v is None else v
                vals.append(last)
            inputs[h] = np.array(vals)
    return {"meta": meta, "t": t, "obs": obs, "inputs": inputs, "raw": cols}


def _truth(paths: dict) -> dict:
    return json.loads(Path(paths["truth"]).read_text())


# ----------------------------------------------------------------------------- conservation
@pytest.mark.parametrize("fluid", cs.FLUIDS)
def test_closure_every_operation_each_fluid(tmp_path, fluid):
    """Mass, helium and energy close to round-off through every operation; the fluid mass also
    closes against the schedule (metered flows + the mechanisms' true flows) read back here."""
    sc = cs.random_scenario(7, fluid=fluid, ops=cs.OPERATIONS, phase_s=(120.0, 180.0))
    mech = {"heat_leak_liquid_W": 3.0, "heat_leak_vapor_W": 1.0, "heat_leak_wall_W": 2.0,
            "liquid_leak_kg_s": 1e-3, "inflow_meter_bias": 0.05, "wall_heat_capacity_error": 0.2}
    paths = cs.simulate_run(sc, mech, noise="none", out_dir=tmp_path, name=f"ops_{fluid}")
    tr = _truth(paths)
    assert tr["scenario"]["fluid"] == fluid
    c = tr["closure"]
    assert c["mass_rel"] < 1e-11, c
    assert c["energy_rel"] < 1e-11, c
    # every operation really ran (non-zero metered inputs of each kind)
    active = {s["kind"] for s in tr["schedule"] if set(s["inputs"]) - {"Q_aw_W"}}
    assert active >= {"pressurize", "vent", "fill", "drain", "slosh"}, tr["schedule"]
    # independent mass balance from the written schedule and the mechanisms
    dm = 0.0
    for s in tr["schedule"]:
        f = s["inputs"]
        dt = s["t1_s"] - s["t0_s"]
        dm += dt * ((1 + mech["inflow_meter_bias"]) * (f.get("mdot_v_in_kg_s", 0.0) + f.get("mdot_l_in_kg_s", 0.0))
                    - f.get("mdot_v_out_kg_s", 0.0) - f.get("mdot_l_out_kg_s", 0.0) - mech["liquid_leak_kg_s"])
    m0 = tr["initial_true"]["m_v_kg"] + tr["initial_true"]["m_l_kg"]
    m1 = tr["final_true"]["m_v_kg"] + tr["final_true"]["m_l_kg"]
    assert m1 - m0 == pytest.approx(dm, rel=1e-8, abs=1e-9 * m0)
    # plausible numbers
    fp = cs.fluid_props(fluid)
    s = tr["summary"]
    assert 0.45 * 101325 < s["p"]["min"] and s["p"]["max"] < 0.62 * fp.p_c
    assert 0.04 < s["fill"]["min"] and s["fill"]["max"] < 0.96
    assert fp.T_trip < s["T_l"]["min"] and s["T_l"]["max"] < fp.T_c
    assert tr["wall_time_s"] < 20.0


def test_helium_closure_and_total_pressure(tmp_path):
    """Helium is conserved (the vent removes it with the mixture), the sensors read the total
    pressure, and a mechanism leaves the metered schedule unchanged."""
    sc = cs.random_scenario(3, fluid="Nitrogen", ops=("rest", "vent", "pressurize", "rest"), phase_s=(150.0, 200.0))
    base = _truth(cs.simulate_run(sc, None, noise="none", out_dir=tmp_path, name="base"))
    ini = sc["initial"]
    V_v = (1 - ini["fill_ratio"]) * cs.Geometry(sc["tank"]).V
    n_he = 0.1 * ini["p_Pa"] * V_v / (cs.R_GAS * ini["T_v_K"])  # 10 % of the ullage
    paths = cs.simulate_run(sc, {"helium_mol": n_he, "pressure_sensor_bias_Pa": 700.0}, noise="none",
                            out_dir=tmp_path, name="he")
    tr = _truth(paths)
    run = read_run(Path(paths["json"]))
    assert tr["closure"]["helium_mol_max_abs"] < 1e-9 * n_he
    assert tr["closure"]["mass_rel"] < 1e-11 and tr["closure"]["energy_rel"] < 1e-11
    it = tr["initial_true"]
    assert it["p_helium_Pa"] == pytest.approx(0.1 * ini["p_Pa"], rel=1e-6)
    assert it["p_Pa"] == pytest.approx(ini["p_Pa"], rel=1e-9)
    assert it["p_fluid_Pa"] + it["p_helium_Pa"] == pytest.approx(it["p_Pa"], rel=1e-12)
    assert run["meta"]["initial"]["p_v_Pa"] == pytest.approx(ini["p_Pa"] + 700.0, rel=1e-9)
    assert tr["final_true"]["helium_mol"] < n_he  # the vent took some helium away
    assert [s["inputs"] for s in tr["schedule"]] == [s["inputs"] for s in base["schedule"]]


# ----------------------------------------------------------------------------- physics
def test_self_pressurisation_and_vent(tmp_path):
    sc = cs.named_scenario("ln2_dewar")
    sc["phases"] = [{"kind": "rest", "duration_s": 900.0}, {"kind": "vent", "duration_s": 300.0, "p_frac": 0.8}]
    sc["duration_s"] = 1200.0
    paths = cs.simulate_run(sc, None, noise="none", out_dir=tmp_path, name="selfpress")
    run = read_run(Path(paths["json"]))
    t, p = run["obs"]["p_v_Pa"]
    rest = t <= 900.0
    assert set(run["inputs"]) == {"mdot_v_out_kg_s", "Q_aw_W"}
    assert np.all(run["inputs"]["mdot_v_out_kg_s"][run["t"] < 900.0] == 0.0)  # closed tank
    assert np.all(run["inputs"]["Q_aw_W"] > 0)
    assert p[rest][-1] - p[0] > 1000.0  # self-pressurisation
    assert np.all(np.diff(p[rest][t[rest] >= 300.0]) > 0)
    vent = t >= 900.0
    assert p[vent][-1] < p[rest][-1] - 10000.0  # the vent lowers the pressure
    assert np.all(np.diff(p[vent]) < 0)
    # the vented liquid flashes: the liquid cools during the vent
    tl, Tl = run["obs"]["T_l_K"]
    assert Tl[tl >= 1200.0][0] < Tl[tl == 900.0][0] - 0.1


def test_sloshing_at_resonance_collapses_pressure():
    """Sloshing near the first mode mixes the subcooled liquid into the interface: the
    pressure falls faster than at rest (same tank, same time)."""
    sc = cs.named_scenario("lch4_sphere")
    sc["phases"] = [{"kind": "pressurize", "duration_s": 300.0, "dp_frac": 0.3, "T_in_factor": 1.6},
                    {"kind": "slosh", "duration_s": 600.0, "amp_m": 0.01, "freq_ratio": 1.0}]
    sc["duration_s"] = 900.0
    slosh = cs.simulate(sc)
    sc["phases"][1] = {"kind": "rest", "duration_s": 600.0}
    rest = cs.simulate(sc)
    p_s = slosh["obs"][-1]["p"] - slosh["obs"][30]["p"]
    p_r = rest["obs"][-1]["p"] - rest["obs"][30]["p"]
    assert p_s < p_r - 5000.0


# ----------------------------------------------------------------------------- geometry
@pytest.mark.parametrize("tank", [
    {"shape": "vertical_cylinder", "radius_m": 0.8, "height_m": 2.5},
    {"shape": "vertical_cylinder_elliptical_heads", "radius_m": 1.2, "cylinder_length_m": 2.0, "head_aspect": 2.0},
    {"shape": "vertical_cylinder_elliptical_heads", "radius_m": 1.0, "cylinder_length_m": 0.5, "head_aspect": 0.8},
    {"shape": "sphere", "radius_m": 1.5},
    {"shape": "horizontal_cylinder", "radius_m": 0.9, "cylinder_length_m": 4.0},
])
def test_geometry(tank):
    g = cs.Geometry(tank)
    assert g.V == pytest.approx(_shape_volume(tank), rel=1e-12)
    hs = np.linspace(0.0, g.H, 2001)
    at = np.array([g.at(h) for h in hs])
    assert at[-1, 0] == pytest.approx(g.V, rel=1e-12)
    assert np.all(np.diff(at[:, 0]) > 0) and np.all(np.diff(at[:, 2]) >= 0)
    for h1, h2 in ((0.0, 0.2 * g.H), (0.2 * g.H, 0.7 * g.H), (0.7 * g.H, g.H)):  # dV/dh = interface area
        integral = quad(lambda h: g.at(h)[1], h1, h2, epsabs=1e-12, epsrel=1e-10, limit=200)[0]
        assert g.at(h2)[0] - g.at(h1)[0] == pytest.approx(integral, rel=1e-8)
    # wetted area by brute force for surfaces of revolution (upright shapes)
    if tank["shape"] in ("sphere", "vertical_cylinder_elliptical_heads"):
        zz = np.linspace(0.0, g.H, 400001)
        r = np.sqrt([g.at(z)[1] / math.pi for z in zz[::100]])
        zc = zz[::100]
        band = math.pi * (r[1:] + r[:-1]) * np.hypot(np.diff(r), np.diff(zc))
        for h in (0.1 * g.H, 0.5 * g.H, 0.93 * g.H):
            assert g.at(h)[2] == pytest.approx(band[zc[1:] <= h + 1e-12].sum(), rel=2e-3)
        assert g.A_wall == pytest.approx(band.sum(), rel=2e-3)
    for h in (0.03 * g.H, 0.4 * g.H, 0.97 * g.H):
        assert g.level(g.at(h)[0]) == pytest.approx(h, rel=1e-9, abs=1e-12)


# ----------------------------------------------------------------------------- files
def test_files_round_trip(tmp_path):
    paths = cs.simulate_run("random_11", None, noise="low", seed=5, out_dir=tmp_path, name="rt", duration_s=1500.0,
                            wall_capacity_unknown=True)
    assert set(paths) == {"json", "csv", "truth"}
    run = read_run(Path(paths["json"]))
    meta = run["meta"]
    assert meta["name"] == "rt" and meta["timeseries"] == "rt.csv"
    assert "cryo_sim" in meta["source"]
    assert meta["tank"]["wall_heat_capacity_J_per_K"] is None
    assert meta["noise_std"] == cs.NOISE_LEVELS["low"]
    assert meta["duration_s"] == 1500.0
    # sampling: p_v, T_v, T_l, H_l every 10 s, T_w every 30 s (empty cells in between)
    for ch in ("p_v_Pa", "T_v_K", "T_l_K", "H_l_m"):
        assert np.array_equal(run["obs"][ch][0], np.arange(0.0, 1500.1, 10.0))
    assert np.array_equal(run["obs"]["T_w_K"][0], np.arange(0.0, 1500.1, 30.0))
    assert any(v is None for v in run["raw"]["T_w_K"])
    # the inputs are known columns, filled, and Q_aw is always on
    assert "Q_aw_W" in run["inputs"] and np.all(run["inputs"]["Q_aw_W"] > 0)
    tr = _truth(paths)
    # CSV inputs agree with the executed schedule in the truth file
    for s in tr["schedule"]:
        row = int(np.searchsorted(run["t"], s["t0_s"]))
        assert run["t"][row] == pytest.approx(s["t0_s"])
        for c in INPUTS:
            if c in run["inputs"]:
                assert run["inputs"][c][row] == pytest.approx(s["inputs"].get(c, 0.0), rel=1e-15)
    # noise: the low level's scale around the truth (the t=0 row vs the noise-free metadata)
    p_t, p_v = run["obs"]["p_v_Pa"]
    assert abs(p_v[0] - meta["initial"]["p_v_Pa"]) < 5 * 300.0
    assert meta["initial"]["p_v_Pa"] == pytest.approx(tr["initial_true"]["p_Pa"])
    assert meta["initial"]["fill_ratio"] == pytest.approx(tr["initial_true"]["fill_ratio"])
    # noise-free writing reproduces the metadata at t = 0 exactly
    clean = read_run(Path(cs.simulate_run("random_11", None, noise="none", out_dir=tmp_path, name="clean",
                                          duration_s=300.0)["json"]))
    for ch, key in (("p_v_Pa", "p_v_Pa"), ("T_v_K", "T_v_K"), ("T_l_K", "T_l_K"), ("T_w_K", "T_w_K")):
        assert clean["obs"][ch][1][0] == clean["meta"]["initial"][key]


def test_rejects_unknown_names(tmp_path):
    with pytest.raises(ValueError, match="unknown mechanisms"):
        cs.simulate_run("ln2_dewar", {"heat_leak_W": 1.0}, out_dir=tmp_path, duration_s=60.0)
    with pytest.raises(ValueError, match="unknown scenario"):
        cs.simulate_run("ln2_dewer", out_dir=tmp_path)
    with pytest.raises(ValueError, match="CoolProp"):
        cs.fluid_props("Nitrogenn")
    assert cs.main(["ln2_dewar", "--out", str(tmp_path), "--mechanism", "helium_mol=1e9", "--duration", "60"]) == 2
