"""One emulated Crazyflie in-process: physics, onboard firmware and sensors on one simulation clock.

Takes in: uplink messages (ThrustMoment, AttitudeTarget, VehicleCommand, MotorOutputsRequest, TimeSync
requests, ground-station Heartbeats) delivered by the radio at a sim time (`handle_uplink`), and `step()`
calls (one physics step of 1 / physics_rate_hz each).
Gives out: `pop_outputs()` -> Output(release_time_s, channel, message), in release order, holding each
until the vehicle's clock reaches its release time:
  "downlink": ImuSample (imu rate), Heartbeat and BatteryStatus (telemetry rates), TimeSync replies,
              MotorOutputs at the rate a MotorOutputsRequest asked (faithful firmware; none unless asked);
  "mocap":    MocapPose (mocap rate; time_s = sample time, released latency_s later; dropped frames
              are simply absent);
  "truth":    TruthState (telemetry.truth_rate_hz; simulation only);
  "crtp":     CRTP packets (bytes): the replies of the vehicle's CRTP services (`crtp`, set by the fleet)
              to the CrtpDatagrams delivered, and its log blocks, both at firmware cycles;
plus `crash` (None or a dynamics.Crash) and `truth` (the current TruthState). No transport here.

Within a step at time t, in order: if the firmware is due (500 Hz), it takes every uplink message
delivered by t from its radio queue, in delivery order, each stamped with the cycle's time t (the
commander watchdog counts from it; a TIMESYNC request is answered with it; a CRTP packet is served by
the vehicle's CRTP services, as the Crazyflie's CRTP tasks take it), and ticks, setting the rotor
command, then the CRTP log blocks due are read; sensors and telemetry due by t sample the state at t
(stamped t), then the physics integrates to t + dt. Periodic tasks run on an integer schedule k / rate
(no drift), sampled at the first physics step at or after each due time; a step with nothing due (half
of them at 1 kHz physics and 500 Hz tasks) runs the physics alone. Everything random comes from the Generator passed in
(split into independent IMU and mocap streams), so the same seed gives identical outputs.

airborne=True starts in flight: armed, rotors at hover speed, as if a hover ThrustMoment arrived at
t = 0 - so the commander watchdog (level at 0.5 s, motors off at 2 s) applies until setpoints come.
"""

from __future__ import annotations

import heapq
import math
from collections import deque
from pathlib import Path
from typing import NamedTuple

import numpy as np

from link.messages import Message, MotorOutputs, MotorOutputsRequest, TimeSync, TruthState
from model.errors import UserError, WorldError
from model.firmwares import FIRMWARE_VEHICLES
from model.frames import rotate
from model.vehicle import GRAVITY_MPS2, MocapRoom, Vehicle
from model.world import World
from simulator.crtp_service import CrtpDatagram
from simulator.dynamics import Crash, QuadrotorDynamics
from simulator.firmware import Firmware, FirmwareParams, load_firmware_params
from simulator.profiling import time_parts
from simulator.sensors import ImuModel, MocapModel
from simulator.variation import VariationProfile
from simulator.variation import draw as draw_variation

_EPS_S = 1e-9  # schedule comparisons tolerate float rounding of k / rate (well under a nanosecond tick)
NS_PER_S = 1_000_000_000


class Output(NamedTuple):
    release_time_s: float
    channel: str  # "downlink", "mocap", "truth" or "crtp"
    message: Message  # (bytes on "crtp")


class _Schedule:
    """Due times k / rate_hz, k = 0, 1, ...; skips ahead when the caller steps slower than the rate."""

    __slots__ = ("period_s", "k", "next_s")

    def __init__(self, rate_hz: float):
        self.period_s = 1.0 / rate_hz
        self.k = 0
        self.next_s = 0.0

    def advance(self, t_s: float) -> None:
        """The next due time after t_s: k + 1, or later if the caller skipped whole periods."""
        k = self.k + 1
        next_s = k * self.period_s
        if next_s <= t_s + _EPS_S:
            k = max(k, math.floor((t_s + _EPS_S) / self.period_s) + 1)
            next_s = k * self.period_s
        self.k, self.next_s = k, next_s


