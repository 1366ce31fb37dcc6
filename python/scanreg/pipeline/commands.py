"""What each ``scanreg`` command does, as library functions a Python user calls the same way:
the command line only parses its arguments, calls one of these and prints what it returns.

=================================  ==========================================================
:func:`run_odometry_to_folder`     ``scanreg odometry PATH -o OUT`` (3D sequences; 2D CARMEN
                                   logs and LaserScan bags with :class:`Odometry2D`)
:func:`run_mapping_to_folder`      ``scanreg map PATH -o OUT`` (2D or 3D, with loop closure;
                                   the folder is a :class:`scanreg.SavedMap`)
:func:`run_localization_to_folder` ``scanreg localize PATH --map MAP -o OUT``
:func:`merge_maps_to_folder`       ``scanreg merge A/ B/ -o M/`` (two saved maps, 2D or 3D, one
                                   graph)
:func:`register_files`             ``scanreg register SOURCE TARGET [--global]``
:func:`registration_summary`       the JSON of ``scanreg register`` for a result
:func:`describe_input`             ``scanreg info PATH``
:func:`evaluate_trajectories`      ``scanreg evaluate ESTIMATE REFERENCE``
:func:`plot_trajectory_files`      ``scanreg plot trajectory|errors``
:func:`simulate_to_folder`         ``scanreg simulate -o OUT``
=================================  ==========================================================

``scanreg report`` is :func:`scanreg.report.write_report`, ``scanreg batch``
:func:`scanreg.batch.run_batch`, ``scanreg demo`` :func:`scanreg.demo.run_demo`.

Each takes the command's options as keyword arguments (``config`` a TOML path, ``plots``,
``progress`` a bar on stderr...), writes the command's files into ``output`` and returns the
JSON-ready dict the command prints with ``--json`` (the paths written under ``outputs``).

>>> from scanreg.pipeline import run_mapping_to_folder
>>> result = run_mapping_to_folder("intel.clf.bz2", "out/", resolution=0.05)
>>> result["loops_accepted"], result["outputs"]["map_yaml"]
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Sequence
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from .._progress import Progress
from ..saved_map import refresh_manifest

PathLike = str | os.PathLike[str]

#: ``scanreg simulate``'s scenes and sensor presets, 2D and 3D.
SCENES_2D = ("floor_plan", "corridor", "square_room")


SCENES_3D = ("street", "tunnel", "corridor")


SENSORS_2D = ("sick_lms200", "laser_360", "laser_361")


SENSORS_3D = ("vlp16", "hdl32", "hdl64")


def _path(value: PathLike | None, name: str) -> Path | None:
    if value is None:
        return None
    if not isinstance(value, (str, os.PathLike)):
        raise TypeError(f"{name}: expected a str or os.PathLike, got {type(value).__name__}")
    return Path(value)


def _source(value: Any) -> str:
    if not isinstance(value, (str, os.PathLike)):
        raise TypeError(f"path: expected a str or os.PathLike, got {type(value).__name__}")
    return str(value)


def _pose(value: Sequence[float] | None) -> list[float] | None:
    return None if value is None else [float(v) for v in value]


def _at_least_one(value: int | None, option: str, unit: str = "") -> None:
    """Refuse a count option below 1 (``None``: not given)."""
    if value is not None and value < 1:
        raise ValueError(f"--{option} must be >= 1{unit}, got {value}")


def _positive(value: float, option: str) -> None:
    """Refuse an option that must be > 0 (NaN too)."""
    if not value > 0:
        raise ValueError(f"--{option} must be > 0, got {value}")


def _not_available(args: SimpleNamespace, flags: Sequence[str], where: str) -> None:
    """Refuse the first of ``flags`` (option names as ``args`` spells them) that is set:
    ``--flag: not available <where>``."""
    for flag in flags:
        if getattr(args, flag, None):
            raise ValueError(f"--{flag.replace('_', '-')}: not available {where}")


def run_odometry_to_folder(
    path: PathLike,
    output: PathLike = "odometry-output",
    *,
    config: PathLike | None = None,
    presets: Sequence[str] = (),
    method: str | None = None,
    max_frames: int | None = None,
    topic: str | None = None,
    scan_topic: str | None = None,
    odom_topic: str | None = None,
    laser_pose: Sequence[float] | None = None,
    save_map: bool = False,
    map_format: str = "ply",
    map_origin: Sequence[float] | None = None,
    las_scale: float = 0.001,
    las_offset: Sequence[float] | None = None,
    crs: str | None = None,
    bag: PathLike | None = None,
    bag_frames: Sequence[str] = ("map", "odom", "lidar"),
    bag_scan_voxel: float = 0.2,
    report: bool = False,
    plots: bool = True,
    progress: bool = False,
) -> dict[str, Any]:
    """``scanreg odometry``: odometry over ``path`` (KITTI folder, folder of point files, ROS
    bag, ``sim:`` URI; or a 2D CARMEN log / LaserScan bag) into ``output``: poses, per-frame
    quality, effective config, plots; returns the command's JSON (see the CLI's ``--help``
    for each option)."""
    args = SimpleNamespace(
        path=_source(path),
        output=_path(output, "output"),
        config=_path(config, "config"),
        preset=list(presets),
        method=method,
        max_frames=max_frames,
        topic=topic,
        scan_topic=scan_topic,
        odom_topic=odom_topic,
        laser_pose=_pose(laser_pose),
        save_map=save_map,
        map_format=map_format,
        map_origin=_pose(map_origin),
        las_scale=las_scale,
        las_offset=_pose(las_offset),
        crs=crs,
        bag=_path(bag, "bag"),
        bag_frames=list(bag_frames),
        bag_scan_voxel=bag_scan_voxel,
        report=report,
        no_plots=not plots,
        json=False,
        quiet=not progress,
    )
    return _odometry(args)


def run_mapping_to_folder(
    path: PathLike,
    output: PathLike = "map-output",
    *,
    config: PathLike | None = None,
    max_scans: int | None = None,
    kind: str | None = None,
    resolution: float = 0.05,
    voxel_size: float = 0.2,
    topic: str | None = None,
    scan_topic: str | None = None,
    odom_topic: str | None = None,
    laser_pose: Sequence[float] | None = None,
    bag: PathLike | None = None,
    bag_frames: Sequence[str] = ("map", "odom", "laser"),
    report: bool = False,
    checkpoint: int | None = None,
    extend: PathLike | None = None,
    plots: bool = True,
    progress: bool = False,
) -> dict[str, Any]:
    """``scanreg map``: mapping with loop closure of ``path`` (2D: CARMEN log or LaserScan
    bag; 3D: KITTI folder, folder of point files, bag, ``sim:loop``) into ``output`` (a
    :class:`scanreg.SavedMap` folder plus the run's summary, config, plot); returns the
    command's JSON. A run stopped by an error or Ctrl-C writes what it mapped and raises
    :class:`MappingStopped`. A map whose self-check finds it inconsistent is returned with
    ``self_check["consistent"] == False`` and the reasons.

    ``extend``: a saved map's folder (of the run's dimension): the run is mapped, located
    in it from no initial pose, closed against it and joined into one graph
    (:func:`~scanreg.pipeline.extend_map`; the saved map's ``config.toml`` unless ``config``
    is given); ``output`` may be that folder (updated in place once the joint map is made).
    With it, ``report`` and ``bag`` are the joint map's (every session), and ``checkpoint``
    (2D) writes the new run's map alone, in its own frame, to ``output/new_run_checkpoint/``
    (kept after a stop, for :func:`merge_maps_to_folder`; removed once joined).

    >>> run_mapping_to_folder("run2.mcap", "out2/", extend="out/", report=True)"""
    args = SimpleNamespace(
        path=_source(path),
        output=_path(output, "output"),
        config=_path(config, "config"),
        max_scans=max_scans,
        kind=kind,
        resolution=resolution,
        voxel_size=voxel_size,
        topic=topic,
        scan_topic=scan_topic,
        odom_topic=odom_topic,
        laser_pose=_pose(laser_pose),
        bag=_path(bag, "bag"),
        bag_frames=list(bag_frames),
        report=report,
        checkpoint=checkpoint,
        extend=_path(extend, "extend"),
        no_plots=not plots,
        json=False,
        quiet=not progress,
    )
    return _map(args)


def run_localization_to_folder(
    path: PathLike,
    map: PathLike,  # the command's own option name
    output: PathLike = "localize-output",
    *,
    topic: str | None = None,
    scan_topic: str | None = None,
    odom_topic: str | None = None,
    laser_pose: Sequence[float] | None = None,
    max_scans: int | None = None,
    progress: bool = False,
) -> dict[str, Any]:
    """``scanreg localize``: locate ``path``'s scans in ``map`` (a folder ``scanreg map``
    wrote, read as a :class:`scanreg.SavedMap`; 2D also a ``map_server`` ``map.yaml``, 3D a
    point file) without changing it, from no initial pose; ``poses_tum.txt`` and
    ``quality.jsonl`` into ``output``; returns the command's JSON."""
    map_path = _path(map, "map")
    assert map_path is not None
    args = SimpleNamespace(
        path=_source(path),
        map=map_path,
        output=_path(output, "output"),
        topic=topic,
        scan_topic=scan_topic,
        odom_topic=odom_topic,
        laser_pose=_pose(laser_pose),
        max_scans=max_scans,
        json=False,
        quiet=not progress,
    )
    return _localize(args)


