"""Interoperability with a real MQTT broker (Debian mosquitto, started here on a free loopback port).

A paho subscriber gets our state, health and fault messages; the broker is
stopped and restarted mid-run: the loop keeps processing every IMU sample
(no backlog, nothing dropped) and publishing resumes, with the fault raised
during the outage delivered after the reconnect.
"""

from __future__ import annotations

import asyncio
import datetime
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Coroutine
from pathlib import Path
from typing import Any

import paho.mqtt.client as mqtt
import pytest
from runtime_helpers import free_port, sim_config, sim_gateway

from ins_hil.types import FaultEvent, FaultMode, NavState

PREFIX = "test_ins"


def _mosquitto() -> str:
    exe = shutil.which("mosquitto") or ("/usr/sbin/mosquitto" if Path("/usr/sbin/mosquitto").exists() else None)
    if exe is None:
        raise RuntimeError("mosquitto not installed: scripts/test.d/40-mosquitto.sh installs it (apt)")
    return exe


class Broker:
    def __init__(self, tmp: Path, users: dict[str, str] | None = None, persist: bool = False) -> None:
        """``persist``: the broker keeps its sessions (and their queued QoS-1 messages) across a restart."""
        self.port = free_port(socket.SOCK_STREAM)
        self.conf = tmp / "mosquitto.conf"
        conf = f"listener {self.port} 127.0.0.1\n"
        conf += f"persistence true\npersistence_location {tmp}/\n" if persist else "persistence false\n"
        if users:
            pw = tmp / "passwd"
            pw.write_text("")
            for u, p in users.items():
                subprocess.run(["mosquitto_passwd", "-b", str(pw), u, p], check=True, capture_output=True)
            conf += f"allow_anonymous false\npassword_file {pw}\n"
            if os.geteuid() == 0:  # as root mosquitto drops to its own user, who cannot read pytest's tmp dir
                conf += "user root\n"
        else:
            conf += "allow_anonymous true\n"
        self.conf.write_text(conf)
        self.proc: subprocess.Popen[bytes] | None = None

    def start(self) -> None:
        self.proc = subprocess.Popen([_mosquitto(), "-c", str(self.conf)], stderr=subprocess.DEVNULL)
        t0 = time.monotonic()
        while time.monotonic() - t0 < 10:
            try:
                socket.create_connection(("127.0.0.1", self.port), timeout=0.2).close()
                return
            except OSError:
                time.sleep(0.05)
        raise RuntimeError("mosquitto did not start")

    def stop(self) -> None:
        if self.proc is not None:
            self.proc.terminate()
            self.proc.wait(timeout=10)
            self.proc = None


class Subscriber:
    def __init__(self, port: int, persistent: bool = False) -> None:
        """``persistent``: a session the broker keeps while the subscriber is away (clean_session false), so a
        QoS-1 message published before it reconnects is queued for it instead of lost."""
        self.msgs: list[tuple[float, str, bytes, bool]] = []
        self.lock = threading.Lock()
        self.c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="test-sub", clean_session=not persistent)
        self.c.on_connect = lambda c, u, f, rc, p=None: c.subscribe(f"{PREFIX}/#", qos=1)
        self.c.on_message = self._on
        self.c.reconnect_delay_set(0.1, 0.5)
        self.c.connect("127.0.0.1", port, keepalive=5)
        self.c.loop_start()

    def _on(self, c: mqtt.Client, u: object, m: mqtt.MQTTMessage) -> None:
        with self.lock:
            self.msgs.append((time.monotonic(), m.topic, m.payload, bool(m.retain)))

    def topic(self, t: str) -> list[tuple[float, dict]]:
        with self.lock:
            return [(ts, json.loads(p)) for ts, top, p, _ in self.msgs if top == f"{PREFIX}/{t}"]

    def close(self) -> None:
        self.c.loop_stop()
        self.c.disconnect()


