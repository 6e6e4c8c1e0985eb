"""The fast MAVLink output path: byte-identical framing, unchanged ODOMETRY values, highest rate first."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2
from runtime_helpers import BufferSink

from ins_hil.nav import earth
from ins_hil.nav.rotation import dcm_from_quat, quat_normalize
from ins_hil.runtime.mavlink_out import EndpointConfig, MavlinkEndpoint, MavReceiver, _Frame
from ins_hil.runtime.metrics import RuntimeMetrics
from ins_hil.types import NavState

HOT = ("ODOMETRY", "ATTITUDE", "ATTITUDE_QUATERNION", "GLOBAL_POSITION_INT", "LOCAL_POSITION_NED",
       "HEARTBEAT", "SYS_STATUS")  # fmt: skip
KEY = bytes(range(32))

_INT_RANGES = {
    "uint8_t": (0, 255),
    "int8_t": (-128, 127),
    "uint16_t": (0, 65535),
    "int16_t": (-32768, 32767),
    "uint32_t": (0, 2**32 - 1),
    "int32_t": (-(2**31), 2**31 - 1),
    "uint64_t": (0, 2**64 - 1),
}


def _random_value(rng: np.random.Generator, typ: str, zero: bool) -> Any:
    if zero:
        return 0.0 if typ == "float" else 0
    if typ == "float":
        return float(rng.choice([-1.0, 1.0]) * 10.0 ** rng.uniform(-6, 6))
    lo, hi = _INT_RANGES[typ]
    return int(rng.integers(lo, hi, endpoint=True, dtype=np.uint64 if typ == "uint64_t" else np.int64))


@pytest.mark.parametrize("typ", HOT)
def test_frame_is_byte_identical_to_pymavlink_for_random_values(typ: str) -> None:
    cls = mavlink2.mavlink_map[getattr(mavlink2, "MAVLINK_MSG_ID_" + typ)]
    rng = np.random.default_rng(sum(map(ord, typ)))
    frame = _Frame(cls)
    for trial in range(200):
        # trial 0: every field zero (the payload trims to one byte); 1: trailing fields zero (partial trim)
        kwargs: dict[str, Any] = {}
        wire: list[Any] = []
        for k, name in enumerate(cls.ordered_fieldnames):
            ftype = cls.fieldtypes[cls.fieldnames.index(name)]
            zero = trial == 0 or (trial == 1 and k >= len(cls.ordered_fieldnames) // 2)
            n = cls.array_lengths[k]
            if n:
                vals = [_random_value(rng, ftype, zero) for _ in range(n)]
                kwargs[name], wire = vals, wire + vals
            else:
                v = _random_value(rng, ftype, zero)
                kwargs[name] = v
                wire.append(v)
        sysid, compid, seq = (int(x) for x in rng.integers(0, 256, 3))
        ref = mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        ref.seq = seq
        mine = mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        mine.seq = seq
        assert frame.frame(mine, *wire) == cls(**kwargs).pack(ref), (typ, trial)
    # and the frame decodes as that message
    m = mavlink2.MAVLink(None).parse_buffer(frame.frame(ref, *wire))
    assert m is not None and m[0].get_type() == typ


def _random_state(rng: np.random.Generator, t: float, lat0: float = 0.6, lon0: float = -1.2) -> NavState:
    return NavState(
        t=t,
        q_nb=quat_normalize(rng.normal(size=4)),
        vel_ned=rng.normal(0.0, 20.0, 3),
        lat=lat0 + rng.normal(0.0, 1e-3),
        lon=lon0 + rng.normal(0.0, 1e-3),
        h=float(rng.uniform(-100.0, 3000.0)),
        std_pos=np.abs(rng.normal(0.0, 2.0, 3)),
        std_vel=np.abs(rng.normal(0.0, 0.2, 3)),
        std_att=np.abs(rng.normal(0.0, 0.02, 3)),
        omega_b=rng.normal(0.0, 1.0, 3),
        aligned=bool(rng.integers(0, 2)),
    )


def _endpoint(role: str, key: str = "") -> tuple[MavlinkEndpoint, BufferSink]:
    ep = MavlinkEndpoint(EndpointConfig(role=role, signing_key=key), RuntimeMetrics())
    ep.reset_counter = 0  # ODOMETRY's counter starts at random: the same start on both paths compared
    sink = BufferSink()
    ep.tr = sink  # type: ignore[assignment]
    return ep, sink


@pytest.mark.parametrize("role", ["gcs", "fc"])
def test_unsigned_builders_send_the_bytes_pymavlink_sends(role: str) -> None:
    """Every hot builder on the fast path writes exactly what it writes through pymavlink's senders."""
    rng = np.random.default_rng(7)
    fast, fsink = _endpoint(role)
    slow, ssink = _endpoint(role)
    slow._fast = False
    assert fast._fast
    for k in range(40):
        st = _random_state(rng, 10.0 + 0.37 * k)
        if k == 5:
            st.std_pos = np.array([0.0, math.nan, 1.0])  # unknown covariance → NaN first element
        for typ in HOT:
            getattr(fast, "_send_" + typ.lower())(st)
            getattr(slow, "_send_" + typ.lower())(st)
    # role fc: no ODOMETRY of an unaligned state, SET_GPS_GLOBAL_ORIGIN after the first of each usable run
    assert len(fsink.bufs) == len(HOT) * 40 if role == "gcs" else len(fsink.bufs) > (len(HOT) - 1) * 40
    assert fsink.bufs == ssink.bufs
    assert fast.mav.seq == slow.mav.seq and fast.mav.total_bytes_sent == slow.mav.total_bytes_sent


