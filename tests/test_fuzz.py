"""Hostile files: the CI smoke pass of every fuzz target (``fuzz/targets.py``: its seeds and a
few structured mutations of each, no coverage guidance — the campaign, ``fuzz/campaign.sh``,
does that), and each finding of the campaigns kept as a regression test."""

from __future__ import annotations

import gzip
import multiprocessing
import operator
import os
import signal
import sys
import traceback
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from conftest import data_dir
from scanreg.io import FileFormatError, PointCloud, read_carmen, read_pcd, read_tum

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "fuzz"))
from targets import TARGETS, Runner, smoke_pass

#: Mutations per seed in the smoke pass (about 0.1-0.5 s per target).
SMOKE_MUTATIONS = 40


#: Each target's smoke pass runs in a child forked from one clean server process (scanreg
#: and the targets imported once, no threads): an input that aborts the interpreter (lazrs
#: once did: SIGABRT on a damaged LAZ chunk table) fails its test with the signal instead of
#: ending the whole test run.
_CHILDREN = multiprocessing.get_context("forkserver")
_CHILDREN.set_forkserver_preload(
    ["targets", "scanreg.io.rosbag", "scanreg.batch", "scanreg.config", "laspy", "pyarrow.parquet"]
)


#: Targets whose seeds come from our writers alone (the others read the real data folder).
WRITER_SEEDED = {
    "g2o", "config", "las", "laz", "map_server", "manifest_csv", "manifest_tsv",
    "manifest_parquet", "command_configs",
}  # fmt: skip


def _child(run: Callable[..., object], args: tuple[object, ...], report: Path) -> None:
    """In the child: ``run(*args)``, its traceback written to ``report`` on failure."""
    try:
        run(*args)
    except BaseException:
        report.write_text(traceback.format_exc())
        raise SystemExit(1) from None


def _in_a_child(run: Callable[..., object], *args: object, folder: Path) -> None:
    report = folder / "traceback.txt"
    child = _CHILDREN.Process(target=_child, args=(run, args, report))
    child.start()
    child.join(timeout=300)
    if child.exitcode is None:
        child.kill()
        child.join()
        pytest.fail("the child did not end within 300 s")
    if child.exitcode < 0:
        pytest.fail(f"the child was killed by {signal.Signals(-child.exitcode).name}")
    if child.exitcode:
        pytest.fail(f"an unnamed exception in the child:\n{report.read_text()}")


@pytest.mark.parametrize("name", sorted(TARGETS))
def test_smoke_pass(name: str, tmp_path: Path) -> None:
    if name not in WRITER_SEEDED:
        data_dir()  # the seeds come from the real data folder
    _in_a_child(smoke_pass, name, tmp_path, SMOKE_MUTATIONS, 20261203, folder=tmp_path)


def test_a_child_killed_by_a_signal_fails_by_the_signals_name(tmp_path: Path) -> None:
    """The isolation works: an abort in the child (as lazrs's was) fails the test by the
    signal's name and the test run goes on; an exception fails it with its traceback."""
    with pytest.raises(pytest.fail.Exception, match="killed by SIGABRT"):
        _in_a_child(os.abort, folder=tmp_path)
    with pytest.raises(pytest.fail.Exception, match=r"(?s)unnamed exception.*KeyError: 'k'"):
        _in_a_child(operator.getitem, {}, "k", folder=tmp_path)


def test_a_seed_is_read_without_a_refusal(tmp_path: Path) -> None:
    """The smoke pass would pass on a reader that refuses everything: its seeds must read."""
    data_dir()
    for target in TARGETS.values():
        path = tmp_path / f"seed{target.suffix}"
        path.write_bytes(target.seeds()[0])
        with warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)
            target.read(path)


