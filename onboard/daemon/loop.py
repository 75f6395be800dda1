"""The onboard daemon: one agent core driven by an autopilot link, a bearing source and peers.

Two threads. The **core loop** (the caller's thread) steps the agent core at ``rates.core`` on
the daemon's clock, feeds it only what the vehicle measures (autopilot attitude and body
velocity, its own bearings) and what peers send, publishes its peer messages at
``rates.publish`` and its status at ``rates.status``, and hands the setpoint to the link, which
streams it at ``rates.setpoint``. The **flight thread** runs the slow, blocking autopilot
actions (connect, wait for the estimator, arm, take off, enter OFFBOARD/GUIDED, land) so the
core never stalls behind them.

Safety (docs/design.md): setpoints are saturated by the link; every other rule is a guard
(:mod:`onboard.daemon.guards`): stale inputs (autopilot telemetry, bearings, the clock), a
neighbour's clock that disagrees, a non-finite setpoint or a sensing graph that is no longer
rigid after a peer was lost give zero velocity (hold); the altitude band and the fence bound
the setpoint; a pilot who takes the vehicle out of OFFBOARD/GUIDED gets it, since the link
stops streaming; SIGINT/SIGTERM hold, then exit (or land, if configured).
"""

from __future__ import annotations

import json
import logging
import math
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import msgspec
import numpy as np

from messages.agent import AgentStatus, OwnMeasurements, Setpoint, VehicleStatus
from messages.codec import Payload
from messages.command import FleetCommand, drive_problem, formation_problem
from messages.fatal import PermanentError, is_permanent
from messages.limits import (
    ANGLE_MAX_RAD,
    DIMENSIONLESS_MAX,
    INV_DISTANCE_MAX_INV_M,
    POSITION_MAX_M,
    STAMP_FUTURE_MAX_S,
)
from messages.vocabulary import Alarm, DropReason, DropScope, Phase, drop_key
from onboard.autopilot.base import AutopilotLink, LinkError, Telemetry, signing_rejections
from onboard.autopilot.states import HOLD_MODE
from onboard.control.leader import LeaderPlan
from onboard.core.agent import AgentCore
from onboard.core.config import (
    AgentConfig,
    FormationGains,
    GradientLocalizationGains,
    Graph,
    RigidityGains,
    Safety,
    ScaleGains,
)
from onboard.core.rigidity import estimate_uncertain
from onboard.daemon.bearings import BearingSource, RangeSource
from onboard.daemon.clock import Clock
from onboard.daemon.config import Fleet
from onboard.daemon.guards import (
    PILOT_MODES,
    ZERO_SETPOINT,
    GuardInput,
    daemon_guards,
    decide,
    takeover_kind,
)
from onboard.daemon.lateness import TickLateness
from onboard.daemon.metrics import DaemonMetrics, percentiles_ms
from onboard.daemon.odometry import odometry
from onboard.daemon.peer_clock import PeerClockCheck
from onboard.daemon.peers import DropCounter, PeerLink
from onboard.daemon.presence import PeerPresence
from onboard.daemon.replay import SeqWindow
from onboard.daemon.tape import open_tape, tape_path
from onboard.geometry import bearings_body
from onboard.graph import complete_graph, formation_edges
from onboard.rigidity.bearing import ibr_r3s1

log = logging.getLogger(__name__)

PHASES: tuple[Phase, ...] = tuple(Phase)
"""Every phase (:class:`messages.vocabulary.Phase`, defined there once)."""
STALL_TICK_GAP_S = 1.0
"""A gap between two core ticks this long (wall time) is a stall of the daemon (SIGSTOP, a
frozen machine): the autopilot's offboard-loss failsafe may have acted meanwhile."""
MAX_CORE_DT_S = 0.005
"""Longest integration step given to the core (its gains want <= 5 ms, see sim/runner.py)."""
MIN_TICK_SPEEDUP = 0.05
"""Below this simulation speed the daemon does not slow its ticks further (a stalled clock)."""
MAX_GAP_S = 0.5
"""A longer gap between two ticks is skipped rather than integrated."""
PEER_LOST_HOLD_S = 2.0
"""A peer without a liveliness token, or without a peer payload, for this long is out of the
graph (:mod:`onboard.daemon.presence`: a stalled vehicle keeps its token)."""
FIRST_CONNECT_GRACE_S = 15.0
"""Wall seconds a starting daemon waits for its autopilot's first telemetry before the status
says ``autopilot_lost`` (until then the phase ``connecting`` says it all: the demo's vehicles
each raised the alarm while their simulated autopilots booted). Once connected, a lost link
raises it at once."""
STEP_ERROR_ALARM_S = 1.0
"""After an exception escaped a core tick the vehicle holds with alarm ``step_error`` this long."""


