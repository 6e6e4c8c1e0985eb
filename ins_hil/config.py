"""Gateway configuration: load a TOML file, validate every key, build typed settings.

Every key is checked against the schema (:mod:`ins_hil.config_schema`: type, unit, range; NaN and
infinities rejected), then what start-up builds is built once (the pipeline, the MAVLink endpoints,
the MQTT publisher, the input drivers, without opening a device), so a file that loads starts.
Errors are one line naming the file, the key (dotted path, e.g. ``outputs[1].url``), the bad value
and what is allowed, and are raised before anything starts (nothing half-starts).
``docs/configuration.md`` lists every key; ``configs/default.toml`` is a commented example.
"""

from __future__ import annotations

import copy
import dataclasses
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ins_hil import config_schema as schema
from ins_hil.config_schema import ConfigError
from ins_hil.drivers.factory import driver_class, make_driver
from ins_hil.drivers.mavlink_in import GNSS_MESSAGES as MAVLINK_GNSS_MESSAGES
from ins_hil.drivers.mavlink_link import SCHEMES as MAVLINK_SCHEMES
from ins_hil.drivers.mavlink_link import parse_url
from ins_hil.drivers.mavlink_link import parse_url as mavlink_in_url
from ins_hil.gateway_settings import GatewaySettings as GatewaySettings
from ins_hil.gateway_settings import InputConfig as InputConfig
from ins_hil.gateway_settings import RecorderConfig as RecorderConfig
from ins_hil.gateway_settings import gps_input_echo
from ins_hil.runtime.mavlink_msgs.common import MAV_TYPES as MAV_TYPES
from ins_hil.runtime.mavlink_msgs.common import read_key_file
from ins_hil.runtime.mavlink_out import EndpointConfig
from ins_hil.runtime.mqtt_out import MqttConfig
from ins_hil.runtime.pipeline import PipelineConfig, check_core, nav_config
from ins_hil.types import SimConfig
from ins_hil.validation import Limits

REPO_CONFIGS = Path(__file__).resolve().parent.parent / "configs"
INPUT_TYPES = ("serial_imu", "mavlink", "can_imu")


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
        """Plain values (a recording's header): the ``[core.nav]`` settings as their TOML table (the keys that
        differ from the defaults, :func:`ins_hil.settings.table`)."""
        d = dataclasses.asdict(self)
        d["pipeline"] = self.pipeline.to_dict()
        return d

    def mavlink_ids(self) -> list[tuple[int, int]]:
        """Every MAVLink identity (system, component) the gateway's outputs send as: its inputs refuse them."""
        return [(o.sysid, o.compid) for o in self.outputs]

    def document(self) -> dict[str, Any]:
        """This configuration as a TOML document (:func:`config_document`)."""
        return config_document(self)

    def revalidate(self, doc: dict[str, Any]) -> Config:
        """The configuration of the TOML document ``doc`` (e.g. :meth:`document` with one value changed),
        validated as a file is (:func:`from_dict`; ConfigError naming the key), under this one's source."""
        return from_dict(copy.deepcopy(doc), self.source or "<params>")


