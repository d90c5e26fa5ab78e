"""The (p, T) region a property surrogate is fitted on, per phase, and its validation.

Each phase's domain is a band in (p, T):

    vapor:  p_min <= p <= p_max,  T_sat(p) - metastable_K <= T <= T_v_max
    liquid: p_min <= p <= p_max,  T_l_min <= T <= T_sat(p) + metastable_K

The metastable margins exist because the 0D model evaluates each phase at the common (ullage)
pressure while the phases are out of equilibrium: the ullage can be transiently subcooled and the
liquid superheated relative to that pressure (Marques, Ahizi & Mendez, section 3). Mapped to the
surrogate's inputs (u, rho), the liquid band is a thin curved strip (the liquid is nearly
incompressible), which is why the surrogate's ``contains`` checks (p, T) and not only a box.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from functools import lru_cache

import numpy as np


@lru_cache(maxsize=16)
def _fluid_limits(fluid_name: str) -> dict:
    from .coolprop import CoolPropFluid

    f = CoolPropFluid(fluid_name)
    return {"T_triple": f.T_triple_K, "p_triple": f.p_triple_Pa, "T_crit": f.T_crit_K, "p_crit": f.p_crit_Pa,
            "T_max": f.T_max_K}


@lru_cache(maxsize=256)
def _T_sat(fluid_name: str, p_Pa: float) -> float:
    from .coolprop import CoolPropFluid

    return float(CoolPropFluid(fluid_name).saturation(p_Pa)["T_sat"])


def _branch_exists(fluid, phase: str, p_Pa: float, T_K: float) -> bool:
    try:
        fluid.props_pT(p_Pa, T_K, phase)
        return True
    except ValueError:
        return False


@lru_cache(maxsize=64)
def _max_metastable_K(fluid_name: str, p_Pa: float) -> float:
    """Largest margin (K) for which both single-phase branches still exist at ``p_Pa`` (bisection, 0.01 K)."""
    from .coolprop import CoolPropFluid

    f = CoolPropFluid(fluid_name)
    T_sat = _T_sat(fluid_name, p_Pa)
    out = []
    for phase, sign in (("vapor", -1.0), ("liquid", 1.0)):
        lo, hi = 0.0, 5.0
        while hi - lo > 0.01:
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if _branch_exists(f, phase, p_Pa, T_sat + sign * mid) else (lo, mid)
        out.append(lo)
    return min(out)


@dataclass(frozen=True)
class Domain:
    """Fitted region of a property surrogate, in pressure and temperature (SI).

    Validated on construction against the fluid's triple and critical points (``ValueError``
    naming the field and its allowed range). Defaults suit liquid-hydrogen storage tanks.
    """

    # Pa; below the ~1 bar venting pressure of LH2 tanks with room for depressurisation dips.
    p_min_Pa: float = 0.7e5
    # Pa; the paper's environments peak at 5.3 bar; 6 bar (a typical relief setting of small LH2
    # tanks) keeps the vapour spinodal 1.88 K below T_sat, room for the metastable margin below.
    p_max_Pa: float = 6.0e5
    # K; covers warm, stratified ullage and warm-gas pressurisation near the saturated liquid.
    T_v_max_K: float = 50.0
    # K; allows subcooled (densified) liquid, kept 3 K above the 13.8 K triple point.
    T_l_min_K: float = 17.0
    # K; vapour down to T_sat(p) - margin, liquid up to T_sat(p) + margin (metastable states of
    # a non-equilibrium tank: case 1's ullage, cooled by a wall below T_sat, subcools by 1.3 K);
    # CoolProp's vapour branch ends 1.88 K below T_sat at 6 bar (the spinodal), validated below.
    metastable_K: float = 1.8
    # Fluid whose triple/critical points bound the fields (validation only).
    fluid_name: str = "ParaHydrogen"

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name == "fluid_name":
                if not isinstance(v, str):
                    raise ValueError(f"Domain.fluid_name must be a str, got {v!r}")
                continue
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"Domain.{f.name} must be a finite number, got {v!r}")
        lim = _fluid_limits(self.fluid_name)
        name = self.fluid_name
        if not 0.0 <= self.metastable_K <= 5.0:
            raise ValueError(f"Domain.metastable_K must be in [0, 5] K, got {self.metastable_K}")
        if not lim["p_triple"] < self.p_min_Pa < self.p_max_Pa:
            raise ValueError(
                f"Domain.p_min_Pa must be in ({lim['p_triple']:.6g}, p_max_Pa={self.p_max_Pa:.6g}) Pa "
                f"(above the {name} triple-point pressure, below p_max), got {self.p_min_Pa}"
            )
        if not self.p_max_Pa < lim["p_crit"]:
            raise ValueError(
                f"Domain.p_max_Pa must be in (p_min_Pa={self.p_min_Pa:.6g}, {lim['p_crit']:.6g}) Pa "
                f"(below the {name} critical pressure, where saturation exists), got {self.p_max_Pa}"
            )
        T_sat_lo, T_sat_hi = _T_sat(name, float(self.p_min_Pa)), _T_sat(name, float(self.p_max_Pa))
        if not T_sat_hi + self.metastable_K < lim["T_crit"]:
            raise ValueError(
                f"Domain.p_max_Pa / metastable_K: T_sat(p_max)={T_sat_hi:.4f} K plus metastable_K must stay "
                f"below the {name} critical temperature {lim['T_crit']:.4f} K"
            )
        # The metastable branches end at the spinodals, closest to saturation at high pressure.
        m_max = min(_max_metastable_K(name, float(self.p_max_Pa)), _max_metastable_K(name, float(self.p_min_Pa)))
        m_max = math.floor(m_max * 100.0) / 100.0
        if self.metastable_K > m_max:
            raise ValueError(
                f"Domain.metastable_K must be in [0, {m_max:.2f}] K for p_max_Pa={self.p_max_Pa:.6g} "
                f"(beyond, CoolProp's {name} single-phase branch ends: spinodal), got {self.metastable_K}"
            )
        if not lim["T_triple"] < self.T_l_min_K < T_sat_lo:
            raise ValueError(
                f"Domain.T_l_min_K must be in ({lim['T_triple']:.6g}, {T_sat_lo:.6g}) K (above the {name} "
                f"triple point, below T_sat(p_min)), got {self.T_l_min_K}"
            )
        if not T_sat_hi < self.T_v_max_K <= lim["T_max"]:
            raise ValueError(
                f"Domain.T_v_max_K must be in ({T_sat_hi:.6g}, {lim['T_max']:.6g}] K (above T_sat(p_max), within "
                f"the {name} EOS range), got {self.T_v_max_K}"
            )

    def T_bounds(self, phase: str, T_sat_K):
        """Temperature bounds (K) of ``phase`` at pressures whose saturation temperature is ``T_sat_K``.

        Works on numpy arrays and torch tensors alike; returns ``(T_lo, T_hi)``.
        """
        if phase == "vapor":
            return T_sat_K - self.metastable_K, T_sat_K * 0.0 + self.T_v_max_K
        if phase == "liquid":
            return T_sat_K * 0.0 + self.T_l_min_K, T_sat_K + self.metastable_K
        raise ValueError(f"phase must be 'vapor' or 'liquid', got {phase!r}")

    def sample_pT(self, phase: str, p_frac, s_frac, T_sat_of_p) -> tuple[np.ndarray, np.ndarray]:
        """Map unit coordinates to (p, T) in the phase's band: p linear in ``p_frac``, T linear in ``s_frac``.

        Args:
            phase: ``"vapor"`` or ``"liquid"``.
            p_frac, s_frac: arrays in [0, 1] (same shape).
            T_sat_of_p: callable mapping a pressure array (Pa) to T_sat (K).
        """
        p = self.p_min_Pa + np.asarray(p_frac, dtype=np.float64) * (self.p_max_Pa - self.p_min_Pa)
        lo, hi = self.T_bounds(phase, np.asarray(T_sat_of_p(p), dtype=np.float64))
        return p, lo + np.asarray(s_frac, dtype=np.float64) * (hi - lo)

    def as_dict(self) -> dict:
        return asdict(self)


__all__ = ["Domain"]
