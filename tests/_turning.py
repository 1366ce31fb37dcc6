"""Simulated turning drives shared by the sweep-distortion tests: the ``laser_361`` preset (a
361-beam 180° laser whose sweep is slow enough to distort; benchmarks/sweep_distortion.py draws
the same rooms and drives), and the drive whose yaw rate swings ±peak with a 4 s period through a
random office."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from scanreg import SE2
from scanreg import simulate as sim
from scanreg.simulate.scan import Reference

#: The preset's sweep (s): 26.7 ms, a 0.5° scan of a SICK-like mirror at 37.5 Hz.
SWEEP = 0.0267


def swept_laser(sweep: float = SWEEP) -> sim.LaserModel:
    """The ``laser_361`` preset with its beams ``sweep`` apart end to end."""
    laser = sim.LaserModel.preset("laser_361")
    return dataclasses.replace(laser, time_increment=sweep / (laser.num_beams - 1))


def turning_run(
    seed: int, peak_deg: float, *, num_scans: int, reference: Reference = "start"
) -> sim.SimulatedRun:
    """``num_scans`` scans 0.1 s apart of :func:`swept_laser` along a 0.3 m/s drive through
    ``floor_plan(seed)``, its yaw rate swinging ±``peak_deg`` °/s with a 4 s period, from a
    start drawn by ``seed``."""
    scene = sim.floor_plan(seed=seed, num_people=0)
    rng = np.random.default_rng(seed)
    start = SE2.from_vector([rng.uniform(3, 7), rng.uniform(3, 5), rng.uniform(-3, 3)])
    path = sim.Trajectory.from_speed_and_yaw_rate(
        0.3,
        0.0,
        duration=4.2,
        start=start,
        yaw_rate_amplitude=math.radians(peak_deg),
        yaw_rate_period=4.0,
    )
    return sim.simulate_run(
        scene,
        swept_laser(),
        path,
        num_scans=num_scans,
        scan_rate=10.0,
        seed=seed,
        reference=reference,
    )
