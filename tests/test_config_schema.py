"""The configuration schema: every key typed, ranged and with its unit; a file that loads starts;
no input file makes a command print a traceback; docs/configuration.md is generated from the schema."""

from __future__ import annotations

import copy
import dataclasses
import math
import os
import subprocess
import sys
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ins_hil import config_schema
from ins_hil.config import REPO_CONFIGS, Config, ConfigError, from_dict, load
from ins_hil.types import ImuSample

CONFIGS = sorted(REPO_CONFIGS.glob("*.toml"))
DBC = REPO_CONFIGS / "imu_dbc.dbc"


def _doc(name: str) -> dict[str, Any]:
    return tomllib.loads((REPO_CONFIGS / name).read_text())


def sim_doc(**over: Any) -> dict[str, Any]:
    """configs/default.toml (MQTT off, no outputs unless given) with tables merged from ``over``."""
    d = _doc("default.toml")
    d["mqtt"] = {"enabled": False}
    for k, v in over.items():
        d[k] = {**d[k], **v} if isinstance(v, dict) and isinstance(d.get(k), dict) else v
    return d


def dbc_doc(**dbc: Any) -> dict[str, Any]:
    """configs/dronecan_imu.toml with its CAN IMU switched to the shipped DBC profile."""
    d = _doc("dronecan_imu.toml")
    opts = {"interface": "virtual", "channel": "t", "protocol": "dbc", "dbc": {"dbc": str(DBC), **dbc}}
    d["inputs"][0]["options"] = opts
    return d


def fdi_doc() -> dict[str, Any]:
    """Three serial IMUs with FDI (the soak test's layout)."""
    d = sim_doc()
    d["inputs"] = [{"name": f"imu{i}", "type": "serial_imu", "port": f"/dev/ttyUSB{i}"} for i in range(3)]
    d["inputs"].append({"name": "gnss", "type": "mavlink", "url": "udpin:127.0.0.1:0"})
    d["sim"] = {"enabled": False}
    opts = {"geometry": "triple_imu", "dt": 0.001, "gyro_noise": 1e-4, "accel_noise": 1e-3}
    d["fdi"] = {"enabled": True, "imu_ids": [0, 1, 2], "options": opts}
    return d


def _rejects(d: dict[str, Any], message: str) -> str:
    with pytest.raises(ConfigError) as e:
        from_dict(d)
    msg = str(e.value)
    assert message in msg and "\n" not in msg, msg
    return msg


# ---------------------------------------------------------------------------------------------- findings


def _set(d: dict[str, Any], path: str, value: Any) -> dict[str, Any]:
    """``d`` with ``path`` (dotted; ``inputs.0.port``) set to ``value``."""
    d = copy.deepcopy(d)
    node: Any = d
    parts = path.split(".")
    for p in parts[:-1]:
        node = node[int(p)] if isinstance(node, list) else node.setdefault(p, {})
    node[int(parts[-1]) if isinstance(node, list) else parts[-1]] = value
    return d


SIM = sim_doc(outputs=[{"name": "gcs", "url": "udpout:127.0.0.1:14550"}])
INF, NAN = math.inf, math.nan

