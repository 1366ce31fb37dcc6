"""The core's thread budget: set once per process, honoured (no extra threads), and results
identical to the bit for any thread count."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import pytest
import scanreg

#: Runs in a fresh interpreter (the pool is sized once per process): sizes the pool, then
#: odometry on a simulated drive, a GICP registration of a cloud large enough to be split
#: across threads, and normals; prints digests of every pose, covariance and normal, and the
#: threads the process gained.
_PROBE = textwrap.dedent(
    """
    import hashlib, json, os, sys
    import numpy as np
    import scanreg
    from scanreg.io import open_sequence

    def threads():
        return len(os.listdir("/proc/self/task"))

    before = threads()
    scanreg.set_num_threads(int(sys.argv[1]))
    digest = hashlib.sha256()
    odo = scanreg.Odometry(scanreg.OdometryConfig())
    for f in open_sequence("sim:street,frames=4"):
        r = odo.step(f.points, f.timestamps, stamp=f.stamp)
        digest.update(r.pose.as_matrix().tobytes() + r.covariance.tobytes())
    rng = np.random.default_rng(0)
    cloud = rng.uniform(-20, 20, (20000, 3)) * [1, 1, 0.1]
    target = scanreg.prepare(cloud, normals=True, covariances=True)
    half = np.ascontiguousarray(cloud[::2])
    moved = scanreg.SE3.from_vector([0.3, -0.2, 0.05, 0.0, 0.01, 0.02]).apply(half)
    res = scanreg.register(moved, target, method="gicp")
    digest.update(res.pose.as_matrix().tobytes() + res.covariance.tobytes())
    digest.update(target.normals.tobytes() + target.covariances.tobytes())
    print(json.dumps({"digest": digest.hexdigest(), "pool": scanreg.get_num_threads(),
                      "gained": threads() - before}))
    """
)


def _probe(num_threads: int) -> dict[str, object]:
    out = subprocess.run(
        [sys.executable, "-c", _PROBE, str(num_threads)],
        capture_output=True,
        text=True,
        check=True,
        timeout=300,
    )
    result: dict[str, object] = json.loads(out.stdout)
    return result


def test_results_are_identical_for_any_thread_count_and_the_budget_holds() -> None:
    one, three = _probe(1), _probe(3)
    assert one["digest"] == three["digest"]
    assert (one["pool"], three["pool"]) == (1, 3)
    # the pool's threads and no others (a 1-CPU worker must not start one per core)
    assert (one["gained"], three["gained"]) == (1, 3)


def test_bad_thread_counts_are_refused() -> None:
    with pytest.raises(ValueError, match="num_threads: must be >= 1, got 0"):
        scanreg.set_num_threads(0)
    with pytest.raises(TypeError, match="num_threads: expected an int, got str"):
        scanreg.set_num_threads("2")  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="num_threads: expected an int, got bool"):
        scanreg.set_num_threads(True)
    # this process's pool exists by now: another size names the one it has
    n = scanreg.get_num_threads()
    scanreg.set_num_threads(n)
    with pytest.raises(RuntimeError, match=f"already runs {n} threads.*RAYON_NUM_THREADS"):
        scanreg.set_num_threads(n + 1)
