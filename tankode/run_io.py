"""Reading and writing runs as files: ``NAME.json`` + ``NAME.csv`` (``../shared/data-format.md``).

``read_run`` parses and validates both files and turns every problem into a
:class:`~tankode.run.RunFormatError` that names the file, the line and the column (CSV) or key
(JSON); ``write_run`` writes a :class:`~tankode.run.Run` so that reading it back gives an equal
run. The decisions this module takes beyond the format document (time origin, empty and
non-finite cells, what is written) are listed in ``tankode.run``'s docstring; the run itself,
and its validation in code, live there.
"""

from __future__ import annotations

import csv
import difflib
import io
import json
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .run import (
    _JSON_TANK_OPTIONAL,
    _NOISE_OF,
    NOISE_KEYS,
    OBS_CHANNELS,
    TANK_SHAPES,
    InitialState,
    Observations,
    Run,
    RunFormatError,
    RunValueError,
    TankSpec,
    _as_float,
    _check_initial_for_fluid,
    _check_noise_std,
    _g,
    _plausibility_problem,
    canonical_fluid,
)
from .files import OutputError
from .schedule import INPUT_NAMES, Schedule, ScheduleError, input_value_problem

__all__ = ["read_run", "write_run", "read_timeseries_csv", "timeseries_path"]

_JSON_TOP_REQUIRED = ("name", "fluid", "tank", "initial", "timeseries")
_JSON_TOP_OPTIONAL = ("source", "noise_std", "duration_s")
_JSON_INITIAL_REQUIRED = ("p_v_Pa", "T_v_K", "T_l_K", "fill_ratio")
_JSON_INITIAL_OPTIONAL = ("T_w_K",)


# ===================================================================== JSON helpers
class _DuplicateKey(Exception):
    def __init__(self, key: str):
        self.key = key


