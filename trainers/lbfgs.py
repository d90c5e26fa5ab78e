"""Bounded, mini-batch L-BFGS: ``torch.optim.LBFGS`` (strong Wolfe) in a bound-respecting latent space.

Every trained parameter ``w`` has a box ``lower <= w <= upper``. The optimiser never moves ``w``
itself: it runs the unmodified ``torch.optim.LBFGS(line_search_fn="strong_wolfe")`` on an
unconstrained latent variable ``z`` of the same shape and writes ``w = fold(z)`` into the parameter
before every closure evaluation; the gradient follows by the exact elementwise chain rule
``dL/dz = dL/dw * fold'(z)``.

``fold`` is a *smoothed reflection* of the real line onto the box. With ``W = upper - lower`` and
a cap width ``eps = 0.05 W``, one fold is, in ``r = z - z0`` (``z0 = lower - eps/2``):

    lower + r**2 / (2 eps)                for 0 <= r <= eps          (lower cap)
    lower + r - eps/2   (i.e. w = z)      for eps <= r <= P - eps    (straight part)
    upper - (P - r)**2 / (2 eps)          for P - eps <= r <= P      (upper cap),   P = W + eps,

continued to all ``z`` as a mirror image (period ``2P``), like a ray reflected between the bounds.
It is continuously differentiable, and its properties are the reasons for the choice:

* ``w`` is inside its box for *every* ``z``, so every closure call -- line-search trial points
  included -- sees admissible parameters (the ODE inside the loss may blow up outside).
* Away from the bounds (all but the outer 2.5 % of the box on each side) the fold is linear with
  slope +-1 (``w = z`` on the first fold): a parameter whose bounds are not active is optimised
  exactly as by plain ``torch.optim.LBFGS``, which is invariant to such shifts and reflections.
* A bound is reached exactly (at the tip of a cap), and an optimum on a bound with a non-zero
  gradient ``g`` pointing out of the box becomes a regular minimum in ``z``: the cap is exactly
  quadratic, so the loss is ``L* + |g| r**2 / (2 eps)`` there, L-BFGS converges to it quickly, and
  the curvature pairs, all built in ``z``, are secant pairs of one C1 function (torch skips pairs
  with ``y.s <= 1e-10``, e.g. across a fold, so the history stays positive definite).

Measured on the problems of ``tests/test_lbfgs.py`` (iterations to scipy's optimum; quadratic
8-D, Rosenbrock 2-D with x on a bound / y on a bound / optimum inside, convex 30-D, chained
Rosenbrock 20-D): scipy's L-BFGS-B 14, 17, 8, 16, 51, 14; the fold 19, 28, 25, 35, 55, 32 (35 on
the interior problem is exactly plain ``torch.optim.LBFGS``); the sine map ``w = mid + half
sin(z)``, curved everywhere so that even interior parameters see a distorted problem, 36, 27, 23,
28, 104, 56. A sigmoid reaches a bound only as ``z -> inf`` with an exponentially vanishing
gradient (slow, never exact). A genuine projected L-BFGS (L-BFGS-B: Cauchy point, subspace
minimisation, line search along the projected path) identifies active bounds in one step and is
the fastest on bound optima, but it is a re-implementation of the optimiser, not a wrapper.

Mini-batches (:class:`MiniBatch`): each :meth:`BoundedLBFGS.step` draws a boolean mask over the
window's ``n_samples`` observation times from a seeded ``torch.Generator`` and runs up to
``max_iter`` L-BFGS iterations on that batch's loss. A pair spanning a batch change,
``y = g_new(z1) - g_old(z0)``, is the difference of gradients of two different functions and no
secant pair at all, so the history is kept consistent by one of two strategies:

* :class:`ResetHistory` -- independent batches; the L-BFGS history is cleared at every batch
  change (always valid; the first iteration on a new batch is a steepest-descent step whose
  length the strong-Wolfe search has to find).
* :class:`OverlapBatches` -- multi-batch L-BFGS (Berahas, Nocedal & Takac, NeurIPS 2016):
  consecutive batches share a fixed number of samples ``O``; the pairs from earlier batches are
  kept (each is a secant pair of its own batch loss) and the pair spanning the change is
  computed on the overlap only, ``y = g_O(z) - g_O(z - s)`` with ``s`` the last L-BFGS step.
  This costs two closure calls on ``O`` per change and keeps the quasi-Newton scaling.

``fraction = 1.0`` is the full batch: the mask never changes and the history is kept across outer
steps, as with plain ``torch.optim.LBFGS``.

Closure contract: ``closure(mask)`` -- ``closure()`` when there is no :class:`MiniBatch` -- builds
the loss from the module's parameters and returns it as a scalar tensor that requires grad. It must
*not* call ``backward``/``zero_grad``: the optimiser clears the parameters' ``.grad`` before each
call, checks that the closure left them alone and back-propagates itself. With mini-batches the
closure should return the *mean* over the masked samples (not the sum), so that curvature pairs
from batches and overlaps of different sizes estimate the same Hessian; it is also called with the
overlap mask by :class:`OverlapBatches`.

Honest limits:

* Parameters must start strictly inside their box: on a bound the fold has zero slope, the latent
  gradient vanishes and the coordinate could never move.
* A coordinate that converged onto a bound sits at the tip of a cap, where the slope is at most
  about ``tolerance_grad / |g|``; if a later batch pulls it back inside, it leaves slowly (its latent
  gradient is tiny and the direction is one of negative curvature in ``z``). An active-set method
  releases it in one step.
* An optimum on a bound where the gradient is exactly zero is a quartic minimum in ``z``
  (sublinear convergence). Near a bound ``w`` resolves ``r**2 / (2 eps)`` only to the float
  spacing of the bound, which limits how precisely a cap minimum is located in ``z`` (harmless
  for ``w`` and the loss, which are then on the bound to rounding).
* Stopping tests are torch's and act in ``z`` (``tolerance_grad`` on the max-norm of the latent
  gradient, ``tolerance_change`` on step and loss changes); :attr:`StepResult.proj_grad_norm` is
  the optimality measure in ``w`` (L-BFGS-B's projected gradient) for the caller to judge.
* The optimiser reads and edits the state layout of ``torch.optim.LBFGS`` (``d``, ``t``,
  ``old_dirs``, ``old_stps``, ``ro``, ``H_diag``, ``n_iter``); ``tests/test_lbfgs.py`` pins it.
* A closure may end a step early by raising :class:`StopStep` (e.g. a wall-clock budget spent):
  the step then ends at the best point it evaluated, not at the line search's trial point, and
  the curvature history is cleared (the interrupted line search left it mid-update).
* The parameters' values are rounded once at construction to ``fold(z(w))`` (a few ulps), so that
  the module and the latent state agree bit for bit from the start.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field

import torch
from torch import Tensor, nn

__all__ = [
    "Box", "uniform_box", "ResetHistory", "OverlapBatches", "MiniBatch", "StepResult", "StopStep", "BoundedLBFGS",
]

# Width of each quadratic cap of the fold, as a fraction of the box width. Measured (module
# docstring): 0.03 - 0.1 all do well; much smaller caps make the fold's curvature jump too abrupt
# for the line search, much larger ones distort the interior like the sine map.
_CAP = 0.05
# A parameter counts as "at" a bound when within this fraction of its box width of it. The fold
# converges onto a bound optimum to ~ (eps * tolerance_grad / |g|)**2 / eps, far below.
_ACTIVE_RTOL = 1e-9
# Loss given to the line search at a rejected (infeasible) trial point: above any feasible loss,
# finite so that torch's cubic interpolation stays finite.
INFEASIBLE_LOSS = 1e30
# torch.optim.LBFGS skips pairs with y.s <= 1e-10; the overlap pair uses the same safeguard.
_MIN_CURVATURE = 1e-10

Closure = Callable[..., Tensor]
NamedParams = nn.Module | Mapping[str, Tensor] | Iterable[tuple[str, Tensor]]


# ----------------------------------------------------------------------------------------------
# Bounds
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Box:
    """Box bounds ``lower <= w <= upper`` for one parameter.

    Attributes:
        lower: float or tensor broadcastable to the parameter's shape; finite.
        upper: float or tensor broadcastable to the parameter's shape; finite and ``> lower``
            everywhere (strictly: a zero-width box pins the parameter, so it should not be trained).
    """

    lower: float | Tensor
    upper: float | Tensor

    def __post_init__(self):
        try:
            lo, hi = torch.broadcast_tensors(torch.as_tensor(self.lower, dtype=torch.float64),
                                             torch.as_tensor(self.upper, dtype=torch.float64))
        except (RuntimeError, TypeError, ValueError) as e:
            raise ValueError(f"Box: lower and upper must be floats or broadcastable tensors ({e})") from None
        _check_range("Box", lo, hi)

    def resolve(self, name: str, param: Tensor) -> tuple[Tensor, Tensor]:
        """The bounds expanded to ``param``'s shape, dtype and device: ``(lower, upper)``.

        Raises:
            ValueError: naming ``name``, when the bounds do not broadcast to the parameter's shape.
        """
        lo = torch.as_tensor(self.lower, dtype=param.dtype, device=param.device)
        hi = torch.as_tensor(self.upper, dtype=param.dtype, device=param.device)
        try:
            lo, hi = lo.expand(param.shape).clone(), hi.expand(param.shape).clone()
        except RuntimeError:
            raise ValueError(f"bounds for parameter {name!r}: lower {tuple(lo.shape)} / upper {tuple(hi.shape)} "
                             f"do not broadcast to its shape {tuple(param.shape)}") from None
        # Re-check in the parameter's dtype: float64 bounds may collapse when rounded to float32.
        _check_range(f"bounds for parameter {name!r}", lo, hi)
        return lo, hi


def _check_range(what: str, lo: Tensor, hi: Tensor) -> None:
    """Raise ValueError unless both bounds are finite and ``lo < hi`` everywhere."""
    for label, b in (("lower", lo), ("upper", hi)):
        bad = ~torch.isfinite(b)
        if bad.any():
            i = _first(bad)
            raise ValueError(f"{what}: the {label} bound must be finite, got {b[i].item()} at index {i}")
    bad = ~(lo < hi)
    if bad.any():
        i = _first(bad)
        raise ValueError(f"{what}: need lower < upper, got the range [{lo[i].item()}, {hi[i].item()}] at index {i}")


def _first(mask: Tensor) -> tuple[int, ...]:
    """Index of the first True entry of a boolean tensor (``()`` for a 0-d one)."""
    return tuple(int(k) for k in mask.nonzero()[0]) if mask.dim() else ()


def _named_params(params: NamedParams) -> list[tuple[str, Tensor]]:
    """(name, tensor) pairs from a module (its trainable parameters), a mapping or an iterable of pairs."""
    if isinstance(params, nn.Module):
        return [(n, p) for n, p in params.named_parameters() if p.requires_grad]
    if isinstance(params, Mapping):
        return list(params.items())
    pairs = list(params)
    if not all(isinstance(q, tuple) and len(q) == 2 and isinstance(q[0], str) for q in pairs):
        raise TypeError("params must be an nn.Module, a mapping name -> tensor or an iterable of (name, tensor)")
    return pairs


def uniform_box(params: NamedParams, lower: float, upper: float) -> dict[str, Box]:
    """The same box ``[lower, upper]`` for every trainable parameter.

    Args:
        params: a module (its parameters with ``requires_grad``), a mapping name -> tensor or an
            iterable of ``(name, tensor)`` pairs (e.g. ``module.named_parameters()``).
        lower, upper: finite floats, ``lower < upper``.

    Returns:
        dict name -> Box, the ``bounds`` argument of :class:`BoundedLBFGS`.
    """
    box = Box(float(lower), float(upper))
    return {name: box for name, _ in _named_params(params)}


class _Fold:
    """The smoothed reflection ``w = fold(z)`` of the real line onto one parameter's box.

    Piecewise: quadratic caps of width ``eps`` at the bounds, ``w = z`` in between (first fold),
    mirrored with period ``2P``; see the module docstring. All tensors have the parameter's shape.
    """

    def __init__(self, lo: Tensor, hi: Tensor):
        self.lo, self.hi = lo, hi
        self.eps = _CAP * (hi - lo)
        self.P = (hi - lo) + self.eps  # z-length of one fold, lower tip to upper tip
        self.z0 = lo - self.eps / 2  # so that w = z on the straight part of the first fold

    def _r(self, z: Tensor) -> tuple[Tensor, Tensor]:
        """Position ``r`` in [0, P] within the fold, and whether the fold runs upwards."""
        v = torch.remainder(z - self.z0, 2 * self.P)
        up = v <= self.P
        return torch.where(up, v, 2 * self.P - v), up

    def w(self, z: Tensor) -> Tensor:
        r, _ = self._r(z)
        e, P = self.eps, self.P
        w = torch.where(r <= e, self.lo + r * r / (2 * e),
                        torch.where(r >= P - e, self.hi - (P - r) ** 2 / (2 * e), self.lo + (r - e / 2)))
        return torch.clamp(w, self.lo, self.hi)  # exact arithmetic stays inside; this guards rounding

    def slope(self, z: Tensor) -> Tensor:
        """dw/dz, in [-1, 1]; zero exactly at the bounds."""
        r, up = self._r(z)
        e, P = self.eps, self.P
        s = torch.where(r <= e, r / e, torch.where(r >= P - e, (P - r) / e, torch.ones_like(r)))
        return torch.where(up, s, -s)

    def z_of(self, w: Tensor) -> Tensor:
        """The latent point on the first (upward) fold that maps to ``w`` (inside the box)."""
        q, e = w - self.lo, self.eps
        r = torch.where(q <= e / 2, torch.sqrt((2 * e * q).clamp_min(0)),
                        torch.where(q >= (self.hi - self.lo) - e / 2,
                                    self.P - torch.sqrt((2 * e * (self.hi - w)).clamp_min(0)), q + e / 2))
        return self.z0 + r


# ----------------------------------------------------------------------------------------------
# Mini-batch configuration and history strategies
# ----------------------------------------------------------------------------------------------


def _random_subset(indices: Tensor, k: int, gen: torch.Generator) -> Tensor:
    """``k`` distinct entries of the index tensor ``indices``, uniformly at random."""
    return indices[torch.randperm(len(indices), generator=gen)[:k]]


@dataclass(frozen=True)
class ResetHistory:
    """Independent random batch each outer step; the L-BFGS history is cleared at every batch change."""

    def _check(self, n_samples: int, n_batch: int) -> None:
        pass

    def _draw(self, prev: Tensor | None, n_samples: int, n_batch: int, gen: torch.Generator) -> Tensor:
        mask = torch.zeros(n_samples, dtype=torch.bool)
        mask[torch.randperm(n_samples, generator=gen)[:n_batch]] = True
        return mask

    def _on_batch_change(self, opt: BoundedLBFGS, prev: Tensor, new: Tensor, closure: Closure) -> None:
        opt._reset_history()


@dataclass(frozen=True)
class OverlapBatches:
    """Multi-batch L-BFGS: consecutive batches share ``round(overlap * batch size)`` samples.

    At a batch change the pair ``y = g_O(z) - g_O(z - s)``, ``s`` the last L-BFGS step, is
    computed on the shared samples ``O`` and appended to the kept history (two closure calls on
    ``O``); the pair torch would form from two different batch losses is suppressed.

    Attributes:
        overlap: fraction of a batch carried over from the previous batch, in (0, 1). The number
            of shared samples must be at least 1 and at most ``batch - 1``, and the remaining
            ``batch - shared`` samples are drawn from outside the previous batch, so there must be
            that many: ``batch - shared <= n_samples - batch``.
    """

    overlap: float = 0.5

    def __post_init__(self):
        if not (math.isfinite(self.overlap) and 0.0 < self.overlap < 1.0):
            raise ValueError(f"OverlapBatches.overlap must be in (0, 1), got {self.overlap}")

    def _n_shared(self, n_batch: int) -> int:
        return round(self.overlap * n_batch)

    def _check(self, n_samples: int, n_batch: int) -> None:
        k = self._n_shared(n_batch)
        if not 1 <= k <= n_batch - 1:
            raise ValueError(f"OverlapBatches: a batch of {n_batch} samples with overlap {self.overlap} shares {k}; "
                             f"need 1 <= shared <= {n_batch - 1}")
        if n_batch - k > n_samples - n_batch:
            raise ValueError(f"OverlapBatches: a batch of {n_batch} of {n_samples} samples sharing {k} with the "
                             f"previous one needs {n_batch - k} new samples, but only {n_samples - n_batch} lie "
                             f"outside it; lower the fraction or raise the overlap")

    def _draw(self, prev: Tensor | None, n_samples: int, n_batch: int, gen: torch.Generator) -> Tensor:
        if prev is None:
            return ResetHistory()._draw(prev, n_samples, n_batch, gen)
        k = self._n_shared(n_batch)
        mask = torch.zeros(n_samples, dtype=torch.bool)
        mask[_random_subset(prev.nonzero().squeeze(1), k, gen)] = True
        mask[_random_subset((~prev).nonzero().squeeze(1), n_batch - k, gen)] = True
        return mask

    def _on_batch_change(self, opt: BoundedLBFGS, prev: Tensor, new: Tensor, closure: Closure) -> None:
        opt._bridge_on_overlap(closure, prev & new)


@dataclass(frozen=True)
class MiniBatch:
    """Which observation times each outer step uses.

    Attributes:
        fraction: share of the ``n_samples`` times in each batch, in (0, 1]; the batch has
            ``max(1, round(fraction * n_samples))`` times. 1.0 is the full batch (history kept).
        n_samples: number of observation times in the window (length of the mask).
        seed: seed of the ``torch.Generator`` that draws the masks (reproducible batches).
        history: how the L-BFGS history survives a batch change: :class:`ResetHistory` or
            :class:`OverlapBatches`.
    """

    fraction: float
    n_samples: int
    seed: int = 0
    history: ResetHistory | OverlapBatches = field(default_factory=ResetHistory)

    def __post_init__(self):
        if not (math.isfinite(self.fraction) and 0.0 < self.fraction <= 1.0):
            raise ValueError(f"MiniBatch.fraction must be in (0, 1], got {self.fraction}")
        if not (isinstance(self.n_samples, int) and self.n_samples >= 1):
            raise ValueError(f"MiniBatch.n_samples must be a positive int, got {self.n_samples!r}")
        if not isinstance(self.history, (ResetHistory, OverlapBatches)):
            raise TypeError(f"MiniBatch.history must be ResetHistory() or OverlapBatches(...), got {self.history!r}")
        if self.n_batch < self.n_samples:
            self.history._check(self.n_samples, self.n_batch)

    @property
    def n_batch(self) -> int:
        """Number of observation times per batch."""
        return max(1, round(self.fraction * self.n_samples))


# ----------------------------------------------------------------------------------------------
# The optimiser
# ----------------------------------------------------------------------------------------------


class StopStep(Exception):
    """Raised by a closure to end the current :meth:`BoundedLBFGS.step` at the best point evaluated
    so far (lowest loss); at the step's first evaluation, where there is none, it propagates."""


