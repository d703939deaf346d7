"""Flying users' own course-style code (MEAM 620 flightsim / RotorPy interface) unchanged.

Holds: loader (PATH[:Name] -> object, the course's import environment), compat (flightsim and the
course's occupancy_map/graph_search backed by cfstack), quad_params (the course's 9-key dict of a
vehicle), guard (timed, interruptible calls; faults), adapters (controller, trajectory, planner behind
cfstack's interfaces), host (what a session needs: prepare, attach, summary).
Takes in: the user's files or objects. Gives out: cfstack controllers, trajectories and planners.
"""