def test_the_message_target_reads_each_kind_of_message(tmp_path: Path) -> None:
    """ros_msg's first byte picks the serialisation and type: each seed reads as its kind,
    and a message of one kind fed as another is a named refusal."""
    from scanreg.io.rosbag import BagCloud, RosLaserScan
    from targets import MESSAGE_KINDS, POINT_CLOUD2

    data_dir()
    target = TARGETS["ros_msg"]
    seeds = target.seeds()
    assert [s[0] for s in seeds] == list(range(len(MESSAGE_KINDS)))
    path = tmp_path / "m.msg"
    for seed, (_, msgtype) in zip(seeds, MESSAGE_KINDS, strict=True):
        path.write_bytes(seed)
        read = target.read(path)
        assert isinstance(read, BagCloud if msgtype == POINT_CLOUD2 else RosLaserScan)
        assert len(read.cloud) == 10 if isinstance(read, BagCloud) else len(read) > 100
        path.write_bytes(bytes([seed[0] ^ 1]) + seed[1:])  # the other type, same bytes
        with pytest.raises(FileFormatError, match="/fuzz message 0"):
            target.read(path)


# --- findings kept as regression tests ---------------------------------------------------


def test_corrupt_gzip_stream_in_a_carmen_log_is_a_named_error(tmp_path: Path) -> None:
    """Found by the carmen_gz target: a valid gzip header over a corrupt deflate stream raised
    zlib.error."""
    raw = bytearray(gzip.compress(b"ODOM 0 0 0 0 0 0 1.0 host 1.0\n" * 40, mtime=0))
    raw[12:20] = b"\xff" * 8  # inside the deflate stream, after the 10-byte header
    path = tmp_path / "bad.log.gz"
    path.write_bytes(bytes(raw))
    with pytest.raises(FileFormatError, match="cannot read as a CARMEN text log"):
        read_carmen(path)


def test_carmen_reads_bzip2(tmp_path: Path) -> None:
    import bz2

    text = data_dir("carmen-intel", "intel.gfs.log").read_bytes()[:20000]
    text = text[: text.rindex(b"\n") + 1]
    (tmp_path / "a.log").write_bytes(text)
    (tmp_path / "a.log.bz2").write_bytes(bz2.compress(text))
    plain, packed = read_carmen(tmp_path / "a.log"), read_carmen(tmp_path / "a.log.bz2")
    assert len(plain.scans) == len(packed.scans) > 0
    np.testing.assert_array_equal(plain.scans[-1].ranges, packed.scans[-1].ranges)


