"""`cfstack plan`: defaults, output formats, exit codes and one-line errors through the dispatcher."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest
from testsupport import shared_world

from cfstack.cli import main


def course(name: str) -> str:
    return str(shared_world(name.removesuffix(".json")))


def run_json(capsys, *argv) -> tuple[int, dict]:
    code = main(["plan", *argv, "--json"])
    out = capsys.readouterr().out
    assert out.count("\n") == 1  # exactly one JSON object on one line
    return code, json.loads(out)


def interior_on_lattice(path: np.ndarray, origin: np.ndarray, res: np.ndarray) -> bool:
    """Whether the points between start and goal are voxel centres origin + (i + 1/2) res."""
    k = (path[1:-1] - origin) / res - 0.5
    return bool(np.allclose(k, np.round(k), atol=1e-6))


def test_json_output_runs_from_the_exact_start_to_the_exact_goal(capsys):
    code, out = run_json(capsys, course("test_saw.json"))
    assert code == 0
    assert set(out) == {"found", "path", "length_m", "nodes_expanded", "planning_time_s"}
    path = np.array(out["path"])
    assert out["found"] and path[0].tolist() == [1, 1, 1] and path[-1].tolist() == [2.5, 7.5, 2]
    assert out["length_m"] == pytest.approx(np.linalg.norm(np.diff(path, axis=0), axis=1).sum())
    assert out["nodes_expanded"] > 0 and out["planning_time_s"] > 0
    # test_saw.json says resolution 0.5: the interior points are centres of 0.5 m voxels
    assert interior_on_lattice(path, np.zeros(3), np.full(3, 0.5))


def test_resolution_defaults_to_planning_toml_when_the_world_has_none(capsys):
    code, out = run_json(capsys, course("test_lab_1.json"))
    assert code == 0
    path = np.array(out["path"])
    assert interior_on_lattice(path, np.array([-2.0, -2.0, 0.0]), np.full(3, 0.1))
    assert not interior_on_lattice(path, np.array([-2.0, -2.0, 0.0]), np.full(3, 0.2))


def test_three_resolutions_margin_start_and_goal_options(capsys):
    code, out = run_json(
        capsys,
        course("test_lab_1.json"),
        "--resolution",
        "0.2",
        "0.1",
        "0.25",
        "--margin",
        "0.3",
        "--start",
        "-1.5",
        "-1.6",
        "1.0",
        "--goal",
        "2.4",
        "1.5",
        "0.8",
    )
    assert code == 0
    path = np.array(out["path"])
    assert path[0].tolist() == [-1.5, -1.6, 1.0] and path[-1].tolist() == [2.4, 1.5, 0.8]
    assert interior_on_lattice(path, np.array([-2.0, -2.0, 0.0]), np.array([0.2, 0.1, 0.25]))


def test_human_output_reports_length_nodes_and_time(capsys):
    assert main(["plan", course("test_empty.json")]) == 0
    out = capsys.readouterr().out
    assert "path length" in out and "nodes expanded" in out and "planning time" in out


def test_no_path_is_exit_code_1_with_a_message(capsys):
    code, out = run_json(capsys, course("test_impossible.json"))
    assert code == 1
    assert out["found"] is False and out["path"] == [] and out["length_m"] is None
    assert main(["plan", course("test_impossible.json")]) == 1
    assert "no path" in capsys.readouterr().err


def test_world_warnings_go_to_stderr_one_line_each(capsys):
    assert main(["plan", course("maze_2022_1.json"), "--json"]) == 0
    err = capsys.readouterr().err.splitlines()
    assert err and all("inverted" in line for line in err)


def test_plot_writes_a_png(tmp_path, capsys):
    target = tmp_path / "plan.png"
    assert main(["plan", course("test_saw.json"), "--plot", str(target)]) == 0
    assert target.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


GOOD = {
    "bounds": {"extents": [0, 4, 0, 3, 0, 2]},
    "blocks": [{"extents": [1, 2, 0, 1, 0, 2]}],
    "start": [0.5, 0.5, 1.0],
    "goal": [3.5, 2.5, 1.0],
}
BAD_WORLDS = {
    "missing_bounds": json.dumps({k: v for k, v in GOOD.items() if k != "bounds"}),
    "nan": json.dumps({**GOOD, "start": [math.nan, 0.5, 1.0]}),
    "inverted_bounds": json.dumps({**GOOD, "bounds": {"extents": [4, 0, 0, 3, 0, 2]}}),
    "start_in_block": json.dumps({**GOOD, "start": [1.5, 0.5, 1.0]}),
    "goal_outside": json.dumps({**GOOD, "goal": [5.0, 2.5, 1.0]}),
    "truncated": json.dumps(GOOD)[:40],
}


@pytest.mark.parametrize("case", sorted(BAD_WORLDS))
def test_bad_world_files_are_one_line_errors_with_exit_code_2(case, tmp_path, capsys):
    path = tmp_path / f"{case}.json"
    path.write_text(BAD_WORLDS[case])
    assert main(["plan", str(path)]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert len(captured.err.splitlines()) == 1 and str(path) in captured.err


@pytest.mark.parametrize(
    "argv",
    [
        ["--resolution", "0.1", "0.2"],
        ["--margin", "-1"],
        ["--resolution", "0"],
        ["--start", "1", "2"],
        ["--bogus"],
    ],
)
def test_bad_arguments_are_one_line_errors(argv, tmp_path, capsys):
    path = tmp_path / "good.json"
    path.write_text(json.dumps(GOOD))
    assert main(["plan", str(path), *argv]) == 2
    assert len(capsys.readouterr().err.splitlines()) == 1


def test_real_process_prints_no_traceback(tmp_path):
    path = tmp_path / "truncated.json"
    path.write_text(BAD_WORLDS["truncated"])
    proc = subprocess.run(
        [sys.executable, "-m", "cfstack.cli", "plan", str(path)], capture_output=True, text=True, timeout=60
    )
    assert proc.returncode == 2
    assert proc.stdout == "" and len(proc.stderr.splitlines()) == 1 and "not valid JSON" in proc.stderr
