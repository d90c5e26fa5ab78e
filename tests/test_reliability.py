"""Hostile input and misuse: no data lost, no traceback, no spin, causes named, exact round trips."""

import json
import os
import shutil
import stat
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from tankode.cli import main
from tankode.run_io import read_run

from mhtb_data import MHTB, needs_mhtb


@pytest.fixture(scope="module")
def case3(tmp_path_factory):
    """A clean simulated copy of case 3 on disk: (json path, its folder)."""
    d = tmp_path_factory.mktemp("case3")
    assert main(["simulate", "case3", "--out", str(d)]) == 0
    return d / "case3.json"


def _variant(src: Path, dst: Path, meta=None, column=None) -> Path:
    """A copy of the run ``src`` in ``dst`` with metadata edits and one input column set from t = 0."""
    dst.mkdir(parents=True, exist_ok=True)
    d = json.loads(src.read_text())
    for key, value in (meta or {}).items():
        obj = d
        *path, last = key.split(".")
        for k in path:
            obj = obj[k]
        obj[last] = value
    (dst / src.name).write_text(json.dumps(d))
    lines = (src.parent / d["timeseries"]).read_text().splitlines()
    if column is not None:
        name, value = column
        header = lines[0].split(",")
        if name not in header:
            header.append(name)
            lines = [",".join(header)] + [row + "," for row in lines[1:]]
        i = header.index(name)
        rows = [row.split(",") for row in lines[1:]]
        for row in rows:
            row[i] = repr(float(value))
        lines = [lines[0]] + [",".join(r) for r in rows]
    (dst / d["timeseries"]).write_text("\n".join(lines) + "\n")
    return dst / src.name


def _error(capsys, argv) -> str:
    """Run the CLI, expect exit code 2 and exactly one line on stderr; return that line."""
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert "Traceback" not in err[0]
    return err[0]


# ------------------------------------------------------------------ outputs never replace inputs
def test_simulate_and_predict_refuse_to_write_over_their_input(case3, tmp_path, capsys):
    run = _variant(case3, tmp_path / "x")
    before = run.read_bytes(), (tmp_path / "x" / "case3.csv").read_bytes()
    assert "outputs never replace inputs" in _error(capsys, ["simulate", str(run), "--out", str(tmp_path / "x")])
    model = tmp_path / "model"
    # the model only has to exist: one iteration on the lumped wall (no fitted wall start)
    assert main(["assimilate", str(run), "--out", str(model), "--iters", "1", "--window", "3600", "--wall", "lumped", "--quiet"]) == 0
    capsys.readouterr()
    assert "outputs never replace inputs" in _error(capsys, ["predict", str(model), str(run), "--out", str(tmp_path / "x")])
    assert "outputs never replace inputs" in _error(capsys, ["predict", str(model), str(run), "--out", str(model)])
    assert (run.read_bytes(), (tmp_path / "x" / "case3.csv").read_bytes()) == before


@needs_mhtb
def test_a_folder_of_measured_runs_or_a_read_only_one_is_never_written(tmp_path, capsys):
    data = tmp_path / "data"
    shutil.copytree(MHTB, data)
    for p in data.iterdir():
        p.chmod(stat.S_IRUSR | stat.S_IWUSR)
    data.chmod(stat.S_IRWXU)
    run = str(MHTB / "P263981D.json")
    assert "tankode did not write" in _error(capsys, ["simulate", run, "--out", str(data)])
    data.chmod(stat.S_IRUSR | stat.S_IXUSR)  # marked read-only, as the shared data folder is
    try:
        assert "marked read-only" in _error(capsys, ["simulate", run, "--out", str(data / "sub")])
    finally:
        data.chmod(stat.S_IRWXU)
    assert not (data / "sub").exists()


def test_out_naming_a_file_and_a_folder_given_as_the_run(case3, tmp_path, capsys):
    f = tmp_path / "afile"
    f.write_text("x")
    assert "is an existing file" in _error(capsys, ["simulate", "case3", "--out", str(f)])
    assert "is a directory" in _error(capsys, ["simulate", str(case3.parent), "--out", str(tmp_path / "o")])
    assert "neither a case" in _error(capsys, ["simulate", str(tmp_path / "missing.json"), "--out", str(tmp_path / "o")])


# ------------------------------------------------------------------ refused pickles, resume
def test_a_missing_model_is_named_alone_not_led_by_the_run(case3, tmp_path, capsys):
    # The run file leads errors that name no file; one about the model directory names its own.
    line = _error(capsys, ["predict", str(tmp_path / "none"), str(case3), "--out", str(tmp_path / "p")])
    assert line.startswith(f"tankode predict: error: {tmp_path / 'none'}"), line
    assert str(case3) not in line, line


