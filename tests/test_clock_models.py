"""Sensor clocks that recover (drivers/clock.py): every clock accident of the field, through the
serial parser, the DroneCAN decoder and the DBC decoder, and property tests of the model.

Each scenario checks that samples are accepted again within max(3 nominal periods, 50 ms) of
sensor time after the event, that the output time is strictly increasing (the pipeline drops any
sample that is not) and continuous (no step beyond the host time that passed), and that every
received sample is accepted or counted exactly once.
"""

from __future__ import annotations

import math

import can
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from ins_hil.drivers import dronecan_codec as dc
from ins_hil.drivers import serial_frame as sf
from ins_hil.drivers.can_imu import CanImuDriver
from ins_hil.drivers.clock import SourceClock
from ins_hil.drivers.dbc_codec import DbcImuDecoder, DbcProfile, encode_imu_frames

from ins_hil.runtime.clock import SensorClock
from ins_hil.types import GnssFix, ImuSample

G = 9.80665
DROPS = ("duplicate", "seq_backwards", "time_backwards", "time_jump", "nonfinite", "range")


def bound_s(period: float) -> float:
    """The recovery target: max(3 nominal IMU periods, 50 ms) of sensor time."""
    return max(3 * period, 0.05)


def drops(counts: dict[str, int]) -> int:
    return sum(counts.get(k, 0) for k in DROPS)


# ---------------------------------------------------------------- serial
class SerialSensor:
    """A serial IMU: 32-bit µs clock, 16-bit sequence, frames stamped with their host arrival."""

    def __init__(self, rate_hz: float = 1000.0, t_us: int = 5_000_000, seq: int = 0, host_s: float = 100.0) -> None:
        self.dt_us = round(1e6 / rate_hz)
        self.t_us, self.seq = t_us, seq
        self.host_ns = round(host_s * 1e9)

    def frame(self) -> tuple[bytes, int]:
        self.t_us += self.dt_us
        self.seq += 1
        self.host_ns += self.dt_us * 1000
        return self.encode(self.seq, self.t_us), self.host_ns

    def encode(self, seq: int, t_us: int) -> bytes:
        dt = self.dt_us * 1e-6
        s = ImuSample(
            t=(t_us & 0xFFFFFFFF) * 1e-6, dt=dt, dtheta=np.array([1e-5, 0, 0]), dvel=np.array([0, 0, -G * dt]),
            seq=seq & 0xFFFF,
        )  # fmt: skip
        return sf.encode(s)

    def frames(self, n: int) -> list[tuple[bytes, int]]:
        return [self.frame() for _ in range(n)]


def feed(p: sf.FrameParser, frames: list[tuple[bytes, int]]) -> list[ImuSample | None]:
    """Each frame on its own read, at its host time; the accepted sample or None per frame."""
    out: list[ImuSample | None] = []
    for b, h in frames:
        got = p.feed(b, h)
        out.append(got[0] if got else None)
    return out


def check_recovery(before: list[ImuSample | None], after: list[ImuSample | None], period: float) -> None:
    """Acceptance resumes within the bound, and then every sample is accepted; time strictly increasing."""
    lost = next(i for i, s in enumerate(after) if s is not None)
    assert lost * period <= bound_s(period)
    assert all(s is not None for s in after[lost:])
    t = [s.t for s in before + after if s is not None]
    assert np.all(np.diff(t) > 0)


def test_serial_reboot_after_long_uptime_recovers() -> None:
    """30 min of uptime, then the sensor reboots on a link that stays open: its clock and sequence
    restart at 0. The first frame of the new clock is held as a candidate; the second confirms it."""
    imu = SerialSensor(t_us=1_800_000_000, seq=40_000)
    p = sf.FrameParser()
    before = feed(p, imu.frames(200))
    t_last = before[-1].t  # type: ignore[union-attr]
    imu.t_us, imu.seq = 0, -1  # reboot: the next frame has seq 0, t 1 ms
    imu.host_ns += 300_000_000  # 0.3 s of silence while it boots
    after = feed(p, imu.frames(2000))
    check_recovery(before, after, 1e-3)
    assert sum(s is not None for s in after) >= 1999
    first = next(s for s in after if s is not None)
    # the output continues after the last output by the host time that passed (0.3 s + 2 intervals)
    assert first.t - t_last == pytest.approx(0.302, abs=2e-3)
    assert p.counts["clock_reanchor_reboot"] == 1
    assert p.counts.get("seq_gap", 0) == 0


