"""The error-state Kalman filter against synthetic ground truth (tests/estimator/synthetic.py).

Targets from the issue "The ground station", item 1: 1 m/s flight with default sensors: position RMS
<= 3 mm, velocity RMS <= 2 cm/s; a 0.5 s mocap blackout in hover drifts <= 5 cm, sets the health flag
and grows the covariance; injected 10 cm outliers are all rejected while >= 99 % of good frames are
accepted; NEES inside its 95 % chi-square band; late / out-of-order mocap handled by rollback is clearly
better than applying frames on arrival; lost / reordered IMU frames do not break the filter.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

sys.path.insert(0, str(Path(__file__).resolve().parent))

from synthetic import Flight, LinkFaults, circle_kinematics, flat_attitude, simulate  # noqa: E402

from estimator.eskf import ErrorStateKF, load_eskf_params  # noqa: E402
from estimator.sensor_spec import SensorSpec  # noqa: E402
from link.messages import ImuSample, MocapPose  # noqa: E402
from model.errors import ConfigError, UserError  # noqa: E402
from model.frames import attitude_error  # noqa: E402
from model.vehicle import GRAVITY_MPS2, load_mocap_room, load_vehicle  # noqa: E402

VEHICLE = load_vehicle("crazyflie")
ROOM = load_mocap_room("vicon")
# The filter is told the simulated noise exactly here: these tests check its mathematics.
SPEC = SensorSpec.matching_simulation(VEHICLE, ROOM)
CRUISE_FROM_S = 3.5  # after the 1 s hover and the 2 s speed ramp of the default Flight, plus 0.5 s


def fly(run, kf: ErrorStateKF | None = None, on_arrival: bool = False, events=None):
    """Feed the run's messages in arrival order; estimates after every IMU sample, mocap results by time.

    on_arrival: pretend each mocap frame was sampled when it arrived (the naive, uncompensated filter).
    """
    kf = kf if kf is not None else ErrorStateKF(SPEC, VEHICLE.imu.rate_hz)
    estimates, accepted = [], {}
    for arrival_s, msg in run.events if events is None else events:
        if isinstance(msg, ImuSample):
            kf.add_imu(msg)
            if kf.initialised:
                estimates.append(kf.estimate())
        else:
            if on_arrival:
                msg = dataclasses.replace(msg, time_s=arrival_s)
            accepted.setdefault(msg.time_s, kf.add_mocap(msg))
    return kf, estimates, accepted


def error_vector(truth, e) -> np.ndarray:
    """Truth minus estimate in the filter's 15-dim error coordinates (attitude: local, body frame)."""
    i = truth.index(e.time_s)
    dtheta = attitude_error(tuple(e.attitude_wxyz), tuple(truth.attitude_wxyz[i]))
    return np.concatenate([
        truth.position_enu_m[i] - e.position_enu_m,
        truth.velocity_enu_mps[i] - e.velocity_enu_mps,
        dtheta,
        truth.accel_bias_flu_mps2[i] - e.accel_bias_flu_mps2,
        truth.gyro_bias_flu_radps[i] - e.gyro_bias_flu_radps,
    ])


def rms_errors(run, estimates, t_from: float, t_to: float = math.inf) -> tuple[float, float]:
    """RMS of the 3-D position (m) and velocity (m/s) errors over sample times in [t_from, t_to)."""
    errs = np.array([error_vector(run.truth, e)[:6] for e in estimates if t_from <= e.time_s < t_to])
    return (float(np.sqrt(np.mean(np.sum(errs[:, 0:3] ** 2, axis=1)))),
            float(np.sqrt(np.mean(np.sum(errs[:, 3:6] ** 2, axis=1)))))


# ---------------------------------------------------------------------------- helpers are right


