"""The emulator process: simulated Crazyflies behind simulated radios, answering on zenoh.

Takes in: an EmulatorConfig (vehicle, mocap room, radio profile, world, number of vehicles, seed,
clock, connection); uplink MAVLink frames on each vehicle's uplink key (through the vehicle's uplink
radio); lockstep acknowledgements on the clock-ack keys (link.clock).
Gives out: downlink frames (through the downlink radio), mocap poses (ground network, no radio),
simulation-only ground truth, lockstep clock ticks (keys: link.keys.VehicleKeys, one set per vehicle
id 1..N); `summary()` (one line), `radio_report()` (per-channel statistics, the frames the fault
windows cut, the uplink parser's counters - signature failures included - and, with keep_ledger,
every frame's fate), and per-part timing with `profile=True` (for benchmarks).

Fault injection (EmulatorConfig.radio_cuts / mocap_cuts, `--cut-radio` / `--cut-mocap`), in
simulation time so lockstep runs stay deterministic: while a radio cut covers the time a frame is
offered to a radio (uplink: the tick time it is pushed at; downlink: its release time), the frame is
dropped before the radio, in both directions of every vehicle, and counted as `cut` (not as a radio
drop cause: the radio never sees it). While a mocap cut covers a mocap frame's release time, it is not
published (counted as `mocap_cut`).

Foreign uplink frames. Anyone may publish on a vehicle's uplink key. Every sample is offered to the
uplink radio (so the vehicle's parser rejects what is unsigned, forged or replayed, and counts it), but
only the ground station's own frames count towards the `uplink_sent` its lockstep acks announce
(GroundFrameGate: source system id GROUND_STATION_SYSTEM_ID and, with signing on, a valid signature
newer than the last one, checked by a signing state of the gate's own). Foreign samples are counted
apart (`uplink_foreign`), so they neither release a tick early nor stall one. Without signing, a frame
that claims the ground station's system id cannot be told from its own.

Clocks: `realtime` paces physics by the monotonic wall clock; `lockstep` advances simulation time
only when every ground station taking part has acknowledged the previous tick, so a run depends on
the seed and on what the ground stations send, never on scheduling. Without a ground station the
lockstep clock stands still (and says so every WAIT_LOG_PERIOD_S).

Lockstep with conservative lookahead. After publishing tick k at t_k the emulator does not know when
tick k+1 will be (the acks say), but it knows that nothing the ground station sends in answer to tick
k is pushed into an uplink radio before t_k, hence delivered to a vehicle before t_k + L, with
L = RadioChannel.min_latency_s (a true lower bound), and that a vehicle's firmware takes delivered
messages only at its next 500 Hz cycle (SimVehicle.first_effect_s). So while it waits for the acks it
may already run every physics step that STARTS before horizon_s = min over vehicles of the first
firmware cycle at or after t_k + L (with crazyradio's 0.84 ms and 2 ms cycles: one whole 500 Hz tick).
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
crazyradio and 500 Hz ticks the horizon covers a whole tick, so tick k+1 goes out while the ground
station still computes tick k and the zenoh round trip leaves the serial path (the ground station
takes exactly each tick's announced samples, so it sees the same inputs either way).
A tick's frames go out in one burst, packed per key into as few samples as possible (pack_samples),
then the tick record, which counts samples.
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections import defaultdict, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from link.clock import NS_PER_S, ClockTick, unpack_ack
from link.keys import GROUND_STATION_SYSTEM_ID, VehicleKeys
from link.mavlink.codec import IFLAG_SIGNED, MAGIC_V2, MIN_FRAME_LEN, ActuatorLimits, Codec, FrameParser
from link.mavlink.signing import SIGNATURE_BLOCK_LEN, SignatureCheck
from link.messages import RadioStatus
from link.transports import Transport, open_transport
from model.errors import UserError
from model.radio import RadioProfile
from model.vehicle import MocapRoom, Vehicle
from model.world import World
from simulator.radio import TIME_EPS_S, RadioChannel
from simulator.vehicle_sim import SimVehicle

log = logging.getLogger("cfstack.emulator")

RADIO_STATUS_PERIOD_S = 1.0  # RADIO_STATUS once a second, as SiK radios report it
WAIT_LOG_PERIOD_S = 5.0  # how often a waiting lockstep emulator says so
JOIN_POLL_S = 0.05  # nobody in the lockstep yet: how long to block between looks for a join
LAGGARD_POLL_S = 0.005  # waiting for one ack or uplink frame: longest single block (keeps Ctrl-C prompt)
REALTIME_MAX_SLEEP_S = 0.05  # the realtime loop never sleeps longer than this (keeps Ctrl-C prompt)
# A step may run ahead only if it starts this much before the earliest possible uplink delivery: the
# radio hands out at a step start what is due within TIME_EPS_S of it, so a smaller margin could let a
# run-ahead step take a frame that float rounding of t_k + L put just after its start.
LOOKAHEAD_MARGIN_S = TIME_EPS_S
# Frames published together (one tick's, or one realtime step's) share a sample up to this size: far
# below a UDP datagram (65,507 B) and zenoh's default batch (65,535 B).
MAX_SAMPLE_BYTES = 8192
MAX_VEHICLES = 250  # MAVLink system ids 1..250 (251..255 are ground-side ids, link.keys)

DOWNLINK, MOCAP, TRUTH = 0, 1, 2  # outbox channels, in ClockTick count order


@dataclass(frozen=True)
class Outage:
    """A fault window in simulation time: from start_s for duration_s seconds (None: to the end)."""

    start_s: float
    duration_s: float | None = None

    @property
    def end_s(self) -> float:
        return math.inf if self.duration_s is None else self.start_s + self.duration_s

    def covers(self, t_s: float) -> bool:
        """start_s <= t_s < start_s + duration_s."""
        return self.start_s <= t_s < self.end_s

    def check(self, what: str) -> None:
        if not (isinstance(self.start_s, (int, float)) and math.isfinite(self.start_s) and self.start_s >= 0.0):
            raise UserError(f"{what}: start {self.start_s!r} is not a time >= 0 s")
        d = self.duration_s
        if d is not None and not (isinstance(d, (int, float)) and math.isfinite(d) and d > 0.0):
            raise UserError(f"{what}: duration {d!r} is not a positive number of seconds")


def covered(outages: tuple[Outage, ...], t_s: float) -> bool:
    """Whether any of the windows covers simulation time t_s."""
    return any(o.start_s <= t_s < o.end_s for o in outages)


@dataclass
class EmulatorConfig:
    vehicle: Vehicle
    mocap_room: MocapRoom
    radio: RadioProfile
    world: World | None
    vehicles: int = 1
    seed: int = 0
    clock: str = "lockstep"  # or "realtime"
    physics_rate_hz: float = 1000.0
    prefix: str = "cfstack"
    connection: str = "zenoh"
    zenoh_options: dict = field(default_factory=dict)
    start_positions_enu_m: list[tuple[float, float, float]] | None = None
    airborne: bool = False
    signing: object | None = None
    duration_s: float | None = None  # stop after this much simulation time (None: until stopped)
    lookahead: bool = True  # lockstep: run physics ahead by the uplink's minimum latency (see above)
    keep_ledger: bool = False  # radios keep every frame's fate (memory grows with the run: tests only)
    profile: bool = False  # accumulate per-part wall time in Emulator.timing_s (benchmarks)
    radio_cuts: tuple[Outage, ...] = ()  # every radio frame offered inside these windows is dropped
    mocap_cuts: tuple[Outage, ...] = ()  # no mocap frame is published inside these windows
    # A fresh Signing with the key of `signing` (one per vehicle, for GroundFrameGate's own replay state).
    # None with signing on: the gate can only require signed frames from the ground station's system id.
    signing_factory: Callable[[], object | None] | None = None

    def check(self) -> None:
        """One-line UserError for settings no emulator can run with."""
        if isinstance(self.vehicles, bool) or not isinstance(self.vehicles, int) \
                or not 1 <= self.vehicles <= MAX_VEHICLES:
            raise UserError(f"vehicles: {self.vehicles!r} is not a vehicle count 1..{MAX_VEHICLES}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise UserError(f"seed: {self.seed!r} is not a non-negative integer")
        if self.clock not in ("lockstep", "realtime"):
            raise UserError(f"clock: '{self.clock}' is not one of lockstep, realtime")
        rate = self.physics_rate_hz
        if not isinstance(rate, (int, float)) or not math.isfinite(rate) or rate <= 0.0:
            raise UserError(f"physics rate: {rate!r} is not a positive number of Hz")
        if self.duration_s is not None and not (math.isfinite(self.duration_s) and self.duration_s > 0.0):
            raise UserError(f"duration: {self.duration_s!r} is not a positive number of seconds")
        starts = self.start_positions_enu_m
        if starts is not None and len(starts) != self.vehicles:
            raise UserError(f"{len(starts)} start positions given for {self.vehicles} vehicle(s)")
        for outage in self.radio_cuts:
            outage.check("radio cut")
        for outage in self.mocap_cuts:
            outage.check("mocap cut")


class GroundFrameGate:
    """Counts the ground station's own frames in an uplink sample, as they arrive (before the radio).

    A frame is the ground station's if it is a whole MAVLink 2 frame from GROUND_STATION_SYSTEM_ID and,
    when signing is on, signed; with a Signing of its own (same key) the gate also checks the signature
    and that its timestamp is newer than the last one accepted (so a replay is not counted). The
    vehicle's parser decides independently, later, on what the radio delivers."""

    def __init__(self, require_signed: bool, signing=None):
        self.require_signed = require_signed
        self.signing = signing

    def count(self, sample: bytes) -> int:
        """The ground station's frames in one sample (normally the sample is one frame: 0 or 1)."""
        ours = 0
        pos = 0
        size = len(sample)
        while pos + MIN_FRAME_LEN <= size and sample[pos] == MAGIC_V2:
            signed = sample[pos + 2] & IFLAG_SIGNED
            end = pos + MIN_FRAME_LEN + sample[pos + 1] + (SIGNATURE_BLOCK_LEN if signed else 0)
            if end > size:
                break
            if self._ours(sample[pos:end], signed):
                ours += 1
            pos = end
        return ours

    def _ours(self, frame: bytes, signed: int) -> bool:
        if frame[5] != GROUND_STATION_SYSTEM_ID:
            return False
        if not self.require_signed:
            return True
        if not signed:
            return False
        return self.signing is None or self.signing.check(frame, frame[5], frame[6]) is SignatureCheck.OK


