"""ROS bags: bags written here with rosbags' writers (ROS 1 plain/bz2/lz4, ROS 2 sqlite3/mcap)
from real KITTI points and simulated 2D scans, read back exactly; the real CCNY bag whose index
records stock rosbags rejects; PointCloud2 layouts; truncated and corrupt bags."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import data_dir
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray
from scanreg import SE2
from scanreg import simulate as sim
from scanreg.io import FileFormatError, PointCloud, read_kitti_bin

pytest.importorskip("rosbags", reason="rosbags is not installed (pip install 'scanreg[ros]')")

from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore
from scanreg.io.rosbag import (
    BagTopic,
    RosLaserScan,
    decode_pointcloud2,
    iter_bag_scans,
    list_topics,
    read_bag_clouds,
    read_bag_scans,
)

SCAN = "sensor_msgs/msg/LaserScan"
CLOUD = "sensor_msgs/msg/PointCloud2"
KINDS = ["ros1", "ros1-bz2", "ros1-lz4", "sqlite3", "mcap"]


# --------------------------------------------------------------------------- bag writing


def _store(kind: str) -> Any:
    return get_typestore(Stores.ROS1_NOETIC if kind.startswith("ros1") else Stores.LATEST)


def _header(ts: Any, kind: str, stamp_ns: int, frame: str) -> Any:
    time = ts.types["builtin_interfaces/msg/Time"](
        sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000
    )
    extra = {"seq": 0} if kind.startswith("ros1") else {}
    return ts.types["std_msgs/msg/Header"](stamp=time, frame_id=frame, **extra)


def _scan_msg(ts: Any, kind: str, scan: Any, stamp_ns: int, intensities: bool) -> Any:
    n = len(scan.ranges)
    return ts.types[SCAN](
        header=_header(ts, kind, stamp_ns, "laser"),
        angle_min=float(scan.angles[0]),
        angle_max=float(scan.angles[-1]),
        angle_increment=float(scan.angles[1] - scan.angles[0]),
        time_increment=1e-4,
        scan_time=0.1,
        range_min=0.1,
        range_max=float(scan.max_range),
        ranges=np.asarray(scan.ranges, dtype=np.float32),
        intensities=np.linspace(0, 100, n, dtype=np.float32)
        if intensities
        else np.zeros(0, np.float32),
    )


def _cloud_msg(
    ts: Any,
    kind: str,
    records: NDArray[Any],
    stamp_ns: int,
    *,
    height: int = 1,
    row_pad: int = 0,
    bigendian: bool = False,
) -> Any:
    dt = records.dtype
    codes = {"f4": 7, "f8": 8, "u2": 4, "u1": 2, "i4": 5, "u4": 6}
    assert dt.fields is not None
    fields = [
        ts.types["sensor_msgs/msg/PointField"](
            name=name, offset=off, datatype=codes[f.base.str[1:]], count=int(np.prod(f.shape) or 1)
        )
        for name, (f, off) in dt.fields.items()
    ]
    width = records.size // height
    rows = np.ascontiguousarray(records).reshape(height, width).view(np.uint8).reshape(height, -1)
    rows = np.concatenate([rows, np.full((height, row_pad), 0xAB, np.uint8)], axis=1)
    return ts.types[CLOUD](
        header=_header(ts, kind, stamp_ns, "velodyne"),
        height=height,
        width=width,
        fields=fields,
        is_bigendian=bigendian,
        point_step=dt.itemsize,
        row_step=width * dt.itemsize + row_pad,
        data=np.ascontiguousarray(rows).reshape(-1),
        is_dense=bool(np.isfinite(records["x"]).all()),
    )


def write_bag(path: Path, kind: str, topics: dict[str, tuple[str, list[tuple[int, Any]]]]) -> Path:
    """Write ``{topic: (msgtype, [(bag_time_ns, msg), ...])}`` as a bag of ``kind``."""
    ts = _store(kind)
    if kind.startswith("ros1"):
        path = path.with_suffix(".bag")
        w1 = Writer1(path)
        if kind == "ros1-bz2":
            w1.set_compression(Writer1.CompressionFormat.BZ2)
        if kind == "ros1-lz4":
            w1.set_compression(Writer1.CompressionFormat.LZ4)
        with w1:
            for topic, (msgtype, msgs) in topics.items():
                conn = w1.add_connection(topic, msgtype, typestore=ts)
                for t, msg in msgs:
                    w1.write(conn, t, ts.serialize_ros1(msg, msgtype))
        return path
    plugin = StoragePlugin.MCAP if kind.startswith("mcap") else StoragePlugin.SQLITE3
    w2 = Writer2(path, version=9, storage_plugin=plugin)
    if kind.endswith("-zstd-file"):
        w2.set_compression(CompressionMode.FILE, CompressionFormat.ZSTD)
    if kind.endswith("-zstd-message"):
        w2.set_compression(CompressionMode.MESSAGE, CompressionFormat.ZSTD)
    with w2:
        for topic, (msgtype, msgs) in topics.items():
            conn = w2.add_connection(topic, msgtype, typestore=ts)
            for t, msg in msgs:
                w2.write(conn, t, ts.serialize_cdr(msg, msgtype))
    return path


def _sim_scans(n: int = 4) -> list[Any]:
    traj = sim.Trajectory.from_speed_and_yaw_rate(
        1.0, 0.1, duration=2.0, start=SE2.from_vector([1, 0, 0])
    )
    run = sim.simulate_run(
        sim.floor_plan(seed=1), sim.LaserModel.preset("laser_360"), traj, num_scans=n, seed=0
    )
    return list(run.scans)


def _kitti_records(step: int = 25) -> NDArray[Any]:
    cloud = read_kitti_bin(data_dir("kitti-odometry-00-frames-000-015", "velodyne", "000000.bin"))
    pts = cloud.points[::step]
    assert cloud.intensity is not None
    dt = np.dtype(
        {
            "names": ["x", "y", "z", "intensity", "ring", "time"],
            "formats": ["<f4", "<f4", "<f4", "<f4", "<u2", "<f4"],
            "offsets": [0, 4, 8, 16, 20, 24],  # a 4-byte hole at 12, like real drivers
            "itemsize": 32,
        }
    )
    rec = np.zeros(pts.shape[0], dtype=dt)
    rec["x"], rec["y"], rec["z"] = pts.T
    rec["intensity"] = cloud.intensity[::step]
    elevation = np.degrees(np.arctan2(pts[:, 2], np.hypot(pts[:, 0], pts[:, 1])))
    rec["ring"] = np.clip(np.round((elevation + 25) * 2), 0, 63)
    rec["time"] = (np.arctan2(pts[:, 1], pts[:, 0]) + np.pi) / (2 * np.pi) * 0.1
    return rec


# --------------------------------------------------------------------------- round trips


@pytest.mark.parametrize("kind", [*KINDS, "sqlite3-zstd-file", "mcap-zstd-message"])
def test_laserscan_round_trip(tmp_path: Path, kind: str) -> None:
    ts = _store(kind)
    scans = _sim_scans()
    t0 = 1_700_000_000_123_456_789
    msgs = [
        (t0 + i * 100_000_000 + 5_000, _scan_msg(ts, kind, s, t0 + i * 100_000_000, i % 2 == 0))
        for i, s in enumerate(scans)
    ]
    other = [(t0, _scan_msg(ts, kind, scans[0], t0, False))]
    path = write_bag(tmp_path / "scans", kind, {"/scan": (SCAN, msgs), "/rear": (SCAN, other)})

    assert list_topics(path) == (
        BagTopic("/rear", SCAN, 1),
        BagTopic("/scan", SCAN, len(scans)),
    )
    with pytest.raises(ValueError, match="several"):
        read_bag_scans(path)
    got = read_bag_scans(path, topic="/scan")
    assert len(got) == len(scans)
    for i, (scan, sim_scan) in enumerate(zip(got, scans, strict=True)):
        assert isinstance(scan, RosLaserScan)
        assert scan.topic == "/scan" and scan.frame_id == "laser"
        expected = np.asarray(sim_scan.ranges, dtype=np.float32).astype(np.float64)
        np.testing.assert_array_equal(scan.ranges, expected)
        inc = np.float32(sim_scan.angles[1] - sim_scan.angles[0])
        np.testing.assert_allclose(scan.angles, sim_scan.angles, atol=1e-4)
        assert scan.angle_increment == float(inc)
        assert scan.timestamp == pytest.approx((t0 + i * 100_000_000) * 1e-9, abs=1e-6)
        assert scan.logger_timestamp == pytest.approx(
            (t0 + i * 100_000_000 + 5000) * 1e-9, abs=1e-6
        )
        assert scan.max_range == float(np.float32(sim_scan.max_range))
        assert scan.range_min == float(np.float32(0.1))
        if i % 2 == 0:
            assert scan.intensities is not None
            assert scan.intensities[-1] == 100.0
        else:
            assert scan.intensities is None
        # points: every finite return inside (range_min, range_max)
        keep = np.isfinite(expected) & (expected > scan.range_min) & (expected < scan.max_range)
        assert scan.to_points().shape == (int(keep.sum()), 2)
    assert len(read_bag_scans(path, topic="/rear")) == 1


@pytest.mark.parametrize("kind", KINDS)
def test_pointcloud2_round_trip_from_kitti(tmp_path: Path, kind: str) -> None:
    ts = _store(kind)
    rec = _kitti_records()
    t0 = 1_317_000_000_000_000_000
    frames = [rec, rec[::2]]
    msgs = [(t0 + i * 10**8, _cloud_msg(ts, kind, r, t0 + i * 10**8)) for i, r in enumerate(frames)]
    path = write_bag(tmp_path / "clouds", kind, {"/velodyne_points": (CLOUD, msgs)})

    assert list_topics(path) == (BagTopic("/velodyne_points", CLOUD, 2),)
    got = read_bag_clouds(path)
    assert len(got) == 2
    for i, (bag_cloud, r) in enumerate(zip(got, frames, strict=True)):
        cloud = bag_cloud.cloud
        assert isinstance(cloud, PointCloud)
        assert bag_cloud.timestamp == pytest.approx((t0 + i * 10**8) * 1e-9, abs=1e-6)
        assert bag_cloud.frame_id == "velodyne" and bag_cloud.is_dense
        assert (bag_cloud.height, bag_cloud.width) == (1, r.size)
        expected = np.stack([r["x"], r["y"], r["z"]], axis=1).astype(np.float64)
        np.testing.assert_array_equal(cloud.points, expected)
        np.testing.assert_array_equal(cloud.intensity, r["intensity"].astype(np.float64))
        np.testing.assert_array_equal(cloud.ring, r["ring"].astype(np.int64))
        np.testing.assert_array_equal(cloud.time, r["time"].astype(np.float64))
        assert cloud.points.flags.c_contiguous and cloud.points.dtype == np.float64
    assert len(got[0].cloud) > 4000 and got[0].cloud.ring is not None
    assert got[0].cloud.ring.max() > 30  # the rings are real elevations, not all zero


def test_ros_laserscan_semantics() -> None:
    """range_min is honoured whatever min_range is asked; beam times follow time_increment."""
    scan = RosLaserScan(
        kind="sensor_msgs/LaserScan",
        ranges=np.array([0.01, 0.5, np.inf, 5.0, 6.0, np.nan]),
        angles=np.linspace(0, 1, 6),
        max_range=5.6,
        laser_pose=None,
        odometry_pose=None,
        timestamp=10.0,
        logger_timestamp=10.01,
        range_min=0.02,
        time_increment=1e-3,
    )
    np.testing.assert_array_equal(scan.valid(), [False, True, False, True, False, False])
    np.testing.assert_array_equal(
        scan.valid(min_range=1.0), [False, False, False, True, False, False]
    )
    assert scan.to_points().shape == (2, 2)
    np.testing.assert_allclose(scan.beam_times, np.arange(6) * 1e-3)
    with pytest.raises(ValueError, match="range_min"):
        RosLaserScan(
            kind="k",
            ranges=np.ones(3),
            angles=np.zeros(3),
            max_range=1.0,
            laser_pose=None,
            odometry_pose=None,
            timestamp=0.0,
            logger_timestamp=0.0,
            range_min=2.0,
        )
    with pytest.raises(ValueError, match="intensities"):
        RosLaserScan(
            kind="k",
            ranges=np.ones(3),
            angles=np.zeros(3),
            max_range=1.0,
            laser_pose=None,
            odometry_pose=None,
            timestamp=0.0,
            logger_timestamp=0.0,
            intensities=np.ones(2),
        )


def test_pointcloud2_layouts() -> None:
    """Big-endian, organised with NaNs and row padding, float64 and multi-count fields."""
    ts = _store("mcap")
    rng = np.random.default_rng(0)
    dt = np.dtype(
        {
            "names": ["x", "y", "z", "t", "normal"],
            "formats": [">f8", ">f8", ">f8", ">u4", (">f4", (3,))],
            "offsets": [0, 8, 16, 24, 28],
            "itemsize": 40,
        }
    )
    rec = np.zeros(24, dtype=dt)
    for name in ("x", "y", "z"):
        rec[name] = rng.normal(size=24)
    rec["x"][[3, 7]] = np.nan
    rec["t"] = rng.integers(0, 100_000_000, 24)
    rec["normal"] = rng.normal(size=(24, 3))
    msg = _cloud_msg(ts, "mcap", rec, 0, height=4, row_pad=12, bigendian=True)
    cloud = decode_pointcloud2(
        msg.fields,
        msg.data,
        height=msg.height,
        width=msg.width,
        point_step=msg.point_step,
        row_step=msg.row_step,
        is_bigendian=msg.is_bigendian,
    )
    expected = np.stack([rec["x"], rec["y"], rec["z"]], axis=1)
    np.testing.assert_array_equal(cloud.points, expected)  # NaN == NaN here
    assert len(cloud.finite()) == 22
    np.testing.assert_array_equal(cloud.time, rec["t"].astype(np.float64))
    np.testing.assert_array_equal(cloud.fields["normal"], rec["normal"].astype(np.float64))
    # the same bytes read as little-endian are different numbers: the flag is honoured
    swapped = decode_pointcloud2(
        msg.fields,
        msg.data,
        height=msg.height,
        width=msg.width,
        point_step=msg.point_step,
        row_step=msg.row_step,
        is_bigendian=False,
    )
    assert not np.array_equal(swapped.points[0], cloud.points[0])


def test_pointcloud2_refuses_bad_layouts() -> None:
    ts = _store("mcap")
    rec = _kitti_records(step=400)
    msg = _cloud_msg(ts, "mcap", rec, 0)
    base = {
        "height": 1,
        "width": msg.width,
        "point_step": msg.point_step,
        "row_step": msg.row_step,
        "is_bigendian": False,
    }
    with pytest.raises(ValueError, match="data"):
        decode_pointcloud2(msg.fields, msg.data[:-40], **base)
    with pytest.raises(ValueError, match="row_step"):
        decode_pointcloud2(msg.fields, msg.data, **{**base, "row_step": 10})
    with pytest.raises(ValueError, match="point_step"):
        decode_pointcloud2(msg.fields, msg.data, **{**base, "point_step": 20, "row_step": 10**6})
    bad = list(msg.fields)
    bad[3] = ts.types["sensor_msgs/msg/PointField"](
        name="intensity", offset=16, datatype=9, count=1
    )
    with pytest.raises(ValueError, match="datatype"):
        decode_pointcloud2(bad, msg.data, **base)
    no_z = [f for f in msg.fields if f.name != "z"]
    with pytest.raises(ValueError, match="z"):
        decode_pointcloud2(no_z, msg.data, **base)


# --------------------------------------------------------------------------- the real bag


def test_ccny_demo_bag() -> None:
    path = data_dir("rosbag1-laserscan-ccny-demo", "demo.bag")
    assert list_topics(path) == (BagTopic("/scan", SCAN, 360),)
    scans = read_bag_scans(path)
    assert len(scans) == 360
    assert {len(s) for s in scans} == {681}
    first = scans[0]
    assert first.angles[0] == pytest.approx(-2.0862, abs=1e-4)
    assert first.angles[-1] == pytest.approx(2.0862, abs=1e-4)
    assert first.angle_increment == pytest.approx(0.0061359, abs=1e-7)
    assert first.time_increment == pytest.approx(9.77e-5, rel=1e-3)
    assert first.scan_time == pytest.approx(0.1)
    assert first.range_min == pytest.approx(0.02) and first.max_range == pytest.approx(5.6)
    assert first.frame_id == "/laser" and first.intensities is None
    stamps = np.array([s.timestamp for s in scans])
    assert np.all(np.diff(stamps) > 0)
    assert stamps[-1] - stamps[0] == pytest.approx(35.8, abs=0.1)
    assert np.median(np.diff(stamps)) == pytest.approx(0.1, abs=0.01)
    assert first.timestamp == pytest.approx(1282836370.97, abs=0.01)  # 2010-08-26
    pts = first.to_points()
    radii = np.hypot(pts[:, 0], pts[:, 1])
    assert 500 < len(pts) <= 681
    assert radii.min() > 0.02 and radii.max() < 5.6
    # stock rosbags rejects this bag (its index records are non-standard)
    from rosbags.rosbag1 import Reader

    with pytest.raises(AssertionError), Reader(path):
        pass
    # the iterator stops early without reading the rest
    assert next(iter(iter_bag_scans(path))).timestamp == first.timestamp


# --------------------------------------------------------------------------- hostile bags


@pytest.mark.parametrize("cut", [20, 4200, 400_000, 792_700, 1_031_000])
def test_truncated_ros1_bag(tmp_path: Path, cut: int) -> None:
    data = data_dir("rosbag1-laserscan-ccny-demo", "demo.bag").read_bytes()
    path = tmp_path / "cut.bag"
    path.write_bytes(data[:cut])
    with pytest.raises(FileFormatError, match=r"cut\.bag"):
        read_bag_scans(path, topic="/scan")


def test_corrupt_ros1_bags(tmp_path: Path) -> None:
    data = bytearray(data_dir("rosbag1-laserscan-ccny-demo", "demo.bag").read_bytes())
    bad = tmp_path / "bad.bag"
    bad.write_bytes(b"not a bag at all")
    with pytest.raises(FileFormatError, match=r"bad\.bag.*not a ROS 1 bag|bad\.bag"):
        list_topics(bad)
    # the first chunk's header length replaced by a huge value
    flipped = bytearray(data)
    flipped[4117:4121] = (10**9).to_bytes(4, "little")
    (tmp_path / "flipped.bag").write_bytes(bytes(flipped))
    with pytest.raises(FileFormatError, match=r"flipped\.bag"):
        read_bag_scans(tmp_path / "flipped.bag")
    (tmp_path / "empty.bag").write_bytes(b"")
    with pytest.raises(FileFormatError, match="empty"):
        list_topics(tmp_path / "empty.bag")
    with pytest.raises(FileNotFoundError):
        list_topics(tmp_path / "missing.bag")


@pytest.mark.parametrize("index_pos", [0, 500_000, 2**40])
def test_ros1_bag_without_a_usable_index(tmp_path: Path, index_pos: int) -> None:
    """Unindexed (index_pos 0), or pointing into a chunk or past the end: the walk still
    reads every message (the chunk-info counts still agree)."""
    data = bytearray(data_dir("rosbag1-laserscan-ccny-demo", "demo.bag").read_bytes())
    at = data.index(b"index_pos=") + len(b"index_pos=")
    data[at : at + 8] = index_pos.to_bytes(8, "little")
    path = tmp_path / "reindexed.bag"
    path.write_bytes(bytes(data))
    assert list_topics(path) == (BagTopic("/scan", SCAN, 360),)
    assert len(read_bag_scans(path)) == 360


def test_truncated_message_bytes(tmp_path: Path) -> None:
    """A well-framed bag whose message bytes are cut short: the deserialiser's error is named."""
    ts = _store("ros1")
    msg = _scan_msg(ts, "ros1", _sim_scans(1)[0], 10**9, False)
    raw = ts.serialize_ros1(msg, SCAN)
    path = tmp_path / "short.bag"
    with Writer1(path) as w:
        conn = w.add_connection("/scan", SCAN, typestore=ts)
        w.write(conn, 10**9, raw[: len(raw) // 2])
    with pytest.raises(FileFormatError, match=r"short\.bag.*/scan message 0"):
        read_bag_scans(path)


@pytest.mark.parametrize("kind", ["sqlite3", "mcap"])
def test_corrupt_ros2_bags(tmp_path: Path, kind: str) -> None:
    ts = _store(kind)
    scans = _sim_scans(3)
    msgs = [
        (10**9 * (i + 1), _scan_msg(ts, kind, s, 10**9 * (i + 1), False))
        for i, s in enumerate(scans)
    ]
    folder = write_bag(tmp_path / "bag", kind, {"/scan": (SCAN, msgs)})
    assert len(read_bag_scans(folder)) == 3
    storage = next(p for p in folder.iterdir() if p.suffix in (".db3", ".mcap"))
    assert len(read_bag_scans(storage)) == 3  # the storage file alone also reads
    data = storage.read_bytes()
    cut = tmp_path / f"cut{storage.suffix}"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(FileFormatError, match=f"cut{storage.suffix}"):
        read_bag_scans(cut)
    garbage = tmp_path / f"garbage{storage.suffix}"
    garbage.write_bytes(b"\x00\x01garbage" * 100)
    with pytest.raises(FileFormatError, match=f"garbage{storage.suffix}"):
        list_topics(garbage)


def test_topic_selection_errors(tmp_path: Path) -> None:
    ts = _store("mcap")
    msgs = [(10**9, _scan_msg(ts, "mcap", _sim_scans(1)[0], 10**9, False))]
    path = write_bag(tmp_path / "b", "mcap", {"/scan": (SCAN, msgs)})
    with pytest.raises(ValueError, match="no sensor_msgs/msg/PointCloud2 topic"):
        read_bag_clouds(path)
    with pytest.raises(ValueError, match=r"topic: .*no topic '/nope'"):
        read_bag_scans(path, topic="/nope")
    with pytest.raises(ValueError, match="not sensor_msgs/msg/PointCloud2"):
        read_bag_clouds(path, topic="/scan")
    with pytest.raises(TypeError, match="topic"):
        read_bag_scans(path, topic=3)  # type: ignore[arg-type]


@pytest.mark.parametrize("kind", ["sqlite3", "mcap"])
def test_a_ros2_bag_is_opened_once_per_read(
    tmp_path: Path, kind: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The topic is chosen from the connections of the open that reads the messages (each
    open of a sqlite3 bag costs ~2 ms), and the choice still refuses a missing type."""
    from rosbags.rosbag2 import Reader

    ts = _store(kind)
    msgs = [(10**9, _scan_msg(ts, kind, _sim_scans(1)[0], 10**9, False))]
    path = write_bag(tmp_path / "b", kind, {"/scan": (SCAN, msgs)})
    opens = []
    real_open = Reader.open
    monkeypatch.setattr(Reader, "open", lambda self: opens.append(1) or real_open(self))
    assert len(read_bag_scans(path)) == 1
    assert len(opens) == 1
    with pytest.raises(ValueError, match="no sensor_msgs/msg/PointCloud2 topic"):
        read_bag_clouds(path)
    assert len(opens) == 2


@pytest.fixture(scope="module")
def small_bags(tmp_path_factory: pytest.TempPathFactory) -> dict[str, bytes]:
    """Small valid ROS 1 bags (plain, bz2, lz4) holding 2 LaserScans and 1 PointCloud2."""
    out = {}
    for kind in ("ros1", "ros1-bz2", "ros1-lz4"):
        ts = _store(kind)
        scans = [
            (10**9 * (i + 1), _scan_msg(ts, kind, s, 10**9, i == 0))
            for i, s in enumerate(_sim_scans(2))
        ]
        rec = np.zeros(30, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
        clouds = [(10**9, _cloud_msg(ts, kind, rec, 10**9))]
        folder = tmp_path_factory.mktemp(kind)
        path = write_bag(folder / "b", kind, {"/scan": (SCAN, scans), "/cloud": (CLOUD, clouds)})
        out[kind] = path.read_bytes()
    return out


@settings(
    max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    kind=st.sampled_from(["ros1", "ros1-bz2", "ros1-lz4"]),
    cut=st.floats(0, 1),
    edits=st.lists(st.tuples(st.floats(0, 1), st.integers(0, 255)), max_size=4),
    insert=st.binary(max_size=8),
)
def test_fuzz_mutated_ros1_bags(
    tmp_path: Path,
    small_bags: dict[str, bytes],
    kind: str,
    cut: float,
    edits: list[tuple[float, int]],
    insert: bytes,
) -> None:
    """Mutated bags either read (with consistent shapes) or raise FileFormatError naming the
    file — never another exception, a hang or a crash."""
    raw = bytearray(small_bags[kind])
    for where, value in edits:
        raw[int(where * (len(raw) - 1))] = value
    pos = int(cut * len(raw))
    data = bytes(raw[:pos]) + insert + bytes(raw[pos:]) if insert else bytes(raw[: max(pos, 1)])
    path = tmp_path / "fuzz.bag"
    path.write_bytes(data)
    try:
        topics = list_topics(path)
        scans = read_bag_scans(path, topic="/scan")
        clouds = read_bag_clouds(path, topic="/cloud")
    except FileFormatError as exc:
        assert "fuzz.bag" in str(exc)
        return
    except ValueError as exc:  # topic selection after a mutated connection record
        assert str(exc).startswith("topic:") or "fuzz.bag" in str(exc)
        return
    assert {t.name for t in topics} >= {"/scan", "/cloud"}
    for scan in scans:
        assert scan.ranges.shape == scan.angles.shape
    for cloud in clouds:
        assert cloud.cloud.points.shape == (cloud.height * cloud.width, 3)


# --------------------------------------------------------------------------- CLI


def test_cli_info_on_bags(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    import json

    from scanreg import cli

    path = data_dir("rosbag1-laserscan-ccny-demo", "demo.bag")
    assert cli.main(["info", str(path), "--json"]) == cli.EXIT_OK
    out = json.loads(capsys.readouterr().out)
    assert out == {
        "kind": "bag",
        "format": "ros1",
        "messages": 360,
        "topics": {"/scan": {"type": SCAN, "messages": 360}},
    }
    ts = _store("mcap")
    msgs = [
        (10**9 * (i + 1), _scan_msg(ts, "mcap", s, 10**9, False))
        for i, s in enumerate(_sim_scans(2))
    ]
    folder = write_bag(tmp_path / "b2", "mcap", {"/scan": (SCAN, msgs)})
    assert cli.main(["info", str(folder), "--json"]) == cli.EXIT_OK
    out = json.loads(capsys.readouterr().out)
    assert out["format"] == "ros2" and out["topics"]["/scan"]["messages"] == 2
    cut = tmp_path / "cut.bag"
    cut.write_bytes(path.read_bytes()[:5000])
    assert cli.main(["info", str(cut)]) == cli.EXIT_BAD_INPUT
    assert "cut.bag" in capsys.readouterr().err


def test_missing_rosbags_is_a_clear_error(monkeypatch: pytest.MonkeyPatch) -> None:
    """Without the ros extra, reading a bag says what to install (simulated)."""
    import builtins

    real_import = builtins.__import__

    def fake_import(name: str, *args: Any, **kwargs: Any) -> Any:
        if name == "rosbags" or name.startswith("rosbags."):
            raise ImportError(f"No module named {name!r}")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", fake_import)
    path = data_dir("rosbag1-laserscan-ccny-demo", "demo.bag")
    with pytest.raises(ImportError, match=r"pip install 'scanreg\[ros\]'"):
        read_bag_scans(path)
