"""3D mapping with loop closure on simulated loop drives, against exact truth and KISS-ICP.

Two courses of :func:`scanreg.simulate.block_loop` (VLP-16 model, 10 m/s, two laps):

* ``loop`` — an ordinary city block: ATE of the trajectory after loop closure
  (:class:`scanreg.pipeline.Mapper3D`, iSAM2 + final batch pass) against the exact truth,
  of our odometry alone (the same run before closure) and of KISS-ICP's odometry (pip
  ``kiss-icp``), stepped in the same process on the same sweeps, the contenders alternating
  which goes first; loop precision and recall; the NEES of accepted loop edges;
* ``loop-repeated`` — the four sides of the block are copies (every place has three
  look-alikes a quarter lap away): the number of accepted false loops.

A loop is *true* when its measured ``T_submap_node`` is within 1 m and 5° of the truth (a
look-alike is tens of metres off). Recall: of the nodes with a true revisit (an older node,
beyond ``loop_min_travel`` of path, within 3 m), the fraction with an accepted true loop.
NEES of a loop: ``eᵀ Λ e`` with ``e = log(T_true⁻¹ T_measured)`` and ``Λ`` the information of
its edge (none along degenerate directions), over ``rank Λ`` dof (ideal: the rank, 6).

    .venv/bin/python benchmarks/mapping_3d.py                  # ~5 min on 2 loaded cores
    .venv/bin/python benchmarks/mapping_3d.py --lap-length 260 --no-kiss --scenes loop
    .venv/bin/python benchmarks/mapping_3d.py --no-kiss --scenes loop:25:0.03 loop-repeated::0.03

``scene:range:scale`` maps with the graph's odometry σ × ``scale`` (the drift model and the
covariance the odometry reports, tests/_understated.py): the drift at the revisits then
exceeds what the graph believes; the last column measures by how much (``|e_t| / σ`` of each
revisit's relative pose from the odometry alone, against the odometry chain's σ along it:
min / median / max).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from scanreg.eval import absolute_trajectory_error
from scanreg.graph import Graph
from scanreg.io import Trajectory
from scanreg.io.sequences import SimulatedSequence
from scanreg.pipeline import OdometryConfig
from scanreg.pipeline.map_check import check_map
from scanreg.pipeline.mapping3d import MappingConfig3D
from scanreg.transform import SE3

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
from _understated import understated_mapper


def _kiss(threads: int) -> Any:
    from kiss_icp.config import KISSConfig
    from kiss_icp.kiss_icp import KissICP

    cfg = KISSConfig()
    cfg.data.max_range, cfg.data.min_range = 100.0, 1.0
    cfg.data.deskew = True
    cfg.mapping.voxel_size = 1.0  # our odometry's voxel
    cfg.registration.max_num_threads = threads
    return KissICP(cfg)


def _ate(poses: np.ndarray, truth: np.ndarray, stamps: np.ndarray) -> float:
    ate = absolute_trajectory_error(
        Trajectory(poses, stamps), Trajectory(truth, stamps), alignment="se3"
    )
    return float(ate.translation.rmse)


def loop_statistics(
    res: Any, truth: np.ndarray, min_travel: float, floor: np.ndarray, floor_range: float
) -> dict[str, Any]:
    """Precision, recall, false loops and NEES of a run's loop records against the truth
    (``floor``: the covariance the mapper adds to the registration's at a keyframe of RMS
    range ``floor_range``, for the NEES of the registration's own covariance)."""
    true_acc = false_acc = 0
    nees: list[float] = []
    nees_registration: list[float] = []
    ranks: list[int] = []
    good_nodes: set[int] = set()
    for r in res.loops:
        if not r.accepted:
            continue
        m = r.match
        t_true = SE3.from_matrix(np.linalg.inv(truth[r.submap_scan]) @ truth[r.scan], atol=1e-6)
        e = (t_true.inverse() @ m.measured).log()
        if np.linalg.norm(e[:3]) < 1.0 and np.linalg.norm(e[3:]) < math.radians(5.0):
            true_acc += 1
            good_nodes.add(m.node)
            info = np.asarray(m.information)
            nees.append(float(e @ info @ e))
            # The floor scales with the keyframe's RMS range (LoopSettings3D.submap_sigma_range).
            pts = res.node_points[m.node]
            scale = float(np.sqrt(np.mean(np.sum(pts * pts, axis=1)))) / floor_range
            nees_registration.append(float(e @ np.linalg.solve(m.covariance - floor * scale**2, e)))
            ranks.append(int(np.linalg.matrix_rank(info, tol=1e-6 * np.abs(info).max())))
        else:
            false_acc += 1
    # Nodes with a true revisit: an older node, beyond min_travel of path, within 3 m.
    xyz = np.array([truth[s][:3, 3] for s in res.node_scans])
    travel = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xyz, axis=0), axis=1))])
    revisit = [
        n
        for n in range(len(xyz))
        if np.any(
            (travel[:n] <= travel[n] - min_travel)
            & (np.linalg.norm(xyz[:n] - xyz[n], axis=1) <= 3.0)
        )
    ]
    accepted = true_acc + false_acc
    # Place candidates between scans truly more than 20 m apart: look-alikes the descriptor
    # proposed; matched = within reach (the graph's, or the drift the path allows), so
    # registered and judged.
    apart = [
        float(np.linalg.norm(truth[r.scan][:3, 3] - truth[r.submap_scan][:3, 3])) for r in res.loops
    ]
    lookalikes = [
        r for r, d in zip(res.loops, apart, strict=True) if r.match.origin == "place" and d > 20
    ]
    return {
        "lookalikes_proposed": len(lookalikes),
        "lookalikes_matched": sum(math.isfinite(r.match.overlap) for r in lookalikes),
        "lookalikes_accepted": sum(r.accepted for r in lookalikes),
        "nees_registration_mean": float(np.mean(nees_registration)) if nees else math.nan,
        "accepted": accepted,
        # Accepted by agreeing with other loops after the graph's tests refused them.
        "by_loops": sum(getattr(r.match, "evidence", "") == "loops" for r in res.loops),
        "rejected": len(res.loops) - accepted,
        "true": true_acc,
        "false": false_acc,
        "precision": true_acc / accepted if accepted else math.nan,
        "nodes_with_revisit": len(revisit),
        "recall": (len(good_nodes & set(revisit)) / len(revisit)) if revisit else math.nan,
        "nees_mean": float(np.mean(nees)) if nees else math.nan,
        "nees_median": float(np.median(nees)) if nees else math.nan,
        "nees_dof": float(np.mean(ranks)) if ranks else math.nan,
    }


