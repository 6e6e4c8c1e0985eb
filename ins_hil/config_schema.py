"""The configuration schema: every key of a gateway TOML file with its type, unit, default, range and help.

The keys of a section are the fields of the dataclass it fills (``[core]`` → ``PipelineConfig``,
``[core.nav]`` → ``NavConfig``, ``[core.nav.gnss]`` → ``GnssConfig``, ``[sim]`` → ``SimConfig``, ...): a field
added to one of them is a key at once, typed from its default and described by its metadata, the one place a
key's unit, range, default and help are written (``setting(40.0, "rad/s", "(0, 100]", "...")``,
:mod:`ins_hil.settings`). The dataclasses check the same ranges when built in code (``check_fields``).
The few keys the loader handles itself (``[sim] enabled``, ``[fdi]``, a can_imu input's options, ...) are
:class:`Key` objects below.

``python -m ins_hil.config_schema`` (or ``ins-hil config --docs``) writes ``docs/configuration.md``.
"""

from __future__ import annotations

import dataclasses
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ins_hil.settings import KNOWN_LIST_MAX as KNOWN_LIST_MAX
from ins_hil.settings import TYPES as TYPES
from ins_hil.settings import ConfigError as ConfigError  # the runtime raises it too
from ins_hil.settings import Key, dataclass_keys, known_hint, show

DOCS = Path(__file__).resolve().parent.parent / "docs" / "configuration.md"
#: the keys the loader handles itself (not dataclass fields): [sim] enabled, [fdi.aiding] enabled, ...
SIM_ENABLED = Key("enabled", "bool", False, help="run the simulated sensors (their own process)")
AIDING_ENABLED = Key("enabled", "bool", True, help="the GNSS/baro drift and slow-pull monitor (ins_hil.fdi.aiding)")
FDI_GEOMETRY = Key("geometry", "str", "triple_imu", choices=("cone5", "dual_imu", "skew6", "triple_imu"),
                   help="the redundant set (ins_hil.fdi.geometry)")  # fmt: skip
OUTPUT_TYPE = Key("type", "str", "mavlink", choices=("mavlink",), help="mavlink (MQTT is the [mqtt] table)")

#: the [[inputs]] options of a can_imu input (the CAN IMU driver's own keys; others go to python-can's Bus)
CAN_OPTIONS = {
    "interface": Key(
        "interface",
        "str",
        None,
        required=True,
        nonempty=True,
        help="python-can interface: socketcan, slcan, gs_usb, virtual, ...",
    ),
    "channel": Key("channel", "str|int", None, optional=True, help="the bus: can0, vcan0, a serial port (slcan), ..."),
    "protocol": Key(
        "protocol",
        "str",
        "dronecan",
        choices=("dronecan", "dbc"),
        help="dronecan: RawIMU/Fix2/mag/pressure from DroneCAN nodes; dbc: a DBC-described IMU",
    ),
    "nodes": Key(
        "nodes",
        "list[int]",
        None,
        optional=True,
        range="[1, 127]",
        unique=True,
        help="DroneCAN: accept these source node ids only; not set = any",
    ),
    "node_id": Key(
        "node_id",
        "int",
        100,
        range="[0, 127]",
        help="DroneCAN: our node id (NodeStatus at 1 Hz); 0 = listen only (anonymous, nothing is sent)",
    ),
    "stale_s": Key("stale_s", "float", 2.0, unit="s", range="[0.01, 3600]", help="re-open the bus after this silence"),
    "rcvbuf": Key(
        "rcvbuf",
        "int",
        4 << 20,
        unit="bytes",
        range="[0, 2147483647]",
        help="socketcan receive buffer asked for; 0 = the system default",
    ),
    "bitrate": Key(
        "bitrate", "int", None, optional=True, unit="bit/s", range="[1000, 10000000]", help="bus bit rate (python-can)"
    ),
    "dbc": Key("dbc", "table", None, optional=True, help="dbc: the [inputs.options.dbc] table"),
    "*": Key(
        "*", "any", None, optional=True, help="any other key is passed to python-can's can.Bus (e.g. fd, can_filters)"
    ),
}