FINDINGS = [
    # wrong types in core, sim, [core.nav.filter] (TypeError from deep inside before)
    (SIM, "core.init_h", "high", "core.init_h = 'high': expected a finite number in [-1000, 100000] m"),
    (SIM, "core.level_samples", 2.5, "core.level_samples = 2.5: expected an integer 1..100000"),
    (SIM, "core.nav", "fast", "core.nav = 'fast': expected a table"),
    (SIM, "core.nav.gnss.lever_arm_b", [0, 0], "core.nav.gnss.lever_arm_b = [0, 0]: expected 3 finite numbers"),
    (SIM, "core.nav.gnss.gate", "5", "core.nav.gnss.gate = '5': expected a finite number"),
    (SIM, "core.nav.gnss", 5, "core.nav.gnss = 5: expected a table"),
    (SIM, "core.nav.filter", [1], "core.nav.filter = [1]: expected a table"),
    (SIM, "core.nav.filter.cov_every", "10", "core.nav.filter.cov_every = '10': expected an integer 1..1000"),
    (SIM, "core.nav.filter.gyro_arw", [1.0], "core.nav.filter.gyro_arw = [1.0]: expected a finite number"),
    (SIM, "core.nav.filter.init_accel_sf", [1e-3], "core.nav.filter.init_accel_sf = [0.001]: expected 3"),
    (SIM, "sim.imu_rate", "1k", "sim.imu_rate = '1k': expected a finite number in [1, 10000] Hz"),
    (SIM, "sim.seed", 1.5, "sim.seed = 1.5: expected an integer"),
    (SIM, "sim.seed", -1, "sim.seed = -1: expected an integer 0..4294967295"),
    (SIM, "sim.profile", 3, "sim.profile = 3: expected one of 'uav', 'static'"),
    # values that passed and then crashed at start or run
    (SIM, "recorder.max_mb", INF, "recorder.max_mb = inf: expected a finite number in [0.01, 1048576] MiB"),
    (SIM, "outputs.0.rates", {"ATTITUDE": 1e-300}, "outputs[0].rates.ATTITUDE = 1e-300: expected a finite number 0 or"),
    (SIM, "outputs.0.rates", {"ATTITUDE": INF}, "outputs[0].rates.ATTITUDE = inf"),
    (SIM, "inputs.0.port", "", "inputs[0].port = '': expected a non-empty string"),
    (SIM, "core.init_h", NAN, "core.init_h = nan: expected a finite number"),
    (SIM, "core.init_lat_deg", 900, "core.init_lat_deg = 900: expected a finite number in [-89, 89] °"),
    (SIM, "inputs.1.sysid", 999, "inputs[1].sysid = 999: expected an integer 0..255"),
    (SIM, "fdi.imu_ids", [True], "fdi.imu_ids = [True]: expected a non-empty list of integers 0..255"),
    (SIM, "gateway.status_period", INF, "gateway.status_period = inf"),
    (SIM, "gateway.late_threshold_ms", INF, "gateway.late_threshold_ms = inf"),
    (SIM, "sim.gnss_rate", INF, "sim.gnss_rate = inf"),
    (SIM, "sim.duration", INF, "sim.duration = inf"),
    (SIM, "sim.chunk_s", 1e-300, "sim.chunk_s = 1e-300"),
    (SIM, "mqtt", {"enabled": True, "health_period": INF}, "mqtt.health_period = inf"),
    (SIM, "mqtt", {"enabled": True, "state_rate": 1e-300}, "mqtt.state_rate = 1e-300"),
    (SIM, "mqtt", {"enabled": True, "topic_prefix": "a/#"}, "mqtt.topic_prefix = 'a/#'"),
    (SIM, "core.epoch_wait_periods", INF, "core.epoch_wait_periods = inf"),
    (SIM, "core.nav.delay.max_delay", INF, "core.nav.delay.max_delay = inf"),
    (SIM, "fdi.aiding.window", INF, "fdi.aiding.window = inf"),
    (SIM, "fdi.aiding.p_fa_hour", 1e-300, "fdi.aiding.p_fa_hour = 1e-300: expected a finite number in [1e-12, 1)"),
    (fdi_doc(), "fdi.options.p_false_alarm", 1e-300, "fdi.options.p_false_alarm = 1e-300"),
    (SIM, "fdi.aiding.cusum_k", 1e-300, "fdi.aiding.cusum_k = 1e-300"),
    (SIM, "core.nav.mag.ref_ned", [0, 0, 0], "core.nav.mag.ref_ned = [0, 0, 0]: expected 3 finite numbers"),
    (SIM, "sim.lat_deg", 90.0, "sim.lat_deg = 90.0"),
    # the CAN IMU's options (float node ids were truncated; rate_hz = inf gave dt = 0)
    (_doc("dronecan_imu.toml"), "inputs.0.options.nodes", [10.5], "inputs[0].options.nodes = [10.5]: expected"),
    (_doc("dronecan_imu.toml"), "inputs.0.options.node_id", 100.0, "inputs[0].options.node_id = 100.0"),
    (_doc("dronecan_imu.toml"), "inputs.0.options.nodes", [True], "inputs[0].options.nodes = [True]"),
    (_doc("dronecan_imu.toml"), "inputs.0.options.stale_s", INF, "inputs[0].options.stale_s = inf"),
    (_doc("dronecan_imu.toml"), "inputs.0.options.bitrate", 1e6, "inputs[0].options.bitrate = 1000000.0"),
    (_doc("dronecan_imu.toml"), "inputs.0.options.fd", NAN, "inputs[0].options.fd = nan"),
    (_doc("dronecan_imu.toml"), "inputs.0.options.dbc", {"rate_hz": 100.0}, "inputs[0].options.dbc: only with"),
    (dbc_doc(), "inputs.0.options.dbc.rate_hz", INF, "inputs[0].options.dbc.rate_hz = inf"),
    (dbc_doc(), "inputs.0.options.dbc.rate_hz", 0, "inputs[0].options.dbc.rate_hz = 0"),
    (dbc_doc(), "inputs.0.options.dbc.counter_signal", "Cnt", "inputs[0].options.dbc.counter_signal = 'Cnt': not a"),
    (dbc_doc(), "inputs.0.options.dbc.crc_signal", "Crc", "inputs[0].options.dbc.crc_signal = 'Crc': not a signal"),
    (dbc_doc(), "inputs.0.options.dbc.gyro_signals", ["GyroX"], "inputs[0].options.dbc.gyro_signals = ['GyroX']"),
    (dbc_doc(), "inputs.0.options.dbc.dbc", str(REPO_CONFIGS), "inputs[0].options.dbc.dbc = "),
    (dbc_doc(), "inputs.0.options.dbc.dbc", str(REPO_CONFIGS / "default.toml"), "not a DBC file"),
    (fdi_doc(), "fdi.options.dt", INF, "fdi.options.dt = inf"),
    (fdi_doc(), "fdi.options.persistence", 2.0, "fdi.options.persistence = 2.0: expected an integer"),
    (fdi_doc(), "fdi.imu_ids", [0, 1, 1], "fdi.imu_ids = [0, 1, 1]"),
]


