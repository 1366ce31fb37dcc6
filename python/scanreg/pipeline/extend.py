"""Extend a saved map (2D or 3D) with a new run: one graph over both sessions.

:func:`extend_map` takes a :class:`scanreg.SavedMap` (format 2: it keeps its nodes' scans
or clouds) and a new run mapped on its own (:func:`~scanreg.pipeline.run_mapping` or
:func:`~scanreg.pipeline.run_mapping_3d`, in its own frame), and joins them
(:func:`~scanreg.pipeline.join.join_sessions`): 2D, the new run's first node is located in
the saved map by the global search (the next nodes if the run starts outside the old map),
every new node is matched against the nearest old node's submap; 3D, the new nodes are looked
up by place recognition and global registration (:mod:`~scanreg.pipeline.join3d`); the
agreeing
inter-session loops close one graph in which the old nodes keep their ids. A new run that
fewer than ``min_loops`` agreeing matches place in the old map is refused: nothing is written
that would pretend to be one map. (:func:`~scanreg.pipeline.merge_maps` is the same join for
two maps both already made.)
"""

from __future__ import annotations

import math
from typing import Any

from ..saved_map import SavedMap
from .join import JoinReport, join_sessions
from .mapping import MappingConfig, MappingResult
from .mapping3d import MappingConfig3D


def extend_map(
    saved: SavedMap,
    result: MappingResult[Any] | SavedMap,
    *,
    session: str | None = None,
    config: MappingConfig | MappingConfig3D | None = None,
    locate_tries: int = 10,
    max_distance: float = 2.0,
    prior_sigma: tuple[float, float] = (0.3, math.radians(5.0)),
    window: tuple[float, float] = (1.0, math.radians(15.0)),
    min_loops: int = 2,
) -> tuple[SavedMap, JoinReport]:
    """``saved`` and the new run ``result`` as one map (module docstring): returns the joint
    :class:`~scanreg.SavedMap` (one more session) and how they were joined. ``result``: a
    :class:`~scanreg.pipeline.MappingResult` (named ``session``) or a saved map of format 2
    (its sessions kept).

    ``locate_tries`` (2D): the new run's first nodes the global search tries; ``max_distance``,
    ``prior_sigma``, ``window``, ``min_loops``: as :func:`~scanreg.pipeline.join.join_sessions`
    takes them (``min_loops`` agreeing inter-session loops are needed to join)."""
    if not isinstance(saved, SavedMap):
        raise TypeError(f"saved: expected a SavedMap, got {type(saved).__name__}")
    if isinstance(result, MappingResult):
        if session is None:
            raise ValueError("session: a new run's name is needed (e.g. its log's path)")
        new = SavedMap.from_result(result, session=session, resolution=_resolution(saved))
    elif isinstance(result, SavedMap):
        new = result
    else:
        raise TypeError(
            f"result: expected a MappingResult or SavedMap, got {type(result).__name__}"
        )
    if saved.dim != new.dim:
        raise ValueError(f"extend: a {saved.dim}D map cannot be extended with a {new.dim}D run")
    if isinstance(locate_tries, bool) or not isinstance(locate_tries, int) or locate_tries < 1:
        raise ValueError(f"locate_tries: expected an int >= 1, got {locate_tries!r}")
    return join_sessions(
        saved,
        new,
        config=config,
        locate_nodes=range(min(locate_tries, max(new.num_nodes, 1))),
        max_distance=max_distance,
        prior_sigma=prior_sigma,
        window=window,
        min_loops=min_loops,
        verb="extend",
    )


def _resolution(saved: SavedMap) -> float:
    return 0.05 if saved.grid is None else saved.grid.resolution


__all__ = ["extend_map"]
