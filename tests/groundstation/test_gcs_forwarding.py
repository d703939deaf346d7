"""`cfstack fly --gcs`: MAVProxy, the real client, headless, sees the vehicle where the ground station's log
says it was; and a GCS that floods and sends garbage and commands changes nothing in a lockstep flight."""

from __future__ import annotations

import csv
import hashlib
import json
import socket
import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mav
from testsupport import cfstack, free_port, mavproxy, needs_mavproxy, wait_for_text

from groundstation.logread import read_log
from model.geodetic import load_origin

GAINS_AND_SESSION_PARAMS = 15  # groundstation.gcs_forward.session_parameters: 3 of the session, 12 gains


@needs_mavproxy
def test_mavproxy_sees_the_vehicle_fly_where_the_log_says(tmp_path):
    port = free_port(socket.SOCK_DGRAM)
    with mavproxy(f"udp:127.0.0.1:{port}", tmp_path) as out:
        assert wait_for_text(out, "Waiting for heartbeat", 30.0), out.read_text()
        flight = cfstack("fly", "--trajectory", "circle", "--log", str(tmp_path / "flight"),
                         "--gcs", f"udp:127.0.0.1:{port}", "--json")
        assert flight.returncode == 0, flight.stderr
        assert wait_for_text(out, f"Received {GAINS_AND_SESSION_PARAMS} parameters", 15.0), out.read_text()
    text = out.read_text()
    assert "Detected vehicle 1:1" in text and "ARMED" in text

    seen = {"LOCAL_POSITION_NED": [], "GLOBAL_POSITION_INT": [], "HEARTBEAT": []}
    tlog = mavutil.mavlink_connection(str(tmp_path / "mav.tlog"))
    while (m := tlog.recv_match(type=list(seen))) is not None:
        if m.get_srcSystem() == 1:
            seen[m.get_type()].append(m)
    assert seen["HEARTBEAT"] and seen["HEARTBEAT"][0].type == mav.MAV_TYPE_QUADROTOR
    local = seen["LOCAL_POSITION_NED"]
    assert len(local) > 100

    log = read_log(tmp_path / "flight")
    est = log.position_m("est")
    t_ms = log.t_s * 1e3

    def row_of(time_boot_ms: int) -> int:  # the tick a frame was sent for (time_boot_ms is truncated)
        i = int(np.argmin(np.abs(t_ms - time_boot_ms)))
        assert abs(t_ms[i] - time_boot_ms) <= 1.0
        return i

    ned = np.array([(m.x, m.y, m.z) for m in local])
    enu_logged = np.array([est[row_of(m.time_boot_ms)] for m in local])
    # what MAVProxy received is the estimate of the same tick, in NED: north = y, east = x, down = -z
    # (float32 on the wire: 1e-6 relative)
    assert np.abs(ned - enu_logged[:, [1, 0, 2]] * [1, 1, -1]).max() < 1e-5
    # and it moved: the circle's extent seen by MAVProxy is the flown one
    assert np.ptp(ned[:, 0]) > 1.0 and np.ptp(ned[:, 1]) > 1.0 and ned[:, 2].min() < -0.5
    origin = load_origin("lab")
    m_radius, _ = origin.radii_m()
    glob = seen["GLOBAL_POSITION_INT"]
    lat = np.array([g.lat for g in glob]) * 1e-7
    north_from_lat = np.radians(lat - origin.latitude_deg) * (m_radius + origin.altitude_msl_m)
    north = np.array([est[row_of(g.time_boot_ms)][1] for g in glob])
    assert np.abs(north_from_lat - north).max() < 0.02  # 1e-7 deg is 1.1 cm


class Flooder:
    """A hostile GCS on the --gcs port: answers every datagram with garbage, parameter-list requests and
    unsigned land/arm commands, as fast as it can, until stopped."""

    def __init__(self, port: int):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", port))
        self.sock.settimeout(0.1)
        self.mav = mav.MAVLink(None, srcSystem=255, srcComponent=190)
        self.sent = 0
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self.run, daemon=True)
        self.thread.start()

    def run(self) -> None:
        vehicle = None
        frames = [bytes([0xFD, 0x20, 0x00]) + bytes(range(40)), b"\xfe" * 300,
                  mav.MAVLink_param_request_list_message(1, 1).pack(self.mav),
                  mav.MAVLink_command_long_message(1, 1, mav.MAV_CMD_NAV_LAND, 0, 0, 0, 0, 0, 0, 0, 0).pack(self.mav),
                  mav.MAVLink_command_long_message(1, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 0, 0, 0, 0, 0, 0,
                                                   0).pack(self.mav)]
        while not self.stop.is_set():
            try:
                _, vehicle = self.sock.recvfrom(4096)
            except TimeoutError:
                pass
            if vehicle is not None:
                for _ in range(20):
                    self.sock.sendto(frames[self.sent % len(frames)], vehicle)
                    self.sent += 1

    def close(self) -> None:
        self.stop.set()
        self.thread.join()
        self.sock.close()


def test_a_flooding_gcs_changes_nothing_in_a_lockstep_flight(tmp_path):
    port = free_port(socket.SOCK_DGRAM)
    flooder = Flooder(port)
    try:  # both flights at once (independent; each lockstep flight keeps about one core busy)
        with ThreadPoolExecutor(2) as pool:
            plain = pool.submit(cfstack, "fly", "--trajectory", "hover", "--seed", "3", "--log",
                                str(tmp_path / "plain"), "--json")
            flooded = pool.submit(cfstack, "fly", "--trajectory", "hover", "--seed", "3", "--log",
                                  str(tmp_path / "flooded"), "--gcs", f"udp:127.0.0.1:{port}", "--json")
            plain, flooded = plain.result(), flooded.result()
    finally:
        flooder.close()
    assert plain.returncode == 0, plain.stderr
    assert flooded.returncode == 0, flooded.stderr
    assert flooder.sent > 1000
    digest = [hashlib.sha256((tmp_path / name / "states.csv").read_bytes()).hexdigest()
              for name in ("plain", "flooded")]
    assert digest[0] == digest[1]
    with (tmp_path / "flooded" / "gcs_commands.csv").open() as f:
        commands = list(csv.DictReader(f))
    assert {c["command"] for c in commands} == {"land", "arm_disarm"}
    assert {c["verdict"] for c in commands} == {"denied"} and {c["signed"] for c in commands} == {"0"}
    summary = json.loads(flooded.stdout)
    assert summary["result"] == "reached_goal"
