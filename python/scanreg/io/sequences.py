"""Sequences of LiDAR sweeps: KITTI odometry folders, folders of point files, ROS bags and
simulated drives, behind one small interface.

Every loader is a :class:`ScanSequence`: ``len(seq)``, ``seq[k]`` and ``for frame in seq``
give :class:`SequenceFrame` objects (points in the sensor frame, per-point time, the frame's
stamp), ``seq.ground_truth`` is ``(K, 4, 4)`` poses ``T_world_lidar`` or None, and
``seq.name`` names it. :func:`open_sequence` chooses the loader from what the path is:

>>> seq = open_sequence("dataset/sequences/00")       # KITTI: velodyne/*.bin + calib.txt
>>> seq = open_sequence("run/")                 # a folder of .pcd/.ply/.las/.laz/.bin/.npy/.npz
>>> seq = open_sequence("drive.bag", topic="/points") # ROS 1 bag; ROS 2: .db3/.mcap/folder
>>> seq = open_sequence("sim:street")                 # simulated, no download
>>> for frame in seq:
...     frame.points, frame.timestamps, frame.stamp

Per-point time
--------------
``SequenceFrame.timestamps`` are seconds **since the frame's** ``stamp`` (absolute time of
point ``i`` = ``stamp + timestamps[i]``), or None when the source has no per-point time
(KITTI scans are already motion-compensated). Files store per-point time under many names
and units (Velodyne ``time``: seconds since the sweep stamp; Ouster ``t`` and Livox
``offset_time``: nanoseconds; Hesai/Robosense ``timestamp``: absolute seconds). With
``time_unit="auto"`` the unit is inferred from the span of the values within one sweep — a
LiDAR sweep lasts between a few milliseconds and a couple of seconds, so a span up to 2 is
seconds, up to 2e3 milliseconds, up to 2e6 microseconds, and beyond nanoseconds — and
absolute times (beyond 1e6 s, i.e. epoch seconds) are made relative to the message header
stamp (bags) or to the sweep's earliest point (folders, whose stamps may be synthetic). Pass
``time_unit="s"``/``"ms"``/``"us"``/``"ns"`` to override the guess.

Errors name the path and what is wrong (:class:`~scanreg.io.FileFormatError` for bad
content, ``FileNotFoundError`` for missing paths).
"""

from __future__ import annotations

import abc
import math
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from .._validate import FloatArray
from ..transform import SE3
from ._common import FileFormatError, PathLike, PointCloud
from .arrays import read_kitti_bin, read_npy, read_npz
from .las import read_las, relative_gps_time
from .pcd import read_pcd
from .ply import read_ply
from .trajectory import Trajectory, read_kitti_calib, read_kitti_poses, read_times, read_tum


def read_las_sweep(path: PathLike) -> PointCloud:
    """A LAS/LAZ sweep with its GPS time (always seconds) relative to its first point when
    absolute, so the span-based unit guess and deskew see seconds since the sweep start."""
    cloud = read_las(path)
    return PointCloud(
        points=cloud.points,
        intensity=cloud.intensity,
        ring=cloud.ring,
        time=relative_gps_time(cloud.time),
        fields=cloud.fields,
    )


TimeUnit = Literal["auto", "s", "ms", "us", "ns"]
TIME_UNITS: dict[str, float] = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}

#: Point-file readers a folder sequence accepts, by extension (text formats are left out:
#: pose and time files in the same folder are ``.txt``).
SEQUENCE_FILE_READERS = {
    ".pcd": read_pcd,
    ".ply": read_ply,
    ".las": read_las_sweep,
    ".laz": read_las_sweep,
    ".bin": read_kitti_bin,
    ".npy": read_npy,
    ".npz": read_npz,
}
#: Suffixes read as ROS bags (a folder with ``metadata.yaml`` is a ROS 2 bag too).
BAG_SUFFIXES = (".bag", ".db3", ".mcap")
#: Ground-truth files a folder sequence picks up by itself, in this order.
FOLDER_GROUND_TRUTH = ("poses_tum.txt", "poses_kitti.txt", "poses.txt", "groundtruth.txt")
#: Frame period assumed when a source has no frame times (s).
DEFAULT_FRAME_PERIOD = 0.1


def _readonly(a: Any, dtype: Any = np.float64) -> Any:
    out = np.array(a, dtype=dtype)
    out.setflags(write=False)
    return out


