"""Piecewise-constant input schedule: the known operations applied to a tank over time.

A :class:`Schedule` holds breakpoints ``t_s`` (K,) and rows ``values`` (K, n_in), one column
per name in :data:`INPUT_NAMES`; row k holds on ``[t_k, t_{k+1})`` and the last row holds
until the end of the run. The first breakpoint is the start of the run.

Units (SI, spelled in the names):

==========================  =========================================================
``mdot_v_in_kg_s``          vapor injected into the ullage [kg/s]
``T_v_in_K``, ``p_v_in_Pa`` state the injected vapor's enthalpy is taken at [K], [Pa]
``mdot_v_out_kg_s``         vapor vented, at ullage conditions [kg/s]
``mdot_l_in_kg_s``          liquid injected [kg/s]
``T_l_in_K``                temperature the injected liquid's enthalpy is taken at [K]
``mdot_l_out_kg_s``         liquid drained, at liquid conditions [kg/s]
``slosh_amplitude_m``       amplitude A0 of the lateral sinusoidal excitation [m]
``slosh_frequency_Hz``      frequency f_e of that excitation [Hz]
``Q_aw_W``                  heat entering the wall from the ambient [W] (may be negative)
==========================  =========================================================

Every input is 0 unless set. An inlet temperature/pressure of 0 means "not set"; it is an
error for a flow to be on while the state its enthalpy is taken at is not set.
"""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass
from typing import Iterable, Mapping, Sequence

import numpy as np

__all__ = [
    "INPUT_NAMES",
    "Schedule",
    "ScheduleError",
    "input_value_problem",
    "merge_breakpoints",
]

INPUT_NAMES: tuple[str, ...] = (
    "mdot_v_in_kg_s",
    "T_v_in_K",
    "p_v_in_Pa",
    "mdot_v_out_kg_s",
    "mdot_l_in_kg_s",
    "T_l_in_K",
    "mdot_l_out_kg_s",
    "slosh_amplitude_m",
    "slosh_frequency_Hz",
    "Q_aw_W",
)
_INDEX = {name: i for i, name in enumerate(INPUT_NAMES)}

# Inputs that are physically non-negative. Q_aw_W is absent on purpose: a wall warmer than
# the ambient loses heat, which is a negative heat input.
_NON_NEGATIVE = frozenset(INPUT_NAMES) - {"Q_aw_W"}

# A flow that is on needs the state its enthalpy is taken at; venting and draining use the
# tank's own state, so they need nothing. (flow, required inputs)
_FLOW_NEEDS = (
    ("mdot_v_in_kg_s", ("T_v_in_K", "p_v_in_Pa")),
    ("mdot_l_in_kg_s", ("T_l_in_K",)),
    ("slosh_amplitude_m", ("slosh_frequency_Hz",)),
)


class ScheduleError(ValueError):
    """Invalid schedule content; ``name`` is the input and ``t_s`` the time [s] of the offence.

    ``reason`` is the message without the "input ... at t = ..." prefix, so that a file reader
    can re-word it with its own file/line context.
    """

    def __init__(self, name: str | None, t_s: float | None, reason: str):
        self.name = name
        self.t_s = t_s
        self.reason = reason
        where = []
        if name is not None:
            where.append(f"input '{name}'")
        if t_s is not None:
            where.append(f"at t = {t_s!r} s")
        super().__init__(f"{' '.join(where)}: {reason}" if where else reason)


def input_value_problem(name: str, value: float) -> str | None:
    """Return why ``value`` is not acceptable for input ``name`` (fluid-independent), or None."""
    if not math.isfinite(value):
        return f"value {value!r} is not finite (inputs must be numbers; an empty CSV cell means 'unchanged')"
    if name in _NON_NEGATIVE and value < 0.0:
        if name.startswith("mdot_"):
            hint = "mass flows are >= 0; the direction is in the name (_in / _out)"
        elif name.endswith("_K"):
            hint = f"absolute temperature; is it in Celsius? {value!r} °C = {value + 273.15:.10g} K"
        else:
            hint = "it must be >= 0"
        return f"value {value!r} is negative ({hint})"
    return None


