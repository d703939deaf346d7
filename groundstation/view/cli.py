"""`cfstack view LOGDIR`: replay a flight's logs into the same rerun view the live flight showed.

Takes in: a flight log folder (states.csv; plan.json and its world when the flight was planned), and
--save FILE.rrd to record instead of spawning the viewer.
Gives out: the rerun recording (groundstation.view.scene), frames at view.toml's period of flight time
(as live), the trajectory drawn from the references the log holds; exit 0, or 2 with one line on bad
input (missing folder, malformed log, no viewer).
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from groundstation.logread import read_log
from groundstation.tickframe import frames_from_log
from groundstation.view.live import load_view_settings, open_recording
from groundstation.view.scene import FlightView
from model.errors import OneLineParser, UserError, WorldError
from model.world import load_world


def build_parser() -> argparse.ArgumentParser:
    p = OneLineParser(prog="cfstack view", description="Replay a flight's logs into the rerun 3-D view.")
    p.add_argument("log_dir", metavar="LOGDIR", help="flight log folder (holds states.csv)")
    p.add_argument("--save", metavar="FILE.rrd", help="record to this file instead of spawning the viewer")
    return p


def command(argv: list[str]) -> int:
    args = build_parser().parse_args(argv)
    try:
        count = replay(args.log_dir, args.save)
    except UserError as err:
        print(f"cfstack view: {err}", file=sys.stderr)
        return 2
    print(f"replayed {count} frames of {args.log_dir}" + (f" into {args.save}" if args.save else ""))
    return 0


def replay(log_dir: str, save_path: str | None) -> int:
    log = read_log(log_dir)
    settings = load_view_settings()
    rec = open_recording(save_path, f"replay {log.folder.name}")
    view = FlightView(rec, settings.batch_frames)
    if log.plan is not None:
        try:
            view.world(load_world(log.plan.world_path))
        except WorldError as err:
            print(f"cfstack view: drawn without blocks: {err}", file=sys.stderr)
        view.plan(log.plan.path_m, log.plan.waypoints_m)
    reference = log.position_m("ref")
    view.trajectory(reference[np.isfinite(reference).all(axis=1)])
    shown, next_s = 0, -np.inf
    for frame in frames_from_log(log):
        if frame.t_s >= next_s:
            view.frame(frame)
            next_s = frame.t_s + settings.period_s
            shown += 1
    view.flush()
    rec.flush()
    rec.disconnect()
    return shown