FDI_KEYS = {
    "enabled": Key(
        "enabled", "bool", False, help="inertial-sensor fault detection and isolation (needs redundant IMUs)"
    ),
    "imu_ids": Key(
        "imu_ids",
        "list[int]",
        [0],
        range="[0, 255]",
        nonempty=True,
        unique=True,
        help="the IMU ids of the redundant set, in geometry order",
    ),
    "options": Key("options", "table", None, optional=True, help="the [fdi.options] table"),
    "aiding": Key("aiding", "table", None, optional=True, help="the [fdi.aiding] table"),
}


def rate_keys() -> dict[str, Key]:
    """``[outputs.rates]``: one key per MAVLink message the output can send (Hz; 0 = off)."""
    from ins_hil.runtime.mavlink_out import ALL_MESSAGES, FC_RATES, GCS_RATES

    return {
        m: Key(m, "float", None, unit="Hz", range="0 | [0.01, 1000]", optional=True,
               doc_default=f"gcs {GCS_RATES.get(m, 0.0):g} / fc {FC_RATES.get(m, 0.0):g}",
               help="messages per second; 0 = off")
        for m in ALL_MESSAGES
    }  # fmt: skip


@dataclass(frozen=True)
class Section:
    """One table of the file: its dotted name (``[]`` = an array of tables), its keys, a description."""

    name: str
    keys: dict[str, Key]
    doc: str = ""
    open: bool = False  # other keys are allowed (passed on, e.g. to python-can)


def _nav_sections() -> list[Section]:
    """The ``[core.nav]`` section and its sub-sections (the core's settings only: what a dataset config's
    ``[sensor]`` / ``[nav]`` tables are checked against, without the gateway's drivers and outputs)."""
    from ins_hil import aids
    from ins_hil.core_parts.config import SECTIONS as NAV_SECTIONS
    from ins_hil.core_parts.config import NavConfig
    from ins_hil.fusion.ekf import FilterConfig

    nav = dataclass_keys(NavConfig)  # the sections are tables of their own
    nav_secs: list[tuple[str, type, str]] = [
        (k, c, f"{(c.__doc__ or '').split(' (``')[0]} (ins_hil.core_parts.config.{c.__name__}).")
        for k, c in NAV_SECTIONS.items()
    ]
    # the aid modules' own sections (ins_hil.aids: the registry collects them; NavConfig.sources)
    nav_secs += [(k, c, f"{(c.__doc__ or '').split(' (``')[0]} (ins_hil.aids.{k}.{c.__name__}).")
                 for k, c in aids.sections().items()]  # fmt: skip
    nav_secs.append(("filter", FilterConfig, "The error-state Kalman filter (ins_hil.fusion.ekf.FilterConfig; noise "
                     "densities per √Hz)."))  # fmt: skip
    for k, _, _ in nav_secs:
        nav[k] = Key(k, "table", None, optional=True, help=f"the [core.nav.{k}] table")
    return [
        Section("core.nav", nav,
                "The navigation core (ins_hil.core.NavConfig; SI units, gates in σ)."),
        *(Section(f"core.nav.{k}", dataclass_keys(c), doc) for k, c, doc in nav_secs),
    ]  # fmt: skip


