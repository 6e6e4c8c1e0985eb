"""The gateway's MAVLink command surface held against a stranger on the link.

A real MAVLink endpoint with its ParamStore, fed bytes that a pymavlink peer encodes (as the link layer hands
them over), its answers read back from the transport: PARAM_SET, MAV_CMD_PREFLIGHT_STORAGE and state-changing
commands from a system id that is not an allowed ground station are refused (counted, COMMAND_ACK DENIED or
PARAM_VALUE with the unchanged value, one STATUSTEXT per system id), nothing is saved, and a gateway started
afterwards runs with the config file's values; ``allowed_gcs_sysids`` lets a ground station in by id; commands
addressed to another component of our system id (the autopilot of the ``fc`` role) are not ours; the override
file is announced at start (log line and STATUSTEXT) and can be switched off; an unsigned output listening on a
network address is warned about at start; MQTT refuses a password without a user name and warns when it would go
out in clear text, and the documented TLS set-up works against a real broker (mosquitto, certificates from openssl).
"""

from __future__ import annotations

import asyncio
import logging
import math
import subprocess
import time
from pathlib import Path
from typing import Any

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2
from runtime_helpers import BufferSink, sim_config_dict

from ins_hil.config import ConfigError, load
from ins_hil.runtime.loop import Gateway
from ins_hil.runtime.mavlink_out import MavlinkEndpoint
from ins_hil.runtime.mavlink_params import ParamStore
from ins_hil.runtime.metrics import RuntimeMetrics

M = mavlink2
SYSID = 42
GATE = 5.0  # the config's NAV_GATE_GNSS


def _toml(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, list):
        return "[" + ", ".join(_toml(x) for x in v) + "]"
    return repr(v)


def _write_config(path: Path, **output: Any) -> Path:
    """A config file (configs/default.toml with one gcs output to a port nobody listens on): the override file's
    default place is beside it (``<name>.params.toml``)."""
    d = sim_config_dict(recorder={"enabled": False})
    out = {"name": "gcs", "url": "udpout:127.0.0.1:9", "role": "gcs", "sysid": SYSID, **output}
    lines = []
    for sec, table in d.items():
        if isinstance(table, list):
            continue
        lines += _table(sec, table)
    for t in d["inputs"]:
        lines += _table("inputs", t, array=True)
    lines += _table("outputs", out, array=True)
    path.write_text("\n".join(lines) + "\n")
    return path


def _table(name: str, t: dict[str, Any], array: bool = False) -> list[str]:
    lines = [f"[[{name}]]" if array else f"[{name}]"]
    subs = {k: v for k, v in t.items() if isinstance(v, dict)}
    lines += [f"{k} = {_toml(v)}" for k, v in t.items() if k not in subs]
    for k, v in subs.items():
        lines += _table(f"{name}.{k}", v)
    return lines


class Peer:
    """The gateway's gcs endpoint (its ParamStore attached, the transport a BufferSink) and pymavlink peers."""

    def __init__(self, cfg_path: Path) -> None:
        self.cfg = load(cfg_path)
        self.store = ParamStore(self.cfg)
        self.metrics = RuntimeMetrics()
        self.ep = MavlinkEndpoint(self.store.cfg.outputs[0], self.metrics)
        self.sink = BufferSink()
        self.ep.tr = self.sink  # type: ignore[assignment]
        self.store.attach([self.ep])
        self.rx = M.MAVLink(None)
        self.rx.robust_parsing = True

    def send(self, src: int, build: Any, compid: int = 190) -> list[Any]:
        """``build(mav)`` encodes one message as system ``src``; the endpoint's answers to it."""
        mav = M.MAVLink(None, srcSystem=src, srcComponent=compid)
        self.sink.bufs.clear()
        self.ep._on_data(build(mav).pack(mav))
        self.ep._send_texts()
        return [m for b in self.sink.bufs for m in self.rx.parse_buffer(b) or []]

    def param_set(self, src: int, name: str, value: float, target: int = SYSID, comp: int = 1) -> list[Any]:
        return self.send(src, lambda m: m.param_set_encode(target, comp, name.encode(), value, 9))

    def command(self, src: int, cmd: int, *p: float, target: int = SYSID, comp: int = 1) -> list[Any]:
        params = [*p, *([0.0] * (7 - len(p)))]
        return self.send(src, lambda m: m.command_long_encode(target, comp, cmd, 0, *params))

    def refused(self) -> int:
        return self.metrics.outputs.get(self.ep.name, {}).get("rx_refused_sysid", 0)


