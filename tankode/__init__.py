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

import importlib

# Public name -> the module that defines it. Loaded on first use (PEP 562), so that
# ``tankode --help`` and argument errors answer without importing torch and CoolProp.
_EXPORTS = {
    "get_case": ".cases",
    "ConstantClosure": ".closures", "MLPClosure": ".closures", "MLPConfig": ".closures",
    "ReferenceClosure": ".closures", "ReferenceCorrelation": ".closures",
    "Fleet": ".fleet",
    "geometry_from_spec": ".geometry",
    "SimulationError": ".errors",
    "TankModel": ".model",
    "CoolPropFluid": ".properties", "Domain": ".properties", "load_surrogate": ".properties",
    "InitialState": ".run", "Observations": ".run", "Run": ".run", "RunFormatError": ".run", "TankSpec": ".run",
    "read_run": ".run_io", "write_run": ".run_io",
    "Schedule": ".schedule",
    "Solution": ".simulation", "simulate": ".simulation",
    "LSODA": ".solver", "AdaptiveRK": ".solver", "Adjoint": ".solver", "Backprop": ".solver",
    "Checkpointed": ".solver", "NoGradient": ".solver", "Rosenbrock": ".solver",
}


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'tankode' has no attribute {name!r}")
    value = getattr(importlib.import_module(module, __name__), name)
    globals()[name] = value  # later lookups skip this function
    return value


def __dir__():
    return sorted(set(globals()) | set(_EXPORTS))


__version__ = "0.1.0"

__all__ = [
    "AdaptiveRK", "Adjoint", "Backprop", "Checkpointed", "ConstantClosure", "CoolPropFluid", "Domain", "Fleet", "InitialState",
    "LSODA", "MLPClosure", "MLPConfig", "NoGradient", "Observations", "ReferenceClosure", "ReferenceCorrelation",
    "Rosenbrock",
    "Run", "RunFormatError", "Schedule", "SimulationError", "Solution", "TankModel", "TankSpec", "geometry_from_spec",
    "get_case", "load_surrogate", "read_run", "simulate", "write_run",
]
