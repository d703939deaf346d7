"""Tests of `cfstack sweep` (groundstation/sweep/): options, generated radio profiles, the
"largest survived latency" rule, fly-result classification, the CSV, and one tiny real sweep.

The generated profiles are checked by the simulator's own loader (the emulator reads them); the
real sweep flies two cells whose outcome is certain by physics: a perfect radio (hover succeeds) and
a 2 s one-way delay (a 4 s round trip: no vehicle can be armed and stabilised through that).
"""

from __future__ import annotations

import csv
import dataclasses
import json
import tomllib
from pathlib import Path

import pytest

from cfstack.cli import main as cfstack_main
from groundstation.sweep import cli, grid, runner, table
from model.config import Params, dump_toml
from model.errors import ConfigError, UserError
from model.radio import load_radio_profile, radio_profile_path

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _opts(*extra: str) -> grid.SweepOptions:
    return cli.parse_options(["--latency", "0,10", "--loss", "0", *extra])


# ------------------------------------------------------------------------------------------ options


def test_lists_are_parsed_sorted_and_distinct_and_modes_default_to_both():
    opts = cli.parse_options(["--latency", "40, 0,10", "--latency", "10,2.5", "--loss", "50,0,20"])
    assert opts.latencies_ms == (0.0, 2.5, 10.0, 40.0)
    assert opts.losses_pct == (0.0, 20.0, 50.0)
    assert opts.modes == ("moments", "attitude")
    assert opts.radio_base == "ideal"
    assert opts.jobs >= 1


def test_extra_arguments_are_split_like_a_shell_even_when_they_look_like_options():
    opts = _opts("--extra", "--from-ground", "--extra", "--trajectory 'constant-speed' --speed=0.5")
    assert opts.extra == ("--from-ground", "--trajectory", "constant-speed", "--speed=0.5")
    assert runner.fly_argv(opts, grid.Cell("moments", 0.0, 0.0), Path("p.toml"), Path("log"))[-4:] == list(opts.extra)


def test_modes_keep_the_order_given_without_repeats():
    assert _opts("--mode", "attitude", "--mode", "moments", "--mode", "attitude").modes == ("attitude", "moments")


@pytest.mark.parametrize("argv, fragment", [
    (["--latency", "", "--loss", "0"], "empty entry"),
    (["--latency", "0,,10", "--loss", "0"], "empty entry"),
    (["--latency", ",", "--loss", "0"], "empty entry"),
    (["--latency", "-10", "--loss", "0"], ">= 0"),
    (["--latency=-10,5", "--loss", "0"], ">= 0"),
    (["--latency", "nan", "--loss", "0"], "finite"),
    (["--latency", "ten", "--loss", "0"], "not a number"),
    (["--latency", "0", "--loss", "101"], "maximum 100"),
    (["--latency", "0", "--loss", "-1"], ">= 0"),
    (["--latency", "0"], "--loss"),
    (["--loss", "0"], "--latency"),
    (["--latency", "0", "--loss", "0", "--jobs", "0"], "--jobs"),
    (["--latency", "0", "--loss", "0", "--seed", "-1"], "--seed"),
    (["--latency", "0", "--loss", "0", "--timeout", "0"], "--timeout"),
    (["--latency", "0", "--loss", "0", "--mode", "rates"], "invalid choice"),
    (["--latency", "0", "--loss", "0", "--extra", "--radio lab"], "--radio is set by the sweep"),
    (["--latency", "0", "--loss", "0", "--extra", "--seed=3"], "--seed is set by the sweep"),
    (["--latency", "0", "--loss", "0", "--extra", "'unclosed"], "--extra"),
    (["/nonexistent/world.json", "--latency", "0", "--loss", "0"], "world.json"),
])
def test_bad_options_are_one_line_user_errors(argv, fragment):
    with pytest.raises(UserError) as err:
        cli.parse_options(argv)
    message = str(err.value)
    assert fragment in message
    assert "\n" not in message


