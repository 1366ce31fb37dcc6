"""The wheel odometry at each laser scan's time, whatever file the run came from.

A 2D run records two streams: laser scans and wheel-odometry messages, each stamped by its own
clock and received in some order. Which odometry pose goes with a scan is decided here, once
for both sources (a CARMEN log: :func:`scanreg.pipeline.mapping.scan_odometry`; a LaserScan
bag: :func:`scanreg.pipeline.scan_source.scan_log`):

* each scan first has its *own* odometry: what the recorder paired with it (a CARMEN laser
  line's odometry fields: the last ``ODOM`` message the logger had received; in a bag, the
  last odometry message received before the scan), and how old that is (its *lag*);
* when the own poses are synchronous with the scans (:data:`STALE_ODOMETRY`) they are kept:
  the recorder paired them at the scan (Intel), whatever the stamps of a busy logger say;
* when they are stale (ACES: 0.08 s by median), the stream is interpolated at each scan's
  stamp less the laser's latency, measured on the run by :func:`measure_laser_latency`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence

import numpy as np

from .._validate import FloatArray
from ..io.laserscan_bag import interpolate_poses
from ..io.scan_log import ScanLog
from ..transform import SE2

#: A run's scans carry stale odometry when their own odometry is, by median, this much older
#: than the scans themselves (s): clock jitter between two messages logged together is a few
#: milliseconds (Intel: 0.3 ms).
STALE_ODOMETRY = 0.01


def odometry_at_scans(
    own: Sequence[SE2 | None],
    lags: Sequence[float],
    stamps: FloatArray,
    odom_stamps: FloatArray,
    odom_poses: FloatArray,
    points: Callable[[int], FloatArray],
    *,
    latency: float | None,
) -> tuple[list[SE2 | None], float | None]:
    """Each scan's wheel odometry ``T_odom_base`` and the latency applied (None: none was,
    the own poses are kept).

    ``own``: per scan the odometry its recorder paired with it (None: none); ``lags``: how
    much older than their scans those own poses are (s), for the scans where that is known;
    ``stamps``: the scans' times; ``odom_stamps`` / ``odom_poses``: the odometry messages
    (``[x, y, θ]`` rows) in the order they were recorded; ``points(k)``: scan ``k``'s returns
    (for the latency). When the own poses are stale (median lag over
    :data:`STALE_ODOMETRY`), the stream is interpolated (:func:`interpolate_poses`) at each
    scan's stamp less ``latency`` (``None``: :func:`measure_laser_latency`); a scan that no
    two messages at most 1 s apart bracket keeps its own pose.
    """
    out = list(own)
    if len(odom_stamps) < 2 or not out:
        return out, None
    if not lags or float(np.median(lags)) <= STALE_ODOMETRY:
        return out, None
    if latency is None:
        latency = measure_laser_latency(stamps, points, odom_stamps, odom_poses)
    shifted = interpolate_poses(odom_stamps, odom_poses, np.asarray(stamps) - latency)
    for k, (pose, at) in enumerate(zip(own, shifted, strict=True)):
        if pose is not None and at is not None:
            out[k] = at
    return out, latency


def settle_odometry(
    scans: ScanLog, *, latency: float | None = None, min_range: float = 0.1, max_range: float = 40.0
) -> ScanLog:
    """``scans`` with each scan's odometry paired as a CARMEN log's is (:func:`odometry_at_scans`)
    from its :attr:`~scanreg.io.ScanLog.odometry_stream` (a bag's messages as recorded), the
    stream then dropped; ``scans`` itself when it has none (a CARMEN log: already paired).

    A scan's own odometry is the last message the bag received before it (a CARMEN logger
    writes that into the laser line; the hospital log's bag: the message stamped with the
    scan), its lag the scan's stamp less that message's. ``latency`` (s; ``None``: measured
    with the returns in ``[min_range, max_range]``) is used only when the own odometry is
    stale, as for a log.
    """
    stream = scans.odometry_stream
    if stream is None:
        return scans
    order = np.argsort(stream.received, kind="stable")  # the order recorded
    t_odom, p_odom, received = stream.stamps[order], stream.poses[order], stream.received[order]
    at = np.array([s.logger_timestamp for s in scans.scans], dtype=np.float64)
    last = np.searchsorted(received, at, side="right") - 1
    own = [None if j < 0 else SE2.from_vector(p_odom[j]) for j in last]
    lags = [float(scans.stamps[k] - t_odom[j]) for k, j in enumerate(last) if j >= 0]
    odometry, applied = odometry_at_scans(
        own,
        lags,
        scans.stamps,
        t_odom,
        p_odom,
        lambda k: scans.points(k, min_range, max_range),
        latency=latency,
    )
    return dataclasses.replace(
        scans, odometry=tuple(odometry), odometry_stream=None, laser_latency=applied
    )


def measure_laser_latency(
    stamps: FloatArray,
    points: Callable[[int], FloatArray],
    odom_stamps: FloatArray,
    odom_poses: FloatArray,
    *,
    max_pairs: int = 400,
    max_latency: float = 0.3,
) -> float:
    """How long before its stamp a laser scan was taken, against an odometry stream (s, in
    ``[0, max_latency]``, 5 ms steps): the shift δ that makes the heading change between
    consecutive scans measured by the scans themselves (point-to-line registration of
    ``points(k + 1)`` to ``points(k)``) best agree with the stream's, interpolated at the
    scans' ``stamps`` less δ (median absolute difference). Only pairs over which the odometry
    turns more than 1° are used (up to ``max_pairs``, spread over the run): a shift changes
    nothing on a straight line. ``odom_stamps`` / ``odom_poses`` (``[x, y, θ]`` rows) in the
    order recorded. The relations of a benchmark play no part.

    A scan is sent after its sweep (a SICK LMS200 at 38.4 kBd needs about 0.1 s for a 180-beam
    scan): on ACES this gives 0.07 s. ``0.0`` when the run has too few turning pairs (fewer
    than 20), fewer than two odometry messages, or a stream whose stamps step backwards more
    than once in a hundred (Intel's busy logger: its stamps cannot time a turn).
    """
    from ..register import register
    from ..target import prepare

    stamps = np.asarray(stamps, dtype=np.float64)
    t_odom = np.asarray(odom_stamps, dtype=np.float64)
    p_odom = np.asarray(odom_poses, dtype=np.float64).reshape(-1, 3)
    if len(t_odom) < 2 or len(stamps) < 2:
        return 0.0
    if not (np.diff(t_odom) >= 0).mean() > 0.99:
        return 0.0
    heading = np.unwrap(p_odom[:, 2])

    def odom_turn(shift: float) -> FloatArray:
        h = np.interp(stamps - shift, t_odom, heading)
        turn: FloatArray = np.diff(h)
        return turn

    turning = np.flatnonzero((np.abs(odom_turn(0.0)) > math.radians(1.0)) & (np.diff(stamps) > 0))
    if len(turning) < 20:
        return 0.0
    pick = turning[np.linspace(0, len(turning) - 1, min(max_pairs, len(turning))).astype(int)]
    measured, used = [], []
    for k in pick:
        a, b = points(int(k)), points(int(k) + 1)
        if len(a) < 20 or len(b) < 20:
            continue
        init = SE2.from_vector([0.0, 0.0, float(odom_turn(0.0)[k])])
        res = register(
            b,
            prepare(a, normals=True),
            method="point_to_line",
            init=init,
            max_correspondence_distance=0.3,
            kernel="cauchy",
            # The scans' own turn: a refinement that prefers its start where the fit cannot
            # tell poses apart would lean towards the unshifted odometry the turn is compared
            # with (ACES: 0.07 -> 0.06 s read, the halves 0.08 / 0.07 -> 0.055 / 0.065 s).
            refine_in_basin=False,
        )
        if res.stop_reason == "converged":
            measured.append(res.pose.angle)
            used.append(k)
    if len(used) < 20:
        return 0.0
    m = np.asarray(measured)
    shifts = np.arange(0.0, max_latency + 1e-9, 0.005)
    cost = [float(np.median(np.abs(odom_turn(d)[used] - m))) for d in shifts]
    return float(shifts[int(np.argmin(cost))])


__all__ = ["STALE_ODOMETRY", "measure_laser_latency", "odometry_at_scans", "settle_odometry"]
