"""Users' course-style code (issue 17): the loader and the course's import environment, the compat modules
against the course's definitions, the adapters' handling of what real student code returns, bad code,
and whole flights of student-style code written by us (tests/groundstation/student_code) through the CLI
and the API over the lab radio, reaching the goal of a lab maze and a course maze."""

from __future__ import annotations

import csv
import json
import logging
import math
import subprocess
import sys
import textwrap
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
from testsupport import SHARED_WORLDS, cfstack, shared_world

from groundstation.controller import ControllerState, SE3Controller, load_gains
from groundstation.logread import read_log
from groundstation.planning.astar import plan_path
from groundstation.trajectory import FlatOutput
from groundstation.usercode import loader
from groundstation.usercode.adapters import (
    UserController,
    UserTrajectory,
    _path_and_nodes,
    load_usercode_settings,
    plus_mixer,
)
from groundstation.usercode.guard import Guard
from groundstation.usercode.quad_params import quad_params_of
from model.errors import UserError
from model.vehicle import load_vehicle
from model.world import load_world

STUDENTS = Path(__file__).parent / "student_code"
# The course's flightsim/crazyflie_params.py (../shared/reference/course_controller_interface.md, section 1)
COURSE_QUAD_PARAMS = {"mass": 0.03, "Ixx": 1.43e-5, "Iyy": 1.43e-5, "Izz": 2.89e-5, "arm_length": 0.046,
                      "rotor_speed_min": 0, "rotor_speed_max": 2500, "k_thrust": 2.3e-08, "k_drag": 7.8e-11}


# --- the course's definitions -------------------------------------------------------------------------
def test_quad_params_of_the_course_vehicle_are_the_courses():
    params = quad_params_of(load_vehicle("crazyflie"))
    assert params.keys() == COURSE_QUAD_PARAMS.keys()
    for key, value in COURSE_QUAD_PARAMS.items():
        assert params[key] == pytest.approx(value, rel=1e-9), key


def test_plus_mixer_is_the_courses_to_TM_matrix():
    p = COURSE_QUAD_PARAMS
    arm, k = p["arm_length"], p["k_drag"] / p["k_thrust"]
    to_tm = np.array([[1, 1, 1, 1], [0, arm, 0, -arm], [-arm, 0, arm, 0], [k, -k, k, -k]])
    rng = np.random.default_rng(3)
    for _ in range(20):
        speeds = rng.uniform(0, 2500, 4)
        thrust, moment = plus_mixer(p, speeds)
        expected = to_tm @ (p["k_thrust"] * speeds**2)
        assert thrust == pytest.approx(expected[0]) and moment == pytest.approx(expected[1:])
    # clipped to the rotor speed limits first, as Quadrotor.step does
    thrust, _ = plus_mixer(p, np.array([3000.0, 3000.0, -10.0, 0.0]))
    assert thrust == pytest.approx(2 * p["k_thrust"] * 2500.0**2)


# --- loading unchanged files ----------------------------------------------------------------------------
def test_absolute_relative_and_flat_imports_resolve(tmp_path):
    a = loader.load(str(STUDENTS / "student_a"), "trajectory")  # from proj1_3.code.graph_search import ...
    assert a.name == "WorldTraj" and a.file == (STUDENTS / "student_a" / "world_traj.py").resolve()
    assert Path(a.obj.__init__.__globals__["graph_search"].__code__.co_filename).parent.name == "student_a"
    # student_b has no graph_search.py: its `from .graph_search import` is the course's (ours), never the
    # student_a one loaded just before in this process
    b = loader.load(str(STUDENTS / "student_b" / "world_traj.py"), "trajectory")
    b_search = b.obj.__init__.__globals__["graph_search"]
    assert Path(b_search.__code__.co_filename).parent == loader.COURSE_CODE
    flat = tmp_path / "flat_style"
    flat.mkdir()
    (flat / "my_traj.py").write_text(textwrap.dedent("""
        from graph_search import graph_search
        from occupancy_map import OccupancyMap
        from flightsim.world import World
        from flightsim.crazyflie_params import quad_params

        class Mine:
            def __init__(self, world, start, goal):
                self.mass = quad_params['mass']
                self.found = graph_search(world, 0.2, 0.2, start, goal, astar=True)
    """))
    mine = loader.load(f"{flat / 'my_traj.py'}:Mine", "trajectory")
    assert mine.name == "Mine"


