"""Two 3D drives mapped separately, in unrelated frames, merged (``scanreg merge`` on 3D maps).

Drives around the simulated city block (``sim:loop``, :func:`scanreg.simulate.block_loop`):
drive a starts where the course starts, drive b a lap and a half later (so half a lap from
a's start), each mapped alone (``Mapper3D``, default ``MappingConfig3D``); b's map is then
moved into an unrelated frame (73° yaw, (40, -25, 3) m) and merged into a's
(:func:`scanreg.pipeline.merge_maps`). Rows: ATE (SE(3)-aligned RMSE) against the exact truth
of a alone, b alone (its own frame), and the merged map over every scan of both in a's frame;
inter-session loops joined of those tried; times. The same join through ``scanreg map B
--extend A/`` (:func:`scanreg.pipeline.run_mapping_to_folder` with ``extend``): a's map saved
as a folder, drive b's sweeps written as a folder of PCD files (per-point time, stamps in
``poses_tum.txt``), mapped by the command in its own frame (b's first sweep: half a lap from
a's start, heading the other way) and joined. Then a drive around another block (another
seed: the same road, other façades, poles, cars) is merged into a: it must be refused.

Run: ``.venv/bin/python benchmarks/merge_3d.py [--lap-length 300] [--scans 300]
[--output DIR]`` (``--output``: the maps and the merged one, as ``scanreg map`` / ``scanreg
merge`` write them, in ``DIR/{a,b,merged}``, and ``DIR/{b_sweeps,extended}``).
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from pathlib import Path

import numpy as np
from scanreg import SE3
from scanreg.eval import absolute_trajectory_error
from scanreg.io import PointCloud, Trajectory, write_points, write_poses
from scanreg.io.sequences import SimulatedSequence
from scanreg.pipeline import Mapper3D, MappingConfig3D, merge_maps, run_mapping_to_folder
from scanreg.saved_map import SavedMap

#: The unrelated frame the second map is moved into.
ELSEWHERE = SE3.from_vector([40.0, -25.0, 3.0, 0.0, 0.0, math.radians(73.0)])
CONFIG = MappingConfig3D()


def drive(seq: SimulatedSequence, frames: range, session: str) -> SavedMap:
    mapper = Mapper3D(CONFIG)
    for k in frames:
        f = seq[k]
        mapper.step(f.points, f.timestamps, stamp=f.stamp)
    return SavedMap.from_result(mapper.finish(), session=session)


def ate(m: SavedMap, truth: np.ndarray) -> float:
    est = np.array([p.as_matrix() for p in m.poses])
    err = absolute_trajectory_error(
        Trajectory(est, m.stamps), Trajectory(truth, m.stamps), alignment="se3"
    )
    return float(err.translation.rmse)


def write_sweeps(seq: SimulatedSequence, frames: range, folder: Path) -> Path:
    """``frames`` of ``seq`` as a folder ``scanreg map`` reads: one PCD per sweep (points as
    the driver reports them, per-point time since the sweep's start), ``poses_tum.txt`` (the
    truth, for the stamps)."""
    folder.mkdir(parents=True, exist_ok=True)
    for k in frames:
        f = seq[k]
        write_points(folder / f"{k:06d}.pcd", PointCloud(points=f.points, time=f.timestamps))
    truth = seq.ground_truth_at(CONFIG.odometry.reference_time)[list(frames)]
    write_poses(folder / "poses_tum.txt", truth, "tum", timestamps=seq.stamps[list(frames)])
    return folder


def extend_through_command(
    seq: SimulatedSequence, a: SavedMap, frames: range, root: Path
) -> tuple[SavedMap, dict[str, object], float]:
    """``scanreg map B_SWEEPS/ --extend A/ -o EXTENDED/``: the joint map, the command's JSON
    and its seconds (b's mapping included)."""
    a.save(root / "a")
    sweeps = write_sweeps(seq, frames, root / "b_sweeps")
    wall = time.perf_counter()
    result = run_mapping_to_folder(sweeps, root / "extended", extend=root / "a")
    seconds = time.perf_counter() - wall
    return SavedMap.load(root / "extended"), result, seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lap-length", type=float, default=300.0)
    parser.add_argument("--scans", type=int, default=300, help="scans per drive")
    parser.add_argument("--output", type=Path, default=None)
    args = parser.parse_args()
    seq = SimulatedSequence("loop", laps=3, lap_length=args.lap_length)
    per_lap = round(args.lap_length / seq.speed / seq.lidar.sweep_duration)
    a_frames = range(0, args.scans)
    b_frames = range(per_lap + per_lap // 2, per_lap + per_lap // 2 + args.scans)
    truth = seq.ground_truth_at(CONFIG.odometry.reference_time)

    wall = time.perf_counter()
    a = drive(seq, a_frames, "a")
    b = drive(seq, b_frames, "b").transformed(ELSEWHERE)
    mapped = time.perf_counter() - wall
    wall = time.perf_counter()
    merged, report = merge_maps(a, b)
    joined = time.perf_counter() - wall
    both = np.concatenate([truth[list(a_frames)], truth[list(b_frames)]])
    b_truth = truth[list(b_frames)]
    print(
        f"lap {args.lap_length:g} m, {args.scans} scans a drive, a at frame 0, b at frame "
        f"{b_frames.start} ({a.num_nodes} + {b.num_nodes} nodes)"
    )
    print()
    print("| map | scans | ATE (m) | inter-session loops (left out) | time (s) |")
    print("|---|---|---|---|---|")
    print(f"| a alone | {a.num_scans} | {ate(a, truth[list(a_frames)]):.4f} | | |")
    print(f"| b alone (own frame) | {b.num_scans} | {ate(b, b_truth):.4f} | | |")
    loops = f"{report.accepted} of {report.candidates} ({report.disagreeing})"
    print(
        f"| merged, a's frame | {merged.num_scans} | {ate(merged, both):.4f} | {loops} | "
        f"{joined:.1f} |"
    )
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) if args.output is None else args.output
        extended, result, seconds = extend_through_command(seq, a, b_frames, root)
    loops = (
        f"{result['inter_session_loops']} of {result['inter_session_candidates']} "
        f"({result['inter_session_disagreeing']})"
    )
    print(
        f"| extended (`scanreg map B/ --extend A/`), a's frame | {extended.num_scans} | "
        f"{ate(extended, both):.4f} | {loops} | {seconds:.1f} (b mapped in it) |"
    )
    print(f"<!-- mapping both drives {mapped:.0f} s -->")

    other_seq = SimulatedSequence("loop", laps=3, lap_length=args.lap_length, seed=3)
    other = drive(other_seq, b_frames, "c")
    wall = time.perf_counter()
    try:
        merge_maps(a, other.transformed(ELSEWHERE))
        outcome = "MERGED (a false merge)"
    except ValueError as exc:
        outcome = f"refused: {exc}"
    print(
        f"| another block (seed 3) | {other.num_scans} | | {outcome} | "
        f"{time.perf_counter() - wall:.1f} |"
    )
    if args.output is not None:
        for key, m in (("a", a), ("b", b), ("merged", merged)):
            m.save(args.output / key)


if __name__ == "__main__":
    main()
