"""cfstack simulator: the emulated Crazyflie, its sensors, the mocap room and the simulated radio.

Takes in: MAVLink uplink frames (commands, heartbeats, TIMESYNC) through link/.
Gives out: downlink frames (IMU, HEARTBEAT, status, TIMESYNC replies, RADIO_STATUS), mocap poses,
and simulation-only ground truth, all through link/.
Never imports groundstation/.
"""
