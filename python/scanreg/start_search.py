"""Search a 2D start's stated uncertainty before the local solve.

ICP converges to the minimum of the basin its start is in: from within about half a gate of
the truth. A start whose own stated uncertainty (``init_covariance``, e.g. a wheel step's
noise model) reaches well beyond that lands wherever its error puts it. On consecutive scans
of the 13 Radish logs started from simulated wheels (``benchmarks/relation_pairs.py --logs
radish-...``: a 1 m step starts ~2.5° off) the default solve ended 0.15–0.5 m from GMapping's
pose on 15 Edmonton and 19 Örebro pairs where a correlative search of the step's window found
the place; OpenKarto's matcher (slam_toolbox's), which searches a fixed ±0.3 m / ±20° window
around every start, was wrong on 7 and 0.

So when the start's 3σ reaches beyond half the gate — in translation, or in heading times the
source's RMS radius — that window (capped at one gate and :data:`MAX_TURN`) is searched first
by correlative branch and bound (:func:`scanreg.match_correlative`) on a grid of a tenth of
the gate, its candidates penalised by the stated covariance as Karto penalises its own, and
the local solve starts from the answer. A start whose window lies inside the basin costs
nothing more. The verdict still measures the result's motion from the caller's ``init``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ._validate import FloatArray, as_covariance, as_points
from .correlative import CorrelativeGrid, match_correlative
from .transform import SE2

#: The window's half-width in standard deviations of the stated covariance.
WINDOW_SIGMAS = 3.0
#: Search when the window reaches beyond this fraction of the gate (the solve's basin).
BASIN_FRACTION = 0.5
#: Grid cells (and translation steps) as a fraction of the gate.
CELL_FRACTION = 0.1
#: The window is capped at one gate in translation and this in heading: a start known no
#: better than that calls for global registration, not a local one.
MAX_TURN = math.radians(30.0)


def search_window(
    prior: FloatArray, source: FloatArray, gate: float
) -> tuple[float, float, float] | None:
    """The window ``(dx, dy, dθ)`` to search around a start with covariance ``prior``
    (``[x, y, θ]`` over the tangent), or ``None`` when it lies inside the solve's basin (or the
    gate is infinite: no basin to speak of). Bad input is refused naming the argument."""
    prior = as_covariance(prior, "prior", 3)
    source = as_points(source, "source", dim=2)
    gate = float(gate)
    if not gate > 0.0:
        raise ValueError(f"gate: must be > 0 (inf for no limit), got {gate!r}")
    return _search_window(prior, source, gate)


def _search_window(
    prior: FloatArray, source: FloatArray, gate: float
) -> tuple[float, float, float] | None:
    # Inputs checked by the caller (register checked them once: this runs on every 2D call
    # with a stated covariance).
    if not math.isfinite(gate):
        return None
    sigma = np.sqrt(np.clip(np.diag(prior), 0.0, None))
    reach = WINDOW_SIGMAS * float(max(sigma[0], sigma[1]))
    turn = WINDOW_SIGMAS * float(sigma[2])
    radius = float(np.sqrt((source**2).sum(axis=1).mean()))
    if max(reach, turn * radius) < BASIN_FRACTION * gate:
        return None
    reach = min(reach, gate)
    return (reach, reach, min(turn, MAX_TURN))


def searched_start(
    source: FloatArray,
    grid_of: Any,
    start: SE2,
    prior: FloatArray,
    gate: float,
) -> SE2 | None:
    """The best pose of ``start``'s stated window (:func:`search_window`), penalised by
    ``prior``; ``None`` when the window needs no search or its best lies on its edge.
    ``grid_of(resolution)``: the target's
    :class:`~scanreg.CorrelativeGrid` at that resolution (kept by a prepared target)."""
    if not isinstance(start, SE2):
        raise TypeError(f"start: expected an SE2, got {type(start).__name__}")
    window = search_window(prior, source, gate)
    return None if window is None else _search(source, grid_of, start, prior, gate, window)


def _searched_start(
    source: FloatArray, grid_of: Any, start: SE2, prior: FloatArray, gate: float
) -> SE2 | None:
    """:func:`searched_start` on inputs :func:`scanreg.register` has checked."""
    window = _search_window(prior, source, gate)
    return None if window is None else _search(source, grid_of, start, prior, gate, window)


def _search(
    source: FloatArray,
    grid_of: Any,
    start: SE2,
    prior: FloatArray,
    gate: float,
    window: tuple[float, float, float],
) -> SE2 | None:
    grid: CorrelativeGrid = grid_of(CELL_FRACTION * gate)
    found = match_correlative(source, grid, init=start, window=window, init_covariance=prior)
    # An optimum on the window's edge is no answer: the place may lie beyond it, or the
    # scan leaves that direction open (a corridor's axis) and the edge won a flat tie.
    return None if found.at_window_edge else found.pose
