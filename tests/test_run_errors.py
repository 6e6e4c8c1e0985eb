"""What a person running `ins-hil run` sees: the errors of inputs and outputs that do not open (once, with
the config path), start-up lines saying where everything goes, warnings in `--no-status` mode, one final
summary, and a non-zero exit when an input never delivers within `gateway.input_timeout`.

The real command runs in a subprocess on small configs derived from configs/default.toml (the simulator
where a working input is needed); missing devices are paths that do not exist.
"""

from __future__ import annotations

import asyncio
import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from runtime_helpers import free_port, sim_config, sim_config_dict, sim_gateway

from ins_hil.config import ConfigError, from_dict

MISSING_IMU = "/nonexistent/ttyUSB9"
MISSING_OUT = "/nonexistent/ttyAMA9"


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float):
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"no TOML for {v!r}")


def _is_tables(v: Any) -> bool:
    return isinstance(v, list) and bool(v) and all(isinstance(x, dict) for x in v)


def to_toml(d: dict[str, Any], prefix: str = "") -> str:
    """A config dict as TOML (scalars, arrays, tables and arrays of tables: what the gateway config uses)."""
    lines = [f"{k} = {_toml_value(v)}" for k, v in d.items() if not isinstance(v, dict) and not _is_tables(v)]
    for k, v in d.items():
        name = f"{prefix}{k}"
        if isinstance(v, dict):
            lines += ["", f"[{name}]", to_toml(v, name + ".")]
        elif _is_tables(v):
            for item in v:
                lines += ["", f"[[{name}]]", to_toml(item, name + ".")]
    return "\n".join(lines)


def write_config(tmp: Path, **over: Any) -> Path:
    """configs/default.toml with tables overridden (runtime_helpers.sim_config_dict) as a file in ``tmp``."""
    p = tmp / "gw.toml"
    p.write_text(to_toml(sim_config_dict(**over)) + "\n")
    return p


