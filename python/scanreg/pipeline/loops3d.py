"""3D loop closure: submaps, the match of a keyframe against one, and its verification.

A **submap** is a few consecutive keyframes' clouds in the frame of the middle one, voxelized
and prepared once for GICP (:func:`scanreg.prepare` with covariances). A candidate comes from
one of two places, and :func:`match_loop_3d` treats both the same way once it has a start:

* ``"graph"`` — the pose graph predicts ``T_submap_node`` well enough for GICP's basin: the
  match starts from the graph's prediction;
* ``"place"`` — Scan Context (:mod:`scanreg.place`) retrieved the submap's anchor as a place
  the keyframe may revisit, for drift beyond the local basin: :func:`scanreg.register_global`
  (FPFH, max clique, GNC-TLS, with its own verdict and ambiguity test) gives the start.

Then, for both:

1. **refine** — GICP (:func:`scanreg.register`) of the keyframe's cloud against the submap;
2. **verify** — the registration's verdict (overlap, residual, convergence), the motion
   against the graph's prediction (within ``window_sigmas`` σ of the prediction's
   uncertainty), and the χ² consistency of the loop with the graph: ``e = log(T̂⁻¹ T)``
   against ``Σ_graph + Σ_match`` (6 dof). A look-alike place a quarter lap away passes the
   geometry (it *is* the same geometry) and fails here.

The graph's tests are only as good as the graph's idea of its own drift. A match that is
sound on its own evidence (the verdict, not degenerate) and fails only them, landing within
the drift-independent window (:func:`drift_window_3d`: the drift the path between the two
nodes could hold, whatever the graph believes), is a **hypothesis**: the mapper holds it until
a loop from another node agrees with it (:func:`~scanreg.pipeline.loops.loops_agree`), as the
2D mapper does. Beyond that window (a look-alike a quarter lap around a repeated block is 90°
off) it is rejected.

The constraint's information is the inverse of the match's calibrated covariance with nothing
along a direction the match names degenerate (:func:`scanreg.graph.project_information`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from .._validate import FloatArray
from ..global_registration import register_global
from ..preprocess import voxel_downsample
from ..register import register
from ..target import PreparedTarget, prepare
from ..transform import SE3
from ..verdict import VerdictThresholds
from .loops import MAX_DRIFT_PER_METRE, _information, _well_posed

LoopOrigin = Literal["graph", "place"]


def _se3(pose: Any) -> SE3:
    assert isinstance(pose, SE3)
    return pose


@dataclass(frozen=True, eq=False)
class Submap3D:
    """Clouds of keyframes ``nodes`` in the frame of keyframe ``anchor``, prepared for GICP."""

    anchor: int
    nodes: tuple[int, ...]
    points: FloatArray
    target: PreparedTarget


def build_submap_3d(
    anchor: int,
    nodes: list[int],
    scans: dict[int, FloatArray],
    poses: dict[int, SE3],
    *,
    voxel_size: float,
    num_neighbors: int = 10,
    refine: bool = False,
) -> Submap3D:
    """``scans[n]`` (sensor frame) laid into ``anchor``'s frame with the relative poses
    ``inv(poses[anchor]) @ poses[n]`` (odometry poses), voxelized.

    ``refine``: each other node's cloud is first registered (GICP) to the anchor's from that
    relative pose, and the result used when its verdict accepts it (not degenerate, enough
    overlap, within 0.5 m of the start). An odometry glitch between a submap's nodes otherwise
    biases every loop into it: on the repeated block, 12-15 cm wrong relative poses in the
    drive's first seconds put loops into that submap 15-19 cm off, against 1 cm for the same
    match against the anchor's cloud alone."""
    base = poses[anchor].inverse()
    relative = {n: _se3(base @ poses[n]) for n in nodes}
    if refine and len(nodes) > 1:
        anchor_target = prepare(
            scans[anchor], covariances=True, num_neighbors=min(num_neighbors, len(scans[anchor]))
        )
        for n in nodes:
            if n == anchor:
                continue
            res = register(
                scans[n],
                anchor_target,
                method="gicp",
                init=relative[n],
                max_correspondence_distance=1.0,
                thresholds=VerdictThresholds(min_overlap=0.5, max_translation=0.5),
            )
            if res.verdict is not None and res.verdict.accepted:
                relative[n] = _se3(res.pose)
    parts = [relative[n].apply(scans[n]) for n in nodes]
    pts = np.ascontiguousarray(np.vstack(parts))
    if voxel_size > 0:
        pts = np.ascontiguousarray(voxel_downsample(pts, voxel_size).points)
    return Submap3D(
        anchor=anchor,
        nodes=tuple(nodes),
        points=pts,
        target=prepare(pts, covariances=True, num_neighbors=min(num_neighbors, len(pts))),
    )


