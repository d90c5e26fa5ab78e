"""What a simulation gets wrong: residual statistics per channel and operating phase."""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2 as chi2_dist

from .data import CHANNELS, PHASES, Observed

# A residual beyond 3 sigma for this many consecutive samples is a misfit, not noise (three
# independent 3-sigma exceedances in a row have probability ~2e-8).
MIN_SPAN_SAMPLES = 3


def ljung_box(x: np.ndarray, lags: int = 10) -> tuple[float, float]:
    """Ljung-Box statistic Q and its p-value for the series ``x`` (NaN removed): white noise gives large p."""
    x = x[np.isfinite(x)]
    n = len(x)
    lags = min(lags, n // 5)
    if lags < 1:
        return float("nan"), float("nan")
    x = x - x.mean()
    denom = float(x @ x)
    if denom == 0:
        return 0.0, 1.0
    rho = np.array([float(x[k:] @ x[:-k]) / denom for k in range(1, lags + 1)])
    Q = n * (n + 2) * float(np.sum(rho**2 / (n - np.arange(1, lags + 1))))
    return Q, float(chi2_dist.sf(Q, lags))


def spans_outside(t: np.ndarray, z: np.ndarray, limit: float = 3.0, min_samples: int = MIN_SPAN_SAMPLES) -> list[dict]:
    """Time spans where ``|z|`` stays above ``limit`` for at least ``min_samples`` consecutive samples."""
    ok = np.isfinite(z)
    t, z = t[ok], z[ok]
    out = []
    k = 0
    while k < len(z):
        if abs(z[k]) > limit:
            j = k
            while j + 1 < len(z) and abs(z[j + 1]) > limit:
                j += 1
            if j - k + 1 >= min_samples:
                out.append({"t_start_s": float(t[k]), "t_end_s": float(t[j]), "n_samples": j - k + 1,
                            "max_abs_sigma": float(np.abs(z[k:j + 1]).max()),
                            "sign": "over" if z[k] > 0 else "under"})
            k = j + 1
        else:
            k += 1
    return out


def residual_report(obs: Observed, pred: np.ndarray, heldout: np.ndarray) -> dict:
    """Bias and RMS (in noise sigmas) per channel and phase, whiteness and 3-sigma spans.

    Args:
        obs: the observations.
        pred: ``(env, T, 5)`` predicted observations.
        heldout: ``(env, T)`` bool, the held-out samples (the rest calibrated the model).

    Returns:
        ``{"runs": {name: {channel: {...}}}}`` with, per run and measured channel, ``bias_sigma``
        and ``rms_sigma`` for the calibration part, the held-out part and each operating phase,
        the Ljung-Box statistic of the whole residual series and its p-value, and the spans
        outside the 3-sigma band. Residuals are prediction minus data.
    """
    z = (pred - obs.y) / obs.sigma[:, None, :]  # (env, T, 5)
    runs = {}
    for e, name in enumerate(obs.run_names):
        chans = {}
        for c, ch in enumerate(CHANNELS):
            zc = z[e, :, c]
            if not np.isfinite(zc).any():
                continue

            def stats(mask):
                v = zc[mask & np.isfinite(zc)]
                if len(v) == 0:
                    return None
                return {"n": int(len(v)), "bias_sigma": float(v.mean()), "rms_sigma": float(np.sqrt((v**2).mean()))}

            Q, p = ljung_box(zc)
            chans[ch] = {
                "calibration": stats(~heldout[e]),
                "heldout": stats(heldout[e]),
                "phases": {ph: s for ph in PHASES if (s := stats(obs.phase[e] == ph)) is not None},
                "ljung_box_Q": Q, "ljung_box_p": p, "white": bool(p > 0.01) if np.isfinite(p) else None,
                "spans_outside_3sigma": spans_outside(obs.t_s, zc),
            }
        runs[name] = chans
    return {"runs": runs}


def heldout_rms_sigma(report: dict) -> dict:
    """``{run: {channel: RMS}}`` of the held-out residuals in noise sigmas, from a ``residual_report``."""
    return {run: {ch: v["heldout"]["rms_sigma"] for ch, v in chans.items() if v["heldout"]}
            for run, chans in report["runs"].items()}


def heldout_terms(obs: Observed, pred: np.ndarray, heldout: np.ndarray, block_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Per-block sums of squared normalised residuals and counts, ``(n_blocks, 5)`` each.

    Blocks are ``block_s`` long in each run's held-out span; they are what the bootstrap
    resamples (residuals within a block are correlated, blocks far less so).
    """
    z2 = ((pred - obs.y) / obs.sigma[:, None, :]) ** 2
    ss, nn = [], []
    for e in range(len(obs.run_names)):
        t = obs.t_s[heldout[e]]
        if len(t) == 0:
            continue
        block = np.floor((t - t[0]) / block_s).astype(int)
        ze = z2[e, heldout[e]]  # (T_e, 5)
        for b in np.unique(block):
            zb = ze[block == b]
            ok = np.isfinite(zb)
            ss.append(np.where(ok, zb, 0).sum(0))
            nn.append(ok.sum(0))
    return np.array(ss).reshape(-1, 5), np.array(nn).reshape(-1, 5)


def loss_from_terms(ss: np.ndarray, nn: np.ndarray) -> tuple[float, np.ndarray]:
    """Held-out loss: sum over channels of half the mean squared normalised residual (0.5 per channel at the noise floor)."""
    tot_n = nn.sum(0)
    per = np.where(tot_n > 0, 0.5 * ss.sum(0) / np.maximum(tot_n, 1), 0.0)
    return float(per.sum()), per


__all__ = ["residual_report", "heldout_rms_sigma", "ljung_box", "spans_outside", "heldout_terms", "loss_from_terms"]
