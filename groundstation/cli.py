"""`cfstack groundstation`, `cfstack fly` and `cfstack step`.

Takes in: command-line options, each checked before anything starts (a bad one is one line on stderr and
exit code 2, never a usage block, a hang or a traceback); world files, checked by the pre-flight rules
(groundstation.preflight: a start or goal on the bounds is moved inward by the collision radius, with a
warning; one in or beside a block is refused).
Gives out: a flown session (logs in --log DIR), a human summary or one JSON object on stdout (`--json`),
one line on stderr for a crash or a failsafe (what, where, when), and an exit code that follows the
mission: 0 when the goal was reached without a collision in flight (whatever the landing after it did),
1 otherwise, 2 for bad input.
`fly` and `step` start an emulator as a child process on a private loopback zenoh endpoint. In lockstep
(where the child's time stands still until the ground station joins) they start it as soon as the options
and the world are checked, so that its start-up (~0.3 s) overlaps the ground station's: the modules that
take most of a ground station's start (the planner with scipy.optimize, the session with the estimator:
~0.5 s together) are imported after it, where they are used, and an
error in the user's code or in planning stops the child again (one line, as before). In realtime the child
starts last, as the vehicle lives from its start;
`groundstation` flies whatever answers at the default endpoint (DEFAULT_ENDPOINT, where `cfstack
emulator` listens by default) or at --connect/--listen. The ground station never imports the simulator:
the child is another program.
"""

from __future__ import annotations

import argparse
import importlib.util
import logging
import os
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from estimator.sensor_spec import DEFAULT_SENSOR_SPEC, load_sensor_spec
from groundstation.child_process import die_with_parent
from groundstation.clocks import DEFAULT_RATE_HZ
from groundstation.controller import VARIANTS as CONTROLLER_VARIANTS
from groundstation.preflight import checked_world
from groundstation.tickframe import Displays
from groundstation.trajectories.basic import make_builtin
from groundstation.usercode.adapters import CONTROLLER_OUTPUTS
from groundstation.usercode.loader import builtin_or_user_file
from link.crtp.packet import CRTP_HOST, DEFAULT_CRTP_PORT
from link.keys import DEFAULT_PREFIX, MAX_VEHICLE_ID
from link.mavlink.signing import add_signing_arguments, signing_from_args
from link.transports import zenoh_process
from link.transports.base import free_loopback_port
from link.transports.table import check_radio_link, far_end
from link.transports.zenoh_session import (
    DEFAULT_ENDPOINT,
    PrivateEndpoint,
    add_zenoh_arguments,
    zenoh_options_from_args,
)
from model.errors import OneLineParser, UserError
from model.firmwares import DEFAULT_FIRMWARE, FIRMWARE_VEHICLES, default_vehicle_model
from model.options import float_in, non_negative_float, positive_float, seed, whole_number
from model.vehicle import load_vehicle
from model.world import World, load_world

if TYPE_CHECKING:
    from groundstation.session import SessionOptions

log = logging.getLogger("cfstack.groundstation")
BUILTIN_TRAJECTORIES = ("hover", "line", "circle")
DEFAULT_PLANNED = "minsnap"
# From the stability map (README): in moments mode compensation is as good at zero latency and keeps the
# loop stable to 100 ms instead of 10 ms; in attitude mode it wins from 10 ms on but costs ~2 mm of peak
# tracking error at zero latency, so there it stays an option.
COMPENSATION_DEFAULT = {"moments": True, "attitude": False, "position": False}
# The highest control rate: the emulator's physics step (1 kHz); faster commands would share a step.
MAX_RATE_HZ = 1000.0
EMULATOR_START_CHECK_S = 0.05  # how long `fly` gives its emulator child to fail on its own options


