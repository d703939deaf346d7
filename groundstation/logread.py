"""Reading a flight log folder written by the ground station (`--log DIR`) into numpy arrays.

Takes in: a log folder holding states.csv (required: one row per control tick, header first, empty
cell = unknown), summary.json (optional: the flight's summary object) and plan.json (optional: only
for planned world flights). Column names and meanings are those of STATE_COLUMNS (world ENU, SI units,
quaternions w, x, y, z rotating body FLU -> world ENU).
Gives out: a `FlightLog` (numeric columns as float arrays with NaN for unknown cells, the phase words,
the summary dict, a `Plan`), or a one-line UserError naming the file and the problem.

A ground station that is killed mid-write can leave the last row of states.csv cut short; that row is
dropped with a warning in `FlightLog.warnings` instead of failing the whole log.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from groundstation.flightlog import MOTOR_COLUMNS, MOTORS_FILE
from model.errors import UserError

STATES_FILE = "states.csv"
SUMMARY_FILE = "summary.json"
PLAN_FILE = "plan.json"

# Exactly the columns the ground station writes, in its order (see notes/logformat.md).
STATE_COLUMNS: tuple[str, ...] = (
    "t_s", "phase",
    "truth_x_m", "truth_y_m", "truth_z_m", "truth_vx_mps", "truth_vy_mps", "truth_vz_mps",
    "truth_qw", "truth_qx", "truth_qy", "truth_qz",
    "est_x_m", "est_y_m", "est_z_m", "est_vx_mps", "est_vy_mps", "est_vz_mps",
    "est_qw", "est_qx", "est_qy", "est_qz",
    "est_sigma_x_m", "est_sigma_y_m", "est_sigma_z_m", "est_sigma_vx_mps", "est_sigma_vy_mps",
    "est_sigma_vz_mps", "est_sigma_roll_rad", "est_sigma_pitch_rad", "est_sigma_yaw_rad",
    "ref_x_m", "ref_y_m", "ref_z_m", "ref_vx_mps", "ref_vy_mps", "ref_vz_mps",
    "cmd_thrust_n", "cmd_mx_nm", "cmd_my_nm", "cmd_mz_nm", "cmd_qw", "cmd_qx", "cmd_qy", "cmd_qz",
    "cmd_saturated",
    "mocap_age_s", "est_healthy", "uplink_sent", "downlink_received", "downlink_lost", "rtt_ms",
    "tick_time_ms",
)
# Written by newer ground stations; NaN when a log predates them.
OPTIONAL_COLUMNS: tuple[str, ...] = ("est_time_s", "truth_time_s", "battery_v")
TEXT_COLUMNS = frozenset({"phase"})
NUMERIC_COLUMNS: tuple[str, ...] = tuple(c for c in STATE_COLUMNS if c not in TEXT_COLUMNS)


@dataclass(frozen=True)
class Plan:
    """plan.json: the planned world flight. Points are (N, 3) arrays in metres, world ENU."""

    world_path: Path  # resolved: as written if it exists, else relative to the log folder
    path_m: np.ndarray  # (N, 3) A* path
    waypoints_m: np.ndarray  # (M, 3) points the trajectory passes through
    trajectory: str
    resolution_m: np.ndarray | None
    margin_m: float | None
    source: str


@dataclass(frozen=True)
class FlightLog:
    folder: Path
    t_s: np.ndarray  # (N,) s
    phase: np.ndarray  # (N,) str, one phase word per tick ("" when unknown)
    columns: dict[str, np.ndarray]  # every NUMERIC_COLUMNS name -> (N,) float, NaN = unknown
    summary: dict | None = None
    plan: Plan | None = None
    warnings: tuple[str, ...] = field(default_factory=tuple)
    motors: np.ndarray | None = None  # motors.csv, (K, 6): t_s, vehicle_time_s, m1..m4 duty; None without it

    def __len__(self) -> int:
        return len(self.t_s)

    def vec(self, *names: str) -> np.ndarray:
        """Columns stacked side by side, (N, len(names)); e.g. vec("ref_x_m", "ref_y_m", "ref_z_m")."""
        return np.column_stack([self.columns[n] for n in names])

    def position_m(self, source: str) -> np.ndarray:
        """(N, 3) position of `source` in "truth" | "est" | "ref"."""
        return self.vec(f"{source}_x_m", f"{source}_y_m", f"{source}_z_m")

    def velocity_mps(self, source: str) -> np.ndarray:
        """(N, 3) velocity of `source` in "truth" | "est" | "ref"."""
        return self.vec(f"{source}_vx_mps", f"{source}_vy_mps", f"{source}_vz_mps")

    def has(self, *names: str) -> bool:
        """True when every named column has at least one known value."""
        return all(np.isfinite(self.columns[n]).any() for n in names)

    @property
    def has_truth(self) -> bool:
        """Simulation logs carry ground truth; real-vehicle logs leave truth_* empty."""
        return self.has("truth_x_m", "truth_y_m", "truth_z_m")


def read_log(folder: str | Path) -> FlightLog:
    """Read a whole log folder; states.csv is required, summary.json and plan.json are optional."""
    folder = Path(folder)
    if not folder.exists():
        raise UserError(f"{folder}: log folder not found")
    if not folder.is_dir():
        raise UserError(f"{folder}: not a folder (expected a flight log folder holding {STATES_FILE})")
    states_path = folder / STATES_FILE
    if not states_path.is_file():
        raise UserError(f"{states_path}: not found (is {folder} a flight log folder?)")
    t_s, phase, columns, warnings = read_states(states_path)
    summary_path, plan_path = folder / SUMMARY_FILE, folder / PLAN_FILE
    summary = read_summary(summary_path) if summary_path.exists() else None
    plan = read_plan(plan_path) if plan_path.exists() else None
    motors_path = folder / MOTORS_FILE
    motors = read_motors(motors_path) if motors_path.exists() else None
    return FlightLog(folder=folder, t_s=t_s, phase=phase, columns=columns, summary=summary, plan=plan,
                     warnings=tuple(warnings), motors=motors)


def read_motors(path: str | Path) -> np.ndarray:
    """motors.csv -> (K, 6) floats in MOTOR_COLUMNS order; a malformed file is one line naming it."""
    path = Path(path)
    lines = _read_text(path).splitlines()
    header = [h.strip() for h in lines[0].split(",")] if lines else []
    if tuple(header) != MOTOR_COLUMNS:
        raise UserError(f"{path}: header is not {','.join(MOTOR_COLUMNS)}")
    body = [line for line in lines[1:] if line.strip()]
    rows = []
    for number, line in enumerate(body, start=2):
        cells = line.split(",")
        try:
            if len(cells) != len(MOTOR_COLUMNS):
                raise ValueError(f"{len(cells)} cells, expected {len(MOTOR_COLUMNS)}")
            rows.append([float(cell) for cell in cells])
        except ValueError as err:
            if number == len(body) + 1:  # the last line of a killed flight may be cut short: dropped
                break
            raise UserError(f"{path}: line {number}: {err}") from None
    return np.array(rows, dtype=float).reshape(-1, len(MOTOR_COLUMNS))


def read_states(path: str | Path) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray], list[str]]:
    """states.csv -> (t_s (N,), phase (N,) str, {column: (N,) float, NaN = empty}, warnings).

    Columns are found by header name, so extra columns a newer writer adds are ignored.
    """
    path = Path(path)
    text = _read_text(path)
    lines = text.splitlines()
    if not lines or not lines[0].strip():
        raise UserError(f"{path}: empty file (expected a header row)")
    header = [h.strip() for h in next(csv.reader([lines[0]]))]
    index = _column_index(header, path)
    rows = list(csv.reader(lines[1:]))
    warnings: list[str] = []
    if rows and _last_row_cut_short(text, rows[-1], len(header)):
        warnings.append(f"{path}: line {len(lines)} is cut short (ground station stopped mid-write); dropped")
        rows.pop()
    for i, row in enumerate(rows):
        if len(row) != len(header):
            raise UserError(f"{path}: line {i + 2} has {len(row)} cells, header has {len(header)}")
    if not rows:
        raise UserError(f"{path}: no data rows after the header")
    table = np.array(rows, dtype=str)
    columns = {name: _numeric_column(table[:, index[name]], name, path) for name in NUMERIC_COLUMNS}
    for name in OPTIONAL_COLUMNS:
        where = header.index(name) if name in header else None
        columns[name] = (np.full(len(rows), np.nan) if where is None
                         else _numeric_column(table[:, where], name, path))
    t_s = columns.pop("t_s")
    if not np.isfinite(t_s).all():
        bad = int(np.flatnonzero(~np.isfinite(t_s))[0])
        raise UserError(f"{path}: line {bad + 2}: t_s is empty or not finite")
    phase = np.char.strip(table[:, index["phase"]])
    return t_s, phase, columns, warnings


def read_summary(path: str | Path) -> dict:
    """summary.json -> dict; the object is passed on as written (the writer owns its fields)."""
    data = _read_json(Path(path))
    if not isinstance(data, dict):
        raise UserError(f"{path}: expected a JSON object, got {type(data).__name__}")
    return data


def read_plan(path: str | Path) -> Plan:
    """plan.json -> Plan; a relative world path that does not exist from here is tried beside the log."""
    path = Path(path)
    data = _read_json(path)
    if not isinstance(data, dict):
        raise UserError(f"{path}: expected a JSON object, got {type(data).__name__}")
    world = data.get("world")
    if not isinstance(world, str) or not world:
        raise UserError(f"{path}: world: expected the path of the world file")
    world_path = Path(world)
    if not world_path.is_absolute() and not world_path.exists() and (path.parent / world_path).exists():
        world_path = path.parent / world_path
    resolution = data.get("resolution")
    margin = data.get("margin")
    return Plan(
        world_path=world_path,
        path_m=_points(data.get("path", []), "path", path),
        waypoints_m=_points(data.get("waypoints", []), "waypoints", path),
        trajectory=str(data.get("trajectory", "")),
        resolution_m=None if resolution is None else _numbers(resolution, "resolution", path),
        margin_m=None if margin is None else float(_numbers([margin], "margin", path)[0]),
        source=str(path),
    )


def _read_text(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise UserError(f"{path}: not a UTF-8 text file") from None
    except OSError as err:
        raise UserError(f"{path}: cannot read ({err.strerror})") from None


def _read_json(path: Path) -> object:
    text = _read_text(path)
    try:
        return json.loads(text)
    except json.JSONDecodeError as err:
        where = f"line {err.lineno} column {err.colno}"
        raise UserError(f"{path}: not valid JSON ({err.msg} at {where})") from None


def _column_index(header: list[str], path: Path) -> dict[str, int]:
    missing = [c for c in STATE_COLUMNS if c not in header]
    if missing:
        shown = ", ".join(missing[:5]) + (f" and {len(missing) - 5} more" if len(missing) > 5 else "")
        raise UserError(f"{path}: header lacks column(s) {shown}")
    return {name: header.index(name) for name in STATE_COLUMNS}


def _last_row_cut_short(text: str, last_row: list[str], n_cells: int) -> bool:
    # The writer ends every row with a newline, so a missing final newline means the write was cut.
    return not text.endswith(("\n", "\r")) or len(last_row) < n_cells


def _numeric_column(cells: np.ndarray, name: str, path: Path) -> np.ndarray:
    """Strings -> float with '' -> NaN; one-line error naming the first bad cell."""
    cleaned = np.char.strip(cells)
    cleaned = np.where(cleaned == "", "nan", cleaned)
    try:
        return cleaned.astype(float)
    except ValueError:
        for i, cell in enumerate(cleaned):
            try:
                float(cell)
            except ValueError:
                raise UserError(f"{path}: line {i + 2}: {name}: not a number ({cell[:30]!r})") from None
        raise  # unreachable: astype failed, so some cell fails float() too


def _numbers(value: object, where: str, path: Path) -> np.ndarray:
    values = value if isinstance(value, list) else [value]
    out = []
    for v in values:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or math.isnan(v):
            raise UserError(f"{path}: {where}: expected numbers, got {json.dumps(v)[:40]}")
        out.append(float(v))
    return np.array(out)


def _points(value: object, where: str, path: Path) -> np.ndarray:
    """A JSON list of [x, y, z] -> (N, 3) float array."""
    if not isinstance(value, list) or any(not isinstance(p, list) or len(p) != 3 for p in value):
        raise UserError(f"{path}: {where}: expected a list of [x, y, z] points")
    return _numbers([c for p in value for c in p], where, path).reshape(-1, 3)