@pytest.mark.parametrize(("doc", "path", "value", "message"), FINDINGS, ids=[f"{p}={v!r}" for _, p, v, _ in FINDINGS])
def test_fuzz_findings_are_one_line_errors(doc: dict[str, Any], path: str, value: Any, message: str) -> None:
    """Each finding of the config fuzzing (traceback, or accepted and then crashing/NaN) is a ConfigError
    naming the dotted key, the value and what is allowed."""
    _rejects(_set(doc, path, value), message)


def test_variants_used_by_the_findings_load() -> None:
    """The documents the findings mutate are valid as they are (so each finding is the mutation's doing)."""
    for d in (SIM, dbc_doc(), fdi_doc(), _doc("dronecan_imu.toml")):
        assert isinstance(from_dict(copy.deepcopy(d)), Config)


def test_empty_strings_mean_none_in_the_dbc_profile() -> None:
    cfg = from_dict(dbc_doc(status_message="", crc_signal=""))
    assert cfg.inputs[0].options["dbc"]["crc_signal"] is None and cfg.inputs[0].options["dbc"]["status_message"] is None


def test_int_for_a_float_key_is_converted_and_floats_stay_exact() -> None:
    cfg = from_dict(_set(SIM, "core.nav.gnss.gate", 4))
    assert cfg.pipeline.nav.gnss.gate == 4.0 and isinstance(cfg.pipeline.nav.gnss.gate, float)
    assert cfg.pipeline.nav.filter.cov_every == 10 and cfg.to_dict()["pipeline"]["nav"]["filter"] == {"cov_every": 10}


