"""Turn a simulation into runs in the interchange format (synthetic measurements)."""

from __future__ import annotations

import numpy as np

from .noise import add_noise, nominal_R_std
from .run import Observations, Run
from .simulate import Solution

OBS_COLUMNS = ("p_v_Pa", "T_v_K", "T_l_K", "T_w_K", "H_l_m")


def solution_to_runs(runs, solution: Solution, noise: str = "clean", seed: int = 0, channels=OBS_COLUMNS,
                     model_name: str = "the reference closure") -> list[Run]:
    """One run per environment whose observations are the simulated h(s) plus noise.

    Args:
        runs: the simulated runs, in the order of the solution's environments.
        solution: their ``Solution``.
        noise: "clean", "low" or "high" (``tankode.noise``); the run's ``noise_std`` is the
            level's (the low level's for clean data, as a nominal R).
        seed: noise seed; environment ``e`` uses ``seed + e`` so tanks get independent noise.
        channels: the observation columns to keep (others are left unmeasured).
        model_name: what simulated it, for the run's ``source`` field.

    Each environment keeps the output times inside its own run's duration.
    """
    runs = [runs] if isinstance(runs, Run) else list(runs)
    t = solution.t_s.numpy()
    out = []
    keep = np.array([c in channels for c in OBS_COLUMNS])
    for e, run in enumerate(runs):
        inside = t <= run.t_end_s + 1e-9
        values = solution.observations[e].numpy()[inside].copy()
        values[:, ~keep] = np.nan
        obs = add_noise(Observations(t[inside].copy(), values), noise, seed + e)
        std = nominal_R_std(noise)
        note = (f"tankode simulation of run {run.name!r} from its initial state and inputs with {model_name}; "
                f"noise: {noise} (seed {seed + e})")
        out.append(run.replace(
            observations=obs,
            noise_std={k: v for (k, v), c in zip(std.items(), OBS_COLUMNS) if c in channels},
            source=note, duration_s=float(t[inside][-1]), path=None,
        ))
    return out


__all__ = ["solution_to_runs", "OBS_COLUMNS"]
