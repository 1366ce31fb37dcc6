"""Is the reported covariance calibrated? Monte Carlo NEES on simulated scenes with exact truth.

For each scene and method: R realisations of two independent scans taken from poses A and B
(B = A moved by a small known step, fresh range noise, dropouts and sampling each time);
register source (A) to target (B); error ``δ = log(T_est⁻¹ T_true)`` in scanreg's tangent
convention; ``NEES = δᵀ Σ⁻¹ δ`` for every covariance kind of the result. A calibrated
covariance gives mean NEES ≈ dof (3 in 2D, 6 in 3D), inside the printed 95 % band.

Protocols (``--protocols``, default ``identity prior``):

* ``identity``: registered from the identity, default settings (the gate-wide prior is used
  along degenerate directions); ``identity-aware``: the same with ``degeneracy_aware=True``;
* ``prior``: the initial guess is drawn around the truth from a motion prior
  ``P = diag(0.1² m², …, (1°)², …)``, passed as ``init_covariance``, with
  ``degeneracy_aware=True`` (the estimate keeps the prior along weak directions);
* ``gate``: the initial guess drawn from the law the default call assumes without
  ``init_covariance`` — uniform within ±δ per translation axis and ±δ/L_a per rotation axis
  (the gate-wide prior ``diag(δ², …, (δ/L_a)², …) / 3``, δ = 1 m) — and no covariance
  passed. ``identity`` samples one point of that law (the fixed step, 0.3 m / 0.5 m along a
  corridor's / tunnel's axis against σ = 0.58 m); ``gate`` tests the default along weak
  directions over the law it states. Run in the corridor and the tunnel only: elsewhere
  nothing reports that prior, and starts a gate away test the basin instead.
* ``identity-law``: the identity protocol with the true step *along the scene's axis* drawn
  from that same stated law, uniform within ±δ (δ = 1 m) instead of the fixed 0.3 m / 0.5 m;
  the rest of the step, the start (the identity) and the call as ``identity``. From the
  identity the estimate stays (corridor) or locks (tunnel) along the axis, so the error there
  is the step, and every term that carries the weak axis's variance across it (the tilt,
  the axis cover) is scaled by the stated σ_w = 0.58 m while the fixed step is 0.3 m: the
  ``identity`` row measures that mismatch on every axis, not only along the weak one
  (``docs/calibration.md``). This row judges the default call from the identity; the
  ``identity`` row stays printed. Weak-axis scenes only.

Per row, the NEES is also split by axis (``weak`` / ``rest`` in the JSON rows and the
printed table): in the scaled coordinates of the result's degeneracy analysis, with ``W``
its weak eigenvectors and ``U`` the others, ``NEES = z_wᵀ C_ww⁻¹ z_w + (z_u|z_w)ᵀ C_u|w⁻¹
(z_u|z_w)`` exactly — the weak directions' marginal part, and the rest given them. ``weak``
is the mean of the first per weak direction (over the results flagged degenerate), ``rest``
of the second per remaining dof (over all results): each is 1 when calibrated.

``--randomise-pose``: the sensor pose A is moved per realisation by a uniform offset of
±0.15 m in x and y and ±0.05 rad (±2.9°) of yaw (the step A→B, hence the truth, is unchanged).
Without it every realisation sees the scene from the same pose: the voxel grid falls on the
same place of every wall and a corridor is exactly along the sensor's x axis, so one
configuration is sampled 200 times; with it the grid's phase and the scene's heading are part
of the sampling, as they are for a robot.

    .venv/bin/python benchmarks/covariance_calibration.py [--realisations 200] [--quick]
        [--methods point_to_plane gicp] [--scenes "2D room" ...] [--json out.json]
        [--drop-linear] [--randomise-pose] [--protocols identity prior gate]

Scenes: 2D square room, 2D long corridor (degenerate along x), 3D street, 3D tunnel
(degenerate along x). Also printed: how often each scene was flagged degenerate.

``--split-beam [--pairs N] [--sets ...]``: instead, real geometry with exact truth. 2D: a real
scan of Intel (the CARMEN subset and the Freiburg benchmark's full log), MbICP, ACES or the
Freiburg hospital split into its even beams (target) and its odd beams (source), the odd half
re-noised by 1 cm along the beam and moved by a random known transform (≤ 0.2 m, ≤ 3°); 3D: a
KITTI frame or the outdoor pair's source split into two random halves (voxel 0.5 m after
moving), one re-noised by 2 cm and moved (≤ 0.2 m, ≤ 3° yaw, ≤ 1° roll/pitch). Registered from
the identity with the default call; prints mean NEES per covariance kind over the accepted
results and the share outside χ²(dof) at 99.9 %.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

os.environ.setdefault("RAYON_NUM_THREADS", "2")

import numpy as np
import scanreg
from scanreg import SE2, SE3
from scanreg import simulate as sim
from scanreg.quality import nees_band

sys.path.insert(0, os.path.dirname(__file__))
from radish_mapping import LOGS as RADISH  # the same 13 logs

KINDS = ("hessian", "censi", "block", "calibrated")


@dataclass(frozen=True)
class Scene:
    name: str
    dim: int
    scan: Callable[[object, int], np.ndarray]  # (pose, seed) -> points in the sensor frame
    pose_a: SE2 | SE3
    step: SE2 | SE3  # T_A_B
    #: Degenerate along an axis: the ``gate`` protocol runs here only (elsewhere the gate-wide
    #: prior is not reported, and starts a gate away measure the basin, not the covariance).
    weak_axis: bool = False


def scenes() -> list[Scene]:
    laser = sim.LaserModel.preset("laser_360")
    lidar = sim.LidarModel.preset("vlp16")
    room, corridor = sim.square_room(5.0), sim.corridor(length=200.0, width=3.0)
    street, tunnel = sim.street(seed=4), sim.tunnel()

    def scan2d(scene: object) -> Callable[[object, int], np.ndarray]:
        return lambda pose, seed: np.ascontiguousarray(
            sim.simulate_scan(scene, laser, pose, seed=seed).points  # type: ignore[arg-type]
        )

    def sweep3d(scene: object) -> Callable[[object, int], np.ndarray]:
        def run(pose: object, seed: int) -> np.ndarray:
            pts = sim.simulate_sweep(scene, lidar, pose, seed=seed).points  # type: ignore[arg-type]
            return scanreg.preprocess.voxel_downsample(np.ascontiguousarray(pts), 0.3).points

        return run

    step2 = SE2.from_vector([0.3, 0.1, np.deg2rad(2.0)])
    step3 = SE3.from_vector([0.5, 0.1, 0.0, 0.0, 0.0, np.deg2rad(2.0)])
    return [
        Scene("2D room", 2, scan2d(room), SE2.from_vector([0.5, 0.3, 0.3]), step2),
        Scene("2D corridor", 2, scan2d(corridor), SE2.from_vector([100.0, 0.0, 0.0]), step2, True),
        Scene("3D street", 3, sweep3d(street), SE3.from_vector([0, 1.75, 1.73, 0, 0, 0]), step3),
        Scene("3D tunnel", 3, sweep3d(tunnel), SE3.from_vector([0, 0, 1.8, 0, 0, 0]), step3, True),
    ]


def scene_named(name: str) -> tuple[Scene, SE2 | SE3, SE2 | SE3]:
    """The scene ``name``, the target's pose ``B = A · step`` and the truth ``T_B_A``."""
    scene = next(s for s in scenes() if s.name == name)
    return scene, scene.pose_a @ scene.step, scene.step.inverse()  # type: ignore[operator]