def test_serial_replug_fresh_parser_state_continues() -> None:
    """A re-plug: ``reopen()`` drops partial bytes but keeps the time base; the new device (its
    clock restarted) continues from the old output time, no frame lost."""
    imu = SerialSensor(t_us=600_000_000)
    p = sf.FrameParser()
    before = feed(p, imu.frames(100))
    p.feed(imu.frame()[0][:20], imu.host_ns)  # half a frame when the cable was pulled
    p.reopen()
    imu.t_us, imu.seq = 0, 1000
    imu.host_ns += 2_000_000_000
    after = feed(p, imu.frames(100))
    check_recovery(before, after, 1e-3)
    assert all(s is not None for s in after)
    assert after[0].t - before[-1].t == pytest.approx(2.002, abs=1e-3)  # type: ignore[union-attr]


def test_serial_wrap_then_forward_jump_keeps_the_wrap_count() -> None:
    """The 32-bit µs counter wraps, then the clock jumps 2 s forward: the output goes on from
    4294.97 s (it went back to 2.002 s before), one frame lost."""
    imu = SerialSensor(t_us=0xFFFFFFFF - 50_000)
    p = sf.FrameParser()
    before = feed(p, imu.frames(100))
    assert p.counts["clock_wrap"] == 1
    imu.t_us += 2_000_000
    after = feed(p, imu.frames(100))
    check_recovery(before, after, 1e-3)
    assert sum(s is None for s in after) == 1
    t = np.array([s.t for s in before + after if s is not None])
    assert t.min() > 4294.9 and np.max(np.diff(t)) < 0.003
    assert p.counts["clock_reanchor_jump"] == 1 and p.counts["time_jump"] == 1


@pytest.mark.parametrize(
    "dseq,dt_us",
    [(30_000, 30_000_000), (30_000, 1000), (1, 30_000_000), (1, 150_000), (-20_000, -20_000_000)],
    ids=["seq-and-time-ahead", "seq-ahead", "time-ahead", "time-150ms-ahead", "both-behind"],
)
def test_serial_one_out_of_range_frame_costs_that_frame_only(dseq: int, dt_us: int) -> None:
    """One CRC-valid frame with its sequence and/or time far off; the next 1,000 good frames all
    come through (a seq 30,000 ahead made the next 32,767 frames seq_backwards)."""
    imu = SerialSensor(t_us=10_000_000, seq=100)
    p = sf.FrameParser()
    before = feed(p, imu.frames(50))
    bad = (imu.encode(imu.seq + dseq, imu.t_us + dt_us), imu.host_ns + 500_000)
    after = feed(p, [bad, *imu.frames(1000)])
    assert after[0] is None and all(s is not None for s in after[1:])
    t = [s.t for s in before + after if s is not None]
    assert np.all(np.diff(t) > 0) and np.max(np.diff(t)) < 0.0011
    assert drops(p.counts) == 1 and p.counts.get("seq_gap", 0) == 0


def test_serial_long_stall_with_the_clock_running_loses_nothing() -> None:
    """10 s without a frame (the sensor's clock ran on, its sequence did not): the host time says 10 s
    passed, so the first frame after the stall is consistent and accepted."""
    imu = SerialSensor()
    p = sf.FrameParser()
    before = feed(p, imu.frames(50))
    imu.t_us += 10_000_000
    imu.host_ns += 10_000_000_000
    after = feed(p, imu.frames(50))
    assert all(s is not None for s in after)
    assert after[0].t - before[-1].t == pytest.approx(10.001)  # type: ignore[union-attr]
    assert drops(p.counts) == 0


