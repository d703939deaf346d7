"""link.mavlink.codec: frame conventions, MAVLink field semantics (checked with pymavlink's own decoder),
round trips of every field of every message, interoperability with pymavlink, parser drop rules."""

from __future__ import annotations

import dataclasses
import math
import struct

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mav
from scipy.spatial.transform import Rotation

from link.mavlink.codec import (
    ODOMETRY_QUALITY_TRUTH,
    Q_FLU_FROM_FRD,
    Q_NED_FROM_ENU,
    ActuatorLimits,
    Codec,
    Decoded,
    FrameParser,
    enu_to_ned,
    flu_to_frd,
    measure_codec_costs,
    quat_enu_flu_to_ned_frd,
    quat_ned_frd_to_enu_flu,
    sample_messages,
)
from link.mavlink.signing import Signing
from link.messages import (
    AttitudeTarget,
    BatteryStatus,
    CommandKind,
    ExternalPose,
    Heartbeat,
    ImuSample,
    MocapPose,
    MotorOutputs,
    MotorOutputsRequest,
    RadioStatus,
    ThrustMoment,
    TimeSync,
    TruthState,
    VehicleCommand,
    VehicleMode,
)
from model.frames import quat_multiply
from model.vehicle import GRAVITY_MPS2, load_vehicle

LIMITS = ActuatorLimits(0.6, (0.01, 0.012, 0.002))
# Independent statements of the frame changes, as matrices (column = where each source axis goes)
M_NED_FROM_ENU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
M_FLU_FROM_FRD = np.diag([1.0, -1.0, -1.0])


def rot(q_wxyz) -> Rotation:
    w, x, y, z = q_wxyz
    return Rotation.from_quat([x, y, z, w])


def wxyz(r: Rotation) -> tuple[float, float, float, float]:
    x, y, z, w = r.as_quat()
    return (float(w), float(x), float(y), float(z))


def pymav_decode(frame: bytes):
    """pymavlink's own reading of one of our frames (raises if pymavlink rejects it)."""
    return mav.MAVLink(None).decode(bytearray(frame))


def roundtrip(msg, codec: Codec | None = None, target_system: int = 0):
    codec = codec or Codec(7, 1, LIMITS)
    frame = codec.encode(msg, target_system)
    parser = FrameParser(codec)
    out = parser.feed(frame)
    assert len(out) == 1, parser.counters
    assert out[0].frame == frame
    return out[0]


def f32(x: float) -> float:
    return struct.unpack("<f", struct.pack("<f", x))[0]


def assert_same_rotation(q1, q2, tol=1e-6):
    # |<q1, q2>| = 1 iff same rotation (q and -q are the same)
    assert abs(abs(float(np.dot(q1, q2))) - 1.0) < tol, (q1, q2)


# -- frame conventions -----------------------------------------------------------------------------


def test_vector_frame_changes_match_the_axis_definitions():
    east, north, up = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)
    assert enu_to_ned(east) == (0.0, 1.0, -0.0)  # east is NED's y
    assert enu_to_ned(north) == (1.0, 0.0, -0.0)  # north is NED's x
    assert enu_to_ned(up) == (0.0, 0.0, -1.0)  # up is -down
    assert flu_to_frd((0.0, 1.0, 0.0)) == (0.0, -1.0, -0.0)  # left is -right
    v = (0.3, -1.2, 2.5)
    assert enu_to_ned(enu_to_ned(v)) == v and flu_to_frd(flu_to_frd(v)) == v


ROTATIONS = {
    "identity": Rotation.identity(),
    "yaw 30": Rotation.from_euler("z", 30, degrees=True),
    "roll 20": Rotation.from_euler("x", 20, degrees=True),
    "pitch -15": Rotation.from_euler("y", -15, degrees=True),
    "arbitrary": Rotation.from_euler("ZYX", [123.0, -37.0, 71.0], degrees=True),
    "random": Rotation.random(random_state=np.random.default_rng(4)),
}


