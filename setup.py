"""The compiled parts of cfstack (everything else is in pyproject.toml): estimator/_eskf_kernels.c (the
estimator's per-sample propagation and Kalman steps, and with estimator/_eskf_timeline.h its timeline),
simulator/_dynamics_kernels.c (the rigid body's RK4 step, the rotors' lag), simulator/crazyflie/_drive_kernel.c
(the faithful firmware's drive chain), simulator/crazyflie/_pid_kernel.c (its attitude and rate PIDs),
groundstation/_compensation_kernel.c (the latency compensator's model steps),
groundstation/_controller_kernel.c (the SE(3) controller's report law), groundstation/_flightlog_kernel.c
(states.csv's row text), link/mavlink/_frame_kernel.c (the MAVLink encoder and parser of a tick's frames) and
link/_deliver_kernel.c (Endpoint.deliver's work per frame).

Optional: where they cannot be built (no C compiler), pip installs cfstack without them and each runs its
Python twin (estimator/eskf_kernels.py and eskf_timeline.py, simulator/dynamics_kernels.py, the firmware's,
the compensator's, the controller's, the flight log's, the codec's and the endpoint's own Python), which gives the
same results, slower.
model/_kernels.h holds what they all read from Python (included, so listed in depends: rebuilt and shipped), as
estimator/_eskf_timeline.h does for estimator._eskf_kernels alone.
-ffp-contract=off: no fused multiply-add, so the C gives the Python twins' bits on every CPU.
"""

from setuptools import Extension, setup

HEADERS = {"estimator._eskf_kernels": ("estimator/_eskf_timeline.h",)}  # included by that extension alone

setup(ext_modules=[Extension(name, [source], depends=["model/_kernels.h", *HEADERS.get(name, ())],
                             extra_compile_args=["-ffp-contract=off"], optional=True)
                   for name, source in (("estimator._eskf_kernels", "estimator/_eskf_kernels.c"),
                                        ("simulator._dynamics_kernels", "simulator/_dynamics_kernels.c"),
                                        ("simulator.crazyflie._drive_kernel", "simulator/crazyflie/_drive_kernel.c"),
                                        ("simulator.crazyflie._pid_kernel", "simulator/crazyflie/_pid_kernel.c"),
                                        ("groundstation._compensation_kernel",
                                         "groundstation/_compensation_kernel.c"),
                                        ("groundstation._controller_kernel", "groundstation/_controller_kernel.c"),
                                        ("groundstation._flightlog_kernel", "groundstation/_flightlog_kernel.c"),
                                        ("link.mavlink._frame_kernel", "link/mavlink/_frame_kernel.c"),
                                        ("link._deliver_kernel", "link/_deliver_kernel.c"))])
