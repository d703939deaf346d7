"""The latency compensator's model steps, compiled (issue 19): the part of LatencyCompensator.predict that
integrates the vehicle model from the estimate's time to the time the command will act.

Takes in: step_constants packs the compensator's step (s), the vehicle's mass (kg) and diagonal inertia
(kg m^2), gravity (m/s^2) and model.frames' negligible rotation angle (rad), in the kernel's order.
Gives out: `predict_steps`, the compiled kernel (groundstation/_compensation_kernel.c, built by
`pip install`), or None where it was not built; its arguments and result are the Python twin's,
LatencyCompensator._steps_python (groundstation/compensation.py): the state at t_act as 13 floats, or
None for a prediction it leaves to the Python.

They give the same bits (tests/groundstation/test_compensation_kernel.py). Why compiled: the steps ran on the ground
station's critical path every tick, 9.2 us per call in Python (a replay of a moments circle's calls).
"""

from __future__ import annotations

from model.frames import _NEGLIGIBLE_ANGLE_RAD
from model.vehicle import GRAVITY_MPS2

try:
    from groundstation._compensation_kernel import predict_steps
except ImportError:  # not built (no C compiler at install): the compensator runs its Python, same results
    predict_steps = None

COMPILED = predict_steps is not None


def step_constants(step_s: float, mass_kg: float, inertia_diag_kgm2: tuple[float, float, float]) -> tuple:
    """The kernel's constants, in _compensation_kernel.c's order (its enum)."""
    return tuple(float(v) for v in (step_s, mass_kg, *inertia_diag_kgm2, GRAVITY_MPS2, _NEGLIGIBLE_ANGLE_RAD))
