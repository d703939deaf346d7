"""`cfstack groundstation`, `cfstack fly` and `cfstack step`.

Takes in: command-line options.
Gives out: a flown session (logs in --log DIR), a human summary or one JSON object on stdout
(`--json`), exit code 0 only for a successful flight (1 otherwise, 2 for bad input).
`fly` starts an emulator as a child process on loopback zenoh unless told to connect to one;
the ground station never imports the simulator: the child is another program.
"""

from __future__ import annotations

import argparse
import logging
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from groundstation.planned import plan_track
from groundstation.session import SessionOptions, dump_json, human_summary, run_session
from groundstation.trajectories.basic import make_builtin
from link.errors import UserError
from link.keys import DEFAULT_PREFIX
from link.signing import add_signing_arguments, signing_from_args
from link.vehicle import load_vehicle
from link.world import World, load_world
from link.zenoh_session import add_zenoh_arguments, zenoh_options_from_args

log = logging.getLogger("cfstack.groundstation")
BUILTIN_TRAJECTORIES = ("hover", "line", "circle")
DEFAULT_PLANNED = "minsnap"


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--mode", choices=("moments", "attitude"), default="moments",
                   help="command mode: thrust+moments (500 Hz default) or thrust+attitude (100 Hz default)")
    p.add_argument("--rate", type=float, help="control rate, Hz")
    p.add_argument("--trajectory", help="hover|line|circle; with a world that has a start and goal: "
                   f"constant-speed|minsnap (default {DEFAULT_PLANNED}, planned from start to goal)")
    p.add_argument("--speed", type=float, help="planned speed, m/s (constant-speed: the speed; minsnap: the limit)")
    p.add_argument("--resolution", type=float, nargs="+", metavar="R",
                   help="planning voxel size, m: one value or three (default: the world's, else planning.toml)")
    p.add_argument("--margin", type=float, help="planning clearance to blocks, m (default: the world's, else 0.2)")
    p.add_argument("--log", help="log folder (default: a new timestamped folder under ./flights/)")
    p.add_argument("--json", action="store_true", help="print exactly one JSON object on stdout")
    p.add_argument("--vehicle", type=int, default=1, help="vehicle id (MAVLink system id)")
    p.add_argument("--vehicle-model", default="crazyflie", help="vehicle parameters: name or TOML file")
    p.add_argument("--gains", default="gains", help="controller gains: name or TOML file")
    p.add_argument("--id", dest="prefix", default=DEFAULT_PREFIX, help="zenoh key prefix")
    p.add_argument("-v", "--verbose", action="store_true")
    add_zenoh_arguments(p, mode_flag="--zenoh-mode")
    add_signing_arguments(p)


def _setup_logging(args) -> None:
    level = logging.INFO if args.verbose else logging.WARNING
    logging.basicConfig(level=level, format="%(name)s: %(message)s", stream=sys.stderr)


def _track(args, world: World | None, start_airborne: bool):
    """The trajectory to track and the goal: built-in, or planned through the world."""
    if world is not None and world.start is not None and world.goal is not None \
            and args.trajectory not in BUILTIN_TRAJECTORIES:
        planned = plan_track(world, args.trajectory or DEFAULT_PLANNED, load_vehicle(args.vehicle_model),
                             speed_mps=args.speed, resolution=args.resolution, margin=args.margin)
        return planned.trajectory, planned.goal_enu_m, planned.summary, planned.plan
    name = args.trajectory or "hover"
    floor = float(world.bounds[4]) if world is not None else 0.0
    if world is not None and world.start is not None:
        start = np.array(world.start, float)
    else:
        from groundstation.mission import load_mission_params

        start = np.array([0.0, 0.0, floor + load_mission_params().takeoff_height_m])
    if name not in BUILTIN_TRAJECTORIES:
        raise UserError(f"--trajectory {name}: one of {', '.join(BUILTIN_TRAJECTORIES)}")
    track = make_builtin(name, start)
    return track, np.asarray(track.sample(track.duration_s).position_m, float), {"trajectory": name}, None


