"""Tests of `cfstack sweep` (groundstation/sweep/): options, axes and seeds, generated radio profiles (checked
by the simulator's own loader and radio), the survival rule, aggregates over seeds, the CSV/Parquet table,
fly-result classification, and real sweeps on dask.distributed: a 2-worker LocalCluster with --resume, a
scheduler and a worker started as users start them (`dask scheduler`, `dask worker`), and a worker killed
mid-sweep.

Real flights are hovers whose outcome is certain by physics: a perfect radio (the hover succeeds) and a
2 s one-way delay (a 4 s round trip: no vehicle can be armed and stabilised through that).
"""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import socket
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from distributed import wait
from testsupport import free_port

from cfstack.cli import main as cfstack_main
from groundstation.sweep import cell_task, cli, grid, runner, table
from model.config import Params, dump_toml
from model.errors import ConfigError, UserError
from model.radio import load_radio_profile, radio_profile_path

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
# The flights of the real sweeps: short hovers on the ideal vehicle (the fastest lockstep flight).
HOVER = ("--firmware", "ideal", "--mode", "attitude", "--extra", "--trajectory hover")
GRID = ("--latency", "0,2000", "--loss", "0", "--seeds", "2", *HOVER)
SAME_ROW_COLUMNS = [c for c in table.COLUMNS if c not in ("wall_time_s", "worker", "log_dir", "attempts",
                                                           "worker_lost")]


def _opts(*extra: str) -> grid.SweepOptions:
    return cli.parse_options(["--latency", "0,10", "--loss", "0", *extra])


def _bases(opts: grid.SweepOptions) -> dict:
    return {r: grid.load_base_profile(r) for r in opts.radios}


# ------------------------------------------------------------------------------------------ options


def test_lists_are_parsed_sorted_and_distinct_and_defaults():
    opts = cli.parse_options(["--latency", "40, 0,10", "--latency", "10,2.5", "--loss", "50,0,20"])
    assert opts.latencies_ms == (0.0, 2.5, 10.0, 40.0)
    assert opts.losses_pct == (0.0, 20.0, 50.0)
    assert opts.modes == ("moments", "attitude")
    assert opts.radios == ("ideal",) and opts.seeds == (1,) and opts.worlds == (None,)
    assert opts.jitters_ms is None and opts.bursts_frames is None
    assert opts.jobs >= 1 and opts.scheduler is None


def test_seeds_and_repeated_axes():
    opts = cli.parse_options(["--seed", "5", "--seeds", "3", "--radio", "lab", "--radio", "harsh", "--radio", "lab",
                              "--vehicle-draw", "lab", "--controller", "full", "--controller", "report"])
    assert opts.seeds == (5, 6, 7)
    assert opts.radios == ("lab", "harsh")
    assert opts.vehicle_draws == ("lab",) and opts.controllers == ("full", "report")


def test_extra_arguments_are_split_like_a_shell_even_when_they_look_like_options():
    opts = _opts("--extra", "--from-ground", "--extra", "--trajectory 'constant-speed' --speed=0.5")
    assert opts.extra == ("--from-ground", "--trajectory", "constant-speed", "--speed=0.5")
    job = cli._jobs(opts, grid.grid_cells(opts, _bases(opts))[:1], _bases(opts))[0]
    argv = cell_task.fly_argv(job, Path("cell"))
    assert argv[-4:] == list(opts.extra)
    assert argv[argv.index("--seed") + 1] == "1" and argv[argv.index("--radio") + 1] == str(Path("cell/radio.toml"))


