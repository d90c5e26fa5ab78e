"""Runs in the project's interchange format (``NAME.json`` + ``NAME.csv``, see data-format.md).

A *run* is one tank observed over time: metadata (fluid, tank, initial state, sensor noise)
and time series (asynchronous observations and piecewise-constant inputs). This module
holds the run and validates it, however it was built; ``tankode.run_io`` reads and writes it
as files, with errors that name the file, line and column.

Decisions beyond the format document (v1):

* Time origin. The run starts at the first CSV time stamp ``t0`` (= ``inputs.t_s[0]``); the
  initial state is the state at ``t0``. ``duration_s`` is the length of the run, so
  ``t_end_s = t0 + duration_s`` (with ``t0 = 0`` this is the document's "last time stamp");
  a duration that ends before the last time stamp is extended to it, with a note
  (``Run.notes``): digitised data can end a little after the stated duration.
* Input cells. An empty input cell means "unchanged" (the previous row's value holds); an
  input is 0 before its first value. ``NaN``/``inf`` in an input is an error, not "unchanged".
  An inlet temperature/pressure of 0 means "not set" and is allowed while its flow is off.
* Observation cells. An empty cell (or the literal ``nan``) means "not measured"; ``inf`` is an
  error. Rows that measure nothing carry no observation.
* Writing. CSV rows are the union of the observation times, the start and the times at
  which an input really changes. Every written input column is filled on every row (the
  piecewise-constant value), so naive readers (spreadsheets, pandas) see correct values.
  Only inputs that are non-zero at some time and channels measured at least once are written.
  Floats are written with ``repr`` (shortest round-trip form), so a round trip is bit-exact.
* Strictness. Unknown or duplicate keys/columns are errors (a typo must not lose data). A
  channel with measurements needs its ``noise_std`` (the measurement covariance R); a
  ``noise_std`` for a channel without measurements is allowed (e.g. a simulation to be sampled).
* ``fluid`` is normalised to CoolProp's canonical name (``parahydrogen`` -> ``ParaHydrogen``).
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import re
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .schedule import INPUT_NAMES, Schedule

__all__ = [
    "OBS_CHANNELS",
    "NOISE_KEYS",
    "INPUT_NAMES",
    "TANK_SHAPES",
    "RunFormatError",
    "RunValueError",
    "TankSpec",
    "InitialState",
    "Observations",
    "Run",
    "canonical_fluid",
]

OBS_CHANNELS: tuple[str, ...] = ("p_v_Pa", "T_v_K", "T_l_K", "T_w_K", "H_l_m")
NOISE_KEYS: tuple[str, ...] = ("p_v", "T_v", "T_l", "T_w", "H_l")
_NOISE_OF = dict(zip(OBS_CHANNELS, NOISE_KEYS))
_CHANNEL_OF = dict(zip(NOISE_KEYS, OBS_CHANNELS))

# Shape -> its dimension keys (all in metres except the dimensionless head_aspect).
TANK_SHAPES: dict[str, tuple[str, ...]] = {
    "vertical_cylinder": ("radius_m", "height_m"),
    "vertical_cylinder_elliptical_heads": ("radius_m", "cylinder_length_m", "head_aspect"),
    "sphere": ("radius_m",),
    "horizontal_cylinder": ("radius_m", "cylinder_length_m"),
}
# A straight part of length 0 is a legitimate limit between two elliptical heads (a
# spheroid); every other dimension must be strictly positive.
_DIMS_MAY_BE_ZERO = frozenset({("vertical_cylinder_elliptical_heads", "cylinder_length_m")})

# Plausibility bounds: wide enough for any cryogenic or ambient tank, narrow enough to catch
# unit mistakes (bar for Pa, Celsius for kelvin, mm for m).
_P_MIN_PA, _P_MAX_PA = 1e3, 1e8
_T_MAX_K = 1000.0
_H_MAX_M = 100.0
LEVEL_ABOVE_TANK = 1.5  # a measured level beyond this share of the tank's inner height is an error
# s; the longest span a run may cover: decades of storage, far past any test, short of spans
# (1e300 s) that only a wrong time unit makes and that no simulation or window count can hold.
MAX_SPAN_S = 1e9

# Column -> (kind, what it is) for the plausibility checks.
_QUANTITY: dict[str, tuple[str, str]] = {
    "p_v_Pa": ("pressure", "ullage pressure"),
    "T_v_K": ("temperature", "vapor temperature"),
    "T_l_K": ("temperature", "liquid temperature"),
    "T_w_K": ("temperature", "wall temperature"),
    "H_l_m": ("level", "liquid level"),
    "p_v_in_Pa": ("pressure", "injected-vapor pressure"),
    "T_v_in_K": ("temperature", "injected-vapor temperature"),
    "T_l_in_K": ("temperature", "injected-liquid temperature"),
}
# Inlet states where 0 means "not set" (allowed while the matching flow is off).
_UNSET_ALLOWED = frozenset({"p_v_in_Pa", "T_v_in_K", "T_l_in_K"})

_JSON_TANK_OPTIONAL = ("volume_m3", "wall_heat_capacity_J_per_K")


# ===================================================================== errors
class RunFormatError(ValueError):
    """A run file is malformed; names the file, the line and the column (CSV) or key (JSON).

    Attributes:
        path: the file (as given/derived, str).
        line: 1-based line in that file, or None when it cannot be located.
        column: the CSV column name, the JSON key path (``"initial.fill_ratio"``) or, for a JSON
            syntax error, the 1-based character column (int); None when not applicable.
        detail: the message without the location prefix.
    """

    def __init__(self, path, line: int | None, column: str | int | None, detail: str, *, what: str = "column"):
        self.path = str(path)
        self.line = line
        self.column = column
        self.detail = detail
        loc = self.path
        if line is not None:
            loc += f":{line}"
        if isinstance(column, int):
            loc += f":{column}"
            msg = f"{loc}: {detail}"
        elif column is not None:
            msg = f"{loc}: {what} '{column}': {detail}"
        else:
            msg = f"{loc}: {detail}"
        super().__init__(msg)


class RunValueError(ValueError):
    """A value of a run built in code is invalid; ``key`` is its dotted path (``initial.T_l_K``).

    ``tankode.run_io.read_run`` turns it into a :class:`RunFormatError` that names the file and line.
    """

    def __init__(self, key: str, detail: str, t_s: float | None = None):
        self.key = key
        self.detail = detail
        self.t_s = t_s  # the time stamp of an offending time-series row, if any
        super().__init__(f"{key}: {detail}")


# ===================================================================== fluid & plausibility
@lru_cache(maxsize=None)
def _coolprop_fluids() -> tuple[str, ...]:
    import CoolProp.CoolProp as CP

    return tuple(sorted(CP.get_global_param_string("FluidsList").split(",")))


@lru_cache(maxsize=None)
def _coolprop_names_and_aliases() -> tuple[str, ...]:
    import CoolProp.CoolProp as CP

    out = list(_coolprop_fluids())
    for f in _coolprop_fluids():
        try:
            out += [a for a in CP.get_fluid_param_string(f, "aliases").split(",") if a]
        except ValueError:
            pass
    return tuple(out)


def canonical_fluid(name: str) -> str:
    """CoolProp's canonical name for fluid ``name`` (name or alias); RunValueError if unknown."""
    if not isinstance(name, str) or not name:
        raise RunValueError("fluid", f"must be a non-empty string naming a CoolProp fluid, got {name!r}")
    return _canonical_fluid(name)


