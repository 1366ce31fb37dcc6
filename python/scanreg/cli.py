"""The ``scanreg`` command line.

Exit codes: 0 success; 1 the command ran but its check failed (e.g. the demo's estimate fell
outside 3σ); 2 bad usage (argparse); 3 unreadable or invalid input (the message names the file
and the problem).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

from ._progress import Progress
from ._version import __version__

EXIT_OK, EXIT_CHECK_FAILED, EXIT_USAGE, EXIT_BAD_INPUT = 0, 1, 2, 3
#: Ctrl-C (the shell's 128 + SIGINT).
EXIT_INTERRUPTED = 130


class MappingStopped(Exception):
    """A mapping run stopped early; its partial outputs were written (the message says where).
    ``interrupted``: stopped by Ctrl-C rather than an error."""

    def __init__(self, message: str, *, interrupted: bool) -> None:
        super().__init__(message)
        self.interrupted = interrupted


EXAMPLES = """examples:
  scanreg demo --seed 3
  scanreg info scan.pcd
  scanreg info poses.txt --trajectory-format kitti --json
  scanreg evaluate estimate.txt groundtruth.txt --format tum --metric ate
  scanreg evaluate est.txt gt.txt --format kitti --metric rpe --delta 10 --unit meters --json
  scanreg register source.ply target.ply --voxel-size 0.25 --method gicp --json
  scanreg info demo.bag                      # ROS 1/2 bag: topics, types, message counts
  scanreg info dataset/sequences/00          # a sequence: frames, points per frame, truth
  scanreg plot trajectory est.txt --reference gt.txt --format kitti --alignment se3 -o traj.png
  scanreg plot errors est.txt gt.txt --format tum --alignment sim3 -o errors.svg
  scanreg simulate --scene street --sensor vlp16 --scans 10 --speed 10 -o run/ --json
  scanreg odometry sim:street -o out/        # LiDAR odometry on a simulated drive, scored
  scanreg odometry dataset/sequences/00 --preset velodyne-hdl64 --config run.toml -o out/
  scanreg odometry sim:street -o out/ --bag out/run.mcap --report   # ROS 2 bag + HTML report
  scanreg report out/ -o out/report.html     # the run's HTML report, one file
  scanreg batch odometry drives.csv -o out/ --retries 2      # many sequences, local workers
  scanreg batch register pairs.parquet --engine ray --address 10.0.0.1:6379 -o out/
  scanreg map intel.clf.bz2 -o out/          # 2D mapping with loop closure (CARMEN log)
