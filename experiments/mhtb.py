"""NASA MHTB self-pressurization tests: tankode on real data, against the published EBM.

Two digitised liquid-hydrogen tests (P263968K, 25 % fill, 18.5 h; P263981D, 90 % fill, 5.4 h;
``../shared/data/mhtb/``, read in place) and, beside each, the energy-balance model's (EBM)
published prediction. The script

1. simulates both tests with the baseline model (reference closure, LSODA) and reports its misfit,
2. calibrates on both tests and diagnoses the missing mechanism (leave-one-test-out held-out
   gain); the report and the extended model go to ``OUT/diagnosis`` (``model/`` is the saved model);
   then (2b) diagnoses them again as ``tankode diagnose --initial measured --block 3600 --hold h_wv``
   does (``MEASURED``: each test from its samples at t = 0, the h_wv correlation trusted) into
   ``OUT/diagnosis_measured``,
3. tabulates the RMSE of pressure, ullage and liquid temperature for tankode baseline,
   calibrated and extended against the EBM's, on each test (one figure per test),
4. calibrates on one test and predicts the other (leave one test out) and checks that
   ``tankode predict OUT/diagnosis/model RUN.json`` runs on each test,
5. calibrates the closure with ``boundary_layer_stratification`` (a surface layer renewed by the
   wall's boundary layer, which the diagnosis cannot name: see ``LAYER``) on both tests and on
   each alone, from the best point of a grid scored on the training tests only, saves each as a
   model (``OUT/layer_models/<tests>``) and applies it with ``tankode predict`` to the test it
   was not calibrated on. These fits stop at 8 iterations, before converging: run to
   convergence the fit on P263981D predicts P263968K far worse (``experiments/README.md``).

Usage: ``python experiments/mhtb.py [--quick] [--out results/mhtb]``
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import itertools
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from common import MHTB_CHANNELS, MHTB_DATA, MHTB_FLUID, ebm_predictions, mhtb_runs  # noqa: E402
from tankode.compare import channel_rmse, solution_observations  # noqa: E402
from tankode.diagnosis import (  # noqa: E402
    DiagnosisConfig, LeaveOneRunOut, Problem, diagnose, fit, heldout_rms_sigma, write_report)
from tankode.diagnosis.forward import closure_params, mechanism_params  # noqa: E402
from tankode.errors import SimulationError  # noqa: E402
from tankode.fleet import Fleet  # noqa: E402
from tankode.mechanisms import MECHANISMS  # noqa: E402
from tankode.run_io import read_run  # noqa: E402
from tankode.saved import save_model  # noqa: E402
from tankode.simulation import simulate  # noqa: E402

# ---- configuration ---------------------------------------------------------------------------
DATA, FLUID, CHANNELS = MHTB_DATA, MHTB_FLUID, MHTB_CHANNELS  # the tests (experiments/common.py)
# Samples are ~10-20 min apart and the residuals correlate over hours: one-hour bootstrap blocks.
# The bound-pinned baseline linearises badly: dry_wall_heating scores 4th there but acts strongly
# once the ullage decouples from the wall, so four candidates are refitted, with as many
# iterations as the calibration (it reaches phi = 1 from 0 in about 8).
FULL = DiagnosisConfig(candidates=tuple(MECHANISMS), split=LeaveOneRunOut(), refit_top=4, max_iterations=8,
                       max_iterations_refit=8, block_s=3600.0)
QUICK = DiagnosisConfig(candidates=("heat_leak_vapor", "pressure_sensor_bias", "wall_heat_capacity_error"),
                        split=LeaveOneRunOut(), refit_top=1, max_iterations=1, max_iterations_refit=1,
                        block_s=1800.0, n_boot=200)
# Step 2b. From the metadata the 25 % fill test's ullage starts at 21.01 K where it reads 24.84 K,
# and no model with a dry wall node can then fit it; from the samples the node fits both tests, but
# with the four factors free its sheet resistance trades off with the h_wv factor (correlation
# -1.00) and is unresolved. Holding h_wv at the published correlation resolves it. The rest are the
# command line's defaults (15 / 8 iterations, the twelve default candidates, 5 refitted: the score
# test ranks the node first, as it does not project out the factors held on their bounds).
MEASURED = DiagnosisConfig(split=LeaveOneRunOut(), block_s=3600.0, hold=("h_wv",))
QUICK_MEASURED = dataclasses.replace(QUICK, candidates=("pressure_sensor_bias", "dry_wall_node"), refit_top=None,
                                     hold=("h_wv",))
# The boundary-layer-fed surface layer (tankode/mechanisms/boundary_layer.py). The diagnosis
# cannot name it (its wall-fed source has no slope at 0, where the score test looks), so step 5
# calibrates it with the closure from a layer: the point of this grid (reference closure, all of
# the wetted wall's heat, phi = 1) that fits the training tests best, chosen on them alone so
# that the held-out test plays no part in the start; the fit moves from there.
LAYER = "boundary_layer_stratification"
LAYER_GRID = {"inv_thickness_1_per_m": (50.0, 100.0, 200.0, 400.0),  # 2 cm to 2.5 mm
              "wall_share": (1.0,),
              "renewal_share": (1e-4, 1e-3, 1e-2)}  # of the Eckert-Jackson flow
QUICK_UNTIL_S = 7200.0  # both tests cut to 2 h (the 25 % fill test has 12 samples by then)
OUTPUT_DT_S = 60.0
# -----------------------------------------------------------------------------------------------


def _p_rmse(run, observations, within=None):
    """Pressure RMSE [Pa] of ``observations`` at ``run``'s samples (those ``within`` covers, if given)."""
    return channel_rmse(run, observations, ("p_v_Pa",), within=within)["p_v_Pa"]["rmse"]