def _flight_arguments(p: argparse.ArgumentParser) -> None:
    """How any session flies: mode, rate, vehicle, gains, logs (fly, step and groundstation)."""
    g = p.add_argument_group("flight")
    g.add_argument("--mode", choices=("moments", "attitude", "position"), default="moments",
                   help="command mode: thrust+moments (500 Hz default), thrust+attitude (100 Hz default), or "
                        "position (100 Hz default): the reference's position, velocity and yaw, flown by the "
                        "vehicle's onboard position controller (--firmware crazyflie; it needs --extpose)")
    g.add_argument("--rate", type=float_in(0.0, MAX_RATE_HZ, "Hz"), metavar="HZ",
                   help=f"control rate, Hz, above 0 and at most {MAX_RATE_HZ:g} "
                        f"(default {DEFAULT_RATE_HZ['moments']:g} in moments mode, "
                        f"{DEFAULT_RATE_HZ['attitude']:g} in attitude and position modes)")
    g.add_argument("--log", help="log folder (default: a new timestamped folder under ./flights/)")
    g.add_argument("--json", action="store_true", help="print exactly one JSON object on stdout")
    g.add_argument("--vehicle", type=whole_number(1, "a vehicle id", MAX_VEHICLE_ID), default=1,
                   help=f"vehicle id (MAVLink system id, 1..{MAX_VEHICLE_ID})")
    g.add_argument("--vehicle-model", default=None,
                   help="vehicle parameters: name or TOML file (default: cf21, the Crazyflie 2.1, with --firmware "
                        "crazyflie and for a ground station alone; crazyflie, the course model, with --firmware "
                        "ideal)")
    g.add_argument("--gains", default="gains", help="controller gains: name or TOML file")
    g.add_argument("--sensor-spec", default=DEFAULT_SENSOR_SPEC,
                   help="what the estimator assumes of IMU and mocap noise: name or TOML file "
                        f"(default: {DEFAULT_SENSOR_SPEC}, the BMI088 data sheet and a Vicon room)")
    g.add_argument("--latency-compensation", action=argparse.BooleanOptionalAction, default=None,
                   help="predict the state to when each command will act (one-way latency from TIMESYNC), "
                        "holding the commands already sent (default: on in moments mode, off in attitude mode; "
                        "see README, stability map)")
    g.add_argument("--controller", metavar="report|full|PATH[:Class]",
                   help="SE(3) law: the lab report's (w_des = 0) or the full geometric controller with angular "
                        "velocity/acceleration feed-forward (default: the gains file's variant); or a course-style "
                        "controller file, PATH[:Class] (default class SE3Control; a directory means its "
                        "se3_control.py), flown unchanged on our estimate (README: flying your own code)")
    g.add_argument("--controller-output", choices=CONTROLLER_OUTPUTS, default="commands",
                   help="what of a user controller's output is flown: commands (default: cmd_thrust with "
                        "cmd_moment in moments mode, with cmd_q in attitude mode) or motor_speeds "
                        "(cmd_motor_speeds through the course's '+' mixer, as the course's simulator flies them; "
                        "moments mode)")
    g.add_argument("--extpose", action=argparse.BooleanOptionalAction, default=None,
                   help="forward every mocap pose to the vehicle (MAVLink ATT_POS_MOCAP, as a mocap lab streams "
                        "extpose) for its onboard estimator (default: on, off with --firmware ideal)")
    g.add_argument("--id", dest="prefix", default=DEFAULT_PREFIX, help="zenoh key prefix")
    g.add_argument("--radio-link", metavar="CONNECTION",
                   help="the radio link to the vehicle (uplink and downlink) on its own transport: udpin:HOST:PORT, "
                        "udpout:HOST:PORT, serial:DEVICE:BAUD (--clock realtime), e.g. a telemetry radio; default: "
                        "zenoh, on the vehicle's keys. Mocap and truth stay on zenoh (the ground network). fly and "
                        "step start their emulator on the far end (udpin <-> udpout)")
    g.add_argument("--link", choices=("mavlink", "crtp"), default="mavlink",
                   help="the radio's protocol: mavlink (default) or crtp, a Crazyflie's own, through cflib "
                        "(--uri; moments or attitude mode; README, the ground station's Crazyflie link)")
    g.add_argument("--uri", metavar="URI",
                   help="with --link crtp: the Crazyflie's cflib URI, e.g. radio://0/80/2M/E7E7E7E7E7 or "
                        "udp://127.0.0.1:19850 (realtime), or zenoh://PREFIX/N (either clock; default: the "
                        "emulator's vehicle N, zenoh://PREFIX/N in lockstep, udp://127.0.0.1:19850+N-1 in realtime; "
                        "fly and step: their own emulator's)")
    d = p.add_argument_group("displays")
    d.add_argument("--view", action="store_true", help="show the flight live in the rerun viewer (spawned)")
    d.add_argument("--view-save", metavar="FILE.rrd", help="record the live view to a file instead (headless, CI)")
    d.add_argument("--gcs", metavar="CONNECTION",
                   help="forward the vehicle to a MAVLink ground-control station, e.g. udp:127.0.0.1:14550 "
                        "(QGroundControl, mavproxy.py --master=udp:127.0.0.1:14550); any transport string")
    d.add_argument("--gcs-origin", metavar="NAME|FILE", help="map origin shown to the GCS (default: gcs.toml's, "
                   "lab; model/params/origin)")
    d.add_argument("--gcs-commands", action="store_true",
                   help="accept unsigned flight commands (land, arm) from the GCS; without it only frames signed "
                        "with --signing-key-file are, and every command is logged to gcs_commands.csv")
    g.add_argument("-v", "--verbose", action="store_true")
    add_zenoh_arguments(p, mode_flag="--zenoh-mode")
    add_signing_arguments(p)