class VehicleNode:
    """One emulated vehicle, its two radio channels, its codecs and (once opened) its zenoh keys.

    `step(step_no)` advances it one physics step and queues what it publishes in `outbox` as
    (step_no, channel, frame); `take_due(n)` hands out those stamped <= n, and `send()` publishes them
    packed per channel into samples (pack_samples), counting the samples in `published`. Without
    transports (never opened) it runs in-process, e.g. in benchmarks."""

    def __init__(self, config: EmulatorConfig, vehicle_id: int, rng_seed: np.random.SeedSequence,
                 start: tuple[float, float, float]):
        sim_seed, up_seed, down_seed = rng_seed.spawn(3)
        self.vehicle_id = vehicle_id
        self.keys = VehicleKeys(config.prefix, vehicle_id)
        self.sim = SimVehicle(config.vehicle, np.random.default_rng(sim_seed), world=config.world,
                              mocap_room=config.mocap_room, vehicle_id=vehicle_id,
                              physics_rate_hz=config.physics_rate_hz, initial_position_enu_m=start,
                              airborne=config.airborne, profile=config.profile)
        self.uplink_radio = RadioChannel(config.radio, np.random.default_rng(up_seed), name=f"uplink {vehicle_id}",
                                         keep_ledger=config.keep_ledger)
        self.downlink_radio = RadioChannel(config.radio, np.random.default_rng(down_seed),
                                           name=f"downlink {vehicle_id}", keep_ledger=config.keep_ledger)
        limits = ActuatorLimits.from_vehicle(config.vehicle)
        self.codec = Codec(system_id=vehicle_id, limits=limits, signing=config.signing)
        self.ground_codec = Codec(system_id=vehicle_id, limits=limits)  # mocap and truth: never signed
        self.parser = FrameParser(self.codec, signing=config.signing)
        gate_signing = config.signing_factory() if config.signing is not None and config.signing_factory else None
        self.gate = GroundFrameGate(require_signed=config.signing is not None, signing=gate_signing)
        self.outbox: deque[tuple[int, int, bytes]] = deque()
        self.published = [0, 0, 0]  # samples published per channel (DOWNLINK, MOCAP, TRUTH)
        self.uplink_in = 0  # the ground station's uplink frames taken from the transport (GroundFrameGate)
        self.held_uplink: deque[tuple[bytes, int]] = deque()  # lockstep: (sample, its frames of ours), not yet offered
        self.uplink_released = 0  # the ground station's frames offered to the radio from held_uplink
        self.uplink_foreign = 0  # uplink samples with none of its frames (another publisher on the key)
        self.radio_cuts = config.radio_cuts
        self.mocap_cuts = config.mocap_cuts
        self.cut = {"uplink": 0, "downlink": 0}  # radio frames dropped by a radio cut
        self.mocap_cut = 0  # mocap frames not published during a mocap cut
        self.next_radio_status_s = RADIO_STATUS_PERIOD_S
        self.crash_reported = False
        self.profile = config.profile
        self.timing_s: dict[str, float] = defaultdict(float)
        self.link: Transport | None = None  # tx downlink, rx uplink
        self.clock: Transport | None = None  # tx clock, rx clock_ack
        self.senders: list[Transport | None] = [None, None, None]  # per outbox channel

    # --- transports -----------------------------------------------------------------------------
    def open(self, config: EmulatorConfig) -> None:
        opts = config.zenoh_options if config.connection.startswith("zenoh") else {}
        try:
            self.link = open_transport(config.connection, tx=self.keys.downlink, rx=self.keys.uplink, **opts)
            mocap = open_transport(config.connection, tx=self.keys.mocap, **opts)
            truth = open_transport(config.connection, tx=self.keys.truth, **opts)
            self.senders = [self.link, mocap, truth]
            self.clock = open_transport(config.connection, tx=self.keys.clock, rx=self.keys.clock_ack, **opts)
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        for transport in (*self.senders, self.link, self.clock):
            if transport is not None:
                transport.close()

    def receive_uplink(self, push_time_s: float, timeout_s: float = 0.0) -> int:
        """Offer every uplink frame that has arrived on the transport to the uplink radio at push_time_s."""
        frames = self.link.receive(timeout_s)
        if frames:
            self.push_uplink(frames, push_time_s)
        return len(frames)

    def push_uplink(self, frames: list[bytes], push_time_s: float) -> None:
        """Offer uplink samples to the radio at push_time_s now (realtime, in-process), counting the
        ground station's frames among them."""
        for frame in frames:
            self._count_arrival(frame)
        self._offer_uplink(frames, push_time_s)

    def take_uplink(self, timeout_s: float = 0.0) -> int:
        """Lockstep: take the uplink samples that have arrived, count the ground station's frames among
        them, and hold them until its acks account for them (release_uplink)."""
        samples = self.link.receive(timeout_s)
        for sample in samples:
            self.held_uplink.append((sample, self._count_arrival(sample)))
        return len(samples)

    def _count_arrival(self, sample: bytes) -> int:
        """The ground station's frames in an arriving uplink sample (GroundFrameGate), counted."""
        ours = self.gate.count(sample)
        self.uplink_in += ours
        if not ours:
            self.uplink_foreign += 1
        return ours

    def release_uplink(self, sent: float, push_time_s: float) -> None:
        """Offer held samples, in arrival order, to the radio at push_time_s while the ground station's
        frames among them stay within `sent` (its ack's count); a foreign sample goes with them.
        sent = uplink_released: only the foreign samples at the head; math.inf: every held sample."""
        held = self.held_uplink
        while held and self.uplink_released + held[0][1] <= sent:
            sample, ours = held.popleft()
            self.uplink_released += ours
            self._offer_uplink((sample,), push_time_s)

    def _offer_uplink(self, frames, push_time_s: float) -> None:
        """Into the uplink radio at push_time_s, unless a radio cut covers that time."""
        if self.radio_cuts and covered(self.radio_cuts, push_time_s):
            self.cut["uplink"] += len(frames)
            return
        push = self.uplink_radio.push
        for frame in frames:
            push(frame, push_time_s)

    def _offer_downlink(self, frame: bytes, t_s: float) -> None:
        if self.radio_cuts and covered(self.radio_cuts, t_s):
            self.cut["downlink"] += 1
            return
        self.downlink_radio.push(frame, t_s)

    def _mocap_cut(self, release_s: float) -> bool:
        if self.mocap_cuts and covered(self.mocap_cuts, release_s):
            self.mocap_cut += 1
            return True
        return False

    def take_due(self, step_no: int) -> list[tuple[int, bytes]]:
        """(channel, frame) of every queued frame stamped at or before step_no, in order."""
        outbox = self.outbox
        due = []
        while outbox and outbox[0][0] <= step_no:
            _, channel, frame = outbox.popleft()
            due.append((channel, frame))
        return due

    def send(self, frames: list[tuple[int, bytes]]) -> None:
        """Publish frames, the ones of each channel packed into as few samples as MAX_SAMPLE_BYTES
        allows (in order), counting the samples in `published` (what the clock ticks announce)."""
        batches: tuple[list[bytes], ...] = ([], [], [])
        for channel, frame in frames:
            batches[channel].append(frame)
        for channel, batch in enumerate(batches):
            if batch:
                for sample in pack_samples(batch):
                    self.senders[channel].send(sample)
                    self.published[channel] += 1

    def tick_message(self, tick: int, time_ns: int) -> ClockTick:
        return ClockTick(tick, time_ns, *self.published)

    # --- one physics step -----------------------------------------------------------------------
    def step(self, step_no: int) -> None:
        """Deliver the uplink frames due at the step's start, step the vehicle, route its outputs
        (stamped step_no: the step count once this step is done)."""
        if self.profile:
            self._step_profiled(step_no)
            return
        sim = self.sim
        t = sim.t_s
        due = self.uplink_radio.pop_due(t)  # [] at once when nothing is due (the radio's own check)
        if due:
            self._deliver_uplink(due, t)
        sim.step()
        t = sim.t_s
        outbox = self.outbox
        for release_s, channel, message in sim.pop_outputs():
            if channel == "downlink":
                self._offer_downlink(self.codec.encode(message), release_s)  # encoded: a cut frame uses its seq
            elif channel == "mocap":
                if not self._mocap_cut(release_s):
                    outbox.append((step_no, MOCAP, self.ground_codec.encode(message)))
            else:
                outbox.append((step_no, TRUTH, self.ground_codec.encode(message)))
        self._finish_step(t, step_no)

    def _finish_step(self, t: float, step_no: int) -> None:
        """The end of a step at time t: RADIO_STATUS when due, the downlink frames the radio delivers
        by t into the outbox, a crash reported once."""
        if t >= self.next_radio_status_s:
            self._push_radio_status(t)
        outbox = self.outbox
        for frame in self.downlink_radio.pop_due(t):
            outbox.append((step_no, DOWNLINK, frame))
        if self.sim.crash is not None and not self.crash_reported:
            self._report_crash()

    def _deliver_uplink(self, frames: list[bytes], t: float) -> None:
        feed, handle = self.parser.feed, self.sim.handle_uplink
        for frame in frames:
            for decoded in feed(frame, True):  # each uplink sample is whole frames (a datagram)
                handle(decoded.message, t)

    def _push_radio_status(self, t: float) -> None:
        self.next_radio_status_s += RADIO_STATUS_PERIOD_S
        status = RadioStatus(**self.downlink_radio.radio_status(reverse=self.uplink_radio))
        self._offer_downlink(self.codec.encode(status), t)

    def _report_crash(self) -> None:
        self.crash_reported = True
        c = self.sim.crash
        pos = ", ".join(f"{v:.3f}" for v in c.position_enu_m)
        log.warning("vehicle %d crashed at t=%.3f s at (%s) m: %s", self.vehicle_id, c.time_s, pos, c.reason)

    def _step_profiled(self, step_no: int) -> None:
        """step() with time.perf_counter accounting per part (a few us slower; benchmarks only).
        The vehicle's own split (uplink handling, firmware, sensors, physics) is in sim.timing_s."""
        clock = time.perf_counter
        timing = self.timing_s
        sim = self.sim
        t = sim.t_s
        t0 = clock()
        frames = self.uplink_radio.pop_due(t)
        t1 = clock()
        self._deliver_uplink(frames, t)
        t2 = clock()
        sim.step()
        t3 = clock()
        t = sim.t_s
        outputs = sim.pop_outputs()
        t4 = clock()
        encode_s = radio_s = 0.0
        outbox = self.outbox
        for release_s, channel, message in outputs:
            a = clock()
            if channel == "downlink":
                frame = self.codec.encode(message)
                b = clock()
                self._offer_downlink(frame, release_s)
                radio_s += clock() - b
            else:
                if channel == "truth" or not self._mocap_cut(release_s):
                    outbox.append((step_no, MOCAP if channel == "mocap" else TRUTH,
                                   self.ground_codec.encode(message)))
                b = clock()
            encode_s += b - a
        t5 = clock()
        self._finish_step(t, step_no)
        t6 = clock()
        timing["radio"] += (t1 - t0) + radio_s + (t6 - t5)
        timing["decode"] += t2 - t1
        timing["outputs"] += t4 - t3
        timing["encode"] += encode_s
        timing["route"] += (t5 - t4) - encode_s - radio_s