@pytest.fixture
def broker(tmp_path: Path):  # type: ignore[no-untyped-def]
    b = Broker(tmp_path)
    b.start()
    yield b
    b.stop()


def test_state_and_faults_survive_a_broker_restart(tmp_path: Path) -> None:
    # a persistent broker and subscriber session: the gateway may reconnect and send the fault it queued before
    # the subscriber is back, and the broker must hold it for the subscriber (what a real deployment configures)
    broker = Broker(tmp_path, persist=True)
    broker.start()
    try:
        _broker_restart(broker)
    finally:
        broker.stop()


def _broker_restart(broker: Broker) -> None:
    cfg = sim_config(
        mqtt={"enabled": True, "port": broker.port, "topic_prefix": PREFIX, "state_rate": 20.0},
        recorder={"enabled": False},
    )
    gw = sim_gateway(cfg)
    t_states: list[float] = []
    gw.on_state.append(lambda st: t_states.append(time.monotonic()))
    sub = Subscriber(broker.port, persistent=True)
    marks: dict[str, float] = {}

    def fault(t: float, sensor: str) -> FaultEvent:
        return FaultEvent(t=t, sensor=sensor, mode=FaultMode.STEP_BIAS, magnitude=0.01, detail="test")

    async def states_after(t0: float, n: int) -> None:
        """Until the subscriber has ``n`` states received after monotonic ``t0`` (counts, not times: a loaded
        machine starts the gateway slowly; 120 s guard against a hang, the assertions below say what is missing)."""
        end = time.monotonic() + 120.0
        while sum(ts > t0 for ts, _ in sub.topic("state")) < n and time.monotonic() < end:
            await asyncio.sleep(0.05)

    async def faults_in(n: int) -> None:
        """Until the subscriber has ``n`` of the injected faults (120 s guard against a hang)."""
        end = time.monotonic() + 120.0
        while sum(f["detail"] == "test" for _, f in sub.topic("fault")) < n and time.monotonic() < end:
            await asyncio.sleep(0.05)

    async def scenario() -> None:
        task = asyncio.create_task(gw.run(duration=None, signals=False))
        await states_after(0.0, 21)
        marks["first"] = time.monotonic()
        gw._fault(fault(1.0, "gyro[0]"))
        await faults_in(1)  # published before the broker goes
        marks["stop"] = time.monotonic()
        await asyncio.to_thread(broker.stop)
        await asyncio.sleep(0.5)
        gw._fault(fault(2.0, "accel[1]"))  # raised while the broker is away
        await asyncio.sleep(1.5)
        marks["restart"] = time.monotonic()
        await asyncio.to_thread(broker.start)
        await states_after(marks["restart"], 21)
        gw._fault(fault(3.0, "gyro[2]"))
        await faults_in(3)
        gw.request_stop()
        await asyncio.wait_for(task, 30.0)

    try:
        asyncio.run(scenario())
    finally:
        sub.close()

    states = sub.topic("state")
    before = [s for ts, s in states if ts < marks["stop"]]
    after = [s for ts, s in states if ts > marks["restart"]]
    assert len(before) > 20 and len(after) > 20
    for s in (before[-1], after[-1]):
        assert len(s["q_nb"]) == 4 and len(s["vel_ned"]) == 3 and -90 <= s["lat_deg"] <= 90
    # publishing resumed with the live state: sensor time and message counter move on
    assert after[0]["t"] > before[-1]["t"] + 1.0 and after[0]["seq"] > before[-1]["seq"]
    # the injected faults, each once and in order (a loaded host may add the gateway's own genuine faults, e.g. an
    # IMU that fell behind: those carry their own detail and are not the test's)
    injected = [f for _, f in sub.topic("fault") if f["detail"] == "test"]
    assert [f["sensor"] for f in injected] == ["gyro[0]", "accel[1]", "gyro[2]"]
    assert all(f["mode"] == "STEP_BIAS" for f in injected)
    health = sub.topic("health")
    last_health = health[-1][1]
    assert "latency" in last_health and last_health["sources"]["imu0"]["received"] > 0
    assert gw.mqtt is not None and gw.mqtt.connects >= 2

    # the loop kept its pace through the outage: every IMU sample processed, none queued up or dropped; the pace
    # is the run's own before the outage (a busy host slows both; a loop blocked by the lost broker stops)
    snap = gw.metrics.snapshot()
    assert "queue_full" not in snap["sources"]["imu0"]["dropped"]
    n_out = sum(marks["stop"] <= t <= marks["restart"] for t in t_states)
    n_in = sum(marks["first"] <= t <= marks["stop"] for t in t_states)
    pace_in = n_in / (marks["stop"] - marks["first"])
    assert n_out > 0.5 * pace_in * (marks["restart"] - marks["stop"]), (n_out, pace_in, marks)
    assert snap["queue_depth_max"] < 200


