"""Tests of `cfstack plot` and the log reader on small synthetic log folders written here.

The synthetic flight is a known function of time (a circle at constant height), so what the reader
returns is checked against the values written, not against the reader's own output.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from matplotlib.patches import Rectangle
from testsupport import shared_world

from cfstack.cli import main as cfstack_main
from groundstation import plot
from groundstation.logread import STATE_COLUMNS, read_log
from model.errors import UserError

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
MIN_PNG_BYTES = 10_000  # a blank 1100x700 canvas compresses to a few kB; a real plot is well above
TICK_HZ = 50.0
RADIUS_M, HEIGHT_M, OMEGA_RADPS = 1.0, 1.0, 0.5
BASE_FIGURES = ("position.png", "velocity.png", "tracking_error.png", "commands.png", "link_health.png")
PLAN_FIGURES = ("trajectory_3d.png", "trajectory_top.png", "position_velocity.png")

WORLD = {
    "bounds": {"extents": [-2.0, 2.0, -2.0, 2.0, 0.0, 2.0]},
    "blocks": [
        {"extents": [-0.2, 0.2, -0.2, 0.2, 0.0, 1.5], "color": [0, 1, 0]},
        {"extents": [1.5, 1.8, 1.5, 1.8, 0.0, 0.5], "color": [255, 128, 0]},
        {"extents": [-1.8, -1.5, 1.5, 1.8, 0.0, 0.5], "color": "blue"},
        {"extents": [-1.8, -1.5, -1.8, -1.5, 0.0, 0.5]},
    ],
    "start": [1.0, 0.0, 1.0],
    "goal": [-1.0, 0.0, 1.0],
}


def _phase(t: float) -> str:
    return "takeoff" if t < 1.0 else "track" if t < 5.0 else "land"


def _rows(n: int, truth: bool, rng: np.random.Generator) -> list[dict[str, str]]:
    """A circle p(t) = (R cos wt, R sin wt, H); truth lags the reference, the estimate is noisy truth."""
    rows = []
    counters = {"uplink_sent": 0, "downlink_received": 0, "downlink_lost": 0}
    for k in range(n):
        t = k / TICK_HZ
        phase_rad = OMEGA_RADPS * t
        ref_p = np.array([RADIUS_M * math.cos(phase_rad), RADIUS_M * math.sin(phase_rad), HEIGHT_M])
        ref_v = RADIUS_M * OMEGA_RADPS * np.array([-math.sin(phase_rad), math.cos(phase_rad), 0.0])
        true_p, true_v = ref_p + 0.05 * math.sin(3.0 * t), ref_v * 0.95
        est_p, est_v = true_p + rng.normal(0, 0.01, 3), true_v + rng.normal(0, 0.02, 3)
        counters["uplink_sent"] += 1
        lost = k % 10 == 0  # every tenth downlink message lost
        counters["downlink_lost" if lost else "downlink_received"] += 1
        row = {"t_s": repr(t), "phase": _phase(t), "cmd_saturated": str(int(k % 25 == 0)),
               "cmd_thrust_n": repr(0.3 + 0.01 * math.sin(t)), "mocap_age_s": repr(0.004),
               "est_healthy": "1", "rtt_ms": repr(6.0 + math.sin(t)), "tick_time_ms": repr(0.4)}
        row |= {key: str(v) for key, v in counters.items()}
        # plain floats, so repr() writes numbers as the ground station does
        ref_p, ref_v, true_p, true_v = ref_p.tolist(), ref_v.tolist(), true_p.tolist(), true_v.tolist()
        est_p, est_v = est_p.tolist(), est_v.tolist()
        for i, axis in enumerate("xyz"):
            row[f"ref_{axis}_m"], row[f"ref_v{axis}_mps"] = repr(ref_p[i]), repr(ref_v[i])
            row[f"est_{axis}_m"], row[f"est_v{axis}_mps"] = repr(est_p[i]), repr(est_v[i])
            row[f"est_sigma_{axis}_m"], row[f"est_sigma_v{axis}_mps"] = "0.01", "0.02"
            row[f"cmd_m{axis}_nm"] = repr(1e-4 * math.sin(t + i))
            if truth:
                row[f"truth_{axis}_m"], row[f"truth_v{axis}_mps"] = repr(true_p[i]), repr(true_v[i])
        rows.append(row)
    return rows


def write_log(folder: Path, n: int = 300, truth: bool = True, plan_world: Path | None = None,
              seed: int = 1) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    rows = _rows(n, truth, np.random.default_rng(seed))
    lines = [",".join(STATE_COLUMNS)] + [",".join(r.get(c, "") for c in STATE_COLUMNS) for r in rows]
    (folder / "states.csv").write_text("\n".join(lines) + "\n")
    (folder / "summary.json").write_text(json.dumps({"result": "ok", "flight_time_s": n / TICK_HZ}))
    if plan_world is not None:
        path = [[1.0, 0.0, 1.0], [0.0, 1.0, 1.0], [-1.0, 0.0, 1.0]]
        (folder / "plan.json").write_text(json.dumps({
            "world": str(plan_world), "resolution": [0.1, 0.1, 0.1], "margin": 0.2, "path": path,
            "waypoints": [path[0], path[-1]], "trajectory": "constant-speed"}))
    return folder


@pytest.fixture
def world_file(tmp_path: Path) -> Path:
    path = tmp_path / "tiny_world.json"
    path.write_text(json.dumps(WORLD))
    return path


def assert_pngs(folder: Path, names: tuple[str, ...]) -> None:
    for name in names:
        data = (folder / name).read_bytes()
        assert data[:8] == PNG_MAGIC, name
        assert len(data) > MIN_PNG_BYTES, f"{name}: only {len(data)} bytes"


def test_planned_flight_writes_every_figure(tmp_path, world_file, capsys):
    log = write_log(tmp_path / "log", plan_world=world_file)
    assert plot.command([str(log)]) == 0
    expected = BASE_FIGURES + ("estimator_error.png",) + PLAN_FIGURES
    assert_pngs(log, expected)
    printed = capsys.readouterr().out.splitlines()
    assert sorted(Path(p).name for p in printed if not p.startswith("note:")) == sorted(expected)


def test_truncated_log_without_truth_plots_into_out_folder(tmp_path, capsys):
    """A real-vehicle log (no truth) cut mid-row by a killed ground station, figures sent to --out."""
    log = write_log(tmp_path / "log", n=120, truth=False)
    states = log / "states.csv"
    text = states.read_text()
    states.write_text(text[: len(text) - 40])  # cut mid-row, as a killed writer leaves it
    flight = read_log(log)
    assert len(flight) == 119
    assert len(flight.warnings) == 1 and "cut short" in flight.warnings[0]
    out = tmp_path / "figures" / "nested"
    assert plot.command([str(log), "--out", str(out)]) == 0
    assert_pngs(out, BASE_FIGURES)
    assert not (out / "estimator_error.png").exists()
    assert not (out / "trajectory_3d.png").exists(), "no plan.json, so no world view"
    assert not any(log.glob("*.png")), "with --out nothing is written into the log folder"
    output = capsys.readouterr().out
    assert "cut short" in output
    assert "estimator_error.png skipped" in output and "truth" in output


def test_reader_returns_the_values_written(tmp_path):
    log = write_log(tmp_path / "log", n=100, truth=False)
    flight = read_log(log)
    t = np.arange(100) / TICK_HZ
    np.testing.assert_array_equal(flight.t_s, t)
    expected_x = RADIUS_M * np.cos(OMEGA_RADPS * t)
    np.testing.assert_allclose(flight.position_m("ref")[:, 0], expected_x, rtol=0, atol=1e-15)
    assert np.isnan(flight.columns["truth_x_m"]).all() and not flight.has_truth
    assert list(flight.phase[[0, 60]]) == ["takeoff", "track"]
    assert flight.summary == {"result": "ok", "flight_time_s": 2.0}
    assert flight.plan is None


def _one_line_user_error(argv: list[str], *fragments: str) -> str:
    with pytest.raises(UserError) as info:
        plot.command(argv)
    message = str(info.value)
    assert "\n" not in message
    for fragment in fragments:
        assert fragment in message
    return message


def test_missing_folder_and_states_are_one_line_errors(tmp_path, capsys):
    _one_line_user_error([str(tmp_path / "nope")], "nope", "not found")
    (tmp_path / "empty").mkdir()
    _one_line_user_error([str(tmp_path / "empty")], "states.csv", "not found")
    # through the dispatcher: exit code 2, one line on stderr, no traceback
    assert cfstack_main(["plot", str(tmp_path / "nope")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("cfstack plot:")


def test_malformed_files_name_the_file_and_the_problem(tmp_path, world_file):
    log = write_log(tmp_path / "log", n=20, plan_world=world_file)
    states = log / "states.csv"
    good = states.read_text()
    lines = good.splitlines()
    bad_row = lines[1].replace("takeoff,", "takeoff,abc", 1)  # truth_x_m follows phase
    states.write_text("\n".join([lines[0], bad_row] + lines[2:]) + "\n")
    _one_line_user_error([str(log)], "states.csv", "line 2", "truth_x_m", "not a number")
    states.write_text("\n".join([lines[0].replace("rtt_ms,", "")] + lines[1:]) + "\n")
    _one_line_user_error([str(log)], "states.csv", "rtt_ms")
    states.write_text(lines[0] + "\n")
    _one_line_user_error([str(log)], "states.csv", "no data rows")
    states.write_text(good)
    (log / "summary.json").write_text('{"result": ')
    _one_line_user_error([str(log)], "summary.json", "not valid JSON")
    (log / "summary.json").write_text("{}")
    (log / "plan.json").write_text(json.dumps({"world": str(world_file), "path": [[0, 0]]}))
    _one_line_user_error([str(log)], "plan.json", "path")


def test_unreadable_world_still_draws_the_3d_view_with_a_note(tmp_path):
    flight = read_log(write_log(tmp_path / "log", n=60, plan_world=tmp_path / "moved_world.json"))
    world, note = plot._load_plan_world(flight)
    assert world is None and "moved_world.json" in note and "without blocks" in note
    out = plot._save(plot.plot_trajectory_3d(flight, world), tmp_path / "trajectory_3d.png")
    assert out.read_bytes()[:8] == PNG_MAGIC and out.stat().st_size > MIN_PNG_BYTES


def test_windowed_rate_of_a_steady_counter_is_its_rate():
    t = np.arange(0.0, 5.0, 1.0 / TICK_HZ)
    every_tick = np.arange(len(t), dtype=float)
    every_other = np.floor(every_tick / 2)
    rate = plot.windowed_rate(t, every_tick, 1.0)
    np.testing.assert_allclose(rate[int(TICK_HZ):], TICK_HZ, rtol=1e-9)
    assert np.isnan(rate[0]), "no elapsed time at the first sample"
    np.testing.assert_allclose(plot.windowed_rate(t, every_other, 1.0)[int(TICK_HZ):], TICK_HZ / 2, rtol=0.03)
    with_gap = every_tick.copy()
    with_gap[10:20] = np.nan
    assert np.isnan(plot.windowed_rate(t, with_gap, 1.0)[10:20]).all()


@pytest.mark.parametrize(("color", "rgb"), [
    ([0, 1, 0], (0.0, 1.0, 0.0)),
    ([1.0, 0.0, 0.0], (1.0, 0.0, 0.0)),
    ([255, 0, 51], (1.0, 0.0, 0.2)),
    ("blue", (0.0, 0.0, 1.0)),
    (None, (0.5019607843137255,) * 3),
    ("not-a-colour", (0.5019607843137255,) * 3),
    ([300, 0, 0], (0.5019607843137255,) * 3),
    ([1, 2], (0.5019607843137255,) * 3),
])
def test_block_color_accepts_the_world_file_forms(color, rgb):
    np.testing.assert_allclose(plot.block_color(color), rgb)  # matplotlib "grey" is #808080 = 128/255


def test_box_faces_are_the_six_sides_of_the_box():
    extents = np.array([1.0, 2.0, -1.0, 3.0, 0.0, 0.5])
    faces = plot.box_faces(extents)
    assert len(faces) == 6
    lo, hi = extents[0::2], extents[1::2]
    sides = set()
    for face in faces:
        assert np.all((face == lo) | (face == hi)), "every vertex is a box corner"
        constant = [a for a in range(3) if np.ptp(face[:, a]) == 0]
        assert len(constant) == 1, "a face is flat in exactly one axis"
        axis = constant[0]
        sides.add((axis, face[0, axis]))
        # consecutive vertices share an edge: they differ in exactly one coordinate
        steps = np.diff(np.vstack([face, face[:1]]), axis=0)
        assert np.all((steps != 0).sum(axis=1) == 1)
    assert len(sides) == 6


def test_course_world_renders(tmp_path):
    shared = shared_world("custom_pillars")
    log = read_log(write_log(tmp_path / "log", n=60, plan_world=shared))
    figure = plot.plot_trajectory_3d(log, plot.load_world(log.plan.world_path))
    out = tmp_path / "trajectory_3d.png"
    plot._save(figure, out)
    assert out.read_bytes()[:8] == PNG_MAGIC and out.stat().st_size > MIN_PNG_BYTES


def test_commands_show_attitude_when_moments_are_empty(tmp_path):
    flight = read_log(write_log(tmp_path / "log", n=50))
    for name in ("cmd_mx_nm", "cmd_my_nm", "cmd_mz_nm"):
        flight.columns[name][:] = np.nan
    flight.columns["cmd_qw"][:], flight.columns["cmd_qz"][:] = 1.0, 0.0
    flight.columns["cmd_qx"][:], flight.columns["cmd_qy"][:] = 0.0, 0.0
    figure = plot.plot_commands(flight)
    assert "attitude" in figure.axes[1].get_ylabel() and "(deg)" in figure.axes[1].get_ylabel()
    assert "(N)" in figure.axes[0].get_ylabel()


def test_one_spike_does_not_set_the_scale_of_an_error_panel():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from groundstation.plot import _robust_limits

    rng = np.random.default_rng(0)
    error = rng.normal(0.0, 0.001, 5000)
    error[2500] = 0.1  # a touchdown spike, 100 sigma
    sigma = np.full(5000, 0.001)
    fig, ax = plt.subplots()
    ax.plot(error)
    _robust_limits(ax, error, sigma)
    low, high = ax.get_ylim()
    assert high < 0.01 and low > -0.01  # the bulk (and the 3 sigma band) sets the scale, not the spike
    # the panel says what it leaves out: the spike (and a rare tail sample beyond 1.2 x the 99.5th percentile)
    assert any("beyond the scale (max 0.1)" in t.get_text() for t in ax.texts)
    plt.close(fig)


def test_top_down_view_shows_each_block_footprint_and_the_paths(tmp_path, world_file):
    flight = read_log(write_log(tmp_path / "log", n=600, plan_world=world_file))
    figure = plot.plot_trajectory_top(flight, plot.load_world(world_file))
    ax = figure.axes[0]
    rects = [p for p in ax.patches if isinstance(p, Rectangle)]
    footprints = sorted((r.get_x(), r.get_y(), r.get_width(), r.get_height()) for r in rects)
    expected = sorted((b["extents"][0], b["extents"][2], b["extents"][1] - b["extents"][0],
                       b["extents"][3] - b["extents"][2]) for b in WORLD["blocks"])
    np.testing.assert_allclose(footprints, expected)
    tall = next(r for r in rects if r.get_x() == -0.2)  # 1.5 m of a 2 m room, the others 0.5 m
    assert all(tall.get_facecolor()[3] > r.get_facecolor()[3] for r in rects if r is not tall)
    lines = {line.get_label(): line for line in ax.get_lines()}
    np.testing.assert_allclose(lines["reference"].get_xydata(), flight.position_m("ref")[:, :2])
    np.testing.assert_allclose(lines["flown (truth)"].get_xydata(), flight.position_m("truth")[:, :2])
    assert ax.get_xlabel() == "x east (m)" and ax.get_ylabel() == "y north (m)"
    assert ax.get_xlim() == (-2.0, 2.0) and ax.get_ylim() == (-2.0, 2.0)


@pytest.mark.parametrize("make", [lambda lg: plot.plot_states(lg, "position"), plot.plot_commands,
                                  plot.plot_link_health, plot.plot_position_velocity])
def test_time_plots_mark_each_phase_change_on_every_panel(tmp_path, make):
    flight = read_log(write_log(tmp_path / "log", n=600))  # takeoff until 1 s, track until 5 s, then land
    figure = make(flight)
    changes = [1.0, 5.0]
    for ax in figure.axes:
        marks = sorted(line.get_xdata()[0] for line in ax.get_lines() if line.get_linestyle() == ":"
                       and np.ptp(line.get_xdata()) == 0 and line.get_color() == "gray")
        np.testing.assert_allclose(marks, changes, atol=1.0 / TICK_HZ)
    names = [t.get_text().strip() for t in figure.axes[0].texts]
    assert "track" in names and "land" in names
