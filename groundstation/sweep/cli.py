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

from groundstation.controller import VARIANTS as CONTROLLERS
from groundstation.planned import KINDS as PLANNED_KINDS
from groundstation.preflight import checked_world
from groundstation.sweep.cell_task import CellJob
from groundstation.sweep.grid import (
    DEFAULT_CELL_TIMEOUT_S,
    IID_BURST_FRAMES,
    MODES,
    PCT_PER_UNIT,
    Cell,
    SweepOptions,
    cell_profile_text,
    grid_cells,
    load_base_profile,
    num,
)
from groundstation.sweep.plot import plot_sweep
from groundstation.sweep.runner import DaskRunner, Progress
from groundstation.sweep.table import cell_of, done, read_csv, survival_lines, table_text, write_tables
from groundstation.usercode.adapters import CONTROLLER_OUTPUTS
from groundstation.usercode.loader import builtin_or_user_file, looks_like_path, split_spec
from model.errors import OneLineParser, UserError
from model.firmwares import DEFAULT_FIRMWARE, FIRMWARE_VEHICLES, default_vehicle_model
from model.options import positive_float, seed, whole_number
from model.vehicle import load_vehicle
from model.world import load_world

DEFAULT_BASE_PROFILE = "ideal"  # no impairment but the swept ones
DEFAULT_OUT = "sweep"
BAR_WIDTH = 30
SWEEP_OWNED_FLY_OPTIONS = ("--mode", "--radio", "--firmware", "--vehicle-draw", "--controller", "--clock", "--seed",
                           "--json", "--log",
                           "--connect", "--listen", "--latency-compensation", "--no-latency-compensation")


def build_parser() -> argparse.ArgumentParser:
    p = OneLineParser(prog="cfstack sweep", description="stability maps and Monte Carlo: one mission flown over a "
                      "grid of radio, vehicle and controller axes, each cell a lockstep flight on dask.distributed")
    p.add_argument("worlds", nargs="*", metavar="WORLD",
                   help="world JSON files, an axis (default: fly's empty room and hover)")
    p.add_argument("--mode", action="append", choices=MODES, help="command mode; repeat for several (default: both)")
    p.add_argument("--latency", action="append", metavar="MS,...",
                   help="one-way latencies, ms (comma-separated; repeatable; default: the radio profile's)")
    p.add_argument("--loss", action="append", metavar="PCT,...",
                   help="average frame losses, %% per direction (default: the radio profile's)")
    p.add_argument("--jitter", action="append", metavar="MS,...",
                   help="latency jitter, ms, with the profile's law (uniform: half-width) (default: the profile's)")
    p.add_argument("--burst", action="append", metavar="FRAMES,...",
                   help="mean length of loss bursts in frames, at the same average loss; 1 = i.i.d. "
                        "(default: the profile's)")
    p.add_argument("--radio", action="append", metavar="PROFILE",
                   help=f"base radio profiles, built-in names or TOML files; repeat for several "
                        f"(default {DEFAULT_BASE_PROFILE})")
    p.add_argument("--controller", action="append", type=_controller_axis, metavar="report|full|PATH[:Class]",
                   help="fly's --controller: a variant or a user controller file; repeat for several (default: the "
                        "gains file's). A file must be readable at the same path on every worker")
    p.add_argument("--controller-output", choices=CONTROLLER_OUTPUTS,
                   help="fly's --controller-output for user controllers (default: commands)")
    p.add_argument("--trajectory", metavar="NAME|PATH[:Class]",
                   help="fly's --trajectory for every flight: a built-in or planned kind, or a user trajectory file")
    p.add_argument("--planner", metavar="PATH[:function]", help="fly's --planner for every flight (a user "
                   "graph_search file)")
    p.add_argument("--vehicle-draw", action="append", metavar="PROFILE",
                   help="vehicle variation profiles (see `cfstack fly --help`); repeat for several "
                        "(default nominal); each flight's draw comes from its seed")
    p.add_argument("--seed", type=seed, default=1, help="first seed (default 1)")
    p.add_argument("--seeds", type=whole_number(1, "a number of seeds"), default=1,
                   help="seeds per cell, SEED .. SEED+N-1 (Monte Carlo; default 1)")
    p.add_argument("--jobs", type=whole_number(1, "a number of flights"), default=os.cpu_count() or 1,
                   help="LocalCluster workers, one flight each (default: the number of cores)")
    p.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                   help="use this running dask scheduler and its workers instead of a LocalCluster")
    p.add_argument("--out", default=DEFAULT_OUT, help=f"output folder (default ./{DEFAULT_OUT})")
    p.add_argument("--extra", action="append", default=[], metavar='"ARGS"',
                   help='more `cfstack fly` arguments, e.g. --extra "--trajectory constant-speed --speed 0.5" '
                        "(repeatable)")
    p.add_argument("--latency-compensation", action=argparse.BooleanOptionalAction, default=None,
                   help="pass --latency-compensation / --no-latency-compensation to every flight")
    p.add_argument("--timeout", type=positive_float, default=DEFAULT_CELL_TIMEOUT_S, metavar="S",
                   help=f"wall-clock limit of one flight, s (default {DEFAULT_CELL_TIMEOUT_S:g}); it is retried once, "
                        "then recorded as wall_timeout")
    p.add_argument("--firmware", choices=tuple(FIRMWARE_VEHICLES), default=DEFAULT_FIRMWARE,
                   help="the emulated vehicle's onboard side for every flight (see `cfstack fly --help`)")
    p.add_argument("--resume", action="store_true", help="skip the flights already in OUT/sweep.csv")
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


