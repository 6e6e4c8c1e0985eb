"""MAVLink 2 signing: a keyed input accepts only correctly signed messages; our output is signed.

The simulator signs its GNSS/baro with the key; the test injects unsigned and
wrongly signed GPS_INPUT (at a far-away position) into the same input: they
are rejected, counted, and never reach the pipeline. On the output side a
pymavlink peer with the key verifies every message we send, and its unsigned
and wrongly signed replies are rejected and counted by our endpoint. ``ins-hil keygen`` writes a key file
(0600) that an output takes as ``signing_key_file``: its key is the passphrase's SHA-256, as MAVProxy and
QGroundControl derive it, and a bad key file is a one-line config error.
"""

from __future__ import annotations

import asyncio
import socket
from pathlib import Path
from typing import Any

from ins_hil.drivers.mavlink_link import signing_timestamp
from pymavlink.dialects.v20 import ardupilotmega as mavlink2
from runtime_helpers import free_port, sim_config, sim_gateway

from ins_hil.runtime.recorder import read_records
from ins_hil.types import GnssFix

KEY = "a1" * 32
WRONG = "5c" * 32


class _Buf:
    def __init__(self) -> None:
        self.data = b""

    def write(self, b: bytes) -> None:
        self.data += b


def _mav(key: str | None, sysid: int) -> tuple[Any, _Buf]:
    buf = _Buf()
    m = mavlink2.MAVLink(buf, srcSystem=sysid, srcComponent=220)
    if key:
        m.signing.secret_key = bytes.fromhex(key)
        m.signing.link_id = 3
        m.signing.timestamp = signing_timestamp()
        m.signing.sign_outgoing = True
    return m, buf


def _bogus_gps(m: Any, buf: _Buf) -> bytes:
    buf.data = b""
    m.gps_input_send(1_000_000, 0, 0, 0, 0, 3, 0, 0, 10.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.1, 1.0, 1.0, 12)
    return buf.data


def test_signed_links(tmp_path: Path) -> None:
    peer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    peer.bind(("127.0.0.1", free_port()))
    peer.setblocking(False)
    cfg = sim_config(
        sim={"sign_key": KEY},
        inputs=[
            {"name": "imu0", "type": "serial_imu", "port": "sim"},
            {"name": "gnss", "type": "mavlink", "url": "udpin:127.0.0.1:0", "signing_key": KEY},
        ],
        outputs=[{"name": "gcs", "url": f"udpout:127.0.0.1:{peer.getsockname()[1]}", "signing_key": KEY}],
    )
    gw = sim_gateway(cfg, record_path=tmp_path / "signed.ihlog")
    verifier = mavlink2.MAVLink(None)
    verifier.signing.secret_key = bytes.fromhex(KEY)
    verifier.signing.timestamp = signing_timestamp()
    got: dict[str, int] = {}
    rejected_by_peer = 0

    async def scenario() -> None:
        nonlocal rejected_by_peer
        task = asyncio.create_task(gw.run(duration=None, signals=False))
        for _ in range(1200):  # until the signed simulator got through (about 2.5 s idle; 120 s guards a hang)
            await asyncio.sleep(0.1)
            if gw.metrics.source("gnss").received > 10 and gw.drivers and gw.drivers[0].local_address:
                break
        drv = gw.drivers[0]
        port = drv.local_address[1]
        tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        unsigned, ub = _mav(None, 77)
        wrong, wb = _mav(WRONG, 78)
        for _ in range(5):
            tx.sendto(_bogus_gps(unsigned, ub), ("127.0.0.1", port))
            tx.sendto(_bogus_gps(wrong, wb), ("127.0.0.1", port))
            await asyncio.sleep(0.05)
        # the peer: verify what we send, answer with unsigned / wrongly signed / signed heartbeats
        good, gb = _mav(KEY, 250)
        our_addr = None
        for _ in range(1200):  # until enough of our output was verified (about 2 s idle; 60 s guards a hang)
            await asyncio.sleep(0.05)
            if got.get("HEARTBEAT", 0) >= 1 and got.get("ATTITUDE", 0) > 20 and verifier.signing.goodsig_count > 50:
                break
            while True:
                try:
                    data, our_addr = peer.recvfrom(65536)
                except BlockingIOError:
                    break
                for b in data:
                    try:
                        m = verifier.parse_char(bytes([b]))
                    except mavlink2.MAVError:
                        rejected_by_peer += 1
                        continue
                    if m is not None:
                        got[m.get_type()] = got.get(m.get_type(), 0) + 1
        assert our_addr is not None
        for mav, buf in ((unsigned, ub), (wrong, wb), (good, gb)):
            for _ in range(3):
                buf.data = b""
                mav.heartbeat_send(6, 8, 0, 0, 0)  # GCS heartbeat
                peer.sendto(buf.data, our_addr)
        for _ in range(600):  # until the 9 heartbeats are counted (at once idle; 30 s guards a hang)
            out = gw.metrics.outputs.get("gcs", {})
            if out.get("rx_messages", 0) + out.get("rx_unsigned", 0) + out.get("rx_bad_signature", 0) >= 9:
                break
            await asyncio.sleep(0.05)
        await asyncio.sleep(0.1)  # and nothing more (a heartbeat counted twice would show)
        gw.request_stop()
        await task

    asyncio.run(scenario())
    h = gw.drivers[0].health
    # the MAVLink input driver counts unsigned and wrongly signed messages together
    assert h.errors.get("bad_signature") == 10
    assert gw.metrics.snapshot()["sources"]["gnss"]["received"] > 10  # the signed simulator got through
    # nothing of the rejected input reached the pipeline (the bogus fixes are at lat 0)
    fixes = [r for r in read_records(tmp_path / "signed.ihlog") if isinstance(r, GnssFix)]
    assert KEY not in (tmp_path / "signed.ihlog").read_bytes().decode("latin-1")  # no key in the log header
    assert fixes and all(abs(f.lat) > 0.5 for f in fixes)
    # our output: every message correctly signed with the key
    assert rejected_by_peer == 0 and verifier.signing.goodsig_count > 50
    assert got.get("HEARTBEAT", 0) >= 1 and got.get("ATTITUDE", 0) > 20
    out = gw.metrics.snapshot()["outputs"]["gcs"]
    assert out.get("rx_unsigned") == 3 and out.get("rx_bad_signature") == 3 and out.get("rx_messages") == 3


