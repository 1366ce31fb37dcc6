"""Smoke test of an installed scanreg wheel, as a user without Rust has it.

Run by ``.ci/test-wheel`` (``make test-wheel``) as ``python -I smoke_installed.py WHEEL`` from a
folder outside the source tree, in a fresh venv holding only the wheel and its dependencies,
with no Rust toolchain on ``PATH``. Not collected by pytest (it is no ``test_*`` file): it
checks the installed copy, which the dev venv's editable install is not. Exit status 1 (an
``AssertionError``) when a check fails.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import tempfile
import zipfile
from importlib import metadata
from pathlib import Path

import numpy as np

#: What a wheel must never carry: the source tree's other folders and data files.
NOT_SHIPPED_DIRS = ("tests/", "benchmarks/", "fuzz/", "docs/", "examples/", "crates/", "python/")
DATA_SUFFIXES = (".npz", ".npy", ".pcd", ".ply", ".bag", ".mcap", ".las", ".laz", ".bz2", ".clf")


def check_environment() -> None:
    for tool in ("cargo", "rustc", "rustup"):
        assert shutil.which(tool) is None, f"{tool} is on PATH: {shutil.which(tool)}"
    import scanreg

    where = Path(scanreg.__file__).resolve()
    assert "site-packages" in where.parts, f"scanreg imported from {where}, not the install"
    core = Path(scanreg._core.__file__)
    assert core.name == "_core.abi3.so", core.name


def check_wheel(wheel: Path) -> str:
    """The wheel's name and contents; returns the version its name carries."""
    name = re.fullmatch(r"scanreg-([^-]+)-cp310-abi3-(.+)\.whl", wheel.name)
    assert name, f"{wheel.name}: expected an abi3 wheel for CPython >= 3.10"
    assert "manylinux2014_x86_64" in name.group(2).split("."), wheel.name
    with zipfile.ZipFile(wheel) as zf:
        names = zf.namelist()
        core = zf.read("scanreg/_core.abi3.so")
    assert "scanreg/py.typed" in names and "scanreg/_core.pyi" in names, names
    assert [n for n in names if n.endswith(".so")] == ["scanreg/_core.abi3.so"], names
    stray = [n for n in names if n.startswith(NOT_SHIPPED_DIRS) or n.endswith(DATA_SUFFIXES)]
    assert not stray, f"the wheel carries files it must not: {stray}"
    # manylinux2014 means glibc 2.17: no symbol of the core may need a newer one.
    glibc = {int(m) for m in re.findall(rb"GLIBC_2\.(\d+)", core)}
    assert glibc and max(glibc) <= 17, f"the core needs GLIBC_2.{max(glibc)}"
    return name.group(1)


def check_version(wheel_version: str) -> None:
    import scanreg
    from scanreg import _core

    installed = metadata.version("scanreg")
    assert installed == wheel_version == scanreg.__version__ == _core.__version__, (
        installed,
        wheel_version,
        scanreg.__version__,
        _core.__version__,
    )
    exe = shutil.which("scanreg")
    assert exe is not None and Path(exe).parent == Path(sys.executable).parent, exe
    out = subprocess.run([exe, "--version"], capture_output=True, text=True, check=True).stdout
    assert out == f"scanreg {installed}\n", out


def check_it_works() -> None:
    """The compiled core end to end: a registration against its truth, a simulated scan, a
    file round trip."""
    import scanreg
    from scanreg import io
    from scanreg import simulate as sim

    rng = np.random.default_rng(0)
    source = rng.uniform(-5, 5, (200, 2))
    truth = scanreg.SE2.from_vector([1.2, -0.7, np.deg2rad(12)])
    target = truth.apply(source) + rng.normal(0, 0.02, source.shape)
    paired = scanreg.align_paired(source, target)
    err = (paired.pose.inverse() @ truth).log()
    assert np.all(np.abs(err) < 3 * paired.standard_deviations), (err, paired.standard_deviations)
    guess = scanreg.SE2.from_vector([1.0, -0.5, np.deg2rad(8)])
    res = scanreg.register(source, target, init=guess, method="point_to_point")
    assert res.converged, res.stop_reason
    assert np.linalg.norm(res.pose.translation - truth.translation) < 0.01, res.pose
    scan = sim.simulate_scan(
        sim.floor_plan(seed=0),
        sim.LaserModel.preset("sick_lms200"),
        scanreg.SE2.from_vector([1.0, 0.3, 0.0]),
        seed=0,
    )
    assert scan.points.shape[0] > 100, scan.points.shape
    with tempfile.TemporaryDirectory() as tmp:
        cloud = np.column_stack([scan.points, np.zeros(len(scan.points))])
        io.write_points(Path(tmp) / "scan.pcd", io.PointCloud(cloud))
        back = io.read_points(Path(tmp) / "scan.pcd").points
    assert np.allclose(back, cloud, atol=1e-5)


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print("usage: python -I smoke_installed.py WHEEL", file=sys.stderr)
        return 2
    wheel = Path(argv[0])
    check_environment()
    version = check_wheel(wheel)
    check_version(version)
    check_it_works()
    print(f"smoke test of the installed {wheel.name} ({version}): passed")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
