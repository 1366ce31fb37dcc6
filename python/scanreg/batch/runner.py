"""Run a batch: jobs from a manifest, on an engine, into an output folder, with a summary."""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .._progress import Progress
from .engines import Engine, make_engine
from .jobs import JOB_KINDS, Job, clean_temporary, execute, finished_record, record_attempts
from .manifest import read_manifest
from .summary import write_summary_csv, write_summary_parquet


@dataclass(frozen=True)
class BatchReport:
    """What :func:`run_batch` did."""

    kind: str
    engine: str
    output: Path
    #: One record per job, in manifest order (the summary's rows).
    records: tuple[dict[str, Any], ...]
    seconds: float
    #: Jobs run at once and threads each.
    slots: int
    threads_per_job: int
    summary_csv: Path
    summary_parquet: Path | None = field(default=None)

    @property
    def failed(self) -> tuple[dict[str, Any], ...]:
        return tuple(r for r in self.records if r["status"] != "done")

    @property
    def ok(self) -> bool:
        """Every job done."""
        return not self.failed

    def as_dict(self) -> dict[str, Any]:
        """A JSON-ready summary (what ``scanreg batch --json`` prints)."""
        ran = [r for r in self.records if not r.get("resumed")]
        return {
            "kind": self.kind,
            "engine": self.engine,
            "output": str(self.output),
            "jobs": len(self.records),
            "done": sum(r["status"] == "done" for r in self.records),
            "failed": len(self.failed),
            "resumed": len(self.records) - len(ran),
            "retried": sum(r["attempts"] > 1 for r in ran),
            "slots": self.slots,
            "threads_per_job": self.threads_per_job,
            "seconds": self.seconds,
            "jobs_per_second": len(ran) / self.seconds if self.seconds > 0 else None,
            "summary_csv": str(self.summary_csv),
            "summary_parquet": None if self.summary_parquet is None else str(self.summary_parquet),
            "failures": [
                {"id": r["id"], "error": r["error"], "attempts": r["attempts"]} for r in self.failed
            ],
        }


