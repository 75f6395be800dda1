"""Port ranges for simulators and daemons: free, and below the kernel's ephemeral ports."""

from __future__ import annotations

from pathlib import Path

from sim.server import ephemeral_port_start, free_port_base


def test_ephemeral_start_is_read_from_the_kernel_setting(tmp_path: Path) -> None:
    f = tmp_path / "ip_local_port_range"
    f.write_text("40000\t60999\n")
    assert ephemeral_port_start(str(f)) == 40000
    assert ephemeral_port_start(str(tmp_path / "missing")) == 32768
    f.write_text("garbage")
    assert ephemeral_port_start(str(f)) == 32768


def test_port_bases_stay_below_the_ephemeral_range() -> None:
    """An outgoing connection takes ephemeral ports at any time; a range there is not safe."""
    start = ephemeral_port_start()
    for seed in range(50):
        base = free_port_base(8, span=60, seed=seed)
        assert 20000 <= base and base + 60 + 8 <= start
