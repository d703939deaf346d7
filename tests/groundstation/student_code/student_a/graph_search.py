from heapq import heappush, heappop

import numpy as np

from proj1_3.code.occupancy_map import OccupancyMap


def graph_search(world, resolution, margin, start, goal, astar):
    occ_map = OccupancyMap(world, resolution, margin)
    start_index = tuple(occ_map.metric_to_index(start))
    goal_index = tuple(occ_map.metric_to_index(goal))
    steps = [(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1) if (i, j, k) != (0, 0, 0)]
    res = np.array(occ_map.resolution)
    cost = {start_index: 0.0}
    parent = {}
    heap = [(0.0, start_index)]
    closed = set()
    nodes_expanded = 0
    while heap:
        _, node = heappop(heap)
        if node in closed:
            continue
        closed.add(node)
        nodes_expanded += 1
        if node == goal_index:
            break
        for step in steps:
            nxt = (node[0] + step[0], node[1] + step[1], node[2] + step[2])
            if not occ_map.is_valid_index(nxt) or occ_map.is_occupied_index(nxt):
                continue
            c = cost[node] + np.linalg.norm(np.array(step) * res)
            if c < cost.get(nxt, np.inf):
                cost[nxt] = c
                parent[nxt] = node
                h = np.linalg.norm((np.array(goal_index) - np.array(nxt)) * res) if astar else 0.0
                heappush(heap, (c + h, nxt))
    if goal_index not in closed:
        return None, nodes_expanded
    path = [goal]
    node = parent.get(goal_index)
    while node is not None and node != start_index:
        path.append(occ_map.index_to_metric_center(node))
        node = parent.get(node)
    path.append(start)
    return np.array(path[::-1]), nodes_expanded
