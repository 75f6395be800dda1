"""One bad sample must never break a vehicle (issue 23): regression tests of the agent core and
its estimators against well-formed poison, one defect each."""

from __future__ import annotations

import copy
import math
import tempfile
from functools import lru_cache
from pathlib import Path

import msgspec
import numpy as np
import pytest

from messages.agent import BearingMeasurement, OwnMeasurements
from messages.codec import decode, encode
from messages.peer import (
    BearingShare,
    ConsensusEntry,
    ConsensusState,
    EdgeExcitation,
    ExcitationTable,
    LocalizationState,
    MotionShare,
    PeerPayload,
    SfmEdgeEstimate,
    SfmEstimate,
    TargetBearing,
)
from messages.sim import CameraBearings
from onboard.core.agent import AgentCore
from onboard.core.config import build_config
from onboard.core.peers import JumpGate
from onboard.daemon.bearings import SimCameraSource
from onboard.daemon.peers import DropCounter
from onboard.estimation.sfm_observer import predict_bearing
from onboard.geometry import bearings_body
from sim.world import kinematic_step

TRIANGLE = ((0, 1), (1, 0), (1, 2), (2, 1), (0, 2), (2, 0))
P0 = ((0.0, 0.0, -2.0), (2.5, 0.5, -2.6), (0.5, 2.6, -1.5))


def core(agent_id: int = 1, **kw) -> AgentCore:
    return AgentCore(
        build_config(agent_id=agent_id, n_agents=3, edges=TRIANGLE, p_hat0_ned=P0, seed=1, **kw)
    )


def own(t_s: float) -> OwnMeasurements:
    return OwnMeasurements(t_s=t_s, yaw_rad=0.1, v_body=(0.0, 0.0, 0.0), yaw_rate_rad_s=0.0)


def wire(msg):
    """Through the codec, as a daemon receives it."""
    return decode(encode(msg), PeerPayload)


# ---------------------------------------------------------------- defect 1: magnitudes


def test_predict_bearing_never_divides_by_zero():
    assert predict_bearing((0.0, 0.0, 0.0), 0.5, (0.0, 0.0, 0.0), 0.0, 0.002) == (0.0, 0.0, 0.0)
    # a huge relative velocity overflows the norm: the bearing is kept, not turned into zeros
    beta = (1.0, 0.0, 0.0)
    for _ in range(3):
        beta = predict_bearing(beta, 0.5, (0.0, 1e160, 0.0), 0.0, 0.002)
    assert beta == (1.0, 0.0, 0.0)


def test_a_received_sfm_estimate_expires():
    c = core(1)  # edge (0, 1) is run by agent 0, which shares chi_hat with agent 1
    c.step(1.0, own(1.0))
    est = SfmEstimate(
        sender=0, seq=1, stamp_s=1.0, edges=[SfmEdgeEstimate(1, 0.25, 1.0, 0.0, 10.0)]
    )
    c.step(1.01, own(1.01), [wire(est)])
    assert c.chi_hat(0) == 0.25
    assert c.status().chi_hat_inv_m[0] == 0.25
    c.step(1.0 + 2 * c.config.safety.peer_timeout_s, own(1.0 + 2 * c.config.safety.peer_timeout_s))
    assert c.chi_hat(0) is None  # a silent neighbour's last distance is not kept forever
    assert 0 not in c.status().chi_hat_inv_m
    assert c.scale.received_e_folds(0) == 0.0 and not c.scale_converged()
    assert all(math.isfinite(x) for x in c.status().p_hat_ned)


def test_a_received_sfm_estimate_of_a_vanishing_inverse_distance_is_no_distance():
    """A bit-flipped ``chihat`` (1e-158: finite, within the codec's range) reached the rigidity
    layer as a distance of 1e158 m (bench_poison d1-bitflip); the floor every other user of
    an SfM estimate applies (``chi_min_inv_m``) now holds for the rigidity layer's too."""
    c = core(1)
    c.step(1.0, own(1.0))
    for chi, kept in ((0.25, True), (1e-158, False), (0.5 * c.scale.gains.chi_min_inv_m, False)):
        est = SfmEstimate(
            sender=0, seq=1, stamp_s=1.01, edges=[SfmEdgeEstimate(1, chi, 1.0, 0.0, 10.0)]
        )
        c.scale.sfm_in.clear()
        c.step(1.01, own(1.01), [wire(est)])
        assert c.chi_hat(0) == chi  # still reported as received
        assert (c.scale.distances().get(0) == 1.0 / chi) is kept  # edge (1, 2) is its own


