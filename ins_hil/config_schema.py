"""The configuration schema: every key of a gateway TOML file with its type, unit, default, range and help.

The keys of a section are the fields of the dataclass it fills (``[core]`` → ``PipelineConfig``,
``[core.nav]`` → ``NavConfig``, ``[core.nav.gnss]`` → ``GnssConfig``, ``[sim]`` → ``SimConfig``, ...): a field
added to one of them is a key at once, typed from its default (bool, int, float, str, 3-vector, list, table)
and, if it is a number, required to be finite. Its unit, range and help come from the field's metadata, e.g.
``field(default=40.0, metadata={"unit": "rad/s", "range": "(0, 100]", "help": "..."})``
(accepted keys: ``unit``, ``range``, ``min``/``max`` (inclusive), ``gt``/``lt`` (exclusive),
``choices``, ``help``, ``nonfinite``, ``nonempty``, ``file``), or from one line in the section's
table below (:data:`TABLES`, keyed by the dotted section name).

A range is written as an interval, ``"(0, 1e4]"`` (open/closed ends; ``inf`` for none), with an
optional ``"0 | "`` in front when 0 is also allowed (``"0 | [0.01, 1000]"``: 0 = off). NaN and
infinities are rejected for every number unless the key says ``nonfinite``.

``python -m ins_hil.config_schema`` (or ``ins-hil config --docs``) writes ``docs/configuration.md``.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import re
import sys
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ins_hil.types import ConfigError as ConfigError  # with the shared types: the runtime raises it too

DOCS = Path(__file__).resolve().parent.parent / "docs" / "configuration.md"
REQUIRED = "(required)"


def _scalar(x: Any) -> bool:
    """A string, boolean, integer or finite float."""
    return isinstance(x, str | bool | int) or (isinstance(x, float) and math.isfinite(x))


def show(v: Any) -> str:
    """The value as in the file, shortened to one short line."""
    try:
        s = repr(v)
    except ValueError:  # an integer of more than 4300 digits
        s = f"<an integer of {v.bit_length()} bits>" if isinstance(v, int) else f"<a {type(v).__name__}>"
    return s if len(s) <= 60 else s[:57] + "..."


_RANGE = re.compile(r"^\s*(?:(0)\s*\|\s*)?([\[(])\s*([^,\s]+)\s*,\s*([^,\s\])]+)\s*([\])])\s*$")


@dataclass(frozen=True)
class Interval:
    """A range ``(lo, hi]`` etc.; ``zero``: 0 is allowed as well (e.g. 0 = off)."""

    lo: float
    hi: float
    lo_closed: bool
    hi_closed: bool
    zero: bool = False

    @classmethod
    def parse(cls, s: str) -> Interval:
        m = _RANGE.match(s)
        if not m:
            raise ValueError(f"bad range {s!r} (e.g. '(0, 1e4]', '0 | [0.01, 1000]')")
        return cls(float(m[3]), float(m[4]), m[2] == "[", m[5] == "]", m[1] is not None)

    def __contains__(self, v: float) -> bool:
        if self.zero and v == 0:
            return True
        lo_ok = v >= self.lo if self.lo_closed else v > self.lo
        hi_ok = v <= self.hi if self.hi_closed else v < self.hi
        return lo_ok and hi_ok

    def text(self, integer: bool = False) -> str:
        def num(x: float) -> str:
            if math.isinf(x):
                return "inf" if x > 0 else "-inf"
            return str(int(x)) if integer or (x == int(x) and abs(x) < 1e15) else f"{x:g}"

        if math.isinf(self.hi) and math.isinf(self.lo):
            core = "any"
        elif math.isinf(self.hi):
            core = f"{'≥' if self.lo_closed else '>'} {num(self.lo)}"
        elif math.isinf(self.lo):
            core = f"{'≤' if self.hi_closed else '<'} {num(self.hi)}"
        elif integer and self.lo_closed and self.hi_closed:
            core = f"{num(self.lo)}..{num(self.hi)}"
        else:
            lb, rb = "[" if self.lo_closed else "(", "]" if self.hi_closed else ")"
            core = f"in {lb}{num(self.lo)}, {num(self.hi)}{rb}"
        return f"0 or {core}" if self.zero else core


ANY = Interval(-math.inf, math.inf, False, False)

#: key types: what TOML value each takes
TYPES = {
    "bool": "true or false",
    "int": "an integer",
    "float": "a number",
    "str": "a string",
    "str|int": "a string or an integer",
    "vec3": "3 numbers",
    "list[int]": "a list of integers",
    "list[float]": "a list of numbers",
    "list[str]": "a list of strings",
    "table": "a table",
    "any": "a string, finite number, boolean, or a list of them or of tables of them",
}


@dataclass(frozen=True)
class Key:
    """One configuration key."""

    name: str
    type: str
    default: Any = None
    unit: str = ""
    range: str = ""
    choices: tuple[Any, ...] = ()
    help: str = ""
    attr: str | None = None  # the dataclass field it sets (None: handled by the loader)
    nonfinite: bool = False  # NaN / ±inf allowed (documented per key)
    optional: bool = False  # no default value: absent = not set
    required: bool = False
    nonempty: bool = False  # strings, lists
    file: bool = False  # a path to an existing file ("" = none unless nonempty)
    length: int = 0  # lists: exactly this many entries
    unique: bool = False  # lists: no entry twice
    nonzero: bool = False  # vectors: not all zero
    doc_default: str = ""  # the default as shown in the docs (when the value is machine-specific)
    hex_bytes: int = 0  # a string of 2 × this many hex digits, or ''

    @property
    def interval(self) -> Interval:
        return Interval.parse(self.range) if self.range else ANY

    def allowed(self) -> str:
        """What the key accepts, in words (used in the error messages and the docs)."""
        if self.choices:
            return "one of " + ", ".join(repr(c) for c in self.choices)
        t = self.type
        iv = self.interval
        what = TYPES[t]
        if t in ("float", "int", "vec3", "list[int]", "list[float]"):
            integer = t in ("int", "list[int]")
            rng = iv.text(integer)
            if t == "vec3":
                what = "3 finite numbers" if not self.nonfinite else what
                what += f" each {rng}" if rng != "any" else ""
                what += " (not all 0)" if self.nonzero else ""
            elif t in ("list[int]", "list[float]"):
                n = f"{self.length} " if self.length else ""
                what = (
                    ("a non-empty " if self.nonempty else "a ")
                    + f"list of {n}"
                    + ("integers" if integer else "finite numbers")
                )
                what += f" {rng}" if rng != "any" else ""
                what += " (no duplicates)" if self.unique else ""
            else:
                if t == "float" and not self.nonfinite:
                    what = "a finite number"
                what += f" {rng}" if rng != "any" else ""
        elif t in ("str", "list[str]"):
            if self.hex_bytes:
                what = f"'' or {2 * self.hex_bytes} hex digits"
            elif self.length:
                what = f"a list of {self.length} strings"
            elif self.file:
                what = "the path of an existing file" + ("" if self.nonempty else " ('' = none)")
            elif self.nonempty:
                what = "a non-empty " + what[2:]
        if self.unit and t in ("float", "int", "vec3", "list[int]", "list[float]"):
            what += f" {self.unit}"
        return what

    def check(self, v: Any, where: str) -> Any:
        """The value converted to its Python type (int → float for a float key), or ConfigError."""
        t = self.type

        def bad() -> ConfigError:
            what = self.allowed()
            if self.choices and len(what) > KNOWN_LIST_MAX:  # one line: the close matches, not every choice
                near = difflib.get_close_matches(v, [str(c) for c in self.choices], n=2) if isinstance(v, str) else []
                alt = f" (did you mean {' or '.join(repr(n) for n in near)}?)" if near else ""
                what = f"one of {len(self.choices)} names{alt}, listed in docs/configuration.md"
            return ConfigError(f"{where} = {show(v)}: expected {what}")

        if t == "bool":
            if not isinstance(v, bool):
                raise bad()
            return v
        if t == "int":
            if isinstance(v, bool) or not isinstance(v, int) or v not in self.interval:
                raise bad()
            return v
        if t == "float":
            if isinstance(v, bool) or not isinstance(v, int | float):
                raise bad()
            try:
                x = float(v)
            except OverflowError:
                raise bad() from None
            if math.isnan(x) or math.isinf(x):
                if not self.nonfinite:
                    raise bad()
                return x
            if x not in self.interval:
                raise bad()
            return x
        if t in ("str", "str|int"):
            if t == "str|int" and isinstance(v, int) and not isinstance(v, bool):
                return v
            if not isinstance(v, str) or "\0" in v or (self.nonempty and not v):
                raise bad()
            if self.choices and v not in self.choices:
                raise bad()
            if self.hex_bytes and v:
                try:
                    ok = len(bytes.fromhex(v)) == self.hex_bytes and len(v) == 2 * self.hex_bytes
                except ValueError:
                    ok = False
                if not ok:
                    raise bad()
            if self.file and v:
                try:
                    found = Path(v).is_file()
                except (OSError, ValueError) as e:  # e.g. a name too long, a NUL byte
                    why = getattr(e, "strerror", None) or e
                    raise ConfigError(f"{where} = {show(v)}: not a usable path ({why})") from None
                if not found:
                    raise ConfigError(f"{where} = {show(v)}: file not found (or not a regular file)")
            return v
        if t == "vec3":
            ok = isinstance(v, list) and len(v) == 3
            ok = ok and all(isinstance(x, int | float) and not isinstance(x, bool) for x in v)
            if not ok or not all(abs(x) < 1e300 for x in v if isinstance(x, int)):
                raise bad()
            xs = [float(x) for x in v]
            if not self.nonfinite and not all(math.isfinite(x) and x in self.interval for x in xs):
                raise bad()
            if self.nonzero and not any(xs):
                raise bad()
            return xs
        if t == "list[int]":
            ok = isinstance(v, list) and (bool(v) or not self.nonempty)
            ok = ok and all(isinstance(x, int) and not isinstance(x, bool) and x in self.interval for x in v)
            if not ok or (self.unique and len(set(v)) != len(v)):
                raise bad()
            return list(v)
        if t == "list[float]":
            ok = isinstance(v, list) and (bool(v) or not self.nonempty) and (not self.length or len(v) == self.length)
            ok = ok and all(isinstance(x, int | float) and not isinstance(x, bool) and abs(x) < 1e300 for x in v)
            if not ok or not all(math.isfinite(float(x)) and float(x) in self.interval for x in v):
                raise bad()
            return [float(x) for x in v]
        if t == "list[str]":
            ok = isinstance(v, list) and all(isinstance(x, str) and x for x in v)
            if not ok or (self.length and len(v) != self.length) or (self.nonempty and not v):
                raise bad()
            return list(v)
        if t == "table":
            if not isinstance(v, dict):
                raise bad()
            return v
        if t == "any":
            if (isinstance(v, float) and not math.isfinite(v)) or isinstance(v, dict):
                raise bad()
            if isinstance(v, list) and not all(_scalar(x) or (isinstance(x, dict) and all(map(_scalar, x.values())))
                                               for x in v):  # fmt: skip
                raise bad()
            return v
        raise AssertionError(f"schema: unknown type {t!r} of {where}")

    def shown_default(self) -> str:
        if self.doc_default:
            return self.doc_default
        if self.required:
            return REQUIRED
        if self.optional and self.default is None:
            return "not set"
        if self.type == "table":
            return ""
        d = self.default
        if isinstance(d, bool):
            return "true" if d else "false"
        if isinstance(d, str):
            return f'"{d}"'
        if isinstance(d, float):
            return f"{d:.6g}"
        if isinstance(d, list | tuple):
            return "[" + ", ".join(f"{x:.6g}" if isinstance(x, float) else repr(x) for x in d) + "]"
        return str(d)


# --------------------------------------------------------------------------------------------------
# building the keys of a section from its dataclass (+ metadata / table)


def M(unit: str = "", range: str = "", help: str = "", **kw: Any) -> dict[str, Any]:
    """One line of a section table: unit, range, help and any other :class:`Key` attribute."""
    return {"unit": unit, "range": range, "help": help, **kw}


def _plain(v: Any) -> Any:
    """A default as a TOML-like value (numpy vectors → lists of floats, tuples → lists)."""
    if hasattr(v, "tolist"):
        return v.tolist()
    if isinstance(v, tuple):
        return [_plain(x) for x in v]
    return v


def _infer(default: Any, annotation: str) -> tuple[str, bool]:
    """(key type, optional) from a field's default value or, when it has none, its annotation."""
    if isinstance(default, bool):
        return "bool", False
    if isinstance(default, int):
        return "int", False
    if isinstance(default, float):
        return "float", False
    if isinstance(default, str):
        return "str", False
    if isinstance(default, dict):
        return "table", False
    if hasattr(default, "shape") or (isinstance(default, tuple | list) and len(default) == 3 and
                                     all(isinstance(x, float) for x in default)):  # fmt: skip
        return "vec3", False
    if isinstance(default, list | tuple):
        if default and isinstance(default[0], str):
            return "list[str]", False
        return ("list[float]" if any(isinstance(x, float) for x in default) else "list[int]"), False
    a = str(annotation).replace(" ", "")
    optional = default is None
    if "tuple[float" in a or a.startswith("Vec") or "ndarray" in a:
        return "vec3", optional
    for name in ("bool", "int", "float", "str"):
        if a.split("|")[0] == name:
            return name, optional
    if "dict" in a:
        return "table", optional
    return "any", optional