def test_a_bad_option_is_named_alone_not_led_by_the_run(case3, tmp_path, capsys):
    # A configuration's refusal is a fault of the options: the run file does not lead it.
    for argv in (["assimilate", str(case3), "--out", str(tmp_path / "a"), "--mode", "growing", "--window-start", "data"],
                 ["assimilate", str(case3), "--out", str(tmp_path / "b"), "--mechanism", "no_such:x=1"],
                 ["diagnose", str(case3), "--out", str(tmp_path / "c"), "--block", "-1"],
                 ["diagnose", str(case3), "--out", str(tmp_path / "d"), "--holdout", "2"],
                 ["diagnose", str(case3), str(case3), "--out", str(tmp_path / "e"), "--holdout", "0.2"]):
        line = _error(capsys, argv)
        assert line.startswith(f"tankode {argv[0]}: error: ") and str(case3) not in line, line


def test_refused_pickles_are_one_line_errors_without_the_unsafe_hint(case3, tmp_path, capsys):
    import pickle

    model = tmp_path / "model"
    model.mkdir()
    (model / "model.json").write_text(json.dumps({"format": "tankode-model-1", "fluid": "ParaHydrogen",
                                                  "closure": {"type": "ReferenceClosure", "config": {}}}))
    (model / "weights.pt").write_bytes(pickle.dumps({"w": os.getcwd}))
    line = _error(capsys, ["predict", str(model), str(case3), "--out", str(tmp_path / "p")])
    assert "refused to load" in line and "weights_only=False" not in line
    out = tmp_path / "agent"
    out.mkdir()
    (out / "checkpoint.pt").write_bytes(pickle.dumps({"w": os.getcwd}))
    line = _error(capsys, ["assimilate", str(case3), "--out", str(out), "--resume", "--quiet"])
    assert "refused to load" in line and "weights_only=False" not in line


def test_resume_without_a_checkpoint_is_an_error(case3, tmp_path, capsys):
    assert "no checkpoint to resume" in _error(capsys, ["assimilate", str(case3), "--out", str(tmp_path / "a"),
                                                        "--resume", "--quiet"])


# ------------------------------------------------------------------ causes named, before any spin
@pytest.mark.parametrize("meta, column, words", [
    ({"initial.p_v_Pa": 30e5, "initial.T_l_K": 51.0}, None, "critical pressure"),
    ({"initial.T_l_K": 51.0}, None, "above the critical temperature"),
    ({}, ("slosh_amplitude_m", 5.0), "not smaller than the tank radius"),
    ({"timeseries": "/etc/passwd"}, None, "must lie beside the JSON file"),
])
def test_impossible_runs_are_refused_with_their_cause(case3, tmp_path, capsys, meta, column, words):
    if column and column[0] == "slosh_amplitude_m":
        run = _variant(case3, tmp_path / "v", meta, column)
        run = _variant(run, tmp_path / "w", {}, ("slosh_frequency_Hz", 0.5))
    else:
        run = _variant(case3, tmp_path / "v", meta, column)
    line = _error(capsys, ["simulate", str(run), "--out", str(tmp_path / "o")])
    assert words in line
    assert "root:" not in line  # nothing of a foreign file is echoed


# ------------------------------------------------------------------ round trips
def test_a_simulated_copy_round_trips_exactly(tmp_path):
    assert main(["simulate", "case3", "--out", str(tmp_path / "a")]) == 0
    assert main(["simulate", str(tmp_path / "a" / "case3.json"), "--out", str(tmp_path / "b")]) == 0
    assert main(["simulate", str(tmp_path / "b" / "case3.json"), "--out", str(tmp_path / "c")]) == 0
    assert (tmp_path / "b" / "case3.json").read_text() == (tmp_path / "c" / "case3.json").read_text()
    assert (tmp_path / "b" / "case3.csv").read_text() == (tmp_path / "c" / "case3.csv").read_text()
    a, c = read_run(tmp_path / "a" / "case3.json"), read_run(tmp_path / "c" / "case3.json")
    assert (a.t0_s, a.t_end_s) == (c.t0_s, c.t_end_s)


def test_a_run_that_starts_late_keeps_its_span(case3, tmp_path):
    d = json.loads(case3.read_text())
    lines = (case3.parent / "case3.csv").read_text().splitlines()
    shifted = [lines[0]] + [",".join([repr(float(r.split(",")[0]) + 100.0)] + r.split(",")[1:]) for r in lines[1:]]
    (tmp_path / "late").mkdir()
    (tmp_path / "late" / "case3.csv").write_text("\n".join(shifted) + "\n")
    (tmp_path / "late" / "case3.json").write_text(json.dumps(d))
    src = tmp_path / "late" / "case3.json"
    for k in range(2):
        assert main(["simulate", str(src), "--out", str(tmp_path / f"s{k}")]) == 0
        src = tmp_path / f"s{k}" / "case3.json"
        run = read_run(src)
        assert (run.t0_s, run.t_end_s) == (100.0, 3700.0)


