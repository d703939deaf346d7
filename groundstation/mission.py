"""The mission: connect, arm, take off, settle, track, hover, land, disarm - and the failsafes.

Takes in: the time (s), the state estimate and its health, what the vehicle reports (heartbeat,
downlink age), the trajectory to track, the world (for the landing spot) and the vehicle's collision
radius, and mission parameters (params/mission.toml).
Gives out: each tick, the phase, the reference to fly (a FlatOutput) or None (send nothing), and a
vehicle command to send (arm, disarm, land, reboot) when one is due; at the end, the mission's result
(`result`: reached_goal, timeout, failsafe, aborted, crashed) kept apart from what happened after it
(`landing`: landed, crashed, or not attempted, and where).

Landing: from where it hovers, the vehicle flies to the nearest clear spot (groundstation.landing: straight
down when the footprint is clear, else the nearest clear floor or pad top) and descends there; with no
clear spot within the search radius it hovers `no_spot_hover_s`, says so, then asks the vehicle's own
LAND. A crash while landing after the goal leaves the mission's result as it was.
Reset: a vehicle that already reports CRASHED when the session starts ends the session at once (result
"crashed", with the reason), unless the session may reset it (`allow_reset`): then it sends REBOOT until
the vehicle reports it is no longer crashed, and flies from where the vehicle now stands.

update() runs every control tick (500 Hz): what does not change between ticks (the phase handlers, the
phase sets, the goal as floats) is built once, and distances are taken on floats (math.dist), not numpy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

import numpy as np

from groundstation.landing import LandingSettings, LandingSpot, find_landing_spot
from groundstation.trajectories.basic import Chain, Hover, Line
from groundstation.trajectories.flat import at_rest
from groundstation.trajectory import FlatOutput, Trajectory
from link.messages import CommandKind
from model.config import Params, resolve
from model.world import World

COMMAND_REPEAT_S = 0.25  # arm/land commands are repeated this often until the vehicle reports them done


class Phase(Enum):
    CONNECT = "connect"
    ARM = "arm"
    TAKEOFF = "takeoff"
    SETTLE = "settle"
    TRACK = "track"
    HOVER = "hover"
    LAND = "land"
    DISARM = "disarm"
    DONE = "done"
    FAILSAFE_HOLD = "failsafe_hold"
    FAILSAFE_DESCENT = "failsafe_descent"
    RESET = "reset"  # asking a crashed vehicle to reboot before the flight
    VEHICLE_LAND = "vehicle_land"  # no clear landing spot: the vehicle's own LAND


# Phase sets the state machine tests every tick (tuples: `in` compares members by identity, no hashing).
_NO_FAILSAFE_PHASES = (Phase.DONE, Phase.DISARM, Phase.CONNECT, Phase.RESET)  # nothing airborne to protect
# on the ground, or the vehicle lands itself
_NO_MOCAP_FAILSAFE_PHASES = (Phase.ARM, Phase.FAILSAFE_DESCENT, Phase.VEHICLE_LAND)
_LANDING_PHASES = (Phase.LAND, Phase.VEHICLE_LAND, Phase.DISARM)  # after the mission's result is decided
_ABORTABLE_PHASES = (Phase.ARM, Phase.TAKEOFF, Phase.SETTLE, Phase.TRACK, Phase.HOVER)


@dataclass(frozen=True)
class MissionParams:
    connect_timeout_s: float
    arm_timeout_s: float
    reboot_repeat_s: float
    reset_timeout_s: float
    settle_s: float
    end_hover_s: float
    max_end_hover_s: float
    heartbeat_period_s: float
    timesync_period_s: float
    land_timeout_s: float
    final_report_wait_s: float
    failsafe_observe_s: float
    takeoff_height_m: float
    takeoff_speed_mps: float
    landing_speed_mps: float
    touchdown_height_m: float
    goal_position_tolerance_m: float
    goal_speed_tolerance_mps: float
    mocap_hold_after_s: float
    mocap_descend_after_s: float
    downlink_silent_after_s: float
    heartbeat_lost_after_s: float
    user_code_hold_s: float
    mocap_rate_min_hz: float
    mocap_rate_max_hz: float
    delivery_ratio_min: float
    latency_max_ms: float
    landing: LandingSettings
    landing_move_speed_mps: float
    no_spot_hover_s: float


def load_mission_params(name_or_path: str = "mission") -> MissionParams:
    p = Params.load(resolve(name_or_path, "groundstation", "params", "mission parameters"))
    timing, motion, goal = p.table("timing"), p.table("motion"), p.table("goal")
    failsafe, health, landing = p.table("failsafe"), p.table("link_health"), p.table("landing")
    pos = {"minimum": 0.0}
    positive = {"minimum": 1e-6}
    return MissionParams(
        **{k: timing.number(k, **pos) for k in ("connect_timeout_s", "arm_timeout_s", "reboot_repeat_s",
                                                 "reset_timeout_s", "settle_s", "end_hover_s",
                                                 "max_end_hover_s", "heartbeat_period_s", "timesync_period_s",
                                                 "land_timeout_s", "final_report_wait_s",
                                                 "failsafe_observe_s")},
        **{k: motion.number(k, **pos) for k in ("takeoff_height_m", "takeoff_speed_mps", "landing_speed_mps",
                                                 "touchdown_height_m")},
        goal_position_tolerance_m=goal.number("position_tolerance_m", **pos),
        goal_speed_tolerance_mps=goal.number("speed_tolerance_mps", **pos),
        **{k: failsafe.number(k, **pos) for k in ("mocap_hold_after_s", "mocap_descend_after_s",
                                                   "downlink_silent_after_s", "heartbeat_lost_after_s",
                                                   "user_code_hold_s")},
        **{k: health.number(k, **pos) for k in ("mocap_rate_min_hz", "mocap_rate_max_hz", "delivery_ratio_min",
                                                 "latency_max_ms")},
        landing=LandingSettings(**{k: landing.number(k, **positive) for k in (
            "search_radius_m", "search_step_m", "safety_m", "path_check_step_m")}),
        landing_move_speed_mps=landing.number("move_speed_mps", **positive),
        no_spot_hover_s=landing.number("no_spot_hover_s", **pos),
    )


@dataclass
class VehicleView:
    """What the ground station knows of the vehicle this tick (never simulator truth)."""

    t_s: float
    position_enu_m: np.ndarray
    velocity_enu_mps: np.ndarray
    armed: bool
    crashed: bool
    mocap_age_s: float
    estimator_healthy: bool
    downlink_age_s: float
    landing: bool = False  # the vehicle's own LAND is under way (heartbeat mode LANDING)
    heartbeat_age_s: float = 0.0  # since the newest vehicle HEARTBEAT arrived (our clock)


@dataclass
class LandingOutcome:
    """What happened after the mission's result was decided."""

    result: str = "not_attempted"  # landed | crashed | not_attempted (the session ended airborne or earlier)
    spot_enu_m: list[float] | None = None  # where it descended to
    moved_m: float | None = None  # horizontal move from the hover point to the spot
    on_block: int | None = None  # index of the block it landed on (a pad); None: the floor
    note: str | None = None  # e.g. no clear spot within the search radius


