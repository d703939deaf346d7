"""The sweep's result table: one row per flight, the CSV and Parquet files it lives in, and what it says.

Takes in: rows (a cell's axes, its seed and what its flight measured: groundstation.sweep.cell_task) and
the CSV of an earlier run (--resume).
Gives out: sweep.csv and sweep.parquet (COLUMNS; both rewritten atomically after every finished flight, so
a kill or Ctrl-C leaves two consistent files), the per-cell aggregates over seeds (success rate, spread of
the tracking error), the text table per mode, and per mode the largest one-way latency survived at 0 % and
20 % loss. "Survives" is conservative: every seed succeeded (goal reached, no collision) in that cell AND
in every cell of lower latency at the same loss, so a lucky cell past a failure does not count.
"""

from __future__ import annotations

import csv
import os
import statistics
from collections import defaultdict
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from groundstation.sweep.grid import Cell, num
from model.errors import UserError

REPORT_LOSSES_PCT = (0.0, 20.0)  # the stability map's headline: survived latency at these losses
CELL_COLUMNS = Cell.field_names()
OUTCOME_COLUMNS = ("cell_status", "attempts", "worker_lost", "success", "result", "reached_goal", "collided", "reason",
                   "rms_tracking_error_m", "max_tracking_error_m", "min_clearance_m", "flight_time_s",
                   "uplink_delivery", "downlink_delivery", "rtt_ms_p50", "rtt_ms_p99", "wall_time_s", "exit_code",
                   "worker", "log_dir")
COLUMNS = CELL_COLUMNS + OUTCOME_COLUMNS
_TYPES = {"seed": int, "attempts": int, "exit_code": int, "success": bool, "reached_goal": bool, "collided": bool,
          "worker_lost": bool, "latency_ms": float, "jitter_ms": float, "loss_pct": float, "burst_frames": float,
          "rms_tracking_error_m": float, "max_tracking_error_m": float, "min_clearance_m": float,
          "flight_time_s": float, "uplink_delivery": float, "downlink_delivery": float, "rtt_ms_p50": float,
          "rtt_ms_p99": float, "wall_time_s": float}
_ARROW = {int: pa.int64(), float: pa.float64(), bool: pa.bool_(), str: pa.string()}
SCHEMA = pa.schema([(c, _ARROW[_TYPES.get(c, str)]) for c in COLUMNS])


def make_row(cell: Cell, measured: Mapping, attempts: int, worker_lost: bool) -> dict:
    """One flight's row: its axes, then what it measured (absent measures are None)."""
    row = {c: getattr(cell, c) for c in CELL_COLUMNS}
    row.update({c: measured.get(c) for c in OUTCOME_COLUMNS})
    row.update(attempts=attempts, worker_lost=worker_lost, success=bool(measured.get("success")),
               reached_goal=bool(measured.get("reached_goal")), collided=bool(measured.get("collided")))
    return row


def cell_of(row: Mapping) -> Cell:
    return Cell(**{c: row[c] for c in CELL_COLUMNS})


def done(row: Mapping) -> bool:
    """A row that --resume keeps: the flight was flown (whatever its outcome). Crashes, wall-clock timeouts
    and lost workers (after their retry) are flown again."""
    return row.get("cell_status") == "flown"


def _text(value) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return num(value)
    return str(value)


def _parse(column: str, text: str):
    kind = _TYPES.get(column, str)
    if kind is str:
        return text if text or column in CELL_COLUMNS else None
    if text == "":
        return None
    if kind is bool:
        if text not in ("true", "false"):
            raise ValueError(f"{column}: expected true or false, got {text!r}")
        return text == "true"
    return kind(text)


def read_csv(path: Path) -> list[dict]:
    if not path.is_file():
        return []
    with path.open(newline="") as f:
        reader = csv.DictReader(f)
        if tuple(reader.fieldnames or ()) != COLUMNS:
            raise UserError(f"{path}: not a sweep table of this version (columns differ); remove it or use another "
                            "--out")
        rows = []
        for i, raw in enumerate(reader):
            try:
                rows.append({c: _parse(c, raw[c]) for c in COLUMNS})
            except (KeyError, ValueError, TypeError) as err:
                raise UserError(f"{path}:{i + 2}: malformed row ({err}); remove the file or use another --out") \
                    from None
    return rows


def _sorted(rows: Iterable[Mapping]) -> list[Mapping]:
    return sorted(rows, key=lambda r: tuple((v is None, v) for v in (r[c] for c in CELL_COLUMNS)))


def write_tables(csv_path: Path, rows: Iterable[Mapping]) -> None:
    """sweep.csv and sweep.parquet beside it, sorted by the axes, each replaced atomically."""
    ordered = _sorted(rows)
    tmp = csv_path.with_suffix(".csv.tmp")
    with tmp.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=COLUMNS)
        writer.writeheader()
        writer.writerows({c: _text(r[c]) for c in COLUMNS} for r in ordered)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, csv_path)
    parquet = csv_path.with_suffix(".parquet")
    tmp = parquet.with_suffix(".parquet.tmp")
    pq.write_table(pa.Table.from_pylist([dict(r) for r in ordered], schema=SCHEMA), tmp)
    os.replace(tmp, parquet)


# -- aggregates over seeds ------------------------------------------------------------------------------------

AXES_BUT_SEED = tuple(c for c in CELL_COLUMNS if c != "seed")


