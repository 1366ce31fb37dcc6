"""2D localization in a fixed map: track a laser in a saved map without changing it, and find it
again, from no guess at all, when the track is lost (as Cartographer's and slam_toolbox's
localization modes do).

``Localizer2D(map_points)`` (or :meth:`Localizer2D.from_map_server` on a ``map.yaml`` + image
as ``scanreg map`` and ROS ``map_server`` write), then one :meth:`Localizer2D.step` per scan,
with the :class:`~scanreg.pipeline.Odometry2D` signature and its :class:`Frame2D` results:

1. **predict** — from the wheel-odometry ``prior`` when given, else constant velocity;
   before the first fix there is no prediction, and the scan is located globally (3.);
2. **track** — point-to-line :func:`scanreg.register` against the map from the prediction,
   judged by :func:`scanreg.verdict.assess`. With a ``prior`` and a wheel noise model
   (``config.wheel``) the prior is part of the solve: the prediction's covariance (the last
   pose's, carried through the wheels' step, plus the wheels' own, their distance scale
   learned online: :class:`~scanreg.pipeline.wheel.WheelOdometry`) is the registration's
   ``init_covariance``, so a step that slides along a corridor beyond it is rejected by the
   verdict, and along directions the map does not constrain the scan is held to the
   prediction (:func:`~scanreg.pipeline.odometry2d.hold_to_prediction`); the verdict and
   covariance are always those of the returned pose, the covariance with the map's own
   discretization added (:attr:`Localizer2D.map_spacing`: on the Intel log, 10.4 % of the
   accepted poses lay outside their covariance without it, and tracks whose next step moved
   2 cm were rejected as slid and lost to a global search);
3. **relocalize** — when there is no fix yet, or ``lost_after`` consecutive scans were
   rejected: :func:`scanreg.match_correlative` by branch and bound over the whole map (every
   position, every heading) on a coarse grid, the best refined by point-to-line and judged.
   The global search also reports the best candidate elsewhere (more than
   ``ambiguity_distance`` away): a runner-up scoring nearly as well is an ambiguous place,
   rejected with a reason rather than guessed.

Poses are ``T_map_scan``. The map is never modified.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .._validate import FloatArray, as_points, frozen
from ..correlative import CorrelativeGrid, match_correlative, prepare_correlative
from ..io.occupancy import read_map_server
from ..preprocess import DEFAULT_K
from ..register import RegistrationResult, register
from ..target import PreparedTarget, prepare
from ..transform import SE2, as_pose
from ..verdict import Verdict, VerdictThresholds, assess
from .odometry2d import (
    _FAILED,
    Frame2D,
    FrameTiming2D,
    _count,
    _hold,
    _positive,
    _without_default_probe,
    predicted_covariance,
)
from .wheel import WheelNoise, WheelOdometry

if TYPE_CHECKING:
    from ..saved_map import SavedMap


@dataclass(frozen=True)
class LocalizationConfig2D:
    """How :class:`Localizer2D` runs. Frozen; validated on construction. Metres, radians."""

    #: Point-to-line correspondence gate when tracking.
    max_correspondence_distance: float = 0.3
    kernel: str = "huber"
    max_iterations: int = 30
    #: Consecutive rejected scans after which the track is lost and the next scan is located
    #: globally.
    lost_after: int = 3
    #: Grid of the global search (coarser than tracking: the whole map is searched).
    global_resolution: float = 0.1
    #: A global fix is refused when another place, farther than ``ambiguity_distance``, scores
    #: at least ``ambiguity_ratio`` of the best.
    ambiguity_distance: float = 1.0
    ambiguity_ratio: float = 0.95
    #: The wheel odometry's noise model (see the module docstring), used when a ``prior`` is
    #: given; ``None``: the prior only starts the registration (its gate-wide prior judges
    #: how far it may move).
    wheel: WheelNoise | None = field(default_factory=WheelNoise)
    thresholds: VerdictThresholds = field(default_factory=VerdictThresholds)

    def __post_init__(self) -> None:
        _positive(self.max_correspondence_distance, "max_correspondence_distance")
        _count(self.max_iterations, "max_iterations", 1)
        _count(self.lost_after, "lost_after", 1)
        _positive(self.global_resolution, "global_resolution")
        _positive(self.ambiguity_distance, "ambiguity_distance")
        if self.wheel is not None and not isinstance(self.wheel, WheelNoise):
            raise TypeError(f"wheel: expected WheelNoise or None, got {type(self.wheel).__name__}")
        if not 0.0 < float(self.ambiguity_ratio) <= 1.0:
            raise ValueError(f"ambiguity_ratio: must be in (0, 1], got {self.ambiguity_ratio}")
        if not isinstance(self.thresholds, VerdictThresholds):
            raise TypeError(
                f"thresholds: expected VerdictThresholds, got {type(self.thresholds).__name__}"
            )


@dataclass(frozen=True)
class GlobalFix:
    """What a global search found (:meth:`Localizer2D.relocalize`)."""

    frame: Frame2D
    #: Correlative score of the best pose and of the best pose elsewhere.
    score: float
    runner_up_score: float
    search_seconds: float


class Localizer2D:
    """Track a 2D laser in a fixed map (see the module docstring).

    Parameters
    ----------
    map_points
        ``(M, 2)`` the map in its own frame (e.g. the occupied cells of a saved occupancy grid).
    config
        :class:`LocalizationConfig2D`.
    initial_pose
        ``T_map_scan`` of the first scan if known; ``None``: the first scan is located globally.
    """

    def __init__(
        self,
        map_points: Any,
        config: LocalizationConfig2D | None = None,
        *,
        initial_pose: Any = None,
    ) -> None:
        cfg = LocalizationConfig2D() if config is None else config
        if not isinstance(cfg, LocalizationConfig2D):
            raise TypeError(f"config: expected LocalizationConfig2D, got {type(cfg).__name__}")
        self.config = cfg
        # prepare() fits each map point's normal to its DEFAULT_K nearest neighbours.
        pts = as_points(map_points, "map_points", dim=2, min_points=DEFAULT_K)
        self.map_points = frozen(np.array(pts))
        self._target: PreparedTarget = prepare(self.map_points, normals=True)
        #: The map's point spacing (m): an occupancy grid's cell. A wall is known only to
        #: within it, by every one of its points alike, which the registration (the map's
        #: points taken as exact) does not see; each pose's covariance carries its variance,
        #: spacing² / 12 per axis of the translation (uniform over a cell).
        self.map_spacing = self._target.spacing
        self._grid: CorrelativeGrid | None = None  # the whole-map grid, built on first need
        self._pose: SE2 | None = (
            None if initial_pose is None else _se2(as_pose(initial_pose, "initial_pose", 2))
        )
        self._velocity = SE2.identity()
        self._rejected = 0
        self._index = 0
        self._wheels = None if cfg.wheel is None else WheelOdometry(cfg.wheel)
        #: Covariance of the tracked pose (over its tangent): the prediction's starting point.
        self._covariance: FloatArray = np.zeros((3, 3))

    @classmethod
    def from_map_server(
        cls, path: str | Path, config: LocalizationConfig2D | None = None, **kwargs: Any
    ) -> Localizer2D:
        """A localizer in the occupancy map ``path`` (``map.yaml``; :func:`read_map_server`)."""
        points, _ = read_map_server(path)
        return cls(points, config, **kwargs)

    @classmethod
    def from_saved_map(
        cls, saved: SavedMap, config: LocalizationConfig2D | None = None, **kwargs: Any
    ) -> Localizer2D:
        """A localizer in a 2D :class:`scanreg.SavedMap` (its occupancy grid's occupied
        cells), e.g. ``SavedMap.load("out/")`` of what ``scanreg map`` wrote."""
        from ..saved_map import SavedMap

        if not isinstance(saved, SavedMap):
            raise TypeError(f"saved: expected a SavedMap, got {type(saved).__name__}")
        if saved.dim != 2:
            raise ValueError(f"saved: a {saved.dim}D map; Localizer2D needs a 2D map")
        return cls(saved.occupied_points(), config, **kwargs)

    @property
    def pose(self) -> SE2 | None:
        """The latest ``T_map_scan`` (``None`` before the first fix)."""
        return self._pose

    def step(
        self,
        points: Any,
        timestamps: Any = None,
        prior: Any = None,
        *,
        stamp: float | None = None,
    ) -> Frame2D:
        """Locate one scan (``(N, 2)``, scan frame) in the map; the :class:`Odometry2D` call."""
        t_start = time.perf_counter()
        pts = as_points(points, "points", dim=2, min_points=3)
        if timestamps is not None:
            raise ValueError("timestamps: a 2D scan is taken as instantaneous; pass None")
        motion = None if prior is None else _se2(as_pose(prior, "prior", 2))
        index = self._index
        self._index += 1
        lost = self._pose is None or self._rejected >= self.config.lost_after
        if lost:
            fix = self.relocalize(pts, stamp=stamp, index=index)
            return fix.frame
        assert self._pose is not None
        previous = self._pose
        step_cov = None
        if motion is not None:
            step = motion
            if self._wheels is not None:
                step, step_cov = self._wheels.prior(motion)
            predicted, how = previous @ step, "prior"
        else:
            step = self._velocity
            predicted, how = previous @ step, "constant_velocity"
        predicted = predicted.orthonormalized()  # see Odometry2D.step: held frames feed it back
        predicted_cov = None
        if step_cov is not None:
            predicted_cov = predicted_covariance(self._covariance, step, step_cov)
        t0 = time.perf_counter()
        res = self._register(pts, predicted, predicted_cov)
        held: tuple[str, ...] = ()
        if predicted_cov is not None and res.stop_reason not in _FAILED:
            # Along a corridor the map pins the scan only weakly and point-to-line slides
            # (Intel: tracks accepted 0.2-0.5 m off the wheels' step, ending 1-14 m from the
            # mapped pose): there the prediction holds.
            res, held, _ = _hold(res, pts, self._target, predicted, predicted_cov, self.config)
        t_align = time.perf_counter() - t0
        frame = self._judged(
            pts, res, predicted, how, index, stamp, t_start, t_align, held_directions=held
        )
        if motion is not None and self._wheels is not None:
            pinned = frame.verdict.accepted and not held and not frame.degenerate
            self._wheels.observe(motion, previous.inverse() @ frame.pose, constrained=pinned)
        if frame.verdict.accepted:
            self._velocity = previous.inverse() @ frame.pose
            self._pose = frame.pose
            self._covariance = _finite_or_zero(frame.covariance)
            self._rejected = 0
        else:
            self._pose = predicted  # dead-reckon on the prediction until found again
            self._covariance = _finite_or_zero(
                np.zeros((3, 3)) if predicted_cov is None else predicted_cov
            )
            self._rejected += 1
        return frame

    def relocalize(
        self, points: Any, *, stamp: float | None = None, index: int | None = None
    ) -> GlobalFix:
        """Locate ``points`` anywhere in the map, at any heading (branch and bound), refine and
        judge it; an accepted fix becomes the tracked pose."""
        cfg = self.config
        t_start = time.perf_counter()
        pts = as_points(points, "points", dim=2, min_points=3)
        if self._grid is None:
            self._grid = prepare_correlative(self.map_points, resolution=cfg.global_resolution)
        lo, hi = self.map_points.min(axis=0), self.map_points.max(axis=0)
        centre = 0.5 * (lo + hi)
        half = 0.5 * (hi - lo) + cfg.global_resolution
        t0 = time.perf_counter()
        window = (float(half[0]), float(half[1]), math.pi)
        best = match_correlative(
            pts, self._grid, init=SE2.from_vector([centre[0], centre[1], 0.0]), window=window
        )
        runner_up = self._runner_up(pts, best.pose)
        search = time.perf_counter() - t0
        res = self._register(pts, best.pose)
        t_align = time.perf_counter() - t_start
        frame = self._judged(
            pts,
            res,
            best.pose,
            "global",
            self._index - 1 if index is None else index,
            stamp,
            t_start,
            t_align,
        )
        score = float(best.score)
        ambiguous = runner_up >= cfg.ambiguity_ratio * score
        if ambiguous:
            reason = (
                f"ambiguous: another place scores {runner_up:.2f} against {score:.2f} "
                f"(>= {cfg.ambiguity_ratio:.2f} of it)"
            )
            verdict = Verdict(accepted=False, reasons=(*frame.verdict.reasons, reason))
            frame = _replace_verdict(frame, verdict)
        if frame.verdict.accepted:
            self._pose = frame.pose
            self._velocity = SE2.identity()
            self._covariance = _finite_or_zero(frame.covariance)
            self._rejected = 0
        return GlobalFix(frame=frame, score=score, runner_up_score=runner_up, search_seconds=search)

    def _runner_up(self, pts: FloatArray, best: SE2) -> float:
        """The best correlative score found at least ``ambiguity_distance`` from ``best``: one
        branch and bound per quadrant of the map (every heading), each keeping its own best.
        A quadrant whose best is ``best`` itself says nothing (an alternative there scoring
        just below it is missed): an approximation that catches distinct places elsewhere."""
        assert self._grid is not None
        cfg = self.config
        lo, hi = self.map_points.min(axis=0), self.map_points.max(axis=0)
        top = 0.0
        for qx in (0, 1):
            for qy in (0, 1):
                a = lo + (hi - lo) * np.array([qx, qy]) / 2.0
                b = a + (hi - lo) / 2.0
                centre = 0.5 * (a + b)
                half = 0.5 * (b - a) + cfg.global_resolution
                res = match_correlative(
                    pts,
                    self._grid,
                    init=SE2.from_vector([centre[0], centre[1], 0.0]),
                    window=(float(half[0]), float(half[1]), math.pi),
                )
                if np.linalg.norm(res.pose.translation - best.translation) > (
                    cfg.ambiguity_distance
                ):
                    top = max(top, float(res.score))
        return top

    def _register(
        self, pts: FloatArray, start: SE2, start_covariance: FloatArray | None = None
    ) -> RegistrationResult:
        cfg = self.config
        return register(
            pts,
            self._target,
            method="point_to_line",
            init=start,
            # The prediction's own spread, when known: the verdict's motion check rejects a
            # step that slid beyond it (else the gate-wide prior).
            init_covariance=start_covariance,
            # Its own correlative search recovers a lost track (global fixes, the ambiguity
            # test); a grid of the whole map per target would not pay here.
            search_start=False,
            max_correspondence_distance=cfg.max_correspondence_distance,
            kernel=cfg.kernel,
            max_iterations=cfg.max_iterations,
            # Its own ambiguity test runs on the map; the basin probe would build a correlative
            # grid of the whole map per frame.
            thresholds=_without_default_probe(cfg.thresholds),
        )

    def _with_map_spacing(self, covariance: Any) -> FloatArray:
        """``covariance`` plus the map's own discretization (:attr:`map_spacing`)."""
        out = np.array(covariance, dtype=np.float64)
        out[:2, :2] += np.eye(2) * self.map_spacing**2 / 12.0
        return out

    def _judged(
        self,
        pts: FloatArray,
        res: RegistrationResult,
        predicted: SE2,
        how: str,
        index: int,
        stamp: float | None,
        t_start: float,
        t_align: float,
        held_directions: tuple[str, ...] = (),
    ) -> Frame2D:
        t0 = time.perf_counter()
        th = self.config.thresholds
        if held_directions:
            # Held to the prediction along its weak directions: that is how the weakness was
            # handled, not a reason to reject the pose (a corridor step held to the wheels is
            # the best estimate there is), as the 3D odometry's held frames.
            th = dataclasses.replace(th, reject_degenerate=False)
        out = assess(res, pts, self._target, init=predicted, thresholds=th)
        t_judge = time.perf_counter() - t0
        pose = res.pose
        assert isinstance(pose, SE2)
        previous = self._pose if self._pose is not None else pose
        return Frame2D(
            index=index,
            stamp=None if stamp is None else float(stamp),
            pose=pose,
            motion=previous.inverse() @ pose,
            prediction=predicted,
            prediction_source=how,
            covariance=frozen(self._with_map_spacing(res.covariance)),
            verdict=out.verdict,
            quality=out.report,
            registration=res,
            num_source_points=int(pts.shape[0]),
            num_map_points=int(self.map_points.shape[0]),
            map_updated=False,
            timing=FrameTiming2D(
                align=t_align, judge=t_judge, map_update=0.0, total=time.perf_counter() - t_start
            ),
            held_directions=held_directions,
        )


def _se2(pose: Any) -> SE2:
    assert isinstance(pose, SE2)
    return pose


def _finite_or_zero(cov: Any) -> FloatArray:
    """``cov`` as a float array when finite, else zeros (nothing known to carry)."""
    out = np.array(cov, dtype=np.float64)
    return out if np.isfinite(out).all() else np.zeros((3, 3))


def _replace_verdict(frame: Frame2D, verdict: Verdict) -> Frame2D:
    return dataclasses.replace(frame, verdict=verdict)


__all__ = ["GlobalFix", "LocalizationConfig2D", "Localizer2D", "read_map_server"]
