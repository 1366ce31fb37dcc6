"""Batch odometry, registration and mapping: many independent jobs on an engine, same results
anywhere.

A manifest (CSV or Parquet, one row per job) names the inputs — file paths or ``sim:`` URIs,
never arrays — and each job runs in a worker exactly as the single-job command would
(``scanreg odometry``, ``scanreg register``, ``scanreg map``: the same library functions,
:mod:`scanreg.pipeline.commands`), writing ``out/<id>/`` atomically. Engines:
``"local"`` (worker processes on this machine, no extra dependency) and ``"ray"`` (a Ray
cluster, ``pip install 'scanreg[ray]'``). The core's results do not depend on the thread
count or on the worker, so every engine gives the same poses to the bit.

>>> from scanreg.batch import run_batch
>>> report = run_batch("odometry", "drives.csv", "out/", engine="local", retries=2)
>>> report.ok, report.as_dict()["failed"]

A job's exception is recorded (status, error, traceback) and the others go on; a job whose
worker died is retried ``retries`` times; ``resume=True`` skips the jobs already done;
``out/summary.csv`` and ``out/summary.parquet`` (with pyarrow, ``scanreg[batch]``) hold one row
per job. A target named by many register rows (a prior map) is read and prepared once per
worker process, never shipped with the tasks. Job kinds: :data:`~scanreg.batch.jobs.JOB_KINDS`.
"""

from .engines import ENGINES, Engine, Outcome, make_engine
from .jobs import JOB_KINDS, JobKind
from .manifest import Job, ManifestError, read_manifest
from .runner import BatchReport, run_batch

__all__ = [
    "ENGINES",
    "JOB_KINDS",
    "BatchReport",
    "Engine",
    "Job",
    "JobKind",
    "ManifestError",
    "Outcome",
    "make_engine",
    "read_manifest",
    "run_batch",
]
