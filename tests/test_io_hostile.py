"""Corrupt, truncated and hostile files: a ValueError naming the file, nothing else.

The fuzz tests mutate valid files (truncation, byte changes, inserted bytes) and accept two
outcomes only: a consistent result or a ``ValueError`` whose message starts with the path.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
import scanreg.io as sio
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scanreg import SE3
from scanreg.io import FileFormatError, PointCloud, PoseGraph, PoseGraphEdge, Trajectory


def _cloud(n: int = 6) -> PointCloud:
    rng = np.random.default_rng(0)
    return PointCloud(
        points=rng.normal(size=(n, 3)),
        intensity=rng.uniform(0, 1, n),
        ring=rng.integers(0, 8, n),
        time=rng.uniform(0, 0.1, n),
    )


def _valid_files(folder: Path) -> dict[str, bytes]:
    cloud = _cloud()
    files: dict[str, bytes] = {}
    writers = {
        "a.pcd": lambda p: sio.write_pcd(p, cloud, data="ascii"),
        "b.pcd": lambda p: sio.write_pcd(p, cloud, data="binary"),
        "c.pcd": lambda p: sio.write_pcd(p, cloud, data="binary_compressed"),
        "a.ply": lambda p: sio.write_ply(p, cloud, data="ascii"),
        "b.ply": lambda p: sio.write_ply(p, cloud, data="binary_little_endian"),
        "c.ply": lambda p: sio.write_ply(p, cloud, data="binary_big_endian"),
        "a.bin": lambda p: sio.write_kitti_bin(p, cloud),
        "a.npy": lambda p: sio.write_npy(p, cloud),
        "a.npz": lambda p: sio.write_npz(p, cloud),
        "a.csv": lambda p: sio.write_csv(p, cloud),
        "a.xyz": lambda p: sio.write_xyz(p, cloud),
    }
    for name, write in writers.items():
        write(folder / name)
        files[name] = (folder / name).read_bytes()
    return files


@pytest.fixture(scope="module")
def valid(tmp_path_factory: pytest.TempPathFactory) -> dict[str, bytes]:
    return _valid_files(tmp_path_factory.mktemp("valid"))


def _check_outcome(path: Path) -> None:
    try:
        cloud = sio.read_points(path)
    except ValueError as exc:
        assert str(exc).startswith(str(path)), str(exc)
        return
    # parsed: it must be a consistent cloud
    assert cloud.points.dtype == np.float64 and cloud.points.ndim == 2
    for arr in cloud.named_fields().values():
        assert arr.shape[0] == len(cloud)


NAMES = [
    "a.pcd",
    "b.pcd",
    "c.pcd",
    "a.ply",
    "b.ply",
    "c.ply",
    "a.bin",
    "a.npy",
    "a.npz",
    "a.csv",
    "a.xyz",
]


@settings(
    max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    name=st.sampled_from(NAMES),
    cut=st.floats(0, 1),
    edits=st.lists(st.tuples(st.floats(0, 1), st.integers(0, 255)), max_size=4),
    insert=st.binary(max_size=8),
)
def test_fuzz_mutated_files(
    tmp_path: Path,
    valid: dict[str, bytes],
    name: str,
    cut: float,
    edits: list[tuple[float, int]],
    insert: bytes,
) -> None:
    raw = bytearray(valid[name])
    for where, value in edits:
        raw[int(where * (len(raw) - 1))] = value
    pos = int(cut * len(raw))
    data = bytes(raw[:pos]) + insert + bytes(raw[pos:]) if insert else bytes(raw[: max(pos, 1)])
    path = tmp_path / name
    path.write_bytes(data)
    _check_outcome(path)


@pytest.mark.parametrize("name", NAMES)
def test_every_truncation_is_clean(tmp_path: Path, valid: dict[str, bytes], name: str) -> None:
    raw = valid[name]
    path = tmp_path / name
    for cut in sorted({0, 1, 5, len(raw) // 3, len(raw) // 2, len(raw) - 9, len(raw) - 1}):
        path.write_bytes(raw[:cut])
        _check_outcome(path)
    path.write_bytes(b"")
    with pytest.raises(ValueError, match=str(path)):
        sio.read_points(path)


def _pcd(header_lines: list[str], body: bytes) -> bytes:
    return ("\n".join(header_lines) + "\n").encode() + body


PCD_HEAD = ["VERSION 0.7", "FIELDS x y z", "SIZE 4 4 4", "TYPE F F F", "COUNT 1 1 1"]


@pytest.mark.parametrize(
    ("content", "problem"),
    [
        (
            _pcd([*PCD_HEAD, "WIDTH 3", "HEIGHT 1", "POINTS 3", "DATA binary"], b"\0" * 24),
            "truncated",
        ),
        (
            _pcd(
                [*PCD_HEAD, "WIDTH 9999999999", "HEIGHT 1", "POINTS 9999999999", "DATA binary"],
                b"\0" * 24,
            ),
            "truncated",
        ),
        (
            _pcd([*PCD_HEAD, "WIDTH 2", "HEIGHT 1", "POINTS 3", "DATA binary"], b"\0" * 36),
            "POINTS 3 != WIDTH 2",
        ),
        (
            _pcd([*PCD_HEAD, "WIDTH 2", "HEIGHT 1", "POINTS 2", "DATA ascii"], b"1 2 3\n4 5 x\n"),
            "bad number",
        ),
        (_pcd([*PCD_HEAD, "WIDTH 2", "HEIGHT 1", "POINTS 2", "DATA ascii"], b"1 2 3\n"), "1 lines"),
        (_pcd([*PCD_HEAD, "WIDTH 1", "HEIGHT 1", "POINTS 1", "DATA ascii"], b"1 2\n"), "2 values"),
        (
            _pcd(
                [*PCD_HEAD, "WIDTH 1", "HEIGHT 1", "POINTS 1", "DATA binary_compressed"],
                b"\xff\xff\xff\x7f\x0c\0\0\0",
            ),
            "truncated",
        ),
        (
            _pcd(
                [*PCD_HEAD, "WIDTH 1", "HEIGHT 1", "POINTS 1", "DATA binary_compressed"],
                b"\x02\0\0\0\x0c\0\0\0\xe0\x00",
            ),
            "corrupt compressed",
        ),
        (
            _pcd(
                [
                    *PCD_HEAD,
                    "WIDTH 100000000",
                    "HEIGHT 1",
                    "POINTS 100000000",
                    "DATA binary_compressed",
                ],
                np.array([2, 1_200_000_000], "<u4").tobytes() + b"\0\0",
            ),
            "cannot come from",
        ),
        (
            _pcd(
                [
                    "VERSION 0.7",
                    "FIELDS x y",
                    "SIZE 4 4",
                    "TYPE F F",
                    "WIDTH 1",
                    "POINTS 1",
                    "DATA ascii",
                ],
                b"1 2\n",
            ),
            "no z",
        ),
        (
            _pcd(
                [
                    "VERSION 0.7",
                    "FIELDS x y z",
                    "SIZE 4 4 4",
                    "TYPE F F Q",
                    "WIDTH 1",
                    "POINTS 1",
                    "DATA ascii",
                ],
                b"1 2 3\n",
            ),
            "unsupported TYPE",
        ),
        (
            _pcd(
                [
                    "VERSION 0.7",
                    "FIELDS x y z",
                    "SIZE 4 4",
                    "TYPE F F F",
                    "WIDTH 1",
                    "POINTS 1",
                    "DATA ascii",
                ],
                b"1 2 3\n",
            ),
            "SIZE has 2 entries",
        ),
        (
            _pcd([*PCD_HEAD, "WIDTH 1", "HEIGHT 1", "POINTS 1", "DATA lzma"], b""),
            "unsupported DATA",
        ),
        (b"PK\x03\x04 not a pcd at all\n" * 3, "not a PCD file"),
        (b"\x00" * 100_000, "no DATA line"),
    ],
)
def test_hostile_pcd(tmp_path: Path, content: bytes, problem: str) -> None:
    path = tmp_path / "h.pcd"
    path.write_bytes(content)
    with pytest.raises(FileFormatError, match=problem) as info:
        sio.read_points(path)
    assert str(info.value).startswith(str(path))


XYZ_PROPS = "property float x\nproperty float y\nproperty float z\n"
PLY_HEAD = "ply\nformat binary_little_endian 1.0\nelement vertex {n}\n" + XYZ_PROPS
ASCII1 = b"ply\nformat ascii 1.0\nelement vertex 1\n"


@pytest.mark.parametrize(
    ("content", "problem"),
    [
        ((PLY_HEAD.format(n=3) + "end_header\n").encode() + b"\0" * 20, "truncated"),
        ((PLY_HEAD.format(n=4_000_000_000) + "end_header\n").encode() + b"\0" * 24, "truncated"),
        (b"plz\nformat ascii 1.0\nend_header\n", "no 'ply' magic"),
        (b"ply\nelement vertex 1\nproperty float x\nend_header\n1\n", "no format line"),
        (
            b"ply\nformat ascii 1.0\nelement vertex 2\n"
            + XYZ_PROPS.encode()
            + b"end_header\n1 2 3\n",
            "truncated",
        ),
        (
            ASCII1 + XYZ_PROPS.encode() + b"end_header\n1 2 nan3\n",
            "bad number",
        ),
        (
            ASCII1 + b"property float x\nproperty float y\nend_header\n1 2\n",
            "no z",
        ),
        (
            b"ply\nformat binary_little_endian 1.0\nelement face 1000\n"
            b"property list uchar int idx\nelement vertex 1\n"
            + XYZ_PROPS.encode()
            + b"end_header\n\x05\0\0",
            "truncated inside element face",
        ),
        (
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float128 x\nend_header\n",
            "bad property",
        ),
        (b"ply\nformat ascii 1.0\n" + b"comment " + b"a" * 70_000, "no end_header"),
    ],
)
def test_hostile_ply(tmp_path: Path, content: bytes, problem: str) -> None:
    path = tmp_path / "h.ply"
    path.write_bytes(content)
    with pytest.raises(FileFormatError, match=problem) as info:
        sio.read_points(path)
    assert str(info.value).startswith(str(path))


def test_hostile_simple_formats(tmp_path: Path) -> None:
    (tmp_path / "a.bin").write_bytes(b"\0" * 17)
    with pytest.raises(FileFormatError, match="not a multiple of 16"):
        sio.read_points(tmp_path / "a.bin")
    (tmp_path / "a.npy").write_bytes(b"\x93NUMPY garbage")
    with pytest.raises(FileFormatError, match="cannot load"):
        sio.read_points(tmp_path / "a.npy")
    np.save(tmp_path / "b.npy", np.array(["a", "b"]))
    with pytest.raises(FileFormatError, match="numeric"):
        sio.read_points(tmp_path / "b.npy")
    np.savez(tmp_path / "c.npz", other=np.zeros(3))
    with pytest.raises(FileFormatError, match="no 'points' array"):
        sio.read_points(tmp_path / "c.npz")
    (tmp_path / "d.csv").write_text("x,y,z\n1,2,3\n4,5\n")
    with pytest.raises(FileFormatError, match="line 3: 2 values"):
        sio.read_points(tmp_path / "d.csv")
    (tmp_path / "e.xyz").write_bytes(b"1 2 3\n\xff\xfe\n")
    with pytest.raises(FileFormatError, match="UTF-8"):
        sio.read_points(tmp_path / "e.xyz")


def test_hostile_trajectories(tmp_path: Path) -> None:
    path = tmp_path / "t.txt"
    cases = [
        ("kitti", "1 0 0 0 0 1 0 0 0 0 1\n", "11 values"),
        ("kitti", "1 0 0 0 0 1 0 0 0 0 1 zz\n", "bad number"),
        ("kitti", "2 0 0 0 0 1 0 0 0 0 1 0\n", "not a rotation"),
        ("kitti", "-1 0 0 0 0 1 0 0 0 0 1 0\n", "not a rotation"),
        ("kitti", "", "no KITTI pose lines"),
        ("tum", "# only a comment\n", "no TUM lines"),
        ("tum", "0 1 2 3 0 0 0 0\n", "quaternion norm 0"),
        ("tum", "0 1 2 nan 0 0 0 1\n", "NaN"),
    ]
    for fmt, text, problem in cases:
        path.write_text(text)
        with pytest.raises(FileFormatError, match=problem) as info:
            sio.read_trajectory(path, fmt)
        assert str(info.value).startswith(str(path))
    path.write_text("Tr: 1 0 0 0 0 1 0 0 0 0 1\n")
    with pytest.raises(FileFormatError, match="12 finite numbers"):
        sio.read_kitti_calib(path)


def test_hostile_g2o(tmp_path: Path) -> None:
    path = tmp_path / "g.g2o"
    cases = [
        ("VERTEX_SE2 0 1 2\n", "needs 4 values, got 3"),
        ("VERTEX_XY 0 1 2\n", "unsupported g2o tag"),
        ("VERTEX_SE2 0 1 2 x\n", "bad number"),
        ("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 0 0 0 0\n", "defined twice"),
        ("VERTEX_SE2 0 0 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n", "unknown vertex 1"),
        (
            "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 0 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0\n",
            "needs 11 values",
        ),
        ("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 2\n", "quaternion norm"),
        ("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE2 1 0 0 0\n", "all SE2 or all SE3"),
    ]
    for text, problem in cases:
        path.write_text(text)
        with pytest.raises(FileFormatError, match=problem):
            sio.read_g2o(path)


@settings(
    max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(data=st.data())
def test_fuzz_text_formats(tmp_path: Path, data: st.DataObject) -> None:
    traj = Trajectory.from_poses(
        [SE3.from_vector([i, 0, 0, 0, 0, 0.1 * i]) for i in range(3)], [0.0, 1.0, 2.0]
    )
    graph = PoseGraph(
        {0: traj.se3(0), 1: traj.se3(1)}, (PoseGraphEdge(0, 1, traj.se3(1), np.eye(6)),)
    )
    kind = data.draw(st.sampled_from(["kitti", "tum", "g2o"]))
    path = tmp_path / "t.txt"
    if kind == "g2o":
        sio.write_g2o(path, graph)
    else:
        sio.write_trajectory(path, traj, kind)
    raw = bytearray(path.read_bytes())
    for _ in range(data.draw(st.integers(1, 4))):
        raw[data.draw(st.integers(0, len(raw) - 1))] = data.draw(
            st.sampled_from(b"0123456789.-e +#\nxn\xff")
        )
    path.write_bytes(bytes(raw[: data.draw(st.integers(0, len(raw)))]))
    try:
        result = sio.read_g2o(path) if kind == "g2o" else sio.read_trajectory(path, kind)
    except ValueError as exc:
        assert str(exc).startswith(str(path)), str(exc)
        return
    if isinstance(result, Trajectory):
        assert result.poses.shape[1:] == (4, 4) and np.isfinite(result.poses).all()


# --- no NaN cast into an integer field ---------------------------------------------------


def _las_with_float_ring(path: Path, ring: list[float]) -> None:
    laspy = pytest.importorskip("laspy")
    header = laspy.LasHeader(point_format=3, version="1.4")
    header.add_extra_dim(laspy.ExtraBytesParams(name="ring", type=np.float64))
    las = laspy.LasData(header)
    las.x, las.y, las.z = [0.0, 1.0], [0.0, 1.0], [0.0, 1.0]
    las.ring = ring
    las.write(path)


@pytest.mark.parametrize("bad", ["nan", "inf", "1.5"])
def test_no_reader_casts_a_non_integer_ring_into_int64(tmp_path: Path, bad: str) -> None:
    """A float ring field that is not a whole number is refused by name in every cloud format
    (numpy's "invalid value encountered in cast", an error here, would mean a silent cast).
    The LAS reader cast its extra-bytes ring itself and warned; it leaves that to PointCloud."""
    pcd = tmp_path / "r.pcd"
    pcd.write_text(
        "VERSION .7\nFIELDS x y z ring\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\n"
        f"WIDTH 2\nHEIGHT 1\nPOINTS 2\nDATA ascii\n0 0 0 1\n1 1 1 {bad}\n"
    )
    ply = tmp_path / "r.ply"
    ply.write_text(
        "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
        f"property float z\nproperty float ring\nend_header\n0 0 0 1\n1 1 1 {bad}\n"
    )
    las = tmp_path / "r.las"
    _las_with_float_ring(las, [1.0, float(bad)])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for path, read in ((pcd, sio.read_pcd), (ply, sio.read_ply), (las, sio.read_las)):
            with pytest.raises(ValueError, match=r"ring.*(integer|int64)") as info:
                read(path)
            assert str(path) in str(info.value)


def test_a_whole_float_ring_is_read_as_int64(tmp_path: Path) -> None:
    las = tmp_path / "r.las"
    _las_with_float_ring(las, [3.0, 7.0])
    cloud = sio.read_las(las)
    assert cloud.ring is not None and cloud.ring.dtype == np.int64
    np.testing.assert_array_equal(cloud.ring, [3, 7])


# --- findings of the fuzz campaign (fuzz/campaign.sh) ------------------------------------


def _run_bag_db3(path: Path, frames: int = 3) -> Path:
    pytest.importorskip("rosbags")
    poses = np.repeat(np.eye(4)[None], frames, axis=0)
    poses[:, 0, 3] = np.arange(frames)
    sio.write_run_bag(path, np.arange(frames) * 0.1, poses, scans=[_cloud(20)] * frames)
    return path


def test_a_ros2_sqlite_bag_refused_mid_stream_is_closed_without_an_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Found by the ros2_sqlite target: a corrupt message refused while rosbags' sqlite3
    statement was still open, with the refusal kept in a reference cycle (the fuzz harness
    kept it in a list its traceback reaches; so do loggers and retry loops), left the clean-up
    to the garbage collector, which closed the database under the statement: "database is
    locked" from the generator's finally (an unraisable exception), the file left open."""
    import gc
    import sqlite3
    import sys

    unraised: list[str] = []
    monkeypatch.setattr(sys, "unraisablehook", lambda u: unraised.append(repr(u.exc_value)))
    bag = _run_bag_db3(tmp_path / "run.db3")
    with sqlite3.connect(bag) as db:  # the second of three clouds: one byte
        db.execute(
            "UPDATE messages SET data = x'00' WHERE id = (SELECT id FROM messages WHERE "
            "topic_id = (SELECT id FROM topics WHERE name = '/scanreg/scan') "
            "ORDER BY timestamp LIMIT 1 OFFSET 1)"
        )
    db.close()

    def read_keeping_the_refusal() -> None:
        refusals = []
        try:
            sio.read_bag_clouds(bag)
        except FileFormatError as exc:
            refusals.append(exc)
        raise refusals[0]  # exc -> traceback -> this frame -> refusals -> exc

    with pytest.raises(FileFormatError, match="message 1: cannot deserialise"):
        read_keeping_the_refusal()
    gc.collect()
    assert unraised == []


def test_a_huge_row_step_in_a_small_pointcloud2_allocates_nothing_extra() -> None:
    """Found by the ros1 and ros2_mcap targets: a 6 kB bag whose PointCloud2 said
    row_step = 1 GiB (height 1) made the decoder pad its 160-byte blob out to height·row_step:
    1 GiB allocated and 10 s spent. The last row's missing padding is now skipped in place."""
    import tracemalloc
    from types import SimpleNamespace

    from scanreg.io.rosbag import decode_pointcloud2

    pts = np.arange(40, dtype=np.float32).reshape(10, 4)
    fields = [
        SimpleNamespace(name=n, offset=4 * i, datatype=7, count=1)
        for i, n in enumerate(("x", "y", "z", "intensity"))
    ]
    shape = {"width": 10, "point_step": 16, "is_bigendian": False}
    tracemalloc.start()
    try:
        cloud = decode_pointcloud2(fields, pts.tobytes(), height=1, row_step=2**30, **shape)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 1 << 20, peak
    np.testing.assert_array_equal(cloud.points, pts[:, :3])
    np.testing.assert_array_equal(cloud.intensity, pts[:, 3])  # type: ignore[arg-type]
    # Two rows need the first row's padding in full.
    with pytest.raises(ValueError, match="data: 160 bytes, expected height·row_step"):
        decode_pointcloud2(fields, pts.tobytes(), height=2, row_step=2**30, **shape)
    # Rows with padding, the last one's cut off: the points of both rows, in order.
    padded = np.zeros((2, 96), np.uint8)
    padded[:, :80] = pts.view(np.uint8).reshape(2, 80)
    two = decode_pointcloud2(
        fields, padded.reshape(-1)[:-16].tobytes(), height=2, row_step=96, **{**shape, "width": 5}
    )
    np.testing.assert_array_equal(two.points, pts[:, :3])


def test_a_huge_entry_in_a_kitti_calibration_is_refused_without_a_warning(tmp_path: Path) -> None:
    """Found by the kitti_calib target: a finite 7e203 in Tr overflowed RᵀR in the rotation
    check ("overflow encountered in matmul"); it is refused as not orthonormal, by name."""
    path = tmp_path / "calib.txt"
    path.write_text("Tr: 1 0 0 0 0 -7.2e203 0 0 0 0 1 0\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(FileFormatError, match=r"Tr is not a rigid transform: .*= inf"):
            sio.read_kitti_calib(path)
        with pytest.raises(ValueError, match="rotation: not orthonormal"):
            SE3.from_matrix(np.diag([1e200, 1.0, 1.0, 1.0]))


# --- ROS map_server maps (what `scanreg localize --map` reads) ------------------------------

_MAP_YAML = "image: map.pgm\nresolution: 0.05\norigin: [1.0, -2.0, 0.0]\nnegate: 0\n"


def _map(folder: Path, yaml: str = _MAP_YAML, pgm: bytes | None = None) -> Path:
    img = np.full((6, 8), 254, dtype=np.uint8)
    img[2, 1:7] = 0
    (folder / "map.pgm").write_bytes(b"P5\n8 6\n255\n" + img.tobytes() if pgm is None else pgm)
    (folder / "map.yaml").write_text(yaml)
    return folder / "map.yaml"


@pytest.mark.parametrize(
    ("yaml", "pgm", "message"),
    [
        (None, b"P5\n999999999 999999999\n255\n\0\0", r"map\.pgm: truncated: width 999999999"),
        (None, b"P5\n8 6\n255\n" + b"\0" * 47, r"map\.pgm: truncated: width 8 x height 6"),
        (None, b"P5\n8 6\n65535\n" + b"\0" * 96, r"map\.pgm: maxval 65535"),
        (None, b"P5\n0 6\n255\n", r"map\.pgm: empty image"),
        (None, b"P2\n8 6\n255\n", r"map\.pgm: not a binary PGM"),
        (_MAP_YAML.replace("map.pgm", "/dev/zero"), None, r"map\.yaml: image: /dev/zero is not"),
        (_MAP_YAML.replace("map.pgm", "."), None, r"map\.yaml: image: .* is not a readable file"),
        (_MAP_YAML.replace("0.05", "nan"), None, r"map\.yaml: resolution: expected a finite"),
        (_MAP_YAML.replace("0.05", "-1"), None, r"map\.yaml: resolution: must be > 0"),
        (_MAP_YAML.replace("0.05", "1e308"), None, r"map\.yaml: resolution: 1e\+308 m over"),
        (_MAP_YAML.replace(", 0.0]", "]"), None, r"map\.yaml: origin: expected \[x, y, yaw\]"),
        (_MAP_YAML.replace("[1.0", "[inf"), None, r"map\.yaml: origin: expected a finite"),
        (_MAP_YAML.replace("negate: 0", "negate: 2"), None, r"map\.yaml: negate: expected 0"),
        (_MAP_YAML + "occupied_thresh: 7\n", None, r"map\.yaml: occupied_thresh 7\.0"),
        ("image: map.pgm\n", None, r"map\.yaml: lacks resolution, origin"),
    ],
)
def test_a_damaged_map_server_map_is_refused_by_field(
    tmp_path: Path, yaml: str | None, pgm: bytes | None, message: str
) -> None:
    """PGM dimensions are checked against the bytes before anything is allocated, the image
    a YAML names must be a regular file (``/dev/zero`` was read until memory ran out), and
    each YAML field is range-checked: FileFormatError naming the file and the field."""
    from scanreg.io.occupancy import read_map_server

    path = _map(tmp_path, _MAP_YAML if yaml is None else yaml, pgm)
    with pytest.raises(FileFormatError, match=message):
        read_map_server(path)


def test_a_sound_map_server_map_reads_and_the_yaml_is_bounded(tmp_path: Path) -> None:
    from scanreg.io.occupancy import MAX_YAML_BYTES, read_map_server

    points, resolution = read_map_server(_map(tmp_path))
    assert resolution == 0.05 and len(points) == 6  # the wall on image row 2
    np.testing.assert_allclose(points[:, 1], -2.0 + (6 - 1 - 2 + 0.5) * 0.05)
    (tmp_path / "big.yaml").write_bytes(b"#" * (MAX_YAML_BYTES + 1))
    with pytest.raises(FileFormatError, match=r"big\.yaml: larger than"):
        read_map_server(tmp_path / "big.yaml")
    (tmp_path / "bin.yaml").write_bytes(b"image: \xff\n")
    with pytest.raises(FileFormatError, match=r"bin\.yaml: not a text file"):
        read_map_server(tmp_path / "bin.yaml")


# --- batch manifests and TOML configs --------------------------------------------------------


@pytest.mark.parametrize(
    ("cell", "message"),
    [
        ("~no-such-user-scanreg/x.toml", "no home directory for user 'no-such-user-scanreg'"),
        ("a\0b.toml", "a path cannot hold a NUL byte"),
        ("x" * 5000, "no such file or directory"),
    ],
)
def test_a_manifest_cell_that_is_no_usable_path_is_a_manifest_error(
    tmp_path: Path, cell: str, message: str
) -> None:
    """Issue 40: ``~someone/...`` of an unknown user raised a bare ``RuntimeError: Could not
    determine home directory`` from ``expanduser``; a NUL byte or a name too long for the file
    system are the same kind of cell. Each is a ManifestError (a ValueError) naming the
    manifest, the row and the column."""
    from scanreg.batch import ManifestError, read_manifest

    manifest = tmp_path / "jobs.csv"
    manifest.write_text(f'id,input,config\na,sim:street,"{cell}"\n')
    with pytest.raises(ManifestError, match=rf"jobs\.csv: row 1 \(id 'a'\): config .*{message}"):
        read_manifest(manifest, "odometry")


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("voxel_size = " + "9" * 400 + "\n", r"voxel_size: expected float, .*too large"),
        ("max_iterations = " + "9" * 30 + "\n", r"max_iterations: .*beyond the 64-bit"),
        ("voxel_size = " + "[" * 5000 + "]" * 5000 + "\n", r"nested too deeply"),
    ],
)
def test_a_config_past_what_toml_holds_is_a_config_error(
    tmp_path: Path, text: str, message: str
) -> None:
    """Found writing the config targets of the campaign: Python's TOML parser reads integers
    of any size (TOML's are 64-bit) and recurses per nested array — an OverflowError and a
    RecursionError escaped ``load_config``. ``/dev/zero`` as a config was read forever."""
    from scanreg.batch.jobs import register_options
    from scanreg.config import MAX_CONFIG_BYTES, ConfigError, load_config
    from scanreg.pipeline import OdometryConfig

    path = tmp_path / "c.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=rf"c\.toml: .*{message}"):
        load_config(OdometryConfig, path)
    if "voxel_size = 9" in text:  # batch register's config: the same integer, named
        with pytest.raises(ValueError, match=r"c\.toml: voxel_size is too large"):
            register_options(str(path))
    with pytest.raises(ConfigError, match=rf"larger than {MAX_CONFIG_BYTES} bytes"):
        load_config(OdometryConfig, "/dev/zero")