def _controller_axis(value: str) -> str:
    """A --controller value: a variant, or a user file made absolute (workers do not share our cwd)."""
    variant, spec = builtin_or_user_file(value, CONTROLLERS, "controller")
    return variant or _user_file(spec, "controller")


def _user_file(value: str, kind: str) -> str:
    path, name = split_spec(value, kind)
    return f"{path}:{name}"


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


def _number_axis(texts: list[str] | None, flag: str, maximum: float | None = None,
                 minimum: float = 0.0) -> tuple[float, ...] | None:
    if not texts:
        return None
    values = parse_number_list(texts, flag, maximum)
    if values[0] < minimum:
        raise UserError(f"{flag}: {num(values[0])} is below the minimum {num(minimum)}")
    return values


def parse_options(argv: Sequence[str]) -> SweepOptions:
    """Checked options; a one-line UserError for anything wrong."""
    args = build_parser().parse_args(_glue_extra(argv))
    extra = _check_extra(" ".join(args.extra))
    draws = tuple(dict.fromkeys(args.vehicle_draw or ["nominal"]))
    for world in args.worlds:
        # Fail now, not after the first flight: the same pre-flight check as fly (a start or goal inside a
        # block is refused, naming the file); fly itself moves a point on the bounds and warns.
        checked_world(load_world(world), load_vehicle(_vehicle_model(extra, args.firmware)).collision_radius_m)
    return SweepOptions(
        worlds=tuple(dict.fromkeys(args.worlds)) or (None,),
        modes=tuple(dict.fromkeys(args.mode)) if args.mode else MODES,
        radios=tuple(dict.fromkeys(args.radio or [DEFAULT_BASE_PROFILE])),
        latencies_ms=_number_axis(args.latency, "--latency"),
        losses_pct=_number_axis(args.loss, "--loss", maximum=PCT_PER_UNIT),
        jitters_ms=_number_axis(args.jitter, "--jitter"),
        bursts_frames=_number_axis(args.burst, "--burst", minimum=IID_BURST_FRAMES),
        controllers=tuple(dict.fromkeys(args.controller or [""])), vehicle_draws=draws,
        seeds=tuple(range(args.seed, args.seed + args.seeds)), jobs=args.jobs, out=Path(args.out),
        extra=extra, latency_compensation=args.latency_compensation, timeout_s=args.timeout, resume=args.resume,
        firmware=args.firmware, scheduler=args.scheduler, user_options=_user_options(args))


def _user_options(args) -> tuple[str, ...]:
    """--trajectory/--planner/--controller-output for every flight (user files made absolute)."""
    options: list[str] = []
    if args.trajectory is not None:
        builtin = args.trajectory in PLANNED_KINDS or not looks_like_path(args.trajectory)
        options += ["--trajectory", args.trajectory if builtin else _user_file(args.trajectory, "trajectory")]
    if args.planner is not None:
        options += ["--planner", _user_file(args.planner, "planner")]
    if args.controller_output is not None:
        options += ["--controller-output", args.controller_output]
    return tuple(options)


class ProgressBar:
    """`[#####.....] 12/70 flights  failed 1  retried 0  elapsed 3:12  ETA 14:30  dashboard URL` on stderr:
    redrawn in place on a terminal, one line per finished flight otherwise (logs, pipes)."""

    def __init__(self, total: int, already_done: int, dashboard: str, stream=None):
        self.total, self.done, self.started_done = total, already_done, already_done
        self.dashboard = dashboard
        self.progress = Progress()
        self.stream = stream if stream is not None else sys.stderr
        self.tty = self.stream.isatty()
        self.start_s = time.monotonic()

    def line(self) -> str:
        elapsed = time.monotonic() - self.start_s
        flown = self.done - self.started_done
        eta = elapsed / flown * (self.total - self.done) if flown > 0 else None
        return progress_line(self.done, self.total, elapsed, eta, self.progress, self.dashboard)

    def tick(self, progress: Progress) -> None:
        self.progress = progress
        if self.tty:
            self.stream.write("\r" + self.line())
            self.stream.flush()

    def flight_done(self, row: dict) -> None:
        self.done += 1
        if not self.tty:
            print(f"{self.line()}  {cell_of(row).label}: {row['result']}", file=self.stream, flush=True)

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


