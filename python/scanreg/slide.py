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

SlideOutcome = Literal["kept", "resolved", "start"]


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

    @property
    def returned_fit(self) -> float:
        """The fit of the pose returned (``end_fit``, ``resolved_fit`` or ``start_fit``)."""
        if self.outcome == "resolved":
            return self.resolved_fit
        return self.start_fit if self.outcome == "start" else self.end_fit

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
    if not check.start_fit >= cover_ratio * check.resolved_fit:
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


__all__ = ["SlideCheck", "clearly_worse", "guard_start", "start_cover"]
