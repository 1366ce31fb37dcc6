"""The ``scanreg`` command line.

Exit codes: 0 success; 1 the command ran but its check failed (e.g. the demo's estimate fell
outside 3σ); 2 bad usage (argparse); 3 unreadable or invalid input (the message names the file
and the problem).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from ._version import __version__

EXIT_OK, EXIT_CHECK_FAILED, EXIT_USAGE, EXIT_BAD_INPUT = 0, 1, 2, 3
#: Ctrl-C (the shell's 128 + SIGINT).
EXIT_INTERRUPTED = 130


def __getattr__(name: str) -> Any:
    # Names that moved into the library (scanreg.pipeline.commands), still found here.
    moved = {"MappingStopped": "MappingStopped", "register_summary": "registration_summary"}
    if name in moved:
        from .pipeline import commands

        return getattr(commands, moved[name])
    raise AttributeError(f"module 'scanreg.cli' has no attribute {name!r}")


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
  scanreg batch map logs.csv -o maps/        # one map per row (2D logs/bags, 3D sequences)
  scanreg map intel.clf.bz2 -o out/          # 2D mapping with loop closure (CARMEN log)
  scanreg merge mapA/ mapB/ -o merged/       # two saved maps (2D or 3D), unrelated frames
"""

#: Per-subcommand examples, shown by ``scanreg SUBCOMMAND --help``.
SUB_EXAMPLES = {
    "demo": "examples:\n  scanreg demo\n  scanreg demo --seed 3 -o /tmp/demo\n",
    "info": "examples:\n  scanreg info scan.pcd\n  scanreg info demo.bag --json\n"
    "  scanreg info poses.txt --trajectory-format kitti\n"
    "  scanreg info dataset/sequences/00        # KITTI: frames, points, ground truth\n"
    "  scanreg info sim:street --json          # a simulated sequence\n"
    "  scanreg info out/                       # a map folder: version, sensor, sessions\n",
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
    "  scanreg batch map logs.csv -o maps/                  # one map folder per row\n"
    "  scanreg batch odometry drives.parquet --engine ray --address HEAD:6379 -o out/\n",
    "map": "examples:\n"
    "  scanreg map intel.clf.bz2 -o out/                  # CARMEN .clf/.log, .gz or .bz2\n"
    "  scanreg map sim:loop,lap_length=250 -o out/ --json  # 3D: sim:, KITTI, folder, bag\n"
    "  scanreg map aces.clf.bz2 --config map.toml --max-scans 2000 -o out/ --json\n"
    "  scanreg map intel.clf -o out/ --bag out/map.mcap --report   # Foxglove + browser\n"
    "  scanreg map run2.clf --extend out/ -o out2/        # a second session into the map\n",
    "localize": "examples:\n"
    "  scanreg localize intel.clf --map out/ -o loc/        # out/map.yaml from scanreg map\n"
    "  scanreg localize run2.log --map ros_maps/lab.yaml --max-scans 500 --json\n"
    "  scanreg localize run2/velodyne --map out/ -o loc/    # 3D: out/map.ply from scanreg map\n",
    "merge": "examples:\n"
    "  scanreg merge day1/ day2/ -o both/       # two maps of `scanreg map`, in day1's frame\n"
    "  scanreg merge day1/ day2/ -o day1/ --json  # day1/ becomes the merged map\n",
    "simulate": "examples:\n"
    "  scanreg simulate -o run/                  # 2D: floor_plan, sick_lms200\n"
    "  scanreg simulate --scene street --sensor vlp16 --scans 10 --speed 10 -o run/\n"
    "  scanreg simulate --scene corridor --sensor laser_360 --format pcd -o run/ --json\n",
}


