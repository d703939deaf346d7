"""A whole flight session: build the pieces, fly the mission, grade it, write the logs.

Takes in: SessionOptions (connection, vehicle id, mode, rate, clock, trajectory or planned world, log dir).
Gives out: the summary dict (the `--json` object of `cfstack fly`), written to summary.json too.
Grading uses simulator truth when the link provides it (simulation only); control never does.
"""

from __future__ import annotations

import json
import logging
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from estimator.eskf import ErrorStateKF
from groundstation.clocks import LockstepClock, RealtimeClock
from groundstation.compensation import LatencyCompensator
from groundstation.controller import SE3Controller, load_gains
from groundstation.flight import FlightLoop
from groundstation.flightlog import FlightLog, default_log_dir
from groundstation.mission import Mission, load_mission_params
from groundstation.trajectory import Trajectory
from groundstation.vehicle_link import VehicleLink
from link.keys import VehicleKeys
from link.mavlink.codec import ActuatorLimits
from link.transports import open_transport
from model.vehicle import load_mocap_room, load_vehicle
from model.world import World

log = logging.getLogger("cfstack.groundstation")

DEFAULT_RATE_HZ = {"moments": 500.0, "attitude": 100.0}


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
    prefix: str = "cfstack"
    vehicle_id: int = 1
    vehicle_model: str = "crazyflie"
    mocap_room: str = "vicon"
    gains: str = "gains"
    controller_variant: str | None = None  # None: the gains file's
    latency_compensation: bool = False
    log_dir: Path | None = None
    signing: object | None = None
    extra_summary: dict = field(default_factory=dict)
    plan: dict | None = None
    peer_failure: object = None  # callable: why the emulator child stopped, or None while it runs


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
    ground_height = world.support_height if world is not None else (lambda point: 0.0)
    log_dir = Path(opts.log_dir) if opts.log_dir else default_log_dir()
    keys = VehicleKeys(opts.prefix, opts.vehicle_id)
    wall_start = time.monotonic()
    with FlightLog(log_dir) as flight_log:
        if opts.plan is not None:
            flight_log.write_json("plan.json", opts.plan)
        clock_box: dict = {}
        link = VehicleLink(opts.connection, keys, ActuatorLimits.from_vehicle(vehicle),
                           clock=lambda: clock_box["clock"].now(), zenoh_options=opts.zenoh_options,
                           signing=opts.signing, tlog_path=flight_log.tlog_path,
                           shared_clock=opts.clock == "lockstep")
        try:
            if opts.clock == "lockstep":
                clock_transport = open_transport(opts.connection, tx=keys.clock_ack, rx=keys.clock,
                                                 **opts.zenoh_options)
                clock = LockstepClock(period, link, clock_transport, peer_failure=opts.peer_failure)
            else:
                clock_transport = None
                clock = RealtimeClock(period, link)
            clock_box["clock"] = clock
            estimator = ErrorStateKF(vehicle, load_mocap_room(opts.mocap_room))
            controller = SE3Controller(vehicle, load_gains(opts.gains), variant=opts.controller_variant)
            mission = Mission(params, opts.track, ground_height, opts.goal_enu_m)
            compensator = LatencyCompensator(vehicle, opts.mode, period) if opts.latency_compensation else None
            loop = FlightLoop(link, clock, estimator, controller, mission, params, flight_log, opts.mode, period,
                              compensator)
            loop.run()
        finally:
            link.close()
            if clock_transport is not None:
                clock_transport.close()
        summary = grade(loop, opts, params, log_dir, time.monotonic() - wall_start)
        flight_log.write_json("summary.json", summary)
    return SessionResult(summary, loop.record)


def _stack(rows: list) -> np.ndarray:
    return np.array([r if r is not None else [np.nan] * 3 for r in rows], float).reshape(-1, 3)


