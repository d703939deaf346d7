"""The sweep's result table: one row per flown cell, the CSV it lives in, and what it says.

Takes in: cell results (from the runner) and CSV files of earlier runs (--resume).
Gives out: sweep.csv (CSV_COLUMNS; rewritten atomically after every cell, so a kill leaves a valid file),
the text table per mode, and per mode the largest one-way latency it survives at 0 % and 20 % loss.
"Survives" is conservative: success (goal reached, no collision) in that cell AND in every cell of lower
latency at the same loss, so a lucky cell past a failure does not count.
"""

from __future__ import annotations

import csv
import json
import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from groundstation.sweep.grid import Cell, SweepOptions, _num
from model.errors import UserError

REPORT_LOSSES_PCT = (0.0, 20.0)  # the issue asks for the survived latency at these losses
CSV_COLUMNS = ("mode", "latency_ms", "loss_pct", "success", "result", "reached_goal", "collided", "reason",
               "rms_tracking_error_m", "max_tracking_error_m", "min_clearance_m", "flight_time_s", "wall_time_s",
               "exit_code", "log_dir")
SETTINGS_CHECKED_ON_RESUME = ("world", "seed", "radio_base", "extra", "latency_compensation")


@dataclass
class CellResult:
    cell: Cell
    success: bool  # reached the goal without a collision
    result: str  # fly's result, or "crash" / "timeout" when it gave none
    reached_goal: bool = False
    collided: bool = False
    reason: str | None = None  # fly's failsafe_reason, or the last stderr line of a crash or timeout
    rms_tracking_error_m: float | None = None
    max_tracking_error_m: float | None = None
    min_clearance_m: float | None = None
    flight_time_s: float | None = None
    wall_time_s: float | None = None  # of the whole fly subprocess (emulator start to exit)
    exit_code: int | None = None
    log_dir: str = ""

    def to_row(self) -> dict[str, str]:
        values = {"mode": self.cell.mode, "latency_ms": self.cell.latency_ms, "loss_pct": self.cell.loss_pct,
                  **{k: getattr(self, k) for k in CSV_COLUMNS[3:]}}
        return {k: _csv_text(v) for k, v in values.items()}

    @staticmethod
    def from_row(row: Mapping[str, str], where: str) -> CellResult:
        try:
            cell = Cell(row["mode"], float(row["latency_ms"]), float(row["loss_pct"]))
            return CellResult(
                cell=cell, success=_csv_bool(row["success"]), result=row["result"],
                reached_goal=_csv_bool(row["reached_goal"]), collided=_csv_bool(row["collided"]),
                reason=row["reason"] or None,
                **{k: _csv_float(row[k]) for k in ("rms_tracking_error_m", "max_tracking_error_m", "min_clearance_m",
                                                   "flight_time_s", "wall_time_s")},
                exit_code=int(row["exit_code"]) if row["exit_code"] else None, log_dir=row["log_dir"])
        except (KeyError, ValueError, TypeError) as err:
            raise UserError(f"{where}: malformed row ({err}); remove the file or use another --out") from None


def _csv_text(value) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return _num(value)
    return str(value)


def _csv_bool(text: str) -> bool:
    if text not in ("true", "false"):
        raise ValueError(f"expected true or false, got {text!r}")
    return text == "true"


def _csv_float(text: str) -> float | None:
    return float(text) if text else None


def read_csv(path: Path) -> list[CellResult]:
    if not path.is_file():
        return []
    with path.open(newline="") as f:
        reader = csv.DictReader(f)
        if tuple(reader.fieldnames or ()) != CSV_COLUMNS:
            raise UserError(f"{path}: not a sweep table (columns differ); remove it or use another --out")
        return [CellResult.from_row(row, f"{path}:{i + 2}") for i, row in enumerate(reader)]