def motion_prior(dim: int) -> np.ndarray:
    dof = 3 if dim == 2 else 6
    return np.diag([0.1**2] * dim + [np.deg2rad(1.0) ** 2] * (dof - dim))


def sensor_pose(scene: Scene, k: int, randomise: bool) -> SE2 | SE3:
    """Pose A of realisation ``k``: the scene's, or moved by ±0.15 m in x, y and ±0.05 rad
    of yaw (seeded by ``k``)."""
    if not randomise:
        return scene.pose_a
    rng = np.random.default_rng(20_000 + k)
    x, y, yaw = rng.uniform(-0.15, 0.15), rng.uniform(-0.15, 0.15), rng.uniform(-0.05, 0.05)
    if scene.dim == 2:
        return scene.pose_a @ SE2.from_vector([x, y, yaw])  # type: ignore[operator]
    return scene.pose_a @ SE3.from_vector([x, y, 0.0, 0.0, 0.0, yaw])  # type: ignore[operator]


def gate_law_start(truth: SE2 | SE3, source: np.ndarray, rng: np.random.Generator) -> SE2 | SE3:
    """An initial guess drawn from the default call's own prior: uniform within ±δ per
    translation axis and ±δ/L_a per rotation axis (δ = 1 m, the benchmark's gate; L_a the
    source's RMS lever about axis ``a``), i.e. the gate-wide ``diag(δ², …, (δ/L_a)², …) / 3``
    that ``register`` reports along weak directions when no ``init_covariance`` is given."""
    dof = 3 if source.shape[1] == 2 else 6
    gate_prior = np.asarray(scanreg._core.trust_scene(np.ascontiguousarray(source), 1.0)[3])
    half = np.sqrt(3.0 * np.diag(gate_prior.reshape(dof, dof)))
    return truth @ type(truth).exp(rng.uniform(-half, half))  # type: ignore[operator, attr-defined]