def describe_input(
    path: PathLike, *, topic: str | None = None, trajectory_format: str | None = None
) -> dict[str, Any]:
    """``scanreg info``: what ``path`` holds — a map folder (:meth:`scanreg.SavedMap.describe`),
    a point cloud, a trajectory (read as
    ``trajectory_format``, ``"kitti"`` or ``"tum"``), a ROS bag (its topics; ``topic`` the
    PointCloud2 to summarise as a sequence) or a sequence (folder or ``sim:`` URI)."""
    args = SimpleNamespace(
        path=_path(path, "path"), topic=topic, trajectory_format=trajectory_format
    )
    return _info(args)


def evaluate_trajectories(
    estimate: PathLike,
    reference: PathLike,
    *,
    format: str,  # the command's own option name
    metric: str = "ate",
    alignment: str = "se3",
    delta: float = 1.0,
    unit: str = "frames",
) -> dict[str, Any]:
    """``scanreg evaluate``: ``estimate`` against ``reference`` (both ``"kitti"`` or ``"tum"``
    files): ATE, RPE over ``delta`` frames or metres, or the KITTI metric."""
    args = SimpleNamespace(
        estimate=_path(estimate, "estimate"),
        reference=_path(reference, "reference"),
        format=format,
        metric=metric,
        alignment=alignment,
        delta=delta,
        unit=unit,
    )
    return _evaluate(args)


def register_files(
    source: PathLike,
    target: PathLike,
    *,
    method: str = "point_to_plane",
    init: PathLike | None = None,
    max_correspondence_distance: float = 1.0,
    voxel_size: float | None = None,
    kernel: str = "none",
    max_iterations: int = 30,
    global_search: bool = False,
) -> dict[str, Any]:
    """``scanreg register``: align the point file ``source`` to ``target`` (``init``: a text
    file with the initial 3x3/4x4 ``T_target_source``; ``global_search``: 3D, no guess);
    returns :func:`registration_summary` (or the global search's hypotheses)."""
    args = SimpleNamespace(
        source=_path(source, "source"),
        target=_path(target, "target"),
        method=method,
        init=_path(init, "init"),
        max_correspondence_distance=max_correspondence_distance,
        voxel_size=voxel_size,
        kernel=kernel,
        max_iterations=max_iterations,
        global_=global_search,
    )
    return _register(args)


def plot_trajectory_files(
    kind: str,
    estimate: PathLike,
    output: PathLike,
    *,
    format: str,  # the command's own option name
    reference: PathLike | None = None,
    alignment: str = "none",
    plane: str = "auto",
) -> dict[str, Any]:
    """``scanreg plot trajectory|errors``: a figure (PNG/SVG by ``output``'s extension) of
    ``estimate`` (and ``reference``; ``"errors"`` needs it)."""
    if kind not in ("trajectory", "errors"):
        raise ValueError(f"kind: expected 'trajectory' or 'errors', got {kind!r}")
    if kind == "errors" and reference is None:
        raise ValueError("reference: the errors plot needs a reference trajectory")
    args = SimpleNamespace(
        plot_kind=kind,
        estimate=_path(estimate, "estimate"),
        reference=_path(reference, "reference"),
        output=_path(output, "output"),
        format=format,
        alignment=alignment,
        plane=plane,
    )
    return _plot(args)


def simulate_to_folder(
    output: PathLike,
    *,
    scene: str = "floor_plan",
    sensor: str = "sick_lms200",
    scans: int = 10,
    speed: float = 1.0,
    yaw_rate: float = 0.0,
    scan_rate: float = 10.0,
    seed: int = 0,
    format: str = "auto",  # the command's own option name
    progress: bool = False,
) -> dict[str, Any]:
    """``scanreg simulate``: one point file per simulated scan and the ground-truth poses
    (``poses_kitti.txt``, ``poses_tum.txt``) into ``output``."""
    scenes = {*SCENES_2D, *SCENES_3D}
    if scene not in scenes:
        raise ValueError(f"scene: expected one of {', '.join(sorted(scenes))}, got {scene!r}")
    if sensor not in (*SENSORS_2D, *SENSORS_3D):
        known = ", ".join((*SENSORS_2D, *SENSORS_3D))
        raise ValueError(f"sensor: expected one of {known}, got {sensor!r}")
    args = SimpleNamespace(
        output=_path(output, "output"),
        scene=scene,
        sensor=sensor,
        scans=scans,
        speed=speed,
        yaw_rate=yaw_rate,
        scan_rate=scan_rate,
        seed=seed,
        format=format,
        json=False,
        quiet=not progress,
    )
    return _simulate(args)


def _info(args: SimpleNamespace) -> dict[str, Any]:
    from .. import io
    from ..io import sequences

    if not args.trajectory_format:
        spec = str(args.path)
        if spec.startswith("sim:"):
            return sequences.describe_sequence(sequences.open_sequence(spec))
        if args.path.suffix.lower() in _BAG_SUFFIXES or (args.path / "metadata.yaml").is_file():
            return _bag_info(args.path, args.topic)
        if args.path.is_dir() and (args.path / "manifest.json").is_file():
            from ..saved_map import SavedMap

            return {"kind": "map", **SavedMap.load(args.path).describe()}
        if args.path.is_dir():
            return sequences.describe_sequence(sequences.open_sequence(args.path))
    if args.trajectory_format:
        traj = io.TRAJECTORY_READERS[args.trajectory_format](args.path)
        positions = traj.positions
        steps = np.linalg.norm(np.diff(positions, axis=0), axis=1)
        out: dict[str, Any] = {
            "kind": "trajectory",
            "format": args.trajectory_format,
            "poses": len(traj),
            "path_length_m": float(steps.sum()),
            "start": positions[0].tolist(),
            "end": positions[-1].tolist(),
        }
        if traj.timestamps is not None:
            out["duration_s"] = float(traj.timestamps[-1] - traj.timestamps[0])
        return out
    cloud = io.read_points(args.path)
    finite = cloud.points[np.isfinite(cloud.points).all(axis=1)]
    return {
        "kind": "points",
        "points": len(cloud),
        "finite_points": int(finite.shape[0]),
        "dim": cloud.dim,
        "min": finite.min(axis=0).tolist() if finite.size else None,
        "max": finite.max(axis=0).tolist() if finite.size else None,
        "fields": sorted(cloud.named_fields()),
        **_las_info(args.path),
    }


