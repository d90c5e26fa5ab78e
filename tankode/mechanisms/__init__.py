"""Candidate mechanisms the baseline model leaves out, each absent at parameter value 0.

``MECHANISMS`` maps each id to its class; ``make_mechanism(id, **values)`` builds one.
"""

from __future__ import annotations

from .base import Mechanism, Param, Start, StateVar
from .boundary_layer import BoundaryLayerStratification
from .dry_wall import DryWallHeating
from .dry_wall_node import DryWallNode
from .diffusive_layer import DiffusiveLayer
from .growing_layer import GrowingLayer
from .heat_leaks import HeatLeakLiquid, HeatLeakVapor, HeatLeakWall
from .leaks import LiquidLeak, VaporLeak
from .noncondensable import NoncondensableGas
from .saturated_boiling import SaturatedBoiling
from .saturated_start import SaturatedStart
from .sensors import InflowMeterBias, PressureSensorBias, TemperatureSensorBias
from .stratification import ThermalStratification
from .surface_layer import SurfaceLayer
from .two_node_wall import TwoNodeWall
from .wall_capacity import UNKNOWN_WALL_FACTOR_RANGE, UnknownWallCapacity, WallHeatCapacityError, applied_to_walls

MECHANISMS: dict[str, type[Mechanism]] = {
    m.id: m
    for m in (HeatLeakLiquid, HeatLeakVapor, HeatLeakWall, VaporLeak, LiquidLeak, PressureSensorBias,
              WallHeatCapacityError, NoncondensableGas, ThermalStratification, InflowMeterBias, DryWallHeating,
              SurfaceLayer, BoundaryLayerStratification, GrowingLayer, DiffusiveLayer, DryWallNode, TwoNodeWall,
              SaturatedBoiling, TemperatureSensorBias, SaturatedStart, UnknownWallCapacity)
}


def make_mechanism(mechanism_id: str, **values: float) -> Mechanism:
    """The mechanism ``mechanism_id`` with the given parameter values (others 0)."""
    if mechanism_id not in MECHANISMS:
        raise ValueError(f"unknown mechanism {mechanism_id!r}; known: {', '.join(MECHANISMS)}")
    return MECHANISMS[mechanism_id](**values)


def mechanisms_spec(mechanisms) -> list[dict]:
    """JSON description ``[{"id": ..., "params": {...}}, ...]`` of mechanisms with their values."""
    return [{"id": m.id, "params": m.values_dict()} for m in mechanisms]


def mechanisms_from_spec(spec) -> list[Mechanism]:
    """Rebuild mechanisms from ``mechanisms_spec``."""
    out = []
    for i, item in enumerate(spec or []):
        if not isinstance(item, dict) or "id" not in item:
            raise ValueError(f"mechanisms[{i}]: expected {{'id': ..., 'params': {{...}}}}, got {item!r}")
        out.append(make_mechanism(item["id"], **item.get("params", {})))
    return out


__all__ = [
    "MECHANISMS", "Mechanism", "Param", "Start", "StateVar", "make_mechanism", "mechanisms_spec", "mechanisms_from_spec",
    "HeatLeakLiquid", "HeatLeakVapor", "HeatLeakWall", "VaporLeak", "LiquidLeak", "PressureSensorBias",
    "WallHeatCapacityError", "NoncondensableGas", "ThermalStratification", "InflowMeterBias", "DryWallHeating",
    "SurfaceLayer", "BoundaryLayerStratification", "GrowingLayer", "DiffusiveLayer", "DryWallNode", "TwoNodeWall",
    "SaturatedBoiling", "TemperatureSensorBias", "SaturatedStart", "UnknownWallCapacity", "UNKNOWN_WALL_FACTOR_RANGE",
    "applied_to_walls",
]
