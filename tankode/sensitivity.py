"""Global (Sobol) and one-at-a-time sensitivity of the ullage pressure to the four h (paper, 6.1.5).

The paper (section 6.1.5) asks which heat-transfer coefficient the pressure is sensitive to,
and when: it perturbs the closure's output theta = (h_vi, h_li, h_wv, h_wl) by multipliers
and looks at the pressure response. Here:

* ``sobol_indices``: variance-based global sensitivity (Saltelli et al. 2010) of the ullage
  pressure p_v(t) to four independent multipliers theta_i -> theta_i * (1 + u_i), u_i uniform
  in [-spread, +spread], time-resolved (first-order S1 and total ST indices at every output
  time, with bootstrap confidence intervals). All samples run as environments of batched ODEs.
* ``one_at_a_time``: the paper's one-at-a-time curves (one multiplier varied, the others 1).
* ``plot_sensitivity``: the figure (``tankode sensitivity`` on the command line).

References:
    A. Saltelli, P. Annoni, I. Azzini, F. Campolongo, M. Ratto, S. Tarantola (2010),
    "Variance based sensitivity analysis of model output. Design and estimator for the total
    sensitivity index", Computer Physics Communications 181, 259-270.
    The paper, section 6.1.5 (sensitivity of the pressure to the heat transfer coefficients).

Limits (honest): the multipliers act on the *reference* correlations' output, so the indices
describe the reference model around its own coefficients, not the real tank; the factors are
independent and uniform (no correlation between, e.g., h_vi and h_wv, which the reference
closure ties together by a fixed factor); the estimators are Monte Carlo estimates whose
error is reported by the bootstrap CI (small ``n_base`` gives wide CIs, S1 may be slightly
negative or sum a bit above 1 by sampling error); second-order indices are not computed.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from .closures.scaled import ScaledClosure
from .closures.reference import ReferenceClosure

NAMES = ("h_vi", "h_li", "h_wv", "h_wl")

# Output standard deviation below this fraction of |mean| (p_v ~ 1e5 Pa: ~1e-4 Pa) counts as
# zero variance: the indices there are 0/0 and SALib would return noise (or NaN + warnings).
REL_STD_FLOOR = 1e-9


@dataclasses.dataclass(frozen=True)
class SobolResult:
    """Time-resolved Sobol indices of the ullage pressure p_v to the four h multipliers.

    Attributes:
        t_s: output times, shape ``(T,)``, s.
        S1, ST: first-order and total indices, shape ``(T, 4)`` (NaN where Var p_v(t) ~ 0).
        S1_conf, ST_conf: half-widths of their 95 % bootstrap confidence intervals, ``(T, 4)``.
        names: the factor names, order of the last axis.
        spread: the multipliers are ``1 + u``, u uniform in ``[-spread, spread]``.
        n_base: Saltelli base sample size N; n_samples = N * (4 + 2) model runs.
        p_mean_Pa, p_std_Pa: mean and standard deviation of p_v over the samples, ``(T,)``, Pa.
        wall_s: wall time of the simulations, s.
    """

    t_s: np.ndarray
    S1: np.ndarray
    ST: np.ndarray
    S1_conf: np.ndarray
    ST_conf: np.ndarray
    names: tuple[str, ...]
    spread: float
    n_base: int
    n_samples: int
    p_mean_Pa: np.ndarray
    p_std_Pa: np.ndarray
    run_name: str = ""
    seed: int = 0
    wall_s: float = 0.0

    def to_json(self) -> dict:
        """A JSON-serialisable dict (NaN written as null)."""

        def arr(a):
            return [None if not math.isfinite(v) else float(v) for v in np.asarray(a, float).ravel()] \
                if np.ndim(a) == 1 else [arr(row) for row in a]

        return {"run": self.run_name, "names": list(self.names), "spread": self.spread, "n_base": self.n_base,
                "n_samples": self.n_samples, "seed": self.seed, "wall_s": self.wall_s, "t_s": arr(self.t_s),
                "p_mean_Pa": arr(self.p_mean_Pa), "p_std_Pa": arr(self.p_std_Pa),
                "S1": arr(self.S1), "ST": arr(self.ST), "S1_conf": arr(self.S1_conf), "ST_conf": arr(self.ST_conf),
                "method": "Saltelli (2010) sampling and estimators via SALib 1.6 sobol, calc_second_order=False, "
                          "95 % bootstrap CI (100 resamples)"}


def _problem(spread: float, names=NAMES) -> dict:
    return {"num_vars": len(names), "names": list(names), "bounds": [[-spread, spread]] * len(names)}


def _check_spread(spread: float) -> float:
    spread = float(spread)
    if not 0.0 < spread < 1.0:
        # >= 1 would allow h <= 0 (no heat transfer or a negative coefficient).
        raise ValueError(f"spread must lie in (0, 1) (multipliers 1 +- spread must stay > 0), got {spread!r}")
    return spread


def _check_n_base(n_base: int) -> int:
    if isinstance(n_base, bool) or int(n_base) != n_base or n_base < 2 or (int(n_base) & (int(n_base) - 1)):
        # Sobol' sequences keep their balance properties only for N = 2^m (SALib warns otherwise).
        raise ValueError(f"n_base must be a power of 2 >= 2 (Sobol' sequence), got {n_base!r}")
    return int(n_base)


def saltelli_sample(spread: float, n_base: int, seed: int = 0, names=NAMES) -> np.ndarray:
    """Saltelli sample of the perturbations u, shape ``(n_base * (D + 2), D)``, in [-spread, spread].

    Scrambled Sobol' sequence (SALib ``sample.sobol.sample``), no second-order columns.
    """
    from SALib.sample import sobol as sobol_sample

    spread, n_base = _check_spread(spread), _check_n_base(n_base)
    return sobol_sample.sample(_problem(spread, names), n_base, calc_second_order=False, seed=seed)


def sobol_analyze(X: np.ndarray, Y: np.ndarray, bounds, *, num_resamples: int = 100, conf_level: float = 0.95,
                  seed: int = 0, rel_std_floor: float = REL_STD_FLOOR) -> dict[str, np.ndarray]:
    """First-order and total Sobol indices (SALib ``analyze.sobol``) of outputs at each time.

    Args:
        X: the Saltelli sample matrix, shape ``(N * (D + 2), D)`` (as ``saltelli_sample`` gives).
        Y: model outputs, shape ``(N * (D + 2),)`` or ``(N * (D + 2), T)`` (one column per time).
        bounds: ``D`` pairs ``[low, high]`` of the factors (the SALib problem definition).
        num_resamples, conf_level: bootstrap for the confidence intervals.
        seed: bootstrap seed (reproducible CIs).
        rel_std_floor: columns with ``std(Y) <= rel_std_floor * max(|mean(Y)|, 1)`` have no
            variance to apportion: their indices are NaN.

    Returns:
        ``{"S1", "ST", "S1_conf", "ST_conf"}``, each shape ``(T, D)`` (``(1, D)`` for 1-D ``Y``).
    """
    from SALib.analyze import sobol as sobol_analyze_mod

    X = np.asarray(X, dtype=np.float64)
    Y = np.asarray(Y, dtype=np.float64)
    if Y.ndim == 1:
        Y = Y[:, None]
    if X.ndim != 2 or Y.ndim != 2 or X.shape[0] != Y.shape[0]:
        raise ValueError(f"X must be (n_samples, D) and Y (n_samples,) or (n_samples, T) with the same n_samples, "
                         f"got X {X.shape}, Y {Y.shape}")
    D = X.shape[1]
    if X.shape[0] % (D + 2):
        raise ValueError(f"n_samples must be a multiple of D + 2 = {D + 2} (Saltelli design without second "
                         f"order), got {X.shape[0]}")
    if not np.isfinite(Y).all():
        raise ValueError("Y contains non-finite values")
    problem = {"num_vars": D, "names": [f"x{i}" for i in range(D)], "bounds": [list(b) for b in bounds]}
    T = Y.shape[1]
    out = {k: np.full((T, D), np.nan) for k in ("S1", "ST", "S1_conf", "ST_conf")}
    std, scale = Y.std(axis=0), np.maximum(np.abs(Y.mean(axis=0)), 1.0)
    for j in range(T):
        if std[j] <= rel_std_floor * scale[j]:
            continue
        # SALib seeds its bootstrap only for a truthy seed (`if seed:`): 0 would draw from numpy's
        # global generator, so the CIs would change with whatever ran before in the process
        r = sobol_analyze_mod.analyze(problem, Y[:, j], calc_second_order=False, num_resamples=num_resamples,
                                      conf_level=conf_level, print_to_console=False, seed=seed + 1)
        for k in out:
            out[k][j] = r[k]
    return out


def _as_run(case_or_run):
    from .cases import CASES, get_case

    if isinstance(case_or_run, str):
        if case_or_run in CASES:
            return get_case(case_or_run)
        from .run_io import read_run

        path = Path(case_or_run)
        if not path.exists():
            raise ValueError(f"{case_or_run!r} is neither a case ({', '.join(CASES)}) nor an existing run JSON file")
        return read_run(path)
    if isinstance(case_or_run, Path):
        from .run_io import read_run

        return read_run(case_or_run)
    return case_or_run


def _pressures(run, factors: np.ndarray, batch: int, t_eval, output_dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """p_v (n, T) in Pa for each row of ``factors`` (n, 4), in batched ODEs of <= ``batch`` runs."""
    from .simulation import simulate

    base = ReferenceClosure()
    chunks, t_s = [], None
    for i in range(0, len(factors), batch):
        f = factors[i:i + batch]
        sol = simulate([run] * len(f), ScaledClosure(base, f), t_eval=t_eval, output_dt_s=output_dt_s)
        chunks.append(sol.observations[:, :, 0].detach().cpu().numpy())
        t_s = sol.t_s.cpu().numpy()
    return t_s, np.concatenate(chunks, axis=0)


def sobol_indices(case_or_run, *, spread: float = 0.10, n_base: int = 64, seed: int = 0, t_eval=None,
                  batch: int = 64, output_dt_s: float = 10.0) -> SobolResult:
    """Time-resolved Sobol indices (S1, ST) of the ullage pressure to the four h multipliers.

    Each sample scales the reference closure's theta by ``1 + u`` (u in [-spread, spread]^4,
    Saltelli/Sobol' design of ``n_base * 6`` samples) and simulates the whole run; the indices
    are computed at every output time from the p_v values (Saltelli 2010, paper 6.1.5).

    Args:
        case_or_run: "case1".."case5", a run JSON path, or a ``Run``.
        spread: half-width of the multiplier range, in (0, 1) (0.1 = +-10 %).
        n_base: Saltelli base sample size, a power of 2 (model runs = 6 * n_base).
        seed: scrambling seed of the Sobol' sequence and the bootstrap.
        t_eval: output times (s); default every ``output_dt_s`` over the run.
        batch: environments per batched ODE, >= 1 (memory vs number of solver calls).
        output_dt_s: output spacing (s) when ``t_eval`` is None.

    Returns:
        A ``SobolResult``; indices NaN at times where p_v has (numerically) no variance, e.g. t0.

    Raises:
        ValueError: a parameter out of range (the message names it); SimulationError if a
            sample leaves the property surrogate's domain (use a smaller spread).
    """
    spread, n_base = _check_spread(spread), _check_n_base(n_base)
    if isinstance(batch, bool) or int(batch) != batch or batch < 1:
        raise ValueError(f"batch must be an integer >= 1 (environments per batched ODE), got {batch!r}")
    run = _as_run(case_or_run)
    X = saltelli_sample(spread, n_base, seed)
    start = time.perf_counter()
    t_s, p = _pressures(run, 1.0 + X, int(batch), t_eval, output_dt_s)
    wall = time.perf_counter() - start
    idx = sobol_analyze(X, p, _problem(spread)["bounds"], seed=seed)
    return SobolResult(t_s=t_s, names=NAMES, spread=spread, n_base=n_base, n_samples=len(X),
                       p_mean_Pa=p.mean(axis=0), p_std_Pa=p.std(axis=0), run_name=getattr(run, "name", ""),
                       seed=int(seed), wall_s=wall, **idx)


def one_at_a_time(case_or_run, *, spread: float = 0.10, n: int = 5, t_eval=None, output_dt_s: float = 10.0) -> dict:
    """The paper's one-at-a-time study: each h scaled by n multipliers, the others at 1.

    All ``4 * n`` perturbed runs are one batched ODE.

    Args:
        case_or_run: "case1".."case5", a run JSON path, or a ``Run``.
        spread: multipliers ``linspace(1 - spread, 1 + spread, n)``, spread in (0, 1).
        n: multipliers per coefficient, >= 2.
        t_eval, output_dt_s: output grid (s), as in ``simulate``.

    Returns:
        ``{"t_s": (T,) s, "multipliers": (n,), "p_v_Pa": (4, n, T) Pa, "names", "spread"}``.
    """
    spread = _check_spread(spread)
    if isinstance(n, bool) or int(n) != n or n < 2:
        raise ValueError(f"n must be an integer >= 2 (multipliers per coefficient), got {n!r}")
    n = int(n)
    run = _as_run(case_or_run)
    m = np.linspace(1.0 - spread, 1.0 + spread, n)
    factors = np.ones((4, n, 4))
    for i in range(4):
        factors[i, :, i] = m
    t_s, p = _pressures(run, factors.reshape(-1, 4), 4 * n, t_eval, output_dt_s)
    return {"t_s": t_s, "multipliers": m, "p_v_Pa": p.reshape(4, n, -1), "names": NAMES, "spread": spread,
            "run": getattr(run, "name", "")}


def slosh_intervals(run, t_s: np.ndarray) -> list[tuple[float, float]]:
    """Time intervals (s) of the output grid during which the run's slosh amplitude is > 0."""
    if run.inputs is None or "slosh_amplitude_m" not in run.inputs.used_inputs():
        return []
    a = np.asarray(run.inputs.get("slosh_amplitude_m", t_s), dtype=float) > 0
    out, start = [], None
    for t, on in zip(t_s, a):
        if on and start is None:
            start = t
        if not on and start is not None:
            out.append((float(start), float(t)))
            start = None
    if start is not None:
        out.append((float(start), float(t_s[-1])))
    return out


