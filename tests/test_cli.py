"""The command line: simulate cases and measured runs, round trip, clear errors."""

import numpy as np
import pytest

from tankode.cli import build_parser, main
from tankode.run_io import read_run

from mhtb_data import MHTB, needs_mhtb


def test_simulate_case_writes_run_csv_and_figure(tmp_path, capsys):
    assert main(["simulate", "case1", "--out", str(tmp_path), "--noise", "high", "--seed", "3"]) == 0
    for ext in ("json", "csv", "png"):
        assert (tmp_path / f"case1.{ext}").stat().st_size > 0
    run = read_run(tmp_path / "case1.json")
    assert run.noise_std["p_v"] == 4000.0
    t, p = run.observations.channel("p_v_Pa")
    assert len(t) == 361 and t[-1] == 3600.0
    # High noise: residual against the clean simulation has the stated standard deviation.
    assert main(["simulate", "case1", "--out", str(tmp_path / "clean")]) == 0
    _, p_clean = read_run(tmp_path / "clean" / "case1.json").observations.channel("p_v_Pa")
    assert np.std(p - p_clean) == pytest.approx(4000.0, rel=0.15)
    assert "real-time factor" in capsys.readouterr().out


def test_simulate_round_trip_of_its_own_output(tmp_path):
    assert main(["simulate", "case2", "--out", str(tmp_path / "a")]) == 0
    assert main(["simulate", str(tmp_path / "a" / "case2.json"), "--out", str(tmp_path / "b")]) == 0
    a = read_run(tmp_path / "a" / "case2.json")
    b = read_run(tmp_path / "b" / "case2.json")
    assert a.inputs == b.inputs and a.initial == b.initial
    # Re-simulating the clean simulation from the same initial state and inputs reproduces it.
    np.testing.assert_allclose(a.observations.values, b.observations.values, rtol=1e-9)


