"""The course's `quad_params` dict for a cfstack vehicle model.

Takes in: a model.vehicle.Vehicle (or the name of its TOML). Gives out: the 9-key dict the course's
SE3Control(quad_params) reads (mass kg, Ixx/Iyy/Izz kg m^2, arm_length m, rotor_speed_min/max rad/s,
k_thrust N/(rad/s)^2, k_drag N m/(rad/s)^2), plus the vehicle the host selected for the compat
`flightsim.crazyflie_params` module.
"""

from __future__ import annotations

import numpy as np

from model.vehicle import Vehicle, load_vehicle

QUAD_PARAM_KEYS = ("mass", "Ixx", "Iyy", "Izz", "arm_length", "rotor_speed_min", "rotor_speed_max",
                   "k_thrust", "k_drag")
COURSE_VEHICLE = "crazyflie"  # model/params/vehicles/crazyflie.toml: the course's crazyflie_params
_selected: list[Vehicle] = []


def quad_params_of(vehicle: Vehicle) -> dict:
    """The course dict of a vehicle; arm_length is the rotors' mean distance from the centre."""
    inertia = np.asarray(vehicle.inertia_kgm2, float)
    arm = float(np.mean(np.linalg.norm(np.asarray(vehicle.rotor_positions_flu_m, float)[:, :2], axis=1)))
    return {
        "mass": float(vehicle.mass_kg), "Ixx": float(inertia[0, 0]), "Iyy": float(inertia[1, 1]),
        "Izz": float(inertia[2, 2]), "arm_length": arm,
        "rotor_speed_min": float(vehicle.rotor_speed_min_radps),
        "rotor_speed_max": float(vehicle.rotor_speed_max_radps),
        "k_thrust": float(vehicle.k_thrust), "k_drag": float(vehicle.k_drag_torque),
    }


def select_vehicle(vehicle: Vehicle) -> None:
    """The vehicle `flightsim.crazyflie_params.quad_params` describes from now on in this process."""
    _selected[:] = [vehicle]


def current_quad_params() -> dict:
    return quad_params_of(_selected[0] if _selected else load_vehicle(COURSE_VEHICLE))
