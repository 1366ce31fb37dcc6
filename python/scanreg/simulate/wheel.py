"""Simulated 2D wheel odometry: the true increments with the noise of a differential drive."""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence

import numpy as np

from ..transform import SE2


def wheel_odometry(truth: Sequence[SE2], seed: int | np.random.Generator = 0) -> list[SE2 | None]:
    """The motion between consecutive poses of ``truth`` as noisy wheels measure it: ``None``
    for the first pose, then each true increment ``exp(v + ε)`` with ``ε`` drawn per axis at
    σ = 5 % of the step along, 2 % across, and 5 % of the turn plus 1°/m of heading (a noisy
    differential drive; 1 mm, 1 mm and 1e-4 rad floors). ``seed``: an int or a
    ``numpy.random.Generator`` (drawn from in place)."""
    if any(not isinstance(p, SE2) for p in truth):
        raise TypeError("truth: expected a sequence of SE2 poses")
    rng = np.random.default_rng(seed)
    out: list[SE2 | None] = [None] if len(truth) else []
    for a, b in itertools.pairwise(truth):
        v = (a.inverse() @ b).log()
        sigma = np.array(
            [
                0.05 * abs(v[0]) + 1e-3,
                0.02 * abs(v[0]) + 1e-3,
                0.05 * abs(v[2]) + math.radians(1.0) * abs(v[0]) + 1e-4,
            ]
        )
        out.append(SE2.exp(v + rng.normal(0.0, 1.0, 3) * sigma))
    return out
