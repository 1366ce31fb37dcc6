"""2D scan-to-map odometry: each scan registered against a bounded local map of recent keyframes.

One :meth:`Odometry2D.step` per scan, in four stages:

1. **predict** — ``T_world_scan`` of the new scan from the wheel-odometry ``prior`` (motion from
   the previous scan to this one) when given, else constant velocity (the last estimated motion
   repeated);
2. **align** — against the local map: ``"icp"`` is point-to-line :func:`scanreg.register` from
   the prediction; ``"correlative"`` is :func:`scanreg.match_correlative` (branch and bound over
   a window around the prediction) followed by the same point-to-line refinement;
3. **judge** — :func:`scanreg.verdict.assess` of the point-to-line result against the map
   (a frame whose refinement ran off its correlative start keeps that start, and is rejected:
   the verdict was the refinement's; a frame rejected for sliding beyond the uncertainty of its
   start keeps that start, as a failed alignment does);
4. **update** — the scan becomes a keyframe (its points, in the world frame, join the map) when
   it has moved more than ``keyframe_distance`` or turned more than ``keyframe_angle`` since the
   last keyframe and its alignment was not a failure (nor a slide whose start was kept) and
   overlapped the map — or, whatever its verdict, once it has moved three times that far
   without one: a map left behind would never be overlapped again (a lost robot would stay
   lost). The map holds the last ``max_keyframes`` keyframes, voxel-downsampled to
   ``map_voxel_size``. A keyframe updates it in the core
   (:class:`scanreg._core.KeyframeMap`): only the voxels the new keyframe and the evicted one
   touch get a new centroid, and only normals whose neighbourhood holds a changed point are
   computed again — the same map, normals, normal noise and point spacing as downsampling and
   :func:`scanreg.prepare` of the window from scratch, at about half the cost on the Intel log
   (the k-d tree is rebuilt).
   The correlative grid is brought up to date, in place, when next needed
   (:meth:`scanreg.CorrelativeGrid.updated`): only the cells near the occupied cells the
   keyframe added or the evicted one took away are rasterised again, and its pooled levels
   pooled again only where those changed — the grid a build from scratch gives, to the bit.

Poses are ``T_world_scan`` with the world frame that of the first scan.
"""

from __future__ import annotations

import collections
import dataclasses
import math
import time
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from .. import _core
from .._validate import FloatArray, as_covariance, as_matrix, as_points, frozen
from ..correlative import (
    CorrelativeGrid,
    best_correlative_pose,
    match_correlative,
    prepare_correlative,
)
from ..deskew import deskew, velocity_from_motion
from ..preprocess import DEFAULT_K, voxel_downsample
from ..register import RegistrationResult, register
from ..target import PreparedTarget, prepared_from_normals
from ..transform import SE2, as_pose
from ..verdict import Assessment, QualityReport, Verdict, VerdictThresholds, assess

FrontEnd = Literal["icp", "correlative"]
FRONT_ENDS: tuple[str, ...] = ("icp", "correlative")
#: What a step's ``prior_covariance`` does (:attr:`OdometryConfig2D.prior_covariance_use`).
PriorUse = Literal["solve", "search"]
PRIOR_USES: tuple[str, ...] = ("solve", "search")
ROBUST_KERNELS: tuple[str, ...] = ("none", "huber", "cauchy", "tukey", "geman_mcclure", "welsch")

#: The odometry keeps its own guards (the basin probe, the slide test against the prediction)
#: and not register's never-worse-than-the-start rerun: with it, on the Intel subset the
#: correlative front end's local error went 0.0163 -> 0.0174 m, and on the simulated ring lap
#: of tests/test_mapping.py the constant-velocity prediction then missed the turn and the
#: odometry lost track (the start a rerun returns is the prediction, not the scan's pose).
_NEVER_WORSE = False


def _positive(value: Any, name: str, *, allow_zero: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name}: expected a number, got {type(value).__name__}")
    v = float(value)
    if not math.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        bound = ">= 0" if allow_zero else "> 0"
        raise ValueError(f"{name}: must be finite and {bound}, got {value!r}")
    return v


def _count(value: Any, name: str, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"{name}: expected an int, got {type(value).__name__}")
    if int(value) < minimum:
        raise ValueError(f"{name}: must be >= {minimum}, got {value!r}")
    return int(value)