def sections() -> list[Section]:
    """Every section of a gateway configuration file, in the order of the docs."""
    from ins_hil.drivers.dbc_codec import DbcProfile
    from ins_hil.fdi.aiding import AidingConfig
    from ins_hil.fdi.monitor import FdiConfig
    from ins_hil.gateway_settings import GatewaySettings, InputConfig, RecorderConfig
    from ins_hil.runtime.mqtt_out import MqttConfig
    from ins_hil.runtime.pipeline import PipelineConfig
    from ins_hil.types import SimConfig
    from ins_hil.validation import Limits

    sim_keys = {"enabled": SIM_ENABLED}
    sim_keys.update(dataclass_keys(SimConfig))
    aid = {"enabled": AIDING_ENABLED}
    aid.update(dataclass_keys(AidingConfig))
    core = dataclass_keys(PipelineConfig, rename={"core": "kind"},
                          skip=("imu_ids", "fdi", "fdi_options", "aiding_fdi", "aiding_options", "limits"))  # fmt: skip
    core["nav"] = Key("nav", "table", None, help="the [core.nav] table")  # built by runtime.pipeline.nav_config
    # the validation limits (PipelineConfig.limits) are flat keys of [core]; the loader builds the Limits
    core.update({k: dataclasses.replace(v, attr=None) for k, v in dataclass_keys(Limits).items()})
    fdi_opts = {"geometry": FDI_GEOMETRY, **dataclass_keys(FdiConfig, skip=("geometry",))}
    return [
        Section("gateway", dataclass_keys(GatewaySettings), "The gateway process."),
        Section("core", core, "The navigation pipeline (ins_hil.runtime.pipeline.PipelineConfig)."),
        *_nav_sections(),
        Section("fdi", FDI_KEYS, "Inertial-sensor fault detection and isolation over redundant IMUs."),
        Section("fdi.options", fdi_opts, "The FDI monitor (ins_hil.fdi.monitor.FdiConfig); dt, gyro_noise and "
                "accel_noise are required when [fdi] enabled = true."),
        Section("fdi.aiding", aid, "The GNSS/baro drift monitor (ins_hil.fdi.aiding.AidingConfig)."),
        Section("sim", sim_keys, "The simulated sensors (ins_hil.types.SimConfig, read by ins_hil.sim.devices)."),
        Section("inputs[]", dataclass_keys(InputConfig), "One sensor input per [[inputs]] table."),
        Section("inputs[].options", CAN_OPTIONS, "A can_imu input's options (ins_hil.drivers.can_imu).", open=True),
        Section("inputs[].options.dbc", dataclass_keys(DbcProfile),
                "protocol = 'dbc': which DBC messages and signals carry the IMU (ins_hil.drivers.dbc_codec)."),
        *_output_sections(),
        Section("mqtt", dataclass_keys(MqttConfig), "The MQTT publisher (ins_hil.runtime.mqtt_out); "
                "without an [mqtt] table MQTT is off."),
        Section("recorder", dataclass_keys(RecorderConfig),
                "The input recorder (ins_hil.runtime.recorder)."),
    ]  # fmt: skip


def _output_sections() -> list[Section]:
    """The sections of the ``[[outputs]]`` tables: built without the core's imports, so that
    :func:`ins_hil.config.load_outputs` stays light (``ins-hil run`` opens the outputs first)."""
    from ins_hil.runtime.mavlink_out import EndpointConfig

    out_keys = {"type": OUTPUT_TYPE}
    out_keys.update(dataclass_keys(EndpointConfig, skip=("rates",)))
    out_keys["rates"] = Key("rates", "table", None, optional=True, help="the [outputs.rates] table")
    return [
        Section("outputs[]", out_keys, "One MAVLink output per [[outputs]] table (ins_hil.runtime.mavlink_out)."),
        Section("outputs[].rates", rate_keys(), "Messages per second of one output (the defaults depend on role)."),
    ]


_CACHE: dict[str, Section] = {}


def section(name: str) -> Section:
    """A section by its dotted name (``inputs[0].options`` → ``inputs[].options``)."""
    name = re.sub(r"\[\d+\]", "[]", name)
    if name not in _CACHE:
        light = "gateway" not in _CACHE  # one group alone: the outputs' without the core, the core's without
        # the drivers and outputs (a dataset config's check)
        if light and name.startswith("outputs[]"):
            built = _output_sections()
        elif light and (name == "core.nav" or name.startswith("core.nav.")):
            built = _nav_sections()
        else:
            built = sections()
        _CACHE.update({s.name: s for s in built})
    return _CACHE[name]


