"""The dataset config (``configs/datasets/*.toml``): what a replay of one recording needs besides the data.

Tables and keys (all optional except ``[dataset].name``; see ``docs/datasets.md``)::

    [dataset]  name, format (a reader of ins_hil.datasets.dataset.READERS; detected if absent),
               path (the recording, relative to this file), position_deg = [lat, lon, h] (where the log has
               no GNSS: the start point for the no-GNSS hold and the field model), rotary_wing = true | false
               (a multirotor: the replay's rotor-drag check; default: what the log says, off where it says nothing)
    [sensor]   grade = "mems" | "tactical"; any FilterConfig noise field to override the preset
    [mounting] imu_to_body_deg = [roll, pitch, yaw] (deg): the IMU's axes as seen from the body FRD axes, ZYX
               Euler angles (yaw about body z, then pitch, then roll), so that a vector read in the IMU's axes
               is v_b = C_s^b v_s with C_s^b = Rz(yaw) Ry(pitch) Rx(roll): yaw = +90 is an IMU whose x axis points
               to the body's right (+y), roll = 180 an IMU upside down (its z up); or a list of such rotations
               applied in turn, the first to the IMU axes: C_s^b = R_n … R_1. The readers' IMU and magnetometer
               data are in the IMU's axes (PX4 and ArduPilot log them already in body FRD: identity there);
               gnss_lever_arm_m (IMU → antenna,
               body FRD, m), reference_lever_arm_m, imu_time_offset_s (added to the IMU times),
               gnss_time_offset_s (added to the GNSS times, e.g. −0.11 for PX4's EKF2_GPS_DELAY)
    [aiding]   gnss, baro, mag (bool); mag_heading_only (bool, default true: the magnetometer corrects the heading
               only, levelled with the current attitude as EKF2 does in flight);
               mag_reference = "wmm" | "rest" | [N, E, D] (µT);
               declination_deg (with "rest"); no_gnss_hold (bool), hold_std_m, hold_vel_std_mps (0 = position
               only), hold_rate_hz
    [nav]      ins_hil.core.NavConfig: its sections ``[nav.gnss]``, ``[nav.baro]``, ``[nav.mag]``, ``[nav.aids]``,
               ``[nav.hold]``, ``[nav.alignment]``, ``[nav.delay]``, ``[nav.filter]`` (FilterConfig fields) and
               ``adaptive``/``adaptive_b``, as ``[core.nav]`` of the gateway config
               (``ins_hil.runtime.pipeline.nav_config``)
    [outages]  relative_to = "takeoff" | "start" | "first_gnss", start_s, on_s (outage), off_s (GNSS between),
               end_s (s from ``relative_to``), tail_s (the last outage ends ≥ tail_s before the last fix or the end)
    [fdi]      aiding (bool, default true): the gateway's GNSS/baro drift monitor (``ins_hil.fdi.aiding``, the
               ``[fdi.aiding]`` of a gateway config) on the replayed aiding, as the live pipeline runs it
    [score]    against = ["gnss", "onboard", "reference"], settle_s (s after the core starts navigating),
               min_fix_type (only fixes of this ins_hil.types.FixType or better are scored, e.g. 6 = RTK fixed)
    [rtklib]   file names and conventions of an RTKLIB recording (``ins_hil.datasets.rtklib``)
    [study]    the held-out checks of a tuned data set (``ins_hil.datasets.study``): validation_shifts_s,
               startup_restart_s, startup_score_until_s, whatif_baro = [[label, white m, drift m/√s], …],
               whatif_baro_datum_m; targets = {outage_h_rms_m, outage_h_max_m, gnss_h_rms_m, realtime_factor} and
               upstream = {outage_h_rms_m, outage_h_max_m, outage_v_rms_m} (the report's target and reference rows)

Errors are one line naming the file and the key.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ins_hil.core import NavConfig
from ins_hil.core_parts.config import MOVED
from ins_hil.datasets import rtklib
from ins_hil.fusion.ekf import FilterConfig
from ins_hil.nav.rotation import dcm_from_euler
from ins_hil.types import Vec

DEG = math.pi / 180.0
G0 = 9.80665

#: noise presets by sensor grade (FilterConfig fields). ``mems``: a consumer MEMS IMU on a vehicle with
#: motors (datasheet-class white noise: gyro 0.01 °/s/√Hz, accelerometer 150 µg/√Hz; bias instability of a
#: few °/h and mg drifting with temperature: Gauss–Markov 0.2 °/s and 5 mg over 300 s; large initial biases:
#: 0.5 °/s and 0.3 m/s²; vibration added from the measured sample-to-sample change, the same model as on
#: the car drive). ``tactical``: FilterConfig's defaults. :data:`GRADE_NAV`: NavConfig sections of the grade
#: (``mems``: the field direction of an uncompensated MEMS magnetometer near motors is good to ~0.15 per
#: unit-vector component, ≈ 9°: a residual hard iron of ~0.06 G against a 0.4–0.5 G field).
GRADES: dict[str, dict[str, Any]] = {
    "mems": {
        "gyro_arw": 0.01 * DEG,
        "accel_vrw": 150e-6 * G0,
        "gyro_bias_sigma": 0.2 * DEG,
        "gyro_bias_tau": 300.0,
        "accel_bias_sigma": 5e-3 * G0,
        "accel_bias_tau": 300.0,
        "init_gyro_bias": 0.5 * DEG,
        "init_accel_bias": 0.3,
        "gyro_vib_gain": 0.4,
        "accel_vib_gain": 0.6,
    },
    "tactical": {},
}

GRADE_NAV: dict[str, dict[str, Any]] = {"mems": {"mag": {"std": 0.15}}, "tactical": {}}

SCHEMA: dict[str, dict[str, type | tuple[type, ...]]] = {
    "dataset": {"name": str, "format": str, "path": str, "position_deg": list, "description": str,
                "rotary_wing": bool},
    "sensor": {"grade": str},  # + FilterConfig fields
    "mounting": {"imu_to_body_deg": list, "gnss_lever_arm_m": list, "reference_lever_arm_m": list,
                 "imu_time_offset_s": (int, float), "gnss_time_offset_s": (int, float)},
    "aiding": {"gnss": bool, "baro": bool, "mag": bool, "mag_heading_only": bool,
               "mag_reference": (str, list), "declination_deg": (int, float),
               "no_gnss_hold": bool, "hold_std_m": (int, float), "hold_vel_std_mps": (int, float),
               "hold_rate_hz": (int, float)},
    "nav": {},  # NavConfig sections (tables) and top-level keys
    "outages": {"relative_to": str, "start_s": (int, float), "on_s": (int, float), "off_s": (int, float),
                "end_s": (int, float), "tail_s": (int, float)},
    "fdi": {"aiding": bool},
    "score": {"against": list, "settle_s": (int, float), "min_fix_type": int},
    "rtklib": rtklib.OPTIONS,
    "study": {"validation_shifts_s": list, "startup_restart_s": (int, float), "startup_score_until_s": (int, float),
              "whatif_baro": list, "whatif_baro_datum_m": (int, float), "targets": dict, "upstream": dict},
}  # fmt: skip
RELATIVE_TO = ("takeoff", "start", "first_gnss")
#: the most outage windows a protocol may open on one log
MAX_WINDOWS = 10_000


class DatasetConfigError(ValueError):
    """A bad dataset config (one line: file, key, what was expected)."""


@dataclass
class OutageProtocol:
    """GNSS outages of ``on_s`` s every ``on_s + off_s`` s from ``start_s`` to ``end_s`` (s after the event
    ``relative_to``: "takeoff", "start" of the data or "first_gnss" fix; ``end_s`` None = the landing or the
    end), the last one ending at least ``tail_s`` s before that end."""

    relative_to: str = "takeoff"
    start_s: float = 20.0
    on_s: float = 10.0
    off_s: float = 20.0
    end_s: float | None = None
    tail_s: float = 0.0

    def windows(self, t_ref: float, t_end: float) -> list[tuple[float, float]]:
        """The outage windows (absolute s) that end at least ``tail_s`` before ``t_end``."""
        out: list[tuple[float, float]] = []
        a = t_ref + self.start_s
        stop = t_end - self.tail_s if self.end_s is None else min(t_end - self.tail_s, t_ref + self.end_s)
        step = self.on_s + self.off_s
        while a + self.on_s <= stop:
            if not (a < a + self.on_s and a < a + step) or len(out) >= MAX_WINDOWS:  # every loop advances
                raise ValueError(
                    f"outages: on_s = {self.on_s:g} s, off_s = {self.off_s:g} s from {a:g} s to {stop:g} s: "
                    f"more than {MAX_WINDOWS} windows or a step lost in the times' rounding"
                )
            out.append((a, a + self.on_s))
            a += step
        return out


@dataclass
class DatasetConfig:
    """A loaded dataset config (see the module docstring)."""

    name: str = "dataset"
    source: Path | None = None
    format: str | None = None
    path: Path | None = None
    position: tuple[float, float, float] | None = None  # rad, rad, m
    rotary_wing: bool | None = None  # None: the log's vehicle type
    grade: str = "mems"
    imu_to_body: Vec = field(default_factory=lambda: np.zeros((1, 3)))  # rad, (k, 3): rotations applied in turn
    gnss_lever_arm: Vec = field(default_factory=lambda: np.zeros(3))
    reference_lever_arm: Vec = field(default_factory=lambda: np.zeros(3))
    imu_time_offset: float = 0.0
    gnss_time_offset: float = 0.0
    use_gnss: bool = True
    use_baro: bool = True
    use_mag: bool = True
    mag_heading_only: bool = True
    mag_reference: str | Vec = "wmm"  # "wmm" | "rest" | NED µT
    declination: float = 0.0  # rad
    no_gnss_hold: bool = True
    hold_std: float = 10.0
    hold_vel_std: float = 1.0
    hold_rate: float = 5.0
    nav: dict[str, Any] = field(default_factory=dict)
    filter_overrides: dict[str, Any] = field(default_factory=dict)
    outages: OutageProtocol | None = None
    aiding_fdi: bool = True  # the gateway's aiding drift monitor in the replay's pipeline
    score: tuple[str, ...] = ("gnss", "onboard", "reference")
    settle_s: float = 0.0
    min_fix_type: int = 0
    rtklib: dict[str, Any] = field(default_factory=dict)
    study: dict[str, Any] = field(default_factory=dict)

    def mounting_dcm(self) -> Vec:
        """C_s^b, IMU axes → body FRD: the product R_n … R_1 of the ``imu_to_body`` rotations (ZYX Euler, book
        eq. 2.12), the first applied to the IMU axes first."""
        R = dcm_from_euler(*self.imu_to_body[0])
        for e in self.imu_to_body[1:]:
            R = dcm_from_euler(*e) @ R
        return R

    @property
    def rotated(self) -> bool:
        """Whether the mounting rotates the IMU axes at all."""
        return bool(np.any(self.imu_to_body != 0.0))

    def nav_config(self) -> NavConfig:
        """The NavConfig: the grade's preset, then ``[sensor]`` overrides, then ``[nav]`` (``[nav.filter]``)."""
        from ins_hil.runtime.pipeline import nav_config

        fk = dict(GRADES[self.grade])
        fk.update(self.filter_overrides)
        nav: dict[str, Any] = {"alignment": {"mode": "static"}, "gnss": {"lever_arm_b": list(self.gnss_lever_arm)}}
        for over in (GRADE_NAV[self.grade], {k: v for k, v in self.nav.items() if k != "filter"}):
            for k, v in over.items():  # a section's keys merge into the section
                nav[k] = {**nav.get(k, {}), **v} if isinstance(v, dict) and isinstance(nav.get(k), dict) else v
        fk.update(self.nav.get("filter", {}))
        nav["filter"] = {k: tuple(v) if isinstance(v, list) else v for k, v in fk.items()}  # TOML arrays → tuples
        try:
            cfg = nav_config(nav)
        except ValueError as e:
            raise DatasetConfigError(f"{self.source or self.name}: {str(e).replace('core.nav', 'nav')}") from None
        assert isinstance(cfg.filter, FilterConfig)
        return cfg


