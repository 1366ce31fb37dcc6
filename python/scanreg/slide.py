"""Never worse than the start: a registration does not return a pose that explains the scan
clearly worse than the pose it started from.

ICP settles at the minimum of its cost over the pairs inside its gate. With a generous gate (the
default 1 m) and no kernel, pairs that are not the same surface (a wall seen by one scan only, a
table's legs, the far side of a doorway) pull even a right start away, to a minimum where far
fewer points lie on the target. Measured on Kümmerle relations (scan t2 matched to scan t1 with
the default point-to-line call, started *at* the relation pose; the first 400 relations under
10 s apart; ``benchmarks/relation_slide.py``): 35 Intel and 33 ACES results ended more than
0.15 m or 2° from their start, 23 and 30 of them accepted by the verdict, at poses where a median
81 % of the scan within 0.1 m at the start became 52 % (Intel; ACES 83 % → 67 %).

The guard (:func:`guard_start`) compares the fraction of source points with a target point
within the tight gate (the wrong-basin probe's, :func:`scanreg.basin.tight_gate`: a tenth of the
registration's gate) at the start and where the solve ended — two nearest-neighbour passes that
stop at the first point inside the gate. When the end explains clearly less
(:data:`SLIDE_RATIO`, :data:`SLIDE_MIN_DROP`) than a start that fits well
(:data:`SLIDE_MIN_START_FIT`), the solve runs again from the start with a
narrower gate (:data:`RESOLVE_GATE_FRACTION` of the gate: a start that fits that many points
within a tenth of the gate is well inside it) and that result is kept when it explains at least
:data:`SLIDE_RATIO` of what the start does. Otherwise the start itself is returned
(``stop_reason == "slid"``) and the verdict rejects it, naming both fits.

Thresholds from the relation pairs above (no per-log tuning): flagging below 0.9 of the start's
fraction caught 27 of 35 wrong Intel results (11 correct results flagged too, all re-solved to
within 0.15 m / 2°) and 26 of 33 on ACES (19 correct flagged); the re-solve at a fifth of the gate
ended within 0.15 m / 2° on every flagged pair it kept (Intel 38 of 38, ACES 42 of 45; the other
3 returned their start, rejected). Below 0.85 caught fewer (23 / 21) and, accepting re-solves
down to 0.85, kept one wrong ACES result. With :data:`SLIDE_MIN_START_FIT` as well (final
figures, ``benchmarks/relation_slide.py``): Intel wrong 35 → 11, accepted and wrong 23 → 3,
median error 2.49 → 2.11 cm; ACES 33 → 7, 30 → 4, 4.41 → 3.28 cm; from the wheel odometry's
relative pose instead of the relation, Intel 35 → 22, 21 → 10, ACES 38 → 15, 31 → 8.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from . import _core
from ._validate import FloatArray
from ._validate import build as _build
from .basin import CHI2_999, NEAR_ROTATION_DEG, tight_gate
from .quality import covariance_upper_bound
from .transform import SE2, SE3

#: The end explains clearly less than the start below this fraction of the start's fit ...
SLIDE_RATIO = 0.9
#: ... and by at least this fraction of the source (a few points of a sparse fit are noise).
SLIDE_MIN_DROP = 0.05
#: Only a start that explains at least this fraction of the source within the tight gate is
#: defended (the verdict's ``min_overlap``, here at the tight gate). Below it the fits are too
#: sparse to rank poses: in a simulated ring corridor (tests/test_mapping.py) a prediction
#: 0.52 m and 10° off explained 28 % of a scan within 3 cm against 21 % for a solve 0.19 m and
#: 1.5° off, and re-solving from it cost the odometry 10° (end error 0.09 m -> 1.9 m). On the
#: relation pairs this floor leaves 3 of 27 flagged wrong Intel results (starts at 20-45 %).
SLIDE_MIN_START_FIT = 0.5
#: The re-solve from the start runs with this fraction of the registration's gate (twice the
#: tight gate; a fifth and three tenths ended alike on the relation pairs, a tenth kept one
#: wrong ACES result).
RESOLVE_GATE_FRACTION = 0.2
#: The narrow robust refinement (:func:`refine_in_basin`) runs with this fraction of the
#: registration's gate and a Cauchy kernel of a third of that.
REFINE_GATE_FRACTION = 0.3
#: ... only from a start that explains at least this fraction of the source within the tight
#: gate: the Intel pairs of tests/test_basin.py turned by 60° start at 1-15 % (refined from
#: there, 3 of 14 accepted results were wrong and outside their ellipse); the relation pairs'
#: odometry starts mostly above (on the hospital's, a floor of 0.5 kept 136 wrong of 400
#: against 57 with none).
REFINE_MIN_START_FIT = 0.2

#: Truncated costs closer than this relative difference are ties (round-off: a frame far
#: from the points changes the last digits; tests/test_frames.py).
COST_TIE = 1e-6

SlideOutcome = Literal["kept", "resolved", "start"]
RefinedFrom = Literal["off", "start", "from start", "from end"]


@dataclass(frozen=True)
class SlideCheck:
    """What :func:`guard_start` measured and did (units of the points)."""

    #: The tight gate the fits are counted within.
    gate: float
    #: Fraction of source points with a target point within ``gate`` at the start ...
    start_fit: float
    #: ... and where the solve ended.
    end_fit: float
    #: ``kept``: the solve's end (not clearly worse than the start); ``resolved``: the solve
    #: slid, the re-solve from the start with ``resolve_gate`` fits about as well as the start
    #: and is returned; ``start``: it slid too, the start is returned (the verdict rejects it).
    outcome: SlideOutcome
    #: The re-solve's gate and fit (NaN when it did not run).
    resolve_gate: float = math.nan
    resolved_fit: float = math.nan
    #: What the refinement in the basin (:func:`refine_in_basin`) returned: ``off`` (it did
    #: not run), ``start`` (the start fits best: returned), ``from start`` / ``from end``
    #: (the narrow solve from there).
    refined: RefinedFrom = "off"
    #: The fit of the pose the refinement returned (NaN when it did not run).
    refined_fit: float = math.nan
    #: The refinement's iterations (0 when it did not run or returned the start).
    refined_iterations: int = 0
    #: The fit of the pose returned after the hold of a degenerate refined result
    #: (``RegistrationSettings.hold_degenerate``), which re-solves held along the weak
    #: directions at the start's coordinates there and replaces the refinement's pose; NaN
    #: when it did not run.
    held_fit: float = math.nan

    @property
    def returned_fit(self) -> float:
        """The fit of the pose returned (``held_fit`` after a hold, ``refined_fit`` when the
        refinement ran, else ``end_fit``, ``resolved_fit`` or ``start_fit`` by the outcome)."""
        if not math.isnan(self.held_fit):
            return self.held_fit
        if self.refined != "off":
            return self.refined_fit
        if self.outcome == "resolved":
            return self.resolved_fit
        return self.start_fit if self.outcome == "start" else self.end_fit

    @property
    def refined_solve(self) -> bool:
        """The pose returned is the minimum of the refinement's narrow objective (``from
        start`` / ``from end``; :func:`refined_objective`)."""
        return self.refined in ("from start", "from end")

    @property
    def slid(self) -> bool:
        """The solve's own end explained clearly less than the start."""
        return self.outcome != "kept"

    def describe(self) -> str:
        """``"slid from a start that fitted better: 88% → 72% of the source within 0.1"``."""
        return (
            f"slid from a start that fitted better: {self.start_fit:.0%} → {self.end_fit:.0%} "
            f"of the source within {self.gate:.3g}"
        )


