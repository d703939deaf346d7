"""`cfstack emulator`: start the emulated Crazyflie(s) on zenoh and run until stopped.

Takes in: command-line options (world, vehicles, radio profile, clock, seed, zenoh endpoints, key prefix,
injected faults --cut-radio / --cut-mocap AT[:DURATION] in simulated seconds; see `cfstack emulator --help`).
Gives out: a running emulator (see simulator.emulator), and with the realtime clock and the faithful
firmware, by default, CRTP for unmodified cflib clients on udp 127.0.0.1:19850+N-1 (--crtp-port), and
with the faithful firmware in either clock CRTP on each vehicle's zenoh keys (cflib's zenoh:// driver); on
Ctrl-C or SIGTERM (or after --duration simulated seconds) a clean stop and a one-line summary on stderr;
with --radio-ledger, a JSON file of the radio statistics (frames cut, the uplink parser's signature
failures) and every frame's fate.
Exit code 0; bad input (files, options) is one line on stderr and exit code 2, never a traceback.
"""

from __future__ import annotations

import argparse
import logging
import math
import signal
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from link.crtp.packet import CRTP_HOST, DEFAULT_CRTP_PORT
from link.keys import DEFAULT_PREFIX, MAX_VEHICLE_ID
from link.mavlink.signing import add_signing_arguments, signing_from_args
from link.transports.zenoh_session import DEFAULT_ENDPOINT, add_zenoh_arguments, zenoh_options_from_args
from model.errors import OneLineParser, UserError
from model.firmwares import DEFAULT_FIRMWARE, FIRMWARE_VEHICLES, default_vehicle_model
from model.options import finite_float, positive_float, seed, whole_number

if TYPE_CHECKING:
    from simulator.emulator_config import EmulatorConfig

# numpy, scipy and the emulator load only after the options are parsed: a mistyped option fails at once.

log = logging.getLogger("cfstack.emulator")


def _outage(text: str) -> tuple[float, float | None]:
    """AT[:DURATION] in simulated seconds -> (AT, DURATION or None for 'until the end')."""
    at_text, _, duration_text = text.partition(":")
    try:
        at = float(at_text)
        duration = float(duration_text) if duration_text else None
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not AT[:DURATION] in seconds (e.g. 8 or 8:0.5)") from None
    if not (math.isfinite(at) and at >= 0.0):
        raise argparse.ArgumentTypeError(f"'{text}': the start must be a time >= 0 s")
    if duration is not None and not (math.isfinite(duration) and duration > 0.0):
        raise argparse.ArgumentTypeError(f"'{text}': the duration must be a positive number of seconds")
    return at, duration


