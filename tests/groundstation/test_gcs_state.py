"""Ground-station state without sockets: MAVLink folding and loss, Zenoh sample classification,
the monitor's rows and alarms, the table, fleet-command helpers and the analysis math."""

from __future__ import annotations

import math

import msgspec
import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as dialect
from rich.console import Console

from groundstation.gcs import analysis, commands
from groundstation.gcs.mavlink_listener import MavlinkListener, parse_endpoint
from groundstation.gcs.mavlink_state import LossWindow, MavlinkState, sequence_gap
from groundstation.gcs.monitor import MonitorConfig, render, snapshot
from groundstation.gcs.similarity import similarity_2d
from groundstation.gcs.zenoh_listener import ZenohState, classify
from messages import mavlink as mv
from messages.codec import SCHEMA_VERSION, MessageError, encode, encode_unchecked
from messages.envelope import PeerEnvelope, pack
from messages.peer import LocalizationState, MotionShare
from messages.sim import SimClock
from messages.vocabulary import Alarm, alarm_text
from tests.groundstation.standin import StandinConfig, scripted_status


class _Sink:
    def write(self, _b: bytes) -> None:
        pass


def frames(sysid: int, msgs: list, start_seq: int = 0) -> list[bytes]:
    """Pack messages as system ``sysid`` would, with consecutive sequence numbers."""
    tx = dialect.MAVLink(_Sink(), srcSystem=sysid, srcComponent=1)
    tx.seq = start_seq
    out = []
    for m in msgs:
        out.append(bytes(m.pack(tx)))
        tx.seq = (tx.seq + 1) % 256
    return out


def parse(buf: bytes):
    p = dialect.MAVLink(_Sink())
    return p.parse_buffer(buf)[0]


def px4_heartbeat(mode: str, armed: bool):
    main, sub = mv.PX4_MODES[mode]
    base = mv.BASE_MODE_CUSTOM | (mv.BASE_MODE_ARMED if armed else 0)
    return dialect.MAVLink_heartbeat_message(
        2, mv.MAV_AUTOPILOT_PX4, base, mv.px4_custom_mode(main, sub), 4 if armed else 3, 3
    )


# --- MAVLink --------------------------------------------------------------------------------------
def test_sequence_gap_and_loss_window():
    assert sequence_gap(10, 11) == 0
    assert sequence_gap(255, 0) == 0  # wrap-around is not loss
    assert sequence_gap(10, 14) == 3
    assert sequence_gap(10, 10) == 0  # a duplicate (gap 255) is not counted as loss
    w = LossWindow()
    rng = np.random.default_rng(3)
    seq, skips = 0, []
    for _ in range(100):
        skips.append(int(rng.integers(0, 3)))
        seq = (seq + 1 + skips[-1]) % 256
        w.add(seq)
    # the first packet has no predecessor, so its own skip is not observable
    assert w.lost == sum(skips[1:]) > 0
    assert w.loss_pct() == pytest.approx(100.0 * w.lost / (w.lost + 100))


def test_fold_heartbeats_telemetry_and_acks():
    st = MavlinkState()
    msgs = [
        px4_heartbeat("AUTO.TAKEOFF", armed=True),
        dialect.MAVLink_global_position_int_message(0, 0, 0, 0, 2500, 300, 400, 0, 0),
        dialect.MAVLink_sys_status_message(0, 0, 0, 0, 0, 0, 87, 0, 0, 0, 0, 0, 0),
        dialect.MAVLink_extended_sys_state_message(0, mv.LANDED_IN_AIR),
        dialect.MAVLink_command_ack_message(400, mv.RESULT_ACCEPTED, 0, 0, 255, 190),
    ]
    for k, buf in enumerate(frames(3, msgs)):
        st.fold(parse(buf), 10.0 + k)
    s = st.systems[3]
    assert (s.flavour, s.mode, s.armed, s.in_air) == ("px4", "AUTO.TAKEOFF", True, True)
    assert s.altitude_m == pytest.approx(2.5)
    assert s.speed_m_s == pytest.approx(5.0)
    assert s.battery_pct == 87.0
    assert s.last_heartbeat_s == 10.0 and s.last_message_s == 14.0
    assert [(a.sysid, a.command, a.result) for a in st.acks] == [(3, 400, 0)]
    # an ArduCopter heartbeat; a GCS heartbeat is not a vehicle
    ap = dialect.MAVLink_heartbeat_message(2, mv.MAV_AUTOPILOT_ARDUPILOTMEGA, 1 | 16, 4, 3, 3)
    gcs = dialect.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3)
    st.fold(parse(frames(5, [ap])[0]), 20.0)
    st.fold(parse(frames(255, [gcs])[0]), 20.0)
    assert st.systems[5].mode == "GUIDED" and st.systems[5].armed is False
    assert 255 not in st.systems and st.counters["other_heartbeats"] == 1


