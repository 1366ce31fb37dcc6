"""Two maps of one building merged across unrelated frames (scanreg.pipeline.merge_maps).

Each Freiburg log (Intel, ACES) is cut at its middle line into two sessions, each mapped alone
(``run_mapping``, default ``MappingConfig``); the second map is then moved into an unrelated
frame (73°, (40, -25) m) and merged into the first; and the second half's map, in its own
frame, joined to the first as ``scanreg map --extend`` joins a new run (``extend_map``). Rows:
the Kümmerle relations over all scans of the joint map (2984 Intel / 1279 ACES), and those
whose two stamps fall in different sessions; the inter-session loops joined and left out for
disagreeing; the joint map's self-check (``check_map``: contradicted returns); times.

Run: ``.venv/bin/python benchmarks/freiburg_merge.py [--data ../shared/data]
[--logs intel aces] [--output DIR]`` (``--output``: the two maps and the merged one, as
``scanreg map`` / ``scanreg merge`` write them, in ``DIR/<log>/{a,b,merged}``: ``scanreg merge
DIR/intel/a DIR/intel/b -o M`` repeats the merge from the command line).
"""

from __future__ import annotations

import argparse
import bz2
import math
import os
import tempfile
import time
from pathlib import Path

import numpy as np
from scanreg import SE2
from scanreg.eval.relations import Relations, read_relations, relation_error
from scanreg.io import read_scans
from scanreg.io.trajectory import Trajectory
from scanreg.pipeline import MappingConfig, check_map, extend_map, merge_maps, run_mapping
from scanreg.saved_map import SavedMap

FILES = {"intel": ("intel.clf.bz2", "intel.relations"), "aces": ("aces.clf.bz2", "aces.relations")}
#: The unrelated frame the second map is moved into.
ELSEWHERE = SE2.from_vector([40.0, -25.0, math.radians(73.0)])


def map_lines(lines: list[str], name: str, folder: Path) -> SavedMap:
    path = folder / f"{name}.clf"
    path.write_text("".join(lines), encoding="utf-8")
    return SavedMap.from_result(run_mapping(read_scans(path), MappingConfig()), session=name)


def score(m: SavedMap, relations: Relations, cut: float) -> tuple[str, str]:
    traj = Trajectory.from_poses(list(m.poses), m.stamps)  # type: ignore[arg-type]
    both = relation_error(traj, relations)
    u = np.flatnonzero((relations.t1 < cut) != (relations.t2 < cut))
    cross = relation_error(traj, Relations(relations.t1[u], relations.t2[u], relations.poses[u]))

    def row(e: object) -> str:
        t, r = e.translation, e.rotation_deg  # type: ignore[attr-defined]
        return f"{len(e.used)} | {t.mean:.4f} ± {t.std:.4f} | {r.mean:.3f} ± {r.std:.3f}"  # type: ignore[attr-defined]

    return row(both), row(cross)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    here = Path(__file__).resolve().parent.parent
    default = Path(os.environ.get("SCANREG_DATA", here.parent / "shared" / "data"))
    parser.add_argument("--data", type=Path, default=default)
    parser.add_argument("--logs", nargs="+", default=list(FILES), choices=list(FILES))
    parser.add_argument("--output", type=Path, default=None)
    args = parser.parse_args()
    folder = args.data / "freiburg-slam-benchmark"
    print(
        "| log | join | relations | n | translation (m) | rotation (deg) | loops (left out) "
        "| self-check |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for name in args.logs:
        log_file, relations_file = FILES[name]
        with bz2.open(folder / log_file, "rt", encoding="utf-8") as fh:
            lines = fh.readlines()
        half = len(lines) // 2
        wall = time.perf_counter()
        with tempfile.TemporaryDirectory() as tmp:
            a = map_lines(lines[:half], "a", Path(tmp))
            own = map_lines(lines[half:], "b", Path(tmp))  # (the second half's own frame)
        b = own.transformed(ELSEWHERE)
        mapped = time.perf_counter() - wall
        relations = read_relations(folder / relations_file)
        joints = {}
        for how in ("merge", "extend"):
            wall = time.perf_counter()
            if how == "merge":
                joint, report = merge_maps(a, b)
            else:
                joint, report = extend_map(a, own)
            joined = time.perf_counter() - wall
            joints[how] = joint
            both, cross = score(joint, relations, float(b.stamps[0]))
            loops = f"{report.accepted} of {report.candidates} ({report.disagreeing})"
            check = check_map(joint)
            verdict = "consistent" if check.consistent else "INCONSISTENT"
            judged = f"{verdict}, {check.contradiction_fraction:.2%} of {check.returns}"
            print(f"| {name} | {how} | all | {both} | {loops} | {judged} |")
            print(f"| {name} | {how} | across the sessions | {cross} | | |")
            print(f"<!-- {name}: mapping both halves {mapped:.0f} s, {how} {joined:.1f} s -->")
        if args.output is not None:
            for key, m in (("a", a), ("b", b), ("merged", joints["merge"])):
                m.save(args.output / name / key)


if __name__ == "__main__":
    main()