def test_bad_options_through_cfstack_give_exit_code_2_and_one_line(capsys):
    code = cfstack_main(["sweep", "--latency", "0", "--loss", "120"])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1 and err.startswith("cfstack sweep:") and "120" in err


def test_unknown_base_profile_is_a_config_error():
    with pytest.raises(ConfigError, match="nosuch"):
        radio_profile_path("nosuch")
    with pytest.raises(ConfigError, match="not found"):
        radio_profile_path("/nonexistent/radio.toml")


# ------------------------------------------------------------------------------------------ profiles


@pytest.mark.parametrize("base_name", ["ideal", "crazyradio", "harsh"])
@pytest.mark.parametrize("latency_ms, loss_pct", [(0.0, 0.0), (40.0, 20.0), (2.5, 100.0)])
def test_generated_profile_loads_and_changes_only_latency_and_iid_loss(tmp_path, base_name, latency_ms, loss_pct):
    base = grid.load_base_profile(radio_profile_path(base_name))
    path = grid.write_cell_profile(base, latency_ms, loss_pct, tmp_path)
    generated = load_radio_profile(path)
    original = load_radio_profile(base_name)
    assert generated.base_latency_s == pytest.approx(latency_ms * 1e-3, abs=0.0, rel=1e-15)
    assert generated.loss_probability == pytest.approx(loss_pct * 1e-2, abs=0.0, rel=1e-15)
    # every other field is the base's (name/source/path say where the file came from)
    expected = dataclasses.replace(original, base_latency_s=generated.base_latency_s,
                                   loss_probability=generated.loss_probability, name=generated.name,
                                   source=generated.source, path=generated.path)
    assert generated == expected
    assert base_name in generated.name and base_name in generated.source


def test_toml_writer_round_trips_nested_tables_and_awkward_strings():
    data = {"schema_version": 1, "name": 'a "quoted"\\ name\nwith ünïcode\ttab', "x": 1e-05, "flag": False,
            "t": {"v": [1.0, 2, True], "s": "", "deeper": {"k": -3.5}}, "u": {"w": 0.1}}
    assert tomllib.loads(dump_toml(data, header="two\nlines")) == data


def test_profile_file_names_differ_per_cell(tmp_path):
    base = grid.load_base_profile(radio_profile_path("ideal"))
    paths = {grid.write_cell_profile(base, lat, loss, tmp_path) for lat in (0.0, 10.0, 100.0) for loss in (0.0, 10.0)}
    assert len(paths) == 6


