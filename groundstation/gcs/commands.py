"""Fleet commands: one action sent to every selected vehicle at the same moment.

* ``arm``, ``takeoff``, ``land`` go to the autopilots: a COMMAND_LONG to each system id over the
  ground-station link, retried like MAVSDK does (every :data:`RETRY_PERIOD_S` until a
  COMMAND_ACK arrives or the timeout ends). ``takeoff`` on ArduPilot first sets GUIDED and sends
  the altitude in param 7; on PX4 the params are NaN, so ``MIS_TAKEOFF_ALT`` applies.
* ``start``, ``hold`` go to the agents: a :class:`~messages.command.FleetCommand` on
  ``bf/<fleet>/<id>/command``, answered by a :class:`~messages.command.CommandAck`.
* ``stop`` is the emergency action: LAND to every selected autopilot *and* a Zenoh ``stop`` to
  every selected agent, at once; a vehicle counts as reached when either path acknowledged, so
  it lands even if its agent is dead.

* ``formation FILE`` sends a new desired formation (:class:`~messages.command.FormationChange`
  on ``bf/<fleet>/<id>/command/formation``), repeated every :data:`RETRY_PERIOD_S` until each
  agent's status shows its ``formation_id`` (:func:`run_formation`).
* ``leader ID`` drives the formation's leader (:class:`~messages.command.LeaderDrive` on
  ``bf/<fleet>/<id>/command/leader``: a velocity or waypoints), repeated the same way until its
  status shows the ``drive_id`` (:func:`run_leader`); waypoint files: :func:`load_waypoints`.

Every vehicle gets a :class:`Outcome`; the caller prints them and fails if any is not ``ok``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgspec

from groundstation.gcs.mavlink_listener import MavlinkListener
from groundstation.gcs.mavlink_state import Ack, MavlinkState
from groundstation.gcs.zenoh_listener import ZenohListener, ZenohState
from messages import mavlink as mv
from messages.codec import encode
from messages.command import (
    COMMAND_TOPIC,
    FORMATION_TOPIC,
    LEADER_TOPIC,
    FleetCommand,
    FormationChange,
    FormationSlot,
    LeaderDrive,
    Waypoints,
    drive_problem,
)
from messages.formation import Formation
from messages.keys import key

MAVLINK_ACTIONS = ("arm", "takeoff", "land")
AGENT_ACTIONS = ("start", "hold")
ACTIONS = ("arm", "takeoff", "start", "hold", "land", "stop")
RETRY_PERIOD_S = 0.5
GCS_SENDER_ID = 0
"""``FleetCommand.sender`` of the ground station (messages/command.py convention)."""

RESULT_NAMES = {
    mv.RESULT_ACCEPTED: "ACCEPTED",
    mv.RESULT_TEMPORARILY_REJECTED: "TEMPORARILY_REJECTED",
    mv.RESULT_DENIED: "DENIED",
    mv.RESULT_UNSUPPORTED: "UNSUPPORTED",
    mv.RESULT_FAILED: "FAILED",
    mv.RESULT_IN_PROGRESS: "IN_PROGRESS",
}


@dataclass
class Outcome:
    """What happened to one vehicle: ``ok`` and a human-readable line per path."""

    agent_id: int
    ok: bool = False
    details: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class MavStep:
    """One COMMAND_LONG of a (possibly multi-step) action."""

    command: int
    params: tuple[float, ...]
    label: str


def parse_ids(text: str) -> list[int]:
    """``"1,3,5-7"`` -> ``[1, 3, 5, 6, 7]``; ``ValueError`` on anything else."""
    out: set[int] = set()
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        lo, sep, hi = part.partition("-")
        try:
            a = int(lo)
            b = int(hi) if sep else a
        except ValueError:
            raise ValueError(f"bad id list {text!r}: use e.g. 1,3 or 0-3") from None
        if a < 0 or b < a:
            raise ValueError(f"bad id range {part!r} in {text!r}")
        out.update(range(a, b + 1))
    if not out:
        raise ValueError("empty id list")
    return sorted(out)


def mavlink_steps(action: str, flavour: str, takeoff_alt_m: float) -> list[MavStep]:
    """The COMMAND_LONGs of a MAVLink action for one autopilot flavour."""
    nan = math.nan
    if action == "arm":
        return [MavStep(mv.CMD_COMPONENT_ARM_DISARM, (1.0,), "arm")]
    if action == "takeoff":
        if flavour == "ardupilot":
            guided = (float(mv.BASE_MODE_CUSTOM), float(mv.COPTER_MODES["GUIDED"]))
            return [
                MavStep(mv.CMD_DO_SET_MODE, guided, "GUIDED"),
                MavStep(mv.CMD_NAV_TAKEOFF, (0, 0, 0, nan, 0, 0, takeoff_alt_m), "takeoff"),
            ]
        return [MavStep(mv.CMD_NAV_TAKEOFF, (-1, 0, 0, nan, nan, nan, nan), "takeoff")]
    if action in ("land", "stop"):
        if flavour == "ardupilot":
            return [MavStep(mv.CMD_NAV_LAND, (0, 0, 0, nan, 0, 0, 0), "land")]
        return [MavStep(mv.CMD_NAV_LAND, (0, 0, 0, nan, nan, nan, nan), "land")]
    raise ValueError(f"{action!r} is not a MAVLink action")


def discover(
    mavlink: MavlinkListener | None,
    zenoh: ZenohListener | None,
    wanted: Sequence[int] | None,
    timeout_s: float,
    sysid_offset: int,
) -> tuple[set[int], set[int]]:
    """Vehicles heard within ``timeout_s``: (agent ids with an autopilot heartbeat, agent ids
    with a live agent). With ``wanted`` it returns as soon as every wanted id was heard on every
    link we listen to; without, it listens for the whole ``timeout_s``."""

    def heard() -> tuple[set[int], set[int]]:
        autopilots: set[int] = set()
        agents: set[int] = set()
        if mavlink is not None:
            with mavlink.lock:
                autopilots = {
                    s - sysid_offset
                    for s, t in mavlink.state.systems.items()
                    if t.last_heartbeat_s is not None
                }
        if zenoh is not None:
            with zenoh.lock:
                agents = {
                    i
                    for i, a in zenoh.state.agents.items()
                    if a.alive or (a.status_s is not None and a.alive is not False)
                }
        return autopilots, agents

    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        autopilots, agents = heard()
        if wanted is not None:
            need = set(wanted)
            if (mavlink is None or need <= autopilots) and (zenoh is None or need <= agents):
                return autopilots, agents
        time.sleep(0.05)
    return heard()


def _final_ack(acks: Iterable[Ack], sysid: int, command: int) -> Ack | None:
    for a in acks:
        if a.sysid == sysid and a.command == command and a.result != mv.RESULT_IN_PROGRESS:
            return a
    return None


def run_mavlink(
    mavlink: MavlinkListener,
    action: str,
    ids: Sequence[int],
    sysid_offset: int,
    timeout_s: float,
    takeoff_alt_m: float = 2.5,
) -> dict[int, Outcome]:
    """Send ``action`` to every vehicle in ``ids`` at once (step by step for multi-step actions)
    and wait for each COMMAND_ACK. Vehicles never heard fail with ``not heard``."""
    out = {i: Outcome(i) for i in ids}
    systems = mavlink.systems()
    active: dict[int, list[MavStep]] = {}
    for i in ids:
        sys = systems.get(i + sysid_offset)
        if sys is None or sys.last_heartbeat_s is None:
            out[i].details.append("mavlink: not heard")
        else:
            active[i] = mavlink_steps(action, sys.flavour, takeoff_alt_m)
    step = 0
    while active:
        batch = {i: steps[step] for i, steps in active.items() if step < len(steps)}
        if not batch:
            break
        results = _send_and_wait(mavlink, batch, sysid_offset, timeout_s)
        for i, (ok, text) in results.items():
            if not ok:
                out[i].details.append(f"mavlink {batch[i].label}: {text}")
                del active[i]
            elif step == len(active[i]) - 1:
                out[i].ok = True
                out[i].details.append(f"mavlink {batch[i].label}: {text}")
                del active[i]
        step += 1
    return out


def _send_and_wait(
    mavlink: MavlinkListener,
    batch: dict[int, MavStep],
    sysid_offset: int,
    timeout_s: float,
) -> dict[int, tuple[bool, str]]:
    """One COMMAND_LONG to every vehicle of ``batch`` in one burst, retried until each ACK."""
    t0 = mavlink.clock()
    deadline = t0 + timeout_s
    pending = dict(batch)
    results: dict[int, tuple[bool, str]] = {}
    attempt = 0
    next_send = t0

    def all_answered(state: MavlinkState) -> bool:
        acks = [a for a in state.acks if a.t_s >= t0]
        return all(
            _final_ack(acks, i + sysid_offset, st.command) is not None for i, st in pending.items()
        )

    while pending:
        if mavlink.clock() >= next_send:
            for i, st in pending.items():
                mavlink.send_command_long(
                    i + sysid_offset, st.command, st.params, min(attempt, 255)
                )
            attempt += 1
            next_send = mavlink.clock() + RETRY_PERIOD_S
        mavlink.wait_for(all_answered, max(0.0, min(next_send, deadline) - mavlink.clock()))
        acks = mavlink.acks_since(t0)
        systems = mavlink.systems()
        for i, st in list(pending.items()):
            ack = _final_ack(acks, i + sysid_offset, st.command)
            if ack is None:
                continue
            text = RESULT_NAMES.get(ack.result, f"RESULT_{ack.result}")
            sys = systems.get(i + sysid_offset)
            if ack.result != mv.RESULT_ACCEPTED and sys is not None and sys.statustext:
                text = f"{text} ({sys.statustext})"
            results[i] = (ack.result == mv.RESULT_ACCEPTED, text)
            del pending[i]
        if pending and mavlink.clock() >= deadline:
            for i in pending:
                results[i] = (False, f"timeout after {timeout_s:g} s ({attempt} tries)")
            break
    return results


def run_zenoh(
    session: Any,
    zenoh: ZenohListener,
    fleet: str,
    action: str,
    ids: Sequence[int],
    timeout_s: float,
    request_id: int | None = None,
    expect: Sequence[int] | None = None,
) -> dict[int, Outcome]:
    """Publish one :class:`FleetCommand` per agent in ``ids`` in one burst, then wait for the
    :class:`CommandAck` with our ``request_id`` of every agent in ``expect`` (default: all of
    ``ids``); an agent not expected (never heard) is reported without waiting for it."""
    wait_ids = set(ids if expect is None else expect) & set(ids)
    rid = request_id if request_id is not None else time.time_ns() & 0x7FFFFFFF
    t0 = zenoh.clock()
    stamp = time.time()
    for seq, i in enumerate(ids):
        cmd = FleetCommand(
            sender=GCS_SENDER_ID, seq=seq, stamp_s=stamp, target=i, action=action, request_id=rid
        )  # type: ignore[arg-type]
        session.put(key(fleet, i, COMMAND_TOPIC), encode(cmd))

    def acked(state: ZenohState) -> dict[int, Any]:
        return {
            a.sender: a
            for t, a in state.acks
            if t >= t0 and a.request_id == rid and a.sender in ids
        }

    zenoh.wait_for(lambda s: wait_ids <= set(acked(s)), timeout_s if wait_ids else 0.0)
    with zenoh.lock:
        got = acked(zenoh.state)
    out = {i: Outcome(i) for i in ids}
    for i in ids:
        a = got.get(i)
        if a is None and i not in wait_ids:
            out[i].details.append(f"agent: never heard ({action} sent)")
        elif a is None:
            out[i].details.append(f"agent: no ack within {timeout_s:g} s")
        else:
            out[i].ok = a.accepted
            verdict = "accepted" if a.accepted else "rejected"
            out[i].details.append(f"agent: {verdict}{f' ({a.detail})' if a.detail else ''}")
    return out


def merge_stop(mav: dict[int, Outcome], agents: dict[int, Outcome]) -> dict[int, Outcome]:
    """``stop`` reaches a vehicle when its autopilot acknowledged LAND or its agent the stop."""
    out: dict[int, Outcome] = {}
    for i in sorted(set(mav) | set(agents)):
        parts = [o for o in (mav.get(i), agents.get(i)) if o is not None]
        out[i] = Outcome(i, any(o.ok for o in parts), [d for o in parts for d in o.details])
    return out


def formation_slots(formation: Formation) -> list[FormationSlot]:
    """A formation file's agents as the slots of a :class:`FormationChange`."""
    return [
        FormationSlot(id=int(i), position_ned=tuple(float(x) for x in p), yaw_rad=float(y))  # type: ignore[arg-type]
        for i, p, y in zip(formation.ids, formation.p_ned, formation.yaw_rad, strict=True)
    ]