# ---------------------------------------------------------------- defect 2: future stamps


def motion(sender: int, stamp_s: float, seq: int = 0) -> MotionShare:
    return MotionShare(
        sender=sender, seq=seq, stamp_s=stamp_s, v_body=(0.1, 0.0, 0.0), yaw_rate_rad_s=0.0,
        yaw_rad=0.5,
    )  # fmt: skip


def test_one_future_stamped_peer_sample_does_not_freeze_peer_state():
    c = core(1)  # runs the SfM observer of edge (1, 2): agent 2's motion history matters
    t = 1.0
    c.step(t, own(t), [wire(motion(2, t))])
    future = wire(motion(2, t + 1e6))
    bearings = wire(BearingShare(sender=2, stamp_s=t + 1e6, yaw_rad=0.0,
                                 bearings=[TargetBearing(1, (1.0, 0.0, 0.0))]))  # fmt: skip
    table = wire(ExcitationTable(sender=2, stamp_s=t,
                                 entries=[EdgeExcitation(0, 2, 5.0, t + 1e6)]))  # fmt: skip
    c.step(t + 0.01, own(t + 0.01), [future, bearings, table])
    for k in range(2, 50):
        t_k = t + 0.01 * k
        c.step(t_k, own(t_k), [wire(motion(2, t_k))])
        assert c.scale.motion_hist[2].newest_s == t_k  # real samples keep coming in
    assert c.dropped["future_stamp"] == 3
    assert 2 not in c.bearings.beta_in and (0, 2) not in c.scale.lam_table


def test_one_future_stamped_camera_frame_does_not_blind_the_core():
    c = core(1)
    beta = (1.0, 0.0, 0.0)

    def frame(t_s: float, stamp_s: float) -> OwnMeasurements:
        b = (BearingMeasurement(0, beta, stamp_s), BearingMeasurement(2, beta, stamp_s))
        return msgspec.structs.replace(own(t_s), bearings=b)

    _, out = c.step(1.0, frame(1.0, 1e6))
    assert not [p for p in out if isinstance(p, BearingShare)] and c.dropped["future_stamp"] == 2
    _, out = c.step(1.02, frame(1.02, 1.01))
    assert [p.stamp_s for p in out if isinstance(p, BearingShare)] == [1.01]


class _Link:
    """What :class:`SimCameraSource` needs of a peer link: its id, the fleet's ids, subscribe."""

    id, known, fleet = 1, frozenset({0, 1, 2}), "t"

    def subscribe(self, key_expr, handler):
        self.handler = handler


class _Sample:
    """A Zenoh sample as the handler reads it (``sample.payload.to_bytes()``)."""

    def __init__(self, msg) -> None:
        self.payload, self.data = self, encode(msg)

    def to_bytes(self) -> bytes:
        return self.data


_sample = _Sample


def test_sim_camera_drops_future_frames_and_bearings_stale_can_fire():
    now = [10.0]
    link, drops = _Link(), DropCounter()
    src = SimCameraSource(link, drops, lambda: now[0])
    frame = lambda stamp: CameraBearings(  # noqa: E731
        sender=1, stamp_s=stamp, targets=[0], beta_body=[(1.0, 0.0, 0.0)]
    )
    link.handler(_sample(frame(10.0 + 1e6)))
    assert src.poll() is None and drops.snapshot() == {"camera_future_stamp": 1}
    link.handler(_sample(frame(10.0)))
    assert src.poll()[0].stamp_s == 10.0
    now[0] = 10.5  # a frame within the allowed skew is fresh, never of negative age
    link.handler(_sample(frame(11.0)))
    assert src.poll()[0].stamp_s == 11.0 and src.age_s(now[0]) == 0.0
    assert src.age_s(13.0) == 2.0  # and it ages: bearings_stale fires once stale_s passes
    now[0] = 0.2  # the simulator restarted: the frame "newest by stamp" lies in the future
    link.handler(_sample(frame(0.2)))
    assert src.poll()[0].stamp_s == 0.2