@dataclass(frozen=True)
class OdometryConfig2D:
    """How :class:`Odometry2D` runs. Frozen; validated on construction (errors name the field).

    Distances in metres, angles in radians.
    """

    #: ``"icp"`` (point-to-line from the prediction) or ``"correlative"`` (correlative search
    #: around the prediction, then point-to-line refinement).
    front_end: FrontEnd = "icp"
    #: Point-to-line correspondence gate.
    max_correspondence_distance: float = 0.3
    #: Robust kernel of the point-to-line step (scale: a third of the gate).
    kernel: str = "huber"
    max_iterations: int = 30
    #: Scan points are voxel-downsampled to this before alignment (``0``: not at all).
    scan_voxel_size: float = 0.0
    #: Keyframe policy: a scan joins the map after moving this far ...
    keyframe_distance: float = 0.3
    #: ... or turning this much since the last keyframe.
    keyframe_angle: float = math.radians(10.0)
    #: The map holds this many most recent keyframes.
    max_keyframes: int = 20
    #: The map's accumulated points are voxel-downsampled to this (``0``: not at all).
    map_voxel_size: float = 0.05
    #: Correlative front end: search half-widths (dx, dy, dθ) around the prediction (around
    #: constant velocity, without a prior, widened by the last motion: the robot may have
    #: stopped, or turned as much again) ...
    correlative_window: tuple[float, float, float] = (0.3, 0.3, math.radians(10.0))
    #: ... and grid resolution.
    correlative_resolution: float = 0.05
    #: A point-to-line result moving further than this (m) from where it started (the
    #: prediction, or the correlative pose) is discarded and its start kept. ``None``: 0.15 m
    #: (three 5 cm cells) for the correlative front end, no limit for the ICP front end.
    max_refinement_step: float | None = None
    #: Verdict thresholds (gate: the point-to-line gate).
    thresholds: VerdictThresholds = field(default_factory=VerdictThresholds)
    #: What a step's ``prior_covariance`` does: ``"solve"`` — the prior is part of the solve
    #: (directions the scan leaves open are held to the prediction, :func:`hold_to_prediction`);
    #: ``"search"`` — it only ranks the correlative front end's candidates, as a motion cost
    #: (:func:`scanreg.match_correlative`'s ``init_covariance``; positive definite), so that of
    #: two poses the scan supports about equally the one nearer the prediction is refined,
    #: while the refinement, verdict and covariance stay the scan's own.
    prior_covariance_use: PriorUse = "solve"
    #: How long one scan's sweep takes (s), for scans without per-beam time (``step`` then
    #: needs ``stamp``): the prediction's motion between the scans, scaled to this duration,
    #: is the registration's ``sweep_motion``, so the covariance covers what the sweep's
    #: distortion does to the pose while turning fast (:class:`~scanreg.RegistrationSettings`).
    #: ``0``: scans taken as instantaneous.
    sweep_duration: float = 0.0

    def __post_init__(self) -> None:
        if self.front_end not in FRONT_ENDS:
            raise ValueError(
                f"front_end: unknown {self.front_end!r}; expected one of {', '.join(FRONT_ENDS)}"
            )
        _positive(self.max_correspondence_distance, "max_correspondence_distance")
        if not isinstance(self.kernel, str):
            raise TypeError(f"kernel: expected a str, got {type(self.kernel).__name__}")
        if self.kernel not in ROBUST_KERNELS:
            raise ValueError(
                f"kernel: unknown {self.kernel!r}; expected one of {', '.join(ROBUST_KERNELS)}"
            )
        _count(self.max_iterations, "max_iterations", 1)
        _positive(self.scan_voxel_size, "scan_voxel_size", allow_zero=True)
        _positive(self.keyframe_distance, "keyframe_distance", allow_zero=True)
        _positive(self.keyframe_angle, "keyframe_angle", allow_zero=True)
        _count(self.max_keyframes, "max_keyframes", 1)
        _positive(self.map_voxel_size, "map_voxel_size", allow_zero=True)
        w = self.correlative_window
        if not isinstance(w, tuple) or len(w) != 3:
            raise ValueError(f"correlative_window: expected (dx, dy, dθ), got {w!r}")
        for i, v in enumerate(w):
            _positive(v, f"correlative_window[{i}]", allow_zero=True)
        _positive(self.correlative_resolution, "correlative_resolution")
        _positive(self.sweep_duration, "sweep_duration", allow_zero=True)
        step = self.max_refinement_step
        if step is not None and not (isinstance(step, float) and step == math.inf):
            _positive(step, "max_refinement_step")
        if self.prior_covariance_use not in PRIOR_USES:
            raise ValueError(
                f"prior_covariance_use: unknown {self.prior_covariance_use!r}; expected one of "
                f"{', '.join(PRIOR_USES)}"
            )
        if not isinstance(self.thresholds, VerdictThresholds):
            raise TypeError(
                f"thresholds: expected VerdictThresholds, got {type(self.thresholds).__name__}"
            )


@dataclass(frozen=True)
class FrameTiming2D:
    """Wall-clock seconds of one :meth:`Odometry2D.step`."""

    align: float
    judge: float
    map_update: float
    total: float


