"""The 2D mapper's odometry in a child process (scanreg.pipeline.odometry_process): the same
map as on a second thread, to the bit; Ctrl-C and errors in the child reach the caller with
what was mapped, and leave no child behind."""

from __future__ import annotations

import copy
import dataclasses
import os
from pathlib import Path

import numpy as np
import pytest
from scanreg.io.scan_log import ScanLog
from scanreg.pipeline import MappingConfig, odometry_process, run_mapping
from scanreg.pipeline.mapping import Mapper, MappingInterrupted, track_scan
from scanreg.pipeline.odometry_process import available

from tests._sim_scan_log import tour_log

pytestmark = pytest.mark.skipif(not available(), reason="no child process on this platform")
pytest.importorskip("gtsam", reason="mapping needs the `mapping` extra (gtsam)")

SCANS = 150


def _children() -> list[int]:
    """This process's live odometry children (Linux; none elsewhere). Other tests may leave
    children of their own (a multiprocessing fork server): only ours are counted."""
    path = Path(f"/proc/{os.getpid()}/task/{os.getpid()}/children")
    if not path.exists():
        return []
    ours = []
    for pid in path.read_text().split():
        try:
            cmdline = Path(f"/proc/{pid}/cmdline").read_bytes()
        except OSError:  # gone meanwhile
            continue
        if b"odometry_process" in cmdline:
            ours.append(int(pid))
    return ours


@pytest.fixture(scope="module")
def log() -> ScanLog:
    return tour_log(0, "laser_360", beam_times=False, odometry=True)[0]


def test_the_process_maps_what_the_thread_maps(log: ScanLog) -> None:
    cfg = MappingConfig()
    threaded = run_mapping(log, cfg, max_scans=SCANS, odometry_process=False)
    child = run_mapping(log, cfg, max_scans=SCANS, odometry_process=True)
    assert len(child.poses) == SCANS
    for a, b in zip(threaded.poses, child.poses, strict=True):
        assert np.array_equal(a.as_vector(), b.as_vector())
    for a, b in zip(threaded.odometry_poses, child.odometry_poses, strict=True):
        assert np.array_equal(a.as_vector(), b.as_vector())
    assert threaded.node_scans == child.node_scans
    assert (threaded.rejected, threaded.held, threaded.skipped) == (
        child.rejected,
        child.held,
        child.skipped,
    )
    assert len(threaded.loops) == len(child.loops)
    # The odometry's time is the child's, reported as the thread's is.
    assert child.timing.odometry > 0 and child.timing.odometry_cpu > 0
    assert _children() == []


def test_ctrl_c_keeps_what_was_mapped_and_stops_the_child(log: ScanLog) -> None:
    def interrupt(partial: object) -> None:
        raise KeyboardInterrupt

    with pytest.raises(MappingInterrupted) as info:
        run_mapping(
            log,
            MappingConfig(),
            max_scans=SCANS,
            odometry_process=True,
            checkpoint=interrupt,
            checkpoint_every=40,
        )
    assert isinstance(info.value.__cause__, KeyboardInterrupt)
    assert info.value.partial is not None and len(info.value.partial.poses) == 40
    # The child's odometry time comes with its scans: the partial run reports it.
    assert info.value.partial.timing.odometry > 0
    assert _children() == []


def test_an_error_in_the_child_is_raised_with_what_was_mapped(log: ScanLog) -> None:
    # Scan 60's ranges and bearings disagree in length (set past its own check, as memory
    # gone bad would): its points cannot be formed.
    scans = list(log.scans)
    scans[60] = copy.copy(scans[60])
    object.__setattr__(scans[60], "angles", scans[60].angles[:-5])
    broken = dataclasses.replace(log, scans=tuple(scans))
    with pytest.raises(MappingInterrupted) as threaded:
        run_mapping(broken, MappingConfig(), max_scans=SCANS, odometry_process=False)
    with pytest.raises(MappingInterrupted) as child:
        run_mapping(broken, MappingConfig(), max_scans=SCANS, odometry_process=True)
    assert type(child.value.__cause__) is type(threaded.value.__cause__)
    assert str(child.value.__cause__) == str(threaded.value.__cause__)
    assert child.value.partial is not None
    assert len(child.value.partial.poses) == len(threaded.value.partial.poses) == 60
    assert _children() == []


def test_a_child_that_cannot_start_leaves_the_odometry_on_a_thread(
    log: ScanLog, monkeypatch: pytest.MonkeyPatch
) -> None:
    threaded = run_mapping(log, MappingConfig(), max_scans=60, odometry_process=False)
    # An interpreter that cannot run scanreg's child (it exits at once).
    monkeypatch.setattr(odometry_process, "_BOOT", "raise SystemExit(3)")
    with pytest.warns(RuntimeWarning, match=r"the odometry runs on a thread .*exit 3"):
        fallback = run_mapping(log, MappingConfig(), max_scans=60, odometry_process=True)
    for a, b in zip(threaded.poses, fallback.poses, strict=True):
        assert np.array_equal(a.as_vector(), b.as_vector())
    assert _children() == []


def test_bad_input_is_refused_by_name(log: ScanLog) -> None:
    with pytest.raises(TypeError, match="odometry_process: expected True, False or None, got str"):
        run_mapping(log, MappingConfig(), max_scans=10, odometry_process="yes")  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="scans: expected a ScanLog, got ndarray"):
        odometry_process.OdometryProcess(np.zeros((0, 2)), MappingConfig())  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="config: expected a MappingConfig, got dict"):
        odometry_process.OdometryProcess(log, {})  # type: ignore[arg-type]
    mapper = Mapper(MappingConfig())
    lengths, seconds = mapper.odometry_mark()
    with pytest.raises(ValueError, match="mark: expected 4 finite times"):
        mapper.odometry_since((lengths, (float("nan"), 0.0, 0.0, 0.0)))
    with pytest.raises(ValueError, match="mark: expected 8 list lengths"):
        mapper.odometry_since(((), seconds))
    with pytest.raises(TypeError, match=r"record: expected what Mapper\.odometry_since returns"):
        mapper.adopt_odometry(np.zeros((2, 3)))  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="record: expected 4 finite times >= 0"):
        mapper.adopt_odometry((mapper.odometry_since(mapper.odometry_mark())[0], (0.0,)))
    with pytest.raises(ValueError, match=r"end: expected what Mapper\.odometry_end returns"):
        mapper.adopt_odometry_end({})
    with pytest.raises(TypeError, match="scans: expected a ScanLog, got ndarray"):
        track_scan(mapper, np.zeros((3, 2)), MappingConfig(), 0)  # type: ignore[arg-type]
    assert mapper.odometry_mark() == (lengths, seconds)  # nothing adopted
