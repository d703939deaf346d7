"""CRTP, the Crazyflie's own protocol as Bitcraze's cflib speaks it: packets, TOCs and setpoint payloads.

The MAVLink codec (link.mavlink) carries cfstack's messages; this package is the second codec, for
clients that speak to a Crazyflie (cflib scripts, cfclient). Wire facts: ../shared/reference/
crtp_cflib_emulation.md, checked against cflib 0.1.34 (cflib/crtp/crtpstack.py, cflib/crazyflie/*.py).
"""
