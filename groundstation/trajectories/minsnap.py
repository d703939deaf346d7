"""Minimum-snap trajectories through waypoints, with optimised segment times, limits and clearance repair.

Takes in: waypoints (K, 3) m, world ENU - or a dense A* path with the `World` and margin (m), which is
pruned (groundstation.planning.pruning) - and `MinSnapSettings` (limits from
groundstation/params/planning.toml [minsnap] and the vehicle's thrust-to-weight ratio).
Gives out: `MinSnapTrajectory`, a groundstation.trajectory.Trajectory (yaw held at 0), and for a path
a `MinSnapPlan` (trajectory, waypoint positions on the path, repairs made, clearance reached).

Problem (Mellinger & Kumar 2011; Richter, Bry & Roy 2016): x(t) piecewise polynomial of degree 7,
segment i on [t_i, t_i + T_i], minimising J = sum_i int |x''''(t)|^2 dt subject to x(t_i) = w_i,
x(t_i + T_i) = w_i+1 and rest (velocity, acceleration, jerk 0) at both ends. Its optimum is the degree-7
spline with derivatives 1..6 continuous at the interior knots (the Euler-Lagrange conditions), so for
fixed times it is one square, banded linear system (8 unknowns per segment and axis, bandwidth 11),
solved with LAPACK dgbsv (scipy.linalg.lapack). Each segment is written in normalised time tau = (t - t_i)/T_i
(coefficients c_k of tau^k), which keeps the system well conditioned whatever the times.

Segment times: a trapezoidal speed profile per segment (max speed, max acceleration) is the start;
then log T is optimised (scipy TNC, bounded) for J(T) + k_T sum(T), with the exact gradient
dJ/dT_i = -H_i, where H = |x''''|^2 - 2 x^(5).x''' + 2 x^(6).x'' - 2 x^(7).x' is the (Ostrogradsky)
Hamiltonian of the snap functional, constant on each optimal segment. As J(a T) = a^-7 J(T), k_T only sets
the overall time scale, not the allocation; k_T = 7 J(T0) / sum(T0) keeps the initial total. Finally all
times are scaled by one factor a so that the sampled speed, acceleration and thrust-to-weight limits
hold with the binding one met exactly (|v| ~ 1/a, |a| ~ 1/a^2; thrust: |a/a^2 + g e3| <= (T/W) f g and
a_z/a^2 + g >= f_min g solved in closed form).

Clearance repair: the curve is sampled about every `clearance_sample_spacing_m` of path; a segment whose
samples come closer to a block than the margin plus a bound on how far the clearance can dip between
two samples (see _violations; micrometres), or leave the bounds, gets a waypoint on the input path
halfway between its two waypoints - the A* point nearest the middle, or the middle of the straight A*
piece when its waypoints are adjacent A* points (splitting the segment) - times are re-optimised, and
this repeats until the whole continuous curve clears the margin. The waypoints converge onto the A*
path, whose pieces clear the margin, so the repair terminates in practice; after
`max_repair_rounds` rounds it gives up with a UserError. Where the A* path itself is inside the margin
(a start or goal within it, see astar.py) the curve is held to that path's clearance less half a
sample spacing instead.
"""

from __future__ import annotations

import bisect
import functools
import math
from dataclasses import dataclass

import numpy as np

# scipy.linalg.lapack and scipy.optimize are imported where they are used, so that a flight that plans nothing
# (hover, circle) starts without them: importing the ground station took 0.58-0.81 s that way against
# 0.80-1.01 s (4 interleaved pairs, 2-core machine).
from groundstation.planning import load_planning_params
from groundstation.planning.occupancy import segments_clearance
from groundstation.planning.pruning import prune_waypoints
from groundstation.trajectories.flat import at_rest
from groundstation.trajectory import FlatOutput
from model.config import Params
from model.errors import UserError
from model.vehicle import GRAVITY_MPS2, Vehicle, load_vehicle
from model.world import World

DEGREE = 7
N_COEF = DEGREE + 1
_BAND = 11  # lower and upper bandwidth of the knot-ordered system (see _pattern)
_POWERS = np.arange(N_COEF)
_FACT = np.array([math.factorial(k) for k in range(N_COEF)], float)


