"""The batch summary: one row per job, as ``summary.csv`` and (with pyarrow) ``summary.parquet``.

Both are written to a temporary name and renamed into place, so a reader never sees half a
table.
"""

from __future__ import annotations

import csv
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

#: Columns of the summary, in order, with their Parquet types.
COLUMNS: dict[str, str] = {
    "id": "string",
    "kind": "string",
    "status": "string",  # done | failed
    "error": "string",
    "attempts": "int64",
    "resumed": "bool_",  # done by an earlier run (--resume), not run again
    "seconds": "float64",  # inside the job (reading, computing, writing)
    "started": "float64",  # Unix time
    "finished": "float64",
    "worker": "string",  # host:pid of the last attempt
    "threads": "int64",  # the thread pool the job ran on
    "output": "string",  # the job's folder (relative to the batch output), empty if failed
    "traceback": "string",
}


def summary_rows(records: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Records as summary rows: every column present, missing values None."""
    return [{c: rec.get(c) for c in COLUMNS} for rec in records]


def _replace_atomically(path: Path, write: Any) -> Path:
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        write(tmp)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


def write_summary_csv(path: str | Path, records: Sequence[Mapping[str, Any]]) -> Path:
    def write(tmp: Path) -> None:
        with open(tmp, "w", newline="", encoding="utf-8") as fh:
            writer = csv.DictWriter(fh, fieldnames=list(COLUMNS))
            writer.writeheader()
            for row in summary_rows(records):
                writer.writerow({k: "" if v is None else v for k, v in row.items()})

    return _replace_atomically(Path(path), write)


def write_summary_parquet(path: str | Path, records: Sequence[Mapping[str, Any]]) -> Path | None:
    """The Parquet summary, or None without pyarrow (``pip install 'scanreg[batch]'``)."""
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return None
    rows = summary_rows(records)
    schema = pa.schema([(c, getattr(pa, t)()) for c, t in COLUMNS.items()])
    table = pa.Table.from_pylist(rows, schema=schema)
    return _replace_atomically(Path(path), lambda tmp: pq.write_table(table, tmp))


def read_summary_csv(path: str | Path) -> list[dict[str, str]]:
    """``summary.csv`` as a list of dicts (values as text)."""
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


__all__ = [
    "COLUMNS",
    "read_summary_csv",
    "summary_rows",
    "write_summary_csv",
    "write_summary_parquet",
]