def test_keygen_key_file_signs_an_output(tmp_path: Path, capsys: Any) -> None:
    """``ins-hil keygen`` writes a 0600 passphrase file and prints the config line; an output with that
    ``signing_key_file`` signs with SHA-256(passphrase) (the key MAVProxy's ``signing key`` and QGroundControl
    make of it) and obeys only messages signed with it; a bad key file is a one-line config error."""
    import hashlib
    import os
    import stat

    import pytest
    from runtime_helpers import BufferSink

    from ins_hil.cli import main
    from ins_hil.config import ConfigError
    from ins_hil.runtime.mavlink_out import MavlinkEndpoint
    from ins_hil.runtime.metrics import RuntimeMetrics

    key_file = tmp_path / "signing.key"
    assert main(["keygen", str(key_file)]) == 0
    out = capsys.readouterr().out
    assert stat.S_IMODE(key_file.stat().st_mode) == 0o600
    secret = key_file.read_text().strip()
    key = hashlib.sha256(secret.encode()).digest()
    assert f'signing_key_file = "{key_file.resolve()}"' in out and f"signing key {secret}" in out
    assert f'signing_key = "{key.hex()}"' in out
    assert main(["keygen", str(key_file)]) == 2 and key_file.read_text().strip() == secret  # never overwritten
    os.chmod(key_file, 0o644)
    assert main(["keygen", "--force", str(key_file)]) == 0 and stat.S_IMODE(key_file.stat().st_mode) == 0o600
    capsys.readouterr()
    secret = key_file.read_text().strip()
    key = hashlib.sha256(secret.encode()).digest()

    def output(**kw: Any) -> dict[str, Any]:
        return {"name": "gcs", "url": "udpout:127.0.0.1:9", "sysid": 42, **kw}

    cfg = sim_config(outputs=[output(signing_key_file=str(key_file))])
    ep = MavlinkEndpoint(cfg.outputs[0], RuntimeMetrics())
    sink = BufferSink()
    ep.tr = sink  # type: ignore[assignment]
    ep._send_heartbeat(None)
    verifier = mavlink2.MAVLink(None)
    verifier.signing.secret_key = key
    verifier.signing.timestamp = signing_timestamp()
    assert [m.get_type() for m in verifier.parse_buffer(b"".join(sink.bufs)) or []] == ["HEARTBEAT"]
    assert verifier.signing.goodsig_count == 1
    # a ground station with the key is obeyed; without it, or with another key, it is not
    for k, answered in ((None, False), (WRONG, False), (key.hex(), True)):
        gcs, buf = _mav(k, 255)
        sink.bufs.clear()
        buf.data = b""
        gcs.command_long_send(42, 1, mavlink2.MAV_CMD_REQUEST_MESSAGE, 0, 148, 0, 0, 0, 0, 0, 0)
        ep._on_data(buf.data)
        ep._send_replies()
        assert bool(sink.bufs) == answered, k
    o = ep.metrics.outputs["gcs"]
    assert o["rx_unsigned"] == 1 and o["rx_bad_signature"] == 1

    # bad key files and keys: one line naming the key
    os.chmod(key_file, 0o640)
    bad = {
        "readable by other users (mode 0640): chmod 600": output(signing_key_file=str(key_file)),
        "signing_key also given": output(signing_key_file=str(key_file), signing_key=KEY),
        "file not found": output(signing_key_file=str(tmp_path / "none.key")),
        "expected '' or 64 hex digits": output(signing_key="abc"),
    }
    short = tmp_path / "short.key"
    short.write_text("hunter2\n")
    short.chmod(0o600)
    bad["at least 16 printable ASCII characters"] = output(signing_key_file=str(short))
    for why, out_table in bad.items():
        with pytest.raises(ConfigError) as e:
            sim_config(outputs=[out_table])
        msg = str(e.value)
        assert why in msg and "outputs[0].signing_key" in msg and "\n" not in msg, msg
