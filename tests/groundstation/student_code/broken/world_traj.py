import numpy as np


class WorldTraj(object):
    """A line from start to goal at 0.5 m/s whose update() raises once its cache of 1500 samples is full
    (a bug that a scan of the trajectory before the flight does not reach)."""

    def __init__(self, world, start, goal):
        self.start, self.goal = np.asarray(start, float), np.asarray(goal, float)
        self.T = np.linalg.norm(self.goal - self.start) / 0.5
        self.cache = np.zeros((1500, 3))
        self.calls = 0

    def update(self, t):
        self.cache[self.calls] = t
        self.calls += 1
        s = min(t / self.T, 1.0)
        return {'x': self.start + s * (self.goal - self.start), 'x_dot': np.zeros(3), 'x_ddot': np.zeros(3),
                'x_dddot': np.zeros(3), 'x_ddddot': np.zeros(3), 'yaw': 0, 'yaw_dot': 0}


class RaisesInConstructor(object):
    def __init__(self, world, start, goal):
        self.points = world.world['blocks'][0]['extents'][7]
