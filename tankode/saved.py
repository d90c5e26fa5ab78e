"""Saved models: a directory with ``model.json`` (configuration) and ``weights.pt`` (tensors).

Loading never unpickles arbitrary objects: the configuration is JSON, the weights are read
with ``torch.load(weights_only=True)`` and the closure is rebuilt from a known type name.
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

from typing import NamedTuple

import torch

from .closures import FEATURE_NAMES, ConstantClosure, MLPClosure, MLPConfig, ReferenceClosure, ReferenceCorrelation, ScaledClosure
from .files import load_tensors
from .mechanisms import Mechanism, mechanisms_from_spec, mechanisms_spec

FORMAT = "tankode-model-1"


class SavedModel(NamedTuple):
    """A loaded model: the closure, the mechanisms the model includes (with values) and the metadata."""

    closure: object
    mechanisms: tuple[Mechanism, ...]
    meta: dict


def closure_spec(closure) -> dict:
    """JSON description of a closure (type and configuration, not the weights)."""
    if isinstance(closure, MLPClosure):
        cfg = asdict(closure.config)
        cfg["features"] = list(cfg["features"])
        cfg["clamped_features"] = list(cfg["clamped_features"])
        cfg["hidden"] = list(cfg["hidden"])
        cfg["h_ref_W_m2K"] = list(cfg["h_ref_W_m2K"])
        return {"type": "MLPClosure", "config": cfg}
    if isinstance(closure, ReferenceClosure):
        return {"type": "ReferenceClosure", "config": asdict(closure.correlation)}
    if isinstance(closure, ConstantClosure):
        return {"type": "ConstantClosure", "theta_W_m2K": closure.theta.tolist()}
    if isinstance(closure, ScaledClosure):
        return {"type": "ScaledClosure", "base": closure_spec(closure.base), "factors": closure.factors.tolist(),
                "stable_mixing": closure.stable_mixing.tolist()}
    raise TypeError(f"cannot save a closure of type {type(closure).__name__}")


def closure_from_spec(spec: dict):
    """Rebuild a closure (untrained weights) from ``closure_spec``."""
    kind = spec.get("type")
    if kind == "MLPClosure":
        cfg = dict(spec["config"])
        # Models saved before the feature set became configurable used the default eight inputs.
        cfg["features"] = tuple(cfg.get("features", FEATURE_NAMES))
        cfg.setdefault("base", "constant")  # models saved before the residual agent had the constant base
        cfg["clamped_features"] = tuple(cfg.get("clamped_features", ()))  # every feature faded before the clamp
        cfg["hidden"] = tuple(cfg["hidden"])
        cfg["h_ref_W_m2K"] = tuple(cfg["h_ref_W_m2K"])
        return MLPClosure(MLPConfig(**cfg))
    if kind == "ReferenceClosure":
        return ReferenceClosure(ReferenceCorrelation(**spec["config"]))
    if kind == "ConstantClosure":
        return ConstantClosure(spec["theta_W_m2K"])
    if kind == "ScaledClosure":
        # Models saved before the stable-mixing share existed had none (0).
        return ScaledClosure(closure_from_spec(spec["base"]), spec["factors"], spec.get("stable_mixing", 0.0))
    raise ValueError(f"unknown closure type {kind!r} (known: MLPClosure, ReferenceClosure, ConstantClosure, "
                     "ScaledClosure)")


def save_model(model_dir, closure, fluid: str, info: dict | None = None, mechanisms=()) -> Path:
    """Write ``model_dir/model.json`` and ``model_dir/weights.pt``; returns the directory.

    ``mechanisms`` (``tankode.mechanisms``) are saved with their parameter values in the JSON:
    a model extended by the diagnosis is simulated, trained and used for prediction with them.
    """
    d = Path(model_dir)
    d.mkdir(parents=True, exist_ok=True)
    meta = {"format": FORMAT, "fluid": fluid, "closure": closure_spec(closure),
            "mechanisms": mechanisms_spec(mechanisms), "info": info or {}}
    torch.save({k: v.detach().clone() for k, v in closure.state_dict().items()}, d / "weights.pt")
    (d / "model.json").write_text(json.dumps(meta, indent=2) + "\n")
    return d


def load_model(model_dir) -> SavedModel:
    """Return ``SavedModel(closure, mechanisms, meta)`` from a model directory, validating its format."""
    d = Path(model_dir)
    path = d / "model.json"
    if not path.exists():
        raise FileNotFoundError(f"{d} is not a tankode model directory (no model.json)")
    try:
        meta = json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise ValueError(f"{path}:{err.lineno}:{err.colno}: invalid JSON: {err.msg}") from None
    if meta.get("format") != FORMAT:
        raise ValueError(f"{path}: format {meta.get('format')!r} is not {FORMAT!r}")
    if not isinstance(meta, dict) or not isinstance(meta.get("fluid"), str) or not isinstance(meta.get("closure"), dict):
        raise ValueError(f"{path}: a model needs 'fluid' (a string) and 'closure' (an object)")
    try:
        closure = closure_from_spec(meta["closure"])
    except KeyError as err:
        raise ValueError(f"{path}: closure: missing key {err}") from None
    except (TypeError, ValueError) as err:
        raise ValueError(f"{path}: closure: {err}") from None
    weights = load_tensors(d / "weights.pt", "weights file")
    try:
        closure.load_state_dict(weights)
    except (RuntimeError, TypeError, AttributeError) as err:
        first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        raise ValueError(f"{d / 'weights.pt'}: the weights do not fit the closure of {path} ({first})") from None
    try:
        mechanisms = tuple(mechanisms_from_spec(meta.get("mechanisms", [])))
    except (ValueError, TypeError) as err:
        raise ValueError(f"{path}: mechanisms: {err}") from None
    return SavedModel(closure, mechanisms, meta)


__all__ = ["SavedModel", "save_model", "load_model", "closure_spec", "closure_from_spec"]