@pytest.mark.parametrize(
    ("size_bytes", "limit"),
    [(0, 100), (1, 100), (100, 100), (101, 100), (70_000, 100_000), (70_000, 65_537)],
)
def test_a_config_is_read_up_to_its_size_limit_and_no_further(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, size_bytes: int, limit: int
) -> None:
    """``read_config_file`` reads by the file's size instead of reserving the whole limit
    per read (16 MB: a fifth of a batch manifest check); the limit still holds at, below and
    above it, and for a file larger than one read step."""
    from scanreg import config

    monkeypatch.setattr(config, "MAX_CONFIG_BYTES", limit)
    path = tmp_path / "c.toml"
    path.write_bytes(b"#" * size_bytes)
    if size_bytes <= limit:
        assert config.read_config_file(path) == {}
    else:
        with pytest.raises(config.ConfigError, match=rf"c\.toml: larger than {limit} bytes"):
            config.read_config_file(path)


def test_a_config_read_asks_for_no_more_than_the_file_holds(tmp_path: Path) -> None:
    """Found by the command_configs campaign: each read asked for the whole 16 MB limit, and
    a process reading configs grew ~1 MB per 1 000 executions (glibc's heap fragmenting
    around the 16 MB buffers: 1153 MB after 1 M; 72 MB once reads ask for the file's size)."""
    import io

    from scanreg import config

    path = tmp_path / "c.toml"
    path.write_bytes(b"voxel_size = 0.5\n" * 100)
    asked: list[int] = []

    class Recording(io.BufferedReader):
        def read(self, size: int | None = -1, /) -> bytes:
            asked.append(-1 if size is None else size)
            return super().read(size)

    with Recording(io.FileIO(path, "rb")) as fh:
        assert config._read_at_most(fh, config.MAX_CONFIG_BYTES + 1) == path.read_bytes()
    assert asked and max(asked) <= path.stat().st_size + 1


