"""The fleet benchmark: one window update of synthetic fleets on 1 and 2 processes.

Fleets are the paper's five cases with jittered tanks, fills, initial states and schedules, a
share of them with light walls (``FleetSpec``); their data are tankode's own simulations with
the low noise level. The update is the first 10-minute window with 20 bounded L-BFGS iterations,
the Rosenbrock integrator and back-propagation through its steps (the configuration for fleets
with light walls, whose stiffness holds dopri5 to sub-second steps). Each process count runs as
a data-parallel job (``trainers/distributed.py``; one process is a process group of one, whose
update equals the plain ``Assimilator``'s, ``tests/test_distributed.py``) with shards cut by
their modelled cost (``trainers.distributed.ShardCost``: probed rates and input changes), and
reports the update's wall time, its real-time factor (window length over update time) and where
each rank's time went.

Usage: ``python -m trainers.fleet_bench --sizes 64 1024 --processes 1 2 [--out DIR]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

# Columns of the schedule (tankode.schedule.INPUT_NAMES) whose magnitudes are jittered.
_SCALED_INPUTS = ("mdot_v_in_kg_s", "mdot_v_out_kg_s", "mdot_l_in_kg_s", "mdot_l_out_kg_s", "slosh_amplitude_m",
                  "Q_aw_W")


@dataclass(frozen=True)
class FleetSpec:
    """How a synthetic fleet is drawn from the paper's five cases.

    Attributes:
        n_tanks: tanks in the fleet; tank ``i`` is case ``i % 5 + 1`` jittered.
        duration_s: length of every run (s); 600 = the one window the benchmark updates on.
        seed: seed of the jitter and of the noise.
        light_share: share of tanks with a light wall (1/8: enough light tanks that a fleet
            split by count gives each shard some).
        light_wall_J_per_K: a light wall's heat capacity (J/K), times a factor in [0.5, 2]:
            an aluminium shell at 20 K of the paper's tank size (MHTB's is 1.4e4 J/K), against
            the paper's 2.44e6 J/K steel wall.
        size_jitter: radius and height each times a factor in ``1 +- size_jitter``.
        time_jitter: every schedule time times one factor in ``1 +- time_jitter`` per tank.
        input_jitter: flows, slosh amplitude and heat ingress times a factor in ``1 +- input_jitter``.
        fill_jitter: fill ratio plus ``+- fill_jitter``.
    """

    n_tanks: int
    duration_s: float = 600.0
    seed: int = 0
    light_share: float = 0.125
    light_wall_J_per_K: float = 2.0e4
    size_jitter: float = 0.15
    time_jitter: float = 0.3
    input_jitter: float = 0.3
    fill_jitter: float = 0.05

    def __post_init__(self):
        if self.n_tanks < 1:
            raise ValueError(f"n_tanks must be >= 1, got {self.n_tanks}")
        if not 0 <= self.light_share <= 1:
            raise ValueError(f"light_share must be in [0, 1], got {self.light_share}")


def jittered_runs(spec: FleetSpec) -> list:
    """The fleet's runs (no observations): cases 1-5 with jittered tank, fill, initial state and schedule."""
    from tankode.cases import get_case
    from tankode.run import InitialState
    from tankode.schedule import INPUT_NAMES, Schedule

    rng = np.random.default_rng(spec.seed)
    base = [get_case(f"case{i}") for i in range(1, 6)]
    n_light = int(round(spec.light_share * spec.n_tanks))
    light = set(rng.choice(spec.n_tanks, size=n_light, replace=False).tolist())
    runs = []
    for i in range(spec.n_tanks):
        case = base[i % 5]
        u = lambda width: 1.0 + rng.uniform(-width, width)  # noqa: E731
        dims = {k: v * u(spec.size_jitter) for k, v in case.tank.dims.items()}
        wall = (spec.light_wall_J_per_K * 2.0 ** rng.uniform(-1, 1) if i in light
                else case.tank.wall_heat_capacity_J_per_K * u(0.2))
        tank = dataclasses.replace(case.tank, dims=dims, wall_heat_capacity_J_per_K=wall, volume_m3=None)
        ini = case.initial
        initial = InitialState(p_v_Pa=ini.p_v_Pa * u(0.1), T_v_K=ini.T_v_K + rng.uniform(-1, 1),
                               T_l_K=ini.T_l_K + rng.uniform(-0.1, 0.1), T_w_K=ini.T_w_K + rng.uniform(-1, 1),
                               fill_ratio=float(np.clip(ini.fill_ratio + rng.uniform(-spec.fill_jitter, spec.fill_jitter),
                                                        0.2, 0.85)))
        t = case.inputs.t_s.copy()
        t[1:] *= u(spec.time_jitter)
        values = case.inputs.values.copy()
        for name in _SCALED_INPUTS:
            values[:, INPUT_NAMES.index(name)] *= u(spec.input_jitter)
        keep = t < case.t_end_s
        schedule = Schedule.from_steps([(float(tk), dict(zip(INPUT_NAMES, row.tolist())))
                                        for tk, row in zip(t[keep], values[keep])], t_end=case.t_end_s)
        run = case.replace(name=f"{case.name}-{i:05d}" + ("-light" if i in light else ""), tank=tank, initial=initial,
                           inputs=schedule)
        runs.append(run.until(spec.duration_s))
    return runs


