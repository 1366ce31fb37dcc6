"""The memory budget: a request whose estimated peak exceeds it is refused with a clear error
before anything is allocated; without a budget nothing changes."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest
import scanreg
from scanreg import LocalMap, MemoryBudgetExceeded, budget
from scanreg.preprocess import voxel_downsample


@pytest.fixture(autouse=True)
def _no_budget_after() -> Iterator[None]:
    before = scanreg.memory_budget()
    yield
    scanreg.set_memory_budget(before)


def test_requests_over_the_budget_are_refused_by_name() -> None:
    pts = np.random.default_rng(0).uniform(-5, 5, (30_000, 3))
    scanreg.set_memory_budget("1M")
    assert scanreg.memory_budget() == 1 << 20
    with pytest.raises(MemoryBudgetExceeded, match=r"prepare: points: 30000 points would need"):
        scanreg.prepare(pts)
    with pytest.raises(MemoryBudgetExceeded, match=r"index \+ normals \+ covariances"):
        scanreg.prepare(pts, covariances=True)
    with pytest.raises(MemoryBudgetExceeded, match="over the memory budget of 1 MiB"):
        LocalMap(3, 0.5, 20).insert(pts)
    with pytest.raises(MemoryBudgetExceeded, match="voxel_downsample: points"):
        voxel_downsample(pts, 0.5)
    small = scanreg.prepare(pts[:2000])  # 2000 × 160 B fits in 1 MiB
    with pytest.raises(MemoryBudgetExceeded, match="register: source"):
        scanreg.register(pts, small, method="point_to_plane")
    # A MemoryError: code that already handles running out of memory handles this too.
    assert issubclass(MemoryBudgetExceeded, MemoryError)


def test_no_budget_changes_nothing() -> None:
    scanreg.set_memory_budget(None)
    pts = np.random.default_rng(1).uniform(-5, 5, (5000, 3))
    a = scanreg.register(pts[::2], scanreg.prepare(pts), method="point_to_plane")
    scanreg.set_memory_budget("10G")
    b = scanreg.register(pts[::2], scanreg.prepare(pts), method="point_to_plane")
    assert np.array_equal(a.pose.as_matrix(), b.pose.as_matrix())


@pytest.mark.parametrize(
    ("value", "exc", "match"),
    [
        (0, ValueError, "max_bytes: must be > 0"),
        ("lots", ValueError, "max_bytes: expected bytes like"),
        (True, TypeError, "max_bytes: expected bytes"),
        (1.5, TypeError, "max_bytes: expected bytes"),
    ],
)
def test_bad_budgets_are_named(value: object, exc: type[Exception], match: str) -> None:
    with pytest.raises(exc, match=match):
        scanreg.set_memory_budget(value)  # type: ignore[arg-type]


def test_sizes_parse_with_units_and_the_environment_is_read() -> None:
    import subprocess
    import sys

    scanreg.set_memory_budget("1.5G")
    assert scanreg.memory_budget() == int(1.5 * (1 << 30))
    scanreg.set_memory_budget("512MiB")
    assert scanreg.memory_budget() == 512 << 20
    code = "import scanreg; print(scanreg.memory_budget())"
    out = subprocess.run(
        [sys.executable, "-c", code],
        env={"SCANREG_MEMORY_BUDGET": "2G", "PATH": ""},
        capture_output=True,
        text=True,
        check=True,
    )
    assert out.stdout.strip() == str(2 << 30)
    assert budget.BYTES_PER_POINT["index"] > 0
