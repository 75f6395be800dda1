"""``bearingflock sweep``: seeds, grids, rows identical whatever the executor, resume, failures,
``--json`` (issue 28). Small sweeps of short runs on the agent cores (no numba compile)."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from groundstation.cli import app
from sim.sweep.driver import auto_batch, run_sweep, tasks_of
from sim.sweep.executors import (
    ExecutorError,
    InlineExecutor,
    open_executor,
    parse_executor,
)
from sim.sweep.results import ResultsDir
from sim.sweep.spec import SpecError, from_cli, from_toml, parse_seeds, run_seed
from sim.sweep.summary import bootstrap_median_ci, quantile, summarize_points

DUR = "0.2"
VOLATILE = ("wall_s", "cpu_s", "worker", "git_commit")


def comparable(rows: list[dict]) -> list[dict]:
    """Rows without what legitimately differs between two executions (timing, worker)."""
    return [{k: v for k, v in r.items() if k not in VOLATILE} for r in rows]


def run(spec, out: Path, executor: str = "local", resume: bool = False, batch=None):
    with open_executor(parse_executor(executor, env={})) as (ex, slots):
        outcome = run_sweep(spec, ResultsDir(out), ex, slots, resume, batch)
    return outcome, ResultsDir(out).read()


# --- seeds and grids ------------------------------------------------------------------------


def test_seed_ranges_are_inclusive_and_lists_are_sorted_unique() -> None:
    assert parse_seeds("0:999") == tuple(range(1000))
    assert parse_seeds("3,7,11") == (3, 7, 11)
    assert parse_seeds("11, 3,3,0:1") == (0, 1, 3, 11)
    assert parse_seeds("5:5") == (5,)


@pytest.mark.parametrize("bad", ["", "5:2", "a", "1:b", "-1", "0:-1", "1,,2"])
def test_bad_seed_lists_are_rejected_clearly(bad: str) -> None:
    with pytest.raises(SpecError):
        parse_seeds(bad)


def test_run_seed_is_the_seed_unless_a_seed_root_derives_it_from_a_seed_sequence() -> None:
    assert [run_seed(s, None) for s in (0, 5, 99)] == [0, 5, 99]
    derived = [run_seed(s, 2024) for s in range(50)]
    assert len(set(derived)) == 50
    assert derived == [run_seed(s, 2024) for s in range(50)]  # no hidden state
    ref = np.random.SeedSequence(2024, spawn_key=(7,)).generate_state(1, dtype=np.uint32)[0]
    assert derived[7] == int(ref)
    assert derived != [run_seed(s, 2025) for s in range(50)]


def test_the_grid_is_the_cartesian_product_of_scenarios_and_axes_in_order() -> None:
    spec = from_cli(
        "scale-active,scale-random",
        "0:2",
        ["loss=0,0.1", "bearing_noise_deg=0,0.5,1"],
        "cores",
        1.0,
    )
    pts = spec.points()
    assert len(pts) == 2 * 2 * 3
    assert [p.scenario for p in pts[:6]] == ["scale-active"] * 6
    assert [p.params_dict for p in pts[:3]] == [
        {"loss": 0.0, "bearing_noise_deg": 0.0},
        {"loss": 0.0, "bearing_noise_deg": 0.5},
        {"loss": 0.0, "bearing_noise_deg": 1.0},
    ]
    assert len(tasks_of(spec)) == 12 * 3
    assert len({p.key for p in pts}) == 12


def test_values_take_their_field_type_so_equal_values_are_one_grid_point() -> None:
    spec = from_cli("scale-active", "0", ["loss=0,0.0", "k_formation=1"], "cores", 1.0)
    (pt,) = spec.points()
    assert pt.params_dict == {"loss": 0.0, "k_formation": 1.0}
    assert isinstance(pt.params_dict["loss"], float)


@pytest.mark.parametrize(
    ("sets", "engine", "scenario", "message"),
    [
        (["no_such_param=1"], "cores", "scale-active", "unknown sweep parameter"),
        (["loss=1.5"], "cores", "scale-active", "loss must be in"),
        (["bearing_noise_deg=-1"], "cores", "scale-active", ">= 0"),
        (["rigidity_eigen=3"], "cores", "scale-active", "rigidity_eigen"),
        (["loss"], "cores", "scale-active", "NAME=V1"),
        ([], "warp", "scale-active", "unknown engine"),
        ([], "cores", "scale-nothing", "unknown scenario"),
    ],
)
def test_bad_sweeps_are_rejected_before_anything_runs(sets, engine, scenario, message) -> None:
    with pytest.raises(SpecError, match=message):
        from_cli(scenario, "0:1", sets, engine, 1.0)


def test_sweep_files_hold_cases_whose_union_is_the_grid(tmp_path: Path) -> None:
    f = tmp_path / "s.toml"
    f.write_text(
        'seeds = "0:4"\nduration = 2.0\n'
        '[[case]]\nscenario = ["scale-active", "scale-random"]\n'
        '[[case]]\nlabel = "noisy"\nscenario = "scale-active"\nloss = [0.1, 0.2]\n'
    )
    spec = from_toml(f)
    assert spec.seeds == tuple(range(5))
    assert [(p.scenario, p.params_dict, p.label) for p in spec.points()] == [
        ("scale-active", {}, ""),
        ("scale-random", {}, ""),
        ("scale-active", {"loss": 0.1}, "noisy"),
        ("scale-active", {"loss": 0.2}, "noisy"),
    ]
    assert from_toml(f, seeds="3").seeds == (3,)
    f.write_text('seeds = "0:1"\nbogus = 1\n[[case]]\nscenario = "scale-active"\n')
    with pytest.raises(SpecError, match="unknown keys"):
        from_toml(f)


@pytest.mark.parametrize("name", ["paper-000.toml", "paper-003.toml"])
def test_shipped_sweep_files_parse(name: str) -> None:
    spec = from_toml(Path(__file__).parents[2] / "sweeps" / name)
    assert len(spec.points()) >= 3
    assert len(spec.seeds) >= 10


def test_executor_names() -> None:
    assert parse_executor("local", env={}).kind == "local"
    assert parse_executor("processes:3", env={}).workers == 3
    assert parse_executor(None, env={}).kind == "processes"
    env = {"DASK_SCHEDULER_ADDRESS": "tcp://10.0.0.1:8786"}
    assert parse_executor(None, env=env).address == "tcp://10.0.0.1:8786"
    assert parse_executor("dask://127.0.0.1:9999", env={}).address == "tcp://127.0.0.1:9999"
    assert parse_executor("dask:2", env={}) == parse_executor("dask:2", env=env)
    for bad in ("processes:0", "processes:x", "dask://nohost", "threads"):
        with pytest.raises(ExecutorError):
            parse_executor(bad, env={})


def test_auto_batch_keeps_several_tasks_per_slot_and_caps_the_size() -> None:
    assert auto_batch(10, 2) == 2
    assert auto_batch(1, 8) == 1
    assert auto_batch(100_000, 2) == 16


# --- statistics -----------------------------------------------------------------------------


def test_quantiles_with_never_converged_runs() -> None:
    x = np.array([1.0, 2.0, 3.0, math.inf])
    assert quantile(x, 0.5) == 2.5
    assert quantile(x, 1.0) == math.inf
    assert quantile(np.array([1.0, math.inf, math.inf]), 0.75) == math.inf
    assert quantile(np.array([1.0, 3.0]), 0.25) == 1.5


def test_bootstrap_ci_brackets_the_median_and_shrinks_with_more_runs() -> None:
    rng = np.random.default_rng(0)
    small, large = rng.normal(5.0, 1.0, 20), rng.normal(5.0, 1.0, 400)
    lo_s, hi_s = bootstrap_median_ci(small, 0)
    lo_l, hi_l = bootstrap_median_ci(large, 0)
    assert lo_s <= np.median(small) <= hi_s
    assert lo_l <= np.median(large) <= hi_l
    assert hi_l - lo_l < 0.5 * (hi_s - lo_s)
    assert (lo_s, hi_s) == bootstrap_median_ci(small, 0)  # deterministic


# --- running sweeps -------------------------------------------------------------------------


def small_spec(seeds: str = "0:2", sets: list[str] | None = None, **kw):
    return from_cli("scale-active", seeds, sets or ["loss=0,0.2"], "cores", float(DUR), **kw)


def test_rows_are_identical_embedded_and_on_two_processes(tmp_path: Path) -> None:
    spec = small_spec()
    _, local = run(spec, tmp_path / "local", "local")
    _, procs = run(spec, tmp_path / "procs", "processes:2", batch=1)
    assert len(local) == 6
    assert {r["status"] for r in local} == {"ok"}
    assert len({r["worker"] for r in procs}) == 2  # both workers ran some
    assert comparable(local) == comparable(procs)
    # and the loss changed something: the grid points are different runs
    assert local[0]["final_chi_error_max"] != local[3]["final_chi_error_max"]


def test_a_row_is_what_bearingflock_scenario_json_prints(tmp_path: Path) -> None:
    spec = from_cli("scale-active", "4", ["bearing_noise_deg=1"], "cores", float(DUR))
    _, (row,) = run(spec, tmp_path / "r")
    res = CliRunner().invoke(
        app,
        [
            "scenario",
            "scale-active",
            "--seed",
            "4",
            "--duration",
            DUR,
            "--json",
            "--bearing-noise-deg",
            "1",
        ],
    )
    assert res.exit_code == 0, res.output
    ref = json.loads(res.stdout.strip().splitlines()[-1])
    metrics = json.loads(row["metrics"])
    assert set(metrics) == set(ref) - {"scenario", "seed", "duration_s", "engine"}
    assert {m: row[m] for m in metrics} == {m: ref[m] for m in metrics}


def test_resume_skips_finished_runs_and_gives_the_rows_of_one_session(tmp_path: Path) -> None:
    out = tmp_path / "r"
    first, rows1 = run(small_spec("0:1"), out)
    assert (first.done, len(rows1)) == (4, 4)
    with pytest.raises(FileExistsError, match="--resume"):
        run(small_spec("0:3"), out)
    second, rows2 = run(small_spec("0:3"), out, resume=True)
    assert (second.done, second.skipped, len(rows2)) == (4, 4, 8)
    _, fresh = run(small_spec("0:3"), tmp_path / "fresh")
    assert comparable(rows2) == comparable(fresh)
    with pytest.raises(ValueError, match="another sweep"):
        run(small_spec("0:3", ["loss=0.5"]), out, resume=True)


def test_a_failed_run_is_recorded_and_the_sweep_goes_on(tmp_path: Path) -> None:
    # camera_rate_hz = 0 passes the grid check (a float) but RunnerConfig refuses it
    spec = small_spec("0:1", ["camera_rate_hz=50,0"])
    outcome, rows = run(spec, tmp_path / "r")
    assert outcome.failed == 2
    assert [r["status"] for r in rows] == ["ok", "ok", "failed", "failed"]
    assert "camera_rate_hz must be positive" in rows[2]["error"]
    assert rows[2]["error"].startswith("ValueError")
    s = summarize_points(rows)
    assert [(p["ok"], p["failed"]) for p in s] == [(2, 0), (0, 2)]
    # a failed run is re-run by --resume (and fails again, recorded once)
    again, rows2 = run(spec, tmp_path / "r", resume=True)
    assert (again.done, again.skipped, len(rows2)) == (2, 2, 4)


def test_a_run_over_its_timeout_is_recorded_as_timeout(tmp_path: Path) -> None:
    spec = from_cli("scale-active", "0", [], "cores", 5.0, timeout_s=0.05)
    outcome, (row,) = run(spec, tmp_path / "r")
    assert outcome.failed == 1
    assert row["status"] == "timeout"
    assert "0.05 s" in row["error"]
    assert row["wall_s"] < 2.0  # stopped early: 5 s of simulation take much longer


def test_inline_executor_runs_in_this_process() -> None:
    ex = InlineExecutor()
    assert ex.submit(sum, [1, 2]).result() == 3
    with pytest.raises(ZeroDivisionError):
        ex.submit(lambda: 1 / 0).result()


# --- the command line -----------------------------------------------------------------------


def test_json_prints_rows_with_seed_params_metrics_and_a_summary(tmp_path: Path) -> None:
    out = tmp_path / "r"
    args = ["sweep", "scale-active", "--seeds", "0:1", "--set", "loss=0,0.2"]
    args += ["--duration", DUR, "--executor", "local", "--out", str(out), "--json"]
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout.strip().splitlines()[-1])
    assert set(doc) == {"rows", "summary"}
    assert len(doc["rows"]) == 4
    r = doc["rows"][2]
    assert (r["seed"], r["params"], r["status"]) == (0, {"loss": 0.2}, "ok")
    for m in ("converged_s", "lambda_bar_mean", "final_localization_error", "final_scale_ratio"):
        assert m in r
    (s0, s1) = doc["summary"]
    assert (s0["params"], s1["params"]) == ({"loss": 0.0}, {"loss": 0.2})
    st = s0["metrics"]["lambda_bar_mean"]
    assert st["ci95"][0] <= st["median"] <= st["ci95"][1]
    assert st["q25"] <= st["median"] <= st["q75"]
    assert 0.0 <= s0["fractions"]["converged"] <= 1.0
    # the table (no --json) reads the same directory
    res = CliRunner().invoke(app, ["sweep", "scale-active", "--seeds", "0:1", "--set", "loss=0,0.2",
                                   "--duration", DUR, "--executor", "local", "--out", str(out),
                                   "--resume"])  # fmt: skip
    assert res.exit_code == 0, res.output
    assert "lambda_bar_mean" in res.stdout and "loss=0.2" in res.stdout


def test_bad_command_lines_are_clear_errors(tmp_path: Path) -> None:
    r = CliRunner()
    res = r.invoke(app, ["sweep", "scale-active", "--seeds", "9:1", "--out", str(tmp_path)])
    assert res.exit_code == 2 and "empty" in res.output
    res = r.invoke(app, ["sweep", "scale-active", "--executor", "threads", "--out", str(tmp_path)])
    assert res.exit_code == 2 and "unknown executor" in res.output
    res = r.invoke(app, ["sweep", "plot", str(tmp_path / "nothing")])
    assert res.exit_code == 2 and "no sweep rows" in res.output


def test_plot_draws_cdf_bands_and_a_heat_map_for_two_parameters(tmp_path: Path) -> None:
    out = tmp_path / "r"
    spec = small_spec("0", ["loss=0,0.2", "bearing_noise_deg=0,1"])
    run(spec, out)
    res = CliRunner().invoke(app, ["sweep", "plot", str(out)])
    assert res.exit_code == 0, res.output
    names = sorted(p.name for p in (out / "plots").iterdir())
    assert "cdf_converged_s.png" in names
    assert "heatmap_lambda_bar_mean.png" in names
    assert "lambda_bar_mean_vs_loss.png" in names
    assert "lambda_bar_mean_vs_bearing_noise_deg.png" in names
    assert all((out / "plots" / n).stat().st_size > 1000 for n in names)


def test_rigidity_rows_are_the_scenario_json_and_agent_gains_reach_the_agents(
    tmp_path: Path,
) -> None:
    spec = from_cli(
        "rigidity-tracking", "1", ["rigidity_eigen=distributed,centralized"], "cores", 0.2
    )
    _, (dist, central) = run(spec, tmp_path / "r")
    res = CliRunner().invoke(
        app, ["scenario", "rigidity-tracking", "--seed", "1", "--duration", "0.2", "--json"]
    )
    assert res.exit_code == 0, res.output
    ref = json.loads(res.stdout.strip().splitlines()[-1])
    metrics = json.loads(dist["metrics"])
    assert set(metrics) == set(ref) - {"scenario", "seed", "duration_s"}
    assert {m: dist[m] for m in metrics} == {m: ref[m] for m in metrics}
    # the centralized eigenpair is another estimate of the same true trajectory's eigenvalue
    assert central["distributed_eigen_error_p95"] != dist["distributed_eigen_error_p95"]
    assert central["params"] == '{"rigidity_eigen": "centralized"}'


def test_compiled_rigidity_rows_are_the_compiled_scenario_json(tmp_path: Path) -> None:
    """A ``rigidity-tracking --engine compiled`` row is ``bearingflock scenario rigidity-tracking
    --engine compiled --json`` (issue 21)."""
    spec = from_cli("rigidity-tracking", "1", [], "compiled", 0.2)
    _, (row,) = run(spec, tmp_path / "r")
    assert row["status"] == "ok", row["error"]
    args = ["scenario", "rigidity-tracking", "--seed", "1", "--duration", "0.2", "--json"]
    res = CliRunner().invoke(app, [*args, "--engine", "compiled"])
    assert res.exit_code == 0, res.output
    ref = json.loads(res.stdout.strip().splitlines()[-1])
    metrics = json.loads(row["metrics"])
    assert set(metrics) == set(ref) - {"scenario", "seed", "duration_s", "engine"}
    assert {m: row[m] for m in metrics} == {m: ref[m] for m in metrics}


def test_a_sweep_file_with_duration_on_the_command_line_and_no_dask_import(
    tmp_path: Path,
) -> None:
    """dask is imported only for the dask executors; --duration overrides a case's duration."""
    f = tmp_path / "s.toml"
    f.write_text('seeds = "0"\n[[case]]\nscenario = "scale-active"\nduration = 30.0\n')
    code = (
        "import sys\n"
        "from typer.testing import CliRunner\n"
        "from groundstation.cli import app\n"
        f"r = CliRunner().invoke(app, ['sweep', {str(f)!r}, '--duration', '0.2', '--executor',"
        f" 'local', '--out', {str(tmp_path / 'r')!r}, '--json'])\n"
        "assert r.exit_code == 0, r.output\n"
        "print(r.stdout.strip().splitlines()[-1])\n"
        "print('distributed' in sys.modules, 'dask' in sys.modules)\n"
    )
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).parents[2])}
    env.pop("DASK_SCHEDULER_ADDRESS", None)
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert res.returncode == 0, res.stderr
    doc_line, imported = res.stdout.strip().splitlines()[-2:]
    assert imported == "False False"
    (summary,) = json.loads(doc_line)["summary"]
    assert summary["duration_s"] == 0.2