@dataclass(frozen=True, eq=False)
class SequenceFrame:
    """One sweep of a :class:`ScanSequence`.

    Attributes
    ----------
    index : int
        Position in the sequence (0-based).
    points : (N, 3) float64
        Finite points in the sensor frame (metres), read-only. Points with a NaN/inf
        coordinate in the file (organised clouds) are dropped.
    timestamps : (N,) float64 or None
        Per-point time in seconds since ``stamp`` (see the module docs), read-only; None when
        the source has no per-point time.
    stamp : float
        The frame's time (s): KITTI ``times.txt``, the message header stamp of a bag, the sweep
        start of a simulated frame, else ``index · frame_period``.
    intensity : (N,) float64 or None
        As stored.
    source : str
        Where the frame came from (file name, ``topic#k`` or ``sim:…#k``).
    """

    index: int
    points: FloatArray
    timestamps: FloatArray | None
    stamp: float
    intensity: FloatArray | None = None
    source: str = ""

    def __post_init__(self) -> None:
        pts = np.asarray(self.points)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ValueError(f"points: expected shape (N, 3), got {pts.shape}")
        object.__setattr__(self, "points", _readonly(pts))
        n = pts.shape[0]
        for name in ("timestamps", "intensity"):
            value = getattr(self, name)
            if value is not None:
                arr = np.asarray(value)
                if arr.shape != (n,):
                    raise ValueError(f"{name}: expected shape ({n},), got {arr.shape}")
                object.__setattr__(self, name, _readonly(arr))
        if not math.isfinite(self.stamp):
            raise ValueError(f"stamp: must be finite, got {self.stamp}")

    def __len__(self) -> int:
        return int(self.points.shape[0])


def time_in_seconds(values: Any, unit: TimeUnit, stamp: float | None = None) -> FloatArray:
    """Per-point times ``values`` (file units) as seconds since ``stamp`` (see the module docs).

    Relative times (``|t| < 1e6`` s after conversion) are kept as they are; absolute times are
    made relative to ``stamp`` — or to their minimum when ``stamp`` is None.
    """
    t = np.asarray(values, dtype=np.float64)
    finite = t[np.isfinite(t)]
    if unit == "auto":
        span = float(finite.max() - finite.min()) if finite.size else 0.0
        scale = 1.0 if span <= 2.0 else 1e-3 if span <= 2e3 else 1e-6 if span <= 2e6 else 1e-9
    elif unit in TIME_UNITS:
        scale = TIME_UNITS[unit]
    else:
        raise ValueError(f"time_unit: expected one of auto, {', '.join(TIME_UNITS)}, got {unit!r}")
    # subtract before scaling: absolute nanosecond stamps keep their precision
    if finite.size and abs(float(np.median(finite)) * scale) > 1e6:
        origin = float(finite.min()) if stamp is None else stamp / scale
        out: FloatArray = (t - origin) * scale
        return out
    scaled: FloatArray = t * scale
    return scaled


def _natural_key(path: Path) -> list[Any]:
    return [int(s) if s.isdigit() else s.lower() for s in re.split(r"(\d+)", path.name)]


def natural_sorted(paths: Any) -> list[Path]:
    """Paths sorted by name with digit runs compared as numbers (``2.pcd`` before ``10.pcd``)."""
    return sorted((Path(p) for p in paths), key=_natural_key)


def _check_ground_truth(poses: Any, count: int, where: PathLike, what: str) -> FloatArray:
    arr = np.asarray(poses, dtype=np.float64)
    if arr.shape[0] != count:
        raise FileFormatError(where, f"{arr.shape[0]} {what} for {count} frames")
    out: FloatArray = _readonly(arr)
    return out


class ScanSequence(abc.ABC):
    """A sequence of LiDAR sweeps (see the module docs).

    Subclasses implement ``__len__`` and :meth:`_frame`; indexing accepts negative indices
    and raises ``IndexError`` out of range; iteration yields the frames in order.
    """

    #: A short name for reports (a folder name, bag topic, ``sim:street``).
    name: str = ""

    @abc.abstractmethod
    def __len__(self) -> int: ...

    @abc.abstractmethod
    def _frame(self, index: int) -> SequenceFrame: ...

    @property
    def ground_truth(self) -> FloatArray | None:
        """``(K, 4, 4)`` poses ``T_world_lidar`` of each frame at its stamp, or None."""
        return None

    @property
    def has_point_time(self) -> bool | None:
        """Whether frames carry per-point time (None: unknown until a frame is read)."""
        return None

    def __getitem__(self, index: int) -> SequenceFrame:
        if isinstance(index, bool) or not isinstance(index, (int, np.integer)):
            raise TypeError(f"index: expected an int, got {type(index).__name__}")
        n = len(self)
        k = int(index) + n if index < 0 else int(index)
        if not 0 <= k < n:
            raise IndexError(f"index: {index} out of range for {n} frames of {self.name}")
        return self._frame(k)

    def __iter__(self) -> Iterator[SequenceFrame]:
        for k in range(len(self)):
            yield self._frame(k)

    def ground_truth_trajectory(self) -> Trajectory | None:
        """The ground truth as a :class:`~scanreg.io.Trajectory` (no timestamps), or None."""
        gt = self.ground_truth
        return None if gt is None else Trajectory(gt)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r}, {len(self)} frames)"


