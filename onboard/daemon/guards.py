"""The daemon's safety rules, one small guard each (docs/design.md, "Safety").

Every core tick the daemon gathers what its rules look at into one :class:`GuardInput` (plain
values: no link, no clock, no threads) and asks its guards in order. A guard answers with a
:class:`Verdict`: pass, hold (the vehicle gets zero velocity) or clamp (the setpoint is bounded),
and the alarms it raises (:class:`messages.vocabulary.Alarm`, wire form from
:func:`messages.vocabulary.alarm_text`). :func:`decide` folds the verdicts:

* the **checks** (lost peers, rigidity, clock skew, stale inputs, a failed tick, clock faults,
  pilot takeover, non-finite setpoints) each may raise alarms and may hold;
* the **envelope** (altitude band, fence) bounds the setpoint, and is asked only when the
  vehicle flies the setpoint (phase ``flying``, no check holds): its alarms say a bound acted.

Each guard is pure logic over its fields of :class:`GuardInput` and the limits it was built
with, so each is unit-tested in milliseconds (``tests/onboard/test_guards.py``).
"""

from __future__ import annotations

import dataclasses
import enum
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

from messages.agent import Setpoint
from messages.vocabulary import Alarm, Phase, alarm_text
from onboard.autopilot.base import Flavour
from onboard.control.envelope import bound_down_velocity, bound_horizontal_velocity

ZERO_SETPOINT = Setpoint(v_body=(0.0, 0.0, 0.0), yaw_rate_rad_s=0.0)


class Action(enum.Enum):
    """What a guard wants done with this tick's setpoint."""

    PASS = "pass"
    HOLD = "hold"
    """Send zero velocity and yaw rate."""
    CLAMP = "clamp"
    """Send :attr:`Verdict.setpoint` (bounded) instead."""


@dataclass(frozen=True)
class Verdict:
    """A guard's answer: its action, the alarms it raises, and the bounded setpoint of a clamp."""

    action: Action = Action.PASS
    alarms: tuple[str, ...] = ()
    setpoint: Setpoint | None = None


PASS = Verdict()


@dataclass(frozen=True)
class GuardInput:
    """What the guards look at in one tick (the daemon's clock; NED about the autopilot's local
    origin). The defaults are a healthy vehicle flying a zero setpoint."""

    phase: Phase = Phase.FLYING
    """The daemon's phase (:data:`onboard.daemon.loop.PHASES`)."""
    setpoint: Setpoint = ZERO_SETPOINT
    """The core's setpoint (heading frame, :mod:`onboard.autopilot.base`)."""
    lost_peers: tuple[int, ...] = ()
    """Graph neighbours seen once and without liveliness, or silent (no peer payload; a
    stalled vehicle keeps its token), for the loss time (:mod:`onboard.daemon.presence`)."""
    skewed_peers: tuple[int, ...] = ()
    """Neighbours whose clocks disagree with ours (:mod:`onboard.daemon.peer_clock`)."""
    autopilot_stale: bool = False
    """The autopilot's heartbeat, attitude or velocity is older than the link's limit."""
    bearings_age_s: float = 0.0
    """Age of the newest camera frame (``inf``: none yet)."""
    step_error_age_s: float = math.inf
    """Seconds since a core tick last raised (``inf``: never)."""
    clock_fault: Alarm | None = None
    """``clock_jump`` / ``clock_resync`` while the daemon's clock reports one."""
    estimate_healthy: bool = True
    """The core's own estimates are finite and within the physical ranges (its last status)."""
    implausible_telemetry_age_s: float = math.inf
    """Seconds since the autopilot last sent finite but impossible telemetry (``inf``: never)."""
    altitude_m: float = 0.0
    north_m: float = 0.0
    east_m: float = 0.0
    yaw_rad: float = 0.0


class Guard(Protocol):
    """One safety rule: pure logic over :class:`GuardInput` and the guard's own limits."""

    def check(self, inp: GuardInput) -> Verdict:
        """This tick's verdict."""
        ...


class LostPeersGuard:
    """``peer_lost:<id>`` for every lost neighbour; losing peers alone does not hold (the
    rigidity guard decides whether the rest can still fly)."""

    def check(self, inp: GuardInput) -> Verdict:
        if not inp.lost_peers:
            return PASS
        return Verdict(alarms=tuple(alarm_text(Alarm.PEER_LOST, j) for j in inp.lost_peers))


class RigidityGuard:
    """Hold with ``rigidity_lost`` when the planned framework without the lost neighbours is no
    longer infinitesimally bearing rigid (paper 000's localization needs a rigid sensing graph).
    ``rigid_without(lost)`` answers for a set of lost ids (the daemon caches
    :func:`onboard.rigidity.bearing.ibr_r3s1` on the planned formation)."""

    def __init__(self, rigid_without: Callable[[frozenset[int]], bool]) -> None:
        self.rigid_without = rigid_without

    def check(self, inp: GuardInput) -> Verdict:
        if not inp.lost_peers or self.rigid_without(frozenset(inp.lost_peers)):
            return PASS
        return Verdict(Action.HOLD, (Alarm.RIGIDITY_LOST.value,))


