"""The faithful firmware's compiled power stage (simulator/crazyflie/_drive_kernel.c) gives the Python's bits:
the drive chain (CrazyflieFirmware._drive_python: battery compensation, the cap, the motor forces, the
battery's draw and the rotor speeds) and the force-torque mixer (ForceTorqueMixer.pwm_python), cycle by
cycle on random commands and battery states, and over whole flights (issue 19: behaviour unchanged). What
the chain computes is checked against the firmware's definitions in test_crazyflie_parts.py and
test_crazyflie_crtp.py (the compensation inverts the thrust curve, the battery sags by R I)."""

from __future__ import annotations

import dataclasses
import struct

import numpy as np
import pytest
from faithful_flight import fly_faithful

from model.vehicle import load_vehicle
from simulator.crazyflie import drive_kernel
from simulator.crazyflie.stabilizer import CrazyflieFirmware, load_crazyflie_params
from simulator.firmware import MOTORS_OFF, load_firmware_params

needs_compiled = pytest.mark.skipif(
    not drive_kernel.COMPILED,
    reason="simulator/crazyflie/_drive_kernel.c was not built (no C compiler at pip install): the Python drives")

STATE = ("supply_v", "battery.voltage_v", "battery.current_a", "battery.drawn_as")


def _firmware(**curve_changes) -> CrazyflieFirmware:
    cf = load_crazyflie_params()
    if curve_changes:
        cf = dataclasses.replace(cf, curve=dataclasses.replace(cf.curve, **curve_changes))
    return CrazyflieFirmware(load_vehicle("cf21"), load_firmware_params(), cf)


def _get(fw, name: str):
    obj = fw
    for part in name.split(".")[:-1]:
        obj = getattr(obj, part)
    return getattr(obj, name.split(".")[-1])


def _set(fw, name: str, value) -> None:
    obj = fw
    for part in name.split(".")[:-1]:
        obj = getattr(obj, part)
    setattr(obj, name.split(".")[-1], value)


def _bits(values) -> bytes:
    return struct.pack(f"{len(values)}d", *values)


def _outcome(fw, speeds) -> tuple:
    """What a cycle leaves: the speeds, the PWM (ints, compared exactly), forces and state (compared as bits)."""
    floats = [*fw.motor_forces_n, *(_get(fw, name) for name in STATE)]
    return (speeds if speeds is MOTORS_OFF else _bits(speeds)), tuple(fw.motor_pwm), _bits(floats), \
        tuple(type(p) for p in fw.motor_pwm)


def _both(fw, uncapped, state: dict):
    """The cycle on the compiled kernel (through _drive, as the firmware runs it) and on the Python, from the
    same state; each as _outcome, or the exception it raised."""
    results = []
    for run in (fw._drive, fw._drive_python):
        for name, value in state.items():
            _set(fw, name, value)
        try:
            results.append(_outcome(fw, run(uncapped)))
        except (ArithmeticError, ValueError, TypeError) as error:
            results.append(type(error))
    return results


def _random_state(rng: np.random.Generator, fw) -> dict:
    b = fw.battery
    return {"supply_v": float(rng.choice([rng.uniform(1.0, 4.5), fw.cf.curve.min_supply_v])),
            "battery.voltage_v": float(rng.uniform(2.5, 4.3)), "battery.current_a": float(rng.uniform(0.0, 10.0)),
            "battery.drawn_as": float(rng.choice([rng.uniform(0.0, b.capacity_as), 1.5 * b.capacity_as]))}


def _random_command(rng: np.random.Generator) -> tuple[int, int, int, int]:
    kind = rng.integers(4)
    if kind == 0:
        return (0, 0, 0, 0)  # disarmed
    if kind == 1:  # above the cap: the shift down
        return tuple(int(v) for v in rng.integers(40000, 140000, 4))
    return tuple(int(v) for v in rng.integers(-70000, 70000, 4))  # the legacy mixer's sums go negative too


@needs_compiled
def test_compiled_drive_is_the_pythons_bit_for_bit():
    fw = _firmware()
    assert fw._drive_constants is not None  # the kernel drives
    rng = np.random.default_rng(21)
    off = capped = sagged_past_the_peak = 0
    for _ in range(20000):
        uncapped, state = _random_command(rng), _random_state(rng, fw)
        compiled, python = _both(fw, uncapped, state)
        assert compiled == python, (uncapped, state)
        off += compiled[0] is MOTORS_OFF
        capped += max(compiled[1]) == fw.cf.curve.pwm_max
        # past the battery's maximum power point the terminal voltage is half the open-circuit one
        sagged_past_the_peak += fw.battery.voltage_v == 0.5 * fw.battery.empty_v and state["battery.drawn_as"] > \
            fw.battery.capacity_as
    assert off > 1000 and capped > 1000 and sagged_past_the_peak > 100, (off, capped, sagged_past_the_peak)