def run_batch(
    kind: str,
    jobs: str | Path | Sequence[Job],
    output: str | Path,
    *,
    engine: str | Engine = "local",
    address: str | None = None,
    workers: int | None = None,
    threads_per_job: int | None = None,
    retries: int = 2,
    resume: bool = False,
    config: str | Path | None = None,
    progress: bool = False,
    job_function: Callable[[Job, Path], Mapping[str, Any]] | None = None,
) -> BatchReport:
    """Run the ``kind`` jobs (``"odometry"``, ``"register"``) of a manifest on an engine.

    Parameters
    ----------
    kind
        A key of :data:`scanreg.batch.jobs.JOB_KINDS`.
    jobs
        A manifest file (CSV, TSV or Parquet; see :mod:`scanreg.batch.manifest`) or jobs
        already read.
    output
        Folder: ``output/<id>/`` per done job (what the single-job command writes there, and
        ``result.json``, ``job.json``), ``summary.csv`` and ``summary.parquet`` (with pyarrow).
    engine
        ``"local"`` (worker processes, the default), ``"ray"`` or an engine object (left open).
    address
        Ray: a running cluster's head (``host:port``) or ``"auto"``; default: start a local one.
    workers
        Local: worker processes (default one per CPU); Ray without ``address``: the local
        cluster's CPUs.
    threads_per_job
        Threads each job's core calls may use (default: CPUs / workers, at least 1; on Ray 1,
        and each task reserves that many CPUs).
    retries
        Times a job whose worker died is run again. A job's own exception is recorded at once.
    resume
        Skip the jobs already done in ``output`` with the same manifest row.
    config
        A TOML config for the rows without one.
    progress
        A progress bar on stderr (done / failed / running, jobs/s).
    job_function
        Run this instead of the kind's own job (``fn(job, folder) -> result``; it must be
        importable by name in the workers, or pickled by value).

    The manifest and the engine are checked before anything is written: a bad row, an unknown
    engine or an unreachable address raises (ValueError / ConnectionError / ImportError naming
    it) and leaves no file behind.
    """
    if kind not in JOB_KINDS:
        raise ValueError(f"kind: unknown job kind {kind!r} (known: {', '.join(JOB_KINDS)})")
    if isinstance(retries, bool) or not isinstance(retries, int) or retries < 0:
        raise ValueError(f"retries: must be an int >= 0, got {retries!r}")
    if isinstance(jobs, (str, Path)):
        job_list = read_manifest(jobs, kind, default_config=config)
    else:
        job_list = tuple(jobs)
        if not all(isinstance(j, Job) for j in job_list):
            raise TypeError("jobs: expected a manifest path or a sequence of Job")
        ids = [j.id for j in job_list]
        if len(set(ids)) != len(ids):
            raise ValueError("jobs: duplicate ids")
    run_fn = JOB_KINDS[kind].run if job_function is None else job_function
    out = Path(output)
    if out.exists() and not out.is_dir():
        raise ValueError(f"output: {out} exists and is not a folder")
    owned = isinstance(engine, str)
    eng: Engine = (
        make_engine(engine, workers=workers, threads_per_job=threads_per_job, address=address)
        if isinstance(engine, str)
        else engine
    )
    t0 = time.perf_counter()
    records: dict[str, dict[str, Any]] = {}
    summary_csv = out / "summary.csv"
    summary_parquet: Path | None = None
    try:
        out.mkdir(parents=True, exist_ok=True)
        clean_temporary(out)
        todo: list[Job] = []
        for job in job_list:
            previous = finished_record(out, job) if resume else None
            if previous is None:
                todo.append(job)
            else:
                records[job.id] = {
                    **previous,
                    "kind": kind,
                    "resumed": True,
                    "attempts": previous.get("attempts", 1),
                    "output": job.id,
                }
        # the rate counts the jobs run here, not those an earlier run did
        bar = Progress(len(todo), description=f"batch {kind}", unit="jobs", enabled=progress)
        bar.set_counters(done=0, failed=0, running=0)
        if records:
            bar.set_counters(resumed=len(records))
        done = failed = running = 0
        calls = [(job, str(out), run_fn, eng.threads_per_job) for job in todo]

        def started(i: int) -> None:
            nonlocal running
            running += 1
            bar.set_counters(running=running)

        for outcome in eng.run(execute, calls, retries=retries, on_start=started):
            job = todo[outcome.index]
            running -= 1
            if outcome.record is None:
                rec: dict[str, Any] = {
                    "id": job.id,
                    "status": "failed",
                    "error": f"{outcome.lost[-1]} on each of {outcome.attempts} attempts",
                    "traceback": "",
                }
            else:
                rec = dict(outcome.record)
            rec.update(
                id=job.id,
                kind=kind,
                attempts=outcome.attempts,
                resumed=False,
                output=job.id if rec["status"] == "done" else "",
            )
            if outcome.lost and rec["status"] == "done":
                rec["error"] = f"retried after: {'; '.join(outcome.lost)}"
            if rec["status"] == "done":
                record_attempts(out, job.id, outcome.attempts)
            failed += rec["status"] != "done"
            done += rec["status"] == "done"
            records[job.id] = rec
            bar.update(done=done, failed=failed, running=running)
        bar.close()
    finally:
        if owned:
            eng.close()
        clean_temporary(out)
        ordered = [records[j.id] for j in job_list if j.id in records]
        if out.is_dir():
            write_summary_csv(summary_csv, ordered)
            summary_parquet = write_summary_parquet(out / "summary.parquet", ordered)
    return BatchReport(
        kind=kind,
        engine=eng.name,
        output=out,
        records=tuple(ordered),
        seconds=time.perf_counter() - t0,
        slots=eng.slots,
        threads_per_job=eng.threads_per_job,
        summary_csv=summary_csv,
        summary_parquet=summary_parquet,
    )


__all__ = ["BatchReport", "run_batch"]
