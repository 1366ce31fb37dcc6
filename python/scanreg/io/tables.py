"""Per-frame result tables (lists of flat dicts) as JSON lines or CSV, and pose lists as
KITTI / TUM trajectory files.

>>> rows = [{"frame": 0, "accepted": True, "fitness": 0.93, "reasons": ""}, ...]
>>> write_rows("quality.jsonl", rows)          # one JSON object per line
>>> write_rows("quality.csv", rows)            # header from the keys, in first-seen order
>>> write_poses("poses_kitti.txt", poses, "kitti")
>>> write_poses("poses_tum.txt", poses, "tum", timestamps=stamps)
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..transform import SE3
from ._common import PathLike
from .trajectory import Trajectory, write_kitti_poses, write_tum

#: Table writers by extension.
ROW_FORMATS = (".jsonl", ".csv")


def _scalar(value: Any, key: str, index: int) -> Any:
    """A JSON/CSV-ready scalar: numpy scalars unwrapped; nested values refused."""
    if isinstance(value, np.generic):
        value = value.item()
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    raise TypeError(
        f"rows[{index}][{key!r}]: expected a scalar (bool, int, float, str or None), "
        f"got {type(value).__name__}; flatten it into named columns"
    )


def _checked_rows(rows: Iterable[Mapping[str, Any]]) -> tuple[list[dict[str, Any]], list[str]]:
    out: list[dict[str, Any]] = []
    columns: dict[str, None] = {}
    for i, row in enumerate(rows):
        if not isinstance(row, Mapping):
            raise TypeError(f"rows[{i}]: expected a mapping, got {type(row).__name__}")
        clean = {}
        for key, value in row.items():
            if not isinstance(key, str):
                raise TypeError(f"rows[{i}]: keys must be str, got {key!r}")
            clean[key] = _scalar(value, key, i)
            columns.setdefault(key, None)
        out.append(clean)
    return out, list(columns)


def _json_value(value: Any) -> Any:
    # JSON has no NaN/inf: write null (the CSV keeps "nan"/"inf")
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def write_jsonl(path: PathLike, rows: Iterable[Mapping[str, Any]]) -> Path:
    """One JSON object per line (non-finite floats become ``null``)."""
    checked, _ = _checked_rows(rows)
    p = Path(path)
    with p.open("w", encoding="utf-8") as fh:
        for row in checked:
            fh.write(json.dumps({k: _json_value(v) for k, v in row.items()}) + "\n")
    return p


def write_csv_rows(path: PathLike, rows: Iterable[Mapping[str, Any]]) -> Path:
    """A header of every key (first-seen order) and one line per row; missing keys and None
    are empty cells, bools ``true``/``false``, floats in ``repr`` precision."""
    checked, columns = _checked_rows(rows)
    p = Path(path)

    def cell(value: Any) -> str:
        if value is None:
            return ""
        if isinstance(value, bool):
            return "true" if value else "false"
        if isinstance(value, float):
            return repr(value)
        return str(value)

    with p.open("w", encoding="utf-8", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(columns)
        for row in checked:
            writer.writerow([cell(row.get(c)) for c in columns])
    return p


def write_rows(path: PathLike, rows: Iterable[Mapping[str, Any]]) -> Path:
    """Write rows as JSON lines (``.jsonl``) or CSV (``.csv``), chosen by the extension."""
    suffix = Path(path).suffix.lower()
    if suffix == ".jsonl":
        return write_jsonl(path, rows)
    if suffix == ".csv":
        return write_csv_rows(path, rows)
    raise ValueError(f"{path}: no table writer for {suffix!r} (known: {', '.join(ROW_FORMATS)})")


def read_jsonl(path: PathLike) -> list[dict[str, Any]]:
    """The rows of a JSON-lines file (blank lines skipped)."""
    p = Path(path)
    rows = []
    for number, line in enumerate(p.read_text(encoding="utf-8").splitlines(), start=1):
        if not line.strip():
            continue
        try:
            row = json.loads(line)
        except json.JSONDecodeError as exc:
            raise ValueError(f"{p}: line {number}: not JSON: {exc}") from None
        if not isinstance(row, dict):
            raise ValueError(f"{p}: line {number}: expected an object")
        rows.append(row)
    return rows


# --------------------------------------------------------------------------- poses


def poses_to_trajectory(poses: Any, timestamps: Any = None) -> Trajectory:
    """A :class:`Trajectory` from ``(K, 4, 4)`` matrices or a list of :class:`~scanreg.SE3`."""
    if isinstance(poses, Sequence) and poses and isinstance(poses[0], SE3):
        return Trajectory.from_poses(list(poses), timestamps)
    mats = np.asarray(poses, dtype=np.float64)
    return Trajectory(mats, timestamps)


def write_poses(path: PathLike, poses: Any, format: str, *, timestamps: Any = None) -> Path:
    """Write poses ``T_world_lidar`` (``(K, 4, 4)`` or SE3 list) as ``"kitti"`` (12 numbers per
    line) or ``"tum"`` (needs ``timestamps``, seconds)."""
    traj = poses_to_trajectory(poses, timestamps)
    p = Path(path)
    if format == "kitti":
        write_kitti_poses(p, traj)
    elif format == "tum":
        write_tum(p, traj)
    else:
        raise ValueError(f"format: expected 'kitti' or 'tum', got {format!r}")
    return p


def lidar_to_camera_poses(poses: Any, T_cam0_velo: Any) -> Any:
    """KITTI: LiDAR-frame poses ``T_velo0_velok`` → camera-0 poses ``Tr · T · Tr⁻¹`` (what the
    official KITTI evaluation reads). ``T_cam0_velo``: 4×4 or SE3 (calib ``Tr``)."""
    tr = T_cam0_velo.as_matrix() if isinstance(T_cam0_velo, SE3) else np.asarray(T_cam0_velo)
    mats = poses_to_trajectory(poses).poses
    return tr @ mats @ np.linalg.inv(tr)


def write_run_outputs(
    folder: PathLike,
    *,
    poses: Any,
    stamps: Any,
    rows: Iterable[Mapping[str, Any]] = (),
    config: Any = None,
    T_cam0_velo: Any = None,
) -> dict[str, str]:
    """Write an odometry run's outputs into ``folder`` (created) and return their paths.

    * ``poses_kitti.txt`` and ``poses_tum.txt``: ``poses`` (``T_world_lidar``, ``(K, 4, 4)`` or
      SE3 list) with ``stamps`` (``(K,)`` s) for TUM;
    * ``poses_kitti_cam0.txt`` when ``T_cam0_velo`` is given (a KITTI sequence's
      ``T_cam0_velo``): the poses in the camera-0 frame, as the KITTI benchmark reads them;
    * ``quality.jsonl`` and ``quality.csv``: ``rows`` (one flat dict per frame), when any;
    * ``config.toml``: ``config`` (a dataclass) through :func:`scanreg.config.dump_config`.

    Returns ``{"poses_kitti": path, ...}`` (JSON-ready strings).
    """
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    traj = poses_to_trajectory(poses, stamps)
    written = {
        "poses_kitti": write_poses(out / "poses_kitti.txt", traj.poses, "kitti"),
        "poses_tum": write_poses(out / "poses_tum.txt", traj.poses, "tum", timestamps=stamps),
    }
    if T_cam0_velo is not None:
        cam = lidar_to_camera_poses(traj.poses, T_cam0_velo)
        written["poses_kitti_cam0"] = write_poses(out / "poses_kitti_cam0.txt", cam, "kitti")
    table = list(rows)
    if table:
        written["quality_jsonl"] = write_jsonl(out / "quality.jsonl", table)
        written["quality_csv"] = write_csv_rows(out / "quality.csv", table)
    if config is not None:
        from ..config import write_config

        written["config"] = write_config(out / "config.toml", config)
    return {k: str(v) for k, v in written.items()}


__all__ = [
    "ROW_FORMATS",
    "lidar_to_camera_poses",
    "poses_to_trajectory",
    "read_jsonl",
    "write_csv_rows",
    "write_jsonl",
    "write_poses",
    "write_rows",
    "write_run_outputs",
]
