"""Which objective does each library's "point-to-plane" minimise? (the outdoor pair)

Run:

    .venv/bin/python benchmarks/plane_objective.py \
        [--peers-site /tmp/peers-venv/lib/python3.11/site-packages]

Every library gets the same inputs: the outdoor pair voxelised at 0.25 m by scanreg, target
normals from k = 20 neighbours (scanreg's; small_gicp estimates its own on the same points and
the script prints how well they agree; Open3D is handed scanreg's). From the identity, the
first Gauss–Newton step is computed here in plain numpy (brute-force nearest neighbours, gate
1.0 m) for two objectives:

* point-to-plane, one residual per correspondence: ``r = n·(R p + t − q)``;
* the per-axis product, three residuals per correspondence: ``r_k = n_k (q − R p − t)_k``,
  which is what small_gicp's ``PointToPlaneICPFactor`` linearises (``normal.array() *
  residual.array()``): it weighs each axis of the point-to-point error by that axis's normal
  component squared, so a tangential offset still pulls.

Each library's first step is then compared with both, and each is run to convergence (1e-3 m /
0.1°, at most 20 iterations) with the truncated point-to-plane cost of its final pose. The two
objectives have different minima; comparing iteration counts across them compares problems,
not solvers.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
import scanreg
from register_speed import DATA, load_pairs, load_peers
from scanreg import SE3
from scanreg import preprocess as pp

VOXEL, K, GATE = 0.25, 20, 1.0
T_EPS, R_EPS, MAX_IT = 1e-3, np.deg2rad(0.1), 20


def nearest(queries: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Brute-force nearest neighbours (an independent check of every library's k-d tree)."""
    idx = np.empty(len(queries), dtype=np.int64)
    dist = np.empty(len(queries))
    sq = np.sum(points**2, axis=1)
    for lo in range(0, len(queries), 512):
        q = queries[lo : lo + 512]
        d2 = np.sum(q**2, axis=1)[:, None] - 2.0 * q @ points.T + sq[None, :]
        j = np.argmin(d2, axis=1)
        idx[lo : lo + 512] = j
        dist[lo : lo + 512] = np.linalg.norm(q - points[j], axis=1)
    return idx, dist


def skew(v: np.ndarray) -> np.ndarray:
    """(N, 3) -> (N, 3, 3) cross-product matrices."""
    z = np.zeros(len(v))
    return np.stack(
        [
            np.stack([z, -v[:, 2], v[:, 1]], axis=1),
            np.stack([v[:, 2], z, -v[:, 0]], axis=1),
            np.stack([-v[:, 1], v[:, 0], z], axis=1),
        ],
        axis=1,
    )


def gauss_newton_steps(s: np.ndarray, t: np.ndarray, n: np.ndarray) -> dict[str, np.ndarray]:
    """First step from the identity, right perturbation ``T exp(δ)``, δ = [t, rotation]."""
    j, d = nearest(s, t)
    m = d < GATE
    p, q, nn = s[m], t[j[m]], n[j[m]]
    # Point-to-plane: d r / d δ = [nᵀ, (p × n)ᵀ] at the identity.
    jac = np.c_[nn, np.cross(p, nn)]
    r = np.sum((p - q) * nn, axis=1)
    plane = -np.linalg.solve(jac.T @ jac, jac.T @ r)
    # Per-axis product: e = diag(n) (q − p − δt + [p]× δω), three rows per correspondence.
    e = nn * (q - p)
    jt = -nn[:, :, None] * np.eye(3)[None]
    jr = nn[:, :, None] * skew(p)
    ja = np.concatenate([jt, jr], axis=2).reshape(-1, 6)
    axis = -np.linalg.solve(ja.T @ ja, ja.T @ e.reshape(-1))
    return {"point-to-plane": plane, "per-axis product": axis}


def plane_cost(pose: np.ndarray, s: np.ndarray, t: np.ndarray, n: np.ndarray) -> tuple[float, int]:
    """The truncated point-to-plane cost, mean over every source point of r² inside the gate and
    gate² outside (what the gated objective approximates, defined whichever points are gated),
    and the number inside."""
    q = s @ pose[:3, :3].T + pose[:3, 3]
    j, d = nearest(q, t)
    m = d < GATE
    r = np.sum((q[m] - t[j[m]]) * n[j[m]], axis=1)
    return float((np.sum(r**2) + (len(s) - m.sum()) * GATE**2) / len(s)), int(m.sum())