def test_serial_reboot_during_a_stall_reanchors_on_host_time() -> None:
    imu = SerialSensor(t_us=50_000_000)
    p = sf.FrameParser()
    before = feed(p, imu.frames(50))
    imu.t_us, imu.seq = 3_000_000, 7  # a different clock after the stall
    imu.host_ns += 10_000_000_000
    after = feed(p, imu.frames(50))
    check_recovery(before, after, 1e-3)
    first = next(s for s in after if s is not None)
    assert first.t - before[-1].t == pytest.approx(10.002, abs=1e-3)  # type: ignore[union-attr]


def test_frames_dropped_for_time_or_values_are_not_also_seq_gaps() -> None:
    imu = SerialSensor()
    frames = imu.frames(20)
    frames[5] = (imu.encode(6, imu.t_us + 5_000_000), frames[5][1])  # a time glitch
    frames[9] = (imu.encode(10, imu.t_us - 5_000_000), frames[9][1])  # time backwards
    bad = ImuSample(t=(5_000_000 + 13 * 1000) * 1e-6, dt=1e-3, dtheta=np.array([3.0, 0, 0]), dvel=np.zeros(3), seq=13)
    frames[12] = (sf.encode(bad), frames[12][1])  # 3 rad in 1 ms: range
    del frames[15]  # one frame never arrives
    p = sf.FrameParser()
    out = feed(p, frames)
    assert sum(s is not None for s in out) == 16
    c = p.counts
    assert (c["time_jump"], c["time_backwards"], c["range"]) == (1, 1, 1)
    assert c["seq_gap"] == 1  # only the frame that never came
    assert c["frames"] + drops(c) == len(frames)


# ---------------------------------------------------------------- DroneCAN
class CanNode:
    """A DroneCAN node: RawIMU at ``rate_hz`` with its node clock, NodeStatus on request."""

    def __init__(self, node_id: int = 10, rate_hz: float = 200.0, usec: int = 1_000_000, host_s: float = 50.0):
        self.node_id, self.dt = node_id, 1.0 / rate_hz
        self.usec = usec
        self.host_ns = round(host_s * 1e9)
        self.tids: dict[int, int] = {}

    def transfer(self, dtid: int, payload: bytes, tid: int | None = None) -> list[tuple[int, bytes]]:
        if tid is None:
            tid = self.tids.get(dtid, 0)
            self.tids[dtid] = (tid + 1) & 0x1F
        cid = dc.message_can_id(dtid, self.node_id)
        return [(cid, d) for d in dc.split_transfer(dtid, payload, tid)]

    def imu(self, usec: int | None = None, dt: float | None = None, advance: bool = True) -> list[tuple[int, bytes]]:
        if advance:
            self.usec += round(self.dt * 1e6)
            self.host_ns += round(self.dt * 1e9)
        dt = self.dt if dt is None else dt
        v = {
            "timestamp.usec": self.usec if usec is None else usec, "integration_interval": dt,
            "rate_gyro_latest": [0.0] * 3, "rate_gyro_integral": [0.0] * 3, "accelerometer_latest": [0.0, 0.0, -G],
            "accelerometer_integral": [0.0, 0.0, -G * self.dt],
        }  # fmt: skip
        return self.transfer(dc.DTID_RAW_IMU, dc.encode_payload(dc.DTID_RAW_IMU, v))

    def status(self, uptime_s: int) -> list[tuple[int, bytes]]:
        return self.transfer(dc.DTID_NODE_STATUS, dc.node_status_payload(uptime_s))


def send(dec: dc.DroneCanDecoder, frames: list[tuple[int, bytes]], host_ns: int) -> object:
    r = None
    for cid, d in frames:
        r = dec.feed(cid, d, True, host_ns)
    return r


def imu_run(dec: dc.DroneCanDecoder, node: CanNode, n: int) -> list[ImuSample | None]:
    return [send(dec, node.imu(), node.host_ns) for _ in range(n)]  # type: ignore[misc]


