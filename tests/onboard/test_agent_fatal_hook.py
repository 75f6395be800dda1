"""The daemon's entry point installs the fatal-thread hook first thing and removes it on every
way out (issue 23, defect 5 leftover): a thread that died before the daemon was built (a camera
capture at startup) was left to Python's default hook and the daemon ran on half alive; an
early error exit must not leave the hook behind in the calling process either."""

from __future__ import annotations

import threading
from pathlib import Path

from typer.testing import CliRunner

from groundstation.cli import app


def test_an_early_error_exit_leaves_no_fatal_hook_behind(tmp_path: Path) -> None:
    before = threading.excepthook
    res = CliRunner().invoke(app, ["agent", "--id", "0", "--config", str(tmp_path / "none.toml")])
    assert res.exit_code == 2, res.output
    assert threading.excepthook is before
