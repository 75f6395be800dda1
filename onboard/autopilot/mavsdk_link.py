"""The autopilot link through MAVSDK v4 (``mavsdk`` 4.x: the native ctypes binding, no server).

The same :class:`~onboard.autopilot.base.AutopilotLink` as the pymavlink backend, built on
MAVSDK's blocking plugin calls (``Action``, ``Offboard``, ``Telemetry``) instead of raw messages:

* telemetry comes from MAVSDK subscriptions (attitude, body rates, position/velocity NED, landed
  state, battery, health, status text), whose callbacks run on MAVSDK's threads and write into one
  :class:`~onboard.autopilot.states.TelemetryState` under a lock; the HEARTBEAT itself is read
  through ``MavlinkDirect``, so mode names, the armed flag and the heartbeat age mean exactly what
  they mean in the pymavlink backend;
* actions map MAVSDK's result enums to MAV_RESULT codes and retry with the same backoff
  (:func:`~onboard.autopilot.states.retry_loop`); MAVSDK itself re-sends each command;
* velocity control: MAVSDK streams the last ``Offboard.set_velocity_body`` at its own fixed 20 Hz
  (``LinkConfig.rate_hz`` does not apply); :meth:`set_setpoint` updates it. A watchdog thread at
  ``rate_hz`` replaces a stale setpoint by zero and stops the stream when the heartbeat leaves
  OFFBOARD. Stopping destroys the ``Offboard`` plugin (which ends MAVSDK's sender) without
  commanding a mode, so a pilot's mode choice is never overridden and PX4 fails safe on its own.

What MAVSDK hides: the parser's bad-CRC and foreign-system counts (the counters stay 0).
Streams: PX4 sends MAVSDK what it needs unasked, ArduPilot sends nothing until asked and MAVSDK
does not ask, so for an ArduPilot :meth:`connect` and :meth:`request_streams` send
SET_MESSAGE_INTERVAL for :attr:`LinkConfig.stream_rates_hz` through ``MavlinkDirect``, as the
pymavlink backend does. Tested against both simulated flavours: PX4 (OFFBOARD) and ArduPilot
(GUIDED), and ArduCopter SITL.
"""

from __future__ import annotations

import errno
import json
import math
import socket
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

from messages import mavlink as mv
from onboard.autopilot.base import (
    ActionResult,
    Flavour,
    LinkConfig,
    LinkError,
    LinkEvent,
    StreamState,
    serial_device,
    wrong_system_message,
)
from onboard.autopilot.bookkeeping import ZERO_SETPOINT, LinkBookkeeping
from onboard.autopilot.states import (
    CONTROL_MODE,
    TELEMETRY_LIMITS,
    Attempt,
    Saturated,
    TelemetryState,
    climb_done,
    flavour_from_autopilot,
    plausible,
)

HEARTBEAT_WAIT_S = 2.5

# MAVSDK ActionResult / OffboardResult names -> (MAV_RESULT or None for timeout, worth a retry)
_MAVSDK_RESULTS: dict[str, tuple[int | None, bool]] = {
    "SUCCESS": (mv.RESULT_ACCEPTED, False),
    "BUSY": (mv.RESULT_TEMPORARILY_REJECTED, True),
    "COMMAND_DENIED": (mv.RESULT_DENIED, True),
    "COMMAND_DENIED_LANDED_STATE_UNKNOWN": (mv.RESULT_DENIED, True),
    "COMMAND_DENIED_NOT_LANDED": (mv.RESULT_DENIED, False),
    "TIMEOUT": (None, True),
    "FAILED": (mv.RESULT_FAILED, True),
    "UNSUPPORTED": (mv.RESULT_UNSUPPORTED, False),
}


_LISTENING = {"udpin": socket.SOCK_DGRAM, "tcpin": socket.SOCK_STREAM}


