"""The emulator in-process and its command line: bad input, the lockstep's waiting and tick arithmetic,
the radios' ledger option, datagram parsing of uplink frames, realtime pacing.

(Behaviour against a ground station over zenoh: test_emulator_zenoh.py.)
"""

from __future__ import annotations

import json
import logging
import math
import subprocess
import sys
import threading
import time

import pytest

from link.clock import NS_PER_S, ClockAck, unpack_tick
from link.keys import GROUND_STATION_SYSTEM_ID, VehicleKeys
from link.mavlink.codec import ActuatorLimits, Codec
from link.messages import CommandKind, ThrustMoment, VehicleCommand
from link.transports import open_transport
from model.errors import UserError
from model.radio import load_radio_profile
from model.vehicle import load_mocap_room, load_vehicle
from simulator.emulator import Emulator, EmulatorConfig
from simulator.firmware import load_firmware_params

VEHICLE = load_vehicle("crazyflie")
GROUND = Codec(GROUND_STATION_SYSTEM_ID, limits=ActuatorLimits.from_vehicle(VEHICLE))


def config(**changes) -> EmulatorConfig:
    base = dict(vehicle=VEHICLE, mocap_room=load_mocap_room("vicon"), radio=load_radio_profile("esb-duplex"),
                world=None, seed=3)
    base.update(changes)
    return EmulatorConfig(**base)


def run_in_thread(emulator: Emulator) -> threading.Thread:
    thread = threading.Thread(target=emulator.run, name="emulator", daemon=True)
    thread.start()
    return thread