def test_synthetic_truth_obeys_rigid_body_kinematics():
    """Flatness-derived rates and specific forces agree with finite differences of the trajectory."""
    flight = Flight()
    t = np.linspace(0.5, 6.0, 2000)
    h = 1e-4
    rot, rates, force = flat_attitude(*circle_kinematics(flight, t)[2:])
    rot_next = flat_attitude(*circle_kinematics(flight, t + h)[2:])[0]
    rot_prev = flat_attitude(*circle_kinematics(flight, t - h)[2:])[0]
    rates_fd = Rotation.from_matrix(np.einsum("nji,njk->nik", rot_prev, rot_next)).as_rotvec() / (2 * h)
    assert np.max(np.abs(rates_fd - rates)) < 1e-6
    accel_fd = (circle_kinematics(flight, t + h)[1] - circle_kinematics(flight, t - h)[1]) / (2 * h)
    accel_from_force = np.einsum("nij,nj->ni", rot, force) - [0.0, 0.0, GRAVITY_MPS2]
    assert np.max(np.abs(accel_fd - accel_from_force)) < 1e-6
    assert np.allclose(force[:, :2], 0.0, atol=1e-12)  # thrust along body z only
    pos, vel, _, _ = circle_kinematics(flight, np.array([CRUISE_FROM_S]))
    assert np.isclose(np.linalg.norm(vel), flight.speed_mps) and np.isclose(pos[0, 2], flight.altitude_m)


def test_same_seed_same_bytes():
    runs = [simulate(Flight(duration_s=2.0), VEHICLE.imu, ROOM, np.random.default_rng(5)) for _ in range(2)]
    assert runs[0].events == runs[1].events
    finals = [fly(run)[0].estimate() for run in runs]
    assert finals[0].position_enu_m.tobytes() == finals[1].position_enu_m.tobytes()
    assert finals[0].covariance.tobytes() == finals[1].covariance.tobytes()


# ---------------------------------------------------------------------------- accuracy and consistency


def test_circle_at_one_metre_per_second_meets_accuracy_targets():
    run = simulate(Flight(duration_s=12.0), VEHICLE.imu, ROOM, np.random.default_rng(11))
    kf, estimates, _ = fly(run)
    pos_rms, vel_rms = rms_errors(run, estimates, CRUISE_FROM_S)
    print(f"1 m/s circle: position RMS {1e3 * pos_rms:.2f} mm, velocity RMS {1e3 * vel_rms:.2f} mm/s")
    assert pos_rms <= 0.003
    assert vel_rms <= 0.02
    assert all(e.healthy for e in estimates if e.time_s > 0.2)
    rates = np.array([e.rate_flu_radps for e in estimates if e.time_s >= CRUISE_FROM_S])
    true_rates = np.array([run.truth.rate_flu_radps[run.truth.index(e.time_s)]
                           for e in estimates if e.time_s >= CRUISE_FROM_S])
    assert np.sqrt(np.mean((rates - true_rates) ** 2)) < 3 * VEHICLE.imu.gyro_noise_density * math.sqrt(
        VEHICLE.imu.rate_hz)  # bias removed: what is left is the sample noise


def test_nees_within_chi_square_band():
    """Time- and run-averaged NEES against its 95 % band chi2.ppf([.025, .975], N dof) / N.

    Position + attitude (6 dof): sampled every `spacing` s in M independent runs, N = M K. Samples are
    effectively independent when spaced by >= 2 time constants of the slowest of these errors, the
    attitude's: a gyro random walk (density s_g) fused with mocap attitude (s_t at rate f) settles with
    tau = sqrt(r_c / q) = sqrt(s_t^2 / f / s_g^2) (scalar steady-state Kalman-Bucy filter), ~1.4 s here;
    position settles faster (tau = (r_c / q_a)^(1/4) ~ 0.2 s). Full 15 dof: the bias errors stay
    correlated for the whole run, so each run's time average counts as ONE sample (N = M): averaging
    correlated samples never widens the spread beyond that of one, so this band is conservative.
    """
    imu = VEHICLE.imu
    tau_attitude = math.sqrt(ROOM.attitude_noise_rad**2 / ROOM.rate_hz / imu.gyro_noise_density**2)
    tau_position = (ROOM.position_noise_m**2 / ROOM.rate_hz / imu.accel_noise_density**2) ** 0.25
    spacing = math.ceil(2 * max(tau_attitude, tau_position))
    runs, duration = 8, 11.0
    sample_times = np.arange(3.0, duration, spacing)  # from 3 s: the initial transient is over
    nees6, nees15 = [], []
    for seed in range(runs):
        run = simulate(Flight(duration_s=duration), imu, ROOM, np.random.default_rng(100 + seed))
        kf = ErrorStateKF(SPEC, VEHICLE.imu.rate_hz)
        pending = list(sample_times)
        run_nees15 = []
        for _, msg in run.events:
            if isinstance(msg, MocapPose):
                kf.add_mocap(msg)
                continue
            kf.add_imu(msg)
            e = kf.estimate()
            if e.time_s >= 3.0 and run.truth.index(e.time_s) % 25 == 0:  # 20 Hz for the 15-dof average
                err = error_vector(run.truth, e)
                run_nees15.append(err @ np.linalg.solve(e.covariance, err))
            if pending and e.time_s >= pending[0]:
                pending.pop(0)
                sub = [0, 1, 2, 6, 7, 8]
                err = error_vector(run.truth, e)[sub]
                nees6.append(err @ np.linalg.solve(e.covariance[np.ix_(sub, sub)], err))
        nees15.append(np.mean(run_nees15))
    n6 = len(nees6)
    band6 = chi2.ppf([0.025, 0.975], n6 * 6) / n6
    band15 = chi2.ppf([0.025, 0.975], runs * 15) / runs
    print(f"NEES pos+att {np.mean(nees6):.2f} in {band6.round(2)} (N={n6}); "
          f"15-dim {np.mean(nees15):.2f} in {band15.round(2)} (N={runs})")
    assert band6[0] <= np.mean(nees6) <= band6[1]
    assert band15[0] <= np.mean(nees15) <= band15[1]