def test_unreachable_broker_does_not_stall_the_loop() -> None:
    port = free_port(socket.SOCK_STREAM)  # nothing listens here
    cfg = sim_config(mqtt={"enabled": True, "port": port, "topic_prefix": PREFIX}, recorder={"enabled": False})
    gw = sim_gateway(cfg)
    states: list[NavState] = []
    gw.on_state.append(states.append)

    def enough() -> bool:  # 1000 states and 10 dropped while offline (about 3 s idle), not a fixed run
        return len(states) > 1000 and gw.metrics.snapshot()["outputs"]["mqtt"].get("state_dropped_offline", 0) > 10

    asyncio.run(_run_until(gw, enough))
    snap = gw.metrics.snapshot()
    assert gw.mqtt is not None and not gw.mqtt.connected and gw.mqtt.connects == 0
    assert snap["outputs"]["mqtt"]["state_dropped_offline"] > 10
    assert len(states) == snap["imu_epochs"] > 1000
    assert "queue_full" not in snap["sources"]["imu0"]["dropped"]


def test_username_password(tmp_path: Path) -> None:
    """A broker that requires a login: right credentials publish, wrong ones never connect (and never stall)."""
    b = Broker(tmp_path, users={"gw": "s3cret"})
    b.start()
    try:
        got = {}
        for name, pw in (("right", "s3cret"), ("wrong", "nope")):
            cfg = sim_config(
                mqtt={"enabled": True, "port": b.port, "topic_prefix": PREFIX, "username": "gw", "password": pw},
                recorder={"enabled": False},
            )
            gw = sim_gateway(cfg)

            def enough(gw: Any = gw, right: bool = pw == "s3cret") -> bool:  # about 1 s idle
                """Connected and 5 states sent, or refused (the reason kept) and 5 states dropped."""
                m, out = gw.mqtt, gw.metrics.outputs.get("mqtt", {})
                if m is None:
                    return False
                if right:
                    return bool(m.connects == 1 and out.get("states", 0) > 5)
                return bool(m.last_error) and out.get("state_dropped_offline", 0) > 5

            asyncio.run(_run_until(gw, enough))
            assert gw.mqtt is not None
            got[name] = (gw.mqtt.connects, gw.metrics.snapshot()["outputs"]["mqtt"], gw.mqtt.last_error)
    finally:
        b.stop()
    assert got["right"][0] == 1 and got["right"][1].get("states", 0) > 5
    assert got["wrong"][0] == 0 and got["wrong"][1].get("state_dropped_offline", 0) > 5
    assert got["wrong"][2]  # the reason is kept for the status view


def _run_until(gw: Any, cond: Callable[[], bool], deadline: float = 120.0) -> Coroutine[Any, Any, None]:
    """``gw.run()`` until ``cond()`` holds (polled every 50 ms); ``deadline`` (s) only guards against a hang: a busy
    machine starts the gateway and the simulator slowly. The caller checks what is missing."""

    async def go() -> None:
        task = asyncio.create_task(gw.run(duration=None, signals=False))
        end = time.monotonic() + deadline
        while not task.done() and not cond() and time.monotonic() < end:
            await asyncio.sleep(0.05)
        gw.request_stop("test")
        await asyncio.wait_for(task, 60.0)

    return go()