def wait_until(condition, timeout_s: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


# --- bad input: one line, exit code 2, no traceback --------------------------------------------------

CEILING_WORLD = {"bounds": {"extents": [-2, 2, -2, 2, 0, 3]}, "blocks": [{"extents": [-1, 1, -1, 1, 1.5, 2.0]}]}


def bad_invocations(tmp_path) -> dict[str, list[str]]:
    (tmp_path / "broken.json").write_text("{")
    (tmp_path / "no_bounds.json").write_text(json.dumps({"blocks": []}))
    (tmp_path / "ceiling.json").write_text(json.dumps(CEILING_WORLD))
    (tmp_path / "radio_missing_table.toml").write_text(
        'schema_version = 1\nname = "x"\nsource = "test"\nmodel = "simple"\n')
    (tmp_path / "radio_syntax.toml").write_text("schema_version = = 1\n")
    (tmp_path / "vehicle.toml").write_text('schema_version = 1\nname = "x"\nsource = "test"\n')
    return {
        "zero vehicles": ["--vehicles", "0"],
        "vehicles not a number": ["--vehicles", "two"],
        "negative seed": ["--seed", "-1"],
        "zero physics rate": ["--physics-rate", "0"],
        "nan physics rate": ["--physics-rate", "nan"],
        "negative duration": ["--duration", "-1"],
        "unknown clock": ["--clock", "sometimes"],
        "unknown option": ["--warp-speed"],
        "bad endpoint": ["--connect", "not-an-endpoint"],
        "missing world": ["--world", str(tmp_path / "nowhere.json")],
        "broken world json": ["--world", str(tmp_path / "broken.json")],
        "world without bounds": ["--world", str(tmp_path / "no_bounds.json")],
        "start inside a block": ["--world", str(tmp_path / "ceiling.json"), "--start", "0", "0", "1.6"],
        "start below the floor": ["--start", "0", "0", "-1"],
        "unknown radio profile": ["--radio", "no-such-profile"],
        "radio file missing a table": ["--radio", str(tmp_path / "radio_missing_table.toml")],
        "radio file bad toml": ["--radio", str(tmp_path / "radio_syntax.toml")],
        "unknown vehicle": ["--vehicle-model", "no-such-vehicle"],
        "vehicle file missing fields": ["--vehicle-model", str(tmp_path / "vehicle.toml")],
        "unknown mocap room": ["--mocap-room", "no-such-room"],
        "ledger in a missing directory": ["--radio-ledger", str(tmp_path / "nowhere" / "ledger.json")],
    }


# Through a real `python -m cfstack emulator` process: one case of each kind (the others run in-process
# below, through the same `cfstack` dispatcher, to keep the suite fast on a busy machine).
SUBPROCESS_CASES = ("unknown option", "negative seed", "broken world json", "radio file missing a table")


def check_one_line_error(name: str, code: int, out: str, err: str) -> str | None:
    lines = err.strip().splitlines()
    if code != 2 or len(lines) != 1 or "Traceback" in err or out.strip():
        return f"{name}: exit {code}, stdout {out!r}, stderr {err!r}"
    if not lines[0].startswith("cfstack emulator: "):
        return f"{name}: {lines[0]!r}"
    return None


def test_bad_files_and_options_give_one_line_and_exit_code_2_from_the_process(tmp_path):
    cases = bad_invocations(tmp_path)
    procs = {name: subprocess.Popen([sys.executable, "-m", "cfstack", "emulator", "--quiet", *cases[name]],
                                    stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                    text=True)
             for name in SUBPROCESS_CASES}
    failures = []
    for name, proc in procs.items():
        try:
            out, err = proc.communicate(timeout=120)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()
            failures.append(f"{name}: still running (the bad input was accepted)")
            continue
        failures.append(check_one_line_error(name, proc.returncode, out, err))
    assert not [f for f in failures if f], "\n".join(f for f in failures if f)


def test_every_bad_file_and_option_gives_one_line_and_exit_code_2(tmp_path, capsys, monkeypatch):
    from cfstack.cli import main

    monkeypatch.setattr(logging, "basicConfig", lambda **_: None)  # keep this process's logging as it is
    failures = []
    for name, args in bad_invocations(tmp_path).items():
        try:
            code = main(["emulator", "--quiet", *args])
        except SystemExit as exit_:  # argparse's own exit would be a second line of usage
            code = exit_.code
        out, err = capsys.readouterr()
        failures.append(check_one_line_error(name, code, out, err))
    assert not [f for f in failures if f], "\n".join(f for f in failures if f)


@pytest.mark.parametrize("changes", [dict(vehicles=0), dict(vehicles=251), dict(seed=-1), dict(clock="fast"),
                                     dict(physics_rate_hz=math.inf), dict(duration_s=0.0),
                                     dict(vehicles=2, start_positions_enu_m=[(0.0, 0.0, 0.0)])])
def test_an_impossible_config_is_a_user_error(changes):
    with pytest.raises(UserError):
        Emulator(config(**changes))


# --- lockstep -----------------------------------------------------------------------------------------


def test_lockstep_without_a_ground_station_waits_and_says_so(caplog):
    emulator = Emulator(config(connection="mem:emulator-wait-1"))
    emulator.lockstep.wait_log_period_s = 0.05
    with caplog.at_level(logging.INFO, logger="cfstack.emulator"), emulator:
        thread = run_in_thread(emulator)
        time.sleep(0.4)
        emulator.stopped = True
        thread.join(5.0)
    assert not thread.is_alive()
    assert emulator.steps == 0 and emulator.tick == -1
    waiting = [r for r in caplog.records if "waiting for a ground station to join" in r.getMessage()]
    assert len(waiting) >= 2


def test_a_silent_ground_station_holds_the_clock_at_its_tick_within_the_lookahead(caplog):
    """After tick 0 the emulator may run ahead until the first firmware cycle at or after the uplink
    radio's minimum latency (nothing delivered earlier acts before that cycle), no further, and
    publishes nothing beyond tick 0 until the ack comes."""
    bus = "mem:emulator-wait-2"
    emulator = Emulator(config(connection=bus))
    emulator.lockstep.wait_log_period_s = 0.05
    keys = VehicleKeys("cfstack", 1)
    with caplog.at_level(logging.INFO, logger="cfstack.emulator"), emulator, \
            open_transport(bus, tx=keys.clock_ack, rx=keys.clock) as clock, \
            open_transport(bus, rx=keys.truth) as truth:
        thread = run_in_thread(emulator)
        clock.send(ClockAck(-1, 0, 0).pack())
        assert wait_until(lambda: emulator.tick == 0)
        time.sleep(0.3)
        ticks = [unpack_tick(data) for data in clock.receive(0.1)]
        published = truth.receive(0.1)
        emulator.stopped = True
        thread.join(5.0)
    assert [t.tick for t in ticks] == [0] and ticks[0].time_ns == 0
    assert published == [] and ticks[0].truth_published == 0
    cycle_s = 1.0 / load_firmware_params().commander_rate_hz
    limit = math.ceil(load_radio_profile("esb-duplex").min_latency_s / cycle_s) * cycle_s
    assert 0 < emulator.steps and (emulator.steps - 1) * emulator.dt_s < limit  # the last step started before it
    assert emulator.steps * emulator.dt_s == pytest.approx(limit)  # ... and the steps reached it
    assert any("to finish tick 0" in r.getMessage() for r in caplog.records)


@pytest.mark.parametrize("rate_hz", [1000.0, 300.0])
def test_the_lookahead_horizon_is_the_first_firmware_cycle_after_the_minimum_latency(rate_hz):
    """At 1 kHz every 500 Hz firmware cycle is a step start, so a frame delivered at L acts at the next
    cycle; at 300 Hz the cycles fall between steps, so only L itself is a safe bound."""
    emulator = Emulator(config(physics_rate_hz=rate_hz))
    latency_s = load_radio_profile("esb-duplex").min_latency_s
    cycle_s = 1.0 / load_firmware_params().commander_rate_hz
    expected = math.ceil(latency_s / cycle_s) * cycle_s if rate_hz == 1000.0 else latency_s
    assert latency_s < expected or rate_hz == 300.0
    assert emulator.lockstep.lookahead_horizon_s() == pytest.approx(expected)
    assert Emulator(config(physics_rate_hz=rate_hz, lookahead=False)).lockstep.lookahead_horizon_s() == 0.0


def test_no_lookahead_when_disabled_or_when_the_radio_has_no_latency():
    assert Emulator(config(lookahead=False)).lockstep.lookahead_horizon_s() == 0.0
    assert Emulator(config(radio=load_radio_profile("ideal"))).lockstep.lookahead_horizon_s() == 0.0
    lab = load_radio_profile("lab")
    cycle_s = 1.0 / load_firmware_params().commander_rate_hz
    expected = math.ceil(lab.min_latency_s / cycle_s) * cycle_s  # the first firmware cycle at or after L
    assert lab.min_latency_s <= Emulator(config(radio=lab)).lockstep.lookahead_horizon_s() == pytest.approx(expected)


@pytest.mark.parametrize("rate_hz", [1000.0, 300.0])
def test_the_next_tick_is_the_first_step_boundary_at_or_after_the_wakeup(rate_hz):
    emulator = Emulator(config(physics_rate_hz=rate_hz))
    step_ns = NS_PER_S / rate_hz
    for target_ns in (1, 2_000_000, 2_000_001, 10_000_000, 123_456_789, 3 * NS_PER_S):
        n = emulator.lockstep.next_tick_steps(target_ns)
        assert round(n * emulator.dt_s * NS_PER_S) >= target_ns
        assert round((n - 1) * emulator.dt_s * NS_PER_S) < target_ns
        assert abs(n - math.ceil(target_ns / step_ns)) <= 1
    emulator.lockstep.tick_steps = 50
    assert emulator.lockstep.next_tick_steps(0) == 50  # never back in time


def test_the_duration_caps_the_last_tick():
    emulator = Emulator(config(duration_s=0.25))
    assert emulator.lockstep.next_tick_steps(10 * NS_PER_S) == 250


# --- vehicles, radios, parsing --------------------------------------------------------------------


def step_with_traffic(emulator: Emulator, steps: int) -> None:
    node = emulator.nodes[0]
    for _ in range(steps):
        if emulator.steps % 2 == 0:
            node.push_uplink([GROUND.encode(ThrustMoment(emulator.t_s, 0.0, (0.0, 0.0, 0.0)), 1)], emulator.t_s)
        emulator.step_all()
        node.outbox.take_due(emulator.steps)


@pytest.mark.parametrize("keep", [False, True])
def test_the_radios_keep_a_ledger_only_when_asked(keep):
    emulator = Emulator(config(keep_ledger=keep))
    step_with_traffic(emulator, 200)
    node = emulator.nodes[0]
    for radio in (node.uplink_radio, node.downlink_radio):
        assert radio.stats.offered > 50
        assert len(radio.ledger) == (radio.stats.offered if keep else 0)
    ledger = emulator.radio_report()["vehicles"]["1"]["downlink"]["ledger"]
    assert (ledger is not None) == keep


def test_an_uplink_frame_cut_short_is_dropped_as_a_truncated_datagram():
    """Each zenoh sample is a whole datagram: a frame cut short must not wait for bytes that never
    come (and swallow the next frame's start), it is counted as truncated."""
    emulator = Emulator(config(radio=load_radio_profile("ideal")))
    node = emulator.nodes[0]
    arm = GROUND.encode(VehicleCommand(0.0, CommandKind.ARM), 1)
    node.push_uplink([arm[:-3]], 0.0)
    emulator.step_all()
    assert node.parser.counters.truncated_frames == 1
    assert node.parser.pending_bytes == 0
    node.push_uplink([GROUND.encode(VehicleCommand(0.0, CommandKind.ARM), 1)], emulator.t_s)
    emulator.step_all()  # delivered at 1 ms, between firmware cycles
    emulator.step_all()  # the firmware cycle at 2 ms takes it
    assert node.sim.firmware.armed


def test_vehicles_get_their_own_ids_starts_and_random_streams():
    emulator = Emulator(config(vehicles=3))
    ids = [n.vehicle_id for n in emulator.nodes]
    assert ids == [1, 2, 3]
    assert [n.keys.downlink for n in emulator.nodes] == [f"cfstack/vehicle/{i}/downlink" for i in ids]
    xs = [n.sim.truth.position_enu_m[0] for n in emulator.nodes]
    assert xs == pytest.approx([0.0, 0.5, 1.0])
    draws = {tuple(n.uplink_radio.rng.random(4)) for n in emulator.nodes}
    draws |= {tuple(n.downlink_radio.rng.random(4)) for n in emulator.nodes}
    assert len(draws) == 6


# --- realtime --------------------------------------------------------------------------------------


@pytest.mark.realtime
def test_realtime_runs_at_the_wall_clocks_pace_and_publishes_as_it_goes():
    bus = "mem:emulator-realtime"
    duration_s = 0.5
    emulator = Emulator(config(connection=bus, clock="realtime", duration_s=duration_s))
    keys = VehicleKeys("cfstack", 1)
    with emulator, open_transport(bus, rx=keys.truth) as truth:
        start = time.monotonic()
        emulator.run()
        wall = time.monotonic() - start
        frames = truth.receive(0.5)
    assert emulator.t_s == pytest.approx(duration_s)
    assert wall >= duration_s * 0.98  # paced: never faster than the wall clock
    assert wall < duration_s + 2.0
    truth_rate_hz = emulator.nodes[0].sim.params.truth_rate_hz
    assert len(frames) == pytest.approx(duration_s * truth_rate_hz, abs=2)
    assert emulator.nodes[0].downlink_radio.ledger == []


@pytest.mark.parametrize("rate_hz", [1000.0, 300.0])
def test_a_batch_runs_exactly_the_steps_that_start_before_the_horizon_and_the_bounds(rate_hz, monkeypatch):
    """steps_allowed (one batch, no polls between its steps) against the one-step rule it replaces: the
    next step may run while it starts before horizon - margin, the next tick and the duration."""
    from simulator.lockstep import LOOKAHEAD_MARGIN_S, Lockstep, Participant

    emulator = Emulator(config(physics_rate_hz=rate_hz, duration_s=1.0))
    clock = emulator.lockstep
    clock.lock.participants[1] = Participant(acked=0, wake_ns=0, period_ns=0, complete=0)
    clock.tick = 0
    dt = emulator.dt_s

    def one_by_one(start: int, horizon_s: float, next_tick: int | None) -> int:
        s = start
        while (s * dt < horizon_s - LOOKAHEAD_MARGIN_S and (next_tick is None or s < next_tick)
               and s < emulator.duration_steps):
            s += 1
        return s - start

    sizes = set()  # the batch sizes the grid exercises
    for start in (0, 1, 7, 299, 995):
        for horizon_s in (start * dt, start * dt + 1e-12, (start + 1) * dt, (start + 2.5) * dt, 0.0137, 5.0,
                          (start + 2) * dt + LOOKAHEAD_MARGIN_S, (start + 3) * dt + LOOKAHEAD_MARGIN_S):
            for next_tick in (None, start, start + 1, start + 4, 2000):
                emulator.steps = start
                monkeypatch.setattr(clock, "horizon_s", lambda n, h=horizon_s: h)
                expected = one_by_one(start, horizon_s, next_tick)
                assert clock.steps_allowed(next_tick) == expected, (start, horizon_s, next_tick)
                sizes.add(expected)
    assert 0 in sizes and len(sizes) >= 4  # the grid reaches empty, one-step and longer batches
    clock.lock = Lockstep()
    assert clock.steps_allowed(None) == 0  # nobody taking part