@pytest.mark.parametrize("name", sorted(ROTATIONS))
def test_quaternion_conversion_is_the_matrix_product(name):
    r_enu_flu = ROTATIONS[name]
    q_ned = quat_enu_flu_to_ned_frd(wxyz(r_enu_flu))
    expected = M_NED_FROM_ENU @ r_enu_flu.as_matrix() @ M_FLU_FROM_FRD
    np.testing.assert_allclose(rot(q_ned).as_matrix(), expected, atol=1e-12)
    np.testing.assert_allclose(quat_ned_frd_to_enu_flu(q_ned), wxyz(r_enu_flu), atol=1e-12)  # sign too


@pytest.mark.parametrize("name", sorted(ROTATIONS))
def test_quaternion_conversion_is_the_two_quaternion_products(name):
    q = wxyz(ROTATIONS[name])
    product = quat_multiply(quat_multiply(Q_NED_FROM_ENU, q), Q_FLU_FROM_FRD)
    np.testing.assert_allclose(quat_enu_flu_to_ned_frd(q), [-v for v in product], atol=1e-15)


@pytest.mark.parametrize("name", sorted(ROTATIONS))
def test_body_vectors_point_the_same_physical_way(name):
    r_enu_flu = ROTATIONS[name]
    r_ned_frd = rot(quat_enu_flu_to_ned_frd(wxyz(r_enu_flu)))
    for body_flu in ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.3, -0.4, 0.8)):
        world_enu = r_enu_flu.apply(body_flu)
        world_ned = r_ned_frd.apply(flu_to_frd(body_flu))
        np.testing.assert_allclose(world_ned, enu_to_ned(world_enu), atol=1e-12)


def test_nose_north_is_ned_yaw_zero_and_nose_east_is_ned_yaw_90():
    north = quat_enu_flu_to_ned_frd(wxyz(Rotation.from_euler("z", 90, degrees=True)))
    assert_same_rotation(north, (1.0, 0.0, 0.0, 0.0))
    east = quat_enu_flu_to_ned_frd((1.0, 0.0, 0.0, 0.0))
    yaw, pitch, roll = rot(east).as_euler("ZYX", degrees=True)
    assert (yaw, pitch, roll) == pytest.approx((90.0, 0.0, 0.0), abs=1e-9)


def test_roll_keeps_its_sign_and_pitch_flips_between_flu_and_frd():
    # FLU roll +20 deg (about forward, left side up) is FRD roll +20 deg (right side down): same motion
    q = quat_enu_flu_to_ned_frd(wxyz(Rotation.from_euler("ZYX", [90, 0, 20], degrees=True)))
    yaw, pitch, roll = rot(q).as_euler("ZYX", degrees=True)
    assert (yaw, pitch, roll) == pytest.approx((0.0, 0.0, 20.0), abs=1e-9)
    # FLU pitch +10 deg about the left axis pushes the nose down, which FRD calls pitch -10 deg
    q = quat_enu_flu_to_ned_frd(wxyz(Rotation.from_euler("ZYX", [90, 10, 0], degrees=True)))
    yaw, pitch, roll = rot(q).as_euler("ZYX", degrees=True)
    assert (yaw, pitch, roll) == pytest.approx((0.0, -10.0, 0.0), abs=1e-9)


# -- what the MAVLink fields mean (read back by pymavlink) ------------------------------------------


def test_imu_at_rest_reads_minus_g_on_frd_z():
    msg = pymav_decode(Codec(1).encode(ImuSample(1.5, (0.0, 0.0, GRAVITY_MPS2), (0.1, 0.2, 0.3))))
    assert msg.get_type() == "HIGHRES_IMU"
    assert (msg.xacc, msg.yacc, msg.zacc) == pytest.approx((0.0, 0.0, -GRAVITY_MPS2), rel=1e-6)
    assert (msg.xgyro, msg.ygyro, msg.zgyro) == pytest.approx((0.1, -0.2, -0.3), rel=1e-6)
    assert msg.time_usec == 1_500_000
    assert msg.fields_updated & 0b111111 == 0b111111


def test_actuator_controls_are_normalised_frd_moments_and_thrust():
    vehicle = load_vehicle("crazyflie")
    limits = ActuatorLimits.from_vehicle(vehicle)
    mx, my, mz = vehicle.max_moment_nm
    hover = ThrustMoment(2.0, vehicle.weight_n, (mx, my / 2, -mz / 4))
    msg = pymav_decode(Codec(1, 1, limits).encode(hover, target_system=9))
    assert msg.get_type() == "SET_ACTUATOR_CONTROL_TARGET"
    assert msg.controls[3] == pytest.approx(1.0 / vehicle.thrust_to_weight, rel=1e-6)
    assert msg.controls[:3] == pytest.approx([1.0, -0.5, 0.25], rel=1e-6)  # y and z flip to FRD
    assert msg.group_mlx == 0 and msg.target_system == 9 and msg.time_usec == 2_000_000


