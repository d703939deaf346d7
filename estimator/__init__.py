"""cfstack estimator: error-state Kalman filter fusing IMU and mocap.

Takes in: link.messages.ImuSample and link.messages.MocapPose (sample times in seconds), what it assumes
of its sensors (estimator.sensor_spec, estimator/params/sensors/: data-sheet figures, never the simulator's
settings) and its tuning (estimator/params/eskf.toml).
Gives out: state estimate (position ENU m, velocity ENU m/s, attitude quaternion wxyz body FLU -> world ENU,
IMU biases), its covariance and a health flag.
May import: model, link.messages.
"""
