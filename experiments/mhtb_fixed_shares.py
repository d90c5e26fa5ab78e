"""MHTB leave one test out with the physical shares fixed: two fitted parameters (issue 6).

``mhtb_multistart.py`` fits seven parameters on one test (four closure factors and the
boundary-layer layer's 1/delta, phi, c) and the minimum it reaches on the 90 % fill test
predicts the 25 % fill test 6.7 times worse than the EBM. Here the model has two free
parameters only; the rest is fixed by the classic picture of a self-pressurising tank:

* the correlations as published (the reference closure, every factor 1);
* ``dry_wall_heating`` with ``phi = 1``: the heat load on the dry wall heats the ullage (lumped
  tank models commonly split the heat load by wetted and dry area);
* ``boundary_layer_stratification`` with ``wall_share = 1``: all the wetted wall's heat rises
  in the boundary layer to the surface layer (Tellep and Harper's stratification picture);
* fitted: the layer's 1/delta and its renewal share c, from one start.

Then (``ROUNDS`` > 1) each channel's sigma is re-estimated as max(sensor noise_std, the fit's
RMS residual) where the residuals exceed the noise beyond chance (``ModelError``, the
diagnosis' own weighting) and the fit repeated from there: the maximum-likelihood fit with an
unknown variance per channel, the sensors' noise as its floor. The model's error on a channel
it cannot follow (the ullage temperature: 1.6 K on P263981D against a 0.1 K sensor) then no
longer outweighs the pressure. The held-out test plays no part in either fit. Honest limit: the shares were
fixed after a grid of the reference closure on both tests had shown that a share below 1 spoils
the 25 % fill test (``experiments/README.md``), so this is not a blind test of the choice.

Measured (twelfth session; again with ``ModelError`` in the fourteenth): calibrated on P263968K
it predicts P263981D at 1126 Pa on the EBM's samples (EBM 12728); calibrated on P263981D it
predicts P263968K at 464 Pa (EBM 388): leave one test out is not met on the 25 % fill test.
``--layer growing_layer``: 462 Pa; ``--layer diffusive_layer``: 776 Pa (``experiments/README.md``).

``--wall dry_wall_node --initial measured`` (fifteenth session): the dry wall as a node tied to the
wetted wall by conduction along the shell (its sheet resistance fitted instead of the dry wall's
share fixed) and each test started from its samples at t = 0 (P263968K's ullage reads 24.84 K
there; its metadata say 21.01 K). Both tests fit the same shell (R_s 8.8 and 9.6 K/W) and each is
then fitted near its noise (training RMSE p 191 / 416 Pa, T_v 0.026 / 0.24 K); held out, tankode
beats the EBM on every channel of P263981D (p 1829 against 12728 Pa, T_v 0.40 against 0.45 K, T_l
0.027 against 0.072 K) and on the temperatures of P263968K (T_v 0.16 against 4.1 K, T_l 0.082
against 0.092 K), but not on its pressure (1874 against 388 Pa): the layer's fitted thickness
differs between the tests (53 cm against 18 cm), and every growth law collapses to a fixed layer.

Usage: ``python experiments/mhtb_fixed_shares.py [--quick] [--out results/mhtb_fixed_shares]
[--layer LAYER] [--wall dry_wall_heating|dry_wall_node] [--initial metadata|measured]``
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from mhtb import CHANNELS, LAYER, RUNS, _ebm, _p_rmse, _predict, _runs, _values
from tankode._threads import single_threaded
from tankode.compare import channel_rmse, solution_observations
from tankode.diagnosis import ModelError, Problem, fit
from tankode.diagnosis.data import CHANNELS as DIAGNOSIS_CHANNELS
from tankode.diagnosis.forward import mechanism_params
from tankode.diagnosis.weighting import reweigh, rms_residual
from tankode.fleet import Fleet

# ---- configuration ---------------------------------------------------------------------------
DRY_WALL = "dry_wall_heating"
# the layer (--layer) -> the name and start of its second fitted parameter: the grid's renewal
# share c for the layer of fixed thickness; for the growing layer an entrainment share of 1e-2,
# which thickens it by centimetres over the tests' hours; for the layer that thickens by
# conduction (diffusive_layer) molecular conduction, a diffusivity factor of 1
LAYERS = {LAYER: ("renewal_share", 1e-3), "growing_layer": ("entrainment_share", 1e-2),
          "diffusive_layer": ("diffusivity_factor", 1.0)}
START_INV_THICKNESS_1_PER_M = 50.0  # 2 cm
# the dry wall (--wall): dry_wall_heating with its share fixed at 1 (the twelfth session's model), or
# dry_wall_node, the dry wall as a node tied to the wetted wall by conduction along the shell, whose
# sheet resistance is fitted from 10 K/W (a 12.7 mm shell of k_w = 8 W/(m K); aluminium alloys at
# 20 K: 5-40) and whose layer starts thicker (4 cm), where a one-off grid of both tests put it
WALLS = {DRY_WALL: None, "dry_wall_node": ("R_sheet_K_per_W", 10.0, 25.0)}
MAX_ITERATIONS = 16  # each costs 3 simulations; both directions converged in 4-5 (measured)
ROUNDS = 3  # fit, then up to two refits with re-estimated sigmas (stops when they move < 5 %)
# sigma = max(sensor, RMS residual of the fit) where the residuals exceed the noise beyond chance
# (tankode.diagnosis.weighting): on these tests the temperatures' always do (by factors of 2 to
# 40); the pressure's does at the first fit, not once the 25 % fill test is fitted to 354 Pa
WEIGHTING = ModelError()
QUICK_ITERATIONS = 1  # --quick: both tests cut to 2 h, one iteration per round, two rounds,
QUICK_ROUNDS = 2  # calibrated on P263981D only (a smoke run)
QUICK_TRAIN = ("P263981D",)
# -----------------------------------------------------------------------------------------------


def _fixed(layer, wall=DRY_WALL):
    """The shares held at 1 by a degenerate box: the dry wall's (``dry_wall_heating``) and the layer's wall share."""
    return {(DRY_WALL, "phi"): 1.0, (layer, "wall_share"): 1.0} if wall == DRY_WALL else {(layer, "wall_share"): 1.0}


def _start(layer, wall=DRY_WALL):
    share, c0 = LAYERS[layer]
    if wall == DRY_WALL:
        return {(layer, "inv_thickness_1_per_m"): START_INV_THICKNESS_1_PER_M, (layer, share): c0}
    name, v0, inv0 = WALLS[wall]
    return {(wall, name): v0, (layer, "inv_thickness_1_per_m"): inv0, (layer, share): c0}


def _params(layer, wall=DRY_WALL):
    """Free parameters of both mechanisms, the fixed ones boxed to their value."""
    out = []
    fixed = _fixed(layer, wall)
    for mid in (wall, layer):
        for p in mechanism_params(mid):
            v = fixed.get((mid, p.name))
            out.append(p if v is None else dataclasses.replace(p, lower=v, upper=v))
    return out


def _rounds(train, held, ebm, iterations, rounds, layer, wall=DRY_WALL):
    """Fit on ``train`` with sensor sigmas, then refit with ``ModelError`` sigmas; one row per round."""
    params = _params(layer, wall)
    fixed, start = _fixed(layer, wall), _start(layer, wall)
    x = np.array([fixed.get((p.owner, p.name), start.get((p.owner, p.name), 0.0)) for p in params])
    problem = Problem(Fleet.from_runs([train]))
    every_sample = np.ones(problem.obs.y.shape[:2], bool)  # (env, T)
    col = {c: DIAGNOSIS_CHANNELS.index(c) for c in CHANNELS}  # the measured channels' columns
    rows = []
    for k in range(rounds):
        t = time.perf_counter()
        f = fit(problem, params, x, every_sample, iterations)
        x = f.values
        closure, mechs = problem.build(f.params, f.values)
        own = channel_rmse(train, solution_observations(_predict(train, closure, mechs)), CHANNELS)
        sol = solution_observations(_predict(held, closure, mechs))
        heldout = {c: v["rmse"] for c, v in channel_rmse(held, sol, CHANNELS).items()}
        values = _values(f)
        sigma = {c.rsplit("_", 1)[0]: float(problem.obs.sigma[0, i]) for c, i in col.items()}
        rms, _ = rms_residual(problem.obs, f.pred, every_sample)  # (1, 5)
        fit_rms = {c: float(rms[0, i]) for c, i in col.items()}
        rows.append({"round": k, "sigma": sigma, "values": values, "std": dict(zip(values, f.std.tolist())),
                     "chi2_train": f.chi2, "n_data": f.n_data, "fit_status": f.status,
                     "train_rmse": {c: v["rmse"] for c, v in own.items()}, "fit_rms": fit_rms,
                     "p_rmse_Pa": _p_rmse(held, sol, within=ebm[held.name]),
                     "p_rmse_all_samples_Pa": heldout["p_v_Pa"], "heldout_rmse": heldout,
                     "wall_s": time.perf_counter() - t})
        print(f"{train.name} -> {held.name}: {json.dumps(rows[-1], default=float)}", flush=True)
        if not reweigh(problem, WEIGHTING, f.pred, every_sample):
            break
    return rows, sol


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="both tests cut to 2 h, one iteration, two rounds, P263981D only")
    ap.add_argument("--out", default="results/mhtb_fixed_shares")
    ap.add_argument("--layer", choices=tuple(LAYERS), default=LAYER,
                    help="the surface layer: of fixed thickness, renewed by the boundary layer (default), "
                         "thickened by it (growing_layer), or thickened by conduction (diffusive_layer)")
    ap.add_argument("--wall", choices=tuple(WALLS), default=DRY_WALL,
                    help="the dry wall: its ambient heat into the ullage (dry_wall_heating, share 1, default) or a "
                         "node of its own tied to the wetted wall by conduction (dry_wall_node, fitted)")
    ap.add_argument("--initial", choices=("metadata", "measured"), default="metadata",
                    help="start each test from its metadata (the format's rule, default) or from its samples at "
                         "t = 0 (P263968K's ullage reads 24.84 K there, its metadata 21.01 K)")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    runs = _runs(args.quick)
    ebm = _ebm(runs)
    if args.initial == "measured":
        runs = [r.with_measured_initial() for r in runs]
    summary = {"layer": args.layer, "wall": args.wall, "initial": args.initial,
               "fixed": {f"{m}.{n}": v for (m, n), v in _fixed(args.layer, args.wall).items()},
               "start": {f"{m}.{n}": v for (m, n), v in _start(args.layer, args.wall).items()}, "quick": args.quick,
               "directions": {}}
    with single_threaded():
        for train in [r for r in runs if r.name in (QUICK_TRAIN if args.quick else RUNS)]:
            held = next(r for r in runs if r is not train)
            rows, sol = _rounds(train, held, ebm, QUICK_ITERATIONS if args.quick else MAX_ITERATIONS,
                           QUICK_ROUNDS if args.quick else ROUNDS, args.layer, args.wall)
            ebm_all = {c: v["rmse"] for c, v in channel_rmse(held, ebm[held.name], CHANNELS, within=ebm[held.name]).items()}
            ebm_rmse = ebm_all["p_v_Pa"]
            _figure(out / f"{held.name}_from_{train.name}.png", held, ebm[held.name], sol,
                    f"tankode ({args.wall} + {args.layer}), calibrated on {train.name}")
            summary["directions"][f"{train.name}->{held.name}"] = {
                "rounds": rows, "ebm_p_rmse_Pa": ebm_rmse, "ebm_rmse": ebm_all, "below_ebm": rows[-1]["p_rmse_Pa"] < ebm_rmse}
    (out / "summary.json").write_text(json.dumps(summary, indent=2, default=float) + "\n")
    (out / "summary.md").write_text(_markdown(summary))
    print((out / "summary.md").read_text())
    return summary


def _figure(path, run, ebm, prediction, label):
    """The held-out test's data, the EBM's published prediction and tankode's: pressure and temperatures."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_p, ax_t) = plt.subplots(2, 1, figsize=(8, 6.5), sharex=True)
    for ax, chans in ((ax_p, ("p_v_Pa",)), (ax_t, ("T_v_K", "T_l_K"))):
        for ch in chans:
            scale = 1e-3 if ch == "p_v_Pa" else 1.0
            t, y = run.observations.channel(ch)
            ax.plot(t / 3600, y * scale, "ko" if ch != "T_l_K" else "ks", ms=3, mfc="none" if ch == "T_l_K" else "k",
                    label=f"{ch} data")
            t, y = ebm.channel(ch)
            ax.plot(t / 3600, y * scale, "--", color="tab:green", label="EBM (published)" if ch != "T_l_K" else None)
            t, y = prediction.channel(ch)
            ax.plot(t / 3600, y * scale, "-", color="tab:blue", label=label if ch != "T_l_K" else None)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    ax_p.set_ylabel("ullage pressure p_v [kPa]")
    ax_t.set_ylabel("temperature [K] (upper: T_v, lower: T_l)")
    ax_t.set_xlabel("time [h]")
    ax_p.set_title(f"MHTB {run.name} (fill {run.initial.fill_ratio:.0%}), held out")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _temps(r, d) -> str:
    """Held-out T_v and T_l RMSE with the EBM's beside them."""
    h, e = r["heldout_rmse"], d["ebm_rmse"]
    return ", ".join(f"{h[c]:.3g} ({e[c]:.3g})" for c in ("T_v_K", "T_l_K"))


