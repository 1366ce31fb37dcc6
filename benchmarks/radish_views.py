"""Whose is a Radish map's global error: a relation between two passes, judged by the scans.

For one log of ``radish_mapping.py`` (the same simulated wheels, the default ``MappingConfig``)
and pairs of passes ``A0-A1:B0-B1`` (scans of the log), each scan ``b`` of the second pass is
laid on the first pass's scans (in the frame of its middle scan ``a``, each trajectory laying
the first pass with its own poses) at our relative pose ``T_a_b`` and at GMapping's:

* **relation error**: ours against GMapping's (mean m / deg over the pass);
* **the scans as judge**: the fraction of scan ``b``'s returns (0.1–40 m) within 5 cm and 10 cm
  of the first pass's returns at either pose (mean over the pass);
* **our own matching of the view**: the best correlative score (the loop search's, 5 cm cells)
  of scan ``b`` on the first pass within ±1.5 m / ±10° of our relation, refined by
  point-to-line ICP; the refined pose's distance to GMapping's relation (median);
* **free space**: the fraction of scan ``b``'s returns that A's scans (within 20 m) saw and most
  of them saw through (the self-check's test) at our relation, GMapping's, our own match, and
  ours moved 1 m (mean of four directions) — a wrong relation puts walls in the other pass's
  free space;
* **what the loop search did**: the loop records between the two passes (by search, accepted,
  reasons) — none means no candidate was ever proposed there;
* **every view, found without the reference**: each scan ``b`` and the scan ``a`` nearest it by
  our poses among those at least ``MIN_PATH`` m of path before it and within ``VIEW_RANGE`` m,
  scan ``b`` laid on scans ``a ± 2`` at both relations; consecutive scans ``b`` whose ``a`` stay
  together are one view (a table row): its mean distance, relation error, fractions within
  10 cm and the loops accepted between the two passes;
* **the map with the view closed**: every refined match of the pair added as a loop edge
  (σ 0.1 m, 1°, Cauchy as the mapper's) and the graph re-solved: ATE against GMapping's poses
  and the self-check's contradicted fraction, before and after.

A pass the scans lay better at GMapping's relation, that our own matching finds there, is a
revisit our loop search left open: the error is ours. The per-stretch path length (ours over
GMapping's) says whether a scale error (a corridor slide) is in it too.

    .venv/bin/python benchmarks/radish_views.py [--log edmonton] [--pair 55-75:147-158 ...]
"""

from __future__ import annotations

import argparse
import collections
import itertools
import math
import os
import sys
from pathlib import Path

import numpy as np
from scanreg import SE2, _core
from scanreg.correlative import find_correlative, prepare_correlative
from scanreg.graph import Kernel
from scanreg.pipeline import MappingConfig, run_mapping
from scanreg.pipeline.map_check import check_map
from scanreg.register import register

sys.path.insert(0, str(Path(__file__).resolve().parent))
from radish_mapping import LOGS, errors, prepared

DATA = Path(os.environ.get("SCANREG_DATA", Path(__file__).resolve().parents[2] / "shared/data"))
#: Edmonton's passes (the default pairs of ``--log edmonton``, none for another log): the
#: view across open space (scans 147-158 facing scans 55-75 from 9-15 m, headings 110-170°
#: apart) and two revisits the loop search closed or came near (controls).
DEFAULT_PAIRS = ("55-75:147-158", "158-172:205-224", "283-297:308-326")
MIN_RANGE, MAX_RANGE = 0.1, 40.0
WINDOW = (1.5, math.radians(10.0))
#: A view: an earlier scan at least this much path back (m), within this distance (m) ...
MIN_PATH, VIEW_RANGE = 30.0, 15.0
#: ... laid on it and this many scans each side; a view ends where the earlier scan jumps
#: by more than this many scans, and is shown with at least this many scans.
VIEW_HALF, VIEW_JUMP, VIEW_MIN = 2, 15, 3
#: Free space: A's scans judge b's returns within this range (m), a return seen through when
#: most of those that saw it have their beams end more than ``THROUGH_MARGIN`` m beyond it
#: (the self-check's test, ``scanreg.pipeline.map_check``); the wrong poses it is asked about.
THROUGH_RANGE, THROUGH_MARGIN = 20.0, 0.3
SHIFTS = tuple(SE2.from_vector(v) for v in ([1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0]))
#: The injected loop edges' σ (m, rad).
SIGMA = (0.1, math.radians(1.0))


