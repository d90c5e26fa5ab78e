"""How well can one window of data determine the coefficients? A Cramer-Rao bound on case 1.

The issue asks the real-time agent to recover h_li within 30 % in the sloshing phases. This
script asks what the data allow at best: with the true model form (the reference correlations
times four window-constant multipliers), started from the true state at each window, the
Fisher information of the window's observations about ln(multiplier) gives the smallest
standard deviation any unbiased estimate can have. Reported per window (the paper's fixed
windows, which see one window) and accumulated over the windows so far (what a real-time loop
that keeps the earlier windows' information could know); "alone" is the bound with the other
three coefficients known. The Hessian is ``trainers.memory.remember``'s (the one
``LaplaceMemory`` carries), so this also shows what that prior holds.

Usage: ``python experiments/information.py [--quick] [--out results/information]``
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from tankode._threads import single_threaded
from tankode.cases import get_case
from tankode.closures import ReferenceClosure, ScaledClosure
from tankode.simulate import simulate
from tankode.solver import NoGradient
from tankode.synthetic import solution_to_runs
from trainers.assimilate import AssimilationConfig, Assimilator
from trainers.cost import Window
from trainers.memory import remember

# ---- configuration ---------------------------------------------------------------------------
CASE = "case1"
NOISES = ("high", "low")
WINDOW_S = 600.0  # the paper's 10 minutes
SEED = 0  # the noise draw (the bound does not depend on it: the Fisher information is noise-free)
QUICK_DURATION_S = 1200.0
NAMES = ("h_vi", "h_li", "h_wv", "h_wl")
# -----------------------------------------------------------------------------------------------


def _bounds(noise: str, run, truth) -> list[dict]:
    (data,) = solution_to_runs(run, truth, noise=noise, seed=SEED)
    agent = ScaledClosure(ReferenceClosure(), torch.ones(4, dtype=torch.float64))
    a = Assimilator([data], AssimilationConfig(window_s=WINDOW_S), closure=agent)
    rows, cumulative = [], np.zeros((4, 4))
    for k, (t0, t1) in enumerate(a.windows):
        i = int(torch.argmin((truth.t_s - t0).abs()))
        s0 = truth.states[:, i].clone()  # the true state: the bound of a perfectly started window
        window = Window.from_runs(a.fleet.runs, t0, t1)
        t_eval = torch.cat([torch.tensor([t0], dtype=torch.float64), window.t_s]).unique()
        idx = torch.searchsorted(t_eval, window.t_s)
        states = a.predict(s0, t0, t_eval, NoGradient())
        H = remember(a, s0, t0, t_eval, idx, window, states, t1 - t0).hessian[0].numpy()
        # J is a time average (trainers/cost.py): the log-likelihood's Hessian is the number of
        # samples per channel times J's (all five channels sampled together in the synthetic runs).
        fisher = H * len(window)
        cumulative = cumulative + fisher
        cov = np.linalg.pinv(fisher)
        one = np.sqrt(np.diag(cov))
        acc = np.sqrt(np.diag(np.linalg.pinv(cumulative)))
        alone = 1.0 / np.sqrt(np.diag(fisher))
        corr = cov[1, 2] / (one[1] * one[2])
        rows.append({"window": k, "t0_min": t0 / 60, "t1_min": t1 / 60,
                     "sloshing_share": float((run.inputs.at(np.linspace(t0, t1, 121))[:, 7] > 0).mean()),
                     "std_ln_h_window": dict(zip(NAMES, one.tolist())),
                     "std_ln_h_alone": dict(zip(NAMES, alone.tolist())),
                     "std_ln_h_cumulative": dict(zip(NAMES, acc.tolist())), "corr_li_wv_window": float(corr)})
    return rows


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="two windows, high noise only (CI smoke run)")
    ap.add_argument("--out", default="results/information")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    run = get_case(CASE)
    if args.quick:
        run = run.until(QUICK_DURATION_S)
    with single_threaded():
        truth = simulate(run)
        summary = {"case": CASE, "window_s": WINDOW_S,
                   "noise": {n: _bounds(n, run, truth) for n in (NOISES[:1] if args.quick else NOISES)}}
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    lines = ["| noise | window [min] | sloshing share | std ln h_li, this window | h_li alone | corr(h_li, h_wv) "
             "| std ln h_li, windows so far | std ln h_wv, this window / so far |", "|---|---|---|---|---|---|---|---|"]
    for n, rows in summary["noise"].items():
        for r in rows:
            lines.append(f"| {n} | {r['t0_min']:.0f}-{r['t1_min']:.0f} | {r['sloshing_share']:.0%} "
                         f"| {r['std_ln_h_window']['h_li']:.2f} | {r['std_ln_h_alone']['h_li']:.3f} "
                         f"| {r['corr_li_wv_window']:.2f} | {r['std_ln_h_cumulative']['h_li']:.3f} "
                         f"| {r['std_ln_h_window']['h_wv']:.2f} / {r['std_ln_h_cumulative']['h_wv']:.3f} |")
    (out / "summary.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return summary


if __name__ == "__main__":
    main()
