"""Checks shared by the trajectory tests (imported by test_basic_trajectories, test_constant_speed
and test_minsnap): a trajectory sample's five vectors, and that each sample's arrays are its own."""

from __future__ import annotations

import numpy as np

FIELDS = ("position_m", "velocity_mps", "acceleration_mps2", "jerk_mps3", "snap_mps4")


def derivatives(trajectory, t):
    out = trajectory.sample(t)
    return [np.asarray(getattr(out, f)) for f in FIELDS]


def assert_samples_are_fresh_arrays(trajectory, times):
    """Each sample's five vectors are its own: changing them in place changes nothing else."""
    for t in times:
        first, again = derivatives(trajectory, t), derivatives(trajectory, t)
        for k, vector in enumerate(first):
            assert isinstance(vector, np.ndarray) and vector.shape == (3,) and vector.dtype == float
            vector += 1000.0 * (k + 1)
        for k, vector in enumerate(first):
            np.testing.assert_array_equal(vector, again[k] + 1000.0 * (k + 1), err_msg=f"{FIELDS[k]} at t={t}")
        np.testing.assert_array_equal(derivatives(trajectory, t), again)