@lru_cache(maxsize=None)
def _canonical_fluid(name: str) -> str:
    if name in _coolprop_fluids():
        return name
    import CoolProp.CoolProp as CP

    try:
        canon = CP.get_fluid_param_string(name, "name")
    except ValueError:
        canon = ""
    if canon in _coolprop_fluids():
        return canon
    close = difflib.get_close_matches(name, _coolprop_names_and_aliases(), n=3, cutoff=0.6)
    hint = f" (did you mean {' or '.join(repr(c) for c in close)}?)" if close else ""
    raise RunValueError(
        "fluid",
        f"unknown fluid {name!r}{hint}; it must be a CoolProp fluid name or alias "
        "(CoolProp.CoolProp.get_global_param_string('FluidsList'))",
    )


@lru_cache(maxsize=None)
def _triple_point_K(fluid: str) -> float:
    import CoolProp.CoolProp as CP

    try:
        return float(CP.PropsSI("Ttriple", fluid))
    except ValueError:  # a few pseudo-pure fluids have none; the generic bounds still apply
        return 0.0


def _sci(v: float) -> str:
    """1000.0 -> '1e3' (how a person writes a bound)."""
    m, e = f"{v:e}".split("e")
    return f"{float(m):g}e{int(e)}"


def _g(v: float) -> str:
    return f"{v:.10g}"


