"""Fault injection in simulation time: outage windows for the radios and the mocap room.

Takes in: windows (start, duration) in simulated seconds (EmulatorConfig.radio_cuts / mocap_cuts,
`cfstack emulator --cut-radio` / `--cut-mocap`).
Gives out: `Outage` and `covered(windows, t)`.

Fault injection (EmulatorConfig.radio_cuts / mocap_cuts, `--cut-radio` / `--cut-mocap`), in
simulation time so lockstep runs stay deterministic: while a radio cut covers the time a frame is
offered to a radio (uplink: the tick time it is pushed at; downlink: its release time), the frame is
dropped before the radio, in both directions of every vehicle, and counted as `cut` (not as a radio
drop cause: the radio never sees it). While a mocap cut covers a mocap frame's release time, it is not
published (counted as `mocap_cut`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from model.errors import UserError


@dataclass(frozen=True)
class Outage:
    """A fault window in simulation time: from start_s for duration_s seconds (None: to the end)."""

    start_s: float
    duration_s: float | None = None

    @property
    def end_s(self) -> float:
        return math.inf if self.duration_s is None else self.start_s + self.duration_s

    def covers(self, t_s: float) -> bool:
        """start_s <= t_s < start_s + duration_s."""
        return self.start_s <= t_s < self.end_s

    def check(self, what: str) -> None:
        if not (isinstance(self.start_s, (int, float)) and math.isfinite(self.start_s) and self.start_s >= 0.0):
            raise UserError(f"{what}: start {self.start_s!r} is not a time >= 0 s")
        d = self.duration_s
        if d is not None and not (isinstance(d, (int, float)) and math.isfinite(d) and d > 0.0):
            raise UserError(f"{what}: duration {d!r} is not a positive number of seconds")


def covered(outages: tuple[Outage, ...], t_s: float) -> bool:
    """Whether any of the windows covers simulation time t_s."""
    return any(o.start_s <= t_s < o.end_s for o in outages)