class MissionStep:
    """One tick's decision: the phase, the reference to fly (None: send no setpoint this tick) and a
    vehicle command (None: none).

    A reference on the phase's trajectory segment (`on_segment`) is sampled when first read, then kept:
    with latency compensation the controller flies the segment at a later time (Mission.reference_at), so
    this tick's own sample is read only by the log row, after the tick's commands are sent, off the
    lockstep's critical path. The segment and its time are fixed at construction: the value is the same
    whenever it is read."""

    __slots__ = ("phase", "command", "_reference", "_segment", "_segment_t_s")

    def __init__(self, phase: Phase, reference: FlatOutput | None, command: CommandKind | None = None):
        self.phase = phase
        self.command = command
        self._reference = reference
        self._segment: Trajectory | None = None
        self._segment_t_s = 0.0

    @classmethod
    def on_segment(cls, phase: Phase, segment: Trajectory, t_s: float,
                   command: CommandKind | None = None) -> MissionStep:
        """A step flying `segment` at its own time t_s (seconds since the segment began); sampled at once
        unless the segment says its samples depend on time alone (Trajectory.sample_is_pure: user code's
        may keep state or raise, and then must be called in the tick's order)."""
        if not getattr(segment, "sample_is_pure", False):
            return cls(phase, segment.sample(t_s), command)
        step = cls(phase, None, command)
        step._segment, step._segment_t_s = segment, t_s
        return step

    @property
    def has_reference(self) -> bool:
        """Whether the step has a reference, without sampling it."""
        return self._segment is not None or self._reference is not None

    @property
    def reference(self) -> FlatOutput | None:
        if self._segment is not None:
            self._reference = self._segment.sample(self._segment_t_s)
            self._segment = None
        return self._reference

    def __repr__(self) -> str:
        return f"MissionStep({self.phase!r}, {self.reference!r}, {self.command!r})"