def test_non_utf8_file_is_named(tmp_path: Path) -> None:
    p = tmp_path / "latin1.toml"
    p.write_bytes((REPO_CONFIGS / "default.toml").read_bytes().replace(b'name = "ins-hil"', b'name = "ins-h\xefl"'))
    with pytest.raises(ConfigError, match=r"latin1\.toml: not UTF-8 text \(byte 0xef on line 14, offset \d+\)"):
        load(p)


def test_directory_and_deep_nesting(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="cannot read config"):
        load(tmp_path)
    p = tmp_path / "deep.toml"
    p.write_text("a = " + "[" * 5000 + "]" * 5000 + "\n")
    with pytest.raises(ConfigError, match=r"deep\.toml: not valid TOML"):
        load(p)


# ---------------------------------------------------------------------------------------------- schema


def test_every_key_has_a_type_and_numbers_a_range_and_help() -> None:
    for sec in config_schema.sections():
        for k in sec.keys.values():
            assert k.type in config_schema.TYPES, (sec.name, k.name)
            assert k.help, f"{sec.name}.{k.name}: no help"
            if k.type in ("int", "float") and not k.choices:
                assert k.range, f"{sec.name}.{k.name}: no range"


def test_a_new_dataclass_field_is_a_key_with_its_metadata() -> None:
    """A field added to a section's dataclass becomes a key: typed from its default, finite, with the unit and
    range of its metadata (one line, no schema edit)."""

    @dataclasses.dataclass
    class Guard:
        max_rate: float = dataclasses.field(default=40.0, metadata={"unit": "rad/s", "range": "(0, 100]"})
        max_dt: float = dataclasses.field(default=0.1, metadata={"unit": "s", "gt": 0, "max": 1})
        plain: float = 1.0
        count: int = 3
        band: tuple[float, float] = dataclasses.field(default=(0.5, 2.0), metadata={"range": "(0, 10]"})

    keys = config_schema.dataclass_keys(Guard)
    assert keys["max_rate"].unit == "rad/s" and keys["max_rate"].allowed() == "a finite number in (0, 100] rad/s"
    assert keys["max_dt"].allowed() == "a finite number in (0, 1] s"
    assert keys["max_rate"].check(7, "core.max_rate") == 7.0
    for bad in (0, 101, INF, NAN, "1", True):
        with pytest.raises(ConfigError, match=r"core\.max_rate = "):
            keys["max_rate"].check(bad, "core.max_rate")
    with pytest.raises(ConfigError, match=r"core\.plain = inf: expected a finite number"):
        keys["plain"].check(INF, "core.plain")
    with pytest.raises(ConfigError, match=r"core\.count = 3.0: expected an integer"):
        keys["count"].check(3.0, "core.count")
    assert keys["band"].type == "list[float]" and keys["band"].check([1, 3.0], "core.band") == [1.0, 3.0]
    with pytest.raises(ConfigError, match=r"core\.band = \[0, 1\]: expected a list of finite numbers in \(0, 10\]"):
        keys["band"].check([0, 1], "core.band")


def test_a_setting_built_in_code_obeys_the_range_of_its_key_in_a_file() -> None:
    """One range per key, from its field's metadata: the dataclass refuses what the TOML loader refuses (drag_coef
    was '(0, 10]' in the schema's table but '> 0' in AidsConfig.__post_init__), in one line naming the key."""
    from ins_hil.core_parts.config import SECTIONS, AidsConfig, NavConfig
    from ins_hil.fusion.ekf import FilterConfig
    from ins_hil.settings import dataclass_keys

    with pytest.raises(
        ValueError, match=r"^NavConfig\.aids\.drag_coef=20\.0: expected a finite number in \(0, 10\] 1/s$"
    ):
        AidsConfig(drag_coef=20.0)
    with pytest.raises(
        ConfigError, match=r"^core\.nav\.aids\.drag_coef = 20\.0: expected a finite number in \(0, 10\] 1/s$"
    ):
        config_schema.validate("core.nav.aids", {"drag_coef": 20.0})
    with pytest.raises(ValueError, match=r"^NavConfig\.gravity='flat': expected one of 'normal', 'j2'$"):
        NavConfig(gravity="flat")
    checked = 0
    for name, cls in [*SECTIONS.items(), ("filter", FilterConfig)]:
        for k in dataclass_keys(cls).values():
            if k.type not in ("float", "int") or not k.range or math.isinf(k.interval.hi):
                continue
            bad = int(k.interval.hi) + 1 if k.type == "int" else 2.0 * k.interval.hi + 1.0
            with pytest.raises(ValueError, match=rf"\.{k.name}="):
                cls(**{k.attr: bad})
            with pytest.raises(ConfigError, match=rf"core\.nav\.{name}\.{k.name} = "):
                config_schema.validate(f"core.nav.{name}", {k.name: bad})
            checked += 1
    assert checked > 60


