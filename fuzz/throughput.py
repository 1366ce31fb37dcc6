"""Executions per second of every fuzz target, as the campaign runs them against the former
harness, in one process (uninstrumented: what the reader allows; atheris adds its coverage
callbacks on top of both).

    .venv/bin/python fuzz/throughput.py [SECONDS per contender and round, default 1]

"former": the input written to a temp folder on disk and a fresh rosbags typestore per read
(what a bag read cost before scanreg.io.rosbag kept one). "now": the input in /dev/shm, the
store kept. Contenders alternate over 3 rounds over the targets' seeds; the table gives the
median exec/s of each and the ratio.
"""

from __future__ import annotations

import shutil
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import scanreg.io.rosbag as rosbag
from targets import TARGETS, Runner, scratch_dir


def rate(run: Callable[[bytes], None], seeds: list[bytes], seconds: float, fresh: bool) -> float:
    n, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        if fresh:
            rosbag._typestore.cache_clear()
        run(seeds[n % len(seeds)])
        n += 1
    return n / (time.perf_counter() - start)


def main() -> None:
    seconds = float(sys.argv[1]) if len(sys.argv) > 1 else 1.0
    print("| target | former exec/s | now exec/s | ratio |\n|---|---:|---:|---:|")
    for name, target in TARGETS.items():
        seeds = target.seeds()
        former = Runner(target, Path(tempfile.mkdtemp(prefix="scanreg-fuzz-disk-")))
        now = Runner(target, scratch_dir(name))
        old, new = [], []
        for _ in range(3):
            old.append(rate(former, seeds, seconds, fresh=True))
            new.append(rate(now, seeds, seconds, fresh=False))
        a, b = statistics.median(old), statistics.median(new)
        print(f"| {name} | {a:.0f} | {b:.0f} | {b / a:.1f} |", flush=True)
        for runner in (former, now):
            shutil.rmtree(runner.path.parent)


if __name__ == "__main__":
    main()
