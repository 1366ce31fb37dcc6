"""Executions per second of every fuzz target, against the targets and readers of another
commit (uninstrumented: what the reader allows; atheris adds its coverage callbacks on top).

    .venv/bin/python fuzz/throughput.py [--against REV] [--seconds S] [TARGET ...]

``REV`` (default ``main``): its ``python/scanreg`` and ``fuzz/`` are extracted with ``git
archive`` into a temporary folder, with this tree's compiled core copied in (the core's
speed is not what this measures). Each contender runs in its own worker process (this
script with ``--worker``), fed the target's seeds in turn through the ``Runner`` of its own
``fuzz/targets.py``; contenders alternate over 3 rounds of ``S`` seconds (default 1) per
target, and the table gives the median exec/s of each and the ratio. A target the other
commit lacks shows "—".
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from io import BytesIO
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent


def worker(name: str, seconds: float) -> None:
    """Print the exec/s of target ``name`` of the ``targets`` module on PYTHONPATH."""
    sys.path.pop(0)  # this script's folder: the tree measured is on PYTHONPATH
    from targets import TARGETS, Runner, scratch_dir

    if name not in TARGETS:
        print("nan")
        return
    target = TARGETS[name]
    seeds = target.seeds()
    run = Runner(target, scratch_dir(name))
    for seed in seeds:  # warm up: imports, type stores, caches
        run(seed)
    n, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        run(seeds[n % len(seeds)])
        n += 1
    print(n / (time.perf_counter() - start))
    shutil.rmtree(run.path.parent)


def extract(rev: str, into: Path) -> Path:
    """``python/`` and ``fuzz/`` of commit ``rev`` in ``into``, with this tree's core."""
    tar = subprocess.run(
        ["git", "-C", str(ROOT), "archive", rev, "python", "fuzz"],
        check=True,
        capture_output=True,
    ).stdout
    with tarfile.open(fileobj=BytesIO(tar)) as t:
        t.extractall(into, filter="data")
    for core in (ROOT / "python/scanreg").glob("_core*.so"):
        shutil.copy2(core, into / "python/scanreg" / core.name)
    return into


def rate(tree: Path, name: str, seconds: float, data: Path) -> float:
    path = f"{tree / 'fuzz'}{os.pathsep}{tree / 'python'}"
    env = dict(os.environ, PYTHONPATH=path, SCANREG_DATA=str(data))
    out = subprocess.run(
        [sys.executable, __file__, "--worker", name, "--seconds", str(seconds)],
        check=True,
        capture_output=True,
        text=True,
        env=env,
        cwd=tree,
    ).stdout
    return float(out.split()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("targets", nargs="*")
    parser.add_argument("--against", default="main")
    parser.add_argument("--seconds", type=float, default=1.0)
    parser.add_argument("--worker", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        worker(args.worker, args.seconds)
        return
    sys.path.insert(0, str(HERE))
    from targets import DATA, TARGETS

    rev = subprocess.run(
        ["git", "-C", str(ROOT), "rev-parse", "--short", args.against],
        check=True,
        capture_output=True,
        text=True,
    ).stdout.strip()
    print(f"| target | {rev} exec/s | this tree exec/s | ratio |\n|---|---:|---:|---:|")
    with tempfile.TemporaryDirectory(prefix="scanreg-throughput-") as d:
        old_tree = extract(args.against, Path(d))
        for name in args.targets or list(TARGETS):
            old, new = [], []
            for _ in range(3):
                old.append(rate(old_tree, name, args.seconds, DATA))
                new.append(rate(ROOT, name, args.seconds, DATA))
            a, b = statistics.median(old), statistics.median(new)
            before = "—" if a != a else f"{a:.0f}"
            ratio = "—" if a != a else f"{b / a:.1f}"
            print(f"| {name} | {before} | {b:.0f} | {ratio} |", flush=True)


if __name__ == "__main__":
    main()
