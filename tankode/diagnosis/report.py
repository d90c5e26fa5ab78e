"""Write a diagnosis out: ``report.json``, ``report.md`` (tables + figures), figures and ``model/``."""

from __future__ import annotations

import json
import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ..saved import save_model  # noqa: E402
from .data import CHANNELS  # noqa: E402
from .diagnose import Diagnosis  # noqa: E402
from .residuals import heldout_rms_sigma  # noqa: E402
from .weighting import SensorNoise  # noqa: E402

_UNITS = {"p_v_Pa": ("p_v", "bar", 1e-5), "T_v_K": ("T_v", "K", 1.0), "T_l_K": ("T_l", "K", 1.0),
          "T_w_K": ("T_w", "K", 1.0), "H_l_m": ("H_l", "mm", 1e3)}


def _finite(x):
    """JSON-safe: NaN and inf become None."""
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_finite(v) for v in x]
    if isinstance(x, (np.floating, np.integer)):
        return _finite(x.item())
    return x


def write_report(d: Diagnosis, out_dir, fluid: str) -> dict:
    """Write every output of the diagnosis into ``out_dir``; returns the paths written.

    Figures: ``inventory_RUN.png`` (the audit's measured inventory against the metered one),
    and where the dynamic search ran ``prediction_RUN.png``, ``residuals_RUN.png`` and
    ``heldout_loss.png``.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {"json": out / "report.json", "md": out / "report.md", "model": out / "model"}
    figs = []
    for a in d.audits:
        f = out / f"inventory_{a.run}.png"
        plot_inventory(a, f)
        figs.append(f)
    if d.baseline_fit is not None:
        for e, name in enumerate(d.runs):
            p = out / f"prediction_{name}.png"
            _plot_prediction(d, e, p)
            r = out / f"residuals_{name}.png"
            _plot_residuals(d, e, r)
            figs += [p, r]
        g = out / "heldout_loss.png"
        _plot_heldout(d, g)
        figs.append(g)
    paths["figures"] = figs
    closure, mechanisms = d.extended_model()
    save_model(paths["model"], closure, fluid, {
        "diagnosis": {"cause": d.cause, "model_form": d.named if d.cause is None else None,
                      "runs": list(d.runs), "split": d.split},
        "note": "closure = the base closure times the calibrated factors; mechanisms with their fitted values",
    }, mechanisms=mechanisms)
    paths["json"].write_text(json.dumps(_finite(d.to_json()), indent=2) + "\n")
    paths["md"].write_text(markdown(d, [f.name for f in figs]))
    return paths


def markdown(d: Diagnosis, figures: list[str]) -> str:
    """The engineer's report: verdict, inventory audit, evidence table, what the baseline gets wrong, figures."""
    L = ["# tankode diagnosis", ""]
    L.append(f"Runs: {', '.join(d.runs)}. Validation: {d.split}. {d.n_simulations} simulations, "
             f"{d.wall_time_s:.0f} s.")
    L.append("")
    v = d.verdict
    if v.kind == "cause":
        L.append(f"**Cause: `{d.cause}`** ({v.source}): {v.sentence}.")
    elif v.kind == "unresolved":
        L.append(f"**Measured, not located: {v.sentence}.** Candidates: "
                 + ", ".join(f"`{c}`" for c in v.candidates) + ".")
    elif v.kind == "model_form":
        L.append(f"**No cause; the model's form: `{d.named}`** ({v.source}): "
                 f"{v.sentence.removeprefix('no cause: ')}. This is the tank's own physics, not a fault: the "
                 "extended model (model/) carries it.")
    L += [f"{n[0].upper() + n[1:]}." for n in v.notes]
    if d.named and d.extended and v.source != "inventory audit" and d.ranking and d.ranking[0].mechanism == d.named:
        c = d.ranking[0]
        ps = ", ".join(f"{k} = {val:.4g} +- {d.extended['params_std'][k]:.2g}" for k, val in d.extended["params"].items())
        L.append(f"Fitted on all data: {ps}. It lowers the held-out loss by "
                 f"{100 * c.heldout_gain:.0f} % (95 % interval {100 * c.heldout_gain_ci[0]:.0f} to "
                 f"{100 * c.heldout_gain_ci[1]:.0f} %), dBIC {c.delta_bic:.1f}.")
        if d.alternatives:
            alts = [a for a in d.ranking if a.mechanism in d.alternatives]
            L.append("Not ruled out: " + ", ".join(
                f"`{a.mechanism}` (dBIC {a.delta_bic:.1f}, held-out gain {a.heldout_gain:.2f})" for a in alts)
                + f" also clears every threshold, within {d.thresholds.alternative_bic:g} of the named one's dBIC: "
                "the data favour it but do not exclude these; a measurement that tells them apart "
                "(see each mechanism's signature) would settle it.")
    elif v.kind == "none":
        L.append(f"**No cause**: {v.sentence.removeprefix('no cause: ')}.")
    if d.withheld:
        # Near the threshold the property model decides; the user should see that before the details.
        L.append("Withheld by the inventory audit (named by one of its two explanations, with the reference's "
                 "properties or with another model of the fluid allowed for, not by both; figures below): "
                 + "; ".join(d.withheld) + ".")
    if d.named is None and d.unexplained:
        L.append("Channels still beyond the noise on held-out data: " + ", ".join(
            f"{u['run']} {u['channel']} (RMS {u['rms_sigma']:.1f} sigma, bias {u['bias_sigma']:+.1f} sigma)"
            for u in d.unexplained) + ".")
    elif d.named is None and d.baseline_fit is not None:
        L.append("The calibrated baseline predicts the held-out data within the noise.")
    L += [f"{n[0].upper() + n[1:]}." for n in d.dynamic_notes]
    L += [""] + audit_markdown(d)
    if d.baseline_fit is None:
        L += ["## Figures", ""] + [f"![{f}]({f})" for f in figures]
        return "\n".join(L) + "\n"
    th = d.thresholds
    L += ["", f"Decision rule: dBIC <= {th.delta_bic}, held-out gain >= {th.heldout_gain} with the lower end of its "
          f"95 % block-bootstrap interval > {th.gain_ci_low}, estimate / standard error >= {th.z_score}, and at least "
          f"{th.explained:.0%} of the baseline's held-out loss above the noise floor explained; a held-out loss with "
          f"the mechanism of at most {th.adequate:g} times the noise floor (the model follows the data); a rate "
          "within the inventory audit's interval (inventory mechanisms); the estimate "
          f"refitted on held-out data agrees within {th.stability:.0%} plus three standard errors; and no other "
          f"candidate that fits better by more than {th.outranked_bic:g} in dBIC with a real held-out gain is left "
          f"unnamed (outranked).", ""]
    L += ["## Dynamic search: candidates", "",
          "| rank | mechanism | estimate | score | dBIC | LR | held-out gain [95 % CI] | explained | verdict |",
          "|---|---|---|---|---|---|---|---|---|"]
    named = d.verdict.kind.replace("_", " ")  # "cause" or "model form" for the named candidate
    for i, c in enumerate(d.ranking, 1):
        est = ", ".join(f"{k} = {v:.3g} +- {c.params_std.get(k, float('nan')):.2g}" for k, v in c.params.items())
        verdict = named if c.passes and c.mechanism == d.named else ("passes" if c.passes else "; ".join(c.reasons)
                                                                     or "not refitted")
        if c.passes and d.named is None:
            verdict = "passes; not named (the verdict rests on the inventory audit)"
        gain = (f"{c.heldout_gain:.3f} [{c.heldout_gain_ci[0]:.3f}, {c.heldout_gain_ci[1]:.3f}]"
                if c.refit else "")
        expl = f"{c.explained:.0%}" if c.refit else ""
        ic = f"{c.delta_bic:.1f} | {c.likelihood_ratio:.1f}" if c.refit else " | "
        L.append(f"| {i} | `{c.mechanism}` | {est} | {c.score:.3g} | {ic} | {gain} | {expl} | {verdict} |")
    notes = [f"Note on `{c.mechanism}`: {n}." for c in d.ranking for n in c.notes]
    L += [""] + notes if notes else []
    L += ["", "## Held-out loss per channel (0.5 = at the noise floor)", ""]
    weighting = d.baseline["weighting"]
    if weighting != SensorNoise().describe():
        sig = "; ".join(f"{run}: " + ", ".join(f"{c} {v:.3g}" for c, v in chans.items())
                        for run, chans in d.baseline["sigma"].items())
        L += [f"Residuals weighed by {weighting}: sigma {sig}. The evidence above and the held-out loss are "
              "in these units; the residual tables below stay in units of the sensor noise.", ""]
    L += ["| channel | baseline | extended |", "|---|---|---|"]
    ext = d.extended["heldout_loss_by_channel"] if d.extended else {}
    for ch in CHANNELS:
        b = d.baseline["heldout_loss_by_channel"][ch]
        if b == 0 and not ext.get(ch):
            continue
        L.append(f"| {ch} | {b:.3g} | {ext[ch]:.3g} |" if ch in ext else f"| {ch} | {b:.3g} | |")
    L += _heldout_rms_table(d)
    held_factors = d.baseline["held_factors"]
    L += ["", "## What the calibrated baseline gets wrong", "",
          "Closure factors: " + ", ".join(f"{k} x{v:.3g}" if k.endswith("_factor") else f"{k} {v:.3g}"
                                           for k, v in d.baseline["closure_factors"].items()) + "."
          + (f" Held at 1 by the user (the correlation trusted, not calibrated): {', '.join(held_factors)}."
             if held_factors else ""),
          ""]
    dropped = d.baseline.get("failed_starts", [])
    L += [f"Calibration start dropped: {line}." for line in dropped] + ([""] if dropped else [])
    for run, chans in d.baseline["residuals"]["runs"].items():
        L += [f"### {run}", "", "| channel | calibration bias / RMS [sigma] | held-out bias / RMS [sigma] | "
              "Ljung-Box p | worst phase (RMS) | spans outside 3 sigma |", "|---|---|---|---|---|---|"]
        for ch, s in chans.items():
            cal, held = s["calibration"], s["heldout"]
            fmt = lambda x: f"{x['bias_sigma']:+.2f} / {x['rms_sigma']:.2f}" if x else "-"  # noqa: E731
            worst = max(s["phases"].items(), key=lambda kv: kv[1]["rms_sigma"]) if s["phases"] else None
            spans = "; ".join(f"{sp['t_start_s']:.0f}-{sp['t_end_s']:.0f} s ({sp['sign']}, {sp['max_abs_sigma']:.1f})"
                              for sp in s["spans_outside_3sigma"][:4]) or "none"
            worst_txt = f"{worst[0]} ({worst[1]['rms_sigma']:.2f})" if worst else "-"
            L.append(f"| {ch} | {fmt(cal)} | {fmt(held)} | {s['ljung_box_p']:.2g} | {worst_txt} | {spans} |")
        L.append("")
    L += ["## Figures", ""] + [f"![{f}]({f})" for f in figures]
    L += ["", "The extended model is in `model/` (use it with `tankode simulate|assimilate|predict`)."]
    return "\n".join(L) + "\n"


