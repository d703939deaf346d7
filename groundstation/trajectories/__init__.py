"""Reference trajectories implementing groundstation.trajectory.Trajectory (duration_s, sample(t_s)).

Takes in: waypoints or paths (m, world ENU) and timing parameters.
Gives out: trajectories whose sample(t_s) returns a FlatOutput (position, velocity, acceleration, jerk,
snap, yaw); before 0 they hold the start and after duration_s the end, at rest.
"""
