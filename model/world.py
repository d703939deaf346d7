"""World maps: the course's world JSON files, read and validated the same way everywhere.

Takes in: a world JSON file `{"bounds": {"extents": [xmin, xmax, ymin, ymax, zmin, zmax]},
"blocks": [{"extents": [...], "color": ...}], "start": [x, y, z], "goal": [x, y, z]}` with optional
`resolution`, `margin`, `expected_path_length` (may be the bare token Infinity) and `timeout`.
Gives out: a `World` (bounds, blocks as an (N, 6) array in metres, ENU) or a one-line `WorldError`
naming the file and the problem.

Both the emulator (collisions) and the ground station (planning, clearance) read worlds, so this is
their one home.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np

from model.errors import WorldError

# A point this close below a block's top still rests on it: positions that crossed a MAVLink link are
# float32 (1.16 m reads back as 1.1599999666 m; float32 spacing is 1.2e-7 m at 1 m, 1.9e-6 m at 20 m).
RESTING_TOLERANCE_M = 1e-5


@dataclass(frozen=True)
class World:
    bounds: np.ndarray  # (6,) [xmin, xmax, ymin, ymax, zmin, zmax] m
    blocks: np.ndarray  # (N, 6) same layout, one row per axis-aligned box
    colors: tuple = ()
    start: np.ndarray | None = None  # (3,) m
    goal: np.ndarray | None = None  # (3,) m
    resolution: np.ndarray | None = None  # (3,) m
    margin: float | None = None  # m
    expected_path_length: float | None = None  # m (may be inf)
    timeout: float | None = None  # s
    source: str = "<memory>"
    warnings: tuple[str, ...] = field(default_factory=tuple)

    @staticmethod
    def empty(bounds=(-5.0, 5.0, -5.0, 5.0, 0.0, 4.0)) -> World:
        return World(bounds=np.asarray(bounds, float), blocks=np.zeros((0, 6)), source="<empty>")

    def contains(self, points: np.ndarray) -> np.ndarray:
        """True where points (..., 3) lie inside the bounds (closed box)."""
        p = np.asarray(points, float)
        lo, hi = self.bounds[0::2], self.bounds[1::2]
        return np.all((p >= lo) & (p <= hi), axis=-1)

    def distance_to_blocks(self, points: np.ndarray) -> np.ndarray:
        """Euclidean distance (m) from each point (..., 3) to the nearest block surface.

        Zero inside a block; +inf when the world has no blocks.
        """
        p = np.asarray(points, float)
        if len(self.blocks) == 0:
            return np.full(p.shape[:-1], np.inf)
        lo = self.blocks[:, 0::2]
        hi = self.blocks[:, 1::2]
        q = p[..., None, :]
        gap = np.maximum(np.maximum(lo - q, q - hi), 0.0)
        return np.sqrt((gap**2).sum(-1)).min(-1)

    def support_height(self, point) -> float:
        """Height (m) of the surface a vehicle at `point` would land on: the floor (bounds zmin) or the
        highest block top whose footprint holds (x, y) and that lies at or below z (a landing pad).

        In Python floats over the blocks' rows: the mission asks this every control tick while landing, and
        numpy's masks over a few blocks cost ~10 us a call where this loop costs ~1.6 (float64 either way,
        so the same comparisons and the same result)."""
        x, y, z = map(float, point)
        support = float(self.bounds[4])
        top_limit = z + 1e-9
        for x_min, x_max, y_min, y_max, _, top in self._block_rows:
            if x_min <= x <= x_max and y_min <= y <= y_max and top <= top_limit and top > support:
                support = top
        return support

    @cached_property
    def _block_rows(self) -> tuple[tuple[float, ...], ...]:
        """The blocks as rows of Python floats (support_height); cached on first use (frozen: by __dict__)."""
        return tuple(tuple(row) for row in self.blocks.tolist())

    def inside_block(self, points: np.ndarray) -> np.ndarray:
        return self.distance_to_blocks(points) <= 0.0

    def obstacle_clearance(self, points: np.ndarray, pads_allowed=False) -> tuple[np.ndarray, np.ndarray]:
        """(distance m, obstacle) from each point (N, 3) to the nearest obstacle: a block (its index) or a
        wall or the ceiling of the bounds (-1). The floor is a landing surface, not an obstacle; where
        pads_allowed is true (a scalar or one flag per point: taking off, landing), a block right below the
        point (footprint under it, top at or below it: a landing pad) is not one either."""
        p = np.asarray(points, float).reshape(-1, 3)
        lo, hi = self.bounds[0::2], self.bounds[1::2]
        walls = np.column_stack([p[:, 0] - lo[0], hi[0] - p[:, 0], p[:, 1] - lo[1], hi[1] - p[:, 1],
                                 hi[2] - p[:, 2]]).min(axis=1)
        distance, index = walls, np.full(len(p), -1)
        if len(self.blocks):
            b_lo, b_hi = self.blocks[None, :, 0::2], self.blocks[None, :, 1::2]
            q = p[:, None, :]
            gaps = np.sqrt((np.maximum(np.maximum(b_lo - q, q - b_hi), 0.0) ** 2).sum(-1))
            pad = ((b_lo[..., 0] <= q[..., 0]) & (q[..., 0] <= b_hi[..., 0]) & (b_lo[..., 1] <= q[..., 1])
                   & (q[..., 1] <= b_hi[..., 1]) & (b_hi[..., 2] <= q[..., 2] + RESTING_TOLERANCE_M))
            allowed = np.broadcast_to(np.asarray(pads_allowed, bool).reshape(-1, 1), pad.shape)
            gaps = np.where(pad & allowed, np.inf, gaps)
            nearest = gaps.argmin(axis=1)
            block_distance = gaps[np.arange(len(p)), nearest]
            closer = block_distance < distance
            distance = np.where(closer, block_distance, distance)
            index = np.where(closer, nearest, index)
        return distance, index

    def nudged_inside(self, point, radius_m: float) -> np.ndarray:
        """The point moved inward so that it is at least radius_m inside every face of the bounds (the floor
        included); unchanged when it already is."""
        lo, hi = self.bounds[0::2] + radius_m, self.bounds[1::2] - radius_m
        return np.minimum(np.maximum(np.asarray(point, float), lo), hi)


def load_world(path: str | Path) -> World:
    """Read and validate a world file; raise WorldError("FILE: problem") on any defect."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as err:
        raise WorldError(f"{path}: cannot read world file ({err.strerror})") from None
    try:
        data = json.loads(text)  # accepts the bare token Infinity, as the course's Python json does
    except json.JSONDecodeError as err:
        raise WorldError(f"{path}: not valid JSON ({err.msg} at line {err.lineno} column {err.colno})") from None
    return parse_world(data, source=str(path))


