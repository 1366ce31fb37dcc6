"""The MbICP / CSM self-matching protocol on the 778 real laserazosSM3 scans.

Minguez, Montesano & Lamiraux (T-RO 2006), as in Censi's CSM harness: each scan is matched
against a copy of itself with σ = 1 cm range noise, displaced by a random offset (uniform in
±t, ±t, ±θ); the displacement is the exact ground truth. Reported per perturbation size: median
and 95th-percentile error, success rate (translation ≤ 2 cells and rotation ≤ 2 angular steps of
the correlative lattice) and time per match, for correlative (branch and bound, window ±0.2 m,
±45°), point-to-line ICP (``scanreg.register``, from the identity), NDT
(``scanreg.match_ndt``, from the identity) and correlative followed by ICP.

Run: ``.venv/bin/python benchmarks/mbicp_self_matching.py [--scans 200] [--data ../shared/data]``.
"""

from __future__ import annotations

import argparse
import math
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import scanreg
from scanreg import SE2
from scanreg.io import read_carmen

RESOLUTION = 0.03
ANGULAR = 0.01
LEVELS = [(0.05, 5.0), (0.1, 15.0), (0.2, 30.0), (0.2, 45.0)]


def correlative(src: Any, ref: Any) -> SE2:
    return scanreg.match_correlative(
        src,
        ref,
        window=(0.2, 0.2, math.radians(45)),
        resolution=RESOLUTION,
        angular_resolution=ANGULAR,
        search="branch_and_bound",
    ).pose


def point_to_line(src: Any, ref: Any) -> SE2:
    pose = scanreg.register(src, ref, method="point_to_line", max_correspondence_distance=0.5).pose
    assert isinstance(pose, SE2)
    return pose


def ndt(src: Any, ref: Any) -> SE2:
    return scanreg.match_ndt(src, ref, cell_size=1.0).pose


def correlative_then_icp(src: Any, ref: Any) -> SE2:
    init = correlative(src, ref)
    pose = scanreg.register(
        src, ref, method="point_to_line", init=init, max_correspondence_distance=3 * RESOLUTION
    ).pose
    assert isinstance(pose, SE2)
    return pose


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    here = Path(__file__).resolve().parent.parent
    default = Path(os.environ.get("SCANREG_DATA", here.parent / "shared" / "data"))
    parser.add_argument("--data", type=Path, default=default)
    parser.add_argument("--scans", type=int, default=200)
    args = parser.parse_args()
    log = read_carmen(args.data / "carmen-mbicp-laserazos" / "laserazosSM3.log")
    rng = np.random.default_rng(0)
    subset = rng.choice(len(log), min(args.scans, len(log)), replace=False)
    methods: dict[str, Callable[[Any, Any], SE2]] = {
        "correlative (BnB)": correlative,
        "point-to-line ICP": point_to_line,
        "NDT (1 m cells, 2 levels)": ndt,
        "correlative + point-to-line": correlative_then_icp,
    }
    print(f"laserazosSM3: {len(subset)} scans per row; success = |t| ≤ 6 cm and |θ| ≤ 1.15°")
    print(
        "| method | max offset | median \\|t\\| (m) | p95 \\|t\\| | median \\|θ\\| (°) "
        "| p95 \\|θ\\| | success | ms |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for max_t, max_deg in LEVELS:
        max_th = math.radians(max_deg)
        cases = []
        for i in subset:
            scan = log.scans[int(i)]
            mask = scan.valid(min_range=0.05)
            noisy = scan.ranges[mask] + rng.normal(0.0, 0.01, int(mask.sum()))
            ang = scan.angles[mask]
            copy = np.c_[noisy * np.cos(ang), noisy * np.sin(ang)]
            truth = SE2.from_vector(rng.uniform([-max_t, -max_t, -max_th], [max_t, max_t, max_th]))
            cases.append(
                (np.ascontiguousarray(truth.inverse().apply(copy)), scan.to_points(0.05), truth)
            )
        for name, fn in methods.items():
            errors = []
            t0 = time.perf_counter()
            for src, ref, truth in cases:
                e = (truth.inverse() @ fn(src, ref)).as_vector()
                errors.append([math.hypot(e[0], e[1]), abs(math.degrees(e[2]))])
            ms = (time.perf_counter() - t0) / len(cases) * 1e3
            err = np.array(errors)
            ok = np.mean((err[:, 0] <= 2 * RESOLUTION) & (err[:, 1] <= math.degrees(2 * ANGULAR)))
            med, p95 = np.median(err, axis=0), np.percentile(err, 95, axis=0)
            print(
                f"| {name} | {max_t} m, {max_deg:.0f}° | {med[0]:.4f} | {p95[0]:.4f} | "
                f"{med[1]:.3f} | {p95[1]:.3f} | {ok:.1%} | {ms:.1f} |"
            )


if __name__ == "__main__":
    main()
