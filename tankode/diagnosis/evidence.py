"""Evidence for a candidate mechanism: score test, information criteria, held-out gain."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import SimulationError
from .fit import Fit, normalised_box
from .forward import FreeParam, Problem, mechanism_params
from .residuals import loss_from_terms

# Finite-difference step of the score test in normalised units: one typical magnitude of the
# parameter, where its response is still close to linear and far above the solver's error.
SCORE_STEP = 1.0
# Step fractions tried in turn when the perturbed simulation fails (leaves the property domain).
SCORE_STEP_SHRINK = (1.0, 0.1, 0.01)


@dataclass(frozen=True)
class Score:
    """Rao's score test of one mechanism at 0, given the calibrated closure.

    Attributes:
        mechanism: the mechanism id.
        statistic: ``U^T I^-1 U`` with U the efficient score (the gradient of -chi2/2 w.r.t.
            the mechanism's normalised parameters with the closure's directions projected out)
            and I its Fisher information; chi-square with k degrees of freedom if the mechanism
            is absent and the noise white. 0 when the data pull the parameter out of its bounds.
            The nuisance directions projected out are the closure's free ones at the baseline
            (a factor held on a bound is locally fixed: the constrained score).
        one_step: the one-step estimate ``I^-1 U`` in physical units (starting point of the refit).
    """

    mechanism: str
    statistic: float
    one_step: dict


def score_tests(problem: Problem, baseline: Fit, candidates: list[str], train: np.ndarray) -> list[Score]:
    """Score every candidate at 0 from one batched simulation (baseline + one perturbation per parameter)."""
    mparams = [p for mid in candidates for p in mechanism_params(mid)]
    params = list(baseline.params) + mparams
    base_steps = np.array([SCORE_STEP * p.scale if p.upper > 0 else -SCORE_STEP * p.scale for p in mparams])
    # A full step can drive a small ullage out of the property domain (e.g. 100 W into 2 m^3 of
    # vapor for hours); the score is a derivative, so a smaller step measures the same thing.
    for shrink in SCORE_STEP_SHRINK:
        steps = base_steps * shrink
        V = np.repeat(np.concatenate([baseline.values, np.zeros(len(mparams))])[None], len(mparams) + 1, axis=0)
        V[1:, len(baseline.params):] += np.diag(steps)
        try:
            pred = problem.predict(params, V)  # (1 + m, env, T, 5)
            break
        except SimulationError:
            if shrink == SCORE_STEP_SHRINK[-1]:
                raise
    sel = train[:, :, None] & problem.obs.measured
    R = problem.normalised_residuals(pred)[:, sel]  # (1 + m, n_data)
    r = R[0]
    S = ((R[1:] - r) / (steps / np.array([p.scale for p in mparams]))[:, None]).T  # (n_data, m), per normalised unit
    # Orthonormal basis of the directions the closure can still take (rank-revealing: h_vi may
    # have none). A factor on a bound the data pull it beyond cannot move that way, so it cannot
    # mimic the mechanism: projecting it out too would zero the score of whatever resembles it
    # (on the MHTB tests, with every factor at a bound, a whole mechanism would drop out of the
    # ranking's top; experiments/README.md).
    Sc = baseline.jac[:, baseline.nuisance_free(r)]  # (n_data, n_free)
    Q = np.zeros((len(r), 0))
    if Sc.size:
        u, sv, _ = np.linalg.svd(Sc, full_matrices=False)
        Q = u[:, sv > 1e-10 * sv.max()] if sv.max() > 0 else Q
    out = []
    col = 0
    for mid in candidates:
        ps = mechanism_params(mid)
        Sm = S[:, col:col + len(ps)]
        col += len(ps)
        St = Sm - Q @ (Q.T @ Sm)  # what the closure cannot mimic
        U = -St.T @ r
        info = St.T @ St
        step = np.linalg.pinv(info) @ U  # normalised units
        _, lo, hi = normalised_box(ps)
        feasible = np.clip(step, lo, hi)
        stat = float(U @ np.linalg.pinv(info) @ U) if np.allclose(feasible, step) else float(
            max(0.0, 2 * (U @ feasible) - feasible @ info @ feasible))
        out.append(Score(mid, stat, {p.name: float(v * p.scale) for p, v in zip(ps, feasible)}))
    return out


def bootstrap_gain(base_terms, ext_terms, n_boot: int = 2000, seed: int = 0, level: float = 0.95):
    """Relative held-out loss reduction ``1 - L_ext / L_base`` and its block-bootstrap interval.

    Args:
        base_terms, ext_terms: ``(ss, nn)`` per-block sums of squares and counts (``heldout_terms``)
            of the baseline and the extended model on the same blocks.
        n_boot: bootstrap resamples of the blocks.
        level: two-sided confidence level of the percentile interval.

    Returns:
        ``(gain, (low, high))``.
    """
    (ssb, nnb), (sse, nne) = base_terms, ext_terms
    Lb, _ = loss_from_terms(ssb, nnb)
    Le, _ = loss_from_terms(sse, nne)
    if not Lb > 0:
        raise ValueError("the held-out part has no observations to judge a gain on")
    gain = 1.0 - Le / Lb
    rng = np.random.default_rng(seed)
    n = len(ssb)
    gains = np.empty(n_boot)
    for i in range(n_boot):
        k = rng.integers(0, n, n)
        gains[i] = 1.0 - loss_from_terms(sse[k], nne[k])[0] / loss_from_terms(ssb[k], nnb[k])[0]
    a = (1 - level) / 2
    return gain, (float(np.quantile(gains, a)), float(np.quantile(gains, 1 - a)))


def information_criteria(base: Fit, ext: Fit) -> dict:
    """Likelihood ratio and the changes of BIC and AIC from the baseline to the extended fit.

    With Gaussian noise of known sigma, -2 ln L = chi2 + const, so LR = chi2_base - chi2_ext,
    dBIC = -LR + k ln n and dAIC = -LR + 2k (k added parameters, n training observations).
    Negative = the extension is supported. These assume white noise; residuals correlated by
    model error inflate LR, which is why the held-out gain is required as well.
    """
    k = len(ext.params) - len(base.params)
    lr = base.chi2 - ext.chi2
    return {"likelihood_ratio": lr, "delta_bic": -lr + k * np.log(ext.n_data), "delta_aic": -lr + 2 * k, "k": k}


__all__ = ["Score", "score_tests", "bootstrap_gain", "information_criteria", "FreeParam"]