def _markdown(s) -> str:
    layer, wall = s["layer"], s["wall"]
    share = LAYERS[layer][0]
    node = WALLS[wall][0] if WALLS[wall] else None  # the dry wall's fitted parameter, if any
    head = ("the dry wall's heat into the ullage (share 1)" if node is None
            else f"`{wall}`'s {node} fitted")
    lines = [f"# MHTB leave one test out: {head}, the layer's wall share 1, `{layer}`'s 1/delta and {share} "
             f"fitted (initial state: {s['initial']})", "",
             "| calibrated -> predicted | round (sigma p, T_v, T_l) | " + ("R_s [K/W], " if node else "")
             + f"1/delta [1/m], {share} | status | training RMSE p [Pa], T_v [K], T_l [K] | "
             "p RMSE [Pa] (all samples) | EBM [Pa] | held-out T_v, T_l RMSE [K] (EBM) |",
             "|---|---|---|---|---|---|---|---|"]
    for key, d in s["directions"].items():
        for r in d["rounds"]:
            v = r["values"]
            sig = ", ".join(f"{x:.3g}" for x in r["sigma"].values())
            own = ", ".join(f"{x:.3g}" for x in r["train_rmse"].values())
            wall_v = f"{v[wall + '.' + node]:.3g}, " if node else ""
            lines.append(f"| {key} | {r['round']} ({sig}) | {wall_v}{v[layer + '.inv_thickness_1_per_m']:.4g}, "
                         f"{v[layer + '.' + share]:.3g} | {r['fit_status']} | {own} | {r['p_rmse_Pa']:.0f} "
                         f"({r['p_rmse_all_samples_Pa']:.0f}) | {d['ebm_p_rmse_Pa']:.0f} | {_temps(r, d)} |")
    return "\n".join(lines) + "\n"

if __name__ == "__main__":
    main()