def _frame_from_cloud(
    index: int,
    cloud: PointCloud,
    stamp: float,
    unit: TimeUnit,
    source: str,
    *,
    absolute_stamp: bool,
    where: PathLike,
) -> SequenceFrame:
    if cloud.dim != 3:
        raise FileFormatError(where, f"expected 3D points, got shape {cloud.points.shape}")
    cloud = cloud.finite()
    times = None
    if cloud.time is not None:
        times = time_in_seconds(cloud.time, unit, stamp if absolute_stamp else None)
        if not np.isfinite(times).all():
            raise FileFormatError(where, "per-point time holds NaN or inf")
    return SequenceFrame(
        index=index,
        points=cloud.points,
        timestamps=times,
        stamp=stamp,
        intensity=cloud.intensity,
        source=source,
    )


# --------------------------------------------------------------------------- KITTI


def _kitti_poses_path(root: Path) -> Path | None:
    for cand in (
        root / "poses.txt",
        root / "poses" / f"{root.name}.txt",
        root.parent.parent / "poses" / f"{root.name}.txt",
    ):
        if cand.is_file():
            return cand
    return None


class KittiSequence(ScanSequence):
    """A KITTI odometry sequence folder.

    Layout: ``velodyne/NNNNNN.bin`` (float32 x y z reflectance, numbered from 0 without gaps),
    ``calib.txt`` with ``Tr`` (velodyne → camera 0), optional ``times.txt`` and ground-truth
    poses of camera 0 — ``poses.txt`` in the folder, ``poses/<name>.txt`` in it, or the
    official ``dataset/poses/<name>.txt`` next to ``dataset/sequences/<name>``; or ``poses=``.

    ``ground_truth`` is in the LiDAR frame: ``T_velo_k = Tr⁻¹ · P_k · Tr`` (the pose of sweep
    ``k`` in the frame of the LiDAR at frame 0 when ``P_0 = I``). Scans carry no per-point
    time (KITTI's are already motion-compensated).
    """

    def __init__(self, root: PathLike, *, poses: PathLike | None = None) -> None:
        self.root = Path(root)
        if not self.root.is_dir():
            raise FileNotFoundError(f"{self.root}: no such folder")
        self.name = self.root.name
        velo = self.root / "velodyne"
        if not velo.is_dir():
            raise FileFormatError(self.root, "not a KITTI sequence: no velodyne/ folder")
        self.files = natural_sorted(velo.glob("*.bin"))
        if not self.files:
            raise FileFormatError(velo, "no .bin scans")
        for k, f in enumerate(self.files):
            if not f.stem.isdigit():
                raise FileFormatError(f, "KITTI scan names are frame numbers (000000.bin)")
            if int(f.stem) != k:
                raise FileFormatError(
                    velo, f"frame numbers are not consecutive from 0: {f.name} is frame {k}"
                )
            size = f.stat().st_size
            if size == 0 or size % 16:
                raise FileFormatError(
                    f, f"size {size} bytes is not a positive multiple of 16 (float32 x y z r)"
                )
        n = len(self.files)
        times_path = self.root / "times.txt"
        if times_path.is_file():
            stamps = read_times(times_path)
            if stamps.shape[0] != n:
                raise FileFormatError(times_path, f"{stamps.shape[0]} times for {n} frames")
            self.stamps: FloatArray = _readonly(stamps)
        else:
            self.stamps = _readonly(DEFAULT_FRAME_PERIOD * np.arange(n))
        self.poses_path = Path(poses) if poses is not None else _kitti_poses_path(self.root)
        self._gt: FloatArray | None = None
        calib_path = self.root / "calib.txt"
        #: ``Tr`` of ``calib.txt`` (velodyne → camera 0), None without a calib file.
        self.T_cam0_velo: SE3 | None = None
        if calib_path.is_file():
            self.T_cam0_velo = read_kitti_calib(calib_path).T_cam0_velo
        if self.poses_path is not None:
            if not self.poses_path.is_file():
                raise FileNotFoundError(f"{self.poses_path}: no such pose file")
            if self.T_cam0_velo is None:
                raise FileFormatError(
                    self.root,
                    f"no calib.txt: needed (Tr) to express {self.poses_path.name} in the "
                    "LiDAR frame",
                )
            tr = self.T_cam0_velo.as_matrix()
            cam = read_kitti_poses(self.poses_path).poses
            if cam.shape[0] != n:
                raise FileFormatError(
                    self.poses_path, f"{cam.shape[0]} poses for {n} frames in {velo}"
                )
            # T_velo0_velok = Tr⁻¹ · T_cam0_camk · Tr
            self._gt = _check_ground_truth(
                np.linalg.inv(tr) @ cam @ tr, n, self.poses_path, "poses"
            )

    def __len__(self) -> int:
        return len(self.files)

    @property
    def ground_truth(self) -> FloatArray | None:
        return self._gt

    @property
    def has_point_time(self) -> bool:
        return False

    def _frame(self, index: int) -> SequenceFrame:
        path = self.files[index]
        cloud = read_kitti_bin(path)
        return _frame_from_cloud(
            index,
            cloud,
            float(self.stamps[index]),
            "s",
            path.name,
            absolute_stamp=False,
            where=path,
        )


