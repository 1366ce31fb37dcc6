"""The final pass of 2D mapping: every scan between two graph nodes re-solved from its scan
step and its wheel step, each weighted by noise identified on the run itself.

After loop closure (:meth:`scanreg.pipeline.Mapper.finish`) a scan that is not a node hangs
from the last node by the odometry alone: one bad scan step (a point-to-line refinement that
slid a few centimetres along a corridor) stays in every later scan of that stretch. The wheels
measure the same steps independently. Which of the two deserves how much weight differs from
robot to robot (ACES' wheels are about as precise per step as its scan matching; Intel's are
far worse, its scans far better), and neither the scan's calibrated covariance (a bound on the
pose against the map, not on one step's error) nor a wheel noise model fixed in advance says
so. The run says so:

* the disagreement ``r_k = log(W_k⁻¹ S_k)`` between the wheels' step ``W_k`` (distance rescaled
  by the ratio of the scans' to the wheels' distance over the run) and the scans' step ``S_k``
  is, per axis, the wheels' error ``w_k`` less the scans' ``ε_k − ε_{k−1}``, with ``ε_k`` each
  scan's error against the local map (the map changes slowly, so consecutive steps share it);
* the wheels' errors are independent from step to step and the scans' step errors are
  differences, hence ``cov(r_k, r_{k−1}) = −var(ε)`` and ``var(r) = var(w) + 2 var(ε)``:
  both variances from the run's residuals alone (:func:`identify_step_noise`);
* the scans' step errors have no mean, so the residuals' mean is the wheels' (a bias the
  scale does not take out; all of their error when they report no motion while the robot
  drives): the wheels' weight is their mean square error, ``var(w) + mean(r)²``.

:func:`smooth_scan_poses` then solves a pose graph over every scan — the scans' steps with
covariance ``2 var(ε)``, the wheels' with ``var(w)`` — with each node's scan held where the
loop-closed graph put it, as firmly as the graph knows a node against its neighbours. No
benchmark relation plays a part.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .._validate import FloatArray
from ..graph import Graph
from ..transform import SE2

#: Fewer consecutive residual pairs than this: no identification (and no smoothing).
MIN_PAIRS = 50
#: Least σ of either step's noise (m, m, rad): what the identification can resolve over a few
#: thousand steps; an estimate of zero (Intel's scans across and in heading) must not become
#: an infinite weight.
NOISE_FLOOR = np.array([1e-3, 1e-3, 5e-4])
#: Residuals beyond this percentile per axis are left out of the identification: a wheel
#: slip or a scan in the wrong basin is not noise and would dominate a variance.
TRIM_PERCENTILE = 99.5
#: The wheels' distance scale is the ratio of the scans' to the wheels' distance over stretches
#: of this many steps ...
SCALE_CHUNK = 20
#: ... that rolled at least this far (m).
MIN_SCALE_DISTANCE = 0.1


@dataclass(frozen=True)
class StepNoise:
    """What :func:`identify_step_noise` found on a run (per axis ``[x, y, θ]`` of a step's
    tangent: m, m, rad)."""

    #: The scans' distance per wheel distance over the run.
    scale: float
    #: σ of one scan's error against its local map (a step's error is the difference of two).
    scan: FloatArray
    #: σ of one wheel step's error (after the scale).
    wheel: FloatArray
    #: Consecutive residual pairs the variances came from.
    pairs: int

    def __post_init__(self) -> None:
        if not (isinstance(self.scale, (int, float)) and math.isfinite(self.scale)):
            raise ValueError(f"scale: expected a finite number, got {self.scale!r}")
        if not self.scale > 0:
            raise ValueError(f"scale: must be > 0, got {self.scale!r}")
        for name in ("scan", "wheel"):
            sigma = np.asarray(getattr(self, name), dtype=np.float64)
            if sigma.shape != (3,):
                raise ValueError(f"{name}: expected shape (3,) (x, y, θ), got {sigma.shape}")
            if not (np.all(np.isfinite(sigma)) and np.all(sigma > 0)):
                raise ValueError(f"{name}: expected three finite σ > 0, got {sigma.tolist()}")
            object.__setattr__(self, name, sigma)


def _scaled(wheel: SE2, scale: float) -> SE2:
    # Through the vector: from_rt would check the (already orthonormal) rotation, the pass's
    # largest cost.
    x, y = scale * wheel.translation
    return SE2.from_vector([x, y, wheel.angle])


@dataclass(frozen=True)
class ResidualMoments:
    """Per axis ``[x, y, θ]``, what consecutive step residuals ``r_k = log(W_k⁻¹ S_k)`` say
    (:func:`residual_moments`)."""

    #: var(ε): one scan's error against its local map, ``−cov(r_k, r_{k−1})`` (≥ 0).
    scan_variance: FloatArray
    #: var(r) (about the mean) and the mean of the residuals.
    variance: FloatArray
    mean: FloatArray
    #: ``(n, 3)``: which pairs each axis kept (both residuals within the trim).
    kept: np.ndarray


def residual_moments(here: FloatArray, before: FloatArray) -> ResidualMoments:
    """The moments of ``(n, 3)`` residuals ``here[k]`` whose step follows ``before[k]``'s,
    each axis trimmed at :data:`TRIM_PERCENTILE` (module docstring; shared with the wheels'
    online identification, :class:`~scanreg.pipeline.wheel.WheelOdometry`)."""
    for name, value in (("here", here), ("before", before)):
        arr = np.asarray(value)
        if arr.ndim != 2 or arr.shape[1] != 3 or arr.shape[0] == 0:
            raise ValueError(f"{name}: expected shape (n, 3) with n >= 1, got {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{name}: residuals must be finite (NaN or inf found)")
    if np.shape(here) != np.shape(before):
        raise ValueError(
            f"before: expected the shape of here {np.shape(here)}, got {np.shape(before)}"
        )
    limit = np.percentile(np.abs(np.vstack([here, before])), TRIM_PERCENTILE, axis=0)
    kept = (np.abs(here) <= limit) & (np.abs(before) <= limit)
    var_scan, var, mean = np.zeros(3), np.zeros(3), np.zeros(3)
    for i in range(3):
        keep = kept[:, i]
        mean[i] = float(here[keep, i].mean())
        a = here[keep, i] - mean[i]
        b = before[keep, i] - before[keep, i].mean()
        # A positive lag-one covariance (wheel errors that persist over steps: a heading bias
        # on a turn) leaves nothing to the scans.
        var_scan[i] = max(-float(np.mean(a * b)), 0.0)
        var[i] = float(np.mean(a * a))
    return ResidualMoments(scan_variance=var_scan, variance=var, mean=mean, kept=kept)


def identify_step_noise(
    scan_steps: Sequence[SE2 | None], wheel_steps: Sequence[SE2 | None]
) -> StepNoise | None:
    """The wheels' distance scale and the step noise of scans and wheels (module docstring)
    from the run's steps ``scan_steps[k]`` and ``wheel_steps[k]`` (``T_{k−1}_k``, ``None``
    where a step has none). ``None`` when fewer than :data:`MIN_PAIRS` consecutive steps have
    both."""
    if len(scan_steps) != len(wheel_steps):
        raise ValueError(
            f"wheel_steps: expected {len(scan_steps)} steps (one per scan step), "
            f"got {len(wheel_steps)}"
        )
    for name, steps in (("scan_steps", scan_steps), ("wheel_steps", wheel_steps)):
        for k, step in enumerate(steps):
            if step is not None and not isinstance(step, SE2):
                raise TypeError(f"{name}[{k}]: expected an SE2 or None, got {type(step).__name__}")
    # The scale over stretches of SCALE_CHUNK steps: one step's noise (millimetres across a
    # step of centimetres) would bias a ratio of single steps' lengths by a percent; over a
    # stretch the scans' error does not accumulate and the wheels' grows only as its root.
    num = den = 0.0
    scan_run, wheel_run, length = SE2.identity(), SE2.identity(), 0
    for s, w in zip(scan_steps, wheel_steps, strict=True):
        if s is None or w is None:
            scan_run, wheel_run, length = SE2.identity(), SE2.identity(), 0
            continue
        scan_run, wheel_run, length = scan_run @ s, wheel_run @ w, length + 1
        if length == SCALE_CHUNK:
            d = float(np.linalg.norm(wheel_run.translation))
            if d >= MIN_SCALE_DISTANCE:
                num += float(scan_run.translation @ wheel_run.translation) / d
                den += d
            scan_run, wheel_run, length = SE2.identity(), SE2.identity(), 0
    scale = num / den if den > 0 and num > 0 else 1.0
    residuals = [
        None if s is None or w is None else (_scaled(w, scale).inverse() @ s).log()
        for s, w in zip(scan_steps, wheel_steps, strict=True)
    ]
    pairs = [
        (a, b)
        for a, b in zip(residuals[1:], residuals[:-1], strict=True)
        if a is not None and b is not None
    ]
    if len(pairs) < MIN_PAIRS:
        return None
    moments = residual_moments(np.array([a for a, _ in pairs]), np.array([b for _, b in pairs]))
    # The residuals' mean is the wheels' too (the scans' step error has none): a bias the
    # scale does not explain, at worst wheels that report no motion while the scans move,
    # is error the final pass must not trust them with.
    var_wheel = np.maximum(moments.variance + moments.mean**2 - 2.0 * moments.scan_variance, 0.0)
    return StepNoise(
        scale=float(scale),
        scan=np.maximum(np.sqrt(moments.scan_variance), NOISE_FLOOR),
        wheel=np.maximum(np.sqrt(var_wheel), NOISE_FLOOR),
        pairs=len(pairs),
    )


def smooth_scan_poses(
    poses: Sequence[SE2],
    odometry: Sequence[SE2],
    scanned: Sequence[bool],
    wheel_steps: Sequence[SE2 | None],
    nodes: Sequence[int],
    noise: StepNoise,
    node_sigma: tuple[float, float],
) -> list[SE2]:
    """Every scan's pose re-solved (module docstring).

    ``poses``: the loop-closed ``T_world_scan`` (the start, and at the ``nodes``' scans the
    poses held); ``odometry``: ``T_odom_scan``; ``scanned[k]``: whether scan ``k``'s pose came
    from its own registration (a skipped scan's was carried on the wheels: its step enters
    only through the wheels, or with a loose σ where there were none); ``wheel_steps[k]``:
    the wheels' raw ``T_{k−1}_k`` (``None`` for none); ``node_sigma``: σ (m, rad) with which
    each node's scan is held at its pose in ``poses`` (the mapper's: its odometry edges' floor,
    how well the graph knows a node against its neighbours)."""
    n = len(poses)
    if n == 0:
        raise ValueError("poses: no pose to smooth")
    if not (len(odometry) == len(scanned) == len(wheel_steps) == n):
        raise ValueError("odometry, scanned, wheel_steps: one entry per pose expected")
    outside = [k for k in nodes if not 0 <= k < n]
    if outside:
        raise ValueError(f"nodes: indices {outside[:3]} outside the {n} poses")
    g = Graph(2)
    for k, pose in enumerate(poses):
        g.add_node(k, pose)
    if len(node_sigma) != 2 or not all(math.isfinite(v) and v > 0 for v in node_sigma):
        raise ValueError(f"node_sigma: expected two positive numbers, got {node_sigma!r}")
    held = np.diag([node_sigma[0] ** -2] * 2 + [node_sigma[1] ** -2])
    first = min(nodes, default=0)
    for k in sorted(set(nodes)):
        # The first node is the map's frame, not an estimate: held exactly (held as the others,
        # it moved ~1.5 mm / 0.3 mrad on the simulated tours, and a first-pose ATE charges
        # every scan for that).
        g.add_prior(k, poses[k], held if k != first else np.eye(3) * 1e8)
    scan_info = np.diag(1.0 / (2.0 * noise.scan**2))
    wheel_info = np.diag(1.0 / noise.wheel**2)
    loose = np.diag([0.1**-2, 0.1**-2, 0.05**-2])
    for k in range(1, n):
        wheel = wheel_steps[k]
        if wheel is not None:
            g.add_edge(k - 1, k, _scaled(wheel, noise.scale), wheel_info)
        if scanned[k] and scanned[k - 1]:
            g.add_edge(k - 1, k, odometry[k - 1].inverse() @ odometry[k], scan_info)
        elif wheel is None:
            g.add_edge(k - 1, k, odometry[k - 1].inverse() @ odometry[k], loose)
    g.optimize()
    g.move_gauge(first, poses[first])
    keys, rows = g.pose_vectors()
    order = np.argsort(keys)
    return [SE2.from_vector(rows[i]) for i in order]


__all__ = [
    "ResidualMoments",
    "StepNoise",
    "identify_step_noise",
    "residual_moments",
    "smooth_scan_poses",
]