def grade(loop: FlightLoop, opts: SessionOptions, params, log_dir: Path, wall_s: float) -> dict:
    rec = loop.record
    t = np.array(rec.t)
    phase = np.array(rec.phase)
    ref, est, est_vel = _stack(rec.ref), _stack(rec.est), _stack(rec.est_vel)
    truth, truth_vel = _stack(rec.truth), _stack(rec.truth_vel)
    have_truth = bool(np.isfinite(truth).all(axis=1).any())
    flown, flown_vel = (truth, truth_vel) if have_truth else (est, est_vel)
    tracking = np.isin(phase, ("track", "hover"))
    err = np.linalg.norm(flown - ref, axis=1)
    err_tracking = err[tracking & np.isfinite(err)]
    airborne = np.isin(phase, ("takeoff", "settle", "track", "hover", "land", "failsafe_hold", "failsafe_descent"))
    truth_at_est, truth_vel_at_est = _stack(rec.truth_at_est), _stack(rec.truth_vel_at_est)
    valid = airborne & np.isfinite(truth_at_est).all(axis=1) & np.isfinite(est).all(axis=1)
    est_pos_err = np.linalg.norm(est[valid] - truth_at_est[valid], axis=1)
    est_vel_err = np.linalg.norm(est_vel[valid] - truth_vel_at_est[valid], axis=1)
    goal = np.asarray(opts.goal_enu_m, float)
    track_start = loop.mission.track_start_s
    reached_at = None
    if track_start is not None:
        after = (t >= track_start + loop.mission.arrival_s) & np.isfinite(flown).all(axis=1)
        near = np.linalg.norm(flown - goal, axis=1) <= params.goal_position_tolerance_m
        slow = np.linalg.norm(flown_vel, axis=1) <= params.goal_speed_tolerance_mps
        hits = np.flatnonzero(after & near & slow)
        if hits.size:
            reached_at = float(t[hits[0]])
    flown_track = flown[tracking & np.isfinite(flown).all(axis=1)]
    path_length = float(np.linalg.norm(np.diff(flown_track, axis=0), axis=1).sum()) if len(flown_track) > 1 else None
    hover_rows = np.flatnonzero(phase == "hover")
    final_error = None
    if hover_rows.size:
        final_error = float(np.linalg.norm(flown[hover_rows[-1]] - goal))
    min_clearance = None
    world = opts.world
    if world is not None and len(world.blocks) and have_truth:
        # Clearance of the flight itself: take-off from and landing on a pad touch blocks by design.
        flight = np.isin(phase, ("settle", "track", "hover", "failsafe_hold"))
        pts = truth[flight & np.isfinite(truth).all(axis=1)]
        if len(pts):
            min_clearance = float(world.distance_to_blocks(pts).min())
    crashed = loop.mission.result == "crashed"
    result = loop.mission.result or "aborted"
    if result == "reached_goal" and reached_at is None:
        result = "timeout"  # the mission thought so from its estimate, but the truth never got there
    stats = loop.link.radio.stats.snapshot()
    ages = np.array(loop.link.radio.stats.age_s) * 1e3
    rtts = np.array(loop.health.rtt_s) * 1e3
    status = loop.health.last_status
    summary = {
        "result": result,
        "reached_goal": result == "reached_goal",
        "collided": crashed,
        "min_clearance_m": min_clearance,
        "flight_time_s": None if reached_at is None or track_start is None else reached_at - track_start,
        "rms_tracking_error_m": _rms(err_tracking),
        "max_tracking_error_m": float(err_tracking.max()) if err_tracking.size else None,
        "final_position_error_m": final_error,
        "path_length_m": path_length,  # flown (truth, else estimate) while tracking and hovering at the end
        "estimator": {"rms_position_error_m": _rms(est_pos_err), "rms_velocity_error_mps": _rms(est_vel_err)}
        | _estimator_counts(loop.estimator),
        "link": {
            "uplink_sent": stats.tx_frames,
            "uplink_delivered": None if status is None else loop.health.uplink_received,
            "downlink_sent": stats.rx_frames + stats.rx_lost,
            "downlink_delivered": stats.rx_frames,
            "rtt_ms_p50": float(np.percentile(rtts, 50)) if rtts.size else None,
            "rtt_ms_p99": float(np.percentile(rtts, 99)) if rtts.size else None,
            # one-way age of downlink frames (receive time - sample time, clocks related by TIMESYNC or
            # shared in lockstep), over the recent window the link statistics keep
            "age_ms_p50": float(np.percentile(ages, 50)) if ages.size else None,
            "age_ms_p99": float(np.percentile(ages, 99)) if ages.size else None,
            "downlink_lost": stats.rx_lost,
            "uplink_lost": None if status is None else stats.tx_frames - loop.health.uplink_received,
        },
        "mode": opts.mode,
        "latency_compensation": opts.latency_compensation,
        "clock": opts.clock,
        "failsafe_reason": loop.mission.failsafe_reason,
        "sim_time_s": float(t[-1]) if t.size else 0.0,
        "wall_time_s": wall_s,
        "log_dir": str(log_dir),
    }
    timing = loop.clock.timer.summary()
    # Simulated seconds per wall second while flying (first tick to last); wall_time_s above also holds
    # the start: opening the link and, with `fly`, waiting for the emulator child to boot.
    loop_s = timing["loop_wall_s"]
    timing["real_time_factor"] = summary["sim_time_s"] / loop_s if loop_s else None
    summary["timing"] = timing
    if opts.clock == "realtime":
        summary["timing"]["achieved_rate_hz"] = loop.clock.achieved_rate_hz()
    summary.update(opts.extra_summary)
    return summary