# --------------------------------------------------------------------------- folder


def _read_trajectory_auto(path: Path) -> Trajectory:
    """A TUM (8 columns) or KITTI (12 columns) trajectory, told apart by the column count."""
    for line in path.read_text(encoding="utf-8", errors="replace").splitlines():
        words = line.replace(",", " ").split()
        if not words or words[0].startswith("#"):
            continue
        if len(words) == 8:
            return read_tum(path)
        if len(words) == 12:
            return read_kitti_poses(path)
        raise FileFormatError(
            path, f"{len(words)} values per line: neither TUM (8) nor KITTI poses (12)"
        )
    raise FileFormatError(path, "no pose lines")


class FolderSequence(ScanSequence):
    """A folder of point files (``.pcd``, ``.ply``, ``.las``, ``.laz``, ``.bin``, ``.npy``,
    ``.npz``; one format),
    in natural order (``2.pcd`` before ``10.pcd``).

    Per-point time comes from the files' time field when the reader exposes one (see the
    module docs for units). Frame stamps: the ground-truth trajectory's timestamps when it has
    them (TUM), else ``index · frame_period``. Ground truth: ``ground_truth=`` (a TUM or KITTI
    pose file, told apart by its columns) or, if absent, the first of
    :data:`FOLDER_GROUND_TRUTH` found in the folder; poses are ``T_world_lidar`` as the file
    gives them.
    """

    def __init__(
        self,
        root: PathLike,
        *,
        ground_truth: PathLike | None = None,
        time_unit: TimeUnit = "auto",
        frame_period: float = DEFAULT_FRAME_PERIOD,
    ) -> None:
        self.root = Path(root)
        if not self.root.is_dir():
            raise FileNotFoundError(f"{self.root}: no such folder")
        self.name = self.root.name
        if time_unit != "auto" and time_unit not in TIME_UNITS:
            raise ValueError(f"time_unit: expected auto, s, ms, us or ns, got {time_unit!r}")
        self.time_unit: TimeUnit = time_unit
        files = [p for p in self.root.iterdir() if p.suffix.lower() in SEQUENCE_FILE_READERS]
        if not files:
            known = ", ".join(SEQUENCE_FILE_READERS)
            raise FileFormatError(self.root, f"no point files ({known})")
        suffixes = sorted({p.suffix.lower() for p in files})
        if len(suffixes) > 1:
            raise FileFormatError(
                self.root, f"point files of several formats ({', '.join(suffixes)}); keep one"
            )
        self.files = natural_sorted(files)
        self._reader = SEQUENCE_FILE_READERS[suffixes[0]]
        n = len(self.files)
        gt_path = Path(ground_truth) if ground_truth is not None else None
        if gt_path is None:
            gt_path = next(
                (self.root / g for g in FOLDER_GROUND_TRUTH if (self.root / g).is_file()), None
            )
            if gt_path is not None and (self.root / "calib.txt").is_file():
                # KITTI poses next to a calib.txt are camera-0 poses: taking them as LiDAR
                # poses would be silently wrong
                raise FileFormatError(
                    self.root,
                    f"has calib.txt and {gt_path.name}: for KITTI camera-0 poses put the scans "
                    "in velodyne/ (KITTI layout); else pass ground_truth= explicitly",
                )
        self.ground_truth_path = gt_path
        self._gt: FloatArray | None = None
        stamps = None
        if gt_path is not None:
            if not gt_path.is_file():
                raise FileNotFoundError(f"{gt_path}: no such ground-truth file")
            traj = _read_trajectory_auto(gt_path)
            self._gt = _check_ground_truth(traj.poses, n, gt_path, "poses")
            stamps = traj.timestamps
        if not (math.isfinite(frame_period) and frame_period > 0):
            raise ValueError(f"frame_period: must be finite and > 0, got {frame_period}")
        self.stamps: FloatArray = _readonly(
            stamps if stamps is not None else frame_period * np.arange(n)
        )

    def __len__(self) -> int:
        return len(self.files)

    @property
    def ground_truth(self) -> FloatArray | None:
        return self._gt

    def _frame(self, index: int) -> SequenceFrame:
        path = self.files[index]
        return _frame_from_cloud(
            index,
            self._reader(path),
            float(self.stamps[index]),
            self.time_unit,
            path.name,
            absolute_stamp=False,
            where=path,
        )