class Emulator:
    """N VehicleNodes on one simulation clock. `with Emulator(config) as emu: emu.run()`."""

    def __init__(self, config: EmulatorConfig):
        config.check()
        self.config = config
        seeds = np.random.SeedSequence(config.seed).spawn(config.vehicles)
        starts = config.start_positions_enu_m or default_starts(config.world, config.vehicles, config.airborne)
        self.nodes = [VehicleNode(config, i + 1, seeds[i], starts[i]) for i in range(config.vehicles)]
        self.dt_s = 1.0 / config.physics_rate_hz
        self.steps = 0  # physics steps done (lockstep: may run ahead of the last tick, see the docstring)
        self.tick = -1  # the last lockstep tick published
        self.tick_steps = 0  # the step count (simulation time) of that tick
        self.lookahead_steps = 0  # steps run while waiting for acks
        self.stopped = False
        self.wall_start = time.monotonic()
        self.wait_log_period_s = WAIT_LOG_PERIOD_S
        self.first_tick_wall: float | None = None  # monotonic time of tick 0 (lockstep), for rates
        self.timing_s: dict[str, float] = defaultdict(float)  # transport parts, with config.profile
        # the run ends at the step boundary nearest the duration
        self.duration_steps = (None if config.duration_s is None
                               else max(1, math.ceil(config.duration_s / self.dt_s - 0.5)))
        self._last_progress = time.monotonic()

    @property
    def t_s(self) -> float:
        """Simulation time of the physics (s); in lockstep, possibly ahead of the last tick."""
        return self.steps * self.dt_s

    @property
    def tick_time_s(self) -> float:
        """Simulation time of the last tick published (s): what the ground stations have seen."""
        return self.tick_steps * self.dt_s

    def __enter__(self) -> Emulator:
        try:
            for node in self.nodes:
                node.open(self.config)
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        for node in self.nodes:
            node.close()

    def step_all(self) -> None:
        self.steps += 1
        n = self.steps
        for node in self.nodes:
            node.step(n)

    def run(self) -> None:
        self.wall_start = time.monotonic()
        if self.config.clock == "realtime":
            self.run_realtime()
        else:
            self.run_lockstep()

    def _duration_reached(self, steps: int) -> bool:
        return self.duration_steps is not None and steps >= self.duration_steps

    # --- realtime -------------------------------------------------------------------------------
    def run_realtime(self) -> None:
        """Step at the wall clock's pace; uplink frames enter the radio at the current sim time."""
        start = time.monotonic()
        while not self.stopped and not self._duration_reached(self.steps):
            for node in self.nodes:
                node.receive_uplink(self.t_s)
            self.step_all()
            for node in self.nodes:
                node.send(node.take_due(self.steps))
            lag = start + self.t_s - time.monotonic()
            if lag > 0:
                time.sleep(min(lag, REALTIME_MAX_SLEEP_S))

    # --- lockstep -------------------------------------------------------------------------------
    def run_lockstep(self) -> None:
        """Poll; publish the next tick once its time is decided and the physics has reached it; else
        run, in one batch with no poll between its steps, every step the horizon allows (an ack that
        arrives meanwhile can only extend the horizon, and the results never depend on when it is
        seen), publishing the tick the batch reaches; else block briefly on what is missing (a join,
        an ack, frames)."""
        lock = _Lockstep()
        self._last_progress = time.monotonic()
        prof = self.config.profile
        clock = time.perf_counter
        while not self.stopped and not self._duration_reached(self.tick_steps):
            t0 = clock() if prof else 0.0
            self.poll(lock)
            if prof:
                self.timing_s["poll"] += clock() - t0
            n = self.next_tick_steps_decided(lock)
            if n is not None and self.steps >= n:
                self.publish_tick(lock, n)
                continue
            allowed = self.steps_allowed(lock, n)
            if allowed:
                if any(p.acked < self.tick for p in lock.participants.values()):
                    self.lookahead_steps += allowed  # run before every ground station has answered the last tick
                for _ in range(allowed):  # no poll in between: what arrives meanwhile can only extend the horizon
                    self.step_all()
                if n is not None and self.steps >= n:  # as if the acks meanwhile came just after the tick
                    self.publish_tick(lock, n)
                continue
            t0 = clock() if prof else 0.0
            self.wait_briefly(lock)
            if prof:
                self.timing_s["wait"] += clock() - t0
            self.log_if_waiting(lock)

    def next_tick_steps_decided(self, lock: _Lockstep) -> int | None:
        """The step count of the next tick if its time is decided, else None. It is decided when every
        participant has said when it wants it: by acking the last tick (its next wake-up), or by a
        standing period (ClockAck.period_ns: the tick after t comes at t + period), which lets the
        next tick be decided before the last one's acks are in."""
        if not lock.participants:
            return None
        last_ns = round(self.tick_steps * self.dt_s * NS_PER_S)
        wanted = []
        for p in lock.participants.values():
            if p.period_ns > 0 and not p.fresh:  # its standing order (its acks' wake-ups say the same)
                wanted.append(last_ns + p.period_ns)
            elif p.acked >= self.tick:
                wanted.append(p.wake_ns)
            else:
                return None
        return self.next_tick_steps(min(wanted))

    def steps_allowed(self, lock: _Lockstep, next_tick_steps: int | None) -> int:
        """How many physics steps may run now: those that start before the horizon (below), never past
        a decided next tick or the duration (0 before the first tick or with nobody taking part)."""
        if not lock.participants or self.tick < 0:
            return 0
        dt = self.dt_s
        limit = self.horizon_s(lock, next_tick_steps) - LOOKAHEAD_MARGIN_S  # finite once anyone takes part
        end = max(self.steps, math.floor(limit / dt) - 1)  # then exactly: the first step not starting before it
        while end * dt < limit:
            end += 1
        for bound in (next_tick_steps, self.duration_steps):
            if bound is not None and bound < end:
                end = bound
        return max(0, end - self.steps)

    def horizon_s(self, lock: _Lockstep, next_tick_steps: int | None = None) -> float:
        """The earliest time anything a ground station may still send can act on its vehicle.

        A participant's frames are all in (and offered to its radio) up to some tick a (`complete`);
        whatever it sends later belongs to a tick at or after tick a + 1, is offered at that tick's time
        t, so is delivered no earlier than t + L (L = the uplink radio's minimum latency) and taken by
        the firmware at its first cycle at or after that (SimVehicle.first_effect_s). Without
        lookahead, t itself. t: tick a + 1's time when published or decided, else the last tick's
        (a lower bound: a tick is never before the one before it)."""
        horizon = math.inf
        for vid, p in lock.participants.items():
            following = p.complete + 1
            if following <= self.tick:
                t = lock.tick_steps[following] * self.dt_s
            elif following == self.tick + 1 and next_tick_steps is not None:
                t = next_tick_steps * self.dt_s
            else:
                t = self.tick_time_s
            horizon = min(horizon, self.first_effect_s(self.nodes[vid - 1], t))
        return horizon

    def first_effect_s(self, node: VehicleNode, offered_s: float) -> float:
        """The earliest time an uplink frame offered to node's radio at offered_s can act on the
        vehicle: with lookahead, the first firmware cycle at or after offered_s + L; else offered_s."""
        if not self.config.lookahead:
            return offered_s
        return node.sim.first_effect_s(offered_s + node.uplink_radio.min_latency_s)

    def lookahead_horizon_s(self) -> float:
        """The horizon right after a tick at tick_time_s, before any answer to it (benchmarks, tests)."""
        return min(self.first_effect_s(node, self.tick_time_s) for node in self.nodes)

    def poll(self, lock: _Lockstep) -> None:
        """Take every pending ack and uplink sample without blocking, and offer to the radios the
        uplink samples the acks account for."""
        for node in self.nodes:
            for data in node.clock.receive(0.0):
                lock.handle(node.vehicle_id, data, self.tick, self.tick_steps, self.dt_s)
            node.take_uplink()
            if node.held_uplink and node.vehicle_id not in lock.participants:
                node.release_uplink(math.inf, self.tick_time_s)  # nobody's acks account for them
        lock.release(self.nodes, self.dt_s)

    def wait_briefly(self, lock: _Lockstep) -> None:
        """Block a little on whatever the lockstep is waiting for: a join, an ack, or uplink frames."""
        if not lock.participants:
            node = self.nodes[0]
            for data in node.clock.receive(JOIN_POLL_S):
                lock.handle(node.vehicle_id, data, self.tick, self.tick_steps, self.dt_s)
            return
        vid, p = min(lock.participants.items(), key=lambda item: item[1].complete)
        node = self.nodes[vid - 1]
        if p.pending:  # acked, but not all of that tick's frames are in
            node.take_uplink(LAGGARD_POLL_S)
            return
        for data in node.clock.receive(LAGGARD_POLL_S):
            lock.handle(vid, data, self.tick, self.tick_steps, self.dt_s)

    def log_if_waiting(self, lock: _Lockstep) -> None:
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
        dt_ns = self.dt_s * NS_PER_S
        n = max(self.tick_steps, math.floor(target_ns / dt_ns) - 1)
        while round(n * self.dt_s * NS_PER_S) < target_ns:
            n += 1
        if self.duration_steps is not None:
            n = min(n, max(self.duration_steps, self.tick_steps))
        return n

    def publish_tick(self, lock: _Lockstep, n: int) -> None:
        """Publish the frames due by step n in one burst, then the record of the next tick at n. (One
        burst lets zenoh batch the samples into few writes, and the ground station finds the frames
        already there when the record wakes it: measured fewer context switches per tick than
        publishing frames step by step or the record first.)"""
        self.tick += 1
        self.tick_steps = n
        lock.tick_steps[self.tick] = n
        lock.forget_before(min(p.complete for p in lock.participants.values()))
        if self.first_tick_wall is None:
            self.first_tick_wall = time.monotonic()
        time_ns = round(n * self.dt_s * NS_PER_S)
        self.flush(n)
        prof = self.config.profile
        t0 = time.perf_counter() if prof else 0.0
        for node in self.nodes:
            if node.vehicle_id in lock.participants:
                node.clock.send(node.tick_message(self.tick, time_ns).pack())
        self._last_progress = time.monotonic()
        if prof:
            self.timing_s["send"] += time.perf_counter() - t0

    def flush(self, step_no: int) -> None:
        """Publish every vehicle's frames stamped at or before step_no."""
        prof = self.config.profile
        t0 = time.perf_counter() if prof else 0.0
        for node in self.nodes:
            if node.outbox:
                node.send(node.take_due(step_no))
        if prof:
            self.timing_s["send"] += time.perf_counter() - t0

    # --- reports --------------------------------------------------------------------------------
    def summary(self) -> str:
        now = time.monotonic()
        wall = now - self.wall_start
        sim_s = self.tick_time_s if self.config.clock == "lockstep" else self.t_s
        running = now - (self.first_tick_wall or self.wall_start)  # lockstep: from the first tick
        rtf = sim_s / running if running > 0 else 0.0
        parts = [f"emulator: stopped at t={sim_s:.3f} s simulated ({wall:.1f} s wall, {rtf:.3f}x real time), "
                 f"{len(self.nodes)} vehicle(s), seed {self.config.seed}"]
        if self.config.clock == "lockstep":
            parts[0] += f", {self.tick + 1} ticks"
        for node in self.nodes:
            up, down = node.uplink_radio.stats, node.downlink_radio.stats
            crash = "ok"
            if node.sim.crash is not None:
                c = node.sim.crash
                crash = f"crashed at t={c.time_s:.3f} s at ({', '.join(f'{v:.2f}' for v in c.position_enu_m)}) m"
            line = (f"v{node.vehicle_id}: uplink {up.delivered}/{up.offered} delivered, "
                    f"downlink {down.delivered}/{down.offered}, rejected {node.sim.firmware.rejected_commands}")
            c = node.parser.counters
            if self.config.signing is not None or c.signature_failures:
                line += (f", signature failures {c.signature_failures} ({c.unsigned_rejected} unsigned, "
                         f"{c.bad_signatures} bad, {c.replays_rejected} replayed)")
            if node.uplink_foreign:
                line += f", {node.uplink_foreign} foreign uplink samples"
            if self.config.radio_cuts:
                line += f", radio cut {node.cut['uplink']} up / {node.cut['downlink']} down"
            if self.config.mocap_cuts:
                line += f", mocap cut {node.mocap_cut}"
            parts.append(f"{line}, {crash}")
        return "; ".join(parts)

    def radio_report(self) -> dict:
        """Per vehicle and direction: the radio's counters, `cut` (frames a radio cut dropped before
        the radio: not in offered, dropped or the ledger) and, with keep_ledger, every offered frame's
        fate [offered_s, bytes, drop cause or null, [delivery_s...]] in offer order. Per vehicle also:
        `uplink_parser` (the vehicle's frame parser counters: frames_ok, crc_failures, unsigned_rejected,
        bad_signatures, replays_rejected, signature_failures, ...), `uplink_foreign` (uplink samples
        not from the ground station, see GroundFrameGate) and `mocap_cut`."""
        report = {"seed": self.config.seed, "radio": self.config.radio.name, "vehicles": {}}
        for node in self.nodes:
            entry = {}
            for name, radio in (("uplink", node.uplink_radio), ("downlink", node.downlink_radio)):
                s = radio.stats
                entry[name] = {
                    "offered": s.offered, "delivered": s.delivered, "duplicated": s.duplicated,
                    "corrupted": s.corrupted, "dropped": {str(cause): count for cause, count in s.dropped.items()},
                    "dropped_total": s.dropped_total, "pending": radio.pending, "cut": node.cut[name],
                    "ledger": [[f.offered_s, f.size_bytes, f.drop_cause and str(f.drop_cause), list(f.delivery_s)]
                               for f in radio.ledger] if radio.keep_ledger else None,
                }
            entry["rejected_commands"] = node.sim.firmware.rejected_commands
            entry["uplink_parser"] = node.parser.counters.as_dict()
            entry["uplink_foreign"] = node.uplink_foreign
            entry["mocap_cut"] = node.mocap_cut
            entry["crash"] = None if node.sim.crash is None else {
                "time_s": node.sim.crash.time_s, "position_enu_m": list(node.sim.crash.position_enu_m),
                "reason": node.sim.crash.reason}
            report["vehicles"][str(node.vehicle_id)] = entry
        return report

    def write_radio_report(self, path: str | Path) -> None:
        try:
            Path(path).write_text(json.dumps(self.radio_report()))
        except OSError as err:
            raise UserError(f"{path}: cannot write the radio report ({err.strerror})") from None

    def timing_report(self) -> dict[str, float]:
        """Seconds spent per part (with config.profile): the vehicles' own split (uplink handling,
        firmware, sensors, physics), radio, encode/decode, routing, and the transport's send, poll
        and wait."""
        total: dict[str, float] = defaultdict(float)
        for node in self.nodes:
            for name, seconds in node.sim.timing_s.items():
                total[name] += seconds
            for name, seconds in node.timing_s.items():
                total[name] += seconds
        for name, seconds in self.timing_s.items():
            total[name] += seconds
        return dict(total)


