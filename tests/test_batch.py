"""scanreg.batch on the local engine: outputs equal the single-job commands', failures recorded,
dead workers retried, --resume, bad manifests refused before anything is written."""

from __future__ import annotations

import csv
import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from batch_jobs import DIES_ONCE, RAISES, flaky_odometry, simulated_manifest, thread_census
from scanreg import cli, io
from scanreg.batch import ManifestError, make_engine, read_manifest, run_batch
from scanreg.batch.jobs import run_odometry_job
from scanreg.batch.summary import COLUMNS, read_summary_csv


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def test_odometry_jobs_write_what_the_single_command_writes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cfg = _write(tmp_path / "pp.toml", 'method = "point_to_plane"\n')
    manifest = _write(
        tmp_path / "jobs.csv",
        'id,input,config\nstreet,"sim:street,frames=3,seed=2",\n'
        'tunnel,"sim:tunnel,frames=3",pp.toml\n',
    )
    report = run_batch("odometry", manifest, tmp_path / "out", workers=2, retries=0)
    assert report.ok and [r["id"] for r in report.records] == ["street", "tunnel"]
    assert all(r["attempts"] == 1 and r["threads"] == 1 for r in report.records)
    for job_id, spec, extra in (
        ("street", "sim:street,frames=3,seed=2", []),
        ("tunnel", "sim:tunnel,frames=3", ["--config", str(cfg)]),
    ):
        single = tmp_path / f"single-{job_id}"
        args = [spec, "-o", str(single), "--no-plots", "--quiet", "--json", *extra]
        assert cli.main(["odometry", *args]) == cli.EXIT_OK
        printed = json.loads(capsys.readouterr().out)
        job_dir = tmp_path / "out" / job_id
        for name in ("poses_kitti.txt", "poses_tum.txt", "config.toml"):
            assert (job_dir / name).read_bytes() == (single / name).read_bytes(), name
        a, b = (io.read_jsonl(d / "quality.jsonl") for d in (job_dir, single))
        # Everything but the wall times (time_ms and the per-stage time_<stage>_ms).
        untimed = [
            [{k: v for k, v in r.items() if not k.startswith("time_")} for r in x] for x in (a, b)
        ]
        assert untimed[0] == untimed[1]
        written = json.loads((job_dir / "result.json").read_text())
        assert written["accuracy"] == printed["accuracy"]
        assert written["outputs"]["poses_tum"] == "poses_tum.txt"
    rows = read_summary_csv(tmp_path / "out" / "summary.csv")
    assert list(rows[0]) == list(COLUMNS)
    assert [(r["id"], r["status"], r["attempts"]) for r in rows] == [
        ("street", "done", "1"),
        ("tunnel", "done", "1"),
    ]
    assert not list((tmp_path / "out").glob(".tmp-*"))


def test_failure_is_recorded_dead_worker_retried_and_resume_skips(tmp_path: Path) -> None:
    manifest = simulated_manifest(tmp_path / "jobs.csv", count=6, frames=2)
    out = tmp_path / "out"
    report = run_batch("odometry", manifest, out, workers=2, retries=1, job_function=flaky_odometry)
    by_id = {r["id"]: r for r in report.records}
    assert len(by_id) == 6 and not report.ok
    assert [r["id"] for r in report.failed] == [RAISES]
    failed = by_id[RAISES]
    assert failed["error"] == f"RuntimeError: {RAISES}: simulated failure"
    assert "raise RuntimeError" in failed["traceback"] and failed["attempts"] == 1
    assert not (out / RAISES).exists()  # no partial output of a failed job
    retried = by_id[DIES_ONCE]
    assert retried["status"] == "done" and retried["attempts"] == 2
    assert "worker died (exit code 17)" in retried["error"]
    assert sum(r["attempts"] for r in report.records) == 7
    assert not list(out.glob(".tmp-*"))  # the dead worker's half-written folder is gone

    # the retried job's poses are those of a clean run in this process
    (job,) = [j for j in read_manifest(manifest, "odometry") if j.id == DIES_ONCE]
    run_odometry_job(job, tmp_path / "clean")
    clean = (tmp_path / "clean" / "poses_tum.txt").read_bytes()
    assert (out / DIES_ONCE / "poses_tum.txt").read_bytes() == clean

    # --resume runs only the failed job (now with the real job function: it succeeds)
    stamp = (out / "job-00" / "job.json").stat().st_mtime_ns
    again = run_batch("odometry", manifest, out, workers=2, retries=0, resume=True)
    assert again.ok
    resumed = {r["id"]: r["resumed"] for r in again.records}
    assert [k for k, v in resumed.items() if not v] == [RAISES]
    assert (out / "job-00" / "job.json").stat().st_mtime_ns == stamp
    assert {r["id"]: r["attempts"] for r in again.records}[DIES_ONCE] == 2


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="counts threads in /proc")
def test_a_one_thread_worker_runs_no_other_thread(tmp_path: Path) -> None:
    manifest = simulated_manifest(tmp_path / "jobs.csv", count=1)
    report = run_batch(
        "odometry", manifest, tmp_path / "out", workers=2, job_function=thread_census
    )
    assert report.ok and report.threads_per_job == 1
    result = json.loads((tmp_path / "out" / "job-00" / "result.json").read_text())
    # the worker's main thread and the core's pool of one; no BLAS threads
    assert result["process_threads"] == 2


