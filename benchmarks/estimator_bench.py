"""Speed of the estimator: microseconds per add_imu and per add_mocap, candidate against a naive baseline.

Takes in: nothing (a seeded synthetic 1 m/s circle from tests/estimator/synthetic.py, crazyflie + vicon).
Gives out: a table on stdout. Budget (issue "The ground station"): <= 60 us per IMU propagation and
<= 150 us per mocap update including the rollback, on average.

Baseline ("naive"), same run, same data: the textbook way - F and Q by the exact Van Loan
discretisation with scipy.linalg.expm every IMU interval, and every mocap frame replays the whole
buffer (full recompute) instead of only the samples after the frame.

Run: python benchmarks/estimator_bench.py [--seconds 10] [--naive-seconds 1.5]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import scipy.linalg

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "estimator"))

from synthetic import Flight, LinkFaults, simulate  # noqa: E402

from estimator.eskf import ErrorStateKF  # noqa: E402
from link.messages import ImuSample  # noqa: E402
from link.vehicle import load_mocap_room, load_vehicle  # noqa: E402


class NaiveErrorStateKF(ErrorStateKF):
    """Same filter, textbook costs: expm discretisation and full-buffer replay on every frame."""

    def _transition(self, r, f, w, dt):
        rot = np.array(r).reshape(3, 3)
        a = np.zeros((15, 15))
        a[0:3, 3:6] = np.eye(3)
        a[3:6, 6:9] = -rot @ _skew(f)
        a[3:6, 9:12] = -rot
        a[6:9, 6:9] = -_skew(w)
        a[6:9, 12:15] = -np.eye(3)
        qc = np.diag([0.0] * 3 + [self._accel_psd] * 3 + [self._gyro_psd] * 3
                     + [self._accel_bias_psd] * 3 + [self._gyro_bias_psd] * 3)
        m = np.zeros((30, 30))
        m[:15, :15] = -a * dt
        m[:15, 15:] = qc * dt
        m[15:, 15:] = a.T * dt
        e = scipy.linalg.expm(m)
        f_d = e[15:, 15:].T
        return f_d, f_d @ e[:15, 15:]

    _in_mocap = False

    def add_mocap(self, pose):
        self._in_mocap = True
        try:
            return super().add_mocap(pose)
        finally:
            self._in_mocap = False

    def _replay_from(self, i):
        self._reuse_transitions = False
        for j in range(1 if self._in_mocap else i, len(self._nodes)):
            self._process(j)


def _skew(v) -> np.ndarray:
    x, y, z = v
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def time_filter(kf: ErrorStateKF, events: list, warmup_events: int) -> tuple[float, float, int, int]:
    """Mean microseconds per add_imu and per add_mocap (after warm-up), and how many of each."""
    t_imu = t_mocap = 0.0
    n_imu = n_mocap = 0
    clock = time.perf_counter
    for k, (_, msg) in enumerate(events):
        if isinstance(msg, ImuSample):
            t0 = clock()
            kf.add_imu(msg)
            dt = clock() - t0
            if k >= warmup_events:
                t_imu += dt
                n_imu += 1
        else:
            t0 = clock()
            kf.add_mocap(msg)
            dt = clock() - t0
            if k >= warmup_events:
                t_mocap += dt
                n_mocap += 1
    return 1e6 * t_imu / n_imu, 1e6 * t_mocap / n_mocap, n_imu, n_mocap


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0, help="flight length (s)")
    parser.add_argument("--naive-seconds", type=float, default=1.5,
                        help="flight length for the (slow) naive baseline, its first seconds of the same run")
    args = parser.parse_args(argv)
    vehicle, room = load_vehicle("crazyflie"), load_mocap_room("vicon")
    flight = Flight(duration_s=args.seconds)
    print(f"estimator bench: {args.seconds:.0f} s synthetic 1 m/s circle, IMU {vehicle.imu.rate_hz:.0f} Hz, "
          f"mocap {room.rate_hz:.0f} Hz")
    print(f"{'case':34s} {'us/add_imu':>11s} {'us/add_mocap':>13s}   budget 60 / 150 us")
    cases = (("vicon latency 5 ms", LinkFaults()),
             ("latency 20 ms", LinkFaults(mocap_latency_s=0.020)),
             ("20 ms + 15 ms jitter", LinkFaults(mocap_latency_s=0.020, mocap_jitter_s=0.015)))
    for label, faults in cases:
        run = simulate(flight, vehicle.imu, room, np.random.default_rng(7), faults)
        warmup = len(run.events) // 10
        cand = time_filter(ErrorStateKF(vehicle, room), run.events, warmup)
        naive_events = [e for e in run.events if e[0] < args.naive_seconds]
        naive = time_filter(NaiveErrorStateKF(vehicle, room), naive_events, len(naive_events) // 5)
        print(f"{'  candidate, ' + label:34s} {cand[0]:11.1f} {cand[1]:13.1f}")
        print(f"{'  naive, ' + label:34s} {naive[0]:11.1f} {naive[1]:13.1f}   "
              f"(candidate faster x{naive[0] / cand[0]:.1f} / x{naive[1] / cand[1]:.1f})")


if __name__ == "__main__":
    main()