@needs_mhtb
@pytest.mark.parametrize("name", ["P263968K", "P263981D"])
def test_simulate_measured_mhtb_runs(tmp_path, capsys, name):
    assert main(["simulate", str(MHTB / f"{name}.json"), "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "wall heat capacity unknown in the run; assumed" in out
    sim = read_run(tmp_path / f"{name}.json")
    measured = read_run(MHTB / f"{name}.json")
    # Output at every measured time stamp (irregular, asynchronous channels) plus a regular grid.
    assert set(measured.observations.t_s) <= set(sim.observations.t_s)
    assert sim.t_end_s == measured.t_end_s
    p0 = sim.observations.channel("p_v_Pa")[1][0]
    assert p0 == pytest.approx(measured.initial.p_v_Pa, rel=1e-3)


@needs_mhtb
def test_simulate_reports_and_can_start_from_first_samples_that_contradict_the_metadata(tmp_path, capsys):
    run = MHTB / "P263968K.json"
    assert main(["simulate", str(run), "--out", str(tmp_path / "meta"), "--dt", "3600"]) == 0
    assert "initial.T_v_K = 21.01 but T_v_K = 24.8394" in capsys.readouterr().out
    assert main(["simulate", str(run), "--out", str(tmp_path / "meas"), "--dt", "3600", "--initial", "measured"]) == 0
    assert "starting from the samples at the start" in capsys.readouterr().out
    T_v = {k: read_run(tmp_path / k / "P263968K.json").observations.channel("T_v_K")[1][0] for k in ("meta", "meas")}
    assert T_v["meta"] == pytest.approx(21.01, abs=1e-3) and T_v["meas"] == pytest.approx(24.8394, abs=1e-3)


class _Captured(Exception):
    """Raised by a stand-in for the trainer or the diagnosis once it has the runs the CLI built."""


@needs_mhtb
@pytest.mark.parametrize("command,target", [("diagnose", "tankode.diagnosis.diagnose"),
                                            ("assimilate", "trainers.assimilate.Assimilator")])
@pytest.mark.parametrize("initial,T_v_K", [("metadata", 21.01), ("measured", 24.8394)])
def test_diagnose_and_assimilate_start_where_initial_says(tmp_path, monkeypatch, capsys, command, target, initial,
                                                          T_v_K):
    import importlib

    module, name = target.rsplit(".", 1)
    seen = []

    def stand_in(runs, *args, **kwargs):
        seen.extend(runs)
        raise _Captured

    monkeypatch.setattr(importlib.import_module(module), name, stand_in)
    # The CLI turns every exception into one line and exit code 2, the stand-in's included.
    assert main([command, str(MHTB / "P263968K.json"), "--out", str(tmp_path), "--initial", initial]) == 2
    (run,) = seen
    assert run.initial.T_v_K == pytest.approx(T_v_K, abs=1e-3)
    assert "initial.T_v_K = 21.01 but T_v_K = 24.8394" in capsys.readouterr().out


def test_bad_input_is_a_clear_error(tmp_path, capsys):
    assert main(["simulate", "case2", "--out", str(tmp_path)]) == 0
    good = (tmp_path / "case2.json").read_text()
    bad = tmp_path / "bad.json"
    bad.write_text(good.replace('"ParaHydrogen"', '"Hydrogenn"').replace('"case2.csv"', '"case2.csv"'))
    assert main(["simulate", str(bad), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "bad.json:3" in err and "Hydrogenn" in err
    bad.write_text('{"name": "bad", "fluid": "ParaHydrogen"}')
    assert main(["simulate", str(bad), "--out", str(tmp_path / "o")]) == 2
    assert "missing required key" in capsys.readouterr().err
    assert main(["simulate", "case9", "--out", str(tmp_path)]) == 2
    assert "neither a case" in capsys.readouterr().err
    # An output grid no memory holds names the option instead of failing to allocate it.
    assert main(["simulate", "case2", "--out", str(tmp_path / "fine"), "--dt", "1e-9"]) == 2
    assert "(--dt)" in capsys.readouterr().err
    # A run with nothing measured after its start has nothing to train on: said, not a silent model.
    csv = tmp_path / "case2.csv"
    csv.write_text("".join(csv.read_text().splitlines(keepends=True)[:2]))
    assert main(["assimilate", str(tmp_path / "case2.json"), "--out", str(tmp_path / "agent")]) == 2
    assert "no measurement after the run's start" in capsys.readouterr().err
    assert not (tmp_path / "agent" / "model.json").exists()


def test_diagnose_block_hold_and_refit_top_reach_the_config(tmp_path, monkeypatch, capsys):
    import tankode.diagnosis
    from tankode.diagnosis import DiagnosisConfig

    sub = next(a for a in build_parser()._actions if a.dest == "command").choices["diagnose"]
    (block,) = [a for a in sub._actions if a.dest == "block"]
    assert block.default == DiagnosisConfig.block_s
    seen = {}

    def stand_in(runs, closure, mechanisms, config, **kwargs):
        seen["config"] = config
        raise _Captured

    monkeypatch.setattr(tankode.diagnosis, "diagnose", stand_in)
    assert main(["simulate", "case1", "--out", str(tmp_path), "--dt", "600"]) == 0
    assert main(["diagnose", str(tmp_path / "case1.json"), "--out", str(tmp_path / "d"), "--block", "3600"]) == 2  # the stand-in stops the command
    assert seen["config"].block_s == 3600.0
    assert main(["diagnose", str(tmp_path / "case1.json"), "--out", str(tmp_path / "d"), "--block", "0"]) == 2
    assert "block_s must be > 0 s, got 0.0" in capsys.readouterr().err
    assert seen["config"].hold == ()
    assert main(["diagnose", str(tmp_path / "case1.json"), "--out", str(tmp_path / "d"), "--hold", "h_wv", "h_vi"]) == 2  # the stand-in stops the command
    assert seen["config"].hold == ("h_wv", "h_vi")
    assert main(["diagnose", str(tmp_path / "case1.json"), "--out", str(tmp_path / "d"), "--hold", "h_w"]) == 2
    assert "hold: unknown coefficient(s) ['h_w']; allowed: h_vi, h_li, h_wv, h_wl" in capsys.readouterr().err
    assert seen["config"].refit_top == DiagnosisConfig.refit_top == 5
    assert main(["diagnose", str(tmp_path / "case1.json"), "--out", str(tmp_path / "d"), "--refit-top", "all"]) == 2  # the stand-in stops the command
    assert seen["config"].refit_top is None
    assert main(["diagnose", str(tmp_path / "case1.json"), "--out", str(tmp_path / "d"), "--refit-top", "x"]) == 2
    assert "--refit-top N|all: expected a whole number, got 'x'" in capsys.readouterr().err
    assert main(["diagnose", str(tmp_path / "case1.json"), "--out", str(tmp_path / "d"), "--refit-top", "0"]) == 2
    assert "refit_top must be >= 1 or None, got 0" in capsys.readouterr().err


def test_assimilate_memory_names_are_the_trainers_strategies():
    """The parser spells out the --memory names (it does not import the trainers): they must stay in step."""
    from trainers.memory import MEMORIES

    sub = next(a for a in build_parser()._actions if a.dest == "command").choices["assimilate"]
    (memory,) = [a for a in sub._actions if a.dest == "memory"]
    assert set(memory.choices) == set(MEMORIES)
    assert memory.default in MEMORIES


def test_assimilate_window_start_and_gradient_reach_the_config(tmp_path, monkeypatch, capsys):
    """--window-start, --start-prior-sigmas, --gradient, --integrator and --train-mechanisms become the
    AssimilationConfig's (--mechanism the model's); a bad value is a clear error."""
    import trainers.assimilate
    from trainers.assimilate import AssimilationConfig

    sub = next(a for a in build_parser()._actions if a.dest == "command").choices["assimilate"]
    (start,) = [a for a in sub._actions if a.dest == "window_start"]
    assert start.default is None  # None: the configuration's default
    for choice in start.choices:  # every choice the parser offers is one the config accepts
        AssimilationConfig(window_start=choice, mode="fixed")
    seen = {}

    def stand_in(runs, config, **kwargs):
        seen["config"], seen["mechanisms"] = config, kwargs.get("mechanisms", ())
        raise _Captured

    monkeypatch.setattr(trainers.assimilate, "Assimilator", stand_in)
    assert main(["simulate", "case1", "--out", str(tmp_path), "--dt", "600"]) == 0
    args = ["assimilate", str(tmp_path / "case1.json"), "--out", str(tmp_path / "a")]
    assert main([*args, "--mode", "fixed", "--window-start", "joint", "--start-prior-sigmas", "3"]) == 2  # the stand-in stops the command
    assert (seen["config"].window_start, seen["config"].start_prior_sigmas) == ("joint", 3.0)
    # The defaults are the configuration's: Rosenbrock, whose gradient is Backprop (it has no adjoint)
    assert (seen["config"].integrator, type(seen["config"].gradient).__name__) == ("rosenbrock", "Backprop")
    # ...but the window: the run is sampled every 600 s, so a window holds ten samples (6000 s)
    assert seen["config"] == AssimilationConfig(window_s=6000.0, mode="fixed", window_start="joint", start_prior_sigmas=3.0)
    assert main([*args, "--gradient", "checkpointed"]) == 2  # the stand-in stops the command
    assert type(seen["config"].gradient).__name__ == "Checkpointed"
    assert seen["config"].window_start == AssimilationConfig.window_start
    # dopri5's default gradient is the adjoint
    assert main([*args, "--integrator", "dopri5"]) == 2  # the stand-in stops the command
    assert (seen["config"].integrator, type(seen["config"].gradient).__name__) == ("dopri5", "Adjoint")
    assert main([*args, "--integrator", "rosenbrock", "--gradient", "adjoint"]) == 2
    assert "has no continuous adjoint" in capsys.readouterr().err
    # mechanisms added to the model and trained with the agent
    assert main([*args, "--mechanism", "dry_wall_node:R_sheet_K_per_W=10", "--train-mechanisms", "dry_wall_node",
                 "--wall", "lumped"]) == 2  # the stand-in stops the command
    assert seen["config"].train_mechanisms == ("dry_wall_node",)
    assert [(m.id, m.values_dict()) for m in seen["mechanisms"]] == [("dry_wall_node", {"R_sheet_K_per_W": 10.0})]
    # several parameters of one mechanism go in one spec; naming it twice says so
    capsys.readouterr()
    assert main([*args, "--mechanism", "surface_layer:inv_thickness_1_per_m=50,wall_share=0.1"]) == 2
    assert seen["mechanisms"][-1].values_dict() == {"inv_thickness_1_per_m": 50.0, "wall_share": 0.1,
                                                    "mixing_rate_1_per_s": 0.0}
    seen.clear()
    assert main([*args, "--mechanism", "surface_layer:inv_thickness_1_per_m=50",
                 "--mechanism", "surface_layer:wall_share=0.1"]) == 2
    assert "names surface_layer more than once; give a mechanism's parameters once, comma-separated" in capsys.readouterr().err
    assert "mechanisms" not in seen  # refused before any training starts
    assert main([*args, "--mode", "fixed", "--window-start", "joint", "--start-prior-sigmas", "-1"]) == 2
    assert "start_prior_sigmas must be a positive number of noise sigmas, got -1.0" in capsys.readouterr().err