"""

#: Per-subcommand examples, shown by ``scanreg SUBCOMMAND --help``.
SUB_EXAMPLES = {
    "demo": "examples:\n  scanreg demo\n  scanreg demo --seed 3\n",
    "info": "examples:\n  scanreg info scan.pcd\n  scanreg info demo.bag --json\n"
    "  scanreg info poses.txt --trajectory-format kitti\n"
    "  scanreg info dataset/sequences/00        # KITTI: frames, points, ground truth\n"
    "  scanreg info sim:street --json          # a simulated sequence\n",
    "evaluate": "examples:\n  scanreg evaluate est.txt gt.txt --format tum --metric ate\n"
    "  scanreg evaluate est.txt gt.txt --format kitti --metric rpe --delta 10 --unit meters\n"
    "  scanreg evaluate est.txt gt.txt --format kitti --metric kitti --json\n",
    "register": "examples:\n  scanreg register source.pcd target.pcd --json\n"
    "  scanreg register src.ply tgt.ply --voxel-size 0.25 --method gicp --kernel huber\n"
    "  scanreg register a.csv b.csv --method point_to_line --init guess.txt\n"
    "  scanreg register scan.pcd map.pcd --global --json   # no initial guess (3D)\n",
    "plot": "examples:\n"
    "  scanreg plot trajectory est.txt --reference gt.txt --format kitti -o traj.png\n"
    "  scanreg plot errors est.txt gt.txt --format tum --alignment sim3 -o errors.svg\n",
    "odometry": "examples:\n"
    "  scanreg odometry sim:street -o out/                 # no download; scored vs truth\n"
    "  scanreg odometry sim:tunnel,frames=50 --method point_to_plane -o out/ --json\n"
    "  scanreg odometry dataset/sequences/00 --preset velodyne-hdl64 -o out/\n"
    "  scanreg odometry drive.bag --topic /points --config run.toml --max-frames 200 -o out/\n"
    "  scanreg odometry sim:street -o out/ --bag out/run.mcap --report   # Foxglove + browser\n"
    "  scanreg odometry scans_laz/ --save-map --map-format laz --map-origin 500123 5000456 "
    "210 --crs utm32.wkt -o out/\n",
    "report": "examples:\n  scanreg report out/                  # out/report.html\n"
    "  scanreg report out/ -o drive07.html --title 'drive 07'\n",
    "batch": "examples:\n"
    "  scanreg batch odometry drives.csv -o out/              # id,input[,config] per row\n"
    "  scanreg batch odometry drives.csv -o out/ --resume     # skip the jobs already done\n"
    "  scanreg batch register pairs.csv -o out/ --config reg.toml --json\n"
    "  scanreg batch odometry drives.parquet --engine ray --address HEAD:6379 -o out/\n",
    "map": "examples:\n"
    "  scanreg map intel.clf.bz2 -o out/                  # CARMEN .clf/.log, .gz or .bz2\n"
    "  scanreg map sim:loop,lap_length=250 -o out/ --json  # 3D: sim:, KITTI, folder, bag\n"
    "  scanreg map aces.clf.bz2 --config map.toml --max-scans 2000 -o out/ --json\n"
    "  scanreg map intel.clf -o out/ --bag out/map.mcap --report   # Foxglove + browser\n",
    "localize": "examples:\n"
    "  scanreg localize intel.clf --map out/ -o loc/        # out/map.yaml from scanreg map\n"
    "  scanreg localize run2.log --map ros_maps/lab.yaml --max-scans 500 --json\n"
    "  scanreg localize run2/velodyne --map out/ -o loc/    # 3D: out/map.ply from scanreg map\n",
    "simulate": "examples:\n"
    "  scanreg simulate -o run/                  # 2D: floor_plan, sick_lms200\n"
    "  scanreg simulate --scene street --sensor vlp16 --scans 10 --speed 10 -o run/\n"
    "  scanreg simulate --scene corridor --sensor laser_360 --format pcd -o run/ --json\n",
}

_SCENES_2D = ("floor_plan", "corridor", "square_room")
_SCENES_3D = ("street", "tunnel", "corridor")
_SENSORS_2D = ("sick_lms200", "laser_360")
_SENSORS_3D = ("vlp16", "hdl32", "hdl64")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="scanreg",
        description="2D/3D LiDAR scan registration with covariance, degeneracy and a verdict.",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"scanreg {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    demo = sub.add_parser("demo", help="run the built-in demo on generated data")
    demo.add_argument("--seed", type=int, default=0, help="random seed (default 0)")

    info = sub.add_parser(
        "info",
        help="summarise a point cloud, trajectory, ROS bag (.bag, .db3, .mcap, folder) or "
        "sequence (KITTI folder, folder of point files, sim:street)",
    )
    info.add_argument("path", type=Path, help="file, folder or sim:NAME")
    info.add_argument(
        "--topic", default=None, help="bag: the PointCloud2 topic to summarise as a sequence"
    )
    info.add_argument(
        "--trajectory-format",
        choices=["kitti", "tum"],
        default=None,
        help="read PATH as a trajectory in this format (default: a point cloud by extension)",
    )
    info.add_argument("--json", action="store_true", help="print JSON instead of text")

    ev = sub.add_parser("evaluate", help="compare an estimated trajectory with a reference")
    ev.add_argument("estimate", type=Path)
    ev.add_argument("reference", type=Path)
    ev.add_argument("--format", choices=["kitti", "tum"], required=True, help="both files' format")
    ev.add_argument("--metric", choices=["ate", "rpe", "kitti"], default="ate")
    ev.add_argument(
        "--alignment", choices=["se3", "sim3", "none"], default="se3", help="ATE alignment"
    )
    ev.add_argument("--delta", type=float, default=1.0, help="RPE pair separation (default 1)")
    ev.add_argument("--unit", choices=["frames", "meters"], default="frames", help="RPE delta unit")
    ev.add_argument("--json", action="store_true", help="print JSON instead of text")

    reg = sub.add_parser(
        "register", help="align SOURCE to TARGET (point clouds); exit 1 if it did not converge"
    )
    reg.add_argument("source", type=Path)
    reg.add_argument("target", type=Path)
    reg.add_argument(
        "--method",
        choices=["point_to_point", "point_to_plane", "point_to_line", "gicp"],
        default="point_to_plane",
    )
    reg.add_argument(
        "--init",
        type=Path,
        default=None,
        help="text file with the initial 4x4 or 3x3 T_target_source",
    )
    reg.add_argument("--max-correspondence-distance", type=float, default=1.0, help="gate (m)")
    reg.add_argument("--voxel-size", type=float, default=None, help="downsample both clouds (m)")
    reg.add_argument("--kernel", default="none", help="robust kernel (huber, cauchy, tukey, ...)")
    reg.add_argument("--max-iterations", type=int, default=30)
    reg.add_argument(
        "--global",
        dest="global_",
        action="store_true",
        help="3D, no initial guess: FPFH + max clique + GNC-TLS, GICP refinement, verdict; "
        "exit 1 if no reliable alignment (--voxel-size sets the keypoint grid)",
    )
    reg.add_argument("--json", action="store_true", help="print JSON instead of text")

    plot = sub.add_parser("plot", help="draw a figure (PNG/SVG by the output's extension)")
    kinds = plot.add_subparsers(dest="plot_kind", required=True)
    traj = kinds.add_parser("trajectory", help="top view of a trajectory (and a reference)")
    traj.add_argument("estimate", type=Path)
    traj.add_argument("--reference", type=Path, default=None)
    errs = kinds.add_parser("errors", help="position/rotation error over distance travelled")
    errs.add_argument("estimate", type=Path)
    errs.add_argument("reference", type=Path)
    for kind in (traj, errs):
        kind.add_argument("--format", choices=["kitti", "tum"], required=True, help="files' format")
        kind.add_argument("--alignment", choices=["none", "se3", "sim3"], default="none")
        kind.add_argument("-o", "--output", type=Path, required=True, help="figure (.png/.svg)")
        kind.add_argument("--json", action="store_true", help="print JSON instead of text")
    traj.add_argument("--plane", choices=["auto", "xy", "xz", "yz"], default="auto")

    sim = sub.add_parser(
        "simulate",
        help="write a simulated run: one point file per scan and the ground-truth poses",
    )
    sim.add_argument("--scene", choices=sorted({*_SCENES_2D, *_SCENES_3D}), default="floor_plan")
    sim.add_argument(
        "--sensor", choices=[*_SENSORS_2D, *_SENSORS_3D], default="sick_lms200", help="preset"
    )
    sim.add_argument("--scans", type=int, default=10, help="number of scans (default 10)")
    sim.add_argument("--speed", type=float, default=1.0, help="forward speed, m/s (default 1)")
    sim.add_argument("--yaw-rate", type=float, default=0.0, help="rad/s (default 0)")
    sim.add_argument("--scan-rate", type=float, default=10.0, help="2D scans per second")
    sim.add_argument("--seed", type=int, default=0, help="scene and noise seed (default 0)")
    sim.add_argument(
        "--format",
        choices=["auto", "pcd", "csv", "ply", "npy", "xyz", "las", "laz"],
        default="auto",
        help="scan file format (auto: pcd for 3D, csv for 2D)",
    )
    sim.add_argument("-o", "--output", type=Path, required=True, help="folder (created)")
    sim.add_argument("--json", action="store_true", help="print JSON instead of text")
    sim.add_argument("--quiet", action="store_true", help="no progress bar on stderr")
    odo = sub.add_parser(
        "odometry",
        help="LiDAR odometry over a sequence (KITTI folder, folder of point files, ROS bag, "
        "sim:street): poses, per-frame quality, effective config, plots",
    )
    odo.add_argument(
        "path",
        help="sequence: folder, bag, sim:street / sim:tunnel[,frames=N], or a 2D CARMEN log "
        "(.clf/.log, optionally .gz/.bz2: Odometry2D with the wheel odometry as prior)",
    )
    odo.add_argument(
        "-o",
        "--output",
        type=Path,
        default=Path("odometry-output"),
        help="folder for the outputs (created; default odometry-output)",
    )
    odo.add_argument("--config", type=Path, default=None, help="TOML config (unknown keys fail)")
    odo.add_argument(
        "--preset",
        action="append",
        default=[],
        help="sensor preset (repeatable; see scanreg.config.PRESETS)",
    )
    odo.add_argument(
        "--method",
        choices=["point_to_point", "point_to_plane", "gicp"],
        default=None,
        help="override the config's method",
    )
    odo.add_argument("--max-frames", type=int, default=None, help="stop after N frames")
    odo.add_argument("--topic", default=None, help="bag: the PointCloud2 topic")
    _add_laser_options(odo)
    odo.add_argument(
        "--save-map",
        action="store_true",
        help="also write the final local map (world frame) as map.ply (see --map-format)",
    )
    odo.add_argument(
        "--map-format",
        choices=["ply", "pcd", "las", "laz"],
        default="ply",
        help="format of the saved map (default ply)",
    )
    _add_las_options(odo)
    _add_bag_options(odo, "odometry, poses, tf, scans, map", sensor="lidar")
    odo.add_argument(
        "--bag-scan-voxel",
        type=float,
        default=0.2,
        help="voxel size of the scans written to the bag (m; 0 keeps every point); the sweeps "
        "are deskewed to their pose's time with the estimated motion, in the sensor frame",
    )
    odo.add_argument(
        "--report",
        action="store_true",
        help="also write report.html (implies --save-map: the report shows the map)",
    )
    odo.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    odo.add_argument("--json", action="store_true", help="print JSON instead of text")
    odo.add_argument("--quiet", action="store_true", help="no progress bar on stderr")
    rep = sub.add_parser(
        "report",
        help="write a run folder's report: one self-contained HTML file (trajectory, σ and "
        "verdicts, timing, 3D map)",
    )
    rep.add_argument("folder", type=Path, help="a run folder (scanreg odometry -o FOLDER)")
    rep.add_argument(
        "-o", "--output", type=Path, default=None, help="HTML file (default FOLDER/report.html)"
    )
    rep.add_argument("--title", default=None, help="page title (default: the sequence name)")
    rep.add_argument("--json", action="store_true", help="print JSON instead of text")
    _add_batch_parser(sub)
    mp = sub.add_parser(
        "map",
        help="mapping with loop closure on a pose graph, 2D (CARMEN log) or 3D (KITTI folder, "
        "folder of point files, ROS bag, sim:loop): optimized poses, graph, loops, map, plot",
    )
    mp.add_argument(
        "path",
        help="2D: CARMEN log (.clf, .log, optionally .gz or .bz2); 3D: KITTI folder, folder of "
        "point files, ROS bag, or sim:loop / sim:loop-repeated[,laps=N,lap_length=M]",
    )
    mp.add_argument(
        "-o", "--output", type=Path, default=Path("map-output"), help="folder (created)"
    )
    mp.add_argument("--config", type=Path, default=None, help="TOML config (unknown keys fail)")
    mp.add_argument("--max-scans", type=int, default=None, help="stop after N scans")
    mp.add_argument("--kind", default=None, help="laser message kind (default FLASER)")
    mp.add_argument("--resolution", type=float, default=0.05, help="2D map cell size (m)")
    mp.add_argument("--voxel-size", type=float, default=0.2, help="3D map voxel (m)")
    mp.add_argument("--topic", default=None, help="3D bag: the PointCloud2 topic")
    _add_laser_options(mp)
    mp.add_argument("--no-plots", action="store_true", help="skip trajectory.png")
    _add_bag_options(
        mp, "the graph nodes' poses and scans, the occupancy grid, loop closures", sensor="laser"
    )
    mp.add_argument("--report", action="store_true", help="also write report.html")
    mp.add_argument(
        "--checkpoint",
        type=int,
        default=None,
        metavar="N",
        help="2D: write the outputs so far every N scans (a partial map; the final run "
        "overwrites it)",
    )
    mp.add_argument("--json", action="store_true", help="print JSON instead of text")
    mp.add_argument("--quiet", action="store_true", help="no progress bar on stderr")
    lz = sub.add_parser(
        "localize",
        help="locate a log's scans in a saved map without changing it (global relocalization "
        "when there is no fix): 2D CARMEN logs, 3D sequences",
    )
    lz.add_argument(
        "path",
        help="2D: CARMEN log (.clf, .log, optionally .gz or .bz2); 3D: KITTI folder, folder "
        "of point files, ROS bag or sim:NAME",
    )
    lz.add_argument(
        "--map",
        type=Path,
        required=True,
        help="2D: map.yaml of a ROS map_server map, or the folder `scanreg map` wrote; 3D: "
        "that folder (map.ply/.pcd, places.npz) or a point file",
    )
    lz.add_argument("--topic", default=None, help="3D bag: the PointCloud2 topic")
    _add_laser_options(lz)
    lz.add_argument("-o", "--output", type=Path, default=Path("localize-output"))
    lz.add_argument("--max-scans", type=int, default=None, help="stop after N scans")
    lz.add_argument("--json", action="store_true", help="print JSON instead of text")
    lz.add_argument("--quiet", action="store_true", help="no progress bar on stderr")
    for name, subparser in sub.choices.items():
        subparser.epilog = SUB_EXAMPLES[name]
        subparser.formatter_class = argparse.RawDescriptionHelpFormatter
    return parser


def _add_laser_options(sub: argparse.ArgumentParser) -> None:
    """A 2D LaserScan bag's topics and the laser's mounting (scanreg.io.laserscan_bag)."""
    sub.add_argument("--scan-topic", default=None, help="2D bag: the LaserScan topic")
    sub.add_argument("--odom-topic", default=None, help="2D bag: the nav_msgs/Odometry topic")
    sub.add_argument(
        "--laser-pose",
        type=float,
        nargs=3,
        metavar=("X", "Y", "THETA"),
        default=None,
        help="2D: the laser's mounting on the base (m, m, rad), instead of the bag's tf",
    )


def _is_2d_bag(args: argparse.Namespace) -> bool:
    """A bag read as 2D laser scans: a 2D option given, or a LaserScan and no PointCloud2."""
    from .pipeline.scan_source import is_bag

    if str(args.path).startswith("sim:") or not is_bag(args.path):
        return False
    if args.scan_topic is not None or args.odom_topic is not None:
        return True
    from .io.laserscan_bag import is_laserscan_bag

    return args.topic is None and is_laserscan_bag(args.path)


def _scan_log(args: argparse.Namespace, **options: Any) -> Any:
    """The 2D run of ``args.path`` (CARMEN log or LaserScan bag) as a ScanLog."""
    from .pipeline.scan_source import open_scan_log

    return open_scan_log(
        args.path,
        scan_topic=args.scan_topic,
        odom_topic=args.odom_topic,
        laser_pose=args.laser_pose,
        **options,
    )


def _add_bag_options(sub: argparse.ArgumentParser, contents: str, *, sensor: str) -> None:
    sub.add_argument(
        "--bag",
        type=Path,
        default=None,
        help=f"also write a ROS 2 bag: out.mcap, out.db3 or a bag folder ({contents})",
    )
    sub.add_argument(
        "--bag-frames",
        nargs=3,
        metavar=("MAP", "ODOM", "SENSOR"),
        default=["map", "odom", sensor],
        help=f"tf frame ids in the bag (default map odom {sensor})",
    )


def _add_las_options(sub: argparse.ArgumentParser) -> None:
    sub.add_argument(
        "--map-origin",
        type=float,
        nargs=3,
        metavar=("X", "Y", "Z"),
        default=None,
        help="saved map: add this translation (m), e.g. the first pose's UTM easting, "
        "northing and height, so the file holds CRS coordinates",
    )
    sub.add_argument(
        "--las-scale",
        type=float,
        default=0.001,
        help="LAS/LAZ map: coordinate resolution in metres (default 0.001)",
    )
    sub.add_argument(
        "--las-offset",
        type=float,
        nargs=3,
        metavar=("X", "Y", "Z"),
        default=None,
        help="LAS/LAZ map: header offset (m; default the map's minimum, whole metres)",
    )
    sub.add_argument(
        "--crs",
        default=None,
        help="LAS/LAZ map: coordinate reference system as OGC WKT, or a .wkt/.prj file",
    )


def _las_options(args: argparse.Namespace) -> dict[str, Any]:
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


def _bag_settings(args: argparse.Namespace) -> Any:
    """Check ``--bag`` and its frame ids before any work (a bad path fails in a second, not
    after the run)."""
    if args.bag is None:
        return None
    from .io.rosbag_write import BagFrames, check_bag_destination

    check_bag_destination(args.bag, overwrite=True)
    if getattr(args, "bag_scan_voxel", 0.0) < 0:  # (odometry's option; map has none)
        raise ValueError(f"--bag-scan-voxel must be >= 0, got {args.bag_scan_voxel}")
    return BagFrames(*args.bag_frames)


def _write_bag(args: argparse.Namespace, frames: Any, seq: Any, run: Any) -> dict[str, Any]:
    from . import preprocess
    from .deskew import deskew, velocity_from_motion
    from .io.rosbag_write import write_run_bag

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


def _add_batch_parser(sub: Any) -> None:
    from .batch.engines import ENGINES
    from .batch.jobs import JOB_KINDS

    batch = sub.add_parser(
        "batch",
        help="run many odometry or registration jobs (a CSV/Parquet manifest) on local worker "
        "processes or a Ray cluster; exit 1 if any job failed",
    )
    batch.add_argument("kind", choices=list(JOB_KINDS), help="job kind")
    batch.add_argument(
        "manifest",
        type=Path,
        help="CSV/TSV/Parquet, one row per job: id and input (odometry: a sequence or sim: URI) "
        "or source,target (register); optional config (TOML), init (register)",
    )
    batch.add_argument("--engine", choices=list(ENGINES), default="local")
    batch.add_argument("--address", default=None, help="ray: a running cluster's HOST:PORT")
    batch.add_argument("-o", "--output", type=Path, required=True, help="folder (created)")
    batch.add_argument(
        "--retries", type=int, default=2, help="runs again of a job whose worker died (default 2)"
    )
    batch.add_argument("--resume", action="store_true", help="skip the jobs already done")
    batch.add_argument("--config", type=Path, default=None, help="TOML for rows without one")
    batch.add_argument(
        "--workers", type=int, default=None, help="local worker processes (default: one per CPU)"
    )
    batch.add_argument("--threads-per-job", type=int, default=None, help="threads each job may use")
    batch.add_argument("--json", action="store_true", help="print JSON instead of text")
    batch.add_argument("--quiet", action="store_true", help="no progress bar on stderr")


def _batch(args: argparse.Namespace) -> dict[str, Any]:
    from .batch import run_batch

    if args.retries < 0:
        raise ValueError(f"--retries must be >= 0, got {args.retries}")
    for flag in ("workers", "threads_per_job"):
        value = getattr(args, flag)
        if value is not None and value < 1:
            raise ValueError(f"--{flag.replace('_', '-')} must be >= 1, got {value}")
    report = run_batch(
        args.kind,
        args.manifest,
        args.output,
        engine=args.engine,
        address=args.address,
        workers=args.workers,
        threads_per_job=args.threads_per_job,
        retries=args.retries,
        resume=args.resume,
        config=args.config,
        progress=not (args.quiet or args.json),
    )
    return report.as_dict()


def _stats(stats: Any) -> dict[str, float]:
    keys = ("rmse", "mean", "median", "std", "min", "max", "sse")
    return {k: float(getattr(stats, k)) for k in keys}


_BAG_SUFFIXES = {".bag": "ros1", ".db3": "ros2-sqlite3", ".mcap": "ros2-mcap"}


def _bag_info(path: Path, topic: str | None) -> dict[str, Any]:
    from .io import rosbag, sequences

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


def _info(args: argparse.Namespace) -> dict[str, Any]:
    from . import io
    from .io import sequences

    if not args.trajectory_format:
        spec = str(args.path)
        if spec.startswith("sim:"):
            return sequences.describe_sequence(sequences.open_sequence(spec))
        if args.path.suffix.lower() in _BAG_SUFFIXES or (args.path / "metadata.yaml").is_file():
            return _bag_info(args.path, args.topic)
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


def _las_info(path: Path) -> dict[str, Any]:
    """A LAS/LAZ file's header facts (scale, offset, CRS); nothing for other formats."""
    if path.suffix.lower() not in (".las", ".laz"):
        return {}
    from .io import read_las_header

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