def _plausibility_problem(column: str, value: float, fluid: str | None) -> str | None:
    """Return why ``value`` is physically implausible for ``column`` (SI unit), or None."""
    if column not in _QUANTITY:
        return None
    kind, what = _QUANTITY[column]
    if column in _UNSET_ALLOWED and value == 0.0:
        return None
    for_fluid = f" for {fluid}" if fluid else ""
    if kind == "pressure":
        if _P_MIN_PA <= value <= _P_MAX_PA:
            return None
        if 0.0 < value < 30.0:
            hint = "; is it in bar (or MPa)?"
        elif 30.0 <= value < _P_MIN_PA:
            hint = "; is it in kPa?"
        else:
            hint = ""
        return (
            f"value {_g(value)} is not a plausible {what}{for_fluid} "
            f"(expected Pa between {_sci(_P_MIN_PA)} and {_sci(_P_MAX_PA)}{hint})"
        )
    if kind == "temperature":
        t_min = 0.5 * _triple_point_K(fluid) if fluid else 0.0
        if value > 0.0 and value >= t_min and value <= _T_MAX_K:
            return None
        if value <= 0.0 and value + 273.15 > 0.0:
            hint = f"; is it in Celsius? {_g(value)} °C = {_g(value + 273.15)} K"
        elif value <= 0.0:
            hint = "; absolute temperatures are > 0"
        elif value < t_min:
            hint = f"; half the triple point of {fluid} is {t_min:.4g} K"
        else:
            hint = ""
        lo = f"{t_min:.4g}" if t_min > 0 else "0 (exclusive)"
        return (
            f"value {_g(value)} is not a plausible {what}{for_fluid} "
            f"(expected K between {lo} and {_T_MAX_K:g}{hint})"
        )
    # level
    if 0.0 <= value <= _H_MAX_M:
        return None
    hint = "; is it in mm or cm?" if value > _H_MAX_M else ""
    return f"value {_g(value)} is not a plausible {what} (expected m between 0 and {_H_MAX_M:g}{hint})"


def _first_implausible(column: str, values: np.ndarray, fluid: str | None) -> int | None:
    """Index of the first value (NaN = not measured, skipped) that is implausible, or None.

    Vectorised twin of :func:`_plausibility_problem`, which words the message.
    """
    if column not in _QUANTITY:
        return None
    kind = _QUANTITY[column][0]
    v = np.asarray(values, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        if kind == "pressure":
            ok = (v >= _P_MIN_PA) & (v <= _P_MAX_PA)
        elif kind == "temperature":
            t_min = 0.5 * _triple_point_K(fluid) if fluid else 0.0
            ok = (v > 0.0) & (v >= t_min) & (v <= _T_MAX_K)
        else:
            ok = (v >= 0.0) & (v <= _H_MAX_M)
    ok |= np.isnan(v)
    if column in _UNSET_ALLOWED:
        ok |= v == 0.0
    bad = np.flatnonzero(~ok)
    return int(bad[0]) if bad.size else None


def _as_float(key: str, value: Any, *, allow_none: bool = False) -> float | None:
    """Convert a code/JSON value to float; bools and strings are type errors, not numbers."""
    if value is None and allow_none:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        kind = "a number or null" if allow_none else "a number"
        raise RunValueError(key, f"must be {kind}, got {type(value).__name__} {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise RunValueError(key, f"must be finite, got {v!r}")
    return v


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=np.float64, copy=True)
    a.setflags(write=False)
    return a


# ===================================================================== dataclasses
@dataclass(frozen=True)
class TankSpec:
    """Tank shape and wall.

    Fields:
        shape: one of :data:`TANK_SHAPES` (``vertical_cylinder``, ``sphere``, ...).
        dims: the shape's dimensions, e.g. ``{"radius_m": 0.9, "height_m": 2.2}`` [m];
            ``head_aspect`` (radius / head depth) is dimensionless.
        volume_m3: stated internal volume [m^3]; when given it must agree with the shape
            within 1 % (checked by :func:`tankode.geometry.geometry_from_spec`).
        wall_heat_capacity_J_per_K: m_w c_w of the wall [J/K]; None when unknown.
    """

    shape: str
    dims: dict[str, float]
    volume_m3: float | None = None
    wall_heat_capacity_J_per_K: float | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.shape, str) or self.shape not in TANK_SHAPES:
            close = difflib.get_close_matches(str(self.shape), TANK_SHAPES, n=1, cutoff=0.5)
            hint = f" (did you mean '{close[0]}'?)" if close else ""
            raise RunValueError("tank.shape", f"unknown shape {self.shape!r}{hint}; known: {', '.join(TANK_SHAPES)}")
        if not isinstance(self.dims, Mapping):
            raise RunValueError("tank", f"dims must be a mapping of dimension name to metres, got {type(self.dims).__name__}")
        need = TANK_SHAPES[self.shape]
        for k in self.dims:
            if k not in need:
                close = difflib.get_close_matches(str(k), need + _JSON_TANK_OPTIONAL, n=1, cutoff=0.5)
                hint = f" (did you mean '{close[0]}'?)" if close else ""
                raise RunValueError(f"tank.{k}", f"unknown key for shape '{self.shape}'{hint}; it takes {', '.join(need)}")
        dims = {}
        for k in need:
            if k not in self.dims:
                raise RunValueError(f"tank.{k}", f"missing: shape '{self.shape}' needs {', '.join(need)}")
            v = _as_float(f"tank.{k}", self.dims[k])
            may_be_zero = (self.shape, k) in _DIMS_MAY_BE_ZERO
            if v < 0 or (v == 0 and not may_be_zero):
                rng = ">= 0" if may_be_zero else "> 0"
                raise RunValueError(f"tank.{k}", f"{k} = {v!r} is outside the allowed range ({rng})")
            dims[k] = v
        object.__setattr__(self, "dims", dims)
        vol = _as_float("tank.volume_m3", self.volume_m3, allow_none=True)
        if vol is not None and vol <= 0:
            raise RunValueError("tank.volume_m3", f"volume_m3 = {vol!r} must be > 0 (or null)")
        object.__setattr__(self, "volume_m3", vol)
        cw = _as_float("tank.wall_heat_capacity_J_per_K", self.wall_heat_capacity_J_per_K, allow_none=True)
        if cw is not None and cw <= 0:
            raise RunValueError("tank.wall_heat_capacity_J_per_K", f"wall_heat_capacity_J_per_K = {cw!r} must be > 0 (or null when unknown)")
        object.__setattr__(self, "wall_heat_capacity_J_per_K", cw)
        self._check_geometry()

    def _check_geometry(self) -> None:
        # Shape/volume consistency is the geometry module's job (it owns the closed forms).
        from tankode.geometry import geometry_from_spec

        try:
            geometry_from_spec(self.to_dict())
        except ValueError as e:
            msg = str(e)
            # Point at the key the geometry complains about, so a file error names its line.
            named = [k for k in re.findall(r"'(\w+)'", msg) if k in self.dims or k == "volume_m3"]
            if named:
                key = f"tank.{named[0]}"
            elif self.volume_m3 is not None and "volume" in msg.lower():
                key = "tank.volume_m3"
            else:
                key = "tank"
            raise RunValueError(key, msg) from e

    def to_dict(self) -> dict[str, Any]:
        """The JSON ``tank`` object: shape, dims, volume_m3 (if given), wall_heat_capacity_J_per_K."""
        d: dict[str, Any] = {"shape": self.shape, **self.dims}
        if self.volume_m3 is not None:
            d["volume_m3"] = self.volume_m3
        d["wall_heat_capacity_J_per_K"] = self.wall_heat_capacity_J_per_K
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "TankSpec":
        """Build from the JSON ``tank`` object (dims at the same level as ``shape``)."""
        if "shape" not in d:
            raise RunValueError("tank.shape", "missing")
        dims = {k: v for k, v in d.items() if k not in ("shape",) + _JSON_TANK_OPTIONAL}
        return cls(
            shape=d["shape"],
            dims=dims,
            volume_m3=d.get("volume_m3"),
            wall_heat_capacity_J_per_K=d.get("wall_heat_capacity_J_per_K"),
        )

    def geometry(self):
        """The tank geometry object, :func:`tankode.geometry.geometry_from_spec` of this spec."""
        from tankode.geometry import geometry_from_spec

        return geometry_from_spec(self.to_dict())