def drift_statistics(res: Any, truth: np.ndarray, min_travel: float) -> dict[str, Any]:
    """How far the odometry drifted at each true revisit against what the graph believes:
    ``|e_t| / σ`` with ``e = log(T_true⁻¹ T_odom)`` of the revisit's relative pose (node
    against the nearest older node beyond ``min_travel`` of path, within 3 m) and σ the
    odometry chain's σ along ``e_t`` (the graph's odometry edges alone, as the graph stood
    before any loop closed)."""
    chain = Graph(3)
    nodes = len(res.node_scans)
    odom = [res.odometry_poses[s] for s in res.node_scans]
    for n in range(nodes):
        chain.add_node(n, odom[n])
    for e in res.graph.edges:
        if e.kind == "prior":
            chain.add_prior(e.i, odom[e.i], e.information)
        elif e.kind == "odometry":
            chain.add_edge(e.i, e.j, e.measurement, e.information)
    chain.update()
    xyz = np.array([truth[s][:3, 3] for s in res.node_scans])
    travel = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xyz, axis=0), axis=1))])
    drift, ratio = [], []
    for n in range(nodes):
        old = np.flatnonzero(travel[:n] <= travel[n] - min_travel)
        if not len(old):
            continue
        d = np.linalg.norm(xyz[old] - xyz[n], axis=1)
        if d.min() > 3.0:
            continue
        c = int(old[np.argmin(d)])
        t_true = SE3.from_matrix(
            np.linalg.inv(truth[res.node_scans[c]]) @ truth[res.node_scans[n]], atol=1e-6
        )
        e = (t_true.inverse() @ (odom[c].inverse() @ odom[n])).log()
        cov = chain.relative_covariance(c, n)
        u = e[:3] / max(float(np.linalg.norm(e[:3])), 1e-12)
        drift.append(float(np.linalg.norm(e[:3])))
        ratio.append(drift[-1] / math.sqrt(float(u @ cov[:3, :3] @ u)))
    return {
        "revisit_drift_m": [min(drift), max(drift)] if drift else None,
        "drift_over_sigma": [min(ratio), float(np.median(ratio)), max(ratio)] if ratio else None,
    }