def law_step(scene: Scene, rng: np.random.Generator) -> SE2 | SE3:
    """The scene's step with its component along the sensor's x axis (the corridor's and the
    tunnel's axis, within the ±2.9° of a randomised pose) drawn uniform within ±δ, δ = 1 m:
    the law the default call states along a weak axis without ``init_covariance``."""
    dof = 3 if scene.dim == 2 else 6
    along = np.zeros(dof)
    along[0] = rng.uniform(-1.0, 1.0) - float(scene.step.translation[0])
    return type(scene.step).from_vector(along) @ scene.step  # type: ignore[operator, attr-defined, return-value]


def nees_split(
    error: np.ndarray, covariance: np.ndarray, degeneracy: scanreg.Degeneracy
) -> tuple[float, float, int]:
    """``(weak, rest, k)``: the NEES of ``error`` under ``covariance`` split exactly into the
    marginal part along the ``k`` weak directions of ``degeneracy`` and the rest given them
    (scaled coordinates, see the module docstring); ``weak`` is 0 when ``k`` is 0."""
    s_inv = degeneracy.scaling()
    basis = np.hstack([degeneracy.weak_basis(), degeneracy.strong_basis()])  # orthonormal
    z = basis.T @ (error / s_inv)
    c = basis.T @ (covariance / np.outer(s_inv, s_inv)) @ basis
    k = degeneracy.weak_basis().shape[1]
    total = float(z @ np.linalg.solve(c, z))
    weak = float(z[:k] @ np.linalg.solve(c[:k, :k], z[:k])) if k else 0.0
    return weak, total - weak, k


