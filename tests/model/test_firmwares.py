"""The onboard sides every command offers (model/firmwares.py) and the vehicle file each is written for."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from groundstation.cli import fly_parser
from groundstation.sweep.cli import build_parser as sweep_parser
from model.errors import UserError
from model.firmwares import DEFAULT_FIRMWARE, FIRMWARE_VEHICLES, default_vehicle_model
from model.vehicle import load_vehicle
from simulator.cli import build_parser as emulator_parser
from simulator.firmware import load_firmware_params
from simulator.vehicle_sim import make_firmware


def _firmware_option(parser) -> tuple[tuple[str, ...], str]:
    (action,) = [a for a in parser._actions if "--firmware" in a.option_strings]
    return tuple(action.choices), action.default


def test_fly_sweep_and_the_emulator_offer_the_same_firmwares_with_the_same_default():
    for parser in (fly_parser(), sweep_parser(), emulator_parser()):
        assert _firmware_option(parser) == (tuple(FIRMWARE_VEHICLES), DEFAULT_FIRMWARE)
    assert DEFAULT_FIRMWARE in FIRMWARE_VEHICLES


@pytest.mark.parametrize("firmware", sorted(FIRMWARE_VEHICLES))
def test_the_emulator_makes_each_firmware_offered_on_the_vehicle_file_it_flies(firmware):
    vehicle = load_vehicle(default_vehicle_model(firmware))
    assert vehicle.mass_kg > 0 and len(vehicle.rotor_positions_flu_m) == 4
    made = make_firmware(firmware, vehicle, load_firmware_params())
    assert type(made).__name__ == {"ideal": "Firmware", "crazyflie": "CrazyflieFirmware"}[firmware]


def test_an_unknown_firmware_is_one_line_naming_the_ones_offered():
    with pytest.raises(UserError) as raised:
        make_firmware("px4", load_vehicle(default_vehicle_model()), load_firmware_params())
    assert str(raised.value) == "firmware: 'px4' is not one of ideal, crazyflie"


def test_the_faithful_firmware_flies_an_x_layout_vehicle():
    # the Crazyflie firmware's quadrotor mixer (power_distribution_quadrotor.c) takes the arms at 45 degrees
    # between the body axes: each rotor is as far along x as along y
    rotors = load_vehicle(default_vehicle_model("crazyflie")).rotor_positions_flu_m
    np.testing.assert_allclose(np.abs(rotors[:, 0]), np.abs(rotors[:, 1]), rtol=1e-9)
    assert np.all(np.abs(rotors[:, 0]) > 0)


def test_the_firmware_names_and_the_emulator_options_load_without_numpy():
    # the emulator parses its options before numpy loads, so a mistyped option fails at once
    probe = "import sys, model.firmwares, simulator.cli; print('numpy' in sys.modules)"
    run = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60)
    assert run.returncode == 0 and run.stdout.strip() == "False", run.stdout + run.stderr
