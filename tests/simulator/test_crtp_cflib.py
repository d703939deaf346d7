"""Unmodified cflib flies the emulator: `cfstack emulator` as users start it, cflib's udp:// driver as Crazyflie
users use it (issue 16). Ground truth comes from the emulator's truth key over zenoh, for grading only."""

from __future__ import annotations

import math
import signal
import socket
import struct
import subprocess
import sys
import time
import uuid

import pytest

pytest.importorskip("cflib", reason="cflib is in the test extra (pip install -e '.[test]')")
import cflib.crtp  # noqa: E402
from cflib.crazyflie import Crazyflie  # noqa: E402
from cflib.crazyflie.log import LogConfig  # noqa: E402
from cflib.crazyflie.syncCrazyflie import SyncCrazyflie  # noqa: E402
from cflib.crazyflie.syncLogger import SyncLogger  # noqa: E402

from link.keys import VehicleKeys  # noqa: E402
from link.mavlink.codec import ActuatorLimits, Codec, FrameParser  # noqa: E402
from link.messages import TruthState  # noqa: E402
from link.transports import open_transport  # noqa: E402
from link.transports.base import free_loopback_port  # noqa: E402
from model.vehicle import load_vehicle  # noqa: E402

SCAN_PORTS = range(19850, 19860)  # cflib udpdriver.scan_interface's ports
START_TIMEOUT_S = 60.0  # a busy 2-core machine can take a while to import and open zenoh
# The firmware's log variable names and types that cflib scripts use (stabilizer.c, sensors, pm.c,
# power_distribution_quadrotor.c at crazyflie-firmware 2a18fc2)
FIRMWARE_LOG_NAMES = {
    **{f"stateEstimate.{v}": "float" for v in ("x", "y", "z", "vx", "vy", "vz", "roll", "pitch", "yaw",
                                                "qw", "qx", "qy", "qz")},
    **{f"stabilizer.{v}": "float" for v in ("roll", "pitch", "yaw")},
    **{f"gyro.{v}": "float" for v in "xyz"}, **{f"acc.{v}": "float" for v in "xyz"},
    "pm.vbat": "float", **{f"motor.m{i}": "uint16_t" for i in range(1, 5)},
}

cflib.crtp.init_drivers()


def _free_udp_port(candidates=None) -> int | None:
    for port in candidates or [free_loopback_port(socket.SOCK_DGRAM)]:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            try:
                sock.bind(("127.0.0.1", port))
            except OSError:
                continue
            return port
    return None


class Emulator:
    """`cfstack emulator` in realtime with CRTP on `port`, zenoh on a private endpoint, truth readable."""

    def __init__(self, tmp_path, port: int, *extra: str):
        self.port = port
        self.uri = f"udp://127.0.0.1:{port}"
        self.endpoint = f"tcp/127.0.0.1:{free_loopback_port()}"
        self.prefix = f"c{uuid.uuid4().hex[:8]}"
        self.stderr_path = tmp_path / f"emulator-{port}.log"
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "cfstack", "emulator", "--clock", "realtime", "--crtp-port", str(port),
             "--listen", self.endpoint, "--id", self.prefix, "--seed", "3", "--quiet", *extra],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=open(self.stderr_path, "w"))
        self.truth_link = open_transport("zenoh", rx=VehicleKeys(self.prefix, 1).truth, connect=[self.endpoint],
                                         listen=[])
        self.parser = FrameParser(Codec(1, limits=ActuatorLimits.from_vehicle(load_vehicle("cf21"))))
        self.truth: TruthState | None = None
        self._wait_for_crtp()

    def _wait_for_crtp(self) -> None:
        deadline = time.monotonic() + START_TIMEOUT_S
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            sock.settimeout(0.2)
            while time.monotonic() < deadline:
                assert self.proc.poll() is None, self.stderr_path.read_text()
                sock.sendto(b"\xff", ("127.0.0.1", self.port))
                try:
                    if sock.recvfrom(64)[0] == b"\xff":
                        return
                except OSError:
                    pass
        raise AssertionError(f"the emulator did not answer CRTP in {START_TIMEOUT_S} s")

    def latest_truth(self) -> TruthState:
        deadline = time.monotonic() + 5.0
        while True:
            for chunk in self.truth_link.receive(0.05):
                for decoded in self.parser.feed(chunk, True):
                    if isinstance(decoded.message, TruthState):
                        self.truth = decoded.message
            if self.truth is not None or time.monotonic() > deadline:
                return self.truth

    def wait_sim(self, seconds: float) -> TruthState:
        """Wait until the vehicle's clock (the truth's time) has advanced `seconds`: a loaded machine may run
        the realtime emulator behind the wall clock, and the commands act in simulated time."""
        start = self.latest_truth().time_s
        deadline = time.monotonic() + 10.0 * seconds + 10.0
        while self.latest_truth().time_s < start + seconds:
            assert time.monotonic() < deadline, "the emulator's clock stopped"
            time.sleep(0.02)
        return self.truth

    def stop(self) -> str:
        """SIGINT, as Ctrl-C; the emulator's summary line."""
        self.truth_link.close()
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            self.proc.wait(timeout=30)
        return self.stderr_path.read_text().strip().splitlines()[-1]


