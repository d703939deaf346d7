"""The emulator process over zenoh, against a minimal scripted ground station in this process.

The emulator runs as `python -m cfstack emulator --connect <our endpoint>`; `Responder` joins its lockstep
clock for one vehicle, waits for each tick's frames (the counts the tick announces), sends scripted
uplink messages and acknowledges. Checked: startup time, clean stop on SIGTERM / Ctrl-C, the clock
standing still without acks, byte-identical downlink for equal seeds (with and without lookahead),
radio loss measured at the receiver = the emulator radio's own decisions, crash reporting, rejection
of non-finite commands, several vehicles in one process.
"""

from __future__ import annotations

import hashlib
import json
import math
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from contextlib import contextmanager

import pytest
from testsupport import free_port

from link.clock import NS_PER_S, ClockAck, ClockTick, unpack_tick
from link.keys import GROUND_STATION_SYSTEM_ID, VehicleKeys
from link.mavlink.codec import ActuatorLimits, Codec, FrameParser
from link.messages import (
    BatteryStatus,
    CommandKind,
    Heartbeat,
    ImuSample,
    MocapPose,
    ThrustMoment,
    TimeSync,
    TruthState,
    VehicleCommand,
    VehicleMode,
)
from link.stats import LinkStats
from link.transports import open_transport
from model.vehicle import GRAVITY_MPS2, load_vehicle
from simulator.firmware import load_firmware_params

VEHICLE = load_vehicle("crazyflie")
LIMITS = ActuatorLimits.from_vehicle(VEHICLE)
PREFIX = "emutest"
STARTUP_LIMIT_S = 2.0  # issue "The emulator": ready within 2 s of being started
TIMEOUT_S = 30.0

IID10_PROFILE = """\
schema_version = 1
name = "iid10"
source = "test profile: 10 % i.i.d. loss, 2 ms fixed latency, nothing else"
model = "simple"
[latency]
base_s = 0.002
jitter = "uniform"
jitter_s = 0.0
preserve_order = true
reorder_probability = 0.0
reorder_delay_s = 0.0
[loss]
probability = 0.1
[burst]
p_good_to_bad = 0.0
p_bad_to_good = 1.0
loss_good = 0.0
loss_bad = 0.0
[duplication]
probability = 0.0
[corruption]
frame_probability = 0.0
bits_per_frame = 1
bit_error_rate = 0.0
[queue]
bandwidth_bps = 0.0
capacity_frames = 0
[status]
window_frames = 100
"""

Script = Callable[[int, float], list]


def no_commands(tick: int, t_s: float) -> list:  # noqa: ARG001 - script signature
    return []


def hover_script(thrust_n: float) -> Script:
    """ARM at the first tick, then a ThrustMoment of thrust_n and no moment at every tick."""

    def script(tick: int, t_s: float) -> list:
        messages = [VehicleCommand(t_s, CommandKind.ARM)] if tick == 0 else []
        return messages + [ThrustMoment(t_s, thrust_n, (0.0, 0.0, 0.0))]

    return script


def free_endpoint() -> str:
    return f"tcp/127.0.0.1:{free_port()}"


