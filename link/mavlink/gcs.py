"""The vehicle as a MAVLink ground-control station (QGroundControl, MAVProxy) sees it.

Takes in: `GcsSnapshot`s (plain dataclasses: ENU position and velocity, FLU rates, attitude (w, x, y, z)
ENU<-FLU, the geodetic position the ground station computed from its map origin, battery, armed, phase)
from the ground station's loop; MAVLink frames from the GCS, of any content.
Gives out: MAVLink 2 frames to the GCS endpoint (any connection string of the transport table, e.g.
`udpout:127.0.0.1:14550`, where QGroundControl and `mavproxy.py --master=udp:127.0.0.1:14550` listen):
    HEARTBEAT           every heartbeat_period_s of wall time, from system 1 component 1 (MAV_COMP_ID_AUTOPILOT1),
                        type QUADROTOR, autopilot GENERIC (a Crazyflie runs neither PX4 nor ArduPilot);
    SYS_STATUS, BATTERY_STATUS  with the heartbeat;
    ATTITUDE, LOCAL_POSITION_NED, GLOBAL_POSITION_INT  for every snapshot published (NED/FRD here only);
and answers: PARAM_REQUEST_LIST / PARAM_REQUEST_READ -> PARAM_VALUE (read-only: a PARAM_SET is answered
with the unchanged value), MISSION_REQUEST_LIST -> MISSION_COUNT 0, COMMAND_LONG/COMMAND_INT ->
COMMAND_ACK (AUTOPILOT_VERSION on request), FILE_TRANSFER_PROTOCOL -> NAK (no FTP server). Flight
commands (arm/disarm, land, return, takeoff, mode:
COMMAND_* or SET_MODE) are refused (MAV_RESULT_DENIED) unless the frame is signed with our key or the user
allowed GCS commands; either way each is recorded through `on_command_logged`.

All of it runs on one thread of its own: the loop only hands over the newest snapshot (`publish`, a
deque append), so a GCS that floods or sends garbage costs the flight nothing but that thread's CPU, and
at most `max_frames_per_s` frames per second are even parsed (the rest are drained and counted).
time_boot_ms is the flight's simulated time, so lockstep and realtime flights read alike.
"""

from __future__ import annotations

import math
import struct
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum

from pymavlink.dialects.v20 import common as mav

from link.mavlink.codec import enu_to_ned, flu_to_frd, quat_enu_flu_to_ned_frd
from link.mavlink.signing import SignatureCheck, Signing
from link.transports import open_transport
from model.frames import euler_zyx_of

VEHICLE_SYSTEM_ID = 1
AUTOPILOT_COMPONENT_ID = mav.MAV_COMP_ID_AUTOPILOT1
UINT16_MAX = 0xFFFF
INT16_MAX = 0x7FFF
PARAM_ID_LEN = 16
# The thread's longest sleep: frames from the GCS wake it at once; snapshots wait at most this long (a GCS
# draws at 10-30 Hz). Longer sleeps mean fewer wake-ups competing with the flight loop for the GIL.
POLL_S = 0.05  # MAVLink PARAM_VALUE.param_id: at most 16 characters

# COMMAND_LONG / COMMAND_INT that act on the flight (what "arm, land, mode" covers), by name for the log.
FLIGHT_COMMANDS = {
    mav.MAV_CMD_COMPONENT_ARM_DISARM: "arm_disarm",
    mav.MAV_CMD_NAV_LAND: "land",
    mav.MAV_CMD_NAV_RETURN_TO_LAUNCH: "return_to_launch",
    mav.MAV_CMD_NAV_TAKEOFF: "takeoff",
    mav.MAV_CMD_DO_SET_MODE: "set_mode",
    mav.MAV_CMD_DO_FLIGHTTERMINATION: "flight_termination",
    mav.MAV_CMD_MISSION_START: "mission_start",
    mav.MAV_CMD_DO_REPOSITION: "reposition",
}
# MAVLink FTP (mavlink.io "File Transfer Protocol"): header seq u16, session, opcode, size, req_opcode,
# burst_complete, padding u8, offset u32; a NAK (129) carries one error byte.
FTP_HEADER = struct.Struct("<HBBBBBBI")
FTP_PAYLOAD_LEN = 251
FTP_NAK = 129
FTP_ERR_UNKNOWN_COMMAND = 7
# Requests a GCS sends on connect that we answer with a message and an ACK.
MESSAGE_REQUESTS = (mav.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, mav.MAV_CMD_REQUEST_MESSAGE)


class Verdict(Enum):
    """What became of a flight command (sent to the GCS as the matching MAV_RESULT)."""

    ACCEPTED = "accepted"
    DENIED = "denied"  # not allowed: unsigned without the user's permission, or unsafe now
    TEMPORARILY_REJECTED = "temporarily_rejected"  # allowed, but not in this state
    UNSUPPORTED = "unsupported"


