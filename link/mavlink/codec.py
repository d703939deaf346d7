"""MAVLink 2 encoding and decoding of the link.messages dataclasses (common dialect).

Takes in: message dataclasses (world ENU, body FLU, SI units, quaternions w,x,y,z body->world) to encode;
arbitrary byte chunks (datagrams or a serial stream) to decode.
Gives out: one MAVLink 2 frame (bytes) per message from `Codec.encode`; `Decoded` records (message,
header fields, signed flag, the frame's bytes) from `FrameParser.feed`, which never raises and counts
everything it drops in `FrameParser.counters` (`FrameParser.feed_fields`: the same as plain tuples).

Frames and units on the wire (MAVLink convention: world NED, body FRD):
    ENU -> NED: (x, y, z) -> (y, x, -z);  FLU -> FRD: (x, y, z) -> (x, -y, -z)   (both are involutions)
    q_ned_frd = q_(NED<-ENU) * q_enu_flu * q_(FLU<-FRD), with q_(NED<-ENU) the 180 deg turn about
    (x+y)/sqrt(2) and q_(FLU<-FRD) the 180 deg turn about x. Times are microseconds on the wire.

Mapping (message -> MAVLink message: fields):
    ThrustMoment   -> SET_ACTUATOR_CONTROL_TARGET (group 0): controls[0..2] = FRD moments / max moment
                      of that axis, controls[3] = thrust / max thrust (ActuatorLimits). Values outside
                      [-1, 1] / [0, 1] are sent as they are: saturation is the vehicle's decision.
    AttitudeTarget -> SET_ATTITUDE_TARGET: q NED/FRD, body rates FRD, thrust / max thrust, type_mask 0.
                      time_boot_ms: millisecond resolution, wraps after 49.7 days.
    PositionTarget -> SET_POSITION_TARGET_LOCAL_NED: local NED position and velocity, yaw from north
                      clockwise, acceleration and yaw rate ignored (type_mask), frame MAV_FRAME_LOCAL_NED.
    ImuSample      -> HIGHRES_IMU: x/y/zacc = specific force FRD (MAVLink's accel is specific force:
                      about (0, 0, -9.81) at rest), x/y/zgyro FRD, fields_updated = accel + gyro bits.
    MocapPose      -> ATT_POS_MOCAP: position NED, q NED/FRD, covariance[0] = NaN ("unknown").
                      The message has no body field: body_id travels as the frame's SOURCE SYSTEM ID,
                      as if the tracked vehicle's own companion computer sent it (PX4's convention for
                      external vision). Each source system id has its own sequence counter.
    ExternalPose   -> ATT_POS_MOCAP from the ground station (system id 255) to the vehicle it describes
                      (the vehicle's pose to fuse onboard); decoded as ExternalPose by that source id.
    Heartbeat      -> HEARTBEAT: type GCS (ground station) or QUADROTOR; base_mode SAFETY_ARMED when
                      armed (+ CUSTOM_MODE_ENABLED); custom_mode = VehicleMode, plus bit 8 when failsafe;
                      system_status FLIGHT_TERMINATION when CRASHED, else CRITICAL when failsafe, else
                      ACTIVE when armed, else STANDBY. (Bit 8 keeps failsafe when the status says
                      FLIGHT_TERMINATION; a CRITICAL or EMERGENCY status also decodes as failsafe.)
    VehicleCommand -> COMMAND_LONG: ARM/DISARM = MAV_CMD_COMPONENT_ARM_DISARM param1 1/0;
                      LAND = MAV_CMD_NAV_LAND with param4..7 NaN (current yaw and position);
                      REBOOT = MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN param1 1 (reboot the autopilot).
                      The issue time rides in param3 (unused by both commands) as float32 seconds:
                      resolution 2^-24 relative (< 1 ms for the first 4.5 h).
    MotorOutputs   -> SERVO_OUTPUT_RAW (port 0): servo1..4_raw = 1000 + 1000 duty us, the ESC pulse range
                      (PX4's PWM_MAIN_MIN/MAX defaults) for the Crazyflie's 16-bit PWM duty;
                      time_usec uint32 (wraps after 71.6 min).
    MotorOutputsRequest -> COMMAND_LONG MAV_CMD_SET_MESSAGE_INTERVAL: param1 = SERVO_OUTPUT_RAW's id,
                      param2 = interval us (-1: stop). Other message ids are not ours to answer.
    TimeSync       -> TIMESYNC: tc1 = remote_ns, ts1 = origin_ns.
    RadioStatus    -> RADIO_STATUS: field for field.
    BatteryStatus  -> SYS_STATUS: voltage_battery mV (NaN <-> UINT16_MAX "not sent"), battery_remaining
                      %, load in 0.1 %, errors_count1 = rejected_commands, current -1 ("not sent").
    TruthState     -> ODOMETRY: frame_id = child_frame_id = LOCAL_NED (so the velocity is world NED),
                      rates FRD, covariances NaN ("unknown"), quality 100. float32 fields.
    CrashReport    -> DEBUG_FLOAT_ARRAY, name "CRASH", array_id = Touched, data (a simulation-only array
                      of our own, on the truth key; ENU as the world file): position ENU (3), velocity
                      ENU (3), block index, block extents (6, NaN when none), limit; float32.

Decoding: the parser finds frames itself (bytes.find of the 0xFD magic) and checks the CRC with
pymavlink's own CRC-16/MCRF4XX (fastcrc); payloads are packed and unpacked with the struct layouts and
CRC_EXTRA bytes of pymavlink's generated common-dialect classes. Measured on this machine this is about
7x faster than pymavlink's `MAVLink.parse_buffer` / `decode` (about 7.6 / 5.6 us a HIGHRES_IMU frame
before any conversion) and its `pack` (5.1 us). Rules:
    - bytes before a magic byte, and the rest of any rejected candidate frame, count as garbage_bytes;
      after a rejected candidate the search resumes one byte after its magic byte, so garbage that
      looks like a frame start cannot swallow the genuine frame behind it;
    - unknown message ids (no CRC_EXTRA, so unverifiable) count in unknown_messages;
    - CRC mismatches count in crc_failures; unknown incompat flags in bad_headers;
    - valid frames whose message or content the schema cannot express (another message id, another
      command, an unknown mode...) count in unsupported_messages;
    - zero-truncated payloads are zero-extended (MAVLink 2); payloads longer than this dialect's message
      are accepted and the unknown extension bytes ignored, as the MAVLink C library does; a zero-length
      payload is malformed (the first byte is never truncated) and counts in bad_lengths;
    - with signing, see link.mavlink.signing (unsigned_rejected, bad_signatures, replays_rejected);
    - an incomplete frame at the end of a chunk waits for the next chunk (stream semantics), unless
      `feed(..., final=True)` says the chunk was a whole datagram: then it counts in truncated_frames;
    - non-finite numbers decode as they are: checking them is the receiver's job.
"""

from __future__ import annotations

import inspect
import math
import statistics
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass, fields, is_dataclass