class Responder:
    """A minimal lockstep ground station for one vehicle (what groundstation.clocks.LockstepClock does,
    without estimator or controller): join, then per tick: wait for the announced frames, send the
    script's messages, ack with the next wake-up = tick time + period."""

    def __init__(self, endpoint: str, script: Script = no_commands, *, vehicle_id: int = 1,
                 period_s: float = 0.01, prefix: str = PREFIX):
        opts = {"listen": [endpoint]}
        self.keys = VehicleKeys(prefix, vehicle_id)
        self.script = script
        self.period_ns = round(period_s * NS_PER_S)
        self.codec = Codec(GROUND_STATION_SYSTEM_ID, limits=LIMITS)
        self.radio = open_transport("zenoh", tx=self.keys.uplink, rx=self.keys.downlink, **opts)
        self.mocap_rx = open_transport("zenoh", rx=self.keys.mocap, **opts)
        self.truth_rx = open_transport("zenoh", rx=self.keys.truth, **opts)
        self.clock = open_transport("zenoh", tx=self.keys.clock_ack, rx=self.keys.clock, **opts)
        self.parser = FrameParser(self.codec)
        self.stats = LinkStats(shared_clock=True)  # loss from sequence numbers, at the receiver
        self.stats.attach_parser(self.parser)
        self.ground_parser = FrameParser(self.codec)
        self.raw_downlink: list[bytes] = []  # every frame that decoded, as bytes (a sample may hold several)
        self.downlink: list[tuple[float, object]] = []  # (tick time, message)
        self.mocap: list[tuple[float, MocapPose]] = []
        self.truth: list[tuple[float, TruthState]] = []
        self.ticks: list[ClockTick] = []
        self.counts = [0, 0, 0]
        self.t_s = 0.0

    def close(self) -> None:
        for transport in (self.radio, self.mocap_rx, self.truth_rx, self.clock):
            transport.close()

    def __enter__(self) -> Responder:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def uplink_sent(self) -> int:
        return self.radio.stats.frames_sent

    def join(self) -> None:
        assert self.clock.wait_for_subscribers(TIMEOUT_S), "no emulator subscribes to the clock acks"
        self.clock.send(ClockAck(-1, self.uplink_sent, 0).pack())

    def next_tick(self, timeout_s: float = TIMEOUT_S) -> ClockTick | None:
        """The next tick (None if none comes within timeout_s), with all the frames it announces."""
        last = self.ticks[-1].tick if self.ticks else -1
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            for data in self.clock.receive(min(0.05, timeout_s)):
                tick = unpack_tick(data)
                if tick is not None and tick.tick > last:
                    self.ticks.append(tick)
                    self.t_s = tick.time_s
                    self.collect(tick)
                    return tick
        return None

    def collect(self, tick: ClockTick) -> None:
        want = (tick.downlink_published, tick.mocap_published, tick.truth_published)
        deadline = time.monotonic() + TIMEOUT_S
        self.drain(0.0)
        while any(have < need for have, need in zip(self.counts, want, strict=True)):
            assert time.monotonic() < deadline, f"frames of tick {tick.tick} never came: {self.counts} < {want}"
            self.drain(0.005)

    def drain(self, timeout_s: float) -> None:
        """Take what arrived; block up to timeout_s on the first key still short of its count."""
        want = self.ticks[-1] if self.ticks else None
        short = 0
        if want is not None:
            needs = (want.downlink_published, want.mocap_published, want.truth_published)
            short = next((i for i in range(3) if self.counts[i] < needs[i]), 0)
        sources = (self.radio, self.mocap_rx, self.truth_rx)
        for i, source in enumerate(sources):
            frames = source.receive(timeout_s if i == short else 0.0)
            self.counts[i] += len(frames)
            for frame in frames:
                self._decode(i, frame)

    def _decode(self, channel: int, frame: bytes) -> None:
        if channel == 0:
            for decoded in self.parser.feed(frame, True):
                self.raw_downlink.append(decoded.frame)
                self.stats.record_received(decoded, self.t_s)
                self.downlink.append((self.t_s, decoded.message))
            return
        for decoded in self.ground_parser.feed(frame, True):
            (self.mocap if channel == 1 else self.truth).append((self.t_s, decoded.message))

    def send(self, message) -> None:
        self.radio.send(self.codec.encode(message, self.keys.vehicle_id))

    def ack(self, tick: ClockTick, next_wakeup_ns: int | None = None) -> None:
        wake = tick.time_ns + self.period_ns if next_wakeup_ns is None else next_wakeup_ns
        self.clock.send(ClockAck(tick.tick, self.uplink_sent, wake).pack())

    def leave(self) -> None:
        tick = self.ticks[-1].tick if self.ticks else -1
        self.clock.send(ClockAck(tick, self.uplink_sent, 0, leaving=True).pack())

    def fly(self, until_s: float) -> None:
        """Join and follow the clock until a tick at or after until_s (answered, not acked), then leave."""
        self.join()
        while True:
            tick = self.next_tick()
            assert tick is not None, f"the emulator's clock stopped at t={self.t_s:.3f} s"
            for message in self.script(tick.tick, tick.time_s):
                self.send(message)
            if tick.time_s >= until_s - 1e-9:
                break
            self.ack(tick)
        self.leave()

    def downlink_hash(self) -> str:
        return hashlib.sha256(b"".join(len(f).to_bytes(2, "little") + f for f in self.raw_downlink)).hexdigest()

    def messages(self, kind: type) -> list[tuple[float, object]]:
        return [(t, m) for t, m in self.downlink if isinstance(m, kind)]


@contextmanager
def emulator(endpoint: str, *args: str):
    """`python -m cfstack emulator` connected to our endpoint; yields the process, stops it at the end."""
    # the ideal firmware: these tests check the emulator's protocol and commander against the exact mixer
    cmd = [sys.executable, "-m", "cfstack", "emulator", "--connect", endpoint, "--id", PREFIX, "--clock", "lockstep",
           "--firmware", "ideal", "--quiet", *args]
    proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True)
    try:
        yield proc
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.communicate()