def config_document(cfg: Config) -> dict[str, Any]:
    """The TOML document (sections as in ``configs/*.toml``) of a validated ``Config``, with only the
    keys that differ from their defaults (plus names and types): :func:`from_dict` of it gives the
    same configuration (checked by ``ins_hil.runtime.mavlink_params.ParamStore``)."""
    d = cfg.to_dict()
    ref = Config().to_dict()

    def diff(table: dict[str, Any], default: dict[str, Any], keep: tuple[str, ...] = ()) -> dict[str, Any]:
        return {k: v for k, v in table.items() if k in keep or k not in default or v != default[k]}

    p = dict(d["pipeline"])
    p.update(p.pop("limits"))  # the validation limits are flat keys of [core]
    fdi: dict[str, Any] = {"enabled": p.pop("fdi"), "imu_ids": p.pop("imu_ids"), "options": p.pop("fdi_options")}
    fdi = diff(fdi, {"enabled": False, "imu_ids": [0], "options": {}})
    aiding = {"enabled": p.pop("aiding_fdi"), **p.pop("aiding_options")}
    if aiding != {"enabled": True}:
        fdi["aiding"] = aiding
    p["kind"] = p.pop("core")
    pref = dict(ref["pipeline"], kind=ref["pipeline"]["core"], **ref["pipeline"]["limits"])
    core = diff(p, pref, keep=("nav",))
    inputs = [diff(i, dataclasses.asdict(InputConfig(name=i["name"])), keep=("name", "type")) for i in d["inputs"]]
    outputs = [
        {"type": "mavlink", **diff(o, dataclasses.asdict(EndpointConfig(name=o["name"])), keep=("name",))}
        for o in d["outputs"]
    ]
    return {
        "gateway": diff(d["gateway"], ref["gateway"]),
        "core": core,
        **({"fdi": fdi} if fdi else {}),
        "sim": {"enabled": d["sim_enabled"], **diff(d["sim"], ref["sim"])},
        "inputs": inputs,
        "outputs": outputs,
        "mqtt": diff(d["mqtt"], dataclasses.asdict(MqttConfig()), keep=("enabled",)),
        "recorder": diff(d["recorder"], ref["recorder"]),
    }


def _fill(obj: Any, table: Any, where: str, section: str | None = None) -> dict[str, Any]:
    """Set dataclass fields from a TOML table checked against the schema (type, range, unit).

    Returns every key present with its converted value (also those the loader handles itself)."""
    vals = schema.validate(section or where, table, where)
    keys = schema.section(section or where).keys
    for k, v in vals.items():
        attr = keys[k].attr if k in keys else None
        if attr is not None:
            setattr(obj, attr, v)
    return vals


def _choice(key: str, v: Any, options: tuple[str, ...]) -> None:
    if v not in options:
        raise ConfigError(f"{key} = {v!r}: must be one of {', '.join(repr(o) for o in options)}")


def _key(key: str, v: str) -> None:
    if v:
        try:
            b = bytes.fromhex(v)
        except ValueError:
            raise ConfigError(f"{key} = {v!r}: must be 64 hex digits (a 32-byte MAVLink signing key)") from None
        if len(b) != 32:
            raise ConfigError(f"{key}: must be 64 hex digits (32 bytes), got {len(v)} characters")


def _fdi(cfg: Config, fdi: Any) -> None:
    p = cfg.pipeline
    vals = schema.validate("fdi", fdi)
    p.fdi = vals.get("enabled", p.fdi)
    p.imu_ids = vals.get("imu_ids", p.imu_ids)
    if "options" in vals:
        p.fdi_options = vals["options"]
    if "aiding" in vals:
        opts = schema.validate("fdi.aiding", vals["aiding"])  # its `enabled` (the loader's key) as well
        p.aiding_fdi, p.aiding_options = opts.pop("enabled", True), opts
        p.aiding_config()  # built once, here (ConfigError naming the key); the pipeline's monitor uses it
    if p.fdi or "options" in vals:  # checked even while FDI is off: a bad key is an error now, not when enabled
        geo = p.fdi_config().geometry  # built once, here; the pipeline's monitor uses it
        if p.fdi and len(p.imu_ids) != geo.units:
            raise ConfigError(f"fdi.imu_ids = {p.imu_ids}: the geometry {geo.name!r} has {geo.units} IMUs")


def _registered(kind: Any) -> bool:
    """Whether ``kind`` names a driver registered beyond the built-in types (``drivers/factory.py`` ``register``
    or the ``ins_hil.drivers`` entry points)."""
    try:
        driver_class(kind)
    except (ValueError, ImportError, AttributeError):
        return False
    return True


