"""`bearingflock check --json` reports paper 001's field DBOM rank beside the motion DBOM ranks."""

import json
from pathlib import Path

from typer.testing import CliRunner

from groundstation.cli import app

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def test_rank_dbom_fields_is_reported_beside_the_motion_ranks():
    result = CliRunner().invoke(app, ["check", str(EXAMPLES / "tetra_rigid.toml"), "--json"])
    assert result.exit_code == 0, result.output
    report = json.loads(result.output)
    # N = 4: the paper's field matrix reaches 6N - 6 (only translations and rotations remain)
    assert report["rank_dbom_fields"] == report["expected_rank_dbom_fields"] == 18
    # today's keys are still there, unchanged (R^3 x S^1 motion matrix: 4N - 5 -> 4N - 4)
    assert report["rank_observability_static"] == 11
    assert report["rank_observability_moving"] == 12