def _options(args, world, track, goal, extra, plan, clock: str, zopts: dict) -> SessionOptions:
    return SessionOptions(
        track=track, goal_enu_m=goal, world=world, mode=args.mode, rate_hz=args.rate, clock=clock,
        connection="zenoh", zenoh_options=zopts, prefix=args.prefix, vehicle_id=args.vehicle,
        vehicle_model=args.vehicle_model, gains=args.gains, log_dir=Path(args.log) if args.log else None,
        signing=signing_from_args(args), extra_summary=extra, plan=plan)


def _report(summary: dict, as_json: bool) -> int:
    if as_json:
        print(dump_json(summary))
    else:
        print(human_summary(summary))
    return 0 if summary["result"] == "reached_goal" else 1


def groundstation_command(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="cfstack groundstation",
                                description="Fly whatever vehicle answers on the link (emulator or real).")
    _common(p)
    p.add_argument("--world", help="world JSON (for planning, clearance and the floor)")
    p.add_argument("--clock", choices=("lockstep", "realtime"), default="realtime",
                   help="realtime for a real vehicle or a realtime emulator; lockstep to follow an emulator's clock")
    args = p.parse_args(argv)
    _setup_logging(args)
    world = load_world(args.world) if args.world else None
    track, goal, extra, plan = _track(args, world, start_airborne=False)
    summary = run_session(_options(args, world, track, goal, extra, plan, args.clock, zenoh_options_from_args(args)))
    return _report(summary, args.json)


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class EmulatorChild:
    """`cfstack emulator` as a child process on a private loopback zenoh endpoint."""

    def __init__(self, args, world_path: str | None, airborne: bool, clock: str):
        port = _free_port()
        self.endpoint = f"tcp/127.0.0.1:{port}"
        cmd = [sys.executable, "-m", "link", "emulator", "--listen", self.endpoint, "--clock", clock,
               "--radio", args.radio, "--seed", str(args.seed), "--id", args.prefix,
               "--vehicle-model", args.vehicle_model, "--quiet"]
        if world_path:
            cmd += ["--world", world_path]
        if airborne:
            cmd += ["--airborne"]
        cmd += getattr(args, "emulator_extra", [])
        self.stderr_path = None
        self.proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                     stderr=subprocess.PIPE, text=True, env=os.environ.copy())

    def check_started(self) -> None:
        time.sleep(0.05)
        if self.proc.poll() is not None:
            err = (self.proc.stderr.read() or "").strip().splitlines()
            raise UserError(err[-1] if err else "the emulator child exited at start")

    def stop(self) -> str:
        if self.proc.poll() is None:
            self.proc.terminate()
        try:
            _, err = self.proc.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            _, err = self.proc.communicate()
        lines = (err or "").strip().splitlines()
        return lines[-1] if lines else ""


def fly_command(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="cfstack fly",
                                description="One command: start an emulator, fly, land, log, summarise.")
    p.add_argument("world", nargs="?", help="world JSON file (default: an empty room)")
    _common(p)
    p.add_argument("--radio", default="crazyradio", help="radio profile for the emulator")
    p.add_argument("--clock", choices=("lockstep", "realtime"), default="lockstep")
    p.add_argument("--seed", type=int, default=1, help="seed of every random source")
    p.add_argument("--from-ground", action="store_true", help="take off from the floor below the start")
    args = p.parse_args(argv)
    _setup_logging(args)
    world = load_world(args.world) if args.world else None
    if world is not None:
        for warning in world.warnings:
            print(f"warning: {warning}", file=sys.stderr)
    airborne = not args.from_ground and world is not None and world.start is not None
    track, goal, extra, plan = _track(args, world, start_airborne=airborne)
    zopts = zenoh_options_from_args(args)
    child = None
    if not zopts.get("connect"):
        child = EmulatorChild(args, args.world, airborne, args.clock)
        child.check_started()
        zopts = {**zopts, "connect": [child.endpoint], "listen": []}
    try:
        summary = run_session(_options(args, world, track, goal, extra, plan, args.clock, zopts))
    finally:
        if child is not None:
            line = child.stop()
            if line and args.verbose:
                print(line, file=sys.stderr)
    return _report(summary, args.json)


def step_command(argv: list[str]) -> int:
    raise UserError("cfstack step: not built yet")