def pack_samples(frames: list[bytes]) -> list[bytes]:
    """Whole frames, in order, concatenated into samples of at most MAX_SAMPLE_BYTES (a longer frame
    alone). One zenoh put costs far more than its bytes (measured ~6-9 us each on this kind of machine),
    and the receiving parser takes any number of whole frames per datagram."""
    if len(frames) == 1:
        return frames
    samples, current, size = [], [], 0
    for frame in frames:
        if current and size + len(frame) > MAX_SAMPLE_BYTES:
            samples.append(b"".join(current))
            current, size = [], 0
        current.append(frame)
        size += len(frame)
    samples.append(b"".join(current))
    return samples


def default_starts(world: World | None, count: int, airborne: bool) -> list[tuple[float, float, float]]:
    """Vehicle 1 at the world's start (else the origin): in the air there, or on the floor below it;
    further vehicles 0.5 m apart along +x."""
    floor = 0.0 if world is None else float(world.bounds[4])
    base = np.array([0.0, 0.0, floor])
    if world is not None and world.start is not None:
        base = np.array(world.start, float)
    if not airborne:
        base[2] = floor if world is None else world.support_height(base)
    return [tuple((base + np.array([0.5 * i, 0.0, 0.0])).tolist()) for i in range(count)]


@dataclass
class _Participant:
    """A ground station in the lockstep (one per vehicle id)."""

    acked: int  # the last tick it acknowledged (on joining: the last tick published then)
    wake_ns: int  # when it wants the tick after `acked`
    period_ns: int  # its standing period (ClockAck.period_ns; 0: none)
    complete: int  # the last tick whose uplink frames are all in and offered to the radio
    fresh: bool = True  # joined, no tick acknowledged yet: its standing period does not apply yet
    pending: deque = field(default_factory=deque)  # (tick, uplink_sent) of acks whose frames are not all in


