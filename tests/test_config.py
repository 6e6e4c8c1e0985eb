"""Config loading and validation: every shipped config loads; bad keys/values are named; nothing half-starts."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from runtime_helpers import sim_config_dict

from ins_hil.config import ConfigError, default_path, from_dict, load
from ins_hil.core_parts.config import MOVED

CONFIGS = sorted((Path(__file__).resolve().parent.parent / "configs").glob("*.toml"))


@pytest.mark.parametrize("path", CONFIGS, ids=lambda p: p.name)
def test_shipped_configs_load(path: Path) -> None:
    cfg = load(path)
    assert any(i.type in ("serial_imu", "can_imu") for i in cfg.inputs)


def test_default_is_the_simulated_setup() -> None:
    cfg = load(default_path())
    assert cfg.sim_enabled and cfg.sim.imu_rate == 1000.0
    assert [o.url for o in cfg.outputs] == ["udpout:127.0.0.1:14550"]
    assert cfg.mqtt.enabled and cfg.recorder.enabled and cfg.pipeline.core == "python"


@pytest.mark.parametrize(
    ("patch", "message"),
    [
        ({"gateway": {"late_treshold_ms": 5.0}}, "unknown key 'gateway.late_treshold_ms'"),
        ({"mqtt": {"enabled": True, "port": "1883"}}, "mqtt.port = '1883': expected an integer 1..65535"),
        ({"mqtt": {"enabled": True, "port": 70000}}, "mqtt.port = 70000"),
        ({"core": {"kind": "rust"}}, "core.kind = 'rust': expected one of 'python', 'c'"),
        ({"sim": {"imu_rate": -5.0}}, "sim.imu_rate = -5.0: expected a finite number in [1, 10000] Hz"),
        ({"outputs": [{"url": "udpout:localhost"}]}, "outputs[0].url = 'udpout:localhost'"),
        ({"outputs": [{"url": "udpout:127.0.0.1:14550", "role": "autopilot"}]}, "outputs[0].role = 'autopilot'"),
        ({"outputs": [{"signing_key": "abc"}]}, "outputs[0].signing_key = 'abc'"),
        ({"outputs": [{"rates": {"ATTITUDE_EULER": 10}}]}, "unknown key 'outputs[0].rates.ATTITUDE_EULER'"),
        ({"outputs": [{"rates": {"ATTITUDE": -1}}]}, "outputs[0].rates.ATTITUDE = -1"),
        ({"inputs": [{"type": "serial_imu", "port": "sim", "bauds": 5}]}, "unknown key 'inputs[0].bauds'"),
        ({"inputs": [{"type": "usb", "port": "x"}]}, "inputs[0].type = 'usb'"),
        (
            {
                "inputs": [
                    {"type": "can_imu", "options": {"interface": "socketcan", "channel": "vcan0", "protocol": "x"}}
                ]
            },
            "inputs[0].options.protocol = 'x': expected one of 'dronecan', 'dbc'",
        ),
        ({"core": {"nav": {"gnss_lever_arm": [0, 0, 0]}}}, "unknown key 'core.nav.gnss_lever_arm'"),
        ({"inputs": [{"type": "mavlink", "url": "udpin:127.0.0.1:0"}]}, "no IMU input"),
        ({"recorder": {"flush_period": 0.5}}, "recorder.flush_period = 0.5: expected a finite number in (0, 0.1] s"),
        ({"fdi": {"imu_ids": []}}, "fdi.imu_ids = []"),
        (
            {"core": {"calibration": "/nonexistent/cal.json"}},
            "core.calibration = '/nonexistent/cal.json': file not found",
        ),
        ({"telemetry": {}}, "unknown section 'telemetry'"),
    ],
)
def test_bad_values_are_named(patch: dict, message: str) -> None:
    with pytest.raises(ConfigError) as e:
        from_dict(sim_config_dict(**patch))
    assert message in str(e.value)


def test_a_flat_nav_key_names_its_section(tmp_path: Path) -> None:
    """[core.nav] keys before the sections: one line naming the file and where the key moved."""
    p = tmp_path / "x.toml"
    text = default_path().read_text()
    assert "[core.nav]" in text and "[core.nav.delay]" in text  # the key lands in [core.nav]: the table before
    p.write_text(text.replace("\n[core.nav.delay]", "\ngnss_lever_arm_b = [0.0, 0.0, -0.1]\n[core.nav.delay]", 1))
    with pytest.raises(ConfigError) as e:
        load(p)
    assert str(e.value) == f"{p}: [core.nav] gnss_lever_arm_b moved to [core.nav.gnss] lever_arm_b"
    p.write_text(
        text.replace("\n[core.nav.delay]", "\n[core.nav.gnss]\nlever_arm_b = [0.0, 0.0, -0.1]\n[core.nav.delay]", 1)
    )
    assert load(p).pipeline.nav.gnss.lever_arm_b.tolist() == [0.0, 0.0, -0.1]
    for old, (sec, new) in MOVED.items():
        with pytest.raises(ConfigError, match=rf"^\[core\.nav\] {old} moved to \[core\.nav\.{sec}\] {new}$"):
            from_dict(sim_config_dict(core={"nav": {old: 1.0}}))


def test_bad_toml_names_the_file(tmp_path: Path) -> None:
    p = tmp_path / "broken.toml"
    p.write_text("[gateway\nname = 1\n")
    with pytest.raises(ConfigError, match=r"broken\.toml: not valid TOML"):
        load(p)
    with pytest.raises(ConfigError, match="cannot read config"):
        load(tmp_path / "missing.toml")


def test_cli_rejects_bad_config_before_starting_anything(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    text = default_path().read_text()
    bad.write_text(text.replace('url = "udpout:127.0.0.1:14550"', 'url = "udpout:127.0.0.1:99999"'))
    r = subprocess.run(
        [sys.executable, "-m", "ins_hil", "run", "--config", str(bad), "--no-status", "--duration", "5"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 2
    assert "outputs[0].url = 'udpout:127.0.0.1:99999'" in r.stderr and "port 99999 out of range" in r.stderr
    assert not (tmp_path / "recordings").exists()  # nothing half-started: no recorder file, no simulator


@pytest.mark.slow
def test_cli_core_c_runs(tmp_path: Path) -> None:
    """``--core c`` runs the gateway on the C reference core (built with the package, as the parity tests need)."""
    r = subprocess.run(
        [sys.executable, "-m", "ins_hil", "run", "--core", "c", "--no-status", "--no-mqtt", "--duration", "2"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 0, r.stderr
    assert "C reference core" not in r.stderr and list((tmp_path / "recordings").glob("*.ihlog"))


def test_cli_core_c_unavailable_stops_before_starting(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Without the C core (its module not importable) ``--core c`` stops with status 2 and a clear message before
    anything starts; the Python core is still built."""
    import ins_hil
    from ins_hil.cli import main
    from ins_hil.runtime.pipeline import check_core

    monkeypatch.setitem(sys.modules, "ins_hil.cref", None)  # import ins_hil.cref -> ImportError
    monkeypatch.delattr(ins_hil, "cref", raising=False)  # (else `from ins_hil import cref` finds the loaded module)
    with pytest.raises(RuntimeError, match=r"core 'c': the C reference core \(ins_hil.cref\) is not available"):
        check_core("c")
    check_core("python")
    monkeypatch.chdir(tmp_path)
    assert main(["run", "--core", "c", "--no-status", "--no-mqtt", "--duration", "2"]) == 2
    assert "C reference core" in capsys.readouterr().err
    assert not (tmp_path / "recordings").exists()
