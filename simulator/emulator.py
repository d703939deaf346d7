"""The emulator process: simulated Crazyflies behind simulated radios, answering on zenoh.

Takes in: uplink MAVLink frames on each vehicle's uplink key (through the vehicle's uplink radio),
lockstep acknowledgements on the clock-ack keys.
Gives out: downlink frames (through the downlink radio), mocap poses (ground network, no radio),
simulation-only ground truth, and lockstep clock ticks. Keys: link.keys.VehicleKeys.

Clocks: `realtime` paces physics by the monotonic wall clock; `lockstep` advances simulation time
only when every ground station taking part has acknowledged the previous tick (link.clock), so a run
depends on the seed alone.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np

from link.clock import NS_PER_S, ClockTick, unpack_ack
from link.codec import ActuatorLimits, Codec, FrameParser
from link.keys import VehicleKeys
from link.messages import RadioStatus
from link.transports import Transport, open_transport
from link.vehicle import MocapRoom, Vehicle
from link.world import World
from simulator.radio import RadioChannel, RadioProfile
from simulator.vehicle_sim import SimVehicle

log = logging.getLogger("cfstack.emulator")

RADIO_STATUS_PERIOD_S = 1.0  # RADIO_STATUS once a second, as SiK radios report it
WAIT_LOG_PERIOD_S = 5.0  # how often a waiting lockstep emulator says so


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


class VehicleNode:
    """One emulated vehicle with its radio channels and its zenoh keys."""

    def __init__(self, config: EmulatorConfig, vehicle_id: int, rng_seed: np.random.SeedSequence,
                 start: tuple[float, float, float]):
        sim_seed, up_seed, down_seed = rng_seed.spawn(3)
        self.vehicle_id = vehicle_id
        self.keys = VehicleKeys(config.prefix, vehicle_id)
        self.sim = SimVehicle(config.vehicle, np.random.default_rng(sim_seed), world=config.world,
                              mocap_room=config.mocap_room, vehicle_id=vehicle_id,
                              physics_rate_hz=config.physics_rate_hz, initial_position_enu_m=start,
                              airborne=config.airborne)
        self.uplink_radio = RadioChannel(config.radio, np.random.default_rng(up_seed), name=f"uplink {vehicle_id}")
        self.downlink_radio = RadioChannel(config.radio, np.random.default_rng(down_seed),
                                           name=f"downlink {vehicle_id}")
        limits = ActuatorLimits.from_vehicle(config.vehicle)
        self.codec = Codec(system_id=vehicle_id, limits=limits, signing=config.signing)
        self.truth_codec = Codec(system_id=vehicle_id, limits=limits)
        self.parser = FrameParser(self.codec, signing=config.signing)
        self.counts = {"downlink": 0, "mocap": 0, "truth": 0, "uplink_in": 0}
        self.mocap_queue: list[tuple[float, bytes]] = []
        self.next_radio_status_s = RADIO_STATUS_PERIOD_S
        self.crash_reported = False
        self.link: Transport | None = None

    def open(self, config: EmulatorConfig) -> None:
        opts = config.zenoh_options
        self.link = open_transport(config.connection, tx=self.keys.downlink, rx=self.keys.uplink, **opts)
        self.mocap_tx = open_transport(config.connection, tx=self.keys.mocap, **opts)
        self.truth_tx = open_transport(config.connection, tx=self.keys.truth, **opts)
        self.clock = open_transport(config.connection, tx=self.keys.clock, rx=self.keys.clock_ack, **opts)

    def clock_wait(self, lock: _Lockstep, emulator: Emulator, tick: int, timeout_s: float) -> None:
        """Block up to timeout_s for this vehicle's next ack (the caller has nothing else to do)."""
        for data in self.clock.receive(timeout_s):
            lock.handle(self.vehicle_id, data, tick, emulator.t_s)
        self.take_uplink(emulator.t_s)

    def close(self) -> None:
        for t in (self.link, getattr(self, "mocap_tx", None), getattr(self, "truth_tx", None),
                  getattr(self, "clock", None)):
            if t is not None:
                t.close()

    # --- the radio edge -------------------------------------------------------------------------
    def take_uplink(self, now_s: float) -> int:
        """Offer every uplink frame that has arrived on zenoh to the uplink radio at time now_s."""
        frames = self.link.receive(0.0)
        for frame in frames:
            self.uplink_radio.push(frame, now_s)
        self.counts["uplink_in"] += len(frames)
        return len(frames)

    def step(self) -> None:
        """One physics step: deliver due uplink frames, step the vehicle, route its outputs."""
        t = self.sim.t_s
        for frame in self.uplink_radio.pop_due(t):
            for decoded in self.parser.feed(frame):
                self.sim.handle_uplink(decoded.message, t)
        self.sim.step()
        t = self.sim.t_s
        for release_s, channel, message in self.sim.pop_outputs():
            if channel == "downlink":
                self.downlink_radio.push(self.codec.encode(message), release_s)
            elif channel == "mocap":
                self.mocap_queue.append((release_s, self.truth_codec.encode(message)))
            elif channel == "truth":
                self.truth_tx.send(self.truth_codec.encode(message))
                self.counts["truth"] += 1
        if t >= self.next_radio_status_s:
            self.next_radio_status_s += RADIO_STATUS_PERIOD_S
            status = RadioStatus(**self.downlink_radio.radio_status())
            self.downlink_radio.push(self.codec.encode(status), t)
        self.publish_due(t)
        if self.sim.crash is not None and not self.crash_reported:
            self.crash_reported = True
            c = self.sim.crash
            pos = ", ".join(f"{v:.3f}" for v in c.position_enu_m)
            log.warning("vehicle %d crashed at t=%.3f s at (%s) m: %s", self.vehicle_id, c.time_s, pos, c.reason)

    def publish_due(self, t: float) -> None:
        for frame in self.downlink_radio.pop_due(t):
            self.link.send(frame)
            self.counts["downlink"] += 1
        while self.mocap_queue and self.mocap_queue[0][0] <= t:
            self.mocap_tx.send(self.mocap_queue.pop(0)[1])
            self.counts["mocap"] += 1

    def tick_message(self, tick: int, time_ns: int) -> ClockTick:
        return ClockTick(tick, time_ns, self.counts["downlink"], self.counts["mocap"], self.counts["truth"])


