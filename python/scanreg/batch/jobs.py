"""Job kinds and the worker-side execution of one job.

A job kind (:class:`JobKind`) names its manifest columns, checks a row before the batch starts
and runs one job into a folder. :data:`JOB_KINDS` is the registry the CLI and
:func:`scanreg.batch.run_batch` read: ``odometry``, ``register`` and ``map``, each calling
the library function its single-job command calls (:mod:`scanreg.pipeline.commands`), never
the command line's own code.

:func:`execute` runs in the worker: it writes the job's outputs into a temporary folder beside
the final one and renames it into place only when the job succeeded (``out/<id>/`` exists only
complete), records a failure (error, traceback) instead of raising, and returns a small record.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import socket
import time
import traceback
import uuid
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .manifest import Job

#: The job's own record, written last into ``out/<id>/job.json`` (``--resume`` reads it).
JOB_FILE = "job.json"
#: What the single-job command prints with ``--json``, written into ``out/<id>/result.json``.
RESULT_FILE = "result.json"
#: Prefix of a job's folder while it is written (removed on failure; left by a killed worker,
#: cleaned by the next run).
TMP_PREFIX = ".tmp-"

#: ``scanreg register``'s options a register job's TOML config may set, with their types.
REGISTER_OPTIONS: dict[str, type] = {
    "method": str,
    "max_correspondence_distance": float,
    "voxel_size": float,
    "kernel": str,
    "max_iterations": int,
}

JobFunction = Callable[[Job, Path], Mapping[str, Any]]


@dataclass(frozen=True)
class JobKind:
    """A kind of batch job."""

    #: Required manifest columns besides ``id``.
    columns: tuple[str, ...]
    #: Optional manifest columns.
    optional: tuple[str, ...]
    #: ``run(job, folder) -> result``: writes the job's files into ``folder`` (created) and
    #: returns what goes into ``result.json``. Must be importable by name (workers unpickle it).
    run: JobFunction
    #: ``check(job)``: raises ValueError/OSError for a row that cannot run (called up front).
    check: Callable[[Job], None] = field(default=lambda job: None)
    #: Columns that may hold a ``sim:`` URI instead of a path.
    sim_columns: tuple[str, ...] = ()


# --------------------------------------------------------------------------- odometry


def _check_odometry(job: Job) -> None:
    from ..config import load_config
    from ..io.sequences import parse_sim_spec
    from ..pipeline.odometry import OdometryConfig

    spec = str(job.get("input"))
    if spec.startswith("sim:"):
        parse_sim_spec(spec)
    if job.get("config"):
        load_config(OdometryConfig, job.get("config"))


def run_odometry_job(job: Job, folder: Path) -> dict[str, Any]:
    """``scanreg odometry INPUT -o FOLDER [--config CONFIG] --no-plots``, in this process
    (:func:`scanreg.pipeline.run_odometry_to_folder`): ``poses_kitti.txt``, ``poses_tum.txt``,
    ``quality.jsonl``/``.csv``, ``config.toml``. Figures per job would dominate small jobs:
    none are drawn (plot from the poses)."""
    from ..pipeline.commands import run_odometry_to_folder

    result = run_odometry_to_folder(
        str(job.get("input")), folder, config=job.get("config"), plots=False
    )
    return _relative_outputs(result)


def _relative_outputs(result: dict[str, Any]) -> dict[str, Any]:
    # file names, not the temporary folder's paths
    result["outputs"] = {k: Path(v).name for k, v in result["outputs"].items()}
    return result


# --------------------------------------------------------------------------- map


def _check_map(job: Job) -> None:
    from ..config import load_config
    from ..io.sequences import parse_sim_spec
    from ..pipeline.commands import is_3d_source
    from ..pipeline.mapping import MappingConfig
    from ..pipeline.mapping3d import MappingConfig3D

    spec = str(job.get("input"))
    if spec.startswith("sim:"):
        parse_sim_spec(spec)
    if job.get("config"):
        from ..io.laserscan_bag import is_laserscan_bag
        from ..pipeline.scan_source import is_bag

        laserscans = not spec.startswith("sim:") and is_bag(spec) and is_laserscan_bag(spec)
        kind = MappingConfig3D if is_3d_source(spec) and not laserscans else MappingConfig
        load_config(kind, job.get("config"))


def run_map_job(job: Job, folder: Path) -> dict[str, Any]:
    """``scanreg map INPUT -o FOLDER [--config CONFIG] --no-plots``, in this process
    (:func:`scanreg.pipeline.run_mapping_to_folder`): the map folder (a
    :class:`scanreg.SavedMap`), ``summary.json``, ``config.toml``."""
    from ..pipeline.commands import run_mapping_to_folder

    result = run_mapping_to_folder(
        str(job.get("input")), folder, config=job.get("config"), plots=False
    )
    return _relative_outputs(result)


# --------------------------------------------------------------------------- register


def register_options(config: str | None) -> dict[str, Any]:
    """The register options of a job's TOML config (unknown keys and wrong types refused)."""
    if not config:
        return {}
    from ..config import read_config_file

    table = read_config_file(config)
    out: dict[str, Any] = {}
    for key, value in table.items():
        if key not in REGISTER_OPTIONS:
            raise ValueError(
                f"config {config}: unknown key {key!r} (keys: {', '.join(REGISTER_OPTIONS)})"
            )
        kind = REGISTER_OPTIONS[key]
        if isinstance(value, bool) or not isinstance(value, (kind, int) if kind is float else kind):
            raise ValueError(f"config {config}: {key} must be {kind.__name__}, got {value!r}")
        try:
            out[key] = kind(value)
        except OverflowError:  # an integer of 309+ digits for a float option
            raise ValueError(f"config {config}: {key} is too large, got {value!r}") from None
    return out