@dataclass(frozen=True)
class Frame2D:
    """The outcome of one :meth:`Odometry2D.step`; the same fields as the 3D
    :class:`~scanreg.FrameResult` (SE2 poses, 3×3 covariances)."""

    index: int
    #: The scan's time (s) as passed to ``step(..., stamp=...)``, or ``None``.
    stamp: float | None
    #: ``T_world_scan``.
    pose: SE2
    #: ``T_prev_curr``: this scan's motion since the previous one (identity for the first).
    motion: SE2
    #: Where the prediction put the scan (``T_world_scan``); the alignment starts here.
    prediction: SE2
    #: ``"prior"``, ``"constant_velocity"`` or ``"first"``.
    prediction_source: str
    #: 3×3 over the right-perturbation tangent [ρx, ρy, θ] of ``pose`` given the map (the
    #: point-to-line covariance against it); zeros for the first scan, which defines the map
    #: frame.
    covariance: FloatArray
    verdict: Verdict
    #: ``None`` for the first scan (nothing to align to).
    quality: QualityReport | None
    #: The point-to-line registration against the map (``None`` for the first scan).
    registration: RegistrationResult | None
    #: Points aligned (after ``scan_voxel_size``).
    num_source_points: int
    #: Map size after this scan's update.
    num_map_points: int
    #: Whether the scan joined the map (as a keyframe).
    map_updated: bool
    timing: FrameTiming2D
    #: Directions held to the prediction (with a ``prior_covariance``: the weak directions of
    #: the registration, :func:`hold_to_prediction`); empty otherwise.
    held_directions: tuple[str, ...] = ()
    #: The ICP front end's first result was rejected as a wrong basin or as a slide beyond
    #: the prediction's uncertainty (with ``thresholds.basin_probe=True``) and the scan was
    #: registered again from the probe's better pose or a correlative search over every
    #: heading (:mod:`scanreg.basin`).
    basin_fallback: bool = False
    #: The map had been left behind (no keyframe for three keyframe spacings) and this scan
    #: joined it whatever its verdict: the odometry went on from its best guess here.
    map_reseeded: bool = False
    #: The scan's points re-expressed at ``stamp`` (``step``'s ``timestamps``: deskewed, before
    #: ``scan_voxel_size``); ``None`` when the scan came without per-point times.
    deskewed: FloatArray | None = field(default=None, repr=False)

    @property
    def degenerate(self) -> bool:
        """Whether the registration named weak directions (:class:`~scanreg.Degeneracy`)."""
        reg = self.registration
        deg = None if reg is None else reg.degeneracy
        return bool(deg is not None and deg.degenerate)


