"""--radio-link: the radio's uplink and downlink on a transport of the scheme table, from both commands.

- A lockstep flight whose radio link is UDP is the flight on zenoh, byte for byte (same seed): the transport
  carries frames, it changes nothing in them.
- MAVProxy, the real client, headless, finds the emulated vehicle on a UDP radio link.
- Over a serial line (a real pseudo-terminal) the emulator speaks MAVLink 2 to whatever holds the far end.
- Impossible combinations are one line and a non-zero exit.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import signal
import socket
import subprocess
import sys
import time
import tty
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as mav
from testsupport import cfstack, free_port, mavproxy, needs_mavproxy, one_line_error, wait_for_text

from link.mavlink.tlog import read_tlog


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_a_lockstep_flight_over_a_udp_radio_link_is_the_zenoh_flight(tmp_path):
    port = free_port(socket.SOCK_DGRAM)
    variants = {"zenoh": [], "udp": ["--radio-link", f"udpout:127.0.0.1:{port}"]}
    with ThreadPoolExecutor(2) as pool:  # at once: each lockstep flight keeps about one core busy
        futures = {name: pool.submit(cfstack, "fly", "--trajectory", "hover", "--seed", "3", "--log",
                                     str(tmp_path / name), "--json", *extra) for name, extra in variants.items()}
    runs = {}
    for name, future in futures.items():
        run = future.result()
        assert run.returncode == 0, run.stderr
        runs[name] = json.loads(run.stdout)
    assert runs["udp"]["result"] == "reached_goal"
    assert (runs["zenoh"]["link"]["radio"], runs["udp"]["link"]["radio"]) == ("zenoh", "udpout")
    # every frame crossed (none lost on loopback), and the same frames as on zenoh
    assert runs["udp"]["link"]["uplink_sent"] == runs["zenoh"]["link"]["uplink_sent"] > 1000
    assert runs["udp"]["link"]["downlink_delivered"] == runs["zenoh"]["link"]["downlink_delivered"] > 1000
    assert _sha(tmp_path / "zenoh" / "states.csv") == _sha(tmp_path / "udp" / "states.csv")
    # the same frames crossed in the same order (the tlog's stamps are wall-clock time, as the format has it)
    frames = {name: [decoded.frame for _, decoded in read_tlog(tmp_path / name / "link.mavlink.tlog")]
              for name in runs}
    assert len(frames["udp"]) > 2000 and frames["udp"] == frames["zenoh"]


class EmulatorProcess:
    """`cfstack emulator` in realtime with its radio link on `radio_link`, zenoh on a private endpoint."""

    def __init__(self, tmp_path: Path, radio_link: str, seconds: float):
        self.stderr_path = tmp_path / "emulator.log"
        with self.stderr_path.open("w") as sink:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "cfstack", "emulator", "--clock", "realtime", "--radio-link", radio_link,
                 "--listen", f"tcp/127.0.0.1:{free_port()}", "--crtp-port", "off", "--duration", str(seconds)],
                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=sink)

    def stop(self) -> str:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
        self.proc.wait(timeout=30)
        return self.stderr_path.read_text()


@needs_mavproxy
def test_mavproxy_finds_the_vehicle_on_a_udp_radio_link(tmp_path):
    port = free_port(socket.SOCK_DGRAM)
    emulator = EmulatorProcess(tmp_path, f"udpin:127.0.0.1:{port}", seconds=60)
    try:  # MAVProxy speaks first (its GCS heartbeat), as a ground station does
        with mavproxy(f"udpout:127.0.0.1:{port}", tmp_path) as out:
            detected = wait_for_text(out, "Detected vehicle 1:1", 40.0)
    finally:
        log = emulator.stop()
    assert detected, (out.read_text(), log)
    assert "udpin:127.0.0.1" in log  # the emulator says where its radio is


def test_the_emulator_speaks_mavlink_over_a_serial_line(tmp_path):
    master, slave = os.openpty()
    tty.setraw(master)
    os.set_blocking(master, False)
    emulator = EmulatorProcess(tmp_path, f"serial:{os.ttyname(slave)}:57600", seconds=30)
    parser = mav.MAVLink(None)
    parser.robust_parsing = True
    seen: dict[str, int] = {}
    try:
        deadline = time.monotonic() + 30.0
        while not {"HEARTBEAT", "HIGHRES_IMU"} <= seen.keys() and time.monotonic() < deadline:
            assert emulator.proc.poll() is None, emulator.stderr_path.read_text()
            try:
                chunk = os.read(master, 4096)
            except BlockingIOError:
                chunk = b""
            for message in parser.parse_buffer(chunk) or []:
                if message.get_srcSystem() == 1:
                    seen[message.get_type()] = seen.get(message.get_type(), 0) + 1
    finally:
        emulator.stop()
        os.close(master)
        os.close(slave)
    assert {"HEARTBEAT", "HIGHRES_IMU"} <= seen.keys(), seen


@pytest.mark.parametrize(("command", "named"), [
    (["emulator", "--clock", "lockstep", "--radio-link", "serial:/dev/ttyUSB0:57600"], "--clock realtime"),
    (["emulator", "--vehicles", "2", "--radio-link", "serial:/dev/ttyUSB0:57600"], "carries one vehicle"),
    (["emulator", "--radio-link", "tcp:127.0.0.1:5760"], "unknown transport scheme 'tcp'"),
    (["fly", "--radio-link", "serial:/dev/ttyUSB0:57600", "--clock", "realtime"], "another device"),
    (["groundstation", "--radio-link", "serial:/dev/ttyUSB0:57600", "--clock", "lockstep"], "--clock realtime"),
])
def test_an_impossible_radio_link_is_one_line_and_a_non_zero_exit(command, named):
    assert named in one_line_error(cfstack(*command, timeout=60))


@pytest.mark.parametrize("radio, link, warned", [
    ("crazyradio", "mavlink", True),  # 500 Hz HIGHRES_IMU, 3 radio packets a frame: 1500/s against 1000 transactions/s
    ("esb-duplex", "mavlink", False),  # each direction on its own air, no USB cadence
    ("crazyradio", "crtp", False),  # CRTP's IMU log block is one packet at 100 Hz
    (None, "mavlink", False),  # the default radio for MAVLink is esb-duplex
])
def test_fly_warns_before_flying_mavlink_on_one_crazyradio(capsys, radio, link, warned):
    from groundstation import cli

    args = argparse.Namespace(link=link, radio=radio, vehicle_model="cf21")
    cli._warn_if_one_crazyradio_cannot_carry_mavlink(args)
    err = capsys.readouterr().err
    assert ("1500 radio packets/s down and it carries 1000" in err) is warned
    assert err.count("\n") == (1 if warned else 0)