def test_a_pgm_header_of_many_blank_lines_is_refused_at_once(tmp_path: Path) -> None:
    """Found by the map_server target: a PGM header whose comment was followed by a run of
    newlines and no number made the header pattern backtrack exponentially (seconds for a
    261-byte file, a libFuzzer timeout)."""
    import time

    from scanreg.io.occupancy import read_pgm

    path = tmp_path / "m.pgm"
    path.write_bytes(b"P5\n# CREATOR\n" + b"\n" * 25 + b"x")  # the old pattern: ~4 s
    start = time.perf_counter()
    with pytest.raises(FileFormatError, match=r"m\.pgm: not a binary PGM"):
        read_pgm(path)
    assert time.perf_counter() - start < 0.5
    path.write_bytes(b"P5\n# CREATOR\n\n\n 2\n\n# c\n1 255\n\x00\xfe")  # comments, blank lines
    assert read_pgm(path).tolist() == [[0, 254]]


def test_a_map_yaml_value_with_a_long_run_of_blanks_is_read_at_once(tmp_path: Path) -> None:
    """Found reading the map_server reader after the fuzz finding above: the YAML line
    pattern's lazy value ``(.+?)[ \\t]*$`` went quadratic on blanks inside a value (3.5 s for
    16 000 spaces; the 1 MB cap would have allowed hours)."""
    import time

    from scanreg.io.occupancy import read_map_server

    path = _map(tmp_path, _MAP_YAML.replace("image: map.pgm", "image: map" + " " * 30_000 + "x"))
    start = time.perf_counter()
    with pytest.raises(FileFormatError, match=r"map\.yaml: image: .* is not a readable file"):
        read_map_server(path)
    assert time.perf_counter() - start < 0.5
    path.write_text(_MAP_YAML.replace("negate: 0", "negate:   \t  0   \t"))
    assert len(read_map_server(path)[0]) == 6  # blanks around a value are not part of it


