"""Building FlatOutputs cheaply from plain floats: the per-tick half of every trajectory's sample().

Takes in: the 15 numbers of a reference (position, velocity, acceleration, jerk, snap; world ENU, SI) as
Python floats, or a rest position; polynomial coefficients (lowest power first) and an argument.
Gives out: a groundstation.trajectory.FlatOutput with fresh numpy arrays (callers may keep or modify
them), and polynomial values.

Why: sample() runs twice per control tick (500 Hz). Arithmetic on Python floats costs ~30 ns an operation
while each numpy call on a 3-vector costs ~1 us, so trajectories compute in floats and make arrays once,
here: one 15-element array sliced into five views (the slices do not overlap) is the cheapest way to get
five fresh 3-vectors (see benchmarks/controller_bench.py).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from groundstation.trajectory import FlatOutput


def flat_output(values: list[float], yaw_rad: float = 0.0, yaw_rate_radps: float = 0.0) -> FlatOutput:
    """A FlatOutput from [x, y, z, vx, vy, vz, ax, ..., snap_z] (m, m/s, m/s^2, m/s^3, m/s^4)."""
    a = np.array(values)
    return FlatOutput(a[0:3], a[3:6], a[6:9], a[9:12], a[12:15], yaw_rad, yaw_rate_radps)


def at_rest(position_m: np.ndarray, yaw_rad: float = 0.0) -> FlatOutput:
    """A FlatOutput at rest at position_m (a copy of it), all derivatives zero."""
    zeros = np.zeros
    return FlatOutput(position_m.copy(), zeros(3), zeros(3), zeros(3), zeros(3), yaw_rad)


def polyval(coefficients: Sequence[float], x: float) -> float:
    """sum_k c_k x^k by Horner's rule, the same operations in the same order as numpy's polyval."""
    value = coefficients[-1]
    for c in coefficients[-2::-1]:
        value = c + value * x
    return value
