"""The geometric controller against its defining equations, rotation identities and closed-loop physics;
the latency compensator's state prediction (the controller's input) against closed-form motion."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from groundstation.compensation import LatencyCompensator
from groundstation.controller import ControllerState, Gains, SE3Controller, load_gains
from groundstation.trajectories.basic import Circle, Step
from groundstation.trajectory import FlatOutput
from model.errors import ConfigError
from model.frames import matrix_to_quat, quat_to_matrix, rot_x, rot_y, rot_z, vee
from model.vehicle import GRAVITY_MPS2, load_vehicle

VEHICLE = load_vehicle("crazyflie")
GAINS = load_gains()
HOME = np.array([0.0, 0.0, 1.0])


LEVEL = np.eye(3)


def at_rest(position, attitude=LEVEL, rate=(0.0, 0.0, 0.0), velocity=(0.0, 0.0, 0.0)) -> ControllerState:
    return ControllerState(np.asarray(position, float), np.asarray(velocity, float), matrix_to_quat(attitude),
                           np.asarray(rate, float))


def hold(position, yaw=0.0) -> FlatOutput:
    return FlatOutput(position_m=np.asarray(position, float), yaw_rad=yaw)


# --- gains file ---------------------------------------------------------------------------------------

def test_default_gains_are_the_reports():
    assert GAINS.kp == (5.0, 5.0, 8.0) and GAINS.kd == (4.0, 4.0, 7.0)
    assert GAINS.k_r == (480.0, 480.0, 240.0) and GAINS.k_w == (70.0, 70.0, 50.0)
    assert GAINS.mass_offset_kg == 0.0 and GAINS.variant == "report"
    assert "report" in GAINS.source
    assert load_gains("default") == GAINS


def test_bad_gains_file_gives_one_line_error(tmp_path):
    bad = tmp_path / "g.toml"
    bad.write_text('schema_version = 1\nname = "g"\nsource = "t"\nvariant = "fast"\n'
                   '[position]\nkp = [1, 1, 1]\nkd = [1, 1, 1]\n'
                   '[attitude]\nk_r = [1, 1, 1]\nk_w = [1, -1, 1]\n')
    with pytest.raises(ConfigError, match=r"g\.toml: attitude\.k_w: gains must be positive"):
        load_gains(bad)
    bad.write_text(bad.read_text().replace("[1, -1, 1]", "[1, 1, 1]"))
    with pytest.raises(ConfigError, match=r"g\.toml: variant: 'fast' is not one of"):
        load_gains(bad)
    with pytest.raises(ConfigError, match="unknown gains 'nope'"):
        load_gains("nope")


# --- the control law at chosen states -----------------------------------------------------------------

def test_at_the_reference_it_hovers_with_zero_moment():
    for variant in ("report", "full"):
        out = SE3Controller(VEHICLE, GAINS, variant).update(at_rest(HOME), hold(HOME))
        assert out.thrust_n == pytest.approx(VEHICLE.mass_kg * GRAVITY_MPS2, rel=1e-12)
        np.testing.assert_allclose(out.moment_flu_nm, 0.0, atol=1e-15)
        np.testing.assert_allclose(out.attitude_des_wxyz, [1, 0, 0, 0], atol=1e-15)
        np.testing.assert_allclose(out.e_R, 0.0, atol=1e-15)
        assert not out.saturated


def test_mass_offset_adds_to_the_model_mass():
    offset = 0.004
    out = SE3Controller(VEHICLE, replace(GAINS, mass_offset_kg=offset)).update(at_rest(HOME), hold(HOME))
    assert out.thrust_n == pytest.approx((VEHICLE.mass_kg + offset) * GRAVITY_MPS2, rel=1e-12)
    with pytest.raises(ConfigError, match="mass_offset_kg"):
        SE3Controller(VEHICLE, replace(GAINS, mass_offset_kg=-1.0))


def test_thrust_is_the_projection_of_f_des_on_the_current_b3():
    # Tilted by 0.3 rad about x at the reference: F_des = m g e3, b3 = Rx(0.3) e3, u1 = m g cos(0.3).
    out = SE3Controller(VEHICLE, GAINS).update(at_rest(HOME, rot_x(0.3)), hold(HOME))
    assert out.thrust_n == pytest.approx(VEHICLE.mass_kg * GRAVITY_MPS2 * math.cos(0.3), rel=1e-12)


def tilted_reference() -> FlatOutput:
    return FlatOutput(position_m=HOME, acceleration_mps2=np.array([1.5, -0.8, 0.4]), yaw_rad=0.6)


def test_attitude_error_vanishes_when_r_equals_r_des():
    controller = SE3Controller(VEHICLE, GAINS)
    r_des = quat_to_matrix(controller.update(at_rest(HOME), tilted_reference()).attitude_des_wxyz)
    out = controller.update(at_rest(HOME, r_des), tilted_reference())
    np.testing.assert_allclose(out.e_R, 0.0, atol=1e-14)
    np.testing.assert_allclose(out.moment_flu_nm, 0.0, atol=1e-16)
    # With R = R_des the thrust is the whole of F_des.
    assert out.thrust_n == pytest.approx(np.linalg.norm(out.force_des_enu_n), rel=1e-12)


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_attitude_error_of_a_single_axis_rotation_is_its_sine(axis):
    # R = R_des Re(theta): R_des^T R = Re(theta), R^T R_des = Re(-theta) = Re(theta)^T, and
    # Re(theta) - Re(theta)^T = 2 sin(theta) hat(e), so e_R = 1/2 vee(.) = sin(theta) e exactly.
    # u2 = I (-K_R e_R) with no rate.
    theta = 0.02
    controller = SE3Controller(VEHICLE, GAINS)
    r_des = quat_to_matrix(controller.update(at_rest(HOME), tilted_reference()).attitude_des_wxyz)
    elementary = (rot_x, rot_y, rot_z)[axis](theta)
    out = controller.update(at_rest(HOME, r_des @ elementary), tilted_reference())
    expected = np.zeros(3)
    expected[axis] = math.sin(theta)
    np.testing.assert_allclose(out.e_R, expected, atol=1e-12)
    k_r = np.diag(GAINS.k_r)
    np.testing.assert_allclose(out.moment_flu_nm, VEHICLE.inertia_kgm2 @ (-k_r @ expected), rtol=1e-9,
                               atol=1e-15)


def test_report_variant_damps_the_full_body_rate():
    rate = np.array([0.2, -0.1, 0.05])
    out = SE3Controller(VEHICLE, GAINS).update(at_rest(HOME, rate=rate), hold(HOME))
    np.testing.assert_allclose(out.e_w, rate)
    np.testing.assert_allclose(out.moment_flu_nm, VEHICLE.inertia_kgm2 @ (-np.diag(GAINS.k_w) @ rate),
                               rtol=1e-12)


def test_lateral_errors_tilt_b3_towards_the_target():
    # Target dx = +0.1 m east of a level vehicle: F_des = m (Kp_x dx, 0, g), so b3_des leans east by
    # theta = atan(Kp_x dx / g). Leaning b3 east is a positive rotation about body +y (FLU); in FLU that
    # turns the nose down ("pitch forward", a negative pitch angle in the FRD/NED convention).
    dx = 0.1
    out = SE3Controller(VEHICLE, GAINS).update(at_rest(HOME), hold(HOME + [dx, 0, 0]))
    theta = math.atan2(GAINS.kp[0] * dx, GRAVITY_MPS2)
    np.testing.assert_allclose(quat_to_matrix(out.attitude_des_wxyz), rot_y(theta), atol=1e-12)
    assert out.moment_flu_nm[1] > 0.0 and abs(out.moment_flu_nm[0]) < 1e-15
    # Target north: b3 leans north, a negative rotation about body +x (right side down in FLU).
    dy = 0.1
    out = SE3Controller(VEHICLE, GAINS).update(at_rest(HOME), hold(HOME + [0, dy, 0]))
    phi = math.atan2(GAINS.kp[1] * dy, GRAVITY_MPS2)
    np.testing.assert_allclose(quat_to_matrix(out.attitude_des_wxyz), rot_x(-phi), atol=1e-12)
    assert out.moment_flu_nm[0] < 0.0


def test_desired_heading_follows_the_reference_yaw():
    psi = 0.05
    out = SE3Controller(VEHICLE, GAINS).update(at_rest(HOME), hold(HOME, yaw=psi))
    np.testing.assert_allclose(quat_to_matrix(out.attitude_des_wxyz), rot_z(psi), atol=1e-12)
    # R = I, R_des = Rz(psi): e_R = -sin(psi) e3, so the moment turns the vehicle counter-clockwise.
    np.testing.assert_allclose(out.e_R, [0, 0, -math.sin(psi)], atol=1e-14)
    assert out.moment_flu_nm[2] == pytest.approx(VEHICLE.inertia_kgm2[2, 2] * GAINS.k_r[2] * math.sin(psi))


def test_outputs_are_clipped_to_the_vehicle_limits_and_flagged():
    controller = SE3Controller(VEHICLE, GAINS)
    below = controller.update(at_rest(HOME), hold(HOME - [0, 0, 5.0]))  # F_des points down: u1 < 0
    assert below.thrust_n == 0.0 and below.thrust_saturated
    above = controller.update(at_rest(HOME), hold(HOME + [0, 0, 5.0]))  # m (8 * 5 + g) > max thrust
    assert above.thrust_n == pytest.approx(VEHICLE.max_thrust_n) and above.thrust_saturated
    spin = controller.update(at_rest(HOME), hold(HOME, yaw=2.0))  # I_zz K_R sin(2) > max yaw moment
    assert spin.moment_flu_nm[2] == pytest.approx(VEHICLE.max_moment_nm[2])
    assert spin.moment_saturated == (False, False, True) and spin.saturated


def test_degenerate_commands_give_finite_outputs():
    # Commanded free fall (F_des = 0) and a horizontal F_des along the heading (b3_des = a_psi) leave
    # b3_des or b2_des undefined; the controller must fall back to the current axes, not divide by zero.
    free_fall = FlatOutput(position_m=HOME, acceleration_mps2=np.array([0.0, 0.0, -GRAVITY_MPS2]))
    sideways = FlatOutput(position_m=HOME, acceleration_mps2=np.array([3.0, 0.0, -GRAVITY_MPS2]))
    for variant in ("report", "full"):
        controller = SE3Controller(VEHICLE, GAINS, variant)
        for ref, attitude in ((free_fall, LEVEL), (sideways, LEVEL), (sideways, rot_y(math.pi / 2))):
            out = controller.update(at_rest(HOME, attitude), ref)
            assert all(math.isfinite(x) for x in (*out.moment_flu_nm, *out.attitude_des_wxyz, out.thrust_n))
        # Sideways: b3_des must be +x whatever the fallback chose for b1_des, b2_des.
        np.testing.assert_allclose(quat_to_matrix(out.attitude_des_wxyz)[:, 2], [1, 0, 0], atol=1e-12)


def test_rejects_an_unknown_variant():
    with pytest.raises(ConfigError, match="variant 'fancy'"):
        SE3Controller(VEHICLE, GAINS, variant="fancy")


# --- full variant: feed-forward = derivatives of R_des along the reference ----------------------------

def lissajous(t: float) -> FlatOutput:
    """r = A sin(W t + phase), all derivatives analytic; yaw turning at a constant rate."""
    amplitude, freq = np.array([1.0, 0.7, 0.3]), np.array([2.0, 3.0, 1.5])
    d = [amplitude * freq**k * np.sin(freq * t + k * np.pi / 2) for k in range(5)]
    return FlatOutput(*d, yaw_rad=0.4 + 0.6 * t, yaw_rate_radps=0.6)


def on_reference(controller, t, attitude=LEVEL, rate=(0.0, 0.0, 0.0)):
    ref = lissajous(t)
    return controller.update(at_rest(ref.position_m, attitude, rate, ref.velocity_mps), ref)


@pytest.mark.parametrize("t", [0.1, 0.5, 1.3])
def test_full_variant_feed_forward_matches_the_derivatives_of_r_des(t):
    # On the reference, R_des(t) is a function of time only: w_des = vee(R_des^T dR_des/dt), and with
    # R = R_des, w = w_des the moment is I w_des' + w x I w (e_R = e_w = 0), Lee et al. eq. (11).
    controller = SE3Controller(VEHICLE, GAINS, variant="full")
    h = 1e-5
    r_des = [quat_to_matrix(on_reference(controller, t + s).attitude_des_wxyz) for s in (-h, 0.0, h)]
    w_fd = vee(r_des[1].T @ (r_des[2] - r_des[0]) / (2 * h))
    out = on_reference(controller, t)
    np.testing.assert_allclose(out.rate_des_flu_radps, w_fd, rtol=1e-6, atol=1e-6)

    w_des = np.array(out.rate_des_flu_radps)
    rates = [np.array(on_reference(controller, t + s).rate_des_flu_radps) for s in (-h, h)]
    alpha_fd = (rates[1] - rates[0]) / (2 * h)
    tracked = on_reference(controller, t, r_des[1], w_des)
    np.testing.assert_allclose(tracked.e_R, 0.0, atol=1e-12)
    np.testing.assert_allclose(tracked.e_w, 0.0, atol=1e-12)
    inertia = VEHICLE.inertia_kgm2
    alpha = np.linalg.solve(inertia, np.array(tracked.moment_flu_nm) - np.cross(w_des, inertia @ w_des))
    np.testing.assert_allclose(alpha, alpha_fd, rtol=1e-5, atol=1e-4)


# --- closed loop: rigid body written here, no rotors --------------------------------------------------

def fly(controller: SE3Controller, trajectory, start_m, duration_s: float, dt: float = 0.002):
    """Rigid-body flight at the controller rate: m r'' = u1 R e3 - m g e3, I w' = u2 - w x I w, R' = R hat(w).

    Semi-implicit Euler; the attitude is advanced by the exact exponential of w dt. Returns (t, r, error).
    """
    m, inertia = VEHICLE.mass_kg, VEHICLE.inertia_kgm2
    r, v, rot, w = np.array(start_m, float), np.zeros(3), np.eye(3), np.zeros(3)
    steps = int(round(duration_s / dt))
    times, positions, errors = np.arange(steps) * dt, np.zeros((steps, 3)), np.zeros((steps, 3))
    for k, t in enumerate(times):
        ref = trajectory.sample(t)
        out = controller.update(ControllerState(r, v, matrix_to_quat(rot), w), ref)
        positions[k], errors[k] = r, r - ref.position_m
        v = v + dt * (out.thrust_n / m * rot[:, 2] - np.array([0.0, 0.0, GRAVITY_MPS2]))
        r = r + dt * v
        w = w + dt * np.linalg.solve(inertia, np.array(out.moment_flu_nm) - np.cross(w, inertia @ w))
        rot = rot @ Rotation.from_rotvec(w * dt).as_matrix()
    return times, positions, errors


def test_closed_loop_step_in_x_converges_like_the_position_loop():
    # With a fast attitude loop, x obeys e'' + Kd e' + Kp e = 0: wn = sqrt(5) rad/s, zeta = 4/(2 wn) = 0.89,
    # PO = exp(-pi zeta / sqrt(1 - zeta^2)) = 0.2 %; from e(0) = -1 m at rest the error stays inside the
    # envelope exp(-zeta wn t) / sqrt(1 - zeta^2). The attitude loop's lag adds a little: allow 1.5x.
    step = Step(HOME, "x", 1.0, hold_s=5.0, step_at_s=0.0)
    t, r, err = fly(SE3Controller(VEHICLE, GAINS), step, HOME, 5.0)
    wn = math.sqrt(GAINS.kp[0])
    zeta = GAINS.kd[0] / (2.0 * wn)
    envelope = np.exp(-zeta * wn * t) / math.sqrt(1.0 - zeta**2)
    late = t >= 1.0
    assert np.all(np.abs(err[late, 0]) < 1.5 * envelope[late])
    assert abs(err[-1, 0]) < 1e-3
    assert np.max(r[:, 0]) < 1.0 + 0.02  # no more than the small second-order overshoot
    assert np.max(np.abs(r[:, 2] - HOME[2])) < 0.05  # height held while tilting
    assert np.max(np.abs(r[:, 1])) < 1e-9  # nothing pushes it north


def test_closed_loop_tracks_the_default_circle():
    # Report variant on a 0.5 m circle at 0.5 m/s. With w_des = 0 the attitude loop lags by
    # e_R ~ (K_w / K_R) |w_des|, and |w_des| = |h_w| ~ |j| / g (thrust ~ m g), so the thrust direction is
    # off by e_R: lateral acceleration error g e_R ~ (K_w / K_R) |j|, position error ~ (K_w / K_R) |j| / Kp
    # (its peak, taken as if it were held: the loop filters the short jerk peaks, so this bounds the error).
    circle = Circle(HOME - [0.5, 0, 0], 0.5, 0.5, spin_up_s=2.0)
    _, _, err = fly(SE3Controller(VEHICLE, GAINS), circle, HOME, circle.duration_s + 1.0)
    max_jerk = max(np.linalg.norm(circle.sample(t).jerk_mps3) for t in np.linspace(0, circle.duration_s, 500))
    expected = GAINS.k_w[0] / GAINS.k_r[0] * max_jerk / GAINS.kp[0]
    assert np.max(np.linalg.norm(err, axis=1)) < expected


def test_full_variant_tracks_a_fast_circle_better():
    circle = Circle(HOME - [0.5, 0, 0], 0.5, 1.5)  # 3 rad/s, 4.5 m/s^2 centripetal
    rms = {}
    for variant in ("report", "full"):
        _, _, err = fly(SE3Controller(VEHICLE, GAINS, variant), circle, HOME, circle.duration_s)
        rms[variant] = float(np.sqrt(np.mean(np.sum(err**2, axis=1))))
    assert rms["full"] < 0.5 * rms["report"], rms


def test_gains_dataclass_can_be_built_directly():
    gains = Gains(kp=(1.0, 1.0, 1.0), kd=(2.0, 2.0, 2.0), k_r=(100.0, 100.0, 50.0), k_w=(20.0, 20.0, 10.0))
    out = SE3Controller(VEHICLE, gains).update(at_rest(HOME, velocity=(0.1, 0, 0)), hold(HOME))
    assert out.force_des_enu_n[0] == pytest.approx(-VEHICLE.mass_kg * 2.0 * 0.1)


# --- latency compensation (groundstation/compensation.py): predictions against closed-form motion -------

@dataclass
class Estimate:
    """The fields of an estimator.Estimate the compensator reads."""

    time_s: float
    position_enu_m: np.ndarray
    velocity_enu_mps: np.ndarray
    attitude_wxyz: np.ndarray
    rate_flu_radps: np.ndarray


STEP_S = 0.002


def test_prediction_coasts_while_no_command_of_ours_acts():
    compensator = LatencyCompensator(VEHICLE, "moments", STEP_S)
    q = matrix_to_quat(rot_x(0.3))
    est = Estimate(1.0, np.array([0.1, 0.2, 1.0]), np.array([0.5, -0.2, 0.1]), q, np.array([0.1, 0.0, 0.2]))
    # the estimate is 5 ms old on our clock (offset 0.25 s), and the command will act 7 ms from now
    state = compensator.predict(est, now_s=0.755, vehicle_minus_ground_s=0.25, uplink_latency_s=0.007)
    np.testing.assert_allclose(state.position_enu_m, est.position_enu_m + 0.012 * est.velocity_enu_mps,
                               rtol=0, atol=1e-15)
    np.testing.assert_array_equal(state.velocity_enu_mps, est.velocity_enu_mps)
    np.testing.assert_array_equal(state.attitude_wxyz, q)
    np.testing.assert_array_equal(state.rate_flu_radps, est.rate_flu_radps)


def test_attitude_mode_prediction_applies_the_newest_arrived_command_from_its_arrival():
    # Two commands: A (tilted, 1.3 x hover thrust) arrives at 4 ms, B (level, hover thrust) at 8 ms; the
    # prediction runs from the estimate at 0 to the moment the next command acts, 12 ms. Acceleration is
    # piecewise constant: 0 (coast) until A, a_A = T_A/m R_A e3 - g e3 until B, then 0.
    m, g, latency = VEHICLE.mass_kg, GRAVITY_MPS2, 0.004
    tilt = rot_x(0.2) @ rot_y(-0.1)
    compensator = LatencyCompensator(VEHICLE, "attitude", STEP_S)
    compensator.record(-0.5, m * g, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0))  # acting long before: level hover
    compensator.record(0.0, 1.3 * m * g, (0.0, 0.0, 0.0), matrix_to_quat(tilt))
    compensator.record(0.004, m * g, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0))
    p0, v0 = np.array([0.0, 0.0, 1.0]), np.array([0.3, 0.0, 0.0])
    est = Estimate(0.0, p0, v0, matrix_to_quat(LEVEL), np.array([0.5, 0.5, 0.0]))
    state = compensator.predict(est, now_s=0.008, vehicle_minus_ground_s=0.0, uplink_latency_s=latency)
    a_tilted = 1.3 * g * tilt[:, 2] - [0.0, 0.0, g]
    # 0..4 ms: the old level hover command acts (zero acceleration); 4..8 ms: A; 8..12 ms: B (level again)
    v_expected = v0 + 0.004 * a_tilted
    p_expected = p0 + v0 * 0.012 + 0.5 * a_tilted * 0.004**2 + a_tilted * 0.004 * 0.004
    np.testing.assert_allclose(state.velocity_enu_mps, v_expected, rtol=0, atol=1e-14)
    np.testing.assert_allclose(state.position_enu_m, p_expected, rtol=0, atol=1e-14)
    np.testing.assert_allclose(state.attitude_wxyz, (1.0, 0.0, 0.0, 0.0), atol=1e-15)  # B's attitude
    assert state.rate_flu_radps == (0.0, 0.0, 0.0)  # the onboard loop holds the commanded attitude


def test_moments_mode_prediction_spins_up_under_a_yaw_moment():
    # From level rest with hover thrust and a yaw moment M_z: w_z = (M_z / I_zz) t (no gyroscopic term about
    # a single axis), the yaw angle sum_k w_z(t_k) dt -> (M_z / I_zz) t^2 / 2, and the thrust stays vertical.
    m, g, izz, moment = VEHICLE.mass_kg, GRAVITY_MPS2, float(VEHICLE.inertia_kgm2[2, 2]), 1e-4
    compensator = LatencyCompensator(VEHICLE, "moments", STEP_S)
    compensator.record(-1.0, m * g, (0.0, 0.0, moment), (1.0, 0.0, 0.0, 0.0))
    est = Estimate(0.0, np.array([0.0, 0.0, 1.0]), np.zeros(3), matrix_to_quat(LEVEL), np.zeros(3))
    state = compensator.predict(est, now_s=0.0, vehicle_minus_ground_s=0.0, uplink_latency_s=0.02)
    steps, alpha = 10, moment / izz
    np.testing.assert_allclose(state.rate_flu_radps, (0.0, 0.0, alpha * 0.02), rtol=1e-12, atol=1e-15)
    yaw = 2.0 * math.atan2(state.attitude_wxyz[3], state.attitude_wxyz[0])
    assert yaw == pytest.approx(alpha * STEP_S**2 * steps * (steps + 1) / 2, rel=1e-9)  # the rate after each step
    np.testing.assert_allclose(state.position_enu_m, (0.0, 0.0, 1.0), atol=1e-15)
    np.testing.assert_allclose(state.velocity_enu_mps, 0.0, atol=1e-15)