def _derivative_matrix(tau: float) -> np.ndarray:
    """(N_COEF, N_COEF) M[r, k] = d^r/dtau^r tau^k at tau (0 or 1)."""
    m = np.zeros((N_COEF, N_COEF))
    for r in range(N_COEF):
        for k in range(r, N_COEF):
            m[r, k] = _FACT[k] / _FACT[k - r] * (tau ** (k - r) if k > r else 1.0)
    return m


_D0 = _derivative_matrix(0.0)
_D1 = _derivative_matrix(1.0)
# Gram matrix of the 4th derivative on [0, 1]: int q''''^2 dtau = c^T Q c.
_Q = np.zeros((N_COEF, N_COEF))
for _k in range(4, N_COEF):
    for _l in range(4, N_COEF):
        _Q[_k, _l] = (_FACT[_k] / _FACT[_k - 4]) * (_FACT[_l] / _FACT[_l - 4]) / (_k + _l - 7)


@dataclass(frozen=True)
class MinSnapSettings:
    max_speed_mps: float
    max_accel_mps2: float
    max_thrust_accel_mps2: float  # |a + g e3| limit: safety factor x T/W x g
    min_vertical_thrust_accel_mps2: float  # a_z + g lower limit
    optimiser_max_evaluations: int
    optimiser_tolerance: float
    clearance_sample_spacing_m: float
    max_repair_rounds: int
    limit_samples_per_segment: int
    gravity_mps2: float = GRAVITY_MPS2

    @staticmethod
    def default(vehicle: str = "crazyflie") -> MinSnapSettings:
        """The shipped planning.toml [minsnap] limits for a built-in vehicle."""
        return MinSnapSettings.from_params(load_planning_params(), load_vehicle(vehicle))

    @staticmethod
    def from_params(params: Params, vehicle: Vehicle) -> MinSnapSettings:
        """From the [minsnap] table of a planning parameter file and the vehicle's thrust-to-weight ratio."""
        t = params.table("minsnap")
        factor = t.number("thrust_to_weight_safety_factor", minimum=0.0, maximum=1.0)
        max_thrust = factor * vehicle.thrust_to_weight * GRAVITY_MPS2
        if max_thrust <= GRAVITY_MPS2:
            raise t.error(
                "thrust_to_weight_safety_factor",
                f"{factor} x T/W {vehicle.thrust_to_weight:.2f} leaves no thrust above hover",
            )
        return MinSnapSettings(
            max_speed_mps=t.number("max_speed_mps", minimum=1e-3),
            max_accel_mps2=t.number("max_accel_mps2", minimum=1e-3),
            max_thrust_accel_mps2=max_thrust,
            min_vertical_thrust_accel_mps2=t.number(
                "min_vertical_thrust_to_weight", minimum=0.0, maximum=0.99
            )
            * GRAVITY_MPS2,
            optimiser_max_evaluations=t.integer("time_optimiser_max_evaluations", minimum=0),
            optimiser_tolerance=t.number("time_optimiser_tolerance", minimum=0.0),
            clearance_sample_spacing_m=t.number("clearance_sample_spacing_m", minimum=1e-4),
            max_repair_rounds=t.integer("max_repair_rounds", minimum=0),
            limit_samples_per_segment=t.integer("limit_samples_per_segment", minimum=4),
        )


