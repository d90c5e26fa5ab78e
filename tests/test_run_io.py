"""Runs (tankode.run), reading and writing them (tankode.run_io), and the input schedule (tankode.schedule)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from tankode.run import (
    INPUT_NAMES,
    NOISE_KEYS,
    OBS_CHANNELS,
    InitialState,
    Observations,
    Run,
    RunFormatError,
    RunValueError,
    TankSpec,
)
from tankode.run_io import read_run, read_timeseries_csv, write_run
from tankode.schedule import Schedule, ScheduleError, merge_breakpoints

from mhtb_data import MHTB, needs_mhtb


# ============================================================================ real data
@needs_mhtb
@pytest.mark.parametrize(
    "name, counts, q_aw, duration, fill",
    [
        ("P263968K", {"p_v_Pa": 40, "T_v_K": 38, "T_l_K": 8, "T_w_K": 0, "H_l_m": 0}, 18.8, 66446.0, 0.25),
        ("P263981D", {"p_v_Pa": 41, "T_v_K": 38, "T_l_K": 38, "T_w_K": 0, "H_l_m": 0}, 54.1, 19591.0, 0.9),
    ],
)
def test_read_mhtb(name, counts, q_aw, duration, fill):
    run = read_run(MHTB / f"{name}.json")
    assert run.name == name and run.fluid == "ParaHydrogen"
    assert run.observations.counts() == counts
    assert run.observations.measured_channels == tuple(c for c, n in counts.items() if n)
    # Q_aw_W is on every row with one value: a single constant segment, no breakpoints.
    assert run.inputs.t0_s == 0.0 and run.t0_s == 0.0
    assert run.inputs.breakpoints(0.0, run.t_end_s).size == 0
    assert run.inputs.get("Q_aw_W", 1234.5) == q_aw
    assert run.inputs.used_inputs() == ("Q_aw_W",)
    assert run.tank.wall_heat_capacity_J_per_K is None
    assert run.tank.shape == "vertical_cylinder_elliptical_heads" and run.tank.volume_m3 == 18.09
    assert run.initial.T_w_K is None and run.initial.T_w0_K == run.initial.T_l_K
    assert run.initial.fill_ratio == fill
    assert run.duration_s == duration and run.t_end_s == duration
    assert set(run.noise_std) == {"p_v", "T_v", "T_l"}
    t, v = run.observations.channel("p_v_Pa")
    assert t.size == counts["p_v_Pa"] and np.all(np.diff(t) > 0) and np.all((v > 1e5) & (v < 3e5))


@needs_mhtb
def test_mhtb_initial_state_contradicting_the_first_samples_is_reported_and_can_be_replaced():
    (note,) = read_run(MHTB / "P263968K.json").initial_disagreements()
    assert "initial.T_v_K = 21.01 but T_v_K = 24.8394" in note and "P263968K.csv, first row" in note
    assert "38 sigma" in note
    assert read_run(MHTB / "P263981D.json").initial_disagreements() == ()  # its ullage is first read at 30 s
    run = read_run(MHTB / "P263968K.json").with_measured_initial()
    assert (run.initial.p_v_Pa, run.initial.T_v_K, run.initial.T_l_K) == (122014.0, 24.8394, 20.9645)
    assert run.initial.fill_ratio == 0.25 and run.initial_disagreements() == ()


def test_measured_initial_takes_only_the_channels_sampled_at_the_start():
    obs = Observations.from_channels({"T_v_K": ([0.0, 10.0], [31.2, 31.5]), "p_v_Pa": ([5.0], [4.9e5])})
    run = Run(name="r", fluid="ParaHydrogen", tank=TankSpec.from_dict({"shape": "sphere", "radius_m": 1.0}),
              initial=InitialState(p_v_Pa=4.8e5, T_v_K=30.0, T_l_K=20.1, fill_ratio=0.5),
              noise_std={"p_v": 1e3, "T_v": 0.2}, observations=obs, duration_s=20.0)
    (note,) = run.initial_disagreements()
    assert note.startswith("r: initial.T_v_K = 30 but T_v_K = 31.2") and "6 sigma" in note
    assert run.initial_disagreements(n_sigma=7.0) == ()
    moved = run.with_measured_initial().initial
    assert (moved.T_v_K, moved.p_v_Pa, moved.T_l_K) == (31.2, 4.8e5, 20.1)  # p is first read at 5 s


@needs_mhtb
@pytest.mark.parametrize("name", ["P263968K", "P263981D"])
def test_read_peer_prediction_csv(name):
    obs, sched = read_timeseries_csv(MHTB / f"{name}.ebm.csv")
    assert sched is None  # no input columns in the peer's file
    assert set(obs.measured_channels) == {"p_v_Pa", "T_v_K", "T_l_K"}
    assert len(obs) > 50


@needs_mhtb
def test_mhtb_round_trip(tmp_path):
    run = read_run(MHTB / "P263981D.json")
    j, _ = write_run(run, tmp_path)
    assert read_run(j) == run


# ============================================================================ round trip
def _synthetic_run(**changes) -> Run:
    rng = np.random.default_rng(0)
    t_p = np.cumsum(rng.uniform(0.5, 30.0, 200))  # irregular
    t_T = np.arange(0.0, 3000.0, 7.3)  # another clock
    t_H = np.array([0.1 + 0.2, 1800.0, 2999.9])  # awkward floats; one at an input change
    obs = Observations.from_channels(
        {
            "p_v_Pa": (t_p[t_p < 3000], 4.8e5 + 1e3 * rng.standard_normal((t_p < 3000).sum())),
            "T_v": (t_T, 32.0 + rng.standard_normal(t_T.size) / 3),
            "T_l_K": (t_T[::5], np.full(t_T[::5].size, 20.09)),
            "H_l_m": (t_H, np.array([1.4, 1.41, -0.0])),
        }
    )
    inputs = Schedule.from_steps(
        [
            (0.0, {"Q_aw_W": 50.0}),
            (600.0, {"slosh_amplitude_m": 0.01, "slosh_frequency_Hz": 0.57}),
            (1000.0, {"Q_aw_W": 50.0}),  # a repeated value: not a change
            (1800.0, {"mdot_v_in_kg_s": 4.2e-3, "T_v_in_K": 32.0, "p_v_in_Pa": 5e5}),
            (2400.0 + 1 / 3, {"mdot_v_in_kg_s": 0.0, "slosh_amplitude_m": 0.0}),
        ],
        t_end=3000.0,
    )
    kw = dict(
        name="synthetic_1",
        fluid="parahydrogen",  # an alias: normalised to ParaHydrogen
        source="test_run_io synthetic",
        tank=TankSpec("vertical_cylinder", {"radius_m": 0.9, "height_m": 2.2}, None, 2.44e6),
        initial=InitialState(p_v_Pa=4.8e5, T_v_K=32.0, T_l_K=20.09, T_w_K=29.1, fill_ratio=0.65),
        noise_std={"p_v": 2000.0, "T_v": 0.2, "T_l": 0.2, "H_l": 5e-4},
        duration_s=3000.0,
        observations=obs,
        inputs=inputs,
    )
    kw.update(changes)
    return Run(**kw)


def test_round_trip_is_exact(tmp_path):
    run = _synthetic_run()
    assert run.fluid == "ParaHydrogen"
    j, c = write_run(run, tmp_path / "out")
    assert (j.name, c.name) == ("synthetic_1.json", "synthetic_1.csv")
    back = read_run(j)
    assert back == run
    assert back.path == str(j)
    # Bit-identical samples, NaN where not measured, -0.0 kept.
    assert np.array_equal(back.observations.values.view(np.int64)[~np.isnan(run.observations.values)],
                          run.observations.values.view(np.int64)[~np.isnan(run.observations.values)])
    assert np.array_equal(back.inputs.change_times(), [600.0, 1800.0, 2400.0 + 1 / 3])
    header = c.read_text().splitlines()[0].split(",")
    # Only measured channels and inputs that are ever non-zero are written.
    assert header == ["t_s", "p_v_Pa", "T_v_K", "T_l_K", "H_l_m", "mdot_v_in_kg_s", "T_v_in_K", "p_v_in_Pa",
                      "slosh_amplitude_m", "slosh_frequency_Hz", "Q_aw_W"]
    # A second round trip writes identical files.
    j2, c2 = write_run(back, tmp_path / "again")
    assert c2.read_text() == c.read_text() and j2.read_text() == j.read_text()


def test_round_trip_late_first_sample_and_no_inputs(tmp_path):
    obs = Observations.from_channels({"p_v": ([5.0, 9.5], [1e5, 1.1e5])})
    run = _synthetic_run(observations=obs, inputs=Schedule.constant(0.0), duration_s=None,
                         noise_std={"p_v": 100.0}, initial=InitialState(p_v_Pa=1e5, T_v_K=21.0, T_l_K=20.0, fill_ratio=0.5))
    assert run.duration_s == 9.5 and run.t0_s == 0.0
    back = read_run(write_run(run, tmp_path)[0])
    assert back == run and back.t0_s == 0.0 and back.initial.T_w_K is None


# ============================================================================ run validation: files
_BASE_CSV = """t_s,p_v_Pa,T_v_K,T_l_K,mdot_v_out_kg_s,Q_aw_W
0,480000,32.0,20.09,0,50
10,481000,,,,
20,,32.1,,,
30,482000,,20.1,0.001,
40,483000,32.2,,,
"""


def _base_meta() -> dict:
    return {
        "name": "case1",
        "fluid": "ParaHydrogen",
        "source": "crafted",
        "tank": {"shape": "vertical_cylinder", "radius_m": 0.9, "height_m": 2.2, "wall_heat_capacity_J_per_K": 2.44e6},
        "initial": {"p_v_Pa": 4.8e5, "T_v_K": 32.0, "T_l_K": 20.09, "T_w_K": 29.1, "fill_ratio": 0.65},
        "noise_std": {"p_v": 2000.0, "T_v": 0.2, "T_l": 0.2},
        "duration_s": 60,
        "timeseries": "case1.csv",
    }


def _write_case(tmp_path, *, meta=None, csv_text=_BASE_CSV, json_text=None) -> Path:
    j = tmp_path / "case1.json"
    j.write_text(json_text if json_text is not None else json.dumps(meta or _base_meta(), indent=2))
    (tmp_path / "case1.csv").write_text(csv_text)
    return j


def _csv_with(line: int, column: str, value: str) -> str:
    rows = [r.split(",") for r in _BASE_CSV.splitlines()]
    rows[line - 1][rows[0].index(column)] = value
    return "\n".join(",".join(r) for r in rows) + "\n"


def _line_of(text: str, needle: str) -> int:
    return next(i for i, l in enumerate(text.splitlines(), 1) if needle in l)


def test_base_case_is_valid(tmp_path):
    run = read_run(_write_case(tmp_path))
    assert run.inputs.change_times().tolist() == [30.0]
    assert run.inputs.get("mdot_v_out_kg_s", 35.0) == 0.001 and run.inputs.get("Q_aw_W", 35.0) == 50.0


@pytest.mark.parametrize(
    "csv_text, line, column, fragment",
    [
        (_BASE_CSV.replace("T_l_K,", "p_v_bar,", 1), 1, "p_v_bar", "did you mean"),
        (_BASE_CSV.replace("T_l_K,", "T_v_K,", 1), 1, "T_v_K", "duplicate column"),
        (_BASE_CSV.replace("t_s,", "time,", 1), 1, "time", "first column must be 't_s'"),
        (_csv_with(5, "t_s", "15"), 5, "t_s", "strictly increasing"),
        (_csv_with(4, "mdot_v_out_kg_s", "-1"), 4, "mdot_v_out_kg_s", "negative"),
        (_csv_with(3, "Q_aw_W", "nan"), 3, "Q_aw_W", "not finite"),
        (_csv_with(3, "p_v_Pa", "4.8"), 3, "p_v_Pa", "is it in bar"),
        (_csv_with(5, "T_l_K", "-253.06"), 5, "T_l_K", "Celsius"),
        (_csv_with(6, "T_v_K", "5.0"), 6, "T_v_K", "triple point"),
        (_csv_with(4, "T_v_K", "32,1"), 4, None, "cells"),
        (_csv_with(4, "T_v_K", "abc"), 4, "T_v_K", "not a number"),
        (_csv_with(2, "p_v_Pa", "inf"), 2, "p_v_Pa", "not finite"),
    ],
    ids=["unknown-column", "duplicate-column", "no-t_s", "t-decreasing", "negative-flow", "nan-input",
         "pressure-in-bar", "temperature-in-celsius", "below-triple", "extra-cell", "non-numeric", "inf-obs"],
)
def test_csv_errors_name_file_line_column(tmp_path, csv_text, line, column, fragment):
    with pytest.raises(RunFormatError) as ei:
        read_run(_write_case(tmp_path, csv_text=csv_text))
    e = ei.value
    assert Path(e.path).name == "case1.csv" and e.line == line and e.column == column
    msg = str(e)
    assert msg.startswith(f"{e.path}:{line}:") and "case1.csv" in msg
    if column is not None:
        assert f"column '{column}'" in msg
    assert fragment in msg


def test_unknown_column_suggests_closest(tmp_path):
    with pytest.raises(RunFormatError, match="did you mean 'p_v_Pa'"):
        read_run(_write_case(tmp_path, csv_text=_BASE_CSV.replace("T_l_K,", "p_v_bar,", 1)))


def test_input_flow_without_inlet_state(tmp_path):
    text = "t_s,p_v_Pa,mdot_v_in_kg_s\n0,1e5,0\n10,,0.002\n"
    meta = _base_meta() | {"noise_std": {"p_v": 100.0}}
    with pytest.raises(RunFormatError) as ei:
        read_run(_write_case(tmp_path, meta=meta, csv_text=text))
    assert (ei.value.line, ei.value.column) == (3, "T_v_in_K")
    assert "mdot_v_in_kg_s" in str(ei.value)


def test_empty_input_cells_carry_previous_value(tmp_path):
    text = "t_s,p_v_Pa,Q_aw_W,mdot_v_out_kg_s\n0,1e5,,\n10,,20,\n20,,,0.5\n30,1.2e5,,\n"
    meta = _base_meta() | {"noise_std": {"p_v": 100.0}}
    run = read_run(_write_case(tmp_path, meta=meta, csv_text=text))
    assert run.inputs.at(np.array([0.0, 10.0, 25.0, 35.0]))[:, [INPUT_NAMES.index("Q_aw_W"), INPUT_NAMES.index("mdot_v_out_kg_s")]].tolist() == [
        [0.0, 0.0], [20.0, 0.0], [20.0, 0.5], [20.0, 0.5]]


def test_measured_channel_without_noise_names_both(tmp_path):
    meta = _base_meta()
    del meta["noise_std"]["T_l"]
    with pytest.raises(RunFormatError) as ei:
        read_run(_write_case(tmp_path, meta=meta))
    e = ei.value
    assert Path(e.path).name == "case1.csv" and e.line == 2 and e.column == "T_l_K"
    assert "noise_std" in str(e) and "case1.json" in str(e) and "'T_l'" in str(e)


def _json_error(tmp_path, meta=None, json_text=None) -> RunFormatError:
    with pytest.raises(RunFormatError) as ei:
        read_run(_write_case(tmp_path, meta=meta, json_text=json_text))
    assert Path(ei.value.path).name == "case1.json"
    assert str(ei.value).startswith(f"{ei.value.path}:{ei.value.line}")
    return ei.value


def _meta_with(path: str, value=None, delete=False) -> dict:
    meta = _base_meta()
    *parents, last = path.split(".")
    d = meta
    for p in parents:
        d = d[p]
    if delete:
        del d[last]
    else:
        d[last] = value
    return meta


@pytest.mark.parametrize(
    "meta, key, needle, fragment",
    [
        (_meta_with("initial.fill_ratio", 1.2), "initial.fill_ratio", '"fill_ratio"', "(0, 1)"),
        (_meta_with("fluid", "Hydrogenn"), "fluid", '"fluid"', "did you mean 'Hydrogen'"),
        (_meta_with("initial.p_v_Pa", 4.8), "initial.p_v_Pa", '"p_v_Pa"', "is it in bar"),
        (_meta_with("initial.T_l_K", -253.06), "initial.T_l_K", '"T_l_K"', "Celsius"),
        (_meta_with("noise_sdt", {}), "noise_sdt", '"noise_sdt"', "did you mean 'noise_std'"),
        (_meta_with("initial.fill_ratio", delete=True), "initial.fill_ratio", '"initial"', "missing"),
        (_meta_with("initial", delete=True), "initial", "{", "missing"),  # the top-level object
        (_meta_with("tank.height_m", "2.2"), "tank.height_m", '"height_m"', "must be a number"),
        (_meta_with("tank.hieght_m", 2.2), "tank.hieght_m", '"hieght_m"', "did you mean 'height_m'"),
        (_meta_with("tank.shape", "cylinder"), "tank.shape", '"shape"', "unknown shape"),
        (_meta_with("noise_std.p", 1.0), "noise_std.p", '"p"', "unknown sensor"),
        (_meta_with("noise_std.T_v", 0.0), "noise_std.T_v", '"T_v": 0', "> 0"),
        (_meta_with("name", 3), "name", '"name"', "must be a string"),
        (_meta_with("timeseries", "nope.csv"), "timeseries", '"timeseries"', "not found"),
    ],
    ids=["fill-ratio", "unknown-fluid", "initial-p-bar", "initial-T-celsius", "unknown-key", "missing-nested",
         "missing-top", "wrong-type", "unknown-tank-key", "unknown-shape", "noise-key", "noise-zero",
         "name-type", "missing-csv"],
)
def test_json_errors_name_file_line_key(tmp_path, meta, key, needle, fragment):
    e = _json_error(tmp_path, meta=meta)
    text = (tmp_path / "case1.json").read_text()
    assert e.column == key and f"key '{key}'" in str(e)
    assert e.line == _line_of(text, needle)
    assert fragment in str(e)


def test_undecodable_bytes_absurd_levels_and_spans_name_their_line(tmp_path):
    # Bytes that are not UTF-8 (a Latin-1 degree sign in a CSV, an e-acute in the JSON).
    csv_bytes = _BASE_CSV.replace("20.1,", "20.1\u00b0,", 1).encode("latin-1")
    j = _write_case(tmp_path)
    (tmp_path / "case1.csv").write_bytes(csv_bytes)
    with pytest.raises(RunFormatError) as ei:
        read_run(j)
    assert (ei.value.line, ei.value.column) == (5, 16) and "0xb0 is not UTF-8" in str(ei.value)
    meta = json.dumps(_base_meta(), indent=2).replace('"crafted"', '"cr\u00e9e"').encode("latin-1")
    (tmp_path / "case1.csv").write_text(_BASE_CSV)
    j.write_bytes(meta)
    with pytest.raises(RunFormatError) as ei:
        read_run(j)
    assert Path(ei.value.path).name == "case1.json" and ei.value.line == _line_of(meta.decode("latin-1"), "source")
    # A level far above the tank (2.2 m high): its CSV row.
    level = "t_s,p_v_Pa,T_v_K,T_l_K,H_l_m\n0,480000,32.0,20.09,1.4\n10,481000,32.0,20.09,50\n"
    m = _base_meta()
    m["noise_std"]["H_l"] = 0.001
    with pytest.raises(RunFormatError) as ei:
        read_run(_write_case(tmp_path, meta=m, csv_text=level))
    assert (Path(ei.value.path).name, ei.value.line, ei.value.column) == ("case1.csv", 3, "H_l_m")
    assert "above 1.5 times the tank's inner height" in str(ei.value)
    # A span only a wrong time unit makes: by duration_s, or by the last time stamp.
    from tankode.run import MAX_SPAN_S

    m = _base_meta()
    m["duration_s"] = 2 * MAX_SPAN_S
    with pytest.raises(RunFormatError, match="duration_s.*beyond 1e\\+09 s"):
        read_run(_write_case(tmp_path, meta=m))
    for duration in (None, 60):  # the time stamp is the cause whether or not a short duration is declared
        m["duration_s"] = duration
        with pytest.raises(RunFormatError) as ei:
            read_run(_write_case(tmp_path, meta={k: v for k, v in m.items() if v is not None},
                                 csv_text=_BASE_CSV + "1e300,,,20.1,,\n"))
        assert (ei.value.line, ei.value.column) == (7, "t_s") and "time unit" in str(ei.value)
    with pytest.raises(RunValueError, match="duration_s"):  # a run built in code is held to the same span
        Run(name="r", fluid="ParaHydrogen", tank=read_run(_write_case(tmp_path)).tank,
            initial=read_run(_write_case(tmp_path)).initial, duration_s=2 * MAX_SPAN_S)


def test_json_syntax_error(tmp_path):
    text = json.dumps(_base_meta(), indent=2).replace('"source"', '"source" "x",', 1)
    e = _json_error(tmp_path, json_text=text)
    assert "JSON syntax" in str(e)
    assert e.line == _line_of(text, '"source"') and isinstance(e.column, int)


def test_json_duplicate_key(tmp_path):
    text = json.dumps(_base_meta(), indent=2).replace('"source": "crafted"', '"fluid": "Nitrogen"', 1)
    e = _json_error(tmp_path, json_text=text)
    assert e.column == "fluid" and "duplicate" in str(e)
    assert e.line == _line_of(text, '"Nitrogen"')


def test_fluid_alias_accepted(tmp_path):
    meta = _meta_with("fluid", "parahydrogen")
    assert read_run(_write_case(tmp_path, meta=meta)).fluid == "ParaHydrogen"


# ============================================================================ run validation: code
def test_run_in_code_names_parameter_and_range():
    with pytest.raises(ValueError, match=r"initial\.fill_ratio.*\(0, 1\)"):
        InitialState(p_v_Pa=1e5, T_v_K=21.0, T_l_K=20.0, fill_ratio=1.2)
    with pytest.raises(ValueError, match=r"initial\.p_v_Pa.*between 1e3 and 1e8.*bar"):
        InitialState(p_v_Pa=1.2, T_v_K=21.0, T_l_K=20.0, fill_ratio=0.5)
    with pytest.raises(ValueError, match=r"noise_std\.T_w.*T_w_K"):
        obs = Observations.from_channels({"T_w_K": ([0.0, 1.0], [25.0, 25.1])})
        _synthetic_run(observations=obs, inputs=None, duration_s=None)
    with pytest.raises(ValueError, match=r"T_v_in_K.*Celsius"):
        Schedule.from_steps([(0, {"mdot_v_in_kg_s": 1e-3, "T_v_in_K": -240.0, "p_v_in_Pa": 5e5})])
    with pytest.raises(ValueError, match=r"inputs\.T_v_in_K.*triple point of ParaHydrogen"):
        _synthetic_run(inputs=Schedule.from_steps([(0, {"mdot_v_in_kg_s": 1e-3, "T_v_in_K": 3.0, "p_v_in_Pa": 5e5})]))
    # A duration that ends before the data (digitised runs) drops nothing: the run ends at its last sample.
    short = _synthetic_run(duration_s=100.0)
    assert short.t_end_s > short.t0_s + 100.0
    assert "no sample is dropped" in short.notes()[0]
    with pytest.raises(ValueError, match="fluid.*Hydrogenn"):
        _synthetic_run(fluid="Hydrogenn")
    with pytest.raises(ValueError, match="tank.radius_m"):
        TankSpec("sphere", {"radius_m": -1.0})


def test_observations():
    obs = Observations(np.array([0.0, 1.0, 2.0]),
                       np.array([[1e5, np.nan, np.nan, np.nan, np.nan],
                                 [np.nan] * 5,  # measures nothing: dropped
                                 [np.nan, 20.0, np.nan, np.nan, np.nan]]))
    assert len(obs) == 2 and obs.mask.sum() == 2
    t, v = obs.channel("T_v")
    assert t.tolist() == [2.0] and v.tolist() == [20.0]
    assert obs.channel("p_v_Pa")[0].tolist() == [0.0]
    with pytest.raises(KeyError, match="did you mean"):
        obs.channel("p_v_bar")
    with pytest.raises(ValueError, match="strictly increasing"):
        Observations(np.array([1.0, 1.0]), np.ones((2, 5)))
    assert len(OBS_CHANNELS) == len(NOISE_KEYS) == 5


# ============================================================================ geometry delegation
def test_tank_volume_disagreement_is_reported(tmp_path):
    meta = _meta_with("tank.volume_m3", 1.1 * math.pi * 0.9**2 * 2.2)  # 10 % off
    e = _json_error(tmp_path, meta=meta)
    assert e.column in ("tank", "tank.volume_m3")
    assert "volume" in str(e).lower()
    ok = _meta_with("tank.volume_m3", math.pi * 0.9**2 * 2.2)
    assert read_run(_write_case(tmp_path, meta=ok)).tank.volume_m3 == pytest.approx(5.598, rel=1e-3)


# ============================================================================ schedule
def _sched() -> Schedule:
    return Schedule.from_steps(
        [(0, {}), (600, {"slosh_amplitude_m": 0.01, "slosh_frequency_Hz": 0.57}),
         (900, {"slosh_amplitude_m": 0.01}),  # no real change
         (1800, {"mdot_v_in_kg_s": 4.2e-3, "T_v_in_K": 32.0, "p_v_in_Pa": 5e5}),
         (2400, {"mdot_v_in_kg_s": 0.0})],
        t_end=3600,
    )


def test_schedule_at():
    s = _sched()
    ia, iv = INPUT_NAMES.index("slosh_amplitude_m"), INPUT_NAMES.index("mdot_v_in_kg_s")
    assert s.at(0.0).shape == (len(INPUT_NAMES),) and not s.at(0.0).any()
    assert s.at(599.999)[ia] == 0.0 and s.at(600.0)[ia] == 0.01  # right-continuous
    v = s.at(np.array([0.0, 1800.0, 2399.0, 2400.0, 1e6]))
    assert v.shape == (5, len(INPUT_NAMES))
    assert v[:, iv].tolist() == [0.0, 4.2e-3, 4.2e-3, 0.0, 0.0]
    # Steps keep unmentioned inputs: the slosh stays on through the injection; T_v_in_K stays set.
    assert v[2, ia] == 0.01 and v[4, INPUT_NAMES.index("T_v_in_K")] == 32.0
    with pytest.raises(ValueError, match="before the start"):
        s.at(-1.0)


def test_schedule_breakpoints_only_real_changes():
    s = _sched()
    assert s.breakpoints(0.0, 3600.0).tolist() == [600.0, 1800.0, 2400.0]  # not 900
    assert s.breakpoints(600.0, 2400.0).tolist() == [1800.0]  # open interval
    assert s == s.compressed() and len(s.compressed().t_s) == 4


def test_schedule_segments():
    segs = _sched().segments(100.0, 2000.0)
    assert [(a, b) for a, b, _ in segs] == [(100.0, 600.0), (600.0, 1800.0), (1800.0, 2000.0)]
    assert segs[1][2][INPUT_NAMES.index("slosh_frequency_Hz")] == 0.57
    assert _sched().segments(5.0, 5.0) == []


def test_merge_breakpoints():
    a = _sched()
    b = Schedule.from_steps([(0, {"Q_aw_W": 10.0}), (600, {"Q_aw_W": 20.0}), (700, {"Q_aw_W": 30.0}), (5000, {"Q_aw_W": 0.0})])
    assert merge_breakpoints([a, b], 0.0, 3600.0).tolist() == [600.0, 700.0, 1800.0, 2400.0]
    assert merge_breakpoints([], 0.0, 1.0).size == 0


@pytest.mark.parametrize(
    "steps, name, t, fragment",
    [
        ([(0, {"mdot_v_out_kg_s": -1.0})], "mdot_v_out_kg_s", 0.0, "negative"),
        ([(0, {}), (5, {"slosh_frequency_Hz": -0.5})], "slosh_frequency_Hz", 5.0, "negative"),
        ([(0, {}), (5, {"Q_aw_W": float("nan")})], "Q_aw_W", 5.0, "not finite"),
        ([(0, {}), (5, {"mdot_l_in_kg_s": float("inf")})], "mdot_l_in_kg_s", 5.0, "not finite"),
        ([(0, {}), (7, {"mdot_l_in_kg_s": 1.0})], "T_l_in_K", 7.0, "not set"),
        ([(0, {}), (5, {"mdot_vin_kg_s": 1.0})], "mdot_vin_kg_s", 5.0, "did you mean 'mdot_v_in_kg_s'"),
        ([(0, {}), (0, {})], None, 0.0, "strictly increasing"),
    ],
)
def test_schedule_validation(steps, name, t, fragment):
    with pytest.raises(ScheduleError) as ei:
        Schedule.from_steps(steps)
    assert ei.value.name == name and ei.value.t_s == t and fragment in str(ei.value)
    if name:
        assert f"'{name}'" in str(ei.value)


def test_schedule_misc():
    assert Schedule.constant(Q_aw_W=3.0) == Schedule.from_steps([(0, {"Q_aw_W": 3.0}), (10, {})])
    assert Schedule.constant(Q_aw_W=3.0) != Schedule.constant(1.0, Q_aw_W=3.0)  # other start
    assert Schedule.constant(Q_aw_W=-3.0).get("Q_aw_W", 1.0) == -3.0  # heat loss is allowed
    with pytest.raises(ValueError, match="never act"):
        Schedule.from_steps([(0, {}), (10, {"Q_aw_W": 1.0})], t_end=10)
    with pytest.raises(ValueError, match="shape"):
        Schedule(np.array([0.0]), np.zeros((1, 3)))


def test_until_cuts_observations_and_inputs():
    from tankode.cases import case1
    from tankode.simulation import simulate
    from tankode.synthetic import solution_to_runs

    run = case1()
    (data,) = solution_to_runs(run, simulate(run))
    cut = data.until(1000.0)
    assert cut.t_end_s == 1000.0 and cut.observations.t_s[-1] == 1000.0
    assert list(cut.inputs.t_s) == [0.0, 600.0]
    np.testing.assert_array_equal(cut.inputs.at(900.0), data.inputs.at(900.0))
    with pytest.raises(ValueError, match="t_end_s"):
        data.until(5000.0)
