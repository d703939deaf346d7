"""`flightsim.world.World` as course code uses it, backed by model.world.

Takes in: a course world dict or JSON file (bounds.extents, blocks[].extents, start, goal, ...).
Gives out: World with `.world` (the dict, as the course's World keeps it), `from_file`, `empty` and
`path_collisions(path, margin)` (the points of a densely sampled path within `margin` of a block).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from model.world import World as ModelWorld
from model.world import parse_world

# The course's path_collisions samples the path densely; we sample every centimetre (our choice: a
# tenth of the thinnest wall in ../shared/worlds, 0.04 m, would be 4 mm; 1 cm keeps it cheap and a 2 cm
# margin check still sees a point on each side of a 4 cm wall).
COLLISION_SAMPLE_STEP_M = 0.01


class World:
    """The course's World: the raw dict in `.world`, geometry from cfstack's model.world."""

    def __init__(self, world_data: dict):
        self.world = world_data
        self._model = parse_world(world_data, source="<flightsim World>")

    @classmethod
    def from_file(cls, filename: str | Path) -> World:
        with open(filename) as file:
            return cls(json.load(file))

    @classmethod
    def from_model(cls, world: ModelWorld) -> World:
        """The course's dict of a cfstack world (what the host hands to WorldTraj and graph_search)."""
        data: dict = {"bounds": {"extents": [float(v) for v in world.bounds]},
                      "blocks": [{"extents": [float(v) for v in block]} for block in world.blocks]}
        for key in ("start", "goal", "resolution"):
            value = getattr(world, key)
            if value is not None:
                data[key] = [float(v) for v in value]
        if world.margin is not None:
            data["margin"] = float(world.margin)
        return cls(data)

    @classmethod
    def empty(cls, extents) -> World:
        return cls({"bounds": {"extents": [float(v) for v in extents]}, "blocks": []})

    @property
    def model(self) -> ModelWorld:
        return self._model

    def path_collisions(self, path, margin: float) -> np.ndarray:
        """Points (N, 3) of the path, sampled every COLLISION_SAMPLE_STEP_M, closer than `margin` to a block."""
        points = np.asarray(path, float).reshape(-1, 3)
        if len(points) == 0:
            return np.zeros((0, 3))
        dense = [points[:1]]
        for p0, p1 in zip(points[:-1], points[1:], strict=True):
            n = max(1, int(np.ceil(np.linalg.norm(p1 - p0) / COLLISION_SAMPLE_STEP_M)))
            dense.append(p0 + np.outer(np.arange(1, n + 1) / n, p1 - p0))
        samples = np.concatenate(dense)
        return samples[self._model.distance_to_blocks(samples) < margin]
