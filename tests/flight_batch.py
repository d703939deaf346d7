"""Many `cfstack fly` command lines flown a few at a time in long-lived worker processes, the way a script that
calls cfstack.fly in a loop flies them: each worker imports the ground station once, then runs the command's
own entry point (cfstack.cli.main: its parser, checks, one-line refusals and exit codes) for flight after
flight. Every flight still starts its own emulator child and flies it over zenoh, as the command does.

Why: a fresh `cfstack fly` process spends most of a CPU-second starting before it flies (`python -c "import
groundstation.session, groundstation.planned, groundstation.cli"`: 0.58-1.01 s on this project's 2-core
machines); the acceptance batches fly 66 lockstep flights, CPU-bound. The impaired batch took 69.3 s this way
against 103.5 s as `cfstack fly` processes (one run each, by hand, 2026-11-28).
tests/groundstation/test_impaired_flights.py checks that a flight flown here (by a worker that has flown others
before it) is the command's flight, byte for byte.

Takes in: command lines (the words after `cfstack fly`), keyed by the caller, and how many fly at once.
Gives out: per key (exit code, the --json summary or None, the tail of the flight's stderr).
"""

from __future__ import annotations

import json
import math
import multiprocessing
import os
import sys
import tempfile
import time
import traceback
from collections.abc import Hashable, Sequence
from concurrent.futures import ProcessPoolExecutor

STDERR_TAIL_CHARS = 2000
FLIGHT_TIMEOUT_S = 600  # per flight, as the batches' subprocess.run allowed; the batch's whole: per round


def _import_ground_station() -> None:
    """Each worker's start: what a fresh `cfstack fly` imports before its flight."""
    import groundstation.cli  # noqa: F401
    import groundstation.planned  # noqa: F401
    import groundstation.session  # noqa: F401


def _fly(argv: Sequence[str]) -> tuple[int, str, str]:
    """`cfstack fly ARGV` in this worker: exit code, stdout, stderr (captured at the file descriptors, so the
    log handler set up by an earlier flight, which holds the process's stderr, is captured too)."""
    from cfstack.cli import main

    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        sys.stdout.flush()
        sys.stderr.flush()
        saved = os.dup(1), os.dup(2)
        os.dup2(out.fileno(), 1)
        os.dup2(err.fileno(), 2)
        try:
            code = main(["fly", *argv])
        except BaseException:  # noqa: BLE001 - the harness reports whatever the command let escape
            traceback.print_exc()
            code = 1
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            os.close(saved[0])
            os.close(saved[1])
        out.seek(0)
        err.seek(0)
        return code, out.read().decode(), err.read().decode()


def fly_batch(flights: dict[Hashable, Sequence[str]], concurrent: int
              ) -> dict[Hashable, tuple[int, dict | None, str]]:
    """Each value's `cfstack fly` command line, `concurrent` at a time; per key (exit code, the --json summary
    or None, the tail of its stderr). Workers are started fresh (spawn), not forked from the test process; a
    worker that dies fails the batch at once (BrokenProcessPool), one that hangs at the deadline."""
    if not flights:
        return {}
    workers = min(concurrent, len(flights))
    deadline = time.monotonic() + FLIGHT_TIMEOUT_S * math.ceil(len(flights) / workers)
    pool = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"),
                               initializer=_import_ground_station)
    try:
        pending = {key: pool.submit(_fly, list(argv)) for key, argv in flights.items()}
        results = {}
        for key, future in pending.items():
            code, out, err = future.result(timeout=max(0.0, deadline - time.monotonic()))
            results[key] = code, (json.loads(out) if out.strip() else None), err[-STDERR_TAIL_CHARS:]
        return results
    finally:
        pool.shutdown(wait=False, cancel_futures=True)
        for worker in multiprocessing.active_children():  # a worker still flying past the deadline
            worker.kill()