class Odometry2D:
    """2D scan-to-map odometry (see the module docstring).

    >>> odo = Odometry2D(OdometryConfig2D(front_end="icp"))
    >>> frame = odo.step(points)                     # (N, 2) float64, scan frame
    >>> frame = odo.step(points, prior=motion)       # SE2 T_prev_curr from wheel odometry
    >>> frame = odo.step(points, stamp=t)            # the scan's time (s), non-decreasing
    """

    def __init__(self, config: OdometryConfig2D | None = None) -> None:
        cfg = OdometryConfig2D() if config is None else config
        if not isinstance(cfg, OdometryConfig2D):
            raise TypeError(f"config: expected OdometryConfig2D, got {type(cfg).__name__}")
        self.config = cfg
        self._num_neighbors = DEFAULT_K
        self._register_thresholds = _without_default_probe(cfg.thresholds)
        self._map = _core.KeyframeMap(
            2, cfg.map_voxel_size, DEFAULT_K, cfg.max_keyframes, np.zeros(2)
        )
        self._last_keyframe: SE2 | None = None
        #: Each keyframe in the map's window (the same ``max_keyframes``), how it was swept:
        #: its sweep motion (``OdometryConfig2D.sweep_duration``; zero when not known, the
        #: first scan's) and its pose in the map, ``(x, y, θ)``.
        self._keyframe_sweeps: collections.deque[
            tuple[tuple[float, float, float], tuple[float, float, float]]
        ] = collections.deque(maxlen=cfg.max_keyframes)
        self._pose: SE2 | None = None
        self._velocity = SE2.identity()
        self._target: PreparedTarget | None = None
        self._grid: CorrelativeGrid | None = None
        #: The map changed since ``_grid`` was made (:meth:`_correlative_grid`).
        self._grid_stale = False
        self._map_points: FloatArray | None = None
        self._index = 0
        self._last_time: float | None = None
        #: Covariance of the latest pose (zeros: the first scan defines the map frame).
        self._covariance: FloatArray = np.zeros((3, 3))

    @property
    def pose(self) -> SE2 | None:
        """The latest ``T_world_scan`` (``None`` before the first step)."""
        return self._pose

    @property
    def map_points(self) -> FloatArray | None:
        """The local map, ``(M, 2)`` world-frame points (read-only)."""
        return self._map_points

    def _add_keyframe(
        self, points: FloatArray, pose: SE2, sweep: tuple[float, float, float] | None = None
    ) -> None:
        # The map is updated, not rebuilt: only the voxels this keyframe and the one it
        # evicts touch get a new centroid and normal (scanreg._core.KeyframeMap).
        # The map also knows each point's nearest neighbour, hence the target's spacing (the
        # trust analysis's sampling-density ratio reads it), without a 2-NN search of its own.
        index, normals, valid, noise, spacing, _ = self._map.insert(pose.apply(points))
        self._last_keyframe = pose
        x, y, theta = pose.as_vector()
        self._keyframe_sweeps.append(
            ((0.0, 0.0, 0.0) if sweep is None else sweep, (float(x), float(y), float(theta)))
        )
        self._target = prepared_from_normals(
            index, normals, valid, self._num_neighbors, noise, spacing
        )
        self._map_points = self._target.points
        self._grid_stale = True

    def _correlative_grid(self) -> CorrelativeGrid:
        """The local map's correlative grid: built on first use, then updated where the
        keyframes since changed it (the same grid as a build from scratch)."""
        assert self._map_points is not None
        if self._grid is None:
            self._grid = prepare_correlative(
                self._map_points, resolution=self.config.correlative_resolution
            )
        elif self._grid_stale:
            # In place: no one else holds the odometry's grid.
            self._grid = self._grid.updated(self._map_points, in_place=True)
        self._grid_stale = False
        return self._grid

    def _map_sweep(self) -> dict[str, Any]:
        """The map's sweeps for :func:`scanreg.register` (``OdometryConfig2D.sweep_duration``):
        the map blends its keyframes, each swept at its own rate and heading from its own
        pose, and which of them laid the points the scan matches is not known
        (``target_sweeps``: the covariance takes the mean of their distortion terms). On
        turning drives whose keyframes change every frame the last keyframe's term alone
        (the freshest points) covered the frame's error at mean NEES 7.0, the mean over the
        window's at 3.4 (``benchmarks/sweep_distortion.py --odometry``). Nothing without a
        sweep duration or before any keyframe's sweep is known."""
        if self.config.sweep_duration <= 0 or not any(
            any(motion) for motion, _ in self._keyframe_sweeps
        ):
            return {}
        return {"target_sweeps": tuple(self._keyframe_sweeps)}

    def step(
        self,
        points: Any,
        timestamps: Any = None,
        prior: Any = None,
        *,
        stamp: float | None = None,
        prior_covariance: Any = None,
    ) -> Frame2D:
        """Register one scan to the local map; the signature of :meth:`scanreg.Odometry.step`.

        Parameters
        ----------
        points
            ``(N, 2)`` points in the scan's own frame (metres).
        timestamps
            ``(N,)`` each point's time (s, on the clock of ``stamp``, which is then required),
            or ``None`` (the scan taken as instantaneous). With them the scan is deskewed
            before it is registered: every point re-expressed in the scan's frame at
            ``stamp`` under the predicted motion (the prior, or the last motion) spread evenly
            over the time since the previous scan (:func:`scanreg.deskew`), as the 3D
            odometry does; the frame's ``deskewed`` holds the result. The first scan, whose
            motion is not known, is kept as it is.
        prior
            ``T_prev_curr`` motion from wheel odometry (``SE2`` or ``3x3``), used as the
            prediction instead of constant velocity.
        stamp
            The scan's time (s); must not decrease from scan to scan.
        prior_covariance
            ``(3, 3)`` covariance of ``prior`` over its right-perturbation tangent (a wheel
            noise model: :class:`~scanreg.pipeline.wheel.WheelNoise`). With it the prior is
            part of the solve: where the registration names directions the map does not
            constrain (a corridor's axis), the scan is registered again held to the
            prediction along them (:func:`hold_to_prediction`), so there the wheels decide
            and elsewhere the scan; the frame's verdict and covariance are those of the held
            registration (the prediction's variance along the held directions: the previous
            pose's, carried through the motion, plus ``prior_covariance``), and
            ``held_directions`` names them. ``None``: the prior only starts the search.
            With ``config.prior_covariance_use="search"`` it instead only ranks the
            correlative front end's candidates (a motion cost; nothing is held).
        """
        t_start = time.perf_counter()
        pts = as_points(points, "points", dim=2)
        if pts.shape[0] < 3:
            raise ValueError(f"points: need at least 3 points, got {pts.shape[0]}")
        times = None if timestamps is None else as_matrix(timestamps, "timestamps", (len(pts),))
        if times is not None and stamp is None:
            raise ValueError("stamp: required with timestamps (the time the scan is deskewed to)")
        if stamp is not None:
            if isinstance(stamp, bool) or not isinstance(
                stamp, (int, float, np.integer, np.floating)
            ):
                raise TypeError(f"stamp: expected a number, got {type(stamp).__name__}")
            if not math.isfinite(float(stamp)):
                raise ValueError(f"stamp: must be finite, got {stamp!r}")
            if self._last_time is not None and float(stamp) < self._last_time:
                raise ValueError(
                    f"stamp: {stamp} is earlier than the previous scan's {self._last_time}"
                )
        motion = None if prior is None else as_pose(prior, "prior", 2)
        assert motion is None or isinstance(motion, SE2)
        cfg = self.config
        if cfg.sweep_duration > 0 and stamp is None:
            raise ValueError("stamp: required with config.sweep_duration > 0 (the turn rate)")
        previous_time = self._last_time
        search = cfg.prior_covariance_use == "search"
        prior_cov = _checked_prior_covariance(prior_covariance, motion, definite=search)
        search_cov = prior_cov if search else None
        if search:
            prior_cov = None
        deskewed = None
        if times is not None:
            assert stamp is not None  # (checked above)
            pts = deskewed = self._deskewed(pts, times, motion, float(stamp), previous_time)
        if cfg.scan_voxel_size > 0:
            pts = np.ascontiguousarray(voxel_downsample(pts, cfg.scan_voxel_size).points)
        index = self._index
        self._index += 1
        if stamp is not None:
            self._last_time = float(stamp)

        if self._pose is None:
            pose = SE2.identity()
            self._pose = pose
            t0 = time.perf_counter()
            self._add_keyframe(pts, pose)
            t_map = time.perf_counter() - t0
            assert self._map_points is not None
            return Frame2D(
                index=index,
                stamp=None if stamp is None else float(stamp),
                pose=pose,
                motion=SE2.identity(),
                prediction=pose,
                prediction_source="first",
                covariance=frozen(np.zeros((3, 3))),
                verdict=Verdict(accepted=True),
                quality=None,
                registration=None,
                num_source_points=int(pts.shape[0]),
                num_map_points=int(self._map_points.shape[0]),
                map_updated=True,
                timing=FrameTiming2D(
                    align=0.0, judge=0.0, map_update=t_map, total=time.perf_counter() - t_start
                ),
                deskewed=deskewed,
            )

        # 1. predict
        previous = self._pose
        if motion is not None:
            predicted = previous @ motion
            how = "prior"
        else:
            predicted = previous @ self._velocity
            how = "constant_velocity"
        # A held frame keeps its prediction, which feeds the next velocity: clean the rotation
        # or its round-off grows geometrically over a run of held frames.
        predicted = predicted.orthonormalized()
        assert isinstance(predicted, SE2)
        assert self._target is not None and self._map_points is not None
        # (a deskewed scan's sweep is undone; the sweep term is for scans without beam times)
        sweep = None
        if times is None:
            sweep = _sweep_motion(
                motion if motion is not None else self._velocity, stamp, previous_time, cfg
            )

        # 2. align
        t0 = time.perf_counter()
        start = predicted
        if cfg.front_end == "correlative":
            grid = self._correlative_grid()
            # With a motion cost the lattice's candidates are ranked by their posterior: of
            # two that the scan scores about alike (a corridor's axis, a repeated doorway)
            # the one the wheels' step supports wins; a clearly better basin still does.
            # Only the pose is read (the refinement gives the frame's covariance): neither
            # Olson's covariance nor the result's statistics are computed.
            window = _search_window(cfg.correlative_window, motion, self._velocity)
            start = best_correlative_pose(pts, grid, predicted, window, search_cov)
        target, map_sweep = self._target, self._map_sweep()

        def refine(init: SE2) -> RegistrationResult:
            return register(
                pts,
                target,
                method="point_to_line",
                init=init,
                max_correspondence_distance=cfg.max_correspondence_distance,
                kernel=cfg.kernel,
                max_iterations=cfg.max_iterations,
                thresholds=self._register_thresholds,
                never_worse_than_start=_NEVER_WORSE,
                sweep_motion=sweep,
                **map_sweep,
            )

        res = refine(start)
        fallback = False
        probe = None if res.quality is None else res.quality.basin
        reasons = () if res.verdict is None else res.verdict.reasons
        wrong_basin = any(r.startswith("wrong basin:") for r in reasons)
        slid = any(r.startswith("slid beyond") for r in reasons)
        if cfg.front_end == "icp" and cfg.thresholds.basin_probe and (wrong_basin or slid):
            # Rejected as a wrong basin (the probe found a pose that explains the scan clearly
            # better) or slid beyond the prediction's uncertainty: start again from the
            # probe's pose, or from a correlative search around the prediction over every
            # heading, rather than keep a pose the verdict rejected.
            if wrong_basin and probe is not None and isinstance(probe.alternative, SE2):
                start = probe.alternative
            else:
                gate = cfg.max_correspondence_distance
                start = match_correlative(
                    pts,
                    self._correlative_grid(),
                    init=predicted,
                    window=(2.0 * gate, 2.0 * gate, math.pi),
                    angular_resolution=math.radians(1.0),
                    search="branch_and_bound",
                ).pose
            fallback = True
            res = refine(start)
        held: tuple[str, ...] = ()
        # (With the wheels as a motion cost only, a degenerate result is not held: held to the
        # correlative start, the ring corridor's stuck start was fixed but five Radish logs
        # and the Freiburg hospital's odometry mapped worse; benchmarks/README.md,
        # simulated_buildings.py.)
        if prior_cov is not None and motion is not None and res.stop_reason not in _FAILED:
            predicted_cov = predicted_covariance(self._covariance, motion, prior_cov)
            res, held, held_start = _hold(
                res, pts, self._target, predicted, predicted_cov, cfg, sweep, self._map_sweep()
            )
            if held:
                start = held_start
        t_align = time.perf_counter() - t0
        pose = _accepted_pose(res, start, cfg)

        # 3. judge
        t0 = time.perf_counter()
        if not held and start is predicted and res.quality is not None and res.verdict is not None:
            # Registered from the prediction itself, with thresholds that differ from the
            # pipeline's at most in whether the probe runs (which judging does not read): the
            # registration's own verdict is the one ``assess`` would give (the same overlap
            # pass, degeneracy, motion χ² and probe), without a second overlap pass.
            out = Assessment(report=res.quality, verdict=res.verdict)
        else:
            # A frame held to its prediction along its weak directions is not rejected for
            # them (that is how the weakness was handled), as the 3D odometry's held frames.
            th = cfg.thresholds
            if held:
                th = dataclasses.replace(th, reject_degenerate=False)
            out = assess(res, pts, self._target, init=predicted, thresholds=th)
        ran_off = _ran_off(res, pose)
        if ran_off:
            # The verdict judged the registration's pose, which is not the one kept: the kept
            # start is not confirmed by the scan's refinement (wheels that stalled while the
            # robot moved pin the correlative start; the refinement finds the motion).
            out = Assessment(
                report=out.report,
                verdict=Verdict(accepted=False, reasons=(*out.verdict.reasons, ran_off)),
            )
        kept_start = not ran_off and pose is not start and _slid(out.verdict)
        if kept_start:
            # Rejected for sliding beyond the uncertainty of its start: the scan moved the
            # pose further than the prediction (and the gate) allow, and the verdict rejected
            # where it went, so the start is kept, as for a failed alignment. Kept at the
            # registration's pose, such a frame joined the map there: a drive inside a pillar
            # (sweep_distortion.py --odometry, room 3), given the wheels' exact step, slid
            # 2.5 m / 61° with overlap 0.61 and laid its scan into the map there.
            pose = start
        t_judge = time.perf_counter() - t0

        # 4. update
        t0 = time.perf_counter()
        # A failed alignment, or a start kept for a slide, is no evidence of where the scan
        # lies: it joins the map only when the map is left behind (below). (A refinement that
        # ran off its correlative start still may: without it on the Intel subset the local
        # error went 0.015 -> 0.016 m, the long-range 0.379 -> 0.348 m.)
        failed = res.stop_reason in _FAILED or kept_start
        assert self._last_keyframe is not None
        since = self._last_keyframe.inverse() @ pose
        moved = (
            float(np.linalg.norm(since.translation)) > cfg.keyframe_distance
            or abs(float(since.angle)) > cfg.keyframe_angle
        )
        keyframe = moved and not failed and out.report.overlap >= cfg.thresholds.min_overlap
        reseeded = False
        if moved and not keyframe:
            # The map is left behind: a robot that drove on while no scan overlapped the map
            # enough to join it would never be registered again (a map that no longer
            # changes, every later scan failing against it: the hospital lost its map at
            # scan 2722 and ran its last 4 200 scans on the wheels). Past three keyframe
            # spacings without a keyframe the scan joins it at its best-guess pose.
            far = float(np.linalg.norm(since.translation)) > _LEFT_BEHIND * cfg.keyframe_distance
            keyframe = far or abs(float(since.angle)) > _LEFT_BEHIND * cfg.keyframe_angle
            reseeded = keyframe
        if keyframe:
            self._add_keyframe(pts, pose, sweep)
        t_map = time.perf_counter() - t0

        velocity = previous.inverse() @ pose
        assert isinstance(velocity, SE2)
        self._velocity = velocity
        self._pose = pose
        # One read-only copy serves the frame and the next prediction (which only reads it).
        cov = frozen(res.covariance)
        # The pose's covariance, carried to the next prediction; a failed alignment's is
        # none (the pose stays at the start) and the prediction's would grow without bound.
        self._covariance = cov if np.isfinite(cov).all() and not failed else np.zeros((3, 3))
        return Frame2D(
            index=index,
            stamp=None if stamp is None else float(stamp),
            pose=pose,
            motion=velocity,
            prediction=predicted,
            prediction_source=how,
            covariance=cov,
            verdict=out.verdict,
            quality=out.report,
            registration=res,
            num_source_points=int(pts.shape[0]),
            num_map_points=int(self._map_points.shape[0]),
            map_updated=keyframe,
            timing=FrameTiming2D(
                align=t_align, judge=t_judge, map_update=t_map, total=time.perf_counter() - t_start
            ),
            basin_fallback=fallback,
            map_reseeded=reseeded,
            held_directions=held,
            deskewed=deskewed,
        )

    def _deskewed(
        self,
        points: FloatArray,
        times: FloatArray,
        motion: SE2 | None,
        stamp: float,
        previous_time: float | None,
    ) -> FloatArray:
        """``points`` in the scan's frame at ``stamp``, moved by the predicted motion spread
        over the time since the previous scan (as they are for the first scan, or when that
        time is not positive)."""
        if self._pose is None or previous_time is None or not stamp > previous_time:
            return np.ascontiguousarray(points)
        guess = motion if motion is not None else self._velocity
        velocity = velocity_from_motion(guess, stamp - previous_time)
        return deskew(points, times, velocity, reference_time=stamp)


