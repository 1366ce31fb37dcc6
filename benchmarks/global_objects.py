"""Global registration of scanned objects (issue 41): two partial views of a small object, any
rotation, no initial guess.

Run::

    nice .venv/bin/python benchmarks/global_objects.py [--trials 36] [--seed 41]

Each trial: an object (:mod:`scanreg.simulate.objects`: the trefoil-knot tube, an organic blob,
the figurine, in turn) of size 0.1, 0.2 or 0.5 m (its longest side), seen from two directions
60° apart (each view keeps the points whose normals face its viewpoint), 10⁴-10⁵ points per
view (log-uniform), Gaussian noise of 1-3 mm per axis, the source turned about a random axis by
120° (every other trial) or a uniform random angle and shifted by up to the size. A low-overlap
trial is the same with the views 150° apart.

Success: accepted, rotation error <= 2° and the source centre moved <= 1 % of the size from
where the truth puts it. Accepted but outside that is a *confident wrong* answer (split into
"off" — within 5° and 3 % — and "wrong" beyond). Refused is neither. Low-overlap trials count
refusals, correct answers and confident wrong ones.
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import time
from dataclasses import dataclass

os.environ.setdefault("RAYON_NUM_THREADS", "2")  # before scanreg starts its pool

import numpy as np
from scanreg import SE3
from scanreg import simulate as sim
from scanreg.global_registration import register_global

SIZES = (0.1, 0.2, 0.5)
SHAPES = ("trefoil_knot", "blob", "figurine")


@dataclass
class Trial:
    shape: str
    size: float
    points: int
    noise: float
    turn_deg: float
    views_deg: float
    accepted: bool
    rotation_deg: float
    shift: float
    cpu_s: float
    reason: str


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    return SE3.from_vector(
        np.concatenate([np.zeros(3), axis / np.linalg.norm(axis) * angle])
    ).rotation


def _unit(rng: np.random.Generator) -> np.ndarray:
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def _shape(name: str, size: float, seed: int) -> sim.ObjectShape:
    if name == "blob":
        return sim.blob(size=size, seed=seed)
    return sim.trefoil_knot(size=size) if name == "trefoil_knot" else sim.figurine(size=size)


def run_trial(k: int, rng: np.random.Generator, views_deg: float) -> Trial:
    name = SHAPES[k % len(SHAPES)]
    size = SIZES[(k // len(SHAPES)) % len(SIZES)]
    shape = _shape(name, size, seed=k)
    n = round(10 ** rng.uniform(4, 5))
    noise = float(rng.uniform(0.001, 0.003))
    d_source = _unit(rng)
    d_target = _rotation(np.cross(d_source, _unit(rng)), math.radians(views_deg)) @ d_source
    src = sim.object_view(shape, d_source, n, noise=noise, seed=int(rng.integers(2**31)))
    tgt = sim.object_view(shape, d_target, n, noise=noise, seed=int(rng.integers(2**31)))
    turn = 120.0 if k % 2 == 0 else float(rng.uniform(0, 180))
    move = SE3(_rotation(_unit(rng), math.radians(turn)), rng.uniform(-1, 1, 3) * size)
    moved = np.ascontiguousarray(src @ move.rotation.T + move.translation)
    truth = move.inverse()
    c0 = time.process_time()
    res = register_global(moved, np.ascontiguousarray(tgt))
    cpu = time.process_time() - c0
    pose = (
        res.pose if res.pose is not None else (res.hypotheses[0].pose if res.hypotheses else None)
    )
    if pose is None:
        rot, shift = 180.0, math.inf
    else:
        r = pose.rotation.T @ truth.rotation
        rot = math.degrees(math.acos(float(np.clip((np.trace(r) - 1) / 2, -1, 1))))
        centre = moved.mean(axis=0)
        shift = float(np.linalg.norm(pose.apply(centre[None])[0] - truth.apply(centre[None])[0]))
    reason = "" if res.accepted else res.reasons[-1].replace("best hypothesis: ", "")
    return Trial(name, size, n, noise, turn, views_deg, res.accepted, rot, shift, cpu, reason)


def _ok(t: Trial, deg: float = 2.0, frac: float = 0.01) -> bool:
    return t.rotation_deg <= deg and t.shift <= frac * t.size


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--trials",
        type=int,
        default=36,
        help="overlapping trials (and a third as many low-overlap ones)",
    )
    ap.add_argument("--seed", type=int, default=41)
    ap.add_argument("--verbose", action="store_true", help="print every trial")
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    trials = [run_trial(k, rng, 60.0) for k in range(args.trials)]
    low = [run_trial(k, rng, 150.0) for k in range(max(1, args.trials // 3))]
    if args.verbose:
        for t in trials + low:
            verdict = "accepted" if t.accepted else "refused "
            print(
                f"{t.shape:12s} {t.size:.1f} m {t.points:6d} pts {1000 * t.noise:.1f} mm turn "
                f"{t.turn_deg:5.1f} views {t.views_deg:3.0f}: {verdict} "
                f"{t.rotation_deg:6.2f}° {1000 * t.shift:6.1f} mm {t.cpu_s:.2f} s {t.reason[:70]}"
            )
    print(f"RAYON_NUM_THREADS={os.environ['RAYON_NUM_THREADS']}, seed {args.seed}")
    print(
        "| objects | trials | success % | of them at 120° | refused % | accepted off % "
        "| accepted wrong % | median CPU s |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    groups = [(f"{s:.1f} m", [t for t in trials if t.size == s]) for s in SIZES]
    groups.append(("all", trials))
    for label, ts in groups:
        turned = [t for t in ts if t.turn_deg == 120.0]
        ok = [t for t in ts if t.accepted and _ok(t)]
        off = [t for t in ts if t.accepted and not _ok(t) and _ok(t, 5.0, 0.03)]
        wrong = [t for t in ts if t.accepted and not _ok(t, 5.0, 0.03)]
        print(
            f"| {label} | {len(ts)} | {100 * len(ok) / len(ts):.0f} "
            f"| {sum(1 for t in turned if t.accepted and _ok(t))}/{len(turned)} "
            f"| {100 * sum(not t.accepted for t in ts) / len(ts):.0f} "
            f"| {100 * len(off) / len(ts):.0f} | {100 * len(wrong) / len(ts):.0f} "
            f"| {statistics.median(t.cpu_s for t in ts):.2f} |"
        )
    refused = sum(not t.accepted for t in low)
    right = sum(t.accepted and _ok(t) for t in low)
    wrong_low = sum(t.accepted and not _ok(t) for t in low)
    print()
    print(
        f"Low overlap (views 150° apart): {len(low)} trials, {refused} refused, {right} right, "
        f"{wrong_low} accepted outside 2° / 1 %"
    )


if __name__ == "__main__":
    main()