def test_limits_come_from_the_vehicle_and_reject_nonsense():
    vehicle = load_vehicle("cf2x")
    limits = ActuatorLimits.from_vehicle(vehicle)
    assert limits.max_thrust_n == pytest.approx(vehicle.max_thrust_n)
    assert limits.max_moment_nm == pytest.approx(tuple(vehicle.max_moment_nm))
    for bad in ((0.0, (1, 1, 1)), (1.0, (1, -1, 1)), (math.nan, (1, 1, 1)), (1.0, (1, 1))):
        with pytest.raises(ValueError):
            ActuatorLimits(*bad)


def test_attitude_target_fields():
    q_enu = wxyz(Rotation.from_euler("ZYX", [90, 0, 0], degrees=True))  # nose north
    frame = Codec(1, 1, LIMITS).encode(AttitudeTarget(3.0015, 0.3, q_enu, (0.1, 0.2, 0.3)), 4)
    msg = pymav_decode(frame)
    assert_same_rotation(msg.q, (1.0, 0.0, 0.0, 0.0), tol=1e-6)
    assert msg.thrust == pytest.approx(0.5)
    assert (msg.body_roll_rate, msg.body_pitch_rate, msg.body_yaw_rate) == pytest.approx((0.1, -0.2, -0.3))
    assert msg.time_boot_ms == 3002 and msg.type_mask == 0 and msg.target_system == 4  # ms resolution


def test_mocap_pose_fields_and_body_id_in_the_header():
    frame = Codec(254, 3).encode(MocapPose(0.25, 42, (1.0, 2.0, 3.0), (1.0, 0.0, 0.0, 0.0)))
    msg = pymav_decode(frame)
    assert msg.get_type() == "ATT_POS_MOCAP"
    assert (msg.x, msg.y, msg.z) == (2.0, 1.0, -3.0)
    assert msg.get_srcSystem() == 42 and msg.get_srcComponent() == 3
    assert math.isnan(msg.covariance[0])  # "unknown" per the MAVLink definition
    decoded = roundtrip(MocapPose(0.25, 42, (1.0, 2.0, 3.0), (1.0, 0.0, 0.0, 0.0)))
    assert decoded.system_id == 42 and decoded.message.body_id == 42


def test_an_external_pose_goes_from_the_ground_station_and_comes_back_as_one():
    q = (math.cos(0.2), 0.0, 0.0, math.sin(0.2))  # yaw 0.4 rad
    frame = Codec(255).encode(ExternalPose(1.25, (1.0, 2.0, 3.0), q), target_system=7)
    msg = pymav_decode(frame)
    # ATT_POS_MOCAP from the ground station's system id (the vehicle told apart by the link it goes on)
    assert msg.get_type() == "ATT_POS_MOCAP" and msg.get_srcSystem() == 255
    assert (msg.x, msg.y, msg.z) == (2.0, 1.0, -3.0) and msg.time_usec == 1_250_000
    decoded = FrameParser(Codec(1)).feed(frame, True)[0].message
    assert isinstance(decoded, ExternalPose) and decoded.position_enu_m == (1.0, 2.0, 3.0)
    assert decoded.attitude_wxyz == pytest.approx(q, abs=1e-6)
    # the same message from a mocap system (any other source id) stays a MocapPose of that body
    mocap = FrameParser(Codec(1)).feed(Codec(254).encode(MocapPose(1.25, 7, (1.0, 2.0, 3.0), q)), True)[0]
    assert isinstance(mocap.message, MocapPose) and mocap.message.body_id == 7


def test_each_mocap_body_has_its_own_sequence():
    codec = Codec(254)
    seqs = [pymav_decode(codec.encode(MocapPose(0.0, body, (0, 0, 0), (1, 0, 0, 0)))).get_seq()
            for body in (1, 2, 1, 2, 1)]
    assert seqs == [0, 0, 1, 1, 2]