class Emulator:
    def __init__(self, config: EmulatorConfig):
        self.config = config
        seeds = np.random.SeedSequence(config.seed).spawn(config.vehicles)
        starts = config.start_positions_enu_m or default_starts(config.world, config.vehicles, config.airborne)
        self.nodes = [VehicleNode(config, i + 1, seeds[i], starts[i]) for i in range(config.vehicles)]
        self.dt_s = 1.0 / config.physics_rate_hz
        self.steps = 0
        self.stopped = False
        self.wall_start = 0.0

    @property
    def t_s(self) -> float:
        return self.steps * self.dt_s

    def __enter__(self) -> Emulator:
        for node in self.nodes:
            node.open(self.config)
        return self

    def __exit__(self, *exc) -> None:
        for node in self.nodes:
            node.close()

    def step_all(self) -> None:
        for node in self.nodes:
            node.step()
        self.steps += 1

    def run(self) -> None:
        self.wall_start = time.monotonic()
        if self.config.clock == "realtime":
            self.run_realtime()
        else:
            self.run_lockstep()

    def finished(self) -> bool:
        return self.stopped or (self.config.duration_s is not None and self.t_s >= self.config.duration_s)

    def run_realtime(self) -> None:
        start = time.monotonic()
        while not self.finished():
            for node in self.nodes:
                node.take_uplink(self.t_s)
            self.step_all()
            lag = start + self.t_s - time.monotonic()
            if lag > 0:
                time.sleep(lag)

    def run_lockstep(self) -> None:
        lock = _Lockstep()
        tick = -1  # the last tick published
        last_log = time.monotonic()
        while not self.finished():
            got = self.collect_acks(lock, tick)
            if not lock.participants:
                if time.monotonic() - last_log > WAIT_LOG_PERIOD_S:
                    log.info("lockstep: waiting for a ground station to join (t=%.3f s)", self.t_s)
                    last_log = time.monotonic()
                if not got:
                    self.nodes[0].clock_wait(lock, self, tick, timeout_s=0.05)
                continue
            if not lock.ready(self.nodes, tick):
                if time.monotonic() - last_log > WAIT_LOG_PERIOD_S:
                    log.info("lockstep: waiting for the ground station to finish tick %d (t=%.3f s)",
                             tick, self.t_s)
                    last_log = time.monotonic()
                if not got:
                    self.wait_for_laggard(lock, tick)
                continue
            target_ns = min(lock.participants.values())
            while round(self.t_s * NS_PER_S) < target_ns and not self.finished():
                self.step_all()
            tick += 1
            now_ns = round(self.t_s * NS_PER_S)
            lock.acked.clear()
            for node in self.nodes:
                if node.vehicle_id in lock.participants:
                    node.clock.send(node.tick_message(tick, now_ns).pack())

    def wait_for_laggard(self, lock: _Lockstep, tick: int) -> None:
        """Block briefly on whatever the lockstep is waiting for: an ack, or uplink frames."""
        for vid in lock.participants:
            node = self.nodes[vid - 1]
            if vid not in lock.acked:
                node.clock_wait(lock, self, tick, timeout_s=0.002)
                return
            if node.counts["uplink_in"] < lock.uplink_expected.get(vid, 0):
                for frame in node.link.receive(0.002):
                    node.uplink_radio.push(frame, self.t_s)
                    node.counts["uplink_in"] += 1
                return

    def collect_acks(self, lock: _Lockstep, tick: int) -> bool:
        """Read every pending ack and uplink frame without blocking; True if anything arrived."""
        got = False
        for node in self.nodes:
            for data in node.clock.receive(0.0):
                got = True
                lock.handle(node.vehicle_id, data, tick, self.t_s)
            got = node.take_uplink(self.t_s) > 0 or got
        return got

    def summary(self) -> str:
        wall = time.monotonic() - self.wall_start
        parts = [f"emulator: stopped at t={self.t_s:.3f} s simulated ({wall:.1f} s wall), "
                 f"{len(self.nodes)} vehicle(s)"]
        for node in self.nodes:
            up, down = node.uplink_radio.stats, node.downlink_radio.stats
            crash = "crashed" if node.sim.crash else "ok"
            parts.append(f"v{node.vehicle_id}: uplink {up.delivered}/{up.offered} delivered, "
                         f"downlink {down.delivered}/{down.offered}, {crash}")
        return "; ".join(parts)


