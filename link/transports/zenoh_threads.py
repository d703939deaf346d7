"""How zenoh's own threads run in this process: in the background, or as the process's own threads.

Takes in: the process's choice (`use_background_threads`, before its first zenoh session opens: a lockstep
ground station or emulator asks for the background, a realtime one does not) and the environment variable
CFSTACK_ZENOH_THREADS (`background` | `normal`), which overrides it.
Gives out: `in_background()`, what link.transports.zenoh_session's open goes by, and `to_background(tid)`.

In the background (Linux) means SCHED_BATCH, so a zenoh thread that wakes for a sample or a put never preempts
the thread running on its core, and niceness BACKGROUND_NICE, so it gives way to our Python threads when they
contend. It then runs on an idle core, or once the Python thread blocks, which in a lockstep flight each
process does every tick. Why: per thread, at 500 Hz, the ground station's loop thread was preempted 1.4 times
per tick, and each process's zenoh threads woke 5-6 times per tick. Why only in lockstep: there a run's speed is
its throughput, and each tick waits on the other process anyway; in realtime a frame's wall-clock latency is
what counts, and it was worse in two of seven realtime flights with the background (README "Lockstep speed").
It is never starved: four flights at once on two cores finished sooner, not later.
"""

from __future__ import annotations

import logging
import os

from model.errors import UserError

log = logging.getLogger("cfstack.link")

ENV = "CFSTACK_ZENOH_THREADS"
CHOICES = ("background", "normal")
BACKGROUND_NICE = 19  # the lowest priority a thread may take without privileges

_background = False  # zenoh's own way, until the process asks


def use_background_threads(background: bool) -> None:
    """The process's choice, taken by the sessions it opens from now on (zenoh starts its threads at the
    first one)."""
    global _background
    _background = background


def environment_choice() -> str | None:
    """ENV's value (one of CHOICES), None where it is not set; a one-line UserError for any other value (the
    command lines check it before they start a process)."""
    choice = os.environ.get(ENV)
    if choice is not None and choice not in CHOICES:
        raise UserError(f"{ENV}={choice!r}: must be one of {', '.join(CHOICES)}")
    return choice


def in_background() -> bool:
    """Whether the sessions opened now put zenoh's threads in the background: ENV if set, else the process's
    choice; never where the operating system has no SCHED_BATCH."""
    choice = environment_choice()
    wanted = _background if choice is None else choice == "background"
    return wanted and hasattr(os, "SCHED_BATCH")


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
                    "%s=normal skips the attempt", err.strerror or err, ENV)
