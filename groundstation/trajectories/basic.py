"""Built-in reference trajectories: hover, straight line, circle, and the report's step experiment.

Takes in: start/end positions (world ENU, m), speeds (m/s), durations (s), yaw (rad); defaults from a
trajectories TOML (groundstation/params/trajectories.toml) for `make_builtin`.
Gives out: objects implementing groundstation.trajectory.Trajectory: `sample(t_s) -> FlatOutput` with
analytic velocity, acceleration, jerk and snap; they hold the start before t = 0 and the end after
`duration_s`, at rest.

Smooth profiles use the septic smoothstep s(tau) = 35 tau^4 - 84 tau^5 + 70 tau^6 - 20 tau^7 on [0, 1]:
rest to rest with zero velocity, acceleration and jerk at both ends (the minimum-snap rest-to-rest
polynomial). `Step` is deliberately not smooth: all derivatives zero, as in the report's tuning flights.

sample() runs twice per control tick, so it works on Python floats with what does not change precomputed
at construction (groundstation/trajectories/flat.py says why); numpy's Polynomial is used only to derive
the coefficients, once.
"""

from __future__ import annotations

import bisect
import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.polynomial import Polynomial

from groundstation.trajectories.flat import at_rest, flat_output, polyval
from groundstation.trajectory import FlatOutput, Trajectory
from model.config import Params, resolve
from model.errors import UserError

SMOOTHSTEP = Polynomial([0.0, 0.0, 0.0, 0.0, 35.0, -84.0, 70.0, -20.0])
# s, s', s'', s''', s'''' of the smoothstep, and its integral (for the circle's angle during spin-up).
_SMOOTHSTEP_DERIVATIVES = tuple(SMOOTHSTEP.deriv(k) if k else SMOOTHSTEP for k in range(5))
_SMOOTHSTEP_INTEGRAL = SMOOTHSTEP.integ()
# Peak of s' (at tau = 1/2): the ratio of peak to mean speed of a smoothstep move.
SMOOTHSTEP_PEAK_RATE = float(_SMOOTHSTEP_DERIVATIVES[1](0.5))
# The same as coefficient tuples (lowest power first) for polyval on floats.
_SMOOTHSTEP_COEFFICIENTS = tuple(tuple(p.coef.tolist()) for p in _SMOOTHSTEP_DERIVATIVES)
_SMOOTHSTEP_INTEGRAL_COEFFICIENTS = tuple(_SMOOTHSTEP_INTEGRAL.coef.tolist())

AXES = {"x": 0, "y": 1, "z": 2}


def _vector3(value: Sequence[float], what: str) -> np.ndarray:
    v = np.asarray(value, dtype=float)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise UserError(f"{what}: expected three finite numbers (m), got {value!r}")
    return v


def _positive(value: float, what: str) -> float:
    if not (math.isfinite(value) and value > 0.0):
        raise UserError(f"{what}: expected a positive number, got {value!r}")
    return float(value)


def _non_negative(value: float, what: str) -> float:
    if not (math.isfinite(value) and value >= 0.0):
        raise UserError(f"{what}: expected a non-negative number, got {value!r}")
    return float(value)


class Hover:
    """Hold one position (world ENU, m) at yaw `yaw_rad` for `duration_s`."""

    sample_is_pure = True  # a function of t alone (groundstation.trajectory)

    def __init__(self, position_m: Sequence[float], duration_s: float, yaw_rad: float = 0.0):
        self.position_m = _vector3(position_m, "hover position_m")
        self.duration_s = _non_negative(duration_s, "hover duration_s")
        self.yaw_rad = float(yaw_rad)

    def sample(self, t_s: float) -> FlatOutput:
        return at_rest(self.position_m, self.yaw_rad)