def run_scene(
    scene: str,
    lap_length: float,
    laps: int,
    kiss: bool,
    threads: int,
    max_range: float,
    sigma_scale: float = 1.0,
) -> dict[str, Any]:
    seq = SimulatedSequence(scene, laps=laps, lap_length=lap_length)
    cfg = MappingConfig3D(odometry=OdometryConfig(max_range=max_range))
    truth = seq.ground_truth_at(cfg.odometry.reference_time)
    stamps = np.asarray(seq.stamps)
    mapper = understated_mapper(cfg, sigma_scale)
    cfg = mapper.config
    peer = _kiss(threads) if kiss else None
    kiss_poses: list[np.ndarray] = []
    t_ours = t_kiss = 0.0
    cpu0 = time.process_time()
    for k in range(len(seq)):
        f = seq[k]
        writable = (np.array(f.points), np.array(f.timestamps))  # KISS-ICP writes into them

        def ours(f: Any = f) -> float:
            t0 = time.perf_counter()
            mapper.step(f.points, f.timestamps, stamp=f.stamp)
            return time.perf_counter() - t0

        def theirs(writable: Any = writable) -> float:
            t0 = time.perf_counter()
            assert peer is not None
            peer.register_frame(*writable)
            kiss_poses.append(np.array(peer.last_pose))
            return time.perf_counter() - t0

        if peer is None:
            t_ours += ours()
        elif k % 2:  # alternate which contender runs first
            t_ours += ours()
            t_kiss += theirs()
        else:
            t_kiss += theirs()
            t_ours += ours()
    t0 = time.perf_counter()
    res = mapper.finish()
    t_ours += time.perf_counter() - t0
    n = res.num_scans
    closed = np.array([p.as_matrix() for p in res.poses])
    odometry = np.array([p.as_matrix() for p in res.odometry_poses])
    name = scene if max_range == 100.0 else f"{scene}, {max_range:g} m odometry"
    if sigma_scale != 1.0:
        name += f", odometry σ × {sigma_scale:g}"
    out: dict[str, Any] = {
        "scene": name,
        "length_m": float(seq.course.length) if seq.course is not None else math.nan,
        "scans": n,
        "nodes": len(res.node_scans),
        "ate_closed_m": _ate(closed, truth, stamps),
        "ate_odometry_m": _ate(odometry, truth, stamps),
        "end_closed_m": float(np.linalg.norm(closed[-1, :3, 3] - truth[-1, :3, 3])),
        "end_odometry_m": float(np.linalg.norm(odometry[-1, :3, 3] - truth[-1, :3, 3])),
        "ms_per_scan": 1e3 * t_ours / n,
        # The process's CPU time over the run (both contenders' when KISS-ICP runs too).
        "cpu_ms_per_scan": 1e3 * (time.process_time() - cpu0) / n,
        "timing": {
            k: getattr(res.timing, k)
            for k in ("odometry", "candidates", "matching", "optimization", "total")
        },
        "loops": loop_statistics(
            res,
            truth,
            cfg.loop_min_travel,
            np.diag([cfg.loops.submap_sigma[0] ** 2] * 3 + [cfg.loops.submap_sigma[1] ** 2] * 3),
            cfg.loops.submap_sigma_range,
        ),
        "drift": drift_statistics(res, truth, cfg.loop_min_travel),
        # The map's self-check (no ground truth), of the run and of its odometry alone.
        "self_check": {
            "closed": check_map(res).as_dict(),
            "odometry": check_map(res, poses=res.odometry_poses).as_dict(),
        },
    }
    if kiss_poses:
        kp = np.array(kiss_poses)
        out["ate_kiss_m"] = _ate(kp, truth, stamps)
        out["end_kiss_m"] = float(np.linalg.norm(kp[-1, :3, 3] - truth[-1, :3, 3]))
        out["kiss_ms_per_scan"] = 1e3 * t_kiss / n
    return out


