"""The flight loop: estimator -> mission/trajectory -> controller -> send, at a fixed rate.

Takes in: a VehicleLink (downlink IMU, heartbeats, TIMESYNC replies, status; mocap poses; truth for
logs only), a clock (realtime or lockstep), the estimator, the controller, the mission, and a FlightLog.
Gives out: thrust/moment or thrust/attitude setpoints and vehicle commands on the uplink, one log row
per tick, a FlightRecord (per-tick arrays) for the summary, and TickFrames to its observers (the live
view, the GCS forwarding), which only read them.

The ground station never uses simulator truth for control: truth goes to the log and the grading only.
"""

from __future__ import annotations

import gc
import logging
import math
import signal
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from estimator.eskf import POSITION, ErrorStateKF
from groundstation.compensation import LatencyCompensator
from groundstation.controller import ControllerState, SE3Controller
from groundstation.flightlog import FlightLog
from groundstation.mission import Mission, MissionParams, MissionStep, Phase, VehicleView
from groundstation.tickframe import TickFrame
from link.messages import (
    AttitudeTarget,
    BatteryStatus,
    CrashReport,
    ExternalPose,
    Heartbeat,
    ImuSample,
    MocapPose,
    MotorOutputs,
    MotorOutputsRequest,
    PositionTarget,
    RadioStatus,
    ThrustMoment,
    TimeSync,
    TruthState,
    VehicleCommand,
    VehicleMode,
)
from link.stats import TimeSyncTracker

log = logging.getLogger("cfstack.groundstation")
NS = 1_000_000_000
COMPENSATION_RTT_SAMPLES = 5  # median over the last few TIMESYNC round trips (2 Hz): robust to one late reply
# Compensate only while flying a reference: on the ground and while arming the model has no floor contact.
COMPENSATED_PHASES = (Phase.TAKEOFF, Phase.SETTLE, Phase.TRACK, Phase.HOVER, Phase.LAND, Phase.FAILSAFE_HOLD)
TRUTH_HISTORY = 512  # truth samples kept to grade the estimate at its own time (~1 s at 500 Hz)
# The oldest generation's threshold while the loop runs (FlightLoop.run says why): gc's thresholds are C ints,
# and this, the largest, is never reached, so CPython starts no full collection by itself.
NO_AUTOMATIC_FULL_COLLECTION = 2**31 - 1


@dataclass
class LinkHealth:
    """Numbers the loop keeps about the link, from what arrives (sequence-based loss is in link stats)."""

    last_downlink_s: float | None = None
    last_heartbeat: Heartbeat | None = None
    last_heartbeat_s: float | None = None  # when it arrived (our clock)
    last_status: BatteryStatus | None = None
    uplink_received: int = 0  # unwrapped from the vehicle's 16-bit counter
    last_status_s: float | None = None  # when the newest status report arrived (our clock)
    last_radio: RadioStatus | None = None
    rtt_s: list[float] = field(default_factory=list)
    offset_s: float = 0.0  # vehicle clock - ground station clock
    have_offset: bool = False
    mocap_times: list[float] = field(default_factory=list)
    warned: set[str] = field(default_factory=set)


@dataclass
class FlightRecord:
    t: list[float] = field(default_factory=list)
    phase: list[str] = field(default_factory=list)
    ref: list[np.ndarray] = field(default_factory=list)
    est: list[np.ndarray] = field(default_factory=list)
    est_vel: list[np.ndarray] = field(default_factory=list)
    est_sigma: list[tuple | None] = field(default_factory=list)  # position (m) and velocity (m/s) std devs
    truth: list[np.ndarray | None] = field(default_factory=list)
    truth_vel: list[np.ndarray | None] = field(default_factory=list)
    truth_att: list[np.ndarray | None] = field(default_factory=list)  # quaternion (w, x, y, z)
    # truth at the estimate's own sample time (the estimate lags the tick by the link's latency), so the
    # estimator is graded on what it estimates, not on the link's delay
    truth_at_est: list[np.ndarray | None] = field(default_factory=list)
    truth_vel_at_est: list[np.ndarray | None] = field(default_factory=list)
    crash: CrashReport | None = None  # simulation only: how the flight ended, when it ended in a crash


