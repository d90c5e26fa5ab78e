"""Shared drivers of the assimilation studies (paper, sections 6.1.2-6.1.4).

* :func:`synthetic_data`: a case, its clean truth and noisy measurements.
* :func:`assimilate_stream`: the real-time loop recording J after each window's update and
  snapshots of the agent at chosen observation times (what the loop knew then).
* :func:`noise_study` / :func:`write_noise_study`: one case at several noise levels (the noise
  study with growing windows, 6.1.2, and the fixed-window study, 6.1.3): J against observation
  time, and whole-hour predictions of the agents of chosen times.
* :func:`whole_run_error`: how well an agent predicts a whole run from its initial state.

The scripts in ``experiments/`` hold the configuration; the logic shared between them is here.
"""

from __future__ import annotations

import copy
import csv
import dataclasses
import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from tankode.cases import get_case
from tankode.closures import Closure, MLPClosure
from tankode.errors import SimulationError
from tankode.run import Run
from tankode.simulation import Solution, simulate
from tankode.synthetic import solution_to_runs

from .assimilate import AssimilationConfig, Assimilator, WindowReport, window_edges
from .evaluate import rmse_by_channel, validation_cost

# Units in which the studies report a prediction error: (channel, factor from SI, unit).
_REPORT_UNITS = {"p_v_Pa": (1e-3, "kPa"), "T_v_K": (1.0, "K"), "T_l_K": (1.0, "K"), "T_w_K": (1.0, "K"),
                 "H_l_m": (1e3, "mm")}


@dataclass(frozen=True)
class SyntheticCase:
    """A case run (no observations), its clean reference simulation and the noisy measured run."""

    run: Run
    truth: Solution
    data: Run
    noise: str


def synthetic_data(case: str, noise: str, seed: int = 0, duration_s: float | None = None) -> SyntheticCase:
    """Simulate ``case`` with the reference closure and measure it with ``noise`` ("clean", "low", "high").

    ``duration_s`` cuts the case (quick runs); the truth is sampled every 10 s as the data.
    """
    run = get_case(case)
    if duration_s is not None:
        run = run.until(duration_s)
    truth = simulate(run)
    (data,) = solution_to_runs(run, truth, noise=noise, seed=seed)
    return SyntheticCase(run, truth, data, noise)


def _print_now(line: str) -> None:
    """Print a progress line immediately (also when stdout is a file)."""
    print(line, flush=True)


@dataclass
class StreamRecord:
    """What one pass of the real-time loop over a stream recorded.

    Attributes:
        label: a name for tables and legends.
        config: the assimilation configuration.
        reports: one ``WindowReport`` per window (J before / after the update, timings).
        snapshots: agent after the update of the window ending at each requested time (s).
        closure: the final agent.
        train_wall_s: wall-clock time of the whole loop (s).
    """

    label: str
    config: AssimilationConfig
    reports: list[WindowReport]
    snapshots: dict[float, MLPClosure]
    closure: MLPClosure
    train_wall_s: float

    @property
    def t_obs_min(self) -> np.ndarray:
        """Observation time (end of each window) in minutes."""
        return np.array([r.t1_s for r in self.reports]) / 60.0

    @property
    def J_after(self) -> np.ndarray:
        """J after each window's update (the minimum of J the loop reached on that window)."""
        return np.array([r.cost_after for r in self.reports])

    @property
    def wall_per_iter_s(self) -> float:
        """Mean wall-clock time of one L-BFGS iteration over the stream (s)."""
        n = sum(r.n_iters for r in self.reports)
        return sum(r.wall_s for r in self.reports) / max(n, 1)

    def rows(self) -> list[dict]:
        """One table row per window."""
        return [{"label": self.label, "window": r.index, "t0_min": r.t0_s / 60, "t_obs_min": r.t1_s / 60,
                 "J_before": r.cost_before, "J_after": r.cost_after, "iters": r.n_iters, "evals": r.n_evals,
                 "wall_s": r.wall_s, "note": r.note} for r in self.reports]