@pytest.mark.parametrize("with_status", [False, True], ids=["rawimu-only", "nodestatus-hint"])
def test_dronecan_node_reboot_recovers(with_status: bool) -> None:
    """A node reboots after 30 min: its usec and transfer ids restart. Without a hint one RawIMU is
    the candidate; a NodeStatus whose uptime went back re-anchors on the first one."""
    node = CanNode(usec=1_800_000_000)
    dec = dc.DroneCanDecoder()
    send(dec, node.status(1800), node.host_ns)
    before = imu_run(dec, node, 100)
    node.usec, node.tids = 400_000, {}
    node.host_ns += 500_000_000
    if with_status:
        send(dec, node.status(0), node.host_ns)
    after = imu_run(dec, node, 2000)
    check_recovery(before, after, node.dt)
    assert sum(s is None for s in after) == (0 if with_status else 1)
    first = next(s for s in after if s is not None)
    assert first.t - before[-1].t == pytest.approx(0.5 + node.dt * (1 if with_status else 2), abs=1e-3)  # type: ignore[union-attr]
    assert dec.counts["clock_reanchor_reboot"] == 1
    assert dec.counts.get("duplicate", 0) == 0


def test_dronecan_state_is_no_trap_across_a_bus_reopen() -> None:
    node = CanNode(usec=900_000_000)
    dec = dc.DroneCanDecoder()
    before = imu_run(dec, node, 50)
    dec.feed(*node.imu()[0], True, node.host_ns)  # the first frame of a transfer, then the bus went away
    dec.reopen()
    node.usec, node.tids = 1000, {}  # the node restarted while the bus was down
    node.host_ns += 3_000_000_000
    after = imu_run(dec, node, 50)
    assert all(s is not None for s in after)
    check_recovery(before, after, node.dt)


def test_dronecan_usec_zero_uses_host_time_for_that_sample_only() -> None:
    node = CanNode()
    dec = dc.DroneCanDecoder()
    before = imu_run(dec, node, 20)
    unknown = send(dec, node.imu(usec=0), node.host_ns)
    after = imu_run(dec, node, 200)
    assert isinstance(unknown, ImuSample)
    assert all(s is not None for s in after)
    t = [s.t for s in [*before, unknown, *after]]  # type: ignore[union-attr]
    assert np.all(np.diff(t) > 0) and np.max(np.diff(t)) < 2 * node.dt
    assert dec.counts["clock_host_time"] == 1 and drops(dec.counts) == 0


def test_dronecan_32_lost_transfers_are_not_a_duplicate() -> None:
    """31 transfers lost: the next good one carries the same 5-bit transfer id as the last one seen.
    The host time says 32 periods went by: a new transfer, 31 counted as seq_gap. A real duplicate
    (the same transfer again at once) is still one."""
    node = CanNode()
    dec = dc.DroneCanDecoder()
    imu_run(dec, node, 40)
    for _ in range(31):
        node.imu()  # lost on the bus
    s = send(dec, node.imu(), node.host_ns)
    assert isinstance(s, ImuSample)
    assert dec.counts.get("duplicate", 0) == 0 and dec.counts["seq_gap"] == 31
    node.tids[dc.DTID_RAW_IMU] = (node.tids[dc.DTID_RAW_IMU] - 1) & 0x1F  # the same transfer, re-sent
    again = node.imu(advance=False)
    assert send(dec, again, node.host_ns + 100_000) is None and dec.counts["duplicate"] == 1


@pytest.mark.parametrize("before", ["one-transfer", "batched"])
def test_dronecan_32_lost_transfers_are_not_a_duplicate_whatever_the_host_period_says(before: str) -> None:
    """31 transfers lost when the host time cannot tell (the transfer period not learnt yet after one
    transfer, or learnt 10x too long from frames handed over in batches): the node time moved by 32
    integration intervals, so the same transfer id is a new transfer, not a duplicate (it was). A re-sent
    transfer (the same node time) is still a duplicate."""
    node = CanNode(rate_hz=1000.0)
    dec = dc.DroneCanDecoder()
    if before == "one-transfer":
        assert isinstance(send(dec, node.imu(), node.host_ns), ImuSample)
    else:
        for _batch in range(50):  # batches of 10 transfers under one host stamp, 10 ms apart
            stamp = node.host_ns
            for _ in range(10):
                send(dec, node.imu(), stamp)
    for _ in range(31):
        node.imu()  # lost on the bus
    s = send(dec, node.imu(), node.host_ns)
    assert isinstance(s, ImuSample), dec.counts
    assert dec.counts.get("duplicate", 0) == 0 and dec.counts["seq_gap"] == 31
    node.tids[dc.DTID_RAW_IMU] = (node.tids[dc.DTID_RAW_IMU] - 1) & 0x1F  # the same transfer, re-sent
    assert send(dec, node.imu(advance=False), node.host_ns + 100_000) is None and dec.counts["duplicate"] == 1