_FAILED = ("diverged", "too_few_correspondences")
#: Keyframe spacings a robot may move without a keyframe before its scan joins the map
#: regardless of its verdict (:meth:`Odometry2D.step`, "the map is left behind").
_LEFT_BEHIND = 3.0


def _search_window(
    window: tuple[float, float, float], prior: SE2 | None, velocity: SE2
) -> tuple[float, float, float]:
    """The correlative search's half-widths around the prediction: ``window`` around a prior;
    around constant velocity (no prior), widened by the last motion itself, so that a robot
    that stopped, or turned as much again, is still inside it."""
    if prior is not None:
        return window
    step = float(np.linalg.norm(velocity.translation))
    turn = min(math.pi, window[2] + abs(float(velocity.angle)))  # (every heading at most)
    return (window[0] + step, window[1] + step, turn)


def _checked_prior_covariance(
    value: Any, motion: Any, dof: int = 3, *, definite: bool = False
) -> FloatArray | None:
    """``prior_covariance`` checked: ``(dof, dof)``, finite, symmetric, positive
    semi-definite (``definite``: positive definite), and only with a ``prior``
    (``motion``); shared by the 2D and 3D odometry."""
    if value is None:
        return None
    if motion is None:
        raise ValueError("prior_covariance: given without a prior (the motion it describes)")
    return as_covariance(value, "prior_covariance", dof, definite=definite)