def build_parser() -> argparse.ArgumentParser:
    p = OneLineParser(prog="cfstack emulator", description=__doc__.splitlines()[0])
    p.add_argument("--world", help="world JSON file (default: an empty room)")
    p.add_argument("--vehicles", type=whole_number(1, "a vehicle count", MAX_VEHICLE_ID), default=1,
                   help="number of vehicles (ids 1..N)")
    p.add_argument("--vehicle-model", default=None,
                   help="vehicle name (cf21, crazyflie, cf2x) or TOML file (default: the firmware's: cf21 with "
                        "--firmware crazyflie, crazyflie with --firmware ideal)")
    p.add_argument("--mocap-room", default="vicon", help="mocap room name or TOML file")
    p.add_argument("--radio", help="radio profile of every radio, MAVLink's and CRTP's: a name (ideal, crazyradio, "
                                   "esb-duplex, lab, harsh) or TOML file; default: esb-duplex for MAVLink (its traffic "
                                   "does not fit one Crazyradio), crazyradio for CRTP")
    p.add_argument("--clock", choices=("realtime", "lockstep"), default="realtime",
                   help="realtime (default, as `cfstack groundstation`): paced by the wall clock; lockstep: "
                        "simulation time advances only as the ground stations acknowledge its ticks")
    p.add_argument("--seed", type=seed, default=1, help="seed of every random source (>= 0)")
    p.add_argument("--id", dest="prefix", default=DEFAULT_PREFIX, help="zenoh key prefix")
    p.add_argument("--radio-link", metavar="CONNECTION",
                   help="the radio link (each vehicle's uplink and downlink) on its own transport: udpin:HOST:PORT or "
                        "udpout:HOST:PORT (vehicle N on PORT+N-1), serial:DEVICE:BAUD (one vehicle, --clock "
                        "realtime); default: zenoh, on each vehicle's keys. Mocap, truth and the lockstep clock stay "
                        "on zenoh (the ground network)")
    p.add_argument("--physics-rate", type=positive_float, default=1000.0, help="physics steps per second")
    p.add_argument("--firmware", choices=tuple(FIRMWARE_VEHICLES), default=DEFAULT_FIRMWARE,
                   help="the onboard side: crazyflie (default: the Crazyflie's PID stabilizer on its own estimate, "
                        "PWM, battery) or ideal (the lab report's geometric law on the true state, exact mixer)")
    p.add_argument("--ideal", dest="ideal_parts", action="append", default=[], choices=("estimator", "battery"),
                   help="ablation studies only: make one part of the crazyflie firmware ideal (estimator: fly on "
                        "the true attitude; battery: full voltage, no sag) (repeatable)")
    p.add_argument("--vehicle-draw", default="nominal", metavar="PROFILE",
                   help="vehicle-to-vehicle variation: nominal (default) or a profile (lab, or a TOML file) from "
                        "which each vehicle draws its mass, centre of mass, motor thrusts and IMU alignment with "
                        "the seed; the ground station is not told")
    p.add_argument("--airborne", action="store_true", help="start hovering at the start point instead of on the floor")
    p.add_argument("--start", type=finite_float, nargs=3, metavar=("X", "Y", "Z"),
                   help="start of vehicle 1 (ENU, m); further vehicles 0.5 m apart along +x")
    p.add_argument("--duration", type=positive_float, help="stop after this many simulated seconds")
    p.add_argument("--no-lookahead", dest="lookahead", action="store_false",
                   help="lockstep: do not run physics ahead while waiting for acks (byte-identical results; "
                        "for comparison)")
    p.add_argument("--radio-ledger", metavar="FILE",
                   help="keep every radio frame's fate and write it with the radio statistics to FILE (JSON) "
                        "at exit (memory grows with the run: for tests and short runs)")
    p.add_argument("--cut-radio", type=_outage, action="append", default=[], metavar="AT[:DURATION]",
                   help="fault injection: from simulated time AT (s) for DURATION s (default: to the end), drop "
                        "every frame offered to either radio direction of every vehicle (repeatable)")
    p.add_argument("--cut-mocap", type=_outage, action="append", default=[], metavar="AT[:DURATION]",
                   help="fault injection: from simulated time AT (s) for DURATION s (default: to the end), "
                        "publish no mocap frames (repeatable)")
    p.add_argument("--crtp-port", type=_crtp_port, default=None, metavar="BASE|off",
                   help=f"serve unmodified cflib clients (CRTP over UDP) with vehicle N on {CRTP_HOST}:BASE+N-1, "
                        f"e.g. cflib's udp://{CRTP_HOST}:{DEFAULT_CRTP_PORT} (default: {DEFAULT_CRTP_PORT}, "
                        "CrazySim's convention, with --clock realtime and --firmware crazyflie, skipped with a "
                        "warning when the port is taken; off: none)")
    p.add_argument("--no-position-deck", dest="position_deck", action="store_false",
                   help="with CRTP: no simulated positioning deck (the onboard estimator then has a position only "
                        "from extpos/extpose)")
    p.add_argument("--quiet", action="store_true", help="log warnings only")
    add_zenoh_arguments(p, mode_flag="--zenoh-mode")
    add_signing_arguments(p)
    return p