def run_scene(
    scene: Scene,
    method: str,
    reps: int,
    protocol: str,
    drop_linear: bool = False,
    randomise_pose: bool = False,
) -> dict[str, object]:
    """Mean NEES per covariance kind over ``reps`` realisations (seeded: realisation k uses
    scan seeds 2k, 2k+1 and init seed k)."""
    dof = 3 if scene.dim == 2 else 6
    truth = scene.step.inverse()  # T_target_source = T_B_A
    prior = motion_prior(scene.dim)
    nees: dict[str, list[float]] = {k: [] for k in KINDS}
    flagged = 0
    weak_names: dict[str, int] = {}
    abs_err = []
    weak_parts: list[float] = []
    rest_parts: list[float] = []
    for k in range(reps):
        pose_a = sensor_pose(scene, k, randomise_pose)
        src = scene.scan(pose_a, 2 * k)
        step = scene.step
        if protocol == "identity-law":
            step = law_step(scene, np.random.default_rng(40_000 + k))
            truth = step.inverse()
        tgt = scene.scan(pose_a @ step, 2 * k + 1)  # type: ignore[operator]
        target = scanreg.prepare(tgt, covariances=method == "gicp", drop_linear=drop_linear)
        if protocol == "prior":
            rng = np.random.default_rng(10_000 + k)
            init = truth @ type(truth).exp(rng.multivariate_normal(np.zeros(dof), prior))  # type: ignore[operator]
            res = scanreg.register(
                src,
                target,
                method=method,  # type: ignore[arg-type]
                init=init,
                init_covariance=prior,
                max_correspondence_distance=1.0,
                degeneracy_aware=True,
            )
        elif protocol == "gate":
            res = scanreg.register(
                src,
                target,
                method=method,  # type: ignore[arg-type]
                init=gate_law_start(truth, src, np.random.default_rng(30_000 + k)),
                max_correspondence_distance=1.0,
            )
        else:
            res = scanreg.register(
                src,
                target,
                method=method,  # type: ignore[arg-type]
                max_correspondence_distance=1.0,
                degeneracy_aware=protocol == "identity-aware",
            )
        d = (res.pose.inverse() @ truth).log()  # type: ignore[operator]
        abs_err.append(np.abs(d))
        assert res.covariances is not None and res.degeneracy is not None
        for kind in KINDS:
            cov = getattr(res.covariances, kind)
            try:
                nees[kind].append(float(d @ np.linalg.solve(cov, d)))
            except np.linalg.LinAlgError:
                nees[kind].append(float("inf"))
        weak, rest, nw = nees_split(d, np.asarray(res.covariances.calibrated), res.degeneracy)
        rest_parts.append(rest / (dof - nw))
        if nw:
            weak_parts.append(weak / nw)
        if res.degeneracy.degenerate:
            flagged += 1
            for w in res.degeneracy.weak_directions:
                weak_names[w.description] = weak_names.get(w.description, 0) + 1
    lo, hi = nees_band(dof, reps)
    return {
        "scene": scene.name,
        "method": method,
        "protocol": protocol,
        "randomised_pose": randomise_pose,
        "realisations": reps,
        "dof": dof,
        "band": [lo, hi],
        "mean_nees": {k: float(np.mean(v)) for k, v in nees.items()},
        # calibrated's NEES split by axis (module docstring): per weak direction, per other dof
        "weak": float(np.mean(weak_parts)) if weak_parts else None,
        "rest": float(np.mean(rest_parts)),
        "flagged": flagged,
        "weak_directions": weak_names,
        "median_abs_error": np.median(np.array(abs_err), axis=0).tolist(),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--realisations", type=int, default=200)
    parser.add_argument("--quick", action="store_true", help="20 realisations (a smoke run)")
    parser.add_argument(
        "--methods", nargs="+", default=["point_to_point", "point_to_plane", "gicp"]
    )
    parser.add_argument("--scenes", nargs="+", default=None)
    parser.add_argument(
        "--protocols",
        nargs="+",
        default=["identity", "prior"],
        choices=["identity", "identity-aware", "prior", "gate", "identity-law"],
    )
    parser.add_argument("--json", default=None, help="also write the rows to this file")
    parser.add_argument(
        "--drop-linear",
        action="store_true",
        help="targets without normals at linear 3D neighbourhoods (scanreg.prepare)",
    )
    parser.add_argument(
        "--randomise-pose",
        action="store_true",
        help="move the sensor per realisation (±0.15 m, ±2.9° yaw; see the docstring)",
    )
    parser.add_argument(
        "--markdown-from", default=None, help="only print the table of a --json file"
    )
    parser.add_argument("--split-beam", action="store_true", help="real split-beam pairs")
    parser.add_argument("--pairs", type=int, default=40, help="--split-beam: pairs per set")
    parser.add_argument(
        "--sets",
        nargs="*",
        default=None,
        help="--split-beam: only these sets (intel mbicp freiburg-intel aces hospital "
        "radish-NAME for each of RADISH, kitti outdoor; default all)",
    )
    parser.add_argument(
        "--halves",
        choices=HALVES,
        default="parity",
        help="--split-beam, 2D: halve a scan into even and odd beams or alternate pairs of "
        "beams (see HALVES)",
    )
    parser.add_argument(
        "--halves-offset",
        action="store_true",
        help="2D split-beam sets: how far apart the two halves of a scan are (halves_offset)",
    )
    args = parser.parse_args()
    if args.halves_offset:
        print(
            "| set | halves | scans | median abs offset (deg) | within 0.125 deg "
            "| correlation with the turn |"
        )
        print("|---|---|---:|---:|---:|---:|")
        for name in SPLIT_BEAM_2D:
            if args.sets and name not in args.sets:
                continue
            off, turn = halves_offset(name, args.pairs, args.halves)
            both = np.isfinite(turn)
            corr = (
                np.corrcoef(off[both], turn[both])[0, 1]
                if both.sum() > 2 and np.std(off[both]) > 0 and np.std(turn[both]) > 0
                else float("nan")
            )
            print(
                f"| {name} | {args.halves} | {len(off)} | {np.median(np.abs(off)):.3f} | "
                f"{np.mean(np.abs(off) <= 0.125):.0%} | {corr:.2f} |",
                flush=True,
            )
        return
    if args.split_beam:
        split_beam(args.pairs, args.methods, args.sets, args.halves)
        return
    if args.markdown_from:
        with open(args.markdown_from) as f:
            print(markdown_table(json.load(f)))
        return
    reps = 20 if args.quick else args.realisations
    rows = []
    print(f"{reps} realisations per row; mean NEES (dof: 3 in 2D, 6 in 3D)\n")
    print(
        f"{'scene':<12} {'method':<15} {'protocol':<9} {'band':>13} "
        + " ".join(f"{k:>10}" for k in KINDS)
        + "   weak   rest  flagged  weak directions"
    )
    for scene in scenes():
        if args.scenes and scene.name not in args.scenes:
            continue
        for method in args.methods:
            for protocol in args.protocols:
                if protocol in ("gate", "identity-law") and not scene.weak_axis:
                    continue
                row = run_scene(
                    scene, method, reps, protocol, args.drop_linear, args.randomise_pose
                )
                rows.append(row)
                lo, hi = row["band"]  # type: ignore[misc]
                means = row["mean_nees"]
                weak = "–" if row["weak"] is None else f"{row['weak']:.2f}"
                print(
                    f"{scene.name:<12} {method:<15} {protocol:<9} {lo:6.2f}–{hi:<6.2f} "
                    + " ".join(f"{means[k]:10.3g}" for k in KINDS)  # type: ignore[index]
                    + f" {weak:>6} {row['rest']:6.2f}"
                    + f"  {row['flagged']:>3}/{reps}  {row['weak_directions']}",
                    flush=True,
                )
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=1)
    print("\n" + markdown_table(rows))


