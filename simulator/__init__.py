"""cfstack simulator: the emulated Crazyflie, its sensors, the mocap room and the simulated radio.

Takes in: MAVLink uplink frames (commands, heartbeats, TIMESYNC) through link/; world, vehicle, mocap
and radio descriptions from model/; firmware parameters (simulator/params/firmware.toml).
Gives out: downlink frames (IMU, HEARTBEAT, status, TIMESYNC replies, RADIO_STATUS), mocap poses,
and simulation-only ground truth, all through link/.
May import: link, model. Never imports groundstation/ (the emulator must answer any client).
"""
