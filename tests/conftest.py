"""Shared test helpers."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

_REPO = Path(__file__).resolve().parent.parent


def data_dir(*parts: str) -> Path:
    """The real-data folder (``../shared/data`` or ``$SCANREG_DATA``), or a sub-path of it.

    Skips the calling test with the reason when it is absent — except under ``CI=true``,
    where missing data is a failure.
    """
    root = Path(os.environ.get("SCANREG_DATA", _REPO.parent / "shared" / "data"))
    path = root.joinpath(*parts)
    if not path.exists():
        reason = f"real data not found at {path} (set SCANREG_DATA to the data folder)"
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(f"{reason}; CI=true requires it", pytrace=False)
        pytest.skip(reason)
    return path


@pytest.fixture
def data() -> Path:
    """The real-data root folder (see :func:`data_dir`)."""
    return data_dir()