# --------------------------------------------------------------------------- ROS bags


class RosbagSequence(ScanSequence):
    """The ``sensor_msgs/PointCloud2`` messages of one topic of a ROS 1 or ROS 2 bag.

    ``topic`` may be omitted when the bag has one PointCloud2 topic. Frame stamps are the
    message header stamps; per-point time from the field ``t``, ``time``, ``timestamp``,
    ``offset_time``, … (units: see the module docs; absolute times become relative to the
    header stamp). ``ground_truth``: an optional TUM/KITTI file with one pose per message.

    Random access (``seq[k]``) reads the bag from the start; iterate for a sequential pass.
    """

    def __init__(
        self,
        path: PathLike,
        *,
        topic: str | None = None,
        ground_truth: PathLike | None = None,
        time_unit: TimeUnit = "auto",
    ) -> None:
        from . import rosbag

        self.path = Path(path)
        if not self.path.exists():
            raise FileNotFoundError(f"{self.path}: no such file or directory")
        if time_unit != "auto" and time_unit not in TIME_UNITS:
            raise ValueError(f"time_unit: expected auto, s, ms, us or ns, got {time_unit!r}")
        self.time_unit: TimeUnit = time_unit
        topics = rosbag.list_topics(self.path)
        clouds = {t.name: t.message_count for t in topics if t.msgtype == rosbag.POINT_CLOUD2}
        if topic is None:
            if not clouds:
                known = ", ".join(f"{t.name} ({t.msgtype})" for t in topics) or "none"
                raise FileFormatError(self.path, f"no PointCloud2 topic (topics: {known})")
            if len(clouds) > 1:
                raise ValueError(
                    f"topic: {self.path} has several PointCloud2 topics "
                    f"({', '.join(sorted(clouds))}); choose one"
                )
            topic = next(iter(clouds))
        elif topic not in clouds:
            known = ", ".join(sorted(clouds)) or "none"
            raise ValueError(f"topic: {self.path} has no PointCloud2 topic {topic!r} ({known})")
        self.topic: str = topic
        self._count = clouds[topic]
        self.name = f"{self.path.name}:{topic}"
        self._gt: FloatArray | None = None
        if ground_truth is not None:
            gt_path = Path(ground_truth)
            self._gt = _check_ground_truth(
                _read_trajectory_auto(gt_path).poses, self._count, gt_path, "poses"
            )

    def __len__(self) -> int:
        return self._count

    @property
    def ground_truth(self) -> FloatArray | None:
        return self._gt

    def _convert(self, index: int, msg: Any) -> SequenceFrame:
        return _frame_from_cloud(
            index,
            msg.cloud,
            float(msg.timestamp),
            self.time_unit,
            f"{self.topic}#{index}",
            absolute_stamp=True,
            where=self.path,
        )

    def _messages(self) -> Iterator[Any]:
        from .rosbag import iter_bag_clouds

        return iter_bag_clouds(self.path, self.topic)

    def _frame(self, index: int) -> SequenceFrame:
        for k, msg in enumerate(self._messages()):
            if k == index:
                return self._convert(k, msg)
        raise FileFormatError(self.path, f"{self.topic}: message {index} not found")

    def __iter__(self) -> Iterator[SequenceFrame]:
        for k, msg in enumerate(self._messages()):
            yield self._convert(k, msg)


# --------------------------------------------------------------------------- simulation

#: Simulated sequences by name: scene, start pose (x, y, z), default speed (m/s) and the
#: amplitude of a zero-mean yaw-rate weave (rad/s, period 8 s).
SIMULATED_SCENES: dict[str, dict[str, Any]] = {
    "street": {"start": (0.0, 1.75, 1.73), "speed": 10.0, "weave": 0.04},
    "tunnel": {"start": (0.0, 0.0, 1.73), "speed": 10.0, "weave": 0.0},
    # Courses of scanreg.simulate.block_loop (laps around a city block, exact closure); the
    # repeated one has four identical sides (look-alike places: false loops).
    "loop": {"speed": 10.0, "weave": 0.0, "symmetry": 1},
    "loop-repeated": {"speed": 10.0, "weave": 0.0, "symmetry": 4},
}
#: Keys accepted after ``sim:NAME,`` (see :func:`parse_sim_spec`), with their types.
SIM_OPTIONS: dict[str, type] = {
    "frames": int,
    "sensor": str,
    "speed": float,
    "weave": float,
    "ramp": float,
    "seed": int,
    "laps": int,
    "lap_length": float,
}