# ---------------------------------------------------------------------------- link faults


def test_hover_blackout_drifts_little_and_is_flagged():
    start, end = 2.0, 2.5
    flight = Flight(duration_s=4.0, speed_mps=0.0)
    run = simulate(flight, VEHICLE.imu, ROOM, np.random.default_rng(21),
                   LinkFaults(mocap_blackouts_s=((start, end),), mocap_dropout_probability=0.0,
                              mocap_outlier_probability=0.0))
    kf, estimates, _ = fly(run)
    inside = [e for e in estimates if start <= e.time_s < end]
    drift = max(np.linalg.norm(error_vector(run.truth, e)[:3]) for e in inside)
    print(f"0.5 s blackout: max position error {1e3 * drift:.2f} mm")
    assert drift <= 0.05
    params = kf.params
    assert all(e.healthy and not e.health.blackout for e in estimates if 0.5 < e.time_s < start)
    flagged = [e for e in inside if e.time_s > start + params.blackout_s]
    assert flagged and all(e.health.blackout and not e.healthy for e in flagged)
    position_var = [np.trace(e.covariance[:3, :3]) for e in inside[::5]]
    assert np.all(np.diff(position_var) > 0) and position_var[-1] > 2 * position_var[0]
    assert all(e.healthy for e in estimates if e.time_s > end + 0.2)
    assert kf.health().reinitialisations == 0  # the returning frames pass the gate


def test_every_outlier_rejected_and_good_frames_accepted():
    outlier_times = tuple(np.linspace(1.5, 11.5, 50))
    run = simulate(Flight(duration_s=12.0), VEHICLE.imu, ROOM, np.random.default_rng(31),
                   LinkFaults(mocap_outlier_probability=0.0, mocap_outlier_magnitude_m=0.10,
                              mocap_outlier_times_s=outlier_times))
    assert len(run.outlier_times_s) == 50
    kf, estimates, accepted = fly(run)
    assert not any(accepted[t] for t in run.outlier_times_s)
    good = [ok for t, ok in accepted.items() if t not in run.outlier_times_s]
    print(f"outliers: 50/50 rejected, good frames accepted {100 * np.mean(good):.2f} %")
    assert np.mean(good) >= 0.99
    assert kf.health().rejected_outliers >= 50 and kf.health().reinitialisations == 0
    assert rms_errors(run, estimates, CRUISE_FROM_S)[0] <= 0.003


def test_late_and_reordered_mocap_rollback_beats_applying_on_arrival():
    faults = LinkFaults(mocap_latency_s=0.020, mocap_jitter_s=0.015, mocap_duplicate_probability=0.05)
    run = simulate(Flight(duration_s=10.0), VEHICLE.imu, ROOM, np.random.default_rng(41), faults)
    sample_times = [m.time_s for _, m in run.events if isinstance(m, MocapPose)]
    assert any(b < a for a, b in zip(sample_times, sample_times[1:], strict=False))  # really out of order
    kf, estimates, _ = fly(run)
    _, naive_estimates, _ = fly(run, on_arrival=True)
    rollback = rms_errors(run, estimates, CRUISE_FROM_S)
    on_arrival = rms_errors(run, naive_estimates, CRUISE_FROM_S)
    print(f"20 ms + jitter: rollback position RMS {1e3 * rollback[0]:.2f} mm, "
          f"on arrival {1e3 * on_arrival[0]:.2f} mm")
    assert rollback[0] <= 0.003 and rollback[1] <= 0.02
    assert on_arrival[0] > 3 * rollback[0]
    assert kf.health().duplicate_mocap > 0