#: A finding of the manifest_parquet target (an odometry manifest of our writer with 12
#: bytes changed; zlib + base64): a damaged size-statistics histogram in the footer. pyarrow's
#: ``RowGroupMetaData.column(i)`` throws a C++ exception there that it does not convert:
#: ``std::terminate``, SIGABRT.
_PARQUET_HISTOGRAM_FINDING = """
eNqNk89u0zAcxx03WGUqUjZwlEwRyiGLEOratdBplFbIqWBMFNFWGhMcJlVt1lU0SUnSdeKwp9iBA0+xE0eegBMn
noDH4Gd7bTe1SPzk2M7vz+f7i5O0WKdEVbpHq01KKNpAyHIIQihJY99PlbWn6SQM/ZEKrtMo8CmiD6iRh1QNLmLt
okdEZhgqj6+vQ+Kag2EmCs44CNhnNJ6xn59vcvYwqEp+/iR+gaT5fr9eun/vYUviININ/KT+hKMuiit08UXR2LyF
EgWVfCJQqzqxqdOEhXei1bIQifoRTMGINwASG1S/JZGFeCGFuIEE7q4tcUqGUNVsVpBBkt6pH3QpQTTnYAMP+1uo
aXFabgsbd4bheJLe9JBeFJ4MB9cunZiWWXORRXNmBRHN5ACKdaJfKfp3xT12s6tO2Mzzh6CYt6zBUtNtk5gu4u/t
JkzKC94lhuH+xO4P5f/OblnjeKXG9QNJEUX/priXqvsrs3x6y0BtDtR/qzpxs/ofFZmWkWOdzrujqjxZ4ysuctsb
MLA2k/aGsSnzBuwVYwPWECHmeYy95ZsGYwfCsViZDHnJbCdRjSlHi9qOcH5Y5AvbF87ys8nHYBRC/ieeX27BNOWI
w/Y8ad4a1PPt/mjSe/1+h99/4fnnjDd7wCW8qWzh5aLoX/oNPnWP2oLviZKZ1evIsMfd+PPET7d74/F2N46jx/aZ
HyfDKLTLu4WdQsmswWcmB7qCb7cFf/tfpkfNOw==
"""