def test_dronecan_batched_arrivals_keep_the_transfer_period_sane() -> None:
    """A CAN driver hands frames over in batches with one host stamp (the gap between transfers is 0):
    the transfer period is learnt from real gaps only, so a later gap neither overflows the lost-transfer
    count (it decayed towards 0 and raised OverflowError, counted as internal) nor invents lost transfers."""
    node = CanNode(rate_hz=1000.0)
    dec = dc.DroneCanDecoder()
    got = []
    for _batch in range(200):  # 200 batches of 10 transfers, 10 ms apart, each batch under one stamp
        stamp = node.host_ns
        for _ in range(10):
            got.append(send(dec, node.imu(), stamp))
    assert all(isinstance(s, ImuSample) for s in got[1:])
    assert dec.counts.get("internal", 0) == 0 and dec.counts.get("seq_gap", 0) == 0, dec.counts
    assert dec.counts.get("duplicate", 0) == 0


def test_dronecan_fix2_no_fix_and_time_only_are_not_fixes() -> None:
    node = CanNode(node_id=12)
    dec = dc.DroneCanDecoder()
    fix = GnssFix(t=0.0, lat=0.0, lon=0.0, h=0.0, vel_ned=np.zeros(3), num_sats=0)
    got = []
    for status in (0, 1, 2, 3):
        payload = bytearray(dc.fix2_payload(fix, 1_000_000))
        v = dc.dronecan_decode(dc.DTID_FIX2, bytes(payload))
        v["status"] = status
        keys = ("timestamp.usec", "latitude_deg_1e8", "longitude_deg_1e8", "height_ellipsoid_mm", "ned_velocity")
        p = dc.dronecan_encode(dc.DTID_FIX2, **{k: v[k] for k in (*keys, "sats_used", "status")})
        got.append(send(dec, node.transfer(dc.DTID_FIX2, p), 10**10))
    assert got[0] is None and got[1] is None
    assert dec.counts["no_fix"] == 2
    assert [g.fix_type for g in got[2:]] == [2, 3]  # type: ignore[union-attr]


def test_dronecan_node_time_beyond_host_uptime_maps_onto_host_time() -> None:
    """A node up 11.6 days, a host up 100 s: its Fix2 time is node time; mapped onto the host
    monotonic clock (as the runtime expects every aiding time) it is not "in the future"."""
    node = CanNode(usec=10**12, host_s=100.0)
    dec = dc.DroneCanDecoder()
    imu = SensorClock()
    for s in imu_run(dec, node, 50):
        imu.update(s.t, s.t_arrival_ns)  # type: ignore[union-attr]
    f_usec = node.usec - 80_000  # the fix was valid 80 ms before the last IMU sample
    fix = GnssFix(t=0.0, lat=0.5, lon=0.3, h=100.0, vel_ned=np.zeros(3), num_sats=9)
    host = node.host_ns + 2_000_000
    g = send(dec, node.transfer(dc.DTID_FIX2, dc.fix2_payload(fix, f_usec)), host)
    assert isinstance(g, GnssFix)
    assert host * 1e-9 - 0.1 < g.t <= host * 1e-9
    assert imu.to_sensor(g.t) == pytest.approx(f_usec * 1e-6, abs=1e-3)  # back on the node's IMU clock


@pytest.mark.parametrize("dt", [1.4e-45, 1e-7, 0.0, 0.05], ids=["denormal", "0.1us", "zero", "10x-nominal"])
def test_dronecan_unphysical_integration_interval_rejected(dt: float) -> None:
    node = CanNode()
    dec = dc.DroneCanDecoder()
    imu_run(dec, node, 20)
    assert send(dec, node.imu(dt=dt), node.host_ns) is None
    assert dec.counts["range"] == 1
    assert all(s is not None for s in imu_run(dec, node, 20))


