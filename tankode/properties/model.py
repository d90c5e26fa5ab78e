"""The fitted property surrogate: PR + Taylor baseline plus RBF corrections, per phase (torch).

For each phase, at specific internal energy u (J/kg) and density rho (kg/m3):

    T_b = T0 + (u - u0)/cv0                       first-order Taylor temperature
    p   = p_PR(T_b, rho) + R_p(u, rho)            Peng-Robinson baseline + RBF residual
    T   = T_b + R_T(u, rho)
    k, mu, cp, beta = exp(R_k, R_mu, R_cp, R_beta)(u, rho)   (logs fitted: positive, smoother)
    T_sat, h_lsat, h_vsat = S(p)                  1-D polynomial at the surrogate's own p

where the six R share one RBF kernel matrix (Marques, Ahizi & Mendez, section 3: PR pressure and
Taylor temperature corrected by RBF interpolants in min-max scaled (u, rho), one per phase).
``dp_du`` and ``dp_drho`` are the analytic derivatives of this ``p`` (PR partials chained with
``dT_b/du`` plus the RBF gradient), so they are exact for the surrogate and differentiable again.

Honest limits: accurate only inside the fitted ``Domain`` (check with ``contains``); outside, the
Gaussian RBF decays to its linear tail and the PR baseline can return NaN (T_b <= 0).
"""

from __future__ import annotations

import json
from typing import NamedTuple

import torch
from torch import Tensor, nn

from .domain import Domain
from .peng_robinson import PengRobinson, PRTaylorBaseline, TaylorTemperature
from .rbf import RBFInterpolant
from .saturation import SaturationPolynomial

# Columns of each phase's RBF: residual p (Pa), residual T (K), then logs of k, mu, cp, beta.
RBF_OUTPUTS = ("p_residual", "T_residual", "log_k", "log_mu", "log_cp", "log_beta")


class PhaseProps(NamedTuple):
    """Properties of one phase, each a float64 tensor of the input's (broadcast) shape.

    p: pressure (Pa). T: temperature (K).
    dp_du: dp/du at constant rho (Pa per J/kg). dp_drho: dp/drho at constant u (Pa per kg/m3);
        both exact derivatives of the surrogate's own ``p``.
    T_sat: saturation temperature at this phase's pressure ``p`` (K).
    h_lsat, h_vsat: saturated liquid / vapour specific enthalpies at ``p`` (J/kg). ParaHydrogen's
        h_lsat crosses zero near 1 atm, so their accuracy is stated relative to the latent heat
        L(p) = h_vsat - h_lsat, not to themselves.
    k: thermal conductivity (W/m/K). mu: dynamic viscosity (Pa s).
    cp: isobaric specific heat (J/kg/K). beta: isobaric expansion coefficient (1/K).
    """

    p: Tensor
    T: Tensor
    dp_du: Tensor
    dp_drho: Tensor
    T_sat: Tensor
    h_lsat: Tensor
    h_vsat: Tensor
    k: Tensor
    mu: Tensor
    cp: Tensor
    beta: Tensor


class PhaseFit(nn.Module):
    """One phase: its RBF corrections and its PR + Taylor baseline (both buffers-only modules)."""

    def __init__(self, name: str, rbf: RBFInterpolant, pr: PengRobinson, taylor: TaylorTemperature,
                 T_range_K: tuple[float, float]):
        super().__init__()
        if rbf.n_out != len(RBF_OUTPUTS) or rbf.grad_outputs != (0,) or rbf.dim != 2:
            raise ValueError(f"{name} RBF must map (u, rho) to {RBF_OUTPUTS} with the p-residual gradient")
        self.name, self.rbf, self.pr, self.taylor = name, rbf, pr, taylor
        self.baseline = PRTaylorBaseline(pr, taylor)
        self.T_range_K = (float(T_range_K[0]), float(T_range_K[1]))


def _as_f64(x) -> Tensor:
    if torch.is_tensor(x):
        if x.dtype != torch.float64:
            raise TypeError(f"surrogate inputs must be float64 tensors, got {x.dtype}")
        return x
    return torch.as_tensor(x, dtype=torch.float64)