def test_rollback_result_does_not_depend_on_arrival_order():
    """Once every frame is in, the filter equals one that got them all on time (same decisions and state)."""
    flight = Flight(duration_s=4.0)
    on_time = simulate(flight, VEHICLE.imu, ROOM, np.random.default_rng(51), LinkFaults(mocap_latency_s=0.0))
    late = simulate(flight, VEHICLE.imu, ROOM, np.random.default_rng(51),
                    LinkFaults(mocap_latency_s=0.02, mocap_jitter_s=0.03))
    first = min((e for e in late.events if isinstance(e[1], MocapPose)), key=lambda e: e[1].time_s)
    late_events = [first] + [e for e in late.events if e is not first]  # both start from the same pose
    a, b = fly(on_time)[0].estimate(), fly(late, events=late_events)[0].estimate()
    assert a.time_s == b.time_s
    # Equal up to the reuse of transition matrices in replays (linearised before the replay's
    # corrections): a thousandth of the filter's own standard deviation.
    assert np.all(np.abs(a.position_enu_m - b.position_enu_m) < 1e-3 * a.std_dev[0:3])
    assert np.all(np.abs(a.velocity_enu_mps - b.velocity_enu_mps) < 1e-3 * a.std_dev[3:6])
    scale = np.sqrt(np.outer(np.diag(a.covariance), np.diag(a.covariance)))  # compare as correlations
    assert np.max(np.abs(a.covariance - b.covariance) / scale) < 1e-3
    assert a.health.accepted_mocap == b.health.accepted_mocap


def test_state_does_not_depend_on_how_often_it_is_read():
    """Covariances are propagated when asked for: reading after every sample (moments-mode loop) or once per
    5 samples (attitude mode) must give the same filter, through late, reordered and lost frames."""
    faults = LinkFaults(mocap_latency_s=0.02, mocap_jitter_s=0.015, imu_loss_probability=0.02,
                        imu_swap_probability=0.02)
    run = simulate(Flight(duration_s=3.0), VEHICLE.imu, ROOM, np.random.default_rng(45), faults)
    every, sparse = ErrorStateKF(SPEC, VEHICLE.imu.rate_hz), ErrorStateKF(SPEC, VEHICLE.imu.rate_hz)
    compared = 0
    for k, (_, msg) in enumerate(run.events):
        for kf in (every, sparse):
            kf.add_imu(msg) if isinstance(msg, ImuSample) else kf.add_mocap(msg)
        if not every.initialised:
            continue
        a = every.estimate()
        if k % 5 == 0:
            b = sparse.estimate()
            assert a.time_s == b.time_s
            assert np.allclose(a.position_enu_m, b.position_enu_m, rtol=1e-12, atol=0.0)
            assert np.allclose(a.covariance, b.covariance, rtol=1e-12, atol=1e-30)
            assert a.health == b.health
            compared += 1
    assert compared > 100 and every.health().reordered_imu > 0


def test_estimate_is_cached_until_new_input_and_complete():
    run = simulate(Flight(duration_s=1.0), VEHICLE.imu, ROOM, np.random.default_rng(47))
    kf, _, _ = fly(run)
    first = kf.estimate()
    assert kf.estimate() is first
    # Every field is set (the estimate is built without the dataclass __init__) and it stays frozen.
    assert set(vars(first)) == {f.name for f in dataclasses.fields(first)}
    assert set(vars(first.health)) == {f.name for f in dataclasses.fields(first.health)}
    assert dataclasses.replace(first.health) == first.health
    with pytest.raises(dataclasses.FrozenInstanceError):
        first.time_s = 0.0
    # A counter-only change (a rejected NaN sample) is new input too.
    kf.add_imu(ImuSample(first.time_s + 0.002, (math.nan, 0.0, GRAVITY_MPS2), (0.0, 0.0, 0.0)))
    second = kf.estimate()
    assert second is not first and second.health.invalid_imu == first.health.invalid_imu + 1
    assert second.time_s == first.time_s
    kf.add_imu(ImuSample(first.time_s + 0.002, (0.0, 0.0, GRAVITY_MPS2), (0.0, 0.0, 0.0)))
    assert kf.estimate().time_s == first.time_s + 0.002


