"""What the filter assumes about its sensors: IMU noise densities and bias behaviour, and mocap noise.

Takes in: a sensor-specification TOML (built-in: estimator/params/sensors/bmi088_vicon.toml, from the
BMI088 data sheet and the Vicon/firmware figures it cites), or, for filter unit tests only, the
simulator's own vehicle and mocap-room descriptions (`SensorSpec.matching_simulation`).
Gives out: `SensorSpec` (SI units: m/s^2/sqrt(Hz), rad/s/sqrt(Hz), m/s^3/sqrt(Hz), rad/s^2/sqrt(Hz), m, rad).

Why a file of its own: the filter on the ground station cannot know how the emulator draws its noise (and
on hardware there is no emulator), so its assumptions come from the sensors' specifications, not from
the simulator's settings.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

from model.config import Params, resolve
from model.vehicle import MocapRoom, Vehicle

DEFAULT_SENSOR_SPEC = "bmi088_vicon"


@dataclass(frozen=True)
class SensorSpec:
    name: str
    accel_noise_density: float  # m/s^2/sqrt(Hz), white noise on the specific force
    gyro_noise_density: float  # rad/s/sqrt(Hz), white noise on the body rate
    accel_bias_random_walk: float  # m/s^3/sqrt(Hz)
    gyro_bias_random_walk: float  # rad/s^2/sqrt(Hz)
    accel_bias_initial_sigma: float  # m/s^2
    gyro_bias_initial_sigma: float  # rad/s
    mocap_position_sigma_m: float  # 1-sigma per axis
    mocap_attitude_sigma_rad: float  # 1-sigma per axis
    source: str = "<memory>"

    @classmethod
    def matching_simulation(cls, vehicle: Vehicle, room: MocapRoom) -> SensorSpec:
        """The simulator's exact noise: for testing the filter's mathematics, never for flying."""
        imu = vehicle.imu
        return cls(name=f"{vehicle.name}+{room.name} (simulation)",
                   accel_noise_density=imu.accel_noise_density, gyro_noise_density=imu.gyro_noise_density,
                   accel_bias_random_walk=imu.accel_bias_random_walk,
                   gyro_bias_random_walk=imu.gyro_bias_random_walk,
                   accel_bias_initial_sigma=imu.accel_bias_initial_sigma,
                   gyro_bias_initial_sigma=imu.gyro_bias_initial_sigma,
                   mocap_position_sigma_m=room.position_noise_m, mocap_attitude_sigma_rad=room.attitude_noise_rad)


def subsampled(spec: SensorSpec, native_rate_hz: float, sample_rate_hz: float) -> SensorSpec:
    """The spec of an IMU stream made of every (native / sample)-th sample of an IMU sampled at native_rate_hz
    (a Crazyflie's log block reading its sensors every 10 ms): each sample keeps the native sample's white
    noise, variance density^2 native_rate, where a stream sampled at sample_rate would have density^2
    sample_rate, so its density is density sqrt(native / sample). The bias walks are not sampled: unchanged."""
    if sample_rate_hz >= native_rate_hz:
        return spec
    factor = math.sqrt(native_rate_hz / sample_rate_hz)
    return dataclasses.replace(spec, name=f"{spec.name}, sampled at {sample_rate_hz:g} of {native_rate_hz:g} Hz",
                               accel_noise_density=spec.accel_noise_density * factor,
                               gyro_noise_density=spec.gyro_noise_density * factor)


def load_sensor_spec(name_or_path: str | Path = DEFAULT_SENSOR_SPEC) -> SensorSpec:
    """Read a sensor specification (built-in name or .toml path); one-line ConfigError on a bad field."""
    p = Params.load(resolve(name_or_path, "estimator", "params/sensors", "sensor specification"))
    imu, mocap = p.table("imu"), p.table("mocap")
    return SensorSpec(
        name=p.string("name"),
        accel_noise_density=imu.number("accel_noise_density_mps2_per_rthz", minimum=1e-9),
        gyro_noise_density=imu.number("gyro_noise_density_radps_per_rthz", minimum=1e-9),
        accel_bias_random_walk=imu.number("accel_bias_random_walk_mps3_per_rthz", minimum=0.0),
        gyro_bias_random_walk=imu.number("gyro_bias_random_walk_radps2_per_rthz", minimum=0.0),
        accel_bias_initial_sigma=imu.number("accel_bias_initial_sigma_mps2", minimum=1e-9),
        gyro_bias_initial_sigma=imu.number("gyro_bias_initial_sigma_radps", minimum=1e-9),
        mocap_position_sigma_m=mocap.number("position_sigma_m", minimum=1e-9),
        mocap_attitude_sigma_rad=mocap.number("attitude_sigma_rad", minimum=1e-9),
        source=p.source,
    )