def test_dronecan_rate_change_is_followed() -> None:
    """The nominal period is a running mean: a node that really changes its rate 200 → 1000 Hz is
    followed after a few samples, not rejected for good."""
    node = CanNode()
    dec = dc.DroneCanDecoder()
    imu_run(dec, node, 20)
    node.dt = 0.001
    after = imu_run(dec, node, 100)
    assert all(s is not None for s in after[10:])


# ---------------------------------------------------------------- DBC
def dbc_pair(db: object, counter: int) -> list[tuple[int, bytes]]:
    return encode_imu_frames(db, (0.0, 0.0, 0.0), (0.0, 0.0, -G), counter)


def test_dbc_time_after_a_long_stall_follows_the_host() -> None:
    """10 s without frames at 200 Hz, the IMU's 8-bit counter running on: the first sample after the
    stall is 10 s later (it advanced 1.045 s: the 8-bit remainder), then dt by dt."""
    dec = DbcImuDecoder(DbcProfile(rate_hz=200.0))
    host = 10**9
    out = []
    for c in range(50):
        host += 5_000_000
        for cid, d in dbc_pair(dec.db, c):
            s = dec.feed(cid, d, host)
        out.append(s)
    c0 = 50 + 2000  # counts on during the stall
    host += 10_000_000_000
    after = []
    for c in range(c0, c0 + 50):
        host += 5_000_000
        for cid, d in dbc_pair(dec.db, c):
            s = dec.feed(cid, d, host)
        after.append(s)
    assert all(s is not None for s in out + after)
    assert after[0].t - out[-1].t == pytest.approx(10.005, abs=1e-6)  # type: ignore[union-attr]
    assert np.diff([s.t for s in after]) == pytest.approx(0.005)  # type: ignore[union-attr]


def test_dbc_counter_reset_recovers() -> None:
    dec = DbcImuDecoder(DbcProfile(rate_hz=200.0))
    host = 10**9
    out = []
    for c in list(range(100, 150)) + list(range(0, 60)):  # the IMU restarted its counter at 0
        host += 5_000_000
        for cid, d in dbc_pair(dec.db, c):
            s = dec.feed(cid, d, host)
        out.append(s)
    check_recovery(out[:50], out[50:], 0.005)
    assert sum(s is None for s in out) == 1


def test_dbc_extended_id_is_not_the_standard_frame() -> None:
    """A 29-bit frame with id 0x180 is another message than the 11-bit IMU_GYRO 0x180."""
    drv = CanImuDriver({"interface": "virtual", "channel": "x"}, protocol="dbc", node_id=None)
    got: list = []
    db = drv.dbc.db  # type: ignore[union-attr]
    for k, ext in enumerate((False, True, True)):
        for cid, d in dbc_pair(db, k):
            drv.handle(can.Message(arbitration_id=cid, data=d, is_extended_id=ext), got.append, 10**9 + k * 5_000_000)
    assert len(got) == 1
    assert drv.health.errors["ignored"] == 4


# ---------------------------------------------------------------- properties of the model
EVENTS = ("reboot", "jump", "stall_running", "stall_paused", "outlier", "none")


