"""Each part of the faithful firmware against crazyflie-firmware's own definitions (the formulas of pid.c,
controller_pid.c, power_distribution_quadrotor.c, motors.c and sensfusion6.c, worked by hand here)."""

import math

import pytest

from simulator.crazyflie.attitude_controller import AttitudeController, saturate_int16
from simulator.crazyflie.battery import Battery
from simulator.crazyflie.controller_pid import (
    MODE_ABS,
    MODE_DISABLE,
    MODE_VELOCITY,
    ControllerPid,
    LegacyControl,
    Setpoint,
)
from simulator.crazyflie.pid import Pid
from simulator.crazyflie.power_distribution import ForceTorqueMixer, cap, legacy
from simulator.crazyflie.sensfusion6 import Sensfusion6
from simulator.crazyflie.stabilizer import load_crazyflie_params

CF = load_crazyflie_params()
DT = 1.0 / 500.0


def test_the_parameters_are_the_cf2_defaults():
    assert CF.pid_rate["kp"] == [250.0, 250.0, 120.0] and CF.pid_rate["ki"] == [500.0, 500.0, 16.7]
    assert CF.pid_rate["kd"] == [2.5, 2.5, 0.0] and CF.pid_rate["integration_limit"][:2] == [33.3, 33.3]
    assert CF.pid_attitude["kp"] == [6.0, 6.0, 6.0] and CF.pid_attitude["ki"] == [3.0, 3.0, 1.0]
    assert CF.pid_attitude["kd"] == [0.0, 0.0, 0.35] and CF.pid_attitude["integration_limit"][:2] == [20.0, 20.0]
    assert CF.curve.thrust_max_n == 0.12 and CF.thrust_to_torque_m == pytest.approx(0.0069929, rel=1e-4)


def test_pid_output_for_an_error_sequence():
    # kp 2, ki 10, kd 0.5, dt 0.01, i-limit 0.05: by hand from pidUpdate
    pid = Pid(2.0, 10.0, 0.5, 0.01, 0.05)
    pid.reset(0.0)
    # step 1: desired 1, measured 0 -> e = 1; D on the measurement: 0; integ 0.01
    assert pid.update(1.0, 0.0) == pytest.approx(2.0 + 0.0 + 10.0 * 0.01)
    # step 2: measured 0.2 -> e 0.8; D = 0.5 * -(0.2 - 0) / 0.01 = -10; integ 0.018
    assert pid.update(1.0, 0.2) == pytest.approx(1.6 - 10.0 + 10.0 * 0.018)
    # a setpoint jump gives no derivative kick: measured unchanged
    assert pid.out_d == pytest.approx(-10.0)
    assert pid.update(5.0, 0.2) == pytest.approx(2.0 * 4.8 + 0.0 + 10.0 * 0.05)  # integ clamped at 0.05
    assert pid.integ == 0.05


def test_yaw_angle_error_wraps_to_plus_minus_180():
    pid = Pid(1.0, 0.0, 0.0, 0.01, 0.0)
    pid.reset(170.0)
    assert pid.update(-170.0, 170.0, is_yaw_angle=True) == pytest.approx(20.0)


def test_saturate_int16_clamps_and_truncates():
    assert saturate_int16(40000.0) == 32767 and saturate_int16(-40000.0) == -32767
    assert saturate_int16(-12.9) == -12 and saturate_int16(12.9) == 12


def _controller() -> ControllerPid:
    return ControllerPid(AttitudeController(CF.pid_attitude, CF.pid_rate, DT), DT)


ATT = (MODE_DISABLE, MODE_DISABLE, MODE_DISABLE, MODE_ABS, MODE_ABS, MODE_ABS)


