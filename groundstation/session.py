"""A whole flight session: build the pieces, fly the mission, grade it, write the logs.

Takes in: SessionOptions (connection, vehicle id, mode, rate, clock, trajectory or planned world, log dir).
Gives out: the summary dict (the `--json` object of `cfstack fly`; groundstation.grading says what is in
it), written to summary.json too, and the human summary (only figures that mean something for the flight).
Grading uses simulator truth when the link provides it (simulation only); control never does.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from estimator import eskf_kernels
from estimator.eskf import ErrorStateKF
from estimator.sensor_spec import SensorSpec, load_sensor_spec, subsampled
from groundstation import compensation_kernel, controller_kernel
from groundstation.clocks import DEFAULT_RATE_HZ, LockstepClock, RealtimeClock
from groundstation.compensation import LatencyCompensator
from groundstation.controller import SE3Controller, load_gains
from groundstation.flight import FlightLoop
from groundstation.flightlog import FlightLog, default_log_dir
from groundstation.grading import (
    TRACKING_PHASES,
    course_grade,
    failure,
    load_course_rules,
    min_clearance,
    rms,
    stack3,
)
from groundstation.mission import Mission, load_mission_params
from groundstation.tickframe import Displays
from groundstation.trajectory import Trajectory
from groundstation.vehicle_link import VehicleLink
from link import deliver_kernel
from link.keys import VehicleKeys
from link.mavlink import frame_kernel
from link.mavlink.codec import ActuatorLimits
from link.transports import open_transport
from link.transports.zenoh_process import use_lockstep_settings
from model.vehicle import load_vehicle
from model.world import World

log = logging.getLogger("cfstack.groundstation")

# The course tests np.array_equal(start, end): a closed trajectory's end may differ from its start by rounding.
COURSE_SAME_POINT_M = 1e-9


@dataclass
class SessionOptions:
    track: Trajectory
    goal_enu_m: np.ndarray
    world: World | None = None
    mode: str = "moments"
    rate_hz: float | None = None
    clock: str = "lockstep"
    connection: str = "zenoh"
    zenoh_options: dict = field(default_factory=dict)
    radio_link: str | None = None  # the radio's own connection string (udp, serial...); None: `connection`
    link: str = "mavlink"  # the radio's protocol: mavlink, or crtp (a Crazyflie through cflib, at crtp_uri)
    crtp_uri: str | None = None
    prefix: str = "cfstack"
    vehicle_id: int = 1
    vehicle_model: str = "crazyflie"
    # what the filter assumes of IMU and mocap (estimator/params/sensors)
    sensor_spec: SensorSpec = field(default_factory=load_sensor_spec)
    gains: str = "gains"
    controller_variant: str | None = None  # None: the gains file's
    latency_compensation: bool = False
    log_dir: Path | None = None
    signing: object | None = None
    extra_summary: dict = field(default_factory=dict)
    plan: dict | None = None
    peer_failure: object = None  # callable: why the emulator child stopped, or None while it runs
    allow_reset: bool = False  # a vehicle already CRASHED at the start may be asked to reboot (--reset)
    extpose: bool = False  # forward each mocap pose to the vehicle (ExternalPose) for its onboard estimator
    displays: Displays = field(default_factory=Displays)
    user_code: object = None  # groundstation.usercode.host.UserCode: the user's controller/trajectory/planner


@dataclass
class SessionResult:
    summary: dict
    record: object  # flight.FlightRecord: per-tick reference, estimate and truth


def run_session(opts: SessionOptions) -> SessionResult:
    rate = opts.rate_hz or DEFAULT_RATE_HZ[opts.mode]
    period = 1.0 / rate
    vehicle = load_vehicle(opts.vehicle_model)
    params = load_mission_params()
    world = opts.world
    log_dir = Path(opts.log_dir) if opts.log_dir else default_log_dir()
    keys = VehicleKeys(opts.prefix, opts.vehicle_id)
    use_lockstep_settings(opts.clock == "lockstep")  # before the first zenoh session (link.transports.zenoh_process)
    wall_start = time.monotonic()
    with FlightLog(log_dir) as flight_log:
        if opts.plan is not None:
            flight_log.write_json("plan.json", opts.plan)
        clock_box: dict = {}
        observers: list = []
        crazyflie = _crazyflie_radio(opts, lambda: clock_box["clock"].now()) if opts.link == "crtp" else None
        try:
            link = VehicleLink(opts.connection, keys, ActuatorLimits.from_vehicle(vehicle),
                               clock=lambda: clock_box["clock"].now(), zenoh_options=opts.zenoh_options,
                               signing=opts.signing, tlog_path=flight_log.tlog_path,
                               shared_clock=opts.clock == "lockstep", radio_link=opts.radio_link, radio=crazyflie)
        except BaseException:
            if crazyflie is not None:
                crazyflie.close()
            raise
        imu_rate_hz = vehicle.imu.rate_hz if crazyflie is None else 1000.0 / crazyflie.settings.imu_period_ms
        try:
            if opts.clock == "lockstep":
                clock_transport = open_transport(opts.connection, tx=keys.clock_ack, rx=keys.clock,
                                                 **opts.zenoh_options)
                clock = LockstepClock(period, link, clock_transport, peer_failure=opts.peer_failure)
            else:
                clock_transport = None
                clock = RealtimeClock(period, link)
            clock_box["clock"] = clock
            # a log block's IMU is every n-th sample of the vehicle's: each carries that sample's noise
            estimator = ErrorStateKF(subsampled(opts.sensor_spec, vehicle.imu.rate_hz, imu_rate_hz), imu_rate_hz)
            missing = [name for name, compiled in (("the estimator's kernels and timeline", eskf_kernels.COMPILED),
                                                   ("the latency compensator's steps", compensation_kernel.COMPILED),
                                                   ("the controller's report law", controller_kernel.COMPILED),
                                                   ("the MAVLink frames' encoder and parser", frame_kernel.COMPILED),
                                                   ("the link's per-frame delivery", deliver_kernel.COMPILED))
                       if not compiled]
            if missing:
                log.warning("ground station: %s not built (no C compiler at pip install?): the Python twins run, "
                            "same results, slower (README: Lockstep speed)", ", ".join(missing))
            gains = load_gains(opts.gains)
            controller = SE3Controller(vehicle, gains, variant=opts.controller_variant)
            if opts.user_code is not None:  # the user's SE3Control; ours stays as its failsafe
                controller = opts.user_code.controller_for(vehicle, controller, opts.mode, log_dir)
            mission = Mission(params, opts.track, opts.goal_enu_m, world, vehicle.collision_radius_m,
                              allow_reset=opts.allow_reset)
            if opts.user_code is not None:
                opts.user_code.attach(mission, period if opts.clock == "realtime" else None)
            compensator = LatencyCompensator(vehicle, opts.mode, period) if opts.latency_compensation else None
            observers = _open_displays(opts, log_dir, mission, rate, gains)
            loop = FlightLoop(link, clock, estimator, controller, mission, params, flight_log, opts.mode, period,
                              compensator, extpose=opts.extpose, observers=tuple(observers))
            with opts.user_code.guard if opts.user_code is not None else contextlib.nullcontext():
                loop.run()
        finally:
            if opts.user_code is not None:
                opts.user_code.close()
            link.close()
            for observer in observers:
                observer.close()
            if clock_transport is not None:
                clock_transport.close()
        summary = grade(loop, opts, params, log_dir, time.monotonic() - wall_start)
        flight_log.write_json("summary.json", summary)
    return SessionResult(summary, loop.record)


def grade(loop: FlightLoop, opts: SessionOptions, params, log_dir: Path, wall_s: float) -> dict:
    rec, mission = loop.record, loop.mission
    t, phase = np.array(rec.t), np.array(rec.phase)
    ref, est, est_vel = stack3(rec.ref), stack3(rec.est), stack3(rec.est_vel)
    truth, truth_vel, truth_att = stack3(rec.truth), stack3(rec.truth_vel), stack3(rec.truth_att, 4)
    have_truth = bool(np.isfinite(truth).all(axis=1).any())
    flown, flown_vel = (truth, truth_vel) if have_truth else (est, est_vel)
    tracking = np.isin(phase, TRACKING_PHASES)
    err = np.linalg.norm(flown - ref, axis=1)
    err_tracking = err[tracking & np.isfinite(err)]
    goal = np.asarray(opts.goal_enu_m, float)
    reached_at = _reached_goal_at(t, flown, flown_vel, goal, mission, params)
    result = mission.result or "aborted"
    if result == "reached_goal" and reached_at is None:
        result = "timeout"  # the mission thought so from its estimate, but the truth never got there
    travels = mission.arrival_s > 0.0  # the reference leaves the goal at some point (not a hover)
    starts_at_goal = bool(np.linalg.norm(mission.track.sample(0.0).position_m - goal) <= COURSE_SAME_POINT_M)
    flight_over = _flight_over_s(t, phase)
    # a crash is a collision in flight unless it is the landing's, after the mission's result was decided
    crashed = rec.crash is not None or mission.crash_seen is not None
    crashed_in_flight = crashed and mission.landing.result != "crashed"
    summary = {
        "result": result,
        "reached_goal": result == "reached_goal",
        "collided": crashed_in_flight,
        "time_to_goal_s": (reached_at - mission.track_start_s if reached_at is not None and travels else None),
        "mission": {"result": result, "reached_goal": result == "reached_goal",
                    "collision_in_flight": crashed_in_flight, "failsafe_reason": mission.failsafe_reason,
                    "vehicle_resets": mission.resets},
        "landing": dataclasses.asdict(mission.landing),
        "failure": failure(mission, rec.crash, t, phase, est),
        **min_clearance(opts.world, t, phase, truth),
        "course_grade": course_grade(load_course_rules(), opts.world, t, truth, truth_vel, truth_att, goal,
                                     mission.track.sample(mission.track.duration_s).yaw_rad, mission.track_start_s,
                                     starts_at_goal, flight_over),
        "rms_tracking_error_m": rms(err_tracking),
        "max_tracking_error_m": float(err_tracking.max()) if err_tracking.size else None,
        "final_position_error_m": _final_error(phase, flown, goal),
        "path_length_m": _path_length(flown[tracking & np.isfinite(flown).all(axis=1)]),
        "estimator": _estimator_errors(rec, phase, est, est_vel) | _estimator_counts(loop.estimator),
        "link": _link_summary(loop),
        "mode": opts.mode,
        "latency_compensation": opts.latency_compensation,
        "clock": opts.clock,
        "failsafe_reason": mission.failsafe_reason,
        "sim_time_s": float(t[-1]) if t.size else 0.0,
        "wall_time_s": wall_s,
        "log_dir": str(log_dir),
    }
    summary["flight_time_s"] = summary["time_to_goal_s"]  # the name earlier summaries (and sweeps) used
    summary["timing"] = _timing(loop, opts, summary["sim_time_s"])
    if opts.user_code is not None:
        summary["user_code"] = opts.user_code.summary()
    summary.update(opts.extra_summary)
    return summary


def _reached_goal_at(t, flown, flown_vel, goal, mission, params) -> float | None:
    """The first time after the track's arrival time at which the flown position is within the goal
    tolerances (truth when the link has it, else the estimate)."""
    if mission.track_start_s is None:
        return None
    after = (t >= mission.track_start_s + mission.arrival_s) & np.isfinite(flown).all(axis=1)
    near = np.linalg.norm(flown - goal, axis=1) <= params.goal_position_tolerance_m
    slow = np.linalg.norm(flown_vel, axis=1) <= params.goal_speed_tolerance_mps
    hits = np.flatnonzero(after & near & slow)
    return float(t[hits[0]]) if hits.size else None


def _flight_over_s(t: np.ndarray, phase: np.ndarray) -> float:
    """When the flight proper ended: the first tick of landing (or of the end), else the last tick."""
    over = np.flatnonzero(np.isin(phase, ("land", "vehicle_land", "disarm", "done", "failsafe_descent")))
    return float(t[over[0]]) if over.size else (float(t[-1]) if t.size else 0.0)


def _final_error(phase: np.ndarray, flown: np.ndarray, goal: np.ndarray) -> float | None:
    hover_rows = np.flatnonzero(phase == "hover")
    return float(np.linalg.norm(flown[hover_rows[-1]] - goal)) if hover_rows.size else None


def _path_length(points: np.ndarray) -> float | None:
    return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum()) if len(points) > 1 else None


def _estimator_errors(rec, phase, est, est_vel) -> dict:
    """RMS errors and consistency, all against the truth at the estimate's own sample time (airborne).

    Consistency per axis (x, y, z): the mean normalised squared error (error / sigma)^2, which is 1 for a
    consistent filter, and the fraction of samples inside +-3 sigma (0.997 for a consistent Gaussian error).
    """
    airborne = np.isin(phase, ("takeoff", "settle", "track", "hover", "land", "failsafe_hold", "failsafe_descent"))
    truth_at_est, truth_vel_at_est = stack3(rec.truth_at_est), stack3(rec.truth_vel_at_est)
    sigma = stack3(rec.est_sigma, width=6)
    valid = (airborne & np.isfinite(truth_at_est).all(axis=1) & np.isfinite(est).all(axis=1)
             & np.isfinite(sigma).all(axis=1) & (sigma > 0.0).all(axis=1))
    position_error = est[valid] - truth_at_est[valid]
    velocity_error = est_vel[valid] - truth_vel_at_est[valid]
    z_position, z_velocity = position_error / sigma[valid, :3], velocity_error / sigma[valid, 3:]
    return {"rms_position_error_m": rms(np.linalg.norm(position_error, axis=1)),
            "rms_velocity_error_mps": rms(np.linalg.norm(velocity_error, axis=1)),
            "position_nees_per_axis": _mean_rows(z_position**2),
            "velocity_nees_per_axis": _mean_rows(z_velocity**2),
            "position_inside_3sigma": _mean_rows(np.abs(z_position) <= 3.0),
            "velocity_inside_3sigma": _mean_rows(np.abs(z_velocity) <= 3.0)}


def _mean_rows(values: np.ndarray) -> list[float] | None:
    return [float(v) for v in np.mean(values, axis=0)] if len(values) else None


def _link_summary(loop: FlightLoop) -> dict:
    """This session's link figures; the vehicle's counters are per session (it restarts them when a ground
    station is heard after a silence), so None stands for "the vehicle never reported"."""
    stats = loop.link.radio.stats.snapshot()
    ages = np.array(loop.link.radio.stats.age_s) * 1e3
    rtts = np.array(loop.health.rtt_s) * 1e3
    # a Crazyflie does not count the packets it received: what it got is unknown, not "none"
    reported = loop.health.last_status is not None and getattr(loop.link.radio, "reports_uplink_count", True)
    return {
        "radio": loop.link.radio.transport.scheme,  # the transport the radio link crossed (--radio-link)
        "uplink_sent": stats.tx_frames,
        "uplink_delivered": loop.health.uplink_received if reported else None,
        "downlink_sent": stats.rx_frames + stats.rx_lost,
        "downlink_delivered": stats.rx_frames,
        "rtt_ms_p50": float(np.percentile(rtts, 50)) if rtts.size else None,
        "rtt_ms_p99": float(np.percentile(rtts, 99)) if rtts.size else None,
        # one-way age of downlink frames (receive time - sample time, clocks related by TIMESYNC or
        # shared in lockstep), over the recent window the link statistics keep
        "age_ms_p50": float(np.percentile(ages, 50)) if ages.size else None,
        "age_ms_p99": float(np.percentile(ages, 99)) if ages.size else None,
        "downlink_lost": stats.rx_lost,
        "uplink_lost": stats.tx_frames - loop.health.uplink_received if reported else None,
    }


def _crazyflie_radio(opts: SessionOptions, clock):
    """The opened cflib link to the Crazyflie at opts.crtp_uri (imported only for --link crtp)."""
    from groundstation.crtp_settings import load_crtp_link_settings
    from link.crtp import zenoh_driver
    from link.crtp.cflib_link import CrazyflieRadio

    zenoh_driver.use_session(opts.connection, opts.zenoh_options)  # zenoh://: the ground network's session
    radio = CrazyflieRadio(opts.crtp_uri, load_crtp_link_settings(), clock, lockstep=opts.clock == "lockstep")
    radio.open()
    return radio


def _open_displays(opts: SessionOptions, log_dir: Path, mission: Mission, rate_hz: float, gains) -> list:
    """The observers the options ask for (imported only then: rerun is an optional dependency)."""
    d = opts.displays
    observers = []
    if d.view or d.view_save:
        from groundstation.view.live import LiveView, load_view_settings, open_recording

        recording = open_recording(d.view_save, f"flight {log_dir.name}")
        observers.append(LiveView(recording, load_view_settings(), opts.world, opts.plan, opts.track))
    if d.gcs:
        from groundstation.gcs_forward import GcsForwarder, session_parameters

        params = session_parameters(opts.mode, rate_hz, opts.vehicle_id, gains)
        observers.append(GcsForwarder(d.gcs, d.gcs_settings, log_dir, params, signing=d.gcs_signing,
                                      allow_commands=d.gcs_commands, mission=mission))
    return observers


def _timing(loop: FlightLoop, opts: SessionOptions, sim_time_s: float) -> dict:
    timing = loop.clock.timer.summary()
    # Simulated seconds per wall second while flying (first tick to last); wall_time_s also holds the
    # start: opening the link and, with `fly`, waiting for the emulator child to boot.
    loop_s = timing["loop_wall_s"]
    timing["real_time_factor"] = sim_time_s / loop_s if loop_s else None
    if opts.clock == "realtime":
        timing["achieved_rate_hz"] = loop.clock.achieved_rate_hz()
    else:
        timing.update(loop.clock.critical_path_summary())
    return timing


def _estimator_counts(estimator) -> dict:
    if not estimator.initialised:
        return {}
    h = estimator.health()
    return {"mocap_accepted": h.accepted_mocap, "mocap_rejected_outliers": h.rejected_outliers,
            "reinitialisations": h.reinitialisations, "imu_lost": h.lost_imu, "imu_reordered": h.reordered_imu}


def human_summary(summary: dict) -> str:
    """A few lines, each figure only where it means something for this flight."""
    lines = [_result_line(summary)]
    flight = [f"time to goal {summary['time_to_goal_s']:.2f} s" if summary.get("time_to_goal_s") is not None
              else None,
              _tracking_text(summary),
              _mm("final error", summary["final_position_error_m"]),
              f"min clearance {summary['min_clearance_m']:.3f} m ({summary['min_clearance_to']}, "
              f"{summary['min_clearance_phase']})" if summary.get("min_clearance_m") is not None else None]
    if any(flight):
        lines.append(", ".join(part for part in flight if part))
    landing = summary.get("landing") or {}
    if landing.get("result") not in (None, "not_attempted") or landing.get("note"):
        where = (f" at {[round(v, 3) for v in landing['spot_enu_m']]} m ({landing['moved_m']:.2f} m from the goal "
                 "hover point)" if landing.get("spot_enu_m") is not None else "")
        lines.append(f"landing: {landing['result']}{where}" + (f"; {landing['note']}" if landing.get("note") else ""))
    grade = summary.get("course_grade")
    if grade is not None:
        course_time = f", flight time {grade['flight_time_s']:.2f} s" if grade["flight_time_s"] is not None else ""
        lines.append(f"course grade: {'pass' if grade['passed'] else 'FAIL'} (stopped at goal "
                     f"{_yes(grade['stopped_at_goal'])}, no collision within {grade['robot_radius_m']:g} m "
                     f"{_yes(grade['no_collision'])}{course_time})")
    est = summary["estimator"]
    if est.get("rms_position_error_m") is not None:
        inside = est.get("position_inside_3sigma")
        consistency = ("" if not inside else ", position inside 3 sigma x/y/z "
                       + "/".join(f"{100 * v:.1f}" for v in inside) + " %")
        lines.append(f"estimator rms error {est['rms_position_error_m'] * 1e3:.2f} mm, "
                     f"{est['rms_velocity_error_mps'] * 1e2:.2f} cm/s{consistency}")
    lines.append(_link_line(summary["link"]))
    if summary.get("user_code"):
        lines.append(_user_code_line(summary["user_code"]))
    lines.append(f"{summary['sim_time_s']:.2f} s simulated in {summary['wall_time_s']:.2f} s wall"
                 f"{_loop_speed(summary.get('timing', {}))}; logs in {summary['log_dir']}")
    return "\n".join(lines)


def _tracking_text(summary: dict) -> str | None:
    if summary["rms_tracking_error_m"] is None:
        return None
    return (f"tracking error rms {summary['rms_tracking_error_m'] * 1e3:.1f} mm "
            f"max {summary['max_tracking_error_m'] * 1e3:.1f} mm")


def _result_line(summary: dict) -> str:
    line = f"result: {summary['result']}"
    failure_ = summary.get("failure")
    if failure_ is not None:
        line += f" ({failure_['reason']})"
    elif summary.get("failsafe_reason"):
        line += f" ({summary['failsafe_reason']})"
    return line


def _user_code_line(user: dict) -> str:
    """The user's own time per call (wall time: in lockstep it slows the run, never changes it)."""
    parts = []
    for name, key in (("controller", "controller_update"), ("trajectory", "trajectory_update")):
        times = user.get(key)
        if times and times.get("calls"):
            parts.append(f"{user[name]}.update p50 {times['p50_ms']:.3f} ms p99 {times['p99_ms']:.3f} ms "
                         f"({times['calls']} calls)")
    if user.get("realtime_overruns"):
        parts.append(f"{user['realtime_overruns']} calls over the control period")
    return "user code: " + ("; ".join(parts) or "no calls")


def _link_line(link: dict) -> str:
    parts = []
    if link["uplink_delivered"] is not None:
        parts.append(f"uplink {link['uplink_delivered']}/{link['uplink_sent']} delivered")
    else:
        parts.append(f"uplink {link['uplink_sent']} sent (the vehicle never reported what it received)")
    if link["downlink_sent"]:
        parts.append(f"downlink {link['downlink_delivered']}/{link['downlink_sent']}")
    if link["rtt_ms_p50"] is not None:
        parts.append(f"rtt p50 {link['rtt_ms_p50']:.2f} ms p99 {link['rtt_ms_p99']:.2f} ms")
    return "link: " + ", ".join(parts)


def _mm(label: str, value: float | None) -> str | None:
    return None if value is None else f"{label} {value * 1e3:.1f} mm"


def _yes(flag: bool) -> str:
    return "yes" if flag else "no"


def _loop_speed(timing: dict) -> str:
    rtf = timing.get("real_time_factor")
    return "" if rtf is None else f" (flight loop {rtf:.1f}x real time)"


def dump_json(summary: dict) -> str:
    return json.dumps(summary, allow_nan=False)
