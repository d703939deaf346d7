"""cfstack estimator: error-state Kalman filter fusing IMU and mocap.

Takes in: link.messages.ImuSample and link.messages.MocapPose (sample times in seconds).
Gives out: state estimate (position ENU m, velocity ENU m/s, attitude quaternion wxyz body FLU -> world ENU,
IMU biases), its covariance and a health flag.
"""
