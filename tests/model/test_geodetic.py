"""model.geodetic against the exact WGS 84 route (geodetic -> ECEF -> local ENU and back), written here
from NIMA TR8350.2 ch. 4 independently of the module's tangent-plane formulas."""

from __future__ import annotations

import math

import numpy as np
import pytest

from model.errors import ConfigError
from model.geodetic import WGS84_A_M, WGS84_E2, GeodeticOrigin, load_origin


def ecef(lat_deg: float, lon_deg: float, h_m: float) -> np.ndarray:
    lat, lon = math.radians(lat_deg), math.radians(lon_deg)
    n = WGS84_A_M / math.sqrt(1.0 - WGS84_E2 * math.sin(lat) ** 2)
    return np.array([(n + h_m) * math.cos(lat) * math.cos(lon), (n + h_m) * math.cos(lat) * math.sin(lon),
                     (n * (1.0 - WGS84_E2) + h_m) * math.sin(lat)])


def enu_of(origin: GeodeticOrigin, lat_deg: float, lon_deg: float, h_m: float) -> np.ndarray:
    lat, lon = math.radians(origin.latitude_deg), math.radians(origin.longitude_deg)
    d = ecef(lat_deg, lon_deg, h_m) - ecef(origin.latitude_deg, origin.longitude_deg, origin.altitude_msl_m)
    rows = np.array([[-math.sin(lon), math.cos(lon), 0.0],
                     [-math.sin(lat) * math.cos(lon), -math.sin(lat) * math.sin(lon), math.cos(lat)],
                     [math.cos(lat) * math.cos(lon), math.cos(lat) * math.sin(lon), math.sin(lat)]])
    return rows @ d


@pytest.mark.parametrize("origin", [GeodeticOrigin(39.9522, -75.1906, 12.0), GeodeticOrigin(-33.9, 151.2, 50.0),
                                    GeodeticOrigin(64.1, -21.9, 0.0), GeodeticOrigin(0.0, 0.0, 0.0)])
@pytest.mark.parametrize("enu", [(10.0, 0.0, 0.0), (0.0, 10.0, 0.0), (-7.0, 4.5, 2.0), (25.0, -30.0, 3.0)])
def test_a_lab_offset_lands_where_the_exact_ellipsoid_puts_it(origin, enu):
    lat, lon, alt = origin.to_geodetic(enu)
    back = enu_of(origin, lat, lon, alt)
    # horizontal: the tangent plane drops second-order terms ((east^2 + |east * north|) tan(lat) / R, the
    # meridians' convergence): 0.3 mm at 40 m from the origin, within the module's "far less than a millimetre"
    tan_lat = max(1.0, abs(math.tan(math.radians(origin.latitude_deg))))
    second_order = (enu[0] ** 2 + abs(enu[0] * enu[1])) * tan_lat / 6.3e6
    assert np.abs(back[:2] - enu[:2]).max() <= 1.5 * second_order + 1e-6
    assert np.abs(back[:2] - enu[:2]).max() < 1e-3
    # vertical: Earth's curvature drops the plane below the ellipsoid by d^2 / 2R (71 um at 30 m)
    assert back[2] == pytest.approx(enu[2] - math.hypot(*enu[:2]) ** 2 / (2 * 6.371e6), abs=2e-5)


def test_one_degree_of_latitude_is_the_meridian_arc():
    # 1' of latitude at 45 deg is 1852.2 m on WGS 84 (the nautical mile was defined near it)
    origin = GeodeticOrigin(45.0, 0.0, 0.0)
    lat, _, _ = origin.to_geodetic((0.0, 1852.0, 0.0))
    assert (lat - 45.0) * 60.0 == pytest.approx(1852.0 / 1852.2, rel=2e-4)


def test_the_lab_origin_loads_and_a_bad_file_is_one_line(tmp_path):
    lab = load_origin("lab")
    assert 39.0 < lab.latitude_deg < 41.0 and -76.0 < lab.longitude_deg < -75.0 and lab.source
    bad = tmp_path / "bad.toml"
    bad.write_text('schema_version = 1\nsource = "x"\nlatitude_deg = 123.0\nlongitude_deg = 0.0\n'
                   'altitude_msl_m = 0.0\n')
    with pytest.raises(ConfigError, match=r"bad.toml: latitude_deg: 123.0 is above the maximum 90"):
        load_origin(str(bad))
