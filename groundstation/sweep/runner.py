"""The sweep's runner: each cell is one `cfstack fly` subprocess, at most --jobs at a time.

Takes in: SweepOptions and the (cell, radio profile file) pairs still to fly.
Gives out: a CellResult per cell as it finishes (on_done). Each cell is
`cfstack fly WORLD --mode M --radio PROFILE --clock lockstep --seed N --json --log DIR` in its own
process session (lockstep + seed: the same cell gives the same flight on a busy machine), its stdout and
stderr kept in the cell's log folder. A fly that exits with code 2 (bad input) aborts the sweep with its
one-line error; a crash, a timeout or a failsafe is a normal, failed cell. A KeyboardInterrupt stops
every running flight before it propagates.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from groundstation.child_process import die_with_parent
from groundstation.sweep.grid import Cell, SweepOptions
from groundstation.sweep.table import CellResult
from model.errors import UserError

POLL_S = 0.2  # how often the scheduler looks at its children and redraws the bar
SECOND_SIGINT_AFTER_S = 0.5  # fly lands on the first Ctrl-C and disarms at once on the second
STOP_GRACE_S = 10.0  # after the second SIGINT, how long a fly child gets to stop its emulator and exit
BAD_INPUT_EXIT_CODE = UserError.exit_code  # what `cfstack fly` returns for bad input (2)


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
    failure = summary.get("failure") or {}  # a crash's or failsafe's one line (groundstation.grading)
    collided = summary.get("collided") is True
    # Stopped for its timeout, fly may still land and print a summary ("aborted"): the cell timed out.
    return CellResult(
        cell, success=reached and not collided and exit_code == 0 and not timed_out,
        result="timeout" if timed_out else str(summary["result"]),
        reached_goal=reached, collided=collided, reason=failure.get("reason") or summary.get("failsafe_reason"),
        rms_tracking_error_m=_float_or_none(summary.get("rms_tracking_error_m")),
        max_tracking_error_m=_float_or_none(summary.get("max_tracking_error_m")),
        min_clearance_m=_float_or_none(summary.get("min_clearance_m")),
        flight_time_s=_float_or_none(summary.get("flight_time_s")),
        wall_time_s=wall_s, exit_code=exit_code, log_dir=str(log_dir))


def fly_argv(opts: SweepOptions, cell: Cell, profile: Path, log_dir: Path) -> list[str]:
    """The `cfstack fly` command line of one cell (run as `python -m cfstack`, the same program)."""
    argv = [sys.executable, "-m", "cfstack", "fly"]
    if opts.world:
        argv.append(str(Path(opts.world).resolve()))
    argv += ["--mode", cell.mode, "--radio", str(profile.resolve()), "--clock", "lockstep",
             "--seed", str(opts.seed), "--firmware", opts.firmware,
             "--vehicle-draw", opts.vehicle_draw, "--json", "--log", str(log_dir.resolve())]
    if opts.latency_compensation is not None:
        argv.append("--latency-compensation" if opts.latency_compensation else "--no-latency-compensation")
    return argv + list(opts.extra)


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
                                    stderr=err, start_new_session=True, preexec_fn=die_with_parent)
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
