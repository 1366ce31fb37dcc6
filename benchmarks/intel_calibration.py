"""Normalised errors of scanreg's 2D covariances on real laser data: the Intel lab relations.

Each local Kümmerle relation (``|t2 − t1| < 60 s``; reference poses from manually verified
alignments, see ``../shared/data/carmen-intel/README.md``) whose two scans are in the subset is
matched directly: scan ``t2`` (source) against scan ``t1`` (target), the wheel odometry as the
guess, correlative branch and bound (±0.3 m, ±10°, 5 cm) then ``register`` point-to-line.
For the pairs the verdict accepts, the error ``δ = log(T̂⁻¹ · T_ref)`` (right perturbation,
``[tx, ty, θ]``) is normalised by each covariance kind: mean and median NEES (calibrated: 3, the
95 % band of the mean given below), per-axis RMS of ``δᵢ/σᵢ`` (1 = calibrated), and the share
of pairs inside the 95 % χ²(3) bound (7.81).

The reference relations have errors of their own (a few cm / tenths of a degree); where they
dominate, the normalised errors overstate the miscalibration — the errors in metres are
printed next to them to judge that.

    .venv/bin/python benchmarks/intel_calibration.py [--data ../shared/data] [--method gicp]
"""

from __future__ import annotations

import argparse
import math
import os
from pathlib import Path

import numpy as np
import scanreg
from scanreg import SE2
from scanreg.eval.relations import read_relations
from scanreg.io import read_carmen

KINDS = ("hessian", "censi", "block", "calibrated")
LOCAL_SECONDS = 60.0
CHI2_3_95 = 7.815


def _scan_index(stamps: np.ndarray, t: float) -> int:
    k = int(np.argmin(np.abs(stamps - t)))
    return k if abs(stamps[k] - t) <= 1e-4 else -1


def _se2(m: np.ndarray) -> SE2:
    """The planar part of a 4x4 relation."""
    out = np.eye(3)
    out[:2, :2] = m[:2, :2]
    out[:2, 2] = m[:2, 3]
    return SE2.from_matrix(out)


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    here = Path(__file__).resolve().parent.parent
    default = Path(os.environ.get("SCANREG_DATA", here.parent / "shared" / "data"))
    parser.add_argument("--data", type=Path, default=default)
    parser.add_argument("--method", default="point_to_line")
    args = parser.parse_args()
    folder = args.data / "carmen-intel"
    log = read_carmen(folder / "intel_gfs_subset_clf_timestamps.clf")
    relations = read_relations(folder / "intel_gfs_subset.relations")
    stamps = np.array([s.timestamp for s in log.scans])
    points = [s.to_points(0.1, 40.0) for s in log.scans]

    deltas: list[np.ndarray] = []
    covs: dict[str, list[np.ndarray]] = {k: [] for k in KINDS}
    tried = rejected = 0
    for t1, t2, rel in zip(relations.t1, relations.t2, relations.poses, strict=True):
        i, j = _scan_index(stamps, t1), _scan_index(stamps, t2)
        if i < 0 or j < 0 or abs(t2 - t1) >= LOCAL_SECONDS:
            continue
        tried += 1
        guess = log.motion_prior(i, j)
        coarse = scanreg.match_correlative(
            points[j],
            points[i],
            init=guess,
            window=(0.3, 0.3, math.radians(10)),
            resolution=0.05,
            search="branch_and_bound",
        )
        res = scanreg.register(
            points[j],
            points[i],
            method=args.method,
            init=coarse.pose,
            max_correspondence_distance=0.3,
            kernel="huber",
        )
        if res.verdict is None or not res.verdict.accepted:
            rejected += 1
            continue
        est = res.pose
        assert isinstance(est, SE2)
        deltas.append((est.inverse() @ _se2(rel)).log())
        for k in KINDS:
            covs[k].append(np.asarray(getattr(res.covariances, k)))

    n = len(deltas)
    d = np.array(deltas)
    print(
        f"# Intel subset, {args.method}: {tried} local relations with both scans, "
        f"{rejected} rejected by the verdict, {n} evaluated"
    )
    if n == 0:
        return
    # Band of the mean of n χ²(3) values (normal approximation: variance 2·3/n).
    half = 1.96 * math.sqrt(2 * 3 / n)
    print(
        f"# |error| median {np.median(np.hypot(d[:, 0], d[:, 1])) * 100:.1f} cm, "
        f"{np.degrees(np.median(np.abs(d[:, 2]))):.2f} deg; mean NEES 95 % band "
        f"{3 - half:.2f}-{3 + half:.2f}"
    )
    print(
        "| kind | mean NEES | median NEES | RMS δ/σ: tx / ty / θ | inside χ²(3) 95 % "
        "| σ scale for mean NEES 3 |"
    )
    print("|---|---:|---:|---|---:|---:|")
    for k in KINDS:
        c = np.array(covs[k])
        ok = np.isfinite(c).all(axis=(1, 2))
        nees = np.array([di @ np.linalg.solve(ci, di) for di, ci in zip(d[ok], c[ok], strict=True)])
        z = d[ok] / np.sqrt(np.einsum("kii->ki", c[ok]))
        rms = np.sqrt(np.mean(z**2, axis=0))
        sig = np.median(np.sqrt(np.einsum("kii->ki", c[ok])), axis=0)
        print(
            f"# {k}: median σ {sig[0] * 1e3:.1f} / {sig[1] * 1e3:.1f} mm, "
            f"{np.degrees(sig[2]):.3f} deg"
        )
        print(
            f"| {k} | {nees.mean():.2f} | {np.median(nees):.2f} | "
            f"{rms[0]:.2f} / {rms[1]:.2f} / {rms[2]:.2f} | {np.mean(nees <= CHI2_3_95):.2f} "
            f"| {math.sqrt(nees.mean() / 3):.2f} |"
        )


if __name__ == "__main__":
    main()