def _evaluate(args: argparse.Namespace) -> dict[str, Any]:
    from . import eval as ev
    from . import io

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


def _register_global(args: argparse.Namespace) -> dict[str, Any]:
    from . import io
    from .global_registration import register_global

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


def _register(args: argparse.Namespace) -> dict[str, Any]:
    from . import io, preprocess
    from .register import register

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
    return register_summary(res)


def register_summary(res: Any) -> dict[str, Any]:
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


def _plot(args: argparse.Namespace) -> dict[str, Any]:
    from . import io, plot

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


def _simulate(args: argparse.Namespace) -> dict[str, Any]:
    from . import io
    from . import simulate as sim
    from .transform import SE2, SE3

    dim = 3 if args.sensor in _SENSORS_3D else 2
    scenes = _SCENES_3D if dim == 3 else _SCENES_2D
    if args.scene not in scenes:
        raise ValueError(
            f"--scene {args.scene} is not available for the {dim}D sensor {args.sensor} "
            f"(choose from {', '.join(scenes)})"
        )
    if args.scans < 1:
        raise ValueError(f"--scans must be >= 1, got {args.scans}")
    if not args.scan_rate > 0:
        raise ValueError(f"--scan-rate must be > 0, got {args.scan_rate}")
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


def _carmen_key(path: str) -> str | None:
    """The :data:`scanreg.io.SCAN_SOURCES` key of a CARMEN log path, or ``None``."""
    from .io import SCAN_SOURCES

    p = Path(path)
    suffixes = [s.lower() for s in p.suffixes]
    key = "".join(suffixes[-2:]) if suffixes[-1:] in ([".gz"], [".bz2"]) else p.suffix.lower()
    return key if key in SCAN_SOURCES else None