_META = {"unit", "range", "choices", "help", "nonfinite", "nonempty", "file", "length", "unique", "nonzero",
         "optional", "required", "type", "doc_default"}  # fmt: skip


def _from_metadata(md: Any) -> dict[str, Any]:
    """The :class:`Key` attributes a dataclass field's metadata gives (min/max/gt/lt → range)."""
    out = {k: md[k] for k in _META if k in md}
    if "range" not in out and any(k in md for k in ("min", "max", "gt", "lt")):
        lo = md.get("min", md.get("gt", -math.inf))
        hi = md.get("max", md.get("lt", math.inf))
        out["range"] = f"{'(' if 'min' not in md else '['}{lo}, {hi}{')' if 'max' not in md else ']'}"
    if "choices" in out:
        out["choices"] = tuple(out["choices"])
    if isinstance(out.get("range"), tuple | list):
        lo, hi = out["range"]
        out["range"] = f"[{lo}, {hi}]"
    return out


def dataclass_keys(cls: type, section: str, rename: dict[str, str] | None = None,
                   skip: tuple[str, ...] = ()) -> dict[str, Key]:  # fmt: skip
    """The keys of ``section`` from the fields of dataclass ``cls`` (metadata over the section table)."""
    table = TABLES.get(section, {})
    rename = rename or {}
    out: dict[str, Key] = {}
    for f in dataclasses.fields(cls):
        if f.name in skip or not f.init or f.name.startswith("_"):
            continue
        name = rename.get(f.name, f.name)
        attrs: dict[str, Any] = {**table.get(name, {}), **_from_metadata(f.metadata)}
        if f.default is not dataclasses.MISSING:
            default: Any = f.default
        elif f.default_factory is not dataclasses.MISSING:
            default = f.default_factory()
        else:
            default = None
            attrs.setdefault("required", True)
        default = attrs.pop("default", default)
        if dataclasses.is_dataclass(default):  # a nested settings object is its own section (e.g. core.nav.filter)
            continue
        typ, optional = _infer(default, str(f.type))
        attrs.setdefault("type", typ)
        if optional:
            attrs.setdefault("optional", True)
        out[name] = Key(name=name, default=_plain(default), attr=f.name, **attrs)
    return out