def predicted_covariance(previous: FloatArray, motion: SE2, motion_covariance: Any) -> FloatArray:
    """The prediction's covariance over its tangent: ``previous`` (the last pose's) carried
    through ``motion``, plus ``motion_covariance`` (the wheels' over this step)."""
    carry = motion.inverse().adjoint()
    out: FloatArray = carry @ previous @ carry.T + motion_covariance
    return out


def _hold(
    res: RegistrationResult,
    points: FloatArray,
    target: PreparedTarget,
    predicted: SE2,
    covariance: FloatArray,
    config: Any,
    sweep_motion: tuple[float, float, float] | None = None,
    map_sweep: dict[str, Any] | None = None,
) -> tuple[RegistrationResult, tuple[str, ...], SE2]:
    """:func:`hold_to_prediction` with the point-to-line settings of a 2D pipeline's
    ``config`` (:class:`OdometryConfig2D`, ``LocalizationConfig2D``): the one call both make
    (``sweep_motion`` and ``map_sweep``: the registration's, :meth:`Odometry2D._map_sweep`)."""
    return hold_to_prediction(
        res,
        points,
        target,
        predicted,
        covariance,
        method="point_to_line",
        max_correspondence_distance=config.max_correspondence_distance,
        kernel=config.kernel,
        max_iterations=config.max_iterations,
        thresholds=_without_default_probe(config.thresholds),
        never_worse_than_start=_NEVER_WORSE,
        sweep_motion=sweep_motion,
        **(map_sweep or {}),
    )


