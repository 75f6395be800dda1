"""``bearingflock gcs estimate`` live: paper 001's centralized EKF on a flying team over Zenoh.

A thin shell around :class:`groundstation.gcs.ekf_loop.EkfLoop`: :class:`LiveEstimator`
subscribes to every vehicle's peer envelopes (``bf/<fleet>/*/peer``, :mod:`messages.envelope`:
its odometry ``MotionShare`` and camera frames ``BearingShare`` among them) and status
(``.../status``: the daemon's own estimate, for the cross-check); Zenoh's callbacks only queue
the bytes, :meth:`LiveEstimator.pump` decodes them
(:func:`groundstation.gcs.zenoh_listener.classify_all`: undecodable or mis-addressed samples
and payloads are counted by reason) and feeds the loop in the caller's thread. The
simulator's truth is never subscribed to. :func:`render` draws the loop's summary as a rich table (like ``gcs monitor``).
"""

from __future__ import annotations

import math
import queue
import threading
from collections.abc import Callable
from typing import Any

from groundstation.gcs.ekf_loop import EkfLoop
from groundstation.gcs.zenoh_listener import classify_all
from messages.agent import VehicleStatus
from messages.codec import MessageError
from messages.keys import PEER_TOPIC, STATUS_TOPIC, topic_keys
from messages.peer import BearingShare, LocalizationState, MotionShare

TOPICS = (PEER_TOPIC, STATUS_TOPIC)
"""What the estimator subscribes to, per vehicle: its peer envelopes (it keeps ``MotionShare``,
``BearingShare`` and ``LocalizationState``) and its status."""
MAX_QUEUE = 100_000
"""Samples waiting to be processed; beyond, new ones are counted ``overflow`` and dropped."""


class LiveEstimator:
    """Zenoh subscription feeding an :class:`EkfLoop` (module doc). ``on_event`` is called
    with each new event's message (joined, dropped, re-added, alarms) as it happens."""

    def __init__(
        self,
        session: Any,
        fleet: str,
        loop: EkfLoop,
        on_event: Callable[[str], None] | None = None,
    ) -> None:
        self.session = session
        self.fleet = fleet
        self.loop = loop
        self.on_event = on_event
        self.samples: queue.Queue[tuple[str, bytes]] = queue.Queue(MAX_QUEUE)
        self.received = 0
        self._subs: list[Any] = []
        self._events_seen = 0
        self._lock = threading.Lock()
        self._lost: dict[str, int] = {}
        """Samples the callbacks could not queue, by reason (moved to the loop's counts)."""

    def start(self) -> LiveEstimator:
        for topic in TOPICS:
            self._subs.append(
                self.session.declare_subscriber(topic_keys(self.fleet, topic), self._on_sample)
            )
        return self

    def close(self) -> None:
        for sub in self._subs:
            try:
                sub.undeclare()
            except Exception:  # the session may be closing already
                pass
        self._subs = []

    def _on_sample(self, sample: Any) -> None:  # a Zenoh thread: queue only, never raise
        try:
            self.samples.put_nowait((str(sample.key_expr), sample.payload.to_bytes()))
        except queue.Full:
            with self._lock:
                self._lost["overflow"] = self._lost.get("overflow", 0) + 1
        except Exception:  # a payload zenoh cannot hand over
            with self._lock:
                self._lost["undecodable_zenoh_payload"] = (
                    self._lost.get("undecodable_zenoh_payload", 0) + 1
                )

    def pump(self, timeout_s: float) -> int:
        """Process every queued sample, waiting up to ``timeout_s`` for the first; returns how
        many were processed."""
        n = 0
        with self._lock:
            lost, self._lost = self._lost, {}
        for word, k in lost.items():
            self.loop.counts[word] = self.loop.counts.get(word, 0) + k
        try:
            item = self.samples.get(timeout=max(0.0, timeout_s))
        except queue.Empty:
            return 0
        while True:
            self._process(*item)
            n += 1
            try:
                item = self.samples.get_nowait()
            except queue.Empty:
                break
        self._emit_events()
        return n

    def _process(self, key: str, data: bytes) -> None:
        self.received += 1
        try:
            decoded, errors = classify_all(self.fleet, key, data)
        except MessageError as exc:
            decoded, errors = [], [exc]
        for exc in errors:
            self.loop.count(f"undecodable_{exc.reason}")
        for d in decoded:
            self._use(d.payload)

    def _use(self, p: object) -> None:
        if isinstance(p, MotionShare):
            self.loop.add_motion(p)
        elif isinstance(p, BearingShare):
            self.loop.add_frame(p)
        elif isinstance(p, VehicleStatus):
            a = p.agent
            self.loop.add_daemon_estimate(p.sender, p.stamp_s, a.p_hat_ned, a.yaw_hat_rad)
        elif isinstance(p, LocalizationState):
            self.loop.add_daemon_estimate(p.sender, p.stamp_s, p.p_hat_ned, p.yaw_hat_rad)

    def _emit_events(self) -> None:
        total = sum(self.loop.event_counts.values())
        new = total - self._events_seen
        self._events_seen = total
        if self.on_event is None or new <= 0:
            return
        for e in self.loop.events[-min(new, len(self.loop.events)) :]:
            self.on_event(f"t={e.t_s:.1f}s {e.message}")


