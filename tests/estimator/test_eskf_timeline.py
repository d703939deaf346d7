"""The estimator's timeline (issue 19): the compiled twin (estimator/_eskf_timeline.h, in
estimator._eskf_kernels) gives the Python twin's bits (estimator/eskf_timeline.py), estimate for estimate,
gate decision for gate decision and counter for counter, over filtered flights that take every path of the
bookkeeping: late, jittered and reordered mocap frames (rollback and replay), frames from the future (held,
then released by the IMU stream), lost IMU bursts (sub-stepped intervals, gaps counted at the trim), swapped
IMU samples (insertion), duplicates, stale and invalid samples, outliers, re-initialisation after rejections
and after a blackout, poses before the first IMU sample, a restart mid-flight, and predict_to."""

from __future__ import annotations

import dataclasses
import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from synthetic import Flight, LinkFaults, simulate  # noqa: E402

from estimator import eskf  # noqa: E402
from estimator.eskf import ErrorStateKF, EstimatorHealth  # noqa: E402
from estimator.eskf_timeline import COUNTERS, INVALID, N_ERROR, N_VALUES, NOT_STARTED, TAKEN, Timeline  # noqa: E402
from estimator.sensor_spec import SensorSpec  # noqa: E402
from link.messages import ImuSample, MocapPose  # noqa: E402
from model.vehicle import GRAVITY_MPS2, load_mocap_room, load_vehicle  # noqa: E402

VEHICLE = load_vehicle("crazyflie")
ROOM = load_mocap_room("vicon")
SPEC = SensorSpec.matching_simulation(VEHICLE, ROOM)

needs_compiled = pytest.mark.skipif(
    eskf.CompiledTimeline is None,
    reason="estimator/_eskf_kernels.c was not built (no C compiler at pip install): the Python twin runs")


def _estimate_bytes(e) -> bytes:
    return b"".join(np.asarray(v).tobytes() for v in (
        e.time_s, e.position_enu_m, e.velocity_enu_mps, e.attitude_wxyz, e.rate_flu_radps, e.accel_bias_flu_mps2,
        e.gyro_bias_flu_radps, e.covariance, e.std_dev, e.healthy)) + repr(e.health).encode()


def _trace(events, timeline: type, restart_at_s: float | None = None) -> list:
    """Everything the filter gives for the events in arrival order: each add_mocap's answer, the estimate
    after each IMU sample and, every 25th sample, a prediction 20 ms ahead; a restart at the first pose
    after restart_at_s (as the mission's reset does)."""
    kf = ErrorStateKF(SPEC, VEHICLE.imu.rate_hz, timeline=timeline)
    out = []
    for n, (_, msg) in enumerate(events):
        if isinstance(msg, ImuSample):
            kf.add_imu(msg)
            out.append(_estimate_bytes(kf.estimate()))
            if n % 25 == 0:
                out.append(_estimate_bytes(kf.predict_to(msg.time_s + 0.02)))
        elif restart_at_s is not None and msg.time_s >= restart_at_s:
            out.append(kf.health())  # what the restart clears
            kf.initialise(msg)
            restart_at_s = None
            out.append(_estimate_bytes(kf.estimate()))
        else:
            out.append(kf.add_mocap(msg))
    out.append(kf.health())
    return out


def _shifted(events, from_s: float, shift) -> list:
    """The mocap frames from from_s on moved by `shift` (m): the room's origin jumps."""
    return [(a, dataclasses.replace(m, position_enu_m=tuple(np.add(m.position_enu_m, shift))))
            if isinstance(m, MocapPose) and m.time_s >= from_s else (a, m) for a, m in events]


