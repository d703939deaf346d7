"""Decoders of the CRTP packets that command a Crazyflie, into plain records in the firmware's own units.

Takes in: a CrtpPacket on the commander (3), generic setpoint (7), localization (6), high-level
commander (8) or supervisor (9) port.
Gives out: one record per packet (below), or Malformed(reason) for a packet of the right port whose
payload cannot be what it claims (wrong length, unknown type), or Unsupported(what) for a valid packet
that the emulated firmware does not act on. Values stay in the units the Crazyflie's firmware decodes
them in (degrees, its legacy pitch sign, thrust in PWM units 0..65535): these records are read only by
the emulated firmware, which works in those units as the real one does; cfstack's own messages are SI.

Sources: cflib 0.1.34 commander.py, high_level_commander.py, extpos.py/localization.py, supervisor.py;
firmware crtp_commander_rpyt.c, crtp_commander_generic.c, crtp_localization_service.c,
crtp_commander_high_level.c, supervisor.c (../shared/reference/crtp_cflib_emulation.md section 6).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

from link.crtp.packet import CrtpPacket, Port


@dataclass(frozen=True)
class Rpyt:
    """Legacy setpoint (3:0, `<fffH>`): roll, pitch (as sent: cflib negates it), yaw rate, thrust."""

    roll_deg: float
    pitch_deg: float
    yaw_rate_dps: float
    thrust: int


@dataclass(frozen=True)
class StopSetpoint:
    """Generic type 0: every mode off, thrust 0 (motors stop)."""


@dataclass(frozen=True)
class PositionSetpoint:
    """Generic type 7: absolute position (m, world) and yaw (deg)."""

    x_m: float
    y_m: float
    z_m: float
    yaw_deg: float


@dataclass(frozen=True)
class VelocityWorld:
    """Generic type 8: velocity (m/s, world) and yaw rate (deg/s, counter-clockwise positive)."""

    vx_mps: float
    vy_mps: float
    vz_mps: float
    yaw_rate_dps: float


@dataclass(frozen=True)
class Hover:
    """Generic type 10: velocity in the yaw frame (m/s), yaw rate (deg/s, counter-clockwise positive) and
    absolute height (m); what cflib's MotionCommander streams."""

    vx_mps: float
    vy_mps: float
    yaw_rate_dps: float
    z_m: float


@dataclass(frozen=True)
class ZDistance:
    """Generic type 9: roll and pitch (deg, as sent), yaw rate (deg/s, counter-clockwise positive), height (m)."""

    roll_deg: float
    pitch_deg: float
    yaw_rate_dps: float
    z_m: float


@dataclass(frozen=True)
class Manual:
    """Generic type 11 (`<fffHB`): roll and pitch (deg, or deg/s with `rate`; pitch as sent: cflib negates
    it), yaw rate (deg/s, counter-clockwise positive), thrust (PWM units, no lock, no clamps)."""

    roll: float
    pitch: float
    yaw_rate_dps: float
    thrust: int
    rate: bool


@dataclass(frozen=True)
class CppmEmulation:
    """Generic type 3: RC channels in microseconds (1000..2000, midpoint 1500) and up to 10 auxiliary ones;
    aux 0 below 1500 turns self-levelling off (roll and pitch then command rates)."""

    roll_us: int
    pitch_us: int
    yaw_us: int
    thrust_us: int
    aux_us: tuple[int, ...]


@dataclass(frozen=True)
class AltitudeHold:
    """Generic type 4: roll and pitch (the firmware's header says rad, its decoder writes them to the
    attitude setpoint, which is in degrees: degrees is what flies), yaw rate (deg/s), vertical velocity
    (m/s, world)."""

    roll_deg: float
    pitch_deg: float
    yaw_rate_dps: float
    vz_mps: float


@dataclass(frozen=True)
class FullState:
    """Generic type 6: position (m), velocity (m/s), acceleration (m/s^2) on the wire in mm units, the
    attitude decompressed (w, x, y, z), body rates (rad/s; milliradians/s on the wire)."""

    position_m: tuple[float, float, float]
    velocity_mps: tuple[float, float, float]
    acceleration_mps2: tuple[float, float, float]
    attitude_wxyz: tuple[float, float, float, float]
    rates_radps: tuple[float, float, float]


@dataclass(frozen=True)
class NotifySetpointsStop:
    """Meta (7:1) type 0: the low-level setpoints end; the high-level commander may take over."""


@dataclass(frozen=True)
class ExternalPosition:
    """extpos (6:0): a position fix (m, world); attitude None for a position-only fix."""

    x_m: float
    y_m: float
    z_m: float
    attitude_wxyz: tuple[float, float, float, float] | None = None


