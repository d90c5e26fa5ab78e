"""The diagnosis on four simulators that share no code with tankode: what it names, against the truth.

Generates runs with ``tests/nodal_sim.py`` (through its command line: laws ``mcadams`` and
``paper_printed`` by default, four shapes and operations, low noise, each hidden mechanism, nulls),
the fourteen runs of ``tests/independent_sim.py`` (seed 0, the magnitudes of its
``SCENARIO_FOR`` table; that module has no command line that writes runs, so a subprocess calls
its public ``simulate_run``) and ``tests/cryo_sim.py``'s three named tanks (liquid nitrogen,
methane and hydrogen; every hidden mechanism at the magnitudes of ``CRYO_MAGNITUDES``, nulls) and
``tests/eng_sim.py``'s (an engineering property model: ``ENG_SCENARIOS``, ``ENG_MAGNITUDES``),
diagnoses each with ``tankode.diagnosis.diagnose`` and writes

* ``OUT/table.md`` and ``OUT/table.json``: simulator, scenario, law, hidden mechanism and value,
  the verdict (kind, name, estimate, candidates), the audit's z of the hidden mechanism's
  inventory signature, the outcome and the time;
* ``OUT/runs/``: the generated runs (their ``.truth.json`` sidecars are not read by tankode).

Outcomes: ``right`` (the hidden mechanism named, an inventory mechanism's estimate within 25 %),
``listed`` (a measured quantity named with the hidden mechanism among its indistinguishable
candidates, estimate within 25 %), ``estimate off`` (right name or list, estimate beyond 25 %),
``none`` (nothing named), ``wrong`` (anything else). A run with nothing hidden is ``right`` when
nothing is named.

Usage::

    python experiments/diagnosis_foreign.py --out diag_foreign            # the whole table (~1-2 h)
    python experiments/diagnosis_foreign.py --out d --only nodal --laws mcadams --scenarios tank_4p9m3
    python experiments/diagnosis_foreign.py --out d --only cryo                  # 33 runs, three fluids
    python experiments/diagnosis_foreign.py --out d --only eng                   # 77 runs, engineering properties
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import time
from pathlib import Path

from tankode.diagnosis.verdict import AUDIT_HYPOTHESIS, INVENTORY as INVENTORY_MECHANISMS
from tankode.mechanisms.noncondensable import R_J_PER_MOLK

ROOT = Path(__file__).resolve().parents[1]

# nodal_sim mechanism -> (tankode's name for it, the value the verdict's estimate is compared with)
NODAL_MECHANISMS = {
    "heat_leak_liquid_W": ("heat_leak_liquid", 400.0),
    "heat_leak_vapor_W": ("heat_leak_vapor", 300.0),
    "heat_leak_wall_W": ("heat_leak_wall", 400.0),
    "vapor_leak_kg_s": ("vapor_leak", 5e-4),
    "liquid_leak_kg_s": ("liquid_leak", 5e-4),
    "inflow_meter_bias": ("inflow_meter_bias", 0.15),
    "pressure_sensor_bias_Pa": ("pressure_sensor_bias", 8000.0),
    "temperature_sensor_bias_K": ("temperature_sensor_bias", 0.5),
    "noncondensable_mol": ("noncondensable_gas", None),  # per scenario: INERT_MOL
    "wall_heat_capacity_error": ("wall_heat_capacity_error", 0.5),
}
# Helium amounts that carry 13-23 % of each scenario's initial ullage pressure (nodal_sim's truth files).
INERT_MOL = {"tank_4p9m3": 200.0, "upright_13m3": 700.0, "sphere_4m3": 200.0, "hcyl_drain_fill": 400.0}
# The audit's hypothesis that measures each inventory mechanism.
INVENTORY = {m: AUDIT_HYPOTHESIS[m] for m in INVENTORY_MECHANISMS}
SCENARIOS = ("tank_4p9m3", "upright_13m3", "sphere_4m3", "hcyl_drain_fill")
LAWS = ("mcadams", "paper_printed")
# cryo_sim mechanism -> tankode's name for it.
CRYO_MECHANISMS = {"heat_leak_liquid_W": "heat_leak_liquid", "heat_leak_vapor_W": "heat_leak_vapor",
                   "heat_leak_wall_W": "heat_leak_wall", "vapor_leak_kg_s": "vapor_leak",
                   "liquid_leak_kg_s": "liquid_leak", "inflow_meter_bias": "inflow_meter_bias",
                   "pressure_sensor_bias_Pa": "pressure_sensor_bias", "temperature_sensor_bias_K": "temperature_sensor_bias",
                   "helium_mol": "noncondensable_gas", "wall_heat_capacity_error": "wall_heat_capacity_error"}
# Per cryo_sim tank: heat leaks [W] and leaks [kg/s] of about 5 standard errors of its audit (measured
# on nulls of seeds 1-6: heat 20-35 W on the 2 m3 and 8 m3 tanks); helium for 15 % of the initial pressure.
CRYO_SCENARIOS = ("ln2_dewar", "lh2_hcyl", "lch4_sphere")
CRYO_MAGNITUDES = {"ln2_dewar": (150.0, 5e-4), "lh2_hcyl": (150.0, 5e-4), "lch4_sphere": (600.0, 2e-3)}
# tests/eng_sim.py (an engineering property model, cryo_sim's command line and mechanism names):
# its four named tanks and random ones, at the magnitudes the audit resolves on its nulls' scatter.
ENG_SCENARIOS = ("lh2_upright", "ln2_hcyl", "lch4_sphere", "lh2_small", "random_1", "random_2", "random_3")
ENG_MAGNITUDES = {"lh2_upright": (300.0, 5e-4), "ln2_hcyl": (600.0, 2e-3), "lch4_sphere": (600.0, 2e-3),
                  "lh2_small": (150.0, 5e-4), "random_1": (300.0, 5e-4), "random_2": (300.0, 5e-4),
                  "random_3": (300.0, 5e-4)}
# Per simulator of that command line: its scenarios, magnitudes and heat-transfer laws in words.
CLI_SIMS = {"cryo": (CRYO_SCENARIOS, CRYO_MAGNITUDES, "Churchill-Chu"),
            "eng": (ENG_SCENARIOS, ENG_MAGNITUDES, "Nu = 0.13 Ra^(1/3)")}


def nodal_jobs(scenarios, laws) -> list[dict]:
    jobs = []
    for law in laws:
        for sc in scenarios:
            jobs.append({"sim": "nodal", "scenario": sc, "law": law, "hidden": None, "value": 0.0, "args": []})
            for key, (mid, value) in NODAL_MECHANISMS.items():
                value = INERT_MOL.get(sc, 200.0) if value is None else value
                jobs.append({"sim": "nodal", "scenario": sc, "law": law, "hidden": mid, "value": value,
                             "args": ["--mechanism", f"{key}={value}"]})
            jobs.append({"sim": "nodal", "scenario": sc, "law": law, "hidden": "thermal_stratification", "value": 0.0,
                         "args": ["--liquid-layers", "4"]})
    return jobs


_INDEPENDENT = """
import json, sys
sys.path.insert(0, {tests!r})
from independent_sim import SCENARIOS, SCENARIO_FOR, simulate_run, suggested_magnitude
out = []
for sc in SCENARIOS:
    out.append((str(simulate_run(sc, None, 0.0, seed=0, out_dir={folder!r})), sc, None, 0.0))
