"""`cfstack sweep`: the stability map, one mission flown over a grid of radio latency x loss per mode.

Takes in: `cfstack sweep [WORLD] --mode moments|attitude [--mode ...] --latency MS,... --loss PCT,...
[--jobs N] [--out DIR] [--seed N] [--radio BASE] [--extra "ARGS"] [--latency-compensation] [--timeout S]
[--resume]`.
Gives out, in OUT (default ./sweep):
  profiles/*.toml  one radio profile per (latency, loss): the base profile (default `ideal`, no other
                   impairment) with latency.base_s = L / 1000 s and i.i.d. loss.probability = P / 100;
                   the emulator applies the one profile to both directions (uplink and downlink);
  cells/<cell>/    each flight's log folder (`cfstack fly --log`), plus fly_stdout.json / fly_stderr.txt;
  sweep.csv        one row per cell (CSV_COLUMNS; `reason` is fly's failsafe_reason, or the last line fly
                   wrote on stderr when it crashed or timed out), rewritten after every finished cell;
  sweep.json       the settings the cells were flown with (what --resume checks);
  sweep.png        heatmaps, one panel per mode: latency x loss, colour = max tracking error (m),
                   failed cells hatched and marked X;
and on stdout a table per mode and, per mode, the largest one-way latency it survives at 0 % and 20 % loss.
A progress bar (cells done / total, elapsed, ETA) goes to stderr.

Every cell is `cfstack fly WORLD --mode M --radio PROFILE --clock lockstep --seed N --json --log DIR`
in its own subprocess (lockstep + seed: the same cell gives the same flight on a busy machine), at
most --jobs at a time. A cell whose fly exits with code 2 (bad input) aborts the sweep with fly's
one-line error; a crash, a timeout or a failsafe is a normal, failed cell. Ctrl-C stops the running
flights and still writes what was done (exit code 130); `--resume` skips the cells already in sweep.csv.

"Survives" is conservative: success (goal reached, no collision) in that cell AND in every cell of
lower latency at the same loss, so a lucky cell past a failure does not count.
"""

from __future__ import annotations

import argparse
import copy
import csv
import json
import math
import os
import shlex
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from matplotlib import colormaps
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.cm import ScalarMappable
from matplotlib.colors import LogNorm, Normalize
from matplotlib.figure import Figure
from matplotlib.patches import Patch, Rectangle

from model.config import Params
from model.errors import ConfigError, UserError
from model.radio import radio_profile_path
from model.world import load_world

MODES = ("moments", "attitude")
REPORT_LOSSES_PCT = (0.0, 20.0)  # the issue asks for the survived latency at these losses
DEFAULT_BASE_PROFILE = "ideal"  # no impairment but the swept ones
DEFAULT_OUT = "sweep"
DEFAULT_CELL_TIMEOUT_S = 600.0  # a lockstep flight of a lab maze takes ~10 s wall; this only catches hangs
POLL_S = 0.2  # how often the scheduler looks at its children and redraws the bar
SECOND_SIGINT_AFTER_S = 0.5  # fly lands on the first Ctrl-C and disarms at once on the second
STOP_GRACE_S = 10.0  # after the second SIGINT, how long a fly child gets to stop its emulator and exit
BAD_INPUT_EXIT_CODE = UserError.exit_code  # what `cfstack fly` returns for bad input (2)
MS_PER_S = 1000.0
PCT_PER_UNIT = 100.0
FIG_DPI = 110
BAR_WIDTH = 30
# Options of `cfstack fly` the sweep sets itself: --extra may not override them.
SWEEP_OWNED_FLY_OPTIONS = ("--mode", "--radio", "--clock", "--seed", "--json", "--log", "--connect", "--listen",
                           "--latency-compensation", "--no-latency-compensation")
CSV_COLUMNS = ("mode", "latency_ms", "loss_pct", "success", "result", "reached_goal", "collided", "reason",
               "rms_tracking_error_m", "max_tracking_error_m", "min_clearance_m", "flight_time_s", "wall_time_s",
               "exit_code", "log_dir")
SETTINGS_CHECKED_ON_RESUME = ("world", "seed", "radio_base", "extra", "latency_compensation")