def _bag_info(path: Path, topic: str | None) -> dict[str, Any]:
    from ..io import rosbag, sequences

    topics = rosbag.list_topics(path)
    out: dict[str, Any] = {
        "kind": "bag",
        "format": "ros2" if path.is_dir() else _BAG_SUFFIXES[path.suffix.lower()],
        "messages": sum(t.message_count for t in topics),
        "topics": {t.name: {"type": t.msgtype, "messages": t.message_count} for t in topics},
    }
    clouds = [t.name for t in topics if t.msgtype == rosbag.POINT_CLOUD2]
    if topic is not None or len(clouds) == 1:
        # random access re-reads a bag from the start: summarise the first frame only
        seq = sequences.RosbagSequence(path, topic=topic)
        out["sequence"] = sequences.describe_sequence(seq, max_frames=1)
    return out


_BAG_SUFFIXES = {".bag": "ros1", ".db3": "ros2-sqlite3", ".mcap": "ros2-mcap"}


def _las_info(path: Path) -> dict[str, Any]:
    """A LAS/LAZ file's header facts (scale, offset, CRS); nothing for other formats."""
    if path.suffix.lower() not in (".las", ".laz"):
        return {}
    from ..io import read_las_header

    h = read_las_header(path)
    return {
        "las": {
            "version": h.version,
            "point_format": h.point_format,
            "compressed": h.compressed,
            "scale": h.scale.tolist(),
            "offset": h.offset.tolist(),
            "crs_wkt": h.crs_wkt,
        }
    }


def _evaluate(args: SimpleNamespace) -> dict[str, Any]:
    from .. import eval as ev
    from .. import io

    read = io.TRAJECTORY_READERS[args.format]
    est, ref = read(args.estimate), read(args.reference)
    if args.metric == "ate":
        ate = ev.absolute_trajectory_error(est, ref, alignment=args.alignment)
        return {
            "metric": "ate",
            "alignment": args.alignment,
            "translation_m": _stats(ate.translation),
            "rotation_deg": _stats(ate.rotation_deg),
        }
    if args.metric == "rpe":
        delta = int(args.delta) if args.unit == "frames" else args.delta
        rpe = ev.relative_pose_error(est, ref, delta=delta, unit=args.unit)
        return {
            "metric": "rpe",
            "delta": args.delta,
            "unit": args.unit,
            "translation_m": _stats(rpe.translation),
            "rotation_deg": _stats(rpe.rotation_deg),
        }
    kitti = ev.kitti_odometry_error(est, ref)
    return {
        "metric": "kitti",
        "translation_percent": kitti.translation_percent,
        "rotation_deg_per_m": kitti.rotation_deg_per_m,
    }


def _stats(stats: Any) -> dict[str, float]:
    keys = ("rmse", "mean", "median", "std", "min", "max", "sse")
    return {k: float(getattr(stats, k)) for k in keys}


def _register(args: SimpleNamespace) -> dict[str, Any]:
    from .. import io, preprocess
    from ..register import register

    if args.global_:
        return _register_global(args)

    clouds = []
    for name in ("source", "target"):
        pts = io.read_points(getattr(args, name)).finite().points
        if args.voxel_size:
            pts = preprocess.voxel_downsample(pts, args.voxel_size).points
        clouds.append(np.ascontiguousarray(pts))
    init = None if args.init is None else np.loadtxt(args.init, ndmin=2)
    res = register(
        clouds[0],
        clouds[1],
        method=args.method,
        init=init,
        max_correspondence_distance=args.max_correspondence_distance,
        kernel=args.kernel,
        max_iterations=args.max_iterations,
    )
    from .commands import registration_summary

    return registration_summary(res)


def _register_global(args: SimpleNamespace) -> dict[str, Any]:
    from .. import io
    from ..global_registration import register_global

    if args.init is not None:
        raise ValueError("--init: --global registers without an initial guess")
    clouds = [
        np.ascontiguousarray(io.read_points(getattr(args, n)).finite().points)
        for n in ("source", "target")
    ]
    res = register_global(clouds[0], clouds[1], voxel_size=args.voxel_size)
    best = res.hypotheses[0] if res.accepted else None
    return {
        # The exit status reads "converged": false when nothing is reliable.
        "converged": res.accepted,
        "accepted": res.accepted,
        "reasons": list(res.reasons),
        "pose": None if best is None else best.pose.as_matrix().tolist(),
        "pose_vector": None if best is None else best.pose.as_vector().tolist(),
        "covariance": None if best is None else best.covariance.tolist(),
        "voxel_size": res.voxel_size,
        "feature_radius": res.feature_radius,
        "num_correspondences": res.num_correspondences,
        "hypotheses": [
            {
                "pose": h.pose.as_matrix().tolist(),
                "initial_pose": h.initial_pose.as_matrix().tolist(),
                "num_inliers": h.num_inliers,
                "clique_size": h.clique_size,
                "accepted": h.verdict.accepted,
                "reasons": list(h.verdict.reasons),
                "covariance": [
                    [v if math.isfinite(v) else None for v in row] for row in h.covariance.tolist()
                ],
            }
            for h in res.hypotheses
        ],
        "time_s": res.time_s,
    }


def _plot(args: SimpleNamespace) -> dict[str, Any]:
    from .. import io, plot

    read = io.TRAJECTORY_READERS[args.format]
    estimate = read(args.estimate)
    reference = None if args.reference is None else read(args.reference)
    if args.plot_kind == "trajectory":
        out = plot.plot_trajectories(
            args.output, estimate, reference, alignment=args.alignment, plane=args.plane
        )
    else:
        assert reference is not None
        out = plot.plot_error_over_distance(
            args.output, estimate, reference, alignment=args.alignment
        )
    return {"plot": args.plot_kind, "output": str(out), "bytes": out.stat().st_size}


def _simulate(args: SimpleNamespace) -> dict[str, Any]:
    from .. import io
    from .. import simulate as sim
    from ..transform import SE2, SE3

    dim = 3 if args.sensor in SENSORS_3D else 2
    scenes = SCENES_3D if dim == 3 else SCENES_2D
    if args.scene not in scenes:
        raise ValueError(
            f"--scene {args.scene} is not available for the {dim}D sensor {args.sensor} "
            f"(choose from {', '.join(scenes)})"
        )
    _at_least_one(args.scans, "scans")
    _positive(args.scan_rate, "scan-rate")
    fmt = args.format if args.format != "auto" else ("pcd" if dim == 3 else "csv")
    # PCD/PLY/LAS hold 3D points: a 2D scan is written in the plane z = 0.
    pad_z = dim == 2 and fmt in ("pcd", "ply", "las", "laz")
    sensor: sim.LaserModel | sim.LidarModel
    start: SE2 | SE3
    if dim == 3:
        sensor = sim.LidarModel.preset(args.sensor)
        period = sensor.sweep_duration
        if args.scene == "street":
            scene = sim.street(seed=args.seed)
            start = SE3.from_vector([0.0, 1.75, 1.73, 0.0, 0.0, 0.0])
        elif args.scene == "tunnel":
            scene = sim.tunnel()
            start = SE3.from_vector([0.0, 0.0, 1.73, 0.0, 0.0, 0.0])
        else:
            scene = sim.corridor(dim=3)
            start = SE3.from_vector([1.0, 0.0, 1.2, 0.0, 0.0, 0.0])
    else:
        sensor = sim.LaserModel.preset(args.sensor)
        period = 1.0 / args.scan_rate
        if args.scene == "floor_plan":
            scene = sim.floor_plan(seed=args.seed)
            start = SE2.from_vector([1.0, 0.0, 0.0])
        elif args.scene == "corridor":
            scene = sim.corridor()
            start = SE2.from_vector([1.0, 0.0, 0.0])
        else:
            scene = sim.square_room()
            start = SE2.identity()
    duration = period * args.scans + 0.5
    traj = sim.Trajectory.from_speed_and_yaw_rate(
        args.speed, args.yaw_rate, duration=duration, dim=dim, start=start
    )
    out: Path = args.output
    out.mkdir(parents=True, exist_ok=True)
    files = []
    # one scan at a time (the same calls and seeds as simulate_run) so the bar can move
    start_times = traj.start_time + period * np.arange(args.scans)
    scans: list[sim.LaserScan | sim.LidarSweep] = []
    bar = Progress(
        args.scans,
        description="simulate",
        unit="scans",
        enabled=not (args.quiet or args.json),
    )
    for k, t0 in enumerate(start_times):
        scan: sim.LaserScan | sim.LidarSweep
        if isinstance(sensor, sim.LidarModel):
            scan = sim.simulate_sweep(
                scene, sensor, traj, start_time=float(t0), seed=args.seed, scan_index=k
            )
        else:
            scan = sim.simulate_scan(
                scene, sensor, traj, start_time=float(t0), seed=args.seed, scan_index=k
            )
        scans.append(scan)
        points = scan.points
        if pad_z:
            points = np.column_stack([points, np.zeros(len(points))])
        if isinstance(scan, sim.LidarSweep):
            ring, stamps = scan.rings, scan.timestamps
        else:
            ring, stamps = None, scan.timestamps[scan.point_beams]
        # Per-point time in seconds since the scan's start, as drivers report it.
        cloud = io.PointCloud(
            points=np.ascontiguousarray(points), ring=ring, time=stamps - scan.start_time
        )
        path = out / f"{k:06d}.{fmt}"
        io.write_points(path, cloud)
        files.append(path.name)
        bar.update(points=len(scan.points))
    bar.close()
    poses: list[Any] = [s.pose for s in scans]
    truth = io.Trajectory.from_poses(poses, timestamps=start_times)
    io.write_kitti_poses(out / "poses_kitti.txt", truth)
    io.write_tum(out / "poses_tum.txt", truth)
    return {
        "output": str(out),
        "scene": args.scene,
        "sensor": args.sensor,
        "dim": dim,
        "scans": len(files),
        "files": files,
        "points_per_scan": [len(s.points) for s in scans],
        "poses_kitti": "poses_kitti.txt",
        "poses_tum": "poses_tum.txt",
        "poses": "T_world_sensor at each scan's start time (the TUM timestamps)",
    }