def assimilate_stream(runs: Sequence[Run], config: AssimilationConfig, *, snapshot_times_s: Sequence[float] = (),
                      closure: MLPClosure | None = None, label: str = "", logdir: str | Path | None = None,
                      log: Callable[[str], None] | None = _print_now) -> StreamRecord:
    """Run the real-time loop on ``runs`` and keep the agent after the windows ending at ``snapshot_times_s``.

    Args:
        runs: measured runs (one agent for all).
        config: window length, mode, iterations, mini-batch fraction, seed.
        snapshot_times_s: observation times (s) at which to copy the agent; a time matches the
            window whose end is within 1 s of it.
        closure: the initial agent (a fresh seeded ``MLPClosure`` if None); it is trained in place.
        label: name of the record.
        logdir: TensorBoard directory (None: no logging).
        log: where to print one line per window (None: silent).
    """
    assimilator = Assimilator(list(runs), config, closure=closure)
    wanted = [float(t) for t in snapshot_times_s]
    snapshots: dict[float, MLPClosure] = {}

    def on_window(r: WindowReport) -> None:
        for t in wanted:
            if abs(r.t1_s - t) <= 1.0:
                snapshots[t] = copy.deepcopy(assimilator.closure)
        if log is not None:
            log(f"{label} window {r.index} (t = {r.t1_s / 60:g} min): J {r.cost_before:.3g} -> {r.cost_after:.3g} "
                f"({r.n_iters} it, {r.wall_s:.0f} s) {r.note}")

    start = time.perf_counter()
    result = assimilator.run(logdir=logdir, on_window=on_window)
    return StreamRecord(label, config, result.reports, snapshots, result.closure, time.perf_counter() - start)


def whole_run_error(agent: Closure, case: SyntheticCase) -> dict:
    """Prediction of the whole (uncut) run by ``agent`` from its initial state: observations, J, RMSE.

    Returns ``{"obs": (T, 5) array or None, "J": J against the measured data, "rmse": per channel in
    kPa / K / mm, "error": message}``; an agent whose ODE cannot be integrated gives NaNs and the message.
    """
    try:
        pred = simulate(case.run, agent, t_eval=case.truth.t_s)
        val = validation_cost(agent, [case.data])
    except SimulationError as err:
        nan = {_unit_key(c): math.nan for c in _REPORT_UNITS}
        return {"obs": None, "J": math.nan, "rmse": nan, "error": str(err).splitlines()[0]}
    rmse = rmse_by_channel(pred.observations[0], case.truth.observations[0])
    rmse_units = {_unit_key(c): rmse[c] * f for c, (f, _) in _REPORT_UNITS.items()}
    return {"obs": pred.observations[0].numpy(), "J": val["J"], "rmse": rmse_units, "error": ""}


def _unit_key(channel: str) -> str:
    """``p_v_Pa`` -> ``p_v_kPa``: the channel name with the reporting unit."""
    return f"{channel.rsplit('_', 1)[0]}_{_REPORT_UNITS[channel][1]}"


# -- the noise study (growing or fixed windows at several noise levels) ------------------------------


@dataclass
class NoiseStudyResult:
    """Records and whole-run predictions of a noise study, per noise level."""

    case: str
    config: AssimilationConfig
    cases: dict[str, SyntheticCase] = field(default_factory=dict)
    records: dict[str, StreamRecord] = field(default_factory=dict)
    predictions: dict[str, dict[float, dict]] = field(default_factory=dict)  # level -> t_s -> whole_run_error


