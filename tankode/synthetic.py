"""Turn a simulation into runs in the interchange format (synthetic measurements)."""

from __future__ import annotations

import dataclasses

import numpy as np

from .files import TANKODE_SOURCE_PREFIX
from .noise import add_noise, noise_std, nominal_R_std
from .run import NOISE_KEYS, OBS_CHANNELS, Observations, Run
from .simulation import Solution

OBS_COLUMNS = OBS_CHANNELS  # the observation columns, in order (tankode.run)


def solution_to_runs(runs, solution: Solution, noise: str = "clean", seed: int = 0, channels=None,
                     model_name: str = "the reference closure") -> list[Run]:
    """One run per environment whose observations are the simulated h(s), plus noise.

    A simulated copy keeps what it copies: each run's time span (its ``duration_s``), its
    sensors (the channels it measures) and their ``noise_std``, and the wall heat capacity
    the simulation used (written where the run had none, so that simulating the copy again
    gives the same trajectory).

    Args:
        runs: the simulated runs, in the order of the solution's environments.
        solution: their ``Solution``.
        noise: "clean", "low", "high" (``tankode.noise`` levels) or "sensors" (each run's own
            ``noise_std``). The written ``noise_std`` is the standard deviation of the noise
            added; for clean data it is the run's own where it has one, else the low level's
            (a nominal R, which the cost needs to weigh the channels).
        seed: noise seed; environment ``e`` uses ``seed + e`` so tanks get independent noise.
        channels: the observation columns to keep; None (default): the channels the run
            measures, or all five for a run that measures none (a built-in case).
        model_name: what simulated it, for the run's ``source`` field.

    Raises:
        ValueError: an unknown noise level, or "sensors" for a run without ``noise_std``.
    """
    runs = [runs] if isinstance(runs, Run) else list(runs)
    t = solution.t_s.numpy()
    out = []
    for e, run in enumerate(runs):
        keep = tuple(channels) if channels is not None else (run.observations.measured_channels or OBS_CHANNELS)
        unknown = [c for c in keep if c not in OBS_CHANNELS]
        if unknown:
            raise ValueError(f"channels must be among {OBS_CHANNELS}, got {unknown}")
        keys = [NOISE_KEYS[OBS_CHANNELS.index(c)] for c in keep]
        if noise == "sensors":
            missing = [k for k in keys if k not in run.noise_std]
            if missing:
                raise ValueError(f"run {run.name!r}: noise 'sensors' needs the run's noise_std for {missing}")
            std = {k: run.noise_std[k] for k in keys}
        else:
            level = noise_std(noise)
            nominal = nominal_R_std(noise)
            std = {k: (run.noise_std.get(k, nominal[k]) if noise == "clean" else level[k]) for k in keys}
        inside = (t >= run.t0_s - 1e-9) & (t <= run.t_end_s + 1e-9)
        values = solution.observations[e].numpy()[inside].copy()
        values[:, [c not in keep for c in OBS_CHANNELS]] = np.nan
        obs = Observations(t[inside].copy(), values)
        if noise != "clean":
            obs = add_noise(obs, std, seed + e)
        tank = run.tank
        if tank.wall_heat_capacity_J_per_K is None and solution.wall_heat_capacity_J_per_K:
            tank = dataclasses.replace(tank, wall_heat_capacity_J_per_K=solution.wall_heat_capacity_J_per_K[e])
        note = (f"{TANKODE_SOURCE_PREFIX}simulation of run {run.name!r} from its initial state and inputs with "
                f"{model_name}; noise: {noise} (seed {seed + e})")
        out.append(run.replace(observations=obs, noise_std=std, source=note, tank=tank, path=None))
    return out


__all__ = ["solution_to_runs", "OBS_COLUMNS"]