class MappingStopped(Exception):
    """A mapping run stopped early; its partial outputs were written (the message says where).
    ``interrupted``: stopped by Ctrl-C rather than an error."""

    def __init__(self, message: str, *, interrupted: bool) -> None:
        super().__init__(message)
        self.interrupted = interrupted


def _odometry(args: SimpleNamespace) -> dict[str, Any]:
    from ..config import load_config
    from ..io import open_sequence, write_poses, write_run_outputs
    from ..io.sequences import KittiSequence, SimulatedSequence
    from .odometry import OdometryConfig
    from .run import evaluate_run, run_odometry

    if not str(args.path).startswith("sim:") and (
        _carmen_key(args.path) is not None or _is_2d_bag(args)
    ):
        return _odometry_carmen(args)  # a 2D laser log or LaserScan bag
    _at_least_one(args.max_frames, "max-frames")
    overrides = {} if args.method is None else {"method": args.method}
    config = load_config(OdometryConfig, args.config, presets=args.preset, overrides=overrides)
    las_options = _las_options(args)
    args.output.mkdir(parents=True, exist_ok=True)  # a --bag inside it can be checked now
    bag_frames = _bag_settings(args)
    seq = open_sequence(args.path, topic=args.topic)
    run = run_odometry(
        seq, config, max_frames=args.max_frames, progress=not (args.quiet or args.json)
    )
    t_cam = getattr(seq, "T_cam0_velo", None) if isinstance(seq, KittiSequence) else None
    written = write_run_outputs(
        args.output,
        poses=run.poses,
        stamps=run.stamps,
        rows=run.quality_rows(),
        config=config,
        T_cam0_velo=t_cam,
    )
    result: dict[str, Any] = {
        "sequence": getattr(seq, "name", str(args.path)),
        "frames": len(run.frames),
        "frames_per_second": run.frames_per_second,
        "accepted": run.num_accepted,
        "rejected": len(run.frames) - run.num_accepted,
        "rejection_reasons": run.rejection_reasons(),
        "held_frames": sum(bool(f.held_directions) for f in run.frames),
        "method": config.method,
    }
    truth = None
    if isinstance(seq, SimulatedSequence):
        truth = seq.ground_truth_at(config.reference_time)  # the time the poses refer to
    elif seq.ground_truth is not None:
        truth = seq.ground_truth
    if truth is not None and len(run.frames) >= 3:  # the SE(3) alignment needs 3 positions
        result["accuracy"] = evaluate_run(run, truth)
    if not args.no_plots:
        from .. import plot
        from ..io import Trajectory

        est = Trajectory(run.poses, run.stamps)
        ref = None if truth is None else Trajectory(truth[: len(run.poses)], run.stamps)
        traj_png = plot.plot_trajectories(
            args.output / "trajectory.png",
            est,
            ref,
            alignment="none" if ref is None else "se3",
            title=f"{result['sequence']}: odometry",
        )
        unc_png = plot.plot_frame_uncertainty(
            args.output / "uncertainty.png",
            np.array([f.covariance for f in run.frames]),
            accepted=[f.verdict.accepted for f in run.frames],
            held=[bool(f.held_directions) for f in run.frames],
        )
        written["trajectory_plot"] = str(traj_png)
        written["uncertainty_plot"] = str(unc_png)
    if args.save_map or args.report:
        map_path = args.output / f"map.{args.map_format}"
        written["map"] = str(map_path)
        if args.map_origin is None:
            result["map_points"] = run.odometry.save_map(map_path, **las_options)
        else:
            from ..io import PointCloud, write_points

            cloud = run.odometry.map_cloud()
            moved = cloud.points + np.asarray(args.map_origin, dtype=np.float64)
            write_points(map_path, PointCloud(points=moved, fields=cloud.fields), **las_options)
            result["map_points"] = len(cloud)
            result["map_origin"] = list(args.map_origin)
    if truth is not None:
        reference = write_poses(
            args.output / "reference_tum.txt",
            truth[: len(run.poses)],
            "tum",
            timestamps=run.stamps,
        )
        written["reference_tum"] = str(reference)
    if bag_frames is not None:
        result["bag"] = _write_bag(args, bag_frames, seq, run)
        written["bag"] = result["bag"]["path"]
    result["outputs"] = written
    summary_path = args.output / "summary.json"
    written["summary"] = str(summary_path)
    summary_path.write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
    if args.report:
        from ..report import write_report

        written["report"] = str(write_report(args.output))
    return result


