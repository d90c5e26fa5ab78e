"""Supervised fit of an MLP closure to known coefficients: what its inputs can represent.

Assimilation learns the closure from observations through the ODE; whether the learned agent
can generalise to an unseen environment is bounded by something simpler: could the MLP, given
the true coefficients along the training trajectories, predict them on the unseen one? This
module answers that for synthetic data, where the reference closure is known, which separates
a representation limit (the inputs or the environments) from an optimisation one.
"""

from __future__ import annotations

import torch
from torch import Tensor

from tankode.closures import Closure, ClosureInputs, MLPClosure, ReferenceClosure
from tankode.closures.mlp import mlp_features
from tankode.run import Run
from tankode.simulation import Solution

from .evaluate import closure_along


class _Recorder(Closure):
    """The reference closure, recording the features and the coefficients it is asked for."""

    def __init__(self, feature_sets: dict[str, tuple[str, ...]]):
        super().__init__()
        self.reference = ReferenceClosure()
        self.feature_sets = feature_sets
        self.features: dict[str, list[Tensor]] = {k: [] for k in feature_sets}
        self.theta: list[Tensor] = []

    def forward(self, x: ClosureInputs) -> Tensor:
        theta = self.reference(x)
        for k, names in self.feature_sets.items():
            self.features[k].append(mlp_features(x, names).detach())
        self.theta.append(theta.detach())
        return theta


def reference_samples(run: Run, truth: Solution, feature_sets: dict[str, tuple[str, ...]]):
    """Features and reference coefficients at every output time of ``truth``.

    Returns ``({set name: (T, n_features)}, (T, 4) coefficients in W/(m^2 K))``.
    """
    rec = _Recorder(feature_sets)
    closure_along(rec, [run], truth)
    return {k: torch.cat(v) for k, v in rec.features.items()}, torch.cat(rec.theta)


def fit_supervised(closure: MLPClosure, features: Tensor, theta_W_m2K: Tensor, *, weight_decay: float,
                   max_iter: int) -> float:
    """Fit ``closure``'s weights in place to ``ln theta`` (least squares plus ``weight_decay * |w|^2``).

    Args:
        closure: the MLP; its ``config.features`` must be the columns of ``features``.
        features: ``(N, n_features)`` scaled inputs.
        theta_W_m2K: ``(N, 4)`` target coefficients.
        weight_decay: L2 penalty on every weight (the MLP has no other regulariser here).
        max_iter: L-BFGS iterations (strong Wolfe).

    Returns:
        The final mean squared error of ``ln theta`` (without the penalty).
    """
    if features.shape[-1] != len(closure.config.features):
        raise ValueError(f"features have {features.shape[-1]} columns, the closure expects "
                         f"{len(closure.config.features)} ({closure.config.features})")
    params = list(closure.net.parameters())
    target = torch.log(theta_W_m2K)
    opt = torch.optim.LBFGS(params, max_iter=max_iter, line_search_fn="strong_wolfe", tolerance_grad=1e-12,
                            tolerance_change=1e-14)

    def objective():
        opt.zero_grad()
        loss = (closure.log_theta(features) - target).pow(2).mean() + weight_decay * sum(p.pow(2).sum() for p in params)
        loss.backward()
        return loss

    opt.step(objective)
    with torch.no_grad():
        return float((closure.log_theta(features) - target).pow(2).mean())


def log_error(closure: MLPClosure, features: Tensor, theta_W_m2K: Tensor) -> Tensor:
    """``|ln theta_closure - ln theta_ref|`` ``(N, 4)``."""
    with torch.no_grad():
        return (closure.log_theta(features) - torch.log(theta_W_m2K)).abs()


__all__ = ["reference_samples", "fit_supervised", "log_error"]