@dataclass(frozen=True, kw_only=True)
class InitialState:
    """State at the start of the run (keyword-only, to keep temperatures from being swapped).

    Fields:
        p_v_Pa: ullage pressure [Pa].
        T_v_K: mass-averaged vapor temperature [K].
        T_l_K: mass-averaged liquid temperature [K].
        T_w_K: wall temperature [K]; None = starts at ``T_l_K`` (see :attr:`T_w0_K`).
        fill_ratio: liquid volume / tank volume, in the open interval (0, 1).
    """

    p_v_Pa: float
    T_v_K: float
    T_l_K: float
    T_w_K: float | None = None
    fill_ratio: float

    def __post_init__(self) -> None:
        for name in ("p_v_Pa", "T_v_K", "T_l_K", "T_w_K"):
            v = _as_float(f"initial.{name}", getattr(self, name), allow_none=(name == "T_w_K"))
            if v is not None:
                problem = _plausibility_problem(name, v, None)
                if problem:
                    raise RunValueError(f"initial.{name}", problem)
            object.__setattr__(self, name, v)
        f = _as_float("initial.fill_ratio", self.fill_ratio)
        if not 0.0 < f < 1.0:
            raise RunValueError(
                "initial.fill_ratio",
                f"fill_ratio = {f!r} is outside the open interval (0, 1) (liquid volume / tank volume"
                + ("; is it a percentage?)" if 1.0 < f <= 100.0 else ")"),
            )
        object.__setattr__(self, "fill_ratio", f)

    @property
    def T_w0_K(self) -> float:
        """Initial wall temperature [K]: ``T_w_K``, or ``T_l_K`` when it is not given."""
        return self.T_l_K if self.T_w_K is None else self.T_w_K

    def to_dict(self) -> dict[str, float]:
        """The JSON ``initial`` object (``T_w_K`` omitted when None)."""
        d = {"p_v_Pa": self.p_v_Pa, "T_v_K": self.T_v_K, "T_l_K": self.T_l_K}
        if self.T_w_K is not None:
            d["T_w_K"] = self.T_w_K
        d["fill_ratio"] = self.fill_ratio
        return d