def default_starts(world: World | None, count: int, airborne: bool) -> list[tuple[float, float, float]]:
    """Vehicle 1 at the world's start (else the origin): in the air there, or on the floor below it;
    further vehicles 0.5 m apart along +x."""
    floor = 0.0 if world is None else float(world.bounds[4])
    base = np.array([0.0, 0.0, floor])
    if world is not None and world.start is not None:
        base = np.array(world.start, float)
    if not airborne:
        base[2] = floor
    return [tuple((base + np.array([0.5 * i, 0.0, 0.0])).tolist()) for i in range(count)]


class _Lockstep:
    """Who takes part in the lockstep, what they acknowledged, and when they want to be woken."""

    def __init__(self):
        self.participants: dict[int, int] = {}  # vehicle id -> next wakeup, ns
        self.uplink_expected: dict[int, int] = {}
        self.acked: set[int] = set()

    def handle(self, vehicle_id: int, data: bytes, tick: int, now_s: float) -> None:
        ack = unpack_ack(data)
        if ack is None:
            log.warning("lockstep: ignored a malformed clock ack for vehicle %d", vehicle_id)
            return
        if ack.leaving:
            self.participants.pop(vehicle_id, None)
            self.acked.discard(vehicle_id)
            log.info("lockstep: the ground station of vehicle %d left at t=%.3f s", vehicle_id, now_s)
            return
        if ack.tick == -1:
            if vehicle_id not in self.participants:
                log.info("lockstep: a ground station joined for vehicle %d at t=%.3f s", vehicle_id, now_s)
            self.participants[vehicle_id] = round(now_s * NS_PER_S)
        elif ack.tick == tick and vehicle_id in self.participants:
            self.participants[vehicle_id] = ack.next_wakeup_ns
        else:
            return
        self.uplink_expected[vehicle_id] = ack.uplink_sent
        self.acked.add(vehicle_id)

    def ready(self, nodes: list[VehicleNode], tick: int) -> bool:
        for vid in self.participants:
            if tick >= 0 and vid not in self.acked:
                return False
            if nodes[vid - 1].counts["uplink_in"] < self.uplink_expected.get(vid, 0):
                return False
        return True