def noise_study(case: str, levels: Sequence[str], config: AssimilationConfig, snapshot_times_s: Sequence[float],
                *, duration_s: float | None = None, seed: int = 0, logdir: Path | None = None) -> NoiseStudyResult:
    """Assimilate ``case`` measured at each noise level; predict the whole run with the agents of chosen times.

    Every level starts from the same untrained agent (``config.seed``) and uses noise seed ``seed``.
    """
    res = NoiseStudyResult(case, config)
    for level in levels:
        data = synthetic_data(case, level, seed, duration_s)
        rec = assimilate_stream([data.data], config, snapshot_times_s=snapshot_times_s, label=level,
                                logdir=None if logdir is None else logdir / level)
        res.cases[level], res.records[level] = data, rec
        res.predictions[level] = {t: whole_run_error(agent, data) for t, agent in rec.snapshots.items()}
    return res


def write_rows(path: Path, rows: Sequence[dict]) -> None:
    """Write dict rows (same keys) as CSV."""
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def write_noise_study(out: Path, res: NoiseStudyResult, *, title: str, paper: str) -> dict:
    """Write a noise study's figures, ``cost_vs_time.csv``, ``summary.json`` and ``summary.md``; return the summary.

    Figures: ``cost_vs_time.png`` (J after each update against observation time, one curve per
    level) and ``prediction_<level>.png`` (data and the whole-run prediction of the agent of each
    snapshot time). ``paper`` is a sentence on what the paper found, quoted in ``summary.md``.
    """
    from tankode.plotting import Curve, plot_cost_curves, plot_predictions

    out.mkdir(parents=True, exist_ok=True)
    rows = [row for rec in res.records.values() for row in rec.rows()]
    write_rows(out / "cost_vs_time.csv", rows)
    curves = {f"{lvl} noise": Curve(rec.t_obs_min, rec.J_after) for lvl, rec in res.records.items()}
    by_value: dict[float, list[str]] = {}
    for lvl in res.records:
        if lvl != "clean":
            by_value.setdefault(noise_floor_J(res.cases[lvl]), []).append(lvl)
    floors = {f"noise floor ({', '.join(lvls)} noise)": v for v, lvls in by_value.items()}
    plot_cost_curves(out / "cost_vs_time.png", curves, xlabel="observation time [min]",
                     ylabel="J after the window's update [-]", title=title, floors=floors)
    for lvl, preds in res.predictions.items():
        c = res.cases[lvl]
        plot_predictions(out / f"prediction_{lvl}.png", c.truth.t_s.numpy(), c.truth.observations[0].numpy(), c.data,
                         {t: p["obs"] for t, p in sorted(preds.items())},
                         title=f"{res.case}, {lvl} noise, {res.config.mode} windows: whole-run prediction of the agent "
                               f"at each observation time")

    levels = {}
    for lvl, rec in res.records.items():
        J = rec.J_after
        levels[lvl] = {
            "t_obs_min": rec.t_obs_min.tolist(), "J_before": [r.cost_before for r in rec.reports],
            "J_after": J.tolist(), "J_first_update": [rec.reports[0].cost_before, rec.reports[0].cost_after],
            "J_falls_in_first_window": bool(rec.reports[0].cost_after < rec.reports[0].cost_before),
            "noise_floor_J": noise_floor_J(res.cases[lvl]),
            "train_wall_s": rec.train_wall_s, "wall_per_iter_s": rec.wall_per_iter_s,
            "predictions": {f"{t / 60:g} min": {k: v for k, v in p.items() if k != "obs"}
                            for t, p in sorted(res.predictions[lvl].items())},
        }
    summary = {"case": res.case, "mode": res.config.mode, "config": json.loads(res.config.to_json()),
               "levels": levels, "figures": sorted(p.name for p in out.glob("*.png"))}
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    (out / "summary.md").write_text(_noise_markdown(summary, title, paper))
    return summary


def _n_measured(run: Run) -> int:
    """Number of observation channels with at least one sample."""
    return int(np.isfinite(run.observations.values).any(axis=0).sum())