_MAV_RESULT = {
    Verdict.ACCEPTED: mav.MAV_RESULT_ACCEPTED,
    Verdict.DENIED: mav.MAV_RESULT_DENIED,
    Verdict.TEMPORARILY_REJECTED: mav.MAV_RESULT_TEMPORARILY_REJECTED,
    Verdict.UNSUPPORTED: mav.MAV_RESULT_UNSUPPORTED,
}


@dataclass(frozen=True)
class GcsSnapshot:
    """What the GCS is shown at one moment of the flight (world ENU, body FLU, SI units)."""

    time_s: float  # simulated time since the vehicle's boot
    position_enu_m: tuple[float, float, float]
    velocity_enu_mps: tuple[float, float, float]
    attitude_wxyz: tuple[float, float, float, float]  # body FLU -> world ENU
    rate_flu_radps: tuple[float, float, float]
    latitude_deg: float
    longitude_deg: float
    altitude_msl_m: float
    height_above_origin_m: float
    battery_v: float | None  # None: not reported yet
    battery_remaining_pct: int | None
    armed: bool
    healthy: bool  # the estimate is fit for control


@dataclass
class GcsCounters:
    frames_parsed: int = 0
    frames_dropped_rate_limit: int = 0  # drained without parsing: over max_frames_per_s
    bad_data: int = 0  # bytes pymavlink could not make a frame of
    param_values_sent: int = 0
    commands_refused: int = 0
    commands_accepted: int = 0
    snapshots_sent: int = 0
    gcs_heartbeats: int = 0
    by_type: dict[str, int] = field(default_factory=dict)


@dataclass(frozen=True)
class GcsCommand:
    """A flight command from the GCS, for the decision and the log."""

    wall_time_s: float
    sim_time_s: float | None  # of the newest snapshot when it arrived
    name: str  # FLIGHT_COMMANDS name, or "set_mode" for SET_MODE
    params: tuple[float, ...]
    signed: bool  # signed with our key (SignatureCheck.OK)