def test_a_roll_error_drives_the_rate_loop_with_the_cf2_gains():
    c = _controller()
    out = c.update(Setpoint(ATT, (10.0, 0.0, 0.0), thrust_pwm=30000.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    # attitude PID: 6 * 10 + 3 * 10 * dt = 60.06 deg/s desired roll rate; rate PID: 250 * 60.06 +
    # 500 * 60.06 * dt (+ no D: gyro unchanged) = 15075.06 -> int16 15075
    assert out.roll == int(250.0 * 60.06 + 500.0 * 60.06 * DT) and out.pitch == 0 and out.thrust_pwm == 30000.0


def test_legacy_pitch_sign_and_negated_yaw():
    c = _controller()
    # a nose-up body rate (gyro.y > 0) is a negative legacy pitch rate: the rate PID pushes legacy pitch up
    out = c.update(Setpoint(ATT, thrust_pwm=30000.0), (0.0, 0.0, 0.0), (0.0, 10.0, 0.0))
    assert out.pitch > 0
    c = _controller()
    out = c.update(Setpoint(ATT, thrust_pwm=30000.0), (0.0, 0.0, 0.0), (0.0, 0.0, 10.0))
    # yaw rate PID: 120 * (0 - 10) + 16.7 * (-10 * dt) -> negative; the controller negates it
    assert out.yaw == -int(120.0 * -10.0 + 16.7 * -10.0 * DT)


def test_a_mode_change_resets_the_pids_and_zero_thrust_resets_them_too():
    c = _controller()
    for _ in range(50):
        c.update(Setpoint(ATT, (5.0, 0.0, 0.0), thrust_pwm=30000.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    assert c.attitude.attitude[0].integ > 0.0
    velocity_yaw = (MODE_DISABLE, MODE_DISABLE, MODE_DISABLE, MODE_ABS, MODE_ABS, MODE_VELOCITY)
    c.update(Setpoint(velocity_yaw, (0.0, 0.0, 0.0), thrust_pwm=30000.0), (1.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    # reset at the mode change, then one update: the integral holds one step's error only
    assert c.attitude.attitude[0].integ == pytest.approx(-1.0 * DT)
    out = c.update(Setpoint(velocity_yaw, thrust_pwm=0.0), (1.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    assert (out.roll, out.pitch, out.yaw, out.thrust_pwm) == (0, 0, 0, 0.0)
    assert c.attitude.attitude[0].integ == 0.0 and c.attitude.rate[0].integ == 0.0


def test_a_yaw_rate_setpoint_is_integrated_and_wrapped():
    c = _controller()
    sp = Setpoint((MODE_DISABLE,) * 3 + (MODE_ABS, MODE_ABS, MODE_VELOCITY), (0.0, 0.0, 0.0), (0.0, 0.0, 90.0),
                  thrust_pwm=30000.0)
    for _ in range(500):  # 1 s at 90 deg/s
        c.update(sp, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    assert c.desired_deg[2] == pytest.approx(90.0, abs=1e-6)
    for _ in range(1000):  # 2 s more: 270 deg, wrapped to -90
        c.update(sp, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    assert c.desired_deg[2] == pytest.approx(-90.0, abs=1e-6)


def test_legacy_mixer_and_cap():
    m = legacy(LegacyControl(thrust_pwm=40000.0, roll=1001, pitch=-2000, yaw=300))
    r, p = 500, -1000  # int16 truncation of 1001 / 2 and -2000 / 2
    assert m == (40000 - r + p + 300, 40000 - r - p - 300, 40000 + r - p + 300, 40000 + r + p - 300)
    # the highest motor 70000 shifts all four down by 4465, keeping their differences
    assert cap((70000, 60000, 50000, 1000), 65535, 0) == (65535, 55535, 45535, 0)
    assert cap((30000, 20000, 10000, 5000), 65535, 0) == (30000, 20000, 10000, 5000)


def test_force_torque_mixer_reproduces_the_wrench_on_the_x_layout():
    mixer = ForceTorqueMixer(CF.arm_length_m, CF.thrust_to_torque_m, CF.curve.thrust_max_n, CF.curve.pwm_max)
    thrust, torque = 0.3, (1e-3, -2e-3, 5e-4)
    f = mixer.forces_n(thrust, torque)
    # rotor positions (x, y) of M1..M4 and their yaw signs, from the mixer's own signs
    a = 0.707106781 * CF.arm_length_m
    pos = [(a, -a), (-a, -a), (-a, a), (a, a)]
    yaw_sign = [-1, 1, -1, 1]
    assert sum(f) == pytest.approx(thrust)
    assert sum(fi * y for fi, (x, y) in zip(f, pos, strict=True)) == pytest.approx(torque[0])
    assert sum(-fi * x for fi, (x, y) in zip(f, pos, strict=True)) == pytest.approx(torque[1])
    assert sum(s * CF.thrust_to_torque_m * fi for fi, s in zip(f, yaw_sign, strict=True)) == pytest.approx(torque[2])
    assert mixer.pwm(0.48, (0.0, 0.0, 0.0)) == (65535,) * 4  # THRUST_MAX per motor is full PWM
    assert mixer.pwm(0.0, (1e-3, 0.0, 0.0))[0] == 0  # a negative force is clipped


@pytest.mark.parametrize("battery_v", [4.2, 3.7, 3.3])
@pytest.mark.parametrize("pwm", [5000, 30000, 39000, 65535])
def test_battery_compensation_makes_the_command_linear_in_force(pwm, battery_v):
    curve = CF.curve
    ratio = curve.compensate(pwm, battery_v)
    wanted = pwm / 65535 * curve.thrust_max_n
    if wanted < curve.thrust_min_n:
        assert ratio == 0.0
    else:
        assert curve.thrust_n(ratio, battery_v) == pytest.approx(wanted, rel=1e-9)
        assert ratio < 65535  # 0.12 N needs about 3.08 V: a battery above that has headroom


def test_below_two_volts_compensation_gives_nothing_and_a_flat_battery_saturates():
    curve = CF.curve
    assert curve.compensate(40000, 1.9) == 0.0
    assert curve.compensate(65535, 3.0) > 65535  # 0.12 N needs more than 3.0 V: capped by the mixer later


def test_battery_sags_with_load_and_drains():
    p = CF.battery
    b = Battery(250.0, 4.2, 3.0, **p)
    hover = [p["hover_thrust_n"] / 4.0] * 4
    v = b.step(hover, 0.01)
    # at hover the draw is V_nominal * I_hover; the sag is R * I
    assert b.power_w(hover) == pytest.approx(p["nominal_voltage_v"] * p["hover_current_a"])
    assert v == pytest.approx(4.2 - p["internal_resistance_ohm"] * b.current_a, rel=1e-9)
    assert b.step([0.0] * 4, 0.01) == pytest.approx(b.open_circuit_v)
    for _ in range(42000):  # 7 minutes at hover
        b.step(hover, 0.01)
    assert b.charge_left < 0.1


def test_complementary_filter_levels_to_gravity_and_reports_legacy_pitch():
    f = Sensfusion6(CF.two_kp, CF.two_ki)
    # at rest nose up 10 deg (FLU pitch -10 deg): the accelerometer reads R^T (0, 0, 1 g) = (sin 10, 0, cos 10)
    nose_up = math.radians(10.0)
    acc = (math.sin(nose_up), 0.0, math.cos(nose_up))
    # the proportional pull is twoKp/2 per rad (0.4/s): 98 % after 10 s, within 0.1 deg after 40 s
    for _ in range(2500):  # 10 s at 250 Hz
        f.update((0.0, 0.0, 0.0), acc, 1.0 / 250.0)
    assert f.euler_rpy_deg()[1] == pytest.approx(10.0 * (1.0 - math.exp(-0.4 * 10.0)), abs=0.1)
    for _ in range(7500):
        f.update((0.0, 0.0, 0.0), acc, 1.0 / 250.0)
    roll, legacy_pitch, yaw = f.euler_rpy_deg()
    # the legacy frame's pitch is positive nose up (the opposite of the FLU pitch)
    assert legacy_pitch == pytest.approx(10.0, abs=0.1) and abs(roll) < 1e-9 and abs(yaw) < 1e-9


def test_rpyt_thrust_lock_min_max_and_inverted_yaw_rate():
    from simulator.crazyflie.commander_rpyt import MAX_THRUST, RpytDecoder

    rpyt = RpytDecoder()
    # locked after start-up: a stale non-zero thrust spins nothing until a zero-thrust packet has come
    assert rpyt.decode(0.0, 0.0, 0.0, 40000).thrust_pwm == 0.0
    assert rpyt.decode(0.0, 0.0, 0.0, 0).thrust_pwm == 0.0
    sp = rpyt.decode(5.0, -3.0, 30.0, 40000)
    assert sp.thrust_pwm == 40000.0 and sp.attitude_deg[:2] == (5.0, -3.0)
    assert sp.attitude_rate_dps[2] == -30.0  # "legacy rate input is inverted"
    assert sp.modes == (MODE_DISABLE, MODE_DISABLE, MODE_DISABLE, MODE_ABS, MODE_ABS, MODE_VELOCITY)
    assert rpyt.decode(0.0, 0.0, 0.0, 999).thrust_pwm == 0.0  # below MIN_THRUST
    assert rpyt.decode(0.0, 0.0, 0.0, 65000).thrust_pwm == MAX_THRUST
    # the commander fell back to DISABLE (watchdog): locked again until the next zero
    assert rpyt.decode(0.0, 0.0, 0.0, 40000, priority_disabled=True).thrust_pwm == 0.0
    assert rpyt.decode(0.0, 0.0, 0.0, 40000).thrust_pwm == 0.0
    rpyt.decode(0.0, 0.0, 0.0, 0)
    assert rpyt.decode(0.0, 0.0, 0.0, 40000).thrust_pwm == 40000.0