@pytest.mark.parametrize("armed", [False, True])
@pytest.mark.parametrize("failsafe", [False, True])
@pytest.mark.parametrize("mode", list(VehicleMode))
def test_heartbeat_flags(armed, failsafe, mode):
    hb = Heartbeat(armed, mode, failsafe, is_ground_station=False)
    msg = pymav_decode(Codec(1).encode(hb))
    assert bool(msg.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED) == armed
    assert msg.custom_mode & 0xFF == int(mode)
    assert msg.type == mav.MAV_TYPE_QUADROTOR
    if mode is VehicleMode.CRASHED:
        assert msg.system_status == mav.MAV_STATE_FLIGHT_TERMINATION
    elif failsafe:
        assert msg.system_status == mav.MAV_STATE_CRITICAL
    else:
        assert msg.system_status in (mav.MAV_STATE_ACTIVE, mav.MAV_STATE_STANDBY)
    assert roundtrip(hb).message == hb


def test_ground_station_heartbeat():
    hb = Heartbeat(False, is_ground_station=True)
    assert pymav_decode(Codec(255).encode(hb)).type == mav.MAV_TYPE_GCS
    assert roundtrip(hb, Codec(255)).message == hb


def test_foreign_heartbeat_with_critical_status_is_failsafe():
    m = mav.MAVLink(None, 3, 1)
    frame = m.heartbeat_encode(mav.MAV_TYPE_QUADROTOR, 0, 0, 2, mav.MAV_STATE_EMERGENCY, 3).pack(m)
    (decoded,) = FrameParser().feed(frame)
    assert decoded.message == Heartbeat(False, VehicleMode.ATTITUDE, True, False)


@pytest.mark.parametrize("kind,command,param1", [
    (CommandKind.ARM, mav.MAV_CMD_COMPONENT_ARM_DISARM, 1.0),
    (CommandKind.DISARM, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0.0),
    (CommandKind.LAND, mav.MAV_CMD_NAV_LAND, 0.0),
])
def test_commands(kind, command, param1):
    cmd = VehicleCommand(12.5, kind)
    msg = pymav_decode(Codec(255).encode(cmd, target_system=3))
    assert (msg.command, msg.param1, msg.target_system) == (command, param1, 3)
    assert msg.param3 == 12.5  # issue time in the unused param3
    decoded = roundtrip(cmd, Codec(255), target_system=3)
    assert decoded.message == cmd and decoded.target_system == 3


def test_motor_outputs_are_servo_output_raw_pulses_of_one_to_two_milliseconds():
    """Duty 0..1 is the ESC pulse range 1000..2000 us (MAVLink's servoN_raw unit), port 0, motors on 1..4."""
    outputs = MotorOutputs(2.5, (0.0, 0.25, 0.5, 1.0))
    msg = pymav_decode(Codec(1).encode(outputs))
    assert msg.get_type() == "SERVO_OUTPUT_RAW" and msg.port == 0 and msg.time_usec == 2_500_000
    pulses = (msg.servo1_raw, msg.servo2_raw, msg.servo3_raw, msg.servo4_raw, msg.servo5_raw)
    assert pulses == (1000, 1250, 1500, 2000, 0)
    assert roundtrip(outputs).message == outputs
    m = mav.MAVLink(None, 1, 1)
    other_port = m.servo_output_raw_encode(0, 1, 1500, 1500, 1500, 1500, 0, 0, 0, 0).pack(m)
    assert FrameParser().feed(other_port) == []  # outputs 9..16 are not the motors


@pytest.mark.parametrize("rate_hz, interval_us", [(10.0, 100_000.0), (0.0, -1.0)])
def test_motor_outputs_request_is_set_message_interval_for_servo_output_raw(rate_hz, interval_us):
    request = MotorOutputsRequest(rate_hz)
    msg = pymav_decode(Codec(255).encode(request, target_system=3))
    assert (msg.command, msg.param1, msg.param2, msg.target_system) == (
        mav.MAV_CMD_SET_MESSAGE_INTERVAL, mav.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW, interval_us, 3)
    decoded = roundtrip(request, Codec(255), target_system=3)
    assert decoded.message == request and decoded.target_system == 3
    m = mav.MAVLink(None, 255, 1)
    other = m.command_long_encode(3, 1, mav.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                  mav.MAVLINK_MSG_ID_ATTITUDE, 1e5, 0, 0, 0, 0, 0).pack(m)
    assert FrameParser().feed(other) == []  # another message's interval: not ours to answer