def _default_thresholds() -> VerdictThresholds:
    # A revisit sees the same street from a lane that may differ and at another time: half the
    # keyframe within the gate of the submap is what a true loop gives (0.7-0.95 measured on
    # the simulated block); degenerate loops are kept, constraining their strong directions.
    return VerdictThresholds(min_overlap=0.5, reject_degenerate=False)


@dataclass(frozen=True)
class LoopSettings3D:
    """How 3D loop candidates are matched and verified (metres, radians)."""

    #: GICP's correspondence gate (m) — also the radius of its basin, roughly.
    max_correspondence_distance: float = 1.5
    kernel: str = "cauchy"
    max_iterations: int = 50
    #: The match may land at most this many σ of the prediction's uncertainty from it
    #: (per the largest translation / rotation σ) ...
    window_sigmas: float = 4.0
    #: ... at least this (m, rad) ...
    min_window: tuple[float, float] = (1.0, math.radians(5.0))
    #: ... and at most this.
    max_window: tuple[float, float] = (50.0, math.pi)
    #: σ (m, rad) per axis added to the registration's covariance: the keyframe's and the
    #: submap's own errors (deskew, the poses between a submap's nodes), correlated over every
    #: point, which the match's covariance cannot see (it takes both clouds as exact up to
    #: independent noise). Measured on 43 true loops of a simulated lap (seed 1, VLP-16,
    #: refined submaps): errors 4 mm and 0.016° RMS per axis against a median registration σ
    #: of 2 mm and 0.008°. GICP's point noise is now taken along the normal (its registration
    #: σ about half that): the registration's covariance alone gives loop NEES 41 / 98 / 18
    #: (ordinary block, repeated sides, 25 m odometry; 6 dof), a (2 mm, 0.01°) floor 9.1 /
    #: 12.5 / –, this one 5.5 / 6.8 / 7.4 (`benchmarks/README.md`, mapping_3d.py).
    submap_sigma: tuple[float, float] = (0.003, math.radians(0.015))
    #: ... at keyframes of this RMS range (m; the full-range VLP-16 lap's nodes: 27-37 m,
    #: median 32); they scale with the keyframe's own RMS range. Measured (with GICP's
    #: Euclidean point noise then): the registration's covariance alone was over-confident at
    #: full range (NEES 10.7 for 6 dof on the ordinary block) but not with the odometry's range
    #: cut to 25 m (RMS range 16 m: NEES 5.0), where a fixed floor made loops 2.3x cautious
    #: (2.65).
    submap_sigma_range: float = 32.0
    #: χ² bound on the loop's disagreement with the graph (6 dof, 0.999: 22.46).
    chi2_threshold: float = 22.46
    thresholds: VerdictThresholds = field(default_factory=_default_thresholds)
    #: Place recognition: Scan Context distance below which a retrieved keyframe is tried.
    place_max_distance: float = 0.3
    #: ... and how many retrieved keyframes are tried per query.
    place_top_k: int = 1
    #: Keypoint voxel of :func:`scanreg.register_global` on place candidates (m).
    global_voxel_size: float = 1.0
    #: Two loops agree (:func:`~scanreg.pipeline.loops.loops_agree`, what a merge of two
    #: maps keeps its inter-session loops by) when the cycle through both closes within this
    #: (m, rad) plus ``agreement_per_metre`` × the path the cycle spans.
    agreement: tuple[float, float] = (0.2, math.radians(1.0))
    agreement_per_metre: tuple[float, float] = (0.01, math.radians(0.05))
    #: Least overlap (the verdict's, within ``max_correspondence_distance``) of a loop
    #: between two sessions (merge, extend): with no prediction to test it against, the match
    #: alone must tell a revisit from a look-alike. Measured on two drives around the
    #: simulated block, node against submap: true loops 0.991-1.000; the other side of the
    #: block 0.56-0.80 and another block of the same shape (seed 3) 0.75-0.84, both passing
    #: the in-session 0.5.
    inter_session_min_overlap: float = 0.9
    #: The drift-independent window (m, rad): a match may land this far from the graph's
    #: prediction whatever the graph believes its uncertainty to be — no farther than the
    #: drift the path between the two nodes could hold (``min_window`` +
    #: ``MAX_DRIFT_PER_METRE`` × the path) and at most this (Cartographer searches ±7 m /
    #: ±30°). Within it, a match sound on its own evidence that fails only the graph's σ
    #: window or χ² test is a hypothesis (:func:`match_loop_3d`); Scan Context's places are
    #: matched within it however small the graph's σ (:class:`~scanreg.pipeline.Mapper3D`).
    drift_window: tuple[float, float] = (20.0, math.radians(30.0))
    #: A hypothesis becomes a loop once this many from different nodes agree with each other
    #: (:func:`~scanreg.pipeline.loops.loops_agree`) ...
    min_agreeing: int = 2
    #: ... within this much path (m): the leg between their nodes must be short to be trusted.
    hypothesis_horizon: float = 20.0

    def __post_init__(self) -> None:
        for name in (
            "max_correspondence_distance",
            "window_sigmas",
            "chi2_threshold",
            "submap_sigma_range",
        ):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | float) or not v > 0:
                raise ValueError(f"{name}: must be > 0, got {v!r}")
        if not isinstance(self.thresholds, VerdictThresholds):
            raise TypeError(
                f"thresholds: expected VerdictThresholds, got {type(self.thresholds).__name__}"
            )
        if len(self.submap_sigma) != 2 or not all(
            isinstance(v, int | float) and math.isfinite(v) and v >= 0 for v in self.submap_sigma
        ):
            raise ValueError(f"submap_sigma: expected two finite σ >= 0, got {self.submap_sigma!r}")
        for name in ("min_window", "max_window"):
            w = getattr(self, name)
            if len(w) != 2 or not all(isinstance(v, int | float) and v > 0 for v in w):
                raise ValueError(f"{name}: expected two values > 0, got {w!r}")
        for name in ("agreement", "agreement_per_metre", "drift_window"):
            pair = getattr(self, name)
            if not (
                isinstance(pair, tuple)
                and len(pair) == 2
                and all(isinstance(v, int | float) and math.isfinite(v) and v >= 0 for v in pair)
            ):
                raise ValueError(f"{name}: expected two finite numbers >= 0, got {pair!r}")
        if not (math.isfinite(self.hypothesis_horizon) and self.hypothesis_horizon >= 0):
            raise ValueError(
                f"hypothesis_horizon: must be finite and >= 0, got {self.hypothesis_horizon!r}"
            )
        if isinstance(self.min_agreeing, bool) or not (
            isinstance(self.min_agreeing, int) and self.min_agreeing >= 2
        ):
            raise ValueError(f"min_agreeing: must be an int >= 2, got {self.min_agreeing!r}")
        if not 0 <= self.inter_session_min_overlap <= 1:
            raise ValueError(
                "inter_session_min_overlap: must be in [0, 1], got "
                f"{self.inter_session_min_overlap!r}"
            )
        if not self.global_voxel_size > 0:
            raise ValueError(f"global_voxel_size: must be > 0, got {self.global_voxel_size!r}")
        if isinstance(self.place_top_k, bool) or not isinstance(self.place_top_k, int):
            raise TypeError(f"place_top_k: expected an int, got {type(self.place_top_k).__name__}")
        if self.place_top_k < 0:
            raise ValueError(f"place_top_k: must be >= 0, got {self.place_top_k}")


