"""The fleet: each emulated vehicle with its radios, codecs, uplink gate and zenoh keys.

Takes in: the EmulatorConfig, a vehicle id and its seed; uplink samples from the transport (or pushed
in-process); the step count of each physics step.
Gives out: per step, the vehicle's frames in its Outbox (downlink through the downlink radio, mocap and
truth on the ground network), RADIO_STATUS once a second, a crash reported once; per-part timing when
profiled. With the crazyflie firmware, CRTP (simulator.crtp_service) on the vehicle's CRTP keys
(link.keys crtp_uplink / crtp_downlink, in both clocks) and, with config.crtp_base_port, on a UDP
endpoint per vehicle for cflib clients (realtime), then also the positioning deck: each mocap frame
into the onboard estimator at its release time while no ground station streams extpose.

CRTP crosses radios of its own (config.crtp_radio's, seeded after the MAVLink ones). With a "crazyradio"
profile each protocol's two directions share one air (simulator.radio.EsbAir, seeded after the radios):
one dongle per protocol, so CRTP and MAVLink never share air. A packet the air loses
is offered again one physics step later, and the ones behind it wait (head of line): cflib's radio
driver resends a packet until it is acknowledged, giving up after CRTP_LINK_ATTEMPTS, and the
Crazyflie's reply rides on an acknowledgement that is resent with it. So CRTP is delayed, not lost, by
the air (the UDP driver alone would never resend). A corrupted copy fails the radio's CRC. Every
attempt's time is decided when the packet is offered (each attempt one step after the last, never
before the previous packet's), so the result does not depend on when steps run (lockstep lookahead).
The vehicle serves what arrives at its next firmware cycle (SimVehicle: CrtpDatagram).

Lockstep and CRTP. A ground station speaks one protocol on its radio, and its acks say which
(ClockAck.crtp). If CRTP, every sample on the vehicle's CRTP uplink key but a null packet counts as its
own (CRTP names no sender; null packets are what its link sends to find the emulator, and some are lost
before the sessions meet) and MAVLink frames are foreign; if MAVLink, CRTP samples are foreign (a cflib
script watching the vehicle, say). CRTP a lockstep ack has not yet accounted for in flight - a vehicle's traffic
before its ground station joins (a cflib connect: TOCs, parameters, log blocks), and any while no
ground station of it takes part - is answered at once, off the air: simulation time may stand
still meanwhile (nobody steps it), and the join must not depend on which key's samples came first.
`default_starts` places a fleet: vehicle 1 at the world's start, the others 0.5 m apart.

Foreign uplink frames. Anyone may publish on a vehicle's uplink key. Every sample is offered to the
uplink radio (so the vehicle's parser rejects what is unsigned, forged or replayed, and counts it), but
only the ground station's own frames count towards the `uplink_sent` its lockstep acks announce
(GroundFrameGate: source system id GROUND_STATION_SYSTEM_ID and, with signing on, a valid signature
newer than the last one, checked by a signing state of the gate's own). Foreign samples are counted
apart (`uplink_foreign`), so they neither release a tick early nor stall one. Without signing, a frame
that claims the ground station's system id cannot be told from its own.
"""

from __future__ import annotations

import logging
import math
from collections import defaultdict, deque

import numpy as np

from link.crtp.packet import is_null
from link.keys import GROUND_STATION_SYSTEM_ID, VehicleKeys
from link.mavlink.codec import IFLAG_SIGNED, MAGIC_V2, MIN_FRAME_LEN, ActuatorLimits, Codec, FrameParser
from link.mavlink.signing import SIGNATURE_BLOCK_LEN, SignatureCheck
from link.messages import ExternalPose, RadioStatus
from link.transports import Transport, open_transport
from link.transports.table import KEYED_SCHEMES, for_vehicle, parse_connection, transport_options
from model.errors import UserError
from model.radio import RadioProfile
from model.world import World
from simulator.crtp_service import CrtpDatagram, CrtpService
from simulator.emulator_config import EmulatorConfig
from simulator.faults import covered
from simulator.profiling import time_parts
from simulator.publishing import CRTP, DOWNLINK, MOCAP, TRUTH, Outbox
from simulator.radio import DOWNLINK as RADIO_DOWNLINK
from simulator.radio import UPLINK as RADIO_UPLINK
from simulator.radio import EsbAir, RadioChannel
from simulator.vehicle_sim import SimVehicle