# --------------------------------------------------------------------------------------------------
# the section tables: unit, range and help of each key (the dataclasses give the types and defaults)

PI = "3.1416"
HEX_KEY = M(help="MAVLink 2 signing key (32 bytes); '' = unsigned", hex_bytes=32)

TABLES: dict[str, dict[str, dict[str, Any]]] = {
    "gateway": {
        "name": M(help="the gateway's name (status view, recording header)", nonempty=True),
        "late_threshold_ms": M(
            "ms", "(0, 10000]", "an IMU sample whose arrival → state latency exceeds this is 'late'"
        ),
        "queue_size": M("samples", "[1, 10000000]", "bounded input queue; overflow is dropped and counted"),
        "status_period": M("s", "[0.01, 3600]", "period of the live status view"),
        "rt_priority": M(
            "", "[0, 99]", "SCHED_FIFO priority with mlockall (root or CAP_SYS_NICE/CAP_IPC_LOCK); 0 = off"
        ),
        "input_timeout": M(
            "s", "[0, 86400]", "ins-hil run exits 3 when an input delivered nothing by then; 0 = wait for ever"
        ),
    },
    "core": {
        "kind": M(
            help="navigation core: python (ins_hil.core) or c (the C reference core, ins_hil.cref)",
            choices=("python", "c"),
        ),
        "init": M(
            help="gnss: start at the first 3-D fix, levelled from the accelerometers; config: the init_* keys",
            choices=("gnss", "config"),
        ),
        "init_lat_deg": M(
            "°", "[-89, 89]", "initial latitude (init = 'config'); the NED mechanization is singular at the poles"
        ),
        "init_lon_deg": M("°", "[-180, 180]", "initial longitude (init = 'config')"),
        "init_h": M("m", "[-1000, 100000]", "initial height above the WGS84 ellipsoid (init = 'config')"),
        "init_roll_deg": M("°", "[-180, 180]", "initial roll (init = 'config')"),
        "init_pitch_deg": M("°", "[-90, 90]", "initial pitch (init = 'config')"),
        "init_yaw_deg": M(
            "°", "[-360, 360]", "initial yaw (init = 'config'; with gnss: when not moving at the first fix)"
        ),
        "level_samples": M("IMU intervals", "[1, 100000]", "intervals averaged for the levelling"),
        "epoch_wait_periods": M(
            "IMU periods", "(0, 1000]", "redundant IMUs: how long an epoch waits (arrival time) for a missing unit"
        ),
        "gyro_range_dps": M("°/s", "(0, 100000]", "per-axis gyro full scale; beyond range × range_margin: rejected"),
        "accel_range_g": M("g", "(0, 1000]", "per-axis accelerometer full scale (g = 9.80665 m/s²)"),
        "range_margin": M("", "[1, 100]", "factor on the full scales before a reading is rejected"),
        "imu_period_s": M("s", "[0, 1]", "nominal IMU interval; 0 = learnt per IMU id (median of its first 8)"),
        "imu_dt_min_periods": M("", "(0, 1]", "shortest accepted dt, in nominal periods (never below 1e-5 s)"),
        "imu_dt_max_periods": M("", "[1, 1000]", "longest accepted dt, in nominal periods (never above 1 s)"),
        "gnss_min_fix_type": M("", "[0, 8]", "lowest GNSS fix type fused (MAVLink GPS_FIX_TYPE: 3 = 3-D)"),
        "gnss_h_min_m": M("m", "[-100000, 100000]", "lowest plausible GNSS ellipsoidal height"),
        "gnss_h_max_m": M("m", "[-100000, 1000000]", "highest plausible GNSS ellipsoidal height"),
        "gnss_speed_max_mps": M("m/s", "(0, 100000]", "highest plausible GNSS speed"),
        "gnss_std_max_m": M("m", "(0, 1000000]", "a fix reporting a larger position σ is rejected"),
        "gnss_std_vel_max_mps": M("m/s", "(0, 100000]", "a fix reporting a larger velocity σ is rejected"),
        "baro_pressure_min_pa": M("Pa", "[0, 1000000]", "lowest plausible static pressure"),
        "baro_pressure_max_pa": M("Pa", "(0, 10000000]", "highest plausible static pressure"),
        "baro_alt_min_m": M("m", "[-100000, 100000]", "lowest plausible barometric altitude"),
        "baro_alt_max_m": M("m", "[-100000, 1000000]", "highest plausible barometric altitude"),
        "mag_max_t": M("T", "(0, 1]", "a magnetometer reading with a larger field magnitude is rejected"),
        "calibration": M(
            help="IMU calibration file (ins-hil calibrate; ins_hil.nav.calibration); '' = none", file=True
        ),
        "nav": M(help="the [core.nav] table"),
    },
    "core.nav": {
        "adaptive": M(help="Sage–Husa adaptive R on GNSS/baro"),
        "adaptive_b": M("", "(0, 1)", "Sage–Husa forgetting factor"),
        "gravity": M(
            help="strapdown gravity model: 'normal' Somigliana + height series, 'j2' J2 field + centrifugal",
            choices=("normal", "j2"),
        ),
    },
    "core.nav.gnss": {
        "lever_arm_b": M("m", "[-100, 100]", "IMU → GNSS antenna, body FRD"),
        "min_std": M("m, m, m/s", "(0, 1000]", "floor on the reported GNSS σ: north/east, down, velocity"),
        "std_scale": M("", "(0, 1000]", "factor on the reported GNSS σ"),
        "use_vel": M(help="fuse the GNSS velocity"),
        "vel_delay": M(
            "s", "[0, 2]", "the GNSS velocity is valid this long before the fix's position time (≤ delay.max_delay)"
        ),
        "gate": M("σ", "(0, 1e6]", "innovation gate of GNSS"),
        "reset_after": M("fixes", "[0, 1000000]", "consecutive rejected fixes before the GNSS position is reset"),
    },
    "core.nav.baro": {
        "std": M("m", "(0, 1000]", "barometer noise"),
        "gate": M("σ", "(0, 1e6]", "innovation gate of the barometer"),
        "offset": M(
            "m", "[-10000, 10000]", "fixed baro datum offset (baro altitude → ellipsoidal height); not set = learnt"
        ),
        "offset_tau": M("s", "(0, 1e6]", "time constant of the baro datum calibration against GNSS"),
    },
    "core.nav.mag": {
        "std": M("", "(0, 10]", "magnetometer noise (unit-vector component, book σ_m)"),
        "ref_ned": M(
            "any unit",
            "[-1e6, 1e6]",
            "reference magnetic field, NED (e.g. from WMM); not set = no heading from it",
            nonzero=True,
        ),
        "gate": M("σ", "(0, 1e6]", "innovation gate of the magnetometer"),
    },
    "core.nav.aids": {
        "nhc": M(help="non-holonomic constraint (ground vehicles)"),
        "nhc_std": M("m/s", "(0, 100]", "NHC lateral velocity σ"),
        "nhc_rate": M("Hz", "(0, 10000]", "NHC update rate"),
        "nhc_min_speed": M("m/s", "[0, 1000]", "NHC only above this speed"),
        "nhc_vertical": M(help="NHC on the vertical axis as well"),
        "nhc_std_vertical": M("m/s", "(0, 100]", "NHC vertical velocity σ"),
        "nhc_lever_b": M(
            "m", "[-100, 100]", "IMU → the vehicle point whose lateral/vertical velocity is zero, body FRD"
        ),
        "nhc_pitch_per_accel": M(
            "rad/(m/s²)", "[-1, 1]", "suspension pitch per forward acceleration (nose-up accelerating)"
        ),
        "nhc_omega_lp_hz": M("Hz", "[0, 10000]", "low-pass corner of the body rate in the NHC lever-arm term; 0 = raw"),
        "zupt": M(help="zero-velocity update when at rest"),
        "zupt_std": M("m/s", "(0, 100]", "ZUPT velocity σ"),
        "zupt_gyro": M("rad/s", "(0, 10]", "rest detection: averaged rate below this"),
        "zupt_accel": M("m/s²", "(0, 100]", "rest detection: averaged specific-force change below this"),
        "zupt_time": M("s", "(0, 3600]", "rest detection: this long"),
        "zupt_tau": M("s", "(0, 3600]", "averaging time constant of the rest detection"),
        "zupt_max_speed": M("m/s", "[0, 1000]", "ZUPT only below this speed"),
        "zaru": M(help="zero angular rate update on the gyro bias with ZUPT"),
        "zaru_std": M("rad/s", "(0, 10]", "ZARU σ"),
        "drag": M(help="multirotor rotor drag on the body x/y specific force (needs filter.wind_states)"),
        "drag_coef": M("1/s", "(0, 10]", "drag coefficient: specific force per air speed (PX4 EKF2_MCOEF)"),
        "drag_std": M("m/s²", "(0, 100]", "drag aid σ of the averaged specific force"),
        "drag_tau": M("s", "(0, 60]", "averaging time constant of the specific force for the drag aid"),
        "drag_rate": M("Hz", "(0, 1000]", "drag aid rate"),
        "gate": M("σ", "(0, 1e6]", "innovation gate of the auxiliary aids (NHC, ZUPT, drag)"),
    },
    "core.nav.hold": {
        "enabled": M(
            help="flight without GNSS: constant-position / zero-velocity pseudo-measurements once no GNSS position "
            "has been fused for `after` s (EKF2's no-aiding mode; for hovers and bench tests, not for a moving car)"
        ),
        "after": M("s", "[0, 3600]", "seconds without a fused GNSS position before the hold"),
        "std": M("m", "(0, 1e6]", "σ of the constant-position row"),
        "vel_std": M("m/s", "[0, 1e3]", "σ of the zero-velocity row; 0 = none"),
        "rate": M("Hz", "(0, 100]", "pseudo-measurements per second"),
        "gate": M("σ", "(0, 1e6]", "innovation gate of the hold"),
    },
    "core.nav.alignment": {
        "mode": M(
            help="given: trust the initial state; static: level at rest, yaw from magnetometer or GNSS course",
            choices=("given", "static"),
        ),
        "time": M("s", "(0, 3600]", "static alignment: levelling time at rest"),
        "level_only": M(help="static alignment: level only (yaw from the initial state)"),
        "gyrocompass": M(
            help="static alignment: yaw from the Earth rate (book eq. 4.2) when filter.init_gyro_bias allows "
            "σ_ψ ≤ gyrocompass_max_std (navigation-grade gyros; MEMS cannot resolve 15 °/h)"
        ),
        "gyrocompass_max_std": M("rad", f"(0, {PI}]", "gyrocompass: the largest yaw σ it may give"),
        "level_tilt_prior": M(help="levelled tilt prior correlated with the accelerometer errors"),
        "still_speed": M("m/s", "[0, 100]", "static alignment: at rest below this GNSS speed"),
        "still_delay": M("s", "[0, 3600]", "static alignment: at rest for this long"),
        "still_gyro": M(
            "rad/s",
            "(0, 10]",
            "static alignment: in motion when the rate departs from the window's "
            "mean by this much (RMS over still_tau)",
        ),
        "still_accel": M(
            "m/s^2",
            "(0, 100]",
            "static alignment: in motion when the specific force departs from the "
            "window's mean by this much (RMS over still_tau)",
        ),
        "still_tau": M("s", "(0, 60]", "static alignment: time constant of the IMU motion test"),
        "gyro_bias_std": M("rad/s", "(0, 1]", "gyro bias σ after the alignment"),
        "mag_yaw_std": M("rad", f"(0, {PI}]", "yaw σ from the magnetometer alignment"),
        "gnss_yaw_speed": M(
            "m/s", "(0, 1000]", "in-motion yaw from a receiver's velocity course above this speed (else a fitted track)"
        ),
        "gnss_yaw_std": M("rad", f"(0, {PI}]", "yaw σ of the in-motion alignment (⊕ σ_v/V)"),
        "gnss_yaw_vel_floor": M("m/s", "[0, 100]", "floor on the receiver's σ_v in the in-motion yaw σ"),
        "aligned_yaw_std": M("rad", f"(0, {PI}]", "the state is 'aligned' when the yaw σ is below this"),
        "yaw_gsf": M(
            help="heading phase: yaw from the GNSS-velocity yaw bank (PX4 EKF-GSF, σ < 15°) "
            "instead of the GNSS course (a multicopter without magnetometer)"
        ),
        "position": M(
            help="[lat deg, lon deg, h m]: a known position (levelling and the hold need no GNSS fix)",
            length=3,
            optional=True,
        ),
    },
    "core.nav.delay": {
        "compensation": M(
            help="fuse a late GNSS fix at its time (roll-back); false: at the current step, shifted by v·Δt"
        ),
        "max_delay": M("s", "[0, 2]", "history kept for delayed fusion"),
    },
    "core.nav.filter": {
        "gyro_bias": M(help="estimate the gyro bias (3 states)"),
        "accel_bias": M(help="estimate the accelerometer bias (3 states)"),
        "scale_factors": M(help="estimate the gyro and accelerometer scale factors (6 states)"),
        "gyro_arw": M("rad/s/√Hz", "(0, 1]", "gyro white noise"),
        "accel_vrw": M("m/s²/√Hz", "(0, 10]", "accelerometer white noise"),
        "gyro_bias_sigma": M("rad/s", "[0, 1]", "1-σ of the Gauss–Markov gyro bias"),
        "gyro_bias_tau": M("s", "(0, 1e7]", "correlation time of the gyro bias"),
        "accel_bias_sigma": M("m/s²", "[0, 10]", "1-σ of the Gauss–Markov accelerometer bias"),
        "accel_bias_tau": M("s", "(0, 1e7]", "correlation time of the accelerometer bias"),
        "gyro_sf_sigma": M("", "[0, 1]", "1-σ of the gyro scale factor"),
        "accel_sf_sigma": M("", "[0, 1]", "1-σ of the accelerometer scale factor"),
        "sf_tau": M("s", "(0, 1e7]", "correlation time of the scale factors"),
        "gyro_gsens": M(help="estimate the gyro g-sensitivity matrix (9 states)"),
        "gsens_sigma_rw": M("rad/s/(m/s²)/√s", "[0, 1]", "random walk of the g-sensitivity"),
        "init_gsens": M("rad/s/(m/s²)", "(0, 1]", "initial 1-σ of the g-sensitivity"),
        "mount_states": M(help="estimate the residual IMU → vehicle boresight (3 states; needs nhc)"),
        "mount_sigma_rw": M("rad/√s", "[0, 1]", "random walk of the boresight"),
        "init_mount": M("rad", f"(0, {PI}]", "initial 1-σ of the boresight"),
        "mag_bias": M(help="estimate the magnetometer hard iron (3 states; field and reference in one unit)"),
        "mag_bias_sigma_rw": M("|m_ref|/√s", "[0, 1]", "random walk of the hard iron (fraction of the field)"),
        "init_mag_bias": M("|m_ref|", "(0, 10]", "initial 1-σ of the hard iron (fraction of the field)"),
        "wind_states": M(help="estimate the horizontal wind (2 states; the multirotor drag aid)"),
        "wind_sigma_rw": M("m/s/√s", "[0, 100]", "random walk of the wind"),
        "init_wind": M("m/s", "[0, 100]", "initial 1-σ of the wind"),
        "gyro_vib_gain": M("", "[0, 1000]", "attitude process noise from the measured rate change; 0 = off"),
        "accel_vib_gain": M("", "[0, 1000]", "velocity process noise from the measured specific-force change; 0 = off"),
        "vib_tau": M("s", "(0, 3600]", "averaging time of the vibration measure"),
        "gap_accel_sigma": M("m/s²", "[0, 100]", "unknown acceleration across lost IMU data (velocity σ = it × gap)"),
        "gap_rate_sigma": M("rad/s", "[0, 10]", "unknown rotation rate across lost IMU data (attitude σ = it × gap)"),
        "init_pos": M("m", "(0, 1e6]", "initial 1-σ position"),
        "init_vel": M("m/s", "(0, 1000]", "initial 1-σ velocity"),
        "init_att": M("rad", f"(0, {PI}]", "initial 1-σ roll/pitch"),
        "init_yaw": M("rad", f"(0, {PI}]", "initial 1-σ yaw"),
        "init_gyro_bias": M("rad/s", "(0, 10]", "initial 1-σ gyro bias"),
        "init_accel_bias": M("m/s²", "(0, 100]", "initial 1-σ accelerometer bias"),
        "init_sf": M("", "(0, 1]", "initial 1-σ scale factors"),
        "init_accel_sf": M("", "(0, 1]", "initial 1-σ accelerometer scale factors x, y, z; not set = init_sf"),
        "cov_every": M("IMU steps", "[1, 1000]", "propagate the covariance every N IMU steps (Python core only)"),
        "second_order": M(help="second-order transition matrix"),
        "earth_terms": M(help="Earth rate and transport rate terms in the error model"),
        "omega_rv_terms": M(help="∂ω/∂r, ∂ω/∂v terms of Earth and transport rate in F (seed 001 F21/F22/F31/F32)"),
        "numerics": M(
            help="measurement update form (ins_hil.fusion.sqrt)",
            choices=("joseph", "conventional", "qr", "cholesky", "ud"),
        ),
    },
    "fdi": {},  # explicit keys (SECTIONS)
    "fdi.options": {
        "geometry": M(
            help="the redundant set (ins_hil.fdi.geometry)",
            choices=("cone5", "dual_imu", "skew6", "triple_imu"),
            type="str",
            default="triple_imu",
            required=False,
        ),
        "dt": M("s", "(0, 1]", "nominal IMU interval", required=False, doc_default="required with FDI"),
        "gyro_noise": M(
            "rad/s/√Hz", "(0, 1]", "white-noise density of one gyro", required=False, doc_default="required with FDI"
        ),
        "accel_noise": M(
            "m/s²/√Hz",
            "(0, 10]",
            "white-noise density of one accelerometer",
            required=False,
            doc_default="required with FDI",
        ),
        "gyro_bias": M("rad/s", "[0, 1]", "1-σ residual bias of one gyro after calibration"),
        "accel_bias": M("m/s²", "[0, 10]", "1-σ residual bias of one accelerometer after calibration"),
        "p_false_alarm": M("per hour", "[1e-12, 1)", "false-alarm probability per hour and test"),
        "persistence": M("samples", "[1, 1000000]", "consecutive exceedances to trip"),
        "slow_tau": M("s", "(0, 3600]", "averaging time constant of the slow test"),
        "classify_time": M("s", "[0, 3600]", "post-exclusion time used to classify the failure mode"),
        "readmit_after": M("s", "[0, 1e6]", "healthy time before re-admission; 0 = never"),
        "stuck_samples": M("samples", "[0, 1000000]", "identical consecutive outputs that mean STUCK; 0 = off"),
        "dropout_samples": M("samples", "[1, 1000000]", "consecutive missing epochs that mean DROPOUT"),
        "exclude_unit": M(help="exclude every row of the failed unit (whole IMU), not only the axis"),
        "history": M("s", "(0, 3600]", "pre-isolation residual history kept for classification"),
        "isolation_margin": M("χ²", "[0, 1e6]", "best candidate's score margin over the second before excluding"),
        "compensate_leak": M(help="on exclusion, remove what the fault put into the output since its onset"),
    },
    "fdi.aiding": {
        "enabled": M(help="the GNSS/baro drift and slow-pull monitor (ins_hil.fdi.aiding)"),
        "p_fa_hour": M("per hour", "[1e-12, 1)", "false-alarm probability per hour (thresholds are derived from it)"),
        "window": M("s", "(0, 3600]", "sliding window of the slope tests"),
        "min_span": M("s", "(0, 3600]", "shortest filled window a slope test runs on (≤ window)"),
        "cusum_k": M("σ", "[0.01, 100]", "CUSUM allowance"),
        "clear_gate": M("σ", "(0, 100]", "a flag clears below this"),
        "clear_time": M("s", "[0, 3600]", "time below clear_gate to clear"),
        "rate_floor": M("m/s", "[0, 100]", "floor of the drift-rate σ (time-correlated receiver errors)"),
        "baro_std": M("m", "(0, 100]", "barometer noise"),
        "gnss_rate": M("Hz", "(0, 1000]", "nominal GNSS rate (counts trials per hour)"),
        "baro_rate": M("Hz", "(0, 1000]", "nominal baro rate (counts trials per hour)"),
        "min_std": M("m", "(0, 100]", "floor on a fix's σ"),
        "jump_gate": M("σ", "(0, 1e6]", "normalised innovations are clipped here in the CUSUM"),
        "vertical_cusum": M(help="CUSUM on the vertical axis as well"),
        "clear_fraction": M("", "[0, 1]", "hysteresis: a CUSUM clears below this fraction of its threshold"),
        "max_gap": M("s", "(0, 3600]", "a GNSS gap that restarts the windows"),
        "exclude": M(help="stop fusing a sensor while it is flagged"),
        "lag_margin": M("", "[0, 100]", "dead zone factor on the error a late fix's lag can cause"),
        "lag_tau": M("s", "(0, 3600]", "time constant of the mean velocity in the lag dead zone"),
        "max_lag": M("s", "[0, 10]", "a fix up to this late is compared at its time (or as current)"),
        "late_fix_as_current": M(help="compare a late fix with the current state; default follows the core"),
        "ins_vel_floor": M("", "[0, 100]", "the INS velocity σ in the CUSUM is at least this × the fix's σ_vel"),
    },
    "sim": {
        "enabled": M(help="run the simulated sensors (their own process)"),
        "profile": M(
            help="uav: 10 s at rest, then sweeping turns at 20 m/s; static: at rest", choices=("uav", "static")
        ),
        "imu_rate": M("Hz", "[1, 10000]", "simulated IMU rate (serial frames into a pty)"),
        "imu_errors": M(help="mems: UAV-grade MEMS errors; none: error-free", choices=("mems", "none")),
        "gnss_rate": M("Hz", "(0, 100]", "GNSS rate (GPS_INPUT over MAVLink)"),
        "gnss_latency": M("s", "[0, 1]", "from the time of validity to sending"),
        "gnss_std_ne": M("m", "(0, 1000]", "GNSS horizontal noise"),
        "gnss_std_d": M("m", "(0, 1000]", "GNSS vertical noise"),
        "gnss_std_vel": M("m/s", "(0, 100]", "GNSS velocity noise"),
        "baro_rate": M("Hz", "(0, 1000]", "baro rate (SCALED_PRESSURE over MAVLink)"),
        "baro_std": M("m", "[0, 100]", "baro noise"),
        "lat_deg": M("°", "[-89, 89]", "start latitude"),
        "lon_deg": M("°", "[-180, 180]", "start longitude"),
        "h": M("m", "[-1000, 100000]", "start height above the WGS84 ellipsoid"),
        "seed": M("", "[0, 4294967295]", "random seed (the same seed gives the same run)"),
        "chunk_s": M("s", "[0.1, 60]", "simulated in chunks of this length"),
        "duration": M("s", "0 | [0.1, 1e7]", "stop the simulator after this long; 0 = until stopped"),
        "gnss_sysid": M("", "[1, 255]", "MAVLink system id of the simulated GNSS"),
        "sign_key": HEX_KEY,
    },
    "inputs[]": {
        "name": M(help="the input's name (status view, counters)", nonempty=True, doc_default="input<N>"),
        "type": M(
            help="serial_imu: IMU frames on a serial port; mavlink: GNSS/baro from MAVLink; can_imu: CAN IMU; or a "
            "type a driver package registers (ins_hil.drivers entry points), its keys in [inputs.options]",
            choices=("serial_imu", "mavlink", "can_imu"),
        ),
        "port": M(help="serial_imu: the device (/dev/ttyUSB0), or 'sim' for the simulator's pty", nonempty=True),
        "baud": M("bit/s", "[1, 20000000]", "serial_imu: baud rate"),
        "url": M(
            help="mavlink: udpin:HOST:PORT (0 = any free port), udpout:HOST:PORT, tcp:HOST:PORT, serial:DEV[:BAUD]"
        ),
        "signing_key": M(help="mavlink: accept only messages signed with this key (32 bytes); '' = any", hex_bytes=32),
        "sysid": M(
            "",
            "[0, 255]",
            "mavlink: take GNSS/baro only from this system id (the flight controller's; "
            "ArduPilot and PX4: 1); 0 = any (not on a shared network)",
        ),
        "compid": M(
            "",
            "[0, 255]",
            "mavlink: take GNSS only from this component; 0 = any (messages from the "
            "gateway's own output identities are always refused)",
        ),
        "gnss_messages": M(
            help="mavlink: the GNSS messages taken (of GPS_RAW_INT, GPS2_RAW, GPS_INPUT, HIL_GPS); "
            "[] = all, less GPS_RAW_INT from a system an fc output sends GPS_INPUT to (its echo); "
            "naming GPS_RAW_INT while one does is a config error",
            type="list[str]",
        ),
        "fc_gnss_lag_s": M(
            "s",
            "[0, 1]",
            "mavlink: the flight controller's GNSS lag, removed from GPS_RAW_INT/"
            "GPS2_RAW time (their time is the FC's arrival, not the fix's time of validity)",
        ),
        "options": M(help="can_imu: the [inputs.options] table"),
    },
    "inputs[].options": {},  # explicit keys (SECTIONS)
    "inputs[].options.dbc": {
        "dbc": M(help="the DBC file", file=True, nonempty=True, doc_default="configs/imu_dbc.dbc (shipped)"),
        "gyro_message": M(help="DBC message with the angular rates", nonempty=True),
        "gyro_signals": M(help="its x, y, z signals (rad/s)", length=3),
        "accel_message": M(help="DBC message with the specific force", nonempty=True),
        "accel_signals": M(help="its x, y, z signals (m/s²)", length=3),
        "status_message": M(help="DBC message with Temperature/flags; '' = none"),
        "counter_signal": M(
            help="the sample counter signal in both messages (pairs them, times the samples); '' = none"
        ),
        "crc_signal": M(help="the CRC-8/SAE-J1850 signal in the last byte; '' = none"),
        "rate_hz": M("Hz", "[1, 10000]", "nominal sample rate"),
    },
    "outputs[]": {
        "type": M(help="mavlink (MQTT is the [mqtt] table)", choices=("mavlink",), type="str", default="mavlink"),
        "name": M(help="the output's name (status view, counters)", nonempty=True, doc_default="mav<N>"),
        "url": M(
            help="udpout:HOST:PORT (send to), udpin:HOST:PORT (listen, answer the last sender), "
            "tcp:HOST:PORT (connect), tcpin:HOST:PORT (listen), serial:DEVICE:BAUD or DEVICE,BAUD (MAVProxy's grammar)"
        ),
        "role": M(
            help="gcs: a ground station view; fc: external navigation for a flight controller", choices=("gcs", "fc")
        ),
        "sysid": M("", "[1, 255]", "our MAVLink system id"),
        "compid": M("", "[0, 255]", "our MAVLink component id (197: MAV_COMP_ID_VISUAL_INERTIAL_ODOMETRY)"),
        "mav_type": M(help="HEARTBEAT vehicle type (MAV_TYPE_*)"),
        "signing_key": HEX_KEY,
        "rates": M(help="the [outputs.rates] table"),
        "params_file": M(help="parameter override file (MAV_CMD_PREFLIGHT_STORAGE); '' = <config>.params.toml"),
        "odometry_frame": M(
            help="ODOMETRY frame_id: LOCAL_NED (PX4) or LOCAL_FRD (ArduPilot accepts only this)",
            choices=("LOCAL_NED", "LOCAL_FRD"),
        ),
        "allowed_gcs_sysids": M(
            "",
            "[0, 255]",
            "system ids obeyed for PARAM_SET, parameter saves and state-changing commands (255: "
            "QGroundControl, MAVProxy; 245: MAVSDK); [] = none (read-only); [0] = any system",
            unique=True,
        ),
        "signing_key_file": M(
            help="file holding the signing key: a passphrase (its SHA-256, as MAVProxy and "
            "QGroundControl make it) or 64 hex digits, mode 0600; `ins-hil keygen` writes one; "
            "'' = signing_key",
            file=True,
        ),
        "param_encoding": M(
            help="INT32 parameters on the wire: bytewise (MAVSDK, QGroundControl), c_cast (MAVProxy, Mission Planner)",
            choices=("bytewise", "c_cast"),
        ),
    },
    "mqtt": {
        "enabled": M(help="publish state/fault/health to an MQTT broker (reconnects with backoff)"),
        "host": M(help="broker host", nonempty=True),
        "port": M("", "[1, 65535]", "broker port"),
        "topic_prefix": M(help="topics <prefix>/state, <prefix>/fault, <prefix>/health (no + or #)", nonempty=True),
        "state_rate": M("Hz", "0 | [0.01, 1000]", "state messages per second; 0 = none"),
        "health_period": M("s", "[0.01, 3600]", "period of the health message"),
        "client_id": M(help="MQTT client id; '' = generated"),
        "username": M(help="'' = anonymous"),
        "password": M(help="with username"),
        "tls": M(help="TLS to the broker"),
        "tls_ca": M(help="CA certificate file; '' = system CAs", file=True),
        "tls_cert": M(help="client certificate file; '' = none", file=True),
        "tls_key": M(help="client key file; '' = none", file=True),
        "tls_insecure": M(help="do not verify the broker's certificate nor its host name (tests only)"),
        "keepalive": M("s", "[1, 65535]", "MQTT keep-alive"),
    },
    "recorder": {
        "enabled": M(help="record every input to an .ihlog file (ins-hil replay reproduces the run)"),
        "dir": M(help="directory of the recordings (ins-hil-<time>.ihlog)", nonempty=True),
        "max_mb": M("MiB", "[0.01, 1048576]", "rotate files at this size"),
        "flush_period": M("s", "(0, 0.1]", "a killed process loses at most about this much"),
        "total_mb": M(
            "MiB", "[0.01, 16777216]", "all parts of one run; its oldest parts are deleted first (8192 ≈ 25 h at 1 kHz)"
        ),
        "dir_total_mb": M(
            "MiB", "[0, 16777216]", "every .ihlog in dir; other runs' oldest files deleted first; 0 = no limit"
        ),
    },
}

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


