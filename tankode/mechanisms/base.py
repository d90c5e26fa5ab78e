"""The mechanism interface: a bounded physical effect, absent at 0, that plugs into the model.

A mechanism is something the baseline model leaves out (a heat leak, an unmetered loss, a
sensor bias, ...). Each has a few physical parameters with units and bounds; the value 0
means "absent", so the baseline model is the extended model at 0 and adding a mechanism is a
nested hypothesis (what the score test, the likelihood ratio and BIC of the diagnosis need).

It acts through hooks of ``TankModel``, each a no-op by default:

* ``adjust_forcing``: change the operations actually applied (unmetered leaks, meter bias);
* ``heat_W``: extra heat into the vapour, the liquid and the wall (W), which may depend on the
  state, the applied forcing and the baseline's flows (a redistribution sums to 0);
* ``interface_offset_K``: a liquid surface temperature above the bulk's at the interface;
* ``flash_kg_s``: liquid flashing to vapour beside the bulk's (``tankode.bulk``), leaving the
  liquid as saturated vapour;
* ``inert_pressure_Pa``: the partial pressure of an inert gas in the ullage, which the liquid
  bears: its bulk boils at saturation of the total pressure (a bubble inside it holds the fluid
  alone), its surface at saturation of the fluid's own (Dalton);
* ``state_derivative``: the rate of the mechanism's own states (``states``, e.g. a surface
  layer's temperature excess), which the model appends to the 7 of ``tankode.state``;
* ``wall_capacity_factor``: multiply m_w c_w;
* ``pressure_offset_Pa``: what the pressure sensor reads beyond the hydrogen's own pressure
  (a bias, an inert gas). The run's initial pressure is a sensor reading too, so the same
  offset is removed from it when the initial state is built (``Fleet.initial_state``).
* ``liquid_temperature_offset_K``: what the liquid thermometer reads beyond the liquid's
  temperature (a bias); removed from the initial reading likewise.
* ``initial_liquid_K``: the liquid's initial temperature from its (offset-corrected) reading
  and the saturation temperature at the initial pressure (a liquid that starts saturated).

Own states. A mechanism may carry ``states`` (a tuple of ``StateVar``) that the ODE integrates
with the tank's: the model's state is then ``(env, 7 + n)``, the mechanisms' states after the
tank's, in the order of the model's mechanisms. They start at ``initial_state`` (0: nothing
accumulated yet, unless an ``initial`` parameter says otherwise; it receives the ``Start``
of the tank: the liquid's temperature and the wetted and dry wall areas) and every hook that
may depend on them receives the mechanism's own slice ``z`` ``(env, n_states)`` (``(env, 0)``
for a mechanism without states). With every parameter at 0 a state must stay at 0, so that
the baseline is still the extended model at 0.

The first parameter is the mechanism's presence: at 0 the mechanism is absent whatever the
others, which only shape it (a surface layer's mixing rate); the diagnosis requires it, not the
shape parameters, to be resolved.

Parameters are a float64 buffer ``value``: ``(n_params,)``, shared by every environment of a
fleet (one tank observed in several runs), or ``(env, n_params)``, one row per environment (the
diagnosis integrates the perturbed copies of a finite-difference Jacobian as one batched ODE).
The diagnosis sets them by finite-difference Gauss-Newton; the assimilation keeps them fixed
while it trains the closure. Hooks read a parameter with ``self.param(i, like)``, which shapes
it to broadcast against a tensor ``like`` of shape ``(env,)`` or ``(env, time)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar, NamedTuple

import torch
from torch import Tensor, nn

from ..forcing import Forcing


@dataclass(frozen=True)
class Param:
    """One parameter of a mechanism.

    Attributes:
        name: identifier with its unit suffix (e.g. ``Q_W``).
        unit: SI unit, for reports.
        lower, upper: physical bounds (the box of the fit); 0 is inside or on the boundary.
        scale: a typical magnitude, the unit of the normalised fit variable and of its
            finite-difference step (the fit is scale-invariant otherwise).
        initial: the parameter sets only the mechanism's initial state (an unmeasured part of
            the tank's state at the first time stamp). The assimilation chooses it from the
            first window's data rather than training it with the weights: a window that starts
            from a carried state has no slope in it.
    """

    name: str
    unit: str
    lower: float
    upper: float
    scale: float
    initial: bool = False

    def __post_init__(self):
        if not (self.lower <= 0.0 <= self.upper and self.scale > 0 and math.isfinite(self.scale)):
            raise ValueError(f"parameter {self.name}: need lower <= 0 <= upper and scale > 0")


@dataclass(frozen=True)
class StateVar:
    """One state a mechanism adds to the ODE.

    Attributes:
        name: identifier with its unit suffix (e.g. ``dT_layer_K``).
        unit: SI unit, for reports and error messages.
        scale: a typical magnitude: the solver's unit for this component (``state_scale``).
    """

    name: str
    unit: str
    scale: float

    def __post_init__(self):
        if not (self.scale > 0 and math.isfinite(self.scale)):
            raise ValueError(f"state {self.name}: scale must be positive and finite, got {self.scale}")


class Start(NamedTuple):
    """What a mechanism's initial state may depend on besides the tank's state, each ``(env,)``."""

    T_l_K: Tensor
    A_wv_m2: Tensor  # the dry wall's area
    A_wl_m2: Tensor  # the wetted wall's area


class Mechanism(nn.Module):
    """Base class of a candidate mechanism (see the module docstring for the hooks).

    Subclasses set ``id``, ``params`` (a tuple of ``Param``) and ``signature`` (how it shows
    in the data), and override the hooks they act through. ``model_form`` is True for physics
    a tank has by its build (a dry wall that heats the ullage, a stratified liquid) rather than
    a fault (a leak, unmetered heat, a faulty sensor or meter, an inert gas, a wrong stated
    wall): the diagnosis reports such a mechanism as the model's form, never as a cause, since
    another simulator's or a real tank with nothing wrong has it (``tankode.diagnosis.verdict``).
    ``alternative_to`` names mechanisms that model the same physics another way (the dry wall
    as a massless node or as a node with heat capacity): the diagnosis does not test this one
    beside them, since the sum would count that physics twice.

    Args:
        **values: parameter values by name (SI units); missing ones are 0 (absent).

    Raises:
        ValueError: an unknown parameter name, or a value outside its bounds.
    """

    id: ClassVar[str] = ""
    params: ClassVar[tuple[Param, ...]] = ()
    signature: ClassVar[str] = ""
    states: ClassVar[tuple[StateVar, ...]] = ()
    model_form: ClassVar[bool] = False
    alternative_to: ClassVar[tuple[str, ...]] = ()

    def __init__(self, **values: float):
        super().__init__()
        unknown = set(values) - {p.name for p in self.params}
        if unknown:
            raise ValueError(f"mechanism {self.id!r} has no parameter(s) {sorted(unknown)}; "
                             f"its parameters: {[p.name for p in self.params]}")
        v = torch.tensor([float(values.get(p.name, 0.0)) for p in self.params], dtype=torch.float64)
        self.register_buffer("value", v)
        self.set_values(v)

    # -- parameters ------------------------------------------------------------------------

    def set_values(self, values) -> None:
        """Set all parameters (SI units), ``(n_params,)`` or ``(env, n_params)``, checking their bounds."""
        v = torch.as_tensor(values, dtype=torch.float64)
        if v.ndim not in (1, 2) or v.shape[-1] != len(self.params):
            raise ValueError(f"mechanism {self.id!r}: values must have shape ({len(self.params)},) or "
                             f"(env, {len(self.params)}), got {tuple(v.shape)}")
        for i, p in enumerate(self.params):
            for x in v[..., i].reshape(-1).tolist():
                if not (math.isfinite(x) and p.lower <= x <= p.upper):
                    unit = "" if p.unit == "1" else f" {p.unit}"  # "eps = -2 1" reads as two numbers
                    raise ValueError(f"mechanism {self.id!r}: {p.name} = {x:g}{unit} is outside its allowed "
                                     f"range [{p.lower:g}, {p.upper:g}]{unit}")
        self.value = v.clone()

    def values_dict(self) -> dict[str, float]:
        """Parameter values by name (SI units); for shared (1-D) values."""
        if self.value.ndim != 1:
            raise ValueError(f"mechanism {self.id!r} has per-environment values; no single value per parameter")
        return {p.name: float(x) for p, x in zip(self.params, self.value)}

    def param(self, i: int, like: Tensor | None = None) -> Tensor:
        """Parameter ``i``: a 0-d tensor, or ``(env,)`` shaped to broadcast against ``like`` ``(env, ...)``."""
        v = self.value[..., i]
        if v.ndim == 1 and like is not None and like.ndim > 1:
            v = v.reshape(-1, *([1] * (like.ndim - 1)))
        return v

    def extra_repr(self) -> str:
        if self.value.ndim != 1:
            return f"per-environment values of shape {tuple(self.value.shape)}"
        return ", ".join(f"{k}={v:.4g}" for k, v in self.values_dict().items())

    # -- hooks (no-ops) --------------------------------------------------------------------

    def adjust_forcing(self, forcing: Forcing) -> Forcing:
        """The operations actually applied, given the metered ones."""
        return forcing

    def heat_W(self, s: Tensor, forcing: Forcing, fluxes, z: Tensor) -> tuple[Tensor | float, Tensor | float,
                                                                            Tensor | float]:
        """Extra heat (W) into (vapour, liquid, wall) at state ``s`` ``(env, 7)`` and own states ``z``.

        ``forcing`` is the applied forcing and ``fluxes`` the baseline's ``tankode.model.Fluxes``
        at ``s`` (heat flows, wetted areas), for mechanisms that redistribute them.
        """
        return 0.0, 0.0, 0.0

    def wall_node_offsets_K(self, z: Tensor, A_wv_m2: Tensor, A_wl_m2: Tensor) -> tuple[Tensor, Tensor] | None:
        """How much warmer than the wall's mean ``T_w`` the dry and the wetted wall are (K),
        given own states ``z`` and the wetted areas ``(env,)``; None: the wall is one lump."""
        return None

    def interface_offset_K(self, z: Tensor) -> Tensor | float:
        """How much warmer than the bulk liquid the liquid at the interface is (K), given own states ``z``."""
        return 0.0

    def flash_kg_s(self, m_v: Tensor, m_l: Tensor, vapor, liquid, z: Tensor, T_boil_K: Tensor) -> Tensor | float:
        """Liquid flashing to vapour (kg/s, >= 0) beside the bulk's, from the phases' masses
        ``(env,)`` and properties, own states ``z`` and the liquid's boiling point ``T_boil_K``
        ``(env,)`` (saturation at the pressure the liquid bears: ``vapor.T_sat`` unless an inert
        gas adds to it, ``inert_pressure_Pa``)."""
        return 0.0

    def initial_state(self, s0: Tensor, start: Start) -> Tensor:
        """Own states ``(env, n_states)`` at the start, for the tank's initial state ``s0`` ``(env, 7)``
        (``start``: its liquid temperature and wall areas)."""
        return s0.new_zeros(s0.shape[0], len(self.states))

    def state_derivative(self, z: Tensor, s: Tensor, forcing: Forcing, fluxes, liquid, tank_rate: Tensor) -> Tensor:
        """d/dt of own states ``z`` ``(env, n_states)`` at tank state ``s`` ``(env, 7)``.

        ``fluxes`` is the model's ``tankode.model.Fluxes`` at ``s`` (with every mechanism's
        effect on them), ``liquid`` the liquid's ``PhaseProps`` and ``tank_rate`` the tank's own
        ``ds/dt`` ``(env, 7)`` (e.g. the level's motion, ``dV_l/dt``).
        """
        return z.new_zeros(z.shape)

    def wall_capacity_factor(self) -> Tensor | float:
        """Factor on the nominal m_w c_w."""
        return 1.0

    def pressure_offset_Pa(self, T_v_K: Tensor, V_v_m3: Tensor) -> Tensor | float:
        """Sensor pressure minus hydrogen pressure (Pa) for ullage temperature and volume ``(...)``."""
        return 0.0

    def inert_pressure_Pa(self, T_v_K: Tensor, V_v_m3: Tensor) -> Tensor | float:
        """Partial pressure (Pa) of gases other than the fluid in the ullage, for ullage temperature
        and volume ``(...)``: the liquid bears it, so its bulk boils at saturation of the fluid's
        pressure plus this, while the interface sits at saturation of the fluid's pressure alone."""
        return 0.0

    def liquid_temperature_offset_K(self, T_l_K: Tensor) -> Tensor | float:
        """Liquid thermometer reading minus the liquid's temperature (K) for liquid temperatures ``(...)``."""
        return 0.0

    def initial_liquid_K(self, T_l_K: Tensor, T_sat_K: Tensor) -> Tensor:
        """The liquid's initial temperature ``(env,)`` (K) from its initial reading (less any thermometer
        offset) and the saturation temperature at the initial pressure, both ``(env,)``."""
        return T_l_K


__all__ = ["Mechanism", "Param", "Start", "StateVar"]
