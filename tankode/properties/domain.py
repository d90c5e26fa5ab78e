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
from dataclasses import asdict, dataclass, fields, replace
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
    # Share of T_crit - T_sat(p) the margin may not exceed (0: the margin is metastable_K at every
    # pressure). The single-phase branches end closer to saturation as the critical point nears:
    # a domain reaching it needs a margin that narrows there but stays wide at low pressure.
    metastable_share: float = 0.0

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
        if not T_sat_hi + (0.0 if self.metastable_share else self.metastable_K) < lim["T_crit"]:
            raise ValueError(
                f"Domain.p_max_Pa / metastable_K: T_sat(p_max)={T_sat_hi:.4f} K plus metastable_K must stay "
                f"below the {name} critical temperature {lim['T_crit']:.4f} K"
            )
        if not 0.0 <= self.metastable_share < 1.0:
            raise ValueError(f"Domain.metastable_share must be in [0, 1), got {self.metastable_share}")
        # The metastable branches end at the spinodals, closest to saturation at high pressure.
        m_max = min(_max_metastable_K(name, float(self.p_max_Pa)), _max_metastable_K(name, float(self.p_min_Pa)))
        m_max = math.floor(m_max * 100.0) / 100.0
        if self.metastable_share > 0:
            at_p_max = min(self.metastable_K, self.metastable_share * (lim["T_crit"] - T_sat_hi))
            if at_p_max > m_max:
                raise ValueError(f"Domain.metastable_share: the margin at p_max_Pa={self.p_max_Pa:.6g} is "
                                 f"{at_p_max:.3g} K, beyond the {m_max:.2f} K where {name}'s single-phase branch ends")
        elif self.metastable_K > m_max:
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

    def margin_K(self, T_sat_K):
        """The metastable margin (K) at saturation temperature ``T_sat_K`` (numpy or torch, or a float)."""
        if not self.metastable_share:
            return self.metastable_K
        gap = self.metastable_share * (_fluid_limits(self.fluid_name)["T_crit"] - T_sat_K)
        if hasattr(gap, "clamp"):  # a torch tensor
            return gap.clamp(max=self.metastable_K)
        return np.minimum(self.metastable_K, gap)

    def T_bounds(self, phase: str, T_sat_K):
        """Temperature bounds (K) of ``phase`` at pressures whose saturation temperature is ``T_sat_K``.

        Works on numpy arrays and torch tensors alike; returns ``(T_lo, T_hi)``.
        """
        m = self.margin_K(T_sat_K)
        if phase == "vapor":
            return T_sat_K - m, T_sat_K * 0.0 + self.T_v_max_K
        if phase == "liquid":
            return T_sat_K * 0.0 + self.T_l_min_K, T_sat_K + m
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

    def extent(self) -> str:
        """Its pressures and the vapour's top temperature, in words (for notes and errors)."""
        return f"{self.p_min_Pa:.4g} to {self.p_max_Pa:.4g} Pa with the vapour up to {self.T_v_max_K:.4g} K"




# Hydrogen's default fields above, carried to other fluids (``default_domain``): the same storage
# pressures, the vapour up to this multiple of T_sat(p_max) (hydrogen: 50 K over 30.1 K) and the
# liquid down to this share of the way from the triple point to T_sat(p_min) (hydrogen: 17 K).
_T_V_MAX_OF_T_SAT = 1.66
_T_L_MIN_SHARE = 0.6
# The wide and the low tier take the liquid down to this share of the way from the triple point
# to saturation at their lowest pressure (hydrogen's wide tier: 15.1 K at 0.32 bar).
_T_L_MIN_SHARE_LOW_P = 0.4
# Both tiers start at least this multiple of the triple-point pressure: argon, krypton and
# xenon boil at 1 atm only 1.2-1.5 times their triple-point pressure, so their tanks store liquid
# within a few kelvin of freezing (argon: 87.3 K at 1 atm, triple point 83.8 K at 0.69 bar).
_P_MIN_OF_TRIPLE = 1.05
_HYDROGENS = ("ParaHydrogen", "Hydrogen", "OrthoHydrogen")


def _margin_K(fluid_name: str, p_min_Pa: float, p_max_Pa: float) -> float:
    """``Domain.metastable_K``, or less where the fluid's single-phase branches end sooner at
    either end of the pressures, floored to 0.01 K."""
    margin = min(Domain.metastable_K, _max_metastable_K(fluid_name, float(p_min_Pa)),
                 _max_metastable_K(fluid_name, float(p_max_Pa)))
    return math.floor(margin * 100.0) / 100.0


