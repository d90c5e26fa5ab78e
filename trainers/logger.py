"""TensorBoard logging of the assimilation: costs, coefficients, gradients, prediction figures."""

from __future__ import annotations

import warnings

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import torch  # noqa: E402
from torch.utils.tensorboard import SummaryWriter  # noqa: E402

from tankode.closures import THETA_NAMES  # noqa: E402
from tankode.errors import SimulationError  # noqa: E402
from tankode.solver import NoGradient  # noqa: E402

from .cost import CHANNELS  # noqa: E402


class TrainingLogger:
    """Per-window scalars and a prediction-vs-data figure, in TensorBoard's format.

    Scalars (step = window index): ``J/total``, ``J/<env>/<channel>``, ``h/<env>/<coefficient>``
    (window means, W/(m^2 K)), ``start_offset_sigma/<env>/<channel>`` (``window_start="joint"``:
    the fitted offset of the window's initial state, in noise sigmas), ``saturated/<env>/<coefficient>``
    (MLP agents: the share of the window at an output bound), ``mechanism/<id>/<parameter>``
    (``train_mechanisms``: the values after the update, SI units), ``optim/grad_norm``, ``optim/function_evals``, ``optim/iterations``,
    ``time/update_s``. Figure ``prediction/<env>``: the current agent's prediction from the
    fleet's start to the window's end, with the data so far. A fixed-window agent has been fitted
    to the newest window only and may be unable to integrate the whole history; that is logged
    (a warning, text ``prediction/failed`` with the time and state, the figure with the data
    alone), never raised: a figure must not stop the training.
    """

    def __init__(self, logdir, env_names):
        self.writer = SummaryWriter(str(logdir))
        self.env_names = list(env_names)

    def log_window(self, report, assimilator, s_next) -> None:
        k = report.index
        w = self.writer
        w.add_scalar("J/total", report.cost_after, k)
        w.add_scalar("J/before_update", report.cost_before, k)
        for e, name in enumerate(self.env_names):
            for c, ch in enumerate(CHANNELS):
                if report.cost_terms[e][c] > 0:
                    w.add_scalar(f"J/{name}/{ch}", report.cost_terms[e][c], k)
            for j, th in enumerate(THETA_NAMES):
                w.add_scalar(f"h/{name}/{th}", report.theta_mean[e][j], k)
            if report.saturated:  # the share of the window each coefficient spent at an output bound
                for j, th in enumerate(THETA_NAMES):
                    w.add_scalar(f"saturated/{name}/{th}", report.saturated[e][j], k)
            if report.start_offset_sigmas:  # window_start="joint": how far the data moved the carried state
                for c, ch in enumerate(CHANNELS):
                    w.add_scalar(f"start_offset_sigma/{name}/{ch}", report.start_offset_sigmas[e][c], k)
        for mid, values in report.mechanisms.items():  # train_mechanisms: the fitted physical parameters
            for pname, v in values.items():
                w.add_scalar(f"mechanism/{mid}/{pname}", v, k)
        w.add_scalar("optim/grad_norm", report.grad_norm, k)
        w.add_scalar("optim/function_evals", report.n_evals, k)
        w.add_scalar("optim/iterations", report.n_iters, k)
        w.add_scalar("time/update_s", report.wall_s, k)
        # One simulation of the whole fleet from t0 to the window's end serves every
        # environment's figure: it is the logging's dominant cost.
        t = torch.linspace(assimilator.fleet.t0_s, report.t1_s, 121, dtype=torch.float64)  # (121,)
        obs = None
        try:
            with torch.no_grad():
                obs = assimilator.model.observe(assimilator.predict(assimilator.s0, float(t[0]), t, NoGradient()))
        except SimulationError as err:
            message = f"window {k}: the agent's prediction from the start could not be integrated: {err}"
            warnings.warn(message, RuntimeWarning, stacklevel=2)
            w.add_text("prediction/failed", message, k)
        # obs: (env, 121, 5) of this process's runs (with data parallelism: rank 0's shard)
        for e, run in enumerate(assimilator.fleet.runs):
            fig = self._figure(run, t, None if obs is None else obs[e], report.t1_s)
            w.add_figure(f"prediction/{run.name}", fig, k)
        w.flush()

    @staticmethod
    def _figure(run, t, obs, t1):
        """Pressure and temperatures, data and (``obs`` (121, 5), or None if it failed) prediction."""
        fig, (ax_p, ax_t) = plt.subplots(1, 2, figsize=(9, 3.2))
        tm = t.numpy() / 60
        if obs is None:
            ax_p.set_title("agent's prediction from t0 failed (see prediction/failed)", fontsize=8)
        else:
            ax_p.plot(tm, obs[:, 0].numpy() / 1e5, "k-", label="agent (from t0)")
        tp, vp = run.observations.channel("p_v_Pa")
        keep = tp <= t1
        ax_p.plot(tp[keep] / 60, vp[keep] / 1e5, "k.", ms=2, alpha=0.4, label="data")
        ax_p.set_xlabel("time [min]")
        ax_p.set_ylabel("p_v [bar]")
        for c, color in ((1, "tab:red"), (2, "tab:blue"), (3, "tab:gray")):
            if obs is not None:
                ax_t.plot(tm, obs[:, c].numpy(), "-", color=color, label=CHANNELS[c])
            tc, vc = run.observations.channel(CHANNELS[c])
            keep = tc <= t1
            ax_t.plot(tc[keep] / 60, vc[keep], ".", color=color, ms=2, alpha=0.4,
                      label=CHANNELS[c] if obs is None else None)
        ax_t.set_xlabel("time [min]")
        ax_t.set_ylabel("temperature [K]")
        ax_p.legend(fontsize=7)
        ax_t.legend(fontsize=7)
        fig.tight_layout()
        return fig

    def close(self) -> None:
        self.writer.close()


__all__ = ["TrainingLogger"]