class ClockSkewGuard:
    """Hold with ``peer_clock:<id>`` while a neighbour's clock disagrees with ours: its data
    would corrupt the estimates without a sign."""

    def check(self, inp: GuardInput) -> Verdict:
        if not inp.skewed_peers:
            return PASS
        alarms = tuple(alarm_text(Alarm.PEER_CLOCK, j) for j in inp.skewed_peers)
        return Verdict(Action.HOLD, alarms)


class StaleInputsGuard:
    """Hold with ``autopilot_stale`` / ``bearings_stale`` when the vehicle's own inputs are old:
    the autopilot's telemetry (the link's flag) or the newest camera frame (``stale_s``)."""

    def __init__(self, stale_s: float) -> None:
        self.stale_s = stale_s

    def check(self, inp: GuardInput) -> Verdict:
        alarms = []
        if inp.autopilot_stale:
            alarms.append(Alarm.AUTOPILOT_STALE.value)
        if inp.bearings_age_s > self.stale_s:
            alarms.append(Alarm.BEARINGS_STALE.value)
        return Verdict(Action.HOLD, tuple(alarms)) if alarms else PASS


class StepErrorGuard:
    """Hold with ``step_error`` for ``window_s`` after a core tick raised."""

    def __init__(self, window_s: float) -> None:
        self.window_s = window_s

    def check(self, inp: GuardInput) -> Verdict:
        if inp.step_error_age_s <= self.window_s:
            return Verdict(Action.HOLD, (Alarm.STEP_ERROR.value,))
        return PASS


class ClockFaultGuard:
    """Raise the clock's own fault (``clock_jump``, ``clock_resync``): the clock rejected or
    followed a timeline and says so; it does not hold (the peers' clock check does)."""

    def check(self, inp: GuardInput) -> Verdict:
        if inp.clock_fault is None:
            return PASS
        return Verdict(alarms=(Alarm(inp.clock_fault).value,))


class PilotTakeoverGuard:
    """While the autopilot has the vehicle (it left OFFBOARD/GUIDED and the link stopped
    streaming, so no setpoint goes out anyway): ``pilot_takeover`` in phase ``pilot``,
    ``failsafe`` in phase ``failsafe`` (:func:`takeover_kind` told them apart)."""

    def check(self, inp: GuardInput) -> Verdict:
        if inp.phase == Phase.PILOT:
            return Verdict(alarms=(Alarm.PILOT_TAKEOVER.value,))
        if inp.phase == Phase.FAILSAFE:
            return Verdict(alarms=(Alarm.FAILSAFE.value,))
        return PASS


PILOT_MODES: dict[Flavour, frozenset[str]] = {
    Flavour.PX4: frozenset({"MANUAL", "STABILIZED", "ACRO", "RATTITUDE", "ALTCTL", "POSCTL"}),
    Flavour.ARDUPILOT: frozenset(
        {"STABILIZE", "ACRO", "ALT_HOLD", "LOITER", "POSHOLD", "SPORT", "DRIFT", "FLOWHOLD"}
    ),
}
"""Modes a pilot flies with the sticks. An autopilot's own failsafe never picks them without
an RC link: it holds, lands or returns (PX4 AUTO.LOITER / AUTO.LAND / AUTO.RTL, ArduPilot
BRAKE / LAND / RTL)."""
STALL_MEMORY_S = 5.0
"""A stall of the daemon or a lost autopilot link this recent explains a mode change."""


def takeover_kind(
    flavour: Flavour | None, mode: str, since_stall_s: float, since_link_lost_s: float
) -> Phase:
    """Who took the vehicle out of OFFBOARD/GUIDED: ``"pilot"`` or ``"failsafe"``.

    A failsafe when the daemon stalled (a tick gap, e.g. SIGSTOP: PX4 fails over after
    ``COM_OF_LOSS_T``) or the autopilot link was lost (a restarted simulator) within
    :data:`STALL_MEMORY_S`, or when the new mode is no pilot mode (:data:`PILOT_MODES`: a
    hold, land or return mode, or one a forged HEARTBEAT shows); a pilot only when a healthy
    stream was replaced by a stick mode."""
    if since_stall_s <= STALL_MEMORY_S or since_link_lost_s <= STALL_MEMORY_S:
        return Phase.FAILSAFE
    if flavour is not None and mode in PILOT_MODES[flavour]:
        return Phase.PILOT
    return Phase.FAILSAFE


class FiniteSetpointGuard:
    """Hold with ``estimate_diverging`` when the core's setpoint has a NaN or an infinity."""

    def check(self, inp: GuardInput) -> Verdict:
        sp = inp.setpoint
        if all(math.isfinite(x) for x in (*sp.v_body, sp.yaw_rate_rad_s)):
            return PASS
        return Verdict(Action.HOLD, (Alarm.ESTIMATE_DIVERGING.value,))