def _vec3(where: str, v: Any, source: str) -> Vec:
    if not (isinstance(v, list) and len(v) == 3 and all(isinstance(x, (int, float)) for x in v)):
        raise DatasetConfigError(f"{source}: {where} = {v!r}: expected 3 numbers")
    return np.array(v, dtype=np.float64)


#: the ranges of the numbers of the tables the dataset config defines itself ((table, key): (lo, hi), inclusive;
#: the ``[sensor]`` and ``[nav.*]`` keys are checked by the gateway's schema, ``ins_hil.config_schema``)
RANGES: dict[tuple[str, str], tuple[float, float]] = {
    ("mounting", "imu_time_offset_s"): (-3600.0, 3600.0),
    ("mounting", "gnss_time_offset_s"): (-3600.0, 3600.0),
    ("aiding", "declination_deg"): (-180.0, 180.0),
    ("aiding", "hold_std_m"): (1e-3, 1e4),
    ("aiding", "hold_vel_std_mps"): (0.0, 100.0),
    ("aiding", "hold_rate_hz"): (1e-3, 1000.0),
    ("outages", "start_s"): (-1e6, 1e6),
    ("outages", "end_s"): (-1e6, 1e6),
    ("outages", "on_s"): (0.01, 1e6),
    ("outages", "off_s"): (0.0, 1e6),
    ("outages", "tail_s"): (0.0, 1e6),
    ("score", "settle_s"): (0.0, 1e6),
    ("score", "min_fix_type"): (0, 6),
    ("rtklib", "time_calib_s"): (1e-3, 1e6),
    ("rtklib", "accel_lag_s"): (-1.0, 1.0),
    ("rtklib", "max_q"): (1, 6),
    ("study", "startup_restart_s"): (-1e6, 1e6),
    ("study", "startup_score_until_s"): (-1e6, 1e6),
    ("study", "whatif_baro_datum_m"): (-1e4, 1e4),
}
#: vectors: (table, key): the largest magnitude of a component
VECTOR_MAX = {("mounting", "imu_to_body_deg"): 360.0, ("mounting", "gnss_lever_arm_m"): 100.0,
              ("mounting", "reference_lever_arm_m"): 100.0, ("aiding", "mag_reference"): 1000.0}  # fmt: skip
