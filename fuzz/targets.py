"""Fuzz targets: one per reader, each a function of the raw file bytes.

A target writes the bytes to a file with the reader's extension and reads it back. A reader may
refuse a file only with a named error (``ValueError`` and its subclasses, which include
``FileFormatError`` and ``ConfigError``, or ``TypeError``); anything else — another exception,
a numpy warning such as "invalid value encountered in cast" (turned into an error here), a
crash or a hang — is a finding. Seeds are made at run time from the real data folder
(``../shared/data`` or ``$SCANREG_DATA``) and from our own writers: no data is committed.
"""

from __future__ import annotations

import bz2
import contextlib
import functools
import gzip
import hashlib
import os
import sys
import tempfile
import traceback
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

DATA = Path(os.environ.get("SCANREG_DATA", Path(__file__).resolve().parents[2] / "shared/data"))
#: Seeds are cut to this many bytes: mutations of a small file explore the parser, not the data.
SEED_BYTES = 16384
#: Refusals that name the problem (FileFormatError and ConfigError are ValueErrors).
NAMED = (ValueError, TypeError)
LASER_SCAN = "sensor_msgs/msg/LaserScan"
POINT_CLOUD2 = "sensor_msgs/msg/PointCloud2"


@dataclass(frozen=True)
class Target:
    name: str
    suffix: str
    read: Callable[[Path], object]
    seeds: Callable[[], list[bytes]]


def _head(path: Path, n: int = SEED_BYTES) -> bytes:
    with open(path, "rb") as f:
        return f.read(n)


def _text_head(path: Path, lines: int) -> bytes:
    opener = {".gz": gzip.open, ".bz2": bz2.open}.get(path.suffix, open)
    with opener(path, "rb") as f:
        return b"".join(f.readline() for _ in range(lines))


def _cloud() -> object:
    from scanreg.io import PointCloud

    rng = np.random.default_rng(0)
    pts = rng.normal(size=(20, 3))
    return PointCloud(points=pts, intensity=rng.uniform(size=20), ring=np.arange(20) % 4)


def _written(write: Callable[..., None], suffix: str, **options: object) -> bytes:
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / f"seed{suffix}"
        write(p, _cloud(), **options)
        return p.read_bytes()


def _pcd_seeds() -> list[bytes]:
    from scanreg.io import write_pcd

    out = [_written(write_pcd, ".pcd", data=m) for m in ("ascii", "binary", "binary_compressed")]
    out.append(_written(write_pcd, ".pcd", data="binary_compressed", precision="float64"))
    for p in sorted((DATA / "kitti-odometry-00-frames-000-015/original_pcd").glob("*.pcd"))[:1]:
        out.append(_head(p))
    return out


def _ply_seeds() -> list[bytes]:
    from scanreg.io import write_ply

    modes = ("ascii", "binary_little_endian", "binary_big_endian")
    out = [_written(write_ply, ".ply", data=m) for m in modes]
    for p in sorted((DATA / "gicp-outdoor-scan-pair").rglob("*.ply"))[:1]:
        out.append(_head(p))
    return out


def _kitti_bin_seeds() -> list[bytes]:
    return [_head(DATA / "kitti-odometry-00-frames-000-015/velodyne/000000.bin", 4096)]


def _calib_seeds() -> list[bytes]:
    return [_head(DATA / "kitti-odometry-00-frames-000-015/calib.txt")]


def _kitti_poses_seeds() -> list[bytes]:
    return [_text_head(DATA / "kitti-odometry-00-frames-000-015/poses.txt", 20)]


def _tum_seeds() -> list[bytes]:
    return [_text_head(DATA / "trajectories-evo-testdata/fr2_desk_groundtruth.txt", 20)]


def _carmen_seeds() -> list[bytes]:
    return [_text_head(DATA / "carmen-intel/intel.gfs.log", 12)]


def _carmen_gz_seeds() -> list[bytes]:
    return [gzip.compress(s, mtime=0) for s in _carmen_seeds()]


def _carmen_bz2_seeds() -> list[bytes]:
    return [bz2.compress(_text_head(DATA / "freiburg-slam-benchmark/intel.clf.bz2", 12))]


