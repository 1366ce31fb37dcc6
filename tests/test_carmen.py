"""CARMEN log reader: real-file counts and values, beam geometry, motion prior, hostile files."""

from __future__ import annotations

import gzip
import math
import tempfile
from pathlib import Path

import numpy as np
import pytest
from conftest import data_dir
from hypothesis import given, settings
from hypothesis import strategies as st
from scanreg import SE2
from scanreg.io import FileFormatError, read_carmen, read_scans
from scanreg.io.carmen import flaser_angles


def _raw_lines(path: Path) -> list[list[str]]:
    """The file's lines split on whitespace — an independent count, not the reader's."""
    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "rt") as fh:
        return [line.split() for line in fh]


@pytest.mark.parametrize(
    ("folder", "name", "beams", "status"),
    [
        ("carmen-intel", "intel_gfs_subset_clf_timestamps.clf", 180, "ok"),
        ("carmen-intel", "intel.gfs.log", 180, "non_monotonic"),
        ("carmen-mbicp-laserazos", "laserazosSM3.log", 361, "all_zero"),
        ("carmen-radish-corrected", "belgioioso-corrected.log.gz", 361, "coarse"),
        ("carmen-radish-corrected", "orebro-corrected.log.gz", 181, "all_zero"),
        ("carmen-radish-corrected", "infinite-corridor-corrected.log.gz", 180, "non_monotonic"),
        ("carmen-radish-corrected", "freiburg-101-corrected.log.gz", 360, "ok"),
    ],
)
def test_real_logs_counts_and_values(folder: str, name: str, beams: int, status: str) -> None:
    path = data_dir(folder, name)
    raw = _raw_lines(path)
    flaser = [p for p in raw if p and p[0] == "FLASER"]
    odom = [p for p in raw if p and p[0] == "ODOM"]
    log = read_scans(path)
    assert len(log) == len(flaser) > 0
    assert len(log.odometry) == len(odom)
    assert {len(s) for s in log.scans} == {beams}
    assert log.time_status == status
    # The last scan's values, straight from its tokens.
    last, tokens = log.scans[-1], flaser[-1]
    n = int(tokens[1])
    np.testing.assert_array_equal(last.ranges, np.array(tokens[2 : 2 + n], dtype=float))
    assert last.laser_pose is not None and last.odometry_pose is not None
    np.testing.assert_array_equal(last.laser_pose, np.array(tokens[2 + n : 5 + n], dtype=float))
    np.testing.assert_array_equal(last.odometry_pose, np.array(tokens[5 + n : 8 + n], dtype=float))
    assert last.timestamp == float(tokens[8 + n])
    assert last.line == max(i for i, p in enumerate(raw, 1) if p and p[0] == "FLASER")
    if odom:
        np.testing.assert_array_equal(log.odometry.poses[-1], np.array(odom[-1][1:4], dtype=float))
        assert log.odometry.timestamps[-1] == float(odom[-1][7])


def test_nan_tokens_are_invalid_beams() -> None:
    log = read_carmen(data_dir("carmen-mbicp-laserazos", "laserazosSM3.log"))
    ranges = np.concatenate([s.ranges for s in log.scans])
    assert int(np.isnan(ranges).sum()) == 19234  # the README's count
    assert sum(bool(np.isnan(s.ranges).any()) for s in log.scans) == 571
    scan = next(s for s in log.scans if np.isnan(s.ranges).any())
    mask = scan.valid()
    assert mask.sum() == np.isfinite(scan.ranges).sum()
    assert scan.to_points().shape == (int(mask.sum()), 2)
    assert np.isfinite(scan.to_points()).all()


