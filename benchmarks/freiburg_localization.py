"""2D localization in a saved map (scanreg.pipeline.Localizer2D) on the Intel log (issue 22).

The map is what ``benchmarks/freiburg_mapping.py --output DIR`` (or ``scanreg map``) wrote for
the whole Intel log: ``DIR/intel/map.yaml`` (the occupancy grid, ROS map_server convention)
and ``DIR/intel/poses_tum.txt`` (the mapped pose of every scan). Every scan of the same log is
then located in that map from no initial pose (the first scan by a global branch and bound
over the whole map; afterwards the wheel odometry predicts, and a lost track is found
globally again), exactly as ``scanreg localize LOG --map DIR/intel`` does. Reported: the
fraction of scans accepted, the global fixes, scans/s (wall and CPU, since the machine is
shared), and the distance and heading of each accepted pose from the mapped one (and how many
accepted poses are more than 0.3 m from it).

Run: ``.venv/bin/python benchmarks/freiburg_localization.py --map DIR/intel
[--data ../shared/data] [--max-scans N]``.
"""

from __future__ import annotations

import argparse
import math
import os
import time
from pathlib import Path

import numpy as np
from scanreg.io import read_scans, read_tum
from scanreg.pipeline.localizer2d import Localizer2D


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    here = Path(__file__).resolve().parent.parent
    default = Path(os.environ.get("SCANREG_DATA", here.parent / "shared" / "data"))
    parser.add_argument("--data", type=Path, default=default)
    parser.add_argument("--map", type=Path, required=True, help="folder scanreg map wrote")
    parser.add_argument("--max-scans", type=int, default=None)
    args = parser.parse_args()
    log = read_scans(args.data / "freiburg-slam-benchmark" / "intel.clf.bz2")
    mapped = read_tum(args.map / "poses_tum.txt")
    indices = [i for i, s in enumerate(log.scans) if s.kind == "FLASER"][: args.max_scans]
    loc = Localizer2D.from_map_server(args.map / "map.yaml")
    load_before = os.getloadavg()[0]
    wall, cpu = time.perf_counter(), time.process_time()
    accepted, sources, gaps, turns = 0, [], [], []
    previous = None
    located = 0
    for k, i in enumerate(indices):
        scan = log.scans[i]
        prior = None
        if previous is not None and scan.odometry_pose is not None:
            prior = log.motion_prior(previous, i)
        previous = i
        pts = scan.to_points(0.1, 40.0)
        if len(pts) < 3:
            continue
        frame = loc.step(pts, prior=prior, stamp=scan.timestamp)
        located += 1
        sources.append(frame.prediction_source)
        if frame.verdict.accepted:
            accepted += 1
            ref = mapped.poses[k]  # (4, 4): the mapped pose of scan k, lifted to 3D
            gaps.append(float(np.hypot(*(frame.pose.translation - ref[:2, 3]))))
            dth = frame.pose.angle - math.atan2(ref[1, 0], ref[0, 0])
            turns.append(abs(math.degrees(math.atan2(math.sin(dth), math.cos(dth)))))
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    load = 0.5 * (load_before + os.getloadavg()[0])
    g, t = np.array(gaps), np.array(turns)
    fixes = sum(s == "global" for s in sources)
    print(
        "| scans | accepted | global fixes | distance from the mapped pose: median / mean / 95 % "
        "(m) | accepted > 0.3 m off | heading: median / 95 % (deg) | scans/s (wall) | "
        "scans/s (CPU) | load avg |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    print(
        f"| {located} | {accepted} ({accepted / located:.1%}) | {fixes} | "
        f"{np.median(g):.3f} / {g.mean():.3f} / {np.quantile(g, 0.95):.3f} | "
        f"{int(np.sum(g > 0.3))} | "
        f"{np.median(t):.2f} / {np.quantile(t, 0.95):.2f} | {located / wall:.0f} | "
        f"{located / cpu:.0f} | {load:.1f} |"
    )


if __name__ == "__main__":
    main()
