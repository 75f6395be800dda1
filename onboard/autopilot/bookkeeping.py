"""What both autopilot-link backends keep the same way: the telemetry state and its lock, the
counters, the event queue and the latest (saturated) setpoint. A backend subclasses
:class:`LinkBookkeeping` and adds the protocol: how messages arrive and commands go out."""

from __future__ import annotations

import math
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import fields

from messages.agent import Setpoint
from onboard.autopilot.base import (
    ActionResult,
    AutopilotLink,
    LinkConfig,
    LinkCounters,
    LinkEvent,
    StreamState,
    Telemetry,
)
from onboard.autopilot.states import (
    Attempt,
    Saturated,
    TelemetryState,
    retry_loop,
    saturate_setpoint,
    snapshot,
)

MAX_EVENTS = 1000
ZERO_SETPOINT = Saturated((0.0, 0.0, 0.0), 0.0, non_finite=False, clipped=False)


class LinkBookkeeping(AutopilotLink):
    """Shared state of a link; every access goes through ``_cond`` (an RLock condition)."""

    def __init__(self, config: LinkConfig | None = None) -> None:
        self.config = config if config is not None else LinkConfig()
        self._clock = self.config.clock
        self._cond = threading.Condition(threading.RLock())
        self._state = TelemetryState()
        self._counts = {f.name: 0 for f in fields(LinkCounters)}
        self._events: deque[LinkEvent] = deque(maxlen=MAX_EVENTS)
        self._stream = StreamState.IDLE
        self._setpoint = ZERO_SETPOINT
        self._t_setpoint = -math.inf
        self._source_t: float | None = None
        self.setpoint_ages_s: deque[float] = deque(maxlen=20_000)
        self.frame_to_wire_s: deque[float] = deque(maxlen=20_000)
        self._stop = threading.Event()

    def telemetry(self) -> Telemetry:
        with self._cond:
            return snapshot(
                self._state,
                self._clock(),
                self.config,
                self.target_system,
                self._stream,
                self._setpoint,
                LinkCounters(**self._counts),
            )

    def events(self) -> list[LinkEvent]:
        with self._cond:
            out = list(self._events)
            self._events.clear()
        return out

    def _event(self, kind: str, detail: str, t_s: float | None = None) -> None:
        with self._cond:
            self._events.append(LinkEvent(self._clock() if t_s is None else t_s, kind, detail))

    def _count(self, name: str, k: int = 1) -> None:
        with self._cond:
            self._counts[name] += k

    def _wait_state(self, pred: Callable[[TelemetryState], bool], timeout_s: float) -> bool:
        """Block until ``pred(state)`` holds (re-checked on every message) or time runs out."""
        with self._cond:
            return (
                self._cond.wait_for(lambda: pred(self._state) or self._stop.is_set(), timeout_s)
                and not self._stop.is_set()
            )

    def _retry(
        self, action: str, attempt: Callable[[], Attempt], timeout_s: float | None
    ) -> ActionResult:
        """Run ``attempt`` until it works, cannot work, or ``timeout_s`` runs out (backoff)."""
        t0 = self._clock()
        cfg = self.config
        a, sends, why = retry_loop(
            attempt,
            self._clock,
            self._stop.wait,
            cfg.retry_timeout_s if timeout_s is None else timeout_s,
            cfg.backoff_initial_s,
            cfg.backoff_max_s,
        )
        return self._result(action, a, sends, t0, suffix=f" ({why})" if why else "")

    def _result(
        self, action: str, a: Attempt, sends: int, t0: float, suffix: str = ""
    ) -> ActionResult:
        """The action's outcome with the STATUSTEXT reasons the autopilot gave since ``t0``."""
        with self._cond:
            reasons = self._state.texts_since(t0)
        return ActionResult(
            action=action,
            ok=a.ok,
            result=a.result,
            attempts=sends,
            elapsed_s=self._clock() - t0,
            reasons=reasons,
            detail=a.detail + suffix,
        )

    def set_setpoint(self, setpoint: Setpoint, source_t: float | None = None) -> Setpoint:
        cfg = self.config
        sat = saturate_setpoint(
            setpoint.v_body,
            setpoint.yaw_rate_rad_s,
            cfg.max_speed_xy_m_s,
            cfg.max_speed_z_m_s,
            cfg.max_yaw_rate_rad_s,
        )
        with self._cond:
            self._setpoint, self._t_setpoint = sat, self._clock()
            self._source_t = source_t
            self._counts["nan_setpoints"] += int(sat.non_finite)
            self._counts["saturated_setpoints"] += int(sat.clipped)
            active = self._stream is not StreamState.IDLE
        if active:
            self._on_setpoint(sat)
        return Setpoint(sat.v_body, sat.yaw_rate_rad_s)

    def _on_setpoint(self, sat: Saturated) -> None:
        """A new setpoint while streaming: backends that push setpoints on change do it here
        (pymavlink streams from its own sender thread and needs nothing)."""