def test_a_clock_reset_rebuilds_the_stamped_peer_state():
    c = core(1)
    for k in range(100):
        t_k = 100.0 + 0.01 * k
        c.step(t_k, own(t_k), [wire(motion(2, t_k))])
    c.step(0.5, own(0.5), [wire(motion(2, 0.5))])  # restarted simulator: time starts again
    assert c.dropped["time_backwards"] == 1
    c.step(0.51, own(0.51), [wire(motion(2, 0.51))])
    assert c.scale.motion_hist[2].newest_s == 0.51 and c.bearings.own_hist.newest_s == 0.51


# ---------------------------------------------------------------- defect 4: bounded tables


def test_consensus_names_and_excitation_edges_are_bounded_by_the_fleet():
    c = core(1)
    t = 1.0
    for k in range(20):
        t += 0.01
        names = [f"n{k}_{m}" for m in range(1000)]
        cons = ConsensusState(sender=2, stamp_s=t, states=[
            ConsensusEntry(name, [0.0], [0.0]) for name in ["e_index", *names]])  # fmt: skip
        first = [m % 50 for m in range(1000)]
        second = [50 + k + m // 50 for m in range(1000)]
        table = ExcitationTable(sender=2, stamp_s=t, entries=[
            EdgeExcitation(a, b, 1.0, t) for a, b in zip([0, *first], [2, *second], strict=True)
        ])  # fmt: skip
        c.step(t, own(t), [wire(cons), wire(table)])
    assert (
        set(c.scale.cons_in) <= {"e_index", "p_bar", "dlam_dwl", "w_l"}
        and 2 in c.scale.cons_in["e_index"]
    )
    assert set(c.scale.lam_table) <= {(0, 1), (0, 2), (1, 2)} and (0, 2) in c.scale.lam_table
    assert c.dropped["unknown_name"] == 20_000 and c.dropped["unknown_edge"] == 20_000


# ---------------------------------------------------------------- defect 1: one bit flip of E


def e_state(sender: int, t_s: float, x: float, z: float) -> ConsensusState:
    return ConsensusState(sender=sender, stamp_s=t_s, states=[ConsensusEntry("e_index", [x], [z])])


def test_one_jumped_e_index_consensus_state_is_not_taken():
    """bench_poison's ``d1-bitflip``: a flipped exponent turned a neighbour's converged ``E``
    state 1e-6 into 1.0; the receiver took it, and its ``E`` stayed above ``e_low`` for 30 s.
    A jump beyond ``E_STEP_MAX_HIGHS e_high`` waits for the sender's next sample to confirm it,
    so a real change is followed one sample late, and the sample after a bad one is taken."""
    c = core(1)
    c.step(1.0, own(1.0), [wire(e_state(0, 1.0, 1e-6, 2e-6))])
    c.step(1.02, own(1.02), [wire(e_state(0, 1.02, 1.0, 2e-6))])
    assert c.scale.cons_in["e_index"][0] == (1.0, [1e-6], [2e-6])
    assert c.dropped["implausible_jump"] == 1
    c.step(1.03, own(1.03), [wire(e_state(0, 1.03, 1.1e-6, 2e-6))])  # back to normal: taken
    assert c.scale.cons_in["e_index"][0] == (1.03, [1.1e-6], [2e-6])
    c.step(1.04, own(1.04), [wire(e_state(0, 1.04, 2e-6, 1e3))])  # a jump of z: dropped too
    assert c.scale.cons_in["e_index"][0][0] == 1.03 and c.dropped["implausible_jump"] == 2
    c.step(1.06, own(1.06), [wire(e_state(0, 1.06, 3e-6, 1e3 + 1e-3))])  # confirmed: followed
    assert c.scale.cons_in["e_index"][0] == (1.06, [3e-6], [1e3 + 1e-3])
    c.step(1.08, own(1.08), [wire(e_state(0, 1.08, 5e-3, 1e3))])  # a real step of 5 e_high
    assert c.scale.cons_in["e_index"][0][0] == 1.08 and c.dropped["implausible_jump"] == 2


def test_jump_gate_holds_one_jump_until_the_next_sample_confirms_it():
    """:class:`onboard.core.peers.JumpGate`, the one rule for every neighbour estimate: a jump
    passes only when the sender's next sample agrees with it; one bad sample is never taken and
    costs nothing after it; angles are compared wrapped."""
    gate = JumpGate()
    lim, ang = (0.5, 10.0), (True,)
    assert gate.admit("k", (3.1, 0.0), lim, ang)  # the first sample
    assert gate.admit("k", (-3.1, 0.5), lim, ang)  # across +-pi: 0.08 rad
    assert not gate.admit("k", (-3.1, 1e6), lim, ang)  # one bad sample
    assert gate.admit("k", (-3.05, 0.6), lim, ang)  # the next real one, compared with the last
    assert not gate.admit("k", (-2.0, 0.6), lim, ang)  # a real jump of 1 rad ...
    assert gate.admit("k", (-2.01, 0.6), lim, ang)  # ... followed one sample late
    assert not gate.admit("k", (1.0, 0.6), lim, ang) and not gate.admit("k", (-1.0, 0.6), lim, ang)
    assert gate.admit("k", (-2.0, 0.6), lim, ang)  # two different bad ones: neither taken
    assert gate.admit("other", (1e6, 1e6), lim, ang)  # keys are independent


class _DemoTeam:
    """The demo's team (its fleet file; 100 Hz cores, camera every 30 ms, the simulator's
    autopilot lags, every payload through the codec) on a kinematic world."""

    def __init__(self, tmp: Path) -> None:
        from groundstation.demo import DemoPorts, plan_formation, write_demo_files
        from onboard.daemon.config import load_fleet
        from onboard.daemon.loop import agent_config

        plan = plan_formation(3, seed=1)
        ports = DemoPorts(7447, 14540, 14550)
        fleet = load_fleet(write_demo_files(tmp, plan, ports, "p", "formation-active"))
        self.cores = [AgentCore(agent_config(fleet, i)) for i in range(3)]
        self.p = [tuple(float(x) for x in r) for r in plan.p_start_ned]
        self.yaw = [float(y) for y in plan.yaw_start_rad]
        self.v_ned, self.v_body = [(0.0, 0.0, 0.0)] * 3, [(0.0, 0.0, 0.0)] * 3
        self.w = [0.0] * 3
        self.inbox: list[list] = [[], [], []]
        self.newest: dict[tuple[int, type], bytes] = {}
        self.k = 0
        self.held: tuple[type, int] | None = None
        """(kind, until step): vehicle 1's real payloads of that kind do not reach 0 and 2, as
        when a forged one came with a sequence number ahead (:mod:`onboard.daemon.replay`)."""

    def step(self, forged: bytes | None = None) -> float:
        """One 10 ms step (``forged`` reaches vehicles 0 and 2 after the real traffic); returns
        the fastest true speed."""
        dt, t, n = 0.01, self.k * 0.01, 3
        edges = self.cores[0].config.graph.edges
        frames = [()] * n
        if self.k % 3 == 0:
            for i in range(n):
                out = [j for a, j in edges if a == i]
                b, _ = bearings_body(
                    np.asarray(self.p), np.asarray(self.yaw), [(i, j) for j in out]
                )
                frames[i] = tuple(BearingMeasurement(j, tuple(b[m]), t) for m, j in enumerate(out))
        if forged is not None:
            for r in (0, 2):
                self.inbox[r].append(decode(forged, PeerPayload))
        nxt: list[list] = [[] for _ in range(n)]
        for i, c in enumerate(self.cores):
            own_i = OwnMeasurements(t_s=t, yaw_rad=self.yaw[i], v_body=self.v_body[i],
                                    yaw_rate_rad_s=self.w[i], bearings=frames[i])  # fmt: skip
            sp, out = c.step(t, own_i, self.inbox[i])
            for m in out:
                data = encode(m)
                self.newest[(i, type(m))] = data
                held = self.held is not None and i == 1 and type(m) is self.held[0]
                for r in range(n):
                    if r != i and not (held and r != 1 and self.k < self.held[1]):  # type: ignore[index]
                        nxt[r].append(decode(data, PeerPayload))
            self.p[i], self.yaw[i], self.v_ned[i], self.v_body[i], self.w[i] = kinematic_step(
                self.p[i], self.yaw[i], self.v_ned[i], self.w[i], sp.v_body, sp.yaw_rate_rad_s,
                dt, dt / 0.3, dt / 0.2,
            )  # fmt: skip
        self.inbox = nxt
        self.k += 1
        return max(math.hypot(*v) for v in self.v_ned)

    def formation_m(self) -> float:
        """Mean true distance between two vehicles."""
        return (
            math.dist(*self.p[:2]) + math.dist(self.p[0], self.p[2]) + math.dist(*self.p[1:])
        ) / 3


@lru_cache(maxsize=1)
def _converged_demo_team() -> _DemoTeam:
    with tempfile.TemporaryDirectory() as tmp:
        team = _DemoTeam(Path(tmp))
    for _ in range(4000):  # 40 s
        team.step()
    assert all(c.scale_converged() for c in team.cores)
    return team


def _forge_e(raw: dict) -> None:
    for entry in raw["states"]:
        if entry[0] == "e_index":
            entry[1] = [1.0]  # e.g. 9.4e-10 with exponent bit 5 flipped: 4.0; any large value


def _forge_yaw(raw: dict) -> None:
    raw["yaw_hat_rad"] += 1.0  # e.g. 2.83 with exponent bit 3 flipped: 724 rad, another angle


def _forge_p_bar(raw: dict) -> None:
    for entry in raw["states"]:
        if entry[0] == "p_bar":
            entry[2][0] = 5.5e6  # seed 28: a flipped exponent bit of z


def _forged(team: _DemoTeam, kind: type, forge) -> bytes:
    """Vehicle 1's newest payload of ``kind``, forged, numbered 30 ahead as bench_poison's
    ``d1-bitflip`` numbers it (the replay window then holds the real ones for 0.3 s)."""
    raw = msgspec.msgpack.decode(team.newest[(1, kind)])
    raw["seq"] += 30
    forge(raw)
    team.held = (kind, team.k + 30)
    return msgspec.msgpack.encode(raw)


@pytest.mark.parametrize(
    ("kind", "forge"), [(ConsensusState, _forge_e), (LocalizationState, _forge_yaw)]
)
def test_one_bit_flipped_estimate_does_not_spin_a_converged_team(kind, forge):
    """The demo team converges, then ONE payload of vehicle 1 arrives, numbered 30 ahead, with
    its ``E`` consensus state turned into 1.0, or its yaw estimate turned by 1 rad. Before, the
    gate ``k_E`` of vehicles 0 and 2 opened fully and the team flew at the 2 m/s limit within
    10 s (2.0 m/s both; with the bench's timing offline ``E`` stayed above ``e_low`` for 30 s and
    the formation went 11.7 -> 26.7 m; the yaw, 9.3 s fast and 11.8 -> 15.5 m for good). Now the
    gate stays shut, nobody speeds up, the formation keeps its size; the forged sample is the
    only one dropped (the real one after it is compared with the last one taken)."""
    team = copy.deepcopy(_converged_demo_team())
    size = team.formation_m()
    fastest = team.step(_forged(team, kind, forge))
    k_e = 0.0
    for _ in range(1000):  # 10 s
        fastest = max(fastest, team.step())
        k_e = max(k_e, *(c.k_e for c in team.cores))
    assert k_e == 0.0 and fastest < 0.5, (k_e, fastest)
    assert [team.cores[r].dropped["implausible_jump"] for r in (0, 2)] == [1, 1]
    assert team.formation_m() == pytest.approx(size, abs=0.1)


def test_a_flipped_barycenter_state_and_a_small_e_kick_do_not_fly_the_team_fast():
    """bench_poison ``d1-bitflip`` offline, seed 28, bisected to two of its 1,495 mutations:
    ONE ``ConsensusState`` whose ``pbar`` integral state ``z`` a flipped exponent made 5.5e6
    (the receivers' barycenter went 55 km away and decayed over tens of seconds), then 1.9 s
    later one whose ``E`` state was 0.0036 (under the ``E`` jump limit of 1e-2). ``k_E`` opened
    a little, the rotation about the far barycenter saturated at 2 m/s, the fast motion pushed
    the SfM corrections over ``wander_max``, the edges un-converged and ``k_E`` opened fully:
    14.3 s of 15 s at the limit, the formation 9.9 m off. Here the same two on the demo team:
    before, the barycenter 1.1e5 m off, the team at 2.0 m/s and the formation 11.4 m off after
    15 s; now both are held back (barycenter within 1.4 m, 0.01 m/s)."""
    team = copy.deepcopy(_converged_demo_team())
    size = team.formation_m()
    fastest = team.step(_forged(team, ConsensusState, _forge_p_bar))
    p_bar_off = 0.0
    for _ in range(190):
        fastest = max(fastest, team.step())
        p_bar_off = max(p_bar_off, *(abs(c.scale.p_bar[0]) for c in team.cores))

    def small_e(raw: dict) -> None:
        for entry in raw["states"]:
            if entry[0] == "e_index":
                entry[1] = [0.0036]

    fastest = max(fastest, team.step(_forged(team, ConsensusState, small_e)))
    for _ in range(1500):  # 15 s
        fastest = max(fastest, team.step())
    assert p_bar_off < 100.0 and fastest < 0.5, (p_bar_off, fastest)
    assert team.formation_m() == pytest.approx(size, abs=0.1)
    assert [team.cores[r].dropped["implausible_jump"] for r in (0, 2)] == [1, 1]


def loc(sender: int, t_s: float, p: tuple, yaw: float) -> LocalizationState:
    return LocalizationState(sender=sender, stamp_s=t_s, p_hat_ned=p, yaw_hat_rad=yaw)


def test_one_jumped_localization_estimate_waits_for_confirmation():
    """A neighbour's ``LocalizationState`` that turned by more than ``LOC_STEP_MAX_RAD`` or moved
    by more than ``LOC_STEP_MAX_M`` is held back until its next one agrees (counted
    ``implausible_jump``, not ``malformed``)."""
    c = core(1)
    c.step(1.0, own(1.0), [wire(loc(0, 1.0, (0.0, 0.0, -2.0), 0.3))])
    c.step(1.02, own(1.02), [wire(loc(0, 1.02, (0.0, 0.0, -2.0), 0.3 + 1.0))])  # turned 1 rad
    taken = c.peers.latest(LocalizationState, 0)
    assert taken is not None and taken.stamp_s == 1.0 and c.dropped["implausible_jump"] == 1
    c.step(1.03, own(1.03), [wire(loc(0, 1.03, (0.0, 0.1, -2.0), 0.31))])  # the real next one
    assert c.peers.latest(LocalizationState, 0).stamp_s == 1.03  # type: ignore[union-attr]
    c.step(1.04, own(1.04), [wire(loc(0, 1.04, (50.0, 0.0, -2.0), 0.31))])  # moved 50 m
    assert c.peers.latest(LocalizationState, 0).stamp_s == 1.03  # type: ignore[union-attr]
    c.step(1.06, own(1.06), [wire(loc(0, 1.06, (50.1, 0.0, -2.0), 0.31 + math.tau))])
    assert c.peers.latest(LocalizationState, 0).stamp_s == 1.06  # type: ignore[union-attr]
    assert c.dropped["implausible_jump"] == 2 and "malformed" not in c.dropped
