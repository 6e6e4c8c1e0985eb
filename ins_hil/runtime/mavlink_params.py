"""The gateway's tunable configuration as MAVLink parameters (PARAM_REQUEST_LIST / READ / SET).

Every MAVLink output endpoint serves the same navigation parameters (``NAV_*``, ``FLT_*``) and
its own message rates (``SR_*``, Hz; 0 = off). A PARAM_SET is checked by the config file's own
validation — the config object's ``revalidate`` (``ins_hil.config.from_dict``) of its ``document()``
with that one value changed; the runtime never imports the config module — and then:

- ``SR_*``: applied at once to that endpoint's stream (like MAV_CMD_SET_MESSAGE_INTERVAL);
- ``live`` navigation values (gates, measurement σ: read by the Python core at each update):
  applied to the running core between two pipeline calls (a plain attribute swap of its
  ``NavConfig``; the C core copies its configuration at start, so it refuses them). The
  recording's header keeps the configuration of the start: a replay of that run uses the
  start values (a warning says so);
- everything else (noise densities, aids, delay compensation: they shape the filter at its
  start) is refused at run time: set them in the config file.

Wire encoding (:func:`encode_wire`, :func:`decode_wire`): REAL32 values are the float itself; integer
parameters (INT32) are sent *bytewise* (PARAM_VALUE's float holds the int32's four bytes, as the
endpoint advertises with MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE in AUTOPILOT_VERSION): MAVSDK and
QGroundControl decode a non-ArduPilot vehicle's integers that way. MAVProxy decodes bytewise only for
PX4 autopilots, so it shows an INT32 parameter's raw float (1 reads 1.4e-45); its REAL32 values, and its
PARAM_SET of an integer (a REAL32 with an integral value, "C cast"), are read as meant. A PARAM_SET of
an integer type is decoded bytewise unless its float is itself a whole number below 2^24 (a C-cast
sender; an int32 sent bytewise is such a float only from 0x3F800000 = 1065353216 up).

A refused set is answered with PARAM_VALUE carrying the unchanged value (the MAVLink
parameter protocol's way to say no) and a STATUSTEXT with the reason. MAV_CMD_PREFLIGHT_STORAGE
(param1 = 1) writes the values that differ from the config file to the override file
(``<config>.params.toml`` beside the config, or an endpoint's ``params_file``; ``params_file = "off"``:
none, neither loaded nor written); it is loaded at start, validated the same way (a bad entry is a
ConfigError naming the file and the parameter), and announced (:meth:`ParamStore.announcement`: the
gateway's log names the file and every value it overrides; each ``gcs`` output gets a STATUSTEXT), so a
retune cannot stick silently. Writes are obeyed only from an allowed ground station
(``allowed_gcs_sysids``, :mod:`ins_hil.runtime.mavlink_msgs.requests`).
"""

from __future__ import annotations

import copy
import dataclasses
import math
import struct
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ins_hil.runtime.mavlink_out import ALL_MESSAGES
from ins_hil.types import ConfigError

#: MAV_PARAM_TYPE values used here
REAL32 = 9
INT32 = 6
#: MAV_PARAM_TYPE → struct code of the integer types (UINT8 … INT32; 64-bit types do not fit the float)
_INT_CODES = {1: "B", 2: "b", 3: "H", 4: "h", 5: "I", 6: "i"}


def encode_wire(value: float, ptype: int) -> float:
    """The PARAM_VALUE float of a parameter value: REAL32 as is, an integer type bytewise (the integer's
    little-endian bytes in the float's four bytes, the rest zero)."""
    code = _INT_CODES.get(ptype)
    if code is None:
        return float(value)
    raw = struct.pack("<" + code, int(value)).ljust(4, b"\x00")
    return float(struct.unpack("<f", raw)[0])


def decode_wire(wire: float, ptype: int) -> float:
    """The value of a PARAM_SET float of MAV_PARAM_TYPE ``ptype``: REAL32 (and the 64-bit types) as is; an
    integer type bytewise, except a whole number below 2^24, which a C-cast sender (MAVProxy, ArduPilot
    style) means as itself. A NaN's payload bits survive (Python floats keep them)."""
    code = _INT_CODES.get(ptype)
    if code is None:
        return float(wire)
    if math.isfinite(wire) and wire == int(wire) and wire != 0 and abs(wire) < 2**24:
        return float(wire)  # C cast
    raw = struct.pack("<f", wire)
    return float(struct.unpack("<" + code, raw[: struct.calcsize(code)])[0])