def _only(msgs: list[Any], typ: str) -> Any:
    got = [m for m in msgs if m.get_type() == typ]
    assert len(got) == 1, [m.get_type() for m in msgs]
    return got[0]


def _texts(msgs: list[Any]) -> list[str]:
    return [m.text for m in msgs if m.get_type() == "STATUSTEXT"]


def test_unknown_system_cannot_retune_save_or_command(tmp_path: Path) -> None:
    cfg_path = _write_config(tmp_path / "gw.toml")
    p = Peer(cfg_path)
    override = tmp_path / "gw.params.toml"
    assert p.store.path == override

    # system 99: PARAM_SET refused, answered with the unchanged value, one STATUSTEXT for the system id
    first = p.param_set(99, "NAV_GATE_GNSS", 1000.0)
    assert math.isclose(_only(first, "PARAM_VALUE").param_value, GATE)
    assert [t for t in _texts(first) if "sysid 99" in t] == ["sysid 99: not an allowed GCS, writes refused"]
    # the save, a stream-rate command and an unknown command: COMMAND_ACK DENIED to system 99, no more STATUSTEXT
    for cmd, args in ((M.MAV_CMD_PREFLIGHT_STORAGE, (1,)),
                      (M.MAV_CMD_SET_MESSAGE_INTERVAL, (M.MAVLINK_MSG_ID_ATTITUDE, -1)),
                      (M.MAV_CMD_DO_SET_SERVO, (1, 1500))):  # fmt: skip
        msgs = p.command(99, cmd, *args)
        ack = _only(msgs, "COMMAND_ACK")
        assert (ack.command, ack.result, ack.target_system) == (cmd, M.MAV_RESULT_DENIED, 99)
        assert not _texts(msgs)
    assert not _texts(p.param_set(99, "SR_ATTITUDE", 0.0))
    assert p.refused() == 5
    # nothing changed, nothing saved
    assert p.store.cfg.pipeline.nav.gnss.gate == GATE
    assert p.ep.rates["ATTITUDE"] == 50.0 and not p.store.changed
    assert not override.exists()
    # reading stays open to anyone: PARAM_REQUEST_READ and REQUEST_MESSAGE are answered
    r = p.send(99, lambda m: m.param_request_read_encode(SYSID, 1, b"NAV_GATE_GNSS", -1))
    assert math.isclose(_only(r, "PARAM_VALUE").param_value, GATE)
    ack = _only(p.command(99, M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION), "COMMAND_ACK")
    assert ack.result == M.MAV_RESULT_ACCEPTED
    # another system id is told once too
    assert "sysid 7: not an allowed GCS, writes refused" in _texts(p.param_set(7, "NAV_GATE_GNSS", 1000.0))

    # a gateway started afterwards runs with the config's values
    gw = Gateway(load(cfg_path))
    assert not gw.params.loaded
    assert gw.cfg.pipeline.nav.gnss.gate == GATE


