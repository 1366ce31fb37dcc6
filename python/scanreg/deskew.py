"""Motion compensation ("deskew") of a sweep from per-point timestamps.

A spinning LiDAR (or a slow 2D laser) measures each point from the pose the sensor has at that
point's time; while the vehicle moves, a sweep is smeared by up to ``speed × sweep duration``.
``deskew`` re-expresses every point in the sensor frame at one reference time, assuming a
constant body twist over the sweep (the usual constant-velocity model):

    T_ref_t = exp((t - t_ref) · ξ),    p_ref = T_ref_t · p_t

``ξ`` is translation first and in the sensor frame (``[vx, vy, ω]`` in 2D,
``[vx, vy, vz, ωx, ωy, ωz]`` in 3D), per second — the right-perturbation tangent of
:mod:`scanreg.transform` divided by time. :func:`velocity_from_motion` turns a relative pose
over an interval (e.g. the previous frame's odometry) into ``ξ``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from . import _core
from ._validate import FloatArray, as_matrix, as_points
from .transform import SE2, SE3

REFERENCES = ("start", "middle", "end")


def velocity_from_motion(motion: SE2 | SE3, duration: float) -> FloatArray:
    """Constant body twist that moves the sensor by ``motion`` (``T_start_end``) in ``duration``
    seconds: ``ξ = log(motion) / duration``."""
    if not isinstance(motion, SE2 | SE3):
        raise TypeError(f"motion: expected SE2 or SE3, got {type(motion).__name__}")
    d = float(duration)
    if not np.isfinite(d) or d <= 0:
        raise ValueError(f"duration: must be finite and > 0, got {duration}")
    out: FloatArray = motion.log() / d
    return out


def deskew(
    points: Any,
    timestamps: Any,
    velocity: Any,
    *,
    reference_time: float | str = "start",
) -> FloatArray:
    """Express each point in the sensor frame at ``reference_time``.

    Parameters
    ----------
    points
        ``(N, 2)`` or ``(N, 3)`` float64: each point in the sensor frame at its own time.
    timestamps
        ``(N,)`` float64 seconds, any clock (absolute or relative to the sweep).
    velocity
        Body twist ``ξ`` (3 values in 2D, 6 in 3D; m/s and rad/s, translation first).
    reference_time
        Seconds on the same clock as ``timestamps``, or ``"start"``/``"middle"``/``"end"`` of
        the sweep (the smallest/mean of extremes/largest timestamp). KISS-ICP deskews to the
        sweep's middle; scanreg's default is the start, where the simulator's ground-truth pose
        is. Choose the time your pose estimate refers to.

    Returns
    -------
    ``(N, D)`` float64, a new array; the input is not modified.
    """
    pts = as_points(points, "points")
    n, dim = pts.shape
    times = as_matrix(timestamps, "timestamps", (n,))
    twist = as_matrix(velocity, "velocity", (3 if dim == 2 else 6,))
    if isinstance(reference_time, str):
        if reference_time not in REFERENCES:
            raise ValueError(
                f"reference_time: expected seconds or one of {', '.join(REFERENCES)}, "
                f"got {reference_time!r}"
            )
        lo, hi = float(times.min()), float(times.max())
        t_ref = {"start": lo, "middle": 0.5 * (lo + hi), "end": hi}[reference_time]
    else:
        t_ref = float(reference_time)
        if not np.isfinite(t_ref):
            raise ValueError(f"reference_time: must be finite, got {reference_time}")
    return _core.deskew(pts, times, twist, t_ref)
