"""Write docs/api.md, the API reference, from scanreg's docstrings and signatures.

Run from the repository root after changing the public API::

    .venv/bin/python docs/gen_api.py

A module's public names are its ``__all__``, or else every name it defines (not imported)
without a leading underscore. Each function and class is listed with its signature and its
docstring as written (they carry shapes, units, frames and the errors raised).
"""

from __future__ import annotations

import importlib
import inspect
import re
from pathlib import Path
from typing import Any

#: Modules in reading order, with a one-line summary each.
MODULES: tuple[tuple[str, str], ...] = (
    ("scanreg", "the top-level entry points (re-exported from the modules below)"),
    ("scanreg.transform", "SE(2)/SE(3) poses, exp/log, adjoints"),
    ("scanreg.paired", "closed-form and robust alignment of paired points"),
    ("scanreg.register", "local registration: ICP, point-to-plane/line, GICP"),
    ("scanreg.trust", "the trust analysis: covariance kinds, degeneracy, verdict orchestration"),
    ("scanreg.target", "prepared targets (k-d tree, normals, covariances)"),
    ("scanreg.preprocess", "downsampling, cropping, outliers, normals, covariances"),
    ("scanreg.correlative", "2D correlative scan matching (global within a window)"),
    ("scanreg.ndt", "NDT, 2D and 3D"),
    ("scanreg.global_registration", "3D registration without a guess: FPFH, max clique, GNC-TLS"),
    ("scanreg.surface_noise", "a scanned surface's noise and whether it leaves the shape resolved"),
    ("scanreg.basin", "the verdict's wrong-basin / ambiguity probe"),
    ("scanreg.slide", "never worse than the start: a registration that slid from a better start"),
    ("scanreg.budget", "a memory budget for large clouds"),
    ("scanreg.quality", "covariance, conditioning, residual statistics"),
    ("scanreg.degeneracy", "weak directions named in pose coordinates"),
    ("scanreg.pinned", "whether the scan itself pins a 2D result along a weak direction"),
    ("scanreg.verdict", "accept or reject a registration, with reasons"),
    ("scanreg.deskew", "motion compensation of a sweep"),
    ("scanreg.robust", "robust kernels"),
    ("scanreg.io", "point clouds, CARMEN logs, ROS bags, trajectories, g2o"),
    ("scanreg.io.sequences", "sequences of sweeps: KITTI, folders, bags, simulated drives"),
    ("scanreg.io.tables", "per-frame tables (JSON lines, CSV) and pose files"),
    ("scanreg.config", "TOML/dict configs into frozen dataclasses, strictly; presets"),
    ("scanreg.eval", "ATE, RPE, the KITTI metric, Kümmerle relations"),
    ("scanreg.simulate", "scenes, sensors, trajectories and ray-cast scans with truth"),
    ("scanreg.simulate.courses", "loops and revisits with truth: block_loop, room_tour"),
    ("scanreg.simulate.objects", "scanned objects with truth: knot, blob, figurine, views"),
    ("scanreg.place", "place recognition: Scan Context descriptors and their database"),
    ("scanreg.interop", "Open3D and ROS message layouts"),
    ("scanreg.plot", "figures (matplotlib)"),
    ("scanreg.pipeline", "odometry, localization (2D/3D) and mapping pipelines"),
    ("scanreg.pipeline.commands", "what each scanreg command does, as library functions"),
    ("scanreg.pipeline.join", "one graph over two maps' sessions, 2D or 3D (extend and merge)"),
    ("scanreg.pipeline.join3d", "3D inter-session loops: place recognition, global registration"),
    ("scanreg.pipeline.odometry_timing", "which wheel odometry goes with each 2D scan: latency"),
    ("scanreg.saved_map", "a saved map folder as one versioned type: SavedMap, its manifest"),
    ("scanreg.graph", "the pose graph (gtsam): calibrated-covariance edges, iSAM2, marginals"),
    ("scanreg.report", "the HTML run report"),
    ("scanreg.batch", "many odometry/registration jobs on local workers or a Ray cluster"),
    ("scanreg.threads", "the core's process-wide thread budget"),
)

OUT = Path(__file__).resolve().parent / "api.md"


