"""CoolProp reference backend: the ground truth the surrogate is fitted to and benchmarked against.

Wraps one ``CoolProp.AbstractState("HEOS", name)`` (Helmholtz-energy reference EOS and its
transport models) behind vectorised numpy methods in SI mass units. Every method loops in
Python over the points, so it is accurate but slow (~10-40 us per point); the ODE uses the
surrogate (``tankode.properties.Surrogate``) instead.

Metastable states. The 0D tank model keeps each phase on its own single-phase branch: the ullage
may be slightly subcooled and the liquid slightly superheated relative to the common pressure.
CoolProp's (u, rho) flash always returns the two-phase *equilibrium* state inside the dome, even
with an imposed phase, so ``props_urho`` solves ``u(T, rho) = u`` by Newton iteration on the
imposed single-phase branch (``DmassT_INPUTS`` evaluates the Helmholtz EOS directly there).
"""

from __future__ import annotations

from contextlib import contextmanager
from typing import Iterator

import CoolProp
import CoolProp.CoolProp as _CP
import numpy as np

_PHASES = {"vapor": CoolProp.iphase_gas, "liquid": CoolProp.iphase_liquid}


def _check_phase(phase: str) -> int:
    try:
        return _PHASES[phase]
    except KeyError:
        raise ValueError(f"phase must be 'vapor' or 'liquid', got {phase!r}") from None


def available_fluids() -> list[str]:
    """Names accepted by ``CoolPropFluid`` (CoolProp's HEOS fluid list)."""
    return sorted(_CP.get_global_param_string("FluidsList").split(","))


