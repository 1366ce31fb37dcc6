"""2D loop closure by passes: the node's last metres of path matched against an earlier pass.

A revisit seen across open space (a scan facing an earlier pass from 10-30 m away, headings
110-170° apart) shares a tenth of its returns with the earlier pass: one scan scores 0.10-0.16
on it at the true pose, far below the single-scan search's floor, and a floor that low would
let look-alikes in. Many scans together do not score higher, but their best pose becomes one
of a kind: the last ``pass_path`` metres of the searching node's path, laid by the graph (the
graph's short legs are locally right whatever its drift), are matched against the candidate's
grown pass (:func:`~scanreg.pipeline.loops.wide_submap_span`) over the widest loop window, and
the match is kept only when no pose ``pass_rival_exclusion`` or more away scores
``pass_rival_ratio`` of its score (:func:`~scanreg.pipeline.loops.rival_search`) and the graph
agrees with it (χ²). Edmonton's view (scans 146-153 on the pass around scan 65): 0.18, nothing
outside 1.5 m at half of it, 0.04 m from GMapping's relation; the same pass searched 6 m or 60°
away from the truth: 0.04-0.10, a rival at 0.88-0.98 of it (benchmarks/README.md,
"radish_views.py").
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence

import numpy as np

from .._validate import FloatArray
from ..correlative import find_correlative
from ..preprocess import voxel_downsample
from ..register import register
from ..transform import SE2
from .loops import LoopMatch, LoopSettings, Submap2D, rival_search


def pass_points(
    node: int,
    points: Mapping[int, FloatArray],
    pose: Callable[[int], SE2],
    travel: Sequence[float],
    *,
    path: float,
    voxel_size: float,
) -> tuple[int, FloatArray]:
    """``(first, points)``: the nodes ``first … node`` whose path to ``node`` is at most
    ``path`` metres, their ``points`` laid in ``node``'s frame by ``pose(k)`` (the graph's),
    downsampled to ``voxel_size``; ``travel[k]``: the path length at node ``k``."""
    if not 0 <= node < len(travel):
        raise ValueError(f"node: {node} is not one of the {len(travel)} nodes")
    if not (math.isfinite(path) and path >= 0):
        raise ValueError(f"path: must be finite and >= 0, got {path!r}")
    first = node
    while first > 0 and travel[node] - travel[first - 1] <= path:
        first -= 1
    base = pose(node).inverse()
    laid = np.vstack([(base @ pose(k)).apply(points[k]) for k in range(first, node + 1)])
    if voxel_size > 0:
        laid = voxel_downsample(laid, voxel_size).points
    return first, np.ascontiguousarray(laid, dtype=np.float64)


def match_pass(
    points: FloatArray,
    node: int,
    submap: Submap2D,
    predicted: SE2,
    relative_covariance: FloatArray,
    settings: LoopSettings,
) -> LoopMatch:
    """Match a pass's ``points`` (:func:`pass_points`, ``node``'s frame) against ``submap``
    (an earlier pass, its anchor's frame) over ``settings.max_window`` around the graph's
    ``predicted`` ``T_anchor_node``; accepted when its best pose is one of a kind (module
    docstring), the point-to-line refinement stays within ``max_refinement_step`` and the
    graph agrees (χ² against ``relative_covariance`` + the loop's covariance,
    ``pass_sigma``). A loop edge of a fixed covariance: the match's own would read thousands
    of points as independent, which a pass's points laid by drifting poses are not."""
    s = settings
    dt, dr = s.max_window
    sigma_t, sigma_r = s.pass_sigma
    cov = np.diag([sigma_t**2, sigma_t**2, sigma_r**2])
    reasons: list[str] = []
    measured, score, chi2 = predicted, math.nan, math.nan
    rival = math.nan
    coarse = find_correlative(
        points,
        submap.grid,
        min_score=s.pass_min_score,
        init=predicted,
        window=(dt, dt, dr),
        angular_resolution=s.pass_angular_resolution,
    )
    if coarse is None:
        reasons.append(f"pass: correlative score < {s.pass_min_score:.2f} everywhere in the window")
    elif coarse.at_window_edge:
        score = float(coarse.score)
        reasons.append("pass: correlative optimum at the window's edge")
    else:
        score = float(coarse.score)
        other = rival_search(
            points,
            submap.grid,
            predicted,
            (dt, dr),
            coarse.pose,
            min_score=s.pass_rival_ratio * coarse.score,
            exclusion=(s.pass_rival_exclusion, s.min_window[1]),
            angular_resolution=s.pass_angular_resolution,
        )
        rival = 0.0 if other is None else float(other.score / coarse.score)
        if other is not None:
            gap = float(np.linalg.norm((coarse.pose.inverse() @ other.pose).translation))
            reasons.append(
                f"pass: ambiguous: a pose {gap:.2f} m away scores {rival:.2f} of its score"
            )
        else:
            res = register(
                points,
                submap.target,
                method="point_to_line",
                init=coarse.pose,
                max_correspondence_distance=s.max_correspondence_distance,
                kernel=s.kernel,
                never_worse_than_start=False,
            )
            pose = res.pose
            assert isinstance(pose, SE2)
            step = float(np.linalg.norm((coarse.pose.inverse() @ pose).translation))
            if step > s.max_refinement_step:
                reasons.append(f"refinement moved {step:.2f} m > {s.max_refinement_step:.2f} m")
            else:
                measured = pose
                e = (predicted.inverse() @ pose).log()
                chi2 = float(e @ np.linalg.solve(relative_covariance + cov, e))
                if not chi2 <= s.chi2_threshold:
                    reasons.append(
                        f"inconsistent with the graph: χ² {chi2:.1f} > {s.chi2_threshold:.1f}"
                    )
    return LoopMatch(
        submap_node=submap.anchor,
        node=node,
        predicted=predicted,
        measured=measured,
        window=(dt, dr),
        score=score,
        overlap=math.nan,
        chi2=chi2,
        covariance=cov,
        information=np.linalg.inv(cov),
        degenerate_directions=(),
        weak_vectors=np.zeros((3, 0)),
        accepted=not reasons,
        reasons=tuple(reasons),
        evidence="" if reasons else "graph",
        search="pass",
        rival=rival,
    )