def _g2o_seeds() -> list[bytes]:
    from scanreg import SE2, SE3
    from scanreg.io import PoseGraph, PoseGraphEdge, write_g2o

    out = []
    for cls, dof in ((SE2, 3), (SE3, 6)):
        a, b = cls.identity(), cls.exp(np.full(dof, 0.1))  # type: ignore[attr-defined]
        graph = PoseGraph(
            vertices={0: a, 1: b},
            edges=[PoseGraphEdge(0, 1, b, np.eye(dof))],
        )
        with tempfile.TemporaryDirectory() as d:
            p = Path(d) / "g.g2o"
            write_g2o(p, graph)
            out.append(p.read_bytes())
    return out


def _scan_messages(ros1: bool) -> list[tuple[int, Any]]:
    """``(bag time ns, message)`` of three LaserScans of the real ROS 1 bag, as objects of
    the ROS 1 (``ros1``) or the ROS 2 type store."""
    from rosbags.typesys import Stores, get_typestore
    from scanreg.io import read_bag_scans

    scans = read_bag_scans(DATA / "rosbag1-laserscan-ccny-demo/demo.bag")[:3]
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.LATEST)
    msgs = []
    for i, scan in enumerate(scans):
        ns = 1_000_000_000 + i * 100_000_000
        stamp = ts.types["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
        header = ts.types["std_msgs/msg/Header"](
            stamp=stamp, frame_id="laser", **({"seq": i} if ros1 else {})
        )
        msgs.append(
            (
                ns,
                ts.types[LASER_SCAN](
                    header=header,
                    angle_min=float(scan.angles[0]),
                    angle_max=float(scan.angles[-1]),
                    angle_increment=float(scan.angles[1] - scan.angles[0]),
                    time_increment=1e-4,
                    scan_time=0.1,
                    range_min=float(scan.range_min),
                    range_max=float(scan.max_range),
                    ranges=np.asarray(scan.ranges, dtype=np.float32),
                    intensities=np.zeros(0, np.float32),
                ),
            )
        )
    return msgs


def _cloud_messages(ros1: bool) -> list[tuple[int, Any]]:
    """``(bag time ns, message)`` of two small ``sensor_msgs/PointCloud2`` (x y z intensity,
    float32) of the ROS 1 (``ros1``) or the ROS 2 type store."""
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.LATEST)
    t = ts.types
    fields = [
        t["sensor_msgs/msg/PointField"](name=n, offset=4 * i, datatype=7, count=1)
        for i, n in enumerate(("x", "y", "z", "intensity"))
    ]
    rng = np.random.default_rng(0)
    msgs = []
    for i in range(2):
        stamp = t["builtin_interfaces/msg/Time"](sec=1, nanosec=i * 100_000_000)
        data = rng.normal(size=(10, 4)).astype(np.float32).tobytes()
        header = t["std_msgs/msg/Header"](
            stamp=stamp, frame_id="lidar", **({"seq": i} if ros1 else {})
        )
        msg = t[POINT_CLOUD2](
            header=header,
            height=1,
            width=10,
            fields=fields,
            is_bigendian=False,
            point_step=16,
            row_step=160,
            data=np.frombuffer(data, np.uint8),
            is_dense=True,
        )
        msgs.append((1_000_000_000 + i * 100_000_000, msg))
    return msgs


def _bag(kind: str, path: Path) -> Path:
    """Three LaserScan messages of the real ROS 1 bag, written again as a ``kind`` bag
    (``ros1``, ``ros1-bz2``, or a ROS 2 bag folder: ``mcap`` or ``sqlite3``) at ``path``."""
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Writer2
    from rosbags.typesys import Stores, get_typestore

    ros1 = kind.startswith("ros1")
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.LATEST)
    msgtype = LASER_SCAN
    msgs = _scan_messages(ros1)
    if ros1:
        w1 = Writer1(path)
        if kind == "ros1-bz2":
            w1.set_compression(Writer1.CompressionFormat.BZ2)
        with w1:
            conn = w1.add_connection("/scan", msgtype, typestore=ts)
            for t, msg in msgs:
                w1.write(conn, t, ts.serialize_ros1(msg, msgtype))
    else:
        plugin = StoragePlugin.SQLITE3 if kind == "sqlite3" else StoragePlugin.MCAP
        w2 = Writer2(path, version=9, storage_plugin=plugin)
        with w2:
            conn = w2.add_connection("/scan", msgtype, typestore=ts)
            for t, msg in msgs:
                w2.write(conn, t, ts.serialize_cdr(msg, msgtype))
    return path