def progress_line(done: int, total: int, elapsed_s: float, eta_s: float | None, progress: Progress | None = None,
                  dashboard: str | None = None, width: int = BAR_WIDTH) -> str:
    filled = int(width * done / total) if total else width
    text = f"[{'#' * filled}{'.' * (width - filled)}] {done}/{total} flights"
    if progress is not None:
        text += f"  failed {progress.failed}  retried {progress.retried}"
        if progress.lost_workers:
            text += f"  lost workers {progress.lost_workers}"
    text += f"  elapsed {_clock(elapsed_s)}  ETA {_clock(eta_s)}"
    return text + (f"  dashboard {dashboard}" if dashboard else "")


def _jobs(opts: SweepOptions, cells: Sequence[Cell], bases: dict) -> list[CellJob]:
    worlds = {w: Path(w).read_text() for w in {c.world for c in cells} if w}
    options = [*opts.extra, *opts.user_options]
    if opts.latency_compensation is not None:
        options.append("--latency-compensation" if opts.latency_compensation else "--no-latency-compensation")
    jobs = []
    for cell in cells:
        fly_options = ["--mode", cell.mode, "--firmware", opts.firmware, "--vehicle-draw", cell.vehicle_draw]
        if cell.controller:
            fly_options += ["--controller", cell.controller]
        jobs.append(CellJob(cell, tuple(fly_options + options), worlds.get(cell.world),
                            cell_profile_text(bases[cell.radio], cell, opts), str((opts.out / "cells").resolve()),
                            opts.timeout_s))
    return jobs


@dataclass
class _Outputs:
    opts: SweepOptions
    rows: dict[tuple, dict] = field(default_factory=dict)

    @property
    def csv_path(self) -> Path:
        return self.opts.out / "sweep.csv"

    def add(self, row: dict) -> None:
        key = cell_of(row).key
        if key in self.rows and done(self.rows[key]) and not done(row):
            return  # a flown row is never replaced by a failed retry of a later run
        self.rows[key] = row
        write_tables(self.csv_path, self.rows.values())

    def finish(self) -> None:
        write_tables(self.csv_path, self.rows.values())
        rows = list(self.rows.values())
        png = plot_sweep(rows, self.opts, self.opts.out / "sweep.png")
        print(table_text(rows))
        print()
        for line in survival_lines(rows):
            print(line)
        print(f"table: {self.csv_path} and {self.csv_path.with_suffix('.parquet')}\nstability map: {png}")


def _check_resume(opts: SweepOptions) -> None:
    path = opts.out / "sweep.json"
    if not path.is_file():
        return
    try:
        previous = json.loads(path.read_text()).get("settings", {})
    except (OSError, json.JSONDecodeError, AttributeError) as err:
        raise UserError(f"{path}: unreadable ({err}); remove it or use another --out") from None
    for key, value in opts.settings().items():
        if previous.get(key) != value:
            raise UserError(f"--resume: {opts.out} was swept with {key} = {previous.get(key)!r}, not {value!r}; "
                            "use the same settings or another --out")


def command(argv: list[str]) -> int:
    """Entry point of `cfstack sweep`: 0 when every flight was flown, 130 after Ctrl-C; UserError on bad input."""
    opts = parse_options(argv)
    bases = {radio: load_base_profile(radio) for radio in opts.radios}
    if opts.out.exists() and not opts.out.is_dir():
        raise UserError(f"--out {opts.out}: exists and is not a folder")
    if opts.resume:
        _check_resume(opts)
    opts.out.mkdir(parents=True, exist_ok=True)
    outputs = _Outputs(opts)
    if opts.resume:
        outputs.rows = {cell_of(r).key: r for r in read_csv(outputs.csv_path)}
    (opts.out / "sweep.json").write_text(json.dumps({"settings": opts.settings()}, indent=2) + "\n")
    cells = grid_cells(opts, bases)
    todo = [c for c in cells if not (c.key in outputs.rows and done(outputs.rows[c.key]))]
    if not todo:
        print(f"cfstack sweep: all {len(cells)} flights are already in {outputs.csv_path}; nothing to fly",
              file=sys.stderr)
        outputs.finish()
        return 0
    runner = DaskRunner(opts)
    bar = ProgressBar(len(cells), len(cells) - len(todo), runner.dashboard)
    print(f"cfstack sweep: {len(todo)} flights on {runner.workers()} dask workers"
          f"{' at ' + opts.scheduler if opts.scheduler else ' (LocalCluster)'}; dashboard {runner.dashboard}",
          file=sys.stderr, flush=True)

    def flown(row: dict) -> None:
        outputs.add(row)
        bar.flight_done(row)

    interrupted = False
    try:
        runner.run(_jobs(opts, todo, bases), flown, bar.tick)
    except KeyboardInterrupt:
        interrupted = True
    except UserError:
        write_tables(outputs.csv_path, outputs.rows.values())
        raise
    finally:
        bar.close()
        runner.close()
    outputs.finish()
    if interrupted:
        print(f"cfstack sweep: interrupted after {bar.done} of {len(cells)} flights; the rest: rerun with --resume "
              f"--out {opts.out}", file=sys.stderr)
        return 130
    return 0
