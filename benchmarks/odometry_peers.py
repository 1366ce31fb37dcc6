"""LiDAR odometry side by side: scanreg, KISS-ICP and GenZ-ICP on the same sequences.

    python benchmarks/odometry_peers.py --peers-site /tmp/peers-venv/lib/python3.11/site-packages
        [--frames 100] [--sensor hdl64] [--threads 2] [--json out.json]

Sequences (every method gets the same arrays, saved once to a temporary .npz):

* ``kitti16`` — the 16 real KITTI 00 frames (``../shared/data``; no per-point time, already
  motion-compensated; its ground truth is doubtful, so there the peers' agreement is the check);
* ``sim-street`` / ``sim-tunnel`` — ``scanreg.io.SimulatedSequence`` drives with motion
  distortion and per-point time, exact truth at mid-sweep (the time every method here deskews
  to), starting from rest and reaching 10 m/s after 2 s (a standing start: every method begins
  with a zero-velocity prediction, as on a real vehicle). The tunnel reaches beyond the sensor
  range at both ends: degenerate along its axis.
  ``scanreg+prior`` also gets a wheel-odometry-like motion prior there (the true increments
  with 2 % scale error and noise, seeded), which KISS-ICP and GenZ-ICP cannot take.

Each method runs in its own subprocess (for its peak RSS, ``ru_maxrss``) with 2 threads.
Reported: ATE (SE(3)-aligned RMSE), end-point error, KITTI-style drift over short segments,
median per-frame time, frames per second, peak memory, and our ratios to KISS-ICP.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
DATA = Path(os.environ.get("SCANREG_DATA", HERE.parent.parent / "shared" / "data"))
METHODS = ("scanreg", "scanreg+prior", "scanreg-p2p", "kiss_icp", "genz_icp")


# ------------------------------------------------------------------ inputs


def _save_sequence(path: Path, frames: list[Any], gt: np.ndarray, min_range: float) -> None:
    arrays: dict[str, Any] = {"gt": gt, "min_range": np.array(min_range)}
    arrays["stamps"] = np.array([f.stamp for f in frames])
    for k, f in enumerate(frames):
        arrays[f"p{k}"] = np.ascontiguousarray(f.points)
        if f.timestamps is not None:
            arrays[f"t{k}"] = np.ascontiguousarray(f.timestamps)
    np.savez(path, **arrays)


def build_inputs(folder: Path, frames: int, sensor: str) -> dict[str, Path]:
    from scanreg.io import open_sequence
    from scanreg.io.sequences import SimulatedSequence

    out: dict[str, Path] = {}
    kitti = DATA / "kitti-odometry-00-frames-000-015"
    if kitti.exists():
        seq = open_sequence(str(kitti))
        assert seq.ground_truth is not None
        out["kitti16"] = folder / "kitti16.npz"
        _save_sequence(out["kitti16"], list(seq), np.asarray(seq.ground_truth), 3.0)
    else:
        print(f"# {kitti} not found: KITTI rows skipped", file=sys.stderr)
    for scene in ("street", "tunnel"):
        sim = SimulatedSequence(scene, num_frames=frames, sensor=sensor, ramp=2.0)
        out[f"sim-{scene}"] = folder / f"sim-{scene}.npz"
        _save_sequence(out[f"sim-{scene}"], list(sim), sim.ground_truth_at("middle"), 1.0)
    return out


class _Frames:
    """Frames read from the .npz one at a time, so a worker's peak memory is the method's
    (plus one frame), not the whole sequence's."""

    def __init__(self, path: Path) -> None:
        self.z = np.load(path)
        self.n = len(self.z["stamps"])
        self.has_time = "t0" in self.z.files

    def __len__(self) -> int:
        return self.n

    def points(self, k: int) -> np.ndarray:
        return self.z[f"p{k}"]

    def times(self, k: int) -> np.ndarray | None:
        return self.z[f"t{k}"] if self.has_time else None


def _ground_truth(path: Path) -> np.ndarray:
    return np.load(path)["gt"]


def wheel_prior(gt: np.ndarray, seed: int = 7) -> list[np.ndarray | None]:
    """True increments with a 2 % scale error, 2 cm / 0.1° noise per frame: a wheel odometry."""
    rng = np.random.default_rng(seed)
    from scanreg import SE3

    out: list[np.ndarray | None] = [None]
    for k in range(1, len(gt)):
        inc = SE3.from_matrix(np.linalg.inv(gt[k - 1]) @ gt[k]).log()
        inc[:3] = inc[:3] * 1.02 + rng.normal(0, 0.02, 3)
        inc[3:] += rng.normal(0, math.radians(0.1), 3)
        out.append(SE3.exp(inc).as_matrix())
    return out


# ------------------------------------------------------------------ workers


