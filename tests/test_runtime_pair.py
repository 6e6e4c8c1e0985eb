"""The two units' samples of one read in one pipeline call (``Pipeline.imu_pair``, the live loop's path for the
two frames of one serial read) against ``Pipeline.imu`` on each: the same states, counts, events and validation
times, whatever the stream does (refused samples, a unit that drops out, duplicates, a clock that steps back,
samples without an arrival stamp, the FDI isolating a fault)."""

from __future__ import annotations

import dataclasses
import math
import random

import numpy as np

from ins_hil.fdi.geometry import dual_imu
from ins_hil.runtime.pipeline import Pipeline, PipelineConfig
from ins_hil.sim.redundant import simulate
from ins_hil.sim.trajectory import generate, static_profile
from ins_hil.types import ImuSample

RATE = 200.0
DT = 1.0 / RATE


def _cfg(wait: float = 3.0, core: str = "python") -> PipelineConfig:
    return PipelineConfig(
        init="config", init_lat_deg=50.45, init_lon_deg=30.52, init_h=180.0, init_yaw_deg=math.degrees(0.3),
        imu_ids=[0, 1], fdi=True, epoch_wait_periods=wait, core=core,
        fdi_options={"geometry": "dual_imu", "dt": DT, "gyro_noise": 0.15 * math.pi / 180 / 60,
                     "accel_noise": 70e-6 * 9.80665},
    )  # fmt: skip