def sections() -> list[Section]:
    """Every section of a gateway configuration file, in the order of the docs."""
    from ins_hil import aids
    from ins_hil.config import GatewaySettings, InputConfig, RecorderConfig
    from ins_hil.core import NavConfig
    from ins_hil.core_parts.config import SECTIONS as NAV_SECTIONS
    from ins_hil.drivers.dbc_codec import DbcProfile
    from ins_hil.fdi.aiding import AidingConfig
    from ins_hil.fdi.monitor import FdiConfig
    from ins_hil.fusion.ekf import FilterConfig
    from ins_hil.runtime.mqtt_out import MqttConfig
    from ins_hil.runtime.pipeline import PipelineConfig
    from ins_hil.types import SimConfig
    from ins_hil.validation import Limits

    sim_keys = {"enabled": Key("enabled", "bool", False, **_help("sim", "enabled"))}
    sim_keys.update(dataclass_keys(SimConfig, "sim"))
    aid = {"enabled": Key("enabled", "bool", True, **_help("fdi.aiding", "enabled"))}
    aid.update(dataclass_keys(AidingConfig, "fdi.aiding"))
    core = dataclass_keys(PipelineConfig, "core", rename={"core": "kind"},
                          skip=("imu_ids", "fdi", "fdi_options", "aiding_fdi", "aiding_options", "limits"))  # fmt: skip
    # the validation limits (PipelineConfig.limits) are flat keys of [core]; the loader builds the Limits
    core.update({k: dataclasses.replace(v, attr=None) for k, v in dataclass_keys(Limits, "core").items()})
    nav = dataclass_keys(NavConfig, "core.nav", skip=("sources",))  # the sections are tables of their own
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
    fdi_opts = dataclass_keys(FdiConfig, "fdi.options")
    fdi_opts["geometry"] = dataclasses.replace(fdi_opts["geometry"], attr=None)
    return [
        Section("gateway", dataclass_keys(GatewaySettings, "gateway"), "The gateway process."),
        Section("core", core, "The navigation pipeline (ins_hil.runtime.pipeline.PipelineConfig)."),
        Section("core.nav", nav,
                "The navigation core (ins_hil.core.NavConfig; SI units, gates in σ)."),
        *(Section(f"core.nav.{k}", dataclass_keys(c, f"core.nav.{k}"), doc) for k, c, doc in nav_secs),
        Section("fdi", FDI_KEYS, "Inertial-sensor fault detection and isolation over redundant IMUs."),
        Section("fdi.options", fdi_opts, "The FDI monitor (ins_hil.fdi.monitor.FdiConfig); dt, gyro_noise and "
                "accel_noise are required when [fdi] enabled = true."),
        Section("fdi.aiding", aid, "The GNSS/baro drift monitor (ins_hil.fdi.aiding.AidingConfig)."),
        Section("sim", sim_keys, "The simulated sensors (ins_hil.types.SimConfig, read by ins_hil.sim.devices)."),
        Section("inputs[]", dataclass_keys(InputConfig, "inputs[]"), "One sensor input per [[inputs]] table."),
        Section("inputs[].options", CAN_OPTIONS, "A can_imu input's options (ins_hil.drivers.can_imu).", open=True),
        Section("inputs[].options.dbc", dataclass_keys(DbcProfile, "inputs[].options.dbc"),
                "protocol = 'dbc': which DBC messages and signals carry the IMU (ins_hil.drivers.dbc_codec)."),
        *_output_sections(),
        Section("mqtt", dataclass_keys(MqttConfig, "mqtt"), "The MQTT publisher (ins_hil.runtime.mqtt_out); "
                "without an [mqtt] table MQTT is off."),
        Section("recorder", dataclass_keys(RecorderConfig, "recorder"),
                "The input recorder (ins_hil.runtime.recorder)."),
    ]  # fmt: skip