def _estimator_counts(estimator) -> dict:
    if not estimator.initialised:
        return {}
    h = estimator.health()
    return {"mocap_accepted": h.accepted_mocap, "mocap_rejected_outliers": h.rejected_outliers,
            "reinitialisations": h.reinitialisations, "imu_lost": h.lost_imu, "imu_reordered": h.reordered_imu}


def _rms(values: np.ndarray) -> float | None:
    values = np.asarray(values, float)
    return float(math.sqrt(np.mean(values**2))) if values.size else None


def human_summary(summary: dict) -> str:
    def fmt(v, unit="", scale=1.0, digits=3):
        return "n/a" if v is None else f"{v * scale:.{digits}f}{unit}"

    link = summary["link"]
    lines = [
        f"result: {summary['result']}" + (f" ({summary['failsafe_reason']})" if summary.get("failsafe_reason") else ""),
        f"flight time {fmt(summary['flight_time_s'], ' s', digits=2)}, tracking error rms "
        f"{fmt(summary['rms_tracking_error_m'], ' mm', 1e3, 1)} "
        f"max {fmt(summary['max_tracking_error_m'], ' mm', 1e3, 1)}, "
        f"final error {fmt(summary['final_position_error_m'], ' mm', 1e3, 1)}, "
        f"min clearance {fmt(summary['min_clearance_m'], ' m')}",
        f"estimator rms error {fmt(summary['estimator']['rms_position_error_m'], ' mm', 1e3, 2)}, "
        f"{fmt(summary['estimator']['rms_velocity_error_mps'], ' cm/s', 1e2, 2)}",
        f"link: uplink {link['uplink_delivered']}/{link['uplink_sent']} delivered, downlink "
        f"{link['downlink_delivered']}/{link['downlink_sent']}, rtt p50 {fmt(link['rtt_ms_p50'], ' ms', digits=2)} "
        f"p99 {fmt(link['rtt_ms_p99'], ' ms', digits=2)}",
        f"{summary['sim_time_s']:.2f} s simulated in {summary['wall_time_s']:.2f} s wall"
        f"{_loop_speed(summary.get('timing', {}))}; logs in {summary['log_dir']}",
    ]
    return "\n".join(lines)


def _loop_speed(timing: dict) -> str:
    rtf = timing.get("real_time_factor")
    return "" if rtf is None else f" (flight loop {rtf:.1f}x real time)"


def dump_json(summary: dict) -> str:
    return json.dumps(summary, allow_nan=False)
