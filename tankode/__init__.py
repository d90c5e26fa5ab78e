"""tankode: learn the heat and mass transfer of cryogenic tanks from their sensor data.

Public surface (one entry point per job):

* ``simulate(runs, closure=None) -> Solution``: the forward model (``tankode.simulate``).
* ``read_run`` / ``write_run``: runs in the interchange format (``tankode.run_io``).
* ``get_case``: the paper's five environments (``tankode.cases``).
* ``TankModel``, ``Fleet``: the right-hand side and a batch of tanks for it.
* closures: ``ReferenceClosure`` (the paper's correlations), ``MLPClosure`` (the agent),
  ``ConstantClosure``.
* properties: ``CoolPropFluid`` (reference), ``load_surrogate`` (differentiable surrogate).
* solvers and gradients: ``AdaptiveRK``, ``LSODA``, ``Rosenbrock``, ``Adjoint``, ``Backprop``, ``Checkpointed``, ``NoGradient``.
"""

from .cases import get_case
from .closures import ConstantClosure, MLPClosure, MLPConfig, ReferenceClosure, ReferenceCorrelation
from .fleet import Fleet
from .geometry import geometry_from_spec
from .integrate import SimulationError
from .model import TankModel
from .properties import CoolPropFluid, Domain, load_surrogate
from .run import InitialState, Observations, Run, RunFormatError, TankSpec
from .run_io import read_run, write_run
from .schedule import Schedule
from .simulate import Solution, simulate
from .solver import LSODA, AdaptiveRK, Adjoint, Backprop, Checkpointed, NoGradient, Rosenbrock

__version__ = "0.1.0"

__all__ = [
    "AdaptiveRK", "Adjoint", "Backprop", "Checkpointed", "ConstantClosure", "CoolPropFluid", "Domain", "Fleet", "InitialState",
    "LSODA", "MLPClosure", "MLPConfig", "NoGradient", "Observations", "ReferenceClosure", "ReferenceCorrelation",
    "Rosenbrock",
    "Run", "RunFormatError", "Schedule", "SimulationError", "Solution", "TankModel", "TankSpec", "geometry_from_spec",
    "get_case", "load_surrogate", "read_run", "simulate", "write_run",
]
