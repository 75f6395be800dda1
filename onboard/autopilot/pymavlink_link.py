"""The autopilot link over raw MAVLink with pymavlink (the daemon's main backend).

Three threads meet here, and one lock (``_cond``) guards everything they share:

* the **receive thread** parses every byte the autopilot sends and folds valid messages from the
  target system into :class:`~onboard.autopilot.states.TelemetryState`; garbage, bad CRCs and
  messages from other systems/components are counted and dropped. It also watches the
  heartbeat: when the vehicle leaves OFFBOARD/GUIDED (the pilot took over) or disarms while
  velocity control is active, it stops the stream and reports a ``stream_stopped`` event;
* the **sender thread** wakes at :attr:`LinkConfig.rate_hz` (wall clock): it streams the latest
  setpoint as ``SET_POSITION_TARGET_LOCAL_NED`` in ``MAV_FRAME_BODY_NED`` (frame 8) with the
  velocity + yaw-rate type mask (1479) while the stream is PRIMING or ACTIVE, replaces a setpoint
  older than :attr:`LinkConfig.setpoint_timeout_s` by zero velocity, sends a 1 Hz companion
  HEARTBEAT and notices a lost link;
* the **caller** (the agent loop) reads :meth:`telemetry`, calls :meth:`set_setpoint`, and runs the
  blocking actions, which send COMMAND_LONG and wait for the COMMAND_ACK the receive thread
  stores.

Real autopilots refuse things while they boot (docs/sim.md; the simulator's
``--strict`` mode reproduces it). Every action therefore retries with exponential backoff while the
refusal is one a later attempt may turn around (TEMPORARILY_REJECTED, DENIED, FAILED, no ACK),
collects the STATUSTEXT reasons, and checks the outcome in the heartbeat rather than trusting the
ACK: a mode is trusted only after it stayed for :attr:`LinkConfig.mode_settle_s`, and a mode
accepted before the estimator was ready is re-applied by :meth:`wait_ready` if the autopilot
reverted it when its boot ended.

Per flavour: PX4 takes off with ``NAV_TAKEOFF`` to ``MIS_TAKEOFF_ALT`` (set first with PARAM_SET)
and needs setpoints streaming before it accepts OFFBOARD; ArduPilot streams telemetry only when
asked (:meth:`request_streams`, SET_MESSAGE_INTERVAL with a REQUEST_DATA_STREAM fallback; done by
:meth:`connect`), takes off in GUIDED with the altitude in param 7, and ignores velocity targets
while a takeoff climbs, so :meth:`start_velocity_control` waits for the climb to end.
"""

from __future__ import annotations

import math
import sys
import threading
from collections.abc import Callable, Mapping
from typing import Any

from pymavlink import mavutil

from messages import mavlink as mv
from messages.mavsign import SignatureVerifier, Verdict, keep_timestamp_current, sign_outgoing
from onboard.autopilot.base import (
    ActionResult,
    Flavour,
    LinkConfig,
    LinkError,
    StreamState,
    result_name,
    serial_device,
    wrong_system_message,
)
from onboard.autopilot.bookkeeping import ZERO_SETPOINT, LinkBookkeeping
from onboard.autopilot.states import (
    CONTROL_MODE,
    HOLD_MODE,
    MAV_AUTOPILOT_INVALID,
    MAV_TYPE_ONBOARD_CONTROLLER,
    Attempt,
    Saturated,
    TelemetryState,
    climb_done,
    flavour_from_autopilot,
    is_autopilot_heartbeat,
    mode_command_params,
    retryable,
    stream_groups,
)

HEARTBEAT_PERIOD_S = 1.0
"""Our own companion heartbeat."""
HEARTBEAT_WAIT_S = 2.5
"""How long a state change confirmed by ACK may take to show in the heartbeat (1 Hz + slack)."""
PRIME_S = 0.3
"""PX4: stream setpoints this long before asking for OFFBOARD."""