#: the most rotations ``mounting.imu_to_body_deg`` may chain
MAX_ROTATIONS = 16


def _nonfinite(d: Any, where: str) -> str | None:
    """The dotted key of the first NaN / ±inf number in a TOML tree, None if none."""
    if isinstance(d, float) and not math.isfinite(d):
        return where
    if isinstance(d, dict):
        for k, v in d.items():
            bad = _nonfinite(v, f"{where}.{k}" if where else str(k))
            if bad:
                return bad
    if isinstance(d, list):
        for i, v in enumerate(d):
            bad = _nonfinite(v, f"{where}[{i}]")
            if bad:
                return bad
    return None


def _get(tree: dict[str, Any], where: str) -> Any:
    """The value at a dotted key with list indices (``mounting.imu_to_body_deg[1][0]``), for the message."""
    import re

    v: Any = tree
    for part in re.findall(r"[^.\[\]]+|\[\d+\]", where):
        v = v[int(part[1:-1])] if part.startswith("[") else v[part]
    return v


def check_values(d: dict[str, Any], source: str) -> None:
    """DatasetConfigError (one line: the file, the key, its value and what is allowed) for a number that is not
    finite or out of its range, a string with a NUL, or a ``[sensor]`` / ``[nav.*]`` key the gateway's schema
    (``ins_hil.config_schema``, the ``[core.nav]`` tables) refuses. The types are checked by :func:`from_dict`."""
    bad = _nonfinite(d, "")
    if bad:
        raise DatasetConfigError(f"{source}: {bad} = {_get(d, bad)!r}: expected a finite number")
    for (tab, key), (lo, hi) in RANGES.items():
        v = d.get(tab, {}).get(key) if isinstance(d.get(tab), dict) else None
        if isinstance(v, int | float) and not isinstance(v, bool) and not lo <= v <= hi:
            kind = "an integer" if isinstance(lo, int) else "a number"
            raise DatasetConfigError(f"{source}: {tab}.{key} = {v!r}: expected {kind} in [{lo:g}, {hi:g}]")
    for (tab, key), top in VECTOR_MAX.items():
        v = d.get(tab, {}).get(key) if isinstance(d.get(tab), dict) else None
        rows = v if isinstance(v, list) and v and all(isinstance(x, list) for x in v) else [v]
        if key == "imu_to_body_deg" and len(rows) > MAX_ROTATIONS:
            raise DatasetConfigError(f"{source}: {tab}.{key}: {len(rows)} rotations (at most {MAX_ROTATIONS})")
        for r in rows:
            if isinstance(r, list) and any(isinstance(x, int | float) and not abs(x) <= top for x in r):
                raise DatasetConfigError(f"{source}: {tab}.{key} = {r!r}: expected 3 numbers within ±{top:g}")
    ds = d.get("dataset")
    if isinstance(ds, dict):
        p = ds.get("position_deg")
        if isinstance(p, list) and len(p) == 3 and all(isinstance(x, int | float) for x in p):
            if not (-90 <= p[0] <= 90 and -180 <= p[1] <= 360 and -1000 <= p[2] <= 1e5):
                raise DatasetConfigError(f"{source}: dataset.position_deg = {p!r}: expected [lat −90…90°, "
                                         "lon −180…360°, h −1000…100000 m]")  # fmt: skip
    for tab, t in d.items():
        if isinstance(t, dict):
            for k, v in t.items():
                if isinstance(v, str) and (
                    "\0" in v or (k in ("name", "path", "imu_csv", "time_tag", "pos") and not v)
                ):
                    raise DatasetConfigError(f"{source}: {tab}.{k} = {v!r}: expected a non-empty text without NUL")
    _schema_tables(d, source)


