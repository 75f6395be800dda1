"""Setpoints files and the ``plan`` command (invoked through a tiny typer app)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from groundstation.plan_cli import plan
from groundstation.planner.setpoints import SetpointsError, parse_setpoints, problem_from_spec

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"

GOOD = """
sigma_m = 0.1
prior_cov = 30.0
r_min = 2.0
r_max = 40.0
[[setpoint]]
p = [0.0, 10.0, -5.0]
[[setpoint]]
p = [10.0, -10.0, -5.0]
[[setpoint]]
p = [-10.0, 0.0, -8.0]
"""

# setpoints at the origin and 4 m along each axis: every point within 6 m of the origin is
# closer than 5 m to one of them
AXES = "sigma_m = 0.1\nprior_cov = 30.0\nr_min = 5.0\nr_max = 6.0\n" + "".join(
    f"[[setpoint]]\np = {list(map(float, p))}\n"
    for p in [(0, 0, 0), (4, 0, 0), (-4, 0, 0), (0, 4, 0), (0, -4, 0), (0, 0, 4), (0, 0, -4)]
)


def _app() -> typer.Typer:
    app = typer.Typer()
    app.command()(plan)

    @app.command()
    def version() -> None:  # a second command so typer keeps "plan" as a subcommand
        typer.echo("0")

    return app


def _run(tmp_path: Path, text: str, *args: str) -> tuple[int, str, str]:
    path = tmp_path / "setpoints.toml"
    path.write_text(text)
    result = CliRunner().invoke(_app(), ["plan", str(path), *args])
    return result.exit_code, result.stdout, result.stderr


def test_parse_good_file_and_matrix_prior() -> None:
    spec = parse_setpoints(GOOD.replace("30.0", "[[30.0, 0, 0], [0, 30.0, 0], [0, 0, 10.0]]"))
    problem = problem_from_spec(spec, 2)
    assert problem.n_setpoints == 3
    np.testing.assert_allclose(problem.prior_cov, np.diag([30.0, 30.0, 10.0]))


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (GOOD.split("[[setpoint]]")[0], "no [[setpoint]]"),
        (
            GOOD.replace("p = [0.0, 10.0, -5.0]", "p = [0.0, nan, -5.0]"),
            "setpoint 0: p must be finite",
        ),
        (GOOD.replace("sigma_m = 0.1", "sigma_m = nan"), "sigma_m must be a finite"),
        (GOOD.replace("r_min = 2.0\n", ""), "missing required field `r_min`"),
        (GOOD.replace("r_max = 40.0", "r_max = [40"), "not valid TOML"),
        (GOOD + "colour = 1\n", "unknown field `colour`"),
        (GOOD.replace("p = [0.0, 10.0, -5.0]", "p = [0.0, 10.0]"), "setpoint[0].p"),
    ],
)
def test_bad_files_name_the_problem(text: str, message: str) -> None:
    with pytest.raises(SetpointsError, match=None) as info:
        parse_setpoints(text, "f.toml")
    assert message in str(info.value)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (GOOD.replace("r_min = 2.0", "r_min = 50.0"), "must be larger than r_min"),
        (AXES, "infeasible"),
        (GOOD.replace("sigma_m = 0.1", "sigma_m = -0.1"), "sigma_m must be positive"),
        (GOOD.replace("prior_cov = 30.0", "prior_cov = -1.0"), "positive definite"),
    ],
)
def test_bad_geometry_names_the_problem(text: str, message: str) -> None:
    with pytest.raises(SetpointsError) as info:
        problem_from_spec(parse_setpoints(text, "f.toml"), 2, source="f.toml")
    assert message in str(info.value)


def test_cli_json_has_the_documented_keys(tmp_path: Path) -> None:
    code, out, _ = _run(tmp_path, GOOD, "-m", "2", "--json", "--starts", "2", "--seed", "4")
    assert code == 0
    data = json.loads(out)
    for key in ("method", "objective", "landmarks", "setpoint_traces", "seconds"):
        assert key in data
    assert data["method"] == "ipopt"
    assert np.asarray(data["landmarks"]).shape == (2, 3)
    assert len(data["setpoint_traces"]) == 3
    assert data["objective"] == pytest.approx(max(data["setpoint_traces"]))


def test_cli_compile_caches_the_derivatives(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("BEARINGFLOCK_CACHE_DIR", str(tmp_path / "cache"))
    args = ("-m", "2", "--json", "--starts", "2", "--seed", "4")
    _, plain, _ = _run(tmp_path, GOOD, *args)
    code, out, _ = _run(tmp_path, GOOD, *args, "--compile")
    assert code == 0
    assert json.loads(out)["objective"] == pytest.approx(json.loads(plain)["objective"], rel=1e-9)
    assert json.loads(out)["details"]["build_seconds"] > 0.0
    assert len(list((tmp_path / "cache" / "planner").glob("planner_*.so"))) == 3


def test_cli_greedy_table_and_plot(tmp_path: Path) -> None:
    figure = tmp_path / "placement.png"
    code, out, _ = _run(tmp_path, GOOD, "-m", "2", "--method", "greedy", "--plot", str(figure))
    assert code == 0
    assert "objective (worst trace)" in out and "1-sigma radius" in out
    assert figure.stat().st_size > 10_000


@pytest.mark.parametrize(
    ("text", "args"),
    [
        (GOOD.split("[[setpoint]]")[0], ["-m", "2"]),
        (GOOD.replace("r_max = 40.0", "r_max = [40"), ["-m", "2"]),
        (GOOD.replace("p = [0.0, 10.0, -5.0]", "p = [0.0, nan, -5.0]"), ["-m", "2"]),
        (GOOD.replace("r_min = 2.0", "r_min = 50.0"), ["-m", "2"]),
        (GOOD, ["-m", "0"]),
        (GOOD, ["-m", "2", "--method", "greedy", "--fov", "90"]),
        (GOOD, ["-m", "2", "--fov", "270"]),
        (GOOD, ["-m", "2", "--method", "greedy", "--compile"]),
    ],
)
def test_cli_bad_input_exits_2_with_one_line(tmp_path: Path, text: str, args: list[str]) -> None:
    code, out, err = _run(tmp_path, text, *args)
    assert code == 2
    assert out == ""
    assert err.startswith("error:") and err.count("\n") == 1


def test_cli_error_keeps_brackets_in_paths(tmp_path: Path) -> None:
    """Errors are printed with rich: a path like ``[run1]/x.toml`` must not lose its tag-like
    part."""
    missing = tmp_path / "[run1]" / "nope.toml"
    result = CliRunner().invoke(_app(), ["plan", str(missing), "-m", "2"])
    assert result.exit_code == 2
    assert "[run1]" in result.stderr


def test_cli_missing_file_exits_2(tmp_path: Path) -> None:
    result = CliRunner().invoke(_app(), ["plan", str(tmp_path / "nope.toml"), "-m", "2"])
    assert result.exit_code == 2
    assert "cannot read" in result.stderr


def test_example_files_parse() -> None:
    for path in sorted(EXAMPLES.glob("setpoints_*.toml")):
        spec = parse_setpoints(path.read_bytes(), str(path))
        fov = 90.0 if "fov" in path.name else None
        assert problem_from_spec(spec, 3, fov).n_setpoints == len(spec.setpoint)
