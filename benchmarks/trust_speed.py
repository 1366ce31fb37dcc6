"""Speed of a full result — pose, covariance, degeneracy, verdict — against small_gicp's bare
registration, and the scans per second of ``Odometry2D``.

Run (peers imported in the same process; small_gicp is optional, its columns are then empty):

    .venv/bin/python benchmarks/trust_speed.py --peers-site $PEERS [--rounds 11] \
        [--sections 2d 3d odometry]

Sections:
* ``2d``: the Intel pairs of ``scan2d_speed.py`` (consecutive scans k-1 -> k for every 4th k,
  points at 0.1–40 m, the wheel-odometry guess), one thread, CPU time, gate 0.3 m, k = 10,
  ≤ 30 iterations, 1e-4 m / rad. small_gicp: its bare point-to-point ``ICP`` (z = 0 padding,
  its k-d tree built per pair). scanreg: ``prepare`` + ``register(method="point_to_line")``
  reading the pose only; then the full result (``covariance``, ``degeneracy``, ``verdict``)
  without the wrong-basin probe (``VerdictThresholds(basin_probe=False)``) and with it (the
  2D default).
* ``3d``: KITTI 00 frames 1 -> 0, raw float64 arrays in, identity guess: small_gicp's one-call
  ``align(target, source, registration_type="GICP")`` (voxel 0.25 m, its 10 neighbours, gate
  1 m, ≤ 20 iterations) against ``register(source, target, method="gicp", voxel_size=0.25,
  num_neighbors=10, ...)`` whose trust analysis runs inside the call (a raw-array target),
  the covariance and verdict read. Wall clock, ``--threads`` (2) each; ``--threads 1 --cpu``:
  one thread and CPU time (on a loaded machine small_gicp's OpenMP threads spin-wait).
* ``odometry``: ``Odometry2D`` (default configuration) over the 902 Intel scans with the
  wheel-odometry prior: scans per CPU second, against the same odometry with its map rebuilt
  from scratch on every keyframe (``RebuiltMapOdometry``: the same poses to the bit).

Each round runs every contender once on the whole set, in an order rotated per round; the
table gives each one's median ms per pair and the median over rounds of the per-round ratio
to small_gicp (< 1: scanreg faster).
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import sys
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
import scanreg
from scanreg.io import read_carmen
from scanreg.pipeline import Odometry2D
from scanreg.preprocess import voxel_downsample

DATA = Path(os.environ.get("SCANREG_DATA", Path(__file__).resolve().parents[2] / "shared/data"))
NO_PROBE = scanreg.VerdictThresholds(basin_probe=False)
PROBE = scanreg.VerdictThresholds()


def intel() -> Any:
    return read_carmen(DATA / "carmen-intel" / "intel_gfs_subset_clf_timestamps.clf")


def intel_pairs(log: Any) -> list[tuple[np.ndarray, np.ndarray, Any]]:
    pts = [s.to_points(0.1, 40.0) for s in log.scans]
    return [
        (pts[k], pts[k - 1], log.motion_prior(k - 1, k))
        for k in range(4, len(pts), 4)
        if min(len(pts[k]), len(pts[k - 1])) >= 50
    ]


def pad(points: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(np.c_[points, np.zeros(len(points))])


def mat4(pose: Any) -> np.ndarray:
    m = np.eye(4)
    m[:2, :2] = pose.rotation
    m[:2, 3] = pose.translation
    return m


def ours2d(pairs: list[Any], read: bool, thresholds: Any) -> None:
    for src, tgt, init in pairs:
        target = scanreg.prepare(tgt, normals=True, num_neighbors=10)
        res = scanreg.register(
            src,
            target,
            method="point_to_line",
            init=init,
            max_correspondence_distance=0.3,
            max_iterations=30,
            translation_tolerance=1e-4,
            rotation_tolerance=1e-4,
            num_threads=1,
            num_neighbors=10,
            thresholds=thresholds,
        )
        if read:
            assert res.covariance.shape == (3, 3)
            assert res.degeneracy is not None and res.verdict is not None


def small_gicp_icp(sg: Any, padded: list[Any]) -> None:
    for src, tgt, init in padded:
        t = sg.PointCloud(tgt)
        tree = sg.KdTree(t, 1)
        sg.align(
            t,
            sg.PointCloud(src),
            tree,
            init_T_target_source=init,
            registration_type="ICP",
            max_correspondence_distance=0.3,
            num_threads=1,
            max_iterations=30,
            rotation_epsilon=1e-4,
            translation_epsilon=1e-4,
        )


def rounds(
    fns: dict[str, Callable[[], Any]], n: int, count: int, clock: Callable[[], float]
) -> dict[str, list[float]]:
    """ms per item of each contender per round, the order rotated each round."""
    names = list(fns)
    for fn in fns.values():
        fn()  # warm-up
    times: dict[str, list[float]] = {name: [] for name in names}
    for r in range(count):
        turn = r % len(names)
        for name in names[turn:] + names[:turn]:
            t0 = clock()
            fns[name]()
            times[name].append((clock() - t0) / n * 1e3)
    return times


def table(title: str, times: dict[str, list[float]], peer: str | None) -> None:
    print(f"\n{title}\n")
    print(f"| contender | median ms | ratio to {peer or 'peer'} (median of rounds) |")
    print("|---|---:|---:|")
    for name, ts in times.items():
        if name == peer:
            ratio = "1"
        elif peer is not None:
            ratio = f"{statistics.median(a / b for a, b in zip(ts, times[peer], strict=True)):.2f}"
        else:
            ratio = "–"
        print(f"| {name} | {statistics.median(ts):.3f} | {ratio} |", flush=True)


def section_2d(sg: Any, count: int) -> None:
    pairs = intel_pairs(intel())
    padded = [(pad(s), pad(t), mat4(i)) for s, t, i in pairs]
    fns: dict[str, Callable[[], Any]] = {}
    if sg is not None:
        fns["small_gicp ICP (bare)"] = lambda: small_gicp_icp(sg, padded)
    fns["scanreg pose"] = lambda: ours2d(pairs, False, PROBE)
    fns["scanreg full, no probe"] = lambda: ours2d(pairs, True, NO_PROBE)
    fns["scanreg full, with probe"] = lambda: ours2d(pairs, True, PROBE)
    times = rounds(fns, len(pairs), count, time.process_time)
    peer = "small_gicp ICP (bare)" if sg is not None else None
    table(f"2D: {len(pairs)} Intel pairs, CPU ms per pair, {count} rounds", times, peer)


def kitti(i: int) -> np.ndarray:
    path = DATA / f"kitti-odometry-00-frames-000-015/velodyne/{i:06d}.bin"
    raw = np.fromfile(path, dtype=np.float32).reshape(-1, 4)
    return np.ascontiguousarray(raw[:, :3], dtype=np.float64)


def section_3d(sg: Any, count: int, threads: int, cpu: bool) -> None:
    src, tgt = kitti(1), kitti(0)

    def ours(probe: bool = True) -> None:
        res = scanreg.register(
            src,
            tgt,
            thresholds=PROBE if probe else NO_PROBE,
            method="gicp",
            voxel_size=0.25,
            num_neighbors=10,
            max_correspondence_distance=1.0,
            max_iterations=20,
            translation_tolerance=1e-3,
            rotation_tolerance=math.radians(0.1),
            num_threads=threads,
        )
        assert res.covariance.shape == (6, 6) and res.verdict is not None

    fns: dict[str, Callable[[], Any]] = {}
    if sg is not None:
        fns["small_gicp align GICP"] = lambda: sg.align(
            tgt,
            src,
            registration_type="GICP",
            downsampling_resolution=0.25,
            max_correspondence_distance=1.0,
            num_threads=threads,
            max_iterations=20,
        )
    fns["scanreg register gicp + trust"] = ours
    # The wrong-basin probe restarts the solve only when its screen doubts the result; here it
    # does not (in 3D the motion from the start counts only against a stated init_covariance),
    # so the difference between the two rows is the screen itself.
    fns["scanreg register gicp + trust, no basin probe"] = lambda: ours(probe=False)
    times = rounds(fns, 1, count, time.process_time if cpu else time.perf_counter)
    peer = "small_gicp align GICP" if sg is not None else None
    clock = "CPU" if cpu else "wall"
    table(
        f"3D: KITTI 01->00 end to end, {clock} ms, {threads} thread(s), {count} rounds", times, peer
    )


class RebuiltMapOdometry(Odometry2D):
    """``Odometry2D`` with its map rebuilt from scratch on every keyframe (voxel-downsampling
    the window's keyframes, then ``prepare``): what the keyframe map replaced. Same poses to
    the bit (``tests/test_odometry2d.py``), so the ratio is the map update's saving alone."""

    def __init__(self) -> None:
        super().__init__()
        self._window: deque[np.ndarray] = deque(maxlen=self.config.max_keyframes)

    def _add_keyframe(self, points: np.ndarray, pose: Any) -> None:
        self._window.append(pose.apply(points))
        pts = voxel_downsample(np.concatenate(list(self._window)), self.config.map_voxel_size)
        self._target = scanreg.prepare(np.ascontiguousarray(pts.points), normals=True)
        self._map_points = self._target.points
        self._last_keyframe = pose
        self._grid = None


def section_odometry(count: int) -> None:
    log = intel()
    points = [s.to_points(0.1, 40.0) for s in log.scans]

    def runner(make: Callable[[], Odometry2D]) -> Callable[[], None]:
        def run() -> None:
            odo = make()
            for k, p in enumerate(points):
                odo.step(p, prior=None if k == 0 else log.motion_prior(k - 1, k))

        return run

    fns = {"Odometry2D": runner(Odometry2D), "map rebuilt per keyframe": runner(RebuiltMapOdometry)}
    times = rounds(fns, len(points), count, time.process_time)
    print(f"\nOdometry2D, {len(points)} Intel scans, {count} rounds, CPU time\n")
    print("| contender | scans per CPU s | ratio to the rebuilt map (median of rounds) |")
    print("|---|---:|---:|")
    base = times["map rebuilt per keyframe"]
    for name, ts in times.items():
        ratio = statistics.median(b / a for a, b in zip(ts, base, strict=True))
        print(f"| {name} | {1e3 / statistics.median(ts):.0f} | {ratio:.2f} |")


def import_small_gicp(site: str | None) -> Any:
    """small_gicp from ``site`` (a peers venv's site-packages) or this environment; None when
    it is not installed (its columns are then empty)."""
    if site:
        sys.path.append(site)
    try:
        import small_gicp
    except ImportError:
        return None
    return small_gicp


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--peers-site", default=None, help="site-packages holding small_gicp")
    ap.add_argument("--rounds", type=int, default=11)
    ap.add_argument("--threads", type=int, default=2, help="3D: threads of each library")
    ap.add_argument(
        "--cpu",
        action="store_true",
        help="3D: process CPU time instead of wall clock (OpenMP peers spin-wait on a loaded "
        "machine; with --threads 1 the fairer clock there)",
    )
    ap.add_argument(
        "--sections", nargs="+", choices=["2d", "3d", "odometry"], default=["2d", "3d", "odometry"]
    )
    args = ap.parse_args()
    sg = import_small_gicp(args.peers_site)
    if "2d" in args.sections:
        section_2d(sg, args.rounds)
    if "3d" in args.sections:
        section_3d(sg, args.rounds, args.threads, args.cpu)
    if "odometry" in args.sections:
        section_odometry(max(2, args.rounds // 2))


if __name__ == "__main__":
    main()
