"""Vehicle-to-vehicle variation (simulator/variation.py, the `lab` profile): draws stay in their documented
ranges, come from the seed alone, change only the physics' vehicle and sensors (never the nominal file the
firmware and ground station use), and leave every other random stream as it was."""

import math

import numpy as np
import pytest

from model.frames import rotate
from model.vehicle import load_vehicle
from simulator.variation import VehicleDraw, draw, load_variation
from simulator.vehicle_sim import SimVehicle

LAB = load_variation("lab")
CF21 = load_vehicle("cf21")


def test_draws_stay_in_the_documented_ranges():
    draws = [draw(LAB, np.random.default_rng(seed)) for seed in range(400)]
    masses = np.array([d.mass_offset_kg for d in draws])
    com = np.array([d.com_offset_flu_m[:2] for d in draws])
    factors = np.array([d.motor_thrust_factors for d in draws])
    tilt = np.array([d.imu_misalignment_rad for d in draws])
    assert LAB.mass_offset_kg[0] <= masses.min() and masses.max() <= LAB.mass_offset_kg[1]
    assert np.all((LAB.com_offset_m[0] <= com) & (com <= LAB.com_offset_m[1]))
    # normal draws: sample standard deviations within 15 % of the profile's (400 x 4 and 400 x 3 samples)
    assert factors.std() == pytest.approx(LAB.motor_thrust_sigma, rel=0.15)
    assert factors.mean() == pytest.approx(1.0, abs=0.01)
    assert tilt.std() == pytest.approx(LAB.imu_misalignment_sigma_rad, rel=0.15)


def test_nominal_draws_nothing_and_the_same_seed_draws_the_same():
    assert draw(None, np.random.default_rng(1)).is_nominal and load_variation("nominal") is None
    assert draw(LAB, np.random.default_rng(5)) == draw(LAB, np.random.default_rng(5))
    assert draw(LAB, np.random.default_rng(5)) != draw(LAB, np.random.default_rng(6))


def test_a_centre_of_mass_offset_makes_equal_thrusts_tip_the_vehicle():
    d = VehicleDraw(com_offset_flu_m=(0.001, 0.0, 0.0))
    body = d.apply(CF21)
    # equal rotor speeds: the moment about y is -sum(x_i) k_T w^2 with x measured from the new centre
    w2 = CF21.hover_rotor_speed_radps ** 2
    my = (body.allocation @ np.full(4, w2))[2]
    assert my == pytest.approx(4 * 0.001 * CF21.k_thrust * w2)
    assert body.mass_kg == CF21.mass_kg


def test_the_physics_flies_the_draw_and_the_firmware_the_nominal_file():
    sim = SimVehicle(CF21, np.random.default_rng(3), initial_position_enu_m=(0.0, 0.0, 1.0), airborne=True,
                     firmware="crazyflie", variation=LAB)
    assert not sim.draw.is_nominal
    assert sim.dynamics.vehicle.mass_kg == pytest.approx(CF21.mass_kg + sim.draw.mass_offset_kg)
    assert sim.firmware.vehicle is CF21
    # the IMU and mocap streams are the nominal vehicle's: the draw takes a stream of its own
    plain = SimVehicle(CF21, np.random.default_rng(3), initial_position_enu_m=(0.0, 0.0, 1.0), airborne=True,
                       firmware="crazyflie")
    a = sim.imu.sample(0.0, (0.0, 0.0, 9.81), (0.0, 0.0, 0.0))
    b = plain.imu.sample(0.0, (0.0, 0.0, 9.81), (0.0, 0.0, 0.0))
    assert a == b


def test_a_misaligned_imu_sees_gravity_tilted_by_its_misalignment():
    d = VehicleDraw(imu_misalignment_rad=(0.01, 0.0, 0.0))
    rows = d.misalignment_rows()
    g = (0.0, 0.0, 9.81)
    seen = rotate(rows, *g)
    # a sensor rolled by +0.01 rad about x reads R^T (0, 0, g): the specific force appears rolled by -0.01 rad,
    # i.e. (0, g sin 0.01, g cos 0.01), as a level vehicle would read with its body rolled by +0.01 rad
    assert math.atan2(seen[1], seen[2]) == pytest.approx(0.01, abs=1e-9)
    assert math.hypot(*seen) == pytest.approx(9.81)