class _Lockstep:
    """Who takes part in the lockstep, what they acknowledged, and when they want to be woken."""

    def __init__(self):
        self.participants: dict[int, _Participant] = {}
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
                p = self.participants[vehicle_id] = _Participant(tick, wake_ns, ack.period_ns, tick - 1)
                self.tick_steps.setdefault(tick, tick_steps)
                p.pending.append((tick, ack.uplink_sent))
            return
        if p is None or ack.tick != p.acked + 1 or ack.tick > tick:
            return  # not a participant, or not the answer to the tick it is on (a repeat, say)
        p.acked = ack.tick
        p.wake_ns = ack.next_wakeup_ns
        p.period_ns = ack.period_ns
        p.fresh = False
        p.pending.append((ack.tick, ack.uplink_sent))

    def release(self, nodes: list[VehicleNode], dt_s: float) -> None:
        """Offer each participant's held uplink samples to its radio at the time of the tick they
        answer, as far as its acks account for them (ClockAck.uplink_sent counts its frames)."""
        for vid, p in self.participants.items():
            node = nodes[vid - 1]
            while p.pending:
                tick, sent = p.pending[0]
                t_s = self.tick_steps[tick] * dt_s
                node.release_uplink(sent, t_s)
                if node.uplink_released < sent:
                    break
                p.pending.popleft()
                p.complete = tick
            if p.complete in self.tick_steps:  # another publisher's samples need no ack: offer them on
                node.release_uplink(node.uplink_released, self.tick_steps[p.complete] * dt_s)

    def forget_before(self, tick: int) -> None:
        for old in [k for k in self.tick_steps if k < tick]:
            del self.tick_steps[old]
