"""The one MAVLink link layer: URL grammar, real sockets for every scheme (udpin, udpout, tcp,
tcpin, serial pty), used by the input driver and the output endpoints alike; signing in one place;
the shipped configs' listeners and signing."""

from __future__ import annotations

import asyncio
import glob
import os
import socket
import tty
from pathlib import Path
from typing import Any

import pytest
from ins_hil.drivers import mavlink_link
from ins_hil.drivers.mavlink_in import MavlinkDriver
from ins_hil.drivers.mavlink_link import Link, LinkUrl, MavReceiver, parse_url, signing_key_from
from pymavlink.dialects.v20 import ardupilotmega as mavlink2
from runtime_helpers import sim_config_dict
from test_drivers_mavlink import _stream  # n HIL_GPS messages

from ins_hil import config
from ins_hil.runtime.mavlink_out import EndpointConfig, MavlinkEndpoint
from ins_hil.runtime.metrics import RuntimeMetrics
from ins_hil.types import GnssFix, NavState

CONFIGS = sorted(Path(__file__).resolve().parent.parent.joinpath("configs").glob("*.toml"))


# ------------------------------------------------------------------ grammar
@pytest.mark.parametrize(
    ("url", "parsed"),
    [
        ("udpin:127.0.0.1:14550", ("udpin", "127.0.0.1", 14550)),
        ("udpin:0.0.0.0:0", ("udpin", "0.0.0.0", 0)),
        ("udpout:192.168.1.10:14555", ("udpout", "192.168.1.10", 14555)),
        ("tcp:localhost:5760", ("tcp", "localhost", 5760)),
        ("tcpin:127.0.0.1:5760", ("tcpin", "127.0.0.1", 5760)),
        ("udpin:[::1]:14550", ("udpin", "::1", 14550)),
        ("serial:/dev/ttyAMA0:921600", ("serial", "/dev/ttyAMA0", 921600)),
        ("serial:/dev/ttyACM0", ("serial", "/dev/ttyACM0", 115200)),
        ("/dev/ttyUSB0,57600", ("serial", "/dev/ttyUSB0", 57600)),
        ("/dev/ttyUSB0", ("serial", "/dev/ttyUSB0", 115200)),
        ("serial:/dev/serial/by-path/pci-0000:00:14.0-usb-0:1:1.0-port0:921600",
         ("serial", "/dev/serial/by-path/pci-0000:00:14.0-usb-0:1:1.0-port0", 921600)),
    ],
)  # fmt: skip
def test_url_grammar(url: str, parsed: tuple[str, str, int]) -> None:
    u = parse_url(url)
    assert u == parsed and isinstance(u, LinkUrl)
    assert u.listens == (u.scheme in ("udpin", "tcpin"))


@pytest.mark.parametrize(
    ("url", "message"),
    [
        ("udp:127.0.0.1:14550", "write 'udpin:127.0.0.1:14550' to listen or 'udpout:127.0.0.1:14550' to send"),
        ("udpin:14550", "expected udpin:HOST:PORT"),
        ("udpout:127.0.0.1:0", "port 0 out of range (1..65535)"),
        ("tcp:host:x", "expected tcp:HOST:PORT"),
        ("tcpin:127.0.0.1:70000", "port 70000 out of range"),
        ("serial:", "expected serial:DEVICE[:BAUD]"),
        ("/dev/ttyUSB0,fast", "baud 'fast' is not a positive number"),
        ("bluetooth:a:1", "unknown scheme 'bluetooth'"),
        ("", "expected udpin:HOST:PORT"),
    ],
)
def test_url_errors_are_one_line(url: str, message: str) -> None:
    with pytest.raises(ValueError) as e:
        parse_url(url)
    assert message in str(e.value) and "\n" not in str(e.value)


@pytest.mark.parametrize("where", ["inputs", "outputs"])
def test_legacy_udp_is_a_config_error_saying_what_to_write(where: str) -> None:
    d = sim_config_dict()
    if where == "inputs":
        d["inputs"][1]["url"] = "udp:127.0.0.1:0"
    else:
        d["outputs"] = [{"name": "gcs", "url": "udp:127.0.0.1:14550"}]
    with pytest.raises(config.ConfigError) as e:
        config.from_dict(d)
    msg = str(e.value)
    assert f"{where}[" in msg and "'udp:' is ambiguous" in msg and "udpout:127.0.0.1:" in msg and "\n" not in msg


def test_every_scheme_is_accepted_by_the_config_for_inputs_and_outputs() -> None:
    for url in ("udpin:127.0.0.1:0", "udpout:127.0.0.1:14550", "tcp:127.0.0.1:5760", "tcpin:127.0.0.1:5760",
                "serial:/dev/ttyAMA0:921600", "/dev/ttyUSB0,57600"):  # fmt: skip
        d = sim_config_dict(outputs=[{"name": "o", "url": url}])
        d["inputs"][1]["url"] = url
        cfg = config.from_dict(d)
        assert cfg.outputs[0].url == url and cfg.inputs[1].url == url


