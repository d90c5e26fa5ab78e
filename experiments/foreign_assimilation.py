"""The agent on heat transfer tankode was not built from: train on 70 % of a run, predict the rest.

Runs come from ``tests/nodal_sim.py``, a simulator that shares no code with tankode (its own
formulation, a two-node wall, bulk flash and fog, its own geometry), with three heat-transfer
laws tankode does not use: the paper's correlations as printed (``paper_printed``), McAdams-type
natural convection on all four surfaces (``mcadams``) and a sloshing enhancement of another form
(``slosh_energy``), in four tank shapes, each run with heat load, pressurisation or venting,
fill or drain, and sloshing. For every run, ``trainers.evaluate.hold_out`` trains the agent with
the package's default ``AssimilationConfig`` on the first 70 % and judges it. The table gives,
in noise sigmas per channel (p, T_v, T_l, T_w, H_l): the held-out 30 % forecast from the state the
assimilation carried to the split with the final agent and no refit (what a real-time twin
predicts when its data stop); the windows' own cost after their updates against the noise
floor; then the stricter check of the final agent simulated over the whole run from its start
(RMSE over the training part and the held-out part, and its cost over the training part); and
the real-time factor of the window updates (window length over update time: >= 1 is real time).

``--simulator cryo`` takes the runs from ``tests/cryo_sim.py`` instead, a third simulator
sharing no code with tankode or the other two, with laws of its own (Churchill-Chu walls, a
Globe-Dropkin interface, a surface layer over the bulk liquid, wet and dry wall nodes whose
split at the start is its own, nucleate boiling) and other fluids: a 2 m3 nitrogen dewar with
2:1 heads (vent, drain), an 8 m3 hydrogen horizontal cylinder (drain, vent, sloshing) and a
30 m3 methane sphere (warm-gas pressurisation, sloshing, fill). ``--simulator layer`` takes them
from ``tests/layer_sim.py``, a fourth: a stratified liquid and ullage in layers and a wall of ten
nodes along the height (a 15 m3 hydrogen tank with heads: pressurisation, vent, sloshing; a 5 m3
nitrogen sphere: fill, drain, vent; an 8 m3 hydrogen horizontal cylinder: drain, top-up).

``--scenarios upright_cycles sphere_cycles hcyl_cycles`` takes three of those tanks with their
operations run twice in an hour, so that the held-out 30 % repeats operations the training part
showed: the forecast then asks the agent to carry what it learned rather than meet an operation
it never saw (which the four default scenarios ask, and which only the base closure can
answer).

The simulator is run through its command line (``python tests/nodal_sim.py``), as a user's data
would arrive: as files.

    python experiments/foreign_assimilation.py [--quick] [--out results/foreign_assimilation]
        [--simulator nodal|cryo|layer] [--laws LAW ...] [--scenarios SCENARIO ...] [--duration S] [--seeds 0 1 2]
        [--replay-segments N] [--replay-s S] [--window-start model|data]

``--seeds`` trains one agent per seed (initial weights and replay draws) on the same run, to
separate what the data teach from what one draw of the initial weights does.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from tankode.run_io import read_run
from trainers.assimilate import AssimilationConfig
from trainers.evaluate import hold_out

TESTS = Path(__file__).resolve().parents[1] / "tests"
SIMULATORS = {"nodal": TESTS / "nodal_sim.py", "cryo": TESTS / "cryo_sim.py", "layer": TESTS / "layer_sim.py"}
LAWS = ("paper_printed", "mcadams", "slosh_energy")
# The third and fourth simulators come with their own laws (module docstring): their scenarios.
OWN_LAW_SCENARIOS = {"cryo": ("ln2_dewar", "lh2_hcyl", "lch4_sphere"),
                     "layer": ("lh2_upright", "ln2_sphere", "lh2_hcyl")}
# (scenario, what it holds): four shapes, every operation between them.
SCENARIOS = (
    ("upright_13m3", "upright cylinder 13.6 m3: heat, warm-gas pressurisation, sloshing, vent, drain"),
    ("sphere_4m3", "sphere 4.2 m3: heat, warm-gas pressurisation, vent, sloshing"),
    ("hcyl_drain_fill", "horizontal cylinder 10.2 m3: heat, drain, fill with venting"),
    ("ellipsoidal_light_wall", "elliptical heads 6.8 m3, light wall: heat, pressurisation, vent, sloshing"),
)
# Three of them with their operations twice in an hour: the held-out part repeats what training saw.
REPEATED = (
    ("upright_cycles", "upright cylinder 13.6 m3: pressurisation, sloshing, vent, drain, twice"),
    ("sphere_cycles", "sphere 4.2 m3: pressurisation, vent, sloshing, fill, twice"),
    ("hcyl_cycles", "horizontal cylinder 10.2 m3: drain, pressurisation, sloshing, fill with venting, twice"),
)
NOISE = "low"  # the simulator's low level: 300 Pa, 0.05 K, 1 mm


def make_run(out: Path, scenario: str, law: str, seed: int, duration_s: float | None = None) -> Path:
    """Write one run of an independent simulator into ``out`` (``law`` the name of a simulator with
    its own laws, ``cryo`` or ``layer``; else ``tests/nodal_sim.py`` with that law); return its JSON path."""
    name = f"{scenario}_{law}"
    own = law in OWN_LAW_SCENARIOS
    cmd = [sys.executable, str(SIMULATORS[law if own else "nodal"]), scenario, "--out", str(out), "--name", name,
           "--noise", NOISE, "--seed", str(seed)] + ([] if own else ["--law", law])
    if duration_s is not None:
        cmd += ["--duration", str(duration_s)]
    subprocess.run(cmd, check=True, capture_output=True, text=True)
    return out / f"{name}.json"


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one law and one 40-minute run (CI smoke run)")
    ap.add_argument("--out", default="results/foreign_assimilation")
    ap.add_argument("--simulator", choices=sorted(SIMULATORS), default="nodal",
                    help="nodal: tests/nodal_sim.py with --laws; cryo, layer: tests/cryo_sim.py or "
                         "tests/layer_sim.py, each with its own laws")
    ap.add_argument("--laws", nargs="+", choices=LAWS, default=list(LAWS))
    ap.add_argument("--scenarios", nargs="+",
                    choices=sorted({s for s, _ in SCENARIOS + REPEATED} | {s for v in OWN_LAW_SCENARIOS.values() for s in v}),
                    help="default: the simulator's scenarios")
    ap.add_argument("--duration", type=float, default=None, help="cut each run to this many seconds (default: whole)")
    ap.add_argument("--replay-segments", type=int, default=AssimilationConfig.replay_segments,
                    help="AssimilationConfig.replay_segments (default: the package's)")
    ap.add_argument("--replay-s", type=float, default=AssimilationConfig.replay_s,
                    help="AssimilationConfig.replay_s in s (default: the package's)")
    ap.add_argument("--window-start", choices=("model", "data"), default=AssimilationConfig.window_start,
                    help="where each window starts (AssimilationConfig.window_start)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0],
                    help="agent seeds (AssimilationConfig.seed: initial weights, replay draws); one row per seed")
    args = ap.parse_args(argv)
    quick, out = args.quick, Path(args.out)
    data = out / "runs"
    data.mkdir(parents=True, exist_ok=True)
    own = args.simulator in OWN_LAW_SCENARIOS
    names = list(OWN_LAW_SCENARIOS[args.simulator]) if own else [s for s, _ in SCENARIOS + REPEATED]
    scenarios = args.scenarios or (names if own else [s for s, _ in SCENARIOS])
    if any(s not in names for s in scenarios):
        ap.error(f"--simulator {args.simulator} has the scenarios {names}, got {scenarios}")
    laws = [args.simulator] if own else args.laws
    plan = [(s, law) for law in laws for s in scenarios] if not quick else [("upright_13m3", "mcadams")]
    duration_s = 2400.0 if quick else args.duration
    base = AssimilationConfig(replay_segments=args.replay_segments, replay_s=args.replay_s,
                              window_start=args.window_start)
    rows = []
    for (scenario, law), agent_seed in itertools.product(plan, args.seeds):
        config = dataclasses.replace(base, seed=agent_seed)
        # the same run whatever the selection (the repeated-operation tanks after the four)
        seed = (0 if own else LAWS.index(law)) * (len(names) if own else len(SCENARIOS)) + names.index(scenario)
        path = make_run(data, scenario, law, seed=seed, duration_s=duration_s)
        run = read_run(path)
        start = time.perf_counter()
        h = hold_out(run, config)
        rtf = h.real_time_factors
        row = {"run": run.name, "scenario": scenario, "law": law, "agent_seed": agent_seed, "duration_s": run.t_end_s - run.t0_s,
               "held_out": h.held_out, "cost_windows": h.cost_windows, "fit": h.fit,
               "held_out_from_start": h.held_out_from_start, "cost_fit": h.cost_fit, "floor": h.floor,
               "rtf_min": min(rtf), "rtf_median": float(np.median(rtf)), "wall_s": time.perf_counter() - start,
               "mechanisms": h.mechanisms}
        rows.append(row)
        print(json.dumps(row), flush=True)
    (out / "results.json").write_text(json.dumps({"config": base.to_json(), "noise": NOISE,
                                                  "rows": rows}, indent=1))
    lines = ["| law | run | agent seed | held-out forecast RMSE / sigma (p, T_v, T_l, T_w, H_l) | J windows / floor | "
             "from the start: fit RMSE / sigma | held-out | J fit / floor | RTF min / median |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        fmt = lambda d: ", ".join(f"{d[c]:.1f}" for c in d)  # noqa: E731
        lines.append(f"| {r['law']} | {r['scenario']} | {r['agent_seed']} | {fmt(r['held_out'])} | {r['cost_windows'] / r['floor']:.1f} | "
                     f"{fmt(r['fit'])} | {fmt(r['held_out_from_start'])} | {r['cost_fit'] / r['floor']:.1f} | "
                     f"{r['rtf_min']:.1f} / {r['rtf_median']:.1f} |")
    (out / "table.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return {"rows": rows}


if __name__ == "__main__":
    main()