def parse_sim_spec(spec: str) -> dict[str, Any]:
    """Parse ``sim:NAME[,key=value,...]`` (e.g. ``sim:street,frames=150,sensor=hdl64``).

    Returns the keyword arguments of :class:`SimulatedSequence` (``scene`` and the options of
    :data:`SIM_OPTIONS`: ``frames``, ``sensor``, ``speed``, ``weave``, ``ramp``, ``seed``,
    ``laps``, ``lap_length``).
    """
    if not spec.startswith("sim:"):
        raise ValueError(f"{spec!r}: a simulated sequence is written sim:NAME[,key=value...]")
    name, *items = spec[4:].split(",")
    if name not in SIMULATED_SCENES:
        raise ValueError(f"{spec!r}: unknown scene {name!r} (known: {', '.join(SIMULATED_SCENES)})")
    out: dict[str, Any] = {"scene": name}
    for item in items:
        key, sep, value = item.partition("=")
        key = key.strip()
        if not sep or key not in SIM_OPTIONS:
            raise ValueError(
                f"{spec!r}: bad option {item!r} (options: "
                f"{', '.join(f'{k}=<{t.__name__}>' for k, t in SIM_OPTIONS.items())})"
            )
        try:
            out["num_frames" if key == "frames" else key] = SIM_OPTIONS[key](value.strip())
        except ValueError:
            raise ValueError(
                f"{spec!r}: {key} must be {SIM_OPTIONS[key].__name__}, got {value!r}"
            ) from None
    return out


