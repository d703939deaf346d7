"""Issue 14: every flight's outcome is honest and explained, checked on flights of our own worlds (lockstep,
seeded, over zenoh, as `cfstack fly` runs them) and on the command line's option checks.

- A goal right above a block's edge: the landing after the goal moves to a clear spot, the flight is
  reached_goal with exit 0, and the whole flight (landing included) keeps clear of the block.
- A start on the world bounds: moved inward by the collision radius with a warning, then flown.
- A flight into a wall: crashed, with the reason (what was touched: the block's index and extents, where,
  when, how fast) on stderr and in the summary, and min_clearance_m 0 to that block.
- Bad options: one line naming the option, exit code 2, at once (no hang), for every command.
"""

import csv
import json
import math
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
from testsupport import cfstack, one_line_error, processes_with

from model.vehicle import load_vehicle
from model.world import load_world

WORLDS = {
    # a pad spanning y 4..6, 0.5 m tall; the goal 2 mm beyond its edge at y = 6 (issue 14's student map)
    "edge_goal": {"bounds": {"extents": [0, 4, 0, 8, 0, 3]}, "blocks": [{"extents": [1.0, 3.0, 4.0, 6.0, 0.0, 0.5]}],
                  "start": [2.0, 1.0, 1.0], "goal": [2.0, 6.002, 1.0]},
    # the start exactly on the x = 0 wall
    "start_on_bounds": {"bounds": {"extents": [0, 4, 0, 4, 0, 3]}, "blocks": [{"extents": [2.5, 3.0, 0, 4, 0, 3]}],
                        "start": [0.0, 1.0, 1.0], "goal": [1.5, 3.0, 1.0]},
    # a wall across the built-in line (2 m along +x from the start)
    "wall_on_line": {"bounds": {"extents": [0, 5, 0, 3, 0, 3]}, "blocks": [{"extents": [2.0, 2.2, 0, 3, 0, 3]}],
                     "start": [1.0, 1.5, 1.0]},
}
FLIGHT_ARGS = {"edge_goal": (), "start_on_bounds": (), "wall_on_line": ("--trajectory", "line")}
RADIUS_M = load_vehicle().collision_radius_m


@pytest.fixture(scope="module")
def flights(tmp_path_factory):
    folder = tmp_path_factory.mktemp("outcomes")

    def fly(name: str):
        world = folder / f"{name}.json"
        world.write_text(json.dumps(WORLDS[name]))
        run = cfstack("fly", str(world), *FLIGHT_ARGS[name], "--json", "--log", str(folder / name))
        summary = json.loads(run.stdout) if run.stdout.strip() else None
        return run.returncode, summary, run.stderr, load_world(world)

    with ThreadPoolExecutor(max_workers=len(WORLDS)) as pool:
        return dict(zip(WORLDS, pool.map(fly, WORLDS), strict=True))


def truth_positions(log_dir: str) -> tuple[np.ndarray, np.ndarray]:
    """(truth positions (N, 3), phases (N,)) of every logged row that has truth."""
    with (Path(log_dir) / "states.csv").open() as f:
        rows = [r for r in csv.DictReader(f) if r["truth_x_m"]]
    return np.array([[float(r[f"truth_{a}_m"]) for a in "xyz"] for r in rows]), np.array([r["phase"] for r in rows])


def test_a_goal_over_a_block_edge_is_reached_and_the_landing_moves_off_the_edge(flights):
    code, summary, stderr, world = flights["edge_goal"]
    assert summary is not None, stderr
    assert code == 0 and summary["result"] == "reached_goal" and summary["reached_goal"], summary.get("failure")
    assert not summary["collided"] and summary["failure"] is None
    landing = summary["landing"]
    assert landing["result"] == "landed" and landing["moved_m"] > 0.0
    # from the log, against the world file: after the take-off nothing came within the collision radius of
    # the block, except resting on its top (a pad) during the landing
    truth, phase = truth_positions(summary["log_dir"])
    airborne = ~np.isin(phase, ("connect", "arm", "takeoff", "land", "disarm", "done"))
    assert world.distance_to_blocks(truth[airborne]).min() >= RADIUS_M
    final = truth[-1]
    assert final[2] <= 0.5 + 0.01 if 1.0 <= final[0] <= 3.0 and 4.0 <= final[1] <= 6.0 else final[2] <= 0.01
    assert summary["min_clearance_m"] >= RADIUS_M


def test_a_start_on_the_bounds_is_moved_inward_with_a_warning_and_flown(flights):
    code, summary, stderr, world = flights["start_on_bounds"]
    assert summary is not None, stderr
    warnings = [line for line in stderr.splitlines() if line.startswith("warning:")]
    assert len(warnings) == 1 and "start [0.0, 1.0, 1.0]" in warnings[0] and "inward" in warnings[0]
    assert code == 0 and summary["result"] == "reached_goal" and summary["failure"] is None
    truth, _ = truth_positions(summary["log_dir"])
    # the vehicle stayed inside the bounds the whole time; it started at the nudged x
    assert world.contains(truth).all() and math.isclose(truth[0, 0], RADIUS_M, abs_tol=0.01)