def _check_register(job: Job) -> None:
    from ..register import METHODS

    options = register_options(job.get("config"))
    method = options.get("method", "point_to_plane")
    if method not in METHODS:
        raise ValueError(f"config: unknown method {method!r} (known: {', '.join(METHODS)})")


#: Targets loaded in this worker process, by (path, mtime, size, options): a shared prior map
#: named by many rows is read and prepared once per worker, never shipped with the tasks.
_TARGETS: dict[tuple[Any, ...], Any] = {}
_TARGETS_MAX = 4


def _load_cloud(path: str, voxel_size: float | None) -> Any:
    import numpy as np

    from .. import io, preprocess

    pts = io.read_points(path).finite().points
    if voxel_size:
        pts = preprocess.voxel_downsample(pts, voxel_size).points
    return np.ascontiguousarray(pts)


def shared_target(path: str, options: Mapping[str, Any]) -> Any:
    """The prepared target of ``path`` as ``scanreg register`` would prepare it with
    ``options``, loaded once per worker process (kept for the next jobs naming it)."""
    from ..register import _DEFAULT_SETTINGS, _plan, _prepared_target, _with_overrides

    stat = os.stat(path)
    voxel = options.get("voxel_size")
    method = options.get("method", "point_to_plane")
    key = (os.path.realpath(path), stat.st_mtime_ns, stat.st_size, voxel, method)
    if key not in _TARGETS:
        points = _load_cloud(path, voxel)
        settings = _with_overrides(_DEFAULT_SETTINGS, _settings_overrides(options))
        method_eff = _plan(settings, method, int(points.shape[1])).method
        if len(_TARGETS) >= _TARGETS_MAX:
            _TARGETS.pop(next(iter(_TARGETS)))
        _TARGETS[key] = _prepared_target(points, int(points.shape[1]), method_eff, settings)
    return _TARGETS[key]


def _settings_overrides(options: Mapping[str, Any]) -> dict[str, Any]:
    # voxel_size is applied to the clouds as the CLI does, not by register()
    out = {k: v for k, v in options.items() if k not in ("method", "voxel_size")}
    out.setdefault("max_correspondence_distance", 1.0)
    out.setdefault("kernel", "none")
    out.setdefault("max_iterations", 30)
    return out


def run_register_job(job: Job, folder: Path) -> dict[str, Any]:
    """``scanreg register SOURCE TARGET [--init INIT] ... --json``, with the target prepared
    once per worker: writes nothing but ``result.json`` (the command's JSON)."""
    import numpy as np

    from ..pipeline.commands import registration_summary
    from ..register import register

    options = register_options(job.get("config"))
    source = _load_cloud(str(job.get("source")), options.get("voxel_size"))
    target = shared_target(str(job.get("target")), options)
    init_file = job.get("init")
    init = None if init_file is None else np.loadtxt(init_file, ndmin=2)
    res = register(
        source,
        target,
        method=options.get("method", "point_to_plane"),
        init=init,
        **_settings_overrides(options),
    )
    folder.mkdir(parents=True, exist_ok=True)
    return registration_summary(res)