def fleet_data(spec: FleetSpec, chunk: int = 256) -> list:
    """The fleet with noisy observations (low noise): tankode's simulation, ``chunk`` tanks at a time."""
    from tankode.simulation import simulate
    from tankode.synthetic import solution_to_runs

    runs = jittered_runs(spec)
    out = []
    for a in range(0, len(runs), chunk):
        part = runs[a:a + chunk]
        out.extend(solution_to_runs(part, simulate(part), noise="low", seed=spec.seed * 1_000_003 + a))
    return out


def bench_config():
    """The update the benchmark times: a 10-minute window, 20 iterations, Rosenbrock and Backprop."""
    from tankode.solver import Backprop

    from .assimilate import AssimilationConfig

    # No time budget: the benchmark times a fixed amount of work (20 iterations) on 1 and 2 processes;
    # the bulk's flash alone: the tanks are tankode's own, whose liquid flashes so.
    return AssimilationConfig(window_s=600.0, mode="fixed", iters=20, integrator="rosenbrock", gradient=Backprop(),
                              update_budget_s=math.inf, boiling="bulk")


# ---------------------------------------------------------------------------------------------
# One rank
# ---------------------------------------------------------------------------------------------


def _worker(folder: str, out: str, groups: int = 1, iters: int | None = None) -> None:
    """One rank of the benchmark (RANK, WORLD_SIZE, MASTER_* set): read the fleet, update window 0, write timings."""
    import torch
    import torch.distributed as dist

    from tankode.run_io import read_run

    from .assimilate import Assimilator, uniform_wall
    from .distributed import DistributedConfig, Launch, shard_by_cost

    torch.set_num_threads(1)
    start = time.perf_counter()
    files = sorted(Path(folder).glob("*.json"))
    runs = [read_run(f) for f in files]
    read_s = time.perf_counter() - start
    launch = Launch.from_environment(DistributedConfig(timeout_s=3600.0))
    rank, world = launch.rank, launch.world_size
    config = bench_config()
    # The probes shared out and the shards cut as under torchrun.
    t = time.perf_counter()
    local, parallel = launch.shard(runs, config)
    shards, rates, restarts = parallel.shards, np.asarray(launch.rates), np.asarray(launch.restarts)
    probe_s = time.perf_counter() - t
    if iters is not None:
        config = dataclasses.replace(config, iters=iters)
    wall = uniform_wall(config)  # the benchmark times one update, not the choice of the wall's start
    if groups > 1:  # this rank's runs integrated in groups cut by their probed cost
        from .grouped import GroupedAssimilator

        local_groups = shard_by_cost(rates[list(shards[rank])], groups, restarts=restarts[list(shards[rank])])
        assim = GroupedAssimilator(local, config, local_groups, parallel=parallel, mechanisms=wall)
    else:
        assim = Assimilator(local, config, parallel=parallel, mechanisms=wall)
    # Counted on the class: the grouped assimilator integrates each group with its own model
    # (``TankModel.on``), which an instance's counter would not see.
    from tankode.model import TankModel

    calls = [0]
    forward = TankModel.forward

    def counted(self, t, s, f):
        calls[0] += 1
        return forward(self, t, s, f)

    TankModel.forward = counted
    dist.barrier()
    t, cpu = time.perf_counter(), time.process_time()
    report, _, _ = assim.update(0, assim.s0)
    update_s, cpu_s = time.perf_counter() - t, time.process_time() - cpu
    result = {"rank": rank, "world": world, "groups": groups, "n_local": len(local), "update_s": update_s,
              "update_cpu_s": cpu_s, "rhs_evals": calls[0], "n_evals": report.n_evals, "n_iters": report.n_iters,
              "cost_before": report.cost_before, "cost_after": report.cost_after,
              "forward_s": parallel.timings.forward_s, "backward_s": parallel.timings.backward_s,
              "reduce_s": parallel.timings.reduce_s, "read_s": read_s, "probe_s": probe_s,
              "shards": [list(s) for s in shards], "light_local": sum("light" in r.name for r in local),
              "rates_local": rates[list(shards[rank])].tolist()}
    Path(out).write_text(json.dumps(result))
    launch.close()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def run_job(folder: Path, n_processes: int, groups: int = 1, iters: int | None = None,
            timeout_s: float = 7200.0) -> list[dict]:
    """Launch ``n_processes`` ranks on this machine (the environment torchrun sets); their result dicts."""
    port = _free_port()
    with tempfile.TemporaryDirectory() as tmp:
        outs = [Path(tmp) / f"rank{r}.json" for r in range(n_processes)]
        env = {**os.environ, "WORLD_SIZE": str(n_processes), "MASTER_ADDR": "127.0.0.1", "MASTER_PORT": str(port),
               "OMP_NUM_THREADS": "1"}
        cmd = [sys.executable, "-m", "trainers.fleet_bench", "--worker", str(folder)]
        extra = ["--groups", str(groups)] + (["--iters", str(iters)] if iters is not None else [])
        procs = [subprocess.Popen(cmd + ["--worker-out", str(outs[r])] + extra,
                                  env={**env, "RANK": str(r), "LOCAL_RANK": str(r)}) for r in range(n_processes)]
        for p in procs:
            p.wait(timeout=timeout_s)
            if p.returncode != 0:
                raise RuntimeError(f"benchmark rank failed with exit code {p.returncode}")
        return [json.loads(o.read_text()) for o in outs]


