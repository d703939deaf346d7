"""Line-of-sight pruning of a dense grid path into sparse waypoints.

Takes in: a path (M, 3) m (typically A*'s, start first and goal last), the `World` and a margin (m).
Gives out: the indices (K,) of the points kept, increasing, always including the first and the last.

Greedy from the start: from the last kept point (the anchor), the next point is dropped while the anchor
sees the point after it - the continuous straight segment stays in the bounds and farther than the
margin from every block (exact segment-box distance, occupancy.segments_are_free). The first point the
anchor cannot see makes its predecessor the next anchor. Every segment of the pruned path is therefore
clear by more than the margin, except a segment that was already closer in the input path (e.g. a start
inside the margin), which is kept as it was.
"""

from __future__ import annotations

import numpy as np

from groundstation.planning.occupancy import segments_are_free
from model.world import World

# Visibility is tested from the anchor to this many following points at once, doubling each time the
# whole chunk is visible (A* paths in the lab mazes see 10-100 points ahead).
_FIRST_CHUNK = 16


def prune_waypoints(path_m: np.ndarray, world: World, margin_m: float) -> np.ndarray:
    """Indices of the points of `path_m` kept by greedy line-of-sight pruning at `margin_m`."""
    path = np.asarray(path_m, float).reshape(-1, 3)
    last = len(path) - 1
    if last <= 1:
        return np.arange(len(path))
    kept = [0]
    anchor = 0
    while anchor < last:
        anchor = _next_anchor(path, world, margin_m, anchor)
        kept.append(anchor)
    return np.array(kept)


def prune_path(path_m: np.ndarray, world: World, margin_m: float) -> np.ndarray:
    """The pruned waypoints (K, 3) m themselves."""
    path = np.asarray(path_m, float).reshape(-1, 3)
    return path[prune_waypoints(path, world, margin_m)]


def _next_anchor(path: np.ndarray, world: World, margin_m: float, anchor: int) -> int:
    """The point kept after `anchor`: the predecessor of the first point the anchor cannot see."""
    last = len(path) - 1
    first = anchor + 2  # the anchor's own successor is never dropped: it is what connects them
    chunk = _FIRST_CHUNK
    while first <= last:
        stop = min(first + chunk, last + 1)
        targets = path[first:stop]
        visible = segments_are_free(world, np.broadcast_to(path[anchor], targets.shape), targets, margin_m)
        if not visible.all():
            return first + int(np.argmin(visible)) - 1
        first, chunk = stop, chunk * 2
    return last
