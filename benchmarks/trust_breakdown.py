"""Where a 2D full result's time goes: the stages of ``trust_speed.py``'s 2D loop, in place.

Run (small_gicp is optional; without it the ratio column is empty):

    RAYON_NUM_THREADS=1 .venv/bin/python benchmarks/trust_breakdown.py --peers-site $PEERS \
        [--rounds 11] [--probe]

The loop of ``trust_speed.py``'s 2D section (225 Intel pairs: ``prepare`` + ``register`` +
covariance, degeneracy and verdict; without the wrong-basin probe, or with it: ``--probe``) is
run as it is and with the calls of one more stage each time replaced by a replay of what they
returned in a recording run (the same objects, in the same order): the difference between two
successive variants is that stage's cost where it runs, caches and all (timing each call in a
loop of its own gives less: a 2D scan's analysis runs on caches its ICP has just filled).
What is left with every stage replayed is the Python around the core calls. Stages:
``prepare()`` (k-d tree, 10-NN normals, their noise and spacing; with its argument checks), the
ICP solve (``_core.register_icp``), the trust analysis (``_core.trust_analysis``: the source's
sampled normals, the per-correspondence sums, the covariances, the degeneracy, the verdict's
overlap pass) and, with the probe, its screen (``count_within``, ``orientation_symmetry``) and its
restart path (the correlative grid and ``probe_restarts``). Then the floor: the ICP call alone
in a loop, and the fixed cost of a call into the core with an array. CPU time, rounds
alternating with small_gicp's bare ICP; medians of the per-round values and ratios.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import statistics
import time
from collections import defaultdict
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import scanreg
import scanreg.register
from scanreg import _core
from trust_speed import (
    NO_PROBE,
    PROBE,
    import_small_gicp,
    intel,
    intel_pairs,
    mat4,
    ours2d,
    pad,
    small_gicp_icp,
)

REAL_PREPARE = scanreg.prepare


def set_prepare(fn: Callable[..., Any]) -> None:
    scanreg.prepare = fn  # what the loop calls
    scanreg.register.prepare = fn  # (register's own, for raw targets)


@contextlib.contextmanager
def patched(core: dict[str, Callable[..., Any]], prepare: Callable[..., Any]) -> Iterator[None]:
    """``_core``'s functions ``core`` and ``prepare`` replaced for the block, then restored."""
    real = {name: getattr(_core, name) for name in core}
    for name, fn in core.items():
        setattr(_core, name, fn)
    set_prepare(prepare)
    try:
        yield
    finally:
        for name, fn in real.items():
            setattr(_core, name, fn)
        set_prepare(REAL_PREPARE)


def replaying(pairs: list[Any], thresholds: Any, calls: list[str]) -> Callable[[], None]:
    """The loop with ``prepare`` and the core functions ``calls`` replayed."""
    real = {name: getattr(_core, name) for name in calls}
    recorded: dict[str, list[Any]] = defaultdict(list)

    def recorder(name: str, fn: Callable[..., Any]) -> Callable[..., Any]:
        def call(*args: Any, **kwargs: Any) -> Any:
            out = fn(*args, **kwargs)
            recorded[name].append(out)
            return out

        return call

    with patched(
        {name: recorder(name, real[name]) for name in calls}, recorder("prepare", REAL_PREPARE)
    ):
        ours2d(pairs, True, thresholds)

    def run() -> None:
        outs = {name: iter(values) for name, values in recorded.items()}
        for target in recorded["prepare"]:
            # What a target keeps for the probe (its grid, its symmetry) is built afresh.
            target.__dict__.pop("_grids", None)
            target.__dict__.pop("_symmetry", None)
        replays = {name: (lambda *a, _n=name, **k: next(outs[_n])) for name in calls}
        with patched(replays, lambda *a, **k: next(outs["prepare"])):
            ours2d(pairs, True, thresholds)

    return run


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--peers-site", default=None, help="site-packages holding small_gicp")
    ap.add_argument("--rounds", type=int, default=11)
    ap.add_argument(
        "--probe", action="store_true", help="with the wrong-basin probe (the 2D default)"
    )
    args = ap.parse_args()
    sg = import_small_gicp(args.peers_site)
    pairs = intel_pairs(intel())
    n = len(pairs)
    thresholds = PROBE if args.probe else NO_PROBE
    screen = ["count_within", "orientation_symmetry"]
    stages: list[tuple[str, list[str]]] = [
        ("prepare()", []),
        ("ICP solve (_core.register_icp)", ["register_icp"]),
        ("trust analysis (_core.trust_analysis)", ["trust_analysis"]),
    ]
    if args.probe:
        stages += [
            ("probe screen (count_within, orientation_symmetry)", screen),
            ("probe restart path (grid, probe_restarts)", ["CorrelativeGrid", "probe_restarts"]),
        ]
    fns: dict[str, Callable[[], Any]] = {}
    if sg is not None:
        padded = [(pad(s), pad(t), mat4(i)) for s, t, i in pairs]
        fns["small_gicp"] = lambda: small_gicp_icp(sg, padded)
    fns["full"] = lambda: ours2d(pairs, True, thresholds)
    fns["pose"] = lambda: ours2d(pairs, False, thresholds)
    replayed: list[str] = []
    for label, calls in stages:
        replayed += calls
        fns[label] = replaying(pairs, thresholds, list(replayed))
    # The floor: the ICP call alone, as the loop made it, and a call with one small array.
    icp_calls: list[tuple[Any, ...]] = []
    real_icp = _core.register_icp

    def record_icp(*a: Any) -> Any:
        icp_calls.append(a)
        return real_icp(*a)

    _core.register_icp = record_icp
    try:
        ours2d(pairs, False, thresholds)
    finally:
        _core.register_icp = real_icp
    fns["floor: the ICP call alone"] = lambda: [real_icp(*a) for a in icp_calls]
    one = np.zeros((1, 2))
    fns["floor: a core call with an array (x1 per pair)"] = lambda: [
        _core.trust_scene(one, math.inf, beam_phase=False) for _ in range(n)
    ]
    names = list(fns)
    for fn in fns.values():
        fn()
    times: dict[str, list[float]] = {name: [] for name in names}
    for r in range(args.rounds):
        for name in names[r % len(names) :] + names[: r % len(names)]:
            t0 = time.process_time()
            fns[name]()
            times[name].append((time.process_time() - t0) / n * 1e6)
    rows = [("small_gicp bare ICP", times["small_gicp"])] if sg is not None else []
    rows += [("full result", times["full"]), ("pose only", times["pose"])]
    before = times["full"]
    for label, _ in stages:
        rows.append((label, [a - b for a, b in zip(before, times[label], strict=True)]))
        before = times[label]
    rows.append(("Python around the core calls (all of the above replayed)", before))
    rows += [(name, times[name]) for name in names if name.startswith("floor")]
    probe = "with" if args.probe else "without"
    print(f"\n2D full result {probe} the probe: {n} Intel pairs, CPU µs per pair", end="")
    print(f", {args.rounds} rounds\n")
    print("| stage | µs per pair | ratio to small_gicp's bare ICP (median of rounds) |")
    print("|---|---:|---:|")
    for label, ts in rows:
        ratio = "–"
        if sg is not None:
            ratios = (a / b for a, b in zip(ts, times["small_gicp"], strict=True))
            ratio = f"{statistics.median(ratios):.3f}"
        print(f"| {label} | {statistics.median(ts):.1f} | {ratio} |", flush=True)


if __name__ == "__main__":
    main()
