"""One model of the NASA MHTB tank, checked on the test it was not trained on, in all three rotations.

The three digitised liquid-hydrogen tests of the 18.1 m3 MHTB tank (P263968K: 25 % fill, 18.8 W;
P263981D: 90 %, 54.1 W; P263981T: 50 %, 51.0 W; ``../shared/data/mhtb/``, read in place) train
one model, ``MODEL``: the paper's agent (from constant coefficients) on the lumped wall with a
node of its own for the dry wall above the liquid (``dry_wall_node``), its sheet resistance
trained with the agent from 3 K/W, growing 30-minute windows, the Rosenbrock integrator with
back-propagation. It was chosen on P263968K and P263981D (``mhtb_agent.py``): the package's
default agent and two-node wall, streamed the same way, did not fit the growing span (its J
rose from 19 to 111 over seven 2-hour windows, P263968K held out at 4.6 kPa). For each rotation
the model is trained on two tests, as one fleet, and predicts the third from its measured state
at t = 0 and its inputs alone; the pressure, ullage and liquid temperature RMSE are scored on
the samples the published energy-balance model (EBM) covers, beside the EBM's. Then the model is
trained on all three tests, saved (``OUT/model``) and applied by ``tankode predict OUT/model
RUN.json`` to each test, given only its metadata and inputs, as a user would.

What is learned: the agent's weights (four bounded heat-transfer coefficients) and the dry wall's
sheet resistance. What is fixed: the tank's geometry, the shell's heat capacity (estimated from
the aluminium shell, ``tankode.run``), the measured heat load and the 0D model.

Usage: ``python experiments/mhtb_rotations.py [--quick] [--jobs 2] [--out results/mhtb_rotations]``
(``--jobs N`` runs the four trainings in N processes.)
"""

from __future__ import annotations

import dataclasses
import json
import multiprocessing
import subprocess
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from common import MHTB_ALL_RUNS, MHTB_CHANNELS as CHANNELS, MHTB_DATA, ebm_predictions, mhtb_runs, score_on_ebm_samples  # noqa: E402
from tankode.compare import channel_rmse, solution_observations  # noqa: E402
from tankode.saved import save_model  # noqa: E402
from tankode.mechanisms import make_mechanism  # noqa: E402
from tankode.solver import Backprop  # noqa: E402
from trainers.assimilate import AssimilationConfig, Assimilator  # noqa: E402
from trainers.studies import study_args  # noqa: E402

# ---- configuration ---------------------------------------------------------------------------
# The model chosen on two tests (module docstring; ``mhtb_agent.py``'s "dry_wall_node_trained_from_3"):
# 30-minute windows (the tests are sampled every 3-13 minutes), 10 L-BFGS iterations, at most
# 300 s per update (six times faster than real time).
CONFIG = AssimilationConfig.paper(mode="growing", window_s=1800.0, iters=10, integrator="rosenbrock",
                                  gradient=Backprop(), train_mechanisms=("dry_wall_node",), update_budget_s=300.0, seed=0)
SHELL_START_K_PER_W = 3.0  # the dry wall's sheet resistance the training starts from


def _mechanisms() -> tuple:
    """The model's mechanisms, fresh (training sets their values in place)."""
    return (make_mechanism("dry_wall_node", R_sheet_K_per_W=SHELL_START_K_PER_W),)


QUICK_CONFIG = dataclasses.replace(CONFIG, iters=2)
QUICK_UNTIL_S = 3600.0  # --quick: every test cut to 1 h, one rotation
# -----------------------------------------------------------------------------------------------


def _runs(quick: bool) -> dict:
    """The three tests, started from their measured state (cut to ``QUICK_UNTIL_S`` for --quick)."""
    runs = {r.name: r.with_measured_initial() for r in mhtb_runs(names=MHTB_ALL_RUNS)}
    return {n: r.until(QUICK_UNTIL_S) for n, r in runs.items()} if quick else runs


def _training(trained_on: tuple, scored: tuple, held_out: bool, quick: bool, model_dir: str | None):
    """Train one model on the tests ``trained_on`` (one fleet) and score it on ``scored``.

    Runs in a worker process where ``--jobs`` > 1 (one torch thread each, so that the jobs do not
    contend for the cores). Returns (rows, {test: predicted observations}); saves the model to
    ``model_dir`` when given.
    """
    import torch

    torch.set_num_threads(1)
    config = QUICK_CONFIG if quick else CONFIG
    runs = _runs(quick)
    ebm = ebm_predictions(list(runs.values()))
    a = Assimilator([runs[n] for n in trained_on], config, mechanisms=_mechanisms())
    start = time.perf_counter()
    tag = "+".join(trained_on)
    result = a.run(on_window=lambda r: print(f"{tag}: window {r.index + 1}/{len(a.windows)} J {r.cost_before:.3g} -> "
                                             f"{r.cost_after:.3g} in {r.wall_s:.0f} s", flush=True))
    wall_s = time.perf_counter() - start
    mechanisms = tuple(a.model.mechanisms)
    shell = next((m.values_dict()["R_sheet_K_per_W"] for m in mechanisms if m.id == "dry_wall_node"), None)
    if model_dir is not None:
        save_model(Path(model_dir), result.closure, next(iter(runs.values())).fluid,
                   {"trained_on": list(trained_on), "config": config.to_json()}, mechanisms=mechanisms)
    rows, predicted = [], {}
    label = "trained on the other two" if held_out else "trained on all three"
    for name in scored:
        rmse, sol, error = score_on_ebm_samples(runs[name], result.closure, mechanisms, ebm[name])
        rows.append({"test": name, "model": label, "trained_on": list(trained_on), "held_out": held_out,
                     "rmse": rmse, "error": error, "train_s": wall_s, "R_sheet_K_per_W": shell})
        predicted[name] = None if sol is None else solution_observations(sol)
        print(json.dumps(rows[-1]), flush=True)
    return rows, predicted


