"""Run :class:`~scanreg.Odometry` over a whole sequence: the loop behind ``scanreg odometry``.

:func:`run_odometry` steps through a :class:`~scanreg.io.ScanSequence` (KITTI folder, folder of
point files, ROS bag, ``sim:street``) with an optional progress bar, and returns the poses,
per-frame results and a flat quality table; :func:`evaluate_run` scores it against the
sequence's ground truth (ATE after SE(3) alignment, KITTI drift over short segments).
"""

from __future__ import annotations

import dataclasses
import re
import time
from collections import Counter
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._progress import Progress
from .._validate import FloatArray
from .odometry import FrameResult, Odometry, OdometryConfig


@dataclass(frozen=True)
class OdometryRun:
    """What :func:`run_odometry` returns."""

    config: OdometryConfig
    frames: tuple[FrameResult, ...]
    #: ``(K, 4, 4)`` ``T_world_lidar`` per frame (world = the first frame).
    poses: FloatArray
    #: ``(K,)`` frame times (s).
    stamps: FloatArray
    #: Wall-clock seconds of the whole loop (reading the frames included).
    seconds: float
    #: Seconds spent inside ``Odometry.step`` only.
    step_seconds: float
    #: The odometry after the last frame (its local map, e.g. for ``save_map``).
    odometry: Odometry = dataclasses.field(repr=False, compare=False)

    @property
    def frames_per_second(self) -> float:
        return len(self.frames) / self.step_seconds if self.step_seconds > 0 else float("inf")

    @property
    def num_accepted(self) -> int:
        return sum(f.verdict.accepted for f in self.frames)

    def rejection_reasons(self) -> dict[str, int]:
        """How often each kind of reason occurred: the text before its first ``:`` or
        figure (``"overlap"``, ``"not converged"``, ``"inlier RMSE"``, ``"degenerate"``)."""
        kinds: Counter[str] = Counter()
        for f in self.frames:
            for reason in f.verdict.reasons:
                kinds[re.split(r"[:\d]", reason, maxsplit=1)[0].strip()] += 1
        return dict(kinds)

    def quality_rows(self) -> list[dict[str, Any]]:
        """One flat row per frame (for JSON lines / CSV)."""
        return [quality_row(f, stamp) for f, stamp in zip(self.frames, self.stamps, strict=True)]


def quality_row(frame: FrameResult, stamp: float) -> dict[str, Any]:
    """The per-frame quality table row: pose, σ per axis, verdict, registration statistics."""
    sd = np.sqrt(np.clip(np.diag(frame.covariance), 0, None))
    q = frame.quality
    reg = frame.registration
    row: dict[str, Any] = {
        "frame": frame.index,
        "stamp": float(stamp),
        "accepted": frame.verdict.accepted,
        "reasons": "; ".join(frame.verdict.reasons),
        "held_directions": "; ".join(frame.held_directions),
        "x": float(frame.pose.translation[0]),
        "y": float(frame.pose.translation[1]),
        "z": float(frame.pose.translation[2]),
        "sigma_x": float(sd[0]),
        "sigma_y": float(sd[1]),
        "sigma_z": float(sd[2]),
        "sigma_roll": float(sd[3]),
        "sigma_pitch": float(sd[4]),
        "sigma_yaw": float(sd[5]),
        "gate": frame.gate,
        "num_points": frame.num_points,
        "num_source_points": frame.num_source_points,
        "num_map_points": frame.num_map_points,
        "overlap": None if q is None else q.overlap,
        "residual_rmse": None if q is None else q.residual_rmse,
        "iterations": None if reg is None else reg.iterations,
        "stop_reason": None if reg is None else reg.stop_reason,
        "scaled_condition_number": None if q is None else q.conditioning.scaled_condition_number,
        "time_ms": 1e3 * frame.timing.total,
    }
    for stage in ("deskew", "downsample", "align", "judge", "update"):
        row[f"time_{stage}_ms"] = 1e3 * getattr(frame.timing, stage)
    return row


def run_odometry(
    sequence: Any,
    config: OdometryConfig | None = None,
    *,
    max_frames: int | None = None,
    progress: bool = False,
) -> OdometryRun:
    """Odometry over ``sequence`` (anything with ``len()`` and indexable
    :class:`~scanreg.io.SequenceFrame` items), at most ``max_frames`` frames."""
    cfg = OdometryConfig() if config is None else config
    odo = Odometry(cfg)
    n = len(sequence) if max_frames is None else min(len(sequence), int(max_frames))
    if n < 1:
        raise ValueError(f"sequence: has no frames to process (max_frames={max_frames})")
    frames: list[FrameResult] = []
    stamps: list[float] = []
    bar = Progress(n, description="odometry", unit="frames", enabled=progress)
    t_start = time.perf_counter()
    in_step = 0.0
    accepted = rejected = 0
    for k, frame in enumerate(sequence):
        if k >= n:
            break
        t0 = time.perf_counter()
        res = odo.step(frame.points, frame.timestamps, stamp=frame.stamp)
        in_step += time.perf_counter() - t0
        frames.append(res)
        stamps.append(float(frame.stamp))
        accepted += res.verdict.accepted
        rejected += not res.verdict.accepted
        bar.update(accepted=accepted, rejected=rejected)
    bar.close()
    return OdometryRun(
        config=cfg,
        frames=tuple(frames),
        poses=np.array([f.pose.as_matrix() for f in frames]),
        stamps=np.array(stamps),
        seconds=time.perf_counter() - t_start,
        step_seconds=in_step,
        odometry=odo,
    )


def evaluate_run(run: OdometryRun, ground_truth: Any) -> dict[str, float]:
    """ATE (SE(3)-aligned RMSE, m) and KITTI drift over 5/10 m segments against
    ``ground_truth`` (``(K', 4, 4)``, ``K' >= K``, the same frames in the same order)."""
    from ..eval import absolute_trajectory_error, kitti_odometry_error
    from ..io import Trajectory

    gt = np.asarray(ground_truth, dtype=np.float64)[: len(run.poses)]
    est_t = Trajectory(run.poses, run.stamps)
    gt_t = Trajectory(gt, run.stamps)
    ate = absolute_trajectory_error(est_t, gt_t, alignment="se3")
    out = {
        "ate_rmse_m": float(ate.translation.rmse),
        "end_error_m": float(np.linalg.norm(run.poses[-1][:3, 3] - gt[-1][:3, 3])),
        "path_length_m": float(np.sum(np.linalg.norm(np.diff(gt[:, :3, 3], axis=0), axis=1))),
    }
    try:
        kitti = kitti_odometry_error(est_t, gt_t, lengths=(5.0, 10.0), step=1)
        out["kitti_translation_percent"] = float(kitti.translation_percent)
        out["kitti_rotation_deg_per_100m"] = 100.0 * float(kitti.rotation_deg_per_m)
    except ValueError:  # too short for any segment
        pass
    return out
