"""Data-parallel assimilation (trainers/distributed.py): the reduction, the shards, launches, faults.

The multi-process tests launch the command line as a data-parallel job on this machine: with
torchrun, or (to control one rank) as two processes given the environment torchrun sets. They
train 4 short synthetic tanks (cases 1-4, 8 minutes, low noise) on 2-minute windows with 3
L-BFGS iterations and the Rosenbrock integrator.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from tankode.cases import get_case
from tankode.run_io import read_run, write_run
from tankode.simulation import simulate
from tankode.solver import Backprop
from tankode.synthetic import solution_to_runs
from trainers.assimilate import AssimilationConfig, Assimilator
from trainers.distributed import DataParallel, ShardCost, SingleProcess, group_sum, probe_costs, shard_by_cost
from trainers.grouped import GroupedAssimilator

BIN = Path(sys.executable).parent
DURATION_S = 480.0
WINDOW_S = 120.0
ITERS = 3
# No update budget: the comparisons below need weights that do not depend on each run's speed.
CONFIG = AssimilationConfig(window_s=WINDOW_S, iters=ITERS, integrator="rosenbrock", gradient=Backprop(),
                            update_budget_s=math.inf)
CLI_OPTIONS = ["--window", str(WINDOW_S), "--iters", str(ITERS), "--integrator", "rosenbrock",
               "--update-budget", "inf", "--quiet"]


def _weights(path) -> torch.Tensor:
    return torch.cat([v.reshape(-1) for v in torch.load(path, weights_only=True).values()])


def _closure_weights(closure) -> torch.Tensor:
    return torch.cat([v.detach().reshape(-1) for v in closure.state_dict().values()])


def _rel(a: torch.Tensor, b: torch.Tensor) -> float:
    return float((a - b).norm() / b.norm())


# ---------------------------------------------------------------------------------------------
# Shards by cost
# ---------------------------------------------------------------------------------------------


def _brute_force_best(rates, n_ranks, model):
    """The smallest largest-shard cost over every assignment of runs to ranks (no rank empty)."""
    best = np.inf
    for labels in itertools.product(range(n_ranks), repeat=len(rates)):
        if len(set(labels)) < n_ranks:
            continue
        worst = max(model.of([r for r, lab in zip(rates, labels) if lab == k]) for k in range(n_ranks))
        best = min(best, worst)
    return best


@pytest.mark.parametrize("seed", range(6))
def test_shard_by_cost_is_optimal_over_all_assignments(seed):
    """Against exhaustive search: no assignment of 7 runs to 2-3 ranks has a cheaper costliest shard."""
    rng = np.random.default_rng(seed)
    rates = np.exp(rng.normal(0.0, 1.5, size=7))
    model = ShardCost(overhead_tanks=float(rng.choice([0.0, 2.0, 50.0])))
    for n_ranks in (2, 3):
        shards = shard_by_cost(rates, n_ranks, model)
        assert sorted(i for s in shards for i in s) == list(range(7)) and all(shards)
        got = max(model.of(rates[list(s)]) for s in shards)
        assert got <= _brute_force_best(rates, n_ranks, model) * (1 + 1e-9)


def test_shard_by_cost_keeps_stiff_tanks_together_and_balances_cost_not_count():
    """10 stiff tanks (rate 50) among 1,014 (rate 1): the stiff ones share a small shard."""
    rates = np.ones(1024)
    stiff = np.arange(0, 1024, 100)[:10]
    rates[stiff] = 50.0
    model = ShardCost(overhead_tanks=500.0)
    shards = shard_by_cost(rates, 2, model)
    small = min(shards, key=len)
    assert set(stiff) <= set(small)
    assert len(small) == 10  # any non-stiff tank added there costs 50 x 1; the other shard is far cheaper
    costs = [model.of(rates[list(s)]) for s in shards]
    by_count = [model.of(rates[:512]), model.of(rates[512:])]  # half the runs each, stiff ones spread
    assert max(costs) < 0.6 * max(by_count)


def test_shard_by_cost_balances_the_restarts_of_a_large_fleet():
    """1,024 tanks, 128 stiff (rate 2.5, the rest 1), each changing its inputs once per 10 minutes
    (as the benchmark's jittered fleet): a batched ODE restarts at every change, so a shard's
    cost grows with its restarts times its size. Counting them, the shards come out near equal
    in size with the stiff tanks together, and the costliest costs less than half what the
    restart-blind cut (the stiff tanks alone) leaves on its other shard. Fails if the restarts
    are ignored (the blind cut) or counted per shard as one (no balance)."""
    rates = np.ones(1024)
    stiff = np.arange(0, 1024, 8)
    rates[stiff] = 2.5
    restarts = np.full(1024, 1.0 / 600.0)
    model = ShardCost()
    aware = shard_by_cost(rates, 2, model, restarts)
    blind = shard_by_cost(rates, 2, model)
    assert set(stiff) == set(min(blind, key=len))  # restart-blind: the stiff tanks alone
    worst = max(model.of(rates[list(s)], restarts[list(s)]) for s in aware)
    worst_blind = max(model.of(rates[list(s)], restarts[list(s)]) for s in blind)
    assert worst < 0.6 * worst_blind, (worst, worst_blind)
    assert 0.3 < min(len(s) for s in aware) / 1024 <= 0.5
    assert any(set(stiff) <= set(s) for s in aware)
    with pytest.raises(ValueError, match="restarts must be"):
        shard_by_cost(rates, 2, model, restarts[:-1])


def test_shard_by_cost_refuses_what_it_cannot_do():
    with pytest.raises(ValueError, match="at most 2 ranks"):
        shard_by_cost([1.0, 2.0], 3)
    with pytest.raises(ValueError, match="positive and finite"):
        shard_by_cost([1.0, float("nan")], 1)
    with pytest.raises(ValueError, match="at least one run"):
        shard_by_cost([], 1)
    assert shard_by_cost([3.0, 1.0, 2.0], 1) == ((0, 1, 2),)


def test_probe_costs_measure_a_light_wall_as_dearer():
    """A light wall (2e4 J/K instead of 2.44e6) makes the probe's first five minutes more than
    twice as dear to integrate (2.8 times measured)."""
    heavy = get_case("case1")
    light = heavy.replace(name="light", tank=dataclasses.replace(heavy.tank, wall_heat_capacity_J_per_K=2.0e4))
    rates = probe_costs([heavy, light], CONFIG, max_probes=2)
    assert rates[1] > 2 * rates[0] > 0


# ---------------------------------------------------------------------------------------------
# The reduction, in this process (a process group of one rank)
# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def runs():
    cases = [get_case(f"case{i}").until(DURATION_S) for i in (1, 2, 3, 4)]
    return solution_to_runs(cases, simulate(cases), noise="low", seed=0)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_group_sum_is_the_weighted_sum_with_its_gradient():
    """Two groups: the value and the gradient are sum_g share_g J_g and sum_g share_g dJ_g/dw
    (each group differentiated alone); one group passes through untouched."""
    torch.manual_seed(0)
    w = torch.randn(3, dtype=torch.float64, requires_grad=True)
    v = torch.randn(2, dtype=torch.float64, requires_grad=True)
    parts = [lambda: (w.exp() * v.sum()).sum(), lambda: (w**2).sum() * v.prod()]
    shares = [0.25, 0.75]
    J = group_sum(parts, shares, [w, v])
    J.backward()
    ref_w, ref_v = w.grad.clone(), v.grad.clone()
    w.grad = v.grad = None
    expected = sum(s * f() for s, f in zip(shares, parts))
    expected.backward()
    assert float(J.detach()) == pytest.approx(float(expected.detach()), rel=1e-15)
    assert torch.allclose(ref_w, w.grad, rtol=1e-14) and torch.allclose(ref_v, v.grad, rtol=1e-14)
    one = parts[0]()
    assert torch.equal(group_sum([lambda: one], [1.0], [w, v]), one)
    with pytest.raises(ValueError, match="batch_fraction"):
        GroupedAssimilator([get_case("case1").until(60.0)] * 2, dataclasses.replace(CONFIG, batch_fraction=0.5),
                           [[0], [1]])


def test_one_rank_data_parallel_update_equals_the_single_process_update(runs):
    """The all-reduced value and gradient (``_Reduced``) reproduce the single-process update exactly."""
    import torch.distributed as dist

    short = [r.until(60.0) for r in runs[:2]]
    config = dataclasses.replace(CONFIG, window_s=60.0)
    single = Assimilator(short, config)
    report, _, _ = single.update(0, single.s0)
    dist.init_process_group("gloo", init_method=f"tcp://127.0.0.1:{_free_port()}", rank=0, world_size=1)
    try:
        parallel = DataParallel([(0, 1)], [r.name for r in short], max(r.t_end_s for r in short))
        dp = Assimilator(short, config, parallel=parallel)
        dp_report, _, _ = dp.update(0, dp.s0)
    finally:
        dist.destroy_process_group()
    assert _rel(_closure_weights(dp.closure), _closure_weights(single.closure)) <= 1e-12
    assert dp_report.cost_after == pytest.approx(report.cost_after, rel=1e-12)
    assert dp_report.n_evals == report.n_evals
    assert parallel.timings.n_evals == report.n_evals


def test_data_parallel_refuses_what_it_does_not_support(runs):
    import torch.distributed as dist

    dist.init_process_group("gloo", init_method=f"tcp://127.0.0.1:{_free_port()}", rank=0, world_size=1)
    try:
        parallel = DataParallel([(0,)], [runs[0].name], runs[0].t_end_s)
        with pytest.raises(ValueError, match="does not support window_start='joint'"):
            Assimilator(runs[:1], dataclasses.replace(CONFIG, mode="fixed", window_start="joint"), parallel=parallel)
        with pytest.raises(ValueError, match="batch_fraction < 1"):
            Assimilator(runs[:1], dataclasses.replace(CONFIG, batch_fraction=0.5), parallel=parallel)
        with pytest.raises(ValueError, match="its shard is"):
            Assimilator(runs[1:2], CONFIG, parallel=parallel)
    finally:
        dist.destroy_process_group()
    assert isinstance(Assimilator(runs[:1], CONFIG).parallel, SingleProcess)


# ---------------------------------------------------------------------------------------------
# Two processes: the command line under torchrun, faults, resume
# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def run_files(runs, tmp_path_factory):
    folder = tmp_path_factory.mktemp("runs")
    return [str(write_run(r, folder)[0]) for r in runs]


def _rank_env(rank: int, port: int) -> dict:
    return {**os.environ, "RANK": str(rank), "LOCAL_RANK": str(rank), "WORLD_SIZE": "2", "LOCAL_WORLD_SIZE": "2",
            "MASTER_ADDR": "127.0.0.1", "MASTER_PORT": str(port), "OMP_NUM_THREADS": "1"}


def _start_ranks(run_files, out, *extra):
    port = _free_port()
    cmd = [sys.executable, "-m", "tankode.cli", "assimilate", *run_files, "--out", str(out), *CLI_OPTIONS, *extra]
    return [subprocess.Popen(cmd, env=_rank_env(r, port), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            for r in (0, 1)]


def test_torchrun_window_update_equals_the_single_process_update_of_its_shards(runs, tmp_path):
    """``torchrun --standalone --nproc-per-node 2 --no-python tankode assimilate``: one window, 2 ranks.

    The job's weights equal those one process computes on the same fleet integrated in the
    job's shards (``GroupedAssimilator``: relative difference <= 1e-12, measured 0); rank 0 alone
    wrote the outputs.
    """
    one = [r.until(WINDOW_S) for r in runs]
    files = [str(write_run(r, tmp_path / "runs")[0]) for r in one]
    out = tmp_path / "model"
    proc = subprocess.run([str(BIN / "torchrun"), "--standalone", "--nproc-per-node", "2", "--no-python",
                           str(BIN / "tankode"), "assimilate", *files, "--out", str(out), *CLI_OPTIONS],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "data-parallel: 2 ranks" in proc.stdout and proc.stdout.count("window 1/1 ") == 1
    meta = json.loads((out / "model.json").read_text())
    names = [r.name for r in one]
    shards = [[names.index(n) for n in shard] for shard in meta["info"]["data_parallel"]["shards"]]
    assert sorted(i for s in shards for i in s) == [0, 1, 2, 3]
    reference = GroupedAssimilator([read_run(f) for f in files], CONFIG, shards)
    report, _, _ = reference.update(0, reference.s0)
    # The reference integrates and differentiates each shard alone and sums them as the
    # all-reduce does (trainers.distributed.group_sum): the same arithmetic.
    # Measured: bit-identical weights (relative difference 0).
    assert _rel(_weights(out / "weights.pt"), _closure_weights(reference.closure)) <= 1e-12
    assert meta["info"]["final_cost"] == pytest.approx(report.cost_after, rel=1e-12)
    assert sorted(p.name for p in out.iterdir()) == ["checkpoint.pt", "model.json", "weights.pt"]


def _wait_for(path: Path, procs, timeout_s: float) -> None:
    end = time.monotonic() + timeout_s
    while not path.exists():
        if any(p.poll() is not None for p in procs):
            raise AssertionError("a rank ended early: " + " | ".join(p.stderr.read()[-2000:] for p in procs))
        if time.monotonic() > end:
            raise AssertionError(f"{path} did not appear within {timeout_s} s")
        time.sleep(0.05)


def _signal_rank_1_in_window_2(procs, out: Path, sig, timeout_s: float) -> tuple[float, list[str]]:
    """Send ``sig`` to rank 1 once window 1 is checkpointed and window 2 has begun; wait for rank 0
    to end (at most ``timeout_s``). Returns (seconds rank 0 took to end, its stderr lines)."""
    _wait_for(out / "checkpoint.pt", procs, 240)
    time.sleep(0.3)
    procs[1].send_signal(sig)
    sent = time.monotonic()
    procs[0].wait(timeout=timeout_s)
    return time.monotonic() - sent, procs[0].stderr.read().strip().splitlines()


def _finish(procs) -> None:
    for p in procs:
        p.wait(timeout=300)
        assert p.returncode == 0, p.stderr.read()[-2000:]


@pytest.mark.slow
def test_killing_a_rank_mid_update_ends_the_job_and_resume_matches_the_uninterrupted_job(run_files, tmp_path):
    """Rank 1 killed during window 2: rank 0 stops within 60 s with one line; --resume finishes the same weights."""
    expected = tmp_path / "uninterrupted"
    _finish(_start_ranks(run_files, expected))
    out = tmp_path / "model"
    procs = _start_ranks(run_files, out)
    waited, stderr = _signal_rank_1_in_window_2(procs, out, signal.SIGKILL, timeout_s=60)
    procs[1].wait()
    assert waited < 60
    assert procs[0].returncode == 2
    assert len(stderr) == 1 and stderr[0].startswith("tankode assimilate: error: rank 0 of 2:"), stderr
    assert "another rank stopped" in stderr[0] and "--resume" in stderr[0]
    assert not (out / "weights.pt").exists()

    _finish(_start_ranks(run_files, out, "--resume"))
    assert _rel(_weights(out / "weights.pt"), _weights(expected / "weights.pt")) <= 1e-10


@pytest.mark.slow
def test_a_hung_rank_ends_the_job_after_the_collective_timeout(run_files, tmp_path):
    """Rank 1 stopped (SIGSTOP) during window 2: rank 0 gives up after --collective-timeout with one line."""
    out = tmp_path / "model"
    procs = _start_ranks(run_files, out, "--collective-timeout", "15")
    try:
        waited, stderr = _signal_rank_1_in_window_2(procs, out, signal.SIGSTOP, timeout_s=90)
    finally:
        procs[1].send_signal(signal.SIGKILL)
        procs[1].wait()
    assert 10 < waited < 60
    assert procs[0].returncode == 2
    assert len(stderr) == 1 and "another rank stopped or stopped answering" in stderr[0], stderr


def test_a_rank_s_simulation_failure_is_a_rejected_point_on_every_rank(runs):
    """The failure flags: a SimulationError on one rank is a SimulationError on all (one-rank group here)."""
    import torch.distributed as dist

    from tankode.errors import SimulationError

    dist.init_process_group("gloo", init_method=f"tcp://127.0.0.1:{_free_port()}", rank=0, world_size=1)
    try:
        parallel = DataParallel([(0,)], ["a"], 1.0)
        w = torch.ones(3, dtype=torch.float64, requires_grad=True)

        def failing():
            raise SimulationError("solver gave up", t_s=5.0)

        with pytest.raises(SimulationError, match="trial point rejected: rank 0: SimulationError: solver gave up"):
            parallel.data_cost(failing, [w])
        with pytest.raises(RuntimeError, match="a loss evaluation failed on rank 0: KeyError"):
            parallel.data_cost(lambda: {}["x"], [w])
        J = parallel.data_cost(lambda: (w ** 2).sum() / 2, [w])
        J.backward()
    finally:
        dist.destroy_process_group()
    assert float(J.detach()) == pytest.approx(1.5) and torch.equal(w.grad, torch.ones(3, dtype=torch.float64))
