"""Benchmarks of training: window-update speed and the adjoint's memory."""

from __future__ import annotations

import time

import torch

from tankode.cases import get_case
from tankode.schedule import Schedule
from tankode.simulation import simulate
from tankode.solver import Adjoint, Backprop, Checkpointed, NoGradient
from tankode.synthetic import solution_to_runs

from .assimilate import AssimilationConfig, Assimilator, uniform_wall
from .cost import Window, cost


def _data(names, noise="high", seed=0):
    runs = [get_case(n) for n in names]
    return solution_to_runs(runs, simulate(runs), noise=noise, seed=seed)


def window_update_benchmark(n_tanks: int = 4, iters: int = 20, window_s: float = 600.0) -> dict:
    """Wall time of one window update in each window mode: ``n_tanks`` environments, ``iters`` iterations.

    The tanks are cases 1..n (high noise); the timed update is the second window ([600, 1200] s
    of case 1: sloshing starts, the hardest to fit), after an untimed first one (which gives the
    replay mode its history and the carried state), for each of the default configuration's
    modes ("fixed", "growing", "replay") and for the paper's setup (fixed windows, dopri5 with the
    adjoint, a lumped wall, the agent from constant coefficients) in the same run, as the baseline.
    Real-time factor = window length / update time (target >= 10).
    """
    data = _data([f"case{i + 1}" for i in range(n_tanks)])
    configs = {"paper (fixed, dopri5 + adjoint)": AssimilationConfig.paper(window_s=window_s, iters=iters)}
    configs.update({mode: AssimilationConfig(window_s=window_s, iters=iters, mode=mode)
                    for mode in ("fixed", "growing", "replay")})
    out = {"n_tanks": n_tanks, "window_s": window_s, "modes": {}}
    for label, config in configs.items():
        # Uniform: what the first window chooses on case 1; the benchmark times updates, not that choice.
        a = Assimilator(data, config, mechanisms=uniform_wall(config))
        _, s_next, _ = a.update(0, a.s0)
        report, _, _ = a.update(1, s_next)
        out["modes"][label] = {
            "iters": report.n_iters, "function_evals": report.n_evals, "update_wall_s": report.wall_s,
            "real_time_factor": window_s / report.wall_s, "cost_before": report.cost_before,
            "cost_after": report.cost_after,
        }
    return out


def _saved_bytes(fn) -> int:
    """Bytes of tensors autograd saves for backward while ``fn`` runs (the graph's memory)."""
    total = 0

    def pack(t):
        nonlocal total
        total += t.numel() * t.element_size()
        return t

    with torch.autograd.graph.saved_tensors_hooks(pack, lambda t: t):
        fn()
    return total


def adjoint_memory_benchmark(lengths_s=(300.0, 600.0, 1200.0, 2400.0)) -> dict:
    """Autograd memory of the cost's graph vs horizon length, adjoint against backprop.

    Case 1's tank under constant sloshing (one input segment, so only the solver steps grow
    with the horizon) and six outputs at every length. With ``Adjoint`` only the outputs are
    kept (the backward pass re-integrates): the saved bytes do not grow with the number of
    solver steps; with ``Backprop`` they grow linearly with it; with ``Checkpointed`` only the
    outputs are kept until the backward pass recomputes one interval at a time.
    """
    run = get_case("case1")
    run = run.replace(inputs=Schedule.from_steps([(0, {"slosh_amplitude_m": 0.01, "slosh_frequency_Hz": 0.57})]))
    out = {"lengths_s": list(lengths_s), "adjoint_bytes": [], "backprop_bytes": [], "checkpointed_bytes": [],
           "rhs_evals_forward": []}
    for L in lengths_s:
        t_eval = torch.linspace(0.0, L, 7, dtype=torch.float64)
        window = Window(0.0, L, t_eval[1:], torch.zeros(1, 6, 5, dtype=torch.float64),
                        torch.full((1, 6, 5), 1 / 6, dtype=torch.float64), torch.ones(1, 5, dtype=torch.float64))
        for gradient, key in ((Adjoint(), "adjoint_bytes"), (Backprop(), "backprop_bytes"),
                              (Checkpointed(), "checkpointed_bytes")):
            a = Assimilator([run], AssimilationConfig.paper(gradient=gradient))
            out[key].append(_saved_bytes(
                lambda: cost(a.model.observe(a.predict(a.s0, 0.0, t_eval, gradient)[:, 1:]), window)))
        calls = []
        orig = a.model.forward
        a.model.forward = lambda t, s, f: (calls.append(1), orig(t, s, f))[1]
        with torch.no_grad():
            a.predict(a.s0, 0.0, t_eval, NoGradient())
        out["rhs_evals_forward"].append(len(calls))
    return out


def run_training_benchmarks() -> dict:
    start = time.perf_counter()
    result = {"window_update": window_update_benchmark(), "adjoint_memory": adjoint_memory_benchmark()}
    result["wall_s"] = time.perf_counter() - start
    return result


__all__ = ["window_update_benchmark", "adjoint_memory_benchmark", "run_training_benchmarks"]