def test_other_commands_are_counted_not_delivered():
    m = mav.MAVLink(None, 255, 1)
    parser = FrameParser()
    frame = m.command_long_encode(1, 1, mav.MAV_CMD_DO_SET_MODE, 0, 1, 0, 0, 0, 0, 0, 0).pack(m)
    assert parser.feed(frame) == [] and parser.counters.unsupported_messages == 1


def test_timesync_radio_and_battery_fields():
    msg = pymav_decode(Codec(1).encode(TimeSync(-5, 2**62)))
    assert (msg.tc1, msg.ts1) == (-5, 2**62)
    radio = RadioStatus(rssi=255, remote_rssi=0, tx_buffer_pct=100, noise=7, remote_noise=8, rx_errors=65535,
                        fixed=12)
    msg = pymav_decode(Codec(1).encode(radio))
    assert (msg.rssi, msg.remrssi, msg.txbuf, msg.noise, msg.remnoise, msg.rxerrors, msg.fixed) == (
        255, 0, 100, 7, 8, 65535, 12)
    msg = pymav_decode(Codec(1).encode(BatteryStatus(3.7, 55, 4, 12.3)))
    assert (msg.voltage_battery, msg.battery_remaining, msg.errors_count1, msg.load) == (3700, 55, 4, 123)
    assert msg.current_battery == -1
    unknown = roundtrip(BatteryStatus(math.nan, -1)).message
    assert math.isnan(unknown.voltage_v) and unknown.remaining_pct == -1
    assert pymav_decode(Codec(1).encode(BatteryStatus(math.nan, -1))).voltage_battery == 65535


def test_truth_state_is_odometry_in_local_ned():
    truth = TruthState(4.0, (1.0, 2.0, 3.0), (0.5, -0.25, 1.0), (1.0, 0.0, 0.0, 0.0), (0.1, 0.2, 0.3))
    msg = pymav_decode(Codec(1).encode(truth))
    assert (msg.frame_id, msg.child_frame_id) == (mav.MAV_FRAME_LOCAL_NED, mav.MAV_FRAME_LOCAL_NED)
    assert (msg.x, msg.y, msg.z) == (2.0, 1.0, -3.0)
    assert (msg.vx, msg.vy, msg.vz) == (-0.25, 0.5, -1.0)
    assert (msg.rollspeed, msg.pitchspeed, msg.yawspeed) == pytest.approx((0.1, -0.2, -0.3))
    assert msg.time_usec == 4_000_000
    # the fields every truth frame shares (packed once in the codec), as pymavlink reads them
    assert math.isnan(msg.pose_covariance[0]) and math.isnan(msg.velocity_covariance[0])
    assert list(msg.pose_covariance[1:]) == [0.0] * 20 and list(msg.velocity_covariance[1:]) == [0.0] * 20
    assert (msg.reset_counter, msg.estimator_type) == (0, mav.MAV_ESTIMATOR_TYPE_UNKNOWN)
    assert msg.quality == ODOMETRY_QUALITY_TRUTH


# -- round trips -----------------------------------------------------------------------------------


def assert_close_f32(a, b):
    a, b = np.atleast_1d(np.asarray(a, float)), np.atleast_1d(np.asarray(b, float))
    np.testing.assert_allclose(a, b, rtol=2**-23, atol=1e-30)


def random_quat(rng):
    return wxyz(Rotation.random(random_state=rng))