def _channel_index(name: str) -> int:
    if name in _NOISE_OF:
        return OBS_CHANNELS.index(name)
    if name in _CHANNEL_OF:
        return NOISE_KEYS.index(name)
    close = difflib.get_close_matches(name, OBS_CHANNELS + NOISE_KEYS, n=1, cutoff=0.5)
    hint = f" (did you mean '{close[0]}'?)" if close else ""
    raise KeyError(f"unknown observation channel {name!r}{hint}; channels: {', '.join(OBS_CHANNELS)}")


@dataclass(frozen=True, eq=False)
class Observations:
    """Asynchronous sensor samples on a shared time axis.

    Fields:
        t_s: (N,) strictly increasing sample times [s].
        values: (N, 5) float64, columns :data:`OBS_CHANNELS` (``p_v_Pa`` [Pa], ``T_v_K``,
            ``T_l_K``, ``T_w_K`` [K], ``H_l_m`` [m]); NaN where a channel is not measured.

    Rows that measure nothing are dropped on construction (they carry no data), so equal
    measurements give equal objects. Equality is exact (bit-identical; NaN == NaN).
    """

    t_s: np.ndarray
    values: np.ndarray

    def __post_init__(self) -> None:
        t = np.asarray(self.t_s, dtype=np.float64)
        v = np.asarray(self.values, dtype=np.float64)
        if t.ndim != 1:
            raise RunValueError("observations.t_s", f"must be 1-D, got shape {t.shape}")
        if v.ndim == 1 and v.size == 0 and t.size == 0:
            v = v.reshape(0, len(OBS_CHANNELS))
        if v.shape != (t.size, len(OBS_CHANNELS)):
            raise RunValueError(
                "observations.values",
                f"must have shape (len(t_s), {len(OBS_CHANNELS)}) = ({t.size}, {len(OBS_CHANNELS)}), got {v.shape}",
            )
        if not np.isfinite(t).all():
            k = int(np.argmax(~np.isfinite(t)))
            raise RunValueError("observations.t_s", f"t_s[{k}] = {t[k]!r} is not finite")
        dt = np.diff(t)
        if (dt <= 0).any():
            k = int(np.argmax(dt <= 0)) + 1
            raise RunValueError(
                "observations.t_s",
                f"must be strictly increasing: t_s[{k}] = {t[k]!r} s follows t_s[{k - 1}] = {t[k - 1]!r} s",
            )
        inf = np.isinf(v)
        if inf.any():
            k, j = np.argwhere(inf)[0]
            raise RunValueError(f"observations.{OBS_CHANNELS[j]}", f"value {v[k, j]!r} at t = {t[k]!r} s is not finite")
        keep = ~np.isnan(v).all(axis=1)
        object.__setattr__(self, "t_s", _readonly(t[keep]))
        object.__setattr__(self, "values", _readonly(v[keep]))

    @classmethod
    def empty(cls) -> "Observations":
        """No samples."""
        return cls(np.zeros(0), np.zeros((0, len(OBS_CHANNELS))))

    @classmethod
    def from_channels(cls, channels: Mapping[str, tuple[Any, Any]]) -> "Observations":
        """Build from ``{channel: (t_s, values)}`` sampled at different times (union of times).

        Channel names are :data:`OBS_CHANNELS` or :data:`NOISE_KEYS`; times within a channel must be
        strictly increasing.
        """
        ts = []
        for name, (t, v) in channels.items():
            t = np.asarray(t, dtype=np.float64)
            v = np.asarray(v, dtype=np.float64)
            if t.shape != v.shape or t.ndim != 1:
                raise RunValueError(f"observations.{name}", f"t and values must be 1-D of equal length, got {t.shape} and {v.shape}")
            if (np.diff(t) <= 0).any():
                raise RunValueError(f"observations.{name}", "sample times must be strictly increasing")
            ts.append(t)
        t_all = np.unique(np.concatenate(ts)) if ts else np.zeros(0)
        vals = np.full((t_all.size, len(OBS_CHANNELS)), np.nan)
        for name, (t, v) in channels.items():
            j = _channel_index(name)
            vals[np.searchsorted(t_all, np.asarray(t, dtype=np.float64)), j] = v
        return cls(t_all, vals)

    @property
    def mask(self) -> np.ndarray:
        """(N, 5) bool, True where a channel is measured."""
        return ~np.isnan(self.values)

    def channel(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """``(t_s, values)`` of the measured samples of one channel (``"p_v_Pa"`` or ``"p_v"``)."""
        j = _channel_index(name)
        m = ~np.isnan(self.values[:, j])
        return np.array(self.t_s[m]), np.array(self.values[m, j])

    @property
    def measured_channels(self) -> tuple[str, ...]:
        """Channels with at least one sample, in :data:`OBS_CHANNELS` order."""
        any_ = self.mask.any(axis=0)
        return tuple(c for c, a in zip(OBS_CHANNELS, any_) if a)

    def counts(self) -> dict[str, int]:
        """Number of measured samples per channel."""
        return dict(zip(OBS_CHANNELS, (int(n) for n in self.mask.sum(axis=0))))

    def __len__(self) -> int:
        return int(self.t_s.size)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Observations):
            return NotImplemented
        return (
            self.values.shape == other.values.shape
            and np.array_equal(self.t_s, other.t_s)
            and np.array_equal(self.values, other.values, equal_nan=True)
        )

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        return f"Observations(N={len(self)}, counts={self.counts()})"