def _odometry_carmen(args: SimpleNamespace) -> dict[str, Any]:
    """``scanreg odometry LOG.clf``: 2D scan-to-map odometry (:class:`Odometry2D`) over a CARMEN
    log in file order, the wheel odometry as each scan's prior. ``--config`` is an
    :class:`OdometryConfig2D` TOML over the mapping pipeline's odometry defaults."""
    import time

    from ..config import load_config, write_config
    from ..io import Trajectory, write_kitti_poses, write_tum
    from .mapping import MappingConfig
    from .odometry2d import Odometry2D, OdometryConfig2D

    flags = ("preset", "method", "topic", "bag", "save_map", "report")
    _not_available(args, flags, "for a 2D laser log")
    _at_least_one(args.max_frames, "max-frames")
    # The mapping pipeline's odometry (correlative front end) under the user's file.
    mapping = MappingConfig().odometry
    preset = {f: getattr(mapping, f) for f in ("front_end", "kernel", "max_keyframes")}
    config = load_config(
        OdometryConfig2D, args.config, presets=["mapping"], preset_table={"mapping": preset}
    )
    # The wheel odometry at each scan's own time (a log whose laser messages carry stale
    # odometry, as ACES', is read from its ODOM stream; the mapping pipeline's prior).
    scans = _scan_log(args, max_scans=args.max_frames)
    args.output.mkdir(parents=True, exist_ok=True)
    odo = Odometry2D(config)
    rows: list[dict[str, Any]] = []
    poses: list[Any] = []
    stamps: list[float] = []
    pending = None
    accepted = 0
    skipped = 0
    last_timed: float | None = None
    t0 = time.perf_counter()
    enabled = not (args.quiet or args.json)
    with Progress(len(scans), description="odometry", unit="scans", enabled=enabled) as bar:
        for i in range(len(scans)):
            step = scans.prior(i)
            if step is not None:
                pending = step if pending is None else pending @ step
            # Its sweep undone by the wheels, or with beam times left to the odometry's own
            # prediction (as Mapper.track: a stamp out of order is taken as instantaneous).
            pts, times = scans.swept_points(i, 0.1, 40.0)
            if len(pts) < 3:  # no returns: nothing to align; its motion joins the next prior
                skipped += 1
                bar.update()
                continue
            stamp = float(scans.stamps[i])
            timed: dict[str, Any] = {}
            if times is not None and (last_timed is None or stamp >= last_timed):
                timed, last_timed = {"timestamps": times, "stamp": stamp}, stamp
            frame = odo.step(pts, prior=pending if poses else None, **timed)
            pending = None
            poses.append(frame.pose)
            stamps.append(float(scans.stamps[i]))
            accepted += frame.verdict.accepted
            sd = np.sqrt(np.clip(np.diag(frame.covariance), 0, None))
            rows.append(
                {
                    "scan": i,
                    "stamp": float(scans.stamps[i]),
                    "accepted": frame.verdict.accepted,
                    "reasons": "; ".join(frame.verdict.reasons),
                    "prediction_source": frame.prediction_source,
                    "sigma_x": float(sd[0]),
                    "sigma_y": float(sd[1]),
                    "sigma_theta_deg": float(np.degrees(sd[2])),
                    "map_updated": frame.map_updated,
                }
            )
            bar.update(accepted=accepted, rejected=len(poses) - accepted)
    elapsed = time.perf_counter() - t0
    if not poses:
        raise ValueError(f"path: no scan of {args.path} had at least 3 returns")
    traj = Trajectory.from_poses(poses, np.array(stamps, dtype=np.float64))
    written = {
        "poses_kitti": args.output / "poses_kitti.txt",
        "poses_tum": args.output / "poses_tum.txt",
    }
    write_kitti_poses(written["poses_kitti"], traj)
    write_tum(written["poses_tum"], traj)
    written["quality"] = args.output / "quality.jsonl"
    with written["quality"].open("w", encoding="utf-8") as fh:
        for row in rows:
            fh.write(json.dumps(row) + "\n")
    written["config"] = write_config(args.output / "config.toml", config)
    result: dict[str, Any] = {
        "sequence": str(args.path),
        "frames": len(poses),
        "skipped_scans": skipped,
        "frames_per_second": len(poses) / elapsed if elapsed > 0 else 0.0,
        "accepted": accepted,
        "rejected": len(poses) - accepted,
        "front_end": config.front_end,
        "final_pose": [float(v) for v in poses[-1].as_vector()],
        "scans": scans.describe(),
    }
    written["summary"] = args.output / "summary.json"
    result["outputs"] = {k: str(v) for k, v in written.items()}
    written["summary"].write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
    return result


def _carmen_key(path: str) -> str | None:
    """The :data:`scanreg.io.SCAN_SOURCES` key of a CARMEN log path, or ``None``."""
    from ..io import SCAN_SOURCES

    p = Path(path)
    suffixes = [s.lower() for s in p.suffixes]
    key = "".join(suffixes[-2:]) if suffixes[-1:] in ([".gz"], [".bz2"]) else p.suffix.lower()
    return key if key in SCAN_SOURCES else None


def _map(args: SimpleNamespace) -> dict[str, Any]:
    from ..config import load_config, write_config
    from ..graph import require_gtsam

    require_gtsam()  # fail before reading a large log
    from .map_check import check_map
    from .mapping import MappingConfig, MappingInterrupted, run_mapping
    from .mapping_output import summary, write_outputs

    _at_least_one(args.max_scans, "max-scans")
    _positive(args.resolution, "resolution")
    three_d = is_3d_source(args.path) and not _is_2d_bag(args)
    if args.extend is not None:
        return _extend(args, three_d)
    if three_d:
        return _map_3d(args)
    config = load_config(MappingConfig, args.config)
    if args.bag is not None:
        args.output.mkdir(parents=True, exist_ok=True)  # a --bag inside it can be checked now
    frames = _bag_settings(args)  # a bad bag path fails now, not after the run
    _at_least_one(args.checkpoint, "checkpoint", " scans")
    scans = _scan_log(
        args,
        kind=args.kind,
        max_scans=args.max_scans,
        latency=config.laser_latency,
        min_range=config.min_range,
        max_range=config.max_range,
    )

    def checkpoint(partial: Any) -> None:
        write_outputs(
            args.output, partial, resolution=args.resolution, plot=False, session=str(args.path)
        )

    try:
        res = run_mapping(
            scans,
            config,
            progress=not (args.quiet or args.json),
            checkpoint=None if args.checkpoint is None else checkpoint,
            checkpoint_every=args.checkpoint or 1000,
        )
    except MappingInterrupted as exc:
        raise _stopped(args, exc, resolution=args.resolution) from exc
    # An inconsistent map is returned with its reasons (self_check); the CLI warns.
    check = check_map(res)
    paths = write_outputs(
        args.output,
        res,
        resolution=args.resolution,
        plot=not args.no_plots,
        check=check,
        session=str(args.path),
    )
    paths["config"] = write_config(args.output / "config.toml", config)
    if args.bag is not None:
        from ..saved_map import SavedMap

        paths["bag"] = _write_map_bag(args.bag, SavedMap.load(args.output), frames)
    if args.report:
        from ..report import write_report

        paths["report"] = write_report(args.output)
    refresh_manifest(args.output)  # config.toml, report.html: listed too
    result = summary(res, check)
    result["log"] = str(args.path)
    result["scans"] = scans.describe()
    result["outputs"] = {k: str(v) for k, v in paths.items()}
    return result


def _stopped(args: SimpleNamespace, exc: Any, **outputs: Any) -> MappingStopped:
    """Never lose work: what a stopped run mapped (``exc.partial``) is written to the output
    folder (``outputs``: write_outputs' map options), and the run fails saying so."""
    from .mapping_output import write_outputs

    write_outputs(args.output, exc.partial, plot=False, session=str(args.path), **outputs)
    return MappingStopped(
        f"{exc}; what was mapped so far is written to {args.output}/ "
        f"({len(exc.partial.poses)} scans, {len(exc.partial.node_scans)} nodes)",
        interrupted=isinstance(exc.__cause__, KeyboardInterrupt),
    )


#: Files of a map folder that describe one run and not an extended map: removed when an
#: extended map is written over them.
_ONE_RUN_FILES = ("trajectory.png", "contradictions.csv", "report.html")

#: The folder (inside the output) where ``--extend --checkpoint N`` writes the new run's map
#: so far: a map of the new run alone, in its own frame (removed once the joint map is
#: written; after a stop, ``scanreg merge OLD/ OUT/new_run_checkpoint -o OUT/`` joins it).
EXTEND_CHECKPOINT = "new_run_checkpoint"


