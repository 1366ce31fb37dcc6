"""The demo's main job: maps with their loops closed and localization in a saved map, on
simulated data scored against the exact truth (see :mod:`scanreg.demo`).

* :func:`map_room_tour` — a 2D laser on a tour of an office floor, out through the rooms and
  back, with noisy wheel odometry, mapped with loop closure (:class:`~scanreg.pipeline.Mapper`);
  the map's self-check (:func:`~scanreg.pipeline.map_check.check_map`); the map written as a
  ROS ``map_server`` map with the run's files, and the truth beside them for the report
  (:func:`write_demo_report`).
* :func:`localize_in_saved_map` — a second pass of the tour (new sensor noise) located in
  that saved map from no pose (:class:`~scanreg.pipeline.Localizer2D`).
* :func:`map_block_loop` — a 3D LiDAR lapping a city block, mapped with loop closure
  (:class:`~scanreg.pipeline.Mapper3D`).

Each returns the figures it prints and :class:`Check` rows: a figure against its threshold.
Mapping needs gtsam (the ``mapping`` extra), the report plotly (``report``).
"""

from __future__ import annotations

import importlib.util
import math
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from . import simulate as sim
from ._validate import FloatArray
from .transform import SE2, SE3

#: The 2D laser's scan rate on the room tour (Hz).
TOUR_RATE = 5.0
#: The 3D course: one lap of this length (m) at 10 m/s, then this many sweeps more (the
#: revisit of the lap's start, where the loops close).
LAP_LENGTH = 200.0
LAP_EXTRA_SWEEPS = 20


@dataclass(frozen=True)
class Check:
    """One printed figure against its threshold: passes when ``value < limit``."""

    name: str
    value: float
    limit: float
    unit: str = ""

    @property
    def passed(self) -> bool:
        return bool(self.value < self.limit)  # NaN fails

    def line(self) -> str:
        unit = f" {self.unit}" if self.unit else ""
        return (
            f"  {'PASS' if self.passed else 'FAIL'}  {self.name}: "
            f"{self.value:.4g}{unit} (must be < {self.limit:g}{unit})"
        )


def missing_extra(module: str, extra: str, what: str) -> str | None:
    """``None`` when ``module`` imports, else the line saying which extra installs it."""
    if importlib.util.find_spec(module) is not None:
        return None
    return f"  skipped: {what} needs {module}: pip install 'scanreg[{extra}]'"


def _errors(poses: Any, truth: Any) -> tuple[float, float, float]:
    """ATE (m, RMS over all poses), end position error (m) and end heading error (deg)."""
    est = np.array([p.translation for p in poses])
    ref = np.array([p.translation for p in truth])
    ate = float(np.sqrt(np.mean(np.sum((est - ref) ** 2, axis=1))))
    end = truth[-1].inverse() @ poses[-1]
    heading = abs(end.angle) if isinstance(end, SE2) else float(np.linalg.norm(end.log()[3:]))
    return ate, float(np.linalg.norm(end.translation)), float(np.degrees(heading))


