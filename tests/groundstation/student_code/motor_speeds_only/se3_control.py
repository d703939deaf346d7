import numpy as np
from scipy.spatial.transform import Rotation


class SE3Control:
    """Written for the course simulator, which flies only cmd_motor_speeds: the rest is left as zeros."""

    def __init__(self, quad_params):
        self.m = quad_params['mass']
        self.J = np.diag([quad_params['Ixx'], quad_params['Iyy'], quad_params['Izz']])
        self.kf = quad_params['k_thrust']
        self.wmin, self.wmax = quad_params['rotor_speed_min'], quad_params['rotor_speed_max']
        L, g = quad_params['arm_length'], quad_params['k_drag'] / quad_params['k_thrust']
        self.TM_inv = np.linalg.inv(np.array([[1, 1, 1, 1], [0, L, 0, -L], [-L, 0, L, 0], [g, -g, g, -g]]))

    def update(self, t, state, flat_output):
        a = flat_output['x_ddot'] - 4.5 * (state['v'] - flat_output['x_dot']) - 7.0 * (state['x'] - flat_output['x'])
        F = self.m * (a + [0, 0, 9.81])
        R = Rotation.from_quat(state['q']).as_matrix()
        b3 = F / np.linalg.norm(F)
        b2 = np.cross(b3, [np.cos(flat_output['yaw']), np.sin(flat_output['yaw']), 0])
        b2 = b2 / np.linalg.norm(b2)
        Rd = np.column_stack([np.cross(b2, b3), b2, b3])
        E = Rd.T @ R - R.T @ Rd
        M = self.J @ (-np.diag([500, 500, 250]) @ (0.5 * np.array([E[2, 1], E[0, 2], E[1, 0]]))
                      - np.diag([70, 70, 50]) @ state['w'])
        f = self.TM_inv @ np.r_[F @ R[:, 2], M]
        w = np.clip(np.sqrt(np.clip(f, 0, None) / self.kf), self.wmin, self.wmax)
        return {'cmd_motor_speeds': w, 'cmd_thrust': 0, 'cmd_moment': np.zeros(3), 'cmd_q': np.array([0, 0, 0, 1])}