@st.composite
def clock_streams(draw: st.DrawFn) -> tuple[dict, list[tuple[int, int, int, int]], list[str]]:
    """(model config, samples (raw, seq, host_ns, segment), event per segment)."""
    bits = draw(st.sampled_from([8, 12, 32, 56]))
    tick, dt = {8: (5e-3, 1), 12: (1e-3, draw(st.integers(1, 10))), 32: (1e-6, 1000), 56: (1e-6, 5000)}[bits]
    seq_bits = 16 if bits == 32 and draw(st.booleans()) else 0
    cfg = {"bits": bits, "tick": tick, "dt": dt, "seq_bits": seq_bits, "gaps": bits == 8}
    mod = 1 << bits
    u = draw(st.integers(0, mod - 1))
    seq = draw(st.integers(0, 0xFFFF))
    host = 10**9 + draw(st.integers(0, 10**9))
    step_ns = round(dt * tick * 1e9)
    out: list[tuple[int, int, int, int]] = []
    events: list[str] = []
    for k in range(draw(st.integers(1, 5))):
        ev = "none" if k == 0 else draw(st.sampled_from(EVENTS if bits >= 32 else EVENTS[:4]))
        events.append(ev)
        if ev == "reboot":
            u, seq = draw(st.integers(0, mod - 1)), draw(st.integers(0, 0xFFFF))
            host += draw(st.integers(0, 3 * 10**9))
        elif ev == "jump":
            u += round(draw(st.floats(0.5, 100.0)) / tick)
        elif ev in ("stall_running", "stall_paused"):
            gap = draw(st.floats(1.0, 12.0))
            host += round(gap * 1e9)
            if ev == "stall_running":
                u += round(gap / tick)
        n = draw(st.integers(3, 25))
        outlier_at = draw(st.integers(1, n - 2)) if ev == "outlier" else -1
        for i in range(n):
            u += dt
            seq += 1
            host += step_ns
            if i == outlier_at:
                off = round(draw(st.sampled_from([-1, 1])) * draw(st.floats(1.0, 1000.0)) / tick)
                out.append(((u + off) % mod, draw(st.integers(0, 0xFFFF)), host, -1))
                continue
            out.append((u % mod, seq & 0xFFFF, host, k))
    return cfg, out, events


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(clock_streams())
def test_model_output_strictly_increasing_and_every_sample_counted_once(stream: tuple) -> None:
    cfg, samples, events = stream
    counts: dict[str, int] = {}
    clk = SourceClock(cfg["bits"], cfg["tick"], counts, seq_bits=cfg["seq_bits"], gaps_from_time=cfg["gaps"])
    accepted: list[tuple[float, int]] = []
    for raw, seq, host, seg in samples:
        t = clk.accept(raw, seq, cfg["dt"], host)
        if t is not None:
            accepted.append((t, seg))
    check_stream(accepted, samples, events, counts)


def check_stream(accepted: list[tuple[float, int]], samples: list, events: list[str], counts: dict) -> None:
    t = [a for a, _ in accepted]
    assert all(math.isfinite(x) for x in t)
    assert np.all(np.diff(t) > 0)
    assert len(accepted) + drops(counts) == len(samples)  # accepted or counted, exactly once
    # recovery: each segment (a run of good samples after a clock event) loses at most its first sample
    for k in range(len(events)):
        n = sum(1 for s in samples if s[3] == k)
        got = sum(1 for _, seg in accepted if seg == k)
        assert got >= n - (0 if k == 0 or events[k] in ("stall_running", "outlier", "none") else 1), (k, events)
    assert not any(seg == -1 for _, seg in accepted)  # a lone outlier is never accepted


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(clock_streams().filter(lambda s: s[0]["bits"] == 32 and s[0]["seq_bits"]))
def test_serial_parser_property(stream: tuple) -> None:
    """The same streams as serial frames through FrameParser."""
    _cfg, samples, events = stream
    imu = SerialSensor()
    p = sf.FrameParser()
    accepted = []
    for raw, seq, host, seg in samples:
        accepted += [(s.t, seg) for s in p.feed(imu.encode(seq, raw), host)]
    check_stream(accepted, samples, events, p.counts)
    assert p.counts.get("frames", 0) == len(accepted)


def test_a_reopen_hint_does_not_outlive_the_next_good_sample() -> None:
    """After a re-open the device kept its clock: the hint is spent on that first good frame, so a
    later lone glitch is dropped as usual and does not move the time base."""
    imu = SerialSensor()
    p = sf.FrameParser()
    feed(p, imu.frames(20))
    p.reopen()
    feed(p, imu.frames(5))
    glitch = (imu.encode(imu.seq + 1, imu.t_us + 7_000_000), imu.host_ns + 500_000)
    after = feed(p, [glitch, *imu.frames(20)])
    assert after[0] is None and all(s is not None for s in after[1:])
    assert p.counts["time_jump"] == 1 and not any(k.startswith("clock_reanchor") for k in p.counts)
