"""A warm surface layer that thickens by conduction into the bulk (a thermal penetration depth)."""

from __future__ import annotations

import math

from .base import Param
from .growing_layer import GrowingLayer

# A liquid at rest heated through its top with a steady flux q has the conduction profile of a
# semi-infinite body: surface excess 2 q sqrt(alpha t / pi) / k and heat content q t, i.e. those
# of a uniform layer of thickness (sqrt(pi) / 2) sqrt(alpha t), so delta^2 = (pi / 4) alpha t
# = 2 D t with D = (pi / 8) alpha (Carslaw & Jaeger, section 2.9).
TOP_HAT_DIFFUSIVITY = math.pi / 8.0


class DiffusiveLayer(GrowingLayer):
    """A warm surface layer fed by the wall's boundary layer that thickens by conduction into the bulk.

    Physics. As in ``growing_layer`` a share ``phi`` of the wetted wall's heat and the
    interface's own heat stay in a layer under the surface whose excess over the bulk is
    ``x`` and whose thickness ``delta`` grows, the grown liquid joining it at the bulk's
    temperature; but the layer grows the way a stably stratified warm layer does when nothing
    stirs it, by conduction into the cold liquid below, not by the boundary layer's delivery.
    A liquid at rest heated through its top has the heat content and surface excess of a
    uniform layer with ``delta^2 = delta_0^2 + 2 D t``, ``D = (pi/8) alpha_l`` for pure
    conduction (``alpha_l = k_l / (rho_l c_p,l)``, 1.5e-7 m^2/s for hydrogen at 20 K: a layer of
    about 3 cm after 5 h, 6 cm after 18 h). With a factor ``a`` on that diffusivity
    (``a = 1``: molecular conduction; ``a > 1``: eddies)::

        dE/dt = phi Q_wl - Q_li,      d delta/dt = a (pi/8) alpha_l / delta,

    ``E = rho_l c_p,l A_i delta x``, that is ``dx/dt = (phi Q_wl - Q_li) / C_s - x (d delta/dt) / delta``.
    The thickness then depends on the time since the liquid was last mixed (the run's start),
    not on the heat load or the fill: a long test at a low load has a thicker layer than a short
    one at a high load, in the ratio of the square roots of their durations.

    States (``growing_layer``'s): ``x`` (K) and ``delta - delta_0`` (m). Parameters: ``inv_thickness_1_per_m`` =
    1/delta_0 (presence: 0 = absent), ``wall_share`` = phi, ``diffusivity_factor`` = a.

    Signature: pressure above the model growing over hours, its rise slowing as the square
    root of time; bulk liquid temperature unchanged.

    Limits: the interface sees ``T_l + x`` with ``T_l`` the mass-averaged liquid (right while
    the layer is much thinner than the liquid); a uniform layer stands for the conduction
    profile (exact for the heat content and the surface excess under a steady flux, not under
    a varying one); no sloshing, boiling or fill erosion; the run's start is taken as the time
    the liquid was last mixed.

    On the MHTB self-pressurisation tests, fitted on the high-fill test the diffusivity factor
    comes out at molecular conduction (``a`` near 1), but the fit predicts the low-fill test
    worse than the layer of fixed thickness, and fitted on the low-fill test ``a`` goes to 0 (a
    fixed layer): the two tests do not share this growth law (figures in ``experiments/README.md``).
    """

    id = "diffusive_layer"
    params = (
        Param("inv_thickness_1_per_m", "1/m", 0.0, 1000.0, 50.0),
        Param("wall_share", "1", 0.0, 1.0, 0.1),
        Param("diffusivity_factor", "1", 0.0, 100.0, 1.0),
    )
    signature = "pressure above the model growing over hours, its rise slowing as sqrt(t), bulk liquid unchanged"

    def _growth(self, x, s, fluxes, liquid, inv_delta):
        """``d delta/dt = a (pi/8) alpha_l / delta`` (m/s), ``(env,)``."""
        alpha = liquid.k / (s[..., 1] / s[..., 6] * liquid.cp)  # m^2/s
        return self.param(2, x) * TOP_HAT_DIFFUSIVITY * alpha * inv_delta


__all__ = ["DiffusiveLayer", "TOP_HAT_DIFFUSIVITY"]
