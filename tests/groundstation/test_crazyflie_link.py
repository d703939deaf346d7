"""`--link crtp`: the ground station flies the emulated Crazyflie through Bitcraze's cflib, as it would fly a real
one through a Crazyradio: attitude mode on the stock RPYT setpoint (heading mode, thrust from the calibrated
N -> PWM map), mocap up as extpose, IMU and status down in log blocks. Over CRTP on UDP in realtime, and over
zenoh (link.crtp.zenoh_driver) in lockstep, byte-identical per seed. Graded on the simulator's truth; what the
link cannot do is one line."""

from __future__ import annotations

import csv
import json
import signal
import subprocess
import sys
import uuid
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
from testsupport import cfstack, free_port, one_line_error, shared_world

pytest.importorskip("cflib", reason="cflib is in the test extra (pip install -e '.[test]')")

LAB_CLEARANCE_M = 0.10  # as tests/groundstation/test_maze_flights.py grades the lab mazes


def _check_lab_flight(run, log_dir, imu_rate_hz: float = 100.0) -> dict:
    """The flight's summary, after checking it reached the goal and landed, graded on the truth."""
    assert run.returncode == 0, run.stderr
    summary = json.loads(run.stdout)
    assert summary["result"] == "reached_goal" and not summary["collided"]
    assert summary["course_grade"]["passed"] and summary["landing"]["result"] == "landed"
    assert summary["link"]["radio"] == "crtp" and summary["link"]["uplink_delivered"] is None  # CRTP has no count
    with (log_dir / "states.csv").open() as f:
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
    assert summary["link"]["downlink_delivered"] > imu_rate_hz * flown_s * 0.9
    return summary


def _fly_lab(mode_args: tuple[str, ...], log_dir):
    return cfstack("fly", str(shared_world("test_lab_1")), "--mode", "attitude", "--link", "crtp", *mode_args,
                   "--log", str(log_dir), "--json")


@pytest.fixture(scope="module")
def flights(tmp_path_factory):
    """Every flight of this module, the realtime one beside the lockstep ones: the realtime flight keeps under
    a core busy, and the lockstep flights, one at a time, about one."""
    root = tmp_path_factory.mktemp("crazyflie_link")

    def lockstep_flights():
        maze = [(_fly_lab(("--seed", "3"), root / name), root / name) for name in ("a", "b")]
        return maze, _lockstep_pair(root, "plain", False), _lockstep_pair(root, "watched", True)

    with ThreadPoolExecutor(2) as pool:
        realtime = pool.submit(_fly_lab, ("--clock", "realtime"), root / "realtime")
        lockstep = pool.submit(lockstep_flights)
        maze, plain, watched = lockstep.result()
        return {"realtime": (realtime.result(), root / "realtime"), "maze": maze, "plain": plain,
                "watched": watched, "root": root}


def test_the_ground_station_flies_a_lab_maze_through_cflib_in_realtime_over_udp(flights):
    _check_lab_flight(*flights["realtime"])


def test_the_ground_station_flies_a_lab_maze_through_cflib_in_lockstep_over_zenoh_byte_identical(flights):
    """Lockstep is the default clock; its URI is zenoh://cfstack/1. Two flights of one seed log the same bytes;
    every log-block sample of the flight reached the estimator (in lockstep, exactly)."""
    (run_a, dir_a), (run_b, dir_b) = flights["maze"]
    summaries = [_check_lab_flight(run_a, dir_a), _check_lab_flight(run_b, dir_b)]
    assert (dir_a / "states.csv").read_bytes() == (dir_b / "states.csv").read_bytes()
    assert summaries[0]["max_tracking_error_m"] == summaries[1]["max_tracking_error_m"]
    assert summaries[0]["clock"] == "lockstep"


@pytest.mark.parametrize(("arguments", "named"), [
    (["groundstation", "--link", "crtp", "--clock", "lockstep", "--uri", "udp://127.0.0.1:19850"],
     "cannot fly in lockstep"),
    (["groundstation", "--link", "crtp", "--uri", "zenoh://cfstack/0"], "is not zenoh://PREFIX/VEHICLE"),
    (["fly", "--link", "crtp", "--mode", "position"], "not with --mode position"),
    (["fly", "--uri", "udp://127.0.0.1:19850"], "--uri: a cflib URI is for --link crtp"),
    (["fly", "--link", "crtp", "--uri", "127.0.0.1:19850"], "is not a cflib URI"),
    (["fly", "--link", "crtp", "--radio-link", "udpout:127.0.0.1:14560"], "--radio-link"),
])
def test_what_the_crazyflie_link_cannot_do_is_one_line(arguments, named):
    assert named in one_line_error(cfstack(*arguments, timeout=60))


def _lockstep_pair(tmp_path, name: str, watch: bool) -> tuple[subprocess.CompletedProcess, list]:
    """`cfstack emulator` and `cfstack groundstation` in lockstep on a private endpoint, a MAVLink hover; with
    `watch`, a cflib script connected over zenoh before the flight logs stateEstimate.z all through it."""
    from cflib.crazyflie import Crazyflie
    from cflib.crazyflie.log import LogConfig
    from cflib.crazyflie.syncCrazyflie import SyncCrazyflie

    from link.crtp import zenoh_driver

    endpoint, prefix = f"tcp/127.0.0.1:{free_port()}", f"w{uuid.uuid4().hex[:8]}"
    emulator = subprocess.Popen([sys.executable, "-m", "cfstack", "emulator", "--clock", "lockstep", "--seed", "3",
                                 "--listen", endpoint, "--id", prefix, "--crtp-port", "off", "--quiet"],
                                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    entries: list = []
    scf = None
    try:
        if watch:
            zenoh_driver.register()
            scf = SyncCrazyflie(f"zenoh://{prefix}/1?connect={endpoint}", cf=Crazyflie(rw_cache=None))
            scf.open_link()
            config = LogConfig("watch", period_in_ms=100)
            config.add_variable("stateEstimate.z", "float")
            scf.cf.log.add_config(config)
            config.data_received_cb.add_callback(lambda stamp, data, _c: entries.append((stamp, data)))
            config.start()
        run = cfstack("groundstation", "--trajectory", "hover", "--clock", "lockstep", "--connect", endpoint,
                      "--id", prefix, "--log", str(tmp_path / name), "--json")
    finally:
        if scf is not None:
            scf.close_link()
        emulator.send_signal(signal.SIGINT)
        emulator.wait(timeout=30)
    return run, entries


def test_a_cflib_script_watching_over_zenoh_changes_nothing_in_a_mavlink_lockstep_flight(flights):
    """Its CRTP is foreign to the MAVLink ground station's lockstep (ClockAck.crtp): served on the vehicle's CRTP
    radios in simulation time, it neither counts towards the ground station's acks nor touches its radios."""
    (plain_run, _), (watched_run, entries) = flights["plain"], flights["watched"]
    root = flights["root"]
    assert plain_run.returncode == 0, plain_run.stderr
    assert watched_run.returncode == 0, watched_run.stderr
    assert (root / "plain" / "states.csv").read_bytes() == (root / "watched" / "states.csv").read_bytes()
    flown_s = json.loads(watched_run.stdout)["sim_time_s"]
    assert len(entries) >= 0.9 * flown_s / 0.1  # the log block ran all through, on the simulation's clock
    assert max(data["stateEstimate.z"] for _, data in entries) > 0.5  # and saw the hover
