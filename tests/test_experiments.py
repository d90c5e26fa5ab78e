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
    assert set(summary["table"]) == {"A1", "A23", "A234", "reference_closure"}
    for name in ("A1", "A23", "A234"):
        assert (tmp_path / name / "model.json").exists()
    # The truth scores at the noise floor on the validation case (about 0.5 per channel).
    assert summary["table"]["reference_closure"]["J_case5"] == pytest.approx(2.5, rel=0.3)


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


@pytest.mark.slow
@needs_mhtb
def test_mhtb_layer_quick(tmp_path):
    _run("mhtb_layer.py", tmp_path)
    rows = json.loads((tmp_path / "summary.json").read_text())
    # per start: both tests calibrated together, then each predicted from the other
    assert [(r["start"], r["calibrated_on"], r["test"]) for r in rows[:4]] == [
        ("absent", "P263968K+P263981D", "P263968K"), ("absent", "P263968K+P263981D", "P263981D"),
        ("absent", "P263981D", "P263968K"), ("absent", "P263968K", "P263981D")]
    assert len(rows) == 8 and all(r["p_rmse_Pa"] > 0 and r["ebm_p_rmse_Pa"] > 0 for r in rows)
    # from the layer absent the fit has no slope along the layer and leaves it at 0
    assert rows[0]["values"]["surface_layer.inv_thickness_1_per_m"] == 0.0


def test_closure_inputs_quick(tmp_path):
    _run("closure_inputs.py", tmp_path)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert len(summary["rows"]) == 4 * 3
    # The validation case is never among the training cases.
    assert all("case5" not in r["trained_on"] for r in summary["rows"])
    assert summary["J_reference_closure"] == pytest.approx(2.5, rel=0.3)
    assert (tmp_path / "summary.md").read_text().startswith("# Supervised fit")


def test_information_quick(tmp_path):
    """Two windows of case 1: accumulated information can only tighten the bound, and the sloshing
    window alone cannot separate h_li from h_wv (the identification target's limit)."""
    _run("information.py", tmp_path)
    rows = json.loads((tmp_path / "summary.json").read_text())["noise"]["high"]
    assert [r["window"] for r in rows] == [0, 1]
    for r in rows:
        for h in ("h_vi", "h_li", "h_wv", "h_wl"):
            assert r["std_ln_h_cumulative"][h] <= r["std_ln_h_window"][h] * (1 + 1e-9)
            assert r["std_ln_h_alone"][h] <= r["std_ln_h_window"][h] * (1 + 1e-9)
    slosh = rows[1]
    assert slosh["sloshing_share"] == 1.0
    assert slosh["corr_li_wv_window"] < -0.9
    assert slosh["std_ln_h_window"]["h_li"] > 0.3 > slosh["std_ln_h_cumulative"]["h_li"]


@pytest.mark.slow
@needs_mhtb
def test_mhtb_multistart_quick(tmp_path):
    _run("mhtb_multistart.py", tmp_path, timeout_s=1800)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert set(summary["directions"]) == {"P263981D->P263968K"}
    for d in summary["directions"].values():
        assert len(d["fits"]) == 2 and all(f["p_rmse_Pa"] > 0 for f in d["fits"])
        # the chosen fit is the one with the least training chi2, whatever it predicts
        assert d["chosen"] == min(range(2), key=lambda i: d["fits"][i]["chi2_train"])
        assert d["chosen_below_ebm"] == (d["fits"][d["chosen"]]["p_rmse_Pa"] < d["ebm_p_rmse_Pa"])
    assert (tmp_path / "summary.md").read_text().startswith("# boundary_layer_stratification")


@pytest.mark.slow
@needs_mhtb
def test_mhtb_fixed_shares_quick(tmp_path):
    _run("mhtb_fixed_shares.py", tmp_path, timeout_s=1800)
    summary = json.loads((tmp_path / "summary.json").read_text())
    (d,) = summary["directions"].values()
    first, second = d["rounds"]
    # the fixed shares stay where their degenerate boxes hold them, with no uncertainty
    for r in (first, second):
        assert r["values"]["dry_wall_heating.phi"] == 1.0 and r["std"]["dry_wall_heating.phi"] == 0.0
        assert r["values"]["boundary_layer_stratification.wall_share"] == 1.0
    # round 1 weighs a channel by round 0's RMS residual on the training test where it exceeds the
    # sensor noise beyond chance (ModelError), else by the sensor. That residual is the fit's own;
    # the reported RMSE re-simulates at simulate's tolerances and interpolates a 60 s output,
    # which moves it by a few per cent at most
    sensor = {"p_v": 300.0, "T_v": 0.1, "T_l": 0.02}
    assert first["sigma"] == sensor
    raised = 0
    for ch, rms in first["fit_rms"].items():
        key = ch.rsplit("_", 1)[0]
        assert rms == pytest.approx(first["train_rmse"][ch], rel=0.05)
        if second["sigma"][key] != sensor[key]:
            assert second["sigma"][key] == pytest.approx(rms, rel=1e-12) and rms > sensor[key]
            raised += 1
    assert raised >= 2  # the ullage temperature and the pressure are missed by far more than noise
    assert d["below_ebm"] == (second["p_rmse_Pa"] < d["ebm_p_rmse_Pa"])


@pytest.mark.slow
@needs_mhtb
def test_mhtb_fixed_shares_with_the_dry_wall_node_quick(tmp_path):
    _run("mhtb_fixed_shares.py", tmp_path, timeout_s=1800, args=("--wall", "dry_wall_node", "--initial", "measured"))
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert (summary["wall"], summary["initial"]) == ("dry_wall_node", "measured")
    assert "dry_wall_heating.phi" not in summary["fixed"]
    (d,) = summary["directions"].values()
    for r in d["rounds"]:
        # the shell's sheet resistance is fitted (from 10 K/W) inside its box, the wall share held at 1
        assert 0.0 < r["values"]["dry_wall_node.R_sheet_K_per_W"] < 1e3 and r["std"]["dry_wall_node.R_sheet_K_per_W"] > 0
        assert r["values"]["boundary_layer_stratification.wall_share"] == 1.0
        assert set(r["heldout_rmse"]) == {"p_v_Pa", "T_v_K", "T_l_K"}
    assert set(d["ebm_rmse"]) == {"p_v_Pa", "T_v_K", "T_l_K"}
    assert (tmp_path / "P263968K_from_P263981D.png").stat().st_size > 10_000
    assert "`dry_wall_node`'s R_sheet_K_per_W fitted" in (tmp_path / "summary.md").read_text()


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