def _ros1_cloud_bag(path: Path) -> Path:
    """Two small ``sensor_msgs/PointCloud2`` messages (x y z intensity, float32) in a ROS 1
    bag: the walker's path to ``decode_pointcloud2``."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    with Writer(path) as w:
        conn = w.add_connection("/points", POINT_CLOUD2, typestore=ts)
        for t, msg in _cloud_messages(ros1=True):
            w.write(conn, t, ts.serialize_ros1(msg, POINT_CLOUD2))
    return path


def _ros1_seeds() -> list[bytes]:
    out = []
    for kind in ("ros1", "ros1-bz2"):
        with tempfile.TemporaryDirectory() as d:
            out.append(_bag(kind, Path(d) / "seed.bag").read_bytes())
    with tempfile.TemporaryDirectory() as d:
        out.append(_ros1_cloud_bag(Path(d) / "cloud.bag").read_bytes())
    return out


def _run_bag(suffix: str) -> bytes:
    """A two-frame run bag of our writer (odometry, pose, tf, PointCloud2 scans with
    intensity, path) as one ``.mcap`` or ``.db3`` file: the clouds are what the readers
    decode, the other topics are records the reader must walk past."""
    from scanreg.io import write_run_bag

    poses = np.repeat(np.eye(4)[None], 2, axis=0)
    poses[1, 0, 3] = 0.5
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / f"run{suffix}"
        write_run_bag(p, [0.0, 0.1], poses, scans=[_cloud(), _cloud()])
        return p.read_bytes()


def _ros2_seeds(suffix: str) -> Callable[[], list[bytes]]:
    def seeds() -> list[bytes]:
        out = [_run_bag(suffix)]
        with tempfile.TemporaryDirectory() as d:  # and the storage file of a LaserScan bag
            bag = _bag("mcap" if suffix == ".mcap" else "sqlite3", Path(d) / "bag")
            out.append(next(bag.glob(f"*{suffix}")).read_bytes())
        return out

    return seeds


@functools.cache
def _memoise_qos() -> None:
    """rosbags parses each topic's QoS profile YAML text with ruamel on every open of an MCAP
    or sqlite3 file (~5 ms per topic: 90 % of a ROS 2 execution). The text only changes when
    the fuzzer mutates it, so each distinct text is still parsed (same code paths, same
    refusals) and a repeat is served from a cache."""
    from rosbags.rosbag2 import metadata, storage_mcap, storage_sqlite3

    parse = metadata.parse_qos
    seen = functools.lru_cache(maxsize=4096)(parse)

    def parse_qos(dcts: Any) -> Any:
        return list(seen(dcts)) if isinstance(dcts, str) else parse(dcts)

    storage_mcap.parse_qos = parse_qos
    storage_sqlite3.parse_qos = parse_qos


def _bag_read(p: Path) -> object:
    """The bag readers whose message type the file names, each left to refuse by name: a
    LaserScan seed exercises ``read_bag_scans``, a run bag ``read_bag_clouds`` (PointCloud2
    decoding). Type names are plain text in every bag's connection records; a file naming
    neither (or only inside compressed ROS 1 chunks) gets both. Calling both on every input
    opened each ROS 2 bag twice, half of them only to refuse "no ... topic" (~2 ms per open
    of a sqlite3 bag)."""
    from scanreg.io import read_bag_clouds, read_bag_scans

    _memoise_qos()
    data = p.read_bytes()
    named = [
        read
        for read, name in ((read_bag_scans, b"LaserScan"), (read_bag_clouds, b"PointCloud2"))
        if name in data
    ]
    out, refusals = [], []
    for read in named or (read_bag_scans, read_bag_clouds):
        try:
            out.append(read(p))
        except NAMED as exc:
            refusals.append(exc)
    if not out:  # every reader refused: say so (a seed must read with one of them)
        raise refusals[0]
    return out


#: ``ros_msg``: the first byte of an input picks the serialisation (ROS 1 or CDR) and the
#: message type; the rest is one serialised message.
MESSAGE_KINDS = (
    (True, LASER_SCAN),
    (True, POINT_CLOUD2),
    (False, LASER_SCAN),
    (False, POINT_CLOUD2),
)


def _message_seeds() -> list[bytes]:
    from rosbags.typesys import Stores, get_typestore

    out = []
    for selector, (ros1, msgtype) in enumerate(MESSAGE_KINDS):
        ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.LATEST)
        serialise = ts.serialize_ros1 if ros1 else ts.serialize_cdr
        make = _scan_messages if msgtype == LASER_SCAN else _cloud_messages
        _, msg = make(ros1)[0]
        out.append(bytes([selector]) + bytes(serialise(msg, msgtype)))
    return out


def _read_message(p: Path) -> object:
    """One bag message through the reader's own layer — deserialisation with the reader's
    cached type store, then the LaserScan / PointCloud2 conversion and its checks — without
    the bag container around it (rosbags' reader setup, ~2 ms per sqlite3 open, is not our
    code; the whole-file targets ``ros1``, ``ros2_mcap`` and ``ros2_sqlite`` keep it)."""
    from scanreg.io import rosbag

    data = p.read_bytes()
    if not data:
        raise ValueError("empty input")
    ros1, msgtype = MESSAGE_KINDS[data[0] % len(MESSAGE_KINDS)]
    msg = rosbag._deserialise(p, memoryview(data)[1:], msgtype, ros1, "/fuzz message 0")
    convert = rosbag._scan_from_message if msgtype == LASER_SCAN else rosbag._cloud_from_message
    return convert(p, "/fuzz", 1_000_000_000, msg, 0)


def _config_seeds() -> list[bytes]:
    from scanreg.config import dump_config
    from scanreg.pipeline import OdometryConfig

    return [dump_config(OdometryConfig()).encode()]


def _read_config(p: Path) -> object:
    from scanreg.config import load_config
    from scanreg.pipeline import OdometryConfig

    return load_config(OdometryConfig, p)


def _las_seeds(compress: bool) -> Callable[[], list[bytes]]:
    """Our writer's LAS/LAZ in the point formats people meet: 6 (LAS 1.4, GPS time, a float
    intensity as an extra-bytes field, a ring, a WKT CRS), 1 (LAS 1.2 with time), 0."""

    def seeds() -> list[bytes]:
        from scanreg.io import PointCloud, write_las

        cloud = _cloud()
        assert isinstance(cloud, PointCloud)
        timed = PointCloud(points=cloud.points, time=np.linspace(0.0, 0.1, len(cloud)))
        wkt = 'PROJCS["WGS 84 / UTM zone 32N",GEOGCS["WGS 84"],UNIT["metre",1]]'
        out = []
        for c, options in (
            (cloud, {"crs_wkt": wkt}),
            (timed, {"point_format": 1}),
            (PointCloud(points=cloud.points), {"point_format": 0}),
        ):
            with tempfile.TemporaryDirectory() as d:
                p = Path(d) / "seed.las"
                write_las(p, c, compress=compress, **options)
                out.append(p.read_bytes())
        return out

    return seeds


def _read_las(p: Path) -> object:
    from scanreg.io import read_las

    return read_las(p)


#: ``map_server``: one input holds both files, the YAML text, a NUL byte, then the PGM
#: bytes (a YAML cannot hold a NUL); the PGM is written as ``map.pgm`` beside the YAML.
MAP_SEPARATOR = b"\0"


def _map_server_seeds() -> list[bytes]:
    from scanreg import SE2
    from scanreg.io.occupancy import occupancy_grid, write_map

    angles = np.linspace(-np.pi, np.pi, 90, endpoint=False)
    scan = np.c_[np.cos(angles), np.sin(angles)] * 1.5
    grid = occupancy_grid([SE2.identity()], [scan], resolution=0.1, padding=0.3)
    out = []
    with tempfile.TemporaryDirectory() as d:
        paths = write_map(d, grid)
        yaml, pgm = paths["yaml"].read_bytes(), paths["pgm"].read_bytes()
        out.append(yaml + MAP_SEPARATOR + pgm)
        commented = pgm.replace(b"P5\n", b"P5\n# CREATOR: map_saver.cpp 0.050 m/pix\n", 1)
        negated = yaml.replace(b"negate: 0", b"negate: 1").replace(b"map.pgm", b"'map.pgm'")
        out.append(negated + MAP_SEPARATOR + commented)
    return out


def _read_map_server(p: Path) -> object:
    from scanreg.io.occupancy import read_map_server

    data = p.read_bytes()
    yaml, _, pgm = data.partition(MAP_SEPARATOR)
    p.write_bytes(yaml)
    (p.parent / "map.pgm").write_bytes(pgm)
    return read_map_server(p)


#: Files a manifest row may name, made once beside the target's input (its folder is the
#: rows' base): two point clouds, a register config, an odometry config, an initial pose.
MANIFEST_FILES = {
    "a.pcd": b"",
    "b.pcd": b"",
    "reg.toml": b'method = "point_to_plane"\nmax_iterations = 20\nvoxel_size = 0.2\n',
    "odo.toml": b"voxel_size = 0.5\nmax_range = 60.0\n",
    "init.txt": b"1 0 0 0.1\n0 1 0 0\n0 0 1 0\n0 0 0 1\n",
}
MANIFEST_ROWS = {
    "odometry": [
        ["id", "input", "config"],
        ["street", "sim:street,frames=5,seed=1", "odo.toml"],
        ["tunnel", "sim:tunnel,frames=3", ""],
        ["home", "~/", ""],
    ],
    "register": [
        ["id", "source", "target", "config", "init"],
        ["p1", "a.pcd", "b.pcd", "reg.toml", "init.txt"],
        ["p2", "b.pcd", "a.pcd", "", ""],
    ],
}


def _manifest_text(rows: list[list[str]], delimiter: str) -> bytes:
    import csv
    import io

    buf = io.StringIO()
    csv.writer(buf, delimiter=delimiter, lineterminator="\n").writerows(rows)
    return buf.getvalue().encode()


def _manifest_seeds(suffix: str) -> Callable[[], list[bytes]]:
    def seeds() -> list[bytes]:
        out = []
        for rows in MANIFEST_ROWS.values():
            if suffix == ".parquet":
                import pyarrow as pa
                import pyarrow.parquet as pq

                table = pa.table({c: [r[i] for r in rows[1:]] for i, c in enumerate(rows[0])})
                with tempfile.TemporaryDirectory() as d:
                    pq.write_table(table, Path(d) / "m.parquet")
                    out.append((Path(d) / "m.parquet").read_bytes())
            else:
                out.append(_manifest_text(rows, "\t" if suffix == ".tsv" else ","))
        return out

    return seeds


def _read_manifest(p: Path) -> object:
    """The manifest as ``scanreg batch`` checks it before running anything (files present,
    ``sim:`` URIs and configs valid): a register manifest when it names a ``source``
    column, else an odometry one."""
    from scanreg.batch import read_manifest

    _manifest_files(p.parent)
    kind = "register" if b"source" in p.read_bytes() else "odometry"
    return read_manifest(p, kind)


@functools.cache
def _manifest_files(folder: Path) -> None:
    """Write :data:`MANIFEST_FILES` into ``folder``, once per process: no reader removes
    them, and checking each one's presence per input was a fifth of a TSV execution."""
    for name, content in MANIFEST_FILES.items():
        (folder / name).write_bytes(content)


