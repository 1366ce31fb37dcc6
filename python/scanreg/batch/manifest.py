"""Batch manifests: one row per job, read from CSV or Parquet and checked before anything runs.

Columns (``id`` always; the others by job kind, see :data:`scanreg.batch.jobs.JOB_KINDS`):

* ``odometry``: ``input`` — a sequence (KITTI folder, folder of point files, ROS bag) or a
  ``sim:`` URI (``sim:street,frames=20,seed=3``); optional ``config`` — a TOML file as
  ``scanreg odometry --config`` takes.
* ``map``: ``input`` — what ``scanreg map`` reads (a 2D CARMEN log or LaserScan bag; a 3D
  sequence or ``sim:`` URI); optional ``config`` — a TOML file as ``scanreg map --config``
  takes. Each job writes the map folder (:class:`scanreg.SavedMap`) without the plot.
* ``register``: ``source`` and ``target`` — point files; optional ``config`` — a TOML file of
  ``scanreg register``'s options (``method``, ``max_correspondence_distance``, ``voxel_size``,
  ``kernel``, ``max_iterations``); optional ``init`` — a text file with the initial
  ``T_target_source`` (as ``scanreg register --init``).

Relative paths are relative to the manifest's folder. Every row is checked up front (ids unique
and usable as folder names, files present, ``sim:`` URIs and configs valid): a bad row stops the
batch before any job starts, with an error naming the manifest, the row and the column.
"""

from __future__ import annotations

import csv
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

#: A job id names its output folder: letters, digits, ``.``, ``_``, ``-`` (not only dots).
_ID = re.compile(r"^[A-Za-z0-9._-]{1,200}$")


class ManifestError(ValueError):
    """A manifest that cannot run: the message names the file, the row and the column."""


@dataclass(frozen=True)
class Job:
    """One job of a batch: small, picklable, with paths already resolved."""

    id: str
    kind: str
    #: Column values (paths made absolute; ``sim:`` URIs as written), by column name.
    params: Mapping[str, str] = field(default_factory=dict)
    #: The manifest row (1 = the first data row), for messages.
    row: int = field(default=0, compare=False)

    def get(self, column: str) -> str | None:
        return self.params.get(column)

    def spec(self) -> dict[str, Any]:
        """What identifies the job's work (``--resume`` re-runs a job whose spec changed)."""
        return {"id": self.id, "kind": self.kind, **dict(sorted(self.params.items()))}


#: More rows than a batch could ever run: a Parquet manifest holding more is refused.
MAX_PARQUET_ROWS = 1_000_000
#: Rows per record batch read from a Parquet manifest.
_PARQUET_BATCH = 4096


def _parquet_rows(path: Path, pq: Any) -> tuple[list[str], list[dict[str, Any]]]:
    """The rows of a Parquet manifest, read batch by batch.

    Not ``read_table``: it allocates by the footer's row counts (a 1 kB manifest whose row
    group claimed 82 797 590 141 rows made it reserve 275 GB; where the system grants that,
    the process swells until the kernel kills it). Batches bound what a damaged footer can
    make it allocate. Nor the footer's per-column metadata (``row_group(i).column(j)``): on a
    damaged size-statistics histogram it throws a C++ exception pyarrow does not convert
    (``std::terminate``, SIGABRT); the batch reader refuses the same file with an OSError.
    Both found by fuzz/ (target manifest_parquet)."""
    parquet = pq.ParquetFile(path)
    columns = list(parquet.schema_arrow.names)
    rows: list[dict[str, Any]] = []
    for batch in parquet.iter_batches(batch_size=_PARQUET_BATCH):
        rows.extend(batch.to_pylist())
        if len(rows) > MAX_PARQUET_ROWS:
            raise ManifestError(
                f"{path}: more than {MAX_PARQUET_ROWS} rows: more than a manifest holds"
            )
    return columns, rows


def _read_rows(path: Path) -> tuple[list[str], list[dict[str, Any]]]:
    suffix = path.suffix.lower()
    if suffix == ".parquet":
        try:
            import pyarrow.parquet as pq
        except ImportError:
            raise ImportError(
                f"{path}: reading a Parquet manifest needs pyarrow: pip install 'scanreg[batch]'"
            ) from None
        return _parquet_rows(path, pq)
    if suffix not in (".csv", ".tsv"):
        raise ManifestError(f"{path}: a manifest is a .csv, .tsv or .parquet file")
    with open(path, newline="", encoding="utf-8") as fh:
        reader = csv.DictReader(fh, delimiter="\t" if suffix == ".tsv" else ",", restkey="\0")
        columns = [c.strip() for c in (reader.fieldnames or [])]
        rows = []
        for k, raw in enumerate(reader, start=1):
            if "\0" in raw:
                raise ManifestError(
                    f"{path}: row {k}: {len(columns) + len(raw[chr(0)])} fields, the header has "
                    f"{len(columns)} ({', '.join(columns)})"
                )
            if any(v is None for v in raw.values()):
                have = sum(v is not None for v in raw.values())
                raise ManifestError(
                    f"{path}: row {k}: {have} fields, the header has {len(columns)} "
                    f"({', '.join(columns)})"
                )
            rows.append({c.strip(): v for c, v in raw.items()})
        return columns, rows