def _plugin_input(t: dict[str, Any], i: int, where: str) -> InputConfig:
    """An ``[[inputs]]`` table of a registered third-party driver: ``name``, ``type`` and its
    ``[inputs.options]`` (the driver's own keys, checked by building it once)."""
    extra = sorted(set(t) - {"name", "type", "options"})
    if extra:
        raise ConfigError(f"{where}.{extra[0]}: a {t['type']!r} input takes its keys in [inputs.options]")
    opts = t.get("options", {})
    if not isinstance(opts, dict):
        raise ConfigError(f"{where}.options: expected a table")
    ic = InputConfig(name=str(t.get("name", f"input{i}")), type=str(t["type"]), options=dict(opts))
    try:
        make_driver(ic.driver_table())
    except Exception as e:  # the third-party driver's own check of its options
        raise ConfigError(f"{where}.options: {type(e).__name__}: {e}") from None
    return ic


def _can_options(ic: InputConfig, where: str) -> None:
    """A can_imu input's ``[inputs.options]``: checked, then the driver is built (the DBC file loaded)."""
    opts = schema.validate("inputs[].options", ic.options, f"{where}.options")
    for k in ("name", "type"):
        if k in opts:
            raise ConfigError(f"{where}.options.{k}: set it in the [[inputs]] table, not in its options")
    if opts.get("protocol", "dronecan") == "dronecan" and "dbc" in opts:
        raise ConfigError(f"{where}.options.dbc: only with protocol = 'dbc'")
    dbc = None
    if "dbc" in opts:
        dbc = schema.validate("inputs[].options.dbc", opts["dbc"], f"{where}.options.dbc")
        for k in ("status_message", "counter_signal", "crc_signal"):  # "" = none
            if dbc.get(k) == "":
                dbc[k] = None
        opts["dbc"] = dbc
    ic.options = opts
    try:
        drv: Any = make_driver(ic.driver_table())  # a CanImuDriver: .dbc
    except ValueError as e:
        msg = str(e)
        head, _, rest = msg.partition(": ")
        if head == "DBC profile" and " = " in rest and rest.partition(" = ")[0].isidentifier():
            raise ConfigError(f"{where}.options.dbc.{rest}") from None  # the key named as in the file
        if msg.startswith(("CAN IMU", "DBC profile")):
            raise ConfigError(f"{where}.options: {e}") from None
        path = (dbc or {}).get("dbc", "")
        raise ConfigError(f"{where}.options.dbc.dbc = {path!r}: not a DBC file ({e})") from None
    except Exception as e:  # the DBC parser's own errors (a file that is not a DBC)
        path = (dbc or {}).get("dbc", "")
        raise ConfigError(f"{where}.options.dbc.dbc = {path!r}: not a DBC file ({type(e).__name__}: {e})") from None
    dec = drv.dbc
    if dec is not None:
        prof = dec.profile
        for k in ("counter_signal", "crc_signal"):
            sig = getattr(prof, k)
            for m in (dec.gyro, dec.accel):
                names = sorted(s.name for s in m.signals)
                if sig is not None and sig not in names:
                    raise ConfigError(f"{where}.options.dbc.{k} = {sig!r}: not a signal of {m.name} "
                                      f"(signals: {', '.join(names)}; '' = none)")  # fmt: skip


def _startable(cfg: Config) -> None:
    """Build what start-up builds (no device opened): a config that loads must start."""
    from ins_hil.runtime.metrics import RuntimeMetrics
    from ins_hil.runtime.mqtt_out import MqttPublisher
    from ins_hil.runtime.pipeline import Pipeline

    try:
        Pipeline(cfg.pipeline)
    except (ValueError, RuntimeError) as e:
        msg = str(e)
        raise ConfigError(msg if msg.startswith(("core", "fdi")) else f"core: {msg}") from None
    metrics = RuntimeMetrics(cfg.gateway.late_threshold_ms * 1e-3)
    _startable_outputs(cfg.outputs)
    if cfg.mqtt.enabled:
        MqttPublisher(cfg.mqtt, metrics)
    for i, ic in enumerate(cfg.inputs):
        try:
            if ic.type != "can_imu":  # built (its DBC file loaded) by _can_options
                make_driver(ic.driver_table())  # as the gateway builds it (no device opened)
        except ValueError as e:
            raise ConfigError(f"inputs[{i}]: {e}") from None


