"""The firmware's attitude and rate PIDs, three at a time, compiled (issue 19).

Takes in: a tuple of three simulator.crazyflie.pid.Pid (gains and state read from them, state written back),
the desired and measured values (3 floats each: deg or deg/s), whether the third error wraps to +-180 deg (the
yaw angle PID), whether the outputs saturate to int16 (the rate PIDs).
Gives out: `update3`, the compiled kernel (simulator/crazyflie/_pid_kernel.c, built by `pip install`), or None
where it was not built; it returns the three outputs, or None (having changed nothing) for a call it leaves to
the Python.

The Python is AttitudeController.correct_attitude_python and correct_rate_python (attitude_controller.py,
through Pid.update); the kernel gives their bits (tests/simulator/test_pid_kernel.py). Why compiled: the six
PID updates of each 500 Hz cycle took about 6 us in Python, a third of the faithful firmware's cycle in
attitude mode (README: Lockstep speed).
"""

from __future__ import annotations

try:
    from simulator.crazyflie._pid_kernel import update3
except ImportError:  # not built (no C compiler at install): the firmware runs its Python, same results, slower
    update3 = None

COMPILED = update3 is not None
