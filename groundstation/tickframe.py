"""One control tick as the displays see it: the live view, the GCS forwarding, and log replay.

Takes in: the values the flight loop writes to states.csv for a tick (or, in replay, one row of a read
log), plus what a display wants beside them (the vehicle's armed flag and the estimate's body rates).
Gives out: `Displays` (which displays watch a flight, from the command line); `TickFrame`, plain tuples
in world ENU / body FLU / SI units, `None` where unknown; and
`frames_from_log(log)`, the frames of a read flight log, so that a replay feeds a display exactly what
the live flight fed it (the values a live frame has beyond the log, armed, battery charge and rates, are left
unknown; the motor reports come from motors.csv when the flight kept one).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from model.frames import Quat, Vec3


@dataclass
class Displays:
    """What watches the flight besides the log: the rerun view and a MAVLink GCS (none by default)."""

    view: bool = False  # spawn the rerun viewer
    view_save: str | None = None  # or record the view to this .rrd file
    gcs: str | None = None  # GCS connection string (udp:HOST:PORT = udpout)
    gcs_settings: object = None  # groundstation.gcs_forward.GcsSettings, loaded with the options
    gcs_commands: bool = False  # accept unsigned flight commands from the GCS
    gcs_signing: object = None  # link.mavlink.signing.Signing: commands signed with it are accepted


@dataclass(frozen=True)
class TickFrame:
    t_s: float  # simulated (or vehicle) time of the tick
    phase: str
    truth_position_enu_m: Vec3 | None  # simulation only: shown, never used for control
    truth_attitude_wxyz: Quat | None
    est_position_enu_m: Vec3 | None
    est_velocity_enu_mps: Vec3 | None
    est_attitude_wxyz: Quat | None
    est_sigma_position_m: Vec3 | None  # 1 sigma per world axis (the covariance diagonal)
    ref_position_enu_m: Vec3 | None
    cmd_thrust_n: float | None
    cmd_moment_flu_nm: Vec3 | None
    cmd_attitude_wxyz: Quat | None
    battery_v: float | None
    mocap_age_s: float | None
    rtt_ms: float | None
    uplink_sent: int
    downlink_received: int
    downlink_lost: int
    est_healthy: bool | None = None
    armed: bool | None = None  # live only
    battery_remaining_pct: int | None = None  # live only
    est_rate_flu_radps: Vec3 | None = None  # live only
    motor_duty: tuple[float, float, float, float] | None = None  # live only: PWM duty 0..1, m1..m4 (on request)


def frames_from_log(log) -> Iterator[TickFrame]:
    """The TickFrames of a groundstation.logread.FlightLog, one per row."""
    c = log.columns
    n = len(log)
    columns = {name: c[name].tolist() for name in c}
    motors = _motor_duty_per_row(log)
    for i in range(n):
        yield TickFrame(
            t_s=float(log.t_s[i]), phase=str(log.phase[i]),
            truth_position_enu_m=_vec(columns, i, "truth_x_m", "truth_y_m", "truth_z_m"),
            truth_attitude_wxyz=_vec(columns, i, "truth_qw", "truth_qx", "truth_qy", "truth_qz"),
            est_position_enu_m=_vec(columns, i, "est_x_m", "est_y_m", "est_z_m"),
            est_velocity_enu_mps=_vec(columns, i, "est_vx_mps", "est_vy_mps", "est_vz_mps"),
            est_attitude_wxyz=_vec(columns, i, "est_qw", "est_qx", "est_qy", "est_qz"),
            est_sigma_position_m=_vec(columns, i, "est_sigma_x_m", "est_sigma_y_m", "est_sigma_z_m"),
            ref_position_enu_m=_vec(columns, i, "ref_x_m", "ref_y_m", "ref_z_m"),
            cmd_thrust_n=_num(columns, i, "cmd_thrust_n"),
            cmd_moment_flu_nm=_vec(columns, i, "cmd_mx_nm", "cmd_my_nm", "cmd_mz_nm"),
            cmd_attitude_wxyz=_vec(columns, i, "cmd_qw", "cmd_qx", "cmd_qy", "cmd_qz"),
            battery_v=_num(columns, i, "battery_v"),
            mocap_age_s=_num(columns, i, "mocap_age_s"),
            rtt_ms=_num(columns, i, "rtt_ms"),
            uplink_sent=_count(columns, i, "uplink_sent"),
            downlink_received=_count(columns, i, "downlink_received"),
            downlink_lost=_count(columns, i, "downlink_lost"),
            est_healthy=None if _num(columns, i, "est_healthy") is None else bool(columns["est_healthy"][i]),
            motor_duty=motors[i],
        )


def _motor_duty_per_row(log) -> list:
    """Per states.csv row, the newest motor report at or before its time (one tuple object per report, as the
    live flight loop holds it); None before the first, or without motors.csv."""
    if log.motors is None or not len(log.motors):
        return [None] * len(log)
    reports = [tuple(float(d) for d in row[2:6]) for row in log.motors]
    index = np.searchsorted(log.motors[:, 0], np.asarray(log.t_s) + 1e-9, side="right") - 1
    return [reports[k] if k >= 0 else None for k in index.tolist()]


def _num(columns: dict, i: int, name: str) -> float | None:
    value = columns[name][i] if name in columns else math.nan
    return None if math.isnan(value) else value


def _vec(columns: dict, i: int, *names: str):
    values = tuple(_num(columns, i, name) for name in names)
    return None if None in values else values


def _count(columns: dict, i: int, name: str) -> int:
    value = _num(columns, i, name)
    return 0 if value is None else int(value)