@needs_mhtb
def test_a_simulated_copy_of_a_measured_run_keeps_its_sensors_noise_and_wall(tmp_path):
    assert main(["simulate", str(MHTB / "P263968K.json"), "--out", str(tmp_path / "a")]) == 0
    measured, sim = read_run(MHTB / "P263968K.json"), read_run(tmp_path / "a" / "P263968K.json")
    assert sim.noise_std == measured.noise_std
    assert sim.observations.measured_channels == measured.observations.measured_channels
    assert measured.tank.wall_heat_capacity_J_per_K is None and sim.tank.wall_heat_capacity_J_per_K > 0
    assert main(["simulate", str(tmp_path / "a" / "P263968K.json"), "--out", str(tmp_path / "b"),
                 "--noise", "sensors", "--seed", "1"]) == 0
    noisy = read_run(tmp_path / "b" / "P263968K.json")
    _, p_clean = sim.observations.channel("p_v_Pa")
    _, p_noisy = noisy.observations.channel("p_v_Pa")
    assert np.std(p_noisy - p_clean) == pytest.approx(measured.noise_std["p_v"], rel=0.2)


# ------------------------------------------------------------------ the command line itself
def test_help_answers_without_importing_torch_or_coolprop():
    code = "import sys, tankode.cli; sys.exit(('torch' in sys.modules) + 2 * ('CoolProp' in sys.modules))"
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "tankode.cli", "--help"], capture_output=True, text=True)
    assert done.returncode == 0 and "simulate" in done.stdout
    assert time.perf_counter() - start < 10  # a bound against hangs, not a timing target


def test_cli_choices_match_the_library_tables():
    from tankode import cli
    from tankode.closures import INPUT_SETS

    assert set(cli._INPUT_SETS) == set(INPUT_SETS)
    assert {type(cli._gradient(g)).__name__.lower() for g in cli._GRADIENTS} == set(cli._GRADIENTS)


def test_warnings_and_unexpected_errors_are_one_line(capsys):
    from tankode.cli import describe_error

    assert describe_error(KeyError("x")).startswith("internal error (KeyError")
    assert "\n" not in describe_error(RuntimeError("a\n  b\n c"))


# ------------------------------------------------------------------ impossible schedules fail fast, with the cause
@pytest.mark.parametrize("meta, columns, words", [
    ({"initial.fill_ratio": 0.999}, (), ["ullage vanished", "0.999 full"]),
    ({}, (("mdot_l_out_kg_s", 2.0),), ["dry"]),
    ({}, (("Q_aw_W", -1e7),), ["wall temperature fell", "Q_aw_W is -1e+07 W"]),
    ({}, (("mdot_v_in_kg_s", 100.0), ("T_v_in_K", 30.0), ("p_v_in_Pa", 5e5)), ["vapour inflow is 100 kg/s"]),
    ({"duration_s": 1e6}, (), ["ullage is nearly gone"]),
], ids=["fill-0.999", "drained-dry", "wall-below-0K", "vapour-inflow-100kg/s", "duration-1e6s"])
def test_impossible_schedules_fail_within_seconds_naming_the_cause(case3, tmp_path, capsys, meta, columns, words):
    run = case3
    for k, column in enumerate(columns or [None]):
        run = _variant(run, tmp_path / f"v{k}", meta if k == 0 else {}, column)
    start = time.perf_counter()
    line = _error(capsys, ["simulate", str(run), "--out", str(tmp_path / "o")])
    assert time.perf_counter() - start < 30  # seconds of work, not minutes of a stalled solver
    for w in words:
        assert w in line, line
    assert " at t = " in line and "in state env 0" in line


def test_a_run_at_10_bar_simulates_on_the_wide_property_domain(case3, tmp_path):
    # No measured pressure contradicts the metadata's 9 bar: a valid run beyond the default domain.
    d = json.loads(case3.read_text())
    d["initial"].update({"p_v_Pa": 9e5, "T_v_K": 33.0, "T_l_K": 24.0, "T_w_K": 30.0})
    d["noise_std"] = {"T_l": 0.2}
    (tmp_path / "r").mkdir()
    (tmp_path / "r" / "case3.json").write_text(json.dumps(d))
    rows = (case3.parent / "case3.csv").read_text().splitlines()
    header = rows[0].split(",")
    keep = [i for i, h in enumerate(header) if h not in ("p_v_Pa", "T_v_K", "T_w_K", "H_l_m", "T_l_K")]
    (tmp_path / "r" / "case3.csv").write_text("\n".join(",".join(r.split(",")[i] for i in keep) for r in rows) + "\n")
    assert main(["simulate", str(tmp_path / "r" / "case3.json"), "--out", str(tmp_path / "o")]) == 0
    p = read_run(tmp_path / "o" / "case3.json").observations.channel("p_v_Pa")[1]
    assert p.max() > 8e5


