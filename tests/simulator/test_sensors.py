"""IMU and mocap models: noise statistics from the densities, bias random walk, specific force at rest
and in free fall, mocap latency, dropout and outlier rates."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from link.messages import ImuSample, MocapPose
from model.frames import quat_from_euler_zyx, rotation_angle_between
from model.vehicle import GRAVITY_MPS2, load_mocap_room, load_vehicle
from simulator.sensors import DRAW_BLOCK, ImuModel, MocapModel
from simulator.vehicle_sim import SimVehicle

CF = load_vehicle("crazyflie")
ROOM = load_mocap_room("vicon")


def _imu_readings(noise, count, seed=0, force=(0.1, -0.2, 9.81), rate=(0.01, 0.02, -0.03)):
    imu = ImuModel(noise, np.random.default_rng(seed))
    samples = [imu.sample(k / noise.rate_hz, force, rate) for k in range(count)]
    accel = np.array([s.specific_force_flu_mps2 for s in samples]) - force
    gyro = np.array([s.rate_flu_radps for s in samples]) - rate
    return accel, gyro


def test_imu_white_noise_std_is_density_over_root_dt():
    white_only = dataclasses.replace(CF.imu, accel_bias_random_walk=0.0, gyro_bias_random_walk=0.0,
                                     accel_bias_initial_sigma=0.0, gyro_bias_initial_sigma=0.0)
    accel, gyro = _imu_readings(white_only, 20_000)
    dt = 1.0 / white_only.rate_hz
    # std of the sample std over n = 20000 Gaussian draws is sigma / sqrt(2n) = 0.5 %: 3 % is 6 sigma
    assert accel.std(axis=0) == pytest.approx([white_only.accel_noise_density / math.sqrt(dt)] * 3, rel=0.03)
    assert gyro.std(axis=0) == pytest.approx([white_only.gyro_noise_density / math.sqrt(dt)] * 3, rel=0.03)
    assert np.abs(accel.mean(axis=0)).max() < 5 * accel.std() / math.sqrt(len(accel))


def test_imu_bias_random_walk_increments_have_density_times_root_dt():
    walk_only = dataclasses.replace(CF.imu, accel_noise_density=0.0, gyro_noise_density=0.0)
    accel, gyro = _imu_readings(walk_only, 20_000)
    dt = 1.0 / walk_only.rate_hz
    assert np.diff(accel, axis=0).std(axis=0) == pytest.approx([walk_only.accel_bias_random_walk
                                                                 * math.sqrt(dt)] * 3, rel=0.03)
    assert np.diff(gyro, axis=0).std(axis=0) == pytest.approx([walk_only.gyro_bias_random_walk
                                                                * math.sqrt(dt)] * 3, rel=0.03)


def test_imu_bias_walk_carries_on_across_draw_blocks():
    # the biases are drawn DRAW_BLOCK samples at a time: no block may restart or jump the walk
    walk_only = dataclasses.replace(CF.imu, accel_noise_density=0.0, gyro_noise_density=0.0)
    accel, gyro = _imu_readings(walk_only, 5 * DRAW_BLOCK + 7)
    root_dt = math.sqrt(1.0 / walk_only.rate_hz)
    # 6.5 sigma: P(any of ~3800 Gaussian steps beyond it) < 1e-6
    assert np.abs(np.diff(accel, axis=0)).max() < 6.5 * walk_only.accel_bias_random_walk * root_dt
    assert np.abs(np.diff(gyro, axis=0)).max() < 6.5 * walk_only.gyro_bias_random_walk * root_dt
    imu = ImuModel(walk_only, np.random.default_rng(0))
    first = imu.accel_bias
    assert imu.sample(0.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)).specific_force_flu_mps2 == pytest.approx(first)


def test_imu_turn_on_bias_spread():
    biases = np.array([ImuModel(CF.imu, np.random.default_rng(seed)).accel_bias for seed in range(3000)])
    assert biases.std(axis=0) == pytest.approx([CF.imu.accel_bias_initial_sigma] * 3, rel=0.08)


def _imu_from_sim(sim, seconds):
    sim.run(seconds)
    return np.array([o.message.specific_force_flu_mps2 for o in sim.pop_outputs()
                     if isinstance(o.message, ImuSample)])


def test_imu_reads_plus_g_on_body_z_at_rest_and_zero_in_free_fall():
    resting = _imu_from_sim(SimVehicle(CF, np.random.default_rng(1)), 2.0)
    high = SimVehicle(CF, np.random.default_rng(1), initial_position_enu_m=(0.0, 0.0, 50.0))
    falling = _imu_from_sim(high, 2.0)
    # tolerance: turn-on bias (0.02 m/s^2, 1 sigma) plus the white noise of the mean
    assert resting.mean(axis=0) == pytest.approx([0.0, 0.0, GRAVITY_MPS2], abs=0.1)
    assert falling.mean(axis=0) == pytest.approx([0.0, 0.0, 0.0], abs=0.1)
    assert len(resting) == pytest.approx(2.0 * CF.imu.rate_hz, abs=1)


def test_mocap_noise_matches_the_room():
    mocap = MocapModel(dataclasses.replace(ROOM, dropout_probability=0.0, outlier_probability=0.0),
                       np.random.default_rng(2), body_id=7)
    truth_q = quat_from_euler_zyx(0.1, 0.2, 0.3)
    poses = [mocap.sample(k * 0.01, (1.0, 2.0, 0.5), truth_q) for k in range(10_000)]
    assert all(p.body_id == 7 for p in poses)
    errors = np.array([p.position_enu_m for p in poses]) - (1.0, 2.0, 0.5)
    assert errors.std(axis=0) == pytest.approx([ROOM.position_noise_m] * 3, rel=0.04)
    angles = np.array([rotation_angle_between(p.attitude_wxyz, truth_q) for p in poses])
    # the angle of a 3-D isotropic Gaussian rotation vector has RMS sigma * sqrt(3)
    assert math.sqrt(np.mean(angles**2)) == pytest.approx(ROOM.attitude_noise_rad * math.sqrt(3.0), rel=0.04)


@pytest.mark.parametrize("drop, outlier", [(ROOM.dropout_probability, ROOM.outlier_probability), (0.1, 0.05)])
def test_mocap_dropout_and_outlier_rates_match_the_parameters(drop, outlier):
    room = dataclasses.replace(ROOM, dropout_probability=drop, outlier_probability=outlier)
    mocap = MocapModel(room, np.random.default_rng(4), body_id=1)
    frames = 100_000 if drop < 0.01 else 20_000
    dropped = jumps = 0
    for k in range(frames):
        pose = mocap.sample(k * 0.01, (0.0, 0.0, 1.0), (1.0, 0.0, 0.0, 0.0))
        if pose is None:
            dropped += 1
            continue
        error = math.dist(pose.position_enu_m, (0.0, 0.0, 1.0))
        if error > 0.5 * room.outlier_magnitude_m:
            jumps += 1
            assert error == pytest.approx(room.outlier_magnitude_m, abs=10 * room.position_noise_m)
    # binomial counts within 4.5 standard deviations
    for count, n, p in ((dropped, frames, drop), (jumps, frames - dropped, outlier)):
        assert abs(count - n * p) <= 4.5 * math.sqrt(n * p * (1 - p)), (count, n, p)
    assert (mocap.dropouts, mocap.outliers) == (dropped, jumps)


def test_mocap_frames_carry_sample_time_and_are_released_after_the_latency():
    sim = SimVehicle(CF, np.random.default_rng(5), mocap_room=ROOM, initial_position_enu_m=(0.5, 0.0, 0.0))
    released = []
    for _ in range(1000):
        sim.step()
        for out in sim.pop_outputs():
            if out.channel == "mocap":
                assert out.release_time_s <= sim.t_s + 1e-9
                released.append(out)
    assert all(isinstance(o.message, MocapPose) for o in released)
    assert all(o.release_time_s - o.message.time_s == pytest.approx(ROOM.latency_s) for o in released)
    times = [o.message.time_s for o in released]
    assert min(np.diff(times)) == pytest.approx(1.0 / ROOM.rate_hz)
    assert len(released) == pytest.approx(1.0 * ROOM.rate_hz, abs=3)  # minus rare dropouts
    assert released[0].message.position_enu_m == pytest.approx((0.5, 0.0, 0.0), abs=5 * ROOM.position_noise_m)