@dataclass(frozen=True)
class StepResult:
    """What one outer step did; losses are on this step's batch.

    Attributes:
        loss_before: loss at the start point.
        loss_after: loss at the end point (no extra evaluation: taken from the line search).
        n_evals: closure calls in this step (including overlap evaluations).
        n_iters: L-BFGS iterations in this step.
        grad_norm: max-norm of the latent gradient dL/dz at the end point (torch's stopping test).
        proj_grad_norm: max-norm of the projected gradient dL/dw at the end point (zero where a
            parameter is at a bound and the gradient points out of the box) -- the first-order
            optimality measure of L-BFGS-B.
        batch_fraction: share of the observation times in this step's batch (1.0 without batches).
        at_lower, at_upper: number of parameter entries at their lower / upper bound (within
            1e-9 of the box width).
        n_pairs: curvature pairs in the L-BFGS history after the step.
        stopped: whether the closure ended the step early (:class:`StopStep`).
    """

    loss_before: float
    loss_after: float
    n_evals: int
    n_iters: int
    grad_norm: float
    proj_grad_norm: float
    batch_fraction: float
    at_lower: int
    at_upper: int
    n_pairs: int
    stopped: bool = False


@dataclass(frozen=True)
class _Eval:
    """One closure evaluation during ``torch.optim.LBFGS.step``: flat latent point, loss, gradients."""

    z: Tensor
    loss: float
    grad_z: Tensor
    grad_w: Tensor