def default_domain(fluid_name: str = "ParaHydrogen") -> Domain:
    """The default (first) tier for ``fluid_name``: storage tanks' pressures and temperatures.

    Hydrogen (para, normal, ortho) gets ``Domain``'s defaults. Another fluid (nitrogen, methane,
    oxygen, argon, ...) gets the same pressures, 0.7 to 6 bar, kept within 1.05 times its
    triple-point and half its critical pressure, the vapour up to 1.66 ``T_sat(p_max)`` and the liquid down to 60 %
    of the way from its triple point to ``T_sat(p_min)`` (hydrogen's fields in those terms), with
    the metastable margin of 1.8 K or less where its single-phase branches end sooner.
    """
    if fluid_name in _HYDROGENS:
        return Domain(fluid_name=fluid_name)
    lim = _fluid_limits(fluid_name)
    p_min = max(Domain.p_min_Pa, _P_MIN_OF_TRIPLE * lim["p_triple"])
    p_max = min(Domain.p_max_Pa, 0.5 * lim["p_crit"])
    if not p_min < p_max:
        raise ValueError(f"{fluid_name}: no storage pressures between {_P_MIN_OF_TRIPLE:g} times its triple-point "
                         f"pressure ({_P_MIN_OF_TRIPLE * lim['p_triple']:.4g} Pa) and half its critical pressure ({0.5 * lim['p_crit']:.4g} Pa)")
    T_sat_lo, T_sat_hi = _T_sat(fluid_name, float(p_min)), _T_sat(fluid_name, float(p_max))
    return Domain(p_min_Pa=p_min, p_max_Pa=p_max, T_v_max_K=min(_T_V_MAX_OF_T_SAT * T_sat_hi, lim["T_max"]),
                  T_l_min_K=lim["T_triple"] + _T_L_MIN_SHARE * (T_sat_lo - lim["T_triple"]),
                  metastable_K=_margin_K(fluid_name, p_min, p_max), fluid_name=fluid_name)


# The wide tier, as fractions of the fluid's critical point: ParaHydrogen 0.32 to 11.1 bar and
# vapour up to 82 K, beyond the pressures of any storage tank's relief setting and below the
# critical region, where the liquid's metastable branch (and so the margin) shrinks to nothing.
WIDE_P_MIN_OF_CRIT = 0.025
WIDE_P_MAX_OF_CRIT = 0.86
WIDE_T_V_MAX_OF_CRIT = 2.5


def wide_domain(fluid_name: str = "ParaHydrogen") -> Domain:
    """The widest domain tankode fits for ``fluid_name`` (constants above).

    The metastable margin is the default's (1.8 K) where the fluid allows it and narrows towards
    the critical point: 70 % of the smallest share of ``T_crit - T_sat`` that the spinodals leave
    over the domain's pressures (ParaHydrogen: 0.17, so 1.8 K up to 2.5 bar, 0.18 K at 11 bar;
    CoolProp's density solver fails nearer the spinodal than its branch test says).
    """
    lim = _fluid_limits(fluid_name)
    p_min = max(WIDE_P_MIN_OF_CRIT * lim["p_crit"], _P_MIN_OF_TRIPLE * lim["p_triple"])
    p_max = WIDE_P_MAX_OF_CRIT * lim["p_crit"]
    shares = [_max_metastable_K(fluid_name, float(p)) / (lim["T_crit"] - _T_sat(fluid_name, float(p)))
              for p in np.linspace(p_min, p_max, 8)]
    T_l_min = lim["T_triple"] + _T_L_MIN_SHARE_LOW_P * (_T_sat(fluid_name, float(p_min)) - lim["T_triple"])
    return Domain(p_min_Pa=p_min, p_max_Pa=p_max, T_v_max_K=min(WIDE_T_V_MAX_OF_CRIT * lim["T_crit"], lim["T_max"]),
                  T_l_min_K=T_l_min, metastable_K=Domain.metastable_K, fluid_name=fluid_name,
                  metastable_share=math.floor(0.7 * min(shares) * 1000.0) / 1000.0)


# The low tier reaches this share of the default tier's lowest pressure (ParaHydrogen and most
# fluids: 0.233 bar), up to the default's highest: a vent below 0.7 bar of a fluid whose wide tier
# starts above it (2.5 % of p_crit is 1.15 bar for methane, 0.85 bar for nitrogen). One
# saturation polynomial does not hold from there up to the wide tier's top (methane 0.35 to 40
# bar: 8e-4 at degree 20, against its 1e-4 tolerance); over this range it does.
LOW_P_MIN_OF_DEFAULT = 1.0 / 3.0


