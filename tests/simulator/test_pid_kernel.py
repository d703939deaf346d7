"""The faithful firmware's compiled attitude and rate PIDs (simulator/crazyflie/_pid_kernel.c) give the Python's
bits: AttitudeController.correct_attitude and correct_rate (through the kernel) against correct_attitude_python
and correct_rate_python (through Pid.update), outputs and every PID's state, on random gains, states and
inputs, special values included, and over a whole flight (issue 19: behaviour unchanged). What the PIDs compute
is checked against the firmware's definitions in test_crazyflie_parts.py. Also here: the attitude setpoint the
stabilizer keeps between setpoints (built once per setpoint) is the one it would build each cycle."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest
from faithful_flight import fly_faithful

from link.messages import AttitudeTarget, CommandKind, VehicleCommand
from model.frames import quat_from_euler_zyx
from model.vehicle import load_vehicle
from simulator.crazyflie import attitude_controller, pid_kernel
from simulator.crazyflie.attitude_controller import AttitudeController
from simulator.crazyflie.controller_pid import Setpoint
from simulator.crazyflie.pid import Pid
from simulator.crazyflie.stabilizer import ATTITUDE_MODES, CrazyflieFirmware, _legacy_rpy_deg, load_crazyflie_params
from simulator.firmware import load_firmware_params

needs_compiled = pytest.mark.skipif(
    not pid_kernel.COMPILED,
    reason="simulator/crazyflie/_pid_kernel.c was not built (no C compiler at pip install): the Python runs")

STATE = ("integ", "prev_measured", "out_p", "out_i", "out_d")
SPECIAL = (float("nan"), float("inf"), -float("inf"), 1e300, -0.0, 0.0)
DT = 1.0 / 500.0


def _bits(values) -> bytes:
    """The doubles' bits, every NaN as one NaN: IEEE leaves a NaN's sign and payload, where both operands of an
    addition are NaN, to the operand order the compiler picks, in CPython's float_add as in the kernel; nothing
    but the raw bits of a NaN can tell them apart (it prints as nan, compares and propagates alike)."""
    return struct.pack(f"{len(values)}d", *(math.nan if v != v else v for v in values))


def _state(controller: AttitudeController) -> bytes:
    return _bits([getattr(pid, name) for pid in (*controller.attitude, *controller.rate) for name in STATE])


def _random_controller(rng: np.random.Generator) -> AttitudeController:
    """Gains of the firmware's magnitudes, limits zero (off) or not, a feed-forward now and then, and states
    that start anywhere."""
    def gains() -> dict:
        return {"kp": [float(v) for v in rng.uniform(0.0, 300.0, 3)],
                "ki": [float(v) for v in rng.uniform(0.0, 600.0, 3)],
                "kd": [float(v) for v in rng.uniform(0.0, 5.0, 3)],
                "integration_limit": [float(rng.choice([0.0, rng.uniform(1.0, 400.0)])) for _ in range(3)]}
    controller = AttitudeController(gains(), gains(), DT)
    for pid in (*controller.attitude, *controller.rate):
        pid.output_limit = float(rng.choice([0.0, rng.uniform(10.0, 2000.0)]))
        pid.kff = float(rng.choice([0.0, rng.uniform(-1.0, 1.0)]))
        pid.integ = float(rng.normal(scale=50.0))
        pid.prev_measured = float(rng.uniform(-360.0, 360.0))
    return controller


def _random_vector(rng: np.random.Generator, scale: float) -> tuple[float, float, float]:
    values = [float(v) for v in rng.uniform(-scale, scale, 3)]
    if rng.random() < 0.05:
        values[int(rng.integers(3))] = SPECIAL[int(rng.integers(len(SPECIAL)))]
    return tuple(values)


def _both(controller: AttitudeController, name: str, actual, desired):
    """The call through the kernel and through the Python, from the same state: (result, types, state bits)
    each, or the exception's type."""
    start = {id(pid): [getattr(pid, field) for field in STATE] for pid in (*controller.attitude, *controller.rate)}
    results = []
    for method in (getattr(controller, name), getattr(controller, f"{name}_python")):
        for pid in (*controller.attitude, *controller.rate):
            for field, value in zip(STATE, start[id(pid)], strict=True):
                setattr(pid, field, value)
        try:
            out = method(actual, desired)
            results.append((_bits([float(v) for v in out]), tuple(type(v) for v in out), _state(controller)))
        except (ArithmeticError, ValueError) as error:
            results.append((type(error), _state(controller)))
    return results


def _compared_calls(seed: int, name: str, scale: float, calls: int = 5000):
    """`calls` calls of the controller's `name` on random controllers and inputs within +-scale, each through
    the kernel and the Python and asserted alike; yields (controller after the call, actual, desired, the
    kernel's outcome as _both gives it)."""
    rng = np.random.default_rng(seed)
    for _ in range(calls):
        controller = _random_controller(rng)
        actual, desired = _random_vector(rng, scale), _random_vector(rng, scale)
        compiled, python = _both(controller, name, actual, desired)
        assert compiled == python, (actual, desired)
        yield controller, actual, desired, compiled


@needs_compiled
def test_compiled_attitude_pids_are_the_pythons_bit_for_bit():
    wrapped = clamped = limited = 0
    for controller, actual, desired, _ in _compared_calls(31, "correct_attitude", 200.0):
        wrapped += abs(desired[2] - actual[2]) > 180.0
        clamped += any(p.i_limit and abs(p.integ) == p.i_limit for p in controller.attitude)
        limited += any(p.output_limit and abs(p.out_p + p.out_d + p.out_i + p.kff * d) > p.output_limit
                       for p, d in zip(controller.attitude, desired, strict=True))
    assert wrapped > 500 and clamped > 500 and limited > 500, (wrapped, clamped, limited)


