"""Fleet-file keys for camera bearings (additive: files without them keep their meaning), and
the agent command's checks of the camera options."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from groundstation.demo_cli import write_camera_rig
from onboard.autopilot.base import DEFAULT_STREAM_RATES_HZ
from onboard.daemon.cli import _stream_rates
from onboard.daemon.config import ConfigError, load_fleet
from onboard.vision.config import load_camera, load_markers

FORMATION = """
[[agent]]
id = 0
position_ned = [0.0, 0.0, -5.0]
[[agent]]
id = 1
position_ned = [4.0, 0.0, -5.0]
"""


def write(tmp_path: Path, fleet: str) -> Path:
    (tmp_path / "formation.toml").write_text(FORMATION)
    path = tmp_path / "fleet.toml"
    path.write_text('formation = "formation.toml"\n' + fleet)
    return path


def test_camera_keys_default_to_the_virtual_camera(tmp_path: Path) -> None:
    fleet = load_fleet(write(tmp_path, ""))
    assert fleet.config.bearings == "sim" and fleet.config.camera.files == []


def test_camera_section_is_resolved_next_to_the_fleet_file(tmp_path: Path) -> None:
    path = write(
        tmp_path,
        'bearings = "camera"\n[camera]\nfiles = ["rig/camera0.toml"]\nmarkers = "rig/m.toml"\n',
    )
    fleet = load_fleet(path)
    assert fleet.resolve(fleet.config.camera.files[0]) == tmp_path / "rig" / "camera0.toml"


@pytest.mark.parametrize(
    "text,message",
    [
        ('bearings = "camera"\n', "needs camera.files and camera.markers"),
        ('bearings = "pixels"\n', "bearings"),
        ('[camera]\nfiles = ["a.toml", "b.toml"]\ndevice = "0"\n', "exactly one camera file"),
        ("[camera]\nlens = 3\n", "lens"),
        ("[camera]\nattitude_rate_hz = 0.0\n", "camera.attitude_rate_hz"),
        ("[camera]\nattitude_rate_hz = nan\n", "camera.attitude_rate_hz"),
    ],
)
def test_bad_camera_keys_are_named(tmp_path: Path, text: str, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        load_fleet(write(tmp_path, text))


def test_camera_bearings_ask_for_attitude_at_the_levelling_rate(tmp_path: Path) -> None:
    """Levelling interpolates roll and pitch at each frame's exposure: with camera bearings the
    daemon asks for ATTITUDE at ``camera.attitude_rate_hz`` (default 100 Hz, PX4's onboard
    rate); with the virtual camera it keeps the link's defaults."""
    fleet = load_fleet(write(tmp_path, ""))
    assert fleet.config.camera.attitude_rate_hz == 100.0
    assert _stream_rates("sim", 100.0) == dict(DEFAULT_STREAM_RATES_HZ)
    rates = _stream_rates("camera", 100.0)
    assert rates["ATTITUDE"] == 100.0 > DEFAULT_STREAM_RATES_HZ["ATTITUDE"]
    assert {k: v for k, v in rates.items() if k != "ATTITUDE"} == {
        k: v for k, v in DEFAULT_STREAM_RATES_HZ.items() if k != "ATTITUDE"
    }


def test_rig_files_load_with_the_vision_config(tmp_path: Path) -> None:
    files, markers = write_camera_rig(tmp_path, 6, cameras=4, width=320, height=240, hfov_deg=100)
    cams = [load_camera(f) for f in files]
    # the convention of CameraModel.from_fov: f = (W / 2) / tan(hfov / 2)
    assert [c.fx for c in cams] == pytest.approx([160.0 / 1.19175359] * 4)
    assert [c.mount_rpy_deg[2] for c in cams] == [0.0, 90.0, 180.0, 270.0]
    specs = load_markers(markers)
    assert [s.id for s in specs] == list(range(6)) and {s.kind for s in specs} == {"disc"}
    assert specs[0].color_hsv_min[0] > specs[0].color_hsv_max[0]  # red wraps through H = 0
    with pytest.raises(ValueError, match="at most 6"):
        write_camera_rig(tmp_path, 7)


def test_agent_refuses_camera_bearings_without_files(tmp_path: Path) -> None:
    from groundstation.cli import app

    path = write(tmp_path, "")
    result = CliRunner().invoke(
        app, ["agent", "--id", "0", "--config", str(path), "--bearings", "camera"]
    )
    assert result.exit_code == 2 and "camera files and a markers file" in result.output
    result = CliRunner().invoke(
        app, ["agent", "--id", "0", "--config", str(path), "--bearings", "sonar"]
    )
    assert result.exit_code == 2 and "sim or camera" in result.output


@pytest.mark.parametrize(
    "text,expected",
    [
        ("", False),  # paper 000 does not read ranges: nothing changes
        ('[core]\nlocalization = "paper002"\n', True),  # its eq. 22 terms want them
        ('[core]\nlocalization = "paper002"\n[camera]\nranges = false\n', False),
        ("[camera]\nranges = true\n", True),
    ],
)
def test_camera_ranges_default_to_where_a_layer_uses_them(tmp_path, text, expected) -> None:
    fleet = load_fleet(write(tmp_path, text))
    assert fleet.camera_ranges is expected


def test_camera_ranges_stay_off_for_the_rigidity_layer_unless_asked(tmp_path: Path) -> None:
    """Paper 003's angle localization takes any range in place of its SfM distances: with
    rigidity maintenance on, camera ranges only when the file says so."""
    from groundstation.demo import DemoPorts, plan_formation, write_demo_files

    path = write_demo_files(tmp_path, plan_formation(4, seed=0), DemoPorts(zenoh=1, mavlink=2,
                            gcs=3), "t", "formation-active", localization="paper002")  # fmt: skip
    fleet = load_fleet(path)
    assert fleet.config.rigidity.maintenance and not fleet.camera_ranges
    path.write_text(path.read_text().replace("[camera]", "[camera]\nranges = true", 1))
    if "[camera]" not in path.read_text():
        path.write_text(path.read_text() + "\n[camera]\nranges = true\n")
    assert load_fleet(path).camera_ranges


def test_a_bad_camera_ranges_value_is_named(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"camera\.ranges"):
        load_fleet(write(tmp_path, '[camera]\nranges = "yes"\n'))