class Line:
    """Rest-to-rest straight move start -> end with a smoothstep profile peaking at `speed_mps`, then a hold.

    r(t) = start + (end - start) s(t / T), T = s'(1/2) |end - start| / speed (s'(1/2) = 35/16 is the
    peak-to-mean speed ratio); the k-th derivative is (end - start) s^(k)(t/T) / T^k.
    """

    sample_is_pure = True  # a function of t alone (groundstation.trajectory)

    def __init__(self, start_m: Sequence[float], end_m: Sequence[float], speed_mps: float = 0.5,
                 hold_s: float = 0.0, yaw_rad: float = 0.0):
        self.start_m = _vector3(start_m, "line start_m")
        self.end_m = _vector3(end_m, "line end_m")
        self.speed_mps = _positive(speed_mps, "line speed_mps")
        self.yaw_rad = float(yaw_rad)
        self.length_m = float(np.linalg.norm(self.end_m - self.start_m))
        self.move_s = SMOOTHSTEP_PEAK_RATE * self.length_m / self.speed_mps
        self.duration_s = self.move_s + _non_negative(hold_s, "line hold_s")
        self._start = self.start_m.tolist()
        self._delta = (self.end_m - self.start_m).tolist()
        self._time_scales = tuple(self.move_s**k for k in range(5))  # T^k: s^(k)(t/T) / T^k

    def sample(self, t_s: float) -> FlatOutput:
        move_s = self.move_s
        if t_s <= 0.0 or move_s == 0.0:
            return at_rest(self.start_m if t_s <= 0.0 else self.end_m, self.yaw_rad)
        if t_s >= move_s:
            return at_rest(self.end_m, self.yaw_rad)
        tau = t_s / move_s
        sx, sy, sz = self._start
        dx, dy, dz = self._delta
        d0, d1, d2, d3, d4 = (polyval(c, tau) / scale
                              for c, scale in zip(_SMOOTHSTEP_COEFFICIENTS, self._time_scales, strict=True))
        return flat_output([sx + d0 * dx, sy + d0 * dy, sz + d0 * dz, d1 * dx, d1 * dy, d1 * dz,
                            d2 * dx, d2 * dy, d2 * dz, d3 * dx, d3 * dy, d3 * dz, d4 * dx, d4 * dy, d4 * dz],
                           self.yaw_rad)


class Chain:
    """Trajectories flown one after another (rest-to-rest segments such as Line join smoothly)."""

    def __init__(self, *segments):
        if not segments:
            raise ValueError("a chain needs at least one segment")
        self.segments = segments
        self._starts = list(itertools.accumulate((s.duration_s for s in segments[:-1]), initial=0.0))
        self.duration_s = self._starts[-1] + segments[-1].duration_s
        self.sample_is_pure = all(getattr(segment, "sample_is_pure", False) for segment in segments)

    def sample(self, t_s: float) -> FlatOutput:
        i = max(0, bisect.bisect_right(self._starts, t_s) - 1)
        return self.segments[i].sample(t_s - self._starts[i])


