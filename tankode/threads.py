"""Temporarily single-threaded torch for small dense solves."""

from __future__ import annotations

from contextlib import contextmanager

import torch


@contextmanager
def single_threaded():
    """Run the body with one torch (OpenMP/MKL) thread; the previous count is restored after.

    The fits' matrices are small (~2500 x 100) and the ODE's tensors smaller still ((env, 7)
    states): one thread is as fast or faster, while on an oversubscribed machine multi-threaded
    BLAS/OpenMP stalls the surrogate fit and a window update several-fold. Usable as a
    decorator (``@single_threaded()``). Process-global while it lasts, like any
    ``torch.set_num_threads``.
    """
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(n)


__all__ = ["single_threaded"]