def _nearest(query: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Distance of each query point to its nearest target point (brute force, in blocks)."""
    out = np.empty(len(query))
    for i in range(0, len(query), 64):
        block = query[i : i + 64, None, :] - target[None]
        out[i : i + 64] = np.sqrt((block**2).sum(-1).min(1))
    return out


def _error(reference: SE2, estimate: SE2) -> tuple[float, float]:
    e = reference.inverse() @ estimate
    return float(np.linalg.norm(e.translation)), abs(math.degrees(e.angle))


def _seen_through(laid: list[SE2], old: list[np.ndarray], pose: SE2, points: np.ndarray) -> float:
    """The fraction of ``points`` (a scan at ``pose``) that the scans ``old`` (at ``laid``, the
    same frame) saw, and most of those saw through — a wall where the other pass saw free space."""
    rows = np.ascontiguousarray([p.as_vector() for p in [*laid, pose]], dtype=np.float64)
    counts = [len(p) for p in [*old, points]]
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    sessions = np.array([0] * len(old) + [1], dtype=np.uint32)  # only the other pass judges
    _, judged, seen, through = _core.see_through(
        rows, np.ascontiguousarray(np.vstack([*old, points])), offsets, bins=360,
        margin=THROUGH_MARGIN, max_range=THROUGH_RANGE, min_gap=len(counts), sessions=sessions,
    )  # fmt: skip
    mine = (np.asarray(judged) >= offsets[-2]) & (seen >= 1)
    return float(np.mean(2 * through[mine] > seen[mine])) if mine.any() else math.nan


def _span(text: str) -> tuple[int, int]:
    lo, hi = (int(v) for v in text.split("-"))
    return lo, hi


def _path(poses: list[SE2], lo: int, hi: int) -> float:
    return sum(
        float(np.linalg.norm(a.translation - b.translation))
        for a, b in itertools.pairwise(poses[lo : hi + 1])
    )


def _laid(poses: list[SE2], a: int, k: int, pts: dict[int, np.ndarray]) -> np.ndarray:
    return (poses[a].inverse() @ poses[k]).apply(pts[k])


def views(ours: list[SE2], ref: list[SE2], pts: dict[int, np.ndarray], res: object) -> None:
    """The views table (module docstring), found by our poses, judged at both relations."""
    xy = np.array([p.translation for p in ours])
    steps = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    travel = np.concatenate([[0.0], np.cumsum(steps)])
    rows = []  # (b, a, distance, relation error m / deg, within 10 cm ours / GMapping)
    for b in range(len(ours)):
        old = np.flatnonzero(travel <= travel[b] - MIN_PATH)
        if not len(old):
            continue
        d = np.linalg.norm(xy[old] - xy[b], axis=1)
        if d.min() > VIEW_RANGE:
            continue
        a = int(old[np.argmin(d)])
        near = range(max(a - VIEW_HALF, 0), min(a + VIEW_HALF, old[-1]) + 1)
        fits = []
        for poses in (ours, ref):
            target = np.vstack([_laid(poses, a, k, pts) for k in near])
            fits.append(float(np.mean(_nearest(_laid(poses, a, b, pts), target) < 0.10)))
        err = _error(ref[a].inverse() @ ref[b], ours[a].inverse() @ ours[b])
        rows.append((b, a, float(d.min()), *err, *fits))
    groups: list[list[tuple]] = []
    for row in rows:
        last = groups[-1][-1] if groups else None
        if last is not None and row[0] == last[0] + 1 and abs(row[1] - last[1]) <= VIEW_JUMP:
            groups[-1].append(row)
        else:
            groups.append([row])
    print(
        f"\nviews (scan b, the nearest scan a >= {MIN_PATH:.0f} m of path before it within "
        f"{VIEW_RANGE:.0f} m by our poses; b laid on a ± {VIEW_HALF}):\n"
        "\n| scans b | scans a | distance (m) | relation error (m / deg) "
        "| within 10 cm ours / GMapping | loops accepted b→a |"
    )
    print("|---|---|---:|---|---|---:|")
    for g in groups:
        if len(g) < VIEW_MIN:
            continue
        arr = np.array([r[2:] for r in g])
        b0, b1 = g[0][0], g[-1][0]
        a0, a1 = min(r[1] for r in g), max(r[1] for r in g)
        loops = sum(
            1 for r in res.loops  # type: ignore[attr-defined]
            if r.accepted and b0 <= r.scan <= b1 and a0 - 10 <= r.submap_scan <= a1 + 10
        )  # fmt: skip
        m = arr.mean(axis=0)
        print(
            f"| {b0}–{b1} | {a0}–{a1} | {m[0]:.1f} | {m[1]:.3f} / {m[2]:.2f} "
            f"| {m[3]:.2f} / {m[4]:.2f} | {loops} |"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DATA)
    parser.add_argument("--log", default="edmonton", choices=LOGS)
    parser.add_argument("--pair", action="append", default=None, help="A0-A1:B0-B1")
    args = parser.parse_args()
    given = args.pair if args.pair is not None else DEFAULT_PAIRS if args.log == "edmonton" else ()
    pairs = [tuple(_span(s) for s in p.split(":")) for p in given]
    run, ref, stamps = prepared(
        args.log, args.data / "carmen-radish-corrected", LOGS.index(args.log)
    )
    res = run_mapping(run, MappingConfig())
    ours = list(res.poses)
    node_of = {s: i for i, s in enumerate(res.node_scans)}
    pts = {k: run.points(k, MIN_RANGE, MAX_RANGE) for k in range(len(ours))}
    before = (errors(ours, ref, stamps)[4], check_map(res).contradiction_fraction)
    graph = res.graph
    scans_nodes = sorted(node_of)

    def resolved() -> tuple[float, float]:
        """The graph re-solved in batch, each scan laid on its node as mapped: ATE, contradicted."""
        graph.optimize()
        laid = []
        for k in range(len(ours)):
            n = scans_nodes[max(np.searchsorted(scans_nodes, k, side="right") - 1, 0)]
            laid.append(graph.pose(node_of[n]) @ (ours[n].inverse() @ ours[k]))
        return errors(laid, ref, stamps)[4], check_map(res, poses=laid).contradiction_fraction

    plain = resolved()
    print(
        f"{args.log}: ATE {before[0]:.3f} m, self-check {before[1]:.1%} contradicted "
        f"(the graph re-solved with nodes only, the yardstick of the last column: "
        f"{plain[0]:.3f} m, {plain[1]:.1%})"
    )
    if pairs:
        print(
            "\n| passes A : B | relation error (m / deg) | within 5 cm ours / GMapping "
            "| within 10 cm ours / GMapping | best score (median) "
            "| refined − GMapping (median m) | loop records A↔B "
            "| ATE, self-check with the view closed "
            "| seen through: ours / GMapping / our match / ours 1 m off |"
        )
        print("|---|---|---|---|---:|---:|---|---|---|")
    for (alo, ahi), (blo, bhi) in pairs:
        a = (alo + ahi) // 2
        passes = {
            label: np.vstack([_laid(poses, a, k, pts) for k in range(alo, ahi + 1)])
            for label, poses in (("ours", ours), ("ref", ref))
        }
        grid = prepare_correlative(passes["ours"], resolution=0.05)
        rel_err, fit5, fit10, scores, refined_err, edges = [], [], [], [], [], []
        laid = {
            label: [poses[a].inverse() @ poses[k] for k in range(alo, ahi + 1)]
            for label, poses in (("ours", ours), ("ref", ref))
        }
        old = [pts[k] for k in range(alo, ahi + 1)]
        through = []
        for b in range(blo, bhi + 1):
            t_ours, t_ref = ours[a].inverse() @ ours[b], ref[a].inverse() @ ref[b]
            rel_err.append(_error(t_ref, t_ours))
            d_ours = _nearest(t_ours.apply(pts[b]), passes["ours"])
            d_ref = _nearest(t_ref.apply(pts[b]), passes["ref"])
            fit5.append((np.mean(d_ours < 0.05), np.mean(d_ref < 0.05)))
            fit10.append((np.mean(d_ours < 0.10), np.mean(d_ref < 0.10)))
            found = find_correlative(
                pts[b], grid, min_score=0.0, init=t_ours, window=(WINDOW[0], WINDOW[0], WINDOW[1])
            )
            if found is None:
                continue
            scores.append(found.score)
            fit = register(
                pts[b], passes["ours"], init=found.pose, method="point_to_line",
                max_correspondence_distance=0.3, kernel="cauchy",
            )  # fmt: skip
            refined_err.append(_error(t_ref, fit.pose)[0])
            through.append(
                (
                    _seen_through(laid["ours"], old, t_ours, pts[b]),
                    _seen_through(laid["ref"], old, t_ref, pts[b]),
                    _seen_through(laid["ours"], old, fit.pose, pts[b]),
                    np.nanmean(
                        [_seen_through(laid["ours"], old, t_ours @ d, pts[b]) for d in SHIFTS]
                    ),
                )
            )
            if a in node_of and b in node_of:
                edges.append((node_of[a], node_of[b], fit.pose))
        records = [
            r for r in res.loops
            if (alo <= r.submap_scan <= ahi and blo <= r.scan <= bhi)
            or (blo <= r.submap_scan <= bhi and alo <= r.scan <= ahi)
        ]  # fmt: skip
        kinds = collections.Counter(
            r.match.search + (" accepted" if r.accepted else ": " + (r.match.reasons or ("?",))[0])
            for r in records
        )
        said = "; ".join(f"{n}× {k}" for k, n in kinds.most_common()) or "none"
        # The view closed by our own matches, then the graph as it was.
        graph_edges = len(graph.edges)
        info = np.diag([SIGMA[0] ** -2, SIGMA[0] ** -2, SIGMA[1] ** -2])
        for i, j, pose in edges:
            graph.add_edge(i, j, pose, info, kind="loop", kernel=Kernel("cauchy", 1.0))
        after = resolved()
        graph.remove_last_edges(len(graph.edges) - graph_edges)
        resolved()
        r, f5, f10 = np.mean(rel_err, axis=0), np.mean(fit5, axis=0), np.mean(fit10, axis=0)
        print(
            f"| {alo}–{ahi} : {blo}–{bhi} | {r[0]:.3f} / {r[1]:.2f} | {f5[0]:.2f} / {f5[1]:.2f} "
            f"| {f10[0]:.2f} / {f10[1]:.2f} | {np.median(scores):.2f} | "
            f"{np.median(refined_err):.2f} | {said} | {after[0]:.3f} m, {after[1]:.1%} | "
            + " / ".join(f"{v:.2f}" for v in np.nanmean(through, axis=0))
            + " |",
            flush=True,
        )

    views(ours, ref, pts, res)

    # A scale error (a corridor slide) would show as a path length off GMapping's.
    edges_at = np.linspace(0, len(ours) - 1, 5).astype(int)
    parts = []
    for lo, hi in itertools.pairwise(edges_at):
        parts.append(f"{lo}–{hi} {_path(ours, lo, hi) / _path(ref, lo, hi) - 1:+.2%}")
    print("\npath length, ours over GMapping's: " + ", ".join(parts))


if __name__ == "__main__":
    main()
