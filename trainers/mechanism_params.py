"""Mechanism parameters trained with the agent: a physical effect's size learned from the stream.

The diagnosis fits a mechanism's parameters with the four closure factors (``tankode.diagnosis``);
the assimilation kept them fixed while the agent trained. With
``AssimilationConfig(train_mechanisms=("dry_wall_node",))`` each window's L-BFGS update moves the
named mechanisms' parameters together with the weights, inside their physical bounds
(``Param.lower``, ``Param.upper``), so that, e.g., the shell's sheet resistance of the MHTB tank
or an unknown wall heat capacity (``wall_heat_capacity_error``) is estimated from the training
data rather than chosen beforehand.

The trained variable is ``xi = value / Param.scale`` (one per parameter but those marked
``Param.initial``, which set only the first state and have no slope in a carried window; shared by every
environment: one tank's physics), so that one step of the optimiser moves a parameter in units
of its typical size, as the weights move in units of 1. The mechanism reads ``xi * scale``; it
is re-applied before every forward pass because the optimiser updates ``xi`` in place. ``xi``
is registered as a parameter of its mechanism (``trained_xi``), so the model's parameters
include it and every gradient strategy (``Adjoint()`` too) differentiates it; the mechanism
keeps it after the training, with its values also in the usual buffer.

Which window mode. A constant of the tank is learned from all the data so far, so train it
with growing windows: in fixed windows it is refitted to each window alone, like the weights,
and it drifts with what the agent compensates there. On the MHTB tests with the dry wall node
(``experiments/mhtb_agent.py``, figures in ``experiments/README.md``), growing windows put the
shell at the same value from starts an order of magnitude apart, on either test; fixed windows
end where the start leaves them, or at the parameter's bound.

A mechanism that offsets a reading the first state is built from (``pressure_sensor_bias``,
``noncondensable_gas``, ``temperature_sensor_bias``) also moves that state: the update of a
window that starts at the run's start rebuilds it from the trained values on every evaluation
(``sets_start``), differentiably (``tankode.fleet.Fleet.initial_state``). A later fixed window
starts from the carried state, where such a mechanism acts only through what the sensors read.

Limits:

* Every parameter must start strictly inside its bounds, so a mechanism whose presence is
  bounded below by 0 (a heat leak) starts present, however little: the bounded optimiser's
  map has no slope on a bound. A parameter the cost has no slope in at its start does not move
  either (a surface layer's wall share at a vanishing thickness).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from tankode.mechanisms.base import Mechanism

from .lbfgs import Box

PREFIX = "mechanism."
XI_NAME = "trained_xi"  # the trained variable's name on its mechanism module


class TrainedMechanisms:
    """The trained parameters of some of a model's mechanisms.

    Args:
        mechanisms: the model's mechanisms (``TankModel.mechanisms``).
        ids: the ids of those whose parameters are trained (each must be among ``mechanisms``).

    Raises:
        ValueError: an id not among the model's mechanisms (naming those it has), a mechanism
            with per-environment values, or one that starts on a bound.
    """

    def __init__(self, mechanisms, ids):
        by_id = {m.id: m for m in mechanisms}
        unknown = [i for i in ids if i not in by_id]
        if unknown:
            raise ValueError(f"train_mechanisms {unknown}: not among the model's mechanisms {sorted(by_id)} "
                             "(add them to the model first, e.g. `tankode assimilate --mechanism ID:NAME=VALUE`)")
        self.mechanisms = [by_id[i] for i in ids]
        for m in self.mechanisms:
            if m.value.ndim != 1:
                raise ValueError(f"train_mechanisms: {m.id!r} has per-environment values; one value per "
                                 "parameter is trained")
            for p, v in zip(m.params, m.value.tolist()):
                if not p.initial and not p.lower < v < p.upper:
                    raise ValueError(f"train_mechanisms: {m.id} {p.name} = {v:g} starts on its bound "
                                     f"[{p.lower:g}, {p.upper:g}] {p.unit}; the bounded optimiser has no slope "
                                     f"there: start it strictly inside (e.g. {m.id}:{p.name}={p.scale:g})")
        # An initial parameter (Param.initial) is not trained: it sets only the first state.
        self.index = [torch.tensor([i for i, p in enumerate(m.params) if not p.initial], dtype=torch.long)
                      for m in self.mechanisms]
        kept = [[p for p in m.params if not p.initial] for m in self.mechanisms]
        self.scales = [torch.tensor([p.scale for p in ps], dtype=torch.float64) for ps in kept]
        self.lower = [torch.tensor([p.lower for p in ps], dtype=torch.float64) for ps in kept]
        self.upper = [torch.tensor([p.upper for p in ps], dtype=torch.float64) for ps in kept]
        self.xi = [nn.Parameter((m.value.detach()[i] / s).clone())
                   for m, i, s in zip(self.mechanisms, self.index, self.scales)]
        # Registered on the mechanism, so that the model's parameters include it: the adjoint
        # integrates the sensitivities of exactly those (torchdiffeq's adjoint_params), and a
        # tensor outside them would get no gradient from Adjoint().
        for m, x in zip(self.mechanisms, self.xi):
            m.register_parameter(XI_NAME, x)

    @property
    def sets_start(self) -> bool:
        """Whether a trained mechanism offsets a reading the run's first state is built from
        (the pressure or the liquid temperature), so that the first state moves with it."""
        return any(type(m).pressure_offset_Pa is not Mechanism.pressure_offset_Pa
                   or type(m).liquid_temperature_offset_K is not Mechanism.liquid_temperature_offset_K
                   for m in self.mechanisms)

    def named(self) -> list[tuple[str, Tensor]]:
        """``(name, xi)`` pairs for the optimiser, named ``mechanism.<id>``."""
        return [(PREFIX + m.id, x) for m, x in zip(self.mechanisms, self.xi)]

    def bounds(self) -> dict[str, Box]:
        """Each mechanism's physical bounds, in units of its parameters' scales."""
        return {PREFIX + m.id: Box(lo / s, hi / s)
                for m, s, lo, hi in zip(self.mechanisms, self.scales, self.lower, self.upper)}

    def apply(self) -> None:
        """Set every trained mechanism's parameters from ``xi`` (differentiably, for the next forward pass)."""
        for m, i, x, s in zip(self.mechanisms, self.index, self.xi, self.scales):
            m.value = m.value.detach().index_put((i,), x * s)

    def settle(self) -> None:
        """Set the parameters from ``xi`` without a graph (after an update: for saving and simulating)."""
        with torch.no_grad():
            for m, i, x, s, lo, hi in zip(self.mechanisms, self.index, self.xi, self.scales, self.lower, self.upper):
                # xi stays in its box (the bounded optimiser's map); the clamp only absorbs the
                # rounding of xi * scale at a bound, which set_values would otherwise refuse
                m.set_values(m.value.detach().index_put((i,), (x * s).clamp(lo, hi)))

    def values(self) -> dict[str, dict[str, float]]:
        """The current values, ``{id: {param: value}}`` (SI units)."""
        return {m.id: m.values_dict() for m in self.mechanisms}

    def state_dict(self) -> dict[str, Tensor]:
        """The trained variables ``{id: xi}`` as they are, for a checkpoint (``values()`` rounds through SI)."""
        return {m.id: x.detach().clone() for m, x in zip(self.mechanisms, self.xi)}

    def load_state_dict(self, state: dict[str, Tensor]) -> None:
        """Restore ``state_dict()`` exactly, so that a resumed training continues bit for bit.

        Raises:
            ValueError: the checkpoint lacks a trained mechanism (it was written by another training).
        """
        missing = [m.id for m in self.mechanisms if m.id not in state]
        if missing:
            raise ValueError(f"checkpoint has no trained values for {missing}: it was written by a training "
                             "that did not train them")
        with torch.no_grad():
            for m, x in zip(self.mechanisms, self.xi):
                x.copy_(state[m.id])
        self.settle()


__all__ = ["TrainedMechanisms"]
