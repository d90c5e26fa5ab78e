"""A liquid that starts saturated: a first reading above saturation is not the liquid's temperature."""

from __future__ import annotations

import torch

from .base import Mechanism, Param


class SaturatedStart(Mechanism):
    """The liquid starts no warmer than saturation at the initial pressure.

    Physics. A run that starts from a conditioned, quiescent tank starts with a liquid at or below
    saturation at the ullage's pressure: a superheated liquid at rest boils. A first liquid
    reading above ``T_sat(p0)`` is then the thermometer's (or the data reduction's property
    model's) and not the liquid's: the NASA MHTB tests' liquid reads 0.05-0.10 K above
    para-hydrogen's saturation at their start, where normal hydrogen's saturation lies
    (``experiments/mhtb_rotations.py``). The liquid starts at::

        T_l0 = reading - share * max(reading - T_sat(p0), 0),

    with ``p0`` the condensable's initial pressure (the reading less the mechanisms' pressure
    offsets). Nothing else changes: the model's liquid temperature is what it is compared with,
    so where the thermometer's offset persists it stays in the liquid temperature's residual.
    ``share = 0`` is the baseline (the liquid starts at its reading, superheated if it reads so).

    Signature: without it, a model whose liquid starts superheated evaporates at the interface
    at first, its pressure rising by about ``dp_sat/dT`` times the excess within the first hour.

    Limits: a property of a run's start only (an initial parameter, never trained); a liquid that
    is superheated at the start for real (a tank being depressurised) is moved to saturation too.
    """

    id = "saturated_start"
    model_form = True
    params = (Param("share", "1", 0.0, 1.0, 1.0, initial=True),)
    signature = "the early pressure rise of a liquid that started superheated, gone"

    def initial_liquid_K(self, T_l_K, T_sat_K):
        return T_l_K - self.param(0, T_l_K) * torch.clamp(T_l_K - T_sat_K, min=0.0)


__all__ = ["SaturatedStart"]