def test_signed_link_falls_back_to_pymavlink_and_signs() -> None:
    rng = np.random.default_rng(3)
    ep, sink = _endpoint("fc", KEY.hex())
    assert not ep._fast
    plain, psink = _endpoint("fc")
    states = [_random_state(rng, 1.0 + k) for k in range(5)]
    for st in states:
        ep._send_odometry(st)
        plain._send_odometry(st)
    rx = MavReceiver(KEY)
    msgs = [m for b in sink.bufs for m in rx.feed(b)]
    assert rx.counts["messages"] == 5 and rx.counts["bad_signature"] == 0 and rx.counts["unsigned"] == 0
    ref = [m for b in psink.bufs for m in mavlink2.MAVLink(None).parse_buffer(b) or []]
    for a, b in zip(msgs, ref, strict=True):
        assert a.get_payload() == b.get_payload()  # same values, only the framing (signature) differs


def _euler_jacobian(q: Any) -> np.ndarray:
    """∂(roll, pitch, yaw)/∂ψ for a small rotation ψ about the NED axes (C ← (I + [ψ×]) C), numerically."""
    from ins_hil.nav.rotation import euler_from_quat, quat_from_rotvec, quat_mul

    e0 = euler_from_quat(q)
    cols = []
    for k in range(3):
        d = np.zeros(3)
        d[k] = 1e-6
        de = euler_from_quat(quat_mul(quat_from_rotvec(d), q)) - e0
        de[2] = (de[2] + math.pi) % (2 * math.pi) - math.pi
        cols.append(de / 1e-6)
    return np.array(cols).T


def _ref_odometry(st: NavState, home: tuple[float, float, float]) -> dict[str, Any]:
    """ODOMETRY's values computed with numpy: NED offset, body velocity, covariances in the message's frames."""
    d = earth.ned_from_geodetic(st.lat, st.lon, st.h, *home)
    c = dcm_from_quat(st.q_nb)
    v_b = c.T @ st.vel_ned
    pc = [float("nan")] + [0.0] * 20
    vc = list(pc)
    sp, sv, sa = st.std_pos, st.std_vel, st.std_att
    if float(np.max(sp)) > 0:
        pc = [0.0] * 21
        for i, val in zip((0, 6, 11), (sp[0], sp[1], sp[2])):
            pc[i] = float(val) ** 2
        j = _euler_jacobian(st.q_nb)
        ea = j @ np.diag(np.asarray(sa) ** 2) @ j.T
        for i, (r, cc) in zip((15, 16, 17, 18, 19, 20), ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))):
            pc[i] = ea[r, cc]
        vb = c.T @ np.diag(np.asarray(sv) ** 2) @ c
        vc = [0.0] * 21
        for i, (r, cc) in zip((0, 1, 2, 6, 7, 11), ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))):
            vc[i] = vb[r, cc]
    return {"time_usec": round(st.t * 1e6), "xyz": d, "q": st.q_nb, "v": v_b, "w": st.omega_b, "pc": pc, "vc": vc,
            "quality": 100 if st.aligned else -1}  # fmt: skip