@pytest.mark.parametrize("seed", range(5))
def test_every_field_of_every_message_survives(seed):
    rng = np.random.default_rng(seed)
    vec = lambda scale=10.0: tuple(float(x) for x in rng.uniform(-scale, scale, 3))  # noqa: E731
    t = float(rng.uniform(0, 1e5))
    codec = Codec(int(rng.integers(1, 256)), int(rng.integers(1, 256)), LIMITS)

    tm = ThrustMoment(t, float(rng.uniform(0, 0.6)), vec(0.01))
    d = roundtrip(tm, codec).message
    assert abs(d.time_s - t) <= 0.5e-6
    # float32 of the normalised value, scaled back: relative float32 precision
    assert_close_f32(d.thrust_n, f32(tm.thrust_n / 0.6) * 0.6)
    assert_close_f32(d.moment_flu_nm, tm.moment_flu_nm)

    at = AttitudeTarget(t, 0.3, random_quat(rng), vec(5.0))
    d = roundtrip(at, codec).message
    assert abs(d.time_s - t) <= 0.5e-3
    assert_same_rotation(d.attitude_wxyz, at.attitude_wxyz, tol=1e-6)
    assert_close_f32(d.rates_flu_radps, at.rates_flu_radps)
    assert d.thrust_n == pytest.approx(0.3, rel=1e-7)

    imu = ImuSample(t, vec(50.0), vec(30.0))
    d = roundtrip(imu, codec).message
    assert abs(d.time_s - t) <= 0.5e-6
    assert_close_f32(d.specific_force_flu_mps2, imu.specific_force_flu_mps2)
    assert_close_f32(d.rate_flu_radps, imu.rate_flu_radps)

    pose = MocapPose(t, int(rng.integers(1, 256)), vec(), random_quat(rng))
    d = roundtrip(pose, codec).message
    assert d.body_id == pose.body_id
    assert_close_f32(d.position_enu_m, pose.position_enu_m)
    assert_same_rotation(d.attitude_wxyz, pose.attitude_wxyz, tol=1e-6)

    truth = TruthState(t, vec(), vec(), random_quat(rng), vec())
    d = roundtrip(truth, codec).message
    assert abs(d.time_s - t) <= 0.5e-6
    assert_close_f32(d.position_enu_m, truth.position_enu_m)
    assert_close_f32(d.velocity_enu_mps, truth.velocity_enu_mps)
    assert_close_f32(d.rate_flu_radps, truth.rate_flu_radps)
    assert_same_rotation(d.attitude_wxyz, truth.attitude_wxyz, tol=1e-6)

    cmd = VehicleCommand(t, CommandKind(int(rng.integers(1, 4))))
    d = roundtrip(cmd, codec).message
    assert d.kind is cmd.kind and d.time_s == f32(t)

    ts = TimeSync(int(rng.integers(-2**63, 2**63 - 1)), int(rng.integers(-2**63, 2**63 - 1)))
    assert roundtrip(ts, codec).message == ts
    bytes5, words2 = rng.integers(0, 256, 5), rng.integers(0, 65536, 2)
    radio = RadioStatus(*(int(x) for x in bytes5), *(int(x) for x in words2))
    assert roundtrip(radio, codec).message == radio
    batt = BatteryStatus(float(rng.uniform(0, 60)), int(rng.integers(-1, 101)), int(rng.integers(0, 65536)),
                         float(rng.uniform(0, 100)))
    d = roundtrip(batt, codec).message
    assert abs(d.voltage_v - batt.voltage_v) <= 0.5e-3 and abs(d.load_pct - batt.load_pct) <= 0.05
    assert (d.remaining_pct, d.rejected_commands) == (batt.remaining_pct, batt.rejected_commands)


def test_header_fields_and_sequence_wrap():
    codec = Codec(17, 42, LIMITS)
    parser = FrameParser(codec)
    for i in range(300):
        (d,) = parser.feed(codec.encode(ImuSample(i * 1e-3, (0, 0, 9.81), (0, 0, 0))))
        assert (d.system_id, d.component_id, d.sequence, d.msgid, d.signed) == (17, 42, i % 256, 105, False)


def test_non_finite_values_decode_as_they_are():
    imu = ImuSample(1.0, (math.nan, math.inf, -math.inf), (0.0, math.nan, 1.0))
    d = roundtrip(imu).message
    assert math.isnan(d.specific_force_flu_mps2[0])
    assert d.specific_force_flu_mps2[1:] == (math.inf, -math.inf)  # FLU->FRD->FLU: two sign flips
    assert math.isnan(d.rate_flu_radps[1])


@pytest.mark.parametrize("msg", [
    ImuSample(-1.0, (0, 0, 0), (0, 0, 0)),
    ImuSample(math.nan, (0, 0, 0), (0, 0, 0)),
    RadioStatus(256, 0, 0, 0, 0, 0, 0),
    BatteryStatus(-1.0, 0),
    MocapPose(0.0, 0, (0, 0, 0), (1, 0, 0, 0)),
    MocapPose(0.0, 256, (0, 0, 0), (1, 0, 0, 0)),
])
def test_values_the_wire_cannot_hold_raise_value_error(msg):
    with pytest.raises(ValueError, match=type(msg).__name__):
        Codec(1, 1, LIMITS).encode(msg)