#: stream rate parameter name per message (≤ 16 characters)
RATE_PARAM = {
    "HEARTBEAT": "SR_HEARTBEAT",
    "SYS_STATUS": "SR_SYS_STATUS",
    "ATTITUDE": "SR_ATTITUDE",
    "ATTITUDE_QUATERNION": "SR_ATTITUDE_Q",
    "GLOBAL_POSITION_INT": "SR_GLOBAL_POS",
    "LOCAL_POSITION_NED": "SR_LOCAL_POS",
    "GPS_RAW_INT": "SR_GPS_RAW_INT",
    "VFR_HUD": "SR_VFR_HUD",
    "ESTIMATOR_STATUS": "SR_EST_STATUS",
    "EXTENDED_SYS_STATE": "SR_EXT_SYS_STATE",
    "BATTERY_STATUS": "SR_BATTERY",
    "HOME_POSITION": "SR_HOME_POS",
    "ODOMETRY": "SR_ODOMETRY",
    "GPS_INPUT": "SR_GPS_INPUT",
    "HIL_STATE_QUATERNION": "SR_HIL_STATE_Q",
}
assert set(RATE_PARAM) == set(ALL_MESSAGES)


@dataclass(frozen=True)
class NavParam:
    """One navigation parameter: its name, the ``[core.nav]`` key (``section.x``, e.g. ``gnss.gate`` or
    ``filter.gyro_arw``; ``section.k[i]`` for an element of a tuple), the MAV_PARAM_TYPE and whether it applies live."""

    name: str
    key: str
    ptype: int = REAL32
    live: bool = False
    doc: str = ""


NAV_PARAMS: tuple[NavParam, ...] = (
    NavParam("NAV_GATE_GNSS", "gnss.gate", live=True, doc="GNSS innovation gate (σ)"),
    NavParam("NAV_GATE_BARO", "baro.gate", live=True, doc="baro innovation gate (σ)"),
    NavParam("NAV_GATE_MAG", "mag.gate", live=True, doc="magnetometer innovation gate (σ)"),
    NavParam("NAV_GATE_AUX", "aids.gate", live=True, doc="NHC/ZUPT innovation gate (σ)"),
    NavParam("NAV_BARO_STD", "baro.std", live=True, doc="baro height σ (m)"),
    NavParam("NAV_MAG_STD", "mag.std", live=True, doc="magnetometer σ (unit-vector component)"),
    NavParam("NAV_GNSS_SCALE", "gnss.std_scale", live=True, doc="factor on the receiver's σ"),
    NavParam("NAV_GNSS_MIN_NE", "gnss.min_std[0]", live=True, doc="floor on the GNSS horizontal σ (m)"),
    NavParam("NAV_GNSS_MIN_D", "gnss.min_std[1]", live=True, doc="floor on the GNSS vertical σ (m)"),
    NavParam("NAV_GNSS_MIN_V", "gnss.min_std[2]", live=True, doc="floor on the GNSS velocity σ (m/s)"),
    NavParam("NAV_NHC_STD", "aids.nhc_std", live=True, doc="non-holonomic constraint σ (m/s)"),
    NavParam("NAV_ZUPT_STD", "aids.zupt_std", live=True, doc="zero-velocity update σ (m/s)"),
    NavParam("NAV_USE_GNSS_V", "gnss.use_vel", INT32, doc="fuse the GNSS velocity (0/1)"),
    NavParam("NAV_DELAY_COMP", "delay.compensation", INT32, doc="fuse late aids at their time (0/1)"),
    NavParam("NAV_NHC", "aids.nhc", INT32, doc="non-holonomic constraint (0/1)"),
    NavParam("NAV_ZUPT", "aids.zupt", INT32, doc="zero-velocity updates (0/1)"),
    NavParam("NAV_ADAPTIVE", "adaptive", INT32, doc="Sage–Husa adaptive R (0/1)"),
    NavParam("FLT_GYRO_ARW", "filter.gyro_arw", doc="gyro white noise (rad/s/√Hz)"),
    NavParam("FLT_ACCEL_VRW", "filter.accel_vrw", doc="accelerometer white noise (m/s²/√Hz)"),
    NavParam("FLT_GB_SIGMA", "filter.gyro_bias_sigma", doc="gyro bias Gauss–Markov σ (rad/s)"),
    NavParam("FLT_AB_SIGMA", "filter.accel_bias_sigma", doc="accelerometer bias Gauss–Markov σ (m/s²)"),
    NavParam("FLT_COV_EVERY", "filter.cov_every", INT32, doc="covariance propagation every N IMU steps"),
)
_NAV_BY_NAME = {p.name: p for p in NAV_PARAMS}