@dataclass(frozen=True)
class HighLevel:
    """A high-level commander request (8:0): kind takeoff / land / go_to / stop, group mask, target and
    duration. For takeoff and land, z_m is the absolute height; go_to may be relative."""

    kind: str
    group_mask: int
    x_m: float = 0.0
    y_m: float = 0.0
    z_m: float = 0.0
    yaw_rad: float = 0.0
    use_current_yaw: bool = False
    duration_s: float = 0.0
    relative: bool = False


@dataclass(frozen=True)
class SupervisorRequest:
    """Supervisor (9): "state" (bitfield query, channel 0), "arm" / "disarm", "recover", "emergency_stop"."""

    kind: str


@dataclass(frozen=True)
class Malformed:
    reason: str


@dataclass(frozen=True)
class Unsupported:
    what: str


# generic setpoint types (crtp_commander_generic.c packetType)
GENERIC_STOP, GENERIC_FULL_STATE, GENERIC_POSITION, GENERIC_VELOCITY_WORLD = 0, 6, 7, 8
GENERIC_Z_DISTANCE, GENERIC_HOVER, GENERIC_MANUAL = 9, 10, 11
GENERIC_CPPM, GENERIC_ALTITUDE_HOLD = 3, 4
# the legacy types (cflib sends them to firmware of protocol < 8): the same packets with the yaw rate
# clockwise positive (legacyVelocityDecoder & co. negate it)
GENERIC_LEGACY = {1: GENERIC_VELOCITY_WORLD, 2: GENERIC_Z_DISTANCE, 5: GENERIC_HOVER}
CPPM_MAX_AUX_CHANNELS = 10  # MAX_AUX_RC_CHANNELS
QUAT_MAGNITUDE_BITS = 9  # quatcompress.h: per smaller component, a sign bit and a 9-bit magnitude
# high-level commander commands (high_level_commander.py)
HL_STOP, HL_GO_TO, HL_TAKEOFF_2, HL_LAND_2, HL_GO_TO_2 = 3, 4, 7, 8, 12
# supervisor commands (supervisor.py)
SUPERVISOR_STATE = 0x0C
SUPERVISOR_COMMANDS = {0x01: None, 0x02: "recover", 0x03: "emergency_stop", 0x04: "emergency_stop"}


def _unpack(fmt: str, data: bytes, what: str):
    if len(data) != struct.calcsize(fmt):
        return Malformed(f"{what}: {len(data)} bytes, expected {struct.calcsize(fmt)}")
    return struct.unpack(fmt, data)


def decode_command(packet: CrtpPacket):
    """The record of a commanding packet (see the module docstring); None for a port not handled here."""
    port, channel, data = packet.port, packet.channel, packet.data
    if port == Port.COMMANDER:
        values = _unpack("<fffH", data, "RPYT setpoint")
        return values if isinstance(values, Malformed) else Rpyt(*values)
    if port == Port.GENERIC_SETPOINT:
        return _generic(channel, data)
    if port == Port.LOCALIZATION:
        return _localization(channel, data)
    if port == Port.HIGH_LEVEL:
        return _high_level(data)
    if port == Port.SUPERVISOR:
        return _supervisor(channel, data)
    return None


def _generic(channel: int, data: bytes):
    if not data:
        return Malformed("generic setpoint without a type")
    kind, body = data[0], data[1:]
    if channel == 1:
        return NotifySetpointsStop() if kind == 0 else Malformed(f"meta command {kind} unknown")
    if channel != 0:
        return Malformed(f"generic setpoint channel {channel} unknown")
    if kind == GENERIC_STOP:
        return StopSetpoint() if not body else Malformed("stop setpoint with a payload")
    if kind == GENERIC_FULL_STATE:
        values = _unpack("<hhhhhhhhhIhhh", body, "full-state setpoint")
        if isinstance(values, Malformed):
            return values
        mm = [v / 1000.0 for v in values[:9]]
        return FullState(tuple(mm[0:3]), tuple(mm[3:6]), tuple(mm[6:9]), decompress_quaternion(values[9]),
                         tuple(v / 1000.0 for v in values[10:13]))
    if kind == GENERIC_MANUAL:
        values = _unpack("<fffHB", body, "manual setpoint")
        return values if isinstance(values, Malformed) else Manual(*values[:4], rate=values[4] != 0)
    if kind == GENERIC_CPPM:
        return _cppm(body)
    records = {GENERIC_POSITION: PositionSetpoint, GENERIC_VELOCITY_WORLD: VelocityWorld, GENERIC_HOVER: Hover,
               GENERIC_Z_DISTANCE: ZDistance, GENERIC_ALTITUDE_HOLD: AltitudeHold}
    legacy = kind in GENERIC_LEGACY
    record = records.get(GENERIC_LEGACY.get(kind, kind))
    if record is None:
        return Malformed(f"generic setpoint type {kind} unknown")
    values = _unpack("<ffff", body, f"generic setpoint type {kind}")
    if isinstance(values, Malformed):
        return values
    if legacy:
        yaw = 3 if record is VelocityWorld else 2  # the yaw rate's place in the packet
        values = (*values[:yaw], -values[yaw], *values[yaw + 1:])
    return record(*values)