def _planning_arguments(p: argparse.ArgumentParser) -> None:
    """What to fly: a built-in trajectory or one planned through a world (fly and groundstation)."""
    g = p.add_argument_group("trajectory and planning")
    g.add_argument("--trajectory", help="hover|line|circle; with a world that has a start and goal: "
                   f"constant-speed|minsnap (default {DEFAULT_PLANNED}, planned from start to goal), or a "
                   "course-style trajectory file PATH[:Class] (default class WorldTraj; a directory means its "
                   "world_traj.py), built as Class(world, start, goal) before the flight")
    g.add_argument("--planner", metavar="PATH[:function]",
                   help="a course-style graph_search(world, resolution, margin, start, goal, astar) file (a "
                        "directory means its graph_search.py): plans for constant-speed and minsnap instead of "
                        "cfstack's A*")
    g.add_argument("--speed", type=positive_float, metavar="MPS",
                   help="planned speed, m/s (constant-speed: the speed; minsnap: the limit)")
    g.add_argument("--planning", default="planning",
                   help="planning parameters: a name (planning, planning_aggressive) or a TOML file")
    g.add_argument("--accel", type=positive_float, metavar="MPS2",
                   help="minsnap acceleration limit, m/s^2 (default: planning.toml; the thrust-to-weight limit "
                        "applies on top)")
    g.add_argument("--resolution", type=positive_float, nargs="+", metavar="R",
                   help="planning voxel size, m: one value or three (default: the world's, else planning.toml)")
    g.add_argument("--margin", type=non_negative_float, metavar="M",
                   help="planning clearance to blocks and walls, m (default: the world's, else planning.toml)")


def _emulator_arguments(p: argparse.ArgumentParser) -> None:
    """The emulator child that fly and step start."""
    g = p.add_argument_group("emulator child")
    g.add_argument("--radio", help="radio profile for the emulator: name or TOML file (default: the link's own, "
                                   "esb-duplex for MAVLink, crazyradio for CRTP; see `cfstack emulator --help`)")
    g.add_argument("--clock", choices=("lockstep", "realtime"), default="lockstep",
                   help="lockstep (default) or realtime")
    g.add_argument("--seed", type=seed, default=1, help="seed of every random source (0, 1, 2, ...)")
    g.add_argument("--from-ground", action="store_true", help="take off from the floor below the start")
    g.add_argument("--firmware", choices=tuple(FIRMWARE_VEHICLES), default=DEFAULT_FIRMWARE,
                   help="the emulated vehicle's onboard side: crazyflie (default: the Crazyflie's PID stabilizer on "
                        "its own estimate, PWM, battery) or ideal (the lab report's geometric law on the true "
                        "state and an exact mixer, for controller-only studies)")
    g.add_argument("--vehicle-draw", default="nominal", metavar="PROFILE",
                   help="the emulated vehicle's variation from its nominal file: nominal (default) or lab (mass, "
                        "centre of mass, motor thrusts, IMU alignment drawn from the seed; this ground station "
                        "is not told the draw)")
    g.add_argument("--emulator-arg", dest="emulator_extra", action="append", default=[], metavar="ARG",
                   help="passed to the emulator child, e.g. --emulator-arg=--cut-mocap=8:2 (repeatable)")


