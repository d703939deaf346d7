"""The live view: a flight-loop observer that draws each frame into rerun as the flight goes.

Takes in: where to show it (spawn the viewer, or record to an .rrd file), the world, the plan dict
(plan.json's content) and the trajectory being flown, and TickFrames from the flight loop at
groundstation/params/view.toml's period of flight time.
Gives out: a rerun recording (groundstation.view.scene); `open_recording` also serves the replay.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rerun as rr

from groundstation.tickframe import TickFrame
from groundstation.view.scene import FlightView
from model.config import Params, resolve
from model.errors import UserError

APPLICATION_ID = "cfstack"


@dataclass(frozen=True)
class ViewSettings:
    period_s: float
    trajectory_samples: int
    batch_frames: int
    motor_outputs_hz: float
    motor_request_retry_s: float


def load_view_settings(name_or_path: str = "view") -> ViewSettings:
    p = Params.load(resolve(name_or_path, "groundstation", "params", "view settings"))
    return ViewSettings(p.number("period_s", 1e-3, 1.0), p.integer("trajectory_samples", 2),
                        p.integer("batch_frames", 1), p.number("motor_outputs_hz", 0.0),
                        p.number("motor_request_retry_s", 1e-3))


def open_recording(save_path: str | Path | None, name: str) -> rr.RecordingStream:
    """A recording streamed to a spawned viewer (save_path None) or written to save_path (.rrd)."""
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=name)
    if save_path is not None:
        path = Path(save_path)
        if not path.parent.is_dir():
            raise UserError(f"--view-save {path}: folder {path.parent} does not exist")
        rec.save(path)
        return rec
    try:
        rec.spawn()
    except Exception as err:  # noqa: BLE001 - rerun raises several kinds when no viewer can start
        raise UserError(f"--view: cannot start the rerun viewer ({err}); on a machine without a screen use "
                        "--view-save FILE.rrd and open it elsewhere with `rerun FILE.rrd`") from None
    return rec


class LiveView:
    """Observer of the flight loop (period_s, observe, close)."""

    def __init__(self, recording: rr.RecordingStream, settings: ViewSettings, world=None, plan: dict | None = None,
                 track=None):
        self.period_s = settings.period_s
        # the flight loop asks the vehicle for its motors' PWM at this rate (MAVLink; 0: not at all)
        self.motor_outputs_hz = settings.motor_outputs_hz
        self.motor_request_retry_s = settings.motor_request_retry_s
        self.rec = recording
        self.view = FlightView(recording, settings.batch_frames)
        self.view.world(world)
        if plan is not None:
            self.view.plan(_points(plan.get("path")), _points(plan.get("waypoints")))
        if track is not None:
            times = np.linspace(0.0, track.duration_s, settings.trajectory_samples)
            self.view.trajectory(np.array([track.sample(t).position_m for t in times], dtype=float))

    def observe(self, frame: TickFrame) -> None:
        self.view.frame(frame)

    def close(self) -> None:
        self.view.flush()
        self.rec.flush()
        self.rec.disconnect()


def _points(value) -> np.ndarray | None:
    return None if value is None else np.asarray(value, dtype=float).reshape(-1, 3)