def clearly_worse(end: float, start: float) -> bool:
    """Whether a fit ``end`` is clearly below ``start`` (fractions of the source)."""
    return end < SLIDE_RATIO * start and start - end >= SLIDE_MIN_DROP


def _fit(index: Any, source: FloatArray, pose_matrix: FloatArray, gate: float) -> float:
    # Counted in the core, each query stopping at the first target point inside the gate.
    found = _core.count_within(index, source, pose_matrix, gate)
    return float(found) / float(source.shape[0])


def guard_start(
    out: Any,
    *,
    index: Any,
    source: FloatArray,
    start: SE2 | SE3,
    gate: float,
    target_points: FloatArray | None,
    solve_from_start: Callable[[float], Any],
    evaluate_start: Callable[[], Any],
) -> tuple[Any, SlideCheck]:
    """The outcome to return instead of the solve's ``out``, and what was measured.

    ``index`` is the target's search structure, ``gate`` the registration's;
    ``solve_from_start(gate)`` runs the registration's own solve from the
    start with another gate; ``evaluate_start()`` evaluates the registration at the start
    without moving (its outcome when the start is returned)."""
    tight = tight_gate(index, source, start, gate, target_points)
    start_fit = _fit(index, source, start.as_matrix(), tight)
    end_fit = _fit(index, source, out.pose, tight)  # the core's homogeneous matrix
    fields: dict[str, Any] = {
        "gate": tight,
        "start_fit": start_fit,
        "end_fit": end_fit,
        "outcome": "kept",
        "resolve_gate": math.nan,
        "resolved_fit": math.nan,
    }
    if start_fit < SLIDE_MIN_START_FIT or not clearly_worse(end_fit, start_fit):
        return out, _build(SlideCheck, fields)
    narrow = RESOLVE_GATE_FRACTION * gate if math.isfinite(gate) else 2.0 * tight
    again = solve_from_start(narrow)
    fields["resolve_gate"] = narrow
    if str(again.stop_reason) in ("converged", "max_iterations"):
        fields["resolved_fit"] = _fit(index, source, again.pose, tight)
        if not clearly_worse(fields["resolved_fit"], start_fit):
            fields["outcome"] = "resolved"
            return again, _build(SlideCheck, fields)
    fields["outcome"] = "start"
    return evaluate_start(), _build(SlideCheck, fields)


