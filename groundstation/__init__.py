"""cfstack ground station: planning, trajectories, the SE(3) controller, the flight loop and mission.

Takes in: downlink frames and mocap poses through link/, world files, gains and vehicle parameters.
Gives out: thrust/moment or thrust/attitude commands through link/, logs and plots.
Never imports simulator/.
"""