def test_the_validation_limits_have_one_range_in_the_file_the_docs_and_the_check() -> None:
    """[core] gnss_min_fix_type was '[0, 8]' in the schema and docs but 2..6 in Limits.check: one range now, from
    the field's metadata, with the file's one-line message."""
    from ins_hil.validation import Limits

    for bad, allowed in ((7, r"an integer 2\.\.6"), (1, r"an integer 2\.\.6")):
        with pytest.raises(ConfigError, match=rf"core\.gnss_min_fix_type = {bad}: expected {allowed}$"):
            from_dict(sim_doc(core={"gnss_min_fix_type": bad}), "t")
        with pytest.raises(ValueError, match=rf"^core\.gnss_min_fix_type = {bad}: expected {allowed}$"):
            Limits(gnss_min_fix_type=bad).check("core")
    assert "| `gnss_min_fix_type` | int |  | 3 | an integer 2..6 |" in config_schema.markdown()
    with pytest.raises(ValueError, match=r"^core\.imu_period_s = 1e-06: expected a finite number 0 or in \[1e-05, 1\]"):
        Limits(imu_period_s=1e-6).check("core")


def test_every_pipeline_field_is_a_core_key() -> None:
    from ins_hil.runtime.pipeline import PipelineConfig

    core = config_schema.section("core").keys
    loader = {"imu_ids", "fdi", "fdi_options", "aiding_fdi", "aiding_options"}  # set from the [fdi] tables
    loader.add("limits")  # built from its flat [core] keys, checked below
    loader.add("nav")  # the [core.nav] table, built once as a NavConfig (runtime.pipeline.nav_config)
    assert core["nav"].type == "table"
    attrs = {k.attr for k in core.values()}
    missing = {f.name for f in dataclasses.fields(PipelineConfig) if f.init} - loader - attrs
    assert not missing, f"PipelineConfig fields that are no [core] key (a nested dataclass needs a section): {missing}"
    from ins_hil.validation import Limits

    assert {f.name for f in dataclasses.fields(Limits)} <= set(core)


def test_core_limit_keys_reach_the_validation_boundary() -> None:
    """[core] gyro_range_dps & co. fill PipelineConfig.limits, and a saved document keeps them."""
    from ins_hil import config as config_mod
    from ins_hil.validation import Limits
    from tests.runtime_helpers import sim_config_dict

    cfg = config_mod.from_dict(sim_config_dict(core={"gyro_range_dps": 500, "gnss_min_fix_type": 4}), "t.toml")
    assert cfg.pipeline.limits == Limits(gyro_range_dps=500.0, gnss_min_fix_type=4)
    doc = cfg.document()["core"]
    assert doc["gyro_range_dps"] == 500.0 and doc["gnss_min_fix_type"] == 4 and "limits" not in doc
    assert config_mod.from_dict(cfg.document(), "again.toml").pipeline.limits == cfg.pipeline.limits


def test_docs_are_generated_from_the_schema() -> None:
    """docs/configuration.md is what ``ins-hil config --docs`` writes (regenerate it after a schema change)."""
    assert config_schema.DOCS.read_text(encoding="utf-8") == config_schema.markdown(), (
        "docs/configuration.md is stale: run `ins-hil config --docs`"
    )
    text = config_schema.DOCS.read_text(encoding="utf-8")
    for sec in config_schema.sections():
        for k in sec.keys:
            assert f"`{k}`" in text or k == "*"