def _unknown_name_message(name: str, known: Sequence[str]) -> str:
    close = difflib.get_close_matches(name, known, n=1, cutoff=0.5)
    hint = f" (did you mean '{close[0]}'?)" if close else ""
    return f"unknown input '{name}'{hint}; known inputs: {', '.join(known)}"


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=np.float64, copy=True)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class Schedule:
    """Piecewise-constant inputs.

    Fields:
        t_s: (K,) strictly increasing breakpoints [s]; ``t_s[0]`` is the start of the run.
        values: (K, len(INPUT_NAMES)) float64; row k holds on ``[t_s[k], t_s[k+1])``, the last
            row until the end of the run. Columns in the order of :data:`INPUT_NAMES`, SI units.

    Equality is semantic: two schedules are equal when they start at the same time and give
    the same inputs at every later time (repeated equal rows do not matter).
    """

    t_s: np.ndarray
    values: np.ndarray

    def __post_init__(self) -> None:
        t = np.asarray(self.t_s, dtype=np.float64)
        v = np.asarray(self.values, dtype=np.float64)
        if t.ndim != 1 or t.size == 0:
            raise ScheduleError(None, None, f"t_s must be a non-empty 1-D array, got shape {t.shape}")
        if v.shape != (t.size, len(INPUT_NAMES)):
            raise ScheduleError(
                None, None,
                f"values must have shape (len(t_s), {len(INPUT_NAMES)}) = ({t.size}, {len(INPUT_NAMES)}), "
                f"got {v.shape}",
            )
        bad_t = ~np.isfinite(t)
        if bad_t.any():
            k = int(np.argmax(bad_t))
            raise ScheduleError(None, None, f"breakpoint t_s[{k}] = {t[k]!r} is not finite")
        dt = np.diff(t)
        if (dt <= 0).any():
            k = int(np.argmax(dt <= 0)) + 1
            raise ScheduleError(
                None, float(t[k]),
                f"breakpoints must be strictly increasing: t_s[{k}] = {t[k]!r} s "
                f"follows t_s[{k - 1}] = {t[k - 1]!r} s",
            )
        _check_rows(t, v)
        object.__setattr__(self, "t_s", _readonly(t))
        object.__setattr__(self, "values", _readonly(v))

    # ----------------------------------------------------------------- constructors
    @classmethod
    def from_steps(
        cls,
        steps: Iterable[tuple[float, Mapping[str, float]]],
        t_end: float | None = None,
    ) -> "Schedule":
        """Build a schedule from ``[(t_s, {input_name: value, ...}), ...]``.

        Each step **sets the named inputs from its time on and keeps all other inputs as they
        were** (every input is 0 before it is first set). To switch something off, set it to 0
        explicitly, e.g. ``(3600, {"mdot_v_in_kg_s": 0.0})``. The first step's time is the start
        of the run (give ``(0, {})`` for "all off from t = 0"). Step times must be strictly
        increasing and, when ``t_end`` [s] is given, before it (a later step would never act).

        Example::

            Schedule.from_steps([(0, {}),
                                 (600, {"slosh_amplitude_m": 0.01, "slosh_frequency_Hz": 0.57}),
                                 (1800, {"mdot_v_in_kg_s": 4.2e-3, "T_v_in_K": 32.0, "p_v_in_Pa": 5e5})])
        """
        steps = list(steps)
        if not steps:
            raise ScheduleError(None, None, "from_steps needs at least one step (the start of the run)")
        times = []
        rows = []
        current = np.zeros(len(INPUT_NAMES))
        for t, changes in steps:
            t = float(t)
            if not isinstance(changes, Mapping):
                raise ScheduleError(None, t, f"a step must be (time, dict of inputs), got {type(changes).__name__}")
            for name, value in changes.items():
                if name not in _INDEX:
                    raise ScheduleError(name, t, _unknown_name_message(str(name), INPUT_NAMES))
                try:
                    current[_INDEX[name]] = float(value)
                except (TypeError, ValueError):
                    raise ScheduleError(name, t, f"value {value!r} is not a number") from None
            times.append(t)
            rows.append(current.copy())
        if t_end is not None and times[-1] >= float(t_end):
            raise ScheduleError(
                None, times[-1], f"step at t = {times[-1]!r} s is not before t_end = {float(t_end)!r} s, so it would never act"
            )
        return cls(np.array(times), np.array(rows))

    @classmethod
    def constant(cls, t0_s: float = 0.0, **inputs: float) -> "Schedule":
        """A schedule that holds the given inputs (others 0) from ``t0_s`` [s] on."""
        return cls.from_steps([(t0_s, inputs)])

    # ----------------------------------------------------------------- queries
    @property
    def t0_s(self) -> float:
        """Start of the schedule [s]."""
        return float(self.t_s[0])

    def at(self, t) -> np.ndarray:
        """Inputs at time ``t`` [s]: (n_in,) for a scalar, (n, n_in) for an array of n times.

        Right-continuous: at a breakpoint the new value already holds. Times before the start
        are an error (the inputs are not defined there).
        """
        ta = np.asarray(t, dtype=np.float64)
        if np.isnan(ta).any():
            raise ScheduleError(None, None, "at(t): t is NaN")
        if (ta < self.t_s[0]).any():
            bad = float(ta.min())
            raise ScheduleError(None, bad, f"at(t): t = {bad!r} s is before the start of the schedule {self.t0_s!r} s")
        k = np.searchsorted(self.t_s, ta, side="right") - 1
        return np.array(self.values[k])

    def __call__(self, t) -> np.ndarray:
        return self.at(t)

    def get(self, name: str, t) -> np.ndarray | float:
        """Value of input ``name`` at ``t`` [s] (scalar for scalar t)."""
        if name not in _INDEX:
            raise ScheduleError(name, None, _unknown_name_message(name, INPUT_NAMES))
        v = self.at(t)[..., _INDEX[name]]
        return float(v) if np.ndim(v) == 0 else v

    def change_times(self) -> np.ndarray:
        """All times [s] after the start at which some input really changes (sorted)."""
        changed = (self.values[1:] != self.values[:-1]).any(axis=1)
        return np.array(self.t_s[1:][changed])

    def breakpoints(self, t0: float, t1: float) -> np.ndarray:
        """Sorted times in the open interval (t0, t1) [s] at which some input changes value.

        Rows that repeat the previous values are not breakpoints, so an ODE solver is only
        restarted where the right-hand side really jumps.
        """
        c = self.change_times()
        return c[(c > t0) & (c < t1)]

    def segments(self, t0: float, t1: float) -> list[tuple[float, float, np.ndarray]]:
        """Split [t0, t1] [s] into ``(t_start, t_end, values)`` pieces of constant inputs.

        ``values`` is (n_in,). Consecutive pieces share their end/start time. Empty if
        ``t1 == t0``; ``t0`` must not be before the start of the schedule.
        """
        t0 = float(t0)
        t1 = float(t1)
        if t1 < t0:
            raise ScheduleError(None, t0, f"segments(t0, t1): t1 = {t1!r} s is before t0 = {t0!r} s")
        if t1 == t0:
            return []
        edges = [t0, *self.breakpoints(t0, t1).tolist(), t1]
        return [(a, b, self.at(a)) for a, b in zip(edges[:-1], edges[1:])]

    def compressed(self) -> "Schedule":
        """The same schedule without rows that repeat the previous row."""
        keep = np.ones(len(self.t_s), dtype=bool)
        keep[1:] = (self.values[1:] != self.values[:-1]).any(axis=1)
        if keep.all():
            return self
        return Schedule(self.t_s[keep], self.values[keep])

    def used_inputs(self) -> tuple[str, ...]:
        """Names of the inputs that are non-zero at some time, in :data:`INPUT_NAMES` order."""
        nz = (self.values != 0.0).any(axis=0)
        return tuple(n for n, used in zip(INPUT_NAMES, nz) if used)

    def as_dict(self, t) -> dict[str, float]:
        """Inputs at scalar time ``t`` [s] as ``{name: value}``."""
        return dict(zip(INPUT_NAMES, (float(x) for x in self.at(float(t)))))

    # ----------------------------------------------------------------- dunder
    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Schedule):
            return NotImplemented
        a, b = self.compressed(), other.compressed()
        return (
            a.t_s.shape == b.t_s.shape
            and np.array_equal(a.t_s, b.t_s)
            and np.array_equal(a.values, b.values)
        )

    __hash__ = None  # type: ignore[assignment]  # mutable-looking arrays inside: not hashable

    def __repr__(self) -> str:
        c = self.compressed()
        parts = []
        for t, row in zip(c.t_s, c.values):
            nz = {n: float(x) for n, x in zip(INPUT_NAMES, row) if x != 0.0}
            parts.append(f"({float(t)!r}, {nz!r})")
        return f"Schedule.from_steps([{', '.join(parts)}])"


