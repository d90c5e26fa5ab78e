"""Checks of the nodal tank simulator (tests/nodal_sim.py): the mathematics and the writer.

The simulator must stay independent of tankode; only the read-back test imports tankode.
Each simulation here is short (well under a second), so the file runs in well under a minute.
"""

from __future__ import annotations

import ast
import json
import math
from pathlib import Path

import CoolProp as CP
import numpy as np
import pytest
from scipy.integrate import quad
from scipy.optimize import brentq

import nodal_sim as ns

HERE = Path(__file__).resolve().parent
DYNAMIC_LAWS = ("paper_printed", "mcadams", "slosh_energy")


def _tsat(p: float, fluid: str = "ParaHydrogen") -> float:
    return CP.CoolProp.PropsSI("T", "P", p, "Q", 0, fluid)


def _scenario(tank: dict, p: float, T_v: float, T_l: float, T_w: float, fill: float, duration: float,
              steps: list) -> dict:
    return {"name": "test", "tank": tank,
            "initial": {"p_Pa": p, "T_v_K": T_v, "T_l_K": T_l, "T_w_K": T_w, "fill_ratio": fill},
            "duration_s": duration, "steps": steps}


def _all_operations(dt: float = 150.0) -> dict:
    """A small upright tank through every operation: heat, pressurisation, vent, fill, drain, sloshing."""
    tank = {"shape": "vertical_cylinder", "radius_m": 0.8, "height_m": 2.0, "wall_heat_capacity_J_per_K": 1.5e5}
    steps = [
        (0.0, {"Q_aw_W": 200.0}),
        (dt, {"mdot_v_in_kg_s": 0.004, "T_v_in_K": 50.0, "p_v_in_Pa": 5e5}),
        (2 * dt, {"mdot_v_in_kg_s": 0.0, "mdot_v_out_kg_s": 0.003}),
        (3 * dt, {"mdot_v_out_kg_s": 0.0, "mdot_l_in_kg_s": 0.05, "T_l_in_K": 20.4}),
        (4 * dt, {"mdot_l_in_kg_s": 0.0, "mdot_l_out_kg_s": 0.08}),
        (5 * dt, {"mdot_l_out_kg_s": 0.0, "slosh_amplitude_m": 0.006, "slosh_frequency_Hz": 0.6}),
    ]
    return _scenario(tank, 1.5e5, 23.0, _tsat(1.5e5) - 0.2, 22.0, 0.5, 6 * dt, steps)