@dataclass(frozen=True)
class LoopMatch3D:
    """What matching one 3D candidate gave; the fields of the 2D
    :class:`~scanreg.pipeline.loops.LoopMatch` (``window``: the translation and rotation bound
    on the match's distance from the prediction; ``score``: the Scan Context distance of a
    place candidate, ``nan`` for a graph one), plus where the candidate came from."""

    submap_node: int
    node: int
    #: The graph's prediction of ``T_submap_node`` and the match's estimate of it.
    predicted: SE3
    measured: SE3
    window: tuple[float, float]
    score: float
    overlap: float
    chi2: float
    #: 6×6 covariance of ``measured`` (right perturbation, translation first): the match's
    #: calibrated one plus ``submap_sigma`` (scaled by range); the information the constraint
    #: carries (its inverse, weak directions removed).
    covariance: FloatArray
    information: FloatArray
    degenerate_directions: tuple[str, ...]
    #: ``(6, w)`` the weak directions as tangent vectors, one column each.
    weak_vectors: FloatArray
    accepted: bool
    reasons: tuple[str, ...]
    #: ``"graph"`` (started from the graph's prediction) or ``"place"`` (Scan Context, then
    #: global registration).
    origin: LoopOrigin = "graph"
    #: Sound on its own evidence, within the drift-independent window, and failing only the
    #: graph's tests: held until another loop agrees with it (:class:`~scanreg.pipeline.Mapper3D`).
    hypothesis: bool = False
    #: Why it was accepted: ``"graph"`` (the graph's tests), ``"loops"`` (it disagreed with
    #: the graph but agreed with other loops: the graph had drifted more than it knew), ``""``
    #: while not accepted.
    evidence: str = ""


