"""`cfstack sweep`'s command line: options, progress, and the outputs of a run.

Takes in: the command line (see the package docstring and `cfstack sweep --help`).
Gives out: OUT/sweep.json (the settings, checked by --resume), the table (groundstation.sweep.table),
the heatmap (groundstation.sweep.plot), a progress bar on stderr, exit code 0 when every cell was flown,
130 after Ctrl-C; bad input is one line and exit code 2.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shlex
import sys
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from groundstation.preflight import checked_world
from groundstation.sweep.grid import (
    DEFAULT_CELL_TIMEOUT_S,
    MODES,
    PCT_PER_UNIT,
    SweepOptions,
    grid_cells,
    load_base_profile,
    write_cell_profile,
)
from groundstation.sweep.plot import plot_sweep
from groundstation.sweep.runner import run_cells
from groundstation.sweep.table import CellResult, _check_resume, read_csv, survival_lines, table_text, write_csv
from model.errors import OneLineParser, UserError
from model.options import positive_float, seed, whole_number
from model.radio import radio_profile_path
from model.vehicle import default_vehicle_model, load_vehicle
from model.world import load_world

DEFAULT_BASE_PROFILE = "ideal"  # no impairment but the swept ones
DEFAULT_OUT = "sweep"
BAR_WIDTH = 30
SWEEP_OWNED_FLY_OPTIONS = ("--mode", "--radio", "--firmware", "--vehicle-draw", "--clock", "--seed", "--json", "--log",
                           "--connect", "--listen", "--latency-compensation", "--no-latency-compensation")


def build_parser() -> argparse.ArgumentParser:
    p = OneLineParser(prog="cfstack sweep", description="the stability map, one mission flown over a grid of "
                      "radio latency x loss per mode")
    p.add_argument("world", nargs="?", help="world JSON file (default: fly's empty room and hover)")
    p.add_argument("--mode", action="append", choices=MODES,
                   help="command mode; repeat for several (default: both)")
    p.add_argument("--latency", action="append", required=True, metavar="MS,...",
                   help="one-way latencies to sweep, ms (comma-separated; repeatable)")
    p.add_argument("--loss", action="append", required=True, metavar="PCT,...",
                   help="i.i.d. frame losses to sweep, %% per direction (comma-separated; repeatable)")
    p.add_argument("--jobs", type=whole_number(1, "a number of flights"), default=os.cpu_count() or 1,
                   help="flights at a time (default: the number of cores)")
    p.add_argument("--out", default=DEFAULT_OUT, help=f"output folder (default ./{DEFAULT_OUT})")
    p.add_argument("--seed", type=seed, default=1, help="seed of every flight (default 1)")
    p.add_argument("--radio", default=DEFAULT_BASE_PROFILE,
                   help=f"base radio profile, built-in name or TOML file (default {DEFAULT_BASE_PROFILE})")
    p.add_argument("--extra", action="append", default=[], metavar='"ARGS"',
                   help='more `cfstack fly` arguments, e.g. --extra "--trajectory constant-speed --speed 0.5" '
                        "(repeatable)")
    p.add_argument("--latency-compensation", action=argparse.BooleanOptionalAction, default=None,
                   help="pass --latency-compensation / --no-latency-compensation to every flight")
    p.add_argument("--timeout", type=positive_float, default=DEFAULT_CELL_TIMEOUT_S, metavar="S",
                   help=f"wall-clock limit of one flight, s (default {DEFAULT_CELL_TIMEOUT_S:g}); a timeout is a "
                        "failed cell")
    p.add_argument("--firmware", choices=("crazyflie", "ideal"), default="crazyflie",
                   help="the emulated vehicle's onboard side for every flight (see `cfstack fly --help`)")
    p.add_argument("--vehicle-draw", default="nominal", metavar="PROFILE",
                   help="each flight's vehicle variation (see `cfstack fly --help`); drawn from the flight's seed")
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


def _vehicle_model(extra: tuple[str, ...], firmware: str) -> str:
    """The --vehicle-model the flights will use (the last one given in --extra), else fly's default for it."""
    model = default_vehicle_model(firmware)
    for i, token in enumerate(extra):
        if token.startswith("--vehicle-model="):
            model = token.split("=", 1)[1]
        elif token == "--vehicle-model" and i + 1 < len(extra):
            model = extra[i + 1]
    return model


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
    extra = _check_extra(" ".join(args.extra))
    if args.world is not None:
        # Fail now, not after the first flight: the same pre-flight check as fly (a start or goal inside a
        # block is refused, naming the file); fly itself moves a point on the bounds and warns.
        checked_world(load_world(args.world), load_vehicle(_vehicle_model(extra, args.firmware)).collision_radius_m)
    modes = tuple(dict.fromkeys(args.mode)) if args.mode else MODES
    return SweepOptions(
        world=args.world, modes=modes,
        latencies_ms=parse_number_list(args.latency, "--latency"),
        losses_pct=parse_number_list(args.loss, "--loss", maximum=PCT_PER_UNIT),
        jobs=args.jobs, out=Path(args.out), seed=args.seed, radio_base=args.radio,
        extra=extra, latency_compensation=args.latency_compensation,
        timeout_s=args.timeout, resume=args.resume, firmware=args.firmware, vehicle_draw=args.vehicle_draw)


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
