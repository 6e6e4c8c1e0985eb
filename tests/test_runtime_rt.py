"""Real-time scheduling option and the loop's deferred aiding fusion."""

from __future__ import annotations

import asyncio
import os

import numpy as np
import pytest
from runtime_helpers import sim_config, sim_config_dict

from ins_hil.config import ConfigError, from_dict
from ins_hil.runtime.loop import AID_MAX_WAIT_S, Gateway
from ins_hil.runtime.pipeline import aiding_monitor
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


def test_the_c_core_fuses_late_fixes_as_current_for_the_drift_monitor() -> None:
    # the C core has no roll-back: the drift monitor must compare a late fix with the current state
    assert aiding_monitor({}, "c", {}).cfg.late_fix_as_current
    assert aiding_monitor({}, "python", {"delay_compensation": False}).cfg.late_fix_as_current
    assert not aiding_monitor({}, "python", {}).cfg.late_fix_as_current


def test_aiding_is_fused_after_the_next_published_imu_state() -> None:
    cfg = sim_config(core={"init": "config", "init_lat_deg": 50.0, "init_lon_deg": 30.0, "init_h": 100.0})

    async def go() -> tuple[list[str], list[str], list[str]]:
        gw = Gateway(cfg)
        order: list[str] = []
        gw.on_state.append(lambda st: order.append(f"state {st.t:.3f}"))
        fuse = gw.pipeline.aid
        gw.pipeline.aid = lambda m: (order.append(f"aid {type(m).__name__}"), fuse(m))[1]  # type: ignore[method-assign]
        gw.imu_clock.update(0.0, 1)
        for k in range(1, 4):
            gw.queue.append((_imu(k), "imu0"))
        gw._process_queue()
        # a baro sample with IMU samples behind it in the queue: fused once the queue is empty
        gw.queue.append((BaroSample(t=0.0035, pressure=1e5), "gnss"))
        gw.queue.append((_imu(4), "imu0"))
        gw.queue.append((_imu(5), "imu0"))
        gw._process_queue()
        first = list(order)
        order.clear()
        # a backlog: the aiding has already waited longer than AID_MAX_WAIT_S when the next IMU state is
        # published, so it is fused right then, before the IMU samples still in the queue
        gw.queue.append((BaroSample(t=0.0055, pressure=1e5), "gnss"))
        gw.queue.append((_imu(6), "imu0"))
        gw.queue.append((_imu(7), "imu0"))
        gw._aid_wait.append(gw.queue.popleft()[0])
        gw._aid_since, gw._published = 0, False
        gw._process_queue()
        backlog = list(order)
        order.clear()
        # no IMU sample follows: fused by the timer after at most AID_MAX_WAIT_S
        gw.queue.append((GnssFix(t=0.0045, lat=0.87, lon=0.52, h=100.0), "gnss"))
        gw._process_queue()
        assert order == [] and gw._aid_wait
        await asyncio.sleep(AID_MAX_WAIT_S + 0.02)
        return first, backlog, order

    first, backlog, second = asyncio.run(go())
    assert backlog == ["state 0.006", "aid BaroSample", "state 0.007"]
    assert first == ["state 0.001", "state 0.002", "state 0.003", "state 0.004", "state 0.005", "aid BaroSample"]
    assert second == ["aid GnssFix"]
