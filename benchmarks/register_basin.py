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

``--wide``: yaw offsets 0-90° (0, 30, 45, 60, 70, 80, 90) at 0 and 1 m, in 3D (the pairs above)
and in 2D (``--dim 2``: eight Intel pairs, every 8th scan from 8, against the chain reference of
``scan2d_speed.py``; gate 0.3 m, k = 10, <= 30 iterations, success within 10 cm / 1°; small_gicp
gets the scans with z = 0). Besides the success rates it counts, for scanreg, the starts
returned unchanged and the stop reasons: far outside the basin a run must end in a minimum or a
named stop, never hand back its start labelled ``diverged``. Without ``--wide`` the last
table, overall success per pair and method, is the one in ``benchmarks/README.md``.
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
from scanreg import SE2, SE3
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
        tgt, normals=method == "point_to_plane", covariances=method == "gicp", num_neighbors=K
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


def small_gicp(
    sg: Any,
    src: np.ndarray,
    tgt: np.ndarray,
    method: str,
    threads: int,
    gate: float = GATE,
    k: int = K,
    iterations: int = MAX_ITERATIONS,
) -> Align:
    s_pc, t_pc = sg.PointCloud(src), sg.PointCloud(tgt)
    t_tree = sg.KdTree(t_pc, threads)
    sg.estimate_normals_covariances(t_pc, t_tree, k, threads)
    sg.estimate_normals_covariances(s_pc, sg.KdTree(s_pc, threads), k, threads)

    def align(init: SE3) -> SE3:
        r = sg.align(
            t_pc,
            s_pc,
            t_tree,
            init_T_target_source=init.as_matrix(),
            registration_type=SMALL_GICP[method],
            max_correspondence_distance=gate,
            num_threads=threads,
            max_iterations=iterations,
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


GATE_2D, K_2D, MAX_ITERATIONS_2D = 0.3, 10, 30
WIDE_YAWS_DEG = (0, 30, 45, 60, 70, 80, 90)
WIDE_OFFSETS_M = (0.0, 1.0)


def intel_pairs() -> dict[str, tuple[np.ndarray, np.ndarray, SE2]]:
    from scanreg.io import read_carmen

    log = read_carmen(DATA / "carmen-intel/intel.gfs.log")
    out = {}
    for k in range(8, 72, 8):
        src, tgt = log.scans[k].to_points(0.1, 40.0), log.scans[k - 1].to_points(0.1, 40.0)
        c = scanreg.match_correlative(
            src, tgt, init=log.motion_prior(k - 1, k), window=(0.3, 0.3, np.deg2rad(10.0))
        )
        r = scanreg.register(
            src,
            tgt,
            method="point_to_line",
            init=c.pose,
            max_correspondence_distance=0.15,
            kernel="huber",
        )
        ref = r.pose if r.converged else c.pose
        assert isinstance(ref, SE2)
        out[f"intel {k - 1}->{k}"] = (src, tgt, ref)
    return out


def wide(sg: Any, dim: int, directions: int, threads: int) -> None:
    """Yaw offsets up to 90°: success rates, and how scanreg's failures end."""
    from collections import Counter

    data = intel_pairs() if dim == 2 else pairs()
    gate, k, iters = (GATE_2D, K_2D, MAX_ITERATIONS_2D) if dim == 2 else (GATE, K, MAX_ITERATIONS)
    methods = ("point_to_point", "point_to_line", "gicp") if dim == 2 else tuple(SMALL_GICP)
    for method in methods:
        hits: dict[tuple[str, int], list[int]] = {}
        ends: Counter[str] = Counter()
        for src, tgt, truth in data.values():
            prepared = scanreg.prepare(
                tgt,
                normals=method != "point_to_point",
                covariances=method == "gicp",
                num_neighbors=k,
            )
            peer = None
            if sg is not None:
                pad = (lambda p: np.hstack([p, np.zeros((len(p), 1))])) if dim == 2 else np.array
                peer = small_gicp(
                    sg, pad(src), pad(tgt), method.replace("line", "plane"), threads, gate, k, iters
                )
            for yaw in WIDE_YAWS_DEG:
                for off in WIDE_OFFSETS_M:
                    rng = np.random.default_rng(int(yaw * 100 + off * 10))
                    for _ in range(directions):
                        ang = rng.uniform(0, 2 * np.pi)
                        sign = rng.choice([-1.0, 1.0])
                        v = [off * np.cos(ang), off * np.sin(ang), sign * np.deg2rad(yaw)]
                        if dim == 2:
                            start: Any = truth @ SE2.from_vector(v)
                        else:
                            start = truth @ SE3.from_vector([v[0], v[1], 0, 0, 0, v[2]])
                        r = scanreg.register(
                            src,
                            prepared,
                            method=method,  # type: ignore[arg-type]
                            init=start,
                            max_correspondence_distance=gate,
                            max_iterations=iters,
                        )
                        cell = hits.setdefault((f"{yaw}", int(off * 10)), [0, 0, 0])
                        cell[2] += 1
                        good = ok2(r.pose, truth)
                        cell[0] += good
                        moved = float(np.abs((start.inverse() @ r.pose).log()).max()) > 1e-12
                        if not good:
                            ends[f"{r.stop_reason}{'' if moved else ' (start returned)'}"] += 1
                        if peer is not None:
                            p = start
                            if dim == 2:
                                m = np.eye(4)
                                m[:2, :2], m[:2, 3] = start.rotation, start.translation
                                p = SE3.from_matrix(m)
                            q = peer(p)
                            if dim == 2:
                                q = SE2.from_vector(
                                    [
                                        *q.translation[:2],
                                        np.arctan2(q.rotation[1, 0], q.rotation[0, 0]),
                                    ]
                                )
                            cell[1] += ok2(q, truth)
        print(f"\n{dim}D {method}: success % (scanreg / small_gicp), rows yaw°, cols offset m")
        print("| yaw \\ offset | " + " | ".join(f"{o:g} m" for o in WIDE_OFFSETS_M) + " |")
        print("|---" * (len(WIDE_OFFSETS_M) + 1) + "|")
        for yaw in WIDE_YAWS_DEG:
            cells = []
            for off in WIDE_OFFSETS_M:
                a, b, n = hits[(f"{yaw}", int(off * 10))]
                cells.append(f"{100 * a // n} / {100 * b // n if sg is not None else '-'}")
            print(f"| {yaw}° | " + " | ".join(cells) + " |")
        print(
            "scanreg's misses ended as: " + ", ".join(f"{k} {v}" for k, v in sorted(ends.items()))
        )


def ok2(pose: Any, truth: Any) -> bool:
    d = (truth.inverse() @ pose).log()
    k = 2 if isinstance(pose, SE2) else 3
    return bool(
        np.linalg.norm(d[:k]) < SUCCESS_M and np.degrees(np.linalg.norm(d[k:])) < SUCCESS_DEG
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--peers-site", default=None)
    ap.add_argument("--directions", type=int, default=4)
    ap.add_argument("--wide", action="store_true", help="yaw offsets up to 90° (see above)")
    ap.add_argument("--dim", type=int, choices=(2, 3), default=3, help="with --wide")
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
    if args.wide:
        wide(sg, args.dim, args.directions, threads)
        return
    overall: list[str] = []
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
            shares = [f"{100 * totals[lib] / runs:.0f} %" if lib in totals else "-" for lib in LIBS]
            print(
                "overall: " + ", ".join(f"{lib} {v}" for lib, v in zip(LIBS, shares, strict=True))
            )
            overall.append(f"| {name} | {method} | " + " | ".join(shares) + " |")
    print("\n| pair | method | scanreg | small_gicp | Open3D |")
    print("|---|---|---:|---:|---:|")
    print("\n".join(overall))


if __name__ == "__main__":
    main()