@needs_compiled
def test_compiled_rate_pids_are_the_pythons_bit_for_bit():
    """int16 outputs, saturated at +-32767 and truncated toward zero; a NaN output raises ValueError (int() of
    NaN) in both, the PIDs before it updated and those after it not."""
    saturated = truncated = raised = 0
    for _, _, _, compiled in _compared_calls(32, "correct_rate", 2000.0):
        if compiled[0] is ValueError:
            raised += 1
            continue
        assert compiled[1] == (int, int, int)
        out = struct.unpack("3d", compiled[0])
        saturated += any(abs(v) == 32767 for v in out)
        truncated += any(v != 0 and abs(v) < 32767 for v in out)
    assert saturated > 500 and truncated > 500 and raised > 100, (saturated, truncated, raised)


@needs_compiled
def test_the_kernel_leaves_to_the_python_what_it_does_not_do_alike():
    """Values that are not floats (ints, numpy numbers, a bool), a tuple of PIDs of another length and a zero
    dt: the kernel answers None without changing a PID, and the controller gives what the Python gives."""
    controller = AttitudeController(load_crazyflie_params().pid_attitude, load_crazyflie_params().pid_rate, DT)
    for actual, desired in (((1, 2.0, 3.0), (0.0, 0.0, 0.0)), ((1.0, 2.0, 3.0), np.array([0.0, 1.0, 2.0])),
                            ((1.0, 2.0), (0.0, 0.0, 0.0)), ((1.0, 2.0, 3.0), [0.0, 0.0, True])):
        before = _state(controller)
        assert pid_kernel.update3(controller.attitude, desired, actual, True, False) is None
        assert _state(controller) == before
        if len(actual) == 3:
            compiled, python = _both(controller, "correct_attitude", actual, desired)
            assert compiled == python
    assert pid_kernel.update3(controller.attitude[:2], (0.0,) * 3, (1.0,) * 3, True, False) is None
    unit = {"kp": [1.0] * 3, "ki": [1.0] * 3, "kd": [1.0] * 3, "integration_limit": [0.0] * 3}
    stopped = AttitudeController(unit, unit, 0.0)
    assert pid_kernel.update3(stopped.rate, (0.0,) * 3, (1.0,) * 3, False, True) is None
    compiled, python = _both(stopped, "correct_rate", (1.0,) * 3, (0.0,) * 3)
    assert compiled == python and compiled[0] is ZeroDivisionError
    odd = Pid(1, 0.0, 0.0, DT, 0.0)  # an int gain
    assert pid_kernel.update3((odd, *controller.attitude[1:]), (0.0,) * 3, (1.0,) * 3, True, False) is None
    with pytest.raises(TypeError, match="update3 takes 5 arguments"):
        pid_kernel.update3(controller.attitude, (0.0,) * 3, (1.0,) * 3, True)


def _fly(steps: int) -> list[bytes]:
    """Every step's PWM and truth of the faithful vehicle flown in attitude mode by setpoints that tilt and turn
    it, its yaw passing +-180 deg, with the mocap pose streamed as extpose (faithful_flight)."""
    def record(sim) -> bytes:
        truth = sim.truth
        return repr(sim.firmware.motor_pwm).encode() + _bits([*truth.position_enu_m, *truth.attitude_wxyz])
    return fly_faithful("cf21", "attitude", steps, record, seed=4, yaw_rad=lambda t: 2.0 * t)


@needs_compiled
def test_a_flight_on_the_compiled_pids_is_the_flight_on_the_python(monkeypatch):
    answered = []  # per call: did the kernel answer (not hand back to the Python)?

    def counted(*args):
        outputs = pid_kernel.update3(*args)
        answered.append(outputs is not None)
        return outputs

    monkeypatch.setattr(attitude_controller, "update3", counted)
    compiled = _fly(4000)
    assert len(answered) == 4000 and all(answered)  # two per 500 Hz cycle: every cycle ran on the kernel
    monkeypatch.setattr(attitude_controller, "update3", None)  # the Python
    python = _fly(4000)
    assert compiled == python
    assert len(set(compiled)) == len(compiled)  # airborne and moving every step


def test_the_kept_attitude_setpoint_is_the_one_built_from_the_newest_setpoint():
    fw = CrazyflieFirmware(load_vehicle("cf21"), load_firmware_params())
    assert fw.receive(VehicleCommand(0.0, CommandKind.ARM), 0.0) and fw.armed
    for k, (roll, thrust) in enumerate(((0.1, 0.3), (0.1, 0.3), (-0.2, 0.3), (-0.2, 0.25))):
        q = tuple(quat_from_euler_zyx(roll, 0.05, 1.0))
        fw.receive(AttitudeTarget(0.01 * k, thrust, q), 0.01 * k)
        kept = fw._attitude_setpoint()
        expected = Setpoint(ATTITUDE_MODES, _legacy_rpy_deg(fw._sp_attitude), thrust_pwm=fw._thrust_pwm(thrust))
        assert kept == expected
        assert fw._attitude_setpoint() is kept  # the cycles until the next setpoint reuse it
    assert kept.attitude_deg[0] == pytest.approx(np.degrees(-0.2)) and kept.thrust_pwm == fw._thrust_pwm(0.25)
