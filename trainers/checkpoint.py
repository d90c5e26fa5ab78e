"""Checkpoints that survive a kill and never unpickle arbitrary objects."""

from __future__ import annotations

import os
from pathlib import Path

import torch

from tankode.files import load_tensors


def save_checkpoint(path, payload: dict) -> None:
    """Write ``payload`` (tensors, numbers, strings, lists, dicts) atomically to ``path``.

    The file is written beside the target and renamed over it, so a process killed mid-write
    leaves the previous checkpoint intact.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    torch.save(payload, tmp)
    with open(tmp, "rb") as f:
        os.fsync(f.fileno())
    os.replace(tmp, path)


def load_checkpoint(path) -> dict:
    """Load a checkpoint written by ``save_checkpoint`` with ``weights_only=True`` (no pickled code)."""
    return load_tensors(path, "checkpoint")


__all__ = ["save_checkpoint", "load_checkpoint"]