class PymavlinkLink(LinkBookkeeping):
    """:class:`~onboard.autopilot.base.AutopilotLink` over pymavlink (module docstring)."""

    def __init__(self, config: LinkConfig | None = None) -> None:
        super().__init__(config)
        self._send_lock = threading.Lock()
        self._conn: Any = None
        self._target: tuple[int, int] | None = None
        self._acks: dict[int, int] = {}
        self._params: dict[str, float] = {}
        self._setpoint_stale = False
        self._provisional_mode: str | None = None
        self._link_lost = False
        self._t0 = self._clock()
        self._t_heartbeat_sent = -math.inf
        self._threads: list[threading.Thread] = []
        self._wake = threading.Event()
        """Set by :meth:`_on_setpoint` for a setpoint on a new frame: the sender sends at once."""
        self._sent_source_t: float | None = None
        """The ``source_t`` of the newest setpoint on the wire (a new one is a new frame's)."""
        self._other_systems: set[int] = set()
        """Autopilots heard that are not ``config.system_id`` (named if it never comes)."""
        self._verifier: SignatureVerifier | None = None
        """With ``config.signing_key``: decides on every received message, first."""

    # --- identity -------------------------------------------------------------------------------
    @property
    def flavour(self) -> Flavour | None:
        return self._state.flavour

    @property
    def target_system(self) -> int | None:
        return None if self._target is None else self._target[0]

    # --- connection -----------------------------------------------------------------------------
    def connect(
        self, url: str, timeout_s: float = 10.0, request_streams: bool | None = None
    ) -> None:
        """Open ``url`` (pymavlink syntax: ``udpin:HOST:PORT``, ``udpout:``, ``tcp:HOST:PORT``;
        or a serial device, ``serial:/dev/ttyACM0:921600``, see :func:`serial_device`), wait for
        an autopilot heartbeat and start the threads.

        ``request_streams``: ask for telemetry (:meth:`request_streams`); ``None`` asks an
        ArduPilot (which streams nothing unasked) and leaves a PX4's defaults alone. A position
        that does not stream yet does not fail the connection (a ``streams_pending`` event says
        what is missing; :meth:`wait_ready` waits for it). Raises :class:`LinkError` if no
        autopilot is heard within ``timeout_s``; the same link may then try again.
        """
        if self._conn is not None:
            raise LinkError("already connected")
        self._reset()
        try:
            serial = serial_device(url)  # pymavlink would read "/dev/ttyACM0:921600" as UDP
            device, port = (url, {}) if serial is None else (serial[0], {"baud": serial[1]})
            self._conn = mavutil.mavlink_connection(
                device,
                source_system=self.config.source_system,
                source_component=self.config.source_component,
                autoreconnect=True,
                **port,
            )
        except (OSError, ValueError, ImportError) as exc:
            raise LinkError(f"cannot open {url!r}: {exc}") from exc
        if self.config.signing_key is not None:
            self._verifier = SignatureVerifier(self.config.signing_key)
        self._start_thread(self._receive_loop, "autopilot-rx")
        with self._cond:
            heard = self._cond.wait_for(lambda: self._target is not None, timeout_s)
        if not heard:
            others = set(self._other_systems)
            rejected = self._signing_rejections()
            self.close()
            if others and self.config.system_id is not None:
                raise LinkError(wrong_system_message(url, self.config.system_id, others, timeout_s))
            if rejected:
                raise LinkError(
                    f"no correctly signed autopilot heartbeat on {url!r} within {timeout_s} s: "
                    f"{rejected} (does the autopilot have this vehicle's signing key? "
                    "docs/flying.md)"
                )
            raise LinkError(f"no autopilot heartbeat on {url!r} within {timeout_s} s")
        self._start_thread(self._send_loop, "autopilot-tx")
        if request_streams is None:
            request_streams = self.flavour is Flavour.ARDUPILOT
        if request_streams:
            # Only what every autopilot sends at once is waited for: ArduPilot accepts the
            # LOCAL_POSITION_NED request at boot but streams it only once its EKF has a position
            # (about 40 s after boot with GPS), and :meth:`wait_ready` waits for that.
            res = self._request_streams(None, need_velocity=False)
            if not res.ok:
                self._event("streams_pending", res.detail)

    def _reset(self) -> None:
        """Forget a previous connection: a daemon retries ``connect`` on the same link after a
        failed attempt (no autopilot yet, or one still booting), and a stop flag or a target
        left over from it made every later attempt fail at once."""
        with self._cond:
            self._stop.clear()
            self._target = None
            self._state = TelemetryState()
            self._acks.clear()
            self._params.clear()
            self._other_systems.clear()
            self._provisional_mode = None
            self._link_lost = False
            self._setpoint_stale = False
            self._sent_source_t = None
            self._t_heartbeat_sent = -math.inf
            self._stream = StreamState.IDLE
            self._counts = dict.fromkeys(self._counts, 0)

    def _start_thread(self, target: Callable[[], None], name: str) -> None:
        t = threading.Thread(target=target, name=name, daemon=True)
        t.start()
        self._threads.append(t)

    def close(self) -> None:
        """Stop the stream and the threads, close the connection (idempotent)."""
        self.stop_streaming("closed")
        self._stop.set()
        self._wake.set()
        for t in self._threads:
            if t is not threading.current_thread():
                t.join(timeout=2.0)
        self._threads = []
        if self._conn is not None:
            try:
                self._conn.close()
            except Exception:  # pymavlink's TCP file after a failed reconnect: port is None
                self._count("link_errors")
            self._conn = None

    # --- receiving ------------------------------------------------------------------------------
    def _receive_loop(self) -> None:
        while not self._stop.is_set():
            conn = self._conn
            if conn is None:
                return
            try:
                msg = conn.recv_match(blocking=True, timeout=0.1)
            except Exception:  # a socket or parser error must not kill the link
                self._count("link_errors")
                self._stop.wait(0.1)
                continue
            if msg is not None:
                self.feed(msg)

    def _signing_rejections(self) -> str:
        with self._cond:
            c = self._counts
            parts = [f"{c[k]} {k}" for k in ("bad_signature", "unsigned_rejected", "replayed")]
            return ", ".join(p for p in parts if not p.startswith("0 "))

    def _verified(self, msg: Any) -> bool:
        """With signing: the verifier's verdict, counted (call with the lock held)."""
        if self._verifier is None:
            return True
        verdict = self._verifier.check_message(msg)
        name = {
            Verdict.GOOD: "signed_ok",
            Verdict.BAD_SIGNATURE: "bad_signature",
            Verdict.UNSIGNED: "unsigned_rejected",
            Verdict.REPLAYED: "replayed",
        }.get(verdict)
        if name is not None:
            self._counts[name] += 1
        return verdict.accepted

    def feed(self, msg: Any) -> None:
        """Handle one parsed message (the receive thread's work; public for tests and replay)."""
        kind = msg.get_type()
        now = self._clock()
        with self._cond:
            if kind == "BAD_DATA" or kind.startswith("UNKNOWN_"):  # garbage, CRC, unknown id
                self._counts["bad_data"] += 1
                return
            if not self._verified(msg):  # before anything reads it
                return
            src = (msg.get_srcSystem(), msg.get_srcComponent())
            if self._target is None and not self._adopt(msg, src):
                return  # nothing is foreign before we know whom we talk to
            if src != self._target:
                self._counts["foreign"] += 1
                return
            prev_mode, prev_armed = self._state.mode, self._state.armed
            if not self._state.apply(msg, now):
                self._counts["invalid_values"] += 1
                return
            self._counts["received"] += 1
            if kind == "HEARTBEAT":
                self._after_heartbeat(prev_mode, prev_armed, now)
            elif kind == "COMMAND_ACK":
                if msg.target_system in (0, self.config.source_system):
                    self._acks[int(msg.command)] = int(msg.result)
            elif kind == "PARAM_VALUE":
                pid = msg.param_id
                name = pid.decode(errors="replace") if isinstance(pid, bytes) else str(pid)
                self._params[name.rstrip("\x00")] = float(msg.param_value)
            elif kind == "STATUSTEXT":
                self._event("statustext", self._state.statustexts[-1][2], t_s=now)
            self._cond.notify_all()

    def _adopt(self, msg: Any, src: tuple[int, int]) -> bool:
        """Before connecting: take the first autopilot heartbeat (of ``config.system_id``)."""
        if msg.get_type() != "HEARTBEAT" or not is_autopilot_heartbeat(msg.type, msg.autopilot):
            return False
        if self.config.system_id is not None and src[0] != self.config.system_id:
            self._other_systems.add(src[0])
            return False
        flavour = flavour_from_autopilot(int(msg.autopilot))
        if flavour is None:
            return False
        self._target = src
        self._state.flavour = flavour
        self._event("connected", f"system {src[0]} ({flavour.value})")
        return True

    def _after_heartbeat(self, prev_mode: str, prev_armed: bool, now: float) -> None:
        st = self._state
        if self._link_lost:
            self._link_lost = False
            self._event("link_restored", "heartbeat back", t_s=now)
        if st.mode != prev_mode and prev_mode != "UNKNOWN":
            self._event("mode_changed", f"{prev_mode} -> {st.mode}", t_s=now)
            if self._provisional_mode == prev_mode:
                self._event("mode_reverted", f"{prev_mode} reverted to {st.mode}", t_s=now)
        if st.armed != prev_armed:
            self._event("armed" if st.armed else "disarmed", st.mode, t_s=now)
        if self._stream is StreamState.ACTIVE and st.flavour is not None:
            control = CONTROL_MODE[st.flavour]
            if st.mode != control:
                self._stop_stream_locked(now, f"vehicle left {control}: now {st.mode}")
            elif not st.armed:
                self._stop_stream_locked(now, "vehicle disarmed")

    # --- sending --------------------------------------------------------------------------------
    def _send(self, fn: Callable[[Any], None]) -> bool:
        """Run ``fn(mav)`` under the send lock; any error is counted, never raised.

        Not only socket errors: when a TCP autopilot goes away, pymavlink's reconnect (in the
        receive thread and in this one at once) leaves its socket ``None`` halfway and raises
        AttributeError, which killed the sender thread (no more setpoints or heartbeats, even
        once the autopilot was back)."""
        conn = self._conn
        if conn is None:
            return False
        with self._send_lock:
            try:
                if self._verifier is not None and not self._signing(conn.mav):
                    return False
                fn(conn.mav)
            except Exception:
                self._count("link_errors")
                return False
        return True

    def _signing(self, mav: Any) -> bool:
        """Make ``mav`` sign (again: pymavlink replaces its MAVLink object when it switches to
        MAVLink 2 on the first v2 frame, and the new one would send unsigned); ``False`` for a
        MAVLink 1 object, which cannot sign: nothing is sent then (counted)."""
        key = self.config.signing_key
        assert key is not None
        module = sys.modules.get(type(mav).__module__)
        if getattr(module, "WIRE_PROTOCOL_VERSION", "1.0") != "2.0":
            self._count("signing_unavailable")
            return False
        if mav.signing.secret_key != key:
            sign_outgoing(mav, key, self.config.signing_link_id)
        keep_timestamp_current(mav)
        return True

    def _boot_ms(self) -> int:
        return int((self._clock() - self._t0) * 1000.0) & 0xFFFFFFFF

    def _send_loop(self) -> None:
        """The stream at ``rate_hz``, and a setpoint at once when the daemon sets one based on a
        new camera frame (:meth:`_on_setpoint`): the stream period then restarts from that send,
        so a frame's command waits for no stream slot and the rate stays bounded (at most the
        stream's plus the camera's)."""
        period = 1.0 / self.config.rate_hz
        next_t = self._clock()
        while not self._stop.is_set():
            prompt = self._wake.wait(max(0.0, next_t - self._clock()))
            if self._stop.is_set():
                return
            self._wake.clear()
            now = self._clock()
            next_t = now + period if prompt else next_t + period
            if next_t < now:  # fell behind (a stalled machine): do not burst to catch up
                next_t = now + period
            self._tick(now)

    def _on_setpoint(self, sat: Saturated) -> None:
        with self._cond:
            fresh = self._source_t is not None and self._source_t != self._sent_source_t
        if fresh:
            self._wake.set()

    def _tick(self, now: float) -> None:
        """One sender period: companion heartbeat, link watchdog, the setpoint."""
        if now - self._t_heartbeat_sent >= HEARTBEAT_PERIOD_S:
            self._t_heartbeat_sent = now
            self._send(
                lambda mav: mav.heartbeat_send(
                    MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID, 0, 0, mv.MAV_STATE_ACTIVE
                )
            )
        with self._cond:
            if (
                not self._link_lost
                and now - self._state.t_heartbeat_s > self.config.heartbeat_timeout_s
            ):
                self._link_lost = True
                self._event("link_lost", "no heartbeat", t_s=now)
            if self._stream is StreamState.IDLE or self._target is None:
                return
            sp = self._setpoint
            if self._stream is StreamState.ACTIVE:
                stale = now - self._t_setpoint > self.config.setpoint_timeout_s
                if stale:
                    sp = ZERO_SETPOINT
                    self._counts["stale_setpoints"] += 1
                    if not self._setpoint_stale:
                        self._event("setpoint_stale", "no fresh setpoint: sending zero", t_s=now)
                self._setpoint_stale = stale
            ts, tc = self._target
            source_t = self._source_t if sp is self._setpoint else None
            first = source_t is not None and source_t != self._sent_source_t
        v, r = sp.v_body, sp.yaw_rate_rad_s
        sent = self._send(
            lambda mav: mav.set_position_target_local_ned_send(
                self._boot_ms(), ts, tc, mv.FRAME_BODY_NED, mv.MASK_VELOCITY_YAW_RATE,
                0.0, 0.0, 0.0, v[0], v[1], v[2], 0.0, 0.0, 0.0, 0.0, r,
            )
        )  # fmt: skip
        if sent:
            self._count("setpoints_sent")
            if source_t is not None:
                age = self._clock() - source_t
                self.setpoint_ages_s.append(age)
                if first:
                    with self._cond:
                        self._sent_source_t = source_t
                    self.frame_to_wire_s.append(age)

    # --- public state ---------------------------------------------------------------------------
    # --- setpoints ------------------------------------------------------------------------------
    def stop_streaming(self, reason: str = "requested") -> None:
        with self._cond:
            self._stop_stream_locked(self._clock(), reason)

    def _stop_stream_locked(self, now: float, reason: str) -> None:
        if self._stream is not StreamState.IDLE:
            self._stream = StreamState.IDLE
            self._event("stream_stopped", reason, t_s=now)

    # --- commands -------------------------------------------------------------------------------
    def _require_target(self) -> tuple[int, int]:
        if self._target is None:
            raise LinkError("not connected")
        return self._target

    def _command(self, command: int, *params: float) -> tuple[int | None, int]:
        """COMMAND_LONG with re-sends until an ACK: (MAV_RESULT or ``None``, commands sent)."""
        ts, tc = self._require_target()
        p = [float(x) for x in params] + [0.0] * (7 - len(params))
        sends = 0
        for confirmation in range(self.config.command_sends):
            with self._cond:
                self._acks.pop(command, None)
            self._send(lambda mav, k=confirmation: mav.command_long_send(ts, tc, command, k, *p))
            sends += 1
            result = self._wait_ack(command)
            if result is not None:
                return result, sends
            if self._stop.is_set():
                break
        return None, sends

    def _wait_ack(self, command: int) -> int | None:
        """Wait for the ACK of ``command``; IN_PROGRESS extends the wait for the final one."""
        deadline = self._clock() + self.config.ack_timeout_s
        with self._cond:
            while True:
                left = deadline - self._clock()
                got = self._cond.wait_for(lambda: command in self._acks, max(0.0, left))
                if not got:
                    return None
                result = self._acks.pop(command)
                if result != mv.RESULT_IN_PROGRESS:
                    return result
                deadline = self._clock() + 5.0 * self.config.ack_timeout_s

    def _command_attempt(self, command: int, *params: float) -> Attempt:
        result, sends = self._command(command, *params)
        ok = result == mv.RESULT_ACCEPTED
        return Attempt(ok, result, sends, "" if ok else result_name(result), retryable(result))

    # --- actions --------------------------------------------------------------------------------
    def request_streams(self, rates_hz: Mapping[str, float] | None = None) -> ActionResult:
        """SET_MESSAGE_INTERVAL per message; REQUEST_DATA_STREAM for any refused or unanswered;
        then wait until attitude, local position (and SYS_STATUS, if requested) arrive."""
        return self._request_streams(rates_hz, need_velocity=True)

    def _request_streams(
        self, rates_hz: Mapping[str, float] | None, need_velocity: bool
    ) -> ActionResult:
        rates = dict(self.config.stream_rates_hz if rates_hz is None else rates_hz)
        t0 = self._clock()
        sends, refused, last = 0, [], None
        for name, hz in rates.items():
            msg_id = getattr(mavutil.mavlink, f"MAVLINK_MSG_ID_{name}", None)
            if msg_id is None or not (math.isfinite(hz) and hz > 0.0):
                return self._result(
                    "request_streams", Attempt(False, None, 0, f"bad stream {name}={hz}"), 0, t0
                )
            last, n = self._command(mv.CMD_SET_MESSAGE_INTERVAL, msg_id, 1e6 / hz)
            sends += n
            if last != mv.RESULT_ACCEPTED:
                refused.append(name)
        groups, ungrouped = stream_groups(refused, rates)
        if groups:
            ts, tc = self._require_target()
            for g, rate in groups.items():
                self._send(lambda mav, g=g, r=rate: mav.request_data_stream_send(ts, tc, g, r, 1))
        need_status = "SYS_STATUS" in rates

        def arrived(s: TelemetryState) -> bool:
            status = s.t_sys_status_s >= t0 or not need_status
            velocity = s.t_velocity_s >= t0 or not need_velocity
            return s.t_attitude_s >= t0 and velocity and status

        got = self._wait_state(arrived, 5.0 * self.config.ack_timeout_s)
        detail = f"fallback REQUEST_DATA_STREAM for {refused}" if refused else ""
        if ungrouped:
            detail += f" ({', '.join(ungrouped)}: in no stream group, not requested)"
        if not got:
            with self._cond:
                st = self._state
                missing = ", ".join(
                    name
                    for name, t, needed in (
                        ("ATTITUDE", st.t_attitude_s, True),
                        ("LOCAL_POSITION_NED", st.t_velocity_s, need_velocity),
                        ("SYS_STATUS", st.t_sys_status_s, need_status),
                    )
                    if needed and t < t0
                )
            missing = f"{missing or 'telemetry'} not received"
            detail = (detail + "; " if detail else "") + missing
        return self._result("request_streams", Attempt(got, last, sends, detail), sends, t0)

    def wait_ready(self, timeout_s: float = 60.0) -> ActionResult:
        """Wait until the pre-arm bit is healthy, position/velocity is streaming and the landed
        state is known; then
        re-apply a mode that was accepted during boot and reverted when the boot ended."""
        t0 = self._clock()
        stale = self.config.stale_after_s

        def ready(s: TelemetryState) -> bool:
            fresh = self._clock() - s.t_velocity_s <= stale
            return s.ready and fresh and s.landed_state != mv.LANDED_UNDEFINED

        ok = self._wait_state(ready, timeout_s)
        with self._cond:
            seen = self._state.sys_status_seen
            pending = self._provisional_mode
        if not ok:
            why = "pre-arm checks not passing" if seen else "no SYS_STATUS received"
            if self._state.ready:
                why = "no fresh LOCAL_POSITION_NED or no EXTENDED_SYS_STATE"
            return self._result("wait_ready", Attempt(False, None, 0, why), 0, t0)
        detail = ""
        if pending is not None:
            self._wait_state(lambda s: s.mode != pending, self.config.mode_settle_s)
            with self._cond:
                self._provisional_mode = None
                current = self._state.mode
            if current != pending:
                res = self.set_mode(pending, timeout_s=max(0.0, timeout_s - (self._clock() - t0)))
                detail = f"re-applied {pending} (reverted to {current} at boot end): {res.ok}"
                if not res.ok:
                    return self._result("wait_ready", Attempt(False, res.result, 0, detail), 0, t0)
        return self._result("wait_ready", Attempt(True, None, 0, detail), 0, t0)

    def set_mode(self, mode: str, timeout_s: float | None = None) -> ActionResult:
        """DO_SET_MODE with retries; done when the heartbeat shows ``mode`` for ``mode_settle_s``."""
        self._require_target()
        assert self.flavour is not None
        try:
            params = mode_command_params(self.flavour, mode)
        except ValueError as exc:
            return self._result("set_mode", Attempt(False, None, 0, str(exc)), 0, self._clock())
        return self._retry(f"set_mode {mode}", lambda: self._mode_attempt(mode, params), timeout_s)

    def _mode_attempt(self, mode: str, params: tuple[float, float, float]) -> Attempt:
        result: int | None = mv.RESULT_ACCEPTED
        sends = 0
        if self._state.mode != mode:
            result, sends = self._command(mv.CMD_DO_SET_MODE, *params)
            if result != mv.RESULT_ACCEPTED:
                return Attempt(False, result, sends, result_name(result), retryable(result))
            if not self._wait_state(lambda s: s.mode == mode, HEARTBEAT_WAIT_S):
                return Attempt(False, result, sends, "accepted but heartbeat never showed it", True)
        with self._cond:
            booting = not self._state.ready  # (not yet known counts as booting)
            # accepted before the estimator is ready: the autopilot may revert it at boot end
            self._provisional_mode = mode if booting else None
        if self._wait_state(lambda s: s.mode != mode, self.config.mode_settle_s):
            # a boot-time revert is worth another try; anything else is someone else's decision
            return Attempt(False, result, sends, f"changed to {self._state.mode}", booting)
        return Attempt(True, result, sends)

    def arm(self, timeout_s: float | None = None) -> ActionResult:
        """Arm (retrying while the autopilot refuses, e.g. during estimator warm-up)."""

        def attempt() -> Attempt:
            if self._state.armed:
                return Attempt(True, None, 0, "already armed")
            a = self._command_attempt(mv.CMD_COMPONENT_ARM_DISARM, 1.0)
            if a.ok and not self._wait_state(lambda s: s.armed, HEARTBEAT_WAIT_S):
                return Attempt(False, a.result, a.sends, "accepted but not armed", True)
            return a

        self._require_target()
        return self._retry("arm", attempt, timeout_s)

    def disarm(self, force: bool = False, timeout_s: float | None = None) -> ActionResult:
        """Disarm (``force`` also in the air: the vehicle falls). No retries: a refusal
        (not landed) will not change by waiting."""
        self._require_target()
        self.stop_streaming("disarm")
        t0 = self._clock()
        if not self._state.armed:
            return self._result("disarm", Attempt(True, None, 0, "already disarmed"), 0, t0)
        magic = float(mv.FORCE_DISARM_MAGIC) if force else 0.0
        a = self._command_attempt(mv.CMD_COMPONENT_ARM_DISARM, 0.0, magic)
        if a.ok and not self._wait_state(lambda s: not s.armed, timeout_s or HEARTBEAT_WAIT_S):
            a = Attempt(False, a.result, a.sends, "accepted but still armed")
        return self._result("disarm", a, a.sends, t0)

    def takeoff(
        self, altitude_m: float, wait: bool = True, timeout_s: float | None = None
    ) -> ActionResult:
        """Climb to ``altitude_m`` above the local origin; with ``wait``, return when the climb
        is over (landed state IN_AIR and the altitude reached). PX4: ``MIS_TAKEOFF_ALT`` is set
        first; ArduPilot: switches to GUIDED first. The vehicle must be armed."""
        t0 = self._clock()
        self._require_target()
        if not (math.isfinite(altitude_m) and altitude_m > 0.0):
            return self._result(
                "takeoff", Attempt(False, None, 0, f"bad altitude {altitude_m}"), 0, t0
            )
        if not self._state.armed:
            return self._result("takeoff", Attempt(False, None, 0, "not armed"), 0, t0)
        if self.flavour is Flavour.PX4:
            if not self._set_param("MIS_TAKEOFF_ALT", altitude_m):  # never climb to a guess
                why = "MIS_TAKEOFF_ALT not confirmed (no PARAM_VALUE echo)"
                return self._result("takeoff", Attempt(False, None, 0, why), 0, t0)
            nan = math.nan
            res = self._retry(
                "takeoff",
                lambda: self._command_attempt(
                    mv.CMD_NAV_TAKEOFF, nan, nan, nan, nan, nan, nan, nan
                ),
                timeout_s,
            )
        else:
            guided = self.set_mode("GUIDED", timeout_s)
            if not guided.ok:
                return self._result(
                    "takeoff",
                    Attempt(False, guided.result, guided.attempts, f"GUIDED: {guided.detail}"),
                    guided.attempts,
                    t0,
                )
            res = self._retry(
                "takeoff",
                lambda: self._command_attempt(mv.CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, altitude_m),
                timeout_s,
            )
        if not res.ok or not wait:
            return res
        climb_s = altitude_m / 0.5 + 10.0 if timeout_s is None else timeout_s
        done = self._wait_state(lambda s: climb_done(s, altitude_m), climb_s)
        detail = "" if done else f"climb not finished within {climb_s:.1f} s"
        return self._result("takeoff", Attempt(done, res.result, 0, detail), res.attempts, t0)

    def _set_param(self, name: str, value: float) -> bool:
        """PARAM_SET (REAL32) and wait for the PARAM_VALUE echo."""
        ts, tc = self._require_target()
        for _ in range(self.config.command_sends):
            with self._cond:
                self._params.pop(name, None)
            self._send(lambda mav: mav.param_set_send(ts, tc, name.encode(), float(value), 9))
            with self._cond:
                if self._cond.wait_for(lambda: name in self._params, self.config.ack_timeout_s):
                    return abs(self._params[name] - value) < 1e-4 * max(1.0, abs(value))
        return False

    def land(self, wait: bool = False, timeout_s: float | None = None) -> ActionResult:
        """NAV_LAND (stops the stream); with ``wait``, return once on the ground."""
        self._require_target()
        self.stop_streaming("land")
        t0 = self._clock()
        res = self._retry("land", lambda: self._command_attempt(mv.CMD_NAV_LAND), timeout_s)
        if not res.ok or not wait:
            return res
        done = self._wait_state(
            lambda s: s.landed_state == mv.LANDED_ON_GROUND or not s.armed,
            60.0 if timeout_s is None else timeout_s,
        )
        detail = "" if done else "still in the air"
        return self._result("land", Attempt(done, res.result, 0, detail), res.attempts, t0)

    def hold(self, timeout_s: float | None = None) -> ActionResult:
        """Stop the stream and switch to the flavour's position-hold mode."""
        self._require_target()
        self.stop_streaming("hold")
        assert self.flavour is not None
        return self.set_mode(HOLD_MODE[self.flavour], timeout_s)

    def start_velocity_control(self, timeout_s: float | None = None) -> ActionResult:
        """Enter OFFBOARD (PX4, after priming the stream) or GUIDED (ArduPilot, after the takeoff
        climb has finished) and stream setpoints (zero until :meth:`set_setpoint`)."""
        t0 = self._clock()
        self._require_target()
        assert self.flavour is not None
        control = CONTROL_MODE[self.flavour]
        if not self._state.armed:
            return self._result(
                "start_velocity_control", Attempt(False, None, 0, "not armed"), 0, t0
            )
        if self.flavour is Flavour.ARDUPILOT:
            # velocity targets are ignored while a takeoff climbs: wait for it to end
            airborne = self._wait_state(
                lambda s: s.landed_state == mv.LANDED_IN_AIR,
                30.0 if timeout_s is None else timeout_s,
            )
            if not airborne:
                why = f"not in the air (landed state {self._state.landed_state})"
                return self._result("start_velocity_control", Attempt(False, None, 0, why), 0, t0)
        with self._cond:
            self._setpoint, self._t_setpoint = ZERO_SETPOINT, self._clock()
            self._stream = StreamState.PRIMING
        if self.flavour is Flavour.PX4:
            self._stop.wait(PRIME_S)
        res = self.set_mode(control, timeout_s)
        with self._cond:
            if res.ok and self._stream is StreamState.PRIMING:
                self._stream = StreamState.ACTIVE
                self._event("stream_started", control)
            elif not res.ok:
                self._stop_stream_locked(self._clock(), f"{control} refused: {res.detail}")
            ok = self._stream is StreamState.ACTIVE
        a = Attempt(ok, res.result, 0, res.detail if ok else res.detail or "stream stopped")
        return self._result("start_velocity_control", a, res.attempts, t0)
