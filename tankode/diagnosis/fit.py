"""Bounded nonlinear least squares of normalised residuals over a few physical parameters.

The diagnosis fits at most a handful of parameters (four closure multipliers and one or two of
a mechanism) to long, possibly stiff runs. Finite-difference Levenberg-Marquardt on the
forward solver is the right tool there: each Jacobian is one batched LSODA simulation of the
``n + 1`` points (LSODA handles a light wall's stiffness that an explicit adjoint integration
cannot afford), the problems are nearly linear in the mechanism parameters so Gauss-Newton converges
in a few iterations, and the Jacobian is the one the Fisher information, the score test and
the parameter uncertainties need anyway. Bounds are kept by projecting each step onto the box
(SciPy's reflective trust region crawls away from a bound where a mechanism starts, at 0).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import SimulationError
from .forward import FreeParam, Problem

# Residual of a trial point the solver could not integrate: large enough that the trust
# region rejects the step and shrinks (in units of sigma, per sample).
_FAILED_RESIDUAL = 1.0e3


@dataclass(frozen=True)
class Fit:
    """The result of one calibration.

    Attributes:
        params: the fitted parameters (``FreeParam``), in order.
        values: their estimates in physical units ``(n,)``.
        std: their standard errors ``(n,)`` from the Gauss-Newton covariance, inflated by the
            reduced chi-square when it exceeds 1 (misfit the noise does not explain); 0 for a
            parameter held fixed by a degenerate box (lower == upper).
        chi2: sum of squared normalised training residuals at the estimate.
        n_data: number of training residuals.
        pred: ``(env, T, 5)`` predicted observations at the estimate (the whole run).
        jac: ``(n_data, n)`` Jacobian of the training residuals w.r.t. ``z = value / scale``.
        n_simulations: forward simulations spent.
        status: how the iterations ended.
        corr: ``(n, n)`` correlation of the estimates, from the same covariance as ``std``
            (identity rows and columns for a parameter held fixed).
    """

    params: list
    values: np.ndarray
    std: np.ndarray
    chi2: float
    n_data: int
    pred: np.ndarray
    jac: np.ndarray
    n_simulations: int
    status: str
    corr: np.ndarray

    def strongest_partner(self, owner: str, name: str) -> tuple[FreeParam, float] | None:
        """The other parameter whose estimate is most correlated with ``owner.name``'s, and the correlation.

        A presence parameter that is not resolved (its standard error comparable to its value)
        usually trades off with one other freedom: this names it. ``None`` with a single parameter.
        """
        i = self._index(owner, name)
        others = [k for k in range(len(self.params)) if k != i]
        if not others:
            return None
        k = max(others, key=lambda k: abs(self.corr[i, k]))
        return self.params[k], float(self.corr[i, k])

    def nuisance_free(self, r: np.ndarray) -> np.ndarray:
        """Which parameters may still move at the estimate ``(n,)`` bool, given its training residuals ``r``.

        A parameter held by a degenerate box, or on a bound that the data pull it beyond, is
        locally fixed (the active set of the fit's own iterations); the others are free.
        """
        scale, lo, hi = normalised_box(self.params)
        return _free(self.values / scale, self.jac.T @ r, lo, hi)

    def value(self, owner: str, name: str) -> float:
        return float(self.values[self._index(owner, name)])

    def _index(self, owner: str, name: str) -> int:
        for k, p in enumerate(self.params):
            if p.owner == owner and p.name == name:
                return k
        raise KeyError(f"{owner}.{name}")


def fit(problem: Problem, params: list[FreeParam], x0: np.ndarray, train: np.ndarray, max_iterations: int = 15) -> Fit:
    """Fit ``params`` to the observations selected by ``train`` (``(env, T)`` bool).

    Args:
        problem: the forward map.
        params: the parameters to fit; all others stay at 0 (absent) or 1 (closure multipliers).
        x0: starting values in physical units ``(n,)`` (clipped into the bounds).
        train: which sample times calibrate.
        max_iterations: bound on Gauss-Newton iterations (each one batched Jacobian simulation
            and one or more trial simulations, a damping ladder batched in one).

    Raises:
        SimulationError: the model cannot even be integrated at the starting point.
    """
    scale, lo, hi = normalised_box(params)
    z0 = np.clip(np.asarray(x0, float) / scale, lo, hi)
    sel = train[:, :, None] & problem.obs.measured  # (env, T, 5)
    n_data = int(sel.sum())
    if n_data <= len(params):
        runs = ", ".join(repr(n) for n in problem.obs.run_names)
        raise ValueError(f"run {runs}: {n_data} calibration readings cannot determine {len(params)} parameters "
                         f"({', '.join(p.name for p in params)}); the run is too short or too sparsely measured")
    start = problem.n_simulations
    cache: dict[bytes, np.ndarray] = {}

    def residual(z: np.ndarray) -> np.ndarray:
        """Residuals ``(n_data,)`` for ``z`` ``(n,)``, or ``(B, n_data)`` for ``(B, n)``."""
        try:
            pred = problem.predict(params, z * scale)
        except SimulationError:
            return np.full((*z.shape[:-1], n_data), _FAILED_RESIDUAL)
        for zk, pk in zip(z.reshape(-1, z.shape[-1]), pred.reshape(-1, *pred.shape[-3:])):
            cache[zk.tobytes()] = pk  # the Jacobian's rows too: its base point may end the fit
        return problem.normalised_residuals(pred)[..., sel]

    z, r, jac, status = _levenberg_marquardt(residual, z0, lo, hi, max_iterations)
    if np.all(r == _FAILED_RESIDUAL):
        problem.predict(params, z * scale)  # raises with the time and state of the failure
    if jac is None:
        jac = _jacobian(residual, z, r, lo, hi)
    pred = cache.get(z.tobytes())
    if pred is None:
        pred = problem.predict(params, z * scale)
    chi2 = float(r @ r)
    std = np.zeros(len(params))
    corr = np.eye(len(params))
    free = hi > lo  # a degenerate box holds a parameter fixed: no uncertainty, not in the covariance
    if free.any():
        dof = max(n_data - int(free.sum()), 1)
        cov = np.linalg.pinv(jac[:, free].T @ jac[:, free]) * max(1.0, chi2 / dof)
        sd = np.sqrt(np.clip(np.diag(cov), 0, None))
        std[free] = sd * scale[free]
        # A parameter the data do not move at all (a zero Jacobian column: sd = 0) correlates with nothing.
        inv = np.divide(1.0, sd, out=np.zeros_like(sd), where=sd > 0)
        c = cov * np.outer(inv, inv)
        np.fill_diagonal(c, 1.0)
        corr[np.ix_(free, free)] = np.clip(c, -1.0, 1.0)
    return Fit(list(params), z * scale, std, chi2, n_data, pred, jac, problem.n_simulations - start, status, corr)


def normalised_box(params: list[FreeParam]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(scale, lower / scale, upper / scale)``, each ``(n,)``: the box the fit variables ``z = value / scale`` live in."""
    scale = np.array([p.scale for p in params], dtype=float)
    return scale, np.array([p.lower for p in params]) / scale, np.array([p.upper for p in params]) / scale


def _jacobian(residual, z: np.ndarray, r: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Forward differences, stepping inwards at an upper bound; ``(n_data, n)`` w.r.t. ``z``.

    The base point and the n perturbed points run as one batched simulation (one step
    sequence), so the differences are free of step-selection noise; ``r`` is not reused.
    """
    # 1e-3 normalised units resolve the response far above LSODA's error at rtol 1e-8.
    h = 1e-3 * np.maximum(1.0, np.abs(z))
    h = np.where(z + h > hi, -h, h)
    Z = np.repeat(z[None], len(z) + 1, axis=0)  # (n + 1, n)
    # A degenerate box (lower == upper) holds a parameter fixed: not perturbed (a zero column,
    # unused), since either step would leave its physical range (e.g. a share at 0 or 1).
    Z[1:] += np.diag(np.where(hi > lo, h, 0.0))
    R = residual(Z)  # (n + 1, n_data)
    return ((R[1:] - R[0]) / h[:, None]).T


def _free(z: np.ndarray, g: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Not in the active set: a variable on a bound whose descent direction (``-g``, ``g`` the
    gradient of chi2 / 2) leaves the box stays there, and a degenerate box holds it.

    "On a bound" allows a relative 1e-9, since ``z`` may have been through ``value / scale``.
    """
    tol = 1e-9 * np.maximum(1.0, np.maximum(np.abs(lo), np.abs(hi)))
    return ~(((z <= lo + tol) & (g > 0)) | ((z >= hi - tol) & (g < 0))) & (hi > lo)


_LADDER = 4  # damping values tried at once after a rejected step (one batched simulation)
_NEGLIGIBLE_CHI2 = 1e-2  # a chi2 change of 0.01 is statistically nothing (a 0.1-sigma shift of one sample)


def _levenberg_marquardt(residual, z0, lo, hi, max_iterations: int):
    """Projected Levenberg-Marquardt; returns ``(z, r, jac at z or None, status)``.

    Each iteration first tries the current damping ``lam``. After a rejection it tries the next
    ``_LADDER`` damping values (``lam`` times 10, 100, ...) as one batched simulation, which
    costs little more than one, and takes the least damped step that lowers chi2: the step the
    one-at-a-time search would take, for a fraction of its simulations (a fit whose last
    iteration finds no better point climbs through up to fifteen decades of damping). A ladder
    the batch cannot integrate is retried one value at a time. After a rejection, the search
    stops where the linearised model itself promises less than ``_NEGLIGIBLE_CHI2``.
    """
    z = z0.copy()
    r = residual(z)
    if len(z) == 0:
        return z, r, np.zeros((len(r), 0)), "nothing to fit"
    if np.all(r == _FAILED_RESIDUAL):
        return z, r, None, "the model fails at the starting point"
    chi2 = float(r @ r)
    lam = 1e-3
    for it in range(1, max_iterations + 1):
        jac = _jacobian(residual, z, r, lo, hi)
        g = jac.T @ r  # gradient of chi2 / 2
        free = _free(z, g, lo, hi)
        if not free.any():
            return z, r, jac, f"converged after {it - 1} iterations (every parameter held at a bound)"
        A = (jac.T @ jac)[np.ix_(free, free)]
        D = np.diag(np.diag(A).clip(1e-12))
        accepted = None
        lams, first = [lam], True
        while accepted is None:
            lams = [x for x in lams if x <= 1e8]
            Z, promised = [], []
            for x in lams:
                step = np.zeros_like(z)
                step[free] = s_f = np.linalg.solve(A + x * D, -g[free])
                # the linear model's chi2 gain for the unprojected step: positive, and falling as
                # the damping grows, so once negligible it stays so up the ladder
                promised.append(-(2.0 * g[free] @ s_f + s_f @ A @ s_f))
                Z.append(np.clip(z + step, lo, hi))
            # a prefix of the ladder; the first try is always made (its small step may still end the fit)
            keep = [k for k, p in enumerate(promised) if p >= _NEGLIGIBLE_CHI2 or first]
            first = False
            if not keep:
                return z, r, jac, f"converged after {it - 1} iterations (no step lowers chi2)"
            lams, Z = [lams[k] for k in keep], np.array([Z[k] for k in keep])
            R = residual(Z)
            if len(Z) > 1 and np.all(R == _FAILED_RESIDUAL):
                R = np.array([residual(zk) for zk in Z])
            chi2s = np.einsum("bi,bi->b", R, R)
            lower = np.flatnonzero(chi2s < chi2)
            if len(lower):
                k = int(lower[0])
                accepted = (lams[k], Z[k], R[k], float(chi2s[k]))
            else:
                lams = [lams[-1] * 10.0**j for j in range(1, _LADDER + 1)]
        gain = chi2 - accepted[3]
        lam, z, r, chi2 = max(accepted[0] / 10.0, 1e-7), accepted[1], accepted[2], accepted[3]
        if gain < _NEGLIGIBLE_CHI2:
            return z, r, None, f"converged after {it} iterations (chi2 change {gain:.1e})"
    return z, r, None, f"stopped after {max_iterations} iterations"


__all__ = ["Fit", "fit"]
