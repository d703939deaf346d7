import numpy as np
from scipy.spatial.transform import Rotation

from flightsim.crazyflie_params import quad_params as QP

CALLS_BEFORE_TROUBLE = 1500  # 3 s at 500 Hz: airborne, then the bug


class _Hover:
    """A geometric law that is fine until CALLS_BEFORE_TROUBLE calls; subclasses break differently then."""

    def __init__(self, quad_params=QP):
        self.m = quad_params['mass']
        self.J = np.diag([quad_params['Ixx'], quad_params['Iyy'], quad_params['Izz']])
        self.calls = 0

    def law(self, state, flat_output):
        a = flat_output['x_ddot'] - 4.0 * (state['v'] - flat_output['x_dot']) - 6.0 * (state['x'] - flat_output['x'])
        F = self.m * (a + [0, 0, 9.81])
        R = Rotation.from_quat(state['q']).as_matrix()
        b3 = F / np.linalg.norm(F)
        b2 = np.cross(b3, [1.0, 0.0, 0.0])
        b2 = b2 / np.linalg.norm(b2)
        Rd = np.column_stack([np.cross(b2, b3), b2, b3])
        E = Rd.T @ R - R.T @ Rd
        M = self.J @ (-500.0 * 0.5 * np.array([E[2, 1], E[0, 2], E[1, 0]]) - 70.0 * state['w'])
        return {'cmd_thrust': F @ R[:, 2], 'cmd_moment': M, 'cmd_q': Rotation.from_matrix(Rd).as_quat(),
                'cmd_motor_speeds': np.zeros(4)}

    def update(self, t, state, flat_output):
        self.calls += 1
        out = self.law(state, flat_output)
        return self.trouble(out) if self.calls > CALLS_BEFORE_TROUBLE else out

    def trouble(self, out):
        return out


class Raises(_Hover):
    def trouble(self, out):
        return {'cmd_thrust': out['cmd_thrust'], 'cmd_moment': out['cmd_moment'][3]}


class ReturnsNaN(_Hover):
    def trouble(self, out):
        out['cmd_moment'] = np.array([np.nan, 0, 0])
        return out


class OmitsKey(_Hover):
    def trouble(self, out):
        del out['cmd_moment']
        return out


class Hangs(_Hover):
    def trouble(self, out):
        while True:
            pass


class Slow(_Hover):
    """Correct, but takes a few milliseconds per call (as real student code does, 4-18 ms)."""

    def update(self, t, state, flat_output):
        import time
        time.sleep(0.004)
        return self.law(state, flat_output)


class Correct(_Hover):
    pass
