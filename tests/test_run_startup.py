"""The start-up probe: how soon `ins-hil run` is on the ground station's list.

The real command runs on configs/default.toml (simulated sensors, MQTT to a broker that may not run, the
recorder on) with only its MAVLink output moved to a free port, where the test listens as the ground
station. The HEARTBEAT needs neither the core nor the simulator, so the gateway opens its MAVLink outputs
first: the test asserts that order (load-independent: what the process had loaded, and whether the
simulator existed, when it sent its first HEARTBEAT) and prints the times it measured.
"""

from __future__ import annotations

import asyncio
import socket
import subprocess
import sys
import time
import tomllib
from pathlib import Path
from typing import Any

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink
from test_run_errors import to_toml

from ins_hil import config as config_mod

#: loaded by the core, the full config validation or the simulator: none of it before the first HEARTBEAT (the
#: typed [core.nav] of the config reads FilterConfig's field metadata from ins_hil.fusion.ekf, an 8-ms import
#: of plain dataclasses: the filter's numerics, the aid models, the FDI and scipy stay out)
HEAVY = (
    "scipy",
    "ins_hil.core",
    "ins_hil.fdi",
    "ins_hil.fusion.measurements",
    "ins_hil.fusion.sqrt",
    "ins_hil.fusion.yaw_gsf",
    "ins_hil.sim",
)

# Runs `python -m ins_hil ARGV` with socket.send/sendto wrapped: at the first MAVLink 2 HEARTBEAT the
# process sends, it prints the seconds since it started (/proc), the CPU seconds it used (what that
# takes on an idle machine), the HEAVY modules it has loaded and its child processes (the simulator is one).
_PROBE = """
import os, runpy, socket, sys
HEAVY = HEAVY_NAMES
def since_start():
    with open("/proc/self/stat") as f:
        start = int(f.read().rsplit(")", 1)[1].split()[19])
    with open("/proc/uptime") as f:
        return float(f.read().split()[0]) - start / os.sysconf("SC_CLK_TCK")
def children():
    out = []
    for d in os.listdir("/proc"):
        try:
            with open(f"/proc/{d}/stat") as f:
                if d.isdigit() and int(f.read().rsplit(")", 1)[1].split()[1]) == os.getpid():
                    out.append(d)
        except OSError:
            pass
    return out
seen = []
def probe(data):
    if not seen and data[:1] == b"\\xfd" and len(data) > 10 and data[7:10] == b"\\0\\0\\0":
        seen.append(1)
        heavy = [h for h in HEAVY if any(m == h or m.startswith(h + ".") for m in sys.modules)]
        cpu = os.times().user + os.times().system
        print("FIRST-HEARTBEAT", f"{since_start():.3f}", f"{cpu:.3f}", "heavy=" + ",".join(heavy),
              "children=" + ",".join(children()), file=sys.stderr, flush=True)
send, sendto = socket.socket.send, socket.socket.sendto
def send_(self, data, *a):
    probe(data)
    return send(self, data, *a)
def sendto_(self, data, *a):
    probe(data)
    return sendto(self, data, *a)
socket.socket.send, socket.socket.sendto = send_, sendto_
sys.argv[0] = "ins-hil"
runpy.run_module("ins_hil", run_name="__main__", alter_sys=True)
""".replace("HEAVY_NAMES", repr(HEAVY))


def _default_config_to(tmp: Path, port: int) -> Path:
    """configs/default.toml with its ground-station output sending to 127.0.0.1:port."""
    d = tomllib.loads(config_mod.default_path().read_text())
    assert [o["url"] for o in d["outputs"]] == ["udpout:127.0.0.1:14550"]
    d["outputs"][0]["url"] = f"udpout:127.0.0.1:{port}"
    p = tmp / "gw.toml"
    p.write_text(to_toml(d) + "\n")
    return p