def _extend(args: SimpleNamespace, three_d: bool) -> dict[str, Any]:
    """``scanreg map NEW --extend OLD/``: the new run (a log or bag, as ``scanreg map`` reads
    it) mapped alone, then joined to the saved map (:func:`scanreg.pipeline.extend_map`),
    written to ``args.output`` with, on request, the joint map's report and ROS 2 bag;
    ``--checkpoint``: the new run's map so far in ``OUT/new_run_checkpoint/``."""
    import shutil

    from ..config import load_config
    from ..saved_map import MANIFEST, SavedMap
    from .extend import extend_map
    from .mapping import MappingConfig, MappingInterrupted, run_mapping
    from .mapping3d import MappingConfig3D, run_mapping_3d
    from .mapping_output import write_outputs

    _at_least_one(args.checkpoint, "checkpoint", " scans")
    if three_d:
        _not_available(args, ("checkpoint",), "for 3D --extend runs (2D only)")
    saved = SavedMap.load(args.extend)
    dim = 3 if three_d else 2
    if saved.dim != dim or saved.node_points is None:
        raise ValueError(
            f"--extend: {args.extend} is a format-{saved.format_version} {saved.dim}D map; "
            f"a {dim}D run extends only a {dim}D map of format 2 (with its node scans)"
        )
    out = Path(args.output)
    if args.bag is not None:
        out.mkdir(parents=True, exist_ok=True)  # a --bag inside it can be checked now
    frames = _bag_settings(args)  # a bad bag path fails now, not after the run
    # The saved map's own configuration, unless another is given.
    own = Path(args.extend) / "config.toml"
    config_path = args.config if args.config is not None or not own.is_file() else own
    progress = not (args.quiet or args.json)
    held = out / EXTEND_CHECKPOINT
    res: Any
    if three_d:
        from ..io import open_sequence

        config: Any = load_config(MappingConfig3D, config_path)
        seq = open_sequence(args.path, topic=args.topic)
        res = run_mapping_3d(seq, config, max_scans=args.max_scans, progress=progress)
        described: dict[str, Any] = {"sequence": getattr(seq, "name", str(args.path))}
    else:
        config = load_config(MappingConfig, config_path)
        scans = _scan_log(
            args,
            kind=args.kind,
            max_scans=args.max_scans,
            latency=config.laser_latency,
            min_range=config.min_range,
            max_range=config.max_range,
        )

        def checkpoint(partial: Any) -> None:  # the new run alone, in its own frame
            write_outputs(
                held, partial, resolution=args.resolution, plot=False, session=str(args.path)
            )

        try:
            res = run_mapping(
                scans,
                config,
                progress=progress,
                checkpoint=None if args.checkpoint is None else checkpoint,
                checkpoint_every=args.checkpoint or 1000,
            )
        except MappingInterrupted as exc:
            kept = ""
            if args.checkpoint is not None:  # never lose the new run's work
                checkpoint(exc.partial)
                kept = (
                    f"; the new run mapped so far is written to {held}/ "
                    f"({len(exc.partial.poses)} scans; `scanreg merge {args.extend} {held} "
                    f"-o OUT/` joins it)"
                )
            raise MappingStopped(
                f"{exc}; nothing joined: the saved map {args.extend}/ is unchanged{kept}",
                interrupted=isinstance(exc.__cause__, KeyboardInterrupt),
            ) from exc
        described = {"scans": scans.describe()}
    joint, report = extend_map(saved, res, session=str(args.path), config=config)
    head: dict[str, Any] = {"extended": str(args.extend), "log": str(args.path)}
    tail: dict[str, Any] = {
        "new_run": {
            "num_scans": res.num_scans,
            "num_nodes": len(res.node_scans),
            "loops_accepted": len(res.accepted_loops),
        },
        **described,
    }
    result = _write_joint(out, joint, report, config, head, tail)
    if args.checkpoint is not None and (held / MANIFEST).is_file():
        shutil.rmtree(held)  # superseded by the joint map
    extra: dict[str, Path] = {}
    if frames is not None:
        extra["bag"] = _write_map_bag(args.bag, joint, frames)
    if args.report:
        from ..report import write_report

        extra["report"] = write_report(out)
        refresh_manifest(out)
    result["outputs"].update({k: str(v) for k, v in extra.items()})
    return result


def _write_joint(
    out: Path,
    joint: Any,
    report: Any,
    config: Any,
    head: dict[str, Any],
    tail: dict[str, Any],
) -> dict[str, Any]:
    """Write a joined map (extend, merge) with its config and summary into ``out`` (the
    one-run files a former map there had removed); a 2D one with its self-check
    (:func:`~scanreg.pipeline.check_map`: ``self_check`` in the summary,
    ``contradictions.csv``); returns the command's JSON."""
    from ..config import write_config

    for name in _ONE_RUN_FILES:  # (the map itself is written whole below)
        (out / name).unlink(missing_ok=True)
    paths = joint.save(out)
    paths["config"] = write_config(out / "config.toml", config)
    result: dict[str, Any] = {
        **head,
        **report.as_dict(),
        **{k: v for k, v in joint.describe().items() if k not in ("frames", "folder")},
        **tail,
    }
    if joint.dim == 2:  # the joint map judged by its own scans, as a single run's is
        from .map_check import check_map

        check = check_map(joint)
        paths["contradictions"] = out / "contradictions.csv"
        points = check.contradiction_points
        np.savetxt(paths["contradictions"], points, "%.3f", ",", header="x,y", comments="")
        result["self_check"] = check.as_dict()
    paths["summary"] = out / "summary.json"
    paths["summary"].write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
    refresh_manifest(out)
    result["outputs"] = {k: str(v) for k, v in paths.items()}
    return result


def merge_maps_to_folder(
    a: PathLike,
    b: PathLike,
    output: PathLike,
    *,
    config: PathLike | None = None,
    locate_tries: int = 20,
    min_loops: int = 2,
) -> dict[str, Any]:
    """``scanreg merge A/ B/ -o M/``: two saved map folders (format 2, both 2D or both 3D,
    frames unrelated) merged into one map in ``a``'s frame
    (:func:`~scanreg.pipeline.merge_maps`), written to ``output`` (which may be ``a``:
    updated in place); ``a``'s ``config.toml`` unless ``config`` is given. ``M/poses_tum.txt``
    holds every scan of both maps with its own stamp, ``M/session_K_poses_tum.txt`` each
    session's. Maps without a reliable overlap raise
    ValueError with the reason, and nothing is written."""
    from ..config import load_config
    from ..saved_map import SavedMap
    from .mapping import MappingConfig
    from .mapping3d import MappingConfig3D
    from .merge import merge_maps

    folders = {"a": _path(a, "a"), "b": _path(b, "b")}
    out = _path(output, "output")
    assert out is not None
    maps = {}
    for name, folder in folders.items():
        assert folder is not None
        if not folder.is_dir():
            raise ValueError(f"{name}: {folder} is not a map folder")
        m = SavedMap.load(folder)
        if m.node_points is None:
            raise ValueError(
                f"{name}: {folder} is a format-{m.format_version} {m.dim}D map; only maps "
                "of format 2 (with their node scans or clouds) can be merged"
            )
        maps[name] = m
    if maps["a"].dim != maps["b"].dim:
        raise ValueError(
            f"b: {folders['b']} is a {maps['b'].dim}D map and a ({folders['a']}) a "
            f"{maps['a'].dim}D map; they cannot merge"
        )
    if out.resolve() == Path(b).resolve():
        raise ValueError(f"output: {out} is map b; merge into a new folder or into a")
    own = Path(a) / "config.toml"
    config_path = _path(config, "config")
    config_path = config_path if config_path is not None or not own.is_file() else own
    kind = MappingConfig if maps["a"].dim == 2 else MappingConfig3D
    settings: Any = load_config(kind, config_path)
    joint, report = merge_maps(
        maps["a"], maps["b"], config=settings, locate_tries=locate_tries, min_loops=min_loops
    )
    head: dict[str, Any] = {"merged": [str(folders["a"]), str(folders["b"])]}
    tail: dict[str, Any] = {"maps": {k: m.describe()["num_scans"] for k, m in maps.items()}}
    return _write_joint(out, joint, report, settings, head, tail)


