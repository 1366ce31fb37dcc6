"""2D mapping from a ROS bag against mapping from the CARMEN log it was made from.

Each log is written as a ROS 2 bag by rosbags' own writer (``tests/_carmen_bag.py``:
``/scan`` LaserScan from the laser lines, ``/odom`` Odometry from the ``ODOM`` lines, each at
its own stamp, ``/tf_static`` base_link → laser; the hospital's laser 0.22 m ahead, its
odometry the laser lines' own), read back with ``scanreg.io.read_laserscan_bag`` and
``scan_log`` (which pairs the odometry with the scans as for the log: the laser latency
measured when the odometry is stale) and mapped with ``run_mapping`` (default
``MappingConfig``), as the log itself is. Rows: the Kümmerle relations score (mean
translation m / rotation deg over all relations), the latency applied, the wall time of
reading (with the pairing) and of mapping, and the CPU time of mapping (this process's, both
threads: less moved by other work on the machine than the wall time), log and bag side by
side; with ``--repeat N`` the sources alternate N rounds and the times are medians, the last
column the map CPU over the log's. ``--float32-log`` adds the log mapped with its ranges
rounded to float32, as a LaserScan stores them (row ``log f32``): how far that rounding alone
moves the mapper.

Run: ``.venv/bin/python benchmarks/freiburg_bags.py [--data ../shared/data] [--logs intel
aces fr-clinic] [--max-scans N] [--storage mcap|sqlite3|ros1] [--float32-log] [--repeat N]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scanreg.eval.relations import read_relations, relation_error
from scanreg.io import ScanLog, read_laserscan_bag, read_scans
from scanreg.io.trajectory import Trajectory
from scanreg.pipeline import MappingConfig, run_mapping, scan_log

HERE = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(HERE / "tests"))
from _carmen_bag import write_carmen_bag  # noqa: E402

#: log name → (file, laser message, T_base_laser written to /tf_static)
LOGS = {
    "intel": ("intel.clf.bz2", "FLASER", (0.0, 0.0, 0.0)),
    "aces": ("aces.clf.bz2", "FLASER", (0.0, 0.0, 0.0)),
    "fr-clinic": ("fr-clinic_robotlaser.clf.bz2", "ROBOTLASER1", (0.22, 0.0, 0.0)),
}


def float32_ranges(scans: ScanLog) -> ScanLog:
    """``scans`` with every range rounded to float32, as a LaserScan message stores it (the
    bag's only other difference, its float32 beam angles, is ~1e-7 rad)."""
    rounded = tuple(
        dataclasses.replace(s, ranges=np.asarray(s.ranges, dtype=np.float32).astype(np.float64))
        for s in scans.scans
    )
    return dataclasses.replace(scans, scans=rounded)


def _cpu() -> float:
    """This process's CPU time and its reaped children's (the mapper's odometry runs in a
    child process for long runs: ``scanreg.pipeline.odometry_process``)."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default = Path(os.environ.get("SCANREG_DATA", HERE.parent / "shared" / "data"))
    parser.add_argument("--data", type=Path, default=default)
    parser.add_argument("--logs", nargs="+", default=["intel"], choices=sorted(LOGS))
    parser.add_argument("--max-scans", type=int, default=None)
    parser.add_argument("--storage", choices=["mcap", "sqlite3", "ros1"], default="mcap")
    parser.add_argument(
        "--repeat", type=int, default=1, help="rounds of the sources, alternating (median times)"
    )
    parser.add_argument(
        "--float32-log",
        action="store_true",
        help="also map the log with its ranges rounded to float32 (row 'log f32')",
    )
    args = parser.parse_args()
    folder = args.data / "freiburg-slam-benchmark"
    print(
        "| log | source | relations | translation (m) | rotation (deg) | latency (s) "
        "| read (s) | map (s) | map CPU (s) | CPU / log's |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name in args.logs:
        file, laser, mounting = LOGS[name]
        relations = read_relations(folder / f"{name}.relations")
        t0 = time.perf_counter()
        log = read_scans(folder / file)
        scans = scan_log(log, kind=laser, max_scans=args.max_scans)
        read_log = time.perf_counter() - t0
        with tempfile.TemporaryDirectory() as tmp:
            path = write_carmen_bag(
                log,
                Path(tmp) / f"{name}_bag",
                kind=args.storage,
                laser=laser,
                mounting=mounting,
                max_scans=args.max_scans,
            )
            t0 = time.perf_counter()
            bag = scan_log(read_laserscan_bag(path))
            read_bag = time.perf_counter() - t0
        runs = [("log", scans, read_log), (args.storage, bag, read_bag)]
        if args.float32_log:
            runs.insert(1, ("log f32", float32_ranges(scans), read_log))
        # The sources alternate, ``--repeat`` rounds: the machine's load then falls on each
        # alike, and the map times are the median of each source's runs (the maps themselves
        # are the same every round: the runs are deterministic).
        times: dict[str, list[tuple[float, float]]] = {source: [] for source, _, _ in runs}
        rows: dict[str, str] = {}
        for _ in range(args.repeat):
            for source, run, seconds in runs:
                t0, c0 = time.perf_counter(), _cpu()
                res = run_mapping(run, MappingConfig())
                times[source].append((time.perf_counter() - t0, _cpu() - c0))
                stamps = np.array(res.stamps, dtype=np.float64)
                err = relation_error(Trajectory.from_poses(list(res.poses), stamps), relations)
                rows[source] = (
                    f"| {name} | {source} | {len(err.used)} | {err.translation.mean:.5f} | "
                    f"{err.rotation_deg.mean:.4f} | {run.laser_latency} | {seconds:.1f}"
                )
        log_cpu = float(np.median([c for _, c in times["log"]]))
        for source, _, _ in runs:
            wall, cpu = (float(np.median(v)) for v in zip(*times[source], strict=True))
            print(f"{rows[source]} | {wall:.0f} | {cpu:.0f} | {cpu / log_cpu:.2f} |", flush=True)


if __name__ == "__main__":
    main()