def _startable_outputs(outputs: list[EndpointConfig]) -> None:
    """Build each MAVLink endpoint as start-up does (nothing opened)."""
    from ins_hil.runtime.mavlink_out import MavlinkEndpoint
    from ins_hil.runtime.metrics import RuntimeMetrics

    metrics = RuntimeMetrics()
    for i, ec in enumerate(outputs):
        try:
            MavlinkEndpoint(ec, metrics)
        except (ValueError, RuntimeError) as e:
            raise ConfigError(f"outputs[{i}]: {e}") from None


def from_dict(d: dict[str, Any], source: str = "<dict>") -> Config:
    """Validate a parsed TOML document into a Config (raises ConfigError)."""
    cfg = Config(source=source)
    if not isinstance(d, dict):
        raise ConfigError(f"expected a TOML document (a table), got {type(d).__name__}")
    known = {"gateway", "core", "fdi", "sim", "inputs", "outputs", "mqtt", "recorder"}
    for k in d:
        if k not in known:
            raise ConfigError(f"unknown section {k!r} (known: {', '.join(sorted(known))})")
    _fill(cfg.gateway, d.get("gateway", {}), "gateway")

    core = _fill(cfg.pipeline, d.get("core", {}), "core")
    p = cfg.pipeline
    p.limits = Limits(**{f.name: core[f.name] for f in dataclasses.fields(Limits) if f.name in core})
    p.nav = nav_config(core.get("nav", {}))  # built once, each key checked (an old flat key: where it moved)
    if p.calibration:
        from ins_hil.calibration.files import load_calibration

        try:
            load_calibration(p.calibration)
        except Exception as e:
            raise ConfigError(f"core.calibration = {p.calibration!r}: {e}") from None
    try:
        check_core(p.core, p.nav)
    except (ValueError, RuntimeError) as e:
        raise ConfigError(str(e)) from None
    _fdi(cfg, d.get("fdi", {}))

    sim = _fill(cfg.sim, d.get("sim", {}), "sim")
    cfg.sim_enabled = sim.get("enabled", False)
    _key("sim.sign_key", cfg.sim.sign_key)

    inputs = d.get("inputs", [])
    if not isinstance(inputs, list):
        raise ConfigError("inputs: expected an array of tables ([[inputs]])")
    plugins = 0
    for i, t in enumerate(inputs):
        where = f"inputs[{i}]"
        if isinstance(t, dict) and t.get("type") not in INPUT_TYPES and _registered(t.get("type")):
            cfg.inputs.append(_plugin_input(t, i, where))
            plugins += 1
            continue
        ic = InputConfig(name=f"input{i}")
        _fill(ic, t, f"inputs[{i}]")
        if ic.options and ic.type != "can_imu":
            raise ConfigError(f"{where}.options: only for type = 'can_imu' (this input is {ic.type!r})")
        _choice(f"{where}.type", ic.type, INPUT_TYPES)
        if ic.type == "mavlink":
            try:
                mavlink_in_url(ic.url)
            except ValueError as e:
                raise _url_error(f"{where}.url", ic.url, e) from None
            _key(f"{where}.signing_key", ic.signing_key)
            bad = [m for m in ic.gnss_messages if m not in MAVLINK_GNSS_MESSAGES]
            if bad or len(set(ic.gnss_messages)) != len(ic.gnss_messages):
                raise ConfigError(f"{where}.gnss_messages = {schema.show(ic.gnss_messages)}: expected distinct names "
                                  f"of {', '.join(MAVLINK_GNSS_MESSAGES)}")  # fmt: skip
        elif ic.type == "can_imu":
            _can_options(ic, where)
        else:
            if ic.port == "sim" and not cfg.sim_enabled:
                raise ConfigError(f"{where}.port = 'sim' needs [sim] enabled = true")
        cfg.inputs.append(ic)
    names = [i.name for i in cfg.inputs]
    if len(set(names)) != len(names):
        raise ConfigError(f"inputs: duplicate names {names}")
    if not plugins and not any(i.type in ("serial_imu", "can_imu") for i in cfg.inputs):
        raise ConfigError("inputs: no IMU input (add an [[inputs]] table with type = 'serial_imu' or 'can_imu')")

    cfg.outputs = _outputs(d)

    if "mqtt" in d:
        cfg.mqtt = MqttConfig()
        _fill(cfg.mqtt, d["mqtt"], "mqtt")
        if any(c in cfg.mqtt.topic_prefix for c in "+#"):
            raise ConfigError(f"mqtt.topic_prefix = {cfg.mqtt.topic_prefix!r}: must not hold the wildcards + or #")
        _mqtt_auth(cfg.mqtt)
    _fill(cfg.recorder, d.get("recorder", {}), "recorder")
    _gnss_sources(cfg)
    _startable(cfg)
    return cfg


