"""Serial IMU: frame codec fuzzing, and the async driver over real pseudo-terminals."""

from __future__ import annotations

import asyncio
import os
import random
import time
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from ins_hil.drivers import serial_frame as sf
from ins_hil.drivers.serial_imu import SerialImuDriver
from runtime_helpers import open_raw_pty, start_driver, wait_for_count

from ins_hil.types import ImuSample

f32 = st.floats(min_value=-0.875, max_value=0.875, allow_nan=False, width=32)


def _sample(seq: int, t: float, dt: float = 0.001, imu_id: int = 0) -> ImuSample:
    return ImuSample(
        t=t, dt=dt, dtheta=np.array([1e-4, -2e-4, 3e-5]), dvel=np.array([1e-3, 0.0, -9.80665 * dt]),
        imu_id=imu_id, seq=seq, temperature=30.0,
    )  # fmt: skip


@settings(max_examples=100, deadline=None)
@given(
    st.lists(f32, min_size=6, max_size=6),
    st.integers(0, 255),
    st.integers(0, 0xFFFF),
    st.integers(0, 0xFFFFFFFF),
    st.integers(1, 0xFFFF),
    st.floats(-300, 300),
    st.integers(0, 255),
)
def test_round_trip_property(
    v: list[float], imu_id: int, seq: int, t_us: int, dt_us: int, temp: float, flags: int
) -> None:
    s = ImuSample(
        t=t_us * 1e-6, dt=dt_us * 1e-6, dtheta=np.array(v[:3]), dvel=np.array(v[3:]) * 10, imu_id=imu_id, seq=seq,
        temperature=temp, flags=flags,
    )  # fmt: skip
    d = sf.decode(sf.encode(s))
    assert (d.imu_id, d.seq, d.flags) == (imu_id, seq, flags)
    assert round(d.t * 1e6) == t_us and round(d.dt * 1e6) == dt_us
    np.testing.assert_array_equal(d.dtheta, np.float32(v[:3]))
    assert d.temperature == pytest.approx(temp, abs=0.006)


@settings(max_examples=150, deadline=None)
@given(st.binary(max_size=400), st.integers(1, 64))
def test_parser_never_crashes_on_garbage(data: bytes, chunk: int) -> None:
    p = sf.FrameParser()
    out = []
    for i in range(0, len(data), chunk):
        out += p.feed(data[i : i + chunk])
    # random bytes essentially never carry a valid CRC-16 frame; if one does it must decode cleanly
    for s in out:
        assert np.all(np.isfinite(s.dtheta)) and np.all(np.isfinite(s.dvel))


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_every_corrupted_frame_is_counted_and_none_accepted(data: st.DataObject) -> None:
    """Bit flips, truncation and oversize frames in a stream of good frames: each bad frame is
    dropped and counted; every good frame comes through in order."""
    n = 40
    frames = [bytearray(sf.encode(_sample(i, 1.0 + i * 1e-3))) for i in range(n)]
    bad = set(data.draw(st.sets(st.integers(1, n - 2), max_size=8)))
    stream = bytearray()
    for i, f in enumerate(frames):
        if i in bad:
            kind = data.draw(st.sampled_from(["flip", "truncate", "oversize"]))
            if kind == "flip":
                pos = data.draw(st.integers(2, sf.FRAME_LEN - 1))
                f[pos] ^= 1 << data.draw(st.integers(0, 7))
            elif kind == "truncate":
                f = f[: data.draw(st.integers(3, sf.FRAME_LEN - 1))]
            else:
                f = f[:39] + bytes(data.draw(st.integers(1, 9))) + f[39:]
        stream += f
    p = sf.FrameParser()
    out = []
    step = data.draw(st.integers(1, 100))
    for i in range(0, len(stream), step):
        out += p.feed(bytes(stream[i : i + step]))
    assert [s.seq for s in out] == [i for i in range(n) if i not in bad]
    dropped = sum(p.counts.get(k, 0) for k in ("crc", "version", "nonfinite", "range"))
    # every bad frame was counted (a truncated frame makes the next one's CRC window fail: ≥)
    assert dropped >= len(bad)
    assert p.counts.get("seq_gap", 0) == len(bad)