def test_two_users_files_of_one_name_each_load_their_own():
    a = loader.load(str(STUDENTS / "student_a"), "controller")
    c = loader.load(str(STUDENTS / "motor_speeds_only"), "controller")
    assert a.obj is not c.obj
    assert Path(sys.modules[c.obj.__module__].__file__).parent.name == "motor_speeds_only"


@pytest.mark.parametrize(("spec", "fragment"), [
    ("nowhere/se3_control.py", "no such file"),
    (f"{STUDENTS / 'student_a' / 'se3_control.py'}:Missing", "has no Missing"),
])
def test_bad_specs_are_one_line(spec, fragment):
    with pytest.raises(UserError) as err:
        loader.load(spec, "controller")
    assert fragment in str(err.value) and "\n" not in str(err.value)


def test_a_file_that_fails_to_import_names_file_and_line(tmp_path):
    bad = tmp_path / "syntax_error.py"
    bad.write_text("class SE3Control:\n    def update(self, t\n")
    with pytest.raises(UserError) as err:
        loader.load(str(bad), "controller")
    assert "syntax_error.py" in str(err.value) and "SyntaxError" in str(err.value) and ":2)" in str(err.value)


# --- compat modules against cfstack's world and grid ----------------------------------------------------
def test_occupancy_map_and_world_follow_the_course_conventions():
    from groundstation.usercode.compat.course_code.occupancy_map import OccupancyMap
    from groundstation.usercode.compat.flightsim.world import World

    world = World.from_file(shared_world("test_lab_1"))
    assert world.world["start"] == [-1.5, -1.5, 0.9]  # .world is the course's dict
    occ = OccupancyMap(world, [0.1, 0.1, 0.1], 0.1)
    wall_point = np.array([0.0, -0.5, 1.0])  # inside block 1 (x -0.02..0.02, y -1..0)
    free_point = np.array([-1.5, -1.5, 0.9])
    assert occ.is_occupied_metric(wall_point) and not occ.is_occupied_metric(free_point)
    index = occ.metric_to_index(free_point)
    assert occ.is_valid_index(index) and not occ.is_valid_index((-1, 0, 0))
    assert np.all(np.abs(occ.index_to_metric_center(index) - free_point) <= 0.05 + 1e-12)
    assert occ.index_to_metric_negative_corner((0, 0, 0)).tolist() == [-2.0, -2.0, 0.0]
    # a path across the wall collides; one beside it, 0.5 m away, does not at a 0.3 m margin
    hits = world.path_collisions(np.array([[-0.5, -0.5, 1.0], [0.5, -0.5, 1.0]]), 0.3)
    assert len(hits) and np.all(np.abs(hits[:, 0]) <= 0.32 + 1e-9)
    assert len(world.path_collisions(np.array([[-0.5, 0.5, 1.0], [-0.5, 0.6, 1.0]]), 0.3)) == 0


def test_the_default_graph_search_is_cfstacks_astar_in_the_courses_form():
    from groundstation.usercode.compat.course_code.graph_search import graph_search
    from groundstation.usercode.compat.flightsim.world import World

    path_file = shared_world("test_lab_1")
    world = World.from_file(path_file)
    path, nodes = graph_search(world, [0.1, 0.1, 0.1], 0.2, world.world["start"], world.world["goal"], True)
    ours = plan_path(load_world(path_file), [0.1, 0.1, 0.1], 0.2)
    assert path.tolist() == ours.path_m.tolist() and nodes == ours.nodes_expanded
    assert path[0].tolist() == world.world["start"] and path[-1].tolist() == world.world["goal"]


def test_every_graph_search_return_convention_is_taken():
    dense = np.array([[0, 0, 1.0], [0.5, 0, 1], [1, 0, 1]])
    sparse = dense[[0, -1]]
    assert _path_and_nodes(dense, "g")[0].tolist() == dense.tolist()  # 2020: path only
    path, nodes = _path_and_nodes((dense, 42), "g")
    assert path.tolist() == dense.tolist() and nodes == 42
    path, nodes = _path_and_nodes((sparse, dense), "g")  # (sparse_path, dense_path): the dense one
    assert path.tolist() == dense.tolist() and nodes is None
    assert _path_and_nodes((None, 7), "g") == (None, 7)
    with pytest.raises(UserError, match="not an \\(N, 3\\)"):
        _path_and_nodes(np.zeros((3, 2)), "g")