def _predict(run, closure=None, mechanisms=()):
    return simulate(run, closure, output_dt_s=OUTPUT_DT_S, mechanisms=mechanisms)


def _calibrate_on(runs, mechanism, max_iterations, start=None):
    """Closure factors (+ ``mechanism``'s parameters, from ``start`` or 0) fitted to all of ``runs``.

    Returns (closure, mechanisms, fit).
    """
    problem = Problem(Fleet.from_runs(runs))
    params = closure_params() + (mechanism_params(mechanism) if mechanism else [])
    every_sample = np.ones(problem.obs.y.shape[:2], bool)  # (env, T)
    x0 = np.zeros(len(params))
    if start is not None:
        x0[len(params) - len(start):] = start
    f = fit(problem, params, x0, every_sample, max_iterations)
    closure, mechs = problem.build(f.params, f.values)
    return closure, mechs, f


def _layer_start(train):
    """The ``LAYER_GRID`` point that fits ``train`` best (reference closure), as the fit's start.

    Scored by chi2 = sum over tests and channels of n RMSE^2 / sigma^2 (the sensors' noise_std),
    on the training tests only. Returns (start values in the mechanism's parameter order, grid
    rows); a grid point the solver cannot integrate is kept in the rows with its error and
    scores inf.
    """
    names = [p.name for p in MECHANISMS[LAYER].params]
    rows = []
    for point in itertools.product(*(LAYER_GRID[n] for n in names)):
        values = dict(zip(names, point))
        try:
            chi2 = 0.0
            for r in train:
                rmse = channel_rmse(r, solution_observations(_predict(r, None, [MECHANISMS[LAYER](**values)])),
                                    CHANNELS)
                chi2 += sum(v["n"] * (v["rmse"] / r.noise_std[ch.rsplit("_", 1)[0]]) ** 2 for ch, v in rmse.items())
            rows.append({**values, "chi2": chi2})
        except SimulationError as e:
            rows.append({**values, "chi2": float("inf"), "error": str(e)[:300]})
    best = min(rows, key=lambda row: row["chi2"])
    if not np.isfinite(best["chi2"]):
        raise SimulationError(f"{LAYER}: no point of LAYER_GRID could be simulated on {[r.name for r in train]}")
    return tuple(best[n] for n in names), rows


def _leave_one_out(runs, held, mechanism, max_iterations):
    """Calibrate on every run but ``held``, predict ``held`` from its metadata and inputs; returns (solution, fit)."""
    closure, mechs, f = _calibrate_on([r for r in runs if r is not held], mechanism, max_iterations)
    return _predict(held, closure, mechs), f