def write_csv(path: Path, results: Iterable[CellResult], modes: Sequence[str]) -> None:
    """The whole table, sorted (mode, loss, latency), replaced atomically: a kill leaves a valid file."""
    order = {m: i for i, m in enumerate(modes)}
    rows = sorted(results, key=lambda r: (order.get(r.cell.mode, len(order)), r.cell.mode,
                                          r.cell.loss_pct, r.cell.latency_ms))
    tmp = path.with_suffix(".csv.tmp")
    with tmp.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=CSV_COLUMNS)
        writer.writeheader()
        writer.writerows(r.to_row() for r in rows)
    os.replace(tmp, path)


def largest_survived_latency(outcomes: Mapping[float, bool | None]) -> float | None:
    """The largest latency L with success at L and at every lower latency swept (None: not even the lowest).

    outcomes: latency (ms) -> success (None: not flown, which stops the walk: unknown is not survived).
    """
    survived = None
    for latency in sorted(outcomes):
        if outcomes[latency] is not True:
            break
        survived = latency
    return survived


def outcomes_at(results: Mapping[tuple[str, float, float], CellResult], opts: SweepOptions, mode: str,
                loss_pct: float) -> dict[float, bool | None]:
    return {lat: (r.success if (r := results.get((mode, lat, loss_pct))) else None) for lat in opts.latencies_ms}


def survival_lines(results: Mapping[tuple[str, float, float], CellResult], opts: SweepOptions) -> list[str]:
    """Per mode: 'survived latency, attitude mode: 60 ms at 0% loss, 20 ms at 20% loss'."""
    lines = []
    for mode in opts.modes:
        parts = []
        for loss in REPORT_LOSSES_PCT:
            if loss not in opts.losses_pct:
                parts.append(f"not swept at {_num(loss)}% loss")
                continue
            outcomes = outcomes_at(results, opts, mode, loss)
            survived = largest_survived_latency(outcomes)
            if survived is not None:
                text = f"{_num(survived)} ms"
            else:
                text = "none" if outcomes[min(outcomes)] is False else "unknown (not flown)"
            parts.append(f"{text} at {_num(loss)}% loss")
        lines.append(f"survived latency, {mode} mode: {', '.join(parts)}")
    return lines


def _cell_text(result: CellResult | None) -> str:
    if result is None:
        return "-"
    if result.success:
        return f"{result.max_tracking_error_m:.3f}" if result.max_tracking_error_m is not None else "ok"
    return "X " + ("collided" if result.collided else result.result)


def table_text(results: Mapping[tuple[str, float, float], CellResult], opts: SweepOptions) -> str:
    """Per mode: rows = loss, columns = latency, cells = max tracking error (m) or X and why it failed."""
    width = max(10, *(len(_cell_text(r)) + 2 for r in results.values())) if results else 10
    blocks = []
    for mode in opts.modes:
        head = "loss \\ latency".ljust(16) + "".join(f"{_num(lat)} ms".rjust(width) for lat in opts.latencies_ms)
        rows = [f"{mode} mode: max tracking error (m); X = failed (reason), - = not flown", head]
        for loss in opts.losses_pct:
            cells = "".join(_cell_text(results.get((mode, lat, loss))).rjust(width) for lat in opts.latencies_ms)
            rows.append(f"{_num(loss)} %".ljust(16) + cells)
        blocks.append("\n".join(rows))
    return "\n\n".join(blocks)


def _check_resume(opts: SweepOptions) -> None:
    path = opts.out / "sweep.json"
    if not path.is_file():
        return
    try:
        previous = json.loads(path.read_text()).get("settings", {})
    except (OSError, json.JSONDecodeError, AttributeError) as err:
        raise UserError(f"{path}: unreadable ({err}); remove it or use another --out") from None
    for key in SETTINGS_CHECKED_ON_RESUME:
        if previous.get(key) != opts.settings()[key]:
            raise UserError(f"--resume: {opts.out} was swept with {key} = {previous.get(key)!r}, not "
                            f"{opts.settings()[key]!r}; use the same settings or another --out")