class EstimateHealthGuard:
    """Hold while the vehicle's picture of itself cannot be trusted: ``estimate_nonfinite``
    when the core's estimates are NaN/inf or beyond the physical ranges, and
    ``telemetry_implausible`` for ``window_s`` after the autopilot sent impossible values
    (dropped by :meth:`onboard.autopilot.states.TelemetryState.apply`; a corrupted autopilot
    keeps sending them, so the hold lasts while it does)."""

    def __init__(self, window_s: float) -> None:
        self.window_s = window_s

    def check(self, inp: GuardInput) -> Verdict:
        alarms = []
        if not inp.estimate_healthy:
            alarms.append(Alarm.ESTIMATE_NONFINITE.value)
        if inp.implausible_telemetry_age_s <= self.window_s:
            alarms.append(Alarm.TELEMETRY_IMPLAUSIBLE.value)
        return Verdict(Action.HOLD, tuple(alarms)) if alarms else PASS


class AltitudeBandGuard:
    """Bound the down velocity so the vehicle stays between ``min_alt_m`` and ``max_alt_m``
    above the autopilot's origin (:func:`onboard.control.envelope.bound_down_velocity`):
    ``altitude_floor`` / ``altitude_ceiling`` when the bound acted."""

    def __init__(self, min_alt_m: float, max_alt_m: float) -> None:
        self.min_alt_m, self.max_alt_m = min_alt_m, max_alt_m

    def check(self, inp: GuardInput) -> Verdict:
        v = inp.setpoint.v_body
        v_down = bound_down_velocity(v[2], inp.altitude_m, self.min_alt_m, self.max_alt_m)
        if v_down == v[2]:
            return PASS
        alarm = Alarm.ALTITUDE_FLOOR if v_down < v[2] else Alarm.ALTITUDE_CEILING
        bounded = Setpoint((v[0], v[1], v_down), inp.setpoint.yaw_rate_rad_s)
        return Verdict(Action.CLAMP, (alarm.value,), bounded)


class FenceGuard:
    """Bound the horizontal velocity by the fence of radius ``max_radius_m`` about the
    autopilot's origin (:func:`onboard.control.envelope.bound_horizontal_velocity`, in NED;
    the setpoint is in the heading frame, rotated by ``yaw_rad``): ``fence`` when it acted."""

    def __init__(self, max_radius_m: float) -> None:
        self.max_radius_m = max_radius_m

    def check(self, inp: GuardInput) -> Verdict:
        v_x, v_y, v_z = inp.setpoint.v_body
        c, s = math.cos(inp.yaw_rad), math.sin(inp.yaw_rad)
        v_n, v_e = c * v_x - s * v_y, s * v_x + c * v_y
        b_n, b_e = bound_horizontal_velocity(v_n, v_e, inp.north_m, inp.east_m, self.max_radius_m)
        if (b_n, b_e) == (v_n, v_e):
            return PASS  # untouched (no round trip through the rotation)
        bounded = Setpoint(
            (c * b_n + s * b_e, -s * b_n + c * b_e, v_z), inp.setpoint.yaw_rate_rad_s
        )
        return Verdict(Action.CLAMP, (Alarm.FENCE.value,), bounded)


@dataclass(frozen=True)
class Guards:
    """The daemon's rules in the order their alarms are listed: checks, then the envelope."""

    checks: tuple[Guard, ...]
    envelope: tuple[Guard, ...]


@dataclass(frozen=True)
class Decision:
    """What one tick sends: hold (zero) or :attr:`setpoint`, and every alarm raised."""

    hold: bool
    setpoint: Setpoint
    alarms: tuple[str, ...]


def decide(guards: Guards, inp: GuardInput) -> Decision:
    """Ask every check, then (flying and nothing holds) let the envelope bound the setpoint."""
    alarms: list[str] = []
    hold = False
    for g in guards.checks:
        v = g.check(inp)
        alarms.extend(v.alarms)
        hold = hold or v.action is Action.HOLD
    if hold:
        return Decision(True, ZERO_SETPOINT, tuple(alarms))
    if inp.phase == Phase.FLYING:
        for g in guards.envelope:
            v = g.check(inp)
            alarms.extend(v.alarms)
            if v.action is Action.CLAMP and v.setpoint is not None:
                inp = dataclasses.replace(inp, setpoint=v.setpoint)
    return Decision(False, inp.setpoint, tuple(alarms))


def daemon_guards(
    rigid_without: Callable[[frozenset[int]], bool],
    stale_s: float,
    step_error_window_s: float,
    min_alt_m: float,
    max_alt_m: float,
    max_radius_m: float,
    implausible_window_s: float = 1.0,
    extra_checks: Sequence[Guard] = (),
) -> Guards:
    """The onboard daemon's guards, in its order."""
    return Guards(
        checks=(
            LostPeersGuard(),
            RigidityGuard(rigid_without),
            ClockSkewGuard(),
            StaleInputsGuard(stale_s),
            StepErrorGuard(step_error_window_s),
            ClockFaultGuard(),
            PilotTakeoverGuard(),
            FiniteSetpointGuard(),
            EstimateHealthGuard(implausible_window_s),
            *extra_checks,
        ),
        envelope=(AltitudeBandGuard(min_alt_m, max_alt_m), FenceGuard(max_radius_m)),
    )
