"""The 0D three-control-volume tank model: ullage vapour, liquid, wall (paper, section 2).

Balances, for the state ``s = [m_v, m_l, u_v, u_l, T_w, V_v, V_l]`` (``tankode.state``) and a
common pressure ``p`` (the ullage pressure; hydrostatics neglected)::

    dm_v/dt      = mdot_v_in - mdot_v_out + J
    dm_l/dt      = mdot_l_in - mdot_l_out - J
    d(m_v u_v)/dt = mdot_v_in h_v_in - mdot_v_out h_v + J h_v,sat + Q_wv - Q_vi - p dV_v/dt
    d(m_l u_l)/dt = mdot_l_in h_l_in - mdot_l_out h_l - J h_l,sat + Q_wl - Q_li - p dV_l/dt
    C_w dT_w/dt  = Q_aw - Q_wv - Q_wl
    dV_l/dt = -dV_v/dt = W

with the heat flows ``Q_vi = h_vi A_i (T_v - T_sat)``, ``Q_li = h_li A_i (T_l - T_sat)`` (into
the interface), ``Q_wv = h_wv A_wv (T_w - T_v)``, ``Q_wl = h_wl A_wl (T_w - T_l)`` (out of the
wall), ``T_sat = T_sat(p)`` and ``theta = (h_vi, h_li, h_wv, h_wl) = g(s; w)`` from the closure.

Phase change. The interface is massless and held at saturation, so it stores no energy: the
heat reaching it, ``Q_vi + Q_li``, evaporates liquid at the rate ``J = (Q_vi + Q_li) / L_v``
with ``L_v = h_v,sat - h_l,sat``. Evaporated mass leaves the liquid at ``h_l,sat`` and enters
the vapour at ``h_v,sat``; condensate (``J < 0``) leaves the vapour at ``h_v,sat`` and enters
the liquid at ``h_l,sat``. Then ``d/dt (m_v u_v + m_l u_l + C_w T_w)`` equals exactly the
enthalpy carried by the external flows plus ``Q_aw``: total mass and energy are conserved.

Departures from the printed paper. Its balances have two slips, in the sign of the
phase-change flux and in the enthalpy the condensate carries; implemented literally they make
heat arriving at the interface condense vapour and let the interface create or destroy energy.
tankode uses the thermodynamically consistent form above: heat reaching the interface
evaporates (``J > 0``), so a superheated ullage over a subcooled liquid condenses only when the
liquid side draws more heat than the vapour side brings, and the phase-change mass carries the
saturation enthalpies on both sides, so the interface energy balance closes exactly
(``tests/test_model.py`` checks conservation and the direction of phase change).

Volume split. Both phases share ``p``, so ``W = dV_l/dt`` is the rate that keeps
``dp_l/dt = dp_v/dt`` given the surrogate's ``dp/du`` and ``dp/drho`` of each phase (an index
reduction of the algebraic constraint ``p_l(u_l, rho_l) = p_v(u_v, rho_v)``). This needs no
liquid compressibility parameter and keeps ``V_v + V_l`` equal to the tank volume exactly.
Only the derivative of the constraint is enforced, so a constant offset between the
surrogate's liquid and vapour pressures (its fitting error) does not perturb the dynamics.

Bulk phase change. Beyond a metastable threshold past saturation, the ullage forms fog and the
liquid flashes in their volumes (``tankode.bulk``), conserving mass and energy; the printed
paper has no such term. The liquid boils past saturation at the pressure it bears
(``boiling_point_K``): with an inert gas in the ullage that is the total pressure, while the
interface stays at saturation of the fluid's partial pressure.

Mechanisms. Effects the baseline leaves out (``tankode.mechanisms``: heat leaks, unmetered
losses, sensor biases, ...) enter through hooks: the forcing actually applied, extra heat into
each control volume (added to ``e_v``, ``e_l`` and the wall balance, so conservation holds with
them as external inputs), a liquid surface warmer than the bulk in ``Q_li``, liquid flashing
beside the bulk's, a factor on
``C_w`` and an offset in the observed pressure. A mechanism may also carry states of its own
(a surface layer's temperature excess), integrated with the tank's: the model's state is then
``(env, 7 + n)``, the mechanisms' states after the 7 of ``tankode.state``. With every parameter
at 0 the model is the baseline exactly.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor, nn

from .bulk import BulkPhaseChange
from .closures.base import Closure, ClosureInputs
from .errors import ImpossibleState
from .forcing import Forcing
from .mechanisms import Mechanism, Start
from .state import N_STATE, STATE_NAMES


class Fluxes(NamedTuple):
    """Every term of the balances at one state, each ``(env,)``, SI units (W, kg/s, Pa, K, m)."""

    p_v_Pa: Tensor
    T_v_K: Tensor
    T_l_K: Tensor
    T_sat_K: Tensor
    H_l_m: Tensor
    A_i_m2: Tensor
    theta_W_m2K: Tensor  # (env, 4)
    Q_vi_W: Tensor
    Q_li_W: Tensor
    Q_wv_W: Tensor
    Q_wl_W: Tensor
    A_wv_m2: Tensor
    A_wl_m2: Tensor
    L_c_m: Tensor  # length of the liquid line on the wall (the interface's perimeter)
    J_evap_kg_s: Tensor
    h_v_J_per_kg: Tensor
    h_l_J_per_kg: Tensor
    h_vsat_J_per_kg: Tensor
    h_lsat_J_per_kg: Tensor
    dA_wl_dH_m: Tensor  # wetted wall area gained per metre of level rise
    C_w_J_per_K: Tensor  # the wall's heat capacity (the mechanisms' factors included)


class TankModel(nn.Module):
    """Right-hand side f(t, s; theta) of the tank model, batched over environments.

    Args:
        fluid: a property surrogate with ``vapor(u, rho)`` and ``liquid(u, rho)`` returning
            ``PhaseProps`` (``tankode.properties.Surrogate``).
        geometry: a ``TankGeometry`` whose dimensions are 0-d or shaped ``(env,)``.
        closure: the closure module theta = g(s; w).
        wall_heat_capacity_J_per_K: m_w c_w, scalar or ``(env,)`` (J/K); the nominal value
            (a ``wall_heat_capacity_error`` mechanism multiplies it).
        mechanisms: extra physical effects (``tankode.mechanisms``), none by default.
        bulk: fog in a subcooled ullage and flash in a superheated liquid beyond a metastable
            threshold (``tankode.bulk.BulkPhaseChange``); None turns it off.

    Call ``model(t, s, forcing)`` with ``s`` of shape ``(env, n_state)`` to get ``ds/dt`` of the
    same shape; ``n_state`` is 7 plus the mechanisms' own states (``state_names``).
    """

    def __init__(self, fluid, geometry, closure: Closure, wall_heat_capacity_J_per_K, mechanisms=(),
                 bulk: BulkPhaseChange | None = BulkPhaseChange()):
        super().__init__()
        self.bulk = bulk
        mechanisms = tuple(mechanisms)
        for m in mechanisms:
            if not isinstance(m, Mechanism):
                raise TypeError(f"mechanisms must be tankode.mechanisms.Mechanism instances, got {type(m).__name__}")
        ids = [m.id for m in mechanisms]
        if len(set(ids)) != len(ids):
            raise ValueError(f"each mechanism may appear once, got {ids}")
        self.mechanisms = nn.ModuleList(mechanisms)
        # Those that put an inert gas in the ullage (boiling_point_K, on every right-hand side).
        self._inert = tuple(m for m in mechanisms if type(m).inert_pressure_Pa is not Mechanism.inert_pressure_Pa)
        self.fluid = fluid
        self.geometry = geometry
        self.closure = closure
        cw = torch.as_tensor(wall_heat_capacity_J_per_K, dtype=torch.float64)
        if not torch.isfinite(cw).all() or (cw <= 0).any():
            raise ValueError(f"wall_heat_capacity_J_per_K must be positive and finite, got {cw}")
        self.register_buffer("wall_heat_capacity_J_per_K", cw)
        # Column ranges of each mechanism's own states in s, after the tank's 7.
        edges = [N_STATE]
        for m in mechanisms:
            edges.append(edges[-1] + len(m.states))
        self._state_slices = tuple(zip(edges[:-1], edges[1:]))

    def on(self, fleet) -> "TankModel":
        """This model's closure, mechanisms and bulk phase change on ``fleet``'s tanks (their fluid,
        geometry and wall heat capacities): a shard of a fleet, or copies of its tanks. The
        parameters are shared, not copied, so gradients reach this model's."""
        return TankModel(fleet.fluid, fleet.geometry, self.closure, fleet.wall_heat_capacity_J_per_K,
                         self.mechanisms, bulk=self.bulk)

    @property
    def n_state(self) -> int:
        """Length of the state vector: 7 plus the mechanisms' own states."""
        return self._state_slices[-1][1] if self._state_slices else N_STATE

    @property
    def state_names(self) -> tuple[str, ...]:
        """Names of the state's components: ``tankode.state.STATE_NAMES``, then ``<mechanism>.<state>``."""
        return STATE_NAMES + tuple(f"{m.id}.{v.name}" for m in self.mechanisms for v in m.states)

    @property
    def extra_state_scales(self) -> tuple[float, ...]:
        """The solver's unit of each mechanism state (``StateVar.scale``), in state order."""
        return tuple(v.scale for m in self.mechanisms for v in m.states)

    def mechanism_states(self, s: Tensor) -> list[Tensor]:
        """Each mechanism's own states ``(..., n_states)`` from the model state ``s`` ``(..., n_state)``."""
        if s.shape[-1] != self.n_state:
            raise ValueError(f"state has {s.shape[-1]} components, this model has {self.n_state} "
                             f"({', '.join(self.state_names)})")
        return [s[..., a:b] for a, b in self._state_slices]

    def initial_state(self, s0: Tensor) -> Tensor:
        """The model state ``(env, n_state)``: the tank's ``s0`` ``(env, 7)`` and the mechanisms' initial states."""
        if s0.shape[-1] != N_STATE:
            raise ValueError(f"tank state must have {N_STATE} components, got {tuple(s0.shape)}")
        if not self.mechanisms:
            return s0
        m_l, u_l, V_l = s0[..., 1], s0[..., 3], s0[..., 6]
        A_wl, A_wv = self.geometry.wetted_areas_m2(self.geometry.level_at_volume(V_l))
        start = Start(T_l_K=self.fluid.liquid(u_l, m_l / V_l).T, A_wv_m2=A_wv, A_wl_m2=A_wl)
        return torch.cat([s0, *(m.initial_state(s0, start) for m in self.mechanisms)], dim=-1)

    def closure_inputs(self, s: Tensor, forcing: Forcing) -> ClosureInputs:
        """What the closure sees at state ``s`` ``(env, n_state)`` under the applied ``forcing``."""
        m_v, m_l, u_v, u_l, T_w, V_v, V_l = s[..., :N_STATE].unbind(-1)
        rho_v = m_v / V_v
        rho_l = m_l / V_l
        pv = self.fluid.vapor(u_v, rho_v)
        pl = self.fluid.liquid(u_l, rho_l)
        g = self.geometry
        H_l = g.level_at_volume(V_l)
        T_wv = T_wl = None
        if self.mechanisms:  # the wetted areas once, not per mechanism (a right-hand side's hot path)
            A_wl, A_wv = g.wetted_areas_m2(H_l)
            for m, z in zip(self.mechanisms, self.mechanism_states(s)):
                offsets = m.wall_node_offsets_K(z, A_wv, A_wl)
                if offsets is not None:
                    T_wv, T_wl = T_w + offsets[0], T_w + offsets[1]
        return ClosureInputs(
            T_v_K=pv.T, T_l_K=pl.T, T_w_K=T_w, T_sat_K=pv.T_sat, rho_v_kg_m3=rho_v, rho_l_kg_m3=rho_l,
            vapor=pv, liquid=pl, H_l_m=H_l, radius_m=g.radius_m.expand_as(H_l),
            aspect_ratio=g.aspect_ratio.expand_as(H_l),
            slosh_amplitude_m=forcing.slosh_amplitude_m, slosh_frequency_Hz=forcing.slosh_frequency_Hz,
            m_v_kg=m_v, m_l_kg=m_l, mdot_v_in_kg_s=forcing.mdot_v_in_kg_s, mdot_v_out_kg_s=forcing.mdot_v_out_kg_s,
            mdot_l_in_kg_s=forcing.mdot_l_in_kg_s, mdot_l_out_kg_s=forcing.mdot_l_out_kg_s,
            T_wv_K=T_wv, T_wl_K=T_wl,
        )

    def fluxes(self, s: Tensor, forcing: Forcing) -> tuple[Fluxes, object, object]:
        """All heat and mass flows at state ``s`` ``(env, n_state)``; also the two phases' properties."""
        m_v, m_l, u_v, u_l, T_w, V_v, V_l = s[..., :N_STATE].unbind(-1)
        x = self.closure_inputs(s, forcing)
        pv, pl, H_l, T_sat = x.vapor, x.liquid, x.H_l_m, x.T_sat_K
        rho_v, rho_l = x.rho_v_kg_m3, x.rho_l_kg_m3
        p = pv.p
        g = self.geometry
        A_i = g.interface_area_m2(H_l)
        A_wl, A_wv = g.wetted_areas_m2(H_l)
        theta = self.closure(x)
        h_vi, h_li, h_wv, h_wl = theta.unbind(-1)
        zs = self.mechanism_states(s)
        dT_surface = sum((m.interface_offset_K(z) for m, z in zip(self.mechanisms, zs)), 0.0)
        Q_vi = h_vi * A_i * (pv.T - T_sat)
        Q_li = h_li * A_i * (pl.T + dT_surface - T_sat)
        Q_wv = h_wv * A_wv * (T_w - pv.T)
        Q_wl = h_wl * A_wl * (T_w - pl.T)
        J = (Q_vi + Q_li) / (pv.h_vsat - pv.h_lsat)
        f = Fluxes(
            p_v_Pa=p, T_v_K=pv.T, T_l_K=pl.T, T_sat_K=T_sat, H_l_m=H_l, A_i_m2=A_i, theta_W_m2K=theta,
            Q_vi_W=Q_vi, Q_li_W=Q_li, Q_wv_W=Q_wv, Q_wl_W=Q_wl, A_wv_m2=A_wv, A_wl_m2=A_wl,
            L_c_m=g.contact_line_m(H_l), J_evap_kg_s=J,
            h_v_J_per_kg=u_v + p / rho_v, h_l_J_per_kg=u_l + p / rho_l,
            h_vsat_J_per_kg=pv.h_vsat, h_lsat_J_per_kg=pv.h_lsat,
            dA_wl_dH_m=g.wetted_area_slope_m(H_l),
            C_w_J_per_K=torch.as_tensor(self.effective_wall_heat_capacity_J_per_K).expand_as(H_l),
        )
        return f, pv, pl

    def applied_forcing(self, forcing: Forcing) -> Forcing:
        """The operations actually applied: the metered ``forcing`` as the mechanisms change it."""
        for m in self.mechanisms:
            forcing = m.adjust_forcing(forcing)
        return forcing

    def extra_heat_W(self, s: Tensor, forcing: Forcing, fluxes: Fluxes):
        """Mechanisms' heat into (vapour, liquid, wall), W, each broadcastable to ``(env,)``.

        ``s`` is the model state ``(env, n_state)``, ``forcing`` the applied forcing and
        ``fluxes`` the baseline's flows at ``s``.
        """
        q_v = q_l = q_w = 0.0
        base = s[..., :N_STATE]
        for m, z in zip(self.mechanisms, self.mechanism_states(s)):
            a, b, c = m.heat_W(base, forcing, fluxes, z)
            q_v, q_l, q_w = q_v + a, q_l + b, q_w + c
        return q_v, q_l, q_w

    @property
    def effective_wall_heat_capacity_J_per_K(self) -> Tensor:
        """m_w c_w times the mechanisms' factors (J/K)."""
        cw = self.wall_heat_capacity_J_per_K
        for m in self.mechanisms:
            cw = cw * m.wall_capacity_factor()
        return cw

    def boiling_point_K(self, vapor, V_v_m3: Tensor) -> Tensor:
        """The liquid's bulk boiling point ``(env,)`` (K): saturation at the pressure it bears, the
        fluid's (``vapor.T_sat``) plus the mechanisms' inert partial pressures (``inert_pressure_Pa``)."""
        if not self._inert:
            return vapor.T_sat
        return self.fluid.saturation_K(vapor.p + sum(m.inert_pressure_Pa(vapor.T, V_v_m3) for m in self._inert))

    def pressure_offset_Pa(self, T_v_K: Tensor, V_v_m3: Tensor):
        """Sensor pressure minus hydrogen pressure from the mechanisms (Pa), shaped like ``T_v_K``."""
        return sum((m.pressure_offset_Pa(T_v_K, V_v_m3) for m in self.mechanisms), torch.zeros_like(T_v_K))

    def liquid_temperature_offset_K(self, T_l_K: Tensor):
        """Liquid thermometer reading minus the liquid's temperature from the mechanisms (K), shaped like ``T_l_K``."""
        return sum((m.liquid_temperature_offset_K(T_l_K) for m in self.mechanisms), torch.zeros_like(T_l_K))

    def _impossible(self, base: Tensor) -> None:
        """Raise ``ImpossibleState`` where the tank cannot go on: no ullage, no liquid, a wall at 0 K."""
        with torch.no_grad():
            m_v, m_l, _, _, T_w, V_v, V_l = base.unbind(-1)
            for bad, kind, say in (
                ((V_v <= 0) | (m_v <= 0), "ullage",
                 lambda e: f"the ullage vanished (vapour volume {float(V_v[e]):.3g} m3, mass {float(m_v[e]):.3g} kg): "
                           "the liquid filled the tank"),
                ((V_l <= 0) | (m_l <= 0), "dry",
                 lambda e: f"the tank ran dry (liquid volume {float(V_l[e]):.3g} m3, mass {float(m_l[e]):.3g} kg)"),
                (~(T_w > 0), "wall", lambda e: f"the wall temperature fell to {float(T_w[e]):.4g} K"),
            ):
                if bool(bad.any()):
                    e = int(bad.nonzero()[0, 0])
                    raise ImpossibleState(say(e), kind, e)

    def _far_outside(self, pv, pl) -> None:
        """Raise ``ImpossibleState`` where a phase is far beyond the property surrogate's domain.

        Both phases are judged at the ullage's pressure and saturation temperature: the liquid's
        own ``p(u, rho)`` is steep (a solver's trial stage moves it by bars), and the dynamics use
        only its derivatives (module docstring).
        """
        with torch.no_grad():
            for phase, props in (("vapor", pv), ("liquid", pl)):
                bad = self.fluid.far_outside(phase, pv.p, props.T, pv.T_sat)
                if bool(bad.any()):
                    e = int(bad.nonzero()[0, 0])
                    d = self.fluid.domain
                    raise ImpossibleState(
                        f"the {phase} reached p = {float(pv.p[e]):.4g} Pa, T = {float(props.T[e]):.4g} K "
                        f"(saturation {float(pv.T_sat[e]):.4g} K), beyond the property domain fitted for "
                        f"{d.p_min_Pa:.4g} to {d.p_max_Pa:.4g} Pa (the vapour up to {d.T_v_max_K:.4g} K, "
                        f"{float(d.margin_K(pv.T_sat[e])):.2g} K past saturation on either side here)", "domain", e)

    def forward(self, t: Tensor, s: Tensor, forcing: Forcing) -> Tensor:
        base = s[..., :N_STATE]  # (env, 7): the tank's part; mechanisms' own states follow it
        m_v, m_l, u_v, u_l, T_w, V_v, V_l = base.unbind(-1)
        self._impossible(base)
        fc = self.applied_forcing(forcing)
        f, pv, pl = self.fluxes(s, fc)
        if hasattr(self.fluid, "far_outside"):  # analytic test fluids have no fitted domain
            self._far_outside(pv, pl)
        q_v, q_l, q_w = self.extra_heat_W(s, fc, f)
        p, J = f.p_v_Pa, f.J_evap_kg_s
        dm_v = fc.mdot_v_in_kg_s - fc.mdot_v_out_kg_s + J
        dm_l = fc.mdot_l_in_kg_s - fc.mdot_l_out_kg_s - J
        # Energy inflow to each phase except the volume work -p dV/dt.
        e_v = (fc.mdot_v_in_kg_s * fc.h_v_in_J_per_kg - fc.mdot_v_out_kg_s * f.h_v_J_per_kg
               + J * f.h_vsat_J_per_kg + f.Q_wv_W - f.Q_vi_W + q_v)
        e_l = (fc.mdot_l_in_kg_s * fc.h_l_in_J_per_kg - fc.mdot_l_out_kg_s * f.h_l_J_per_kg
               - J * f.h_lsat_J_per_kg + f.Q_wl_W - f.Q_li_W + q_l)
        fog, flash = 0.0, 0.0
        T_boil = self.boiling_point_K(pv, V_v)
        if self.bulk is not None:
            domain = getattr(self.fluid, "domain", None)  # analytic test fluids have none
            fog, flash = self.bulk.rates_kg_s(m_v, m_l, pv, pl,
                                              None if domain is None else torch.as_tensor(domain.margin_K(pv.T_sat.detach())),
                                              T_boil)
        zs = self.mechanism_states(s)
        for m, z in zip(self.mechanisms, zs):
            flash = flash + m.flash_kg_s(m_v, m_l, pv, pl, z, T_boil)
        # fog leaves the vapour as saturated liquid, flash the liquid as saturated vapour
        dm_v = dm_v - fog + flash
        dm_l = dm_l + fog - flash
        e_v = e_v - fog * f.h_lsat_J_per_kg + flash * f.h_vsat_J_per_kg
        e_l = e_l + fog * f.h_lsat_J_per_kg - flash * f.h_vsat_J_per_kg
        # dp/dt of each phase is affine in W = dV_l/dt: a + b W (see module docstring).
        rho_v = m_v / V_v
        rho_l = m_l / V_l
        a_v = pv.dp_du * (e_v - u_v * dm_v) / m_v + pv.dp_drho * dm_v / V_v
        b_v = pv.dp_du * p / m_v + pv.dp_drho * rho_v / V_v
        a_l = pl.dp_du * (e_l - u_l * dm_l) / m_l + pl.dp_drho * dm_l / V_l
        b_l = -pl.dp_du * p / m_l - pl.dp_drho * rho_l / V_l
        W = (a_v - a_l) / (b_l - b_v)
        du_v = (e_v + p * W - u_v * dm_v) / m_v
        du_l = (e_l - p * W - u_l * dm_l) / m_l
        dT_w = (fc.Q_aw_W + q_w - f.Q_wv_W - f.Q_wl_W) / self.effective_wall_heat_capacity_J_per_K
        ds = torch.stack([dm_v, dm_l, du_v, du_l, dT_w, -W, W], dim=-1)
        if self.n_state == N_STATE:
            return ds
        dz = [m.state_derivative(z, base, fc, f, pl, ds) for m, z in zip(self.mechanisms, zs)]
        return torch.cat([ds, *dz], dim=-1)

    def observe(self, s: Tensor) -> Tensor:
        """Observation operator h(s) = (p_v [Pa], T_v [K], T_l [K], T_w [K], H_l [m]), shape ``(..., 5)``.

        The pressure is what the sensor reads: the hydrogen pressure plus the mechanisms'
        offsets (a bias, an inert gas's partial pressure); the liquid temperature likewise
        (a thermometer's bias).
        """
        m_v, m_l, u_v, u_l, T_w, V_v, V_l = s[..., :N_STATE].unbind(-1)
        pv = self.fluid.vapor(u_v, m_v / V_v)
        pl = self.fluid.liquid(u_l, m_l / V_l)
        H_l = self.geometry.level_at_volume(V_l)
        p = pv.p + self.pressure_offset_Pa(pv.T, V_v)
        return torch.stack([p, pv.T, pl.T + self.liquid_temperature_offset_K(pl.T), T_w, H_l], dim=-1)

    def total_energy_J(self, s: Tensor) -> Tensor:
        """m_v u_v + m_l u_l + C_w T_w (J) for ``s`` shaped ``(env, n_state)`` or ``(env, time, n_state)``.

        A mechanism's own states redistribute energy within a control volume (a surface layer's
        excess is part of the liquid's ``u_l``), so they do not enter the total.
        """
        cw = torch.as_tensor(self.effective_wall_heat_capacity_J_per_K)
        if cw.dim() == 1 and s.dim() == 3:
            cw = cw[:, None]  # (env, 1) against (env, time)
        return s[..., 0] * s[..., 2] + s[..., 1] * s[..., 3] + cw * s[..., 4]


__all__ = ["TankModel", "Fluxes"]