def _check_rows(t: np.ndarray, v: np.ndarray) -> None:
    """Validate every value and flow/state consistency; raise ScheduleError at the first problem."""
    bad = ~np.isfinite(v)
    neg = np.zeros_like(bad)
    for name in _NON_NEGATIVE:
        neg[:, _INDEX[name]] = v[:, _INDEX[name]] < 0.0
    offending = bad | neg
    if offending.any():
        k, j = np.argwhere(offending)[0]
        name = INPUT_NAMES[j]
        raise ScheduleError(name, float(t[k]), input_value_problem(name, float(v[k, j])) or "invalid")
    for flow, needs in _FLOW_NEEDS:
        on = v[:, _INDEX[flow]] > 0.0
        for need in needs:
            missing = on & (v[:, _INDEX[need]] == 0.0)
            if missing.any():
                k = int(np.argmax(missing))
                raise ScheduleError(
                    need, float(t[k]),
                    f"'{flow}' = {float(v[k, _INDEX[flow]])!r} is on but '{need}' is not set (0); "
                    f"it is needed while '{flow}' > 0",
                )


def merge_breakpoints(schedules: Iterable[Schedule], t0: float, t1: float) -> np.ndarray:
    """Sorted union of the times in (t0, t1) [s] at which any of ``schedules`` changes."""
    parts = [s.breakpoints(t0, t1) for s in schedules]
    if not parts:
        return np.zeros(0)
    return np.unique(np.concatenate(parts))
