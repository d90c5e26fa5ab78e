"""A batch of tanks, one per run, set up for one batched ODE: geometry, wall, fluid, inputs."""

from __future__ import annotations

import dataclasses

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from .errors import SimulationError
from .forcing import Forcing
from .geometry import stack_geometries
from .run import Run
from .mechanisms.base import Mechanism
from .schedule import INPUT_NAMES, merge_breakpoints
from .wall import WallHeatCapacity, resolve_wall_heat_capacity

_I = {name: i for i, name in enumerate(INPUT_NAMES)}


def _states_seen(runs) -> tuple[list[float], list[float], list[float]]:
    """Pressures, vapour and liquid temperatures the runs start at, measure or inject (the property
    domain must hold them): gas injected at ``T_v_in_K`` can bring the ullage towards that
    temperature (warm-gas pressurisation), whatever its sensor reads."""
    p, T_v, T_l = [], [], []
    mdot_in, T_in = INPUT_NAMES.index("mdot_v_in_kg_s"), INPUT_NAMES.index("T_v_in_K")
    for r in runs:
        p.append(r.initial.p_v_Pa)
        T_v.append(r.initial.T_v_K)
        T_l.append(r.initial.T_l_K)
        for seen, channel in ((p, "p_v_Pa"), (T_v, "T_v_K"), (T_l, "T_l_K")):
            seen.extend(r.observations.channel(channel)[1].tolist())
        if r.inputs is not None:
            rows = r.inputs.values
            T_v.extend(rows[rows[:, mdot_in] > 0, T_in].tolist())
    return p, T_v, T_l


def _may_hold(domain, p_Pa, T_v_K, T_l_K, T_sat_K) -> bool:
    """Whether ``domain`` may hold these states (arrays), with room for the estimates'
    extrapolation just past the current tier (1 % in pressure, 0.5 K in the vapour, 0.1 K in the
    liquid): a quick test before a tier is fitted (tens of seconds on first use); its
    surrogate's ``contains`` decides."""
    v_lo, v_hi = domain.T_bounds("vapor", T_sat_K)
    l_lo, l_hi = domain.T_bounds("liquid", T_sat_K)
    return bool(np.all((p_Pa >= 0.99 * domain.p_min_Pa) & (p_Pa <= 1.01 * domain.p_max_Pa)
                       & (T_v_K >= v_lo - 0.5) & (T_v_K <= v_hi + 0.5)
                       & (T_l_K >= l_lo - 0.1) & (T_l_K <= l_hi + 0.1)))


def sampling_interval_s(run) -> float:
    """A run's typical sampling interval (s): the median spacing of the times at which any channel
    was measured (0 for a run with fewer than two such times)."""
    t = run.observations.t_s[np.isfinite(run.observations.values).any(axis=1)]
    return float(np.median(np.diff(t))) if len(t) > 1 else 0.0



def _less(readings: Tensor, offsets) -> Tensor:
    """``readings`` ``(env,)`` less each of the mechanisms' ``offsets`` (floats, 0-d or ``(env,)`` tensors;
    a graph they carry is kept)."""
    for off in offsets:
        readings = readings - torch.as_tensor(off, dtype=torch.float64).expand(readings.shape)
    return readings


# Central-difference steps of the initial state's slopes (Fleet.initial_state): a relative step
# of the hydrogen pressure (1e-5: CoolProp's states are smooth to ~1e-12 relative, so the
# truncation and the rounding error both stay below 1e-8 of the slope) and one of the liquid
# reading (1e-4 K).
_START_STEPS = (1.0e-5, 1.0e-4)

