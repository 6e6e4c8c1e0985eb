"""The live gateway survives a restart of the simulated sensor process: a new process behind the same device
path, whose IMU clock and sequence start again at 0 (a power-cycled sensor) and whose GNSS/baro clock
restarts too. Navigation resumes within max(3 IMU periods, 50 ms); the IMU data lost during the restart is
reported once (an ``imu`` dropout event, cleared: the core coasted across it) and no other fault is raised."""

from __future__ import annotations

import asyncio
import itertools
import time

from runtime_helpers import sim_config

from ins_hil.runtime.loop import Gateway
from ins_hil.sim.devices import SimDevices
from ins_hil.types import FaultEvent, FaultMode, NavState


def test_simulator_restart_navigation_resumes_within_the_bound(tmp_path):
    cfg = sim_config(sim={"profile": "static", "imu_errors": "none"})
    opened: list[tuple[str, int]] = []

    def devices(addr: tuple[str, int]) -> SimDevices:  # what `ins-hil run` hands the gateway: the simulator
        opened.append(addr)
        return SimDevices(cfg.sim, addr)

    gw = Gateway(cfg, record_path=tmp_path / "restart.ihlog", devices=devices)
    states: list[tuple[int, float]] = []
    faults: list[FaultEvent] = []

    def on_state(st: NavState) -> None:
        states.append((time.monotonic_ns(), st.t))

    gw.on_state.append(on_state)
    gw.on_fault.append(faults.append)
    marks: dict[str, float] = {}

    async def scenario() -> None:
        run = asyncio.create_task(gw.run(duration=None, signals=False))
        for _ in range(300):  # until navigating (the core starts at the first GNSS fix)
            await asyncio.sleep(0.1)
            if len(states) > 2000:
                break
        assert len(states) > 2000, "the gateway never navigated"
        imu = gw.metrics.source("imu0")
        fused0 = gw.pipeline.counts.get("fused_GnssFix", 0)
        await asyncio.get_running_loop().run_in_executor(None, gw.sim.restart)
        marks["t_restart"] = time.monotonic_ns()
        n_states, n_recv = len(states), imu.received
        await asyncio.sleep(6.0)
        marks["new_states"] = len(states) - n_states
        marks["new_samples"] = imu.received - n_recv
        marks["new_fixes"] = gw.pipeline.counts.get("fused_GnssFix", 0) - fused0
        gw.request_stop("test")
        await run

    asyncio.run(scenario())
    # the devices are the ones handed in, built once for the address the MAVLink input listens on
    assert len(opened) == 1 and opened[0][0] == "127.0.0.1" and opened[0][1] > 0, opened
    assert isinstance(gw.sim, SimDevices)
    t = [s for _, s in states]
    assert all(b > a for a, b in itertools.pairwise(t)), "sensor time of the states went backwards"
    assert marks["new_samples"] > 4000  # the restarted IMU delivered at 1 kHz
    # every sample after the restart gave a state, but for at most 50 ms (50 samples at 1 kHz)
    assert marks["new_states"] >= marks["new_samples"] - 50, marks
    # the state after the gap continues the sensor time by about the host time of the restart
    after = [(a, s) for a, s in states if a >= marks["t_restart"]]
    before = [(a, s) for a, s in states if a < marks["t_restart"]]
    gap_host = (after[0][0] - before[-1][0]) * 1e-9
    gap_sensor = after[0][1] - before[-1][1]
    assert abs(gap_sensor - gap_host) < 0.5, (gap_sensor, gap_host)
    assert marks["new_fixes"] > 10  # GNSS from the new process is fused again
    lost = [f for f in faults if f.sensor == "imu" and f.mode == FaultMode.DROPOUT]
    assert [f for f in faults if f not in lost] == [], faults
    assert len(lost) <= 1 and all(f.cleared and 0.0 < f.magnitude < gap_sensor for f in lost), (lost, gap_sensor)
