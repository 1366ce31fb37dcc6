"""Preprocessing and neighbour-search speed on a real KITTI frame, against small_gicp/Open3D.

Run (2 threads for everyone; peers are optional and imported in the same process):

    RAYON_NUM_THREADS=2 .venv/bin/python benchmarks/preprocess_speed.py \
        [--peers-site /tmp/peers-venv/lib/python3.11/site-packages] [--repeat 15]

Prints one row per operation: our median time, each peer's, and our time as a ratio to theirs
(< 1 means scanreg is faster). Peers are never a dependency of scanreg.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

os.environ.setdefault("RAYON_NUM_THREADS", "2")  # before scanreg starts its pool

import numpy as np
import scanreg
from scanreg import preprocess as pp

DATA = Path(os.environ.get("SCANREG_DATA", Path(__file__).resolve().parents[2] / "shared/data"))
FRAME = DATA / "kitti-odometry-00-frames-000-015/velodyne/000000.bin"
VOXEL = 0.25
K = 20
MAX_DISTANCE = 1.0


def median_time(fn: Callable[[], Any], repeat: int) -> float:
    fn()  # warm-up
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def load_peers(site: str | None) -> dict[str, Any]:
    if site:
        sys.path.append(site)
    peers: dict[str, Any] = {}
    try:
        import small_gicp

        peers["small_gicp"] = small_gicp
    except ImportError:
        pass
    try:
        import open3d

        peers["open3d"] = open3d
    except (ImportError, OSError):
        pass
    return peers


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--peers-site", default=None, help="site-packages holding small_gicp/open3d")
    ap.add_argument("--repeat", type=int, default=15)
    args = ap.parse_args()
    threads = int(os.environ["RAYON_NUM_THREADS"])
    raw = np.fromfile(FRAME, dtype=np.float32).reshape(-1, 4)
    frame = np.ascontiguousarray(raw[:, :3], dtype=np.float64)
    down = pp.voxel_downsample(frame, VOXEL).points
    target = scanreg.prepare(down, normals=False)
    # Queries: the full frame moved by 10 cm, gated at MAX_DISTANCE.
    queries = frame + np.array([0.1, 0.0, 0.0])
    print(
        f"frame {FRAME.name}: {len(frame)} points; voxel {VOXEL} m -> {len(down)}; "
        f"k = {K}; {threads} threads; median of {args.repeat}"
    )

    ours: dict[str, Callable[[], Any]] = {
        "voxel downsample (centroid)": lambda: pp.voxel_downsample(frame, VOXEL),
        "kd-tree build": lambda: scanreg.prepare(down, normals=False),
        "batch nearest (full frame)": lambda: target.nearest(queries, MAX_DISTANCE),
        "normals (incl. tree)": lambda: scanreg.prepare(down, normals=True, num_neighbors=K),
        "normals+covariances (incl. tree)": lambda: scanreg.prepare(
            down, normals=True, covariances=True, num_neighbors=K
        ),
    }
    theirs: dict[str, dict[str, Callable[[], Any]]] = {}
    peers = load_peers(args.peers_site)
    if "small_gicp" in peers:
        sg = peers["small_gicp"]
        cloud = sg.PointCloud(frame)
        sg_down = sg.voxelgrid_sampling(cloud, VOXEL, threads)
        sg_tree = sg.KdTree(sg_down, threads)

        def sg_normals() -> None:
            pc = sg.PointCloud(down)
            sg.estimate_normals(pc, sg.KdTree(pc, threads), K, threads)

        def sg_both() -> None:
            pc = sg.PointCloud(down)
            sg.estimate_normals_covariances(pc, sg.KdTree(pc, threads), K, threads)

        theirs["small_gicp"] = {
            # small_gicp's numpy overload of voxelgrid_sampling copies into a PointCloud first;
            # time it from numpy like ours.
            "voxel downsample (centroid)": lambda: sg.voxelgrid_sampling(
                sg.PointCloud(frame), VOXEL, threads
            ),
            "kd-tree build": lambda: sg.KdTree(down, threads),
            # Returns Python lists (its binding's choice): part of what a caller pays.
            "batch nearest (full frame)": lambda: sg_tree.batch_nearest_neighbor_search(
                queries, threads
            ),
            "normals (incl. tree)": sg_normals,
            "normals+covariances (incl. tree)": sg_both,
        }
    if "open3d" in peers:
        o3 = peers["open3d"]
        pcd = o3.geometry.PointCloud(o3.utility.Vector3dVector(frame))
        # Vector3dVector wants a writable array; scanreg's outputs are read-only.
        pcd_down = o3.geometry.PointCloud(o3.utility.Vector3dVector(np.array(down)))

        def o3_normals() -> None:
            p = o3.geometry.PointCloud(pcd_down)
            p.estimate_normals(o3.geometry.KDTreeSearchParamKNN(K))

        theirs["open3d"] = {
            "voxel downsample (centroid)": lambda: pcd.voxel_down_sample(VOXEL),
            "kd-tree build": lambda: o3.geometry.KDTreeFlann(pcd_down),
            "normals (incl. tree)": o3_normals,
        }

    names = list(theirs)
    header = (
        ["operation", "scanreg ms"] + [f"{n} ms" for n in names] + [f"ratio vs {n}" for n in names]
    )
    rows = []
    for op, fn in ours.items():
        t = median_time(fn, args.repeat)
        row = [op, f"{1e3 * t:.2f}"]
        ratios = []
        for n in names:
            if op in theirs[n]:
                tp = median_time(theirs[n][op], args.repeat)
                row.append(f"{1e3 * tp:.2f}")
                ratios.append(f"{t / tp:.2f}")
            else:
                row.append("—")
                ratios.append("—")
        rows.append(row + ratios)
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
    print("| " + " | ".join(h.ljust(w) for h, w in zip(header, widths, strict=True)) + " |")
    print("|" + "|".join("-" * (w + 2) for w in widths) + "|")
    for r in rows:
        print("| " + " | ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)) + " |")
    if not names:
        print("(no peer importable: pass --peers-site to compare with small_gicp / Open3D)")


if __name__ == "__main__":
    main()
