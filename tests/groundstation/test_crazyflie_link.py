"""`--link crtp`: the ground station flies the emulated Crazyflie through Bitcraze's cflib, over CRTP on UDP in
realtime, as it would fly a real one through a Crazyradio: attitude mode on the stock RPYT setpoint (heading
mode, thrust from the calibrated N -> PWM map), mocap up as extpose, IMU and status down in log blocks.
Graded on the simulator's truth; what the link cannot do is one line."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from testsupport import cfstack, one_line_error, shared_world

pytest.importorskip("cflib", reason="cflib is in the test extra (pip install -e '.[test]')")

LAB_CLEARANCE_M = 0.10  # as tests/groundstation/test_maze_flights.py grades the lab mazes


def test_the_ground_station_flies_a_lab_maze_through_cflib_in_realtime(tmp_path):
    world = shared_world("test_lab_1")
    run = cfstack("fly", str(world), "--mode", "attitude", "--link", "crtp", "--log", str(tmp_path), "--json")
    assert run.returncode == 0, run.stderr
    summary = json.loads(run.stdout)
    assert summary["result"] == "reached_goal" and not summary["collided"]
    assert summary["course_grade"]["passed"] and summary["landing"]["result"] == "landed"
    assert summary["link"]["radio"] == "crtp" and summary["link"]["uplink_delivered"] is None  # CRTP has no count
    with (tmp_path / "states.csv").open() as f:
        rows = [r for r in csv.DictReader(f) if r["truth_x_m"]]
    truth = np.array([[float(r[f"truth_{a}_m"]) for a in "xyz"] for r in rows])
    assert summary["min_clearance_m"] >= LAB_CLEARANCE_M
    assert summary["final_position_error_m"] < 0.05  # the truth at the goal when the hover there ended
    assert abs(truth[-1, 2] - summary["landing"]["spot_enu_m"][2]) < 0.05  # and down on its landing spot
    # the estimator ran on the log block's IMU at 100 Hz (one 10 ms unit) and lost none of it
    assert summary["estimator"]["imu_lost"] == 0
    # and is consistent on it: each 10 ms sample carries the 500 Hz sample's noise (sensor_spec.subsampled)
    assert max(summary["estimator"]["velocity_nees_per_axis"]) < 2.0
    flown_s = float(rows[-1]["t_s"]) - float(rows[0]["t_s"])
    assert summary["link"]["downlink_delivered"] > 100 * flown_s * 0.9


@pytest.mark.parametrize(("arguments", "named"), [
    (["groundstation", "--link", "crtp", "--clock", "lockstep"], "--clock realtime"),
    (["fly", "--link", "crtp", "--mode", "position"], "not with --mode position"),
    (["fly", "--uri", "udp://127.0.0.1:19850"], "--uri: a cflib URI is for --link crtp"),
    (["fly", "--link", "crtp", "--uri", "127.0.0.1:19850"], "is not a cflib URI"),
    (["fly", "--link", "crtp", "--radio-link", "udpout:127.0.0.1:14560"], "--radio-link"),
])
def test_what_the_crazyflie_link_cannot_do_is_one_line(arguments, named):
    assert named in one_line_error(cfstack(*arguments, timeout=60))