def _cli_predict(model_dir, run, out_dir, quick):
    """``tankode predict MODEL_DIR RUN.json`` in a subprocess; returns (predicted Run or None, record)."""
    run_json = DATA / f"{run.name}.json" if not quick else _write_cut(run, out_dir / "cut_runs")
    proc = subprocess.run([sys.executable, "-m", "tankode.cli", "predict", str(model_dir), str(run_json),
                           "--out", str(out_dir / run.name)], capture_output=True, text=True,
                          env=dict(os.environ, MPLBACKEND="Agg"))
    entry = {"returncode": proc.returncode, "ok": proc.returncode == 0}
    if not entry["ok"]:
        entry["stderr"] = proc.stderr[-2000:]
        return None, entry
    return read_run(out_dir / run.name / f"{run.name}.json"), entry


def _values(f):
    """A fit's parameter values by label."""
    return {p.label: float(v) for p, v in zip(f.params, f.values)}


def _misfit_summary(run, rmse):
    """What the uncalibrated baseline gets wrong, per channel: RMSE and bias in sensor sigmas."""
    sig = {"p_v_Pa": run.noise_std["p_v"], "T_v_K": run.noise_std["T_v"], "T_l_K": run.noise_std["T_l"]}
    return {ch: {"rmse": v["rmse"], "bias": v["bias"], "rmse_sigma": v["rmse"] / sig[ch], "bias_sigma": v["bias"] / sig[ch]}
            for ch, v in rmse.items()}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="both tests cut to 2 h, 3 candidates (CI smoke run)")
    ap.add_argument("--out", default="results/mhtb")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    config = QUICK if args.quick else FULL
    start = time.perf_counter()
    runs = mhtb_runs(QUICK_UNTIL_S if args.quick else None)
    ebm = ebm_predictions(runs)

    # 1. baseline (reference closure, estimated wall heat capacity)
    baseline = {r.name: _predict(r) for r in runs}
    notes = sorted({n for s in baseline.values() for n in s.notes})
    def score(run, prediction):
        # Every model on all samples, and on the samples the EBM's published curves cover (its
        # pressure of P263981D stops at 1.35 h): the comparison with the EBM uses the latter.
        return {"all": channel_rmse(run, prediction, CHANNELS),
                "ebm_span": channel_rmse(run, prediction, CHANNELS, within=ebm[run.name])}

    rm = {r.name: {"tankode_baseline": score(r, solution_observations(baseline[r.name])),
                   "ebm": score(r, ebm[r.name])} for r in runs}
    misfit = {r.name: _misfit_summary(r, rm[r.name]["tankode_baseline"]["all"]) for r in runs}
    print("baseline misfit:", json.dumps(misfit, indent=1), flush=True)

    # 2. diagnosis on both tests (leave one test out)
    d = diagnose(runs, config=config, progress=lambda line: print(line, flush=True))
    paths = write_report(d, out / "diagnosis", FLUID)
    best = d.ranking[0] if d.ranking else None
    print(f"diagnosis: {d.verdict.kind} {d.named} ({d.wall_time_s:.0f} s)", flush=True)

    # 2b. the same from each test's samples at t = 0, with the h_wv correlation trusted (MEASURED)
    measured = [r.with_measured_initial() for r in runs]
    dm = diagnose(measured, config=QUICK_MEASURED if args.quick else MEASURED,
                  progress=lambda line: print(line, flush=True))
    write_report(dm, out / "diagnosis_measured", FLUID)
    print(f"diagnosis from the samples, h_wv held: {dm.verdict.kind} {dm.named} ({dm.wall_time_s:.0f} s)", flush=True)

    # 3. calibrated (baseline fit on both) and extended (with the cause) against the EBM
    cal_closure, cal_mechs = d.problem.build(d.baseline_fit.params, d.baseline_fit.values)
    ext_closure, ext_mechs = d.extended_model()
    calibrated = {r.name: _predict(r, cal_closure, cal_mechs) for r in runs}
    extended = {r.name: _predict(r, ext_closure, ext_mechs) for r in runs}
    for r in runs:
        rm[r.name]["tankode_calibrated"] = score(r, solution_observations(calibrated[r.name]))
        rm[r.name]["tankode_extended"] = score(r, solution_observations(extended[r.name]))

    # 3b. the best-evidenced candidate even when it is not named: how far it takes the fit
    best_not_named = None
    if best is not None and best.refit and best.mechanism != d.named:
        closure, mechs, f = _calibrate_on(runs, best.mechanism, config.max_iterations)
        best_not_named = {"mechanism": best.mechanism, "values_calibrated_on_both": _values(f),
                          "values_leave_one_out": {}}
        for r in runs:
            rm[r.name]["tankode_best_candidate"] = score(r, solution_observations(_predict(r, closure, mechs)))
            sol, f = _leave_one_out(runs, r, best.mechanism, config.max_iterations)
            rm[r.name]["tankode_best_candidate_leave_one_out"] = score(r, solution_observations(sol))
            best_not_named["values_leave_one_out"][r.name] = _values(f)
        print(f"best candidate, not named: {best_not_named}", flush=True)

    # 4. leave one test out: calibrate on one, predict the other from its metadata and inputs
    loo = {}
    for held in runs:
        (train,) = [r for r in runs if r is not held]
        sol, f = _leave_one_out(runs, held, d.named, config.max_iterations)
        rm[held.name]["tankode_leave_one_out"] = sc = score(held, solution_observations(sol))
        loo[held.name] = {"calibrated_on": train.name, "mechanism": d.named, "fit_status": f.status,
                          "values": _values(f), "solution": sol,
                          "p_rmse_Pa": sc["ebm_span"]["p_v_Pa"]["rmse"],
                          "ebm_p_rmse_Pa": rm[held.name]["ebm"]["ebm_span"]["p_v_Pa"]["rmse"],
                          "p_samples": sc["ebm_span"]["p_v_Pa"]["n"],
                          "p_rmse_all_samples_Pa": sc["all"]["p_v_Pa"]["rmse"],
                          "p_samples_all": sc["all"]["p_v_Pa"]["n"]}
        loo[held.name]["below_ebm"] = loo[held.name]["p_rmse_Pa"] < loo[held.name]["ebm_p_rmse_Pa"]
        print(f"leave one out: {train.name} -> {held.name}: p RMSE {loo[held.name]['p_rmse_Pa']:.0f} Pa "
              f"(EBM {loo[held.name]['ebm_p_rmse_Pa']:.0f} Pa) on the EBM's {loo[held.name]['p_samples']} samples; "
              f"{loo[held.name]['p_rmse_all_samples_Pa']:.0f} Pa on all {loo[held.name]['p_samples_all']}", flush=True)

    # the saved model (calibrated on both) through the CLI, on each test
    cli = {}
    for r in runs:
        pred, entry = _cli_predict(paths["model"], r, out / "predict", args.quick)
        if pred is not None:
            entry["p_rmse_Pa"] = _p_rmse(r, pred.observations)
        cli[r.name] = entry
        print(f"tankode predict on {r.name}: {entry}", flush=True)

    # 5. the boundary-layer-fed surface layer with the closure, from a layer (LAYER's comment):
    #    calibrated on both tests and on each alone, saved as a model, and applied by `tankode
    #    predict` to the test it was not calibrated on, from that test's metadata and inputs alone
    layer = {"mechanism": LAYER, "grid": LAYER_GRID, "fits": {}}
    layer_solutions = {}
    for held in [None, *runs]:
        train = [r for r in runs if r is not held]
        key = "+".join(r.name for r in train)
        layer_start, grid = _layer_start(train)
        closure, mechs, f = _calibrate_on(train, LAYER, config.max_iterations, layer_start)
        model_dir = save_model(out / "layer_models" / key, closure, FLUID, mechanisms=mechs,
                               info={"calibrated_on": [r.name for r in train], "script": "experiments/mhtb.py"})
        record = {"calibrated_on": key, "start": dict(zip((p.name for p in MECHANISMS[LAYER].params), layer_start)),
                  "grid": grid, "fit_status": f.status, "values": _values(f), "model": str(model_dir),
                  "predictions": {}}
        for r in (runs if held is None else [held]):
            sol = _predict(r, closure, mechs)
            label = "tankode_layer_both" if held is None else "tankode_layer_leave_one_out"
            rm[r.name][label] = sc = score(r, solution_observations(sol))
            pred, entry = _cli_predict(model_dir, r, out / "layer_predict" / key, args.quick)
            if pred is not None:
                entry["p_rmse_Pa"] = _p_rmse(r, pred.observations, within=ebm[r.name])
            record["predictions"][r.name] = {
                "p_rmse_Pa": sc["ebm_span"]["p_v_Pa"]["rmse"], "p_rmse_all_samples_Pa": sc["all"]["p_v_Pa"]["rmse"],
                "ebm_p_rmse_Pa": rm[r.name]["ebm"]["ebm_span"]["p_v_Pa"]["rmse"], "cli_predict": entry}
            record["predictions"][r.name]["below_ebm"] = (record["predictions"][r.name]["p_rmse_Pa"]
                                                          < record["predictions"][r.name]["ebm_p_rmse_Pa"])
            if held is not None:
                layer_solutions[r.name] = sol
        layer["fits"][key] = record
        print(f"{LAYER} calibrated on {key}: {json.dumps(record, default=float)}", flush=True)

    wall = time.perf_counter() - start
    table = [{"test": name, "channel": ch, "model": model, "samples": span, **rm[name][model][span][ch]}
             for name in rm for model in rm[name] for span in ("ebm_span", "all") for ch in CHANNELS]
    with open(out / "table.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(table[0]))
        w.writeheader()
        w.writerows(table)
    summary = {
        "quick": args.quick, "runs": [r.name for r in runs], "notes": notes, "baseline_misfit": misfit,
        "diagnosis": {"cause": d.cause, "named": d.named, "split": d.split, "wall_time_s": d.wall_time_s,
                      "n_simulations": d.n_simulations, "unexplained": d.unexplained,
                      "baseline_closure_factors": d.baseline["closure_factors"],
                      "baseline_heldout_loss": d.baseline["heldout_loss"],
                      "best_candidate": None if best is None else {
                          k: best.to_json()[k] for k in ("mechanism", "params", "params_std", "z_score", "delta_bic",
                                                         "heldout_gain", "heldout_gain_ci", "explained", "reasons")}},
        "diagnosis_measured": _diagnosis_summary(dm),
        "table": {name: {model: {span: {ch: rm[name][model][span][ch]["rmse"] for ch in CHANNELS}
                                 for span in ("ebm_span", "all")} for model in rm[name]} for name in rm},
        "samples": {name: {span: {ch: {k: rm[name]["ebm"][span][ch][k] for k in ("n", "n_outside", "t_end_s")}
                                  for ch in CHANNELS} for span in ("ebm_span",)} for name in rm},
        "best_candidate_not_named": best_not_named,
        "leave_one_out": {k: {kk: vv for kk, vv in v.items() if kk != "solution"} for k, v in loo.items()},
        "leave_one_out_p_below_ebm_on_both": all(v["below_ebm"] for v in loo.values()),
        "cli_predict": cli, "layer": layer,
        "layer_leave_one_out_p_below_ebm_on_both": all(
            v["predictions"][k]["below_ebm"] for v in layer["fits"].values() for k in v["predictions"]
            if k not in v["calibrated_on"].split("+")),
        "wall_time_s": wall,
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2, default=float) + "\n")
    (out / "summary.md").write_text(_markdown(summary))
    for r in runs:
        _figure(out / f"mhtb_{r.name}.png", r, ebm[r.name], baseline[r.name], extended[r.name],
                loo[r.name]["solution"], d.named, layer_solutions[r.name])
    print((out / "summary.md").read_text())
    print(f"wall time {wall:.0f} s")
    return summary