# ------------------------------------------------------------------------------------------------
# Options
# ------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class SweepOptions:
    world: str | None  # world JSON path (None: fly's default empty room)
    modes: tuple[str, ...]
    latencies_ms: tuple[float, ...]  # one-way, ascending, distinct
    losses_pct: tuple[float, ...]  # i.i.d. per frame and direction, ascending, distinct
    jobs: int
    out: Path
    seed: int
    radio_base: str
    extra: tuple[str, ...] = ()  # more `cfstack fly` arguments
    latency_compensation: bool | None = None  # None: fly's default
    timeout_s: float = DEFAULT_CELL_TIMEOUT_S
    resume: bool = False

    def settings(self) -> dict:
        """What makes two sweeps' cells comparable (written to sweep.json, checked by --resume)."""
        return {"world": str(Path(self.world).resolve()) if self.world else None, "seed": self.seed,
                "radio_base": self.radio_base, "extra": list(self.extra),
                "latency_compensation": self.latency_compensation}


class _Parser(argparse.ArgumentParser):
    """argparse, but a bad option is a one-line UserError instead of usage text and SystemExit."""

    def error(self, message: str):
        raise UserError(message)


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="cfstack sweep", description=__doc__.splitlines()[0])
    p.add_argument("world", nargs="?", help="world JSON file (default: fly's empty room and hover)")
    p.add_argument("--mode", action="append", choices=MODES,
                   help="command mode; repeat for several (default: both)")
    p.add_argument("--latency", action="append", required=True, metavar="MS,...",
                   help="one-way latencies to sweep, ms (comma-separated; repeatable)")
    p.add_argument("--loss", action="append", required=True, metavar="PCT,...",
                   help="i.i.d. frame losses to sweep, %% per direction (comma-separated; repeatable)")
    p.add_argument("--jobs", type=int, default=os.cpu_count() or 1,
                   help="flights at a time (default: the number of cores)")
    p.add_argument("--out", default=DEFAULT_OUT, help=f"output folder (default ./{DEFAULT_OUT})")
    p.add_argument("--seed", type=int, default=1, help="seed of every flight (default 1)")
    p.add_argument("--radio", default=DEFAULT_BASE_PROFILE,
                   help=f"base radio profile, built-in name or TOML file (default {DEFAULT_BASE_PROFILE})")
    p.add_argument("--extra", action="append", default=[], metavar='"ARGS"',
                   help='more `cfstack fly` arguments, e.g. --extra "--trajectory constant-speed --speed 0.5" '
                        "(repeatable)")
    p.add_argument("--latency-compensation", action=argparse.BooleanOptionalAction, default=None,
                   help="pass --latency-compensation / --no-latency-compensation to every flight")
    p.add_argument("--timeout", type=float, default=DEFAULT_CELL_TIMEOUT_S, metavar="S",
                   help=f"wall-clock limit of one flight, s (default {DEFAULT_CELL_TIMEOUT_S:g}); a timeout is a "
                        "failed cell")
    p.add_argument("--resume", action="store_true", help="skip the cells already in OUT/sweep.csv")
    return p


def parse_number_list(texts: Iterable[str], flag: str, maximum: float | None = None) -> tuple[float, ...]:
    """'0,10,20' (possibly given several times) -> (0.0, 10.0, 20.0): sorted, distinct, finite, >= 0."""
    values: set[float] = set()
    for text in texts:
        for item in text.split(","):
            item = item.strip()
            if not item:
                raise UserError(f"{flag} '{text}': empty entry (give comma-separated numbers, e.g. 0,10,20)")
            try:
                value = float(item)
            except ValueError:
                raise UserError(f"{flag} '{text}': '{item}' is not a number") from None
            if not math.isfinite(value) or value < 0.0:
                raise UserError(f"{flag} '{text}': {item} must be a finite number >= 0")
            if maximum is not None and value > maximum:
                raise UserError(f"{flag} '{text}': {item} is above the maximum {maximum:g}")
            values.add(value)
    if not values:
        raise UserError(f"{flag}: no values given")
    return tuple(sorted(values))