class Circle:
    """Horizontal counter-clockwise circle at the centre's height, starting and ending at rest.

    Position: r(t) = c + R [cos theta, sin theta, 0]. The angular rate theta' rises from 0 to
    Omega = speed/R over `spin_up_s` along the smoothstep, cruises, and falls back symmetrically, so the
    angle covers exactly 2 pi laps: T = 2 pi laps / Omega + spin_up_s. Derivatives come from
    z = R e^{i theta}: z' = i theta' z, z'' = (i theta'' - theta'^2) z,
    z''' = (i theta''' - 3 theta' theta'' - i theta'^3) z,
    z'''' = (i theta'''' - 4 theta' theta''' - 3 theta''^2 - 6 i theta'^2 theta'' + theta'^4) z.
    Default spin-up: the peak tangential acceleration equals the cruise centripetal one, speed^2 / R.
    """

    sample_is_pure = True  # a function of t alone (groundstation.trajectory)

    def __init__(self, center_m: Sequence[float], radius_m: float, speed_mps: float, laps: float = 1,
                 spin_up_s: float | None = None, start_angle_rad: float = 0.0, yaw_rad: float = 0.0):
        self.center_m = _vector3(center_m, "circle center_m")
        self.radius_m = _positive(radius_m, "circle radius_m")
        self.speed_mps = _positive(speed_mps, "circle speed_mps")
        self.laps = _positive(laps, "circle laps")
        self.rate_radps = self.speed_mps / self.radius_m
        if spin_up_s is None:
            spin_up_s = SMOOTHSTEP_PEAK_RATE * self.radius_m / self.speed_mps
        self.spin_up_s = _positive(spin_up_s, "circle spin_up_s")
        self.total_angle_rad = 2.0 * math.pi * self.laps
        if self.total_angle_rad < self.rate_radps * self.spin_up_s:
            raise UserError(f"circle: {self.laps} laps at {self.speed_mps} m/s are too short for a "
                            f"{self.spin_up_s} s spin-up and spin-down; lower spin_up_s or the speed")
        self.duration_s = self.total_angle_rad / self.rate_radps + self.spin_up_s
        self.start_angle_rad = float(start_angle_rad)
        self.yaw_rad = float(yaw_rad)
        self._center = self.center_m.tolist()

    def angle_derivatives(self, t_s: float) -> tuple[float, float, float, float, float]:
        """theta and its first four time derivatives (rad, rad/s, ... rad/s^4) at t_s."""
        t = min(max(t_s, 0.0), self.duration_s)
        omega, ramp = self.rate_radps, self.spin_up_s
        s0, s1, s2, s3 = _SMOOTHSTEP_COEFFICIENTS[:4]
        if t < ramp:
            tau = t / ramp
            return (omega * ramp * polyval(_SMOOTHSTEP_INTEGRAL_COEFFICIENTS, tau), omega * polyval(s0, tau),
                    omega * polyval(s1, tau) / ramp, omega * polyval(s2, tau) / ramp**2,
                    omega * polyval(s3, tau) / ramp**3)
        if t > self.duration_s - ramp:  # mirror image of the spin-up: tau runs backwards
            tau = (self.duration_s - t) / ramp
            return (self.total_angle_rad - omega * ramp * polyval(_SMOOTHSTEP_INTEGRAL_COEFFICIENTS, tau),
                    omega * polyval(s0, tau), -omega * polyval(s1, tau) / ramp,
                    omega * polyval(s2, tau) / ramp**2, -omega * polyval(s3, tau) / ramp**3)
        return omega * (t - 0.5 * ramp), omega, 0.0, 0.0, 0.0

    def sample(self, t_s: float) -> FlatOutput:
        theta, d1, d2, d3, d4 = self.angle_derivatives(t_s)
        angle = theta + self.start_angle_rad
        zr, zi = self.radius_m * math.cos(angle), self.radius_m * math.sin(angle)  # z = R e^{i angle}
        # The factors f = a + i b of the docstring; each derivative is f z = (a zr - b zi) + i (a zi + b zr).
        a2, b2 = -(d1**2), d2
        a3, b3 = -(3.0 * d1 * d2), d3 - d1**3
        a4, b4 = -(4.0 * d1 * d3) - 3.0 * d2**2 + d1**4, d4 - 6.0 * d1**2 * d2
        cx, cy, cz = self._center
        return flat_output([cx + zr, cy + zi, cz + 0.0, -d1 * zi, d1 * zr, 0.0,
                            a2 * zr - b2 * zi, a2 * zi + b2 * zr, 0.0, a3 * zr - b3 * zi, a3 * zi + b3 * zr, 0.0,
                            a4 * zr - b4 * zi, a4 * zi + b4 * zr, 0.0], self.yaw_rad)


class Step:
    """The report's tuning experiment: hover at start, jump by size_m along axis at step_at_s, hold hold_s.

    All derivatives are zero: the reference is a true step.
    """

    sample_is_pure = True  # a function of t alone (groundstation.trajectory)

    def __init__(self, start_m: Sequence[float], axis: str | int, size_m: float, hold_s: float,
                 step_at_s: float, yaw_rad: float = 0.0):
        self.start_m = _vector3(start_m, "step start_m")
        if isinstance(axis, str) and axis.lower() in AXES:
            self.axis = AXES[axis.lower()]
        elif isinstance(axis, int) and not isinstance(axis, bool) and axis in AXES.values():
            self.axis = axis
        else:
            raise UserError(f"step axis: expected one of x, y, z, got {axis!r}")
        if not math.isfinite(size_m):
            raise UserError(f"step size_m: expected a finite number, got {size_m!r}")
        self.size_m = float(size_m)
        self.step_at_s = _non_negative(step_at_s, "step step_at_s")
        self.duration_s = self.step_at_s + _non_negative(hold_s, "step hold_s")
        self.end_m = self.start_m.copy()
        self.end_m[self.axis] += self.size_m
        self.yaw_rad = float(yaw_rad)

    def sample(self, t_s: float) -> FlatOutput:
        return at_rest(self.start_m if t_s < self.step_at_s else self.end_m, self.yaw_rad)


@dataclass(frozen=True)
class HoverParams:
    height_m: float
    climb_speed_mps: float
    duration_s: float


@dataclass(frozen=True)
class LineParams:
    length_m: float
    direction_enu: tuple[float, float, float]  # unit vector
    speed_mps: float
    hold_s: float


