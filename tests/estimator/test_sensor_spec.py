"""The filter's sensor assumptions come from the sensors' data sheets, not from the simulator's settings."""

import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from estimator.eskf import ErrorStateKF
from estimator.sensor_spec import DEFAULT_SENSOR_SPEC, SensorSpec, load_sensor_spec, subsampled
from model.errors import ConfigError
from model.vehicle import load_mocap_room, load_vehicle

STANDARD_GRAVITY = 9.80665  # the g of "ug" in data sheets (ISO 80000-3)


def test_builtin_spec_is_the_bmi088_data_sheet_and_vicon() -> None:
    spec = load_sensor_spec(DEFAULT_SENSOR_SPEC)
    # BMI088 data sheet: accel 175 ug/sqrt(Hz), gyro 0.014 deg/s/sqrt(Hz).
    assert spec.accel_noise_density == pytest.approx(175e-6 * STANDARD_GRAVITY, rel=1e-3)
    assert spec.gyro_noise_density == pytest.approx(math.radians(0.014), rel=1e-3)
    # Vicon static jitter below 0.5 mm; the firmware's extQuatStdDev 4.5e-3 rad.
    assert spec.mocap_position_sigma_m == pytest.approx(0.5e-3)
    assert spec.mocap_attitude_sigma_rad == pytest.approx(4.5e-3)
    cited = tomllib.loads(Path(spec.source).read_text())["source"]
    assert "BST-BMI088" in cited and "Merriaux" in cited and "extQuatStdDev" in cited


def test_filter_assumptions_differ_from_the_emulated_room() -> None:
    """The emulated mocap room is simulated with its own figures; the filter is not handed them."""
    spec, room = load_sensor_spec(), load_mocap_room("vicon")
    kf = ErrorStateKF(spec, load_vehicle("cf21").imu.rate_hz)
    assert kf.config.r_diag[3] == pytest.approx(spec.mocap_attitude_sigma_rad**2)
    assert kf.config.r_diag[3] != pytest.approx(room.attitude_noise_rad**2)


def test_matching_simulation_copies_the_simulated_noise() -> None:
    vehicle, room = load_vehicle("crazyflie"), load_mocap_room("vicon")
    spec = SensorSpec.matching_simulation(vehicle, room)
    assert spec.gyro_noise_density == vehicle.imu.gyro_noise_density
    assert spec.mocap_position_sigma_m == room.position_noise_m


def test_bad_spec_file_is_one_line_naming_the_field(tmp_path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text('schema_version = 1\nname = "x"\nsource = "s"\n[imu]\naccel_noise_density_mps2_per_rthz = -1\n'
                   'gyro_noise_density_radps_per_rthz = 1e-4\naccel_bias_random_walk_mps3_per_rthz = 0\n'
                   'gyro_bias_random_walk_radps2_per_rthz = 0\naccel_bias_initial_sigma_mps2 = 0.1\n'
                   'gyro_bias_initial_sigma_radps = 0.1\n[mocap]\nposition_sigma_m = 1e-3\nattitude_sigma_rad = 1e-3\n')
    with pytest.raises(ConfigError) as err:
        load_sensor_spec(bad)
    message = str(err.value)
    assert "\n" not in message and "bad.toml" in message and "accel_noise_density_mps2_per_rthz" in message
    with pytest.raises(ConfigError, match="unknown sensor specification 'nope'"):
        load_sensor_spec("nope")


def test_every_fifth_sample_of_500_hz_noise_is_100_hz_noise_of_sqrt_5_the_density():
    spec = load_sensor_spec()
    stream = subsampled(spec, native_rate_hz=500.0, sample_rate_hz=100.0)
    # white noise of density d sampled at f has per-sample variance d^2 f (what the filter assumes of a stream)
    rng = np.random.default_rng(3)
    native = rng.normal(0.0, spec.accel_noise_density * math.sqrt(500.0), size=500_000)
    every_fifth = native[::5]
    assert every_fifth.var() == pytest.approx(stream.accel_noise_density**2 * 100.0, rel=0.02)
    assert stream.gyro_noise_density == pytest.approx(spec.gyro_noise_density * math.sqrt(5.0))
    assert stream.accel_bias_random_walk == spec.accel_bias_random_walk  # a walk is not sampled
    assert subsampled(spec, 500.0, 500.0) is spec