# ---------------------------------------------------------------------------------------------- fuzzing


def _starts(cfg: Config) -> None:
    """Build what ``Gateway`` builds before and at start, without opening a device or a socket."""
    from ins_hil.drivers.can_imu import CanImuDriver
    from ins_hil.drivers.mavlink_in import MavlinkDriver
    from ins_hil.drivers.serial_imu import SerialImuDriver

    from ins_hil.runtime.loop import Gateway

    gw = Gateway(cfg)  # pipeline, metrics, MAVLink endpoints, MQTT publisher
    if cfg.pipeline.init == "config":  # the core runs from the first sample: a few steps at rest stay finite
        g = 9.80665e-2
        for k in range(1, 4):
            st_ = gw.pipeline.imu(ImuSample(t=k * 0.01, dt=0.01, dtheta=np.zeros(3), dvel=np.array((0.0, 0.0, -g))))
            if st_ is not None:
                assert all(math.isfinite(x) for x in (st_.lat, st_.lon, st_.h, *st_.vel_ned, *st_.q_nb)), st_
    assert int(cfg.recorder.max_mb * 1024 * 1024) > 0 and 0 < cfg.recorder.flush_period <= 0.1
    for ic in cfg.inputs:
        if ic.type == "mavlink":
            MavlinkDriver(ic.url, name=ic.name, system_id=ic.sysid or None, signing_key=ic.signing_key or None)
        elif ic.type == "can_imu":
            CanImuDriver.from_config({"type": "can_imu", "name": ic.name, **ic.options})
        else:
            SerialImuDriver(ic.port, ic.baud, name=ic.name)
    if cfg.sim_enabled:
        s = cfg.sim
        assert all(math.isfinite(v) and v > 0 for v in (1 / s.imu_rate, 1 / s.gnss_rate, 1 / s.baro_rate, s.chunk_s))
        assert max(1, round(s.chunk_s * s.imu_rate)) <= 600_000


def _outcome(load_it: Any) -> None:
    """Loading either gives a Config that starts, or a one-line ConfigError; never another exception."""
    try:
        cfg = load_it()
    except ConfigError as e:
        msg = str(e)
        assert msg and "\n" not in msg and "Traceback" not in msg
        return
    _starts(cfg)


VALUES = st.one_of(
    st.sampled_from([0, -1, 1, 2**31, 2**70, -(2**63), 0.0, -0.0, 1e-300, -1e-300, 1e300, INF, -INF, NAN, 0.5, 900.0,
                     999, 128, 256, 65536, True, False, "", "x", "sim", "/", "\x00", "nan", "udp:1:2", [], [1], [True],
                     [1.5, 2, 3], [0, 0, 0], [[]], {}, {"a": 1}, {"ATTITUDE": 1e-300}, str(DBC), str(REPO_CONFIGS)]),
    st.integers(), st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=8), st.booleans(),
    st.lists(st.one_of(st.integers(-3, 300), st.floats(), st.booleans()), max_size=4),
)  # fmt: skip


