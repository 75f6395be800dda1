"""Replay a recording on Zenoh, so the monitor, the recorder and other tools run on it.

Every Zenoh sample is republished on its key with the recorded bytes, paced by the recorded
receive times divided by ``speed`` (``speed <= 0``: as fast as possible); liveliness channels
declare and undeclare the tokens again. Three things are never republished unless asked:
fleet commands (``bf/<fleet>/<id>/command``) and lockstep steps (``bf/<fleet>/sim/step``) —
replaying them would command live vehicles or a simulator — and MAVLink frames (the replay is
Zenoh only). ``fleet_to`` rewrites the fleet name in every key, to replay next to a live fleet.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

from groundstation.gcs.record import LIVELINESS_ENCODING, ZENOH_ENCODING, Record
from messages.command import COMMAND_TOPIC

UNSAFE_SUFFIXES = (f"/{COMMAND_TOPIC}", "/sim/step")


@dataclass
class ReplayStats:
    published: int = 0
    tokens: int = 0
    skipped: dict[str, int] = field(default_factory=dict)

    def skip(self, reason: str) -> None:
        self.skipped[reason] = self.skipped.get(reason, 0) + 1


def rename_fleet(topic: str, fleet_to: str | None) -> str:
    """``bf/<any>/rest`` -> ``bf/<fleet_to>/rest`` (other topics unchanged)."""
    if fleet_to is None:
        return topic
    parts = topic.split("/", 2)
    if len(parts) == 3 and parts[0] == "bf":
        return f"bf/{fleet_to}/{parts[2]}"
    return topic


def is_unsafe(topic: str) -> bool:
    return topic.endswith(UNSAFE_SUFFIXES)


def replay(
    records: Iterable[Record],
    session: Any,
    speed: float = 1.0,
    fleet_to: str | None = None,
    include_commands: bool = False,
    wait_subscribers_s: float = 2.0,
    stop: threading.Event | None = None,
    clock: Callable[[], float] = time.monotonic,
) -> ReplayStats:
    """Republish ``records`` on ``session``; returns what was published and skipped."""
    import zenoh

    stop = stop or threading.Event()
    stats = ReplayStats()
    publishers: dict[str, Any] = {}
    tokens: dict[str, Any] = {}
    t0_log: int | None = None
    t0_wall = 0.0
    try:
        for rec in records:
            if stop.is_set():
                break
            if rec.encoding not in (ZENOH_ENCODING, LIVELINESS_ENCODING):
                stats.skip(rec.source or rec.encoding)
                continue
            if not include_commands and is_unsafe(rec.topic):
                stats.skip("command")
                continue
            topic = rename_fleet(rec.topic, fleet_to)
            if t0_log is None:
                _wait_for_subscriber(session, topic, wait_subscribers_s, clock)
                t0_log, t0_wall = rec.log_time_ns, clock()
            if speed > 0:
                due = t0_wall + (rec.log_time_ns - t0_log) / 1e9 / speed
                if stop.wait(max(0.0, due - clock())):
                    break
            if rec.encoding == LIVELINESS_ENCODING:
                if rec.data == b"1" and topic not in tokens:
                    tokens[topic] = session.liveliness().declare_token(topic)
                    stats.tokens += 1
                elif rec.data == b"0" and topic in tokens:
                    tokens.pop(topic).undeclare()
                continue
            pub = publishers.get(topic)
            if pub is None:
                pub = publishers[topic] = session.declare_publisher(
                    topic, congestion_control=zenoh.CongestionControl.BLOCK
                )
            pub.put(rec.data)
            stats.published += 1
    finally:
        for tok in tokens.values():
            tok.undeclare()
        for pub in publishers.values():
            pub.undeclare()
    return stats


def _wait_for_subscriber(
    session: Any, topic: str, timeout_s: float, clock: Callable[[], float]
) -> None:
    """Give remote subscribers time to appear before the first sample (best effort)."""
    if timeout_s <= 0:
        return
    probe = session.declare_publisher(topic)
    try:
        deadline = clock() + timeout_s
        while clock() < deadline and not probe.matching_status.matching:
            time.sleep(0.02)
        time.sleep(0.1)  # the matching subscriber's peers may still be declaring theirs
    finally:
        probe.undeclare()
