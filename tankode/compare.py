"""Score predictions of a run (tankode's or a peer model's) against its measured channels.

Each channel of a run is sampled on its own times, and a peer model's published prediction
(e.g. ``NAME.ebm.csv`` beside a NASA MHTB run) on yet other times. ``channel_rmse``
interpolates a prediction linearly to the measured sample times of each channel, so every
model is scored on the measured samples. Samples outside the prediction's time span are left out
(never extrapolated) and counted, so a comparison can say how many samples it used. A published
prediction may stop early (the MHTB EBM's pressure of P263981D leaves its plot after 1.35 h of
5.4): ``within=`` then restricts another model's score to the samples that prediction covers,
so the two are compared on the same samples.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .run import OBS_CHANNELS, Observations, Run
from .run_io import read_timeseries_csv


def read_peer_prediction(path, fluid: str = "ParaHydrogen") -> Observations:
    """A peer model's prediction of a run: a time-series CSV of observation columns only."""
    obs, _ = read_timeseries_csv(Path(path), fluid)
    return obs


def solution_observations(solution, env: int = 0) -> Observations:
    """The predicted observations of one environment of a ``tankode.simulate.Solution``."""
    return Observations(solution.t_s.detach().numpy(), solution.observations[env].detach().numpy())


def channel_rmse(run: Run, prediction: Observations, channels=None,
                 within: Observations | None = None) -> dict[str, dict]:
    """RMSE of ``prediction`` against ``run``'s measurements, channel by channel.

    Args:
        run: the measured run.
        prediction: predicted observations (NaN where a channel is not predicted at a time).
        channels: channel names (``OBS_CHANNELS``); by default those both measured and predicted.
        within: another prediction (e.g. a peer model's); if given, only samples inside its
            time span of the channel count as well, so both are scored on the same samples.

    Returns:
        ``{channel: {"rmse": float, "bias": float, "n": samples used, "n_outside": samples
        outside the prediction's span (or ``within``'s), "t_end_s": the last sample used}}``
        in the channel's SI unit (Pa, K, m); bias is prediction minus data.
    """
    measured = run.observations.measured_channels
    predicted = prediction.measured_channels
    if channels is None:
        channels = [c for c in OBS_CHANNELS if c in measured and c in predicted]
    out = {}
    for ch in channels:
        t_d, y_d = run.observations.channel(ch)
        t_p, y_p = prediction.channel(ch)
        if len(t_p) < 2 or len(t_d) == 0:
            raise ValueError(f"channel {ch}: {len(t_d)} measured and {len(t_p)} predicted samples; need >= 1 and >= 2")
        inside = (t_d >= t_p[0]) & (t_d <= t_p[-1])
        if within is not None:
            t_w, _ = within.channel(ch)
            if len(t_w) < 2:
                raise ValueError(f"channel {ch}: the reference prediction has {len(t_w)} samples; need >= 2")
            inside &= (t_d >= t_w[0]) & (t_d <= t_w[-1])
        err = np.interp(t_d[inside], t_p, y_p) - y_d[inside]
        out[ch] = {"rmse": float(np.sqrt(np.mean(err**2))) if err.size else float("nan"),
                   "bias": float(np.mean(err)) if err.size else float("nan"),
                   "n": int(inside.sum()), "n_outside": int((~inside).sum()),
                   "t_end_s": float(t_d[inside][-1]) if err.size else float("nan")}
    return out


__all__ = ["channel_rmse", "read_peer_prediction", "solution_observations"]
