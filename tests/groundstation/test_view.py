"""The rerun view: a recorded flight (`cfstack fly --view-save`) holds the world, the plan, the poses and the
time series on the flight's own time axis, with the log's values; `cfstack view LOGDIR` replays the logs
into the same entities at the same times. Read back with rerun's own API (rerun.chunk.RrdReader)."""

from __future__ import annotations

import json

import numpy as np
import pyarrow as pa
import pytest
from testsupport import cfstack

from groundstation.logread import read_log

rerun_chunk = pytest.importorskip("rerun.chunk", reason="the rerun-sdk package is not installed (cfstack[view])")

WORLD = {"bounds": {"extents": [0, 4, 0, 3, 0, 2]},
         "blocks": [{"extents": [1.8, 2.2, 0, 1.8, 0, 2], "color": [1, 0, 0]}],
         "start": [0.5, 0.5, 1.0], "goal": [3.5, 0.5, 1.0], "resolution": [0.1, 0.1, 0.1], "margin": 0.3}
SCENE = ("world/blocks", "world/bounds", "world/start", "world/goal", "world/plan/path", "world/plan/waypoints",
         "world/plan/trajectory")
POSES = ("world/vehicle/truth", "world/vehicle/estimate", "world/vehicle/estimate_3sigma", "world/vehicle/command")
SERIES = ("plots/tracking_error_m", "plots/thrust_n", "plots/moment_nm", "plots/attitude_cmd_deg", "plots/battery_v",
          "plots/link/delivery_pct", "plots/link/rtt_ms",
          "plots/link/mocap_age_ms", "plots/link/downlink_gap_ms")


def read_rrd(path) -> dict[str, dict]:
    """entity path -> {"static": bool, column name -> list of values}, chunks of an entity concatenated and
    sorted by sim_time (int64 nanoseconds); the wall-clock log_time is left out."""
    entities: dict[str, dict] = {}
    for chunk in rerun_chunk.RrdReader(path).store().stream():
        batch = chunk.to_record_batch()
        entry = entities.setdefault(chunk.entity_path.lstrip("/"), {"static": True})
        entry["static"] &= chunk.is_static
        prefix = "static " if chunk.is_static else ""  # static components (colors) apart from the time series
        for name in batch.schema.names:
            if name == "log_time":
                continue
            column = batch.column(name)
            values = column.cast(pa.int64()).to_pylist() if name == "sim_time" else column.to_pylist()
            entry.setdefault(prefix + name, []).extend(values)
    for entry in entities.values():  # chunks need not come in time order
        if "sim_time" in entry:
            order = np.argsort(entry["sim_time"], kind="stable")
            for name, values in entry.items():
                if isinstance(values, list) and not name.startswith("static "):
                    entry[name] = [values[i] for i in order]
    return entities


def seconds(entry: dict) -> np.ndarray:
    return np.array(entry["sim_time"]) * 1e-9


@pytest.fixture(scope="module")
def flown(tmp_path_factory):
    folder = tmp_path_factory.mktemp("view")
    world = folder / "wall.json"
    world.write_text(json.dumps(WORLD))
    result = cfstack("fly", str(world), "--log", str(folder / "flight"), "--view-save", str(folder / "live.rrd"))
    assert result.returncode == 0, result.stderr
    replay = cfstack("view", str(folder / "flight"), "--save", str(folder / "replay.rrd"))
    assert replay.returncode == 0, replay.stderr
    return folder, read_rrd(folder / "live.rrd"), read_rrd(folder / "replay.rrd"), read_log(folder / "flight")


def test_the_recording_holds_the_scene_poses_and_series(flown):
    _, live, _, log = flown
    missing = [e for e in (*SCENE, *POSES, *SERIES, "phase") if e not in live]
    assert not missing
    assert all(live[e]["static"] for e in SCENE)
    half = np.array(live["world/blocks"]["static Boxes3D:half_sizes"][0][0])
    center = np.array(live["world/blocks"]["static Boxes3D:centers"][0][0])
    assert half == pytest.approx([0.2, 0.9, 1.0]) and center == pytest.approx([2.0, 0.9, 1.0])
    path = np.array(live["world/plan/path"]["static LineStrips3D:strips"][0][0])
    assert path[0] == pytest.approx(WORLD["start"], abs=0.06) and path[-1] == pytest.approx(WORLD["goal"], abs=0.06)
    phases = [text for [text] in live["phase"]["TextLog:text"]]
    assert phases[0] == "phase: connect" and "phase: track" in phases and "phase: land" in phases