def _command_configs() -> list[tuple[str, Callable[[Path], object]]]:
    """``(name, load)`` of the TOML config of every command but ``scanreg odometry`` on a
    3D sequence (the ``config`` target): 2D odometry (over the mapping preset, as the CLI
    loads it), ``map``, ``map`` in 3D, and ``batch register``'s options."""
    from scanreg.batch.jobs import register_options
    from scanreg.config import load_config
    from scanreg.pipeline.mapping import MappingConfig
    from scanreg.pipeline.mapping3d import MappingConfig3D
    from scanreg.pipeline.odometry2d import OdometryConfig2D

    mapping = MappingConfig().odometry
    preset = {f: getattr(mapping, f) for f in ("front_end", "kernel", "max_keyframes")}

    def odometry_2d(p: Path) -> object:
        return load_config(
            OdometryConfig2D, p, presets=["mapping"], preset_table={"mapping": preset}
        )

    return [
        ("odometry 2D", odometry_2d),
        ("map", lambda p: load_config(MappingConfig, p)),
        ("map 3D", lambda p: load_config(MappingConfig3D, p)),
        ("batch register", lambda p: register_options(str(p))),
    ]


def _command_config_seeds() -> list[bytes]:
    from scanreg.config import dump_config
    from scanreg.pipeline.mapping import MappingConfig
    from scanreg.pipeline.mapping3d import MappingConfig3D
    from scanreg.pipeline.odometry2d import OdometryConfig2D

    out = [dump_config(c()).encode() for c in (OdometryConfig2D, MappingConfig, MappingConfig3D)]
    out.append(MANIFEST_FILES["reg.toml"])
    return out


