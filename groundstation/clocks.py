"""The flight loop's clocks: realtime (monotonic wall clock) and lockstep (the emulator's sim clock).

Takes in: the loop period; for lockstep, the clock transport and the vehicle link (to count frames).
Gives out: `wait()` -> the time of the tick to compute (s); `release(next_wakeup_s)` as soon as the
tick's commands are sent (lockstep: the ack, so the emulator steps on while the tick's bookkeeping and
log row are written); `done()` when the tick's work is finished; tick timing statistics (tick duration,
lateness, deadline misses).
"""

from __future__ import annotations

import logging
import time
from collections import deque

import numpy as np

from link.clock import NS_PER_S, ClockAck, unpack_tick
from link.transports.zenoh_process import let_woken_reader_run
from model.errors import UserError

log = logging.getLogger("cfstack.groundstation")
# The flight loop's rate per command mode unless --rate says otherwise (position: the firmware's POSITION_RATE).
DEFAULT_RATE_HZ = {"moments": 500.0, "attitude": 100.0, "position": 100.0}


class TickTimer:
    """Measures how long each tick's work takes and whether it met its deadline."""

    def __init__(self, period_s: float):
        self.period_s = period_s
        self.work_s: list[float] = []
        self.misses = 0
        self._t0 = 0.0
        self.first_start: float | None = None  # perf_counter of the first tick's start
        self.last_stop: float | None = None

    def start(self) -> None:
        self._t0 = time.perf_counter()
        if self.first_start is None:
            self.first_start = self._t0

    def stop(self) -> float:
        self.last_stop = time.perf_counter()
        work = self.last_stop - self._t0
        self.work_s.append(work)
        if work > self.period_s:
            self.misses += 1
        return work

    def summary(self) -> dict:
        w = np.array(self.work_s or [0.0]) * 1e3
        loop_s = None if self.first_start is None else self.last_stop - self.first_start
        return {"ticks": len(self.work_s), "tick_ms_p50": float(np.percentile(w, 50)),
                "tick_ms_p99": float(np.percentile(w, 99)), "deadline_misses": self.misses,
                "deadline_miss_rate": self.misses / max(1, len(self.work_s)),
                "loop_wall_s": loop_s}  # from the first tick's start to the last tick's end


class RealtimeClock:
    """Ticks at a fixed period of the monotonic clock; t = seconds since start()."""

    kind = "realtime"

    def __init__(self, period_s: float, link):
        self.period_s = period_s
        self.link = link
        self.timer = TickTimer(period_s)
        self.late_ticks = 0
        self.ticks = 0

    def start(self) -> None:
        self.t0 = time.monotonic()
        self.next_s = 0.0

    def now(self) -> float:
        return time.monotonic() - self.t0

    def wait(self) -> float:
        while True:
            remaining = self.next_s - self.now()
            if remaining <= 0:
                break
            self.link.pump(min(remaining, 0.002))
        if -remaining > self.period_s:  # a whole period late: skip ahead rather than burst
            self.late_ticks += 1
            self.next_s = self.now()
        t = self.next_s
        self.next_s += self.period_s
        self.ticks += 1
        self.link.pump(0.0)
        self.timer.start()
        return t

    def release(self, next_wakeup_s: float) -> None:
        """Nothing to tell anyone: the period decides the next tick."""

    def done(self) -> None:
        self.timer.stop()

    def leave(self) -> None:
        pass

    def achieved_rate_hz(self) -> float:
        elapsed = self.now()
        return self.ticks / elapsed if elapsed > 0 else 0.0


def _cpu_times_s() -> tuple[float, float]:
    """CPU seconds so far of the process (all its threads) and of the calling thread (the flight loop's)."""
    return time.process_time(), time.thread_time()


