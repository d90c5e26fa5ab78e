"""Accuracy and speed of a ``Surrogate`` against CoolProp on fresh held-out points.

Points are drawn uniformly in each phase's (p, T-fraction) band of the surrogate's ``Domain``
from a random stream that neither the training grid nor the selection set uses, mapped to
(u, rho) by CoolProp, and the reference at (u, rho) is ``CoolPropFluid.props_urho`` (single-phase
branch, metastable states included). Error measures:

* p, T, T_sat, k, mu, cp, beta, dp_du, dp_drho: relative error ``|s/r - 1|``.
* h_lsat, h_vsat: error relative to the latent heat ``L(p) = h_vsat - h_lsat`` at the reference
  pressure, because ParaHydrogen's ``h_lsat`` crosses zero near 1 atm (its own relative error is
  unbounded there); absolute errors (J/kg) are reported as well. The surrogate evaluates these at
  its own pressure, so this includes the propagated pressure error.

Speed: the surrogate's batched evaluation of all points versus the plain CoolProp loop a user
would write (``DmassUmass_INPUTS`` update, p, T, k, mu, cp, beta, then a ``PQ_INPUTS`` update for
T_sat and the saturation enthalpies), over the same points, in the same process.
"""

from __future__ import annotations

import time

import CoolProp
import numpy as np
import torch

from .coolprop import CoolPropFluid
from .fit import PHASES, random_phase_points

_BENCHMARK_STREAM = 2  # random stream id (validation during the fit uses 1)
TARGETS = {"p": 1e-3, "T": 1e-3, "T_sat": 1e-3, "h_lsat": 1e-3, "h_vsat": 1e-3}
_REL = ("p", "T", "T_sat", "k", "mu", "cp", "beta", "dp_du", "dp_drho")


def _best_time(fn, repeats: int) -> float:
    fn()
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def _per_call_us(fn, n_calls: int = 1000, repeats: int = 3) -> float:
    for _ in range(100):
        fn()
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(n_calls):
            fn()
        best = min(best, (time.perf_counter() - t0) / n_calls)
    return best * 1e6


def _coolprop_loop(fluid: CoolPropFluid, u: np.ndarray, rho: np.ndarray) -> tuple[float, int]:
    """Seconds for the plain CoolProp loop over (u, rho), and how many points raised."""
    st = fluid._state
    failed = 0
    t0 = time.perf_counter()
    for ui, ri in zip(u.tolist(), rho.tolist()):
        try:
            st.update(CoolProp.DmassUmass_INPUTS, ri, ui)
            p = st.p()
            st.T(), st.conductivity(), st.viscosity(), st.cpmass(), st.isobaric_expansion_coefficient()
            st.update(CoolProp.PQ_INPUTS, p, 0.0)
            st.T(), st.hmass()
            st.update(CoolProp.PQ_INPUTS, p, 1.0)
            st.hmass()
        except ValueError:
            failed += 1
    return time.perf_counter() - t0, failed


def _stats(err: np.ndarray) -> dict:
    return {"max": float(np.max(err)), "mean": float(np.mean(err))}