def _check_extra(extra: str) -> tuple[str, ...]:
    try:
        tokens = tuple(shlex.split(extra))
    except ValueError as err:
        raise UserError(f"--extra '{extra}': {err}") from None
    for token in tokens:
        if token.split("=", 1)[0] in SWEEP_OWNED_FLY_OPTIONS:
            raise UserError(f"--extra: {token.split('=', 1)[0]} is set by the sweep itself "
                            "(use the sweep's own option)")
    return tokens


def _glue_extra(argv: Sequence[str]) -> list[str]:
    """`--extra "--from-ground"` -> `--extra=--from-ground`: argparse would take a value that looks like an
    option for a missing argument."""
    out, tokens = [], iter(argv)
    for token in tokens:
        value = next(tokens, None) if token == "--extra" else None
        out.append(token if value is None else f"--extra={value}")
    return out


def parse_options(argv: Sequence[str]) -> SweepOptions:
    """Checked options; a one-line UserError for anything wrong."""
    args = build_parser().parse_args(_glue_extra(argv))
    if args.jobs < 1:
        raise UserError(f"--jobs {args.jobs}: must be at least 1")
    if args.seed < 0:
        raise UserError(f"--seed {args.seed}: must be >= 0")
    if not (math.isfinite(args.timeout) and args.timeout > 0.0):
        raise UserError(f"--timeout {args.timeout}: must be > 0 s")
    if args.world is not None:
        load_world(args.world)  # fail now, not after the first flight (WorldError names the file)
    modes = tuple(dict.fromkeys(args.mode)) if args.mode else MODES
    return SweepOptions(
        world=args.world, modes=modes,
        latencies_ms=parse_number_list(args.latency, "--latency"),
        losses_pct=parse_number_list(args.loss, "--loss", maximum=PCT_PER_UNIT),
        jobs=args.jobs, out=Path(args.out), seed=args.seed, radio_base=args.radio,
        extra=_check_extra(" ".join(args.extra)), latency_compensation=args.latency_compensation,
        timeout_s=args.timeout, resume=args.resume)


# ------------------------------------------------------------------------------------------------
# Radio profiles
# ------------------------------------------------------------------------------------------------


def load_base_profile(path: Path) -> Params:
    """The base profile, checked for what the sweep overrides (the emulator checks the rest)."""
    base = Params.load(path)
    base.table("latency").number("base_s", minimum=0.0)
    base.table("loss").number("probability", minimum=0.0, maximum=1.0)
    base.string("name")
    base.string("source")
    return base


def cell_profile(base: Params, latency_ms: float, loss_pct: float) -> dict:
    """The base profile's data with latency.base_s = L / 1000 s and loss.probability = P / 100."""
    data = copy.deepcopy(base.data)
    base_name = data["name"]
    data["name"] = f"{base_name}_lat{_num(latency_ms)}ms_loss{_num(loss_pct)}pct"
    data["source"] = (f"Generated by cfstack sweep from '{base_name}' ({base.source}): latency.base_s = "
                      f"{_num(latency_ms)} ms / 1000, loss.probability = {_num(loss_pct)} % / 100 (i.i.d. per frame, "
                      f"both directions); everything else as in the base, whose source is: {data['source']}")
    data["latency"]["base_s"] = latency_ms / MS_PER_S
    data["loss"]["probability"] = loss_pct / PCT_PER_UNIT
    return data


def _toml_value(value, where: str) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ConfigError(f"{where}: cannot write {value!r}")
        return repr(value)  # shortest round-trip form, valid TOML ("1e-05", "0.02")
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)  # JSON string escapes are valid TOML basic strings
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v, where) for v in value) + "]"
    raise ConfigError(f"{where}: cannot write a {type(value).__name__} value to TOML")


def dump_toml(data: Mapping, header: str = "") -> str:
    """TOML text of nested tables of scalars and lists (what radio profiles hold)."""
    lines = [f"# {line}" for line in header.splitlines()]

    def emit(table: Mapping, prefix: str) -> None:
        for key, value in table.items():
            if not isinstance(value, Mapping):
                lines.append(f"{key} = {_toml_value(value, prefix + key)}")
        for key, value in table.items():
            if isinstance(value, Mapping):
                lines.extend(["", f"[{prefix}{key}]"])
                emit(value, f"{prefix}{key}.")

    emit(data, "")
    return "\n".join(lines) + "\n"