def config_from_args(args: argparse.Namespace) -> EmulatorConfig:
    from model.radio import DEFAULT_CRTP_RADIO, DEFAULT_MAVLINK_RADIO, load_radio_profile
    from model.vehicle import load_mocap_room, load_vehicle
    from model.world import load_world
    from simulator.emulator_config import EmulatorConfig
    from simulator.faults import Outage
    from simulator.variation import load_variation

    if args.radio_ledger is not None and not Path(args.radio_ledger).resolve().parent.is_dir():
        raise UserError(f"--radio-ledger {args.radio_ledger}: no such directory to write it in")
    world = load_world(args.world) if args.world else None
    if world is not None:
        for warning in world.warnings:
            log.warning("%s", warning)
    starts = None
    if args.start is not None:
        x, y, z = args.start
        starts = [(x + 0.5 * i, y, z) for i in range(args.vehicles)]
    return EmulatorConfig(
        vehicle=load_vehicle(args.vehicle_model or default_vehicle_model(args.firmware)),
        mocap_room=load_mocap_room(args.mocap_room),
        radio=load_radio_profile(args.radio or DEFAULT_MAVLINK_RADIO),
        crtp_radio=load_radio_profile(args.radio or DEFAULT_CRTP_RADIO),
        world=world, vehicles=args.vehicles, seed=args.seed,
        clock=args.clock, physics_rate_hz=args.physics_rate, prefix=args.prefix,
        connection="zenoh", zenoh_options=_zenoh_options(args), radio_link=args.radio_link,
        start_positions_enu_m=starts,
        airborne=args.airborne, firmware=args.firmware, variation=load_variation(args.vehicle_draw),
        ideal_parts=tuple(args.ideal_parts),
        signing=signing_from_args(args), duration_s=args.duration,
        lookahead=args.lookahead, keep_ledger=args.radio_ledger is not None,
        radio_cuts=tuple(Outage(at, duration) for at, duration in args.cut_radio),
        mocap_cuts=tuple(Outage(at, duration) for at, duration in args.cut_mocap),
        # the uplink gate keeps a signing state of its own (simulator.emulator.GroundFrameGate)
        signing_factory=lambda: signing_from_args(args),
        **_crtp_settings(args),
    )


def _crtp_port(text: str) -> int | str:
    if text == "off":
        return text
    return whole_number(1, "a UDP port", 65535)(text)


def _crtp_settings(args: argparse.Namespace) -> dict:
    """CRTP on by default where it can run (realtime, faithful firmware), on the CrazySim port."""
    if args.crtp_port == "off":
        return {"crtp_base_port": None}
    settings = {"crtp_base_port": args.crtp_port, "crtp_host": CRTP_HOST, "position_deck": args.position_deck}
    if args.crtp_port is None:
        default_on = args.clock == "realtime" and args.firmware == "crazyflie"
        settings.update(crtp_base_port=DEFAULT_CRTP_PORT if default_on else None, crtp_required=False)
    return settings


def _zenoh_options(args: argparse.Namespace) -> dict:
    """The zenoh options given, listening on DEFAULT_ENDPOINT (where `cfstack groundstation` connects by
    default) when neither --connect nor --listen is."""
    options = zenoh_options_from_args(args)
    if not options.get("connect") and not options.get("listen"):
        options["listen"] = [DEFAULT_ENDPOINT]
    return options


def emulator_command(argv: list[str]) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.WARNING if args.quiet else logging.INFO,
                        format="%(asctime)s %(name)s: %(message)s", stream=sys.stderr)
    from simulator.emulator import Emulator

    config = config_from_args(args)
    emulator = Emulator(config)

    def stop(signum, frame):  # noqa: ARG001 - signal handler signature
        emulator.stopped = True

    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    with emulator:
        radio_link = ("on the keys" if config.radio_link is None
                      else f"on {config.radio_link}" + (" (vehicle N: PORT+N-1)" if config.vehicles > 1 else ""))
        log.info("emulator up: %d vehicle(s), %s clock, radio %s (CRTP %s) %s, seed %d, keys %s/vehicle/1..%d/..., "
                 "lookahead %.3f ms", config.vehicles, config.clock, config.radio.name, config.crtp_radio_profile.name,
                 radio_link, config.seed,
                 config.prefix, config.vehicles, emulator.lockstep.lookahead_horizon_s() * 1e3)
        from link.mavlink import frame_kernel
        from simulator import dynamics_kernels  # loaded already (the dynamics): asked here for the warning only
        from simulator.crazyflie import drive_kernel, pid_kernel

        missing = [name for name, compiled in (("the RK4 step and rotor lag", dynamics_kernels.COMPILED),
                                               ("the faithful firmware's drive chain", drive_kernel.COMPILED),
                                               ("the faithful firmware's attitude and rate PIDs", pid_kernel.COMPILED),
                                               ("the MAVLink frames' encoder and parser", frame_kernel.COMPILED))
                   if not compiled]
        if missing:
            log.warning("emulator: compiled kernels not built (no C compiler at pip install?): %s; their Python "
                        "twins run, same results, slower (README: Lockstep speed)", "; ".join(missing))
        emulator.run()
    if args.radio_ledger:
        emulator.write_radio_report(args.radio_ledger)
    print(emulator.summary(), file=sys.stderr)
    return 0
