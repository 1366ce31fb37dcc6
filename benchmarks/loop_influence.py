"""Which edges of a 2D map's pose graph carry its error, against exact truth.

A simulated room tour (``simulated_buildings.py``'s variants) mapped by ``run_mapping`` with the
default ``MappingConfig``; its final graph's nodes scored against the simulator's truth (node
ATE: RMS position error, first node aligned). Every edge's NEES against the truth
(``δᵀ I δ``, ``δ = log(T̂⁻¹ T_true)``, ``I`` the information the edge carries; ideal mean 3
for a full-rank edge), per kind. Then the graph is re-solved in batch (Levenberg–Marquardt,
from the map's own poses) without each accepted loop in turn, and with the odometry edges'
information scaled: how much of the map's error one loop, or the odometry's weight, accounts for.

Run: ``.venv/bin/python benchmarks/loop_influence.py [--variant "demo tour"] [--seeds 0 1]
[--top 5]``
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

import numpy as np
from scanreg import SE2
from scanreg.graph import Edge, Graph
from scanreg.pipeline import MappingConfig, MappingResult, run_mapping
from simulated_buildings import VARIANTS, tour

#: Odometry information scales tried (1: as mapped).
ODOMETRY_SCALES = (1.0, 4.0, 10.0, 40.0)


def _node_ate(poses: list[SE2], truth: list[SE2]) -> float:
    p0, t0 = poses[0], truth[0]
    err = [
        np.linalg.norm(((t0.inverse() @ t).inverse() @ (p0.inverse() @ p)).translation)
        for p, t in zip(poses, truth, strict=True)
    ]
    return float(np.sqrt(np.mean(np.square(err))))


def _error(e: Edge, truth: list[SE2]) -> np.ndarray:
    true = truth[e.i].inverse() @ truth[e.j]
    return (e.measurement.inverse() @ true).log()  # type: ignore[operator,no-any-return]


def _resolve(res: MappingResult[SE2], weight: Callable[[int, Edge], float]) -> list[SE2]:
    """The final graph re-solved in batch, each edge's information × ``weight(k, edge)``
    (0: left out)."""
    g = res.graph
    h = Graph(2)
    for k in g.keys:
        h.add_node(k, g.pose(k))
    for k, e in enumerate(g.edges):
        if e.kind == "prior":
            h.add_prior(e.i, e.measurement, e.information)
            continue
        w = weight(k, e)
        if w > 0:
            h.add_edge(e.i, e.j, e.measurement, w * e.information, kind=e.kind, kernel=e.kernel)
    h.optimize()
    return [h.pose(k) for k in g.keys]  # type: ignore[misc]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--variant", default="demo tour", choices=list(VARIANTS))
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--top", type=int, default=5, help="loops listed per seed")
    args = parser.parse_args()
    summary, loops = [], []
    for seed in args.seeds:
        log, scan_truth = tour(VARIANTS[args.variant], seed)
        res = run_mapping(log, MappingConfig())
        truth = [scan_truth[s] for s in res.node_scans]
        odometry = [res.odometry_poses[s] for s in res.node_scans]
        mapped = _node_ate([res.graph.pose(k) for k in res.graph.keys], truth)  # type: ignore[misc]
        nees: dict[str, list[float]] = {"odometry": [], "loop": []}
        for e in res.graph.edges:
            if e.kind != "prior":
                d = _error(e, truth)
                nees[e.kind].append(float(d @ e.information @ d))
        scaled = [
            _resolve(res, lambda _, e, s=s: s if e.kind == "odometry" else 1.0)
            for s in ODOMETRY_SCALES
        ]
        summary.append(
            f"| {seed} | {len(truth)} | {_node_ate(odometry, truth):.4f} | {mapped:.4f} | "
            + " | ".join(f"{len(v)}: {np.mean(v):.2f} / {np.median(v):.2f}" for v in nees.values())
            + " | "
            + " / ".join(f"{_node_ate(p, truth):.4f}" for p in scaled)
            + " |"
        )
        search = {(r.match.submap_node, r.match.node): r.match for r in res.accepted_loops}
        ranked = []
        for k, e in enumerate(res.graph.edges):
            if e.kind != "loop":
                continue
            without = _node_ate(_resolve(res, lambda j, _, k=k: 0.0 if j == k else 1.0), truth)
            ranked.append((without - mapped, k, e))
        ranked.sort(key=lambda x: x[0])
        for change, _, e in ranked[: args.top]:
            d = _error(e, truth)
            m = search.get((e.i, e.j))
            sd = (
                np.sqrt(np.diag(np.asarray(m.covariance)))
                if m is not None
                else np.full(3, math.nan)
            )
            how = f"{m.search}, {m.evidence}" if m is not None else "?"
            loops.append(
                f"| {seed} | {e.i} → {e.j} | {how} | {1e3 * d[0]:.1f}, {1e3 * d[1]:.1f}, "
                f"{math.degrees(d[2]):.2f} | {1e3 * sd[0]:.1f}, {1e3 * sd[1]:.1f}, "
                f"{math.degrees(sd[2]):.2f} | {float(d @ e.information @ d):.2f} | "
                f"{mapped:.4f} → {mapped + change:.4f} |"
            )
    scales = " / ".join(f"×{s:g}" for s in ODOMETRY_SCALES)
    print(
        "| seed | nodes | odometry node ATE (m) | map node ATE (m) | odometry edges: n, NEES "
        f"mean / median | loop edges: n, NEES mean / median | map node ATE, odometry information "
        f"{scales} |"
    )
    print("|---:|---:|---:|---:|---|---|---|")
    print("\n".join(summary))
    print()
    print(
        "| seed | loop (nodes) | search, evidence | error x, y (mm), θ (°) | σ x, y (mm), θ (°) "
        "| NEES | map node ATE without it (m) |"
    )
    print("|---:|---|---|---|---|---:|---|")
    print("\n".join(loops))


if __name__ == "__main__":
    main()