CHI2_999 = {3: 16.266, 6: 22.458}


#: The 2D split-beam sets: log file under the data folder and the laser message it reads.
SPLIT_BEAM_2D = {
    "intel": ("carmen-intel/intel_gfs_subset_clf_timestamps.clf", "FLASER"),
    "mbicp": ("carmen-mbicp-laserazos/laserazosSM3.log", None),
    "freiburg-intel": ("freiburg-slam-benchmark/intel.clf.bz2", "FLASER"),
    "aces": ("freiburg-slam-benchmark/aces.clf.bz2", "FLASER"),
    "hospital": ("freiburg-slam-benchmark/fr-clinic_robotlaser.clf.bz2", "ROBOTLASER1"),
}
#: Buildings and lasers the defaults were never chosen on: the 13 Radish "corrected" logs
#: (180-, 181-, 360- and 361-beam 180° lasers; ``radish_mapping.py``).
SPLIT_BEAM_2D.update(
    {f"radish-{n}": (f"carmen-radish-corrected/{n}-corrected.log.gz", "FLASER") for n in RADISH}
)
#: How a scan is halved: even and odd beams, or alternate pairs of beams (0–1 and 2–3 of
#: every four). A 0.5° laser that interlaces two 1° sweeps puts one sweep in the even
#: beams and the other in the odd ones: if they disagree, the parity halves are not one
#: scene seen twice (the "exact truth" is not), while each pair holds one beam of either.
HALVES = ("parity", "pairs")