def _est(e, scale: float = 1.0, digits: str = ".3g") -> str:
    if e is None:
        return "-"
    std = f" +- {e.std * scale:.2g}" if math.isfinite(e.std) else ""
    return f"{e.value * scale:{digits}}{std}"


def audit_markdown(d: Diagnosis) -> list[str]:
    """The inventory audit's section: run-wide and per-phase unmetered mass and heat, hypotheses, consistency."""
    L = ["## Inventory audit: what the meters did not see", "",
         "The tank's mass and energy reconstructed from its sensors (CoolProp), less the metered inflows, outflows "
         "and heat load; heat and mass exchanged inside the tank cancel, so no heat-transfer law enters. Rates "
         "are +- one standard error (sensor noise, widened by the Birge ratio where a straight line does not fit).",
         ""]
    L += [f"Not audited: {n}." for n in d.audit_notes]
    for a in d.audits:
        wall = a.wall_capacity_sentence()
        L += [f"### {a.run}", "",
              f"Over the run: unmetered mass {_est(a.mass_kg_s, 1e3)} g/s, unmetered heat {_est(a.heat_W)} W"
              + (f", {wall}" if wall else "")
              + f", liquid temperature offset {_est(a.liquid_offset_K)} K (Birge ratio {a.birge:.2f}).", ""]
        named = [f.sentence for f in a.findings]
        L.append("Findings: " + ("; ".join(named) if named else "nothing unmetered beyond the noise") + ".")
        if a.consistency:
            L.append("Saturation consistency: " + "; ".join(a.consistency) + ".")
        if a.inert_gas_unmeasured:
            L.append("Inert gas: " + a.inert_gas_unmeasured + ".")
        if a.withheld:
            L.append("Withheld: " + "; ".join(a.withheld) + ".")
        L += ["", "| single cause | estimate | chi2 |", "|---|---|---|"]
        units = {"heat": "W", "vapor_leak": "g/s lost", "liquid_leak": "g/s lost", "inflow_meter_bias": "relative",
                 "wall_heat_capacity_error": "x stated C_w", "noncondensable_gas": "mol of inert gas",
                 "heat_at_stated_wall": "W at the stated C_w"}
        for h in sorted(a.hypotheses.values(), key=lambda h: h.chi2):
            scale = 1e3 if h.name.endswith("leak") else 1.0
            L.append(f"| {h.name} | {_est(h.estimate, scale)} {units[h.name]} | {h.chi2:.1f} |")
        L += ["", "| phase | operations | unmetered mass [g/s] | unmetered heat [W] | Birge (mass, heat) |",
              "|---|---|---|---|---|"]
        for p in a.phases:
            L.append(f"| {p.t0_s:.0f}-{p.t1_s:.0f} s | {p.kind} | {_est(p.mass_kg_s, 1e3)} | {_est(p.heat_W)} | "
                     f"{p.birge_mass:.2f}, {p.birge_heat:.2f} |")
        L.append("")
    return L