def test_tum_quaternion_overflowing_the_norm_is_refused_without_a_warning(tmp_path: Path) -> None:
    """Found by the tum target: a component of 1e308 overflowed the norm (numpy warning)."""
    path = tmp_path / "t.txt"
    path.write_text("1.0 0 0 0 0 0 1e308 1\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        with pytest.raises(FileFormatError, match="quaternion norm inf"):
            read_tum(path)


@pytest.mark.parametrize("bad", [np.nan, np.inf, 1e19, -1e300])
def test_ring_values_an_int64_cannot_hold_are_refused(bad: float, tmp_path: Path) -> None:
    """A float ring field is cast to int64: NaN, inf or a value past 2⁶³ must be refused by
    name, never cast to an arbitrary integer ("invalid value encountered in cast")."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        with pytest.raises(ValueError, match="ring: expected integer values"):
            PointCloud(points=np.zeros((2, 3)), ring=np.array([1.0, bad]))
        with pytest.raises(ValueError, match="ring: values past the int64 range"):
            PointCloud(points=np.zeros((2, 3)), ring=np.array([1, 2**63], dtype=np.uint64))
        path = tmp_path / "r.pcd"
        path.write_text(
            "VERSION .7\nFIELDS x y z ring\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\n"
            f"WIDTH 2\nHEIGHT 1\nPOINTS 2\nDATA ascii\n0 0 0 1\n1 1 1 {bad}\n"
        )
        with pytest.raises(ValueError, match="ring"):
            read_pcd(path)


def test_signalling_nan_in_a_float32_file_is_read_as_nan_without_a_warning(tmp_path: Path) -> None:
    """Found by the kitti_bin and ply targets: a float32 signalling NaN (0x7fa00000) in the
    coordinates or the intensity warned "invalid value encountered in cast" on widening."""
    from scanreg.io import read_kitti_bin

    raw = np.array([[1.0, 2.0, 3.0, 0.5], [4.0, 5.0, 6.0, 0.5]], dtype=np.float32)
    bits = raw.view(np.uint32)
    bits[0, 1] = 0x7FA00000  # a signalling NaN: y of the first point
    bits[1, 3] = 0x7FA00000  # and the second point's intensity
    path = tmp_path / "s.bin"
    raw.tofile(path)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        cloud = read_kitti_bin(path)
    assert np.isnan(cloud.points[0, 1]) and np.isnan(cloud.intensity[1])  # type: ignore[index]
    np.testing.assert_array_equal(cloud.points[1], [4.0, 5.0, 6.0])


def test_the_campaign_keeps_unnamed_exceptions_and_goes_on(tmp_path: Path) -> None:
    """With a findings folder (campaign.sh) an unnamed exception is kept (input and traceback,
    once per raising line) and counted; a named refusal is not a finding; without the folder
    (the smoke pass above, libFuzzer's default) the exception propagates."""
    from targets import Target

    def read(p: Path) -> None:
        data = p.read_bytes()
        if data.startswith(b"named"):
            raise FileFormatError(p, "refused")
        if data.startswith(b"bad"):
            raise KeyError(data.decode())

    target = Target("t", ".x", read, lambda: [b"ok"])
    findings = tmp_path / "findings"
    findings.mkdir()
    run = Runner(target, tmp_path, findings)
    for data in (b"ok", b"named", b"bad1", b"bad2", b"ok"):
        run(data)
    assert (run.executions, run.unnamed) == (5, 2)
    kept = sorted(p.name for p in findings.iterdir())
    assert len(kept) == 2 and kept[1] == kept[0] + ".txt"  # one raising line: one example
    assert (findings / kept[0]).read_bytes() == b"bad1"
    assert "KeyError: 'bad1'" in (findings / kept[1]).read_text()
    with pytest.raises(KeyError):
        Runner(target, tmp_path)(b"bad3")


def test_a_las_scale_that_overflows_the_coordinates_is_refused(tmp_path: Path) -> None:
    """Found by the las target: a header scale of -1.8e305 made laspy's ``X·scale + offset``
    overflow (numpy's "overflow encountered in multiply", the file then read as inf)."""
    from scanreg.io import read_las, write_las

    path = tmp_path / "s.las"
    write_las(path, PointCloud(points=np.ones((4, 3))), point_format=1)
    raw = bytearray(path.read_bytes())
    raw[131:139] = np.float64(-1.8e305).tobytes()  # the x scale factor
    path.write_bytes(bytes(raw))
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        with pytest.raises(FileFormatError, match=r"s\.las: corrupt header: x scale factor"):
            read_las(path)


def test_a_signalling_nan_gps_time_in_a_las_file_reads_as_nan_without_a_warning(
    tmp_path: Path,
) -> None:
    """Found by the las target: a float64 signalling NaN in GPS time warned "invalid value
    encountered in reduce" where the reader checks whether any time is set."""
    from scanreg.io import read_las, write_las

    path = tmp_path / "t.las"
    cloud = PointCloud(points=np.ones((3, 3)), time=np.array([0.0, 0.05, 0.1]))
    write_las(path, cloud, point_format=1)
    raw = bytearray(path.read_bytes())
    offset = int.from_bytes(raw[96:100], "little")
    record = int.from_bytes(raw[105:107], "little")
    # format 1: GPS time is the float64 at byte 20 of each record
    raw[offset + 20 : offset + 28] = np.uint64(0x7FF4000000000000).tobytes()
    path.write_bytes(bytes(raw))
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        read = read_las(path)
    assert read.time is not None and np.isnan(read.time[0])
    np.testing.assert_allclose(read.time[1:], [0.05, 0.1])
    assert record >= 28