def test_base_without_the_swept_fields_is_a_config_error(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('schema_version = 1\nname = "bad"\nsource = "test"\n[latency]\njitter_s = 0.0\n')
    with pytest.raises(ConfigError, match="base_s"):
        grid.load_base_profile(bad)


# ------------------------------------------------------------------------------------------ survival rule


@pytest.mark.parametrize("outcomes, expected", [
    ({0.0: True, 10.0: True, 20.0: True}, 20.0),  # all survive: the largest
    ({0.0: True, 10.0: True, 20.0: False, 40.0: True}, 10.0),  # a lucky cell after a failure does not count
    ({0.0: False, 10.0: True}, None),  # fails at the lowest latency: nothing survived
    ({20.0: True, 0.0: True, 10.0: False}, 0.0),  # order of the mapping is irrelevant
    ({0.0: True, 10.0: None, 20.0: True}, 0.0),  # a cell not flown is not survived
    ({}, None),
])
def test_largest_survived_latency(outcomes, expected):
    assert table.largest_survived_latency(outcomes) == expected


def _result(mode: str, lat: float, loss: float, ok: bool) -> table.CellResult:
    return table.CellResult(grid.Cell(mode, lat, loss), success=ok, result="reached_goal" if ok else "failsafe",
                            reached_goal=ok, max_tracking_error_m=0.05 if ok else None, exit_code=0 if ok else 1)


def test_survival_lines_on_a_synthetic_table():
    opts = cli.parse_options(["--latency", "0,20,40,60", "--loss", "0,20,50"])
    outcomes = {  # moments: 0 % loss survives to 40 (60 fails); 20 %: 20 fails, 40 ok again -> 0
        ("moments", 0.0, 0.0): True, ("moments", 20.0, 0.0): True, ("moments", 40.0, 0.0): True,
        ("moments", 60.0, 0.0): False,
        ("moments", 0.0, 20.0): True, ("moments", 20.0, 20.0): False, ("moments", 40.0, 20.0): True,
        ("moments", 60.0, 20.0): False,
        # attitude: everything survives at 0 %; at 20 % the lowest fails
        **{("attitude", lat, 0.0): True for lat in (0.0, 20.0, 40.0, 60.0)},
        **{("attitude", lat, 20.0): lat > 0 for lat in (0.0, 20.0, 40.0, 60.0)},
    }
    results = {key: _result(*key, ok) for key, ok in outcomes.items()}
    lines = table.survival_lines(results, opts)
    assert lines == ["survived latency, moments mode: 40 ms at 0% loss, 0 ms at 20% loss",
                     "survived latency, attitude mode: 60 ms at 0% loss, none at 20% loss"]
    text = table.table_text(results, opts)
    assert text.count("X failsafe") == sum(not ok for ok in outcomes.values())
    not_flown_rows = [line.split()[2:] for line in text.splitlines() if line.startswith("50 %")]
    assert not_flown_rows == [["-"] * 4, ["-"] * 4]  # both modes' 50 % rows were not flown


def test_survival_says_when_a_report_loss_was_not_swept_or_not_flown():
    opts = cli.parse_options(["--latency", "0,10", "--loss", "0,10", "--mode", "moments"])
    assert table.survival_lines({}, opts) == ["survived latency, moments mode: unknown (not flown) at 0% loss, "
                                              "not swept at 20% loss"]


# ------------------------------------------------------------------------------------------ fly results


CELL = grid.Cell("attitude", 10.0, 20.0)


def test_exit_code_2_aborts_with_flys_last_line():
    with pytest.raises(UserError) as err:
        runner.result_from_fly(CELL, 2, "", "usage: ...\ncfstack fly: error: bad thing\n", 1.0, Path("x"))
    assert "bad thing" in str(err.value) and "attitude 10 ms 20 %" in str(err.value)


def test_a_crash_or_timeout_is_a_failed_cell_not_an_abort():
    crash = runner.result_from_fly(CELL, 1, "", "Traceback...\nZeroDivisionError: boom\n", 3.0, Path("x"))
    assert (crash.success, crash.result, crash.exit_code) == (False, "crash", 1)
    assert "boom" in crash.reason
    killed = runner.result_from_fly(CELL, -9, "", "", 3.0, Path("x"), timed_out=True)
    assert (killed.success, killed.result) == (False, "timeout")
    # stopped at its timeout, fly landed and printed its summary in time: still a timeout, metrics kept
    landed = json.dumps({"result": "aborted", "reached_goal": False, "collided": False, "flight_time_s": 0.4})
    stopped = runner.result_from_fly(CELL, 1, landed, "", 3.0, Path("x"), timed_out=True)
    assert (stopped.success, stopped.result, stopped.flight_time_s) == (False, "timeout", 0.4)
    garbage = runner.result_from_fly(CELL, 0, "not json", "", 3.0, Path("x"))
    assert not garbage.success


def test_success_needs_the_goal_and_no_collision():
    base = {"result": "reached_goal", "reached_goal": True, "collided": False, "max_tracking_error_m": 0.1,
            "rms_tracking_error_m": 0.05, "min_clearance_m": 0.2, "flight_time_s": 9.0, "failsafe_reason": None}
    ok = runner.result_from_fly(CELL, 0, json.dumps(base), "", 5.0, Path("x"))
    assert ok.success and ok.max_tracking_error_m == 0.1 and ok.min_clearance_m == 0.2
    hit = runner.result_from_fly(CELL, 0, json.dumps({**base, "collided": True}), "", 5.0, Path("x"))
    assert not hit.success
    failsafe = runner.result_from_fly(CELL, 1, json.dumps({**base, "result": "failsafe", "reached_goal": False,
                                                          "failsafe_reason": "mocap lost"}), "", 5.0, Path("x"))
    assert not failsafe.success and failsafe.reason == "mocap lost"


def test_csv_round_trip(tmp_path):
    results = [_result("moments", 10.0, 0.0, True), _result("attitude", 2.5, 50.0, False),
               _result("moments", 0.0, 0.0, True)]
    path = tmp_path / "sweep.csv"
    table.write_csv(path, results, ("moments", "attitude"))
    back = table.read_csv(path)
    assert [r.cell.key for r in back] == [("moments", 0.0, 0.0), ("moments", 10.0, 0.0), ("attitude", 2.5, 50.0)]
    assert {r.cell.key: r for r in back} == {r.cell.key: r for r in results}


def test_a_foreign_csv_is_refused(tmp_path):
    path = tmp_path / "sweep.csv"
    path.write_text("a,b\n1,2\n")
    with pytest.raises(UserError, match="not a sweep table"):
        table.read_csv(path)


def test_progress_line():
    assert cli.progress_line(0, 4, 0.0, None, width=8) == "[........] 0/4 cells  elapsed 0:00  ETA --:--"
    assert cli.progress_line(2, 4, 75.0, 75.0, width=8) == "[####....] 2/4 cells  elapsed 1:15  ETA 1:15"
    assert cli.progress_line(4, 4, 3725.0, 0.0, width=8).endswith("elapsed 1:02:05  ETA 0:00")


# ------------------------------------------------------------------------------------------ real flights


def test_tiny_real_sweep_then_resume(tmp_path, capsys):
    """Two hover cells in attitude mode: a perfect radio (must succeed) and 2 s one-way (must fail)."""
    out = tmp_path / "sweep"
    argv = ["sweep", "--mode", "attitude", "--latency", "0,2000", "--loss", "0", "--jobs", "2", "--out", str(out)]
    assert cfstack_main(argv) == 0
    stdout = capsys.readouterr().out
    with (out / "sweep.csv").open(newline="") as f:
        rows = {float(r["latency_ms"]): r for r in csv.DictReader(f)}
    assert set(rows) == {0.0, 2000.0}
    assert rows[0.0]["success"] == "true" and rows[0.0]["result"] == "reached_goal"
    assert rows[2000.0]["success"] == "false" and rows[2000.0]["result"] != "reached_goal"
    for row in rows.values():
        assert row["mode"] == "attitude" and row["loss_pct"] == "0"
        assert (Path(row["log_dir"]) / "fly_stdout.json").is_file()
        assert Path(row["log_dir"]).parent == out / "cells"
    assert 0.0 < float(rows[0.0]["max_tracking_error_m"]) < 0.1  # a hover on a perfect radio: mm-level
    assert (out / "sweep.png").read_bytes().startswith(PNG_MAGIC)
    assert "survived latency, attitude mode: 0 ms at 0% loss, not swept at 20% loss" in stdout
    profiles = sorted((out / "profiles").glob("*.toml"))
    assert [load_radio_profile(p).base_latency_s for p in profiles] == [0.0, 2.0]

    # --resume: every cell is in the table, so nothing is flown again and the table is unchanged
    before = (out / "sweep.csv").read_text()
    assert cfstack_main([*argv, "--resume"]) == 0
    assert (out / "sweep.csv").read_text() == before
    assert "survived latency, attitude mode: 0 ms at 0% loss" in capsys.readouterr().out

    # --resume with other settings is refused rather than mixing two experiments in one table
    assert cfstack_main([*argv, "--resume", "--seed", "7"]) == 2
    assert "seed" in capsys.readouterr().err


def test_bad_fly_argument_aborts_the_sweep_with_one_line(tmp_path, capsys):
    out = tmp_path / "sweep"
    code = cfstack_main(["sweep", "--mode", "attitude", "--latency", "0", "--loss", "0", "--out", str(out),
                         "--extra", "--trajectory no-such-trajectory"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert err[-1].startswith("cfstack sweep: cell attitude 0 ms 0 %:") and "no-such-trajectory" in err[-1]


def test_base_profile_is_read_without_importing_the_simulator():
    """House rule: the ground station finds the shipped profile as data, never by importing simulator/."""
    import subprocess
    import sys

    code = ("import sys; from groundstation.sweep import grid; from model.radio import radio_profile_path; "
            "p = radio_profile_path('lab'); "
            "grid.load_base_profile(p); print(p.name, 'simulator' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["lab.toml", "False"]
    assert Params.load(radio_profile_path("lab")).string("name") == "lab"


def _started_flights(monkeypatch) -> list:
    """Record every fly child the sweep starts."""
    flights, start = [], runner._Flight.start

    def recording_start(*args):
        flights.append(start(*args))
        return flights[-1]

    monkeypatch.setattr(runner._Flight, "start", staticmethod(recording_start))
    return flights


def _one_cell(tmp_path, *extra: str) -> tuple[grid.SweepOptions, list]:
    opts = cli.parse_options(["--mode", "attitude", "--latency", "0", "--loss", "0", "--out", str(tmp_path),
                                *extra])
    base = grid.load_base_profile(radio_profile_path("ideal"))
    cell = grid.grid_cells(opts)[0]
    return opts, [(cell, grid.write_cell_profile(base, 0.0, 0.0, tmp_path / "profiles"))]


def test_a_flight_past_its_timeout_is_stopped_and_is_a_failed_cell(tmp_path, monkeypatch):
    flights = _started_flights(monkeypatch)
    opts, todo = _one_cell(tmp_path, "--timeout", "1")
    done: list[table.CellResult] = []
    runner.run_cells(opts, todo, done.append)
    assert [(r.success, r.result) for r in done] == [(False, "timeout")]
    assert len(flights) == 1 and flights[0].proc.poll() is not None


def test_ctrl_c_stops_the_running_flights(tmp_path, monkeypatch):
    flights = _started_flights(monkeypatch)
    opts, todo = _one_cell(tmp_path)

    def interrupt():
        raise KeyboardInterrupt

    done: list[table.CellResult] = []
    with pytest.raises(KeyboardInterrupt):
        runner.run_cells(opts, todo, done.append, on_tick=interrupt)
    assert done == [] and len(flights) == 1
    assert flights[0].proc.poll() is not None  # stopped, not orphaned


def test_ctrl_c_still_writes_what_was_done(tmp_path, monkeypatch, capsys):
    """The command keeps the finished cells (CSV, PNG, table) and exits 130 to ask for --resume."""
    def one_cell_then_ctrl_c(opts, todo, on_done, on_tick):
        cell, _ = todo[0]
        on_done(_result(cell.mode, cell.latency_ms, cell.loss_pct, True))
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "run_cells", one_cell_then_ctrl_c)
    out = tmp_path / "sweep"
    code = cfstack_main(["sweep", "--mode", "moments", "--latency", "0,10", "--loss", "0", "--out", str(out)])
    captured = capsys.readouterr()
    assert code == 130 and "--resume" in captured.err
    assert [r.cell.key for r in table.read_csv(out / "sweep.csv")] == [("moments", 0.0, 0.0)]
    assert (out / "sweep.png").read_bytes().startswith(PNG_MAGIC)
    assert "survived latency, moments mode: 0 ms at 0% loss" in captured.out