def _output_sections() -> list[Section]:
    """The sections of the ``[[outputs]]`` tables: built without the core's imports, so that
    :func:`ins_hil.config.load_outputs` stays light (``ins-hil run`` opens the outputs first)."""
    from ins_hil.config import MAV_TYPES
    from ins_hil.runtime.mavlink_out import EndpointConfig

    out_keys = {"type": Key("type", **TABLES["outputs[]"]["type"])}
    out_keys.update(dataclass_keys(EndpointConfig, "outputs[]", skip=("rates",)))
    out_keys["rates"] = Key("rates", "table", None, optional=True, help="the [outputs.rates] table")
    out_keys["mav_type"] = dataclasses.replace(out_keys["mav_type"], choices=MAV_TYPES)
    return [
        Section("outputs[]", out_keys, "One MAVLink output per [[outputs]] table (ins_hil.runtime.mavlink_out)."),
        Section("outputs[].rates", rate_keys(), "Messages per second of one output (the defaults depend on role)."),
    ]


def _help(section: str, key: str) -> dict[str, Any]:
    return {"help": TABLES[section][key]["help"]}


_CACHE: dict[str, Section] = {}


def section(name: str) -> Section:
    """A section by its dotted name (``inputs[0].options`` → ``inputs[].options``)."""
    name = re.sub(r"\[\d+\]", "[]", name)
    if name not in _CACHE:
        light = name.startswith("outputs[]") and "gateway" not in _CACHE  # the outputs' alone: no core imported
        _CACHE.update({s.name: s for s in (_output_sections() if light else sections())})
    return _CACHE[name]


