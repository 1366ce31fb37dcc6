"""2D loop closure: submaps, the match of a scan against one, and its verification.

A **submap** is a few consecutive keyframes' points in the frame of the middle one, rasterised
once for correlative matching (:func:`scanreg.prepare_correlative`) and prepared once, by the
first search that finds something, for point-to-line ICP (:func:`scanreg.prepare`).
:func:`match_loop` matches the current keyframe's scan against a candidate's submap in three
steps and says what it found and why it would be rejected:

1. **search** — :func:`scanreg.match_correlative` with branch and bound over a window around
   the graph's prediction, sized by the prediction's uncertainty (and capped);
2. **refine** — point-to-line :func:`scanreg.register` from the correlative pose;
3. **verify** — :func:`scanreg.verdict.assess` (overlap, residual, convergence, degeneracy,
   motion against the prediction), the correlative score, and the χ² consistency of the loop
   with the graph: ``e = log(T̂⁻¹ T)`` against ``Σ_graph + Σ_match`` (a Mahalanobis test).

The loop constraint's information is the inverse of the match's calibrated covariance, with
nothing along a direction the match names degenerate (:func:`scanreg.graph.project_information`).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol, TypeVar

import numpy as np

from .._validate import FloatArray, as_matrix, as_points
from ..correlative import CorrelativeGrid, find_correlative, prepare_correlative
from ..graph import project_information
from ..preprocess import voxel_downsample
from ..register import register
from ..target import PreparedTarget, prepare
from ..transform import SE2, SE3
from ..verdict import VerdictThresholds, assess
from .sweep_residual import DeskewedSweep, SubmapSweeps, submap_sweeps, sweep_covariance


@dataclass(frozen=True, eq=False)
class Submap2D:
    """Points of keyframes ``nodes`` in the frame of keyframe ``anchor``, prepared."""

    anchor: int
    nodes: tuple[int, ...]
    points: FloatArray
    grid: CorrelativeGrid
    #: 3×3 over a left perturbation in ``anchor``'s frame: how far the submap as a whole may
    #: sit from where its poses put it — the mean of its nodes' odometry covariances carried
    #: into that frame (zeros when none were given). A loop matched against the submap
    #: inherits it (:func:`match_loop`).
    covariance: FloatArray = field(default_factory=lambda: np.zeros((3, 3)))
    #: The deskewed sweeps behind its points (None: none of its scans was deskewed with a
    #: motion of known error); a loop matched against it covers what they leave
    #: (:mod:`scanreg.pipeline.sweep_residual`).
    sweeps: SubmapSweeps | None = None

    @functools.cached_property
    def target(self) -> PreparedTarget:
        """``points`` prepared for point-to-line ICP (normals), on first use: only a search
        that finds something refines on it (the Freiburg hospital: 163 of 1247 searches; the
        preparation was a third of a submap's build)."""
        return prepare(self.points, normals=True)


def build_submap(
    anchor: int,
    nodes: list[int],
    scans: dict[int, FloatArray],
    poses: dict[int, SE2],
    *,
    resolution: float,
    voxel_size: float,
    covariances: dict[int, FloatArray] | None = None,
    sweeps: dict[int, DeskewedSweep] | None = None,
) -> Submap2D:
    """``scans[n]`` (scan frame) laid into ``anchor``'s frame with the relative poses
    ``inv(poses[anchor]) @ poses[n]`` (locally consistent odometry poses).

    ``covariances[n]``: the odometry covariance of node ``n``'s pose (3×3, right perturbation,
    as :class:`~scanreg.pipeline.Frame2D` gives it); their mean, carried into the anchor's
    frame, is the submap's :attr:`Submap2D.covariance`. ``sweeps[n]``: how node ``n``'s scan
    was deskewed (:attr:`Submap2D.sweeps`)."""
    base = poses[anchor].inverse()
    relative = [base @ poses[n] for n in nodes]
    parts = [rel.apply(scans[n]) for rel, n in zip(relative, nodes, strict=True)]
    spread = np.zeros((3, 3))
    if covariances is not None:
        # T_a_n exp(δ) = exp(Ad δ) T_a_n: each node's error as a shift of its points in the
        # anchor's frame. The mean (not the mean / count of independent errors): the nodes'
        # odometry errors are correlated (each was matched against the same local map).
        for rel, n in zip(relative, nodes, strict=True):
            cov = covariances.get(n)
            if cov is not None and np.shape(cov) == (3, 3) and np.isfinite(cov).all():
                ad = rel.adjoint()
                spread += ad @ np.asarray(cov, dtype=np.float64) @ ad.T
        spread = 0.5 * (spread + spread.T) / len(nodes)
    pts = np.ascontiguousarray(np.vstack(parts))
    kept = None
    if voxel_size > 0:
        grid = voxel_downsample(pts, voxel_size)
        pts, kept = np.ascontiguousarray(grid.points), grid.indices
    swept = None
    if sweeps:
        sizes = [len(part) for part in parts]
        swept = submap_sweeps(anchor, nodes, relative, sizes, kept, sweeps)
    return Submap2D(
        anchor=anchor,
        nodes=tuple(nodes),
        points=pts,
        grid=prepare_correlative(pts, resolution=resolution),
        covariance=spread,
        sweeps=swept,
    )


def wide_submap_span(
    anchor: int,
    positions: FloatArray,
    here: FloatArray,
    settings: LoopSettings,
    *,
    margin: float = 0.0,
) -> tuple[int, int]:
    """First and last node ``(lo, hi)`` of the wide search's submap around ``anchor``:
    ``anchor ± wide_submap_half_size``, grown along the anchor's own pass (consecutive nodes,
    whose odometry poses agree with each other) while the next node's position
    (``positions[k]``, ``(N, 2)``, the old nodes only) lies within ``wide_submap_radius`` of
    ``here`` (where the graph puts the searching node), at most ``wide_submap_max_half_size``
    nodes a side. A scan that passes the place the other way sees what lay behind the earlier
    pass, far down the corridor, where an index-centred submap holds nothing. ``margin``
    (m): added to the radius — the search window's half-width, so that the submap holds
    the pass wherever in the window the scan may be (the graph's ``here`` is as wrong as
    the window is wide)."""
    s = settings
    if not (math.isfinite(margin) and margin >= 0):
        raise ValueError(f"margin: must be finite and >= 0, got {margin!r}")
    last = len(positions) - 1
    if not 0 <= anchor <= last:
        raise ValueError(f"anchor: {anchor} is not one of the {len(positions)} positions")
    xy = as_matrix(positions, "positions", (len(positions), 2))
    reach = np.linalg.norm(xy - as_matrix(here, "here", (2,)), axis=1)
    near = reach <= s.wide_submap_radius + margin
    lo = max(anchor - s.wide_submap_half_size, 0)
    hi = min(anchor + s.wide_submap_half_size, last)
    while lo > 0 and anchor - lo < s.wide_submap_max_half_size and near[lo - 1]:
        lo -= 1
    while hi < last and hi - anchor < s.wide_submap_max_half_size and near[hi + 1]:
        hi += 1
    return lo, hi


@dataclass(frozen=True)
class LoopSettings:
    """How loop candidates are matched and verified (metres, radians)."""

    #: The search window is this many σ of the prediction's uncertainty per axis ...
    window_sigmas: float = 3.0
    #: ... at least this (dx = dy, dθ) ...
    min_window: tuple[float, float] = (0.5, math.radians(10.0))
    #: ... and at most this.
    max_window: tuple[float, float] = (3.0, math.radians(30.0))
    #: Correlative grid resolution of the submaps ...
    resolution: float = 0.05
    #: ... and angular step (rad; ``None``: the matcher's default, one cell at the farthest
    #: return, 0.07° at 40 m — fine steps over a wide loop window cost the most).
    angular_resolution: float | None = None
    #: Least mean likelihood of the scan on the submap at the correlative optimum.
    min_score: float = 0.5
    #: Point-to-line gate and kernel of the refinement.
    max_correspondence_distance: float = 0.3
    kernel: str = "cauchy"
    #: The refinement may move the correlative pose at most this far (m).
    max_refinement_step: float = 0.15
    #: χ² bound on the loop's disagreement with the graph (3 dof, 0.999: 16.27).
    chi2_threshold: float = 16.27
    #: Verdict thresholds of the point-to-line match (degenerate loops are not rejected:
    #: they constrain only their strong directions).
    thresholds: VerdictThresholds = field(
        default_factory=lambda: VerdictThresholds(min_overlap=0.6, reject_degenerate=False)
    )
    #: The drift-independent search (dx = dy, dθ): a window around the graph's prediction,
    #: whatever the graph believes its uncertainty to be (Cartographer searches ±7 m / ±30°),
    #: no wider than the drift the path between the two nodes could hold (0.5 m + 10 % of
    #: it) and at most this. Run when the window above found nothing
    #: (:class:`~scanreg.pipeline.Mapper`). ±4 m left the Freiburg hospital's return to its
    #: start, 4-15 m off after 1 km, unclosed.
    wide_window: tuple[float, float] = (20.0, math.radians(30.0))
    #: ... its correlative search over a larger submap than the usual one: this many nodes
    #: on each side of the candidate (a revisit from another heading sees little of 5 nodes'
    #: points; on the Freiburg hospital the true pose scored 0.13-0.64 against 5 nodes,
    #: 0.26-0.76 against 17). The match is refined and verified against the usual submap,
    #: and against this one only when the usual one rejects it: many nodes' odometry poses
    #: hold centimetres of their own drift, and loops always measured against 17 made the
    #: simulated room tours' maps worse (seed 0: 0.009 -> 0.014 m).
    wide_submap_half_size: int = 8
    #: ... grown, along the candidate's own pass (consecutive nodes: their odometry poses
    #: agree), while its nodes lie within this distance (m) of where the graph puts the
    #: searching node, up to ``wide_submap_max_half_size`` nodes a side: what a scan driving
    #: the other way sees lies behind the earlier pass, metres down the corridor. On the
    #: Freiburg hospital's return to its start (scans 6651-6674) the true pose scored
    #: 0.30-0.39 against 9-15 such nodes (4 m), 0.48-0.54 (10 m) and 0.50-0.61 (16 m).
    #: The wide search adds its window's half-width to this radius: where the graph puts the
    #: scan is as wrong as the window is wide (the hospital's return 13-20 m off: the pass it
    #: sees ended a few nodes short of the submap grown within 16 m of the wrong place).
    wide_submap_radius: float = 16.0
    wide_submap_max_half_size: int = 40
    #: ... at most once per this much path (m), and only after this much path without a
    #: closed loop: the bound on its cost.
    wide_spacing: float = 2.0
    #: A match that fails only the χ² test (its own evidence is good) is a *hypothesis*: the
    #: graph may be the one that is wrong. It needs at least this correlative score ...
    hypothesis_min_score: float = 0.6
    #: ... and becomes a loop once this many hypotheses from different nodes agree with each
    #: other (:func:`loops_agree`); while it waits, the next nodes are searched where it puts
    #: them (``Mapper._guided``), and those matches are such hypotheses.
    min_agreeing: int = 2
    #: Hypotheses agree when the cycle through both closes within this (m, rad) plus
    #: ``agreement_per_metre`` × the path the cycle spans (the graph's own segments drift).
    agreement: tuple[float, float] = (0.15, math.radians(1.5))
    agreement_per_metre: tuple[float, float] = (0.02, math.radians(0.15))
    #: A hypothesis waits for agreement over at most this much path (m).
    hypothesis_horizon: float = 20.0
    #: A match held without the graph's check (a hypothesis, or one the wide search found)
    #: is refused as ambiguous when another pose of its window, outside ``min_window`` of
    #: it, scores at least this fraction of its correlative score (:func:`rival_search`).
    ambiguity_ratio: float = 0.9

    def __post_init__(self) -> None:
        for name in ("wide_window", "agreement", "agreement_per_metre"):
            pair = getattr(self, name)
            if not (
                isinstance(pair, tuple)
                and len(pair) == 2
                and all(isinstance(v, (int, float)) and math.isfinite(v) and v >= 0 for v in pair)
            ):
                raise ValueError(f"{name}: expected two finite numbers >= 0, got {pair!r}")
        if not self.wide_window[0] > 0 or not 0 < self.wide_window[1] <= math.pi:
            raise ValueError(
                f"wide_window: must be > 0 m and in (0, π] rad, got {self.wide_window}"
            )
        for name in ("wide_spacing", "hypothesis_horizon", "wide_submap_radius"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"{name}: must be finite and >= 0, got {value!r}")
        if not self.ambiguity_ratio > 0.0:
            raise ValueError(f"ambiguity_ratio: must be > 0, got {self.ambiguity_ratio!r}")
        if not 0.0 <= self.hypothesis_min_score <= 1.0:
            raise ValueError(
                f"hypothesis_min_score: must be in [0, 1], got {self.hypothesis_min_score!r}"
            )
        if isinstance(self.wide_submap_half_size, bool) or not (
            isinstance(self.wide_submap_half_size, int) and self.wide_submap_half_size >= 0
        ):
            raise ValueError(
                f"wide_submap_half_size: must be an int >= 0, got {self.wide_submap_half_size!r}"
            )
        if isinstance(self.wide_submap_max_half_size, bool) or not (
            isinstance(self.wide_submap_max_half_size, int)
            and self.wide_submap_max_half_size >= self.wide_submap_half_size
        ):
            raise ValueError(
                "wide_submap_max_half_size: must be an int >= wide_submap_half_size "
                f"({self.wide_submap_half_size}), got {self.wide_submap_max_half_size!r}"
            )
        if isinstance(self.min_agreeing, bool) or not (
            isinstance(self.min_agreeing, int) and self.min_agreeing >= 2
        ):
            raise ValueError(f"min_agreeing: must be an int >= 2, got {self.min_agreeing!r}")


#: The most an odometry drifts per metre of path (a wrong wheel scale of several percent
#: and a heading off by degrees): the mapping's wide search looks no farther than this times
#: the path between the two nodes, plus the least loop window, and a merge's second search
#: no farther than this times the path since its fix (:mod:`scanreg.pipeline.join`); the 3D
#: mapper's drift-independent window is as wide (:func:`~scanreg.pipeline.loops3d.drift_window_3d`).
MAX_DRIFT_PER_METRE = 0.1

#: A loop is what the map bets on: every match the verdict accepts is probed for other basins.
#: The screen's cheap evidence (``VerdictThresholds.basin_screen``) is tuned for odometry steps
#: and misses along-corridor look-alikes: on ACES it let 16 loops through whose scan a pose
#: 2 m along the corridor explained better (64 % against 48 % within 3 cm), 0.040 → 0.051 m.
_PROBE_EVERY_MATCH = VerdictThresholds(basin_screen=False)


@dataclass(frozen=True)
class LoopMatch:
    """What matching one candidate gave; ``accepted`` with ``reasons`` empty, or not."""

    #: Keyframe (graph node) of the submap and of the current scan.
    submap_node: int
    node: int
    #: The graph's prediction of ``T_submap_node`` and the match's estimate of it.
    predicted: SE2
    measured: SE2
    #: Search half-widths (dx = dy, dθ) used.
    window: tuple[float, float]
    score: float
    overlap: float
    chi2: float
    #: 3×3 calibrated covariance of ``measured`` (right perturbation) and the information the
    #: constraint carries (inverse, weak directions removed).
    covariance: FloatArray
    information: FloatArray
    degenerate_directions: tuple[str, ...]
    #: ``(3, w)`` the weak directions as tangent vectors (unit length in metres), one column
    #: each; ``information`` is zero along them.
    weak_vectors: FloatArray
    accepted: bool
    reasons: tuple[str, ...]
    #: Why it was accepted: ``"graph"`` (it agrees with the graph's prediction, χ²),
    #: ``"loops"`` (it disagreed with the graph but agreed with other loops: the graph had
    #: drifted more than it knew), ``""`` while not accepted.
    evidence: str = ""
    #: Its own evidence is good and only the χ² test failed: held as a hypothesis until other
    #: loops agree with it (:func:`loops_agree`).
    hypothesis: bool = False
    #: Which search found it (:class:`~scanreg.pipeline.Mapper`): ``"graph"`` (the window
    #: the graph's uncertainty sized), ``"wide"`` (the drift-independent window) or
    #: ``"guided"`` (where a held loop puts the node).
    search: str = "graph"
    #: The best correlative score elsewhere in the window (outside ``min_window`` of the
    #: match) over the match's own when it reaches ``ambiguity_ratio`` (the match is then
    #: refused), 0 when none does, NaN when not searched (:func:`rival_search`).
    rival: float = math.nan


def search_window(relative_covariance: FloatArray, settings: LoopSettings) -> tuple[float, float]:
    """Half-widths ``(dx = dy, dθ)`` from the prediction's covariance (largest translation
    σ, heading σ), clipped to ``[min_window, max_window]``."""
    s = settings
    sigma_t = math.sqrt(max(float(np.linalg.eigvalsh(relative_covariance[:2, :2])[-1]), 0.0))
    sigma_r = math.sqrt(max(float(relative_covariance[2, 2]), 0.0))
    dt = min(max(s.window_sigmas * sigma_t, s.min_window[0]), s.max_window[0])
    dr = min(max(s.window_sigmas * sigma_r, s.min_window[1]), s.max_window[1])
    return dt, dr


#: A covariance whose eigenvalues span more than this ratio is treated as singular.
_MAX_CONDITION = 1e12


def _well_posed(covariance: FloatArray) -> bool:
    if not np.isfinite(covariance).all():
        return False
    vals = np.linalg.eigvalsh(0.5 * (covariance + covariance.T))
    return bool(vals[-1] > 0 and vals[0] > vals[-1] / _MAX_CONDITION)


def _information(
    covariance: FloatArray, res: Any
) -> tuple[FloatArray, tuple[str, ...], FloatArray]:
    # Through the eigen-decomposition: the caller checked the conditioning, so no direction
    # divides by (numerically) zero.
    vals, vecs = np.linalg.eigh(0.5 * (covariance + covariance.T))
    info = (vecs / vals) @ vecs.T
    info = 0.5 * (info + info.T)
    deg = res.degeneracy
    if deg is not None and deg.degenerate:
        info = project_information(info, deg.weak_projector())
        vectors = np.column_stack([w.vector for w in deg.weak_directions])
        return info, tuple(w.description for w in deg.weak_directions), vectors
    return info, (), np.zeros((len(covariance), 0))


def match_loop(
    points: FloatArray,
    node: int,
    submap: Submap2D,
    predicted: SE2,
    relative_covariance: FloatArray,
    settings: LoopSettings,
    *,
    window: tuple[float, float] | None = None,
    search_submap: Submap2D | None = None,
    sweep: DeskewedSweep | None = None,
    unchecked: bool = False,
) -> LoopMatch:
    """Match ``points`` (keyframe ``node``'s scan, own frame) against ``submap`` from the
    graph's ``predicted`` ``T_submap_node`` with its ``relative_covariance``.

    ``window``: the search's half-widths ``(dx = dy, dθ)``; default :func:`search_window`
    (sized by ``relative_covariance``). ``search_submap``: a larger submap with the same
    anchor for the correlative search; the refinement and verification run on ``submap``,
    and on ``search_submap`` when ``submap`` rejects the match (a revisit from another
    heading may see little of ``submap``). ``sweep``: how ``points`` were deskewed; the loop's
    covariance then covers what that deskew and the submap's (:attr:`Submap2D.sweeps`) leave.
    The χ² test against ``relative_covariance`` never stops a match whose own evidence is
    good: it is then returned as a ``hypothesis``. ``unchecked``: the caller holds an
    accepted match until other loops agree, as it holds a hypothesis (the wide search's).

    A match so held has not passed the graph's test, and the loops that may confirm it are
    searched where it puts the next nodes: it must not be one of two fits. It is refused as
    ambiguous when a pose elsewhere in its window scores ``ambiguity_ratio`` of its score
    (:func:`rival_search`). On ACES, a corridor with doors every few metres, the wide search
    found a pose 2.6 m along it that scored 0.72, the true one (found by the next node's
    usual search) 0.67; the next node, searched where it put it, agreed and the two closed."""
    s = settings
    if search_submap is not None:
        if not isinstance(search_submap, Submap2D):
            raise TypeError(
                f"search_submap: expected a Submap2D or None, got {type(search_submap).__name__}"
            )
        if search_submap.anchor != submap.anchor:
            raise ValueError(
                f"search_submap: must share the submap's anchor (its frame), got anchor "
                f"{search_submap.anchor} for {submap.anchor}"
            )
    dt, dr = search_window(relative_covariance, s) if window is None else window
    # Branch and bound with the score floor: a window that does not hold the place (most
    # candidates) is given up early instead of searched to its best non-match.
    coarse = find_correlative(
        points,
        submap.grid if search_submap is None else search_submap.grid,
        min_score=s.min_score,
        init=predicted,
        window=(dt, dt, dr),
        angular_resolution=s.angular_resolution,
    )
    if coarse is None:
        return _not_found(node, submap, predicted, (dt, dr), s)
    match = _measure(
        points, node, submap, coarse, predicted, relative_covariance, (dt, dr), s, sweep
    )
    if search_submap is not None and not match.accepted and not match.hypothesis:
        # The usual submap may hold too little of what the scan sees (a revisit driven the
        # other way sees what lay behind the earlier pass): the match is then measured on
        # the search submap it was found in, by the same tests.
        wide = _measure(
            points, node, search_submap, coarse, predicted, relative_covariance, (dt, dr), s, sweep
        )
        if wide.accepted or wide.hypothesis:
            match = wide
    if match.hypothesis or (unchecked and match.accepted):
        grid = submap.grid if search_submap is None else search_submap.grid
        match = _unless_ambiguous(match, points, grid, coarse, (dt, dr), s)
    return match


def _unless_ambiguous(
    match: LoopMatch,
    points: FloatArray,
    grid: CorrelativeGrid,
    coarse: Any,
    window: tuple[float, float],
    s: LoopSettings,
) -> LoopMatch:
    """``match`` with the rival search's ratio; refused when a rival scores as much."""
    rival = rival_search(
        points,
        grid,
        match.predicted,
        window,
        coarse.pose,
        min_score=s.ambiguity_ratio * coarse.score,
        exclusion=s.min_window,
        angular_resolution=s.angular_resolution,
    )
    ratio = 0.0 if rival is None else rival.score / coarse.score
    match = dataclasses.replace(match, rival=ratio)
    if rival is None or ratio < s.ambiguity_ratio:
        return match
    gap = match.measured.inverse() @ rival.pose
    reason = (
        f"ambiguous: a pose {np.linalg.norm(gap.translation):.2f} m and "
        f"{math.degrees(abs(gap.angle)):.1f} deg away scores {ratio:.2f} of its score"
    )
    return dataclasses.replace(
        match,
        accepted=False,
        hypothesis=False,
        evidence="",
        reasons=(*match.reasons, reason),
    )


def rival_search(
    points: FloatArray,
    grid: CorrelativeGrid,
    predicted: SE2,
    window: tuple[float, float],
    best: SE2,
    *,
    min_score: float,
    exclusion: tuple[float, float],
    angular_resolution: float | None,
) -> Any:
    """The best correlative candidate of the window ``predicted ± window`` (``(dx = dy, dθ)``,
    pose-vector offsets as :func:`~scanreg.find_correlative` takes them) that lies outside
    ``best ± exclusion``, if it scores at least ``min_score``; else None.

    The window less the excluded box is cut into at most six boxes (below and above the
    box in x; within its x-range, below and above in y; within its x- and y-range, below
    and above in θ), each searched by branch and bound with the floor (most are pruned
    whole)."""
    points = as_points(points, "points", dim=2)
    if not isinstance(grid, CorrelativeGrid):
        raise TypeError(f"grid: expected a CorrelativeGrid, got {type(grid).__name__}")
    for name, pair in (("window", window), ("exclusion", exclusion)):
        if not (len(pair) == 2 and all(math.isfinite(float(v)) and float(v) >= 0 for v in pair)):
            raise ValueError(
                f"{name}: expected (dx = dy, dθ), two finite numbers >= 0, got {pair!r}"
            )
    p, b = predicted.as_vector(), best.as_vector()
    half = np.array([window[0], window[0], window[1]])
    lo, hi = p - half, p + half
    # Angles as offsets from the prediction (the window is narrower than π).
    b[2] = p[2] + math.remainder(b[2] - p[2], 2.0 * math.pi)
    ex = np.array([exclusion[0], exclusion[0], exclusion[1]])
    elo, ehi = np.maximum(b - ex, lo), np.minimum(b + ex, hi)
    boxes: list[tuple[FloatArray, FloatArray]] = []
    inner_lo, inner_hi = lo.copy(), hi.copy()
    for axis in range(3):
        below_hi, above_lo = inner_hi.copy(), inner_lo.copy()
        below_hi[axis] = elo[axis]
        above_lo[axis] = ehi[axis]
        boxes.append((inner_lo.copy(), below_hi))
        boxes.append((above_lo, inner_hi.copy()))
        inner_lo[axis], inner_hi[axis] = elo[axis], ehi[axis]
    found = None
    floor = min_score
    for a, z in boxes:
        if not (z > a).all():
            continue
        centre, radius = 0.5 * (a + z), 0.5 * (z - a)
        res = find_correlative(
            points,
            grid,
            min_score=min(floor, 1.0),
            init=SE2.from_vector(centre),
            window=tuple(float(v) for v in radius),
            angular_resolution=angular_resolution,
        )
        if res is not None and (found is None or res.score > found.score):
            found, floor = res, res.score
    return found


def _measure(
    points: FloatArray,
    node: int,
    submap: Submap2D,
    coarse: Any,
    predicted: SE2,
    relative_covariance: FloatArray,
    window: tuple[float, float],
    s: LoopSettings,
    sweep: DeskewedSweep | None,
) -> LoopMatch:
    """Refine the correlative optimum ``coarse`` on ``submap`` and verify it (see
    :func:`match_loop`)."""
    dt, dr = window
    res = register(
        points,
        submap.target,
        method="point_to_line",
        init=coarse.pose,
        max_correspondence_distance=s.max_correspondence_distance,
        kernel=s.kernel,
        thresholds=_PROBE_EVERY_MATCH,
        # Its own test stands in: the refinement may not move the correlative optimum more
        # than max_refinement_step (the maps of benchmarks/README.md were measured so).
        never_worse_than_start=False,
    )
    pose = res.pose
    assert isinstance(pose, SE2)
    reasons: list[str] = []
    if coarse.score < s.min_score:
        reasons.append(f"correlative score {coarse.score:.2f} < {s.min_score:.2f}")
    if coarse.at_window_edge:
        reasons.append("correlative optimum at the window's edge")
    step = float(np.linalg.norm((coarse.pose.inverse() @ pose).translation))
    if step > s.max_refinement_step:
        reasons.append(f"refinement moved {step:.2f} m > {s.max_refinement_step:.2f} m")
    thresholds = s.thresholds
    window_bound = VerdictThresholds(
        min_overlap=thresholds.min_overlap,
        overlap_gate=thresholds.overlap_gate,
        max_inlier_rmse=thresholds.max_inlier_rmse,
        weak_ratio=thresholds.weak_ratio,
        max_translation=min(thresholds.max_translation, math.hypot(dt, dt) + 0.1),
        max_rotation=min(thresholds.max_rotation, dr + math.radians(2.0)),
        require_convergence=thresholds.require_convergence,
        reject_degenerate=thresholds.reject_degenerate,
        basin_screen=False,
    )
    out = assess(res, points, submap.target, init=predicted, thresholds=window_bound)
    reasons.extend(out.verdict.reasons)
    # The match's calibrated covariance is against the submap as built; the submap itself
    # sits only as well as the odometry poses that built it (a left perturbation in the
    # anchor's frame, carried to the right perturbation of T_anchor_node). Measured on
    # simulated room tours, without it the accepted loops' NEES was about 2× the ideal.
    ad = pose.inverse().adjoint()
    cov = np.array(res.covariance, dtype=np.float64) + ad @ submap.covariance @ ad.T
    # Scans deskewed with the wheels keep the wheels' error over their sweeps: a distortion
    # their beams' noise, which the match's own covariance reads, says nothing of.
    residual = sweep_covariance(
        points, sweep, submap.target, submap.sweeps, pose, s.max_correspondence_distance
    )
    if residual is not None:
        cov = cov + residual
    combined = relative_covariance + cov
    hypothesis = False
    measured = pose
    if _well_posed(cov) and _well_posed(combined):
        info, weak, vectors = _information(cov, res)
        if len(weak) >= 3:
            reasons.append("degenerate in every direction")
        e = (predicted.inverse() @ pose).log()
        if weak and res.degeneracy is not None:
            # The edge carries no information along its weak directions, and there the
            # refined pose is no measurement: along a bare corridor it slides to where the
            # submap sampled the walls, metres off. Through the weak vector's small tilt
            # (1-2 %) that leaked centimetres across the corridor into the graph (a ring
            # corridor's lap bent 1.6 deg: benchmarks/simulated_buildings.py). Along them
            # the edge says what the graph says; across them, what the scan does.
            measured = predicted @ SE2.exp(e - res.degeneracy.weak_projector() @ e)
        chi2 = float(e @ np.linalg.solve(combined, e))
        if not chi2 <= s.chi2_threshold:
            # The graph's prediction may be what is wrong (more drift than it knows): a
            # match that is sound on its own evidence waits for other loops to agree. Not a
            # degenerate one: where it cannot fix its own pose (a corridor's axis), its
            # look-alikes one window apart agree with each other as well as true ones do.
            hypothesis = not reasons and not weak and coarse.score >= s.hypothesis_min_score
            reasons.append(f"inconsistent with the graph: χ² {chi2:.1f} > {s.chi2_threshold:.1f}")
    else:
        info, weak, vectors, chi2 = np.zeros((3, 3)), (), np.zeros((3, 0)), math.nan
        reasons.append("covariance singular or not finite")
    return LoopMatch(
        submap_node=submap.anchor,
        node=node,
        predicted=predicted,
        measured=measured,
        window=(dt, dr),
        score=float(coarse.score),
        overlap=float(out.report.overlap),
        chi2=chi2,
        covariance=cov,
        information=info,
        degenerate_directions=weak,
        weak_vectors=vectors,
        accepted=not reasons,
        reasons=tuple(reasons),
        evidence="" if reasons else "graph",
        hypothesis=hypothesis,
    )


def _not_found(
    node: int,
    submap: Submap2D,
    predicted: SE2,
    window: tuple[float, float],
    settings: LoopSettings,
) -> LoopMatch:
    """The record of a search in which no candidate reached ``min_score``."""
    return LoopMatch(
        submap_node=submap.anchor,
        node=node,
        predicted=predicted,
        measured=predicted,
        window=window,
        score=math.nan,
        overlap=math.nan,
        chi2=math.nan,
        covariance=np.full((3, 3), np.nan),
        information=np.zeros((3, 3)),
        degenerate_directions=(),
        weak_vectors=np.zeros((3, 0)),
        accepted=False,
        reasons=(f"correlative score < {settings.min_score:.2f} everywhere in the window",),
    )


class AgreementTolerances(Protocol):
    """What :func:`loops_agree` reads of a loop setting (2D :class:`LoopSettings` and 3D
    :class:`~scanreg.pipeline.loops3d.LoopSettings3D` both carry it)."""

    @property
    def agreement(self) -> tuple[float, float]: ...
    @property
    def agreement_per_metre(self) -> tuple[float, float]: ...


class _Loop(Protocol):
    """The fields of a loop match :func:`loops_agree` reads (2D or 3D)."""

    @property
    def submap_node(self) -> int: ...
    @property
    def node(self) -> int: ...
    @property
    def measured(self) -> SE2 | SE3: ...


def loops_agree(
    first: _Loop,
    second: _Loop,
    poses: Mapping[int, SE2 | SE3],
    settings: AgreementTolerances,
) -> bool:
    """Whether two loop matches tell the same story: the cycle ``submap₁ → node₁ → node₂ →
    submap₂ → submap₁`` closes, with the graph's ``poses`` for the two short legs between the
    nodes and between the submaps. Each leg is locally consistent even when the graph as a
    whole has drifted, so two true loops agree whatever the drift, and two false ones rarely
    do (pairwise consistency, as in Olson's single-cluster graph partitioning and Mangelson's
    PCM). 2D (SE2) or 3D (SE3) alike: the rotation compared is the cycle's angle."""

    def leg(i: int, j: int) -> Any:
        start: Any = poses[i]  # (both SE2 or both SE3)
        return start.inverse() @ poses[j]

    t_a = leg(first.submap_node, second.submap_node)
    t_n = leg(first.node, second.node)
    cycle = first.measured.inverse() @ t_a @ second.measured @ t_n.inverse()
    assert isinstance(cycle, SE2 | SE3)
    span = float(np.linalg.norm(t_a.translation) + np.linalg.norm(t_n.translation))
    (tol_t, tol_r), (per_t, per_r) = settings.agreement, settings.agreement_per_metre
    return bool(
        np.linalg.norm(cycle.translation) <= tol_t + per_t * span
        and abs(cycle.angle) <= tol_r + per_r * span
    )


class _Held(Protocol):
    """A loop record as :func:`agreeing_group` reads it (2D or 3D)."""

    @property
    def match(self) -> _Loop: ...


HeldT = TypeVar("HeldT", bound=_Held)


class AgreementSettings(AgreementTolerances, Protocol):
    """:class:`AgreementTolerances` and how many nodes' loops must agree."""

    @property
    def min_agreeing(self) -> int: ...


def agreeing_group(
    record: HeldT,
    held: Sequence[HeldT],
    pose: Callable[[int], SE2 | SE3],
    settings: AgreementSettings,
    *,
    support: Sequence[HeldT] = (),
) -> list[HeldT] | None:
    """``[record, *the held loops that agree with it]`` (:func:`loops_agree`, loops of other
    nodes than ``record``'s) when they, with the ``support`` loops that agree with it, come
    from at least ``settings.min_agreeing`` nodes; None otherwise (``record`` should then be
    held too). ``pose(k)``: the graph's pose of node ``k``. The mappers hold a loop the graph
    disagrees with this way (2D :class:`~scanreg.pipeline.Mapper`, 3D
    :class:`~scanreg.pipeline.Mapper3D`): once loops of several nodes agree, the graph, not the
    loops, was wrong."""
    here = record.match.node
    needed = {k for h in (*held, *support, record) for k in (h.match.node, h.match.submap_node)}
    poses = {k: pose(k) for k in needed}

    def agrees(h: HeldT) -> bool:
        return h.match.node != here and loops_agree(h.match, record.match, poses, settings)

    group = [record] + [h for h in held if agrees(h)]
    backers = [h for h in support if agrees(h)]
    if len({h.match.node for h in (*group, *backers)}) < settings.min_agreeing:
        return None
    return group


def record_decided(loops: list[Any], held: Sequence[Any], decided: Sequence[Any]) -> None:
    """Replace in ``loops`` (a run's records, in order) each of ``held`` by its ``decided``
    record: held loops were recorded as rejected when they were matched (2D and 3D)."""
    index = {id(h): k for k, h in enumerate(loops)}
    for old, new in zip(held, decided, strict=True):
        k = index.get(id(old))
        if k is not None:
            loops[k] = new