# --- the controller adapter ---------------------------------------------------------------------------
class _Scripted:
    """A controller returning what it is told (what real student code returns), recording its inputs."""

    def __init__(self, output):
        self.output = output
        self.seen = []

    def update(self, t, state, flat_output):
        self.seen.append((t, state, flat_output))
        return self.output() if callable(self.output) else self.output


def _adapter(output, mode="moments", controller_output="commands", timeout_s=2.0, tmp_path=None):
    vehicle = load_vehicle("crazyflie")
    guard = Guard(timeout_s, [Path(__file__).parent])
    fallback = SE3Controller(vehicle, load_gains())
    adapter = UserController(_Scripted(output), "test.py Scripted", vehicle, fallback, mode, controller_output,
                             guard, load_usercode_settings(), tmp_path / "user_commands.csv" if tmp_path else None)
    faults = []
    adapter.on_fault = faults.append
    return adapter, guard, faults


STATE = ControllerState((1.0, 2.0, 3.0), (0.1, 0.0, 0.0), (math.cos(0.1), 0.0, 0.0, math.sin(0.1)),
                        (0.0, 0.0, 0.2))
REF = FlatOutput(np.array([1.0, 2.0, 3.5]), yaw_rad=0.3)


def test_the_state_and_flat_output_are_the_courses_dicts():
    adapter, _, _ = _adapter({"cmd_thrust": 0.3, "cmd_moment": np.zeros(3)})
    adapter.update(STATE, REF, 4.0)
    t, state, flat = adapter.instance.seen[0]
    assert t == 4.0
    assert state["q"].tolist() == [0.0, 0.0, math.sin(0.1), math.cos(0.1)]  # [i, j, k, w]
    assert state["x"].tolist() == [1.0, 2.0, 3.0] and state["w"].tolist() == [0.0, 0.0, 0.2]
    assert set(flat) == {"x", "x_dot", "x_ddot", "x_dddot", "x_ddddot", "yaw", "yaw_dot"}
    assert flat["x"].tolist() == [1.0, 2.0, 3.5] and flat["yaw"] == 0.3


@pytest.mark.parametrize("shape", [(1,), (1, 1)])
def test_column_and_scalar_shaped_outputs_are_ravelled(shape):
    moment = np.array([1e-4, -2e-4, 3e-5])
    adapter, guard, _ = _adapter({"cmd_thrust": np.full(shape, 0.31), "cmd_moment": moment.reshape(3, 1)})
    out = adapter.update(STATE, REF, 0.0)
    assert guard.fault is None and out.thrust_n == pytest.approx(0.31)
    assert out.moment_flu_nm == pytest.approx(tuple(moment))


def test_cmd_q_is_scalar_last_and_four_rotor_thrusts_are_summed(caplog):
    q_ijkw = np.array([0.0, 0.0, math.sin(0.25), math.cos(0.25)]).reshape(4, 1)
    rotor_thrusts = np.array([0.07, 0.075, 0.08, 0.07]).reshape(4, 1)
    adapter, guard, _ = _adapter({"cmd_thrust": rotor_thrusts, "cmd_moment": np.zeros(3), "cmd_q": q_ijkw},
                                 mode="attitude")
    with caplog.at_level(logging.WARNING, logger="cfstack.usercode"):
        out = adapter.update(STATE, REF, 0.0)
        adapter.update(STATE, REF, 0.01)
    assert out.thrust_n == pytest.approx(0.295)
    assert out.attitude_des_wxyz == pytest.approx((math.cos(0.25), 0.0, 0.0, math.sin(0.25)))
    assert len([r for r in caplog.records if "summed" in r.message]) == 1  # said once, kept as a note
    assert any("summed" in n for n in adapter.summary()["notes"])


