"""The estimator's shortcuts around filterpy give filterpy's own bits (issue 19: behaviour unchanged)."""

from __future__ import annotations

import numpy as np
from filterpy.kalman import KalmanFilter

from estimator.eskf import N_ERROR, ErrorStateKF


def _random_transition(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    A = rng.normal(size=(N_ERROR, N_ERROR))
    P = A @ A.T + np.eye(N_ERROR)  # a covariance: symmetric positive definite
    F = np.eye(N_ERROR) + 0.01 * rng.normal(size=(N_ERROR, N_ERROR))
    B = rng.normal(size=(N_ERROR, N_ERROR))
    return P, F, 1e-6 * (B @ B.T)


def test_covariance_prediction_is_filterpys_bit_for_bit():
    rng = np.random.default_rng(7)
    for _ in range(50):
        P, F, Q = _random_transition(rng)
        kf = KalmanFilter(dim_x=N_ERROR, dim_z=6)
        kf.x, kf.P, kf.F, kf.Q = np.zeros((N_ERROR, 1)), P, F, Q
        kf.predict()
        ours = ErrorStateKF._predict(P, (F, Q))
        assert ours.tobytes() == kf.P.tobytes()
        assert not np.shares_memory(ours, P)  # a new array: the stored P of the node before is kept


def test_chained_predictions_stay_equal_over_a_flight_length():
    """A second of 500 Hz steps: rounding does not drift apart either (same calls, same order)."""
    rng = np.random.default_rng(11)
    P, _, _ = _random_transition(rng)
    kf = KalmanFilter(dim_x=N_ERROR, dim_z=6)
    kf.x, kf.P = np.zeros((N_ERROR, 1)), P.copy()
    ours = P.copy()
    for _ in range(500):
        _, F, Q = _random_transition(rng)
        kf.F, kf.Q = F, Q
        kf.predict()
        ours = ErrorStateKF._predict(ours, (F, Q))
    assert ours.tobytes() == kf.P.tobytes()