def main(argv=None) -> dict:
    args = study_args(argv, __doc__.splitlines()[0], "tests cut to 1 h, 2 iterations, one rotation",
                      "mhtb_rotations")
    quick, out = args.quick, args.out
    config = QUICK_CONFIG if quick else CONFIG
    runs = _runs(quick)
    ebm = ebm_predictions(list(runs.values()))
    rows = []
    for name, run in runs.items():
        rmse = channel_rmse(run, ebm[name], CHANNELS)
        rows.append({"test": name, "model": "EBM (published)", "trained_on": [], "held_out": None,
                     "rmse": {c: rmse[c]["rmse"] for c in CHANNELS}})

    names = tuple(runs)
    # The model on all three first: its training is the longest, so two jobs finish together.
    trainings = [(names, names, False, quick, str(out / "model"))]
    trainings += [(tuple(n for n in names if n != held), (held,), True, quick, None) for held in names]
    if quick:
        trainings = trainings[:2]
    if args.jobs == 1:
        results = [_training(*t) for t in trainings]
    else:
        with ProcessPoolExecutor(args.jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
            results = list(pool.map(_training, *zip(*trainings)))
    predicted = {}
    for (_, _, held_out, _, _), (job_rows, job_predicted) in zip(trainings, results):
        rows += job_rows
        predicted.update({(name, "held out" if held_out else "all three"): obs for name, obs in job_predicted.items()})

    predict_s = {}
    for name in runs:  # the saved model on the test as given: its metadata and inputs only
        start = time.perf_counter()
        source = MHTB_DATA / f"{name}.json"
        if quick:
            source = _cut(source, out / "cut", QUICK_UNTIL_S)
        proc = subprocess.run([sys.executable, "-m", "tankode.cli", "predict", str(out / "model"), str(source),
                               "--out", str(out / "predict" / name)], capture_output=True, text=True)
        if proc.returncode != 0:
            raise RuntimeError(f"tankode predict on {name} failed: {proc.stderr.strip()}")
        predict_s[name] = time.perf_counter() - start

    summary = {"config": json.loads(config.to_json()), "rows": rows, "predict_s": predict_s, "jobs": args.jobs}
    (out / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
    (out / "table.md").write_text(_markdown(rows, predict_s))
    for name, run in runs.items():
        _figure(out / f"mhtb_rotations_{name}.png", run, ebm[name], predicted.get((name, "held out")),
                predicted.get((name, "all three")))
    print((out / "table.md").read_text())
    return summary


def _cut(source: Path, folder: Path, until_s: float) -> Path:
    """A copy of an MHTB test cut to ``until_s`` in ``folder`` (for --quick), written by tankode."""
    from tankode.run_io import read_run, write_run

    json_path, _ = write_run(read_run(source).until(until_s), folder)
    return json_path


def _markdown(rows, predict_s) -> str:
    lines = ["| test | model | trained on | p_v RMSE [Pa] | T_v RMSE [K] | T_l RMSE [K] | R_sheet [K/W] | training [s] |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if r["rmse"] is None:
            cells = f"failed: {r['error']} | | "
        else:
            cells = f"{r['rmse']['p_v_Pa']:.0f} | {r['rmse']['T_v_K']:.2f} | {r['rmse']['T_l_K']:.3f}"
        shell = "" if r.get("R_sheet_K_per_W") is None else f"{r['R_sheet_K_per_W']:.1f}"
        train = "" if r.get("train_s") is None else f"{r['train_s']:.0f}"
        lines.append(f"| {r['test']} | {r['model']} | {', '.join(r['trained_on'])} | {cells} | {shell} | {train} |")
    lines.append("")
    lines.append("`tankode predict` with the model trained on all three, per test (s): "
                 + ", ".join(f"{n} {s:.1f}" for n, s in predict_s.items()))
    return "\n".join(lines) + "\n"


def _figure(path, run, ebm, held_out, all_three):
    fig, ax = plt.subplots(figsize=(7, 4))
    t, p = run.observations.channel("p_v_Pa")
    ax.plot(t / 3600, p / 1e3, "k.", label="measured")
    te, pe = ebm.channel("p_v_Pa")
    ax.plot(te / 3600, pe / 1e3, "C2--", label="EBM (published)")
    for obs, label, style in ((held_out, "tankode, trained on the other two", "C0-"),
                              (all_three, "tankode, trained on all three", "C1-")):
        if obs is not None:
            tp, pp = obs.channel("p_v_Pa")
            ax.plot(tp / 3600, pp / 1e3, style, label=label)
    ax.set_xlabel("t [h]")
    ax.set_ylabel("ullage pressure [kPa]")
    ax.set_title(run.name)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
