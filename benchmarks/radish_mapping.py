"""2D mapping's defaults on 13 buildings they were never chosen on: the Radish "corrected" logs.

Each log of ``../shared/data/carmen-radish-corrected`` (GMapping-corrected poses in its
``FLASER`` lines; the scans GMapping kept, typically 0.5–1 m and up to ~30° apart; 180° lasers
with 180, 181, 360 or 361 beams; see its README) is mapped with the default ``MappingConfig``
from wheel odometry simulated on the corrected poses: each step ``T_{k-1,k}`` perturbed by
zero-mean Gaussian noise of σ = 5 % of its length along it, 2 % across, and 0.5° + 2° per
metre in heading (seeded per log), with no other change. The logs' corrected poses are the
reference: GMapping's own output, cm-level locally, not ground truth. A log with broken
timestamps gets one second per scan (the README's "truncated", "all 0", "corrupted").

Columns: the reference path; RPE over consecutive scans and over 10 scans (mean translation,
m / mean rotation, deg) of the simulated odometry and of the map; ATE (RMS position after the
best rigid alignment, m); the map's self-check verdict without the reference (contradicted
fraction) and the same check's contradicted fraction with GMapping's poses in place of ours;
the frames the odometry rejected and reseeded; CPU seconds of mapping.

Run: ``.venv/bin/python benchmarks/radish_mapping.py [--data ../shared/data] [--logs NAME ...]``
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import math
import os
from pathlib import Path

import numpy as np
from scanreg import SE2
from scanreg.eval.ate import absolute_trajectory_error
from scanreg.eval.rpe import relative_pose_error
from scanreg.io import ScanLog, read_scans
from scanreg.io.trajectory import Trajectory
from scanreg.pipeline import MappingConfig, run_mapping, scan_log
from scanreg.pipeline.map_check import check_map

HERE = Path(__file__).resolve().parent.parent
LOGS = (
    "acapulco",
    "aces",
    "belgioioso",
    "csail",
    "edmonton",
    "fhw",
    "freiburg-079",
    "freiburg-101",
    "freiburg-campus",
    "infinite-corridor",
    "intel",
    "orebro",
    "seattle",
)
#: The simulated wheels' noise per step: σ along and across as a fraction of the step's
#: length, σ of heading (rad) per step and per metre.
ALONG, ACROSS, TURN, TURN_PER_METRE = 0.05, 0.02, math.radians(0.5), math.radians(2.0)


def noisy_odometry(reference: list[SE2], seed: int) -> list[SE2]:
    """The reference's steps, each perturbed (module docstring), chained from its first pose."""
    rng = np.random.default_rng(seed)
    out = [reference[0]]
    for a, b in itertools.pairwise(reference):
        step = a.inverse() @ b
        d = float(np.linalg.norm(step.translation))
        noise = rng.normal(size=3) * [ALONG * d, ACROSS * d, TURN + TURN_PER_METRE * d]
        out.append(out[-1] @ step @ SE2.from_vector(noise))
    return out


def prepared(name: str, folder: Path, seed: int) -> tuple[ScanLog, list[SE2], np.ndarray]:
    """The log with simulated wheels, its reference poses and the stamps used."""
    log = scan_log(read_scans(folder / f"{name}-corrected.log.gz"), kind="FLASER")
    # The corrected pose is each FLASER line's own (its ODOM lines are all zeros).
    reference = [SE2.from_vector(s.odometry_pose) for s in log.scans]
    stamps = np.asarray(log.stamps, dtype=np.float64)
    if not (np.all(np.diff(stamps) > 0) and np.all(np.isfinite(stamps))):
        stamps = np.arange(len(stamps), dtype=np.float64)
    scans = tuple(
        dataclasses.replace(s, timestamp=float(t)) for s, t in zip(log.scans, stamps, strict=True)
    )
    wheels = noisy_odometry(reference, seed)
    run = dataclasses.replace(log, scans=scans, stamps=stamps, odometry=tuple(wheels))
    return run, reference, stamps


def errors(poses: list[SE2], reference: list[SE2], stamps: np.ndarray) -> tuple[float, ...]:
    est = Trajectory.from_poses(poses, stamps)
    ref = Trajectory.from_poses(reference, stamps)
    out: list[float] = []
    for delta in (1, 10):
        rpe = relative_pose_error(est, ref, delta=delta, all_pairs=True)
        out += [rpe.translation.mean, rpe.rotation_deg.mean]
    out.append(absolute_trajectory_error(est, ref).translation.rmse)
    return tuple(out)


def _cpu() -> float:
    """This process's CPU time and its reaped children's (the mapper's odometry runs in a
    child process for long runs: ``scanreg.pipeline.odometry_process``)."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default = Path(os.environ.get("SCANREG_DATA", HERE.parent / "shared" / "data"))
    parser.add_argument("--data", type=Path, default=default)
    parser.add_argument("--logs", nargs="+", default=list(LOGS), choices=LOGS)
    args = parser.parse_args()
    folder = args.data / "carmen-radish-corrected"
    print(
        "| log | scans | path (m) | odometry RPE 1 (m / deg) | map RPE 1 | odometry RPE 10 "
        "| map RPE 10 | odometry ATE (m) | map ATE (m) | self-check | at GMapping's poses "
        "| rejected / reseeded | CPU (s) |"
    )
    print("|---|---:|---:|---|---|---|---|---:|---:|---|---:|---|---:|")
    for name in args.logs:
        seed = LOGS.index(name)  # the same wheels whichever logs are run
        run, reference, stamps = prepared(name, folder, seed)
        c0 = _cpu()
        res = run_mapping(run, MappingConfig())
        cpu = _cpu() - c0
        check = check_map(res)
        # The same self-check of GMapping's poses (the same scans and graph): is our map
        # less consistent than the reference, or the reference itself contradicted?
        at_reference = check_map(res, poses=reference)
        path = sum(
            float(np.linalg.norm((a.inverse() @ b).translation))
            for a, b in itertools.pairwise(reference)
        )
        odo = errors(list(run.odometry), reference, stamps)  # type: ignore[arg-type]
        mapped = errors(list(res.poses), reference, stamps)
        verdict = "consistent" if check.consistent else "**INCONSISTENT**"
        print(
            f"| {name} | {len(stamps)} | {path:.0f} | {odo[0]:.3f} / {odo[1]:.2f} | "
            f"{mapped[0]:.3f} / {mapped[1]:.2f} | {odo[2]:.3f} / {odo[3]:.2f} | "
            f"{mapped[2]:.3f} / {mapped[3]:.2f} | {odo[4]:.3f} | {mapped[4]:.3f} | "
            f"{verdict}, {check.contradiction_fraction:.1%} | "
            f"{at_reference.contradiction_fraction:.1%} | "
            f"{len(res.rejected)} / {len(res.reseeded)} | {cpu:.0f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
