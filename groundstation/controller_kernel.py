"""The SE(3) controller's "report" law (the lab report's: no feed-forward, no gyroscopic term), compiled
(issue 19): SE3Controller.update's work once per control tick, on the ground station's critical path.

Takes in: report_constants packs the model mass (kg), the gains K_p, K_d (per axis), K_R, K_w (normalised
by the inertia), the diagonal inertia (kg m^2), the thrust limit (N), the moment limits (N m), gravity (m/s^2)
and the controller's degenerate norm, in the kernel's order.
Gives out: `se3_update`, the compiled kernel (groundstation/_controller_kernel.c, built by `pip install`), or
None where it was not built; given the state's and the reference's vectors, the yaw, the constants and the
ControlOutput class, it returns the ControlOutput the Python twin (SE3Controller._update_python) returns,
or None for a step it leaves to the Python. The "full" variant (Lee et al.'s feed-forward) always runs the
Python.

They give the same bits (tests/groundstation/test_controller_kernel.py). Why compiled: the law ran in 7.9 us
per call in Python (a replay of a moments circle's calls).
"""

from __future__ import annotations

from model.vehicle import GRAVITY_MPS2

try:
    from groundstation._controller_kernel import se3_update
except ImportError:  # not built (no C compiler at install): the controller runs its Python, same results
    se3_update = None

COMPILED = se3_update is not None


def report_constants(mass_kg: float, position_gains: tuple, k_r, k_w, inertia_diag_kgm2: tuple,
                     max_thrust_n: float, max_moment_nm: tuple, degenerate_norm: float) -> tuple:
    """The kernel's constants, in _controller_kernel.c's order (its enum)."""
    return tuple(float(v) for v in (mass_kg, *position_gains, *k_r, *k_w, *inertia_diag_kgm2, max_thrust_n,
                                    *max_moment_nm, GRAVITY_MPS2, degenerate_norm))
