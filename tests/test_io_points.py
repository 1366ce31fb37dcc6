"""Point-cloud readers/writers: round trips, real files, the registry."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scanreg.io as sio
from conftest import data_dir
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from scanreg.io import PointCloud

KITTI = "kitti-odometry-00-frames-000-015"
GICP = "gicp-outdoor-scan-pair"


def _cloud(n: int = 50, seed: int = 0) -> PointCloud:
    rng = np.random.default_rng(seed)
    return PointCloud(
        points=rng.normal(0, 20, (n, 3)),
        intensity=rng.uniform(0, 255, n),
        ring=rng.integers(0, 64, n),
        time=1.7e9 + rng.uniform(0, 0.1, n),
        fields={"normal_x": rng.normal(size=n)},
    )


def _assert_same(a: PointCloud, b: PointCloud, exact: bool) -> None:
    assert len(a) == len(b)
    cmp = np.testing.assert_array_equal if exact else np.testing.assert_allclose
    cmp(a.points, b.points)
    for name, arr in a.named_fields().items():
        assert name in b.named_fields(), name
        cmp(arr, b.named_fields()[name])
    assert set(a.named_fields()) == set(b.named_fields())


LOSSLESS = [
    ("c.pcd", {"data": "binary", "precision": "float64"}),
    ("c.pcd", {"data": "ascii", "precision": "float64"}),
    ("c.pcd", {"data": "binary_compressed", "precision": "float64"}),
    ("c.ply", {"data": "binary_little_endian", "precision": "float64"}),
    ("c.ply", {"data": "binary_big_endian", "precision": "float64"}),
    ("c.ply", {"data": "ascii", "precision": "float64"}),
    ("c.npy", {}),
    ("c.npz", {}),
    ("c.csv", {}),
    ("c.xyz", {}),
]


@pytest.mark.parametrize(("name", "options"), LOSSLESS)
def test_round_trip_is_exact(tmp_path: Path, name: str, options: dict[str, str]) -> None:
    cloud = _cloud()
    sio.write_points(tmp_path / name, cloud, **options)
    _assert_same(cloud, sio.read_points(tmp_path / name), exact=True)


@pytest.mark.parametrize("name", ["c.pcd", "c.ply"])
def test_float32_round_trip_equals_float32_cast(tmp_path: Path, name: str) -> None:
    cloud = _cloud()
    sio.write_points(tmp_path / name, cloud)  # default precision float32
    back = sio.read_points(tmp_path / name)
    np.testing.assert_array_equal(back.points, cloud.points.astype(np.float32))
    assert back.intensity is not None
    np.testing.assert_array_equal(back.intensity, cloud.intensity.astype(np.float32))  # type: ignore[union-attr]
    np.testing.assert_array_equal(back.time, cloud.time)  # time stays float64
    np.testing.assert_array_equal(back.ring, cloud.ring)


def test_kitti_bin_round_trip(tmp_path: Path) -> None:
    cloud = PointCloud(points=np.arange(12.0).reshape(4, 3), intensity=np.array([0, 0.25, 0.5, 1]))
    sio.write_points(tmp_path / "s.bin", cloud)
    assert (tmp_path / "s.bin").stat().st_size == 4 * 16
    _assert_same(cloud, sio.read_points(tmp_path / "s.bin"), exact=True)


def test_plain_arrays_and_2d_text(tmp_path: Path) -> None:
    pts = np.random.default_rng(1).normal(size=(7, 2))
    np.save(tmp_path / "a.npy", pts)
    assert sio.read_points(tmp_path / "a.npy").dim == 2
    (tmp_path / "a.xyz").write_text("\n".join(f"{float(x)!r} {float(y)!r}" for x, y in pts) + "\n")
    back = sio.read_points(tmp_path / "a.xyz")
    np.testing.assert_array_equal(back.points, pts)
    (tmp_path / "b.csv").write_text("X,Y,Z,reflectance\n1,2,3,0.5\n4,5,6,0.25\n")
    c = sio.read_points(tmp_path / "b.csv")
    np.testing.assert_array_equal(c.points, [[1, 2, 3], [4, 5, 6]])
    np.testing.assert_array_equal(c.intensity, [0.5, 0.25])  # type: ignore[arg-type]


def test_time_field_names_are_recognised(tmp_path: Path) -> None:
    for name in ("t", "time", "timestamp", "offset_time"):
        body = "x y z " + name + "\n1 2 3 0.5\n"
        (tmp_path / "c.xyz").write_text("# " + body)
        assert sio.read_points(tmp_path / "c.xyz").time is not None, name


def test_pcd_padding_fields_and_counts(tmp_path: Path) -> None:
    # PCL pads with "_" fields; COUNT > 1 gives an (N, k) extra field.
    header = (
        "VERSION 0.7\nFIELDS x y z _ rgb hist\nSIZE 4 4 4 1 4 4\nTYPE F F F U U F\n"
        "COUNT 1 1 1 4 1 3\nWIDTH 2\nHEIGHT 1\nPOINTS 2\nDATA ascii\n"
    )
    (tmp_path / "p.pcd").write_text(header + "1 2 3 0 0 0 0 7 1 2 3\n4 5 6 0 0 0 0 8 4 5 6\n")
    c = sio.read_points(tmp_path / "p.pcd")
    np.testing.assert_array_equal(c.points, [[1, 2, 3], [4, 5, 6]])
    assert set(c.fields) == {"rgb", "hist"}
    assert c.fields["hist"].shape == (2, 3)


def test_ply_skips_face_elements(tmp_path: Path) -> None:
    cloud = _cloud(5)
    # a binary PLY with a face element (list property) *before* the vertices
    faces = [(3, 0, 1, 2), (4, 0, 1, 2, 3)]
    body = b"".join(
        np.array([f[0]], "<u1").tobytes() + np.array(f[1:], "<i4").tobytes() for f in faces
    )
    verts = np.zeros(5, dtype=[("x", "<f8"), ("y", "<f8"), ("z", "<f8")])
    for i, a in enumerate("xyz"):
        verts[a] = cloud.points[:, i]
    header = (
        "ply\nformat binary_little_endian 1.0\nelement face 2\n"
        "property list uchar int vertex_indices\nelement vertex 5\n"
        "property double x\nproperty double y\nproperty double z\nend_header\n"
    )
    (tmp_path / "m.ply").write_bytes(header.encode() + body + verts.tobytes())
    np.testing.assert_array_equal(sio.read_points(tmp_path / "m.ply").points, cloud.points)


def test_registry_and_errors(tmp_path: Path) -> None:
    assert sio.READERS[".pcd"] is sio.read_pcd and sio.WRITERS[".ply"] is sio.write_ply
    with pytest.raises(ValueError, match=r"no point-cloud reader for '\.e57'"):
        sio.read_points(tmp_path / "x.e57")
    with pytest.raises(ValueError, match="PCD stores 3D points"):
        sio.write_points(tmp_path / "x.pcd", PointCloud(points=np.zeros((2, 2))))
    with pytest.raises(ValueError, match="ring"):
        PointCloud(points=np.zeros((2, 3)), ring=np.array([0.5, 1.0]))
    with pytest.raises(ValueError, match="intensity"):
        PointCloud(points=np.zeros((2, 3)), intensity=np.zeros(3))
    c = PointCloud(points=np.array([[0.0, 0, 0], [np.nan, 0, 0]]))
    assert len(c.finite()) == 1
    with pytest.raises(ValueError, match="read-only"):
        c.points[0, 0] = 1.0


clouds = st.integers(0, 40).flatmap(
    lambda n: st.builds(
        lambda p, i, r, t: PointCloud(points=p, intensity=i, ring=r, time=t),
        hnp.arrays(np.float64, (n, 3), elements=st.floats(-1e6, 1e6, width=32)),
        st.none() | hnp.arrays(np.float64, n, elements=st.floats(0, 1e4, width=32)),
        st.none() | hnp.arrays(np.int64, n, elements=st.integers(0, 127)),
        st.none() | hnp.arrays(np.float64, n, elements=st.floats(-1e9, 1e9)),
    )
)


@settings(
    max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(cloud=clouds, ext=st.sampled_from([".pcd", ".ply", ".npz", ".npy", ".csv", ".xyz"]))
def test_hypothesis_round_trip(tmp_path: Path, cloud: PointCloud, ext: str) -> None:
    # float32-representable coordinates survive every format exactly
    path = tmp_path / ("h" + ext)
    sio.write_points(path, cloud)
    _assert_same(cloud, sio.read_points(path), exact=True)


@settings(
    max_examples=20, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(cloud=clouds, data=st.sampled_from(["binary", "ascii", "binary_compressed"]))
def test_hypothesis_pcd_modes(tmp_path: Path, cloud: PointCloud, data: str) -> None:
    sio.write_pcd(tmp_path / "h.pcd", cloud, data=data, precision="float64")  # type: ignore[arg-type]
    _assert_same(cloud, sio.read_pcd(tmp_path / "h.pcd"), exact=True)


# --- real files -----------------------------------------------------------------------------
KITTI_COUNTS = {0: 124668, 1: 124605, 15: 121023}


def test_kitti_bin_counts() -> None:
    folder = data_dir(KITTI, "velodyne")
    files = sorted(folder.glob("*.bin"))
    assert len(files) == 16
    for path in files:
        cloud = sio.read_points(path)
        assert len(cloud) == path.stat().st_size // 16
        assert (
            cloud.intensity is not None and 0 <= cloud.intensity.min() <= cloud.intensity.max() <= 1
        )
    assert len(sio.read_points(files[0])) == 124668
    assert min(len(sio.read_points(f)) for f in files[-2:]) >= 120_295


def test_original_pcd_matches_bin() -> None:
    pcd = sio.read_points(data_dir(KITTI, "original_pcd", "000000.pcd"))
    assert len(pcd) == 124668
    assert set(pcd.fields) == {"normal_x", "normal_y", "normal_z", "curvature"}
    bin0 = sio.read_points(data_dir(KITTI, "velodyne", "000000.bin"))
    np.testing.assert_array_equal(pcd.points, bin0.points)  # README: xyz copied bit-exactly
    np.testing.assert_allclose(pcd.intensity / 255.0, bin0.intensity, rtol=1e-6)  # type: ignore[operator]


def test_gicp_pair_ply_equals_pcd() -> None:
    for ply, pcd, n in [
        ("source.ply", "251371071.pcd", 69792),
        ("target.ply", "251370668.pcd", 69088),
    ]:
        a = sio.read_points(data_dir(GICP, "small_gicp", ply))
        b = sio.read_points(data_dir(GICP, "fast_gicp", pcd))
        assert len(a) == len(b) == n
        np.testing.assert_array_equal(a.points, b.points)
        np.testing.assert_array_equal(a.intensity, b.intensity)  # type: ignore[arg-type]
        assert a.intensity is not None and 100 < a.intensity.max() <= 255
        np.testing.assert_array_equal(a.intensity, np.round(a.intensity))  # integer-valued


def test_real_pcd_survives_binary_compressed(tmp_path: Path) -> None:
    cloud = sio.read_points(data_dir(KITTI, "original_pcd", "000000.pcd"))
    sio.write_pcd(tmp_path / "c.pcd", cloud, data="binary_compressed")
    assert (tmp_path / "c.pcd").stat().st_size < 0.9 * 124668 * 32
    _assert_same(cloud, sio.read_points(tmp_path / "c.pcd"), exact=True)


@pytest.mark.parametrize("name", ["a.pcd", "a.ply", "a.las"])
@pytest.mark.parametrize("kind", ["float64", "float32", "list", "int32"])
def test_write_points_takes_an_n_by_3_array(tmp_path: Path, name: str, kind: str) -> None:
    """Issue 40: ``write_points(path, array)`` raised TypeError; the points alone now round-trip
    through PCD, PLY and LAS as a cloud of them would (values on LAS's millimetre grid, and
    exact in float32 for PCD/PLY's default precision)."""
    if name.endswith(".las"):
        pytest.importorskip("laspy")
    rng = np.random.default_rng(4)
    grid = np.round(rng.uniform(-50, 50, (200, 3)), 3).astype(np.float32).astype(np.float64)
    given: object = {
        "float64": grid,
        "float32": grid.astype(np.float32),
        "list": grid.tolist(),
        "int32": np.rint(grid).astype(np.int32),
    }[kind]
    expected = np.rint(grid) if kind == "int32" else grid
    sio.write_points(tmp_path / name, given)
    back = sio.read_points(tmp_path / name)
    assert back.ring is None and back.time is None
    if name.endswith(".las"):  # LAS always has an intensity field: zero when not given
        assert back.intensity is not None and not back.intensity.any()
        np.testing.assert_allclose(back.points, expected, atol=5e-4, rtol=0)
    else:
        np.testing.assert_array_equal(back.points, expected)
    # the same file as from a PointCloud of those points
    sio.write_points(tmp_path / f"b{name[1:]}", PointCloud(points=np.asarray(given)))
    assert (tmp_path / name).read_bytes() == (tmp_path / f"b{name[1:]}").read_bytes()


def test_write_points_takes_2d_points_where_the_format_holds_them(tmp_path: Path) -> None:
    xy = np.array([[0.5, 1.0], [2.0, -3.25]])
    for name in ("a.csv", "a.xyz", "a.npy", "a.npz"):
        sio.write_points(tmp_path / name, xy)
        np.testing.assert_array_equal(sio.read_points(tmp_path / name).points, xy)
    for name, fmt in (("a.pcd", "PCD"), ("a.ply", "PLY"), ("a.bin", "KITTI .bin")):
        with pytest.raises(ValueError, match=rf"cloud: {fmt} stores 3D points, got shape \(2, 2\)"):
            sio.write_points(tmp_path / name, xy)
        assert not (tmp_path / name).exists()
    bad: list[tuple[object, type[Exception], str]] = [
        (np.zeros((4, 4)), ValueError, r"cloud: expected shape \(N, 2\) or \(N, 3\), got \(4, 4\)"),
        (np.zeros(3), ValueError, r"cloud: expected shape"),
        ("points.txt", TypeError, r"cloud: expected a scanreg.io.PointCloud or an \(N, 3\) array"),
        (None, TypeError, r"cloud: expected a scanreg.io.PointCloud"),
        ([["a", "b", "c"]], TypeError, r"cloud"),
    ]
    for value, error, message in bad:
        with pytest.raises(error, match=message):
            sio.write_points(tmp_path / "c.pcd", value)
