"""Temporarily single-threaded torch for small dense solves."""

from __future__ import annotations

from contextlib import contextmanager

import torch


@contextmanager
def single_threaded():
    """Run the body with one torch (OpenMP/MKL) thread; the previous count is restored after.

    The fits' matrices are small (~2500 x 100): one thread is as fast, while on an oversubscribed
    machine multi-threaded BLAS/OpenMP stalled the surrogate fit ~20x (measured 18 s vs 1 s).
    Process-global while it lasts, like any ``torch.set_num_threads``.
    """
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(n)
