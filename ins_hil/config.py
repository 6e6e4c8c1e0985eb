"""Gateway configuration: load a TOML file, validate every key, build typed settings.

Errors name the file, the key (dotted path, e.g. ``outputs[1].url``) and the
bad value, and are raised before anything starts (nothing half-starts).
See ``configs/default.toml`` for every key with its meaning.
"""

from __future__ import annotations

import dataclasses
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ins_hil.drivers.mavlink_in import parse_url as mavlink_in_url
from ins_hil.runtime.mavlink_out import ALL_MESSAGES, EndpointConfig, parse_url
from ins_hil.runtime.mqtt_out import MqttConfig
from ins_hil.runtime.pipeline import CORE_KINDS, PipelineConfig, aiding_monitor, check_core, fdi_monitor
from ins_hil.sim.devices import SimConfig

REPO_CONFIGS = Path(__file__).resolve().parent.parent / "configs"
INPUT_TYPES = ("serial_imu", "mavlink", "can_imu")
MAV_TYPES = ("QUADROTOR", "FIXED_WING", "HELICOPTER", "HEXAROTOR", "OCTOROTOR", "VTOL_FIXEDROTOR", "GROUND_ROVER",
             "SURFACE_BOAT", "GENERIC", "ONBOARD_CONTROLLER")  # fmt: skip


class ConfigError(ValueError):
    """A configuration problem; the message names the key and the value."""


@dataclass
class GatewaySettings:
    name: str = "ins-hil"
    late_threshold_ms: float = 5.0
    queue_size: int = 4096
    status_period: float = 0.5
    rt_priority: int = 0  # SCHED_FIFO priority of the gateway process (1-99; 0 = time-sharing)


@dataclass
class InputConfig:
    """One ``[[inputs]]`` table: ``serial_imu`` (port, baud), ``mavlink`` (url, signing_key, sysid)
    or ``can_imu`` (``[inputs.options]``: the CAN IMU driver's keys, ins_hil.drivers.can_imu)."""

    name: str = ""
    type: str = "serial_imu"
    port: str = "sim"  # serial device, or "sim" for the simulator's pty
    baud: int = 921600
    url: str = "udpin:127.0.0.1:0"
    signing_key: str = ""
    sysid: int = 0
    options: dict[str, Any] = field(default_factory=dict)


@dataclass
class RecorderConfig:
    enabled: bool = True
    dir: str = "recordings"
    max_mb: float = 256.0
    flush_period: float = 0.05
    total_mb: float = 8192.0  # MiB: all parts of one run; its oldest parts deleted first (≈ 25 h at 1 kHz)
    dir_total_mb: float = 0.0  # MiB: every .ihlog in dir (other runs' oldest files deleted first); 0 = no limit


@dataclass
class Config:
    """A validated gateway configuration."""

    gateway: GatewaySettings = field(default_factory=GatewaySettings)
    pipeline: PipelineConfig = field(default_factory=PipelineConfig)
    sim: SimConfig = field(default_factory=SimConfig)
    sim_enabled: bool = False
    inputs: list[InputConfig] = field(default_factory=list)
    outputs: list[EndpointConfig] = field(default_factory=list)
    mqtt: MqttConfig = field(default_factory=lambda: MqttConfig(enabled=False))
    recorder: RecorderConfig = field(default_factory=RecorderConfig)
    source: str = ""

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def _fill(obj: Any, table: Any, where: str, extra: tuple[str, ...] = ()) -> set[str]:
    """Set dataclass fields from a TOML table, checking key names and value types."""
    if not isinstance(table, dict):
        raise ConfigError(f"{where}: expected a table, got {table!r}")
    fields = {f.name: f for f in dataclasses.fields(obj)}
    seen = set()
    for k, v in table.items():
        key = f"{where}.{k}"
        if k in extra:
            seen.add(k)
            continue
        if k not in fields:
            raise ConfigError(f"unknown key {key!r} (known: {', '.join(sorted(set(fields) | set(extra)))})")
        cur = getattr(obj, k)
        if isinstance(cur, bool):
            ok = isinstance(v, bool)
        elif isinstance(cur, int):
            ok = isinstance(v, int) and not isinstance(v, bool)
        elif isinstance(cur, float):
            ok = isinstance(v, int | float) and not isinstance(v, bool)
            v = float(v) if ok else v
        elif isinstance(cur, str):
            ok = isinstance(v, str)
        elif isinstance(cur, list):
            ok = isinstance(v, list)
        elif isinstance(cur, dict):
            ok = isinstance(v, dict)
        else:
            ok = True
        if not ok:
            raise ConfigError(f"{key} = {v!r}: expected a {type(cur).__name__}")
        setattr(obj, k, v)
        seen.add(k)
    return seen