def _noise_markdown(summary: dict, title: str, paper: str) -> str:
    """The summary table of a noise study as Markdown."""
    levels = summary["levels"]
    first = next(iter(levels.values()))
    lines = [f"# {title}", "", f"Case {summary['case']}, {summary['mode']} windows of "
             f"{summary['config']['window_s'] / 60:g} min, {summary['config']['iters']} L-BFGS iterations per window.",
             "", f"Paper: {paper}", "", "J after each window's update (noise floor 2.5 for low/high noise, 0 for clean):",
             "", "| noise | " + " | ".join(f"{t:g} min" for t in first["t_obs_min"]) + " | training [s] | s/iteration |",
             "|---|" + "---|" * (len(first["t_obs_min"]) + 2)]
    for lvl, d in levels.items():
        lines.append(f"| {lvl} | " + " | ".join(f"{j:.3g}" for j in d["J_after"])
                     + f" | {d['train_wall_s']:.0f} | {d['wall_per_iter_s']:.2f} |")
    lines += ["", "Whole-run prediction of the agent at each observation time (J against the data; "
              "RMSE against the clean truth):", "",
              "| noise | agent at | J whole run | RMSE p_v [kPa] | RMSE T_l [K] | RMSE T_w [K] | RMSE H_l [mm] |",
              "|---|---|---|---|---|---|---|"]
    for lvl, d in levels.items():
        for t, p in d["predictions"].items():
            r = p["rmse"]
            lines.append(f"| {lvl} | {t} | {p['J']:.3g} | {r['p_v_kPa']:.2f} | {r['T_l_K']:.3f} | {r['T_w_K']:.3f} | "
                         f"{r['H_l_mm']:.2f} |" + (f" {p['error']}" if p["error"] else ""))
    return "\n".join(lines) + "\n"


@dataclass(frozen=True)
class NoiseStudySpec:
    """Configuration of a noise-study script: what its full and its ``--quick`` mode run.

    Attributes:
        name: default output folder ``results/<name>``.
        title: figure and summary title.
        paper: one sentence on what the paper found (quoted in ``summary.md``).
        full: assimilation configuration of the full mode (window length, mode, iterations).
        case: the environment.
        levels: noise levels.
        seed: noise seed (the untrained agent's seed is ``full.seed``).
        snapshots_s: observation times (s) whose agents predict the whole run (full mode).
        quick_window_s, quick_iters, quick_duration_s: the quick mode cuts the case at
            ``quick_duration_s`` and runs ``full`` with these window length and iterations; its
            snapshots are the ends of all its windows.
    """

    name: str
    title: str
    paper: str
    full: AssimilationConfig
    case: str = "case1"
    levels: tuple[str, ...] = ("clean", "low", "high")
    seed: int = 0
    snapshots_s: tuple[float, ...] = (600.0, 1200.0, 2400.0)
    quick_window_s: float = 150.0
    quick_iters: int = 2
    quick_duration_s: float = 300.0

    def mode(self, quick: bool) -> tuple[AssimilationConfig, tuple[float, ...], float | None]:
        """(configuration, snapshot times [s], duration [s] or None for the whole case) of a mode."""
        if not quick:
            return self.full, self.snapshots_s, None
        config = dataclasses.replace(self.full, window_s=self.quick_window_s, iters=self.quick_iters)
        ends = tuple(t1 for _, t1 in window_edges(0.0, self.quick_duration_s, self.quick_window_s))
        return config, ends, self.quick_duration_s


@dataclass(frozen=True)
class StudyArgs:
    """The command line every study script shares.

    Attributes:
        quick: the CI smoke run instead of the full study.
        out: the output folder (created).
        jobs: processes for a study's independent trainings (1: in this process).
    """

    quick: bool
    out: Path
    jobs: int