def _odometry_carmen(args: argparse.Namespace) -> dict[str, Any]:
    """``scanreg odometry LOG.clf``: 2D scan-to-map odometry (:class:`Odometry2D`) over a CARMEN
    log in file order, the wheel odometry as each scan's prior. ``--config`` is an
    :class:`OdometryConfig2D` TOML over the mapping pipeline's odometry defaults."""
    import time

    from .config import load_config, write_config
    from .io import Trajectory, write_kitti_poses, write_tum
    from .pipeline.mapping import MappingConfig
    from .pipeline.odometry2d import Odometry2D, OdometryConfig2D

    for flag in ("preset", "method", "topic", "bag", "save_map", "report"):
        value = getattr(args, flag, None)
        if value:
            raise ValueError(f"--{flag.replace('_', '-')}: not available for a 2D laser log")
    if args.max_frames is not None and args.max_frames < 1:
        raise ValueError(f"--max-frames must be >= 1, got {args.max_frames}")
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
    t0 = time.perf_counter()
    enabled = not (args.quiet or args.json)
    with Progress(len(scans), description="odometry", unit="scans", enabled=enabled) as bar:
        for i in range(len(scans)):
            step = scans.prior(i)
            if step is not None:
                pending = step if pending is None else pending @ step
            pts = scans.points(i, 0.1, 40.0)
            if len(pts) < 3:  # no returns: nothing to align; its motion joins the next prior
                skipped += 1
                bar.update()
                continue
            frame = odo.step(pts, prior=pending if poses else None)
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


