"""CAN drivers on a real SocketCAN vcan0/vcan1 (run by scripts/test.d/50-vcan.sh through scripts/vcan:
natively where the kernel has CAN, else inside a QEMU guest). One guest runs this whole module."""

from __future__ import annotations

import asyncio
import subprocess

import can
import pytest
from ins_hil.drivers.can_imu import CanImuDriver

from ins_hil.sim.can_imu import DbcImuNode, DroneCanImuNode, send_frames
from ins_hil.types import BaroSample, GnssFix, ImuSample, MagSample

pytestmark = pytest.mark.vcan


def _ip(*args: str) -> None:
    subprocess.run(["ip", "link", *args], check=True)


async def _wait(cond, timeout: float = 10.0) -> bool:  # type: ignore[no-untyped-def]
    for _ in range(int(timeout / 0.02)):
        if cond():
            return True
        await asyncio.sleep(0.02)
    return cond()


def test_dronecan_on_vcan0_node_filter_nodestatus_and_link_down() -> None:
    async def main() -> tuple[list, CanImuDriver, list[can.Message]]:
        drv = CanImuDriver.from_config(
            {"interface": "socketcan", "channel": "vcan0", "protocol": "dronecan", "nodes": [10], "node_id": 100,
             "stale_s": 5.0},
        )  # fmt: skip
        got: list = []
        task = asyncio.create_task(drv.run(got.append))
        assert await _wait(lambda: drv.health.connected)
        tx = can.Bus(interface="socketcan", channel="vcan0", receive_own_messages=False)
        node = DroneCanImuNode(node_id=10, rate_hz=200.0, aux_hz=10.0)
        foreign = DroneCanImuNode(node_id=33, rate_hz=200.0, aux_hz=0)
        frames = list(node.frames(100)) + list(foreign.frames(5))
        sent = await send_frames(tx, frames, rate_hz=1400.0, burst=14)  # a 200 Hz RawIMU node
        assert sent == len(frames)
        # a frame that is no DroneCAN at all (11-bit id), sent by can-utils
        subprocess.run(["cansend", "vcan0", "123#DEADBEEF"], check=True)
        ok = await _wait(lambda: sum(isinstance(s, ImuSample) for s in got) >= 100)
        assert ok, (sum(isinstance(s, ImuSample) for s in got), drv.health.errors)
        await asyncio.sleep(1.2)  # at least one NodeStatus period
        seen = []
        while (m := tx.recv(0)) is not None:
            seen.append(m)
        # the interface goes away and comes back: the driver reopens the socket
        _ip("set", "vcan0", "down")
        assert await _wait(lambda: not drv.health.connected or drv.health.errors.get("bus_lost", 0) > 0, 5)
        _ip("set", "vcan0", "up")
        tx.shutdown()
        tx = can.Bus(interface="socketcan", channel="vcan0", receive_own_messages=False)
        n0 = sum(isinstance(s, ImuSample) for s in got)
        for _ in range(100):  # keep sending until the reopened socket hears us
            await send_frames(tx, list(node.frames(5)), rate_hz=1400.0, burst=14)
            if sum(isinstance(s, ImuSample) for s in got) > n0:
                break
            await asyncio.sleep(0.05)
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        tx.shutdown()
        return got, drv, seen

    got, drv, seen = asyncio.run(main())
    imu = [s for s in got if isinstance(s, ImuSample)]
    assert len(imu) > 100 and {s.imu_id for s in imu} == {10}
    assert [s.seq for s in imu[:100]] == list(range(100))
    assert any(isinstance(s, GnssFix) for s in got)
    assert any(isinstance(s, MagSample) for s in got) and any(isinstance(s, BaroSample) for s in got)
    e = drv.health.errors
    assert e["unknown_node"] == 5 * 7 and e["not_dronecan"] == 1
    assert drv.health.reconnects >= 1 and e.get("bus_lost", 0) + e.get("silence", 0) >= 1
    assert any((m.arbitration_id >> 8) & 0xFFFF == 341 and m.arbitration_id & 0x7F == 100 for m in seen)


def test_dbc_imu_on_vcan1_with_corruption() -> None:
    async def main() -> tuple[list, CanImuDriver, int]:
        drv = CanImuDriver.from_config(
            {"interface": "socketcan", "channel": "vcan1", "protocol": "dbc", "dbc": {"rate_hz": 500.0},
             "node_id": None},
        )  # fmt: skip
        got: list = []
        task = asyncio.create_task(drv.run(got.append))
        assert await _wait(lambda: drv.health.connected)
        tx = can.Bus(interface="socketcan", channel="vcan1")
        frames = list(DbcImuNode(rate_hz=500.0, noise=0.02).frames(300))
        bad = 0
        for k in range(3, len(frames), 100):  # ~1% of the frames: one bit flipped
            d = bytearray(frames[k].data)
            d[k % 7] ^= 0x04
            frames[k] = can.Message(arbitration_id=frames[k].arbitration_id, data=d, is_extended_id=False)
            bad += 1
        await send_frames(tx, frames, rate_hz=1000.0, burst=10)
        await _wait(lambda: len(got) >= 300 - bad)
        await asyncio.sleep(0.2)
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        tx.shutdown()
        return got, drv, bad

    got, drv, bad = asyncio.run(main())
    assert len(got) == 300 - bad, drv.health.errors
    assert drv.health.errors["crc"] == bad
    # each lost sample is counted once, by its frames (crc + unpaired), not again as seq_gap
    assert drv.health.errors["unpaired"] == bad and drv.health.errors.get("seq_gap", 0) == 0