def _manifest_in_a_child(path: Path) -> tuple[int, str]:
    """``read_manifest(path, "odometry")`` in a child interpreter capped at 3 GB of address
    space (an allocation bug fails there instead of swelling on a shared machine): its exit
    code and what it printed (the job ids, or the refusal)."""
    import os
    import resource
    import subprocess
    import sys

    code = (
        "import sys\n"
        "from scanreg.batch import ManifestError, read_manifest\n"
        "try:\n"
        "    print([job.id for job in read_manifest(sys.argv[1], 'odometry')])\n"
        "except ManifestError as exc:\n"
        "    print('ManifestError:', exc)\n"
    )

    def cap() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (3 << 30, 3 << 30))

    python = str(Path(__file__).resolve().parent.parent / "python")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([python, *sys.path])}
    done = subprocess.run(
        [sys.executable, "-c", code, str(path)], capture_output=True, text=True, timeout=120,
        env=env, preexec_fn=cap, check=False,
    )  # fmt: skip
    return done.returncode, done.stdout + done.stderr[-2000:]


def test_a_damaged_parquet_manifest_is_refused_by_name_in_a_process_that_survives(
    tmp_path: Path,
) -> None:
    """Found by the manifest_parquet target: (1) a 1 kB manifest whose row group claimed
    82 797 590 141 rows made ``read_table`` reserve 275 GB by that count (a timeout under
    libFuzzer; read outside it, the kernel killed the process); (2) a damaged size-statistics
    histogram aborted the interpreter through pyarrow's footer metadata accessor (a first
    version of the fix read the counts there). The manifest is now read batch by batch: the
    claim costs nothing, the histogram is an OSError named as a ManifestError."""
    import base64
    import zlib

    pa = pytest.importorskip("pyarrow")
    pq = pytest.importorskip("pyarrow.parquet")
    from scanreg.batch import ManifestError, read_manifest
    from scanreg.batch.manifest import MAX_PARQUET_ROWS

    good = tmp_path / "good.parquet"
    table = pa.table({"id": ["a", "b", "c"], "input": ["sim:street"] * 3, "config": [None] * 3})
    pq.write_table(table, good)
    assert [job.id for job in read_manifest(good, "odometry")] == ["a", "b", "c"]  # nulls too
    # (1) the row group's num_rows (the last i64 field holding 3 in the footer, zigzag varint
    # 0x06) re-encoded as 82 797 590 141, the footer's length adjusted
    raw = good.read_bytes()
    length = int.from_bytes(raw[-8:-4], "little")
    at = raw.rindex(b"\x16\x06", len(raw) - 8 - length)
    rows, varint = 82_797_590_141 * 2, bytearray()  # zigzag of a positive count
    while rows >= 0x80:
        varint.append(rows & 0x7F | 0x80)
        rows >>= 7
    varint.append(rows)
    claim = raw[: at + 1] + bytes(varint) + raw[at + 2 : -8]
    claim += (length + len(varint) - 1).to_bytes(4, "little") + b"PAR1"
    (tmp_path / "claim.parquet").write_bytes(claim)
    assert pq.ParquetFile(tmp_path / "claim.parquet").metadata.row_group(0).num_rows == (
        82_797_590_141
    )
    status, out = _manifest_in_a_child(tmp_path / "claim.parquet")
    assert (status, out.strip()) == (0, "['a', 'b', 'c']"), out
    # (2) the histogram finding
    finding = tmp_path / "histogram.parquet"
    finding.write_bytes(zlib.decompress(base64.b64decode(_PARQUET_HISTOGRAM_FINDING)))
    status, out = _manifest_in_a_child(finding)
    assert status == 0, f"the reading process died (exit {status}): {out}"
    assert "ManifestError:" in out and "histogram.parquet: cannot read the manifest:" in out
    # and a manifest of more rows than any batch runs
    many = tmp_path / "many.parquet"
    ids = [f"j{k}" for k in range(MAX_PARQUET_ROWS + 1)]
    pq.write_table(pa.table({"id": ids, "input": ["sim:street"] * len(ids)}), many)
    with pytest.raises(ManifestError, match=r"many\.parquet: more than 1000000 rows"):
        read_manifest(many, "odometry")
