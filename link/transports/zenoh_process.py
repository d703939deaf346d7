"""How zenoh runs in this process: its own threads (in the background or not) and the unicast transport its
sessions offer (zenoh's low-latency one or its universal one).

Takes in: the process's choice (`use_lockstep_settings`, before its first zenoh session opens: a lockstep
ground station or emulator asks for both, a realtime one for neither) and the environment variables
CFSTACK_ZENOH_THREADS (`background` | `normal`) and CFSTACK_ZENOH_TRANSPORT (`lowlatency` | `universal`),
which override it.
Gives out: `in_background()` and `offers_low_latency()`, what link.transports.zenoh_session's open goes by,
`to_background(tid)`, `check_environment()` for the command lines, and `let_woken_reader_run()`, which both
lockstep clocks call after the put the other process waits on (why, there).

Threads. In the background (Linux) means SCHED_BATCH, so a zenoh thread that wakes for a sample or a put never
preempts the thread running on its core, and niceness BACKGROUND_NICE, so it gives way to our Python threads
when they contend. It then runs on an idle core, or once the Python thread blocks, which in a lockstep flight
each process does every tick. Why: per thread, at 500 Hz, the ground station's loop thread was preempted 1.4
times per tick, and each process's zenoh threads woke 5-6 times per tick. Why only in lockstep: there a run's
speed is its throughput, and each tick waits on the other process anyway; in realtime a frame's wall-clock
latency is what counts, and it was worse in two of seven realtime flights with the background (README "Lockstep
speed"). It is never starved: four flights at once on two cores finished sooner, not later.

Transport. zenoh's low-latency unicast transport (transport/unicast/lowlatency, with QoS off as it requires)
writes each sample from the caller's thread, where the universal one hands it to zenoh's sending thread and
batches. `cfstack link-bench` measured it at ~20-30 us lower round trips on loopback, but a burst of many small
samples slower (25-45 k against 50-60 k frames/s), and it drops QoS priorities: which is why a realtime process
keeps zenoh's universal transport; in lockstep a tick's frames go out packed into
a few samples (simulator.publishing) and every tick waits on a round trip. Measured on this project's 2-core
machines (2026-11-27, throwaway scripts): a 60 B ping-pong between two processes, p50 137-174 us against 183-201;
`cfstack fly --trajectory circle` interleaved, 6 pairs per mode, moments 1.185x the real-time factor (6 of 6
faster), attitude 1.037x (6 of 6), states.csv unchanged. zenoh uses it only where both ends offer it (an
extension of its handshake): a peer that does not (a cflib script, a router, an older cfstack) gets the universal
transport on its own link, as before. It has no fragmentation (zenoh_session.LOW_LATENCY_MAX_SAMPLE_BYTES).
"""

from __future__ import annotations

import logging
import os

from model.errors import UserError

log = logging.getLogger("cfstack.link")

THREADS_ENV = "CFSTACK_ZENOH_THREADS"
THREADS_CHOICES = ("background", "normal")
TRANSPORT_ENV = "CFSTACK_ZENOH_TRANSPORT"
TRANSPORT_CHOICES = ("lowlatency", "universal")
BACKGROUND_NICE = 19  # the lowest priority a thread may take without privileges

_lockstep = False  # zenoh's own threads and transport, until the process asks


def use_lockstep_settings(lockstep: bool) -> None:
    """The process's choice, taken by the sessions it opens from now on (zenoh starts its threads at the
    first one): a lockstep process's zenoh threads in the background and its sessions offering the
    low-latency transport, or zenoh's own way for both."""
    global _lockstep
    _lockstep = lockstep


def _environment_choice(name: str, choices: tuple[str, ...]) -> str | None:
    """The variable's value (one of choices), None where it is not set; a one-line UserError for any other."""
    choice = os.environ.get(name)
    if choice is not None and choice not in choices:
        raise UserError(f"{name}={choice!r}: must be one of {', '.join(choices)}")
    return choice


def check_environment() -> None:
    """A one-line UserError for a value of THREADS_ENV or TRANSPORT_ENV that is not one of its choices (the
    command lines check before they start a process)."""
    _environment_choice(THREADS_ENV, THREADS_CHOICES)
    _environment_choice(TRANSPORT_ENV, TRANSPORT_CHOICES)


def in_background() -> bool:
    """Whether the sessions opened now put zenoh's threads in the background: THREADS_ENV if set, else the
    process's choice; never where the operating system has no SCHED_BATCH."""
    choice = _environment_choice(THREADS_ENV, THREADS_CHOICES)
    wanted = _lockstep if choice is None else choice == "background"
    return wanted and hasattr(os, "SCHED_BATCH")


def offers_low_latency() -> bool:
    """Whether the sessions opened now (without a config file, which decides alone) offer zenoh's low-latency
    transport: TRANSPORT_ENV if set, else the process's choice."""
    choice = _environment_choice(TRANSPORT_ENV, TRANSPORT_CHOICES)
    return _lockstep if choice is None else choice == "lowlatency"


def to_background(tid: int) -> None:
    """SCHED_BATCH and BACKGROUND_NICE for thread tid (Linux: both are a thread's own, and its new threads
    inherit them); a policy or a niceness the user gave the process (chrt, nice) is kept if already lower.
    Where the system refuses (a sandbox may), one warning, and the thread stays as it is: only speed is lost."""
    try:
        if os.sched_getscheduler(tid) == os.SCHED_OTHER:
            os.sched_setscheduler(tid, os.SCHED_BATCH, os.sched_param(0))
        os.setpriority(os.PRIO_PROCESS, tid, max(BACKGROUND_NICE, os.getpriority(os.PRIO_PROCESS, tid)))
    except OSError as err:
        log.warning("could not put zenoh's threads in the background (%s): they run as the process does; "
                    "%s=normal skips the attempt", err.strerror or err, THREADS_ENV)


def let_woken_reader_run() -> None:
    """Give this thread's CPU away once, right after a put that the other lockstep process is blocked on (the
    ground station's ack, the emulator's tick record). Why: Linux wakes the thread reading a Unix socket (the
    private endpoint of `cfstack fly`, link.transports.zenoh_session.PrivateEndpoint) with a hint that the
    writer is about to sleep, and so queues it on the writer's CPU. Our writer does not sleep: it goes on with
    its tick (the ground station's log row and truth after its ack, the emulator's next physics steps after
    its record), and a zenoh thread in the background never preempts it, so the sample waited behind that work
    while the other CPU idled: benchmarks/lockstep_hops.py measured the ack's hop at 242-308 us (medians, five of
    six attitude circles) against 44-64 us with this yield (README "Lockstep speed"). Where nothing else is ready to
    run on this CPU, sched_yield returns at once; where the system has none, this does nothing."""
    if _HAS_SCHED_YIELD:
        os.sched_yield()


_HAS_SCHED_YIELD = hasattr(os, "sched_yield")