class SimulatedSequence(ScanSequence):
    """A simulated drive with motion distortion, per-point time and exact ground truth.

    ``scene`` ``"street"`` (buildings, cars, poles, vegetation, pedestrians, a moving car; the
    vehicle weaves gently in its lane) or ``"tunnel"`` (a featureless tube, straight drive,
    ends beyond the sensor's range: degenerate along the axis). The scene is made long enough
    for ``num_frames`` sweeps at ``speed``. Sweeps are simulated on demand (each
    ``seq[k]`` casts the rays again, deterministically: the noise is keyed by
    ``(seed, k)``).

    ``"loop"`` and ``"loop-repeated"``: ``laps`` laps of ``lap_length`` m around a city block
    (:func:`scanreg.simulate.block_loop`; the repeated one with four identical sides and no
    moving objects); ``num_frames`` defaults to the whole drive, :attr:`course` holds the
    course (its :meth:`~scanreg.simulate.Course.revisits` are the true loops).

    Frames: points motion-distorted exactly as a driver reports them, ``timestamps`` seconds
    since the sweep start (``stamp``). ``ground_truth[k]`` is ``T_lidar0_lidark`` at the start
    of sweep ``k`` (the first is the identity). :meth:`sweep` gives the full simulator output
    (deskewed points, rings, ranges, …).
    """

    def __init__(
        self,
        scene: str = "street",
        *,
        num_frames: int | None = None,
        sensor: str = "vlp16",
        speed: float | None = None,
        weave: float | None = None,
        ramp: float = 0.0,
        seed: int = 0,
        laps: int = 2,
        lap_length: float = 300.0,
    ) -> None:
        from .. import simulate as sim
        from ..transform import SE3

        if scene not in SIMULATED_SCENES:
            raise ValueError(f"scene: unknown {scene!r} (known: {', '.join(SIMULATED_SCENES)})")
        preset = SIMULATED_SCENES[scene]
        self.lidar = sim.LidarModel.preset(sensor)
        self.course: sim.Course | None = None
        if "symmetry" in preset:
            if ramp or weave:
                raise ValueError(f"ramp, weave: not supported on sim:{scene}")
            repeated = preset["symmetry"] > 1
            self.course = sim.block_loop(
                seed,
                lap_length=lap_length,
                laps=laps,
                speed=preset["speed"] if speed is None else speed,
                symmetry=preset["symmetry"],
                aspect=1.0 if repeated else 0.5,
                num_pedestrians=0 if repeated else 4,
                num_moving_cars=0 if repeated else 1,
            )
            if num_frames is None:
                num_frames = self.course.num_scans(1.0 / self.lidar.sweep_duration)
        if num_frames is None:
            num_frames = 100
        if isinstance(num_frames, bool) or not isinstance(num_frames, int) or num_frames < 1:
            raise ValueError(f"num_frames: must be an int >= 1, got {num_frames!r}")
        self.scene_name = scene
        self.num_frames = num_frames
        self.seed = seed
        self.speed = float(preset["speed"] if speed is None else speed)
        self.weave = float(preset["weave"] if weave is None else weave)
        if not (math.isfinite(self.speed) and self.speed >= 0):
            raise ValueError(f"speed: must be finite and >= 0, got {speed}")
        if not (math.isfinite(self.weave) and self.weave >= 0):
            raise ValueError(f"weave: must be finite and >= 0, got {weave}")
        self.ramp = float(ramp)
        if not (math.isfinite(self.ramp) and self.ramp >= 0):
            raise ValueError(f"ramp: must be finite and >= 0, got {ramp}")
        period = self.lidar.sweep_duration
        duration = period * (num_frames + 1)
        travel = self.speed * duration
        # the scene reaches beyond the sensor's range at both ends of the drive
        length = travel + 2.0 * (self.lidar.max_range + 20.0)
        self.trajectory: Any
        if self.course is not None:
            self.scene = self.course.scene
            self.trajectory = self.course.trajectory
        else:
            x0, y0, z0 = preset["start"]
            x0 -= travel / 2
            if scene == "street":
                self.scene = sim.street(seed=seed, length=max(200.0, length))
            else:
                self.scene = sim.tunnel(length=max(400.0, length))
            self.trajectory = _weaving_trajectory(
                SE3.from_vector([x0, y0, z0, 0.0, 0.0, 0.0]),
                self.speed,
                self.weave,
                duration,
                ramp=self.ramp,
            )
        self.stamps: FloatArray = _readonly(period * np.arange(num_frames))
        self._gt: FloatArray = self.ground_truth_at("start")
        self.name = f"sim:{scene}"

    def ground_truth_at(self, reference: str | float) -> FloatArray:
        """``(K, 4, 4)`` truth at each sweep's ``"start"``, ``"middle"`` or ``"end"`` (or that
        many seconds after its start) — to compare with an
        odometry whose poses refer to that time within the sweep. Relative to the first sweep at
        the same time, so the first pose is the identity."""
        period = self.lidar.sweep_duration
        offsets = {"start": 0.0, "middle": 0.5 * period, "end": period}
        if isinstance(reference, str):
            if reference not in offsets:
                raise ValueError(
                    f"reference: expected seconds or one of start, middle, end; got {reference!r}"
                )
            offset = offsets[reference]
        else:
            offset = float(reference)
        first_inv = self.trajectory.pose_at(float(self.stamps[0]) + offset).inverse()
        poses = [first_inv @ self.trajectory.pose_at(float(t) + offset) for t in self.stamps]
        out: FloatArray = _readonly([p.as_matrix() for p in poses])
        return out

    def __len__(self) -> int:
        return self.num_frames

    @property
    def ground_truth(self) -> FloatArray:
        return self._gt

    @property
    def has_point_time(self) -> bool:
        return True

    def sweep(self, index: int) -> Any:
        """The :class:`~scanreg.simulate.LidarSweep` of frame ``index`` (world-frame pose)."""
        from .. import simulate as sim

        return sim.simulate_sweep(
            self.scene,
            self.lidar,
            self.trajectory,
            start_time=float(self.stamps[index]),
            seed=self.seed,
            scan_index=index,
        )

    def _frame(self, index: int) -> SequenceFrame:
        sweep = self.sweep(index)
        stamp = float(self.stamps[index])
        return SequenceFrame(
            index=index,
            points=sweep.points,
            timestamps=sweep.timestamps - stamp,
            stamp=stamp,
            source=f"{self.name}#{index}",
        )


def _weaving_trajectory(
    start: Any, speed: float, weave: float, duration: float, *, ramp: float = 0.0
) -> Any:
    """Forward at ``speed`` with yaw rate ``weave · cos(2π t / 8 s)`` (zero-mean heading),
    held constant over 0.05 s steps; with ``ramp`` > 0, starting from rest and reaching
    ``speed`` after ``ramp`` seconds (constant acceleration)."""
    from ..simulate import Trajectory as SimTrajectory
    from ..transform import SE3

    if weave == 0.0 and ramp == 0.0:
        return SimTrajectory.constant_velocity(
            start, [speed, 0.0, 0.0], [0.0, 0.0, 0.0], duration=duration + 1.0
        )
    step = 0.05
    n = math.ceil((duration + 1.0) / step)
    knots = step * np.arange(n + 1, dtype=np.float64)
    mid = knots[:-1] + step / 2
    twists = np.zeros((n, 6))
    twists[:, 0] = speed * (np.minimum(1.0, mid / ramp) if ramp > 0 else 1.0)
    twists[:, 5] = weave * np.cos(2 * math.pi * mid / 8.0)
    poses = [start]
    for k in range(n - 1):
        poses.append(poses[-1] @ SE3.exp(step * twists[k]))
    return SimTrajectory(knots, tuple(poses), twists)