def run_formation(
    session: Any,
    zenoh: ZenohListener,
    fleet: str,
    formation: Formation,
    ids: Sequence[int],
    timeout_s: float,
    formation_id: int,
    leader: int | None = None,
    distances: bool = False,
    ramp_s: float | None = None,
) -> dict[int, Outcome]:
    """Send ``formation`` to every agent in ``ids`` (one :class:`FormationChange` each, again
    every :data:`RETRY_PERIOD_S`) until each status reports ``formation_id`` or ``timeout_s``;
    ``distances``: hold its distances too (paper 002 eq. 23), ``ramp_s``: the switch time."""
    slots = formation_slots(formation)
    name = formation.name[:64]

    def adopted(state: ZenohState) -> set[int]:
        return {
            i
            for i, a in state.agents.items()
            if a.status is not None and a.status.formation_id == formation_id
        }

    deadline = time.monotonic() + timeout_s
    seq = 0
    while True:
        stamp = time.time()
        for i in ids:
            change = FormationChange(
                sender=GCS_SENDER_ID, seq=seq, stamp_s=stamp, target=i,
                formation_id=formation_id, agents=slots, name=name, leader=leader,
                distances=distances, ramp_s=ramp_s,
            )  # fmt: skip
            session.put(key(fleet, i, FORMATION_TOPIC), encode(change))
            seq += 1
        left = deadline - time.monotonic()
        if left <= 0 or zenoh.wait_for(lambda s: set(ids) <= adopted(s), min(RETRY_PERIOD_S, left)):
            break
    out = {i: Outcome(i) for i in ids}
    with zenoh.lock:
        for i in ids:
            a = zenoh.state.agents.get(i)
            status = None if a is None else a.status
            if status is not None and status.formation_id == formation_id:
                out[i].ok = True
                held = " (leader: holds)" if status.formation_leader == i else ""
                scale = " with its distances" if status.formation_distances else ""
                out[i].details.append(f"agent: flies formation {formation_id}{scale}{held}")
            elif status is None:
                out[i].details.append(f"agent: no status within {timeout_s:g} s")
            else:
                refused = {k: n for k, n in status.dropped.items() if k.startswith("command_")}
                out[i].details.append(
                    f"agent: still flies formation {status.formation_id} after {timeout_s:g} s"
                    + (f" (dropped {refused})" if refused else "")
                )
    return out