def _parsed(p: argparse.ArgumentParser, argv: list[str]) -> argparse.Namespace:
    args = p.parse_args(argv)
    resolution = getattr(args, "resolution", None)
    if resolution is not None and len(resolution) not in (1, 3):
        raise UserError(f"argument --resolution: give one value or three, not {len(resolution)} "
                        f"(see '{p.prog} --help')")
    if getattr(args, "vehicle_model", "") is None:
        args.vehicle_model = default_vehicle_model(getattr(args, "firmware", DEFAULT_FIRMWARE))
    level = logging.INFO if args.verbose else logging.WARNING
    logging.basicConfig(level=level, format="%(name)s: %(message)s", stream=sys.stderr)
    return args


def _world(path: str | None, vehicle_model: str) -> World | None:
    """The world, its start and goal checked before anything starts (warnings on stderr, one line each)."""
    if path is None:
        return None
    world = load_world(path)
    world, nudges = checked_world(world, load_vehicle(vehicle_model).collision_radius_m)
    for warning in (*world.warnings, *nudges):
        print(f"warning: {warning}", file=sys.stderr)
    return world


def _controller_variant(args) -> str | None:
    """--controller's built-in law (None for the gains file's, or when it names user code)."""
    return builtin_or_user_file(args.controller, CONTROLLER_VARIANTS, "controller")[0]


def _user_code(args, world: World | None, objects: dict | None = None):
    """The user's controller, trajectory and planner, loaded and constructed now, before any emulator runs
    (a slow WorldTraj cannot make a handshake time out; `fly`'s lockstep child may be starting, its time
    standing still until the ground station joins). objects: classes/functions from the Python API."""
    from groundstation.planned import KINDS as PLANNED_KINDS

    named = dict(objects or {})
    trajectories = (*BUILTIN_TRAJECTORIES, *PLANNED_KINDS)
    files = {"controller": builtin_or_user_file(args.controller, CONTROLLER_VARIANTS, "controller")[1],
             # `step` flies its own step: it has no --trajectory or --planner
             "trajectory": builtin_or_user_file(getattr(args, "trajectory", None), trajectories, "trajectory")[1],
             "planner": getattr(args, "planner", None)}
    for kind, spec in files.items():
        if spec is not None:
            named.setdefault(kind, spec)
    if not named and args.controller_output == "commands":
        return None
    from groundstation.usercode.host import prepare

    return prepare(load_vehicle(args.vehicle_model), world, controller_output=args.controller_output,
                   mode=args.mode, **named)


def _track(args, world: World | None, user_code=None):
    """The trajectory to track and the goal: the user's, built-in, or planned through the world."""
    if user_code is not None and user_code.trajectory is not None:
        track = user_code.trajectory
        return track, np.array(world.goal, float), {"trajectory": track.name,
                                                    "planned_duration_s": track.duration_s}, None
    if world is not None and world.start is not None and world.goal is not None \
            and args.trajectory not in BUILTIN_TRAJECTORIES:
        from groundstation.planned import plan_track

        planned = plan_track(world, args.trajectory or DEFAULT_PLANNED, load_vehicle(args.vehicle_model),
                             speed_mps=args.speed, resolution=args.resolution, margin=args.margin,
                             accel_mps2=args.accel, planning=args.planning,
                             planner=user_code.planner if user_code is not None else None)
        return planned.trajectory, planned.goal_enu_m, planned.summary, planned.plan
    name = args.trajectory or "hover"
    if name not in BUILTIN_TRAJECTORIES:
        raise UserError(f"--trajectory {name}: one of {', '.join(BUILTIN_TRAJECTORIES)}"
                        + ("" if world is not None else " (planned trajectories need a world with a start and goal)"))
    floor = float(world.bounds[4]) if world is not None else 0.0
    if world is not None and world.start is not None:
        start = np.array(world.start, float)
    else:
        from groundstation.mission import load_mission_params

        start = np.array([0.0, 0.0, floor + load_mission_params().takeoff_height_m])
    track = make_builtin(name, start)
    return track, np.asarray(track.sample(track.duration_s).position_m, float), {"trajectory": name}, None


