"""Wheel odometry as a prior: a noise model of a differential drive's increments, with the
wheels' distance scale calibrated online against the scan matcher.

:class:`WheelNoise` says how uncertain one wheel-odometry increment ``T_prev_curr`` is: σ
growing with the distance rolled (along and across the robot's heading) and with the turn,
over floors for a robot standing still. :class:`WheelOdometry` turns each increment into a
prior for the scan's registration — the increment with its distance rescaled by the
calibrated scale, and its covariance — and learns that scale from the scan matcher's own
steps where they are well constrained (no degenerate direction, accepted by the verdict):
the ratio of the distance the scans say the robot moved along the wheels' direction to the
distance the wheels say, over the recent path. Scan matching pins such a step to millimetres
while the wheels' scale is off by percents (a worn or differently inflated tyre: Intel's
wheels read 4.6 % long, ACES' 1.3 %); where the scans cannot pin the step (a corridor's axis)
the scaled wheels are what holds it (:meth:`scanreg.pipeline.Odometry2D.step`'s
``prior_covariance``). The relations of a benchmark play no part.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._validate import FloatArray
from ..transform import SE2, as_pose
from .odometry2d import _positive


@dataclass(frozen=True)
class WheelNoise:
    """σ of one wheel-odometry increment ``exp([x, y, θ])`` of a differential drive, per
    robot-frame axis: ``along·|x| + floor_translation`` forward, ``across·|x| +
    floor_translation`` sideways, ``turn·|θ| + heading_per_metre·|x| + floor_rotation`` in
    heading. Frozen; validated on construction (errors name the field). Metres, radians.

    The defaults are those of :func:`scanreg.simulate.wheel_odometry` (the simulated drive the
    tests run): 5 % of the distance is the uncalibrated scale error of real wheels (Intel
    4.6 %), kept as the along-track σ because the scale is only learned while the scans pin
    the steps; 2 % across is a skid on a turn; 5 % of a turn plus 1° per metre is the heading
    of two wheels whose track width and diameters are not exactly known.
    """

    along: float = 0.05
    across: float = 0.02
    turn: float = 0.05
    heading_per_metre: float = math.radians(1.0)
    floor_translation: float = 0.001
    floor_rotation: float = 1e-4
    #: Learn the wheels' distance scale online (:class:`WheelOdometry`); ``False``: take the
    #: distances as the wheels report them.
    calibrate_scale: bool = True
    #: The learned scale is used once this many metres of well-constrained steps stand behind
    #: it: a few metres make a percent of scale resolvable against millimetre scan steps.
    scale_settle: float = 2.0
    #: The scale is learned over about this much recent travel (m; older steps fade
    #: exponentially): long enough to average the scan steps' millimetres to a fraction of a
    #: percent, short enough to follow a change of floor or load.
    scale_memory: float = 50.0
    #: A learned scale outside ``[1 / max_scale_error, max_scale_error]`` is not used: a
    #: scale so far off is no calibration but a fault (wheels slipping, a wrong unit).
    max_scale_error: float = 1.25

    def __post_init__(self) -> None:
        for name in ("along", "across", "turn", "heading_per_metre"):
            _positive(getattr(self, name), name, allow_zero=True)
        for name in ("floor_translation", "floor_rotation", "scale_memory"):
            _positive(getattr(self, name), name)
        _positive(self.scale_settle, "scale_settle", allow_zero=True)
        _positive(self.max_scale_error, "max_scale_error")
        if self.max_scale_error <= 1.0:
            raise ValueError(f"max_scale_error: must exceed 1, got {self.max_scale_error}")
        if not isinstance(self.calibrate_scale, bool):
            raise TypeError(
                f"calibrate_scale: expected a bool, got {type(self.calibrate_scale).__name__}"
            )

    def covariance(self, motion: Any) -> FloatArray:
        """``(3, 3)`` covariance of the increment ``motion`` (``SE2`` or ``3x3``) over its
        right-perturbation tangent ``[ρx, ρy, θ]`` (its end frame; for a step of centimetres
        and degrees the robot frame the noise is drawn in)."""
        step = as_pose(motion, "motion", 2)
        assert isinstance(step, SE2)
        x, _, theta = step.log()
        d = abs(float(x))
        sigma = np.array(
            [
                self.along * d + self.floor_translation,
                self.across * d + self.floor_translation,
                self.turn * abs(float(theta)) + self.heading_per_metre * d + self.floor_rotation,
            ]
        )
        out: FloatArray = np.diag(sigma**2)
        return out


#: A step counts towards the scale when the wheels rolled more than this many times their
#: distance noise floor.
_MOVING = 5.0


class WheelOdometry:
    """A :class:`WheelNoise` model with the wheels' distance scale learned online.

    >>> wheels = WheelOdometry(WheelNoise())
    >>> prior, cov = wheels.prior(increment)           # scaled increment and its covariance
    >>> frame = odometry.step(points, prior=prior, prior_covariance=cov)
    >>> if well_constrained(frame):
    ...     wheels.observe(increment, frame.motion)      # the raw increment, the scans' step
    """

    def __init__(self, noise: WheelNoise | None = None) -> None:
        model = WheelNoise() if noise is None else noise
        if not isinstance(model, WheelNoise):
            raise TypeError(f"noise: expected WheelNoise, got {type(model).__name__}")
        self.noise = model
        self._scanned = 0.0  # the scans' distance along the wheels' direction, faded
        self._rolled = 0.0  # the wheels' distance, faded alike
        self._behind = 0.0  # metres of observed steps in all

    @property
    def scale(self) -> float:
        """Scan distance per wheel distance; 1 until ``scale_settle`` metres were observed or
        when the estimate is beyond ``max_scale_error``."""
        model = self.noise
        if not model.calibrate_scale or self._behind < model.scale_settle or self._rolled <= 0:
            return 1.0
        s = self._scanned / self._rolled
        if not (1.0 / model.max_scale_error <= s <= model.max_scale_error):
            return 1.0
        return s

    @property
    def observed_distance(self) -> float:
        """Metres of well-constrained steps observed so far."""
        return self._behind

    def prior(self, increment: Any) -> tuple[SE2, FloatArray]:
        """The wheels' ``increment`` (``T_prev_curr``) with its translation rescaled by
        :attr:`scale`, and its covariance (:meth:`WheelNoise.covariance`)."""
        motion = as_pose(increment, "increment", 2)
        assert isinstance(motion, SE2)
        s = self.scale
        if s != 1.0:
            motion = SE2.from_rt(motion.rotation, s * motion.translation)
        return motion, self.noise.covariance(motion)

    def observe(self, increment: Any, measured: Any) -> None:
        """Learn from one step the scans pinned: ``increment`` the wheels' raw ``T_prev_curr``
        (as given to :meth:`prior`), ``measured`` the scan matcher's. Only the distance along
        the wheels' direction is compared (the heading is not rescaled)."""
        wheel = as_pose(increment, "increment", 2)
        scan = as_pose(measured, "measured", 2)
        d = float(np.linalg.norm(wheel.translation))
        if d < _MOVING * self.noise.floor_translation:
            # Standing or turning on the spot: the wheels' distance is then their floor noise,
            # never negative, and would bias the scale low (simulated drive: 0.992-0.998
            # learned for an exact 1 when such steps counted).
            return
        along = float(scan.translation @ wheel.translation) / d
        fade = math.exp(-d / self.noise.scale_memory)
        self._scanned = fade * self._scanned + along
        self._rolled = fade * self._rolled + d
        self._behind += d


__all__ = ["WheelNoise", "WheelOdometry"]