# ------------------------------------------------------------------ shipped configs
def _mavlink_urls(cfg: config.Config) -> list[str]:
    return [i.url for i in cfg.inputs if i.type == "mavlink"] + [o.url for o in cfg.outputs]


@pytest.mark.parametrize("path", CONFIGS, ids=lambda p: p.name)
def test_shipped_listeners_bind_to_localhost(path: Path) -> None:
    cfg = config.load(path)
    listening = [u for u in map(parse_url, _mavlink_urls(cfg)) if u.listens]
    assert all(u.host == "127.0.0.1" for u in listening), listening


def test_hil_px4_signs_every_mavlink_link() -> None:
    cfg = config.load(next(p for p in CONFIGS if p.name == "hil_px4.toml"))
    keys = {i.signing_key for i in cfg.inputs if i.type == "mavlink"} | {o.signing_key for o in cfg.outputs}
    keys.add(cfg.sim.sign_key)
    assert len(keys) == 1 and len(keys.pop()) == 64


def test_signing_lives_in_the_link_layer() -> None:
    """The simulator and the runtime take the signing timestamp from the link layer."""
    from ins_hil.sim import devices

    assert devices.signing_timestamp is mavlink_link.signing_timestamp
    src = Path(mavlink_link.__file__).resolve().parent.parent / "ins_hil" / "runtime" / "mavlink_out.py"
    assert "ins_hil.sim" not in src.read_text()


# ------------------------------------------------------------------ real sockets
async def _until(cond: Any, timeout: float = 30.0) -> None:  # a hang guard: a busy machine may take seconds
    loop = asyncio.get_running_loop()
    end = loop.time() + timeout
    while not cond():
        assert loop.time() < end, "timed out"
        await asyncio.sleep(0.01)


def test_udpin_and_udpout_links() -> None:
    async def main() -> None:
        a_got: list[bytes] = []
        b_got: list[bytes] = []
        a = Link("udpin:127.0.0.1:0", lambda d: a_got.append(d) is None and d.startswith(b"ok"))
        await a.open()
        assert not a.write(b"nobody yet") and not a.connected  # udpin: no peer until one talks
        b = Link(f"udpout:127.0.0.1:{a.local_address[1]}", b_got.append)
        await b.open()
        assert b.connected and b.write(b"ok hello")
        await _until(lambda: a_got)
        assert a.connected and a.peer == b.local_address
        assert a.write(b"reply")
        await _until(lambda: b_got)
        assert b_got == [b"reply"]
        # a datagram without valid data from a third sender does not take the peer over
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.sendto(b"junk", a.local_address)
            await _until(lambda: len(a_got) == 2)
        assert a.peer == b.local_address
        a.close()
        b.close()

    asyncio.run(main())


def test_tcp_client_and_tcpin_server_links_reconnect() -> None:
    async def main() -> None:
        srv_got: list[bytes] = []
        srv = Link("tcpin:127.0.0.1:0", srv_got.append)
        await srv.open()
        assert not srv.write(b"x")  # no client yet
        port = srv.local_address[1]
        got1: list[bytes] = []
        got2: list[bytes] = []
        c1 = Link(f"tcp:127.0.0.1:{port}", got1.append)
        c2 = Link(f"tcp:127.0.0.1:{port}", got2.append)
        await c1.open()
        await c2.open()
        await _until(lambda: c1.connected and c2.connected and len(srv._clients) == 2)
        assert c1.write(b"from c1")
        await _until(lambda: srv_got)
        assert srv.write(b"to all")
        await _until(lambda: got1 and got2)
        assert got1 == got2 == [b"to all"]
        for t in list(srv._clients):  # the server drops its clients: they re-connect
            t.close()
        await _until(lambda: c1.errors.get("disconnected") and c2.errors.get("disconnected"))
        await _until(lambda: c1.connected and c2.connected and len(srv._clients) == 2)
        srv.close()
        c1.close()
        c2.close()

    asyncio.run(main())


def test_tcp_link_counts_failed_connects() -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # nobody listens there

    async def main() -> Link:
        c = Link(f"tcp:127.0.0.1:{port}", lambda d: None)
        await c.open()
        await _until(lambda: c.errors.get("connect_failed", 0) >= 2)
        c.close()
        return c

    c = asyncio.run(main())
    assert not c.connected and "connect_failed" in c.last_error and str(port) in c.last_error


