"""Rigid-body quadrotor dynamics with floor contact and crash detection.

Takes in: a Vehicle (model.vehicle), contact rules (ContactParams, from simulator/params/firmware.toml),
an optional World, a fixed step dt (s), and commanded rotor speeds (rad/s) held over each step.
Gives out: the state after each step - position r (world ENU, m), velocity v (ENU, m/s), attitude q
(w, x, y, z; body FLU -> world ENU), body rates w (FLU, rad/s), rotor speeds (rad/s) - the specific
force an accelerometer would read, whether the floor holds the vehicle, and a Crash when the flight ends.

Physics (Mellinger & Kumar 2011 notation; body z = thrust axis):
    r' = v
    m v' = R(q) [f_drag_x, f_drag_y, sum_i k_T w_i^2]^T - m g e3
    q' = 1/2 q (x) (0, w)
    I w' = M - w x I w,   [T, M]^T = A [w_1^2 .. w_4^2]^T  (A = Vehicle.allocation)
    motor lag (tau > 0):  w_i' = (w_cmd_i - w_i) / tau  (solved exactly over the step)
    rotor drag (c > 0):   f_drag_xy = -c (sum_i w_i / w_hover) v_body_xy   (N; c per rotor at hover)
Integrated by classical RK4 at a fixed step (tests check its fourth order against an independent
solution): simulator.dynamics_kernels.rk4, compiled when it was built, else its Python twin (the same bits);
the rotors' lag and the wrench terms they give likewise (dynamics_kernels.rotor_lag, rotor_inputs).
The state lives in plain Python floats and the RK4 stages are written out: a numpy call on a 3-vector costs
~1 us, and a Python call per stage ~0.3 us, against a budget of a few us per step. The wrench terms (T/m,
M/I, drag/m) are recomputed only when the rotor speeds change.

Floor (z = world bounds zmin, or 0 without a world): a resting vehicle stays put, level, at rest, until
its thrust exceeds its weight. Touching the floor no faster than landing_speed_max_mps is a landing
(the vehicle comes to rest, levelled, yaw kept; its tilt at touchdown is not judged); faster is a
crash. A resting vehicle does not tip over or yaw whatever moments it is given. The vehicle centre
coming within collision_radius_m of a block, or leaving the world bounds, is a crash. A crash stops the
vehicle: motors off, state frozen where it happened, reported as a Crash (link.messages.CrashReport: time,
position, velocity, what was touched).
Block distances (numpy) are recomputed only once the vehicle has moved as far as its last clearance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from link.messages import CrashReport, Touched, TruthState
from model.frames import IDENTITY, Quat, Vec3, level_with_yaw, quat_normalize
from model.vehicle import GRAVITY_MPS2, Vehicle
from model.world import World
from simulator.dynamics_kernels import rk4, rotor_coeffs, rotor_inputs, rotor_lag, world_to_body

_NO_DV: Vec3 = (0.0, 0.0, 0.0)  # no contact impulse since the last IMU sample (compared by identity)


@dataclass(frozen=True)
class ContactParams:
    """How the vehicle meets the floor (simulator/params/firmware.toml [contact]); its collision radius
    for blocks is the vehicle's (model.vehicle.Vehicle.collision_radius_m)."""

    landing_speed_max_mps: float  # touching the floor faster than this is a crash


# The end of a flight: when, where, how fast and what was touched (also sent to the ground as a
# simulation-only report on the truth key).
Crash = CrashReport


