"""A fleet integrated in groups: each group a batched ODE with its own step sequence.

One batched ODE shares one step sequence across its tanks, so its stiffest tank sets the steps
of all. ``GroupedAssimilator`` trains one closure on a fleet exactly as ``Assimilator`` does, but
integrates each group of runs separately (the same solver, tolerances and closure; each group
restarts at its own runs' input changes only). Each group's data cost is also its own graph,
differentiated alone and summed as a data-parallel job sums its ranks
(``trainers.distributed.group_sum``): it is the single-process form of the objective a
data-parallel job (``trainers/distributed.py``) optimises with one group per rank, to the bit,
and the way to keep stiff tanks (light walls) from holding the others to small steps in one
process. Mini-batches (``batch_fraction < 1``) need one group.
"""

from __future__ import annotations

import torch
from torch import Tensor

from tankode.fleet import Fleet
from tankode.integrate import integrate, state_scale
from tankode.model import TankModel

from .assimilate import Assimilator
from .cost import Window


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
        if len(self.groups) > 1 and config.batch_fraction < 1.0:
            raise ValueError("GroupedAssimilator with several groups does not support batch_fraction < 1 (a "
                             "mini-batch mask is over one window's samples; each group has its own)")
        self.rhs_evals = [0] * len(self.groups)
        # Each group's initial state and scales from its own runs, as its rank computes them (a
        # batched function of 4 tanks and of 2 can differ in the last bit: vectorised lanes).
        s0 = self._group_start_states()
        self.s0 = torch.cat(s0, dim=0)[self._order]
        self.scale = torch.cat([state_scale(s, f.geometry.volume_m3, self.model.extra_state_scales)
                                for s, f in zip(s0, self._fleets)], dim=0)[self._order]

    @property
    def _order(self) -> Tensor:
        """The fleet's environment order from the groups' concatenation."""
        return torch.argsort(torch.tensor([i for g in self.groups for i in g]))

    def _group_start_states(self) -> list[Tensor]:
        return [self._submodel(self.model, g).initial_state(f.initial_state(self.model.mechanisms))
                for g, f in enumerate(self._fleets)]

    def start_state(self) -> Tensor:
        return torch.cat(self._group_start_states(), dim=0)[self._order]

    def _submodel(self, model: TankModel, g: int) -> TankModel:
        return model.on(self._fleets[g])

    @property
    def cost_groups(self) -> list[list[int]]:
        """The groups: each group's data cost is its own graph (``trainers.distributed.group_sum``)."""
        return self.groups

    def _group_predict(self, g: int, s_start: Tensor, t_start: float, t_eval: Tensor, gradient,
                       model: TankModel | None = None) -> Tensor:
        self.trained.apply()
        fleet, idx = self._fleets[g], self.groups[g]
        states, stats = integrate(self._submodel(self.model if model is None else model, g), s_start[idx],
                                  fleet.segments(t_start, float(t_eval[-1])), fleet.forcing, t_eval, self.scale[idx],
                                  self.solver, gradient)
        self.rhs_evals[g] += stats.n_rhs_evals
        return states

    def _group_model(self, g: int) -> tuple[TankModel, Fleet]:
        return self._submodel(self.model, g), self._fleets[g]

    def _group_windows(self, window: Window) -> list[Window]:
        return [Window.from_runs(f.runs, window.t0_s, window.t1_s) for f in self._fleets]

    def predict(self, s_start: Tensor, t_start: float, t_eval: Tensor, gradient, model: TankModel | None = None) -> Tensor:
        """States ``(env, T, n)`` at ``t_eval`` from ``s_start`` at ``t_start``, each group integrated alone."""
        parts = [self._group_predict(g, s_start, t_start, t_eval, gradient, model) for g in range(len(self.groups))]
        order = torch.tensor([i for idx in self.groups for i in idx])
        return torch.cat(parts, dim=0)[torch.argsort(order)]


__all__ = ["GroupedAssimilator"]