def _halves(n: int, halves: str) -> np.ndarray:
    """True for the target half's beams."""
    idx = np.arange(n)
    first: np.ndarray = idx % 2 == 0 if halves == "parity" else (idx // 2) % 2 == 0
    return first


def _halved_scans(
    name: str, count: int, halves: str
) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]]:
    """``(ranges, angles, target half, source half, turn)`` of ``count`` scans spread over a
    2D set, the halves as beam masks (valid returns only, at least 40 each); ``turn`` the
    log's own heading change (deg) from the scan before to the scan after (NaN where the log
    carries no poses)."""
    from scanreg.io import read_scans

    data = os.environ.get(
        "SCANREG_DATA", os.path.join(os.path.dirname(__file__), "../../shared/data")
    )
    path, kind = SPLIT_BEAM_2D[name]
    log = read_scans(os.path.join(data, path))
    scans = log.scans if kind is None else log.laser(kind)
    for i in np.linspace(0, len(scans) - 1, count).round().astype(int):
        scan = scans[int(i)]
        valid = scan.valid(min_range=0.1, max_range=40.0)
        r, a = scan.ranges, scan.angles
        first = _halves(len(r), halves)
        even, odd = valid & first, valid & ~first
        if even.sum() >= 40 and odd.sum() >= 40:
            yield r, a, even, odd, _turn(scans, int(i))


def _turn(scans: Sequence[Any], i: int) -> float:
    """Heading change (deg) of the log's laser poses from scan ``i - 1`` to ``i + 1``."""
    before, after = scans[max(i - 1, 0)], scans[min(i + 1, len(scans) - 1)]
    if getattr(before, "laser_pose", None) is None or getattr(after, "laser_pose", None) is None:
        return float("nan")
    d = float(after.laser_pose[2] - before.laser_pose[2])
    return math.degrees((d + math.pi) % (2 * math.pi) - math.pi)


def _split_beam_2d(
    name: str, count: int, rng: np.random.Generator, halves: str = "parity"
) -> list[tuple]:
    out = []
    for r, a, even, odd, _ in _halved_scans(name, count, halves):
        tgt = np.c_[r[even] * np.cos(a[even]), r[even] * np.sin(a[even])]
        ro = r[odd] + rng.normal(0.0, 0.01, int(odd.sum()))
        pts = np.c_[ro * np.cos(a[odd]), ro * np.sin(a[odd])]
        lim = np.array([0.2, 0.2, np.deg2rad(3.0)])
        truth = SE2.from_vector(rng.uniform(-lim, lim))
        out.append(
            (np.ascontiguousarray(truth.inverse().apply(pts)), np.ascontiguousarray(tgt), truth)
        )
    return out


