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
``prior_covariance``).

The noise model's variances are calibrated on the run the same way: how far the wheels'
prediction actually lands from where the scans put the robot differs by a factor of ten from
robot to robot (per step of heading: Intel's wheels 0.56°, the Freiburg hospital's 0.10°,
where a fixed model says 0.06° and 0.2°). From the same well-constrained steps, the residuals
``r_k = log(W_k⁻¹ S_k)`` give per axis the scans' own error against the map (their lag-one
covariance, :func:`~scanreg.pipeline.smoothing.residual_moments`) and hence the prediction's
(the residuals' second moment less that); each axis of the model is rescaled so that over the
recent steps its variance averages the prediction's. The relations of a benchmark play no
part.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._validate import FloatArray
from ..transform import SE2, as_pose
from .odometry2d import _positive
from .smoothing import MIN_PAIRS, NOISE_FLOOR, residual_moments


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
    #: Rescale the model's variances per axis to what the run shows (module docstring), once
    #: enough consecutive well-constrained steps were observed; ``False``: the model as set.
    calibrate_noise: bool = True

    def __post_init__(self) -> None:
        for name in ("along", "across", "turn", "heading_per_metre"):
            _positive(getattr(self, name), name, allow_zero=True)
        for name in ("floor_translation", "floor_rotation", "scale_memory"):
            _positive(getattr(self, name), name)
        _positive(self.scale_settle, "scale_settle", allow_zero=True)
        _positive(self.max_scale_error, "max_scale_error")
        if self.max_scale_error <= 1.0:
            raise ValueError(f"max_scale_error: must exceed 1, got {self.max_scale_error}")
        for name in ("calibrate_scale", "calibrate_noise"):
            if not isinstance(getattr(self, name), bool):
                raise TypeError(
                    f"{name}: expected a bool, got {type(getattr(self, name)).__name__}"
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
#: The noise is calibrated over this many recent observed steps (a few minutes of driving:
#: enough pairs for a variance to a few percent, recent enough to follow a change of floor) ...
_NOISE_STEPS = 2000
#: ... and recomputed every this many observations.
_NOISE_EVERY = 50


class WheelOdometry:
    """A :class:`WheelNoise` model with the wheels' distance scale learned online.

    >>> wheels = WheelOdometry(WheelNoise())
    >>> prior, cov = wheels.prior(increment)           # scaled increment and its covariance
    >>> frame = odometry.step(points, prior=prior, prior_covariance=cov)
    >>> wheels.observe(increment, frame.motion, constrained=well_constrained(frame))
    """

    def __init__(self, noise: WheelNoise | None = None) -> None:
        model = WheelNoise() if noise is None else noise
        if not isinstance(model, WheelNoise):
            raise TypeError(f"noise: expected WheelNoise, got {type(model).__name__}")
        self.noise = model
        self._scanned = 0.0  # the scans' distance along the wheels' direction, faded
        self._rolled = 0.0  # the wheels' distance, faded alike
        self._behind = 0.0  # metres of observed steps in all
        # The noise calibration: the last _NOISE_STEPS observed steps' residuals against the
        # wheels, the model's variances for them, and whether each directly follows the
        # previous observed step; rings (step number k at row k % _NOISE_STEPS), read in
        # order by _calibrate without a Python loop over them.
        self._residuals = np.zeros((_NOISE_STEPS, 3))
        self._variances = np.zeros((_NOISE_STEPS, 3))
        self._follows = np.zeros(_NOISE_STEPS, dtype=bool)
        self._observed = 0  # steps put in the rings in all
        self._linked = False
        self._since = 0
        self._factor = np.ones(3)
        #: The last :meth:`prior`: its increment (an SE2, immutable), the scale, the scaled
        #: increment and the model's covariance of it, which :meth:`observe` of the same
        #: increment reads again (the scale only changes after that).
        self._last_prior: tuple[SE2, float, SE2, FloatArray] | None = None

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
    def noise_factor(self) -> FloatArray:
        """Per axis ``[x, y, θ]``, the factor the model's variances are multiplied by (ones
        until calibrated, or with ``calibrate_noise=False``)."""
        return self._factor.copy()

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
        cov = self.noise.covariance(motion)
        if isinstance(increment, SE2):
            self._last_prior = (increment, s, motion, cov)
        return motion, cov * np.sqrt(np.outer(self._factor, self._factor))

    def covariance(self, increment: Any) -> FloatArray:
        """The covariance of the wheels' ``increment`` as reported (unscaled: its scale error
        is in the along-track σ), the model's variances calibrated on the run as
        :meth:`prior`'s are; no state is touched."""
        motion = as_pose(increment, "increment", 2)
        out: FloatArray = self.noise.covariance(motion) * np.sqrt(
            np.outer(self._factor, self._factor)
        )
        return out

    def observe(self, increment: Any, measured: Any, *, constrained: bool = True) -> None:
        """Learn from one step: ``increment`` the wheels' raw ``T_prev_curr`` (as given to
        :meth:`prior`), ``measured`` the scan matcher's. Only a step the scans pinned
        (``constrained``: registered, accepted, no weak direction) teaches anything; any
        other breaks the chain of consecutive steps the noise calibration pairs up. Only the
        distance along the wheels' direction is compared for the scale (the heading is not
        rescaled)."""
        wheel = as_pose(increment, "increment", 2)
        scan = as_pose(measured, "measured", 2)
        assert isinstance(wheel, SE2) and isinstance(scan, SE2)
        if not isinstance(constrained, (bool, np.bool_)):
            raise TypeError(f"constrained: expected a bool, got {type(constrained).__name__}")
        if not constrained:
            self._linked = False
            return
        if self.noise.calibrate_noise:
            self._observe_noise(increment, wheel, scan)
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

    def _observe_noise(self, increment: Any, wheel: SE2, scan: SE2) -> None:
        last = self._last_prior
        if last is not None and last[0] is increment and last[1] == self.scale:
            motion, cov = last[2], last[3]  # what prior(increment) just gave
        else:
            motion, _ = self.prior(wheel)
            cov = self.noise.covariance(motion)
        row = self._observed % _NOISE_STEPS
        self._residuals[row] = (motion.inverse() @ scan).log()
        self._variances[row] = np.diag(cov)
        self._follows[row] = self._linked
        self._observed += 1
        self._linked = True
        self._since += 1
        if self._since >= _NOISE_EVERY:
            self._since = 0
            self._calibrate()

    def _calibrate(self) -> None:
        """The model's per-axis factors from the recent steps (module docstring): the
        prediction's variance (the residuals' second moment less the scans' own variance,
        floored at what a run can resolve) over the model's mean variance."""
        count = min(self._observed, _NOISE_STEPS)
        rows = (np.arange(count) + (self._observed - count)) % _NOISE_STEPS  # oldest first
        # The steps (by age) that directly follow the one before them.
        linked = np.flatnonzero(self._follows[rows[1:]]) + 1
        if len(linked) < MIN_PAIRS:
            return
        here = self._residuals[rows[linked]]
        before = self._residuals[rows[linked - 1]]
        model = self._variances[rows[linked]]
        moments = residual_moments(here, before)
        predicted = moments.variance + moments.mean**2 - moments.scan_variance
        predicted = np.maximum(predicted, NOISE_FLOOR**2)
        for i in range(3):
            kept = moments.kept[:, i]
            self._factor[i] = predicted[i] / float(model[kept, i].mean())


__all__ = ["WheelNoise", "WheelOdometry"]