def _diagnosis_summary(d):
    """Step 2b's verdict and its first candidate's evidence, with the held-out residuals of its model per test."""
    first = d.ranking[0].to_json() if d.ranking else None
    model = d.extended or d.baseline
    return {"cause": d.cause, "named": d.named, "wall_time_s": d.wall_time_s, "n_simulations": d.n_simulations,
            "held_factors": d.baseline["held_factors"], "baseline_closure_factors": d.baseline["closure_factors"],
            "extended_closure_factors": d.extended["closure_factors"] if d.extended else None,
            "extended_params": d.extended["params"] if d.extended else None,
            "first": None if first is None else {k: first[k] for k in (
                "mechanism", "params", "params_std", "z_score", "delta_bic", "heldout_gain", "heldout_gain_ci",
                "explained", "heldout_estimate", "tradeoff", "reasons", "heldout_loss_by_channel",
                "heldout_rms_sigma")},
            # leave one test out: each test's held-out part is predicted by the fit on the other
            "heldout_rms_sigma": heldout_rms_sigma(model["residuals"]),
            "baseline_heldout_rms_sigma": heldout_rms_sigma(d.baseline["residuals"])}


def _write_cut(run, folder):
    from tankode.run_io import write_run

    json_path, _ = write_run(run, folder)
    return json_path


