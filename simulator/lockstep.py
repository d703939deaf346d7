"""The lockstep clock: simulation time advances only as the ground stations acknowledge its ticks.

Takes in: an Emulator (its fleet, physics steps and publishing) and, on each vehicle's clock-ack key,
the acks of the ground stations taking part (link.clock.ClockAck).
Gives out: clock ticks (link.clock.ClockTick) on each participant's clock key, each after the frames due
by its time; the uplink samples each ack accounts for, offered to the radios at the time of the tick they
answer; physics run ahead while the acks are out (lookahead).

Clocks: `realtime` paces physics by the monotonic wall clock; `lockstep` advances simulation time
only when every ground station taking part has acknowledged the previous tick, so a run depends on
the seed and on what the ground stations send, never on scheduling. Without a ground station the
lockstep clock stands still (and says so every WAIT_LOG_PERIOD_S).

Lockstep with conservative lookahead. After publishing tick k at t_k the emulator does not know when
tick k+1 will be (the acks say), but it knows that nothing the ground station sends in answer to tick
k is pushed into an uplink radio before t_k, hence delivered to a vehicle before t_k + L, with
L = the smallest RadioChannel.min_latency_s of the vehicle's uplink radios, MAVLink's and CRTP's (a true
lower bound), and that a vehicle's firmware takes delivered
messages only at its next 500 Hz cycle (SimVehicle.first_effect_s). So while it waits for the acks it
may already run every physics step that STARTS before horizon_s = min over vehicles of the first
firmware cycle at or after t_k + L (with esb-duplex's 0.84 ms or crazyradio's 0.17 ms and 2 ms cycles: one whole
500 Hz tick).
Frames those steps produce are kept in each vehicle's outbox,
stamped with the step count at which a non-lookahead emulator would have published them, and are
published with the first tick whose time reaches that stamp; tick k's view is therefore unchanged.
Uplink samples are held until an ack accounts for them (ClockAck.uplink_sent counts the ground
station's frames) and then pushed into the radio at the time of the tick they answer, as without
lookahead; another publisher's samples go with them. The result is byte-identical with or without
lookahead (tests/simulator/test_emulator*.py and tests/groundstation/test_link_accounting.py check it).

Pipelined ticks. When every ground station's acks carry a standing period (ClockAck.period_ns: the
tick after t comes at t + period), the next tick's time is decided before the last tick's acks are
in, and the emulator publishes it as soon as the physics reaches it within the horizon. With
the default radios and 500 Hz ticks the horizon covers a whole tick, so tick k+1 goes out while the ground
station still computes tick k and the zenoh round trip leaves the serial path (the ground station
takes exactly each tick's announced samples, so it sees the same inputs either way).
A tick's frames go out in one burst, packed per key into as few samples as possible (pack_samples),
then the tick record, which counts samples.

"""

from __future__ import annotations

import logging
import math
import time
from collections import deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from link.clock import NS_PER_S, unpack_ack
from link.transports.zenoh_process import let_woken_reader_run
from simulator.profiling import time_parts
from simulator.radio import TIME_EPS_S

if TYPE_CHECKING:
    from simulator.emulator import Emulator
    from simulator.fleet import VehicleNode

log = logging.getLogger("cfstack.emulator")

WAIT_LOG_PERIOD_S = 5.0  # how often a waiting lockstep emulator says so
JOIN_POLL_S = 0.05  # nobody in the lockstep yet: how long to block between looks for a join
LAGGARD_POLL_S = 0.005  # waiting for one ack or uplink frame: longest single block (keeps Ctrl-C prompt)
# A step may run ahead only if it starts this much before the earliest possible uplink delivery: the
# radio hands out at a step start what is due within TIME_EPS_S of it, so a smaller margin could let a
# run-ahead step take a frame that float rounding of t_k + L put just after its start.
LOOKAHEAD_MARGIN_S = TIME_EPS_S


@dataclass
class Participant:
    """A ground station in the lockstep (one per vehicle id)."""

    acked: int  # the last tick it acknowledged (on joining: the last tick published then)
    wake_ns: int  # when it wants the tick after `acked`
    period_ns: int  # its standing period (ClockAck.period_ns; 0: none)
    complete: int  # the last tick whose uplink frames are all in and offered to the radio
    fresh: bool = True  # joined, no tick acknowledged yet: its standing period does not apply yet
    crtp: bool = False  # it speaks CRTP: its acks count its CRTP packets (ClockAck.crtp), not MAVLink frames
    # (tick, uplink_sent, joining) of acks whose frames are not all in; a join's CRTP is answered off the air
    pending: deque = field(default_factory=deque)