class FlightLoop:
    def __init__(self, link, clock, estimator: ErrorStateKF, controller: SE3Controller, mission: Mission,
                 params: MissionParams, flight_log: FlightLog, mode: str, period_s: float,
                 compensator: LatencyCompensator | None = None, extpose: bool = False,
                 observers: tuple = ()):
        self.link = link
        # Displays (live view, GCS forwarding): each has period_s and observe(TickFrame), and is shown a
        # frame at most every period_s of flight time; they read the flight and change nothing in it.
        self.observers = [[observer, 0.0] for observer in observers]
        # A display that shows the motors (the live view) asks the vehicle for them (MotorOutputsRequest,
        # MAVLink only: CRTP's log blocks are fixed at connect), again each retry period until they come.
        self._motor_request = max(((o.motor_outputs_hz, o.motor_request_retry_s) for o in observers
                                   if getattr(o, "motor_outputs_hz", 0.0) > 0.0), default=None)
        self._next_motor_request_s = 0.0
        self.motor_duty: tuple[float, float, float, float] | None = None
        self.extpose = extpose  # forward each mocap pose to the vehicle, as a mocap lab streams extpose
        self.clock = clock
        self.estimator = estimator
        self.controller = controller
        self.mission = mission
        self.p = params
        self.log = flight_log
        self.mode = mode
        self.period_s = period_s
        self.compensator = compensator
        self.health = LinkHealth()
        self.truth: TruthState | None = None
        self.estimate = None  # the estimator's Estimate after this tick's samples (None before the first pose)
        self.record = FlightRecord()
        self.next_heartbeat_s = 0.0
        self.next_timesync_s = 0.0
        self.commands_stopped = False
        self.truth_history: deque[TruthState] = deque(maxlen=TRUTH_HISTORY)
        self.timesync = TimeSyncTracker(clock=clock.now, stats=link.radio.stats)
        self.interrupts = 0
        self._uplink_latency_s: float | None = None
        self.last_pose: MocapPose | None = None
        self._resets_seen = 0

    # --- inputs ----------------------------------------------------------------------------------
    def absorb(self, now_s: float) -> None:
        inbox = self.link.take()
        for rx in inbox.downlink:
            msg = rx.message
            self.health.last_downlink_s = now_s
            if isinstance(msg, ImuSample):
                self.estimator.add_imu(msg)
            elif isinstance(msg, Heartbeat):
                self.health.last_heartbeat = msg
                self.health.last_heartbeat_s = now_s
            elif isinstance(msg, TimeSync):
                self._timesync_reply(msg, now_s)
            elif isinstance(msg, BatteryStatus):
                self._status(msg)
                self.health.last_status_s = now_s
            elif isinstance(msg, RadioStatus):
                self.health.last_radio = msg
            elif isinstance(msg, MotorOutputs):
                self.motor_duty = msg.duty
                self.log.motors(now_s, msg.time_s, msg.duty)
        for rx in inbox.mocap:
            if isinstance(rx.message, MocapPose):
                pose = rx.message
                self.last_pose = pose
                self.estimator.add_mocap(pose)
                self.health.mocap_times.append(now_s)
                if self.extpose and not self.commands_stopped:
                    self.link.send(ExternalPose(pose.time_s, pose.position_enu_m, pose.attitude_wxyz))
        # The filter changes only here: one estimate serves the view, the controller and the log row.
        self.estimate = self.estimator.estimate() if self.estimator.initialised else None

    def absorb_truth(self) -> None:
        """The tick's simulator truth (for the log and the grading only), taken after the tick's commands
        are sent: nothing before the send reads it, so its decoding overlaps the emulator's next step."""
        for rx in self.link.take_truth():
            if isinstance(rx.message, TruthState):
                self.truth = rx.message
                self.truth_history.append(rx.message)
            elif isinstance(rx.message, CrashReport) and self.record.crash is None:
                self.record.crash = rx.message

    def after_release(self, now_s: float, step, out) -> None:
        """The tick's bookkeeping once its commands are sent: the command history of the latency
        compensator (read from the next tick on), truth, the log row, the tlog records."""
        if out is not None and self.compensator is not None:
            self.compensator.record(now_s, out.thrust_n, out.moment_flu_nm, out.attitude_des_wxyz)
        self.absorb_truth()
        self.write_row(now_s, step, out)
        self.link.flush_logs()

    def _status(self, msg: BatteryStatus) -> None:
        previous = self.health.uplink_received
        step = (msg.uplink_received - previous) % 65536  # the wire counter wraps at 2^16
        if step < 32768:  # newer (a reordered older report would look like a huge step)
            self.health.uplink_received = previous + step
        self.health.last_status = msg

    def _timesync_reply(self, msg: TimeSync, now_s: float) -> None:  # noqa: ARG002
        if msg.remote_ns == 0:
            return  # a request, not a reply: the vehicle does not ask us
        sample = self.timesync.on_reply(msg)
        if sample is None:
            return
        self.health.rtt_s.append(sample.rtt_s)
        recent = self.health.rtt_s[-COMPENSATION_RTT_SAMPLES:]
        self._uplink_latency_s = float(np.median(recent)) / 2.0  # per reply (2 Hz), not per tick
        self.health.offset_s = -sample.offset_s  # the tracker gives local - remote; we keep vehicle - ours
        self.health.have_offset = True

    def view(self, now_s: float) -> VehicleView | None:
        hb = self.health.last_heartbeat
        if hb is None or not self.estimator.initialised:
            return None
        if self.compensator is not None and not self.health.rtt_s:
            return None  # compensating needs a latency estimate: stay connecting until TIMESYNC answers
        est = self.estimate
        downlink_age = now_s - (self.health.last_downlink_s or now_s)
        # "Unhealthy" for the mission means the filter itself is in trouble (its position uncertainty is
        # beyond its limit); a mocap blackout alone is handled by the mocap-age thresholds.
        sx, sy, sz = est.std_dev[POSITION].tolist()  # floats: numpy's max on 3 numbers costs ~6 us per tick
        limit = self.estimator.params.max_position_sigma_m
        filter_ok = sx <= limit and sy <= limit and sz <= limit  # a NaN sigma is not ok (as with max)
        return VehicleView(
            t_s=now_s, position_enu_m=np.asarray(est.position_enu_m, float),
            velocity_enu_mps=np.asarray(est.velocity_enu_mps, float), armed=hb.armed,
            crashed=hb.mode == VehicleMode.CRASHED, mocap_age_s=self.mocap_age(now_s, est),
            estimator_healthy=filter_ok, downlink_age_s=downlink_age, landing=hb.mode == VehicleMode.LANDING,
            heartbeat_age_s=now_s - self.health.last_heartbeat_s,
        )

    def mocap_age(self, now_s: float, est) -> float:
        """Seconds since the sample time of the newest accepted mocap frame, on the vehicle clock."""
        last_mocap_s = est.time_s - est.health.mocap_age_s
        return max(0.0, now_s + self.health.offset_s - last_mocap_s)

    # --- outputs ---------------------------------------------------------------------------------
    def send_housekeeping(self, now_s: float) -> None:
        if now_s >= self.next_heartbeat_s:
            self.link.send(Heartbeat(armed=False, is_ground_station=True))
            self.next_heartbeat_s = now_s + self.p.heartbeat_period_s
        if now_s >= self.next_timesync_s:
            self.link.send(self.timesync.request())
            # ask more often until the first reply: with compensation on, the mission waits for it
            period = self.p.timesync_period_s if self.health.rtt_s else self.p.timesync_period_s / 5
            self.next_timesync_s = now_s + period
        request = self._motor_request
        if (request is not None and self.motor_duty is None and now_s >= self._next_motor_request_s
                and self.health.last_heartbeat is not None and not getattr(self.link, "speaks_crtp", False)):
            self.link.send(MotorOutputsRequest(request[0]))
            self._next_motor_request_s = now_s + request[1]

    def uplink_latency_s(self) -> float | None:
        """One-way uplink latency: half the median of the recent TIMESYNC round trips (None before any)."""
        return self._uplink_latency_s

    def control(self, now_s: float, step):
        """Send this tick's setpoint; the ground station's controller output (None in position mode, where
        the vehicle's onboard position controller flies the reference itself)."""
        if self.mode == "position":
            ref = step.reference
            self.link.send(PositionTarget(now_s, tuple(float(v) for v in ref.position_m),
                                          tuple(float(v) for v in ref.velocity_mps), float(ref.yaw_rad)))
            return None
        est = self.estimate
        latency = self.uplink_latency_s() if self.compensator is not None else None
        if latency is not None and step.phase in COMPENSATED_PHASES:
            state = self.compensator.predict(est, now_s, self.health.offset_s, latency)
            # the tick's own reference (step.reference) is then read only by the log row, after the ack
            reference = self.mission.reference_at(now_s + latency) or step.reference
        else:
            state = ControllerState(position_enu_m=est.position_enu_m, velocity_enu_mps=est.velocity_enu_mps,
                                    attitude_wxyz=est.attitude_wxyz, rate_flu_radps=est.rate_flu_radps)
            reference = step.reference
        out = self.controller.update(state, reference, now_s)
        if self.mode == "moments":
            self.link.send(ThrustMoment(now_s, out.thrust_n, tuple(out.moment_flu_nm)))
        else:
            self.link.send(AttitudeTarget(now_s, out.thrust_n, tuple(out.attitude_des_wxyz),
                                          tuple(out.rate_des_flu_radps)))
        return out

    # --- the loop --------------------------------------------------------------------------------
    def run(self) -> None:
        previous = signal.getsignal(signal.SIGINT)
        signal.signal(signal.SIGINT, self._interrupt)
        # No full garbage collection inside the loop: a full collection walks the whole heap, and one inside a 500 Hz
        # realtime flight took 44 ms (22 ticks skipped at once). So one before the first tick, and none during
        # it: CPython starts one when the objects promoted to its oldest generation since the last one reach a
        # quarter of it, and the loop's ring buffers (sent commands, truth, time-sync samples, ~1 s each) promote
        # a few per tick, so a lockstep moments circle still ran one (29 ms, at tick 10727) once the start-up
        # heap was smaller. Young collections still run; they find the loop's cycles while they are young.
        # gc.freeze() would also spare the walk, but with it every young collection took 5.8 ms instead of 0.13.
        gc.collect()
        thresholds = gc.get_threshold()
        gc.set_threshold(thresholds[0], thresholds[1], NO_AUTOMATIC_FULL_COLLECTION)
        try:
            self.clock.start()
            while not self.mission.finished:
                self.tick()
            self.listen_for_final_report()
        finally:
            gc.set_threshold(*thresholds)
            signal.signal(signal.SIGINT, previous)
            self.clock.leave()

    def listen_for_final_report(self) -> None:
        """Keep receiving and logging (phase "done", no reference, no command) without sending, until the
        vehicle's status report covers every uplink frame we sent (a report received at r covers what
        was sent before r minus the round trip) or final_report_wait_s has passed; after a failsafe at
        least failsafe_observe_s, so the log shows what the vehicle's own watchdog did."""
        start = self.clock.now()
        observe_until = start + (self.p.failsafe_observe_s if self.mission.result == "failsafe" else 0.0)
        give_up = max(observe_until, start + self.p.final_report_wait_s)
        done = MissionStep(Phase.DONE, None)
        while True:
            now = self.clock.wait()
            self.absorb(now)
            self.clock.release(now + self.period_s)
            self.after_release(now, done, None)
            self.clock.done()
            if now >= give_up or (now >= observe_until and self._status_covers_all_sent()):
                return

    def _status_covers_all_sent(self) -> bool:
        if self.health.last_status_s is None or self.link.last_sent_s is None:
            return False
        round_trip = max(self.health.rtt_s[-COMPENSATION_RTT_SAMPLES:], default=0.0)
        return self.health.last_status_s - round_trip > self.link.last_sent_s

    def _interrupt(self, signum, frame) -> None:  # noqa: ARG002
        self.interrupts += 1
        if self.interrupts == 1:
            log.warning("interrupted: landing and disarming (Ctrl-C again to disarm at once)")
            self.mission.request_abort()
        else:
            self.mission.result = "aborted"
            self.mission.phase = Phase.DISARM

    def tick(self) -> None:
        now = self.clock.wait()
        self.absorb(now)
        self.send_housekeeping(now)
        view = self.view(now)
        step = self.mission.update(now, view)
        if self.mission.resets != self._resets_seen and self.last_pose is not None:
            # the vehicle was put back where it started: restart the filter there, not across the jump
            self._resets_seen = self.mission.resets
            self.estimator.initialise(self.last_pose)
            self.estimate = self.estimator.estimate()
        out = None
        if step.command is not None:
            self.link.send(VehicleCommand(now, step.command))
        if step.has_reference and view is not None and step.phase != Phase.DONE:
            out = self.control(now, step)
        # Everything the vehicle needs from this tick is sent: release the lockstep before the
        # bookkeeping, which changes nothing that is sent (the log is the same either way).
        self.clock.release(now + self.period_s)
        self.after_release(now, step, out)
        self.check_health(now)
        self.clock.done()

    def write_row(self, now: float, step, out) -> None:
        est = self.estimate
        truth = self.truth
        truth_vals = None
        if truth is not None:
            truth_vals = (*truth.position_enu_m, *truth.velocity_enu_mps, *truth.attitude_wxyz)
        # numpy vectors as Python floats, each in one tolist(): unpacking makes a numpy scalar per value, and
        # the log formats floats faster (a row of floats 11 us, of these 14; unpacking 5 us, tolist 1.6: timeit)
        est_vals = sigma = None
        if est is not None:
            est_vals = (*est.position_enu_m.tolist(), *est.velocity_enu_mps.tolist(), *est.attitude_wxyz.tolist())
            sigma = tuple(est.std_dev[:9].tolist())
        ref = None
        if step.reference is not None:
            ref = (*step.reference.position_m.tolist(), *step.reference.velocity_mps.tolist())
        moment = attitude = None
        if out is not None:
            moment = (out.thrust_n, *out.moment_flu_nm)
            attitude = tuple(out.attitude_des_wxyz)
        stats = self.link.radio.stats  # raw counters: a snapshot computes percentiles, too slow per tick
        rtt = self.health.rtt_s[-1] * 1e3 if self.health.rtt_s else None
        # wall-clock tick time only in realtime: a lockstep log must depend on the seed alone
        realtime = self.clock.kind == "realtime" and self.clock.timer.work_s
        tick_ms = self.clock.timer.work_s[-1] * 1e3 if realtime else None
        view_age = None if est is None else self.mocap_age(now, est)
        status = self.health.last_status
        battery_v = None if status is None or math.isnan(status.voltage_v) else status.voltage_v
        self.log.row(now, step.phase.value, truth_vals, est_vals, sigma, ref, moment, attitude,
                     None if out is None else bool(out.saturated), view_age,
                     None if est is None else est.healthy, stats.tx_frames,
                     stats.rx_frames, stats.sequences.lost, rtt, tick_ms,
                     None if est is None else est.time_s, None if truth is None else truth.time_s,
                     battery_v)
        if self.observers:
            self._observe(now, step, est, truth, sigma, ref, out, status, battery_v, view_age, rtt, stats)
        record = self.record  # tuples, stacked into arrays once at the end (session.grade)
        record.t.append(now)
        record.phase.append(step.phase.value)
        record.ref.append(ref and ref[:3])
        record.est.append(est_vals and est_vals[:3])
        record.est_vel.append(est_vals and est_vals[3:6])
        record.est_sigma.append(sigma and sigma[:6])
        record.truth.append(truth_vals and truth_vals[:3])
        record.truth_vel.append(truth_vals and truth_vals[3:6])
        record.truth_att.append(truth_vals and truth_vals[6:10])
        at_est = None if est is None else self.truth_at(est.time_s)
        record.truth_at_est.append(None if at_est is None else at_est[0])
        record.truth_vel_at_est.append(None if at_est is None else at_est[1])

    def _observe(self, now, step, est, truth, sigma, ref, out, status, battery_v, mocap_age, rtt, stats) -> None:
        due = [entry for entry in self.observers if now >= entry[1]]
        if not due:
            return
        heartbeat = self.health.last_heartbeat
        frame = TickFrame(
            t_s=now, phase=step.phase.value,
            truth_position_enu_m=None if truth is None else tuple(truth.position_enu_m),
            truth_attitude_wxyz=None if truth is None else tuple(truth.attitude_wxyz),
            est_position_enu_m=None if est is None else tuple(est.position_enu_m.tolist()),
            est_velocity_enu_mps=None if est is None else tuple(est.velocity_enu_mps.tolist()),
            est_attitude_wxyz=None if est is None else tuple(est.attitude_wxyz.tolist()),
            est_sigma_position_m=None if sigma is None else sigma[:3],
            ref_position_enu_m=None if ref is None else ref[:3],
            cmd_thrust_n=None if out is None else float(out.thrust_n),
            cmd_moment_flu_nm=None if out is None else tuple(float(m) for m in out.moment_flu_nm),
            cmd_attitude_wxyz=None if out is None else tuple(float(q) for q in out.attitude_des_wxyz),
            battery_v=battery_v, mocap_age_s=mocap_age, rtt_ms=rtt, uplink_sent=stats.tx_frames,
            downlink_received=stats.rx_frames, downlink_lost=stats.sequences.lost,
            est_healthy=None if est is None else bool(est.healthy),
            armed=None if heartbeat is None else bool(heartbeat.armed),
            battery_remaining_pct=None if status is None else status.remaining_pct,
            est_rate_flu_radps=None if est is None else tuple(est.rate_flu_radps.tolist()),
            motor_duty=self.motor_duty)
        for entry in due:
            entry[0].observe(frame)
            entry[1] = now + entry[0].period_s

    def truth_at(self, t_s: float):
        """(position, velocity) of the truth at time t_s, linearly interpolated, as tuples; None outside
        the history. Searched from the newest sample: the estimate lags the newest truth by a few frames."""
        history = self.truth_history
        if not history or not history[0].time_s <= t_s <= history[-1].time_s:
            return None
        older = history[-1]  # "older" in time order is the later sample; walk back from the newest
        for i in range(len(history) - 2, -1, -1):
            newer = history[i]
            if newer.time_s <= t_s:
                span = older.time_s - newer.time_s
                f = 0.0 if span <= 0 else (t_s - newer.time_s) / span
                return (_lerp(newer.position_enu_m, older.position_enu_m, f),
                        _lerp(newer.velocity_enu_mps, older.velocity_enu_mps, f))
            older = newer
        only = history[0]  # a single sample, at exactly t_s
        return tuple(map(float, only.position_enu_m)), tuple(map(float, only.velocity_enu_mps))

    def check_health(self, now: float) -> None:
        """Warn once when mocap rate, latency or delivery leave sane bounds."""
        times = self.health.mocap_times
        while times and times[0] < now - 1.0:
            times.pop(0)
        if now > 2.0:
            rate = len(times)
            if not self.p.mocap_rate_min_hz <= rate <= self.p.mocap_rate_max_hz:
                self._warn_once("mocap", f"mocap rate {rate} Hz outside {self.p.mocap_rate_min_hz:.0f}-"
                                         f"{self.p.mocap_rate_max_hz:.0f} Hz")
        if self.health.rtt_s and self.health.rtt_s[-1] * 1e3 / 2 > self.p.latency_max_ms:
            self._warn_once("latency", f"one-way latency {self.health.rtt_s[-1] * 500:.1f} ms above "
                                       f"{self.p.latency_max_ms:.0f} ms")
        stats = self.link.radio.stats
        total = stats.rx_frames + stats.sequences.lost
        if total > 500 and stats.rx_frames / total < self.p.delivery_ratio_min:
            self._warn_once("delivery", f"downlink delivery {stats.rx_frames / total:.3f} below "
                                        f"{self.p.delivery_ratio_min:.2f}")

    def _warn_once(self, key: str, message: str) -> None:
        if key not in self.health.warned:
            self.health.warned.add(key)
            log.warning("link health: %s", message)


def _lerp(a, b, f: float) -> tuple[float, float, float]:
    """a + f (b - a) for 3-vectors, as floats."""
    a0, a1, a2 = a
    b0, b1, b2 = b
    return (float(a0 + f * (b0 - a0)), float(a1 + f * (b1 - a1)), float(a2 + f * (b2 - a2)))