for mech, sc in SCENARIO_FOR.items():
    v = suggested_magnitude(mech, sc)
    out.append((str(simulate_run(sc, mech, v, seed=0, out_dir={folder!r})), sc, mech, v))
print(json.dumps(out))
"""


def generate(job: dict, folder: Path) -> Path:
    name = f"{job['scenario']}_{job['law']}_{job['hidden'] or 'none'}"
    cmd = [sys.executable, str(ROOT / "tests" / "nodal_sim.py"), job["scenario"], "--law", job["law"], "--noise", "low",
           "--seed", "0", "--out", str(folder), "--name", name, *job["args"]]
    subprocess.run(cmd, check=True, capture_output=True, text=True)
    truth = json.loads((folder / f"{name}.truth.json").read_text())["initial_true"]
    job["inert_share"] = 1.0 - truth["p_H2_Pa"] / truth["p_Pa"]  # the inert gas's share of the initial pressure
    return folder / f"{name}.json"


def cli_jobs(sim: str) -> list[dict]:
    """Every hidden mechanism and a null per scenario of ``cryo_sim`` or ``eng_sim`` (``CLI_SIMS``)."""
    scenarios, magnitudes, law = CLI_SIMS[sim]
    jobs = []
    for sc in scenarios:
        heat, leak = magnitudes[sc]
        values = {"heat_leak_liquid_W": heat, "heat_leak_vapor_W": heat, "heat_leak_wall_W": heat,
                  "vapor_leak_kg_s": leak, "liquid_leak_kg_s": leak, "inflow_meter_bias": 0.15,
                  "pressure_sensor_bias_Pa": 5000.0, "temperature_sensor_bias_K": 0.5, "helium_mol": None,
                  "wall_heat_capacity_error": 0.5}
        jobs.append({"sim": sim, "scenario": sc, "law": law, "hidden": None, "value": 0.0})
        for key, value in values.items():
            jobs.append({"sim": sim, "scenario": sc, "law": law, "hidden": CRYO_MECHANISMS[key],
                         "value": value, "key": key})
    return jobs


def generate_cli(job: dict, folder: Path) -> Path:
    """Write a cryo_sim or eng_sim run; the helium amount is set from the null run's initial ullage (15 % of p)."""
    sim = job["sim"]
    name = f"{sim}_{job['scenario']}_{job['hidden'] or 'none'}"
    args = []
    if job["hidden"] is not None:
        if job["value"] is None:
            null = json.loads((folder / f"{sim}_{job['scenario']}_none.truth.json").read_text())["initial_true"]
            meta = json.loads((folder / f"{sim}_{job['scenario']}_none.json").read_text())
            V_v = (1.0 - null["fill_ratio"]) * meta["tank"]["volume_m3"]
            job["value"] = 0.15 * null["p_Pa"] * V_v / (R_J_PER_MOLK * null["T_v_K"])
        args = ["--mechanism", f"{job['key']}={job['value']}"]
    path = folder / f"{name}.json"
    if not path.exists():
        cmd = [sys.executable, str(ROOT / "tests" / f"{sim}_sim.py"), job["scenario"], "--noise", "low", "--seed", "0",
               "--out", str(folder), "--name", name, *args]
        subprocess.run(cmd, check=True, capture_output=True, text=True)
    truth = json.loads((folder / f"{name}.truth.json").read_text())["initial_true"]
    job["inert_share"] = truth.get("p_helium_Pa", 0.0) / truth["p_Pa"]
    return path


