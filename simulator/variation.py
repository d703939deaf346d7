"""Vehicle-to-vehicle variation: what makes one emulated Crazyflie differ from the nominal one.

Takes in: a variation profile (simulator/params/variation/NAME.toml, e.g. `lab`), a nominal Vehicle and a
random Generator (a stream of the emulator's seed of its own, so the other streams do not change).
Gives out: a VehicleDraw: the added mass (kg), the centre-of-mass offset (m, body x-y), four per-motor thrust
factors and an IMU misalignment rotation (rad, body axes), with `apply(vehicle)` giving the vehicle the
physics flies (heavier, rotors seen from the shifted centre of mass) and `describe()` one line for the log.
The ground station is never told: it flies the nominal vehicle file, as a lab flies its CAD numbers.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from model.config import Params, resolve
from model.frames import Mat9, quat_conjugate, quat_exp, quat_to_rows
from model.vehicle import Vehicle

NOMINAL = "nominal"


@dataclass(frozen=True)
class VariationProfile:
    name: str
    mass_offset_kg: tuple[float, float]
    com_offset_m: tuple[float, float]
    motor_thrust_sigma: float
    imu_misalignment_sigma_rad: float
    source: str


@dataclass(frozen=True)
class VehicleDraw:
    mass_offset_kg: float = 0.0
    com_offset_flu_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    motor_thrust_factors: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0)
    imu_misalignment_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @property
    def is_nominal(self) -> bool:
        return self == VehicleDraw()

    def apply(self, vehicle: Vehicle) -> Vehicle:
        """The vehicle the physics flies: its mass plus the offset, its rotors seen from the shifted centre
        of mass (so equal thrusts make a moment, as on a vehicle whose battery sits off-centre)."""
        if self.is_nominal:
            return vehicle
        positions = np.asarray(vehicle.rotor_positions_flu_m, float) - np.asarray(self.com_offset_flu_m)
        return dataclasses.replace(vehicle, mass_kg=vehicle.mass_kg + self.mass_offset_kg,
                                   rotor_positions_flu_m=positions)

    def misalignment_rows(self) -> Mat9:
        """R^T (row-major) for the IMU's rotation R = Exp(r) from the body: the sensor reads R^T v_body."""
        return quat_to_rows(quat_conjugate(quat_exp(*self.imu_misalignment_rad)))

    def describe(self) -> str:
        f = ", ".join(f"{v:.3f}" for v in self.motor_thrust_factors)
        c = self.com_offset_flu_m
        m = [math.degrees(v) for v in self.imu_misalignment_rad]
        return (f"mass {self.mass_offset_kg * 1e3:+.2f} g, centre of mass ({c[0] * 1e3:+.2f}, {c[1] * 1e3:+.2f}) mm, "
                f"motor thrust x[{f}], IMU misaligned ({m[0]:+.2f}, {m[1]:+.2f}, {m[2]:+.2f}) deg")


def load_variation(name_or_path: str | Path) -> VariationProfile | None:
    """The profile, or None for `nominal` (no variation)."""
    if str(name_or_path) == NOMINAL:
        return None
    p = Params.load(resolve(name_or_path, "simulator", "params/variation", "vehicle variation profile"))
    mass = p.vector("mass_offset_kg", 2)
    com = p.vector("com_offset_m", 2)
    for key, (low, high) in (("mass_offset_kg", mass), ("com_offset_m", com)):
        if not low <= high:
            raise p.error(key, "expected [low, high] with low <= high")
    return VariationProfile(p.string("name"), (mass[0], mass[1]), (com[0], com[1]),
                            p.number("motor_thrust_sigma", minimum=0.0, maximum=0.3),
                            p.number("imu_misalignment_sigma_rad", minimum=0.0, maximum=0.2), p.source)


def draw(profile: VariationProfile | None, rng: np.random.Generator) -> VehicleDraw:
    """One vehicle's draw (always the same number of draws from rng, whatever the profile's values)."""
    u = rng.random(3)
    n = rng.standard_normal(7)
    if profile is None:
        return VehicleDraw()
    (m0, m1), (c0, c1) = profile.mass_offset_kg, profile.com_offset_m
    factors = tuple(float(max(0.5, 1.0 + profile.motor_thrust_sigma * v)) for v in n[:4])
    return VehicleDraw(
        mass_offset_kg=float(m0 + (m1 - m0) * u[0]),
        com_offset_flu_m=(float(c0 + (c1 - c0) * u[1]), float(c0 + (c1 - c0) * u[2]), 0.0),
        motor_thrust_factors=factors,
        imu_misalignment_rad=tuple(float(v * profile.imu_misalignment_sigma_rad) for v in n[4:7]),
    )