def _split_beam_3d(name: str, count: int, rng: np.random.Generator) -> list[tuple]:
    from scanreg import io

    data = os.environ.get(
        "SCANREG_DATA", os.path.join(os.path.dirname(__file__), "../../shared/data")
    )
    if name == "kitti":
        files = sorted(os.listdir(os.path.join(data, "kitti-odometry-00-frames-000-015/velodyne")))
        clouds = [
            io.read_points(os.path.join(data, "kitti-odometry-00-frames-000-015/velodyne", f))
            .finite()
            .points
            for f in files[: max(1, min(count, len(files)))]
        ]
    else:
        clouds = [
            io.read_points(
                os.path.join(data, "gicp-outdoor-scan-pair/small_gicp/source.ply")
            ).points
        ]
    out = []
    vox = scanreg.preprocess.voxel_downsample
    for k in range(count):
        pts = np.asarray(clouds[k % len(clouds)], dtype=np.float64)
        half = rng.permutation(len(pts))
        a, b = pts[half[: len(pts) // 2]], pts[half[len(pts) // 2 :]]
        lim = np.array([0.2, 0.2, 0.05, np.deg2rad(1.0), np.deg2rad(1.0), np.deg2rad(3.0)])
        truth = SE3.from_vector(rng.uniform(-lim, lim))
        b = b + rng.normal(0.0, 0.02, b.shape)
        src = vox(np.ascontiguousarray(truth.inverse().apply(b)), 0.5).points
        out.append((src, vox(np.ascontiguousarray(a), 0.5).points, truth))
    return out


def _nees(err: np.ndarray, cov: np.ndarray) -> float:
    """``errᵀ cov⁻¹ err``; infinite for a non-finite covariance or an error along a direction
    it says is exact (a singular one)."""
    if not np.isfinite(cov).all():
        return float("inf")
    vals, vecs = np.linalg.eigh(0.5 * (cov + cov.T))
    proj = vecs.T @ err
    tiny = vals <= 1e-15 * max(float(vals[-1]), 1e-300)
    if np.any(tiny & (np.abs(proj) > 1e-9)):
        return float("inf")
    return float(np.sum(proj[~tiny] ** 2 / vals[~tiny]))


def halves_offset(name: str, count: int, halves: str = "parity") -> tuple[np.ndarray, np.ndarray]:
    """Per scan of a 2D set, the heading (deg) that best lays one half onto the other,
    found without our registration: the source half turned over a 1/16° grid within ±1°,
    scored by the mean squared distance (capped at 5 cm) to the target half's polyline
    (consecutive beams less than 0.3 m apart, densely interpolated). Where the halves are
    one scene sampled twice the answer is 0 within the grid: the estimator's own bias on
    interleaved samples does not enter. Returned beside each scan's turn (``_turn``): halves
    swept at different times disagree in proportion to it."""
    grid = np.radians(np.arange(-1.0, 1.0 + 1e-9, 1.0 / 16.0))
    out, turns = [], []
    for r, a, even, odd, turn in _halved_scans(name, count, halves):
        tgt = np.c_[r[even] * np.cos(a[even]), r[even] * np.sin(a[even])]
        gaps = np.linalg.norm(np.diff(tgt, axis=0), axis=1) < 0.3
        if gaps.sum() < 20:
            continue
        t = np.linspace(0.0, 1.0, 40)[None, :, None]
        line = (tgt[:-1][gaps, None, :] + t * (tgt[1:] - tgt[:-1])[gaps, None, :]).reshape(-1, 2)
        target = scanreg.prepare(line)
        cost = []
        for dth in grid:
            src = np.c_[r[odd] * np.cos(a[odd] + dth), r[odd] * np.sin(a[odd] + dth)]
            d2 = np.asarray(target.nearest(src).squared_distances)
            cost.append(float(np.mean(np.minimum(d2, 0.05**2))))
        out.append(float(np.degrees(grid[int(np.argmin(cost))])))
        turns.append(turn)
    return np.array(out), np.array(turns)


def split_beam(
    count: int, methods: list[str], sets: list[str] | None = None, halves: str = "parity"
) -> None:
    """The split-beam protocol (see the module docstring): one table row per set and method."""
    print(
        "| pairs | method | accepted | mean NEES hessian | censi | block | **calibrated** "
        "| calibrated / dof | outside 99.9 % | median error (mm / deg) |"
    )
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    every = [(name, 2) for name in SPLIT_BEAM_2D] + [("kitti", 3), ("outdoor", 3)]
    for name, dim in every:
        if sets and name not in sets:
            continue
        rng = np.random.default_rng(0)
        n3 = count if dim == 2 else max(count // 4, 4)
        pairs = _split_beam_2d(name, n3, rng, halves) if dim == 2 else _split_beam_3d(name, n3, rng)
        dof = 3 if dim == 2 else 6
        for method in methods:
            planar = ("point_to_plane", "point_to_line")
            m = (
                method
                if method not in planar
                else ("point_to_line" if dim == 2 else "point_to_plane")
            )
            nees: dict[str, list[float]] = {k: [] for k in KINDS}
            errors: list[tuple[float, float]] = []
            accepted = 0
            for src, tgt, truth in pairs:
                res = scanreg.register(src, tgt, method=m)  # type: ignore[arg-type]
                if res.verdict is None or not res.verdict.accepted:
                    continue
                accepted += 1
                d = (res.pose.inverse() @ truth).log()  # type: ignore[operator]
                turn = np.linalg.norm(d[dim:]) if dim == 3 else abs(d[2])
                errors.append((float(np.linalg.norm(d[:dim])), float(np.degrees(turn))))
                for k in KINDS:
                    c = np.asarray(getattr(res.covariances, k))
                    nees[k].append(_nees(d, c))
            if not accepted:
                print(f"| {name} | {m} | 0/{len(pairs)} | | | | | | |")
                continue
            means = {k: float(np.mean(v)) for k, v in nees.items()}
            cal = np.array(nees["calibrated"])
            err_t, err_r = np.median(np.array(errors), axis=0)
            print(
                f"| {name} | {m} | {accepted}/{len(pairs)} | {means['hessian']:.3g} | "
                f"{means['censi']:.3g} | {means['block']:.3g} | **{means['calibrated']:.3g}** | "
                f"{means['calibrated'] / dof:.2f} | {np.mean(cal > CHI2_999[dof]):.0%} | "
                f"{err_t * 1e3:.1f} / {err_r:.2f} |",
                flush=True,
            )


def _cell(value: object) -> str:
    return "–" if value is None else f"{float(value):.2f}"  # type: ignore[arg-type]


def markdown_table(rows: list[dict[str, object]]) -> str:
    """The rows as the table of ``docs/calibration.md``."""
    out = [
        "| scene | method | protocol | 95 % band | hessian | censi | block | **calibrated** "
        "| calibrated / dof | weak | rest | flagged degenerate |",
        "|---|---|---|---|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for row in rows:
        lo, hi = row["band"]  # type: ignore[misc]
        means: dict[str, float] = row["mean_nees"]  # type: ignore[assignment]
        dof = int(row["dof"])  # type: ignore[call-overload]
        cal = means["calibrated"]
        ratio = cal / dof
        mark = "in band" if lo <= cal <= hi else ("in ×2" if 0.5 <= ratio <= 2.0 else None)
        judged = f"{ratio:.2f} ({mark})" if mark else f"{ratio:.2f} ✗"
        names: dict[str, int] = row["weak_directions"]  # type: ignore[assignment]
        flagged = f"{row['flagged']}/{row['realisations']}"
        if names:
            top, count = max(names.items(), key=lambda kv: kv[1])
            flagged += f" {top} ×{count}" + (", …" if len(names) > 1 else "")
        cells = [f"{means[k]:.3g}" for k in KINDS if k != "calibrated"]
        out.append(
            f"| {row['scene']} | {row['method']} | {row['protocol']} | {lo:.2f}–{hi:.2f} | "
            + " | ".join(cells)
            + f" | **{cal:.3g}** | {judged} | {_cell(row.get('weak'))} | {_cell(row.get('rest'))} "
            + f"| {flagged} |"
        )
    return "\n".join(out)


if __name__ == "__main__":
    main()