class WaypointError(ValueError):
    """A waypoint file that cannot be flown; the message names the problem and the place."""


class _Waypoint(msgspec.Struct, forbid_unknown_fields=True):
    ned: tuple[float, float, float]


class _WaypointFile(msgspec.Struct, forbid_unknown_fields=True):
    waypoint: list[_Waypoint]
    speed_m_s: float | None = None


def load_waypoints(path: str | Path) -> tuple[list[tuple[float, float, float]], float | None]:
    """A waypoint file (TOML; docs/gcs.md)::

        speed_m_s = 0.5              # optional: the bound of the leg speeds
        [[waypoint]]
        ned = [2.0, 0.0, -5.0]       # m, NED in the leader's odometry frame

    Returns the waypoints and the speed (``None``: not given); :class:`WaypointError` if the file
    does not load or a value is beyond the payload's bounds (:class:`LeaderDrive`)."""
    path = Path(path)
    try:
        spec = msgspec.toml.decode(path.read_bytes(), type=_WaypointFile)
    except OSError as exc:
        raise WaypointError(f"{path}: cannot read file ({exc.strerror})") from None
    except (msgspec.ValidationError, msgspec.DecodeError) as exc:
        raise WaypointError(f"{path}: {exc}") from None
    points = [w.ned for w in spec.waypoint]
    if not points:
        raise WaypointError(f"{path}: waypoint: at least one [[waypoint]] is needed")
    try:
        msgspec.convert(points, Waypoints)
        speed = spec.speed_m_s
        if speed is not None:
            msgspec.convert({"sender": 0, "target": 0, "drive_id": 1, "speed_m_s": speed},
                            LeaderDrive)  # fmt: skip
    except msgspec.ValidationError as exc:
        raise WaypointError(f"{path}: {exc}") from None
    if not all(math.isfinite(x) for p in points for x in p):
        raise WaypointError(f"{path}: waypoint: every coordinate must be finite")
    return points, spec.speed_m_s


