"""Vehicle parameters: the one home of what both the emulator and the ground station know of a vehicle.

Takes in: a vehicle TOML file (built-in names: crazyflie, cf2x; see model/params/vehicles/).
Gives out: `Vehicle` (mass, inertia, rotor geometry and coefficients, limits, IMU noise densities) and
`MocapRoom` (mocap rate, latency, noise, dropouts, outliers). SI units throughout, body frame FLU.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from model.config import Params, resolve

GRAVITY_MPS2 = 9.81  # the course's g (issue 3: "gravity 9.81")


@dataclass(frozen=True)
class ImuNoise:
    rate_hz: float
    accel_noise_density: float  # m/s^2/sqrt(Hz)
    gyro_noise_density: float  # rad/s/sqrt(Hz)
    accel_bias_random_walk: float  # m/s^3/sqrt(Hz)
    gyro_bias_random_walk: float  # rad/s^2/sqrt(Hz)
    accel_bias_initial_sigma: float  # m/s^2
    gyro_bias_initial_sigma: float  # rad/s


@dataclass(frozen=True)
class Vehicle:
    name: str
    mass_kg: float
    inertia_kgm2: np.ndarray  # (3, 3) diagonal, body FLU
    rotor_positions_flu_m: np.ndarray  # (4, 3)
    rotor_spin: np.ndarray  # (4,) +1 counter-clockwise seen from above
    k_thrust: float  # N/(rad/s)^2
    k_drag_torque: float  # N m/(rad/s)^2
    rotor_speed_min_radps: float
    rotor_speed_max_radps: float
    motor_time_constant_s: float
    rotor_drag_coefficient: float  # N s/m per rotor at hover speed
    imu: ImuNoise
    battery_full_v: float
    battery_empty_v: float
    battery_capacity_mah: float
    source: str
    prop_radius_m: float = 0.0
    collision_radius_override_m: float | None = None  # [rotors] collision_radius_m, when given

    @property
    def collision_radius_m(self) -> float:
        """Radius (m) around the centre that must stay clear of blocks and walls: the given one, else the
        largest rotor distance from the centre plus a propeller radius (0.0685 m for the course Crazyflie)."""
        if self.collision_radius_override_m is not None:
            return self.collision_radius_override_m
        return float(np.max(np.linalg.norm(self.rotor_positions_flu_m, axis=1))) + self.prop_radius_m

    @property
    def weight_n(self) -> float:
        return self.mass_kg * GRAVITY_MPS2

    @property
    def max_thrust_n(self) -> float:
        return 4.0 * self.k_thrust * self.rotor_speed_max_radps**2

    @property
    def thrust_to_weight(self) -> float:
        return self.max_thrust_n / self.weight_n

    @property
    def hover_rotor_speed_radps(self) -> float:
        return float(np.sqrt(self.weight_n / (4.0 * self.k_thrust)))

    @property
    def allocation(self) -> np.ndarray:
        """(4, 4) matrix A with [thrust N, Mx, My, Mz N m] = A @ rotor_speed^2 (body FLU)."""
        p = self.rotor_positions_flu_m
        k = self.k_thrust
        return np.vstack([
            np.full(4, k),
            k * p[:, 1],  # thrust along +z at (x, y): Mx = y * F
            -k * p[:, 0],  # My = -x * F
            -self.rotor_spin * self.k_drag_torque,  # reaction torque opposes the spin
        ])

    @property
    def max_moment_nm(self) -> np.ndarray:
        """Largest body moment (N m) each axis can get about hover, with the others at zero."""
        w2max = self.rotor_speed_max_radps**2
        a = self.allocation
        return np.array([np.abs(a[i]).sum() * w2max / 2.0 for i in (1, 2, 3)])


def load_vehicle(name_or_path: str | Path = "crazyflie") -> Vehicle:
    path = resolve(name_or_path, "model", "params/vehicles", "vehicle")
    p = Params.load(path)
    inertia = p.table("inertia")
    rotors = p.table("rotors")
    imu = p.table("imu")
    battery = p.table("battery")
    positions = np.array(rotors.matrix("positions_flu_m", 4, 3))
    spin = np.array(rotors.vector("spin", 4))
    if not np.all(np.isin(spin, (-1.0, 1.0))) or spin.sum() != 0:
        raise rotors.error("spin", "expected four entries of +1/-1, two of each")
    speed_min = rotors.number("speed_min_radps", minimum=0.0)
    speed_max = rotors.number("speed_max_radps", minimum=1.0)
    if speed_max <= speed_min:
        raise rotors.error("speed_max_radps", "must exceed speed_min_radps")
    vehicle = Vehicle(
        name=p.string("name"),
        mass_kg=inertia.number("mass_kg", minimum=1e-4),
        inertia_kgm2=np.diag([inertia.number(k, minimum=1e-9) for k in ("ixx_kgm2", "iyy_kgm2", "izz_kgm2")]),
        rotor_positions_flu_m=positions,
        rotor_spin=spin,
        k_thrust=rotors.number("thrust_coefficient_n_per_radps2", minimum=1e-12),
        k_drag_torque=rotors.number("drag_torque_coefficient_nm_per_radps2", minimum=1e-15),
        rotor_speed_min_radps=speed_min,
        rotor_speed_max_radps=speed_max,
        motor_time_constant_s=rotors.number("time_constant_s", minimum=0.0),
        rotor_drag_coefficient=rotors.number("rotor_drag_coefficient_ns_per_m", minimum=0.0),
        imu=ImuNoise(
            rate_hz=imu.number("rate_hz", minimum=1.0),
            accel_noise_density=imu.number("accel_noise_density_mps2_per_rthz", minimum=0.0),
            gyro_noise_density=imu.number("gyro_noise_density_radps_per_rthz", minimum=0.0),
            accel_bias_random_walk=imu.number("accel_bias_random_walk_mps3_per_rthz", minimum=0.0),
            gyro_bias_random_walk=imu.number("gyro_bias_random_walk_radps2_per_rthz", minimum=0.0),
            accel_bias_initial_sigma=imu.number("accel_bias_initial_sigma_mps2", minimum=0.0),
            gyro_bias_initial_sigma=imu.number("gyro_bias_initial_sigma_radps", minimum=0.0),
        ),
        battery_full_v=battery.number("voltage_full_v", minimum=0.1),
        battery_empty_v=battery.number("voltage_empty_v", minimum=0.0),
        battery_capacity_mah=battery.number("capacity_mah", minimum=1.0),
        source=str(path),
        prop_radius_m=rotors.number("prop_radius_m", minimum=0.0),
        collision_radius_override_m=(rotors.number("collision_radius_m", minimum=0.0)
                                     if rotors.has("collision_radius_m") else None),
    )
    a = vehicle.allocation
    if np.linalg.matrix_rank(a / np.abs(a).max(axis=1, keepdims=True)) < 4:
        raise rotors.error("positions_flu_m", "rotor geometry cannot produce independent thrust and moments")
    return vehicle


@dataclass(frozen=True)
class MocapRoom:
    name: str
    rate_hz: float
    latency_s: float
    position_noise_m: float
    attitude_noise_rad: float
    dropout_probability: float
    outlier_probability: float
    outlier_magnitude_m: float


def load_mocap_room(name_or_path: str | Path = "vicon") -> MocapRoom:
    p = Params.load(resolve(name_or_path, "model", "params/mocap", "mocap room"))
    return MocapRoom(
        name=p.string("name"),
        rate_hz=p.number("rate_hz", minimum=1.0),
        latency_s=p.number("latency_s", minimum=0.0),
        position_noise_m=p.number("position_noise_m", minimum=0.0),
        attitude_noise_rad=p.number("attitude_noise_rad", minimum=0.0),
        dropout_probability=p.number("dropout_probability", minimum=0.0, maximum=1.0),
        outlier_probability=p.number("outlier_probability", minimum=0.0, maximum=1.0),
        outlier_magnitude_m=p.number("outlier_magnitude_m", minimum=0.0),
    )
