"""``bearingflock sweep`` on a real Dask cluster: a ``dask scheduler`` and two ``dask worker``
processes on loopback (ports chosen by the OS), against the embedded run (issue 28); and a
sweep interrupted with SIGINT keeps its finished rows and resumes."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from sim.sweep.driver import run_sweep
from sim.sweep.executors import open_executor, parse_executor
from sim.sweep.results import ResultsDir
from sim.sweep.spec import from_cli

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(240)]
ROOT = Path(__file__).resolve().parents[2]
VOLATILE = ("wall_s", "cpu_s", "worker", "git_commit")


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    env.pop("DASK_SCHEDULER_ADDRESS", None)
    return env


def _stop(procs: list[subprocess.Popen]) -> None:
    for p in reversed(procs):
        if p.poll() is None:
            p.terminate()
    for p in reversed(procs):
        try:
            p.wait(timeout=15)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


@pytest.fixture
def dask_cluster(tmp_path: Path) -> Iterator[str]:
    """A scheduler and two single-threaded workers as separate processes; yields the
    scheduler's ``tcp://127.0.0.1:PORT``."""
    sched_file = tmp_path / "scheduler.json"
    dask = [sys.executable, "-m", "dask"]
    procs: list[subprocess.Popen] = []
    log = (tmp_path / "dask.log").open("w")
    try:
        procs.append(
            subprocess.Popen(
                [*dask, "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                 "--scheduler-file", str(sched_file)],
                env=_env(), stdout=log, stderr=subprocess.STDOUT, cwd=tmp_path,
            )
        )  # fmt: skip
        t0 = time.monotonic()
        while not sched_file.exists() or not sched_file.read_text().strip():
            assert procs[0].poll() is None, (tmp_path / "dask.log").read_text()
            assert time.monotonic() - t0 < 60, "the dask scheduler did not start"
            time.sleep(0.2)
        time.sleep(0.2)  # the file is written in one go, but give it its closing brace
        address = json.loads(sched_file.read_text())["address"]
        for i in range(2):
            procs.append(
                subprocess.Popen(
                    [*dask, "worker", address, "--nthreads", "1", "--nworkers", "1",
                     "--no-dashboard", "--host", "127.0.0.1", "--name", f"w{i}",
                     "--local-directory", str(tmp_path / f"w{i}")],
                    env=_env(), stdout=log, stderr=subprocess.STDOUT, cwd=tmp_path,
                )
            )  # fmt: skip
        from distributed import Client

        with Client(address, timeout=30) as c:
            c.wait_for_workers(2, timeout=90)
        yield address
    finally:
        _stop(procs)
        log.close()


def _rows(spec, out: Path, executor: str, env: dict[str, str] | None = None) -> list[dict]:
    with open_executor(parse_executor(executor, env={} if env is None else env)) as (ex, n):
        outcome = run_sweep(spec, ResultsDir(out), ex, n, batch_size=1)
    assert outcome.failed == 0
    return ResultsDir(out).read()


def test_rows_on_two_dask_workers_equal_the_embedded_rows(
    dask_cluster: str, tmp_path: Path
) -> None:
    spec = from_cli("scale-active,scale-formation", "0:2", ["loss=0,0.1"], "cores", 0.3)
    embedded = _rows(spec, tmp_path / "embedded", "local")
    host_port = dask_cluster.removeprefix("tcp://")
    on_dask = _rows(spec, tmp_path / "dask", f"dask://{host_port}")
    assert len(embedded) == 12
    workers = {r["worker"] for r in on_dask}
    assert len(workers) == 2, workers  # both worker processes ran batches
    assert os.getpid() not in {int(w.rsplit(":", 1)[1]) for w in workers}
    strip = [{k: v for k, v in r.items() if k not in VOLATILE} for r in embedded]
    assert strip == [{k: v for k, v in r.items() if k not in VOLATILE} for r in on_dask]
    # DASK_SCHEDULER_ADDRESS alone selects the cluster (no --executor)
    via_env = _rows(spec, tmp_path / "env", None, {"DASK_SCHEDULER_ADDRESS": dask_cluster})
    assert {r["worker"] for r in via_env} <= workers


def test_the_command_line_on_the_cluster_prints_the_same_json(
    dask_cluster: str, tmp_path: Path
) -> None:
    args = ["-m", "groundstation.cli", "sweep", "scale-active", "--seeds", "0:1", "--set",
            "bearing_noise_deg=0,1", "--duration", "0.3", "--json"]  # fmt: skip
    docs = []
    for name, extra_env in (("local", {}), ("dask", {"DASK_SCHEDULER_ADDRESS": dask_cluster})):
        env = _env() | extra_env
        ex = ["--executor", "local"] if name == "local" else []
        res = subprocess.run(
            [sys.executable, *args, *ex, "--out", str(tmp_path / name)],
            env=env, capture_output=True, text=True, timeout=120, cwd=tmp_path,
        )  # fmt: skip
        assert res.returncode == 0, res.stderr
        docs.append(json.loads(res.stdout))
    for doc in docs:
        for r in doc["rows"]:
            r.pop("wall_s"), r.pop("cpu_s")
        for s in doc["summary"]:
            s.pop("wall_s_median")
    assert docs[0] == docs[1]
    assert "dask scheduler" in res.stderr


def test_sigint_keeps_finished_rows_and_resume_completes(tmp_path: Path) -> None:
    out = tmp_path / "r"
    args = [sys.executable, "-m", "groundstation.cli", "sweep", "scale-active", "--seeds",
            "0:59", "--duration", "0.3", "--executor", "processes:2", "--batch", "1",
            "--out", str(out), "--json"]  # fmt: skip
    proc = subprocess.Popen(
        args,
        env=_env(),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=tmp_path,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN),  # as a background job
    )
    t0 = time.monotonic()
    while len(list((out / "rows").glob("part-*.parquet"))) < 3 if (out / "rows").exists() else True:
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() - t0 < 120, "no rows written"
        time.sleep(0.1)
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=30)
    assert proc.returncode == 130, stderr
    assert "interrupted" in stderr
    kept = ResultsDir(out).read()
    assert 3 <= len(kept) < 60
    doc = json.loads(stdout)
    assert len(doc["rows"]) == len(kept)
    res = subprocess.run(
        [*args, "--resume"], env=_env(), capture_output=True, text=True, timeout=180, cwd=tmp_path
    )
    assert res.returncode == 0, res.stderr
    rows = ResultsDir(out).read()
    assert [r["seed"] for r in rows] == list(range(60))
    assert {r["status"] for r in rows} == {"ok"}
