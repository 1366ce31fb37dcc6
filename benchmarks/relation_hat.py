"""How good are the Kümmerle relations as pair truth? A three-cornered hat.

Two independent scan matchers — scanreg's default 2D call (``register(src, prepare(tgt,
normals=True), method="point_to_line", init=odometry)``) and OpenKarto's (``karto-scanmatcher``,
as ``relation_pairs.py`` runs it) — and the relation give three estimates of each pair's
motion (the first ``--count`` relations under 10 s apart of each Freiburg log, scan t2 against
scan t1 from the wheel odometry's relative pose). With independent errors the variance of each
difference is the sum of two of the three error variances, so each one follows:
``σ²_relation = (σ²(ours − relation) + σ²(Karto − relation) − σ²(ours − Karto)) / 2``, and the
same for the two matchers. Per axis (the laser's x forward, y left, heading), over the pairs
where all three agree within 0.15 m and 2° (a wrong answer is not an error variance), with
robust spreads (1.4826 × the median absolute deviation): the reference error that
``wrong_start.py``'s "(ref. error added)" columns assume, measured. Errors the two matchers
share (a sweep distorted by the robot's motion, both reading the same scans) count as the
relation's here.

Also: how many accepted default-call results lie outside their own covariance against the
relation (NEES > χ²(3) at 99.9 %), as reported and with the measured relation error added.

    .venv/bin/python benchmarks/relation_hat.py [--logs intel,aces,fr-clinic] [--count 400]
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path
from typing import Any

os.environ.setdefault("RAYON_NUM_THREADS", "1")

import numpy as np
import scanreg
from scanreg import SE2

sys.path.insert(0, str(Path(__file__).resolve().parent))
from relation_pairs import karto_match
from relation_slide import MAX_RANGE, MIN_RANGE, WRONG_DEG, WRONG_M, relation_scans

CHI2_999 = 16.266  # χ²(3) at 99.9 %
AXES = ("x (cm)", "y (cm)", "heading (°)")


def _robust_sigma(values: np.ndarray) -> np.ndarray:
    """1.4826 × the median absolute deviation per column."""
    med = np.median(values, axis=0)
    return np.asarray(1.4826 * np.median(np.abs(values - med), axis=0))


def _shown(sigma: np.ndarray) -> list[str]:
    return [f"{100 * sigma[0]:.2f}", f"{100 * sigma[1]:.2f}", f"{math.degrees(sigma[2]):.3f}"]


def _wrong(e: np.ndarray) -> bool:
    return bool(math.hypot(e[0], e[1]) > WRONG_M or abs(e[2]) > math.radians(WRONG_DEG))


def measure(log: str, count: int) -> dict[str, Any]:
    """The three differences per pair, the accepted results' errors and covariances."""
    diffs: dict[str, list[np.ndarray]] = {"ours - relation": [], "karto - relation": [],
                                          "ours - karto": []}  # fmt: skip
    accepted: list[tuple[np.ndarray, np.ndarray]] = []
    n = 0
    for _, scan1, scan2, relation, odometry in relation_scans(log, count):
        n += 1
        source = scan2.to_points(MIN_RANGE, MAX_RANGE)
        target = scanreg.prepare(scan1.to_points(MIN_RANGE, MAX_RANGE), normals=True)
        res = scanreg.register(source, target, method="point_to_line", init=odometry)
        ours: SE2 = res.pose  # type: ignore[assignment]
        karto, _ = karto_match(scan1, scan2, odometry)
        d = {
            "ours - relation": (relation.inverse() @ ours).log(),
            "karto - relation": (relation.inverse() @ karto).log(),
            "ours - karto": (karto.inverse() @ ours).log(),
        }
        assert res.verdict is not None
        if res.verdict.accepted:
            accepted.append(((ours.inverse() @ relation).log(), np.asarray(res.covariance)))
        if any(_wrong(v) for v in d.values()):
            continue
        for key, v in d.items():
            diffs[key].append(v)
    return {"pairs": n, "diffs": {k: np.array(v) for k, v in diffs.items()}, "accepted": accepted}


def report(log: str, m: dict[str, Any]) -> np.ndarray:
    """Prints the log's table; returns the relation's σ per axis (m, m, rad)."""
    diffs = m["diffs"]
    var = {k: _robust_sigma(v) ** 2 for k, v in diffs.items()}
    kept = len(diffs["ours - relation"])
    print(f"\n{log}: {m['pairs']} pairs, {kept} where all three agree within 0.15 m / 2°\n")
    print("| spread of | " + " | ".join(AXES) + " |")
    print("|---|---:|---:|---:|")
    for key in var:
        print(f"| {key} | " + " | ".join(_shown(np.sqrt(var[key]))) + " |")
    hats = {
        "relation": ("ours - relation", "karto - relation", "ours - karto"),
        "ours": ("ours - relation", "ours - karto", "karto - relation"),
        "karto": ("karto - relation", "ours - karto", "ours - relation"),
    }
    sigma: dict[str, np.ndarray] = {}
    for who, (a, b, c) in hats.items():
        sigma[who] = np.sqrt(np.maximum(0.5 * (var[a] + var[b] - var[c]), 0.0))
        print(f"| **{who}** (hat) | " + " | ".join(_shown(sigma[who])) + " |")
    ref_cov = np.diag(sigma["relation"] ** 2)
    own = [float(e @ np.linalg.solve(c, e)) for e, c in m["accepted"] if np.isfinite(c).all()]
    added = [
        float(e @ np.linalg.solve(c + ref_cov, e)) for e, c in m["accepted"] if np.isfinite(c).all()
    ]
    n_acc = len(m["accepted"])
    print(
        f"\naccepted {n_acc}: outside own covariance {sum(x > CHI2_999 for x in own)}, with the "
        f"relation's measured error added {sum(x > CHI2_999 for x in added)} (mean NEES "
        f"{np.mean(own):.2f} / {np.mean(added):.2f}, ideal 3)"
    )
    return sigma["relation"]


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--logs", default="intel,aces,fr-clinic")
    parser.add_argument("--count", type=int, default=400)
    args = parser.parse_args()
    for log in args.logs.split(","):
        report(log, measure(log, args.count))


if __name__ == "__main__":
    main()
