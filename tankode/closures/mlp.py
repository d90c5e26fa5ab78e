"""The agent: a small MLP closure theta = g(s; w) learned from data (paper, section 5.2).

Eight dimensionless inputs (the paper's seven plus one of ours):

===  ==========================================================  ==============
 #   feature                                                     scaling
===  ==========================================================  ==============
 0   Pr_v = mu_v c_p,v / k_v                                     ``/ 2``
 1   Pr_l                                                        ``/ 2``
 2   aspect ratio R/H of the tank                                as is
 3   Re = f_e A_0 R / nu_l, divided by 1e4 (paper)               as is
 4   ln(|Gr_wv| + 1), Gr = g beta |dT| R^3 / nu^2, wall-vapour   ``/ 30``
 5   ln(|Gr_wl| + 1), wall-liquid                                ``/ 30``
 6   ln(|Gr_vl| + 1), vapour-liquid (liquid properties)          ``/ 30``
 7   f_e / f_11, excitation over first sloshing frequency        as is
===  ==========================================================  ==============

``|dT|`` is smoothed as ``sqrt(dT^2 + (0.05 K)^2)``: with ``g beta R^3/nu^2`` ~ 1e13 per kelvin
for LH2, the raw ``ln(|Gr| + 1)`` climbs from 0 to 16 within a microkelvin of ``dT = 0`` with an
infinite slope there, so an agent using it switches its coefficients abruptly whenever two
temperatures cross and the ODE solver stalls (observed: 200,000 evaluations in one window of
case 1, where wall, vapour and liquid end within 0.2 K). 0.05 K is below the sensors' noise,
so nothing measurable is lost.

Feature 7 is ours: the wave a given forcing raises depends on how close f_e is to the tank's
first natural frequency f_11 (which moves with the fill level), which Re alone cannot tell.
The scalings bring every feature to O(1) for LH2 tanks of metres; they are fixed constants
(not fitted), so a model trained on one tank applies unchanged to another.

Outputs: ``h_j = h_ref,j * exp(span * tanh(o_j))``, positive and bounded in
``[h_ref/e^span, h_ref e^span]`` whatever the weights; the last layer starts at zero so an
untrained agent returns ``h_ref`` (a sane, mid-range closure) and the first ODE of training
never blows up. Architecture: 8 -> 16 -> 16 -> 4, tanh, 484 weights (paper).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor, nn

from .base import GRAVITY_M_S2, Closure, ClosureInputs
from .reference import first_slosh_frequency_Hz

N_FEATURES = 8
DT_SMOOTH_K = 0.05  # temperature differences are resolved down to this (module docstring)
FEATURE_NAMES = ("Pr_v", "Pr_l", "R_over_H", "Re_1e4", "lnGr_wv", "lnGr_wl", "lnGr_vl", "f_over_f11")


@dataclass(frozen=True)
class MLPConfig:
    """Architecture and output ranges of the MLP closure.

    Attributes:
        hidden: hidden layer widths (paper: two layers of 16).
        h_ref_W_m2K: mid-range coefficients ``(h_vi, h_li, h_wv, h_wl)`` in W/(m^2 K); an
            untrained agent returns these. Chosen at the order of magnitude of LH2 tanks at
            rest to moderately sloshing.
        span: half-width of the output range in natural-log units (4.6 = factor 100 each way).
        seed: weight initialisation seed.
    """

    hidden: tuple[int, ...] = (16, 16)
    h_ref_W_m2K: tuple[float, float, float, float] = (3.0, 10.0, 60.0, 100.0)
    span: float = math.log(100.0)
    seed: int = 0

    def __post_init__(self):
        if not self.hidden or any(int(h) < 1 for h in self.hidden):
            raise ValueError(f"MLPConfig.hidden must be positive layer widths, got {self.hidden}")
        if len(self.h_ref_W_m2K) != 4 or any(not (h > 0 and math.isfinite(h)) for h in self.h_ref_W_m2K):
            raise ValueError(f"MLPConfig.h_ref_W_m2K must be 4 positive values in W/(m^2 K), got {self.h_ref_W_m2K}")
        if not (0 < self.span <= 10):
            raise ValueError(f"MLPConfig.span must be in (0, 10] (log units), got {self.span}")


def mlp_features(x: ClosureInputs) -> Tensor:
    """The eight scaled features ``(env, 8)`` of the module docstring."""
    R = x.radius_m
    nu_v = x.vapor.mu / x.rho_v_kg_m3
    nu_l = x.liquid.mu / x.rho_l_kg_m3
    pr_v = x.vapor.mu * x.vapor.cp / x.vapor.k
    pr_l = x.liquid.mu * x.liquid.cp / x.liquid.k
    re = x.slosh_frequency_Hz * x.slosh_amplitude_m * R / nu_l / 1e4

    def ln_gr(beta, dT, nu):
        return torch.log1p(GRAVITY_M_S2 * beta.abs() * torch.sqrt(dT * dT + DT_SMOOTH_K**2) * R**3 / nu**2)

    gr_wv = ln_gr(x.vapor.beta, x.T_w_K - x.T_v_K, nu_v)
    gr_wl = ln_gr(x.liquid.beta, x.T_w_K - x.T_l_K, nu_l)
    gr_vl = ln_gr(x.liquid.beta, x.T_v_K - x.T_l_K, nu_l)
    ratio = x.slosh_frequency_Hz / first_slosh_frequency_Hz(R, x.H_l_m)
    return torch.stack([pr_v / 2, pr_l / 2, x.aspect_ratio, re, gr_wv / 30, gr_wl / 30, gr_vl / 30, ratio], dim=-1)


class MLPClosure(Closure):
    """theta = h_ref * exp(span * tanh(MLP(features))), see the module docstring."""

    def __init__(self, config: MLPConfig = MLPConfig()):
        super().__init__()
        self.config = config
        gen = torch.Generator().manual_seed(config.seed)
        widths = (N_FEATURES, *config.hidden, 4)
        layers: list[nn.Module] = []
        for i, (a, b) in enumerate(zip(widths[:-1], widths[1:])):
            lin = nn.Linear(a, b, dtype=torch.float64)
            bound = 1.0 / math.sqrt(a)
            with torch.no_grad():
                lin.weight.uniform_(-bound, bound, generator=gen)
                lin.bias.uniform_(-bound, bound, generator=gen)
                if i == len(widths) - 2:  # start at h_ref (see module docstring)
                    lin.weight.zero_()
                    lin.bias.zero_()
            layers.append(lin)
            if i < len(widths) - 2:
                layers.append(nn.Tanh())
        self.net = nn.Sequential(*layers)
        self.register_buffer("log_h_ref", torch.log(torch.tensor(config.h_ref_W_m2K, dtype=torch.float64)))

    def forward(self, x: ClosureInputs) -> Tensor:
        out = self.net(mlp_features(x))
        return torch.exp(self.log_h_ref + self.config.span * torch.tanh(out))


__all__ = ["MLPClosure", "MLPConfig", "mlp_features", "FEATURE_NAMES", "N_FEATURES"]