# ---------------------------------------------------------------------------------------------
# The machine's parallelism and the table
# ---------------------------------------------------------------------------------------------


def _spin(seconds: float) -> int:
    """Count loop iterations of pure Python for ``seconds`` of wall time (one core's work)."""
    n, end = 0, time.perf_counter() + seconds
    while time.perf_counter() < end:
        n += 1
    return n


def available_parallelism(seconds: float = 3.0) -> float:
    """Throughput of two concurrent CPU-bound processes over one alone (2.0 on two idle cores)."""
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(2) as pool:
        one = pool.submit(_spin, seconds).result()
        two = sum(f.result() for f in [pool.submit(_spin, seconds) for _ in range(2)])
    return two / one


def summarise(rows: list[dict]) -> dict:
    """A job's row: the update's wall time (slowest rank) and the ranks' time split."""
    slow = max(rows, key=lambda r: r["update_s"])
    return {"n_tanks": sum(r["n_local"] for r in rows), "processes": len(rows), "groups": rows[0]["groups"],
            "update_s": slow["update_s"], "update_cpu_s": max(r["update_cpu_s"] for r in rows),
            "real_time_factor": 600.0 / slow["update_s"], "n_evals": slow["n_evals"], "n_iters": slow["n_iters"],
            "cost_before": slow["cost_before"], "cost_after": slow["cost_after"],
            "ranks": [{k: r[k] for k in ("n_local", "light_local", "update_s", "update_cpu_s", "rhs_evals", "forward_s",
                                         "backward_s", "reduce_s", "probe_s", "rates_local")}
                      for r in sorted(rows, key=lambda r: r["rank"])]}


