"""File safety: outputs never replace inputs, and loaded files never run code.

Two rules every command follows:

* **Outputs never replace inputs.** A command writes into a directory of its own
  (``check_output_dir``): not the folder of any file it reads (a run's JSON or CSV, a model
  directory), not a folder that holds runs tankode did not write (measured data), and not a
  folder inside a directory its owner marked read-only (no write bit for anyone, as shared data
  folders are; honoured even for root, whom the file system itself would let through).
* **Loading never unpickles code.** ``load_tensors`` reads ``torch.save`` files with
  ``weights_only=True`` and turns a refusal into a ``ValueError`` that names the file, instead
  of torch's hint to retry with the unsafe option.
"""

from __future__ import annotations

import json
import stat
import warnings
from pathlib import Path
from typing import Iterable

# Runs tankode writes say so at the start of their ``source`` (tankode.synthetic).
TANKODE_SOURCE_PREFIX = "tankode "


class OutputError(ValueError):
    """An output location that would replace or mix with input data."""


def _read_only_marked(d: Path) -> bool:
    try:
        mode = d.stat().st_mode
    except OSError:
        return False
    return not mode & (stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH)


def _foreign_runs(d: Path) -> list[str]:
    """Names of the run JSON files in ``d`` that tankode did not write (measured data)."""
    names = []
    for path in sorted(d.glob("*.json")):
        try:
            meta = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError, UnicodeDecodeError):
            continue
        if isinstance(meta, dict) and "timeseries" in meta and "tank" in meta:
            if not str(meta.get("source", "")).startswith(TANKODE_SOURCE_PREFIX):
                names.append(path.name)
    return names


def check_output_dir(out, inputs: Iterable = (), option: str = "--out") -> Path:
    """Validate ``out`` as a command's output directory (module docstring); return it as a Path.

    Args:
        out: the directory to write into (created later by the caller if missing).
        inputs: files and directories the command reads (run JSON and CSV files, model
            directories); ``out`` may be none of their folders.
        option: how the user named ``out`` (for the message).

    Raises:
        OutputError: with a one-line reason.
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise OutputError(f"{option} {out} is an existing file; give a directory")
    target = out.resolve()
    for item in inputs:
        p = Path(item).resolve()
        folder = p if p.is_dir() else p.parent
        if folder == target:
            raise OutputError(f"{option} {out} holds the input {item}: outputs never replace inputs; "
                              "choose another directory")
    for d in (target, *target.parents):
        if d.exists():
            if _read_only_marked(d):
                raise OutputError(f"{option} {out} lies in {d}, which is marked read-only; choose another directory")
    if target.is_dir():
        foreign = _foreign_runs(target)
        if foreign:
            shown = ", ".join(foreign[:3]) + (", ..." if len(foreign) > 3 else "")
            raise OutputError(f"{option} {out} holds runs that tankode did not write ({shown}): outputs never go "
                              "into a data folder; choose another directory")
    return out


def load_tensors(path, what: str = "file"):
    """``torch.load(path, weights_only=True)`` on the CPU, with one-line errors naming ``path``.

    Raises:
        FileNotFoundError: no such file.
        ValueError: the file is not a tensor file tankode wrote (e.g. it holds pickled objects,
            which are refused rather than executed).
    """
    import pickle

    import torch

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such {what}")
    try:
        with warnings.catch_warnings():  # torch warns about foreign pickle protocols before refusing them
            warnings.simplefilter("ignore")
            return torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError:
        # torch's own message suggests weights_only=False, which would run the file's code: not repeated.
        raise ValueError(f"{path}: refused to load this {what}: it is not a plain tensor file (tankode never "
                         "unpickles objects other than tensors and plain values)") from None
    except (RuntimeError, EOFError, OSError) as err:
        detail = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        raise ValueError(f"{path}: not a readable {what} ({detail})") from None


__all__ = ["OutputError", "check_output_dir", "load_tensors", "TANKODE_SOURCE_PREFIX"]