def public_names(module: Any) -> list[str]:
    names = getattr(module, "__all__", None)
    if names is not None:
        return [n for n in names if not n.startswith("__")]
    return sorted(
        name
        for name, obj in vars(module).items()
        if not name.startswith("_")
        and (inspect.isfunction(obj) or inspect.isclass(obj))
        and getattr(obj, "__module__", None) == module.__name__
    )


def signature(obj: Any) -> str:
    try:
        text = str(inspect.signature(obj))
    except (TypeError, ValueError):
        return "(...)"
    # Postponed annotations are strings: show them unquoted (defaults keep their quotes).
    text = re.sub(r"(: |-> )'([^']*)'", r"\1\2", text)
    # A callable default's repr carries its memory address: drop it so the file is reproducible.
    text = re.sub(r"<function ([^ ]+) at 0x[0-9a-f]+>", r"<function \1>", text)
    return re.sub(r'(: |-> )"([^"]*)"', r"\1\2", text)


def value(obj: Any) -> str:
    """A constant's value; functions by name (their reprs hold memory addresses)."""
    if isinstance(obj, dict):
        items = ", ".join(f"{k!r}: {value(v)}" for k, v in obj.items())
        return "{" + items + "}"
    if callable(obj):
        return str(getattr(obj, "__name__", type(obj).__name__))
    text = repr(obj)
    return text if len(text) <= 120 else f"{type(obj).__name__}(...)"


def docstring(obj: Any) -> str:
    doc = inspect.getdoc(obj)
    return doc.strip() if doc else "(no docstring)"


def summary(obj: Any) -> str:
    doc = inspect.getdoc(obj)
    return f": {doc.strip().splitlines()[0]}" if doc else ""


def fence(text: str) -> str:
    return f"```text\n{text}\n```\n"


def render_class(qualname: str, cls: type) -> list[str]:
    lines = [f"### class `{qualname}`\n", f"`{qualname}{signature(cls)}`\n", fence(docstring(cls))]
    members = []
    for name, member in inspect.getmembers(cls):
        if name.startswith("_") or name not in vars(cls):
            continue
        raw = vars(cls)[name]
        if isinstance(raw, property):
            members.append(f"- `{name}` (property){summary(raw)}")
        elif inspect.isfunction(member) or isinstance(raw, (classmethod, staticmethod)):
            members.append(f"- `{name}{signature(member)}`{summary(member)}")
    if members:
        lines.append("Members:\n")
        lines.extend(members)
        lines.append("")
    return lines


def render_module(name: str, title: str) -> list[str]:
    module = importlib.import_module(name)
    lines = [f"## `{name}` — {title}\n", fence(docstring(module))]
    if name == "scanreg":  # re-exports: point to where each is documented
        for attr in public_names(module):
            obj = getattr(module, attr)
            home = obj.__name__ if inspect.ismodule(obj) else getattr(obj, "__module__", name)
            lines.append(f"- `scanreg.{attr}` — see `{home}`")
        lines.append("")
        return lines
    for attr in public_names(module):
        obj = getattr(module, attr)
        qualname = f"{name}.{attr}"
        if inspect.isclass(obj):
            lines.extend(render_class(qualname, obj))
        elif callable(obj):
            lines.append(f"### `{qualname}{signature(obj)}`\n")
            lines.append(fence(docstring(obj)))
        elif inspect.ismodule(obj):
            lines.append(f"### module `{qualname}` (see its section)\n")
        else:
            lines.append(f"### `{qualname}` = `{value(obj)}`\n")
    return lines


def render() -> str:
    lines = [
        "# scanreg API reference\n",
        "Generated by `docs/gen_api.py` from the docstrings; regenerate it after API changes.",
        "Conventions (frames, `T_target_source`, tangent order, covariances) are in",
        "[concepts.md](concepts.md). Errors: invalid arguments raise `ValueError`/`TypeError`",
        "naming the argument; unreadable files raise `scanreg.io.FileFormatError` (a",
        "`ValueError`) naming the file and the problem.\n",
        "Modules:\n",
    ]
    lines.extend(f"- `{name}` — {summary}" for name, summary in MODULES)
    lines.append("")
    for name, summary in MODULES:
        lines.extend(render_module(name, summary))
    return "\n".join(lines).rstrip() + "\n"


if __name__ == "__main__":
    OUT.write_text(render(), encoding="utf-8")
    print(f"wrote {OUT}")
