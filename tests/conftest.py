"""Shared test helpers."""

from __future__ import annotations

import dataclasses
import math
import os
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
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


def interrupt_mapping_at(monkeypatch: pytest.MonkeyPatch, index: int) -> None:
    """Make the 2D mapper raise KeyboardInterrupt (Ctrl-C) as it takes scan ``index``."""
    from scanreg.pipeline import mapping

    integrate = mapping.Mapper.integrate

    def interrupted(self: mapping.Mapper, tracked: mapping.Tracked) -> mapping.MappingStep:
        if tracked.index == index:
            raise KeyboardInterrupt
        return integrate(self, tracked)

    monkeypatch.setattr(mapping.Mapper, "integrate", interrupted)


@pytest.fixture
def data() -> Path:
    """The real-data root folder (see :func:`data_dir`)."""
    return data_dir()


@cache
def office_map() -> tuple[Any, np.ndarray[Any, np.dtype[np.float64]]]:
    """A room of the simulated office (``floor_plan(seed=1)``, no people), outlined densely by
    four noise-free 360° scans, in the world frame; shared by the 2D matcher tests."""
    from scanreg import SE2
    from scanreg import simulate as sim

    scene = sim.floor_plan(seed=1, num_people=0)
    dense = dataclasses.replace(
        sim.LaserModel.preset("laser_360"),
        range_sigma=0.0,
        dropout_probability=0.0,
        num_beams=2880,
        angle_increment=2 * math.pi / 2880,
    )
    parts = []
    for p in ([3.0, 3.7, 0.0], [3.0, 3.7, 1.0], [2.2, 3.2, 2.0], [4.0, 4.4, -1.0]):
        pose = SE2.from_vector(p)
        parts.append(pose.apply(sim.simulate_scan(scene, dense, pose, seed=7).points))
    return scene, np.ascontiguousarray(np.vstack(parts), dtype=np.float64)