def _outputs(d: dict[str, Any]) -> list[EndpointConfig]:
    """The ``[[outputs]]`` tables of a parsed TOML document, validated (ConfigError naming the key)."""
    outputs = d.get("outputs", [])
    if not isinstance(outputs, list):
        raise ConfigError("outputs: expected an array of tables ([[outputs]])")
    out: list[EndpointConfig] = []
    for i, t in enumerate(outputs):
        where = f"outputs[{i}]"
        t = dict(t) if isinstance(t, dict) else _bad(where, t, "a table")
        typ = t.pop("type", "mavlink")
        if typ != "mavlink":
            raise ConfigError(f"{where}.type = {schema.show(typ)}: must be 'mavlink' (MQTT is the [mqtt] table)")
        ec = EndpointConfig(name=f"mav{i}")
        _fill(ec, t, where)
        _url(f"{where}.url", ec.url, MAVLINK_SCHEMES)
        _choice(f"{where}.role", ec.role, ("gcs", "fc"))
        _choice(f"{where}.mav_type", ec.mav_type, MAV_TYPES)
        _key(f"{where}.signing_key", ec.signing_key)
        _gcs_output(ec, where)
        ec.rates = schema.validate("outputs[].rates", t.get("rates", {}), f"{where}.rates")
        out.append(ec)

    return out


def _gcs_output(ec: EndpointConfig, where: str) -> None:
    """The ground-station access keys of a MAVLink output: allowed_gcs_sysids (0 = any, alone), the signing key file."""
    ids = ec.allowed_gcs_sysids
    if 0 in ids and len(ids) > 1:
        raise ConfigError(f"{where}.allowed_gcs_sysids = {ids}: 0 means any system; give [0] alone or only ids 1-255")
    if ec.signing_key_file:
        if ec.signing_key:
            raise ConfigError(f"{where}.signing_key_file: signing_key also given: keep one of both")
        try:
            read_key_file(ec.signing_key_file)
        except ValueError as e:
            raise ConfigError(f"{where}.signing_key_file: {e}") from None


def _mqtt_auth(mq: MqttConfig) -> None:
    """The broker credentials and TLS keys go together (MQTT sends a password only with a user name)."""
    if mq.password and not mq.username:
        raise ConfigError("mqtt.password: needs mqtt.username (MQTT sends a password only with a user name)")
    for k in ("tls_ca", "tls_cert", "tls_key", "tls_insecure"):
        if getattr(mq, k) and not mq.tls:
            raise ConfigError(f"mqtt.{k}: needs mqtt.tls = true (without it the connection is plain TCP)")
    if mq.tls_key and not mq.tls_cert:
        raise ConfigError("mqtt.tls_key: needs mqtt.tls_cert (the client certificate of that key)")


