"""The package version, single-sourced: the workspace ``Cargo.toml`` ``version``.

maturin writes it into the wheel's metadata (``pyproject.toml``: ``dynamic = ["version"]``)
and the compiled core carries it too (``env!("CARGO_PKG_VERSION")``). The installed
distribution's metadata is read first; a tree used without installing (``PYTHONPATH``) falls
back to the core's copy.
"""

from __future__ import annotations

from importlib import metadata


def package_version() -> str:
    """``scanreg``'s version (PEP 440), e.g. ``"0.1.0"``."""
    try:
        return metadata.version("scanreg")
    except metadata.PackageNotFoundError:
        from ._core import __version__ as core_version

        return str(core_version)


__version__ = package_version()
