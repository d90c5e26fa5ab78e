"""A closure whose four coefficients are another closure's times fixed multipliers."""

from __future__ import annotations

import torch
from torch import Tensor

from .base import Closure, ClosureInputs


class ScaledClosure(Closure):
    """``theta = base(x) * factors``: calibrate a closure's level without changing its shape.

    Used by the sensitivity study (one row of multipliers per environment, so perturbed
    samples run as one batched ODE) and by the diagnosis (four multipliers shared by all
    environments: a closure with only four degrees of freedom, which cannot bend itself to
    mimic a missing mechanism's time signature).

    Args:
        base: the closure to scale (e.g. ``ReferenceClosure()`` or a trained ``MLPClosure``).
        factors: multipliers (dimensionless, order h_vi, h_li, h_wv, h_wl), shape ``(4,)``
            (shared) or ``(env, 4)`` (one row per environment); finite and >= 0. A float64
            buffer, not trained by gradient.

    Raises:
        ValueError: ``factors`` has the wrong shape or non-finite / negative entries, or (in
            ``forward``) a per-environment ``factors`` does not match the number of environments.
    """

    def __init__(self, base: Closure, factors):
        super().__init__()
        f = torch.as_tensor(factors, dtype=torch.float64)
        if f.ndim not in (1, 2) or f.shape[-1] != 4:
            raise ValueError(f"factors must have shape (4,) or (env, 4), got {tuple(f.shape)}")
        if not torch.isfinite(f).all() or (f < 0).any():
            raise ValueError("factors must be finite and >= 0")
        self.base = base
        self.register_buffer("factors", f.clone())

    def forward(self, x: ClosureInputs) -> Tensor:
        theta = self.base(x)  # (env, 4)
        if self.factors.ndim == 2 and theta.shape != self.factors.shape:
            raise ValueError(f"ScaledClosure: base closure returned theta of shape {tuple(theta.shape)}, "
                             f"but factors have shape {tuple(self.factors.shape)} (one row per environment)")
        return theta * self.factors


__all__ = ["ScaledClosure"]
