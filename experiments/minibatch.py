"""Mini-batches: a share of the window's observations per gradient (paper, section 6.1.4).

Case 1 with high noise, fixed 10-minute windows, 20 L-BFGS iterations per window (on one batch
for 5 iterations, then a new draw). The agents learn from the first ``TRAIN_DURATION_S`` of the
stream with 80, 50, 20 and 5 % of the observation times per gradient, each repeated with
``len(SEEDS)`` seeds of the batch draws (same data, same untrained agent), and the full batch
(100 %, deterministic) once as the reference. Reported: J after each window's update (over the
whole window) against observation time, mean and min-max band over the repetitions
(``cost_vs_time.png``); the wall time per iteration; and the validation error of each final
agent, its prediction of the whole hour from the initial state (J against the data, pressure
RMSE against the clean truth). Tables: ``runs.csv`` (one row per window and repetition),
``table.csv`` (one row per fraction), ``summary.json``, ``summary.md``.

Usage: ``python experiments/minibatch.py [--quick] [--out results/minibatch]``
"""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from tankode.plotting import Curve, plot_cost_curves  # noqa: E402
from trainers.assimilate import AssimilationConfig  # noqa: E402
from trainers.studies import (MiniBatchStudyResult, minibatch_study, noise_floor_J, spread,  # noqa: E402
                              study_args, synthetic_data, write_rows)

# ---- configuration ---------------------------------------------------------------------------
CASE = "case1"
NOISE = "high"
NOISE_SEED = 0
AGENT_SEED = 0
FRACTIONS = (1.0, 0.8, 0.5, 0.2, 0.05)  # 1.0: the full-batch reference, run once
FULL = AssimilationConfig.paper(window_s=600.0, iters=20, iters_per_batch=5)
SEEDS = (1, 2, 3)  # repetitions (batch draws); the paper used 100
TRAIN_DURATION_S = 1200.0  # two windows: rest, then the onset of sloshing
QUICK = AssimilationConfig.paper(window_s=150.0, iters=2, iters_per_batch=1)
QUICK_FRACTIONS = (1.0, 0.5, 0.05)
QUICK_SEEDS = (1, 2)
QUICK_TRAIN_DURATION_S = 150.0  # one 2.5-minute window
QUICK_DURATION_S = 300.0  # validation on the first 5 minutes
PAPER = ("smaller batches are cheaper per iteration but noisier, and converge to a similar J "
         "(100 repetitions per batch size).")
# -----------------------------------------------------------------------------------------------


def main(argv: list[str] | None = None) -> dict:
    """Run the study and write its outputs under ``--out``; return the summary."""
    args = study_args(argv, __doc__.splitlines()[0], "one 2.5-minute window, 2 iterations, 3 fractions, 2 seeds",
                            "minibatch")
    quick, out = args.quick, args.out
    config, fractions, seeds, train_s = (QUICK, QUICK_FRACTIONS, QUICK_SEEDS, QUICK_TRAIN_DURATION_S) if quick \
        else (FULL, FRACTIONS, SEEDS, TRAIN_DURATION_S)
    case = synthetic_data(CASE, NOISE, NOISE_SEED, QUICK_DURATION_S if quick else None)
    res = minibatch_study(case, config, fractions, seeds, train_duration_s=train_s, agent_seed=AGENT_SEED)

    write_rows(out / "runs.csv", [{**row, "fraction": f, "seed": rec.config.seed}
                                  for f, recs in res.records.items() for rec in recs for row in rec.rows()])
    table = _table(res)
    write_rows(out / "table.csv", table)
    _figure(out / "cost_vs_time.png", res)
    summary = {"case": CASE, "noise": NOISE, "config": json.loads(config.to_json()), "seeds": list(seeds),
               "train_duration_s": train_s, "validation_duration_s": float(case.truth.t_s[-1]),
               "noise_floor_J": noise_floor_J(case), "table": table,
               "J_falls_in_first_window": all(rec.reports[0].cost_after < rec.reports[0].cost_before
                                              for recs in res.records.values() for rec in recs),
               "figures": sorted(p.name for p in out.glob("*.png"))}
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    (out / "summary.md").write_text(_markdown(summary))
    print((out / "summary.md").read_text())
    return summary