class GcsLink:
    """Streams snapshots to one GCS endpoint and answers it, on a daemon thread. Use as a context manager.

    params: read-only parameters shown to the GCS (name <= 16 characters -> float).
    on_command: decides an allowed flight command (returns a Verdict); None refuses everything.
    allow_commands: accept flight commands without a signature (else only frames signed with `signing`).
    on_command_logged(command, verdict): every flight command and its Verdict, accepted or not."""

    def __init__(self, connection: str, params: dict[str, float], *, heartbeat_period_s: float = 1.0,
                 max_frames_per_s: int = 500, signing: Signing | None = None, allow_commands: bool = False,
                 on_command: Callable[[GcsCommand], Verdict] | None = None,
                 on_command_logged: Callable[[GcsCommand, Verdict], None] | None = None):
        self._transport = open_transport(connection)
        self._params = {name[:PARAM_ID_LEN]: float(v) for name, v in params.items()}
        self._param_names = list(self._params)
        self._heartbeat_period_s = heartbeat_period_s
        self._max_frames_per_s = max_frames_per_s
        self._signing = signing
        self._allow_commands = allow_commands
        self._on_command = on_command
        self._on_command_logged = on_command_logged
        self._mav = mav.MAVLink(None, srcSystem=VEHICLE_SYSTEM_ID, srcComponent=AUTOPILOT_COMPONENT_ID)  # sender
        self._pending: deque[GcsSnapshot] = deque(maxlen=64)  # the loop appends; the thread sends
        self._latest: GcsSnapshot | None = None
        self.counters = GcsCounters()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="cfstack-gcs", daemon=True)
        self._thread.start()

    # -- the loop's side ---------------------------------------------------------------------------------

    def publish(self, snapshot: GcsSnapshot) -> None:
        """Hand over a snapshot (never blocks; the oldest unsent ones are dropped past 64)."""
        self._pending.append(snapshot)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self._transport.close()

    def __enter__(self) -> GcsLink:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- the thread ---------------------------------------------------------------------------------------

    def _run(self) -> None:
        next_heartbeat = 0.0
        window_start, parsed_in_window = time.monotonic(), 0
        while not self._stop.is_set():
            datagrams = self._transport.receive(timeout_s=POLL_S)
            now = time.monotonic()
            if now - window_start >= 1.0:
                window_start, parsed_in_window = now, 0
            for datagram in datagrams:
                if parsed_in_window >= self._max_frames_per_s:
                    self.counters.frames_dropped_rate_limit += 1
                    continue
                parsed_in_window += 1
                self._receive(datagram)
            while self._pending:
                self._send_snapshot(self._pending.popleft())
            if now >= next_heartbeat:
                next_heartbeat = now + self._heartbeat_period_s
                self._send_heartbeat()

    def _send(self, message) -> None:
        self._transport.send(message.pack(self._mav))

    def _send_heartbeat(self) -> None:
        s = self._latest
        armed = bool(s and s.armed)
        base_mode = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (mav.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0)
        status = mav.MAV_STATE_ACTIVE if armed else mav.MAV_STATE_STANDBY
        self._send(mav.MAVLink_heartbeat_message(mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_GENERIC, base_mode, 0,
                                                 status, 3))
        if s is not None:
            self._send_battery(s)

    def _send_battery(self, s: GcsSnapshot) -> None:
        millivolts = UINT16_MAX if s.battery_v is None else min(int(round(s.battery_v * 1e3)), UINT16_MAX - 1)
        remaining = -1 if s.battery_remaining_pct is None else int(s.battery_remaining_pct)
        sensors = (mav.MAV_SYS_STATUS_SENSOR_3D_GYRO | mav.MAV_SYS_STATUS_SENSOR_3D_ACCEL
                   | mav.MAV_SYS_STATUS_SENSOR_VISION_POSITION)
        health = sensors if s.healthy else sensors & ~mav.MAV_SYS_STATUS_SENSOR_VISION_POSITION
        self._send(mav.MAVLink_sys_status_message(sensors, sensors, health, 0, millivolts, -1, remaining,
                                                  0, 0, 0, 0, 0, 0))
        cells = [millivolts] + [UINT16_MAX] * 9
        self._send(mav.MAVLink_battery_status_message(0, mav.MAV_BATTERY_FUNCTION_ALL, mav.MAV_BATTERY_TYPE_LIPO,
                                                      INT16_MAX, cells, -1, -1, -1, remaining))

    def _send_snapshot(self, s: GcsSnapshot) -> None:
        self._latest = s
        boot_ms = int(s.time_s * 1e3) & 0xFFFFFFFF
        roll, pitch, yaw = euler_zyx_of(quat_enu_flu_to_ned_frd(s.attitude_wxyz))
        p, q, r = flu_to_frd(s.rate_flu_radps)
        self._send(mav.MAVLink_attitude_message(boot_ms, roll, pitch, yaw, p, q, r))
        north, east, down = enu_to_ned(s.position_enu_m)
        vn, ve, vd = enu_to_ned(s.velocity_enu_mps)
        self._send(mav.MAVLink_local_position_ned_message(boot_ms, north, east, down, vn, ve, vd))
        heading_cdeg = int(round(math.degrees(yaw) * 100)) % 36000
        self._send(mav.MAVLink_global_position_int_message(
            boot_ms, int(round(s.latitude_deg * 1e7)), int(round(s.longitude_deg * 1e7)),
            int(round(s.altitude_msl_m * 1e3)), int(round(s.height_above_origin_m * 1e3)),
            _cm_per_s(vn), _cm_per_s(ve), _cm_per_s(vd), heading_cdeg))
        self.counters.snapshots_sent += 1

    # -- what the GCS sends ------------------------------------------------------------------------------

    def _receive(self, datagram: bytes) -> None:
        # A parser per datagram: UDP keeps frame boundaries, so a truncated or hostile datagram must not
        # leave half a frame in a stream buffer to swallow the next, well-formed one.
        parser = mav.MAVLink(None)
        parser.robust_parsing = True
        try:
            messages = parser.parse_buffer(datagram) or []
        except Exception:  # noqa: BLE001 - pymavlink raises on some malformed input even when robust
            self.counters.bad_data += 1
            return
        for message in messages:
            kind = message.get_type()
            if kind == "BAD_DATA":
                self.counters.bad_data += 1
                continue
            self.counters.frames_parsed += 1
            self.counters.by_type[kind] = self.counters.by_type.get(kind, 0) + 1
            handler = getattr(self, f"_on_{kind.lower()}", None)
            if handler is not None:
                handler(message)

    def _on_heartbeat(self, message) -> None:
        self.counters.gcs_heartbeats += 1

    def _on_param_request_list(self, message) -> None:
        for index in range(len(self._param_names)):
            self._send_param(index)

    def _on_param_request_read(self, message) -> None:
        index = message.param_index
        if index < 0:
            name = message.param_id
            index = self._param_names.index(name) if name in self._params else -1
        if 0 <= index < len(self._param_names):
            self._send_param(index)

    def _on_param_set(self, message) -> None:
        # Read-only: the answer is the value we keep (the MAVLink parameter protocol's refusal).
        if message.param_id in self._params:
            self._send_param(self._param_names.index(message.param_id))

    def _send_param(self, index: int) -> None:
        name = self._param_names[index]
        self._send(mav.MAVLink_param_value_message(name.encode(), self._params[name], mav.MAV_PARAM_TYPE_REAL32,
                                                   len(self._param_names), index))
        self.counters.param_values_sent += 1

    def _on_mission_request_list(self, message) -> None:
        self._send(mav.MAVLink_mission_count_message(message.get_srcSystem(), message.get_srcComponent(), 0,
                                                     getattr(message, "mission_type", 0)))

    def _on_file_transfer_protocol(self, message) -> None:
        """No MAVLink FTP server here: NAK every request (UnknownCommand), so a GCS falls back at once to
        the parameter protocol instead of waiting for its FTP timeout (MAVProxy, QGroundControl)."""
        request = bytes(message.payload)
        if len(request) < FTP_HEADER.size:
            return
        seq, session, opcode = FTP_HEADER.unpack_from(request)[:3]
        header = FTP_HEADER.pack((seq + 1) & 0xFFFF, session, FTP_NAK, 1, opcode, 0, 0, 0)
        reply = header + bytes([FTP_ERR_UNKNOWN_COMMAND])
        self._send(mav.MAVLink_file_transfer_protocol_message(0, message.get_srcSystem(), message.get_srcComponent(),
                                                              list(reply.ljust(FTP_PAYLOAD_LEN, b"\0"))))

    def _on_command_long(self, message) -> None:
        params = (message.param1, message.param2, message.param3, message.param4, message.param5,
                  message.param6, message.param7)
        self._command(message, message.command, params)

    def _on_command_int(self, message) -> None:
        params = (message.param1, message.param2, message.param3, message.param4, float(message.x),
                  float(message.y), message.z)
        self._command(message, message.command, params)

    def _on_set_mode(self, message) -> None:
        result = self._flight_command(message, "set_mode", (float(message.base_mode), float(message.custom_mode)))
        self._send(mav.MAVLink_command_ack_message(mav.MAVLINK_MSG_ID_SET_MODE, result))

    def _command(self, message, command: int, params: tuple[float, ...]) -> None:
        if command in MESSAGE_REQUESTS:
            wanted = int(params[0]) if command == mav.MAV_CMD_REQUEST_MESSAGE else mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION
            if wanted == mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
                self._send_ack(message, command, mav.MAV_RESULT_ACCEPTED)
                self._send_autopilot_version()
            else:
                self._send_ack(message, command, mav.MAV_RESULT_UNSUPPORTED)
        elif command in FLIGHT_COMMANDS:
            self._send_ack(message, command, self._flight_command(message, FLIGHT_COMMANDS[command], params))
        else:
            self._send_ack(message, command, mav.MAV_RESULT_UNSUPPORTED)

    def _flight_command(self, message, name: str, params: tuple[float, ...]) -> int:
        """The MAV_RESULT for a flight command: DENIED unless signed by us or allowed, else on_command's."""
        signed = self._signed_by_us(message)
        command = GcsCommand(time.time(), None if self._latest is None else self._latest.time_s, name,
                             tuple(float(p) for p in params), signed)
        if not (signed or self._allow_commands) or self._on_command is None:
            verdict = Verdict.DENIED
        else:
            verdict = self._on_command(command)
        if verdict == Verdict.ACCEPTED:
            self.counters.commands_accepted += 1
        else:
            self.counters.commands_refused += 1
        if self._on_command_logged is not None:
            self._on_command_logged(command, verdict)
        return _MAV_RESULT[verdict]

    def _signed_by_us(self, message) -> bool:
        frame = bytes(message.get_msgbuf())
        # pymavlink without a key of its own marks no frame signed: read the header's incompat flag
        if self._signing is None or frame[0] != mav.PROTOCOL_MARKER_V2 or not frame[2] & mav.MAVLINK_IFLAG_SIGNED:
            return False
        return self._signing.check(frame, message.get_srcSystem(), message.get_srcComponent()) == SignatureCheck.OK

    def _send_ack(self, message, command: int, result: int) -> None:
        self._send(mav.MAVLink_command_ack_message(command, result, 0, 0, message.get_srcSystem(),
                                                  message.get_srcComponent()))

    def _send_autopilot_version(self) -> None:
        capabilities = mav.MAV_PROTOCOL_CAPABILITY_MAVLINK2 | mav.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
        self._send(mav.MAVLink_autopilot_version_message(capabilities, 0, 0, 0, 0,
                                                         bytes(8), bytes(8), bytes(8), 0, 0, 0))


def _cm_per_s(v_mps: float) -> int:
    """GLOBAL_POSITION_INT velocities: int16 cm/s, clipped."""
    return max(-INT16_MAX, min(INT16_MAX, int(round(v_mps * 100))))