def stop(proc: subprocess.Popen, sig: int = signal.SIGTERM) -> tuple[int, list[str]]:
    """Signal the emulator; (exit code, stderr lines)."""
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=10)
    return proc.returncode, err.strip().splitlines()


def flight(endpoint: str, script: Script, until_s: float, *emulator_args: str, period_s: float = 0.01):
    """One scripted flight; (responder, emulator exit code, emulator stderr lines)."""
    with Responder(endpoint, script, period_s=period_s) as gs, emulator(endpoint, *emulator_args) as proc:
        gs.fly(until_s)
        code, lines = stop(proc)
        return gs, code, lines


# ----------------------------------------------------------------------------------------------------


def seconds_to_first_tick() -> float:
    """Spawn an emulator with our ground station already waiting; seconds until tick 0 arrives."""
    endpoint = free_endpoint()
    with Responder(endpoint) as gs:
        start = time.monotonic()
        with emulator(endpoint) as proc:
            gs.join()
            tick = gs.next_tick(timeout_s=20.0)
            elapsed = time.monotonic() - start
            assert tick is not None and tick.tick == 0 and tick.time_ns == 0
            stop(proc)
    return elapsed


@pytest.mark.realtime
def test_starts_within_two_seconds_and_answers_the_first_tick():
    """Wall-clock requirement on a shared machine: one of up to three starts must make it."""
    attempts = []
    for _ in range(3):
        attempts.append(seconds_to_first_tick())
        if attempts[-1] < STARTUP_LIMIT_S:
            break
    assert min(attempts) < STARTUP_LIMIT_S, f"first tick after {', '.join(f'{a:.2f}' for a in attempts)} s"


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_stops_it_cleanly_with_a_one_line_summary(sig):
    endpoint = free_endpoint()
    with Responder(endpoint, period_s=0.05) as gs, emulator(endpoint) as proc:
        gs.join()
        for _ in range(5):
            gs.ack(gs.next_tick())
        code, lines = stop(proc, sig)
    assert code == 0
    assert len(lines) == 1 and lines[0].startswith("emulator: stopped at t="), lines
    assert "Traceback" not in "\n".join(lines)


def test_lockstep_time_stands_still_without_a_ground_station_or_its_acks():
    endpoint = free_endpoint()
    with Responder(endpoint) as gs, emulator(endpoint) as proc:
        time.sleep(1.0)  # no ground station yet
        gs.join()
        first = gs.next_tick()
        assert first.tick == 0 and first.time_ns == 0, "simulation time moved before anyone joined"
        assert gs.next_tick(timeout_s=0.5) is None, "a tick came without an ack"
        gs.drain(0.05)
        assert gs.counts == [first.downlink_published, first.mocap_published, first.truth_published], \
            "frames beyond the unacknowledged tick were published"
        gs.ack(first, next_wakeup_ns=100_000_000)
        second = gs.next_tick()
        assert second is not None and second.tick == 1 and second.time_ns == 100_000_000
        assert gs.counts[0] > 0 and gs.counts[2] > 0  # 0.1 s of IMU and truth frames arrived with it
        stop(proc)


def hover_and_timesync_script(thrust_n: float, every: int) -> Script:
    """hover_script, plus a TIMESYNC request every `every` ticks (its reply enters the downlink)."""
    hover = hover_script(thrust_n)

    def script(tick: int, t_s: float) -> list:
        messages = hover(tick, t_s)
        if tick % every == 0:
            messages.append(TimeSync(remote_ns=0, origin_ns=round(t_s * NS_PER_S) + 1))
        return messages

    return script


@pytest.mark.parametrize(("radio", "period_s"), [("lab", 0.01), ("esb-duplex", 0.002), ("crazyradio", 0.002)])
def test_same_seed_same_downlink_bytes_with_or_without_lookahead_other_seed_differs(radio, period_s):
    """The lab radio (20 ms minimum latency) lets the emulator run two 10 ms ticks ahead; esb-duplex's
    0.84 ms and crazyradio's 0.17 ms, rounded up to the firmware's next 2 ms cycle, one whole 500 Hz tick.
    crazyradio's two directions share one air whose downlink runs ahead of the uplink under lookahead: the
    bytes must still be the same (its 500 Hz HIGHRES_IMU overfills the one radio, so fewer frames arrive)."""
    script = hover_and_timesync_script(1.02 * VEHICLE.weight_n, every=round(0.1 / period_s))
    runs = {}
    for name, args in {"a": ("--seed", "7"), "b": ("--seed", "7"), "no_lookahead": ("--seed", "7", "--no-lookahead"),
                       "other_seed": ("--seed", "8")}.items():
        gs, code, _ = flight(free_endpoint(), script, 1.5, "--radio", radio, *args, period_s=period_s)
        assert code == 0
        assert len(gs.raw_downlink) > 300
        assert len(gs.messages(TimeSync)) >= 10  # replies to the requests are part of the compared bytes
        runs[name] = gs.downlink_hash()
    assert runs["a"] == runs["b"] == runs["no_lookahead"]
    assert runs["other_seed"] != runs["a"]


