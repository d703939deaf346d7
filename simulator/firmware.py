"""The emulated Crazyflie's onboard commander: arming, setpoint checking, watchdog, attitude loop, landing.

Takes in: uplink ThrustMoment / AttitudeTarget setpoints and VehicleCommands with their ARRIVAL time at
the vehicle (sim time, s); at each tick (commander.rate_hz, 500 Hz) the body's state - attitude,
body rates, vertical velocity, whether the floor holds it, crash - as an ideal onboard estimate (the
Crazyflie's own estimator is not emulated: the loop reads the true state).
Gives out: rotor speed commands (rad/s; zeros = motors off) from each tick, Heartbeat and BatteryStatus
on request, and the count of rejected commands.

Parameters: simulator/params/firmware.toml (load_firmware_params), sources cited there.

Behaviour:
- Disarmed: motors off; setpoints are checked but not applied. ARM arms (motors idle until a setpoint),
  DISARM cuts the motors at once (also in flight: the kill switch), LAND descends level at
  landing.descent_speed_mps and disarms when the floor holds the vehicle (setpoints are ignored while
  landing; LAND on the floor disarms at once).
- MOMENTS: ThrustMoment setpoints go straight to the mixer. ATTITUDE: AttitudeTarget setpoints go to the
  geometric attitude law (Lee, Leok & McClamroch 2010, as in the lab report)
      M = I (-K_R e_R - K_w (w - w_des)) + w x I w,   e_R = 1/2 vee(R_des^T R - R^T R_des)
  (computed as e_R = 2 q_e,w q_e,xyz with q_e = q_des^* (x) q, the same vector).
- Watchdog (crazyflie-firmware commander.c), on the age of the last valid setpoint's arrival (or of
  arming when none came): > watchdog_level_timeout_s -> LEVEL: roll = pitch = 0, yaw held at its value
  on entry, last thrust kept; > watchdog_shutdown_timeout_s -> motors off and disarm. Heartbeat.failsafe
  is raised in LEVEL, after a watchdog shutdown (until the next ARM) and after a crash.
- Rejected (counted in rejected_commands, never applied): any NaN/inf, thrust < 0 or above the vehicle's
  maximum, |moment| above the vehicle's maximum on an axis, | |q| - 1 | above quaternion_norm_tolerance,
  |rate| above max_rate_radps, unknown command kinds, and ARM after a crash.
- Battery: energy drawn = integral of (sum_i k_D w_i^3 / motor_efficiency + avionics_power_w) dt;
  voltage falls linearly from full to empty with the energy left (no sag, no brown-out).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

from link.messages import (
    AttitudeTarget,
    BatteryStatus,
    CommandKind,
    Heartbeat,
    PositionTarget,
    ThrustMoment,
    VehicleCommand,
    VehicleMode,
)
from model.attitude_law import attitude_error, attitude_moment
from model.config import Params, resolve
from model.frames import (
    Quat,
    Vec3,
    quat_from_euler_zyx,
    quat_from_yaw,
    yaw_of,
)
from model.vehicle import GRAVITY_MPS2, Vehicle
from simulator.dynamics import ContactParams, Crash
from simulator.mixer import Mixer

MOTORS_OFF = (0.0, 0.0, 0.0, 0.0)
_SETPOINTS_IGNORED_IN = (VehicleMode.LANDING, VehicleMode.CRASHED)  # armed modes that ignore setpoints


@dataclass(frozen=True)
class FirmwareParams:
    commander_rate_hz: float
    watchdog_level_timeout_s: float
    watchdog_shutdown_timeout_s: float
    session_gap_s: float
    quaternion_norm_tolerance: float
    max_rate_radps: float
    limit_relative_tolerance: float
    k_r_per_s2: Vec3
    k_w_per_s: Vec3
    landing_descent_speed_mps: float
    landing_velocity_gain_per_s: float
    landing_timeout_s: float
    landing_horizontal_gain_per_s: float
    landing_max_tilt_rad: float
    heartbeat_rate_hz: float
    battery_rate_hz: float
    truth_rate_hz: float
    motor_efficiency: float
    avionics_power_w: float
    contact: ContactParams
    source: str


def load_firmware_params(name_or_path: str | Path = "firmware") -> FirmwareParams:
    """Read simulator/params/firmware.toml (or the given file); ConfigError naming file and field."""
    p = Params.load(resolve(name_or_path, "simulator", "params", "firmware parameters"))
    p.string("name")
    p.string("source")
    commander = p.table("commander")
    attitude = p.table("attitude")
    landing = p.table("landing")
    telemetry = p.table("telemetry")
    battery = p.table("battery")
    contact = p.table("contact")
    level = commander.number("watchdog_level_timeout_s", minimum=0.0)
    shutdown = commander.number("watchdog_shutdown_timeout_s", minimum=0.0)
    if shutdown <= level:
        raise commander.error("watchdog_shutdown_timeout_s", "must exceed watchdog_level_timeout_s")
    k_r, k_w = attitude.vector("k_r_per_s2", 3), attitude.vector("k_w_per_s", 3)
    for name, gains in (("k_r_per_s2", k_r), ("k_w_per_s", k_w)):
        if min(gains) <= 0.0:
            raise attitude.error(name, "gains must be positive")
    return FirmwareParams(
        commander_rate_hz=commander.number("rate_hz", minimum=1.0),
        watchdog_level_timeout_s=level,
        watchdog_shutdown_timeout_s=shutdown,
        session_gap_s=commander.number("session_gap_s", minimum=0.0),
        quaternion_norm_tolerance=commander.number("quaternion_norm_tolerance", minimum=0.0, maximum=0.5),
        max_rate_radps=commander.number("max_rate_radps", minimum=0.0),
        limit_relative_tolerance=commander.number("limit_relative_tolerance", minimum=0.0, maximum=0.1),
        k_r_per_s2=tuple(k_r),
        k_w_per_s=tuple(k_w),
        landing_descent_speed_mps=landing.number("descent_speed_mps", minimum=0.01),
        landing_velocity_gain_per_s=landing.number("velocity_gain_per_s", minimum=0.0),
        landing_timeout_s=landing.number("timeout_s", minimum=0.0),
        landing_horizontal_gain_per_s=landing.number("horizontal_velocity_gain_per_s", minimum=0.0),
        landing_max_tilt_rad=landing.number("max_tilt_rad", minimum=0.0, maximum=1.0),
        heartbeat_rate_hz=telemetry.number("heartbeat_rate_hz", minimum=0.01),
        battery_rate_hz=telemetry.number("battery_rate_hz", minimum=0.01),
        truth_rate_hz=telemetry.number("truth_rate_hz", minimum=0.01),
        motor_efficiency=battery.number("motor_efficiency", minimum=0.01, maximum=1.0),
        avionics_power_w=battery.number("avionics_power_w", minimum=0.0),
        contact=ContactParams(
            landing_speed_max_mps=contact.number("landing_speed_max_mps", minimum=0.0),
        ),
        source=p.source,
    )


class BodyState(Protocol):
    """What the commander reads of the vehicle each tick (simulator.dynamics.QuadrotorDynamics has it)."""

    attitude_wxyz: Quat
    rate_flu_radps: Vec3
    velocity_enu_mps: Vec3
    rotor_speeds_radps: tuple[float, ...]
    on_ground: bool
    crash: Crash | None


def _finite(*values) -> bool:
    """Every value a finite real number (False for NaN, inf and non-numbers)."""
    isfinite = math.isfinite
    try:
        for v in values:
            if not isfinite(v):
                return False
    except TypeError:
        return False
    return True


def _within(values, limits) -> bool:
    """|v| <= limit for each pair (False for NaN and non-numbers: a NaN comparison is False)."""
    try:
        for v, limit in zip(values, limits, strict=True):
            if not abs(v) <= limit:
                return False
    except (TypeError, ValueError):
        return False
    return True


class Firmware:
    def __init__(self, vehicle: Vehicle, params: FirmwareParams):
        self.vehicle = vehicle
        self.params = params
        self.mixer = Mixer(vehicle)
        self.tick_period_s = 1.0 / params.commander_rate_hz
        self.armed = False
        self.mode = VehicleMode.IDLE
        self.rejected_commands = 0  # this ground-station session's (see receive)
        self.uplink_received = 0  # uplink messages delivered in this session, reported in SYS_STATUS
        self.reboot_requested = False  # a REBOOT command came: the vehicle restarts (SimVehicle.reboot)
        self._last_uplink_s = -math.inf
        self.ignored_setpoints = 0  # valid setpoints that arrived disarmed or while landing
        self.last_ground_station_heartbeat_s: float | None = None
        self._shutdown_latched = False
        self._inertia = tuple(float(vehicle.inertia_kgm2[i, i]) for i in range(3))
        slack = 1.0 + params.limit_relative_tolerance
        self._max_thrust_n = vehicle.max_thrust_n * slack
        self._max_moment_nm = tuple(float(v) * slack for v in vehicle.max_moment_nm)
        self._max_rates_radps = (params.max_rate_radps,) * 3
        # energy per tick (J): k_D sum(w^3) / efficiency + avionics, times the tick period
        self._rotor_j_per_cube = vehicle.k_drag_torque / params.motor_efficiency * self.tick_period_s
        self._avionics_j = params.avionics_power_w * self.tick_period_s
        self._level_timeout_s = params.watchdog_level_timeout_s
        self._shutdown_timeout_s = params.watchdog_shutdown_timeout_s
        self._watchdog_from_s = min(self._level_timeout_s, self._shutdown_timeout_s)  # one test while fresh
        self._moment_speeds: tuple[float, ...] | None = None  # the mix of the ThrustMoment setpoint, once made
        self._energy_total_j = (vehicle.battery_capacity_mah * 3.6
                                * 0.5 * (vehicle.battery_full_v + vehicle.battery_empty_v))
        self.energy_used_j = 0.0
        self._clear_setpoint(0.0)
        self._held_yaw_rad = 0.0
        self._landing_since_s = 0.0

    # --- uplink -----------------------------------------------------------------------------------
    def receive(self, message, arrival_s: float) -> bool:
        """Take one uplink message that arrived at sim time arrival_s; False if it was rejected."""
        self.count_uplink(arrival_s)
        if isinstance(message, ThrustMoment):
            return self._take_setpoint(message, arrival_s, self._valid_thrust_moment(message))
        if isinstance(message, AttitudeTarget):
            return self._take_setpoint(message, arrival_s, self._valid_attitude_target(message))
        if isinstance(message, VehicleCommand):
            return self._take_command(message, arrival_s)
        if isinstance(message, PositionTarget):  # the ideal vehicle has no position controller
            self.rejected_commands += 1
            return False
        if isinstance(message, Heartbeat) and message.is_ground_station:
            self.last_ground_station_heartbeat_s = arrival_s
        return True

    def count_uplink(self, arrival_s: float) -> None:
        """Count one uplink message. A ground station heard after more than session_gap_s of silence
        starts a new session: the counters it reads back (uplink received, rejected) start again from
        zero, so a second ground station on the same emulator sees its own numbers, not every session's."""
        if arrival_s - self._last_uplink_s > self.params.session_gap_s:
            self.uplink_received = 0
            self.rejected_commands = 0
        self._last_uplink_s = arrival_s
        self.uplink_received += 1

    def _valid_thrust_moment(self, sp: ThrustMoment) -> bool:
        # |M| within the (finite) limits also rejects NaN and inf
        return self._thrust_ok(sp.time_s, sp.thrust_n) and _within(sp.moment_flu_nm, self._max_moment_nm)

    def _valid_attitude_target(self, sp: AttitudeTarget) -> bool:
        if not self._thrust_ok(sp.time_s, sp.thrust_n):
            return False
        if len(sp.attitude_wxyz) != 4 or not _finite(*sp.attitude_wxyz):
            return False
        w, x, y, z = sp.attitude_wxyz
        if abs(math.sqrt(w * w + x * x + y * y + z * z) - 1.0) > self.params.quaternion_norm_tolerance:
            return False
        return _within(sp.rates_flu_radps, self._max_rates_radps)  # also rejects NaN, inf and a wrong length

    def _thrust_ok(self, time_s, thrust_n) -> bool:
        try:  # a NaN or inf thrust fails the range test
            return math.isfinite(time_s) and 0.0 <= thrust_n <= self._max_thrust_n
        except TypeError:
            return False

    def _take_setpoint(self, sp, arrival_s: float, valid: bool) -> bool:
        if not valid:
            self.rejected_commands += 1
            return False
        if not self.armed or self.mode in _SETPOINTS_IGNORED_IN:
            self.ignored_setpoints += 1
            return True
        self._sp_arrival_s = arrival_s
        self._sp_thrust_n = float(sp.thrust_n)
        self._moment_speeds = None
        if isinstance(sp, ThrustMoment):
            self.mode = VehicleMode.MOMENTS
            mx, my, mz = sp.moment_flu_nm
            self._sp_moment = (float(mx), float(my), float(mz))
        else:
            self.mode = VehicleMode.ATTITUDE
            w, x, y, z = sp.attitude_wxyz
            n = math.sqrt(w * w + x * x + y * y + z * z)
            self._sp_attitude = (float(w) / n, float(x) / n, float(y) / n, float(z) / n)
            rx, ry, rz = sp.rates_flu_radps
            self._sp_rates = (float(rx), float(ry), float(rz))
        return True

    def _take_command(self, cmd: VehicleCommand, arrival_s: float) -> bool:
        if not _finite(cmd.time_s) or cmd.kind not in set(CommandKind):
            self.rejected_commands += 1
            return False
        if cmd.kind == CommandKind.ARM:
            if self.mode == VehicleMode.CRASHED:
                self.rejected_commands += 1
                return False
            if not self.armed:
                self.arm(arrival_s)
        elif cmd.kind == CommandKind.DISARM:
            self.disarm()
        elif cmd.kind == CommandKind.REBOOT:
            self.reboot_requested = True
        elif cmd.kind == CommandKind.LAND and self.armed and self.mode != VehicleMode.LANDING:
            self.mode = VehicleMode.LANDING
            self._landing_since_s = arrival_s
            self._yaw_pending = True  # captured from the body at the next tick
        return True

    # --- state changes ----------------------------------------------------------------------------
    def arm(self, t_s: float) -> None:
        """Arm: motors idle until a setpoint comes; the watchdog counts from now."""
        self.armed = True
        self._shutdown_latched = False
        self._clear_setpoint(t_s)

    def start_hovering(self, t_s: float) -> None:
        """An airborne start: armed, as if a hover ThrustMoment had just arrived (the watchdog runs)."""
        self.arm(t_s)
        self.mode = VehicleMode.MOMENTS
        self._sp_thrust_n = self.vehicle.weight_n
        self._moment_speeds = None

    def disarm(self, watchdog: bool = False) -> None:
        self.armed = False
        if self.mode != VehicleMode.CRASHED:
            self.mode = VehicleMode.IDLE
        self._shutdown_latched = watchdog

    def _clear_setpoint(self, t_s: float) -> None:
        self.mode = VehicleMode.IDLE if self.mode != VehicleMode.CRASHED else self.mode
        self._sp_arrival_s = t_s
        self._sp_thrust_n = 0.0
        self._sp_moment = (0.0, 0.0, 0.0)
        self._sp_attitude = (1.0, 0.0, 0.0, 0.0)
        self._sp_rates = (0.0, 0.0, 0.0)
        self._moment_speeds = None
        self._yaw_pending = False

    # --- the 500 Hz loop --------------------------------------------------------------------------
    def tick(self, t_s: float, body: BodyState) -> tuple[float, ...]:
        """One commander + attitude loop pass at sim time t_s; rotor speeds (rad/s) to hold until the next."""
        w0, w1, w2, w3 = body.rotor_speeds_radps
        self.energy_used_j += self._rotor_j_per_cube * (w0 * w0 * w0 + w1 * w1 * w1 + w2 * w2 * w2
                                                        + w3 * w3 * w3) + self._avionics_j
        if body.crash is not None:
            self.armed = False
            self.mode = VehicleMode.CRASHED
            return MOTORS_OFF
        if not self.armed:
            return MOTORS_OFF
        if self.mode == VehicleMode.LANDING:
            return self._land(t_s, body)
        age_s = t_s - self._sp_arrival_s
        if age_s > self._watchdog_from_s:
            if age_s > self._shutdown_timeout_s:
                self.disarm(watchdog=True)
                return MOTORS_OFF
            if self.mode != VehicleMode.LEVEL:
                self.mode = VehicleMode.LEVEL
                self._held_yaw_rad = yaw_of(body.attitude_wxyz)
            return self._follow_attitude(self._sp_thrust_n, quat_from_yaw(self._held_yaw_rad), (0.0, 0.0, 0.0), body)
        if self.mode == VehicleMode.ATTITUDE:
            return self._follow_attitude(self._sp_thrust_n, self._sp_attitude, self._sp_rates, body)
        # MOMENTS, or IDLE-armed at zero: the same rotor speeds until the setpoint changes
        speeds = self._moment_speeds
        if speeds is None:
            speeds = self._moment_speeds = self.mixer.mix(self._sp_thrust_n, self._sp_moment)
        return speeds

    def attitude_moments(self, attitude_des: Quat, rates_des: Vec3, body: BodyState) -> Vec3:
        """M = I (-K_R e_R - K_w (w - w_des)) + w x I w (N m, body FLU): model.attitude_law."""
        w = body.rate_flu_radps
        e_w = (w[0] - rates_des[0], w[1] - rates_des[1], w[2] - rates_des[2])
        return attitude_moment(attitude_error(attitude_des, body.attitude_wxyz), e_w, self.params.k_r_per_s2,
                               self.params.k_w_per_s, self._inertia, w)

    def _follow_attitude(self, thrust_n: float, attitude_des: Quat, rates_des: Vec3,
                         body: BodyState) -> tuple[float, ...]:
        return self.mixer.mix(thrust_n, self.attitude_moments(attitude_des, rates_des, body))

    def _land(self, t_s: float, body: BodyState) -> tuple[float, ...]:
        if body.on_ground or t_s - self._landing_since_s > self.params.landing_timeout_s:
            self.disarm()
            return MOTORS_OFF
        q = body.attitude_wxyz
        if self._yaw_pending:
            self._held_yaw_rad = yaw_of(q)
            self._yaw_pending = False
        p = self.params
        vz = body.velocity_enu_mps[2]
        cos_tilt = max(1.0 - 2.0 * (q[1] * q[1] + q[2] * q[2]), 0.5)  # thrust along body z; cap the boost
        accel = GRAVITY_MPS2 + p.landing_velocity_gain_per_s * (-p.landing_descent_speed_mps - vz)
        thrust = min(max(self.vehicle.mass_kg * accel / cos_tilt, 0.0), self.vehicle.max_thrust_n)
        return self._follow_attitude(thrust, self._braking_attitude(body), (0.0, 0.0, 0.0), body)

    def _braking_attitude(self, body: BodyState) -> Quat:
        """Tilt against the horizontal velocity (a_xy = -k v_xy, as a Crazyflie with a flow deck holds
        velocity), within max_tilt, at the held yaw."""
        p, yaw = self.params, self._held_yaw_rad
        vx, vy = body.velocity_enu_mps[0], body.velocity_enu_mps[1]
        ax, ay = -p.landing_horizontal_gain_per_s * vx, -p.landing_horizontal_gain_per_s * vy
        forward = math.cos(yaw) * ax + math.sin(yaw) * ay  # in the yaw frame
        left = -math.sin(yaw) * ax + math.cos(yaw) * ay
        limit = p.landing_max_tilt_rad
        pitch = min(max(math.atan2(forward, GRAVITY_MPS2), -limit), limit)  # +pitch tips thrust to +x
        roll = min(max(-math.atan2(left, GRAVITY_MPS2), -limit), limit)  # +roll tips thrust to -y
        return quat_from_euler_zyx(roll, pitch, yaw)

    # --- reports ----------------------------------------------------------------------------------
    @property
    def failsafe(self) -> bool:
        return self.mode in (VehicleMode.LEVEL, VehicleMode.CRASHED) or self._shutdown_latched

    def heartbeat(self) -> Heartbeat:
        return Heartbeat(armed=self.armed, mode=self.mode, failsafe=self.failsafe)

    @property
    def state_of_charge(self) -> float:
        return max(0.0, 1.0 - self.energy_used_j / self._energy_total_j)

    def battery_status(self) -> BatteryStatus:
        v = self.vehicle
        soc = self.state_of_charge
        return BatteryStatus(voltage_v=v.battery_empty_v + (v.battery_full_v - v.battery_empty_v) * soc,
                             remaining_pct=int(round(100.0 * soc)), rejected_commands=self.rejected_commands,
                             uplink_received=self.uplink_received)

