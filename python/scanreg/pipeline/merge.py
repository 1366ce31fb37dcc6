"""Merge two maps made separately (2D or 3D), in frames that have nothing to do with each
other.

:func:`merge_maps` joins map ``b``'s sessions, already mapped, to map ``a``
(:func:`~scanreg.pipeline.join.join_sessions`, the step ``extend`` uses after mapping its
run). 2D: nodes spread over ``b`` are searched for in ``a`` by the global search until one is
placed, every node of ``b`` is matched against the submap of its nearest node of ``a``. 3D:
every node of ``b`` is looked up in ``a`` by place recognition and matched from
:func:`scanreg.register_global`'s pose (:mod:`~scanreg.pipeline.join3d`). Then, both: the
inter-session loops that agree with each other close one optimized graph in ``a``'s frame.
``a``'s nodes keep their ids; ``b``'s follow. Two maps that no agreeing loops join (other
buildings, or no shared ground) are refused with the reason: nothing that pretends to be one
map is made.

>>> merged, report = merge_maps(SavedMap.load("a/"), SavedMap.load("b/"))
>>> merged.save("m/")
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..saved_map import SavedMap
from .join import JoinReport, check_joinable, join_sessions
from .mapping import MappingConfig
from .mapping3d import MappingConfig3D


def _spread(count: int, tries: int) -> list[int]:
    """``tries`` node ids spread evenly over ``0..count-1`` (the first included)."""
    picks = np.linspace(0, count - 1, min(tries, count)).round().astype(int)
    return list(dict.fromkeys(int(k) for k in picks))


def _distinct_sessions(a: SavedMap, b: SavedMap) -> SavedMap:
    """``b`` with any session name ``a`` also has made distinct (``name#2``, ...)."""
    taken = set(a.sessions)
    names = []
    for name in b.sessions:
        unique, k = name, 2
        while unique in taken:
            unique, k = f"{name}#{k}", k + 1
        taken.add(unique)
        names.append(unique)
    return dataclasses.replace(b, sessions=tuple(names))


def merge_maps(
    a: SavedMap,
    b: SavedMap,
    *,
    config: MappingConfig | MappingConfig3D | None = None,
    locate_tries: int = 20,
    max_distance: float = 2.0,
    prior_sigma: tuple[float, float] = (0.3, math.radians(5.0)),
    window: tuple[float, float] = (1.0, math.radians(15.0)),
    min_loops: int = 2,
) -> tuple[SavedMap, JoinReport]:
    """Maps ``a`` and ``b`` (both 2D or both 3D, format 2, any frames) as one map in ``a``'s
    frame (module docstring): returns it (``a``'s sessions, then ``b``'s; a name both use
    gets ``#2``) and how they were joined. Raises ValueError starting ``merge:`` and saying
    why when the maps have no reliable overlap.

    ``locate_tries`` (2D): how many of ``b``'s nodes, spread over its whole run, the global
    search tries (``b`` need not start inside ``a``; 3D looks every node up);
    ``max_distance``, ``prior_sigma``, ``window``, ``min_loops``: as
    :func:`~scanreg.pipeline.join.join_sessions` takes them (``min_loops`` agreeing
    inter-session loops are needed to merge). ``config``: the mapping settings
    (loop matching, submaps) of the maps' dimension, :class:`MappingConfig`'s or
    :class:`MappingConfig3D`'s defaults if ``None``."""
    check_joinable(a, "a")
    check_joinable(b, "b")
    if a.dim != b.dim:
        raise ValueError(f"merge: a is a {a.dim}D map and b a {b.dim}D map; they cannot merge")
    if isinstance(locate_tries, bool) or not isinstance(locate_tries, int) or locate_tries < 1:
        raise ValueError(f"locate_tries: expected an int >= 1, got {locate_tries!r}")
    if a.num_nodes == 0 or b.num_nodes == 0:
        raise ValueError("merge: a map without nodes cannot be merged")
    return join_sessions(
        a,
        _distinct_sessions(a, b),
        config=config,
        locate_nodes=_spread(b.num_nodes, locate_tries),
        max_distance=max_distance,
        prior_sigma=prior_sigma,
        window=window,
        min_loops=min_loops,
        verb="merge",
    )


__all__ = ["merge_maps"]
