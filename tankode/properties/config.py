"""Settings of the surrogate fit (kernel selection, sample sizes), validated on construction."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

from .rbf import KERNELS, SHAPE_FREE_KERNELS

_METHODS = ("lstsq", "interp", "auto")


@dataclass(frozen=True)
class SurrogateConfig:
    """How ``fit_surrogate`` builds the RBF corrections (one interpolant per phase).

    The paper (Marques, Ahizi & Mendez, section 3) uses a Gaussian with eps = 0.01 in its own
    scaling; here ``eps`` multiplies the distance in min-max scaled (u, rho) (``exp(-(eps r)^2)``),
    and with ``kernel="auto"`` the kernel, shape and solve method (least squares on ``n_train``
    samples, or collocation at the ``n_centres`` centres) are picked per phase by the worst
    held-out error relative to its tolerance (0.1 % for p and T, 1 % for k, mu, cp, beta); the
    whole table is kept in ``Surrogate.metadata["selection"]``.
    """

    # "auto" or one of rbf.KERNELS; auto tries ``auto_kernels`` x ``eps_grid`` x methods.
    kernel: str = "auto"
    # Shape parameter (per unit of scaled distance) when kernel is not "auto".
    eps: float = 3.0
    # "lstsq" (n_centres < n_train least squares), "interp" (collocation at the centres) or "auto".
    method: str = "auto"
    # Centres per phase (a Chebyshev grid in (p, T-fraction), rounded to n_p x n_T): the batched
    # cost is ~ n_points x n_centres; ~100 meets the 0.1 % targets ~40x over (held-out) and keeps
    # 10k-point evaluation well over 20x faster than CoolProp. 64 still meets them, 200 gains ~2x.
    n_centres: int = 100
    # CoolProp training samples per phase (a regular grid in (p, T-fraction)).
    n_train: int = 2500
    # Held-out samples per phase used to select kernel/shape/method (random, not the benchmark's).
    n_val: int = 2000
    # Polynomial tail degree of the RBF (1 or 2).
    poly_degree: int = 1
    # Relative singular-value cutoff of the truncated-SVD solve: 1e-12 keeps the held-out errors of
    # 1e-13 within ~20 % while shrinking the Gaussian weights ~5x (less cancellation noise).
    rcond: float = 1e-12
    # Candidate shape parameters for the shape-dependent kernels under "auto". 0.01 is the paper's
    # value, kept so the selection table shows it: in this scaling it is the flat limit (rank ~5-9
    # after truncation, liquid p off by ~50 %); 2-4 win.
    eps_grid: tuple = (0.01, 1.0, 2.0, 3.0, 4.0, 6.0)
    # Candidate kernels under "auto".
    auto_kernels: tuple = KERNELS
    # Degree of the 1-D saturation polynomial in p (T_sat, h_lsat, h_vsat); 12 gives ~1e-5 relative.
    sat_degree: int = 12
    # CoolProp saturation samples (Chebyshev nodes) for that polynomial.
    n_sat: int = 200
    # Seed of the held-out (validation) sampling.
    seed: int = 0

    def __post_init__(self):
        if self.kernel != "auto" and self.kernel not in KERNELS:
            raise ValueError(f"SurrogateConfig.kernel must be 'auto' or one of {KERNELS}, got {self.kernel!r}")
        if self.method not in _METHODS:
            raise ValueError(f"SurrogateConfig.method must be one of {_METHODS}, got {self.method!r}")
        if self.kernel not in SHAPE_FREE_KERNELS and not (math.isfinite(self.eps) and self.eps > 0):
            raise ValueError(f"SurrogateConfig.eps must be finite and > 0, got {self.eps!r}")
        bad = [k for k in self.auto_kernels if k not in KERNELS]
        if bad or not self.auto_kernels:
            raise ValueError(
                f"SurrogateConfig.auto_kernels must be a non-empty subset of {KERNELS}, got {self.auto_kernels}"
            )
        if not self.eps_grid or not all(math.isfinite(e) and e > 0 for e in self.eps_grid):
            raise ValueError(f"SurrogateConfig.eps_grid must be non-empty positive numbers, got {self.eps_grid}")
        if not 16 <= self.n_centres <= 2000:
            raise ValueError(f"SurrogateConfig.n_centres must be in [16, 2000], got {self.n_centres}")
        if not self.n_train >= 2 * self.n_centres:
            raise ValueError(
                f"SurrogateConfig.n_train must be >= 2 n_centres = {2 * self.n_centres} for least squares, "
                f"got {self.n_train}"
            )
        if not self.n_val >= 100:
            raise ValueError(f"SurrogateConfig.n_val must be >= 100, got {self.n_val}")
        if self.poly_degree not in (1, 2):
            raise ValueError(f"SurrogateConfig.poly_degree must be 1 or 2, got {self.poly_degree}")
        if not 0.0 < self.rcond < 1e-3:
            raise ValueError(f"SurrogateConfig.rcond must be in (0, 1e-3), got {self.rcond}")
        if not 2 <= self.sat_degree <= 20 or not self.n_sat >= 2 * (self.sat_degree + 1):
            raise ValueError(
                f"SurrogateConfig.sat_degree must be in [2, 20] with n_sat >= 2 (sat_degree + 1), "
                f"got sat_degree={self.sat_degree}, n_sat={self.n_sat}"
            )

    def as_dict(self) -> dict:
        d = asdict(self)
        d["eps_grid"], d["auto_kernels"] = list(self.eps_grid), list(self.auto_kernels)
        return d


__all__ = ["SurrogateConfig"]
