import numpy as np

from proj1_3.code.graph_search import graph_search


class WorldTraj(object):
    """Constant speed through the A* path's corners."""

    def __init__(self, world, start, goal):
        self.resolution = np.array([0.1, 0.1, 0.1])
        self.margin = 0.3
        self.path, _ = graph_search(world, self.resolution, self.margin, start, goal, astar=True)
        self.points = self.prune(self.path)
        self.speed = 0.6
        seg = np.diff(self.points, axis=0)
        self.lengths = np.linalg.norm(seg, axis=1)
        self.dirs = seg / self.lengths[:, None]
        self.times = np.concatenate([[0.0], np.cumsum(self.lengths / self.speed)])

    def prune(self, path):
        keep = [path[0]]
        for i in range(1, len(path) - 1):
            d1 = path[i] - keep[-1]
            d2 = path[i + 1] - path[i]
            if np.linalg.norm(np.cross(d1, d2)) > 1e-9:
                keep.append(path[i])
        keep.append(path[-1])
        return np.array(keep)

    def update(self, t):
        x_dot = np.zeros((3,))
        if t >= self.times[-1]:
            x = self.points[-1]
        else:
            i = np.searchsorted(self.times, t, side='right') - 1
            x = self.points[i] + self.dirs[i] * self.speed * (t - self.times[i])
            x_dot = self.dirs[i] * self.speed
        flat_output = {'x': x, 'x_dot': x_dot, 'x_ddot': np.zeros((3,)), 'x_dddot': np.zeros((3,)),
                       'x_ddddot': np.zeros((3,)), 'yaw': 0, 'yaw_dot': 0}
        return flat_output
