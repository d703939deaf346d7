"""Voxel occupancy grid of a world, and exact line-of-sight checks against its blocks.

Takes in: a `World` (bounds and axis-aligned blocks, ENU, m), a voxel size per axis (m) and a safety
margin (m).
Gives out: an `OccupancyGrid` - a boolean voxel array over the bounds, index <-> metric conversion
(voxel centres) and `segment_is_free`, a test of the continuous segment against the blocks inflated by
the margin.

Geometry (as the course's OccupancyMap, but exact and vectorised):
- The grid starts at the lower bounds corner; voxel (i, j, k) is the box
  [o + (i, j, k) * r, o + (i + 1, j + 1, k + 1) * r] with o the origin and r the resolution, and there are
  ceil(extent / r) voxels per axis, so the last voxel may stick out of the upper bound.
- A voxel is occupied when the distance between its box and any block's box is <= margin:
  d = |max(0, lo_b - hi_v, lo_v - hi_b)| (per-axis gaps, Euclidean norm). No sampling.
- The bounds are walls with the same margin: a voxel whose centre lies closer than the margin to a face
  of the bounds (or outside them) is occupied, so every path point stays inside the bounds minus the
  margin. (The course's OccupancyMap keeps no margin at the bounds, so at a coarse resolution a course
  path can touch them: a vehicle there is half outside the room.)
Because a free voxel's whole box is farther than the margin from every block, and the segment between
two 26-neighbour voxel centres stays inside the union of their two boxes, a path through free voxel
centres keeps clearance > margin everywhere along it, not only at its points.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from model.world import World

# Relative tolerance on ceil(extent / resolution): 5.7 / 0.05 is 114.00000000000001 in floating point
# and must still give 114 voxels, not 115.
_CEIL_TOLERANCE = 1e-9


@dataclass(frozen=True)
class OccupancyGrid:
    world: World
    resolution_m: np.ndarray  # (3,) voxel size per axis
    margin_m: float
    origin_m: np.ndarray  # (3,) lower bounds corner = negative corner of voxel (0, 0, 0)
    occupied: np.ndarray  # (nx, ny, nz) bool

    @staticmethod
    def from_world(world: World, resolution_m, margin_m: float) -> OccupancyGrid:
        """Voxelise `world` at `resolution_m` (scalar or (3,)), inflating blocks by `margin_m`."""
        res = np.broadcast_to(np.asarray(resolution_m, float), (3,)).copy()
        if not np.all(np.isfinite(res)) or np.any(res <= 0):
            raise ValueError(f"resolution must be positive and finite, got {res.tolist()}")
        if not np.isfinite(margin_m) or margin_m < 0:
            raise ValueError(f"margin must be >= 0 and finite, got {margin_m}")
        lo, hi = world.bounds[0::2], world.bounds[1::2]
        shape = np.ceil((hi - lo) / res * (1 - _CEIL_TOLERANCE)).astype(int)
        shape = np.maximum(shape, 1)
        axes_lo = [lo[a] + np.arange(shape[a]) * res[a] for a in range(3)]  # voxel negative corners
        occupied = np.zeros(tuple(shape), bool)
        for block in world.blocks:
            _mark_block(occupied, axes_lo, res, block, float(margin_m))
        for a in range(3):  # voxels whose centre is within the margin of a face of the bounds, or beyond it
            centres = axes_lo[a] + res[a] / 2
            near_wall = (centres < lo[a] + margin_m) | (centres > hi[a] - margin_m)
            index = [slice(None)] * 3
            index[a] = near_wall
            occupied[tuple(index)] = True
        return OccupancyGrid(
            world=world, resolution_m=res, margin_m=float(margin_m), origin_m=lo.copy(), occupied=occupied
        )

    @property
    def shape(self) -> tuple[int, int, int]:
        return self.occupied.shape

    def index_to_metric_center(self, index) -> np.ndarray:
        """Centres (..., 3) m of the voxels with integer indices (..., 3)."""
        return self.origin_m + (np.asarray(index, float) + 0.5) * self.resolution_m

    def metric_to_index(self, points) -> np.ndarray:
        """Integer indices (..., 3) of the voxels containing points (..., 3).

        Points on the upper bound belong to the last voxel; points outside the bounds get indices
        outside the grid (check with `is_valid_index`).
        """
        p = np.asarray(points, float)
        index = np.floor((p - self.origin_m) / self.resolution_m).astype(int)
        on_upper = self.world.contains(p)[..., None] & (index == np.array(self.shape))
        return np.where(on_upper, index - 1, index)

    def is_valid_index(self, index) -> np.ndarray:
        i = np.asarray(index)
        return np.all((i >= 0) & (i < np.array(self.shape)), axis=-1)

    def is_occupied_index(self, index) -> np.ndarray:
        """True where a voxel is occupied or outside the grid (the course's convention)."""
        i = np.asarray(index)
        valid = self.is_valid_index(i)
        clipped = np.clip(i, 0, np.array(self.shape) - 1)
        return ~valid | self.occupied[clipped[..., 0], clipped[..., 1], clipped[..., 2]]

    def segment_is_free(self, p0, p1, margin_m: float | None = None) -> bool:
        """True when the whole segment p0-p1 lies in the bounds and farther than the margin from all blocks.

        Exact: the minimum distance between the continuous segment and each block box is found in
        closed form (see `segment_box_distance`), so a segment passing within the margin is never free.
        """
        margin = self.margin_m if margin_m is None else margin_m
        return bool(
            segments_are_free(self.world, np.asarray(p0, float)[None], np.asarray(p1, float)[None], margin)[0]
        )


def _mark_block(
    occupied: np.ndarray, axes_lo: list[np.ndarray], res: np.ndarray, block: np.ndarray, margin: float
) -> None:
    """Mark the voxels whose box is within `margin` of one block box, in place."""
    gaps, ranges = [], []
    for a in range(3):
        v_lo = axes_lo[a]
        v_hi = v_lo + res[a]
        gap = np.maximum(np.maximum(block[2 * a] - v_hi, v_lo - block[2 * a + 1]), 0.0)
        near = np.flatnonzero(gap <= margin)
        if near.size == 0:
            return
        start, stop = near[0], near[-1] + 1  # the near voxels along one axis are contiguous
        gaps.append(gap[start:stop])
        ranges.append(slice(start, stop))
    gx, gy, gz = gaps
    d2 = gx[:, None, None] ** 2 + gy[None, :, None] ** 2 + gz[None, None, :] ** 2
    occupied[tuple(ranges)] |= d2 <= margin * margin


def segment_box_distance(p0: np.ndarray, p1: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Exact minimum distance (m) between segments and axis-aligned boxes, all pairs.

    p0, p1: (S, 3) segment ends; boxes: (N, 6) [xmin, xmax, ymin, ymax, zmin, zmax]. Returns (S, N).
    """
    p0 = np.asarray(p0, float).reshape(-1, 3)
    p1 = np.asarray(p1, float).reshape(-1, 3)
    boxes = np.asarray(boxes, float).reshape(-1, 6)
    s, n = len(p0), len(boxes)
    pairs_s, pairs_b = np.repeat(np.arange(s), n), np.tile(np.arange(n), s)
    return _pair_distance(p0[pairs_s], p1[pairs_s], boxes[pairs_b]).reshape(s, n)


def _pair_distance(p0: np.ndarray, p1: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Exact minimum distance (K,) between segment k (p0[k]-p1[k]) and box k (boxes[k]).

    The squared distance f(t) = sum_a max(0, lo_a - x_a(t), x_a(t) - hi_a)^2 along x(t) = p0 + t (p1 - p0)
    is convex and piecewise quadratic in t, with breakpoints where x_a(t) crosses lo_a or hi_a. Its
    minimum over [0, 1] is at a breakpoint, an end, or the stationary point of one piece
    t* = -sum(c_a d_a) / sum(d_a^2) over the axes active on that piece (c_a = p0_a - bound_a).
    """
    d = p1 - p0
    lo, hi = boxes[:, 0::2], boxes[:, 1::2]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):  # axis-parallel: no crossing
        crossings = np.concatenate([(lo - p0) / d, (hi - p0) / d], axis=-1)  # (K, 6)
    crossings = np.nan_to_num(crossings, nan=0.0, posinf=0.0, neginf=0.0)
    k = len(p0)
    t = np.concatenate([np.zeros((k, 1)), np.ones((k, 1)), np.clip(crossings, 0.0, 1.0)], axis=-1)
    t.sort(axis=-1)  # (K, 8)
    a, b = t[:, :-1], t[:, 1:]
    p0e, de, loe, hie = p0[:, None, :], d[:, None, :], lo[:, None, :], hi[:, None, :]
    mid = p0e + ((a + b) / 2)[..., None] * de  # (K, 7, 3): the active axes are fixed on each piece
    bound = np.where(mid < loe, loe, hie)
    active = (mid < loe) | (mid > hie)
    c = np.where(active, p0e - bound, 0.0)
    dd = np.where(active, de, 0.0)
    num = (c * dd).sum(-1)
    den = (dd * dd).sum(-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        stationary = np.where(den > 0, -num / den, a)
    candidates = np.concatenate([t, np.clip(stationary, a, b)], axis=-1)  # (K, 15)
    x = p0e + candidates[..., None] * de
    gap = np.maximum(np.maximum(loe - x, x - hie), 0.0)
    return np.sqrt((gap * gap).sum(-1).min(-1))


def segments_clearance(world: World, p0: np.ndarray, p1: np.ndarray, cutoff_m: float = np.inf) -> np.ndarray:
    """Minimum distance (m) from each segment (S,) to the nearest block; +inf without blocks.

    Pairs whose lower bound (the distance from the block to the segment's bounding box) exceeds
    `cutoff_m` are not computed exactly and keep that lower bound: enough to decide "farther than the
    cutoff", and it saves most of the work for short segments.
    """
    p0 = np.asarray(p0, float).reshape(-1, 3)
    p1 = np.asarray(p1, float).reshape(-1, 3)
    if len(world.blocks) == 0:
        return np.full(len(p0), np.inf)
    boxes = world.blocks
    seg_lo, seg_hi = np.minimum(p0, p1)[:, None, :], np.maximum(p0, p1)[:, None, :]
    gap = np.maximum(np.maximum(boxes[None, :, 0::2] - seg_hi, seg_lo - boxes[None, :, 1::2]), 0.0)
    distance = np.sqrt((gap * gap).sum(-1))  # (S, N), a lower bound of the segment-box distance
    near_s, near_b = np.nonzero(distance <= cutoff_m)
    if near_s.size:
        distance[near_s, near_b] = _pair_distance(p0[near_s], p1[near_s], boxes[near_b])
    return distance.min(-1)


def segments_are_free(world: World, p0: np.ndarray, p1: np.ndarray, margin_m: float) -> np.ndarray:
    """(S,) True where a segment stays in the bounds (both ends inside: the bounds are convex) and its
    clearance to every block exceeds the margin."""
    p0 = np.asarray(p0, float).reshape(-1, 3)
    p1 = np.asarray(p1, float).reshape(-1, 3)
    inside = world.contains(p0) & world.contains(p1)
    return inside & (segments_clearance(world, p0, p1, cutoff_m=margin_m) > margin_m)