class Lockstep:
    """Who takes part in the lockstep, what they acknowledged, and when they want to be woken."""

    def __init__(self):
        self.participants: dict[int, Participant] = {}
        self.tick_steps: dict[int, int] = {}  # step count of each published tick still needed

    def handle(self, vehicle_id: int, data: bytes, tick: int, tick_steps: int, dt_s: float) -> None:
        """One ack from the ground station of vehicle_id; tick = the last tick published, at step
        tick_steps (of dt_s each)."""
        ack = unpack_ack(data)
        if ack is None:
            log.warning("lockstep: ignored a malformed clock ack for vehicle %d", vehicle_id)
            return
        p = self.participants.get(vehicle_id)
        if ack.leaving:
            if self.participants.pop(vehicle_id, None) is not None:
                log.info("lockstep: the ground station of vehicle %d left at t=%.3f s", vehicle_id,
                         tick_steps * dt_s)
            return
        if ack.tick == -1:
            if p is None:
                log.info("lockstep: a ground station joined for vehicle %d at t=%.3f s", vehicle_id,
                         tick_steps * dt_s)
                # it has seen nothing: it wants a tick at once (at the last tick's time)
                wake_ns = round(tick_steps * dt_s * NS_PER_S)
                p = self.participants[vehicle_id] = Participant(tick, wake_ns, ack.period_ns, tick - 1,
                                                                crtp=ack.crtp)
                self.tick_steps.setdefault(tick, tick_steps)
                p.pending.append((tick, ack.uplink_sent, True))
            return
        if p is None or ack.tick != p.acked + 1 or ack.tick > tick:
            return  # not a participant, or not the answer to the tick it is on (a repeat, say)
        p.acked = ack.tick
        p.wake_ns = ack.next_wakeup_ns
        p.period_ns = ack.period_ns
        p.fresh = False
        p.pending.append((ack.tick, ack.uplink_sent, False))

    def release(self, nodes: list[VehicleNode], dt_s: float) -> None:
        """Offer each participant's held uplink samples to its radio at the time of the tick they
        answer, as far as its acks account for them (ClockAck.uplink_sent counts its frames)."""
        for vid, p in self.participants.items():
            node = nodes[vid - 1]
            node.ground_speaks_crtp = p.crtp
            while p.pending:
                tick, sent, joining = p.pending[0]
                t_s = self.tick_steps[tick] * dt_s
                node.release_uplink(sent, t_s, off_air=joining)
                if node.uplink_released < sent:
                    break
                p.pending.popleft()
                p.complete = tick
            if p.complete in self.tick_steps:  # another publisher's samples need no ack: offer them on
                node.release_uplink(node.uplink_released, self.tick_steps[p.complete] * dt_s)

    def forget_before(self, tick: int) -> None:
        for old in [k for k in self.tick_steps if k < tick]:
            del self.tick_steps[old]