def _odometry(args: argparse.Namespace) -> dict[str, Any]:
    from .config import load_config
    from .io import open_sequence, write_poses, write_run_outputs
    from .io.sequences import KittiSequence, SimulatedSequence
    from .pipeline.odometry import OdometryConfig
    from .pipeline.run import evaluate_run, run_odometry

    if not str(args.path).startswith("sim:") and (
        _carmen_key(args.path) is not None or _is_2d_bag(args)
    ):
        return _odometry_carmen(args)  # a 2D laser log or LaserScan bag
    if args.max_frames is not None and args.max_frames < 1:
        raise ValueError(f"--max-frames must be >= 1, got {args.max_frames}")
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
        from . import plot
        from .io import Trajectory

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
            from .io import PointCloud, write_points

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
        from .report import write_report

        written["report"] = str(write_report(args.output))
    return result


def _report(args: argparse.Namespace) -> dict[str, Any]:
    from .report import write_report

    out = write_report(args.folder, args.output, title=args.title)
    return {"report": str(out), "bytes": out.stat().st_size}


def _map(args: argparse.Namespace) -> dict[str, Any]:
    from .config import load_config, write_config
    from .graph import require_gtsam

    require_gtsam()  # fail before reading a large log
    from .pipeline.map_check import check_map
    from .pipeline.mapping import MappingConfig, MappingInterrupted, run_mapping
    from .pipeline.mapping_output import summary, write_outputs

    if args.max_scans is not None and args.max_scans < 1:
        raise ValueError(f"--max-scans must be >= 1, got {args.max_scans}")
    if not args.resolution > 0:
        raise ValueError(f"--resolution must be > 0, got {args.resolution}")
    if _is_3d_source(args.path) and not _is_2d_bag(args):
        return _map_3d(args)
    config = load_config(MappingConfig, args.config)
    if args.bag is not None:
        args.output.mkdir(parents=True, exist_ok=True)  # a --bag inside it can be checked now
    frames = _bag_settings(args)  # a bad bag path fails now, not after the run
    if args.checkpoint is not None and args.checkpoint < 1:
        raise ValueError(f"--checkpoint must be >= 1 scans, got {args.checkpoint}")
    scans = _scan_log(
        args,
        kind=args.kind,
        max_scans=args.max_scans,
        latency=config.laser_latency,
        min_range=config.min_range,
        max_range=config.max_range,
    )

    def checkpoint(partial: Any) -> None:
        write_outputs(args.output, partial, resolution=args.resolution, plot=False)

    try:
        res = run_mapping(
            scans,
            config,
            progress=not (args.quiet or args.json),
            checkpoint=None if args.checkpoint is None else checkpoint,
            checkpoint_every=args.checkpoint or 1000,
        )
    except MappingInterrupted as exc:
        # Never lose work: what was mapped before the stop is written, and the run fails.
        write_outputs(args.output, exc.partial, resolution=args.resolution, plot=False)
        raise MappingStopped(
            f"{exc}; what was mapped so far is written to {args.output}/ "
            f"({len(exc.partial.poses)} scans, {len(exc.partial.node_scans)} nodes)",
            interrupted=isinstance(exc.__cause__, KeyboardInterrupt),
        ) from exc
    check = check_map(res)
    if not check.consistent:  # a broken map must not pass silently, --json or not
        for reason in check.reasons:
            print(f"scanreg map: WARNING: the map is inconsistent: {reason}", file=sys.stderr)
    paths = write_outputs(
        args.output, res, resolution=args.resolution, plot=not args.no_plots, check=check
    )
    paths["config"] = write_config(args.output / "config.toml", config)
    if args.bag is not None:
        paths["bag"] = _write_map_bag(args.bag, res, args.resolution, frames)
    if args.report:
        from .report import write_report

        paths["report"] = write_report(args.output)
    result = summary(res, check)
    result["log"] = str(args.path)
    result["scans"] = scans.describe()
    result["outputs"] = {k: str(v) for k, v in paths.items()}
    return result


