"""Textbook convection on all four surfaces: the physical prior the agent corrects.

Every coefficient comes from its own surface's driving temperature difference, so the closure
cools a warm ullage onto a colder wall (and warms a cold liquid from a warmer wall) at the rate
the textbook gives, whatever the other surfaces do. Correlations (Incropera et al.,
*Fundamentals of Heat and Mass Transfer*, ch. 9; properties of each phase at its bulk state):

* **Walls** (wall-vapour, wall-liquid): vertical plate, Churchill & Chu (1975), all Rayleigh
  numbers::

      Nu_L = (0.825 + 0.387 Ra_L^(1/6) / (1 + (0.492/Pr)^(9/16))^(8/27))^2

  with ``Ra_L = g beta |T_w - T_x| L^3 / (nu alpha)``, ``T_w`` the temperature of the wall part
  in contact with the phase (a two-node wall's dry or wetted node, the mean of a lumped wall;
  ``ClosureInputs.wall_temperatures_K``), and ``L`` the height of that wall part (the level
  ``H_l`` for the liquid, ``H - H_l`` for the ullage; at least ``min_height_share`` of the
  radius, so a nearly full or empty tank keeps a finite exchange).
* **Interface**, each side on its own temperature difference to saturation, ``L = R/2`` (area
  over perimeter of a circular surface):

  - unstable side (liquid warmer than the interface: cooled from above; vapour colder than it:
    heated from below): ``Nu = ((0.54 Ra^(1/4))^6 + (0.15 Ra^(1/3))^6)^(1/6)``, the laminar and
    turbulent correlations of a horizontal plate joined smoothly;
  - stable side (the opposite signs): ``Nu = 0.27 Ra^(1/4)``;
  - the two blended by a logistic switch of width ``dT_smooth_K`` in the sign.
* **Sloshing**: a forced-convection term on all four surfaces with the linear first-mode wave
  (``tankode.closures.reference.wave_height_m``, damping ``slosh_damping``) as velocity scale,
  ``U = 2 pi f_e b``, ``Re = U R / nu``, turbulent flat plate ``Nu_f = 0.037 Re^0.8 Pr^(1/3)``,
  combined with natural convection as ``Nu = (Nu_n^3 + Nu_f^3)^(1/3)`` (Churchill's rule for
  mixed convection).

``|dT|`` is smoothed as ``sqrt(dT^2 + dT_smooth_K^2)`` so the coefficients stay differentiable
where two temperatures cross.

Limits: vertical-plate and flat-interface formulas for every shape (a sphere's or a horizontal
cylinder's curved wall, heads, and the sloshing of non-cylindrical tanks only approximately);
no boiling on a wall above saturation; the wave from linear theory, which overestimates near
resonance and ignores breaking. Under sloshing no textbook term is the truth: three
independent simulators' laws put the liquid side's coefficient a factor of 10 apart at the
same states, with this term between them (0.18-1.7 times it; ``experiments/README.md``,
section 5), so the agent learns the sloshing from the data. The agent
(``tankode.closures.MLPClosure`` with ``base="natural"``) multiplies each coefficient by a
learned factor, so these formulas set the starting point and the shape of the closure, not its
final values.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from .base import GRAVITY_M_S2, Closure, ClosureInputs
from .reference import wave_height_m


@dataclass(frozen=True)
class NaturalConvection:
    """Constants of ``NaturalConvectionClosure`` (dimensionless unless stated)."""

    # K; below the temperature sensors' noise, wide enough for a smooth ODE right-hand side.
    dT_smooth_K: float = 0.05
    # A wall part shorter than this share of R exchanges heat as one of this height.
    min_height_share: float = 0.05
    # Modal damping ratio of the wave-height estimate (an engineering value for cryogenic sloshing).
    slosh_damping: float = 0.1

    def __post_init__(self):
        for name in ("dT_smooth_K", "min_height_share", "slosh_damping"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"NaturalConvection.{name} must be finite and > 0, got {v}")


def _smooth_abs(x: Tensor, eps: float) -> Tensor:
    return torch.sqrt(x * x + eps * eps)


def churchill_chu(ra: Tensor, pr: Tensor) -> Tensor:
    """Nusselt number of a vertical plate, all Rayleigh numbers (Churchill & Chu 1975)."""
    return (0.825 + 0.387 * ra ** (1 / 6) / (1 + (0.492 / pr) ** (9 / 16)) ** (8 / 27)) ** 2


def horizontal_unstable(ra: Tensor) -> Tensor:
    """Nusselt number of a horizontal surface on the unstable side (laminar and turbulent joined)."""
    return ((0.54 * ra**0.25) ** 6 + (0.15 * ra ** (1 / 3)) ** 6) ** (1 / 6)


def horizontal_stable(ra: Tensor) -> Tensor:
    """Nusselt number of a horizontal surface on the stable side."""
    return 0.27 * ra**0.25


def forced_turbulent(re: Tensor, pr: Tensor) -> Tensor:
    """Turbulent flat-plate Nusselt number ``0.037 Re^0.8 Pr^(1/3)``."""
    return 0.037 * (re + 1e-12) ** 0.8 * pr ** (1 / 3)


def _mixed(nu_natural: Tensor, nu_forced: Tensor) -> Tensor:
    return (nu_natural**3 + nu_forced**3) ** (1 / 3)


class NaturalConvectionClosure(Closure):
    """Natural convection on each surface plus a sloshing term (module docstring); no trainable parameters."""

    def __init__(self, constants: NaturalConvection = NaturalConvection()):
        super().__init__()
        self.constants = constants

    def forward(self, x: ClosureInputs) -> Tensor:
        c = self.constants
        # Both phases at once along a trailing axis (vapour, liquid): the tensors are tiny, so the
        # right-hand side's cost is the number of operations, not their size.
        v, l = x.vapor, x.liquid
        two = lambda a, b: torch.stack(torch.broadcast_tensors(a, b), dim=-1)  # noqa: E731
        R = x.radius_m[..., None]
        H_l = x.H_l_m[..., None]
        L_floor = c.min_height_share * R
        # the wall each phase wets: the dry wall above the level, the wetted wall below it
        L_wall = torch.sqrt(torch.cat([(R / x.aspect_ratio[..., None] - H_l).clamp_min(0.0), H_l], -1) ** 2
                            + L_floor**2)
        b = wave_height_m(x.slosh_amplitude_m, x.slosh_frequency_Hz, x.radius_m, x.H_l_m, c.slosh_damping)
        U = (2 * math.pi * x.slosh_frequency_Hz * b)[..., None]
        eps = c.dT_smooth_K
        mu, k, cp, beta = two(v.mu, l.mu), two(v.k, l.k), two(v.cp, l.cp), two(v.beta, l.beta)
        rho, T = two(x.rho_v_kg_m3, x.rho_l_kg_m3), two(x.T_v_K, x.T_l_K)
        nu = mu / rho
        alpha = k / (rho * cp)
        pr = nu / alpha
        nu_forced = forced_turbulent(U * R / nu, pr)
        # Interface side: unstable when the liquid is warmer than saturation / the vapour colder.
        dT_i = T - x.T_sat_K[..., None]
        unstable = torch.cat([-dT_i[..., :1], dT_i[..., 1:]], dim=-1)
        g_over = GRAVITY_M_S2 * beta.abs() / (nu * alpha)
        ra_i = g_over * _smooth_abs(dT_i, eps) * (R / 2) ** 3
        s = torch.sigmoid(unstable / eps)
        nu_i = s * horizontal_unstable(ra_i) + (1 - s) * horizontal_stable(ra_i)
        h_i = _mixed(nu_i, nu_forced) * k / (R / 2)
        ra_w = g_over * _smooth_abs(torch.stack(x.wall_temperatures_K(), dim=-1) - T, eps) * L_wall**3
        h_w = _mixed(churchill_chu(ra_w, pr), nu_forced * L_wall / R) * k / L_wall
        return torch.cat([h_i, h_w], dim=-1)  # (h_vi, h_li, h_wv, h_wl)


__all__ = ["NaturalConvection", "NaturalConvectionClosure", "churchill_chu", "horizontal_unstable",
           "horizontal_stable", "forced_turbulent"]
