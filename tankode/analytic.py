"""Problems with known answers: an analytic fluid and tank set-ups whose solutions are closed form.

``AnalyticFluid`` stands in for the property surrogate: an ideal gas with constant c_v for the
vapour, a linear liquid (bulk modulus, thermal expansion, constant heat capacity) and a
Clausius-Clapeyron saturation line. It is not hydrogen; it exists so that tests and examples
can compare the model with exact solutions (``tests/test_model.py``):

* ``wall_heating``: closed tank, all heat transfer off, constant Q_aw:
  ``T_w(t) = T_w0 + Q_aw t / C_w``, everything else constant.
* ``adiabatic_vent``: vapour vented at a constant rate from a tank whose liquid is (nearly)
  rigid and thermally isolated: the remaining gas expands isentropically,
  ``p(t) = p0 (m_v(t)/m_v0)^gamma``, ``T_v(t) = T_v0 (m_v(t)/m_v0)^(gamma-1)``.
* ``wall_liquid_relaxation``: only h_wl on, no thermal expansion: the wall-liquid temperature
  difference decays as ``exp(-h A_wl (1/C_w + 1/(m_l c_l)) t)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor, nn

from .properties import PhaseProps


@dataclass(frozen=True)
class AnalyticFluidParams:
    """Constants of the analytic fluid (SI). Defaults are hydrogen-like orders of magnitude."""

    R_J_per_kgK: float = 4124.0  # specific gas constant of H2
    cv_v_J_per_kgK: float = 6500.0  # vapour c_v (so gamma ~ 1.63, a monatomic-like cold H2)
    c_l_J_per_kgK: float = 9500.0  # liquid heat capacity
    rho_l0_kg_m3: float = 70.0  # liquid reference density
    bulk_modulus_Pa: float = 5.0e7  # liquid isothermal bulk modulus
    beta_l_per_K: float = 0.0  # liquid thermal expansion (0 decouples the liquid from the pressure)
    T0_K: float = 20.0  # temperature where u = 0 for both phases' sensible parts
    p0_Pa: float = 1.0e5  # liquid reference pressure and boiling-point pressure
    T_b_K: float = 20.3  # boiling point at p0
    L_J_per_kg: float = 4.46e5  # latent heat (constant)
    k_W_mK: tuple = (0.02, 0.1)  # (vapour, liquid) conductivity
    mu_Pa_s: tuple = (1.5e-6, 1.3e-5)  # (vapour, liquid) viscosity
    beta_v_per_K: float = 0.04  # reported vapour expansion coefficient (closures only)


class AnalyticFluid(nn.Module):
    """Closed-form stand-in for ``tankode.properties.Surrogate`` (same ``vapor``/``liquid`` API).

    Vapour: ``T = T0 + (u - L)/c_v`` (vapour energy offset by the latent heat), ``p = rho R T``.
    Liquid: ``T = T0 + u/c_l``, ``p = p0 + B (rho/rho0 - 1) + B beta (T - T0)``.
    Saturation: ``T_sat = T_b / (1 - R T_b ln(p/p0) / L)``; ``h_lsat = c_l (T_sat - T0) + p/rho0``,
    ``h_vsat = h_lsat + L``.
    """

    fluid_name = "analytic"

    def __init__(self, params: AnalyticFluidParams = AnalyticFluidParams()):
        super().__init__()
        self.params = params

    def _saturation(self, p: Tensor):
        c = self.params
        T_sat = c.T_b_K / (1 - c.R_J_per_kgK * c.T_b_K * torch.log(p / c.p0_Pa) / c.L_J_per_kg)
        h_l = c.c_l_J_per_kgK * (T_sat - c.T0_K) + p / c.rho_l0_kg_m3
        return T_sat, h_l, h_l + c.L_J_per_kg

    def saturation_K(self, p_Pa: Tensor) -> Tensor:
        """Saturation temperature (K) at pressure ``p_Pa`` (Pa)."""
        return self._saturation(p_Pa)[0]

    def vapor(self, u: Tensor, rho: Tensor) -> PhaseProps:
        c = self.params
        T = c.T0_K + (u - c.L_J_per_kg) / c.cv_v_J_per_kgK
        p = rho * c.R_J_per_kgK * T
        T_sat, h_l, h_v = self._saturation(p)
        one = torch.ones_like(p)
        return PhaseProps(
            p=p, T=T, dp_du=rho * c.R_J_per_kgK / c.cv_v_J_per_kgK, dp_drho=c.R_J_per_kgK * T,
            T_sat=T_sat, h_lsat=h_l, h_vsat=h_v, k=c.k_W_mK[0] * one, mu=c.mu_Pa_s[0] * one,
            cp=(c.cv_v_J_per_kgK + c.R_J_per_kgK) * one, beta=1.0 / T,
        )

    def liquid(self, u: Tensor, rho: Tensor) -> PhaseProps:
        c = self.params
        B = c.bulk_modulus_Pa
        T = c.T0_K + u / c.c_l_J_per_kgK
        p = c.p0_Pa + B * (rho / c.rho_l0_kg_m3 - 1) + B * c.beta_l_per_K * (T - c.T0_K)
        T_sat, h_l, h_v = self._saturation(p)
        one = torch.ones_like(p)
        return PhaseProps(
            p=p, T=T, dp_du=B * c.beta_l_per_K / c.c_l_J_per_kgK * one, dp_drho=B / c.rho_l0_kg_m3 * one,
            T_sat=T_sat, h_lsat=h_l, h_vsat=h_v, k=c.k_W_mK[1] * one, mu=c.mu_Pa_s[1] * one,
            cp=c.c_l_J_per_kgK * one, beta=(c.beta_l_per_K + 1e-6) * one,
        )

    def contains(self, phase: str, u: Tensor, rho: Tensor) -> Tensor:
        return torch.ones_like(u, dtype=torch.bool)

    def state(self, p_Pa: float, T_v_K: float, T_l_K: float) -> tuple[float, float, float, float]:
        """(u_v, rho_v, u_l, rho_l) of both phases at a common pressure and their temperatures."""
        c = self.params
        u_v = c.L_J_per_kg + c.cv_v_J_per_kgK * (T_v_K - c.T0_K)
        rho_v = p_Pa / (c.R_J_per_kgK * T_v_K)
        u_l = c.c_l_J_per_kgK * (T_l_K - c.T0_K)
        rho_l = c.rho_l0_kg_m3 * (1 + (p_Pa - c.p0_Pa) / c.bulk_modulus_Pa - c.beta_l_per_K * (T_l_K - c.T0_K))
        return u_v, rho_v, u_l, rho_l

    @property
    def gamma(self) -> float:
        c = self.params
        return (c.cv_v_J_per_kgK + c.R_J_per_kgK) / c.cv_v_J_per_kgK


def analytic_state(fluid: AnalyticFluid, geometry, p_Pa: float, T_v_K: float, T_l_K: float, T_w_K: float,
                   fill_ratio: float) -> Tensor:
    """Initial state ``(1, 7)`` of a tank with the analytic fluid."""
    u_v, rho_v, u_l, rho_l = fluid.state(p_Pa, T_v_K, T_l_K)
    V = float(geometry.volume_m3)
    V_l = fill_ratio * V
    V_v = V - V_l
    return torch.tensor([[rho_v * V_v, rho_l * V_l, u_v, u_l, T_w_K, V_v, V_l]], dtype=torch.float64)


def wall_heating_T_w(t_s: Tensor, T_w0_K: float, Q_aw_W: float, C_w_J_per_K: float) -> Tensor:
    """Exact wall temperature (K) of a closed tank with heat transfer off."""
    return T_w0_K + Q_aw_W * t_s / C_w_J_per_K


def adiabatic_vent_p(t_s: Tensor, p0_Pa: float, m_v0_kg: float, mdot_kg_s: float, gamma: float) -> Tensor:
    """Exact ullage pressure (Pa) of isentropic venting from a rigid ullage."""
    return p0_Pa * ((m_v0_kg - mdot_kg_s * t_s) / m_v0_kg) ** gamma


def relaxation_rate_per_s(h_W_m2K: float, A_m2: float, C_w_J_per_K: float, m_l_kg: float, c_l_J_per_kgK: float) -> float:
    """Decay rate (1/s) of T_w - T_l when only the wall-liquid exchange is on."""
    return h_W_m2K * A_m2 * (1.0 / C_w_J_per_K + 1.0 / (m_l_kg * c_l_J_per_kgK))


__all__ = [
    "AnalyticFluid", "AnalyticFluidParams", "analytic_state", "wall_heating_T_w", "adiabatic_vent_p",
    "relaxation_rate_per_s",
]
