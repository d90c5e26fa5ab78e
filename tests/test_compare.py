"""Scoring predictions against measured channels: known errors, spans and common samples."""

from __future__ import annotations


import numpy as np
import pytest

from tankode import get_case
from tankode.compare import channel_rmse
from tankode.run import Observations


def _prediction(t_s, p_Pa):
    values = np.full((len(t_s), 5), np.nan)
    values[:, 0] = p_Pa
    return Observations(np.asarray(t_s, float), values)


def _measured(t_s, p_Pa):
    return get_case("case1").replace(observations=_prediction(t_s, p_Pa), noise_std={"p_v": 300.0})


def test_rmse_and_bias_of_a_linear_error_interpolated_to_the_samples():
    t = np.array([0.0, 100.0, 200.0, 300.0])
    run = _measured(t, 1.0e5 + t)
    # predicted on another grid; linear, so interpolation is exact: error 2 t_s / 100 Pa
    tp = np.linspace(0.0, 300.0, 7)
    r = channel_rmse(run, _prediction(tp, 1.0e5 + 1.02 * tp), ("p_v_Pa",))["p_v_Pa"]
    err = 0.02 * t
    assert r["rmse"] == pytest.approx(np.sqrt(np.mean(err**2)), rel=1e-12)
    assert r["bias"] == pytest.approx(err.mean(), rel=1e-12)
    assert (r["n"], r["n_outside"], r["t_end_s"]) == (4, 0, 300.0)


def test_samples_outside_a_prediction_are_counted_not_extrapolated():
    t = np.array([0.0, 100.0, 200.0, 300.0])
    run = _measured(t, np.zeros(4) + 1.0e5)
    short = _prediction([0.0, 150.0], [1.0e5 + 10.0, 1.0e5 + 10.0])
    r = channel_rmse(run, short, ("p_v_Pa",))["p_v_Pa"]
    assert (r["n"], r["n_outside"], r["rmse"], r["t_end_s"]) == (2, 2, pytest.approx(10.0), 100.0)


def test_within_scores_two_models_on_the_same_samples():
    t = np.array([0.0, 100.0, 200.0, 300.0])
    run = _measured(t, 1.0e5 + np.zeros(4))
    peer = _prediction([0.0, 150.0], [1.0e5, 1.0e5])  # stops early, as the MHTB EBM's pressure does
    ours = _prediction(t, 1.0e5 + np.array([1.0, 1.0, 50.0, 50.0]))  # good early, poor late
    full = channel_rmse(run, ours, ("p_v_Pa",))["p_v_Pa"]
    common = channel_rmse(run, ours, ("p_v_Pa",), within=peer)["p_v_Pa"]
    assert full["n"] == 4 and full["rmse"] == pytest.approx(np.sqrt((2 + 2 * 2500) / 4))
    assert (common["n"], common["n_outside"], common["rmse"]) == (2, 2, pytest.approx(1.0))