def test_lost_and_reordered_imu_frames_do_not_break_it():
    faults = LinkFaults(imu_loss_probability=0.05, imu_loss_bursts=5, imu_burst_length=10,
                        imu_swap_probability=0.05)
    run = simulate(Flight(duration_s=10.0), VEHICLE.imu, ROOM, np.random.default_rng(61), faults)
    kf, estimates, _ = fly(run)
    pos_rms, vel_rms = rms_errors(run, estimates, CRUISE_FROM_S)
    print(f"IMU loss/reorder: position RMS {1e3 * pos_rms:.2f} mm, velocity RMS {1e3 * vel_rms:.2f} mm/s")
    assert pos_rms <= 0.003 and vel_rms <= 0.02
    health = kf.health()
    received = {m.time_s for _, m in run.events if isinstance(m, ImuSample)}
    lost = [t for t in run.truth.time_s if t not in received]
    settled = [t for t in lost if t < run.truth.time_s[-1] - 2 * kf.params.buffer_length_s]
    assert health.reordered_imu > 0 and health.imu_gaps > 0
    assert len(settled) <= health.lost_imu <= len(lost)


def test_consecutive_rejections_lead_to_reinitialisation():
    """The mocap origin jumps 0.3 m at 3 s: the filter rejects, then re-initialises onto the new frames."""
    shift = np.array([0.3, 0.0, 0.0])
    run = simulate(Flight(duration_s=6.0), VEHICLE.imu, ROOM, np.random.default_rng(71),
                   LinkFaults(mocap_dropout_probability=0.0, mocap_outlier_probability=0.0))
    events = [(a, dataclasses.replace(m, position_enu_m=tuple(np.add(m.position_enu_m, shift))))
              if isinstance(m, MocapPose) and m.time_s >= 3.0 else (a, m) for a, m in run.events]
    kf, estimates, _ = fly(run, events=events)
    params = kf.params
    assert kf.health().reinitialisations == 1
    assert kf.health().rejected_outliers == params.reinit_after_rejections
    final = kf.estimate()
    truth_now = run.truth.position_enu_m[run.truth.index(final.time_s)]
    assert np.linalg.norm(final.position_enu_m - (truth_now + shift)) < 0.003


def test_long_blackout_then_moved_frame_reinitialises_at_once():
    shift = np.array([0.0, 0.2, 0.0])
    run = simulate(Flight(duration_s=6.0, speed_mps=0.0), VEHICLE.imu, ROOM, np.random.default_rng(81),
                   LinkFaults(mocap_blackouts_s=((2.0, 3.5),), mocap_dropout_probability=0.0,
                              mocap_outlier_probability=0.0))
    events = [(a, dataclasses.replace(m, position_enu_m=tuple(np.add(m.position_enu_m, shift))))
              if isinstance(m, MocapPose) and m.time_s >= 3.5 else (a, m) for a, m in run.events]
    kf, _, accepted = fly(run, events=events)
    first_back = min(t for t in accepted if t >= 3.5)
    assert accepted[first_back] and kf.health().reinitialisations == 1 and kf.health().rejected_outliers == 0


def test_predict_to_compensates_latency_without_touching_the_filter():
    run = simulate(Flight(duration_s=5.0), VEHICLE.imu, ROOM, np.random.default_rng(91))
    kf, _, _ = fly(run, events=[e for e in run.events if e[1].time_s < 4.5])
    now = kf.estimate()
    ahead = kf.predict_to(now.time_s + 0.02)
    again = kf.estimate()
    assert np.array_equal(now.position_enu_m, again.position_enu_m)
    assert np.array_equal(now.covariance, again.covariance)
    repeated = kf.predict_to(now.time_s + 0.02)  # estimate() is cached: this catches a filter touched in place
    assert np.array_equal(repeated.position_enu_m, ahead.position_enu_m)
    assert np.array_equal(repeated.covariance, ahead.covariance)
    truth_ahead = run.truth.position_enu_m[run.truth.index(now.time_s + 0.02)]
    assert np.linalg.norm(ahead.position_enu_m - truth_ahead) < 0.002
    assert np.linalg.norm(now.position_enu_m - truth_ahead) > 0.015  # 20 ms at 1 m/s
    assert np.trace(ahead.covariance[:3, :3]) > np.trace(now.covariance[:3, :3])


