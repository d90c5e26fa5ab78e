"""A closure whose four coefficients are another closure's times fixed multipliers."""

from __future__ import annotations

import torch
from torch import Tensor

from .base import H_LI, Closure, ClosureInputs
from .reference import stable_liquid_convection_W_m2K


class ScaledClosure(Closure):
    """``theta = (base(x) + c h_stable(x) e_li) * factors``: calibrate a closure's level, not its shape.

    Used by the sensitivity study (one row of multipliers per environment, so perturbed
    samples run as one batched ODE) and by the diagnosis (four multipliers, and optionally the
    mixing share, shared by all environments: a closure with four or five degrees of freedom,
    which cannot bend itself in time to mimic a missing mechanism's signature).

    Args:
        base: the closure to scale (e.g. ``ReferenceClosure()`` or a trained ``MLPClosure``).
        factors: multipliers (dimensionless, order h_vi, h_li, h_wv, h_wl), shape ``(4,)``
            (shared) or ``(env, 4)`` (one row per environment); finite and >= 0. A float64
            buffer, not trained by gradient.
        stable_mixing: share ``c`` in [0, 1], ``()`` or ``(env,)``, of the liquid's turbulent
            natural convection kept when the liquid is stably stratified under the interface
            (``stable_liquid_convection_W_m2K``), added to ``h_li`` before its factor. 0 (the
            default) is the base closure unchanged; 1 is the symmetric ``|dT|^(1/3)`` law of
            many tank energy-balance models. Where a subcooled liquid meets a warmer interface
            (pressurisation, fill with colder liquid), published closures differ by this much;
            ``DiagnosisConfig(stable_mixing=True)`` calibrates it with the multipliers.

    Raises:
        ValueError: ``factors`` has the wrong shape or non-finite / negative entries,
            ``stable_mixing`` is outside [0, 1], or (in ``forward``) a per-environment
            ``factors`` does not match the number of environments.
    """

    def __init__(self, base: Closure, factors, stable_mixing=0.0):
        super().__init__()
        f = torch.as_tensor(factors, dtype=torch.float64)
        if f.ndim not in (1, 2) or f.shape[-1] != 4:
            raise ValueError(f"factors must have shape (4,) or (env, 4), got {tuple(f.shape)}")
        if not torch.isfinite(f).all() or (f < 0).any():
            raise ValueError("factors must be finite and >= 0")
        c = torch.as_tensor(stable_mixing, dtype=torch.float64)
        if c.ndim > 1 or not torch.isfinite(c).all() or (c < 0).any() or (c > 1).any():
            raise ValueError(f"stable_mixing must be a share in [0, 1], shape () or (env,), got {stable_mixing!r}")
        self.base = base
        self.register_buffer("factors", f.clone())
        # Not in the state dict: saved models carry it in their JSON spec, and weights saved
        # before it existed must still load.
        self.register_buffer("stable_mixing", c.clone(), persistent=False)
        self._mixing = bool((c > 0).any())  # skip the extra term (and its cost) when it is off
        self.register_buffer("_e_li", torch.eye(4, dtype=torch.float64)[H_LI], persistent=False)  # (4,)

    def forward(self, x: ClosureInputs) -> Tensor:
        theta = self.base(x)  # (env, 4)
        if self.factors.ndim == 2 and theta.shape != self.factors.shape:
            raise ValueError(f"ScaledClosure: base closure returned theta of shape {tuple(theta.shape)}, "
                             f"but factors have shape {tuple(self.factors.shape)} (one row per environment)")
        if self._mixing:
            extra = self.stable_mixing * stable_liquid_convection_W_m2K(x)  # (env,)
            theta = theta + extra[..., None] * self._e_li  # only h_li
        return theta * self.factors


__all__ = ["ScaledClosure"]
