"""Public face of the property surrogate: configuration, model, fitting and cached loading.

The pieces live in one-concept modules (``domain``, ``config``, ``model``, ``fit``, ``cache``);
this module gathers them under the names of the design (Marques, Ahizi & Mendez, section 3:
Peng-Robinson pressure and first-order Taylor temperature corrected by RBF interpolants in
min-max scaled (u, rho), one per phase).
"""

from .cache import HOT_CONFIG, WIDE_CONFIG, load_surrogate, property_tiers, surrogate_covering
from .config import SurrogateConfig
from .domain import Domain, default_domain, hot_domain, low_domain, wide_domain
from .fit import fit_surrogate
from .model import PhaseProps, Surrogate

__all__ = ["WIDE_CONFIG", "Domain", "SurrogateConfig", "Surrogate", "PhaseProps", "fit_surrogate", "load_surrogate", "surrogate_covering",
           "property_tiers", "default_domain", "wide_domain", "low_domain", "hot_domain", "HOT_CONFIG"]
