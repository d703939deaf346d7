"""The faithful firmware: the emulator's commander with the Crazyflie's stabilizer (crazyflie-firmware
src/modules/src/stabilizer.c) in place of the ideal attitude law and exact mixer (`--firmware crazyflie`).

Takes in: what simulator.firmware.Firmware takes (uplink setpoints and commands with their arrival time, a
tick per commander cycle), plus every IMU sample (`take_imu`), which is all the onboard side knows of its
motion: the controller flies on its own estimate, never on the simulation's truth.
Gives out: rotor speed commands (rad/s) for the physics, made from the motor forces the firmware's PWM
produces on the battery's sagging voltage; the per-motor PWM, battery voltage and estimate for logs.

Per IMU sample (500 Hz for the Crazyflie models; the firmware's 1 kHz main loop would repeat the same
500 Hz control on the ticks in between):
1. gyro bias: the mean of the first samples taken disarmed at rest (the firmware's boot calibration) is
   subtracted from every gyro sample;
2. estimator (every second sample, 250 Hz): the complementary filter (sensfusion6.py) and the vertical
   velocity it integrates (position_estimator_altitude.c). When the ground station streams the mocap pose
   (ExternalPose, as a mocap lab streams extpose), each fix pulls the attitude toward it, compared with the
   estimate at the fix's sample time, with the gain a Kalman filter would settle at for the gyro's noise
   and the firmware's extQuatStdDev ([external_pose]); while fixes arrive the accelerometer does not correct
   the attitude (in flight it measures thrust, not gravity). The first fix sets the attitude;
3. controller (each commander tick, 500 Hz), by the setpoint's kind:
   - AttitudeTarget: roll, pitch, yaw absolute (deg, legacy pitch), thrust N -> PWM = T / (4 THRUST_MAX)
     65535, through the PID controller (controller_pid.py) and the legacy mixer; its body rates are not
     used (the PID controller's absolute modes have no rate feed-forward);
   - ThrustMoment: the force-torque mixer (the firmware's controlModeForceTorque path);
   - the watchdog's level-out (supervisorOverrideSetpoint): roll = pitch = 0, yaw rate 0, thrust kept;
   - LAND: level, yaw rate 0, thrust from the onboard vertical velocity estimate (see _landing_thrust);
4. power: battery compensation with the low-passed measured voltage, the cap, then per motor the thrust
   curve at the battery's true terminal voltage, which sags with the current drawn (battery.py).
What is simpler than the firmware: see the README (no Kalman filter, no position loops yet, no tumble
detection, the 1 kHz loop run at the IMU's 500 Hz).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from link.crtp import setpoints as crtp
from link.messages import (
    AttitudeTarget,
    BatteryStatus,
    ExternalPose,
    ImuSample,
    PositionTarget,
    ThrustMoment,
    VehicleMode,
)
from model.config import Params, resolve
from model.frames import attitude_error, euler_zyx_of
from model.vehicle import GRAVITY_MPS2, Vehicle
from simulator.crazyflie import drive_kernel
from simulator.crazyflie.attitude_controller import AttitudeController
from simulator.crazyflie.battery import Battery
from simulator.crazyflie.commander_rpyt import RpytDecoder
from simulator.crazyflie.controller_pid import MODE_ABS, MODE_DISABLE, MODE_VELOCITY, ControllerPid, Setpoint
from simulator.crazyflie.high_level_commander import HighLevelCommander
from simulator.crazyflie.history import TimeHistory
from simulator.crazyflie.motors import ThrustCurve
from simulator.crazyflie.position_controller import PositionController
from simulator.crazyflie.position_estimator import PositionEstimator
from simulator.crazyflie.power_distribution import ForceTorqueMixer, cap, legacy
from simulator.crazyflie.sensfusion6 import Sensfusion6
from simulator.firmware import MOTORS_OFF, BodyState, Firmware, FirmwareParams

DEG_PER_RAD = 180.0 / math.pi
G_MPS2 = 9.81  # the firmware's G (physicalConstants.h GRAVITY_MAGNITUDE), for m/s^2 <-> g
ATTITUDE_MODES = (MODE_DISABLE, MODE_DISABLE, MODE_DISABLE, MODE_ABS, MODE_ABS, MODE_ABS)
LEVEL_MODES = (MODE_DISABLE, MODE_DISABLE, MODE_DISABLE, MODE_ABS, MODE_ABS, MODE_VELOCITY)
POSITION_MODES = (MODE_ABS, MODE_ABS, MODE_ABS, MODE_DISABLE, MODE_DISABLE, MODE_ABS)
# crtp_commander_generic.c velocityDecoder and hoverDecoder: yaw as a rate
VELOCITY_WORLD_MODES = (MODE_VELOCITY, MODE_VELOCITY, MODE_VELOCITY, MODE_DISABLE, MODE_DISABLE, MODE_VELOCITY)
HOVER_MODES = (MODE_VELOCITY, MODE_VELOCITY, MODE_ABS, MODE_DISABLE, MODE_DISABLE, MODE_VELOCITY)
Z_DISTANCE_MODES = (MODE_DISABLE, MODE_DISABLE, MODE_ABS, MODE_ABS, MODE_ABS, MODE_VELOCITY)
# manualDecoder and cppmEmuDecoder: roll and pitch as angles (levelled) or as rates, yaw as a rate
RATE_MODES = (MODE_DISABLE, MODE_DISABLE, MODE_DISABLE, MODE_VELOCITY, MODE_VELOCITY, MODE_VELOCITY)
# altHoldDecoder: roll, pitch absolute, yaw rate, vertical velocity
ALTITUDE_HOLD_MODES = (MODE_DISABLE, MODE_DISABLE, MODE_VELOCITY, MODE_ABS, MODE_ABS, MODE_VELOCITY)
CPPM_MID_US, CPPM_HALF_RANGE_US, CPPM_THRUST_LOW_US, CPPM_THRUST_RANGE_US = 1500.0, 500.0, 1000.0, 1000.0
CPPM_LEVEL_AUX_US = 1500  # aux channel 0 below this: self-levelling off
# supervisorOverrideSetpoint on a position setpoint: x, y off, level, yaw rate 0, z kept
LEVEL_HOLDING_Z_MODES = (MODE_DISABLE, MODE_DISABLE, MODE_ABS, MODE_ABS, MODE_ABS, MODE_VELOCITY)


@dataclass(frozen=True)
class CrazyflieParams:
    attitude_rate_hz: float
    estimator_rate_hz: float
    pid_rate: dict
    pid_attitude: dict
    curve: ThrustCurve
    thrust_to_torque_m: float
    arm_length_m: float
    idle_thrust_pwm: int
    compensation_b_per_1khz: float
    initial_supply_v: float
    two_kp: float
    two_ki: float
    gyro_bias_samples: int
    ext_quat_std_rad: float
    ext_fresh_for_s: float
    v_acc_deadband_g: float
    vel_z_alpha: float
    battery: dict
    position_gains: dict
    position_rate_hz: float
    ext_pos_std_m: float
    initial_position_std_m: tuple[float, float, float]
    position_process_density: tuple[float, float, float]  # m/s^2/sqrt(Hz), per axis
    cppm: dict  # [cppm_emulation]: the RC emulation's largest angles (deg) and rates (deg/s)
    source: str


def load_crazyflie_params(name_or_path: str | Path = "crazyflie") -> CrazyflieParams:
    p = Params.load(resolve(name_or_path, "simulator", "params", "Crazyflie firmware parameters"))
    rates, power, comp = p.table("rates"), p.table("power"), p.table("battery_compensation")
    fusion, altitude, battery = p.table("sensfusion6"), p.table("altitude_estimator"), p.table("battery")

    def gains(table_name: str) -> dict:
        t = p.table(table_name)
        return {k: t.vector(k, 3) for k in ("kp", "ki", "kd", "integration_limit")}

    v = power.vector("vmotor2thrust", 4)
    pwm_max = int(power.number("pwm_max", minimum=1))
    return CrazyflieParams(
        attitude_rate_hz=rates.number("attitude_rate_hz", minimum=1.0),
        estimator_rate_hz=rates.number("estimator_rate_hz", minimum=1.0),
        pid_rate=gains("pid_rate"), pid_attitude=gains("pid_attitude"),
        curve=ThrustCurve(v[0], v[1], v[2], v[3], power.number("thrust_min_n", minimum=0.0),
                          power.number("thrust_max_n", minimum=1e-6), pwm_max,
                          comp.number("min_supply_v", minimum=0.0)),
        thrust_to_torque_m=power.number("thrust_to_torque_m", minimum=1e-9),
        arm_length_m=power.number("arm_length_m", minimum=1e-6),
        idle_thrust_pwm=int(power.number("idle_thrust_pwm", minimum=0, maximum=pwm_max)),
        compensation_b_per_1khz=comp.number("filter_b_per_1khz_tick", minimum=0.0, maximum=1.0),
        initial_supply_v=comp.number("initial_supply_v", minimum=0.0),
        two_kp=fusion.number("two_kp", minimum=0.0), two_ki=fusion.number("two_ki", minimum=0.0),
        gyro_bias_samples=int(p.table("gyro_calibration").number("bias_samples", minimum=1)),
        ext_quat_std_rad=p.table("external_pose").number("quat_std_rad", minimum=1e-9),
        ext_fresh_for_s=p.table("external_pose").number("fresh_for_s", minimum=0.0),
        v_acc_deadband_g=altitude.number("v_acc_deadband_g", minimum=0.0),
        vel_z_alpha=altitude.number("vel_z_alpha", minimum=0.0, maximum=1.0),
        battery={k: battery.number(k, minimum=0.0) for k in (
            "internal_resistance_ohm", "hover_current_a", "hover_thrust_n", "nominal_voltage_v", "power_exponent")},
        position_gains=_position_gains(p.table("position_controller")),
        position_rate_hz=p.table("position_controller").number("rate_hz", minimum=1.0),
        ext_pos_std_m=p.table("position_estimator").number("pos_std_m", minimum=1e-9),
        initial_position_std_m=(p.table("position_estimator").number("initial_std_xy_m", minimum=0.0),) * 2
        + (p.table("position_estimator").number("initial_std_z_m", minimum=0.0),),
        position_process_density=_process_density(p.table("position_estimator")),
        cppm={k: p.table("cppm_emulation").number(k, minimum=0.0) for k in (
            "roll_max_angle_deg", "pitch_max_angle_deg", "roll_max_rate_dps", "pitch_max_rate_dps",
            "yaw_max_rate_dps")},
        source=p.source,
    )


def _process_density(t) -> tuple[float, float, float]:
    """The Kalman filter's acceleration process noise as a density per axis: procNoiseAcc sqrt(1 / rate)."""
    root_dt = math.sqrt(1.0 / t.number("predict_rate_hz", minimum=1e-9))
    xy, z = t.number("process_noise_acc_xy_mps2", minimum=0.0), t.number("process_noise_acc_z_mps2", minimum=0.0)
    return (xy * root_dt, xy * root_dt, z * root_dt)