def plot_sensitivity(result: SobolResult, oat: dict | None, path, *, slosh: list[tuple[float, float]] = ()) -> Path:
    """PNG: S1 and ST vs time (95 % CI bands) and the one-at-a-time pressure curves.

    Args:
        result: a ``SobolResult``.
        oat: the ``one_at_a_time`` dict, or None (then only the index panels).
        path: the PNG file to write.
        slosh: sloshing intervals (s) to shade (``slosh_intervals``).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    layout = [["S1", "S1", "ST", "ST"]] + ([list(NAMES)] if oat is not None else [])
    fig, ax = plt.subplot_mosaic(layout, figsize=(13, 8 if oat is not None else 4.5), layout="constrained")
    t = result.t_s
    for key, conf, title in (("S1", "S1_conf", "first-order index $S_1$"), ("ST", "ST_conf", "total index $S_T$")):
        a = ax[key]
        S, C = getattr(result, key), getattr(result, conf)
        for i, name in enumerate(result.names):
            a.plot(t, S[:, i], color=colors[i], label=name)
            a.fill_between(t, S[:, i] - C[:, i], S[:, i] + C[:, i], color=colors[i], alpha=0.2, lw=0)
        for t0, t1 in slosh:
            a.axvspan(t0, t1, color="0.9", zorder=0)
        a.set_xlabel("time t [s]")
        a.set_ylabel(f"{key} of p_v [-]")
        a.set_ylim(-0.1, 1.1)
        a.set_title(f"{title} (95 % CI), {result.run_name}, spread ±{result.spread:g}, N={result.n_base}")
        a.legend(loc="best", fontsize=8)
    if oat is not None:
        m = oat["multipliers"]
        cmap = plt.get_cmap("coolwarm")
        for i, name in enumerate(NAMES):
            a = ax[name]
            for k, mk in enumerate(m):
                a.plot(oat["t_s"], oat["p_v_Pa"][i, k] / 1e3, color=cmap(k / max(len(m) - 1, 1)), lw=1,
                       label=f"×{mk:.2f}")
            for t0, t1 in slosh:
                a.axvspan(t0, t1, color="0.9", zorder=0)
            a.set_title(f"one at a time: {name}")
            a.set_xlabel("time t [s]")
            a.set_ylabel("ullage pressure p_v [kPa]")
            a.legend(fontsize=7)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


__all__ = ["ScaledClosure", "SobolResult", "sobol_indices", "sobol_analyze", "saltelli_sample", "one_at_a_time",
           "plot_sensitivity", "slosh_intervals", "NAMES"]
