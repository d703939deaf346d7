"""The trajectory interface every reference generator implements.

Takes in: time since the start of tracking, seconds.
Gives out: a FlatOutput (position, velocity, acceleration, jerk, snap in world ENU, SI units; yaw rad).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np


def _zero3() -> np.ndarray:
    return np.zeros(3)


@dataclass(frozen=True)
class FlatOutput:
    position_m: np.ndarray
    velocity_mps: np.ndarray = field(default_factory=_zero3)
    acceleration_mps2: np.ndarray = field(default_factory=_zero3)
    jerk_mps3: np.ndarray = field(default_factory=_zero3)
    snap_mps4: np.ndarray = field(default_factory=_zero3)
    yaw_rad: float = 0.0
    yaw_rate_radps: float = 0.0


class Trajectory(Protocol):
    """A reference to track. Before 0 it holds the start, after `duration_s` the end, at rest.

    Optional `sample_is_pure` (class attribute, default False): True when sample(t) depends on t alone
    and never raises, so the mission may sample it later than the tick that asked (MissionStep)."""

    duration_s: float

    def sample(self, t_s: float) -> FlatOutput: ...