def test_loss_measured_at_the_receiver_is_the_radios_own_drops_frame_for_frame(tmp_path):
    profile = tmp_path / "iid10.toml"
    profile.write_text(IID10_PROFILE)
    ledger_path = tmp_path / "ledger.json"
    gs, code, _ = flight(free_endpoint(), no_commands, 23.0, "--radio", str(profile),
                         "--radio-ledger", str(ledger_path), "--seed", "11", period_s=0.25)
    assert code == 0
    ledger = json.loads(ledger_path.read_text())["vehicles"]["1"]["downlink"]
    fates = ledger["ledger"]
    delivered = [i for i, fate in enumerate(fates) if fate[3]]
    received = gs.raw_downlink
    assert len(received) >= 10_000
    # Frame for frame: the receiver got exactly the frames the radio delivered, in order (the frames
    # delivered after the last tick never reached it); a frame's sequence number is its offer index.
    assert [frame[4] for frame in received] == [i % 256 for i in delivered[:len(received)]]
    assert [len(frame) for frame in received] == [fates[i][1] for i in delivered[:len(received)]]
    last = delivered[len(received) - 1]
    dropped_before_last = sum(1 for fate in fates[:last] if fate[2] is not None)
    snapshot = gs.stats.snapshot()
    assert snapshot.rx_lost == dropped_before_last
    assert {fate[2] for fate in fates if fate[2] is not None} == {"iid"}
    tolerance = 4.0 * math.sqrt(0.1 * 0.9 / (last + 1))
    assert abs(snapshot.rx_loss_ratio - 0.1) < tolerance
    assert abs(ledger["dropped_total"] / ledger["offered"] - 0.1) < tolerance


def test_a_crash_into_a_block_reaches_the_ground_station_with_its_time_and_place(tmp_path):
    """Climbing at a = (1.5 m g - m g) / m = g / 2 from the floor into a ceiling block at 1.5 m: the
    centre meets the block's underside minus the collision radius r at t_c = sqrt(2 (1.5 - r) / a)."""
    ceiling_m = 1.5
    world = tmp_path / "ceiling.json"
    world.write_text(json.dumps({"bounds": {"extents": [-2, 2, -2, 2, 0, 3]},
                                 "blocks": [{"extents": [-1, 1, -1, 1, ceiling_m, 2.0]}]}))
    params = load_firmware_params()
    radius = VEHICLE.collision_radius_m
    crash_z = ceiling_m - radius
    crash_time = math.sqrt(2.0 * crash_z / (0.5 * GRAVITY_MPS2))
    gs, code, lines = flight(free_endpoint(), hover_script(1.5 * VEHICLE.weight_n), crash_time + 0.8,
                             "--world", str(world), "--radio", "ideal")
    assert code == 0
    crashed = [(t, hb) for t, hb in gs.messages(Heartbeat) if hb.mode == VehicleMode.CRASHED]
    assert crashed, "no HEARTBEAT reported the crash"
    seen_s, heartbeat = crashed[0]
    assert heartbeat.failsafe and not heartbeat.armed
    heartbeat_period_s = 1.0 / params.heartbeat_rate_hz
    assert crash_time - 0.01 <= seen_s <= crash_time + heartbeat_period_s + 0.02
    after = [pose for t, pose in gs.mocap if t >= seen_s]
    assert after, "no mocap after the crash"
    for pose in after:  # the vehicle stays where it hit
        assert pose.position_enu_m[2] == pytest.approx(crash_z, abs=0.01)
        assert math.hypot(*pose.position_enu_m[:2]) < 0.01
    reached_s = min(pose.time_s for _, pose in gs.mocap if pose.position_enu_m[2] >= crash_z - 0.01)
    assert reached_s == pytest.approx(crash_time, abs=0.015)  # mocap sample times show when it stopped
    assert "crashed at t=" in lines[-1]
    reported_time = float(lines[-1].split("crashed at t=")[1].split()[0])
    assert reported_time == pytest.approx(crash_time, abs=0.02)


