"""Job functions for the batch tests: the odometry job, with one job that raises and one whose
worker dies on its first attempt. Workers import this module by name (the local engine's spawned
workers inherit sys.path; Ray's get it pickled by value)."""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

from scanreg.batch.jobs import Job, run_odometry_job

#: The job that raises, and the one whose worker dies (``os._exit``) on its first attempt.
RAISES, DIES_ONCE = "job-03", "job-05"


def flaky_odometry(job: Job, folder: Path) -> dict[str, Any]:
    if job.id == RAISES:
        raise RuntimeError(f"{job.id}: simulated failure")
    if job.id == DIES_ONCE:
        # next to the batch's output folder: survives the worker, read by the retry
        marker = Path(folder).parent.parent / f"{job.id}.died"
        if not marker.exists():
            marker.touch()
            os._exit(17)
    _note_ray_node(job, Path(folder))
    return run_odometry_job(job, folder)


def _note_ray_node(job: Job, folder: Path) -> None:
    """On Ray, which node ran the job (``<batch output>/../nodes/<id>``): the two-node test
    checks both nodes worked."""
    try:
        import ray
    except ImportError:
        return
    if ray.is_initialized():
        nodes = folder.parent.parent / "nodes"
        nodes.mkdir(exist_ok=True)
        (nodes / job.id).write_text(ray.get_runtime_context().get_node_id())
        # Hold the slot a moment: jobs this short could otherwise all run one after another
        # on the node that leased first, before the other's lease arrives (seen under load).
        time.sleep(0.5)


def ray_node_after(seconds: float) -> str:
    """The Ray node this runs on, after holding its CPU for ``seconds``: two at once on a
    cluster of two 1-CPU nodes must run on both."""
    import ray

    time.sleep(seconds)
    return str(ray.get_runtime_context().get_node_id())


def thread_census(job: Job, folder: Path) -> dict[str, Any]:
    """The odometry job, then how many threads its worker process runs."""
    result = run_odometry_job(job, folder)
    return {**result, "process_threads": len(os.listdir("/proc/self/task"))}


def simulated_manifest(path: Path, count: int = 20, frames: int = 2) -> Path:
    """A manifest of ``count`` tiny simulated drives (different seeds)."""
    rows = ["id,input"] + [
        f'job-{k:02d},"sim:street,frames={frames},seed={k}"' for k in range(count)
    ]
    path.write_text("\n".join(rows) + "\n")
    return path