class BackgroundEstimator:
    """A :class:`LiveEstimator` pumped by its own thread, for ``gcs monitor --ekf``: the
    monitor's refresh calls :meth:`summary` (under the loop's lock) while samples arrive."""

    def __init__(self, session: Any, fleet: str, loop: EkfLoop) -> None:
        self.loop = loop
        self.lock = threading.Lock()
        self._stop = threading.Event()
        self.estimator = LiveEstimator(session, fleet, loop)
        self._thread = threading.Thread(target=self._run, name="ekf-pump", daemon=True)

    def start(self) -> BackgroundEstimator:
        self.estimator.start()
        self._thread.start()
        return self

    def _run(self) -> None:
        while not self._stop.is_set():
            with self.lock:
                self.estimator.pump(0.02)

    def summary(self) -> dict[str, Any]:
        with self.lock:
            return self.loop.summary()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self.estimator.close()


def _f(x: Any, spec: str = ".2f") -> str:
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else format(x, spec)


def _xyz(v: list[float] | None) -> str:
    return "-" if v is None else " ".join(f"{x:+.1f}" for x in v)


def render(summary: dict[str, Any], fleet: str) -> Any:
    """A rich renderable of :meth:`EkfLoop.summary`: one row per vehicle (EKF pose beside the
    daemons' in the reference's frame, their distance, alarm), the scale line, counters and the
    latest events."""
    from rich import box
    from rich.console import Group
    from rich.table import Table
    from rich.text import Text

    table = Table(
        title=f"bearingflock estimate (paper 001 EKF) fleet {fleet!r}",
        box=box.SIMPLE_HEAD,
        padding=(0, 1),
        header_style="bold",
        title_justify="left",
    )
    for col in ("id", "EKF p m", "yaw deg", "sigma m", "daemons p m", "yaw deg", "diff m", "state"):
        table.add_column(col, justify="left" if col in ("EKF p m", "daemons p m") else "right")
    ref = summary["reference"]
    for i, row in summary["poses"].items():
        alarm = row["alarm"]
        if int(i) == ref:
            state = "reference"
        elif alarm:
            state = "DISAGREE"
        elif "disagreement_m" in row:
            state = "ok"
        else:
            state = "no daemon estimate"
        table.add_row(
            i,
            _xyz(row.get("p_ref_m")),
            _f(None if "yaw_ref_rad" not in row else math.degrees(row["yaw_ref_rad"]), ".0f"),
            _f(row.get("sigma_p_m")),
            _xyz(row.get("daemon_p_ref_m")),
            _f(
                None
                if "daemon_yaw_ref_rad" not in row
                else math.degrees(row["daemon_yaw_ref_rad"]),
                ".0f",
            ),
            _f(row.get("disagreement_m")),
            state,
            style="bold red" if alarm else None,
        )
    scale = (
        f"scale {_f(summary['scale_m'])} m (RMS distance, rel. sigma "
        f"{_f(summary['scale_rel_sigma'], '.1%')}), daemons/EKF "
        f"{_f(summary['daemon_scale_ratio'], '.3f')}  updates {summary['updates']}"
    )
    parts: list[Any] = [table, Text(scale, style="bold")]
    if summary["alarms"]:
        bound = summary["max_disagreement_m"]
        ids = ", ".join(str(i) for i in summary["alarms"])
        parts.append(
            Text(
                f"ALARM: EKF and daemons disagree by more than {bound:.2f} m on vehicle {ids}",
                style="bold red",
            )
        )
    else:
        parts.append(Text("EKF and daemons agree", style="bold green"))
    skipped = " ".join(f"{k}={v}" for k, v in summary["skipped"].items()) or "none"
    parts.append(Text(f"skipped: {skipped}", style="yellow" if summary["skipped"] else "dim"))
    for e in summary["events"][-5:]:
        parts.append(Text(f"t={e['t_s']:.1f}s {e['message']}", style="dim"))
    return Group(*parts)
