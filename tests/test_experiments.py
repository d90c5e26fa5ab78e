"""Smoke runs of every experiment script's quick mode (the full modes are in experiments/README.md)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _run(script, out):
    env = dict(os.environ, MPLBACKEND="Agg")
    proc = subprocess.run([sys.executable, str(ROOT / "experiments" / script), "--quick", "--out", str(out)],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
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
