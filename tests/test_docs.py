"""The tutorials in docs/ run: every ```python block of a file, in order, in one namespace.

A tutorial names the real data it needs in a ``<!-- data: folder, folder -->`` comment; the
file is skipped with the reason when that data is absent (a failure under ``CI=true``, as in
:func:`conftest.data_dir`). Tutorials read ``SCANREG_DATA`` for the data folder and write
figures to ``SCANREG_OUT``; both are pointed at the test's folders here.
"""

from __future__ import annotations

import re
from pathlib import Path

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
