"""3D LiDAR odometry: each sweep registered against a voxel-hash local map of recent sweeps.

One :meth:`Odometry.step` per sweep, in the order the code reads:

1. **predict** — ``T_world_sensor`` of the new sweep: the previous pose times the motion
   ``prior`` (wheel/IMU increment ``T_prev_curr``) when given, else the last estimated motion
   repeated (constant velocity);
2. **deskew** — with per-point ``timestamps``, every point is re-expressed at the sweep's
   ``reference_time`` under that predicted motion (:func:`scanreg.deskew`);
3. **downsample** — range crop, then a voxel grid at ``voxel_size / 2`` (the points that join the
   map) and at ``1.5 × voxel_size`` (the points registered): dense map, sparse queries; for
   GICP on a dense sweep each registered point's covariance is the plane fit of the fine
   points it averages (one pass in the core, no neighbour search), as the map's voxels have
   theirs (``source_covariances``);
4. **gate** — the correspondence gate is ``3σ`` of how far past estimates fell from their
   predictions (an adaptive threshold, as in KISS-ICP), ``initial_gate`` until enough motion has
   been seen; the robust kernel's scale is ``σ``;
5. **align** — :func:`scanreg.register` against the local map from the prediction;
6. **judge** — the verdict :func:`scanreg.register` attaches: overlap and residuals against the
   map, the prediction as the motion-bound reference;
7. **update** — the sweep (in the world frame) joins the map; voxels beyond ``max_range`` of the
   sensor are evicted. A registration that failed outright (too few correspondences, diverged,
   singular) is not trusted: the pose falls back to the prediction and the map is not updated.

Poses are ``T_world_sensor`` with the world frame that of the first sweep (or ``initial_pose``).
The per-frame ``covariance`` is the registration's, over the right-perturbation tangent of the
pose (``T_true = pose @ exp(δ)``, translation first): the uncertainty of this sweep *given the
map*, i.e. of the motion relative to the recent sweeps — what a pose graph's odometry edge wants.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from .. import _core
from .._validate import FloatArray, as_matrix, as_points
from ..deskew import REFERENCES, deskew, velocity_from_motion
from ..local_map import Attributes, LocalMap
from ..ndt import NdtResult
from ..preprocess import estimate_normals, positive_int
from ..register import RegistrationResult, RegistrationSettings, register
from ..robust import check_kernel
from ..target import PreparedTarget
from ..transform import SE3, as_pose
from ..verdict import QualityReport, Verdict, VerdictThresholds
from .odometry2d import _checked_prior_covariance, _positive  # the 2D pipeline's checks

OdometryMethod = Literal["point_to_point", "point_to_plane", "gicp"]
ODOMETRY_METHODS: tuple[str, ...] = ("point_to_point", "point_to_plane", "gicp")
#: What the local map stores for each method.
MAP_ATTRIBUTES: dict[str, Attributes] = {
    "point_to_point": "voxel_covariances",
    "point_to_plane": "normals",
    "gicp": "voxel_covariances",
}
#: Stop reasons after which the estimate is not used (the prediction stands in for it).
FAILED_STOPS: frozenset[str] = frozenset({"too_few_correspondences", "diverged", "degenerate"})


#: The fallback's turns of the prediction about the vertical (degrees), nearest first: a
#: 3D registration converges from within about 15-20° of yaw.
FALLBACK_YAWS_DEG: tuple[float, ...] = (30.0, -30.0, 60.0, -60.0, 90.0, -90.0, 120.0, -120.0, 180.0)


def _wrong_start(verdict: Verdict | None) -> bool:
    """Whether a rejection says the registration started in the wrong basin (a pose that
    explains the scan better, no convergence, a slide beyond the start's uncertainty) rather
    than that the scan cannot be matched (little overlap alone, a weak direction, ambiguity)."""
    if verdict is None or verdict.accepted:
        return False
    return any(
        r.startswith(("wrong basin:", "not converged:", "slid beyond")) for r in verdict.reasons
    )


def _se3(pose: Any) -> SE3:
    assert isinstance(pose, SE3)
    return pose


def _default_thresholds() -> VerdictThresholds:
    # Odometry: the map covers the sweep's near field only, so half the points overlapping is
    # not guaranteed at a new street corner; a third is. Degeneracy is handled by the
    # registration's degeneracy-aware solve and reported in FrameResult.held_directions, not
    # rejected (a tunnel frame held to its prior is still the best estimate there is).
    return VerdictThresholds(min_overlap=0.3, reject_degenerate=False)


@dataclass(frozen=True)
class OdometryConfig:
    """How :class:`Odometry` runs (frozen; validated on construction, errors name the field).

    Distances in metres, angles in radians, times in seconds.
    """

    #: Points nearer than this to the sensor are dropped (the vehicle itself).
    min_range: float = 1.0
    #: Points farther are dropped; the map keeps voxels within this of the sensor.
    max_range: float = 100.0
    #: Map voxel side; sweeps join the map on a grid of half this, and are registered on a grid
    #: of 1.5 × this.
    voxel_size: float = 1.0
    max_points_per_voxel: int = 20
    #: ``point_to_point`` (robust kernel; the map stores points only), ``point_to_plane`` or
    #: ``gicp`` (the map stores normals / covariances computed from each sweep).
    method: OdometryMethod = "gicp"
    kernel: str = "none"
    #: Neighbours for the normals / covariances of ``point_to_plane`` and ``gicp``.
    num_neighbors: int = 10
    #: GICP's covariances of the registered points: ``"sweep"``, the plane fit of the fine
    #: points each coarse point averages (from the grid pass: no neighbour search);
    #: ``"neighbors"``, a k-NN fit over the coarse points (``num_neighbors``, ~3 ms a KITTI
    #: sweep); ``"auto"`` (default): ``"sweep"`` when the fine grid holds at least
    #: ``4 ×`` as many points as the coarse one — dense sweeps (KITTI 4.3–4.5, simulated
    #: HDL-64 street 4.3, tunnels 4.8–5.7), where the sweep's fits were as accurate (KITTI ATE
    #: 0.372 vs 0.380 m; HDL-64 street drift 0.78 vs 0.88 %) — else ``"neighbors"``: on
    #: sparse sweeps (simulated VLP-16 street 3.0, HDL-32 3.4) a voxel sees one ring, and the
    #: sweep's fits doubled the rotation drift (1.4–2.1 vs 0.6–1.0 deg/100 m, 3 seeds).
    source_covariances: Literal["auto", "sweep", "neighbors"] = "auto"
    #: Motion-compensate sweeps that come with per-point timestamps.
    deskew: bool = True
    #: The time within a sweep its pose refers to: ``start``, ``middle`` or ``end``.
    #: Mid-sweep (the default) makes the deskew's first-order error from a wrong velocity
    #: average out over the sweep; at ``start`` it biases the next estimate and the motion
    #: estimates oscillate.
    reference_time: Literal["start", "middle", "end"] = "middle"
    #: Gate used until the adaptive gate has seen enough motion; ``None``: 6 m for
    #: point-to-point (KISS-ICP's initial σ = 2 m, gate 3σ), 2 m for the others. On one
    #: standing-start simulated street (60 HDL-64 frames) the 6 m gate rescued point-to-point
    #: (49 m -> 0.68 m end error) — on the 100-frame drive it stays locked on the ground rings
    #: that move with the sensor (not yet understood); 6 m made GICP worse (0.52 m vs 0.05 m).
    initial_gate: float | None = None
    #: Lower bound of the adaptive gate: the distance from a coarse-grid source point to the
    #: nearest map point is up to ~0.4 × ``voxel_size`` from sampling alone, noise-free.
    min_gate: float = 0.5
    #: Frames moving less than this do not update the adaptive gate.
    min_motion: float = 0.1
    max_iterations: int = 50
    #: Converged when a step moves less than this (m, and rad). 1 mm (as small_gicp's
    #: default): against 0.3 mm it saved 13 % of the KITTI frames' GICP iterations (6.1 -> 5.3)
    #: and 19 % on a simulated street, with drift and ATE equal to 0.1 %.
    convergence_tolerance: float = 1e-3
    #: Hold the prediction along the directions the scan does not constrain (a tunnel's axis):
    #: the registration's degeneracy-aware solve (``RegistrationSettings.degeneracy_aware``)
    #: names them (:class:`~scanreg.Degeneracy`, the one verdict on weakness), solves again
    #: from the prediction with every step kept off them, and its covariance takes the prior's
    #: variance there, so the verdict and the covariance describe the pose returned.
    #: ``"prior"`` (default): only for frames given an external motion ``prior`` — constant
    #: velocity is no evidence (from rest it would hold the vehicle still); ``"always"``: also
    #: with constant velocity; ``"never"``.
    degeneracy_aware: Literal["prior", "always", "never"] = "prior"
    #: Standard deviation of an external ``prior`` per frame, in metres: of its translation,
    #: and of its rotation at the scan's rotation levers (the RMS distance of the points from
    #: each axis, as :class:`~scanreg.Degeneracy` measures directions): the covariance along a
    #: held direction (with constant velocity, the registration's gate-wide prior instead).
    prior_sigma: float = 0.1
    #: Threads for registration (``None``: all cores).
    num_threads: int | None = None
    #: What a frame must satisfy to be accepted (see :class:`scanreg.verdict.VerdictThresholds`).
    thresholds: VerdictThresholds = field(default_factory=_default_thresholds)
    #: A sweep rejected as started in the wrong basin (``"wrong basin"``, ``"not converged"``
    #: or ``"slid beyond"`` its start's uncertainty) is registered again from wider starts —
    #: the probe's better pose, the constant-velocity prediction when a prior was given, the
    #: prediction turned by ±30°, ±60°, ±90°, ±120°, 180° about the vertical — and takes the
    #: first accepted result; when none is, the sweep keeps the constant-velocity prediction
    #: and stays out of the map instead of keeping a pose its verdict rejected
    #: (``FrameResult.basin_fallback``). A retry is a full registration: up to 11 of them for
    #: such a sweep.
    basin_fallback: bool = True

    def __post_init__(self) -> None:
        _positive(self.min_range, "min_range", allow_zero=True)
        _positive(self.max_range, "max_range")
        if self.max_range <= self.min_range:
            raise ValueError(
                f"max_range: must exceed min_range ({self.min_range}), got {self.max_range}"
            )
        _positive(self.voxel_size, "voxel_size")
        positive_int(self.max_points_per_voxel, "max_points_per_voxel", minimum=1)
        if self.method not in ODOMETRY_METHODS:
            raise ValueError(
                f"method: unknown {self.method!r}; expected one of {', '.join(ODOMETRY_METHODS)}"
            )
        check_kernel(self.kernel)
        positive_int(self.num_neighbors, "num_neighbors", minimum=3)
        if self.source_covariances not in ("auto", "sweep", "neighbors"):
            raise ValueError(
                "source_covariances: expected 'auto', 'sweep' or 'neighbors', "
                f"got {self.source_covariances!r}"
            )
        if not isinstance(self.deskew, bool):
            raise TypeError(f"deskew: expected a bool, got {type(self.deskew).__name__}")
        if self.reference_time not in REFERENCES:
            raise ValueError(
                f"reference_time: expected one of {', '.join(REFERENCES)}, "
                f"got {self.reference_time!r}"
            )
        if self.initial_gate is not None:
            _positive(self.initial_gate, "initial_gate")
        _positive(self.min_gate, "min_gate")
        _positive(self.min_motion, "min_motion", allow_zero=True)
        positive_int(self.max_iterations, "max_iterations", minimum=1)
        _positive(self.convergence_tolerance, "convergence_tolerance")
        if self.num_threads is not None:
            positive_int(self.num_threads, "num_threads", minimum=1)
        if self.degeneracy_aware not in ("prior", "always", "never"):
            raise ValueError(
                "degeneracy_aware: expected 'prior', 'always' or 'never', "
                f"got {self.degeneracy_aware!r}"
            )
        _positive(self.prior_sigma, "prior_sigma")
        if not isinstance(self.thresholds, VerdictThresholds):
            raise TypeError(
                f"thresholds: expected VerdictThresholds, got {type(self.thresholds).__name__}"
            )


@dataclass(frozen=True)
class Aligned:
    """What the alignment step hands the rest of :meth:`Odometry.step`."""

    pose: SE3
    covariance: FloatArray
    stop_reason: str
    quality: QualityReport
    verdict: Verdict
    registration: RegistrationResult | None
    ndt: NdtResult | None = None


def _aligned(reg: RegistrationResult) -> Aligned:
    """A registration as the alignment step's outcome (judged where it ended)."""
    assert reg.quality is not None and reg.verdict is not None
    return Aligned(
        pose=_se3(reg.pose),
        covariance=reg.covariance,
        stop_reason=reg.stop_reason,
        quality=reg.quality,
        verdict=reg.verdict,
        registration=reg,
    )


@dataclass(frozen=True)
class FrameTiming:
    """Wall-clock seconds of each stage of one :meth:`Odometry.step`. ``align`` includes the
    verdict, which :func:`scanreg.register` computes with the estimate; ``judge`` is only
    what the pipeline adds to it (reading the attached verdict)."""

    deskew: float
    downsample: float
    align: float
    judge: float
    update: float
    total: float


@dataclass(frozen=True)
class FrameResult:
    """The outcome of one sweep (see the module docstring for frames and the covariance)."""

    index: int
    #: The sweep's time (s) as passed to ``step(..., stamp=...)``, or ``None``.
    stamp: float | None
    #: ``T_world_sensor`` of this sweep (at its ``reference_time``).
    pose: SE3
    #: ``T_prev_curr``: this sweep's motion since the previous one.
    motion: SE3
    #: Where the prediction put the sweep (``T_world_sensor``).
    prediction: SE3
    #: ``"prior"``, ``"constant_velocity"`` or ``"first"``.
    prediction_source: str
    #: ``(6, 6)`` over the right-perturbation tangent of ``pose`` given the map (translation
    #: first); zeros for the first sweep of a map it defines, ``inf`` where unknown (a failed
    #: registration).
    covariance: FloatArray
    verdict: Verdict
    #: ``None`` for the first sweep (nothing to register against).
    quality: QualityReport | None
    registration: RegistrationResult | None
    #: Correspondence gate used (m).
    gate: float
    num_points: int
    #: Points registered (after crop and the coarse grid).
    num_source_points: int
    #: Map size after this sweep's update.
    num_map_points: int
    #: Whether this sweep joined the map.
    map_updated: bool
    #: The weak directions the registration's degeneracy-aware solve held to the prediction
    #: (sensor frame), e.g. ``"translation along (1.00, 0.00, 0.00)"``; empty when none.
    held_directions: tuple[str, ...]
    timing: FrameTiming
    #: The first registration was rejected as a wrong start and the sweep was registered again
    #: from wider starts (``OdometryConfig.basin_fallback``), as ``Frame2D.basin_fallback``:
    #: accepted, ``registration`` is the wider one; rejected, none was accepted and the sweep
    #: kept the constant-velocity prediction (``map_updated`` False).
    basin_fallback: bool = False
    #: The NDT alignment of a :class:`~scanreg.Localizer` with ``method="ndt"`` (then
    #: ``registration`` is ``None``); ``None`` otherwise.
    ndt: NdtResult | None = None

    @property
    def degenerate(self) -> bool:
        """Whether the registration named weak directions (its :class:`~scanreg.Degeneracy`, the
        one verdict on weakness; ``held_directions`` are those it held)."""
        deg = None if self.registration is None else self.registration.degeneracy
        return bool(deg is not None and deg.degenerate)


class AdaptiveGate:
    """The correspondence gate from how far estimates land from their predictions.

    A frame's deviation is ``|Δt| + max_range · |Δθ|`` for ``Δ = prediction⁻¹ · estimate``: the
    largest displacement the prediction error causes on a point within range. ``σ`` is the RMS
    deviation over frames that moved more than ``min_motion``; the gate is ``3σ``, floored at
    ``min_gate``, and ``initial_gate`` until a frame has counted.
    """

    def __init__(self, initial: float, minimum: float, min_motion: float, max_range: float):
        self.initial, self.minimum = initial, minimum
        self.min_motion, self.max_range = min_motion, max_range
        self._sum_sq = 0.0
        self._count = 0

    @property
    def sigma(self) -> float:
        if self._count == 0:
            return self.initial / 3.0
        return max(math.sqrt(self._sum_sq / self._count), self.minimum / 3.0)

    @property
    def gate(self) -> float:
        return 3.0 * self.sigma

    def update(self, prediction: SE3, estimate: SE3, motion: SE3) -> None:
        if float(np.linalg.norm(motion.translation)) < self.min_motion:
            return
        d = _se3(prediction.inverse() @ estimate)
        dev = float(np.linalg.norm(d.translation)) + self.max_range * float(d.angle)
        self._sum_sq += dev * dev
        self._count += 1


class Odometry:
    """Scan-to-map LiDAR odometry (see the module docstring).

    ``Odometry(config)`` then one :meth:`step` per sweep, in time order. Deterministic: the same
    sweeps give the same poses, whatever the thread count.
    """

    def __init__(self, config: OdometryConfig | None = None, *, initial_pose: Any = None):
        self.config = OdometryConfig() if config is None else config
        if not isinstance(self.config, OdometryConfig):
            raise TypeError(f"config: expected OdometryConfig, got {type(config).__name__}")
        c = self.config
        self.map = LocalMap(
            3, c.voxel_size, c.max_points_per_voxel, attributes=MAP_ATTRIBUTES[c.method]
        )
        #: What sweeps are registered against: the local map here; a fixed prior map in
        #: :class:`~scanreg.pipeline.localizer.Localizer`, which also turns map updates off.
        self._target: LocalMap | PreparedTarget = self.map
        self._builds_map = True
        initial_gate = c.initial_gate
        if initial_gate is None:
            initial_gate = 6.0 if c.method == "point_to_point" else 2.0
        self.gate = AdaptiveGate(initial_gate, c.min_gate, c.min_motion, c.max_range)
        self._start = (
            SE3.identity()
            if initial_pose is None
            else _se3(as_pose(initial_pose, "initial_pose", 3))
        )
        self._poses: list[SE3] = []
        self._stamps: list[float | None] = []
        self._last_motion = SE3.identity()
        # Overlap and residuals are judged within a fixed gate (not the adaptive one, which
        # shrinks with good predictions): one voxel unless the thresholds say otherwise.
        th = c.thresholds
        self._thresholds = (
            th
            if th.overlap_gate is not None
            else dataclasses.replace(th, overlap_gate=c.voxel_size)
        )
        # The first sweep, kept until the second gives a velocity to deskew it with.
        self._first_sweep: tuple[FloatArray, FloatArray] | None = None

    @property
    def poses(self) -> tuple[SE3, ...]:
        """``T_world_sensor`` of every sweep so far."""
        return tuple(self._poses)

    def step(
        self,
        points: Any,
        timestamps: Any = None,
        prior: Any = None,
        *,
        stamp: float | None = None,
        prior_covariance: Any = None,
    ) -> FrameResult:
        """Process one sweep; the signature of :meth:`scanreg.pipeline.Odometry2D.step`.

        Parameters
        ----------
        points
            ``(N, 3)`` float64 in the sensor frame (each at its own time if ``timestamps``).
        timestamps
            ``(N,)`` per-point times in seconds (any clock), or ``None`` (no deskew).
        prior
            ``T_prev_curr`` motion increment from another sensor (``SE3`` or ``4x4``), used as
            the prediction instead of constant velocity.
        stamp
            The sweep's time (s); with the previous sweep's it gives the deskew period
            (otherwise the span of ``timestamps``).
        prior_covariance
            ``(6, 6)`` covariance of ``prior`` over its right-perturbation tangent (``[ρ, φ]``).
            It replaces the default ``prior_sigma`` spread as the prediction's covariance:
            the registration's ``init_covariance`` (its verdict's motion check, the basin
            probe's plausible alternatives) and, with ``degeneracy_aware``, what holds the
            directions the sweep cannot observe. ``None``: the ``prior_sigma`` spread.
        """
        checked = _checked_prior_covariance(prior_covariance, prior, 6)
        return self._step(
            points, timestamps, prior, stamp, external_prior=prior is not None, stated=checked
        )

    def _step(
        self,
        points: Any,
        timestamps: Any,
        prior: Any,
        stamp: float | None,
        *,
        external_prior: bool,
        stated: FloatArray | None = None,
    ) -> FrameResult:
        t_start = time.perf_counter()
        c = self.config
        pts = as_points(points, "points", dim=3)
        times = None if timestamps is None else as_matrix(timestamps, "timestamps", (len(pts),))
        index = len(self._poses)

        # 1. predict
        has_prior = external_prior
        motion_guess = _se3(as_pose(prior, "prior", 3)) if prior is not None else self._last_motion
        previous = self._poses[-1] if self._poses else self._start
        # Cleaned of round-off: a held frame keeps its prediction, which feeds the next one.
        prediction = _se3(previous @ motion_guess).orthonormalized() if self._poses else self._start

        # 2. deskew
        t0 = time.perf_counter()
        if c.deskew and times is not None and self._poses:
            period = self._period(times, stamp)
            if period > 0:
                velocity = velocity_from_motion(motion_guess, period)
                pts = deskew(pts, times, velocity, reference_time=c.reference_time)
        t_deskew = time.perf_counter() - t0

        # 3. downsample
        t0 = time.perf_counter()
        map_points, source, source_covariances = self._grids(pts)
        if source_covariances is not None and not self._sweep_covariances(map_points, source):
            source_covariances = None  # register() fits them over the source's k-NN
        t_down = time.perf_counter() - t0

        if not self._poses and self._builds_map:
            if times is not None:
                self._first_sweep = (pts, times)
            return self._first(
                index, prediction, pts, map_points, source, stamp, t_start, t_deskew, t_down
            )

        # 4. gate, and whether to hold the prediction along what the scan cannot observe
        gate = self.gate.gate
        hold = c.degeneracy_aware == "always" or (c.degeneracy_aware == "prior" and has_prior)
        # An external prior's spread is prior_sigma; constant velocity ("always") keeps the
        # registration's gate-wide prior: it is no measurement, and a vehicle starting from rest
        # moves far beyond prior_sigma from it (its motion check would reject the frame).
        prior_cov = (
            stated
            if stated is not None
            else self._prior_covariance(source)
            if hold and has_prior
            else None
        )
        # 5. align
        t0 = time.perf_counter()
        settings = RegistrationSettings(
            max_correspondence_distance=gate,
            max_iterations=c.max_iterations,
            translation_tolerance=c.convergence_tolerance,
            rotation_tolerance=c.convergence_tolerance,
            kernel=c.kernel,
            # The adaptive σ is in metres: the scale of the point methods' residuals.
            # GICP's residuals are whitened, and keep register()'s default scale.
            kernel_scale=None if c.kernel == "none" or c.method == "gicp" else self.gate.sigma,
            num_threads=c.num_threads,
            num_neighbors=c.num_neighbors,
            degeneracy_aware=hold,
        )
        aligned = self._align(source, prediction, settings, prior_cov, source_covariances)
        reg = aligned.registration
        # 5b. wrong start: a wider search rather than a pose the verdict rejected
        fallback = failed = False
        if c.basin_fallback and reg is not None and _wrong_start(reg.verdict):
            retry = self._wider_search(
                source, reg, prediction, previous, has_prior, prior_cov, source_covariances
            )
            fallback, failed = True, retry is None
            if retry is not None:
                reg, aligned = retry, _aligned(retry)
        t_align = time.perf_counter() - t0
        usable = aligned.stop_reason not in FAILED_STOPS and not failed
        if failed:
            prediction = _se3(previous @ self._last_motion)
        pose = aligned.pose if usable else prediction
        cov = np.array(aligned.covariance) if usable else np.full((6, 6), np.inf)
        held: tuple[str, ...] = ()
        if usable and hold and reg is not None and reg.degeneracy is not None:
            # The registration held these to the prediction: its pose, verdict and covariance
            # (the prior's variance along them) all describe the held estimate.
            held = tuple(d.description for d in reg.degeneracy.weak_directions)
        if self._first_sweep is not None and times is not None and c.deskew:
            # The first sweep joined the map undeskewed (no motion was known), and this one was
            # matched undeskewed too: consistent, so `reg` is a sound first motion. Re-seed the
            # map with the first sweep deskewed by it and redo this sweep with that motion.
            first_pts, first_times = self._first_sweep
            self._first_sweep = None
            if usable:
                motion = _se3(previous.inverse() @ pose)
                velocity = velocity_from_motion(motion, self._period(times, stamp))
                self.map.clear()
                self._insert(previous, self._grids(first_pts, first_times, velocity)[0])
                return self._step(
                    points, timestamps, motion, stamp, external_prior=has_prior, stated=stated
                )
        self._first_sweep = None

        # 6. judge: the alignment judged the result against the map, from the prediction
        t0 = time.perf_counter()
        quality, verdict = aligned.quality, aligned.verdict
        t_judge = time.perf_counter() - t0

        # 7. update
        t0 = time.perf_counter()
        # A localizer's first frame corrects its initial pose: not a motion to repeat.
        motion = _se3(previous.inverse() @ pose) if self._poses else SE3.identity()
        if usable and self._poses and not fallback:
            # (A prediction the fallback had to correct says nothing about the motion model's
            # error: it would open the gate for every later sweep.)
            self.gate.update(prediction, pose, motion)
        if usable and self._builds_map:
            self._insert(pose, map_points)
        if self._builds_map:
            self.map.remove_far(pose.translation, c.max_range)
        self._remember(pose, motion, stamp)
        t_update = time.perf_counter() - t0

        return FrameResult(
            index=index,
            stamp=None if stamp is None else float(stamp),
            pose=pose,
            motion=motion,
            prediction=prediction,
            prediction_source="prior" if has_prior else "constant_velocity",
            covariance=cov,
            verdict=verdict,
            quality=quality,
            registration=reg,
            ndt=aligned.ndt,
            gate=gate,
            num_points=len(pts),
            num_source_points=len(source),
            num_map_points=len(self._target),
            map_updated=usable and self._builds_map,
            held_directions=held,
            basin_fallback=fallback,
            timing=FrameTiming(
                deskew=t_deskew,
                downsample=t_down,
                align=t_align,
                judge=t_judge,
                update=t_update,
                total=time.perf_counter() - t_start,
            ),
        )

    def _wider_search(
        self,
        source: FloatArray,
        first: RegistrationResult,
        prediction: SE3,
        previous: SE3,
        has_prior: bool,
        init_covariance: FloatArray | None,
        source_covariances: FloatArray | None,
    ) -> RegistrationResult | None:
        """The first accepted registration of ``source`` from the fallback's starts (see
        ``OdometryConfig.basin_fallback``), with ``first``'s settings (its degeneracy-aware solve
        and prior included); None when none is."""
        starts: list[SE3] = []
        probe = None if first.quality is None else first.quality.basin
        if probe is not None and isinstance(probe.alternative, SE3):
            starts.append(probe.alternative)
        if has_prior and self._poses:
            starts.append(_se3(previous @ self._last_motion))
        starts += [
            _se3(prediction @ SE3.from_vector([0.0, 0.0, 0.0, 0.0, 0.0, math.radians(d)]))
            for d in FALLBACK_YAWS_DEG
        ]
        for start in starts:
            res = register(
                source,
                self._target,
                method=self.config.method,
                init=start,
                settings=first.settings,
                thresholds=self._thresholds,
                init_covariance=init_covariance,
                source_covariances=source_covariances,
            )
            if res.verdict is not None and res.verdict.accepted:
                return res
        return None

    def _align(
        self,
        source: FloatArray,
        prediction: SE3,
        settings: RegistrationSettings,
        init_covariance: FloatArray | None,
        source_covariances: FloatArray | None,
    ) -> Aligned:
        """Step 5: register the sweep to the target from the prediction, judged there (the
        localizer overrides it to align by NDT)."""
        reg = register(
            source,
            self._target,
            method=self.config.method,
            init=prediction,
            settings=settings,
            thresholds=self._thresholds,
            init_covariance=init_covariance,
            source_covariances=source_covariances,
        )
        return _aligned(reg)

    def map_cloud(self) -> Any:
        """The local map (world frame) as a :class:`~scanreg.io.PointCloud`, with
        ``normal_x/y/z`` fields when the map stores normals."""
        from ..io import PointCloud

        target = self._target
        if isinstance(target, LocalMap):
            pts, normals = np.ascontiguousarray(target.points()), target.normals()
        else:
            pts, normals = np.ascontiguousarray(target.points), target.normals
        fields: dict[str, FloatArray] = {}
        if normals is not None:
            fields = {
                f"normal_{a}": np.ascontiguousarray(normals[:, i]) for i, a in enumerate("xyz")
            }
        return PointCloud(points=pts, fields=fields)

    def save_map(self, path: Any, **options: Any) -> int:
        """Write the local map (world frame) to ``path`` — PLY, PCD, LAS/LAZ (or any point
        format of :data:`scanreg.io.WRITERS`; ``options`` go to the writer, e.g. a LAS
        ``offset``), with ``normal_x/y/z`` fields when the map stores normals. Returns the
        number of points written."""
        from ..io import write_points

        cloud = self.map_cloud()
        write_points(path, cloud, **options)
        return len(cloud)

    def run(self, sweeps: Sequence[Any]) -> list[FrameResult]:
        """``step`` over ``(points, timestamps)`` pairs or bare point arrays."""
        out = []
        for s in sweeps:
            if isinstance(s, tuple):
                out.append(self.step(*s))
            else:
                out.append(self.step(s))
        return out

    # --- helpers -------------------------------------------------------------------------

    def _prior_covariance(self, source: FloatArray) -> FloatArray:
        """The prediction's covariance over the tangent: ``prior_sigma²`` per translation axis
        and ``(prior_sigma / L_a)²`` per rotation axis (``L_a`` the source's rotation levers)."""
        sigma = self.config.prior_sigma
        sq = source**2
        # RMS distance of the points from each axis through the sensor (the rotation levers).
        levers = np.maximum(np.sqrt(np.mean(sq.sum(axis=1)[:, None] - sq, axis=0)), 1e-9)
        return np.diag(np.concatenate([np.full(3, sigma**2), (sigma / levers) ** 2]))

    def _period(self, times: FloatArray, stamp: float | None) -> float:
        last = self._stamps[-1] if self._stamps else None
        if stamp is not None and last is not None:
            return float(stamp) - last
        return float(times.max() - times.min())

    def _grids(
        self, pts: FloatArray, times: FloatArray | None = None, velocity: Any = None
    ) -> tuple[FloatArray, FloatArray, FloatArray | None]:
        """Deskewed (when ``velocity`` is given), range-cropped, on the fine grid (the map's
        points) and the coarse grid (the registered points): one pass in the core. For GICP
        also each coarse point's covariance, from the fine points it averages — the same
        per-voxel, plane-regularised kind the map keeps, without a neighbour search."""
        c = self.config
        if velocity is not None and times is not None:
            pts = deskew(pts, times, velocity, reference_time=c.reference_time)
        fine, coarse, kept, covs = _core.sweep_grids(
            pts,
            c.min_range,
            c.max_range,
            0.5 * c.voxel_size,
            1.5 * c.voxel_size,
            coarse_covariances=c.method == "gicp" and c.source_covariances != "neighbors",
        )
        if kept < 10:
            raise ValueError(
                f"points: only {kept} of {len(pts)} points lie within "
                f"[{c.min_range}, {c.max_range}] m of the sensor; need at least 10"
            )
        return fine, coarse, covs

    def _sweep_covariances(self, fine: FloatArray, coarse: FloatArray) -> bool:
        """Whether GICP uses the sweep's own plane fits (see ``source_covariances``)."""
        mode = self.config.source_covariances
        return mode == "sweep" or (mode == "auto" and len(fine) >= 4.0 * len(coarse))

    def _insert(self, pose: SE3, map_points: FloatArray) -> None:
        """Add a sweep's map points (sensor frame) to the map at ``pose``. Point-to-plane: with
        normals computed in the sweep and rotated into the world. GICP and point-to-point: the
        map derives each voxel's covariance from its own points (``voxel_covariances``; GICP's
        cost reads them, point-to-point's degeneracy analysis takes its plane normals from
        them: cheaper than normals, and the registration's covariance stays point-to-point's)."""
        c = self.config
        world = pose.apply(map_points)
        if c.method != "point_to_plane":
            self.map.insert(world)
        elif len(map_points) >= c.num_neighbors:
            nrm = estimate_normals(map_points, num_neighbors=c.num_neighbors)
            ok = nrm.valid
            self.map.insert(world[ok], normals=nrm.normals[ok] @ pose.rotation.T)

    def _remember(self, pose: SE3, motion: SE3, stamp: float | None) -> None:
        self._poses.append(pose)
        self._stamps.append(None if stamp is None else float(stamp))
        self._last_motion = motion

    def _first(
        self,
        index: int,
        pose: SE3,
        pts: FloatArray,
        map_points: FloatArray,
        source: FloatArray,
        stamp: float | None,
        t_start: float,
        t_deskew: float,
        t_down: float,
    ) -> FrameResult:
        t0 = time.perf_counter()
        self._insert(pose, map_points)
        self._remember(pose, SE3.identity(), stamp)
        t_update = time.perf_counter() - t0
        return FrameResult(
            index=index,
            stamp=None if stamp is None else float(stamp),
            pose=pose,
            motion=SE3.identity(),
            prediction=pose,
            prediction_source="first",
            covariance=np.zeros((6, 6)),
            verdict=Verdict(accepted=True, reasons=()),
            quality=None,
            registration=None,
            gate=self.gate.gate,
            num_points=len(pts),
            num_source_points=len(source),
            num_map_points=len(self.map),
            map_updated=True,
            held_directions=(),
            timing=FrameTiming(
                deskew=t_deskew,
                downsample=t_down,
                align=0.0,
                judge=0.0,
                update=t_update,
                total=time.perf_counter() - t_start,
            ),
        )
