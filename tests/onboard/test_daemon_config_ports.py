"""``[mavlink] url``'s ``{port}``: a stride for autopilots whose ports are not consecutive
(ArduPilot SITL instance ``i`` serves SERIAL0 on TCP 5760 + 10 i; issue 22, bug 6)."""

from __future__ import annotations

from pathlib import Path

import pytest

from onboard.daemon.config import ConfigError, load_fleet

FORMATION = "".join(
    f"[[agent]]\nid = {i}\nposition_ned = [{4.0 * i}, 0.0, -5.0]\n" for i in range(3)
)


def _fleet(tmp_path: Path, mavlink: str) -> Path:
    (tmp_path / "formation.toml").write_text(FORMATION)
    path = tmp_path / "fleet.toml"
    path.write_text(f'formation = "formation.toml"\n[mavlink]\n{mavlink}\n')
    return path


def test_port_stride_reaches_sitl_instances(tmp_path):
    fleet = load_fleet(
        _fleet(tmp_path, 'url = "tcp:127.0.0.1:{port}"\nport_base = 5760\nport_stride = 10')
    )
    assert [fleet.mavlink_url(i) for i in range(3)] == [
        "tcp:127.0.0.1:5760", "tcp:127.0.0.1:5770", "tcp:127.0.0.1:5780",
    ]  # fmt: skip
    default = load_fleet(_fleet(tmp_path, 'url = "udpin:0.0.0.0:{port}"  # agent {id}'))
    assert default.mavlink_url(2) == "udpin:0.0.0.0:14542"


@pytest.mark.parametrize(
    ("mavlink", "needle"),
    [
        ("port_stride = 0", "mavlink.port_stride: must be >= 1"),
        ('url = "tcp:127.0.0.1:{instance}"', "only {port} and {id}"),
        ('url = "tcp:127.0.0.1:{port"', "only {port} and {id}"),
    ],
)
def test_bad_port_templates_are_one_line_errors(tmp_path, mavlink, needle):
    with pytest.raises(ConfigError, match=r"fleet\.toml") as info:
        load_fleet(_fleet(tmp_path, mavlink))
    assert needle in str(info.value) and "\n" not in str(info.value)