def _choice(key: str, v: Any, options: tuple[str, ...]) -> None:
    if v not in options:
        raise ConfigError(f"{key} = {v!r}: must be one of {', '.join(repr(o) for o in options)}")


def _positive(key: str, v: float, allow_zero: bool = False) -> None:
    if not (v > 0 or (allow_zero and v == 0)):
        raise ConfigError(f"{key} = {v!r}: must be {'≥ 0' if allow_zero else '> 0'}")


def _key(key: str, v: str) -> None:
    if v:
        try:
            b = bytes.fromhex(v)
        except ValueError:
            raise ConfigError(f"{key} = {v!r}: must be 64 hex digits (a 32-byte MAVLink signing key)") from None
        if len(b) != 32:
            raise ConfigError(f"{key}: must be 64 hex digits (32 bytes), got {len(v)} characters")


def from_dict(d: dict[str, Any], source: str = "<dict>") -> Config:
    """Validate a parsed TOML document into a Config (raises ConfigError)."""
    cfg = Config(source=source)
    known = {"gateway", "core", "fdi", "sim", "inputs", "outputs", "mqtt", "recorder"}
    for k in d:
        if k not in known:
            raise ConfigError(f"unknown section {k!r} (known: {', '.join(sorted(known))})")
    _fill(cfg.gateway, d.get("gateway", {}), "gateway")
    g = cfg.gateway
    _positive("gateway.late_threshold_ms", g.late_threshold_ms)
    _positive("gateway.queue_size", g.queue_size)
    _positive("gateway.status_period", g.status_period)
    if isinstance(g.rt_priority, bool) or not isinstance(g.rt_priority, int) or not 0 <= g.rt_priority <= 99:
        raise ConfigError(f"gateway.rt_priority = {g.rt_priority!r}: must be an integer 0 (off) to 99 (SCHED_FIFO)")

    core = dict(d.get("core", {}))
    if "kind" in core:
        core["core"] = core.pop("kind")
    _fill(cfg.pipeline, core, "core", extra=())
    p = cfg.pipeline
    _choice("core.kind", p.core, CORE_KINDS)
    _choice("core.init", p.init, ("gnss", "config"))
    _positive("core.level_samples", p.level_samples)
    if p.calibration and not Path(p.calibration).is_file():
        raise ConfigError(f"core.calibration = {p.calibration!r}: file not found")
    if p.calibration:
        from ins_hil.nav.calibration import load_calibration

        try:
            load_calibration(p.calibration)
        except Exception as e:
            raise ConfigError(f"core.calibration = {p.calibration!r}: {e}") from None
    try:
        check_core(p.core, p.nav)
    except (ValueError, RuntimeError) as e:
        raise ConfigError(str(e)) from None
    fdi = d.get("fdi", {})
    if not isinstance(fdi, dict):
        raise ConfigError(f"fdi: expected a table, got {fdi!r}")
    for k, v in fdi.items():
        if k == "enabled":
            if not isinstance(v, bool):
                raise ConfigError(f"fdi.enabled = {v!r}: expected true or false")
            p.fdi = v
        elif k == "imu_ids":
            if not (isinstance(v, list) and v and all(isinstance(i, int) and 0 <= i < 256 for i in v)):
                raise ConfigError(f"fdi.imu_ids = {v!r}: expected a non-empty list of IMU ids 0..255")
            p.imu_ids = list(v)
        elif k == "options":
            if not isinstance(v, dict):
                raise ConfigError(f"fdi.options = {v!r}: expected a table")
            p.fdi_options = dict(v)
        elif k == "aiding":
            if not isinstance(v, dict):
                raise ConfigError(f"fdi.aiding = {v!r}: expected a table")
            opts = dict(v)
            en = opts.pop("enabled", True)
            if not isinstance(en, bool):
                raise ConfigError(f"fdi.aiding.enabled = {en!r}: expected true or false")
            try:
                aiding_monitor(opts)
            except ValueError as e:
                raise ConfigError(str(e)) from None
            p.aiding_fdi, p.aiding_options = en, opts
        else:
            raise ConfigError(f"unknown key 'fdi.{k}' (known: enabled, imu_ids, options, aiding)")

    if p.fdi:
        try:
            mon = fdi_monitor(p.fdi_options)
        except ValueError as e:
            raise ConfigError(str(e)) from None
        if len(p.imu_ids) != mon.geo.units:
            raise ConfigError(f"fdi.imu_ids = {p.imu_ids}: the geometry {mon.geo.name!r} has {mon.geo.units} IMUs")

    sim = dict(d.get("sim", {}))
    en = sim.pop("enabled", False)
    if not isinstance(en, bool):
        raise ConfigError(f"sim.enabled = {en!r}: expected true or false")
    cfg.sim_enabled = en
    _fill(cfg.sim, sim, "sim")
    s = cfg.sim
    _choice("sim.profile", s.profile, ("uav", "static"))
    _choice("sim.imu_errors", s.imu_errors, ("mems", "none"))
    for k in ("imu_rate", "gnss_rate", "baro_rate", "chunk_s"):
        _positive(f"sim.{k}", getattr(s, k))
    _positive("sim.duration", s.duration, allow_zero=True)
    _key("sim.sign_key", s.sign_key)

    inputs = d.get("inputs", [])
    if not isinstance(inputs, list):
        raise ConfigError("inputs: expected an array of tables ([[inputs]])")
    for i, t in enumerate(inputs):
        ic = InputConfig(name=f"input{i}")
        _fill(ic, t, f"inputs[{i}]")
        where = f"inputs[{i}]"
        _choice(f"{where}.type", ic.type, INPUT_TYPES)
        if ic.type == "mavlink":
            try:
                mavlink_in_url(ic.url)
            except ValueError as e:
                raise ConfigError(f"{where}.url = {ic.url!r}: {e}") from None
            _key(f"{where}.signing_key", ic.signing_key)
        elif ic.type == "can_imu":
            from ins_hil.drivers.can_imu import CanImuDriver

            try:
                CanImuDriver.from_config({"type": "can_imu", "name": ic.name, **ic.options})
            except (ValueError, TypeError) as e:
                raise ConfigError(f"{where}.options: {e}") from None
        else:
            if ic.port == "sim" and not cfg.sim_enabled:
                raise ConfigError(f"{where}.port = 'sim' needs [sim] enabled = true")
            _positive(f"{where}.baud", ic.baud)
        cfg.inputs.append(ic)
    names = [i.name for i in cfg.inputs]
    if len(set(names)) != len(names):
        raise ConfigError(f"inputs: duplicate names {names}")
    if not any(i.type in ("serial_imu", "can_imu") for i in cfg.inputs):
        raise ConfigError("inputs: no IMU input (add an [[inputs]] table with type = 'serial_imu' or 'can_imu')")

    outputs = d.get("outputs", [])
    if not isinstance(outputs, list):
        raise ConfigError("outputs: expected an array of tables ([[outputs]])")
    for i, t in enumerate(outputs):
        where = f"outputs[{i}]"
        t = dict(t) if isinstance(t, dict) else _bad(where, t, "a table")
        typ = t.pop("type", "mavlink")
        if typ != "mavlink":
            raise ConfigError(f"{where}.type = {typ!r}: must be 'mavlink' (MQTT is the [mqtt] table)")
        ec = EndpointConfig(name=f"mav{i}")
        _fill(ec, t, where)
        _url(f"{where}.url", ec.url, ("udp", "udpin", "tcp", "serial"))
        _choice(f"{where}.role", ec.role, ("gcs", "fc"))
        _choice(f"{where}.mav_type", ec.mav_type, MAV_TYPES)
        _key(f"{where}.signing_key", ec.signing_key)
        if not 1 <= ec.sysid <= 255:
            raise ConfigError(f"{where}.sysid = {ec.sysid}: must be 1..255")
        if not 0 <= ec.compid <= 255:
            raise ConfigError(f"{where}.compid = {ec.compid}: must be 0..255")
        for m, r in ec.rates.items():
            if m not in ALL_MESSAGES:
                raise ConfigError(f"{where}.rates.{m}: unknown message (known: {', '.join(ALL_MESSAGES)})")
            if not isinstance(r, int | float) or isinstance(r, bool) or r < 0:
                raise ConfigError(f"{where}.rates.{m} = {r!r}: must be a rate in Hz ≥ 0 (0 = off)")
            ec.rates[m] = float(r)
        cfg.outputs.append(ec)

    if "mqtt" in d:
        cfg.mqtt = MqttConfig()
        _fill(cfg.mqtt, d["mqtt"], "mqtt")
        if not 0 < cfg.mqtt.port < 65536:
            raise ConfigError(f"mqtt.port = {cfg.mqtt.port}: must be 1..65535")
        _positive("mqtt.state_rate", cfg.mqtt.state_rate, allow_zero=True)
        _positive("mqtt.health_period", cfg.mqtt.health_period)
        for k in ("tls_ca", "tls_cert", "tls_key"):
            v = getattr(cfg.mqtt, k)
            if v and not Path(v).is_file():
                raise ConfigError(f"mqtt.{k} = {v!r}: file not found")
    _fill(cfg.recorder, d.get("recorder", {}), "recorder")
    _positive("recorder.max_mb", cfg.recorder.max_mb)
    _positive("recorder.flush_period", cfg.recorder.flush_period)
    _positive("recorder.total_mb", cfg.recorder.total_mb)
    _positive("recorder.dir_total_mb", cfg.recorder.dir_total_mb, allow_zero=True)
    if cfg.recorder.flush_period > 0.1:
        raise ConfigError(f"recorder.flush_period = {cfg.recorder.flush_period}: must be ≤ 0.1 s")
    return cfg


def _bad(key: str, v: Any, what: str) -> Any:
    raise ConfigError(f"{key} = {v!r}: expected {what}")


def _url(key: str, v: str, schemes: tuple[str, ...]) -> None:
    try:
        scheme, _, _ = parse_url(v)
    except ValueError as e:
        raise ConfigError(f"{key} = {v!r}: {e}") from None
    if scheme not in schemes:
        raise ConfigError(f"{key} = {v!r}: scheme must be one of {', '.join(schemes)}")


def load(path: str | Path) -> Config:
    """Read and validate a TOML config file."""
    p = Path(path)
    try:
        text = p.read_text()
    except OSError as e:
        raise ConfigError(f"cannot read config {p}: {e.strerror}") from None
    try:
        d = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{p}: not valid TOML: {e}") from None
    try:
        return from_dict(d, str(p))
    except ConfigError as e:
        raise ConfigError(f"{p}: {e}") from None


def default_path() -> Path:
    """configs/default.toml of the checkout (or the installed package's copy)."""
    return REPO_CONFIGS / "default.toml"
