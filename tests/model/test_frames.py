"""model.frames against scipy.spatial.transform.Rotation (scalar-first quaternions, w x y z)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from model import frames

RNG_SEED = 7
CASES = 50


def _random_pairs():
    rng = np.random.default_rng(RNG_SEED)
    for a, b in zip(Rotation.random(CASES, rng=rng), Rotation.random(CASES, rng=rng), strict=True):
        yield a, b, tuple(a.as_quat(scalar_first=True)), tuple(b.as_quat(scalar_first=True))


def test_product_conjugate_and_rows_match_scipy():
    for a, b, qa, qb in _random_pairs():
        product = Rotation.from_quat(frames.quat_multiply(qa, qb), scalar_first=True)
        assert (product * (a * b).inv()).magnitude() < 1e-12
        inverse = Rotation.from_quat(frames.quat_conjugate(qa), scalar_first=True)
        assert (inverse * a).magnitude() < 1e-12
        assert np.allclose(np.array(frames.quat_to_rows(qa)).reshape(3, 3), a.as_matrix(), atol=1e-12)
        v = np.array([0.3, -1.2, 2.0])
        assert np.allclose(frames.rotate(frames.quat_to_rows(qa), *v), a.apply(v), atol=1e-12)


def test_rows_and_matrices_convert_back_with_positive_w():
    for a, _, qa, _ in _random_pairs():
        back = frames.rows_to_quat(*a.as_matrix().reshape(9))
        assert back[0] >= 0.0
        assert np.allclose(back, np.array(qa) * np.sign(qa[0]), atol=1e-12)
        assert np.allclose(frames.matrix_to_quat(a.as_matrix()), back, atol=1e-15)
        # quat_to_matrix normalises: a scaled quaternion is the same rotation
        assert np.allclose(frames.quat_to_matrix(3.0 * np.array(qa)), a.as_matrix(), atol=1e-12)


def test_normalisation_keeps_or_fixes_the_sign():
    q = (-2.0, 0.0, 0.0, 2.0)
    assert frames.quat_normalize(q) == pytest.approx((-math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5)))
    assert frames.quat_normalize_positive_w(q) == pytest.approx((math.sqrt(0.5), 0.0, 0.0, -math.sqrt(0.5)))
    with pytest.raises(ValueError):
        frames.quat_normalize_positive_w((0.0, 0.0, 0.0, 0.0))


@pytest.mark.parametrize("magnitude", [0.0, 1e-9, 1e-3, 1.0, 3.0])
def test_exp_log_and_attitude_error_match_scipy(magnitude):
    rng = np.random.default_rng(RNG_SEED)
    for a, b, qa, qb in _random_pairs():
        v = rng.normal(size=3)
        v *= magnitude / np.linalg.norm(v)  # |angle| < pi: Log is unique
        q = frames.quat_exp(*v)
        assert np.allclose(Rotation.from_quat(q, scalar_first=True).as_rotvec(), v, atol=1e-12, rtol=1e-9)
        assert np.allclose(frames.quat_log(q), v, atol=1e-12, rtol=1e-9)
        assert np.allclose(frames.attitude_error(qa, qb), (a.inv() * b).as_rotvec(), atol=1e-10)


def test_batch_exp_matches_scipy():
    rotvecs = np.random.default_rng(6).normal(0.0, 0.3, (200, 3))
    rotvecs[0] = 0.0
    got = frames.quat_exp_rows(rotvecs)
    expected = Rotation.from_rotvec(rotvecs).as_quat(scalar_first=True)
    assert np.allclose(got * np.sign(got[:, :1]), expected * np.sign(expected[:, :1]), atol=1e-12)


def test_integrating_a_held_rate_is_the_exponential_map():
    for _, _, qa, _ in _random_pairs():
        w, dt = (0.4, -1.1, 2.3), 0.01
        expected = Rotation.from_quat(qa, scalar_first=True) * Rotation.from_rotvec(np.array(w) * dt)
        got = Rotation.from_quat(frames.quat_integrate(qa, w, dt), scalar_first=True)
        assert (got * expected.inv()).magnitude() < 1e-12
    assert frames.quat_integrate(frames.IDENTITY, (0.0, 0.0, 0.0), 0.01) == frames.IDENTITY


def test_euler_zyx_and_yaw_match_scipy():
    rng = np.random.default_rng(RNG_SEED)
    for _ in range(CASES):
        roll, pitch, yaw = rng.uniform(-1.4, 1.4), rng.uniform(-1.4, 1.4), rng.uniform(-3.1, 3.1)
        q = frames.quat_from_euler_zyx(roll, pitch, yaw)
        expected = Rotation.from_euler("ZYX", [yaw, pitch, roll])
        assert (Rotation.from_quat(q, scalar_first=True) * expected.inv()).magnitude() < 1e-12
        assert frames.euler_zyx_of(q) == pytest.approx((roll, pitch, yaw), abs=1e-12)
        assert frames.yaw_of(q) == pytest.approx(yaw, abs=1e-12)
        level = frames.level_with_yaw(q)
        assert frames.yaw_of(level) == pytest.approx(yaw, abs=1e-12)
        assert Rotation.from_quat(level, scalar_first=True).apply([0, 0, 1]) == pytest.approx([0, 0, 1], abs=1e-12)
        assert frames.quat_from_yaw(yaw) == pytest.approx(Rotation.from_euler("z", yaw).as_quat(scalar_first=True)
                                                          * np.sign(math.cos(yaw / 2)), abs=1e-12)


def test_flu_pitch_up_tips_thrust_forward():
    """FLU convention: a positive pitch (about +y, left) turns the nose down, thrust towards +x."""
    r = frames.quat_to_matrix(frames.quat_from_euler_zyx(0.0, 0.3, 0.0))
    assert r[:, 2][0] > 0.0


def test_rotation_angle_between_matches_scipy():
    for a, b, qa, qb in _random_pairs():
        assert frames.rotation_angle_between(qa, qb) == pytest.approx((a.inv() * b).magnitude(), abs=1e-7)


def test_hat_vee_and_elementary_rotations():
    v, u = np.array([0.3, -1.2, 2.0]), np.array([-0.7, 0.4, 1.1])
    np.testing.assert_allclose(frames.hat(v) @ u, np.cross(v, u))
    np.testing.assert_allclose(frames.vee(frames.hat(v)), v)
    for rot, axis in ((frames.rot_x, [1, 0, 0]), (frames.rot_y, [0, 1, 0]), (frames.rot_z, [0, 0, 1])):
        expected = Rotation.from_rotvec(0.4 * np.array(axis)).as_matrix()
        np.testing.assert_allclose(rot(0.4), expected, atol=1e-15)


def test_roll_pitch_yaw_rows_match_scipy_and_keep_nan_rows():
    rng = np.random.default_rng(RNG_SEED)
    q = Rotation.random(CASES, rng=rng).as_quat(scalar_first=True)
    q = np.vstack([q, [np.nan] * 4, [0.0] * 4])
    got = frames.roll_pitch_yaw_deg(q)
    expected = Rotation.from_quat(q[:CASES], scalar_first=True).as_euler("ZYX", degrees=True)[:, ::-1]
    np.testing.assert_allclose(got[:CASES], expected, atol=1e-9)
    assert np.isnan(got[CASES:]).all()
