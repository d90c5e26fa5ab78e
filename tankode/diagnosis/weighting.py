"""How the diagnosis weighs each channel's residuals: by the sensor noise, or by the model's own error."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from scipy.stats import chi2 as _chi2

from .data import Observed


@dataclass(frozen=True)
class SensorNoise:
    """Weigh each channel by its sensor noise (the run's ``noise_std``): the default.

    Right when the model can follow the data to the noise, as on tankode's own runs. Where it
    cannot (another simulator's heat transfer, a real tank), the channel it misses by many
    sigma dominates every chi2, and any mechanism that shaves a little off that misfit looks
    significant while one that acts on a well-followed channel is swamped.
    """

    rounds: ClassVar[int] = 0  # re-weightings: none

    def sigma(self, obs: Observed, pred: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """The sensors' ``(env, 5)`` noise std, whatever the fit."""
        return obs.sigma

    def describe(self) -> str:
        return "sensor noise"


@dataclass(frozen=True)
class ModelError:
    """Weigh each channel by its sensor noise or, if the calibrated baseline misses it by more, by that error.

    Maximum likelihood with an unknown variance per run and channel, floored at the sensor's:
    ``sigma_c = max(noise_std_c, RMS_c)``, with ``RMS_c`` the calibrated baseline's root-mean-
    square residual on channel ``c`` of the calibration data, after which the baseline is
    calibrated again (``rounds`` times at most, until no sigma moves by more than 5 %). A
    channel is re-weighted only when its residuals are larger than noise beyond chance (its
    chi2 above the ``1 - significance`` quantile of the chi2 distribution with as many degrees
    of freedom as samples), so a baseline that fits to the noise keeps the sensor weights
    exactly and the diagnosis of tankode's own runs is unchanged.

    What it changes: the information criteria and the held-out loss are in units of what the
    model can follow; a channel the model misses everywhere (the ullage temperature of a real
    tank, 2-4 K off against a 0.1 K sensor) no longer outweighs the others. The residual report
    stays in units of the sensor noise, so such a channel is still reported as unexplained.

    Limits: the error is taken as white with a constant variance per channel; a model error that
    is a slow drift is neither, so the criteria still overstate the evidence on that channel,
    only less. The raised sigma also takes in the signature of a mechanism the baseline lacks,
    and where the baseline's held-out loss in the raised units is at or below the noise floor
    the diagnosis' ``explained`` rule (a share of the excess above that floor) blocks every
    name, the right ones too. How it compares with the sensor weighting on another simulator's
    runs and on the MHTB tests: ``experiments/README.md``. Opt-in
    (``DiagnosisConfig(weighting=ModelError())``).

    Attributes:
        significance: chance of re-weighting a channel whose residuals are noise (1e-3).
        rounds: re-weightings at most (2 by default: on the MHTB tests the second already moves
            no sigma by more than 5 %).
    """

    significance: float = 1e-3
    rounds: int = 2

    def __post_init__(self):
        if not 0 < self.significance < 1:
            raise ValueError(f"ModelError.significance must be in (0, 1), got {self.significance}")
        if self.rounds < 1:
            raise ValueError(f"ModelError.rounds must be >= 1, got {self.rounds}")

    def sigma(self, obs: Observed, pred: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """``(env, 5)`` sigma: the sensor's, or the RMS residual of ``pred`` on ``mask`` where larger beyond chance.

        Args:
            obs: the observations with the sensors' sigma.
            pred: ``(env, T, 5)`` the calibrated baseline's predictions.
            mask: ``(env, T)`` bool, the calibration data.
        """
        rms, n = rms_residual(obs, pred, mask)
        with np.errstate(invalid="ignore", divide="ignore"):
            reduced = (rms / obs.sigma) ** 2
            beyond = reduced > _chi2.ppf(1.0 - self.significance, np.maximum(n, 1)) / np.maximum(n, 1)
        return np.where((n > 0) & beyond, rms, obs.sigma)

    def describe(self) -> str:
        return f"model error (max of sensor noise and the baseline's RMS residual, significance {self.significance:g})"


def rms_residual(obs: Observed, pred: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """RMS residual of ``pred`` ``(env, T, 5)`` on the samples of ``mask`` ``(env, T)``, and their count, each ``(env, 5)``.

    NaN where a channel has no sample there; in the channels' SI units.
    """
    sel = mask[:, :, None] & obs.measured  # (env, T, 5)
    r2 = np.where(sel, (pred - np.nan_to_num(obs.y)) ** 2, 0.0)
    n = sel.sum(axis=1)  # (env, 5)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.sqrt(r2.sum(axis=1) / n), n


def reweigh(problem, weighting: SensorNoise | ModelError, pred: np.ndarray, mask: np.ndarray) -> bool:
    """Weigh ``problem`` by ``weighting``'s sigmas for the fit ``pred`` on ``mask``; False if none moved by 5 %.

    One round of ``ModelError``'s re-weighting (``tankode.diagnosis.calibrate`` repeats it with
    a refit in between); ``problem`` is left as it was when nothing moved.
    """
    sigma = weighting.sigma(problem.sensor_obs, pred, mask)
    if np.allclose(sigma, problem.obs.sigma, rtol=0.05, equal_nan=True):
        return False
    problem.weigh(sigma)
    return True


__all__ = ["SensorNoise", "ModelError", "reweigh", "rms_residual"]
