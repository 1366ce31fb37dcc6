"""Basin of convergence: success rate of local registration over a grid of initial offsets.

Run (peers optional, same process, same inputs and settings):

    RAYON_NUM_THREADS=2 .venv/bin/python benchmarks/register_basin.py \
        [--peers-site /tmp/peers-venv/lib/python3.11/site-packages] [--directions 4]

For each pair (the outdoor pair against its reference; a simulated street sweep pair with exact
truth) and each method, the initial guess is the truth perturbed by a yaw of 0-45° and a
horizontal translation of 0-3 m (``--directions`` random directions per cell, the same for every
library). A run succeeds when it ends within 10 cm / 1° of the truth (the outdoor reference is
itself only good to ~2 cm / 0.2°, and voxel-0.25 m estimates sit ~0.7° from it in roll).
Settings: voxel 0.25 m, k = 20, gate 1.0 m, <= 50 iterations, 2 threads (Open3D: relative
fitness/RMSE 1e-6). Cells print ``ours% / small_gicp% / open3d%`` (``-``: peer not importable).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

os.environ.setdefault("RAYON_NUM_THREADS", "2")  # before scanreg starts its pool
os.environ.setdefault("OMP_NUM_THREADS", os.environ["RAYON_NUM_THREADS"])  # Open3D's OpenMP

import numpy as np
import scanreg
from scanreg import SE3
from scanreg import preprocess as pp
from scanreg import simulate as sim
from scanreg.io import read_points

DATA = Path(os.environ.get("SCANREG_DATA", Path(__file__).resolve().parents[2] / "shared/data"))
VOXEL = 0.25
K = 20
GATE = 1.0
MAX_ITERATIONS = 50
YAWS_DEG = (0, 5, 10, 20, 30, 45)
OFFSETS_M = (0.0, 0.5, 1.0, 2.0, 3.0)
SUCCESS_M, SUCCESS_DEG = 0.10, 1.0
SMALL_GICP = {"point_to_point": "ICP", "point_to_plane": "PLANE_ICP", "gicp": "GICP"}
OPEN3D = {
    "point_to_point": "TransformationEstimationPointToPoint",
    "point_to_plane": "TransformationEstimationPointToPlane",
    "gicp": "TransformationEstimationForGeneralizedICP",
}
LIBS = ("ours", "small_gicp", "open3d")
Align = Callable[[SE3], SE3]


def pairs() -> dict[str, tuple[np.ndarray, np.ndarray, SE3]]:
    root = DATA / "gicp-outdoor-scan-pair/small_gicp"
    src = pp.voxel_downsample(np.ascontiguousarray(read_points(root / "source.ply").points), VOXEL)
    tgt = pp.voxel_downsample(np.ascontiguousarray(read_points(root / "target.ply").points), VOXEL)
    ref = SE3.from_matrix(np.loadtxt(root / "T_target_source.txt"), atol=1e-4)
    lidar = dataclasses.replace(sim.LidarModel.preset("hdl32"), range_sigma=0.02)
    street = sim.street(seed=0)
    a = SE3.from_vector([0.0, 1.75, 1.73, 0, 0, 0])
    b = SE3.from_vector([1.0, 1.9, 1.73, 0, 0, np.deg2rad(2.0)])
    sa = sim.simulate_sweep(street, lidar, a, seed=1).points
    sb = sim.simulate_sweep(street, lidar, b, seed=2).points
    return {
        "outdoor pair (ref)": (src.points, tgt.points, ref),
        "sim street hdl32 (exact)": (
            pp.voxel_downsample(sb, VOXEL).points,
            pp.voxel_downsample(sa, VOXEL).points,
            a.inverse() @ b,
        ),
    }


def inits(truth: SE3, yaw_deg: float, offset: float, directions: int) -> list[SE3]:
    rng = np.random.default_rng(int(yaw_deg * 100 + offset * 10))
    out = []
    for _ in range(directions):
        ang = rng.uniform(0, 2 * np.pi)
        sign = rng.choice([-1.0, 1.0])
        d = SE3.from_vector(
            [offset * np.cos(ang), offset * np.sin(ang), 0, 0, 0, sign * np.deg2rad(yaw_deg)]
        )
        out.append(truth @ d)
    return out


def ok(pose: SE3, truth: SE3) -> bool:
    d = (truth.inverse() @ pose).log()
    return bool(
        np.linalg.norm(d[:3]) < SUCCESS_M and np.degrees(np.linalg.norm(d[3:])) < SUCCESS_DEG
    )


def ours(src: np.ndarray, tgt: np.ndarray, method: str) -> Align:
    prepared = scanreg.prepare(
        tgt, normals=method == "point_to_plane", covariances=method == "gicp", k=K
    )

    def align(init: SE3) -> SE3:
        res = scanreg.register(
            src,
            prepared,
            method=method,  # type: ignore[arg-type]
            init=init,
            max_correspondence_distance=GATE,
            max_iterations=MAX_ITERATIONS,
            num_neighbors=K,
        )
        return res.pose  # type: ignore[return-value]

    return align


def small_gicp(sg: Any, src: np.ndarray, tgt: np.ndarray, method: str, threads: int) -> Align:
    s_pc, t_pc = sg.PointCloud(src), sg.PointCloud(tgt)
    t_tree = sg.KdTree(t_pc, threads)
    sg.estimate_normals_covariances(t_pc, t_tree, K, threads)
    sg.estimate_normals_covariances(s_pc, sg.KdTree(s_pc, threads), K, threads)

    def align(init: SE3) -> SE3:
        r = sg.align(
            t_pc,
            s_pc,
            t_tree,
            init_T_target_source=init.as_matrix(),
            registration_type=SMALL_GICP[method],
            max_correspondence_distance=GATE,
            num_threads=threads,
            max_iterations=MAX_ITERATIONS,
        )
        return SE3.from_matrix(r.T_target_source, atol=1e-5)

    return align


def open3d(o3d: Any, src: np.ndarray, tgt: np.ndarray, method: str) -> Align:
    reg = o3d.pipelines.registration
    # Vector3dVector wants writable arrays; the inputs are read-only.
    s, t = (o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.array(p))) for p in (src, tgt))
    knn = o3d.geometry.KDTreeSearchParamKNN(K)
    # GICP: covariances from k-NN normals, regularised as planes (eigenvalues 1e-3, 1, 1) like ours
    # and small_gicp's (Open3D would take estimate_covariances' raw ones as they are).
    if method != "point_to_point":
        t.estimate_normals(knn)
    if method == "gicp":
        s.estimate_normals(knn)
    run = reg.registration_generalized_icp if method == "gicp" else reg.registration_icp
    estimation = getattr(reg, OPEN3D[method])()
    criteria = reg.ICPConvergenceCriteria(
        relative_fitness=1e-6, relative_rmse=1e-6, max_iteration=MAX_ITERATIONS
    )
    return lambda init: SE3.from_matrix(
        np.asarray(run(s, t, GATE, init.as_matrix(), estimation, criteria).transformation),
        atol=1e-5,
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--peers-site", default=None)
    ap.add_argument("--directions", type=int, default=4)
    args = ap.parse_args()
    if args.peers_site:
        sys.path.append(args.peers_site)
    sg: Any = None
    o3d: Any = None
    with contextlib.suppress(ImportError):
        import small_gicp as sg
    with contextlib.suppress(ImportError, OSError):
        import open3d as o3d
    for lib, mod in (("small_gicp", sg), ("open3d", o3d)):
        if mod is None:
            print(f"({lib} not importable: skipped; pass --peers-site)")
    threads = int(os.environ["RAYON_NUM_THREADS"])
    for name, (src, tgt, truth) in pairs().items():
        for method in SMALL_GICP:
            aligners = {"ours": ours(src, tgt, method)}
            if sg is not None:
                aligners["small_gicp"] = small_gicp(sg, src, tgt, method, threads)
            if o3d is not None:
                aligners["open3d"] = open3d(o3d, src, tgt, method)
            print(f"\n{name}, {method}: success % ({' / '.join(LIBS)}), rows yaw°, cols offset m")
            print("| yaw \\ offset | " + " | ".join(f"{o:g} m" for o in OFFSETS_M) + " |")
            print("|---" * (len(OFFSETS_M) + 1) + "|")
            totals = dict.fromkeys(aligners, 0)
            runs = 0
            for yaw in YAWS_DEG:
                cells = []
                for off in OFFSETS_M:
                    starts = inits(truth, yaw, off, args.directions)
                    hits = {
                        lib: sum(ok(align(init), truth) for init in starts)
                        for lib, align in aligners.items()
                    }
                    for lib, h in hits.items():
                        totals[lib] += h
                    runs += len(starts)
                    pct = {lib: f"{100 * h // len(starts)}" for lib, h in hits.items()}
                    cells.append(" / ".join(pct.get(lib, "-") for lib in LIBS))
                print(f"| {yaw}° | " + " | ".join(cells) + " |")
            print(
                "overall: "
                + ", ".join(
                    f"{lib} {100 * totals[lib] / runs:.0f} %" if lib in totals else f"{lib} -"
                    for lib in LIBS
                )
            )


if __name__ == "__main__":
    main()