class QuadrotorDynamics:
    """One quadrotor body, stepped at a fixed dt. See the module docstring for the equations."""

    def __init__(self, vehicle: Vehicle, contact: ContactParams, *, world: World | None = None,
                 dt_s: float = 1e-3, position_enu_m: Vec3 = (0.0, 0.0, 0.0),
                 attitude_wxyz: Quat = IDENTITY):
        inertia = np.asarray(vehicle.inertia_kgm2, float)
        if np.any(np.abs(inertia - np.diag(np.diag(inertia))) > 0.0):
            raise ValueError(f"{vehicle.source}: the dynamics need a diagonal inertia (principal body axes)")
        self.vehicle = vehicle
        self.world = world
        self.dt_s = float(dt_s)
        self._mass = vehicle.mass_kg
        self._weight = vehicle.weight_n
        self._ixx, self._iyy, self._izz = (float(v) for v in np.diag(inertia))
        self._w_min = vehicle.rotor_speed_min_radps
        self._w_max = vehicle.rotor_speed_max_radps
        tau = vehicle.motor_time_constant_s
        self._lag = tau > 0.0
        self._decay_half = math.exp(-0.5 * self.dt_s / tau) if self._lag else 0.0
        self._decay_full = math.exp(-self.dt_s / tau) if self._lag else 0.0
        drag_per_radps = (vehicle.rotor_drag_coefficient / vehicle.hover_rotor_speed_radps
                          if vehicle.rotor_drag_coefficient > 0.0 else 0.0)
        self._coeffs = rotor_coeffs(vehicle.allocation, self._mass, (self._ixx, self._iyy, self._izz), drag_per_radps)
        self.landing_speed_max_mps = contact.landing_speed_max_mps
        self.collision_radius_m = vehicle.collision_radius_m
        self.floor_z_m = float(world.bounds[4]) if world is not None else 0.0
        self._bounds = tuple(float(v) for v in world.bounds) if world is not None else None
        self._has_blocks = world is not None and len(world.blocks) > 0
        self._block_check_at: Vec3 | None = None
        self._block_clearance_m = 0.0
        self._contact_dv_enu: Vec3 = _NO_DV

        h = self.dt_s
        self._h = (h, 0.5 * h, 0.25 * h, h / 6.0, h / 12.0, h * h / 6.0)  # see simulator.dynamics_kernels
        ixx, iyy, izz = self._ixx, self._iyy, self._izz
        self._gyro = ((izz - iyy) / ixx, (ixx - izz) / iyy, (iyy - ixx) / izz)  # w x I w, per inertia
        self._open_space = world is None  # nothing to meet but the floor

        self._n = 0
        self.t_s = 0.0  # simulation time (s): steps taken times dt
        self._x = [float(v) for v in position_enu_m] + [0.0, 0.0, 0.0] + list(quat_normalize(attitude_wxyz)) \
            + [0.0, 0.0, 0.0]
        self._w_cmd = [0.0, 0.0, 0.0, 0.0]
        self._cmd_given: tuple | None = None  # the last command, when given as a (immutable) tuple
        self._set_rotor_speeds([0.0, 0.0, 0.0, 0.0])  # rotor speeds (rad/s) and what they give
        self.crash: Crash | None = None
        if self._x[2] < self.floor_z_m:
            raise ValueError(f"start height {self._x[2]} m is below the floor at {self.floor_z_m} m")
        self.on_ground = self._x[2] <= self.floor_z_m
        if self.on_ground:
            self._rest_on_floor()
        elif world is not None and self._x[2] == world.support_height(self._x[0:3]):
            self._rest_at(self._x[2])  # starting on a landing pad (a block top)
        self._check_world(0.0)

    def continue_clock(self, steps: int) -> None:
        """Carry on from step `steps` (a rebooted vehicle keeps the simulation clock)."""
        self._n = steps
        self.t_s = steps * self.dt_s

    # --- state ------------------------------------------------------------------------------------
    @property
    def steps(self) -> int:
        return self._n

    @property
    def position_enu_m(self) -> Vec3:
        x = self._x
        return (x[0], x[1], x[2])

    @property
    def velocity_enu_mps(self) -> Vec3:
        x = self._x
        return (x[3], x[4], x[5])

    @property
    def attitude_wxyz(self) -> Quat:
        x = self._x
        return (x[6], x[7], x[8], x[9])

    @property
    def rate_flu_radps(self) -> Vec3:
        x = self._x
        return (x[10], x[11], x[12])

    def truth(self) -> TruthState:
        """The state now (time t_s) as the simulation-only TruthState message."""
        x = self._x
        return TruthState(self.t_s, (x[0], x[1], x[2]), (x[3], x[4], x[5]), (x[6], x[7], x[8], x[9]),
                          (x[10], x[11], x[12]))

    @property
    def rotor_speeds_radps(self) -> tuple[float, float, float, float]:
        return tuple(self._w)

    def set_state(self, *, position_enu_m: Vec3 | None = None, velocity_enu_mps: Vec3 | None = None,
                  attitude_wxyz: Quat | None = None, rate_flu_radps: Vec3 | None = None,
                  rotor_speeds_radps: tuple[float, ...] | None = None) -> None:
        """Overwrite parts of the state (scenario set-up and tests); leaves the vehicle airborne."""
        x = self._x
        if position_enu_m is not None:
            x[0:3] = [float(v) for v in position_enu_m]
        if velocity_enu_mps is not None:
            x[3:6] = [float(v) for v in velocity_enu_mps]
        if attitude_wxyz is not None:
            x[6:10] = list(quat_normalize(attitude_wxyz))
        if rate_flu_radps is not None:
            x[10:13] = [float(v) for v in rate_flu_radps]
        if rotor_speeds_radps is not None:
            speeds = [min(max(float(v), self._w_min), self._w_max) for v in rotor_speeds_radps]
            self._set_rotor_speeds(speeds)
            self._w_cmd = list(speeds)
            self._cmd_given = None
        self.on_ground = False
        self._block_check_at = None

    # --- inputs -----------------------------------------------------------------------------------
    def command_rotor_speeds(self, speeds_radps) -> None:
        """Rotor speeds (rad/s) to hold from now on, clamped to the vehicle's [min, max].

        Without motor lag they apply at once; with lag the rotors approach them with time constant tau.
        Zeros mean motors off (even below a non-zero minimum speed). A tuple equal to the last one
        given changes nothing and costs nothing (the firmware repeats its command between setpoints).
        """
        if speeds_radps.__class__ is tuple and speeds_radps == self._cmd_given:
            return
        lo, hi = self._w_min, self._w_max
        s0, s1, s2, s3 = speeds_radps
        if lo < s0 <= hi and lo < s1 <= hi and lo < s2 <= hi and lo < s3 <= hi:  # the usual case: in range
            cmd = [float(s0), float(s1), float(s2), float(s3)]
        else:
            cmd = [0.0 if s == 0.0 else (lo if s < lo else hi if s > hi else float(s)) for s in speeds_radps]
        self._w_cmd = cmd
        self._cmd_given = speeds_radps if speeds_radps.__class__ is tuple else None
        if not self._lag:
            self._set_rotor_speeds(cmd)

    def stop_motors(self) -> None:
        self._w_cmd = [0.0, 0.0, 0.0, 0.0]
        self._cmd_given = None
        self._set_rotor_speeds([0.0, 0.0, 0.0, 0.0])

    def _set_rotor_speeds(self, speeds: list[float]) -> None:
        """Rotor speeds now, and the wrench terms the integrator takes from them (cached until they change)."""
        self._w = speeds
        self._thrust_n, self._u = rotor_inputs(speeds, self._coeffs)

    # --- outputs ----------------------------------------------------------------------------------
    def specific_force_flu(self) -> Vec3:
        """Non-gravitational force per unit mass in body FLU (m/s^2): what an ideal accelerometer reads.

        Airborne: (rotor drag + thrust) / m. Resting or crashed: the floor's support, R^T (0, 0, g).
        """
        x = self._x
        if self.on_ground or self.crash is not None:
            qw, qx, qy, qz = x[6], x[7], x[8], x[9]
            g = GRAVITY_MPS2
            return (2.0 * (qx * qz - qw * qy) * g, 2.0 * (qy * qz + qw * qx) * g,
                    (1.0 - 2.0 * (qx * qx + qy * qy)) * g)
        thrust_m, _, _, _, drag_m = self._u
        if drag_m == 0.0:
            return (0.0, 0.0, thrust_m)
        vbx, vby, _ = world_to_body(x[6], x[7], x[8], x[9], x[3], x[4], x[5])
        return (-drag_m * vbx, -drag_m * vby, thrust_m)

    # --- stepping ---------------------------------------------------------------------------------
    def step(self) -> Crash | None:
        """Advance one dt with the held rotor command; returns the Crash if this step ended the flight."""
        n = self._n + 1
        self._n = n
        self.t_s = n * self.dt_s
        if self.crash is not None:
            return None
        thrust_start = self._thrust_n  # the floor test goes by the thrust at the step's start
        u0 = um = u1 = self._u
        if self._lag:
            lagged = rotor_lag(self._w, self._w_cmd, self._decay_half, self._decay_full, self._coeffs)
            if lagged is not None:
                w_end, self._thrust_n, um, u1 = lagged
                self._w, self._u = w_end, u1  # the step's end state (rk4 takes u0, um, u1 as arguments)
        if self.on_ground:
            if thrust_start <= self._weight:  # the floor holds it: no sinking, no sliding, stays level
                return None
            self.on_ground = False
        x = self._x = rk4(self._x, u0, um, u1, self._h, self._gyro)
        if self._open_space and x[2] >= self.floor_z_m:
            return None  # no world, above the floor: nothing to meet
        return self._check_world(self.t_s)

    # --- contact ----------------------------------------------------------------------------------
    def _rest_on_floor(self) -> None:
        self._rest_at(self.floor_z_m)

    def take_contact_dv_flu(self) -> Vec3:
        """Velocity change (m/s, body FLU) the floor or a pad imposed since the last call, then zeroed.

        Contact stops the vehicle within one step; an accelerometer integrates that impulse, so the IMU
        adds this over its sample period (else an estimator would never see the vehicle stop).
        """
        dv = self._contact_dv_enu
        if dv is _NO_DV:
            return dv
        self._contact_dv_enu = _NO_DV
        x = self._x
        return world_to_body(x[6], x[7], x[8], x[9], *dv)

    def _rest_at(self, ground_z: float) -> None:
        x = self._x
        pdv = self._contact_dv_enu
        self._contact_dv_enu = (pdv[0] - x[3], pdv[1] - x[4], pdv[2] - x[5])
        x[2] = ground_z
        x[3:6] = [0.0, 0.0, 0.0]
        x[6:10] = list(level_with_yaw((x[6], x[7], x[8], x[9])))
        x[10:13] = [0.0, 0.0, 0.0]
        self.on_ground = True

    def _check_world(self, t_s: float) -> Crash | None:
        x = self._x
        if x[2] < self.floor_z_m:
            sink_mps = -x[5]
            if sink_mps <= self.landing_speed_max_mps:
                self._rest_on_floor()
            else:
                x[2] = self.floor_z_m
                return self._end_flight(t_s, Touched.FLOOR, limit=self.landing_speed_max_mps)
        b = self._bounds
        if b is not None and not (b[0] <= x[0] <= b[1] and b[2] <= x[1] <= b[3] and x[2] <= b[5]):
            return self._end_flight(t_s, Touched.BOUNDS)
        if self._has_blocks:
            return self._check_blocks(t_s)
        return None

    def _check_blocks(self, t_s: float) -> Crash | None:
        """Block contact, computed with numpy only when the vehicle may have used up its last clearance."""
        x = self._x
        at = self._block_check_at
        if at is not None:
            dx, dy, dz = x[0] - at[0], x[1] - at[1], x[2] - at[2]
            if dx * dx + dy * dy + dz * dz < self._block_clearance_m ** 2:
                return None
        p = np.array(x[0:3])
        distance = float(self.world.distance_to_blocks(p))
        self._block_check_at = (x[0], x[1], x[2])
        self._block_clearance_m = distance - self.collision_radius_m
        if self._block_clearance_m >= 0.0:
            return None
        lo, hi = self.world.blocks[:, 0::2], self.world.blocks[:, 1::2]
        gaps = np.linalg.norm(np.maximum(np.maximum(lo - p, p - hi), 0.0), axis=1)
        touching = gaps < self.collision_radius_m
        sunk_this_step = max(0.0, -x[5]) * self.dt_s  # the feet may have passed the top within the step
        pads = touching & self._is_pad_below(p, lo, hi, sunk_this_step)
        if touching.any() and (touching == pads).all():
            # Only the tops of blocks right below: a landing pad. The vehicle's feet meet its top face
            # like the floor (a gentle touchdown rests on it, a fast one is a crash).
            self._block_check_at = None
            top = int(np.flatnonzero(pads)[np.argmax(hi[pads, 2])])
            return self._touch_pad(t_s, top)
        index = int(np.argmin(np.where(touching & ~pads, gaps, np.inf)))
        return self._end_flight(t_s, Touched.BLOCK, index, limit=self.collision_radius_m)

    @staticmethod
    def _is_pad_below(p: np.ndarray, lo: np.ndarray, hi: np.ndarray, sunk_m: float) -> np.ndarray:
        """Blocks whose footprint holds the vehicle's (x, y) and whose top was at or below its centre."""
        inside_xy = (lo[:, 0] <= p[0]) & (p[0] <= hi[:, 0]) & (lo[:, 1] <= p[1]) & (p[1] <= hi[:, 1])
        return inside_xy & (hi[:, 2] <= p[2] + sunk_m + 1e-9)

    def _touch_pad(self, t_s: float, pad: int) -> Crash | None:
        x = self._x
        top_z = float(self.world.blocks[pad, 5])
        if x[2] > top_z:
            return None  # above the pad, within the collision radius of its top face: still flying
        sink_mps = -x[5]
        if sink_mps > self.landing_speed_max_mps:
            x[2] = top_z
            return self._end_flight(t_s, Touched.BLOCK_TOP, pad, limit=self.landing_speed_max_mps)
        self._rest_at(top_z)
        return None

    def _end_flight(self, t_s: float, touched: Touched, block: int = -1, limit: float = 0.0) -> Crash:
        extents = tuple(self.world.blocks[block].tolist()) if block >= 0 else ()
        self.crash = Crash(t_s, self.position_enu_m, self.velocity_enu_mps, touched, block, extents, limit)
        self.stop_motors()
        self._x[3:6] = [0.0, 0.0, 0.0]
        self._x[10:13] = [0.0, 0.0, 0.0]
        return self.crash
