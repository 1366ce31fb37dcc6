"""Calibration of 2D loop-closure constraints against exact truth (issue 22).

Simulated office tours that come back through the same rooms (``sim.room_tour``, two rooms a
side, a SICK LMS200-like laser at 5 Hz, a noisy wheel-odometry prior), mapped with the default
``MappingConfig``. For every accepted loop edge, the error of its measured relative pose
against the true one, ``δ = log(T̂⁻¹ T_true)``, is scored against the covariance the edge
carries: NEES = ``δᵀ Σ⁻¹ δ`` (ideal mean 3, the dof; median 2.37). Also the per-axis RMS of
``δ_i / σ_i`` (ideal 1), false loops (accepted, error beyond 0.3 m / 3° outside a direction
the match named degenerate) and, among the accepted, loops between scans truly more than 6 m
apart (a room width: another room). ``identical_rooms=True`` makes every room the same room
(the false-loop trap).

``--without-submap-term`` repeats the runs with the loop covariance left at the match's own
(the submap's odometry spread not added), to show what that term does.

Run: ``.venv/bin/python benchmarks/loop_calibration.py [--seeds 0 1 2] [--without-submap-term]``.
"""

from __future__ import annotations

import argparse
import math
import time
from typing import Any

import numpy as np
from scanreg import simulate as sim
from scanreg.pipeline import mapping
from scanreg.pipeline.mapping import Mapper, MappingConfig

RATE = 5.0


def run(seed: int, identical: bool) -> dict[str, Any]:
    course = sim.room_tour(seed=seed, identical_rooms=identical, rooms_per_side=2)
    laser = sim.LaserModel.preset("sick_lms200")
    r = sim.simulate_run(
        course.scene,
        laser,
        course.trajectory,
        num_scans=course.num_scans(RATE),
        scan_rate=RATE,
        seed=seed,
    )
    truth = [r.poses[0].inverse() @ p for p in r.poses]
    mapper = Mapper(MappingConfig())
    cpu = time.process_time()
    for k, (scan, prior) in enumerate(
        zip(r.scans, sim.wheel_odometry(truth, np.random.default_rng(seed + 100)), strict=True)
    ):
        mapper.step(scan.points, prior=prior, stamp=k / RATE)
    res = mapper.finish()
    cpu = time.process_time() - cpu
    nees, normalized, false, elsewhere = [], [], 0, 0
    for rec in res.accepted_loops:
        true_rel = truth[rec.submap_scan].inverse() @ truth[rec.scan]
        d = (rec.match.measured.inverse() @ true_rel).log()
        cov = rec.match.covariance
        nees.append(float(d @ np.linalg.solve(cov, d)))
        normalized.append(d / np.sqrt(np.diag(cov)))
        w = rec.match.weak_vectors
        strong = d - w @ (w.T @ d) if w.shape[1] else d
        if np.linalg.norm(strong[:2]) > 0.3 or abs(strong[2]) > math.radians(3.0):
            false += 1
        if np.linalg.norm(true_rel.translation) > 6.0:
            elsewhere += 1
    positions = np.array([p.translation for p in res.poses])
    ate = float(np.sqrt(np.mean(np.sum((positions - [t.translation for t in truth]) ** 2, 1))))
    return {
        "seed": seed,
        "identical": identical,
        "scans": len(r.scans),
        "accepted": len(res.accepted_loops),
        "rejected": len(res.rejected_loops),
        "nees": np.array(nees),
        "normalized": np.array(normalized).reshape(-1, 3),
        "false": false,
        "elsewhere": elsewhere,
        "ate": ate,
        "cpu": cpu,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--without-submap-term", action="store_true")
    args = parser.parse_args()
    if args.without_submap_term:
        original = mapping.build_submap

        def without(*a: Any, **kw: Any) -> Any:
            kw.pop("covariances", None)
            return original(*a, **kw)

        mapping.build_submap = without  # type: ignore[assignment]
    rows = [run(s, identical) for identical in (False, True) for s in args.seeds]
    print(
        "| scene | seed | scans | loops accepted / rejected | false loops | into another room "
        "| mean NEES (ideal 3) "
        "| median NEES (ideal 2.37) | RMS δ/σ x, y, θ (ideal 1) | ATE (m) | CPU (s) |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        rms = np.sqrt((r["normalized"] ** 2).mean(axis=0))
        print(
            f"| {'identical rooms' if r['identical'] else 'room tour'} | {r['seed']} | "
            f"{r['scans']} | {r['accepted']} / {r['rejected']} | {r['false']} | {r['elsewhere']} | "
            f"{r['nees'].mean():.2f} | {np.median(r['nees']):.2f} | "
            f"{rms[0]:.2f}, {rms[1]:.2f}, {rms[2]:.2f} | {r['ate']:.3f} | {r['cpu']:.1f} |"
        )
    nees = np.concatenate([r["nees"] for r in rows])
    rms = np.sqrt((np.concatenate([r["normalized"] for r in rows]) ** 2).mean(axis=0))
    print(
        f"| **all** | | | {len(nees)} loops | {sum(r['false'] for r in rows)} | "
        f"{sum(r['elsewhere'] for r in rows)} | "
        f"**{nees.mean():.2f}** ({nees.mean() / 3:.2f}× ideal) | {np.median(nees):.2f} | "
        f"{rms[0]:.2f}, {rms[1]:.2f}, {rms[2]:.2f} | | |"
    )


if __name__ == "__main__":
    main()
