"""The tutorials in docs/ run: every ```python block of a file, in order, in one namespace.

A tutorial names the real data it needs in a ``<!-- data: folder, folder -->`` comment; the
file is skipped with the reason when that data is absent (a failure under ``CI=true``, as in
:func:`conftest.data_dir`). Tutorials read ``SCANREG_DATA`` for the data folder and write
figures to ``SCANREG_OUT``; both are pointed at the test's folders here.
"""

from __future__ import annotations

import ast
import builtins
import re
from pathlib import Path
from typing import Any

import pytest
from conftest import data_dir

DOCS = Path(__file__).resolve().parent.parent / "docs"
TUTORIALS = sorted(DOCS.glob("tutorial_*.md"))
_BLOCK = re.compile(r"^```python\n(.*?)^```", re.DOTALL | re.MULTILINE)
_DATA = re.compile(r"<!--\s*data:\s*(.*?)\s*-->")


def python_blocks(text: str) -> list[str]:
    return [m.group(1) for m in _BLOCK.finditer(text)]


def test_there_are_tutorials() -> None:
    names = {p.name for p in TUTORIALS}
    assert {"tutorial_pairwise.md", "tutorial_kitti.md", "tutorial_2d_logs.md"} <= names


@pytest.mark.parametrize("path", TUTORIALS, ids=lambda p: p.name)
def test_tutorial_runs(path: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip("matplotlib")
    text = path.read_text(encoding="utf-8")
    needed = [d.strip() for m in _DATA.finditer(text) for d in m.group(1).split(",")]
    for folder in needed:
        data_dir(folder)  # skips (or fails under CI=true) when absent
    monkeypatch.setenv("SCANREG_DATA", str(data_dir()) if needed else "/nonexistent")
    monkeypatch.setenv("SCANREG_OUT", str(tmp_path))
    blocks = python_blocks(text)
    assert blocks, f"{path.name} has no python blocks"
    namespace: dict[str, object] = {"__name__": f"docs.{path.stem}"}
    for number, block in enumerate(blocks, start=1):
        # dont_inherit: a tutorial runs like a script, without this file's __future__ imports
        code = compile(block, f"{path.name} [python block {number}]", "exec", dont_inherit=True)
        exec(code, namespace)  # running the documentation is the point
    figures = [p for p in tmp_path.iterdir() if p.suffix in (".png", ".svg")]
    assert all(p.stat().st_size > 1000 for p in figures)


def test_readme_links_the_docs() -> None:
    readme = (DOCS.parent / "README.md").read_text(encoding="utf-8")
    for path in [*TUTORIALS, DOCS / "api.md", DOCS / "concepts.md"]:
        assert f"docs/{path.name}" in readme, f"README.md does not link docs/{path.name}"


def test_api_reference_covers_the_public_surface() -> None:
    """docs/api.md (written by docs/gen_api.py) documents the main entry points."""
    text = (DOCS / "api.md").read_text(encoding="utf-8")
    for name in (
        "scanreg.register",
        "scanreg.align_paired",
        "scanreg.SE3",
        "scanreg.prepare",
        "scanreg.io.read_points",
        "scanreg.eval.absolute_trajectory_error",
        "scanreg.verdict.assess",
        "scanreg.simulate.simulate_run",
        "scanreg.plot",
    ):
        assert f"`{name}" in text, name


# ---------------------------------------------------------------------------- README.md

README = DOCS.parent / "README.md"
INTEL = "carmen-intel/intel_gfs_subset_clf_timestamps.clf"

# What the README leaves to the reader ("your map", "your sweeps"), keyed by the first line of
# the block that reads it: the code here makes those names and the files the block opens,
# and nothing else (checked below); the block itself runs exactly as written.
GIVEN: dict[str, str] = {
    "map_target = scanreg.prepare(map_points": """
from scanreg import simulate as _sim
_run = _sim.simulate_run(
    _sim.floor_plan(seed=1), _sim.LaserModel.preset("sick_lms200"),
    _sim.Trajectory.from_speed_and_yaw_rate(
        0.5, 0.2, duration=1.0, start=scanreg.SE2.from_vector([1, 0, 0])
    ),
    num_scans=3, seed=0,
)
map_points, scan = _run.scans[0].points, _run.scans[2].points
_offset = scanreg.SE2.from_vector([0.05, -0.03, 0.02])
T_guess = _run.scans[0].pose.inverse() @ _run.scans[2].pose @ _offset
""",
    "from scanreg.verdict import assess": """
points = scan
timestamps = np.linspace(0.0, 0.1, len(points))
velocity = np.array([0.5, 0.0, 0.2])
""",
    "res = scanreg.register_global(source_cloud": """
from scanreg import simulate as _sim
_sweep = _sim.simulate_sweep(
    _sim.street(seed=0), _sim.LidarModel.preset("vlp16"),
    _sim.Trajectory.from_speed_and_yaw_rate(
        5.0, 0.0, duration=0.1, dim=3, start=scanreg.SE3.from_vector([0, 1.75, 1.73, 0, 0, 0])
    ),
)
target_cloud = scanreg.preprocess.voxel_downsample(_sweep.points_deskewed, 0.3).points
source_cloud = scanreg.SE3.from_vector([1.5, -0.8, 0.1, 0.0, 0.0, 0.6]).apply(target_cloud)
""",
    "odo = scanreg.Odometry(scanreg.OdometryConfig())": """
from scanreg import simulate as _sim
_drive = _sim.simulate_run(
    _sim.street(seed=0), _sim.LidarModel.preset("vlp16"),
    _sim.Trajectory.from_speed_and_yaw_rate(
        8.0, 0.0, duration=0.6, dim=3, start=scanreg.SE3.from_vector([0, 1.75, 1.73, 0, 0, 0])
    ),
    num_scans=4, seed=0,
)
sweeps = [(_s.points, _s.timestamps) for _s in _drive.scans]
prior_map_points = np.vstack([_s.pose.apply(_s.points_deskewed) for _s in _drive.scans])
rough_guess = _drive.scans[-1].pose @ scanreg.SE3.from_vector([0.3, -0.2, 0.0, 0.0, 0.0, 0.03])
""",
    'log = scanreg.io.read_scans("intel.clf")': """
_lines, _scans = [], 0
for _line in (DATA / INTEL).read_text().splitlines(keepends=True):
    _scans += _line.startswith(("FLASER", "ROBOTLASER1", "RAWLASER"))
    if _scans > 120:
        break
    _lines.append(_line)
Path("intel.clf").write_text("".join(_lines))  # the log's first 120 scans
""",
    "from scanreg.pipeline import Localizer2D": """
from scanreg.pipeline import write_outputs as _write
_write("out/", scanreg.pipeline.run_mapping(log), plot=False)  # what `scanreg map intel.clf` writes
points = log.scans[60].to_points(0.1, 40.0)
wheel_motion = log.motion_prior(59, 60)
""",
    "from scanreg.pipeline import Mapper, MappingConfig": """
import bz2 as _bz2
Path("intel.clf.bz2").write_bytes(_bz2.compress(Path("intel.clf").read_bytes()))
node = 1
""",
    "from scanreg import interop, io, plot": """
import shutil as _shutil
_shutil.copy(DATA / "rosbag1-laserscan-ccny-demo/demo.bag", "demo.bag")
scanreg.io.write_run_bag(
    "drive", [0.0, 0.1], [np.eye(4), np.eye(4)], scans=[_p for _p, _t in sweeps[:2]],
    topics=scanreg.io.BagTopics(scan="/velodyne_points"),
)
""",
    "from scanreg import place": """
frame_index = 0
""",
}


def free_names(code: str) -> set[str]:
    """Names a block reads that it does not bind itself (anywhere in it) and that are not
    builtins: what must exist before it runs."""
    tree = ast.parse(code)
    bound: set[str] = set()
    read: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Name):
            (read if isinstance(node.ctx, ast.Load) else bound).add(node.id)
        elif isinstance(node, ast.alias):
            bound.add((node.asname or node.name).split(".")[0])
        elif isinstance(node, (ast.FunctionDef, ast.ClassDef)):
            bound.add(node.name)
        elif isinstance(node, ast.arg):
            bound.add(node.arg)
    return read - bound - set(dir(builtins))


