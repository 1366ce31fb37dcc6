"""Scan Context place recognition on simulated two-lap drives: top-1 precision/recall and time.

    .venv/bin/python benchmarks/place_recognition.py [--spacing 0.2] [--sensor vlp16]

Two courses from ``scanreg.simulate.block_loop`` (2 laps of 305 m at 10 m/s): an ordinary
block, and one whose four sides are copies (``symmetry=4``: every place has three look-alikes
a quarter lap apart). Keyframes every ``spacing`` seconds (2 m); each is queried against the
keyframes before it, excluding the last ``exclude`` seconds, then added — as a mapping
front end would. A lap is 30.5 s, so second-lap keyframes fall halfway between first-lap
ones (1 m from the nearest at the default spacing). A query has a true revisit when some
searchable keyframe lies within ``radius`` (3 m); its top-1 is correct when it lies within
``radius`` of the query. At each distance threshold τ a top-1 with distance ≤ τ is a proposed loop:
precision = correct proposed / proposed, recall = correct proposed / queries with a revisit.

Times (median ms): ``ScanContext.from_points`` on one sweep and ``PlaceDatabase.query`` on
the full first lap, each against a vectorised NumPy implementation of the same algorithm run
in the same process, alternating call by call.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import statistics
import time
from typing import Any

import numpy as np
from scanreg import place
from scanreg import simulate as sim


# --- the same algorithm in vectorised NumPy (the peer for the times) ------------------------
def numpy_describe(points: np.ndarray, rings: int, sectors: int, radius: float) -> np.ndarray:
    r = np.hypot(points[:, 0], points[:, 1])
    keep = r < radius
    ring = np.minimum((r[keep] / radius * rings).astype(int), rings - 1)
    az = (np.arctan2(points[keep, 1], points[keep, 0]) + np.pi) / (2 * np.pi)
    sector = np.minimum((az * sectors).astype(int), sectors - 1)
    out = np.zeros(rings * sectors)
    np.maximum.at(out, ring * sectors + sector, np.maximum(points[keep, 2] + 2.0, 0.0))
    return out.reshape(rings, sectors)


def numpy_query(query: np.ndarray, database: np.ndarray, keys: np.ndarray) -> tuple[int, float]:
    """Ring-key shortlist of 10, then the minimum over all column shifts; best index."""
    near = np.argsort(np.linalg.norm(keys - query.mean(axis=1), axis=1), kind="stable")[:10]
    sectors = query.shape[1]
    shifts = np.stack([np.roll(database[near], -s, axis=2) for s in range(sectors)], axis=1)
    qn = np.linalg.norm(query, axis=0)
    cn = np.linalg.norm(shifts, axis=2)
    both = (qn > 0) & (cn > 0)
    cos = np.einsum("ij,csij->csj", query, shifts) / np.where(both, qn * cn, 1.0)
    count = both.sum(axis=2)
    dist = np.where(count > 0, 1.0 - (cos * both).sum(axis=2) / np.maximum(count, 1), 1.0)
    best = dist.min(axis=1)
    i = int(np.argmin(best))
    return int(near[i]), float(best[i])


def run_course(
    name: str, course: sim.Course, lidar: sim.LidarModel, args: argparse.Namespace
) -> dict[str, Any]:
    times = np.arange(0.0, course.duration - lidar.sweep_duration, args.spacing)
    poses = course.trajectory.poses_at(times)
    xy = np.array([p.translation[:2] for p in poses])
    yaws = np.array([p.as_vector()[5] for p in poses])
    exclude = round(args.exclude / args.spacing)
    db = place.PlaceDatabase()
    rows = []
    t_describe = []
    t_query = []
    for k, t in enumerate(times):
        sweep = sim.simulate_sweep(
            course.scene, lidar, course.trajectory, start_time=float(t), seed=k
        )
        t0 = time.perf_counter()
        desc = db.describe(sweep.points_deskewed)
        t_describe.append(time.perf_counter() - t0)
        searchable = max(0, k - exclude)
        if searchable:
            t0 = time.perf_counter()
            best = db.query(desc, exclude_recent=exclude)[0]
            t_query.append(time.perf_counter() - t0)
            gaps = np.hypot(*(xy[:searchable] - xy[k]).T)
            j = int(best.index)
            yaw_err = math.remainder(best.yaw - (yaws[k] - yaws[j]), 2 * math.pi)
            rows.append((gaps.min() <= args.radius, gaps[j] <= args.radius, best.distance, yaw_err))
        db.add(desc, key=k)
    has = np.array([r[0] for r in rows])
    correct = np.array([r[1] for r in rows])
    dist = np.array([r[2] for r in rows])
    yaw_err = np.degrees(np.abs([r[3] for r in rows]))
    table = []
    for tau in args.thresholds:
        proposed = dist <= tau
        tp = int((proposed & correct).sum())
        fp = int((proposed & ~correct).sum())
        table.append((tau, tp, fp, tp / max(tp + fp, 1), tp / max(int(has.sum()), 1)))
    return {
        "name": name,
        "keyframes": len(times),
        "queries": len(rows),
        "with_revisit": int(has.sum()),
        "top1_correct": int((correct & has).sum()),
        "yaw_median": float(np.median(yaw_err[correct])) if correct.any() else math.nan,
        "yaw_max": float(yaw_err[correct].max()) if correct.any() else math.nan,
        "table": table,
        "describe_ms": 1e3 * statistics.median(t_describe),
        "query_ms": 1e3 * statistics.median(t_query),
        "db": db,
    }


def time_against_numpy(course: sim.Course, lidar: sim.LidarModel, repeats: int) -> list[str]:
    """Alternate scanreg and the NumPy peer call by call on the same inputs."""
    sweep = sim.simulate_sweep(course.scene, lidar, course.trajectory, start_time=3.0)
    pts = np.ascontiguousarray(sweep.points_deskewed)
    db = place.PlaceDatabase()
    lap = float(course.pass_start_times[1])
    descs = []
    for k, t in enumerate(np.arange(0.0, lap, 0.2)):
        s = sim.simulate_sweep(course.scene, lidar, course.trajectory, start_time=float(t), seed=k)
        d = db.describe(s.points_deskewed)
        db.add(d, key=k)
        descs.append(d.descriptor)
    stack = np.array(descs)
    keys = stack.mean(axis=2)
    query = db.describe(pts)
    ours_d, theirs_d, ours_q, theirs_q = [], [], [], []
    ref = numpy_describe(pts, 20, 60, 80.0)
    assert np.array_equal(ref, query.descriptor), "the NumPy peer disagrees with scanreg"
    for _ in range(repeats):
        t0 = time.perf_counter()
        place.ScanContext.from_points(pts)
        t1 = time.perf_counter()
        numpy_describe(pts, 20, 60, 80.0)
        t2 = time.perf_counter()
        db.query(query)
        t3 = time.perf_counter()
        numpy_query(query.descriptor, stack, keys)
        t4 = time.perf_counter()
        ours_d.append(t1 - t0)
        theirs_d.append(t2 - t1)
        ours_q.append(t3 - t2)
        theirs_q.append(t4 - t3)
    assert db.query(query)[0].index == numpy_query(query.descriptor, stack, keys)[0]
    ratios_d = [a / b for a, b in zip(ours_d, theirs_d, strict=True)]
    ratios_q = [a / b for a, b in zip(ours_q, theirs_q, strict=True)]
    med = statistics.median
    return [
        "| operation | scanreg ms | NumPy ms | ratio (median of pairs) |",
        "|---|---|---|---|",
        f"| describe one sweep ({len(pts)} points) | {1e3 * med(ours_d):.3f} | "
        f"{1e3 * med(theirs_d):.3f} | {med(ratios_d):.3f} |",
        f"| query ({len(db)} keyframes, shortlist 10) | {1e3 * med(ours_q):.3f} | "
        f"{1e3 * med(theirs_q):.3f} | {med(ratios_q):.3f} |",
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spacing", type=float, default=0.2, help="s between keyframes")
    parser.add_argument("--exclude", type=float, default=20.0, help="s of recent keyframes")
    parser.add_argument("--radius", type=float, default=3.0, help="m: a true revisit")
    parser.add_argument("--sensor", default="vlp16")
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument(
        "--thresholds", type=float, nargs="+", default=[0.1, 0.15, 0.2, 0.25, 0.3, 0.4]
    )
    args = parser.parse_args()
    lidar = sim.LidarModel.preset(args.sensor)
    print(f"# {platform.processor() or platform.machine()}, {os.cpu_count()} cores")
    print(f"# sensor {args.sensor}, keyframe every {args.spacing} s, exclude {args.exclude} s")
    courses = {
        "block (2 × 305 m)": sim.block_loop(seed=0, lap_length=305.0, laps=2),
        "repeated block, symmetry 4 (2 × 305 m)": sim.block_loop(
            seed=0,
            lap_length=305.0,
            laps=2,
            aspect=1.0,
            symmetry=4,
            num_pedestrians=0,
            num_moving_cars=0,
        ),
    }
    for name, course in courses.items():
        out = run_course(name, course, lidar, args)
        print(
            f"\n## {name}: {out['keyframes']} keyframes, {out['queries']} queries, "
            f"{out['with_revisit']} with a true revisit; top-1 correct on "
            f"{out['top1_correct']} of them; yaw error of correct top-1 median "
            f"{out['yaw_median']:.2f}°, max {out['yaw_max']:.2f}°"
        )
        print("| τ | proposed correct | proposed wrong | precision | recall |")
        print("|---|---|---|---|---|")
        for tau, tp, fp, p, r in out["table"]:
            print(f"| {tau:.2f} | {tp} | {fp} | {p:.3f} | {r:.3f} |")
        print(
            f"(in-loop medians: describe {out['describe_ms']:.3f} ms, query "
            f"{out['query_ms']:.3f} ms)"
        )
    print("\n## time against a vectorised NumPy implementation (block, first lap database)")
    for line in time_against_numpy(courses["block (2 × 305 m)"], lidar, args.repeats):
        print(line)


if __name__ == "__main__":
    main()