class Mission:
    """A state machine over Phase. `track` is a trajectory in world coordinates starting at its t=0."""

    def __init__(self, params: MissionParams, track: Trajectory, goal_enu_m: np.ndarray, world: World | None,
                 collision_radius_m: float, allow_reset: bool = False):
        self.p = params
        self.track = track
        self.world = world
        self.ground_height = world.support_height if world is not None else _floor_of_empty_room
        self.collision_radius_m = collision_radius_m
        self.allow_reset = allow_reset
        self.goal = np.asarray(goal_enu_m, float)
        self._goal = self.goal.tolist()
        self.arrival_s = final_arrival_time(track, self.goal, params.goal_position_tolerance_m)
        self.phase = Phase.CONNECT
        self.phase_start_s = 0.0
        self.segment: Trajectory | None = None
        self.track_start_s: float | None = None
        self.reached_goal_s: float | None = None
        self.result: str | None = None  # reached_goal | timeout | failsafe | aborted | crashed
        self.failsafe_reason: str | None = None
        self.failsafe_at: tuple[float, str] | None = None  # (time, phase) when failsafe_reason was set
        self.landing = LandingOutcome()
        self.crash_seen: tuple[float, str] | None = None  # (time, phase) when the vehicle reported CRASHED
        self.resets = 0  # vehicles this session asked to reboot (and saw come back)
        self.abort_requested = False
        self.user_code_fault: str | None = None  # the one-line fault of the user's code, once it failed
        self._last_sent_s: dict[CommandKind, float] = {}  # when each repeated command last went out

    # --- helpers ---------------------------------------------------------------------------------
    def _repeated(self, kind: CommandKind, t: float, period_s: float = COMMAND_REPEAT_S) -> CommandKind | None:
        """`kind` if it was not sent in the last period_s, else None: commands are re-sent until the vehicle
        reports them done, because the uplink may lose them."""
        if t - self._last_sent_s.get(kind, -math.inf) < period_s:
            return None
        self._last_sent_s[kind] = t
        return kind

    def _fail(self, t: float, result: str, reason: str) -> None:
        """End the mission's result with a reason, remembering when and in which phase."""
        self.result = result
        self.failsafe_reason = reason
        self.failsafe_at = (t, self.phase.value)

    def _enter(self, phase: Phase, t: float, segment: Trajectory | None = None) -> None:
        self.phase = phase
        self.phase_start_s = t
        self.segment = segment

    def _on_segment(self, t: float) -> MissionStep:
        """This tick's step: the current phase, flying the current segment at t (sampled when read)."""
        return MissionStep.on_segment(self.phase, self.segment, t - self.phase_start_s)

    def _hold(self, position: np.ndarray, t: float) -> Trajectory:
        return Hover(np.asarray(position, float), duration_s=1e9)

    def _begin_landing(self, t: float, view: VehicleView) -> None:
        """Enter LAND towards the nearest clear spot (groundstation.landing), or hover and then hand the
        landing to the vehicle when there is none."""
        here = np.asarray(view.position_enu_m, float)
        spot = self._landing_spot(here)
        if spot is None:
            self.landing.note = (f"no clear landing spot within {self.p.landing.search_radius_m:g} m: hovered "
                                 f"{self.p.no_spot_hover_s:g} s, then the vehicle's own LAND")
            self._enter(Phase.LAND, t, Hover(here, self.p.no_spot_hover_s))
            return
        self.landing.spot_enu_m = spot.touchdown_m.tolist()
        self.landing.moved_m = spot.moved_m
        self.landing.on_block = spot.on_pad if spot.on_pad >= 0 else None
        move = Line(here, spot.above_m, speed_mps=self.p.landing_move_speed_mps)
        descent = Line(spot.above_m, spot.touchdown_m, speed_mps=self.p.landing_speed_mps)
        hold = (Hover(here, self.p.user_code_hold_s),) if self.user_code_fault and self.p.user_code_hold_s > 0 else ()
        self._enter(Phase.LAND, t, Chain(*hold, move, descent))

    def _landing_spot(self, here: np.ndarray) -> LandingSpot | None:
        if self.world is None:  # an empty room: straight down to the floor
            floor = here.copy()
            floor[2] = self.ground_height(here)
            return LandingSpot(here.copy(), floor, -1, 0.0)
        return find_landing_spot(self.world, here, self.collision_radius_m, self.p.landing)

    def reference_at(self, t: float) -> FlatOutput | None:
        """The current phase's reference at another time t (latency compensation looks ahead)."""
        if self.segment is None:
            return None
        return self.segment.sample(t - self.phase_start_s)

    @property
    def finished(self) -> bool:
        return self.phase == Phase.DONE

    def request_abort(self) -> None:
        """Ctrl-C: land and disarm first."""
        self.abort_requested = True

    def user_code_failed(self, line: str) -> None:
        """The user's controller or trajectory failed (`line` says how): hold, then land, as a failsafe."""
        if self.user_code_fault is None:
            self.user_code_fault = line
            self.abort_requested = True

    # --- the state machine -----------------------------------------------------------------------
    def update(self, t: float, view: VehicleView | None) -> MissionStep:
        if self.phase == Phase.DONE:
            return MissionStep(Phase.DONE, None)
        if self.phase == Phase.CONNECT:
            return self._connect(t, view)
        if self.phase == Phase.RESET:
            return self._reset(t, view)
        if view.crashed:
            return self._crashed(t)
        if view.heartbeat_age_s > self.p.heartbeat_lost_after_s:
            return self._disconnected(t, view)
        failsafe = self._check_failsafes(t, view)
        if failsafe is not None:
            return failsafe
        if self.abort_requested and self.phase in _ABORTABLE_PHASES:
            if self.user_code_fault is not None and self.result is None:
                self._fail(t, "failsafe", self.user_code_fault)
            self.result = self.result or "aborted"
            if self.phase == Phase.ARM or not view.armed:
                self._enter(Phase.DISARM, t)
            else:
                self._begin_landing(t, view)
        return self._HANDLERS[self.phase](self, t, view)

    def _disconnected(self, t: float, view: VehicleView) -> MissionStep:
        """No vehicle HEARTBEAT for heartbeat_lost_after_s (MAVLink's disconnection): whatever the phase, the
        ground station no longer knows whether the vehicle is armed, so it stops commanding and ends; the
        vehicle's own watchdog takes over. After the result (landing, disarming) the landing is unconfirmed."""
        reason = f"no heartbeat from the vehicle for {view.heartbeat_age_s:.2f} s"
        if self.result is None:
            self._fail(t, "failsafe", reason)
        else:
            self.landing.note = self.landing.note or f"unconfirmed: {reason}"
        self._enter(Phase.DONE, t)
        return MissionStep(Phase.DONE, None)

    def _crashed(self, t: float) -> MissionStep:
        """The vehicle reports CRASHED: after the goal (while landing) it is the landing's outcome, else the
        mission's."""
        self.crash_seen = (t, self.phase.value)
        if self.phase in _LANDING_PHASES and self.result is not None:
            self.landing.result = "crashed"
        else:
            self.result = "crashed"
        self._enter(Phase.DONE, t)
        return MissionStep(Phase.DONE, None)

    def _connect(self, t: float, view: VehicleView | None) -> MissionStep:
        if view is not None and view.crashed:
            if not self.allow_reset:
                self._fail(t, "crashed", "the vehicle already reports CRASHED at the start of this session; "
                                         "restart the emulator, or let this ground station reset it (--reset)")
                self._enter(Phase.DONE, t)
                return MissionStep(Phase.DONE, None)
            self._enter(Phase.RESET, t)
            return self._reset(t, view)
        if view is not None:
            self._enter(Phase.ARM, t)
            return self._arm(t, view)
        if t > self.p.connect_timeout_s:
            self._fail(t, "aborted", "no heartbeat from the vehicle")
            self._enter(Phase.DONE, t)
        return MissionStep(self.phase, None)

    def _reset(self, t: float, view: VehicleView) -> MissionStep:
        """Send REBOOT until the vehicle no longer reports CRASHED, then arm as usual."""
        if not view.crashed:
            self.resets += 1
            self._enter(Phase.ARM, t)
            return self._arm(t, view)
        if t - self.phase_start_s > self.p.reset_timeout_s:
            self._fail(t, "crashed", "the crashed vehicle did not come back after REBOOT")
            self._enter(Phase.DONE, t)
            return MissionStep(Phase.DONE, None)
        return MissionStep(self.phase, None, self._repeated(CommandKind.REBOOT, t, self.p.reboot_repeat_s))

    def _arm(self, t: float, view: VehicleView) -> MissionStep:
        hold = at_rest(view.position_enu_m)
        if view.armed:
            start = self.track.sample(0.0).position_m
            if np.linalg.norm(view.position_enu_m - start) > self.p.goal_position_tolerance_m:
                distance = np.linalg.norm(start - view.position_enu_m)
                speed = self.p.takeoff_speed_mps
                self._enter(Phase.TAKEOFF, t, Line(view.position_enu_m, start, speed_mps=speed)
                            if distance > 1e-6 else Hover(start, 0.0))
                return self._on_segment(t)
            self._enter(Phase.SETTLE, t, self._hold(start, t))
            return self._on_segment(t)
        if t - self.phase_start_s > self.p.arm_timeout_s:
            self._fail(t, "failsafe", "vehicle did not arm")
            self._enter(Phase.DONE, t)
            return MissionStep(self.phase, None)
        return MissionStep(self.phase, hold, self._repeated(CommandKind.ARM, t))

    def _takeoff(self, t: float, view: VehicleView) -> MissionStep:
        if t - self.phase_start_s >= self.segment.duration_s:
            self._enter(Phase.SETTLE, t, self._hold(self.track.sample(0.0).position_m, t))
        return self._on_segment(t)

    def _settle(self, t: float, view: VehicleView) -> MissionStep:
        if t - self.phase_start_s >= self.p.settle_s:
            self._enter(Phase.TRACK, t, self.track)
            self.track_start_s = t
        return self._on_segment(t)

    def _track(self, t: float, view: VehicleView) -> MissionStep:
        self._note_goal(t, view)
        if t - self.phase_start_s >= self.track.duration_s:
            self._enter(Phase.HOVER, t, self._hold(self.track.sample(self.track.duration_s).position_m, t))
        return self._on_segment(t)

    def _hover(self, t: float, view: VehicleView) -> MissionStep:
        self._note_goal(t, view)
        waited = t - self.phase_start_s
        if (self.reached_goal_s is not None and waited >= self.p.end_hover_s) or waited >= self.p.max_end_hover_s:
            if self.result is None:
                self.result = "reached_goal" if self.reached_goal_s is not None else "timeout"
            self._begin_landing(t, view)
        return self._on_segment(t)

    def _land(self, t: float, view: VehicleView) -> MissionStep:
        touched = view.position_enu_m[2] - self.ground_height(view.position_enu_m) <= self.p.touchdown_height_m
        if self.landing.note is not None and not touched:  # no clear spot: hovered, now the vehicle lands
            if t - self.phase_start_s >= self.segment.duration_s:
                self._enter(Phase.VEHICLE_LAND, t)
                return self._vehicle_land(t, view)
            return self._on_segment(t)
        # the move and descent's own duration (it grows with the distance) plus the slack land_timeout_s
        if touched or t - self.phase_start_s > self.segment.duration_s + self.p.land_timeout_s:
            if touched:
                self.landing.result = "landed"
            self._enter(Phase.DISARM, t)
            return self._disarm(t, view)
        return self._on_segment(t)

    def _disarm(self, t: float, view: VehicleView) -> MissionStep:
        if not view.armed and t > self.phase_start_s:
            self._enter(Phase.DONE, t)
            return MissionStep(self.phase, None)
        return MissionStep(self.phase, None, CommandKind.DISARM)

    def _vehicle_land(self, t: float, view: VehicleView) -> MissionStep:
        """The vehicle's own LAND (no clear spot found): it descends where it is and disarms."""
        if not view.armed:
            self.landing.result = "landed"
        return self._failsafe_descent(t, view)

    def _failsafe_descent(self, t: float, view: VehicleView) -> MissionStep:
        if not view.armed:
            self._enter(Phase.DISARM, t)
            return MissionStep(self.phase, None)
        command = None if view.landing else self._repeated(CommandKind.LAND, t)
        return MissionStep(self.phase, None, command)

    def _failsafe_hold(self, t: float, view: VehicleView) -> MissionStep:
        if view.mocap_age_s <= self.p.mocap_hold_after_s and view.estimator_healthy:
            # mocap is back: resume where the plan would be (the track clock kept running)
            resume = self._resume_phase
            self._enter(resume[0], resume[1], resume[2])
            return self._on_segment(t)
        return self._on_segment(t)

    def _note_goal(self, t: float, view: VehicleView) -> None:
        if self.reached_goal_s is not None or t - self.track_start_s < self.arrival_s:
            return
        near = math.dist(view.position_enu_m, self._goal) <= self.p.goal_position_tolerance_m
        slow = math.hypot(*view.velocity_enu_mps) <= self.p.goal_speed_tolerance_mps
        if near and slow:
            self.reached_goal_s = t

    def _check_failsafes(self, t: float, view: VehicleView) -> MissionStep | None:
        if self.phase in _NO_FAILSAFE_PHASES:
            return None
        if view.downlink_age_s > self.p.downlink_silent_after_s:
            self._fail(t, "failsafe", f"downlink silent for {view.downlink_age_s:.2f} s")
            self._enter(Phase.DONE, t)
            return MissionStep(Phase.DONE, None)
        if not view.armed or self.phase in _NO_MOCAP_FAILSAFE_PHASES:
            return None
        lost = view.mocap_age_s
        # Mocap that keeps arriving but always too old (a saturated radio delays the IMU the filter runs on)
        # never ages past the descent threshold: a hold counts as mocap lost since it began, so it cannot last.
        stale = lost
        if self.phase == Phase.FAILSAFE_HOLD:
            stale = max(lost, t - self.phase_start_s + self.p.mocap_hold_after_s)
        if stale > self.p.mocap_descend_after_s or not view.estimator_healthy:
            reason = "estimator unhealthy" if stale <= self.p.mocap_descend_after_s else (
                f"mocap lost for {lost:.2f} s" if lost == stale else
                f"mocap stale for {stale:.2f} s (each fix arrived {lost:.2f} s old)")
            self._fail(t, "failsafe", reason)
            # Without mocap the ground station's estimate drifts; the vehicle's own LAND descends on what it
            # measures itself until the floor holds it, then disarms.
            self._enter(Phase.FAILSAFE_DESCENT, t)
            return self._failsafe_descent(t, view)
        if lost > self.p.mocap_hold_after_s and self.phase != Phase.FAILSAFE_HOLD:
            self._resume_phase = (self.phase, self.phase_start_s, self.segment)
            self._enter(Phase.FAILSAFE_HOLD, t, self._hold(view.position_enu_m, t))
            return self._on_segment(t)
        return None

    # The handler of each phase after CONNECT (built once: a dict of bound methods per tick costs ~2 us).
    _HANDLERS = {
        Phase.ARM: _arm, Phase.TAKEOFF: _takeoff, Phase.SETTLE: _settle, Phase.TRACK: _track,
        Phase.HOVER: _hover, Phase.LAND: _land, Phase.DISARM: _disarm, Phase.FAILSAFE_HOLD: _failsafe_hold,
        Phase.FAILSAFE_DESCENT: _failsafe_descent, Phase.VEHICLE_LAND: _vehicle_land,
    }


def _floor_of_empty_room(point) -> float:
    """Without a world the floor is z = 0 (the emulator's empty room)."""
    return 0.0


def final_arrival_time(track: Trajectory, goal: np.ndarray, tolerance_m: float, step_s: float = 0.01) -> float:
    """Track time after which the reference stays within tolerance of the goal.

    A vehicle is only judged to have reached the goal from then on: a closed trajectory (a circle)
    starts at its goal, and being there at the start is not arriving.
    """
    t = track.duration_s
    while t > 0.0 and np.linalg.norm(track.sample(t - step_s).position_m - goal) <= tolerance_m:
        t -= step_s
    return max(0.0, t)