def test_encode_needs_limits_for_normalised_messages_and_a_message():
    with pytest.raises(ValueError, match="ActuatorLimits"):
        Codec(1).encode(ThrustMoment(0.0, 0.1, (0, 0, 0)))
    with pytest.raises(TypeError):
        Codec(1).encode("hello")
    with pytest.raises(ValueError):
        Codec(0)


def test_parser_without_limits_counts_normalised_messages_as_unsupported():
    frame = Codec(1, 1, LIMITS).encode(ThrustMoment(0.0, 0.1, (0, 0, 0)))
    parser = FrameParser()
    assert parser.feed(frame) == [] and parser.counters.unsupported_messages == 1


# -- interoperability with pymavlink ---------------------------------------------------------------


def pymav_pack(msg_obj, system_id=7, component_id=1, seq=0) -> bytes:
    m = mav.MAVLink(None, system_id, component_id)
    m.seq = seq
    return msg_obj.pack(m)


def test_frames_are_byte_identical_to_pymavlinks():
    codec = Codec(7, 1, LIMITS)
    for sample in sample_messages():
        ours = codec.encode(sample, target_system=3)
        theirs_msg = pymav_decode(ours)  # pymavlink's reading of our fields...
        theirs = pymav_pack(theirs_msg, theirs_msg.get_srcSystem(), 1, seq=theirs_msg.get_seq())
        assert ours == theirs, type(sample).__name__  # ...packed again by pymavlink gives our bytes


def test_pymavlink_frames_decode():
    m = mav.MAVLink(None, 9, 1)
    messages = [
        m.highres_imu_encode(1000, 0.0, 0.0, -9.81, 0.1, 0.2, 0.3, 0, 0, 0, 0, 0, 0, 0, 63),
        m.timesync_encode(0, 123),
        m.set_attitude_target_encode(5, 1, 1, 0b111, [1, 0, 0, 0], 1.0, 2.0, 3.0, 0.5),
    ]
    frames = []
    for seq, msg in enumerate(messages):
        m.seq = seq
        frames.append(msg.pack(m))
    out = FrameParser(LIMITS).feed(b"".join(frames))
    assert [type(d.message) for d in out] == [ImuSample, TimeSync, AttitudeTarget]
    assert out[0].message.specific_force_flu_mps2 == pytest.approx((0.0, 0.0, 9.81))
    assert out[2].message.rates_flu_radps == (0.0, 0.0, 0.0)  # the rate fields were marked "ignore"
    assert [d.sequence for d in out] == [0, 1, 2] and out[0].system_id == 9


# -- parser drop rules -----------------------------------------------------------------------------


def test_garbage_before_and_between_frames_is_skipped_and_counted():
    codec = Codec(1)
    a, b = codec.encode(TimeSync(0, 1)), codec.encode(TimeSync(0, 2))
    junk = bytes([0xFD, 0x05, 0x00, 0x11, 0xFE, 0x00])
    parser = FrameParser()
    out = parser.feed(junk + a + junk + b)
    assert [d.frame for d in out] == [a, b]
    assert parser.counters.garbage_bytes == 2 * len(junk)
    assert parser.counters.bytes_in == parser.counters.garbage_bytes + parser.counters.valid_frame_bytes


def test_stream_reassembly_byte_by_byte():
    codec = Codec(1, 1, LIMITS)
    frames = [codec.encode(s) for s in sample_messages()]
    parser = FrameParser(codec)
    out = [d for byte in b"".join(frames) for d in parser.feed(bytes([byte]))]
    assert [d.frame for d in out] == frames


def test_truncated_datagram_is_dropped_at_once():
    codec = Codec(1)
    frame = codec.encode(TimeSync(0, 1))
    parser = FrameParser()
    assert parser.feed(frame[:-3], final=True) == []
    assert parser.counters.truncated_frames == 1 and parser.pending_bytes == 0
    assert [d.frame for d in parser.feed(frame, final=True)] == [frame]