def _map_3d(args: SimpleNamespace) -> dict[str, Any]:
    """``scanreg map`` on a 3D sequence: Mapper3D, its outputs, and (simulated drives) the
    accuracy before and after loop closure against the exact truth."""
    from ..config import load_config, write_config
    from ..io import open_sequence, write_poses
    from ..io.sequences import SimulatedSequence
    from .map_check import check_map
    from .mapping import MappingInterrupted
    from .mapping3d import MappingConfig3D, run_mapping_3d
    from .mapping_output import summary, write_outputs

    _at_least_one(args.checkpoint, "checkpoint", " scans")
    if not args.voxel_size >= 0:
        raise ValueError(f"--voxel-size must be >= 0, got {args.voxel_size}")
    if args.bag is not None:
        args.output.mkdir(parents=True, exist_ok=True)  # a --bag inside it can be checked now
    frames = _bag_settings(args)  # a bad bag path fails now, not after the run
    config = load_config(MappingConfig3D, args.config)
    seq = open_sequence(args.path, topic=args.topic)

    def checkpoint(partial: Any) -> None:
        write_outputs(
            args.output, partial, voxel_size=args.voxel_size, plot=False, session=str(args.path)
        )

    try:
        res = run_mapping_3d(
            seq,
            config,
            max_scans=args.max_scans,
            progress=not (args.quiet or args.json),
            checkpoint=None if args.checkpoint is None else checkpoint,
            checkpoint_every=args.checkpoint or 1000,
        )
    except MappingInterrupted as exc:
        raise _stopped(args, exc, voxel_size=args.voxel_size) from exc
    # An inconsistent map is returned with its reasons (self_check); the CLI warns.
    check = check_map(res)
    paths = write_outputs(
        args.output,
        res,
        voxel_size=args.voxel_size,
        plot=not args.no_plots,
        check=check,
        session=str(args.path),
    )
    paths["config"] = write_config(args.output / "config.toml", config)
    refresh_manifest(args.output)
    result = summary(res, check)
    result["sequence"] = getattr(seq, "name", str(args.path))
    if isinstance(seq, SimulatedSequence):
        from ..eval import absolute_trajectory_error
        from ..io import Trajectory

        truth = seq.ground_truth_at(config.odometry.reference_time)[: res.num_scans]
        stamps = np.asarray(seq.stamps[: res.num_scans])
        paths["reference_tum"] = write_poses(
            args.output / "reference_tum.txt", truth, "tum", timestamps=stamps
        )
        if res.num_scans >= 3:  # the SE(3) alignment needs 3 positions
            accuracy: dict[str, float] = {}
            for name, poses in (("odometry", res.odometry_poses), ("closed", res.poses)):
                est = np.array([p.as_matrix() for p in poses])
                ate = absolute_trajectory_error(
                    Trajectory(est, stamps), Trajectory(truth, stamps), alignment="se3"
                )
                accuracy[f"{name}_ate_m"] = float(ate.translation.rmse)
                accuracy[f"{name}_end_error_m"] = float(
                    np.linalg.norm(est[-1, :3, 3] - truth[-1, :3, 3])
                )
            result["accuracy"] = accuracy
    if frames is not None:
        from ..saved_map import SavedMap

        paths["bag"] = _write_map_bag(args.bag, SavedMap.load(args.output), frames)
    if args.report:
        from ..report import write_report

        paths["report"] = write_report(args.output)
        refresh_manifest(args.output)
    result["outputs"] = {k: str(v) for k, v in paths.items()}
    return result


def is_3d_source(path: str) -> bool:
    """3D mapping for ``sim:`` drives, folders (KITTI, point files, ROS 2 bags) and bag files;
    2D for anything else (a CARMEN log)."""
    from ..io.sequences import BAG_SUFFIXES

    p = Path(path)
    return path.startswith("sim:") or p.is_dir() or p.suffix.lower() in BAG_SUFFIXES


def _localize(args: SimpleNamespace) -> dict[str, Any]:
    import time

    from ..io import Trajectory, write_tum
    from .localizer2d import Localizer2D

    _at_least_one(args.max_scans, "max-scans")
    if is_3d_source(args.path) and not _is_2d_bag(args):
        return _localize_3d(args)
    if args.map.is_dir():  # the folder scanreg map wrote
        from ..saved_map import SavedMap

        loc = Localizer2D.from_saved_map(SavedMap.load(args.map))
    else:  # a ROS map_server map.yaml
        loc = Localizer2D.from_map_server(args.map)
    # The scans in the base frame and the wheel odometry at each one's time, as mapped.
    scans = _scan_log(args, max_scans=args.max_scans)
    args.output.mkdir(parents=True, exist_ok=True)
    rows, poses, stamps = [], [], []
    t0 = time.perf_counter()
    enabled = not (args.quiet or args.json)
    with Progress(len(scans), description="localize", unit="scans", enabled=enabled) as bar:
        for i in range(len(scans)):
            pts, _ = scans.swept_points(i, 0.1, 40.0)  # (its sweep undone by the wheels)
            prior = scans.prior(i)
            if len(pts) < 3:
                bar.update()
                continue
            stamp = float(scans.stamps[i])
            frame = loc.step(pts, prior=prior, stamp=stamp)
            sd = np.sqrt(np.clip(np.diag(frame.covariance), 0, None))
            rows.append(
                {
                    "stamp": stamp,
                    "accepted": frame.verdict.accepted,
                    "reasons": "; ".join(frame.verdict.reasons),
                    "prediction_source": frame.prediction_source,
                    "x": float(frame.pose.translation[0]),
                    "y": float(frame.pose.translation[1]),
                    "theta": float(frame.pose.angle),
                    "sigma_x": float(sd[0]),
                    "sigma_y": float(sd[1]),
                    "sigma_theta": float(sd[2]),
                }
            )
            poses.append(frame.pose)
            stamps.append(stamp)
            bar.update()
    seconds = time.perf_counter() - t0
    tum = args.output / "poses_tum.txt"
    write_tum(tum, Trajectory.from_poses(poses, np.asarray(stamps, dtype=np.float64)))
    quality = args.output / "quality.jsonl"
    quality.write_text("".join(json.dumps(r) + "\n" for r in rows), encoding="utf-8")
    accepted = sum(bool(r["accepted"]) for r in rows)
    return {
        "log": str(args.path),
        "map": str(args.map),
        "num_scans": len(rows),
        "accepted": accepted,
        "rejected": len(rows) - accepted,
        "global_fixes": sum(r["prediction_source"] == "global" and r["accepted"] for r in rows),
        "scans_per_second": len(rows) / seconds if seconds > 0 else 0.0,
        "outputs": {"poses_tum": str(tum), "quality": str(quality)},
    }


def _localize_3d(args: SimpleNamespace) -> dict[str, Any]:
    """``scanreg localize`` on a 3D sequence: MapLocalizer in the saved map, from no pose."""
    import time

    from ..io import open_sequence, write_poses
    from ..io.sequences import SimulatedSequence
    from .map_localizer import MapLocalizer
    from .run import quality_row

    loc = MapLocalizer.from_folder(args.map)
    seq = open_sequence(args.path, topic=args.topic)
    total = len(seq) if args.max_scans is None else min(len(seq), args.max_scans)
    args.output.mkdir(parents=True, exist_ok=True)
    rows, poses, stamps = [], [], []
    t0 = time.perf_counter()
    enabled = not (args.quiet or args.json)
    with Progress(total, description="localize", unit="scans", enabled=enabled) as bar:
        for k in range(total):
            f = seq[k]
            frame = loc.step(f.points, f.timestamps, stamp=f.stamp)
            row = quality_row(frame, f.stamp)
            row["prediction_source"] = frame.prediction_source
            rows.append(row)
            poses.append(frame.pose.as_matrix())
            stamps.append(f.stamp)
            bar.update()
    seconds = time.perf_counter() - t0
    tum = write_poses(args.output / "poses_tum.txt", np.array(poses), "tum", timestamps=stamps)
    quality = args.output / "quality.jsonl"
    quality.write_text("".join(json.dumps(r) + "\n" for r in rows), encoding="utf-8")
    accepted = sum(bool(r["accepted"]) for r in rows)
    result: dict[str, Any] = {
        "sequence": getattr(seq, "name", str(args.path)),
        "map": str(args.map),
        "num_scans": len(rows),
        "accepted": accepted,
        "rejected": len(rows) - accepted,
        "global_fixes": sum(r["prediction_source"] == "global" and r["accepted"] for r in rows),
        "scans_per_second": len(rows) / seconds if seconds > 0 else 0.0,
    }
    if isinstance(seq, SimulatedSequence):
        # The truth is relative to the sequence's first sweep: the map's frame when the map
        # was built from the same simulated course.
        truth = seq.ground_truth_at(loc.tracker.config.reference_time)[:total]
        err = np.linalg.norm(np.array(poses)[:, :3, 3] - truth[:, :3, 3], axis=1)
        result["truth_error_m"] = {"mean": float(err.mean()), "max": float(err.max())}
    result["outputs"] = {"poses_tum": str(tum), "quality": str(quality)}
    return result