_NAME_RE = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.+-]*$")


@dataclass(frozen=True, kw_only=True)
class Run:
    """One tank observed (or simulated) over time (keyword-only construction).

    Fields:
        name: run name; also the file stem (``NAME.json``/``NAME.csv``), so letters, digits, ``_.+-``.
        fluid: CoolProp fluid (normalised to the canonical name, e.g. ``ParaHydrogen``).
        source: free text: where the data comes from.
        tank: :class:`TankSpec`.
        initial: :class:`InitialState` at the start ``t0_s``.
        noise_std: sensor standard deviations (measurement covariance R) by :data:`NOISE_KEYS`
            key, in the channel's unit (Pa, K, m); required for every measured channel.
        duration_s: length of the run [s]; None = up to the last time stamp. The run never ends
            before its last time stamp (``t_end_s``, ``notes``).
        observations: :class:`Observations` (default: none).
        inputs: :class:`Schedule`; None = all inputs 0 from the first observation (or t = 0).
        path: the JSON file it was read from, if any (not part of equality).
    """

    name: str
    fluid: str
    source: str = ""
    tank: TankSpec
    initial: InitialState
    noise_std: Mapping[str, float] = field(default_factory=dict)
    duration_s: float | None = None
    observations: Observations = field(default_factory=Observations.empty)
    inputs: Schedule | None = None
    path: str | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not _NAME_RE.match(self.name):
            raise RunValueError("name", f"{self.name!r} must be a non-empty file stem of letters, digits and _.+-")
        object.__setattr__(self, "fluid", canonical_fluid(self.fluid))
        if not isinstance(self.source, str):
            raise RunValueError("source", f"must be a string, got {type(self.source).__name__}")
        if not isinstance(self.tank, TankSpec):
            raise RunValueError("tank", f"must be a TankSpec, got {type(self.tank).__name__}")
        if not isinstance(self.initial, InitialState):
            raise RunValueError("initial", f"must be an InitialState, got {type(self.initial).__name__}")
        _check_initial_for_fluid(self.initial, self.fluid)
        object.__setattr__(self, "noise_std", _check_noise_std(self.noise_std))
        if not isinstance(self.observations, Observations):
            raise RunValueError("observations", f"must be Observations, got {type(self.observations).__name__}")
        obs = self.observations
        _check_columns_plausible("observations", OBS_CHANNELS, obs.t_s, obs.values, self.fluid)
        level = obs.values[:, OBS_CHANNELS.index("H_l_m")]
        if np.isfinite(level).any():
            height = float(self.tank.geometry().height_m)
            # Generous: a level gauge may read from a datum of its own a little below the tank.
            limit = LEVEL_ABOVE_TANK * height + 5 * float(self.noise_std.get(_NOISE_OF["H_l_m"], 0.0))
            above = np.nan_to_num(level, nan=-np.inf) > limit
            if above.any():
                k = int(np.argmax(above))
                raise RunValueError("observations.H_l_m",
                                    f"at t = {float(obs.t_s[k])!r} s: the level {float(level[k])!r} m lies above "
                                    f"{LEVEL_ABOVE_TANK:g} times the tank's inner height {height:.4g} m (a level in "
                                    "another unit, or another tank's geometry?)", t_s=float(obs.t_s[k]))
        for ch in obs.measured_channels:
            if _NOISE_OF[ch] not in self.noise_std:
                raise RunValueError(
                    f"noise_std.{_NOISE_OF[ch]}",
                    f"missing: channel '{ch}' is measured, so noise_std needs '{_NOISE_OF[ch]}' (its R entry)",
                )
        if self.inputs is None:
            t0 = float(obs.t_s[0]) if len(obs) else 0.0
            object.__setattr__(self, "inputs", Schedule.constant(t0))
        if not isinstance(self.inputs, Schedule):
            raise RunValueError("inputs", f"must be a Schedule, got {type(self.inputs).__name__}")
        sched = self.inputs
        _check_columns_plausible("inputs", INPUT_NAMES, sched.t_s, sched.values, self.fluid)
        amplitude = sched.values[:, INPUT_NAMES.index("slosh_amplitude_m")]
        too_wide = amplitude >= self.tank.dims["radius_m"]
        if too_wide.any():
            k = int(np.argmax(too_wide))
            raise RunValueError("inputs.slosh_amplitude_m",
                                f"at t = {float(sched.t_s[k])!r} s: {float(amplitude[k])!r} m is not smaller than the tank "
                                f"radius {self.tank.dims['radius_m']!r} m; the sloshing excitation's amplitude A0 is a "
                                "lateral displacement of the tank, small against its size (is it in mm?)",
                                t_s=float(sched.t_s[k]))
        t0 = sched.t0_s
        if len(obs) and obs.t_s[0] < t0:
            raise RunValueError(
                "observations.t_s",
                f"first sample t = {float(obs.t_s[0])!r} s is before the start of the inputs "
                f"(inputs.t_s[0] = {t0!r} s, the start of the run)",
            )
        last = self._last_time_stamp()
        if last - t0 > MAX_SPAN_S:
            raise RunValueError("t_s", f"t = {last!r} s lies {last - t0:.3g} s after the start, beyond {_span_limit()}",
                                t_s=last)
        if self.duration_s is None:
            if last <= t0:
                raise RunValueError("duration_s", "missing, and there is no time stamp after the start to default it to")
            object.__setattr__(self, "duration_s", last - t0)
        else:
            d = _as_float("duration_s", self.duration_s)
            if d <= 0:
                raise RunValueError("duration_s", f"duration_s = {d!r} must be > 0")
            if d > MAX_SPAN_S:
                raise RunValueError("duration_s", f"duration_s = {d!r} s is beyond {_span_limit()}")
            object.__setattr__(self, "duration_s", d)  # a shorter one than the data: see notes()
        if self.path is not None:
            object.__setattr__(self, "path", str(self.path))

    def _last_time_stamp(self) -> float:
        t = [self.inputs.t0_s]
        if len(self.observations):
            t.append(float(self.observations.t_s[-1]))
        ch = self.inputs.change_times()
        if ch.size:
            t.append(float(ch[-1]))
        return max(t)

    @property
    def t0_s(self) -> float:
        """Start of the run [s] (the first time stamp; the initial state holds here)."""
        return self.inputs.t0_s

    @property
    def t_end_s(self) -> float:
        """End of the run [s]: ``t0_s + duration_s`` (never before the last time stamp)."""
        return max(self.t0_s + self.duration_s, self._last_time_stamp())

    @property
    def noise_std_array(self) -> np.ndarray:
        """(5,) sensor standard deviations in :data:`OBS_CHANNELS` order; NaN where not given."""
        return np.array([self.noise_std.get(k, np.nan) for k in NOISE_KEYS])

    def replace(self, **changes: Any) -> "Run":
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)

    def notes(self) -> tuple[str, ...]:
        """What the run's own fields contradict and how tankode reads it: one sentence each.

        A ``duration_s`` that ends before the last time stamp (digitised data) does not drop
        the samples after it: the run ends at its last time stamp (``t_end_s``).
        """
        last = self._last_time_stamp()
        if self.t0_s + self.duration_s < last:
            return (f"{self.name}: duration_s = {self.duration_s:g} s ends before the last time stamp "
                    f"t = {last:g} s; the run is taken to end there, no sample is dropped",)
        return ()

    def initial_disagreements(self, n_sigma: float = 5.0) -> tuple[str, ...]:
        """Where the samples taken at the start contradict ``initial``: one sentence per channel.

        A channel measured at exactly ``t0_s`` whose value differs from the metadata's initial
        value by more than ``n_sigma`` of its ``noise_std`` (the level is not compared: the
        metadata give a fill ratio). The data format says ``initial`` is the state at the first
        time stamp, so such a run contradicts itself; tankode starts from the metadata unless
        asked otherwise (:meth:`with_measured_initial`, ``--initial measured``).
        """
        out = []
        for ch, measured in self._samples_at_start().items():
            meta = self.initial.T_w0_K if ch == "T_w_K" else getattr(self.initial, ch)
            sigma = self.noise_std[_NOISE_OF[ch]]
            if abs(measured - meta) > n_sigma * sigma:
                where = f"{Path(self.path).with_suffix('.csv').name}, first row" if self.path else "first sample"
                out.append(f"{self.name}: initial.{ch} = {meta:g} but {ch} = {measured:g} was measured at "
                           f"t = {self.t0_s:g} s ({where}), {abs(measured - meta) / sigma:.0f} sigma apart")
        return tuple(out)

    def with_measured_initial(self) -> "Run":
        """A copy whose initial p_v, T_v, T_l (and T_w) are the samples measured at ``t0_s``, where measured.

        The fill ratio stays the metadata's. For runs whose metadata contradict their own first
        samples (:meth:`initial_disagreements`), e.g. MHTB P263968K, whose ullage reads 24.84 K
        at t = 0 against 21.01 K in its metadata.
        """
        changes = self._samples_at_start()
        return self.replace(initial=dataclasses.replace(self.initial, **changes)) if changes else self

    def _samples_at_start(self) -> dict[str, float]:
        """The initial state's channels (p_v, T_v, T_l, T_w) measured at exactly ``t0_s``, by name."""
        obs = self.observations
        if not len(obs) or obs.t_s[0] != self.t0_s:
            return {}
        cols = {ch: OBS_CHANNELS.index(ch) for ch in ("p_v_Pa", "T_v_K", "T_l_K", "T_w_K")}
        return {ch: float(obs.values[0, i]) for ch, i in cols.items() if obs.mask[0, i]}

    def until(self, t_end_s: float) -> "Run":
        """The run cut at ``t_end_s`` [s]: observations up to it, inputs changing before it.

        For training parts, held-out splits and quick studies; ``t_end_s`` must lie inside the run.
        """
        t_end_s = float(t_end_s)
        if not self.t0_s < t_end_s <= self.t_end_s:
            raise RunValueError("t_end_s", f"must lie in ({self.t0_s!r}, {self.t_end_s!r}] s, got {t_end_s!r}")
        obs = self.observations
        keep = obs.t_s <= t_end_s
        inputs = self.inputs
        if inputs is not None:
            rows = inputs.t_s < t_end_s
            inputs = Schedule(inputs.t_s[rows], inputs.values[rows])
        return self.replace(observations=Observations(obs.t_s[keep], obs.values[keep]), inputs=inputs,
                            duration_s=t_end_s - self.t0_s)