def test_a_crash_says_what_was_touched_where_and_when(flights):
    code, summary, stderr, world = flights["wall_on_line"]
    assert summary is not None, stderr
    assert code == 1 and summary["result"] == "crashed" and summary["collided"] and not summary["reached_goal"]
    failure = summary["failure"]
    assert failure["kind"] == "crash" and failure["phase"] == "track"
    touched = failure["touched"]
    assert touched["what"] == "block" and touched["block_index"] == 0
    # the extents crossed the link as float32 (DEBUG_FLOAT_ARRAY): 2.2 reads back as 2.2000000477
    assert touched["block_extents_m"] == pytest.approx(WORLDS["wall_on_line"]["blocks"][0]["extents"], abs=1e-6)
    # the crash point is within the collision radius of the wall's -x face, which the line runs into
    x, y, z = failure["position_enu_m"]
    assert 2.0 - RADIUS_M - 1e-6 <= x <= 2.0 and failure["speed_mps"] > 0.0
    # the same line on stderr, once, and the clearance says the flight reached the block
    assert stderr.count(failure["reason"]) == 1 and "touched block 0" in failure["reason"]
    assert summary["min_clearance_m"] <= RADIUS_M and summary["min_clearance_to"] == "block 0"


@pytest.mark.parametrize("command, option, value", [
    ("fly", "--rate", "-5"), ("fly", "--rate", "0"), ("fly", "--rate", "nan"), ("fly", "--speed", "0"),
    ("fly", "--margin", "-1"), ("fly", "--mode", "foo"), ("fly", "--seed", "abc"), ("fly", "--accel", "inf"),
    ("fly", "--vehicle", "300"), ("step", "--size", "0"), ("step", "--rate", "-1"),
    ("step", "--jobs", "0"),
    ("groundstation", "--rate", "inf"), ("groundstation", "--vehicle", "0"), ("sweep", "--jobs", "0"),
    ("plan", "--margin", "nan"), ("emulator", "--seed", "-1"),
    ("fly", "--firmware", "px4"), ("emulator", "--firmware", "px4"), ("sweep", "--firmware", "px4"),
])
def test_a_bad_option_is_one_line_and_exit_code_2_at_once(command, option, value):
    extra = {"sweep": ("--latency", "0", "--loss", "0"), "plan": ("missing.json",)}.get(command, ())
    run = cfstack(command, *extra, f"{option}={value}", timeout=30)
    assert option in one_line_error(run) and run.stdout == ""


# What takes most of a ground station's start-up (the planner's scipy.optimize, the estimator's scipy: ~0.5 s
# here; filterpy and scipy.stats were among them before the estimator stopped importing them).
HEAVY_MODULES = ("groundstation.session", "estimator.eskf", "filterpy", "scipy.stats", "groundstation.planned")


def test_fly_and_step_check_their_options_and_start_their_emulator_before_the_heavy_modules_load():
    # `cfstack fly` and `cfstack step` import their module, parse, check the world and start the child; the
    # heavy modules come after, so the child's own start-up overlaps them
    probe = ("import sys, groundstation.cli, groundstation.step_cli; "
             f"print(','.join(m for m in {HEAVY_MODULES!r} if m in sys.modules))")
    run = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60)
    assert run.returncode == 0 and run.stdout.strip() == "", run.stdout + run.stderr


def test_a_ground_station_never_imports_filterpy_or_scipy_stats():
    # the estimator makes filterpy's Kalman steps itself (tests/estimator/test_eskf_kernels.py): importing
    # filterpy imports scipy.stats, ~0.4 s of each flight's start-up
    probe = ("import sys, groundstation.session, groundstation.planned; "
             "print(','.join(m for m in ('filterpy', 'scipy.stats') if m in sys.modules))")
    run = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60)
    assert run.returncode == 0 and run.stdout.strip() == "", run.stdout + run.stderr


def test_a_world_with_no_path_is_one_line_and_leaves_no_emulator_behind(tmp_path):
    # fly starts its emulator child before planning (to overlap their start-ups): a planning failure stops it
    walled = {"bounds": {"extents": [0, 4, 0, 2, 0, 2]}, "blocks": [{"extents": [1.9, 2.1, 0, 2, 0, 2]}],
              "start": [0.5, 1.0, 1.0], "goal": [3.5, 1.0, 1.0]}
    world = tmp_path / "walled.json"
    world.write_text(json.dumps(walled))
    prefix = f"nopath{os.getpid()}"
    run = cfstack("fly", str(world), "--id", prefix, "--json", timeout=60)
    lines = run.stderr.strip().splitlines()
    assert run.returncode == 1 and run.stdout == "" and len(lines) == 1 and "no path" in lines[0], run.stderr
    assert processes_with(prefix) == []


def test_step_offers_no_planning_options():
    help_text = cfstack("step", "--help", timeout=30).stdout
    assert "--axis" in help_text
    for option in ("--planning", "--margin", "--resolution", "--speed"):
        assert option not in help_text