# --------------------------------------------------------------------------- factory


def open_sequence(
    source: PathLike,
    *,
    topic: str | None = None,
    ground_truth: PathLike | None = None,
    time_unit: TimeUnit = "auto",
) -> ScanSequence:
    """Open a sequence, choosing the loader from what ``source`` is.

    * ``"sim:street"``, ``"sim:tunnel"``, ``"sim:loop"``, ``"sim:loop-repeated"`` (options:
      ``sim:street,frames=200,sensor=hdl64``, ``sim:loop,laps=3,lap_length=250``, see
      :func:`parse_sim_spec`) → :class:`SimulatedSequence`;
    * a folder with ``velodyne/`` (or that ``velodyne/`` folder itself, next to a
      ``calib.txt``) → :class:`KittiSequence` (``ground_truth``: a camera-0 pose file that
      replaces the one found next to it);
    * a ``.bag`` / ``.db3`` / ``.mcap`` file or a folder with ``metadata.yaml`` →
      :class:`RosbagSequence` (``topic``);
    * any other folder → :class:`FolderSequence`.
    """
    if isinstance(source, str) and source.startswith("sim:"):
        return SimulatedSequence(**parse_sim_spec(source))
    path = Path(source)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file or directory")
    if path.is_dir():
        if (path / "velodyne").is_dir():
            return KittiSequence(path, poses=ground_truth)
        if path.name == "velodyne" and (path.parent / "calib.txt").is_file():
            return KittiSequence(path.parent, poses=ground_truth)  # the scans' folder given
        if (path / "metadata.yaml").is_file():
            return RosbagSequence(path, topic=topic, ground_truth=ground_truth, time_unit=time_unit)
        if (path / "calib.txt").is_file() and not any(
            p.suffix.lower() in SEQUENCE_FILE_READERS for p in path.iterdir()
        ):
            raise FileFormatError(
                path, "looks like a KITTI sequence (calib.txt) but has no velodyne/"
            )
        return FolderSequence(path, ground_truth=ground_truth, time_unit=time_unit)
    if path.suffix.lower() in BAG_SUFFIXES:
        return RosbagSequence(path, topic=topic, ground_truth=ground_truth, time_unit=time_unit)
    raise FileFormatError(
        path,
        "not a sequence: expected a KITTI folder (velodyne/), a folder of point files, "
        f"a ROS bag ({', '.join(BAG_SUFFIXES)} or a ROS 2 bag folder) or sim:NAME",
    )


def describe_sequence(sequence: ScanSequence, *, max_frames: int = 3) -> dict[str, Any]:
    """A JSON-ready summary: frame count, points per frame (over up to ``max_frames`` frames
    spread over the sequence), ground truth, per-point time, stamps."""
    n = len(sequence)
    picks = sorted({round(i * (n - 1) / max(max_frames - 1, 1)) for i in range(max_frames)})
    picks = [p for p in picks if 0 <= p < n]
    frames = [sequence[p] for p in picks]
    counts = [len(f) for f in frames]
    time_spans = [
        float(f.timestamps.max() - f.timestamps.min())
        for f in frames
        if f.timestamps is not None and len(f)
    ]
    gt = sequence.ground_truth
    out: dict[str, Any] = {
        "kind": "sequence",
        "loader": type(sequence).__name__,
        "name": sequence.name,
        "frames": n,
        "points_per_frame": {str(p): c for p, c in zip(picks, counts, strict=True)},
        "per_point_time": bool(time_spans) if frames else sequence.has_point_time,
        "sweep_time_span_s": max(time_spans) if time_spans else None,
        "first_stamp": frames[0].stamp if frames else None,
        "last_stamp": frames[-1].stamp if frames and picks[-1] == n - 1 else None,
        "ground_truth": gt is not None,
    }
    if gt is not None:
        steps = np.linalg.norm(np.diff(gt[:, :3, 3], axis=0), axis=1)
        out["ground_truth_length_m"] = float(steps.sum())
    return out


__all__ = [
    "BAG_SUFFIXES",
    "DEFAULT_FRAME_PERIOD",
    "FOLDER_GROUND_TRUTH",
    "SEQUENCE_FILE_READERS",
    "SIMULATED_SCENES",
    "SIM_OPTIONS",
    "TIME_UNITS",
    "FolderSequence",
    "KittiSequence",
    "RosbagSequence",
    "ScanSequence",
    "SequenceFrame",
    "SimulatedSequence",
    "describe_sequence",
    "natural_sorted",
    "open_sequence",
    "parse_sim_spec",
    "time_in_seconds",
]
