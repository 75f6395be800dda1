"""The lean install (issue 27): the onboard daemon imports without any optional dependency, and
a command that needs a missing extra ends on one line naming it (``messages.optional``).

Each check runs in a fresh interpreter whose ``sys.meta_path`` refuses the optional packages,
as a vehicle's ``pip install bearingflock`` lacks them."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

from messages.optional import EXTRAS, MissingExtraError, missing_extra_message, require

ROOT = Path(__file__).resolve().parent.parent
BLOCKED = sorted(EXTRAS)
BLOCKER = textwrap.dedent(
    f"""
    import importlib.abc, sys

    class Refuse(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in {BLOCKED!r}:
                raise ModuleNotFoundError(f"No module named {{name!r}}", name=name)
            return None

    sys.meta_path.insert(0, Refuse())
    """
)


def run_blocked(code: str, *argv: str, cwd: Path = ROOT) -> subprocess.CompletedProcess[str]:
    """``code`` in a fresh interpreter without the optional packages (argv after ``-c``)."""
    return subprocess.run(
        [sys.executable, "-c", BLOCKER + textwrap.dedent(code), *argv],
        cwd=cwd,
        env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"},
        capture_output=True,
        text=True,
        timeout=120,
    )


FORMATION = (
    "[[agent]]\nid = 0\nposition_ned = [0.0, 0.0, -5.0]\n"
    "[[agent]]\nid = 1\nposition_ned = [4.0, 0.0, -5.0]\n"
)


def _fleet(tmp_path: Path) -> Path:
    (tmp_path / "formation.toml").write_text(FORMATION)
    (tmp_path / "fleet.toml").write_text('formation = "formation.toml"\n')
    return tmp_path / "fleet.toml"


def test_the_daemon_imports_without_optional_dependencies(tmp_path: Path) -> None:
    # the agent command runs its imports, then refuses --id 7 of a 2-vehicle fleet (exit 2)
    r = run_blocked(
        """
        import sys
        from onboard.autopilot import open_link
        from onboard.autopilot.pymavlink_link import PymavlinkLink
        import zenoh, pymavlink.mavutil, msgspec, scipy
        from groundstation.cli import main
        blocked, sys.argv = sys.argv[2:], ["bearingflock", "agent", "--id", "7", "--config",
                                           sys.argv[1], "--bearings", "sim"]
        try:
            main()
        except SystemExit as exc:
            print("exit", exc.code)
        print("loaded:", sorted({m.split(".")[0] for m in sys.modules} & set(blocked)))
        """,
        str(_fleet(tmp_path)),
        *BLOCKED,
    )
    assert "exit 2" in r.stdout, r.stderr
    assert "the fleet has agents 0..1" in r.stderr
    assert "loaded: []" in r.stdout


def _main(*args: str) -> str:
    return f"import sys; sys.argv = ['bearingflock', *{list(args)!r}]\n" + (
        "from groundstation.cli import main\nmain()\n"
    )


def _one_line_error(r: subprocess.CompletedProcess[str], extra: str) -> None:
    assert r.returncode == 2, (r.stdout, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert lines[0].startswith("error: ") and f"bearingflock[{extra}]" in lines[0]


def test_demo_without_the_demo_extra_says_which_before_it_runs(tmp_path: Path) -> None:
    r = run_blocked(_main("demo", "--out", str(tmp_path / "out")))
    _one_line_error(r, "sim")
    assert not (tmp_path / "out").exists()  # nothing started


def test_camera_bearings_without_the_vision_extra_say_which(tmp_path: Path) -> None:
    fleet = _fleet(tmp_path)
    args = ["agent", "--id", "0", "--config", str(fleet), "--bearings",
            "camera", "--camera", str(tmp_path / "c.toml"), "--markers", str(tmp_path / "m.toml")]  # fmt: skip
    _one_line_error(run_blocked(_main(*args)), "vision")


def test_the_mavsdk_backend_without_its_extra_says_which() -> None:
    r = run_blocked(
        """
        from messages.optional import MissingExtraError
        from onboard.autopilot import open_link
        try:
            open_link("mavsdk")
        except MissingExtraError as exc:
            print(exc)
        """
    )
    assert r.returncode == 0, r.stderr
    assert "bearingflock[mavsdk]" in r.stdout


def test_require_names_the_extra_and_passes_other_errors() -> None:
    assert require("json").dumps([1]) == "[1]"
    assert missing_extra_message("json") is None
    assert "bearingflock[vision]" in (missing_extra_message("cv2.aruco") or "")
    with pytest.raises(ModuleNotFoundError) as info:  # not an optional dependency: unchanged
        require("bearingflock_no_such_module")
    assert not isinstance(info.value, MissingExtraError)
    r = run_blocked("from messages.optional import require\nrequire('casadi')\n")
    assert "MissingExtraError" in r.stderr and "bearingflock[planner]" in r.stderr


def test_extras_exist_and_the_base_install_has_none_of_them() -> None:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    extras = project["optional-dependencies"]
    assert {extra for extra, _ in EXTRAS.values()} <= set(extras)
    base = " ".join(project["dependencies"]).lower()
    for dist in ("opencv", "numba", "matplotlib", "casadi", "nlopt", "mavsdk", "mcap", "pyarrow",
                 "dask", "pytest"):  # fmt: skip
        assert dist not in base, dist
    assert "bearingflock[all]" in extras["test"]
