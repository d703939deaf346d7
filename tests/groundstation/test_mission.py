"""The mission state machine and its failsafes, driven tick by tick with made-up vehicle views.

The thresholds come from groundstation/params/mission.toml (issue 4: mocap lost > 0.2 s -> hold,
> 1 s -> descend and disarm; downlink silent 0.5 s -> stop commanding).
"""

import numpy as np

from groundstation.mission import Mission, Phase, VehicleView, load_mission_params
from groundstation.trajectories.basic import Circle, Line
from link.messages import CommandKind
from model.vehicle import load_vehicle

P = load_mission_params()
VEHICLE = load_vehicle("crazyflie")
DT = 0.002


def view(t, pos, armed=True, vel=(0.0, 0.0, 0.0), mocap_age=0.0, healthy=True, downlink_age=0.0, crashed=False,
         landing=False, heartbeat_age=0.0):
    return VehicleView(t_s=t, position_enu_m=np.array(pos, float), velocity_enu_mps=np.array(vel, float),
                       armed=armed, crashed=crashed, mocap_age_s=mocap_age, estimator_healthy=healthy,
                       downlink_age_s=downlink_age, landing=landing, heartbeat_age_s=heartbeat_age)


def airborne_mission(track=None):
    track = track or Line([0, 0, 1], [1, 0, 1], speed_mps=0.5)
    m = Mission(P, track, track.sample(track.duration_s).position_m, None, VEHICLE.collision_radius_m)
    start = track.sample(0.0).position_m
    t = 0.0
    m.update(t, view(t, start, armed=False))  # connect -> arm
    t += DT
    step = m.update(t, view(t, start, armed=True))  # armed at the start point: settle
    assert step.phase == Phase.SETTLE
    return m, t


def run_until(m, t, pos_fn, phase, limit_s=60.0, **kw):
    while t < limit_s:
        t += DT
        step = m.update(t, view(t, pos_fn(t), **kw))
        if step.phase == phase:
            return step, t
    raise AssertionError(f"never reached {phase}, stuck in {m.phase}")


def test_arm_is_sent_and_repeated_until_the_vehicle_reports_armed():
    track = Line([0, 0, 1], [1, 0, 1], speed_mps=0.5)
    m = Mission(P, track, track.sample(track.duration_s).position_m, None, VEHICLE.collision_radius_m)
    assert m.update(0.0, None).phase == Phase.CONNECT  # nothing heard yet
    commands = [m.update(t, view(t, [0, 0, 0], armed=False)).command for t in np.arange(0.002, 1.0, DT)]
    arms = [c for c in commands if c == CommandKind.ARM]
    assert 2 <= len(arms) <= 1.0 / 0.25 + 1  # re-sent (the uplink may lose it), but not every tick
    step = m.update(1.0, view(1.0, [0, 0, 0], armed=True))
    assert step.phase == Phase.TAKEOFF and step.reference is not None


def test_nominal_mission_tracks_hovers_lands_and_disarms():
    m, t = airborne_mission()
    step, t = run_until(m, t, lambda t: [0, 0, 1], Phase.TRACK)
    # follow the reference exactly, then sit at the goal
    step, t = run_until(m, t, lambda t: m.track.sample(t - m.track_start_s).position_m, Phase.HOVER)
    step, t = run_until(m, t, lambda t: [1, 0, 1], Phase.LAND)
    assert m.result == "reached_goal"
    assert m.reached_goal_s is not None and m.reached_goal_s >= m.track_start_s + m.arrival_s
    # descend to the floor along the landing reference, then a disarm is commanded until disarmed
    while True:
        t += DT
        ref = m.segment.sample(t - m.phase_start_s).position_m if m.phase == Phase.LAND else np.array([1, 0, 0])
        step = m.update(t, view(t, ref))
        if step.phase == Phase.DISARM:
            break
    assert step.command == CommandKind.DISARM and step.reference is None
    t += DT
    assert m.update(t, view(t, [1, 0, 0], armed=False)).phase == Phase.DONE


def test_a_closed_trajectory_is_not_reached_at_its_start():
    circle = Circle([0, -0.5, 1], 0.5, 0.5)
    m, t = airborne_mission(circle)
    start = circle.sample(0.0).position_m
    run_until(m, t, lambda t: start, Phase.TRACK)
    # the vehicle sits at the start (= goal) while the reference flies the circle: never "reached" early
    assert m.arrival_s > 0.8 * circle.duration_s  # only the slow end of the spin-down is near the goal
    t = m.track_start_s
    while t < m.track_start_s + 0.5 * circle.duration_s:
        t += DT
        m.update(t, view(t, start))
    assert m.reached_goal_s is None


