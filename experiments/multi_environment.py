"""Multi-environment assimilation: does an agent trained on more tanks predict unseen tanks better?

The paper (section 6.2) claims that a closure learned from more environments generalises
better. Measured here on environments drawn from a generator of tanks, fills and operation
schedules that tankode did not write: ``tests/nodal_sim.py random_SEED`` (random tank size,
wall, fill, pressure, 4-8 operating segments), with the McAdams natural-convection law as the
truth (tankode uses neither it nor the nodal model), run as a subprocess. One tank shape, as
one batched ODE needs (``SHAPE``); seeds of other shapes are skipped.

* A test set of ``N_TEST`` environments is set aside; the other ``N_POOL`` form the training pool.
* Each draw ``d`` orders the pool at random (seed ``d``); the agent for ``N`` environments is
  trained on the first ``N`` of that order (so within a draw the sets are nested), from the same
  untrained agent (``CONFIG.agent(d)``), with fixed 10-minute windows, 20 bounded L-BFGS
  iterations, the Rosenbrock integrator and back-propagation (``CONFIG``).
* Every agent is scored on the same unseen test environments: J (``trainers/cost.py``: 0.5 per
  measured channel at the noise floor, 2.5 for the five) of its prediction of each whole test
  run from its initial state and inputs, in the physics it was trained in (the configured
  two-node wall with its trained sheet resistance); the score is the mean and the median over
  the test environments. A prediction that cannot be integrated counts as failed (reported).
* Baselines on the same test set, with the untrained model's wall: each draw's untrained agent
  (N = 0) and tankode's reference correlations (the paper's laws, not the truth's).

Usage: ``python experiments/multi_environment.py [--quick] [--duration S] [--n-train N ...] [--pool N]
[--test N] [--draws N] [--out results/multi_environment]`` (the options shrink the study's scope from
its defaults; the summary records the scope that was run).
Writes ``summary.json``, ``table.md`` and ``heldout_loss.png``; the environments are kept under
``OUT/environments`` and reused by a later run with the same configuration.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import subprocess
import sys
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from tankode.closures import ReferenceClosure  # noqa: E402
from tankode.errors import SimulationError  # noqa: E402
from tankode.run_io import read_run  # noqa: E402
from tankode.solver import Backprop  # noqa: E402
from trainers.assimilate import AssimilationConfig, Assimilator  # noqa: E402
from trainers.evaluate import validation_cost  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
GENERATOR = ROOT / "tests" / "nodal_sim.py"

# ---- configuration ---------------------------------------------------------------------------
LAW = "mcadams"  # the truth's heat-transfer law (tests/nodal_sim.py), not one of tankode's
NOISE = "low"
SHAPE = "vertical_cylinder"  # the paper's tank shape; about one generated tank in four
DURATION_S = 1800.0  # each environment: 30 minutes, three 10-minute windows
FIRST_SEED = 1000  # generator seeds tried in order from here
N_TRAIN = (1, 2, 4, 8, 16)
N_POOL = 24
N_TEST = 8
DRAWS = 3
# No time budget: the study measures what N environments teach, and a batch of 16 tanks takes
# longer per update than one; a budget would teach the larger fleets less. The bulk's flash
# alone: the tanks are tankode's own, whose liquid flashes so.
CONFIG = AssimilationConfig(window_s=600.0, mode="fixed", iters=20, integrator="rosenbrock", gradient=Backprop(),
                            update_budget_s=math.inf, boiling="bulk")
# --quick (CI smoke run): three horizontal cylinders (seeds 2, 3 and 7), 2 minutes each, one
# window, two iterations.
QUICK = {"shape": "horizontal_cylinder", "seeds": (2, 3, 7), "duration_s": 120.0, "n_train": (1, 2), "n_pool": 2,
         "n_test": 1, "draws": 1, "config": dataclasses.replace(CONFIG, window_s=120.0, iters=2)}
# -----------------------------------------------------------------------------------------------


# One generator process writes a whole batch: it checks each seed's shape with the generator's
# own random_scenario before simulating (a process costs seconds of imports; a 30-minute
# environment a second of integration). The study's process never imports the generator.
_DRIVER = """
import json, sys
sys.path.insert(0, sys.argv[1])
import nodal_sim
folder, shape, duration, law, noise, count = sys.argv[2], sys.argv[3], float(sys.argv[4]), sys.argv[5], sys.argv[6], int(sys.argv[7])
seeds = [int(s) for s in sys.argv[8:]]
for seed in seeds:
    if count == 0:
        break
    if nodal_sim.random_scenario(seed)["tank"]["shape"] != shape:
        print(json.dumps({"seed": seed, "shape": "other"}), flush=True)
        continue
    try:
        res = nodal_sim.simulate_run(f"random_{seed}", law=law, noise=noise, seed=seed, out_dir=folder,
                                     name=f"env{seed}", duration_s=duration)
    except Exception as err:
        print(json.dumps({"seed": seed, "failed": str(err).splitlines()[0]}), flush=True)
        continue
    count -= 1
    print(json.dumps({"seed": seed, "shape": shape, "json": str(res["json"])}), flush=True)
