"""Run every benchmark script in this folder, one after another, each in its own process.

    .venv/bin/python benchmarks/run_all.py [--peers-site PEERS_SITE_PACKAGES]

Scripts that compare against peers (small_gicp, Open3D, ...) get ``--peers-site`` passed on when
they accept it; the peers are never a dependency of scanreg. Tables go to stdout.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
#: Scripts that compare with another build of scanreg, which only their caller can name.
NEEDS_ANOTHER_BUILD = {"odometry_against_build.py"}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--peers-site", default=None, help="site-packages holding the peers")
    args = parser.parse_args()
    failed = []
    for script in sorted(HERE.glob("*.py")):
        if script.name == Path(__file__).name:
            continue
        if script.name in NEEDS_ANOTHER_BUILD:
            print(f"\n### {script.name}: skipped (needs --against, another build)\n", flush=True)
            continue
        cmd = [sys.executable, str(script)]
        if args.peers_site and "--peers-site" in script.read_text():
            cmd += ["--peers-site", args.peers_site]
        print(f"\n### {script.name}\n", flush=True)
        if subprocess.call(cmd) != 0:
            failed.append(script.name)
    if failed:
        print(f"\nfailed: {', '.join(failed)}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
