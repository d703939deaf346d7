"""Forwarding the flight to a MAVLink ground-control station (`--gcs udpout:127.0.0.1:14550`).

Takes in: TickFrames from the flight loop (an observer: it reads them and changes nothing), the map
origin (model/params/origin) and groundstation/params/gcs.toml; flight commands from the GCS.
Gives out: GcsSnapshots of the ground station's own view of the vehicle (its estimate, never the
simulator's truth: on hardware there is none) to link.mavlink.gcs.GcsLink, the read-only parameters a GCS
lists, and `gcs_commands.csv` in the log folder: every flight command the GCS sent, whether it was signed,
and what became of it (written and flushed as each arrives).

Flight commands are refused unless the frame is signed with the link's key (--signing-key-file) or the
user passed --gcs-commands. When allowed: land or return-to-launch lands at a clear spot and disarms (as
Ctrl-C does); arm is accepted when the vehicle is already armed (the mission arms it); disarm only on the
ground; other commands (takeoff, mode, termination) are unsupported: the mission owns the flight.
"""

from __future__ import annotations

import csv
import logging
from dataclasses import dataclass
from pathlib import Path

from groundstation.tickframe import TickFrame
from link.mavlink.gcs import GcsCommand, GcsLink, GcsSnapshot, Verdict
from model.config import Params, resolve
from model.geodetic import GeodeticOrigin, load_origin

log = logging.getLogger("cfstack.groundstation")

MODE_CODES = {"moments": 0, "attitude": 1, "position": 2}  # the CF_MODE parameter shown to the GCS


@dataclass(frozen=True)
class GcsSettings:
    origin: GeodeticOrigin
    stream_period_s: float
    heartbeat_period_s: float
    max_frames_per_s: int


def load_gcs_settings(name_or_path: str = "gcs", origin: str | None = None) -> GcsSettings:
    p = Params.load(resolve(name_or_path, "groundstation", "params", "GCS settings"))
    return GcsSettings(load_origin(origin or p.string("origin")), p.number("stream_period_s", 1e-3, 10.0),
                       p.number("heartbeat_period_s", 0.1, 5.0), p.integer("max_frames_per_s", 1))


def gcs_connection(text: str) -> str:
    """`udp:HOST:PORT` (MAVProxy's spelling of an outgoing UDP link) is our `udpout:HOST:PORT`."""
    scheme, _, rest = text.partition(":")
    return f"udpout:{rest}" if scheme == "udp" else text


class GcsForwarder:
    """An observer of the flight loop that shows the flight to a GCS."""

    def __init__(self, connection: str, settings: GcsSettings, log_dir: Path, params: dict[str, float], *,
                 signing=None, allow_commands: bool = False, mission=None):
        self.period_s = settings.stream_period_s
        self.origin = settings.origin
        self.mission = mission
        self._armed = False
        self._log_file = open(Path(log_dir) / "gcs_commands.csv", "w", newline="", buffering=1)
        self._log = csv.writer(self._log_file)
        self._log.writerow(["wall_time_s", "sim_time_s", "command", "params", "signed", "verdict"])
        self.link = GcsLink(gcs_connection(connection), params, heartbeat_period_s=settings.heartbeat_period_s,
                            max_frames_per_s=settings.max_frames_per_s, signing=signing,
                            allow_commands=allow_commands, on_command=self._decide,
                            on_command_logged=self._record)

    def observe(self, frame: TickFrame) -> None:
        if frame.est_position_enu_m is None:
            return  # nothing to show before the estimator's first pose
        self._armed = bool(frame.armed)
        lat, lon, alt = self.origin.to_geodetic(frame.est_position_enu_m)
        self.link.publish(GcsSnapshot(
            time_s=frame.t_s, position_enu_m=frame.est_position_enu_m, velocity_enu_mps=frame.est_velocity_enu_mps,
            attitude_wxyz=frame.est_attitude_wxyz, rate_flu_radps=frame.est_rate_flu_radps or (0.0, 0.0, 0.0),
            latitude_deg=lat, longitude_deg=lon, altitude_msl_m=alt, height_above_origin_m=frame.est_position_enu_m[2],
            battery_v=frame.battery_v, battery_remaining_pct=frame.battery_remaining_pct, armed=self._armed,
            healthy=bool(frame.est_healthy)))

    def _decide(self, command: GcsCommand) -> Verdict:
        """An allowed command (runs on the GCS thread: it only sets the mission's abort flag)."""
        if command.name in ("land", "return_to_launch"):
            if self.mission is None:
                return Verdict.UNSUPPORTED
            self.mission.request_abort()
            return Verdict.ACCEPTED
        if command.name == "arm_disarm":
            arm = command.params[0] >= 0.5
            if arm:
                return Verdict.ACCEPTED if self._armed else Verdict.TEMPORARILY_REJECTED
            return Verdict.ACCEPTED if not self._armed else Verdict.DENIED
        return Verdict.UNSUPPORTED

    def _record(self, command: GcsCommand, verdict: Verdict) -> None:
        sim_time = "" if command.sim_time_s is None else f"{command.sim_time_s:.6f}"
        self._log.writerow([f"{command.wall_time_s:.6f}", sim_time,
                            command.name, " ".join(f"{p:g}" for p in command.params), int(command.signed),
                            verdict.value])
        log.warning("GCS command %s (%s): %s", command.name, "signed" if command.signed else "unsigned", verdict.value)

    def close(self) -> None:
        self.link.close()
        self._log_file.close()


def session_parameters(mode: str, rate_hz: float, vehicle_id: int, gains) -> dict[str, float]:
    """The read-only parameters a GCS lists: the session's mode and rate, and the controller's gains."""
    params = {"CF_MODE": MODE_CODES[mode], "CF_RATE_HZ": rate_hz, "CF_VEHICLE_ID": vehicle_id}
    for axis, index in (("X", 0), ("Y", 1), ("Z", 2)):
        params[f"CTL_KP_{axis}"] = gains.kp[index]
        params[f"CTL_KD_{axis}"] = gains.kd[index]
    for axis, index in (("ROLL", 0), ("PITCH", 1), ("YAW", 2)):
        params[f"CTL_KR_{axis}"] = gains.k_r[index]
        params[f"CTL_KW_{axis}"] = gains.k_w[index]
    return params
