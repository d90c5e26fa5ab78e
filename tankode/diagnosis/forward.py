"""The calibration problem: predictions as a function of a few bounded physical parameters."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import torch

from ..threads import single_threaded
from ..closures import ReferenceClosure, ScaledClosure
from ..fleet import Fleet
from ..geometry import stack_geometries
from ..mechanisms import MECHANISMS, Mechanism, make_mechanism
from ..simulation import simulate
from ..solver import LSODA
from .data import Observed

THETA = ("h_vi", "h_li", "h_wv", "h_wl")

# A closure multiplier may move a coefficient by a factor of 10 either way: enough to absorb a
# wrong correlation constant, too little to mimic a mechanism by an unphysical coefficient.
LOG_FACTOR_BOUND = math.log(10.0)
# Normalised unit of a log-multiplier (the fit variable is ln(f) / 0.1): a 10 % change.
LOG_FACTOR_SCALE = 0.1
# The stable-mixing share (``ScaledClosure``) runs over [0, 1]; its fit unit is a tenth of that.
MIXING_SCALE = 0.1


@dataclass(frozen=True)
class FreeParam:
    """One fitted parameter: of the closure (``owner="closure"``) or of a mechanism.

    The fit works on ``z = value / scale`` within ``[lower, upper] / scale``; for closure
    multipliers ``value`` is ln(factor), for the closure's ``stable_mixing`` the share itself.
    """

    owner: str
    name: str
    unit: str
    lower: float
    upper: float
    scale: float

    @property
    def label(self) -> str:
        return f"{self.owner}.{self.name}"


def closure_params(stable_mixing: bool = False, hold: tuple[str, ...] = ()) -> list[FreeParam]:
    """The baseline's degrees of freedom: four log-multipliers of the coefficients (and the stable-mixing share).

    The share (``ScaledClosure``, with ``stable_mixing=True``) is a shape freedom: how much heat
    a liquid colder than the interface takes up, from conduction (0, the reference) to the
    symmetric natural convection law (1). On another simulator's runs with pressurisation or a
    cold fill, its absence leaves the calibrated baseline 20-40 sigma off (experiments/README.md).

    Args:
        stable_mixing: add the share.
        hold: coefficients of ``THETA`` whose multiplier stays 1 (a degenerate box at ln 1 = 0):
            the closure's own correlation is trusted for them.
    """
    unknown = set(hold) - set(THETA)
    if unknown:
        raise ValueError(f"hold: unknown coefficient(s) {sorted(unknown)}; allowed: {', '.join(THETA)}")
    bound = {n: (0.0, 0.0) if n in hold else (-LOG_FACTOR_BOUND, LOG_FACTOR_BOUND) for n in THETA}
    multipliers = [FreeParam("closure", f"ln_{n}_factor", "1", *bound[n], LOG_FACTOR_SCALE) for n in THETA]
    return multipliers + ([FreeParam("closure", "stable_mixing", "1", 0.0, 1.0, MIXING_SCALE)] if stable_mixing else [])


def mechanism_params(mechanism_id: str) -> list[FreeParam]:
    """The parameters of one candidate mechanism."""
    cls = MECHANISMS[mechanism_id]
    return [FreeParam(mechanism_id, p.name, p.unit, p.lower, p.upper, p.scale) for p in cls.params]


class Problem:
    """Predicted observations of a fleet for values of closure multipliers and mechanism parameters.

    Args:
        fleet: the runs (``Fleet``), built once.
        base_closure: the closure whose output the four multipliers scale (the reference
            correlations by default, or a saved model's closure).
        fixed_mechanisms: mechanisms already in the model (from a saved model), kept as they are.
        solver: the forward solver; LSODA with tight tolerances so that finite differences of
            the predictions are accurate (its error, ~1e-8 relative, is far below the noise).
    """

    def __init__(self, fleet: Fleet, base_closure=None, fixed_mechanisms: tuple[Mechanism, ...] = (),
                 solver: LSODA = LSODA(rtol=1e-8, atol=1e-10)):
        self.fleet = fleet
        self.base = ReferenceClosure() if base_closure is None else base_closure
        self.fixed = tuple(fixed_mechanisms)
        self.solver = solver
        self.obs = Observed.from_fleet(fleet)
        self.sensor_obs = self.obs  # ``obs`` with the runs' noise_std, whatever ``weigh`` did
        self.t_eval = np.concatenate([[fleet.t0_s], self.obs.t_s])
        self.n_simulations = 0
        self._fleets = {1: fleet}

    def build(self, params: list[FreeParam], values: np.ndarray) -> tuple[ScaledClosure, tuple[Mechanism, ...]]:
        """The closure and the mechanisms for parameter ``values``.

        ``values`` in physical units is ``(n,)`` (one model for the fleet) or ``(B, n)``: B
        variants, each repeated for the fleet's environments (environment ``b * n_env + e``).
        """
        values = np.asarray(values, float)
        batch = values.ndim == 2
        V = np.atleast_2d(values)  # (B, n)
        rows = np.repeat(V, self.fleet.n_env, axis=0) if batch else V  # (B * env, n) or (1, n)
        log_f = np.zeros((len(rows), 4))
        mixing = np.zeros(len(rows))
        mech: dict[str, dict[str, np.ndarray]] = {}
        for j, p in enumerate(params):
            if p.owner == "closure" and p.name == "stable_mixing":
                mixing = rows[:, j]
            elif p.owner == "closure":
                log_f[:, THETA.index(p.name[3:-7])] = rows[:, j]
            else:
                mech.setdefault(p.owner, {})[p.name] = rows[:, j]
        factors = torch.as_tensor(np.exp(log_f if batch else log_f[0]))
        built = []
        for mid, vals in mech.items():
            m = make_mechanism(mid)
            cols = np.stack([vals.get(q.name, np.zeros(len(rows))) for q in m.params], axis=-1)  # (rows, n_params)
            m.set_values(cols if batch else cols[0])
            built.append(m)
        return ScaledClosure(self.base, factors, mixing if batch else mixing[0]), self.fixed + tuple(built)

    def _fleet(self, copies: int) -> Fleet:
        if copies not in self._fleets:
            self._fleets[copies] = Fleet(self.fleet.runs * copies,
                                         stack_geometries(list(self.fleet.geometry.unbind()) * copies),
                                         self.fleet.walls * copies, self.fleet.fluid, self.fleet.reference)
        return self._fleets[copies]

    def predict(self, params: list[FreeParam], values: np.ndarray) -> np.ndarray:
        """Predicted observations at ``self.obs.t_s``: ``(env, T, 5)``, or ``(B, env, T, 5)`` for ``(B, n)`` values.

        The B variants are integrated as one batched ODE (as cheap as one: the solver's work is
        set by the dynamics, not the batch), on one step sequence, so finite differences
        between them carry no solver noise from differing steps.

        Raises:
            SimulationError: the solver failed or the state left the property domain.
        """
        values = np.asarray(values, float)
        closure, mechanisms = self.build(params, values)
        fleet = self._fleet(len(values) if values.ndim == 2 else 1)
        with single_threaded():  # small tensors: extra threads only contend (20x slower on a busy machine)
            sol = simulate(fleet, closure, t_eval=self.t_eval, solver=self.solver, mechanisms=mechanisms)
        self.n_simulations += 1
        out = sol.observations[:, 1:].numpy()  # (B * env, T, 5)
        if values.ndim == 2:
            return out.reshape(len(values), self.fleet.n_env, *out.shape[1:])
        return out

    def weigh(self, sigma: np.ndarray) -> None:
        """Weigh residuals by ``sigma`` ``(env, 5)`` from now on (``tankode.diagnosis.weighting``)."""
        sigma = np.asarray(sigma, float)
        if sigma.shape != self.sensor_obs.sigma.shape or not np.all((sigma > 0) | np.isnan(self.sensor_obs.sigma)):
            raise ValueError(f"sigma must be positive, of shape {self.sensor_obs.sigma.shape}; got {sigma}")
        self.obs = dataclasses.replace(self.sensor_obs, sigma=np.where(np.isnan(self.sensor_obs.sigma), np.nan, sigma))

    def normalised_residuals(self, pred: np.ndarray) -> np.ndarray:
        """``(pred - y) / sigma``, ``(..., env, T, 5)``, NaN where nothing was measured."""
        return (pred - self.obs.y) / self.obs.sigma[:, None, :]


__all__ = ["Problem", "FreeParam", "closure_params", "mechanism_params", "THETA"]
