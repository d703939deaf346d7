"""Calling user code safely: time each call, stop a call that hangs, turn any failure into one Fault.

Takes in: the user's callable and its arguments, the call budget (usercode.toml call_timeout_s), the flight
clock's kind and control period (a realtime call longer than the period is an overrun).
Gives out: the call's result, or a CallFailed carrying one line (file, method, simulated time, problem);
per-call wall times (p50/p99 for the summary) and the overrun count.
A hung call is interrupted with SIGALRM (an interval timer armed per call), on the main thread only: on
any other thread the budget is checked after the call returns. A call blocked inside C code is
interrupted when it next runs Python.
"""

from __future__ import annotations

import logging
import math
import signal
import threading
import time
from array import array
from dataclasses import dataclass
from pathlib import Path

from groundstation.usercode.loader import describe_error

log = logging.getLogger("cfstack.usercode")


class _CallTimeout(BaseException):
    """Raised inside a user call that ran past its budget (a BaseException: `except Exception` in the
    user's code does not swallow it)."""


class CallFailed(Exception):
    """A user call failed; str() is the problem, without the where."""


@dataclass(frozen=True)
class Fault:
    """The first failure of user code in a flight."""

    where: str  # "se3_control.py SE3Control.update"
    t_s: float  # simulated (flight clock) time of the call
    problem: str

    def line(self) -> str:
        return (f"user code {self.where} at t={self.t_s:.3f} s: {self.problem}; the vehicle holds, then lands "
                "(cfstack's own controller flies the failsafe)")


class CallTimes:
    """Wall time of every call of one user method, seconds."""

    def __init__(self, name: str):
        self.name = name
        self.seconds = array("d")

    def summary(self) -> dict:
        if not self.seconds:
            return {"calls": 0}
        ordered = sorted(self.seconds)

        def pick(q: float) -> float:
            return ordered[min(len(ordered) - 1, math.ceil(q * len(ordered)) - 1)] * 1e3

        return {"calls": len(ordered), "p50_ms": pick(0.5), "p99_ms": pick(0.99), "max_ms": ordered[-1] * 1e3}


class Guard:
    """Runs user calls with a budget; the first failure is kept (later ones are not made: callers stop
    calling user code once `fault` is set)."""

    def __init__(self, timeout_s: float, directories: list[Path], realtime_period_s: float | None = None):
        self.timeout_s = timeout_s
        self.directories = directories  # the user's files' folders: error lines point into them
        self.realtime_period_s = realtime_period_s  # None in lockstep: slow calls only slow the run
        self.fault: Fault | None = None
        self.overruns = 0
        self._use_alarm = hasattr(signal, "setitimer") and threading.current_thread() is threading.main_thread()
        self._previous_handler = None

    def __enter__(self) -> Guard:
        if self._use_alarm:
            self._previous_handler = signal.signal(signal.SIGALRM, _raise_timeout)
        return self

    def __exit__(self, *exc) -> None:
        if self._use_alarm:
            signal.setitimer(signal.ITIMER_REAL, 0.0)
            signal.signal(signal.SIGALRM, self._previous_handler or signal.SIG_DFL)

    def call(self, times: CallTimes, t_s: float, fn, *args):
        """fn(*args), timed; CallFailed with the problem on an exception or a hang."""
        armed = self._use_alarm and signal.getsignal(signal.SIGALRM) is _raise_timeout
        start = time.perf_counter()
        try:
            if armed:
                signal.setitimer(signal.ITIMER_REAL, self.timeout_s)
            try:
                return fn(*args)
            finally:
                if armed:
                    signal.setitimer(signal.ITIMER_REAL, 0.0)
        except _CallTimeout:
            raise CallFailed(f"the call did not return within {self.timeout_s:g} s (usercode.toml "
                             "call_timeout_s)") from None
        except Exception as err:  # noqa: BLE001 - whatever user code raises is its fault, reported in one line
            raise CallFailed(f"raised {describe_error(err, self.directories)}") from None
        finally:
            elapsed = time.perf_counter() - start
            times.seconds.append(elapsed)
            self._check_time(times, t_s, elapsed)

    def _check_time(self, times: CallTimes, t_s: float, elapsed_s: float) -> None:
        if not self._use_alarm and elapsed_s > self.timeout_s and self.fault is None:
            raise CallFailed(f"the call took {elapsed_s:.3f} s, over {self.timeout_s:g} s (usercode.toml "
                             "call_timeout_s)")
        if self.realtime_period_s is not None and elapsed_s > self.realtime_period_s:
            self.overruns += 1
            if self.overruns == 1:
                log.warning("user code %s took %.1f ms at t=%.3f s, over the %.1f ms control period: the vehicle "
                            "gets its commands late (counted in the summary)", times.name, elapsed_s * 1e3, t_s,
                            self.realtime_period_s * 1e3)

    def record(self, where: str, t_s: float, problem: str) -> Fault:
        if self.fault is None:
            self.fault = Fault(where, t_s, problem)
        return self.fault


def _raise_timeout(signum, frame) -> None:  # noqa: ARG001
    raise _CallTimeout()
