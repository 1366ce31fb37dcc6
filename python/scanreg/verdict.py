"""Accept or reject a registration, and say why.

:func:`assess` measures a registration result against its inputs — overlap within a gate,
residual statistics, conditioning, how far the estimate moved from the initial guess,
convergence — and checks each against :class:`VerdictThresholds`. The verdict lists every
failed check as a readable reason (``"overlap 0.18 < 0.50"``,
``"degenerate: translation along (1.00, 0.00, 0.00)"``), so a pipeline can log it or act on it.

Defaults, and the experiment behind them (``benchmarks/verdict_thresholds.py``, recorded in
``docs/calibration.md``): ``min_overlap = 0.5`` (half of the source must lie on the target, the
seed's gate test); the residual bound is half the gate — with a generous 1 m gate a quarter
would separate better (correct registrations up to 0.17 of it, wrong ones with overlap ≥ 0.5
from 0.24; half the gate accepted 28 of 80 wrong office registrations), but with the tight
0.3 m gate of the Intel scan-to-map pipeline correct registrations reach 0.37 of the gate, so
set ``max_inlier_rmse`` from the sensor when the gate is generous; degeneracy
comes from the registration's own analysis (:mod:`scanreg.degeneracy`), whose threshold is
set by the measured normal noise, or else the conditioning's scaled eigenvalue ratio.

The contract: **an accepted result's error lies inside its covariance** (χ² at the stated
confidence), **or the verdict rejects it**. None of the checks above sees a result that
converged, tightly, in the wrong basin (a start turned by 50°; a square room turned by 90°):
:mod:`scanreg.basin` restarts the registration around the result, and the verdict rejects
with ``"wrong basin: …"`` when another pose explains clearly more of the scan
(``basin_wrong_ratio``), ``"ambiguous: …"`` when one explains about as much
(``basin_ambiguous_ratio``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from . import _core
from ._validate import FloatArray, LazyFields, as_points, build, build_lazy
from .basin import BasinProbe
from .degeneracy import Degeneracy
from .local_map import LocalMap
from .pinned import _weak_fit_loss, pinned
from .quality import DEFAULT_WEAK_RATIO, Conditioning, conditioning
from .slide import SlideCheck
from .target import PreparedTarget, prepare
from .transform import SE2, SE3, as_pose


def _nonnegative(value: float, name: str, *, allow_inf: bool = True) -> float:
    v = float(value)
    if math.isnan(v) or v < 0 or (not allow_inf and math.isinf(v)):
        raise ValueError(f"{name}: must be >= 0{'' if allow_inf else ' and finite'}, got {value}")
    return v


#: χ²(D) at 99.9 % for the translation of D = 2, 3.
_CHI2_999 = {2: 13.816, 3: 16.266}


@dataclass(frozen=True)
class VerdictThresholds:
    """What a registration must satisfy to be accepted (validated on construction)."""

    #: Least fraction of source points with a target point within ``overlap_gate``.
    min_overlap: float = 0.5
    #: The overlap gate δ (units of the points); ``None``: the registration's own gate.
    overlap_gate: float | None = None
    #: Largest RMS distance over the overlapping points; ``None``: half the overlap gate.
    max_inlier_rmse: float | None = None
    #: A scaled eigen-direction weaker than this (ratio to the strongest) is degenerate.
    weak_ratio: float = DEFAULT_WEAK_RATIO
    #: Largest translation of the estimate away from the initial guess (a motion bound).
    max_translation: float = math.inf
    #: Largest rotation (radians) of the estimate away from the initial guess.
    max_rotation: float = math.inf
    #: Reject results that did not converge.
    require_convergence: bool = True
    #: Reject results with a weak direction (``result.degeneracy``, whose threshold is derived
    #: from the measured normal noise; results without one fall back to ``weak_ratio``).
    reject_degenerate: bool = True
    #: Probe for other basins (:mod:`scanreg.basin`): ``None`` (default) and ``True``: yes,
    #: in 2D and 3D, restarting only when cheap evidence doubts the basin (``basin_screen``);
    #: ``False``: never.
    basin_probe: bool | None = None
    #: Restart the registration only when cheap evidence doubts the basin (a low fit margin,
    #: a move beyond 1σ of the start's covariance, symmetric walls:
    #: :func:`scanreg.basin.basin_doubts`); ``False``: restart for every result.
    basin_screen: bool = True
    #: The screen's fourth signal in 2D, a look-alike pose along the result's least-determined
    #: translation (:func:`scanreg.basin.along_axis_lookalike`: corridors whose doors and
    #: pillars repeat). Off by default: twelve neighbour passes on every result the other
    #: signals leave alone made the default Intel call 2.1x the call without the probe
    #: (1.5x without it), for 2 of 1800 wrong-start results (and 2 correct ones rejected);
    #: the accepted results outside their covariance stay at 0.6 % (Intel) without it.
    basin_lookalike: bool = False
    #: Reject as a wrong basin when a distinct alternative explains more than this times the
    #: result's fraction of the source within the probe's tight gate.
    basin_wrong_ratio: float = 1.05
    #: Reject as ambiguous when it explains at least this times as much (and not more than
    #: ``basin_wrong_ratio``).
    basin_ambiguous_ratio: float = 0.95
    #: Least fraction of the source with a target point within the tight gate (a tenth of the
    #: registration's gate, the wrong-basin probe's) at the pose returned, as
    #: :func:`scanreg.register`'s never-worse-than-the-start check counted it (results without
    #: that check are not tested). Below it the fit is too loose to rank poses — the floor
    #: below which the refinement in the basin does not run either
    #: (:data:`scanreg.slide.REFINE_MIN_START_FIT`) — and a result can sit a metre off with
    #: its overlap and inlier RMSE inside the generous default gate: on the Freiburg
    #: hospital's Kümmerle relation pairs (``benchmarks/wrong_start.py``) accepted results
    #: with 1-10 % of the scan within 0.1 m were 0.3-1.4 m off, outside their covariance, where
    #: the relation itself fitted 12-23 %. Chosen on the other four 2D logs and reported on the
    #: hospital (``benchmarks/README.md``): no floor up to 0.27 rejects a correct result on Intel,
    #: MbICP or the Intel and ACES relation pairs. ``0``: no test.
    min_tight_fit: float = 0.2
    #: Reject a translation from the initial guess beyond this χ²(D) of its covariance (99.9 %
    #: for D = 2 and 3 by default; ``inf``: never). With the default gate-wide prior
    #: (σ = gate/√3 per axis) that is about 2.1 gates in 2D: ICP converges only from within
    #: about a gate, so a result that slid further ran along something (MbICP self-matches
    #: accepted 3-4.6 m off from starts 0.6 m away). Rotation is not tested: a correct result
    #: from a start turned by 70° turns 70°.
    max_motion_chi2: float | None = None

    def __post_init__(self) -> None:
        if not 0.0 <= float(self.min_overlap) <= 1.0:
            raise ValueError(f"min_overlap: must be in [0, 1], got {self.min_overlap}")
        if not 0.0 <= float(self.min_tight_fit) <= 1.0:
            raise ValueError(f"min_tight_fit: must be in [0, 1], got {self.min_tight_fit}")
        if self.overlap_gate is not None:
            _nonnegative(self.overlap_gate, "overlap_gate", allow_inf=False)
            if self.overlap_gate == 0:
                raise ValueError("overlap_gate: must be > 0")
        if self.max_inlier_rmse is not None:
            _nonnegative(self.max_inlier_rmse, "max_inlier_rmse")
        if not 0.0 < float(self.weak_ratio) < 1.0:
            raise ValueError(f"weak_ratio: must be in (0, 1), got {self.weak_ratio}")
        _nonnegative(self.max_translation, "max_translation")
        _nonnegative(self.max_rotation, "max_rotation")
        if self.basin_probe is not None and not isinstance(self.basin_probe, bool):
            raise TypeError(
                f"basin_probe: expected a bool or None, got {type(self.basin_probe).__name__}"
            )
        if not isinstance(self.basin_screen, bool):
            raise TypeError(
                f"basin_screen: expected a bool, got {type(self.basin_screen).__name__}"
            )
        if not isinstance(self.basin_lookalike, bool):
            raise TypeError(
                f"basin_lookalike: expected a bool, got {type(self.basin_lookalike).__name__}"
            )
        _nonnegative(self.basin_wrong_ratio, "basin_wrong_ratio", allow_inf=True)
        _nonnegative(self.basin_ambiguous_ratio, "basin_ambiguous_ratio", allow_inf=True)
        if self.max_motion_chi2 is not None:
            _nonnegative(self.max_motion_chi2, "max_motion_chi2")
        if self.basin_ambiguous_ratio > self.basin_wrong_ratio:
            raise ValueError(
                f"basin_ambiguous_ratio: must be <= basin_wrong_ratio "
                f"({self.basin_ambiguous_ratio} > {self.basin_wrong_ratio})"
            )

    def probes_basin(self, dim: int) -> bool:
        """Whether a ``dim``-D result is probed for other basins."""
        return self.basin_probe is not False


@dataclass(frozen=True)
class QualityReport(LazyFields):
    """Measurements behind a verdict (units of the points; angles in radians)."""

    #: Fraction of source points whose nearest target point is within ``gate``.
    overlap: float
    gate: float
    num_source_points: int
    #: Distances to the nearest target point over the overlapping points.
    residual_mean: float
    residual_median: float
    residual_rmse: float
    #: RMS of the lowest 90 % of those distances (robust to a few wrong matches).
    residual_trimmed_rmse: float
    translation_from_init: float
    rotation_from_init: float
    converged: bool
    stop_reason: str
    conditioning: Conditioning
    #: The registration's degeneracy analysis, when it has one.
    degeneracy: Degeneracy | None = None
    #: The wrong-basin / ambiguity probe (:mod:`scanreg.basin`), when it ran.
    basin: BasinProbe | None = None
    #: ``tᵀ P_t⁻¹ t`` of the registration's translation from its own start against the
    #: translation block of that start's covariance (``init_covariance``, or the gate-wide
    #: prior), when known.
    motion_nees: float | None = None
    #: The registration's never-worse-than-the-start check (:mod:`scanreg.slide`), when it
    #: ran: a result that returned its start after a slide is rejected, naming both fits.
    slide: SlideCheck | None = None
    #: 2D: for each weak direction of ``degeneracy``, the least fraction of the source lost
    #: from the tight gate when the pose moves along it (:func:`scanreg.pinned.weak_fit_loss`,
    #: measured when read; None without a weak direction). When no other check rejects the
    #: result, a direction whose loss reaches the analysis's threshold is not named degenerate.
    #: (A default factory: a plain default would sit on the class and hide the lazy value.)
    weak_fit_loss: tuple[float, ...] | None = field(default_factory=lambda: None)


@dataclass(frozen=True)
class Verdict:
    accepted: bool
    #: One readable line per failed check; empty when accepted.
    reasons: tuple[str, ...] = field(default=())

    def __bool__(self) -> bool:
        return self.accepted


@dataclass(frozen=True)
class Assessment:
    report: QualityReport
    verdict: Verdict


def assess(
    result: Any,
    source: Any,
    target: Any,
    *,
    init: Any = None,
    thresholds: VerdictThresholds | None = None,
) -> Assessment:
    """Measure a registration ``result`` (``pose``, ``hessian``, ``converged``, ``stop_reason``,
    and ``settings.max_correspondence_distance`` as from :func:`scanreg.register`) and judge it.

    ``source`` are the registered source points (source frame), ``target`` the target points,
    a :class:`~scanreg.PreparedTarget` or a :class:`~scanreg.LocalMap`; ``init`` the initial
    guess it started from (identity when ``None``).
    """
    th = VerdictThresholds() if thresholds is None else thresholds
    if not isinstance(th, VerdictThresholds):
        raise TypeError(f"thresholds: expected VerdictThresholds, got {type(th).__name__}")
    pose = result.pose
    if not isinstance(pose, SE2 | SE3):
        raise TypeError(f"result: its pose must be SE2 or SE3, got {type(pose).__name__}")
    dim = pose.DIM
    src = as_points(source, "source", dim=dim)
    tgt = (
        target
        if isinstance(target, PreparedTarget | LocalMap)
        else prepare(as_points(target, "target", dim=dim), normals=False)
    )
    if tgt.dim != dim:
        raise ValueError(f"target: is {tgt.dim}D but the result is {dim}D")
    gate = th.overlap_gate
    if gate is None:
        gate = float(result.settings.max_correspondence_distance)
    start = type(pose).identity() if init is None else as_pose(init, "init", dim)
    cond = result.conditioning
    if not isinstance(cond, Conditioning):
        cond = conditioning(np.asarray(result.hessian, dtype=np.float64), dim, cond.length_scale)
    return _assess_checked(
        pose,
        src,
        tgt,
        start=start,
        gate=gate,
        thresholds=th,
        conditioning=cond,
        converged=bool(result.converged),
        stop_reason=str(result.stop_reason),
        degeneracy=getattr(result, "degeneracy", None),
        basin=_registration_probe(result) if th.probes_basin(dim) else None,
        motion_nees=getattr(getattr(result, "quality", None), "motion_nees", None),
        slide=getattr(result, "slide", None),
    )


def _registration_probe(result: Any) -> BasinProbe | None:
    """The probe :func:`scanreg.register` ran on this very pose (the restarts need its solve),
    or None."""
    quality = getattr(result, "quality", None)
    probe = getattr(quality, "basin", None)
    return probe if isinstance(probe, BasinProbe) else None


def _assess_checked(
    pose: SE2 | SE3,
    source: FloatArray,
    target: PreparedTarget | LocalMap,
    *,
    start: SE2 | SE3,
    gate: float,
    thresholds: VerdictThresholds,
    conditioning: Conditioning,
    converged: bool,
    stop_reason: str,
    degeneracy: Degeneracy | None,
    hints: Any = None,
    basin: BasinProbe | None = None,
    prior: FloatArray | None = None,
    motion_nees: float | None = None,
    moved: SE2 | SE3 | None = None,
    overlap: tuple[Any, ...] | None = None,
    outcome: Any = None,
    slide: SlideCheck | None = None,
) -> Assessment:
    """:func:`assess` on inputs already checked (``source`` validated, ``target`` prepared
    and of the pose's dimension, ``conditioning`` at ``thresholds.weak_ratio``): what
    :func:`scanreg.register` calls, with no second validation of its own arrays. ``prior``:
    the covariance of ``start`` (the motion check is measured from it); else ``motion_nees``,
    the registration's own (measured from *its* start); ``moved``: ``start⁻¹ · pose`` when the
    caller has it already. ``hints``:
    the registration's final correspondences (int64, ``-1`` for none), where the overlap
    search starts (same result, faster). ``overlap``: ``_core.overlap_statistics`` at ``pose``
    within ``gate`` when the caller has it already (the trust analysis counts the wrong-basin
    probe's tight overlap in the same pass). ``outcome``: the registration's core outcome at
    ``pose`` against ``target``, whose search certificates answer most of the overlap's queries
    (the same answers, to the bit)."""
    is_map = isinstance(target, LocalMap)
    if is_map and not math.isfinite(gate):
        raise ValueError(f"max_distance: must be finite and >= 0, got {gate}")
    index = target.native if isinstance(target, LocalMap) else target.index
    if overlap is None:
        overlap = _core.overlap_statistics(
            index, source, pose.as_matrix(), gate, hints=hints, outcome=outcome
        )
    num_found, *stats = overlap
    if moved is None:
        moved = start.inverse() @ pose  # type: ignore[operator]
    if prior is not None:
        d = pose.DIM
        block = np.asarray(prior, dtype=np.float64)[:d, :d]
        t = np.asarray(moved.translation, dtype=np.float64)
        try:
            motion_nees = float(t @ np.linalg.solve(block, t))
        except np.linalg.LinAlgError:
            motion_nees = None
    weak = (
        degeneracy is not None
        and pose.DIM == 2
        and any(lam < degeneracy.threshold for lam in np.asarray(degeneracy.eigenvalues).tolist())
    )
    # Built without the dataclass __init__ (every field is checked here already); the motion
    # from the start is measured when read (the verdict reads it only under a finite bound).
    report = build_lazy(
        QualityReport,
        {
            "overlap": num_found / source.shape[0],
            "gate": gate,
            "num_source_points": int(source.shape[0]),
            "residual_mean": stats[0],
            "residual_median": stats[1],
            "residual_rmse": stats[2],
            "residual_trimmed_rmse": stats[3],
            "converged": converged,
            "stop_reason": stop_reason,
            "conditioning": conditioning,
            "degeneracy": degeneracy,
            "basin": basin,
            "motion_nees": motion_nees,
            "slide": slide,
        },
        {
            # Does the scan itself hold a weak result there? Measured when read: the verdict
            # reads it only for a result no other check rejects.
            "weak_fit_loss": lambda: (
                _weak_fit_loss(target, source, pose, degeneracy, gate)  # type: ignore[arg-type]
                if weak and degeneracy is not None
                else None
            ),
            "translation_from_init": lambda: float(np.linalg.norm(moved.translation)),
            "rotation_from_init": lambda: (
                float(moved.angle) if pose.DIM == 3 else abs(float(moved.angle))
            ),
        },
    )
    return build(Assessment, {"report": report, "verdict": judge(report, thresholds)})


def judge(report: QualityReport, thresholds: VerdictThresholds) -> Verdict:
    """Apply ``thresholds`` to a :class:`QualityReport`."""
    th = thresholds
    reasons: list[str] = []
    slid = report.slide is not None and report.slide.outcome == "start"
    if slid:
        assert report.slide is not None
        reasons.append(report.slide.describe())
    elif th.require_convergence and not report.converged:
        reasons.append(f"not converged: {report.stop_reason}")
    if report.overlap < th.min_overlap:
        reasons.append(f"overlap {report.overlap:.2f} < {th.min_overlap:.2f}")
    if not slid and report.slide is not None and report.slide.returned_fit < th.min_tight_fit:
        reasons.append(
            f"loose fit: {report.slide.returned_fit:.0%} of the source within "
            f"{report.slide.gate:.3g} < {th.min_tight_fit:.0%}"
        )
    max_rmse = 0.5 * report.gate if th.max_inlier_rmse is None else th.max_inlier_rmse
    if not report.residual_rmse <= max_rmse:  # also rejects nan (no overlap at all)
        reasons.append(f"inlier RMSE {report.residual_rmse:.3g} > {max_rmse:.3g}")
    # Weak directions of the analysis, named after the other checks (below) unless the scan
    # pins them (:mod:`scanreg.pinned`), at this place in the list.
    weak_at, weak_deg = len(reasons), None
    if th.reject_degenerate:
        deg = report.degeneracy
        if deg is not None:
            # Its directions (built on first read) only where one is below the threshold.
            threshold = deg.threshold
            if any(lam < threshold for lam in np.asarray(deg.eigenvalues).tolist()):
                weak_deg = deg
        elif report.conditioning.weakest.ratio < th.weak_ratio:
            # No Degeneracy analysis behind this result: the one number that stands in for it.
            weak = report.conditioning.weakest
            reasons.append(f"degenerate: {weak.description} (ratio {weak.ratio:.1e})")
    # An infinite bound (the default) rejects nothing: the motion is not read for it.
    if th.max_translation < math.inf and report.translation_from_init > th.max_translation:
        reasons.append(
            f"moved {report.translation_from_init:.3g} from the initial guess "
            f"> bound {th.max_translation:.3g}"
        )
    if th.max_rotation < math.inf and report.rotation_from_init > th.max_rotation:
        reasons.append(
            f"rotated {math.degrees(report.rotation_from_init):.3g}° from the initial guess "
            f"> bound {math.degrees(th.max_rotation):.3g}°"
        )
    if report.motion_nees is not None:
        dim = 2 if report.conditioning.eigenvalues.size == 3 else 3
        bound = _CHI2_999[dim] if th.max_motion_chi2 is None else th.max_motion_chi2
        if report.motion_nees > bound:
            reasons.append(
                f"slid beyond the uncertainty of its start: translation χ² "
                f"{report.motion_nees:.3g} > {bound:.3g}"
            )
    if weak_deg is not None:
        # The pin is measured only for a result nothing else rejects (15 nearest-neighbour
        # passes a weak direction): otherwise the analysis's word stands.
        held = pinned(None if reasons else report.weak_fit_loss, weak_deg)
        named = [
            f"degenerate: {w.description} (constraint {lam:.2g} < {weak_deg.threshold:.2g})"
            for i, (w, lam) in enumerate(
                zip(weak_deg.directions, weak_deg.eigenvalues.tolist(), strict=True)
            )
            if lam < weak_deg.threshold and not held[i]
        ]
        reasons[weak_at:weak_at] = named
    probe = report.basin
    if probe is not None and probe.alternative is not None:
        ratio = probe.ratio
        if ratio > th.basin_wrong_ratio:
            reasons.append(f"wrong basin: {probe.describe()}")
        elif ratio >= th.basin_ambiguous_ratio:
            reasons.append(f"ambiguous: {probe.describe()}")
    return build(Verdict, {"accepted": not reasons, "reasons": tuple(reasons)})