def _is_2d_bag(args: SimpleNamespace) -> bool:
    """A bag read as 2D laser scans: a 2D option given, or a LaserScan and no PointCloud2."""
    from .scan_source import is_bag

    if str(args.path).startswith("sim:") or not is_bag(args.path):
        return False
    if args.scan_topic is not None or args.odom_topic is not None:
        return True
    from ..io.laserscan_bag import is_laserscan_bag

    return args.topic is None and is_laserscan_bag(args.path)


def _scan_log(args: SimpleNamespace, **options: Any) -> Any:
    """The 2D run of ``args.path`` (CARMEN log or LaserScan bag) as a ScanLog."""
    from .scan_source import open_scan_log

    return open_scan_log(
        args.path,
        scan_topic=args.scan_topic,
        odom_topic=args.odom_topic,
        laser_pose=args.laser_pose,
        **options,
    )


def _bag_settings(args: SimpleNamespace) -> Any:
    """Check ``--bag`` and its frame ids before any work (a bad path fails in a second, not
    after the run)."""
    if args.bag is None:
        return None
    from ..io.rosbag_write import BagFrames, check_bag_destination

    check_bag_destination(args.bag, overwrite=True)
    if getattr(args, "bag_scan_voxel", 0.0) < 0:  # (odometry's option; map has none)
        raise ValueError(f"--bag-scan-voxel must be >= 0, got {args.bag_scan_voxel}")
    return BagFrames(*args.bag_frames)


def _las_options(args: SimpleNamespace) -> dict[str, Any]:
    """The LAS writer's options from ``--las-scale/--las-offset/--crs``."""
    if args.map_format not in ("las", "laz"):
        if args.las_offset is not None or args.crs is not None:
            raise ValueError("--las-offset and --crs need --map-format las or laz")
        if args.map_origin is not None and not np.isfinite(args.map_origin).all():
            raise ValueError(f"--map-origin must be finite, got {args.map_origin}")
        return {}
    crs = args.crs
    if crs is not None and Path(crs).suffix.lower() in (".wkt", ".prj"):
        crs = Path(crs).read_text(encoding="utf-8").strip()
    return {"scale": args.las_scale, "offset": args.las_offset, "crs_wkt": crs}


def _write_bag(args: SimpleNamespace, frames: Any, seq: Any, run: Any) -> dict[str, Any]:
    from .. import preprocess
    from ..deskew import deskew, velocity_from_motion
    from ..io.rosbag_write import write_run_bag

    scans = []
    n = len(run.frames)
    # the sequence is read again (a bag re-reads from its start on random access): the run
    # keeps no points, and a long run's scans would not fit in memory
    for k, frame in enumerate(seq):
        if k >= n:
            break
        pts = frame.points
        # at the pose's time under the estimated motion, so the scan lies on the map in RViz
        j = k if k > 0 else 1  # the first sweep: the motion into the second
        period = float(run.stamps[j] - run.stamps[j - 1]) if j < n else 0.0
        if run.config.deskew and frame.timestamps is not None and period > 0:
            velocity = velocity_from_motion(run.frames[j].motion, period)
            pts = deskew(pts, frame.timestamps, velocity, reference_time=run.config.reference_time)
        if args.bag_scan_voxel > 0:
            pts = preprocess.voxel_downsample(pts, args.bag_scan_voxel).points
        scans.append(pts)
    summary = write_run_bag(
        args.bag,
        run.stamps,
        run.poses,
        covariances=np.array([f.covariance for f in run.frames]),
        scans=scans,
        map_points=run.odometry.map_cloud().points,
        frames=frames,
        overwrite=True,
    )
    return {"path": str(summary.path), "storage": summary.storage, "messages": summary.messages}


def _write_map_bag(path: Path, saved: Any, frames: Any) -> Path:
    """A map (a :class:`~scanreg.SavedMap`, one session or several) as a ROS 2 bag: one
    message set per graph node (its scan's optimized pose, the odometry's, the node's scan or
    cloud), the map (2D occupancy grid, 3D voxelized cloud) and the loop closures. Bag time is
    each session's own, the sessions one after another (1 s apart): a later session's stamps
    may lie before an earlier one's, or days after it."""
    from ..io.rosbag_write import BagGrid, write_run_bag

    nodes = list(saved.node_scans)
    stamps = np.asarray(saved.stamps, dtype=np.float64)[nodes]
    sessions = (
        np.zeros(len(nodes), np.int64) if saved.scan_sessions is None
        else saved.scan_sessions[nodes]
    )  # fmt: skip
    times = np.zeros(len(nodes))
    start = 0.0
    for k in range(len(saved.sessions) or 1):
        mine = sessions == k
        if mine.any():
            times[mine] = start + stamps[mine] - stamps[mine][0]
            start = float(times[mine].max()) + 1.0
    grid = saved.grid
    index = {n: k for k, n in enumerate(sorted(saved.graph.vertices))}
    loops = [
        (index[r["node"]], index[r["submap_node"]], bool(r["accepted"]))
        for r in saved.loops
        if r.get("node") in index and r.get("submap_node") in index
    ]
    odometry = saved.odometry_poses or saved.poses
    summary = write_run_bag(
        path,
        times,
        [saved.poses[s] for s in nodes],
        odometry_poses=[odometry[s] for s in nodes],
        scans=list(saved.node_points),
        map_points=saved.map_points,
        grid=None if grid is None else BagGrid(grid.probability, grid.resolution, grid.origin),
        loops=loops,
        frames=frames,
        overwrite=True,
    )
    return Path(summary.path)


def registration_summary(res: Any) -> dict[str, Any]:
    """The JSON of ``scanreg register`` for a :class:`~scanreg.RegistrationResult` (also what a
    batch register job writes)."""
    return {
        "converged": res.converged,
        "stop_reason": res.stop_reason,
        "iterations": res.iterations,
        "pose": res.pose.as_matrix().tolist(),
        "pose_vector": res.pose.as_vector().tolist(),
        "covariance": res.covariance.tolist(),
        "standard_deviations": np.sqrt(np.diag(res.covariance)).tolist(),
        "fitness": res.fitness,
        "inlier_rmse": res.inlier_rmse,
        "num_correspondences": res.num_correspondences,
        "weakest_direction": res.conditioning.weakest.description,
        "weak_directions": (
            [d.description for d in res.degeneracy.weak_directions]
            if res.degeneracy is not None
            else []
        ),
        "accepted": bool(res.verdict.accepted) if res.verdict is not None else None,
        "reasons": list(res.verdict.reasons) if res.verdict is not None else [],
        "overlap": res.quality.overlap if res.quality is not None else None,
        "time_s": res.timing.total,
    }


__all__ = [
    "SCENES_2D",
    "SCENES_3D",
    "SENSORS_2D",
    "SENSORS_3D",
    "MappingStopped",
    "describe_input",
    "evaluate_trajectories",
    "is_3d_source",
    "plot_trajectory_files",
    "register_files",
    "registration_summary",
    "run_localization_to_folder",
    "run_mapping_to_folder",
    "run_odometry_to_folder",
    "simulate_to_folder",
]