@pytest.fixture
def emulator(tmp_path):
    emulators = []

    def start(port: int | None = None, *extra: str) -> Emulator:
        emulators.append(Emulator(tmp_path, port or _free_udp_port(), *extra))
        return emulators[-1]

    yield start
    for emu in emulators:
        emu.stop()


def _connect(uri: str) -> SyncCrazyflie:
    return SyncCrazyflie(uri, cf=Crazyflie(rw_cache=None))


def _log_at_100_hz(scf: SyncCrazyflie, names: tuple[str, ...], count: int) -> list:
    """`count` SyncLogger entries (stamp ms, data, config) of float variables at 100 Hz, the fastest a log
    block runs."""
    config = LogConfig("state", period_in_ms=10)
    for name in names:
        config.add_variable(name, "float")
    entries = []
    with SyncLogger(scf, config) as logger:
        for entry in logger:
            entries.append(entry)
            if len(entries) == count:
                break
    return entries


def _median_step_ms(entries: list) -> float:
    stamps_ms = [stamp for stamp, _, _ in entries]
    steps = [b - a for a, b in zip(stamps_ms, stamps_ms[1:], strict=False)]
    return sorted(steps)[len(steps) // 2]


def test_cflib_scans_connects_and_reads_both_tocs_and_logs_state_at_100_hz(emulator):
    port = _free_udp_port(SCAN_PORTS)
    if port is None:
        pytest.skip("every port cflib scans (19850-19859) is taken on this machine")
    emu = emulator(port)
    assert [emu.uri, ""] in cflib.crtp.scan_interfaces()
    with _connect(emu.uri) as scf:
        scf.wait_for_params()
        cf = scf.cf
        log_toc = {f"{g}.{n}": e.ctype for g, names in cf.log.toc.toc.items() for n, e in names.items()}
        assert FIRMWARE_LOG_NAMES.items() <= log_toc.items()
        params = {f"{g}.{n}" for g, names in cf.param.toc.toc.items() for n in names}
        assert {"stabilizer.controller", "stabilizer.estimator", "commander.enHighLevel", "pid_rate.roll_kp",
                "pid_attitude.yaw_kd", "locSrv.extPosStdDev"} <= params
        assert len(cf.mem.get_mems(0)) == 0  # no memories (decks, EEPROM) on the emulated vehicle
        entries = _log_at_100_hz(scf, ("stateEstimate.x", "stateEstimate.y", "stateEstimate.z", "pm.vbat"), 100)
    assert _median_step_ms(entries) == 10  # the vehicle's clock: one entry per 10 ms
    truth = emu.latest_truth()
    last = entries[-1][1]
    # on the floor, seen by the simulated positioning deck through the onboard estimator
    assert math.dist((last["stateEstimate.x"], last["stateEstimate.y"], last["stateEstimate.z"]),
                     truth.position_enu_m) < 0.05
    assert 3.0 < last["pm.vbat"] < 4.3  # a LiPo cell's range


def test_param_get_and_set_round_trip_and_what_the_emulator_cannot_take(emulator):
    emu = emulator()
    with _connect(emu.uri) as scf:
        scf.wait_for_params()
        param = scf.cf.param
        assert float(param.get_value("pid_rate.roll_kp")) == 250.0  # platform_defaults_cf2.h PID_ROLL_RATE_KP
        param.set_value("pid_rate.roll_kp", 200.0)
        param.set_value("stabilizer.controller", 2)  # Mellinger: not emulated, the echo says PID (1) stays
        time.sleep(0.5)
        assert float(param.get_value("pid_rate.roll_kp")) == 200.0
        assert int(param.get_value("stabilizer.controller")) == 1
    with _connect(emu.uri) as scf:  # a second client reads the value the vehicle now holds
        scf.wait_for_params()
        assert float(scf.cf.param.get_value("pid_rate.roll_kp")) == 200.0


def test_a_cflib_script_runs_over_zenoh_with_cfstacks_link_driver(emulator):
    """The same script on `zenoh://PREFIX/1?connect=ENDPOINT` (link.crtp.zenoh_driver registered with cflib):
    the TOCs, a parameter and a log block at 100 Hz on the vehicle's clock, as over UDP."""
    from link.crtp import zenoh_driver

    zenoh_driver.register()
    emu = emulator()
    with _connect(f"zenoh://{emu.prefix}/1?connect={emu.endpoint}") as scf:
        scf.wait_for_params()
        assert int(scf.cf.param.get_value("stabilizer.controller")) == 1  # PID, the emulated one
        entries = _log_at_100_hz(scf, ("stateEstimate.z", "pm.vbat"), 50)
    assert _median_step_ms(entries) == 10
    assert abs(entries[-1][1]["stateEstimate.z"] - emu.latest_truth().position_enu_m[2]) < 0.05
    assert 3.0 < entries[-1][1]["pm.vbat"] < 4.3


def test_malformed_packets_are_counted_and_ignored_and_the_emulator_keeps_answering(emulator):
    emu = emulator()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.settimeout(2.0)
        sock.connect(("127.0.0.1", emu.port))
        hostile = [
            b"",  # no header
            bytes((0x5C,)) + bytes(40),  # oversized (the radio carries 30 bytes at most)
            bytes((0x1C,)) + b"\x01\x02",  # port 1: no such service
            bytes((0x3C,)) + b"\x00\x01",  # RPYT cut short
            bytes((0x3C,)) + struct.pack("<fffH", math.nan, 0.0, 0.0, 20000),  # NaN setpoint
            bytes((0x5D, 0x06, 0x01, 0x77, 0xFF, 0x7F)),  # log block with an unknown TOC id
            bytes((0x2D,)) + struct.pack("<H", 0x7FFF),  # param read of an unknown id
        ]
        for datagram in hostile:
            sock.send(datagram)
        echo = bytes((0xFC,)) + b"ping"  # link echo (15:0), legacy bits set
        sock.send(echo)
        replies = []
        while echo not in replies:
            replies.append(sock.recv(64))  # a lost echo times out and fails the test
    assert bytes((0x5D, 0x06, 0x01, 2)) in replies  # log create: ENOENT for the unknown TOC id
    assert bytes((0x2D,)) + struct.pack("<H", 0x7FFF) + b"\x01" in replies  # param read: an error status
    assert len(replies) == 3  # nothing else was answered
    with _connect(emu.uri) as scf:  # and a real client still connects
        scf.wait_for_params()
    summary = emu.stop()
    for counted in ("3 malformed", "1 unknown,", "2 unknown toc id", "1 non finite"):
        assert counted in summary, summary


# --- three user scripts flown at once, each on its own emulator (realtime: they wait on the clock, not the CPU)

def rpyt_script(emu: Emulator) -> dict:
    """A user's script: thrust before the unlocking zero (nothing happens), then 5 s of RPYT with its own
    altitude loop on the logged estimate."""
    state, heights, tilts = {}, [], []
    with _connect(emu.uri) as scf:
        cf = scf.cf
        config = LogConfig("z", period_in_ms=10)
        for name in ("stateEstimate.z", "stateEstimate.vz", "stateEstimate.roll", "stateEstimate.pitch"):
            config.add_variable(name, "float")
        cf.log.add_config(config)
        config.data_received_cb.add_callback(lambda _t, data, _c: state.update(data))
        config.start()
        for _ in range(50):  # locked: thrust before an unlocking zero does nothing
            cf.commander.send_setpoint(0.0, 0.0, 0.0, 45000)
            time.sleep(0.01)
        locked_z = emu.latest_truth().position_enu_m[2]
        cf.commander.send_setpoint(0.0, 0.0, 0.0, 0)
        start = last = time.monotonic()
        integral = 0.0
        while (elapsed := time.monotonic() - start) < 5.0:
            z, vz = state.get("stateEstimate.z", 0.0), state.get("stateEstimate.vz", 0.0)
            now = time.monotonic()
            integral += (0.5 - z) * (now - last)
            last = now
            # the script's own loop: hover thrust guess + PID on height (PWM units), as user scripts do
            thrust = 36000 + 25000 * (0.5 - z) + 15000 * integral - 12000 * vz
            cf.commander.send_setpoint(0.0, 0.0, 0.0, int(min(max(thrust, 10001), 60000)))
            if elapsed > 3.0:
                heights.append(emu.latest_truth().position_enu_m[2])
                tilts.append(max(abs(state["stateEstimate.roll"]), abs(state["stateEstimate.pitch"])))
            time.sleep(0.01)
        cf.commander.send_stop_setpoint()
        config.stop()
    return {"locked_z": locked_z, "heights": heights, "tilts": tilts}


def high_level_script(emu: Emulator) -> dict:
    with _connect(emu.uri) as scf:
        cf = scf.cf
        scf.wait_for_params()
        cf.param.set_value("commander.enHighLevel", 1)
        hl = cf.high_level_commander
        hl.takeoff(0.5, 1.5)
        took_off = emu.wait_sim(2.5).position_enu_m
        hl.go_to(0.4, -0.3, 0.7, 0.0, 2.0)
        went = emu.wait_sim(3.0).position_enu_m
        hl.land(0.0, 2.0)
        emu.wait_sim(2.5)
        landed = [emu.wait_sim(0.1).position_enu_m for _ in range(10)]  # it stays down (no hop) for a second
        hl.stop()
    return {"took_off": took_off, "went": went, "landed": landed}


def motion_commander_script(emu: Emulator) -> dict:
    """cflib's MotionCommander: it resets the estimator (kalman.resetEstimation), takes off and moves on
    hover setpoints (velocity in the body's yaw frame, absolute height) streamed from its own thread."""
    from cflib.positioning.motion_commander import MotionCommander

    with _connect(emu.uri) as scf:
        mc = MotionCommander(scf, default_height=0.4)
        mc.take_off()
        up = emu.wait_sim(0.5).position_enu_m
        mc.forward(0.4)  # +x: the vehicle starts facing east (yaw 0)
        forward = emu.wait_sim(0.5).position_enu_m
        mc.turn_left(90)
        mc.forward(0.3)  # now facing north: +y
        turned = emu.wait_sim(0.5).position_enu_m
        mc.stop()
        mc.land()
    return {"up": up, "forward": forward, "turned": turned}


SCRIPTS = {"rpyt": rpyt_script, "high_level": high_level_script, "motion_commander": motion_commander_script}


@pytest.fixture(scope="module")
def flown(tmp_path_factory):
    """Each script's measurements (or the exception it raised), flown concurrently."""
    from concurrent.futures import ThreadPoolExecutor

    tmp = tmp_path_factory.mktemp("crtp_flights")
    emulators = {name: Emulator(tmp, _free_udp_port()) for name in SCRIPTS}
    try:
        with ThreadPoolExecutor(len(SCRIPTS)) as pool:
            futures = {name: pool.submit(script, emulators[name]) for name, script in SCRIPTS.items()}
            results = {name: (f.result() if f.exception() is None else f.exception()) for name, f in futures.items()}
    finally:
        summaries = {name: emu.stop() for name, emu in emulators.items()}
    return results, summaries


def _result(flown, name: str) -> dict:
    result = flown[0][name]
    if isinstance(result, BaseException):
        raise result
    return result


def test_thrust_lock_then_a_cflib_altitude_loop_hovers_on_rpyt(flown):
    r = _result(flown, "rpyt")
    assert r["locked_z"] < 0.01  # thrust 45000 before the unlocking zero: still on the floor
    assert 0.35 < min(r["heights"]) and max(r["heights"]) < 0.65, (min(r["heights"]), max(r["heights"]))
    assert max(r["tilts"]) < 5.0  # deg: the onboard attitude PIDs hold it level


def test_high_level_takeoff_go_to_land_reach_their_targets(flown):
    r = _result(flown, "high_level")
    assert math.dist(r["took_off"], (0.0, 0.0, 0.5)) < 0.1, r["took_off"]
    assert math.dist(r["went"], (0.4, -0.3, 0.7)) < 0.1, r["went"]
    landed = r["landed"]
    assert max(p[2] for p in landed) < 0.03 and all(math.dist(p[:2], (0.4, -0.3)) < 0.1 for p in landed), landed


def test_motion_commander_flies_body_frame_moves_on_hover_setpoints(flown):
    r = _result(flown, "motion_commander")
    up, forward, turned = r["up"], r["forward"], r["turned"]
    assert abs(up[2] - 0.4) < 0.1, up
    assert abs(forward[0] - up[0] - 0.4) < 0.15 and abs(forward[1] - up[1]) < 0.15, (up, forward)
    assert abs(turned[1] - forward[1] - 0.3) < 0.15 and abs(turned[0] - forward[0]) < 0.15, (forward, turned)
