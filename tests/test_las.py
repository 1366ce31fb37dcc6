"""LAS/LAZ through laspy + lazrs: round trips (UTM-sized coordinates at millimetre scale,
intensity, GPS time, returns, ring, extra fields, CRS), unknown point formats, unwritable
paths, and LAS accepted wherever PCD is (registry, folder sequence, register, odometry)."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scanreg import SE3, cli
from scanreg.io import (
    READERS,
    WRITERS,
    FileFormatError,
    PointCloud,
    open_sequence,
    read_las_header,
    read_points,
    write_points,
)

pytest.importorskip("laspy", reason="laspy is not installed (pip install 'scanreg[las]')")
pytest.importorskip("lazrs", reason="lazrs is not installed (pip install 'scanreg[las]')")

UTM = np.array([500_000.0, 5_000_000.0, 250.0])
#: The package this test file belongs to (for a child interpreter).
_PYTHON = Path(__file__).resolve().parent.parent / "python"
WKT = 'PROJCS["WGS 84 / UTM zone 32N",GEOGCS["WGS 84"],UNIT["metre",1]]'


def _utm_cloud(n: int = 2000, seed: int = 0) -> PointCloud:
    rng = np.random.default_rng(seed)
    # on the millimetre grid around the UTM origin, ±1 km
    points = UTM + rng.integers(-1_000_000, 1_000_000, (n, 3)) * 1e-3
    return PointCloud(
        points=points,
        intensity=rng.integers(0, 65536, n).astype(float),
        ring=rng.integers(0, 128, n),
        time=1.4e9 + np.sort(rng.uniform(0, 0.1, n)),  # adjusted standard GPS time
        fields={
            "return_number": rng.integers(1, 4, n),
            "number_of_returns": np.full(n, 3),
            "classification": rng.integers(0, 20, n),
            "normal_x": rng.normal(size=n),
        },
    )


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_round_trip_keeps_every_field_and_exact_utm_coordinates(
    tmp_path: Path, suffix: str
) -> None:
    cloud = _utm_cloud()
    path = tmp_path / f"map{suffix}"
    write_points(path, cloud, scale=0.001, offset=UTM, crs_wkt=WKT)
    back = read_points(path)
    # on the grid with the grid's offset: bit-identical float64
    assert np.array_equal(back.points, cloud.points)
    assert np.array_equal(back.intensity, cloud.intensity)
    assert np.array_equal(back.time, cloud.time)  # float64 GPS time, exact
    assert np.array_equal(back.ring, cloud.ring)
    for name, values in cloud.fields.items():
        assert np.array_equal(back.fields[name], values), name
    header = read_las_header(path)
    assert header.crs_wkt == WKT
    assert header.compressed == (suffix == ".laz") and header.point_format == 6
    np.testing.assert_array_equal(header.offset, UTM)
    np.testing.assert_array_equal(header.scale, [0.001] * 3)
    assert os.listdir(tmp_path) == [path.name]  # no temporary file left


def test_default_offset_and_off_grid_values(tmp_path: Path) -> None:
    cloud = _utm_cloud()
    write_points(tmp_path / "a.laz", cloud)  # default offset: the minimum, whole metres
    back = read_points(tmp_path / "a.laz")
    header = read_las_header(tmp_path / "a.laz")
    np.testing.assert_array_equal(header.offset, np.floor(cloud.points.min(axis=0)))
    # the same grid, another origin: float64 rounding only (measured 2.3e-13 m)
    assert np.abs(back.points - cloud.points).max() < 1e-9
    rng = np.random.default_rng(1)
    anywhere = PointCloud(points=UTM + rng.uniform(-1000, 1000, (5000, 3)))
    write_points(tmp_path / "b.las", anywhere, scale=0.01)
    err = np.abs(read_points(tmp_path / "b.las").points - anywhere.points).max()
    assert 0.004 < err <= 0.005 + 1e-9  # half the scale, and it is reached


def test_float_reflectance_and_formats_without_time(tmp_path: Path) -> None:
    rng = np.random.default_rng(2)
    kitti_like = PointCloud(points=rng.normal(size=(100, 3)), intensity=rng.uniform(0, 1, 100))
    write_points(tmp_path / "k.las", kitti_like)
    back = read_points(tmp_path / "k.las")
    np.testing.assert_array_equal(back.intensity, kitti_like.intensity)  # via extra bytes
    assert back.time is None  # format 6 has the field, but all zeros are no times
    with pytest.raises(ValueError, match="point_format: format 0 has no GPS time"):
        write_points(tmp_path / "t.las", _utm_cloud(), point_format=0)
    plain = PointCloud(points=kitti_like.points)
    write_points(tmp_path / "p0.las", plain, point_format=0)
    assert read_las_header(tmp_path / "p0.las").version == "1.2"
    assert read_points(tmp_path / "p0.las").time is None


def test_unknown_point_format_is_a_clear_error(tmp_path: Path) -> None:
    path = tmp_path / "odd.las"
    write_points(path, PointCloud(points=np.zeros((3, 3))))
    raw = bytearray(path.read_bytes())
    raw[104] = 42  # "point data record format" in the public header block
    path.write_bytes(bytes(raw))
    message = r"odd\.las: unknown LAS point format 42 \(LAS 1\.4 defines formats 0-10\)"
    with pytest.raises(FileFormatError, match=message):
        read_points(path)
    with pytest.raises(FileFormatError, match=r"odd\.las: unknown LAS point format"):
        read_las_header(path)
    (tmp_path / "empty.laz").write_bytes(b"")
    with pytest.raises(FileFormatError, match=r"empty\.laz: empty file"):
        read_points(tmp_path / "empty.laz")
    (tmp_path / "junk.las").write_bytes(b"LASF" + b"\0" * 50)
    with pytest.raises(FileFormatError, match=r"junk\.las: truncated header \(54 of 227"):
        read_points(tmp_path / "junk.las")
    (tmp_path / "not.las").write_bytes(b"PK\x03\x04" + b"\0" * 400)
    with pytest.raises(FileFormatError, match=r"not\.las: not a LAS/LAZ file"):
        read_points(tmp_path / "not.las")


def test_bad_writes_name_the_problem_and_leave_nothing(tmp_path: Path) -> None:
    cloud = _utm_cloud(100)
    # UTM coordinates without an offset at µm scale: refused, never wrapped
    with pytest.raises(ValueError, match=r"scale: coordinates span .* overflow LAS's int32"):
        write_points(tmp_path / "a.las", cloud, scale=1e-6, offset=(0, 0, 0))
    bad = PointCloud(points=cloud.points, fields={"return_number": np.full(100, 1.5)})
    with pytest.raises(ValueError, match=r"fields\['return_number'\] must hold integers"):
        write_points(tmp_path / "a.las", bad)
    with pytest.raises(ValueError, match=r"crs_wkt: a WKT CRS needs a LAS 1\.4 point format"):
        write_points(tmp_path / "a.las", PointCloud(points=cloud.points), point_format=1,
                     crs_wkt=WKT)  # fmt: skip
    with pytest.raises(ValueError, match="cloud: LAS stores 3D points"):
        write_points(tmp_path / "a.las", PointCloud(points=np.zeros((3, 2))))
    assert os.listdir(tmp_path) == []
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(FileNotFoundError, match="cannot write there: no folder"):
        write_points(blocker / "a.las", cloud)
    with pytest.raises(PermissionError, match=r"/proc/a.laz: cannot write there"):
        write_points("/proc/a.laz", cloud)
    # an existing file survives a failed overwrite
    write_points(tmp_path / "keep.las", cloud)
    before = (tmp_path / "keep.las").read_bytes()
    with pytest.raises(ValueError, match="must hold integers"):
        write_points(tmp_path / "keep.las", bad)
    assert (tmp_path / "keep.las").read_bytes() == before
    assert sorted(os.listdir(tmp_path)) == ["file", "keep.las"]


def test_las_is_accepted_wherever_pcd_is(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert READERS[".las"] is READERS[".laz"] and ".laz" in WRITERS
    # a folder of LAZ sweeps from the simulator, with absolute GPS times
    assert cli.main(["simulate", "--scene", "street", "--sensor", "vlp16", "--scans", "3",
                     "--speed", "8", "--format", "laz", "-o", str(tmp_path / "run"), "--json",
                     ]) == cli.EXIT_OK  # fmt: skip
    capsys.readouterr()
    relative = read_points(tmp_path / "run" / "000001.laz")
    shifted = PointCloud(
        points=relative.points, ring=relative.ring, time=relative.time + 1_234_567.25
    )
    write_points(tmp_path / "run" / "000001.laz", shifted)
    seq = open_sequence(tmp_path / "run")
    assert len(seq) == 3 and seq.ground_truth is not None
    frame = seq[1]
    assert frame.timestamps is not None
    # absolute GPS time made relative to the sweep's first point (float64: µs-exact at 1e6 s)
    np.testing.assert_allclose(frame.timestamps, relative.time - relative.time.min(), atol=1e-6)
    assert 0.05 < np.ptp(frame.timestamps) <= 0.1
    # scanreg register: two sweeps of the drive
    assert cli.main(["register", str(tmp_path / "run" / "000001.laz"),
                     str(tmp_path / "run" / "000000.laz"), "--method", "gicp", "--voxel-size",
                     "0.3", "--json"]) in (cli.EXIT_OK, cli.EXIT_CHECK_FAILED)  # fmt: skip
    reg = json.loads(capsys.readouterr().out)
    truth = seq.ground_truth
    expected = SE3.from_matrix(np.linalg.inv(truth[0]) @ truth[1]).translation
    assert np.linalg.norm(np.array(reg["pose"])[:3, 3] - expected) < 0.2
    # scanreg odometry over the folder, writing its map as LAZ with a UTM offset and CRS
    out = tmp_path / "out"
    assert cli.main(["odometry", str(tmp_path / "run"), "-o", str(out), "--no-plots",
                     "--save-map", "--map-format", "laz", "--map-origin", "500000.5",
                     "5000000.25", "210", "--las-offset", "500000", "5000000", "200", "--crs",
                     WKT, "--json", "--report"]) == cli.EXIT_OK  # fmt: skip
    result = json.loads(capsys.readouterr().out)
    assert result["frames"] == 3
    header = read_las_header(out / "map.laz")
    assert header.crs_wkt == WKT and header.point_count == result["map_points"]
    np.testing.assert_array_equal(header.offset, [500000, 5000000, 200])
    mapped = read_points(out / "map.laz").points
    # the ground (1.73 m below the sensor at the map origin) lands at the origin's height
    assert abs(np.percentile(mapped[:, 2], 5) - (210 - 1.73)) < 0.3
    assert np.abs(np.median(mapped[:, :2], axis=0) - [500000.5, 5000000.25]).max() < 50
    assert (out / "report.html").stat().st_size > 3_000_000


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_corrupted_files_fail_cleanly_and_fast(tmp_path: Path, suffix: str) -> None:
    """Random byte flips, truncations and overwritten header fields: every read returns a
    cloud or raises FileFormatError — a flipped VLR count once made laspy loop for minutes,
    a flipped point count would allocate terabytes (the header is checked first)."""
    rng = np.random.default_rng(7)
    cloud = PointCloud(points=rng.normal(size=(300, 3)) * 10, time=rng.uniform(0, 0.1, 300),
                       intensity=rng.integers(0, 100, 300).astype(float))  # fmt: skip
    good = tmp_path / f"good{suffix}"
    write_points(good, cloud)
    raw = good.read_bytes()
    outcomes = {"read": 0, "refused": 0}
    for trial in range(90):
        data = bytearray(raw)
        if trial % 3 == 0:
            for _ in range(rng.integers(1, 10)):
                data[rng.integers(0, len(data))] = rng.integers(0, 256)
        elif trial % 3 == 1:
            data = data[: rng.integers(0, len(data))]
        else:  # a header field: counts, offsets, sizes
            at = int(rng.integers(90, 380))
            data[at : at + 4] = rng.integers(0, 256, 4).astype(np.uint8).tobytes()
        bad = tmp_path / f"bad{suffix}"
        bad.write_bytes(bytes(data))
        try:
            read_points(bad)
            outcomes["read"] += 1
        except FileFormatError as exc:
            assert str(exc).startswith(str(bad))
            outcomes["refused"] += 1
    assert outcomes["refused"] > 20 and outcomes["read"] + outcomes["refused"] == 90


def _chunk_table_at(raw: bytes) -> int:
    """Where a LAZ file's chunk table starts (the int64 after the offset to point data)."""
    offset = int.from_bytes(raw[96:100], "little")
    return int.from_bytes(raw[offset : offset + 8], "little", signed=True)


