"""scanreg.batch on Ray: a local cluster (``ray.init(num_cpus=2)``) and a two-node cluster on
this machine (``ray start --head`` plus ``ray start --address``, each node on its own loopback
address and ports), 20 tiny simulated drives each: one job raises, one job's worker dies on its
first attempt. 19 done, 1 failed with its error, the killed job retried, every pose equal to the
local engine's to the bit.

Skipped when ray is not installed (``pip install 'scanreg[ray]'``), except under CI=true.
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import batch_jobs
import pytest
from batch_jobs import DIES_ONCE, RAISES, flaky_odometry, simulated_manifest
from scanreg.batch import BatchReport, run_batch
from scanreg.batch.summary import read_summary_csv

if os.environ.get("CI", "").lower() != "true":
    pytest.importorskip("ray", reason="ray not installed (pip install 'scanreg[ray]')")
import ray

JOBS = 20


@pytest.fixture(scope="module")
def manifest(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return simulated_manifest(tmp_path_factory.mktemp("manifest") / "jobs.csv", count=JOBS)


@pytest.fixture(scope="module")
def local_poses(manifest: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, bytes]:
    """The reference: every job on the local engine (no failure injected)."""
    out = tmp_path_factory.mktemp("local") / "out"
    report = run_batch("odometry", manifest, out, workers=2, retries=0)
    assert report.ok
    return {r["id"]: (out / r["id"] / "poses_tum.txt").read_bytes() for r in report.records}


@pytest.fixture(autouse=True)
def _pickle_job_functions_by_value() -> None:
    # Ray's workers do not have tests/ on their path: ship the test's job function itself
    ray.cloudpickle.register_pickle_by_value(batch_jobs)


def check_report(report: BatchReport, local_poses: dict[str, bytes]) -> None:
    records = {r["id"]: r for r in report.records}
    assert len(records) == JOBS
    failures = {r["id"]: r["error"] for r in report.failed}
    assert list(failures) == [RAISES], failures
    assert records[RAISES]["error"] == f"RuntimeError: {RAISES}: simulated failure"
    assert "raise RuntimeError" in records[RAISES]["traceback"]
    assert not (report.output / RAISES).exists()
    retried = records[DIES_ONCE]
    assert retried["status"] == "done" and retried["attempts"] == 2
    assert "WorkerCrashedError" in retried["error"]
    assert all(r["attempts"] == 1 for k, r in records.items() if k != DIES_ONCE)
    assert all(r["threads"] == 1 for r in report.records)
    for job_id, poses in local_poses.items():
        if job_id != RAISES:
            assert (report.output / job_id / "poses_tum.txt").read_bytes() == poses, job_id
    summary = read_summary_csv(report.output / "summary.csv")
    assert [r["id"] for r in summary] == sorted(local_poses)
    assert not list(report.output.glob(".tmp-*"))


def test_local_ray_cluster(manifest: Path, local_poses: dict[str, bytes], tmp_path: Path) -> None:
    assert not ray.is_initialized()
    report = run_batch(
        "odometry",
        manifest,
        tmp_path / "out",
        engine="ray",
        workers=2,  # ray.init(num_cpus=2)
        retries=1,
        job_function=flaky_odometry,
    )
    assert not ray.is_initialized()  # the engine stopped the cluster it started
    assert report.engine == "ray" and report.slots == 2
    check_report(report, local_poses)


def _free_ports(count: int) -> list[int]:
    socks = [socket.socket() for _ in range(count)]
    try:
        for s in socks:
            s.bind(("127.0.0.1", 0))
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()


def _node_ports(ports: list[int]) -> list[str]:
    names = (
        "--node-manager-port",
        "--object-manager-port",
        "--dashboard-agent-grpc-port",
        "--dashboard-agent-listen-port",
        "--runtime-env-agent-port",
        "--metrics-export-port",
    )
    flags = [x for name, port in zip(names, ports, strict=True) for x in (name, str(port))]
    return flags


def _stop(proc: subprocess.Popen[bytes]) -> None:
    """End a node: its `ray start --block` and everything it started (its own session)."""
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGTERM)
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(timeout=3)
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGKILL)  # the node's raylet, GCS and workers
    proc.wait()


@pytest.fixture
def two_node_cluster(tmp_path: Path) -> Iterator[str]:
    """A head on 127.0.0.2 and a second node on 127.0.0.3 (1 CPU each, all ports explicit so
    they cannot collide); yields the head's address; always torn down."""
    ray_cli = str(Path(sys.executable).with_name("ray"))
    ports = _free_ports(13)
    head_port = ports[0]
    address = f"127.0.0.2:{head_port}"
    env = {**os.environ, "RAY_AUTH_MODE": "disabled", "RAY_USAGE_STATS_ENABLED": "0"}
    common = ["--num-cpus", "1", "--disable-usage-stats", "--block"]
    nodes: list[subprocess.Popen[bytes]] = []
    logs = [open(tmp_path / name, "wb") for name in ("head.log", "node.log")]  # noqa: SIM115
    temp = Path("/tmp") / f"scanreg-ray-{os.getpid()}"  # short: Ray's socket paths
    try:
        head = [ray_cli, "start", "--head", "--node-ip-address", "127.0.0.2"]
        head += ["--port", str(head_port), "--include-dashboard", "false"]
        head += ["--temp-dir", str(temp), *_node_ports(ports[1:7]), *common]
        nodes.append(
            subprocess.Popen(
                head,
                env=env,
                start_new_session=True,
                stdout=logs[0],
                stderr=subprocess.STDOUT,
            )
        )
        deadline = time.monotonic() + 60
        while True:
            try:
                socket.create_connection(("127.0.0.2", head_port), timeout=0.5).close()
                break
            except OSError:
                if time.monotonic() > deadline or nodes[0].poll() is not None:
                    raise RuntimeError((tmp_path / "head.log").read_text()[-2000:]) from None
                time.sleep(0.2)
        second = [ray_cli, "start", "--address", address, "--node-ip-address", "127.0.0.3"]
        second += [*_node_ports(ports[7:13]), *common]
        nodes.append(
            subprocess.Popen(
                second,
                env=env,
                start_new_session=True,
                stdout=logs[1],
                stderr=subprocess.STDOUT,
            )
        )
        os.environ["RAY_AUTH_MODE"] = "disabled"
        yield address
    finally:
        os.environ.pop("RAY_AUTH_MODE", None)
        if ray.is_initialized():
            ray.shutdown()
        for proc in reversed(nodes):
            _stop(proc)
        for log in logs:
            log.close()
        subprocess.run(["rm", "-rf", str(temp)], check=False)