def test_mocap_loss_holds_then_descends_at_the_thresholds():
    m, t = airborne_mission()
    _, t = run_until(m, t, lambda t: [0, 0, 1], Phase.TRACK)
    lost_at = t
    hold_at = descend_at = None
    while t < lost_at + 2.0:
        t += DT
        step = m.update(t, view(t, [0.1, 0, 1], mocap_age=t - lost_at))
        if step.phase == Phase.FAILSAFE_HOLD and hold_at is None:
            hold_at = t - lost_at
            hold_ref = step.reference.position_m
        if step.phase == Phase.FAILSAFE_DESCENT:
            descend_at = t - lost_at
            break
    assert abs(hold_at - P.mocap_hold_after_s) <= 2 * DT
    np.testing.assert_allclose(hold_ref, [0.1, 0, 1])  # hold where the estimate is
    assert abs(descend_at - P.mocap_descend_after_s) <= 2 * DT
    assert m.result == "failsafe" and "mocap" in m.failsafe_reason
    # the vehicle's own LAND, no more setpoints from a drifting estimate; then disarmed -> done
    assert step.reference is None and step.command == CommandKind.LAND
    t += DT
    assert m.update(t, view(t, [0.1, 0, 0.5], mocap_age=t - lost_at, landing=True)).command is None
    t += DT
    assert m.update(t, view(t, [0.1, 0, 0], armed=False, mocap_age=t - lost_at)).phase == Phase.DISARM


def test_mocap_that_always_arrives_too_old_descends_as_if_lost_since_the_hold():
    """Fixes that keep coming but each 0.3 s old (a saturated radio: the filter runs late) never age past the
    descent threshold; the hold must still end, when mocap has been older than the hold threshold for the
    descent threshold in all: hold_after + (descend_after - hold_after) after the hold began."""
    m, t = airborne_mission()
    _, t = run_until(m, t, lambda t: [0, 0, 1], Phase.TRACK)
    stale_age = 0.3
    assert P.mocap_hold_after_s < stale_age < P.mocap_descend_after_s
    hold_at = descend_at = None
    start = t
    while t < start + 5.0:
        t += DT
        step = m.update(t, view(t, [0, 0, 1], mocap_age=stale_age))
        if step.phase == Phase.FAILSAFE_HOLD and hold_at is None:
            hold_at = t
        if step.phase == Phase.FAILSAFE_DESCENT:
            descend_at = t
            break
    assert hold_at is not None and descend_at is not None
    assert abs((descend_at - hold_at) - (P.mocap_descend_after_s - P.mocap_hold_after_s)) <= 2 * DT
    assert m.result == "failsafe" and "stale" in m.failsafe_reason


def test_no_heartbeat_for_five_periods_ends_the_flight_in_any_phase_even_disarming():
    """MAVLink's disconnection (no HEARTBEAT for heartbeat_lost_after_s) while other frames still arrive: in
    flight it is a failsafe; while disarming after the result it ends an otherwise endless wait."""
    m, t = airborne_mission()
    _, t = run_until(m, t, lambda t: [0, 0, 1], Phase.TRACK)
    silent_from = t
    while m.phase != Phase.DONE and t < silent_from + 10.0:
        t += DT
        m.update(t, view(t, [0, 0, 1], heartbeat_age=t - silent_from))
    assert abs((t - silent_from) - P.heartbeat_lost_after_s) <= 2 * DT
    assert m.result == "failsafe" and "heartbeat" in m.failsafe_reason
    m, t = airborne_mission()
    m._fail(t, "reached_goal", "")  # a decided result, then a disarm the vehicle never confirms
    m._enter(Phase.DISARM, t)
    silent_from = t
    while m.phase != Phase.DONE and t < silent_from + 10.0:
        t += DT
        assert m.update(t, view(t, [0, 0, 0], heartbeat_age=t - silent_from)).phase in (Phase.DISARM, Phase.DONE)
    assert m.phase == Phase.DONE and m.result == "reached_goal" and "heartbeat" in m.landing.note


def test_mocap_back_before_one_second_resumes_the_plan():
    m, t = airborne_mission()
    _, t = run_until(m, t, lambda t: [0, 0, 1], Phase.TRACK)
    lost_at = t
    while t < lost_at + 0.5:
        t += DT
        m.update(t, view(t, [0, 0, 1], mocap_age=t - lost_at))
    assert m.phase == Phase.FAILSAFE_HOLD
    t += DT
    assert m.update(t, view(t, [0, 0, 1], mocap_age=0.005)).phase == Phase.TRACK