def test_nan_out_of_range_duplicates_and_time_faults() -> None:
    p = sf.FrameParser()
    good = [sf.encode(_sample(i, 2.0 + i * 1e-3)) for i in range(6)]
    nan = _sample(6, 2.006)
    nan.dtheta = np.array([np.nan, 0, 0])
    inf = _sample(6, 2.006)
    inf.dvel = np.array([0, np.inf, 0])
    big = _sample(6, 2.006)
    big.dtheta = np.array([5.0, 0, 0])  # 5 rad in 1 ms: not physical
    back = _sample(7, 1.5)  # time backwards
    jump = _sample(8, 50.0)  # a lone clock glitch
    ok = _sample(9, 2.009)
    out = p.feed(b"".join(good) + good[5] + sf.encode(nan) + sf.encode(inf) + sf.encode(big))
    out += p.feed(sf.encode(back) + sf.encode(jump) + sf.encode(ok))
    assert [s.seq for s in out] == [0, 1, 2, 3, 4, 5, 9]
    c = p.counts
    assert (c["duplicate"], c["nonfinite"], c["range"], c["time_backwards"], c["time_jump"]) == (1, 2, 1, 1, 1)
    # a real clock jump: two frames agree on the new time base → re-anchored, the output continues
    # after the last accepted time (2.009 s) by the intervals the sensor counted (no host times here)
    out = p.feed(sf.encode(_sample(10, 100.0)) + sf.encode(_sample(11, 100.001)) + sf.encode(_sample(12, 100.002)))
    assert [s.seq for s in out] == [11, 12] and p.counts["clock_reanchor_jump"] == 1
    assert out[0].t == pytest.approx(2.011) and out[-1].t == pytest.approx(2.012)


def test_time_unwraps_over_32bit_counter() -> None:
    p = sf.FrameParser()
    t0 = (0xFFFFFFFF - 1500) * 1e-6
    out = []
    for i in range(4):
        s = _sample(i, t0 + i * 1e-3)
        out += p.feed(sf.encode(s))
    assert np.all(np.diff([s.t for s in out]) == pytest.approx(1e-3, abs=2e-6))


# ---------------------------------------------------------------- real pseudo-terminals
async def _imu_writer(master: int, n: int, rate_hz: float, corrupt: float = 0.0, seed: int = 0) -> list[int]:
    """Write n frames at rate_hz (1 kHz: bursts of 10 every 10 ms). Returns the seqs corrupted."""
    rng = random.Random(seed)
    bad = []
    t0 = time.monotonic()
    per = max(1, int(rate_hz / 100))
    for i0 in range(0, n, per):
        buf = bytearray()
        for i in range(i0, min(n, i0 + per)):
            f = bytearray(sf.encode(_sample(i & 0xFFFF, 5.0 + i / rate_hz)))
            if corrupt and 0 < i < n - 1 and rng.random() < corrupt:
                f[rng.randrange(2, sf.FRAME_LEN)] ^= 1 << rng.randrange(8)
                bad.append(i)
            buf += f
        os.write(master, bytes(buf))
        due = t0 + (i0 + per) / rate_hz
        await asyncio.sleep(max(0.0, due - time.monotonic()))
    return bad


