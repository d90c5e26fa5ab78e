"""Benchmarks that print measured figures: surrogate vs CoolProp, forward real-time factor."""

from __future__ import annotations

import time

import torch


def forward_benchmark(repeats: int = 3, fleet_copies: int = 50) -> dict:
    """Case 1 (one tank, reference closure): real-time factor; 8 tanks batched vs one tank; a fleet.

    The fleet is cases 1-5 (five operating schedules, one tank shape) repeated ``fleet_copies``
    times, against the five cases batched once: what a whole fleet costs over a few tanks on
    the CPU, the figure that says whether a fleet needs an accelerator.

    Each figure is the best of ``repeats`` runs after one warm-up (the first run pays for
    imports, the surrogate load and torch's lazy initialisation).
    """
    from .cases import CASES, case1
    from .fleet import Fleet
    from .simulation import simulate
    from .solver import AdaptiveRK

    run = case1()
    one = Fleet.from_runs([run])
    eight = Fleet.from_runs([run] * 8)
    simulate(one)

    def best(fleet):
        sols = [simulate(fleet) for _ in range(repeats)]
        return min(sols, key=lambda s: s.wall_time_s)

    s1 = best(one)
    s8 = best(eight)
    rk = min((simulate(one, solver=AdaptiveRK()) for _ in range(repeats)), key=lambda s: s.wall_time_s)
    five_runs = [make() for make in CASES.values()]
    five = best(Fleet.from_runs(five_runs))
    fleet_runs = five_runs * fleet_copies
    fleet = best(Fleet.from_runs(fleet_runs))
    return {
        "case1_simulated_s": float(s1.t_s[-1] - s1.t_s[0]),
        "case1_wall_s": s1.wall_time_s,
        "case1_real_time_factor": s1.real_time_factor,
        "case1_rhs_evals": s1.stats.n_rhs_evals,
        "batch8_wall_s": s8.wall_time_s,
        "batch8_over_one_tank": s8.wall_time_s / s1.wall_time_s,
        "case1_dopri5_real_time_factor": rk.real_time_factor,
        "case1_dopri5_rhs_evals": rk.stats.n_rhs_evals,
        "cases5_wall_s": five.wall_time_s,
        "fleet_tanks": len(fleet_runs),
        "fleet_copies": fleet_copies,
        "fleet_wall_s": fleet.wall_time_s,
        "fleet_over_cases5": fleet.wall_time_s / five.wall_time_s,
        # each run's own span: a fleet integrates to its longest run, which counts once per tank
        "fleet_tank_hours_per_s": sum(r.t_end_s - r.t0_s for r in fleet_runs) / 3600 / fleet.wall_time_s,
        "torch_threads": torch.get_num_threads(),
    }


def run_benchmarks(n_points: int = 10_000, repeats: int = 3) -> dict:
    """All benchmarks of this module; a JSON-serialisable dict of measured figures."""
    from .properties import benchmark_surrogate, load_surrogate

    start = time.perf_counter()
    surrogate = load_surrogate("ParaHydrogen")
    load_s = time.perf_counter() - start
    result = {"surrogate_load_s": load_s, "surrogate": benchmark_surrogate(surrogate, n_points=n_points)}
    result["forward"] = forward_benchmark(repeats)
    return result


def verdict(value: float, target: float, at_least: bool = True) -> str:
    """``"target >= 20: met"`` or ``"target >= 20: MISSED"`` (``at_least=False``: an upper bound)."""
    met = value >= target if at_least else value <= target
    return f"target {'>=' if at_least else '<='} {target:g}: {'met' if met else 'MISSED'}"


# The accuracy target of every surrogate output that the ODE uses (relative error).
SURROGATE_TARGET_REL = 1e-3
_TARGETED = ("p", "T", "T_sat", "h_lsat", "h_vsat")


def summary_lines(result: dict) -> list[str]:
    """Human-readable lines of a ``run_benchmarks`` result (the JSON line follows them), each target met or MISSED."""
    sur = result["surrogate"]
    names = ("p", "T", "T_sat", "h_lsat", "h_vsat", "k", "mu", "cp", "beta")
    worst = max(d["max_rel_err"][n] for d in sur["phases"].values() for n in _TARGETED)
    lines = [f"surrogate vs CoolProp on {sur['n_points_per_phase']} held-out points per phase "
             f"(max relative error; h_sat relative to the latent heat; k, mu, cp, beta reported; "
             f"{verdict(worst, SURROGATE_TARGET_REL, at_least=False)} with {worst:.1e}):"]
    lines.append("  phase   " + " ".join(f"{n:>8s}" for n in names))
    for phase, d in sur["phases"].items():
        lines.append(f"  {phase:7s} " + " ".join(f"{d['max_rel_err'][n]:8.1e}" for n in names))
    t = sur["timing"]
    lines.append(f"  batched surrogate {t['surrogate_batched_s'] * 1e3:.2f} ms vs CoolProp loop "
                 f"{t['coolprop_loop_s'] * 1e3:.1f} ms (best of repeats): {t['speed_ratio']:.0f}x faster "
                 f"({verdict(t['speed_ratio'], 20)})")
    f = result["forward"]
    lines.append(f"forward case 1 (1 tank, reference closure, LSODA): {f['case1_simulated_s']:.0f} s simulated in "
                 f"{f['case1_wall_s']:.3f} s, real-time factor {f['case1_real_time_factor']:.0f} "
                 f"({verdict(f['case1_real_time_factor'], 1000)})")
    lines.append(f"  dopri5 (the training solver): real-time factor {f['case1_dopri5_real_time_factor']:.0f}")
    lines.append(f"  8 tanks batched: {f['batch8_wall_s']:.3f} s = {f['batch8_over_one_tank']:.2f}x one tank "
                 f"({verdict(f['batch8_over_one_tank'], 2, at_least=False)})")
    lines.append(f"  fleet of {f['fleet_tanks']} tanks (cases 1-5 x {f['fleet_copies']}): {f['fleet_wall_s']:.2f} s = "
                 f"{f['fleet_over_cases5']:.2f}x the 5 cases batched ({f['cases5_wall_s']:.2f} s), "
                 f"{f['fleet_tank_hours_per_s']:.0f} tank-hours per second")
    return lines


__all__ = ["run_benchmarks", "forward_benchmark", "summary_lines", "verdict"]