def fmt(delta: np.ndarray) -> str:
    return (
        f"t [{', '.join(f'{x * 100:6.2f}' for x in delta[:3])}] cm, "
        f"r [{', '.join(f'{np.degrees(x):6.3f}' for x in delta[3:])}]°"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--peers-site", default=None, help="site-packages holding the peers")
    args = ap.parse_args()
    peers = load_peers(args.peers_site)
    src, tgt, ref = load_pairs()["outdoor pair"]
    assert ref is not None
    s = pp.voxel_downsample(src, VOXEL).points
    t = pp.voxel_downsample(tgt, VOXEL).points
    prepared = scanreg.prepare(t, normals=True, num_neighbors=K)
    normals = np.asarray(prepared.normals)
    print(f"outdoor pair ({DATA.name}): {len(s)} source, {len(t)} target points after {VOXEL} m")

    steps = gauss_newton_steps(s, t, normals)
    print("\nFirst step from the identity (numpy reference):")
    for name, step in steps.items():
        print(f"  {name:17s} {fmt(step)}")

    def ours(iterations: int, eps: float = 1.0) -> scanreg.RegistrationResult:
        return scanreg.register(
            s,
            prepared,
            method="point_to_plane",
            max_correspondence_distance=GATE,
            max_iterations=iterations,
            translation_tolerance=T_EPS * eps,
            rotation_tolerance=R_EPS * eps,
            num_threads=1,
        )

    runs: list[tuple[str, np.ndarray, np.ndarray, str]] = []
    first = ours(1, eps=1e-9)
    res = ours(MAX_IT)
    runs.append(("scanreg", first.pose.log(), res.pose.as_matrix(), str(res.iterations)))

    sg = peers.get("small_gicp")
    if sg is not None:
        tp = sg.PointCloud(t)
        tree = sg.KdTree(tp, 1)
        sg.estimate_normals(tp, tree, K, 1)
        agree = np.abs(np.sum(np.asarray(tp.normals())[:, :3] * normals, axis=1))
        print(
            f"\nsmall_gicp's normals against scanreg's: median |cos| {np.median(agree):.6f}, "
            f"{np.mean(agree < 0.99) * 100:.2f} % below 0.99"
        )
        sp = sg.PointCloud(s)

        def theirs(iterations: int, eps: float = 1.0) -> object:
            return sg.align(
                tp,
                sp,
                tree,
                registration_type="PLANE_ICP",
                max_correspondence_distance=GATE,
                num_threads=1,
                max_iterations=iterations,
                rotation_epsilon=R_EPS * eps,
                translation_epsilon=T_EPS * eps,
            )

        one = SE3.from_matrix(theirs(1, 1e-9).T_target_source, atol=1e-6).log()  # type: ignore[attr-defined]
        full = theirs(MAX_IT)
        # small_gicp reports the 0-based index of its last iteration.
        runs.append(("small_gicp", one, full.T_target_source, str(full.iterations + 1)))  # type: ignore[attr-defined]

    o3d = peers.get("open3d")
    if o3d is not None:
        reg = o3d.pipelines.registration
        ps = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.array(s)))
        pt = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.array(t)))
        pt.normals = o3d.utility.Vector3dVector(np.array(normals))

        def o3d_run(iterations: int) -> np.ndarray:
            crit = reg.ICPConvergenceCriteria(
                relative_fitness=0.0, relative_rmse=0.0, max_iteration=iterations
            )
            out = reg.registration_icp(
                ps, pt, GATE, np.eye(4), reg.TransformationEstimationPointToPlane(), crit
            )
            return np.asarray(out.transformation)

        one = SE3.from_matrix(o3d_run(1), atol=1e-6).log()
        crit = reg.ICPConvergenceCriteria(max_iteration=MAX_IT)
        full = reg.registration_icp(
            ps, pt, GATE, np.eye(4), reg.TransformationEstimationPointToPlane(), crit
        )
        runs.append(("open3d", one, np.asarray(full.transformation), "n/a"))

    print(
        "\n| library | first step | matches | iterations | vs reference | "
        "truncated point-to-plane cost at the end (mean, cm²) |"
    )
    print("|---|---|---|---|---|---|")
    for name, step, final, its in runs:
        dist = {k: float(np.linalg.norm(step - v)) for k, v in steps.items()}
        match = min(dist, key=lambda k: dist[k])
        d = (ref.inverse() @ SE3.from_matrix(final, atol=1e-5)).log()
        cost, m = plane_cost(final, s, t, normals)
        print(
            f"| {name} | {fmt(step)} | {match} (|Δ| {dist[match]:.1e}) | {its} | "
            f"{np.linalg.norm(d[:3]) * 100:.2f} cm / {np.degrees(np.linalg.norm(d[3:])):.3f}° | "
            f"{cost * 1e4:.1f} ({m} inside the gate) |"
        )
    sys.stdout.flush()


if __name__ == "__main__":
    main()
