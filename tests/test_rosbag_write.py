"""ROS 2 bags written by scanreg (mcap, sqlite3, bag folder), read back with rosbags and — for
mcap — with the independent ``mcap`` + ``mcap-ros2-support`` decoders: poses, covariances in
the ROS convention, tf chain, clouds, loop markers; bad input leaves no file behind."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scanreg import SE3, interop

pytest.importorskip("rosbags", reason="rosbags is not installed (pip install 'scanreg[ros]')")

from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore
from scanreg.io import PointCloud, read_bag_clouds
from scanreg.io import rosbag_write as rw
from scanreg.io.rosbag_write import BagFrames, BagGrid, BagTopics, LoopClosure, write_run_bag

K = 6
#: σ = 1 m along the body x axis, everything else small (m, rad).
BODY_COV = np.diag([1.0, 1e-4, 4e-4, 1e-6, 2e-6, 3e-6])


def _run() -> dict[str, Any]:
    # the sensor drives along world x, then turns: frame 3 has yaw = 90° exactly
    yaws = np.array([0.0, 0.0, 0.5, np.pi / 2, np.pi / 2, np.pi / 2])
    poses = [SE3.from_vector([1.5 * k, 0.2 * k, 0.1, 0, 0, yaws[k]]) for k in range(K)]
    covs = np.array([BODY_COV] * K)
    covs[0] = np.inf  # the first frame has no registration
    rng = np.random.default_rng(0)
    scans = [
        PointCloud(points=rng.normal(size=(50 + k, 3)), intensity=rng.uniform(0, 255, 50 + k))
        for k in range(K)
    ]
    return {
        "stamps": 1.7e9 + 0.1 * np.arange(K),
        "poses": poses,
        "covariances": covs,
        "scans": scans,
        "map_points": rng.normal(size=(200, 3)) * 10,
        "loops": [(0, 5, True), LoopClosure(1, 4, accepted=False)],
    }


def _messages(path: Path) -> dict[str, list[Any]]:
    store = get_typestore(Stores.LATEST)
    out: dict[str, list[Any]] = {}
    with Reader(path) as reader:
        for conn, _, data in reader.messages():
            out.setdefault(conn.topic, []).append(store.deserialize_cdr(data, conn.msgtype))
    return out


@pytest.mark.parametrize("name", ["run.mcap", "run.db3", "run_folder"])
def test_bag_round_trip_with_rosbags(tmp_path: Path, name: str) -> None:
    run = _run()
    path = tmp_path / name
    summary = write_run_bag(path, **run)
    assert summary.path == path and path.exists()
    assert summary.storage == ("sqlite3" if name.endswith(".db3") else "mcap")
    assert sorted(os.listdir(tmp_path)) == [name]  # no staging folder left
    msgs = _messages(path)
    assert {t: len(v) for t, v in msgs.items()} == summary.messages
    assert len(msgs["/scanreg/odometry"]) == K and len(msgs["/scanreg/map"]) == 1
    for k, (odo, pose) in enumerate(
        zip(msgs["/scanreg/odometry"], msgs["/scanreg/pose"], strict=True)
    ):
        assert (odo.header.frame_id, odo.child_frame_id) == ("odom", "lidar")
        assert pose.header.frame_id == "map"
        assert odo.header.stamp.sec * 1_000_000_000 + odo.header.stamp.nanosec == round(
            run["stamps"][k] * 1e9
        )
        got, cov = interop.from_ros_pose_with_covariance(pose.pose)
        assert got.is_close(run["poses"][k], atol=1e-12)
        if k == 0:  # unknown: a large diagonal, not inf
            assert np.array_equal(pose.pose.covariance, np.diag(np.full(6, 1e6)).reshape(36))
        else:
            np.testing.assert_allclose(cov, BODY_COV, atol=1e-15)
    # tf: map → odom (identity for plain odometry) → lidar composes to the pose
    for k, tf in enumerate(msgs["/tf"]):
        (m_o, o_s) = tf.transforms
        assert (m_o.header.frame_id, m_o.child_frame_id) == ("map", "odom")
        assert (o_s.header.frame_id, o_s.child_frame_id) == ("odom", "lidar")
        t = o_s.transform.translation
        np.testing.assert_allclose([t.x, t.y, t.z], run["poses"][k].translation, atol=1e-12)
    # scans: float32 points and intensity in the sensor frame
    clouds = read_bag_clouds(path, topic="/scanreg/scan")
    for cloud, src in zip(clouds, run["scans"], strict=True):
        assert cloud.frame_id == "lidar"
        np.testing.assert_allclose(cloud.cloud.points, src.points, atol=1e-6, rtol=1e-6)
        np.testing.assert_allclose(cloud.cloud.intensity, src.intensity, rtol=1e-6)
    (the_map,) = read_bag_clouds(path, topic="/scanreg/map")
    assert the_map.frame_id == "map" and len(the_map.cloud) == 200
    (path_msg,) = msgs["/scanreg/path"]
    assert len(path_msg.poses) == K
    (markers,) = msgs["/scanreg/loop_closures"]
    accepted, rejected = markers.markers
    ends = [[p.x, p.y, p.z] for p in accepted.points]
    np.testing.assert_allclose(ends, [run["poses"][0].translation, run["poses"][5].translation])
    assert (accepted.color.g, rejected.color.r) == (pytest.approx(0.8), pytest.approx(0.9))
    assert len(rejected.points) == 2


def test_covariance_lands_on_the_ros_axis_at_90_degrees_yaw(tmp_path: Path) -> None:
    """Large along the body x axis with yaw = 90°: in ROS (parent frame) it is world y."""
    run = _run()
    path = tmp_path / "run.mcap"
    write_run_bag(path, **run)
    pose_cov = np.array(_messages(path)["/scanreg/pose"][3].pose.covariance).reshape(6, 6)
    assert pose_cov[1, 1] == pytest.approx(1.0, abs=1e-12)  # world y: the large one
    assert pose_cov[0, 0] == pytest.approx(1e-4, abs=1e-12)  # world x: body y's variance
    assert pose_cov[2, 2] == pytest.approx(4e-4, abs=1e-12)
    # rotations follow the same map: body roll ↔ world pitch about the rotated axes
    assert pose_cov[3, 3] == pytest.approx(2e-6) and pose_cov[4, 4] == pytest.approx(1e-6)
    # the twist is in the child frame: no rotation, scaled by 1/Δt²
    odo = _messages(path)["/scanreg/odometry"][3]
    twist_cov = np.array(odo.twist.covariance).reshape(6, 6)
    np.testing.assert_allclose(twist_cov, BODY_COV / 0.1**2, rtol=1e-6)


def test_mcap_reads_with_the_independent_mcap_ros2_decoder(tmp_path: Path) -> None:
    mcap_reader = pytest.importorskip("mcap.reader", reason="mcap is not installed (dev extra)")
    decoder = pytest.importorskip(
        "mcap_ros2.decoder", reason="mcap-ros2-support is not installed (dev extra)"
    )
    run = _run()
    path = tmp_path / "run.mcap"
    write_run_bag(
        path,
        **run,
        frames=BagFrames(map="world", odom="odom_lio", sensor="velodyne"),
        topics=BagTopics(odometry="lio/odom", map="/lio/map"),
    )
    seen: dict[str, list[Any]] = {}
    with path.open("rb") as fh:
        reader = mcap_reader.make_reader(fh, decoder_factories=[decoder.DecoderFactory()])
        for schema, channel, _, msg in reader.iter_decoded_messages():
            seen.setdefault(channel.topic, []).append((schema.name, msg))
    assert seen["/lio/odom"][0][0] == "nav_msgs/msg/Odometry"  # relative name → root namespace
    _, odo = seen["/lio/odom"][3]
    assert (odo.header.frame_id, odo.child_frame_id) == ("odom_lio", "velodyne")
    cov = np.array(odo.pose.covariance).reshape(6, 6)
    assert np.argmax(np.diag(cov)) == 1 and cov[1, 1] == pytest.approx(1.0)
    q = odo.pose.pose.orientation
    np.testing.assert_allclose([q.x, q.y, q.z, q.w], [0, 0, np.sqrt(0.5), np.sqrt(0.5)], atol=1e-12)
    _, the_map = seen["/lio/map"][0]
    assert the_map.header.frame_id == "world" and the_map.width == 200
    _, tf = seen["/tf"][0]
    assert [t.child_frame_id for t in tf.transforms] == ["odom_lio", "velodyne"]
    _, markers = seen["/scanreg/loop_closures"][0]
    assert markers.markers[0].type == 5 and len(markers.markers[0].points) == 2


def test_map_frame_differs_from_odom_after_a_correction(tmp_path: Path) -> None:
    run = _run()
    correction = SE3.from_vector([0.5, -0.2, 0, 0, 0, 0.05])
    odometry = [correction.inverse() @ p for p in run["poses"]]
    path = tmp_path / "run.mcap"
    write_run_bag(path, **run, odometry_poses=odometry, scan_frame="map")
    msgs = _messages(path)
    m_o = msgs["/tf"][2].transforms[0].transform
    np.testing.assert_allclose(
        [m_o.translation.x, m_o.translation.y], correction.translation[:2], atol=1e-12
    )
    odo = msgs["/scanreg/odometry"][2].pose.pose.position
    np.testing.assert_allclose([odo.x, odo.y, odo.z], odometry[2].translation, atol=1e-12)
    cloud = read_bag_clouds(path, topic="/scanreg/scan")[2]
    assert cloud.frame_id == "map"
    np.testing.assert_allclose(
        cloud.cloud.points, run["poses"][2].apply(run["scans"][2].points), atol=1e-4
    )


@pytest.mark.parametrize(
    ("topics", "message"),
    [
        ({"odometry": "/scanreg/2d"}, "token '2d' starts with a digit"),
        ({"pose": "/scan reg"}, "has characters other than"),
        ({"map": "/a//b"}, "contains '//'"),
        ({"path": "/path/"}, "ends with '/'"),
        ({"tf": ""}, "is empty"),
        ({"scan": "/odom~"}, "has characters other than"),
        ({"scan": "/scanreg/odometry"}, "every topic name must differ"),
    ],
)
def test_invalid_topic_names_are_refused(
    tmp_path: Path, topics: dict[str, str], message: str
) -> None:
    with pytest.raises(ValueError, match=message):
        write_run_bag(tmp_path / "run.mcap", **_run(), topics=BagTopics(**topics))
    assert os.listdir(tmp_path) == []


def test_bad_frames_and_inputs_are_refused_naming_the_argument(tmp_path: Path) -> None:
    run = _run()
    with pytest.raises(ValueError, match=r"frames.sensor: '/lidar' is not a valid tf2 frame"):
        BagFrames(sensor="/lidar")
    with pytest.raises(ValueError, match="frames: the three frame ids must differ"):
        BagFrames(map="odom")
    with pytest.raises(ValueError, match=r"scans: expected 6 clouds"):
        write_run_bag(tmp_path / "a.mcap", **{**run, "scans": run["scans"][:3]})
    with pytest.raises(ValueError, match=r"covariances: expected shape \(6, 6, 6\)"):
        write_run_bag(tmp_path / "a.mcap", **{**run, "covariances": np.eye(6)})
    with pytest.raises(ValueError, match="stamps: must be finite, >= 0 and non-decreasing"):
        write_run_bag(tmp_path / "a.mcap", **{**run, "stamps": run["stamps"][::-1]})
    with pytest.raises(ValueError, match=r"loops\[0\]: frame index 9 is not in \[0, 6\)"):
        write_run_bag(tmp_path / "a.mcap", **{**run, "loops": [(0, 9)]})
    with pytest.raises(ValueError, match=r"storage: 'sqlite3' does not match"):
        write_run_bag(tmp_path / "a.mcap", **run, storage="sqlite3")
    nan_scan = [*run["scans"][:5], np.full((3, 3), np.nan)]
    with pytest.raises(ValueError, match=r"scans\[5\]: holds NaN"):
        write_run_bag(tmp_path / "a.mcap", **{**run, "scans": nan_scan})
    assert os.listdir(tmp_path) == []


def test_unwritable_destinations_are_clear_errors(tmp_path: Path) -> None:
    run = _run()
    blocker = tmp_path / "file.txt"
    blocker.write_text("x")
    with pytest.raises(FileNotFoundError, match=r"cannot write a bag there: no folder .*file.txt"):
        write_run_bag(blocker / "run.mcap", **run)
    with pytest.raises(FileNotFoundError, match="no folder"):
        write_run_bag(tmp_path / "missing" / "run.mcap", **run)
    # a folder no one can create files in, even root (a virtual file system)
    with pytest.raises(PermissionError, match=r"/proc/run.mcap: cannot write a bag there"):
        write_run_bag("/proc/run.mcap", **run)
    with pytest.raises(FileExistsError, match="pass overwrite=True"):
        write_run_bag(blocker, **run, storage="mcap")
    assert blocker.read_text() == "x"
    # a folder that is not a bag is never replaced, even with overwrite=True
    (tmp_path / "results").mkdir()
    (tmp_path / "results" / "poses.txt").write_text("keep")
    with pytest.raises(FileExistsError, match="is not a ROS 2 bag folder"):
        write_run_bag(tmp_path / "results", **run, overwrite=True)
    assert (tmp_path / "results" / "poses.txt").read_text() == "keep"
    write_run_bag(tmp_path / "bag", **run)
    write_run_bag(tmp_path / "bag", **run, overwrite=True)  # a bag folder is replaced
    assert sorted(os.listdir(tmp_path / "bag")) == ["bag.mcap", "metadata.yaml"]


def test_a_failure_mid_write_leaves_nothing_and_keeps_the_old_bag(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    run = _run()
    path = tmp_path / "run.mcap"
    write_run_bag(path, **run)
    before = path.read_bytes()
    calls = 0
    original = rw._Messages.pointcloud2

    def failing(self: Any, *args: Any) -> Any:
        nonlocal calls
        calls += 1
        if calls == 3:
            raise OSError(28, "No space left on device")
        return original(self, *args)

    monkeypatch.setattr(rw._Messages, "pointcloud2", failing)
    with pytest.raises(OSError, match="No space left"):
        write_run_bag(path, **run, overwrite=True)
    assert sorted(os.listdir(tmp_path)) == ["run.mcap"]  # no staging folder, no partial bag
    assert path.read_bytes() == before
    calls = 0
    with pytest.raises(OSError, match="No space left"):
        write_run_bag(tmp_path / "new_folder", **run)
    assert sorted(os.listdir(tmp_path)) == ["run.mcap"]


def test_odometry_bag_scans_lie_on_the_map(tmp_path: Path) -> None:
    """`scanreg odometry --bag`: each scan placed by its /scanreg/pose lands on the bag's map;
    deskewed to the pose's time it lands closer than the sweep as read (measured 90th
    percentile of the distance to the map 0.045 m vs 0.10 m on sim:street)."""
    from scanreg import cli
    from scanreg._core import KdTree
    from scanreg.io import open_sequence

    out = tmp_path / "out"
    bag = out / "run.mcap"
    argv = ["odometry", "sim:street,frames=5", "-o", str(out), "--no-plots", "--quiet"]
    assert cli.main([*argv, "--bag", str(bag), "--bag-scan-voxel", "0"]) == cli.EXIT_OK
    poses = [interop.from_ros_pose_with_covariance(m.pose)[0]
             for m in _messages(bag)["/scanreg/pose"]]  # fmt: skip
    tree = KdTree(np.ascontiguousarray(read_bag_clouds(bag, topic="/scanreg/map")[0].cloud.points))
    scans = read_bag_clouds(bag, topic="/scanreg/scan")
    seq = open_sequence("sim:street,frames=5")
    for k in range(1, 5):
        placed = np.ascontiguousarray(poses[k].apply(scans[k].cloud.points))
        raw = np.ascontiguousarray(poses[k].apply(seq[k].points))
        near = np.percentile(tree.nearest(placed)[1], 90)
        far = np.percentile(tree.nearest(raw)[1], 90)
        assert near < 0.07 and near < 0.7 * far, (k, near, far)


def test_planar_runs_are_embedded_at_z_zero(tmp_path: Path) -> None:
    """SE(2) poses, 3×3 covariances and 2D scans (a CARMEN-style run) go in as planar."""
    from scanreg import SE2

    poses = [SE2.from_vector([k, 0.5 * k, np.pi / 2]) for k in range(3)]
    covs = np.array([np.diag([0.25, 1e-4, 1e-6])] * 3)  # large along the body x axis
    scans = [np.random.default_rng(k).normal(size=(20, 2)) for k in range(3)]
    path = tmp_path / "planar.mcap"
    write_run_bag(path, [0.0, 0.1, 0.2], poses, covariances=covs, scans=scans,
                  map_points=np.vstack(scans))  # fmt: skip
    msg = _messages(path)["/scanreg/pose"][1].pose
    pose, cov = interop.from_ros_pose2d_covariance(msg)
    assert pose.is_close(poses[1], atol=1e-12)
    np.testing.assert_allclose(cov, covs[1], atol=1e-15)
    ros = np.array(msg.covariance).reshape(6, 6)
    assert ros[1, 1] == pytest.approx(0.25) and ros[0, 0] == pytest.approx(1e-4)  # yaw 90°
    assert ros[2, 2] == ros[3, 3] == ros[4, 4] == 0.0
    cloud = read_bag_clouds(path, topic="/scanreg/scan")[2].cloud
    np.testing.assert_allclose(cloud.points[:, :2], scans[2], atol=1e-6)
    assert np.all(cloud.points[:, 2] == 0)
    # an occupancy grid for RViz's Map display: row 0 at the origin, percent, -1 unknown
    probability = np.full((4, 5), np.nan)
    probability[0, :] = 0.0
    probability[1, 2] = 1.0
    probability[3, 4] = 0.666
    grid = BagGrid(probability, 0.05, (-1.0, 2.5))
    write_run_bag(tmp_path / "grid.db3", [0.0, 0.1, 0.2], poses, grid=grid)
    (msg,) = _messages(tmp_path / "grid.db3")["/scanreg/grid"]
    assert (msg.info.width, msg.info.height) == (5, 4)
    assert msg.info.resolution == pytest.approx(0.05)
    assert (msg.info.origin.position.x, msg.info.origin.position.y) == (-1.0, 2.5)
    cells = np.asarray(msg.data).reshape(4, 5)
    assert (cells[0] == 0).all() and cells[1, 2] == 100 and cells[3, 4] == 67
    assert (cells[2] == -1).all() and msg.header.frame_id == "map"
    with pytest.raises(ValueError, match=r"grid.probability: must be in \[0, 1\] or NaN"):
        BagGrid(probability + 1, 0.05, (0, 0))
    with pytest.raises(ValueError, match=r"poses\[0\]: last row must be \[0, 0, 1\]"):
        write_run_bag(tmp_path / "x.mcap", [0.0], np.ones((1, 3, 3)))
