"""Planned maze flights through our link (issue 5): every course flight map and every lab maze, both modes.

Lockstep, crazyradio radio profile, seeded. Targets: reach the goal without collision; ground-truth
clearance >= 0.25 m on the course maps (the course's robot radius) and >= 0.1 m on the lab mazes.
The flights run concurrently (each is two processes waiting on each other most of the time).
"""

import json
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
from testsupport import SHARED_WORLDS, shared_world_params, shared_worlds_present

COURSE_MAPS = ("test_maze", "test_over_under", "p13_test_window")
WORLD_CASES = shared_world_params(*(f"{name}.json" for name in COURSE_MAPS), "test_lab_*.json", "maze_20*.json")
MODES = ("moments", "attitude")
COURSE_CLEARANCE_M = 0.25
LAB_CLEARANCE_M = 0.10
# Course maps are big (10-20 m): fly them fast with the full geometric controller, planning at a
# margin that leaves the 0.25 m robot radius plus the tracking error.
COURSE_ARGS = ("--planning", "planning_aggressive", "--controller", "full", "--margin", "0.32")
LAB_ARGS = ()  # the defaults: minimum snap at the report's 1 m/s, margin 0.2 m
CONCURRENT_FLIGHTS = 3

def fly(world: str, mode: str, log: Path) -> tuple[int, dict | None, str]:
    args = COURSE_ARGS if world in COURSE_MAPS else LAB_ARGS
    run = subprocess.run([sys.executable, "-m", "cfstack", "fly", str(SHARED_WORLDS / f"{world}.json"), "--mode", mode,
                          "--radio", "crazyradio", "--clock", "lockstep", "--seed", "7", "--json", "--log", str(log),
                          *args], capture_output=True, text=True, timeout=600, stdin=subprocess.DEVNULL)
    summary = json.loads(run.stdout) if run.stdout.strip() else None
    return run.returncode, summary, run.stderr[-2000:]


@pytest.fixture(scope="module")
def flights(tmp_path_factory):
    cells = [(w, m) for w in (WORLD_CASES if shared_worlds_present() else []) for m in MODES]
    root = tmp_path_factory.mktemp("maze_flights")
    with ThreadPoolExecutor(CONCURRENT_FLIGHTS) as pool:
        futures = {cell: pool.submit(fly, cell[0], cell[1], root / f"{cell[0]}_{cell[1]}") for cell in cells}
        return {cell: f.result() for cell, f in futures.items()}


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("world", WORLD_CASES)
def test_maze_flight_reaches_goal_with_clearance(flights, world, mode):
    code, summary, stderr = flights[(world, mode)]
    assert summary is not None, stderr
    assert code == 0 and summary["result"] == "reached_goal", (summary["result"], summary.get("failsafe_reason"))
    assert not summary["collided"]
    required = COURSE_CLEARANCE_M if world in COURSE_MAPS else LAB_CLEARANCE_M
    assert summary["min_clearance_m"] >= required
    assert summary["final_position_error_m"] <= 0.05
    assert summary["path_length_m"] > 0 and summary["planning_time_s"] > 0