def plot_inventory(a, path) -> None:
    """The measured inventory against the metered one (mass and energy), with the unmetered residual."""
    s = a.series
    t = s["t_s"] / 60.0
    has_mass = np.isfinite(s["mass_kg"]).any()
    rows = [("mass_kg", "mass_metered_kg", "mass_std", "mass", "kg", 1.0)] if has_mass else []
    rows.append(("energy_J", "energy_metered_J", "energy_std", "energy", "MJ", 1e-6))
    fig, axes = plt.subplots(len(rows), 2, figsize=(11, 3.0 * len(rows)), squeeze=False, sharex=True)
    for (m, k, sd, label, unit, f), (ax, axr) in zip(rows, axes):
        ax.plot(t, s[k] * f, color="tab:red", lw=1.2, label="metered (start + inflows - outflows + Q_aw)")
        ax.plot(t, s[m] * f, ".", ms=3, color="k", label="measured (sensors + CoolProp)")
        ax.set_ylabel(f"{label} [{unit}]")
        r, e = (s[m] - s[k]) * f, 2 * s[sd] * f
        axr.fill_between(t, r - e, r + e, color="0.8", lw=0, label="+- 2 std")
        axr.plot(t, r, color="tab:blue", lw=1.0, label="measured - metered")
        axr.axhline(0, color="k", lw=0.6)
        axr.set_ylabel(f"unmetered {label} [{unit}]")
        for x in (ax, axr):
            x.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="best")
        axr.legend(fontsize=7, loc="best")
    for x in axes[-1]:
        x.set_xlabel("time [min]")
    fig.suptitle(f"{a.run}: measured inventory against the metered one")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _heldout_rms_table(d: Diagnosis) -> list[str]:
    """Held-out RMS per run and channel, baseline against the first refitted candidate (named or not)."""
    best = next((c for c in d.ranking if c.refit and c.heldout_rms_sigma), None)
    if best is None:
        return []
    base = heldout_rms_sigma(d.baseline["residuals"])
    role = ("the cause" if best.mechanism == d.cause else "the model's form" if best.mechanism == d.named
            else "best refitted, not named")
    L = ["", f"## Held-out RMS per run and channel [sensor sigma]: baseline and `{best.mechanism}` ({role})", "",
         f"| run | channel | baseline | with `{best.mechanism}` |", "|---|---|---|---|"]
    for run, chans in best.heldout_rms_sigma.items():
        L += [f"| {run} | {ch} | {base[run][ch]:.2f} | {v:.2f} |" for ch, v in chans.items() if ch in base.get(run, {})]
    return L


