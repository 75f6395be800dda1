"""The daemon's shutdown closes everything even when one part raises (issue 22, bug 4)."""

from __future__ import annotations

from onboard.daemon.cli import _close_all


def test_a_raising_close_does_not_skip_the_next_one(caplog):
    closed: list[str] = []

    def link_close() -> None:
        closed.append("link")
        raise AttributeError("'NoneType' object has no attribute 'close'")

    _close_all(link_close, lambda: closed.append("peers"))
    assert closed == ["link", "peers"]
    assert "AttributeError" in caplog.text
