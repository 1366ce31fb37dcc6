"""Sequence loaders: the real KITTI frames, synthetic KITTI folders with a known Tr (both
layouts), folders of point files with per-point time, ROS 1/2 bags written here from the real
frames, simulated drives, and hostile folders that must fail with a named error."""

from __future__ import annotations

import json
import shutil
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import data_dir
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scanreg import SE3
from scanreg.io import (
    FileFormatError,
    FolderSequence,
    KittiSequence,
    PointCloud,
    RosbagSequence,
    SimulatedSequence,
    Trajectory,
    describe_sequence,
    lidar_to_camera_poses,
    open_sequence,
    read_kitti_bin,
    write_kitti_bin,
    write_kitti_poses,
    write_pcd,
    write_tum,
)
from scanreg.io.sequences import natural_sorted, parse_sim_spec, time_in_seconds

KITTI = "kitti-odometry-00-frames-000-015"


# --------------------------------------------------------------------------- real KITTI


def test_kitti_real_frames() -> None:
    root = data_dir(KITTI)
    seq = open_sequence(root)
    assert isinstance(seq, KittiSequence)
    assert len(seq) == 16
    files = sorted((root / "velodyne").glob("*.bin"))
    for frame, f in zip(seq, files, strict=True):
        # every frame: as many points as the file holds records (16 bytes each)
        assert len(frame) == f.stat().st_size // 16
        assert frame.timestamps is None  # KITTI scans are motion-compensated
        assert frame.source == f.name
    assert len(seq[0]) == 124_668
    np.testing.assert_array_equal(seq[3].points, read_kitti_bin(files[3]).points)
    assert seq[-1].index == 15
    times = np.loadtxt(root / "times.txt")
    assert [f.stamp for f in (seq[0], seq[5])] == [times[0], times[5]]

    gt = seq.ground_truth
    assert gt is not None and gt.shape == (16, 4, 4)
    np.testing.assert_allclose(gt[0], np.eye(4), atol=1e-6)
    for k in range(15):
        step = np.linalg.inv(gt[k]) @ gt[k + 1]
        # the car drives forward: ~0.86 m along +x of the LiDAR frame, little sideways/up
        assert 0.8 < step[0, 3] < 0.95, step[:3, 3]
        assert abs(step[1, 3]) < 0.1 and abs(step[2, 3]) < 0.1
        yaw = np.degrees(np.arctan2(step[1, 0], step[0, 0]))
        assert abs(yaw) < 0.5
    # back to camera 0: the file's poses
    assert seq.T_cam0_velo is not None
    cam = lidar_to_camera_poses(gt, seq.T_cam0_velo)
    raw = np.loadtxt(root / "poses.txt").reshape(-1, 3, 4)
    np.testing.assert_allclose(cam[:, :3, :], raw, atol=1e-9)


def test_describe_real_kitti() -> None:
    info = describe_sequence(open_sequence(data_dir(KITTI)))
    assert info["frames"] == 16 and info["ground_truth"] is True
    assert info["points_per_frame"]["0"] == 124_668
    assert info["per_point_time"] is False
    assert 12.0 < info["ground_truth_length_m"] < 15.0


# --------------------------------------------------------------------------- synthetic KITTI


def _random_pose(rng: np.random.Generator, scale: float = 1.0) -> SE3:
    return SE3.exp(np.concatenate([rng.normal(0, scale, 3), rng.normal(0, 0.3, 3)]))


def _calib_text(tr: SE3) -> str:
    proj = " ".join(["1.0", "0", "0", "0", "0", "1.0", "0", "0", "0", "0", "1.0", "0"])
    tr_row = " ".join(f"{v:.15e}" for v in tr.as_matrix()[:3].ravel())
    return f"P0: {proj}\nP1: {proj}\nTr: {tr_row}\n"


