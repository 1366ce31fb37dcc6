"""As accurate as Karto on relation pairs, and faster? Kümmerle relations as pair truth.

For the first ``--count`` relations less than 10 s apart of each Freiburg log (Intel, ACES, the
hospital ``fr-clinic``; ``../shared/data/freiburg-slam-benchmark``), scan t2 (source) is matched
to scan t1 (target) from the wheel odometry's relative pose, by

* ``register``: scanreg's default 2D call, ``scanreg.register(src, scanreg.prepare(tgt,
  normals=True), method="point_to_line", init=odometry)``, its verdict read;
* ``register, init_covariance``: the same with the start's covariance stated, as a caller
  with odometry has it (Freiburg: the default ``WheelNoise`` model of the step; Radish: the
  simulated wheels' own model): a window wider than the solve's basin is searched first
  (``RegistrationSettings.search_start``, :mod:`scanreg.start_search`);
* ``register, hold_degenerate=False``: the same without holding a degenerate refined result
  at the start along its weak directions (``RegistrationSettings.hold_degenerate``);
* ``register, refine_in_basin=False``: the same without the refinement in the basin
  (:func:`scanreg.slide.refine_in_basin`), the default call before it;
* ``correlative + register``: the README's 2D log recipe, correlative branch and bound at 5 cm
  over Karto's window, then the default call from its answer;
* ``karto``: OpenKarto's scan matcher (``karto-scanmatcher`` on PyPI, the matcher inside
  slam_toolbox) with its default configuration (±0.3 m, ±20° around the start, 1 cm grid,
  penalised and refined, as slam_toolbox calls it for consecutive scans).

Every contender is timed from the raw scans on: building its target (scanreg: ``prepare``;
Karto: its grid, inside ``match_scan``) is part of each pair's time. The contenders alternate
pair by pair in one process (best of ``--rounds`` calls each). Per log and contender: the median
translation error against the relation, how many results are wrong (more than 0.15 m or 2° off),
how many are accepted and wrong (Karto has no verdict: every result counts as accepted), the
median ms per pair and its ratio to Karto's. Run with ``RAYON_NUM_THREADS=1`` for the timing
comparison (Karto is single-threaded).

    RAYON_NUM_THREADS=1 .venv/bin/python benchmarks/relation_pairs.py
        [--logs intel,aces,fr-clinic] [--count 400] [--rounds 3] [--list]

``--list``: every pair some contender gets wrong, with each contender's error.

``--logs radish-NAME,...``: logs the defaults were never chosen on, with no relations: the
consecutive scans of a Radish "corrected" log (``radish_mapping.py``; 180–361-beam 180°
lasers, scans 0.5–1 m and up to ~30° apart), the reference GMapping's relative pose between
them (cm-level, not ground truth: both matchers' errors include its own), the start
``radish_mapping.noisy_odometry``'s simulated wheels (seeded by the log).

``--front-end``: also the ``Odometry2D`` front end as ``scanreg map`` runs it (scan to local map,
the wheel prior, loop closure off: ``run_mapping`` with ``max_candidates=0``) over the whole log,
read at the same pairs (its relative pose between the two scans' stamps, in the robot's frame as
the relations are); it has no per-pair verdict or time: its "ms" is CPU per scan of the run.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

os.environ.setdefault("RAYON_NUM_THREADS", "1")

import karto_scanmatcher as karto
import numpy as np
import scanreg
from scanreg import SE2

sys.path.insert(0, str(Path(__file__).resolve().parent))
from relation_slide import MAX_RANGE, MAX_SECONDS, MIN_RANGE, WRONG_DEG, WRONG_M, relation_scans


def _default_call(scan1: Any, scan2: Any, start: SE2, **settings: Any) -> tuple[SE2, bool]:
    """The default 2D call from the raw scans (``settings``: the contender's one change)."""
    target = scanreg.prepare(scan1.to_points(MIN_RANGE, MAX_RANGE), normals=True)
    res = scanreg.register(
        scan2.to_points(MIN_RANGE, MAX_RANGE),
        target,
        method="point_to_line",
        init=start,
        **settings,
    )
    return res.pose, bool(res.verdict.accepted)


def scanreg_default(scan1: Any, scan2: Any, start: SE2) -> tuple[SE2, bool]:
    """The default 2D call, from the raw scans."""
    return _default_call(scan1, scan2, start)


#: The start's stated covariance for the ``register, init_covariance`` contender, per pair:
#: the library's default wheel model on the Freiburg logs' real odometry, the simulation's own
#: noise model on the Radish logs (set by :func:`run`).
_STATED: list[Callable[[SE2], np.ndarray]] = []


def wheel_covariance(step: SE2) -> np.ndarray:
    """The default :class:`~scanreg.pipeline.WheelNoise` model's covariance of ``step``."""
    from scanreg.pipeline.wheel import WheelNoise

    return WheelNoise().covariance(step)


def simulated_covariance(step: SE2) -> np.ndarray:
    """``radish_mapping.noisy_odometry``'s own noise model for ``step`` (robot frame)."""
    from radish_mapping import ACROSS, ALONG, TURN, TURN_PER_METRE

    d = float(np.linalg.norm(step.translation))
    sigma = [ALONG * d + 1e-3, ACROSS * d + 1e-3, TURN + TURN_PER_METRE * d]
    return np.diag(np.square(sigma))


def scanreg_stated(scan1: Any, scan2: Any, start: SE2) -> tuple[SE2, bool]:
    """The default call with the start's covariance stated (``init_covariance``): a window
    wider than the solve's basin is searched first (``RegistrationSettings.search_start``)."""
    return _default_call(scan1, scan2, start, init_covariance=_STATED[0](start))


def scanreg_unheld(scan1: Any, scan2: Any, start: SE2) -> tuple[SE2, bool]:
    """The default call without holding a degenerate result at the start
    (``hold_degenerate=False``)."""
    return _default_call(scan1, scan2, start, hold_degenerate=False)


def scanreg_unrefined(scan1: Any, scan2: Any, start: SE2) -> tuple[SE2, bool]:
    """The default call without the refinement in the basin (``refine_in_basin=False``)."""
    return _default_call(scan1, scan2, start, refine_in_basin=False)


def scanreg_correlative(scan1: Any, scan2: Any, start: SE2) -> tuple[SE2, bool]:
    """The README's 2D log recipe: correlative branch and bound over Karto's window, then the
    default point-to-line call from its answer."""
    ref, src = scan1.to_points(MIN_RANGE, MAX_RANGE), scan2.to_points(MIN_RANGE, MAX_RANGE)
    grid = scanreg.prepare_correlative(ref, resolution=0.05)
    found = scanreg.match_correlative(src, grid, init=start, window=(0.3, 0.3, math.radians(20)))
    res = scanreg.register(
        src, scanreg.prepare(ref, normals=True), method="point_to_line", init=found.pose
    )
    return res.pose, bool(res.verdict.accepted)


def _karto_config(scan: Any) -> Any:
    step = float(scan.angles[1] - scan.angles[0])
    return karto.LaserScanConfig(
        float(scan.angles[0]),
        float(scan.angles[-1]),
        step,
        MIN_RANGE,
        MAX_RANGE,
        MAX_RANGE,
        "laser",
    )


def _karto_ranges(scan: Any) -> list[float]:
    # Karto ignores readings beyond its range threshold; invalid ones are sent there.
    r = np.where(scan.valid(MIN_RANGE, MAX_RANGE), scan.ranges, MAX_RANGE + 1.0)
    return [float(v) for v in r]


_MATCHER: list[Any] = []


def _karto_matcher() -> Any:
    # Built once (70 ms: it allocates its correlation grid), as slam_toolbox builds its own.
    if not _MATCHER:
        _MATCHER.append(karto.Wrapper(karto.ScanMatcherConfig()))
    return _MATCHER[0]


def karto_match(scan1: Any, scan2: Any, start: SE2) -> tuple[SE2, bool]:
    """Karto's matcher, scan 1 at the origin, scan 2 started at ``start``."""
    config = _karto_config(scan1)
    origin = karto.Pose2(0.0, 0.0, 0.0)
    x, y, yaw = start.as_vector()
    guess = karto.Pose2(float(x), float(y), float(yaw))
    base = karto.LocalizedRangeScan(config, _karto_ranges(scan1), origin, origin, 0, 0.0)
    query = karto.LocalizedRangeScan(config, _karto_ranges(scan2), guess, guess, 1, 1.0)
    found = _karto_matcher().match_scan(query, [base], True, True).best_pose
    return SE2.from_vector([found.x, found.y, found.yaw]), True


CONTENDERS: dict[str, Callable[[Any, Any, SE2], tuple[SE2, bool]]] = {
    "register": scanreg_default,
    "register, init_covariance": scanreg_stated,
    "register, hold_degenerate=False": scanreg_unheld,
    "register, refine_in_basin=False": scanreg_unrefined,
    "correlative + register": scanreg_correlative,
    "karto": karto_match,
}


def front_end_rows(name: str, pairs: list[tuple[int, SE2]]) -> tuple[list[dict[str, Any]], float]:
    """The mapping's front end over the whole log (loops off), its error at each of ``pairs``
    (relation index, relation in the laser's frame), and its CPU ms per scan."""
    import dataclasses

    from relation_slide import DATA, LOGS
    from scanreg.eval.relations import read_relations
    from scanreg.io import read_scans
    from scanreg.pipeline.mapping import MappingConfig, run_mapping

    folder = DATA / "freiburg-slam-benchmark"
    log = read_scans(folder / LOGS.get(name, f"{name}.clf.bz2"))
    relations = read_relations(folder / f"{name}.relations")
    t0 = time.process_time()
    res = run_mapping(log, dataclasses.replace(MappingConfig(), max_candidates=0))
    ms = 1e3 * (time.process_time() - t0) / res.num_scans
    at = {float(t): p for t, p in zip(res.stamps, res.odometry_poses, strict=True)}
    first = next(s for s in log.scans if s.kind in ("FLASER", "ROBOTLASER1"))
    assert first.odometry_se2 is not None and first.laser_se2 is not None
    mount = first.odometry_se2.inverse() @ first.laser_se2
    rows = []
    for k, relation in pairs:
        a, b = at[float(relations.t1[k])], at[float(relations.t2[k])]
        # The run's poses are the robot's; the relation here is the laser's (relation_scans).
        pose = mount.inverse() @ a.inverse() @ b @ mount
        err = (pose.inverse() @ relation).log()
        m, deg = float(np.hypot(err[0], err[1])), math.degrees(abs(float(err[2])))
        rows.append({"k": k, "m": m, "deg": deg, "wrong": m > WRONG_M or deg > WRONG_DEG})
    return rows, ms


def radish_front_end_rows(
    name: str, pairs: list[tuple[int, SE2]]
) -> tuple[list[dict[str, Any]], float]:
    """:func:`front_end_rows` for ``radish-NAME``: the front end over the log with the
    simulated wheels (``radish_mapping.prepared``), read between scans k and k+1."""
    import dataclasses

    from radish_mapping import LOGS, prepared
    from relation_slide import DATA
    from scanreg.pipeline.mapping import MappingConfig, run_mapping

    log_name = name.removeprefix("radish-")
    run_log, _, _ = prepared(log_name, DATA / "carmen-radish-corrected", LOGS.index(log_name))
    t0 = time.process_time()
    res = run_mapping(run_log, dataclasses.replace(MappingConfig(), max_candidates=0))
    ms = 1e3 * (time.process_time() - t0) / res.num_scans
    poses = res.odometry_poses
    rows = []
    for k, relation in pairs:
        err = ((poses[k].inverse() @ poses[k + 1]).inverse() @ relation).log()
        m, deg = float(np.hypot(err[0], err[1])), math.degrees(abs(float(err[2])))
        rows.append({"k": k, "m": m, "deg": deg, "wrong": m > WRONG_M or deg > WRONG_DEG})
    return rows, ms


def radish_scans(name: str, count: int) -> list[tuple[int, Any, Any, SE2, SE2]]:
    """:func:`relation_scans` for a Radish corrected log ``radish-NAME``: ``(k, scan k, scan
    k+1, GMapping's relative pose, the simulated wheels')`` for the first ``count`` steps."""
    from radish_mapping import LOGS, noisy_odometry
    from relation_slide import DATA
    from scanreg.io import read_scans

    log_name = name.removeprefix("radish-")
    path = DATA / "carmen-radish-corrected" / f"{log_name}-corrected.log.gz"
    scans = read_scans(path).laser("FLASER")
    # The corrected pose is each FLASER line's own, the laser's (radish_mapping.py).
    reference = [SE2.from_vector(s.odometry_pose) for s in scans]
    wheels = noisy_odometry(reference, LOGS.index(log_name))
    out = []
    for k in range(min(count, len(scans) - 1)):
        relation = reference[k].inverse() @ reference[k + 1]
        out.append((k, scans[k], scans[k + 1], relation, wheels[k].inverse() @ wheels[k + 1]))
    return out


def run(name: str, count: int, rounds: int, listing: bool, front_end: bool = False) -> None:
    radish = name.startswith("radish-")
    pairs = radish_scans(name, count) if radish else relation_scans(name, count)
    _STATED[:] = [simulated_covariance if radish else wheel_covariance]
    rows: dict[str, list[dict[str, Any]]] = {c: [] for c in CONTENDERS}
    for k, scan1, scan2, relation, odometry in pairs:
        for label, call in CONTENDERS.items():
            best = math.inf
            for _ in range(rounds):
                t0 = time.perf_counter()
                pose, accepted = call(scan1, scan2, odometry)
                best = min(best, time.perf_counter() - t0)
            err = (pose.inverse() @ relation).log()
            m, deg = float(np.hypot(err[0], err[1])), math.degrees(abs(float(err[2])))
            rows[label].append(
                {
                    "k": k,
                    "m": m,
                    "deg": deg,
                    "wrong": m > WRONG_M or deg > WRONG_DEG,
                    "accepted": accepted,
                    "seconds": best,
                }
            )
    karto_ms = 1e3 * float(np.median([r["seconds"] for r in rows["karto"]]))
    what = "consecutive scans" if radish else f"relations under {MAX_SECONDS:g} s"
    print(f"\n{name}: {len(pairs)} {what}, from the wheel odometry")
    print("| contender | median error (cm) | wrong | accepted and wrong | ms per pair | ÷ Karto |")
    print("|---|---|---|---|---|---|")
    for label, rs in rows.items():
        ms = 1e3 * float(np.median([r["seconds"] for r in rs]))
        print(
            f"| {label} | {100 * np.median([r['m'] for r in rs]):.3f} | "
            f"{sum(r['wrong'] for r in rs)} | {sum(r['wrong'] and r['accepted'] for r in rs)} | "
            f"{ms:.2f} | {ms / karto_ms:.2f} |"
        )
    if front_end:
        rows_at = [(r["k"], rel) for r, (_, _, _, rel, _) in zip(rows["karto"], pairs, strict=True)]
        fe = radish_front_end_rows(name, rows_at) if radish else front_end_rows(name, rows_at)
        print(
            f"| Odometry2D front end (run over the log) | "
            f"{100 * np.median([r['m'] for r in fe[0]]):.3f} | "
            f"{sum(r['wrong'] for r in fe[0])} | – | {fe[1]:.2f} per scan | – |"
        )
    if listing:
        for i in range(len(pairs)):
            if any(rows[c][i]["wrong"] for c in rows):
                cells = [
                    f"{c} {rows[c][i]['m']:.3f} m {rows[c][i]['deg']:.2f}°"
                    f"{'' if rows[c][i]['accepted'] else ' (rejected)'}"
                    for c in rows
                ]
                print(f"  relation {rows['karto'][i]['k']}: " + " | ".join(cells))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--logs", default="intel,aces,fr-clinic")
    parser.add_argument("--count", type=int, default=400)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--list", action="store_true")
    parser.add_argument("--front-end", action="store_true", help="also the Odometry2D front end")
    args = parser.parse_args()
    print(f"RAYON_NUM_THREADS={os.environ['RAYON_NUM_THREADS']}")
    for name in args.logs.split(","):
        run(name, args.count, args.rounds, args.list, args.front_end)


if __name__ == "__main__":
    main()