def _settings(args, clock: str) -> dict:
    """The session's settings that come from the command line alone, each checked: a bad one is one line
    before any process starts (files loaded now)."""
    if args.mode == "position" and args.latency_compensation:
        raise UserError("argument --latency-compensation: not with --mode position (the vehicle's own position "
                        "controller flies the reference; there is no ground-station command to predict)")
    if args.mode == "position" and getattr(args, "firmware", DEFAULT_FIRMWARE) != "crazyflie":
        raise UserError("argument --mode position: needs --firmware crazyflie (the ideal vehicle has no onboard "
                        "position controller)")
    if args.radio_link is not None:
        check_radio_link(args.radio_link, 1, clock)  # the ground station's address is its own vehicle's
    signing = signing_from_args(args)
    zenoh_process.check_environment()
    if args.link == "crtp":
        _check_crtp(args, clock, signing)
    elif args.uri is not None:
        raise UserError("argument --uri: a cflib URI is for --link crtp")
    return dict(
        mode=args.mode, rate_hz=args.rate, clock=clock, connection="zenoh", radio_link=args.radio_link,
        link=args.link, crtp_uri=args.uri or _default_crtp_uri(args, clock), prefix=args.prefix,
        vehicle_id=args.vehicle, vehicle_model=args.vehicle_model, gains=args.gains,
        sensor_spec=load_sensor_spec(args.sensor_spec), controller_variant=_controller_variant(args),
        latency_compensation=(args.latency_compensation if args.latency_compensation is not None
                              else COMPENSATION_DEFAULT[args.mode]), log_dir=Path(args.log) if args.log else None,
        signing=signing,
        # fly and step know which emulated firmware they started; a ground station alone does not
        extra_summary=({"firmware": args.firmware, "vehicle_draw": args.vehicle_draw}
                       if hasattr(args, "firmware") else {}),
        allow_reset=getattr(args, "reset", False), extpose=_extpose(args), displays=_displays(args))


def _options(settings: dict, world, track, goal, extra, plan, zopts: dict, user_code=None) -> SessionOptions:
    """SessionOptions: the command line's checked settings, and what the world, the user's code and the
    planning gave."""
    from groundstation.session import SessionOptions

    return SessionOptions(**{**settings, "extra_summary": {**extra, **settings["extra_summary"]}},
                          track=track, goal_enu_m=goal, world=world, zenoh_options=zopts, user_code=user_code,
                          plan=plan)


def _default_crtp_uri(args, clock: str) -> str:
    """The emulator's vehicle: on zenoh in lockstep, on CrazySim's UDP port in realtime."""
    if clock == "lockstep":
        return f"zenoh://{args.prefix}/{args.vehicle}"
    return f"udp://{CRTP_HOST}:{DEFAULT_CRTP_PORT + args.vehicle - 1}"


def _check_crtp(args, clock: str, signing) -> None:
    """--link crtp: what it can fly (one line for what it cannot)."""
    if importlib.util.find_spec("cflib") is None:
        raise UserError("argument --link crtp: needs Bitcraze's cflib (pip install \"cfstack[cflib]\")")
    if args.uri is not None and "://" not in args.uri:
        raise UserError(f"argument --uri: '{args.uri}' is not a cflib URI (e.g. udp://127.0.0.1:19850, "
                        "radio://0/80/2M/E7E7E7E7E7)")
    if clock == "lockstep" and args.uri is not None and not args.uri.startswith("zenoh://"):
        raise UserError(f"argument --uri: '{args.uri}' cannot fly in lockstep: only zenoh://PREFIX/VEHICLE can "
                        "(udp:// and radio:// fly with --clock realtime)")
    if args.mode == "position":
        raise UserError("argument --link crtp: not with --mode position (a cflib script flies position setpoints "
                        "itself: README, cflib scripts against the emulator)")
    if args.radio_link is not None:
        raise UserError("argument --radio-link: the Crazyflie link's transport is cflib's, named by --uri")
    if signing is not None:
        raise UserError("argument --signing-key-file: CRTP has no signing (MAVLink's)")
    if args.uri is not None and args.uri.startswith("zenoh://"):
        from link.crtp.zenoh_driver import parse_uri

        try:
            parse_uri(args.uri)
        except UserError as err:
            raise UserError(f"argument --uri: {err}") from None