def independent_runs(folder: Path) -> list[dict]:
    code = _INDEPENDENT.format(tests=str(ROOT / "tests"), folder=str(folder))
    done = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True)
    return [{"sim": "independent", "scenario": sc, "law": "McAdams-type", "hidden": mech, "value": v, "path": Path(p)}
            for p, sc, mech, v in json.loads(done.stdout.strip().splitlines()[-1])]


def outcome(job: dict, verdict, audit) -> tuple[str, float | None]:
    """(outcome, the audit's z of the hidden mechanism's inventory signature or None)."""
    hidden = job["hidden"]
    hyp = AUDIT_HYPOTHESIS.get(hidden)
    z = None
    if hyp is not None and audit is not None and hyp in audit.hypotheses:
        z = audit.hypotheses[hyp].z
    if hidden is None:
        return ("right" if verdict.kind == "none" else "wrong"), z
    if verdict.kind == "none":
        return "none", z
    truth = job["value"] if hidden != "wall_heat_capacity_error" else 1.0 + job["value"]
    if hidden == "thermal_stratification":
        truth = None
    named = verdict.name == hidden or (verdict.kind == "unresolved" and hidden in verdict.candidates)
    if not named:
        return "wrong", z
    kind = "right" if verdict.kind == "cause" else "listed"
    if hidden in INVENTORY and truth is not None and verdict.estimate is not None:
        est = verdict.estimate.value
        if hidden in ("vapor_leak", "liquid_leak") and verdict.name == "unmetered_mass":
            est = -est  # a loss
        if not abs(est - truth) <= 0.25 * abs(truth):
            return "estimate off", z
    return kind, z


def diagnose_one(job: dict) -> dict:
    from tankode import read_run
    from tankode.diagnosis import diagnose

    run = read_run(job["path"])
    t = time.perf_counter()
    d = diagnose([run])
    wall = time.perf_counter() - t
    audit = d.audits[0] if d.audits else None
    result, z = outcome(job, d.verdict, audit)
    v = d.verdict
    return {"sim": job["sim"], "scenario": job["scenario"], "law": job["law"], "hidden": job["hidden"],
            "value": job["value"], "duration_s": run.t_end_s - run.t0_s, "verdict": v.to_json(), "outcome": result,
            "audit_z": z, "time_s": wall, "n_simulations": d.n_simulations, "inert_share": job.get("inert_share")}