def make_kitti(
    root: Path, n: int = 4, *, layout: str = "flat", seed: int = 0, points: int = 50
) -> tuple[Path, SE3, Any]:
    """A KITTI folder with ``n`` random scans, a random Tr and random LiDAR-frame truth.

    ``layout``: ``flat`` (poses.txt in the folder, like the shared data) or ``official``
    (``dataset/sequences/07`` + ``dataset/poses/07.txt``). Returns (folder, Tr, truth)."""
    rng = np.random.default_rng(seed)
    seq = root / "dataset" / "sequences" / "07" if layout == "official" else root / "seq"
    (seq / "velodyne").mkdir(parents=True)
    for k in range(n):
        cloud = PointCloud(
            rng.normal(0, 10, (points + k, 3)), intensity=rng.uniform(0, 1, points + k)
        )
        write_kitti_bin(seq / "velodyne" / f"{k:06d}.bin", cloud)
    tr = _random_pose(rng)
    truth = np.stack([np.eye(4)] + [_random_pose(rng, 5.0).as_matrix() for _ in range(n - 1)])
    cam = tr.as_matrix() @ truth @ np.linalg.inv(tr.as_matrix())
    (seq / "calib.txt").write_text(_calib_text(tr))
    np.savetxt(seq / "times.txt", 0.1 * np.arange(n) + 0.05)
    poses = seq / "poses.txt"
    if layout == "official":
        (root / "dataset" / "poses").mkdir()
        poses = root / "dataset" / "poses" / "07.txt"
    write_kitti_poses(poses, Trajectory(cam))
    return seq, tr, truth


@pytest.mark.parametrize("layout", ["flat", "official"])
def test_kitti_synthetic_frame_conversion(tmp_path: Path, layout: str) -> None:
    root, tr, truth = make_kitti(tmp_path, layout=layout)
    seq = open_sequence(root)
    assert isinstance(seq, KittiSequence) and len(seq) == 4
    assert seq.ground_truth is not None
    # T_velo = Tr⁻¹ · P · Tr recovers the LiDAR-frame truth the camera poses were made from
    np.testing.assert_allclose(seq.ground_truth, truth, atol=1e-9)
    assert seq.T_cam0_velo is not None
    np.testing.assert_allclose(seq.T_cam0_velo.as_matrix(), tr.as_matrix(), atol=1e-12)
    back = lidar_to_camera_poses(seq.ground_truth, tr)
    np.testing.assert_allclose(
        back, tr.as_matrix() @ truth @ np.linalg.inv(tr.as_matrix()), atol=1e-9
    )
    assert [len(f) for f in seq] == [50, 51, 52, 53]
    assert seq[2].stamp == pytest.approx(0.25)
    assert seq.ground_truth_trajectory() is not None


def test_kitti_without_poses_or_times(tmp_path: Path) -> None:
    root, _, _ = make_kitti(tmp_path)
    (root / "poses.txt").unlink()
    (root / "times.txt").unlink()
    seq = KittiSequence(root)
    assert seq.ground_truth is None
    assert seq[3].stamp == pytest.approx(0.3)  # the default 10 Hz


def test_kitti_explicit_poses_override(tmp_path: Path) -> None:
    root, tr, truth = make_kitti(tmp_path)
    other = tmp_path / "other.txt"
    shifted = truth.copy()
    shifted[:, 0, 3] += 1.0
    write_kitti_poses(other, Trajectory(tr.as_matrix() @ shifted @ np.linalg.inv(tr.as_matrix())))
    seq = open_sequence(root, ground_truth=other)
    assert seq.ground_truth is not None
    np.testing.assert_allclose(seq.ground_truth, shifted, atol=1e-9)


# --------------------------------------------------------------------------- hostile KITTI


def test_kitti_missing_velodyne(tmp_path: Path) -> None:
    root, _, _ = make_kitti(tmp_path)
    shutil.rmtree(root / "velodyne")
    with pytest.raises(FileFormatError, match="velodyne"):
        open_sequence(root)
    with pytest.raises(FileFormatError, match="velodyne"):
        KittiSequence(root)


def test_kitti_calib_without_tr(tmp_path: Path) -> None:
    root, _, _ = make_kitti(tmp_path)
    text = (root / "calib.txt").read_text().splitlines()
    (root / "calib.txt").write_text("\n".join(line for line in text if not line.startswith("Tr")))
    with pytest.raises(FileFormatError, match=r"calib\.txt: no Tr"):
        open_sequence(root)


def test_kitti_poses_without_calib(tmp_path: Path) -> None:
    root, _, _ = make_kitti(tmp_path)
    (root / "calib.txt").unlink()
    with pytest.raises(FileFormatError, match=r"no calib\.txt"):
        open_sequence(root)


def test_kitti_truncated_bin(tmp_path: Path) -> None:
    root, _, _ = make_kitti(tmp_path)
    f = root / "velodyne" / "000002.bin"
    f.write_bytes(f.read_bytes()[:-3])
    with pytest.raises(FileFormatError, match=r"000002\.bin.*multiple of 16"):
        open_sequence(root)