#: a list of known names longer than this is not spelt out in an error (the error stays one line)
KNOWN_LIST_MAX = 80


def known_hint(k: str, known: Iterable[str], section: str = "") -> str:
    """What to say about an unknown name ``k`` in one line: the close matches (``did you mean``), else the
    known names when they fit in :data:`KNOWN_LIST_MAX` characters, else how many there are and where
    they are documented (``section``: its name in docs/configuration.md, e.g. ``core.nav.filter``)."""
    names = sorted(known)
    near = difflib.get_close_matches(k, names, n=2)
    if near:
        return f"did you mean {' or '.join(repr(n) for n in near)}?"
    listed = ", ".join(names)
    if len(listed) <= KNOWN_LIST_MAX:
        return f"known: {listed}"
    sec = section.replace("[]", "")
    table = f"[[{sec}]]" if section.endswith("[]") and "." not in sec else f"[{sec}]"
    return f"{len(names)} known keys: docs/configuration.md, {table}" if section else f"{len(names)} known"


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
        "Every key of a gateway configuration file (`ins-hil run --config FILE`, TOML), generated from the schema",
        "(`ins_hil/config_schema.py`) by `ins-hil config --docs` (or `python -m ins_hil.config_schema`);",
        "`ins-hil config --check FILE` validates a file and prints `ok` or the error. See `configs/*.toml` for",
        "working examples.",
        "",
        "The whole file is validated before anything starts: every key typed and ranged, NaN and infinities",
        "rejected for every number, then the navigation pipeline, the MAVLink endpoints, the MQTT publisher and",
        "the input drivers are built (without opening a device). A problem is one line naming the file, the",
        "dotted key, the value and what is allowed, e.g.",
        "",
        "```",
        "ins-hil run: configs/my.toml: core.init_lat_deg = 900.0: expected a finite number in [-89, 89] °",
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