@pytest.mark.slow
def test_a_methane_tank_vented_below_the_default_tier_simulates_on_the_low_one(tmp_path, capsys):
    # cryo_sim's random_701: 45 m3 of methane vented from 1.5 to 0.66 bar, below the default tier
    # (0.7 bar) and the wide one (from 1.15 bar for methane); the low tier holds it.
    sim = Path(__file__).parent / "cryo_sim.py"
    subprocess.run([sys.executable, str(sim), "random_701", "--noise", "low", "--out", str(tmp_path / "r"),
                    "--name", "vent"], check=True, capture_output=True)
    run = read_run(tmp_path / "r" / "vent.json")
    assert np.nanmin(run.observations.channel("p_v_Pa")[1]) < 0.7e5
    assert main(["simulate", str(tmp_path / "r" / "vent.json"), "--out", str(tmp_path / "o")]) == 0
    p = read_run(tmp_path / "o" / "vent.json").observations.channel("p_v_Pa")[1]
    assert p.min() < 0.8e5, p.min()


@pytest.mark.slow
def test_a_tank_pressurised_with_ambient_gas_simulates_on_the_hot_tier(tmp_path, capsys):
    # 2.4 kg of 300 K hydrogen into a half-full 9.4 m3 tank at 1.5 bar: the run's initial state
    # lies in the default tier, its injected gas does not (the wide tier's vapour stops at 82 K),
    # so the run is matched to the hot tier from the start (Fleet.from_runs) and its ullage warms
    # past 82 K.
    from tankode.fleet import Fleet
    from tankode.properties import hot_domain
    from tankode.run import InitialState, Run, TankSpec
    from tankode.run_io import write_run
    from tankode.schedule import Schedule

    run = Run(name="warm", fluid="ParaHydrogen",
              tank=TankSpec.from_dict({"shape": "vertical_cylinder", "radius_m": 1.0, "height_m": 3.0,
                                       "wall_heat_capacity_J_per_K": 2e5}),
              initial=InitialState(p_v_Pa=1.5e5, T_v_K=24.0, T_l_K=21.5, T_w_K=23.0, fill_ratio=0.5), duration_s=1200.0,
              inputs=Schedule.from_steps([(0, {"Q_aw_W": 200.0}),
                                          (300, {"mdot_v_in_kg_s": 0.004, "T_v_in_K": 300.0, "p_v_in_Pa": 6e5}),
                                          (900, {"mdot_v_in_kg_s": 0.0})], t_end=1200.0))
    assert Fleet.from_runs(run).fluid.domain == hot_domain("ParaHydrogen")
    write_run(run, tmp_path / "r")
    assert main(["simulate", str(tmp_path / "r" / "warm.json"), "--out", str(tmp_path / "o")]) == 0
    T_v = read_run(tmp_path / "o" / "warm.json").observations.channel("T_v_K")[1]
    assert T_v.max() > 85.0, T_v.max()


@needs_mhtb
@pytest.mark.parametrize("name", ["P263981D", pytest.param("P263981T", marks=pytest.mark.slow)])
def test_default_assimilate_and_predict_complete_on_the_stiff_real_tanks(tmp_path, capsys, name):
    # MHTB's light aluminium wall makes the tank stiff: the defaults (Rosenbrock, replay windows,
    # the two-node wall) train on it; the paper's dopri5 with the adjoint crashed here.
    from tankode.run_io import write_run

    run = read_run(MHTB / f"{name}.json").until(7200.0)
    write_run(run.replace(name=f"{name}_2h"), tmp_path / "data")
    path = str(tmp_path / "data" / f"{name}_2h.json")
    assert main(["assimilate", path, "--out", str(tmp_path / "agent"), "--iters", "2", "--window", "3600", "--quiet"]) == 0
    assert main(["predict", str(tmp_path / "agent"), path, "--out", str(tmp_path / "pred")]) == 0
    out, err = capsys.readouterr()
    assert "Traceback" not in err and "error" not in err
    # the wall heat capacity is not published: both commands say what they took for it
    assert out.count(f"note: {name}_2h: wall heat capacity unknown in the run; assumed") == 2, out
