"""The flight in rerun: a 3-D scene and time series on the flight's own (simulated) time axis.

Takes in: a rerun RecordingStream (spawned viewer or .rrd file), the world (blocks and bounds), the plan
(A* path, pruned waypoints), trajectory points, and TickFrames (groundstation.tickframe), live or replayed.
Gives out: rerun entities, all on the timeline `sim_time` (seconds of flight time, so a lockstep run
scrubs like a realtime one):
    world/blocks, world/bounds                       Boxes3D (static)
    world/plan/path, world/plan/waypoints            LineStrips3D, Points3D (static)
    world/plan/trajectory                            LineStrips3D (static)
    world/vehicle/truth, world/vehicle/estimate      Transform3D (pose) with a body-axes child
    world/vehicle/estimate_3sigma                    Ellipsoids3D: 3 sigma of position per world axis
                                                     (the log keeps the covariance diagonal only)
    world/vehicle/command                            Transform3D: commanded attitude at the estimate
    world/flown/truth, world/flown/estimate          LineStrips3D of the path so far
    plots/tracking_error_m, plots/thrust_n, plots/moment_nm (x, y, z FLU), plots/attitude_cmd_deg (roll, pitch, yaw),
    plots/battery_v, plots/link/{delivery_pct, rtt_ms, mocap_age_ms, downlink_gap_ms}   Scalars
    phase                                            TextLog at each change of flight phase
Motor PWM is not among the series: the vehicle does not send it down the MAVLink link (README).
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np
import rerun as rr

from groundstation.tickframe import TickFrame
from model.frames import euler_zyx_of

TIMELINE = "sim_time"
BODY_AXIS_LENGTH_M = 0.1  # drawn body axes (a Crazyflie is 92 mm motor to motor)
DELIVERY_WINDOW_S = 1.0  # window of the downlink delivery rate
TRAIL_EVERY = 5  # frames between points of the flown-path strips (keeps the per-frame cost flat)
BLOCK_RGB = (150, 150, 160)
SERIES_NAMES = {"plots/moment_nm": ["x (roll)", "y (pitch)", "z (yaw)"],  # body FLU axes
                "plots/attitude_cmd_deg": ["roll", "pitch", "yaw"],  # ZYX Euler angles of the commanded attitude, ENU
                "plots/motor_pwm_pct": ["m1", "m2", "m3", "m4"]}  # PWM duty, the firmware's motor order


class FlightView:
    """Logs one flight into a recording. Frames are gathered and sent as columns every `batch_frames` frames
    (rerun's send_columns: one call per entity per batch instead of one per entity per frame), and at
    flush(); the viewer is then at most a batch behind the flight."""

    def __init__(self, recording: rr.RecordingStream, batch_frames: int = 1):
        self.rec = recording
        self.batch_frames = batch_frames
        self._phase: str | None = None
        self._counts: deque[tuple[float, int, int]] = deque()  # (t, received, lost) over DELIVERY_WINDOW_S
        self._last_received: tuple[float, int] | None = None  # (time, count) when the count last grew
        self._last_motor_duty: tuple | None = None  # the motor report last drawn (reports come slower than frames)
        self._trails: dict[str, list] = {"truth": [], "estimate": []}
        self._frames = 0
        self._pending: dict[str, tuple[type, list[float], dict[str, list]]] = {}
        for entity in ("world/vehicle/truth/body", "world/vehicle/estimate/body", "world/vehicle/command/body"):
            self._log_axes(entity)
        self.rec.log("world/vehicle/estimate_3sigma", rr.Ellipsoids3D.from_fields(colors=[(40, 120, 255, 90)]),
                     static=True)
        for entity, names in SERIES_NAMES.items():
            self.rec.log(entity, rr.SeriesLines(names=names), static=True)

    # -- static scene ---------------------------------------------------------------------------------

    def world(self, world) -> None:
        """Blocks and bounds of a model.world.World, and its start and goal."""
        if world is None:
            return
        blocks = np.asarray(world.blocks, dtype=float).reshape(-1, 6)
        if len(blocks):
            mins = blocks[:, [0, 2, 4]]
            sizes = blocks[:, [1, 3, 5]] - mins
            self.rec.log("world/blocks", rr.Boxes3D(mins=mins, sizes=sizes, colors=[BLOCK_RGB] * len(blocks),
                                                    fill_mode="solid"), static=True)
        b = np.asarray(world.bounds, dtype=float)
        self.rec.log("world/bounds", rr.Boxes3D(mins=[b[[0, 2, 4]]], sizes=[b[[1, 3, 5]] - b[[0, 2, 4]]],
                                                colors=[(200, 200, 200)]), static=True)
        for name, point, rgb in (("start", world.start, (0, 170, 0)), ("goal", world.goal, (200, 0, 200))):
            if point is not None:
                self.rec.log(f"world/{name}", rr.Points3D([point], radii=0.05, colors=[rgb], labels=[name]),
                             static=True)

    def plan(self, path_m: np.ndarray | None, waypoints_m: np.ndarray | None) -> None:
        if path_m is not None and len(path_m):
            self.rec.log("world/plan/path", rr.LineStrips3D([np.asarray(path_m)], colors=[(255, 160, 0)]), static=True)
        if waypoints_m is not None and len(waypoints_m):
            self.rec.log("world/plan/waypoints", rr.Points3D(np.asarray(waypoints_m), radii=0.03,
                                                             colors=[(220, 40, 40)]), static=True)

    def trajectory(self, points_m: np.ndarray) -> None:
        if len(points_m) >= 2:
            self.rec.log("world/plan/trajectory", rr.LineStrips3D([points_m], colors=[(40, 120, 255)]), static=True)

    # -- per tick -------------------------------------------------------------------------------------

    def frame(self, f: TickFrame) -> None:
        self._frames += 1
        if f.phase != self._phase:
            self._add("phase", rr.TextLog, f.t_s, text=f"phase: {f.phase}")
            self._phase = f.phase
        self._poses(f)
        self._series(f)
        self._link(f)
        if self._frames % self.batch_frames == 0:
            self.flush()

    def flush(self) -> None:
        """Send what is gathered: one send_columns per entity, then the flown paths so far."""
        for entity, (archetype, times, fields) in self._pending.items():
            if times:
                self.rec.send_columns(entity, indexes=[rr.TimeColumn(TIMELINE, duration=times)],
                                      columns=archetype.columns(**fields))
        self._pending.clear()
        for name, trail in self._trails.items():
            if len(trail) >= 2:
                self.rec.set_time(TIMELINE, duration=trail[-1][0])
                self.rec.log(f"world/flown/{name}", rr.LineStrips3D([[p for _, p in trail]], colors=[_TRAIL_RGB[name]]))

    def _add(self, entity: str, archetype: type, t_s: float, **fields) -> None:
        _, times, columns = self._pending.setdefault(entity, (archetype, [], {}))
        times.append(t_s)
        for name, value in fields.items():
            columns.setdefault(name, []).append(value)

    def _poses(self, f: TickFrame) -> None:
        t = f.t_s
        if f.truth_position_enu_m is not None:
            self._add("world/vehicle/truth", rr.Transform3D, t, **_pose(f.truth_position_enu_m, f.truth_attitude_wxyz))
            self._trail("truth", t, f.truth_position_enu_m)
        if f.est_position_enu_m is not None:
            self._add("world/vehicle/estimate", rr.Transform3D, t, **_pose(f.est_position_enu_m, f.est_attitude_wxyz))
            self._trail("estimate", t, f.est_position_enu_m)
            if f.est_sigma_position_m is not None:
                self._add("world/vehicle/estimate_3sigma", rr.Ellipsoids3D, t, centers=f.est_position_enu_m,
                          half_sizes=[3.0 * s for s in f.est_sigma_position_m])
            if f.cmd_attitude_wxyz is not None:
                self._add("world/vehicle/command", rr.Transform3D, t,
                          **_pose(f.est_position_enu_m, f.cmd_attitude_wxyz))

    def _trail(self, name: str, t_s: float, point) -> None:
        # a point every TRAIL_EVERY frames: the strip is resent whole at each flush, so it must stay short
        trail = self._trails[name]
        if self._frames % TRAIL_EVERY == 0 or not trail:
            trail.append((t_s, point))

    def _scalar(self, entity: str, t_s: float, value) -> None:
        """One value, or one per line of a multi-line series (SERIES_NAMES)."""
        self._add(entity, rr.Scalars, t_s, scalars=value)

    def _series(self, f: TickFrame) -> None:
        t = f.t_s
        flown = f.truth_position_enu_m or f.est_position_enu_m
        if flown is not None and f.ref_position_enu_m is not None:
            self._scalar("plots/tracking_error_m", t, math.dist(flown, f.ref_position_enu_m))
        if f.cmd_thrust_n is not None:
            self._scalar("plots/thrust_n", t, f.cmd_thrust_n)
        if f.cmd_moment_flu_nm is not None:
            self._scalar("plots/moment_nm", t, f.cmd_moment_flu_nm)
        if f.cmd_attitude_wxyz is not None:
            self._scalar("plots/attitude_cmd_deg", t, [math.degrees(a) for a in euler_zyx_of(f.cmd_attitude_wxyz)])
        if f.battery_v is not None:
            self._scalar("plots/battery_v", t, f.battery_v)
        if f.motor_duty is not None and f.motor_duty is not self._last_motor_duty:  # each report once (10 Hz)
            self._last_motor_duty = f.motor_duty
            self._scalar("plots/motor_pwm_pct", t, [100.0 * d for d in f.motor_duty])

    def _link(self, f: TickFrame) -> None:
        t = f.t_s
        counts = self._counts
        counts.append((t, f.downlink_received, f.downlink_lost))
        while counts and counts[0][0] < t - DELIVERY_WINDOW_S:
            counts.popleft()
        received = f.downlink_received - counts[0][1]
        lost = f.downlink_lost - counts[0][2]
        if received + lost > 0:
            self._scalar("plots/link/delivery_pct", t, 100.0 * received / (received + lost))
        if self._last_received is None or f.downlink_received != self._last_received[1]:
            self._last_received = (t, f.downlink_received)
        self._scalar("plots/link/downlink_gap_ms", t, 1e3 * (t - self._last_received[0]))
        if f.rtt_ms is not None:
            self._scalar("plots/link/rtt_ms", t, f.rtt_ms)
        if f.mocap_age_s is not None:
            self._scalar("plots/link/mocap_age_ms", t, 1e3 * f.mocap_age_s)

    def _log_axes(self, entity: str) -> None:
        length = BODY_AXIS_LENGTH_M
        self.rec.log(entity, rr.Arrows3D(vectors=[[length, 0, 0], [0, length, 0], [0, 0, length]],
                                         colors=[(255, 0, 0), (0, 200, 0), (0, 0, 255)]), static=True)


_TRAIL_RGB = {"truth": (30, 30, 30), "estimate": (40, 120, 255)}


def _pose(position, attitude_wxyz) -> dict:
    """Transform3D columns of one pose: translation, and the rotation as rerun's (x, y, z, w)."""
    w, x, y, z = attitude_wxyz if attitude_wxyz is not None else (1.0, 0.0, 0.0, 0.0)
    return {"translation": position, "quaternion": (x, y, z, w)}
