"""How well the odometry's per-frame covariance describes its frame-to-frame error.

A simulated drive with exact truth (``SimulatedSequence``, truth at mid-sweep, the time the
poses refer to); for each frame after the first few, the error of the estimated increment
``δ = log(m̂⁻¹ · m)`` (right perturbation, translation first) against the registration's
covariances: mean and median NEES per covariance kind (ideal: 6, the dimension). The frame's
covariance is of the sweep *given the map*, so the increment error, which also carries the
previous frame's error, should if anything score a little above 6.

    .venv/bin/python benchmarks/odometry_covariance.py [--method gicp point_to_plane] [--frames 50]

Prints one Markdown table (a row per method and covariance kind), the one in
``benchmarks/README.md``.
"""

from __future__ import annotations

import argparse

import numpy as np
from scanreg import SE3
from scanreg.io.sequences import SimulatedSequence
from scanreg.pipeline.odometry import Odometry, OdometryConfig

KINDS = ("calibrated", "censi", "block", "hessian")


def nees_per_kind(scene: str, sensor: str, frames: int, method: str) -> dict[str, list[float]]:
    """NEES of every frame's increment error, per covariance kind."""
    seq = SimulatedSequence(scene, num_frames=frames, sensor=sensor, ramp=0.0)
    truth = seq.ground_truth_at("middle")
    odo = Odometry(OdometryConfig(method=method))
    nees: dict[str, list[float]] = {k: [] for k in KINDS}
    for k in range(len(seq)):
        frame = seq[k]
        r = odo.step(frame.points, frame.timestamps, stamp=frame.stamp)
        if k < 3 or r.registration is None:
            continue  # the first frames start from rest and carry the first deskew
        true_motion = SE3.from_matrix(np.linalg.inv(truth[k - 1]) @ truth[k])
        d = (r.motion.inverse() @ true_motion).log()
        for kind in KINDS:
            c = np.asarray(getattr(r.registration.covariances, kind))
            if np.isfinite(c).all():
                nees[kind].append(float(d @ np.linalg.solve(c, d)))
    return nees


def main() -> None:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument(
        "--method",
        nargs="+",
        default=["gicp", "point_to_plane"],
        choices=["gicp", "point_to_plane"],
    )
    ap.add_argument("--scene", default="street", choices=["street", "tunnel"])
    ap.add_argument("--sensor", default="hdl64")
    ap.add_argument("--frames", type=int, default=50)
    args = ap.parse_args()
    print(f"# {args.scene}, {args.sensor}, {args.frames} frames; ideal 6")
    print("| method | kind | frames | mean NEES | median NEES |")
    print("|---|---|---:|---:|---:|")
    for method in args.method:
        nees = nees_per_kind(args.scene, args.sensor, args.frames, method)
        for kind, v in nees.items():
            print(f"| {method} | {kind} | {len(v)} | {np.mean(v):.2f} | {np.median(v):.2f} |")


if __name__ == "__main__":
    main()
