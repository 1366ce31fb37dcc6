"""The trust analysis of a registration: covariances, degeneracy, conditioning, overlap and the
verdict, from the solver's outcome (:func:`scanreg.register` calls it; :mod:`scanreg.register`
keeps the solve).

It reads the core's outcome (the final correspondences, ``JᵀWJ``, the scores) and the inputs
the call kept (:class:`TrustInputs`), and may run **extra solves** through the callbacks the
call hands it — never the solver directly:

* ``plane_solve(start)``: reading ``covariance`` after a point-to-point registration whose
  target has normals runs one point-to-plane/line registration from its pose (the
  ``calibrated`` covariance is that estimate's plus the offset between the two);
* ``solve(starts, iterations, probe)``: the 2D verdict's wrong-basin probe (:mod:`scanreg.basin`)
  restarts the registration's own solve around the result, every start in one core call;
* the degeneracy-aware solve (``degeneracy_aware=True``) measures its valley with two held
  solves per weak direction (:func:`valley_moment`, called by ``register`` itself).

The arithmetic runs in the core, one call per analysed outcome (``_core.trust_analysis``): the
source's sampled normals and, in 2D, its point spacing off the same neighbour search (once per
call), the per-correspondence sums (the normal noise between the two scans, the normal agreement,
the 2D sampling system, Censi's meats, the block sandwich) and everything the ≤ 6×6 matrices give
(``scanreg_core::trust``) — the degeneracy, every covariance kind, the prior along weak directions,
the model shift, the conditioning, the information and the motion χ². The same call measures the
scene (rotation levers, length scale, gate-wide prior) on a result's first analysis and, in 2D
against a :class:`~scanreg.PreparedTarget`, runs the verdict's overlap pass (its searches
started at the final correspondences and mostly settled by the solve's certificates). Here:
which analyses and extra solves run, the verdict, and the result dataclasses (the parts few
callers read — the degeneracy's direction objects, the report's motion from the start — built
on first read, :class:`~scanreg._validate.LazyFields`).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import threading
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from . import _core
from ._validate import FloatArray, build_lazy
from ._validate import build as _build
from ._validate import frozen as _frozen
from ._validate import readonly as _readonly
from ._validate import replaced as _replaced
from .basin import probe_basin, tight_gate
from .degeneracy import (
    Degeneracy,
    sampled_normals,
)
from .local_map import LocalMap
from .preprocess import check_k
from .quality import (
    Conditioning,
    WeakDirection,
    information_from_covariance,
)
from .slide import SlideCheck, start_cover
from .target import PreparedTarget, median_spacing
from .transform import SE2, SE3
from .verdict import (
    Assessment,
    QualityReport,
    Verdict,
    VerdictThresholds,
    _assess_checked,
    judge,
)

if TYPE_CHECKING:
    from .register import RegistrationSettings

#: Pairs whose source and target normals agree less than this (``|cos|``, about 5.7°) are the
#: ones the model-error term leaves out (``CovarianceEstimates.model_shift``): on the simulated
#: street, keeping ``≥ 0.95 / 0.99 / 0.995`` left −1.23 / −0.66 / −0.42 cm of its −2.5 cm
#: point-to-plane bias (``benchmarks/street_bias_normals.py``).
MIN_NORMAL_AGREEMENT = 0.995


#: The point-to-plane/line method of each dimension (point-to-point's reference estimate).
PLANE_METHOD = {2: "point_to_line", 3: "point_to_plane"}


@dataclass(frozen=True)
class CovarianceEstimates:
    """Every covariance kind at the final pose, ``(dof, dof)`` over the tangent ``δ``
    (translation first, right perturbation, source frame); all ``inf`` when not determined."""

    #: σ̂²(JᵀWJ)⁻¹, or the M-estimator sandwich under a kernel.
    hessian: FloatArray
    #: Censi's closed form with per-coordinate point noise ``point_variance``.
    censi: FloatArray
    #: Cluster-robust sandwich over ``num_blocks`` spatial blocks of ``block_size``.
    block: FloatArray
    #: ``censi`` ∨ ``block``, with the prior variance along degenerate directions, plus
    #: ``model_shift`` as ``δδᵀ``.
    calibrated: FloatArray
    #: Variance of each coordinate of a source or target point used by ``censi`` (units²): half
    #: the residual variance, plus in 2D point-to-line the noise the nearest-neighbour
    #: association hides from the residuals (``scanreg_core::trust::association``).
    point_variance: float
    #: Variance of a target normal's direction per tangent axis used by ``censi`` (rad²),
    #: measured between the two scans (point-to-plane/line; 0 otherwise).
    normal_variance: float
    block_size: float
    num_blocks: int
    #: The prior used along degenerate directions (``init_covariance``, or the gate's).
    prior: FloatArray
    #: ``(dof,)`` model-error term of ``calibrated``: how far the estimate would move (one
    #: Gauss–Newton step at the final correspondences, a sample of them) under the
    #: point-to-plane/line objective of the pairs whose source and target normals agree
    #: (``|n_s·n_t| ≥ MIN_NORMAL_AGREEMENT``). Point-to-plane/line: the step with those pairs
    #: minus the step with all sampled pairs (the shift the disagreeing pairs cause).
    #: Point-to-point: the offset to the point-to-plane/line estimate re-solved from its pose
    #: (and ``calibrated`` is that estimate's plus ``δδᵀ``); if that re-solve fails, the
    #: agreeing step itself. GICP in 3D: its own step over the pairs whose target neighbourhood
    #: is not linear (``PreparedTarget.linear``) minus its step over all pairs. Zeros for 2D
    #: GICP, without target normals (GICP: without the target's linear flags), or with too few
    #: agreeing pairs; never along weak directions. See ``docs/calibration.md``.
    model_shift: FloatArray


def pose_from_core(out: Any, dim: int) -> SE2 | SE3:
    """The core's pose, its rotation projected onto SO(D) as ``from_matrix`` does, without
    re-validating what the core built (finite, homogeneous, not a reflection). In 2D the
    binding has projected it (closed form) and checked it orthonormal: its read-only arrays
    are adopted as they are (a 2D scan registers in ~0.2 ms; numpy's fixed costs showed)."""
    if dim == 2:
        return SE2._wrap(out.rotation, out.translation)
    r = out.rotation
    err = float(np.abs(r.T @ r - np.eye(dim)).max())
    if err > 1e-6:  # a core bug, never the user's input
        raise ValueError(f"pose: not orthonormal (max |RᵀR - I| = {err:.2e})")
    u, _, vt = np.linalg.svd(r)
    return SE3._adopt(u @ vt, np.array(out.translation))


@dataclass(frozen=True)
class TrustInputs:
    """What the trust analysis of one :func:`register` call reads (none of it the caller's
    mutable arrays: a lazy analysis runs after the call has returned)."""

    source: FloatArray
    target: PreparedTarget | LocalMap
    target_points: Any
    target_normals: Any
    target_covariances: Any
    source_covariances: Any
    method: str
    settings: RegistrationSettings
    kernel_scale: float
    components: int
    #: Checked (and copied) ``init_covariance``, or None for the gate-wide prior.
    init_covariance: FloatArray | None
    #: The caller's ``init``: the verdict measures the result's motion from it.
    start: SE2 | SE3
    thresholds: VerdictThresholds
    #: Where the solve started (:mod:`scanreg.start_search`: the best pose of ``start``'s
    #: stated window, when searched), the start the never-worse check compared; None: ``start``.
    solve_start: SE2 | SE3 | None = None
    #: Point-to-point with target normals: ``solve(pose)``, the core's point-to-plane/line
    #: registration from ``pose`` (held along the weak directions where the solve was), for
    #: ``calibrated`` (:func:`_via_plane_reference`); None otherwise.
    plane_solve: Any = None
    #: ``solve(starts, max_iterations, probe) -> (kinds, offsets, fractions, poses)``: the
    #: registration's own solve (held where it was) from each of ``starts`` (``(K, D+1, D+1)``)
    #: and each outcome's comparison with the result, in one core call
    #: (``_core.probe_restarts``; ``probe`` holds its arguments after the solver's), for the
    #: verdict's wrong-basin probe (:mod:`scanreg.basin`).
    solve: Any = None
    #: The never-worse-than-the-start check (:mod:`scanreg.slide`), for the verdict; None when
    #: it did not run.
    slide: SlideCheck | None = None
    #: When the pose returned is the minimum of the refinement's narrow objective
    #: (:func:`scanreg.slide.refine_in_basin`): ``evaluate() -> (outcome, (kernel, scale))``,
    #: that objective evaluated at the pose without moving, for the covariance of a source that
    #: is not one scan (:func:`_refined_analysis`); None otherwise.
    refined_objective: Any = None

    @functools.cached_property
    def _scene(self) -> tuple[FloatArray, float, float, FloatArray]:
        """``(levers, length_scale, nan, gate_prior)`` of the source, one pass in the core
        (``scanreg_core::trust::scene``); the beam phase (an angular sort of the scan, most of
        the pass) is measured where it is used (:attr:`beam_phase_variance`)."""
        out: tuple[FloatArray, float, float, FloatArray] = _core.trust_scene(
            self.source, float(self.settings.max_correspondence_distance), beam_phase=False
        )
        return out

    @property
    def levers(self) -> FloatArray:
        """RMS distance of the source from each rotation axis through its origin (≥ 1e-9)."""
        return self._scene[0]

    @property
    def length_scale(self) -> float:
        """RMS distance of the source from its centroid (the conditioning's rotation lever)."""
        return self._scene[1]

    @property
    def prior(self) -> FloatArray:
        """The covariance of the initial guess (see :func:`register`): ``init_covariance``, or
        the gate-wide prior ``diag(δ², …, (δ/L_a)², …) / 3`` (δ the gate, or the RMS lever when
        the gate is infinite). ICP converges only from within about a gate of the truth: the
        error is taken as uniform within ±δ per axis (the least informative law with that
        bound), variance δ²/3."""
        if self.init_covariance is not None:
            return self.init_covariance
        return self._scene[3]

    @functools.cached_property
    def beam_phase_variance(self) -> float:
        """2D: ``Δα²/12`` (rad²) for the source's median angular step ``Δα`` between
        neighbouring points as seen from its origin (the sensor); 0 in 3D.

        Two scans sample the same objects at different beam phases: where an object's edge or
        a corner falls between two beams is known only to a beam step, and the estimate's
        heading takes up that quantisation — a uniform error over one step about the sensor,
        ``θ`` alone in the tangent (the source origin). No model at the final pose sees it.
        Measured on real split-beam pairs (even beams against odd ones, exact truth,
        ``benchmarks/covariance_calibration.py --split-beam``): RMS heading error 0.32° at a
        1° step (MbICP halves) and 0.68° at 2° (Intel halves), against Δα/√12 = 0.29° and
        0.58°, where the covariance claimed 0.08° and 0.45°.

        Used only when the target has neither normals nor covariances. Otherwise
        ``calibrated`` carries the evidence-based sampling term instead
        (``_core.trust_sampling``, ``scanreg_core::trust::scene::sampling_system``): how far
        each matched point's residual moves when its sample slides one beam step along the
        scan (zero along a straight wall, up to the step at edges and on clutter), as a
        sandwich ``¼ H⁻¹ (Σ J Jᵀ e²) H⁻¹`` on the well-constrained subspace (a phase of up to
        ±½ step between the two scans). A fixed ``Δα²/12`` made the simulated corridor's
        heading σ 12× its error, while leaving MbICP split-beam pairs 2× over-confident in
        translation, which the fixed heading term cannot reach (``docs/calibration.md``). A
        source that is not one scan (no single sweep in its input order, and points behind
        points along a bearing: a map, merged submaps) takes each point's neighbours along its
        surface instead of in bearing order (``scanreg_core::trust::scene::sampling_model``).
        """
        phase: float = _core.trust_scene(self.source, math.inf)[2]
        return phase

    @functools.cached_property
    def sampling_density_ratio(self) -> float:
        """How much finer the target samples the surfaces than the source, as the ratio of
        their point spacings (:func:`~scanreg.target.median_spacing`), at most 1.

        The sampling term (:attr:`beam_phase_variance`) moves each matched source point one
        beam step along its surface and asks how far its residual to the target's local line
        changes; that change comes from the target's line following the surface only between
        its own samples, so it shrinks with the target's spacing. Two scans of one sensor have
        equal spacings (ratio 1, the pairs the term was calibrated on); against a map merged
        from many scans (an odometry's local map, a loop's submap) it is a fraction of that.
        Measured on simulated room tours (``benchmarks/loop_calibration.py``): without it the
        loop edges' mean NEES was 0.85 against an ideal 3, their errors a third of their σ. A
        target sparser than the source is not modelled further (ratio 1).

        The first analysis of a call has the core measure the source's spacing off the search
        of its sampled normals (:func:`correspondence_analysis` keeps the ratio here); this
        property measures it alone when read before."""
        target = self.target
        spacing = target.spacing if isinstance(target, PreparedTarget) else math.nan
        src = self.source
        if not math.isfinite(spacing) or len(src) < 2:
            return 1.0
        return _density_ratio(spacing, median_spacing(_core.KdTree(src), src))

    @functools.cached_property
    def source_normals(self) -> tuple[Any, FloatArray]:
        """Normals of a sample of the source, ``(indices, normals)``: once per call, even when
        the degeneracy-aware solve analyses twice."""
        n, dim = self.source.shape
        return sampled_normals(self.source, check_k(min(self.settings.num_neighbors, n), n, dim))

    @functools.cached_property
    def block_size(self) -> float:
        if self.settings.block_size is not None:
            return self.settings.block_size
        block = 2.0 * self.settings.max_correspondence_distance
        if math.isfinite(block):
            return block
        return float(np.sqrt(np.mean(self.levers**2))) / 5.0


def _density_ratio(target: float, source: float) -> float:
    """``min(1, target / source)`` of two median spacings; 1 where the source's is not known."""
    if not (math.isfinite(source) and source > 0.0):
        return 1.0
    return min(1.0, target / source)


@dataclass(frozen=True)
class CorrespondenceAnalysis:
    """The analysis of one outcome at its final correspondences: the scene's degeneracy, the
    noise levels measured from the residuals and normals, and the core's numbers."""

    degeneracy: Degeneracy
    point_variance: float
    normal_variance: float
    #: The degeneracy-aware solve's :func:`valley_moment`, or None.
    valley: FloatArray | None = None
    #: The core's arithmetic of this analysis (``_core.TrustNumbers``): covariances,
    #: conditioning, information and motion χ² of the outcome it was run on.
    numbers: Any = None
    #: ``start⁻¹ · pose``, its logarithm and the outcome's correspondences (int64, -1 for
    #: none): computed once here, read again by the verdict and the basin probe's screen.
    moved: Any = None
    drift: Any = None
    correspondences: Any = None
    #: ``_core.overlap_statistics`` at the outcome's pose within the verdict's gate, when the
    #: analysis ran it in the same core call (a 2D outcome against a PreparedTarget), else None.
    overlap: Any = None


@dataclass(frozen=True)
class _Trust:
    covariance: FloatArray
    information: FloatArray
    conditioning: Conditioning
    covariances: CovarianceEstimates
    degeneracy: Degeneracy
    quality: QualityReport
    verdict: Verdict
    seconds: float


class LazyTrust:
    """The trust analysis of one registration, computed once on first use (thread-safe)."""

    __slots__ = ("_args", "_lock", "_value")

    def __init__(
        self,
        ctx: TrustInputs | dict[str, Any],
        out: Any,
        pose: SE2 | SE3,
        first: CorrespondenceAnalysis | None,
    ) -> None:
        self._args: tuple[Any, ...] | None = (ctx, out, pose, first)
        self._lock = threading.Lock()
        self._value: _Trust | None = None

    def get(self) -> _Trust:
        value = self._value
        if value is None:
            with self._lock:
                if self._value is None:
                    assert self._args is not None
                    ctx, *rest = self._args
                    if isinstance(ctx, dict):  # its fields, as register() gathered them
                        ctx = _build(TrustInputs, ctx)
                    self._value = _trust(ctx, *rest)
                    self._args = None  # the source, target and core outcome can go
                value = self._value
        return value

    def __getstate__(self) -> _Trust:
        return self.get()

    def __setstate__(self, value: _Trust) -> None:
        self._args = None
        self._lock = threading.Lock()
        self._value = value


def correspondence_analysis(
    ctx: TrustInputs,
    out: Any,
    *,
    held: Degeneracy | None = None,
    valley: FloatArray | None = None,
    overlap_gate: float | None = None,
    kernel: tuple[str, float] | None = None,
) -> CorrespondenceAnalysis:
    """The analysis of one core outcome ``out``: the correspondence sums, then the core's
    arithmetic of them (one call). ``held``: the degeneracy-aware solve's weak directions, kept
    as the first solve measured them; ``valley``: its :func:`valley_moment`; ``overlap_gate``:
    the verdict's overlap pass at the outcome's pose within this gate, in the same call (2D
    against a PreparedTarget; the caller checks); ``kernel``: ``(name, scale)`` the outcome
    was evaluated with when it is not the registration's (:func:`_refined_analysis`)."""
    s, src, prepared, method = ctx.settings, ctx.source, ctx.target, ctx.method
    kernel_name, kernel_scale = (s.kernel, ctx.kernel_scale) if kernel is None else kernel
    dim = int(src.shape[1])
    dof = 3 if dim == 2 else 6
    # The target's own normal noise needs its k-d tree: not measured on a map.
    eps2, eps2_typical = (
        prepared.normal_noise
        if isinstance(prepared, PreparedTarget) and prepared.normals is not None
        else (math.nan, math.nan)
    )
    corr = np.asarray(out.correspondences)
    matched = corr  # the core's, before a map's rows are compacted: the overlap's hints
    tp, tn, tc = ctx.target_points, ctx.target_normals, ctx.target_covariances
    if isinstance(prepared, LocalMap):
        # A map's rows are gathered for the matched ids only (a few thousand, not the storage).
        used = corr >= 0
        ids, compact = np.unique(corr[used], return_inverse=True)
        tp, tn, tc = prepared.native.gather(np.ascontiguousarray(ids, dtype=np.int64))
        corr = np.full(corr.shape, -1, dtype=np.int64)
        corr[used] = compact
    n = len(src)
    if method != "gicp" and n > dim and (dim == 3 or tn is not None):
        check_k(min(s.num_neighbors, n), n, dim)  # the sampled normals' neighbourhood
    # The sampling term scaled by how much finer the target samples the surfaces
    # (:attr:`TrustInputs.sampling_density_ratio`): on the first analysis of a call the core
    # measures the source's spacing off the search of its sampled normals.
    sampling_scale, target_spacing = 1.0, None
    if dim == 2 and (tn is not None or tc is not None):
        ratio = ctx.__dict__.get("sampling_density_ratio")
        spacing = prepared.spacing if isinstance(prepared, PreparedTarget) else math.nan
        if ratio is None and math.isfinite(spacing) and n >= 2:
            target_spacing = spacing
        else:
            sampling_scale = ctx.sampling_density_ratio**2
    pose = pose_from_core(out, dim)
    moved = ctx.start.inverse() @ pose  # type: ignore[operator]
    drift = moved.log()
    robust = kernel_name != "none"
    # The scene pass (levers, length scale, gate-wide prior) rides on this call on the first
    # analysis, unless the block size needs the levers first (an infinite gate).
    fold_scene = "_scene" not in ctx.__dict__ and (
        s.block_size is not None or math.isfinite(s.max_correspondence_distance)
    )
    # One core call (``_core.trust_analysis``), by position in the binding's order: the
    # source's sampled normals (measured once per call: the degeneracy-aware solve and the
    # plane reference analyse the same source again) and, on the first 2D analysis, the
    # source's spacing off the same search (the sampling-density ratio), the normal noise
    # between the two scans
    # (Censi's normal term) and which pairs' normals disagree (the model-error term), the 2D
    # sampling system (how far the estimate depends on where the beams fell; without a target
    # normal or covariance, the beam-phase heading variance instead), Censi's and the block
    # sums at unit variances (they scale linearly and are combined once the point noise is
    # known from the residuals of this very analysis), then the arithmetic of
    # ``scanreg_core::trust``. Point-to-point in 3D: a covariance-only target (the odometry's
    # voxel map) gives the degeneracy analysis its plane normals.
    num = _core.trust_analysis(
        src,
        tp,
        out.pose,
        corr,
        method,
        kernel_name,
        kernel_scale,
        max(ctx.block_size, 1e-9),
        min(s.num_neighbors, n),
        tn,
        tc,
        ctx.source_covariances,
        s.num_threads,
        out.hessian,
        residual_variance(out, ctx.components, kernel_name, dof),
        None if fold_scene else ctx.levers,
        ctx.init_covariance if fold_scene else ctx.prior,
        drift,
        np.asarray(moved.translation, dtype=np.float64),
        None if fold_scene else ctx.length_scale,
        s.covariance,
        int(out.num_correspondences),
        float(out.sum_squared_distances),
        out.score_outer if robust else None,
        ctx.components * float(out.irls_weight_sum) if robust else 0.0,
        eps2,
        eps2_typical,
        # Measured by the core only where it is used (a 2D result without a sampling system).
        ctx.__dict__.get("beam_phase_variance", math.nan),
        0.5 * float(s.max_correspondence_distance),
        MIN_NORMAL_AGREEMENT,
        sampling_scale,
        ctx.__dict__.get("source_normals"),
        valley,
        None
        if held is None
        else (
            held.information,
            held.threshold,
            held.normal_noise,
            held.typical_normal_noise,
            held.num_correspondences,
            held.removed_normal_noise,
        ),
        # Which target normals are linear neighbourhoods' guesses (a sparse LiDAR's ring): the
        # degeneracy analysis leaves them out (known for a prepared target's own normals only).
        prepared.linear
        if isinstance(prepared, PreparedTarget) and tn is not None and tn is prepared.normals
        else None,
        target_spacing,
        # The verdict's overlap pass, its searches started at these correspondences and most of
        # them settled by the outcome's certificates (``_core.overlap_statistics``'s answers).
        prepared.index if overlap_gate is not None else None,  # type: ignore[union-attr]
        overlap_gate,
        out if overlap_gate is not None else None,
        float(s.max_correspondence_distance) if fold_scene else None,
        # A sweep's motion distortion (2D scans without per-beam time): its shift's outer
        # product joins ``calibrated``.
        sweep_motion=None if s.sweep_motion is None else np.asarray(s.sweep_motion),
        **_target_sweeps(s),
    )
    if fold_scene:
        ctx.__dict__["_scene"] = num.scene
    if target_spacing is not None:
        ctx.__dict__["sampling_density_ratio"] = _density_ratio(
            target_spacing, float(num.source_spacing)
        )
    if num.source_normals is not None and "source_normals" not in ctx.__dict__:
        ctx.__dict__["source_normals"] = num.source_normals
    if held is None:
        basis = "plane_information" if num.num_plane_correspondences > dof else "hessian"
        deg = _degeneracy(num, ctx.levers, eps2, eps2_typical, basis)
    else:
        deg = held
    return _build(
        CorrespondenceAnalysis,
        {
            "degeneracy": deg,
            "point_variance": float(num.point_variance),
            "normal_variance": float(num.normal_variance),
            "valley": valley,
            "numbers": num,
            "moved": moved,
            "drift": drift,
            "correspondences": matched,
            "overlap": num.overlap,
        },
    )


def _target_sweeps(s: RegistrationSettings) -> dict[str, FloatArray | None]:
    """The binding's target sweeps: one row each of motion and ``[x, y, θ]`` origin (a scan's
    one sweep, or a map's ``target_sweeps``); nothing when the target was not swept."""
    if s.target_sweeps is not None:
        motions = [m for m, _ in s.target_sweeps]
        origins: list[tuple[float, float, float]] | None = [o for _, o in s.target_sweeps]
    elif s.target_sweep_motion is not None:
        motions = [s.target_sweep_motion]
        origins = None if s.target_sweep_origin is None else [s.target_sweep_origin]
    else:
        return {"target_sweep_motion": None, "target_sweep_origin": None}
    return {
        "target_sweep_motion": np.array(motions, dtype=np.float64),
        "target_sweep_origin": None if origins is None else np.array(origins, dtype=np.float64),
    }


def _degeneracy(
    num: Any, levers: FloatArray, eps2: float, eps2_typical: float, basis: str
) -> Degeneracy:
    """:class:`Degeneracy` from the core's eigen-analysis of ``Ĝ`` (``num``)."""
    vals = num.degeneracy_eigenvalues
    ev: list[float] = vals.tolist()
    threshold = float(num.degeneracy_threshold)
    memo: list[tuple[WeakDirection, ...]] = []

    # The direction objects are built on first read (most results are read for their
    # covariance and verdict only): both fields share them.
    def directions() -> tuple[WeakDirection, ...]:
        if not memo:
            units = num.degeneracy_directions
            top = max(ev[-1], 1e-300)
            memo.append(
                tuple(
                    WeakDirection(vector=_frozen(units[:, i]), ratio=ev[i] / top, description=text)
                    for i, text in enumerate(num.degeneracy_descriptions)
                )
            )
        return memo[0]

    def weak_directions() -> tuple[WeakDirection, ...]:
        if not any(lam < threshold for lam in ev):
            return ()
        return tuple(d for d, lam in zip(directions(), ev, strict=True) if lam < threshold)

    deg = build_lazy(
        Degeneracy,
        {
            "information": num.degeneracy_information,
            "levers": levers,
            "eigenvalues": vals,
            "threshold": threshold,
            "normal_noise": float(eps2),
            "typical_normal_noise": float(eps2_typical),
            "basis": basis,
            "num_correspondences": int(num.degeneracy_count),
            "removed_normal_noise": float(num.degeneracy_removed_normal_noise),
        },
        {"directions": directions, "weak_directions": weak_directions},
    )
    # The eigen-decomposition the bases and tilts read: the core's, not a second one.
    deg.__dict__["_eigen"] = (vals, num.degeneracy_eigenvectors)
    return deg


def _covariance_estimates(
    ctx: TrustInputs,
    out: Any,
    pose: SE2 | SE3,
    corr: CorrespondenceAnalysis,
) -> CovarianceEstimates:
    """Every covariance kind of one outcome (:class:`CovarianceEstimates`), from its
    correspondence analysis ``corr`` (the core computed them; point-to-point with target
    normals then re-solves point-to-plane/line, :func:`_via_plane_reference`)."""
    num = corr.numbers
    estimates = _build(
        CovarianceEstimates,
        {
            "hessian": num.hessian,
            "censi": num.censi,
            "block": num.block,
            "calibrated": num.calibrated,
            "point_variance": float(num.point_variance),
            "normal_variance": float(corr.normal_variance),
            "block_size": float(ctx.block_size),
            "num_blocks": int(num.num_blocks),
            "prior": _frozen(ctx.prior),
            "model_shift": num.model_shift,
        },
    )
    if ctx.plane_solve is not None:
        estimates = _via_plane_reference(ctx, pose, corr, estimates)
    return estimates


def _trust(
    ctx: TrustInputs,
    out: Any,
    pose: SE2 | SE3,
    first: CorrespondenceAnalysis | None,
) -> _Trust:
    t0 = time.perf_counter()
    s, src = ctx.settings, ctx.source
    dim = int(src.shape[1])
    dof = 3 if dim == 2 else 6
    th = ctx.thresholds
    gate = float(s.max_correspondence_distance)
    verdict_gate = gate if th.overlap_gate is None else th.overlap_gate
    if first is not None:
        corr = first
    else:
        # 2D: the verdict's overlap pass rides on the analysis's core call.
        fold = dim == 2 and isinstance(ctx.target, PreparedTarget)
        corr = correspondence_analysis(ctx, out, overlap_gate=verdict_gate if fold else None)
    deg = corr.degeneracy
    num = corr.numbers
    covariance_source = corr
    if first is None and ctx.refined_objective is not None and num.source_is_cloud:
        covariance_source = _refined_analysis(ctx)
    estimates = _covariance_estimates(ctx, out, pose, covariance_source)
    chosen = getattr(estimates, s.covariance)
    if chosen is getattr(covariance_source.numbers, s.covariance):
        info = covariance_source.numbers.information
    else:  # point-to-point's calibrated, replaced by the plane reference's
        info = (
            information_from_covariance(chosen)
            if np.isfinite(chosen).all()
            else np.zeros((dof, dof))
        )
    slide = ctx.slide
    solve_start = ctx.start if ctx.solve_start is None else ctx.solve_start
    grown = start_cover(slide, pose, solve_start, chosen, gate, th.basin_ambiguous_ratio)
    if grown is not None:
        # A re-solve from a start that explains about as much: the covariance covers both.
        chosen = _readonly(_psd(grown))
        info = information_from_covariance(chosen)
        if s.covariance == "calibrated":
            estimates = dataclasses.replace(estimates, calibrated=chosen)
    weakest = num.weakest
    cond = _build(
        Conditioning,
        {
            "eigenvalues": num.conditioning_eigenvalues,
            "eigenvectors": num.conditioning_eigenvectors,
            "condition_number": float(num.condition_number),
            "length_scale": float(num.length_scale),
            "scaled_eigenvalues": num.scaled_eigenvalues,
            "scaled_condition_number": float(num.scaled_condition_number),
            "weakest": _build(
                WeakDirection,
                {
                    "vector": weakest,
                    "ratio": float(num.weakest_ratio),
                    "description": num.weakest_description,
                },
            ),
        },
    )
    # The start returned after a slide: evaluated there, not converged there.
    stop = "slid" if slide is not None and slide.outcome == "start" else str(out.stop_reason)
    probing = th.probes_basin(dim) and ctx.solve is not None
    # The probe's tight overlap is counted in the verdict's overlap pass (one nearest-neighbour
    # search of the source instead of two: 3.7 ms of a 25k-point KITTI call) where that pass
    # sees it: a k-d tree target (exact searches) and a tight gate inside the verdict's. 3D
    # only: a 2D outcome's verdict overlap rides on the analysis's core call (``corr.overlap``)
    # and the screen counts its tight overlap alone (``basin._fraction``), which costs less
    # than widening that call.
    overlap = corr.overlap
    tight: float | None = None
    if probing and dim == 3 and isinstance(ctx.target, PreparedTarget) and math.isfinite(gate):
        tight = tight_gate(ctx.target.index, src, pose, gate, ctx.target_points)
        if tight <= verdict_gate:
            overlap = _core.overlap_statistics(
                ctx.target.index,
                src,
                pose.as_matrix(),
                verdict_gate,
                hints=corr.correspondences,
                within=tight,
                outcome=out,  # its certificates settle most searches near its pose
            )
    # The verdict reads the same eigen-analysis unless it asks for another weak ratio.
    checked = _assess_checked(
        pose,
        src,
        ctx.target,
        start=ctx.start,
        gate=verdict_gate,
        thresholds=th,
        conditioning=cond,
        converged=stop == "converged",
        stop_reason=stop,
        degeneracy=deg,
        hints=None if isinstance(ctx.target, LocalMap) else corr.correspondences,
        motion_nees=num.motion_nees,
        moved=corr.moved,
        overlap=overlap,
        outcome=out,
        slide=slide,
    )
    if checked.verdict.accepted and probing:
        # Only a result every other check accepts is probed (the restarts cannot turn a
        # rejection into an acceptance), and restarted only when cheap evidence doubts it.
        index = ctx.target.native if isinstance(ctx.target, LocalMap) else ctx.target.index
        probe = probe_basin(
            ctx.solve,
            index,
            src,
            pose,
            chosen,
            float(s.max_correspondence_distance),
            stop_ratio=th.basin_wrong_ratio,
            cover_ratio=th.basin_ambiguous_ratio,
            target_points=ctx.target_points,
            screen=th.basin_screen,
            lookalike_signal=th.basin_lookalike,
            start=ctx.start,
            motion=corr.drift,
            # In 3D only a stated start uncertainty is evidence: the gate-wide default made an
            # ordinary 0.7 m KITTI step "beyond 1σ" and tripled the call; wrong 3D starts are
            # rejected without it (wrong_start.py: none accepted from 30°/60°).
            prior=ctx.prior if dim == 2 or ctx.init_covariance is not None else None,
            stated_prior=ctx.init_covariance,
            inlier_rmse=checked.report.residual_rmse,
            target_normals=ctx.target_normals,
            tight_overlap=_tight_overlap(ctx, overlap, tight),
            correlative_grid=ctx.target._probe_grid
            if isinstance(ctx.target, PreparedTarget) and dim == 2
            else None,
            symmetry=ctx.target._symmetry
            if isinstance(ctx.target, PreparedTarget) and ctx.target.normals is not None
            else None,
        )
        # (5 of the probe screen's µs on a 2D scan went to dataclasses.replace)
        report = _replaced(checked.report, basin=probe)
        # Only an alternative can add a reason: without one the verdict stands as judged.
        verdict = judge(report, th) if probe.alternative is not None else checked.verdict
        checked = _build(Assessment, {"report": report, "verdict": verdict})
        if probe.covered:
            # Part of the calibrated covariance: alternatives in the same basin it must cover.
            chosen = _readonly(_psd(chosen + probe.growth))
            info = information_from_covariance(chosen)
            if s.covariance == "calibrated":
                estimates = dataclasses.replace(estimates, calibrated=chosen)
    return _build(
        _Trust,
        {
            "covariance": chosen,
            "information": _readonly(info),
            "conditioning": cond,
            "covariances": estimates,
            "degeneracy": deg,
            "quality": checked.report,
            "verdict": checked.verdict,
            "seconds": time.perf_counter() - t0,
        },
    )


def _refined_analysis(ctx: TrustInputs) -> CorrespondenceAnalysis:
    """The correspondence analysis of the refinement's narrow objective (gate and Cauchy kernel
    of :func:`scanreg.slide.refined_objective`) at the pose returned, which is its minimum:
    the covariances of a 2D source that is not one scan after
    :func:`~scanreg.slide.refine_in_basin`.

    The covariance describes the estimator whose result is returned. Between two clouds that are
    not one scan each (merged submaps, a map), the pairs the registration's wide gate adds to
    the narrow objective's are mostly surfaces only one of the clouds sampled: not point noise,
    and not pairs the returned pose depends on, yet read at the returned pose they made the
    point variance many times the samples' and the block scores carry the wide objective's pull
    towards its own minimum (merged submaps: mean NEES 0.93 against the ideal 3). The scales
    that are the scene's, not the objective's — the block size, the sampling term's step cut,
    the gate-wide prior — stay the registration's. A single scan keeps the registration's
    pairs: read over the narrow objective's, split-beam pairs fell outside their ellipse
    (Intel 1 of 35 and MbICP 1 of 39, none before) and wrong_start.py's accepted Intel results
    outside theirs went 31 → 46; why is not established (``docs/calibration.md``, "after the
    refinement in the basin")."""
    outcome, kernel = ctx.refined_objective()
    return correspondence_analysis(ctx, outcome, kernel=kernel)


def _tight_overlap(
    ctx: TrustInputs, overlap: Any, tight: float | None
) -> tuple[float, float] | None:
    """The result's fraction of the source within the basin probe's tight gate when it was
    counted already: in the verdict's overlap pass (3D), or by the never-worse-than-the-start
    check at the pose returned (its gate is the probe's when the registration's is finite)."""
    if overlap is not None and tight is not None:
        return tight, float(overlap[5]) / float(ctx.source.shape[0])
    slide = ctx.slide
    if slide is not None and math.isfinite(ctx.settings.max_correspondence_distance):
        return slide.gate, slide.returned_fit
    return None


def residual_variance(out: Any, components: int, kernel: str, dof: int) -> float:
    """σ̂² of the core's outcome: the residual sum of squares over ``m − dof`` scalar
    residuals (``m`` IRLS-weighted under a kernel); NaN with too few."""
    if kernel == "none":
        m = components * float(out.num_correspondences)
        return float(out.sum_squares / (m - dof)) if m > dof else math.nan
    m = components * float(out.irls_weight_sum)
    return float(out.irls_sum_squares / (m - dof)) if m > dof else math.nan


def has_normals(target: PreparedTarget | LocalMap) -> bool:
    if isinstance(target, LocalMap):
        return target.attributes == "normals"
    return target.normals is not None


def _via_plane_reference(
    ctx: TrustInputs,
    pose: SE2 | SE3,
    corr: CorrespondenceAnalysis,
    estimates: CovarianceEstimates,
) -> CovarianceEstimates:
    """Point-to-point's ``calibrated``: the point-to-plane/line estimate's, plus the offset
    between the two as ``δδᵀ`` (``model_shift``).

    Two scans sample a surface at different places; point-to-point pairs each point with a
    neighbour up to half a spacing along the surface and settles where those offsets balance,
    a bias no noise model at its pose sees (its ``censi`` and ``block`` are 10× over-confident
    in the simulated room). The point-to-plane/line estimate does not carry it (its own
    ``calibrated`` is consistent there). So: re-solve point-to-plane/line from the
    point-to-point pose (held where the solve was), analyse that as any registration (the
    same start, so the same drift and prior along weak directions), and add the offset
    ``log(T̂⁻¹ T̂_plane)`` on the well-determined subspace. The error is that offset plus the
    reference's error. If the re-solve fails, the one-step estimate stays.
    """
    out = ctx.plane_solve(pose)
    if str(out.stop_reason) not in ("converged", "max_iterations"):
        return estimates
    dim = int(ctx.source.shape[1])
    ref_ctx = dataclasses.replace(ctx, method=PLANE_METHOD[dim], components=1, plane_solve=None)
    for name in ("_scene", "block_size", "source_normals", "sampling_density_ratio"):
        # The same source and settings: its scene pass and sampled normals once per call.
        if name in ctx.__dict__:
            ref_ctx.__dict__[name] = ctx.__dict__[name]
    aware = ctx.settings.degeneracy_aware  # the solve's weak directions and valley, as register's
    ref_corr = correspondence_analysis(
        ref_ctx,
        out,
        held=corr.degeneracy if aware else None,
        valley=corr.valley if aware else None,
    )
    ref_pose = pose_from_core(out, dim)
    ref = _covariance_estimates(ref_ctx, out, ref_pose, ref_corr)
    cal = np.asarray(ref.calibrated)
    if not np.isfinite(cal).all():
        return estimates
    s_inv = corr.degeneracy.scaling()
    u = corr.degeneracy.strong_basis()
    offset = (pose.inverse() @ ref_pose).log() / s_inv  # type: ignore[operator]
    shift = (u @ (u.T @ offset)) * s_inv
    return dataclasses.replace(
        estimates,
        calibrated=_readonly(_psd(cal + np.outer(shift, shift))),
        model_shift=_frozen(shift),
    )


def _psd(cov: FloatArray) -> FloatArray:
    """``cov`` with round-off negative eigenvalues set to zero (a noise-free fit leaves
    variances of ±1e-54: a negative one would make its standard deviation NaN)."""
    if not np.isfinite(cov).all():
        return cov
    vals, vecs = np.linalg.eigh(0.5 * (cov + cov.T))
    if vals[0] >= 0.0:
        return cov
    out: FloatArray = (vecs * np.maximum(vals, 0.0)) @ vecs.T
    return out


def valley_moment(
    solve: Any, pose: SE2 | SE3, deg: Degeneracy, prior: FloatArray, gate: float
) -> FloatArray:
    """How the well-determined coordinates follow the held weak ones, over the prior's range.

    The degeneracy-aware solve holds the weak coordinates at the initial guess and solves the
    rest *for that value*. Where the truth lies elsewhere along the axis (by ``σ_w``, the
    prior's), the rest would have come out differently: as the held value moves, the matched
    points and their normals change (a corridor's lateral estimate follows the along-axis
    one by ~0.008 m/m, ``benchmarks/corridor_coupling.py``), which no linearisation at the
    final pose sees. Measured by solving again, held, from ``±h`` along each weak direction
    (``h = min(σ_w, gate / 2)``, inside the basin): where the strong coordinates land,
    ``e₊`` and ``e₋`` (scaled coordinates, strong subspace), give the coupling
    ``b = (e₊ − e₋) / 2h`` and the term ``σ_w² b bᵀ`` (:func:`valley_coupling`).
    With one held solve failed, the other's ``e / h`` stands for ``b``; with both, nothing.
    """
    s_inv = deg.scaling()
    w = deg.weak_basis()
    dof = s_inv.size
    dim = 2 if dof == 3 else 3
    u = deg.strong_basis()
    prior_s = prior / np.outer(s_inv, s_inv)
    out = np.zeros((dof, dof))
    inverse = pose.inverse()
    for i in range(w.shape[1]):
        var = float(w[:, i] @ prior_s @ w[:, i])
        h = math.sqrt(var)
        if math.isfinite(gate):
            h = min(h, gate / 2.0)
        if not h > 0.0:
            continue
        landed: list[FloatArray | None] = []
        for sign in (1.0, -1.0):
            held = solve(pose @ type(pose).exp(sign * h * w[:, i] * s_inv))  # type: ignore[operator]
            if str(held.stop_reason) not in ("converged", "max_iterations"):
                landed.append(None)
                continue
            e = (inverse @ pose_from_core(held, dim)).log() / s_inv  # type: ignore[operator]
            landed.append(u @ (u.T @ e))
        b = valley_coupling(landed[0], landed[1], h)
        if b is not None:
            out += var * np.outer(b, b)
    return out


def valley_coupling(
    plus: FloatArray | None, minus: FloatArray | None, h: float
) -> FloatArray | None:
    """How far the strong coordinates move per unit of the held weak one: ``(e₊ − e₋) / 2h``
    from the held re-solves at ``±h`` (``None`` for a failed one; with one, ``e / h``).

    Only the antisymmetric part. Each re-solve matches a different sampling of the surfaces
    (the source slid by ``h`` along the axis), which moves the strong coordinates at random:
    held re-solves in the corridor from ``+h, +h/2, −h/2, −h`` (``h`` = 0.1 m) land 2–45 mdeg
    apart in heading, not monotonically. That jitter is the estimate's own sampling error,
    which ``censi``, ``block`` and the 2D sampling term already cover at the estimate, and
    the error holds one draw of it; the second moment of both offsets counted it about twice
    more (each offset is the difference of two draws). The symmetric part ``(e₊ + e₋)/2``
    would be the valley's curvature, and a degenerate valley has none: it is a symmetry of
    the scene (a translation along a corridor, a rotation about a round tunnel's axis), a
    one-parameter subgroup through the estimate, a straight line in the tangent
    ``log(T̂⁻¹ T)``; so it carries jitter only. The antisymmetric part keeps a real coupling
    (a corridor's lateral estimate following the held along-axis one) exactly.
    ``benchmarks/covariance_calibration.py`` (prior rows, 100 realisations): corridor
    0.49 / 0.71 / 0.64 → 0.53 / 0.99 / 0.80 × dof (point-to-point / point-to-plane / GICP),
    the across-axis part 0.24 / 0.57 / 0.46 → 0.30 / 0.98 / 0.70 with the weak axis at 1.00."""
    if plus is not None and minus is not None:
        return (plus - minus) / (2.0 * h)
    one = plus if plus is not None else minus
    return None if one is None else one / h


__all__ = ["MIN_NORMAL_AGREEMENT", "CovarianceEstimates"]
