"""Where the 2D corridor's lateral error comes from when the initial guess is off (issue 5).

The calibration table's "2D corridor, point_to_plane, prior" row misses (mean NEES 2.4 × dof):
this script repeats that protocol (``covariance_calibration.py``'s scene and motion prior,
``degeneracy_aware=True``) and prints, per axis, the RMS of error / reported σ (calibrated
covariance), the error spread against the median σ, and how the final lateral (y) and heading
errors correlate with the initial guess's error — the error the solve holds along the corridor.

    .venv/bin/python benchmarks/corridor_coupling.py [--realisations 60]
"""

from __future__ import annotations

import argparse

import numpy as np
import scanreg
from covariance_calibration import motion_prior, scene_named


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--realisations", type=int, default=60)
    args = ap.parse_args()
    scene, pose_b, truth = scene_named("2D corridor")
    prior = motion_prior(2)
    init_err, err, sigma, weak = [], [], [], []
    for k in range(args.realisations):
        src = scene.scan(scene.pose_a, 2 * k)
        target = scanreg.prepare(scene.scan(pose_b, 2 * k + 1))
        e0 = np.random.default_rng(10_000 + k).multivariate_normal(np.zeros(3), prior)
        res = scanreg.register(
            src,
            target,
            method="point_to_plane",
            init=truth @ type(truth).exp(e0),  # type: ignore[operator]
            init_covariance=prior,
            max_correspondence_distance=1.0,
            degeneracy_aware=True,
        )
        assert res.covariances is not None and res.degeneracy is not None
        init_err.append(e0)
        err.append((res.pose.inverse() @ truth).log())  # type: ignore[operator]
        sigma.append(np.sqrt(np.diag(res.covariances.calibrated)))
        if res.degeneracy.weak_directions:
            weak.append(np.abs(res.degeneracy.weak_directions[0].vector))
    e0s, es, ss = np.array(init_err), np.array(err), np.array(sigma)
    print(f"{args.realisations} realisations; axes x (along the corridor), y, θ")
    print("RMS(error / σ):        ", np.round(np.sqrt(np.mean((es / ss) ** 2, axis=0)), 2))
    print("error std (m, m, rad): ", np.round(es.std(axis=0), 5))
    print("median σ:              ", np.round(np.median(ss, axis=0), 5))
    for axis, name in ((1, "y"), (2, "θ")):
        corr = [np.corrcoef(es[:, axis], e0s[:, a])[0, 1] for a in range(3)]
        slope = np.polyfit(es[:, 0], es[:, axis], 1)[0]
        print(
            f"final {name} error: correlation with the initial x / y / θ error "
            f"{corr[0]:.2f} / {corr[1]:.2f} / {corr[2]:.2f}; slope against the final x error "
            f"{slope:.4f}"
        )
    if weak:
        w = np.median(np.array(weak), axis=0)
        print("weak eigenvector (median |components|):", np.round(w, 5))


if __name__ == "__main__":
    main()
