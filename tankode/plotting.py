"""Figures of a run (pressure, temperatures, inputs, level) and of the assimilation studies (J curves, predictions)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import matplotlib

matplotlib.use("Agg")  # files only; no display on servers and CI
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .run import OBS_CHANNELS, Run  # noqa: E402
from .schedule import INPUT_NAMES  # noqa: E402

_I = {n: i for i, n in enumerate(INPUT_NAMES)}


def _measured(run: Run, channel: str):
    t, v = run.observations.channel(channel)
    return t / 60.0, v


def plot_run(path, simulated: Run, measured: Run | None = None, title: str | None = None) -> None:
    """Write a 4-panel PNG: p_v; T_v, T_l, T_w; operations; liquid level.

    Args:
        path: output PNG path.
        simulated: a run whose observations are a simulation (drawn as lines).
        measured: optional measured run drawn as dots with +-1 sigma noise bars where known.
        title: figure title (defaults to the run name).
    """
    fig, axes = plt.subplots(2, 2, figsize=(11, 7.5), sharex=True)
    ax_p, ax_T, ax_u, ax_h = axes.ravel()
    colors = {"T_v_K": "tab:red", "T_l_K": "tab:blue", "T_w_K": "tab:gray"}
    labels = {"T_v_K": "T_v (vapour)", "T_l_K": "T_l (liquid)", "T_w_K": "T_w (wall)"}

    def draw(ax, channel, scale=1.0, color="k", label=None):
        if measured is not None and channel in measured.observations.measured_channels:
            t, v = _measured(measured, channel)
            key = dict(zip(OBS_CHANNELS, ("p_v", "T_v", "T_l", "T_w", "H_l")))[channel]
            sd = measured.noise_std.get(key)
            ax.errorbar(t, v * scale, yerr=None if sd is None else sd * scale, fmt=".", ms=3, color=color, alpha=0.45,
                        elinewidth=0.6, label=f"{label or channel} measured")
        if channel in simulated.observations.measured_channels:
            t, v = _measured(simulated, channel)
            ax.plot(t, v * scale, "-", color=color, lw=1.6, label=f"{label or channel} simulated")

    draw(ax_p, "p_v_Pa", 1e-5, "k", "p_v")
    ax_p.set_ylabel("ullage pressure p_v [bar]")
    for c in ("T_v_K", "T_l_K", "T_w_K"):
        draw(ax_T, c, 1.0, colors[c], labels[c])
    ax_T.set_ylabel("temperature [K]")
    draw(ax_h, "H_l_m", 1.0, "tab:green", "H_l")
    ax_h.set_ylabel("liquid level H_l [m]")

    if simulated.inputs is not None:
        t_end = simulated.t_end_s
        ts = np.concatenate([simulated.inputs.t_s, [t_end]])
        vals = simulated.inputs.at(np.clip(ts, simulated.inputs.t_s[0], None))
        t_min = ts / 60.0
        ax_u.step(t_min, vals[:, _I["mdot_v_in_kg_s"]] * 1e3, where="post", label="vapour in [g/s]")
        ax_u.step(t_min, vals[:, _I["mdot_v_out_kg_s"]] * 1e3, where="post", label="vapour vented [g/s]")
        ax_u.step(t_min, vals[:, _I["mdot_l_in_kg_s"]] * 1e2, where="post", label="liquid in [10 g/s]")
        ax_u.step(t_min, vals[:, _I["mdot_l_out_kg_s"]] * 1e2, where="post", label="liquid out [10 g/s]")
        ax_u.step(t_min, vals[:, _I["slosh_amplitude_m"]] * 1e3, where="post", label="slosh amplitude A0 [mm]")
        ax_u.step(t_min, vals[:, _I["slosh_frequency_Hz"]] * 10, where="post", label="slosh frequency [0.1 Hz]")
        ax_u.step(t_min, vals[:, _I["Q_aw_W"]] / 100, where="post", label="Q_aw [100 W]")
    ax_u.set_ylabel("operations (scaled units in legend)")
    for ax in axes.ravel():
        ax.grid(alpha=0.3)
        handles, _ = ax.get_legend_handles_labels()
        if handles:
            ax.legend(fontsize=7, loc="best")
    for ax in axes[1]:
        ax.set_xlabel("time [min]")
    fig.suptitle(title or simulated.name)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)




# -- assimilation studies ------------------------------------------------------------------------

_STUDY_COLORS = ("tab:blue", "tab:orange", "tab:red", "tab:green", "tab:purple", "tab:brown", "tab:pink")


@dataclass(frozen=True)
class Curve:
    """One curve of a cost figure: ``y`` against ``x``, with an optional band ``[lo, hi]``."""

    x: np.ndarray
    y: np.ndarray
    lo: np.ndarray | None = None
    hi: np.ndarray | None = None


def plot_cost_curves(path, curves: Mapping[str, Curve], *, xlabel: str, ylabel: str, title: str,
                     floors: Mapping[str, float] | None = None, logy: bool = True, ax=None) -> None:
    """Cost curves (markers and lines, shaded bands where given) on a log axis; horizontal lines at ``floors``.

    Writes ``path`` (PNG) unless ``ax`` is given, in which case it draws there and writes nothing.
    """
    own = ax is None
    if own:
        fig, ax = plt.subplots(figsize=(7.5, 4.5))
    for i, ((label, c), color) in enumerate(zip(curves.items(), _STUDY_COLORS)):
        # Marker and line style vary too, so that curves lying on top of each other stay visible.
        ax.plot(c.x, c.y, marker="osD^v"[i % 5], ls=("-", "--", "-.", ":")[i % 4], color=color, lw=1.6,
                ms=5 if i % 5 else 6, mfc="none" if i % 2 else color, label=label)
        if c.lo is not None and c.hi is not None:
            ax.fill_between(c.x, c.lo, c.hi, color=color, alpha=0.2, lw=0)
            ax.vlines(c.x, c.lo, c.hi, color=color, lw=1.0, alpha=0.7)
    for (label, value), style in zip((floors or {}).items(), ("--", ":", "-.")):
        ax.axhline(value, color="k", ls=style, lw=1.0, label=label)
    if logy:
        ax.set_yscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    if own:
        fig.tight_layout()
        fig.savefig(path, dpi=110)
        plt.close(fig)


def plot_predictions(path, t_s: np.ndarray, truth_obs: np.ndarray, measured: Run,
                     predictions: Mapping[float, np.ndarray | None], title: str) -> None:
    """Data, truth and each agent's whole-run prediction: pressure (top) and temperatures (bottom).

    Args:
        path: output PNG.
        t_s: ``(T,)`` times of ``truth_obs`` and of the predictions (s).
        truth_obs: ``(T, 5)`` clean observations (p_v [Pa], T_v, T_l, T_w [K], H_l [m]).
        measured: the noisy run the agents were trained on (drawn as dots).
        predictions: observation time (s) -> ``(T, 5)`` prediction of the agent known then
            (None where its ODE could not be integrated); one column per entry.
        title: figure title.
    """
    n = max(1, len(predictions))
    fig, axes = plt.subplots(2, n, figsize=(4.2 * n, 6.0), sharex=True, sharey="row", squeeze=False)
    t_min = t_s / 60.0
    temps = (("T_v_K", 1, "tab:red", "T_v"), ("T_l_K", 2, "tab:blue", "T_l"), ("T_w_K", 3, "tab:gray", "T_w"))
    for j, (t_obs, pred) in enumerate(predictions.items()):
        ax_p, ax_T = axes[0, j], axes[1, j]
        tp, vp = _measured(measured, "p_v_Pa")
        ax_p.plot(tp, vp / 1e5, ".", ms=2, color="0.6", label="data")
        ax_p.plot(t_min, truth_obs[:, 0] / 1e5, "k-", lw=1.2, label="truth")
        for channel, c, color, name in temps:
            tt, vt = _measured(measured, channel)
            ax_T.plot(tt, vt, ".", ms=1.5, color=color, alpha=0.35)
            ax_T.plot(t_min, truth_obs[:, c], "-", color=color, lw=1.0, label=f"{name} truth")
        if pred is not None:
            ax_p.plot(t_min, pred[:, 0] / 1e5, "--", color="tab:orange", lw=1.8, label="agent")
            for _, c, color, name in temps:
                ax_T.plot(t_min, pred[:, c], "--", color=color, lw=1.8, label=f"{name} agent")
        else:
            ax_p.text(0.5, 0.5, "agent's ODE not integrable", transform=ax_p.transAxes, ha="center")
        for ax in (ax_p, ax_T):
            ax.axvspan(t_obs / 60.0, t_min[-1], color="0.9", zorder=0)
            ax.axvline(t_obs / 60.0, color="k", lw=0.8)
            ax.grid(alpha=0.3)
        ax_p.set_title(f"agent at t = {t_obs / 60:g} min (grey: not yet observed)", fontsize=9)
        ax_T.set_xlabel("time [min]")
    axes[0, 0].set_ylabel("ullage pressure p_v [bar]")
    axes[1, 0].set_ylabel("temperature [K]")
    axes[0, 0].legend(fontsize=7, loc="best")
    axes[1, 0].legend(fontsize=7, loc="best", ncol=2)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


__all__ = ["plot_run", "Curve", "plot_cost_curves", "plot_predictions"]