def _loop_errors(loops: Any, truth: Any) -> tuple[FloatArray, FloatArray]:
    """How far (m) each loop's measured relative pose is from the true one, and that error's
    χ² under the loop's own information (what the graph was told to trust)."""
    dist, chi2 = [], []
    for r in loops:
        true_rel = truth[r.submap_scan].inverse() @ truth[r.scan]
        e = (r.match.measured.inverse() @ true_rel).log()
        dist.append(float(np.linalg.norm(e[: len(e) // 2])))
        chi2.append(float(e @ np.asarray(r.match.information) @ e))
    return np.array(dist), np.array(chi2)


def _largest(values: FloatArray) -> float:
    """The largest value; ``inf`` for none (no accepted loop: a check on it must fail)."""
    return float(values.max()) if values.size else math.inf


def _reasons(loops: Any, top: int = 2) -> str:
    """The most common first reasons of rejected loops, counted."""
    counts = Counter(r.match.reasons[0].split(":")[0] if r.match.reasons else "?" for r in loops)
    return "; ".join(f"{n}× {reason}" for reason, n in counts.most_common(top))


@dataclass(frozen=True)
class ErrorRow:
    label: str
    ate: float
    end: float
    end_deg: float


@dataclass(frozen=True)
class MappingDemo:
    """What a mapping section measured against the truth."""

    description: str
    rows: tuple[ErrorRow, ...]
    accepted: int
    rejected: int
    #: Accepted loops whose measured relative pose is more than ``false_loop`` m off the truth
    #: (a wrong place), and the largest χ² of an accepted loop's error against its own
    #: information (a right place trusted too much in some direction).
    false_loops: int
    false_loop: float
    max_chi2: float
    rejection_reasons: str
    #: The map's self-check line (2D only), the folder written (2D only).
    self_check: str | None
    checks: tuple[Check, ...]
    folder: Path | None
    seconds: float


def _loop_figures(res: Any, truth: Any, false_loop: float) -> dict[str, Any]:
    """A mapping run's loop figures against the truth, as :class:`MappingDemo`'s fields
    (``accepted``, ``rejected``, ``false_loops`` over ``false_loop`` m, ``max_chi2``,
    ``rejection_reasons``)."""
    dist, chi2 = _loop_errors(res.accepted_loops, truth)
    return {
        "accepted": len(res.accepted_loops),
        "rejected": len(res.rejected_loops),
        "false_loops": int(np.sum(dist > false_loop)),
        "false_loop": false_loop,
        "max_chi2": _largest(chi2),
        "rejection_reasons": _reasons(res.rejected_loops),
    }


def _print_mapping(demo: MappingDemo) -> None:
    print(demo.description)
    print(
        f"  loop closures: {demo.accepted} accepted ({demo.false_loops} false: off the truth by "
        f"more than {demo.false_loop:g} m), {demo.rejected} rejected"
        + (f" ({demo.rejection_reasons})" if demo.rejection_reasons else "")
    )
    print(
        f"  accepted loops against the truth: largest χ² of the error under the loop's own "
        f"information {demo.max_chi2:.1f} (3 degrees of freedom in 2D, 6 in 3D)"
    )
    print(f"  {'error against the exact truth':<34}{'ATE [m]':>9}{'end [m]':>9}{'end [°]':>9}")
    for r in demo.rows:
        print(f"    {r.label:<32}{r.ate:>9.3f}{r.end:>9.3f}{r.end_deg:>9.2f}")
    if demo.self_check:
        print(f"  {demo.self_check}")
    for c in demo.checks:
        print(c.line())
    print(f"  ({demo.seconds:.1f} s)")


@dataclass(frozen=True)
class TourRun:
    """The simulated room tour: the course, the mapping run's scans, their truth and the
    wheel odometry between them."""

    course: sim.Course
    scans: tuple[sim.LaserScan, ...]
    #: ``T_world_sensor`` of each scan, and ``T_first_scan`` (the map frame).
    poses: tuple[SE2, ...]
    truth: tuple[SE2, ...]
    wheel: tuple[SE2 | None, ...]


def simulate_tour(seed: int = 0, rooms_per_side: int = 2) -> TourRun:
    """A SICK LMS200-like laser at 5 Hz on :func:`~scanreg.simulate.room_tour`."""
    course = sim.room_tour(seed=seed, rooms_per_side=rooms_per_side)
    run = sim.simulate_run(
        course.scene,
        sim.LaserModel.preset("sick_lms200"),
        course.trajectory,
        num_scans=course.num_scans(TOUR_RATE),
        scan_rate=TOUR_RATE,
        seed=seed,
    )
    poses = tuple(p for p in run.poses if isinstance(p, SE2))
    scans = tuple(s for s in run.scans if isinstance(s, sim.LaserScan))
    assert len(poses) == len(scans) == len(run.poses)  # a 2D course gives 2D scans
    truth = tuple(poses[0].inverse() @ p for p in poses)
    wheel = tuple(sim.wheel_odometry(list(truth), seed + 7))
    return TourRun(course, scans, poses, truth, wheel)


def map_room_tour(tour: TourRun, folder: Path) -> tuple[MappingDemo, Any]:
    """Map the tour with loop closure, check the map, write it to ``folder``; returns the
    figures and the :class:`~scanreg.pipeline.mapping.MappingResult`."""
    from .io import Trajectory, write_tum
    from .pipeline import map_check
    from .pipeline.mapping import Mapper, MappingConfig
    from .pipeline.mapping_output import write_outputs

    t0 = time.perf_counter()
    mapper = Mapper(MappingConfig())
    for k, (scan, prior) in enumerate(zip(tour.scans, tour.wheel, strict=True)):
        mapper.step(scan.points, prior=prior, stamp=k / TOUR_RATE)
    res = mapper.finish()
    check = map_check.check_map(res)
    write_outputs(folder, res, plot=False, check=check)
    stamps = np.arange(len(tour.truth)) / TOUR_RATE
    write_tum(folder / "reference_tum.txt", Trajectory.from_poses(list(tour.truth), stamps))
    dead_reckoning = [SE2.identity()]
    for step in tour.wheel[1:]:
        assert step is not None  # only the first scan has no wheel step
        dead_reckoning.append(dead_reckoning[-1] @ step)
    rows = (
        ErrorRow("wheel odometry alone", *_errors(dead_reckoning, tour.truth)),
        ErrorRow("scan odometry (before)", *_errors(res.odometry_poses, tour.truth)),
        ErrorRow("map, loops closed (after)", *_errors(res.poses, tour.truth)),
    )
    loops = _loop_figures(res, tour.truth, false_loop=0.5)
    verdict = "consistent" if check.consistent else "INCONSISTENT: " + "; ".join(check.reasons)
    self_check = (
        f"map self-check: {verdict} ({check.contradictions} of {check.returns} returns "
        f"contradicted, {check.loops_over_bound} of {len(check.loops)} loops over their bound)"
    )
    # Thresholds over seeds 0-7 (measured): ATE 0.008-0.043 m, end 0.005-0.023 m, χ² at most
    # 113. The scan odometry is already good to a few cm on this tour, so the map is held to
    # absolute bounds rather than to a gain over it (on seed 7 it has none).
    checks = (
        Check("map ATE after loop closure", rows[2].ate, 0.05, "m"),
        Check("map end error after loop closure", rows[2].end, 0.03, "m"),
        Check("false loops accepted", loops["false_loops"], 1),
        Check("largest χ² of an accepted loop's error", loops["max_chi2"], 200.0),
        Check("map self-check inconsistent", float(not check.consistent), 1),
    )
    demo = MappingDemo(
        description=(
            f"scanreg demo: mapping with loop closure, 2D — a SICK LMS200-like laser on a "
            f"{tour.course.length:.0f} m tour of an office floor and back, "
            f"{len(tour.scans)} scans at {TOUR_RATE:g} Hz, noisy wheel odometry"
        ),
        rows=rows,
        **loops,
        self_check=self_check,
        checks=checks,
        folder=folder,
        seconds=time.perf_counter() - t0,
    )
    return demo, res


@dataclass(frozen=True)
class LocalizationDemo:
    scans: int
    first_source: str
    accepted: int
    max_error: float
    median_error: float
    checks: tuple[Check, ...]
    seconds: float


def localize_in_saved_map(
    tour: TourRun, map_yaml: Path, *, start: int | None = None, scans: int = 40, seed: int = 1
) -> LocalizationDemo:
    """A second pass over the tour (sensor noise from ``seed``), ``scans`` scans from
    ``start`` (default: the middle, the walk back), located in the saved map from no pose."""
    from .pipeline.localizer2d import Localizer2D

    t0 = time.perf_counter()
    n = len(tour.truth)
    first = n // 2 if start is None else start
    stop = min(n, first + scans)
    second = sim.simulate_run(
        tour.course.scene,
        sim.LaserModel.preset("sick_lms200"),
        tour.course.trajectory,
        num_scans=n,
        scan_rate=TOUR_RATE,
        seed=seed,
    )
    loc = Localizer2D.from_map_server(map_yaml)
    errors, accepted, source = [], 0, ""
    for k in range(first, stop):
        prior = None if k == first else tour.wheel[k]
        frame = loc.step(second.scans[k].points, prior=prior, stamp=k / TOUR_RATE)
        source = source or frame.prediction_source
        accepted += bool(frame.verdict)
        errors.append(float(np.linalg.norm(frame.pose.translation - tour.truth[k].translation)))
    err = np.array(errors)
    # Measured over seeds 0-7: at most 2 of 40 scans rejected (the verdict declining a scan is
    # no error), the largest position error 3.0-8.5 cm.
    checks = (
        Check("localization: scans rejected, %", 100 * (1 - accepted / (stop - first)), 10.0, "%"),
        Check("localization: largest position error", float(err.max()), 0.1, "m"),
        Check("localization: first fix not found globally", float(source != "global"), 1),
    )
    return LocalizationDemo(
        scans=stop - first,
        first_source=source,
        accepted=accepted,
        max_error=float(err.max()),
        median_error=float(np.median(err)),
        checks=checks,
        seconds=time.perf_counter() - t0,
    )


def _print_localization(demo: LocalizationDemo, map_yaml: Path) -> None:
    print(
        f"scanreg demo: localization from no pose in the saved map ({map_yaml.name}), "
        f"{demo.scans} scans of a second pass"
    )
    print(
        f"  first fix: {demo.first_source} search; {demo.accepted}/{demo.scans} scans accepted; "
        f"position error median {100 * demo.median_error:.1f} cm, largest "
        f"{100 * demo.max_error:.1f} cm"
    )
    for c in demo.checks:
        print(c.line())
    print(f"  ({demo.seconds:.1f} s)")


def map_block_loop(seed: int = 0) -> MappingDemo:
    """A VLP-16 lapping a city block once and revisiting the lap's start, mapped with loop
    closure on a short-range (25 m) odometry that drifts."""
    from .io.sequences import SimulatedSequence
    from .pipeline import Mapper3D, MappingConfig3D, OdometryConfig

    t0 = time.perf_counter()
    seq = SimulatedSequence("loop", laps=2, lap_length=LAP_LENGTH, seed=seed)
    sweeps = int(LAP_LENGTH / (seq.speed * seq.lidar.sweep_duration)) + LAP_EXTRA_SWEEPS
    config = MappingConfig3D(odometry=OdometryConfig(max_range=25.0), loop_min_travel=30.0)
    mapper = Mapper3D(config)
    for k in range(sweeps):
        f = seq[k]
        mapper.step(f.points, f.timestamps, stamp=f.stamp)
    res = mapper.finish()
    truth = [SE3.from_matrix(m) for m in seq.ground_truth_at("middle")[:sweeps]]
    rows = (
        ErrorRow("LiDAR odometry (before)", *_errors(res.odometry_poses, truth)),
        ErrorRow("map, loops closed (after)", *_errors(res.poses, truth)),
    )
    loops = _loop_figures(res, truth, false_loop=1.0)
    # Measured over seeds 0-4: end error 0.36-0.75 m before, 0.04-0.28 m after. (Seeds 5-7
    # end 0.4-1.5 m off, seed 6 with false loops: the checks say FAIL there.)
    checks = (
        Check("3D end error after loop closure", rows[1].end, 0.3, "m"),
        Check("3D end error after / before", rows[1].end / rows[0].end, 0.6),
        Check("3D false loops accepted", loops["false_loops"], 1),
    )
    return MappingDemo(
        description=(
            f"scanreg demo: mapping with loop closure, 3D — a VLP-16 lapping a city block "
            f"({LAP_LENGTH:g} m lap and {LAP_EXTRA_SWEEPS} sweeps over its start, {sweeps} "
            f"sweeps at 10 m/s), odometry limited to 25 m range so that it drifts"
        ),
        rows=rows,
        **loops,
        self_check=None,
        checks=checks,
        folder=None,
        seconds=time.perf_counter() - t0,
    )


def write_demo_report(folder: Path) -> Path:
    """``report.html`` of the 2D map's run folder (needs plotly)."""
    from .report import write_report

    return write_report(folder, title="scanreg demo: 2D room tour mapped with loop closure")


def run_mapping_demo(seed: int, output: Path) -> list[Check]:
    """The three sections and the report, printed; returns every check (none when gtsam is
    missing: the sections are skipped, naming the extra)."""
    skip = missing_extra(
        "gtsam", "mapping", "mapping with loop closure (its localization and report.html too)"
    )
    if skip:
        print("scanreg demo: mapping with loop closure, localization in the saved map")
        print(skip)
        print()
        return []
    checks: list[Check] = []
    tour = simulate_tour(seed)
    folder = output / "room_tour"
    mapping, _ = map_room_tour(tour, folder)
    _print_mapping(mapping)
    print(f"  files: {folder}/ (map.yaml + map.pgm, poses, graph.g2o, loops.jsonl)")
    print()
    map_yaml = folder / "map.yaml"
    loc = localize_in_saved_map(tour, map_yaml, seed=seed + 1)
    _print_localization(loc, map_yaml)
    print()
    loop3d = map_block_loop(seed)
    _print_mapping(loop3d)
    print()
    checks += [*mapping.checks, *loc.checks, *loop3d.checks]
    print("scanreg demo: report")
    skip = missing_extra("plotly", "report", "report.html")
    if skip:
        print(skip)
    else:
        print(f"  open {write_demo_report(folder)}")
    print()
    return checks