def _displays(args) -> Displays:
    """--view/--view-save/--gcs*, checked (files loaded) before any process starts."""
    if args.view and args.view_save:
        raise UserError("argument --view: give --view or --view-save FILE.rrd, not both")
    wants_view = args.view or args.view_save is not None
    if wants_view and importlib.util.find_spec("rerun") is None:
        raise UserError("argument --view: needs the rerun-sdk package (pip install \"cfstack[view]\")")
    if args.gcs_origin and not args.gcs:
        raise UserError("argument --gcs-origin: only with --gcs")
    gcs = None
    if args.gcs:
        from groundstation.gcs_forward import gcs_connection, load_gcs_settings
        from link.transports.table import parse_connection

        parse_connection(gcs_connection(args.gcs))  # an unknown scheme is one line now
        gcs = load_gcs_settings(origin=args.gcs_origin)
    # the GCS link checks signatures with the same key, in a Signing of its own (its own streams and clock)
    return Displays(view=args.view, view_save=args.view_save, gcs=args.gcs, gcs_settings=gcs,
                    gcs_commands=args.gcs_commands, gcs_signing=signing_from_args(args) if gcs else None)


def _extpose(args) -> bool:
    """--extpose as given; by default on, as a mocap lab streams the pose to its vehicles, except when this
    command started the ideal vehicle (which reads the truth and ignores it)."""
    if args.extpose is not None:
        return args.extpose
    return getattr(args, "firmware", DEFAULT_FIRMWARE) != "ideal"


def _explain_silence(summary: dict, zopts: dict) -> None:
    """No vehicle ever answered: say where the ground station looked and how to point it elsewhere."""
    failure = summary.get("failure")
    if failure is not None and summary["result"] == "aborted" and "no heartbeat" in failure["reason"]:
        where = ", ".join([f"connect {e}" for e in zopts.get("connect") or []]
                          + [f"listen {e}" for e in zopts.get("listen") or []])
        failure["reason"] += (f" (nothing answered on zenoh {where}: start `cfstack emulator` there, or point "
                              "--connect/--listen at the vehicle's endpoint)")


def _report(summary: dict, as_json: bool, prog: str) -> int:
    """Print the summary (and the failure line on stderr); the exit code follows the mission."""
    from groundstation.session import dump_json, human_summary

    failure = summary.get("failure")
    if failure is not None:
        print(f"{prog}: {failure['reason']}", file=sys.stderr)
    print(dump_json(summary) if as_json else human_summary(summary))
    return 0 if summary["reached_goal"] and not summary["collided"] else 1


def groundstation_command(argv: list[str]) -> int:
    p = OneLineParser(prog="cfstack groundstation",
                      description="Fly whatever vehicle answers on the link (emulator or real).")
    _flight_arguments(p)
    _planning_arguments(p)
    p.add_argument("--world", help="world JSON (for planning, clearance, landing spots and the floor)")
    p.add_argument("--clock", choices=("lockstep", "realtime"), default="realtime",
                   help="realtime (default) for a real vehicle or a realtime emulator; lockstep to follow an "
                        "emulator's clock")
    p.add_argument("--reset", action="store_true",
                   help="if the vehicle already reports CRASHED, ask it to reboot (MAVLink "
                        "MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN; the emulator then puts it back, disarmed, below its "
                        "start) and fly from there; logged")
    args = _parsed(p, argv)
    world = _world(args.world, args.vehicle_model)
    settings = _settings(args, args.clock)
    user_code = _user_code(args, world)
    track, goal, extra, plan = _track(args, world, user_code)
    zopts = zenoh_options_from_args(args)
    if not zopts.get("connect") and not zopts.get("listen"):
        zopts["connect"] = [DEFAULT_ENDPOINT]  # where `cfstack emulator` listens by default
    from groundstation.session import run_session

    result = run_session(_options(settings, world, track, goal, extra, plan, zopts, user_code))
    _explain_silence(result.summary, zopts)
    return _report(result.summary, args.json, p.prog)