class LockstepClock:
    """An Emulator's lockstep run: the participants, the ticks published, the lookahead.

    `run()` returns when the emulator is stopped or its duration is reached."""

    def __init__(self, emulator: Emulator):
        self.emulator = emulator
        self.lock = Lockstep()
        self.tick = -1  # the last lockstep tick published
        self.tick_steps = 0  # the step count (simulation time) of that tick
        self.lookahead_steps = 0  # steps run while waiting for acks
        self.first_tick_wall: float | None = None  # monotonic time of tick 0, for rates
        self.wait_log_period_s = WAIT_LOG_PERIOD_S
        self._last_progress = time.monotonic()
        self._join_wait = 0  # the vehicle whose CRTP key a wait for a join blocks on
        if emulator.config.profile:  # the transport's share: acks and uplink taken, blocked waiting, ticks sent
            time_parts(self, {"poll": "poll", "wait_briefly": "wait", "_send_ticks": "send"}, emulator.timing_s)

    @property
    def tick_time_s(self) -> float:
        """Simulation time of the last tick published (s): what the ground stations have seen."""
        return self.tick_steps * self.emulator.dt_s

    def run(self) -> None:
        """Poll; publish the next tick once its time is decided and the physics has reached it; else
        run, in one batch with no poll between its steps, every step the horizon allows (an ack that
        arrives meanwhile can only extend the horizon, and the results never depend on when it is
        seen), publishing the tick the batch reaches; else block briefly on what is missing (a join,
        an ack, frames)."""
        emu, lock = self.emulator, self.lock
        self._last_progress = time.monotonic()
        while not emu.stopped and not emu.duration_reached(self.tick_steps):
            self.poll()
            n = self.next_tick_steps_decided()
            if n is not None and emu.steps >= n:
                self.publish_tick(n)
                continue
            allowed = self.steps_allowed(n)
            if allowed:
                if any(p.acked < self.tick for p in lock.participants.values()):
                    self.lookahead_steps += allowed  # run before every ground station has answered the last tick
                for _ in range(allowed):  # no poll in between: what arrives meanwhile can only extend the horizon
                    emu.step_all()
                if n is not None and emu.steps >= n:  # as if the acks meanwhile came just after the tick
                    self.publish_tick(n)
                continue
            self.wait_briefly()
            self.log_if_waiting()

    def next_tick_steps_decided(self) -> int | None:
        """The step count of the next tick if its time is decided, else None. It is decided when every
        participant has said when it wants it: by acking the last tick (its next wake-up), or by a
        standing period (ClockAck.period_ns: the tick after t comes at t + period), which lets the
        next tick be decided before the last one's acks are in."""
        emu, lock = self.emulator, self.lock
        if not lock.participants:
            return None
        last_ns = round(self.tick_steps * emu.dt_s * NS_PER_S)
        wanted = []
        for p in lock.participants.values():
            if p.period_ns > 0 and not p.fresh:  # its standing order (its acks' wake-ups say the same)
                wanted.append(last_ns + p.period_ns)
            elif p.acked >= self.tick:
                wanted.append(p.wake_ns)
            else:
                return None
        return self.next_tick_steps(min(wanted))

    def steps_allowed(self, next_tick_steps: int | None) -> int:
        """How many physics steps may run now: those that start before the horizon (below), never past
        a decided next tick or the duration (0 before the first tick or with nobody taking part)."""
        emu, lock = self.emulator, self.lock
        if not lock.participants or self.tick < 0:
            return 0
        dt = emu.dt_s
        limit = self.horizon_s(next_tick_steps) - LOOKAHEAD_MARGIN_S  # finite once anyone takes part
        end = max(emu.steps, math.floor(limit / dt) - 1)  # then exactly: the first step not starting before it
        while end * dt < limit:
            end += 1
        for bound in (next_tick_steps, emu.duration_steps):
            if bound is not None and bound < end:
                end = bound
        return max(0, end - emu.steps)

    def horizon_s(self, next_tick_steps: int | None = None) -> float:
        """The earliest time anything a ground station may still send can act on its vehicle.

        A participant's frames are all in (and offered to its radio) up to some tick a (`complete`);
        whatever it sends later belongs to a tick at or after tick a + 1, is offered at that tick's time
        t, so is delivered no earlier than t + L (L = the uplink radio's minimum latency) and taken by
        the firmware at its first cycle at or after that (SimVehicle.first_effect_s). Without
        lookahead, t itself. t: tick a + 1's time when published or decided, else the last tick's
        (a lower bound: a tick is never before the one before it)."""
        emu, lock = self.emulator, self.lock
        horizon = math.inf
        for vid, p in lock.participants.items():
            following = p.complete + 1
            if following <= self.tick:
                t = lock.tick_steps[following] * emu.dt_s
            elif following == self.tick + 1 and next_tick_steps is not None:
                t = next_tick_steps * emu.dt_s
            else:
                t = self.tick_time_s
            horizon = min(horizon, self.first_effect_s(emu.nodes[vid - 1], t))
        return horizon

    def first_effect_s(self, node: VehicleNode, offered_s: float) -> float:
        """The earliest time an uplink frame offered to node's radio at offered_s can act on the
        vehicle: with lookahead, the first firmware cycle at or after offered_s + L; else offered_s."""
        emu = self.emulator
        if not emu.config.lookahead:
            return offered_s
        return node.sim.first_effect_s(offered_s + node.uplink_min_latency_s)

    def lookahead_horizon_s(self) -> float:
        """The horizon right after a tick at tick_time_s, before any answer to it (benchmarks, tests)."""
        emu = self.emulator
        return min(self.first_effect_s(node, self.tick_time_s) for node in emu.nodes)

    def poll(self) -> None:
        """Take every pending ack and uplink sample without blocking, and offer to the radios the
        uplink samples the acks account for."""
        emu, lock = self.emulator, self.lock
        for node in emu.nodes:
            for data in node.clock.receive(0.0):
                lock.handle(node.vehicle_id, data, self.tick, self.tick_steps, emu.dt_s)
            node.take_uplink()
            if node.held_uplink and node.vehicle_id not in lock.participants:
                node.release_uplink(math.inf, self.tick_time_s, off_air=True)  # nobody's acks account for them
        lock.release(emu.nodes, emu.dt_s)

    def wait_briefly(self) -> None:
        """Block a little on whatever the lockstep is waiting for: a join, an ack, or uplink frames."""
        emu, lock = self.emulator, self.lock
        if not lock.participants:
            # a cflib client connecting (off the air) must not wait JOIN_POLL_S per answer: block on the
            # CRTP keys, one vehicle's at a time, and look for joins without blocking
            self._join_wait = (self._join_wait + 1) % len(emu.nodes)
            node = emu.nodes[self._join_wait]
            if node.crtp_keys is not None:
                node.take_uplink(JOIN_POLL_S, wait_on_crtp=node.crtp_seen)
                timeout_s = 0.0
            else:
                node, timeout_s = emu.nodes[0], JOIN_POLL_S
            for data in node.clock.receive(timeout_s):
                lock.handle(node.vehicle_id, data, self.tick, self.tick_steps, emu.dt_s)
            return
        vid, p = min(lock.participants.items(), key=lambda item: item[1].complete)
        node = emu.nodes[vid - 1]
        if p.pending:  # acked, but not all of that tick's frames are in
            node.take_uplink(LAGGARD_POLL_S)
            return
        for data in node.clock.receive(LAGGARD_POLL_S):
            lock.handle(vid, data, self.tick, self.tick_steps, emu.dt_s)

    def log_if_waiting(self) -> None:
        lock = self.lock
        now = time.monotonic()
        if now - self._last_progress < self.wait_log_period_s:
            return
        self._last_progress = now
        if not lock.participants:
            log.info("lockstep: waiting for a ground station to join (simulation time %.3f s)", self.tick_time_s)
        else:
            missing = sorted(vid for vid, p in lock.participants.items() if p.acked < self.tick) \
                or sorted(lock.participants)
            log.info("lockstep: waiting for the ground station(s) of vehicle(s) %s to finish tick %d "
                     "(simulation time %.3f s)", ", ".join(map(str, missing)), self.tick, self.tick_time_s)

    def next_tick_steps(self, target_ns: int) -> int:
        """The step count of the next tick: the first step boundary at or after target_ns (never
        before the last tick), capped at the duration."""
        emu = self.emulator
        dt_ns = emu.dt_s * NS_PER_S
        n = max(self.tick_steps, math.floor(target_ns / dt_ns) - 1)
        while round(n * emu.dt_s * NS_PER_S) < target_ns:
            n += 1
        if emu.duration_steps is not None:
            n = min(n, max(emu.duration_steps, self.tick_steps))
        return n

    def publish_tick(self, n: int) -> None:
        """Publish the frames due by step n in one burst, then the record of the next tick at n. (One
        burst lets zenoh batch the samples into few writes, and the ground station finds the frames
        already there when the record wakes it: measured fewer context switches per tick than
        publishing frames step by step or the record first.)"""
        emu, lock = self.emulator, self.lock
        self.tick += 1
        self.tick_steps = n
        lock.tick_steps[self.tick] = n
        lock.forget_before(min(p.complete for p in lock.participants.values()))
        if self.first_tick_wall is None:
            self.first_tick_wall = time.monotonic()
        emu.flush(n)
        self._send_ticks(round(n * emu.dt_s * NS_PER_S))
        self._last_progress = time.monotonic()

    def _send_ticks(self, time_ns: int) -> None:
        """The record of the tick just published, to every participant."""
        emu, lock = self.emulator, self.lock
        for node in emu.nodes:
            if node.vehicle_id in lock.participants:
                node.clock.send(node.outbox.tick_message(self.tick, time_ns).pack())
        let_woken_reader_run()  # the ground stations' threads that read the record, queued on this CPU (zenoh_process)