def refine_in_basin(
    out: Any,
    check: SlideCheck,
    *,
    index: Any,
    source: FloatArray,
    start: SE2 | SE3,
    gate: float,
    solve_narrow: Callable[[SE2 | SE3 | FloatArray, float], Any],
    evaluate_at: Callable[[FloatArray], Any],
    residuals_at: Callable[[FloatArray, float], Any],
) -> tuple[Any, SlideCheck]:
    """The registration's outcome refined inside the basin it chose, and the check updated.

    Two narrow robust solves (:data:`REFINE_GATE_FRACTION` of ``gate``, Cauchy kernel: far
    pairs cannot pull the pose across the basin, near ones weigh by how well they fit) — one
    from the start, one from where the solve ended (the guard's choice). Of the start and the
    converged ones, the pose whose source points lie closest to the target — the mean squared
    residual of the registration's own method (point-to-line: the distance along the target's
    normal), truncated at the guard's tight gate (:func:`truncated_cost`), measured the same
    way at each — is returned, evaluated with the registration's own gate and kernel (its
    covariance and verdict read the same correspondences as before). Ties (within
    :data:`COST_TIE`) go to the start, then to the solve from it: where the scan cannot tell
    poses apart the start stands. Only from a start that fits at least
    :data:`REFINE_MIN_START_FIT`, and not after the guard returned the start (the verdict
    rejects that).

    ``solve_narrow(start, gate)`` runs the registration's solve with the narrow gate and
    kernel; ``evaluate_at(pose)`` evaluates the registration at ``pose`` without moving, and
    ``residuals_at(pose, gate)`` with another gate and no kernel.

    Measured on the first 400 Kümmerle relation pairs under 10 s apart of each Freiburg log,
    from the wheel odometry (``benchmarks/relation_pairs.py``): median error / results more
    than 0.15 m or 2° off, Intel 2.45 cm / 22 → 1.61 cm / 6, ACES 3.90 / 15 → 2.88 / 7, the
    hospital 8.96 / 137 → 4.97 / 53; Karto's scan matcher 1.41 / 6, 3.00 / 7, 6.50 / 58."""
    # Only from a start that fits: a start far off (a wrong heading) has no basin to stay in,
    # and a narrow solve from it or from a far end can settle on a wrong fit the wrong-basin
    # probe then does not doubt (tests/test_basin.py, 60° starts).
    if check.outcome == "start" or check.start_fit < REFINE_MIN_START_FIT:
        return out, check
    if not math.isfinite(gate):
        return out, check
    start_matrix = start.as_matrix()
    best_cost = truncated_cost(residuals_at(start_matrix, check.gate), len(source), check.gate)
    best: Any = None
    label: RefinedFrom = "start"
    narrow, _ = refined_objective(gate)
    for begin, name in ((start, "from start"), (out.pose, "from end")):
        again = solve_narrow(begin, narrow)
        if str(again.stop_reason) != "converged":
            continue  # one still moving at its iteration cap ends wherever round-off takes it
        cost = truncated_cost(residuals_at(again.pose, check.gate), len(source), check.gate)
        # Costs equal to round-off (the same fit in another frame) are ties: the order decides.
        if cost < best_cost * (1.0 - COST_TIE):
            best, best_cost, label = again, cost, name  # type: ignore[assignment]
    fields = {f: getattr(check, f) for f in check.__dataclass_fields__}
    fields["refined"] = label
    if best is None:
        fields["refined_fit"] = check.start_fit
        return evaluate_at(start_matrix), _build(SlideCheck, fields)
    fields["refined_fit"] = _fit(index, source, best.pose, check.gate)
    fields["refined_iterations"] = int(best.iterations)
    return evaluate_at(best.pose), _build(SlideCheck, fields)