def test_motor_speeds_output_flies_the_plus_mixer_and_the_default_warns_on_disagreement(caplog, tmp_path):
    speeds = np.array([1800.0, 1700.0, 1750.0, 1650.0])
    expected_thrust, expected_moment = plus_mixer(COURSE_QUAD_PARAMS, speeds)
    only_speeds = {"cmd_motor_speeds": speeds, "cmd_thrust": 0, "cmd_moment": np.zeros(3), "cmd_q": [0, 0, 0, 1]}
    adapter, guard, _ = _adapter(only_speeds, controller_output="motor_speeds", tmp_path=tmp_path)
    out = adapter.update(STATE, REF, 0.0)
    adapter.close()
    assert out.thrust_n == pytest.approx(expected_thrust)
    assert out.moment_flu_nm == pytest.approx(tuple(expected_moment))
    rows = list(csv.DictReader((tmp_path / "user_commands.csv").open()))
    assert rows[0]["flown"] == "motor_speeds" and float(rows[0]["cmd_motor_speed_2_radps"]) == 1700.0
    with caplog.at_level(logging.WARNING, logger="cfstack.usercode"):
        default, _, _ = _adapter(only_speeds)
        default.update(STATE, REF, 0.0)
        default.update(STATE, REF, 0.002)
    warnings = [r.message for r in caplog.records if "'+' mixer" in r.message]
    assert len(warnings) == 1 and "\n" not in warnings[0]
    consistent = {"cmd_motor_speeds": speeds, "cmd_thrust": expected_thrust, "cmd_moment": expected_moment}
    agreeing, _, _ = _adapter(consistent)
    agreeing.update(STATE, REF, 0.0)
    assert agreeing.disagreement is None


@pytest.mark.parametrize(("output", "problem"), [
    ({"cmd_thrust": 0.3, "cmd_moment": np.array([np.nan, 0, 0])}, "'cmd_moment' is not finite"),
    ({"cmd_thrust": 0.3}, "returned no 'cmd_moment'"),
    ({"cmd_thrust": 0.3, "cmd_moment": np.zeros(2)}, "'cmd_moment' has 2 values"),
    (None, "returned NoneType, not a dict"),
    (lambda: {}["cmd_thrust"], "raised KeyError: 'cmd_thrust'"),
])
def test_bad_outputs_are_one_fault_and_the_fallback_flies(output, problem):
    adapter, guard, faults = _adapter(output)
    out = adapter.update(STATE, REF, 1.25)
    assert len(faults) == 1 and problem in faults[0].problem
    line = faults[0].line()
    assert line.startswith("user code test.py Scripted.update at t=1.250 s: ") and "\n" not in line
    assert out == adapter.fallback.update(STATE, REF)  # cfstack's law flies the failsafe
    adapter.update(STATE, REF, 1.3)
    assert len(adapter.instance.seen) == 1  # never called again


def test_a_hanging_call_is_stopped_at_its_budget():
    def hang():
        while True:
            pass

    adapter, guard, faults = _adapter(hang, timeout_s=0.2)
    start = time.monotonic()
    with guard:
        adapter.update(STATE, REF, 2.0)
    assert time.monotonic() - start < 2.0
    assert "did not return within 0.2 s" in faults[0].problem


def test_realtime_overruns_are_warned_once_and_counted(caplog):
    def slow():
        time.sleep(0.003)
        return {"cmd_thrust": 0.3, "cmd_moment": np.zeros(3)}

    adapter, guard, _ = _adapter(slow)
    guard.realtime_period_s = 0.002
    with caplog.at_level(logging.WARNING, logger="cfstack.usercode"):
        for i in range(3):
            adapter.update(STATE, REF, i * 0.002)
    assert guard.overruns == 3
    assert len([r for r in caplog.records if "over the 2.0 ms control period" in r.message]) == 1
    times = adapter.summary()["controller_update"]
    assert times["calls"] == 3 and times["p50_ms"] >= 3.0


# --- the trajectory adapter -----------------------------------------------------------------------------
def test_the_end_of_a_user_trajectory_is_where_it_comes_to_rest():
    class Line:
        def __init__(self):
            self.a, self.b, self.speed = np.zeros(3), np.array([3.0, 4.0, 0.0]), 0.8  # 5 m: ends at 6.25 s

        def update(self, t):
            s = min(t * self.speed / 5.0, 1.0)
            v = self.speed / 5.0 * (self.b - self.a) if s < 1.0 else np.zeros(3)
            return {"x": self.a + s * (self.b - self.a), "x_dot": v, "x_ddot": np.zeros(3), "x_dddot": np.zeros(3),
                    "x_ddddot": np.zeros(3), "yaw": 0, "yaw_dot": 0}

    settings = load_usercode_settings()
    traj = UserTrajectory(Line(), "line.py Line", settings, Guard(1.0, []))
    assert abs(traj.duration_s - 6.25) <= settings.end_resolution_s
    assert traj.final.position_m.tolist() == [3.0, 4.0, 0.0] and traj.note is None
    assert traj.sample(2.5).position_m == pytest.approx([1.2, 1.6, 0.0])