_MODELS = {"tankode_baseline": "tankode baseline", "tankode_calibrated": "tankode calibrated",
           "tankode_extended": "tankode extended", "tankode_leave_one_out": "tankode leave-one-test-out",
           "tankode_best_candidate": "tankode + best candidate, not named (calibrated on both)",
           "tankode_best_candidate_leave_one_out": "tankode + best candidate, not named (leave-one-test-out)",
           "tankode_layer_both": f"tankode + `{LAYER}` (calibrated on both)",
           "tankode_layer_leave_one_out": f"tankode + `{LAYER}` (leave-one-test-out)",
           "ebm": "EBM (published)"}


def _markdown(s) -> str:
    L = ["# MHTB self-pressurization: tankode against the EBM", "",
         f"Tests {', '.join(s['runs'])}{' (quick: cut to 2 h)' if s['quick'] else ''}. "
         "RMSE at the measured sample times of each channel (p in Pa, T in K), on the samples the EBM's "
         "published curves cover (every model on the same samples); the last column is the pressure on all "
         "samples.", ""]
    for name, spans in s["samples"].items():
        L.append(f"* {name}: " + ", ".join(
            f"{ch} on {v['n']} of {v['n'] + v['n_outside']} samples (to {v['t_end_s'] / 3600:.2f} h)"
            for ch, v in spans["ebm_span"].items()))
    L += ["", "| test | model | p_v [Pa] | T_v [K] | T_l [K] | p_v, all samples [Pa] |", "|---|---|---|---|---|---|"]
    for name, models in s["table"].items():
        for m, spans in models.items():
            v, a = spans["ebm_span"], spans["all"]
            label = _MODELS[m]
            if s["best_candidate_not_named"]:
                label = label.replace("best candidate", f"`{s['best_candidate_not_named']['mechanism']}`")
            L.append(f"| {name} | {label} | {v['p_v_Pa']:.0f} | {v['T_v_K']:.3f} | {v['T_l_K']:.3f} | "
                     f"{a['p_v_Pa']:.0f} |")
    dg = s["diagnosis"]
    L += ["", f"Diagnosis ({dg['split']}): cause **{dg['cause']}**."]
    b = dg["best_candidate"]
    if b:
        L.append(f"Best candidate {b['mechanism']}: held-out gain {b['heldout_gain']:.3f} "
                 f"[{b['heldout_gain_ci'][0]:.3f}, {b['heldout_gain_ci'][1]:.3f}], dBIC {b['delta_bic']:.1f}, "
                 f"explains {b['explained']:.0%}; " + ("; ".join(b["reasons"]) or "passes every threshold") + ".")
    m = s["diagnosis_measured"]
    L += ["", f"Diagnosis from the samples at t = 0 with {', '.join(m['held_factors'])} held at its correlation: "
          f"cause **{m['cause']}**" + (f" ({', '.join(f'{k} = {v:.4g}' for k, v in m['extended_params'].items())})"
                                       if m["cause"] else "") + "."]
    if m["first"]:
        f = m["first"]
        L.append(f"First candidate {f['mechanism']}: held-out gain {f['heldout_gain']:.3f} "
                 f"[{f['heldout_gain_ci'][0]:.3f}, {f['heldout_gain_ci'][1]:.3f}], dBIC {f['delta_bic']:.1f}, "
                 f"explains {f['explained']:.0%}; " + ("; ".join(f["reasons"]) or "passes every threshold") + ".")
    if m["first"]:
        L.append(f"Held-out RMS in sensor sigmas (leave one test out), baseline -> with {m['first']['mechanism']}"
                 + (" (the cause)" if m["cause"] else " (not named)") + ": " + "; ".join(
                     f"{run} " + ", ".join(f"{ch} {m['baseline_heldout_rms_sigma'][run][ch]:.1f} -> {v:.1f}"
                                           for ch, v in chans.items())
                     for run, chans in m["first"]["heldout_rms_sigma"].items()))
    L += ["", "Leave one test out (pressure RMSE on the held-out test, on the EBM's samples):", ""]
    for name, v in s["leave_one_out"].items():
        L.append(f"* {name} predicted from {v['calibrated_on']}: {v['p_rmse_Pa']:.0f} Pa vs EBM "
                 f"{v['ebm_p_rmse_Pa']:.0f} Pa on {v['p_samples']} samples "
                 f"({'below' if v['below_ebm'] else 'NOT below'} the EBM); "
                 f"{v['p_rmse_all_samples_Pa']:.0f} Pa on all {v['p_samples_all']}")
    L += ["", f"With `{LAYER}` (step 5: calibrated with the closure from a layer, saved, applied by "
          "`tankode predict` to the other test; pressure RMSE on the EBM's samples):", ""]
    for key, v in s["layer"]["fits"].items():
        for name, p in v["predictions"].items():
            held = name not in key.split("+")
            L.append(f"* {name} from {'the saved model of ' + key if held else 'the fit on ' + key}: "
                     f"{p['p_rmse_Pa']:.0f} Pa vs EBM {p['ebm_p_rmse_Pa']:.0f} Pa "
                     f"({'below' if p['below_ebm'] else 'NOT below'} the EBM{', held out' if held else ''}); "
                     f"{p['p_rmse_all_samples_Pa']:.0f} Pa on all samples; `tankode predict` "
                     + (f"{p['cli_predict']['p_rmse_Pa']:.0f} Pa" if p["cli_predict"]["ok"] else "FAILED"))
    L.append("")
    L.append("Starts (the best grid point on the training tests alone): " + "; ".join(
        f"{k}: " + ", ".join(f"{n} {x:.4g}" for n, x in v["start"].items()) for k, v in s["layer"]["fits"].items()))
    L.append("")
    L.append("Values: " + "; ".join(f"{k}: " + ", ".join(f"{n} {x:.4g}" for n, x in v["values"].items())
                                    for k, v in s["layer"]["fits"].items()))
    L += ["", "`tankode predict diagnosis/model RUN.json`: " + ", ".join(
        f"{k} {'ok' if v['ok'] else 'FAILED'}" for k, v in s["cli_predict"].items()), "",
        f"Wall time {s['wall_time_s']:.0f} s."]
    return "\n".join(L) + "\n"