# The v20 dialect module speaks MAVLink 2 whatever MAVLINK20 says (only mavutil reads that variable).
from pymavlink.dialects.v20 import common as mav

from link.keys import GROUND_STATION_SYSTEM_ID
from link.mavlink import frame_kernel
from link.mavlink.signing import SIGNATURE_BLOCK_LEN, SignatureCheck, Signing
from link.messages import (
    AttitudeTarget,
    BatteryStatus,
    CommandKind,
    CrashReport,
    ExternalPose,
    Heartbeat,
    ImuSample,
    Message,
    MocapPose,
    MotorOutputs,
    MotorOutputsRequest,
    PositionTarget,
    RadioStatus,
    ThrustMoment,
    TimeSync,
    Touched,
    TruthState,
    VehicleCommand,
    VehicleMode,
)
from model.frames import Quat, Vec3

MAGIC_V2 = 0xFD
HEADER_LEN = 10
CRC_LEN = 2
MIN_FRAME_LEN = HEADER_LEN + CRC_LEN
MAX_FRAME_LEN = HEADER_LEN + 255 + CRC_LEN + SIGNATURE_BLOCK_LEN
IFLAG_SIGNED = mav.MAVLINK_IFLAG_SIGNED
FAILSAFE_MODE_BIT = 1 << 8  # custom_mode bit carrying Heartbeat.failsafe (mode in the low byte)
MAVLINK_VERSION = 3  # HEARTBEAT.mavlink_version: fixed at 3 by the MAVLink definition
UINT16_NOT_SENT = 0xFFFF
ODOMETRY_QUALITY_TRUTH = 100  # best quality on MAVLink's 1..100 scale

_HEADER_AFTER_MAGIC = struct.Struct("<BBBBBBHB")  # len, incompat, compat, seq, sysid, compid, msgid (24 bit)
_MAGIC = bytes([MAGIC_V2])
_CRC = struct.Struct("<H")
_SQRT_HALF = math.sqrt(0.5)
_ZEROS = bytes(255)  # zero extension of a truncated payload (never longer than 255 bytes)
_REJECTED = -1  # FrameParser._signature_link_id: the frame failed the signing rules

if mav.mcrf4xx is not None:
    _crc16 = mav.mcrf4xx  # pymavlink's CRC-16/MCRF4XX binding (fastcrc, a pymavlink dependency)
else:  # pragma: no cover - pymavlink falls back to its pure-Python x25 class; so do we

    def _crc16(data, initial=0xFFFF):
        crc = mav.x25crc()
        crc.crc = initial
        crc.accumulate(bytes(data))
        return crc.crc


# ---------------------------------------------------------------------------------------------
# Frames: ENU/FLU <-> NED/FRD
# ---------------------------------------------------------------------------------------------


def enu_to_ned(v: Vec3) -> Vec3:
    """(east, north, up) -> (north, east, down); its own inverse."""
    return (v[1], v[0], -v[2])


ned_to_enu = enu_to_ned


def flu_to_frd(v: Vec3) -> Vec3:
    """(forward, left, up) -> (forward, right, down); its own inverse."""
    return (v[0], -v[1], -v[2])


frd_to_flu = flu_to_frd


# Rotation taking ENU coordinates to NED coordinates: R = [[0,1,0],[1,0,0],[0,0,-1]], the 180 deg turn
# about (x + y)/sqrt(2); and the one taking FRD body coordinates to FLU: diag(1,-1,-1), 180 deg about x.
Q_NED_FROM_ENU = (0.0, _SQRT_HALF, _SQRT_HALF, 0.0)
Q_FLU_FROM_FRD = (0.0, 1.0, 0.0, 0.0)


def quat_enu_flu_to_ned_frd(q_enu_flu: Quat) -> Quat:
    """q_ned_frd = q_(NED<-ENU) * q_enu_flu * q_(FLU<-FRD).

    Both factors are 180 deg turns (their squares are -1), so the negated product is exactly its own
    inverse: the same function maps NED/FRD back to ENU/FLU, sign included. (q and -q are the same
    rotation; the minus keeps w > 0 for near-level attitudes.) Multiplied out, with s = sqrt(1/2):
    -(a (x) q (x) c) = s (w + z, x + y, x - y, w - z) (tests/link/test_codec.py checks it against
    the two quaternion products and the rotation matrices)."""
    w, x, y, z = q_enu_flu
    return (_SQRT_HALF * (w + z), _SQRT_HALF * (x + y), _SQRT_HALF * (x - y), _SQRT_HALF * (w - z))


quat_ned_frd_to_enu_flu = quat_enu_flu_to_ned_frd


# ---------------------------------------------------------------------------------------------
# Limits for normalised thrust and moments
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ActuatorLimits:
    """The vehicle's maximum collective thrust (N) and body moment per axis (N m, FLU = FRD magnitudes)."""

    max_thrust_n: float
    max_moment_nm: tuple[float, float, float]

    def __post_init__(self):
        values = (self.max_thrust_n, *self.max_moment_nm)
        if len(self.max_moment_nm) != 3 or not all(math.isfinite(v) and v > 0 for v in values):
            raise ValueError(f"actuator limits must be finite and positive, got {values}")
        object.__setattr__(self, "max_moment_nm", tuple(float(m) for m in self.max_moment_nm))

    @staticmethod
    def from_vehicle(vehicle) -> ActuatorLimits:
        """Limits of a model.vehicle.Vehicle: max_thrust_n and max_moment_nm."""
        return ActuatorLimits(float(vehicle.max_thrust_n), tuple(float(m) for m in vehicle.max_moment_nm))


# ---------------------------------------------------------------------------------------------
# Wire layouts (from pymavlink's generated classes)
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Wire:
    msgid: int
    name: str
    unpacker: struct.Struct
    size: int
    crc_extra: bytes

    @staticmethod
    def of(cls) -> _Wire:
        return _Wire(cls.id, cls.msgname, cls.unpacker, cls.unpacker.size, bytes([cls.crc_extra]))


W_ACTUATOR = _Wire.of(mav.MAVLink_set_actuator_control_target_message)
W_ATTITUDE = _Wire.of(mav.MAVLink_set_attitude_target_message)
W_POSITION = _Wire.of(mav.MAVLink_set_position_target_local_ned_message)
W_IMU = _Wire.of(mav.MAVLink_highres_imu_message)
W_MOCAP = _Wire.of(mav.MAVLink_att_pos_mocap_message)
W_HEARTBEAT = _Wire.of(mav.MAVLink_heartbeat_message)
W_COMMAND = _Wire.of(mav.MAVLink_command_long_message)
W_TIMESYNC = _Wire.of(mav.MAVLink_timesync_message)
W_RADIO = _Wire.of(mav.MAVLink_radio_status_message)
W_SYS_STATUS = _Wire.of(mav.MAVLink_sys_status_message)
W_ODOMETRY = _Wire.of(mav.MAVLink_odometry_message)
W_DEBUG_ARRAY = _Wire.of(mav.MAVLink_debug_float_array_message)
W_SERVO = _Wire.of(mav.MAVLink_servo_output_raw_message)
SERVO_PULSE_MIN_US, SERVO_PULSE_SPAN_US = 1000.0, 1000.0  # duty 0..1 <-> 1000..2000 us (PX4 PWM_MAIN_MIN/MAX)
INTERVAL_STOP_US = -1.0  # MAV_CMD_SET_MESSAGE_INTERVAL param2: -1 disables the message