@dataclass(frozen=True)
class Fleet:
    """Runs of one fluid integrated together as environments of a batched ODE.

    Build it with ``Fleet.from_runs(runs, surrogate)``. Tanks must share one shape (their
    dimensions may differ); runs may differ in length and inputs.

    Attributes:
        runs: the runs, one environment each.
        geometry: batched ``TankGeometry`` with ``(env,)`` dimensions.
        walls: each tank's ``WallHeatCapacity`` (given or estimated, with a note).
        fluid: the property surrogate used inside the ODE.
        reference: the CoolProp backend (initial states, inflow enthalpies).
    """

    runs: tuple[Run, ...]
    geometry: object
    walls: tuple[WallHeatCapacity, ...]
    fluid: object
    reference: object

    @staticmethod
    def from_runs(runs, surrogate=None) -> "Fleet":
        """Set up the batch; ``surrogate`` defaults to the cached one whose domain holds what the runs start
        at and measure (``tankode.properties.surrogate_covering``: the default, else the wide tier)."""
        from .properties import CoolPropFluid

        runs = (runs,) if isinstance(runs, Run) else tuple(runs)
        if not runs:
            raise ValueError("Fleet needs at least one run")
        fluids = {r.fluid for r in runs}
        if len(fluids) != 1:
            raise ValueError(f"all runs of one fleet must share a fluid, got {sorted(fluids)}")
        fluid_name = runs[0].fluid
        if surrogate is None:
            from .properties import surrogate_covering

            surrogate = surrogate_covering(fluid_name, *_states_seen(runs))
        elif getattr(surrogate, "fluid_name", fluid_name) != fluid_name:
            raise ValueError(f"surrogate is for {surrogate.fluid_name}, runs are {fluid_name}")
        geometry = stack_geometries([r.tank.geometry() for r in runs])
        walls = tuple(
            resolve_wall_heat_capacity(r.tank.wall_heat_capacity_J_per_K, float(g.wall_area_m2), r.initial.T_w0_K)
            for r, g in zip(runs, geometry.unbind())
        )
        return Fleet(runs, geometry, walls, surrogate, CoolPropFluid(fluid_name))

    def on_next_tier(self, state: Tensor | None = None) -> "Fleet | None":
        """The same runs on the next property tier that holds ``state`` (``tankode.properties.property_tiers``).

        For a trajectory that leaves its tier, which the runs' measured states (what
        ``from_runs`` picks the tier by) do not foresee. Only tiers after the fleet's own, in
        their order (default, wide, low), are tried, so a search for one never returns to a
        tier already left. None where no later tier holds ``state`` (``(..., 7+)`` tank states,
        e.g. a ``StateLeftDomain``'s: an ullage read colder than saturation leaves every tier
        alike) or the fleet's domain is none of the tiers (a surrogate given by the caller).
        """
        from .properties import load_surrogate, property_tiers

        tiers = property_tiers(self.fluid.fluid_name)
        domains = [d for d, _, _ in tiers]
        if self.fluid.domain not in domains:
            return None
        s = None if state is None else state.detach().reshape(-1, state.shape[-1])
        seen = None
        if s is not None:  # the state's p and T as the current surrogate reads them (extrapolated)
            with torch.no_grad():
                pv = self.fluid.vapor(s[:, 2], s[:, 0] / s[:, 5])
                pl = self.fluid.liquid(s[:, 3], s[:, 1] / s[:, 6])
            seen = (pv.p.numpy(), pv.T.numpy(), pl.T.numpy(), pv.T_sat.numpy())
        for domain, config, _ in tiers[domains.index(self.fluid.domain) + 1:]:
            if seen is not None and not _may_hold(domain, *seen):
                continue  # not worth a fit (a tier's first use fits it: seconds to a minute)
            surrogate = load_surrogate(self.fluid.fluid_name, domain, config)
            if s is None or (surrogate.contains("vapor", s[:, 2], s[:, 0] / s[:, 5]).all()
                             and surrogate.contains("liquid", s[:, 3], s[:, 1] / s[:, 6]).all()):
                return dataclasses.replace(self, fluid=surrogate)
        return None

    def wall_notes(self) -> tuple[str, ...]:
        """One sentence per tank whose wall heat capacity the run does not state: what was taken."""
        return tuple(f"{r.name}: wall heat capacity {w.note}" for r, w in zip(self.runs, self.walls) if w.assumed)

    @property
    def n_env(self) -> int:
        return len(self.runs)

    @property
    def wall_heat_capacity_J_per_K(self) -> Tensor:
        """m_w c_w per environment, ``(env,)`` (J/K)."""
        return torch.tensor([w.value_J_per_K for w in self.walls], dtype=torch.float64)

    @property
    def t_end_s(self) -> float:
        return max(r.t_end_s for r in self.runs)

    @property
    def t0_s(self) -> float:
        t0 = {r.t0_s for r in self.runs}
        if len(t0) != 1:
            raise ValueError(f"runs of one fleet must start at the same time stamp, got {sorted(t0)} s")
        return t0.pop()

    def sampling_intervals_s(self) -> np.ndarray:
        """Each run's typical sampling interval ``(env,)`` (s): ``sampling_interval_s`` of each run."""
        return np.array([sampling_interval_s(r) for r in self.runs])

    def initial_state(self, mechanisms=()) -> Tensor:
        """State ``(env, 7)`` from each run's initial (p_v, T_v, T_l, T_w, fill ratio), via CoolProp.

        Both phases are placed at the ullage pressure; the liquid's (u, rho) is taken on the
        liquid branch even if slightly superheated (a metastable state), as measured runs have.
        The initial pressure is a sensor reading: the ``mechanisms``' pressure offsets (a bias,
        an inert gas) at (T_v0, V_v0) are removed from it to get the hydrogen's pressure; their
        liquid thermometer offsets likewise from the initial liquid temperature, which they may
        then set from the saturation temperature at that pressure (``initial_liquid_K``).

        Differentiable in the mechanisms' parameters: where an offset carries a graph (a
        mechanism trained with the agent, ``trainers.mechanism_params``), the state is CoolProp's
        value plus its linearisation in the hydrogen pressure and the liquid reading,
        ``ds/dp (p - p.detach()) + ds/dT_l (T_l - T_l.detach())`` (zero in value; slopes by
        central differences of CoolProp over ``_START_STEPS``), so the start moves with the
        parameters as the reading it is built from does. Without a graph it is CoolProp's value.

        Raises:
            SimulationError: the offsets leave a non-positive hydrogen pressure.
        """
        ini = [r.initial for r in self.runs]
        V = self.geometry.volume_m3.detach().numpy() * np.ones(self.n_env)
        T_v = np.array([i.T_v_K for i in ini])
        V_l = V * np.array([i.fill_ratio for i in ini])
        T_w = np.array([i.T_w0_K for i in ini])
        p = _less(torch.as_tensor([i.p_v_Pa for i in ini], dtype=torch.float64),
                  [m.pressure_offset_Pa(torch.as_tensor(T_v), torch.as_tensor(V - V_l)) for m in mechanisms])
        if (p.detach() <= 0).any():
            # A SimulationError, not a ValueError: the run is valid, the mechanisms' parameters
            # (a trial point of a fit) leave no hydrogen, and a fit rejects such a point.
            raise SimulationError(f"initial hydrogen pressure {p.detach().numpy()} Pa is not positive after "
                                  "removing the mechanisms' pressure offsets from the initial reading", t_s=self.t0_s)
        # the initial liquid temperature is a reading too
        T_l_read = torch.as_tensor([i.T_l_K for i in ini], dtype=torch.float64)
        T_read = _less(T_l_read, [m.liquid_temperature_offset_K(T_l_read) for m in mechanisms])
        sets_liquid = any(type(m).initial_liquid_K is not Mechanism.initial_liquid_K for m in mechanisms)

        def state(p_Pa: np.ndarray, T_l_K: np.ndarray) -> Tensor:
            if sets_liquid:
                with torch.no_grad():
                    T_sat = torch.as_tensor(self.reference.saturation(p_Pa)["T_sat"])  # CoolProp: only where asked for
                    T_l = torch.as_tensor(T_l_K)
                    for m in mechanisms:
                        T_l = m.initial_liquid_K(T_l, T_sat)
                T_l_K = T_l.numpy()
            return self.state_from(p_Pa, T_v, T_l_K, T_w, V_l)

        p0, T0 = p.detach().numpy(), T_read.detach().numpy()
        s = state(p0, T0)
        if p.requires_grad:
            dp = _START_STEPS[0] * p0
            slope = (state(p0 + dp, T0) - state(p0 - dp, T0)) / torch.as_tensor(2 * dp)[:, None]
            s = s + slope * (p - p.detach())[:, None]
        if T_read.requires_grad:
            dT = _START_STEPS[1]
            slope = (state(p0, T0 + dT) - state(p0, T0 - dT)) / (2 * dT)
            s = s + slope * (T_read - T_read.detach())[:, None]
        return s

    def state_from(self, p_v_Pa, T_v_K, T_l_K, T_w_K, V_l_m3) -> Tensor:
        """State ``(env, 7)`` from per-environment (p_v, T_v, T_l, T_w, V_l) arrays, via CoolProp."""
        vap = self.reference.state_pT(np.asarray(p_v_Pa, float), np.asarray(T_v_K, float), "vapor")
        liq = self.reference.state_pT(np.asarray(p_v_Pa, float), np.asarray(T_l_K, float), "liquid")
        V_l = np.asarray(V_l_m3, float)
        V_v = self.geometry.volume_m3.detach().numpy() * np.ones(self.n_env) - V_l
        s = np.stack([
            np.asarray(vap["rho"]) * V_v, np.asarray(liq["rho"]) * V_l, vap["u"], liq["u"],
            np.asarray(T_w_K, float), V_v, V_l,
        ], axis=-1)
        return torch.as_tensor(s, dtype=torch.float64)

    def breakpoints(self, t0: float, t1: float) -> list[float]:
        """Times in (t0, t1) where any run's inputs change: where the solver must restart."""
        schedules = [r.inputs for r in self.runs if r.inputs is not None]
        if not schedules:
            return []
        return [float(t) for t in merge_breakpoints(schedules, t0, t1)]

    def inputs_at(self, t_s: float) -> np.ndarray:
        """Raw schedule values ``(env, n_inputs)`` in force at ``t_s`` (zeros for runs without inputs)."""
        rows = [np.zeros(len(INPUT_NAMES)) if r.inputs is None else np.asarray(r.inputs.at(t_s)) for r in self.runs]
        return np.stack(rows)

    def segments(self, t0: float, t1: float) -> list[tuple[float, float]]:
        """Contiguous ``(start, end)`` spans of [t0, t1] (s) with constant inputs: where the solver runs."""
        cuts = [t0, *self.breakpoints(t0, t1), t1]
        return list(zip(cuts[:-1], cuts[1:]))

    def forcing(self, t_s: float, s: Tensor) -> Forcing:
        """The ``Forcing`` in force from ``t_s`` on, for the state ``s`` ``(env, 7)`` there.

        Injected vapour enthalpy: CoolProp at the schedule's (p_v_in, T_v_in). Injected liquid:
        CoolProp at (current ullage pressure, T_l_in); the pressure is frozen at the segment's
        start (its effect, v dp, is below 0.5 % of the latent heat for a 1 bar change).
        """
        u = self.inputs_at(t_s)  # (env, n_inputs)
        h_v_in = np.zeros(self.n_env)
        h_l_in = np.zeros(self.n_env)
        on_v = u[:, _I["mdot_v_in_kg_s"]] > 0
        if on_v.any():
            h_v_in[on_v] = self.reference.state_pT(u[on_v, _I["p_v_in_Pa"]], u[on_v, _I["T_v_in_K"]], "vapor")["h"]
        on_l = u[:, _I["mdot_l_in_kg_s"]] > 0
        if on_l.any():
            p = self.fluid.vapor(s[:, 2], s[:, 0] / s[:, 5]).p.detach().numpy()[on_l]
            h_l_in[on_l] = self.reference.state_pT(p, u[on_l, _I["T_l_in_K"]], "liquid")["h"]
        t = lambda a: torch.as_tensor(a, dtype=torch.float64)  # noqa: E731
        return Forcing(
            mdot_v_in_kg_s=t(u[:, _I["mdot_v_in_kg_s"]]), h_v_in_J_per_kg=t(h_v_in),
            mdot_v_out_kg_s=t(u[:, _I["mdot_v_out_kg_s"]]),
            mdot_l_in_kg_s=t(u[:, _I["mdot_l_in_kg_s"]]), h_l_in_J_per_kg=t(h_l_in),
            mdot_l_out_kg_s=t(u[:, _I["mdot_l_out_kg_s"]]),
            slosh_amplitude_m=t(u[:, _I["slosh_amplitude_m"]]), slosh_frequency_Hz=t(u[:, _I["slosh_frequency_Hz"]]),
            Q_aw_W=t(u[:, _I["Q_aw_W"]]),
        )


__all__ = ["Fleet"]