log = logging.getLogger("cfstack.emulator")

RADIO_STATUS_PERIOD_S = 1.0  # RADIO_STATUS once a second, as SiK radios report it
STEP_TOTAL = "step"  # profiled: a whole VehicleNode.step, the parts included
DECK_YIELD_S = 1.0  # the positioning deck stands aside while a ground station's extpose is this fresh
CRTP_LINK_ATTEMPTS = 100  # cflib radiodriver.py _nr_of_retries: unacknowledged sends before "Too many packets lost"
UPLINK, DOWNLINK_DIRECTION = 0, 1  # the CRTP radios


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


def _radio_pair(profile: RadioProfile, keep_ledger: bool, prefix: str, suffix: str, up_seed: np.random.SeedSequence,
                down_seed: np.random.SeedSequence,
                air_seed: np.random.SeedSequence) -> tuple[RadioChannel, RadioChannel]:
    """(uplink, downlink) channels of one radio; with a "crazyradio" profile both on one shared EsbAir."""
    air = EsbAir(profile.crazyradio, np.random.default_rng(air_seed)) if profile.model == "crazyradio" else None
    up = RadioChannel(profile, np.random.default_rng(up_seed), name=f"{prefix}uplink {suffix}", keep_ledger=keep_ledger,
                      air=air, direction=RADIO_UPLINK)
    down = RadioChannel(profile, np.random.default_rng(down_seed), name=f"{prefix}downlink {suffix}",
                        keep_ledger=keep_ledger, air=air, direction=RADIO_DOWNLINK)
    return up, down


