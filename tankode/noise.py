"""Sensor noise levels of the paper's studies and synthetic measurement noise."""

from __future__ import annotations

import numpy as np

from .run import NOISE_KEYS, Observations

# Standard deviations per channel (paper, section 6.1.2): low = 2 kPa, 0.2 K, 0.5 mm; high doubles them.
NOISE_LEVELS: dict[str, dict[str, float]] = {
    "low": {"p_v": 2000.0, "T_v": 0.2, "T_l": 0.2, "T_w": 0.2, "H_l": 0.0005},
    "high": {"p_v": 4000.0, "T_v": 0.4, "T_l": 0.4, "T_w": 0.4, "H_l": 0.001},
}
NOISE_LEVELS["clean"] = {k: 0.0 for k in NOISE_LEVELS["low"]}


def noise_std(level: str) -> dict[str, float]:
    """Per-channel standard deviations of a named level: "clean", "low" or "high"."""
    if level not in NOISE_LEVELS:
        raise ValueError(f"noise level must be one of {sorted(NOISE_LEVELS)}, got {level!r}")
    return dict(NOISE_LEVELS[level])


def nominal_R_std(level: str) -> dict[str, float]:
    """The ``noise_std`` to write into a run: the level's, or the low level's for clean data.

    Clean data still needs a positive measurement covariance R to weigh channels in the cost.
    """
    return noise_std("low" if level == "clean" else level)


def add_noise(obs: Observations, std, seed: int) -> Observations:
    """Observations plus independent Gaussian noise (NaN stays NaN).

    ``std``: a level's name ("clean", "low", "high") or per-sensor standard deviations by
    ``NOISE_KEYS`` key (absent keys: no noise on that channel).
    """
    std = noise_std(std) if isinstance(std, str) else std
    sigma = np.array([std.get(k, 0.0) for k in NOISE_KEYS])
    rng = np.random.default_rng(seed)
    noisy = obs.values + rng.standard_normal(obs.values.shape) * sigma
    return Observations(obs.t_s.copy(), noisy)


__all__ = ["NOISE_LEVELS", "noise_std", "nominal_R_std", "add_noise"]