def _sweep_motion(
    step: SE2, stamp: float | None, previous: float | None, config: OdometryConfig2D
) -> tuple[float, float, float] | None:
    """The sensor's motion over one sweep, ``log(step) · T / Δt``: the predicted motion
    between the scans (``Δt`` apart) at the rate it implies over the sweep's duration ``T``
    (``config.sweep_duration``); None without a duration or an interval."""
    if config.sweep_duration <= 0 or stamp is None or previous is None:
        return None
    interval = float(stamp) - previous
    if not interval > 0:
        return None
    xi = step.log() * (config.sweep_duration / interval)
    return (float(xi[0]), float(xi[1]), float(xi[2]))


def hold_to_prediction(
    res: RegistrationResult,
    points: FloatArray,
    target: PreparedTarget,
    predicted: SE2,
    covariance: FloatArray,
    **settings: Any,
) -> tuple[RegistrationResult, tuple[str, ...], SE2]:
    """``res`` registered again held to ``predicted`` along the directions it names degenerate.

    The held registration starts from ``res``'s pose with its weak components (the oblique
    projector of :meth:`~scanreg.Degeneracy.weak_projector`) replaced by the prediction's, and
    solves with every step kept off them (``step_projector``), ``covariance`` (the
    prediction's, over its tangent) as ``init_covariance``: its pose keeps the prediction
    where the scan says nothing and the scan's fit elsewhere, and its covariance, degeneracy
    and quality (hence the verdict) are computed at that pose, with the prediction's variance
    along the held directions. Returns the registration, the held directions' names and
    where the held solve started; ``res`` itself, no names and its pose when it names no
    degenerate direction or the held solve fails. ``settings``: the
    :func:`scanreg.register` keywords ``res`` was registered with."""
    deg = res.degeneracy
    pose = res.pose
    assert isinstance(pose, SE2)
    if deg is None or not deg.degenerate:
        return res, (), pose
    weak = deg.weak_projector()
    offset = (predicted.inverse() @ pose).log()
    start = predicted @ SE2.exp(offset - weak @ offset)
    held = register(
        points,
        target,
        init=start,
        init_covariance=covariance,
        step_projector=np.eye(3) - weak,
        **settings,
    )
    if held.stop_reason in _FAILED:
        return res, (), pose
    return held, tuple(d.description for d in deg.weak_directions), start


