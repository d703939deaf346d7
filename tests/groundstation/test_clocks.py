"""The lockstep clock's critical-path measure: from a tick's record being taken to its ack being sent.

The emulator cannot step past the next tick before the ack (simulator.lockstep), so this span is what the
ground station adds to every simulated tick (benchmarks/loop_bench.py reads it from the flight summary).
Driven here with an in-memory clock key and a link with no frames; the waits are real sleeps.
"""

import hashlib
import threading
import time

from groundstation.clocks import LockstepClock
from link.clock import ClockTick, unpack_ack

PERIOD_S = 0.002
WORK_S = 0.03  # the ground station's work between the tick and its ack
LATE_S = 0.06  # how long each tick record takes to arrive: waiting, not the ground station's work


class NoFrames:
    """A VehicleLink with nothing to deliver (a tick that announces no frames)."""

    speaks_crtp = False
    uplink_sent = 0

    def raw_counts(self):
        return (0, 0, 0)

    def fetch(self, timeout_s=0.0, wait_on=0):
        pass

    def deliver(self, counts=None):
        pass


class LateTicks:
    """The clock key: each tick record arrives LATE_S after it is asked for; acks are kept."""

    rx = "test/clock"

    def __init__(self, ticks: int):
        self.records = [ClockTick(k, round(k * PERIOD_S * 1e9), 0, 0, 0).pack() for k in range(ticks)]
        self.acks = []

    def receive(self, timeout_s=0.0):
        if not self.records:
            return []
        time.sleep(LATE_S)
        return [self.records.pop(0)]

    def send(self, data):
        self.acks.append(unpack_ack(data))
        return True


def test_the_critical_path_runs_from_the_tick_record_to_the_ack_and_excludes_the_wait_for_the_tick():
    transport = LateTicks(3)
    clock = LockstepClock(PERIOD_S, NoFrames(), transport)
    for k in range(3):
        assert clock.wait() == k * PERIOD_S
        time.sleep(WORK_S)
        clock.release(clock.now() + PERIOD_S)
        clock.done()
    assert [ack.tick for ack in transport.acks] == [0, 1, 2]
    summary = clock.critical_path_summary()
    # at least the work; far below work + the wait for the record (a busy machine may add some)
    assert WORK_S * 1e6 <= summary["ack_after_tick_us_p50"] < (WORK_S + LATE_S) * 1e6
    assert WORK_S * 1e6 <= summary["ack_after_tick_us_mean"] < (WORK_S + LATE_S) * 1e6


def test_no_tick_no_critical_path():
    assert LockstepClock(PERIOD_S, NoFrames(), LateTicks(0)).critical_path_summary() == {}


class AlternateTicks(LateTicks):
    """The clock key: every other tick record is already in when asked for; the others arrive LATE_S after."""

    def receive(self, timeout_s=0.0):
        if not self.records or (len(self.records) % 2 == 1 and timeout_s == 0.0):
            return []  # an odd count left: this record is late, a look without waiting finds nothing
        if timeout_s > 0.0:
            time.sleep(LATE_S)
        return [self.records.pop(0)]


def _use_cpu(seconds: float) -> None:
    """Work that uses `seconds` of this thread's CPU time, however busy the machine."""
    end = time.thread_time() + seconds
    while time.thread_time() < end:
        pass


def test_the_summary_says_which_records_were_in_how_long_the_loop_waited_and_its_cpu_per_tick():
    transport = AlternateTicks(6)  # records left 6: in; 5: late; 4: in; 3: late; 2: in; 1: late
    clock = LockstepClock(PERIOD_S, NoFrames(), transport)
    for _ in range(6):
        clock.wait()
        _use_cpu(WORK_S)
        clock.release(clock.now() + PERIOD_S)
        clock.done()
    clock.leave()  # the loop's end: its CPU times are read here
    summary = clock.critical_path_summary()
    # the first tick's wait is the emulator's boot, no tick's: of the others, ticks 2 and 4 were in, 1, 3, 5 late
    assert summary["tick_record_ready_fraction"] == 2 / 6
    # three late records of LATE_S each over six ticks: at least that, far below a fourth one more
    assert 3 * LATE_S / 6 * 1e6 <= summary["tick_record_wait_us_mean"] < 4 * LATE_S / 6 * 1e6
    # six ticks' CPU work (the first tick's record taken -> the last tick done), and no more than work + waits
    assert WORK_S * 1e6 <= summary["process_cpu_us_per_tick"] < (WORK_S + LATE_S) * 1e6


def test_the_loop_threads_cpu_per_tick_is_its_own_work_not_the_other_threads_nor_the_waits():
    """The loop's thread is serial, so its CPU per tick bounds the tick's wall time from below
    (loop_bench prints it against the wall time a target allows): it must count that thread's work only."""
    transport = LateTicks(4)
    clock = LockstepClock(PERIOD_S, NoFrames(), transport)
    helper_cpu_s, stop = [], threading.Event()

    def other_thread():  # CPU in another thread of the process (hashlib releases the GIL on large buffers)
        data = bytes(1 << 20)
        while not stop.is_set():
            hashlib.sha256(data).digest()
        helper_cpu_s.append(time.thread_time())

    helper = None
    for k in range(4):
        clock.wait()
        if k == 0:  # the other thread runs inside the measured span only
            helper = threading.Thread(target=other_thread)
            helper.start()
        _use_cpu(WORK_S)
        clock.release(clock.now() + PERIOD_S)
        if k == 3:
            stop.set()
            helper.join()
        clock.done()
    clock.leave()
    summary = clock.critical_path_summary()
    loop_us, process_us = summary["loop_thread_cpu_us_per_tick"], summary["process_cpu_us_per_tick"]
    # the four ticks' work in this thread; the three late records' waits (sleeps) add no CPU
    assert WORK_S * 1e6 <= loop_us < (WORK_S + LATE_S / 2) * 1e6
    # the process's CPU holds this thread's and the other thread's (both measured by the kernel's CPU clocks)
    assert helper_cpu_s[0] > 0.01
    assert process_us * 4 >= (loop_us * 4 + helper_cpu_s[0] * 1e6) - 1e3
