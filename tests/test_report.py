"""The HTML run report: content, self-containment, bad input, and a real browser (headless
Chromium) that loads it with no script error and paints the plots (checked on pixels)."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scanreg import SE3, cli
from scanreg.io import FileFormatError, PointCloud, write_jsonl, write_points, write_poses

pytest.importorskip("plotly", reason="plotly is not installed (pip install 'scanreg[report]')")

from scanreg import report

K = 40
REJECTED, HELD = 12, 25


def make_run_folder(root: Path) -> Path:
    """A run folder as scanreg odometry writes it, with a rejection, a held frame, loop
    closures, a reference and a map (a street: ground and two façades)."""
    root.mkdir(parents=True, exist_ok=True)
    stamps = 0.1 * np.arange(K)
    poses = [SE3.from_vector([1.0 * k, 8 * np.sin(k / 12), 0, 0, 0, np.cos(k / 12) * 0.6])
             for k in range(K)]  # fmt: skip
    write_poses(root / "poses_tum.txt", poses, "tum", timestamps=stamps)
    ref = [SE3.from_vector([0.02, -0.03, 0, 0, 0, 0]) @ p for p in poses]
    write_poses(root / "reference_tum.txt", ref, "tum", timestamps=stamps)
    rng = np.random.default_rng(0)
    rows = []
    for k in range(K):
        sd = 0.02 * (1 + 0.5 * np.sin(k / 5)) if k else None
        rows.append({
            "frame": k, "stamp": float(stamps[k]),
            "accepted": k != REJECTED,
            "reasons": "overlap 0.18 < 0.50; not converged: max_iterations" if k == REJECTED
            else "",
            "held_directions": "translation along (1.00, 0.00, 0.00)" if k == HELD else "",
            **{f"sigma_{a}": None if sd is None else sd * s for a, s in zip("xyz", (1, 2, 0.5),
                                                                           strict=True)},
            **{f"sigma_{a}": None if sd is None else sd / 20 for a in ("roll", "pitch", "yaw")},
            "time_ms": 30.0,
            **{f"time_{s}_ms": float(v) for s, v in zip(
                report.STAGES, rng.uniform(0.5, 1.5, 5) * [3, 1, 20, 0.1, 3], strict=True)},
        })  # fmt: skip
    write_jsonl(root / "quality.jsonl", rows)
    write_jsonl(root / "loops.jsonl", [
        {"source": 2, "target": 37, "accepted": True},
        {"source": 5, "target": 30, "accepted": False, "reason": "fitness 0.2 < 0.5"},
    ])  # fmt: skip
    x = rng.uniform(-5, 45, 30_000)
    ground = np.column_stack([x, rng.uniform(-12, 12, len(x)), rng.normal(-1.7, 0.02, len(x))])
    walls = np.column_stack([x[:8000], np.where(x[:8000] > 20, 12.0, -12.0),
                             rng.uniform(-1.7, 8, 8000)])  # fmt: skip
    write_points(root / "map.laz", PointCloud(points=np.vstack([ground, walls])))
    (root / "summary.json").write_text(json.dumps({
        "sequence": "synthetic street", "frames_per_second": 31.5,
        "accuracy": {"ate_rmse_m": 0.036, "kitti_translation_percent": 0.81},
    }))  # fmt: skip
    (root / "config.toml").write_text('# OdometryConfig\nmethod = "gicp"\nvoxel_size = 1.0\n')
    return root


def test_report_is_self_contained_and_shows_every_part(tmp_path: Path) -> None:
    run = make_run_folder(tmp_path / "run")
    out = report.write_report(run)
    assert out == run / "report.html"
    text = out.read_text()
    # plotly's JavaScript is inlined once, and nothing is fetched at view time
    assert text.count("plotly.js v") >= 1 and len(text) > 3_000_000
    assert not re.search(r"<script[^>]+src=", text) and not re.search(r"<link[^>]+href=", text)
    for div in ("trajectory", "uncertainty", "timing", "map"):
        assert f'id="scanreg-{div}"' in text
    assert "overlap 0.18 &lt; 0.50; not converged: max_iterations" in text  # the table
    assert "translation along (1.00, 0.00, 0.00)" in text
    assert "synthetic street" in text and "0.036 m" in text
    assert "loop closures (rejected)" in text and "1 / 2" in text
    assert sorted(p.name for p in run.iterdir() if p.name.startswith(".")) == []


def test_map_is_downsampled_to_the_budget(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    run = make_run_folder(tmp_path / "run")
    monkeypatch.setattr(report, "MAX_MAP_POINTS", 5000)
    pts = report._map_points(run / "map.laz")
    assert 1000 < len(pts) <= 5000
    # it still spans the street
    assert np.ptp(pts[:, 0]) > 45 and np.ptp(pts[:, 2]) > 8


def test_report_bad_input(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(FileNotFoundError, match="no such run folder"):
        report.write_report(tmp_path / "missing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(FileFormatError, match=r"not a scanreg run folder: no poses_tum\.txt"):
        report.write_report(tmp_path / "empty")
    run = make_run_folder(tmp_path / "run")
    with pytest.raises(FileNotFoundError, match="cannot write the report: no folder"):
        report.write_report(run, tmp_path / "nowhere" / "r.html")
    with pytest.raises(PermissionError, match="cannot write the report"):
        report.write_report(run, "/proc/report.html")
    rows = [json.loads(x) for x in (run / "quality.jsonl").read_text().splitlines()]
    rows[5]["frame"] = 40
    write_jsonl(run / "quality.jsonl", rows)
    with pytest.raises(FileFormatError, match=r"quality\.jsonl: frame 40 is not one of the 40"):
        report.write_report(run)
    for r in rows:
        del r["frame"]
    write_jsonl(run / "quality.jsonl", rows[:-3])
    with pytest.raises(FileFormatError, match=r"quality\.jsonl has 37 rows for 40 poses"):
        report.write_report(run)
    assert not (run / "report.html").exists()
    assert cli.main(["report", str(tmp_path / "empty")]) == cli.EXIT_BAD_INPUT
    assert "no poses_tum.txt" in capsys.readouterr().err


def test_cli_report_and_odometry_report_flag(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    run = make_run_folder(tmp_path / "run")
    out = tmp_path / "drive.html"
    assert cli.main(["report", str(run), "-o", str(out), "--title", "drive 7", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["report"] == str(out) and result["bytes"] > 3_000_000
    assert "<title>scanreg run: drive 7</title>" in out.read_text()
    # scanreg odometry --report --bag: the report and a bag next to the run's files
    folder = tmp_path / "odo"
    assert cli.main(["odometry", "sim:street,frames=5", "-o", str(folder), "--no-plots",
                     "--report", "--bag", str(folder / "run.mcap"), "--json"]) == 0  # fmt: skip
    result = json.loads(capsys.readouterr().out)
    assert {"report", "bag", "map", "reference_tum", "summary"} <= set(result["outputs"])
    assert result["bag"]["messages"]["/scanreg/scan"] == 5
    assert result["bag"]["messages"]["/scanreg/map"] == 1
    html = (folder / "report.html").read_text()
    assert 'id="scanreg-map"' in html and "reference (SE(3)-aligned)" in html
    rows = [json.loads(x) for x in (folder / "quality.jsonl").read_text().splitlines()]
    assert all(f"time_{s}_ms" in rows[1] for s in report.STAGES)


def test_odometry_bag_errors_come_before_the_run(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    argv = ["odometry", "sim:street,frames=3", "-o", str(tmp_path / "o"), "--no-plots"]
    assert cli.main([*argv, "--bag", str(blocker / "run.mcap")]) == cli.EXIT_BAD_INPUT
    assert "cannot write a bag there" in capsys.readouterr().err
    assert not (tmp_path / "o" / "poses_tum.txt").exists()  # refused before any work
    assert cli.main([*argv, "--bag", str(tmp_path / "b.mcap"), "--bag-frames", "map", "odom",
                     "/lidar"]) == cli.EXIT_BAD_INPUT  # fmt: skip
    assert "not a valid tf2 frame id" in capsys.readouterr().err
    assert cli.main([*argv, "--crs", "x.wkt"]) == cli.EXIT_BAD_INPUT
    assert "--las-offset and --crs need --map-format las or laz" in capsys.readouterr().err


# --------------------------------------------------------------------------- browser


def _chromium() -> str:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        found = shutil.which(name)
        if found:
            return found
    reason = "headless Chromium not found (Debian: apt-get install chromium)"
    if os.environ.get("CI", "").lower() == "true":
        pytest.fail(f"{reason}; CI=true requires it", pytrace=False)
    pytest.skip(reason)


def load_in_browser(page: Path, workdir: Path, *, height: int = 3000) -> tuple[Path, str]:
    """Load ``page`` in headless Chromium: ``(screenshot PNG, browser log)``. One headless
    command only: with --dump-dom as well, Chromium 143 hung now and then."""
    shot = workdir / f"{page.stem}.png"
    argv = [
        _chromium(), "--headless", "--no-sandbox", "--hide-scrollbars", "--mute-audio",
        "--enable-unsafe-swiftshader",  # software WebGL for the 3D map
        f"--user-data-dir={workdir / 'profile'}", f"--window-size=1400,{height}",
        "--virtual-time-budget=5000", "--enable-logging=stderr", "--v=0",
        f"--screenshot={shot}", page.resolve().as_uri(),
    ]  # fmt: skip
    done = subprocess.run(argv, capture_output=True, text=True, timeout=180, cwd=workdir,
                          check=False)  # fmt: skip
    assert done.returncode == 0 and shot.is_file(), done.stderr[-2000:]
    return shot, done.stderr


def page_status(log: str) -> dict[str, Any]:
    """What the page's load hook logged (plots drawn, script errors, remote fetches), with
    the uncaught errors Chromium logged itself added to ``errors``."""
    found = re.search(r"scanreg-report (\{.*?\})\"", log)
    assert found is not None, f"the page did not finish loading: {log[-1500:]}"
    status: dict[str, Any] = json.loads(found.group(1).replace('\\"', '"'))
    status["errors"] += [line for line in log.splitlines() if "Uncaught" in line]
    return status


def test_the_harness_sees_a_script_error(tmp_path: Path) -> None:
    """Negative control: a page whose script throws is reported (else a silent page passes)."""
    page = tmp_path / "broken.html"
    page.write_text(
        f"<html><head>{report._ERROR_HOOK}</head><body><pre id='scanreg-js-errors'></pre>"
        f"<script>notAFunction();</script>{report._DONE_HOOK}</body></html>"
    )
    _, log = load_in_browser(page, tmp_path, height=300)
    errors = page_status(log)["errors"]
    assert any("notAFunction" in e for e in errors), log[-1500:]


def _near(img: Any, rgb: tuple[int, int, int], tol: int = 40) -> Any:
    return np.abs(img[..., :3].astype(int) - np.array(rgb)).max(axis=-1) <= tol


def test_report_renders_in_headless_chromium(tmp_path: Path) -> None:
    image = pytest.importorskip("PIL.Image", reason="Pillow (a matplotlib dependency) is needed")
    run = make_run_folder(tmp_path / "run")
    page = report.write_report(run)
    shot, log = load_in_browser(page, tmp_path, height=3000)
    status = page_status(log)
    assert status["errors"] == []
    assert status["plots"] >= 4  # one SVG layer or more per plot
    assert status["remote"] == 0  # nothing fetched from the network
    img = np.asarray(image.open(shot).convert("RGB"))
    assert img.shape == (3000, 1400, 3)
    white = (img > 245).all(axis=-1)
    assert 0.15 < 1 - white.mean() < 0.9  # plots, not a blank (or black) page
    # the estimate (blue), the rejected frame and loop (red), the accepted loop (green)
    assert _near(img, (0x1F, 0x77, 0xB4)).sum() > 2000
    assert _near(img, (0xD6, 0x27, 0x28)).sum() > 100
    assert _near(img, (0x2C, 0xA0, 0x2C)).sum() > 100
    # the 3D map, drawn with WebGL in the lower part: viridis purple and yellow
    lower = img[1900:]
    assert _near(lower, (0x44, 0x01, 0x54), 50).sum() > 300
    assert _near(lower, (0xFD, 0xE7, 0x25), 60).sum() > 100


def test_a_mapping_run_folder_shows_odometry_loops_and_grid(tmp_path: Path) -> None:
    """The files ``scanreg map`` writes: loops by scan index with reasons as a list, the
    odometry before loop closure, and an occupancy grid image instead of a point map."""
    image = pytest.importorskip("PIL.Image", reason="Pillow (a matplotlib dependency) is needed")
    run = make_run_folder(tmp_path / "run")
    (run / "map.laz").unlink()
    image.fromarray(np.full((40, 60), 127, dtype=np.uint8)).save(run / "map.png")
    poses = [SE3.from_vector([1.0 * k, 0.1 * k, 0, 0, 0, 0]) for k in range(K)]
    write_poses(run / "odometry_tum.txt", poses, "tum", timestamps=0.1 * np.arange(K))
    loops = [
        {"submap_scan": 3, "scan": 36, "accepted": True, "reasons": []},
        {"submap_scan": 8, "scan": 33, "accepted": False,
         "reasons": ["overlap 0.21 < 0.40", "chi2 31.2 > 11.3"]},
    ]  # fmt: skip
    (run / "loops.jsonl").write_text("".join(json.dumps(lp) + "\n" for lp in loops))
    text = report.render_report(run)
    assert "odometry (before loop closure)" in text
    assert "Occupancy grid" in text and "data:image/png;base64," in text
    # plotly's JSON escapes <, > and & as \uXXXX: decode them to read the hover text
    hover = re.sub(r"\\u([0-9a-f]{4})", lambda m: chr(int(m.group(1), 16)), text)
    assert "loop 33 → 8<br>overlap 0.21 &lt; 0.40; chi2 31.2 &gt; 11.3" in hover
    assert 'id="scanreg-map"' not in text and "1 / 2" in text
    write_jsonl(run / "loops.jsonl", [{"accepted": True}])
    with pytest.raises(FileFormatError, match=r"loops\.jsonl: a loop without frames"):
        report.render_report(run)


def test_a_bare_run_folder_still_reports(tmp_path: Path) -> None:
    """Only poses, and rows without σ or timing (a user's own loop): no warning, no crash."""
    poses = [SE3.from_vector([0.5 * k, 0, 0, 0, 0, 0]) for k in range(6)]
    write_poses(tmp_path / "poses_tum.txt", poses, "tum", timestamps=0.1 * np.arange(6))
    text = report.render_report(tmp_path)
    assert 'id="scanreg-trajectory"' in text and 'id="scanreg-timing"' not in text
    assert "No map in the run folder" in text
    write_jsonl(tmp_path / "quality.jsonl", [{"frame": k, "fitness": 0.9} for k in (1, 3)])
    text = report.render_report(tmp_path)
    assert 'id="scanreg-uncertainty"' in text and 'id="scanreg-timing"' not in text