# --- whole flights ------------------------------------------------------------------------------------
def _summary(log: Path) -> dict:
    return json.loads((log / "summary.json").read_text())


def _landed_and_readable(log: Path) -> None:
    flight = read_log(log)  # the logs stay readable after a failsafe
    phases = list(dict.fromkeys(flight.phase.tolist()))
    assert "land" in phases and "disarm" in phases, phases
    assert _summary(log)["landing"]["result"] == "landed"


# The module's `cfstack fly` flights of users' code, each with the world it needs (None: no world).
CLI_FLIGHTS = {
    "student_a": ("test_lab_1", ("--controller", str(STUDENTS / "student_a"), "--trajectory",
                                 str(STUDENTS / "student_a"), "--radio", "lab")),
    "motor_speeds": ("test_lab_2", ("--controller", str(STUDENTS / "motor_speeds_only"), "--controller-output",
                                    "motor_speeds", "--planner", str(STUDENTS / "student_a"), "--trajectory",
                                    "constant-speed", "--radio", "lab")),
    "controller_raises": (None, ("--controller", f"{STUDENTS / 'broken' / 'se3_control.py'}:Raises",
                                 "--trajectory", "hover", "--radio", "lab")),
    "trajectory_raises": ("test_empty", ("--trajectory", str(STUDENTS / "broken"), "--radio", "lab")),
}


@pytest.fixture(scope="module")
def cli_flights(tmp_path_factory) -> dict[str, tuple[subprocess.CompletedProcess, Path]]:
    """Each CLI_FLIGHTS flight whose world is here, flown two at a time (a lockstep flight keeps about one
    core busy): (the finished `cfstack fly`, its log folder). The tests judge them one by one."""
    root = tmp_path_factory.mktemp("usercode_cli")
    argv = {}
    for name, (world, options) in CLI_FLIGHTS.items():
        worlds = [] if world is None else [str(SHARED_WORLDS / f"{world}.json")]
        if all(Path(path).is_file() for path in worlds):  # an absent world: its test skips, saying why
            argv[name] = ("fly", *worlds, *options, "--log", str(root / name))
    with ThreadPoolExecutor(2) as pool:
        futures = {name: pool.submit(cfstack, *words) for name, words in argv.items()}
        return {name: (future.result(), root / name) for name, future in futures.items()}


def _cli_flight(cli_flights: dict, name: str) -> tuple[subprocess.CompletedProcess, Path]:
    world = CLI_FLIGHTS[name][0]
    if world is not None:
        shared_world(world)  # skips, saying why, when the world is absent
    return cli_flights[name]


@pytest.mark.slow
def test_cli_flies_a_students_controller_and_trajectory_through_a_lab_maze(cli_flights):
    done, log = _cli_flight(cli_flights, "student_a")
    assert done.returncode == 0, done.stderr
    summary = _summary(log)
    assert summary["reached_goal"] and not summary["collided"] and summary["mode"] == "moments"
    user = summary["user_code"]
    assert user["controller"] == "se3_control.py SE3Control" and user["trajectory"] == "world_traj.py WorldTraj"
    assert user["controller_update"]["calls"] > 1000 and 0 < user["controller_update"]["p50_ms"] \
        <= user["controller_update"]["p99_ms"]
    assert "SE3Control.update p50" in done.stdout  # the user's own time per call, in the human summary
    rows = list(csv.DictReader((log / "user_commands.csv").open()))
    assert len(rows) == user["controller_update"]["calls"]
    assert all(math.isfinite(float(r["cmd_motor_speed_1_radps"])) for r in rows)  # logged beside the commands
    assert summary["final_position_error_m"] < 0.05  # the trajectory's rest point is the world's goal


