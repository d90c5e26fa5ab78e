"""The errors a simulation raises, naming where it failed and, where it can, why."""

from __future__ import annotations

from typing import TYPE_CHECKING

from .state import STATE_NAMES

if TYPE_CHECKING:
    from torch import Tensor


class SimulationError(RuntimeError):
    """The solver failed; carries the time (s) and the state where it was last evaluated.

    ``names``: the state's component names (``TankModel.state_names``, which names the
    mechanisms' own states); without them, components beyond the tank's 7 print as ``extra_<i>``.
    """

    def __init__(self, message: str, t_s: float | None = None, state: Tensor | None = None,
                 names: tuple[str, ...] | None = None):
        where = ""
        if t_s is not None:
            where = f" at t = {t_s:.6g} s"
        if state is not None:
            rows = []
            n = state.shape[-1]
            if names is None or len(names) != n:
                names = STATE_NAMES + tuple(f"extra_{i}" for i in range(n - len(STATE_NAMES)))
            for e, row in enumerate(state.detach().reshape(-1, n).tolist()):
                rows.append(f"env {e}: " + ", ".join(f"{k}={v:.6g}" for k, v in zip(names, row)))
            where += " in state\n  " + "\n  ".join(rows)
        super().__init__(message + where)
        self.message = message
        self.t_s = t_s
        self.state = state


class ImpossibleState(ValueError):
    """The tank reached a state the model cannot continue from; ``cause`` says which, in words.

    Raised by the model's right-hand side (an empty ullage, a dry tank, a wall below 0 K, a
    phase far outside the property surrogate's domain) and turned into a ``SimulationError``
    with the time and the state by the integrator. ``kind``: ``"ullage"``, ``"dry"``, ``"wall"``
    or ``"domain"``; ``env``: the environment that reached it.
    """

    def __init__(self, cause: str, kind: str, env: int):
        super().__init__(cause)
        self.cause, self.kind, self.env = cause, kind, env


class StateLeftDomain(SimulationError):
    """A phase's state left the property surrogate's fitted domain (a wider domain may hold it)."""


class BeyondPropertyDomain(ValueError):
    """A run's measured or initial states lie beyond every property domain tankode fits for its
    fluid (``tankode.properties.surrogate_covering``): the model cannot simulate it."""


class ConfigurationError(ValueError):
    """A command's options (or a configuration object built from them) are invalid or
    inconsistent: a fault of the options, not of the runs, so the command line says it without
    leading it by the run files."""


__all__ = ["SimulationError", "ImpossibleState", "StateLeftDomain", "BeyondPropertyDomain", "ConfigurationError"]
