"""The path between two nodes of a pose graph, through the loops it has closed.

A loop edge measures two nodes' relative pose directly: the drift between two nodes builds
up only along the shortest route from one to the other over the chain of odometry edges
(each as long as the path it covers) and the accepted loops (each as long as the caller
counts the error a loop may have, in metres of path).
Atlas's Dijkstra projection (Bosse et al. 2004) carries the uncertainty between two places
the same way; the mapping bounds a held loop's correction by it
(:class:`~scanreg.pipeline.Mapper`).
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Mapping, Sequence


def path_between(
    travel: Sequence[float],
    links: Mapping[int, Sequence[int]],
    start: int,
    goal: int,
    *,
    hop: float = 0.0,
    limit: float = math.inf,
) -> float:
    """Metres of path from node ``start`` to node ``goal``: along the chain, node ``k`` to
    ``k ± 1`` costs ``|travel[k ± 1] − travel[k]|`` (``travel``: the path length at each node,
    non-decreasing); a loop, ``links[k]`` (the nodes ``k`` has an accepted loop with), costs
    ``hop`` (m). Dijkstra from ``start``; ``limit`` when the route is longer than that (the
    search stops there)."""
    n = len(travel)
    for name, value in (("start", start), ("goal", goal)):
        if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < n:
            raise ValueError(f"{name}: expected a node in [0, {n}), got {value!r}")
    if not (math.isfinite(hop) and hop >= 0):
        raise ValueError(f"hop: must be finite and >= 0, got {hop!r}")
    if not limit >= 0:
        raise ValueError(f"limit: must be >= 0, got {limit!r}")
    best = {start: 0.0}
    queue = [(0.0, start)]
    while queue:
        d, k = heapq.heappop(queue)
        if k == goal:
            return min(d, limit)
        if d > best.get(k, math.inf) or d >= limit:
            continue
        steps = [(j, abs(travel[j] - travel[k])) for j in (k - 1, k + 1) if 0 <= j < n]
        steps += [(j, hop) for j in links.get(k, ())]
        for j, cost in steps:
            e = d + cost
            if e < best.get(j, math.inf) and e < limit:
                best[j] = e
                heapq.heappush(queue, (e, j))
    return limit