def _hostile(events) -> list:
    """Invalid, stale and repeated samples mixed in, and poses before the first IMU sample."""
    imu = [(a, m) for a, m in events if isinstance(m, ImuSample)]
    poses = [(a, m) for a, m in events if isinstance(m, MocapPose)]
    nan_imu = dataclasses.replace(imu[40][1], specific_force_flu_mps2=(math.nan, 0.0, GRAVITY_MPS2))
    zero_pose = dataclasses.replace(poses[30][1], attitude_wxyz=(0.0, 0.0, 0.0, 0.0))
    extra = [(imu[40][0], nan_imu), (poses[30][0], zero_pose), (imu[300][0], imu[100][1]),  # stale
             (imu[301][0], imu[299][1]), (poses[40][0], poses[38][1]), (poses[41][0], poses[2][1])]  # repeats
    early = [(-0.01, dataclasses.replace(poses[0][1], time_s=poses[0][1].time_s - 0.004 * k)) for k in (3, 1, 2)]
    return early + sorted(events + extra, key=lambda e: e[0])


CASES = {
    "late, jittered and reordered mocap; lost and swapped IMU": (
        LinkFaults(mocap_latency_s=0.020, mocap_jitter_s=0.015, imu_loss_bursts=4, imu_swap_probability=0.02,
                   imu_loss_probability=0.02), 3, None, None),
    "frames from the future, duplicates, dropouts": (
        LinkFaults(imu_latency_s=0.023, mocap_duplicate_probability=0.05, mocap_dropout_probability=0.05), 5, None,
        None),
    "outliers, then rejections until re-initialisation": (
        LinkFaults(mocap_outlier_probability=0.03, mocap_latency_s=0.012), 7, (3.0, (0.3, 0.0, 0.0)), None),
    "a blackout, a moved room, a restart": (
        LinkFaults(mocap_blackouts_s=((1.5, 2.8),), mocap_jitter_s=0.012), 11, (2.8, (0.0, 0.2, 0.0)), 3.6),
}


@needs_compiled
@pytest.mark.parametrize("case", list(CASES))
def test_compiled_timeline_gives_the_python_twins_bits(case):
    faults, seed, jump, restart_at_s = CASES[case]
    run = simulate(Flight(duration_s=4.5), VEHICLE.imu, ROOM, np.random.default_rng(seed), faults)
    events = _hostile(run.events)
    if jump is not None:
        events = _shifted(events, *jump)
    compiled = _trace(events, eskf.CompiledTimeline, restart_at_s)
    python = _trace(events, Timeline, restart_at_s)
    assert len(compiled) == len(python) > 2000
    first_difference = next((i for i, (a, b) in enumerate(zip(compiled, python, strict=True)) if a != b), None)
    assert first_difference is None, (case, first_difference)
    health = python[-1]
    before_restart = next((h for h in python[:-1] if isinstance(h, EstimatorHealth)), health)
    for h in (before_restart, health):
        print(case, {name: getattr(h, name) for name in COUNTERS if getattr(h, name)})
    # the paths the case is for were taken (the counters are the twins' own, checked equal above; a restart
    # sets them to 0, after the hostile samples of the first second)
    if restart_at_s is None:
        assert health.invalid_imu == 1 and health.invalid_mocap == 1 and health.duplicate_mocap >= 1
        assert health.stale_imu + health.duplicate_imu >= 1
    if faults.imu_loss_bursts:
        assert health.imu_gaps > 0 and health.reordered_imu > 0
    if jump is not None:
        assert before_restart.reinitialisations >= 1
    if faults.mocap_outlier_probability:
        assert health.rejected_outliers > health.reinitialisations


@needs_compiled
def test_both_twins_raise_numpys_linalg_error_on_an_update_that_cannot_be_made():
    """R with negative variances: S = H P H' + R is not positive definite at the first frame fused."""
    run = simulate(Flight(duration_s=0.5), VEHICLE.imu, ROOM, np.random.default_rng(1),
                   LinkFaults(mocap_latency_s=0.01))
    for timeline in (eskf.CompiledTimeline, Timeline):
        kf = ErrorStateKF(SPEC, VEHICLE.imu.rate_hz, timeline=timeline)
        config = dataclasses.replace(kf.config, r_diag=(-1.0,) * 6)
        kf._timeline = timeline(config)
        with pytest.raises(np.linalg.LinAlgError, match="not positive definite"):
            for _, msg in run.events:
                kf.add_imu(msg) if isinstance(msg, ImuSample) else kf.add_mocap(msg)