def _is_3d_source(path: str) -> bool:
    """3D mapping for ``sim:`` drives, folders (KITTI, point files, ROS 2 bags) and bag files;
    2D for anything else (a CARMEN log)."""
    from .io.sequences import BAG_SUFFIXES

    p = Path(path)
    return path.startswith("sim:") or p.is_dir() or p.suffix.lower() in BAG_SUFFIXES


def _map_3d(args: argparse.Namespace) -> dict[str, Any]:
    """``scanreg map`` on a 3D sequence: Mapper3D, its outputs, and (simulated drives) the
    accuracy before and after loop closure against the exact truth."""
    from .config import load_config, write_config
    from .io import open_sequence, write_poses
    from .io.sequences import SimulatedSequence
    from .pipeline.mapping3d import MappingConfig3D, run_mapping_3d
    from .pipeline.mapping_output import summary, write_outputs

    if args.bag is not None or args.report:
        raise ValueError("--bag, --report: not available for 3D mapping runs yet")
    if not args.voxel_size >= 0:
        raise ValueError(f"--voxel-size must be >= 0, got {args.voxel_size}")
    config = load_config(MappingConfig3D, args.config)
    seq = open_sequence(args.path, topic=args.topic)
    res = run_mapping_3d(
        seq, config, max_scans=args.max_scans, progress=not (args.quiet or args.json)
    )
    paths = write_outputs(args.output, res, voxel_size=args.voxel_size, plot=not args.no_plots)
    paths["config"] = write_config(args.output / "config.toml", config)
    result = summary(res)
    result["sequence"] = getattr(seq, "name", str(args.path))
    if isinstance(seq, SimulatedSequence):
        from .eval import absolute_trajectory_error
        from .io import Trajectory

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
    result["outputs"] = {k: str(v) for k, v in paths.items()}
    return result


