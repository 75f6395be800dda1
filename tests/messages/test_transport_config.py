"""The fleet's Zenoh configuration: the short lease and the fast reconnect (messages/transport.py)."""

from __future__ import annotations

import json

from messages.transport import CONNECT_RETRY, LEASE_MS, ZenohSettings, zenoh_config

SHM = "transport/shared_memory/enabled"


def test_lost_links_are_retried_within_a_second_and_die_within_a_lease():
    config = zenoh_config(ZenohSettings(connect=["tcp/127.0.0.1:7447"]))
    retry = json.loads(config.get_json("connect/retry"))
    assert retry["period_max_ms"] <= 1000 and retry == CONNECT_RETRY
    assert json.loads(config.get_json("transport/link/tx/lease")) == LEASE_MS == 1000


def test_shared_memory_is_off_unless_asked_for():
    """A payload over Zenoh's 3 KiB threshold (a 10-vehicle peer envelope) would otherwise map
    a shared-memory pool in every session: +200 MB resident per daemon (issue 27)."""
    assert json.loads(zenoh_config(ZenohSettings()).get_json(SHM)) is False
    on = zenoh_config(ZenohSettings(extra={SHM: True}))
    assert json.loads(on.get_json(SHM)) is True
