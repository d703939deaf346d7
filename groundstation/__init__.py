"""cfstack ground station: planning, trajectories, the SE(3) controller, the flight loop and mission.

Takes in: downlink frames and mocap poses through link/, world files and vehicle parameters (model/),
gains and mission parameters (groundstation/params/).
Gives out: thrust/moment or thrust/attitude commands through link/, logs and plots.
May import: estimator, link, model. Never imports simulator/ (it must fly a real vehicle unchanged) and
never uses simulator ground truth for control (truth is for logs and grading only).
"""