def _retained(port: int, topics: tuple[str, ...] = ("online", "health")) -> dict[str, tuple[bytes, bool]]:
    """What a newly connecting subscriber gets under PREFIX/#: the broker's retained messages, once those on
    ``topics`` came (60 s guard against a hang)."""
    sub = Subscriber(port)
    try:
        end = time.monotonic() + 60.0
        while time.monotonic() < end:
            with sub.lock:
                if {f"{PREFIX}/{t}" for t in topics} <= {top for _, top, _, _ in sub.msgs}:
                    break
            time.sleep(0.05)
        with sub.lock:
            return {top: (p, r) for _, top, p, r in sub.msgs}
    finally:
        sub.close()


def test_clean_stop_publishes_offline_and_health_has_wall_clock_time(broker: Broker, tmp_path: Path) -> None:
    """The real `ins-hil run`: online "1" while running; after the broker drops and returns, publishing
    resumes; SIGINT (a clean stop) leaves online "0" retained (not only the will of a killed process) and
    the retained health carries the host's wall-clock time; connecting and losing the broker are said."""
    from test_run_errors import udp_out, write_config

    cfg = write_config(
        tmp_path,
        mqtt={"enabled": True, "port": broker.port, "topic_prefix": PREFIX},
        recorder={"enabled": False},
        outputs=[{"name": "gcs", "type": "mavlink", "url": udp_out(free_port()), "role": "gcs"}],
    )
    sub = Subscriber(broker.port)
    p = subprocess.Popen(
        [sys.executable, "-m", "ins_hil", "run", "--config", str(cfg), "--no-status"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )

    def online(after: float) -> list[bytes]:
        with sub.lock:
            return [pl for ts, top, pl, _ in sub.msgs if top == f"{PREFIX}/online" and ts > after]

    def wait_for(cond: object, timeout: float = 120.0) -> None:
        """Until ``cond()``; the timeout only guards against a hang (the gateway's start-up under load takes long)."""
        t0 = time.monotonic()
        while not cond():  # type: ignore[operator]
            assert time.monotonic() - t0 < timeout and p.poll() is None, "gateway did not get there"
            time.sleep(0.05)

    try:
        wait_for(lambda: online(0.0) == [b"1"] and sub.topic("health"))
        broker.stop()
        time.sleep(1.0)
        t_back = time.monotonic()
        broker.start()
        wait_for(lambda: online(t_back) == [b"1"] and any(ts > t_back for ts, _ in sub.topic("health")))
        t_stop = time.time()
        p.send_signal(signal.SIGINT)
        _, err = p.communicate(timeout=30)
    finally:
        sub.close()
        if p.poll() is None:
            p.kill()
    assert p.returncode == 0, err
    got = _retained(broker.port)
    assert got[f"{PREFIX}/online"] == (b"0", True)
    health, retained = got[f"{PREFIX}/health"]
    h = json.loads(health)
    assert retained and h["sources"]["imu0"]["received"] > 0
    t_utc = datetime.datetime.fromisoformat(h["time_utc"].replace("Z", "+00:00"))
    assert h["time_utc"].endswith("Z") and t_utc.utcoffset() == datetime.timedelta(0)
    assert abs(t_utc.timestamp() - h["time_unix"]) < 1e-3
    assert t_stop - 5.0 < h["time_unix"] < time.time()  # the health published at the stop
    lines = err.splitlines()
    assert sum(f"mqtt: connected to 127.0.0.1:{broker.port}" in ln for ln in lines) == 2, err
    assert sum(f"mqtt: lost the broker 127.0.0.1:{broker.port}" in ln for ln in lines) == 1, err