def _fmt(row: dict) -> str:
    v = row["verdict"]
    est = v["estimate"]
    shown = "" if est is None else (f"{est['value']:.3g}" + (f" +- {est['std']:.2g}" if est["std"] is not None
                                                             and math.isfinite(est["std"]) else ""))
    name = v["name"] or "none"
    if v["kind"] == "unresolved":
        name = f"{name} ({', '.join(v['candidates'])})"
    z = "" if row["audit_z"] is None else f"{row['audit_z']:.1f}"
    hidden = row["hidden"] or "none"
    value = "" if row["hidden"] is None or row["hidden"] == "thermal_stratification" else f"{row['value']:g}"
    if row.get("inert_share") is not None and row["hidden"] == "noncondensable_gas":
        value += f" ({row['inert_share']:.0%} of p)"
    return (f"| {row['sim']} | {row['scenario']} | {row['law']} | {hidden} | {value} | {name} | {shown} | {z} | "
            f"{row['outcome']} | {row['time_s']:.0f} |")


def write_table(rows: list[dict], out: Path) -> str:
    lines = ["| simulator | scenario | law | hidden | value | verdict | estimate | audit z | outcome | time [s] |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    lines += [_fmt(r) for r in rows]
    counts: dict[str, int] = {}
    for r in rows:
        counts[r["outcome"]] = counts.get(r["outcome"], 0) + 1
    times = sorted(r["time_s"] for r in rows)
    summary = (f"\n{len(rows)} runs: " + ", ".join(f"{k} {v}" for k, v in sorted(counts.items()))
               + (f"; time per run {times[0]:.0f}-{times[-1]:.0f} s (median {times[len(times) // 2]:.0f} s)" if times else ""))
    text = "\n".join(lines) + "\n" + summary + "\n"
    (out / "table.md").write_text(text)
    (out / "table.json").write_text(json.dumps(rows, indent=1) + "\n")
    return text


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="output folder (runs/, table.md, table.json)")
    ap.add_argument("--only", choices=("nodal", "independent", *CLI_SIMS), default=None, help="one simulator only")
    ap.add_argument("--laws", nargs="+", default=list(LAWS), help="nodal_sim laws")
    ap.add_argument("--scenarios", nargs="+", default=list(SCENARIOS), help="nodal_sim scenarios")
    ap.add_argument("--hidden", nargs="*", default=None, help="only these hidden mechanisms (tankode names; 'none')")
    ap.add_argument("--regenerate", action="store_true", help="simulate runs again that OUT/runs already holds "
                                                               "(by default they are reused, and OUT/table.json's rows kept)")
    args = ap.parse_args(argv)
    out = Path(args.out)
    runs = out / "runs"
    runs.mkdir(parents=True, exist_ok=True)
    jobs = []
    if args.only in (None, "nodal"):
        for job in nodal_jobs(args.scenarios, args.laws):
            if args.hidden is None or (job["hidden"] or "none") in args.hidden:
                name = runs / f"{job['scenario']}_{job['law']}_{job['hidden'] or 'none'}.json"
                job["path"] = name if name.exists() and not args.regenerate else generate(job, runs)
                if "inert_share" not in job:
                    truth = json.loads(name.with_suffix(".truth.json").read_text())["initial_true"]
                    job["inert_share"] = 1.0 - truth["p_H2_Pa"] / truth["p_Pa"]
                jobs.append(job)
    if args.only in (None, "independent"):
        jobs += [j for j in independent_runs(runs) if args.hidden is None or (j["hidden"] or "none") in args.hidden]
    for sim in CLI_SIMS:
        if args.only not in (None, sim):
            continue
        for job in cli_jobs(sim):
            wanted = args.hidden is None or (job["hidden"] or "none") in args.hidden
            if wanted or job["hidden"] is None:  # the null is always written: the helium amount is set from it
                job["path"] = generate_cli(job, runs)
            if wanted:
                jobs.append(job)
    done = json.loads((out / "table.json").read_text()) if (out / "table.json").exists() else []
    key = lambda r: (r["sim"], r["scenario"], r["law"], r["hidden"])  # noqa: E731
    rows = [r for r in done if key(r) in {key(j) for j in jobs}]  # resume: the rows already measured are kept
    for job in jobs:
        if key(job) in {key(r) for r in rows}:
            continue
        row = diagnose_one(job)
        rows.append(row)
        print(_fmt(row), flush=True)
        write_table(rows, out)
    print(write_table(rows, out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
