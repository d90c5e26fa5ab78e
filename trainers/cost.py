"""The assimilation cost J(w) over an observation window (paper, section 5.2).

    J = 1/(2 N) sum_j (1/T) integral_window e_j(t)^T R_j^-1 e_j(t) dt

with ``e_j = h(s_j(t)) - y_j(t)`` the misfit of environment ``j`` (of ``N``), ``R_j`` diagonal
from the run's ``noise_std`` and ``T`` the window length. Each channel's integral is taken
on its own sample times with the nearest-sample (midpoint) rule, so irregular and
asynchronous channels (real sensors) are weighted by the time they represent, and a missing
observation contributes nothing (masked). Dividing by ``T`` makes J a time average: a perfect
model on noisy data scores about ``n_channels / 2`` (0.5 per measured channel).

Mini-batches keep a subset of the window's observation times; their weights are divided by
the kept fraction so the batch cost is an unbiased estimate of the window cost.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from tankode.run import NOISE_KEYS, OBS_CHANNELS

CHANNELS = OBS_CHANNELS
N_CHANNELS = len(CHANNELS)


def _midpoint_weights(t: np.ndarray, t0: float, t1: float) -> np.ndarray:
    """Weights (s) of samples at sorted times ``t`` in [t0, t1]: the span each one represents."""
    if len(t) == 0:
        return np.zeros(0)
    edges = np.concatenate([[t0], 0.5 * (t[1:] + t[:-1]), [t1]])
    return np.diff(edges)


@dataclass(frozen=True)
class Window:
    """Observations of a fleet over ``[t0_s, t1_s]``, aligned for the cost.

    Attributes:
        t0_s, t1_s: window bounds (s).
        t_s: ``(T,)`` sorted union of the environments' observation times in the window.
        values: ``(env, T, 5)`` observations, 0 where missing (see ``weights``).
        weights: ``(env, T, 5)`` quadrature weight of each sample divided by the window
            length (dimensionless, 0 where missing); each measured channel's weights sum to 1.
        inv_var: ``(env, 5)`` 1/sigma^2 from each run's ``noise_std`` (0 for unmeasured channels).
    """

    t0_s: float
    t1_s: float
    t_s: Tensor
    values: Tensor
    weights: Tensor
    inv_var: Tensor

    @staticmethod
    def from_runs(runs, t0_s: float, t1_s: float) -> "Window":
        """Collect the observations of ``runs`` with ``t0_s < t <= t1_s`` (``t0_s`` itself when 0-length)."""
        if not t1_s > t0_s:
            raise ValueError(f"window must have t1_s > t0_s, got [{t0_s}, {t1_s}] s")
        times = np.unique(np.concatenate([r.observations.t_s for r in runs] + [np.zeros(0)]))
        times = times[(times > t0_s) & (times <= t1_s)]
        n_env, T = len(runs), len(times)
        values = np.zeros((n_env, T, N_CHANNELS))
        weights = np.zeros((n_env, T, N_CHANNELS))
        inv_var = np.zeros((n_env, N_CHANNELS))
        for e, run in enumerate(runs):
            obs = run.observations
            sel = (obs.t_s > t0_s) & (obs.t_s <= t1_s)
            idx = np.searchsorted(times, obs.t_s[sel])
            for c, key in enumerate(NOISE_KEYS):
                v = obs.values[sel, c]
                ok = np.isfinite(v)
                if not ok.any():
                    continue
                if key not in run.noise_std:
                    raise ValueError(f"run {run.name!r} measures {CHANNELS[c]} but has no noise_std[{key!r}]")
                inv_var[e, c] = 1.0 / run.noise_std[key] ** 2
                values[e, idx[ok], c] = v[ok]
                weights[e, idx[ok], c] = _midpoint_weights(obs.t_s[sel][ok], t0_s, t1_s) / (t1_s - t0_s)
        as_t = lambda a: torch.as_tensor(a, dtype=torch.float64)  # noqa: E731
        return Window(float(t0_s), float(t1_s), as_t(times), as_t(values), as_t(weights), as_t(inv_var))

    @property
    def n_env(self) -> int:
        return self.values.shape[0]

    def __len__(self) -> int:
        return len(self.t_s)


def cost_terms(pred: Tensor, window: Window, batch: Tensor | None = None) -> Tensor:
    """Per-environment, per-channel cost ``(env, 5)``; ``J = cost_terms(...).sum() / N``.

    Args:
        pred: ``(env, T, 5)`` predicted observations h(s) at ``window.t_s``.
        window: the observations.
        batch: optional ``(T,)`` bool mask of the observation times to use; the kept weights
            are divided by the kept fraction.
    """
    if pred.shape != window.values.shape:
        raise ValueError(f"prediction shape {tuple(pred.shape)} != observations {tuple(window.values.shape)}")
    w = window.weights
    if batch is not None:
        frac = batch.double().mean().clamp_min(1.0 / max(len(batch), 1))
        w = w * batch[None, :, None].double() / frac
    e2 = (pred - window.values) ** 2
    return 0.5 * (w * e2).sum(1) * window.inv_var


def cost(pred: Tensor, window: Window, batch: Tensor | None = None) -> Tensor:
    """J (dimensionless scalar): the mean over environments of ``cost_terms`` summed over channels."""
    return cost_terms(pred, window, batch).sum() / window.n_env


__all__ = ["Window", "cost", "cost_terms", "CHANNELS"]