@pytest.mark.parametrize("argv, fragment", [
    (["--latency", "", "--loss", "0"], "empty entry"),
    (["--latency", "0,,10", "--loss", "0"], "empty entry"),
    (["--latency", "-10", "--loss", "0"], ">= 0"),
    (["--latency", "nan", "--loss", "0"], "finite"),
    (["--latency", "ten", "--loss", "0"], "not a number"),
    (["--latency", "0", "--loss", "101"], "maximum 100"),
    (["--burst", "0.5"], "--burst"),
    (["--jitter", "-1"], ">= 0"),
    (["--seeds", "0"], "--seeds"),
    (["--jobs", "0"], "--jobs"),
    (["--seed", "-1"], "--seed"),
    (["--timeout", "0"], "--timeout"),
    (["--mode", "rates"], "invalid choice"),
    (["--controller", "mine"], "one of report, full or a user controller file"),
    (["--controller", "/no/such/se3_control.py"], "no such file"),
    (["--extra", "--radio lab"], "--radio is set by the sweep"),
    (["--extra", "--seed=3"], "--seed is set by the sweep"),
    (["--extra", "--controller full"], "--controller is set by the sweep"),
    (["--extra", "'unclosed"], "--extra"),
    (["/nonexistent/world.json"], "world.json"),
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
        grid.load_base_profile("/nonexistent/radio.toml")


def test_unreachable_scheduler_is_one_line(tmp_path, capsys):
    port = free_port()
    code = cfstack_main(["sweep", "--latency", "0", "--loss", "0", "--mode", "moments", "--out", str(tmp_path),
                         "--scheduler", f"tcp://127.0.0.1:{port}", "--timeout", "5"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and err[-1].startswith("cfstack sweep: --scheduler") and "dask scheduler" in err[-1]


# ------------------------------------------------------------------------------------------ grid and profiles


def test_grid_is_the_product_of_the_axes_with_seeds_innermost():
    opts = cli.parse_options(["--latency", "0,10", "--loss", "0,5", "--jitter", "0,2", "--burst", "1,4",
                              "--mode", "moments", "--seeds", "3", "--vehicle-draw", "nominal",
                              "--vehicle-draw", "lab"])
    cells = grid.grid_cells(opts, _bases(opts))
    assert len(cells) == 2 * 2 * 2 * 2 * 2 * 3
    assert len({c.key for c in cells}) == len(cells) and len({c.slug for c in cells}) == len(cells)
    assert [c.seed for c in cells[:3]] == [1, 2, 3]


def test_unswept_radio_axes_take_each_base_profiles_values():
    opts = cli.parse_options(["--radio", "lab", "--radio", "ideal", "--mode", "moments"])
    cells = {c.radio: c for c in grid.grid_cells(opts, _bases(opts))}
    lab = load_radio_profile("lab")
    assert cells["lab"].latency_ms == pytest.approx(lab.base_latency_s * 1000.0)
    assert cells["lab"].jitter_ms == pytest.approx(lab.jitter_s * 1000.0)
    assert cells["lab"].loss_pct == pytest.approx(lab.loss_probability * 100.0)
    assert cells["ideal"].latency_ms == 0.0 and cells["ideal"].loss_pct == 0.0
    # nothing swept: the generated profile is the base's, field for field
    generated = _generated(opts, cells["lab"])
    assert dataclasses.replace(generated, name=lab.name, source=lab.source, path=lab.path) == lab


def _generated(opts, cell, folder: Path | None = None):
    folder = folder or Path(os.environ.get("TMPDIR", "/tmp"))
    path = folder / f"cfstack-test-{cell.slug}-{os.getpid()}.toml"
    path.write_text(grid.cell_profile_text(_bases(opts)[cell.radio], cell, opts))
    try:
        return load_radio_profile(path)
    finally:
        path.unlink()


@pytest.mark.parametrize("base_name", ["ideal", "crazyradio", "lab"])
@pytest.mark.parametrize("latency_ms, loss_pct", [(0.0, 0.0), (40.0, 20.0), (2.5, 100.0)])
def test_generated_profile_changes_only_latency_and_iid_loss(tmp_path, base_name, latency_ms, loss_pct):
    opts = cli.parse_options(["--latency", str(latency_ms), "--loss", str(loss_pct), "--radio", base_name,
                              "--mode", "moments"])
    generated = _generated(opts, grid.grid_cells(opts, _bases(opts))[0], tmp_path)
    original = load_radio_profile(base_name)
    assert generated.base_latency_s == pytest.approx(latency_ms * 1e-3, abs=0.0, rel=1e-15)
    assert generated.loss_probability == pytest.approx(loss_pct * 1e-2, abs=0.0, rel=1e-15)
    assert not generated.burst.enabled
    expected = dataclasses.replace(original, base_latency_s=generated.base_latency_s,
                                   loss_probability=generated.loss_probability, burst=generated.burst,
                                   name=generated.name, source=generated.source, path=generated.path)
    assert generated == expected
    assert base_name in generated.name and base_name in generated.source


def test_burst_axis_keeps_the_average_loss_and_gives_the_mean_burst_length(tmp_path):
    """Fed through the simulator's own radio: 10 % loss in bursts of mean 5 frames loses ~10 % of the frames,
    in runs of mean length ~5 (i.i.d. 10 % loss would give runs of mean 1 / 0.9 = 1.11)."""
    from simulator.radio import RadioChannel

    opts = cli.parse_options(["--loss", "10", "--burst", "1,5", "--mode", "moments"])
    measured = {}
    for cell in grid.grid_cells(opts, _bases(opts)):
        channel = RadioChannel(_generated(opts, cell, tmp_path), np.random.default_rng(3))
        n = 100_000
        for i in range(n):
            channel.push(bytes(20), i * 0.002)
            channel.pop_due(i * 0.002)
        lost = np.array([fate.drop_cause is not None for fate in channel.ledger])
        edges = np.flatnonzero(np.diff(np.concatenate([[0], lost.astype(int), [0]])))
        measured[cell.burst_frames] = (lost.mean(), float(np.mean(edges[1::2] - edges[0::2])))
    assert measured[1.0][0] == pytest.approx(0.10, abs=0.005) and measured[1.0][1] == pytest.approx(1 / 0.9, rel=0.05)
    assert measured[5.0][0] == pytest.approx(0.10, abs=0.01) and measured[5.0][1] == pytest.approx(5.0, rel=0.08)


def test_a_bursty_base_keeps_its_mean_burst_when_only_the_loss_is_swept(tmp_path):
    harsh = load_radio_profile("harsh")
    opts = cli.parse_options(["--loss", "20", "--radio", "harsh", "--mode", "moments"])
    cell = grid.grid_cells(opts, _bases(opts))[0]
    assert cell.burst_frames == pytest.approx(1.0 / harsh.burst.p_bad_to_good)
    generated = _generated(opts, cell, tmp_path)
    assert generated.burst.p_bad_to_good == pytest.approx(harsh.burst.p_bad_to_good)
    assert generated.burst.stationary_bad * generated.burst.loss_bad == pytest.approx(0.20)
    assert generated.loss_probability == 0.0


def test_jitter_axis_sets_the_profiles_jitter(tmp_path):
    opts = cli.parse_options(["--latency", "20", "--jitter", "3", "--radio", "lab", "--mode", "moments"])
    generated = _generated(opts, grid.grid_cells(opts, _bases(opts))[0], tmp_path)
    assert generated.jitter_s == pytest.approx(0.003) and generated.jitter == load_radio_profile("lab").jitter


def test_toml_writer_round_trips_nested_tables_and_awkward_strings():
    data = {"schema_version": 1, "name": 'a "quoted"\\ name\nwith ünïcode\ttab', "x": 1e-05, "flag": False,
            "t": {"v": [1.0, 2, True], "s": "", "deeper": {"k": -3.5}}, "u": {"w": 0.1}}
    assert tomllib.loads(dump_toml(data, header="two\nlines")) == data


def test_base_without_the_swept_fields_is_a_config_error(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('schema_version = 1\nname = "bad"\nsource = "test"\n[latency]\njitter_s = 0.0\n')
    with pytest.raises(ConfigError, match="base_s"):
        grid.load_base_profile(str(bad))


def test_base_profile_is_read_without_importing_the_simulator():
    """House rule: the ground station finds the shipped profile as data, never by importing simulator/."""
    code = ("import sys; from groundstation.sweep import grid, runner; grid.load_base_profile('lab'); "
            "print('simulator' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["False"]
    assert Params.load(radio_profile_path("lab")).string("name") == "lab"


# ------------------------------------------------------------------------------------------ rows and tables


def _row(latency: float, loss: float, ok: bool, seed: int = 1, mode: str = "moments", error: float | None = 0.05,
         status: str = "flown") -> dict:
    cell = grid.Cell("", mode, "ideal", latency, 0.0, loss, 1.0, "", "nominal", seed)
    measured = {"cell_status": status, "success": ok, "result": "reached_goal" if ok else "failsafe",
                "reached_goal": ok, "max_tracking_error_m": error if ok else None, "exit_code": 0 if ok else 1,
                "uplink_delivery": 0.99, "wall_time_s": 3.5, "worker": "host", "log_dir": "/x"}
    return table.make_row(cell, measured, attempts=1, worker_lost=False)


@pytest.mark.parametrize("outcomes, expected", [
    ({0.0: True, 10.0: True, 20.0: True}, 20.0),
    ({0.0: True, 10.0: False, 20.0: True}, 0.0),  # a lucky cell past a failure does not count
    ({0.0: False, 10.0: True}, None),
    ({0.0: True, 10.0: None, 20.0: True}, 0.0),  # not flown is not survived
])
def test_largest_survived_latency(outcomes, expected):
    assert table.largest_survived_latency(outcomes) == expected


def test_survival_needs_every_seed():
    rows = [_row(0, 0, True, 1), _row(0, 0, True, 2), _row(20, 0, True, 1), _row(20, 0, False, 2),
            _row(0, 20, True, 1), _row(0, 20, True, 2)]
    lines = table.survival_lines(rows)
    assert lines == ["survived latency, moments mode: 0 ms at 0% loss, 0 ms at 20% loss"]


def test_aggregate_is_the_success_rate_and_the_sample_spread_over_seeds():
    rows = [_row(0, 0, True, s, error=e) for s, e in ((1, 0.01), (2, 0.03), (3, 0.05))] + [_row(0, 0, False, 4)]
    agg = table.aggregate(rows)[table.cell_key(rows[0])]
    assert agg["flights"] == 4 and agg["successes"] == 3 and agg["success_rate"] == 0.75
    assert agg["max_error_median_m"] == pytest.approx(0.03)
    assert agg["max_error_spread_m"] == pytest.approx(0.02)  # sample std of 0.01, 0.03, 0.05
    assert "3/4 0.030+-0.020" in table.table_text(rows)


def test_csv_and_parquet_hold_the_same_rows_and_read_back(tmp_path):
    rows = [_row(10, 0, True, 2), _row(0, 0, False, 1), _row(0, 5, True, 1, error=0.125)]
    path = tmp_path / "sweep.csv"
    table.write_tables(path, rows)
    back = table.read_csv(path)
    assert sorted(back, key=table.cell_key) == sorted(rows, key=table.cell_key)
    parquet = pq.read_table(tmp_path / "sweep.parquet").to_pylist()
    assert parquet == back  # the same order, types and values
    assert not list(tmp_path.glob("*.tmp"))


def test_a_foreign_csv_is_refused(tmp_path):
    path = tmp_path / "sweep.csv"
    path.write_text("mode,latency_ms\nmoments,0\n")
    with pytest.raises(UserError, match="columns differ"):
        table.read_csv(path)


def test_outcome_classification():
    summary = {"result": "reached_goal", "reached_goal": True, "collided": False, "max_tracking_error_m": 0.01,
               "link": {"uplink_sent": 100, "uplink_delivered": 99, "downlink_sent": 10, "downlink_delivered": 10}}
    ok = cell_task.outcome_from_fly(0, json.dumps(summary), "", timed_out=False)
    assert ok["success"] and ok["cell_status"] == "flown" and ok["uplink_delivery"] == 0.99
    collided = cell_task.outcome_from_fly(1, json.dumps({**summary, "collided": True}), "", timed_out=False)
    assert not collided["success"] and collided["cell_status"] == "flown"
    crash = cell_task.outcome_from_fly(-9, "", "line one\nTraceback: boom\n", timed_out=False)
    assert crash["cell_status"] == "crash" and crash["reason"] == "Traceback: boom"
    late = cell_task.outcome_from_fly(0, json.dumps(summary), "", timed_out=True)
    assert late["cell_status"] == "wall_timeout" and not late["success"]
    bad = cell_task.outcome_from_fly(2, "", "cfstack fly: --trajectory x: unknown\n", timed_out=False)
    assert bad["cell_status"] == "bad_input" and "--trajectory x" in bad["reason"]


def test_progress_line():
    progress = cli.Progress(done=2, failed=1, retried=1)
    line = cli.progress_line(2, 4, 75.0, 75.0, progress, "http://127.0.0.1:8787/status", width=8)
    assert line == ("[####....] 2/4 flights  failed 1  retried 1  elapsed 1:15  ETA 1:15  "
                    "dashboard http://127.0.0.1:8787/status")


# ------------------------------------------------------------------------------------------ real sweeps


def _sweep(*argv: str, timeout: float = 600.0) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cfstack", "sweep", *argv], capture_output=True, text=True,
                          timeout=timeout, stdin=subprocess.DEVNULL)


def _rows(out: Path) -> dict[tuple, dict]:
    return {table.cell_of(r).key: r for r in table.read_csv(out / "sweep.csv")}


def _check_grid_rows(rows: dict[tuple, dict]) -> None:
    assert len(rows) == 4
    for row in rows.values():
        assert row["cell_status"] == "flown" and row["mode"] == "attitude" and row["seed"] in (1, 2)
        assert row["success"] == (row["latency_ms"] == 0.0)  # physics: 4 s round trip cannot fly
        assert (Path(row["log_dir"]) / "fly_stdout.json").is_file()
    for row in rows.values():
        if row["success"]:
            assert 0.0 < row["max_tracking_error_m"] < 0.1 and row["uplink_delivery"] == 1.0


@pytest.fixture(scope="module")
def local_grid(tmp_path_factory) -> tuple[Path, subprocess.CompletedProcess]:
    """GRID flown once on a 2-worker LocalCluster (shared by the tests that read it)."""
    out = tmp_path_factory.mktemp("local") / "sweep"
    return out, _sweep(*GRID, "--jobs", "2", "--out", str(out))


@pytest.fixture
def local_grid_rows(local_grid) -> dict[tuple, dict]:
    out, done = local_grid
    assert done.returncode == 0, done.stderr
    return _rows(out)


@pytest.mark.slow
def test_local_cluster_grid_with_two_seeds_then_resume_does_nothing(local_grid):
    out, first = local_grid
    assert first.returncode == 0, first.stderr
    assert "on 2 dask workers (LocalCluster)" in first.stderr and "dashboard http" in first.stderr
    assert "failed 2  retried 0" in first.stderr
    rows = _rows(out)
    _check_grid_rows(rows)
    assert (out / "sweep.png").read_bytes().startswith(PNG_MAGIC)
    assert pq.read_table(out / "sweep.parquet").num_rows == 4
    assert "survived latency, attitude mode: 0 ms at 0% loss" in first.stdout
    assert "2/2" in first.stdout and "X 0/2" in first.stdout

    before = (out / "sweep.csv").read_text()
    again = _sweep(*GRID, "--jobs", "2", "--out", str(out), "--resume")  # nothing to fly: no cluster started
    assert again.returncode == 0 and "nothing to fly" in again.stderr
    assert (out / "sweep.csv").read_text() == before
    # each seed is a flight of its own (its noise draws differ), not a copy of seed 1
    errors = sorted(r["max_tracking_error_m"] for r in rows.values() if r["success"])
    assert errors[0] != errors[1]

    # --resume with other fly settings is refused rather than mixing two experiments in one table
    other = _sweep(*GRID, "--out", str(out), "--resume", "--extra", "--speed 0.5")
    assert other.returncode == 2 and "extra" in other.stderr


def _start(argv: list[str], log: Path) -> subprocess.Popen:
    """Start a dask process with its log in a file (an unread pipe would fill and stall it)."""
    with log.open("w") as sink:
        return subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=sink, stderr=subprocess.STDOUT,
                                start_new_session=True)


def _kill(proc: subprocess.Popen) -> None:
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    proc.wait(timeout=30)


def _dask(*args: str) -> list[str]:
    return [str(Path(sys.executable).with_name("dask")), *args]


def _wait_until_listening(proc: subprocess.Popen, port: int, log: Path, timeout_s: float = 120.0) -> None:
    """Wait as a user waits for `Scheduler at:`: until the port accepts (a busy machine takes seconds)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        assert proc.poll() is None, f"dask scheduler exited: {log.read_text()[-2000:]}"
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1.0).close()
            return
        except OSError:
            time.sleep(0.2)
    raise AssertionError(f"dask scheduler not listening after {timeout_s} s: {log.read_text()[-2000:]}")


@pytest.fixture
def dask_cluster(tmp_path):
    """A scheduler and workers started as the README starts them; yields (address, start_worker)."""
    port = free_port()
    address = f"tcp://127.0.0.1:{port}"
    scheduler_log = tmp_path / "scheduler.log"
    procs = [_start(_dask("scheduler", "--host", "127.0.0.1", "--port", str(port), "--dashboard-address", ":0"),
                    scheduler_log)]

    def start_worker() -> subprocess.Popen:
        procs.append(_start(_dask("worker", address, "--nworkers", "1", "--nthreads", "1", "--no-dashboard"),
                            tmp_path / f"worker{len(procs)}.log"))
        return procs[-1]

    try:
        _wait_until_listening(procs[0], port, scheduler_log)
        yield address, start_worker
    finally:
        for proc in reversed(procs):
            _kill(proc)


@pytest.mark.slow
def test_separately_started_scheduler_and_worker_give_the_same_rows(tmp_path, dask_cluster, local_grid_rows):
    """The grid of the LocalCluster test, flown by `dask scheduler` + `dask worker`: the same rows."""
    address, start_worker = dask_cluster
    start_worker()
    remote = tmp_path / "remote"
    done = _sweep(*GRID, "--scheduler", address, "--out", str(remote))
    assert done.returncode == 0, done.stderr
    assert f"at {address}" in done.stderr
    remote_rows = _rows(remote)
    _check_grid_rows(remote_rows)
    assert remote_rows.keys() == local_grid_rows.keys()
    for key, row in remote_rows.items():
        assert {c: row[c] for c in SAME_ROW_COLUMNS} == {c: local_grid_rows[key][c] for c in SAME_ROW_COLUMNS}


@pytest.mark.slow
def test_killing_a_worker_mid_sweep_loses_no_finished_row(tmp_path, dask_cluster):
    address, start_worker = dask_cluster
    start_worker()
    victim = start_worker()
    out = tmp_path / "sweep"
    sweep = subprocess.Popen([sys.executable, "-m", "cfstack", "sweep", *HOVER, "--latency", "0", "--loss", "0",
                              "--seeds", "4", "--scheduler", address, "--out", str(out)],
                             stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 300
    while not (out / "sweep.csv").is_file() or not table.read_csv(out / "sweep.csv"):
        assert sweep.poll() is None and time.monotonic() < deadline, "no flight finished"
        time.sleep(0.2)
    finished_before = _rows(out)
    time.sleep(1.0)  # the client has seen which worker flies what
    _kill(victim)
    stdout, stderr = sweep.communicate(timeout=600)
    assert sweep.returncode == 0, stderr
    rows = _rows(out)
    for key, row in finished_before.items():
        assert rows[key] == row  # nothing finished was lost or rewritten
    assert len(rows) == 4 and all(r["cell_status"] == "flown" for r in rows.values())
    assert any(r["worker_lost"] for r in rows.values()), stderr
    assert "lost workers 1" in stderr, stderr
    lost = [r for r in rows.values() if r["worker_lost"]]
    assert all(r["attempts"] == 2 for r in lost)


@pytest.mark.slow
def test_a_worker_dying_after_finishing_a_flight_before_handing_it_over_lost_it(tmp_path, dask_cluster,
                                                                               monkeypatch):
    """The race the test above can meet (it did in CI): the flight finished on the worker, which died before
    the client fetched the result. Dask flies it again on another worker; its row says the worker was lost
    and that it took two flights. The runner waits for a result 0.5 s at a time here, less than a flight
    takes, so the flight is handed back to the run loop while dask flies it again."""
    monkeypatch.setattr(runner, "RESULT_WAIT_S", 0.5)
    address, start_worker = dask_cluster
    victim = start_worker()
    opts = cli.parse_options([*HOVER, "--latency", "0", "--loss", "0", "--scheduler", address,
                              "--out", str(tmp_path / "sweep")])
    bases = _bases(opts)
    (job,) = cli._jobs(opts, grid.grid_cells(opts, bases), bases)
    dask = runner.DaskRunner(opts)
    try:
        flight = runner._Flight(job, dask._submit(job))
        wait(flight.future, timeout=300)  # flown on the victim, the only worker; the client has not fetched it
        start_worker()
        dask.client.wait_for_workers(2, timeout=60)
        _kill(victim)
        rows, progress = [], runner.Progress()
        handed_back = 0
        while (again := dask._finish(flight, rows.append, progress)) is not None:
            assert again is flight  # not finished after all: watched again, never retried by us
            handed_back += 1
            wait(flight.future, timeout=300)  # the run loop finishes it again once it is done
    finally:
        dask.close()
    assert handed_back >= 1
    (row,) = rows
    assert row["cell_status"] == "flown" and row["success"]
    assert row["worker_lost"] and row["attempts"] == 2
    assert progress.lost_workers == 1 and progress.done == 1 and progress.retried == 0


@pytest.mark.slow
def test_ctrl_c_leaves_a_consistent_table_and_resume_finishes(tmp_path):
    out = tmp_path / "sweep"
    argv = [*HOVER, "--latency", "0", "--loss", "0", "--seeds", "3", "--jobs", "1", "--out", str(out)]
    sweep = subprocess.Popen([sys.executable, "-m", "cfstack", "sweep", *argv], stdin=subprocess.DEVNULL,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 300
    while not (out / "sweep.csv").is_file() or not table.read_csv(out / "sweep.csv"):
        assert sweep.poll() is None and time.monotonic() < deadline, "no flight finished"
        time.sleep(0.2)
    sweep.send_signal(signal.SIGINT)
    stdout, stderr = sweep.communicate(timeout=120)
    assert sweep.returncode == 130, stderr
    assert "--resume" in stderr
    partial = _rows(out)
    assert 1 <= len(partial) < 3
    assert pq.read_table(out / "sweep.parquet").num_rows == len(partial)
    finished = _sweep(*argv, "--resume")
    assert finished.returncode == 0, finished.stderr
    rows = _rows(out)
    assert len(rows) == 3 and all(rows[k] == v for k, v in partial.items())


def test_bad_fly_argument_aborts_the_sweep_with_one_line(tmp_path):
    out = tmp_path / "sweep"
    done = _sweep("--mode", "attitude", "--latency", "0", "--loss", "0", "--out", str(out), "--jobs", "1",
                  "--extra", "--trajectory no-such-trajectory")
    err = done.stderr.strip().splitlines()
    assert done.returncode == 2
    assert err[-1].startswith("cfstack sweep: cell empty attitude ideal 0 ms") and "no-such-trajectory" in err[-1]


def test_a_flight_past_its_timeout_is_stopped_retried_once_and_recorded(tmp_path):
    out = tmp_path / "sweep"
    done = _sweep(*HOVER, "--latency", "0", "--loss", "0", "--timeout", "1", "--jobs", "1", "--out", str(out))
    assert done.returncode == 0, done.stderr
    (row,) = _rows(out).values()
    assert row["cell_status"] == "wall_timeout" and row["attempts"] == 2 and not row["success"]
    assert "retried 1" in done.stderr
    # the stopped flights left no process behind: fly's emulator died with it
    leftovers = subprocess.run(["pgrep", "-f", str(out)], capture_output=True, text=True).stdout.split()
    assert leftovers == []