class VehicleNode:
    """One emulated vehicle, its two radio channels, its codecs and (once opened) its zenoh keys.

    `step(step_no)` advances it one physics step and queues what it publishes in its Outbox
    (simulator.publishing) as (step_no, channel, frame). Without transports (never opened) it runs
    in-process, e.g. in benchmarks."""

    def __init__(self, config: EmulatorConfig, vehicle_id: int, rng_seed: np.random.SeedSequence,
                 start: tuple[float, float, float]):
        # the CRTP radios' seeds come after the first three, which stay what they were before CRTP had radios,
        # and the shared airs' after those (SeedSequence children keep their index)
        sim_seed, up_seed, down_seed, crtp_up_seed, crtp_down_seed, air_seed, crtp_air_seed = rng_seed.spawn(7)
        self.vehicle_id = vehicle_id
        self.keys = VehicleKeys(config.prefix, vehicle_id)
        self.sim = SimVehicle(config.vehicle, np.random.default_rng(sim_seed), world=config.world,
                              mocap_room=config.mocap_room, vehicle_id=vehicle_id,
                              physics_rate_hz=config.physics_rate_hz, initial_position_enu_m=start,
                              airborne=config.airborne, profile=config.profile, firmware=config.firmware,
                              variation=config.variation, ideal_parts=config.ideal_parts)
        if not self.sim.draw.is_nominal:
            log.info("vehicle %d draws %s (not told to the ground station)", vehicle_id, self.sim.draw.describe())
        self.uplink_radio, self.downlink_radio = _radio_pair(config.radio, config.keep_ledger, "", f"{vehicle_id}",
                                                             up_seed, down_seed, air_seed)
        # CRTP (cflib clients) on a radio of its own: a second dongle, never MAVLink's air
        self.crtp_uplink_radio, self.crtp_downlink_radio = _radio_pair(
            config.crtp_radio_profile, config.keep_ledger, "crtp ", f"{vehicle_id}", crtp_up_seed, crtp_down_seed,
            crtp_air_seed)
        self._crtp_last_try_s = [-math.inf, -math.inf]  # uplink, downlink: the latest attempt's time
        self.crtp_lost = 0  # packets given up after CRTP_LINK_ATTEMPTS failed attempts
        limits = ActuatorLimits.from_vehicle(config.vehicle)
        self.codec = Codec(system_id=vehicle_id, limits=limits, signing=config.signing)
        self.ground_codec = Codec(system_id=vehicle_id, limits=limits)  # mocap and truth: never signed
        self.parser = FrameParser(self.codec, signing=config.signing)
        gate_signing = config.signing_factory() if config.signing is not None and config.signing_factory else None
        self.gate = GroundFrameGate(require_signed=config.signing is not None, signing=gate_signing)
        self.outbox = Outbox()
        self.uplink_in = 0  # the ground station's uplink frames taken from the transport (GroundFrameGate)
        self.ground_speaks_crtp = False  # lockstep: the participating ground station's protocol (ClockAck.crtp)
        # lockstep: (sample, its ground-station MAVLink frames (GroundFrameGate), CRTP or not), not yet offered
        self.held_uplink: deque[tuple[bytes, int, bool]] = deque()
        # offered from held_uplink: the ground station's MAVLink frames (GroundFrameGate), CRTP packets (not null)
        self._released = [0, 0]
        self.uplink_foreign = 0  # uplink samples with none of its frames (another publisher on the key)
        self.radio_cuts = config.radio_cuts
        self.mocap_cuts = config.mocap_cuts
        self.cut = {"uplink": 0, "downlink": 0}  # radio frames dropped by a radio cut
        self.mocap_cut = 0  # mocap frames not published during a mocap cut
        self.next_radio_status_s = RADIO_STATUS_PERIOD_S
        self.crash_reported = False
        self.reboots_seen = 0
        self.timing_s: dict[str, float] = defaultdict(float)
        self.link: Transport | None = None  # tx downlink, rx uplink
        self.clock: Transport | None = None  # tx clock, rx clock_ack
        # CRTP services: with the crazyflie firmware (the emulated one is the only one that has them)
        self.crtp = CrtpService(self.sim) if config.firmware == "crazyflie" else None
        self.sim.crtp = self.crtp
        self.crtp_keys: Transport | None = None  # CRTP on the vehicle's zenoh keys
        self.crtp_link: Transport | None = None  # CRTP over UDP for cflib clients (realtime)
        self.crtp_seen = False  # a CRTP sample came on the keys (a join's wait blocks on that key)
        self._deck_fixes: deque[tuple[float, ExternalPose]] = deque()  # (release time, fix): outputs come in order
        self._ground_extpose_s = -math.inf  # when the ground station's last extpose arrived
        self.position_deck = config.position_deck and config.crtp_base_port is not None and self.crtp is not None
        if config.profile:
            self._profile()

    # --- transports -----------------------------------------------------------------------------
    def open(self, config: EmulatorConfig) -> None:
        opts = transport_options(config.connection, config.zenoh_options)
        radio = config.connection if config.radio_link is None else for_vehicle(config.radio_link, self.vehicle_id)
        radio_opts = transport_options(radio, config.zenoh_options)
        try:
            self.link = open_transport(radio, tx=self.keys.downlink, rx=self.keys.uplink, **radio_opts)
            mocap = open_transport(config.connection, tx=self.keys.mocap, **opts)
            truth = open_transport(config.connection, tx=self.keys.truth, **opts)
            self.outbox.senders = [self.link, mocap, truth, None]
            self.clock = open_transport(config.connection, tx=self.keys.clock, rx=self.keys.clock_ack, **opts)
            if self.crtp is not None and config.crtp_keys and parse_connection(config.connection)[0] in KEYED_SCHEMES:
                self.crtp_keys = open_transport(config.connection, tx=self.keys.crtp_downlink,
                                                rx=self.keys.crtp_uplink, **opts)
                self.outbox.senders[CRTP] = self.crtp_keys
            if config.crtp_base_port is not None and self.crtp is not None:
                self._open_crtp(config)
        except BaseException:
            self.close()
            raise

    def _open_crtp(self, config: EmulatorConfig) -> None:
        port = config.crtp_base_port + self.vehicle_id - 1
        try:
            self.crtp_link = open_transport(f"udpin:{config.crtp_host}:{port}")
        except UserError as err:
            if not config.crtp_required:
                log.warning("crtp: udp %s:%d is taken (another emulator?): vehicle %d serves no cflib client "
                            "(choose a base with --crtp-port)", config.crtp_host, port, self.vehicle_id)
                self.position_deck = False
                return
            raise UserError(f"crtp: vehicle {self.vehicle_id} cannot serve cflib on udp {config.crtp_host}:{port} "
                            f"({err}); choose another base with --crtp-port or turn it off with --crtp-port off") \
                from None

    def receive_crtp(self, t_s: float) -> None:
        """Realtime, once per step: the CRTP packets that arrived (UDP datagrams, samples on the keys) go
        on the air at t_s."""
        for medium in (self.crtp_link, self.crtp_keys):
            if medium is not None:
                for packet in medium.receive(0.0):
                    self._offer_crtp(UPLINK, packet, t_s)

    def _offer_crtp(self, direction: int, packet: bytes, t_s: float) -> None:
        """One CRTP packet on the air at t_s (uplink or downlink), tried again a physics step later while
        the air loses it, never before the previous packet's last attempt (see the module docstring)."""
        radio = self.crtp_uplink_radio if direction == UPLINK else self.crtp_downlink_radio
        attempt_s = max(t_s, self._crtp_last_try_s[direction])
        for attempt in range(CRTP_LINK_ATTEMPTS):
            if attempt:
                attempt_s += self.sim.dynamics.dt_s
            cut = bool(self.radio_cuts) and covered(self.radio_cuts, attempt_s)
            if not cut and radio.push(packet, attempt_s):
                break
        else:
            self.crtp_lost += 1
        self._crtp_last_try_s[direction] = attempt_s

    def _answer_off_air(self, packet: bytes, t_s: float) -> None:
        """A CRTP packet no lockstep ack accounts for in flight: served now, the replies published now."""
        replies = self.crtp.handle(packet, t_s)
        if replies:
            self.outbox.send([(CRTP, reply) for reply in replies])

    def close(self) -> None:
        for transport in (*self.outbox.senders, self.link, self.clock, self.crtp_link):  # (crtp_keys: a sender)
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

    def take_uplink(self, timeout_s: float = 0.0, wait_on_crtp: bool | None = None) -> int:
        """Lockstep: take the uplink samples that have arrived, count the ground station's frames among
        them, and hold them until its acks account for them (release_uplink). Waiting at most timeout_s on
        the key the ground station speaks on (wait_on_crtp: the CRTP key, None: by ground_speaks_crtp)."""
        crtp_keys = self.crtp_keys
        wait_on_crtp = crtp_keys is not None and (self.ground_speaks_crtp if wait_on_crtp is None else wait_on_crtp)
        samples = self.link.receive(0.0 if wait_on_crtp else timeout_s)
        for sample in samples:
            self.held_uplink.append((sample, self._count_arrival(sample), False))
        if crtp_keys is None:
            return len(samples)
        packets = crtp_keys.receive(timeout_s if wait_on_crtp else 0.0)
        for packet in packets:  # CRTP names no sender: a packet is the CRTP ground station's but a null one
            self.held_uplink.append((packet, 0 if is_null(packet) else 1, True))
        if packets:
            self.crtp_seen = True
        return len(samples) + len(packets)

    def _count_arrival(self, sample: bytes) -> int:
        """The ground station's frames in an arriving uplink sample (GroundFrameGate), counted."""
        ours = self.gate.count(sample)
        self.uplink_in += ours
        if not ours:
            self.uplink_foreign += 1
        return ours

    def release_uplink(self, sent: float, push_time_s: float, off_air: bool = False) -> None:
        """Offer held samples, in arrival order, to the radio at push_time_s while the ground station's
        frames among them stay within `sent` (its ack's count); a foreign sample goes with them.
        sent = uplink_released: only the foreign samples at the head; math.inf: every held sample.
        off_air: CRTP packets among them are answered at once, off the air (see the module docstring)."""
        held = self.held_uplink
        crtp_ground = self.ground_speaks_crtp
        while held:
            sample, counted, is_crtp = held[0]
            ours = counted if is_crtp == crtp_ground else 0  # the other protocol's samples are foreign
            if self.uplink_released + ours > sent:
                break
            held.popleft()
            self._released[is_crtp] += counted  # each protocol's own count: the join's ack may come later
            if is_crtp and not off_air:  # counted here, once a tick accounts for them (MAVLink: on arrival)
                self.uplink_in += ours
                self.uplink_foreign += not ours
            if not is_crtp:
                self._offer_uplink((sample,), push_time_s)
            elif off_air:
                self._answer_off_air(sample, push_time_s)
            else:
                self._offer_crtp(UPLINK, sample, push_time_s)

    @property
    def uplink_min_latency_s(self) -> float:
        """L: the least latency of this vehicle's uplink radios, MAVLink's and CRTP's (a true lower bound on when
        a frame offered to either reaches the vehicle; the lockstep's horizon and RADIO_STATUS's cutoff)."""
        return min(self.uplink_radio.min_latency_s, self.crtp_uplink_radio.min_latency_s)

    @property
    def uplink_released(self) -> int:
        """The ground station's frames (or CRTP packets, if it speaks CRTP) offered from held_uplink."""
        return self._released[self.ground_speaks_crtp]

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

    # --- one physics step -----------------------------------------------------------------------
    def step(self, step_no: int) -> None:
        """Deliver the uplink frames due at the step's start, step the vehicle, route its outputs
        (stamped step_no: the step count once this step is done)."""
        sim = self.sim
        t = sim.t_s
        due = self.uplink_radio.pop_due(t)  # [] at once when nothing is due (the radio's own check)
        if due:
            self._deliver_uplink(due, t)
        if self.crtp is not None:
            for packet in self.crtp_uplink_radio.pop_due(t, discard_corrupted=True):
                sim.handle_uplink(CrtpDatagram(packet), t)
        sim.step()
        t = sim.t_s
        outbox = self.outbox.queue
        for release_s, channel, message in sim.pop_outputs():
            if channel == "downlink":
                self._offer_downlink(self.codec.encode(message), release_s)  # encoded: a cut frame uses its seq
            elif channel == "mocap":
                if not self._mocap_cut(release_s):
                    outbox.append((step_no, MOCAP, self.ground_codec.encode(message)))
                if self.position_deck:
                    self._queue_deck_fix(message, release_s)
            elif channel == "truth":
                outbox.append((step_no, TRUTH, self.ground_codec.encode(message)))
            else:
                self._offer_crtp(DOWNLINK_DIRECTION, message, release_s)
        self._finish_step(t, step_no)

    def _queue_deck_fix(self, pose, release_s: float) -> None:
        self._deck_fixes.append((release_s, ExternalPose(pose.time_s, pose.position_enu_m, pose.attitude_wxyz)))

    def _feed_deck(self, t: float) -> None:
        """The positioning deck's fixes released by t into the onboard estimator, unless the ground station
        streamed extpose within the last DECK_YIELD_S (then its poses are the vehicle's position source)."""
        fixes = self._deck_fixes
        ground_s = max(self._ground_extpose_s, self.crtp.last_extpos_s)
        while fixes and fixes[0][0] <= t:
            _, fix = fixes.popleft()
            if t - ground_s > DECK_YIELD_S:
                self.sim.firmware.take_position_fix(fix, t)

    def _finish_step(self, t: float, step_no: int) -> None:
        """The end of a step at time t: RADIO_STATUS when due, the downlink frames the radio delivers
        by t into the outbox, a crash reported once."""
        if self._deck_fixes:
            self._feed_deck(t)
        if t >= self.next_radio_status_s:
            self._push_radio_status(t)
        outbox = self.outbox.queue
        for frame in self.downlink_radio.pop_due(t):
            outbox.append((step_no, DOWNLINK, frame))
        if self.crtp is not None:
            for packet in self.crtp_downlink_radio.pop_due(t, discard_corrupted=True):
                outbox.append((step_no, CRTP, packet))
                if self.crtp_link is not None:  # a cflib client over UDP (realtime)
                    self.crtp_link.send(packet)
        sim = self.sim
        if sim.reboots != self.reboots_seen:
            self._report_reboot(t)
        if sim.crash is not None and not self.crash_reported:
            self._report_crash(step_no)

    def _deliver_uplink(self, frames: list[bytes], t: float) -> None:
        feed, handle = self.parser.feed, self.sim.handle_uplink
        for frame in frames:
            for decoded in feed(frame, True):  # each uplink sample is whole frames (a datagram)
                if isinstance(decoded.message, ExternalPose):
                    self._ground_extpose_s = t
                handle(decoded.message, t)

    def _push_radio_status(self, t: float) -> None:
        self.next_radio_status_s += RADIO_STATUS_PERIOD_S
        # The vehicle's own reception (rssi) over the uplink frames offered by t - dt - L - one firmware cycle
        # (t the end of the step just run, L the uplink radios' least latency): a lockstep emulator running
        # ahead (lockstep.py) starts a step only before the first firmware cycle at or after t_next + L, t_next
        # the time of the next tick whose frames may not all be in, so every frame offered by then is; later
        # ones may be or not, depending on when their ack came.
        settled_s = t - self.sim.dynamics.dt_s - self.sim.firmware_period_s - self.uplink_min_latency_s
        status = RadioStatus(**self.downlink_radio.radio_status(reverse=self.uplink_radio,
                                                                reverse_offered_by_s=settled_s))
        self._offer_downlink(self.codec.encode(status), t)

    def _report_crash(self, step_no: int) -> None:
        """Once per crash: a log line saying what happened and how to go on, and the simulation-only
        CrashReport on the truth key (for the ground station's logs and grading)."""
        self.crash_reported = True
        crash = self.sim.crash
        self.outbox.queue.append((step_no, TRUTH, self.ground_codec.encode(crash)))
        log.warning("vehicle %d crashed: %s. It stays crashed until a ground station asks for a reset "
                    "(`cfstack groundstation --reset`, MAVLink MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN) or the "
                    "emulator restarts", self.vehicle_id, crash.describe())

    def _report_reboot(self, t: float) -> None:
        self.reboots_seen = self.sim.reboots
        self.crash_reported = False
        x, y, z = self.sim.dynamics.position_enu_m
        log.warning("vehicle %d reset by a ground station's REBOOT at t=%.3f s: disarmed, at rest at "
                    "(%.3f, %.3f, %.3f) m", self.vehicle_id, t, x, y, z)


    def _profile(self) -> None:
        """Time the parts of every step (benchmarks): radio, decode, outputs, encode, and the whole step,
        from which Emulator.timing_report derives the routing left over. The vehicle's own split
        (uplink handling, firmware, sensors, physics) is in sim.timing_s."""
        timing = self.timing_s
        time_parts(self.uplink_radio, {"pop_due": "radio"}, timing)
        time_parts(self.downlink_radio, {"push": "radio", "pop_due": "radio"}, timing)
        time_parts(self.codec, {"encode": "encode"}, timing)
        time_parts(self.ground_codec, {"encode": "encode"}, timing)
        time_parts(self.sim, {"pop_outputs": "outputs"}, timing)
        time_parts(self, {"_deliver_uplink": "decode", "step": STEP_TOTAL}, timing)


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
