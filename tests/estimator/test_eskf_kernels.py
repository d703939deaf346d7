"""The estimator's shortcuts give the bits of what they replace (issue 19: behaviour unchanged): its
covariance step gives filterpy's, and the compiled propagation (estimator/_eskf_kernels.c) its Python twin's
(estimator/eskf_kernels.py), sample by sample and over whole filtered flights."""

from __future__ import annotations

import math
import struct
import sys
from pathlib import Path

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter
from filterpy.kalman import predict as filterpy_predict
from scipy.stats import chi2

sys.path.insert(0, str(Path(__file__).resolve().parent))

from synthetic import Flight, LinkFaults, simulate  # noqa: E402

import estimator.eskf as eskf  # noqa: E402
from estimator import eskf_kernels  # noqa: E402
from estimator.eskf import _F_INDEX, N_ERROR, ErrorStateKF  # noqa: E402
from estimator.sensor_spec import SensorSpec  # noqa: E402
from link.messages import ImuSample  # noqa: E402
from model.frames import SMALL_ANGLE_RAD, quat_normalize_positive_w  # noqa: E402
from model.vehicle import GRAVITY_MPS2, load_mocap_room, load_vehicle  # noqa: E402

needs_compiled = pytest.mark.skipif(
    not eskf_kernels.COMPILED,
    reason="estimator/_eskf_kernels.c was not built (no C compiler at pip install): the Python twin runs")


