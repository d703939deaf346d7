"""`flightsim.crazyflie_params.quad_params`: the course's 9-key dict, for the vehicle this session flies.

Takes in: the vehicle model the host selected (groundstation.usercode.quad_params; the course model
`crazyflie` when imported outside a session). Gives out: `quad_params` (mass kg, Ixx/Iyy/Izz kg m^2,
arm_length m, rotor_speed_min/max rad/s, k_thrust N/(rad/s)^2, k_drag N m/(rad/s)^2).
"""

from groundstation.usercode.quad_params import current_quad_params

quad_params = current_quad_params()
