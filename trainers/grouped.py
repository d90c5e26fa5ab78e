"""A fleet integrated in groups: each group a batched ODE with its own step sequence.

One batched ODE shares one step sequence across its tanks, so its stiffest tank sets the steps
of all. ``GroupedAssimilator`` trains one closure on a fleet exactly as ``Assimilator`` does, but
integrates each group of runs separately (the same solver, tolerances and closure; each group
restarts at its own runs' input changes only). It is the single-process form of the objective a
data-parallel job (``trainers/distributed.py``) optimises with one group per rank, and the way
to keep stiff tanks (light walls) from holding the others to small steps in one process.
"""

from __future__ import annotations

import torch
from torch import Tensor

from tankode.fleet import Fleet
from tankode.integrate import integrate
from tankode.model import TankModel

from .assimilate import Assimilator


class GroupedAssimilator(Assimilator):
    """``Assimilator`` whose predictions integrate each group of runs as its own batched ODE.

    Args:
        runs, config, closure, surrogate, mechanisms, parallel: as ``Assimilator``.
        groups: run indices per group (e.g. ``trainers.distributed.shard_by_cost``), every index
            of ``range(len(runs))`` exactly once, no group empty. The mechanisms must act alike on
            every environment (their parameters are shared by the groups).

    Attributes:
        rhs_evals: right-hand-side evaluations per group since construction (work per group).
    """

    def __init__(self, runs, config, groups, closure=None, surrogate=None, mechanisms=(), parallel=None):
        super().__init__(runs, config, closure=closure, surrogate=surrogate, mechanisms=mechanisms, parallel=parallel)
        self.groups = [list(int(i) for i in g) for g in groups]
        flat = sorted(i for g in self.groups for i in g)
        if flat != list(range(self.fleet.n_env)) or any(len(g) == 0 for g in self.groups):
            raise ValueError(f"groups must hold every run index 0..{self.fleet.n_env - 1} exactly once, none empty")
        self._fleets = [Fleet.from_runs([self.fleet.runs[i] for i in g], self.fleet.fluid) for g in self.groups]
        self.rhs_evals = [0] * len(self.groups)

    def _submodel(self, model: TankModel, g: int) -> TankModel:
        fleet = self._fleets[g]
        return TankModel(fleet.fluid, fleet.geometry, model.closure, fleet.wall_heat_capacity_J_per_K,
                         model.mechanisms, bulk=model.bulk)

    def predict(self, s_start: Tensor, t_start: float, t_eval: Tensor, gradient, model: TankModel | None = None) -> Tensor:
        """States ``(env, T, n)`` at ``t_eval`` from ``s_start`` at ``t_start``, each group integrated alone."""
        self.trained.apply()
        model = self.model if model is None else model
        parts = []
        for g, (idx, fleet) in enumerate(zip(self.groups, self._fleets)):
            states, stats = integrate(self._submodel(model, g), s_start[idx], fleet.segments(t_start, float(t_eval[-1])),
                                      fleet.forcing, t_eval, self.scale[idx], self.solver, gradient)
            self.rhs_evals[g] += stats.n_rhs_evals
            parts.append(states)
        order = torch.tensor([i for idx in self.groups for i in idx])
        return torch.cat(parts, dim=0)[torch.argsort(order)]


__all__ = ["GroupedAssimilator"]