def test_intel_subset_motion_prior_is_relative_odometry() -> None:
    log = read_carmen(data_dir("carmen-intel", "intel_gfs_subset_clf_timestamps.clf"))
    poses = log.odometry_poses()
    i, j = 10, 11
    prior = log.motion_prior(i, j)
    world_j = SE2.from_vector(poses[i]) @ prior
    np.testing.assert_allclose(world_j.as_vector(), poses[j], atol=1e-12)
    assert log.motion_prior(i, i).is_close(SE2.identity())
    # Laser mounting: the prior moves to the laser frame by conjugation.
    mount = SE2.from_vector([0.3, 0.0, 0.0])
    conj = log.motion_prior(i, j, T_robot_laser=mount)
    assert (mount @ conj).is_close(prior @ mount, atol=1e-12)
    with pytest.raises(IndexError, match="j: scan index"):
        log.motion_prior(0, len(log))


def test_flaser_beam_geometry() -> None:
    a180, a181, a360, a361 = (flaser_angles(n) for n in (180, 181, 360, 361))
    assert a180[0] == -math.pi / 2 and math.isclose(a180[1] - a180[0], math.radians(1))
    assert math.isclose(a180[-1], math.radians(89))
    assert math.isclose(a181[-1], math.pi / 2) and math.isclose(a361[-1], math.pi / 2)
    assert math.isclose(a360[1] - a360[0], math.radians(0.5))


def _flaser(ranges: list[str], tail: str = "1 2 0.5 1 2 0.5 10.0 host 10.0") -> str:
    return f"FLASER {len(ranges)} {' '.join(ranges)} {tail}\n"


def test_points_range_limits_keep_beam_angles(tmp_path: Path) -> None:
    path = tmp_path / "a.log"
    path.write_text(_flaser(["1.0", "nan", "inf", "81.83", "0.01", "2.0", "-nan", "3.0"]))
    scan = read_carmen(path).scans[0]
    assert scan.max_range == pytest.approx(81.0)
    mask = scan.valid(min_range=0.05)
    assert mask.tolist() == [True, False, False, False, False, True, False, True]
    pts = scan.to_points(min_range=0.05)
    a = scan.angles[mask]
    np.testing.assert_allclose(pts, np.c_[[1.0, 2.0, 3.0]] * np.c_[np.cos(a), np.sin(a)])
    assert scan.to_points(min_range=0.05, max_range=2.5).shape == (2, 2)
    with pytest.raises(ValueError, match="max_range"):
        scan.valid(min_range=3.0, max_range=2.0)


def test_new_style_messages(tmp_path: Path) -> None:
    path = tmp_path / "new.log"
    ranges = " ".join(["1.5"] * 5)
    path.write_text(
        "# comment\nPARAM robot_x 1 host 0\n"
        f"ROBOTLASER1 0 -1.0 2.0 0.5 30.0 0.01 0 5 {ranges} 0 "
        "1 2 0.1 0.9 2 0.1 0.2 0.01 1 1 0 100.5 host 100.6\n"
        f"RAWLASER1 0 -1.0 2.0 0.5 30.0 0.01 0 5 {ranges} 2 7 8 101.5 host 101.6\n"
        "ODOM 0.9 2 0.1 0.2 0.01 0 100.4 host 100.4\n"
    )
    log = read_carmen(path)
    robot, raw = log.scans
    assert (robot.kind, raw.kind) == ("ROBOTLASER1", "RAWLASER1")
    np.testing.assert_allclose(robot.angles, [-1.0, -0.5, 0.0, 0.5, 1.0])
    assert robot.max_range == 30.0 and robot.timestamp == 100.5
    np.testing.assert_array_equal(robot.laser_pose, [1, 2, 0.1])
    np.testing.assert_array_equal(robot.odometry_pose, [0.9, 2, 0.1])
    assert raw.laser_pose is None and raw.logger_timestamp == 101.6
    assert log.skipped == {"PARAM": 1}
    np.testing.assert_array_equal(log.odometry.velocities, [[0.2, 0.01, 0.0]])
    with pytest.raises(ValueError, match="RAWLASER1 has no odometry"):
        log.motion_prior(0, 1)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        (_flaser(["1.0", "2.0"], tail="1 2 0.5 1 2"), "line 1: FLASER: expected at least"),
        ("FLASER 5 1 2\n", r"line 1: FLASER beam count: 5 but only 2"),
        ("FLASER x 1 2\n", "line 1: FLASER beam count: 'x' is not a count"),
        ("FLASER -3 1 2\n", "not a non-negative integer"),
        (_flaser(["1.0", "abc"]), "line 1: FLASER ranges: 'abc' is not a number"),
        (_flaser(["1.0", "-2.0"]), "negative range"),
        (_flaser(["1.0"], tail="1 nan 0.5 1 2 0.5 10 h 10"), "FLASER poses: non-finite"),
        ("# c\nODOM 1 2\n", "line 2: ODOM: expected at least 10"),
        ("ODOM 1 2 3 0 0 0 q host 1\n", "ODOM ipc_timestamp: 'q' is not a number"),
        ("1.0 2.0 3.0\n", "unknown message"),
        ("# only a comment\nPARAM a b\n", "no laser scan and no ODOM"),
        ("", "no laser scan"),
    ],
)
def test_hostile_files_name_file_and_line(tmp_path: Path, text: str, match: str) -> None:
    path = tmp_path / "bad.log"
    path.write_text(text)
    with pytest.raises(FileFormatError, match=match) as info:
        read_carmen(path)
    assert str(info.value).startswith(str(path))