def study_args(argv: Sequence[str] | None, description: str, quick_help: str, name: str) -> StudyArgs:
    """Parse ``--quick``, ``--out`` (default ``results/<name>``) and ``--jobs``; create the folder."""
    import argparse

    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--quick", action="store_true", help=f"{quick_help} (CI smoke run)")
    ap.add_argument("--out", default=f"results/{name}")
    ap.add_argument("--jobs", type=int, default=1,
                    help="processes for independent trainings, where the study has several (default 1)")
    args = ap.parse_args(argv)
    if args.jobs < 1:
        ap.error(f"--jobs must be at least 1, got {args.jobs}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    return StudyArgs(args.quick, out, args.jobs)


def noise_study_main(spec: NoiseStudySpec, argv: Sequence[str] | None = None, description: str = "") -> dict:
    """Command line of a noise-study script (``--quick``, ``--out``): run, write the outputs, return the summary."""
    args = study_args(argv, description or spec.title, f"{spec.quick_duration_s / 60:g} minutes of data, "
                      f"{spec.quick_iters} iterations per window", spec.name)
    quick, out = args.quick, args.out
    config, snapshots_s, duration_s = spec.mode(quick)
    res = noise_study(spec.case, spec.levels, config, snapshots_s, duration_s=duration_s, seed=spec.seed,
                      logdir=out / "tensorboard")
    summary = write_noise_study(out, res, title=spec.title, paper=spec.paper)
    print((out / "summary.md").read_text())
    return summary


# -- mini-batches ---------------------------------------------------------------------------------


@dataclass
class MiniBatchStudyResult:
    """Repeated assimilations of one stream with several mini-batch fractions.

    Attributes:
        case: the synthetic case (the whole run: the validation data).
        train_duration_s: the agents are trained on the first ``train_duration_s`` of the data.
        records: fraction -> one ``StreamRecord`` per repetition (seed of the batch draws).
        validation: fraction -> ``whole_run_error`` of each repetition's final agent (without ``obs``).
    """

    case: SyntheticCase
    train_duration_s: float
    records: dict[float, list[StreamRecord]] = field(default_factory=dict)
    validation: dict[float, list[dict]] = field(default_factory=dict)


def minibatch_study(case: SyntheticCase, config: AssimilationConfig, fractions: Sequence[float],
                    seeds: Sequence[int], *, train_duration_s: float, agent_seed: int = 0) -> MiniBatchStudyResult:
    """Assimilate the first ``train_duration_s`` of ``case`` with each batch fraction, once per seed.

    Every repetition starts from the same untrained agent (``agent_seed``) on the same noisy data;
    only the batch draws (``config.seed``) change. A fraction of 1 draws nothing and runs once.
    Each final agent then predicts the whole run from its initial state (validation).
    """
    train = case.data.until(train_duration_s)
    res = MiniBatchStudyResult(case, train_duration_s)
    for frac in fractions:
        for seed in (seeds[:1] if frac >= 1.0 else seeds):
            cfg = dataclasses.replace(config, batch_fraction=frac, seed=int(seed))
            rec = assimilate_stream([train], cfg, closure=cfg.agent(agent_seed),
                                    label=f"{frac:.0%} seed {seed}")
            err = whole_run_error(rec.closure, case)
            err.pop("obs")
            res.records.setdefault(frac, []).append(rec)
            res.validation.setdefault(frac, []).append(err)
    return res


def spread(values: np.ndarray, axis: int = 0) -> dict[str, np.ndarray]:
    """Mean, standard deviation, min and max of ``values`` along ``axis`` (NaN-aware)."""
    return {"mean": np.nanmean(values, axis), "std": np.nanstd(values, axis), "min": np.nanmin(values, axis),
            "max": np.nanmax(values, axis)}


def noise_floor_J(case: SyntheticCase) -> float:
    """J of the truth against the case's data: 0.5 per measured channel, 0 for clean data."""
    return 0.0 if case.noise == "clean" else 0.5 * _n_measured(case.data)


__all__ = ["SyntheticCase", "synthetic_data", "StreamRecord", "assimilate_stream", "whole_run_error",
           "NoiseStudyResult", "noise_study", "write_noise_study", "NoiseStudySpec", "noise_study_main", "study_args", "StudyArgs", "write_rows", "MiniBatchStudyResult", "minibatch_study", "spread", "noise_floor_J"]