def _read_in_a_child(path: Path) -> subprocess.CompletedProcess[str]:
    """``read_points(path)`` in a fresh interpreter that prints what it raised: an abort
    inside lazrs (SIGABRT) kills only the child, and the test sees the signal."""
    code = (
        "import sys\n"
        "from scanreg.io import FileFormatError, read_points\n"
        "try:\n"
        "    read_points(sys.argv[1])\n"
        "    print('read')\n"
        "except FileFormatError as exc:\n"
        "    print('FileFormatError:', exc)\n"
    )
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(_PYTHON), *sys.path])}
    return subprocess.run(
        [sys.executable, "-c", code, str(path)],
        capture_output=True, text=True, timeout=120, env=env, check=False,
    )  # fmt: skip


@pytest.mark.parametrize(
    "damage",
    ["chunk count", "chunk table offset", "truncated", "chunk bytes"],
)
def test_a_damaged_laz_chunk_table_is_a_named_error_in_a_process_that_survives(
    tmp_path: Path, damage: str
) -> None:
    """Issue 40: a chunk table claiming 2³¹ chunks made lazrs abort the interpreter
    ("memory allocation of 34359738352 bytes failed", SIGABRT inside lazrs: no exception,
    every thread of a batch worker gone). The chunk table is now checked against the file
    first; the child process exits normally with a FileFormatError naming the field."""
    rng = np.random.default_rng(3)
    good = tmp_path / "good.laz"
    write_points(good, PointCloud(points=rng.normal(size=(60_000, 3)) * 10))
    raw = bytearray(good.read_bytes())
    table = _chunk_table_at(bytes(raw))
    assert 0 < table < len(raw) - 8
    if damage == "chunk count":
        raw[table + 4 : table + 8] = (2**31 - 1).to_bytes(4, "little")
        expected = r"corrupt LAZ chunk table: number of chunks 2147483647"
    elif damage == "chunk table offset":
        offset = int.from_bytes(raw[96:100], "little")
        raw[offset : offset + 8] = (len(raw) + 10**9).to_bytes(8, "little")
        expected = r"LAZ chunk table offset \d+ is past the end of the file"
    elif damage == "truncated":
        raw = raw[: len(raw) // 2]
        expected = r"LAZ chunk table offset \d+ is past the end of the file"
    else:  # the table's compressed entries overwritten: byte counts beyond the points
        raw[table + 8 :] = b"\xff" * (len(raw) - table - 8)
        expected = r"corrupt LAZ chunk table"
    bad = tmp_path / "bad.laz"
    bad.write_bytes(bytes(raw))
    done = _read_in_a_child(bad)
    assert done.returncode == 0, (
        f"the reading process died (exit {done.returncode}"
        f"{', ' + signal.Signals(-done.returncode).name if done.returncode < 0 else ''}): "
        f"{done.stderr[-2000:]}"
    )
    assert re.search(rf"FileFormatError: .*bad\.laz: {expected}", done.stdout), done.stdout
    if damage == "chunk count":  # the checks pass a sound file
        assert _read_in_a_child(good).stdout.strip() == "read"


def test_a_laz_layer_larger_than_its_chunk_is_refused_at_once(tmp_path: Path) -> None:
    """Found by the laz target (a 1.5 kB file, 6-15 s per read): a layered chunk (point
    formats 6-10) lists one byte count per layer after its raw first point, and lazrs
    zero-fills a buffer of each count before reading it — 27 GB claimed, seconds of memset,
    and an abort once the memory is not there. Each layer must fit in its chunk."""
    import time

    path = tmp_path / "l.laz"
    write_points(path, PointCloud(points=np.random.default_rng(5).normal(size=(500, 3))))
    raw = bytearray(path.read_bytes())
    first_chunk = int.from_bytes(raw[96:100], "little") + 8
    record = int.from_bytes(raw[105:107], "little")
    sizes = first_chunk + record + 4  # after the raw first point and the chunk's point count
    raw[sizes + 4 : sizes + 8] = (2**32 - 1).to_bytes(4, "little")  # the z layer: 4 GB
    path.write_bytes(bytes(raw))
    start = time.perf_counter()
    with pytest.raises(FileFormatError, match=r"l\.laz: corrupt LAZ chunk 0: its layers claim"):
        read_points(path)
    assert time.perf_counter() - start < 1.0


def _laszip_items_at(raw: bytes) -> int:
    """Where the laszip VLR's item list (``(type, size, version)`` uint16 each) starts."""
    at = int.from_bytes(raw[94:96], "little")  # the header's size: the first VLR
    for _ in range(int.from_bytes(raw[100:104], "little")):
        length = int.from_bytes(raw[at + 20 : at + 22], "little")
        if raw[at + 2 : at + 18].rstrip(b"\0") == b"laszip encoded":
            return at + 54 + 34
        at += 54 + length
    raise AssertionError("no laszip VLR")


def _laz_with_items_changed(tmp_path: Path, point_format: int) -> tuple[Path, Path, int]:
    """A sound LAZ of ``point_format`` (with extra bytes) and a copy whose first laszip item
    type is one higher (POINT10 -> GPSTIME11, POINT14 -> RGB14): ``(good, bad, new type)``."""
    from scanreg.io import write_las

    rng = np.random.default_rng(point_format)
    cloud = PointCloud(points=rng.normal(size=(50, 3)), ring=np.arange(50) % 4)
    good = tmp_path / "good.laz"
    write_las(good, cloud, point_format=point_format)
    raw = bytearray(good.read_bytes())
    items = _laszip_items_at(bytes(raw))
    changed = int.from_bytes(raw[items : items + 2], "little") + 1
    raw[items : items + 2] = changed.to_bytes(2, "little")
    bad = tmp_path / "bad.laz"
    bad.write_bytes(bytes(raw))
    return good, bad, changed


@pytest.mark.parametrize("point_format", range(11))
def test_laszip_items_must_be_the_point_formats(tmp_path: Path, point_format: int) -> None:
    """lazrs decodes by the laszip VLR's items, laspy reads by the header's point format:
    the items must be the format's (as lazrs writes them, extra bytes included)."""
    good, bad, changed = _laz_with_items_changed(tmp_path, point_format)
    assert read_points(good).ring is not None
    with pytest.raises(
        FileFormatError,
        match=rf"bad\.laz: laszip VLR items \(type, bytes\) \[\({changed}, .* are not point "
        rf"format {point_format}'s",
    ):
        read_points(bad)


def test_a_laz_with_an_rgb14_item_for_point14_is_refused_at_once_in_1_gb(tmp_path: Path) -> None:
    """Found by the laz target: one byte turned the POINT14 item of a 1.5 kB file into a
    30-byte RGB14 (the record length unchanged); lazrs took 2.6 s and 2 GB before refusing
    it (a libFuzzer timeout; an abort where the memory is not there). Refused at once, in a
    child process capped at 1 GB of address space."""
    _, bad, _ = _laz_with_items_changed(tmp_path, 6)
    code = (
        "import resource, sys, time\n"
        "resource.setrlimit(resource.RLIMIT_AS, (1 << 30, 1 << 30))\n"
        "from scanreg.io import FileFormatError, read_points\n"
        "start = time.perf_counter()\n"
        "try:\n"
        "    read_points(sys.argv[1])\n"
        "    print('read')\n"
        "except FileFormatError as exc:\n"
        "    print('FileFormatError:', exc, f'in {time.perf_counter() - start:.2f} s')\n"
    )
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(_PYTHON), *sys.path])}
    done = subprocess.run(
        [sys.executable, "-c", code, str(bad)],
        capture_output=True, text=True, timeout=120, env=env, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    match = re.search(r"FileFormatError: .*bad\.laz: laszip VLR items .* in (\S+) s", done.stdout)
    assert match, done.stdout
    assert float(match.group(1)) < 0.5