# CRC_EXTRA of every message of the common dialect: frames of messages we do not decode can still be
# verified (and skipped whole) instead of being mistaken for garbage.
_CRC_EXTRA = {msgid: bytes([cls.crc_extra]) for msgid, cls in mav.mavlink_map.items()}

_IMU_FIELDS_UPDATED = (
    mav.HIGHRES_IMU_UPDATED_XACC | mav.HIGHRES_IMU_UPDATED_YACC | mav.HIGHRES_IMU_UPDATED_ZACC
    | mav.HIGHRES_IMU_UPDATED_XGYRO | mav.HIGHRES_IMU_UPDATED_YGYRO | mav.HIGHRES_IMU_UPDATED_ZGYRO
)
_NAN = float("nan")
_NAN_COVARIANCE = (_NAN,) + (0.0,) * 20  # MAVLink: NaN in the first element = covariance unknown
_ATTITUDE_RATE_IGNORE = (
    mav.ATTITUDE_TARGET_TYPEMASK_BODY_ROLL_RATE_IGNORE,
    mav.ATTITUDE_TARGET_TYPEMASK_BODY_PITCH_RATE_IGNORE,
    mav.ATTITUDE_TARGET_TYPEMASK_BODY_YAW_RATE_IGNORE,
)
_ATTITUDE_UNSUPPORTED_MASK = (
    mav.ATTITUDE_TARGET_TYPEMASK_THROTTLE_IGNORE | mav.ATTITUDE_TARGET_TYPEMASK_ATTITUDE_IGNORE
)


def _usec(time_s: float) -> int:
    return int(round(time_s * 1e6))


def _msec(time_s: float) -> int:
    return int(round(time_s * 1e3))


# ---------------------------------------------------------------------------------------------
# Encoders: (message, limits, target_system) -> packed payload (before zero truncation)
# ---------------------------------------------------------------------------------------------
# They pack directly with their wire's struct (no intermediate tuple): encoding runs per frame at
# 500 Hz-1 kHz in the ground station and the emulator.

_PACK_ACTUATOR = W_ACTUATOR.unpacker.pack
_PACK_ATTITUDE = W_ATTITUDE.unpacker.pack
_PACK_POSITION = W_POSITION.unpacker.pack
# SET_POSITION_TARGET_LOCAL_NED: position, velocity and yaw used; acceleration and yaw rate ignored
_POSITION_TYPE_MASK = (mav.POSITION_TARGET_TYPEMASK_AX_IGNORE | mav.POSITION_TARGET_TYPEMASK_AY_IGNORE
                       | mav.POSITION_TARGET_TYPEMASK_AZ_IGNORE | mav.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE)
_PACK_IMU = W_IMU.unpacker.pack
_PACK_MOCAP = W_MOCAP.unpacker.pack
_PACK_HEARTBEAT = W_HEARTBEAT.unpacker.pack
_PACK_COMMAND = W_COMMAND.unpacker.pack
_PACK_TIMESYNC = W_TIMESYNC.unpacker.pack
_PACK_RADIO = W_RADIO.unpacker.pack
_PACK_SYS_STATUS = W_SYS_STATUS.unpacker.pack
_PACK_ODOMETRY = W_ODOMETRY.unpacker.pack
_PACK_DEBUG_ARRAY = W_DEBUG_ARRAY.unpacker.pack
_PACK_SERVO = W_SERVO.unpacker.pack


def _enc_thrust_moment(m: ThrustMoment, limits: ActuatorLimits, target: int) -> bytes:
    mx, my, mz = limits.max_moment_nm
    x, y, z = m.moment_flu_nm  # FLU -> FRD inline (as flu_to_frd)
    return _PACK_ACTUATOR(int(round(m.time_s * 1e6)), x / mx, -y / my, -z / mz, m.thrust_n / limits.max_thrust_n,
                          0.0, 0.0, 0.0, 0.0, 0, target, 0)


def _enc_attitude_target(m: AttitudeTarget, limits: ActuatorLimits, target: int) -> bytes:
    q = quat_enu_flu_to_ned_frd(m.attitude_wxyz)
    p, q_, r = flu_to_frd(m.rates_flu_radps)
    return _PACK_ATTITUDE(_msec(m.time_s), *q, p, q_, r, m.thrust_n / limits.max_thrust_n, target, 0, 0)


def _enc_position_target(m: PositionTarget, limits, target: int) -> bytes:
    p, v = m.position_enu_m, m.velocity_enu_mps
    yaw_ned = math.remainder(math.pi / 2.0 - m.yaw_enu_rad, 2.0 * math.pi)  # heading from north, clockwise
    return _PACK_POSITION(_msec(m.time_s), p[1], p[0], -p[2], v[1], v[0], -v[2], 0.0, 0.0, 0.0, yaw_ned, 0.0,
                          _POSITION_TYPE_MASK, target, 0, mav.MAV_FRAME_LOCAL_NED)


def _enc_imu(m: ImuSample, limits, target: int) -> bytes:
    fx, fy, fz = m.specific_force_flu_mps2
    wx, wy, wz = m.rate_flu_radps
    return _PACK_IMU(int(round(m.time_s * 1e6)), fx, -fy, -fz, wx, -wy, -wz,
                     0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, _IMU_FIELDS_UPDATED, 0)


# ATT_POS_MOCAP's wire order is time, q, position, then the covariance, unknown in every frame we send: packed
# once, appended per frame.
_MOCAP_STATE = struct.Struct("<Q7f")
_PACK_MOCAP_STATE = _MOCAP_STATE.pack
_MOCAP_COVARIANCE_TAIL = _PACK_MOCAP(0, *(0.0,) * 7, *_NAN_COVARIANCE)[_MOCAP_STATE.size:]


def _enc_mocap(m: MocapPose, limits, target: int) -> bytes:
    p = m.position_enu_m
    q = quat_enu_flu_to_ned_frd(m.attitude_wxyz)
    return _PACK_MOCAP_STATE(_usec(m.time_s), *q, p[1], p[0], -p[2]) + _MOCAP_COVARIANCE_TAIL


def _enc_external_pose(m: ExternalPose, limits, target: int) -> bytes:
    return _enc_mocap(MocapPose(m.time_s, target, m.position_enu_m, m.attitude_wxyz), limits, target)