def test_an_engine_serves_several_batches(tmp_path: Path) -> None:
    manifest = simulated_manifest(tmp_path / "jobs.csv", count=2)
    engine = make_engine("local", workers=2)
    try:
        first = run_batch("odometry", manifest, tmp_path / "a", engine=engine)
        second = run_batch("odometry", manifest, tmp_path / "b", engine=engine)
    finally:
        engine.close()
    assert first.ok and second.ok
    # the same (at most two) worker processes ran both batches
    assert len({r["worker"] for r in (*first.records, *second.records)}) <= 2
    for job_id in ("job-00", "job-01"):
        a = (tmp_path / "a" / job_id / "poses_tum.txt").read_bytes()
        assert a == (tmp_path / "b" / job_id / "poses_tum.txt").read_bytes()


def test_a_worker_dying_every_time_is_reported_after_its_retries(tmp_path: Path) -> None:
    manifest = _write(tmp_path / "jobs.csv", f'id,input\n{DIES_ONCE},"sim:street,frames=2"\n')
    (tmp_path / f"{DIES_ONCE}.died").unlink(missing_ok=True)
    # retries=0: the first (dying) attempt is the only one
    report = run_batch(
        "odometry", manifest, tmp_path / "out", workers=1, retries=0, job_function=flaky_odometry
    )
    (rec,) = report.records
    assert rec["status"] == "failed" and rec["attempts"] == 1
    assert rec["error"] == "worker died (exit code 17) on each of 1 attempts"
    assert not (tmp_path / "out" / DIES_ONCE).exists()


def test_register_jobs_share_one_prepared_target_and_match_the_cli(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    from scanreg import SE3

    rng = np.random.default_rng(4)
    target = rng.uniform(-5, 5, (1500, 3)) * [1, 1, 0.3]
    io.write_points(tmp_path / "map.ply", io.PointCloud(points=target))
    rows = ["id,source,target,init"]
    np.savetxt(tmp_path / "init.txt", np.eye(4))
    for k in range(3):
        T = SE3.from_vector([0.1 * k, -0.05, 0.02, 0.0, 0.0, 0.01 * k])
        part = np.ascontiguousarray(target[k % 2 :: 2])  # every other point of the map
        src = T.inverse().apply(part) + rng.normal(0, 0.005, part.shape)
        io.write_points(tmp_path / f"scan{k}.pcd", io.PointCloud(points=src))
        rows.append(f"pair{k},scan{k}.pcd,map.ply,{'init.txt' if k == 1 else ''}")
    manifest = _write(tmp_path / "pairs.csv", "\n".join(rows) + "\n")
    cfg = _write(tmp_path / "reg.toml", 'method = "gicp"\nmax_correspondence_distance = 0.5\n')
    report = run_batch("register", manifest, tmp_path / "out", workers=1, config=cfg)
    assert report.ok
    for k in range(3):
        argv = ["register", str(tmp_path / f"scan{k}.pcd"), str(tmp_path / "map.ply")]
        argv += ["--method", "gicp", "--max-correspondence-distance", "0.5", "--json"]
        assert cli.main(argv) == cli.EXIT_OK
        single = json.loads(capsys.readouterr().out)
        batch = json.loads((tmp_path / "out" / f"pair{k}" / "result.json").read_text())
        assert batch["pose"] == single["pose"]  # to the bit
        assert batch["covariance"] == single["covariance"]
        truth = SE3.from_vector([0.1 * k, -0.05, 0.02, 0.0, 0.0, 0.01 * k]).as_matrix()
        np.testing.assert_allclose(batch["pose"], truth, atol=0.01)
    # In one worker, three rows naming map.ply read it once (here: this process).
    from scanreg.batch import jobs

    reads: list[str] = []
    real_read = io.read_points

    def counting_read(path: object, *args: object, **kwargs: object) -> io.PointCloud:
        reads.append(Path(str(path)).name)
        return real_read(path, *args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(io, "read_points", counting_read)
    jobs._TARGETS.clear()
    for job in read_manifest(manifest, "register", default_config=cfg):
        result = jobs.run_register_job(job, tmp_path / "again" / job.id)
        batch = json.loads((tmp_path / "out" / job.id / "result.json").read_text())
        assert result["pose"] == batch["pose"]
    jobs._TARGETS.clear()
    assert sorted(reads) == ["map.ply", "scan0.pcd", "scan1.pcd", "scan2.pcd"]


# ----------------------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("id,input\na,missing_folder\n", "row 1 (id 'a'): input 'missing_folder': no such file"),
        ('id,input\na,"sim:street",extra\n', "row 1: 3 fields, the header has 2"),
        ("id,input,config\na\n", "row 1: 1 fields, the header has 3"),
        ("id,source\na,x\n", "missing column(s) input"),
        ("id,input,speed\na,sim:street,3\n", "unknown column(s) speed"),
        ('id,input\na,"sim:street"\na,"sim:tunnel"\n', "row 2 (id 'a'): duplicate id (also row 1)"),
        ('id,input\n../x,"sim:street"\n', "row 1: id '../x' cannot name a folder"),
        ('id,input\na,"sim:moon"\n', "row 1 (id 'a'): 'sim:moon': unknown scene"),
        ("id,input\n", "no jobs"),
        ('id,input,config\na,"sim:street",bad.toml\n', "row 1 (id 'a'): config 'bad.toml'"),
    ],
)
def test_bad_manifest_names_the_row_and_writes_nothing(
    tmp_path: Path, text: str, message: str
) -> None:
    manifest = _write(tmp_path / "jobs.csv", text)
    out = tmp_path / "out"
    with pytest.raises(ManifestError, match=r".*".join(map(_escape, message.split(" ")))):
        run_batch("odometry", manifest, out)
    assert not out.exists()
    assert cli.main(["batch", "odometry", str(manifest), "-o", str(out)]) == cli.EXIT_BAD_INPUT
    assert not out.exists()