def test_the_first_heartbeat_goes_out_before_the_core_and_the_simulator(tmp_path: Path, record_property: Any) -> None:
    gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gcs.bind(("127.0.0.1", 0))
    gcs.settimeout(1.0)
    cfg = _default_config_to(tmp_path, gcs.getsockname()[1])
    parser = mavlink.MAVLink(None)
    got: list[tuple[float, Any, Any]] = []  # (s since the command was started, sender address, message)
    t0 = time.monotonic()
    proc = subprocess.Popen(
        [sys.executable, "-c", _PROBE, "run", "--config", str(cfg), "--no-status", "--duration", "60"],
        cwd=tmp_path,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        while time.monotonic() - t0 < 90 and not any(m.get_type() == "ATTITUDE" for _, _, m in got):
            try:
                data, addr = gcs.recvfrom(65536)
            except TimeoutError:
                assert proc.poll() is None, proc.communicate()[1]
                continue
            got += [(time.monotonic() - t0, addr, m) for m in parser.parse_buffer(data) or []]
    finally:
        proc.terminate()  # SIGTERM: a clean stop
        _, err = proc.communicate(timeout=60)
        gcs.close()
    assert proc.returncode == 0, err
    probe = [ln.split() for ln in err.splitlines() if ln.startswith("FIRST-HEARTBEAT ")]
    assert len(probe) == 1, err
    since_start, cpu, heavy, children = float(probe[0][1]), float(probe[0][2]), probe[0][3], probe[0][4]
    # the order: the first HEARTBEAT was handed to the socket before the core, the config's full
    # validation (scipy) or the simulator were loaded, and before the simulator process existed
    assert heavy == "heavy=", heavy
    assert children == "children=", children
    # the ground station heard the vehicle first: HEARTBEAT from system 42, then the states, from the
    # same socket (the gateway took over the output opened at start: one link, one sequence)
    first_t, first_addr, first = got[0]
    assert first.get_type() == "HEARTBEAT" and first.get_srcSystem() == 42, [m.get_type() for _, _, m in got]
    att_t, att_addr, _ = next(x for x in got if x[2].get_type() == "ATTITUDE")
    assert att_addr == first_addr
    seqs = [m.get_seq() for _, a, m in got]
    assert seqs == [k % 256 for k in range(seqs[0], seqs[0] + len(seqs))], seqs
    # heartbeats go on at 1 Hz while the rest starts (no gap of the start-up's length)
    beats = [t for t, _, m in got if m.get_type() == "HEARTBEAT"]
    print(
        f"\nfirst HEARTBEAT {since_start:.3f} s after the process started (sent; {cpu:.3f} s of CPU), received "
        f"{first_t:.3f} s after Popen; first ATTITUDE at {att_t:.3f} s; HEARTBEATs received {len(beats)}"
    )
    record_property("first_heartbeat_s", since_start)
    record_property("first_heartbeat_cpu_s", cpu)
    record_property("first_attitude_s", att_t)


def test_outputs_opened_first_are_taken_over_with_the_parameter_file_rates(tmp_path: Path) -> None:
    """The gateway adopts the endpoints `open_outputs` opened: the same objects (link, sequence), with the
    rates of `<config>.params.toml` (SR_*), which only the full load applies."""
    from ins_hil.runtime.loop import Gateway, open_outputs

    gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gcs.bind(("127.0.0.1", 0))
    cfg_path = _default_config_to(tmp_path, gcs.getsockname()[1])
    (tmp_path / "gw.params.toml").write_text("[params.gcs]\nSR_ATTITUDE = 7.0\nSR_VFR_HUD = 0.0\n")

    async def scenario() -> None:
        opened = await open_outputs(config_mod.load_outputs(cfg_path))
        ep = opened.endpoints[0]
        assert ep.sent.get("HEARTBEAT") == 1 and ep.rates["ATTITUDE"] == 50.0 and "VFR_HUD" in ep.rates
        gw = Gateway(config_mod.load(cfg_path), outputs=opened)
        assert gw.mav_outputs == [ep] and gw.metrics is opened.metrics
        assert ep.rates["ATTITUDE"] == 7.0 and "VFR_HUD" not in ep.rates
        assert ep.cfg is gw.cfg.outputs[0]
        await opened.close()
        other = await open_outputs([config_mod.load_outputs(cfg_path)[0], config_mod.load_outputs(cfg_path)[0]])
        with pytest.raises(RuntimeError, match="not those of the configuration"):
            Gateway(config_mod.load(cfg_path), outputs=other)
        await other.close()

    try:
        asyncio.run(scenario())
    finally:
        gcs.close()


def test_a_bad_config_found_after_the_outputs_opened_is_one_line_and_exit_2(tmp_path: Path) -> None:
    """The [[outputs]] are valid, another section is not: the outputs open first, then the full load
    names the bad key (one line, exit 2) and the outputs are closed."""
    cfg = _default_config_to(tmp_path, 9)
    cfg.write_text(cfg.read_text().replace("level_samples = 200", "level_samples = -5"))
    assert "level_samples = -5" in cfg.read_text()
    r = subprocess.run(
        [sys.executable, "-m", "ins_hil", "run", "--config", str(cfg), "--no-status"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1, r.stderr
    assert lines[0].startswith("ins-hil run: config error: ") and "core.level_samples" in lines[0], lines
    assert not (tmp_path / "recordings").exists()
