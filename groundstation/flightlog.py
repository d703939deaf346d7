"""Flight logs: states.csv (one row per control tick), summary.json, plan.json, and motors.csv (the vehicle's
motor reports, when a live view asked for them).

Takes in: per-tick values (time, phase, truth, estimate, reference, command, link health) as floats.
Gives out: files in the log folder, written as they go and flushed every row, so a killed ground station
leaves readable logs (at most the row being written is lost). Format: README "Flight logs".
"""

from __future__ import annotations

import json
import os
from datetime import datetime
from pathlib import Path

from groundstation.flightlog_kernel import format_row

COLUMNS = (
    "t_s,phase,"
    "truth_x_m,truth_y_m,truth_z_m,truth_vx_mps,truth_vy_mps,truth_vz_mps,truth_qw,truth_qx,truth_qy,truth_qz,"
    "est_x_m,est_y_m,est_z_m,est_vx_mps,est_vy_mps,est_vz_mps,est_qw,est_qx,est_qy,est_qz,"
    "est_sigma_x_m,est_sigma_y_m,est_sigma_z_m,est_sigma_vx_mps,est_sigma_vy_mps,est_sigma_vz_mps,"
    "est_sigma_roll_rad,est_sigma_pitch_rad,est_sigma_yaw_rad,"
    "ref_x_m,ref_y_m,ref_z_m,ref_vx_mps,ref_vy_mps,ref_vz_mps,"
    "cmd_thrust_n,cmd_mx_nm,cmd_my_nm,cmd_mz_nm,cmd_qw,cmd_qx,cmd_qy,cmd_qz,cmd_saturated,"
    "mocap_age_s,est_healthy,uplink_sent,downlink_received,downlink_lost,rtt_ms,tick_time_ms,est_time_s,"
    "truth_time_s,battery_v"
).split(",")

MOTORS_FILE = "motors.csv"
MOTOR_COLUMNS = ("t_s", "vehicle_time_s", "m1_duty", "m2_duty", "m3_duty", "m4_duty")  # duty: PWM 0..1

_BLOCKS = {  # how many cells each group of values fills
    "truth": 10, "est": 10, "sigma": 9, "ref": 6, "cmd_moment": 4, "cmd_att": 4,
}


def default_log_dir(root: str | Path = "flights") -> Path:
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S-%f")
    return Path(root) / stamp


# Numbers are written with 12 significant digits (a picometre at metres, well below any sensor's
# resolution): one %-format per block costs a quarter of repr() per float, which matters at 500 rows/s; the
# row's text is compiled (flightlog_kernel), with _row_line as its twin.
NUMBER = "%.12g"
_FORMAT = {count: ",".join([NUMBER] * count) for count in _BLOCKS.values()}
_BLANK = {count: "," * (count - 1) for count in _BLOCKS.values()}


def _cells(values, count: int) -> str:
    """`count` comma-separated cells: the values, or empty cells for None."""
    if values is None:
        return _BLANK[count]
    values = tuple(values)
    if len(values) != count:
        raise ValueError(f"expected {count} values, got {len(values)}")
    return _FORMAT[count] % values


def _cell(value) -> str:
    return "" if value is None else NUMBER % value


def _row_line(t_s, phase, truth, estimate, sigma, reference, moment_cmd, attitude_cmd, saturated, mocap_age_s,
              healthy, uplink_sent, downlink_received, downlink_lost, rtt_ms, tick_time_ms, est_time_s, truth_time_s,
              battery_v) -> str:
    """FlightLog.row's line (newline included): the Python twin of flightlog_kernel.format_row."""
    cells = (NUMBER % t_s, phase, _cells(truth, 10), _cells(estimate, 10), _cells(sigma, 9),
             _cells(reference, 6), _cells(moment_cmd, 4), _cells(attitude_cmd, 4),
             "" if saturated is None else str(int(saturated)), _cell(mocap_age_s),
             "" if healthy is None else str(int(healthy)), str(uplink_sent), str(downlink_received),
             str(downlink_lost), _cell(rtt_ms), _cell(tick_time_ms), _cell(est_time_s), _cell(truth_time_s),
             _cell(battery_v))
    return ",".join(cells) + "\n"


class FlightLog:
    """Writes the log folder incrementally. Use as a context manager."""

    def __init__(self, folder: str | Path):
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self._states = open(self.folder / "states.csv", "w", buffering=1, newline="")  # line buffered
        self._states.write(",".join(COLUMNS) + "\n")
        self._motors = None  # motors.csv, opened at the first motor report
        self._flush()

    @property
    def tlog_path(self) -> Path:
        return self.folder / "link.mavlink.tlog"

    def _flush(self) -> None:
        """Hand the rows written so far to the OS (and to the disk with CFSTACK_FSYNC set)."""
        self._states.flush()
        os.fsync(self._states.fileno()) if os.environ.get("CFSTACK_FSYNC") else None

    def row(self, t_s: float, phase: str, truth, estimate, sigma, reference, moment_cmd, attitude_cmd,
            saturated: bool | None, mocap_age_s: float | None, healthy: bool | None, uplink_sent: int,
            downlink_received: int, downlink_lost: int, rtt_ms: float | None, tick_time_ms: float | None,
            est_time_s: float | None = None, truth_time_s: float | None = None,
            battery_v: float | None = None) -> None:
        """One tick. est_time_s: the sample time (vehicle clock) of the newest IMU sample in the estimate
        the command was computed from - what end-to-end latency is measured from; truth_time_s: the sample
        time of the truth in the row (so the estimate is graded against the truth at its own time);
        battery_v: the newest battery voltage the vehicle reported (SYS_STATUS), None before the first."""
        values = (t_s, phase, truth, estimate, sigma, reference, moment_cmd, attitude_cmd, saturated, mocap_age_s,
                  healthy, uplink_sent, downlink_received, downlink_lost, rtt_ms, tick_time_ms, est_time_s,
                  truth_time_s, battery_v)
        line = None if format_row is None else format_row(*values)
        self._states.write(_row_line(*values) if line is None else line)  # None: not built, or left to the Python

    def motors(self, t_s: float, vehicle_time_s: float, duty) -> None:
        """One motor report (MotorOutputs) as it arrives at tick t_s: motors.csv, line-buffered like states.csv."""
        if self._motors is None:
            self._motors = open(self.folder / MOTORS_FILE, "w", buffering=1, newline="")
            self._motors.write(",".join(MOTOR_COLUMNS) + "\n")
        self._motors.write(",".join(NUMBER % v for v in (t_s, vehicle_time_s, *duty)) + "\n")

    def write_json(self, name: str, data: dict) -> None:
        tmp = self.folder / f".{name}.tmp"
        tmp.write_text(json.dumps(data, indent=2, allow_nan=False, default=_jsonable) + "\n")
        tmp.replace(self.folder / name)

    def close(self) -> None:
        for stream in (self._states, self._motors):
            if stream is not None and not stream.closed:
                stream.close()

    def __enter__(self) -> FlightLog:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _jsonable(value):
    try:
        import numpy as np

        if isinstance(value, np.ndarray):
            return value.tolist()
        if isinstance(value, np.generic):
            return value.item()
    except ImportError:  # pragma: no cover
        pass
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")