def _read_command_configs(p: Path) -> object:
    """The file as each command's config; every loader may refuse it by name, and a seed
    must load with at least one (as ``_bag_read`` does for the bag readers)."""
    out, refusals = [], []
    for _, load in _command_configs():
        try:
            out.append(load(p))
        except NAMED as exc:
            refusals.append(exc)
    if not out:
        raise refusals[0]
    return out


def _io(name: str) -> Callable[[Path], object]:
    def read(p: Path) -> object:
        import scanreg.io as sio

        return getattr(sio, name)(p)

    return read


TARGETS: dict[str, Target] = {
    t.name: t
    for t in (
        Target("pcd", ".pcd", _io("read_pcd"), _pcd_seeds),
        Target("ply", ".ply", _io("read_ply"), _ply_seeds),
        Target("kitti_bin", ".bin", _io("read_kitti_bin"), _kitti_bin_seeds),
        Target("kitti_calib", ".txt", _io("read_kitti_calib"), _calib_seeds),
        Target("kitti_poses", ".txt", _io("read_kitti_poses"), _kitti_poses_seeds),
        Target("tum", ".txt", _io("read_tum"), _tum_seeds),
        Target("carmen", ".log", _io("read_carmen"), _carmen_seeds),
        Target("carmen_gz", ".log.gz", _io("read_carmen"), _carmen_gz_seeds),
        Target("carmen_bz2", ".clf.bz2", _io("read_carmen"), _carmen_bz2_seeds),
        Target("g2o", ".g2o", _io("read_g2o"), _g2o_seeds),
        Target("ros1", ".bag", _bag_read, _ros1_seeds),
        Target("ros2_mcap", ".mcap", _bag_read, _ros2_seeds(".mcap")),
        Target("ros2_sqlite", ".db3", _bag_read, _ros2_seeds(".db3")),
        Target("ros_msg", ".msg", _read_message, _message_seeds),
        Target("config", ".toml", _read_config, _config_seeds),
        Target("las", ".las", _read_las, _las_seeds(compress=False)),
        Target("laz", ".laz", _read_las, _las_seeds(compress=True)),
        Target("map_server", ".yaml", _read_map_server, _map_server_seeds),
        Target("manifest_csv", ".csv", _read_manifest, _manifest_seeds(".csv")),
        Target("manifest_tsv", ".tsv", _read_manifest, _manifest_seeds(".tsv")),
        Target("manifest_parquet", ".parquet", _read_manifest, _manifest_seeds(".parquet")),
        Target("command_configs", ".toml", _read_command_configs, _command_config_seeds),
    )
}