def test_poses_and_series_are_the_logged_values_on_flight_time(flown):
    _, live, _, log = flown
    truth = live["world/vehicle/truth"]
    t = seconds(truth)
    assert np.diff(t).min() >= 0.02 - 1e-9  # decimated to view.toml's period of flight time
    rows = np.searchsorted(log.t_s, t - 1e-9)
    assert np.abs(log.t_s[rows] - t).max() < 1e-6  # every frame is a logged tick
    translation = np.array([v[0] for v in truth["Transform3D:translation"]])
    assert np.abs(translation - log.position_m("truth")[rows]).max() < 1e-6
    error = live["plots/tracking_error_m"]
    rows = np.searchsorted(log.t_s, seconds(error) - 1e-9)
    expected = np.linalg.norm(log.position_m("truth")[rows] - log.position_m("ref")[rows], axis=1)
    assert np.array([v[0] for v in error["Scalars:scalars"]]) == pytest.approx(expected, abs=1e-6)
    sigma = live["world/vehicle/estimate_3sigma"]
    rows = np.searchsorted(log.t_s, seconds(sigma) - 1e-9)
    half_sizes = np.array([v[0] for v in sigma["Ellipsoids3D:half_sizes"]])
    assert half_sizes == pytest.approx(3 * log.vec("est_sigma_x_m", "est_sigma_y_m", "est_sigma_z_m")[rows], rel=1e-5)
    moments = np.array(live["plots/moment_nm"]["Scalars:scalars"])
    rows = np.searchsorted(log.t_s, seconds(live["plots/moment_nm"]) - 1e-9)
    assert moments == pytest.approx(log.vec("cmd_mx_nm", "cmd_my_nm", "cmd_mz_nm")[rows], abs=1e-9)
    battery = np.array([v[0] for v in live["plots/battery_v"]["Scalars:scalars"]])
    assert 3.0 < battery.min() <= battery.max() <= 4.2  # a one-cell LiPo between empty and full


def test_replay_draws_the_same_frames_as_the_live_view(flown):
    _, live, replay, _ = flown
    for entity in (*POSES, *SERIES):
        assert seconds(replay[entity]) == pytest.approx(seconds(live[entity]), abs=1e-6), entity
    live_xyz = np.array([v[0] for v in live["world/vehicle/estimate"]["Transform3D:translation"]])
    replay_xyz = np.array([v[0] for v in replay["world/vehicle/estimate"]["Transform3D:translation"]])
    assert np.abs(live_xyz - replay_xyz).max() < 1e-6  # the log keeps 12 significant digits


def test_view_of_a_missing_folder_is_one_line(tmp_path):
    result = cfstack("view", str(tmp_path / "nowhere"), "--save", str(tmp_path / "x.rrd"))
    assert result.returncode == 2
    assert result.stderr.strip().count("\n") == 0 and "nowhere" in result.stderr


def test_the_live_view_asks_the_vehicle_for_its_motors_and_draws_their_pwm(flown):
    """The live view requests SERVO_OUTPUT_RAW at view.toml's rate (10 Hz); each report is drawn once, motors m1..m4
    as PWM duty %: 0 before the vehicle arms, every motor driven and none saturated while it tracks. The flight
    keeps the reports in motors.csv, and the replay draws the same ones at the same times."""
    _, live, replay, log = flown
    motors = live["plots/motor_pwm_pct"]
    t = seconds(motors)
    duty = np.array(motors["Scalars:scalars"])
    assert duty.shape == (len(t), 4)
    assert np.median(np.diff(t)) == pytest.approx(0.1, abs=0.021)  # 10 Hz reports on the 50 Hz frame grid
    phase = log.phase[np.searchsorted(log.t_s, t - 1e-9)]
    assert np.all(duty[phase == "connect"] == 0.0)
    tracking = duty[phase == "track"]
    assert len(tracking) > 10 and np.all((tracking > 0.0) & (tracking < 100.0))
    replayed = replay["plots/motor_pwm_pct"]
    assert seconds(replayed) == pytest.approx(t, abs=1e-6)
    assert np.array(replayed["Scalars:scalars"]) == pytest.approx(duty, abs=1e-6)


def test_motors_file_cut_at_its_last_line_replays_and_a_bad_one_is_one_line(flown, tmp_path):
    """A killed flight may leave motors.csv's last line cut short: dropped. A bad line before it: one line, exit 2."""
    import shutil

    folder = tmp_path / "flight"
    shutil.copytree(flown[0] / "flight", folder)
    motors = folder / "motors.csv"
    lines = motors.read_text().splitlines()
    motors.write_text("\n".join(lines) + "\n0.5,0.4")  # a row cut short
    assert read_log(folder).motors.shape == (len(lines) - 1, 6)
    motors.write_text("\n".join(lines[:3] + ["1.0,x,0,0,0,0"] + lines[3:]) + "\n")
    result = cfstack("view", str(folder), "--save", str(tmp_path / "x.rrd"))
    assert result.returncode == 2
    # the file's line 4: the header, two rows, then the bad one
    assert result.stderr.strip().count("\n") == 0 and "motors.csv: line 4" in result.stderr
