"""One version, single-sourced: the workspace Cargo.toml's, seen as ``scanreg.__version__``,
``scanreg --version``, the installed metadata, the compiled core and CHANGELOG.md's latest
release."""

from __future__ import annotations

import re
import sys
from importlib import metadata
from pathlib import Path

import pytest
import scanreg
from scanreg import _core, _version, cli

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

ROOT = Path(__file__).resolve().parent.parent


def _cargo_version() -> str:
    text = (ROOT / "Cargo.toml").read_text(encoding="utf-8")
    return str(tomllib.loads(text)["workspace"]["package"]["version"])


def test_the_version_is_cargos_everywhere() -> None:
    version = _cargo_version()
    assert re.fullmatch(r"\d+\.\d+\.\d+", version), version
    assert scanreg.__version__ == version == _core.__version__
    try:
        installed = metadata.version("scanreg")
    except metadata.PackageNotFoundError:
        pytest.skip("scanreg is not installed (a source tree on PYTHONPATH)")
    assert installed == version


def test_without_installed_metadata_the_cores_version_is_used(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    def missing(name: str) -> str:
        raise metadata.PackageNotFoundError(name)

    monkeypatch.setattr(metadata, "version", missing)
    assert _version.package_version() == _core.__version__ == _cargo_version()


def test_cli_version_flag(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_:
        cli.main(["--version"])
    assert exit_.value.code == 0
    assert capsys.readouterr().out == f"scanreg {_cargo_version()}\n"


def test_the_changelog_starts_at_this_version() -> None:
    text = (ROOT / "CHANGELOG.md").read_text(encoding="utf-8")
    assert "Keep a Changelog" in text and "Semantic Versioning" in text
    releases = re.findall(r"^## \[(\d+\.\d+\.\d+)\] - (\d{4}-\d{2}-\d{2})$", text, re.MULTILINE)
    assert releases and releases[0][0] == scanreg.__version__
