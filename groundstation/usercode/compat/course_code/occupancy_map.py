"""The course's `OccupancyMap(world, resolution, margin)`, backed by cfstack's OccupancyGrid.

Takes in: a flightsim-compatible World (or a cfstack model World), a voxel size (m, one value or three)
and a margin (m). Gives out: the course's attributes (`world`, `resolution`, `margin`, `origin`, `map`,
a boolean (nx, ny, nz) array, True = occupied) and methods on single points or indices.
"""

from __future__ import annotations

import numpy as np

from groundstation.planning.occupancy import OccupancyGrid


def model_world(world):
    """cfstack's World behind a flightsim World (or the model World itself)."""
    return getattr(world, "model", world)


class OccupancyMap:
    def __init__(self, world, resolution=(0.1, 0.1, 0.1), margin: float = 0.2):
        self.world = world
        self.resolution = np.broadcast_to(np.asarray(resolution, float), (3,)).copy()
        self.margin = float(margin)
        self._grid = OccupancyGrid.from_world(model_world(world), self.resolution, self.margin)
        self.origin = self._grid.origin_m.copy()
        self.map = self._grid.occupied

    def index_to_metric_negative_corner(self, index) -> np.ndarray:
        return self.origin + np.asarray(index, float) * self.resolution

    def index_to_metric_center(self, index) -> np.ndarray:
        return self._grid.index_to_metric_center(index)

    def metric_to_index(self, metric) -> np.ndarray:
        return self._grid.metric_to_index(metric)

    def is_valid_index(self, index) -> bool:
        return bool(self._grid.is_valid_index(index))

    def is_valid_metric(self, metric) -> bool:
        return self.is_valid_index(self.metric_to_index(metric))

    def is_occupied_index(self, index) -> bool:
        return bool(self._grid.is_occupied_index(index))

    def is_occupied_metric(self, metric) -> bool:
        return self.is_occupied_index(self.metric_to_index(metric))
