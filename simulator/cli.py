"""`cfstack emulator`: start the emulated Crazyflie(s) on zenoh and run until stopped.

Takes in: command-line options (world, vehicles, radio profile, clock, seed, zenoh endpoints, key prefix).
Gives out: a running emulator (see simulator.emulator); on Ctrl-C or SIGTERM a clean stop and a one-line
summary on stderr; exit code 0 (2 for bad input).
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys

from link.keys import DEFAULT_PREFIX
from link.signing import add_signing_arguments, signing_from_args
from link.vehicle import load_mocap_room, load_vehicle
from link.world import load_world
from link.zenoh_session import add_zenoh_arguments, zenoh_options_from_args
from simulator.emulator import Emulator, EmulatorConfig
from simulator.radio import load_radio_profile


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="cfstack emulator", description=__doc__.splitlines()[0])
    p.add_argument("--world", help="world JSON file (default: an empty room)")
    p.add_argument("--vehicles", type=int, default=1, help="number of vehicles (ids 1..N)")
    p.add_argument("--vehicle-model", default="crazyflie", help="vehicle name (crazyflie, cf2x) or TOML file")
    p.add_argument("--mocap-room", default="vicon", help="mocap room name or TOML file")
    p.add_argument("--radio", default="crazyradio", help="radio profile name (ideal, crazyradio, lab, harsh) or TOML")
    p.add_argument("--clock", choices=("realtime", "lockstep"), default="lockstep")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--id", dest="prefix", default=DEFAULT_PREFIX, help="zenoh key prefix")
    p.add_argument("--physics-rate", type=float, default=1000.0, help="physics steps per second")
    p.add_argument("--airborne", action="store_true", help="start hovering at the start point instead of on the floor")
    p.add_argument("--start", type=float, nargs=3, metavar=("X", "Y", "Z"), help="start of vehicle 1 (ENU, m)")
    p.add_argument("--duration", type=float, help="stop after this many simulated seconds")
    p.add_argument("--quiet", action="store_true", help="log warnings only")
    add_zenoh_arguments(p)
    add_signing_arguments(p)
    return p


def config_from_args(args: argparse.Namespace) -> EmulatorConfig:
    from link.errors import UserError

    if args.vehicles < 1 or args.vehicles > 200:
        raise UserError(f"--vehicles {args.vehicles}: must be 1..200")
    world = load_world(args.world) if args.world else None
    if world is not None:
        for warning in world.warnings:
            logging.getLogger("cfstack.emulator").warning("%s", warning)
    starts = None
    if args.start is not None:
        starts = [tuple(args.start)] + [(args.start[0] + 0.5 * i, args.start[1], args.start[2])
                                        for i in range(1, args.vehicles)]
    return EmulatorConfig(
        vehicle=load_vehicle(args.vehicle_model), mocap_room=load_mocap_room(args.mocap_room),
        radio=load_radio_profile(args.radio), world=world, vehicles=args.vehicles, seed=args.seed,
        clock=args.clock, physics_rate_hz=args.physics_rate, prefix=args.prefix,
        connection="zenoh", zenoh_options=zenoh_options_from_args(args), start_positions_enu_m=starts,
        airborne=args.airborne, signing=signing_from_args(args), duration_s=args.duration,
    )


def emulator_command(argv: list[str]) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.WARNING if args.quiet else logging.INFO,
                        format="%(asctime)s %(name)s: %(message)s", stream=sys.stderr)
    config = config_from_args(args)
    emulator = Emulator(config)

    def stop(signum, frame):  # noqa: ARG001 - signal handler signature
        emulator.stopped = True

    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    with emulator:
        logging.getLogger("cfstack.emulator").info(
            "emulator up: %d vehicle(s), %s clock, radio %s, seed %d, keys %s/...",
            config.vehicles, config.clock, config.radio.name, config.seed, config.prefix)
        emulator.run()
    print(emulator.summary(), file=sys.stderr)
    return 0
