"""link.mavlink.gcs against a pymavlink client in the GCS's place: what a GCS is sent (frames and units
by the MAVLink common definitions), what it gets for its connect-time requests, and that flight commands
are refused unless signed with our key or allowed, while garbage is counted and never stops the link.
(The real GCS, MAVProxy, is tests/groundstation/test_gcs_forwarding.py.)"""

from __future__ import annotations

import math
import socket
import time

import pytest
from pymavlink.dialects.v20 import common as mav
from testsupport import free_port

from link.mavlink.gcs import GcsLink, GcsSnapshot, Verdict
from link.mavlink.signing import MAVLINK_EPOCH_UNIX_S, Signing

KEY = bytes(range(1, 33))
PARAMS = {"CF_MODE": 0.0, "CF_RATE_HZ": 500.0, "CTL_KP_X": 5.0}


class Gcs:
    """A UDP socket where a GCS listens, with a pymavlink parser and sender (system 255)."""

    def __init__(self, port: int):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", port))
        self.sock.settimeout(0.2)
        self.mav = mav.MAVLink(None, srcSystem=255, srcComponent=190)
        self.vehicle = None
        self.received: list = []

    def pump(self, seconds: float, until=None) -> list:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            try:
                data, self.vehicle = self.sock.recvfrom(4096)
            except TimeoutError:
                continue
            self.received += [m for m in self.mav.parse_buffer(data) or [] if m.get_type() != "BAD_DATA"]
            if until is not None and until(self.received):
                break
        return self.received

    def send(self, message, sender=None) -> None:
        """Send from this GCS, packed by `sender` (a signing MAVLink) when given, else unsigned."""
        self.sock.sendto(message.pack(sender or self.mav), self.vehicle)

    def of_type(self, kind: str) -> list:
        return [m for m in self.received if m.get_type() == kind]

    def close(self) -> None:
        self.sock.close()


def signer(key: bytes):
    """A pymavlink sender (system 255) that signs with key, its timestamp at now as a signer keeps it."""
    sender = mav.MAVLink(None, srcSystem=255, srcComponent=190)
    sender.signing.secret_key = key
    sender.signing.sign_outgoing = True
    sender.signing.timestamp = int((time.time() - MAVLINK_EPOCH_UNIX_S) * 100_000)
    return sender


def snapshot(t: float = 1.5, armed: bool = True) -> GcsSnapshot:
    # yaw 90 deg ENU (nose to north) -> NED heading 0; level
    half = math.radians(90.0) / 2
    return GcsSnapshot(time_s=t, position_enu_m=(1.0, 2.0, 0.5), velocity_enu_mps=(0.1, -0.2, 0.3),
                       attitude_wxyz=(math.cos(half), 0.0, 0.0, math.sin(half)), rate_flu_radps=(0.01, 0.02, 0.03),
                       latitude_deg=39.9522, longitude_deg=-75.1906, altitude_msl_m=12.5, height_above_origin_m=0.5,
                       battery_v=3.9, battery_remaining_pct=75, armed=armed, healthy=True)


@pytest.fixture
def pair():
    port = free_port(socket.SOCK_DGRAM)
    gcs = Gcs(port)
    decided, logged = [], []

    def decide(command):
        decided.append(command)
        return Verdict.ACCEPTED

    link = GcsLink(f"udpout:127.0.0.1:{port}", PARAMS, heartbeat_period_s=0.1, signing=Signing(KEY, 0),
                   on_command=decide, on_command_logged=lambda c, v: logged.append((c, v)))
    yield gcs, link, decided, logged
    link.close()
    gcs.close()


def test_heartbeat_and_snapshot_frames_follow_the_mavlink_definitions(pair):
    gcs, link, _, _ = pair
    link.publish(snapshot())
    gcs.pump(3.0, until=lambda r: any(m.get_type() == "GLOBAL_POSITION_INT" for m in r)
             and sum(m.get_type() == "HEARTBEAT" for m in r) >= 2)
    heartbeat = gcs.of_type("HEARTBEAT")[-1]
    assert (heartbeat.get_srcSystem(), heartbeat.get_srcComponent()) == (1, mav.MAV_COMP_ID_AUTOPILOT1)
    assert heartbeat.type == mav.MAV_TYPE_QUADROTOR and heartbeat.autopilot == mav.MAV_AUTOPILOT_GENERIC
    assert heartbeat.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED and heartbeat.system_status == mav.MAV_STATE_ACTIVE
    att, = gcs.of_type("ATTITUDE")
    assert att.time_boot_ms == 1500
    assert (att.roll, att.pitch) == pytest.approx((0.0, 0.0), abs=1e-6)
    assert att.yaw == pytest.approx(0.0, abs=1e-6)  # nose north = NED heading 0
    assert (att.rollspeed, att.pitchspeed, att.yawspeed) == pytest.approx((0.01, -0.02, -0.03))  # FLU -> FRD
    local, = gcs.of_type("LOCAL_POSITION_NED")
    assert (local.x, local.y, local.z) == pytest.approx((2.0, 1.0, -0.5))  # north = ENU y, east = x, down = -z
    assert (local.vx, local.vy, local.vz) == pytest.approx((-0.2, 0.1, -0.3))
    glob, = gcs.of_type("GLOBAL_POSITION_INT")
    assert (glob.lat, glob.lon, glob.alt, glob.relative_alt) == (399522000, -751906000, 12500, 500)
    assert (glob.vx, glob.vy, glob.vz, glob.hdg) == (-20, 10, -30, 0)
    status = gcs.of_type("SYS_STATUS")[-1]
    assert status.voltage_battery == 3900 and status.battery_remaining == 75
    battery = gcs.of_type("BATTERY_STATUS")[-1]
    assert battery.voltages[0] == 3900 and battery.voltages[1] == 0xFFFF