def _random_transition(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    A = rng.normal(size=(N_ERROR, N_ERROR))
    P = A @ A.T + np.eye(N_ERROR)  # a covariance: symmetric positive definite
    F = np.eye(N_ERROR) + 0.01 * rng.normal(size=(N_ERROR, N_ERROR))
    B = rng.normal(size=(N_ERROR, N_ERROR))
    return P, F, 1e-6 * (B @ B.T)


def test_covariance_prediction_is_filterpys_bit_for_bit():
    rng = np.random.default_rng(7)
    for _ in range(50):
        P, F, Q = _random_transition(rng)
        kf = KalmanFilter(dim_x=N_ERROR, dim_z=6)
        kf.x, kf.P, kf.F, kf.Q = np.zeros((N_ERROR, 1)), P, F, Q
        kf.predict()
        ours = ErrorStateKF._predict(P, (F, Q))
        assert ours.tobytes() == kf.P.tobytes()
        assert ours.tobytes() == filterpy_predict(np.zeros((N_ERROR, 1)), P, F, Q)[1].tobytes()  # predict_to's
        assert not np.shares_memory(ours, P)  # a new array: the stored P of the node before is kept


def test_gate_quantile_is_scipys_chi2_bit_for_bit():
    for probability in (0.5, 0.9, 0.99, 0.999, 0.99999, 1.0 - 1e-12):
        for dof in (1, 3, 6):
            assert eskf.chi2_quantile(probability, dof) == float(chi2.ppf(probability, dof))
    assert eskf.chi2_quantile(0.95, 6) == pytest.approx(12.5916, abs=1e-4)  # the chi-square table's value


def test_update_is_filterpys_bit_for_bit():
    """The mocap update (estimator.eskf ErrorStateKF._update) against filterpy's KalmanFilter.update with the
    same S^-1 routine, on random covariances and residuals."""
    vehicle, room = load_vehicle("crazyflie"), load_mocap_room("vicon")
    ours = ErrorStateKF(SensorSpec.matching_simulation(vehicle, room), vehicle.imu.rate_hz)
    rng = np.random.default_rng(5)
    for _ in range(50):
        P, _, _ = _random_transition(rng)
        z = rng.normal(scale=0.01, size=(6, 1))
        kf = KalmanFilter(dim_x=N_ERROR, dim_z=6)
        kf.inv = eskf._inverse
        kf.x, kf.P, kf.R = np.zeros((N_ERROR, 1)), P, ours._R
        kf.update(z, H=ours._H)
        dx, P_post, y, SI = ours._update(P, z)
        for mine, theirs in ((dx, kf.x), (P_post, kf.P), (y, kf.y), (SI, kf.SI)):
            assert mine.tobytes() == theirs.tobytes()


def test_chained_predictions_stay_equal_over_a_flight_length():
    """A second of 500 Hz steps: rounding does not drift apart either (same calls, same order)."""
    rng = np.random.default_rng(11)
    P, _, _ = _random_transition(rng)
    kf = KalmanFilter(dim_x=N_ERROR, dim_z=6)
    kf.x, kf.P = np.zeros((N_ERROR, 1)), P.copy()
    ours = P.copy()
    for _ in range(500):
        _, F, Q = _random_transition(rng)
        kf.F, kf.Q = F, Q
        kf.predict()
        ours = ErrorStateKF._predict(ours, (F, Q))
    assert ours.tobytes() == kf.P.tobytes()


def _bits(values) -> bytes:
    return struct.pack(f"{len(values)}d", *values)


def _random_step(rng: np.random.Generator) -> tuple:
    """A nominal state and IMU signal: attitudes anywhere, rates from still (the small-angle series) to
    30 rad/s, forces to 4 g, biases, intervals from 1 us to a lost-frame gap."""
    q = quat_normalize_positive_w(tuple(rng.normal(size=4)))
    x = (*rng.normal(scale=2.0, size=6), *q, *rng.normal(scale=0.2, size=3), *rng.normal(scale=0.05, size=3))
    rate_scale = 10.0 ** rng.uniform(-9, 1.5)  # |w dt| from ~1e-12 rad (below SMALL_ANGLE_RAD) up
    signal = [tuple(rng.normal(scale=scale, size=3).tolist()) for scale in (40.0, rate_scale, 40.0, rate_scale)]
    dt = 10.0 ** rng.uniform(-6, -1.5)
    return tuple(float(v) for v in x), *signal, dt


@needs_compiled
def test_compiled_propagation_is_the_python_twin_bit_for_bit():
    rng = np.random.default_rng(19)
    small_angles = 0
    for _ in range(20000):
        x, f0, w0, f1, w1, dt = _random_step(rng)
        F_c, F_p = np.eye(N_ERROR), np.eye(N_ERROR)
        x_c = eskf_kernels.propagate_compiled(x, f0, w0, f1, w1, dt, GRAVITY_MPS2, F_c, _F_INDEX)
        x_p = eskf_kernels.propagate_python(x, f0, w0, f1, w1, dt, GRAVITY_MPS2, F_p, _F_INDEX)
        assert _bits(x_c) == _bits(x_p)
        assert F_c.tobytes() == F_p.tobytes()
        assert eskf_kernels.propagate_compiled(x, f0, w0, f1, w1, dt, GRAVITY_MPS2, None, None) == x_c
        w = [0.5 * (a + b) - bias for a, b, bias in zip(w0, w1, x[13:16], strict=True)]
        small_angles += math.hypot(*w) * dt < SMALL_ANGLE_RAD
    assert small_angles > 1000  # both branches of quat_exp were compared


def test_python_twin_is_the_trapezoid_of_the_equations():
    """Against the module docstring's equations written with numpy: a held rate about z, a held force."""
    w, f, dt = (0.0, 0.0, 2.0), (0.3, -0.2, 9.9), 0.002
    x = (0.1, 0.2, 1.0, 0.5, -0.4, 0.1, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    F = np.eye(N_ERROR)
    x1 = eskf_kernels.propagate(x, f, w, f, w, dt, GRAVITY_MPS2, F, _F_INDEX)
    yaw = w[2] * dt
    assert x1[6:10] == pytest.approx((math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)), abs=1e-15)
    R1 = np.array([[math.cos(yaw), -math.sin(yaw), 0.0], [math.sin(yaw), math.cos(yaw), 0.0], [0.0, 0.0, 1.0]])
    a = 0.5 * (np.array(f) + R1 @ f) - [0.0, 0.0, GRAVITY_MPS2]
    assert x1[3:6] == pytest.approx(np.array(x[3:6]) + a * dt, abs=1e-14)
    assert x1[0:3] == pytest.approx(np.array(x[0:3]) + np.array(x[3:6]) * dt + a * dt**2 / 2, abs=1e-14)
    f_cross = np.array([[0.0, -f[2], f[1]], [f[2], 0.0, -f[0]], [-f[1], f[0], 0.0]])
    assert F[3:6, 6:9] == pytest.approx(-f_cross * dt, abs=1e-15)  # dv <- dtheta: -R [f]x dt, R = I
    assert F[3:6, 9:12] == pytest.approx(-np.eye(3) * dt)  # dv <- db_a
    assert F[6:9, 6:9] == pytest.approx(np.eye(3) + [[0, yaw, 0], [-yaw, 0, 0], [0, 0, 0]])  # I - [w dt]x
    assert F[6:9, 12:15] == pytest.approx(-np.eye(3) * dt)


@needs_compiled
def test_compiled_propagation_refuses_bad_arguments_with_one_error():
    x = (0.0,) * 6 + (1.0, 0.0, 0.0, 0.0) + (0.0,) * 6
    v = (0.0, 0.0, 9.81)
    compiled = eskf_kernels.propagate_compiled
    with pytest.raises(ValueError, match="x: expected 16"):
        compiled(x[:15], v, v, v, v, 0.002, GRAVITY_MPS2, None, None)
    with pytest.raises(TypeError):
        compiled(x, v, v, v, ("a", 0.0, 0.0), 0.002, GRAVITY_MPS2, None, None)
    with pytest.raises(ValueError, match="zero quaternion"):
        compiled((0.0,) * 16, v, v, v, v, 0.002, GRAVITY_MPS2, None, None)
    with pytest.raises(ValueError, match="15x15 float64"):
        compiled(x, v, v, v, v, 0.002, GRAVITY_MPS2, np.eye(N_ERROR, dtype=np.float32), _F_INDEX)
    with pytest.raises(ValueError, match="15x15 float64"):
        compiled(x, v, v, v, v, 0.002, GRAVITY_MPS2, np.eye(N_ERROR), _F_INDEX[:10])
    with pytest.raises(TypeError):
        compiled(x, v, v, v, v, 0.002)


def _filtered(run) -> list[bytes]:
    """Every estimate of a filter fed the run's messages in arrival order, as bytes."""
    vehicle, room = load_vehicle("crazyflie"), load_mocap_room("vicon")
    kf = ErrorStateKF(SensorSpec.matching_simulation(vehicle, room), vehicle.imu.rate_hz)
    out = []
    for _, msg in run.events:
        if isinstance(msg, ImuSample):
            kf.add_imu(msg)
            if kf.initialised:
                e = kf.estimate()
                out.append(b"".join(np.asarray(v).tobytes() for v in (
                    e.time_s, e.position_enu_m, e.velocity_enu_mps, e.attitude_wxyz, e.rate_flu_radps,
                    e.accel_bias_flu_mps2, e.gyro_bias_flu_radps, e.covariance)))
        else:
            kf.add_mocap(msg)
    return out


@needs_compiled
def test_a_filtered_flight_is_the_same_with_either_twin(monkeypatch):
    """Late, reordered and lost frames: replays, stored transitions and sub-stepped gaps all run."""
    vehicle, room = load_vehicle("crazyflie"), load_mocap_room("vicon")
    faults = LinkFaults(mocap_latency_s=0.020, mocap_jitter_s=0.015, imu_loss_bursts=3, imu_swap_probability=0.01)
    run = simulate(Flight(duration_s=4.0), vehicle.imu, room, np.random.default_rng(3), faults)
    compiled = _filtered(run)
    monkeypatch.setattr(eskf, "propagate", eskf_kernels.propagate_python)
    assert _filtered(run) == compiled
    assert len(compiled) > 1500