def _enc_heartbeat(m: Heartbeat, limits, target: int) -> bytes:
    mode = VehicleMode(m.mode)
    if m.is_ground_station:
        kind, autopilot = mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID
    else:
        kind, autopilot = mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_GENERIC
    base_mode = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (mav.MAV_MODE_FLAG_SAFETY_ARMED if m.armed else 0)
    if mode is VehicleMode.CRASHED:
        status = mav.MAV_STATE_FLIGHT_TERMINATION
    elif m.failsafe:
        status = mav.MAV_STATE_CRITICAL
    else:
        status = mav.MAV_STATE_ACTIVE if m.armed else mav.MAV_STATE_STANDBY
    custom_mode = int(mode) | (FAILSAFE_MODE_BIT if m.failsafe else 0)
    return _PACK_HEARTBEAT(custom_mode, kind, autopilot, base_mode, status, MAVLINK_VERSION)


def _enc_command(m: VehicleCommand, limits, target: int) -> bytes:
    kind = CommandKind(m.kind)
    issue_s = float(m.time_s)
    if kind is CommandKind.LAND:
        # param1 abort altitude 0 (none), param2 normal landing, param3 = issue time,
        # param4 yaw NaN (keep current), param5..7 NaN (land where you are)
        params = (0.0, 0.0, issue_s, _NAN, _NAN, _NAN, _NAN)
        command = mav.MAV_CMD_NAV_LAND
    elif kind is CommandKind.REBOOT:
        # param1 1 = reboot the autopilot, param2 0 = leave the onboard computer alone, param3 = issue time
        params = (1.0, 0.0, issue_s, 0.0, 0.0, 0.0, 0.0)
        command = mav.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN
    else:
        params = (1.0 if kind is CommandKind.ARM else 0.0, 0.0, issue_s, 0.0, 0.0, 0.0, 0.0)
        command = mav.MAV_CMD_COMPONENT_ARM_DISARM
    return _PACK_COMMAND(*params, command, target, 0, 0)


def _enc_motor_outputs(m: MotorOutputs, limits, target: int) -> bytes:
    pulses = [int(round(SERVO_PULSE_MIN_US + SERVO_PULSE_SPAN_US * d)) for d in m.duty]
    return _PACK_SERVO(_usec(m.time_s) & 0xFFFFFFFF, *pulses, 0, 0, 0, 0, 0, *(0,) * 8)


def _enc_motor_request(m: MotorOutputsRequest, limits, target: int) -> bytes:
    interval_us = 1e6 / m.rate_hz if m.rate_hz > 0.0 else INTERVAL_STOP_US
    return _PACK_COMMAND(float(W_SERVO.msgid), interval_us, 0.0, 0.0, 0.0, 0.0, 0.0,
                         mav.MAV_CMD_SET_MESSAGE_INTERVAL, target, 0, 0)


def _enc_timesync(m: TimeSync, limits, target: int) -> bytes:
    return _PACK_TIMESYNC(m.remote_ns, m.origin_ns)


def _enc_radio(m: RadioStatus, limits, target: int) -> bytes:
    return _PACK_RADIO(m.rx_errors, m.fixed, m.rssi, m.remote_rssi, m.tx_buffer_pct, m.noise, m.remote_noise)


def _enc_battery(m: BatteryStatus, limits, target: int) -> bytes:
    millivolts = UINT16_NOT_SENT if math.isnan(m.voltage_v) else int(round(m.voltage_v * 1000.0))
    load_permille = int(round(m.load_pct * 10.0))
    return _PACK_SYS_STATUS(
        0, 0, 0, load_permille, millivolts, -1, 0, 0, m.rejected_commands & 0xFFFF, m.uplink_received & 0xFFFF,
        0, 0, m.remaining_pct, 0, 0, 0,
    )


# ODOMETRY's wire order is time, the 13 state floats, then what truth frames never change (both
# covariances unknown, frames, reset counter, estimator type, quality): packed once, appended per frame.
_ODOMETRY_STATE = struct.Struct("<Q13f")
_PACK_ODOMETRY_STATE = _ODOMETRY_STATE.pack
_ODOMETRY_TRUTH_TAIL = _PACK_ODOMETRY(
    0, *(0.0,) * 13, *_NAN_COVARIANCE, *_NAN_COVARIANCE,
    mav.MAV_FRAME_LOCAL_NED, mav.MAV_FRAME_LOCAL_NED, 0, mav.MAV_ESTIMATOR_TYPE_UNKNOWN, ODOMETRY_QUALITY_TRUTH,
)[_ODOMETRY_STATE.size:]


def _enc_truth(m: TruthState, limits, target: int) -> bytes:
    p = m.position_enu_m
    v = m.velocity_enu_mps
    w = m.rate_flu_radps
    q = quat_enu_flu_to_ned_frd(m.attitude_wxyz)
    return _PACK_ODOMETRY_STATE(
        _usec(m.time_s), p[1], p[0], -p[2], *q, v[1], v[0], -v[2], w[0], -w[1], -w[2],
    ) + _ODOMETRY_TRUTH_TAIL


CRASH_ARRAY_NAME = b"CRASH"
_DEBUG_ARRAY_LEN = 58  # DEBUG_FLOAT_ARRAY data[58]
_CRASH_VALUES = 14  # position (3), velocity (3), block index, extents (6), limit


def _enc_crash(m: CrashReport, limits, target: int) -> bytes:
    extents = tuple(m.block_extents_m) if m.block_extents_m else (_NAN,) * 6
    values = (*m.position_enu_m, *m.velocity_enu_mps, float(m.block_index), *extents, m.limit)
    return _PACK_DEBUG_ARRAY(_usec(m.time_s), int(m.touched), CRASH_ARRAY_NAME,
                             *values, *(0.0,) * (_DEBUG_ARRAY_LEN - _CRASH_VALUES))


_ENCODER_WIRES: dict[type, tuple[_Wire, Callable]] = {
    ThrustMoment: (W_ACTUATOR, _enc_thrust_moment),
    AttitudeTarget: (W_ATTITUDE, _enc_attitude_target),
    PositionTarget: (W_POSITION, _enc_position_target),
    ImuSample: (W_IMU, _enc_imu),
    MocapPose: (W_MOCAP, _enc_mocap),
    ExternalPose: (W_MOCAP, _enc_external_pose),
    Heartbeat: (W_HEARTBEAT, _enc_heartbeat),
    VehicleCommand: (W_COMMAND, _enc_command),
    MotorOutputs: (W_SERVO, _enc_motor_outputs),
    MotorOutputsRequest: (W_COMMAND, _enc_motor_request),
    TimeSync: (W_TIMESYNC, _enc_timesync),
    RadioStatus: (W_RADIO, _enc_radio),
    BatteryStatus: (W_SYS_STATUS, _enc_battery),
    TruthState: (W_ODOMETRY, _enc_truth),
    CrashReport: (W_DEBUG_ARRAY, _enc_crash),
}
# Per message type, flat: (encoder, msgid, crc_extra, wire name), one tuple unpacked per frame.
_ENCODERS: dict[type, tuple[Callable, int, bytes, str]] = {
    kind: (encoder, wire.msgid, wire.crc_extra, wire.name) for kind, (wire, encoder) in _ENCODER_WIRES.items()
}
_NEEDS_LIMITS = frozenset({ThrustMoment, AttitudeTarget})