def low_domain(fluid_name: str = "ParaHydrogen") -> Domain:
    """The low-pressure tier for ``fluid_name``: the default tier reaching down to a third of its
    lowest pressure (no lower than 1.05 times the triple point), the liquid down to 40 % of the
    way from the triple point to saturation there (as the wide tier), the default's top.

    For a run vented or drained below the default tier that the wide tier does not hold
    (``surrogate_covering`` tries default, wide, then low). Fitted with ``WIDE_CONFIG``: held-out
    errors of 1e-4 or less in p, T and saturation for hydrogen, nitrogen, oxygen, methane, argon.
    """
    d = default_domain(fluid_name)
    lim = _fluid_limits(fluid_name)
    p_min = max(LOW_P_MIN_OF_DEFAULT * d.p_min_Pa, _P_MIN_OF_TRIPLE * lim["p_triple"])
    return replace(d, p_min_Pa=p_min,
                   T_l_min_K=lim["T_triple"] + _T_L_MIN_SHARE_LOW_P * (_T_sat(fluid_name, float(p_min)) - lim["T_triple"]),
                   metastable_K=_margin_K(fluid_name, p_min, d.p_max_Pa))


# The hot tier's vapour reaches this temperature (K), or the wide tier's top where that is higher
# (methane 476 K, oxygen 386 K): warm-gas pressurisation with ambient-temperature gas (300 K)
# injected into a small ullage, with the room ``covers`` asks. The wide tier's vapour stops at 2.5
# T_crit, 83 K for hydrogen: a model whose ullage overshoots a measured 52 K under 300 K gas
# (another simulator's tank) left it.
HOT_T_V_MAX_K = 350.0


def hot_domain(fluid_name: str = "ParaHydrogen") -> Domain:
    """The hot tier for ``fluid_name``: the wide tier with its vapour up to ``HOT_T_V_MAX_K``
    (or the fluid's EOS limit, if lower).

    Equal to the wide tier where that already reaches ``HOT_T_V_MAX_K`` (``property_tiers`` then
    leaves it out). Fitted with ``HOT_CONFIG``: six times the default's RBF centres over a vapour
    band ten times as wide; ParaHydrogen's held-out errors are 0.2 % in the vapour's p and T (the
    0.1 % target missed by 2x, a warning at the fit) and within the targets in the liquid.
    """
    wide = wide_domain(fluid_name)
    T_max = _fluid_limits(fluid_name)["T_max"]
    return replace(wide, T_v_max_K=max(wide.T_v_max_K, min(HOT_T_V_MAX_K, T_max)))


def covers(domain: Domain, p_Pa, T_v_K, T_l_K, share: float = 0.05, relative: bool = False) -> bool:
    """Whether ``domain`` holds the pressures and temperatures a run reaches, with room to spare.

    ``p_Pa``, ``T_v_K``, ``T_l_K``: the values seen (measured or initial), any iterables; NaN
    are ignored. The room is ``share`` of the domain's pressure range at each end, the same
    share of the vapour's temperature range below ``T_v_max_K`` and 0.5 K above ``T_l_min_K``.
    ``relative``: the pressure room is ``share`` of the pressure at each end instead, for the
    wide tier, whose range is 35 times the default's: a share of it (0.54 bar for ParaHydrogen)
    would exceed the lowest pressure it holds (0.32 bar) and turn away a vent to 0.5 bar.
    """
    p = np.asarray([x for x in np.ravel(np.asarray(p_Pa, float)) if np.isfinite(x)])
    Tv = np.asarray([x for x in np.ravel(np.asarray(T_v_K, float)) if np.isfinite(x)])
    Tl = np.asarray([x for x in np.ravel(np.asarray(T_l_K, float)) if np.isfinite(x)])
    if relative:
        lo, hi = domain.p_min_Pa * (1 + share), domain.p_max_Pa * (1 - share)
    else:
        dp = share * (domain.p_max_Pa - domain.p_min_Pa)
        lo, hi = domain.p_min_Pa + dp, domain.p_max_Pa - dp
    ok = p.size == 0 or (p.min() >= lo and p.max() <= hi)
    ok &= Tv.size == 0 or Tv.max() <= domain.T_v_max_K - share * (domain.T_v_max_K - domain.T_l_min_K)
    ok &= Tl.size == 0 or Tl.min() >= domain.T_l_min_K + 0.5
    return bool(ok)


__all__ = ["Domain", "default_domain", "wide_domain", "low_domain", "hot_domain", "covers"]