def _escape(text: str) -> str:
    import re

    return re.escape(text)


def test_bad_config_in_a_row_is_refused_up_front(tmp_path: Path) -> None:
    _write(tmp_path / "typo.toml", 'methd = "gicp"\n')
    manifest = _write(tmp_path / "jobs.csv", 'id,input,config\na,"sim:street",typo.toml\n')
    with pytest.raises(ManifestError, match=r"row 1 \(id 'a'\):.*methd"):
        read_manifest(manifest, "odometry")
    _write(tmp_path / "reg.toml", "max_iterations = 2.5\n")
    _write(tmp_path / "p.csv", "id,source,target,config\np,typo.toml,typo.toml,reg.toml\n")
    with pytest.raises(ManifestError, match=r"row 1 \(id 'p'\):.*max_iterations must be int"):
        read_manifest(tmp_path / "p.csv", "register")


def test_unknown_engine_and_unreachable_address_name_the_setting(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    manifest = simulated_manifest(tmp_path / "jobs.csv", count=1)
    out = tmp_path / "out"
    with pytest.raises(ValueError, match="engine: unknown 'dask' \\(known: local, ray\\)"):
        run_batch("odometry", manifest, out, engine="dask")
    with pytest.raises(ValueError, match="address: only the ray engine"):
        run_batch("odometry", manifest, out, address="127.0.0.1:6379")
    with pytest.raises(ValueError, match="retries: must be an int >= 0"):
        run_batch("odometry", manifest, out, retries=-1)
    assert not out.exists()
    if os.environ.get("CI", "").lower() != "true":
        pytest.importorskip("ray", reason="ray not installed (pip install 'scanreg[ray]')")
    with pytest.raises(ConnectionError, match=r"address 127\.0\.0\.1:9: no Ray cluster answers"):
        run_batch("odometry", manifest, out, engine="ray", address="127.0.0.1:9")
    argv = ["batch", "odometry", str(manifest), "-o", str(out), "--engine", "ray"]
    assert cli.main([*argv, "--address", "127.0.0.1:9"]) == cli.EXIT_BAD_INPUT
    assert "address 127.0.0.1:9" in capsys.readouterr().err
    assert not out.exists()


def test_parquet_manifest_and_summary(tmp_path: Path) -> None:
    pa = pytest.importorskip("pyarrow", reason="pyarrow not installed (scanreg[batch])")
    import pyarrow.parquet as pq

    table = pa.table({"id": ["p0", "p1"], "input": ["sim:street,frames=2", "sim:tunnel,frames=2"]})
    pq.write_table(table, tmp_path / "jobs.parquet")
    report = run_batch("odometry", tmp_path / "jobs.parquet", tmp_path / "out", workers=1)
    assert report.ok and report.summary_parquet is not None
    summary = pq.read_table(report.summary_parquet).to_pylist()
    assert [(r["id"], r["status"], r["attempts"]) for r in summary] == [
        ("p0", "done", 1),
        ("p1", "done", 1),
    ]
    with open(tmp_path / "out" / "summary.csv", newline="") as fh:
        assert [r["id"] for r in csv.DictReader(fh)] == ["p0", "p1"]


def test_cli_exit_code_says_whether_a_job_failed(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = tmp_path / "broken"
    folder.mkdir()
    (folder / "000000.pcd").write_text("not a pcd file\n")
    manifest = _write(tmp_path / "jobs.csv", 'id,input\nok,"sim:street,frames=2"\nbad,broken\n')
    argv = ["batch", "odometry", str(manifest), "-o", str(tmp_path / "out"), "--json"]
    assert cli.main([*argv, "--workers", "1"]) == cli.EXIT_CHECK_FAILED
    out = json.loads(capsys.readouterr().out)
    assert (out["done"], out["failed"]) == (1, 1)
    assert out["failures"][0]["id"] == "bad" and "000000.pcd" in out["failures"][0]["error"]
    shutil.rmtree(tmp_path / "out" / "ok")
    assert cli.main([*argv, "--resume"]) == cli.EXIT_CHECK_FAILED  # still broken
    capsys.readouterr()
