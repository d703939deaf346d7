"""The sweep's runner: cells as tasks on dask.distributed, each a whole lockstep flight on its worker.

Takes in: SweepOptions (--jobs for a LocalCluster, or --scheduler tcp://HOST:PORT of a running cluster)
and the CellJobs still to fly.
Gives out: a row per flight as it finishes (on_row), progress counts (on_tick), the dashboard address.

Retries. A flight that gave no summary (crash), hit the wall-clock limit, raised, or whose worker was lost
is flown once more; its row says how many attempts it took and whether a worker was lost. The row of a
flight that fails again records the failure ("crash", "wall_timeout", "lost_worker", "error"). A cell whose
fly exits with code 2 (bad input) stops the sweep with fly's one-line error. A KeyboardInterrupt cancels
what is queued; running flights on a LocalCluster stop with their workers (each fly dies with its parent).
"""

from __future__ import annotations

import logging
import socket
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from urllib.parse import urlsplit

from distributed import Client, Future, LocalCluster

from groundstation.sweep.cell_task import STARTED_TOPIC, CellJob, fly_cell, job_key
from groundstation.sweep.grid import SweepOptions
from groundstation.sweep.table import make_row
from model.errors import UserError

POLL_S = 0.25  # how often the client looks at its futures and redraws the bar
RESULT_WAIT_S = 10.0  # longest wait for a finished flight's result (its worker may have just died with it)
CONNECT_TIMEOUT_S = 20.0
MAX_ATTEMPTS = 2  # the first flight and one retry
RETRIED_STATUSES = ("crash", "wall_timeout")
log = logging.getLogger("cfstack.sweep")


def _check_reachable(address: str) -> None:
    """Fail at once, in one line, when nothing listens there (dask's client would retry until its timeout)."""
    parsed = urlsplit(address if "://" in address else f"tcp://{address}")
    try:
        host, port = parsed.hostname, parsed.port
    except ValueError:
        port = None
    if parsed.scheme != "tcp" or not host or port is None:
        raise UserError(f"--scheduler {address}: expected tcp://HOST:PORT (e.g. tcp://127.0.0.1:8786)")
    try:
        socket.create_connection((host, port), timeout=CONNECT_TIMEOUT_S).close()
    except OSError as err:
        raise _no_scheduler(address, err.strerror or err) from None


def _no_scheduler(address: str, why) -> UserError:
    return UserError(f"--scheduler {address}: no dask scheduler answered ({why}); start one with `dask scheduler` "
                     "and a worker with `dask worker ADDRESS`")


def _connect(address: str) -> Client:
    """A client of the running scheduler at `address` that has at least one worker; one-line UserError if not."""
    _check_reachable(address)
    try:
        client = Client(address, timeout=CONNECT_TIMEOUT_S)
    except (OSError, TimeoutError, ValueError) as err:
        raise _no_scheduler(address, err) from None
    try:
        client.wait_for_workers(1, timeout=CONNECT_TIMEOUT_S)
    except TimeoutError:
        client.close()
        raise UserError(f"--scheduler {address}: the scheduler has no worker after {CONNECT_TIMEOUT_S:g} s; start "
                        "one with `dask worker ADDRESS`") from None
    return client


@dataclass
class Progress:
    done: int = 0
    failed: int = 0  # rows whose flight did not succeed (any reason)
    retried: int = 0  # flights started again (crash, wall-clock timeout, error or lost worker)
    lost_workers: int = 0  # workers that left the cluster while flying one of ours


@dataclass
class _Flight:
    job: CellJob
    future: Future
    worker: str | None = None  # where it said it started
    worker_lost: bool = False
    previous_lost: bool = False