@needs_compiled
def test_compiled_timeline_refuses_bad_calls_with_one_error():
    kf = ErrorStateKF(SPEC, VEHICLE.imu.rate_hz)
    timeline = eskf.CompiledTimeline(kf.config)
    assert timeline.empty and not timeline.started
    with pytest.raises(RuntimeError, match="empty"):
        timeline.add_imu(0.0, (0.0, 0.0, 9.8), (0.0, 0.0, 0.0))
    with pytest.raises(RuntimeError, match="empty"):
        timeline.newest(np.empty((N_ERROR, N_ERROR)))
    with pytest.raises(RuntimeError, match="empty"):
        timeline.newest_state(np.empty((N_ERROR, N_ERROR)), np.empty(N_VALUES), np.empty(N_ERROR))
    with pytest.raises(ValueError, match="x: expected 16 numbers"):
        timeline.initialise(0.0, (0.0,) * 15)
    timeline.initialise(0.0, (0.0,) * 6 + (1.0,) + (0.0,) * 9)
    with pytest.raises(RuntimeError, match="has not started"):
        timeline.add_mocap(0.001, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0))
    timeline.add_imu(0.002, (0.0, 0.0, 9.8), (0.0, 0.0, 0.0))
    assert timeline.started
    with pytest.raises(ValueError, match="f: expected 3 numbers"):
        timeline.add_imu(0.004, (0.0, 9.8), (0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="P_out must be a C-contiguous float64 array of 225"):
        timeline.newest(np.empty((N_ERROR, N_ERROR), dtype=np.float32))
    with pytest.raises(ValueError, match="values_out must be a C-contiguous float64 array of 19"):
        timeline.newest_state(np.empty((N_ERROR, N_ERROR)), np.empty(16), np.empty(N_ERROR))
    with pytest.raises(TypeError):
        timeline.newest_state(np.empty((N_ERROR, N_ERROR)), np.empty(N_VALUES))
    with pytest.raises(TypeError):
        timeline.add_mocap(0.001, (0.0, 0.0, 0.0))
    with pytest.raises(IndexError):
        timeline.count(len(COUNTERS))
    with pytest.raises(AttributeError):
        eskf.CompiledTimeline(object())  # not a TimelineConfig


@pytest.mark.parametrize("twin", ["compiled", "python"])
def test_samples_as_they_arrive_are_checked_the_same_by_both_twins(twin):
    """add_imu_sample / add_mocap_pose: a vector of the wrong length or a number not finite is invalid
    (counted, nothing else done), a sample that is not one raises, and before the first IMU sample they
    say so instead of adding."""
    if twin == "compiled" and eskf.CompiledTimeline is None:
        pytest.skip("estimator/_eskf_kernels.c was not built: no compiled twin")
    timeline = (eskf.CompiledTimeline if twin == "compiled" else Timeline)(ErrorStateKF(SPEC, 500.0).config)
    hover = ImuSample(0.002, (0.0, 0.0, GRAVITY_MPS2), (0.0, 0.0, 0.0))
    pose = MocapPose(0.003, 1, (0.5, -0.2, 1.0), (1.0, 0.0, 0.0, 0.0))
    assert timeline.add_imu_sample(hover) == NOT_STARTED and timeline.add_mocap_pose(pose) is None
    timeline.initialise(0.0, (0.5, -0.2, 1.0, 0.0, 0.0, 0.0, 1.0) + (0.0,) * 9)
    assert timeline.add_imu_sample(hover) == NOT_STARTED  # the first sample is placed by the caller (add_imu)
    timeline.add_imu(hover.time_s, hover.specific_force_flu_mps2, hover.rate_flu_radps)
    assert timeline.started and timeline.add_imu_sample(dataclasses.replace(hover, time_s=0.0025)) == TAKEN
    assert timeline.add_mocap_pose(pose) is True  # newer than the newest sample: held, decided later
    bad_imu = [dataclasses.replace(hover, time_s=0.0026, specific_force_flu_mps2=(0.0, GRAVITY_MPS2)),
               dataclasses.replace(hover, time_s=0.0026, rate_flu_radps=(0.0, math.inf, 0.0)),
               dataclasses.replace(hover, time_s=math.nan)]
    assert [timeline.add_imu_sample(s) for s in bad_imu] == [INVALID] * 3
    bad_poses = [dataclasses.replace(pose, time_s=0.001, attitude_wxyz=(0.0, 0.0, 0.0, 0.0)),
                 dataclasses.replace(pose, time_s=0.001, attitude_wxyz=(1.0, 0.0, 0.0)),
                 dataclasses.replace(pose, time_s=0.001, position_enu_m=(0.5, math.nan, 1.0))]
    assert [timeline.add_mocap_pose(p) for p in bad_poses] == [False] * 3
    counts = timeline.health_values()[3]
    assert list(counts) == list(COUNTERS)
    assert counts["invalid_imu"] == 3 and counts["invalid_mocap"] == 3
    with pytest.raises(TypeError):
        timeline.add_imu_sample(dataclasses.replace(hover, time_s=0.0026, rate_flu_radps=(None, 0.0, 0.0)))
    with pytest.raises(TypeError):  # a number as text is not a number to either twin
        timeline.add_imu_sample(dataclasses.replace(hover, time_s="0.0026"))
    with pytest.raises(TypeError):
        timeline.add_mocap_pose(dataclasses.replace(pose, time_s=0.001, position_enu_m=("0.5", 0.0, 1.0)))
    # the lengths are checked first: a vector of the wrong length is invalid, whatever it holds
    assert timeline.add_imu_sample(dataclasses.replace(hover, time_s=None, rate_flu_radps=(None,))) == INVALID
    assert timeline.add_mocap_pose(dataclasses.replace(pose, time_s=None, attitude_wxyz=("1",))) is False
    with pytest.raises(AttributeError):
        timeline.add_mocap_pose(hover)  # not a pose


@pytest.mark.parametrize("twin", ["compiled", "python"])
def test_newest_state_is_the_newest_node_with_the_bias_corrected_rate_and_the_standard_deviations(twin):
    """newest_state by its definition, from newest() and health_values() of the same twin: the covariance,
    the nominal state, then the newest gyro sample minus the gyro bias (minus the bias alone before the first
    sample), the square root of each variance, and the health values after the newest node's time."""
    if twin == "compiled" and eskf.CompiledTimeline is None:
        pytest.skip("estimator/_eskf_kernels.c was not built: no compiled twin")
    timeline = (eskf.CompiledTimeline if twin == "compiled" else Timeline)(ErrorStateKF(SPEC, 500.0).config)
    gyro_bias = (0.01, -0.02, 0.03)
    timeline.initialise(0.0, (0.5, -0.2, 1.0, 0.0, 0.0, 0.0, 1.0) + (0.0,) * 6 + gyro_bias)

    def check(rate_expected):
        P, values, std = np.empty((N_ERROR, N_ERROR)), np.empty(N_VALUES), np.empty(N_ERROR)
        t, last_accepted_s, in_a_row, counts = timeline.newest_state(P, values, std)
        P_newest = np.empty((N_ERROR, N_ERROR))
        t_newest, x, _ = timeline.newest(P_newest)
        assert t == t_newest and np.array_equal(P, P_newest) and values[:16].tolist() == list(x)
        assert values[16:].tolist() == [rate_expected[i] - x[13 + i] for i in range(3)]
        assert std.tolist() == [math.sqrt(P_newest[i, i]) for i in range(N_ERROR)]
        assert (t, last_accepted_s, in_a_row, counts) == (t, *timeline.health_values()[1:])

    check((0.0, 0.0, 0.0))  # no IMU sample yet: the rate is -b_g
    rate = (0.4, -0.3, 0.2)
    for k in range(1, 6):
        timeline.add_imu(0.002 * k, (0.0, 0.0, GRAVITY_MPS2), rate)
    timeline.add_mocap(0.009, (0.5, -0.2, 1.0), (1.0, 0.0, 0.0, 0.0))
    check(rate)