def test_connect_time_requests_are_answered(pair):
    gcs, link, _, _ = pair
    gcs.pump(1.0, until=lambda r: r)
    gcs.send(mav.MAVLink_param_request_list_message(1, 1))
    gcs.send(mav.MAVLink_param_request_read_message(1, 1, b"CTL_KP_X", -1))
    gcs.send(mav.MAVLink_param_set_message(1, 1, b"CTL_KP_X", 99.0, mav.MAV_PARAM_TYPE_REAL32))
    gcs.send(mav.MAVLink_mission_request_list_message(1, 1, 0))
    gcs.send(mav.MAVLink_command_long_message(1, 1, mav.MAV_CMD_REQUEST_MESSAGE, 0,
                                              mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION, 0, 0, 0, 0, 0, 0))
    ftp = bytes([0, 0, 0, 4, 0, 0, 0, 0]) + bytes(243)  # seq 0, OpenFileRO
    gcs.send(mav.MAVLink_file_transfer_protocol_message(0, 1, 1, list(ftp)))
    gcs.pump(3.0, until=lambda r: sum(m.get_type() == "PARAM_VALUE" for m in r) >= 5
             and any(m.get_type() == "FILE_TRANSFER_PROTOCOL" for m in r))
    values = gcs.of_type("PARAM_VALUE")
    assert sorted({(v.param_id, v.param_index, v.param_count) for v in values}) == [
        ("CF_MODE", 0, 3), ("CF_RATE_HZ", 1, 3), ("CTL_KP_X", 2, 3)]
    assert all(v.param_value == PARAMS[v.param_id] for v in values)  # the PARAM_SET to 99 left 5.0
    assert len([v for v in values if v.param_id == "CTL_KP_X"]) == 3  # list, read, and the refused set
    count, = gcs.of_type("MISSION_COUNT")
    assert count.count == 0
    ack, = gcs.of_type("COMMAND_ACK")
    assert (ack.command, ack.result) == (mav.MAV_CMD_REQUEST_MESSAGE, mav.MAV_RESULT_ACCEPTED)
    assert gcs.of_type("AUTOPILOT_VERSION")[0].capabilities & mav.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    reply = bytes(gcs.of_type("FILE_TRANSFER_PROTOCOL")[0].payload)
    # seq + 1, NAK, size 1, for OpenFileRO, error UnknownCommand
    assert (reply[0], reply[3], reply[4], reply[5], reply[12]) == (1, 129, 1, 4, 7)


def test_flight_commands_need_a_signature_and_are_logged(pair):
    gcs, link, decided, logged = pair
    gcs.pump(1.0, until=lambda r: r)
    gcs.send(mav.MAVLink_command_long_message(1, 1, mav.MAV_CMD_NAV_LAND, 0, 0, 0, 0, 0, 0, 0, 0))
    gcs.send(mav.MAVLink_set_mode_message(1, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4))
    gcs.pump(2.0, until=lambda r: sum(m.get_type() == "COMMAND_ACK" for m in r) >= 2)
    acks = {a.command: a.result for a in gcs.of_type("COMMAND_ACK")}
    assert acks == {mav.MAV_CMD_NAV_LAND: mav.MAV_RESULT_DENIED, mav.MAVLINK_MSG_ID_SET_MODE: mav.MAV_RESULT_DENIED}
    assert decided == []
    assert [(c.name, c.signed, v) for c, v in logged] == [("land", False, Verdict.DENIED),
                                                          ("set_mode", False, Verdict.DENIED)]
    # the same command signed with the link's key goes to the decision
    land = mav.MAVLink_command_long_message(1, 1, mav.MAV_CMD_NAV_LAND, 0, 0, 0, 0, 0, 0, 0, 0)
    gcs.received = []
    gcs.send(land, sender=signer(KEY))
    gcs.pump(2.0, until=lambda r: any(m.get_type() == "COMMAND_ACK" for m in r))
    ack, = gcs.of_type("COMMAND_ACK")
    assert ack.result == mav.MAV_RESULT_ACCEPTED
    assert [(c.name, c.signed) for c in decided] == [("land", True)]
    # signed with another key: refused like an unsigned one
    gcs.received = []
    gcs.send(land, sender=signer(bytes(32)))
    gcs.pump(2.0, until=lambda r: any(m.get_type() == "COMMAND_ACK" for m in r))
    assert gcs.of_type("COMMAND_ACK")[0].result == mav.MAV_RESULT_DENIED
    assert len(decided) == 1 and logged[-1][0].signed is False


def test_garbage_and_floods_are_counted_and_the_link_keeps_answering(pair):
    gcs, link, _, _ = pair
    gcs.pump(1.0, until=lambda r: r)
    for n in range(2000):
        gcs.sock.sendto(bytes([0xFD, 0xFF, n % 256]) + bytes(n % 300), gcs.vehicle)  # truncated, hostile lengths
    for _ in range(300):
        gcs.send(mav.MAVLink_param_request_list_message(1, 1))
    gcs.received = []
    link.publish(snapshot(t=7.0))
    gcs.pump(4.0, until=lambda r: any(m.get_type() == "ATTITUDE" and m.time_boot_ms == 7000 for m in r))
    assert any(m.get_type() == "ATTITUDE" and m.time_boot_ms == 7000 for m in gcs.received)
    c = link.counters
    assert c.bad_data > 0 and c.frames_dropped_rate_limit + c.by_type.get("PARAM_REQUEST_LIST", 0) > 0
    assert c.by_type.get("PARAM_REQUEST_LIST", 0) <= 500 + 300  # parsing is capped per wall second
