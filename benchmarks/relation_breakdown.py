"""Where a mapped trajectory's Kümmerle relation error lies, and what the scans say of it.

For a Freiburg log (Intel, ACES, the hospital ``fr-clinic`` in
``../shared/data/freiburg-slam-benchmark``) and one or more mapped trajectories (``poses_tum.txt``
as ``scanreg map`` or ``freiburg_mapping.py --output`` write them; ``--poses LABEL=FILE``,
repeatable), beside the log's raw wheel odometry (the pose in each laser line):

* **where**: the mean relation error over the local relations (``t2 − t1`` under 100 s) and
  over the revisits, and over each 500-scan stretch (by scan t1), with each part's share of the
  overall mean; the relations that weigh most;
* **the scans as judge** (no reference): for every local relation, scan t2 is laid on scan t1
  at the relation, at each trajectory's relative pose and at the wheels'. *Within 3 cm*: the
  fraction of scan t2's returns (0.1–40 m) within 3 cm of a return of scan t1, mean over the
  relations. *Far-return distance*: the mean distance of scan t2's far returns (8–40 m; a
  degree of heading moves them 14–70 cm) to scan t1's, each capped at 0.3 m, over the relations
  with at least 20 far returns — the heading's witness (also per stretch). *Fits better than
  the relation*: the share of those relations where a pose's far-return distance is at least
  1 mm below the relation's, and the reverse;
* ``--group LABEL=A0-A1:B0-B1``: the relations from scans A0–A1 to scans B0–B1, their mean and
  what they add to the overall mean.

The wheels never saw a scan: where they lay the scans better than the reference does, the
reference is not the truth there. Nothing here changes the benchmark's figure.

    .venv/bin/python benchmarks/relation_breakdown.py --log hospital \
        --poses mapped=OUT/hospital/poses_tum.txt [--poses other=FILE] \
        [--group "return to the start=0-199:6700-6917"]
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
import scanreg
from scanreg import SE2
from scanreg.io import read_trajectory

sys.path.insert(0, str(Path(__file__).resolve().parent))
from relation_audit import FILES, freiburg_log, planar  # the same logs, read the same way

#: Relations at least this far apart in time are revisits (s; the data's README: the
#: hospital's 177 "between revisits more than 100 s apart").
REVISIT_SECONDS = 100.0
#: Scans per stretch of the second table.
STRETCH = 500
#: The returns read (m); far returns, their cap (m) and the least count of them.
MIN_RANGE, MAX_RANGE, FAR_RANGE, CAP, MIN_FAR = 0.1, 40.0, 8.0, 0.3, 20
#: "Within" distance of the overlap fraction (m) and the far-return margin of "fits better".
WITHIN, MARGIN = 0.03, 0.001


def _error(reference: SE2, estimate: SE2) -> tuple[float, float]:
    e = reference.inverse() @ estimate
    return float(np.linalg.norm(e.translation)), abs(math.degrees(e.angle))


class Judge:
    """Scan t2 laid on scan t1 at a relative pose of the robot (the laser's mounting applied)."""

    def __init__(self, lasers: list, mount: SE2) -> None:
        self.lasers, self.mount = lasers, mount
        self._targets: dict[int, scanreg.PreparedTarget] = {}
        self._points: dict[int, np.ndarray] = {}

    def _target(self, k: int) -> scanreg.PreparedTarget:
        if k not in self._targets:
            self._targets[k] = scanreg.prepare(self.lasers[k].to_points(MIN_RANGE, MAX_RANGE))
        return self._targets[k]

    def _laid(self, a: int, b: int, pose: SE2, lo: float) -> np.ndarray:
        pts = self.lasers[b].to_points(lo, MAX_RANGE)
        return np.ascontiguousarray((self.mount.inverse() @ pose @ self.mount).apply(pts))

    def within(self, a: int, b: int, pose: SE2) -> float:
        near, _ = self._target(a).index.nearest(self._laid(a, b, pose, MIN_RANGE), WITHIN)
        return float((np.asarray(near) >= 0).mean())

    def far_distance(self, a: int, b: int, pose: SE2) -> float | None:
        laid = self._laid(a, b, pose, FAR_RANGE)
        if len(laid) < MIN_FAR:
            return None
        near, dist = self._target(a).index.nearest(laid, CAP)
        return float(np.where(np.asarray(near) >= 0, np.asarray(dist), CAP).mean())


def _scan_range(text: str) -> tuple[int, int]:
    lo, _, hi = text.partition("-")
    return int(lo), int(hi)


def breakdown(
    name: str, poses: dict[str, Path], groups: dict[str, tuple[tuple[int, int], ...]]
) -> None:
    lasers, relations, index, mount = freiburg_log(name)
    judge = Judge(lasers, mount)
    trajectories: dict[str, dict[float, SE2]] = {}
    for label, path in poses.items():
        est = read_trajectory(path, "tum")
        assert est.timestamps is not None
        trajectories[label] = {
            float(t): planar(np.asarray(p)) for t, p in zip(est.timestamps, est.poses, strict=True)
        }
    wheels = {s.timestamp: s.odometry_se2 for s in lasers if s.odometry_se2 is not None}
    trajectories["wheels (raw odometry)"] = wheels
    labels = list(trajectories)

    rows = []  # per relation: a, b, local, then (t, r) per trajectory
    judged = []  # per local relation: within and far distance at the relation, then per trajectory
    for k in range(len(relations)):
        t1, t2 = float(relations.t1[k]), float(relations.t2[k])
        if t1 not in index or any(t1 not in tr or t2 not in tr for tr in trajectories.values()):
            continue
        a, b = index[t1], index[t2]
        relation = planar(relations.poses[k])
        rel = {lab: tr[t1].inverse() @ tr[t2] for lab, tr in trajectories.items()}
        local = t2 - t1 < REVISIT_SECONDS
        rows.append([a, b, local, *[v for lab in labels for v in _error(relation, rel[lab])]])
        if not local:
            continue
        far = [judge.far_distance(a, b, p) for p in (relation, *rel.values())]
        judged.append(
            [a]
            + [judge.within(a, b, p) for p in (relation, *rel.values())]
            + [math.nan if f is None else f for f in far]
        )
    table = np.array(rows, dtype=np.float64)
    a, local = table[:, 0], table[:, 2].astype(bool)
    n = len(table)

    print(f"\n{name}: {n} relations, {local.sum()} local, {(~local).sum()} revisits\n")
    print(
        "| log | trajectory | all (m / deg) | local | revisits | local's share of the mean "
        "(m / deg) |"
    )
    print("|---|---|---|---|---|---|")
    for i, lab in enumerate(labels):
        t, r = table[:, 3 + 2 * i], table[:, 4 + 2 * i]
        print(
            f"| {name} | {lab} | {t.mean():.4f} / {r.mean():.3f} | {t[local].mean():.4f} / "
            f"{r[local].mean():.3f} | {t[~local].mean():.4f} / {r[~local].mean():.3f} | "
            f"{t[local].sum() / n:.4f} / {r[local].sum() / n:.3f} |"
        )

    print("\n| scans t1 | relations (revisits) | " + " | ".join(labels) + " |")
    print("|---|---|" + "---|" * len(labels))
    for lo in range(0, int(a.max()) + 1, STRETCH):
        m = (a >= lo) & (a < lo + STRETCH)
        if not m.any():
            continue
        cells = [
            f"{table[m, 3 + 2 * i].mean():.3f} / {table[m, 4 + 2 * i].mean():.2f}"
            for i in range(len(labels))
        ]
        print(
            f"| {lo}–{lo + STRETCH - 1} | {m.sum()} ({(~local[m]).sum()}) | "
            + " | ".join(cells)
            + " |"
        )

    if groups:
        print(f"\nGroups (scan t1 range, scan t2 range; {labels[0]} and the wheels):\n")
        print("| group | relations | mean (m / deg) | adds to the mean | wheels |")
        print("|---|---|---|---|---|")
        w = 3 + 2 * (len(labels) - 1)
        for label, ((a0, a1), (b0, b1)) in groups.items():
            g = (a >= a0) & (a <= a1) & (table[:, 1] >= b0) & (table[:, 1] <= b1)
            if not g.any():
                continue
            t, r = table[g, 3], table[g, 4]
            print(
                f"| {label} | {g.sum()} | {t.mean():.3f} / {r.mean():.2f} | "
                f"{t.sum() / n:.4f} / {r.sum() / n:.3f} | "
                f"{table[g, w].mean():.3f} / {table[g, w + 1].mean():.2f} |"
            )

    t0 = table[:, 3]
    order = np.argsort(-t0)[:10]
    print(f"\nThe ten relations {labels[0]} reads worst (scan t1 → t2: m / deg, wheels):")
    w = 3 + 2 * (len(labels) - 1)
    for k in order:
        print(
            f"  {int(table[k, 0])} → {int(table[k, 1])}: {t0[k]:.3f} / {table[k, 4]:.2f}"
            f" (wheels {table[k, w]:.3f} / {table[k, w + 1]:.2f})"
        )

    j = np.array(judged, dtype=np.float64)
    m = len(labels) + 1
    within, far = j[:, 1 : m + 1], j[:, m + 1 :]
    has_far = np.isfinite(far).all(axis=1)
    far, far_a = far[has_far], j[has_far, 0]
    print(
        f"\nThe scans as judge ({len(j)} local relations; far returns on {has_far.sum()}):\n\n"
        "| log | pose | within 3 cm | far-return distance (m) | fits better than the "
        "relation / worse |"
    )
    print("|---|---|---|---|---|")
    print(f"| {name} | relation | {within[:, 0].mean():.3f} | {far[:, 0].mean():.4f} | – |")
    for i, lab in enumerate(labels, start=1):
        better = (far[:, i] < far[:, 0] - MARGIN).mean()
        worse = (far[:, i] > far[:, 0] + MARGIN).mean()
        print(
            f"| {name} | {lab} | {within[:, i].mean():.3f} | {far[:, i].mean():.4f} | "
            f"{better:.0%} / {worse:.0%} |"
        )
    print("\nFar-return distance (m) by stretch (local relations):\n")
    print("| scans t1 | relations | relation | " + " | ".join(labels) + " |")
    print("|---|---|---|" + "---|" * len(labels))
    for lo in range(0, int(far_a.max()) + 1, STRETCH):
        s = (far_a >= lo) & (far_a < lo + STRETCH)
        if s.any():
            cells = " | ".join(f"{far[s, i].mean():.4f}" for i in range(m))
            print(f"| {lo}–{lo + STRETCH - 1} | {s.sum()} | {cells} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--log", choices=sorted(FILES), required=True)
    parser.add_argument(
        "--poses", action="append", required=True, help="LABEL=FILE (a TUM trajectory)"
    )
    parser.add_argument(
        "--group",
        action="append",
        default=[],
        help="LABEL=A0-A1:B0-B1, the relations from scans A0..A1 to scans B0..B1",
    )
    args = parser.parse_args()
    groups = {}
    for item in args.group:
        label, sep, ranges = item.partition("=")
        first, colon, second = ranges.partition(":")
        if not (sep and colon):
            parser.error(f"--group: expected LABEL=A0-A1:B0-B1, got {item!r}")
        groups[label] = (_scan_range(first), _scan_range(second))
    poses = {}
    for item in args.poses:
        label, sep, path = item.partition("=")
        if not sep:
            parser.error(f"--poses: expected LABEL=FILE, got {item!r}")
        poses[label] = Path(path)
    breakdown(args.log, poses, groups)


if __name__ == "__main__":
    main()