def test_truncated_and_binary_files(tmp_path: Path) -> None:
    good = _flaser(["1.0", "2.0", "3.0"]) * 3
    trunc = tmp_path / "cut.log"
    trunc.write_text(good[: len(good) - 12])
    with pytest.raises(FileFormatError, match="line 3"):
        read_carmen(trunc)
    gz = tmp_path / "cut.log.gz"
    gz.write_bytes(gzip.compress(good.encode())[:-10])
    with pytest.raises(FileFormatError, match=r"cut\.log\.gz"):
        read_scans(gz)
    binary = tmp_path / "bin.clf"
    binary.write_bytes(bytes(range(256)) * 4)
    with pytest.raises(FileFormatError, match=r"bin\.clf"):
        read_scans(binary)
    ok = tmp_path / "ok.log.gz"
    ok.write_bytes(gzip.compress(good.encode()))
    assert len(read_scans(ok)) == 3
    with pytest.raises(ValueError, match="no scan reader"):
        read_scans(tmp_path / "x.bag")


_VALID_LOG = (
    "# CARMEN log\nPARAM robot_frontlaser_offset 0.0 nohost 0\n"
    + _flaser(["1.0", "NaN", "2.5", "81.83"])
    + "ODOM 0.5 0.25 0.1 0.2 0.01 0 10.5 host 10.5\n"
    + "ROBOTLASER1 0 -1.0 2.0 0.5 30.0 0.01 0 3 1 2 3 0 1 2 0.1 0.9 2 0.1 0.2 0.01 1 1 0 11 h 11\n"
    + "RAWLASER1 0 -1.0 2.0 1.0 30.0 0.01 0 3 1 2 3 1 7 12.5 h 12.5\n"
    + "NEFF 42\n"
).encode()


@settings(max_examples=300, deadline=None)
@given(
    cut=st.floats(0, 1),
    edits=st.lists(st.tuples(st.floats(0, 1), st.integers(0, 255)), max_size=4),
    insert=st.binary(max_size=8),
    gz=st.booleans(),
)
def test_fuzz_mutated_logs(
    cut: float, edits: list[tuple[float, int]], insert: bytes, gz: bool
) -> None:
    """Any mutation of a valid log either reads or raises FileFormatError — nothing else."""
    raw = bytearray(_VALID_LOG)
    for where, value in edits:
        raw[int(where * (len(raw) - 1))] = value
    pos = int(cut * len(raw))
    data = bytes(raw[:pos]) + insert + bytes(raw[pos:]) if insert else bytes(raw[: max(pos, 1)])
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / ("f.log.gz" if gz else "f.log")
        path.write_bytes(gzip.compress(data) if gz else data)
        try:
            log = read_scans(path)
        except FileFormatError as exc:
            assert str(exc).startswith(str(path))
            return
        for scan in log.scans:
            assert scan.ranges.shape == scan.angles.shape
            pts = scan.to_points()
            assert np.isfinite(pts).all()
