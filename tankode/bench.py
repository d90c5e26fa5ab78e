"""Benchmarks that print measured figures: surrogate vs CoolProp, forward real-time factor."""

from __future__ import annotations

import time

import torch


def forward_benchmark(repeats: int = 3) -> dict:
    """Case 1 (one tank, reference closure): real-time factor; 8 tanks batched vs one tank.

    Each figure is the best of ``repeats`` runs after one warm-up (the first run pays for
    imports, the surrogate load and torch's lazy initialisation).
    """
    from .cases import case1
    from .fleet import Fleet
    from .simulate import simulate

    run = case1()
    one = Fleet.from_runs([run])
    eight = Fleet.from_runs([run] * 8)
    simulate(one)

    def best(fleet):
        sols = [simulate(fleet) for _ in range(repeats)]
        return min(sols, key=lambda s: s.wall_time_s)

    s1 = best(one)
    s8 = best(eight)
    return {
        "case1_simulated_s": float(s1.t_s[-1] - s1.t_s[0]),
        "case1_wall_s": s1.wall_time_s,
        "case1_real_time_factor": s1.real_time_factor,
        "case1_rhs_evals": s1.stats.n_rhs_evals,
        "batch8_wall_s": s8.wall_time_s,
        "batch8_over_one_tank": s8.wall_time_s / s1.wall_time_s,
        "torch_threads": torch.get_num_threads(),
    }


def run_benchmarks(n_points: int = 10_000, repeats: int = 3) -> dict:
    """All benchmarks of the tank-model issue; a JSON-serialisable dict of measured figures."""
    from .properties import benchmark_surrogate, load_surrogate

    start = time.perf_counter()
    surrogate = load_surrogate("ParaHydrogen")
    load_s = time.perf_counter() - start
    result = {"surrogate_load_s": load_s, "surrogate": benchmark_surrogate(surrogate, n_points=n_points)}
    result["forward"] = forward_benchmark(repeats)
    return result


__all__ = ["run_benchmarks", "forward_benchmark"]