def _split(key: str) -> tuple[str | None, str, int | None]:
    """(section or None, field, tuple index or None) of a parameter key (``gnss.min_std[0]``, ``adaptive``)."""
    sec, _, rest = key.rpartition(".")
    i = None
    if rest.endswith("]"):
        rest, n = rest[:-1].split("[")
        i = int(n)
    return sec or None, rest, i


def _nav_get(nav: dict[str, Any], key: str, default: Any) -> Any:
    """A ``[core.nav]`` value by parameter key (``section.x``, ``section.k[i]``), else the NavConfig default."""
    sec, k, i = _split(key)
    table, dflt = (nav.get(sec) or {}, getattr(default, sec)) if sec else (nav, default)
    v = table.get(k, getattr(dflt, k))
    return tuple(v)[i] if i is not None else v


def _nav_set(nav: dict[str, Any], key: str, value: Any, default: Any) -> None:
    sec, k, i = _split(key)
    if sec:
        nav[sec] = table = dict(nav.get(sec) or {})
        dflt = getattr(default, sec)
    else:
        table, dflt = nav, default
    if i is not None:
        t = list(table.get(k, getattr(dflt, k)))
        t[i] = value
        value = t
    table[k] = value


class ParamError(ValueError):
    """A refused parameter change (the message says why)."""