@needs_compiled
def test_the_kernel_leaves_to_the_python_what_it_does_not_do_alike():
    """Commands that are not a tuple of 4 ints within 2^53, and constants Python would refuse (a division by
    zero, the square root of a negative): the kernel answers None, and _drive gives what the Python gives,
    errors included."""
    fw = _firmware()
    state = {name: _get(fw, name) for name in STATE}
    args = (state["supply_v"], state["battery.voltage_v"], state["battery.drawn_as"], fw._drive_constants)
    for uncapped in ([30000] * 4, (30000, 30000, 30000), (30000.0, 30000, 30000, 30000), (2**60, 0, 0, 0),
                     (True, 0, 0, 0)):
        assert drive_kernel.drive(uncapped, *args) is None
        compiled, python = _both(fw, uncapped, state)
        assert compiled == python
    assert drive_kernel.drive((30000,) * 4, *args) is not None
    for changes in ({"v3": 0.0}, {"pwm_max": 0}, {"v2": 1e3, "v1": 1e3}):
        odd = _firmware(**changes)
        compiled, python = _both(odd, (30000,) * 4, state)
        assert compiled == python
    with pytest.raises(TypeError, match="drive takes 5 arguments"):
        drive_kernel.drive((0, 0, 0, 0), *args[:3])
    with pytest.raises(ValueError, match="constants: expected 19"):
        drive_kernel.drive((0, 0, 0, 0), *args[:3], args[3][:18])


@needs_compiled
def test_compiled_force_torque_mixer_is_the_pythons():
    """ForceTorqueMixer.pwm (compiled) against pwm_python: random commands, negative forces, non-finite ones
    (0, as the firmware's int32 conversion here), and values past 2^53 handed to the Python."""
    mixer = _firmware().force_torque
    assert mixer._compiled is not None
    rng = np.random.default_rng(22)
    special = [float("nan"), float("inf"), -float("inf"), 1e300, -0.0]
    clipped = 0
    for _ in range(20000):
        thrust = float(rng.uniform(-0.2, 0.8))
        torque = tuple(float(v) for v in rng.normal(scale=3e-3, size=3))
        if rng.random() < 0.05:
            thrust = special[rng.integers(len(special))]
        if rng.random() < 0.05:
            torque = (torque[0], special[rng.integers(len(special))], torque[2])
        compiled, python = mixer.pwm(thrust, torque), mixer.pwm_python(thrust, torque)
        assert compiled == python and all(type(p) is int for p in compiled), (thrust, torque)
        clipped += 0 in compiled
    assert clipped > 1000
    assert drive_kernel.force_torque_pwm(1e300, (0.0, 0.0, 0.0), mixer._compiled) is None  # past 2^53: Python's
    with pytest.raises(ValueError, match="torque_flu_nm: expected 3"):
        drive_kernel.force_torque_pwm(0.3, (0.0, 0.0), mixer._compiled)
    with pytest.raises(TypeError):
        drive_kernel.force_torque_pwm("0.3", (0.0, 0.0, 0.0), mixer._compiled)


def _fly(mode: str, steps: int) -> list[bytes]:
    """Every 500 Hz cycle's PWM, forces, battery and truth of the faithful vehicle flown by fixed setpoints
    that tilt and turn it, with the mocap pose streamed as extpose (faithful_flight)."""
    def record(sim) -> bytes:
        fw, truth = sim.firmware, sim.truth
        assert (fw._drive_constants is not None) == (fw.force_torque._compiled is not None) == drive_kernel.COMPILED
        return repr(fw.motor_pwm).encode() + _bits([*fw.motor_forces_n, fw.supply_v, fw.battery.voltage_v,
                                                    fw.battery.drawn_as, *truth.position_enu_m, *truth.attitude_wxyz])
    return fly_faithful("cf21", mode, steps, record, seed=4, extpose_in_moments=True)


@needs_compiled
@pytest.mark.parametrize("mode", ["attitude", "moments"])
def test_a_flight_on_the_compiled_drive_is_the_flight_on_the_python(monkeypatch, mode):
    compiled = _fly(mode, 3000)
    monkeypatch.setattr(drive_kernel, "COMPILED", False)  # firmwares made now drive in Python
    python = _fly(mode, 3000)
    assert compiled == python
    assert len(set(compiled)) == len(compiled)  # airborne, drawing and moving every step