def scratch_dir(name: str) -> Path:
    """A fresh folder for the target's input file, in memory (``/dev/shm``) where there is
    one: the readers take paths, and writing the input to disk cost ~90 % of an execution
    (~1 ms per write on this machine's ext4, against ~0.05 ms on tmpfs). libFuzzer ends the
    process with exit(): nothing removes the folder then (campaign.sh removes its own)."""
    shm = Path("/dev/shm")
    base = os.environ.get("SCANREG_FUZZ_SCRATCH")  # campaign.sh's, removed when it ends
    if base is None and shm.is_dir() and os.access(shm, os.W_OK):
        base = str(shm)
    return Path(tempfile.mkdtemp(prefix=f"scanreg-fuzz-{name}-", dir=base))


class Runner:
    """Feeds bytes to one target through one reused file.

    Without ``findings`` an unnamed exception propagates (libFuzzer records it and stops, as
    the CI smoke pass wants). With a ``findings`` folder (the campaign) it is written there
    as ``unnamed-SHA1`` (the input) and ``unnamed-SHA1.txt`` (the traceback) and the
    campaign goes on; crashes and hangs still stop the process (libFuzzer records them).
    ``executions`` and ``unnamed`` count calls and such findings.
    """

    def __init__(self, target: Target, workdir: Path, findings: Path | None = None) -> None:
        self.target = target
        self.path = workdir / f"input{target.suffix}"
        self.findings = findings
        self.executions = 0
        self.unnamed = 0

    def __call__(self, data: bytes) -> None:
        self.executions += 1
        self.path.write_bytes(data)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("error", RuntimeWarning)
                with contextlib.suppress(*NAMED):
                    self.target.read(self.path)
        except BaseException:
            if self.findings is None or sys.exc_info()[0] is KeyboardInterrupt:
                raise
            self._record(data)

    def _record(self, data: bytes) -> None:
        """Count every unnamed exception; keep the first input per (type, innermost line),
        so one bug does not fill the disk with thousands of variants."""
        kind, _, tb = sys.exc_info()
        while tb is not None and tb.tb_next is not None:
            tb = tb.tb_next
        where = f"{tb.tb_frame.f_code.co_filename}:{tb.tb_lineno}" if tb else "?"
        self.keep(data, f"{getattr(kind, '__name__', kind)} {where}", traceback.format_exc())

    def keep(self, data: bytes, key: str, report: str) -> None:
        """Count a finding (campaign mode) and keep its first input per ``key``."""
        assert self.findings is not None
        self.unnamed += 1
        stem = self.findings / f"unnamed-{hashlib.sha1(key.encode()).hexdigest()[:16]}"
        if not stem.exists():
            stem.write_bytes(data)
            Path(f"{stem}.txt").write_text(report)