def open_failure_cause(murl: str, result_name: str) -> Exception:
    """Why MAVSDK's ``add_any_connection(murl)`` returned ``result_name`` (it says only its
    enum name): the error a retry loop can classify (:func:`messages.fatal.is_permanent`).

    ``CONNECTION_URL_INVALID`` is a :class:`ValueError` (permanent). A ``BIND_ERROR`` or
    ``SOCKET_ERROR`` on a listening URL (``udpin://HOST:PORT``, ``tcpin://``) is the
    :class:`OSError` of binding that address ourselves, with its errno (a port another process
    holds: ``EADDRINUSE``, permanent); anything else is a :class:`ConnectionError` (retried)."""
    if result_name == "CONNECTION_URL_INVALID":
        return ValueError(f"MAVSDK rejected the connection URL {murl!r}")
    scheme, _, rest = murl.partition("://")
    if result_name in ("BIND_ERROR", "SOCKET_ERROR") and scheme in _LISTENING:
        host, _, port = rest.rpartition(":")
        try:
            addr = (host or "0.0.0.0", int(port))
            probe = socket.socket(socket.AF_INET, _LISTENING[scheme])
        except (ValueError, OSError) as exc:
            return exc
        try:
            probe.bind(addr)
        except OSError as exc:
            return exc
        finally:
            probe.close()
        return OSError(errno.EAGAIN, f"{result_name} but {host}:{port} binds now")
    return ConnectionError(result_name)


def mavsdk_url(url: str) -> str:
    """pymavlink-style ``udpin:HOST:PORT`` / ``udpout:`` / ``tcp:`` / serial -> MAVSDK URL."""
    if "://" in url:
        return url
    serial = serial_device(url)
    if serial is not None:
        return f"serial://{serial[0]}:{serial[1]}"
    scheme, _, rest = url.partition(":")
    if scheme in ("udpin", "udpout"):
        return f"{scheme}://{rest}"
    if scheme in ("tcp", "tcpout"):
        return f"tcpout://{rest}"
    if scheme == "tcpin":
        return f"tcpin://{rest}"
    raise ValueError(f"cannot translate {url!r} to a MAVSDK connection URL")


def map_result(name: str) -> tuple[int | None, bool]:
    """MAVSDK result name -> (MAV_RESULT, ``None`` for a timeout; worth retrying)."""
    return _MAVSDK_RESULTS.get(name, (mv.RESULT_FAILED, False))


MAVSDK_CANNOT_SIGN = (
    "the mavsdk backend cannot sign MAVLink 2 (MAVSDK-Python 4.x has no signing API), and "
    'this fleet requires signing ([security] dir): use [mavlink] backend = "pymavlink"'
)


