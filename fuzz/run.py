"""Coverage-guided fuzzing campaign of one reader (atheris, libFuzzer's engine); not run in CI.

    .venv/bin/python fuzz/run.py TARGET [libFuzzer options, e.g. -runs=1000000 -timeout=2]
    .venv/bin/python fuzz/run.py --list

The seed corpus is written to ``fuzz/corpus/TARGET`` (git-ignored) from the real data folder
and our writers (see ``targets.py``); libFuzzer adds what it finds there. A finding is a
crash, a hang (``-timeout``, seconds) or an exception other than a named refusal; libFuzzer
writes the input to ``crash-*`` / ``timeout-*``: keep each as a regression test in
``tests/test_fuzz.py``. One core: run targets one after another.
"""

from __future__ import annotations

import hashlib
import sys
import tempfile
from pathlib import Path

import atheris

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

NAMES = (
    "pcd ply kitti_bin kitti_calib kitti_poses tum carmen carmen_gz carmen_bz2 g2o ros1 ros2 config"
)

if len(sys.argv) < 2 or sys.argv[1] == "--list":
    print(NAMES)  # before instrumenting (which prints)
    raise SystemExit(0)

with atheris.instrument_imports(include=["scanreg"]):
    import scanreg.config
    import scanreg.io  # noqa: F401

from targets import TARGETS, Runner  # noqa: E402

assert set(NAMES.split()) == set(TARGETS), "NAMES must list every target"


def main() -> None:
    target = TARGETS[sys.argv[1]]
    corpus = HERE / "corpus" / target.name
    corpus.mkdir(parents=True, exist_ok=True)
    for seed in target.seeds():
        (corpus / hashlib.sha1(seed).hexdigest()).write_bytes(seed)
    work = Path(tempfile.mkdtemp(prefix=f"scanreg-fuzz-{target.name}-"))
    runner = Runner(target, work)
    atheris.Setup([sys.argv[0], *sys.argv[2:], str(corpus)], runner)
    atheris.Fuzz()


if __name__ == "__main__":
    main()