def test_listener_counts_garbage_and_bad_crc_and_measures_loss():
    listener = MavlinkListener([parse_endpoint("udp:127.0.0.1:0")])
    try:
        addr = ("127.0.0.1", 40000)
        hb = [px4_heartbeat("AUTO.LOITER", armed=False) for _ in range(20)]
        bufs = frames(1, hb)
        kept = [b for k, b in enumerate(bufs) if k not in (5, 6, 7)]  # 3 lost on the way
        bad = bytearray(bufs[0])
        bad[-1] ^= 0xFF
        listener.feed(b"\x00garbage\xff" * 3, addr)
        listener.feed(bytes(bad), addr)
        for b in kept:
            listener.feed(b, addr)
        sys = listener.systems()[1]
        assert sys.messages == 17
        assert sys.loss_pct() == pytest.approx(100 * 3 / 20)
        counters = listener.state.counters
        assert counters.get("bad_crc", 0) + counters.get("garbage", 0) >= 2
        assert listener.addresses[1] == addr
    finally:
        listener.close()


def test_parse_endpoint():
    assert parse_endpoint("udp:0.0.0.0:14550") == parse_endpoint("udpin:0.0.0.0:14550")
    assert parse_endpoint("udpout:127.0.0.1:14580").kind == "udpout"
    for bad in ("tcp:1.2.3.4:5", "udp:host", "udp:h:port", "udp:h:70000"):
        with pytest.raises(ValueError):
            parse_endpoint(bad)


# --- Zenoh samples ----------------------------------------------------------------------------------
def status_bytes(agent_id: int, t_s: float = 0.0, **kw) -> bytes:
    cfg = StandinConfig("alpha", [0, 1, 2], **kw)
    return encode(scripted_status(cfg, agent_id, t_s, 0, "flying"))


def test_classify_accepts_ours_and_names_every_rejection():
    d = classify("alpha", "bf/alpha/1/status", status_bytes(1))
    assert (d.agent_id, d.topic) == (1, "status")
    clock = encode(SimClock(sender=0, t_s=1.0, step=100, speedup=1.0, lockstep=False))
    assert classify("alpha", "bf/alpha/sim/clock", clock).agent_id is None
    cases = {
        "malformed": ("bf/alpha/1/status", b"\x93garbage"),
        "foreign": ("bf/alpha/1/weather", status_bytes(1)),
        "wrong_fleet": ("bf/beta/1/status", status_bytes(1)),
        "sender_mismatch": ("bf/alpha/2/status", status_bytes(1)),
    }
    for reason, (key, data) in cases.items():
        with pytest.raises(MessageError) as exc:
            classify("alpha", key, data)
        assert exc.value.reason == reason, key
    with pytest.raises(MessageError) as exc:
        classify("alpha", "bf/alpha/1/status", encode_version(SCHEMA_VERSION + 1))
    assert exc.value.reason == "version"


def test_a_peer_envelope_is_folded_payload_by_payload():
    motion = MotionShare(sender=1, seq=3, v_body=(0.1, 0.0, 0.0), yaw_rate_rad_s=0.0, yaw_rad=0.0)
    loc = LocalizationState(sender=1, seq=3, p_hat_ned=(0.0, 1.0, -2.0), yaw_hat_rad=0.0)
    good = pack(1, 1, [motion, loc]).data
    forged = encode_unchecked(
        PeerEnvelope(sender=1, payloads=[motion, msgspec.structs.replace(loc, sender=2)])
    )
    zen = ZenohState("alpha")
    assert [d.topic for d in zen.fold_sample("bf/alpha/1/peer", good, 1.0)] == [
        "peer/motion", "peer/localization"
    ]  # fmt: skip
    assert [d.payload for d in zen.fold_sample("bf/alpha/1/peer", forged, 1.1)] == [motion]
    assert zen.fold_sample("bf/alpha/2/peer", good, 1.2) == []  # 1's envelope on 2's key
    assert zen.topics == {"peer/motion": 2, "peer/localization": 1}
    assert zen.counters == {"sender_mismatch": 2}
    d = classify("alpha", "bf/alpha/1/peer", good)  # whole, for who wants the envelope
    assert d.topic == "peer" and d.payload.payloads == [motion, loc]
    with pytest.raises(MessageError) as exc:
        classify("alpha", "bf/alpha/1/peer", forged)
    assert exc.value.reason == "sender_mismatch"
    old = classify("alpha", "bf/alpha/1/peer/motion", encode(motion))  # recordings before
    assert (old.topic, old.payload) == ("peer/motion", motion)


