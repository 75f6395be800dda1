"""IPOPT with its derivatives compiled to C: same answers, a cache, and clear failures."""

from __future__ import annotations

import math
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from groundstation.planner.compiled import compile_functions
from groundstation.planner.ipopt import IpoptPlacer
from groundstation.planner.problem import PlacementProblem, PlannerError, make_problem


def _problem(fov_deg: float | None = None) -> PlacementProblem:
    x = np.array([[-10.0, 0.0, -5.0], [10.0, 0.0, -5.0], [0.0, 10.0, -5.0]])
    return make_problem(x, 2, 0.1, 30.0, 2.0, 40.0, fov_deg=fov_deg)


@pytest.mark.parametrize("fov_deg", [None, 90.0])
def test_compiled_solver_gives_the_interpreted_result(
    tmp_path: Path, fov_deg: float | None
) -> None:
    problem = _problem(fov_deg)
    ref = IpoptPlacer().solve(problem, seed=4, starts=2)
    placer = IpoptPlacer(compiled=True, cache_dir=tmp_path)
    got = placer.solve(problem, seed=4, starts=2)
    assert got.objective == pytest.approx(ref.objective, rel=1e-9)
    np.testing.assert_allclose(got.landmarks_ned, ref.landmarks_ned, atol=1e-6)
    assert got.details["iterations"] == ref.details["iterations"]
    assert len(list(tmp_path.glob("planner_*.so"))) == 3  # gradient, Jacobian, Hessian


def test_compiled_libraries_are_cached(tmp_path: Path) -> None:
    IpoptPlacer(compiled=True, cache_dir=tmp_path).prepare(_problem())
    built = {p: p.stat().st_mtime_ns for p in tmp_path.glob("planner_*.so")}
    assert len(built) == 3
    IpoptPlacer(compiled=True, cache_dir=tmp_path).prepare(_problem())  # same shape: no build
    assert {p: p.stat().st_mtime_ns for p in tmp_path.glob("planner_*.so")} == built
    assert not [p for p in tmp_path.iterdir() if p.is_dir()]  # no build directory left over


def test_a_failing_compiler_is_a_planner_error(tmp_path: Path) -> None:
    with pytest.raises(PlannerError, match="compiling the planner's derivatives failed"):
        compile_functions([_sine()], cache_dir=tmp_path, compiler=shutil.which("false"))
    assert not list(tmp_path.glob("*.so"))


def _sine() -> Any:
    import casadi as ca

    x = ca.SX.sym("x")
    return ca.Function("f", [x], [ca.sin(x)])


def test_an_unwritable_cache_is_a_planner_error(tmp_path: Path) -> None:
    not_a_dir = tmp_path / "file"
    not_a_dir.write_text("")
    with pytest.raises(PlannerError, match="BEARINGFLOCK_CACHE_DIR"):
        compile_functions([_sine()], cache_dir=not_a_dir / "planner")


def test_a_damaged_cache_entry_is_rebuilt(tmp_path: Path) -> None:
    compile_functions([_sine()], cache_dir=tmp_path)
    (so,) = tmp_path.glob("*.so")
    so.write_bytes(b"truncated")
    (f,) = compile_functions([_sine()], cache_dir=tmp_path)
    assert float(f(0.5)) == pytest.approx(math.sin(0.5))
    assert so.stat().st_size > 1000


def test_missing_compiler_is_named(monkeypatch: pytest.MonkeyPatch) -> None:
    from groundstation.planner import compiled

    monkeypatch.setattr(compiled.shutil, "which", lambda name: None)
    with pytest.raises(PlannerError, match="C compiler"):
        compiled.find_compiler()