class FlightFailed(UserError):
    """The vehicle did not fly the experiment: a normal (if unhappy) outcome, exit code 1."""

    exit_code = 1


class EmulatorChild:
    """`cfstack emulator` as a child process on a private zenoh endpoint (a Unix socket where the system has them)."""

    def __init__(self, args, world_path: str | None, start: np.ndarray | None, airborne: bool, clock: str):
        # CRTP only for this ground station's own --link crtp, on a private port (no cflib clients otherwise)
        if args.link == "crtp" and args.uri:
            raise UserError("argument --uri: fly and step fly the emulator they start (its URI is theirs); fly a "
                            "vehicle at a URI with `cfstack groundstation --link crtp --uri URI`")
        # realtime: on UDP, as a cflib user would; lockstep: on the vehicle's zenoh keys (always served)
        self.crtp_port = free_loopback_port(socket.SOCK_DGRAM) if args.link == "crtp" and clock == "realtime" else None
        self._private = PrivateEndpoint()
        self.endpoint = self._private.endpoint
        try:
            cmd = self._command(args, world_path, start, airborne, clock)
            # stderr to a file, not a pipe: a pipe nobody reads during the flight could fill and stall the child
            self.stderr = tempfile.TemporaryFile(mode="w+")
            self.started_s = time.monotonic()
            self.proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                         stderr=self.stderr, text=True, env=os.environ.copy(),
                                         preexec_fn=die_with_parent)
        except BaseException:
            self._private.close()
            raise

    def _command(self, args, world_path: str | None, start: np.ndarray | None, airborne: bool,
                 clock: str) -> list[str]:
        cmd = [sys.executable, "-m", "cfstack", "emulator", "--listen", self.endpoint, "--clock", clock,
               "--seed", str(args.seed), "--id", args.prefix,
               "--vehicle-model", args.vehicle_model, "--firmware", args.firmware,
               "--vehicle-draw", args.vehicle_draw, "--quiet"]
        if args.radio is not None:
            cmd += ["--radio", args.radio]
        if world_path:
            cmd += ["--world", world_path]
        if start is not None:  # the pre-flight-checked start (it may have been moved inside the bounds)
            cmd += ["--start", *(repr(float(v)) for v in start)]
        if airborne:
            cmd += ["--airborne"]
        if args.radio_link is not None:  # the vehicle's end of the ground station's radio link
            cmd += ["--radio-link", far_end(args.radio_link)]
        cmd += ["--crtp-port", "off" if self.crtp_port is None else str(self.crtp_port)]
        return cmd + getattr(args, "emulator_extra", [])

    def _stderr_lines(self) -> list[str]:
        self.stderr.seek(0)
        return self.stderr.read().strip().splitlines()

    def failure(self) -> str | None:
        """None while the child runs; else its last words (e.g. a bad radio profile)."""
        if self.proc.poll() is None:
            return None
        err = self._stderr_lines()
        return f"the emulator stopped: {err[-1]}" if err else f"the emulator stopped (exit {self.proc.returncode})"

    def check_started(self) -> None:
        time.sleep(max(0.0, self.started_s + EMULATOR_START_CHECK_S - time.monotonic()))
        if self.proc.poll() is not None:
            err = self._stderr_lines()
            raise UserError(err[-1] if err else "the emulator child exited at start")

    def stop(self) -> list[str]:
        """Stop the child; its stderr lines (the summary last)."""
        if self.proc.poll() is None:
            self.proc.terminate()
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self._private.close()
        lines = self._stderr_lines()
        self.stderr.close()
        return lines


def fly_command(argv: list[str]) -> int:
    p = fly_parser()
    args = _parsed(p, argv)
    return _report(fly(args).summary, args.json, p.prog)


def fly_parser() -> OneLineParser:
    p = OneLineParser(prog="cfstack fly", description="One command: start an emulator, fly, land, log, summarise.")
    p.add_argument("world", nargs="?", help="world JSON file (default: an empty room)")
    _flight_arguments(p)
    _planning_arguments(p)
    _emulator_arguments(p)
    return p


