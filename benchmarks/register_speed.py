"""Registration speed and accuracy on real pairs, against small_gicp (and Open3D if importable).

Run (2 threads for everyone; peers are optional and imported in the same process):

    RAYON_NUM_THREADS=2 .venv/bin/python benchmarks/register_speed.py \
        [--peers-site /tmp/peers-venv/lib/python3.11/site-packages] [--repeat 11]

Pairs: KITTI 00 frames 000001 -> 000000 and the small_gicp/fast_gicp outdoor pair. Settings
shared by every library: voxel 0.25 m (centroid), k = 20 neighbours for normals/covariances,
max correspondence distance 1.0 m, at most 20 iterations, convergence at 1e-3 m / 0.1°
(small_gicp's defaults), 2 threads, initial guess identity.

Stages, timed the same way for each library (best of --repeat runs after a warm-up; --median
for medians):
* preprocess: downsample both clouds, build the target index, the normals (point-to-plane) or
  the covariances of both clouds (GICP) — only what the method needs;
* register: the alignment call on the preprocessed inputs;
* end-to-end: raw arrays in, pose out.
Ratio = our time / theirs (< 1: scanreg faster).

--memory: peak memory of one end-to-end run (raw arrays in, pose out), each library in a fresh
process per pair and method: the data are loaded and the library imported first, then the
kernel's peak-RSS mark is reset (/proc/self/clear_refs) and the run's VmHWM minus the RSS
before it is reported (native allocations included, which tracemalloc would miss).

--scaling: preparation (index + normals or covariances) and registration time against
N = 10k, 100k, 1M points. Accuracy: translation / rotation error against
the outdoor pair's reference (small_gicp's T_target_source.txt, itself a registration good to
~2 cm / 0.2°); for KITTI, whose published ground truth is doubtful for these scans, the
difference from small_gicp's estimate. "it": linearisations (correspondence searches with a
step computed), counted the same way for both libraries.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

os.environ.setdefault("RAYON_NUM_THREADS", "2")  # before scanreg starts its pool
os.environ.setdefault("OMP_NUM_THREADS", os.environ["RAYON_NUM_THREADS"])  # Open3D's OpenMP

import numpy as np
import scanreg
from scanreg import SE3
from scanreg import preprocess as pp
from scanreg.io import read_points

DATA = Path(os.environ.get("SCANREG_DATA", Path(__file__).resolve().parents[2] / "shared/data"))
VOXEL = 0.25
K = 20
GATE = 1.0
MAX_ITERATIONS = 20
TRANSLATION_EPS = 1e-3
ROTATION_EPS = np.deg2rad(0.1)
BEST_OF = True  # set by --median
CLOCK = time.perf_counter  # time.process_time with --cpu-time

OURS = {"point_to_point": "point_to_point", "point_to_plane": "point_to_plane", "gicp": "gicp"}
SMALL_GICP = {"point_to_point": "ICP", "point_to_plane": "PLANE_ICP", "gicp": "GICP"}


def median_time(fn: Callable[[], Any], repeat: int) -> tuple[float, Any]:
    out = fn()  # warm-up
    times = []
    for _ in range(repeat):
        t0 = CLOCK()
        out = fn()
        times.append(CLOCK() - t0)
    # Best of N: on a shared, loaded machine the minimum is the least disturbed estimate (OpenMP
    # peers spin-wait and suffer more from oversubscription than rayon, which skews medians).
    return (min(times) if BEST_OF else statistics.median(times)), out


def load_pairs() -> dict[str, tuple[np.ndarray, np.ndarray, SE3 | None]]:
    def kitti(i: int) -> np.ndarray:
        path = DATA / f"kitti-odometry-00-frames-000-015/velodyne/{i:06d}.bin"
        raw = np.fromfile(path, dtype=np.float32).reshape(-1, 4)
        return np.ascontiguousarray(raw[:, :3], dtype=np.float64)

    root = DATA / "gicp-outdoor-scan-pair/small_gicp"
    ref = SE3.from_matrix(np.loadtxt(root / "T_target_source.txt"), atol=1e-4)
    return {
        "kitti 01->00": (kitti(1), kitti(0), None),
        "outdoor pair": (
            np.ascontiguousarray(read_points(root / "source.ply").points),
            np.ascontiguousarray(read_points(root / "target.ply").points),
            ref,
        ),
    }


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


def error(pose: SE3, ref: SE3) -> tuple[float, float]:
    d = (ref.inverse() @ pose).log()
    return float(np.linalg.norm(d[:3])), float(np.degrees(np.linalg.norm(d[3:])))


# --- scanreg ------------------------------------------------------------------------------


def ours_preprocess(src: np.ndarray, tgt: np.ndarray, method: str) -> tuple[Any, Any]:
    s = pp.voxel_downsample(src, VOXEL).points
    t = pp.voxel_downsample(tgt, VOXEL).points
    prepared = scanreg.prepare(
        t, normals=method == "point_to_plane", covariances=method == "gicp", num_neighbors=K
    )
    return s, prepared


def ours_register(s: np.ndarray, prepared: Any, method: str) -> scanreg.RegistrationResult:
    return scanreg.register(
        s,
        prepared,
        method=OURS[method],  # type: ignore[arg-type]
        max_correspondence_distance=GATE,
        max_iterations=MAX_ITERATIONS,
        translation_tolerance=TRANSLATION_EPS,
        rotation_tolerance=ROTATION_EPS,
        num_neighbors=K,
    )


def with_trust(res: scanreg.RegistrationResult) -> scanreg.RegistrationResult:
    """Read what a user fusing the estimate reads: this runs the lazy trust analysis."""
    assert res.verdict is not None and res.covariance.shape == (6, 6)
    return res


def run_ours(src: np.ndarray, tgt: np.ndarray, method: str, repeat: int) -> dict[str, Any]:
    pre, (s, prepared) = median_time(lambda: ours_preprocess(src, tgt, method), repeat)
    # GICP's source covariances are computed inside register(); they belong to "preprocess", so
    # split each run by register()'s own timer (source_preparation) and aggregate per part.
    runs = []
    for _ in range(repeat + 1):
        t0 = CLOCK()
        r = ours_register(s, prepared, method)
        runs.append((CLOCK() - t0, r))
    runs = runs[1:]  # warm-up
    agg = min if BEST_OF else statistics.median
    src_prep = agg(r.timing.source_preparation for _, r in runs)
    reg = agg(t - r.timing.source_preparation for t, r in runs)
    e2e, res = median_time(
        lambda: ours_register(*ours_preprocess(src, tgt, method), method), repeat
    )
    return {
        "preprocess": pre + src_prep,
        "register": reg,
        "end-to-end": e2e,
        "pose": res.pose,
        "iterations": res.iterations,
    }


# --- small_gicp ----------------------------------------------------------------------------


def run_small_gicp(
    sg: Any,
    src: np.ndarray,
    tgt: np.ndarray,
    method: str,
    threads: int,
    repeat: int,
    once: bool = False,
) -> dict[str, Any]:
    def preprocess() -> tuple[Any, Any, Any]:
        s = sg.voxelgrid_sampling(sg.PointCloud(src), VOXEL, threads)
        t = sg.voxelgrid_sampling(sg.PointCloud(tgt), VOXEL, threads)
        tree = sg.KdTree(t, threads)
        if method == "point_to_plane":
            sg.estimate_normals(t, tree, K, threads)
        elif method == "gicp":
            sg.estimate_covariances(t, tree, K, threads)
            sg.estimate_covariances(s, sg.KdTree(s, threads), K, threads)
        return s, t, tree

    def register(s: Any, t: Any, tree: Any) -> Any:
        return sg.align(
            t,
            s,
            tree,
            registration_type=SMALL_GICP[method],
            max_correspondence_distance=GATE,
            num_threads=threads,
            max_iterations=MAX_ITERATIONS,
            rotation_epsilon=ROTATION_EPS,
            translation_epsilon=TRANSLATION_EPS,
        )

    if once:  # one end-to-end run only (memory measurement)
        return {"result": register(*preprocess())}
    pre, (s, t, tree) = median_time(preprocess, repeat)
    reg, res = median_time(lambda: register(s, t, tree), repeat)
    e2e, res = median_time(lambda: register(*preprocess()), repeat)
    return {
        "preprocess": pre,
        "register": reg,
        "end-to-end": e2e,
        "pose": SE3.from_matrix(res.T_target_source, atol=1e-5),
        # small_gicp reports the 0-based index of its last iteration (optimizer.hpp:
        # `result.iterations = i`): linearisations = iterations + 1, which is what ours counts.
        "iterations": res.iterations + 1,
    }


# --- Open3D ----------------------------------------------------------------------------


def run_open3d(
    o3d: Any, src: np.ndarray, tgt: np.ndarray, method: str, repeat: int, once: bool = False
) -> dict[str, Any]:
    reg = o3d.pipelines.registration
    # Open3D's Vector3dVector wants writable arrays (it copies them either way); the inputs here
    # are read-only, so copy once, outside the timed functions.
    src, tgt = np.array(src), np.array(tgt)

    def preprocess() -> tuple[Any, Any]:
        s = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(src)).voxel_down_sample(VOXEL)
        t = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(tgt)).voxel_down_sample(VOXEL)
        knn = o3d.geometry.KDTreeSearchParamKNN(K)
        if method == "point_to_plane":
            t.estimate_normals(knn)
        elif method == "gicp":
            t.estimate_covariances(knn)
            s.estimate_covariances(knn)
        return s, t

    estimator = {
        "point_to_point": reg.TransformationEstimationPointToPoint,
        "point_to_plane": reg.TransformationEstimationPointToPlane,
        "gicp": reg.TransformationEstimationForGeneralizedICP,
    }[method]
    criteria = reg.ICPConvergenceCriteria(max_iteration=MAX_ITERATIONS)

    def register(s: Any, t: Any) -> Any:
        return reg.registration_icp(s, t, GATE, np.eye(4), estimator(), criteria)

    if once:  # one end-to-end run only (memory measurement)
        return {"result": register(*preprocess())}
    pre, (s, t) = median_time(preprocess, repeat)
    regt, res = median_time(lambda: register(s, t), repeat)
    e2e, res = median_time(lambda: register(*preprocess()), repeat)
    return {
        "preprocess": pre,
        "register": regt,
        "end-to-end": e2e,
        "pose": SE3.from_matrix(np.asarray(res.transformation), atol=1e-5),
        "iterations": -1,
    }


def _status_kb(field: str) -> int:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(field + ":"):
                return int(line.split()[1])
    raise KeyError(field)


def memory_child(lib: str, pair: str, method: str, peers_site: str | None) -> None:
    """In a fresh process: peak RSS growth (MB) of one end-to-end run of `lib`."""
    src, tgt, _ = load_pairs()[pair]
    threads = int(os.environ["RAYON_NUM_THREADS"])
    run: Callable[[], Any]
    if lib == "scanreg":

        def run() -> Any:
            return ours_register(*ours_preprocess(src, tgt, method), method)

    else:
        mod = load_peers(peers_site)[lib]

        def run() -> Any:
            if lib == "small_gicp":
                return run_small_gicp(mod, src, tgt, method, threads, 0, once=True)
            return run_open3d(mod, src, tgt, method, 0, once=True)

    import gc

    gc.collect()
    with open("/proc/self/clear_refs", "w") as f:
        f.write("5")  # reset VmHWM to the current RSS
    before = _status_kb("VmRSS")
    run()
    print(f"{(_status_kb('VmHWM') - before) / 1024:.1f}")


def peak_memory(lib: str, pair: str, method: str, peers_site: str | None) -> float:
    cmd = [sys.executable, __file__, "--memory-child", lib, pair, method]
    if peers_site:
        cmd += ["--peers-site", peers_site]
    out = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout
    return float(out.strip().splitlines()[-1])


def interleaved(peers: dict[str, Any], threads: int, repeat: int) -> None:
    """End-to-end only, libraries alternating run by run (ours, small_gicp, Open3D, ours, ...):
    a burst of load from other processes then hits every library alike. Reports the best run
    of each and the median over rounds of the per-round ratio (each ratio from two runs
    seconds apart), the statistic least moved by a shared, loaded machine."""
    # "scanreg": pose out (the trust analysis is lazy and not read); "+trust": the same call
    # with its covariance and verdict read, i.e. the whole analysis paid.
    ours_libs = ["scanreg", "scanreg+trust"]
    peer_libs = [n for n in ("small_gicp", "open3d") if n in peers]
    libs = ours_libs + peer_libs
    print(f"\ninterleaved end-to-end, {repeat} rounds (best ms; median of per-round ratios):")
    head = " | ".join(f"{lib} best ms" for lib in libs)
    ratios = " | ".join(f"{o} / {p}" for p in peer_libs for o in ours_libs)
    print(f"| pair | method | {head} | {ratios} |")
    print("|---|---|" + "---|" * (len(libs) + len(ours_libs) * len(peer_libs)))
    for pair, (src, tgt, _) in load_pairs().items():
        for method in OURS:
            fns: dict[str, Callable[[], Any]] = {
                "scanreg": lambda m=method, a=src, b=tgt: ours_register(
                    *ours_preprocess(a, b, m), m
                ),
                "scanreg+trust": lambda m=method, a=src, b=tgt: with_trust(
                    ours_register(*ours_preprocess(a, b, m), m)
                ),
            }
            if "small_gicp" in peers:
                fns["small_gicp"] = lambda m=method, a=src, b=tgt: run_small_gicp(
                    peers["small_gicp"], a, b, m, threads, 0, once=True
                )
            if "open3d" in peers:
                fns["open3d"] = lambda m=method, a=src, b=tgt: run_open3d(
                    peers["open3d"], a, b, m, 0, once=True
                )
            times: dict[str, list[float]] = {lib: [] for lib in libs}
            for lib in libs:
                fns[lib]()  # warm-up
            for _ in range(repeat):
                for lib in libs:
                    t0 = CLOCK()
                    fns[lib]()
                    times[lib].append(CLOCK() - t0)
            best = " | ".join(f"{min(times[lib]) * 1e3:.1f}" for lib in libs)
            rat = " | ".join(
                f"{statistics.median(a / b for a, b in zip(times[o], times[p], strict=True)):.2f}"
                for p in peer_libs
                for o in ours_libs
            )
            print(f"| {pair} | {method} | {best} | {rat} |", flush=True)


def memory_table(peer_names: list[str], peers_site: str | None) -> None:
    libs = ["scanreg", *peer_names]
    print("\npeak RSS growth of one end-to-end run, MB (fresh process per cell):")
    print("| pair | method | " + " | ".join(libs) + " | scanreg / small_gicp |")
    print("|---|---|" + "---|" * len(libs) + "---|")
    for pair in load_pairs():
        for method in OURS:
            mb = {lib: peak_memory(lib, pair, method, peers_site) for lib in libs}
            ratio = f"{mb['scanreg'] / mb['small_gicp']:.2f}" if mb.get("small_gicp") else "-"
            cells = " | ".join(f"{mb[lib]:.1f}" for lib in libs)
            print(f"| {pair} | {method} | {cells} | {ratio} |", flush=True)


def surface(n: int, seed: int) -> np.ndarray:
    """`n` points uniformly on a wavy surface at a constant 25 points/m² (the area grows with
    n), 1 cm noise: a cloud whose local geometry does not change with n."""
    rng = np.random.default_rng(seed)
    side = np.sqrt(n / 25.0)
    xy = rng.uniform(0.0, side, (n, 2))
    z = 0.8 * np.sin(xy[:, 0] / 3.0) * np.cos(xy[:, 1] / 4.0) + 0.3 * np.sin(xy[:, 1] / 1.7)
    pts = np.column_stack([xy, z]) + rng.normal(0.0, 0.01, (n, 3))
    # In raster order (2 m strips), as a scanner delivers points: uniformly random order would
    # make every query of a large cloud a cache miss, which no real scan does.
    order = np.lexsort((xy[:, 0], np.floor(xy[:, 1] / 2.0)))
    return np.ascontiguousarray(pts[order])


def scaling(peers: dict[str, Any], threads: int, repeat: int) -> None:
    """Preparation and registration time against N (no downsampling) on a synthetic wavy
    surface of constant density (its area grows with N, so each point's neighbourhood is the
    same at every N: a scaling test, unlike subsampling or stacking a real scan); the source is
    an independent sampling of the same surface moved by 0.3 m / 1°. Preparation: k-d tree +
    normals (point-to-plane) or covariances (GICP) of the target; registration: the alignment
    call with a prepared target (for GICP, source covariances computed beforehand for
    small_gicp and excluded from ours)."""
    truth = SE3.from_vector([0.3, 0.05, 0.0, 0.0, 0.0, np.deg2rad(1.0)])
    sg = peers.get("small_gicp")
    print("\nscaling (no downsampling; best of runs; it = linearisations):")
    print(
        "| N | method | prepare scanreg ms | prepare small_gicp ms | ratio "
        "| register scanreg ms (it) | register small_gicp ms (it) | ratio "
        "| scanreg µs per point (prep + reg) |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for n in (10_000, 100_000, 1_000_000):
        cloud = surface(n, 0)
        source = np.ascontiguousarray(truth.inverse().apply(surface(n, 1)))
        reps_n = repeat if n < 500_000 else 1
        for method in ("point_to_plane", "gicp"):

            def prep(c: np.ndarray = cloud, m: str = method) -> Any:
                return scanreg.prepare(
                    c, normals=m == "point_to_plane", covariances=m == "gicp", num_neighbors=K
                )

            ours_p, prepared = median_time(prep, reps_n)
            ours_t, res = median_time(
                lambda s=source, p=prepared, m=method: ours_register(s, p, m), reps_n
            )
            ours_t -= res.timing.source_preparation
            row = f"| {n} | {method} | {ours_p * 1e3:.0f} |"
            ours_reg = f"{ours_t * 1e3:.0f} ({res.iterations})"
            tail = f" {(ours_p + ours_t) * 1e6 / n:.2f} |"
            if sg is not None:

                def sg_prep(c: np.ndarray = cloud, m: str = method) -> Any:
                    pc = sg.PointCloud(c)
                    tree = sg.KdTree(pc, threads)
                    if m == "point_to_plane":
                        sg.estimate_normals(pc, tree, K, threads)
                    else:
                        sg.estimate_covariances(pc, tree, K, threads)
                    return pc, tree

                their_p, (t_pc, tree) = median_time(sg_prep, reps_n)
                s_pc = sg.PointCloud(source)
                sg.estimate_normals_covariances(s_pc, sg.KdTree(s_pc, threads), K, threads)

                def theirs(
                    t_pc: Any = t_pc, s_pc: Any = s_pc, tree: Any = tree, m: str = method
                ) -> Any:
                    return sg.align(
                        t_pc,
                        s_pc,
                        tree,
                        registration_type=SMALL_GICP[m],
                        max_correspondence_distance=GATE,
                        num_threads=threads,
                        max_iterations=MAX_ITERATIONS,
                        rotation_epsilon=ROTATION_EPS,
                        translation_epsilon=TRANSLATION_EPS,
                    )

                their_t, their_res = median_time(theirs, reps_n)
                row += f" {their_p * 1e3:.0f} | {ours_p / their_p:.2f} |"
                row += f" {ours_reg} | {their_t * 1e3:.0f} ({their_res.iterations + 1}) |"
                row += f" {ours_t / their_t:.2f} |"
            else:
                row += f" - | - | {ours_reg} | - | - |"
            print(row + tail, flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--peers-site", default=None, help="site-packages holding small_gicp/open3d")
    ap.add_argument("--repeat", type=int, default=11)
    ap.add_argument("--scaling", action="store_true", help="also time N = 10k, 100k, 1M")
    ap.add_argument("--median", action="store_true", help="report medians instead of minima")
    ap.add_argument(
        "--cpu-time",
        action="store_true",
        help="time with process CPU time (use with RAYON_NUM_THREADS=1: load-independent)",
    )
    ap.add_argument(
        "--interleave", type=int, default=0, help="also N interleaved end-to-end rounds"
    )
    ap.add_argument("--memory", action="store_true", help="also peak RSS per library (subprocess)")
    ap.add_argument(
        "--memory-child", nargs=3, metavar=("LIB", "PAIR", "METHOD"), help=argparse.SUPPRESS
    )
    ap.add_argument("--skip-table", action="store_true", help="only --memory / --scaling")
    args = ap.parse_args()
    if args.memory_child:
        lib, pair, method = args.memory_child
        memory_child(lib, pair, method, args.peers_site)
        return
    global BEST_OF, CLOCK
    BEST_OF = not args.median
    if args.cpu_time:
        CLOCK = time.process_time
    threads = int(os.environ["RAYON_NUM_THREADS"])
    peers = load_peers(args.peers_site)
    if "open3d" in peers:
        peers["open3d"].utility.set_verbosity_level(peers["open3d"].utility.VerbosityLevel.Error)
    print(
        f"voxel {VOXEL} m, k = {K}, gate {GATE} m, <= {MAX_ITERATIONS} iterations, "
        f"{threads} threads, {'median' if args.median else 'best'} of {args.repeat}"
        f"{' (process CPU time)' if args.cpu_time else ' (wall clock)'}; "
        f"peers: {', '.join(peers) or 'none'}"
    )
    rows = []
    for pair, (src, tgt, ref) in ({} if args.skip_table else load_pairs()).items():
        for method in OURS:
            ours = run_ours(src, tgt, method, args.repeat)
            theirs: dict[str, dict[str, Any]] = {}
            if "small_gicp" in peers:
                theirs["small_gicp"] = run_small_gicp(
                    peers["small_gicp"], src, tgt, method, threads, args.repeat
                )
            if "open3d" in peers:
                theirs["open3d"] = run_open3d(peers["open3d"], src, tgt, method, args.repeat)
            # Accuracy: vs the reference where there is one, else vs small_gicp.
            anchor = ref if ref is not None else theirs.get("small_gicp", {}).get("pose")
            anchor_name = "ref" if ref is not None else "small_gicp"

            def acc(r: dict[str, Any], anchor: Any = anchor) -> str:
                if anchor is None:
                    return "-"
                dt, dr = error(r["pose"], anchor)
                return f"{dt * 100:.1f} cm / {dr:.2f}°"

            for stage in ("preprocess", "register", "end-to-end"):
                row = [pair, method, stage, f"{ours[stage] * 1e3:.1f}"]
                for name in ("small_gicp", "open3d"):
                    if name in theirs:
                        t = theirs[name][stage]
                        row += [f"{t * 1e3:.1f}", f"{ours[stage] / t:.2f}"]
                    else:
                        row += ["-", "-"]
                if stage == "end-to-end":
                    row += [
                        f"vs {anchor_name}: ours {acc(ours)}"
                        + "".join(f", {n} {acc(r)}" for n, r in theirs.items() if n != anchor_name)
                        + f" (it: ours {ours['iterations']}"
                        + "".join(
                            f", {n} {r['iterations']}"
                            for n, r in theirs.items()
                            if r["iterations"] >= 0
                        )
                        + ")"
                    ]
                else:
                    row += [""]
                rows.append(row)
    header = [
        "pair",
        "method",
        "stage",
        "scanreg ms",
        "small_gicp ms",
        "ratio",
        "open3d ms",
        "ratio",
        "accuracy",
    ]
    widths = [max(len(str(r[i])) for r in [header, *rows]) for i in range(len(header))]

    def line(r: list[str]) -> str:
        return "| " + " | ".join(str(c).ljust(w) for c, w in zip(r, widths, strict=True)) + " |"

    print(line(header))
    print("|" + "|".join("-" * (w + 2) for w in widths) + "|")
    for r in rows:
        print(line(r))
    if args.interleave:
        interleaved(peers, threads, args.interleave)
    if args.memory:
        memory_table(list(peers), args.peers_site)
    if args.scaling:
        scaling(peers, threads, max(3, args.repeat // 3))


if __name__ == "__main__":
    main()