def test_a_ground_station_is_allowed_by_id(tmp_path: Path) -> None:
    # the default: QGroundControl/MAVProxy (255) and MAVSDK (245)
    p = Peer(_write_config(tmp_path / "a.toml"))
    assert math.isclose(_only(p.param_set(255, "NAV_GATE_GNSS", 4.0), "PARAM_VALUE").param_value, 4.0)
    assert math.isclose(_only(p.param_set(245, "NAV_GATE_GNSS", 4.5), "PARAM_VALUE").param_value, 4.5)
    assert p.refused() == 0

    # allowed_gcs_sysids = [99]: system 99 retunes and saves; 255 is now a stranger
    cfg_path = _write_config(tmp_path / "b.toml", allowed_gcs_sysids=[99])
    p = Peer(cfg_path)
    assert math.isclose(_only(p.param_set(99, "NAV_GATE_GNSS", 4.0), "PARAM_VALUE").param_value, 4.0)
    ack = _only(p.command(99, M.MAV_CMD_PREFLIGHT_STORAGE, 1), "COMMAND_ACK")
    assert ack.result == M.MAV_RESULT_ACCEPTED
    assert "NAV_GATE_GNSS = 4.0" in (tmp_path / "b.params.toml").read_text()
    assert _only(p.command(255, M.MAV_CMD_PREFLIGHT_STORAGE, 1), "COMMAND_ACK").result == M.MAV_RESULT_DENIED
    assert p.refused() == 1

    # [0]: any system; []: none (read-only)
    p = Peer(_write_config(tmp_path / "c.toml", allowed_gcs_sysids=[0]))
    assert math.isclose(_only(p.param_set(123, "NAV_GATE_GNSS", 3.0), "PARAM_VALUE").param_value, 3.0)
    p = Peer(_write_config(tmp_path / "d.toml", allowed_gcs_sysids=[]))
    assert math.isclose(_only(p.param_set(255, "NAV_GATE_GNSS", 3.0), "PARAM_VALUE").param_value, GATE)
    with pytest.raises(ConfigError, match=r"outputs\[0\]\.allowed_gcs_sysids = \[0, 255\]: 0 means any system"):
        load(_write_config(tmp_path / "e.toml", allowed_gcs_sysids=[0, 255]))


def test_commands_to_the_autopilot_component_are_not_ours(tmp_path: Path) -> None:
    """Role fc: our system id is the autopilot's (1); what is addressed to its component 1 is left alone."""
    p = Peer(_write_config(tmp_path / "fc.toml", role="fc", sysid=1, compid=197))
    assert p.command(255, M.MAV_CMD_PREFLIGHT_STORAGE, 1, target=1, comp=1) == []
    assert p.param_set(255, "NAV_GATE_GNSS", 4.0, target=1, comp=1) == []
    assert p.send(255, lambda m: m.param_request_list_encode(1, 1)) == []
    assert p.metrics.outputs["gcs"]["rx_other_component"] == 3 and not p.store.changed
    # to our component, or to every component (0): ours
    ack = _only(p.command(255, M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION, target=1, comp=197),
                "COMMAND_ACK")  # fmt: skip
    assert ack.result == M.MAV_RESULT_ACCEPTED
    assert math.isclose(_only(p.param_set(255, "NAV_GATE_GNSS", 4.0, target=1, comp=0), "PARAM_VALUE").param_value,
                        4.0)  # fmt: skip


