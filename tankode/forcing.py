"""Operations as they enter the right-hand side: one constant ``Forcing`` per segment."""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor


class Forcing(NamedTuple):
    """Inputs held constant over one integration segment, each shaped ``(env,)``, SI units.

    The inflow enthalpies are resolved from the schedule's (T, p) before the segment starts
    (see ``tankode.simulate``), so the right-hand side needs no property lookup for them.
    """

    mdot_v_in_kg_s: Tensor
    h_v_in_J_per_kg: Tensor
    mdot_v_out_kg_s: Tensor
    mdot_l_in_kg_s: Tensor
    h_l_in_J_per_kg: Tensor
    mdot_l_out_kg_s: Tensor
    slosh_amplitude_m: Tensor
    slosh_frequency_Hz: Tensor
    Q_aw_W: Tensor

    @staticmethod
    def rest(n_env: int, **values: float | Tensor) -> "Forcing":
        """A closed tank at rest (all zero) with the named fields overridden."""
        unknown = set(values) - set(Forcing._fields)
        if unknown:
            raise ValueError(f"unknown forcing field(s) {sorted(unknown)}; valid: {Forcing._fields}")
        fields = {}
        for name in Forcing._fields:
            v = values.get(name, 0.0)
            fields[name] = torch.as_tensor(v, dtype=torch.float64).expand(n_env).clone()
        return Forcing(**fields)


__all__ = ["Forcing"]