def _schema_tables(d: dict[str, Any], source: str) -> None:
    """``[sensor]`` (FilterConfig fields) and ``[nav]`` through the gateway's schema (``[core.nav]``)."""
    from ins_hil import config_schema as schema
    from ins_hil.core_parts.config import SECTIONS

    def check(name: str, table: Any, where: str) -> None:
        keys = schema.section(name).keys
        if isinstance(table, dict):  # an unknown key is said by nav_config (where it moved, the known ones)
            table = {k: v for k, v in table.items() if k in keys}
        try:
            schema.validate(name, table, where)
        except ValueError as e:  # ConfigError is a ValueError
            raise DatasetConfigError(f"{source}: {' '.join(str(e).split())}") from None

    sensor = d.get("sensor")
    if isinstance(sensor, dict):
        check("core.nav.filter", {k: v for k, v in sensor.items() if k != "grade"}, "sensor")
    nav = d.get("nav")
    if isinstance(nav, dict):
        top = {k: v for k, v in nav.items() if k not in MOVED}
        check("core.nav", top, "nav")
        for k, v in top.items():
            if k == "filter" or k in SECTIONS:
                check(f"core.nav.{k}", v, f"nav.{k}")


def from_dict(d: dict[str, Any], source: str = "<dict>", base: Path | None = None) -> DatasetConfig:
    """Validate and build a DatasetConfig; DatasetConfigError (one line) on a bad key or value."""
    from dataclasses import fields

    filt = {f.name for f in fields(FilterConfig)}
    navk = {f.name for f in fields(NavConfig)}
    for tab, v in d.items():
        if tab not in SCHEMA:
            raise DatasetConfigError(f"{source}: unknown table [{tab}] (known: {', '.join(SCHEMA)})")
        if not isinstance(v, dict):
            raise DatasetConfigError(f"{source}: {tab} must be a table [{tab}]")
        extra = filt if tab == "sensor" else navk if tab == "nav" else set()
        for k, x in v.items():
            if tab == "nav" and k in MOVED:
                sec, new = MOVED[k]
                raise DatasetConfigError(f"{source}: [nav] {k} moved to [nav.{sec}] {new}")
            want = SCHEMA[tab].get(k)
            if want is None and k not in extra:
                known = sorted(set(SCHEMA[tab]) | extra)
                raise DatasetConfigError(f"{source}: unknown key {tab}.{k} (known: {', '.join(known)})")
            if want is not None and (not isinstance(x, want) or (want == (int, float) and isinstance(x, bool))):
                raise DatasetConfigError(f"{source}: {tab}.{k} = {x!r}: wrong type")
    check_values(d, source)
    ds = d.get("dataset")
    if ds is None or "name" not in ds:
        raise DatasetConfigError(f"{source}: missing key dataset.name (every dataset config names its data set)")
    c = DatasetConfig(name=ds["name"], source=Path(source) if source != "<dict>" else None)
    c.format = ds.get("format")
    if c.format is not None:
        from ins_hil.datasets.dataset import READERS, _load_builtin

        _load_builtin()
        if c.format not in READERS:
            raise DatasetConfigError(f"{source}: dataset.format = {c.format!r}: expected one of {', '.join(READERS)}")
    if "path" in ds:
        c.path = (base / ds["path"]).resolve() if base is not None else Path(ds["path"])
    c.rotary_wing = ds.get("rotary_wing")
    if "position_deg" in ds:
        p = _vec3("dataset.position_deg", ds["position_deg"], source)
        c.position = (p[0] * DEG, p[1] * DEG, float(p[2]))
    s = d.get("sensor", {})
    c.grade = s.get("grade", "mems")
    if c.grade not in GRADES:
        raise DatasetConfigError(f"{source}: sensor.grade = {c.grade!r}: expected one of {', '.join(GRADES)}")
    c.filter_overrides = {k: v for k, v in s.items() if k != "grade"}
    m = d.get("mounting", {})
    mb = m.get("imu_to_body_deg", [0, 0, 0])
    rots = mb if mb and all(isinstance(x, list) for x in mb) else [mb]
    c.imu_to_body = np.array([_vec3("mounting.imu_to_body_deg", r, source) * DEG for r in rots])
    c.gnss_lever_arm = _vec3("mounting.gnss_lever_arm_m", m.get("gnss_lever_arm_m", [0, 0, 0]), source)
    c.reference_lever_arm = _vec3("mounting.reference_lever_arm_m", m.get("reference_lever_arm_m", [0, 0, 0]), source)
    c.imu_time_offset = float(m.get("imu_time_offset_s", 0.0))
    c.gnss_time_offset = float(m.get("gnss_time_offset_s", 0.0))
    a = d.get("aiding", {})
    c.use_gnss, c.use_baro, c.use_mag = a.get("gnss", True), a.get("baro", True), a.get("mag", True)
    c.mag_heading_only = a.get("mag_heading_only", True)
    mr = a.get("mag_reference", "wmm")
    if isinstance(mr, list):
        c.mag_reference = _vec3("aiding.mag_reference", mr, source)
    elif mr not in ("wmm", "rest"):
        raise DatasetConfigError(f"{source}: aiding.mag_reference = {mr!r}: expected 'wmm', 'rest' or [N, E, D] µT")
    else:
        c.mag_reference = mr
    c.declination = float(a.get("declination_deg", 0.0)) * DEG
    c.no_gnss_hold = a.get("no_gnss_hold", True)
    c.hold_std = float(a.get("hold_std_m", 10.0))
    c.hold_rate = float(a.get("hold_rate_hz", 5.0))
    c.hold_vel_std = float(a.get("hold_vel_std_mps", 1.0))
    if c.hold_std <= 0 or c.hold_rate <= 0 or c.hold_vel_std < 0:
        raise DatasetConfigError(f"{source}: aiding.hold_std_m, hold_rate_hz must be > 0, hold_vel_std_mps >= 0")
    c.nav = dict(d.get("nav", {}))
    if "outages" in d:
        o = d["outages"]
        c.outages = OutageProtocol(o.get("relative_to", "takeoff"), float(o.get("start_s", 20.0)),
                                   float(o.get("on_s", 10.0)), float(o.get("off_s", 20.0)),
                                   float(o["end_s"]) if "end_s" in o else None,
                                   float(o.get("tail_s", 0.0)))  # fmt: skip
        if c.outages.relative_to not in RELATIVE_TO:
            raise DatasetConfigError(f"{source}: outages.relative_to = {c.outages.relative_to!r}: "
                                     f"expected one of {', '.join(RELATIVE_TO)}")  # fmt: skip
        if c.outages.on_s <= 0 or c.outages.off_s < 0 or c.outages.tail_s < 0:
            raise DatasetConfigError(f"{source}: outages.on_s must be > 0, off_s and tail_s >= 0")
    c.aiding_fdi = bool(d.get("fdi", {}).get("aiding", True))
    sc = d.get("score", {})
    c.score = tuple(sc.get("against", ["gnss", "onboard", "reference"]))
    if not all(isinstance(x, str) for x in c.score):
        raise DatasetConfigError(
            f"{source}: score.against = {list(c.score)!r}: expected names (gnss, onboard, reference)"
        )
    bad = set(c.score) - {"gnss", "onboard", "reference"}
    if bad:
        raise DatasetConfigError(f"{source}: score.against: unknown {sorted(bad)} (expected gnss, onboard, reference)")
    c.settle_s = float(sc.get("settle_s", 0.0))
    c.min_fix_type = int(sc.get("min_fix_type", 0))
    c.rtklib = dict(d.get("rtklib", {}))
    try:
        rtklib.check_options(c.rtklib, source)
    except ValueError as e:
        raise DatasetConfigError(str(e)) from None
    c.study = dict(d.get("study", {}))
    st = c.study
    if not all(isinstance(x, (int, float)) for x in st.get("validation_shifts_s", [])):
        raise DatasetConfigError(f"{source}: study.validation_shifts_s: expected numbers (s)")
    for w in st.get("whatif_baro", []):
        if not (isinstance(w, list) and len(w) == 3 and isinstance(w[0], str)
                and all(isinstance(x, (int, float)) and x >= 0 for x in w[1:])):  # fmt: skip
            raise DatasetConfigError(f"{source}: study.whatif_baro entry {w!r}: expected [label, white m, drift m/√s]")
    for tab, keys in (("targets", ("outage_h_rms_m", "outage_h_max_m", "gnss_h_rms_m", "realtime_factor")),
                      ("upstream", ("outage_h_rms_m", "outage_h_max_m", "outage_v_rms_m"))):  # fmt: skip
        v = st.get(tab)
        if v is not None and (set(v) != set(keys) or not all(isinstance(x, (int, float)) for x in v.values())):
            raise DatasetConfigError(f"{source}: study.{tab}: expected numbers for {', '.join(keys)}")
    if ("startup_restart_s" in st) != ("startup_score_until_s" in st):
        raise DatasetConfigError(f"{source}: study.startup_restart_s and startup_score_until_s go together")
    c.nav_config()  # every [nav] / [sensor] key checked now
    return c


def read_toml(path: str | Path, what: str = "dataset config") -> dict[str, Any]:
    """The tables of a TOML file; DatasetConfigError (one line) when it is missing or not TOML."""
    p = Path(path)
    try:
        return tomllib.loads(p.read_text())
    except FileNotFoundError:
        raise DatasetConfigError(f"{p}: no such {what}") from None
    except tomllib.TOMLDecodeError as e:
        raise DatasetConfigError(f"{p}: not valid TOML ({e})") from None


def merged(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    """``base`` with ``over`` merged in, table by table (a key of ``over`` replaces the one of ``base``;
    nested tables merge); neither is modified."""
    out = dict(base)
    for k, v in over.items():
        out[k] = merged(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def load(path: str | Path, overrides: dict[str, Any] | None = None, label: str = "") -> DatasetConfig:
    """Load and validate a dataset TOML, with ``overrides`` (tables as in the file, :func:`merged` over it;
    ``label`` names them in an error, e.g. a variant's)."""
    p = Path(path)
    d = read_toml(p)
    if overrides:
        d = merged(d, overrides)
    return from_dict(d, f"{p}{label}", p.resolve().parent)
