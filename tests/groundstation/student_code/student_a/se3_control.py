import numpy as np
from scipy.spatial.transform import Rotation


class SE3Control(object):
    """Geometric controller, as in the project handout (gains near the lab report's)."""

    def __init__(self, quad_params):
        self.mass = quad_params['mass']
        self.Ixx = quad_params['Ixx']
        self.Iyy = quad_params['Iyy']
        self.Izz = quad_params['Izz']
        self.arm_length = quad_params['arm_length']
        self.rotor_speed_min = quad_params['rotor_speed_min']
        self.rotor_speed_max = quad_params['rotor_speed_max']
        self.k_thrust = quad_params['k_thrust']
        self.k_drag = quad_params['k_drag']
        self.inertia = np.diag(np.array([self.Ixx, self.Iyy, self.Izz]))
        self.g = 9.81
        self.Kp = np.diag([7.0, 7.0, 12.0])
        self.Kd = np.diag([4.4, 4.4, 6.0])
        self.Kr = np.diag([500.0, 500.0, 250.0])
        self.Kw = np.diag([70.0, 70.0, 50.0])
        L, k = self.arm_length, self.k_drag / self.k_thrust
        self.to_TM = np.array([[1, 1, 1, 1], [0, L, 0, -L], [-L, 0, L, 0], [k, -k, k, -k]])

    def update(self, t, state, flat_output):
        r_ddot_des = (flat_output['x_ddot'] - self.Kd @ (state['v'] - flat_output['x_dot'])
                      - self.Kp @ (state['x'] - flat_output['x']))
        F_des = self.mass * r_ddot_des + np.array([0, 0, self.mass * self.g])
        R = Rotation.from_quat(state['q']).as_matrix()
        b3 = R @ np.array([0, 0, 1])
        u1 = b3 @ F_des
        b3_des = F_des / np.linalg.norm(F_des)
        a_psi = np.array([np.cos(flat_output['yaw']), np.sin(flat_output['yaw']), 0])
        b2_des = np.cross(b3_des, a_psi)
        b2_des = b2_des / np.linalg.norm(b2_des)
        R_des = np.column_stack([np.cross(b2_des, b3_des), b2_des, b3_des])
        S = 0.5 * (R_des.T @ R - R.T @ R_des)
        e_R = np.array([S[2, 1], S[0, 2], S[1, 0]])
        u2 = self.inertia @ (-self.Kr @ e_R - self.Kw @ state['w'])
        F = np.linalg.solve(self.to_TM, np.concatenate([[u1], u2]))
        cmd_motor_speeds = np.sqrt(np.clip(F, 0, None) / self.k_thrust)
        cmd_motor_speeds = np.clip(cmd_motor_speeds, self.rotor_speed_min, self.rotor_speed_max)
        control_input = {'cmd_motor_speeds': cmd_motor_speeds,
                         'cmd_thrust': np.array([u1]),             # shape (1,), as many students return it
                         'cmd_moment': u2.reshape(3, 1),           # shape (3, 1)
                         'cmd_q': Rotation.from_matrix(R_des).as_quat()}
        return control_input
