"""Real-time scheduling option and the loop's deferred aiding fusion."""

from __future__ import annotations

import asyncio
import os

import numpy as np
import pytest
from runtime_helpers import sim_config, sim_config_dict, sim_gateway

from ins_hil.config import ConfigError, from_dict
from ins_hil.runtime.pipeline import PipelineConfig, aiding_config, aiding_monitor, nav_config
from ins_hil.runtime.rt import lock_memory, policy, set_realtime
from ins_hil.types import BaroSample, GnssFix, ImuSample

G = 9.80665


def _imu(k: int) -> ImuSample:
    return ImuSample(t=k * 1e-3, dt=1e-3, dtheta=np.zeros(3), dvel=np.array((0.0, 0.0, -G * 1e-3)))


@pytest.mark.parametrize("bad", [-1, 100, 1.5, "50", True])
def test_rt_priority_is_validated(bad: object) -> None:
    with pytest.raises(ConfigError, match=r"gateway\.rt_priority"):
        from_dict(sim_config_dict(gateway={"rt_priority": bad}))
    assert from_dict(sim_config_dict(gateway={"rt_priority": 10})).gateway.rt_priority == 10


def test_set_realtime_range_and_time_sharing() -> None:
    with pytest.raises(ValueError):
        set_realtime(100)
    before = policy()
    assert before.startswith("SCHED_")
    assert set_realtime(0) == ""  # time-sharing is always allowed
    assert policy() == "SCHED_OTHER"


def test_set_realtime_in_a_child_process() -> None:
    # SCHED_FIFO and locked memory in a forked child (root here; elsewhere the reason is returned, never raised)
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # pragma: no cover - child
        why = set_realtime(10) or lock_memory()
        locked = any(ln.startswith("VmLck:") and ln.split()[1] != "0" for ln in open("/proc/self/status"))
        os.write(w, (why or (policy() if locked else "not locked")).encode())
        os._exit(0)
    os.close(w)
    os.waitpid(pid, 0)
    got = os.read(r, 200).decode()
    os.close(r)
    assert got == "SCHED_FIFO 10" or "permission" in got


def test_the_drift_monitor_follows_the_delay_compensation_of_either_core() -> None:
    # both cores roll back a late fix (delay.compensation, the default) or fuse it as current (off)
    off = nav_config({"delay": {"compensation": False}})
    for core in ("c", "python"):
        assert not PipelineConfig(core=core).aiding_config().late_fix_as_current
        assert PipelineConfig(core=core, nav=off).aiding_config().late_fix_as_current
        assert (
            not PipelineConfig(core=core, nav=off, aiding_options={"late_fix_as_current": False})
            .aiding_config()
            .late_fix_as_current
        )
    assert aiding_monitor(aiding_config({}, off), off).cfg.late_fix_as_current


def test_aiding_is_fused_in_segments_one_per_gap_after_the_published_state() -> None:
    cfg = sim_config(core={"init": "config", "init_lat_deg": 50.0, "init_lon_deg": 30.0, "init_h": 100.0})

    async def go() -> tuple[list[str], list[str], dict[str, int]]:
        gw = sim_gateway(cfg)
        order: list[str] = []
        gw.on_state.append(lambda st: order.append(f"state {st.t:.3f}"))
        core = gw.pipeline.core
        assert core is not None
        fuse_steps = core.fuse_steps

        def traced(m: object) -> object:
            order.append(f"update {type(m).__name__}")
            for _ in fuse_steps(m):  # type: ignore[arg-type]
                order.append("gap")
                yield
            order.append(f"fused {type(m).__name__}")

        core.fuse_steps = traced  # type: ignore[method-assign,assignment]
        mon = gw.pipeline._aid_mon
        assert mon is not None
        check = mon.check
        mon.check = lambda m, st: (order.append(f"check {type(m).__name__}"), check(m, st))[1]  # type: ignore[method-assign]
        gw.imu_clock.update(0.0, 1)
        for k in range(1, 4):
            gw.queue.append((_imu(k), "imu0"))
        gw._process_queue()
        # a GNSS fix with an IMU sample right behind it in the queue: its first segment (the drift
        # monitor's check) is in the gap after that sample's state, then one segment per gap
        # (check | position update | velocity update), each once the queue is empty
        gw.queue.append((GnssFix(t=0.0035, lat=0.87, lon=0.52, h=100.0, vel_ned=(0.0, 0.0, 0.0)), "gnss"))
        gw.queue.append((_imu(4), "imu0"))
        gw._process_queue()
        for k in (5, 6, 7, 8):
            gw.queue.append((_imu(k), "imu0"))
            gw._process_queue()
        first = list(order)
        order.clear()
        # a backlog (an IMU sample already queued when a state is published: no slack in that gap):
        # the gap's segment runs at the start of the next epoch
        gw.queue.append((BaroSample(t=0.0085, pressure=1e5), "gnss"))
        for k in (9, 10, 11):
            gw.queue.append((_imu(k), "imu0"))
        gw._process_queue()
        return first, order, dict(gw.pipeline.counts)

    first, backlog, counts = asyncio.run(go())
    assert first == [
        "state 0.001", "state 0.002", "state 0.003", "state 0.004",
        "check GnssFix",  # gap after 0.004
        "state 0.005", "update GnssFix", "gap",  # gap after 0.005: position update
        "state 0.006", "fused GnssFix",  # gap after 0.006: velocity update
        "state 0.007", "state 0.008",
    ]  # fmt: skip
    assert backlog == [
        "state 0.009", "check BaroSample", "update BaroSample", "fused BaroSample", "state 0.010", "state 0.011"
    ]  # fmt: skip
    assert counts["fused_GnssFix"] == 1 and counts["fused_BaroSample"] == 1


def test_live_and_replay_run_the_same_aiding_segments() -> None:
    """The pipeline's segment schedule depends only on the input order: a log replay (no work() calls)
    reproduces the live loop's states bit for bit, with the aiding work split over gaps."""
    from ins_hil.runtime.pipeline import Pipeline, PipelineConfig

    def run(live: bool) -> list[tuple[float, ...]]:
        p = Pipeline(PipelineConfig(init="config", init_lat_deg=50.0, init_lon_deg=30.0, init_h=100.0))
        out = []
        rng = np.random.default_rng(3)
        for k in range(1, 400):
            s = _imu(k)
            s.dvel = s.dvel + rng.normal(0.0, 1e-4, 3)
            st = p.imu(s)
            assert st is not None
            out.append((*st.vel_ned, st.lat, st.lon, st.h, *st.q_nb))
            if k % 50 == 0:
                p.aid(GnssFix(t=k * 1e-3, lat=0.8726646 + 1e-7, lon=0.5235988, h=101.0, vel_ned=(0.1, 0.0, 0.0)))
            if k % 20 == 0:
                p.aid(BaroSample(t=k * 1e-3, pressure=1e5))
            if live:
                p.work()
        p.flush()
        assert p.counts.get("fused_GnssFix") == 7 and p.pending_work() == 0
        return out

    live, replay = run(True), run(False)
    assert live == replay
