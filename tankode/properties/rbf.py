"""Batched, differentiable radial-basis-function interpolant on min-max scaled inputs (torch, float64).

    f(x) = sum_j W_j phi(|s(x) - c_j|) + b + A^T s(x) [+ quadratic tail],   s(x) = (x - x_min)/(x_max - x_min)

All outputs share one kernel matrix ``phi`` (one matmul per call), and the gradient of selected
outputs with respect to the *unscaled* inputs is analytic: with ``r2 = |s - c_j|^2`` and
``psi = dphi/d(r2)``, ``df/ds = 2 sum_j W_j psi_j (s - c_j) + A``, evaluated as a second matmul of
``psi`` (fused into the first for the Gaussian, whose ``psi`` is ``-eps^2 phi``). Everything is
plain torch, so values and gradients are themselves differentiable (double backward works).

Kernels (``r`` in scaled units, so ``eps`` is per unit of the min-max range):
    gaussian              exp(-(eps r)^2)
    multiquadric          sqrt(1 + (eps r)^2)
    inverse_multiquadric  1 / sqrt(1 + (eps r)^2)
    polyharmonic3         r^3                       (shape-free)
    thin_plate            r^2 log(r) = r2 log(r2)/2  (shape-free)

Fitting (``fit_rbf``): least squares with fewer centres than samples, or collocation at the
centres (square saddle-point system). Both are solved by a truncated SVD of the column-scaled
system matrix; the full and effective condition numbers and the kept rank are reported, because
smooth kernels (Gaussian, multiquadrics) at useful shape parameters are numerically rank-deficient
(condition ~1e16) and an unregularised solve would return noise-amplifying weights.
Used for the property corrections of section 3 of Marques, Ahizi & Mendez (one interpolant per phase).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
import torch
from torch import Tensor, nn

from ..threads import single_threaded

KERNELS = ("gaussian", "multiquadric", "inverse_multiquadric", "polyharmonic3", "thin_plate")
SHAPE_FREE_KERNELS = ("polyharmonic3", "thin_plate")
_TINY = 1e-300  # keeps log(r2) finite at a centre; changes nothing for r2 > 1e-280


def _check_kernel(kernel: str, eps: float) -> None:
    if kernel not in KERNELS:
        raise ValueError(f"unknown RBF kernel {kernel!r}; choose one of {KERNELS}")
    if kernel not in SHAPE_FREE_KERNELS and not (math.isfinite(eps) and eps > 0):
        raise ValueError(f"RBF kernel {kernel!r} needs a finite shape parameter eps > 0, got {eps!r}")


def kernel_phi(kernel: str, eps: float, r2: Tensor) -> Tensor:
    """Kernel value as a function of the squared scaled distance ``r2`` (>= 0)."""
    e2 = eps * eps
    if kernel == "gaussian":
        return torch.exp(r2 * -e2)
    if kernel == "multiquadric":
        return torch.sqrt(1.0 + e2 * r2)
    if kernel == "inverse_multiquadric":
        return torch.rsqrt(1.0 + e2 * r2)
    if kernel == "polyharmonic3":
        return r2 * r2.sqrt()
    if kernel == "thin_plate":
        return 0.5 * r2 * torch.log(r2 + _TINY)
    raise ValueError(f"unknown RBF kernel {kernel!r}")


def kernel_phi_psi(kernel: str, eps: float, r2: Tensor) -> tuple[Tensor, Tensor | None]:
    """Kernel value and ``psi = dphi/d(r2)``; ``psi`` is None for the Gaussian (it is ``-eps^2 phi``)."""
    e2 = eps * eps
    if kernel == "gaussian":
        return torch.exp(r2 * -e2), None
    if kernel == "multiquadric":
        s = torch.sqrt(1.0 + e2 * r2)
        return s, (0.5 * e2) / s
    if kernel == "inverse_multiquadric":
        s = torch.rsqrt(1.0 + e2 * r2)
        return s, (-0.5 * e2) * s * s * s
    if kernel == "polyharmonic3":
        r = r2.sqrt()
        return r2 * r, 1.5 * r
    if kernel == "thin_plate":
        lg = torch.log(r2 + _TINY)
        return 0.5 * r2 * lg, 0.5 * lg + 0.5
    raise ValueError(f"unknown RBF kernel {kernel!r}")


def _quad_index(d: int) -> tuple[list[int], list[int]]:
    return [i for i in range(d) for j in range(i, d)], [j for i in range(d) for j in range(i, d)]


def _poly_matrix(xs: Tensor, degree: int) -> Tensor:
    cols = [torch.ones_like(xs[:, :1]), xs]
    if degree == 2:
        I, J = _quad_index(xs.shape[1])
        cols.append(xs[:, I] * xs[:, J])
    return torch.cat(cols, 1)


class RBFInterpolant(nn.Module):
    """RBF interpolant with a polynomial tail, evaluated in torch float64 (buffers only).

    Args (usually built by ``fit_rbf``):
        kernel, eps: kernel name and shape parameter (ignored for shape-free kernels).
        x_min, x_max: ``(d,)`` min-max scaling of the inputs (input units).
        centres: ``(M, d)`` centres in *scaled* coordinates.
        weights: ``(M, n_out)`` kernel weights.
        poly: ``(1 + d [+ d(d+1)/2], n_out)`` tail coefficients in scaled coordinates
            (constant, linear, optionally quadratic rows).
        degree: tail degree, 1 or 2.
        grad_outputs: indices of the outputs whose input gradient ``value_and_grad`` returns.
    """

    def __init__(self, *, kernel: str, eps: float, x_min: Tensor, x_max: Tensor, centres: Tensor,
                 weights: Tensor, poly: Tensor, degree: int = 1, grad_outputs: tuple[int, ...] = ()):
        super().__init__()
        _check_kernel(kernel, eps)
        if degree not in (1, 2):
            raise ValueError(f"RBF polynomial tail degree must be 1 or 2, got {degree}")
        f64 = dict(dtype=torch.float64)
        x_min, x_max = torch.as_tensor(x_min, **f64), torch.as_tensor(x_max, **f64)
        centres, weights, poly = (torch.as_tensor(t, **f64) for t in (centres, weights, poly))
        d = x_min.numel()
        n_poly = 1 + d + (d * (d + 1) // 2 if degree == 2 else 0)
        if centres.shape[1] != d or weights.shape[0] != centres.shape[0] or poly.shape != (n_poly, weights.shape[1]):
            raise ValueError(
                f"inconsistent RBF shapes: centres {tuple(centres.shape)}, weights {tuple(weights.shape)}, "
                f"poly {tuple(poly.shape)} (expected ({n_poly}, n_out)) for d={d}"
            )
        if not bool((x_max > x_min).all()):
            raise ValueError(f"RBF scaling needs x_max > x_min, got {x_min.tolist()} .. {x_max.tolist()}")
        self.kernel, self.eps, self.degree = kernel, float(eps), degree
        self.grad_outputs = tuple(int(i) for i in grad_outputs)
        self.n_out, self.dim = weights.shape[1], d
        inv_range = 1.0 / (x_max - x_min)
        self.register_buffer("x_min", x_min)
        self.register_buffer("x_max", x_max)
        self.register_buffer("inv_range", inv_range)
        self.register_buffer("shift", -x_min * inv_range)
        self.register_buffer("centres", centres)
        self.register_buffer("weights", weights)
        self.register_buffer("poly", poly)
        # r2 = |s|^2 + |c|^2 - 2 s.c as one addmm and one add, instead of an (n, M, d) difference
        # tensor; for the Gaussian the factor -eps^2 is folded in, so the addmm yields exp's argument.
        fold = -(self.eps**2) if kernel == "gaussian" else 1.0
        self._xx_alpha = fold
        self.register_buffer("_c2", fold * (centres * centres).sum(1))
        self.register_buffer("_cT_m2", (-2.0 * fold) * centres.T.contiguous())
        # Gradient weights per selected output o: column [2 W_o] then columns [-2 W_o c_k], so that
        # df_o/ds_k = s_k * (psi @ col0) + (psi @ col_k) + A_ko.
        sel = list(self.grad_outputs)
        w = weights[:, sel]  # (M, g)
        G = torch.cat([2.0 * w[:, :, None], -2.0 * w[:, :, None] * centres[:, None, :]], 2)  # (M, g, 1+d)
        G = G.reshape(weights.shape[0], -1)
        n_g = G.shape[1]
        if kernel == "gaussian":
            # psi = -eps^2 phi: fold it into the weights so one matmul gives values and gradients,
            # and the constant tail term rides along as the addmm bias.
            self.register_buffer("_W_all", torch.cat([weights, -(self.eps**2) * G], 1).contiguous())
            self.register_buffer("_bias_all", torch.cat([poly[0], torch.zeros(n_g, **f64)]))
            self.register_buffer("_W_psi", torch.zeros(0, **f64))
        else:
            self.register_buffer("_W_all", weights.contiguous())
            self.register_buffer("_bias_all", poly[0].clone())
            self.register_buffer("_W_psi", G.contiguous())
        self.register_buffer("_A", poly[1:1 + d].contiguous())
        self.register_buffer("_A_grad", (poly[1:1 + d, sel].T * inv_range).contiguous())  # (g, d)
        self.register_buffer("_A_grad_row", self._A_grad.reshape(-1).clone())
        if degree == 2:
            I, J = _quad_index(d)
            self.register_buffer("_Q", poly[1 + d:].contiguous())
            self.register_buffer("_qI", torch.tensor(I))
            self.register_buffer("_qJ", torch.tensor(J))

    def scale(self, x: Tensor) -> Tensor:
        """Min-max scaled coordinates ``(..., d)`` of inputs ``x`` ``(..., d)``."""
        B = self._buffers
        return torch.addcmul(B["shift"], x, B["inv_range"])

    # Hot-path methods read buffers from self._buffers: nn.Module.__getattr__ costs ~0.5 us per
    # buffer access, a dict lookup ~0.05 us (and .to() updates the dict, so this stays correct).

    def _kernel_arg(self, xs: Tensor) -> Tensor:
        # r2 (or -eps^2 r2 for the Gaussian) between rows of xs and the centres, (n, M).
        # In-place ops on the (n, M) matrix save two large allocations per call; autograd allows
        # them because addmm's backward needs its inputs, not its output.
        B = self._buffers
        z = torch.addmm(B["_c2"], xs, B["_cT_m2"]).add_((xs * xs).sum(1, keepdim=True), alpha=self._xx_alpha)
        # Cancellation can leave -1e-17 at a centre: sqrt/log kernels need r2 >= 0.
        return z.clamp_min_(0.0) if self.kernel in SHAPE_FREE_KERNELS else z

    def _phi_psi(self, z: Tensor) -> tuple[Tensor, Tensor | None]:
        if self.kernel == "gaussian":
            return z.exp_(), None
        return kernel_phi_psi(self.kernel, self.eps, z)

    def _tail(self, out: Tensor, xs: Tensor) -> Tensor:
        B = self._buffers
        out = torch.addmm(out, xs, B["_A"])
        if self.degree == 2:
            out = torch.addmm(out, xs[:, B["_qI"]] * xs[:, B["_qJ"]], B["_Q"])
        return out

    def forward(self, x: Tensor) -> Tensor:
        """Values ``(..., n_out)`` at inputs ``x`` ``(..., d)`` (input units)."""
        lead = x.shape[:-1]
        xs = self.scale(x.reshape(-1, self.dim))
        phi, _ = self._phi_psi(self._kernel_arg(xs))
        out = self._tail(torch.addmm(self._bias_all[:self.n_out], phi, self._W_all[:, :self.n_out]), xs)
        return out.reshape(*lead, self.n_out)

    def value_and_grad_rows(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """``value_and_grad`` for a 2-D batch ``x`` ``(n, d)``: values ``(n, n_out)``, gradients ``(n, g*d)``.

        The hot path of the surrogate: ~15 tensor ops whatever the number of outputs.
        """
        B = self._buffers
        xs = torch.addcmul(B["shift"], x, B["inv_range"])
        phi, psi = self._phi_psi(self._kernel_arg(xs))
        g, d, n_out = len(self.grad_outputs), self.dim, self.n_out
        both = torch.addmm(B["_bias_all"], phi, B["_W_all"])
        vals = both[:, :n_out]
        gw = both[:, n_out:] if psi is None else psi @ B["_W_psi"]
        if g == 1:
            grad = torch.addcmul(B["_A_grad_row"], torch.addcmul(gw[:, 1:], xs, gw[:, :1]), B["inv_range"])
        else:
            gw = gw.reshape(-1, g, 1 + d)
            grad_s = torch.addcmul(gw[:, :, 1:], xs[:, None, :], gw[:, :, :1])
            grad = torch.addcmul(B["_A_grad"], grad_s, B["inv_range"]).reshape(-1, g * d)
        if self.degree == 2:
            grad = grad + self._quad_grad(xs).reshape(-1, g * d)
        return self._tail(vals, xs), grad

    def value_and_grad(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """Values ``(..., n_out)`` and gradients ``(..., g, d)`` of the ``grad_outputs`` w.r.t. ``x``.

        The gradient is with respect to the unscaled inputs (per input unit), analytic, and
        differentiable again (so an adjoint can differentiate through it).
        """
        lead = x.shape[:-1]
        vals, grad = self.value_and_grad_rows(x.reshape(-1, self.dim))
        return vals.reshape(*lead, self.n_out), grad.reshape(*lead, len(self.grad_outputs), self.dim)

    def _quad_grad(self, xs: Tensor) -> Tensor:
        # d(s_i s_j)/ds_k = [i==k] s_j + [j==k] s_i
        sel = list(self.grad_outputs)
        d = self.dim
        eye = torch.eye(d, dtype=xs.dtype, device=xs.device)
        dq = xs[:, None, self._qJ] * eye[:, self._qI] + xs[:, None, self._qI] * eye[:, self._qJ]  # (n, d, q)
        return (dq @ self._Q[:, sel]).transpose(1, 2) * self.inv_range  # (n, g, d)

    def state(self) -> dict:
        """Plain dict (tensors and python scalars) that ``from_state`` rebuilds the interpolant from."""
        return {
            "kernel": self.kernel, "eps": self.eps, "degree": self.degree, "grad_outputs": list(self.grad_outputs),
            "x_min": self.x_min.detach().cpu(), "x_max": self.x_max.detach().cpu(),
            "centres": self.centres.detach().cpu(), "weights": self.weights.detach().cpu(),
            "poly": self.poly.detach().cpu(),
        }

    @staticmethod
    def from_state(state: dict) -> "RBFInterpolant":
        return RBFInterpolant(
            kernel=state["kernel"], eps=state["eps"], x_min=state["x_min"], x_max=state["x_max"],
            centres=state["centres"], weights=state["weights"], poly=state["poly"], degree=state["degree"],
            grad_outputs=tuple(state["grad_outputs"]),
        )


@dataclass(frozen=True)
class RBFFitInfo:
    """Diagnostics of one ``fit_rbf`` solve (JSON-serialisable via ``asdict``).

    ``cond``: 2-norm condition number of the column-scaled system matrix; ``cond_effective``:
    largest over smallest *kept* singular value (what the truncated solve actually inverts);
    ``rank``: kept singular values out of ``n_unknowns``; ``train_rms``/``train_max``: residual on
    the fitting samples per output (output units).
    """

    kernel: str
    eps: float
    method: str
    degree: int
    n_centres: int
    n_samples: int
    n_unknowns: int
    rank: int
    rcond: float
    cond: float
    cond_effective: float
    train_rms: list
    train_max: list

    def as_dict(self) -> dict:
        return asdict(self)


def _tsvd_solve(A: Tensor, Y: Tensor, rcond: float) -> tuple[Tensor, int, float, float]:
    # Column scaling removes the trivial part of the ill-conditioning (kernel vs tail columns).
    scale = A.norm(dim=0).clamp_min(1e-300)
    U, S, Vh = torch.linalg.svd(A / scale, full_matrices=False)
    keep = S > rcond * S[0]
    rank = int(keep.sum())
    if rank == 0:
        raise RuntimeError("RBF fit failed: the system matrix is numerically zero")
    Z = Vh[keep].T @ ((U[:, keep].T @ Y) / S[keep, None])
    cond = float(S[0] / S[-1]) if S[-1] > 0 else math.inf
    return Z / scale[:, None], rank, cond, float(S[0] / S[keep][-1])


def fit_rbf(x, y, centres, *, kernel: str, eps: float = 1.0, degree: int = 1, method: str = "lstsq",
            rcond: float = 1e-13, x_min=None, x_max=None,
            grad_outputs: tuple[int, ...] = ()) -> tuple[RBFInterpolant, RBFFitInfo]:
    """Fit an ``RBFInterpolant`` to samples (the solve runs single-threaded: small dense matrices).

    Args:
        x: ``(N, d)`` sample inputs (input units).
        y: ``(N, n_out)`` sample outputs; all outputs share the kernel matrix.
        centres: ``(M, d)`` centres (input units). For ``method="interp"`` they must be the samples.
        kernel, eps: see module docstring; ``eps`` is per unit of the min-max scaled range.
        degree: polynomial tail degree (1 or 2).
        method: ``"lstsq"`` (M < N least squares) or ``"interp"`` (collocation: the square system
            ``[[Phi, P], [P^T, 0]] [W; c] = [y; 0]``).
        rcond: relative singular-value cutoff of the truncated SVD.
        x_min, x_max: ``(d,)`` scaling bounds; default the min/max over samples and centres.
        grad_outputs: outputs whose analytic input gradients the interpolant will provide.

    Returns:
        The interpolant and an ``RBFFitInfo``.

    Raises:
        ValueError: bad shapes/options. RuntimeError: non-finite or empty solution.
    """
    with single_threaded():
        return _fit_rbf(x, y, centres, kernel=kernel, eps=eps, degree=degree, method=method, rcond=rcond,
                        x_min=x_min, x_max=x_max, grad_outputs=grad_outputs)


def _fit_rbf(x, y, centres, *, kernel: str, eps: float = 1.0, degree: int = 1, method: str = "lstsq",
            rcond: float = 1e-13, x_min=None, x_max=None,
            grad_outputs: tuple[int, ...] = ()) -> tuple[RBFInterpolant, RBFFitInfo]:
    _check_kernel(kernel, eps)
    f64 = dict(dtype=torch.float64)
    X = torch.as_tensor(np.asarray(x, dtype=np.float64)) if not torch.is_tensor(x) else x.to(**f64)
    Y = torch.as_tensor(np.asarray(y, dtype=np.float64)) if not torch.is_tensor(y) else y.to(**f64)
    C = torch.as_tensor(np.asarray(centres, dtype=np.float64)) if not torch.is_tensor(centres) else centres.to(**f64)
    X, Y, C = X.detach().cpu(), Y.detach().cpu(), C.detach().cpu()
    if Y.ndim == 1:
        Y = Y[:, None]
    if X.ndim != 2 or C.ndim != 2 or X.shape[1] != C.shape[1] or Y.shape[0] != X.shape[0]:
        raise ValueError(f"fit_rbf: bad shapes x {tuple(X.shape)}, y {tuple(Y.shape)}, centres {tuple(C.shape)}")
    if not (torch.isfinite(X).all() and torch.isfinite(Y).all() and torch.isfinite(C).all()):
        raise ValueError("fit_rbf: non-finite samples or centres")
    both = torch.cat([X, C])
    lo = both.min(0).values if x_min is None else torch.as_tensor(x_min, **f64)
    hi = both.max(0).values if x_max is None else torch.as_tensor(x_max, **f64)
    inv = 1.0 / (hi - lo)
    Xs, Cs = (X - lo) * inv, (C - lo) * inv
    r2 = ((Xs[:, None, :] - Cs[None, :, :]) ** 2).sum(-1)
    Phi = kernel_phi(kernel, eps, r2)
    P = _poly_matrix(Xs, degree)
    n_poly = P.shape[1]
    M = C.shape[0]
    if method == "lstsq":
        if M + n_poly > X.shape[0]:
            raise ValueError(f"fit_rbf lstsq: {M} centres + {n_poly} tail terms exceed {X.shape[0]} samples")
        A, rhs = torch.cat([Phi, P], 1), Y
    elif method == "interp":
        if X.shape != C.shape or not torch.equal(X, C):
            raise ValueError("fit_rbf interp: the centres must be the sample points")
        A = torch.cat([torch.cat([Phi, P], 1), torch.cat([P.T, torch.zeros(n_poly, n_poly, **f64)], 1)], 0)
        rhs = torch.cat([Y, torch.zeros(n_poly, Y.shape[1], **f64)], 0)
    else:
        raise ValueError(f"fit_rbf: method must be 'lstsq' or 'interp', got {method!r}")
    Z, rank, cond, cond_eff = _tsvd_solve(A, rhs, rcond)
    if not torch.isfinite(Z).all():
        raise RuntimeError(f"RBF fit failed ({kernel}, eps={eps}, {method}): non-finite weights")
    W, poly = Z[:M], Z[M:]
    res = torch.cat([Phi, P], 1) @ Z - Y
    info = RBFFitInfo(
        kernel=kernel, eps=float(eps), method=method, degree=degree, n_centres=M, n_samples=int(X.shape[0]),
        n_unknowns=int(A.shape[1]), rank=rank, rcond=float(rcond), cond=cond, cond_effective=cond_eff,
        train_rms=res.pow(2).mean(0).sqrt().tolist(), train_max=res.abs().max(0).values.tolist(),
    )
    rbf = RBFInterpolant(kernel=kernel, eps=eps, x_min=lo, x_max=hi, centres=Cs, weights=W, poly=poly,
                         degree=degree, grad_outputs=grad_outputs)
    return rbf, info


__all__ = ["RBFInterpolant", "RBFFitInfo", "fit_rbf", "kernel_phi", "kernel_phi_psi", "KERNELS",
           "SHAPE_FREE_KERNELS"]