def encode_version(version: int) -> bytes:
    import msgspec

    raw = msgspec.msgpack.decode(status_bytes(1))
    raw["version"] = version
    return msgspec.msgpack.encode(raw)


# --- monitor rows and alarms --------------------------------------------------------------------------
def monitor_state(now: float) -> tuple[MavlinkState, ZenohState]:
    mav = MavlinkState()
    for sysid in (1, 2, 3):
        buf = frames(sysid, [px4_heartbeat("OFFBOARD", armed=True)])[0]
        mav.fold(parse(buf), now - (6.0 if sysid == 3 else 0.5))  # system 3: heartbeat lost
    zen = ZenohState("alpha")
    zen.fold_sample("bf/alpha/0/status", status_bytes(0), now - 0.2)
    zen.fold_sample("bf/alpha/1/status", status_bytes(1), now - 4.0)  # stale status
    zen.fold_alive("bf/alpha/0/alive", True, now - 10)
    zen.fold_alive("bf/alpha/1/alive", True, now - 10)
    zen.fold_sample("bf/alpha/0/status", b"\x00\x01", now)  # malformed: counted, no crash
    zen.fold_sample("bf/alpha/0/nonsense", b"", now)
    return mav, zen


def test_snapshot_rows_alarms_and_fleet_line():
    now = 100.0
    mav, zen = monitor_state(now)
    snap = snapshot(mav, zen, now, MonitorConfig(fleet="alpha"))
    rows = {r["id"]: r for r in snap["vehicles"]}
    assert sorted(rows) == [0, 1, 2]
    assert rows[0]["mode"] == "OFFBOARD" and rows[0]["armed"] is True
    assert rows[0]["alarms"] == [] and not rows[0]["red"]
    assert rows[0]["e_index"] == pytest.approx(1.0) and rows[0]["neighbours"] == [1, 2]
    assert rows[1]["alarms"] == ["agent_lost"] and rows[1]["red"]
    assert "heartbeat_lost" in rows[2]["alarms"] and rows[2]["heartbeat_age_s"] == 6.0
    assert snap["zenoh"]["dropped"] == {"malformed": 1, "foreign": 1}
    # the token of agent 0 goes away: red at once, even with a fresh status
    zen.fold_alive("bf/alpha/0/alive", False, now)
    snap = snapshot(mav, zen, now, MonitorConfig(fleet="alpha"))
    assert snap["vehicles"][0]["alarms"] == ["agent_lost"]
    line = snap["fleet_status"]
    assert line["vehicles"] == 3 and line["up"] == 2 and line["red"] == 3


def test_agent_alarms_pass_through_and_time_to_metric_scale():
    zen = ZenohState("alpha")
    # E = exp(-t / 2) falls below 0.05 at t = 2 ln 20 = 5.99 s
    for t in np.arange(0.0, 8.0, 0.5):
        for i in (0, 1):
            data = status_bytes(
                i,
                float(t),
                alarms={1: [alarm_text(Alarm.RIGIDITY_LOST), alarm_text(Alarm.PEER_LOST, 0)]},
            )
            zen.fold_sample(f"bf/alpha/{i}/status", data, 50.0 + float(t))
    snap = snapshot(None, zen, 57.6, MonitorConfig())
    rows = {r["id"]: r for r in snap["vehicles"]}
    assert rows[1]["alarms"] == ["peer_lost:0", "rigidity_lost"]  # the agent's own alarms
    assert rows[1]["red"] and not rows[0]["red"]
    assert rows[0]["scale_converged"] is True
    line = snap["fleet_status"]
    assert line["time_to_metric_scale_s"] == pytest.approx(6.0)
    assert line["rigid"] is False  # agent 1 raises rigidity_lost