"""


def environments(folder: Path, shape: str, count: int, duration_s: float, seeds=None) -> list[Path]:
    """The first ``count`` generated environments of ``shape`` (seeds from ``FIRST_SEED``, or ``seeds``).

    Environments already in ``folder`` are reused; seeds of other shapes (and seeds the generator
    fails on) are listed in ``folder/skipped.json`` and not tried again.
    """
    folder.mkdir(parents=True, exist_ok=True)
    skipped = folder / "skipped.json"
    other = set(json.loads(skipped.read_text())) if skipped.exists() else set()
    candidates = list(seeds) if seeds is not None else list(range(FIRST_SEED, FIRST_SEED + 100 * count))
    found = [s for s in candidates if (folder / f"env{s}.json").exists()]
    todo = [s for s in candidates if s not in other and s not in found]
    if len(found) < count:
        proc = subprocess.Popen([sys.executable, "-c", _DRIVER, str(GENERATOR.parent), str(folder), shape,
                                 str(duration_s), LAW, NOISE, str(count - len(found)), *map(str, todo)],
                                stdout=subprocess.PIPE, text=True)
        for line in proc.stdout:
            item = json.loads(line)
            if "json" in item:
                found.append(item["seed"])
            else:
                other.add(item["seed"])
                if "failed" in item:
                    print(f"generator seed {item['seed']} failed: {item['failed']}", flush=True)
            skipped.write_text(json.dumps(sorted(other)))
        proc.wait()
    found = sorted(found, key=candidates.index)[:count]
    if len(found) < count:
        raise RuntimeError(f"only {len(found)} environments of shape {shape} were generated, {count} needed")
    return [folder / f"env{s}.json" for s in found]


def score(closure, runs, mechanisms) -> dict:
    """J of the model's prediction of each run (from its initial state and inputs); inf where it fails.

    ``mechanisms``: the physics the closure was trained in (the two-node wall and its trained
    sheet resistance): a closure learned with the dry wall at its own temperature and scored
    with one lumped wall would be judged on physics it never saw.
    """
    per_env = []
    for run in runs:
        try:
            per_env.append(float(validation_cost(closure, [run], mechanisms)["J"]))
        except SimulationError:
            per_env.append(math.inf)
    finite = [j for j in per_env if math.isfinite(j)]
    return {"per_env": per_env, "mean": float(np.mean(finite)) if finite else math.inf,
            "median": float(np.median(per_env)), "failed": len(per_env) - len(finite)}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="three short environments, one window, two iterations")
    ap.add_argument("--duration", type=float, default=DURATION_S, help="seconds of each environment")
    ap.add_argument("--n-train", type=int, nargs="+", default=list(N_TRAIN), help="fleet sizes trained on")
    ap.add_argument("--pool", type=int, default=N_POOL, help="training pool size (>= the largest N)")
    ap.add_argument("--test", type=int, default=N_TEST, help="unseen test environments")
    ap.add_argument("--draws", type=int, default=DRAWS, help="draws of pool order and initial weights")
    ap.add_argument("--out", default="results/multi_environment")
    args = ap.parse_args(argv)
    if not args.quick and (max(args.n_train) > args.pool or min(args.n_train) < 1 or args.test < 1
                           or args.draws < 1 or args.duration <= 0):
        ap.error(f"need 1 <= N <= --pool ({args.pool}), --test >= 1, --draws >= 1, --duration > 0; "
                 f"got N = {args.n_train}, --test {args.test}, --draws {args.draws}, --duration {args.duration}")
    start = time.perf_counter()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    q = QUICK if args.quick else None
    shape = q["shape"] if q else SHAPE
    duration_s = q["duration_s"] if q else args.duration
    n_train = q["n_train"] if q else tuple(sorted(set(args.n_train)))
    n_pool, n_test = (q["n_pool"], q["n_test"]) if q else (args.pool, args.test)
    draws, config = (q["draws"], q["config"]) if q else (args.draws, CONFIG)
    paths = environments(out / f"environments_{duration_s:.0f}s", shape, n_pool + n_test, duration_s, q["seeds"] if q else None)
    generated_s = time.perf_counter() - start
    runs = [read_run(p) for p in paths]
    pool, test = runs[:n_pool], runs[n_pool:]
    print(f"{len(runs)} environments ({shape}, {duration_s / 60:.0f} min, {LAW} law, {NOISE} noise) in "
          f"{generated_s:.0f} s; test: {[r.name for r in test]}", flush=True)

    # The untrained model's physics (the configured wall, its default sheet resistance) for the
    # baselines; each trained agent is scored with the mechanisms its training ended with.
    initial_mechanisms = tuple(Assimilator(pool[:1], config, closure=config.agent(0)).model.mechanisms)
    reference = score(ReferenceClosure(), test, initial_mechanisms)
    results = []
    for d in range(draws):
        order = np.random.default_rng(d).permutation(len(pool))
        init = config.agent(d)
        untrained = score(init, test, initial_mechanisms)
        results.append({"draw": d, "n": 0, "trained_on": [], "score": untrained, "train_s": 0.0})
        print(f"draw {d}, untrained agent: held-out J mean {untrained['mean']:.4g}, median {untrained['median']:.4g}",
              flush=True)
        for n in n_train:
            chosen = [pool[i] for i in order[:n]]
            closure = config.agent(d)
            t = time.perf_counter()
            assimilator = Assimilator(chosen, config, closure=closure)
            res = assimilator.run()
            train_s = time.perf_counter() - t
            s = score(res.closure, test, tuple(assimilator.model.mechanisms))
            results.append({"draw": d, "n": n, "trained_on": [r.name for r in chosen], "score": s,
                            "train_s": train_s, "window_costs": [r.cost_after for r in res.reports],
                            "notes": [r.note for r in res.reports if r.note]})
            print(f"draw {d}, N = {n}: trained in {train_s:.0f} s (window J after: "
                  f"{', '.join(f'{r.cost_after:.3g}' for r in res.reports)}); held-out J mean {s['mean']:.4g}, "
                  f"median {s['median']:.4g}, failed {s['failed']}", flush=True)

    table = _table(results, n_train, reference)
    summary = {"law": LAW, "noise": NOISE, "shape": shape, "duration_s": duration_s,
               "config": json.loads(config.to_json()), "pool": [r.name for r in pool], "test": [r.name for r in test],
               "reference_closure": reference, "results": results, "generation_s": generated_s,
               "wall_s": time.perf_counter() - start}
    (out / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
    (out / "table.md").write_text(table + "\n")
    _figure(out / "heldout_loss.png", results, n_train, reference, len(test))
    print(table)
    print(f"study wall time {summary['wall_s']:.0f} s (environments {generated_s:.0f} s); wrote {out / 'summary.json'}, "
          f"{out / 'table.md'}, {out / 'heldout_loss.png'}")
    return summary


def _by_n(results, n):
    return [r for r in results if r["n"] == n]


def _table(results, n_train, reference) -> str:
    lines = ["| N trained on | held-out J, mean over test tanks, per draw | mean over draws | spread (max - min) | "
             "median over test tanks, per draw | failed predictions | training (s), per draw |",
             "|---|---|---|---|---|---|---|"]
    for n in (0, *n_train):
        rows = _by_n(results, n)
        means = [r["score"]["mean"] for r in rows]
        medians = ", ".join(f"{r['score']['median']:.4g}" for r in rows)
        train = ", ".join(f"{r['train_s']:.0f}" for r in rows)
        failed = sum(r["score"]["failed"] for r in rows)
        label = n if n else "0 (untrained)"
        lines.append(f"| {label} | {', '.join(f'{m:.4g}' for m in means)} | {np.mean(means):.4g} | "
                     f"{np.max(means) - np.min(means):.3g} | {medians} | {failed} | {train} |")
    lines.append(f"| tankode's reference correlations | {reference['mean']:.4g} | | | {reference['median']:.4g} | "
                 f"{reference['failed']} | |")
    return "\n".join(lines)


def _figure(path, results, n_train, reference, n_test):
    fig, ax = plt.subplots(figsize=(7, 4.2))
    xs = np.array(n_train, dtype=float)
    draws = sorted({r["draw"] for r in results})
    for d in draws:
        ys = [next(r["score"]["mean"] for r in results if r["draw"] == d and r["n"] == n) for n in n_train]
        ax.plot(xs, ys, "o-", color="0.7", lw=0.8, ms=3, label="one draw" if d == draws[0] else None)
    means = np.array([np.mean([r["score"]["mean"] for r in _by_n(results, n)]) for n in n_train])
    lo = np.array([np.min([r["score"]["mean"] for r in _by_n(results, n)]) for n in n_train])
    hi = np.array([np.max([r["score"]["mean"] for r in _by_n(results, n)]) for n in n_train])
    ax.errorbar(xs, means, yerr=[means - lo, hi - means], fmt="s-", color="tab:blue", capsize=4,
                label=f"mean over {len(draws)} draws (bars: min-max)")
    untrained = np.mean([r["score"]["mean"] for r in _by_n(results, 0)])
    ax.axhline(untrained, color="tab:red", ls="--", lw=1, label="untrained agent (mean over draws)")
    ax.axhline(reference["mean"], color="tab:green", ls=":", lw=1.2, label="tankode's reference correlations")
    ax.axhline(2.5, color="k", ls="-", lw=0.6, alpha=0.5, label="noise floor (2.5)")
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.set_xticks(xs)
    ax.set_xticklabels([str(int(x)) for x in xs])
    ax.set_xlabel("environments trained on, N")
    ax.set_ylabel(f"held-out J (mean over {n_test} unseen tanks)")
    falls = means[-1] < means[0]
    ax.set_title(f"held-out loss {'falls' if falls else 'does not fall'} from N = {n_train[0]} to N = {n_train[-1]} "
                 f"({means[0]:.3g} -> {means[-1]:.3g})", fontsize=10)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


if __name__ == "__main__":
    main()