def test_override_file_is_announced_and_can_be_switched_off(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    cfg_path = _write_config(tmp_path / "gw.toml")
    override = tmp_path / "gw.params.toml"
    override.write_text("[params]\nNAV_GATE_GNSS = 1000.0\n[params.gcs]\nSR_ATTITUDE = 5.0\n")
    gw = Gateway(load(cfg_path))
    assert gw.params.loaded == {"NAV_GATE_GNSS": 1000.0, "SR_ATTITUDE@gcs": 5.0}
    assert gw.cfg.pipeline.nav.gnss.gate == 1000.0
    # the start-up log names the file and every overridden value
    gw.log = logging.getLogger("ins_hil")
    gw.input_paths = {ic.name: f"inputs[{i}] ({ic.name})" for i, ic in enumerate(gw.cfg.inputs)}
    with caplog.at_level(logging.INFO, logger="ins_hil"):
        gw._announce()
    lines = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(lines) == 1, lines
    assert str(override) in lines[0] and "NAV_GATE_GNSS = 1000" in lines[0] and "SR_ATTITUDE@gcs = 5" in lines[0]
    # the ground station gets it as STATUSTEXT
    ep = gw.mav_outputs[0]
    sink = BufferSink()
    ep.tr = sink  # type: ignore[assignment]
    ep._send_texts()
    texts = [m.text for b in sink.bufs for m in M.MAVLink(None).parse_buffer(b) or [] if m.get_type() == "STATUSTEXT"]
    assert texts[0] == "params: 2 override(s) from gw.params.toml"
    assert "param override NAV_GATE_GNSS = 1000" in texts and "param override SR_ATTITUDE@gcs = 5" in texts

    # params_file = "off": the file is not loaded, and a save is refused
    off = Gateway(load(_write_config(tmp_path / "gw.toml", params_file="off")))
    assert not off.params.loaded and off.cfg.pipeline.nav.gnss.gate == GATE
    assert off.params.path is None
    ep = off.mav_outputs[0]
    ep.tr = sink  # type: ignore[assignment]
    sink.bufs.clear()
    mav = M.MAVLink(None, srcSystem=255, srcComponent=190)
    ep._on_data(mav.command_long_encode(SYSID, 1, M.MAV_CMD_PREFLIGHT_STORAGE, 0, 1, 0, 0, 0, 0, 0, 0).pack(mav))
    ep._send_texts()
    msgs = [m for b in sink.bufs for m in M.MAVLink(None).parse_buffer(b) or []]
    assert _only(msgs, "COMMAND_ACK").result == M.MAV_RESULT_FAILED
    assert any("params_file = 'off'" in t for t in _texts(msgs))


def test_mqtt_password_needs_a_user_and_is_not_sent_in_clear_silently(tmp_path: Path) -> None:
    from ins_hil.config import from_dict
    from ins_hil.runtime.mqtt_out import MqttConfig, MqttPublisher

    with pytest.raises(ConfigError, match=r"mqtt\.password: needs mqtt\.username"):
        from_dict(sim_config_dict(mqtt={"enabled": True, "password": "secret"}))
    (tmp_path / "ca.pem").write_text("-----BEGIN CERTIFICATE-----\n")
    with pytest.raises(ConfigError, match=r"mqtt\.tls_ca: needs mqtt\.tls = true"):
        from_dict(sim_config_dict(mqtt={"enabled": True, "tls_ca": str(tmp_path / "ca.pem")}))

    async def start_stop(cfg: MqttConfig) -> list[str]:
        pub = MqttPublisher(cfg, RuntimeMetrics())
        await pub.start()
        await pub.close()
        return pub.metrics.warnings

    port = 9  # nobody listens: the publisher only tries to connect
    clear = asyncio.run(start_stop(MqttConfig(port=port, username="u", password="p")))
    assert any("password" in w and "tls" in w for w in clear), clear
    tls = asyncio.run(start_stop(MqttConfig(port=port, username="u", password="p", tls=True)))
    assert not any("password" in w for w in tls), tls


def test_unsigned_output_listening_on_the_network_is_warned_about(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    from ins_hil.runtime.mavlink_out import EndpointConfig

    assert EndpointConfig(url="udpin:0.0.0.0:14550").exposed()
    assert EndpointConfig(url="tcpin:192.168.1.5:5760").exposed()
    assert not EndpointConfig(url="udpin:127.0.0.1:14550").exposed()
    assert not EndpointConfig(url="udpin:[::1]:14550").exposed()
    assert not EndpointConfig(url="udpout:192.168.1.5:14550").exposed()  # sends; listens on no chosen address
    assert not EndpointConfig(url="udpin:0.0.0.0:14550", signing_key="a1" * 32).exposed()

    gw = Gateway(load(_write_config(tmp_path / "gw.toml", url="udpin:0.0.0.0:0")))
    gw.log = logging.getLogger("ins_hil")
    gw.input_paths = {ic.name: f"inputs[{i}] ({ic.name})" for i, ic in enumerate(gw.cfg.inputs)}
    with caplog.at_level(logging.INFO, logger="ins_hil"):
        gw._announce()
    warned = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(warned) == 1 and "udpin:0.0.0.0:0 for the whole network, unsigned" in warned[0], warned


def _tls_broker(tmp: Path) -> tuple[subprocess.Popen[bytes], int, Path]:
    """mosquitto with a TLS listener (a CA and a server certificate for 127.0.0.1 made by the openssl command) and
    a password file (user gw, password pw): the process, its port and the CA file."""
    import os
    import shutil
    import socket

    from runtime_helpers import free_port

    exe = shutil.which("mosquitto") or "/usr/sbin/mosquitto"
    if not Path(exe).exists():
        raise RuntimeError("mosquitto not installed: scripts/test.d/40-mosquitto.sh installs it (apt)")

    def ssl(*args: str) -> None:
        subprocess.run(["openssl", *args], cwd=tmp, check=True, capture_output=True)

    ec = ["-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes"]
    ssl("req", "-x509", *ec, "-keyout", "ca.key", "-out", "ca.pem", "-days", "2", "-subj", "/CN=ins-hil test CA")
    ssl("req", *ec, "-keyout", "server.key", "-out", "server.csr", "-subj", "/CN=127.0.0.1")
    (tmp / "san.ext").write_text("subjectAltName=IP:127.0.0.1\n")
    ssl("x509", "-req", "-in", "server.csr", "-CA", "ca.pem", "-CAkey", "ca.key", "-CAcreateserial",
        "-out", "server.pem", "-days", "2", "-extfile", "san.ext")  # fmt: skip
    subprocess.run(["mosquitto_passwd", "-c", "-b", str(tmp / "passwd"), "gw", "pw"], check=True, capture_output=True)
    port = free_port(socket.SOCK_STREAM)
    conf = (f"listener {port} 127.0.0.1\ncafile {tmp}/ca.pem\ncertfile {tmp}/server.pem\nkeyfile {tmp}/server.key\n"
            f"allow_anonymous false\npassword_file {tmp}/passwd\npersistence false\n")  # fmt: skip
    if os.geteuid() == 0:  # as root mosquitto drops to its own user, who cannot read pytest's tmp dir
        conf += "user root\n"
    (tmp / "mosquitto.conf").write_text(conf)
    proc = subprocess.Popen([exe, "-c", str(tmp / "mosquitto.conf")], stderr=subprocess.DEVNULL)
    for _ in range(200):
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
            return proc, port, tmp / "ca.pem"
        except OSError:
            time.sleep(0.05)
    proc.terminate()
    raise RuntimeError("mosquitto did not start")


@pytest.mark.integration  # a real broker (mosquitto) and certificates made by openssl
def test_mqtt_over_tls_with_a_password(tmp_path: Path) -> None:
    """The documented broker set-up: TLS with the broker's CA and a password connects and publishes; without the CA
    (the system's CAs do not know the broker) or without TLS the connection is refused, and said so."""
    from ins_hil.runtime.mqtt_out import MqttConfig, MqttPublisher

    proc, port, ca = _tls_broker(tmp_path)

    async def attempt(cfg: MqttConfig) -> MqttPublisher:
        pub = MqttPublisher(cfg, RuntimeMetrics())
        await pub.start()
        for _ in range(300):  # until the health message is out, or an error (at most ~30 s under load)
            if pub.metrics.outputs.get("mqtt", {}).get("health") or pub.last_error:
                break
            await asyncio.sleep(0.1)
        await pub.close()
        return pub

    base = {"host": "127.0.0.1", "port": port, "username": "gw", "password": "pw", "health_period": 0.1}
    try:
        ok = asyncio.run(attempt(MqttConfig(**base, tls=True, tls_ca=str(ca))))
        no_ca = asyncio.run(attempt(MqttConfig(**base, tls=True)))
        plain = asyncio.run(attempt(MqttConfig(**base)))
    finally:
        proc.terminate()
        proc.wait(timeout=10)
    assert ok.connects == 1 and ok.metrics.outputs["mqtt"]["health"] >= 1 and not ok.last_error
    assert not any("clear text" in w for w in ok.metrics.warnings)
    assert no_ca.connects == 0 and "CERTIFICATE_VERIFY_FAILED" in no_ca.last_error, no_ca.last_error
    assert any("cannot connect to" in w for w in no_ca.metrics.warnings)
    assert plain.connects == 0 and plain.last_error
    assert any("clear text" in w for w in plain.metrics.warnings)
