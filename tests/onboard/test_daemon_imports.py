"""The daemon's import path stays lean (issue 27, resident memory <= 70 MB per daemon).

A daemon is ``python -m groundstation.cli agent``: the command line module, then the modules
``onboard.daemon.cli._run_agent`` imports unconditionally (read from its source, so the test
follows the code) and the pymavlink link it opens with simulator bearings. None of that may
pull in SciPy (about 27 MB resident), OpenCV (only with a camera), numba or matplotlib. Checked
in a fresh interpreter: ``sys.modules`` of the test process says nothing about a daemon's.
"""

from __future__ import annotations

import ast
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
HEAVY = ("scipy", "cv2", "numba", "matplotlib")


def run_agent_imports() -> list[str]:
    """Modules the body of ``_run_agent`` imports on every start (not inside a branch)."""
    tree = ast.parse((ROOT / "onboard" / "daemon" / "cli.py").read_text())
    body = next(
        node.body
        for node in ast.walk(tree)
        if isinstance(node, ast.FunctionDef) and node.name == "_run_agent"
    )
    names = []
    for stmt in body:
        if isinstance(stmt, ast.Import):
            names += [alias.name for alias in stmt.names]
        elif isinstance(stmt, ast.ImportFrom) and stmt.module and stmt.level == 0:
            names.append(stmt.module)
    return names


def test_run_agent_imports_are_found() -> None:
    modules = run_agent_imports()
    assert "onboard.daemon.loop" in modules
    assert "onboard.autopilot" in modules


def test_daemon_import_path_has_no_heavy_modules() -> None:
    modules = ["groundstation.cli", *run_agent_imports(), "onboard.autopilot.pymavlink_link"]
    code = (
        "import importlib, json, sys\n"
        f"for m in {modules!r}:\n"
        "    importlib.import_module(m)\n"
        f"print(json.dumps([h for h in {HEAVY!r} if h in sys.modules]))\n"
    )
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
    }
    out = subprocess.run(
        [sys.executable, "-c", code],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    )
    assert json.loads(out.stdout.strip().splitlines()[-1]) == []