def _localize(args: argparse.Namespace) -> dict[str, Any]:
    import json
    import time

    from ._progress import Progress
    from .io import Trajectory, write_tum
    from .pipeline.localizer2d import Localizer2D

    if args.max_scans is not None and args.max_scans < 1:
        raise ValueError(f"--max-scans must be >= 1, got {args.max_scans}")
    if _is_3d_source(args.path) and not _is_2d_bag(args):
        return _localize_3d(args)
    map_yaml = args.map / "map.yaml" if args.map.is_dir() else args.map
    loc = Localizer2D.from_map_server(map_yaml)
    # The scans in the base frame and the wheel odometry at each one's time, as mapped.
    scans = _scan_log(args, max_scans=args.max_scans)
    args.output.mkdir(parents=True, exist_ok=True)
    rows, poses, stamps = [], [], []
    t0 = time.perf_counter()
    enabled = not (args.quiet or args.json)
    with Progress(len(scans), description="localize", unit="scans", enabled=enabled) as bar:
        for i in range(len(scans)):
            pts = scans.points(i, 0.1, 40.0)
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
        "map": str(map_yaml),
        "num_scans": len(rows),
        "accepted": accepted,
        "rejected": len(rows) - accepted,
        "global_fixes": sum(r["prediction_source"] == "global" and r["accepted"] for r in rows),
        "scans_per_second": len(rows) / seconds if seconds > 0 else 0.0,
        "outputs": {"poses_tum": str(tum), "quality": str(quality)},
    }


