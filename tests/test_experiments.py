"""Smoke runs of every experiment script's quick mode (the full modes are in experiments/README.md)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from mhtb_data import MHTB, needs_mhtb

ROOT = Path(__file__).resolve().parents[1]


def _run(script, out, timeout_s=600, args=()):
    env = dict(os.environ, MPLBACKEND="Agg")
    proc = subprocess.run([sys.executable, str(ROOT / "experiments" / script), "--quick", "--out", str(out), *args],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=timeout_s)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]


def test_identification_quick(tmp_path):
    _run("identification.py", tmp_path)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert len(summary["windows"]) == 2
    assert summary["windows"][0]["J_after"] < summary["windows"][0]["J_before"]
    for name in ("coefficients.png", "prediction.png"):
        assert (tmp_path / name).stat().st_size > 10_000


def test_multi_environment_quick(tmp_path):
    _run("multi_environment.py", tmp_path)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert [(r["draw"], r["n"]) for r in summary["results"]] == [(0, 0), (0, 1), (0, 2)]
    assert summary["test"] == ["env7"] and summary["pool"] == ["env2", "env3"]
    for r in summary["results"]:  # J is 0.5 per channel at the noise floor: no score can lie below it
        assert r["score"]["failed"] == 0 and r["score"]["mean"] > 2.0
    assert (tmp_path / "table.md").read_text().startswith("| N trained on")
    assert (tmp_path / "heldout_loss.png").stat().st_size > 10_000


def test_sensitivity_quick(tmp_path):
    _run("sensitivity.py", tmp_path)
    assert (tmp_path / "summary.md").read_text().startswith("# Sobol sensitivity")
    assert any(p.suffix == ".png" for p in tmp_path.iterdir())


@pytest.mark.parametrize("script, mode", [("noise.py", "growing"), ("fixed_windows.py", "fixed")])
def test_noise_studies_quick(tmp_path, script, mode):
    _run(script, tmp_path)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["mode"] == mode
    assert set(summary["levels"]) == {"clean", "low", "high"}
    for level, d in summary["levels"].items():
        assert len(d["J_after"]) == 2
        assert d["J_falls_in_first_window"], (level, d["J_first_update"])
        assert len(d["predictions"]) == 2  # the agents of both windows predicted the whole (cut) run
    assert summary["levels"]["low"]["noise_floor_J"] == pytest.approx(2.5)
    for name in ("cost_vs_time.png", "prediction_clean.png", "prediction_low.png", "prediction_high.png"):
        assert (tmp_path / name).stat().st_size > 10_000
    assert (tmp_path / "cost_vs_time.csv").read_text().count("\n") == 1 + 3 * 2
    assert (tmp_path / "summary.md").read_text().startswith("# ")


def test_minibatch_quick(tmp_path):
    _run("minibatch.py", tmp_path)
    summary = json.loads((tmp_path / "summary.json").read_text())
    table = {row["fraction"]: row for row in summary["table"]}
    assert set(table) == {1.0, 0.5, 0.05}
    assert table[1.0]["repetitions"] == 1 and table[0.05]["repetitions"] == 2
    assert summary["J_falls_in_first_window"]
    assert all(row["J_validation_mean"] > 0 for row in table.values())
    assert (tmp_path / "cost_vs_time.png").stat().st_size > 10_000
    assert (tmp_path / "table.csv").exists() and (tmp_path / "runs.csv").exists()
    assert (tmp_path / "summary.md").read_text().startswith("# Mini-batch study")


@pytest.mark.slow  # 7-21 minutes even cut to 2 h: two diagnoses, fits of two long stiff runs, CLI runs
@needs_mhtb
def test_mhtb_quick(tmp_path):
    _run("mhtb.py", tmp_path, timeout_s=1800)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert set(summary["table"]) == {"P263968K", "P263981D"}
    for test, models in summary["table"].items():
        assert {"tankode_baseline", "tankode_calibrated", "tankode_extended", "tankode_leave_one_out",
                "ebm"} <= set(models)
        for model, spans in models.items():
            assert set(spans) == {"ebm_span", "all"}
            for rmse in spans.values():
                assert set(rmse) == {"p_v_Pa", "T_v_K", "T_l_K"}, (test, model)
                assert all(v >= 0 for v in rmse.values())
    # The EBM's published pressure of P263981D stops at 1.35 h: the comparison leaves the
    # later samples out for every model, and says how many it used.
    p = summary["samples"]["P263981D"]["ebm_span"]["p_v_Pa"]
    assert p["n_outside"] > 0 and p["t_end_s"] < 4900.0
    assert summary["leave_one_out"]["P263981D"]["p_samples"] == p["n"]
    rows = (tmp_path / "table.csv").read_text().splitlines()
    # one row per test, model, span (EBM's samples, all samples) and channel
    assert len(rows) == 1 + sum(len(models) for models in summary["table"].values()) * 2 * 3
    assert set(summary["leave_one_out"]) == {"P263968K", "P263981D"}
    assert all(v["ok"] for v in summary["cli_predict"].values())
    assert (tmp_path / "diagnosis" / "model" / "model.json").exists()
    # Step 2b: the diagnosis from the samples at t = 0 with the h_wv correlation held
    m = summary["diagnosis_measured"]
    assert m["held_factors"] == ["h_wv"] and m["baseline_closure_factors"]["h_wv_factor"] == 1.0
    assert m["first"]["mechanism"] in {"pressure_sensor_bias", "dry_wall_node"}
    assert set(m["heldout_rms_sigma"]) == {"P263968K", "P263981D"}
    assert (tmp_path / "diagnosis_measured" / "report.md").exists()
    # Step 5: the boundary-layer-fed layer, calibrated on both tests and on each alone, saved with
    # its values and applied through `tankode predict` to the test it was not calibrated on.
    layer = summary["layer"]
    assert set(layer["fits"]) == {"P263968K+P263981D", "P263968K", "P263981D"}
    for key, fit in layer["fits"].items():
        held = [n for n in ("P263968K", "P263981D") if n not in key.split("+")]
        assert sorted(fit["predictions"]) == sorted(held or ["P263968K", "P263981D"])
        assert all(p["cli_predict"]["ok"] and p["cli_predict"]["p_rmse_Pa"] > 0 for p in fit["predictions"].values())
        # the start is the grid point with the least chi2 on the training tests
        assert len(fit["grid"]) == 12 and min(fit["grid"], key=lambda r: r["chi2"])["inv_thickness_1_per_m"] == \
            fit["start"]["inv_thickness_1_per_m"]
        (saved,) = json.loads((tmp_path / "layer_models" / key / "model.json").read_text())["mechanisms"]
        assert saved["id"] == "boundary_layer_stratification" and saved["params"]["inv_thickness_1_per_m"] > 0
    for test, models in summary["table"].items():
        assert {"tankode_layer_both", "tankode_layer_leave_one_out"} <= set(models)
    for name in ("mhtb_P263968K.png", "mhtb_P263981D.png"):
        assert (tmp_path / name).stat().st_size > 10_000


@needs_mhtb
def test_mhtb_agent_quick(tmp_path):
    """The agent trains on both real tests (cut to 1 h) with Rosenbrock + Backprop, the dry wall
    node's shell with it: the first window's cost falls, every test is predicted, and the saved
    model (with the trained shell) predicts through the CLI."""
    _run("mhtb_agent.py", tmp_path)
    summary = json.loads((tmp_path / "summary.json").read_text())
    agents = [r for r in summary["rows"] if r["closure"].startswith("agent")]
    assert {r["test"] for r in agents} == {"P263968K", "P263981D"}
    for r in agents:
        assert r["rmse"] is not None and r["rmse"]["p_v_Pa"] > 0, r
        first = r["windows"][0]
        assert first["note"] == "" and first["J_after"] < first["J_before"], first
    solvers = {(r["test"], r["solver"]): r for r in summary["forward_solvers"]}
    assert set(solvers) == {(t, s) for t in ("P263968K", "P263981D") for s in ("LSODA", "Rosenbrock")}
    assert all(r["rhs_evals"] > 0 and r["span_s"] == 3600.0 for r in solvers.values())
    model = tmp_path / "models" / "dry_wall_node_trained_from_3_both"
    (node,) = json.loads((model / "model.json").read_text())["mechanisms"]
    # the shell trained with the agent: saved with the value the last window left, as the rows report it
    assert node["id"] == "dry_wall_node" and node["params"]["R_sheet_K_per_W"] != 3.0, node
    assert {r["R_sheet_K_per_W"] for r in agents} == {node["params"]["R_sheet_K_per_W"]}
    proc = subprocess.run([sys.executable, "-m", "tankode.cli", "predict", str(model), str(MHTB / "P263981D.json"),
                           "--initial", "measured", "--out", str(tmp_path / "pred")], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert any((tmp_path / "pred").iterdir())


@pytest.mark.slow  # a 40-minute run of the independent simulator, trained with the default (replay) protocol
def test_foreign_assimilation_quick(tmp_path):
    _run("foreign_assimilation.py", tmp_path, timeout_s=1200)
    rows = json.loads((tmp_path / "results.json").read_text())["rows"]
    assert [(r["scenario"], r["law"]) for r in rows] == [("upright_13m3", "mcadams")]
    r = rows[0]
    # every channel scored on both parts, the fit no better than the noise allows
    assert set(r["fit"]) == set(r["held_out"]) == set(r["held_out_from_start"])
    assert all(v > 0.5 for v in r["fit"].values())
    assert r["cost_fit"] >= 0.8 * r["floor"] and r["cost_windows"] >= 0.8 * r["floor"]
    assert (tmp_path / "table.md").read_text().startswith("| law |")


@needs_mhtb
@needs_mhtb
def test_mhtb_rotations_quick(tmp_path):
    """One rotation and the law calibrated on all three tests (cut to 1 h): every test predicted and
    scored beside the EBM, the saved model applied by ``tankode predict`` to each test as given."""
    _run("mhtb_rotations.py", tmp_path, timeout_s=1200)
    summary = json.loads((tmp_path / "summary.json").read_text())
    rows = summary["rows"]
    assert {r["test"] for r in rows if r["model"] == "EBM (published)"} == {"P263968K", "P263981D", "P263981T"}
    held = [r for r in rows if r["held_out"]]
    assert [r["test"] for r in held] == ["P263968K"] and held[0]["trained_on"] == ["P263981D", "P263981T"]
    for r in rows:
        assert r["rmse"] is not None and r["rmse"]["p_v_Pa"] > 0, r
    assert sorted(summary["predict_s"]) == ["P263968K", "P263981D", "P263981T"]
    saved = json.loads((tmp_path / "model" / "model.json").read_text())["mechanisms"]
    by = {m["id"]: m["params"] for m in saved}
    assert list(by) == ["dry_wall_heating", "boundary_layer_stratification", "saturated_start"]
    # the fixed shares stay where the law puts them; the two learned parameters moved from their start
    assert by["dry_wall_heating"]["phi"] == 1.0 and by["boundary_layer_stratification"]["wall_share"] == 1.0
    assert by["saturated_start"]["share"] == 1.0
    assert by["boundary_layer_stratification"]["inv_thickness_1_per_m"] != 50.0
