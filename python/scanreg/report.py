"""A run report: one self-contained HTML file to judge a run by looking at it.

>>> write_report("out/")                       # out/report.html
>>> write_report("out/", "drive_07.html")

It reads what ``scanreg odometry`` (or any pipeline writing the same files) leaves in its run
folder and draws, with plotly (the ``report`` extra, ``pip install 'scanreg[report]'``,
whose wheel ships its JavaScript, inlined once so the file needs no network):

* the trajectory (top view), with the reference aligned onto it (SE(3), Umeyama) when the
  folder has one, rejected frames marked, and loop closures as segments;
* per-frame σ (translation in cm, rotation in degrees) over time, and the verdict of every
  frame — rejections and held directions with their reasons on hover and in a table;
* the time per stage (deskew, downsample, align, judge, update) per frame, with medians;
* an interactive 3D view of the map, voxel-downsampled, coloured by height, with the
  trajectory through it.

Run-folder files (all but the poses optional)
---------------------------------------------
``poses_tum.txt`` (estimate, ``T_world_lidar``), ``quality.jsonl`` (one row per frame:
``stamp``, ``accepted``, ``reasons``, ``held_directions``, ``sigma_*``,
``time_<stage>_ms``, ``overlap``, …), ``reference_tum.txt`` (ground truth or a reference
trajectory at the same stamps), ``loops.jsonl`` (``source``, ``target`` frame indices,
``accepted``, optional ``reason``), ``map.ply|.pcd|.las|.laz``, ``summary.json`` (headline
figures; a 2D mapping run's ``self_check`` is shown with its verdict, and the returns of
``contradictions.csv`` drawn on the trajectory) and ``config.toml`` (shown as text). A map
of several sessions (``scanreg map NEW --extend OLD/``, ``scanreg merge``: ``manifest.json``
lists the sessions, ``map_data.npz`` each scan's) is drawn one trajectory per session, each
session's odometry started at its first optimized pose, the loops between sessions apart.
"""

from __future__ import annotations

import base64
import html
import io
import json
import math
import os
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ._validate import FloatArray
from .io import FileFormatError
from .io._common import PathLike

#: Maps the report looks for, in this order.
MAP_NAMES = ("map.ply", "map.pcd", "map.las", "map.laz")
#: Most map points drawn in the 3D view (WebGL stays fluid; the file stays a few MB).
MAX_MAP_POINTS = 60_000
STAGES = ("deskew", "downsample", "align", "judge", "update")
_COLORS = {
    "estimate": "#1f77b4",
    "reference": "#7f7f7f",
    "accepted": "#2ca02c",
    "held": "#ff7f0e",
    "rejected": "#d62728",
    "between": "#9467bd",
}
#: One colour per session of a map of several (the first is the one-run estimate's).
_SESSION_COLORS = ("#1f77b4", "#17becf", "#8c564b", "#e377c2", "#7f7f7f")
#: Collects script errors into the page itself, so a headless browser's DOM dump shows them.
_ERROR_HOOK = """<script>
window.scanregErrors = [];
function scanregError(text) {
  window.scanregErrors.push(text);
  var box = document.getElementById("scanreg-js-errors");
  if (box) { box.textContent = window.scanregErrors.join("\\n"); }
}
window.addEventListener("error", function (e) { scanregError(String(e.message || e)); });
window.addEventListener("unhandledrejection", function (e) { scanregError(String(e.reason)); });
(function () {
  var original = console.error;
  console.error = function () {
    scanregError(Array.prototype.join.call(arguments, " "));
    return original.apply(console, arguments);
  };
})();
</script>"""
_DONE_HOOK = """<script>
window.addEventListener("load", function () {
  var box = document.getElementById("scanreg-js-errors");
  box.textContent = window.scanregErrors.join("\\n");
  var n = document.querySelectorAll(".js-plotly-plot .main-svg").length;
  document.body.setAttribute("data-rendered-plots", String(n));
  var remote = performance.getEntriesByType("resource").filter(function (r) {
    return !/^(file|data|blob):/.test(r.name);
  });
  document.body.setAttribute("data-remote-resources", String(remote.length));
  // one line a headless browser's log shows: what rendered, what failed, what was fetched
  console.log("scanreg-report " + JSON.stringify(
    {plots: n, errors: window.scanregErrors, remote: remote.length}));
});
</script>"""
_CSS = """
body { font-family: system-ui, sans-serif; margin: 24px auto; max-width: 1280px; color: #222; }
h1 { font-size: 1.5em; margin-bottom: 4px; }
h2 { font-size: 1.15em; margin-top: 28px; border-bottom: 1px solid #ddd; }
.cards { display: flex; flex-wrap: wrap; gap: 10px; margin: 12px 0; }
.card { background: #f4f6f8; border-radius: 6px; padding: 8px 14px; min-width: 120px; }
.card b { display: block; font-size: 1.3em; }
table { border-collapse: collapse; font-size: 0.9em; }
td, th { border-bottom: 1px solid #e4e4e4; padding: 3px 10px; text-align: left; }
pre { background: #f4f6f8; padding: 10px; overflow-x: auto; font-size: 0.85em; }
.muted { color: #777; }
#scanreg-js-errors:empty { display: none; }
#scanreg-js-errors { color: #b00; }
"""