def _no_duplicates(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    d: dict[str, Any] = {}
    for k, v in pairs:
        if k in d:
            raise _DuplicateKey(k)
        d[k] = v
    return d


class _BadConstant(Exception):
    def __init__(self, token: str):
        self.token = token


def _reject_constant(token: str):
    raise _BadConstant(token)


def _key_pattern(key: str) -> re.Pattern:
    return re.compile(r'"' + re.escape(key) + r'"\s*:')


def _locate(text: str, keypath: str, occurrence: int = 0) -> int | None:
    """1-based line of ``keypath`` (dotted) in JSON ``text``; the deepest located parent if absent."""
    pos, line = 0, None
    parts = keypath.split(".") if keypath else []
    for i, part in enumerate(parts):
        matches = list(_key_pattern(part).finditer(text, pos))
        idx = occurrence if i == len(parts) - 1 else 0
        if len(matches) <= idx:
            break
        m = matches[idx]
        pos = m.end()
        line = text.count("\n", 0, m.start()) + 1
    return line if line is not None else (1 if text else None)


class _JsonCtx:
    """A JSON file being read: its path and text, to turn key paths into lines."""

    def __init__(self, path: Path, text: str):
        self.path = path
        self.text = text

    def error(self, key: str, detail: str, occurrence: int = 0) -> RunFormatError:
        return RunFormatError(self.path, _locate(self.text, key, occurrence), key, detail, what="key")

    def from_field(self, e: RunValueError) -> RunFormatError:
        return self.error(e.key, e.detail)

    def check_keys(self, obj: Mapping, prefix: str, required: tuple, optional: tuple) -> None:
        known = required + optional
        for k in obj:
            if k not in known:
                close = difflib.get_close_matches(k, known, n=1, cutoff=0.5)
                hint = f" (did you mean '{close[0]}'?)" if close else ""
                raise self.error(f"{prefix}{k}", f"unknown key{hint}; known keys here: {', '.join(known)}")
        for k in required:
            if k not in obj:
                raise self.error(f"{prefix}{k}", f"missing required key (the object {prefix.rstrip('.') or 'at the top level'} needs {', '.join(required)})")

    def object(self, value: Any, key: str) -> Mapping:
        if not isinstance(value, dict):
            raise self.error(key, f"must be a JSON object, got {_json_type(value)}")
        return value

    def string(self, value: Any, key: str) -> str:
        if not isinstance(value, str):
            raise self.error(key, f"must be a string, got {_json_type(value)}")
        return value


def _json_type(v: Any) -> str:
    if v is None:
        return "null"
    if isinstance(v, bool):
        return "a boolean"
    if isinstance(v, (int, float)):
        return f"the number {v!r}"
    if isinstance(v, str):
        return f"the string {v!r}"
    if isinstance(v, list):
        return "an array"
    return "an object"


def _read_text(path: Path) -> str:
    """The file's text (UTF-8, a byte-order mark allowed); bytes that are not UTF-8 are a format
    error naming their line and column."""
    raw = path.read_bytes()
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        line = raw.count(b"\n", 0, e.start) + 1
        column = e.start - (raw.rfind(b"\n", 0, e.start) + 1) + 1
        raise RunFormatError(path, line, column, f"byte 0x{raw[e.start]:02x} is not UTF-8 text (the format's "
                                                 f"encoding): save the file as UTF-8") from None


def _load_json(path: Path) -> tuple[Any, _JsonCtx]:
    text = _read_text(path)
    ctx = _JsonCtx(path, text)
    try:
        data = json.loads(text, object_pairs_hook=_no_duplicates, parse_constant=_reject_constant)
    except json.JSONDecodeError as e:
        raise RunFormatError(path, e.lineno, e.colno, f"JSON syntax error: {e.msg}") from None
    except _DuplicateKey as e:
        raise RunFormatError(
            path, _locate(text, e.key, occurrence=1), e.key,
            "duplicate key (the second value would silently replace the first)", what="key",
        ) from None
    except _BadConstant as e:
        m = re.search(re.escape(e.token), text)
        line = text.count("\n", 0, m.start()) + 1 if m else None
        raise RunFormatError(path, line, None, f"{e.token} is not valid JSON (and not a valid value here)") from None
    return data, ctx


# ===================================================================== CSV
@dataclass
class _CsvData:
    observations: Observations
    schedule: Schedule | None  # None when the CSV has no input column
    t0_s: float
    last_t_s: float
    first_line: dict[str, int]  # observation channel -> line of its first sample
    last_line: int
    input_line: dict[float, int]  # time stamp -> line of a row that sets inputs


def _read_csv(path: Path, fluid: str) -> _CsvData:
    """Read and validate a time-series CSV, every error naming the line and the column."""
    known = OBS_CHANNELS + INPUT_NAMES
    with io.StringIO(_read_text(path), newline="") as fh:
        reader = csv.reader(fh)
        header = next(reader, None)
        if header is None:
            raise RunFormatError(path, 1, None, "empty file: expected a header line starting with 't_s'")
        header = [h.strip() for h in header]
        if not header or header[0] != "t_s":
            if "t_s" in header:
                raise RunFormatError(path, 1, "t_s", f"'t_s' must be the first column, it is column {header.index('t_s') + 1}")
            first = header[0] if header else ""
            raise RunFormatError(path, 1, first, "the first column must be 't_s' (time in seconds)")
        seen: dict[str, int] = {}
        for i, name in enumerate(header):
            if not name:
                raise RunFormatError(path, 1, None, f"column {i + 1} has an empty name")
            if name in seen:
                raise RunFormatError(path, 1, name, f"duplicate column (columns {seen[name] + 1} and {i + 1})")
            seen[name] = i
            if i and name not in known:
                close = difflib.get_close_matches(name, known, n=1, cutoff=0.5)
                hint = f" (did you mean '{close[0]}'? names carry their SI unit)" if close else ""
                raise RunFormatError(
                    path, 1, name,
                    f"unknown column{hint}; known columns: t_s, {', '.join(known)}",
                )
        obs_cols = [(i, OBS_CHANNELS.index(h)) for i, h in enumerate(header) if h in OBS_CHANNELS]
        in_cols = [(i, INPUT_NAMES.index(h)) for i, h in enumerate(header) if h in INPUT_NAMES]

        times: list[float] = []
        obs_t: list[float] = []
        obs_v: list[np.ndarray] = []
        sch_t: list[float] = []
        sch_v: list[np.ndarray] = []
        sch_line: dict[float, int] = {}
        first_line: dict[str, int] = {}
        current = np.zeros(len(INPUT_NAMES))
        prev_t, prev_line = None, None
        line = 1
        for row in reader:
            line = reader.line_num
            if not row:  # a blank line carries nothing
                continue
            if len(row) != len(header):
                raise RunFormatError(
                    path, line, None,
                    f"row has {len(row)} cells but the header has {len(header)} columns",
                )
            t = _parse_cell(path, line, "t_s", row[0])
            if t is None or not math.isfinite(t):
                raise RunFormatError(path, line, "t_s", f"time must be a finite number, got {row[0].strip()!r}")
            if prev_t is not None and t <= prev_t:
                raise RunFormatError(
                    path, line, "t_s",
                    f"t_s = {_g(t)} is not after the previous time stamp {_g(prev_t)} (line {prev_line}); "
                    "time must be strictly increasing",
                )
            prev_t, prev_line = t, line
            times.append(t)

            ov = np.full(len(OBS_CHANNELS), np.nan)
            for i, j in obs_cols:
                v = _parse_cell(path, line, header[i], row[i])
                if v is None or math.isnan(v):
                    continue
                if math.isinf(v):
                    raise RunFormatError(path, line, header[i], f"value {row[i].strip()!r} is not finite")
                problem = _plausibility_problem(header[i], v, fluid)
                if problem:
                    raise RunFormatError(path, line, header[i], problem)
                ov[j] = v
                first_line.setdefault(header[i], line)
            if not np.isnan(ov).all():
                obs_t.append(t)
                obs_v.append(ov)

            changed = len(times) == 1  # the first row always starts the schedule
            for i, j in in_cols:
                v = _parse_cell(path, line, header[i], row[i])
                if v is None:
                    continue  # empty: unchanged
                problem = input_value_problem(header[i], v) or _plausibility_problem(header[i], v, fluid)
                if problem:
                    raise RunFormatError(path, line, header[i], problem)
                current[j] = v
                changed = True
            if in_cols and changed:
                sch_t.append(t)
                sch_v.append(current.copy())
                sch_line[t] = line

    if not times:
        raise RunFormatError(path, 2, None, "no data rows after the header")
    schedule = None
    if in_cols:
        try:
            schedule = Schedule(np.array(sch_t), np.array(sch_v)).compressed()
        except ScheduleError as e:
            raise RunFormatError(path, sch_line.get(e.t_s), e.name, e.reason) from None
    observations = Observations(
        np.array(obs_t), np.array(obs_v) if obs_v else np.zeros((0, len(OBS_CHANNELS)))
    )
    return _CsvData(observations, schedule, times[0], times[-1], first_line, line, sch_line)


def _parse_cell(path: Path, line: int, column: str, cell: str) -> float | None:
    """Float value of a CSV cell; None when empty."""
    s = cell.strip()
    if not s:
        return None
    try:
        return float(s)
    except ValueError:
        raise RunFormatError(path, line, column, f"value {s!r} is not a number") from None


def read_timeseries_csv(path, fluid: str = "ParaHydrogen") -> tuple[Observations, Schedule | None]:
    """Read a time-series CSV without its JSON (e.g. a peer model's ``NAME.ebm.csv``).

    Validated like the CSV of a run (plausibility for ``fluid``). Returns the observations and
    the input schedule, or None for the schedule when the file has no input column.
    """
    data = _read_csv(Path(path), canonical_fluid(fluid))
    return data.observations, data.schedule


# ===================================================================== read / write
def read_run(path) -> Run:
    """Read and validate ``NAME.json`` and the CSV it names (relative to the JSON)."""
    path = Path(path)
    data, ctx = _load_json(path)
    if not isinstance(data, dict):
        raise RunFormatError(path, 1, None, f"the top level must be a JSON object, got {_json_type(data)}")
    ctx.check_keys(data, "", _JSON_TOP_REQUIRED, _JSON_TOP_OPTIONAL)

    name = ctx.string(data["name"], "name")
    try:
        fluid = canonical_fluid(ctx.string(data["fluid"], "fluid"))
    except RunValueError as e:
        raise ctx.from_field(e) from None
    source = ctx.string(data.get("source", ""), "source")

    tank_d = ctx.object(data["tank"], "tank")
    if "shape" not in tank_d:
        raise ctx.error("tank.shape", f"missing required key (one of {', '.join(TANK_SHAPES)})")
    shape = ctx.string(tank_d["shape"], "tank.shape")
    if shape in TANK_SHAPES:
        ctx.check_keys(tank_d, "tank.", ("shape",) + TANK_SHAPES[shape], _JSON_TANK_OPTIONAL)
    try:
        tank = TankSpec.from_dict(tank_d)
    except RunValueError as e:
        raise ctx.from_field(e) from None

    init_d = ctx.object(data["initial"], "initial")
    ctx.check_keys(init_d, "initial.", _JSON_INITIAL_REQUIRED, _JSON_INITIAL_OPTIONAL)
    for k in _JSON_INITIAL_REQUIRED[:3] + _JSON_INITIAL_OPTIONAL:
        v = init_d.get(k)
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            problem = _plausibility_problem(k, float(v), fluid)  # word it with the fluid first
            if problem:
                raise ctx.error(f"initial.{k}", problem)
    try:
        initial = InitialState(**init_d)
        _check_initial_for_fluid(initial, fluid)
        noise_std = _check_noise_std(data.get("noise_std", {}))
        duration = _as_float("duration_s", data.get("duration_s"), allow_none=True)
    except RunValueError as e:
        raise ctx.from_field(e) from None
    if duration is not None and duration <= 0:
        raise ctx.error("duration_s", f"duration_s = {duration!r} must be > 0")

    ts_name = ctx.string(data["timeseries"], "timeseries")
    csv_path = path.parent / ts_name
    if not _beside_or_under(csv_path, path.parent):
        raise ctx.error("timeseries", f"{ts_name!r} must lie beside the JSON file or in a folder under it "
                                      f"({path.parent}), not elsewhere on the system")
    if not csv_path.is_file():
        raise ctx.error("timeseries", f"file {str(csv_path)!r} not found (the path is relative to the JSON file)")
    ts = _read_csv(csv_path, fluid)

    # Cross-file checks, naming both files.
    for ch in OBS_CHANNELS:
        if ch in ts.first_line and _NOISE_OF[ch] not in noise_std:
            raise RunFormatError(
                csv_path, ts.first_line[ch], ch,
                f"channel is measured (first at this line) but 'noise_std' in {path} "
                f"(line {_locate(ctx.text, 'noise_std')}) has no '{_NOISE_OF[ch]}' entry; "
                "the measurement covariance R needs it",
            )
    if duration is None:
        duration = ts.last_t_s - ts.t0_s
        if duration <= 0:
            raise ctx.error("duration_s", f"missing, and {csv_path} has a single time stamp to default it from")
    inputs = ts.schedule if ts.schedule is not None else Schedule.constant(ts.t0_s)
    try:
        return Run(
            name=name, fluid=fluid, source=source, tank=tank, initial=initial, noise_std=noise_std,
            duration_s=duration, observations=ts.observations, inputs=inputs, path=str(path),
        )
    except RunValueError as e:  # what needs the whole run (a value against the tank): name its CSV row
        if e.key == "duration_s" and data.get("duration_s") is None:  # defaulted from the CSV's last row
            raise RunFormatError(csv_path, ts.last_line, "t_s", e.detail) from None
        line = None if e.t_s is None else ts.input_line.get(e.t_s) or _line_of_time(csv_path, e.t_s)
        if line is not None:
            raise RunFormatError(csv_path, line, e.key.split(".")[-1], e.detail) from None
        raise ctx.from_field(e) from None


def _line_of_time(csv_path: Path, t_s: float) -> int | None:
    """The line of the CSV row stamped ``t_s`` (an accepted file: one row per time stamp), or None.
    Reads the file again: only an error's message needs it."""
    for line, row in enumerate(csv.reader(io.StringIO(_read_text(csv_path), newline="")), start=1):
        try:
            if line > 1 and row and float(row[0]) == t_s:
                return line
        except ValueError:
            continue
    return None


def _beside_or_under(path: Path, folder: Path) -> bool:
    """Whether ``path`` (links resolved) lies in ``folder`` or below it."""
    return path.resolve().is_relative_to(folder.resolve())


def timeseries_path(json_path) -> Path:
    """The CSV a run's JSON names (``timeseries``, relative to the JSON), for a run ``read_run`` accepted."""
    json_path = Path(json_path)
    return json_path.parent / json.loads(json_path.read_text(encoding="utf-8"))["timeseries"]


def _fmt(x: float) -> str:
    """Shortest repr that reads back to the same float; NaN -> empty cell."""
    x = float(x)
    return "" if math.isnan(x) else repr(x)


def write_run(run: Run, out_dir) -> tuple[Path, Path]:
    """Write ``NAME.json`` and ``NAME.csv`` into ``out_dir`` (created); return their paths.

    Refuses (``tankode.files.OutputError``) to replace the files ``run`` was read from.

    ``read_run`` of the result gives a Run equal to ``run`` (floats are written bit-exact).
    """
    if not isinstance(run, Run):
        raise TypeError(f"write_run needs a Run, got {type(run).__name__}")
    out = Path(out_dir)
    json_path = out / f"{run.name}.json"
    csv_path = out / f"{run.name}.csv"
    if run.path is not None and Path(run.path).is_file():
        sources = {Path(run.path).resolve(), timeseries_path(run.path).resolve()}
        if {json_path.resolve(), csv_path.resolve()} & sources:
            raise OutputError(f"writing run {run.name!r} into {out} would replace the files it was read from "
                              f"({run.path}); choose another directory")
    out.mkdir(parents=True, exist_ok=True)

    obs = run.observations
    sched = run.inputs.compressed()
    obs_cols = [j for j, c in enumerate(OBS_CHANNELS) if c in obs.measured_channels]
    used = sched.used_inputs()
    in_cols = [INPUT_NAMES.index(n) for n in used]
    times = np.union1d(obs.t_s, sched.t_s)
    obs_row = {float(t): k for k, t in enumerate(obs.t_s)}
    in_vals = sched.at(times)

    header = ["t_s"] + [OBS_CHANNELS[j] for j in obs_cols] + list(used)
    lines = [",".join(header)]
    for r, t in enumerate(times):
        cells = [_fmt(t)]
        k = obs_row.get(float(t))
        cells += [_fmt(obs.values[k, j]) if k is not None else "" for j in obs_cols]
        cells += [_fmt(in_vals[r, j]) for j in in_cols]
        lines.append(",".join(cells))
    csv_path.write_text("\n".join(lines) + "\n", encoding="utf-8")

    meta = {
        "name": run.name,
        "fluid": run.fluid,
        "source": run.source,
        "tank": run.tank.to_dict(),
        "initial": run.initial.to_dict(),
        "noise_std": {k: run.noise_std[k] for k in NOISE_KEYS if k in run.noise_std},
        "duration_s": float(run.duration_s),
        "timeseries": csv_path.name,
    }
    json_path.write_text(json.dumps(meta, indent=2) + "\n", encoding="utf-8")
    return json_path, csv_path