class MavsdkLink(LinkBookkeeping):
    """:class:`~onboard.autopilot.base.AutopilotLink` over MAVSDK v4 (module docstring)."""

    def __init__(self, config: LinkConfig | None = None) -> None:
        super().__init__(config)
        if self.config.signing_key is not None:
            raise LinkError(MAVSDK_CANNOT_SIGN)
        self._sent_setpoint: Saturated | None = None
        self._stop_request: str | None = None
        self._thread: threading.Thread | None = None
        self._mavsdk: Any = None
        self._system: Any = None
        self._plugins: dict[str, Any] = {}
        self._offboard: Any = None
        self._system_id: int | None = None

    def _find_autopilot(self, timeout_s: float) -> tuple[Any, set[int]]:
        """The autopilot of ``config.system_id`` (any, if ``None``) and the other autopilot
        systems heard meanwhile."""
        wanted = self.config.system_id
        if wanted is None:
            return self._mavsdk.first_autopilot(timeout_s), set()
        deadline = time.monotonic() + timeout_s
        others: set[int] = set()
        while True:
            for system in self._mavsdk.get_systems():
                if not system.has_autopilot():
                    continue
                if int(system.get_system_id()) == wanted:
                    return system, others
                others.add(int(system.get_system_id()))
            if time.monotonic() >= deadline:
                return None, others
            time.sleep(0.05)

    # --- identity -------------------------------------------------------------------------------
    @property
    def flavour(self) -> Flavour | None:
        return self._state.flavour

    @property
    def target_system(self) -> int | None:
        return self._system_id

    # --- connection -----------------------------------------------------------------------------
    def connect(self, url: str, timeout_s: float = 10.0) -> None:
        """Open ``url`` (pymavlink or MAVSDK syntax) and wait for the first autopilot."""
        from mavsdk import ComponentType, Configuration, ConnectionResult, Mavsdk
        from mavsdk.plugins.action import Action
        from mavsdk.plugins.mavlink_direct import MavlinkDirect
        from mavsdk.plugins.telemetry import Telemetry as MavsdkTelemetry

        if self._mavsdk is not None:
            raise LinkError("already connected")
        with self._cond:  # a retry after a failed attempt starts afresh (see PymavlinkLink)
            self._stop.clear()
            self._state = TelemetryState()
            self._stream = StreamState.IDLE
            self._system_id = None
            self._stop_request = None
        try:
            murl = mavsdk_url(url)
        except ValueError as exc:
            raise LinkError(str(exc)) from exc
        cfg = Configuration.create_with_component_type(ComponentType.COMPANION_COMPUTER)
        self._mavsdk = Mavsdk(cfg)
        result = self._mavsdk.add_any_connection(murl)
        if result != ConnectionResult.SUCCESS:
            self.close()
            cause = open_failure_cause(murl, result.name)
            raise LinkError(f"cannot open {murl!r}: {result.name} ({cause})") from cause
        system, others = self._find_autopilot(timeout_s)
        if system is None:
            self.close()
            if others and self.config.system_id is not None:
                raise LinkError(
                    wrong_system_message(murl, self.config.system_id, others, timeout_s)
                )
            raise LinkError(f"no autopilot heartbeat on {murl!r} within {timeout_s} s")
        self._system = system
        self._system_id = int(system.get_system_id())
        self._plugins = {
            "telemetry": MavsdkTelemetry(system),
            "action": Action(system),
            "direct": MavlinkDirect(system),
        }
        self._subscribe()
        with self._cond:
            heard = self._cond.wait_for(lambda: self._state.flavour is not None, timeout_s)
        if not heard:
            self.close()
            raise LinkError("autopilot heartbeat not understood (not PX4 or ArduPilot)")
        self._event("connected", f"system {self._system_id} ({self.flavour.value})")  # type: ignore[union-attr]
        self._thread = threading.Thread(target=self._watchdog, name="mavsdk-watchdog", daemon=True)
        self._thread.start()
        if self.flavour is Flavour.ARDUPILOT:
            sent = self._set_intervals(self.config.stream_rates_hz)
            if sent.detail:
                self._event("streams_pending", sent.detail)

    def _subscribe(self) -> None:
        tel = self._plugins["telemetry"]
        tel.subscribe_attitude_euler(self._guard(self._on_attitude))
        tel.subscribe_attitude_angular_velocity_body(self._guard(self._on_rates))
        tel.subscribe_position_velocity_ned(self._guard(self._on_position_velocity))
        tel.subscribe_landed_state(self._guard(self._on_landed))
        tel.subscribe_battery(self._guard(self._on_battery))
        tel.subscribe_health(self._guard(self._on_health))
        tel.subscribe_status_text(self._guard(self._on_status_text))
        self._plugins["direct"].subscribe_message("HEARTBEAT", self._guard(self._on_heartbeat))

    def _guard(self, fn: Callable[[Any], None]) -> Callable[..., None]:
        """Wrap a MAVSDK callback: count it, drop (and count) what it cannot digest."""

        def callback(data: Any, _user_data: Any = None) -> None:
            try:
                with self._cond:
                    fn(data)
                    self._counts["received"] += 1
                    self._cond.notify_all()
            except (ValueError, TypeError, KeyError, AttributeError):
                with self._cond:
                    self._counts["invalid_values"] += 1

        return callback

    # --- MAVSDK callbacks (run on MAVSDK threads, under the lock) ----------------------------
    def _on_heartbeat(self, msg: Any) -> None:
        if int(msg.system_id) != self._system_id or int(msg.component_id) != 1:
            self._counts["foreign"] += 1
            return
        f = json.loads(msg.fields_json)
        st = self._state
        if st.flavour is None:
            st.flavour = flavour_from_autopilot(int(f["autopilot"]))
            if st.flavour is None:
                return
        prev_mode, prev_armed = st.mode, st.armed
        st.heartbeat(int(f["base_mode"]), int(f["custom_mode"]), self._clock())
        if st.mode != prev_mode and prev_mode != "UNKNOWN":
            self._event("mode_changed", f"{prev_mode} -> {st.mode}")
        if st.armed != prev_armed:
            self._event("armed" if st.armed else "disarmed", st.mode)
        if self._stream is StreamState.ACTIVE:
            control = CONTROL_MODE[st.flavour]
            if st.mode != control:
                self._request_stop(f"vehicle left {control}: now {st.mode}")
            elif not st.armed:
                self._request_stop("vehicle disarmed")

    def _on_attitude(self, a: Any) -> None:
        roll, pitch, yaw = (math.radians(x) for x in (a.roll_deg, a.pitch_deg, a.yaw_deg))
        if not all(math.isfinite(x) for x in (roll, pitch, yaw)):
            raise ValueError("non-finite attitude")
        self._require_plausible("ATTITUDE", {"roll": roll, "pitch": pitch, "yaw": yaw})
        st = self._state
        st.roll_rad, st.pitch_rad, st.yaw_rad = roll, pitch, yaw
        st.t_attitude_s = self._clock()
        st.t_boot_s = st.t_boot_attitude_s = a.timestamp_us / 1e6

    def _on_rates(self, w: Any) -> None:
        if not math.isfinite(w.yaw_rad_s):
            raise ValueError("non-finite yaw rate")
        self._require_plausible("ATTITUDE", {"yawspeed": float(w.yaw_rad_s)})
        self._state.yaw_rate_rad_s = float(w.yaw_rad_s)

    def _on_position_velocity(self, pv: Any) -> None:
        v = (pv.velocity.north_m_s, pv.velocity.east_m_s, pv.velocity.down_m_s)
        pos = (pv.position.north_m, pv.position.east_m, pv.position.down_m)
        if not all(math.isfinite(x) for x in (*v, *pos)):
            raise ValueError("non-finite position/velocity")
        names = ("vx", "vy", "vz", "x", "y", "z")
        self._require_plausible("LOCAL_POSITION_NED", dict(zip(names, (*v, *pos), strict=True)))
        st = self._state
        st.v_ned = (float(v[0]), float(v[1]), float(v[2]))
        st.north_m, st.east_m, st.altitude_m = float(pos[0]), float(pos[1]), -float(pos[2])
        st.t_velocity_s = self._clock()

    def _require_plausible(self, kind: str, values: dict[str, float]) -> None:
        """Raise ``ValueError`` (the callback's drop) for values beyond
        :data:`onboard.autopilot.states.TELEMETRY_LIMITS`, remembering when (the daemon holds)."""
        if not plausible(values, TELEMETRY_LIMITS[kind]):
            self._state.implausible_at(self._clock())
            raise ValueError(f"implausible {kind}: {values}")

    def _on_landed(self, landed: Any) -> None:
        self._state.landed_state = int(landed)  # MAVSDK's enum has MAV_LANDED_STATE's values

    def _on_battery(self, b: Any) -> None:
        if math.isfinite(b.remaining_percent):
            self._state.battery_remaining_pct = float(b.remaining_percent)
        if math.isfinite(b.voltage_v):
            self._state.battery_voltage_v = float(b.voltage_v)

    def _on_health(self, h: Any) -> None:
        st = self._state
        st.sys_status_seen = True
        st.ready = bool(h.is_armable)
        st.t_sys_status_s = self._clock()

    def _on_status_text(self, s: Any) -> None:
        self._state.statustext(int(s.type), str(s.text), self._clock())
        self._event("statustext", str(s.text))

    # --- watchdog thread ------------------------------------------------------------------------
    def _watchdog(self) -> None:
        """Stale-setpoint replacement, stream stops requested by callbacks, link loss."""
        lost = False
        period = 1.0 / self.config.rate_hz
        while not self._stop.wait(period):
            now = self._clock()
            with self._cond:
                reason, self._stop_request = self._stop_request, None
                hb_age = now - self._state.t_heartbeat_s
                sp: Saturated | None = None
                if self._stream is StreamState.ACTIVE:
                    sp = self._setpoint
                    if now - self._t_setpoint > self.config.setpoint_timeout_s:
                        sp = ZERO_SETPOINT
                        self._counts["stale_setpoints"] += 1
            if reason is not None:
                self._end_stream(reason)
            elif sp is not None and sp != self._sent_setpoint:
                self._push_setpoint(sp)
            if hb_age > self.config.heartbeat_timeout_s and not lost:
                lost = True
                self._event("link_lost", "no heartbeat")
            elif hb_age <= self.config.heartbeat_timeout_s and lost:
                lost = False
                self._event("link_restored", "heartbeat back")

    def _request_stop(self, reason: str) -> None:
        """From a MAVSDK callback: stop at once in our state, destroy the plugin in the
        watchdog (a MAVSDK call inside a MAVSDK callback could deadlock)."""
        if self._stream is not StreamState.IDLE:
            self._stream = StreamState.IDLE
            self._stop_request = reason

    def _end_stream(self, reason: str) -> None:
        with self._cond:
            off, self._offboard = self._offboard, None
            self._sent_setpoint = None
        if off is not None:
            off.destroy()  # ends MAVSDK's 20 Hz sender without commanding a mode
        self._event("stream_stopped", reason)

    def _on_setpoint(self, sat: Saturated) -> None:
        self._push_setpoint(sat)

    def _push_setpoint(self, sp: Saturated) -> None:
        from mavsdk.plugins.offboard import OffboardError, VelocityBodyYawspeed

        off = self._offboard
        if off is None:
            return
        v, r = sp.v_body, sp.yaw_rate_rad_s
        try:
            off.set_velocity_body(VelocityBodyYawspeed(v[0], v[1], v[2], math.degrees(r)))
            self._sent_setpoint = sp
            self._count("setpoints_sent")
        except OffboardError:
            self._count("link_errors")

    # --- public state ---------------------------------------------------------------------------
    def stop_streaming(self, reason: str = "requested") -> None:
        with self._cond:
            was = self._stream
            self._stream = StreamState.IDLE
        if was is not StreamState.IDLE:
            self._end_stream(reason)

    # --- actions --------------------------------------------------------------------------------
    def _call(self, fn: Callable[[], Any]) -> Attempt:
        """One blocking MAVSDK call as an :class:`Attempt`."""
        from mavsdk import MavsdkError

        try:
            fn()
        except MavsdkError as exc:
            name = getattr(getattr(exc, "result", None), "name", "FAILED")
            result, retry = map_result(name)
            return Attempt(False, result, 1, name, retry)
        return Attempt(True, mv.RESULT_ACCEPTED, 1)

    def _require(self) -> Any:
        if self._system is None:
            raise LinkError("not connected")
        return self._plugins["action"]

    def request_streams(self, rates_hz: Mapping[str, float] | None = None) -> ActionResult:
        """ArduPilot: SET_MESSAGE_INTERVAL per message (MAVSDK does not ask; module docstring);
        PX4 streams by itself. Then wait until attitude and velocity arrive."""
        self._require()
        t0 = self._clock()
        sent = Attempt(True, None, 0)
        if self.flavour is Flavour.ARDUPILOT:
            sent = self._set_intervals(
                self.config.stream_rates_hz if rates_hz is None else rates_hz
            )
        got = self._wait_state(
            lambda s: s.t_attitude_s > -math.inf and s.t_velocity_s > -math.inf,
            5.0 * self.config.ack_timeout_s,
        )
        detail = "; ".join(
            x for x in (sent.detail, "" if got else "attitude/velocity not received") if x
        )
        return self._result(
            "request_streams", Attempt(got, sent.result, sent.sends, detail), sent.sends, t0
        )

    def _set_intervals(self, rates_hz: Mapping[str, float]) -> Attempt:
        """One SET_MESSAGE_INTERVAL command per stream (MavlinkDirect waits for each ACK);
        ``ok`` when every one was accepted, ``detail`` names the others."""
        from mavsdk.plugins.mavlink_direct import MavlinkDirectError, MavlinkMessage
        from pymavlink.dialects.v20 import ardupilotmega as dialect

        direct = self._plugins["direct"]
        refused: list[str] = []
        result: int | None = None
        for name, hz in rates_hz.items():
            msg_id = getattr(dialect, f"MAVLINK_MSG_ID_{name}", None)
            if msg_id is None or not (math.isfinite(hz) and hz > 0.0):
                refused.append(f"{name} (bad stream)")
                continue
            fields = {
                "target_system": self._system_id, "target_component": 1,
                "command": mv.CMD_SET_MESSAGE_INTERVAL, "confirmation": 0,
                "param1": float(msg_id), "param2": 1e6 / hz,
                "param3": 0.0, "param4": 0.0, "param5": 0.0, "param6": 0.0, "param7": 0.0,
            }  # fmt: skip
            cmd = MavlinkMessage("COMMAND_LONG", 0, 0, self._system_id, 1, json.dumps(fields))
            try:
                ack = json.loads(direct.send_command(cmd).fields_json)
                result = int(ack["result"])
            except (MavlinkDirectError, ValueError, KeyError, TypeError):
                result = None
            if result != mv.RESULT_ACCEPTED:
                refused.append(name)
        detail = f"SET_MESSAGE_INTERVAL not accepted for {', '.join(refused)}" if refused else ""
        return Attempt(not refused, result, len(rates_hz), detail)

    def wait_ready(self, timeout_s: float = 60.0) -> ActionResult:
        t0 = self._clock()
        ok = self._wait_state(
            lambda s: s.ready and s.landed_state != mv.LANDED_UNDEFINED, timeout_s
        )
        detail = "" if ok else "not armable (health)"
        return self._result("wait_ready", Attempt(ok, None, 0, detail), 0, t0)

    def set_mode(self, mode: str, timeout_s: float | None = None) -> ActionResult:
        """MAVSDK sets modes only through actions: HOLD (``hold``) and OFFBOARD
        (``start_velocity_control``); other modes are refused here."""
        t0 = self._clock()
        if self.flavour is not None and mode == CONTROL_MODE[self.flavour]:
            return self.start_velocity_control(timeout_s)
        if mode in ("AUTO.LOITER", "BRAKE", "LOITER"):
            return self.hold(timeout_s)
        detail = f"MAVSDK backend cannot set mode {mode}"
        return self._result(f"set_mode {mode}", Attempt(False, None, 0, detail), 0, t0)

    def arm(self, timeout_s: float | None = None) -> ActionResult:
        act = self._require()

        def attempt() -> Attempt:
            if self._state.armed:
                return Attempt(True, None, 0, "already armed")
            a = self._call(act.arm)
            if a.ok and not self._wait_state(lambda s: s.armed, HEARTBEAT_WAIT_S):
                return Attempt(False, a.result, 1, "accepted but not armed", True)
            return a

        return self._retry("arm", attempt, timeout_s)

    def disarm(self, force: bool = False, timeout_s: float | None = None) -> ActionResult:
        act = self._require()
        self.stop_streaming("disarm")
        t0 = self._clock()
        a = self._call(act.kill if force else act.disarm)
        if a.ok and not self._wait_state(lambda s: not s.armed, timeout_s or HEARTBEAT_WAIT_S):
            a = Attempt(False, a.result, 1, "accepted but still armed")
        return self._result("disarm", a, a.sends, t0)

    def takeoff(
        self, altitude_m: float, wait: bool = True, timeout_s: float | None = None
    ) -> ActionResult:
        act = self._require()
        t0 = self._clock()
        if not (math.isfinite(altitude_m) and altitude_m > 0.0):
            return self._result(
                "takeoff", Attempt(False, None, 0, f"bad altitude {altitude_m}"), 0, t0
            )
        if not self._state.armed:
            return self._result("takeoff", Attempt(False, None, 0, "not armed"), 0, t0)
        alt = self._call(lambda: act.set_takeoff_altitude(float(altitude_m)))
        if not alt.ok:
            return self._result("takeoff", alt, 1, t0)
        res = self._retry("takeoff", lambda: self._call(act.takeoff), timeout_s)
        if not res.ok or not wait:
            return res
        climb_s = altitude_m / 0.5 + 10.0 if timeout_s is None else timeout_s
        done = self._wait_state(lambda s: climb_done(s, altitude_m), climb_s)
        detail = "" if done else f"climb not finished within {climb_s:.1f} s"
        return self._result("takeoff", Attempt(done, res.result, 0, detail), res.attempts, t0)

    def land(self, wait: bool = False, timeout_s: float | None = None) -> ActionResult:
        act = self._require()
        self.stop_streaming("land")
        t0 = self._clock()
        res = self._retry("land", lambda: self._call(act.land), timeout_s)
        if not res.ok or not wait:
            return res
        done = self._wait_state(
            lambda s: s.landed_state == mv.LANDED_ON_GROUND or not s.armed,
            60.0 if timeout_s is None else timeout_s,
        )
        return self._result(
            "land", Attempt(done, res.result, 0, "" if done else "still in the air"), 1, t0
        )

    def hold(self, timeout_s: float | None = None) -> ActionResult:
        act = self._require()
        self.stop_streaming("hold")
        return self._retry("hold", lambda: self._call(act.hold), timeout_s)

    def start_velocity_control(self, timeout_s: float | None = None) -> ActionResult:
        """Prime MAVSDK's setpoint (zero), ``Offboard.start()`` (MAVSDK streams before it
        switches), confirm OFFBOARD in the heartbeat."""
        from mavsdk.plugins.offboard import Offboard

        self._require()
        t0 = self._clock()
        if not self._state.armed:
            return self._result(
                "start_velocity_control", Attempt(False, None, 0, "not armed"), 0, t0
            )
        assert self.flavour is not None
        control = CONTROL_MODE[self.flavour]
        if self._offboard is None:
            self._offboard = Offboard(self._system)
        with self._cond:
            self._setpoint, self._t_setpoint = ZERO_SETPOINT, self._clock()
            self._stream = StreamState.PRIMING
        self._sent_setpoint = None
        self._push_setpoint(ZERO_SETPOINT)
        off = self._offboard

        def attempt() -> Attempt:
            a = self._call(off.start)
            if a.ok and not self._wait_state(lambda s: s.mode == control, HEARTBEAT_WAIT_S):
                return Attempt(False, a.result, 1, f"heartbeat never showed {control}", True)
            return a

        res = self._retry("start_velocity_control", attempt, timeout_s)
        with self._cond:
            if res.ok and self._stream is StreamState.PRIMING:
                self._stream = StreamState.ACTIVE
                self._events.append(LinkEvent(self._clock(), "stream_started", control))
            ok = self._stream is StreamState.ACTIVE
        if not ok:
            self.stop_streaming(f"{control} refused: {res.detail}")
        return ActionResult(
            res.action, ok, res.result, res.attempts, res.elapsed_s, res.reasons, res.detail
        )

    def close(self) -> None:
        """Stop the stream and the watchdog, destroy MAVSDK (idempotent)."""
        self.stop_streaming("closed")
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        self._thread = None
        for plugin in self._plugins.values():
            plugin.destroy()
        self._plugins = {}
        if self._mavsdk is not None:
            self._mavsdk.destroy()
            self._mavsdk = None
        self._system = None