def table(results: list[dict]) -> str:
    """Markdown rows: the update's wall time, real-time factor, CPU time, and each rank's split."""
    lines = ["| tanks | processes (groups) | update wall (s) | real-time factor | update CPU, busiest rank (s) | "
             "evaluations | per rank: tanks (light), RHS evaluations, forward / backward / all-reduce wait / other (s) |",
             "|---|---|---|---|---|---|---|"]
    for s in results:
        parts = []
        for r in s["ranks"]:
            other = r["update_s"] - r["forward_s"] - r["backward_s"] - r["reduce_s"]
            parts.append(f"{r['n_local']} ({r['light_local']}), {r['rhs_evals']} RHS: {r['forward_s']:.1f} / "
                         f"{r['backward_s']:.1f} / {r['reduce_s']:.1f} / {other:.1f}")
        lines.append(f"| {s['n_tanks']} | {s['processes']} ({s['groups']}) | {s['update_s']:.1f} | "
                     f"{s['real_time_factor']:.2f} | {s['update_cpu_s']:.1f} | {s['n_evals']} | {'; '.join(parts)} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[64, 1024])
    p.add_argument("--processes", type=int, nargs="+", default=[1, 2])
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default=None, help="folder for results.json (and the fleets' run files)")
    p.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    p.add_argument("--worker-out", default=None, help=argparse.SUPPRESS)
    p.add_argument("--groups", type=int, default=1,
                   help="also time one process integrating the fleet in this many groups cut by cost")
    p.add_argument("--iters", type=int, default=None,
                   help="L-BFGS iterations (default: the benchmark's 20); fewer to time evaluations of a large fleet")
    args = p.parse_args(argv)
    if args.worker:
        _worker(args.worker, args.worker_out, args.groups, args.iters)
        return 0
    from tankode.run_io import write_run

    out = Path(args.out or tempfile.mkdtemp(prefix="fleet_bench_"))
    out.mkdir(parents=True, exist_ok=True)
    t = time.perf_counter()
    parallelism = available_parallelism()
    print(f"this machine: {os.cpu_count()} cores; two concurrent CPU-bound processes get {parallelism:.2f}x the "
          f"throughput of one (load average {os.getloadavg()[0]:.2f})", flush=True)
    results = []
    for n in args.sizes:
        folder = out / f"fleet{n}"
        if not folder.exists():
            t0 = time.perf_counter()
            for run in fleet_data(FleetSpec(n, seed=args.seed)):
                write_run(run, folder)
            print(f"{n} tanks: data simulated in {time.perf_counter() - t0:.0f} s", flush=True)
        jobs = [(k, 1) for k in args.processes] + ([(1, args.groups)] if args.groups > 1 else [])
        for k, groups in jobs:
            rows = run_job(folder, k, groups, args.iters)
            s = summarise(rows)
            s["load_average"] = os.getloadavg()[0]
            results.append(s)
            print(table([s]).splitlines()[-1], flush=True)
        one = [s for s in results if s["n_tanks"] == n and s["processes"] == 1]
        for s in results:
            if s["n_tanks"] == n and s["processes"] > 1 and one:
                print(f"{n} tanks: {s['processes']} processes {one[0]['update_s'] / s['update_s']:.2f}x faster than 1",
                      flush=True)
    print(table(results))
    summary = {"parallelism": parallelism, "results": results, "wall_s": time.perf_counter() - t}
    (out / "results.json").write_text(json.dumps(summary, indent=1))
    print(f"wrote {out / 'results.json'} ({summary['wall_s']:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
