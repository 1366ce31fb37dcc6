"""2D mapping with loop closure (scanreg.pipeline.mapping) on the Freiburg SLAM benchmark.

The complete raw Intel, ACES and hospital logs with all Kümmerle relations (2984 / 1279 /
2820), mapped in file order with the wheel-odometry prior (``run_mapping``, default
``MappingConfig``). Rows: our odometry alone (``Odometry2D``, correlative front end, the
trajectory before closure) and the optimized trajectory after loop closure, beside
Cartographer's published figures (Hess et al. 2016, Table II; the hospital's is on the
benchmark's local relations). Relation error: mean ± std of the translational (m) and
rotational (deg) error over all relations. Speed: wall time and CPU time (the process and its
odometry's child process) of the whole run (reading excluded), per-stage wall / CPU time
(odometry, candidate search, matching, optimization), scans/s.
There is no peer in the same process (Cartographer is not installable here), so the load
average is printed beside the times.

Run: ``.venv/bin/python benchmarks/freiburg_mapping.py [--data ../shared/data]
[--logs intel aces] [--max-scans N] [--config map.toml] [--output DIR] [--self-check]
[--odometry thread|process]``
(``--odometry``: where ``run_mapping`` runs the odometry, as the speed comparison of
``benchmarks/README.md`` alternates it; default its own choice, a child process on these logs)
(``--output``: also write each log's mapping outputs, as ``scanreg map`` does, to
``DIR/<log>/``; the map there is what ``benchmarks/freiburg_localization.py`` localizes in).

``--self-check``: also map each log with loop closure off (``max_candidates = 0``) and print
the map self-check (``scanreg.pipeline.map_check``, no ground truth) of three trajectories per
log: loop-closed, no loops, and the odometry alone. The loop-closed map should pass, the
other two be flagged.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time
from pathlib import Path

import numpy as np
from scanreg.config import load_config
from scanreg.eval.relations import read_relations, relation_error
from scanreg.io import read_scans
from scanreg.io.trajectory import Trajectory
from scanreg.pipeline.map_check import MapCheck, check_map
from scanreg.pipeline.mapping import MappingConfig, MappingResult, run_mapping

#: Hess et al., ICRA 2016, Table II: mean ± std, translation (m) / rotation (deg).
CARTOGRAPHER = {
    "intel": ((0.0229, 0.0239), (0.453, 1.335)),
    "aces": ((0.0375, 0.0426), (0.373, 0.469)),
    # The hospital figure is on the benchmark's "local" relations (see the data's README).
    "hospital": ((0.1078, 0.1943), (0.747, 2.047)),
}
#: The log and relations file of each name.
FILES = {
    "intel": ("intel.clf.bz2", "intel.relations"),
    "aces": ("aces.clf.bz2", "aces.relations"),
    "hospital": ("fr-clinic_robotlaser.clf.bz2", "fr-clinic.relations"),
}


def _fmt(mean: float, std: float, digits: int) -> str:
    return f"{mean:.{digits}f} ± {std:.{digits}f}"


def self_check_row(name: str, label: str, check: MapCheck, seconds: float) -> str:
    """One row of the self-check table."""
    regions = "; ".join(f"({r.x:.0f}, {r.y:.0f}) {r.contradictions}" for r in check.regions[:3])
    return (
        f"| {name} | {label} | {check.returns} | {check.contradiction_fraction:.2%} | "
        f"{check.loops_over_bound} / {len(check.loops)} | {check.loops_downweighted} | "
        f"{'pass' if check.consistent else 'FLAGGED'} | {regions} | {seconds:.2f} |"
    )


def self_checks(name: str, closed: MappingResult, no_loops: MappingResult) -> list[str]:
    """The self-check of the loop-closed map, the map without loops and the odometry alone."""
    rows = []
    for label, res, poses in (
        ("loop-closed", closed, None),
        ("no loops", no_loops, None),
        ("odometry alone", closed, closed.odometry_poses),
    ):
        t = time.perf_counter()
        check = check_map(res, poses)
        rows.append(self_check_row(name, label, check, time.perf_counter() - t))
    return rows


def _cpu() -> float:
    """This process's CPU time and its reaped children's (the mapper's odometry runs in a
    child process for long runs: ``scanreg.pipeline.odometry_process``)."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    here = Path(__file__).resolve().parent.parent
    default = Path(os.environ.get("SCANREG_DATA", here.parent / "shared" / "data"))
    parser.add_argument("--data", type=Path, default=default)
    parser.add_argument("--logs", nargs="+", default=list(FILES), choices=list(FILES))
    parser.add_argument("--max-scans", type=int, default=None)
    parser.add_argument("--config", type=Path, default=None, help="MappingConfig TOML")
    parser.add_argument("--output", type=Path, default=None, help="write outputs to DIR/<log>/")
    parser.add_argument("--self-check", action="store_true", help="self-check table (see above)")
    parser.add_argument(
        "--odometry",
        choices=("auto", "thread", "process"),
        default="auto",
        help="where run_mapping runs the odometry (default: its own choice)",
    )
    args = parser.parse_args()
    config = load_config(MappingConfig, args.config)
    in_process = {"auto": None, "thread": False, "process": True}[args.odometry]
    folder = args.data / "freiburg-slam-benchmark"
    table = []
    speed = []
    checks: list[str] = []
    for name in args.logs:
        log_file, relations_file = FILES[name]
        log = read_scans(folder / log_file)
        relations = read_relations(folder / relations_file)
        load_before = os.getloadavg()[0]
        wall, cpu = time.perf_counter(), _cpu()
        res = run_mapping(log, config, max_scans=args.max_scans, odometry_process=in_process)
        wall, cpu = time.perf_counter() - wall, _cpu() - cpu
        load = 0.5 * (load_before + os.getloadavg()[0])
        if args.output is not None:
            from scanreg.pipeline.mapping_output import write_outputs

            write_outputs(args.output / name, res, plot=False)
        stamps = np.array(res.stamps, dtype=np.float64)
        for label, poses in (
            ("odometry alone", res.odometry_poses),
            ("with loop closure", res.poses),
        ):
            err = relation_error(Trajectory.from_poses(list(poses), stamps), relations)
            t, r = err.translation, err.rotation_deg
            table.append(
                f"| {name} | scanreg, {label} | {len(err.used)} | {_fmt(t.mean, t.std, 4)} | "
                f"{_fmt(r.mean, r.std, 3)} |"
            )
        (tm, ts), (rm, rs) = CARTOGRAPHER[name]
        table.append(
            f"| {name} | Cartographer (published) | {len(relations)} | {_fmt(tm, ts, 4)} | "
            f"{_fmt(rm, rs, 3)} |"
        )
        tt = res.timing
        speed.append(
            f"| {name} | {res.num_scans} | {len(res.node_scans)} | "
            f"{len(res.accepted_loops)} / {len(res.rejected_loops)} | {wall:.1f} | {cpu:.1f} | "
            f"{tt.odometry:.1f} / {tt.odometry_cpu:.1f} | {tt.candidates:.1f} / "
            f"{tt.candidates_cpu:.1f} | {tt.matching:.1f} / {tt.matching_cpu:.1f} | "
            f"{tt.optimization:.1f} / {tt.optimization_cpu:.1f} | {res.num_scans / wall:.0f} | "
            f"{res.num_scans / cpu:.0f} | {load:.1f} |"
        )
        print(f"{name}: done in {wall:.1f} s", flush=True)
        if args.self_check:
            no_loops = dataclasses.replace(config, max_candidates=0)
            rows = self_checks(
                name,
                res,
                run_mapping(log, no_loops, max_scans=args.max_scans, odometry_process=in_process),
            )
            print("\n".join(rows), flush=True)  # kept if a later log fails
            checks += rows
    print()
    print("| log | trajectory | relations | translation (m) | rotation (deg) |")
    print("|---|---|---|---|---|")
    print("\n".join(table))
    print()
    print(
        "| log | scans | nodes | loops accepted / rejected | wall (s) | CPU (s) | odometry (s) | "
        "candidates (s) | matching (s) | optimization (s) | scans/s (wall) | scans/s (CPU) | "
        "load avg |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    print("\n".join(speed))
    if checks:
        print()
        print(
            "| log | trajectory | returns | contradicted | loops over 99.9 % bound | "
            "down-weighted | verdict | worst regions (x, y) m: count | check (s) |"
        )
        print("|---|---|---|---|---|---|---|---|---|")
        print("\n".join(checks))


if __name__ == "__main__":
    main()