def build_parser() -> argparse.ArgumentParser:
    from .pipeline.commands import SCENES_2D, SCENES_3D, SENSORS_2D, SENSORS_3D

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
    demo.add_argument(
        "-o",
        "--output",
        type=Path,
        default=Path("scanreg-demo"),
        help="folder for the maps and report.html (default ./scanreg-demo)",
    )

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
    sim.add_argument("--scene", choices=sorted({*SCENES_2D, *SCENES_3D}), default="floor_plan")
    sim.add_argument(
        "--sensor", choices=[*SENSORS_2D, *SENSORS_3D], default="sick_lms200", help="preset"
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
        help="2D: CARMEN log (.clf, .log, optionally .gz or .bz2) or ROS bag of LaserScans; "
        "3D: KITTI folder, folder of point files, ROS bag of PointCloud2, or sim:loop / "
        "sim:loop-repeated[,laps=N,lap_length=M]",
    )
    mp.add_argument(
        "-o",
        "--output",
        type=Path,
        default=None,
        help="folder (created; default map-output, or with --extend the extended folder)",
    )
    mp.add_argument(
        "--extend",
        type=Path,
        default=None,
        metavar="MAP",
        help="a folder `scanreg map` wrote (2D or 3D, as this run; the run a log or bag): map "
        "this run, locate it there from no pose, close loops against it and write one map of "
        "both sessions (to -o, default MAP)",
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
        mp,
        "the graph nodes' poses and scans or clouds, the occupancy grid or map cloud, loop "
        "closures; with --extend every session's, one after another",
        sensor="laser",
    )
    mp.add_argument(
        "--report",
        action="store_true",
        help="also write report.html (with --extend: the joint map's, each session drawn)",
    )
    mp.add_argument(
        "--checkpoint",
        type=int,
        default=None,
        metavar="N",
        help="write the outputs so far every N scans (a partial map; the final run "
        "overwrites it). With --extend (2D only): the new run's map alone, in its own frame, "
        "to OUT/new_run_checkpoint/ (also on a stop; removed once the joint map is written)",
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
    mg = sub.add_parser(
        "merge",
        help="merge two saved maps made separately (both 2D or both 3D, unrelated frames) into "
        "one graph: inter-session loops by global search (2D) or place recognition and global "
        "registration (3D), verified and mutually consistent",
    )
    mg.add_argument("a", type=Path, help="the first map's folder (its frame is kept)")
    mg.add_argument("b", type=Path, help="the second map's folder")
    mg.add_argument(
        "-o", "--output", type=Path, required=True, help="the merged map's folder (may be A)"
    )
    mg.add_argument("--config", type=Path, default=None, help="TOML (default: A's config.toml)")
    mg.add_argument(
        "--locate-tries",
        type=int,
        default=20,
        help="2D: B's nodes, spread over its run, the global search tries (default 20; 3D "
        "looks every node up by place recognition)",
    )
    mg.add_argument(
        "--min-loops",
        type=int,
        default=2,
        help="agreeing inter-session loops needed to merge (default 2)",
    )
    mg.add_argument("--json", action="store_true", help="print JSON instead of text")
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


def _add_batch_parser(sub: Any) -> None:
    from .batch.engines import ENGINES
    from .batch.jobs import JOB_KINDS

    batch = sub.add_parser(
        "batch",
        help="run many odometry, registration or mapping jobs (a CSV/Parquet manifest) on local "
        "worker processes or a Ray cluster; exit 1 if any job failed",
    )
    batch.add_argument("kind", choices=list(JOB_KINDS), help="job kind")
    batch.add_argument(
        "manifest",
        type=Path,
        help="CSV/TSV/Parquet, one row per job: id and input (odometry, map: a sequence, log, "
        "bag or sim: URI) or source,target (register); optional config (TOML), init (register)",
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


def _info(args: argparse.Namespace) -> dict[str, Any]:
    from .pipeline.commands import describe_input

    return describe_input(args.path, topic=args.topic, trajectory_format=args.trajectory_format)


def _evaluate(args: argparse.Namespace) -> dict[str, Any]:
    from .pipeline.commands import evaluate_trajectories

    return evaluate_trajectories(
        args.estimate,
        args.reference,
        format=args.format,
        metric=args.metric,
        alignment=args.alignment,
        delta=args.delta,
        unit=args.unit,
    )


def _register(args: argparse.Namespace) -> dict[str, Any]:
    from .pipeline.commands import register_files

    return register_files(
        args.source,
        args.target,
        method=args.method,
        init=args.init,
        max_correspondence_distance=args.max_correspondence_distance,
        voxel_size=args.voxel_size,
        kernel=args.kernel,
        max_iterations=args.max_iterations,
        global_search=args.global_,
    )


def _plot(args: argparse.Namespace) -> dict[str, Any]:
    from .pipeline.commands import plot_trajectory_files

    return plot_trajectory_files(
        args.plot_kind,
        args.estimate,
        args.output,
        format=args.format,
        reference=args.reference,
        alignment=args.alignment,
        plane=getattr(args, "plane", "auto"),
    )


def _simulate(args: argparse.Namespace) -> dict[str, Any]:
    from .pipeline.commands import simulate_to_folder

    return simulate_to_folder(
        args.output,
        scene=args.scene,
        sensor=args.sensor,
        scans=args.scans,
        speed=args.speed,
        yaw_rate=args.yaw_rate,
        scan_rate=args.scan_rate,
        seed=args.seed,
        format=args.format,
        progress=not (args.quiet or args.json),
    )


def _report(args: argparse.Namespace) -> dict[str, Any]:
    from .report import write_report

    out = write_report(args.folder, args.output, title=args.title)
    return {"report": str(out), "bytes": out.stat().st_size}


def _odometry(args: argparse.Namespace) -> dict[str, Any]:
    from .pipeline.commands import run_odometry_to_folder

    return run_odometry_to_folder(
        args.path,
        args.output,
        config=args.config,
        presets=args.preset,
        method=args.method,
        max_frames=args.max_frames,
        topic=args.topic,
        scan_topic=args.scan_topic,
        odom_topic=args.odom_topic,
        laser_pose=args.laser_pose,
        save_map=args.save_map,
        map_format=args.map_format,
        map_origin=args.map_origin,
        las_scale=args.las_scale,
        las_offset=args.las_offset,
        crs=args.crs,
        bag=args.bag,
        bag_frames=args.bag_frames,
        bag_scan_voxel=args.bag_scan_voxel,
        report=args.report,
        plots=not args.no_plots,
        progress=not (args.quiet or args.json),
    )


def _map(args: argparse.Namespace) -> dict[str, Any]:
    from .pipeline.commands import run_mapping_to_folder

    output = args.output or args.extend or Path("map-output")
    result = run_mapping_to_folder(
        args.path,
        output,
        config=args.config,
        max_scans=args.max_scans,
        kind=args.kind,
        resolution=args.resolution,
        voxel_size=args.voxel_size,
        topic=args.topic,
        scan_topic=args.scan_topic,
        odom_topic=args.odom_topic,
        laser_pose=args.laser_pose,
        bag=args.bag,
        bag_frames=args.bag_frames,
        report=args.report,
        checkpoint=args.checkpoint,
        extend=args.extend,
        plots=not args.no_plots,
        progress=not (args.quiet or args.json),
    )
    _warn_inconsistent("map", result)
    return result


def _warn_inconsistent(command: str, result: dict[str, Any]) -> None:
    """The map's self-check on stderr when it failed: never silent, ``--json`` or not."""
    check = result.get("self_check")
    if check is not None and not check["consistent"]:
        from .pipeline.map_check import describe_region

        for reason in check["reasons"]:
            print(f"scanreg {command}: WARNING: the map is inconsistent: {reason}", file=sys.stderr)
        for region in check.get("regions", [])[:3]:
            print(f"scanreg {command}: contradicted: {describe_region(region)}", file=sys.stderr)


def _localize(args: argparse.Namespace) -> dict[str, Any]:
    from .pipeline.commands import run_localization_to_folder

    return run_localization_to_folder(
        args.path,
        args.map,
        args.output,
        topic=args.topic,
        scan_topic=args.scan_topic,
        odom_topic=args.odom_topic,
        laser_pose=args.laser_pose,
        max_scans=args.max_scans,
        progress=not (args.quiet or args.json),
    )


def _merge(args: argparse.Namespace) -> dict[str, Any]:
    from .pipeline.commands import merge_maps_to_folder

    result = merge_maps_to_folder(
        args.a,
        args.b,
        args.output,
        config=args.config,
        locate_tries=args.locate_tries,
        min_loops=args.min_loops,
    )
    _warn_inconsistent("merge", result)
    return result


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

        return run_demo(args.seed, args.output)
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
        "merge": _merge,
    }
    try:
        result = handlers[args.command](args)
    except (ValueError, OSError, ImportError) as exc:  # FileFormatError is a ValueError
        print(f"scanreg {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except Exception as exc:
        # (imported here: the pipeline is not loaded for commands that do not need it)
        from .pipeline.commands import MappingStopped

        if not isinstance(exc, MappingStopped):
            raise
        print(f"scanreg {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_INTERRUPTED if exc.interrupted else EXIT_CHECK_FAILED
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        _print_text(result)
    if result.get("converged") is False or (args.command == "batch" and result["failed"]):
        return EXIT_CHECK_FAILED
    return EXIT_OK


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