def agent_config(fleet: Fleet, agent_id: int) -> AgentConfig:
    """The core's configuration from the fleet file: graph, planned formation, scaled prior.

    The localization prior is the *planned* formation scaled by ``prior_scale`` about its
    centroid (bearings carry no scale: the estimators must find it), never the simulator's truth.
    """
    f, c = fleet.formation, fleet.config
    r = c.rigidity
    e = formation_edges(f)
    beta, _ = bearings_body(f.p_ned, f.yaw_rad, e)
    centroid = f.p_ned.mean(axis=0)
    prior = centroid + c.prior_scale * (f.p_ned - centroid)
    graph = Graph(
        agent_id=agent_id,
        n_agents=f.n,
        edges=tuple((int(i), int(j)) for i, j in e),
        p_hat0_ned=tuple(tuple(float(x) for x in row) for row in prior),
        yaw_hat0_rad=tuple(float(y) for y in f.yaw_rad),
    )
    formation = FormationGains(
        desired_beta_body=tuple(
            (int(i), int(j), (float(b[0]), float(b[1]), float(b[2])))
            for (i, j), b in zip(e, beta, strict=True)
        ),
        desired_yaw_rad=tuple(float(y) for y in f.yaw_rad),
    )
    rigidity = RigidityGains(
        rigidity_maintenance=r.maintenance,
        rigidity_edges=(
            tuple((int(i), int(j)) for i, j in complete_graph(f.n))
            if r.maintenance and r.graph == "all"
            else ()
        ),
        rigidity_warmup_s=r.warmup_s,
        rigidity_period_s=1.0 / r.rate_hz,
        rigidity_eigen=r.eigen,
        rigidity_scale_from_sfm=r.maintenance,
        fov_deg=r.fov_deg,
        range_m=r.range_m,
        lambda_safe=r.lambda_safe,
        lambda_min=r.lambda_min,
        r_safe_m=r.r_safe_m,
    )
    scale = ScaleGains(
        sfm_bias_speed_m_s=c.sfm.bias_speed_m_s,
        sfm_wander_window_s=c.sfm.wander_window_s,
        sfm_wander_max=c.sfm.wander_max,
        sfm_folds_forget_s=c.sfm.folds_forget_s,
        sfm_bias_gain=c.sfm.bias_gain,
        sfm_bias_max_m_s=c.sfm.bias_max_m_s,
        sfm_team_scale=c.sfm.team_scale,
    )
    safety = Safety(
        v_max_m_s=c.limits.max_speed_m_s, yaw_rate_max_rad_s=c.limits.max_yaw_rate_rad_s
    )
    return AgentConfig(graph=graph, mode=c.mode, safety=safety, scale=scale,
                       formation=formation, rigidity=rigidity,
                       gradloc=GradientLocalizationGains(
                           localization=c.core.localization,
                           gradloc_yaw_from_bearings=c.core.yaw_from_bearings))  # fmt: skip


def _finite_within(x: float | None, limit: float) -> bool:
    return x is not None and math.isfinite(x) and abs(x) <= limit


def publishable_agent_status(a: AgentStatus) -> tuple[AgentStatus, bool]:
    """The core's status made publishable, and whether it was healthy (issue 23: a core with
    NaN estimates published nothing, since the codec refuses NaN, so the ground station saw a
    frozen row, never the cause). Estimates that are non-finite or beyond the physical ranges
    of :mod:`messages.limits` become neutral values: position and yaw 0, no inverse distance,
    ``E`` at its maximum (not converged), ``lambdabar`` 0, no rigidity eigenvalue; the daemon
    adds ``estimate_nonfinite`` to the status's alarms."""
    healthy = (
        all(_finite_within(x, POSITION_MAX_M) for x in a.p_hat_ned)
        and _finite_within(a.yaw_hat_rad, ANGLE_MAX_RAD)
        and all(_finite_within(x, INV_DISTANCE_MAX_INV_M) for x in a.chi_hat_inv_m.values())
        and _finite_within(a.e_index, DIMENSIONLESS_MAX)
        and _finite_within(a.lambda_bar, DIMENSIONLESS_MAX)
        and (
            a.rigidity_eigenvalue is None
            or _finite_within(a.rigidity_eigenvalue, DIMENSIONLESS_MAX)
        )
    )
    if healthy:
        return a, True
    p = tuple(x if _finite_within(x, POSITION_MAX_M) else 0.0 for x in a.p_hat_ned)
    return msgspec.structs.replace(
        a,
        p_hat_ned=p,
        yaw_hat_rad=a.yaw_hat_rad if _finite_within(a.yaw_hat_rad, ANGLE_MAX_RAD) else 0.0,
        chi_hat_inv_m={
            j: x for j, x in a.chi_hat_inv_m.items() if _finite_within(x, INV_DISTANCE_MAX_INV_M)
        },
        e_index=a.e_index if _finite_within(a.e_index, DIMENSIONLESS_MAX) else DIMENSIONLESS_MAX,
        lambda_bar=a.lambda_bar if _finite_within(a.lambda_bar, DIMENSIONLESS_MAX) else 0.0,
        rigidity_eigenvalue=(
            a.rigidity_eigenvalue
            if _finite_within(a.rigidity_eigenvalue, DIMENSIONLESS_MAX)
            else None
        ),
        scale_converged=False,
    ), False