def _without_default_probe(thresholds: VerdictThresholds) -> VerdictThresholds:
    """The pipeline's thresholds with the wrong-basin probe (:mod:`scanreg.basin`) off unless
    asked for (``basin_probe=True``: then a step rejected as a wrong basin is registered again
    from the probe's better pose): its alternatives are not weighed against the motion
    prediction yet, and in a square room every scan has a 90° twin that the prediction already
    rules out. It also costs: measured on the 902 Intel scans with the wheel prior, it halves
    the scans per CPU second (468 -> 217) for 10 fallbacks; with the prior turned by ±45° on
    every 25th step it recovers 15 of the 36 turned steps that the default run loses (and
    then loses the map: 722 rejections against 273)."""
    if thresholds.basin_probe is None:
        return dataclasses.replace(thresholds, basin_probe=False)
    return thresholds


def _ran_off(res: RegistrationResult, kept: SE2) -> str:
    """Why the pose ``kept`` is not ``res``'s (:func:`_accepted_pose` kept the start of a
    refinement that ran off), or ``""`` when it is ``res``'s or the refinement failed (its
    own verdict says so)."""
    pose = res.pose
    if kept is pose or res.stop_reason in _FAILED:
        return ""
    assert isinstance(pose, SE2)
    step = kept.inverse() @ pose
    return (
        f"refinement ran off: {float(np.linalg.norm(step.translation)):.2f} m, "
        f"{math.degrees(abs(float(step.angle))):.1f}° from its start, which is kept unconfirmed"
    )


def _slid(verdict: Verdict) -> bool:
    """Whether ``verdict`` rejected a registration for moving beyond its start's
    uncertainty (:func:`scanreg.verdict.assess`'s motion χ²)."""
    return not verdict.accepted and any(r.startswith("slid beyond") for r in verdict.reasons)


def _accepted_pose(res: RegistrationResult, start: SE2, cfg: OdometryConfig2D) -> SE2:
    """The registered pose, or ``start`` when the refinement failed or ran off."""
    if res.stop_reason in _FAILED:
        return start
    pose = res.pose
    assert isinstance(pose, SE2)
    bound = cfg.max_refinement_step
    if bound is None:
        bound = 0.15 if cfg.front_end == "correlative" else math.inf
    if bound == math.inf:
        return pose  # no step is longer than that: no need to measure it
    step = start.inverse() @ pose
    return start if float(np.linalg.norm(step.translation)) > bound else pose