def search_window_3d(
    relative_covariance: FloatArray, settings: LoopSettings3D
) -> tuple[float, float]:
    """Bounds ``(translation, rotation)`` on how far a match may land from the prediction:
    ``window_sigmas`` × the largest σ of each block, clipped to ``[min_window, max_window]``."""
    s = settings
    cov = 0.5 * (relative_covariance + relative_covariance.T)
    sigma_t = math.sqrt(max(float(np.linalg.eigvalsh(cov[:3, :3])[-1]), 0.0))
    sigma_r = math.sqrt(max(float(np.linalg.eigvalsh(cov[3:, 3:])[-1]), 0.0))
    dt = min(max(s.window_sigmas * sigma_t, s.min_window[0]), s.max_window[0])
    dr = min(max(s.window_sigmas * sigma_r, s.min_window[1]), s.max_window[1])
    return dt, dr


def drift_window_3d(path: float, settings: LoopSettings3D) -> tuple[float, float]:
    """Bounds ``(translation, rotation)`` on how far a revisit may lie from the graph's
    prediction after ``path`` metres between the two nodes, whatever the graph's σ:
    ``min_window`` + ``MAX_DRIFT_PER_METRE`` × ``path`` (m), capped by ``drift_window``."""
    if not (math.isfinite(path) and path >= 0):
        raise ValueError(f"path: must be finite and >= 0, got {path!r}")
    s = settings
    dt = min(s.min_window[0] + MAX_DRIFT_PER_METRE * path, s.drift_window[0])
    return max(dt, s.min_window[0]), max(s.drift_window[1], s.min_window[1])


def _rms_range(points: FloatArray) -> float:
    """Root-mean-square distance of ``points`` from the sensor (m)."""
    return float(np.sqrt(np.mean(np.sum(points * points, axis=1)))) if len(points) else 0.0


def _angle(pose: SE3) -> float:
    r = pose.rotation
    return float(np.arccos(np.clip((np.trace(r) - 1.0) / 2.0, -1.0, 1.0)))


