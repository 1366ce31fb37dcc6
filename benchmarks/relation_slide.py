"""Started at the right pose, does point-to-line stay there? Kümmerle relations as pair truth.

For the first ``--count`` relations less than 10 s apart of each log (Intel, ACES, the hospital
``fr-clinic`` in
``../shared/data/freiburg-slam-benchmark``), scan t2 (source) is matched to scan t1 (target)
with the default call ``scanreg.register(src, scanreg.prepare(tgt, normals=True),
method="point_to_line", init=relation)`` — started *at* the relation pose — with the
never-worse-than-the-start guard (:mod:`scanreg.slide`) and without it
(``never_worse_than_start=False``). Per log and variant: the median error against the relation,
how many results are wrong (more than 0.15 m or 2° off), how many are accepted and wrong, the
guard's outcomes, how many accepted results lie outside their own covariance (NEES of the error
against the relation above χ²(3) at 99.9 %), and the median time of the call with its verdict
read (best of ``--rounds`` per pair, the two variants alternated pair by pair in one process).

    .venv/bin/python benchmarks/relation_slide.py [--logs intel,aces] [--count 400]
        [--rounds 3] [--start relation|odometry] [--list]

``--start odometry``: start from the wheel odometry's relative pose instead (the issue's setup).
``--list``: print every pair the plain solve gets wrong, with the fits at its start and end.
"""

from __future__ import annotations

import argparse
import math
import os
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("RAYON_NUM_THREADS", "2")

import numpy as np
import scanreg
from scanreg import SE2, _core
from scanreg.eval.relations import read_relations
from scanreg.io import read_scans

DATA = Path(os.environ.get("SCANREG_DATA", Path(__file__).resolve().parents[2] / "shared/data"))
WRONG_M, WRONG_DEG = 0.15, 2.0
CHI2_999 = 16.266  # χ²(3) at 99.9 %
MAX_SECONDS = 10.0
#: The ranges each scan's points are read between (m).
MIN_RANGE, MAX_RANGE = 0.1, 40.0
#: Log files whose name is not ``<name>.clf.bz2``.
LOGS = {"fr-clinic": "fr-clinic_robotlaser.clf.bz2"}


def relation_scans(name: str, count: int) -> list[tuple[int, Any, Any, SE2, SE2]]:
    """``(relation index, scan t1, scan t2, relation, odometry)`` of the first ``count``
    relations under ``MAX_SECONDS`` apart whose scans are both in the log, the raw scans as read;
    ``relation`` is in the laser's frame, ``odometry`` the wheel odometry's relative pose
    between the two scans."""
    folder = DATA / "freiburg-slam-benchmark"
    log = read_scans(folder / LOGS.get(name, f"{name}.clf.bz2"))
    relations = read_relations(folder / f"{name}.relations")
    lasers = [(i, s) for i, s in enumerate(log.scans) if s.kind in ("FLASER", "ROBOTLASER1")]
    stamps = {s.timestamp: i for i, s in lasers}
    # The relations are between robot poses, the scans in the laser's frame (the hospital's
    # laser is 0.22 m ahead of the robot's centre; Intel's and ACES' at it).
    first = lasers[0][1]
    assert first.odometry_se2 is not None and first.laser_se2 is not None
    mount = first.odometry_se2.inverse() @ first.laser_se2
    out = []
    for k in range(len(relations)):
        if abs(relations.t2[k] - relations.t1[k]) >= MAX_SECONDS:
            continue
        i1, i2 = stamps.get(float(relations.t1[k])), stamps.get(float(relations.t2[k]))
        if i1 is None or i2 is None:
            continue
        m = relations.poses[k]
        robot = SE2.from_vector([m[0, 3], m[1, 3], math.atan2(m[1, 0], m[0, 0])])
        relation = mount.inverse() @ robot @ mount
        a, b = log.scans[i1].laser_se2, log.scans[i2].laser_se2
        assert a is not None and b is not None
        odometry = a.inverse() @ b  # the logged laser poses are the wheel odometry's
        out.append((k, log.scans[i1], log.scans[i2], relation, odometry))
        if len(out) == count:
            break
    return out