def _table(res: MiniBatchStudyResult) -> list[dict]:
    """One row per fraction: J after the last update, time per iteration, validation (mean, std, min, max)."""
    rows = []
    for frac, recs in res.records.items():
        last = spread(np.array([rec.J_after[-1] for rec in recs]))
        per_iter = spread(np.array([rec.wall_per_iter_s for rec in recs]))
        val = spread(np.array([v["J"] for v in res.validation[frac]]))
        p_err = spread(np.array([v["rmse"]["p_v_kPa"] for v in res.validation[frac]]))
        rows.append({"fraction": frac, "repetitions": len(recs),
                     **{f"J_last_window_{k}": float(v) for k, v in last.items()},
                     "wall_per_iter_s_mean": float(per_iter["mean"]),
                     "evals_per_iter_mean": float(np.mean([sum(r.n_evals for r in rec.reports)
                                                           / max(1, sum(r.n_iters for r in rec.reports))
                                                           for rec in recs])),
                     **{f"J_validation_{k}": float(v) for k, v in val.items()},
                     "rmse_p_v_kPa_mean": float(p_err["mean"]), "rmse_p_v_kPa_std": float(p_err["std"]),
                     "failed_validations": sum(bool(v["error"]) for v in res.validation[frac])})
    return rows


def _figure(path: Path, res: MiniBatchStudyResult) -> None:
    """J after each update (mean, min-max band) against observation time; validation J of the final agents."""
    fig, (ax_j, ax_v) = plt.subplots(1, 2, figsize=(12, 4.6), gridspec_kw={"width_ratios": [1.4, 1]})
    curves = {}
    for frac, recs in res.records.items():
        s = spread(np.stack([rec.J_after for rec in recs]))
        label = f"{frac:.0%} of the data" + (" (full batch)" if frac >= 1.0 else f", {len(recs)} seeds")
        curves[label] = Curve(recs[0].t_obs_min, s["mean"], s["min"], s["max"])
    plot_cost_curves(path, curves, xlabel="observation time [min]", ylabel="J after the window's update [-]",
                     title=f"J of each window after its update (mean, min-max band); {res.case.noise} noise",
                     floors={"noise floor": noise_floor_J(res.case)}, ax=ax_j)
    for i, (frac, vals) in enumerate(res.validation.items()):
        J = np.array([v["J"] for v in vals])
        ax_v.plot(np.full(len(J), i), J, "o", color="0.5", ms=4, alpha=0.7)
        ax_v.errorbar(i + 0.15, np.nanmean(J), yerr=np.nanstd(J), fmt="s", color="tab:red", capsize=4)
    ax_v.set_xticks(range(len(res.validation)), [f"{f:.0%}" for f in res.validation])
    ax_v.set_yscale("log")
    ax_v.set_xlabel("share of the observations per gradient [-]")
    ax_v.set_ylabel("J of the whole-run prediction [-]")
    ax_v.set_title(f"validation: final agents predict the first {res.case.truth.t_s[-1] / 60:.0f} min\n"
                   "(grey: each seed; red: mean +- std)", fontsize=10)
    ax_v.grid(alpha=0.3, which="both")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _markdown(summary: dict) -> str:
    """The summary table as Markdown."""
    lines = [f"# Mini-batch study (paper 6.1.4), {summary['case']}, {summary['noise']} noise", "",
             f"Fixed {summary['config']['window_s'] / 60:g}-minute windows, {summary['config']['iters']} iterations per "
             f"window ({summary['config']['iters_per_batch']} per batch draw), trained on the first "
             f"{summary['train_duration_s'] / 60:g} min; seeds of the batch draws {summary['seeds']}; validation: "
             f"the final agent's prediction of the first {summary['validation_duration_s'] / 60:g} min from t = 0.", "",
             f"Paper: {PAPER}", "",
             "| batch | runs | J last window, mean (min-max) | s / iteration | evaluations / iteration | "
             "J validation, mean +- std | RMSE p_v [kPa] |", "|---|---|---|---|---|---|---|"]
    for r in summary["table"]:
        lines.append(f"| {r['fraction']:.0%} | {r['repetitions']} | {r['J_last_window_mean']:.3g} "
                     f"({r['J_last_window_min']:.3g}-{r['J_last_window_max']:.3g}) | {r['wall_per_iter_s_mean']:.2f} | "
                     f"{r['evals_per_iter_mean']:.2f} | {r['J_validation_mean']:.3g} +- {r['J_validation_std']:.2g} | "
                     f"{r['rmse_p_v_kPa_mean']:.2f} +- {r['rmse_p_v_kPa_std']:.2f} |")
    lines += ["", f"Noise floor of J: {summary['noise_floor_J']:g}."]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