def match_loop_3d(
    points: FloatArray,
    node: int,
    submap: Submap3D,
    predicted: SE3,
    relative_covariance: FloatArray,
    settings: LoopSettings3D,
    *,
    origin: LoopOrigin = "graph",
    score: float = math.nan,
    drift_window: tuple[float, float] | None = None,
) -> LoopMatch3D:
    """Match ``points`` (keyframe ``node``'s cloud, own frame) against ``submap``; the graph
    predicts ``T_submap_node`` as ``predicted`` with ``relative_covariance`` (6×6).

    ``origin="graph"`` starts GICP from the prediction; ``"place"`` from
    :func:`scanreg.register_global` (the candidate is rejected with its reasons when that
    finds no reliable alignment). ``score``: the place recognition's distance, recorded.
    ``drift_window``: ``(m, rad)`` the drift-independent window (:func:`drift_window_3d`);
    a match landing within it, sound on its own evidence and failing only the graph's σ
    window or χ² test, comes back as a ``hypothesis``; one beyond it is rejected. ``None``:
    the graph's tests decide alone (no hypothesis).
    """
    s = settings
    window = search_window_3d(relative_covariance, s)
    reasons: list[str] = []
    # The graph's own tests (σ window, χ²), which a drift beyond its belief fails.
    graph_reasons: list[str] = []
    start = predicted
    if origin == "place":
        glob = register_global(points, submap.points, voxel_size=s.global_voxel_size)
        if glob.pose is None:
            reasons.extend(f"global registration: {r}" for r in glob.reasons)
        else:
            start = glob.pose
    res = register(
        points,
        submap.target,
        method="gicp",
        init=start,
        max_correspondence_distance=s.max_correspondence_distance,
        kernel=s.kernel,
        max_iterations=s.max_iterations,
        thresholds=s.thresholds,
    )
    pose = res.pose
    assert isinstance(pose, SE3)
    verdict, quality = res.verdict, res.quality
    if verdict is not None:
        reasons.extend(verdict.reasons)
    overlap = float(quality.overlap) if quality is not None else math.nan
    offset = predicted.inverse() @ pose
    assert isinstance(offset, SE3)
    moved = float(np.linalg.norm(offset.translation))
    turned = _angle(offset)
    if moved > window[0]:
        graph_reasons.append(f"{moved:.2f} m from the graph's prediction > {window[0]:.2f} m")
    if turned > window[1]:
        graph_reasons.append(
            f"{math.degrees(turned):.1f} deg from the graph's prediction > "
            f"{math.degrees(window[1]):.1f} deg"
        )
    if drift_window is not None and (moved > drift_window[0] or turned > drift_window[1]):
        reasons.append(
            f"{moved:.2f} m, {math.degrees(turned):.1f} deg from the graph's prediction: "
            f"beyond the drift the path allows ({drift_window[0]:.2f} m, "
            f"{math.degrees(drift_window[1]):.1f} deg)"
        )
    st, sr = s.submap_sigma
    scale = _rms_range(points) / s.submap_sigma_range
    floor = np.diag([st**2] * 3 + [sr**2] * 3) * scale**2
    cov = np.array(res.covariance, dtype=np.float64) + floor
    combined = relative_covariance + cov
    if _well_posed(cov) and _well_posed(combined):
        info, weak, vectors = _information(cov, res)
        if len(weak) >= 6:
            reasons.append("degenerate in every direction")
        e = offset.log()
        chi2 = float(e @ np.linalg.solve(combined, e))
        if not chi2 <= s.chi2_threshold:
            graph_reasons.append(
                f"inconsistent with the graph: χ² {chi2:.1f} > {s.chi2_threshold:.1f}"
            )
    else:
        info, weak, vectors, chi2 = np.zeros((6, 6)), (), np.zeros((6, 0)), math.nan
        reasons.append("covariance singular or not finite")
    # The graph may be what is wrong (more drift than it knows): a match sound on its own
    # evidence waits for another loop to agree. Not a degenerate one: where it cannot fix
    # its own pose (a tunnel's axis), its look-alikes agree with each other as true ones do.
    hypothesis = drift_window is not None and bool(graph_reasons) and not reasons and not weak
    if hypothesis and origin == "graph":
        # Held without the graph's check, the match must be the only fit: GICP from a wrong
        # prediction settles in the nearest basin, and along a street of repeated façades
        # that is a look-alike whose neighbours' matches agree with it as true ones do (the
        # repeated block with the 25 m odometry's σ understated 30x: two loops 13 m along the
        # street closed so). Global registration, which refuses an ambiguous scene, must
        # find the same pose (a place candidate's start came from it already).
        glob = register_global(points, submap.points, voxel_size=s.global_voxel_size)
        if glob.pose is None:
            hypothesis = False
            reasons.extend(f"held, but global registration: {r}" for r in glob.reasons)
        else:
            gap = glob.pose.inverse() @ pose
            assert isinstance(gap, SE3)
            if np.linalg.norm(gap.translation) > s.min_window[0] or _angle(gap) > s.min_window[1]:
                hypothesis = False
                reasons.append(
                    f"held, but global registration finds a pose "
                    f"{np.linalg.norm(gap.translation):.2f} m, {math.degrees(_angle(gap)):.1f} "
                    "deg away"
                )
    reasons.extend(graph_reasons)
    return LoopMatch3D(
        submap_node=submap.anchor,
        node=node,
        predicted=predicted,
        measured=pose,
        window=window,
        score=float(score),
        overlap=overlap,
        chi2=chi2,
        covariance=cov,
        information=info,
        degenerate_directions=weak,
        weak_vectors=vectors,
        accepted=not reasons,
        reasons=tuple(reasons),
        origin=origin,
        hypothesis=hypothesis,
        evidence="" if reasons else "graph",
    )
