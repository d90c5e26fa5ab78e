"""The wall's heat capacity other than the nominal one: a fault in a stated value, or an unknown."""

from __future__ import annotations

import math

import torch

from .base import Mechanism, Param


class WallHeatCapacityError(Mechanism):
    """The wall's true heat capacity is ``(1 + eps) m_w c_w`` (estimated or mis-specified wall).

    Signature: only while the wall temperature changes: T_w relaxes faster (eps < 0) or more
    slowly (eps > 0) towards the fluid than the model says, and the fluid sees the wall's
    heat release with that time constant. A wall at steady temperature shows nothing.
    """

    id = "wall_heat_capacity_error"
    params = (Param("eps", "1", -0.9, 9.0, 0.1),)
    signature = "T_w transients faster or slower than modelled"

    def wall_capacity_factor(self):
        return 1.0 + self.param(0)


# The range of an unknown wall's factor on tankode's aluminium-shell estimate
# (``tankode.wall.resolve_wall_heat_capacity``): a tenth (a thin shell) to a thousand times (a
# stainless wall several centimetres thick, or a simulator's wall taken at room-temperature heat
# capacity: the paper's case 1 states 2.4e6 J/K for 17 m2, 500 times the shell's).
UNKNOWN_WALL_FACTOR_RANGE = (0.1, 1000.0)


class UnknownWallCapacity(Mechanism):
    """A wall heat capacity no one states, learned: ``exp(ln_factor) m_w c_w`` on the assumed shell.

    A run may state no wall heat capacity and carry no wall sensor, so that neither the run nor
    the inventory audit (``tankode.diagnosis.audit.with_audited_wall``) gives it, while the wall
    stores the heat of a warm-gas injection or a warm ullage and sets how fast the ullage cools.
    The assimilation then trains this factor with the agent (``AssimilationConfig.unknown_wall``),
    on a log scale because the plausible walls span four decades
    (``UNKNOWN_WALL_FACTOR_RANGE``); ``ln_factor = 0`` is the assumed shell.

    Not a fault, so not a diagnosis candidate (``model_form``): ``wall_heat_capacity_error`` is
    the fault of a stated value.
    """

    id = "unknown_wall_capacity"
    model_form = True
    params = (Param("ln_factor", "1", math.log(UNKNOWN_WALL_FACTOR_RANGE[0]), math.log(UNKNOWN_WALL_FACTOR_RANGE[1]),
                    1.0),)
    signature = "the ullage's and the wall's transients set by a wall heat capacity the run does not state"

    def wall_capacity_factor(self):
        return torch.exp(self.param(0))


def applied_to_walls(mechanisms, names, walls) -> tuple[tuple, tuple[str, ...]]:
    """``mechanisms`` as they apply to tanks with these walls, and a note per tank.

    A learned ``UnknownWallCapacity`` multiplies every tank's wall, so it applies only where no
    tank states its wall (``walls``: ``tankode.wall.WallHeatCapacity``, one per run named in
    ``names``): a stated capacity is the tank's, not the shell a factor was learned on, and the
    factor is then dropped. Notes say what each tank's wall is.
    """
    mechanisms = tuple(mechanisms)
    learned = [m for m in mechanisms if isinstance(m, UnknownWallCapacity)]
    if not learned:
        return mechanisms, ()
    f = math.prod(float(m.wall_capacity_factor()) for m in learned)
    if all(w.assumed for w in walls):
        return mechanisms, tuple(f"{n}: wall heat capacity learned from data: {w.value_J_per_K * f:.4g} J/K ({f:.3g} "
                                 "times the assumed shell)" for n, w in zip(names, walls))
    kept = tuple(m for m in mechanisms if not isinstance(m, UnknownWallCapacity))
    return kept, tuple(f"{n}: the learned factor on an unknown wall ({f:.3g} times the shell) is not applied: "
                       "a run states its wall heat capacity" for n in names)


__all__ = ["WallHeatCapacityError", "UnknownWallCapacity", "UNKNOWN_WALL_FACTOR_RANGE", "applied_to_walls"]