def _localize_3d(args: argparse.Namespace) -> dict[str, Any]:
    """``scanreg localize`` on a 3D sequence: MapLocalizer in the saved map, from no pose."""
    import json
    import time

    from ._progress import Progress
    from .io import open_sequence, write_poses
    from .io.sequences import SimulatedSequence
    from .pipeline.map_localizer import MapLocalizer
    from .pipeline.run import quality_row

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


def _write_map_bag(path: Path, res: Any, resolution: float, frames: Any) -> Path:
    """The mapping run as a ROS 2 bag: one message set per graph node (its scan's optimized
    pose, the odometry's, the node scan), the occupancy grid and the loop closures."""
    from .io.occupancy import occupancy_grid
    from .io.rosbag_write import BagGrid, write_run_bag

    nodes = list(res.node_scans)
    index = {scan: k for k, scan in enumerate(nodes)}
    stamps = [res.stamps[s] for s in nodes]
    if any(t is None for t in stamps):
        stamps = [0.1 * k for k in range(len(nodes))]  # a log without times: 10 Hz
    t0 = float(stamps[0])
    grid_poses = res.graph.poses()
    grid = occupancy_grid(
        [grid_poses[n] for n in range(len(nodes))], list(res.node_points), resolution=resolution
    )
    loops = [
        (index[r.scan], index[r.submap_scan], r.accepted)
        for r in res.loops
        if r.scan in index and r.submap_scan in index
    ]
    summary = write_run_bag(
        path,
        [float(t) - t0 for t in stamps],
        [res.poses[s] for s in nodes],
        odometry_poses=[res.odometry_poses[s] for s in nodes],
        scans=list(res.node_points),
        grid=BagGrid(grid.probability, grid.resolution, grid.origin),
        loops=loops,
        frames=frames,
        overwrite=True,
    )
    return Path(summary.path)


def _print_text(result: dict[str, Any], indent: str = "") -> None:
    for key, value in result.items():
        if isinstance(value, dict):
            print(f"{indent}{key}:")
            _print_text(value, indent + "  ")
        elif isinstance(value, float):
            print(f"{indent}{key}: {value:.6g}")
        else:
            print(f"{indent}{key}: {value}")


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.command == "demo":
        from .demo import run_demo

        return run_demo(args.seed)
    handlers = {
        "info": _info,
        "evaluate": _evaluate,
        "register": _register,
        "plot": _plot,
        "simulate": _simulate,
        "odometry": _odometry,
        "report": _report,
        "batch": _batch,
        "map": _map,
        "localize": _localize,
    }
    try:
        result = handlers[args.command](args)
    except MappingStopped as exc:
        print(f"scanreg {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_INTERRUPTED if exc.interrupted else EXIT_CHECK_FAILED
    except (ValueError, OSError, ImportError) as exc:  # FileFormatError is a ValueError
        print(f"scanreg {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        _print_text(result)
    if result.get("converged") is False or (args.command == "batch" and result["failed"]):
        return EXIT_CHECK_FAILED
    return EXIT_OK


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
