"""The Crazyflie 2.1's onboard control stack, as crazyflie-firmware runs it (`--firmware crazyflie`).

Holds: one module per firmware part, each with its rate and units, written from the firmware's source
(bitcraze/crazyflie-firmware @ 2a18fc2; the parameters and their files are in
simulator/params/crazyflie.toml):
- pid.py                 the PID object (src/utils/src/pid.c)
- attitude_controller.py the attitude and rate PIDs, 500 Hz (controller/attitude_pid_controller.c)
- controller_pid.py      the PID controller's flow: yaw-rate integration, resets, legacy pitch (controller_pid.c)
- position_controller.py the position and velocity PIDs, 100 Hz (controller/position_controller_pid.c)
- position_estimator.py  the onboard position and velocity from the accelerometer and external positions
- commander_rpyt.py      the legacy RPYT setpoint: thrust lock, thrust limits (crtp_commander_rpyt.c), for CRTP
- power_distribution.py  legacy and force-torque mixers, the cap (power_distribution_quadrotor.c)
- motors.py              battery compensation and the motor-voltage thrust curve (motors.c, platform_defaults_cf2.h)
- battery.py             the battery: open-circuit voltage, sag under load
- sensfusion6.py         the complementary (Mahony) attitude filter, 250 Hz (sensfusion6.c)
- stabilizer.py          the loop that ties them to the commander (stabilizer.c), the emulator's faithful firmware
Units inside follow the firmware where its parts are defined in them (deg, deg/s, PWM 0-65535, g); each
name says its unit. Takes in: IMU samples and setpoints; gives out: per-motor PWM and motor forces (N).
May import: model, link.messages, simulator.firmware (the commander it shares).
"""