def refined_objective(gate: float) -> tuple[float, tuple[str, float]]:
    """The narrow objective :func:`refine_in_basin` solves for a registration's ``gate``: its
    gate (:data:`REFINE_GATE_FRACTION` of ``gate``) and its kernel ``(name, scale)`` (Cauchy,
    a third of that gate)."""
    narrow = REFINE_GATE_FRACTION * gate
    return narrow, ("cauchy", narrow / 3.0)


def truncated_cost(evaluated: Any, count: int, gate: float) -> float:
    """Mean over ``count`` source points of the squared residual, truncated at ``gate``, of a
    core evaluation with that gate: a point without a correspondence inside it costs
    ``gate²``."""
    matched = int(evaluated.num_correspondences)
    return (float(evaluated.sum_squares) + (count - matched) * gate * gate) / count


def start_cover(
    check: SlideCheck | None,
    pose: SE2 | SE3,
    start: SE2 | SE3,
    covariance: FloatArray,
    gate: float,
    cover_ratio: float,
) -> FloatArray | None:
    """``covariance`` grown to cover the start after a re-solve that explains no more than
    about what the start does, or None when nothing is to be covered.

    A ``resolved`` pose came from a solve that slid away from its start once; when the start
    still explains at least ``cover_ratio`` times as much of the source (the verdict's
    ``basin_ambiguous_ratio``), the fits do not tell the two apart, and a start near the result
    (within half the gate and ``NEAR_ROTATION_DEG``) but outside its covariance (χ² at 99.9 %)
    is covered as the wrong-basin probe covers a near alternative that explains about as much
    (:mod:`scanreg.basin`). Measured on the wrong_start.py Intel pairs: a corridor pair re-solved
    0.14 m along the corridor from its reference start (66 % within 0.1 m against the start's
    70 %) was accepted with σ 3.7 cm along it."""
    if check is None or check.outcome != "resolved":
        return None
    if not check.start_fit >= cover_ratio * check.returned_fit:
        return None
    cov = np.asarray(covariance, dtype=np.float64)
    if not np.isfinite(cov).all():
        return None
    e = (pose.inverse() @ start).log()  # type: ignore[operator]
    dim = pose.DIM
    moved = float(np.linalg.norm(e[:dim]))
    turned = abs(float(e[2])) if dim == 2 else float(np.linalg.norm(e[3:]))
    if moved > 0.5 * gate or turned > math.radians(NEAR_ROTATION_DEG):
        return None
    dof = e.size
    try:
        chi2 = float(e @ np.linalg.solve(cov, e))
    except np.linalg.LinAlgError:
        return None
    if chi2 <= CHI2_999[dof]:
        return None
    return covariance_upper_bound(cov, cov + np.outer(e, e))


__all__ = [
    "SlideCheck",
    "clearly_worse",
    "guard_start",
    "refine_in_basin",
    "refined_objective",
    "start_cover",
    "truncated_cost",
]