def test_odometry_values_equal_a_numpy_reference() -> None:
    rng = np.random.default_rng(11)
    ep, sink = _endpoint("gcs")  # role gcs: every state sent (quality −1 when unusable)
    home_state = _random_state(rng, 0.5)
    ep._send_odometry(home_state)  # the first state is the home
    home = (home_state.lat, home_state.lon, home_state.h)
    states = [_random_state(rng, 1.0 + 0.123 * k) for k in range(25)]
    states[3].std_pos = np.zeros(3)  # no covariance yet
    for st in states:
        ep._send_odometry(st)
    mav = mavlink2.MAVLink(None)
    got = [m for b in sink.bufs[1:] for m in mav.parse_buffer(b) or []]
    assert len(got) == len(states)

    def f32(x: Any) -> np.ndarray:
        return np.asarray(x, dtype=np.float64).astype(np.float32).astype(np.float64)

    for st, o in zip(states, got, strict=True):
        ref = _ref_odometry(st, home)
        assert o.time_usec == ref["time_usec"] and o.quality == ref["quality"]
        # positions are up to ~200 m from home: the scalar and numpy ECEF differences agree to < 1 µm
        assert np.allclose([o.x, o.y, o.z], f32(ref["xyz"]), rtol=2e-7, atol=1e-6)
        assert np.array_equal(np.array(o.q), f32(ref["q"]))
        assert np.allclose([o.vx, o.vy, o.vz], f32(ref["v"]), rtol=2e-7, atol=1e-9)
        assert np.array_equal([o.rollspeed, o.pitchspeed, o.yawspeed], f32(ref["w"]))
        # the Euler block against a numerical Jacobian (finite differences: 1e-4 relative of the largest term)
        scale = max(abs(x) for x in ref["pc"][15:21]) if not math.isnan(ref["pc"][0]) else 1.0
        assert np.allclose(o.pose_covariance, ref["pc"], rtol=1e-4, atol=1e-4 * scale, equal_nan=True)
        assert np.allclose(o.velocity_covariance, ref["vc"], rtol=1e-5, atol=1e-9, equal_nan=True)
    assert math.isnan(got[3].pose_covariance[0]) and math.isnan(got[3].velocity_covariance[0])


def test_highest_rate_message_goes_first_and_latency_is_taken_at_it() -> None:
    rates = {
        "HEARTBEAT": 1.0,
        "SYS_STATUS": 1.0,
        "ATTITUDE": 10.0,
        "ATTITUDE_QUATERNION": 0.0,
        "GLOBAL_POSITION_INT": 10.0,
        "LOCAL_POSITION_NED": 0.0,
        "GPS_RAW_INT": 0.0,
        "VFR_HUD": 0.0,
        "ESTIMATOR_STATUS": 0.0,
        "ODOMETRY": 50.0,
        "EXTENDED_SYS_STATE": 0.0,
        "BATTERY_STATUS": 0.0,
        "HOME_POSITION": 0.0,
    }  # fmt: skip  (the soak's gcs endpoint)
    metrics = RuntimeMetrics()
    ep = MavlinkEndpoint(EndpointConfig(rates=rates), metrics)
    sink = BufferSink()
    ep.tr = sink  # type: ignore[assignment]
    at_record: list[int] = []
    orig = metrics.record_sent

    def spy(arrival_ns: int, ready_ns: int, sent_ns: int) -> None:
        at_record.append(len(sink.bufs))
        orig(arrival_ns, ready_ns, sent_ns)

    metrics.record_sent = spy  # type: ignore[method-assign]
    ep.statustext(4, "INS fault gyro[1] step_bias")
    ep.offer(_random_state(np.random.default_rng(1), 1.0), 0, 1)  # everything is due at the first state
    mav = mavlink2.MAVLink(None)
    order = [m.get_type() for b in sink.bufs for m in mav.parse_buffer(b) or []]
    assert order[0] == "ODOMETRY"
    assert order[1:3] == ["ATTITUDE", "GLOBAL_POSITION_INT"] and order[3:5] == ["HEARTBEAT", "SYS_STATUS"]
    assert order[5:] == ["STATUSTEXT"]  # texts after the state's messages
    assert at_record == [1]  # one latency sample per state, taken right after the first (ODOMETRY) write
    assert metrics.snapshot()["latency"]["state_to_sent"]["count"] == 1