# The compiled twin of encode for the messages of a lockstep tick (link.mavlink.frame_kernel), given this
# module's constants (configured below): it gives the bytes the encoders above and Codec._wrap give.
KERNEL_KINDS: dict[type, int] = {  # message type -> its kind in frame_kernel.KINDS
    kind: frame_kernel.KINDS.index(name) for kind, name in (
        (ImuSample, "imu"), (MocapPose, "mocap"), (ExternalPose, "external_pose"), (TruthState, "truth"),
        (ThrustMoment, "thrust_moment"), (AttitudeTarget, "attitude_target"))
}


def _limit_values(limits: ActuatorLimits | None) -> tuple[float, float, float, float] | None:
    """The limits as the compiled encoder takes them (max moments about x, y, z, max thrust), None unless all are
    floats (the Python's arithmetic on other numbers is left to the Python)."""
    if limits is None:
        return None
    values = (*limits.max_moment_nm, limits.max_thrust_n)  # ActuatorLimits holds three moments
    return values if all(type(v) is float for v in values) else None


# ---------------------------------------------------------------------------------------------
# Decoders: values in wire order -> (message, target_system) or None (valid, but not expressible)
# ---------------------------------------------------------------------------------------------


def _thrust_moment_decoder(limits: ActuatorLimits) -> Callable:
    mx, my, mz = limits.max_moment_nm
    max_thrust_n = limits.max_thrust_n

    def decode(v, system_id: int):
        if v[9] != 0:  # control group: only group 0 (flight control) carries thrust and moments
            return None
        # FRD -> FLU inline (frd_to_flu): this runs per frame at 500 Hz-1 kHz
        return ThrustMoment(v[0] / 1e6, v[4] * max_thrust_n, (v[1] * mx, -(v[2] * my), -(v[3] * mz))), v[10]

    return decode


def _attitude_target_decoder(limits: ActuatorLimits) -> Callable:
    max_thrust_n = limits.max_thrust_n

    def decode(v, system_id: int):
        mask = v[11]
        if mask & _ATTITUDE_UNSUPPORTED_MASK:
            return None
        rates = tuple(0.0 if mask & bit else r for r, bit in zip(v[5:8], _ATTITUDE_RATE_IGNORE, strict=True))
        q = quat_ned_frd_to_enu_flu(v[1:5])
        return AttitudeTarget(v[0] / 1e3, v[8] * max_thrust_n, q, frd_to_flu(rates)), v[9]

    return decode


def _dec_position_target(v, system_id: int):
    """Only what we send: local NED, position + velocity + yaw used (anything else is not ours to fly)."""
    if v[15] != mav.MAV_FRAME_LOCAL_NED or v[12] != _POSITION_TYPE_MASK:
        return None
    yaw_enu = math.remainder(math.pi / 2.0 - v[10], 2.0 * math.pi)
    return PositionTarget(v[0] / 1e3, (v[2], v[1], -v[3]), (v[5], v[4], -v[6]), yaw_enu), v[13]


def _dec_imu(v, system_id: int):
    return ImuSample(v[0] / 1e6, (v[1], -v[2], -v[3]), (v[4], -v[5], -v[6])), 0


def _dec_mocap(v, system_id: int):
    """ATT_POS_MOCAP: a mocap system's pose of body `system_id`, or, from the ground station, the receiving
    vehicle's own pose to fuse (ExternalPose)."""
    position, attitude = (v[6], v[5], -v[7]), quat_ned_frd_to_enu_flu(v[1:5])
    if system_id == GROUND_STATION_SYSTEM_ID:
        return ExternalPose(v[0] / 1e6, position, attitude), 0
    return MocapPose(v[0] / 1e6, system_id, position, attitude), 0


_VEHICLE_MODES = frozenset(int(m) for m in VehicleMode)
_FAILSAFE_STATES = (mav.MAV_STATE_CRITICAL, mav.MAV_STATE_EMERGENCY)


def _dec_heartbeat(v, system_id: int):
    custom_mode, kind, _autopilot, base_mode, status, _version = v
    mode_value = custom_mode & 0xFF
    if mode_value not in _VEHICLE_MODES:
        return None
    failsafe = bool(custom_mode & FAILSAFE_MODE_BIT) or status in _FAILSAFE_STATES
    armed = bool(base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED)
    return Heartbeat(armed, VehicleMode(mode_value), failsafe, kind == mav.MAV_TYPE_GCS), 0




def _dec_command(v, system_id: int):
    command = v[7]
    if command == mav.MAV_CMD_NAV_LAND:
        kind = CommandKind.LAND
    elif command == mav.MAV_CMD_COMPONENT_ARM_DISARM and v[0] in (0.0, 1.0):
        kind = CommandKind.ARM if v[0] == 1.0 else CommandKind.DISARM
    elif command == mav.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN and v[0] == 1.0:
        kind = CommandKind.REBOOT
    elif command == mav.MAV_CMD_SET_MESSAGE_INTERVAL and v[0] == W_SERVO.msgid and (v[1] > 0.0 or v[1] == -1.0):
        return MotorOutputsRequest(1e6 / v[1] if v[1] > 0.0 else 0.0), v[8]
    else:
        return None
    return VehicleCommand(v[2], kind), v[8]


def _dec_motor_outputs(v, system_id: int):
    if v[9] != 0:  # port: only the first eight outputs, where the motors are
        return None
    return MotorOutputs(v[0] / 1e6, tuple((pulse - SERVO_PULSE_MIN_US) / SERVO_PULSE_SPAN_US for pulse in v[1:5])), 0


_TOUCHED = frozenset(int(t) for t in Touched)


def _dec_crash(v, system_id: int):
    time_usec, touched, name = v[0], v[1], v[2]
    if name.rstrip(b"\0") != CRASH_ARRAY_NAME or touched not in _TOUCHED:
        return None  # another debug array: not ours to read
    data = v[3:]
    extents = tuple(data[7:13]) if not math.isnan(data[7]) else ()
    return CrashReport(time_usec / 1e6, tuple(data[0:3]), tuple(data[3:6]), Touched(touched), int(data[6]),
                       extents, data[13]), 0


def _dec_timesync(v, system_id: int):
    return TimeSync(v[0], v[1]), 0


def _dec_radio(v, system_id: int):
    rx_errors, fixed, rssi, remote_rssi, txbuf, noise, remote_noise = v
    return RadioStatus(rssi, remote_rssi, txbuf, noise, remote_noise, rx_errors, fixed), 0


def _dec_battery(v, system_id: int):
    voltage = _NAN if v[4] == UINT16_NOT_SENT else v[4] / 1e3
    return BatteryStatus(voltage, v[12], v[8], v[3] * 0.1, v[9]), 0


