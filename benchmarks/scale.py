"""Scale: time and peak memory per point from 10 k to 10 M points.

Each cell runs in a fresh Python process (peak RSS is a process-wide high-water mark), on a
synthetic outdoor-like cloud (half ground plane, half scattered structure, 100 m across):

* ``index``: ``prepare(points, normals=False)`` — the k-d tree;
* ``normals`` / ``covariances``: ``prepare`` with normals (point-to-plane) / GICP covariances;
* ``register``: ``register(points, target, method="point_to_plane", max_iterations=3)`` of the
  whole cloud against a prepared 20 k-point target (per *source* point);
* ``local_map``: ``LocalMap(3, 0.05, 20).insert(points)`` (the odometry map's storage);
* ``voxel``: ``voxel_downsample(points, 0.5)``.

Bytes per point = (peak RSS − RSS before the call) / N. The rounded-up figures are the
estimates :mod:`scanreg.budget` checks against a memory budget. Time per point near-constant
across rows is the near-linear scaling the issue asks for.

    .venv/bin/python benchmarks/scale.py                 # 1e4 .. 1e6
    .venv/bin/python benchmarks/scale.py --max 1e7       # up to 10 M (a few minutes; ~6 GB)
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys

CASES = ("index", "normals", "covariances", "register", "local_map", "voxel")

_CHILD = r"""
import json, resource, sys, time
import numpy as np
n, what = int(sys.argv[1]), sys.argv[2]
rng = np.random.default_rng(0)
pts = rng.uniform(-50, 50, (n, 3))
pts[: n // 2, 2] = rng.normal(0, 0.02, n // 2)
import scanreg
from scanreg.preprocess import voxel_downsample
target = None
if what == "register":
    small = rng.uniform(-50, 50, (20000, 3)); small[:10000, 2] = 0.0
    target = scanreg.prepare(small)
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
t0 = time.perf_counter()
if what == "index":
    out = scanreg.prepare(pts, normals=False)
elif what == "normals":
    out = scanreg.prepare(pts)
elif what == "covariances":
    out = scanreg.prepare(pts, normals=False, covariances=True)
elif what == "register":
    out = scanreg.register(pts, target, method="point_to_plane", max_iterations=3)
elif what == "local_map":
    out = scanreg.LocalMap(3, 0.05, 20); out.insert(pts)
elif what == "voxel":
    out = voxel_downsample(pts, 0.5)
seconds = time.perf_counter() - t0
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(json.dumps({"seconds": seconds, "bytes_per_point": (peak - base) * 1024 / n}))
"""


def measure(n: int, what: str) -> dict[str, float]:
    out = subprocess.run(
        [sys.executable, "-c", _CHILD, str(n), what], check=True, capture_output=True, text=True
    )
    result: dict[str, float] = json.loads(out.stdout)
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--max", type=float, default=1e6, help="largest cloud (points)")
    parser.add_argument("--cases", nargs="*", default=list(CASES), choices=CASES)
    args = parser.parse_args()
    sizes = [n for n in (10_000, 100_000, 1_000_000, 10_000_000) if n <= args.max]
    print("| case | " + " | ".join(f"{n:,} pts" for n in sizes) + " |")
    print("|---|" + "---:|" * len(sizes))
    for what in args.cases:
        cells = []
        for n in sizes:
            r = measure(n, what)
            cells.append(f"{r['bytes_per_point']:.0f} B, {1e9 * r['seconds'] / n:.0f} ns")
        print(f"| {what} | " + " | ".join(cells) + " |")
    print("\n(bytes per point of peak RSS; nanoseconds per point of wall time)")


if __name__ == "__main__":
    main()