def write_cell_profile(base: Params, latency_ms: float, loss_pct: float, folder: Path) -> Path:
    data = cell_profile(base, latency_ms, loss_pct)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{data['name']}.toml"
    path.write_text(dump_toml(data, header="Generated by `cfstack sweep`; regenerated on every run, do not edit."))
    return path


# ------------------------------------------------------------------------------------------------
# Cells and their results
# ------------------------------------------------------------------------------------------------


def _num(x: float) -> str:
    """A number as short as it reads ('10', '2.5'), exact on reading back."""
    short = f"{x:g}"
    return short if float(short) == x else repr(x)


@dataclass(frozen=True)
class Cell:
    mode: str
    latency_ms: float
    loss_pct: float

    @property
    def key(self) -> tuple[str, float, float]:
        return self.mode, self.latency_ms, self.loss_pct

    @property
    def slug(self) -> str:
        return f"{self.mode}_lat{_num(self.latency_ms)}ms_loss{_num(self.loss_pct)}pct"

    @property
    def label(self) -> str:
        return f"{self.mode} {_num(self.latency_ms)} ms {_num(self.loss_pct)} %"


def grid_cells(opts: SweepOptions) -> list[Cell]:
    return [Cell(mode, latency, loss) for mode in opts.modes for loss in opts.losses_pct
            for latency in opts.latencies_ms]


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


def _float_or_none(value) -> float | None:
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else None


def _last_line(text: str) -> str:
    lines = [line for line in text.strip().splitlines() if line.strip()]
    return lines[-1].strip() if lines else ""


def result_from_fly(cell: Cell, exit_code: int | None, stdout: str, stderr: str, wall_s: float, log_dir: Path,
                    timed_out: bool = False) -> CellResult:
    """One cell's row from its fly subprocess; a UserError (abort the sweep) for exit code 2, bad input."""
    if exit_code == BAD_INPUT_EXIT_CODE and not timed_out:
        raise UserError(f"cell {cell.label}: {_last_line(stderr) or 'cfstack fly exited with code 2 (bad input)'}")
    try:
        summary = json.loads(stdout) if stdout.strip() else None
    except json.JSONDecodeError:
        summary = None
    if not isinstance(summary, dict) or "result" not in summary:
        reason = _last_line(stderr)[:200] or None
        return CellResult(cell, success=False, result="timeout" if timed_out else "crash", reason=reason,
                          wall_time_s=wall_s, exit_code=exit_code, log_dir=str(log_dir))
    reached = summary.get("reached_goal") is True
    collided = summary.get("collided") is True
    # Stopped for its timeout, fly may still land and print a summary ("aborted"): the cell timed out.
    return CellResult(
        cell, success=reached and not collided and exit_code == 0 and not timed_out,
        result="timeout" if timed_out else str(summary["result"]),
        reached_goal=reached, collided=collided, reason=summary.get("failsafe_reason"),
        rms_tracking_error_m=_float_or_none(summary.get("rms_tracking_error_m")),
        max_tracking_error_m=_float_or_none(summary.get("max_tracking_error_m")),
        min_clearance_m=_float_or_none(summary.get("min_clearance_m")),
        flight_time_s=_float_or_none(summary.get("flight_time_s")),
        wall_time_s=wall_s, exit_code=exit_code, log_dir=str(log_dir))


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


# ------------------------------------------------------------------------------------------------
# Running the flights
# ------------------------------------------------------------------------------------------------


def fly_argv(opts: SweepOptions, cell: Cell, profile: Path, log_dir: Path) -> list[str]:
    """The `cfstack fly` command line of one cell (run as `python -m link`, the same program)."""
    argv = [sys.executable, "-m", "cfstack", "fly"]
    if opts.world:
        argv.append(str(Path(opts.world).resolve()))
    argv += ["--mode", cell.mode, "--radio", str(profile.resolve()), "--clock", "lockstep",
             "--seed", str(opts.seed), "--json", "--log", str(log_dir.resolve())]
    if opts.latency_compensation is not None:
        argv.append("--latency-compensation" if opts.latency_compensation else "--no-latency-compensation")
    return argv + list(opts.extra)


