"""The Gauss–Newton loop stops at its best iterate when it stalls near a minimum."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from conftest import data_dir
from scanreg import _core
from scanreg.pipeline import Odometry


def test_kitti_frame_14_stops_at_its_best_iterate(monkeypatch: pytest.MonkeyPatch) -> None:
    """Frame 14 of the KITTI sweeps against the default odometry's map: undamped Gauss–Newton
    wanders among correspondence sets (period 5, its truncated cost up and down by ~2 %) and
    ran to 15 iterations, returning an iterate costlier than one it had passed. It must stop
    early at the lowest truncated cost of its iterates (each re-run by capping the core's
    solve at k iterations, inside the call: the map changes after the step)."""
    folder = data_dir("kitti-odometry-00-frames-000-015", "velodyne")
    real = _core.register_icp
    seen: list[tuple[Any, list[float]]] = []
    watch = [False]

    def energy(out: Any, n: int, gate: float) -> float:
        # The loop's truncated cost: a point outside the gate counts as at the gate (no kernel).
        return float(out.cost + (n - out.num_in_gate) * 0.5 * gate * gate)

    def spy(*args: Any) -> Any:
        out = real(*args)
        if watch[0]:
            capped = list(args)
            n, gate = len(args[0]), float(args[6])
            costs = []
            for k in range(1, out.iterations + 1):
                capped[7] = k  # max_iterations: ends at iterate k
                costs.append(energy(real(*capped), n, gate))
            seen.append((out, [energy(out, n, gate), *costs]))
        return out

    monkeypatch.setattr(_core, "register_icp", spy)
    odo = Odometry()
    for i in range(15):
        sweep = np.fromfile(folder / f"{i:06d}.bin", dtype=np.float32).reshape(-1, 4)[:, :3]
        watch[0] = i == 14
        odo.step(sweep.astype(np.float64))
    assert len(seen) == 1
    out, (returned, *iterates) = seen[0]
    assert out.stop_reason == "converged"
    assert out.iterations <= 8, out.iterations  # 15 before the stall test
    assert returned <= min(iterates) * (1 + 1e-12), (returned, iterates)
    assert returned < iterates[-1]  # not simply the last one