def _dec_truth(v, system_id: int):
    if v[56] != mav.MAV_FRAME_LOCAL_NED or v[57] != mav.MAV_FRAME_LOCAL_NED:
        return None  # another frame convention: reading it as ours would be silently wrong
    return TruthState(
        v[0] / 1e6, (v[2], v[1], -v[3]), (v[9], v[8], -v[10]), quat_ned_frd_to_enu_flu(v[4:8]),
        (v[11], -v[12], -v[13]),
    ), 0


# ---------------------------------------------------------------------------------------------
# Codec: encoding with sequence numbers and optional signing
# ---------------------------------------------------------------------------------------------


class Codec:
    """Encodes messages into MAVLink 2 frames from one (system id, component id)."""

    def __init__(
        self,
        system_id: int,
        component_id: int = 1,
        limits: ActuatorLimits | None = None,
        signing: Signing | None = None,
    ):
        for name, value in (("system id", system_id), ("component id", component_id)):
            if not 1 <= value <= 255:
                raise ValueError(f"MAVLink {name} {value} out of range 1..255")
        self.system_id = system_id
        self.component_id = component_id
        self.limits = limits
        self.signing = signing
        self._sequence: dict[int, int] = {}  # per source system id (MocapPose frames use the body id)
        # unsigned frames of a tick's messages go through the compiled encoder where it was built (same bytes)
        self._kernel = frame_kernel.encode_frame if signing is None else None
        self._limit_values = _limit_values(limits)

    def __repr__(self) -> str:
        return (f"Codec(system_id={self.system_id}, component_id={self.component_id}, "
                f"limits={self.limits}, signing={self.signing!r})")

    def encode(self, msg: Message, target_system: int = 0) -> bytes:
        """One MAVLink 2 frame carrying `msg`. Raises ValueError for values the wire cannot hold
        (negative or non-finite times, integers out of range, ...) and TypeError for non-messages."""
        kind = type(msg)
        entry = _ENCODERS.get(kind)
        if entry is None:
            raise TypeError(f"cannot encode {kind.__name__}: not a link.messages message")
        encoder, msgid, crc_extra, wire_name = entry
        limits = self.limits
        if limits is None and kind in _NEEDS_LIMITS:
            raise ValueError(f"encoding {kind.__name__} needs ActuatorLimits (Codec(limits=...))")
        source = self.system_id
        if kind is MocapPose:
            source = msg.body_id
            if not 1 <= source <= 255:
                raise ValueError(f"MocapPose.body_id {source} out of range 1..255 (it is the system id)")
        code = KERNEL_KINDS.get(kind) if self._kernel is not None else None
        if code is not None:
            sequence = self._sequence
            seq = sequence.get(source, 0)
            frame = self._kernel(code, msg, seq, source, self.component_id, target_system, self._limit_values)
            if frame is not None:
                sequence[source] = (seq + 1) & 0xFF
                return frame
        try:
            payload = encoder(msg, limits, target_system)
        except (struct.error, ValueError, OverflowError, TypeError) as err:
            raise ValueError(f"{kind.__name__} cannot be encoded as {wire_name}: {err}") from None
        return self._wrap(msgid, crc_extra, payload, source)

    def frame(self, msgid: int, crc_extra: bytes, payload: bytes, source_system: int | None = None) -> bytes:
        """Wrap a packed payload: zero-truncate it, add header and CRC, sign if signing is on."""
        source = self.system_id if source_system is None else source_system
        return self._wrap(msgid, crc_extra, bytes(payload), source)

    def _wrap(self, msgid: int, crc_extra: bytes, payload: bytes, source: int) -> bytes:
        payload = payload.rstrip(b"\x00") or b"\x00"  # MAVLink 2 keeps at least the first byte
        sequence = self._sequence
        seq = sequence.get(source, 0)
        sequence[source] = (seq + 1) & 0xFF
        signing = self.signing
        # the CRC covers the header without its magic byte, the payload and CRC_EXTRA
        checked = _HEADER_AFTER_MAGIC.pack(len(payload), 0 if signing is None else IFLAG_SIGNED, 0, seq, source,
                                           self.component_id, msgid & 0xFFFF, msgid >> 16) + payload
        body = _MAGIC + checked + _CRC.pack(_crc16(checked + crc_extra))
        if signing is not None:
            body += signing.signature_block(body)
        return body


# ---------------------------------------------------------------------------------------------
# Stream parser
# ---------------------------------------------------------------------------------------------


@dataclass(slots=True)
class Decoded:
    """One accepted frame: the message and what its header said. `signed` means signature verified."""

    message: Message
    system_id: int
    component_id: int
    sequence: int
    msgid: int
    signed: bool
    frame: bytes
    target_system: int = 0
    link_id: int | None = None


@dataclass
class ParserCounters:
    frames_ok: int = 0  # delivered
    bytes_in: int = 0  # = garbage_bytes + valid_frame_bytes + bytes still pending
    garbage_bytes: int = 0
    valid_frame_bytes: int = 0  # bytes of CRC-valid frames, delivered or not
    crc_failures: int = 0
    unknown_messages: int = 0  # message id outside the common dialect (cannot be verified)
    unsupported_messages: int = 0  # valid frame the schema has no message for
    bad_headers: int = 0  # unknown incompat flags
    bad_lengths: int = 0  # zero-length payload
    truncated_frames: int = 0  # incomplete frame at the end of a datagram (feed(final=True))
    unsigned_rejected: int = 0
    bad_signatures: int = 0
    replays_rejected: int = 0
    decode_errors: int = 0  # a field the dataclass refused (should stay 0)

    @property
    def signature_failures(self) -> int:
        return self.unsigned_rejected + self.bad_signatures + self.replays_rejected

    @property
    def dropped_frames(self) -> int:
        return (self.crc_failures + self.unknown_messages + self.unsupported_messages + self.bad_headers
                + self.bad_lengths + self.truncated_frames + self.signature_failures + self.decode_errors)

    def as_dict(self) -> dict[str, int]:
        d = {f.name: getattr(self, f.name) for f in fields(self)}
        d["signature_failures"] = self.signature_failures
        return d