def parse_world(data: object, source: str = "<memory>") -> World:
    def fail(problem: str) -> WorldError:
        return WorldError(f"{source}: {problem}")

    if not isinstance(data, dict):
        raise fail("top level must be a JSON object")
    bounds_obj = data.get("bounds")
    if not isinstance(bounds_obj, dict) or "extents" not in bounds_obj:
        raise fail("missing bounds.extents")
    bounds = _extents(bounds_obj["extents"], "bounds.extents", fail)
    for axis, (lo, hi) in zip("xyz", bounds.reshape(3, 2), strict=True):
        if not lo < hi:
            raise fail(f"bounds.extents: {axis} range is inverted or empty ({lo} .. {hi})")

    warnings: list[str] = []
    blocks_obj = data.get("blocks", [])
    if not isinstance(blocks_obj, list):
        raise fail("blocks must be a list")
    rows, colors = [], []
    for i, block in enumerate(blocks_obj):
        if not isinstance(block, dict) or "extents" not in block:
            raise fail(f"blocks[{i}]: missing extents")
        ext = _extents(block["extents"], f"blocks[{i}].extents", fail)
        for axis, (lo, hi) in zip("xyz", ext.reshape(3, 2), strict=True):
            if lo > hi:
                # Several course lab mazes list a thin wall with min and max swapped; the wall is real,
                # so it is read as the box it describes (never silently dropped) and the user is told.
                warnings.append(f"{source}: blocks[{i}].extents {axis} range inverted ({lo} > {hi}); "
                                f"read as {hi} .. {lo}")
        rows.append(np.concatenate([np.sort(pair) for pair in ext.reshape(3, 2)]))
        colors.append(block.get("color"))
    blocks = np.array(rows, float).reshape(-1, 6)

    world = World(bounds=bounds, blocks=blocks, colors=tuple(colors), source=source)
    start = _point(data, "start", fail)
    goal = _point(data, "goal", fail)
    for name, point in (("start", start), ("goal", goal)):
        if point is None:
            continue
        if not world.contains(point):
            raise fail(f"{name} {point.tolist()} is outside the bounds")
        if len(blocks) and world.inside_block(point):
            raise fail(f"{name} {point.tolist()} is inside a block")
    resolution = None
    if "resolution" in data:
        resolution = _resolution(data["resolution"], fail)
    margin = _optional_number(data, "margin", fail, minimum=0.0)
    epl = _optional_number(data, "expected_path_length", fail, allow_inf=True, minimum=0.0)
    timeout = _optional_number(data, "timeout", fail, minimum=0.0)
    return World(
        bounds=bounds, blocks=blocks, colors=tuple(colors), start=start, goal=goal, resolution=resolution,
        margin=margin, expected_path_length=epl, timeout=timeout, source=source, warnings=tuple(warnings),
    )


def _number(value: object, where: str, fail, allow_inf: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise fail(f"{where}: expected a number, got {json.dumps(value)[:40]}")
    x = float(value)
    if math.isnan(x) or (math.isinf(x) and not allow_inf):
        raise fail(f"{where}: {x} is not a finite number")
    return x


def _extents(value: object, where: str, fail) -> np.ndarray:
    if not isinstance(value, list) or len(value) != 6:
        raise fail(f"{where}: expected 6 numbers [xmin, xmax, ymin, ymax, zmin, zmax]")
    return np.array([_number(v, f"{where}[{i}]", fail) for i, v in enumerate(value)])


def _point(data: dict, key: str, fail) -> np.ndarray | None:
    if key not in data:
        return None
    value = data[key]
    if not isinstance(value, list) or len(value) != 3:
        raise fail(f"{key}: expected 3 numbers [x, y, z]")
    return np.array([_number(v, f"{key}[{i}]", fail) for i, v in enumerate(value)])


def _resolution(value: object, fail) -> np.ndarray:
    values = value if isinstance(value, list) else [value]
    if len(values) not in (1, 3):
        raise fail("resolution: expected one number or 3 numbers")
    res = np.array([_number(v, f"resolution[{i}]", fail) for i, v in enumerate(values)])
    if np.any(res <= 0):
        raise fail("resolution: must be positive")
    return np.broadcast_to(res, (3,)).copy()


def _optional_number(data: dict, key: str, fail, allow_inf: bool = False, minimum: float | None = None):
    if key not in data:
        return None
    x = _number(data[key], key, fail, allow_inf=allow_inf)
    if minimum is not None and x < minimum:
        raise fail(f"{key}: must be >= {minimum}")
    return x