def _plotly() -> Any:
    try:
        import plotly.graph_objects as go
        import plotly.io as pio
        from plotly.subplots import make_subplots
    except ImportError:
        raise ImportError(
            "the run report needs the 'plotly' package: pip install 'scanreg[report]'"
        ) from None
    return go, pio, make_subplots


# --------------------------------------------------------------------------- run folder


def _read_rows(path: Path) -> list[dict[str, Any]]:
    from .io import read_jsonl

    return read_jsonl(path) if path.is_file() else []


def _read_xy(path: Path) -> FloatArray:
    """``x,y`` of the ``x,y`` (a 3D run's: ``x,y,z``) rows under a header line (none: an empty
    ``(0, 2)`` array): what is drawn on the trajectory's plane."""
    text = path.read_text(encoding="utf-8")
    if len(text.splitlines()) < 2:
        return np.zeros((0, 2))
    try:
        xy = np.loadtxt(io.StringIO(text), delimiter=",", skiprows=1, ndmin=2)
    except ValueError as exc:
        raise FileFormatError(path, f"expected x,y rows: {exc}") from None
    if xy.shape[1] not in (2, 3):
        raise FileFormatError(path, f"expected 2 or 3 columns (x,y[,z]), got {xy.shape[1]}")
    return np.asarray(xy[:, :2], dtype=np.float64)


def _sessions(
    root: Path, num_scans: int
) -> tuple[list[str], np.ndarray[Any, np.dtype[np.int64]] | None]:
    """A map folder's session names and every scan's session (``None``: one session, or no
    map folder)."""
    from .saved_map import DATA, MANIFEST, read_manifest

    if not (root / MANIFEST).is_file():
        return [], None
    names = [str(n) for n in read_manifest(root / MANIFEST)["sessions"]]
    if len(names) < 2:
        return names, None
    try:
        with np.load(root / DATA, allow_pickle=False) as data:
            owner = np.asarray(data["scan_sessions"], dtype=np.int64)
    except (OSError, ValueError, KeyError) as exc:
        raise FileFormatError(root / DATA, f"scan_sessions: cannot be read: {exc}") from None
    if owner.shape != (num_scans,) or (
        num_scans and not 0 <= owner.min() <= owner.max() < len(names)
    ):
        raise FileFormatError(
            root / DATA,
            f"scan_sessions: expected {num_scans} session indices 0..{len(names) - 1}",
        )
    return names, owner


def _column(rows: Sequence[dict[str, Any]], key: str) -> FloatArray:
    return np.array(
        [np.nan if r.get(key) is None else float(r[key]) for r in rows], dtype=np.float64
    )


