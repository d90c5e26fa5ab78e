"""Closures theta = g(s; w) for the four heat transfer coefficients."""

from .base import THETA_NAMES, Closure, ClosureInputs, ConstantClosure
from .mlp import (BASES, EXTENDED_FEATURES, FEATURE_NAMES, INPUT_SETS, OPERATION_FEATURES, STATE_FEATURES, MLPClosure,
                  MLPConfig, mlp_features)
from .natural import NaturalConvection, NaturalConvectionClosure
from .scaled import ScaledClosure
from .reference import ReferenceClosure, ReferenceCorrelation, first_slosh_frequency_Hz, wave_height_m

__all__ = [
    "BASES",
    "NaturalConvection",
    "NaturalConvectionClosure",
    "Closure",
    "ClosureInputs",
    "ConstantClosure",
    "FEATURE_NAMES",
    "EXTENDED_FEATURES",
    "INPUT_SETS",
    "OPERATION_FEATURES",
    "STATE_FEATURES",
    "MLPClosure",
    "MLPConfig",
    "mlp_features",
    "ReferenceClosure",
    "ReferenceCorrelation",
    "ScaledClosure",
    "THETA_NAMES",
    "first_slosh_frequency_Hz",
    "wave_height_m",
]
