"""`bearingflock check`: verdicts, exit codes, JSON keys, and numbers recomputed independently."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from groundstation.check import analyze
from groundstation.cli import app
from messages.formation import load_formation
from onboard.geometry import rot_z
from onboard.graph import angle_set, formation_edges
from onboard.rigidity.angle import angle_rigidity_matrix
from onboard.rigidity.bearing import ibr_r3s1, r3s1_rigidity_matrix_body, se3_rigidity_matrix

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
REQUIRED_KEYS = {
    "n_agents",
    "n_edges",
    "reciprocal_pairs",
    "ibr_r3s1",
    "ibr_se3",
    "iar",
    "rank_r3s1",
    "expected_rank_r3s1",
    "rank_angle",
    "expected_rank_angle",
    "rigidity_eigenvalue_angle",
    "rigidity_eigenvalue_bearing",
    "scale_observable_moving",
}
runner = CliRunner()


def run(*args: str):
    return runner.invoke(app, ["check", *args])


def test_rigid_formation_exits_0_with_all_keys():
    result = run(str(EXAMPLES / "tetra_rigid.toml"), "--json")
    assert result.exit_code == 0, result.output
    report = json.loads(result.output)
    assert REQUIRED_KEYS <= report.keys()
    assert report["n_agents"] == 4 and report["n_edges"] == 12
    assert len(report["reciprocal_pairs"]) == 6
    assert report["ibr_r3s1"] and report["ibr_se3"] and report["iar"]
    assert report["rank_r3s1"] == report["expected_rank_r3s1"] == 11
    assert report["rank_angle"] == report["expected_rank_angle"] == 5
    assert report["scale_observable_moving"]
    assert report["rigidity_eigenvalue_bearing"] > 0 and report["rigidity_eigenvalue_angle"] > 0


def test_chain_exits_1_and_names_weak_agents():
    result = run(str(EXAMPLES / "chain_nonrigid.toml"), "--json")
    assert result.exit_code == 1, result.output
    report = json.loads(result.output)
    assert not report["ibr_r3s1"] and not report["iar"]
    assert report["rank_r3s1"] < report["expected_rank_r3s1"]
    assert report["rigidity_eigenvalue_bearing"] == pytest.approx(0.0, abs=1e-12)
    weak = {d["id"] for d in report["degenerate_vertices"]}
    assert weak == {1, 2, 3, 4}  # each sees at most one agent; agent 1 is seen by no one
    assert report["reciprocal_pairs"] == []


@pytest.mark.parametrize("name", ["tetra_rigid", "six_directed", "ring_camera", "chain_nonrigid"])
def test_eigenvalues_match_an_independent_computation(name):
    formation = load_formation(EXAMPLES / f"{name}.toml")
    report = analyze(formation)
    edges = formation_edges(formation)
    p, yaw = formation.p_ned, formation.yaw_rad
    b = r3s1_rigidity_matrix_body(p, yaw, edges)
    assert report.rigidity_eigenvalue_bearing == pytest.approx(
        max(np.linalg.eigvalsh(b.T @ b)[5], 0.0), abs=1e-12
    )
    s = se3_rigidity_matrix(p, rot_z(yaw), edges)
    assert report.rank_se3 == np.linalg.matrix_rank(s, tol=1e-9 * np.linalg.norm(s, 2))
    ra = angle_rigidity_matrix(p, angle_set(edges))
    assert report.rigidity_eigenvalue_angle == pytest.approx(
        np.linalg.eigvalsh(ra.T @ ra)[7], rel=1e-9, abs=1e-12
    )
    assert report.paper003_theorem_holds


def test_critical_edges_really_break_rigidity(tmp_path):
    formation = load_formation(EXAMPLES / "ring_camera.toml")
    report = analyze(formation)
    assert report.ibr_r3s1
    edges = formation_edges(formation)
    pairs = formation.id_pairs(edges)
    for k, pair in enumerate(pairs):
        rest = np.delete(edges, k, axis=0)
        broken = not ibr_r3s1(formation.p_ned, formation.yaw_rad, rest).is_rigid
        assert broken == (pair in report.critical_edges)


def test_camera_edges_come_from_field_of_view():
    formation = load_formation(EXAMPLES / "ring_camera.toml")
    report = analyze(formation)
    assert report.edge_source == "camera"
    assert report.rigidity_eigenvalue_angle_weighted is not None
    assert 0.0 < report.rigidity_eigenvalue_angle_weighted


@pytest.mark.parametrize(
    ("body", "needle"),
    [
        (
            "[[agent]]\nid = 1\nposition_ned = [0.0, 0.0, nan]\n[[agent]]\nid = 2\nposition_ned = [1.0, 0.0, 0.0]\n",
            "agent[0] (id 1).position_ned: must be finite",
        ),
        ("not toml [", "invalid TOML"),
        (
            "[[agent]]\nid = 1\nposition_ned = [0.0, 0.0, 0.0]\n[[agent]]\nid = 2\nposition_ned = [1.0, 0.0, 0.0]\n"
            "[[edge]]\nfrom = 1\nto = 3\n",
            "edge[0]: unknown agent id 3",
        ),
    ],
)
def test_invalid_file_exits_2_with_one_line(tmp_path, body, needle):
    path = tmp_path / "bad.toml"
    path.write_text(body)
    result = run(str(path))
    assert result.exit_code == 2
    assert needle in result.output
    assert "bad.toml" in result.output


def test_error_keeps_tag_like_brackets_in_paths(tmp_path):
    """rich prints the error: ``[run1]`` in a path is text, not a markup tag."""
    folder = tmp_path / "[run1]"
    folder.mkdir()
    path = folder / "bad.toml"
    path.write_text("[[agent]]\nid = 0\n")
    result = run(str(path))
    assert result.exit_code == 2
    assert "[run1]" in result.output


def test_console_script_runs_as_a_process():
    out = subprocess.run(
        [sys.executable, "-m", "groundstation.cli", "check", str(EXAMPLES / "chain_nonrigid.toml")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 1
    assert "NOT RIGID" in out.stdout
