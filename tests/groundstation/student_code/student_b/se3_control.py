import numpy as np
from scipy.spatial.transform import Rotation

from flightsim.crazyflie_params import quad_params as default_params


class SE3Control(object):
    """Attitude-mode controller for the lab: cmd_q is R_des, cmd_thrust the four rotor thrusts."""

    def __init__(self, quad_params=default_params):
        self.mass = quad_params['mass']
        self.inertia = np.diag([quad_params['Ixx'], quad_params['Iyy'], quad_params['Izz']])
        self.k_thrust = quad_params['k_thrust']
        L, k = quad_params['arm_length'], quad_params['k_drag'] / quad_params['k_thrust']
        self.to_TM = np.array([[1, 1, 1, 1], [0, L, 0, -L], [-L, 0, L, 0], [k, -k, k, -k]])
        self.Kp = np.diag([6.0, 6.0, 10.0])
        self.Kd = np.diag([4.0, 4.0, 5.0])
        self.Kr = np.diag([450.0, 450.0, 220.0])
        self.Kw = np.diag([65.0, 65.0, 45.0])

    def update(self, t, state, flat_output):
        x_ddot_des = (np.ravel(flat_output['x_ddot']) - self.Kd @ (state['v'] - np.ravel(flat_output['x_dot']))
                      - self.Kp @ (state['x'] - np.ravel(flat_output['x'])))
        F_des = self.mass * (x_ddot_des + np.array([0, 0, 9.81]))
        R = Rotation.from_quat(state['q']).as_matrix()
        u1 = R[:, 2] @ F_des
        b3 = F_des / np.linalg.norm(F_des)
        psi = flat_output['yaw']
        b2 = np.cross(b3, [np.cos(psi), np.sin(psi), 0])
        b2 /= np.linalg.norm(b2)
        R_des = np.column_stack([np.cross(b2, b3), b2, b3])
        S = R_des.T @ R - R.T @ R_des
        e_R = 0.5 * np.array([S[2, 1], S[0, 2], S[1, 0]])
        u2 = self.inertia @ (-self.Kr @ e_R - self.Kw @ state['w'])
        rotor_thrusts = np.linalg.solve(self.to_TM, np.r_[u1, u2])
        speeds = np.sqrt(np.maximum(rotor_thrusts, 0) / self.k_thrust)
        return {'cmd_motor_speeds': speeds.reshape(4, 1),
                'cmd_thrust': rotor_thrusts.reshape(4, 1),   # the four rotors' thrusts: the host sums them
                'cmd_moment': u2,
                'cmd_q': Rotation.from_matrix(R_des).as_quat()}
