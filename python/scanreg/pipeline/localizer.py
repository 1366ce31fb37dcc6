"""Localization in a prior map: the odometry's machinery against a fixed map, no map updates.

``Localizer(map_points, config, initial_pose=guess)`` then :meth:`Localizer.step` per sweep,
exactly as :class:`~scanreg.Odometry` (predict, deskew, downsample, gate, align, judge) except
that the target is the prior map — a k-d tree with normals/covariances computed from the map's
own neighbourhoods — and nothing is inserted. Poses are ``T_map_sensor``.

``Localizer(map_points, config, method="ndt")`` aligns each sweep to the map by NDT-3D instead
(:func:`scanreg.match_ndt`, point to distribution, coarse to fine over ``ndt_cell_size·2`` and
``ndt_cell_size``; the map's Gaussians built once): Autoware's localizer. Its covariance is the
NDT's Fisher information inverted; the verdict is the same check against the map
(:func:`scanreg.verdict.assess`: overlap within the gate, residuals, convergence, motion from
the prediction); the frame's ``registration`` is then ``None`` and ``ndt`` holds the result.

A rough or lost pose is recovered with :meth:`Localizer.relocalize`: registrations from a grid
of hypotheses around the guess (headings all round, positions within a radius), the best by
overlap then refined, and judged like any frame — so a guess in the wrong place is *rejected*
(low overlap), not silently snapped to the nearest look-alike.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from .._validate import FloatArray, as_points, positive
from ..ndt import match_ndt, prepare_ndt
from ..preprocess import voxel_downsample
from ..register import RegistrationResult, RegistrationSettings, register
from ..target import prepare
from ..transform import SE3, as_pose
from ..verdict import assess
from .odometry import FAILED_STOPS, Aligned, FrameResult, Odometry, OdometryConfig, _se3

#: How each sweep is aligned to the map: the odometry's registration (``config.method``) or NDT.
LOCALIZER_METHODS = ("registration", "ndt")


@dataclasses.dataclass(frozen=True)
class Relocalization:
    """What :meth:`Localizer.relocalize` found."""

    #: The refined best hypothesis, judged against the map; the localizer now tracks from it
    #: when accepted.
    frame: FrameResult
    #: Hypotheses tried.
    num_hypotheses: int
    #: Overlap of the best and of the second-best distinct hypothesis (more than 2 m or 20°
    #: from the best): close values mean an ambiguous place (a corridor, a repeated structure).
    best_overlap: float
    runner_up_overlap: float


class Localizer(Odometry):
    """Track a sensor in a fixed prior map (see the module docstring).

    Parameters
    ----------
    map_points
        ``(M, 3)`` the prior map, in its own frame (downsampled here to half the voxel size).
    config
        The same :class:`~scanreg.OdometryConfig` as the odometry (its map fields are unused).
    initial_pose
        ``T_map_sensor`` to start tracking from (default identity); refine a rough one with
        :meth:`relocalize`.
    method
        ``"registration"`` (default): ``config.method`` against the map; ``"ndt"``: NDT-3D
        (the relocalization's search still registers point to point).
    ndt_cell_size
        Finest NDT voxel (m); the map is matched at twice it, then at it. Only with
        ``method="ndt"``.
    """

    def __init__(
        self,
        map_points: Any,
        config: OdometryConfig | None = None,
        *,
        initial_pose: Any = None,
        method: str = "registration",
        ndt_cell_size: float = 1.0,
    ) -> None:
        super().__init__(config, initial_pose=initial_pose)
        c = self.config
        if method not in LOCALIZER_METHODS:
            raise ValueError(
                f"method: unknown {method!r}; expected one of {', '.join(LOCALIZER_METHODS)}"
            )
        self.method = method
        raw = as_points(map_points, "map_points", dim=3, min_points=c.num_neighbors)
        # NDT keeps every map point: its voxel Gaussians need several points per cell.
        self.ndt_map = (
            prepare_ndt(raw, cell_size=positive(ndt_cell_size, "ndt_cell_size"), levels=2)
            if method == "ndt"
            else None
        )
        pts = voxel_downsample(raw, 0.5 * c.voxel_size).points
        self.prior_map = prepare(
            pts,
            normals=c.method == "point_to_plane",
            covariances=c.method == "gicp",
            num_neighbors=min(c.num_neighbors, len(pts)),
            # A map has no single viewpoint; normals' sign does not matter to the point-to-plane
            # residual.
        )
        self._target = self.prior_map
        self._builds_map = False

    def _align(
        self,
        source: FloatArray,
        prediction: SE3,
        settings: RegistrationSettings,
        init_covariance: FloatArray | None,
        source_covariances: FloatArray | None,
    ) -> Aligned:
        if self.ndt_map is None:
            return super()._align(source, prediction, settings, init_covariance, source_covariances)
        # match_ndt's own stopping rule, not the odometry's (1e-3): NDT's steps shrink where
        # its cost flattens, so a loose tolerance stopped it 0.34-0.38 m from the truth on the
        # simulated street (8 iterations) where 1e-5 reaches 0.3-0.5 mm (30-50).
        res = match_ndt(source, self.ndt_map, init=prediction)
        gate = settings.max_correspondence_distance
        judged = assess(
            res,
            source,
            self.prior_map,
            init=prediction,
            thresholds=dataclasses.replace(self._thresholds, overlap_gate=gate),
        )
        # NDT's "no_overlap" (no source point in any map cell) is the registration's failed
        # stop of the same meaning: the frame keeps the prediction.
        stop = "too_few_correspondences" if res.stop_reason == "no_overlap" else res.stop_reason
        return Aligned(
            pose=_se3(res.pose),
            covariance=res.covariance,
            stop_reason=stop,
            quality=judged.report,
            verdict=judged.verdict,
            registration=None,
            ndt=res,
        )

    def reset(self, pose: Any) -> None:
        """Forget the track and start again from ``pose`` (``T_map_sensor``)."""
        self._start = _se3(as_pose(pose, "pose", 3))
        self._poses.clear()
        self._stamps.clear()
        self._last_motion = SE3.identity()

    def relocalize(
        self,
        points: Any,
        guess: Any,
        *,
        radius: float = 4.0,
        spacing: float = 2.0,
        num_headings: int = 12,
        timestamps: Any = None,
        stamp: float | None = None,
    ) -> Relocalization:
        """Find the sweep in the map near ``guess`` (``T_map_sensor``), then track from there.

        Hypotheses: every ``360° / num_headings`` of heading about the map's z axis, at grid
        positions ``spacing`` apart within ``radius`` of the guess. Each is registered
        point-to-point (Geman–McClure, gate ``spacing``, a few iterations, on a coarse copy of
        the sweep); the one with the largest overlap is refined by :meth:`step` from a clean
        track. Rejected results leave the localizer where it was.
        """
        g = _se3(as_pose(guess, "guess", 3))
        if not (math.isfinite(radius) and radius >= 0):
            raise ValueError(f"radius: must be finite and >= 0, got {radius}")
        if not (math.isfinite(spacing) and spacing > 0):
            raise ValueError(f"spacing: must be finite and > 0, got {spacing}")
        if isinstance(num_headings, bool) or not isinstance(num_headings, int) or num_headings < 1:
            raise ValueError(f"num_headings: must be an int >= 1, got {num_headings!r}")
        c = self.config
        pts = as_points(points, "points", dim=3)
        coarse = voxel_downsample(pts, 2.0 * c.voxel_size).points
        steps = np.arange(-radius, radius + 1e-9, spacing)
        offsets = [(x, y) for x in steps for y in steps if math.hypot(x, y) <= radius + 1e-9]
        yaw0 = math.atan2(g.rotation[1, 0], g.rotation[0, 0])
        settings = RegistrationSettings(
            max_correspondence_distance=spacing,
            max_iterations=10,
            kernel="geman_mcclure",
            kernel_scale=spacing / 3.0,
            num_threads=c.num_threads,
        )
        scored: list[tuple[float, SE3, RegistrationResult]] = []
        for dx, dy in offsets:
            for h in range(num_headings):
                yaw = yaw0 + 2.0 * math.pi * h / num_headings
                rot = _yaw_matrix(yaw) @ _tilt(g)
                start = np.eye(4)
                start[:3, :3] = rot
                start[:3, 3] = g.translation + np.array([dx, dy, 0.0])
                res = register(
                    coarse, self.prior_map, method="point_to_point", init=start, settings=settings
                )
                if res.stop_reason in FAILED_STOPS:
                    continue
                assert res.quality is not None  # register() judged it from `start`
                scored.append((res.quality.overlap, _se3(res.pose), res))
        if not scored:
            raise ValueError("points: no hypothesis found correspondences in the map near guess")
        scored.sort(key=lambda s: -s[0])
        best_overlap, best_pose, _ = scored[0]
        runner_up = next(
            (
                o
                for o, p, _ in scored[1:]
                if np.linalg.norm(p.translation - best_pose.translation) > 2.0
                or _se3(best_pose.inverse() @ p).angle > math.radians(20.0)
            ),
            0.0,
        )
        saved = (self._start, list(self._poses), list(self._stamps), self._last_motion)
        self.reset(best_pose)
        frame = self.step(pts, timestamps, stamp=stamp)
        if not frame.verdict.accepted:
            self._start, self._poses, self._stamps, self._last_motion = saved
        return Relocalization(
            frame=frame,
            num_hypotheses=len(offsets) * num_headings,
            best_overlap=best_overlap,
            runner_up_overlap=runner_up,
        )


def _yaw_matrix(yaw: float) -> Any:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _tilt(pose: SE3) -> Any:
    """The roll/pitch part of ``pose``'s rotation (its yaw removed), kept for every heading."""
    r = pose.rotation
    yaw = math.atan2(r[1, 0], r[0, 0])
    return _yaw_matrix(-yaw) @ r


__all__ = ["Localizer", "Relocalization"]
