"""Redundant IMUs on separate links: epochs grouped by sensor time, bounded wait in arrival time.

The arrival order of two links is not the sensor-time order: one driver may deliver a burst of
frames before the other delivers the same epochs. An epoch runs when every configured unit has
delivered its sample for that sensor time, or incomplete once samples arrive more than
``epoch_wait_periods`` IMU periods (arrival time) after its first one."""

from __future__ import annotations

import asyncio
import math
import os
import random
import threading
import time
import tty

import numpy as np
import pytest
from conftest import machine_alone
from ins_hil.drivers.serial_frame import encode
from ins_hil.drivers.serial_imu import SerialImuDriver

from ins_hil.fdi.geometry import dual_imu
from ins_hil.runtime.pipeline import GONE_EPOCHS, Pipeline, PipelineConfig
from ins_hil.sim.redundant import simulate
from ins_hil.sim.trajectory import generate, static_profile
from ins_hil.types import ImuSample

RATE = 200.0
DT = 1.0 / RATE
MS = 1_000_000


def _cfg(wait: float = 3.0) -> PipelineConfig:
    return PipelineConfig(
        init="config", init_lat_deg=50.45, init_lon_deg=30.52, init_h=180.0, init_yaw_deg=math.degrees(0.3),
        imu_ids=[0, 1], fdi=True, epoch_wait_periods=wait,
        fdi_options={"geometry": "dual_imu", "dt": DT, "gyro_noise": 0.15 * math.pi / 180 / 60,
                     "accel_noise": 70e-6 * 9.80665},
    )  # fmt: skip


def _series(seconds: float, seed: int = 3) -> list[list[ImuSample]]:
    lat, lon = math.radians(50.45), math.radians(30.52)
    truth = generate(static_profile(yaw=0.3), seconds, DT, lat, lon, 180.0)
    r = simulate(truth, dual_imu(), seed=seed)
    return [r.epoch(k) for k in range(len(r.t))]


def _stamp(s: ImuSample, arrival_ns: int) -> ImuSample:
    return ImuSample(s.t, s.dt, s.dtheta, s.dvel, s.imu_id, s.seq, s.temperature, s.flags, arrival_ns)


def test_bursty_separate_links_give_complete_epochs_in_time_order() -> None:
    """Link 0 delivers 4 frames per read, link 1 the same 4 epochs one period later: every epoch is
    complete (the former arrival-batch rule ran the oldest of each burst without unit 1)."""
    eps = _series(2.0)
    pipe = Pipeline(_cfg())
    states = []
    for b in range(0, len(eps) - 3, 4):
        t_read = round((eps[b + 3][0].t + 0.0005) * 1e9)  # arrival of link 0's burst
        arrivals = [_stamp(eps[b + i][0], t_read) for i in range(4)]
        arrivals += [_stamp(eps[b + i][1], t_read + round(DT * 1e9)) for i in range(4)]
        for s in arrivals:
            st = pipe.imu(s)
            if st is not None:
                states.append(st)
    n = 4 * len(range(0, len(eps) - 3, 4))
    assert pipe.counts.get("imu_epoch_incomplete", 0) == 0
    assert len(states) == n
    ts = [st.t for st in states]
    assert ts == sorted(ts) and len(set(ts)) == len(ts)


def test_missing_unit_runs_the_epoch_after_the_wait_and_late_samples_are_dropped() -> None:
    eps = _series(0.5)
    pipe = Pipeline(_cfg(wait=3.0))
    k_lost = 10
    ran_at: dict[int, int] = {}  # epoch index → index of the arrival that produced its state
    arrivals: list[ImuSample] = []
    for k, (a, b) in enumerate(eps):
        arr = round(a.t * 1e9) + MS
        arrivals.append(_stamp(a, arr))
        if k != k_lost:
            arrivals.append(_stamp(b, arr + 100_000))
    for j, s in enumerate(arrivals):
        st = pipe.imu(s)
        if st is not None:
            ran_at[round(st.t / DT)] = j
    # the epoch whose unit-1 frame was lost ran incomplete (when the next epoch completed)
    assert pipe.counts.get("imu_epoch_incomplete", 0) == 1
    # it ran on the arrival that completed the next epoch (that call returns the newer state)
    assert len(ran_at) == len(eps) - 1 and ran_at[k_lost + 2] == 2 * k_lost + 2
    # unit 1's sample for a sensor time that already ran is dropped and counted once, never run again:
    # older than unit 1's newest sample, the validation boundary rejects it (time not increasing per IMU id)
    assert pipe.imu(_stamp(eps[k_lost][1], 10**12)) is None
    assert pipe.counts["reject_imu_time"] == 1 and "imu_epoch_late_sample" not in pipe.counts