def test_pty_1khz_with_corruption() -> None:
    async def main() -> tuple[list[ImuSample], SerialImuDriver, list[int]]:
        master, name = open_raw_pty()
        drv = SerialImuDriver(name, 921600)
        got, task = await start_driver(drv)
        bad = await _imu_writer(master, 2000, 1000.0, corrupt=0.01, seed=3)
        await wait_for_count(got, 2000 - len(bad))
        task.cancel()
        os.close(master)
        return got, drv, bad

    got, drv, bad = asyncio.run(main())
    assert bad, "the 1% corruption must have hit some frames"
    assert [s.seq for s in got] == [i for i in range(2000) if i not in bad]
    assert drv.health.errors["crc"] >= len(bad)
    assert drv.health.errors["seq_gap"] == len(bad)
    assert all(s.t_arrival_ns > 0 for s in got)
    assert drv.health.samples == len(got)


def test_a_pty_is_read_with_one_os_read_per_readiness(monkeypatch: pytest.MonkeyPatch) -> None:
    """A port with a file descriptor is read directly (os.read on the non-blocking fd), not through pyserial's
    read, which adds a select before and after every read (three system calls per chunk on the IMU path)."""
    import serial

    def no(*_a: object, **_k: object) -> bytes:
        raise AssertionError("pyserial's read on the IMU path")

    monkeypatch.setattr(serial.Serial, "read", no)

    async def main() -> list[ImuSample]:
        master, name = open_raw_pty()
        drv = SerialImuDriver(name, 921600)
        got, task = await start_driver(drv)
        await _imu_writer(master, 200, 1000.0)
        await wait_for_count(got, 200)
        task.cancel()
        os.close(master)
        return got

    got = asyncio.run(main())
    assert [s.seq for s in got] == list(range(200))


async def _until(cond: Callable[[], bool], timeout: float = 30.0) -> None:
    """Poll every 20 ms until ``cond()`` or ``timeout`` s (a hang guard: a busy machine may take seconds)."""
    end = time.monotonic() + timeout
    while not cond() and time.monotonic() < end:
        await asyncio.sleep(0.02)


def test_pty_vanishes_and_comes_back(tmp_path: Path) -> None:
    """The device path disappears (pty closed) and a new device appears under the same name."""

    async def main() -> tuple[list[ImuSample], SerialImuDriver]:
        link = tmp_path / "ttyIMU"
        drv = SerialImuDriver(str(link), 115200, stale_s=1.0)
        got: list[ImuSample] = []
        task = asyncio.create_task(drv.run(got.append))  # type: ignore[arg-type]
        await _until(lambda: drv.health.errors.get("open_failed", 0) >= 1)  # nothing there yet: open fails, backoff
        m1, n1 = open_raw_pty()
        link.symlink_to(n1)
        while not drv.health.connected:
            await asyncio.sleep(0.01)
        await _imu_writer(m1, 50, 500.0)
        await wait_for_count(got, 50)  # read before the unplug (the waits: hang guards, 30 s)
        os.close(m1)  # unplugged
        link.unlink()
        await _until(lambda: not drv.health.connected)
        m2, n2 = open_raw_pty()
        link.symlink_to(n2)
        await _until(lambda: drv.health.connected)
        await _imu_writer(m2, 50, 500.0)
        await wait_for_count(got, 100)
        await asyncio.sleep(0.2)  # nothing more comes (a duplicate would show in the count)
        task.cancel()
        os.close(m2)
        return got, drv

    got, drv = asyncio.run(main())
    assert len(got) == 100
    # the new device restarted its clock and sequence: the driver kept the time base, so the output
    # continues (the pipeline drops any sample not after the previous one)
    t = np.array([s.t for s in got])
    assert np.all(np.diff(t) > 0)
    assert drv.health.errors["clock_reanchor_reboot"] == 1
    assert drv.health.reconnects >= 1
    assert drv.health.errors.get("open_failed", 0) >= 1
    assert drv.health.errors.get("port_lost", 0) + drv.health.errors.get("silence", 0) >= 1