class ParamStore:
    """The parameters of one gateway (see the module docstring).

    ``cfg``: the configuration to run, i.e. the given one with the override file applied.
    :meth:`attach` connects the running endpoints and pipeline (rates, live navigation values).
    """

    def __init__(self, cfg: Any, path: str | Path | None = None) -> None:
        from ins_hil.core import NavConfig

        self._nav_default = NavConfig()
        self.base = cfg
        self.cfg = cfg
        self.doc = cfg.document()
        # what the override file is the difference to (copies: the running pipeline's dict is changed live)
        self._base_doc = copy.deepcopy(self.doc)
        self._base_rates = [o.effective_rates() for o in cfg.outputs]
        self.writable = True
        self.why_readonly = ""
        try:  # the document must give back exactly this configuration, else sets would change other keys
            back = self._validate(self.doc)
            if back.to_dict() != cfg.to_dict():
                raise ValueError("the configuration does not round-trip through its document")
        except Exception as e:
            self.writable, self.why_readonly = False, f"parameters read-only: {e}"
        self.off = not path and self._params_file(cfg) == PARAMS_OFF  # params_file = "off": no override file
        self.path = Path(path) if path else self._default_path(cfg)
        self.endpoints: list[Any] = []
        self.pipeline: Any = None
        self.warnings: list[str] = []
        self.changed: dict[str, Any] = {}  # name (``SR_X@endpoint`` for rates) → value set at run time
        self.loaded: dict[str, Any] = {}  # what the override file set at start: name (``SR_X@endpoint``) → value
        if self.path is not None and self.path.is_file():
            self._load(self.path)

    @staticmethod
    def _params_file(cfg: Any) -> str:
        """The first output's non-empty ``params_file`` ('' = none given)."""
        return next((o.params_file for o in cfg.outputs if getattr(o, "params_file", "")), "")

    @classmethod
    def _default_path(cls, cfg: Any) -> Path | None:
        given = cls._params_file(cfg)
        if given:
            return None if given == PARAMS_OFF else Path(given)
        src = Path(cfg.source) if cfg.source else None
        if src is not None and src.suffix == ".toml" and src.is_file():
            return src.with_name(src.stem + ".params.toml")
        return None

    def _validate(self, doc: dict[str, Any]) -> Any:
        return self.base.revalidate(doc)

    # -- the parameter table of one endpoint ------------------------------------------
    def names(self, ep_index: int) -> list[str]:
        """Parameter names served on endpoint ``ep_index`` (navigation first, then its rates)."""
        return [p.name for p in NAV_PARAMS] + [RATE_PARAM[m] for m in ALL_MESSAGES]

    def _ep_doc(self, doc: dict[str, Any], ep_index: int) -> dict[str, Any]:
        return doc["outputs"][ep_index]

    def get(self, ep_index: int, name: str) -> tuple[float, int]:
        """(value, MAV_PARAM_TYPE) of a parameter; KeyError when unknown."""
        p = _NAV_BY_NAME.get(name)
        if p is not None:
            v = _nav_get(self.doc["core"]["nav"], p.key, self._nav_default)
            return (float(int(v)) if p.ptype == INT32 else float(v)), p.ptype
        for m, n in RATE_PARAM.items():
            if n == name:
                o = self._ep_doc(self.doc, ep_index)
                role_rates = self.cfg.outputs[ep_index].effective_rates()
                return float(o.get("rates", {}).get(m, role_rates.get(m, 0.0))), REAL32
        raise KeyError(name)

    def set(self, ep_index: int, name: str, value: float, ptype: int) -> float:
        """Validate and apply a PARAM_SET; returns the value now in force. Raises ParamError
        (the reason) or KeyError (unknown name); nothing changes then."""
        want = self.get(ep_index, name)[1]
        value = decode_wire(value, ptype)
        if not self.writable:
            raise ParamError(self.why_readonly)
        # REAL32 parameters take REAL32 only; INT32 ones any integer type (decoded by decode_wire) or REAL32 with
        # an integral value (the float of the integer, as MAVProxy sends)
        if (want == REAL32 and ptype != REAL32) or (want == INT32 and ptype not in (1, 2, 3, 4, 5, 6, 7, 8, REAL32)):
            raise ParamError(f"{name}: wrong type ({'INT32' if want == INT32 else 'REAL32'} expected)")
        if want == INT32 and math.isfinite(value) and value != int(value):
            raise ParamError(f"{name}: wrong type ({value:g} is no integer)")
        if not math.isfinite(value):
            raise ParamError(f"{name}: not a finite number")
        value = _f32_decimal(value)
        doc = copy.deepcopy(self.doc)
        p = _NAV_BY_NAME.get(name)
        if p is not None:
            if p.ptype == INT32:
                if value != int(value):
                    raise ParamError(f"{name}: {value} is not an integer")
                kind = type(_nav_get(doc["core"]["nav"], p.key, self._nav_default))
                v: Any = bool(int(value)) if kind is bool else int(value)
                if kind is bool and int(value) not in (0, 1):
                    raise ParamError(f"{name}: {int(value)} must be 0 or 1")
            else:
                v = float(value)
            _nav_set(doc["core"]["nav"], p.key, v, self._nav_default)
        else:
            msg = next(m for m, n in RATE_PARAM.items() if n == name)
            if value < 0:
                raise ParamError(f"{name}: a rate is ≥ 0 Hz")
            self._ep_doc(doc, ep_index).setdefault("rates", {})[msg] = float(value)
        try:
            new = self._validate(doc)
        except Exception as e:
            raise ParamError(f"{name}: {e}") from None
        if p is not None and v != _nav_get(self.doc["core"]["nav"], p.key, self._nav_default):
            self._apply_nav(p, new)
        self.doc, self.cfg = doc, new
        if p is None and self.endpoints:
            ep = self.endpoints[ep_index]
            ep.set_rate(msg, float(value))
        key = name if p is not None else f"{name}@{self.cfg.outputs[ep_index].name}"
        self.changed[key] = self.get(ep_index, name)[0]
        return self.get(ep_index, name)[0]

    def _apply_nav(self, p: NavParam, new: Any) -> None:
        """A navigation value on the running core (between two pipeline calls: a safe point)."""
        if not self.endpoints:  # not running (loading the override file): the core starts with it
            return
        if not p.live:
            raise ParamError(f"{p.name}: needs a restart (set it in the config)")
        pipe = self.pipeline
        core = getattr(pipe, "core", None) if pipe is not None else None
        if pipe is not None and pipe.cfg.core != "python":
            raise ParamError(f"{p.name}: C core: needs a restart")
        if core is not None:
            ncfg = getattr(core, "cfg", None)
            if ncfg is None or type(ncfg).__name__ != "NavConfig":
                raise ParamError(f"{p.name}: this core: needs a restart")
            fresh = new.pipeline.nav  # built once by the loader
            sec, k, _ = _split(p.key)
            if sec is None:
                core.cfg = dataclasses.replace(ncfg, **{k: getattr(fresh, k)})
            else:
                sub = dataclasses.replace(getattr(ncfg, sec), **{k: getattr(getattr(fresh, sec), k)})
                core.cfg = dataclasses.replace(ncfg, **{sec: sub})
        if pipe is not None:
            pipe.cfg.nav = copy.deepcopy(new.pipeline.nav)
        self.warnings.append(f"{p.name} applied to the running core (a replay of the recording uses the start value)")

    # -- running gateway ---------------------------------------------------------------
    def attach(self, endpoints: list[Any], pipeline: Any = None) -> None:
        """Serve the parameters on ``endpoints`` (index = position in ``cfg.outputs``)."""
        self.endpoints = list(endpoints)
        self.pipeline = pipeline
        for i, ep in enumerate(self.endpoints):
            ep.params = self
            ep.params_index = i
        if self.loaded:  # the ground stations see that the start values are not the config file's
            texts = [f"params: {len(self.loaded)} override(s) from {self.path.name if self.path else '?'}"]
            texts += [f"param override {k} = {_num(v)}" for k, v in list(self.loaded.items())[:_MAX_TEXTS]]
            if len(self.loaded) > _MAX_TEXTS:
                texts.append(f"... and {len(self.loaded) - _MAX_TEXTS} more overrides (see the log)")
            for ep in self.endpoints:
                if ep.cfg.role == "gcs":
                    for t in texts:
                        ep.statustext(4, t)  # MAV_SEVERITY_WARNING

    def announcement(self) -> str:
        """The start-up log line of the override file: its path and every value it overrides ('' = none loaded)."""
        if not self.loaded:
            return ""
        vals = ", ".join(f"{k} = {_num(v)}" for k, v in self.loaded.items())
        return (f"parameter override file {self.path} loaded (MAV_CMD_PREFLIGHT_STORAGE; delete it, or set "
                f"params_file = 'off', to run the config's values): {vals}")  # fmt: skip

    # -- override file -------------------------------------------------------------------
    def overrides(self) -> dict[str, Any]:
        """The values that differ from the configuration given at start, as the override document."""
        out: dict[str, Any] = {}
        base = self._base_doc
        for p in NAV_PARAMS:
            a = _nav_get(base["core"]["nav"], p.key, self._nav_default)
            b = _nav_get(self.doc["core"]["nav"], p.key, self._nav_default)
            if a != b:
                out[p.name] = int(b) if p.ptype == INT32 else float(b)
        for i, o in enumerate(self.cfg.outputs):
            r0, r1 = self._base_rates[i], o.effective_rates()
            for m, n in RATE_PARAM.items():
                if r0.get(m, 0.0) != r1.get(m, 0.0):
                    out.setdefault(o.name, {})[n] = float(r1.get(m, 0.0))
        return out

    def save(self) -> Path:
        """Write the override file (raises OSError or ParamError when there is no path)."""
        if self.path is None:
            if self.off:
                raise ParamError("params_file = 'off'")
            raise ParamError("no override file: the config is not a file and no endpoint sets params_file")
        lines = [f"# ins-hil parameter overrides of {self.base.source or 'the config'} (MAV_CMD_PREFLIGHT_STORAGE)"]
        lines.append("[params]")
        ov = self.overrides()
        for k, v in ov.items():
            if not isinstance(v, dict):
                lines.append(f"{k} = {v!r}")
        for k, v in ov.items():
            if isinstance(v, dict):
                lines.append(f"[params.{_toml_key(k)}]")
                lines.extend(f"{n} = {x!r}" for n, x in v.items())
        tmp = self.path.with_name(self.path.name + ".tmp")
        tmp.write_text("\n".join(lines) + "\n")
        tmp.replace(self.path)
        return self.path

    def _load(self, path: Path) -> None:
        try:
            d = tomllib.loads(path.read_text()).get("params", {})
        except (OSError, tomllib.TOMLDecodeError) as e:
            raise ConfigError(f"{path}: {e}") from None
        names = {o.name: i for i, o in enumerate(self.cfg.outputs)}
        items: list[tuple[int, str, Any]] = []
        for k, v in d.items():
            if isinstance(v, dict):
                if k not in names:
                    raise ConfigError(f"{path}: [params.{k}]: no MAVLink output named {k!r}")
                items.extend((names[k], n, x) for n, x in v.items())
            else:
                items.append((0, k, v))
        for i, n, v in items:
            if isinstance(v, bool) or not isinstance(v, int | float):
                raise ConfigError(f"{path}: {n} = {v!r}: expected a number")
            try:
                self.get(i, n)  # KeyError when unknown
                self.set(i, n, float(v), REAL32)  # a number, not a wire value: integers as their float
            except KeyError:
                raise ConfigError(f"{path}: unknown parameter {n!r}") from None
            except ParamError as e:
                raise ConfigError(f"{path}: {e}") from None
        self.loaded = dict(self.changed)
        self.changed.clear()


#: ``params_file`` value that switches the override file off (nothing loaded at start, saves refused)
PARAMS_OFF = "off"
_MAX_TEXTS = 8  # STATUSTEXTs naming overridden values at start (the log names all of them)


def _num(v: Any) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)


def _f32_decimal(x: float) -> float:
    """The shortest decimal of a float32 wire value (PARAM_SET 0.8 arrives as 0.800000011920929): the
    value a user typed, for the configuration and the override file."""
    import numpy as np

    return float(str(np.float32(x)))


def _toml_key(k: str) -> str:
    return k if k.replace("_", "").replace("-", "").isalnum() else '"' + k.replace('"', '\\"') + '"'