@dataclass(frozen=True)
class CircleParams:
    radius_m: float
    speed_mps: float
    laps: int
    spin_up_s: float
    direction_to_start_enu: tuple[float, float, float]  # horizontal unit vector, centre -> start


@dataclass(frozen=True)
class StepParams:
    axis: str
    size_m: float
    step_at_s: float
    hold_s: float


@dataclass(frozen=True)
class TrajectoryParams:
    hover: HoverParams
    line: LineParams
    circle: CircleParams
    step: StepParams
    source: str = ""


def _unit(params: Params, key: str, horizontal: bool = False) -> tuple[float, float, float]:
    v = np.array(params.vector(key, 3))
    if horizontal:
        v[2] = 0.0
    norm = float(np.linalg.norm(v))
    if norm == 0.0:
        raise params.error(key, "must be a non-zero" + (" horizontal" if horizontal else "") + " vector")
    x, y, z = (v / norm).tolist()
    return (x, y, z)


def load_trajectory_params(name_or_path: str | Path = "trajectories") -> TrajectoryParams:
    """Built-in trajectory defaults from a TOML file (built-in name: "trajectories")."""
    p = Params.load(resolve(name_or_path, "groundstation", "params", "trajectory parameters"))
    hover, line, circle, step = (p.table(k) for k in ("hover", "line", "circle", "step"))
    return TrajectoryParams(
        hover=HoverParams(height_m=hover.number("height_m"),
                          climb_speed_mps=hover.number("climb_speed_mps", minimum=1e-3),
                          duration_s=hover.number("duration_s", minimum=0.0)),
        line=LineParams(length_m=line.number("length_m", minimum=0.0),
                        direction_enu=_unit(line, "direction_enu"),
                        speed_mps=line.number("speed_mps", minimum=1e-3),
                        hold_s=line.number("hold_s", minimum=0.0)),
        circle=CircleParams(radius_m=circle.number("radius_m", minimum=1e-3),
                            speed_mps=circle.number("speed_mps", minimum=1e-3),
                            laps=circle.integer("laps", minimum=1),
                            spin_up_s=circle.number("spin_up_s", minimum=1e-3),
                            direction_to_start_enu=_unit(circle, "direction_to_start_enu", horizontal=True)),
        step=StepParams(axis=step.string("axis", choices=tuple(AXES)),
                        size_m=step.number("size_m"),
                        step_at_s=step.number("step_at_s", minimum=0.0),
                        hold_s=step.number("hold_s", minimum=0.0)),
        source=p.string("source"),
    )


BUILTIN_NAMES = ("hover", "line", "circle", "step")


def make_builtin(name: str, start_m: Sequence[float], params: TrajectoryParams | None = None,
                 yaw_rad: float = 0.0) -> Trajectory:
    """A built-in trajectory beginning at rest at start_m (world ENU, m).

    hover: climb/descend smoothly to (x0, y0, height_m), then hold duration_s.
    line: move length_m along direction_enu, then hold.
    circle: laps around a centre radius_m from the start (the start lies on the circle), back to the start.
    step: the report's step experiment along axis.
    """
    params = load_trajectory_params() if params is None else params
    start = _vector3(start_m, "start_m")
    if name == "hover":
        h = params.hover
        top = np.array([start[0], start[1], h.height_m])
        return Line(start, top, speed_mps=h.climb_speed_mps, hold_s=h.duration_s, yaw_rad=yaw_rad)
    if name == "line":
        ln = params.line
        return Line(start, start + ln.length_m * np.array(ln.direction_enu), speed_mps=ln.speed_mps,
                    hold_s=ln.hold_s, yaw_rad=yaw_rad)
    if name == "circle":
        c = params.circle
        to_start = np.array(c.direction_to_start_enu)
        return Circle(start - c.radius_m * to_start, c.radius_m, c.speed_mps, laps=c.laps,
                      spin_up_s=c.spin_up_s, start_angle_rad=math.atan2(to_start[1], to_start[0]),
                      yaw_rad=yaw_rad)
    if name == "step":
        s = params.step
        return Step(start, s.axis, s.size_m, hold_s=s.hold_s, step_at_s=s.step_at_s, yaw_rad=yaw_rad)
    raise UserError(f"unknown built-in trajectory '{name}' (built-in: {', '.join(BUILTIN_NAMES)})")
