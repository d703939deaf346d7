import numpy as np

from .graph_search import graph_search


def snap_segments(points, times):
    """Minimum-snap 7th-order polynomials through the points, rest at both ends, C6 at the knots."""
    m = len(points) - 1
    n = 8 * m

    def row(tau, d):
        r = np.zeros(8)
        for p in range(d, 8):
            r[p] = np.prod(range(p - d + 1, p + 1)) * tau ** (p - d)
        return r

    coeffs = np.zeros((m, 8, 3))
    for axis in range(3):
        A = np.zeros((n, n))
        b = np.zeros(n)
        k = 0
        for i in range(m):
            A[k, 8 * i:8 * i + 8] = row(0, 0); b[k] = points[i, axis]; k += 1
            A[k, 8 * i:8 * i + 8] = row(times[i], 0); b[k] = points[i + 1, axis]; k += 1
        for d in (1, 2, 3):
            A[k, 0:8] = row(0, d); k += 1
            A[k, 8 * (m - 1):8 * m] = row(times[-1], d); k += 1
        for i in range(m - 1):
            for d in range(1, 7):
                A[k, 8 * i:8 * i + 8] = row(times[i], d)
                A[k, 8 * (i + 1):8 * (i + 1) + 8] = -row(0, d)
                k += 1
        coeffs[:, :, axis] = np.linalg.solve(A, b).reshape(m, 8)
    return coeffs


class WorldTraj(object):
    def __init__(self, world, start, goal):
        self.resolution = np.array([0.1, 0.1, 0.1])
        self.margin = 0.3
        self.path, _ = graph_search(world, self.resolution, self.margin, start, goal, astar=True)
        self.points = self.sparse(self.path)
        for _ in range(10):
            self.build()
            samples = np.array([self.update(t)['x'] for t in np.linspace(0, self.t_start[-1], 400)])
            if len(world.path_collisions(samples, 0.25)) == 0:
                break
            mids = (self.points[:-1] + self.points[1:]) / 2
            self.points = np.insert(self.points, np.arange(1, len(self.points)), mids, axis=0)

    def sparse(self, path):
        keep = [path[0]]
        for i in range(1, len(path) - 1):
            if np.linalg.norm(np.cross(path[i] - keep[-1], path[i + 1] - path[i])) > 1e-9:
                keep.append(path[i])
        keep.append(path[-1])
        return np.array(keep)

    def build(self):
        lengths = np.linalg.norm(np.diff(self.points, axis=0), axis=1)
        self.durations = np.maximum(2.0 * np.sqrt(lengths / 1.2), 0.4)
        self.t_start = np.concatenate([[0.0], np.cumsum(self.durations)])
        self.coeffs = snap_segments(self.points, self.durations)

    def update(self, t):
        out = {k: np.zeros(3) for k in ('x', 'x_dot', 'x_ddot', 'x_dddot', 'x_ddddot')}
        if t >= self.t_start[-1]:
            out['x'] = self.points[-1]
        else:
            i = int(np.searchsorted(self.t_start, t, side='right') - 1)
            tau = t - self.t_start[i]
            for d, key in enumerate(('x', 'x_dot', 'x_ddot', 'x_dddot', 'x_ddddot')):
                powers = np.array([np.prod(range(p - d + 1, p + 1)) * tau ** (p - d) if p >= d else 0.0
                                   for p in range(8)])
                value = powers @ self.coeffs[i]
                out[key] = value if key == 'x' else value.reshape(3, 1)   # (3, 1), as some students leave it
        out['yaw'] = 0.0
        out['yaw_dot'] = 0.0
        return out