def evaluate_phase(m: PhaseFit, saturation: SaturationPolynomial, u: Tensor, rho: Tensor) -> PhaseProps:
    """All properties of phase ``m`` at (u, rho): the hot path of every ODE right-hand side.

    Few tensor ops by design (~55, no autograd, no loop over properties): one RBF kernel matrix
    and one matmul for the six corrections and the p-residual gradient, the PR baseline with its
    partials, the saturation polynomial, column views. 1-D inputs skip all reshapes.
    """
    u, rho = _as_f64(u), _as_f64(rho)
    if u.shape != rho.shape:
        u, rho = torch.broadcast_tensors(u, rho)
    shape = u.shape
    flat = u.dim() == 1
    uf, rf = (u, rho) if flat else (u.reshape(-1), rho.reshape(-1))
    mods = m._modules  # dict lookup: nn.Module.__getattr__ costs ~0.5 us per submodule
    vals, grad = mods["rbf"].value_and_grad_rows(torch.stack((uf, rf), 1))
    p, T, dp_du, dp_drho = mods["baseline"](uf, rf, vals[:, 0], vals[:, 1], grad[:, 0], grad[:, 1])
    sat = saturation(p)
    kmcb = vals[:, 2:].exp()
    out = (p, T, dp_du, dp_drho, sat[:, 0], sat[:, 1], sat[:, 2], kmcb[:, 0], kmcb[:, 1], kmcb[:, 2], kmcb[:, 3])
    if not flat:
        out = tuple(o.reshape(shape) for o in out)
    return PhaseProps(*out)