class BoundedLBFGS:
    """L-BFGS with strong Wolfe line search, box bounds on every parameter, optional mini-batches.

    Args:
        params: the trained parameters: an ``nn.Module`` (its parameters with ``requires_grad``),
            a mapping name -> tensor, or an iterable of ``(name, tensor)`` pairs. Each tensor is a
            floating-point leaf with ``requires_grad=True``, strictly inside its box.
        bounds: mapping name -> :class:`Box`, exactly one per parameter (see :func:`uniform_box`).
        max_iter: L-BFGS iterations per :meth:`step` (torch's ``max_iter``).
        max_eval: closure calls per step inside ``torch.optim.LBFGS`` (default
            ``max_iter * 5 // 4 + 10``; torch's ``max_iter * 5 // 4`` leaves a line search of a
            step with few iterations no room: with ``max_iter=1`` it may evaluate one trial point
            and, if that is worse, never move); the two overlap evaluations of
            :class:`OverlapBatches` come on top.
        history_size: number of curvature pairs kept.
        tolerance_grad: stop when the max-norm of the latent gradient is below this.
        tolerance_change: stop when a step or a loss change is below this.
        batch: mini-batch configuration; None means ``closure()`` is called without a mask and the
            history is kept across steps.
        reject: exception types that mark a *trial point* as infeasible (e.g. an ODE that cannot
            be integrated with those parameters). Raised by the closure or its backward at any
            evaluation but a step's first, they make that point's loss huge (``INFEASIBLE_LOSS``;
            +inf would turn torch's cubic interpolation into NaN) with a zero gradient: torch's
            strong-Wolfe search then brackets it and shrinks back towards feasible points,
            and a non-finite loss is treated the same way. At a step's first evaluation they
            propagate (there is no feasible point to fall back on). Counted in ``n_rejected``.

    Memory: besides torch's history (``2 * history_size`` flat vectors), one step keeps the point
    and both gradients of each of its closure calls (3 flat vectors per call), to report the end
    point's loss and gradients without evaluating it again; sized for small models.

    After construction and after every :meth:`step` the parameters hold their bounded values, so
    the module can be used and saved normally. Do not edit them in between (the latent state would
    no longer match; :meth:`step` raises): build a new optimiser or :meth:`load_state_dict` instead.
    """

    def __init__(self, params: NamedParams, bounds: Mapping[str, Box], *, max_iter: int = 20,
                 max_eval: int | None = None, history_size: int = 10, tolerance_grad: float = 1e-9,
                 tolerance_change: float = 1e-12, batch: MiniBatch | None = None,
                 reject: tuple[type[BaseException], ...] = ()):
        named = _named_params(params)
        if not named:
            raise ValueError("BoundedLBFGS: no parameters to train")
        names = [n for n, _ in named]
        if len(set(names)) != len(names):
            raise ValueError(f"BoundedLBFGS: duplicate parameter names in {names}")
        if len({id(p) for _, p in named}) != len(named):
            raise ValueError("BoundedLBFGS: the same tensor is given under two names")
        missing, extra = set(names) - set(bounds), set(bounds) - set(names)
        if missing or extra:
            raise ValueError(f"BoundedLBFGS: bounds must name every trained parameter exactly once; "
                             f"missing {sorted(missing)}, unknown {sorted(extra)}")
        if batch is not None and not isinstance(batch, MiniBatch):
            raise TypeError(f"batch must be a MiniBatch or None, got {batch!r}")

        self._names = names
        self._params = [p for _, p in named]
        self._folds: list[_Fold] = []
        z = []
        for name, p in named:
            if not isinstance(p, Tensor) or not p.is_floating_point() or not p.is_leaf or not p.requires_grad:
                raise ValueError(f"parameter {name!r} must be a floating-point leaf tensor with requires_grad=True")
            box = bounds[name]
            if not isinstance(box, Box):
                raise TypeError(f"bounds[{name!r}] must be a Box, got {box!r}")
            fold = _Fold(*box.resolve(name, p))
            w = p.detach()
            outside = ~((w > fold.lo) & (w < fold.hi))
            if outside.any():
                i = _first(outside)
                lo, hi = fold.lo[i].item(), fold.hi[i].item()
                where = "on" if w[i].item() in (lo, hi) else "outside"
                raise ValueError(f"parameter {name!r} starts {where} its box: value {w[i].item()} at index {i}, "
                                 f"range [{lo}, {hi}]; it must start strictly inside (the bounded map has "
                                 f"zero slope on a bound)")
            zp = fold.z_of(w)
            flat = fold.slope(zp) == 0  # inside, but so close to a bound that the slope underflows
            if flat.any():
                i = _first(flat)
                raise ValueError(f"parameter {name!r} at index {i} ({w[i].item()}) is within rounding of its box "
                                 f"[{fold.lo[i].item()}, {fold.hi[i].item()}]; move it inside")
            self._folds.append(fold)
            z.append(zp)
        self._z = z
        if max_eval is None:
            max_eval = max_iter * 5 // 4 + 10
        self._lbfgs = torch.optim.LBFGS(self._z, lr=1, max_iter=max_iter, max_eval=max_eval,
                                        tolerance_grad=tolerance_grad, tolerance_change=tolerance_change,
                                        history_size=history_size, line_search_fn="strong_wolfe")
        self._history_size = history_size
        self._batch = batch
        self._gen = torch.Generator().manual_seed(batch.seed) if batch is not None else None
        self._mask: Tensor | None = None
        self._n_steps = 0
        self._n_evals = 0
        self._trace: list[_Eval] | None = None
        self._reject = tuple(reject)
        self._n_rejected = 0
        with torch.no_grad():
            self._write_params()

    # -- public ----------------------------------------------------------------------------------

    @property
    def mask(self) -> Tensor | None:
        """The current (last step's) batch mask, bool (n_samples,); None before the first step or without batches."""
        return None if self._mask is None else self._mask.clone()

    @property
    def n_steps(self) -> int:
        """Outer steps taken (restored by :meth:`load_state_dict`)."""
        return self._n_steps

    def step(self, closure: Closure) -> StepResult:
        """One outer step: draw the batch, bridge or reset the history, run ``torch.optim.LBFGS.step``.

        Args:
            closure: ``closure(mask)`` with ``mask`` bool (n_samples,) when a :class:`MiniBatch` is
                configured, else ``closure()``; returns the scalar loss (requires grad) without
                calling ``backward``.

        Returns:
            :class:`StepResult`.

        Raises:
            FloatingPointError: the closure returned a non-finite loss.
            RuntimeError: the parameters were changed outside the optimiser, or the closure called
                ``backward``.
            :class:`StopStep` from the closure ends the step at its best evaluated point instead
            (raised at the step's first evaluation, it propagates like any other exception).
            On any exception raised during the step (these, or the closure's own), the latent
            variables and the parameters are restored to the start of the step and the history is
            cleared, so the optimiser stays valid and usable (the batch generator has advanced).
        """
        self._check_params_unchanged()
        z_start = [z.clone() for z in self._z]
        self._n_evals = 0
        try:
            prev, mask = self._mask, self._next_mask()
            self._mask = mask
            if prev is not None and not torch.equal(prev, mask):
                self._batch.history._on_batch_change(self, prev, mask, closure)
            n_iter_before = self._state().get("n_iter", 0)
            self._trace = []
            stopped = False
            try:
                self._lbfgs.step(lambda: self._traced_evaluate(closure, mask))
            except StopStep:
                if not self._trace:
                    raise
                stopped = True
            trace, self._trace = self._trace, None
            n_iters = self._state().get("n_iter", 0) - n_iter_before
            if stopped:  # end at the best point evaluated; the interrupted line search's state is stale
                best = min(trace, key=lambda e: e.loss)
                with torch.no_grad():
                    self._set_flat_z(best.z)
                self._reset_history()
            z_end = self._flat_z()
            end = next((e for e in reversed(trace) if torch.equal(e.z, z_end)), None)
            if end is None:  # cannot happen with torch's strong Wolfe (every end point was evaluated)
                loss, grad_w = self._evaluate(closure, mask)
                end = _Eval(z_end, float(loss), self._flat_grad_z(), torch.cat([g.reshape(-1) for g in grad_w]))
        except BaseException:  # a failing closure (or an interrupt) must not leave a trial point behind
            self._trace = None
            with torch.no_grad():
                for z, z0 in zip(self._z, z_start):
                    z.copy_(z0)
            self._reset_history()
            raise
        finally:
            with torch.no_grad():
                self._write_params()
        self._n_steps += 1
        state = self._state()
        w = torch.cat([p.detach().reshape(-1) for p in self._params])
        lo = torch.cat([f.lo.reshape(-1) for f in self._folds])
        hi = torch.cat([f.hi.reshape(-1) for f in self._folds])
        at_lo = w <= lo + _ACTIVE_RTOL * (hi - lo)
        at_hi = w >= hi - _ACTIVE_RTOL * (hi - lo)
        pg = end.grad_w.clone()
        pg[(at_lo & (pg > 0)) | (at_hi & (pg < 0))] = 0.0
        return StepResult(
            loss_before=trace[0].loss, loss_after=end.loss, n_evals=self._n_evals,
            n_iters=n_iters, grad_norm=float(end.grad_z.abs().max()),
            proj_grad_norm=float(pg.abs().max()),
            batch_fraction=1.0 if mask is None else float(mask.sum()) / len(mask),
            at_lower=int(at_lo.sum()), at_upper=int(at_hi.sum()), n_pairs=len(state.get("old_dirs", [])),
            stopped=stopped)

    def state_dict(self) -> dict:
        """A snapshot (deep copy) of everything :meth:`step` depends on; tensors and plain Python only.

        Contains the latent variables, torch's L-BFGS state (history, last direction and step,
        previous gradient, counters), the batch generator's state and the current mask, so that
        ``load_state_dict`` on a fresh optimiser continues bit-identically. Loadable with
        ``torch.load(..., weights_only=True)``.
        """
        return {
            "names": list(self._names),
            "latent": [z.detach().clone() for z in self._z],
            "lbfgs_state": copy.deepcopy(self._lbfgs.state_dict()["state"]),
            "history_size": self._history_size,
            "rng": None if self._gen is None else self._gen.get_state(),
            "mask": None if self._mask is None else self._mask.clone(),
            "n_steps": self._n_steps,
        }

    def load_state_dict(self, sd: Mapping) -> None:
        """Restore a :meth:`state_dict`; the parameters are set to the restored bounded values.

        The optimiser must have been built with the same parameter names and shapes, bounds,
        ``history_size`` and batch configuration (the other settings are taken from the constructor).

        Raises:
            ValueError: the state dict does not fit this optimiser.
        """
        if list(sd["names"]) != self._names:
            raise ValueError(f"state dict is for parameters {sd['names']}, this optimiser has {self._names}")
        for name, z, zs in zip(self._names, self._z, sd["latent"]):
            if zs.shape != z.shape:
                raise ValueError(f"state dict: latent for {name!r} has shape {tuple(zs.shape)}, "
                                 f"expected {tuple(z.shape)}")
        if sd["history_size"] != self._history_size:
            raise ValueError(f"state dict has history_size {sd['history_size']}, this optimiser {self._history_size}")
        if (sd["rng"] is None) != (self._gen is None):
            raise ValueError("state dict and optimiser disagree on whether mini-batches are used")
        if sd["mask"] is not None and (self._batch is None or sd["mask"].shape != (self._batch.n_samples,)):
            raise ValueError("state dict: the batch mask does not fit this optimiser's MiniBatch.n_samples")
        full = self._lbfgs.state_dict()  # keep this optimiser's settings, take the saved state
        full["state"] = copy.deepcopy(dict(sd["lbfgs_state"]))
        self._lbfgs.load_state_dict(full)
        with torch.no_grad():
            for z, zs in zip(self._z, sd["latent"]):
                z.copy_(zs)
            self._write_params()
        if self._gen is not None:
            self._gen.set_state(sd["rng"])
        self._mask = None if sd["mask"] is None else sd["mask"].clone()
        self._n_steps = int(sd["n_steps"])

    # -- private ---------------------------------------------------------------------------------

    def _state(self) -> dict:
        """torch.optim.LBFGS keeps its global state under its first parameter."""
        return self._lbfgs.state[self._z[0]]

    def _bounded(self, i: int) -> Tensor:
        return self._folds[i].w(self._z[i])

    def _write_params(self) -> None:
        for i, p in enumerate(self._params):
            p.copy_(self._bounded(i))

    def _check_params_unchanged(self) -> None:
        with torch.no_grad():
            for i, (name, p) in enumerate(zip(self._names, self._params)):
                if not torch.equal(p, self._bounded(i)):
                    raise RuntimeError(f"parameter {name!r} was changed outside BoundedLBFGS since its last step; "
                                       f"build a new optimiser (or load_state_dict) after editing parameters")

    def _next_mask(self) -> Tensor | None:
        b = self._batch
        if b is None:
            return None
        if b.n_batch == b.n_samples:
            return torch.ones(b.n_samples, dtype=torch.bool)
        return b.history._draw(self._mask, b.n_samples, b.n_batch, self._gen)

    def _evaluate(self, closure: Closure, mask: Tensor | None) -> tuple[Tensor, list[Tensor]]:
        """Loss at the current latent point; sets ``z.grad`` by the chain rule, returns (loss, dL/dw)."""
        with torch.no_grad():
            self._write_params()
            for p in self._params:
                p.grad = None
        try:
            with torch.enable_grad():
                loss = closure() if mask is None else closure(mask)
                if not (isinstance(loss, Tensor) and loss.numel() == 1 and loss.requires_grad):
                    raise TypeError("the closure must return a scalar loss tensor that requires grad")
                if any(p.grad is not None for p in self._params):
                    raise RuntimeError("the closure must not call backward(): BoundedLBFGS back-propagates itself")
                if not torch.isfinite(loss.detach()).all():
                    raise FloatingPointError(f"non-finite loss {loss.item()} at closure call {self._n_evals + 1} "
                                             f"of step {self._n_steps + 1}")
                loss.backward()
        except self._reject + ((FloatingPointError,) if self._reject else ()):
            if self._n_evals == 0:
                raise
            # An infeasible trial point: infinitely bad, so the line search backtracks from it.
            self._n_evals += 1
            self._n_rejected += 1
            with torch.no_grad():
                for z in self._z:
                    z.grad = torch.zeros_like(z)
            return torch.tensor(INFEASIBLE_LOSS, dtype=self._z[0].dtype), [torch.zeros_like(p) for p in self._params]
        self._n_evals += 1
        with torch.no_grad():
            grad_w = [p.grad if p.grad is not None else torch.zeros_like(p) for p in self._params]
            for z, g, fold in zip(self._z, grad_w, self._folds):
                z.grad = g * fold.slope(z)
        return loss.detach().reshape(()), grad_w

    def _traced_evaluate(self, closure: Closure, mask: Tensor | None) -> Tensor:
        """The closure handed to torch.optim.LBFGS: evaluate and remember point, loss and gradients."""
        loss, grad_w = self._evaluate(closure, mask)
        self._trace.append(_Eval(self._flat_z(), float(loss), self._flat_grad_z(),
                                 torch.cat([g.reshape(-1) for g in grad_w])))
        return loss

    def _flat_z(self) -> Tensor:
        return torch.cat([z.detach().reshape(-1) for z in self._z])

    def _flat_grad_z(self) -> Tensor:
        return torch.cat([z.grad.reshape(-1) for z in self._z])

    def _set_flat_z(self, flat: Tensor) -> None:
        offset = 0
        for z in self._z:
            z.copy_(flat[offset:offset + z.numel()].view_as(z))
            offset += z.numel()

    def _reset_history(self) -> None:
        """Forget all curvature pairs: the next iteration is a steepest-descent step."""
        self._lbfgs.state.clear()

    def _bridge_on_overlap(self, closure: Closure, overlap: Tensor) -> None:
        """Append the pair ``(s, g_O(z) - g_O(z - s))`` computed on the overlap ``O`` of two batches.

        ``s = d * t`` is torch's last step; any secant pair of the overlap loss is valid, so it does
        not matter whether that step was actually taken from ``z - s``. Torch's own pair at the next
        iteration would mix two batch losses; setting ``t = 0`` makes its ``s`` zero, so torch skips
        it (``y.s = 0 <= 1e-10``).
        """
        state = self._state()
        if state.get("n_iter", 0) == 0 or "d" not in state:
            return
        with torch.no_grad():
            z1 = self._flat_z()
            z0 = z1 - state["d"].mul(state["t"])
            s = z1 - z0  # the step between the points actually evaluated (differs from d*t by rounding)
            if not s.any():  # the last line search did not move: no pair to form
                state["t"] = 0.0
                return
            self._evaluate(closure, overlap)
            g1 = self._flat_grad_z()
            self._set_flat_z(z0)
            self._evaluate(closure, overlap)
            g0 = self._flat_grad_z()
            self._set_flat_z(z1)
            self._write_params()
            y = g1 - g0
            ys = y.dot(s)
            if ys > _MIN_CURVATURE:
                if len(state["old_dirs"]) == self._history_size:
                    for key in ("old_dirs", "old_stps", "ro"):
                        state[key].pop(0)
                state["old_dirs"].append(y)
                state["old_stps"].append(s)
                state["ro"].append(1.0 / ys)
                state["H_diag"] = ys / y.dot(y)
            state["t"] = 0.0