def _text(value: Any) -> str | None:
    """A cell as text; None for an empty one (CSV ``""``, Parquet null, NaN)."""
    if value is None or (isinstance(value, float) and value != value):
        return None
    text = str(value).strip()
    return text or None


def _local_path(value: str, where: str) -> Path:
    """A cell as a path, ``~`` and ``~user`` expanded; a user this machine does not know,
    or a NUL byte, is a manifest error (``expanduser`` raised a bare RuntimeError)."""
    if "\0" in value:
        raise ManifestError(f"{where}: a path cannot hold a NUL byte")
    try:
        return Path(value).expanduser()
    except RuntimeError:
        user = value[1:].split("/", 1)[0].split("\\", 1)[0]
        who = f"user {user!r}" if user else "the current user"
        raise ManifestError(f"{where}: no home directory for {who} on this machine") from None


def read_manifest(
    path: str | Path,
    kind: str,
    *,
    default_config: str | Path | None = None,
) -> tuple[Job, ...]:
    """The checked jobs of the manifest at ``path`` for job ``kind``.

    ``default_config`` (a TOML file) applies to the rows without a ``config`` of their own.

    Raises
    ------
    ManifestError
        Unreadable file, missing or unknown column, malformed row, duplicate or unusable id,
        missing file, bad ``sim:`` URI or config — naming the row and the column.
    ImportError
        A Parquet manifest without pyarrow (the message names the extra).
    """
    from .jobs import JOB_KINDS

    if kind not in JOB_KINDS:
        raise ValueError(f"kind: unknown job kind {kind!r} (known: {', '.join(JOB_KINDS)})")
    spec = JOB_KINDS[kind]
    path = Path(path)
    if not path.is_file():
        raise ManifestError(f"{path}: no such manifest file")
    try:
        columns, rows = _read_rows(path)
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise ManifestError(f"{path}: cannot read the manifest: {exc}") from None
    except ManifestError:
        raise
    except ImportError:
        raise
    except Exception as exc:  # pyarrow's ArrowInvalid and friends: not a table
        raise ManifestError(f"{path}: cannot read the manifest: {exc}") from None
    required = ("id", *spec.columns)
    missing = [c for c in required if c not in columns]
    if missing:
        raise ManifestError(
            f"{path}: missing column(s) {', '.join(missing)} for {kind} jobs "
            f"(columns: {', '.join(required)}; optional: {', '.join(spec.optional)})"
        )
    unknown = [c for c in columns if c not in required and c not in spec.optional]
    if unknown:
        raise ManifestError(
            f"{path}: unknown column(s) {', '.join(unknown)} for {kind} jobs "
            f"(columns: {', '.join(required)}; optional: {', '.join(spec.optional)})"
        )
    if not rows:
        raise ManifestError(f"{path}: no jobs (the manifest has a header but no rows)")
    base = path.resolve().parent
    fallback = None if default_config is None else str(Path(default_config).resolve())
    if fallback is not None and not Path(fallback).is_file():
        raise ManifestError(f"--config {default_config}: no such file")
    jobs: list[Job] = []
    seen: dict[str, int] = {}
    for k, row in enumerate(rows, start=1):
        where = f"{path}: row {k}"
        job_id = _text(row.get("id"))
        if job_id is None:
            raise ManifestError(f"{where}: empty id")
        if not _ID.match(job_id) or set(job_id) == {"."}:
            raise ManifestError(
                f"{where}: id {job_id!r} cannot name a folder (letters, digits, '.', '_', '-')"
            )
        where = f"{path}: row {k} (id {job_id!r})"
        if job_id in seen:
            raise ManifestError(f"{where}: duplicate id (also row {seen[job_id]})")
        seen[job_id] = k
        params: dict[str, str] = {}
        for column in (*spec.columns, *spec.optional):
            value = _text(row.get(column))
            if value is None:
                if column in spec.columns:
                    raise ManifestError(f"{where}: empty {column}")
                if column == "config" and fallback is not None:
                    params[column] = fallback
                continue
            if value.startswith("sim:") and column in spec.sim_columns:
                params[column] = value
                continue
            file = _local_path(value, f"{where}: {column} {value!r}")
            file = file if file.is_absolute() else base / file
            try:
                exists = file.exists()
            except (OSError, ValueError):  # a name too long for the file system
                exists = False
            if not exists:
                raise ManifestError(f"{where}: {column} {value!r}: no such file or directory")
            params[column] = str(file)
        job = Job(id=job_id, kind=kind, params=params, row=k)
        try:
            spec.check(job)
        except (ValueError, OSError) as exc:
            raise ManifestError(f"{where}: {exc}") from None
        jobs.append(job)
    return tuple(jobs)


__all__ = ["Job", "ManifestError", "read_manifest"]