def test_serial_link_over_pty() -> None:
    master, slave = os.openpty()
    tty.setraw(slave)
    os.set_blocking(master, False)
    name = os.ttyname(slave)

    async def main() -> list[bytes]:
        got: list[bytes] = []
        link = Link(f"{name},57600", got.append)
        await link.open()
        await _until(lambda: link.connected)
        assert link.write(b"to the device")
        out = b""

        def read() -> bool:
            nonlocal out
            try:
                out += os.read(master, 100)
            except BlockingIOError:
                pass
            return out == b"to the device"

        await _until(read)
        os.write(master, b"from the device")
        await _until(lambda: b"".join(got) == b"from the device")
        link.close()
        return got

    asyncio.run(main())
    os.close(master)
    os.close(slave)


def _state(t: float) -> NavState:
    import numpy as np

    return NavState(t=t, q_nb=np.array([1.0, 0, 0, 0]), vel_ned=np.zeros(3), lat=0.88, lon=0.53, h=180.0,
                    std_pos=np.ones(3), std_vel=np.ones(3) * 0.1, std_att=np.ones(3) * 0.01,
                    omega_b=np.zeros(3), aligned=True)  # fmt: skip


def test_output_endpoint_serves_tcp_clients_signed() -> None:
    """An output endpoint on ``tcpin:`` (a ground station connects to us), signed with a passphrase
    key: a client with the key decodes its messages; its unsigned replies are refused and counted."""
    key = signing_key_from("a passphrase")

    async def main() -> tuple[MavReceiver, RuntimeMetrics]:
        metrics = RuntimeMetrics()
        ep = MavlinkEndpoint(
            EndpointConfig(name="gcs", url="tcpin:127.0.0.1:0", signing_key="a passphrase",
                           rates={"ATTITUDE": 100.0}), metrics,
        )  # fmt: skip
        await ep.start()
        r, w = await asyncio.open_connection("127.0.0.1", ep.tr.local_address[1])
        await _until(lambda: ep.tr.connected)
        rx = MavReceiver(key)
        msgs: list[Any] = []
        for k in range(20):
            ep.offer(_state(1.0 + 0.02 * k), 0, 0)
            await asyncio.sleep(0.02)
            while True:
                try:
                    data = await asyncio.wait_for(r.read(65536), 0.01)
                except TimeoutError:
                    break
                msgs += rx.feed(data)
        plain = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
        for _ in range(3):
            w.write(plain.heartbeat_encode(6, 8, 0, 0, 0).pack(plain))
        await w.drain()
        await _until(lambda: metrics.outputs["gcs"].get("rx_unsigned", 0) == 3)
        w.close()
        await ep.close()
        assert {m.get_type() for m in msgs} >= {"HEARTBEAT", "ATTITUDE"}
        return rx, metrics

    rx, _ = asyncio.run(main())
    assert rx.counts["unsigned"] == 0 and rx.counts["bad_signature"] == 0 and rx.counts["messages"] > 10


def test_input_driver_on_tcpin_and_udpout() -> None:
    """The input driver on the two schemes it could not use before: a flight controller that
    connects to our TCP server, and one we send to over UDP (our HEARTBEAT opens the link)."""

    async def main() -> tuple[list, list]:
        drv = MavlinkDriver("tcpin:127.0.0.1:0", timesync_s=0.2)
        got: list = []
        task = asyncio.create_task(drv.run(got.append))
        await _until(lambda: drv.local_address is not None)
        r, w = await asyncio.open_connection("127.0.0.1", drv.local_address[1])
        w.write(_stream(mavlink2.MAVLink(None, srcSystem=1, srcComponent=1), 10))
        await w.drain()
        hb = await asyncio.wait_for(r.read(4096), 30.0)  # our HEARTBEAT/TIMESYNC reach the FC (30 s: a hang guard)
        await _until(lambda: len(got) == 10)
        w.close()
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        assert {m.get_type() for m in mavlink2.MAVLink(None).parse_buffer(hb) or []} & {"HEARTBEAT", "TIMESYNC"}

        fc_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        fc_sock.bind(("127.0.0.1", 0))
        fc_sock.setblocking(False)
        drv2 = MavlinkDriver(f"udpout:127.0.0.1:{fc_sock.getsockname()[1]}", timesync_s=0.2)
        got2: list = []
        task2 = asyncio.create_task(drv2.run(got2.append))
        loop = asyncio.get_running_loop()
        _, addr = await asyncio.wait_for(loop.sock_recvfrom(fc_sock, 4096), 30.0)  # our HEARTBEAT opens the link
        await loop.sock_sendto(fc_sock, _stream(mavlink2.MAVLink(None, srcSystem=1, srcComponent=1), 5), addr)
        await _until(lambda: len(got2) == 5)
        task2.cancel()
        await asyncio.gather(task2, return_exceptions=True)
        fc_sock.close()
        return got, got2

    got, got2 = asyncio.run(main())
    assert all(isinstance(s, GnssFix) for s in got + got2)


def test_all_config_files_load() -> None:
    for p in glob.glob(str(CONFIGS[0].parent / "*.toml")):
        config.load(p)
