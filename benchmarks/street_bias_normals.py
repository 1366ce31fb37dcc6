"""Where the simulated street's point-to-plane bias comes from: which normals, and which pairs.

Run:

    .venv/bin/python benchmarks/street_bias_normals.py [--realisations 6]

The 3D street of ``covariance_calibration.py`` (VLP-16, 0.3 m voxels, a 0.5 m / 2° step).
Each realisation registers the source to the target with scanreg's point-to-plane. From that
pose, a Gauss–Newton refinement in plain numpy re-solves one variant of the objective (nearest
neighbours inside the 1 m gate, 15 iterations at most), and the script prints its error:

* ``target``: the target's normals, i.e. scanreg's objective. It reproduces scanreg's pose,
  which checks the refinement;
* ``source``: the source's normals, rotated;
* ``symmetric``: their sign-aligned mean (Rusinkiewicz 2019);
* ``agree>c``: the target's normals, keeping only the pairs whose source and target normals
  agree, ``|n_s · n_t| >= c``.

GICP is printed for comparison. The point: which normal is used does not matter, and the bias
stays. Dropping the pairs whose two normals disagree removes it, down to GICP's level. Those
are the neighbourhoods (rings, poles) where PCA picks a normal at random, and GICP's combined
covariance weighs such pairs down by itself.
"""

from __future__ import annotations

import argparse

import numpy as np
import scanreg
from covariance_calibration import scene_named
from scanreg import SE3

VARIANTS = ("target", "source", "symmetric", "agree>0.95", "agree>0.99", "agree>0.995")


def refine(
    src: np.ndarray,
    target: scanreg.PreparedTarget,
    src_normals: np.ndarray,
    pose: SE3,
    variant: str,
    iterations: int = 15,
) -> SE3:
    """Gauss–Newton on ``variant`` from ``pose`` (right perturbation, translation first)."""
    tgt, nt_all = target.points, target.normals
    assert nt_all is not None
    for _ in range(iterations):
        r_mat, t = pose.rotation, pose.translation
        moved = src @ r_mat.T + t
        near = target.nearest(moved, 1.0)
        j = near.indices
        ok = (j >= 0) & (np.linalg.norm(src_normals, axis=1) > 0)
        ok[ok] &= np.linalg.norm(nt_all[j[ok]], axis=1) > 0
        p, q, s = moved[ok], tgt[j[ok]], src[ok]
        nt, ns = nt_all[j[ok]], src_normals[ok] @ r_mat.T
        agree = np.abs(np.sum(ns * nt, axis=1))
        if variant == "source":
            n = ns
        elif variant == "symmetric":
            sign = np.where(np.sum(ns * nt, axis=1) < 0, -1.0, 1.0)
            n = nt + sign[:, None] * ns
            n /= np.linalg.norm(n, axis=1)[:, None]
        else:
            n = nt
        keep = (
            agree >= float(variant[6:]) if variant.startswith("agree>") else np.ones(len(p), bool)
        )
        r = np.sum((p - q) * n, axis=1)[keep]
        rn = (n @ r_mat)[keep]  # d r / d δt = nᵀR, d r / d δω = (s × Rᵀn)ᵀ
        jac = np.c_[rn, np.cross(s[keep], rn)]
        step = -np.linalg.lstsq(jac, r, rcond=None)[0]
        pose = pose @ SE3.exp(step)
        if np.linalg.norm(step) < 1e-7:
            break
    return pose


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--realisations", type=int, default=6)
    args = ap.parse_args()
    scene, pose_b, truth = scene_named("3D street")
    errors: dict[str, list[np.ndarray]] = {k: [] for k in ("scanreg", *VARIANTS, "gicp")}
    for k in range(args.realisations):
        src = scene.scan(scene.pose_a, 2 * k)
        tgt = scene.scan(pose_b, 2 * k + 1)
        target = scanreg.prepare(tgt, covariances=True)
        res = scanreg.register(
            src, target, method="point_to_plane", max_correspondence_distance=1.0
        )
        assert isinstance(res.pose, SE3)
        src_normals = np.asarray(scanreg.prepare(src).normals)
        errors["scanreg"].append((res.pose.inverse() @ truth).log())
        for v in VARIANTS:
            errors[v].append(
                (refine(src, target, src_normals, res.pose, v).inverse() @ truth).log()
            )
        g = scanreg.register(src, target, method="gicp", max_correspondence_distance=1.0)
        errors["gicp"].append((g.pose.inverse() @ truth).log())  # type: ignore[operator]
    print(f"3D street, {args.realisations} realisations: mean error (estimate to truth)")
    print("| objective | x cm | y cm | z cm | roll mdeg | pitch mdeg | yaw mdeg |")
    print("|---|---|---|---|---|---|---|")
    for name, e in errors.items():
        m = np.mean(np.array(e), axis=0)
        print(
            f"| {name} | {m[0] * 100:+.2f} | {m[1] * 100:+.2f} | {m[2] * 100:+.2f} | "
            + " | ".join(f"{np.degrees(x) * 1e3:+.0f}" for x in m[3:])
            + " |"
        )


if __name__ == "__main__":
    main()