def test_pty_sensor_clock_restarts_mid_stream_navigation_resumes() -> None:
    """The sensor on the other end of a real pty reboots after 30 min of uptime, the link staying
    open: its clock restarts at 0 and its sequence at 0. The driver's clock model re-anchors (one
    frame lost: the bound is max(3 periods, 50 ms)), and the pipeline navigates on through it (it
    drops any sample whose time is not after the previous one)."""
    from ins_hil.runtime.pipeline import Pipeline, PipelineConfig

    n1, n2, rate = 400, 400, 1000.0

    async def writer(master: int) -> None:
        t0 = time.monotonic()
        for i0 in range(0, n1 + n2, 10):
            buf = b""
            for i in range(i0, i0 + 10):
                if i < n1:
                    buf += sf.encode(_sample(1000 + i, 1800.0 + i / rate))
                else:
                    buf += sf.encode(_sample(i - n1, (i - n1 + 1) / rate))  # rebooted: t from 1 ms, seq from 0
            os.write(master, buf)
            await asyncio.sleep(max(0.0, t0 + (i0 + 10) / rate - time.monotonic()))

    async def main() -> tuple[list[ImuSample], SerialImuDriver]:
        master, name = open_raw_pty()
        drv = SerialImuDriver(name, 921600)
        got, task = await start_driver(drv)
        await writer(master)
        await wait_for_count(got, n1 + n2 - 1)
        task.cancel()
        os.close(master)
        return got, drv

    got, drv = asyncio.run(main())
    after = [s for s in got if s.seq < 1000]
    assert len(got) - len(after) == n1
    assert after[0].seq <= 1 and [s.seq for s in after] == list(range(after[0].seq, n2))
    assert (n2 - len(after)) / rate <= max(3 / rate, 0.05)
    assert np.all(np.diff([s.t for s in got]) > 0)
    assert drv.health.errors["clock_reanchor_reboot"] == 1
    pipe = Pipeline(
        PipelineConfig(init="config", init_lat_deg=50.0, init_lon_deg=30.0, init_h=100.0, level_samples=100)
    )
    states = [pipe.imu(s) for s in got]
    assert all(st is not None for st in states[len(got) - len(after) :])  # navigation goes on after the reboot
    assert pipe.counts.get("imu_time_backwards", 0) == 0


def test_config_errors_name_the_key() -> None:
    with pytest.raises(ValueError, match="port"):
        SerialImuDriver.from_config({"type": "serial_imu"})
    with pytest.raises(ValueError, match="bauds"):
        SerialImuDriver.from_config({"port": "/dev/null", "bauds": 9600})
    d = SerialImuDriver.from_config({"type": "serial_imu", "port": "/dev/ttyUSB0", "baudrate": 460800})
    assert (d.port, d.baudrate, d.name) == ("/dev/ttyUSB0", 460800, "serial_imu")


def test_a_sink_failing_on_one_frame_of_a_read_loses_only_that_frame() -> None:
    """The frames of one read go to the sink's ``many`` in one call; if it raises on one of them, that frame is
    counted as a ``sink_error`` and every other frame of the read still reaches the sink, in order."""
    got: list[int] = []
    bad = {2, 5}  # the sink raises on these frames' seq

    def take(s: ImuSample) -> None:
        if s.seq in bad:
            raise RuntimeError(f"sink fault on {s.seq}")
        got.append(s.seq)

    calls = []

    def many(samples: Iterable[ImuSample]) -> None:
        calls.append(1)
        for s in samples:
            take(s)

    take.many = many  # type: ignore[attr-defined]
    drv = SerialImuDriver("/dev/null")
    drv.feed(b"".join(sf.encode(_sample(i, 1.0 + i * 1e-3)) for i in range(8)), take, 1_000_000)
    assert got == [0, 1, 3, 4, 6, 7]
    assert drv.health.errors["sink_error"] == 2
    assert drv.health.samples == 8 and calls == [1]
    drv.feed(b"".join(sf.encode(_sample(i, 1.0 + i * 1e-3)) for i in range(8, 11)), take, 2_000_000)
    assert got[6:] == [8, 9, 10] and drv.health.errors["sink_error"] == 2 and calls == [1, 1]  # one call a read
