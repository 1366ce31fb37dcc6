"""A 3D mapper whose graph believes the odometry drifts less than it does, shared by the 3D
mapping tests and benchmarks/mapping_3d.py: every odometry edge's σ × ``scale`` (the drift
model's rates and floors, and the covariance the odometry reports per sweep), so that the
true drift at a revisit exceeds the graph's σ by ~1 / ``scale`` (issue 38)."""

from __future__ import annotations

import dataclasses
from typing import Any

from scanreg.pipeline import Mapper3D, MappingConfig3D


def understated(config: MappingConfig3D, scale: float) -> MappingConfig3D:
    """``config`` with its odometry-edge drift model (rates and floors) × ``scale``."""
    return dataclasses.replace(
        config,
        drift_translation=config.drift_translation * scale,
        drift_rotation=config.drift_rotation * scale,
        drift_floor_translation=config.drift_floor_translation * scale,
        drift_floor_rotation=config.drift_floor_rotation * scale,
    )


def understated_mapper(config: MappingConfig3D, scale: float) -> Mapper3D:
    """A :class:`Mapper3D` on ``understated(config, scale)`` whose odometry reports its
    covariance × ``scale²`` (σ × ``scale``)."""
    mapper = Mapper3D(understated(config, scale))
    if scale == 1.0:
        return mapper
    inner = mapper._odometry.step

    def step(*args: Any, **kwargs: Any) -> Any:
        frame = inner(*args, **kwargs)
        return dataclasses.replace(frame, covariance=frame.covariance * scale**2)

    mapper._odometry.step = step  # type: ignore[method-assign]
    return mapper