class SimVehicle:
    def __init__(self, vehicle: Vehicle, rng: np.random.Generator, *, world: World | None = None,
                 mocap_room: MocapRoom | None = None, vehicle_id: int = 1, physics_rate_hz: float = 1000.0,
                 initial_position_enu_m=(0.0, 0.0, 0.0),
                 firmware_params: FirmwareParams | str | Path | None = None,
                 airborne: bool = False, profile: bool = False, firmware: str = "ideal",
                 variation: VariationProfile | None = None, ideal_parts: tuple[str, ...] = ()):
        if not (isinstance(physics_rate_hz, (int, float)) and math.isfinite(physics_rate_hz)
                and physics_rate_hz > 0.0):
            raise UserError(f"physics rate must be a positive number of Hz, got {physics_rate_hz!r}")
        params = (firmware_params if isinstance(firmware_params, FirmwareParams)
                  else load_firmware_params(firmware_params or "firmware"))
        self.vehicle = vehicle  # what the onboard firmware believes (the nominal vehicle file)
        self.vehicle_id = vehicle_id
        self.params = params
        self.world = world
        self.start_enu_m = _checked_start(initial_position_enu_m, world, vehicle.collision_radius_m)
        self._dt_s = 1.0 / physics_rate_hz
        imu_rng, mocap_rng = rng.spawn(2)
        # this vehicle's own draw (a third stream: the IMU and mocap streams are the same with or without it)
        self.draw = draw_variation(variation, rng.spawn(1)[0])
        self.body = self.draw.apply(vehicle)  # what the physics flies
        self._motor_gain = tuple(math.sqrt(f) for f in self.draw.motor_thrust_factors)  # thrust ~ w^2
        self._varied_motors = self._motor_gain != (1.0, 1.0, 1.0, 1.0)
        self._imu_rows = self.draw.misalignment_rows()
        self._imu_misaligned = any(v != 0.0 for v in self.draw.imu_misalignment_rad)
        self.dynamics = self._new_dynamics(self.start_enu_m)
        self.reboots = 0  # REBOOT commands carried out
        self.firmware_kind = firmware
        self.ideal_parts = tuple(ideal_parts)
        self.firmware = make_firmware(firmware, vehicle, params, self.ideal_parts)
        # The faithful firmware flies on its IMU: a sample due with a firmware cycle is taken first, as the
        # Crazyflie's stabilizer runs on each fresh IMU reading; the ideal one reads the body directly.
        self._imu_before_firmware = hasattr(self.firmware, "take_imu")
        self.imu = ImuModel(vehicle.imu, imu_rng)
        self.mocap = MocapModel(mocap_room, mocap_rng, vehicle_id) if mocap_room is not None else None
        self._fw = _Schedule(params.commander_rate_hz)
        self._imu = _Schedule(vehicle.imu.rate_hz)
        self._mocap = _Schedule(mocap_room.rate_hz) if mocap_room is not None else None
        self._boot_calibration()
        self._truth = _Schedule(params.truth_rate_hz)
        self._heartbeat = _Schedule(params.heartbeat_rate_hz)
        self._battery = _Schedule(params.battery_rate_hz)
        self._motor_outputs: _Schedule | None = None  # MotorOutputs only on request (MotorOutputsRequest)
        self.crtp = None  # simulator.crtp_service.CrtpService, when the fleet serves CRTP
        self._uplinks: list[tuple[float, int, Message]] = []
        self._uplink_seq = 0
        self._out: list[Output] = []  # in release order (everything in it is stamped with its step's time)
        self._mocap_pending: deque[Output] = deque()
        self._due_s = 0.0  # the earliest of the schedules' due times (queued uplinks wait for the firmware)
        # Whether every firmware cycle k / rate is a physics step start: then an uplink cannot act before
        # the first cycle at or after its delivery (first_effect_s, the emulator's lockstep lookahead).
        steps_per_cycle = physics_rate_hz / params.commander_rate_hz
        self._fw_on_steps = abs(steps_per_cycle - round(steps_per_cycle)) < 1e-9 and round(steps_per_cycle) >= 1
        self.timing_s: dict[str, float] = {}
        if profile:  # benchmarks: the same step, its parts timed (simulator.profiling)
            time_parts(self, {"_deliver_due": "uplink", "_tick_firmware": "firmware", "_sample_due": "sensors"},
                       self.timing_s)
            time_parts(self.dynamics, {"step": "physics"}, self.timing_s)
        if airborne:
            hover = self.body.hover_rotor_speed_radps
            if not self.dynamics.on_ground:
                self.dynamics.set_state(rotor_speeds_radps=(hover,) * 4)
            self.firmware.start_hovering(0.0)

    # --- public -----------------------------------------------------------------------------------
    @property
    def t_s(self) -> float:
        """Simulation time (s) = the vehicle's boot clock."""
        return self.dynamics.t_s

    @property
    def crash(self) -> Crash | None:
        return self.dynamics.crash

    @property
    def truth(self) -> TruthState:
        return self.dynamics.truth()

    def handle_uplink(self, message: Message, t_s: float) -> None:
        """A message the radio delivers at sim time t_s: queued for the first firmware cycle at or after
        t_s (the firmware reads its radio queue once per cycle, as the Crazyflie's commander takes
        setpoints in its stabilizer loop), so nothing an uplink frame does acts between cycles."""
        if not math.isfinite(t_s):
            raise ValueError(f"uplink delivery time must be finite, got {t_s!r}")
        heapq.heappush(self._uplinks, (t_s, self._uplink_seq, message))
        self._uplink_seq += 1

    @property
    def firmware_period_s(self) -> float:
        """The firmware cycle's period (s): first_effect_s rounds a delivery up by less than this."""
        return self._fw.period_s

    def first_effect_s(self, delivery_s: float) -> float:
        """The earliest simulation time at which a message delivered at or after delivery_s can change
        anything (a lower bound): the first firmware cycle at or after it, when every firmware cycle
        falls on a physics step boundary; otherwise delivery_s itself."""
        if not self._fw_on_steps:
            return delivery_s
        period = self._fw.period_s
        k = math.ceil((delivery_s - _EPS_S) / period)  # - eps: a delivery on a cycle is handled in it
        return max(delivery_s, k * period)

    def step(self) -> None:
        """One physics step (see the module docstring for what happens inside)."""
        d = self.dynamics
        t = d.t_s
        if t + _EPS_S >= self._due_s:  # most steps at 1 kHz have nothing due but the physics
            if self._imu_before_firmware and t + _EPS_S >= self._imu.next_s:
                self._sample_imu(t)
            if t + _EPS_S >= self._fw.next_s:
                if self._uplinks and self._uplinks[0][0] <= t + _EPS_S:
                    self._deliver_due(t)
                self._tick_firmware(t)
                if self.crtp is not None and self.crtp.blocks:
                    self._out.extend(Output(t, "crtp", packet) for packet in self.crtp.due(t))
                if self.firmware.reboot_requested:
                    self.reboot()
                    d = self.dynamics
            self._sample_due(t)
        d.step()

    def reboot(self) -> None:
        """The flight controller restarts (a REBOOT command): the vehicle is set back where it started,
        at rest on the surface below its start point (a crashed vehicle picked up and put back), disarmed,
        on the same clock; the sensors keep their random streams, so a run stays a function of its seed."""
        old = self.dynamics
        self.dynamics = self._new_dynamics(self._ground_start())
        self.dynamics.continue_clock(old.steps)
        self.firmware = make_firmware(self.firmware_kind, self.vehicle, self.params, self.ideal_parts)
        self._boot_calibration()
        self.reboots += 1
        if self.timing_s:  # profiled: time the new body's physics too
            time_parts(self.dynamics, {"step": "physics"}, self.timing_s)

    def _boot_calibration(self) -> None:
        """The faithful firmware was switched on lying still before t = 0 (as a lab's Crazyflie is, before its
        ground station connects) and took its gyro bias then: the firmware's boot calibration, from IMU
        samples at rest that are not published. The ideal firmware needs none."""
        calibrate = getattr(self.firmware, "calibrate_gyro", None)
        if calibrate is None:
            return
        at_rest = (0.0, 0.0, GRAVITY_MPS2)
        dt = 1.0 / self.imu.rate_hz
        count = self.firmware.cf.gyro_bias_samples
        samples = [self.imu.sample(-(count - k) * dt, at_rest, (0.0, 0.0, 0.0)).rate_flu_radps for k in range(count)]
        calibrate([tuple(math.degrees(w) for w in rate) for rate in samples])

    def _ground_start(self) -> tuple[float, float, float]:
        x, y, z = self.start_enu_m
        floor = float(self.world.bounds[4]) if self.world is not None else 0.0
        return (x, y, self.world.support_height((x, y, z)) if self.world is not None else floor)

    def _new_dynamics(self, position: tuple[float, float, float]) -> QuadrotorDynamics:
        return QuadrotorDynamics(self.body, self.params.contact, world=self.world, dt_s=self._dt_s,
                                 position_enu_m=position)

    def run(self, duration_s: float) -> None:
        """Step until the clock has advanced by duration_s (rounded to whole steps)."""
        for _ in range(round(duration_s / self.dynamics.dt_s)):
            self.step()

    def pop_outputs(self) -> list[Output]:
        """Every output released by now (t_s), oldest release first; later ones stay queued."""
        out = self._out
        pending = self._mocap_pending
        now = self.dynamics.t_s + _EPS_S
        mocap_due = pending and pending[0].release_time_s <= now
        if not out and not mocap_due:
            return []  # most steps
        self._out = []
        if mocap_due:
            unsorted = bool(out)  # frames sampled earlier, released among newer outputs
            while pending and pending[0].release_time_s <= now:
                out.append(pending.popleft())
            if unsorted:
                out.sort(key=_release_time)  # stable: equal times keep their order
        return out

    # --- step parts -------------------------------------------------------------------------------
    def _sample_due(self, t: float) -> None:
        """The sensors and telemetry due by t (IMU, mocap, truth), then the next time anything is due."""
        te = t + _EPS_S
        due = math.inf
        if te >= self._imu.next_s:
            self._sample_imu(t)
        mocap = self._mocap
        if mocap is not None:
            if te >= mocap.next_s:
                self._sample_mocap(t)
            due = min(due, mocap.next_s)
        if te >= self._truth.next_s:
            self._emit_truth(t)
        self._due_s = min(due, self._fw.next_s, self._imu.next_s, self._truth.next_s)

    def _deliver_due(self, t: float) -> None:
        """The firmware cycle at t takes every message delivered by t, in delivery order."""
        queue = self._uplinks
        while queue and queue[0][0] <= t + _EPS_S:
            self._deliver(heapq.heappop(queue)[2], t)

    def _deliver(self, message: Message, cycle_s: float) -> None:
        if type(message) is CrtpDatagram:
            self._out.extend(Output(cycle_s, "crtp", reply) for reply in self.crtp.handle(message.data, cycle_s))
            return
        if isinstance(message, MotorOutputsRequest):
            self.firmware.count_uplink(cycle_s)
            # SET_MESSAGE_INTERVAL: from this cycle on, MotorOutputs at the rate asked (0 stops them)
            self._motor_outputs = _Schedule(message.rate_hz) if message.rate_hz > 0.0 else None
            return
        if isinstance(message, TimeSync):
            self.firmware.count_uplink(cycle_s)  # every uplink message counts, TIMESYNC too
            if message.remote_ns == 0:  # a request; tc1 = 0 would read as another request, so >= 1 ns
                clock_ns = max(1, round(cycle_s * NS_PER_S))
                reply = TimeSync(remote_ns=clock_ns, origin_ns=message.origin_ns)
                self._out.append(Output(cycle_s, "downlink", reply))
            return
        self.firmware.receive(message, cycle_s)  # taken now: the same cycle whatever step popped it

    def _tick_firmware(self, t: float) -> None:
        self._fw.advance(t)
        speeds = self.firmware.tick(t, self.dynamics)
        if self._varied_motors:  # each motor makes its own factor of the thrust the firmware asks for
            g = self._motor_gain
            speeds = (speeds[0] * g[0], speeds[1] * g[1], speeds[2] * g[2], speeds[3] * g[3])
        self.dynamics.command_rotor_speeds(speeds)
        if t + _EPS_S >= self._heartbeat.next_s:
            self._heartbeat.advance(t)
            self._out.append(Output(t, "downlink", self.firmware.heartbeat()))
        if t + _EPS_S >= self._battery.next_s:
            self._battery.advance(t)
            self._out.append(Output(t, "downlink", self.firmware.battery_status()))
        motors = self._motor_outputs
        if motors is not None and t + _EPS_S >= motors.next_s:
            motors.advance(t)
            duty = getattr(self.firmware, "motor_duty", None)  # the faithful firmware's PWM; the ideal has none
            if duty is not None:
                self._out.append(Output(t, "downlink", MotorOutputs(t, duty)))

    def _sample_imu(self, t: float) -> None:
        self._imu.advance(t)
        d = self.dynamics
        f = d.specific_force_flu()
        dv = d.take_contact_dv_flu()
        if dv != (0.0, 0.0, 0.0):  # a touchdown since the last sample: its impulse over the sample period
            rate = self.imu.rate_hz
            f = (f[0] + dv[0] * rate, f[1] + dv[1] * rate, f[2] + dv[2] * rate)
        w = d.rate_flu_radps
        if self._imu_misaligned:  # the IMU measures in its own, slightly rotated axes
            f, w = rotate(self._imu_rows, *f), rotate(self._imu_rows, *w)
        sample = self.imu.sample(t, f, w)
        if self._imu_before_firmware:
            self.firmware.take_imu(sample)
        self._out.append(Output(t, "downlink", sample))

    def _sample_mocap(self, t: float) -> None:
        self._mocap.advance(t)
        d = self.dynamics
        pose = self.mocap.sample(t, d.position_enu_m, d.attitude_wxyz)
        if pose is not None:
            self._mocap_pending.append(Output(t + self.mocap.latency_s, "mocap", pose))

    def _emit_truth(self, t: float) -> None:
        self._truth.advance(t)
        self._out.append(Output(t, "truth", self.dynamics.truth()))