@dataclass
class DaemonState:
    """What the two threads share (guarded by ``lock``)."""

    phase: Phase = Phase.CONNECTING
    detail: str = ""
    lock: threading.Lock = field(default_factory=threading.Lock)

    def set(self, phase: Phase, detail: str = "") -> None:
        with self.lock:
            if phase != self.phase:
                log.info("phase %s -> %s %s", self.phase, phase, detail)
            elif detail != self.detail and detail:  # e.g. why connecting keeps failing
                log.info("phase %s: %s", phase, detail)
            self.phase, self.detail = phase, detail

    def get(self) -> Phase:
        with self.lock:
            return self.phase


class AgentDaemon:
    """One vehicle's daemon (module docstring). Build it, then call :meth:`run`."""

    def __init__(
        self,
        fleet: Fleet,
        agent_id: int,
        link: AutopilotLink,
        peers: PeerLink,
        bearings: BearingSource,
        clock: Clock,
        drops: DropCounter,
        mavlink_url: str,
        on_status: Callable[[VehicleStatus], None] | None = None,
    ) -> None:
        self.fleet = fleet
        self.id = agent_id
        self.link = link
        self.peers = peers
        self.bearings = bearings
        self.clock = clock
        self.drops = drops
        self.url = mavlink_url
        self.on_status = on_status
        self.core = AgentCore(agent_config(fleet, agent_id))
        self.tape = open_tape(tape_path(agent_id), self.core.config)
        """The core's flight recorder (:mod:`onboard.daemon.tape`; None: off)."""
        self.state = DaemonState()
        self.stop_event = threading.Event()
        self._landing = threading.Event()
        self._actions: queue.Queue[tuple[str, FleetCommand | None]] = queue.Queue()
        self._graph_ids = sorted({int(x) for e in self.core.config.graph.edges for x in e})
        # the formation's neighbours, and those only the rigidity layer talks to
        self._neighbours = frozenset(self.core.neighbours) | self.core.rigidity_neighbours
        self._last_core_t: float | None = None
        self.presence = PeerPresence(self._graph_ids, agent_id, PEER_LOST_HOLD_S)
        self._rigid_cache: dict[frozenset[int], bool] = {}
        self._alarms: list[str] = []
        self.lateness = TickLateness()
        self.first_connect_grace_s = FIRST_CONNECT_GRACE_S
        self._was_connected = False
        self.clock_check = PeerClockCheck(behind_tol_s=self.core.config.safety.peer_timeout_s)
        self.seq_window = SeqWindow()
        self._skewed: frozenset[int] = frozenset()
        self._status_seq = 0
        self._formation: tuple[int, int | None] = (0, None)  # (formation_id, leader) flown
        self._formation_name = ""
        self._formation_distances = False
        self._drive_id = 0  # the leader drive taken (0: none)
        self.metrics = DaemonMetrics()
        self._newest_frame_s = -math.inf
        self._frame_link_s: tuple[float, float | None] = (-math.inf, None)
        """(frame stamp, its capture on the link clock), converted once per frame: the link
        tells a new frame's setpoint by a new ``source_t``."""
        self._step_error_s = -math.inf
        self._estimate_healthy = True
        self._stall_mono = -math.inf  # when the core loop last stalled (time.monotonic)
        self._link_lost_t = -math.inf  # when the link last reported link_lost (link clock)
        lim = fleet.config.limits
        self.guards = daemon_guards(
            self._rigid_without,
            stale_s=lim.stale_s,
            step_error_window_s=STEP_ERROR_ALARM_S,
            min_alt_m=lim.min_alt_m,
            max_alt_m=lim.max_alt_m,
            max_radius_m=lim.max_radius_m,
        )

    # ------------------------------------------------------------------ flight thread
    def _flight(self) -> None:
        c = self.fleet.config
        while not self.stop_event.is_set():
            try:
                self.link.connect(self.url, timeout_s=5.0)
                break
            except LinkError as exc:
                if is_permanent(exc):  # e.g. the udpin port is taken: ends the process (issue 23)
                    raise PermanentError(str(exc)) from exc
                self.state.set(Phase.CONNECTING, str(exc))
                self.stop_event.wait(1.0)
        if self.stop_event.is_set():
            return
        self.state.set(Phase.WAITING, "estimator warm-up")
        self.link.request_streams()
        while not self.stop_event.is_set():
            ready = self.link.wait_ready(timeout_s=5.0)
            if ready.ok:
                break
            self.state.set(Phase.WAITING, "; ".join(ready.reasons) or ready.detail)
        self.state.set(Phase.READY)
        if c.auto_start:
            self._actions.put(("takeoff_and_start", None))
        while not self.stop_event.is_set():
            try:
                action, cmd = self._actions.get(timeout=0.2)
            except queue.Empty:
                continue
            ok, detail = self._do(action)
            if cmd is not None:
                self.peers.ack(cmd, ok, detail, self._now() or 0.0)

    def _do(self, action: str) -> tuple[bool, str]:
        """Run one blocking action on the autopilot; returns (accepted, detail)."""
        link, c = self.link, self.fleet.config
        if action in ("takeoff_and_start", "start") and self._landing.is_set():
            return False, "a land or stop command came first: not starting"
        if action == "takeoff_and_start" and link.telemetry().in_air:
            action = "start"  # a restarted daemon rejoins a vehicle that is already flying
        if action == "takeoff_and_start":
            for step in (link.arm, lambda: link.takeoff(c.takeoff_alt_m, wait=True)):
                result = step()
                if not result.ok:
                    detail = f"{result.action}: {result.result_name} {'; '.join(result.reasons)}"
                    self.state.set(Phase.READY, detail)
                    return False, detail
            action = "start"
        if action == "start":
            tel = link.telemetry()
            if not tel.in_air:
                return False, "not in the air: arm and take off first"
            if (
                self.state.get() == Phase.PILOT
                and tel.flavour is not None
                and tel.mode in PILOT_MODES[tel.flavour]
            ):
                return False, (
                    f"a pilot flies the vehicle ({tel.mode}): to hand it back, switch the "
                    f"autopilot to {HOLD_MODE[tel.flavour]}, then start"
                )
            link.set_setpoint(ZERO_SETPOINT)
            result = link.start_velocity_control()
            if not result.ok:
                return False, f"velocity control refused: {result.result_name} {result.detail}"
            self.state.set(Phase.FLYING)
            return True, "flying"
        if action == "hold":
            link.set_setpoint(ZERO_SETPOINT)
            self.state.set(Phase.HOLDING)
            return True, "holding"
        if action in ("land", "stop"):
            link.set_setpoint(ZERO_SETPOINT)
            self.state.set(Phase.LANDING)
            result = link.land()
            link.stop_streaming("landing")
            return result.ok, f"land: {result.result_name}"
        return False, f"unknown action {action!r}"

    # ------------------------------------------------------------------ core loop
    def _now(self) -> float | None:
        return self.clock.now()

    def _handle_commands(self) -> None:
        for cmd in self.peers.commands():
            if cmd.action in ("land", "stop"):
                self._landing.set()  # sticky: no auto-start or start after it
            if cmd.action == "hold" or cmd.action == "stop":
                # act at once on the setpoint, then let the flight thread do the rest
                self.link.set_setpoint(ZERO_SETPOINT)
                if cmd.action == "hold":
                    self.state.set(Phase.HOLDING)
            self._actions.put((cmd.action, cmd))
        self._handle_formation()
        self._handle_drive()

    def _handle_formation(self) -> None:
        """Adopt a new formation change (paper 002's formation changes; counted and dropped if
        the fleet cannot fly it) and log which formation the agent flies now."""
        change = self.peers.formation()
        if change is None or change.formation_id == self._formation[0]:
            return  # the ground station repeats a change until the status shows it
        problem = formation_problem(change, frozenset(range(self.fleet.n)))
        if problem:
            self.drops.drop(DropReason.MALFORMED, problem, DropScope.COMMAND)
            return
        slots = sorted(change.agents, key=lambda a: a.id)
        p_ned = np.array([a.position_ned for a in slots], dtype=float)
        yaw = np.array([a.yaw_rad for a in slots])
        if self.core.adopt_formation(p_ned, yaw, change.leader, change.distances, change.ramp_s):
            self._formation = (change.formation_id, change.leader)
            self._formation_name = change.name
            self._formation_distances = change.distances
            if change.leader != self.id:
                self._drive_id = 0  # a drive is the leader's only
            ramp = (
                self.core.config.formation.change_ramp_s if change.ramp_s is None else change.ramp_s
            )
            role = (" (the leader)" if change.leader == self.id else
                    f", leader {change.leader}" if change.leader is not None else "")  # fmt: skip
            log.info(
                "flying formation %d %r%s: bearings%s, switch over %.1f s",
                change.formation_id, change.name, role,
                " and distances" if change.distances else " only", ramp,
            )  # fmt: skip
        else:
            self.drops.drop(DropReason.FOREIGN, f"mode {self.core.config.mode}: no formation",
                            DropScope.COMMAND)  # fmt: skip

    def _handle_drive(self) -> None:
        """Take a new leader drive (paper 002's leader with an external velocity) if this
        vehicle leads the formation it flies; otherwise count and drop it."""
        drive = self.peers.leader_drive()
        if drive is None or drive.drive_id == self._drive_id:
            return  # repeated until the status shows it
        problem = drive_problem(drive)
        if problem:
            self.drops.drop(DropReason.MALFORMED, problem, DropScope.COMMAND)
            return
        plan = LeaderPlan(
            velocity_ned=drive.velocity_ned,
            duration_s=drive.duration_s,
            waypoints_ned=tuple(drive.waypoints_ned),
            speed_m_s=drive.speed_m_s,
            tolerance_m=drive.tolerance_m,
        )
        stopping = drive.velocity_ned is None and not drive.waypoints_ned
        if not self.core.drive_leader(None if stopping else plan):
            self.drops.drop(
                DropReason.FOREIGN,
                f"leader drive {drive.drive_id}: agent {self.id} does not lead formation "
                f"{self._formation[0]} (leader {self._formation[1]})",
                DropScope.COMMAND,
            )
            return
        self._drive_id = drive.drive_id
        if drive.velocity_ned is not None:
            what = f"velocity {drive.velocity_ned} m/s NED" + (
                f" for {drive.duration_s:g} s" if drive.duration_s is not None else ""
            )
        elif drive.waypoints_ned:
            what = f"{len(drive.waypoints_ned)} waypoints at {drive.speed_m_s:g} m/s"
        else:
            what = "hold"
        log.info("leader drive %d: %s", drive.drive_id, what)

    def _update_peers(self, now_s: float) -> None:
        self.presence.update(self.peers.alive_peers(), now_s)

    def lost_peers(self, now_s: float) -> list[int]:
        """Peers that were seen and have been without a liveliness token, or silent (no peer
        payload), for :data:`PEER_LOST_HOLD_S` or more (:class:`PeerPresence`)."""
        return self.presence.lost(now_s)

    def _rigid_without(self, key: frozenset[int]) -> bool:
        """Is the planned framework still IBR in R^3 x S^1 among the agents that remain?"""
        if key not in self._rigid_cache:
            keep = [k for k in range(self.fleet.n) if k not in key]
            idx = {k: m for m, k in enumerate(keep)}
            edges = np.array(
                [
                    (idx[i], idx[j])
                    for i, j in self.core.config.graph.edges
                    if i in idx and j in idx
                ],
                dtype=np.int64,
            ).reshape(-1, 2)
            f = self.fleet.formation
            self._rigid_cache[key] = bool(
                len(edges)
                and len(keep) >= 2
                and ibr_r3s1(f.p_ned[keep], f.yaw_rad[keep], edges).is_rigid
            )
        return self._rigid_cache[key]

    def _measurements(self, now_s: float, tel: Telemetry) -> OwnMeasurements:
        """The core's own measurements: odometry, and a new camera frame's bearings and ranges
        (the ranges only with the frame they belong to, like its bearings: the core keeps the
        newest per target and uses them while fresh)."""
        frame = self.bearings.poll()
        ranges = (
            self.bearings.frame_ranges()
            if frame is not None and isinstance(self.bearings, RangeSource)
            else ()
        )
        if frame:
            self._newest_frame_s = max(self._newest_frame_s, *(b.stamp_s for b in frame))
            self.metrics.frame_age_s.append(now_s - max(b.stamp_s for b in frame))
        if tel.t_boot_s is not None:
            self.metrics.telemetry_age_s.append(now_s - tel.t_boot_s)
        odo = odometry(tel, now_s, sim=self.fleet.config.clock == "sim")
        p_ned = (tel.north_m, tel.east_m, -tel.altitude_m)  # a driven leader's waypoints
        return OwnMeasurements(
            t_s=now_s,
            yaw_rad=odo.yaw_rad,
            v_body=odo.v_body,
            yaw_rate_rad_s=odo.yaw_rate_rad_s,
            bearings=frame or (),
            ranges=ranges,
            odometry_stamp_s=odo.stamp_s,
            position_ned=p_ned if all(math.isfinite(x) for x in p_ned) else None,
        )

    def _status(self, now_s: float, tel: Telemetry) -> VehicleStatus:
        self._status_seq += 1
        dropped = dict(self.drops.snapshot())
        for reason, count in self.core.dropped.items():
            dropped[drop_key(reason, DropScope.CORE)] = count
        for name, count in signing_rejections(tel.counters).items():
            dropped[f"{DropScope.MAVLINK.value}_{name}"] = count  # a LinkCounters field
        if tel.implausible:
            dropped[drop_key(DropReason.IMPLAUSIBLE, DropScope.MAVLINK)] = tel.implausible
        speed = math.sqrt(sum(v * v for v in tel.v_ned))
        agent, self._estimate_healthy = publishable_agent_status(self.core.status())
        alarms = list(self._alarms)
        if not self._estimate_healthy and Alarm.ESTIMATE_NONFINITE not in alarms:
            alarms.append(Alarm.ESTIMATE_NONFINITE.value)  # the guard holds from the next tick
        unc = agent.rigidity_eigenvalue_uncertainty
        lam = agent.rigidity_eigenvalue
        if unc is not None and lam is not None and estimate_uncertain(lam, unc):
            alarms.append(Alarm.RIGIDITY_UNCERTAIN.value)  # flagged, not trusted
        if self.lateness.late:  # the machine is too slow for this speed (issue 29)
            alarms.append(Alarm.TICKS_LATE.value)
        return VehicleStatus(
            sender=self.id,
            seq=self._status_seq,
            stamp_s=now_s,
            agent=agent,
            autopilot_mode=tel.mode,
            armed=tel.armed,
            in_air=tel.in_air,
            altitude_m=tel.altitude_m if math.isfinite(tel.altitude_m) else 0.0,
            speed_m_s=speed if math.isfinite(speed) else 0.0,
            battery_pct=tel.battery_remaining_pct,
            heartbeat_age_s=min(tel.heartbeat_age_s, 1e6),
            phase=self.state.get(),
            alarms=alarms,
            dropped=dropped,
            formation_id=self._formation[0],
            formation_leader=self._formation[1],
            formation_name=self._formation_name,
            formation_distances=self._formation_distances,
            leader_drive_id=self._drive_id,
        )

    def run(self) -> None:
        """Run until :attr:`stop_event` is set; then hold (or land) and return."""
        c = self.fleet.config
        flight = threading.Thread(target=self._flight, name=f"flight-{self.id}", daemon=True)
        flight.start()
        publish_every = max(1, round(c.rates.core / c.rates.publish))
        status_every = max(1, round(c.rates.core / c.rates.status))
        outbox = []
        step = 0
        next_tick = last_tick_mono = started_mono = time.monotonic()
        while not self.stop_event.is_set():
            next_tick += self._tick_period_s()
            delay = next_tick - time.monotonic()
            if delay > 0:
                time.sleep(delay)
                late_s = max(0.0, time.monotonic() - next_tick)
            else:  # overrun: count how late, do not try to catch up
                late_s = -delay
                next_tick = time.monotonic()
            self.metrics.tick_late_s.append(late_s)
            mono = time.monotonic()
            self.lateness.add(mono, late_s)
            if mono - last_tick_mono > STALL_TICK_GAP_S:
                self._stall_mono = mono
            last_tick_mono = mono
            tel = self.link.telemetry()
            if tel.t_boot_s is not None:
                self.clock.observe(tel.t_boot_s)  # the simulator's autopilot counts sim time
            now_s = self._now()
            if now_s is None:
                continue  # no time yet: nothing can be stamped
            if self._stall_mono == mono:  # we stalled, not our peers: their silence restarts
                self.presence.restart(now_s)
            step += 1
            if not tel.connected:  # the core waits; the ground station still hears why
                waited_s = time.monotonic() - started_mono
                lost = self._was_connected or waited_s > self.first_connect_grace_s
                self._alarms = [Alarm.AUTOPILOT_LOST.value] if lost else []
                if step % status_every == 0:
                    self._publish_status(now_s, tel)
                continue
            self._was_connected = True
            try:
                self._handle_commands()
                self._update_peers(now_s)
                t_step = time.perf_counter()
                setpoint, out = self._step_core(now_s, tel)
                self.metrics.core_step_s.append(time.perf_counter() - t_step)
                outbox.extend(out)
                if step % publish_every == 0:
                    self.peers.publish(outbox)
                    outbox = []
                self._alarms = self._fly(now_s, tel, setpoint)
            except Exception as exc:  # one bad step must never end the daemon (issue 23)
                outbox = []
                self._step_failed(DropReason.STEP_EXCEPTION, now_s, exc)
            if step % status_every == 0:
                self._publish_status(now_s, tel)
        self._shutdown()

    def _publish_status(self, now_s: float, tel: Telemetry) -> None:
        """Publish the status (issue 23: it always goes out, with the reason in its alarms)."""
        try:
            status = self._status(now_s, tel)
            self.peers.publish_status(status)
            if self.on_status is not None:
                self.on_status(status)
        except Exception as exc:
            self._step_failed(DropReason.STATUS_EXCEPTION, now_s, exc)

    def _step_failed(self, reason: DropReason, now_s: float, exc: Exception) -> None:
        """An exception escaped one tick: count it (``dropped``), log the first traceback, hold
        (zero setpoint) and raise the ``step_error`` alarm for :data:`STEP_ERROR_ALARM_S`."""
        if reason not in self.drops.snapshot():
            log.error("%s in the core loop (holding; logged once)", reason, exc_info=exc)
        self.drops.drop(reason, f"{type(exc).__name__}: {exc}")
        self._step_error_s = now_s
        try:
            self.link.set_setpoint(ZERO_SETPOINT)
        except Exception:  # the link itself failed: nothing more to do this tick
            log.debug("zero setpoint after a failed step failed too", exc_info=True)
        if Alarm.STEP_ERROR not in self._alarms:
            self._alarms = [*self._alarms, Alarm.STEP_ERROR]

    def _tick_period_s(self) -> float:
        """Wall seconds between core ticks: the configured rates are per second of the daemon's
        clock, so behind a simulator slower than real time the daemon ticks that much less
        often (six daemons ticking at 100 Hz of wall time saturated two cores at any simulation
        speed). Faster than real time it keeps the wall rate: the tick rate per simulated
        second drops instead."""
        speedup = self.clock.speedup
        return 1.0 / (self.fleet.config.rates.core * min(1.0, max(speedup, MIN_TICK_SPEEDUP)))

    def _step_core(self, now_s: float, tel: Telemetry) -> tuple[Setpoint, list[Payload]]:
        """Step the core to ``now_s`` in sub-steps of at most :data:`MAX_CORE_DT_S`.

        The core integrates its estimators explicitly with the step's ``dt``; a late tick (a
        loaded machine, a stalled clock) must not become one long, unstable Euler step. Longer
        gaps than :data:`MAX_GAP_S` are not integrated: the core jumps (and will re-converge).
        """
        last = self._last_core_t
        self._last_core_t = now_s
        if last is not None and now_s < last - STAMP_FUTURE_MAX_S:
            self._clock_went_back(last, now_s)
        own = self._measurements(now_s, tel)
        inbox = [m for m in self.peers.drain(self._neighbours) if self._admit(m, now_s)]
        for msg in inbox:
            self.clock_check.observe(msg.sender, msg.stamp_s, now_s)
            self.presence.heard(msg.sender, now_s)
        out: list[Payload] = []
        if last is not None and MAX_CORE_DT_S < now_s - last <= MAX_GAP_S:
            n = math.ceil((now_s - last) / MAX_CORE_DT_S)
            quiet = msgspec.structs.replace(own, bearings=(), ranges=())
            for k in range(1, n):
                t_k = last + (now_s - last) * k / n
                _, early = self._core_step(t_k, msgspec.structs.replace(quiet, t_s=t_k), [])
                out.extend(early)
        setpoint, last_out = self._core_step(now_s, own, inbox)
        out.extend(last_out)
        return setpoint, out

    def _core_step(
        self, t_s: float, own: OwnMeasurements, inbox: list[Payload]
    ) -> tuple[Setpoint, list[Payload]]:
        if self.tape is not None:
            self.tape.step(t_s, own, inbox)
        return self.core.step(t_s, own, inbox)

    def _clock_went_back(self, last_s: float, now_s: float) -> None:
        """The daemon's clock went back (a restarted simulator, ``clock_resync``): what the
        daemon keeps by time (peers' loss times, the clock check's windows, the last failed
        tick) would lie in the future and never expire; it starts again. The core does the
        same for its own state (:meth:`onboard.core.agent.AgentCore.step`)."""
        log.warning(
            "clock went back from %.3f to %.3f s: restarting time-keyed state", last_s, now_s
        )
        self.presence.restart(now_s)
        self.clock_check = PeerClockCheck(behind_tol_s=self.core.config.safety.peer_timeout_s)
        self._step_error_s = -math.inf
        self._newest_frame_s = -math.inf

    def _admit(self, msg: Payload, now_s: float) -> bool:
        """The replay check (:mod:`onboard.daemon.replay`): duplicates and out-of-window
        sequence numbers are counted and dropped before anything looks at them."""
        reason = self.seq_window.admit(msg.sender, type(msg), msg.seq, msg.stamp_s, now_s)
        if reason is None:
            return True
        self.drops.drop(reason, f"{type(msg).__name__} seq {msg.seq} from {msg.sender}")
        return reason == DropReason.SEQ_RESYNC

    def _fly(self, now_s: float, tel: Telemetry, setpoint: Setpoint) -> list[str]:
        """Send the setpoint, or zero when a guard holds (:mod:`onboard.daemon.guards`);
        return the active alarms."""
        lost = self.lost_peers(now_s)
        skewed = self._check_peer_clocks(now_s)
        for event in self.link.events():
            if event.kind == "link_lost":
                self._link_lost_t = event.t_s
            if event.kind == "stream_stopped" and self.state.get() == Phase.FLYING:
                kind = takeover_kind(
                    tel.flavour,
                    tel.mode,
                    since_stall_s=time.monotonic() - self._stall_mono,
                    since_link_lost_s=self.link.config.clock() - self._link_lost_t,
                )
                self.state.set(kind, f"{event.detail} ({kind})")
        phase = self.state.get()
        decision = decide(self.guards, self._guard_input(now_s, tel, setpoint, lost, skewed, phase))
        if phase == Phase.FLYING:
            if decision.hold:
                self.link.set_setpoint(ZERO_SETPOINT)
            else:
                self.link.set_setpoint(decision.setpoint, self._frame_link_time(now_s))
        return list(decision.alarms)

    def _guard_input(
        self,
        now_s: float,
        tel: Telemetry,
        setpoint: Setpoint,
        lost: list[int],
        skewed: list[int],
        phase: Phase,
    ) -> GuardInput:
        """What the guards look at this tick."""
        return GuardInput(
            phase=phase,
            setpoint=setpoint,
            lost_peers=tuple(lost),
            skewed_peers=tuple(skewed),
            autopilot_stale=tel.stale,
            bearings_age_s=self.bearings.age_s(now_s),
            step_error_age_s=now_s - self._step_error_s,
            clock_fault=self.clock.fault(),
            estimate_healthy=self._estimate_healthy,
            implausible_telemetry_age_s=tel.implausible_age_s,
            altitude_m=tel.altitude_m,
            north_m=tel.north_m,
            east_m=tel.east_m,
            yaw_rad=tel.yaw_rad,
        )

    def _check_peer_clocks(self, now_s: float) -> list[int]:
        """Neighbours whose clocks disagree with ours (:mod:`onboard.daemon.peer_clock`): their
        data would corrupt the estimates without a sign, so the vehicle holds. Logged on change."""
        skewed = self.clock_check.skewed(now_s)
        now_skewed = frozenset(skewed)
        for j in sorted(now_skewed - self._skewed):
            d = skewed[j]
            where = "behind" if d > 0 else "ahead of"
            log.warning(
                "peer %d's clock is %.2f s %s ours (its messages arrive %+.3f s after their "
                "stamps, 20th percentile over 2 s): holding until the vehicles' clocks agree "
                "(chrony or PTP; docs/flying.md)",
                j, abs(d), where, d,
            )  # fmt: skip
        for j in sorted(self._skewed - now_skewed):
            log.info("peer %d's clock agrees with ours again", j)
        self._skewed = now_skewed
        return sorted(now_skewed)

    def _frame_link_time(self, now_s: float) -> float | None:
        """When (link clock) the newest bearing frame used so far was captured (the same value
        on every tick of one frame)."""
        stamp_s = self._newest_frame_s
        if not math.isfinite(stamp_s):
            return None
        if self._frame_link_s[0] != stamp_s:
            speedup = max(self.clock.speedup, 1e-6)
            self._frame_link_s = (stamp_s, self.link.config.clock() - (now_s - stamp_s) / speedup)
        return self._frame_link_s[1]

    def _shutdown(self) -> None:
        c = self.fleet.config
        if self.state.get() in (Phase.FLYING, Phase.HOLDING):
            self.link.set_setpoint(ZERO_SETPOINT)
            time.sleep(0.3)
            if c.on_exit == "land":
                self.link.land()
            self.link.stop_streaming("daemon exit")
        self.state.set(Phase.STOPPED)
        if self.tape is not None:
            self.tape.close()
        summary = self.metrics.summary()
        summary["bearing_to_wire"] = percentiles_ms(list(self.link.setpoint_ages_s))
        summary["frame_to_wire"] = percentiles_ms(list(self.link.frame_to_wire_s))
        log.info("metrics %s", json.dumps(summary))