def validate(name: str, table: Any, where: str | None = None) -> dict[str, Any]:
    """Check one TOML table against its section: {key: converted value} of the keys present.

    Raises ConfigError naming the dotted key (``where``: the section's path in the file, e.g.
    ``inputs[1]``) for a table that is not one, an unknown key, a missing required key or a bad value.
    """
    where = where or name
    if not isinstance(table, dict):
        raise ConfigError(f"{where}: expected a table, got {show(table)}")
    sec = section(name)
    out: dict[str, Any] = {}
    for k, v in table.items():
        key = sec.keys.get(k)
        if key is None:
            if not sec.open:
                raise ConfigError(f"unknown key {show(f'{where}.{k}')} ({known_hint(str(k), sec.keys, name)})")
            key = sec.keys["*"]
        out[k] = key.check(v, f"{where}.{k}")
    for k, key in sec.keys.items():
        if key.required and k not in table:
            raise ConfigError(f"{where}: missing key {k!r} ({key.allowed()})")
    return out


# --------------------------------------------------------------------------------------------------
# docs/configuration.md


def _md(s: str) -> str:
    return s.replace("|", "\\|")


def markdown() -> str:
    """docs/configuration.md: every key with its type, unit, default, allowed values and meaning."""
    lines = [
        "# Configuration",
        "",
        "Every key of a gateway configuration file (`ins-hil run --config FILE`, TOML), generated from the keys'",
        "field metadata (`ins_hil/settings.py` `setting`: unit, range, default, help; collected by",
        "`ins_hil/config_schema.py`) by `ins-hil config --docs` (or `python -m ins_hil.config_schema`);",
        "`ins-hil config --check FILE` validates a file and prints `ok` or the error. See `configs/*.toml` for",
        "working examples.",
        "",
        "The whole file is validated before anything starts: every key typed and ranged, NaN and infinities",
        "rejected for every number, then the navigation pipeline, the MAVLink endpoints, the MQTT publisher and",
        "the input drivers are built (without opening a device). A problem is one line naming the file, the",
        "dotted key, the value and what is allowed, e.g.",
        "",
        "```",
        "ins-hil run: config error: configs/my.toml: core.init_lat_deg = 900.0: "
        "expected a finite number in [-89, 89] °",
        "```",
        "",
        "and the command exits with status 2. A number key takes an integer or a float; an integer key takes",
        "integers only. Absent keys take the default. Ranges: `[a, b]` closed, `(a, b)` open, `0 or ...` where 0",
        "switches the feature off.",
        "",
    ]
    for sec in sections():
        title = sec.name.replace("[]", "")
        head = f"[[{title}]]" if sec.name.endswith("[]") else f"[{title}]"
        lines += [f"## `{head}`", "", sec.doc, ""]
        lines += ["| key | type | unit | default | allowed | meaning |", "|---|---|---|---|---|---|"]
        for k in sec.keys.values():
            allowed = k.allowed()
            if k.unit and allowed.endswith(" " + k.unit):
                allowed = allowed[: -len(k.unit) - 1]
            name = "*(other)*" if k.name == "*" else f"`{k.name}`"
            lines.append(f"| {name} | {_md(k.type)} | {_md(k.unit)} | {_md(k.shown_default())} | {_md(allowed)} | "
                         f"{_md(k.help)} |")  # fmt: skip
        lines.append("")
    return "\n".join(lines)


def write_docs(path: Path = DOCS) -> Path:
    path.write_text(markdown(), encoding="utf-8")
    return path


if __name__ == "__main__":
    p = write_docs(Path(sys.argv[1]) if len(sys.argv) > 1 else DOCS)
    print(f"wrote {p}")
