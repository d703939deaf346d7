"""Course-compatible modules that unmodified student files import (see groundstation.usercode.loader).

Holds: `flightsim` (world, crazyflie_params), put first on sys.path while user code is loaded, and
`course_code` (occupancy_map, graph_search), mounted behind the user's own directory as `proj1_3.code`.
Written from the course's interface (../shared/reference/course_controller_interface.md), backed by
cfstack's own world model, occupancy grid and A*; nothing is copied from the course's code.
"""