def _figure(path, run, ebm, base, ext, loo_sol, cause, layer_sol):
    fig, (ax_p, ax_t) = plt.subplots(2, 1, figsize=(8, 6.5), sharex=True)
    ext_label = f"tankode extended ({cause})" if cause else "tankode calibrated (no cause found)"
    t_p, y_p = run.observations.channel("p_v_Pa")
    ax_p.plot(t_p / 3600, y_p / 1e3, "ko", ms=3, label="data")
    tp, yp = ebm.channel("p_v_Pa")
    ax_p.plot(tp / 3600, yp / 1e3, "--", color="tab:green", label="EBM (published)")
    for sol, color, ls, label in ((base, "tab:red", "-", "tankode baseline"), (ext, "tab:blue", "-", ext_label),
                                  (loo_sol, "tab:purple", ":", "tankode, calibrated on the other test"),
                                  (layer_sol, "tab:orange", "-", f"tankode + {LAYER}, calibrated on the other test")):
        t = sol.t_s.numpy() / 3600
        ax_p.plot(t, sol.observations[0, :, 0].numpy() / 1e3, ls, color=color, lw=1.3, label=label)
        for j, mk in ((1, "v"), (2, "l")):
            ax_t.plot(t, sol.observations[0, :, j].numpy(), ls, color=color, lw=1.3 if j == 1 else 0.9)
    for ch, mk, name in (("T_v_K", "o", "T_v"), ("T_l_K", "s", "T_l")):
        t_d, y_d = run.observations.channel(ch)
        ax_t.plot(t_d / 3600, y_d, "k" + mk, ms=3, mfc="none" if ch == "T_l_K" else "k", label=f"{name} data")
        te, ye = ebm.channel(ch)
        ax_t.plot(te / 3600, ye, "--", color="tab:green", lw=1.3 if ch == "T_v_K" else 0.9)
    ax_p.set_ylabel("ullage pressure p_v [kPa]")
    ax_t.set_ylabel("temperature [K] (upper: T_v, lower: T_l)")
    ax_t.set_xlabel("time [h]")
    ax_p.set_title(f"MHTB test {run.name} (fill {run.initial.fill_ratio:.0%})")
    ax_p.legend(fontsize=7)
    ax_t.legend(fontsize=7)
    for ax in (ax_p, ax_t):
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


if __name__ == "__main__":
    main()
