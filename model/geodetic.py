"""Local ENU offsets to geodetic coordinates, for showing a flight on a map (MAVLink GCS).

Takes in: a map origin TOML (built-in `lab` in model/params/origin/, or a file of its form: latitude_deg,
longitude_deg, altitude_msl_m, source) and world ENU positions (m) relative to that origin.
Gives out: `GeodeticOrigin` and `GeodeticOrigin.to_geodetic(enu) -> (latitude_deg, longitude_deg,
altitude_m)`, on the WGS 84 ellipsoid in the tangent-plane approximation: north / (M + h) and
east / ((N + h) cos lat) with M and N the meridian and prime-vertical radii of curvature at the origin
(NIMA TR8350.2, ch. 4).
Over a lab (tens of metres) it differs from the exact ECEF route by far less than a millimetre
(tests/model/test_geodetic.py); the altitude is the origin's plus the height (Earth's curvature over
10 m lowers the ellipsoid by 8 micrometres, below anything a GCS shows).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from model.config import Params, resolve

WGS84_A_M = 6_378_137.0  # semi-major axis (NIMA TR8350.2, table 3.1)
WGS84_F = 1.0 / 298.257223563  # flattening (same table)
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)  # first eccentricity squared


@dataclass(frozen=True)
class GeodeticOrigin:
    latitude_deg: float
    longitude_deg: float
    altitude_msl_m: float
    source: str = ""

    def radii_m(self) -> tuple[float, float]:
        """(M, N): meridian and prime-vertical radii of curvature at the origin's latitude."""
        s = math.sin(math.radians(self.latitude_deg))
        w = math.sqrt(1.0 - WGS84_E2 * s * s)
        return WGS84_A_M * (1.0 - WGS84_E2) / w**3, WGS84_A_M / w

    def to_geodetic(self, position_enu_m) -> tuple[float, float, float]:
        """(latitude_deg, longitude_deg, altitude_m) of a point east/north/up of the origin."""
        east, north, up = position_enu_m
        m, n = self.radii_m()
        h = self.altitude_msl_m  # the lab's height above the ellipsoid (the geoid's few tens of m are negligible)
        lat = self.latitude_deg + math.degrees(north / (m + h))
        lon = self.longitude_deg + math.degrees(east / ((n + h) * math.cos(math.radians(self.latitude_deg))))
        return lat, lon, self.altitude_msl_m + up


def load_origin(name_or_path: str | Path = "lab") -> GeodeticOrigin:
    p = Params.load(resolve(name_or_path, "model", "params/origin", "map origin"))
    return GeodeticOrigin(p.number("latitude_deg", -90.0, 90.0), p.number("longitude_deg", -180.0, 180.0),
                          p.number("altitude_msl_m", -500.0, 9000.0), p.string("source"))
