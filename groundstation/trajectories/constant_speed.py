"""The lab report's constant-speed trajectory through a downsampled A* path (report III.B, eq. (1)).

Takes in: a dense path (M, 3) m, world ENU (start first, goal last), the speed v (m/s), which points to
keep (every third) and the first/last segment time factor (1.5); defaults from
groundstation/params/planning.toml [constant_speed].
Gives out: `ConstantSpeedTrajectory`, a groundstation.trajectory.Trajectory.

Definition (report III.B):
- waypoints P_0..P_n: every third path point, plus the goal (consecutive duplicates dropped);
- segment times (eq. 1): T_i = |P_i+1 - P_i| / v, times 1.5 for the first (i = 0) and last (i = n-1);
- middle segments: r_T(t) = P_i + v l_i (t - t_start,i), velocity v l_i, l_i = (P_i+1 - P_i)/|P_i+1 - P_i|;
- acceleration, jerk and snap are reported as zero everywhere, as the report does.
The report's "linear interpolation on the velocity" in the first and last segments is made exact here
(a choice the report leaves open): with factor k the first segment accelerates at a constant rate from
rest to v over tau = 2 (k - 1) |P_1 - P_0| / v (= 2/3 of T_0 for k = 1.5) and then cruises at v, which
covers exactly |P_1 - P_0| in T_0 = k |P_1 - P_0| / v: v (T_0 - tau/2) = |P_1 - P_0|. So position is
continuous, the segment ends exactly at P_1, and the speed is v at the knot like the middle segments.
The last segment is the mirror image: cruise at v, then decelerate linearly to rest exactly at the goal.
A single segment gets the factor once and both ramps, each over tau = (k - 1) |P_1 - P_0| / v (T/3).
This needs 1 <= k <= 2 (k = 1: no ramp, the report's plain constant speed).

sample() runs twice per control tick: it works on per-segment floats precomputed at construction
(groundstation/trajectories/flat.py says why).
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass

import numpy as np

from groundstation.planning import load_planning_params
from groundstation.trajectories.flat import at_rest, flat_output
from groundstation.trajectory import FlatOutput
from model.config import Params
from model.errors import UserError

_ZERO_DERIVATIVES = (0.0,) * 9  # acceleration, jerk and snap within a constant-speed segment


@dataclass(frozen=True)
class ConstantSpeedSettings:
    speed_mps: float
    keep_every: int
    end_segment_time_factor: float

    @staticmethod
    def from_params(params: Params) -> ConstantSpeedSettings:
        """From the [constant_speed] table of a planning parameter file."""
        table = params.table("constant_speed")
        return ConstantSpeedSettings(
            speed_mps=table.number("speed_mps", minimum=1e-3),
            keep_every=table.integer("keep_every", minimum=1),
            end_segment_time_factor=table.number("end_segment_time_factor", minimum=1.0, maximum=2.0),
        )


def downsample_path(path_m: np.ndarray, keep_every: int) -> np.ndarray:
    """Every `keep_every`-th point of the path, always with the last; consecutive duplicates dropped."""
    path = np.asarray(path_m, float).reshape(-1, 3)
    if len(path) == 0:
        raise UserError("constant-speed trajectory: the path is empty")
    keep = np.zeros(len(path), bool)
    keep[::keep_every] = True
    keep[-1] = True
    points = path[keep]
    return points[np.r_[True, np.any(np.diff(points, axis=0) != 0, axis=1)]]


class ConstantSpeedTrajectory:
    """Piecewise-linear constant-speed reference with linear speed ramps in the first and last segments."""

    sample_is_pure = True  # a function of t alone (groundstation.trajectory)

    def __init__(self, waypoints_m: np.ndarray, speed_mps: float, end_segment_time_factor: float):
        points = np.asarray(waypoints_m, float).reshape(-1, 3)
        if len(points) == 0:
            raise UserError("constant-speed trajectory: no waypoints")
        if not np.all(np.isfinite(points)):
            raise UserError("constant-speed trajectory: waypoints must be finite")
        if not speed_mps > 0:
            raise UserError(f"constant-speed trajectory: speed must be positive, got {speed_mps}")
        k = end_segment_time_factor
        if not 1.0 <= k <= 2.0:
            raise UserError(f"constant-speed trajectory: end segment time factor must be in [1, 2], got {k}")
        points = points[np.r_[True, np.any(np.diff(points, axis=0) != 0, axis=1)]]
        self.waypoints_m = points
        self.speed_mps = float(speed_mps)
        steps = np.diff(points, axis=0)
        lengths_m = np.linalg.norm(steps, axis=1)
        directions = steps / lengths_m[:, None] if len(steps) else np.zeros((0, 3))
        self.segment_times_s, ramp_in_s, ramp_out_s = _timing(lengths_m, self.speed_mps, k)
        self.knot_times_s = np.r_[0.0, np.cumsum(self.segment_times_s)]
        self.duration_s = float(self.knot_times_s[-1])
        self._knots = self.knot_times_s.tolist()
        # Per segment, as floats: start point, direction, length, time, ramp-in and ramp-out times.
        self._segments = list(zip(points[:-1].tolist(), directions.tolist(), lengths_m.tolist(),
                                  self.segment_times_s.tolist(), ramp_in_s.tolist(), ramp_out_s.tolist(),
                                  strict=True))

    @staticmethod
    def from_path(
        path_m: np.ndarray, settings: ConstantSpeedSettings | None = None
    ) -> ConstantSpeedTrajectory:
        """The report's trajectory through a dense (A*) path: downsample, then time by eq. (1)."""
        s = settings or ConstantSpeedSettings.from_params(load_planning_params())
        return ConstantSpeedTrajectory(
            downsample_path(path_m, s.keep_every), s.speed_mps, s.end_segment_time_factor
        )

    def sample(self, t_s: float) -> FlatOutput:
        n = len(self._segments)
        if n == 0 or t_s <= 0.0:
            return at_rest(self.waypoints_m[0])
        if t_s >= self.duration_s:
            return at_rest(self.waypoints_m[-1])
        i = min(bisect.bisect_right(self._knots, t_s) - 1, n - 1)
        (px, py, pz), (lx, ly, lz), length, duration, ramp_in, ramp_out = self._segments[i]
        distance, speed = _along(self.speed_mps, length, duration, ramp_in, ramp_out, t_s - self._knots[i])
        return flat_output([px + distance * lx, py + distance * ly, pz + distance * lz,
                            speed * lx, speed * ly, speed * lz, *_ZERO_DERIVATIVES])


