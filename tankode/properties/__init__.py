"""Fluid properties for the 0D tank model: CoolProp reference and a fast differentiable surrogate.

``CoolPropFluid`` is the (slow, numpy) ground truth. ``Surrogate`` gives each phase's pressure,
temperature, pressure derivatives, saturation state and transport/caloric properties as torch
functions of (u, rho), fitted to CoolProp (``fit_surrogate``) and cached on disk
(``load_surrogate``); ``benchmark_surrogate`` measures its error and speed on held-out points.
"""

from .benchmark import benchmark_surrogate
from .coolprop import CoolPropFluid
from .surrogate import (WIDE_CONFIG, Domain, PhaseProps, Surrogate, SurrogateConfig, fit_surrogate, load_surrogate,
                        surrogate_covering, property_tiers, default_domain, wide_domain, low_domain, hot_domain,
                        HOT_CONFIG)

__all__ = [
    "CoolPropFluid", "Domain", "SurrogateConfig", "Surrogate", "PhaseProps", "fit_surrogate", "load_surrogate",
    "benchmark_surrogate", "surrogate_covering", "property_tiers", "default_domain", "wide_domain",
    "low_domain", "hot_domain", "WIDE_CONFIG", "HOT_CONFIG",
]
