"""Sensor models: a 2D scanning laser and a spinning multi-ring 3D LiDAR, with presets.

Sensor frame: x forward, y left, z up. Angles are radians, counter-clockwise about +z.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._validate import FloatArray
from ._checks import count, finite, non_negative, positive, probability


def _check_ranges(min_range: float, max_range: float) -> None:
    positive(max_range, "max_range")
    non_negative(min_range, "min_range")
    if min_range >= max_range:
        raise ValueError(f"min_range: must be < max_range ({max_range}), got {min_range}")


@dataclass(frozen=True)
class LaserModel:
    """A 2D scanning laser (LaserScan-like).

    Beam ``i`` points at ``angle_min + i * angle_increment`` and fires at
    ``i * time_increment`` after the scan start (the mirror sweeps the field of view in
    ``scan_duration = (num_beams - 1) * time_increment``).
    """

    num_beams: int
    angle_min: float
    angle_increment: float
    max_range: float
    #: Standard deviation of the additive Gaussian range noise (m).
    range_sigma: float = 0.01
    min_range: float = 0.0
    #: Probability that a beam hitting a surface in range returns nothing.
    dropout_probability: float = 0.0
    #: Time between consecutive beams (s); 0 for an instantaneous scan.
    time_increment: float = 0.0
    name: str = "custom"

    def __post_init__(self) -> None:
        count(self.num_beams, "num_beams")
        finite(self.angle_min, "angle_min")
        positive(self.angle_increment, "angle_increment")
        if (self.num_beams - 1) * self.angle_increment >= 2 * math.pi:
            raise ValueError(
                f"angle_increment: {self.num_beams} beams of {self.angle_increment} rad "
                "exceed a full turn"
            )
        _check_ranges(self.min_range, self.max_range)
        non_negative(self.range_sigma, "range_sigma")
        probability(self.dropout_probability, "dropout_probability")
        non_negative(self.time_increment, "time_increment")

    @property
    def angles(self) -> FloatArray:
        """Beam angles ``(num_beams,)`` in the sensor frame (rad)."""
        out: FloatArray = self.angle_min + self.angle_increment * np.arange(
            self.num_beams, dtype=np.float64
        )
        return out

    @property
    def field_of_view(self) -> float:
        """Angle between the first and last beam (rad)."""
        return (self.num_beams - 1) * self.angle_increment

    @property
    def scan_duration(self) -> float:
        """Time from the first to the last beam (s)."""
        return (self.num_beams - 1) * self.time_increment

    @classmethod
    def preset(cls, name: str) -> LaserModel:
        """One of :data:`LASER_PRESETS`."""
        if name not in LASER_PRESETS:
            raise ValueError(
                f"name: unknown laser preset {name!r}; expected one of {sorted(LASER_PRESETS)}"
            )
        return LASER_PRESETS[name]


@dataclass(frozen=True)
class LidarModel:
    """A spinning multi-ring LiDAR.

    One sweep is one revolution of ``1 / rotation_rate`` seconds, split into ``num_columns``
    firing instants. Column ``c`` fires all rings at once at ``c / (num_columns · rate)``,
    at azimuth ``-π + 2π c / num_columns`` (counter-clockwise, starting behind the sensor so
    the seam of the sweep is at the back, as in KITTI).
    """

    #: Elevation of each ring (rad, positive up), ring 0 first.
    elevations: tuple[float, ...]
    #: Firing instants (azimuth steps) per revolution.
    num_columns: int
    max_range: float
    #: Revolutions per second (Hz).
    rotation_rate: float = 10.0
    range_sigma: float = 0.02
    min_range: float = 0.0
    dropout_probability: float = 0.0
    name: str = "custom"

    def __post_init__(self) -> None:
        if not isinstance(self.elevations, tuple):
            raise TypeError(
                f"elevations: expected a tuple of floats, got {type(self.elevations).__name__}"
            )
        count(len(self.elevations), "elevations (number of rings)")
        for e in self.elevations:
            if abs(finite(e, "elevations")) >= math.pi / 2:
                raise ValueError(f"elevations: must be in (-π/2, π/2), got {e}")
        count(self.num_columns, "num_columns")
        positive(self.rotation_rate, "rotation_rate")
        _check_ranges(self.min_range, self.max_range)
        non_negative(self.range_sigma, "range_sigma")
        probability(self.dropout_probability, "dropout_probability")

    @classmethod
    def uniform(
        cls,
        num_rings: int,
        lowest: float,
        highest: float,
        num_columns: int,
        max_range: float,
        *,
        rotation_rate: float = 10.0,
        range_sigma: float = 0.02,
        min_range: float = 0.0,
        dropout_probability: float = 0.0,
        name: str = "custom",
    ) -> LidarModel:
        """Rings evenly spaced from ``lowest`` to ``highest`` elevation (degrees)."""
        count(num_rings, "num_rings")
        lo, hi = finite(lowest, "lowest"), finite(highest, "highest")
        el = np.deg2rad(np.linspace(lo, hi, num_rings))
        return cls(
            tuple(float(e) for e in el),
            num_columns,
            max_range,
            rotation_rate=rotation_rate,
            range_sigma=range_sigma,
            min_range=min_range,
            dropout_probability=dropout_probability,
            name=name,
        )

    @property
    def num_rings(self) -> int:
        return len(self.elevations)

    @property
    def num_beams(self) -> int:
        return self.num_rings * self.num_columns

    @property
    def sweep_duration(self) -> float:
        return 1.0 / self.rotation_rate

    @property
    def azimuth_resolution(self) -> float:
        return 2 * math.pi / self.num_columns

    @property
    def azimuths(self) -> FloatArray:
        """Azimuth of each column ``(num_columns,)`` (rad)."""
        out: FloatArray = -math.pi + self.azimuth_resolution * np.arange(
            self.num_columns, dtype=np.float64
        )
        return out

    @property
    def column_times(self) -> FloatArray:
        """Firing time of each column after the sweep start ``(num_columns,)`` (s)."""
        out: FloatArray = np.arange(self.num_columns, dtype=np.float64) * (
            self.sweep_duration / self.num_columns
        )
        return out

    @classmethod
    def preset(cls, name: str) -> LidarModel:
        """One of :data:`LIDAR_PRESETS`."""
        if name not in LIDAR_PRESETS:
            raise ValueError(
                f"name: unknown LiDAR preset {name!r}; expected one of {sorted(LIDAR_PRESETS)}"
            )
        return LIDAR_PRESETS[name]


_DEG = math.pi / 180.0

#: 2D lasers. ``sick_lms200``: 180 beams at 1° over the front half-plane, 80 m, as in the
#: Intel Research Lab / CARMEN logs (the mirror turns at 75 Hz: 1° every 37 µs).
#: ``laser_360``: a 360° laser, 720 beams at 0.5°, 30 m, 10 Hz.
#: ``laser_361``: 361 beams at 0.5° over the front half-plane, 40 m, one 26.7 ms sweep (a SICK
#: LMS at 0.5°, 37.5 Hz; many CARMEN/Radish logs): slow enough for a fast turn to distort it.
#: The real LMS builds such a scan from two interlaced 1° passes; here the sweep is linear.
LASER_PRESETS: dict[str, LaserModel] = {
    "sick_lms200": LaserModel(
        num_beams=180,
        angle_min=-90 * _DEG,
        angle_increment=1 * _DEG,
        max_range=80.0,
        range_sigma=0.01,
        dropout_probability=0.002,
        time_increment=1.0 / 75.0 / 360.0,
        name="sick_lms200",
    ),
    "laser_360": LaserModel(
        num_beams=720,
        angle_min=-180 * _DEG,
        angle_increment=0.5 * _DEG,
        max_range=30.0,
        min_range=0.1,
        range_sigma=0.02,
        dropout_probability=0.005,
        time_increment=0.1 / 720,
        name="laser_360",
    ),
    "laser_361": LaserModel(
        num_beams=361,
        angle_min=-90 * _DEG,
        angle_increment=0.5 * _DEG,
        max_range=40.0,
        range_sigma=0.01,
        time_increment=0.0267 / 360,
        name="laser_361",
    ),
}

#: Spinning LiDARs at 10 Hz, rings evenly spaced over the vertical field of view.
#: ``hdl64``: 64 rings, +2° … −24.9°, 1800 columns (0.2°), 120 m — 115 200 beams a sweep.
#: ``hdl32``: 32 rings, +10.67° … −30.67°, 1800 columns, 100 m.
#: ``vlp16``: 16 rings, +15° … −15°, 1800 columns, 100 m.
LIDAR_PRESETS: dict[str, LidarModel] = {
    "hdl64": LidarModel.uniform(64, -24.9, 2.0, 1800, 120.0, range_sigma=0.02, name="hdl64"),
    "hdl32": LidarModel.uniform(32, -30.67, 10.67, 1800, 100.0, range_sigma=0.02, name="hdl32"),
    "vlp16": LidarModel.uniform(16, -15.0, 15.0, 1800, 100.0, range_sigma=0.03, name="vlp16"),
}