class CoolPropFluid:
    """Reference real-fluid properties of one pure fluid from CoolProp's HEOS backend.

    Args:
        name: CoolProp fluid name, e.g. ``"ParaHydrogen"`` (the tank model's default: liquid
            hydrogen stored for long reaches its para equilibrium), ``"Hydrogen"`` (normal).

    Raises:
        ValueError: unknown fluid name (the message lists a few valid ones).

    Limits: not thread safe (one shared ``AbstractState``); not differentiable (numpy).
    """

    def __init__(self, name: str = "ParaHydrogen"):
        fluids = available_fluids()
        if name not in fluids:
            near = [f for f in fluids if name.lower()[:4] in f.lower()] or fluids[:8]
            raise ValueError(
                f"unknown CoolProp fluid {name!r}; valid names include {', '.join(near[:8])} "
                f"({len(fluids)} in total, see CoolProp.CoolProp.get_global_param_string('FluidsList'))"
            )
        self.name = name
        self._state = CoolProp.AbstractState("HEOS", name)

    def __repr__(self) -> str:
        return f"CoolPropFluid({self.name!r})"

    @property
    def T_triple_K(self) -> float:
        """Triple-point temperature (K): lower validity limit of the liquid."""
        return float(self._state.Ttriple())

    @property
    def p_triple_Pa(self) -> float:
        """Triple-point pressure (Pa): the saturation line starts here."""
        return float(self._state.trivial_keyed_output(CoolProp.iP_triple))

    @property
    def T_crit_K(self) -> float:
        """Critical temperature (K)."""
        return float(self._state.T_critical())

    @property
    def p_crit_Pa(self) -> float:
        """Critical pressure (Pa): no saturation (and no liquid/vapour distinction) above it."""
        return float(self._state.p_critical())

    @property
    def rho_crit_kg_m3(self) -> float:
        """Critical density (kg/m3)."""
        return float(self._state.rhomass_critical())

    @property
    def T_max_K(self) -> float:
        """Upper temperature limit of the EOS (K)."""
        return float(self._state.Tmax())

    @property
    def molar_mass_kg_per_mol(self) -> float:
        """Molar mass (kg/mol)."""
        return float(self._state.molar_mass())

    @property
    def acentric_factor(self) -> float:
        """Pitzer acentric factor (-), for the Peng-Robinson baseline."""
        return float(self._state.acentric_factor())

    @property
    def gas_constant_J_per_molK(self) -> float:
        """Universal gas constant CoolProp uses for this fluid (J/mol/K)."""
        return float(self._state.gas_constant())

    @contextmanager
    def _imposed(self, phase: str) -> Iterator[None]:
        # The phase must be released afterwards: a stale imposed phase would silently put later
        # (e.g. saturation) calls on the wrong branch.
        self._state.specify_phase(_check_phase(phase))
        try:
            yield
        finally:
            self._state.unspecify_phase()

    def _update(self, pair: int, a: float, b: float, what: str) -> None:
        try:
            self._state.update(pair, a, b)
        except ValueError as err:
            raise ValueError(f"CoolProp ({self.name}) failed at {what}: {err}") from err

    def state_pT(self, p_Pa, T_K, phase: str) -> dict[str, np.ndarray]:
        """Internal energy, density and enthalpy on one phase's single-phase branch at (p, T).

        Args:
            p_Pa: pressure (Pa), any shape broadcastable with ``T_K``.
            T_K: temperature (K).
            phase: ``"vapor"`` or ``"liquid"``; imposed so that slightly metastable states
                (liquid above T_sat(p), vapour below) are evaluated on that branch.

        Returns:
            ``{"u": J/kg, "rho": kg/m3, "h": J/kg}``, numpy float64 arrays of the broadcast shape.
        """
        p, T = np.broadcast_arrays(np.asarray(p_Pa, dtype=np.float64), np.asarray(T_K, dtype=np.float64))
        out = {k: np.empty(p.shape) for k in ("u", "rho", "h")}
        st = self._state
        with self._imposed(phase):
            for i in np.ndindex(p.shape):
                self._update(CoolProp.PT_INPUTS, p[i], T[i], f"{phase} p={p[i]:.10g} Pa, T={T[i]:.10g} K")
                out["u"][i], out["rho"][i], out["h"][i] = st.umass(), st.rhomass(), st.hmass()
        return out

    def saturation(self, p_Pa) -> dict[str, np.ndarray]:
        """Saturation temperature, enthalpies and densities at pressure ``p_Pa`` (Pa, any shape).

        Returns:
            ``{"T_sat": K, "h_lsat": J/kg, "h_vsat": J/kg, "rho_lsat": kg/m3, "rho_vsat": kg/m3}``.
            Note: ParaHydrogen's enthalpy reference (IIR-like, h = 0 at the normal boiling
            point's saturated liquid) makes ``h_lsat`` cross zero near 1 atm.
        """
        p = np.asarray(p_Pa, dtype=np.float64)
        out = {k: np.empty(p.shape) for k in ("T_sat", "h_lsat", "h_vsat", "rho_lsat", "rho_vsat")}
        st = self._state
        for i in np.ndindex(p.shape):
            self._update(CoolProp.PQ_INPUTS, p[i], 0.0, f"saturated liquid p={p[i]:.10g} Pa")
            out["T_sat"][i], out["h_lsat"][i], out["rho_lsat"][i] = st.T(), st.hmass(), st.rhomass()
            self._update(CoolProp.PQ_INPUTS, p[i], 1.0, f"saturated vapour p={p[i]:.10g} Pa")
            out["h_vsat"][i], out["rho_vsat"][i] = st.hmass(), st.rhomass()
        return out

    def _T_from_urho(self, u: float, rho: float, phase: str, T_guess: float) -> float:
        # Newton on u(T, rho) = u along the imposed branch; du/dT|rho = c_v > 0 so it is monotone
        # and converges in a few steps from the equilibrium flash temperature.
        st = self._state
        T = T_guess
        for _ in range(50):
            self._update(CoolProp.DmassT_INPUTS, rho, T, f"{phase} rho={rho:.10g} kg/m3, T={T:.10g} K")
            step = (st.umass() - u) / st.cvmass()
            T -= step
            if abs(step) <= 1e-12 * T:
                return T
        raise ValueError(
            f"CoolProp ({self.name}): no {phase} temperature found for u={u:.10g} J/kg, rho={rho:.10g} kg/m3 "
            f"(Newton did not converge; last T={T:.10g} K)"
        )

    def props_urho(self, phase: str, u_J_per_kg, rho_kg_m3) -> dict[str, np.ndarray]:
        """Reference properties at (u, rho) on one phase's branch, the surrogate's ground truth.

        Args:
            phase: ``"vapor"`` or ``"liquid"``.
            u_J_per_kg: specific internal energy (J/kg), any shape broadcastable with ``rho_kg_m3``.
            rho_kg_m3: density (kg/m3).

        Returns:
            Dict of numpy arrays: ``p`` (Pa), ``T`` (K), ``T_sat`` (K, at that p), ``h_lsat``,
            ``h_vsat`` (J/kg, at that p), ``k`` (W/m/K), ``mu`` (Pa s), ``cp`` (J/kg/K),
            ``beta`` (1/K, isobaric expansion), and ``dp_du`` (Pa per J/kg at constant rho),
            ``dp_drho`` (Pa per kg/m3 at constant u) for reference.
        """
        _check_phase(phase)
        u, rho = np.broadcast_arrays(
            np.asarray(u_J_per_kg, dtype=np.float64), np.asarray(rho_kg_m3, dtype=np.float64)
        )
        keys = ("p", "T", "T_sat", "h_lsat", "h_vsat", "k", "mu", "cp", "beta", "dp_du", "dp_drho")
        out = {k: np.empty(u.shape) for k in keys}
        st = self._state
        for i in np.ndindex(u.shape):
            where = f"{phase} u={u[i]:.10g} J/kg, rho={rho[i]:.10g} kg/m3"
            # Equilibrium flash only as a starting guess: inside the dome it is two-phase.
            self._update(CoolProp.DmassUmass_INPUTS, rho[i], u[i], where)
            T_guess = st.T()
            with self._imposed(phase):
                T = self._T_from_urho(u[i], rho[i], phase, T_guess)
                self._update(CoolProp.DmassT_INPUTS, rho[i], T, where)
                out["p"][i], out["T"][i] = st.p(), T
                try:
                    out["k"][i], out["mu"][i] = st.conductivity(), st.viscosity()
                except ValueError as err:
                    raise ValueError(f"CoolProp ({self.name}) transport failed at {where}: {err}") from err
                out["cp"][i], out["beta"][i] = st.cpmass(), st.isobaric_expansion_coefficient()
                out["dp_du"][i] = st.first_partial_deriv(CoolProp.iP, CoolProp.iUmass, CoolProp.iDmass)
                out["dp_drho"][i] = st.first_partial_deriv(CoolProp.iP, CoolProp.iDmass, CoolProp.iUmass)
            p = out["p"][i]
            self._update(CoolProp.PQ_INPUTS, p, 0.0, f"saturated liquid p={p:.10g} Pa ({where})")
            out["T_sat"][i], out["h_lsat"][i] = st.T(), st.hmass()
            self._update(CoolProp.PQ_INPUTS, p, 1.0, f"saturated vapour p={p:.10g} Pa ({where})")
            out["h_vsat"][i] = st.hmass()
        return out

    def props_pT(self, p_Pa, T_K, phase: str) -> dict[str, np.ndarray]:
        """Same dict as ``props_urho`` plus ``u``, ``rho``, for states given by (p, T) on ``phase``.

        Used to generate training data: sampling in (p, T) covers the domain's rectangle-like
        shape exactly; the Newton solve of ``props_urho`` is not needed there.
        """
        p, T = np.broadcast_arrays(np.asarray(p_Pa, dtype=np.float64), np.asarray(T_K, dtype=np.float64))
        keys = ("u", "rho", "p", "T", "T_sat", "h_lsat", "h_vsat", "k", "mu", "cp", "beta", "cv")
        out = {k: np.empty(p.shape) for k in keys}
        st = self._state
        for i in np.ndindex(p.shape):
            where = f"{phase} p={p[i]:.10g} Pa, T={T[i]:.10g} K"
            with self._imposed(phase):
                self._update(CoolProp.PT_INPUTS, p[i], T[i], where)
                out["u"][i], out["rho"][i], out["p"][i], out["T"][i] = st.umass(), st.rhomass(), p[i], T[i]
                try:
                    out["k"][i], out["mu"][i] = st.conductivity(), st.viscosity()
                except ValueError as err:
                    raise ValueError(f"CoolProp ({self.name}) transport failed at {where}: {err}") from err
                out["cp"][i], out["beta"][i] = st.cpmass(), st.isobaric_expansion_coefficient()
                out["cv"][i] = st.cvmass()
            self._update(CoolProp.PQ_INPUTS, p[i], 0.0, f"saturated liquid p={p[i]:.10g} Pa")
            out["T_sat"][i], out["h_lsat"][i] = st.T(), st.hmass()
            self._update(CoolProp.PQ_INPUTS, p[i], 1.0, f"saturated vapour p={p[i]:.10g} Pa")
            out["h_vsat"][i] = st.hmass()
        return out


__all__ = ["CoolPropFluid", "available_fluids"]