JOB_KINDS: dict[str, JobKind] = {
    "odometry": JobKind(
        columns=("input",),
        optional=("config",),
        run=run_odometry_job,
        check=_check_odometry,
        sim_columns=("input",),
    ),
    "register": JobKind(
        columns=("source", "target"),
        optional=("config", "init"),
        run=run_register_job,
        check=_check_register,
    ),
    "map": JobKind(
        columns=("input",),
        optional=("config",),
        run=run_map_job,
        check=_check_map,
        sim_columns=("input",),
    ),
}


# --------------------------------------------------------------------------- execution


def execute(job: Job, output: str, run: JobFunction, threads: int) -> dict[str, Any]:
    """Run ``job`` in this (worker) process into ``output/<id>/``, atomically; never raises
    for the job's own errors. Returns the job's record (status, error, traceback, timing)."""
    from ..threads import get_num_threads, set_num_threads

    with contextlib.suppress(RuntimeError):  # a reused worker sized earlier: recorded below
        set_num_threads(threads)
    root = Path(output)
    final = root / job.id
    tmp = root / f"{TMP_PREFIX}{job.id}-{uuid.uuid4().hex[:12]}"
    started = time.time()
    t0 = time.perf_counter()
    record: dict[str, Any] = {
        "id": job.id,
        "status": "done",
        "error": "",
        "traceback": "",
        "started": started,
        "worker": f"{socket.gethostname()}:{os.getpid()}",
        "threads": get_num_threads(),
    }
    try:
        tmp.mkdir(parents=True)
        result = dict(run(job, tmp))
        seconds = time.perf_counter() - t0
        (tmp / RESULT_FILE).write_text(json.dumps(result, indent=2) + "\n")
        record["seconds"] = seconds
        (tmp / JOB_FILE).write_text(
            json.dumps({"job": job.spec(), **record}, indent=2, default=str) + "\n"
        )
        if final.exists():  # a stale result of a changed row: replaced whole
            shutil.rmtree(final)
        os.replace(tmp, final)
    except (Exception, SystemExit) as exc:  # SystemExit: a job's argparse or sys.exit
        shutil.rmtree(tmp, ignore_errors=True)
        record["status"] = "failed"
        record["error"] = f"{type(exc).__name__}: {exc}"
        record["traceback"] = traceback.format_exc()
        record["seconds"] = time.perf_counter() - t0
    record["finished"] = time.time()
    return record


def finished_record(output: Path, job: Job) -> dict[str, Any] | None:
    """The record of ``job`` already done in ``output`` with the same spec (for ``--resume``),
    or None."""
    path = output / job.id / JOB_FILE
    try:
        stored = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    if stored.get("job") != job.spec() or stored.get("status") != "done":
        return None
    stored.pop("job")
    return dict(stored)


def record_attempts(output: Path, job_id: str, attempts: int) -> None:
    """Add the attempts (known to the engine, not the worker) to a done job's ``job.json``,
    atomically."""
    path = output / job_id / JOB_FILE
    stored = json.loads(path.read_text())
    stored["attempts"] = attempts
    tmp = path.with_name(f".{JOB_FILE}.tmp-{os.getpid()}")
    tmp.write_text(json.dumps(stored, indent=2, default=str) + "\n")
    os.replace(tmp, path)


def clean_temporary(output: Path) -> None:
    """Remove the folders a killed worker left half-written."""
    if output.is_dir():
        for p in output.glob(f"{TMP_PREFIX}*"):
            shutil.rmtree(p, ignore_errors=True)


__all__ = [
    "JOB_FILE",
    "JOB_KINDS",
    "REGISTER_OPTIONS",
    "RESULT_FILE",
    "Job",
    "JobKind",
    "execute",
    "finished_record",
    "register_options",
    "run_map_job",
    "run_odometry_job",
    "run_register_job",
    "shared_target",
]