def benchmark_surrogate(surrogate, n_points: int = 10000, seed: int = 0, repeats: int = 3,
                        timing: bool = True) -> dict:
    """Held-out errors and timings of ``surrogate`` versus CoolProp (JSON-serialisable dict).

    Args:
        surrogate: a fitted ``Surrogate``.
        n_points: held-out points per phase.
        seed: seed of the held-out points (independent of the fit's streams).
        repeats: timing repetitions (the best is kept).
        timing: measure speed too (False: errors only, e.g. in tests on a busy machine).

    Returns:
        ``{"phases": {phase: {"max_rel_err": {...}, "mean_rel_err": {...}, "max_abs_err": {...},
        "meets_targets": {...}, "timing": {...}}}, "timing": {...}, "targets": {...}, ...}`` where
        ``max_rel_err["h_lsat"]`` is relative to the latent heat (see module docstring), timings
        are seconds (per-call figures in microseconds), and ``speed_ratio`` is CoolProp loop time
        over surrogate batched time.
    """
    fluid = CoolPropFluid(surrogate.fluid_name)
    out = {
        "fluid_name": surrogate.fluid_name, "n_points_per_phase": int(n_points), "seed": int(seed),
        "domain": surrogate.domain.as_dict(), "targets": dict(TARGETS),
        "h_sat_error_measure": "|error| / (h_vsat - h_lsat) at the reference pressure",
        "selected": {ph: {k: v for k, v in s.items() if k in ("kernel", "eps", "method", "n_centres", "rank",
                                                             "cond", "cond_effective")}
                     for ph, s in surrogate.metadata.get("selected", {}).items()},
        "torch_threads": torch.get_num_threads(), "phases": {},
    }
    total_s, total_cp = 0.0, 0.0
    for phase in PHASES:
        pts = random_phase_points(fluid, surrogate.domain, phase, n_points, seed, _BENCHMARK_STREAM)
        u, rho = pts["u"], pts["rho"]
        t0 = time.perf_counter()
        ref = fluid.props_urho(phase, u, rho)
        ref_s = time.perf_counter() - t0
        ut, rt = torch.as_tensor(u), torch.as_tensor(rho)
        with torch.no_grad():
            pred = surrogate.props(phase, ut, rt)
        pred = {k: getattr(pred, k).numpy() for k in pred._fields}
        L = ref["h_vsat"] - ref["h_lsat"]
        rel = {k: np.abs(pred[k] / ref[k] - 1.0) for k in _REL}
        rel.update({k: np.abs(pred[k] - ref[k]) / L for k in ("h_lsat", "h_vsat")})
        keys = ("p", "T", "T_sat", "h_lsat", "h_vsat", "k", "mu", "cp", "beta", "dp_du", "dp_drho")
        out["phases"][phase] = {
            "max_rel_err": {k: _stats(rel[k])["max"] for k in keys},
            "mean_rel_err": {k: _stats(rel[k])["mean"] for k in keys},
            "max_abs_err": {k: float(np.max(np.abs(pred[k] - ref[k]))) for k in keys},
            "meets_targets": {k: bool(np.max(rel[k]) <= tol) for k, tol in TARGETS.items()},
        }
        if not timing:
            continue
        with torch.no_grad():
            sur_s = _best_time(lambda: surrogate.props(phase, ut, rt), repeats)
        cp_s, cp_failed = min((_coolprop_loop(fluid, u, rho) for _ in range(max(1, repeats - 1))), key=lambda r: r[0])
        out["phases"][phase]["timing"] = {
            "surrogate_batched_s": sur_s, "coolprop_loop_s": cp_s, "speed_ratio": cp_s / sur_s,
            "coolprop_loop_failed_points": cp_failed, "coolprop_reference_newton_s": ref_s,
        }
        total_s += sur_s
        total_cp += cp_s
    if timing:
        out["timing"] = _timing(surrogate, total_s, total_cp)
    return out


def _timing(surrogate, total_s: float, total_cp: float) -> dict:
    per_call = {}
    with torch.no_grad():
        for b in (1, 8):
            u1 = torch.full((b,), 4.5e5, dtype=torch.float64)
            r1 = torch.full((b,), 3.0, dtype=torch.float64)
            per_call[f"vapor_batch{b}_us"] = _per_call_us(lambda: surrogate.vapor(u1, r1))
            ul = torch.full((b,), 2.0e4, dtype=torch.float64)
            rl = torch.full((b,), 70.0, dtype=torch.float64)
            per_call[f"liquid_batch{b}_us"] = _per_call_us(lambda: surrogate.liquid(ul, rl))
    ug = torch.full((1,), 4.5e5, dtype=torch.float64, requires_grad=True)
    rg = torch.full((1,), 3.0, dtype=torch.float64)
    per_call["vapor_batch1_autograd_us"] = _per_call_us(lambda: surrogate.vapor(ug, rg))
    return {"surrogate_batched_s": total_s, "coolprop_loop_s": total_cp, "speed_ratio": total_cp / total_s,
            "per_call": per_call}


__all__ = ["benchmark_surrogate", "TARGETS"]