def _plot_prediction(d: Diagnosis, e: int, path) -> None:
    obs = d.problem.obs
    chans = [c for c in range(5) if np.isfinite(obs.y[e, :, c]).any()]
    fig, axes = plt.subplots(len(chans), 1, figsize=(10, 2.2 * len(chans)), sharex=True, squeeze=False)
    t = obs.t_s / 60.0
    held = d.heldout[e]
    for ax, c in zip(axes[:, 0], chans):
        label, unit, k = _UNITS[CHANNELS[c]]
        y, s = obs.y[e, :, c] * k, obs.sigma[e, c] * k
        ok = np.isfinite(y)
        ax.plot(t[ok], y[ok], ".", ms=2, color="0.5", label="data")
        ax.fill_between(t, d.baseline_pred[e, :, c] * k - s, d.baseline_pred[e, :, c] * k + s, color="tab:red",
                        alpha=0.15, lw=0)
        ax.plot(t, d.baseline_pred[e, :, c] * k, color="tab:red", lw=1.2, label="baseline +- 1 sigma")
        if d.extended_pred is not None:
            ax.plot(t, d.extended_pred[e, :, c] * k, color="tab:blue", lw=1.2, label=f"with {d.named}")
        if held.any():
            ax.axvspan(t[held][0], t[held][-1], color="0.9", zorder=0, label="held out")
        ax.set_ylabel(f"{label} [{unit}]")
        ax.grid(alpha=0.3)
    _finish(fig, axes, "time [min]", f"{d.runs[e]}: prediction and data (held-out span shaded)", path)