def _stream(seconds: float, seed: int) -> list[ImuSample]:
    """Both units' samples in arrival order, two per epoch (one read), with disturbances drawn by ``seed``; a
    bias step on unit 1's gyro z from the middle on."""
    lat, lon = math.radians(50.45), math.radians(30.52)
    truth = generate(static_profile(yaw=0.3), seconds, DT, lat, lon, 180.0)
    r = simulate(truth, dual_imu(), seed=seed)
    rng = random.Random(seed)
    out: list[ImuSample] = []
    n = len(r.t)
    for k in range(n):
        a, b = r.epoch(k)
        if k > n // 2:
            b = dataclasses.replace(b, dtheta=b.dtheta + np.array((0.0, 0.0, 2e-3 * DT)))
        arr = round((a.t + 0.0004) * 1e9)
        pair = [dataclasses.replace(a, t_arrival_ns=arr), dataclasses.replace(b, t_arrival_ns=arr)]
        u = rng.random()
        if u < 0.03:  # a non-finite sample (refused)
            i = rng.randrange(2)
            pair[i] = dataclasses.replace(pair[i], dvel=np.array((math.nan, 0.0, 0.0)))
        elif u < 0.05:  # the other unit's frame first
            pair.reverse()
        elif u < 0.07:  # a unit's frame lost
            pair.pop(rng.randrange(2))
        elif u < 0.075:  # a non-finite time or step (refused; the pair test does no arithmetic on it)
            i = rng.randrange(2)
            pair[i] = dataclasses.replace(pair[i], **{rng.choice(("t", "dt")): rng.choice((math.nan, math.inf))})
        elif u < 0.085:  # no arrival stamp (a replay of an old recording)
            pair = [dataclasses.replace(s, t_arrival_ns=0) for s in pair]
        # a time that steps back once, a duplicate of unit 0's frame (each refused for its time; 0.3 s apart: two
        # such within 0.1 s would be taken for a clock restart)
        if k in (n // 5, n // 2, 4 * n // 5):
            pair[0] = dataclasses.replace(pair[0], t=pair[0].t - 0.5)
        elif k in (n // 5 + 60, n // 2 + 60, 4 * n // 5 + 60) and len(pair) == 2:
            pair[1] = dataclasses.replace(pair[0])
        if 0.3 * n < k < 0.3 * n + 30:  # unit 1 silent for 30 epochs: counted missing, then gone, then back
            pair = [s for s in pair if s.imu_id != 1]
        out += pair
    return out


def _key(st: object) -> object:
    if st is None:
        return None
    return (st.t, st.q_nb.tolist(), st.vel_ned.tolist(), st.lat, st.lon, st.h, st.std_att.tolist())  # type: ignore[attr-defined]


def _run(stream: list[ImuSample], pairs: bool, core: str) -> tuple[list[object], Pipeline, int, int]:
    """Each sample in order; with ``pairs`` as the live loop takes them: two in one call when ``pair_ready``.
    Returns the states published (None for a call that published none: per sample), the pipeline, and how
    many pair calls and single calls ran."""
    pipe = Pipeline(_cfg(core=core))
    out: list[object] = []
    n_pair = n_one = 0
    i = 0
    while i < len(stream):
        s = stream[i]
        if pairs and i + 1 < len(stream) and pipe.pair_ready(s, stream[i + 1]):
            t_first, st = pipe.imu_pair(s, stream[i + 1])
            out += [("t", t_first), None, ("t", pipe.imu_t), _key(st)]
            n_pair += 1
            i += 2
            continue
        st = pipe.imu(s)
        out += [("t", pipe.imu_t), _key(st)]
        n_one += 1
        i += 1
    return out, pipe, n_pair, n_one


def _events(pipe: Pipeline) -> list[tuple[object, ...]]:
    return [(e.t, e.sensor, e.mode, e.isolated, e.cleared) for e in pipe.events]


def test_a_pair_in_one_call_gives_what_one_call_each_gives() -> None:
    for core in ("python", "c"):
        for seed in (1, 2):
            stream = _stream(8.0, seed)
            seq, p_seq, _, _ = _run(stream, False, core)
            par, p_par, n_pair, n_one = _run(stream, True, core)
            assert par == seq, (core, seed)
            assert p_par.counts == p_seq.counts and _events(p_par) == _events(p_seq)
            assert _key(p_par.last_state) == _key(p_seq.last_state)
            # the stream took both ways: most epochs as a pair, the disturbed ones one sample at a time
            assert n_pair > 1200 and n_one > 50, (n_pair, n_one)
            c = p_seq.counts
            for k in ("reject_imu_nonfinite", "imu_epoch_incomplete", "reject_imu_time"):
                assert c.get(k, 0) > 0, (k, c)
            assert {"imu1.gyro", "imu1.accel"} <= {e[1] for e in _events(p_seq)}  # unit 1's silence isolated


def test_pair_ready_refuses_what_the_grouping_would_do_otherwise() -> None:
    stream = _stream(0.2, 3)
    a, b = stream[0], stream[1]
    pipe = Pipeline(_cfg())
    assert pipe.pair_ready(a, b) and not pipe.pair_ready(b, b)  # the same unit twice: a duplicate
    assert not pipe.pair_ready(a, dataclasses.replace(b, t=b.t + DT))  # two epochs
    assert not pipe.pair_ready(a, dataclasses.replace(b, imu_id=2))  # a unit not configured
    pipe.imu(a)  # an epoch waits for unit 1: the grouping's general rule decides
    assert not pipe.pair_ready(stream[2], stream[3])
    pipe.imu(b)
    assert pipe.pair_ready(stream[2], stream[3])
    assert not pipe.pair_ready(stream[0], stream[1])  # an epoch that already ran (late samples)
    short = Pipeline(_cfg(wait=1e-8))  # a wait under a nanosecond: unit 0's sample would run alone
    assert not short.pair_ready(a, b)
    three = Pipeline(dataclasses.replace(_cfg(), imu_ids=[0, 1, 2], fdi=False))
    assert not three.pair_ready(a, b)
    # samples the validation boundary has not seen yet: no arithmetic on a non-finite time or step (imu() takes
    # each, and refuses it)
    fresh = Pipeline(_cfg())
    for bad in (math.nan, math.inf, -math.inf):
        c, d = stream[4], stream[5]
        assert not fresh.pair_ready(dataclasses.replace(c, t=bad), d)
        assert not fresh.pair_ready(c, dataclasses.replace(d, t=bad))
        assert not fresh.pair_ready(dataclasses.replace(c, dt=bad), d)
    assert fresh.imu(dataclasses.replace(stream[4], t=math.nan)) is None
    assert fresh.counts == {"reject_imu_nonfinite": 1}
