"""Command line: ``tankode simulate``, ``tankode bench`` (more subcommands as they land)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def _load_case_or_run(spec: str):
    from .cases import CASES, get_case
    from .run import read_run

    if spec in CASES:
        return get_case(spec), False
    path = Path(spec)
    if not path.exists():
        raise SystemExit(f"tankode: {spec!r} is neither a case ({', '.join(CASES)}) nor an existing run JSON file")
    run = read_run(path)
    return run, len(run.observations) > 0


def cmd_simulate(args) -> int:
    from .plotting import plot_run
    from .run import write_run
    from .simulate import simulate
    from .synthetic import solution_to_runs

    run, measured = _load_case_or_run(args.run)
    sol = simulate(run, output_dt_s=args.dt)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    channels = ("p_v_Pa", "T_v_K", "T_l_K", "T_w_K", "H_l_m")
    (sim,) = solution_to_runs(run, sol, noise=args.noise, seed=args.seed, channels=channels)
    json_path, csv_path = write_run(sim, out)
    png = out / f"{sim.name}.png"
    clean = solution_to_runs(run, sol, noise="clean", channels=channels)[0]
    plot_run(png, clean if args.noise != "clean" else sim, measured=run if measured else (sim if args.noise != "clean" else None),
             title=f"{run.name}: tankode simulation" + (" vs measured data" if measured else f" ({args.noise} noise)"))
    for note in sol.notes:
        print(f"note: {note}")
    print(f"simulated {sol.t_s[-1] - sol.t_s[0]:.0f} s of {run.name} in {sol.wall_time_s:.2f} s "
          f"(real-time factor {sol.real_time_factor:.0f}, {sol.stats.n_rhs_evals} RHS evaluations, "
          f"{sol.stats.n_segments} segments)")
    print(f"wrote {json_path}, {csv_path}, {png}")
    return 0


def cmd_bench(args) -> int:
    from .bench import run_benchmarks, summary_lines

    result = run_benchmarks(n_points=args.points, repeats=args.repeats)
    print("\n".join(summary_lines(result)))
    print(json.dumps(result))
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="tankode", description=__doc__)
    sub = p.add_subparsers(dest="command", required=True)
    s = sub.add_parser("simulate", help="simulate a case or a run's initial state and inputs")
    s.add_argument("run", help="case1..case5 or a run JSON in the interchange format")
    s.add_argument("--out", required=True, help="output directory for NAME.json, NAME.csv, NAME.png")
    s.add_argument("--noise", choices=("clean", "low", "high"), default="clean", help="synthetic sensor noise level")
    s.add_argument("--seed", type=int, default=0, help="noise seed")
    s.add_argument("--dt", type=float, default=10.0, help="output spacing in s (observation times are added)")
    s.set_defaults(func=cmd_simulate)
    b = sub.add_parser("bench", help="surrogate accuracy and speed vs CoolProp; forward real-time factor")
    b.add_argument("--points", type=int, default=10_000, help="held-out points for the surrogate benchmark")
    b.add_argument("--repeats", type=int, default=3, help="timing repeats (best is kept)")
    b.set_defaults(func=cmd_bench)
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except (ValueError, RuntimeError) as err:  # format errors, simulation errors: say what and where
        print(f"tankode {args.command}: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