@dataclass
class DaskRunner:
    opts: SweepOptions
    client: Client = field(init=False)
    cluster: LocalCluster | None = field(init=False, default=None)
    # task key -> the workers it started on, in order: dask flies a task again when its worker left before
    # the client had its result, even after it finished there
    started_on: dict[str, list[str]] = field(init=False, default_factory=dict)
    lost_workers: set[str] = field(init=False, default_factory=set)  # workers that left while flying ours
    _missing_once: set[str] = field(init=False, default_factory=set)  # flying workers the last look missed

    def __post_init__(self) -> None:
        if self.opts.scheduler:
            self.client = _connect(self.opts.scheduler)
        else:
            # One single-threaded worker process per flight slot: a flight is two busy processes of its own.
            self.cluster = LocalCluster(n_workers=self.opts.jobs, threads_per_worker=1, processes=True,
                                        dashboard_address="127.0.0.1:0", silence_logs=logging.ERROR)
            self.client = Client(self.cluster)
        self._listen()

    def _listen(self) -> None:
        def started(event) -> None:  # runs on the client's event loop: (time, message)
            message = event[1]
            self.started_on.setdefault(message["key"], []).append(message["worker"])

        self.client.subscribe_topic(STARTED_TOPIC, started)

    @property
    def dashboard(self) -> str:
        try:
            return self.client.dashboard_link
        except Exception:  # noqa: BLE001 -- no dashboard (bokeh missing on the scheduler): say so, don't fail
            return "not available"

    def workers(self) -> int:
        return len(self.client.scheduler_info().get("workers", {}))

    def close(self) -> None:
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()

    def _submit(self, job: CellJob) -> Future:
        return self.client.submit(fly_cell, job, key=job_key(job), pure=False)

    def run(self, jobs: Sequence[CellJob], on_row: Callable[[dict], None],
            on_tick: Callable[[Progress], None] = lambda p: None) -> Progress:
        """Fly every job; on_row(row) as each finishes (after its retry, if any)."""
        progress = Progress()
        flights = [_Flight(job, self._submit(job)) for job in jobs]
        try:
            while flights:
                self._watch_workers(flights, progress)
                for flight in [f for f in flights if f.future.done()]:
                    flights.remove(flight)
                    again = self._finish(flight, on_row, progress)
                    if again is not None:
                        flights.append(again)
                on_tick(progress)
                if flights:
                    time.sleep(POLL_S)
        finally:
            if flights:
                self.client.cancel([f.future for f in flights], force=True)
        return progress

    def _watch_workers(self, flights: list[_Flight], progress: Progress) -> None:
        """A flight whose worker left the cluster after it started flying there lost its worker. A worker
        has left when two looks in a row (POLL_S apart) miss it: one look can come back without a worker
        that is there (seen in CI: a snapshot taken while the scheduler removed another worker listed
        neither). Progress counts each lost worker once, however many flights it took down."""
        alive = set(self.client.scheduler_info().get("workers", {}))
        for flight in flights:
            flown_on = self.started_on.get(flight.future.key)
            if flown_on:
                flight.worker = flown_on[-1]  # where it flies now
        missing = {f.worker for f in flights if f.worker is not None and f.worker not in alive}
        gone, self._missing_once = missing & self._missing_once, missing
        for flight in flights:
            if flight.worker in gone and not flight.worker_lost:
                self._lose(flight, [flight.worker], progress)

    def _flown_on(self, flight: _Flight) -> list[str]:
        """The workers it started on, in order (a copy: the client's event loop appends to the list)."""
        return list(self.started_on.get(flight.future.key, ()))

    def _lose(self, flight: _Flight, workers: Sequence[str], progress: Progress) -> None:
        flight.worker_lost = True
        self.lost_workers.update(workers)
        progress.lost_workers = len(self.lost_workers)
        log.warning("worker %s lost while flying %s", ", ".join(workers), flight.job.cell.label)

    def _finish(self, flight: _Flight, on_row: Callable[[dict], None], progress: Progress) -> _Flight | None:
        """Record a finished future; or start its retry and return it; or return the flight itself when
        it is not finished after all (its result died with its worker: dask flies it again)."""
        job = flight.job
        error = None
        try:
            # When the worker holding the result has just died, dask's gather fails ("Couldn't gather 1
            # keys, rescheduling", seen in CI) and the future is pending again until another worker flew it.
            measured = flight.future.result(timeout=RESULT_WAIT_S)
        except Exception as raised:  # noqa: BLE001 -- the task raised, or dask gave up on it (KilledWorker)
            if flight.future.status not in ("error", "cancelled"):
                return flight  # not finished: watched again from the run loop
            error = raised
        flown_on = self._flown_on(flight)
        if len(flown_on) > 1 and not flight.worker_lost:  # its worker left after it had started it
            self._lose(flight, flown_on[:-1], progress)
        if error is not None:
            status = "lost_worker" if flight.worker_lost or type(error).__name__ == "KilledWorker" else "error"
            measured = {"cell_status": status, "success": False, "result": status,
                        "reason": f"{type(error).__name__}: {error}"[:200]}
            retry = True
        else:
            if measured.get("cell_status") == "bad_input":
                raise UserError(f"cell {job.cell.label}: {measured.get('reason')}")
            retry = measured.get("cell_status") in RETRIED_STATUSES
        lost = flight.worker_lost or flight.previous_lost
        if retry and job.attempt < MAX_ATTEMPTS:
            progress.retried += 1
            again = replace(job, attempt=job.attempt + 1)
            return _Flight(again, self._submit(again), previous_lost=lost)
        # A flight dask flew again by itself (its worker left) was flown once more per start. A worker seen
        # leaving mid-flight counts one more even if the new start's event has not reached us yet.
        reruns = max(len(flown_on) - 1, int(flight.worker_lost and error is None))
        row = make_row(job.cell, measured, attempts=job.attempt + reruns, worker_lost=lost)
        progress.done += 1
        progress.failed += 0 if row["success"] else 1
        on_row(row)
        return None