def test_render_shows_every_vehicle_and_red_rows():
    now = 100.0
    mav, zen = monitor_state(now)
    console = Console(record=True, width=160, color_system="truecolor")
    console.print(render(snapshot(mav, zen, now, MonitorConfig(fleet="alpha"))))
    text = console.export_text(clear=False)
    lines = [ln for ln in text.splitlines() if "OFFBOARD" in ln]
    assert len(lines) == 3
    assert "agent_lost" in text and "heartbeat_lost" in text
    assert "malformed=1" in text and "foreign=1" in text
    styled = console.export_text(styles=True).splitlines()
    red = "\x1b[1;31m"
    assert [red in ln for ln in styled if "OFFBOARD" in ln] == [False, True, True]


# --- commands ---------------------------------------------------------------------------------------
def test_parse_ids_and_mavlink_steps():
    assert commands.parse_ids("1,3,5-7") == [1, 3, 5, 6, 7]
    for bad in ("", "a", "3-1", "-2"):
        with pytest.raises(ValueError):
            commands.parse_ids(bad)
    px4 = commands.mavlink_steps("takeoff", "px4", 4.0)
    assert [s.command for s in px4] == [mv.CMD_NAV_TAKEOFF] and math.isnan(px4[0].params[6])
    ap = commands.mavlink_steps("takeoff", "ardupilot", 4.0)
    assert [s.command for s in ap] == [mv.CMD_DO_SET_MODE, mv.CMD_NAV_TAKEOFF]
    assert ap[0].params[1] == mv.COPTER_MODES["GUIDED"] and ap[1].params[6] == 4.0
    assert commands.mavlink_steps("stop", "px4", 0)[0].command == mv.CMD_NAV_LAND
    with pytest.raises(ValueError):
        commands.mavlink_steps("start", "px4", 0)


def test_merge_stop_counts_either_path():
    mav = {0: commands.Outcome(0, True, ["mavlink land: ACCEPTED"]), 1: commands.Outcome(1)}
    agents = {0: commands.Outcome(0), 1: commands.Outcome(1, True, ["agent: accepted"])}
    agents[2] = commands.Outcome(2)
    out = commands.merge_stop(mav, agents)
    assert [out[i].ok for i in (0, 1, 2)] == [True, True, False]


# --- analysis ---------------------------------------------------------------------------------------
def test_similarity_2d_recovers_a_known_transform():
    rng = np.random.default_rng(7)
    src = rng.normal(size=(12, 2))
    ang = 0.8
    r = np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
    dst = 2.5 * src @ r.T + np.array([3.0, -1.0])
    s, r_hat, t_hat = similarity_2d(src, dst)
    assert s == pytest.approx(2.5) and np.allclose(r_hat, r) and np.allclose(t_hat, [3, -1])
    with pytest.raises(ValueError):
        similarity_2d(np.zeros((3, 2)), dst[:3])


def test_bearing_errors_vanish_for_consistent_estimates_and_see_a_yaw_error():
    rng = np.random.default_rng(11)
    p_i, p_j = rng.normal(size=(20, 3)) * 5, rng.normal(size=(20, 3)) * 5
    yaw = rng.uniform(-np.pi, np.pi, 20)
    beta = analysis.predicted_bearings_body(p_i, yaw, p_j)
    cam = analysis.BearingSeries(np.arange(20.0), np.ones(20, int), beta)
    # estimates in another frame: rotated by 0.4 rad about z, shifted and scaled by 0.5
    c, s = np.cos(0.4), np.sin(0.4)
    rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    est_i, est_j = 0.5 * p_i @ rz.T + 3.0, 0.5 * p_j @ rz.T + 3.0
    assert np.max(analysis.bearing_errors_rad(cam, est_i, yaw + 0.4, est_j)) < 1e-9
    err = analysis.bearing_errors_rad(cam, est_i, yaw + 0.4 + 0.05, est_j)
    horizontal = np.linalg.norm(beta[:, :2], axis=1)
    # a yaw error turns the horizontal part of each bearing by 0.05 rad
    assert np.allclose(err, 2 * np.arcsin(horizontal * np.sin(0.025)), atol=1e-9)


def test_inverse_distance_error_and_latest_index():
    p_i = np.zeros((3, 3))
    p_j = np.array([[2.0, 0, 0], [0, 4.0, 0], [0, 0, 5.0]])
    err = analysis.inverse_distance_error(np.arange(3.0), np.array([0.5, 0.3, 0.2]), p_i, p_j)
    assert np.allclose(err, [0.0, 0.05, 0.0])
    assert list(analysis.latest_index(np.array([-1.0, 0.0, 0.5, 3.0]), np.array([0.0, 1.0]))) == [
        -1,
        0,
        0,
        1,
    ]
