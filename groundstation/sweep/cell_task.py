"""One sweep cell, run where a dask worker runs it: a whole lockstep flight on that machine's loopback.

Takes in: a CellJob (the cell, the `cfstack fly` options, the world file's and the radio profile's text,
the folder for the cell's logs on the worker's machine, the wall-clock limit). The texts travel with the
job, so a worker on another machine needs only `pip install` of this project.
Gives out: a plain dict (picklable, no cfstack types): the flight's outcome, tracking error, clearance,
link statistics and the cell's status: "flown" (fly printed a summary), "crash" (it printed none),
"wall_timeout" (stopped at the limit) or "bad_input" (fly exited with code 2: the sweep stops).
Each flight is `python -m cfstack fly WORLD --radio PROFILE --clock lockstep --seed N --json --log DIR`
in a process session of its own (lockstep + seed: the same cell gives the same flight on any worker).
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from distributed import get_worker

from groundstation.child_process import die_with_parent
from groundstation.sweep.grid import Cell
from model.errors import UserError

SECOND_SIGINT_AFTER_S = 0.5  # fly lands on the first Ctrl-C and disarms at once on the second
STOP_GRACE_S = 10.0  # after the second SIGINT, how long a fly child gets to stop its emulator and exit
BAD_INPUT_EXIT_CODE = UserError.exit_code  # what `cfstack fly` returns for bad input (2)
WAIT_POLL_S = 0.2


@dataclass(frozen=True)
class CellJob:
    cell: Cell
    fly_options: tuple[str, ...]  # mode, firmware, draw, controller, extra: everything but world/radio/log
    world_text: str | None  # the world JSON, or None for fly's empty room
    profile_text: str  # the cell's radio profile TOML
    cells_dir: str  # where cell folders go on the worker's machine
    timeout_s: float
    attempt: int = 1


def _number(value) -> float | None:
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else None


def _last_line(text: str) -> str:
    lines = [line for line in text.strip().splitlines() if line.strip()]
    return lines[-1].strip() if lines else ""


def _ratio(delivered, sent) -> float | None:
    return delivered / sent if isinstance(sent, int) and sent > 0 and isinstance(delivered, int) else None


def outcome_from_fly(exit_code: int | None, stdout: str, stderr: str, timed_out: bool) -> dict:
    """The measured part of a row, from fly's exit code, JSON summary and last stderr line."""
    if exit_code == BAD_INPUT_EXIT_CODE and not timed_out:
        return {"cell_status": "bad_input", "success": False, "result": "bad_input",
                "reason": _last_line(stderr) or "cfstack fly exited with code 2 (bad input)"}
    try:
        summary = json.loads(stdout) if stdout.strip() else None
    except json.JSONDecodeError:
        summary = None
    if not isinstance(summary, dict) or "result" not in summary:
        status = "wall_timeout" if timed_out else "crash"
        return {"cell_status": status, "success": False, "result": status, "reason": _last_line(stderr)[:200] or None}
    reached, collided = summary.get("reached_goal") is True, summary.get("collided") is True
    failure = summary.get("failure") or {}  # a crash's or failsafe's one line (groundstation.grading)
    link = summary.get("link") or {}
    return {
        # Stopped at the wall-clock limit, fly may still land and print a summary: the cell timed out.
        "cell_status": "wall_timeout" if timed_out else "flown",
        "success": reached and not collided and exit_code == 0 and not timed_out,
        "result": "wall_timeout" if timed_out else str(summary["result"]),
        "reached_goal": reached, "collided": collided,
        "reason": failure.get("reason") or summary.get("failsafe_reason"),
        **{k: _number(summary.get(k)) for k in ("rms_tracking_error_m", "max_tracking_error_m", "min_clearance_m",
                                                 "flight_time_s")},
        "uplink_delivery": _ratio(link.get("uplink_delivered"), link.get("uplink_sent")),
        "downlink_delivery": _ratio(link.get("downlink_delivered"), link.get("downlink_sent")),
        "rtt_ms_p50": _number(link.get("rtt_ms_p50")), "rtt_ms_p99": _number(link.get("rtt_ms_p99")),
    }


def _stop(proc: subprocess.Popen) -> None:
    """Ctrl-C twice to fly alone (it lands, then disarms, then stops its own emulator), then SIGKILL to its
    process group. Not SIGINT to the group: a lockstep emulator stopped first would leave fly waiting."""
    for _ in range(2):
        if proc.poll() is not None:
            return
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=SECOND_SIGINT_AFTER_S)
        except subprocess.TimeoutExpired:
            pass
    try:
        proc.wait(timeout=STOP_GRACE_S)
    except subprocess.TimeoutExpired:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        proc.wait()


def fly_argv(job: CellJob, folder: Path) -> list[str]:
    """The `cfstack fly` command line of one cell (run as `python -m cfstack`, the same program)."""
    argv = [sys.executable, "-m", "cfstack", "fly"]
    if job.world_text is not None:
        argv.append(str(folder / "world.json"))
    return argv + ["--radio", str(folder / "radio.toml"), "--clock", "lockstep", "--seed", str(job.cell.seed),
                   "--json", "--log", str(folder / "flight"), *job.fly_options]


STARTED_TOPIC = "cfstack-cell-started"  # event each flight logs as it starts: the client's view of what runs where


def _announce_start(job: CellJob) -> None:
    """Tell the client (through the scheduler's event log) which worker is flying this job now: the
    scheduler's own assignment also counts flights merely queued on a worker."""
    try:
        worker = get_worker()
    except ValueError:  # called outside a worker (tests)
        return
    worker.log_event(STARTED_TOPIC, {"key": job_key(job), "worker": worker.address})


def job_key(job: CellJob) -> str:
    return f"cfstack-cell-{job.cell.slug}-attempt{job.attempt}"


def fly_cell(job: CellJob) -> dict:
    """Fly one cell on this machine; the row's measured fields (see the module docstring)."""
    _announce_start(job)
    folder = Path(job.cells_dir) / job.cell.slug
    folder.mkdir(parents=True, exist_ok=True)
    if job.world_text is not None:
        (folder / "world.json").write_text(job.world_text)
    (folder / "radio.toml").write_text(job.profile_text)
    stdout_path, stderr_path = folder / "fly_stdout.json", folder / "fly_stderr.txt"
    started = time.monotonic()
    # Files, not pipes: a pipe nobody reads during a flight could fill and stall it. A session of its own:
    # a Ctrl-C at the worker's terminal reaches the worker, which stops each flight in order.
    with stdout_path.open("w") as out, stderr_path.open("w") as err:
        proc = subprocess.Popen(fly_argv(job, folder), stdin=subprocess.DEVNULL, stdout=out, stderr=err,
                                start_new_session=True, preexec_fn=die_with_parent)
    timed_out = False
    try:
        while proc.poll() is None:
            if time.monotonic() - started > job.timeout_s:
                timed_out = True
                break
            time.sleep(WAIT_POLL_S)
    finally:
        _stop(proc)
    outcome = outcome_from_fly(proc.returncode, stdout_path.read_text(), stderr_path.read_text(), timed_out)
    return {**outcome, "exit_code": proc.returncode, "wall_time_s": time.monotonic() - started,
            "worker": socket.gethostname(), "log_dir": str(folder)}