def relation_pairs(name: str, count: int) -> list[tuple[int, np.ndarray, Any, SE2, SE2]]:
    """``(relation index, source, prepared target, relation, odometry)``: the pairs of
    :func:`relation_scans`, scan t2's points (source) and scan t1's prepared for
    point-to-line (target)."""
    return [
        (
            k,
            scan2.to_points(MIN_RANGE, MAX_RANGE),
            scanreg.prepare(scan1.to_points(MIN_RANGE, MAX_RANGE), normals=True),
            relation,
            odometry,
        )
        for k, scan1, scan2, relation, odometry in relation_scans(name, count)
    ]


def _call(source: Any, target: Any, start: SE2, guard: bool) -> tuple[Any, float]:
    t0 = time.perf_counter()
    res = scanreg.register(
        source, target, method="point_to_line", init=start, never_worse_than_start=guard
    )
    _ = res.verdict
    return res, time.perf_counter() - t0


def run(name: str, count: int, rounds: int, listing: bool, start_at: str) -> None:
    pairs = relation_pairs(name, count)
    rows: dict[bool, list[dict[str, Any]]] = {True: [], False: []}
    for k, source, target, relation, odometry in pairs:
        start = relation if start_at == "relation" else odometry
        for guard in (False, True):
            res, seconds = _call(source, target, start, guard)
            for _ in range(rounds - 1):
                seconds = min(seconds, _call(source, target, start, guard)[1])
            err = (res.pose.inverse() @ relation).log()
            cov = np.asarray(res.covariance)
            nees = float(err @ np.linalg.solve(cov, err)) if np.isfinite(cov).all() else math.inf
            fit = [
                _core.count_within(target.index, source, p.as_matrix(), 0.1) / len(source)
                for p in (start, res.pose)
            ]
            rows[guard].append(
                {
                    "k": k,
                    "m": float(np.hypot(err[0], err[1])),
                    "deg": math.degrees(abs(float(err[2]))),
                    "accepted": bool(res.verdict.accepted),
                    "outside": nees > CHI2_999,
                    "reasons": res.verdict.reasons,
                    "outcome": "off" if res.slide is None else res.slide.outcome,
                    "seconds": seconds,
                    "fit": fit,
                }
            )
    print(f"\n{name}: {len(pairs)} relations under {MAX_SECONDS:g} s, started at the {start_at}")
    print(
        "| guard | median error (cm) | wrong | accepted and wrong | accepted outside own cov. "
        "| kept / resolved / start | ms per call (verdict read) |"
    )
    print("|---|---|---|---|---|---|---|")
    for guard in (False, True):
        rs = rows[guard]
        wrong = [r["m"] > WRONG_M or r["deg"] > WRONG_DEG for r in rs]
        outcomes = [sum(r["outcome"] == o for r in rs) for o in ("kept", "resolved", "start")]
        print(
            f"| {'on' if guard else 'off'} | {100 * np.median([r['m'] for r in rs]):.2f} | "
            f"{sum(wrong)} | {sum(w and r['accepted'] for w, r in zip(wrong, rs, strict=True))} | "
            f"{sum(r['accepted'] and r['outside'] for r in rs)} | "
            f"{' / '.join(map(str, outcomes)) if guard else '-'} | "
            f"{1e3 * np.median([r['seconds'] for r in rs]):.3f} |"
        )
    if listing:
        for off, on in zip(rows[False], rows[True], strict=True):
            if off["m"] > WRONG_M or off["deg"] > WRONG_DEG:
                print(
                    f"  relation {off['k']}: off {off['m']:.3f} m {off['deg']:.2f}° "
                    f"accepted={off['accepted']} within 0.1 m {off['fit'][0]:.0%} → "
                    f"{off['fit'][1]:.0%} | on {on['m']:.3f} m {on['deg']:.2f}° "
                    f"{on['outcome']} accepted={on['accepted']} {list(on['reasons'])}"
                )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--logs", default="intel,aces")
    parser.add_argument("--count", type=int, default=400)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--list", action="store_true")
    parser.add_argument("--start", choices=("relation", "odometry"), default="relation")
    args = parser.parse_args()
    for name in args.logs.split(","):
        run(name, args.count, args.rounds, args.list, args.start)


if __name__ == "__main__":
    main()