class Surrogate(nn.Module):
    """Differentiable real-fluid properties of both phases for the 0D tank ODE (buffers only).

    Build with ``fit_surrogate`` or ``load_surrogate``. ``.to(device)`` moves everything; inputs
    must be float64 (the buffers are, and the liquid's steep p(u, rho) needs the precision).

    Accuracy (ParaHydrogen, default Domain/config, 10k held-out points per phase, see
    ``benchmark_surrogate``): p, T, T_sat better than 1e-4 relative, h_lsat/h_vsat better than
    1e-4 of the latent heat; k, mu, cp, beta better than 1e-3 (k in the liquid is limited to ~3e-4
    by a kink of CoolProp's conductivity model near 23.5 K). ``dp_du``/``dp_drho`` are exact for
    the surrogate's ``p`` but differ from CoolProp's partials by up to ~2 % at the superheated
    liquid corner (7 bar, T_sat + 1 K), ~1e-5 on average. The Gaussian expansion's large
    cancelling weights leave ~1e-9 relative rounding noise on the outputs.

    Attributes:
        fluid_name: CoolProp fluid name. domain: the fitted ``Domain``.
        metadata: JSON-serialisable fit record (selection table, conditioning, errors, timings).
    """

    def __init__(self, fluid_name: str, domain: Domain, vapor: PhaseFit, liquid: PhaseFit,
                 saturation: SaturationPolynomial, metadata: dict | None = None):
        super().__init__()
        self.fluid_name, self.domain = fluid_name, domain
        self._vapor, self._liquid, self.saturation_poly = vapor, liquid, saturation
        self.metadata = dict(metadata or {})

    def __repr__(self) -> str:
        sel = self.metadata.get("selected", {})
        kern = {ph: f"{s.get('kernel')}(eps={s.get('eps')}, {s.get('method')}, M={s.get('n_centres')})"
                for ph, s in sel.items()}
        return f"Surrogate({self.fluid_name!r}, {self.domain}, {kern})"

    def _phase(self, phase: str) -> PhaseFit:
        if phase == "vapor":
            return self._vapor
        if phase == "liquid":
            return self._liquid
        raise ValueError(f"phase must be 'vapor' or 'liquid', got {phase!r}")

    def _evaluate(self, m: PhaseFit, u: Tensor, rho: Tensor) -> PhaseProps:
        return evaluate_phase(m, self.saturation_poly, u, rho)

    def vapor(self, u: Tensor, rho: Tensor) -> PhaseProps:
        """Vapour (ullage) properties at ``u`` (J/kg) and ``rho`` (kg/m3), tensors of any broadcastable shape."""
        mods = self._modules
        return evaluate_phase(mods["_vapor"], mods["saturation_poly"], u, rho)

    def liquid(self, u: Tensor, rho: Tensor) -> PhaseProps:
        """Liquid properties at ``u`` (J/kg) and ``rho`` (kg/m3), tensors of any broadcastable shape."""
        mods = self._modules
        return evaluate_phase(mods["_liquid"], mods["saturation_poly"], u, rho)

    def saturation_K(self, p_Pa: Tensor) -> Tensor:
        """Saturation temperature (K) at pressure ``p_Pa`` (Pa), a tensor of any shape."""
        return self.saturation_poly(p_Pa.reshape(-1))[:, 0].reshape(p_Pa.shape)

    def props(self, phase: str, u: Tensor, rho: Tensor) -> PhaseProps:
        """``vapor`` or ``liquid`` by name."""
        return self._evaluate(self._phase(phase), u, rho)

    def contains(self, phase: str, u: Tensor, rho: Tensor, tol: float = 1e-3) -> Tensor:
        """Whether (u, rho) lies in the fitted domain of ``phase`` (bool tensor of the broadcast shape).

        Two checks, each with slack ``tol`` (a fraction of the corresponding range): the min-max
        box of the phase's (u, rho) samples (scaled coordinates in [-tol, 1 + tol]), and the
        (p, T) band of the ``Domain`` evaluated with the surrogate's own p, T and T_sat (the
        liquid's (u, rho) domain is a thin curved strip, so the box alone admits far-off states).
        """
        m = self._phase(phase)
        d = self.domain
        with torch.no_grad():
            u, rho = torch.broadcast_tensors(_as_f64(u), _as_f64(rho))
            xs = m.rbf.scale(torch.stack((u, rho), -1))
            inside = ((xs >= -tol) & (xs <= 1.0 + tol)).all(-1)
            pp = self._evaluate(m, u, rho)
            dp = tol * (d.p_max_Pa - d.p_min_Pa)
            inside &= (pp.p >= d.p_min_Pa - dp) & (pp.p <= d.p_max_Pa + dp)
            dT = tol * (m.T_range_K[1] - m.T_range_K[0])
            T_lo, T_hi = d.T_bounds(phase, pp.T_sat)
            inside &= (pp.T >= T_lo - dT) & (pp.T <= T_hi + dT)
            inside &= torch.isfinite(pp.p) & torch.isfinite(pp.T)
        return inside

    def far_outside(self, phase: str, p: Tensor, T: Tensor, T_sat: Tensor, slack: float = 0.02,
                    slack_K: float = 0.5) -> Tensor:
        """Where a phase's (p, T) lies well beyond the fitted domain (bool, NaN counts as outside).

        ``slack`` is a share of the domain's pressure range and ``slack_K`` a temperature margin
        beyond the phase's band: states this far out are extrapolation that no step should
        take, unlike the small excursions of a solver's trial stages, which ``contains`` judges.
        """
        d = self.domain
        dp = slack * (d.p_max_Pa - d.p_min_Pa)
        lo, hi = d.T_bounds(phase, T_sat)
        inside = (p >= d.p_min_Pa - dp) & (p <= d.p_max_Pa + dp) & (T >= lo - slack_K) & (T <= hi + slack_K)
        return ~inside

    # ---- serialisation (plain tensors and python values; loaded with weights_only=True) ----

    def state(self) -> dict:
        """Everything needed to rebuild the surrogate, as tensors and plain python values."""
        def phase_state(m: PhaseFit) -> dict:
            return {
                "rbf": m.rbf.state(),
                "taylor": {"T0_K": m.taylor.T0_K, "u0_J_per_kg": m.taylor.u0_J_per_kg,
                           "cv0_J_per_kgK": m.taylor.cv0_J_per_kgK},
                "T_range_K": list(m.T_range_K),
            }

        pr = self._vapor.pr
        return {
            "fluid_name": self.fluid_name,
            "domain": self.domain.as_dict(),
            "pr": {"R_s": pr.R_s, "a": pr.a, "b": pr.b, "kappa": pr.kappa, "T_c": pr.T_c},
            "vapor": phase_state(self._vapor),
            "liquid": phase_state(self._liquid),
            "saturation": self.saturation_poly.state(),
            # JSON round trip: only builtin types survive, as torch.load(weights_only=True) requires.
            "metadata": json.loads(json.dumps(self.metadata)),
        }

    @staticmethod
    def from_state(state: dict) -> "Surrogate":
        pr = PengRobinson(**state["pr"])

        def phase(name: str) -> PhaseFit:
            s = state[name]
            return PhaseFit(name, RBFInterpolant.from_state(s["rbf"]), pr, TaylorTemperature(**s["taylor"]),
                          tuple(s["T_range_K"]))

        return Surrogate(state["fluid_name"], Domain(**state["domain"]), phase("vapor"), phase("liquid"),
                         SaturationPolynomial.from_state(state["saturation"]), state.get("metadata", {}))


__all__ = ["Surrogate", "PhaseProps", "PhaseFit", "RBF_OUTPUTS"]