class FrameParser:
    """Reassembles and decodes MAVLink 2 frames from byte chunks. `feed` never raises."""

    def __init__(self, codec_or_limits: Codec | ActuatorLimits | None = None, signing: Signing | None = None):
        if isinstance(codec_or_limits, Codec):
            self.limits = codec_or_limits.limits
            self.signing = signing if signing is not None else codec_or_limits.signing
        else:
            self.limits = codec_or_limits
            self.signing = signing
        self.counters = ParserCounters()
        # called (system id, component id, sequence) for each authentic frame that is not delivered
        self.frame_observer: Callable[[int, int, int], None] | None = None
        self._pending = b""
        self._wires = _parser_table(self.limits)
        # frames go through the compiled parser where it was built, unless they are signed (same results)
        self._kernel = frame_kernel.parse_frames if self.signing is None else None

    def _undelivered(self, counter: str, system_id: int, component_id: int, sequence: int) -> None:
        """Count an authentic frame that is not delivered; its sequence number still counts as seen."""
        setattr(self.counters, counter, getattr(self.counters, counter) + 1)
        if self.frame_observer is not None:
            self.frame_observer(system_id, component_id, sequence)

    @property
    def pending_bytes(self) -> int:
        """Bytes of an incomplete frame waiting for the rest."""
        return len(self._pending)

    def reset(self) -> None:
        """Forget any partial frame (e.g. after reconnecting a serial port); its bytes count as garbage."""
        self.counters.garbage_bytes += len(self._pending)
        self._pending = b""

    def feed(self, data: bytes | bytearray | memoryview, final: bool = False) -> list[Decoded]:
        """Decode every complete frame in the bytes so far. `final=True`: `data` ended a datagram, so
        an incomplete frame at its end will never complete (dropped and counted in truncated_frames)."""
        return [Decoded(*fields) for fields in self.feed_fields(data, final)]

    def feed_fields(self, data: bytes | bytearray | memoryview, final: bool = False) -> list[tuple]:
        """feed() without building Decoded records: one tuple of Decoded's fields, in Decoded's order,
        per frame (what Endpoint.deliver uses: it turns each frame into a Received at once)."""
        try:
            return self._feed(data, final)
        except Exception:  # noqa: BLE001 - the parser must never raise; count and start clean
            self.counters.decode_errors += 1
            self.reset()
            return []

    def _feed(self, data, final: bool) -> list[tuple]:
        self.counters.bytes_in += len(data)
        if self._pending:
            buf = self._pending + bytes(data)
            self._pending = b""
        else:
            buf = bytes(data)  # no copy when data is bytes already
        kernel = self._kernel
        out, pos = self._scan(buf, final) if kernel is None else kernel(self, buf, final)
        if pos < len(buf):
            self._pending = buf[pos:]  # an incomplete frame starting with its magic byte
        return out

    def _scan(self, buf: bytes, final: bool) -> tuple[list[tuple], int]:
        """(the fields of each frame in buf, the position scanned to: an incomplete frame starts there). The
        compiled parse_frames (frame_kernel, for a parser without signing) is its twin.

        One loop does framing, CRC and decoding, with no helper calls on the way of a good frame: this
        runs per frame at 500 Hz-1 kHz, and on the link's round trip right after a wake-up, where every
        operation costs several times its hot-loop time (the caches are cold; see cfstack.link_bench)."""
        c = self.counters
        wires = self._wires
        out: list = []
        n = len(buf)
        pos = 0
        while pos < n:
            if buf[pos] == MAGIC_V2:  # the usual case (a datagram, or right after a frame): no search
                i = pos
            else:
                i = buf.find(_MAGIC, pos)
                if i < 0:
                    c.garbage_bytes += n - pos
                    return out, n
                c.garbage_bytes += i - pos
                pos = i
            if n - i < MIN_FRAME_LEN:
                end = n + 1  # unknown until the length byte has arrived
            else:
                plen, flags, _, sequence, system_id, component_id, msgid_lo, msgid_hi = \
                    _HEADER_AFTER_MAGIC.unpack_from(buf, i + 1)
                end = i + MIN_FRAME_LEN + plen + (SIGNATURE_BLOCK_LEN if flags & IFLAG_SIGNED else 0)
            if end > n:  # incomplete: wait for more bytes, unless this was a whole datagram
                if not final:
                    break
                c.truncated_frames += 1
                c.garbage_bytes += 1
                pos = i + 1
                continue
            msgid = msgid_lo | (msgid_hi << 16)
            wire = wires.get(msgid)
            if wire is None:  # outside the dialect: no CRC_EXTRA, so the frame cannot be verified
                c.unknown_messages += 1
                c.garbage_bytes += 1
                pos = i + 1
                continue
            crc_extra, unpacker, size, decoder = wire
            crc_at = i + HEADER_LEN + plen
            checked = buf[i + 1:crc_at]  # header without the magic byte, then the payload
            if _crc16(checked + crc_extra) != buf[crc_at] | (buf[crc_at + 1] << 8):
                c.crc_failures += 1
                c.garbage_bytes += 1
                pos = i + 1
                continue
            pos = end  # a genuine frame: whatever happens next, skip it whole
            c.valid_frame_bytes += end - i
            if flags & ~IFLAG_SIGNED:
                c.bad_headers += 1
                continue
            frame = buf if end == n and i == 0 else buf[i:end]
            signed = False
            link_id = None
            if self.signing is not None:
                link_id = self._signature_link_id(frame, flags, msgid, system_id, component_id)
                if link_id == _REJECTED:
                    continue
                signed = link_id is not None
            if decoder is None:
                self._undelivered("unsupported_messages", system_id, component_id, sequence)
                continue
            if plen == 0:
                self._undelivered("bad_lengths", system_id, component_id, sequence)
                continue
            try:
                # a zero-truncated payload reads as zero-extended (MAVLink 2); longer ones: the known part
                result = decoder(unpacker.unpack_from(buf, i + HEADER_LEN) if plen >= size
                                 else unpacker.unpack_from(checked + _ZEROS, HEADER_LEN - 1), system_id)
            except (ValueError, TypeError, OverflowError):
                self._undelivered("decode_errors", system_id, component_id, sequence)
                continue
            if result is None:
                self._undelivered("unsupported_messages", system_id, component_id, sequence)
                continue
            c.frames_ok += 1
            message, target = result
            out.append((message, system_id, component_id, sequence, msgid, signed, frame, target, link_id))
        return out, pos

    def _signature_link_id(self, frame: bytes, flags: int, msgid: int, system_id: int,
                           component_id: int) -> int | None:
        """With signing on: the link id of a frame whose signature checks out, None for an unsigned
        frame of an allowed message id, _REJECTED (counted) for anything else."""
        c = self.counters
        if flags & IFLAG_SIGNED:
            verdict = self.signing.check(frame, system_id, component_id)
            if verdict is SignatureCheck.OK:
                return frame[-13]
            if verdict is SignatureCheck.REPLAY:
                c.replays_rejected += 1
            else:
                c.bad_signatures += 1
            return _REJECTED
        if msgid in self.signing.allow_unsigned_msgids:
            return None
        c.unsigned_rejected += 1
        return _REJECTED