def _independent_state_check(tr: ns.Trajectory, fluid: str = "ParaHydrogen", rtol: float = 1e-8) -> None:
    """Volumes and internal energies recomputed with plain CoolProp (p, T) calls from the outputs."""
    m = tr.model
    gas = CP.AbstractState("HEOS", fluid)
    gas.specify_phase(CP.iphase_gas)
    liq = CP.AbstractState("HEOS", fluid)
    liq.specify_phase(CP.iphase_liquid)
    for i in range(0, len(tr.t), max(1, len(tr.t) // 12)):
        y = tr.y[i]
        gas.update(CP.PT_INPUTS, tr.p_h2[i], tr.T_v[i])
        V = y[m.i_mv] / gas.rhomass()
        U = y[m.i_mv] * gas.umass() + y[m.i_n] * 1.5 * ns.R_GAS * tr.T_v[i]
        assert U == pytest.approx(y[m.i_Ug], rel=rtol, abs=1e-3)
        for k, T_k in enumerate(tr.T_layers[i]):
            liq.update(CP.PT_INPUTS, tr.p[i], T_k)
            V += y[m.i_m][k] / liq.rhomass()
            assert y[m.i_m][k] * liq.umass() == pytest.approx(y[m.i_U][k], rel=rtol, abs=1e-3)
        assert V == pytest.approx(m.shape.volume, rel=rtol)


# =============================================================================== independence
def test_module_does_not_import_tankode():
    tree = ast.parse((HERE / "nodal_sim.py").read_text())
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(a.name.split(".")[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            names.add((node.module or "").split(".")[0])
            assert node.level == 0, "no relative imports"
    assert not names & {"tankode", "trainers", "independent_sim"}
    assert names <= {"__future__", "argparse", "copy", "csv", "json", "math", "pathlib", "sys", "time", "dataclasses",
                     "typing", "CoolProp", "numpy", "scipy"}
    # nor by a dynamic import
    src = (HERE / "nodal_sim.py").read_text()
    assert "importlib" not in src and "__import__" not in src


# =============================================================================== geometry
def _spheroid_area(R: float, c: float) -> float:
    """Closed-form area of a spheroid with equatorial radius R and polar semi-axis c."""
    if abs(c - R) < 1e-12:
        return 4 * math.pi * R * R
    if c < R:
        e = math.sqrt(1 - c * c / (R * R))
        return 2 * math.pi * R * R + math.pi * c * c / e * math.log((1 + e) / (1 - e))
    e = math.sqrt(1 - R * R / (c * c))
    return 2 * math.pi * R * R * (1 + c / (R * e) * math.asin(e))


SHAPES = [
    ({"shape": "vertical_cylinder", "radius_m": 0.7, "height_m": 2.5},
     math.pi * 0.49 * 2.5, 2 * math.pi * 0.49 + 2 * math.pi * 0.7 * 2.5),
    ({"shape": "sphere", "radius_m": 1.1}, 4 / 3 * math.pi * 1.1**3, 4 * math.pi * 1.21),
    ({"shape": "horizontal_cylinder", "radius_m": 0.8, "cylinder_length_m": 3.0},
     math.pi * 0.64 * 3.0, 2 * math.pi * 0.8 * 3.0 + 2 * math.pi * 0.64),
    ({"shape": "vertical_cylinder_elliptical_heads", "radius_m": 1.0, "cylinder_length_m": 1.5, "head_aspect": 2.0},
     math.pi * 1.5 + 4 / 3 * math.pi * 0.5, 2 * math.pi * 1.5 + _spheroid_area(1.0, 0.5)),
    ({"shape": "vertical_cylinder_elliptical_heads", "radius_m": 0.6, "cylinder_length_m": 0.8, "head_aspect": 0.8},
     math.pi * 0.36 * 0.8 + 4 / 3 * math.pi * 0.36 * 0.75, 2 * math.pi * 0.6 * 0.8 + _spheroid_area(0.6, 0.75)),
    ({"shape": "vertical_cylinder_elliptical_heads", "radius_m": 0.9, "cylinder_length_m": 0.0, "head_aspect": 1.0},
     4 / 3 * math.pi * 0.729, 4 * math.pi * 0.81),
]


@pytest.mark.parametrize("tank,volume,wall_area", SHAPES, ids=lambda v: v["shape"] if isinstance(v, dict) else "")
def test_shape_closed_forms_and_integrals(tank, volume, wall_area):
    g = ns.make_shape(tank)
    assert g.volume == pytest.approx(volume, rel=1e-12)
    assert g.wall_area == pytest.approx(wall_area, rel=1e-12)
    assert g.liquid_volume(0.0) == pytest.approx(0.0, abs=1e-14)
    assert g.liquid_volume(g.height) == pytest.approx(volume, rel=1e-12)
    flat = tank["shape"] in ("vertical_cylinder",)
    base = math.pi * tank["radius_m"] ** 2 if flat else 0.0  # the bottom is always wet, the lid always dry
    assert g.wetted_area(0.0) == pytest.approx(base, abs=1e-12)
    assert g.wetted_area(g.height) == pytest.approx(wall_area - base, rel=1e-12)
    for h in np.linspace(0.03, 0.97, 9) * g.height:
        d = 1e-6 * g.height
        # dV/dh = interface area, dA_wl/dh = wetted perimeter (numerical derivatives)
        dV = (g.liquid_volume(h + d) - g.liquid_volume(h - d)) / (2 * d)
        assert dV == pytest.approx(g.interface_area(h), rel=1e-6)
        dA = (g.wetted_area(h + d) - g.wetted_area(h - d)) / (2 * d)
        assert dA == pytest.approx(g.wetted_perimeter(h), rel=1e-6)
        # V(h) = integral of the interface area; inversion
        V = quad(g.interface_area, 0.0, h, epsabs=0, epsrel=1e-12, limit=200)[0]
        assert V == pytest.approx(g.liquid_volume(h), rel=1e-9)
        assert g.level(g.liquid_volume(h)) == pytest.approx(h, rel=1e-11)
        # the contact line is the perimeter of the free surface
        if tank["shape"] == "horizontal_cylinder":
            w = g.interface_area(h) / tank["cylinder_length_m"]
            assert g.contact_line(h) == pytest.approx(2 * tank["cylinder_length_m"] + 2 * w, rel=1e-12)
        else:
            assert g.contact_line(h) == pytest.approx(2 * math.sqrt(math.pi * g.interface_area(h)), rel=1e-12)


def test_elliptical_head_area_against_parametric_integral():
    """Wetted area in a 2:1 head by quadrature of the parametric surface of revolution."""
    R, d = 1.0, 0.5
    g = ns.make_shape({"shape": "vertical_cylinder_elliptical_heads", "radius_m": R, "cylinder_length_m": 1.5,
                       "head_aspect": R / d})
    for h in (0.05, 0.2, 0.4, 0.5):
        t_h = math.acos(1 - h / d)  # z = d (1 - cos t), r = R sin t
        area = quad(lambda t: 2 * math.pi * R * math.sin(t) * math.hypot(R * math.cos(t), d * math.sin(t)), 0, t_h,
                    epsabs=0, epsrel=1e-12)[0]
        assert g.wetted_area(h) == pytest.approx(area, rel=1e-10)
    # a spheroid with head_aspect 1 and no straight part is the sphere
    s = ns.make_shape({"shape": "vertical_cylinder_elliptical_heads", "radius_m": 0.9, "cylinder_length_m": 0.0,
                       "head_aspect": 1.0})
    sp = ns.make_shape({"shape": "sphere", "radius_m": 0.9})
    for h in (0.1, 0.7, 1.5):
        for f in ("liquid_volume", "interface_area", "wetted_area", "wetted_perimeter"):
            assert getattr(s, f)(h) == pytest.approx(getattr(sp, f)(h), rel=1e-12)


# =============================================================================== conservation
@pytest.mark.parametrize("law", DYNAMIC_LAWS)
def test_mass_and_energy_balances_every_operation(law):
    mech = {"vapor_leak_kg_s": 2e-4, "liquid_leak_kg_s": 1e-3, "heat_leak_liquid_W": 30.0, "heat_leak_vapor_W": 10.0,
            "heat_leak_wall_W": 20.0, "noncondensable_mol": 20.0, "inflow_meter_bias": 0.05}
    tr = ns.simulate(_all_operations(), law=law, mechanisms=mech, t_eval=np.arange(0.0, 901.0, 10.0),
                     liquid_layers=2)
    M = tr.mass[0]
    assert np.max(np.abs(tr.mass_balance_error())) < 1e-10 * M
    throughput = np.max(np.abs(tr.H_in)) + np.max(np.abs(tr.H_out)) + np.max(np.abs(tr.Q_in))
    assert throughput > 1e5  # things crossed the boundary
    assert np.max(np.abs(tr.energy_balance_error())) < 1e-10 * throughput
    # every operation happened: the quadratures grew, helium was vented with the gas
    assert tr.M_in[-1] > 0.6 * 150 * (0.004 + 0.05) and tr.M_out[-1] > 150 * (0.003 + 0.08)
    assert tr.n_he[-1] < tr.n_he[0]
    _independent_state_check(tr)


@pytest.mark.parametrize("opts", [
    {"wall_nodes": 1},
    {"liquid_layers": 3},
    {"property_model": "normal_hydrogen"},
    {"bulk_phase_change": False, "vent_removes_helium": False},
], ids=lambda o: ",".join(f"{k}={v}" for k, v in o.items()))
def test_balances_with_options(opts):
    tr = ns.simulate(_all_operations(100.0), law="mcadams", mechanisms={"noncondensable_mol": 10.0,
                                                                        "vapor_leak_kg_s": 1e-4},
                     t_eval=np.arange(0.0, 601.0, 20.0), **opts)
    assert np.max(np.abs(tr.mass_balance_error())) < 1e-10 * tr.mass[0]
    throughput = np.max(np.abs(tr.H_in)) + np.max(np.abs(tr.H_out)) + np.max(np.abs(tr.Q_in))
    assert np.max(np.abs(tr.energy_balance_error())) < 1e-10 * throughput
    fluid = "Hydrogen" if opts.get("property_model") == "normal_hydrogen" else "ParaHydrogen"
    _independent_state_check(tr, fluid)
    if opts.get("vent_removes_helium") is False:
        assert tr.n_he[-1] == pytest.approx(tr.n_he[0], rel=1e-12)


# =============================================================================== analytic cases
def test_closed_adiabatic_tank_relaxes_to_thermodynamic_equilibrium():
    """No inputs, fixed coefficients: the end state is the two-phase equilibrium with the same total
    mass, total energy (fluid + wall) and volume, computed here with CoolProp's saturation states."""
    tank = {"shape": "sphere", "radius_m": 0.3, "wall_heat_capacity_J_per_K": 2.0e4}
    p0, T_v0, T_l0, T_w0, fill = 1.5e5, 24.0, 20.8, 23.0, 0.5
    sc = _scenario(tank, p0, T_v0, T_l0, T_w0, fill, 40000.0, [(0.0, {})])
    tr = ns.simulate(sc, law="constant", h_constant=(50.0, 200.0, 20.0, 300.0), t_eval=[0.0, 20000.0, 40000.0])
    V = 4 / 3 * math.pi * 0.3**3
    st = CP.AbstractState("HEOS", "ParaHydrogen")
    st.update(CP.PT_INPUTS, p0, T_v0)
    m_v, U_v = st.rhomass() * (1 - fill) * V, st.rhomass() * (1 - fill) * V * st.umass()
    st.update(CP.PT_INPUTS, p0, T_l0)
    m_l, U_l = st.rhomass() * fill * V, st.rhomass() * fill * V * st.umass()
    M, E = m_v + m_l, U_v + U_l + 2.0e4 * T_w0

    def equilibrium(T: float) -> tuple[float, float, float]:
        st.update(CP.QT_INPUTS, 0.0, T)
        rl, ul, p = st.rhomass(), st.umass(), st.p()
        st.update(CP.QT_INPUTS, 1.0, T)
        rv, uv = st.rhomass(), st.umass()
        mv = (V - M / rl) / (1 / rv - 1 / rl)
        ml = M - mv
        return ml * ul + mv * uv + 2.0e4 * T - E, p, ml / rl / V

    T_eq = brentq(lambda T: equilibrium(T)[0], 18.0, 30.0, xtol=1e-12)
    _, p_eq, fill_eq = equilibrium(T_eq)
    assert tr.mass[-1] == pytest.approx(M, rel=1e-10)
    assert tr.energy[-1] == pytest.approx(E, rel=1e-10)
    for T in (tr.T_v[-1], tr.T_l[-1], *tr.T_w_nodes[-1]):
        assert T == pytest.approx(T_eq, abs=2e-4)
    assert tr.p[-1] == pytest.approx(p_eq, abs=2.0)
    assert tr.fill[-1] == pytest.approx(fill_eq, abs=1e-5)
    # it was relaxing, not sitting still
    assert abs(T_eq - T_v0) > 1.0 and abs(tr.p[-1] - p0) > 1e3
    assert abs(tr.p[1] - tr.p[2]) < 1.0


def test_pure_vent_is_isentropic_for_each_phase():
    """Venting with no heat transfer and no phase change: both phases expand isentropically."""
    tank = {"shape": "vertical_cylinder", "radius_m": 0.5, "height_m": 1.2, "wall_heat_capacity_J_per_K": 5e4}
    sc = _scenario(tank, 2.0e5, 27.0, 22.0, 25.0, 0.5, 400.0, [(0.0, {"mdot_v_out_kg_s": 0.0004})])
    tr = ns.simulate(sc, law="constant", h_constant=(0.0, 0.0, 0.0, 0.0), bulk_phase_change=False,
                     t_eval=np.linspace(0.0, 400.0, 9), rtol=1e-10)
    gas = CP.AbstractState("HEOS", "ParaHydrogen")
    gas.specify_phase(CP.iphase_gas)
    liq = CP.AbstractState("HEOS", "ParaHydrogen")
    liq.specify_phase(CP.iphase_liquid)
    s_v, s_l = [], []
    for p, T_v, T_l in zip(tr.p, tr.T_v, tr.T_l):
        gas.update(CP.PT_INPUTS, p, T_v)
        s_v.append(gas.smass())
        liq.update(CP.PT_INPUTS, p, T_l)
        s_l.append(liq.smass())
    assert tr.p[-1] < 0.8 * tr.p[0]  # a real expansion
    gas.update(CP.PT_INPUTS, tr.p[-1], tr.T_v[0])
    assert s_v[0] - gas.smass() < -100.0  # an isothermal expansion would gain > 100 J/(kg K)
    assert np.ptp(s_v) < 1e-4  # J/(kg K), out of 2.2e4: the solver tolerance
    assert np.ptp(s_l) < 1e-5
    # the wall did not move
    assert np.ptp(tr.T_w) < 1e-9


# =============================================================================== writer
def test_written_run_is_read_by_tankode_and_round_trips_inputs(tmp_path):
    tankode = pytest.importorskip("tankode")
    mech = {"pressure_sensor_bias_Pa": 1500.0, "temperature_sensor_bias_K": 0.3, "temperature_bias_channel": "T_v",
            "wall_heat_capacity_error": 0.2}
    res = ns.simulate_run("upright_13m3", law="slosh_energy", mechanisms=mech, noise="high", seed=3, out_dir=tmp_path)
    run = tankode.read_run(res["json"])
    sc = ns.SCENARIOS["upright_13m3"]
    segs = ns.segments(sc["steps"], sc["duration_s"])
    for t0, t1, inputs in segs:
        for t in (t0, 0.5 * (t0 + t1), t1 - 1e-6):
            got = dict(zip(ns.INPUT_COLUMNS, run.inputs.at(t)))  # tankode orders inputs like the format
            for c in ns.INPUT_COLUMNS:
                assert got[c] == inputs[c], (t, c)
    tr = res["trajectory"]
    assert run.initial.p_v_Pa == pytest.approx(tr.p[0] + 1500.0, rel=1e-12)
    assert run.initial.T_v_K == pytest.approx(tr.T_v[0] + 0.3, rel=1e-12)
    assert run.initial.T_l_K == pytest.approx(tr.T_l[0], rel=1e-12)
    assert run.initial.fill_ratio == pytest.approx(0.5, rel=1e-9)
    assert dict(run.noise_std) == ns.NOISE_LEVELS["high"]
    assert run.tank.wall_heat_capacity_J_per_K == 5.0e5  # the metadata holds the nominal value
    assert run.duration_s == 7200.0
    # observations: asynchronous channels with the documented periods
    obs_t, vals = run.observations.t_s, run.observations.values
    for j, col in enumerate(ns.OBS_COLUMNS):
        period, offset = ns.SAMPLING[col]
        t_ch = obs_t[~np.isnan(vals[:, j])]
        assert t_ch[0] == offset and np.all(np.diff(t_ch) == period)
    # noise of about the stated size on the pressure channel
    p_meas = vals[~np.isnan(vals[:, 0]), 0]
    idx = np.searchsorted(tr.t, obs_t[~np.isnan(vals[:, 0])])
    resid = p_meas - tr.sensors["p_v_Pa"][idx]
    assert 1500 < np.std(resid) < 2500
    # the truth is beside the run, not in it
    meta = json.loads(Path(res["json"]).read_text())
    assert set(meta) == {"name", "fluid", "source", "tank", "initial", "noise_std", "duration_s", "timeseries"}
    assert meta["source"] == "tests/nodal_sim.py law=slosh_energy" and meta["fluid"] == "ParaHydrogen"
    truth = json.loads(Path(res["truth"]).read_text())
    assert truth["law"] == "slosh_energy"
    assert truth["mechanisms"]["pressure_sensor_bias_Pa"] == 1500.0
    assert truth["wall_heat_capacity_true_J_per_K"] == pytest.approx(6.0e5)
    # inputs only on their change rows
    lines = Path(res["csv"]).read_text().splitlines()
    header = lines[0].split(",")
    k = header.index("Q_aw_W")
    assert sum(1 for ln in lines[1:] if ln.split(",")[k] != "") == len(segs)


def test_command_line(tmp_path, capsys):
    assert ns.main(["--list"]) == 0
    out = capsys.readouterr().out
    for name in ns.SCENARIOS:
        assert name in out
    assert ns.main(["tank_4p9m3", "--law", "paper_printed", "--out", str(tmp_path), "--duration", "600",
                    "--mechanism", "vapor_leak_kg_s=1e-4", "--mechanism", "temperature_bias_channel=T_w",
                    "--noise", "none", "--wall-nodes", "1", "--liquid-layers", "2", "--name", "cli"]) == 0
    meta = json.loads((tmp_path / "cli.json").read_text())
    truth = json.loads((tmp_path / "cli.truth.json").read_text())
    assert meta["duration_s"] == 600.0 and truth["mechanisms"] == {"vapor_leak_kg_s": 1e-4}
    assert truth["options"]["wall_nodes"] == 1 and truth["options"]["liquid_layers"] == 2
    assert (tmp_path / "cli.csv").is_file()


# =============================================================================== qualitative behaviour
def _upright(T_v: float, T_w: float, p: float = 1.2e5, duration: float = 600.0, steps: list | None = None) -> dict:
    tank = {"shape": "vertical_cylinder", "radius_m": 1.2, "height_m": 3.0, "wall_heat_capacity_J_per_K": 5.0e5}
    return _scenario(tank, p, T_v, _tsat(p), T_w, 0.5, duration, steps or [(0.0, {})])


def test_paper_printed_warm_ullage_cools_onto_the_wall_within_minutes():
    sc = _upright(25.0, 21.5)
    t = np.array([0.0, 60.0, 300.0])
    pp = ns.simulate(sc, law="paper_printed", t_eval=t)
    mc = ns.simulate(sc, law="mcadams", t_eval=t)
    gap = pp.T_v - pp.T_w_nodes[:, 1]  # ullage minus dry wall
    assert gap[0] == pytest.approx(3.5)
    assert gap[1] < 0.1 * gap[0] and abs(gap[2]) < 0.1 * gap[0]  # 90 % of the gap is gone in a minute
    assert pp.T_v[2] < 22.5
    assert mc.T_v[1] > pp.T_v[1] + 1.0  # natural convection is far slower
    d = pp.model.evaluate(pp.y[0], full=True)[1]
    assert 50.0 < d["h_wv"] < 1000.0  # order 100 W/(m2 K)


@pytest.mark.parametrize("law", ["mcadams", "slosh_energy"])
def test_sloshing_lowers_the_pressure_after_pressurisation(law):
    press = [(0.0, {"Q_aw_W": 500.0, "mdot_v_in_kg_s": 0.01, "T_v_in_K": 60.0, "p_v_in_Pa": 6e5}),
             (600.0, {"mdot_v_in_kg_s": 0.0})]
    slosh = press + [(900.0, {"slosh_amplitude_m": 0.01, "slosh_frequency_Hz": 0.5})]
    t = np.array([0.0, 900.0, 1800.0])
    a = ns.simulate(_upright(22.0, 21.5, duration=1800.0, steps=press), law=law, t_eval=t)
    b = ns.simulate(_upright(22.0, 21.5, duration=1800.0, steps=slosh), law=law, t_eval=t)
    assert a.p[1] == pytest.approx(b.p[1], rel=1e-5)  # same history up to the sloshing
    assert b.p[2] < a.p[2] - 5e3  # a clearly measurable drop (sensor noise: 0.3-2 kPa)
    assert b.p[2] < b.p[1]


def test_slosh_energy_wave_height_peaks_at_the_first_mode():
    m = ns.NodalTank(_upright(22.0, 21.5)["tank"])
    A_i = m.shape.interface_area(1.5)
    R, H = 1.2, 1.5
    f11 = math.sqrt(9.80665 * 1.8412 / R * math.tanh(1.8412 * H / R)) / (2 * math.pi)
    heights = []
    for f in (0.3 * f11, 0.8 * f11, f11, 1.5 * f11):
        m.set_inputs({"slosh_amplitude_m": 0.001, "slosh_frequency_Hz": f})
        heights.append(m.wave_height(A_i, A_i * H)[0])
    assert heights[2] == max(heights)
    assert heights[2] == pytest.approx(0.001 * 2 * 1.8412 * math.tanh(1.8412 * H / R) / (1.8412**2 - 1) / (2 * 0.07),
                                       rel=0.02)


def test_bulk_flash_limits_the_liquid_superheat_during_a_vent():
    tank = {"shape": "sphere", "radius_m": 0.8, "wall_heat_capacity_J_per_K": 1e5}
    sc = _scenario(tank, 2.0e5, 23.5, _tsat(2.0e5), 23.0, 0.6, 900.0, [(0.0, {"mdot_v_out_kg_s": 0.004})])
    t = np.linspace(0, 900, 10)
    on = ns.simulate(sc, law="mcadams", t_eval=t)
    off = ns.simulate(sc, law="mcadams", t_eval=t, bulk_phase_change=False)
    sup_on = max(T - _tsat(p) for T, p in zip(on.T_l, on.p))
    sup_off = max(T - _tsat(p) for T, p in zip(off.T_l, off.p))
    assert sup_off > 1.0 and sup_on < 0.3
    assert on.p[-1] > off.p[-1] + 1e4  # the flash vapour holds the pressure up


def test_stratified_liquid_has_a_warm_surface_layer_and_pressurises_faster():
    sc = _upright(22.0, 21.5, duration=3600.0, steps=[(0.0, {"Q_aw_W": 1000.0})])
    mixed = ns.simulate(sc, law="mcadams", t_eval=[0.0, 3600.0])
    strat = ns.simulate(sc, law="mcadams", t_eval=[0.0, 3600.0], liquid_layers=3)
    T = strat.T_layers[-1]
    assert T[0] > T[-1] + 0.2  # warm surface layer over the bulk
    assert strat.T_l[-1] == pytest.approx(np.average(T, weights=strat.y[-1][strat.model.i_m]), rel=1e-12)
    assert strat.p[-1] > mixed.p[-1] + 1e3


def test_helium_adds_its_partial_pressure_and_biases_the_metadata():
    sc = _upright(22.0, 21.5, duration=300.0)
    res = ns.simulate_run(sc, law="mcadams", mechanisms={"noncondensable_mol": 200.0}, noise="none")
    tr = res["trajectory"]
    V_v = tr.model.shape.volume * (1 - tr.fill)
    assert tr.p - tr.p_h2 == pytest.approx(200.0 * ns.R_GAS * tr.T_v / V_v, rel=1e-9)
    assert res["metadata"]["initial"]["p_v_Pa"] == pytest.approx(1.2e5, rel=1e-12)  # sensors read the total
    assert tr.p_h2[0] < 1.2e5 - 5e3
    assert res["truth_record"]["initial_true"]["helium_mol"] == 200.0


def test_normal_hydrogen_property_model_is_a_small_mismatch():
    assert abs(_tsat(1.5e5, "Hydrogen") - _tsat(1.5e5)) < 1.0
    sc = _upright(23.0, 22.0, p=1.5e5, duration=1200.0, steps=[(0.0, {"Q_aw_W": 500.0})])
    ref = ns.simulate(sc, law="mcadams", t_eval=[0.0, 1200.0])
    nh = ns.simulate(sc, law="mcadams", t_eval=[0.0, 1200.0], property_model="normal_hydrogen")
    assert nh.p[-1] != pytest.approx(ref.p[-1], rel=1e-3)
    assert nh.p[-1] == pytest.approx(ref.p[-1], rel=0.2)


def test_light_wall_scenario_is_stiff_but_integrates():
    tr = ns.simulate("ellipsoidal_light_wall", law="paper_printed", t_eval=np.arange(0.0, 1201.0, 60.0),
                     duration_s=1200.0)
    assert np.ptp(tr.T_w) > 3.0
    assert tr.n_rhs < 5000


def test_failure_names_the_time_and_the_state():
    tank = {"shape": "sphere", "radius_m": 0.5, "wall_heat_capacity_J_per_K": 2e4}
    sc = _scenario(tank, 1.5e5, 23.0, _tsat(1.5e5), 22.0, 0.3, 3600.0, [(0.0, {"mdot_v_out_kg_s": 0.05})])
    with pytest.raises(ns.SimulationError, match=r"t = [0-9.]+ s: .*(state|p=)"):
        ns.simulate(sc, law="mcadams")


# =============================================================================== scenarios
def test_scenarios_are_complete():
    assert len(ns.SCENARIOS) >= 6
    vols = {k: ns.make_shape(sc["tank"]).volume for k, sc in ns.SCENARIOS.items()}
    assert vols["upright_13m3"] == pytest.approx(13.57, rel=0.01)
    assert vols["tank_4p9m3"] == pytest.approx(4.9, rel=0.01)
    assert vols["large_1600m3_drain"] == pytest.approx(1600.0, rel=0.02)
    assert {sc["tank"]["shape"] for sc in ns.SCENARIOS.values()} == {
        "vertical_cylinder", "vertical_cylinder_elliptical_heads", "sphere", "horizontal_cylinder"}
    assert ns.SCENARIOS["ellipsoidal_light_wall"]["tank"]["wall_heat_capacity_J_per_K"] <= 3e4
    for sc in ns.SCENARIOS.values():
        ns.segments(sc["steps"], sc["duration_s"])  # valid schedules


@pytest.mark.parametrize("law", DYNAMIC_LAWS)
def test_large_tank_drain_goes_below_0p7_bar(law):
    tr = ns.simulate("large_1600m3_drain", law=law, t_eval=np.arange(0.0, 5401.0, 300.0))
    assert tr.p[0] == pytest.approx(1.1e5) and tr.p.min() < 0.7e5
    assert tr.fill[-1] < 0.4


def test_wide_span_scenario_spans_0p5_to_10_bar():
    tr = ns.simulate("wide_span_0p5_10bar", law="mcadams")
    assert tr.p.min() <= 0.5e5 and tr.p.max() >= 10e5


def test_random_scenarios_are_plausible():
    for seed in range(30):
        sc = ns.random_scenario(seed)
        assert sc == ns.random_scenario(seed)  # reproducible
        g = ns.make_shape(sc["tank"])
        assert 0.9 <= g.volume <= 210.0
        assert 0.2 <= sc["initial"]["fill_ratio"] <= 0.9
        assert sc["initial"]["T_l_K"] <= _tsat(sc["initial"]["p_Pa"]) + 1e-9 < sc["initial"]["T_v_K"]
        ns.segments(sc["steps"], sc["duration_s"])
    tr = ns.simulate("random_7", law="slosh_energy", t_eval=np.arange(0.0, 1801.0, 60.0), duration_s=1800.0)
    assert np.max(np.abs(tr.mass_balance_error())) < 1e-10 * tr.mass[0]


# =============================================================================== wall, mechanisms, numerics
def test_wall_material_changes_node_with_its_temperature():
    """Draining with no heat transfer and no wall conduction: the wet wall that falls dry carries its
    temperature into the dry node (a mixing rule), the wet node keeps its temperature and the
    capacity-averaged wall temperature does not move."""
    tank = {"shape": "vertical_cylinder", "radius_m": 0.8, "height_m": 2.0, "wall_heat_capacity_J_per_K": 1.5e5}
    sc = _scenario(tank, 1.5e5, 23.0, 21.0, 21.0, 0.7, 600.0, [(0.0, {"mdot_l_out_kg_s": 0.15})])
    sc["initial"]["T_w_dry_K"] = 25.0
    tr = ns.simulate(sc, law="constant", h_constant=(0.0, 0.0, 0.0, 0.0), wall_conductivity_W_mK=0.0,
                     t_eval=np.linspace(0.0, 600.0, 7))
    g = tr.model.shape
    A_w = g.wall_area

    def c_dry(level: float) -> float:
        return 1.5e5 * (1 - (0.01 + 0.98 * g.wetted_area(level) / A_w))

    assert tr.fill[-1] < 0.5  # the level really fell
    expected = (c_dry(tr.level[0]) * 25.0 + (c_dry(tr.level) - c_dry(tr.level[0])) * 21.0) / c_dry(tr.level)
    assert tr.T_w_nodes[:, 1] == pytest.approx(expected, abs=1e-6)
    assert tr.T_w_nodes[:, 0] == pytest.approx(21.0, abs=1e-6)  # solver tolerance
    assert np.ptp(tr.T_w) < 1e-9


def _mechanism_scenario() -> dict:
    tank = {"shape": "vertical_cylinder", "radius_m": 0.8, "height_m": 2.0, "wall_heat_capacity_J_per_K": 1.5e5}
    steps = [(0.0, {"Q_aw_W": 200.0, "mdot_v_in_kg_s": 0.002, "T_v_in_K": 50.0, "p_v_in_Pa": 5e5}),
             (300.0, {"mdot_v_in_kg_s": 0.0, "mdot_l_in_kg_s": 0.03, "T_l_in_K": 20.5}),
             (600.0, {"mdot_l_in_kg_s": 0.0, "mdot_v_out_kg_s": 0.002})]
    return _scenario(tank, 1.5e5, 23.0, 21.4, 22.0, 0.5, 900.0, steps)


# mechanism, value, {channel: sign of (with - without) at 300/600/900 s}
MECHANISM_SIGNS = [
    ("heat_leak_liquid_W", 300.0, {"p_v_Pa": 1, "T_l_K": 1}),
    ("heat_leak_vapor_W", 100.0, {"p_v_Pa": 1, "T_v_K": 1}),
    ("heat_leak_wall_W", 300.0, {"p_v_Pa": 1, "T_w_K": 1}),
    ("vapor_leak_kg_s", 5e-4, {"p_v_Pa": -1, "T_v_K": -1}),
    ("liquid_leak_kg_s", 5e-3, {"H_l_m": -1, "p_v_Pa": -1}),
    ("inflow_meter_bias", 0.2, {"p_v_Pa": 1}),
    ("noncondensable_mol", 50.0, {"p_v_Pa": 1}),
    ("wall_heat_capacity_error", -0.5, {"T_w_K": 1, "p_v_Pa": 1}),
]


@pytest.mark.parametrize("name,value,signs", MECHANISM_SIGNS, ids=[m[0] for m in MECHANISM_SIGNS])
def test_hidden_mechanisms_act_in_the_expected_direction(name, value, signs):
    t = [0.0, 300.0, 600.0, 900.0]
    base = ns.simulate(_mechanism_scenario(), t_eval=t)
    tr = ns.simulate(_mechanism_scenario(), mechanisms={name: value}, t_eval=t)
    for ch, sign in signs.items():
        d = (tr.sensors[ch] - base.sensors[ch])[1:]
        assert np.all(sign * d > 0), (ch, d)
    assert tr.p[0] == pytest.approx(base.p[0], rel=1e-12)  # the metadata's t0 reading is the same
    if name == "inflow_meter_bias":
        assert tr.M_in[-1] == pytest.approx(1.2 * base.M_in[-1], rel=1e-9)
    if name == "liquid_leak_kg_s":
        assert tr.M_out[-1] - base.M_out[-1] == pytest.approx(900 * 5e-3, rel=1e-9)


def test_sensor_biases_shift_only_their_channel():
    t = [0.0, 450.0, 900.0]
    base = ns.simulate(_mechanism_scenario(), t_eval=t)
    tr = ns.simulate(_mechanism_scenario(), t_eval=t, mechanisms={
        "pressure_sensor_bias_Pa": 2000.0, "temperature_sensor_bias_K": -0.4, "temperature_bias_channel": "T_w"})
    shift = {"p_v_Pa": 2000.0, "T_w_K": -0.4}
    for ch in ns.OBS_COLUMNS:
        assert tr.sensors[ch] - base.sensors[ch] == pytest.approx(shift.get(ch, 0.0), abs=1e-9)


def test_evaluation_budget_is_enforced():
    with pytest.raises(ns.SimulationError, match="right-hand-side evaluations"):
        ns.simulate("upright_13m3", max_rhs=50)


def test_script_runs_as_a_program(tmp_path):
    import subprocess
    import sys

    out = subprocess.run([sys.executable, str(HERE / "nodal_sim.py"), "--list"], capture_output=True, text=True,
                         timeout=60, check=True).stdout
    assert "upright_13m3" in out and "random_SEED" in out
