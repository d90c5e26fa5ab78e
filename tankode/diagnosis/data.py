"""Measured runs laid out for the diagnosis: one time grid, noise, operating phases, splits."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..fleet import Fleet
from ..run import NOISE_KEYS, OBS_CHANNELS
from ..schedule import INPUT_NAMES

CHANNELS = OBS_CHANNELS
_I = {n: i for i, n in enumerate(INPUT_NAMES)}

# Operating phases, in the order that decides a sample with several operations at once: a
# flow through the tank dominates its thermodynamics more than sloshing, sloshing more than
# a heat load on the wall.
PHASES = ("fill/drain", "venting", "pressurisation", "sloshing", "heat ingress", "hold")


def phase_of(inputs: np.ndarray) -> str:
    """The operating phase of one row of schedule values (``tankode.schedule.INPUT_NAMES`` order)."""
    if inputs[_I["mdot_l_in_kg_s"]] > 0 or inputs[_I["mdot_l_out_kg_s"]] > 0:
        return "fill/drain"
    if inputs[_I["mdot_v_out_kg_s"]] > 0:
        return "venting"
    if inputs[_I["mdot_v_in_kg_s"]] > 0:
        return "pressurisation"
    if inputs[_I["slosh_amplitude_m"]] > 0 and inputs[_I["slosh_frequency_Hz"]] > 0:
        return "sloshing"
    if inputs[_I["Q_aw_W"]] > 0:
        return "heat ingress"
    return "hold"


@dataclass(frozen=True)
class Observed:
    """The fleet's observations on the union of their sample times.

    Attributes:
        t_s: ``(T,)`` sorted union of all observation times (s), after each run's start.
        y: ``(env, T, 5)`` observations, NaN where a channel was not sampled.
        sigma: ``(env, 5)`` noise std per channel (NaN for unmeasured channels).
        phase: ``(env, T)`` operating phase label of each time (``PHASES``).
        run_names: the runs' names.
    """

    t_s: np.ndarray
    y: np.ndarray
    sigma: np.ndarray
    phase: np.ndarray
    run_names: tuple[str, ...]

    @staticmethod
    def from_fleet(fleet: Fleet) -> "Observed":
        t0 = fleet.t0_s
        t = np.unique(np.concatenate([r.observations.t_s for r in fleet.runs]))
        t = t[t > t0]
        if len(t) == 0:
            raise ValueError("diagnosis needs observations after the runs' initial time; the runs have none")
        y = np.full((fleet.n_env, len(t), 5), np.nan)
        sigma = np.full((fleet.n_env, 5), np.nan)
        phase = np.empty((fleet.n_env, len(t)), dtype=object)
        for e, run in enumerate(fleet.runs):
            obs = run.observations
            sel = obs.t_s > t0
            y[e, np.searchsorted(t, obs.t_s[sel])] = obs.values[sel]
            for c, key in enumerate(NOISE_KEYS):
                if np.isfinite(y[e, :, c]).any():
                    if key not in run.noise_std or not run.noise_std[key] > 0:
                        raise ValueError(f"run {run.name!r} measures {CHANNELS[c]} but gives no positive "
                                         f"noise_std[{key!r}]; the diagnosis weighs residuals by it")
                    sigma[e, c] = run.noise_std[key]
        inputs = np.stack([fleet.inputs_at(float(tk)) for tk in t], axis=1)  # (env, T, n_inputs)
        for e in range(fleet.n_env):
            phase[e] = [phase_of(u) for u in inputs[e]]
        return Observed(t, y, sigma, phase, tuple(r.name for r in fleet.runs))

    @property
    def measured(self) -> np.ndarray:
        """``(env, T, 5)`` bool: where an observation exists."""
        return np.isfinite(self.y)


@dataclass(frozen=True)
class HoldOutTail:
    """Hold out the last ``fraction`` of each run's measured span; calibrate on the rest.

    The span runs from the run's start to its last measured sample: a run whose declared
    duration reaches past its data (inputs scheduled beyond the last reading) holds out the tail
    of what was measured, not an empty stretch.

    Attributes:
        fraction: held-out share of each run, in (0, 0.8]; 0.3 keeps 70 % for calibration
            and leaves enough held-out samples (~100 at 10 s per hour) for a bootstrap.
    """

    fraction: float = 0.3

    def __post_init__(self):
        if not 0 < self.fraction <= 0.8:
            raise ValueError(f"HoldOutTail.fraction must be in (0, 0.8], got {self.fraction}")

    def folds(self, fleet: Fleet, obs: Observed) -> list[tuple[np.ndarray, np.ndarray]]:
        """One ``(train, heldout)`` pair of ``(env, T)`` boolean masks."""
        measured = obs.measured.any(-1)  # (env, T)
        last = [float(obs.t_s[m].max()) if m.any() else r.t_end_s for r, m in zip(fleet.runs, measured)]
        t_split = np.array([r.t0_s + (1 - self.fraction) * (t1 - r.t0_s) for r, t1 in zip(fleet.runs, last)])
        train = obs.t_s[None, :] <= t_split[:, None]
        return [(train, ~train)]

    def describe(self) -> str:
        return f"last {self.fraction:.0%} of each run held out"


@dataclass(frozen=True)
class LeaveOneRunOut:
    """Each run in turn is held out and the others calibrate; needs at least two runs."""

    def folds(self, fleet: Fleet, obs: Observed) -> list[tuple[np.ndarray, np.ndarray]]:
        if fleet.n_env < 2:
            raise ValueError("LeaveOneRunOut needs at least two runs; use HoldOutTail for one run")
        out = []
        for e in range(fleet.n_env):
            held = np.zeros((fleet.n_env, len(obs.t_s)), bool)
            held[e] = True
            out.append((~held, held))
        return out

    def describe(self) -> str:
        return "leave one run out"


__all__ = ["Observed", "HoldOutTail", "LeaveOneRunOut", "PHASES", "CHANNELS", "phase_of"]