def make_firmware(kind: str, vehicle: Vehicle, params: FirmwareParams, ideal_parts: tuple[str, ...] = ()) -> Firmware:
    """The onboard side: "ideal" (the lab report's geometric law on the true state, exact mixer) or
    "crazyflie" (the Crazyflie's own stabilizer on its own estimate: simulator.crazyflie), with the parts
    an ablation study makes ideal (crazyflie only)."""
    if kind == "ideal":
        return Firmware(vehicle, params)
    if kind == "crazyflie":
        from simulator.crazyflie.stabilizer import CrazyflieFirmware

        return CrazyflieFirmware(vehicle, params, ideal=ideal_parts)
    raise UserError(f"firmware: '{kind}' is not one of {', '.join(FIRMWARE_VEHICLES)}")


def _release_time(output: Output) -> float:
    return output.release_time_s


def _checked_start(position, world: World | None, collision_radius_m: float) -> tuple[float, float, float]:
    """The start position as floats, or a one-line error if it is not a place a vehicle can start."""
    try:
        start = tuple(float(v) for v in position)
    except (TypeError, ValueError):
        raise UserError(f"start position must be 3 numbers (x, y, z) m, got {position!r}") from None
    if len(start) != 3 or not all(math.isfinite(v) for v in start):
        raise UserError(f"start position must be 3 finite numbers (x, y, z) m, got {position!r}")
    floor = float(world.bounds[4]) if world is not None else 0.0
    if start[2] < floor:
        raise UserError(f"start position {list(start)} is below the floor (z = {floor} m)")
    if world is None:
        return start
    if not bool(world.contains(np.array(start))):
        raise WorldError(f"{world.source}: start position {list(start)} is outside the bounds")
    clearance = float(world.distance_to_blocks(np.array(start)))
    pad_top = world.support_height(start)
    # On or just above a landing pad (a block top right below) is fine: the nearest block is the pad.
    over_pad = pad_top > floor and clearance >= start[2] - pad_top - 1e-12
    if clearance < collision_radius_m and not over_pad:
        raise WorldError(f"{world.source}: start position {list(start)} is {clearance:.3f} m from a block, "
                         f"inside the vehicle's collision radius {collision_radius_m:.3f} m")
    return start