def given_names(code: str) -> set[str]:
    """The names a GIVEN defines for its block (its ``_helpers`` stay inside it)."""
    names = set()
    for node in ast.walk(ast.parse(code)):
        if isinstance(node, ast.Name) and not isinstance(node.ctx, ast.Load):
            names.add(node.id)
        elif isinstance(node, ast.alias):
            names.add((node.asname or node.name).split(".")[0])
    return {n for n in names if not n.startswith("_")}


def test_readme_blocks_run_as_written(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Every ```python block of README.md runs, in order and in one namespace, as a reader
    who pastes them one after another would run them. Before a block runs its GIVEN (the
    reader's own data): it may define only names the block reads, and every name the
    block reads must be defined by then."""
    pytest.importorskip("matplotlib")
    pytest.importorskip("gtsam")
    pytest.importorskip("rosbags")
    data = data_dir("carmen-intel").parent
    data_dir("rosbag1-laserscan-ccny-demo")
    monkeypatch.chdir(tmp_path)
    blocks = python_blocks(README.read_text(encoding="utf-8"))
    firsts = [b.splitlines()[0] for b in blocks]
    for key in GIVEN:
        assert sum(f.startswith(key) for f in firsts) == 1, f"GIVEN[{key!r}]: not one block"
    namespace: dict[str, Any] = {"__name__": "readme"}
    for number, block in enumerate(blocks, start=1):
        where = f"README.md [python block {number}]"
        given = next((g for k, g in GIVEN.items() if firsts[number - 1].startswith(k)), "")
        needs, defines = free_names(block), given_names(given)
        assert not defines - needs, f"{where}: its GIVEN defines {sorted(defines - needs)}, unread"
        if given:
            scratch = {**namespace, "DATA": data, "INTEL": INTEL, "Path": Path}
            exec(compile(given, f"{where} GIVEN", "exec", dont_inherit=True), scratch)
            namespace.update({n: scratch[n] for n in defines})
        undefined = needs - set(namespace)
        assert not undefined, f"{where} reads {sorted(undefined)}, defined nowhere before it"
        exec(compile(block, where, "exec", dont_inherit=True), namespace)