class RunFolder:
    """What a run folder holds, read once (see the module docstring for the files)."""

    def __init__(self, folder: PathLike) -> None:
        from .io import read_tum

        self.root = Path(folder)
        if not self.root.is_dir():
            raise FileNotFoundError(f"{self.root}: no such run folder")
        poses = self.root / "poses_tum.txt"
        if not poses.is_file():
            raise FileFormatError(
                self.root, "not a scanreg run folder: no poses_tum.txt (run scanreg odometry)"
            )
        self.estimate = read_tum(poses)
        reference = self.root / "reference_tum.txt"
        self.reference = read_tum(reference) if reference.is_file() else None
        self.rows = self._frame_rows(_read_rows(self.root / "quality.jsonl"))
        self.loops = _read_rows(self.root / "loops.jsonl")
        summary = self.root / "summary.json"
        self.summary: dict[str, Any] = (
            json.loads(summary.read_text(encoding="utf-8")) if summary.is_file() else {}
        )
        config = self.root / "config.toml"
        self.config = config.read_text(encoding="utf-8") if config.is_file() else None
        self.map_path = next((self.root / n for n in MAP_NAMES if (self.root / n).is_file()), None)
        odometry = self.root / "odometry_tum.txt"  # a mapping run: before loop closure
        self.odometry = read_tum(odometry) if odometry.is_file() else None
        image = self.root / "map.png"  # a 2D mapping run's occupancy grid
        self.map_image = image if image.is_file() else None
        contradictions = self.root / "contradictions.csv"  # a mapping run's self-check
        self.contradictions = _read_xy(contradictions) if contradictions.is_file() else None
        self.sessions, self.scan_sessions = _sessions(self.root, len(self.estimate))

    def session_indices(self) -> list[tuple[str, np.ndarray[Any, np.dtype[np.intp]]]]:
        """``(name, scan indices)`` per session; one unnamed session for a one-run folder."""
        if self.scan_sessions is None:
            return [("", np.arange(len(self.estimate)))]
        return [
            (name, np.flatnonzero(self.scan_sessions == k)) for k, name in enumerate(self.sessions)
        ]

    def odometry_positions(self) -> FloatArray | None:
        """The odometry before loop closure (``None`` if absent), each session's started at
        its first optimized pose (a later session's odometry is in a frame of its own)."""
        if self.odometry is None or len(self.odometry) != len(self.estimate):
            return None
        out = self.odometry.positions
        for _, idx in self.session_indices()[1:]:
            if len(idx):
                start = self.estimate.poses[idx[0]] @ np.linalg.inv(self.odometry.poses[idx[0]])
                moved = start @ self.odometry.poses[idx]
                out[idx] = moved[:, :3, 3]
        return out

    def loop_ends(self) -> list[tuple[int, int, bool, str]]:
        """``(source, target, accepted, reasons)`` of each loop closure (``source``/``target``
        frame indices, or a mapping run's ``scan``/``submap_scan``)."""
        out = []
        for lp in self.loops:
            i, j = lp.get("source", lp.get("scan")), lp.get("target", lp.get("submap_scan"))
            if i is None or j is None:
                raise FileFormatError(self.root, f"loops.jsonl: a loop without frames: {lp}")
            reasons = lp.get("reasons", lp.get("reason")) or ""
            if isinstance(reasons, list):
                reasons = "; ".join(map(str, reasons))
            out.append((int(i), int(j), bool(lp.get("accepted", True)), str(reasons)))
        return out

    def _frame_rows(self, rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
        """One row per pose: by their ``frame`` index when the rows have one (a frame without
        a row gets an empty one), else in order."""
        n = len(self.estimate)
        if not rows:
            return []
        if all("frame" in r for r in rows):
            out: list[dict[str, Any]] = [{} for _ in range(n)]
            for r in rows:
                k = r["frame"]
                if not isinstance(k, int) or not 0 <= k < n:
                    raise FileFormatError(
                        self.root, f"quality.jsonl: frame {k!r} is not one of the {n} poses"
                    )
                out[k] = r
            return out
        if len(rows) != n:
            raise FileFormatError(self.root, f"quality.jsonl has {len(rows)} rows for {n} poses")
        return rows

    @property
    def stamps(self) -> FloatArray:
        t = self.estimate.timestamps
        return np.arange(len(self.estimate), dtype=np.float64) if t is None else t - t[0]

    def verdicts(self) -> list[str]:
        """``"accepted"``, ``"held"`` (accepted with directions held to the prediction) or
        ``"rejected"`` per frame."""
        out = []
        for r in self.rows:
            if not r.get("accepted", True):
                out.append("rejected")
            elif r.get("held_directions"):
                out.append("held")
            else:
                out.append("accepted")
        return out or ["accepted"] * len(self.estimate)


# --------------------------------------------------------------------------- figures


def _trajectory_figure(run: RunFolder) -> Any:
    go, _, _ = _plotly()
    est = run.estimate.positions
    fig = go.Figure()
    if run.reference is not None and len(run.reference) == len(run.estimate):
        from .eval.align import align

        ref_in_est, _ = align(run.estimate, run.reference, "se3")
        ref = ref_in_est.positions
        fig.add_trace(
            go.Scatter(
                x=ref[:, 0],
                y=ref[:, 1],
                mode="lines",
                name="reference (SE(3)-aligned)",
                line={"color": _COLORS["reference"], "width": 3, "dash": "dot"},
            )
        )
    several = run.scan_sessions is not None
    for k, (name, scans) in enumerate(run.session_indices()):
        fig.add_trace(
            go.Scatter(
                x=est[scans, 0],
                y=est[scans, 1],
                mode="lines+markers",
                name=f"session {k}: {name}" if several else "estimate",
                marker={"size": 4},
                line={"color": _SESSION_COLORS[k % len(_SESSION_COLORS)], "width": 2},
                text=[f"frame {i}" for i in scans],
                hoverinfo="text+x+y",
            )
        )
    verdicts = run.verdicts()
    for kind in ("held", "rejected"):
        idx = [k for k, v in enumerate(verdicts) if v == kind]
        if idx:
            fig.add_trace(
                go.Scatter(
                    x=est[idx, 0],
                    y=est[idx, 1],
                    mode="markers",
                    name=kind,
                    marker={"color": _COLORS[kind], "size": 10, "symbol": "x"},
                    text=[_reason(run.rows[k], k) for k in idx],
                    hoverinfo="text",
                )
            )
    odo = run.odometry_positions()
    for k, (_, scans) in enumerate(run.session_indices() if odo is not None else ()):
        assert odo is not None
        fig.add_trace(
            go.Scatter(
                x=odo[scans, 0],
                y=odo[scans, 1],
                mode="lines",
                name="odometry (before loop closure)",
                legendgroup="odometry",
                showlegend=k == 0,
                line={"color": "#bcbd22", "width": 1.5},
            )
        )
    loops = run.loop_ends()
    owner = run.scan_sessions
    kinds = [(True, False), (False, False)]
    if owner is not None:
        kinds = [(True, True), *kinds]
    for accepted, between in kinds:
        xs: list[float | None] = []
        ys: list[float | None] = []
        texts: list[str | None] = []
        for i, j, ok, reasons in loops:
            if ok != accepted or not (0 <= i < len(est) and 0 <= j < len(est)):
                continue
            if owner is not None and accepted and (owner[i] != owner[j]) != between:
                continue
            xs += [est[i, 0], est[j, 0], None]
            ys += [est[i, 1], est[j, 1], None]
            label = f"loop {i} → {j}" + (f"<br>{html.escape(reasons)}" if reasons else "")
            texts += [label, label, None]
        if xs:
            color = _COLORS["between" if between else "accepted" if accepted else "rejected"]
            kind = "between sessions" if between else "accepted" if accepted else "rejected"
            fig.add_trace(
                go.Scatter(
                    x=xs,
                    y=ys,
                    mode="lines",
                    name=f"loop closures ({kind})",
                    line={"color": color, "width": 2, "dash": "solid" if accepted else "dash"},
                    text=texts,
                    hoverinfo="text",
                )
            )
    fig.update_layout(
        title="Trajectory (top view)",
        xaxis_title="x (m)",
        yaxis_title="y (m)",
        height=520,
        legend={"orientation": "h"},
    )
    fig.update_yaxes(scaleanchor="x", scaleratio=1)
    return fig


def _reason(row: dict[str, Any], k: int) -> str:
    parts = [f"frame {k}"]
    # escaped: plotly reads hover text as HTML-like markup ("<br>"), and reasons hold "<"
    if row.get("reasons"):
        parts.append(html.escape(str(row["reasons"])))
    if row.get("held_directions"):
        parts.append("held: " + html.escape(str(row["held_directions"])))
    return "<br>".join(parts)


def _sigma_figure(run: RunFolder) -> Any:
    go, _, make_subplots = _plotly()
    t = run.stamps
    fig = make_subplots(
        rows=3,
        cols=1,
        shared_xaxes=True,
        vertical_spacing=0.06,
        row_heights=[0.4, 0.4, 0.2],
        subplot_titles=("σ translation (cm)", "σ rotation (deg)", "verdict"),
    )
    palette = ("#1f77b4", "#2ca02c", "#9467bd")
    for i, axis in enumerate("xyz"):
        fig.add_trace(
            go.Scatter(
                x=t,
                y=100 * _column(run.rows, f"sigma_{axis}"),
                name=f"σ {axis}",
                mode="lines",
                line={"color": palette[i]},
            ),
            row=1,
            col=1,
        )
    for i, axis in enumerate(("roll", "pitch", "yaw")):
        fig.add_trace(
            go.Scatter(
                x=t,
                y=np.degrees(_column(run.rows, f"sigma_{axis}")),
                name=f"σ {axis}",
                mode="lines",
                line={"color": palette[i], "dash": "dash"},
            ),
            row=2,
            col=1,
        )
    verdicts = run.verdicts()
    for kind in ("accepted", "held", "rejected"):
        idx = [k for k, v in enumerate(verdicts) if v == kind]
        if not idx:
            continue
        fig.add_trace(
            go.Scatter(
                x=t[idx],
                y=[kind] * len(idx),
                mode="markers",
                name=kind,
                marker={
                    "color": _COLORS[kind],
                    "size": 7,
                    "symbol": "circle" if kind == "accepted" else "x",
                },
                text=[_reason(run.rows[k], k) for k in idx],
                hoverinfo="text+x",
            ),
            row=3,
            col=1,
        )
        for k in idx if kind == "rejected" else ():
            for row in (1, 2):
                fig.add_vline(
                    x=t[k],
                    line={"color": _COLORS["rejected"], "width": 1},
                    opacity=0.35,
                    row=row,
                    col=1,
                )
    fig.update_yaxes(type="log", row=1, col=1)
    fig.update_yaxes(type="log", row=2, col=1)
    fig.update_yaxes(
        categoryorder="array", categoryarray=["rejected", "held", "accepted"], row=3, col=1
    )
    fig.update_xaxes(title_text="time since the first frame (s)", row=3, col=1)
    fig.update_layout(
        title="Uncertainty and verdict per frame", height=640, legend={"orientation": "h"}
    )
    return fig


def _timing_figure(run: RunFolder) -> tuple[Any, dict[str, float]] | None:
    """Stacked per-stage times per frame with their medians; None when the rows have none."""
    go, _, _ = _plotly()
    frames = np.arange(len(run.rows))
    fig = go.Figure()
    medians: dict[str, float] = {}
    palette = ("#8c564b", "#e377c2", "#1f77b4", "#bcbd22", "#17becf")
    for stage, color in zip(STAGES, palette, strict=True):
        values = _column(run.rows, f"time_{stage}_ms")
        if np.isnan(values).all():
            continue
        medians[stage] = float(np.nanmedian(values))
        fig.add_trace(go.Bar(x=frames, y=values, name=stage, marker={"color": color}))
    if not medians:  # rows from before per-stage timing: the total only
        values = _column(run.rows, "time_ms")
        if np.isnan(values).all():
            return None
        medians["total"] = float(np.nanmedian(values))
        fig.add_trace(go.Bar(x=frames, y=values, name="total"))
    fig.update_layout(
        barmode="stack",
        title="Time per stage and frame",
        height=420,
        xaxis_title="frame",
        yaxis_title="ms",
        legend={"orientation": "h"},
    )
    return fig, medians


def _map_points(path: Path) -> FloatArray:
    from .io import read_points
    from .preprocess import voxel_downsample

    pts = read_points(path).finite().points
    if pts.shape[1] != 3 or len(pts) == 0:
        return np.zeros((0, 3))
    extent = float(np.ptp(pts, axis=0).max())
    voxel = max(extent / 400.0, 0.05)
    while True:  # coarser until the budget holds: the view stays fluid on a laptop
        down = voxel_downsample(np.ascontiguousarray(pts), voxel).points
        if len(down) <= MAX_MAP_POINTS:
            return down
        voxel *= 1.5


def _map_figure(run: RunFolder) -> tuple[Any, int]:
    go, _, _ = _plotly()
    assert run.map_path is not None
    # a map saved with --map-origin is in CRS coordinates: draw it in the run's frame
    origin = np.asarray(run.summary.get("map_origin", (0.0, 0.0, 0.0)), dtype=np.float64)
    pts = _map_points(run.map_path) - origin
    est = run.estimate.positions
    fig = go.Figure()
    fig.add_trace(
        go.Scatter3d(
            x=pts[:, 0],
            y=pts[:, 1],
            z=pts[:, 2],
            mode="markers",
            name="map",
            marker={
                "size": 1.5,
                "color": pts[:, 2],
                "colorscale": "Viridis",
                "colorbar": {"title": "z (m)"},
            },
            hoverinfo="skip",
        )
    )
    fig.add_trace(
        go.Scatter3d(
            x=est[:, 0],
            y=est[:, 1],
            z=est[:, 2],
            mode="lines",
            name="trajectory",
            line={"color": "#d62728", "width": 6},
        )
    )
    fig.update_layout(
        title=f"Map ({len(pts)} points shown, {run.map_path.name})",
        height=640,
        scene={"aspectmode": "data"},
        legend={"orientation": "h"},
    )
    return fig, len(pts)


def _self_check_figure(run: RunFolder, check: dict[str, Any]) -> Any:
    """The trajectory with the returns the self-check found contradicted, and its worst
    regions outlined."""
    go, _, _ = _plotly()
    est = run.estimate.positions
    fig = go.Figure()
    fig.add_trace(
        go.Scatter(
            x=est[:, 0], y=est[:, 1], mode="lines", name="trajectory",
            line={"color": _COLORS["reference"], "width": 1},
        )
    )  # fmt: skip
    points = run.contradictions if run.contradictions is not None else np.zeros((0, 2))
    if len(points) > MAX_MAP_POINTS:  # evenly thinned: the density still shows where
        points = points[:: math.ceil(len(points) / MAX_MAP_POINTS)]
    fig.add_trace(
        go.Scattergl(
            x=points[:, 0], y=points[:, 1], mode="markers", name="contradicted returns",
            marker={"color": _COLORS["rejected"], "size": 3},
        )
    )  # fmt: skip
    for k, r in enumerate(check.get("regions", [])):
        h = 0.5 * float(r["size"])
        x, y = float(r["x"]), float(r["y"])
        fig.add_shape(
            type="rect", x0=x - h, x1=x + h, y0=y - h, y1=y + h,
            line={"color": _COLORS["held"], "width": 2},
        )  # fmt: skip
        fig.add_annotation(
            x=x, y=y + h, text=f"#{k + 1}: {r['contradictions']}", showarrow=False, yshift=8
        )
    fig.update_layout(
        title="Self-check: returns in cells other scans saw free",
        xaxis_title="x (m)",
        yaxis_title="y (m)",
        height=520,
        legend={"orientation": "h"},
    )
    fig.update_yaxes(scaleanchor="x", scaleratio=1)
    return fig


def _self_check_text(check: dict[str, Any]) -> str:
    verdict = "consistent" if check.get("consistent") else "INCONSISTENT"
    fraction = float(check.get("contradiction_fraction") or 0.0)
    lines = [
        f"<p><b>{verdict}</b>: {check.get('contradictions', 0)} of {check.get('returns', 0)} "
        f"returns contradicted ({fraction:.2%}); {check.get('loops_over_bound', 0)} of "
        f"{check.get('loops', 0)} loop edges over their 99.9 % χ² bound, "
        f"{check.get('loops_downweighted', 0)} down-weighted by the back end.</p>"
    ]
    lines += [f"<p>{html.escape(str(r))}</p>" for r in check.get("reasons", [])]
    regions = check.get("regions", [])
    if regions:
        from .pipeline.map_check import describe_region

        items = "".join(
            f"<li>#{k + 1}: {html.escape(describe_region(r))}</li>" for k, r in enumerate(regions)
        )
        lines.append(
            f"<p>Where the contradicted returns gather, and whose they are:</p><ul>{items}</ul>"
        )
    return "".join(lines)


# --------------------------------------------------------------------------- HTML


def _cards(run: RunFolder) -> str:
    verdicts = run.verdicts()
    cards = [
        ("frames", str(len(run.estimate))),
        ("accepted", str(verdicts.count("accepted") + verdicts.count("held"))),
        ("rejected", str(verdicts.count("rejected"))),
        ("held", str(verdicts.count("held"))),
    ]
    pos = run.estimate.positions
    length = sum(  # each session's own: not the jump from one session's end to the next's start
        float(np.linalg.norm(np.diff(pos[idx], axis=0), axis=1).sum())
        for _, idx in run.session_indices()
    )
    cards.append(("path length", f"{length:.1f} m"))
    if "frames_per_second" in run.summary:
        cards.append(("frames/s", f"{run.summary['frames_per_second']:.1f}"))
    total = _column(run.rows, "time_ms")
    if len(total) and not np.isnan(total).all():
        cards.append(("median frame time", f"{np.nanmedian(total):.1f} ms"))
    accuracy = run.summary.get("accuracy", {})
    if "ate_rmse_m" in accuracy:
        cards.append(("ATE RMSE", f"{accuracy['ate_rmse_m']:.3f} m"))
    if "kitti_translation_percent" in accuracy:
        cards.append(("KITTI drift", f"{accuracy['kitti_translation_percent']:.2f} %"))
    if run.loops:
        n_ok = sum(ok for _, _, ok, _ in run.loop_ends())
        cards.append(("loop closures", f"{n_ok} / {len(run.loops)}"))
    if run.scan_sessions is not None:
        cards.append(("sessions", str(len(run.sessions))))
        between = [lp for lp in run.loops if lp.get("inter_session")]
        n_between = sum(bool(lp.get("accepted")) for lp in between)
        cards.append(("loops between sessions", f"{n_between} / {len(between)}"))
    return (
        '<div class="cards">'
        + "".join(
            f'<div class="card"><span class="muted">{html.escape(k)}</span><b>{html.escape(v)}</b>'
            "</div>"
            for k, v in cards
        )
        + "</div>"
    )


def _rejection_table(run: RunFolder) -> str:
    rows = [
        (k, r)
        for k, r in enumerate(run.rows)
        if not r.get("accepted", True) or r.get("held_directions")
    ]
    if not rows:
        return '<p class="muted">Every frame was accepted with nothing held.</p>'
    body = "".join(
        f"<tr><td>{k}</td><td>{float(r.get('stamp', math.nan)):.3f}</td>"
        f"<td>{'rejected' if not r.get('accepted', True) else 'held'}</td>"
        f"<td>{html.escape(str(r.get('reasons') or ''))}</td>"
        f"<td>{html.escape(str(r.get('held_directions') or ''))}</td></tr>"
        for k, r in rows[:500]
    )
    more = f'<p class="muted">… and {len(rows) - 500} more.</p>' if len(rows) > 500 else ""
    return (
        "<table><tr><th>frame</th><th>stamp (s)</th><th>verdict</th><th>reasons</th>"
        f"<th>held directions</th></tr>{body}</table>{more}"
    )


def render_report(folder: PathLike, *, title: str | None = None) -> str:
    """The report of the run in ``folder`` as one HTML string (see the module docstring)."""
    _, pio, _ = _plotly()
    run = RunFolder(folder)
    name = title or str(run.summary.get("sequence") or run.root.resolve().name)
    if title is None and run.scan_sessions is not None:  # a joint map: not its last run's name
        name = f"{run.root.resolve().name}, a map of {len(run.sessions)} sessions"
    sections: list[tuple[str, Any]] = [("Trajectory", _trajectory_figure(run))]
    medians: dict[str, float] = {}
    if run.rows:
        sections.append(("Uncertainty and verdicts", _sigma_figure(run)))
        timing = _timing_figure(run)
        if timing is not None:
            sections.append(("Timing", timing[0]))
            medians = timing[1]
    check = run.summary.get("self_check")
    if isinstance(check, dict):
        sections.append(("Self-check", _self_check_figure(run, check)))
    map_note = '<p class="muted">No map in the run folder (scanreg odometry --save-map).</p>'
    if run.map_path is not None:
        fig, _ = _map_figure(run)
        sections.append(("Map", fig))
        map_note = ""
    parts = [
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>",
        f"<title>scanreg run: {html.escape(name)}</title><style>{_CSS}</style>",
        _ERROR_HOOK,
        "</head><body>",
        f"<h1>scanreg run: {html.escape(name)}</h1>",
        f'<p class="muted">{html.escape(str(run.root.resolve()))}</p>',
        '<pre id="scanreg-js-errors"></pre>',
        _cards(run),
    ]
    config = {"displaylogo": False, "responsive": True}
    for index, (heading, fig) in enumerate(sections):
        parts.append(f"<h2>{heading}</h2>")
        parts.append(
            pio.to_html(
                fig,
                include_plotlyjs=index == 0,
                full_html=False,
                config=config,
                include_mathjax=False,
                div_id=f"scanreg-{heading.lower().split()[0]}",
            )
        )
        if heading == "Timing" and medians:
            cells = "".join(f"<td>{k}: {v:.2f} ms</td>" for k, v in medians.items())
            parts.append(f"<table><tr><th>median</th>{cells}</tr></table>")
        if heading == "Self-check" and isinstance(check, dict):
            parts.append(_self_check_text(check))
        if heading == "Uncertainty and verdicts":
            parts.append("<h2>Rejected and held frames</h2>" + _rejection_table(run))
    if run.map_image is not None and run.map_path is None:
        data = base64.b64encode(run.map_image.read_bytes()).decode("ascii")
        parts.append(
            f"<h2>Occupancy grid</h2><img alt='occupancy grid' src='data:image/png;base64,{data}'"
            " style='max-width: 100%; image-rendering: pixelated'>"
        )
        map_note = ""
    parts.append(map_note)
    if run.config:
        parts.append(f"<h2>Configuration</h2><pre>{html.escape(run.config)}</pre>")
    parts += [_DONE_HOOK, "</body></html>"]
    return "\n".join(parts)


def write_report(
    folder: PathLike, output: PathLike | None = None, *, title: str | None = None
) -> Path:
    """Write the report of the run in ``folder`` to ``output`` (default
    ``folder/report.html``) and return its path. The file is written under a temporary name
    and renamed, so a failure leaves no partial report."""
    text = render_report(folder, title=title)
    out = Path(folder) / "report.html" if output is None else Path(output)
    if not out.parent.is_dir():
        raise FileNotFoundError(f"{out}: cannot write the report: no folder {out.parent}")
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{out.name}.partial-", dir=out.parent)
    except OSError as exc:
        raise PermissionError(f"{out}: cannot write the report: {exc.strerror}") from None
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
        os.chmod(tmp, 0o644)
        os.replace(tmp, out)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return out


__all__ = ["MAP_NAMES", "MAX_MAP_POINTS", "STAGES", "RunFolder", "render_report", "write_report"]