def fly(args: argparse.Namespace, objects: dict | None = None):
    """`cfstack fly` with parsed arguments (the command line's, or cfstack.fly's); objects: user classes and
    functions given as Python objects (the API). Returns the SessionResult."""
    world = _world(args.world, args.vehicle_model)
    airborne = not args.from_ground and world is not None and world.start is not None
    zopts = zenoh_options_from_args(args)
    settings = _settings(args, args.clock)
    _warn_if_one_crazyradio_cannot_carry_mavlink(args)

    def prepared() -> SessionOptions:
        user_code = _user_code(args, world, objects)
        track, goal, extra, plan = _track(args, world, user_code)
        return _options(settings, world, track, goal, extra, plan, zopts, user_code)

    return fly_with_emulator(args, world, airborne, zopts, prepared)


def _warn_if_one_crazyradio_cannot_carry_mavlink(args) -> None:
    """MAVLink on the one-dongle `crazyradio` model: its IMU telemetry alone (HIGHRES_IMU at the IMU rate, a few
    radio packets a frame) needs more transactions than the dongle's USB runs. Say so before flying; the
    whole account is benchmarks/radio_budget.py."""
    if args.link != "mavlink" or args.radio is None:
        return
    from link.mavlink.codec import ActuatorLimits, Codec
    from link.messages import ImuSample
    from model.air_budget import packets
    from model.radio import load_radio_profile

    profile = load_radio_profile(args.radio)
    cr = profile.crazyradio
    if profile.model != "crazyradio" or cr.usb_interval_s <= 0.0:
        return
    vehicle = load_vehicle(args.vehicle_model)
    frame = Codec(system_id=1, limits=ActuatorLimits.from_vehicle(vehicle)).encode(
        ImuSample(0.0, (0.0, 0.0, 9.8), (0.0, 0.0, 0.0)))
    packets_per_s = sum(rate for rate, _ in packets(cr, [(vehicle.imu.rate_hz, len(frame))]))
    transactions_per_s = 1.0 / cr.usb_interval_s
    if packets_per_s > transactions_per_s:
        print(f"cfstack fly: warning: radio {profile.name} is one Crazyradio: MAVLink's {vehicle.imu.rate_hz:g} Hz IMU "
              f"telemetry alone is {packets_per_s:.0f} radio packets/s down and it carries {transactions_per_s:.0f}; "
              f"expect a late, lossy downlink and a failsafe (python benchmarks/radio_budget.py)", file=sys.stderr)


def fly_with_emulator(args, world: World | None, airborne: bool, zopts: dict, prepared: Callable[[], SessionOptions]):
    """The session against a child emulator (or the one --connect names); prepared() loads the user's code,
    plans and returns the SessionOptions. In lockstep the child starts first, as its time stands still until
    the ground station joins: its start-up overlaps ours. In realtime it starts last: its vehicle lives from
    its start (an airborne one levels after 0.5 s without setpoints, its motors stop at 2 s)."""
    if args.clock != "lockstep":
        opts = prepared()
        with emulator_child(args, world, airborne, zopts) as child:
            return _run_against(child, opts)
    with emulator_child(args, world, airborne, zopts) as child:
        return _run_against(child, prepared())


@contextmanager
def emulator_child(args, world: World | None, airborne: bool, zopts: dict) -> Iterator[EmulatorChild | None]:
    """The emulator child `fly` and `step` fly (None when --connect names another vehicle): started on entry,
    stopped on the way out (an error included), its stderr lines printed with -v."""
    if zopts.get("connect"):
        yield None
        return
    start = world.start if world is not None else None
    child = EmulatorChild(args, getattr(args, "world", None), start, airborne, args.clock)
    try:
        yield child
    finally:
        for line in child.stop():
            if args.verbose:
                print(line, file=sys.stderr)


def _run_against(child: EmulatorChild | None, opts: SessionOptions):
    """run_session on the child's private endpoint (or where opts already connect)."""
    from groundstation.session import run_session

    if child is not None:
        child.check_started()
        opts.zenoh_options = {**opts.zenoh_options, "connect": [child.endpoint], "listen": []}
        if child.crtp_port is not None:
            opts.crtp_uri = f"udp://{CRTP_HOST}:{child.crtp_port}"
        opts.peer_failure = child.failure
    return run_session(opts)