def test_crc_failure_is_counted_and_the_next_frame_found():
    codec = Codec(1)
    bad = bytearray(codec.encode(TimeSync(0, 1)))
    bad[12] ^= 0x40
    good = codec.encode(TimeSync(0, 2))
    parser = FrameParser()
    assert [d.frame for d in parser.feed(bytes(bad) + good)] == [good]
    assert parser.counters.crc_failures == 1


def frame_with(msgid: int, payload: bytes, flags: int = 0, crc_extra: int | None = None) -> bytes:
    header = struct.pack("<BBBBBBBHB", 0xFD, len(payload), flags, 0, 0, 1, 1, msgid & 0xFFFF, msgid >> 16)
    extra = mav.mavlink_map[msgid].crc_extra if crc_extra is None else crc_extra
    crc = mav.x25crc(header[1:] + payload + bytes([extra])).crc
    return header + payload + struct.pack("<H", crc)


def test_unknown_unsupported_flagged_and_empty_frames_are_counted():
    parser = FrameParser()
    ping = mav.MAVLink_ping_message(1, 2, 0, 0)
    parser.feed(pymav_pack(ping))
    assert parser.counters.unsupported_messages == 1
    parser.feed(frame_with(60000, b"\x01\x02", crc_extra=0))
    assert parser.counters.unknown_messages == 1
    parser.feed(frame_with(mav.MAVLINK_MSG_ID_TIMESYNC, b"\x01", flags=0x02))
    assert parser.counters.bad_headers == 1
    parser.feed(frame_with(mav.MAVLINK_MSG_ID_TIMESYNC, b""))
    assert parser.counters.bad_lengths == 1
    assert parser.counters.frames_ok == 0


def test_zero_truncated_and_extended_payloads_are_accepted():
    payload = struct.pack("<qq", 0, 7)
    short = frame_with(mav.MAVLINK_MSG_ID_TIMESYNC, struct.pack("<qq", 5, 0).rstrip(b"\0"))
    longer = frame_with(mav.MAVLINK_MSG_ID_TIMESYNC, payload + b"\x03\x04")  # newer dialect: target ids
    out = FrameParser().feed(short + longer)
    assert [d.message for d in out] == [TimeSync(5, 0), TimeSync(0, 7)]


def test_measure_codec_costs_reports_every_message():
    costs = measure_codec_costs(n=20)
    assert set(costs) == {type(m).__name__ for m in sample_messages()}
    assert all(e > 0 and d > 0 for e, d in costs.values())
    assert set(measure_codec_costs(n=20, signing=True)) == set(costs)


def test_feed_fields_are_the_fields_of_the_records_feed_gives():
    codec = Codec(1, 1, LIMITS, Signing(bytes(range(32)), 3))
    frames = [codec.encode(m) for m in sample_messages()]
    unsigned = Codec(7, 1, LIMITS).encode(TimeSync(0, 5))  # rejected: signing is on
    data = b"\x00junk" + b"".join(frames[:4]) + unsigned + b"\xfd\x01" + b"".join(frames[4:])
    by_records = FrameParser(LIMITS, Signing(bytes(range(32)), 3))
    by_fields = FrameParser(LIMITS, Signing(bytes(range(32)), 3))
    records = [d for i in range(0, len(data), 37) for d in by_records.feed(data[i:i + 37])]
    fields = [f for i in range(0, len(data), 37) for f in by_fields.feed_fields(data[i:i + 37])]
    assert len(records) == len(frames)
    assert fields == [tuple(getattr(d, f.name) for f in dataclasses.fields(Decoded)) for d in records]
    assert all(d.signed and d.link_id == 3 for d in records)
    assert by_fields.counters == by_records.counters
    assert by_fields.counters.unsigned_rejected == 1


def test_frame_wraps_a_payload_exactly_as_encode_does():
    for message in sample_messages():
        frame = Codec(4, 2, LIMITS).encode(message, target_system=9)
        msgid = frame[7] | frame[8] << 8 | frame[9] << 16
        payload = frame[10:10 + frame[1]]
        source = frame[5]  # MocapPose frames come from the body's id
        wrapped = Codec(4, 2, LIMITS).frame(msgid, bytes([mav.mavlink_map[msgid].crc_extra]), payload, source)
        assert wrapped == frame, type(message).__name__
