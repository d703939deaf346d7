"""The latency compensator's compiled model steps (groundstation/_compensation_kernel.c) give the Python
twin's bits (LatencyCompensator._steps_python), prediction by prediction on random states and command
histories in both command modes, and hand back to the Python what it would refuse, which then raises what it
raises (issue 19: behaviour unchanged). What the steps compute is checked against the vehicle model in
test_controller.py (coasting, piecewise-constant acceleration between arrivals, the rate step)."""

from __future__ import annotations

import struct
from types import SimpleNamespace

import numpy as np
import pytest

from groundstation import compensation, compensation_kernel
from groundstation.compensation import LatencyCompensator, SentCommand
from model.vehicle import load_vehicle

needs_compiled = pytest.mark.skipif(
    not compensation_kernel.COMPILED,
    reason="groundstation/_compensation_kernel.c was not built (no C compiler at pip install): the Python predicts")

VEHICLE = load_vehicle("cf21")


def _bits(values) -> bytes:
    """The exact bits of a tuple of floats (NaN == NaN here, -0.0 != 0.0)."""
    return struct.pack(f"<{len(values)}d", *values)


def _unit(rng) -> tuple:
    q = rng.normal(size=4)
    return tuple((q / np.linalg.norm(q)).tolist())


def _draw(rng, mode: str):
    """A random prediction: state, commands (some acting before t, some arriving during the window), times."""
    step_s = 0.002 if mode == "moments" else 0.01
    latency = float(rng.uniform(0.0, 0.03))
    t = float(rng.uniform(0.0, 10.0))
    t_act = t + float(rng.uniform(-0.01, 0.05))  # now and then nothing to predict
    rate_scale = 1e3 if rng.random() < 0.05 else 10.0  # a few spin fast enough to wrap the attitude
    state = (*rng.uniform(-5, 5, 3).tolist(), *rng.uniform(-3, 3, 3).tolist(), *_unit(rng),
             *rng.uniform(-rate_scale, rate_scale, 3).tolist())
    commands, sent_s = [], t - latency - float(rng.uniform(0.0, 0.02))
    for _ in range(int(rng.integers(0, 7))):
        commands.append(SentCommand(sent_s, float(rng.uniform(0.0, 1.0)), tuple(rng.uniform(-0.01, 0.01, 3).tolist()),
                                    _unit(rng)))
        sent_s += float(rng.uniform(0.0, 0.01))
    return step_s, latency, t, t_act, state, commands


@needs_compiled
@pytest.mark.parametrize("mode", ["moments", "attitude"])
def test_the_compiled_steps_give_the_python_bits_on_random_predictions(mode):
    rng = np.random.default_rng(19)
    seen = {"coasted": 0, "arrived": 0, "stepped": 0, "nothing": 0}
    for _ in range(10000):
        step_s, latency, t, t_act, state, commands = _draw(rng, mode)
        compensator = LatencyCompensator(VEHICLE, mode, step_s)
        compensator.sent.extend(commands)
        acting, pending = compensator._acting_and_pending(t, latency)
        args = (t, t_act, state, acting, pending, latency)
        python = compensator._steps_python(*args)
        compiled = compensation_kernel.predict_steps(*args, compensator._constants, mode == "attitude")
        assert compiled is not None and _bits(compiled) == _bits(python), (mode, args)
        if t_act - 1e-12 <= t:
            seen["nothing"] += 1
        elif acting is None:
            seen["coasted"] += 1
        else:
            seen["stepped"] += 1
        seen["arrived"] += any(c.sent_s + latency < t_act for c in pending)
    assert min(seen.values()) > 500, seen  # every path ran often: coasting, stepping, arrivals, no window


def _compensator_with(mode: str, command: SentCommand) -> LatencyCompensator:
    compensator = LatencyCompensator(VEHICLE, mode, 0.002)
    compensator.sent.append(command)
    return compensator


def _estimate(attitude, rate):
    return SimpleNamespace(time_s=1.0, position_enu_m=np.zeros(3), velocity_enu_mps=np.zeros(3),
                           attitude_wxyz=np.array(attitude, float), rate_flu_radps=np.array(rate, float))


HOVER = SentCommand(0.0, 0.3, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0))


@pytest.mark.parametrize(("attitude", "rate", "command", "error"), [
    ((0.0, 0.0, 0.0, 0.0), (1.0, 0.0, 0.0), HOVER, ZeroDivisionError),  # a zero quaternion to normalise
    ((1.0, 0.0, 0.0, 0.0), (1e200, 0.0, 0.0), HOVER, ValueError),  # sin of an infinite angle (w^2 overflows)
    ((1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0), SentCommand(0.0, 0.3, (0.0, 0.0), (1.0, 0.0, 0.0, 0.0)), ValueError),
    ((1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0), SentCommand(0.0, "0.3", (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0)),
     TypeError),
])
def test_what_the_python_refuses_is_handed_back_and_raises_there(monkeypatch, attitude, rate, command, error):
    compensator = _compensator_with("moments", command)
    estimate = _estimate(attitude, rate)
    acting, pending = compensator._acting_and_pending(1.0, 0.005)
    if compensation_kernel.COMPILED:
        assert compensation_kernel.predict_steps(1.0, 1.01, (0.0,) * 6 + tuple(attitude) + tuple(rate), acting,
                                                 pending, 0.005, compensator._constants, False) is None
    with pytest.raises(error):
        compensator.predict(estimate, now_s=1.005, vehicle_minus_ground_s=0.0, uplink_latency_s=0.005)
    monkeypatch.setattr(compensation, "predict_steps", None)  # the Python alone raises the same
    with pytest.raises(error):
        compensator.predict(estimate, now_s=1.005, vehicle_minus_ground_s=0.0, uplink_latency_s=0.005)


def test_predict_gives_the_same_state_with_and_without_the_compiled_steps(monkeypatch):
    compensator = LatencyCompensator(VEHICLE, "moments", 0.002)
    for k in range(10):
        compensator.record(0.002 * k, 0.3 + 0.01 * k, (1e-4 * k, -2e-4, 3e-5), (1.0, 0.0, 0.0, 0.0))
    estimate = _estimate(_unit(np.random.default_rng(1)), (0.4, -0.2, 0.1))
    estimate.time_s = 0.012
    compiled = compensator.predict(estimate, now_s=0.02, vehicle_minus_ground_s=0.0, uplink_latency_s=0.006)
    monkeypatch.setattr(compensation, "predict_steps", None)
    python = compensator.predict(estimate, now_s=0.02, vehicle_minus_ground_s=0.0, uplink_latency_s=0.006)
    assert compiled == python and isinstance(compiled.position_enu_m, tuple)