def _along(v: float, length: float, duration: float, ramp_in: float, ramp_out: float, s: float
           ) -> tuple[float, float]:
    """Distance (m) covered and speed (m/s) at time s into a segment (length m, duration s, ramp times s)."""
    if s < ramp_in:  # accelerating from rest: v(s) = v s / tau
        return v * s * s / (2.0 * ramp_in), v * s / ramp_in
    remaining = duration - s
    if remaining < ramp_out:  # decelerating to rest at the segment end
        return length - v * remaining * remaining / (2.0 * ramp_out), v * remaining / ramp_out
    return v * (ramp_in / 2.0 + s - ramp_in), v


def _timing(lengths: np.ndarray, v: float, k: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Segment times (eq. 1) and the speed-ramp times at each segment's start and end (s)."""
    n = len(lengths)
    times = lengths / v
    ramp_in, ramp_out = np.zeros(n), np.zeros(n)
    if n == 1:
        times[0] *= k
        ramp_in[0] = ramp_out[0] = (k - 1.0) * lengths[0] / v  # v (T - tau) = d
    elif n > 1:
        times[0] *= k
        times[-1] *= k
        ramp_in[0] = 2.0 * (k - 1.0) * lengths[0] / v  # v (T_0 - tau / 2) = d_0
        ramp_out[-1] = 2.0 * (k - 1.0) * lengths[-1] / v
    return times, ramp_in, ramp_out