# ---------------------------------------------------------------------------- edges and bad input


def test_before_the_first_pose_nothing_is_claimed():
    kf = ErrorStateKF(SPEC, VEHICLE.imu.rate_hz)
    kf.add_imu(ImuSample(0.0, (0.0, 0.0, GRAVITY_MPS2), (0.0, 0.0, 0.0)))
    e = kf.estimate()
    assert not e.healthy and not e.health.initialised and np.all(np.isnan(e.position_enu_m))


def test_first_pose_initialises_at_rest_and_duplicates_stale_invalid_are_counted():
    kf = ErrorStateKF(SPEC, VEHICLE.imu.rate_hz)
    assert kf.add_mocap(MocapPose(1.0, 1, (0.5, -0.2, 1.0), (1.0, 0.0, 0.0, 0.0)))
    hover = ImuSample(1.002, (0.0, 0.0, GRAVITY_MPS2), (0.0, 0.0, 0.0))
    kf.add_imu(hover)
    kf.add_imu(hover)
    kf.add_imu(ImuSample(0.5, (0.0, 0.0, GRAVITY_MPS2), (0.0, 0.0, 0.0)))
    kf.add_imu(ImuSample(1.004, (math.nan, 0.0, GRAVITY_MPS2), (0.0, 0.0, 0.0)))
    assert not kf.add_mocap(MocapPose(1.0, 1, (0.5, -0.2, 1.0), (1.0, 0.0, 0.0, 0.0)))
    assert not kf.add_mocap(MocapPose(0.2, 1, (0.5, -0.2, 1.0), (1.0, 0.0, 0.0, 0.0)))
    assert not kf.add_mocap(MocapPose(1.001, 1, (0.5, -0.2, 1.0), (0.0, 0.0, 0.0, 0.0)))
    h = kf.health()
    assert (h.duplicate_imu, h.stale_imu, h.invalid_imu) == (1, 1, 1)
    assert (h.duplicate_mocap, h.stale_mocap, h.invalid_mocap) == (1, 1, 1)
    e = kf.estimate()
    assert np.allclose(e.position_enu_m, (0.5, -0.2, 1.0), atol=1e-6)
    assert np.allclose(e.velocity_enu_mps, 0.0, atol=1e-6)
    with pytest.raises(UserError, match="quaternion"):
        kf.initialise(MocapPose(2.0, 1, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0)))


def test_bad_parameter_file_gives_one_line_config_error(tmp_path):
    text = Path(load_eskf_params().source).read_text()
    broken = tmp_path / "eskf.toml"
    broken.write_text(text.replace("chi2_probability = 0.99999", "chi2_probability = 2.0"))
    with pytest.raises(ConfigError) as err:
        load_eskf_params(broken)
    assert str(broken) in str(err.value) and "gating.chi2_probability" in str(err.value)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("imu_latency_s", [0.023, 0.05])
def test_downlink_slower_than_mocap_keeps_every_good_frame(imu_latency_s):
    """A radio of 20-50 ms behind a 5 ms Vicon: mocap frames arrive before the IMU samples of their time.

    They must wait for the IMU stream and be gated on it then, not rejected as outliers.
    """
    faults = LinkFaults(imu_latency_s=imu_latency_s, mocap_outlier_probability=0.0)
    run = simulate(Flight(duration_s=10.0), VEHICLE.imu, ROOM, np.random.default_rng(71), faults)
    kf, estimates, _ = fly(run)
    pos_rms, vel_rms = rms_errors(run, estimates, CRUISE_FROM_S)
    health = kf.health()
    sent = sum(1 for _, m in run.events if not isinstance(m, ImuSample))
    assert health.rejected_outliers == 0 and health.reinitialisations == 0
    assert health.accepted_mocap >= sent - 2  # at most the frames newer than the last IMU sample wait
    assert pos_rms <= 0.003 and vel_rms <= 0.02