def run_leader(
    session: Any, zenoh: ZenohListener, fleet: str, drive: LeaderDrive, timeout_s: float
) -> Outcome:
    """Send ``drive`` to its leader (again every :data:`RETRY_PERIOD_S`) until the leader's status
    reports its ``drive_id`` or ``timeout_s``; a vehicle that leads no formation says so."""
    problem = drive_problem(drive)
    if problem:
        raise ValueError(problem)
    i = drive.target

    def taken(state: ZenohState) -> bool:
        a = state.agents.get(i)
        return a is not None and a.status is not None and a.status.leader_drive_id == drive.drive_id

    deadline = time.monotonic() + timeout_s
    seq = 0
    while True:
        sent = msgspec.structs.replace(drive, seq=seq, stamp_s=time.time())
        session.put(key(fleet, i, LEADER_TOPIC), encode(sent))
        seq += 1
        left = deadline - time.monotonic()
        if left <= 0 or zenoh.wait_for(taken, min(RETRY_PERIOD_S, left)):
            break
    out = Outcome(i)
    with zenoh.lock:
        a = zenoh.state.agents.get(i)
        status = None if a is None else a.status
    if status is not None and status.leader_drive_id == drive.drive_id:
        out.ok = True
        out.details.append(f"agent: leader of formation {status.formation_id} flies drive "
                           f"{drive.drive_id}")  # fmt: skip
    elif status is None:
        out.details.append(f"agent: no status within {timeout_s:g} s")
    elif status.formation_leader != i:
        out.details.append(
            f"agent: does not lead formation {status.formation_id} (leader "
            f"{status.formation_leader}): send `gcs formation FILE --leader {i}` first"
        )
    else:
        refused = {k: n for k, n in status.dropped.items() if k.startswith("command_")}
        out.details.append(
            f"agent: still flies drive {status.leader_drive_id} after {timeout_s:g} s"
            + (f" (dropped {refused})" if refused else "")
        )
    return out