def _plot_residuals(d: Diagnosis, e: int, path) -> None:
    obs = d.problem.obs
    chans = [c for c in range(5) if np.isfinite(obs.y[e, :, c]).any()]
    fig, axes = plt.subplots(len(chans), 1, figsize=(10, 1.9 * len(chans)), sharex=True, squeeze=False)
    t = obs.t_s / 60.0
    for ax, c in zip(axes[:, 0], chans):
        for pred, color, name in ((d.baseline_pred, "tab:red", "baseline"), (d.extended_pred, "tab:blue", d.named)):
            if pred is None:
                continue
            z = (pred[e, :, c] - obs.y[e, :, c]) / obs.sigma[e, c]
            ok = np.isfinite(z)
            ax.plot(t[ok], z[ok], ".", ms=2, color=color, label=name)
        ax.axhspan(-3, 3, color="0.92", zorder=0)
        ax.axhline(0, color="k", lw=0.6)
        if d.heldout[e].any():
            ax.axvline(t[d.heldout[e]][0], color="k", ls="--", lw=0.8)
        ax.set_ylabel(f"{_UNITS[CHANNELS[c]][0]} residual [sigma]")
        ax.grid(alpha=0.3)
    _finish(fig, axes, "time [min] (dashed: start of the held-out span; band: +-3 sigma)",
            f"{d.runs[e]}: residuals (prediction - data) in noise sigmas", path)


def _finish(fig, axes, xlabel: str, title: str, path) -> None:
    axes[0, 0].legend(fontsize=7, loc="best")
    axes[-1, 0].set_xlabel(xlabel)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _plot_heldout(d: Diagnosis, path) -> None:
    base = d.baseline["heldout_loss_by_channel"]
    ext = d.extended["heldout_loss_by_channel"] if d.extended else None
    chans = [c for c in CHANNELS if base[c] > 0]
    x = np.arange(len(chans))
    fig, ax = plt.subplots(figsize=(7, 3.5))
    ax.bar(x - 0.2, [base[c] for c in chans], 0.4, color="tab:red", label="baseline")
    if ext:
        ax.bar(x + 0.2, [ext[c] for c in chans], 0.4, color="tab:blue", label=f"with {d.named}")
    ax.axhline(0.5, color="k", ls="--", lw=0.8, label="noise floor (0.5)")
    ax.set_xticks(x, [_UNITS[c][0] for c in chans])
    ax.set_ylabel("held-out loss (half mean squared residual / sigma^2)")
    ax.set_yscale("log")
    ax.legend(fontsize=8)
    ax.set_title("held-out loss per channel")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


__all__ = ["write_report", "markdown", "audit_markdown", "plot_inventory"]
