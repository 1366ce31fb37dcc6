"""Coverage-guided fuzzing campaign of one reader (atheris, libFuzzer's engine); not run in CI.

    .venv/bin/python fuzz/run.py TARGET [--findings DIR] [libFuzzer options: -runs=N -timeout=2 …]
    .venv/bin/python fuzz/run.py --list

The seed corpus is written to ``fuzz/corpus/TARGET`` (git-ignored) from the real data folder
and our writers (see ``targets.py``); libFuzzer adds what it finds there. Only scanreg's own
modules are instrumented (numpy, rosbags and the standard library run at full speed), and the
input file lives in ``/dev/shm``. A finding is a crash, a hang (``-timeout``, seconds) or an
exception other than a named refusal. Without ``--findings`` the first finding stops the run
(libFuzzer writes ``crash-*`` / ``timeout-*``); with it, unnamed exceptions are kept in DIR
(``unnamed-*``, with the traceback) and the run goes on, and DIR/progress.json counts
executions (what ``campaign.sh`` uses). Keep each finding as a regression test in
``tests/test_io_hostile.py``. One core: run targets one after another.
"""

from __future__ import annotations

import hashlib
import json
import sys
import time
import traceback
from pathlib import Path

import atheris

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

NAMES = (
    "pcd ply kitti_bin kitti_calib kitti_poses tum carmen carmen_gz carmen_bz2 g2o ros1 "
    "ros2_mcap ros2_sqlite ros_msg config las laz map_server manifest_csv manifest_tsv "
    "manifest_parquet command_configs"
)

if len(sys.argv) < 2 or sys.argv[1] == "--list":
    print(NAMES)  # before instrumenting (which prints)
    raise SystemExit(0)

with atheris.instrument_imports(include=["scanreg"]):
    import scanreg.batch
    import scanreg.config
    import scanreg.io
    import scanreg.io.occupancy  # noqa: F401

from targets import TARGETS, Runner, scratch_dir  # noqa: E402

assert set(NAMES.split()) == set(TARGETS), "NAMES must list every target"

#: Executions between two writes of progress.json (libFuzzer ends the process with exit(),
#: so nothing runs after the last input: the count is at most this many short).
PROGRESS_EVERY = 500


def main() -> None:
    target = TARGETS[sys.argv[1]]
    args = sys.argv[2:]
    findings = None
    if "--findings" in args:
        i = args.index("--findings")
        findings = Path(args[i + 1]).resolve()
        findings.mkdir(parents=True, exist_ok=True)
        del args[i : i + 2]
    corpus = HERE / "corpus" / target.name
    corpus.mkdir(parents=True, exist_ok=True)
    for seed in target.seeds():
        (corpus / hashlib.sha1(seed).hexdigest()).write_bytes(seed)
    runner = Runner(target, scratch_dir(target.name), findings)
    # An exception raised where nobody can catch it (a generator's clean-up run by the garbage
    # collector) is only printed by default: here it is a finding, charged to the input
    # being run (the garbage may be older; the report says what raised).
    unraisable: list[str] = []
    sys.unraisablehook = lambda u: unraisable.append(
        f"{u.err_msg or 'Exception ignored in'}: {u.object!r}\n"
        + "".join(traceback.format_exception(u.exc_type, u.exc_value, u.exc_traceback))
    )
    progress = None if findings is None else findings / "progress.json"
    start = time.monotonic()

    def one(data: bytes) -> None:
        runner(data)
        if unraisable:
            report = unraisable.pop(0)
            unraisable.clear()
            if progress is None:
                raise RuntimeError(f"unraisable exception: {report}")
            runner.keep(data, "unraisable " + report.splitlines()[-1], report)
        if progress is not None and runner.executions % PROGRESS_EVERY == 0:
            progress.write_text(
                json.dumps(
                    {
                        "executions": runner.executions,
                        "unnamed": runner.unnamed,
                        "seconds": round(time.monotonic() - start, 1),
                    }
                )
            )

    atheris.Setup([sys.argv[0], *args, str(corpus)], one)
    atheris.Fuzz()


if __name__ == "__main__":
    main()
