"""Run one `cfstack fly` in this process with the ground station's parts timed (loop_bench section 1).

Takes in: an output JSON path, then the `cfstack` arguments (`fly ...`). The cfstack that runs is whichever is
first on sys.path, so loop_bench runs this file against the working tree and against a git baseline
(PYTHONPATH = an extracted older revision) alike; the emulator child inherits the same path.
Gives out: {part: wall seconds} in the JSON file, plus "ticks" and the fly summary's timing. Each part's
time is exclusive (a timed call inside another timed call counts only for the inner part), so the parts
add up to at most the loop's wall time; "other" is the rest of the loop (mission, bookkeeping).

Parts, by the classes' method names (present in every revision since issue 4):
- waiting: the lockstep clock waiting for the emulator's tick, taking raw samples and acking (zenoh);
- codec: decoding the tick's frames and encoding/sending ours (with their tlog records);
- estimator: the ESKF taking IMU samples and mocap poses and forming its estimate;
- controller: the SE(3) law and the latency compensator's prediction;
- mission: the mission's state machine and the vehicle view it reads;
- logging: the tick's log row, flight record and tlog writes (after the ack: overlaps the emulator).
A method a revision does not have is skipped (its work then shows under "other").
"""

from __future__ import annotations

import json
import sys
import time
from contextlib import redirect_stdout
from io import StringIO

PARTS = {
    "waiting": [("groundstation.clocks", "LockstepClock", "_next_tick"),
                ("groundstation.clocks", "LockstepClock", "release"),
                ("groundstation.vehicle_link", "VehicleLink", "fetch")],
    "codec": [("groundstation.vehicle_link", "VehicleLink", "deliver"),
              ("groundstation.vehicle_link", "VehicleLink", "take_truth"),
              ("groundstation.vehicle_link", "VehicleLink", "send")],
    "estimator": [("estimator.eskf", "ErrorStateKF", "add_imu"), ("estimator.eskf", "ErrorStateKF", "add_mocap"),
                  ("estimator.eskf", "ErrorStateKF", "estimate")],
    "controller": [("groundstation.controller", "SE3Controller", "update"),
                   ("groundstation.compensation", "LatencyCompensator", "predict"),
                   ("groundstation.compensation", "LatencyCompensator", "record")],
    "mission": [("groundstation.mission", "Mission", "update"), ("groundstation.flight", "FlightLoop", "view")],
    "logging": [("groundstation.flight", "FlightLoop", "write_row"),
                ("groundstation.vehicle_link", "VehicleLink", "flush_logs")],
}


def install(totals: dict[str, float]) -> None:
    """Wrap each part's methods on their classes with exclusive wall-time accounting."""
    import importlib

    clock = time.perf_counter
    stack: list[float] = []  # time spent in nested timed calls, per open call
    # count from the first tick's start (TickTimer.start, where the loop's wall time starts too) to the
    # end of FlightLoop.run: the handshake and the wait for the emulator to boot are not a tick's work
    flying = [False]

    def timed(fn, part):
        def wrapper(*args, **kwargs):
            if not flying[0]:
                return fn(*args, **kwargs)
            stack.append(0.0)
            start = clock()
            try:
                return fn(*args, **kwargs)
            finally:
                spent = clock() - start
                inner = stack.pop()
                totals[part] += spent - inner
                if stack:
                    stack[-1] += spent
        return wrapper

    def first_tick(fn):
        def wrapper(*args, **kwargs):
            flying[0] = True
            return fn(*args, **kwargs)
        return wrapper

    def run(fn):
        def wrapper(*args, **kwargs):
            try:
                return fn(*args, **kwargs)
            finally:
                flying[0] = False
        return wrapper

    loop = importlib.import_module("groundstation.flight").FlightLoop
    loop.run = run(loop.run)
    timer = importlib.import_module("groundstation.clocks").TickTimer
    timer.start = first_tick(timer.start)
    for part, methods in PARTS.items():
        totals.setdefault(part, 0.0)
        for module, cls, name in methods:
            owner = getattr(importlib.import_module(module), cls)
            if hasattr(owner, name):
                setattr(owner, name, timed(getattr(owner, name), part))


def main() -> int:
    out, argv = sys.argv[1], sys.argv[2:]
    totals: dict[str, float] = {}
    install(totals)
    from cfstack.cli import main as cfstack_main

    printed = StringIO()
    with redirect_stdout(printed):
        code = cfstack_main([*argv, "--json"])
    summary = json.loads(printed.getvalue())
    timing = summary["timing"]
    result = {"parts_s": totals, "ticks": timing["ticks"], "loop_wall_s": timing["loop_wall_s"],
              "sim_time_s": summary["sim_time_s"], "result": summary["result"], "exit": code}
    with open(out, "w") as f:
        json.dump(result, f)
    return 0


if __name__ == "__main__":
    sys.exit(main())
