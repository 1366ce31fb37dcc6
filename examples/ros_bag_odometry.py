"""Scan-to-scan 2D odometry on a ROS bag of sensor_msgs/LaserScan, with figures.

    python examples/ros_bag_odometry.py [BAG] [--topic /scan] [--out ros_bag_odometry]

BAG defaults to the CCNY laser_scan_matcher demo bag in ../shared/data (a ROS 1 bag whose
index records stock readers reject). Writes to --out: the trajectory (TUM), its top view,
one pair's alignment with its covariance, and the weak directions of that pair.
Needs the ``ros`` and ``plot`` extras.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import scanreg
from scanreg import SE2, io, plot

DEFAULT_BAG = (
    Path(__file__).resolve().parents[2] / "shared/data/rosbag1-laserscan-ccny-demo/demo.bag"
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("bag", type=Path, nargs="?", default=DEFAULT_BAG)
    parser.add_argument("--topic", default=None, help="LaserScan topic (default: the only one)")
    parser.add_argument("--out", type=Path, default=Path("ros_bag_odometry"))
    parser.add_argument("--gate", type=float, default=0.3, help="max correspondence distance (m)")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)

    scans = io.read_bag_scans(args.bag, topic=args.topic)
    print(f"{args.bag}: {len(scans)} scans of {len(scans[0])} beams on {scans[0].topic}")

    # T_world_scan_k = T_world_scan_{k-1} @ T_{k-1}_k, each step registered scan k -> k-1,
    # starting from the previous step (constant velocity).
    T_world_scan = SE2.identity()
    poses, step = [T_world_scan], SE2.identity()
    results = []
    previous = scans[0].to_points()
    for scan in scans[1:]:
        current = scan.to_points()
        res = scanreg.register(
            current,
            previous,
            method="point_to_line",
            init=step,
            max_correspondence_distance=args.gate,
        )
        results.append(res)
        step = res.pose
        T_world_scan = T_world_scan @ step
        poses.append(T_world_scan)
        previous = current
    stamps = np.array([s.timestamp for s in scans])
    trajectory = io.Trajectory.from_poses(poses, timestamps=stamps)
    io.write_tum(args.out / "trajectory.tum", trajectory)
    converged = sum(r.converged for r in results)
    print(f"{converged}/{len(results)} steps converged; end pose {poses[-1]}")

    plot.plot_trajectories(args.out / "trajectory.png", trajectory, plane="xy")
    k = int(np.argmax([np.sqrt(r.covariance[2, 2]) for r in results]))  # the least certain step
    src, tgt = scans[k + 1].to_points(), scans[k].to_points()
    plot.plot_scan_alignment(
        args.out / "least_certain_pair.png", src, tgt, results[k].pose, results[k].covariance
    )
    plot.plot_weak_directions(
        args.out / "least_certain_pair_directions.png",
        src,
        results[k].conditioning,
        all_directions=True,
    )
    print(f"figures and trajectory in {args.out}/ (least certain step: {k} -> {k + 1})")


if __name__ == "__main__":
    main()