def _peak_rss_mb() -> float:
    """This process's resident-set high-water mark (VmHWM). Not ``ru_maxrss``: Linux keeps
    that across ``execve`` from the forking parent, which here holds every sequence."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return float(line.split()[1]) / 1024.0
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


Step = Any  # (k, points, times) -> 4x4 pose


def _stepper(method: str, frames: _Frames, threads: int) -> Step:
    """A fresh instance of ``method``, as a per-frame step function."""
    z, gt = frames.z, frames.z["gt"]
    min_range = float(z["min_range"])
    has_time = frames.has_time
    stamps = z["stamps"]
    if method.startswith("scanreg"):
        from scanreg import Odometry, OdometryConfig

        cfg = OdometryConfig(
            min_range=min_range,
            num_threads=threads,
            method="point_to_point" if method == "scanreg-p2p" else "gicp",
            kernel="geman_mcclure" if method == "scanreg-p2p" else "none",
        )
        odo = Odometry(cfg)
        priors = wheel_prior(gt) if method == "scanreg+prior" else [None] * len(frames)

        def step(k: int, p: np.ndarray, t: np.ndarray | None) -> np.ndarray:
            r = odo.step(p, t, priors[k], stamp=float(stamps[k]))
            out: np.ndarray = r.pose.as_matrix()
            return out

        return step
    if method == "kiss_icp":
        from kiss_icp.config import KISSConfig
        from kiss_icp.kiss_icp import KissICP

        kcfg = KISSConfig()
        kcfg.data.max_range, kcfg.data.min_range = 100.0, min_range
        kcfg.data.deskew = has_time
        kcfg.mapping.voxel_size = 1.0
        kcfg.registration.max_num_threads = threads
        kiss = KissICP(kcfg)

        def kiss_step(k: int, p: np.ndarray, t: np.ndarray | None) -> np.ndarray:
            kiss.register_frame(p, t if t is not None else np.array([]))
            return np.array(kiss.last_pose)

        return kiss_step
    if method == "genz_icp":
        from genz_icp.config.parser import load_config
        from genz_icp.genz_icp import GenZICP

        gcfg = load_config(None)
        gcfg.data.max_range, gcfg.data.min_range = 100.0, min_range
        gcfg.data.deskew = has_time
        genz = GenZICP(gcfg)  # no thread knob: TBB picks

        def genz_step(k: int, p: np.ndarray, t: np.ndarray | None) -> np.ndarray:
            genz.register_frame(p, t)
            return np.array(genz.last_pose)

        return genz_step
    raise ValueError(f"method: unknown {method!r}")


def run_worker(method: str, data: Path, threads: int, passes: int = 1) -> dict[str, Any]:
    """``passes`` runs over the sequence, each with a fresh instance: the poses of the first,
    the per-frame times of all (a 16-frame sequence gives too few for a stable median)."""
    frames = _Frames(data)
    poses: list[np.ndarray] = []
    ms: list[float] = []
    # GenZ-ICP's core prints a status panel per frame: silence fd 1 while stepping.
    devnull, saved = os.open(os.devnull, os.O_WRONLY), os.dup(1)
    os.dup2(devnull, 1)
    try:
        for run in range(max(1, passes)):
            step = _stepper(method, frames, threads)
            for k in range(len(frames)):
                p, t = frames.points(k), frames.times(k)
                t0 = time.perf_counter()
                pose = step(k, p, t)
                if k > 0:  # the first frame only initialises the map
                    ms.append(1e3 * (time.perf_counter() - t0))
                if run == 0:
                    poses.append(pose)
    finally:
        os.dup2(saved, 1)
    peak_mb = _peak_rss_mb()
    return {"poses": np.array(poses).tolist(), "ms": ms, "peak_mb": peak_mb}


# ------------------------------------------------------------------ metrics


def metrics(poses: np.ndarray, gt: np.ndarray, ms: list[float]) -> dict[str, float]:
    from scanreg.eval import absolute_trajectory_error, kitti_odometry_error
    from scanreg.io import Trajectory

    est = Trajectory(np.linalg.inv(poses[0]) @ poses)
    ref = Trajectory(np.linalg.inv(gt[0]) @ gt)
    ate = absolute_trajectory_error(est, ref, alignment="se3")
    path = float(np.sum(np.linalg.norm(np.diff(ref.poses[:, :3, 3], axis=0), axis=1)))
    lengths = tuple(x for x in (5.0, 10.0, 20.0, 40.0, 80.0) if x < 0.9 * path)
    out = {
        "ate_m": float(ate.translation.rmse),
        "end_m": float(np.linalg.norm(est.poses[-1, :3, 3] - ref.poses[-1, :3, 3])),
        "median_ms": float(np.median(ms)),
        "fps": 1e3 / float(np.median(ms)),
        "path_m": path,
    }
    try:
        k = kitti_odometry_error(est, ref, lengths=lengths, step=1)
        out["drift_pct"] = float(k.translation_percent)
        out["rot_deg_100m"] = 100.0 * float(k.rotation_deg_per_m)
    except ValueError:
        out["drift_pct"] = out["rot_deg_100m"] = math.nan
    return out


def _run(method: str, data: Path, args: argparse.Namespace) -> dict[str, Any] | None:
    """One method over one sequence in a fresh subprocess (its own peak memory)."""
    cmd = [sys.executable, __file__, "--worker", method, "--data", str(data)]
    cmd += ["--threads", str(args.threads), "--passes", str(args.passes)]
    if args.peers_site:
        cmd += ["--peers-site", args.peers_site]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        print(f"# {data.stem} {method}: failed: {proc.stderr.strip()[-300:]}", file=sys.stderr)
        return None
    out: dict[str, Any] = json.loads(proc.stdout.strip().splitlines()[-1])
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--peers-site", default=None, help="site-packages holding kiss_icp/genz_icp")
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--sensor", default="hdl64", choices=["vlp16", "hdl32", "hdl64"])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--json", type=Path, default=None, help="also write the rows here")
    ap.add_argument(
        "--rounds",
        type=int,
        default=1,
        help="run every method this many times, interleaved (round r runs each method once); "
        "fps and the fps ratio are medians over rounds (ratios taken within each round)",
    )
    ap.add_argument(
        "--passes",
        type=int,
        default=1,
        help="runs over each sequence per worker (fresh instance each; times of all are pooled)",
    )
    ap.add_argument("--sequences", default=None, help="comma-separated subset, e.g. kitti16")
    ap.add_argument("--methods", default=None, help=f"comma-separated subset of {METHODS}")
    ap.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--data", type=Path, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.peers_site:
        sys.path.append(args.peers_site)
    if args.worker:
        print(json.dumps(run_worker(args.worker, args.data, args.threads, args.passes)))
        return

    methods = METHODS if args.methods is None else tuple(args.methods.split(","))
    wanted = None if args.sequences is None else set(args.sequences.split(","))
    rows = []
    fps_ratios: dict[str, list[float]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        inputs = build_inputs(Path(tmp), args.frames, args.sensor)
        for name, data in inputs.items():
            if wanted is not None and name not in wanted:
                continue
            gt = _ground_truth(data)
            runs: dict[str, list[dict[str, Any]]] = {}
            for _ in range(max(1, args.rounds)):
                for method in methods:
                    if method == "scanreg+prior" and name != "sim-tunnel":
                        continue
                    res = _run(method, data, args)
                    if res is not None:
                        runs.setdefault(method, []).append(res)
                if "scanreg" in runs and "kiss_icp" in runs:
                    a, b = runs["scanreg"][-1], runs["kiss_icp"][-1]
                    if len(runs["scanreg"]) == len(runs["kiss_icp"]):
                        ratio = float(np.median(b["ms"]) / np.median(a["ms"]))
                        fps_ratios.setdefault(name, []).append(ratio)
            for method, results in runs.items():
                first = results[0]
                row = {"sequence": name, "method": method, "rounds": len(results)}
                row.update(metrics(np.array(first["poses"]), gt, first["ms"]))
                per_round = [float(np.median(r["ms"])) for r in results]
                row["median_ms"] = float(np.median(per_round))
                row["fps"] = 1e3 / row["median_ms"]
                row["peak_mb"] = float(np.median([r["peak_mb"] for r in results]))
                rows.append(row)
                print(f"# {name:11s} {method:14s} done", file=sys.stderr)

    load = os.getloadavg()[0]
    print(
        f"# {args.frames} simulated frames ({args.sensor}), {args.threads} threads, "
        f"load {load:.1f} at the end"
    )
    head = f"{'sequence':11s} {'method':14s} {'ATE m':>7s} {'end m':>7s} {'drift %':>8s} "
    head += f"{'deg/100m':>8s} {'ms/frame':>9s} {'fps':>6s} {'peak MB':>8s}"
    print(head)
    print("-" * len(head))
    for r in rows:
        print(
            f"{r['sequence']:11s} {r['method']:14s} {r['ate_m']:7.3f} {r['end_m']:7.3f} "
            f"{r['drift_pct']:8.3f} {r['rot_deg_100m']:8.3f} {r['median_ms']:9.1f} "
            f"{r['fps']:6.1f} {r['peak_mb']:8.0f}"
        )
    print("\nratios scanreg (gicp, no prior) / kiss_icp: drift, fps, peak memory")
    print("(fps: median over rounds of the ratio within each round, with the range)")
    for name in sorted({r["sequence"] for r in rows}):
        by = {r["method"]: r for r in rows if r["sequence"] == name}
        if "scanreg" in by and "kiss_icp" in by:
            a, b = by["scanreg"], by["kiss_icp"]
            fr = fps_ratios.get(name, [a["fps"] / b["fps"]])
            print(
                f"{name:11s} drift {a['drift_pct'] / b['drift_pct']:.2f}  "
                f"fps {np.median(fr):.2f} ({min(fr):.2f}-{max(fr):.2f}, {len(fr)} rounds)  "
                f"memory {a['peak_mb'] / b['peak_mb']:.2f}"
            )
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
