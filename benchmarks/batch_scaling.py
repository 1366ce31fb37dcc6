"""Batch throughput: jobs/s of the local and Ray engines with 1 and 2 workers.

Two workloads, each a manifest of independent jobs:

* odometry: simulated drives (``sim:street,frames=F,seed=k``), seconds of work per job;
* register: small GICP pairs (a 3k-point scan against a shared 12k-point map), milliseconds of
  work per job, so the engine's own cost per job shows.

Each engine is warmed (workers started, scanreg imported) before it is timed; every round
runs every contender in turn and the table gives medians over rounds. ``overhead/job`` is the
wall time each slot spends per job beyond the job's own time
(``slots * wall / jobs - mean job seconds``).

    .venv/bin/python benchmarks/batch_scaling.py [--rounds 3] [--odometry-jobs 8] [--frames 8]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
from scanreg import SE3, io
from scanreg.batch import make_engine, run_batch


def odometry_manifest(folder: Path, jobs: int, frames: int) -> Path:
    path = folder / "drives.csv"
    rows = [f'd{k:03d},"sim:street,frames={frames},seed={k}"' for k in range(jobs)]
    path.write_text("id,input\n" + "\n".join(rows) + "\n")
    return path


def register_manifest(folder: Path, jobs: int) -> Path:
    rng = np.random.default_rng(0)
    cloud = np.ascontiguousarray(rng.uniform(-20, 20, (12000, 3)) * [1, 1, 0.1])
    io.write_points(folder / "map.ply", io.PointCloud(points=cloud))
    rows = []
    for k in range(jobs):
        pose = SE3.from_vector([0.2, -0.1, 0.02, 0.0, 0.0, 0.01 * (k % 7)])
        part = np.ascontiguousarray(cloud[k % 4 :: 4])
        scan = pose.inverse().apply(part) + rng.normal(0, 0.01, part.shape)
        io.write_points(folder / f"scan{k:03d}.pcd", io.PointCloud(points=scan))
        rows.append(f"p{k:03d},scan{k:03d}.pcd,map.ply")
    (folder / "reg.toml").write_text('method = "gicp"\nmax_correspondence_distance = 1.0\n')
    path = folder / "pairs.csv"
    path.write_text("id,source,target,config\n" + "\n".join(f"{r},reg.toml" for r in rows) + "\n")
    return path


def timed(engine: Any, kind: str, manifest: Path, out: Path) -> tuple[float, float, int]:
    t0 = time.perf_counter()
    report = run_batch(kind, manifest, out, engine=engine, retries=0)
    wall = time.perf_counter() - t0
    assert report.ok, report.failed
    job_seconds = statistics.fmean(r["seconds"] for r in report.records)
    return wall, job_seconds, len(report.records)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--odometry-jobs", type=int, default=8)
    parser.add_argument("--frames", type=int, default=8)
    parser.add_argument("--register-jobs", type=int, default=40)
    parser.add_argument("--no-ray", action="store_true")
    args = parser.parse_args()

    tmp = Path(tempfile.mkdtemp(prefix="batch-bench-"))
    manifests = {
        "odometry": odometry_manifest(tmp, args.odometry_jobs, args.frames),
        "register": register_manifest(tmp, args.register_jobs),
    }
    engines = [("local", 1), ("local", 2)]
    if not args.no_ray:
        engines += [("ray", 1), ("ray", 2)]
    # wall, job seconds per (engine, workers, kind)
    results: dict[tuple[str, int, str], list[tuple[float, float, int]]] = defaultdict(list)
    # Every round runs every contender in turn (a driver holds one Ray cluster at a time:
    # each contender starts its engine, warms it, is timed and stops it).
    for r in range(args.rounds):
        for name, workers in engines:
            engine = make_engine(name, workers=workers, threads_per_job=1)
            try:
                for kind, manifest in manifests.items():  # warm-up: workers up, imports done
                    timed(engine, kind, manifest, tmp / f"warm-{name}{workers}-{kind}-{r}")
                for kind, manifest in manifests.items():
                    out = tmp / f"out-{name}{workers}-{kind}-{r}"
                    results[(name, workers, kind)].append(timed(engine, kind, manifest, out))
            finally:
                engine.close()

    print("| workload | engine | workers | jobs/s | scaling 1→2 | job s | overhead/job ms |")
    print("|---|---|---|---|---|---|---|")
    for kind in manifests:
        for name, workers in engines:
            runs = results[(name, workers, kind)]
            wall = statistics.median(w for w, _, _ in runs)
            job = statistics.median(j for _, j, _ in runs)
            n = runs[0][2]
            rate = n / wall
            base = statistics.median(w for w, _, _ in results[(name, 1, kind)])
            scaling = f"{base / wall:.2f}×" if workers == 2 else ""
            overhead = 1e3 * (workers * wall / n - job)
            print(
                f"| {kind} | {name} | {workers} | {rate:.2f} | {scaling} | {job:.3f} |"
                f" {overhead:.1f} |"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