def test_non_finite_commands_are_rejected_counted_and_leave_the_motors_alone():
    """Hovering at thrust = weight (an exact equilibrium); 0.2 s of NaN / inf setpoints in between
    (shorter than the watchdog's level timeout) must change nothing and be counted."""
    weight = VEHICLE.weight_n
    bad = [ThrustMoment(0.0, math.nan, (0.0, 0.0, 0.0)), ThrustMoment(0.0, weight, (math.inf, 0.0, 0.0)),
           ThrustMoment(0.0, weight, (0.0, math.nan, 0.0)), ThrustMoment(0.0, math.inf, (0.0, 0.0, 0.0))]
    sent_bad = []

    def script(tick: int, t_s: float) -> list:
        if 0.3 <= t_s < 0.5:
            message = bad[tick % len(bad)]
            sent_bad.append(message)
            return [ThrustMoment(t_s, message.thrust_n, message.moment_flu_nm)]
        return [ThrustMoment(t_s, weight, (0.0, 0.0, 0.0))]

    gs, code, lines = flight(free_endpoint(), script, 1.1, "--airborne", "--start", "0", "0", "1",
                             "--radio", "ideal")
    assert code == 0
    assert len(sent_bad) == 20
    batteries = gs.messages(BatteryStatus)
    assert batteries[-1][0] >= 0.5
    assert batteries[-1][1].rejected_commands == len(sent_bad)
    assert all(b.rejected_commands == 0 for t, b in batteries if t < 0.3)
    for _, state in gs.truth:
        assert state.position_enu_m[2] == pytest.approx(1.0, abs=1e-4)
        assert abs(state.velocity_enu_mps[2]) < 1e-3
    window = [imu.specific_force_flu_mps2[2] for t, imu in gs.messages(ImuSample) if 0.3 <= t <= 0.55]
    assert sum(window) / len(window) == pytest.approx(GRAVITY_MPS2, abs=0.05)  # thrust / m = g throughout
    assert all(hb.mode == VehicleMode.MOMENTS and not hb.failsafe for _, hb in gs.messages(Heartbeat))
    assert "rejected 20" in lines[-1]


def test_several_vehicles_in_one_process_each_on_its_own_keys_and_radios(tmp_path):
    profile = tmp_path / "iid10.toml"
    profile.write_text(IID10_PROFILE)
    ledger_path = tmp_path / "ledger.json"
    endpoint = free_endpoint()
    count = 3
    responders = [Responder(endpoint, hover_script(1.02 * VEHICLE.weight_n), vehicle_id=i + 1, period_s=0.05)
                  for i in range(count)]
    errors: list[BaseException] = []

    def fly(gs: Responder) -> None:
        try:
            gs.fly(2.0)
        except BaseException as err:  # noqa: BLE001 - reported by the test thread
            errors.append(err)

    try:
        with emulator(endpoint, "--vehicles", str(count), "--radio", str(profile),
                      "--radio-ledger", str(ledger_path)) as proc:
            threads = [threading.Thread(target=fly, args=(gs,)) for gs in responders]
            for thread in threads:
                thread.start()
            for thread in threads:
                thread.join(TIMEOUT_S)
            assert not errors, errors
            code, _ = stop(proc)
        assert code == 0
        report = json.loads(ledger_path.read_text())["vehicles"]
        hashes = set()
        for i, gs in enumerate(responders):
            vid = i + 1
            assert {decoded_system_id(f) for f in gs.raw_downlink} == {vid}
            assert gs.mocap[0][1].body_id == vid
            assert gs.mocap[0][1].position_enu_m[0] == pytest.approx(0.5 * i, abs=0.01)
            fates = report[str(vid)]["downlink"]["ledger"]
            delivered = [j for j, fate in enumerate(fates) if fate[3]][:len(gs.raw_downlink)]
            dropped_before_last = sum(1 for fate in fates[:delivered[-1]] if fate[2] is not None)
            assert gs.stats.snapshot().rx_lost == dropped_before_last  # its own radio's drops
            hashes.add(gs.downlink_hash())
        assert len(hashes) == count  # independent noise and radio draws per vehicle
    finally:
        for gs in responders:
            gs.close()


def decoded_system_id(frame: bytes) -> int:
    return frame[5]  # MAVLink 2 header: magic, len, incompat, compat, seq, sysid, compid, msgid

