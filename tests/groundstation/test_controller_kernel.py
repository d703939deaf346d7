"""The SE(3) controller's compiled report law (groundstation/_controller_kernel.c) gives the Python twin's bits
(SE3Controller._update_python), step by step on random states and references, its degenerate branches
included, and hands back to the Python what it would refuse or compute differently (issue 19: behaviour
unchanged). What the law computes is checked against the lab report and Lee et al. in test_controller.py."""

from __future__ import annotations

import dataclasses
import math
import struct

import numpy as np
import pytest

from groundstation import controller, controller_kernel
from groundstation.controller import ControllerState, ControlOutput, SE3Controller, load_gains
from groundstation.trajectory import FlatOutput
from model.vehicle import GRAVITY_MPS2, load_vehicle

needs_compiled = pytest.mark.skipif(
    not controller_kernel.COMPILED,
    reason="groundstation/_controller_kernel.c was not built (no C compiler at pip install): the Python controls")

VEHICLE = load_vehicle("cf21")


def _bits(output: ControlOutput) -> list:
    """Every field with its type and exact bits (NaN == NaN here, -0.0 != 0.0)."""
    def one(v):
        return (type(v).__name__, struct.pack("<d", v)) if isinstance(v, float) else (type(v).__name__, v)
    return [tuple(map(one, v)) if isinstance(v, tuple) else one(v)
            for v in (getattr(output, f.name) for f in dataclasses.fields(ControlOutput))]


def _unit(rng) -> np.ndarray:
    q = rng.normal(size=4)
    return q / np.linalg.norm(q)


def _draw(rng):
    """A random state and reference; now and then a degenerate one: free fall commanded (F_des = 0), or the
    thrust axis along the heading (b3_des x a_psi = 0), or a quaternion far from unit norm."""
    state = ControllerState(rng.uniform(-3, 3, 3), rng.uniform(-4, 4, 3), _unit(rng) * rng.choice([1.0, 1.0, 7.5]),
                            rng.uniform(-20, 20, 3))
    acceleration = rng.uniform(-15, 15, 3)
    kind = rng.integers(0, 6)
    if kind == 0:  # zero gains' worth: the reference at the state, falling freely
        reference = FlatOutput(np.array(state.position_enu_m), np.array(state.velocity_enu_mps),
                               np.array([0.0, 0.0, -GRAVITY_MPS2]), yaw_rad=float(rng.uniform(-4, 4)))
        return state, reference
    if kind == 1:  # F_des horizontal along the heading: b3_des is a_psi, the cross product vanishes
        yaw = float(rng.uniform(-4, 4))
        reference = FlatOutput(np.array(state.position_enu_m), np.array(state.velocity_enu_mps),
                               np.array([5.0 * math.cos(yaw), 5.0 * math.sin(yaw), -GRAVITY_MPS2]), yaw_rad=yaw)
        return state, reference
    reference = FlatOutput(rng.uniform(-3, 3, 3), rng.uniform(-4, 4, 3), acceleration,
                           yaw_rad=float(rng.uniform(-4, 4)))
    return state, reference


@needs_compiled
def test_the_compiled_law_gives_the_python_bits_on_random_steps():
    ctl = SE3Controller(VEHICLE, load_gains())
    assert ctl._report_constants is not None  # the report law, compiled
    rng = np.random.default_rng(19)
    seen = {"thrust_saturated": 0, "moment_saturated": 0, "free_fall": 0, "along_heading": 0}
    for _ in range(20000):
        state, reference = _draw(rng)
        args = (state.position_enu_m, state.velocity_enu_mps, state.attitude_wxyz, state.rate_flu_radps,
                reference.position_m, reference.velocity_mps, reference.acceleration_mps2, reference.yaw_rad,
                ctl._report_constants, ControlOutput)
        compiled = controller_kernel.se3_update(*args)
        python = ctl._update_python(state, reference)
        assert compiled is not None and _bits(compiled) == _bits(python), (state, reference)
        seen["thrust_saturated"] += python.thrust_saturated
        seen["moment_saturated"] += any(python.moment_saturated)
        seen["free_fall"] += np.linalg.norm(python.force_des_enu_n) <= controller._DEGENERATE_NORM
        f = np.asarray(python.force_des_enu_n)
        seen["along_heading"] += abs(f[2]) < 1e-9 < np.linalg.norm(f)
    assert min(seen.values()) > 500, seen  # every branch ran often


@needs_compiled
def test_update_runs_the_compiled_law_and_the_full_variant_runs_the_python(monkeypatch):
    rng = np.random.default_rng(7)
    state, reference = _draw(rng)
    report = SE3Controller(VEHICLE, load_gains())
    compiled = report.update(state, reference)
    monkeypatch.setattr(controller, "se3_update", None)
    assert SE3Controller(VEHICLE, load_gains())._report_constants is None  # not built: the Python alone
    assert _bits(SE3Controller(VEHICLE, load_gains()).update(state, reference)) == _bits(compiled)
    assert SE3Controller(VEHICLE, load_gains(), variant="full")._report_constants is None


@pytest.mark.parametrize(("attitude", "yaw", "error"), [
    ((0.0, 0.0, 0.0, 0.0), 0.0, ZeroDivisionError),  # an attitude of zero norm to normalise
    ((1.0, 0.0, 0.0, 0.0), math.inf, ValueError),  # cos and sin of an infinite yaw
])
def test_what_the_python_refuses_is_handed_back_and_raises_there(monkeypatch, attitude, yaw, error):
    ctl = SE3Controller(VEHICLE, load_gains())
    state = ControllerState(np.zeros(3), np.zeros(3), np.array(attitude), np.zeros(3))
    reference = FlatOutput(np.array([0.0, 0.0, 1.0]), yaw_rad=yaw)
    if controller_kernel.COMPILED:
        assert controller_kernel.se3_update(
            state.position_enu_m, state.velocity_enu_mps, state.attitude_wxyz, state.rate_flu_radps,
            reference.position_m, reference.velocity_mps, reference.acceleration_mps2, reference.yaw_rad,
            ctl._report_constants, ControlOutput) is None
    with pytest.raises(error):
        ctl.update(state, reference)
    monkeypatch.setattr(controller, "se3_update", None)
    with pytest.raises(error):
        SE3Controller(VEHICLE, load_gains()).update(state, reference)


@needs_compiled
@pytest.mark.parametrize("vector", [(0, 0, 1), np.array([0.0, 0.0, 1.0], np.float32), [0.0, 0.0, 1.0]])
def test_vectors_other_than_float64_give_the_python_result(vector):
    """Ints (exact in Python's arithmetic) and float32 arrays are left to the Python; lists of floats are read."""
    ctl = SE3Controller(VEHICLE, load_gains())
    state = ControllerState(vector, (0.1, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), (0.0, 0.2, 0.0))
    reference = FlatOutput(np.array([0.0, 0.5, 1.0]), yaw_rad=0.3)
    assert _bits(ctl.update(state, reference)) == _bits(ctl._update_python(state, reference))


def test_control_output_is_still_what_the_kernel_builds_it_as():
    """The kernel fills a ControlOutput's slots as its generated __init__ does: that holds while the class
    has slots, no defaults and no __post_init__."""
    fields = dataclasses.fields(ControlOutput)
    assert ControlOutput.__slots__ == tuple(f.name for f in fields)
    assert all(f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING for f in fields)
    assert not hasattr(ControlOutput, "__post_init__") and ControlOutput.__dataclass_params__.frozen