def test_wait_is_bounded_in_arrival_time_and_a_dead_unit_is_not_waited_for() -> None:
    eps = _series(0.6)
    pipe = Pipeline(_cfg(wait=3.0))
    out_at: list[tuple[int, float]] = []  # (arrival index, state time)
    for k, (a, _b) in enumerate(eps):  # unit 1 is dead from the start
        st = pipe.imu(_stamp(a, round(a.t * 1e9) + MS))
        if st is not None:
            out_at.append((k, st.t))
    # while unit 1 is still waited for, an epoch runs once a sample arrives > 3 periods later
    first_k, first_t = out_at[0]
    assert first_k in (3, 4) and math.isclose(first_t, eps[0][0].t)
    # once it has been missing from GONE_EPOCHS epochs, each epoch runs on its own arrival
    k_free = next(k for k, t in out_at if math.isclose(t, eps[k][0].t))
    assert k_free <= GONE_EPOCHS + 5
    assert all(math.isclose(t, eps[k][0].t) for k, t in out_at if k >= k_free)
    assert len(out_at) >= len(eps) - 4
    # the unit comes back: it is waited for again and its epochs are complete
    n_inc = pipe.counts["imu_epoch_incomplete"]
    more = _series(0.8)[len(eps) :]
    for a, b in more:
        arr = round(a.t * 1e9) + MS
        pipe.imu(_stamp(a, arr))
        pipe.imu(_stamp(b, arr + 200_000))
    assert pipe.counts["imu_epoch_incomplete"] <= n_inc + 4  # only the epochs pending at the return


def _writer(fd: int, frames: list[bytes], seed: int, stop: threading.Event) -> None:
    """Write frames at RATE with a jittered schedule and random bursts (whole frames, like a UART FIFO)."""
    rng = random.Random(seed)
    t0 = time.monotonic()
    k = 0
    while k < len(frames) and not stop.is_set():
        burst = rng.choice((1, 1, 2, 3, 5))
        due = t0 + (k + burst) * DT + rng.uniform(0.0, 0.004)
        d = due - time.monotonic()
        if d > 0:
            time.sleep(d)
        data = b"".join(frames[k : k + burst])
        view = memoryview(data)
        while view:
            view = view[os.write(fd, view) :]
        k += burst


@pytest.mark.slow
def test_two_real_ptys_with_jittered_writers_give_complete_epochs() -> None:
    eps = _series(3.0, seed=5)
    pipe = Pipeline(_cfg(wait=40.0))  # 200 ms: far above the writers' jitter, even on a busy machine
    masters, paths = [], []
    for _ in range(2):
        m, s = os.openpty()
        tty.setraw(s)
        masters.append((m, s))
        paths.append(os.ttyname(s))
    frames = [[encode(ep[u]) for ep in eps] for u in range(2)]
    states: list[float] = []

    async def go() -> None:
        drivers = [SerialImuDriver(p, 921600, name=f"imu{u}") for u, p in enumerate(paths)]

        def sink(s: ImuSample) -> None:  # both drivers feed one pipeline, in arrival order
            st = pipe.imu(s)
            if st is not None:
                states.append(st.t)

        tasks = [asyncio.create_task(d.run(sink)) for d in drivers]
        for _ in range(200):
            if all(d.health.connected for d in drivers):
                break
            await asyncio.sleep(0.01)
        stop = threading.Event()
        ths = [threading.Thread(target=_writer, args=(masters[u][0], frames[u], u, stop)) for u in range(2)]
        for th in ths:
            th.start()
        try:
            end = time.monotonic() + 60.0  # until every epoch gave its state (3 s idle; a hang guard)
            while len(states) < len(eps) and time.monotonic() < end:
                await asyncio.sleep(0.01)
            await asyncio.sleep(0.1)  # and no more (a state twice would show)
        finally:
            stop.set()
            for th in ths:
                th.join()
            for t in tasks:
                t.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)

    try:
        # alone on the machine: the epochs' completeness is a real-time property (a writer thread or the reader
        # starved for ~0.3 s by another worker's real-time test puts the links more than the wait apart)
        with machine_alone():
            asyncio.run(go())
    finally:
        for m, s in masters:
            os.close(m)
            os.close(s)
    assert pipe.counts.get("imu_epoch_incomplete", 0) == 0
    assert len(states) == len(eps)
    assert np.all(np.diff(states) > 0)


def test_a_bad_epoch_wait_is_rejected_naming_the_key() -> None:
    with pytest.raises(ValueError, match=r"core\.epoch_wait_periods"):
        Pipeline(_cfg(wait=0.0))


def test_a_lost_frame_is_given_up_when_its_unit_delivers_a_later_sample() -> None:
    """Links deliver in order: unit 1's sample for epoch k+1 arriving first means its k is lost;
    epoch k runs on that arrival, without waiting for unit 0's k+1 or for the time bound."""
    eps = _series(0.2)
    pipe = Pipeline(_cfg(wait=3.0))
    k = 5
    for j in range(k):
        for s in eps[j]:
            pipe.imu(_stamp(s, round(s.t * 1e9)))
    arr = round(eps[k][0].t * 1e9)
    assert pipe.imu(_stamp(eps[k][0], arr)) is None  # unit 1's frame for epoch k is lost
    st = pipe.imu(_stamp(eps[k + 1][1], arr + 100_000))  # unit 1 goes on with epoch k+1
    assert st is not None and math.isclose(st.t, eps[k][0].t)
    assert pipe.counts["imu_epoch_incomplete"] == 1
    st = pipe.imu(_stamp(eps[k + 1][0], arr + 200_000))
    assert st is not None and math.isclose(st.t, eps[k + 1][0].t)
    assert pipe.counts["imu_epoch_incomplete"] == 1
