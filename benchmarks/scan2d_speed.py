"""2D scan-to-scan speed and accuracy: scanreg (SE(2)) against small_gicp with z = 0 padding.

Run (one thread for everyone — a 2D scan has a few hundred points; peers imported in the same
process, optional):

    .venv/bin/python benchmarks/scan2d_speed.py \
        [--peers-site /tmp/peers-venv/lib/python3.11/site-packages] [--repeat 7] [--median]

Pairs:
* Intel subset (carmen-intel): consecutive scans k-1 -> k for every 4th k, points at
  0.1–40 m, initial guess the wheel-odometry motion; reference: scan-to-scan correlative
  (branch and bound) + point-to-line, the chain that scores 0.027 m on the local relations;
* simulated: a SICK LMS200 in ``floor_plan(seed=3)`` driving a curve, exact truth, initial
  guess the truth perturbed by (0.05 m, -0.05 m, 2°).
Each library gets raw (N, 2) arrays (small_gicp and Open3D, if importable: (N, 3) with z = 0)
and returns a pose:
building the target index, its normals (point-to-line / PLANE_ICP) or both clouds'
covariances (GICP), then the alignment — end-to-end per pair; no downsampling. Shared settings:
gate 0.3 m, k = 10, at most 30 iterations, convergence at 1e-4 m / 1e-4 rad, no robust
kernel, identical initial guesses. Time: the whole set of pairs, best of --repeat runs after a
warm-up (--median for medians; --cpu: process CPU time instead of wall clock). Ratio = our
time / theirs (< 1: scanreg faster). Accuracy: median and 95th percentile translation error
(mm) against the reference / the truth.
``--interleave N``: instead, N rounds in which every library runs the whole set once, in an
order rotated each round; reports each library's median ms/pair and the median over rounds of
the per-round ratio (each from runs seconds apart: the statistic a loaded, shared machine moves
least). ``--per-pair`` with it: within a round the libraries alternate pair by pair (order
rotated per pair), each library's time summed over the set; the ratio's spread across rounds
falls from about ±0.13 to ±0.03 (every library then also starts each pair with caches the
others have used, as in a program that does more than registration between scans). Each
peer is then timed in its own rounds against scanreg: Open3D's worker threads outlive its
calls, and pair by pair would be charged to whichever library runs next.
``--trust`` adds the time with the covariance and verdict read (``register`` analyses lazily:
the plain column reads the pose only).
Also: scans per second of ``scanreg.pipeline.Odometry2D`` on the 902 Intel scans. ``--floor``
adds, after each row, the time of ``prepare`` + the core ICP loop alone (``_core.register_icp``,
no covariance, degeneracy or verdict): what the single call could reach with no fixed cost.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")  # Open3D's OpenMP: one thread, like everyone
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # numpy's BLAS thread server showed in profiles

import numpy as np
import scanreg
from scanreg import SE2, _core
from scanreg import simulate as sim
from scanreg.io import read_carmen
from scanreg.pipeline import Odometry2D, OdometryConfig2D

DATA = Path(os.environ.get("SCANREG_DATA", Path(__file__).resolve().parents[2] / "shared/data"))
GATE = 0.3
K = 10
MAX_ITERATIONS = 30
EPS = 1e-4
OURS = {"point_to_line": "point_to_line", "point_to_point": "point_to_point", "gicp": "gicp"}
#: The methods timed (``--methods``).
METHODS = list(OURS)
THEIRS = {"point_to_line": "PLANE_ICP", "point_to_point": "ICP", "gicp": "GICP"}

Pair = tuple[np.ndarray, np.ndarray, SE2, SE2]  # source, target, init, reference


#: What ``timed`` reads: wall clock, or with ``--cpu`` this process's CPU time (all its
#: threads), which a machine shared with other jobs inflates far less.
CLOCK: Callable[[], float] = time.perf_counter


def timed(fn: Callable[[], Any], repeat: int, best: bool) -> tuple[float, Any]:
    out = fn()
    times = []
    for _ in range(repeat):
        t0 = CLOCK()
        out = fn()
        times.append(CLOCK() - t0)
    return (min(times) if best else statistics.median(times)), out


def intel_pairs(log: Any) -> list[Pair]:
    pts = [s.to_points(0.1, 40.0) for s in log.scans]
    pairs = []
    for k in range(4, len(pts), 4):
        if min(len(pts[k]), len(pts[k - 1])) < 50:  # a handful of returns: nothing to compare
            continue
        init = log.motion_prior(k - 1, k)
        c = scanreg.match_correlative(
            pts[k],
            pts[k - 1],
            init=init,
            window=(0.3, 0.3, math.radians(10)),
            resolution=0.05,
            search="branch_and_bound",
        )
        r = scanreg.register(
            pts[k],
            pts[k - 1],
            method="point_to_line",
            init=c.pose,
            max_correspondence_distance=0.15,
            kernel="huber",
        )
        ref = r.pose if r.converged else c.pose
        assert isinstance(ref, SE2)
        pairs.append((pts[k], pts[k - 1], init, ref))
    return pairs


def simulated_pairs() -> list[Pair]:
    scene = sim.floor_plan(seed=3, num_people=0)
    start = SE2.from_vector([2.0, 0.0, 0.0])
    traj = sim.Trajectory.from_speed_and_yaw_rate(
        0.8, 0.0, duration=16.0, start=start, yaw_rate_amplitude=0.1
    )
    run = sim.simulate_run(
        scene, sim.LaserModel.preset("sick_lms200"), traj, num_scans=80, scan_rate=5.0, seed=5
    )
    pairs = []
    kick = SE2.from_vector([0.05, -0.05, math.radians(2.0)])
    for k in range(1, len(run.scans)):
        truth = run.poses[k - 1].inverse() @ run.poses[k]
        assert isinstance(truth, SE2)
        src = np.ascontiguousarray(run.scans[k].points)
        tgt = np.ascontiguousarray(run.scans[k - 1].points)
        if min(len(src), len(tgt)) < 50:
            continue
        init = truth @ kick
        assert isinstance(init, SE2)
        pairs.append((src, tgt, init, truth))
    return pairs


def ours(pairs: list[Pair], method: str, trust: bool = False) -> list[SE2]:
    """``trust``: also read the covariance and the verdict, i.e. pay for the lazy analysis."""
    out = []
    for src, tgt, init, _ in pairs:
        target = scanreg.prepare(
            tgt, normals=method == "point_to_line", covariances=method == "gicp", num_neighbors=K
        )
        res = scanreg.register(
            src,
            target,
            method=OURS[method],
            init=init,
            max_correspondence_distance=GATE,
            max_iterations=MAX_ITERATIONS,
            translation_tolerance=EPS,
            rotation_tolerance=EPS,
            num_threads=1,
            num_neighbors=K,
        )
        if trust:
            assert res.verdict is not None and res.covariance.shape == (3, 3)
        out.append(res.pose)
    return out


def core_only(pairs: list[Pair], method: str) -> list[np.ndarray]:
    """The floor of ``ours``: the same prepared target and core ICP loop, none of the analysis
    ``register`` adds (covariances, degeneracy, conditioning, verdict) nor its validation."""
    out = []
    for src, tgt, init, _ in pairs:
        target = scanreg.prepare(
            tgt, normals=method == "point_to_line", covariances=method == "gicp", num_neighbors=K
        )
        source_covs = None
        if method == "gicp":
            _, source_covs, _, _ = _core.KdTree(src).local_geometry(
                K, np.zeros(2), normals=False, regularization="plane", epsilon=1e-3
            )
        res = _core.register_icp(
            src,
            target.index,
            init.as_matrix(),
            method=OURS[method],
            kernel="none",
            kernel_scale=1.0,
            max_correspondence_distance=GATE,
            max_iterations=MAX_ITERATIONS,
            translation_tolerance=EPS,
            rotation_tolerance=EPS,
            optimizer="gauss_newton",
            min_correspondences=2 if method != "point_to_line" else 4,
            num_threads=1,
            source_covariances=source_covs,
            target_normals=target.normals,
            target_covariances=target.covariances,
        )
        out.append(res.pose)
    return out


def pad(points: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(np.c_[points, np.zeros(len(points))])


def mat4(pose: SE2) -> np.ndarray:
    m = np.eye(4)
    m[:2, :2] = pose.rotation
    m[:2, 3] = pose.translation
    return m


def theirs(
    sg: Any, pairs: list[tuple[np.ndarray, np.ndarray, np.ndarray]], method: str
) -> list[SE2]:
    out = []
    for src, tgt, init in pairs:
        t = sg.PointCloud(tgt)
        tree = sg.KdTree(t, 1)
        s = sg.PointCloud(src)
        if method == "point_to_line":
            sg.estimate_normals(t, tree, K, 1)
        elif method == "gicp":
            sg.estimate_covariances(t, tree, K, 1)
            sg.estimate_covariances(s, sg.KdTree(s, 1), K, 1)
        res = sg.align(
            t,
            s,
            tree,
            init_T_target_source=init,
            registration_type=THEIRS[method],
            max_correspondence_distance=GATE,
            num_threads=1,
            max_iterations=MAX_ITERATIONS,
            rotation_epsilon=EPS,
            translation_epsilon=EPS,
        )
        m = np.asarray(res.T_target_source)
        out.append(SE2.from_vector([m[0, 3], m[1, 3], math.atan2(m[1, 0], m[0, 0])]))
    return out


def theirs_open3d(
    o3d: Any, pairs: list[tuple[np.ndarray, np.ndarray, np.ndarray]], method: str
) -> list[SE2]:
    """Open3D on the same padded scans: point-to-point, point-to-plane (normals from k-NN, as
    small_gicp's: in the z = 0 plane they are vertical) or GICP, its default relative
    convergence criteria and the same iteration cap."""
    reg = o3d.pipelines.registration
    knn = o3d.geometry.KDTreeSearchParamKNN(K)
    criteria = reg.ICPConvergenceCriteria(max_iteration=MAX_ITERATIONS)
    out = []
    for src, tgt, init in pairs:
        t = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(tgt))
        s = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(src))
        if method == "point_to_line":
            t.estimate_normals(knn)
            res = reg.registration_icp(
                s, t, GATE, init, reg.TransformationEstimationPointToPlane(), criteria
            )
        elif method == "gicp":
            t.estimate_covariances(knn)
            s.estimate_covariances(knn)
            res = reg.registration_generalized_icp(
                s, t, GATE, init, reg.TransformationEstimationForGeneralizedICP(), criteria
            )
        else:
            res = reg.registration_icp(
                s, t, GATE, init, reg.TransformationEstimationPointToPoint(), criteria
            )
        m = np.asarray(res.transformation)
        if not np.isfinite(m).all():
            # In the z = 0 plane its point-to-plane system is singular (vertical normals): it
            # returns NaN. Scored as the initial guess, and counted.
            OPEN3D_NON_FINITE[method] = OPEN3D_NON_FINITE.get(method, 0) + 1
            m = init
        out.append(SE2.from_vector([m[0, 3], m[1, 3], math.atan2(m[1, 0], m[0, 0])]))
    return out


#: Open3D results that were NaN, per method (all timed runs of every set).
OPEN3D_NON_FINITE: dict[str, int] = {}


def errors_mm(poses: list[SE2], pairs: list[Pair]) -> tuple[float, float]:
    e = [
        1e3 * float(np.linalg.norm((ref.inverse() @ p).translation))
        for p, (_, _, _, ref) in zip(poses, pairs, strict=True)
    ]
    return float(np.median(e)), float(np.percentile(e, 95))


def _median_cell(times: dict[str, list[float]], lib: str) -> str:
    return f"{statistics.median(times[lib]):.3f}" if lib in times else "–"


def _ratio_cell(times: dict[str, list[float]], lib: str) -> str:
    """Median over rounds of our time / theirs in the same round (our times from the rounds
    run against ``lib`` when each peer had its own)."""
    if lib not in times:
        return "–"
    mine = times.get(f"scanreg/{lib}", times["scanreg"])
    per_round = [a / b for a, b in zip(mine, times[lib], strict=True)]
    return f"{statistics.median(per_round):.2f}"


def _rounds(
    fns: dict[str, Callable[[int, int], Any]], n: int, rounds: int, per_pair: bool, libs: list[str]
) -> dict[str, list[float]]:
    """ms/pair of each of ``libs`` per round; the order rotated each round (and each pair)."""
    times: dict[str, list[float]] = {lib: [] for lib in libs}
    blocks = [(k, k + 1) for k in range(n)] if per_pair else [(0, n)]
    for r in range(rounds):
        spent = dict.fromkeys(libs, 0.0)
        for b, (lo, hi) in enumerate(blocks):
            turn = (r + b) % len(libs)
            for lib in libs[turn:] + libs[:turn]:
                t0 = CLOCK()
                fns[lib](lo, hi)
                spent[lib] += CLOCK() - t0
        for lib in libs:
            times[lib].append(spent[lib] / n * 1e3)
    return times


def interleaved(
    sets: dict[str, list[Pair]], sg: Any, o3d: Any, rounds: int, per_pair: bool = False
) -> None:
    """Every library once per round on the whole set, the order rotated each round (or, with
    ``per_pair``, pair by pair, the order rotated each pair)."""
    print(
        f"interleaved {'pair by pair' if per_pair else 'set by set'}, {rounds} rounds "
        f"({'CPU time' if CLOCK is time.process_time else 'wall'})"
    )
    print(
        "| pairs | method | scanreg ms/pair | small_gicp ms/pair | open3d ms/pair | "
        "scanreg / small_gicp | scanreg / open3d | err mm (median) ours / sg / o3d |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for name, pairs in sets.items():
        padded = [(pad(s), pad(t), mat4(i)) for s, t, i, _ in pairs]
        for method in METHODS:
            # Each runs pairs[lo:hi] of the set.
            fns: dict[str, Callable[[int, int], list[SE2]]] = {
                "scanreg": lambda lo, hi, m=method, p=pairs: ours(p[lo:hi], m)
            }
            if sg is not None:
                fns["small_gicp"] = lambda lo, hi, m=method, p=padded: theirs(sg, p[lo:hi], m)
            if o3d is not None:
                fns["open3d"] = lambda lo, hi, m=method, p=padded: theirs_open3d(o3d, p[lo:hi], m)
            n = len(pairs)
            # Also the warm-up.
            errs = {lib: errors_mm(fns[lib](0, n), pairs)[0] for lib in fns}

            peers = [lib for lib in fns if lib != "scanreg"]
            if per_pair:
                # One peer at a time: Open3D's worker threads outlive its calls and, pair by
                # pair, would be charged to (and compete with) whichever library runs next.
                times: dict[str, list[float]] = {}
                for i, peer in enumerate(peers):
                    got = _rounds(fns, n, rounds, per_pair, ["scanreg", peer])
                    times[peer] = got[peer]
                    times[f"scanreg/{peer}"] = got["scanreg"]
                    if i == 0:
                        times["scanreg"] = got["scanreg"]
                if not peers:
                    times = _rounds(fns, n, rounds, per_pair, ["scanreg"])
            else:
                times = _rounds(fns, n, rounds, per_pair, list(fns))
            OPEN3D_NON_FINITE.pop(method, None)

            err = " / ".join(
                f"{errs[lib]:.1f}" if lib in errs else "–"
                for lib in ("scanreg", "small_gicp", "open3d")
            )
            print(
                f"| {name} | {method} | {_median_cell(times, 'scanreg')} | "
                f"{_median_cell(times, 'small_gicp')} | {_median_cell(times, 'open3d')} | "
                f"{_ratio_cell(times, 'small_gicp')} | {_ratio_cell(times, 'open3d')} | {err} |",
                flush=True,
            )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--peers-site", default=None, help="site-packages holding small_gicp")
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--median", action="store_true", help="median instead of best of N")
    ap.add_argument(
        "--floor",
        action="store_true",
        help="also time prepare + the core ICP loop alone (no analysis): the single call's floor",
    )
    ap.add_argument(
        "--trust",
        action="store_true",
        help="also time the call with its covariance and verdict read (the lazy analysis run)",
    )
    ap.add_argument(
        "--cpu", action="store_true", help="time with process CPU time instead of wall clock"
    )
    ap.add_argument(
        "--interleave", type=int, default=0, help="N interleaved rounds instead of the table"
    )
    ap.add_argument(
        "--per-pair",
        action="store_true",
        help="with --interleave: alternate the libraries pair by pair within each round",
    )
    ap.add_argument(
        "--methods", nargs="+", choices=list(OURS), default=list(OURS), help="methods to time"
    )
    args = ap.parse_args()
    METHODS[:] = args.methods
    global CLOCK
    if args.cpu:
        CLOCK = time.process_time
    sg = None
    if args.peers_site:
        sys.path.append(args.peers_site)
    with contextlib.suppress(ImportError):
        import small_gicp as sg
    o3d = None
    with contextlib.suppress(ImportError, OSError):
        import open3d as o3d

        o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    log = read_carmen(DATA / "carmen-intel" / "intel_gfs_subset_clf_timestamps.clf")
    sets = {"intel": intel_pairs(log), "simulated": simulated_pairs()}
    print(
        f"load average: {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f}; "
        f"{'median' if args.median else 'best'} of {args.repeat}, "
        f"{'CPU time' if args.cpu else 'wall clock'}; small_gicp: {sg is not None}; "
        f"open3d: {o3d is not None}"
    )
    if args.interleave:
        interleaved(sets, sg, o3d, args.interleave, per_pair=args.per_pair)
        return
    print(
        "| pairs | n | method | scanreg ms/pair | small_gicp ms/pair | ratio | "
        "scanreg err mm (median / p95) | small_gicp err mm |"
    )
    print("|---|---|---|---|---|---|---|---|")
    best = not args.median
    for name, pairs in sets.items():
        padded = [(pad(s), pad(t), mat4(i)) for s, t, i, _ in pairs]
        for method in METHODS:
            t_ours, p_ours = timed(lambda m=method, p=pairs: ours(p, m), args.repeat, best)
            e_ours = errors_mm(p_ours, pairs)
            row = f"| {name} | {len(pairs)} | {method} | {t_ours / len(pairs) * 1e3:.3f} | "

            def peer(run: Callable[[], list[SE2]], p: list[Pair] = pairs) -> tuple[float, Any]:
                t, poses = timed(run, args.repeat, best)
                return t, errors_mm(poses, p)

            if sg is not None:
                t_them, e_them = peer(lambda m=method, p=padded: theirs(sg, p, m))
                row += (
                    f"{t_them / len(pairs) * 1e3:.3f} | {t_ours / t_them:.2f} | "
                    f"{e_ours[0]:.1f} / {e_ours[1]:.1f} | {e_them[0]:.1f} / {e_them[1]:.1f} |"
                )
            else:
                row += f"– | – | {e_ours[0]:.1f} / {e_ours[1]:.1f} | – |"
            if o3d is not None:
                t_o3d, e_o3d = peer(lambda m=method, p=padded: theirs_open3d(o3d, p, m))
                row += (
                    f" open3d {t_o3d / len(pairs) * 1e3:.3f} ms/pair (ratio {t_ours / t_o3d:.2f}),"
                    f" err {e_o3d[0]:.1f} / {e_o3d[1]:.1f} mm"
                )
                bad = OPEN3D_NON_FINITE.pop(method, 0)
                if bad:
                    row += f" ({bad} NaN poses over {args.repeat + 1} runs)"

            if args.trust:
                t_trust, _ = timed(
                    lambda m=method, p=pairs: ours(p, m, trust=True), args.repeat, best
                )
                row += f" +trust {t_trust / len(pairs) * 1e3:.3f} ms/pair"
                if sg is not None:
                    row += f" (ratio {t_trust / t_them:.2f})"
            if args.floor:
                t_core, _ = timed(lambda m=method, p=pairs: core_only(p, m), args.repeat, best)
                row += f" floor {t_core / len(pairs) * 1e3:.3f} ms/pair"
                if sg is not None:
                    row += f" (ratio {t_core / t_them:.2f})"
            print(row, flush=True)
    points = [s.to_points(0.1, 40.0) for s in log.scans]
    for front_end in ("icp", "correlative"):
        odo = Odometry2D(OdometryConfig2D(front_end=front_end))  # type: ignore[arg-type]
        t0 = time.perf_counter()
        for k, p in enumerate(points):
            odo.step(p, prior=None if k == 0 else log.motion_prior(k - 1, k))
        dt = time.perf_counter() - t0
        print(
            f"Odometry2D ({front_end} front end), {len(points)} Intel scans: "
            f"{len(points) / dt:.0f} scans/s"
        )


if __name__ == "__main__":
    main()