def _check_columns_plausible(prefix: str, names, t_s: np.ndarray, values: np.ndarray, fluid: str) -> None:
    """Raise RunValueError at the first value of any column that is implausible for the fluid."""
    for j, name in enumerate(names):
        k = _first_implausible(name, values[:, j], fluid)
        if k is not None:
            problem = _plausibility_problem(name, float(values[k, j]), fluid)
            raise RunValueError(f"{prefix}.{name}", f"at t = {float(t_s[k])!r} s: {problem}")


def _span_limit() -> str:
    return f"{MAX_SPAN_S:.0e} s ({MAX_SPAN_S / 3.156e7:.0f} years): not a tank's run (check the time unit)"


@lru_cache(maxsize=None)
def _critical_point(fluid: str) -> tuple[float, float]:
    """(T_crit [K], p_crit [Pa]) of the fluid (CoolProp)."""
    import CoolProp.CoolProp as CP

    return float(CP.PropsSI("Tcrit", fluid)), float(CP.PropsSI("pcrit", fluid))


def _check_initial_for_fluid(initial: InitialState, fluid: str) -> None:
    for name in ("p_v_Pa", "T_v_K", "T_l_K", "T_w_K"):
        v = getattr(initial, name)
        if v is not None:
            problem = _plausibility_problem(name, v, fluid)
            if problem:
                raise RunValueError(f"initial.{name}", problem)
    # A tank holds liquid under its vapour: both exist only below the critical point.
    T_c, p_c = _critical_point(fluid)
    if initial.p_v_Pa >= p_c:
        raise RunValueError("initial.p_v_Pa", f"{_g(initial.p_v_Pa)} Pa is above the critical pressure {p_c:.6g} Pa "
                                              f"of {fluid}: liquid and vapour do not coexist there")
    if initial.T_l_K >= T_c:
        raise RunValueError("initial.T_l_K", f"{_g(initial.T_l_K)} K is above the critical temperature {T_c:.4g} K "
                                             f"of {fluid}: there is no liquid")


def _check_noise_std(noise: Any) -> dict[str, float]:
    if not isinstance(noise, Mapping):
        raise RunValueError("noise_std", f"must be an object of sensor standard deviations, got {type(noise).__name__}")
    out = {}
    for k in noise:
        if k not in NOISE_KEYS:
            close = difflib.get_close_matches(str(k), NOISE_KEYS, n=1, cutoff=0.5)
            hint = f" (did you mean '{close[0]}'?)" if close else ""
            raise RunValueError(f"noise_std.{k}", f"unknown sensor{hint}; known: {', '.join(NOISE_KEYS)}")
    for k in NOISE_KEYS:
        if k in noise:
            v = _as_float(f"noise_std.{k}", noise[k])
            if v <= 0:
                raise RunValueError(f"noise_std.{k}", f"{k} = {v!r} must be > 0 (it is a standard deviation in {_CHANNEL_OF[k].rsplit('_', 1)[1]})")
            out[k] = v
    return out
