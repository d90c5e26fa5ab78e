"""Saturation temperature and enthalpies as a polynomial in pressure (torch, differentiable).

T_sat, h_lsat and h_vsat depend on pressure only, so the surrogate evaluates them at its own
pressure output instead of interpolating them in (u, rho): the liquid's p(u, rho) is steep and
an (u, rho) fit of T_sat would inherit that difficulty, while ``T_sat(p_surrogate)`` is consistent
between the two phases whenever their pressures agree. A 1-D least-squares polynomial in the
scaled pressure ``x = (2 p - p_lo - p_hi)/(p_hi - p_lo)`` over Chebyshev nodes is well conditioned
(cond ~2e4 at degree 12) and reaches ~1e-5 relative error; see ``fit_saturation``.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor, nn


class SaturationPolynomial(nn.Module):
    """``(T_sat, h_lsat, h_vsat)`` (K, J/kg, J/kg) of pressure ``p`` (Pa) as one polynomial (buffers only).

    Args:
        p_lo_Pa, p_hi_Pa: pressure interval mapped to x in [-1, 1] (extrapolates outside).
        coef: ``(degree + 1, 3)`` coefficients of ``x^0 .. x^degree`` for the three outputs.
    """

    def __init__(self, p_lo_Pa: float, p_hi_Pa: float, coef: Tensor):
        super().__init__()
        coef = torch.as_tensor(coef, dtype=torch.float64)
        if coef.ndim != 2 or coef.shape[1] != 3 or coef.shape[0] < 2:
            raise ValueError(f"SaturationPolynomial: coef must be (degree+1 >= 2, 3), got {tuple(coef.shape)}")
        if not p_hi_Pa > p_lo_Pa:
            raise ValueError(f"SaturationPolynomial: need p_hi > p_lo, got {p_lo_Pa}, {p_hi_Pa}")
        self.p_lo_Pa, self.p_hi_Pa, self.degree = float(p_lo_Pa), float(p_hi_Pa), coef.shape[0] - 1
        self._a = 2.0 / (self.p_hi_Pa - self.p_lo_Pa)
        self.register_buffer("_b", torch.tensor(-(self.p_hi_Pa + self.p_lo_Pa) / (self.p_hi_Pa - self.p_lo_Pa),
                                                dtype=torch.float64))
        self.register_buffer("coef", coef)
        self.register_buffer("_c0", coef[0].clone())
        self.register_buffer("_c", coef[1:].contiguous())

    def forward(self, p_Pa: Tensor) -> Tensor:
        """``(n, 3)`` columns T_sat (K), h_lsat (J/kg), h_vsat (J/kg) for ``p_Pa`` of shape ``(n,)``."""
        B = self._buffers  # dict lookups: nn.Module.__getattr__ costs ~0.5 us per buffer
        x = torch.add(B["_b"], p_Pa, alpha=self._a)
        # cumprod gives x, x^2, ..., x^d in one op and stays twice differentiable at x = 0
        # (pow(x, k) has a 0 * inf second derivative there).
        powers = torch.cumprod(x[:, None].expand(-1, self.degree), 1)
        return torch.addmm(B["_c0"], powers, B["_c"])

    def state(self) -> dict:
        return {"p_lo_Pa": self.p_lo_Pa, "p_hi_Pa": self.p_hi_Pa, "coef": self.coef.detach().cpu()}

    @staticmethod
    def from_state(state: dict) -> "SaturationPolynomial":
        return SaturationPolynomial(state["p_lo_Pa"], state["p_hi_Pa"], state["coef"])


def fit_saturation(fluid, p_lo_Pa: float, p_hi_Pa: float, degree: int = 12, n_nodes: int = 200,
                   n_check: int = 1000) -> tuple[SaturationPolynomial, dict]:
    """Least-squares fit of ``SaturationPolynomial`` to CoolProp on Chebyshev nodes of [p_lo, p_hi].

    Args:
        fluid: ``CoolPropFluid``.
        p_lo_Pa, p_hi_Pa: fitted pressure interval (Pa).
        degree, n_nodes: polynomial degree and number of nodes.
        n_check: evenly spaced pressures where the error is measured.

    Returns:
        The polynomial and diagnostics: max relative error of T_sat and max error of h_lsat,
        h_vsat relative to the latent heat L = h_vsat - h_lsat (h_lsat crosses 0 near 1 atm for
        ParaHydrogen, so its own relative error is meaningless there), and the condition number.

    Raises:
        RuntimeError: the polynomial misses CoolProp by more than 1e-4 (relative / of L).
    """
    k = np.arange(n_nodes)
    x = np.cos(np.pi * (k + 0.5) / n_nodes)
    p = 0.5 * (p_lo_Pa + p_hi_Pa) + 0.5 * (p_hi_Pa - p_lo_Pa) * x
    sat = fluid.saturation(p)
    Y = np.stack([sat["T_sat"], sat["h_lsat"], sat["h_vsat"]], 1)
    V = x[:, None] ** np.arange(degree + 1)
    coef, *_ = np.linalg.lstsq(V, Y, rcond=None)
    poly = SaturationPolynomial(p_lo_Pa, p_hi_Pa, torch.as_tensor(coef))
    p_chk = np.linspace(p_lo_Pa, p_hi_Pa, n_check)
    ref = fluid.saturation(p_chk)
    with torch.no_grad():
        got = poly(torch.as_tensor(p_chk)).numpy()
    L = ref["h_vsat"] - ref["h_lsat"]
    info = {
        "degree": degree, "n_nodes": n_nodes, "p_lo_Pa": p_lo_Pa, "p_hi_Pa": p_hi_Pa,
        "cond": float(np.linalg.cond(V)),
        "max_rel_err_T_sat": float(np.max(np.abs(got[:, 0] / ref["T_sat"] - 1))),
        "max_err_h_lsat_over_L": float(np.max(np.abs(got[:, 1] - ref["h_lsat"]) / L)),
        "max_err_h_vsat_over_L": float(np.max(np.abs(got[:, 2] - ref["h_vsat"]) / L)),
    }
    worst = max(info["max_rel_err_T_sat"], info["max_err_h_lsat_over_L"], info["max_err_h_vsat_over_L"])
    if not worst <= 1e-4:
        raise RuntimeError(
            f"saturation polynomial fit failed for {fluid.name} on [{p_lo_Pa:.6g}, {p_hi_Pa:.6g}] Pa: "
            f"max error {worst:.3g} > 1e-4 at degree {degree}; raise SurrogateConfig.sat_degree"
        )
    return poly, info


__all__ = ["SaturationPolynomial", "fit_saturation"]
