"""The message schema of cfstack: plain dataclasses, one per kind of message.

Takes in / gives out: nothing by itself; every package sends and receives these.
Frames: world ENU (x east, y north, z up), body FLU (x forward, y left, z up). Units: SI.
Quaternions are (w, x, y, z) and rotate body FLU vectors into world ENU.
Times `time_s` are seconds on the sender's clock (the vehicle's boot clock for downlink,
the ground station's clock for uplink; in lockstep both are simulation time).
MAVLink's NED/FRD conventions exist only inside link.mavlink.codec.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum

from model.frames import Quat, Vec3


@dataclass(frozen=True)
class ThrustMoment:
    """Collective thrust and body moments (wire: SET_ACTUATOR_CONTROL_TARGET, normalised)."""

    time_s: float
    thrust_n: float
    moment_flu_nm: Vec3


@dataclass(frozen=True)
class AttitudeTarget:
    """Collective thrust, desired attitude and body rates (wire: SET_ATTITUDE_TARGET)."""

    time_s: float
    thrust_n: float
    attitude_wxyz: Quat
    rates_flu_radps: Vec3 = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class ImuSample:
    """Specific force and angular rate in the body frame (wire: HIGHRES_IMU)."""

    time_s: float
    specific_force_flu_mps2: Vec3
    rate_flu_radps: Vec3


@dataclass(frozen=True)
class MocapPose:
    """A motion-capture pose of one body (wire: ATT_POS_MOCAP). `time_s` is the sample time."""

    time_s: float
    body_id: int
    position_enu_m: Vec3
    attitude_wxyz: Quat


class VehicleMode(IntEnum):
    """What the vehicle's onboard commander is doing (wire: HEARTBEAT custom_mode)."""

    IDLE = 0  # disarmed, motors off
    MOMENTS = 1  # following thrust + moment setpoints
    ATTITUDE = 2  # onboard attitude loop following thrust + attitude setpoints
    LEVEL = 3  # watchdog: no setpoint for a while, holding level attitude
    LANDING = 4  # executing a land command
    CRASHED = 5  # flight ended by a collision or leaving the bounds


@dataclass(frozen=True)
class Heartbeat:
    """Liveness and state of a sender (wire: HEARTBEAT). MAVLink heartbeats carry no time."""

    armed: bool
    mode: VehicleMode = VehicleMode.IDLE
    failsafe: bool = False
    is_ground_station: bool = False


class CommandKind(IntEnum):
    ARM = 1
    DISARM = 2
    LAND = 3


@dataclass(frozen=True)
class VehicleCommand:
    """Arm, disarm or land (wire: COMMAND_LONG). `time_s` is the issue time."""

    time_s: float
    kind: CommandKind


@dataclass(frozen=True)
class TimeSync:
    """TIMESYNC request (`remote_ns == 0`) or reply. Nanoseconds, as MAVLink defines it."""

    remote_ns: int  # tc1: the responder's clock (0 in a request)
    origin_ns: int  # ts1: the requester's clock when it sent the request


@dataclass(frozen=True)
class RadioStatus:
    """What the radio channel did (wire: RADIO_STATUS)."""

    rssi: int
    remote_rssi: int
    tx_buffer_pct: int
    noise: int
    remote_noise: int
    rx_errors: int
    fixed: int


@dataclass(frozen=True)
class BatteryStatus:
    """Battery and onboard counters (wire: SYS_STATUS)."""

    voltage_v: float
    remaining_pct: int
    rejected_commands: int = 0
    load_pct: float = 0.0
    uplink_received: int = 0  # uplink messages the vehicle has received (wire: errors_count2, mod 65536)


@dataclass(frozen=True)
class TruthState:
    """Simulation-only ground truth (wire: ODOMETRY, published only on the truth key).

    Never used for control: logs and grading only.
    """

    time_s: float
    position_enu_m: Vec3
    velocity_enu_mps: Vec3
    attitude_wxyz: Quat
    rate_flu_radps: Vec3


Message = (
    ThrustMoment
    | AttitudeTarget
    | ImuSample
    | MocapPose
    | Heartbeat
    | VehicleCommand
    | TimeSync
    | RadioStatus
    | BatteryStatus
    | TruthState
)


@dataclass(frozen=True)
class Received:
    """A decoded message and what the link knows about the frame that carried it."""

    message: Message
    system_id: int
    sequence: int
    received_s: float
    signed: bool = False
    extra: dict = field(default_factory=dict)