def smoke_pass(name: str, workdir: Path, per_seed: int, seed: int) -> int:
    """The CI smoke pass of target ``name``: each seed, then ``per_seed`` structured
    mutations of it (:func:`mutations`); an unnamed exception propagates. Returns the number
    of inputs run. ``tests/test_fuzz.py`` runs it in a child process, so that an input that
    aborts the interpreter fails the test with its signal instead of ending the test run."""
    target = TARGETS[name]
    run = Runner(target, workdir)
    rng = np.random.default_rng(seed)
    seeds = target.seeds()
    if not seeds:
        raise AssertionError(f"{name}: no seeds")
    for data in seeds:
        run(data)  # the seed itself reads without an error
        for mutated in mutations(data, per_seed, rng):
            run(mutated)  # only a named refusal may come out (Runner lets nothing else through)
    return run.executions


def mutations(seed: bytes, count: int, rng: np.random.Generator) -> list[bytes]:
    """Cheap structured mutations for the CI smoke pass (the campaign uses libFuzzer's)."""
    out = []
    for _ in range(count):
        b = bytearray(seed)
        kind = int(rng.integers(6))
        if not b or kind == 0:
            b = b[: int(rng.integers(len(b) + 1))]  # truncate
        elif kind == 1:
            for _ in range(int(rng.integers(1, 9))):
                b[int(rng.integers(len(b)))] = int(rng.integers(256))  # flip bytes
        elif kind == 2:
            i = int(rng.integers(len(b)))
            b[i:i] = bytes(rng.integers(0, 256, int(rng.integers(1, 16)), dtype=np.uint8))
        elif kind == 3:
            i = int(rng.integers(len(b)))
            del b[i : i + int(rng.integers(1, 64))]
        elif kind == 4:
            # Numbers are where parsers break: swap a digit run for an extreme value.
            text = bytes(b)
            digits = [i for i, c in enumerate(text) if 48 <= c <= 57]
            if digits:
                i = digits[int(rng.integers(len(digits)))]
                token = [b"nan", b"-inf", b"1e308", b"-0", b"99999999999999999999", b"-1"][
                    int(rng.integers(6))
                ]
                b[i : i + 1] = token
        else:
            i, j = sorted(int(v) for v in rng.integers(len(b) + 1, size=2))
            b[i:i] = b[i:j]  # duplicate a span
        out.append(bytes(b))
    return out


__all__ = ["TARGETS", "Runner", "Target", "mutations", "scratch_dir", "smoke_pass"]