def _verdict(check: dict[str, Any]) -> str:
    """A self-check in one cell: verdict, contradicted fraction, loop edges over their bound."""
    word = "consistent" if check["consistent"] else "**INCONSISTENT**"
    return (
        f"{word}, {100 * check['contradiction_fraction']:.2f} %, "
        f"{check['loops_over_bound']} / {check['loops']} loops over"
    )


def _ratios(values: list[float] | None) -> str:
    return "–" if not values else " / ".join(f"{v:.2g}" for v in values)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument(
        "--scenes",
        nargs="+",
        default=["loop", "loop-repeated", "loop:25"],
        help="sim scene[:odometry max_range m[:σ scale]]; loop:25 drifts (a 25 m "
        "odometry); loop:25:0.1 with every odometry edge's σ × 0.1 (the drift model's rates "
        "and floors, and the covariance the odometry reports)",
    )
    ap.add_argument("--lap-length", type=float, default=260.0, help="m (two laps: >= 500 m)")
    ap.add_argument("--repeated-lap-length", type=float, default=200.0)
    ap.add_argument("--laps", type=int, default=2)
    ap.add_argument("--no-kiss", action="store_true", help="skip the KISS-ICP peer")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--json", default=None, help="also write the results here")
    args = ap.parse_args()
    results = []
    for spec in args.scenes:
        scene, _, rest = spec.partition(":")
        reach, _, scale = rest.partition(":")
        lap = args.repeated_lap_length if scene == "loop-repeated" else args.lap_length
        r = run_scene(
            scene,
            lap,
            args.laps,
            kiss=spec == "loop" and not args.no_kiss,
            threads=args.threads,
            max_range=float(reach) if reach else 100.0,
            sigma_scale=float(scale) if scale else 1.0,
        )
        print(json.dumps(r, indent=1), flush=True)
        results.append(r)
    print("\n| scene | length m | trajectory | ATE m | end m |")
    print("|---|---:|---|---:|---:|")
    for r in results:
        rows = [("scanreg odometry", "odometry"), ("**scanreg + loop closure**", "closed")]
        if "ate_kiss_m" in r:
            rows.append(("KISS-ICP odometry", "kiss"))
        for label, key in rows:
            print(
                f"| {r['scene']} | {r['length_m']:.0f} | {label} | {r[f'ate_{key}_m']:.3f} | "
                f"{r[f'end_{key}_m']:.3f} |"
            )
    print(
        "\n| scene | accepted | true | false | precision | recall | rejected | look-alikes "
        "proposed / matched / accepted | NEES mean / dof | NEES median | NEES, registration "
        "covariance alone | closed by agreeing loops | drift / σ at the revisits |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in results:
        lp = r["loops"]
        print(
            f"| {r['scene']} | {lp['accepted']} | {lp['true']} | {lp['false']} | "
            f"{lp['precision']:.3f} | {lp['recall']:.3f} | {lp['rejected']} | "
            f"{lp['lookalikes_proposed']} / {lp['lookalikes_matched']} / "
            f"{lp['lookalikes_accepted']} | {lp['nees_mean']:.2f} / {lp['nees_dof']:.1f} | "
            f"{lp['nees_median']:.2f} | {lp['nees_registration_mean']:.1f} | "
            f"{lp['by_loops']} | {_ratios(r['drift']['drift_over_sigma'])} |"
        )
    print("\n| scene | self-check: loop-closed map | odometry alone |")
    print("|---|---|---|")
    for r in results:
        print(
            f"| {r['scene']} | {_verdict(r['self_check']['closed'])} | "
            f"{_verdict(r['self_check']['odometry'])} |"
        )
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump(results, fh, indent=1)


if __name__ == "__main__":
    main()