def cell_key(row: Mapping) -> tuple:
    """A cell without its seed: the unit the stability map aggregates over."""
    return tuple(row[c] for c in AXES_BUT_SEED)


def aggregate(rows: Iterable[Mapping]) -> dict[tuple, dict]:
    """Per cell (all axes but the seed): seeds flown, successes, success rate, and the tracking error's
    median and spread (sample standard deviation over the successful seeds; None below two)."""
    groups: dict[tuple, list[Mapping]] = defaultdict(list)
    for row in rows:
        if done(row):
            groups[cell_key(row)].append(row)
    out = {}
    for key, members in groups.items():
        errors = [r["max_tracking_error_m"] for r in members if r["success"] and r["max_tracking_error_m"] is not None]
        successes = sum(1 for r in members if r["success"])
        out[key] = {"flights": len(members), "successes": successes, "success_rate": successes / len(members),
                    "max_error_median_m": statistics.median(errors) if errors else None,
                    "max_error_spread_m": statistics.stdev(errors) if len(errors) >= 2 else None}
    return out


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


# A panel of the stability map: one value of each of these axes; its cells are latency x loss.
PANEL_AXES = ("mode", "world", "radio", "jitter_ms", "burst_frames", "controller", "vehicle_draw")


def panels(rows: Sequence[Mapping]) -> dict[tuple, dict[tuple[float, float], dict]]:
    """Latency x loss maps, one per combination of the PANEL_AXES (mode first): panel key (values of
    PANEL_AXES) -> (latency, loss) -> aggregate."""
    out: dict[tuple, dict] = defaultdict(dict)
    for key, agg in aggregate(rows).items():
        axes = dict(zip(AXES_BUT_SEED, key, strict=True))
        out[tuple(axes[a] for a in PANEL_AXES)][(axes["latency_ms"], axes["loss_pct"])] = agg
    return dict(sorted(out.items()))


_AXIS_TEXT = {
    "mode": lambda v: f"{v} mode", "world": lambda v: f"world {Path(v).stem if v else 'empty'}",
    "radio": lambda v: f"radio {Path(v).stem}", "jitter_ms": lambda v: f"jitter {num(v)} ms",
    "burst_frames": lambda v: f"burst {num(v)} frames", "controller": lambda v: f"controller {v or 'gains'}",
    "vehicle_draw": lambda v: f"draw {v}",
}


def panel_title(panel: tuple, varying: Sequence[str]) -> str:
    """The mode, and the value of every other panel axis that differs between panels."""
    values = dict(zip(PANEL_AXES, panel, strict=True))
    return ", ".join(_AXIS_TEXT[a](values[a]) for a in PANEL_AXES if a == "mode" or a in varying)


def varying_axes(panel_keys: Iterable[tuple]) -> list[str]:
    """The panel axes (besides the mode) whose value differs between panels."""
    keys = list(panel_keys)
    return [a for i, a in enumerate(PANEL_AXES) if a != "mode" and len({k[i] for k in keys}) > 1]


def survival_lines(rows: Sequence[Mapping]) -> list[str]:
    """Per panel: 'survived latency, attitude mode: 60 ms at 0% loss, 20 ms at 20% loss'."""
    maps = panels(rows)
    varying = varying_axes(maps)
    lines = []
    for panel, cells in maps.items():
        parts = []
        for loss in REPORT_LOSSES_PCT:
            outcomes = {lat: agg["success_rate"] == 1.0 for (lat, ls), agg in cells.items() if ls == loss}
            if not outcomes:
                parts.append(f"not swept at {num(loss)}% loss")
                continue
            survived = largest_survived_latency(outcomes)
            parts.append(f"{num(survived) + ' ms' if survived is not None else 'none'} at {num(loss)}% loss")
        lines.append(f"survived latency, {panel_title(panel, varying)}: {', '.join(parts)}")
    return lines


def _cell_text(agg: dict | None) -> str:
    if agg is None:
        return "-"
    rate = f"{agg['successes']}/{agg['flights']}"
    if agg["max_error_median_m"] is None:
        return f"X {rate}"
    spread = agg["max_error_spread_m"]
    return f"{rate} {agg['max_error_median_m']:.3f}" + (f"+-{spread:.3f}" if spread is not None else "")


def table_text(rows: Sequence[Mapping]) -> str:
    """Per panel: rows = loss, columns = latency; cell = successes/seeds, median max tracking error (m) +- its
    spread over the successful seeds; X = no seed succeeded."""
    maps = panels(rows)
    varying = varying_axes(maps)
    blocks = []
    for panel, cells in maps.items():
        lats = sorted({lat for lat, _ in cells})
        losses = sorted({loss for _, loss in cells})
        width = max(12, *(len(_cell_text(a)) + 2 for a in cells.values()))
        head = "loss \\ latency".ljust(16) + "".join(f"{num(lat)} ms".rjust(width) for lat in lats)
        lines = [f"{panel_title(panel, varying)}: successes/seeds, max tracking error (m) median +- spread; "
                 "X = none succeeded, - = not flown", head]
        for loss in losses:
            lines.append(f"{num(loss)} %".ljust(16)
                         + "".join(_cell_text(cells.get((lat, loss))).rjust(width) for lat in lats))
        blocks.append("\n".join(lines))
    return "\n\n".join(blocks)