class LockstepClock:
    """Follows the emulator's simulation clock; t is simulation time from the tick."""

    kind = "lockstep"

    def __init__(self, period_s: float, link, clock_transport, wait_timeout_s: float = 30.0, peer_failure=None):
        """`peer_failure()`: None while the emulator we started is alive, else why it stopped.
        Every ack carries the period as a standing order (ClockAck.period_ns): the loop always asks for
        the next tick one period after the current one, which lets the emulator publish a tick before
        the previous one's ack arrives whenever its lookahead allows."""
        self.period_s = period_s
        self.period_ns = round(period_s * NS_PER_S)
        self._ticks: deque = deque()  # tick records received ahead of the one being computed
        self.link = link
        self.transport = clock_transport
        self.wait_timeout_s = wait_timeout_s
        self.peer_failure = peer_failure or (lambda: None)
        self.timer = TickTimer(period_s)
        self.tick = -1
        self.t_s = 0.0
        self.ticks = 0
        # The lockstep's critical path per tick: from the tick's record being taken to its ack being sent
        # (the tick's frames decoded, estimator, mission, controller, commands sent). The emulator waits
        # for the ack before it steps past the next tick, so this is what the ground station adds to
        # each simulated tick (benchmarks/loop_bench.py); the rest of the tick overlaps the emulator.
        self.ack_after_tick_s: list[float] = []
        self._tick_taken_s = 0.0
        # Who waits for whom, from the first tick on: ticks whose record was already in when the loop asked
        # for it (the ground station is then the bottleneck, and all its work per tick counts, not only the
        # critical path), the wall time spent blocked waiting for records, and the CPU time to the loop's
        # end (leave(), right after its last tick) of the process (all its threads, zenoh's included) and of
        # the loop's own thread. The loop's thread is serial: a tick can never take less wall time than its
        # CPU time there. Read once at the end, not per tick: reading both clocks took 5.5-5.9 us per tick
        # in a 500 Hz moments circle (timed in flight; ~1 us each in a loop), ~2 % of the loop's CPU per tick.
        self.records_ready = 0
        self.record_wait_s = 0.0
        self._cpu_first_s: tuple[float, float] | None = None  # (process, loop thread) CPU s
        self._cpu_last_s = (0.0, 0.0)

    def start(self) -> None:
        self.transport.send(ClockAck(-1, self.link.uplink_sent, 0, period_ns=self.period_ns,
                                     crtp=self.link.speaks_crtp).pack())

    def now(self) -> float:
        return self.t_s

    def wait(self) -> float:
        tick = self._next_tick()
        self._tick_taken_s = time.perf_counter()
        if self._cpu_first_s is None:  # from the first tick on, as the loop's wall time (TickTimer)
            self._cpu_first_s = _cpu_times_s()
            self.records_ready, self.record_wait_s = 0, 0.0  # the wait for the emulator to boot is no tick's
        self.t_s = tick.time_s  # frames of this tick are received at its time (their ages depend on it)
        radio = tick.crtp_published if self.link.speaks_crtp else tick.downlink_published
        target = (radio, tick.mocap_published, tick.truth_published)
        self.link.fetch(0.0)
        deadline = time.monotonic() + self.wait_timeout_s
        while True:
            short = [have < want for have, want in zip(self.link.raw_counts(), target, strict=True)]
            if not any(short):
                break
            self.link.fetch(0.001, wait_on=short.index(True))  # wait on the stream that is behind
            if time.monotonic() > deadline:
                raise UserError(f"lockstep: frames of tick {tick.tick} never arrived "
                                f"(have {self.link.raw_counts()}, expected {target})")
        self.link.deliver(target)  # this tick's samples only: a later tick's may be here already
        self.tick = tick.tick
        self.t_s = tick.time_s
        self.ticks += 1
        self.timer.start()
        return self.t_s

    def _next_tick(self):
        if not self._ticks:
            self._take_ticks(0.0)  # already here? (no wait: the loop is the bottleneck this tick)
        if self._ticks:
            self.records_ready += 1
            return self._ticks.popleft()
        blocked = time.perf_counter()
        try:
            return self._wait_for_tick()
        finally:
            self.record_wait_s += time.perf_counter() - blocked

    def _wait_for_tick(self):
        waited = 0.0
        while True:
            self._take_ticks(0.0 if self._ticks else 0.5)
            if self._ticks:
                return self._ticks.popleft()
            waited += 0.5
            failure = self.peer_failure()
            if failure:
                raise UserError(failure)
            if self.tick < 0:  # the join may have gone out before the emulator subscribed: say it again
                self.start()
            if waited >= self.wait_timeout_s:
                raise UserError(f"lockstep: no simulation clock on '{self.transport.rx}' for "
                                f"{self.wait_timeout_s:.0f} s: is an emulator running with --clock lockstep?")
            if waited % 5.0 < 0.5:
                log.info("lockstep: waiting for the emulator's clock on %s", self.transport.rx)

    def _take_ticks(self, timeout_s: float) -> None:
        """Queue the tick records that arrived (in order; repeats and stale ones dropped)."""
        last = self._ticks[-1].tick if self._ticks else self.tick
        for data in self.transport.receive(timeout_s):
            tick = unpack_tick(data)
            if tick is not None and tick.tick > last:
                self._ticks.append(tick)
                last = tick.tick

    def release(self, next_wakeup_s: float) -> None:
        """Ack the tick: every uplink frame of it is sent. The emulator may step on from here."""
        wake_ns = max(round(next_wakeup_s * NS_PER_S), round(self.t_s * NS_PER_S) + 1)
        self.transport.send(ClockAck(self.tick, self.link.uplink_sent, wake_ns, period_ns=self.period_ns,
                                     crtp=self.link.speaks_crtp).pack())
        let_woken_reader_run()  # the emulator's thread that reads the ack, queued on this CPU (zenoh_process)
        self.ack_after_tick_s.append(time.perf_counter() - self._tick_taken_s)

    def critical_path_summary(self) -> dict:
        """The tick record -> ack times (see __init__), microseconds: median and mean; the share of ticks
        whose record was in when asked for, the mean wait for a record per tick (us), and the CPU time per
        tick (us) of the process and of the loop's thread."""
        if not self.ack_after_tick_s:
            return {}
        us = np.array(self.ack_after_tick_s) * 1e6
        ticks = self.ticks
        return {"ack_after_tick_us_p50": float(np.median(us)), "ack_after_tick_us_mean": float(us.mean()),
                "tick_record_ready_fraction": self.records_ready / ticks,
                "tick_record_wait_us_mean": self.record_wait_s / ticks * 1e6,
                "process_cpu_us_per_tick": (self._cpu_last_s[0] - self._cpu_first_s[0]) / ticks * 1e6,
                "loop_thread_cpu_us_per_tick": (self._cpu_last_s[1] - self._cpu_first_s[1]) / ticks * 1e6}

    def done(self) -> None:
        self.timer.stop()

    def leave(self) -> None:
        self._cpu_last_s = _cpu_times_s()
        self.transport.send(ClockAck(self.tick, self.link.uplink_sent, 0, leaving=True).pack())