class MinSnapTrajectory:
    """Piecewise degree-7 polynomial reference; sample() costs one small matrix-vector product.

    sample() runs twice per control tick: the powers of tau are float products, and one (15, 8) table per
    segment (rows: position, velocity, ..., snap, each x, y, z) maps them to all 15 numbers in one dot.
    """

    sample_is_pure = True  # a function of t alone (groundstation.trajectory)

    def __init__(self, waypoints_m: np.ndarray, segment_times_s: np.ndarray, coefficients: np.ndarray):
        self.waypoints_m = waypoints_m  # (K, 3)
        self.segment_times_s = segment_times_s  # (n,)
        self.coefficients = coefficients  # (n, 8, 3) per segment, in normalised time tau
        self.knot_times_s = np.r_[0.0, np.cumsum(segment_times_s)]
        self.duration_s = float(self.knot_times_s[-1])
        self._knots = self.knot_times_s.tolist()
        # E[i, r, :, k]: coefficient of tau^k in the r-th TIME derivative (r = 0..4) of segment i.
        shifted = np.zeros((len(segment_times_s), 5, 3, N_COEF))
        for r in range(5):
            scale = _D1[r, r:]  # k!/(k-r)!
            shifted[:, r, :, : N_COEF - r] = (coefficients[:, r:, :] * scale[None, :, None]).transpose(
                0, 2, 1
            )
            shifted[:, r] /= segment_times_s[:, None, None] ** r
        self._table = shifted
        self._rows = [np.ascontiguousarray(table.reshape(15, N_COEF)) for table in shifted]
        self._times = segment_times_s.tolist()

    def sample(self, t_s: float) -> FlatOutput:
        if t_s <= 0.0 or self.duration_s == 0.0:
            return at_rest(self.waypoints_m[0])
        if t_s >= self.duration_s:
            return at_rest(self.waypoints_m[-1])
        i = min(bisect.bisect_right(self._knots, t_s) - 1, len(self._times) - 1)
        tau = (t_s - self._knots[i]) / self._times[i]
        tau2 = tau * tau
        tau3 = tau2 * tau
        tau4 = tau2 * tau2
        out = self._rows[i].dot(np.array([1.0, tau, tau2, tau3, tau4, tau4 * tau, tau3 * tau3, tau4 * tau3]))
        return FlatOutput(out[0:3], out[3:6], out[6:9], out[9:12], out[12:15])

    def evaluate(self, t_s: np.ndarray) -> np.ndarray:
        """Vectorised: (5, S, 3) position, velocity, acceleration, jerk, snap at times t_s (S,)."""
        if len(self.segment_times_s) == 0:  # a single waypoint: hold it
            out = np.zeros((5, np.size(t_s), 3))
            out[0] = self.waypoints_m[0]
            return out
        t = np.clip(np.asarray(t_s, float), 0.0, self.duration_s)
        i = np.clip(np.searchsorted(self.knot_times_s, t, side="right") - 1, 0, len(self.segment_times_s) - 1)
        tau = (t - self.knot_times_s[i]) / self.segment_times_s[i]
        out = np.einsum("srak,sk->rsa", self._table[i], tau[:, None] ** _POWERS)
        before_or_after = (np.asarray(t_s) <= 0.0) | (np.asarray(t_s) >= self.duration_s)
        out[1:, before_or_after] = 0.0
        return out

    def segment_samples(self, per_segment: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Times (S,) and segment index (S,) of `per_segment[i]` evenly spaced samples in each segment,
        both ends included."""
        counts = np.maximum(np.asarray(per_segment, int), 2)
        seg = np.repeat(np.arange(len(counts)), counts)
        start = np.repeat(np.cumsum(counts) - counts, counts)
        tau = (np.arange(counts.sum()) - start) / (counts[seg] - 1)
        return self.knot_times_s[seg] + tau * self.segment_times_s[seg], seg


@dataclass(frozen=True)
class MinSnapPlan:
    trajectory: MinSnapTrajectory
    # (K,) where the waypoints lie on the input path: k = path point k; k + f = on the piece k..k+1
    # (inserted by the repair when it had to split between two adjacent path points)
    path_positions: np.ndarray
    repairs: int  # waypoints inserted to clear the margin
    min_clearance_m: float  # smallest sampled distance to a block


# ---------------------------------------------------------------------------------------------------
# Fixed times: the linear system


def solve_coefficients(waypoints_m: np.ndarray, segment_times_s: np.ndarray) -> np.ndarray:
    """Minimum-snap coefficients (n, 8, 3) in normalised time for fixed segment times (n,)."""
    w = np.asarray(waypoints_m, float)
    times = np.asarray(segment_times_s, float)
    n = len(times)
    pattern = _pattern(n)
    ratios = np.r_[times[1:] / times[:-1], 1.0]  # T_j / T_j-1 at interior knot j (index j-1); pad
    vals = pattern.values * ratios[pattern.knot] ** pattern.power
    size = N_COEF * n
    # LAPACK dgbsv storage: 2 kl + ku + 1 rows, the first kl left free for the LU fill-in.
    banded = np.zeros((3 * _BAND + 1, size))
    banded[2 * _BAND + pattern.rows - pattern.cols, pattern.cols] = vals
    rhs = np.zeros((size, 3))
    rhs[pattern.rhs_rows] = w[pattern.rhs_points]
    import scipy.linalg.lapack  # here, not at the top: see the imports

    _, _, solution, info = scipy.linalg.lapack.dgbsv(_BAND, _BAND, banded, rhs, overwrite_ab=1, overwrite_b=1)
    if info != 0:
        raise UserError(f"minimum-snap trajectory: singular system (LAPACK dgbsv info {info})")
    return solution.reshape(n, N_COEF, 3)


@dataclass(frozen=True)
class _Pattern:
    rows: np.ndarray
    cols: np.ndarray
    values: np.ndarray  # entries with all time ratios 1
    knot: np.ndarray  # index of the ratio T_j/T_j-1 scaling each entry (the pad index n-1 for none)
    power: np.ndarray  # its power r
    rhs_rows: np.ndarray
    rhs_points: np.ndarray


@functools.lru_cache(maxsize=64)
def _pattern(n: int) -> _Pattern:
    """The knot-ordered system for n segments, with the time ratios factored out.

    Row order: the 4 start rows (position, v, a, j of segment 0 at tau = 0); for each interior knot j,
    8 rows: position of segment j-1 at tau = 1, derivatives r = 1..6 continuous (scaled by T_j^r:
    (T_j/T_j-1)^r x_j-1^(r)(1) - x_j^(r)(0) = 0), position of segment j at tau = 0; the 4 end rows.
    Every row touches at most the 16 columns of two neighbouring segments: bandwidth 11.
    """
    rows, cols, vals, knots, powers = [], [], [], [], []

    def add(row: int, segment: int, coefs: np.ndarray, knot: int = n - 1, power: int = 0) -> None:
        nz = np.flatnonzero(coefs)
        rows.append(np.full(len(nz), row))
        cols.append(N_COEF * segment + nz)
        vals.append(coefs[nz])
        knots.append(np.full(len(nz), knot))
        powers.append(np.full(len(nz), power))

    rhs_rows, rhs_points = [0], [0]
    for r in range(4):
        add(r, 0, _D0[r])
    for j in range(1, n):
        base = 4 + 8 * (j - 1)
        add(base, j - 1, _D1[0])
        for r in range(1, 7):
            add(base + r, j - 1, _D1[r], knot=j - 1, power=r)
            add(base + r, j, -_D0[r])
        add(base + 7, j, _D0[0])
        rhs_rows += [base, base + 7]
        rhs_points += [j, j]
    end = 4 + 8 * (n - 1)
    for r in range(4):
        add(end + r, n - 1, _D1[r])
    rhs_rows.append(end)
    rhs_points.append(n)
    return _Pattern(
        np.concatenate(rows),
        np.concatenate(cols),
        np.concatenate(vals),
        np.concatenate(knots),
        np.concatenate(powers),
        np.array(rhs_rows),
        np.array(rhs_points),
    )


def snap_cost_and_gradient(coefficients: np.ndarray, segment_times_s: np.ndarray) -> tuple[float, np.ndarray]:
    """J = sum_i int |x''''|^2 dt (m^2/s^7) and dJ/dT_i = -H_i (evaluated at tau = 0 of segment i)."""
    c, times = coefficients, segment_times_s
    per_segment = np.einsum("nka,kl,nla->n", c, _Q, c) / times**7
    f = _FACT
    hamiltonian = (
        (f[4] * c[:, 4]) ** 2
        - 2.0 * (f[5] * c[:, 5]) * (f[3] * c[:, 3])
        + 2.0 * (f[6] * c[:, 6]) * (f[2] * c[:, 2])
        - 2.0 * (f[7] * c[:, 7]) * (f[1] * c[:, 1])
    ).sum(-1) / times**8
    return float(per_segment.sum()), -hamiltonian


def min_snap(waypoints_m: np.ndarray, segment_times_s: np.ndarray) -> MinSnapTrajectory:
    """The minimum-snap trajectory for fixed segment times."""
    w = np.asarray(waypoints_m, float).reshape(-1, 3)
    times = np.asarray(segment_times_s, float)
    return MinSnapTrajectory(w, times, solve_coefficients(w, times))


# ---------------------------------------------------------------------------------------------------
# Time allocation


def trapezoid_times(waypoints_m: np.ndarray, max_speed_mps: float, max_accel_mps2: float) -> np.ndarray:
    """Rest-to-rest time of each segment with a trapezoidal (or triangular) speed profile."""
    d = np.linalg.norm(np.diff(np.asarray(waypoints_m, float), axis=0), axis=1)
    v, a = max_speed_mps, max_accel_mps2
    return np.where(d >= v * v / a, d / v + v / a, 2.0 * np.sqrt(d / a))


def optimise_times(
    waypoints_m: np.ndarray, initial_times_s: np.ndarray, max_evaluations: int = 100, tolerance: float = 1e-6
) -> np.ndarray:
    """Segment times minimising J(T) + k_T sum(T), k_T = 7 J(T0)/sum(T0) (keeps the total near sum(T0))."""
    w = np.asarray(waypoints_m, float)
    t0 = np.asarray(initial_times_s, float)
    if len(t0) < 2 or max_evaluations == 0:
        return t0.copy()  # one segment: the allocation is only the scale, set by the limits
    j0, _ = snap_cost_and_gradient(solve_coefficients(w, t0), t0)
    if not j0 > 0:
        return t0.copy()
    k_t = 7.0 * j0 / t0.sum()
    scale = j0 + k_t * t0.sum()

    def cost(log_t: np.ndarray) -> tuple[float, np.ndarray]:
        times = np.exp(log_t)
        j, dj = snap_cost_and_gradient(solve_coefficients(w, times), times)
        return (j + k_t * times.sum()) / scale, (dj + k_t) * times / scale

    # Bounds keep every segment within a factor e^3 of its initial time (no degenerate segments).
    bounds = [(x - 3.0, x + 3.0) for x in np.log(t0)]
    # TNC rather than L-BFGS-B: about twice the evaluations, but L-BFGS-B's driver calls
    # multithreaded OpenBLAS, which stalls for tens of ms on a busy 2-core machine.
    import scipy.optimize  # here, not at the top: see the imports

    result = scipy.optimize.minimize(
        cost,
        np.log(t0),
        jac=True,
        method="TNC",
        bounds=bounds,
        options={"maxfun": max_evaluations, "ftol": tolerance},
    )
    return np.exp(result.x)


def limit_scale(trajectory: MinSnapTrajectory, settings: MinSnapSettings) -> float:
    """The time scale a >= 0 that makes the binding limit hold exactly (times T -> a T)."""
    t, _ = trajectory.segment_samples(
        np.full(len(trajectory.segment_times_s), settings.limit_samples_per_segment)
    )
    out = trajectory.evaluate(t)
    vel, acc = out[1], out[2]
    g = settings.gravity_mps2
    speed = np.linalg.norm(vel, axis=1).max()
    acc_norm2 = (acc * acc).sum(1)
    scales = [speed / settings.max_speed_mps, math.sqrt(math.sqrt(acc_norm2.max()) / settings.max_accel_mps2)]
    # |s a + g e3|^2 <= tmax^2 with s = 1/a^2: s <= the positive root of |a|^2 s^2 + 2 g a_z s + g^2 - tmax^2.
    tmax = settings.max_thrust_accel_mps2
    moving = acc_norm2 > 0
    if moving.any():
        a2, az = acc_norm2[moving], acc[moving, 2]
        root = (-g * az + np.sqrt((g * az) ** 2 - a2 * (g * g - tmax * tmax))) / a2
        scales.append(1.0 / math.sqrt(root.min()))
    falling = acc[:, 2] < 0  # s a_z + g >= min thrust:  s <= (g - tmin) / -a_z
    if falling.any():
        s_max = (g - settings.min_vertical_thrust_accel_mps2) / -acc[falling, 2]
        scales.append(1.0 / math.sqrt(s_max.min()))
    return max(scales)


def min_snap_through(
    waypoints_m: np.ndarray,
    settings: MinSnapSettings | None = None,
    initial_times_s: np.ndarray | None = None,
) -> MinSnapTrajectory:
    """Minimum-snap trajectory through waypoints with optimised, limit-scaled segment times."""
    s = settings or MinSnapSettings.default()
    w = _checked_waypoints(waypoints_m)
    if len(w) == 1:
        return MinSnapTrajectory(w, np.zeros(0), np.zeros((0, N_COEF, 3)))
    if initial_times_s is None:
        initial_times_s = trapezoid_times(w, s.max_speed_mps, s.max_accel_mps2)
    times = optimise_times(w, initial_times_s, s.optimiser_max_evaluations, s.optimiser_tolerance)
    shape = min_snap(w, times)
    return _scaled(w, times, shape, limit_scale(shape, s))


def _scaled(w: np.ndarray, times: np.ndarray, shape: MinSnapTrajectory, a: float) -> MinSnapTrajectory:
    # Scaling time keeps the normalised-time coefficients: the same curve, traversed a times slower.
    return MinSnapTrajectory(w, times * a, shape.coefficients)


def _checked_waypoints(waypoints_m: np.ndarray) -> np.ndarray:
    w = np.asarray(waypoints_m, float).reshape(-1, 3)
    if len(w) == 0 or not np.all(np.isfinite(w)):
        raise UserError("minimum-snap trajectory: waypoints must be a non-empty list of finite points")
    if len(w) > 1 and np.any(np.linalg.norm(np.diff(w, axis=0), axis=1) == 0):
        raise UserError("minimum-snap trajectory: two consecutive waypoints coincide")
    return w


# ---------------------------------------------------------------------------------------------------
# Through a world: prune, solve, check clearance, repair


def plan_min_snap(
    path_m: np.ndarray, world: World, margin_m: float, settings: MinSnapSettings | None = None
) -> MinSnapPlan:
    """Minimum-snap trajectory along a dense collision-free path (e.g. A*'s), clear of the margin.

    Raises UserError when the curve still cuts the margin after `max_repair_rounds` rounds.
    """
    s = settings or MinSnapSettings.default()
    path = np.asarray(path_m, float).reshape(-1, 3)
    path = path[np.r_[True, np.any(np.diff(path, axis=0) != 0, axis=1)]]
    positions = prune_waypoints(path, world, margin_m).astype(float)
    if len(positions) == 1:
        clearance = float(world.distance_to_blocks(path[0]))
        return MinSnapPlan(min_snap_through(path[:1], s), positions, 0, clearance)
    # Clearance of each straight piece of the input path: below the margin only where the path itself
    # is (a start or goal inside the margin), and then the curve is held to that instead.
    path_clearance = segments_clearance(world, path[:-1], path[1:], cutoff_m=margin_m)
    waypoints = _on_path(path, positions)
    times = optimise_times(
        waypoints,
        trapezoid_times(waypoints, s.max_speed_mps, s.max_accel_mps2),
        s.optimiser_max_evaluations,
        s.optimiser_tolerance,
    )
    repairs = 0
    for _ in range(s.max_repair_rounds + 1):
        shape = min_snap(waypoints, times)
        required = _required_clearance(positions, path_clearance, margin_m, s.clearance_sample_spacing_m)
        bad, clearance = _violations(shape, world, required, s.clearance_sample_spacing_m)
        if not bad.any():
            trajectory = _scaled(waypoints, times, shape, limit_scale(shape, s))
            return MinSnapPlan(trajectory, positions, repairs, clearance)
        positions, times = _split(path, positions, times, bad)
        repairs += int(bad.sum())
        waypoints = _on_path(path, positions)
        times = optimise_times(waypoints, times, s.optimiser_max_evaluations, s.optimiser_tolerance)
    raise UserError(
        f"{world.source}: minimum-snap trajectory still comes within the margin {margin_m} m of a "
        f"block after {repairs} inserted waypoints (clearance {clearance:.4f} m)"
    )


def _on_path(path: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """Points (K, 3) at positions along the path: k is path[k], k + f lies on the piece k..k+1 at f."""
    i = np.minimum(np.floor(positions).astype(int), len(path) - 2)
    f = (positions - i)[:, None]
    return path[i] + f * (path[i + 1] - path[i])


def _required_clearance(
    positions: np.ndarray, path_clearance: np.ndarray, margin_m: float, spacing_m: float
) -> np.ndarray:
    """Clearance (n,) each segment of the curve must keep: the margin, or - where the input path between
    the segment's waypoints is itself closer (a start/goal inside the margin) - that clearance less half
    a sample spacing (the curve leaves such a start at rest and cannot do better than the start)."""
    first = np.floor(positions[:-1]).astype(int)
    last = np.maximum(np.ceil(positions[1:]).astype(int) - 1, first)
    lowest = np.array([path_clearance[i : j + 1].min() for i, j in zip(first, last, strict=True)])
    return np.where(lowest > margin_m, margin_m, lowest - spacing_m / 2)


def _violations(
    trajectory: MinSnapTrajectory, world: World, required: np.ndarray, spacing_m: float
) -> tuple[np.ndarray, float]:
    """Segments (n,) whose curve may come closer to a block than `required` (or leave the bounds), and
    the smallest sampled clearance.

    Samples lie about `spacing_m` apart along the curve. Between two samples the clearance d can dip
    below the smaller sampled value by at most min(|v| dt / 2, (|a| + |v|^2 / d_lo) dt^2 / 8): the first
    because d is 1-Lipschitz in space, the second because the distance to a convex box has a Hessian
    <= 1/d_lo (d >= d_lo = required/2 wherever the curve is not already flagged), so d(t) has second
    derivative <= |a| + |v|^2 / d_lo. Samples must clear the requirement by that bound (a few um at
    2 mm spacing), so the continuous curve clears it everywhere.
    """
    n = len(trajectory.segment_times_s)
    coarse_t, coarse_seg = trajectory.segment_samples(np.full(n, 33))
    coarse = trajectory.evaluate(coarse_t)[0]
    steps = np.linalg.norm(np.diff(coarse, axis=0), axis=1)
    steps[coarse_seg[1:] != coarse_seg[:-1]] = 0.0
    lengths = np.bincount(coarse_seg[1:], weights=steps, minlength=n)
    counts = np.ceil(1.05 * lengths / spacing_m).astype(int) + 2  # 5 % over the chord-length estimate
    t, seg = trajectory.segment_samples(counts)
    out = trajectory.evaluate(t)
    clearance = world.distance_to_blocks(out[0])
    speed_max, accel_max = np.zeros(n), np.zeros(n)
    np.maximum.at(speed_max, seg, np.linalg.norm(out[1], axis=1))
    np.maximum.at(accel_max, seg, np.linalg.norm(out[2], axis=1))
    speed_max *= 1.1  # the peaks between samples: a 10 % allowance
    accel_max *= 1.1
    dt = trajectory.segment_times_s / (np.maximum(counts, 2) - 1)
    lipschitz = speed_max * dt / 2
    with np.errstate(divide="ignore"):
        curvature = (accel_max + speed_max**2 / (required / 2)) * dt**2 / 8
    dip = np.where(required > 0, np.minimum(lipschitz, curvature), lipschitz)
    too_close = (clearance < (required + dip)[seg]) | ~world.contains(out[0])
    bad = np.bincount(seg, weights=too_close, minlength=n) > 0
    return bad, float(clearance.min())


def _split(path: np.ndarray, positions: np.ndarray, times: np.ndarray, bad: np.ndarray):
    """Insert a waypoint on the input path halfway (in path position) along each offending segment:
    the path point nearest the middle if one lies strictly between, else the middle of the path piece
    it spans. Each offending segment's time is split in proportion to the new chords."""
    new_positions, new_times = [positions[0]], []
    for j in range(len(positions) - 1):
        a, b = positions[j], positions[j + 1]
        if not bad[j]:
            new_positions.append(b)
            new_times.append(times[j])
            continue
        lo, hi = math.floor(a) + 1, math.ceil(b) - 1
        middle = float(np.clip(round((a + b) / 2), lo, hi)) if lo <= hi else (a + b) / 2
        pa, pm, pb = _on_path(path, np.array([a, middle, b]))
        d1, d2 = np.linalg.norm(pm - pa), np.linalg.norm(pb - pm)
        new_positions += [middle, b]
        new_times += [times[j] * d1 / (d1 + d2), times[j] * d2 / (d1 + d2)]
    return np.array(new_positions), np.array(new_times)