def test_kitti_extra_frame_mismatches_poses(tmp_path: Path) -> None:
    root, _, _ = make_kitti(tmp_path)
    shutil.copy(root / "velodyne" / "000003.bin", root / "velodyne" / "000004.bin")
    with pytest.raises(FileFormatError, match=r"times\.txt: 4 times for 5 frames"):
        open_sequence(root)
    (root / "times.txt").unlink()
    with pytest.raises(FileFormatError, match=r"poses\.txt: 4 poses for 5 frames"):
        open_sequence(root)


def test_kitti_missing_frame_in_numbering(tmp_path: Path) -> None:
    root, _, _ = make_kitti(tmp_path)
    (root / "velodyne" / "000001.bin").unlink()
    with pytest.raises(FileFormatError, match=r"not consecutive.*000002\.bin"):
        open_sequence(root)


def test_kitti_corrupt_pose_file(tmp_path: Path) -> None:
    root, _, _ = make_kitti(tmp_path)
    lines = (root / "poses.txt").read_text().splitlines()
    lines[2] = lines[2].rsplit(" ", 1)[0]  # 11 numbers
    (root / "poses.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(FileFormatError, match=r"poses\.txt: line 3: 11 values"):
        open_sequence(root)


def test_kitti_velodyne_folder_given_and_flat_kitti_refused(tmp_path: Path) -> None:
    root, _, truth = make_kitti(tmp_path)
    seq = open_sequence(root / "velodyne")
    assert isinstance(seq, KittiSequence) and seq.ground_truth is not None
    np.testing.assert_allclose(seq.ground_truth, truth, atol=1e-9)
    # scans next to calib.txt and camera-0 poses.txt: refused rather than misread as LiDAR poses
    for f in (root / "velodyne").iterdir():
        f.rename(root / f.name)
    (root / "velodyne").rmdir()
    with pytest.raises(FileFormatError, match=r"has calib\.txt and poses\.txt"):
        open_sequence(root)


def test_kitti_calib_but_no_velodyne_folder(tmp_path: Path) -> None:
    (tmp_path / "calib.txt").write_text("Tr: 1 0 0 0 0 1 0 0 0 0 1 0\n")
    with pytest.raises(FileFormatError, match="no velodyne/"):
        open_sequence(tmp_path)


def test_open_sequence_rejects_unknown(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="nowhere"):
        open_sequence(tmp_path / "nowhere")
    f = tmp_path / "scan.pcd"
    f.write_text("x")
    with pytest.raises(FileFormatError, match=r"scan\.pcd: not a sequence"):
        open_sequence(f)
    (tmp_path / "empty").mkdir()
    with pytest.raises(FileFormatError, match="no point files"):
        open_sequence(tmp_path / "empty")


# --------------------------------------------------------------------------- folders


def test_natural_sort() -> None:
    names = ["10.pcd", "2.pcd", "1.pcd", "scan_11.pcd", "scan_9.pcd"]
    got = [p.name for p in natural_sorted(names)]
    assert got == ["1.pcd", "2.pcd", "10.pcd", "scan_9.pcd", "scan_11.pcd"]


def _ouster_like(rng: np.random.Generator, n: int) -> PointCloud:
    # Ouster t: uint32 nanoseconds since the sweep start
    t_ns = np.sort(rng.integers(0, 100_000_000, n)).astype(np.float64)
    return PointCloud(rng.normal(0, 5, (n, 3)), time=t_ns)


def test_folder_of_pcd_with_point_time_and_tum_truth(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    clouds = [_ouster_like(rng, 30 + k) for k in range(11)]
    for k, c in enumerate(clouds):
        write_pcd(tmp_path / f"{k}.pcd", c)  # 0.pcd … 10.pcd: 10 sorts after 9
    (tmp_path / "notes.md").write_text("not a scan")
    poses = [_random_pose(rng) for _ in clouds]
    stamps = 100.0 + 0.1 * np.arange(len(clouds))
    write_tum(tmp_path / "poses_tum.txt", Trajectory.from_poses(poses, stamps))
    seq = open_sequence(tmp_path)
    assert isinstance(seq, FolderSequence) and len(seq) == 11
    assert [f.source for f in seq][-2:] == ["9.pcd", "10.pcd"]
    for frame, cloud, stamp in zip(seq, clouds, stamps, strict=True):
        np.testing.assert_allclose(frame.points, cloud.points)
        assert frame.timestamps is not None and cloud.time is not None
        np.testing.assert_allclose(frame.timestamps, cloud.time * 1e-9)  # ns → s
        assert frame.stamp == pytest.approx(stamp)
    assert seq.ground_truth is not None
    np.testing.assert_allclose(seq.ground_truth, [p.as_matrix() for p in poses], atol=1e-9)
    info = describe_sequence(seq)
    assert info["per_point_time"] is True and 0.05 < info["sweep_time_span_s"] < 0.1


def test_folder_drops_nonfinite_points_and_keeps_time_aligned(tmp_path: Path) -> None:
    pts = np.array([[1.0, 2, 3], [np.nan, 0, 0], [4, 5, 6]])
    write_pcd(tmp_path / "a.pcd", PointCloud(pts, time=np.array([0.0, 0.01, 0.02])))
    frame = open_sequence(tmp_path)[0]
    np.testing.assert_array_equal(frame.points, [[1, 2, 3], [4, 5, 6]])
    assert frame.timestamps is not None
    np.testing.assert_allclose(frame.timestamps, [0.0, 0.02])


def test_folder_hostile(tmp_path: Path) -> None:
    rng = np.random.default_rng(2)
    for k in range(3):
        write_kitti_bin(tmp_path / f"{k:06d}.bin", PointCloud(rng.normal(0, 1, (5, 3))))
    write_pcd(tmp_path / "extra.pcd", PointCloud(rng.normal(0, 1, (5, 3))))
    with pytest.raises(FileFormatError, match=r"several formats \(\.bin, \.pcd\)"):
        open_sequence(tmp_path)
    (tmp_path / "extra.pcd").unlink()
    gt = tmp_path / "gt.txt"
    write_kitti_poses(gt, Trajectory(np.tile(np.eye(4), (2, 1, 1))))
    with pytest.raises(FileFormatError, match=r"gt\.txt: 2 poses for 3 frames"):
        open_sequence(tmp_path, ground_truth=gt)
    gt.write_text("1 2 3\n")
    with pytest.raises(FileFormatError, match="neither TUM"):
        open_sequence(tmp_path, ground_truth=gt)
    seq = open_sequence(tmp_path)
    (tmp_path / "000001.bin").write_bytes(b"\0" * 17)  # truncated after opening
    with pytest.raises(FileFormatError, match=r"000001\.bin"):
        seq[1]
    with pytest.raises(IndexError, match="3 frames"):
        seq[3]
    with pytest.raises(TypeError, match="index"):
        seq["1"]  # type: ignore[index]


@pytest.mark.parametrize(
    ("values", "unit", "stamp", "expected"),
    [
        ([0.0, 0.05, 0.099], "auto", None, [0.0, 0.05, 0.099]),  # seconds
        ([0.0, 50.0, 99.0], "auto", None, [0.0, 0.05, 0.099]),  # milliseconds
        ([0.0, 5e4, 9.9e4], "auto", None, [0.0, 0.05, 0.099]),  # microseconds
        ([0.0, 5e7, 9.9e7], "auto", None, [0.0, 0.05, 0.099]),  # nanoseconds (Ouster t)
        ([-0.1, -0.05, 0.0], "auto", None, [-0.1, -0.05, 0.0]),  # stamped at the sweep end
        ([1.7e9 + 0.01, 1.7e9 + 0.06], "auto", 1.7e9, [0.01, 0.06]),  # absolute seconds
        ([1.7e18 + 1e7, 1.7e18 + 6e7], "auto", 1.7e9, [0.01, 0.06]),  # absolute nanoseconds
        ([0.0, 1.0, 2.0, 3.0], "s", None, [0.0, 1.0, 2.0, 3.0]),  # explicit unit wins
        ([0.0, 5.0], "ms", None, [0.0, 0.005]),
    ],
)
def test_time_units(values: list[float], unit: Any, stamp: Any, expected: list[float]) -> None:
    np.testing.assert_allclose(time_in_seconds(values, unit, stamp), expected, atol=1e-6)


def test_time_unit_rejected() -> None:
    with pytest.raises(ValueError, match="time_unit"):
        time_in_seconds([0.0], "minutes")  # type: ignore[arg-type]


# --------------------------------------------------------------------------- ROS bags


@pytest.mark.parametrize(
    ("kind", "field", "scale", "datatype"),
    [
        ("sqlite3", "t", 1e9, "<u4"),  # Ouster: uint32 ns
        ("mcap", "offset_time", 1e9, "<u4"),  # Livox: uint32 ns
        ("ros1", "time", 1.0, "<f4"),  # Velodyne: float32 s
        ("ros1-lz4", "timestamp", 1.0, "<f8"),  # Hesai: float64 absolute s
    ],
)
def test_bag_sequence_round_trip(
    tmp_path: Path, kind: str, field: str, scale: float, datatype: str
) -> None:
    pytest.importorskip("rosbags")
    from test_rosbag import _cloud_msg, _store, write_bag

    ts = _store(kind)
    root = data_dir(KITTI)
    t0 = 1_700_000_000_000_000_000
    msgs, expected = [], []
    for k in range(3):
        cloud = read_kitti_bin(root / "velodyne" / f"{k:06d}.bin")
        pts = cloud.points[:: 40 + k]
        rel = (np.arctan2(pts[:, 1], pts[:, 0]) + np.pi) / (2 * np.pi) * 0.1  # s in the sweep
        stamp_ns = t0 + k * 100_000_000
        dt = np.dtype(
            [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4"), (field, datatype)]
        )
        rec = np.zeros(len(pts), dt)
        rec["x"], rec["y"], rec["z"] = pts.T
        assert cloud.intensity is not None
        rec["intensity"] = cloud.intensity[:: 40 + k]
        absolute = field == "timestamp"
        if absolute:
            rec[field] = stamp_ns * 1e-9 + rel
        else:
            rec[field] = np.round(rel * scale) if datatype == "<u4" else rel
        msgs.append((stamp_ns + 1000, _cloud_msg(ts, kind, rec, stamp_ns)))
        expected.append((rec, rel, stamp_ns * 1e-9))
    path = write_bag(tmp_path / "drive", kind, {"/points": ("sensor_msgs/msg/PointCloud2", msgs)})

    seq = open_sequence(path)
    assert isinstance(seq, RosbagSequence) and len(seq) == 3 and seq.topic == "/points"
    frames = list(seq)
    assert len(frames) == 3
    for frame, (rec, rel, stamp) in zip(frames, expected, strict=True):
        xyz = np.column_stack([rec["x"], rec["y"], rec["z"]]).astype(np.float64)
        np.testing.assert_array_equal(frame.points, xyz)
        assert frame.stamp == pytest.approx(stamp, abs=1e-6)
        assert frame.timestamps is not None
        # ns fields are integers: within half a ns; float32 s: float32 rounding; f8 absolute: ~µs
        np.testing.assert_allclose(frame.timestamps, rel, atol=1e-6)
        assert frame.intensity is not None
        np.testing.assert_array_equal(frame.intensity, rec["intensity"].astype(np.float64))
    np.testing.assert_array_equal(seq[1].points, frames[1].points)
    info = describe_sequence(seq, max_frames=1)
    assert info["frames"] == 3 and info["per_point_time"] is True


def test_bag_sequence_topics_and_truth(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("rosbags")
    from test_rosbag import _cloud_msg, _store, write_bag

    ts = _store("sqlite3")
    rec = np.zeros(4, np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4")]))
    rec["x"] = [1, 2, 3, 4]
    msgs = [(k, _cloud_msg(ts, "sqlite3", rec, k)) for k in range(2)]
    topics = {
        "/a": ("sensor_msgs/msg/PointCloud2", msgs),
        "/b": ("sensor_msgs/msg/PointCloud2", msgs),
    }
    path = write_bag(tmp_path / "two", "sqlite3", topics)
    with pytest.raises(ValueError, match="several PointCloud2 topics"):
        open_sequence(path)
    with pytest.raises(ValueError, match="no PointCloud2 topic '/c'"):
        open_sequence(path, topic="/c")
    seq = open_sequence(path, topic="/b")
    assert len(seq) == 2 and seq[1].timestamps is None
    # scanreg info: the bag's topics, and the chosen topic summarised as a sequence
    from scanreg import cli

    assert cli.main(["info", str(path), "--json"]) == cli.EXIT_OK
    assert "sequence" not in json.loads(capsys.readouterr().out)  # two topics, none chosen
    assert cli.main(["info", str(path), "--topic", "/b", "--json"]) == cli.EXIT_OK
    out = json.loads(capsys.readouterr().out)
    assert out["kind"] == "bag" and out["sequence"]["frames"] == 2
    assert out["sequence"]["points_per_frame"] == {"0": 4}
    gt = tmp_path / "gt.txt"
    write_kitti_poses(gt, Trajectory(np.tile(np.eye(4), (3, 1, 1))))
    with pytest.raises(FileFormatError, match="3 poses for 2 frames"):
        open_sequence(path, topic="/b", ground_truth=gt)


# --------------------------------------------------------------------------- simulation


def test_simulated_street() -> None:
    seq = open_sequence("sim:street")
    assert isinstance(seq, SimulatedSequence) and len(seq) == 100
    gt = seq.ground_truth
    assert gt.shape == (100, 4, 4)
    np.testing.assert_allclose(gt[0], np.eye(4), atol=1e-12)
    steps = np.linalg.norm(np.diff(gt[:, :3, 3], axis=0), axis=1)
    np.testing.assert_allclose(steps, 1.0, rtol=1e-3)  # 10 m/s, 10 Hz
    assert np.abs(gt[:, 1, 3]).max() < 3.0  # the weave stays in the lane
    for k in (0, 99):
        frame = seq[k]
        assert len(frame) > 10_000
        assert frame.timestamps is not None
        assert frame.timestamps.min() >= 0.0 and frame.timestamps.max() < 0.1
        assert frame.stamp == pytest.approx(0.1 * k)
        # the truth is the sweep-start pose relative to the first sweep
        sweep = seq.sweep(k)
        rel = seq.sweep(0).pose.inverse() @ sweep.pose
        np.testing.assert_allclose(rel.as_matrix(), gt[k], atol=1e-9)
        # motion-distorted: the driver's points differ from the deskewed ones by the motion
        shift = np.linalg.norm(sweep.points - sweep.points_deskewed, axis=1)
        assert 0.5 < shift.max() < 2.0
    np.testing.assert_array_equal(seq[5].points, seq[5].points)  # deterministic


def test_simulated_tunnel_spec() -> None:
    seq = open_sequence("sim:tunnel,frames=120,speed=5,seed=2")
    assert isinstance(seq, SimulatedSequence)
    assert len(seq) == 120 and seq.name == "sim:tunnel"
    assert seq.ground_truth[-1][0, 3] == pytest.approx(119 * 0.5)
    assert np.abs(seq.ground_truth[:, 1:3, 3]).max() < 1e-9  # straight along the axis


@pytest.mark.parametrize(
    ("spec", "match"),
    [
        ("sim:forest", "unknown scene 'forest'"),
        ("sim:street,frame=3", "bad option 'frame=3'"),
        ("sim:street,frames=many", "frames must be int"),
        ("sim:street,frames", "bad option"),
    ],
)
def test_sim_spec_errors(spec: str, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        open_sequence(spec)


def test_sim_spec_parse() -> None:
    assert parse_sim_spec("sim:street,frames=150,sensor=hdl64,weave=0") == {
        "scene": "street",
        "num_frames": 150,
        "sensor": "hdl64",
        "weave": 0.0,
    }
    with pytest.raises(ValueError, match="unknown LiDAR preset"):
        SimulatedSequence("street", sensor="hdl128")


# --------------------------------------------------------------------------- fuzz


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    target=st.sampled_from(["calib.txt", "poses.txt", "times.txt", "velodyne/000001.bin"]),
    content=st.binary(max_size=300)
    | st.text(alphabet="0123456789.-e: \nTrP", max_size=300).map(str.encode),
)
def test_kitti_fuzzed_files_fail_cleanly(target: str, content: bytes) -> None:
    """Whatever a KITTI folder's files hold, opening and reading it either works or raises a
    FileFormatError naming a file of the folder — never another exception."""
    with tempfile.TemporaryDirectory() as tmp:
        root, _, _ = make_kitti(Path(tmp), n=3, points=5)
        (root / target).write_bytes(content)
        try:
            seq = open_sequence(root)
            frames = list(seq)
        except FileFormatError as exc:
            assert str(exc).startswith(str(root))
            return
        assert len(frames) == 3 and all(np.isfinite(f.points).all() for f in frames)


def test_simulated_sequence_can_start_from_rest() -> None:
    from scanreg.io.sequences import SimulatedSequence

    seq = SimulatedSequence("street", num_frames=30, ramp=2.0)
    steps = np.linalg.norm(np.diff(seq.ground_truth[:, :3, 3], axis=0), axis=1)
    # 10 m/s reached after 2 s at constant acceleration: 0.1 s frames move 0.025, 0.075, ...
    np.testing.assert_allclose(steps[:3], [0.025, 0.075, 0.125], atol=2e-3)
    np.testing.assert_allclose(steps[-5:], 1.0, atol=2e-3)
    with pytest.raises(ValueError, match="ramp"):
        SimulatedSequence("street", num_frames=3, ramp=-1.0)