def ins_hil_run(config: Path, *args: str, timeout: float = 60.0) -> tuple[subprocess.CompletedProcess[str], float]:
    """The real `ins-hil run --no-status` on ``config``; returns the result and the wall time (s)."""
    t0 = time.monotonic()
    r = subprocess.run(
        [sys.executable, "-m", "ins_hil", "run", "--config", str(config), "--no-status", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    return r, time.monotonic() - t0


def udp_out(port: int) -> str:
    """The URL of a MAVLink output sending to 127.0.0.1:port (``udpout:`` in MAVProxy's grammar, else ``udp:``)."""
    url = f"udpout:127.0.0.1:{port}"
    try:
        from_dict(sim_config_dict(outputs=[{"name": "gcs", "type": "mavlink", "url": url}]))
    except ConfigError:
        url = f"udp:127.0.0.1:{port}"
    return url


def _gcs(port: int) -> dict[str, Any]:
    return {"name": "gcs", "type": "mavlink", "url": udp_out(port), "role": "gcs", "sysid": 42}


def _imu(port: str) -> dict[str, Any]:
    return {"name": "imu0", "type": "serial_imu", "port": port, "baud": 921600}


_GNSS = {"name": "gnss", "type": "mavlink", "url": "udpin:127.0.0.1:0"}


def test_missing_imu_and_output_are_reported_once_and_the_run_fails(tmp_path: Path) -> None:
    gcs_port = free_port()
    cfg = write_config(
        tmp_path,
        gateway={"input_timeout": 3.0},
        inputs=[_imu(MISSING_IMU), _GNSS],  # the simulator still sends GNSS/baro: one input works
        outputs=[
            _gcs(gcs_port),
            {"name": "fc", "type": "mavlink", "url": f"serial:{MISSING_OUT}:921600", "role": "fc", "sysid": 1},
        ],
    )
    rec = tmp_path / "run.ihlog"
    r, _ = ins_hil_run(cfg, "--duration", "40", "--record", str(rec))
    err = r.stderr
    assert r.returncode == 3, err
    # stopped at the input timeout, not at --duration (the reason, not the wall time: a busy machine is slow)
    assert sum("summary (stopped: no data from 1 input(s) within 3 s)" in ln for ln in err.splitlines()) == 1, err
    lines = err.splitlines()
    # the driver's own error text, with the input's config path, exactly once (not on every re-open)
    imu_err = [ln for ln in lines if f"inputs[0] (imu0): open {MISSING_IMU}" in ln]
    assert len(imu_err) == 1, err
    assert "No such file or directory" in imu_err[0]
    out_err = [ln for ln in lines if "outputs[1] (fc): " in ln and MISSING_OUT in ln and "No such file" in ln]
    assert len(out_err) == 1, err
    # the failure names the input that never came up, and not the one that worked
    last = lines[-1]
    assert last.startswith("ins-hil run: no data within gateway.input_timeout = 3 s from inputs[0] (imu0)"), last
    assert "gnss" not in last
    # one summary at the end
    assert sum("summary" in ln for ln in lines) == 1, err
    # start-up lines: where MAVLink goes (URL and role) and where the recording is written, before any summary
    start = err.index(f"MAVLink outputs[0] (gcs): {udp_out(gcs_port)}, role gcs")
    assert err.index(f"MAVLink outputs[1] (fc): serial:{MISSING_OUT}:921600, role fc") > 0
    assert err.index(f"recording to {rec}") < err.index("summary")
    assert start < err.index("summary")


def test_no_status_prints_the_warnings_and_a_working_run_exits_0(tmp_path: Path) -> None:
    broker = free_port(socket.SOCK_STREAM)  # nothing listens here: MQTT stays offline
    cfg = write_config(
        tmp_path,
        # every IMU sample is "late"; the input timeout only a hang reaches (a busy host starts the simulator slowly)
        gateway={"input_timeout": 60.0, "late_threshold_ms": 0.001},
        mqtt={"enabled": True, "port": broker},
        outputs=[_gcs(free_port())],
        recorder={"enabled": False},
    )
    r, _ = ins_hil_run(cfg, "--duration", "5")
    err = r.stderr
    assert r.returncode == 0, err  # every input delivered within the timeout
    lines = err.splitlines()
    mqtt_off = [ln for ln in lines if f"mqtt: cannot connect to 127.0.0.1:{broker}" in ln]
    assert len(mqtt_off) == 1, err  # once, not on every retry
    assert any("warning: core behind:" in ln for ln in lines), err
    assert "recording to nowhere (recorder off)" in err
    assert f"mqtt: broker 127.0.0.1:{broker}" in err
    assert sum("summary (stopped: duration)" in ln for ln in lines) == 1, err


def test_input_timeout_is_validated_and_0_waits(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"gateway.input_timeout = -1.0: expected a finite number in \[0, 86400\] s"):
        from_dict(sim_config_dict(gateway={"input_timeout": -1.0}))
    cfg = write_config(
        tmp_path, gateway={"input_timeout": 0.0}, inputs=[_imu(MISSING_IMU), _GNSS], recorder={"enabled": False}
    )
    r, _ = ins_hil_run(cfg, "--duration", "2")
    assert r.returncode == 0, r.stderr  # 0 = wait for ever: the run ends at --duration
    assert sum(f"inputs[0] (imu0): open {MISSING_IMU}" in ln for ln in r.stderr.splitlines()) == 1, r.stderr


def test_the_live_view_shows_the_drivers_error_text() -> None:
    from rich.console import Console

    from ins_hil.commands.run import render

    cfg = sim_config(inputs=[_imu(MISSING_IMU), _GNSS], recorder={"enabled": False})
    gw = sim_gateway(cfg)
    seen: dict[str, str] = {}

    async def scenario() -> None:
        task = asyncio.create_task(gw.run(duration=None, signals=False))
        for _ in range(100):
            await asyncio.sleep(0.05)
            if gw.drivers and any(d.health.last_error for d in gw.drivers):
                await asyncio.sleep(0.2)  # a housekeeping tick
                break
        with open(os.devnull, "w") as devnull:
            con = Console(width=240, record=True, file=devnull)
            con.print(render(gw))
        seen["text"] = con.export_text()
        gw.request_stop()
        await asyncio.wait_for(task, 30.0)

    asyncio.run(scenario())
    assert f"inputs[0] (imu0): open {MISSING_IMU}" in seen["text"], seen["text"]
    assert "No such file or directory" in seen["text"]
    assert any(f"inputs[0] (imu0): open {MISSING_IMU}" in w for w in gw.metrics.warnings)


def test_a_device_that_appears_later_clears_the_problem(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """The IMU's device path does not exist at start (reported once), then appears (a symlink to the
    simulator's pty): the driver re-opens, samples flow, the problem is cleared and logged as up."""
    link = tmp_path / "ttyIMU"
    cfg = sim_config(inputs=[_imu(str(link)), _GNSS], recorder={"enabled": False})
    gw = sim_gateway(cfg)
    got: dict[str, Any] = {}

    async def scenario() -> None:
        task = asyncio.create_task(gw.run(duration=None, signals=False))
        for _ in range(200):
            await asyncio.sleep(0.05)
            if getattr(gw, "problems", None):
                break
        got["before"] = dict(gw.problems)
        assert gw.sim is not None
        link.symlink_to(gw.sim.imu_path)
        for _ in range(200):
            await asyncio.sleep(0.05)
            if not gw.problems and gw.metrics.source("imu0").received > 100:
                break
        got["after"] = dict(gw.problems)
        gw.request_stop()
        await asyncio.wait_for(task, 30.0)

    with caplog.at_level("INFO", logger="ins_hil"):
        asyncio.run(scenario())
    assert list(got["before"]) == ["inputs[0] (imu0)"] and str(link) in got["before"]["inputs[0] (imu0)"]
    assert got["after"] == {}
    assert gw.metrics.source("imu0").received > 100
    msgs = [r.getMessage() for r in caplog.records if r.name == "ins_hil"]
    assert sum(m.startswith(f"inputs[0] (imu0): open {link}") for m in msgs) == 1, msgs
    assert "inputs[0] (imu0): up" in msgs


def _busy_gateway(aligned: bool, problems: dict[str, str]) -> Any:
    """A gateway as the live view reads it, with the widest values a long run gives: 7-digit counts,
    5-digit latencies, a long config path, every output counter, the alignment's longest waiting text."""
    from types import SimpleNamespace

    from test_runtime_mavlink import _state

    from ins_hil.runtime.metrics import RuntimeMetrics

    m = RuntimeMetrics()
    m.t_start_ns -= 86_399 * 10**9  # up almost a day
    m.expect_inputs([("imu0", "serial_imu"), ("gnss", "mavlink")])
    for name, n, rate in (("gnss", 2_592_000, 30.0), ("imu0", 86_400_000, 1000.0)):
        src = m.source(name)
        src.received, src.rate_hz = n, rate
    m.source("imu0").drop("queue_full", 12_345)
    m.source("imu0").drop("bad_crc", 678)
    for k in m.hist:
        for ns in (80_000, 9_490_000, 24_626_000, 99_999_000):
            m.record(k, ns)
    m.roll_window()
    for typ in ("ATTITUDE", "ATTITUDE_QUATERNION", "GLOBAL_POSITION_INT", "HEARTBEAT", "SYS_STATUS", "VFR_HUD"):
        m.output("gcs", typ, 4_320_000)
    m.output("gcs", "link_refused", 86_400)
    m.output("gcs", "not_sent", 1_234)
    for k in ("states", "health", "faults", "state_dropped_offline", "connects"):
        m.output("mqtt", k, 864_000)
    m.faults, m.late, m.queue_depth_max, m.aligned = 12, 1_234_567, 4096, aligned
    m.test_ratios = {"gnss_pos": 0.41, "gnss_vel": 0.22, "baro": 0.13, "mag": 1.5}
    m.warn("core behind: 786 late samples in the last second, queue 4096")
    waiting = (
        "levelled at rest: waiting for motion (GNSS speed above 0.5 m/s or the IMU's motion test) to take the "
        "yaw from the GNSS course, or set a magnetometer reference (mag.ref_ned), alignment.gyrocompass or "
        "alignment.level_only"
    )
    st = _state(86_399.99)
    _core = SimpleNamespace(core="python")
    return SimpleNamespace(
        metrics=m,
        cfg=SimpleNamespace(source="/home/someone/vehicle-42/configs/flight_controller.toml", pipeline=_core),
        pipeline=SimpleNamespace(last_state=st, core=SimpleNamespace(align_status=lambda: "" if aligned else waiting)),
        mqtt=SimpleNamespace(connected=False, last_error="[Errno 111] Connection refused"),
        problems=problems,
    )


def _view_lines(gw: Any, width: int = 80) -> list[str]:
    from rich.console import Console

    from ins_hil.commands.run import render

    with open(os.devnull, "w") as devnull:
        con = Console(width=width, height=24, record=True, file=devnull, color_system=None)
        con.print(render(gw))
    return con.export_text().rstrip("\n").split("\n")


@pytest.mark.parametrize("aligned", [True, False])
def test_the_live_view_fits_an_80_column_terminal_and_says_how_to_stop(aligned: bool) -> None:
    """Every line of the live view within 80 cells, nothing cut (every value whole, the long texts all
    there), "Ctrl-C to stop" on the first line, and the default config's view within 24 rows."""
    from rich.cells import cell_len

    from ins_hil.commands.run import STOP_HINT

    problem = {"inputs[0] (imu0)": "open /dev/ttyUSB0: [Errno 2] No such file or directory: '/dev/ttyUSB0'"}
    gw = _busy_gateway(aligned, problem if not aligned else {})
    lines = _view_lines(gw)
    assert max(cell_len(ln) for ln in lines) <= 80, "\n".join(lines)
    assert lines[0].rstrip().endswith(STOP_HINT) and STOP_HINT == "Ctrl-C to stop"
    text = "\n".join(lines)
    for value in ("lat 50.450000", "lon 30.520000", "h 181.5 m", "v 3.0 -4.0 0.5 m/s", "86,400,000", "2,592,000",
                  "queue_full 12345", "bad_crc 678", "mag 1.50", "late 1,234,567", "faults 12", "99,999",
                  "up 23:59:59", "config flight_controller.toml"):  # fmt: skip
        assert value in text, (value, text)
    flat = "".join(text.split())  # a text folded over lines is still whole
    for long in (gw.metrics.warnings[-1], gw.mqtt.last_error, *gw.problems.values(), gw.pipeline.core.align_status()):
        assert "".join(long.split()) in flat, (long, text)
    assert "…" not in text and "..." not in text
    if aligned:  # the default config's view (two inputs, the gcs output, MQTT) on one 80 × 24 screen
        assert len(lines) <= 24, f"{len(lines)} rows:\n{text}"
