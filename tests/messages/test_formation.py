"""Formation files: every invalid file gives one FormationError that names problem and place."""

from pathlib import Path

import numpy as np
import pytest

from messages.formation import FormationError, load_formation, parse_formation
from onboard.graph import formation_edges

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"

TWO = """
[[agent]]
id = 1
position_ned = [0.0, 0.0, -5.0]
[[agent]]
id = 2
position_ned = [5.0, 0.0, -5.0]
yaw_deg = 180.0
"""


FORMATIONS = sorted(p for p in EXAMPLES.glob("*.toml") if "[[agent]]" in p.read_text())


@pytest.mark.parametrize("path", FORMATIONS, ids=lambda p: p.name)
def test_examples_load(path):
    f = load_formation(path)
    assert f.n >= 4
    assert np.all(np.isfinite(f.p_ned))
    assert len(formation_edges(f)) > 0


def test_edge_rules():
    complete = parse_formation(TWO)
    assert complete.edge_source == "complete"
    assert formation_edges(complete).tolist() == [[0, 1], [1, 0]]
    # Agent 2 faces agent 1, agent 1 faces away from 2 with a narrow cone.
    camera = parse_formation(
        "[camera]\nfov_deg = 60.0\nrange_m = 25.0\n"
        + TWO.replace(
            "id = 1\nposition_ned = [0.0, 0.0, -5.0]",
            "id = 1\nposition_ned = [0.0, 0.0, -5.0]\nyaw_deg = 180.0",
        )
    )
    assert camera.edge_source == "camera"
    assert formation_edges(camera).tolist() == [[1, 0]]
    short = parse_formation("[camera]\nfov_deg = 360.0\nrange_m = 4.0\n" + TWO)
    assert formation_edges(short).tolist() == []
    explicit = parse_formation(TWO + "[[edge]]\nfrom = 2\nto = 1\n")
    assert explicit.edge_source == "file"
    assert explicit.id_pairs(formation_edges(explicit)) == [(2, 1)]


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("[[agent]]\nid = 1\n", "agent[0]"),  # missing position
        (TWO.replace("[5.0, 0.0, -5.0]", "[5.0, 0.0]"), "agent[1].position_ned"),
        (
            TWO.replace("[5.0, 0.0, -5.0]", "[5.0, nan, -5.0]"),
            "agent[1] (id 2).position_ned: must be finite",
        ),
        (TWO.replace("[5.0, 0.0, -5.0]", "[0.0, 0.0, -5.0]"), "coincident agents"),
        (TWO.replace("id = 2", "id = 1"), "duplicate agent id 1"),
        (TWO + "[[edge]]\nfrom = 1\nto = 7\n", "edge[0]: unknown agent id 7"),
        (TWO + "[[edge]]\nfrom = 1\nto = 1\n", "edge[0]: agent 1 cannot see itself"),
        ("[camera]\nfov_deg = 0.0\n" + TWO, "camera.fov_deg: must be in (0, 360]"),
        (
            TWO.replace("yaw_deg = 180.0", "yaw_deg = 180.0\nrange_m = -1.0"),
            "agent[1] (id 2).range_m",
        ),
        (TWO + "speed = 3\n", "unknown field"),
        ("[[agent]\nid = 1", "invalid TOML"),
        ("[[agent]]\nid = 1\nposition_ned = [0.0, 0.0, 0.0]\n", "at least 2 agents"),
        (
            TWO.replace("yaw_deg = 180.0", "velocity_body = [1.0, 0.0, 0.0]"),
            "velocity_body must be given",
        ),
    ],
)
def test_invalid_files_name_the_problem(text, needle):
    with pytest.raises(FormationError) as info:
        parse_formation(text, source="f.toml")
    msg = str(info.value)
    assert msg.startswith("f.toml: ")
    assert needle in msg
    assert "\n" not in msg


def test_missing_file(tmp_path):
    with pytest.raises(FormationError, match="cannot read file"):
        load_formation(tmp_path / "nope.toml")