def _parser_table(limits: ActuatorLimits | None) -> dict[int, tuple]:
    """msgid -> (crc_extra, struct, struct size, decoder(values, system id) -> (message, target) or None)
    for every message of the common dialect; struct and decoder are None for those the schema cannot
    express (and for thrust/attitude setpoints without limits: they cannot be de-normalised)."""
    decoders = {
        W_IMU: _dec_imu,
        W_HEARTBEAT: _dec_heartbeat,
        W_COMMAND: _dec_command,
        W_TIMESYNC: _dec_timesync,
        W_RADIO: _dec_radio,
        W_SYS_STATUS: _dec_battery,
        W_ODOMETRY: _dec_truth,
        W_DEBUG_ARRAY: _dec_crash,
        W_MOCAP: _dec_mocap,
        W_POSITION: _dec_position_target,
        W_SERVO: _dec_motor_outputs,
    }
    if limits is not None:
        decoders[W_ACTUATOR] = _thrust_moment_decoder(limits)
        decoders[W_ATTITUDE] = _attitude_target_decoder(limits)
    table: dict[int, tuple] = {msgid: (crc_extra, None, 0, None) for msgid, crc_extra in _CRC_EXTRA.items()}
    for wire, decoder in decoders.items():
        table[wire.msgid] = (wire.crc_extra, wire.unpacker, wire.size, decoder)
    return table


def direct_fields(cls: type) -> tuple[str, ...] | None:
    """The field names, in order, of a message class whose generated __init__ does nothing but set them (a frozen
    dataclass: object.__setattr__ of each field, in order; no __post_init__, no InitVar, no field left out of
    __init__), so the frame kernel may make its instances that way itself; None: the kernel calls the class."""
    if not is_dataclass(cls) or not cls.__dataclass_params__.frozen or hasattr(cls, "__post_init__"):
        return None
    declared = fields(cls)
    names = tuple(f.name for f in declared)
    if not all(f.init for f in declared) or tuple(inspect.signature(cls).parameters) != names:
        return None
    return names


# The compiled twins (link.mavlink.frame_kernel) take this module's constants and decoders once
if frame_kernel.COMPILED:
    frame_kernel.configure(
        _SQRT_HALF,
        (W_IMU.msgid, W_IMU.crc_extra[0], b"", _IMU_FIELDS_UPDATED),
        (W_MOCAP.msgid, W_MOCAP.crc_extra[0], _MOCAP_COVARIANCE_TAIL, 0),
        (W_ODOMETRY.msgid, W_ODOMETRY.crc_extra[0], _ODOMETRY_TRUTH_TAIL, 0),
        (W_ACTUATOR.msgid, W_ACTUATOR.crc_extra[0], b"", 0),
        (W_ATTITUDE.msgid, W_ATTITUDE.crc_extra[0], b"", 0),
    )
    frame_kernel.configure_parser(_dec_imu, _dec_mocap, _dec_truth, ImuSample, MocapPose, ExternalPose, TruthState,
                                  GROUND_STATION_SYSTEM_ID, mav.MAV_FRAME_LOCAL_NED,
                                  *(direct_fields(m) for m in (ImuSample, MocapPose, ExternalPose, TruthState)))


# ---------------------------------------------------------------------------------------------
# Cost measurement (used by `cfstack link-bench`)
# ---------------------------------------------------------------------------------------------


def sample_messages() -> list[Message]:
    """One typical message of every kind (values of a hovering Crazyflie-class vehicle)."""
    q = (math.cos(0.15), 0.0, 0.0, math.sin(0.15))
    return [
        ThrustMoment(12.345678, 0.265, (1.0e-4, -2.0e-4, 3.0e-5)),
        AttitudeTarget(12.345, 0.265, q, (0.1, -0.2, 0.05)),
        ImuSample(12.345678, (0.02, -0.01, 9.81), (0.001, -0.002, 0.003)),
        MocapPose(12.345678, 7, (1.0, 2.0, 0.5), q),
        PositionTarget(12.345, (1.0, 2.0, 0.5), (0.1, 0.2, 0.0), 0.3),
        Heartbeat(True, VehicleMode.ATTITUDE),
        VehicleCommand(12.345, CommandKind.ARM),
        TimeSync(0, 12_345_678_901),
        RadioStatus(200, 190, 100, 30, 31, 2, 1),
        BatteryStatus(3.85, 80, 0, 12.5),
        TruthState(12.345678, (1.0, 2.0, 0.5), (0.1, 0.2, -0.1), q, (0.01, 0.02, 0.03)),
    ]


def _medians_us(calls: list[tuple[Callable, list]], batch: int = 10) -> list[float]:
    """For each (fn, args): the median over batches of `batch` calls of the cost of one call fn(arg), in
    microseconds. The functions take turns, batch by batch, so that the machine's drift falls on all alike."""
    timer = time.perf_counter
    samples: list[list[float]] = [[] for _ in calls]
    for start in range(0, min(len(args) for _, args in calls) - batch + 1, batch):
        for (fn, args), times in zip(calls, samples, strict=True):
            chunk = args[start:start + batch]
            t0 = timer()
            for arg in chunk:
                fn(arg)
            times.append((timer() - t0) / batch * 1e6)
    return [statistics.median(times) for times in samples]


def _decode_datagram(parser: FrameParser) -> Callable[[bytes], list[Decoded]]:
    return lambda frame: parser.feed(frame, True)


def measure_codec_costs(n: int = 2000, signing: bool = False,
                        python_twin: bool = False) -> dict[str, tuple[float, ...]]:
    """Median (encode_us, decode_us) per message type: encode = Codec.encode, decode = FrameParser.feed
    of one whole frame (a datagram). With `signing`, frames are signed and checked (throwaway key). With
    `python_twin` (unsigned, where the compiled twins of link.mavlink.frame_kernel were built), also those of the
    Python twins, the two timed in turns: (encode_us, decode_us, python_encode_us, python_decode_us)."""
    if signing and python_twin:
        raise ValueError("measure_codec_costs: the Python twins are timed unsigned (the compiled ones take no signing)")
    limits = ActuatorLimits(0.6, (0.01, 0.01, 0.002))
    key = bytes(range(32))
    n = max(n, 10)
    results: dict[str, tuple[float, ...]] = {}
    for msg in sample_messages():
        codecs = [Codec(1, 1, limits, Signing(key, 0) if signing else None)]
        parsers = [FrameParser(limits, Signing(key, 0) if signing else None)]
        if python_twin:
            codecs.append(Codec(1, 1, limits))
            parsers.append(FrameParser(limits))
            codecs[1]._kernel = parsers[1]._kernel = None
        encode_us = _medians_us([(codec.encode, [msg] * n) for codec in codecs])
        frames = [codecs[0].encode(msg) for _ in range(n)]  # fresh timestamps: no replay rejections
        decode_us = _medians_us([(_decode_datagram(parser), frames) for parser in parsers])
        for parser in parsers:
            if parser.counters.frames_ok != n:
                raise RuntimeError(f"measure_codec_costs: {type(msg).__name__}: {parser.counters.as_dict()}")
        results[type(msg).__name__] = tuple(v for pair in zip(encode_us, decode_us, strict=True) for v in pair)
    return results


__all__ = [
    "ActuatorLimits", "Codec", "Decoded", "FrameParser", "ParserCounters", "measure_codec_costs",
    "sample_messages", "enu_to_ned", "ned_to_enu", "flu_to_frd", "frd_to_flu",
    "quat_enu_flu_to_ned_frd", "quat_ned_frd_to_enu_flu",
]
