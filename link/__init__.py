"""cfstack link: everything that crosses between processes.

Takes in: typed messages (link.messages dataclasses, ENU/FLU, SI units) and raw frames from transports.
Gives out: MAVLink 2 frames on a transport chosen by connection string, link statistics, .tlog logs.
pymavlink and zenoh are imported here and nowhere else in the project.
"""
