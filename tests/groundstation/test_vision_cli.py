"""``bearingflock vision probe``: JSON detections, drawing, one-line errors with exit 2."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from groundstation.vision_cli import vision_app
from onboard.vision.config import load_camera
from sim.render import Renderer, RenderMarker, make_background, place_in_view

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
runner = CliRunner()


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> tuple[Path, dict[int, np.ndarray]]:
    cam = load_camera(EXAMPLES / "camera.toml")
    ren = Renderer(cam, make_background(2, texture_px=256))
    pose = (np.array([0.0, 0.0, -5.0]), 0.0, 0.0, 0.5)
    p1, r1 = place_in_view(ren, pose, [200.0, 220.0], 6.0, 0.3, 1.0)
    p4, r4 = place_in_view(ren, pose, [450.0, 260.0], 4.0, 0.2, 2.0)
    img = ren.render(
        *pose,
        [
            RenderMarker("disc", 0.5, p1, r1, color_bgr=(0, 0, 220)),
            RenderMarker("tag", 0.5, p4, r4, tag_id=4),
        ],
        noise_std=1.0,
        seed=0,
    )
    path = tmp_path_factory.mktemp("probe") / "view.png"
    cv2.imwrite(str(path), img)
    r_ned_body = ren.camera_pose(*pose)[0] @ cam.r_body_cam.T
    return path, {1: r_ned_body.T @ (p1 - pose[0]), 4: r_ned_body.T @ (p4 - pose[0])}


def test_probe_json(scene) -> None:
    path, truth = scene
    res = runner.invoke(
        vision_app,
        [
            "probe",
            str(path),
            "--camera",
            str(EXAMPLES / "camera.toml"),
            "--markers",
            str(EXAMPLES / "markers.toml"),
            "--json",
        ],
    )
    assert res.exit_code == 0, res.output
    rows = json.loads(res.stdout)
    assert sorted(r["id"] for r in rows) == [1, 4]
    for r in rows:
        p = truth[r["id"]]
        b = np.array(r["bearing_body"])
        assert math.degrees(math.acos(min(1.0, b @ p / np.linalg.norm(p)))) < 0.5
        assert r["range_m"] == pytest.approx(np.linalg.norm(p), rel=0.05)
        assert {"kind", "quality"} <= set(r)


def test_probe_text_draw_and_no_markers_file(scene, tmp_path: Path) -> None:
    path, _ = scene
    out = tmp_path / "drawn.png"
    res = runner.invoke(
        vision_app,
        ["probe", str(path), "--camera", str(EXAMPLES / "camera.toml"), "--draw", str(out)],
    )
    assert res.exit_code == 0, res.output
    assert "id   4 tag" in res.stdout and "range ?" in res.stdout  # tags only, size unknown
    assert cv2.imread(str(out)).shape == (480, 640, 3)


def test_probe_bad_inputs_exit_2(scene, tmp_path: Path) -> None:
    path, _ = scene
    corrupt = tmp_path / "corrupt.png"
    corrupt.write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), np.zeros((10, 10, 3), np.uint8))
    bad_cam = tmp_path / "cam.toml"
    bad_cam.write_text("width = 640\n")
    cam = str(EXAMPLES / "camera.toml")
    for args in (
        [str(corrupt), "--camera", cam],
        [str(small), "--camera", cam],
        [str(tmp_path / "missing.png"), "--camera", cam],
        [str(path), "--camera", str(bad_cam)],
    ):
        res = runner.invoke(vision_app, ["probe", *args])
        assert res.exit_code == 2
        assert res.stderr.startswith("error: ") and res.stderr.count("\n") == 1