def test_unhealthy_estimator_descends_and_silent_downlink_stops_commanding():
    m, t = airborne_mission()
    t += DT
    step = m.update(t, view(t, [0, 0, 1], healthy=False))
    assert step.phase == Phase.FAILSAFE_DESCENT and m.failsafe_reason == "estimator unhealthy"
    assert step.command == CommandKind.LAND

    m, t = airborne_mission()
    t += DT
    step = m.update(t, view(t, [0, 0, 1], downlink_age=P.downlink_silent_after_s + DT))
    assert step.phase == Phase.DONE and step.reference is None and step.command is None
    assert m.result == "failsafe" and "downlink" in m.failsafe_reason


def test_abort_lands_and_disarms_first():
    m, t = airborne_mission()
    _, t = run_until(m, t, lambda t: [0, 0, 1], Phase.TRACK)
    m.request_abort()
    t += DT
    step = m.update(t, view(t, [0.2, 0, 1]))
    assert step.phase == Phase.LAND and m.result == "aborted"
    assert step.reference.position_m[2] <= 1.0


def test_crash_report_ends_the_mission():
    m, t = airborne_mission()
    t += DT
    assert m.update(t, view(t, [0, 0, 1], crashed=True)).phase == Phase.DONE
    assert m.result == "crashed"


class CountingTrack:
    """A trajectory that keeps state, as user code may: it records every time it is asked for, in order.
    It does not declare sample_is_pure, so the mission must sample it during the tick that asks."""

    def __init__(self, track):
        self.track = track
        self.duration_s = track.duration_s
        self.asked: list[float] = []

    def sample(self, t_s):
        self.asked.append(t_s)
        return self.track.sample(t_s)


def test_a_pure_segment_is_sampled_when_the_reference_is_read_with_the_tick_time_it_was_asked_for():
    m, t = airborne_mission()
    step, t = run_until(m, t, lambda t: [0, 0, 1], Phase.TRACK)
    assert step.has_reference
    m.reference_at(t + 0.004)  # compensation reads a later time first; the step's value must not move
    expected = m.track.sample(t - m.track_start_s)
    later = m.update(t + DT, view(t + DT, [0, 0, 1]))  # the next tick, before the first step is read
    assert later.phase == Phase.TRACK
    for name in ("position_m", "velocity_mps", "acceleration_mps2", "jerk_mps3", "snap_mps4"):
        np.testing.assert_array_equal(getattr(step.reference, name), getattr(expected, name))
    assert step.reference is step.reference  # sampled once, then kept


def one_tick_into_tracking(track: CountingTrack):
    """A mission flying `track` taken to TRACK, then one tick more: (mission, that tick's time, its step,
    how many samples the track had been asked for before that tick)."""
    m, t = airborne_mission(track)
    _, t = run_until(m, t, lambda t: [0, 0, 1], Phase.TRACK)
    asked_before = len(track.asked)
    t += DT
    return m, t, m.update(t, view(t, [0, 0, 1])), asked_before


def test_a_segment_that_may_keep_state_is_sampled_in_the_ticks_order():
    track = CountingTrack(Line([0, 0, 1], [1, 0, 1], speed_mps=0.5))
    m, t, step, asked_before = one_tick_into_tracking(track)
    assert track.asked[asked_before:] == [t - m.track_start_s]  # asked during update, not when read
    m.reference_at(t + 0.004)
    assert track.asked[-1] == t + 0.004 - m.track_start_s
    assert step.reference.position_m[0] == track.track.sample(t - m.track_start_s).position_m[0]
    assert len(track.asked) == asked_before + 2


def test_a_chain_is_pure_only_when_all_its_segments_are():
    from groundstation.trajectories.basic import Chain, Hover

    line = Line([0, 0, 1], [1, 0, 1], speed_mps=0.5)
    assert Chain(line, Hover([1, 0, 1], 1.0)).sample_is_pure
    assert not Chain(line, CountingTrack(line)).sample_is_pure


def test_a_pure_segment_is_not_sampled_until_the_reference_is_read():
    class PureCountingTrack(CountingTrack):
        sample_is_pure = True

    track = PureCountingTrack(Line([0, 0, 1], [1, 0, 1], speed_mps=0.5))
    m, t, step, asked_before = one_tick_into_tracking(track)
    assert len(track.asked) == asked_before  # off the critical path: nothing sampled yet
    first, second = step.reference, step.reference
    assert first is second
    assert track.asked[asked_before:] == [t - m.track_start_s]