def _cppm(body: bytes):
    """cppmEmuDecoder's packet: a header byte (aux channel count, low 4 bits), four channels, the aux ones."""
    if len(body) < 9:
        return Malformed(f"cppm setpoint: {len(body)} bytes, expected at least 9")
    aux = body[0] & 0x0F
    if aux > CPPM_MAX_AUX_CHANNELS or len(body) != 9 + 2 * aux:
        return Malformed(f"cppm setpoint: {len(body)} bytes for {aux} aux channels (expected {9 + 2 * aux}, "
                         f"at most {CPPM_MAX_AUX_CHANNELS} aux)")
    channels = struct.unpack(f"<{4 + aux}H", body[1:])
    return CppmEmulation(*channels[:4], aux_us=tuple(channels[4:]))


def _localization(channel: int, data: bytes):
    if channel == 0:
        values = _unpack("<fff", data, "extpos")
        return values if isinstance(values, Malformed) else ExternalPosition(*values)
    if channel == 1 and data and data[0] == 8:  # GENERIC_TYPE EXT_POSE: x y z qx qy qz qw
        values = _unpack("<fffffff", data[1:], "extpose")
        if isinstance(values, Malformed):
            return values
        x, y, z, qx, qy, qz, qw = values
        return ExternalPosition(x, y, z, (qw, qx, qy, qz))
    if channel == 1 and data:
        return Unsupported(f"localization packet type {data[0]}")
    return Malformed(f"localization channel {channel} packet unknown")


def _high_level(data: bytes):
    if not data:
        return Malformed("high-level command without a command byte")
    cmd = data[0]
    if cmd == HL_STOP:
        values = _unpack("<BB", data, "high-level stop")
        return values if isinstance(values, Malformed) else HighLevel("stop", values[1])
    if cmd in (HL_TAKEOFF_2, HL_LAND_2):
        values = _unpack("<BBff?f", data, "high-level takeoff/land")
        if isinstance(values, Malformed):
            return values
        _, group, height, yaw, use_current, duration = values
        return HighLevel("takeoff" if cmd == HL_TAKEOFF_2 else "land", group, z_m=height, yaw_rad=yaw,
                         use_current_yaw=use_current, duration_s=duration)
    if cmd == HL_GO_TO:
        values = _unpack("<BBBfffff", data, "high-level go_to")
        if isinstance(values, Malformed):
            return values
        _, group, relative, x, y, z, yaw, duration = values
        return HighLevel("go_to", group, x, y, z, yaw, duration_s=duration, relative=bool(relative))
    if cmd == HL_GO_TO_2:
        values = _unpack("<BBBBfffff", data, "high-level go_to")
        if isinstance(values, Malformed):
            return values
        _, group, relative, linear, x, y, z, yaw, duration = values
        if linear:
            return Unsupported("high-level go_to with linear interpolation")
        return HighLevel("go_to", group, x, y, z, yaw, duration_s=duration, relative=bool(relative))
    return Unsupported(f"high-level command {cmd}")


def _supervisor(channel: int, data: bytes):
    if not data:
        return Malformed("supervisor packet without a command byte")
    cmd = data[0]
    if channel == 0:
        return SupervisorRequest("state") if cmd == SUPERVISOR_STATE else Unsupported(f"supervisor query {cmd}")
    if channel == 1 and cmd in SUPERVISOR_COMMANDS:
        if cmd == 0x01:
            if len(data) != 2:
                return Malformed("arming request without its flag")
            return SupervisorRequest("arm" if data[1] else "disarm")
        return SupervisorRequest(SUPERVISOR_COMMANDS[cmd])
    return Malformed(f"supervisor channel {channel} command {cmd} unknown")


def decompress_quaternion(packed: int) -> tuple[float, float, float, float]:
    """quatcompress.h quatdecompress: bits 31-30 name the largest of (x, y, z, w); the other three, from w
    down, are a 9-bit magnitude scaled by 1/sqrt(2) and a sign bit; the largest is what makes |q| = 1.
    Returns (w, x, y, z)."""
    mask = (1 << QUAT_MAGNITUDE_BITS) - 1
    largest = packed >> 30
    q = [0.0, 0.0, 0.0, 0.0]  # x, y, z, w as on the wire
    sum_squares = 0.0
    for i in (3, 2, 1, 0):
        if i == largest:
            continue
        magnitude, negative = packed & mask, (packed >> QUAT_MAGNITUDE_BITS) & 1
        packed >>= QUAT_MAGNITUDE_BITS + 1
        q[i] = (-1.0 if negative else 1.0) * math.sqrt(0.5) * magnitude / mask
        sum_squares += q[i] * q[i]
    q[largest] = math.sqrt(max(0.0, 1.0 - sum_squares))
    return (q[3], q[0], q[1], q[2])
