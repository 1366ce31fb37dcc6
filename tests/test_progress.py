"""Progress bar: exact text on a fake terminal and a fake log stream, with a fake clock."""

from __future__ import annotations

import io

import pytest
from scanreg._progress import Progress, format_duration, track


class FakeStream(io.StringIO):
    def __init__(self, tty: bool) -> None:
        super().__init__()
        self._tty = tty

    def isatty(self) -> bool:
        return self._tty


class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_format_duration() -> None:
    assert format_duration(None) == "?"
    assert format_duration(float("inf")) == "?"
    assert format_duration(5.4) == "0:05"
    assert format_duration(65) == "1:05"
    assert format_duration(3723) == "1:02:03"


def test_tty_redraws_in_place() -> None:
    out, clock = FakeStream(tty=True), FakeClock()
    bar = Progress(
        100, description="odometry", unit="frames", stream=out, clock=clock, redraw_interval=0.1
    )
    clock.now += 0.5
    bar.update(accepted=1, rejected=0)  # first update draws at once
    clock.now += 0.05
    bar.update(accepted=2, rejected=0)  # within the redraw interval: nothing
    clock.now += 0.45
    bar.update(accepted=2, rejected=1)
    text = out.getvalue()
    assert "\n" not in text
    draws = text.split("\r")[1:]
    assert len(draws) == 2
    assert draws[0] == (
        "odometry   1/100 [--------------------]   1% 2.0 frames/s ETA 0:50 accepted=1 rejected=0"
    )
    # 3 frames in 1 s: 3.0 frames/s, 97 left → 32 s
    assert draws[1] == (
        "odometry   3/100 [#-------------------]   3% 3.0 frames/s ETA 0:32 accepted=2 rejected=1"
    )
    for _ in range(97):
        clock.now += 0.01
        bar.update()
    bar.close()
    bar.close()  # idempotent
    final = out.getvalue().split("\r")[-1]
    assert final.endswith("\n")
    assert final.startswith("odometry 100/100 [####################] 100% ")
    assert "in 0:02" in final and "ETA" not in final


def test_tty_pads_a_shorter_line() -> None:
    out, clock = FakeStream(tty=True), FakeClock()
    bar = Progress(10, stream=out, clock=clock, redraw_interval=0.0)
    clock.now += 1
    bar.update(note="a long counter value")
    clock.now += 1
    bar.update(note="x")
    first, second = out.getvalue().split("\r")[1:]
    assert len(second) >= len(first)


def test_log_stream_prints_occasional_lines() -> None:
    out, clock = FakeStream(tty=False), FakeClock()
    bar = Progress(
        50, description="simulate", unit="scans", stream=out, clock=clock, line_interval=10
    )
    for _ in range(50):
        clock.now += 1.0  # 1 scan/s: a line every 10 s
        bar.update(points=1000)
    bar.close()
    lines = out.getvalue().splitlines()
    assert "\r" not in out.getvalue()
    assert len(lines) == 6  # at 10, 20, 30, 40, 50 s, and the final line
    assert lines[0] == "simulate 10/50 [####----------------]  20% 1.0 scans/s ETA 0:40 points=1000"
    assert lines[-1] == "simulate 50/50 [####################] 100% 1.0 scans/s in 0:50 points=1000"


def test_disabled_is_silent() -> None:
    out, clock = FakeStream(tty=True), FakeClock()
    with Progress(5, stream=out, clock=clock, enabled=False) as bar:
        for _ in range(5):
            clock.now += 1
            bar.update(accepted=1)
    assert out.getvalue() == ""


def test_unknown_total_and_float_counters() -> None:
    out, clock = FakeStream(tty=False), FakeClock()
    bar = Progress(None, stream=out, clock=clock, unit="msgs")
    clock.now += 2
    bar.update(4, rmse=0.123456)
    bar.close()
    assert out.getvalue() == "4 2.0 msgs/s in 0:02 rmse=0.123\n"
    with pytest.raises(ValueError, match="total"):
        Progress(-1)


def test_track_counts_items() -> None:
    out = FakeStream(tty=False)
    assert list(track(range(3), stream=out, unit="frames")) == [0, 1, 2]
    assert out.getvalue().startswith("3/3 [####################] 100% ")