@pytest.mark.slow
def test_api_flies_a_min_snap_trajectory_and_an_attitude_controller_through_a_course_maze(tmp_path):
    import cfstack as api

    flight = api.fly(shared_world("maze_2022_1"), controller=str(STUDENTS / "student_b" / "se3_control.py"),
                     trajectory=STUDENTS / "student_b", mode="attitude", radio="lab", log=tmp_path / "api")
    assert flight.reached_goal, flight.summary["result"]
    assert flight.log_dir == tmp_path / "api" and (flight.log_dir / "states.csv").is_file()
    assert flight.summary == _summary(flight.log_dir)  # the same summary as the CLI writes
    user = flight.summary["user_code"]
    assert any("summed" in note for note in user["notes"])  # cmd_thrust was the four rotors' thrusts
    rows = list(csv.DictReader((flight.log_dir / "user_commands.csv").open()))
    assert rows[-1]["flown"] == "attitude"
    q = np.array([[float(r[k]) for k in ("cmd_q_w", "cmd_q_x", "cmd_q_y", "cmd_q_z")] for r in rows])
    assert np.allclose(np.linalg.norm(q, axis=1), 1.0)


@pytest.mark.slow
def test_motor_speeds_controller_with_a_users_planner_flies_a_lab_maze(cli_flights):
    done, log = _cli_flight(cli_flights, "motor_speeds")
    assert done.returncode == 0, done.stderr
    summary = _summary(log)
    assert summary["reached_goal"] and not summary["collided"]
    assert summary["user_code"]["planner"] == "graph_search.py graph_search"
    assert summary["user_code"]["controller_output"] == "motor_speeds"
    plan = json.loads((log / "plan.json").read_text())
    assert plan["planner"] == "graph_search.py graph_search" and plan["nodes_expanded"] > 0
    assert "'+' mixer" not in done.stderr  # flown as speeds: nothing to disagree with


@pytest.mark.slow
def test_a_controller_that_raises_mid_flight_gets_one_line_and_the_vehicle_lands(cli_flights):
    done, log = _cli_flight(cli_flights, "controller_raises")
    assert done.returncode == 1
    line = [x for x in done.stderr.splitlines() if x.startswith("cfstack fly:")]
    assert len(line) == 1
    assert "user code se3_control.py Raises.update at t=" in line[0] and "IndexError" in line[0]
    assert "se3_control.py:" in line[0]  # the line in the user's file
    assert "Traceback" not in done.stderr
    _landed_and_readable(log)
    summary = _summary(log)
    assert summary["result"] == "failsafe" and "Raises.update" in summary["user_code"]["fault"]
    fault_t = float(summary["user_code"]["fault"].split("at t=")[1].split(" s")[0])
    rows = list(csv.DictReader((log / "user_commands.csv").open()))
    assert float(rows[-1]["t_s"]) < fault_t  # the user's commands stop at the fault


@pytest.mark.slow
def test_a_trajectory_that_raises_mid_flight_lands_the_vehicle(cli_flights):
    done, log = _cli_flight(cli_flights, "trajectory_raises")
    assert done.returncode == 1
    assert "user code world_traj.py WorldTraj.update at t=" in done.stderr and "IndexError" in done.stderr
    _landed_and_readable(log)


def test_a_trajectory_that_raises_while_built_is_one_line_before_any_flight(tmp_path):
    done = cfstack("fly", str(shared_world("test_lab_1")), "--trajectory",
                   f"{STUDENTS / 'broken' / 'world_traj.py'}:RaisesInConstructor", "--log", str(tmp_path / "x"))
    assert done.returncode == 2
    assert done.stderr.strip().splitlines()[-1].startswith(
        "cfstack fly: user code world_traj.py RaisesInConstructor(world, start, goal): raised IndexError")
    assert not (tmp_path / "x").exists()  # nothing flew


@pytest.mark.slow
def test_a_slow_controller_slows_lockstep_but_does_not_change_it(tmp_path):
    logs = {name: tmp_path / name for name in ("Correct", "Slow")}
    with ThreadPoolExecutor(2) as pool:  # at once: each lockstep flight keeps about one core busy
        runs = [pool.submit(cfstack, "fly", "--controller", f"{STUDENTS / 'broken' / 'se3_control.py'}:{name}",
                            "--trajectory", "hover", "--mode", "attitude", "--rate", "50", "--firmware", "ideal",
                            "--log", str(log)) for name, log in logs.items()]
        for run in runs:
            assert run.result().returncode == 0, run.result().stderr
    assert (logs["Correct"] / "states.csv").read_bytes() == (logs["Slow"] / "states.csv").read_bytes()
    slow = _summary(logs["Slow"])["user_code"]["controller_update"]
    assert slow["p50_ms"] >= 4.0  # it did take its 4 ms per call
    assert _summary(logs["Slow"])["wall_time_s"] > _summary(logs["Correct"])["wall_time_s"]