def test_two_node_cluster(
    two_node_cluster: str, manifest: Path, local_poses: dict[str, bytes], tmp_path: Path
) -> None:
    # the second node joins within seconds of the head: wait for it before counting slots
    ray.init(address=two_node_cluster, log_to_driver=False, _node_ip_address="127.0.0.2")
    deadline = time.monotonic() + 60
    while sum(n["Alive"] for n in ray.nodes()) < 2:
        assert time.monotonic() < deadline, "the second node did not join"
        time.sleep(0.2)
    # ...and until it takes work: alive is not yet schedulable (under load, tiny jobs could all
    # finish on the head before the head's scheduler sees the second node's CPU)
    probe = ray.remote(num_cpus=1)(batch_jobs.ray_node_after)
    while len(set(ray.get([probe.remote(0.5), probe.remote(0.5)]))) < 2:
        assert time.monotonic() < deadline, "the second node took no work"
    ray.shutdown()
    report = run_batch(
        "odometry",
        manifest,
        tmp_path / "out",
        engine="ray",
        address=two_node_cluster,
        retries=1,
        job_function=flaky_odometry,
    )
    assert report.slots == 2
    check_report(report, local_poses)
    ran_on = {p.read_text() for p in (tmp_path / "nodes").iterdir()}
    assert len(ran_on) == 2  # both nodes worked