def _die_with_parent() -> None:
    """In the child: SIGTERM it when the sweep dies, however it dies (it runs in its own session)."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG = 1
    except (OSError, AttributeError):  # not Linux: Ctrl-C handling below still stops the children
        pass


@dataclass
class _Flight:
    """One running `cfstack fly` child."""

    cell: Cell
    log_dir: Path
    proc: subprocess.Popen
    started_s: float
    stdout_path: Path
    stderr_path: Path

    @staticmethod
    def start(opts: SweepOptions, cell: Cell, profile: Path) -> _Flight:
        log_dir = opts.out / "cells" / cell.slug
        log_dir.mkdir(parents=True, exist_ok=True)
        stdout_path, stderr_path = log_dir / "fly_stdout.json", log_dir / "fly_stderr.txt"
        # Files, not pipes: a pipe nobody reads during a flight could fill and stall it. A session of
        # its own: the terminal's Ctrl-C reaches only the sweep, which then stops each flight in order.
        with stdout_path.open("w") as out, stderr_path.open("w") as err:
            proc = subprocess.Popen(fly_argv(opts, cell, profile, log_dir), stdin=subprocess.DEVNULL, stdout=out,
                                    stderr=err, start_new_session=True, preexec_fn=_die_with_parent)
        return _Flight(cell, log_dir, proc, time.monotonic(), stdout_path, stderr_path)

    def signal_group(self, sig: int) -> None:
        try:
            os.killpg(self.proc.pid, sig)  # fly and its emulator child (same process group)
        except ProcessLookupError:
            pass

    def stop(self) -> None:
        """Ctrl-C twice to fly alone (its first lands, the second disarms at once; then it stops its own
        emulator), then SIGKILL to both after STOP_GRACE_S. The cell is discarded: no need to land it.
        Not SIGINT to the group: a lockstep emulator stopped first would leave fly waiting for its clock."""
        for _ in range(2):
            if self.proc.poll() is not None:
                return
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout=SECOND_SIGINT_AFTER_S)
            except subprocess.TimeoutExpired:
                pass
        try:
            self.proc.wait(timeout=STOP_GRACE_S)
        except subprocess.TimeoutExpired:
            self.signal_group(signal.SIGKILL)
            self.proc.wait()

    def result(self, timed_out: bool) -> CellResult:
        return result_from_fly(self.cell, self.proc.returncode, self.stdout_path.read_text(),
                               self.stderr_path.read_text(), time.monotonic() - self.started_s, self.log_dir,
                               timed_out=timed_out)


def run_cells(opts: SweepOptions, todo: Sequence[tuple[Cell, Path]], on_done: Callable[[CellResult], None],
              on_tick: Callable[[], None] = lambda: None) -> None:
    """Fly every (cell, profile), at most opts.jobs at a time; on_done(result) as each finishes.

    A KeyboardInterrupt or a bad-input UserError stops every running flight before it propagates.
    """
    pending = list(reversed(todo))
    running: list[_Flight] = []
    try:
        while pending or running:
            while pending and len(running) < opts.jobs:
                cell, profile = pending.pop()
                running.append(_Flight.start(opts, cell, profile))
            time.sleep(POLL_S)
            for flight in list(running):
                timed_out = flight.proc.poll() is None and time.monotonic() - flight.started_s > opts.timeout_s
                if timed_out:
                    flight.stop()
                if flight.proc.poll() is not None:
                    running.remove(flight)
                    on_done(flight.result(timed_out))
            on_tick()
    finally:
        for flight in running:
            flight.stop()


class ProgressBar:
    """`[#####.....] 12/70 cells  elapsed 3:12  ETA 14:30` on stderr: redrawn in place on a terminal,
    one line per finished cell otherwise (logs, pipes)."""

    def __init__(self, total: int, already_done: int, stream=None):
        self.total, self.done, self.started_done = total, already_done, already_done
        self.stream = stream if stream is not None else sys.stderr
        self.tty = self.stream.isatty()
        self.start_s = time.monotonic()

    def line(self) -> str:
        elapsed = time.monotonic() - self.start_s
        flown = self.done - self.started_done
        eta = elapsed / flown * (self.total - self.done) if flown > 0 else None
        return progress_line(self.done, self.total, elapsed, eta)

    def tick(self) -> None:
        if self.tty:
            self.stream.write("\r" + self.line())
            self.stream.flush()

    def cell_done(self, result: CellResult) -> None:
        self.done += 1
        if self.tty:
            self.tick()
        else:
            print(f"{self.line()}  {result.cell.label}: {result.result}", file=self.stream, flush=True)

    def close(self) -> None:
        if self.tty:
            self.stream.write("\n")
            self.stream.flush()


def _clock(seconds: float | None) -> str:
    if seconds is None:
        return "--:--"
    minutes, secs = divmod(int(round(seconds)), 60)
    hours, minutes = divmod(minutes, 60)
    return f"{hours}:{minutes:02d}:{secs:02d}" if hours else f"{minutes}:{secs:02d}"


def progress_line(done: int, total: int, elapsed_s: float, eta_s: float | None, width: int = BAR_WIDTH) -> str:
    filled = int(width * done / total) if total else width
    return f"[{'#' * filled}{'.' * (width - filled)}] {done}/{total} cells  elapsed {_clock(elapsed_s)}  " \
           f"ETA {_clock(eta_s)}"


# ------------------------------------------------------------------------------------------------
# Analysis and output
# ------------------------------------------------------------------------------------------------


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


def _colour_norm(values: Sequence[float]) -> Normalize:
    """Log colours when the errors span more than a decade (a few mm to tens of cm), linear otherwise."""
    if not values:
        return Normalize(0.0, 1.0)
    low, high = min(values), max(values)
    if low > 0.0 and high / low > 10.0:
        return LogNorm(low, high)
    return Normalize(0.0 if high > 0.0 else -1.0, high if high > 0.0 else 1.0)


def plot_sweep(results: Mapping[tuple[str, float, float], CellResult], opts: SweepOptions, path: Path) -> Path:
    """Heatmaps (one panel per mode): x = one-way latency (ms), y = loss (%), colour = max tracking error (m)."""
    lats, losses = opts.latencies_ms, opts.losses_pct
    values = [r.max_tracking_error_m for r in results.values()
              if r.success and r.max_tracking_error_m is not None and r.cell.mode in opts.modes]
    norm, cmap = _colour_norm(values), colormaps["viridis"]
    panel_w, panel_h = max(4.0, 0.75 * len(lats) + 1.5), max(3.0, 0.55 * len(losses) + 1.8)
    fig = Figure(figsize=(panel_w * len(opts.modes) + 1.5, panel_h + 0.8), dpi=FIG_DPI, layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, len(opts.modes), squeeze=False)[0]
    for ax, mode in zip(axes, opts.modes, strict=True):
        grid = np.full((len(losses), len(lats)), np.nan)
        for i, loss in enumerate(losses):
            for j, lat in enumerate(lats):
                r = results.get((mode, lat, loss))
                if r is not None and r.success and r.max_tracking_error_m is not None:
                    grid[i, j] = r.max_tracking_error_m
                _mark_cell(ax, j, i, r, norm, cmap)
        ax.pcolormesh(np.arange(len(lats) + 1) - 0.5, np.arange(len(losses) + 1) - 0.5, np.ma.masked_invalid(grid),
                      cmap=cmap, norm=norm)
        ax.set_xticks(range(len(lats)), labels=[_num(v) for v in lats])
        ax.set_yticks(range(len(losses)), labels=[_num(v) for v in losses])
        ax.set_xlim(-0.5, len(lats) - 0.5)
        ax.set_ylim(-0.5, len(losses) - 0.5)
        ax.set_xlabel("one-way latency, each direction (ms)")
        ax.set_ylabel("i.i.d. frame loss, each direction (%)")
        ax.set_title(f"{mode} mode")
    fig.colorbar(ScalarMappable(norm=norm, cmap=cmap), ax=list(axes), label="max tracking error (m)")
    fig.legend(handles=[Patch(facecolor="0.85", edgecolor="tab:red", hatch="xx", label="X: failed (no goal, "
                              "collision, crash or timeout)"),
                        Patch(facecolor="white", edgecolor="0.6", label="-: not flown")],
               loc="outside lower center", ncols=2, fontsize="small")
    world = Path(opts.world).name if opts.world else "empty room (hover)"
    fig.suptitle(f"Stability map: {world}\nbase radio '{opts.radio_base}', seed {opts.seed}, lockstep clock",
                 fontsize="medium")
    fig.savefig(path)
    return path


def _mark_cell(ax, x: int, y: int, result: CellResult | None, norm: Normalize, cmap) -> None:
    if result is None:
        ax.text(x, y, "-", ha="center", va="center", color="0.5")
    elif not result.success:
        ax.add_patch(Rectangle((x - 0.5, y - 0.5), 1.0, 1.0, facecolor="0.85", edgecolor="tab:red", hatch="xx",
                               linewidth=0.0, zorder=2))
        ax.text(x, y, "X", ha="center", va="center", color="tab:red", fontsize="x-large", fontweight="bold",
                zorder=3, bbox=dict(boxstyle="round", facecolor="white", edgecolor="none"))
    elif result.max_tracking_error_m is not None:
        value = result.max_tracking_error_m
        dark = norm(value) < 0.5  # viridis is dark at the low end
        ax.text(x, y, f"{value:.3f}", ha="center", va="center", fontsize="x-small", zorder=3,
                color="white" if dark else "black")


# ------------------------------------------------------------------------------------------------
# The command
# ------------------------------------------------------------------------------------------------


@dataclass
class _Outputs:
    opts: SweepOptions
    results: dict[tuple[str, float, float], CellResult] = field(default_factory=dict)

    @property
    def csv_path(self) -> Path:
        return self.opts.out / "sweep.csv"

    def add(self, result: CellResult) -> None:
        self.results[result.cell.key] = result
        write_csv(self.csv_path, self.results.values(), self.opts.modes)

    def finish(self) -> None:
        write_csv(self.csv_path, self.results.values(), self.opts.modes)
        png = plot_sweep(self.results, self.opts, self.opts.out / "sweep.png")
        print(table_text(self.results, self.opts))
        print()
        for line in survival_lines(self.results, self.opts):
            print(line)
        print(f"table: {self.csv_path}\nheatmap: {png}")


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


def command(argv: list[str]) -> int:
    """Entry point of `cfstack sweep`: 0 when every cell was flown, 130 after Ctrl-C; UserError on bad input."""
    opts = parse_options(argv)
    base = load_base_profile(radio_profile_path(opts.radio_base))
    if opts.out.exists() and not opts.out.is_dir():
        raise UserError(f"--out {opts.out}: exists and is not a folder")
    if opts.resume:
        _check_resume(opts)
    opts.out.mkdir(parents=True, exist_ok=True)
    outputs = _Outputs(opts)
    if opts.resume:
        outputs.results = {r.cell.key: r for r in read_csv(outputs.csv_path)}
    (opts.out / "sweep.json").write_text(json.dumps({"settings": opts.settings(), "modes": list(opts.modes),
                                                     "latencies_ms": list(opts.latencies_ms),
                                                     "losses_pct": list(opts.losses_pct)}, indent=2) + "\n")
    cells = grid_cells(opts)
    profiles = {(c.latency_ms, c.loss_pct): write_cell_profile(base, c.latency_ms, c.loss_pct, opts.out / "profiles")
                for c in cells}
    todo = [(c, profiles[c.latency_ms, c.loss_pct]) for c in cells if c.key not in outputs.results]
    bar = ProgressBar(len(cells), len(cells) - len(todo))
    bar.tick()

    def done(result: CellResult) -> None:
        outputs.add(result)
        bar.cell_done(result)

    try:
        run_cells(opts, todo, done, bar.tick)
    except KeyboardInterrupt:
        bar.close()
        outputs.finish()
        print(f"cfstack sweep: interrupted after {bar.done} of {len(cells)} cells; the rest: "
              f"rerun with --resume --out {opts.out}", file=sys.stderr)
        return 130
    except UserError:
        bar.close()
        write_csv(outputs.csv_path, outputs.results.values(), opts.modes)
        raise
    bar.close()
    outputs.finish()
    return 0