def _gnss_sources(cfg: Config) -> None:
    """MAVLink GNSS that would feed the gateway its own output back, refused in one line: an input whose
    ``gnss_messages`` names GPS_RAW_INT from the system an ``fc`` output sends GPS_INPUT to (left empty, the
    input leaves GPS_RAW_INT out itself); and an input that would refuse the simulator's GNSS."""
    mav = [(i, ic) for i, ic in enumerate(cfg.inputs) if ic.type == "mavlink"]
    for i, ic in mav:
        echo = gps_input_echo(ic, cfg) if "GPS_RAW_INT" in ic.gnss_messages else None
        if echo is not None:
            raise ConfigError(
                f"inputs[{i}].gnss_messages takes GPS_RAW_INT from system {ic.sysid or 'any'} while {echo} "
                f"(GPS1_TYPE = 14 echoes our fix back as GPS_RAW_INT): leave GPS_RAW_INT out or set that output's "
                "rates.GPS_INPUT = 0"
            )
    if cfg.sim_enabled and mav:
        i, ic = mav[0]  # the simulator sends its GNSS to the first MAVLink input
        sid, cid = cfg.sim.gnss_sysid, 220  # MAV_COMP_ID_GPS (ins_hil.sim.devices)
        if ic.sysid not in (0, sid) or ic.compid not in (0, cid) or (sid, cid) in cfg.mavlink_ids():
            raise ConfigError(
                f"inputs[{i}] (sysid {ic.sysid}, compid {ic.compid}) would refuse the simulated GNSS "
                f"(system {sid}, component {cid}): set inputs[{i}].sysid = {sid} or sim.gnss_sysid = {ic.sysid}"
            )


def _bad(key: str, v: Any, what: str) -> Any:
    raise ConfigError(f"{key} = {schema.show(v)}: expected {what}")


def _url_error(key: str, v: Any, e: ValueError) -> ConfigError:
    """A MAVLink url the link layer refused, in one line with the value once (its "MAVLink url '...': " dropped)."""
    why = str(e)
    pre = f"MAVLink url {v!r}: "
    return ConfigError(f"{key} = {schema.show(v)}: {why[len(pre) :] if why.startswith(pre) else why}")


def _url(key: str, v: str, schemes: tuple[str, ...]) -> None:
    try:
        scheme, _, _ = parse_url(v)
    except ValueError as e:
        raise _url_error(key, v, e) from None
    if scheme not in schemes:
        raise ConfigError(f"{key} = {v!r}: scheme must be one of {', '.join(schemes)}")


def _read(p: Path) -> dict[str, Any]:
    """The TOML document of a config file (ConfigError: unreadable, not UTF-8, not TOML)."""
    try:
        raw = p.read_bytes()
    except OSError as e:
        raise ConfigError(f"cannot read config {p}: {e.strerror}") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        line = raw[: e.start].count(b"\n") + 1
        raise ConfigError(f"{p}: not UTF-8 text (byte 0x{raw[e.start]:02x} on line {line}, offset {e.start})") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{p}: not valid TOML: {e}") from None
    except RecursionError:
        raise ConfigError(f"{p}: not valid TOML: nested too deeply") from None


def load(path: str | Path) -> Config:
    """Read and validate a TOML config file."""
    p = Path(path)
    d = _read(p)
    try:
        return from_dict(d, str(p))
    except ConfigError as e:
        raise ConfigError(f"{p}: {e}") from None


def load_outputs(path: str | Path) -> list[EndpointConfig]:
    """The ``[[outputs]]`` of a config file, validated as :func:`load` validates them, without the rest
    (nothing of the core is built or imported): ``ins-hil run`` opens them and sends its first HEARTBEAT
    before the whole file is validated. A ``<config>.params.toml`` (rates) is applied later, by the gateway."""
    p = Path(path)
    d = _read(p)
    try:
        outputs = _outputs(d)
        _startable_outputs(outputs)
        return outputs
    except ConfigError as e:
        raise ConfigError(f"{p}: {e}") from None


def default_path() -> Path:
    """configs/default.toml of the checkout (or the installed package's copy)."""
    return REPO_CONFIGS / "default.toml"
