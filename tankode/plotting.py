"""Figures of a run: pressure, temperatures, inputs and level (as the paper's case figure)."""

from __future__ import annotations

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


__all__ = ["plot_run"]