def _position_gains(t) -> dict:
    vectors = ("position_kp", "position_ki", "velocity_kp", "velocity_ki", "velocity_max_mps")
    numbers = ("limit_overhead", "roll_pitch_max_deg", "thrust_base_pwm", "thrust_min_pwm", "thrust_scale",
               "integration_limit")
    return {**{k: t.vector(k, 3) for k in vectors}, **{k: t.number(k, minimum=0.0) for k in numbers}}


def _legacy_rpy_deg(q) -> tuple[float, float, float]:
    """Roll, pitch, yaw (deg) of an FLU/ENU attitude in the firmware's legacy frame (pitch positive nose up)."""
    roll, pitch, yaw = euler_zyx_of(q)
    return roll * DEG_PER_RAD, -pitch * DEG_PER_RAD, yaw * DEG_PER_RAD


def _deadband(value: float, threshold: float) -> float:
    """num.c deadband: 0 inside +-threshold, else shifted toward 0 by it."""
    if abs(value) < threshold:
        return 0.0
    return value - threshold if value > 0.0 else value + threshold


ABLATIONS = ("estimator", "battery")  # parts an ablation study may make ideal (`cfstack step --ablate`)


class CrazyflieFirmware(Firmware):
    def __init__(self, vehicle: Vehicle, params: FirmwareParams, cf: CrazyflieParams | None = None,
                 ideal: tuple[str, ...] = ()):
        super().__init__(vehicle, params)
        # Ablation only (never a default): "estimator" flies on the body's true attitude and rates instead of
        # the onboard estimate; "battery" holds the battery at full voltage without sag, measured exactly.
        self.ideal = frozenset(ideal)
        self._body: BodyState | None = None
        cf = cf or load_crazyflie_params()
        self.cf = cf
        dt = 1.0 / cf.attitude_rate_hz
        self.controller = ControllerPid(AttitudeController(cf.pid_attitude, cf.pid_rate, dt), dt,
                                        PositionController(cf.position_gains, 1.0 / cf.position_rate_hz),
                                        position_every=max(1, round(cf.attitude_rate_hz / cf.position_rate_hz)))
        self.position = PositionEstimator(cf.position_process_density, cf.ext_pos_std_m, G_MPS2,
                                          cf.initial_position_std_m)
        self._sp_position = (0.0, 0.0, 0.0)
        self._sp_yaw_deg = 0.0
        self._level_holds_z = False
        self.force_torque = ForceTorqueMixer(cf.arm_length_m, cf.thrust_to_torque_m, cf.curve.thrust_max_n,
                                             cf.curve.pwm_max)
        self.fusion = Sensfusion6(cf.two_kp, cf.two_ki)
        self.battery = Battery(vehicle.battery_capacity_mah, vehicle.battery_full_v, vehicle.battery_empty_v,
                               **cf.battery)
        self._pwm_per_n = cf.curve.pwm_max / (4.0 * cf.curve.thrust_max_n)  # collective N -> PWM units
        # the 1 kHz filter constant, applied per 500 Hz tick: two 1 kHz steps
        self._supply_b = 1.0 - (1.0 - cf.compensation_b_per_1khz) ** 2
        self.supply_v = cf.initial_supply_v
        self._k_thrust = vehicle.k_thrust
        self._drive_constants = None  # _drive's compiled kernel takes these; None: the Python drives
        if drive_kernel.COMPILED and "battery" not in self.ideal:
            self._drive_constants = drive_kernel.drive_constants(cf.curve, cf.idle_thrust_pwm, self._supply_b,
                                                                 self.battery, self.tick_period_s, self._k_thrust)
        self._estimator_every = max(1, round(vehicle.imu.rate_hz / cf.estimator_rate_hz))
        self._estimator_dt_s = self._estimator_every / vehicle.imu.rate_hz
        self._imu_count = 0
        self._gyro_sum = [0.0, 0.0, 0.0]
        self._gyro_n = 0
        self.gyro_bias_dps = (0.0, 0.0, 0.0)
        self.gyro_dps = (0.0, 0.0, 0.0)
        self.acc_g = (0.0, 0.0, 1.0)
        self.base_z_acc_g: float | None = None
        self.velocity_z_mps = 0.0
        self.motor_pwm = (0, 0, 0, 0)
        self.motor_forces_n = (0.0, 0.0, 0.0, 0.0)
        # external pose fusion: the estimate's recent history (sample time, q) to meet each fix at its own time
        self._history = TimeHistory()  # (IMU sample time, attitude estimate) per estimator update
        self._gyro_density = vehicle.imu.gyro_noise_density
        self._last_ext_time_s: float | None = None
        self._last_ext_arrival_s = -math.inf
        self._imu_time_s = 0.0
        self.external_poses = 0  # fused
        # CRTP (link.crtp.setpoints records, from simulator.crtp_service): the legacy RPYT decoder with its
        # thrust lock, the high-level commander, and the PID setpoint an RPYT packet set (None: a MAVLink one)
        self.rpyt = RpytDecoder()
        self.high_level = HighLevelCommander()
        self.high_level_enabled = True  # param commander.enHighLevel
        self.low_level_active = False  # a low-level setpoint came since the last notify-stop (its priority)
        self._sp_pid: Setpoint | None = None
        self._attitude_sp_key: tuple | None = None  # (attitude, thrust N) that _attitude_sp was built from
        self._attitude_sp: Setpoint | None = None
        self.crtp_ignored = 0  # CRTP commands the emulated firmware counted and ignored

    # --- sensors and estimator ---------------------------------------------------------------------
    def calibrate_gyro(self, samples_dps) -> None:
        """The boot calibration done before this session (an airborne start): the mean of these samples."""
        n = len(samples_dps)
        self.gyro_bias_dps = tuple(sum(s[i] for s in samples_dps) / n for i in range(3))
        self._gyro_n = self.cf.gyro_bias_samples

    def receive(self, message, arrival_s: float) -> bool:
        if isinstance(message, PositionTarget):
            self.count_uplink(arrival_s)
            return self._take_position_target(message, arrival_s)
        if type(message).__module__ == crtp.__name__:
            self.count_uplink(arrival_s)
            return self._take_crtp(message, arrival_s)
        if not super().receive(message, arrival_s):
            return False
        if isinstance(message, (AttitudeTarget, ThrustMoment)):
            self._sp_pid = None  # a MAVLink setpoint replaces an RPYT one
        if isinstance(message, ExternalPose):
            self._fuse_external(message, arrival_s)
        return True

    # --- CRTP commands (crtp_commander_rpyt.c, crtp_commander_generic.c, crtp_commander_high_level.c) ---
    def _take_crtp(self, record, arrival_s: float) -> bool:
        """One decoded CRTP command. As in the Crazyflie's default build (no CONFIG_MOTORS_REQUIRE_ARMING)
        the supervisor arms by itself when a setpoint comes; a crashed vehicle takes none."""
        if isinstance(record, crtp.ExternalPosition):
            return self._take_external_position(record, arrival_s)
        if self.mode == VehicleMode.CRASHED:
            self.rejected_commands += 1
            return False
        if isinstance(record, crtp.Rpyt):
            return self._take_rpyt(record, arrival_s)
        if isinstance(record, crtp.FullState):
            # the PID controller flies a full state as a position with the quaternion's yaw (controller_pid.c:
            # x, y, z absolute, yaw from mode.quat; its velocity, acceleration and rates are not used)
            yaw_rad = euler_zyx_of(record.attitude_wxyz)[2] if all(map(math.isfinite, record.attitude_wxyz)) \
                else math.nan
            record = crtp.PositionSetpoint(*record.position_m, math.degrees(yaw_rad))
        if isinstance(record, crtp.PositionSetpoint):
            values = (record.x_m, record.y_m, record.z_m, record.yaw_deg)
            target = PositionTarget(arrival_s, values[:3], (0.0, 0.0, 0.0), math.radians(record.yaw_deg))
            if self._auto_arm(arrival_s, values) and self._take_position_target(target, arrival_s):
                self.low_level_active = True
                return True
            return False
        if isinstance(record, (crtp.VelocityWorld, crtp.Hover)):
            return self._take_velocity(record, arrival_s)
        if isinstance(record, crtp.ZDistance):
            return self._take_z_distance(record, arrival_s)
        if isinstance(record, crtp.AltitudeHold):
            return self._take_pid_setpoint(record, arrival_s, ALTITUDE_HOLD_MODES, self.position.p[2],
                                           attitude_deg=(record.roll_deg, record.pitch_deg, 0.0),
                                           velocity_mps=(0.0, 0.0, record.vz_mps))
        if isinstance(record, crtp.Manual):
            return self._take_manual(record, arrival_s)
        if isinstance(record, crtp.CppmEmulation):
            return self._take_cppm(record, arrival_s)
        if isinstance(record, crtp.StopSetpoint):
            self.low_level_active = True
            self._stop_motors(arrival_s)
            return True
        if isinstance(record, crtp.NotifySetpointsStop):
            self.low_level_active = False  # commanderRelaxPriority: the high-level commander may take over
            return True
        if isinstance(record, crtp.HighLevel):
            return self._take_high_level(record, arrival_s)
        if isinstance(record, crtp.SupervisorRequest):
            return self._take_supervisor(record, arrival_s)
        self.crtp_ignored += 1
        return False

    def _auto_arm(self, arrival_s: float, values) -> bool:
        if not all(math.isfinite(v) for v in values):
            self.rejected_commands += 1
            return False
        if not self.armed:
            self.arm(arrival_s)
        return True

    def _take_rpyt(self, sp: crtp.Rpyt, arrival_s: float) -> bool:
        values = (sp.roll_deg, sp.pitch_deg, sp.yaw_rate_dps)
        # commander priority fell to DISABLE (no setpoint for the shutdown timeout): the lock re-arms
        stale = arrival_s - self._sp_arrival_s > self._shutdown_timeout_s
        if not self._auto_arm(arrival_s, values):
            return False
        setpoint = self.rpyt.decode(sp.roll_deg, sp.pitch_deg, sp.yaw_rate_dps, sp.thrust, priority_disabled=stale)
        self._hold_attitude_setpoint(arrival_s, setpoint)
        return True

    def _take_manual(self, sp: crtp.Manual, arrival_s: float) -> bool:
        """manualDecoder: roll and pitch as angles or (rate) as rates, yaw rate, thrust as sent (the generic
        setpoints have no thrust lock and no clamps: the power distribution caps it)."""
        roll_pitch = (sp.roll, sp.pitch, 0.0)
        modes, angles, rates = ((RATE_MODES, (0.0, 0.0, 0.0), roll_pitch) if sp.rate
                                else (LEVEL_MODES, roll_pitch, (0.0, 0.0, 0.0)))
        return self._take_attitude_setpoint(arrival_s, Setpoint(modes, angles, (*rates[:2], sp.yaw_rate_dps),
                                                                float(sp.thrust)))

    def _take_cppm(self, sp: crtp.CppmEmulation, arrival_s: float) -> bool:
        """cppmEmuDecoder: RC channels around 1500 us onto angles (self-levelling, by default) or rates, each
        inverted, the yaw rate inverted too, thrust 1000..2000 us onto 0..UINT16_MAX (never negative)."""
        scale = self.cf.cppm
        roll, pitch, yaw = ((CPPM_MID_US - v) / CPPM_HALF_RANGE_US for v in (sp.roll_us, sp.pitch_us, sp.yaw_us))
        thrust = max(0.0, (sp.thrust_us - CPPM_THRUST_LOW_US) / CPPM_THRUST_RANGE_US * self.cf.curve.pwm_max)
        yaw_rate = yaw * scale["yaw_max_rate_dps"]
        if sp.aux_us and sp.aux_us[0] < CPPM_LEVEL_AUX_US:
            rates = (roll * scale["roll_max_rate_dps"], pitch * scale["pitch_max_rate_dps"], yaw_rate)
            setpoint = Setpoint(RATE_MODES, (0.0, 0.0, 0.0), rates, thrust)
        else:
            angles = (roll * scale["roll_max_angle_deg"], pitch * scale["pitch_max_angle_deg"], 0.0)
            setpoint = Setpoint(LEVEL_MODES, angles, (0.0, 0.0, yaw_rate), thrust)
        return self._take_attitude_setpoint(arrival_s, setpoint)

    def _take_attitude_setpoint(self, arrival_s: float, setpoint: Setpoint) -> bool:
        """An attitude (or rate) setpoint with its own thrust, flown without the position estimate."""
        values = (*setpoint.attitude_deg, *setpoint.attitude_rate_dps, setpoint.thrust_pwm)
        if not self._auto_arm(arrival_s, values):
            return False
        self._hold_attitude_setpoint(arrival_s, setpoint)
        return True

    def _hold_attitude_setpoint(self, arrival_s: float, setpoint: Setpoint) -> None:
        """The PID setpoint from now on (a low-level one: it has the priority); its thrust, capped as the power
        distribution caps it, is what the watchdog's level-out keeps."""
        self.low_level_active = True
        self._sp_arrival_s = arrival_s
        self._sp_pid = setpoint
        self._sp_thrust_n = min(setpoint.thrust_pwm, self.cf.curve.pwm_max) / self._pwm_per_n
        self.mode = VehicleMode.ATTITUDE

    def _take_velocity(self, sp, arrival_s: float) -> bool:
        """Velocity world (x, y, z velocity) or hover (x, y velocity in the yaw frame, z absolute), yaw rate:
        flown by the position controller's velocity PIDs."""
        hover = isinstance(sp, crtp.Hover)
        return self._take_pid_setpoint(sp, arrival_s, HOVER_MODES if hover else VELOCITY_WORLD_MODES,
                                       sp.z_m if hover else self.position.p[2],
                                       velocity_mps=(sp.vx_mps, sp.vy_mps, 0.0 if hover else sp.vz_mps),
                                       velocity_body=hover)

    def _take_z_distance(self, sp, arrival_s: float) -> bool:
        """Roll and pitch absolute, yaw rate, height absolute (zDistanceDecoder)."""
        return self._take_pid_setpoint(sp, arrival_s, Z_DISTANCE_MODES, sp.z_m,
                                       attitude_deg=(sp.roll_deg, sp.pitch_deg, 0.0))

    def _take_pid_setpoint(self, sp, arrival_s: float, modes, height_m: float, *, attitude_deg=(0.0, 0.0, 0.0),
                           velocity_mps=(0.0, 0.0, 0.0), velocity_body: bool = False) -> bool:
        """A setpoint with a yaw rate that the PID controller flies on the position estimate (its velocity or
        height): refused without a position estimate, as a position setpoint is. The held position (x, y
        where it is, height_m) is what a watchdog level-out holds."""
        if not self.position.valid:
            self.rejected_commands += 1
            return False
        if not self._auto_arm(arrival_s, tuple(vars(sp).values())):  # refuses (and counts) a non-finite one
            return False
        self._sp_position = (self.position.p[0], self.position.p[1], height_m)
        self._sp_pid = Setpoint(modes, attitude_deg, (0.0, 0.0, sp.yaw_rate_dps), position_m=self._sp_position,
                                velocity_mps=velocity_mps, velocity_body=velocity_body)
        self._sp_arrival_s = arrival_s
        self.low_level_active = True
        self.mode = VehicleMode.POSITION
        return True

    def _stop_motors(self, arrival_s: float) -> None:
        self._sp_arrival_s = arrival_s
        self._sp_pid = None
        self.high_level.plan = None
        self.mode = VehicleMode.IDLE  # armed, thrust 0: the tick's idle branch

    def _take_external_position(self, fix: crtp.ExternalPosition, arrival_s: float) -> bool:
        """extpos / extpose into the estimator (estimatorEnqueuePosition / Pose), stamped on arrival."""
        position = (fix.x_m, fix.y_m, fix.z_m)
        if not all(math.isfinite(v) for v in position):
            self.rejected_commands += 1
            return False
        if fix.attitude_wxyz is None:  # position only: the attitude estimate is left alone
            self._fuse_position_fix(position, arrival_s)
            return True
        self._fuse_external(ExternalPose(arrival_s, position, fix.attitude_wxyz), arrival_s)
        return True

    def _take_high_level(self, request: crtp.HighLevel, arrival_s: float) -> bool:
        if not self.high_level_enabled or not self.position.valid:
            self.crtp_ignored += 1  # disabled (commander.enHighLevel = 0), or no position to plan from
            return False
        values = (request.x_m, request.y_m, request.z_m, request.yaw_rad, request.duration_s)
        if not self._auto_arm(arrival_s, values):
            return False
        yaw_now = math.radians(self.estimate_rpy_deg[2])
        yaw = None if request.use_current_yaw else request.yaw_rad
        ok = self.high_level.request(request.kind, (request.x_m, request.y_m, request.z_m), yaw,
                                     request.duration_s, arrival_s, tuple(self.position.p), yaw_now,
                                     request.relative)
        if not ok:
            self.rejected_commands += 1
            return False
        if request.kind == "stop":
            self._stop_motors(arrival_s)
        return True

    def _take_supervisor(self, request: crtp.SupervisorRequest, arrival_s: float) -> bool:
        if request.kind == "arm":
            if not self.armed:
                self.arm(arrival_s)
        elif request.kind in ("disarm", "emergency_stop"):
            self.disarm()
            self.high_level.plan = None
        return True

    def _fly_high_level(self, t_s: float) -> None:
        """A high-level plan flies when no low-level setpoint holds the priority: it streams position
        setpoints each tick, which keeps the watchdog fed as the firmware's does."""
        target = self.high_level.setpoint(t_s)
        if target is None or self.low_level_active or not self.armed or self.mode == VehicleMode.LANDING:
            return
        position, yaw_rad = target
        self._sp_position = position
        self._sp_yaw_deg = math.degrees(yaw_rad)
        self._sp_pid = None
        self._sp_arrival_s = t_s
        self.mode = VehicleMode.POSITION

    def _take_position_target(self, sp: PositionTarget, arrival_s: float) -> bool:
        """A position setpoint for the onboard position controller: refused (counted) when not finite, or
        while the vehicle has no position estimate (no external pose yet: nothing to fly it on)."""
        values = (sp.time_s, *sp.position_enu_m, *sp.velocity_enu_mps, sp.yaw_enu_rad)
        try:
            finite = len(sp.position_enu_m) == 3 and all(math.isfinite(v) for v in values)
        except TypeError:
            finite = False
        if not finite or not self.position.valid:
            self.rejected_commands += 1
            return False
        if not self.armed or self.mode in (VehicleMode.LANDING, VehicleMode.CRASHED):
            self.ignored_setpoints += 1
            return True
        self._sp_arrival_s = arrival_s
        self._sp_position = tuple(float(v) for v in sp.position_enu_m)
        self._sp_yaw_deg = math.degrees(sp.yaw_enu_rad)
        self._sp_pid = None
        self.mode = VehicleMode.POSITION
        return True

    def _fuse_external(self, pose: ExternalPose, arrival_s: float) -> None:
        """Correct the attitude toward the fix, compared with the estimate at the fix's own sample time
        (the mocap and radio latency are not mistaken for an attitude error); the first fix sets it."""
        q_ext = pose.attitude_wxyz
        if not all(math.isfinite(v) for v in (*q_ext, pose.time_s)):
            self.rejected_commands += 1
            return
        self._last_ext_arrival_s = arrival_s
        dt = self._fuse_position_fix(pose.position_enu_m, pose.time_s)
        if dt is None:
            self.fusion.q = [float(v) for v in q_ext]
            return
        then = self._history.at(pose.time_s) or self.fusion.q
        # error rotation from the estimate then to the fix, in the body frame
        gain = self._gyro_density * math.sqrt(dt) / self.cf.ext_quat_std_rad
        ex, ey, ez = attitude_error(tuple(then), q_ext)
        self.fusion.rotate_body(gain * ex, gain * ey, gain * ez)
        self.external_poses += 1

    def _fuse_position_fix(self, position_enu_m, time_s: float) -> float | None:
        """A fix's position into the position estimator (when finite); the time since the previous fix,
        capped - what each fix's correction is weighted by - or None for the first fix."""
        previous = self._last_ext_time_s
        dt = 0.0 if previous is None else min(max(time_s - previous, 0.0), self.cf.ext_fresh_for_s)
        if all(math.isfinite(v) for v in position_enu_m):
            self.position.fuse(position_enu_m, time_s, dt)
        self._last_ext_time_s = time_s if previous is None else max(previous, time_s)
        return None if previous is None else dt

    def take_imu(self, sample: ImuSample) -> None:
        self._imu_time_s = sample.time_s
        w, f = sample.rate_flu_radps, sample.specific_force_flu_mps2
        raw = (w[0] * DEG_PER_RAD, w[1] * DEG_PER_RAD, w[2] * DEG_PER_RAD)
        if not self.armed and self._gyro_n < self.cf.gyro_bias_samples:
            s = self._gyro_sum
            s[0] += raw[0]
            s[1] += raw[1]
            s[2] += raw[2]
            self._gyro_n += 1
            self.gyro_bias_dps = (s[0] / self._gyro_n, s[1] / self._gyro_n, s[2] / self._gyro_n)
        b = self.gyro_bias_dps
        self.gyro_dps = (raw[0] - b[0], raw[1] - b[1], raw[2] - b[2])
        self.acc_g = (f[0] / G_MPS2, f[1] / G_MPS2, f[2] / G_MPS2)
        self._imu_count += 1
        if self._imu_count % self._estimator_every == 0:
            self._update_estimate()

    def _update_estimate(self) -> None:
        dt = self._estimator_dt_s
        fixes = self._imu_time_s - self._last_ext_arrival_s <= self.cf.ext_fresh_for_s
        self.fusion.update(self.gyro_dps, self.acc_g, dt, use_accelerometer=not fixes)
        self._history.append(self._imu_time_s, self.fusion.q)
        a = self.acc_g
        g = G_MPS2
        self.position.predict(self._imu_time_s, self.fusion.q, (a[0] * g, a[1] * g, a[2] * g), dt)
        qw, qx, qy, qz = self.fusion.q
        gravity = (2.0 * (qx * qz - qw * qy), 2.0 * (qw * qx + qy * qz), qw * qw - qx * qx - qy * qy + qz * qz)
        acc_z = a[0] * gravity[0] + a[1] * gravity[1] + a[2] * gravity[2]
        if self.base_z_acc_g is None:  # sensfusion6UpdateQ: the first reading is the at-rest 1 g
            self.base_z_acc_g = acc_z
        acc_wz = acc_z - self.base_z_acc_g
        self.velocity_z_mps += _deadband(acc_wz, self.cf.v_acc_deadband_g) * dt * G_MPS2
        self.velocity_z_mps *= self.cf.vel_z_alpha

    @property
    def estimate_rpy_deg(self) -> tuple[float, float, float]:
        return self.fusion.euler_rpy_deg()

    @property
    def position_variance_m2(self) -> tuple[float, float, float]:
        return self.position.variance_m2

    @property
    def fusion_q(self) -> tuple[float, float, float, float]:
        """The attitude estimate (w, x, y, z)."""
        return tuple(self.fusion.q)

    def take_position_fix(self, pose: ExternalPose, t_s: float) -> None:
        """A fix from an onboard positioning system (a simulated deck), into the estimator as extpose is,
        without counting as uplink traffic."""
        self._fuse_external(pose, t_s)

    # --- the loop ----------------------------------------------------------------------------------
    def tick(self, t_s: float, body: BodyState) -> tuple[float, ...]:
        """One stabilizer pass; rotor speeds (rad/s) whose k_T w^2 are the motor forces. The body is read for
        the crash and the floor only (and by the estimator ablation)."""
        self._body = body
        if body.crash is not None:
            self.armed = False
            self.mode = VehicleMode.CRASHED
            return self._drive((0, 0, 0, 0))
        if not self.armed:
            self.controller.reinitialize(self.estimate_rpy_deg)
            return self._drive((0, 0, 0, 0))
        if self.high_level.plan is not None:
            self._fly_high_level(t_s)
        if self.mode == VehicleMode.LANDING:
            if body.on_ground or t_s - self._landing_since_s > self.params.landing_timeout_s:
                self.disarm()
                return self._drive((0, 0, 0, 0))
            return self._drive(self._through_pid(self._landing_setpoint()))
        age_s = t_s - self._sp_arrival_s
        if age_s > self._watchdog_from_s:
            if age_s > self._shutdown_timeout_s:
                self.disarm(watchdog=True)
                return self._drive((0, 0, 0, 0))
            if self.mode != VehicleMode.LEVEL:
                self._level_holds_z = self.mode == VehicleMode.POSITION
            self.mode = VehicleMode.LEVEL
            if self._level_holds_z:
                return self._drive(self._through_pid(Setpoint(LEVEL_HOLDING_Z_MODES, position_m=self._sp_position)))
            return self._drive(self._through_pid(self._level_setpoint(self._sp_thrust_n)))
        if self.mode == VehicleMode.POSITION:
            sp = self._sp_pid or Setpoint(POSITION_MODES, (0.0, 0.0, self._sp_yaw_deg), position_m=self._sp_position)
            return self._drive(self._through_pid(sp))
        if self.mode == VehicleMode.ATTITUDE:
            return self._drive(self._through_pid(self._sp_pid or self._attitude_setpoint()))
        if self.mode == VehicleMode.MOMENTS:
            return self._drive(self.force_torque.pwm(self._sp_thrust_n, self._sp_moment))
        return self._drive(self._through_pid(self._level_setpoint(0.0)))  # armed, idle: thrust 0

    def _attitude_setpoint(self) -> Setpoint:
        """The held attitude setpoint in the controller's terms, built once per setpoint taken and reused by
        the 500 Hz cycles until the next one (it arrives at 100 Hz): the same values, 2.27 -> 0.12 us per cycle."""
        key = (self._sp_attitude, self._sp_thrust_n)
        if key != self._attitude_sp_key:
            self._attitude_sp_key = key
            self._attitude_sp = Setpoint(ATTITUDE_MODES, _legacy_rpy_deg(self._sp_attitude),
                                         thrust_pwm=self._thrust_pwm(self._sp_thrust_n))
        return self._attitude_sp

    def _level_setpoint(self, thrust_n: float) -> Setpoint:
        return Setpoint(LEVEL_MODES, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), self._thrust_pwm(thrust_n))

    def _landing_setpoint(self) -> Setpoint:
        """Level, yaw held, the thrust holding the descent speed on the onboard vertical velocity estimate:
        T = m (g + k (v_des - v_z est)) (firmware.toml [landing]); no tilt boost (the estimate is level)."""
        p = self.params
        accel = GRAVITY_MPS2 + p.landing_velocity_gain_per_s * (-p.landing_descent_speed_mps - self.velocity_z_mps)
        return self._level_setpoint(min(max(self.vehicle.mass_kg * accel, 0.0), self.vehicle.max_thrust_n))

    def _thrust_pwm(self, thrust_n: float) -> float:
        return min(max(thrust_n * self._pwm_per_n, 0.0), float(self.cf.curve.pwm_max))

    def _through_pid(self, sp: Setpoint) -> tuple[int, int, int, int]:
        position_state = (self.position.p, self.position.v)
        if "estimator" in self.ideal:
            return legacy(self.controller.update(sp, *self._true_attitude(), position_state))
        return legacy(self.controller.update(sp, self.estimate_rpy_deg, self.gyro_dps, position_state))

    def _true_attitude(self):
        """Ablation: the body's true attitude (legacy roll, pitch, yaw deg) and rates (deg/s)."""
        w = self._body.rate_flu_radps
        return _legacy_rpy_deg(self._body.attitude_wxyz), (w[0] * DEG_PER_RAD, w[1] * DEG_PER_RAD, w[2] * DEG_PER_RAD)

    def _drive(self, uncapped) -> tuple[float, ...]:
        """Battery compensation, the cap, then the motors on the battery's true voltage: compiled
        (drive_kernel) where it was built and the battery is not ablated, else _drive_python."""
        if self._drive_constants is not None:
            b = self.battery
            out = drive_kernel.drive(uncapped, self.supply_v, b.voltage_v, b.drawn_as, self._drive_constants)
            if out is not None:
                self.motor_pwm, self.motor_forces_n, speeds, self.supply_v, b.voltage_v, b.current_a, b.drawn_as = out
                return MOTORS_OFF if speeds is None else speeds
        return self._drive_python(uncapped)

    def _drive_python(self, uncapped) -> tuple[float, ...]:
        """_drive in Python (the compiled kernel's twin, and what runs where it was not built)."""
        cf, curve = self.cf, self.cf.curve
        if "battery" in self.ideal:
            self.battery.voltage_v = self.battery.full_v
            self.supply_v = self.battery.full_v
        self.supply_v += self._supply_b * (self.battery.voltage_v - self.supply_v)
        compensated = tuple(int(curve.compensate(m, self.supply_v)) for m in uncapped)
        pwm = cap(compensated, curve.pwm_max, cf.idle_thrust_pwm)
        self.motor_pwm = pwm
        v = self.battery.voltage_v
        forces = tuple(curve.thrust_n(r, v) for r in pwm)
        self.motor_forces_n = forces
        if "battery" not in self.ideal:
            self.battery.step(forces, self.tick_period_s)
        k = self._k_thrust
        return tuple(math.sqrt(f / k) for f in forces) if any(forces) else MOTORS_OFF

    # --- reports -----------------------------------------------------------------------------------
    @property
    def state_of_charge(self) -> float:
        return self.battery.charge_left

    @property
    def motor_duty(self) -> tuple[float, float, float, float]:
        """Each motor's PWM duty 0..1 (motor.m1..m4 / pwm_max), as the last cycle set it."""
        pwm_max = self.cf.curve.pwm_max
        return tuple(p / pwm_max for p in self.motor_pwm)

    def battery_status(self) -> BatteryStatus:
        return BatteryStatus(voltage_v=self.battery.voltage_v, remaining_pct=int(round(100.0 * self.state_of_charge)),
                             rejected_commands=self.rejected_commands, uplink_received=self.uplink_received)

