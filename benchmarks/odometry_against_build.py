"""``Odometry2D``'s scans per CPU second against another build of scanreg, as alternating
processes (the ratio issue targets are stated in: "N× the scans/s of commit X").

Run (the other build: a checkout of X whose ``python/`` holds its compiled ``_core``, e.g.
``git worktree add /tmp/X X && cd /tmp/X && maturin build --release -o /tmp/Xw`` and the
wheel's ``scanreg/_core*.so`` unzipped into ``/tmp/X/python/scanreg/``):

    RAYON_NUM_THREADS=1 .venv/bin/python benchmarks/odometry_against_build.py \
        --against /tmp/X/python [--pairs 4] [--rounds 3]

Each process runs ``Odometry2D()`` (default configuration) over the 902 Intel scans with the
wheel-odometry prior, as ``trust_speed.py``'s odometry section does, once to warm up and then
``--rounds`` times, and prints the median scans per CPU second. Processes alternate: the other
build, then this one, ``--pairs`` times; each pair's ratio is this build's over the other's,
so that load shared by a pair cancels. Only ``scanreg.io.read_carmen`` and
``scanreg.pipeline.Odometry2D`` are used, so any build since the odometry existed runs it.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

DATA = Path(os.environ.get("SCANREG_DATA", Path(__file__).resolve().parents[2] / "shared/data"))
HERE = Path(__file__).resolve()
OWN_PYTHON = HERE.parents[1] / "python"


def scans_per_second(rounds: int) -> tuple[float, float]:
    """This process's scanreg: median scans per CPU second and per wall-clock second over
    ``rounds`` runs."""
    from scanreg.io import read_carmen
    from scanreg.pipeline import Odometry2D

    log = read_carmen(DATA / "carmen-intel" / "intel_gfs_subset_clf_timestamps.clf")
    points = [s.to_points(0.1, 40.0) for s in log.scans]

    def run() -> None:
        odo = Odometry2D()
        for k, p in enumerate(points):
            odo.step(p, prior=None if k == 0 else log.motion_prior(k - 1, k))

    run()  # warm-up
    cpu, wall = [], []
    for _ in range(rounds):
        c0, w0 = time.process_time(), time.perf_counter()
        run()
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - w0)
    return len(points) / statistics.median(cpu), len(points) / statistics.median(wall)


def child(pythonpath: Path, rounds: int) -> tuple[float, float]:
    # One thread everywhere: idle BLAS or OpenMP threads that spin would count as CPU time.
    env = dict(os.environ, PYTHONPATH=str(pythonpath), OMP_NUM_THREADS="1")
    env.setdefault("OPENBLAS_NUM_THREADS", "1")
    env.setdefault("RAYON_NUM_THREADS", "1")
    out = subprocess.run(
        [sys.executable, str(HERE), "--child", "--rounds", str(rounds)],
        env=env,
        check=True,
        capture_output=True,
        text=True,
    )
    cpu, wall = out.stdout.split()[-2:]
    return float(cpu), float(wall)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--against", type=Path, help="the other build's python/ directory")
    ap.add_argument("--pairs", type=int, default=4)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print("{:.1f} {:.1f}".format(*scans_per_second(args.rounds)))
        return
    if args.against is None:
        ap.error("--against: the other build's python/ directory is required")
    print(f"\nOdometry2D, 902 Intel scans: this build against {args.against}\n")
    print("| pair | other: scans per CPU s / wall s | this build | ratio CPU | ratio wall |")
    print("|---:|---:|---:|---:|---:|")
    cpu_ratios, wall_ratios = [], []
    for i in range(args.pairs):
        other = child(args.against, args.rounds)
        own = child(OWN_PYTHON, args.rounds)
        cpu_ratios.append(own[0] / other[0])
        wall_ratios.append(own[1] / other[1])
        print(
            f"| {i + 1} | {other[0]:.0f} / {other[1]:.0f} | {own[0]:.0f} / {own[1]:.0f} "
            f"| {cpu_ratios[-1]:.2f} | {wall_ratios[-1]:.2f} |",
            flush=True,
        )
    for name, r in (("CPU", cpu_ratios), ("wall", wall_ratios)):
        med, lo, hi = statistics.median(r), min(r), max(r)
        print(f"\nratio ({name}) median {med:.2f}, range {lo:.2f}–{hi:.2f}")


if __name__ == "__main__":
    main()
