"""Interoperability with a real ground station: MAVProxy (PyPI) connected to our MAVLink output.

MAVProxy listens (``--master=udpin``) where our gcs endpoint sends, logs the
telemetry (``.tlog``); the log read back with pymavlink must hold our
HEARTBEAT, ATTITUDE, GLOBAL_POSITION_INT and HOME_POSITION, with values matching the
simulated truth; MAVProxy's own heartbeats must reach our endpoint.
"""

from __future__ import annotations

import asyncio
import math
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from runtime_helpers import free_port, sim_config, sim_gateway

from ins_hil.geoid import undulation
from ins_hil.nav import earth
from ins_hil.nav.rotation import euler_from_quat
from ins_hil.sim.devices import truth_chunks

SYSID = 42


def _mavproxy() -> list[str]:
    exe = shutil.which("mavproxy.py", path=str(Path(sys.executable).parent)) or shutil.which("mavproxy.py")
    if exe is None:
        raise RuntimeError("mavproxy.py not found: MAVProxy is in the dev extras (pip install -e .[dev])")
    return [sys.executable, exe]


def _wait_bound(port: int, timeout: float = 60.0) -> None:
    """Until a UDP socket is bound to ``port`` (Linux /proc/net/udp: no probe that could take the port from
    MAVProxy), ``timeout`` s at most."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        lines = Path("/proc/net/udp").read_text().splitlines()[1:]
        if any(int(ln.split()[1].split(":")[1], 16) == port for ln in lines):
            return
        time.sleep(0.1)


def test_mavproxy_receives_our_vehicle(tmp_path: Path) -> None:
    port = free_port()
    tlog = tmp_path / "gcs.tlog"
    mp = subprocess.Popen(
        [
            *_mavproxy(),
            f"--master=udpin:127.0.0.1:{port}",
            f"--logfile={tlog}",
            f"--state-basedir={tmp_path}",
            "--daemon",
            "--non-interactive",
            "--default-modules=",
            "--mav20",
        ],
        cwd=tmp_path,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        _wait_bound(port)  # MAVProxy binds its UDP port (seconds on a busy machine)
        cfg = sim_config(
            sim={"imu_errors": "none"},
            outputs=[{"name": "gcs", "url": f"udpout:127.0.0.1:{port}", "role": "gcs", "sysid": SYSID}],
            recorder={"enabled": False},
        )
        gw = sim_gateway(cfg)

        async def run() -> None:  # until what the checks below need was sent and heard (about 7 s idle)
            task = asyncio.create_task(gw.run(duration=None, signals=False))
            for _ in range(1200):
                await asyncio.sleep(0.1)
                ep = gw.mav_outputs[0] if gw.mav_outputs else None
                if task.done() or (
                    ep is not None
                    and ep.sent.get("HEARTBEAT", 0) >= 6
                    and ep.sent.get("ATTITUDE", 0) > 200
                    and ep.sent.get("GLOBAL_POSITION_INT", 0) > 40
                    and ep.rx_messages.get("HEARTBEAT", 0) > 0
                ):
                    break
            gw.request_stop("test")
            await task

        asyncio.run(run())
        time.sleep(0.5)
    finally:
        mp.terminate()
        try:
            _, err = mp.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            mp.kill()
            _, err = mp.communicate()
    assert tlog.exists(), err

    from pymavlink import mavutil

    log = mavutil.mavlink_connection(str(tlog), dialect="ardupilotmega")
    seen: dict[str, list] = {"HEARTBEAT": [], "ATTITUDE": [], "GLOBAL_POSITION_INT": [], "HOME_POSITION": []}
    while True:
        m = log.recv_match(type=list(seen))
        if m is None:
            break
        if m.get_srcSystem() == SYSID:
            seen[m.get_type()].append(m)
    assert len(seen["HEARTBEAT"]) >= 3
    assert seen["HEARTBEAT"][0].type == mavutil.mavlink.MAV_TYPE_QUADROTOR
    assert len(seen["ATTITUDE"]) > 100 and len(seen["GLOBAL_POSITION_INT"]) > 20
    assert seen["HOME_POSITION"]  # streamed (0.5 Hz) and sent as the home is taken

    # the gateway heard MAVProxy's own heartbeats on the same link
    out = gw.metrics.snapshot()["outputs"]["gcs"]
    assert out.get("rx_messages", 0) > 0
    assert gw.mav_outputs[0].rx_messages.get("HEARTBEAT", 0) > 0

    # values against the simulated truth. Error-free IMU, GNSS 1 m / 0.1 m/s: the EKF's tilt follows the
    # noisy GNSS velocity in its first seconds (0.1 m/s over 0.2 s ≈ 3° of tilt information), yaw is
    # unobservable at rest (σ ≈ 10° from the config): roll/pitch within 2°, yaw within 5°, position 10 m
    truth = next(truth_chunks(cfg.sim))[0]
    rate = cfg.sim.imu_rate
    for a in seen["ATTITUDE"][::10]:
        k = round(a.time_boot_ms * 1e-3 * rate)
        tr = euler_from_quat(truth.q_nb[k])
        for est, ref, tol in zip((a.roll, a.pitch, a.yaw), tr, (2.0, 2.0, 5.0)):
            d = (est - ref + math.pi) % (2 * math.pi) - math.pi
            assert abs(math.degrees(d)) < tol
    for g in seen["GLOBAL_POSITION_INT"][::3]:
        k = round(g.time_boot_ms * 1e-3 * rate)
        lat, lon = math.radians(g.lat * 1e-7), math.radians(g.lon * 1e-7)
        h = g.alt * 1e-3 + undulation(lat, lon)  # alt is MSL (EGM96): back to the ellipsoidal height of the truth
        d = earth.ned_from_geodetic(lat, lon, h, truth.lat[k], truth.lon[k], truth.h[k])
        assert np.linalg.norm(d) < 10.0
        v = np.array([g.vx, g.vy, g.vz]) * 0.01
        assert np.linalg.norm(v - truth.vel_ned[k]) < 1.0