def _paths(node: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    out = [prefix] if prefix else []
    if isinstance(node, dict):
        for k, v in node.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            out += _paths(v, (*prefix, i))
    return out


CONFIG_INIT = _set(_set(SIM, "core.init", "config"), "core.init_lat_deg", 50.0)
BASES = [tomllib.loads(p.read_text()) for p in CONFIGS] + [dbc_doc(), fdi_doc(), CONFIG_INIT, CONFIG_INIT]


@st.composite
def mutated(draw: st.DrawFn) -> dict[str, Any]:
    d = copy.deepcopy(draw(st.sampled_from(BASES)))
    for _ in range(draw(st.integers(1, 3))):
        paths = _paths(d)
        if not paths:
            break
        path = draw(st.sampled_from(paths))
        parent: Any = d
        for p in path[:-1]:
            parent = parent[p]
        last = path[-1]
        op = draw(st.sampled_from(["value", "value", "value", "delete", "add", "wrap", "str"]))
        if op == "delete":
            del parent[last]
        elif op == "add" and isinstance(parent, dict):
            name = draw(st.sampled_from(["x", "kind", "enabled", "dbc", "nodes", "rates", "filter", "type"]))
            parent[name] = copy.deepcopy(draw(VALUES))  # a copy: VALUES' lists and tables are shared
        elif op == "wrap":
            parent[last] = [parent[last]]
        elif op == "str":
            parent[last] = str(parent[last])
        else:
            parent[last] = copy.deepcopy(draw(VALUES))
    return d


#: examples per fuzz test (INS_HIL_FUZZ_EXAMPLES=N for a longer campaign)
N_FUZZ = int(os.environ.get("INS_HIL_FUZZ_EXAMPLES", "400"))
FUZZ = settings(max_examples=N_FUZZ, deadline=None, suppress_health_check=[HealthCheck.too_slow], database=None)


@pytest.mark.slow  # 9 s on a busy 2-core machine
@FUZZ
@given(mutated())
def test_mutated_documents_start_or_give_one_line(d: dict[str, Any]) -> None:
    """Mutated keys, values and types of the shipped configs: a Config that starts, or one line."""
    _outcome(lambda: from_dict(d, "fuzz"))


EDITS = st.lists(
    st.tuples(st.integers(0, 10**6), st.integers(0, 255), st.sampled_from(["flip", "insert", "delete"])),
    min_size=1,
    max_size=4,
)
HEALTH = [HealthCheck.too_slow, HealthCheck.function_scoped_fixture]


@settings(max_examples=max(1, N_FUZZ * 3 // 4), deadline=None, suppress_health_check=HEALTH, database=None)
@given(st.sampled_from(CONFIGS), EDITS)
def test_mutated_bytes_start_or_give_one_line(tmp_path: Path, path: Path, edits: list[tuple[int, int, str]]) -> None:
    """Flipped, inserted and deleted bytes (non-UTF-8 included) in a shipped config file."""
    raw = bytearray(path.read_bytes())
    for pos, byte, op in edits:
        i = pos % (len(raw) + 1)
        if op == "insert":
            raw.insert(i, byte)
        elif raw and i < len(raw):
            if op == "flip":
                raw[i] ^= byte or 1
            else:
                del raw[i]
    p = tmp_path / "fuzz.toml"
    p.write_bytes(bytes(raw))
    _outcome(lambda: load(p))


# ---------------------------------------------------------------------------------------------- CLI


def _cli(*argv: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "ins_hil", *argv], cwd=cwd, capture_output=True, text=True, timeout=120
    )


@pytest.mark.slow
def test_cli_gives_one_line_and_exit_2_for_bad_files(tmp_path: Path) -> None:
    """The real commands on bad files: exit status 2, one line on stderr, no traceback, nothing started."""
    text = (REPO_CONFIGS / "default.toml").read_text()
    bad = {
        "latin1.toml": text.encode().replace(b'name = "ins-hil"', b'name = "ins-h\xefl"'),
        "type.toml": text.replace("cov_every = 10", 'cov_every = "10"').encode(),
        "nan.toml": text.replace("h = 180.0", "h = nan").encode(),
        "rate.toml": text.replace("VFR_HUD = 4.0", "VFR_HUD = 1e-300").encode(),
        "port.toml": text.replace('port = "sim"', 'port = ""').encode(),
    }
    for name, data in bad.items():
        (tmp_path / name).write_bytes(data)
    runs = [("run", "--config", str(tmp_path / n), "--no-status", "--duration", "5") for n in bad]
    runs += [("config", "--check", str(tmp_path / "nan.toml")), ("run", "--config", str(tmp_path))]
    for argv in runs:
        r = _cli(*argv, cwd=tmp_path)
        lines = r.stderr.strip().splitlines()
        assert r.returncode == 2 and len(lines) == 1 and "Traceback" not in r.stderr, (argv, r.stderr)
    assert not (tmp_path / "recordings").exists()
    cut = tmp_path / "cut.ihlog"  # a recording cut inside its header
    cut.write_bytes(b"IHLOG1\n\x02")
    r = _cli("replay", str(cut), cwd=tmp_path)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr, r.stderr
    r = _cli("config", "--check", str(REPO_CONFIGS / "default.toml"), cwd=tmp_path)
    assert r.returncode == 0 and r.stdout.strip().endswith(": ok")


def test_an_escaped_exception_is_one_line_with_the_debug_hint(capsys: pytest.CaptureFixture[str]) -> None:
    from ins_hil.cli import build_parser, report_error

    assert report_error("ins-hil x", RuntimeError("boom\n  second line")) == 1
    assert capsys.readouterr().err == "ins-hil x: RuntimeError: boom second line (run with --debug for the traceback)\n"
    assert report_error("ins-hil x", ConfigError("f.toml: core.init_h = nan: expected a finite number")) == 2
    assert capsys.readouterr().err == "ins-hil x: f.toml: core.init_h = nan: expected a finite number\n"
    assert report_error("ins-hil x", IsADirectoryError(21, "Is a directory", "/tmp")) == 2
    assert capsys.readouterr().err == "ins-hil x: /tmp: Is a directory\n"
    assert report_error("ins-hil x", UnicodeDecodeError("utf-8", b"\xff", 0, 1, "invalid start byte")) == 2
    assert "(run with --debug for the traceback)" in capsys.readouterr().err
    p = build_parser()
    assert p.parse_args(["--debug", "demo"]).debug and p.parse_args(["demo", "--debug"]).debug
    assert not p.parse_args(["demo"]).debug


def test_main_maps_a_bad_input_file_to_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from ins_hil.cli import main

    p = tmp_path / "bad.toml"
    p.write_bytes(b'[gateway]\nname = "\xff"\n')
    assert main(["config", "--check", str(p)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"ins-hil config: {p}: not UTF-8 text (byte 0xff on line 2, offset 18)"]


def _ends(k: config_schema.Key) -> list[Any]:
    """The extreme values a numeric key accepts (just inside an open end; ±1e12 for an unbounded one)."""
    iv, out = k.interval, []
    for x, closed, up in ((iv.lo, iv.lo_closed, 1), (iv.hi, iv.hi_closed, -1)):
        x = math.copysign(1e12, x) if math.isinf(x) else x
        if not closed:
            x += up * (1e-300 if x == 0 else abs(x) * 1e-9)
        out.append(int(x) if k.type == "int" else [x] * 3 if k.type == "vec3" else x)
    return out


@pytest.mark.slow
def test_every_numeric_key_starts_at_the_ends_of_its_range() -> None:
    """Each number at its smallest and largest allowed value gives a config that starts (or a one-line error
    where keys constrain each other, e.g. gnss.vel_delay ≤ delay.max_delay)."""
    bases = dict.fromkeys(("fdi.aiding", "sim", "gateway", "recorder", "outputs[]", "outputs[].rates"), SIM)
    bases.update(dict.fromkeys([s.name for s in config_schema.sections() if s.name.startswith("core")], CONFIG_INIT))
    bases.update(
        {"fdi.options": fdi_doc(), "inputs[].options": _doc("dronecan_imu.toml"), "inputs[].options.dbc": dbc_doc()}
    )
    where = {"inputs[].options.dbc": "inputs.0.options.dbc", "inputs[].options": "inputs.0.options",
             "outputs[].rates": "outputs.0.rates", "outputs[]": "outputs.0"}  # fmt: skip
    n = 0
    for sec in config_schema.sections():
        for k in sec.keys.values() if sec.name in bases else ():
            if k.type in ("float", "int", "vec3") and not k.choices:
                for v in _ends(k):
                    _outcome(
                        lambda k=k, v=v, sec=sec: from_dict(
                            _set(bases[sec.name], f"{where.get(sec.name, sec.name)}.{k.name}", v)
                        )
                    )
                    n += 1
    assert n > 250  # 288 values over the sections above
