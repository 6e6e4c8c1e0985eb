"""Airspeed aid (fixed-wing): the true airspeed against the ground velocity and the filter's wind states.

A pitot-static airspeed sensor gives the true airspeed (TAS, m/s; its indicated → true conversion with the
air density is the driver's) V = |v − w|, w = (w_N, w_E, 0) the horizontal wind (``FilterConfig.wind_states``,
shared with the multirotor drag aid), as PX4's EKF2 airspeed fusion without sideslip. With GNSS velocity and
turns the wind is observable; without GNSS the airspeed holds the velocity along the air-relative track.

Linearisation (δv = true − computed, δw = w − ŵ; u = v̂ − ŵ): z = Ṽ − |u| = (u/|u|)^T δv − (u_NE/|u|)^T δw,
H_v = u^T/|u|, H_w = −u_NE^T/|u| (no attitude term). Not fused below ``min_airspeed`` (a pitot is blind at
low speed; the linearisation too).

Config ``[core.nav.airspeed]`` (:class:`AirspeedConfig`; needs ``filter.wind_states``); sample
:class:`AirspeedSample`; record type 6.

Inputs (:meth:`AirspeedSource.decoders`, handed to the drivers by the runtime when the aid is enabled):

- MAVLink ``AIRSPEED`` (295: ``airspeed`` the calibrated airspeed CAS, m/s, ``temperature`` cdegC, ``flags``;
  ``AIRSPEED_SENSOR_UNHEALTHY`` refused): TAS = CAS·√(ρ0/ρ) (:func:`eas2tas`, CAS ≈ EAS below ~100 m/s), ρ from
  the last ``SCALED_PRESSURE`` static pressure of the same link (at most 5 s old) and the message's temperature
  (ISA temperature at that pressure when outside −60…+60 °C). Timed at its arrival (no time field).
- MAVLink ``VFR_HUD`` only with ``vfr_hud = true`` and while the link sends no ``AIRSPEED``: its ``airspeed``
  is not always a measured airspeed. ArduPilot (``libraries/GCS_MAVLink/GCS_Common.cpp``,
  ``GCS_MAVLINK::vfr_hud_airspeed``) sends ``AP_Airspeed::get_airspeed()`` (EAS) when the sensor is healthy and
  the GPS ground speed otherwise; PX4 (``src/modules/mavlink/streams/VFR_HUD.hpp``) sends
  ``airspeed_validated.calibrated_airspeed_m_s`` (CAS, 0 without the topic). Converted as ``AIRSPEED``'s CAS
  with the ISA temperature.
- DroneCAN ``uavcan.equipment.air_data.TrueAirspeed`` (1020): ``true_airspeed`` (m/s) and its variance as σ,
  timed at its arrival.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar, Literal

import numpy as np

from ins_hil.core_parts.contract import Measurement
from ins_hil.settings import check_fields
from ins_hil.types import Vec

from . import Aid, AidSource

if TYPE_CHECKING:
    from ins_hil.fusion.ekf import StateIndex

#: the validation boundary's airspeed limit (m/s)
TAS_MAX = 400.0


@dataclass(slots=True)
class AirspeedSample:
    """True airspeed (m/s, ≥ 0) valid at ``t`` (s); ``sigma``: its 1-σ (m/s; NaN = ``airspeed.std``)."""

    kind: ClassVar[Literal["airspeed"]] = "airspeed"
    t: float
    tas_mps: float
    sigma: float = math.nan
    source: int = 0
    t_arrival_ns: int = 0


@dataclass
class AirspeedConfig:
    """The airspeed sensor (``[core.nav.airspeed]``): ``enabled`` (needs ``filter.wind_states``); ``std``: TAS noise
    (m/s, 1-σ, when the sample carries none); ``gate`` (σ); ``min_airspeed``: not fused below (m/s)."""

    enabled: bool = field(default=False, metadata={"help": "fuse the true airspeed (needs filter.wind_states)"})
    std: float = field(
        default=0.5,
        metadata={"unit": "m/s", "range": "(0, 100)", "help": "airspeed noise (1-σ) when the sample carries none"},
    )
    gate: float = field(default=5.0, metadata={"unit": "σ", "range": "(0, 100)", "help": "innovation gate"})
    min_airspeed: float = field(
        default=5.0, metadata={"unit": "m/s", "range": "(0, 400)", "help": "not fused below this airspeed"}
    )
    vfr_hud: bool = field(
        default=False,
        metadata={"help": "MAVLink input: take VFR_HUD.airspeed when the link sends no AIRSPEED (ArduPilot sends "
                  "the GPS ground speed there without a healthy airspeed sensor)"},
    )  # fmt: skip

    def __post_init__(self) -> None:
        check_fields(self, "NavConfig.airspeed")  # the ranges of the fields' metadata (docs/configuration.md)


def true_airspeed(idx: StateIndex, vel: Vec, wind_ne: Vec, tas: float) -> tuple[Vec, Vec]:
    """(z, H) of a true airspeed ``tas`` (m/s) with the velocity ``vel`` (NED m/s) and wind ``wind_ne`` (m/s)."""
    from ins_hil.fusion import generated_jacobians as gj  # the models: not at import (as aids/vehicle.py)
    from ins_hil.fusion import measurements as mm

    u = np.array((float(vel[0]) - float(wind_ne[0]), float(vel[1]) - float(wind_ne[1]), float(vel[2])))
    n = float(np.linalg.norm(u))
    return np.array((tas - n,)), mm.placed_ext(gj.H_airspeed(u), idx, (idx.wind, 2))


#: ISA sea-level density (kg/m³), pressure (Pa), temperature (K); dry-air gas constant (J/(kg·K))
RHO0, P0, T0, R_AIR = 1.225, 101325.0, 288.15, 287.05287
#: the exponent of the ISA troposphere's T(p) = T0 (p/P0)^(R L/g), L = 6.5 K/km
_ISA_EXP = R_AIR * 0.0065 / 9.80665
#: the oldest static pressure a MAVLink airspeed is converted with (s)
PRESSURE_MAX_AGE_S = 5.0
AIRSPEED_SENSOR_UNHEALTHY = 1  # MAVLink AIRSPEED_SENSOR_FLAGS


def isa_temperature(pressure_pa: float) -> float:
    """The ISA temperature (K) at static pressure ``pressure_pa`` (Pa; troposphere, ≥ 216.65 K)."""
    return max(216.65, T0 * (pressure_pa / P0) ** _ISA_EXP)


def eas2tas(pressure_pa: float, temp_k: float) -> float:
    """TAS/EAS = √(ρ0/ρ), ρ = p/(R T): static pressure ``pressure_pa`` (Pa), air temperature ``temp_k`` (K)."""
    return math.sqrt(RHO0 * R_AIR * temp_k / pressure_pa)


def tas_from_eas(
    t: Vec, eas: Vec, t_p: Vec, p: Vec, temp_c: Vec | None = None, source: int = 0
) -> list[AirspeedSample]:
    """True airspeeds (logs) of the equivalent (≈ calibrated) airspeeds ``eas`` (m/s) at ``t`` (s): each with the
    last static pressure ``p`` (Pa, at ``t_p``, increasing) at most :data:`PRESSURE_MAX_AGE_S` before it and the
    air temperature ``temp_c`` (°C; None or outside −60…+60 °C: the ISA temperature at that pressure); samples
    without a pressure, or non-finite, are left out."""
    t, eas, t_p, p = (np.asarray(x, dtype=np.float64) for x in (t, eas, t_p, p))
    k = np.searchsorted(t_p, t, "right") - 1
    out = []
    for i in range(len(t)):
        j = int(k[i])
        if j < 0 or not (t[i] - t_p[j] <= PRESSURE_MAX_AGE_S and 100.0 <= p[j] <= 120_000.0):
            continue
        if not (math.isfinite(t[i]) and math.isfinite(eas[i])):
            continue
        tc = float(temp_c[i]) if temp_c is not None else math.nan
        tk = tc + 273.15 if -60.0 <= tc <= 60.0 else isa_temperature(float(p[j]))
        out.append(AirspeedSample(float(t[i]), float(eas[i]) * eas2tas(float(p[j]), tk), source=source))
    return out


class _MavlinkAirspeed:
    """One MAVLink link's airspeed decoders: the static pressure of its ``SCALED_PRESSURE`` kept for the density."""

    def __init__(self, cfg: AirspeedConfig) -> None:
        self.cfg = cfg
        self.p, self.t_p = math.nan, -math.inf
        self.seen_airspeed = False  # the link sends AIRSPEED: VFR_HUD is not used

    def table(self) -> dict[Any, Any]:
        out: dict[Any, Any] = {"SCALED_PRESSURE": self.pressure, "AIRSPEED": self.airspeed}
        if self.cfg.vfr_hud:
            out["VFR_HUD"] = self.vfr_hud
        return out

    def pressure(self, m: Any, t: float, arrival_ns: int) -> None:
        p = m.press_abs * 100.0
        if 100.0 <= p <= 120_000.0:
            self.p, self.t_p = p, t
        return None

    def tas(self, cas: float, temp_c: float, t: float, source: int, arrival_ns: int) -> AirspeedSample | str:
        if not math.isfinite(cas):
            return "nonfinite"
        if not (math.isfinite(self.p) and abs(t - self.t_p) <= PRESSURE_MAX_AGE_S):
            return "airspeed_no_pressure"
        tk = temp_c + 273.15 if -60.0 <= temp_c <= 60.0 else isa_temperature(self.p)
        return AirspeedSample(t, cas * eas2tas(self.p, tk), source=source, t_arrival_ns=arrival_ns)

    def airspeed(self, m: Any, t: float, arrival_ns: int) -> AirspeedSample | str:
        self.seen_airspeed = True
        if m.flags & AIRSPEED_SENSOR_UNHEALTHY:
            return "airspeed_unhealthy"
        return self.tas(m.airspeed, m.temperature * 0.01, t, m.id, arrival_ns)

    def vfr_hud(self, m: Any, t: float, arrival_ns: int) -> AirspeedSample | str | None:
        if self.seen_airspeed:
            return None
        return self.tas(m.airspeed, math.nan, t, 0, arrival_ns)


def _dronecan_true_airspeed(v: dict[str, Any], t: float, arrival_ns: int) -> AirspeedSample | str:
    """``uavcan.equipment.air_data.TrueAirspeed``: m/s and its variance (m²/s²; ≤ 0 or NaN: the configured σ)."""
    tas, var = float(v["true_airspeed"]), float(v["true_airspeed_variance"])
    if not math.isfinite(tas):
        return "nonfinite"
    sd = math.sqrt(var) if math.isfinite(var) and var > 0.0 else math.nan
    return AirspeedSample(t, tas, sd, source=int(v.get("source_node", 0)) & 0xFF, t_arrival_ns=arrival_ns)


class AirspeedAid(Aid):
    def __init__(self, core: Any, cfg: AirspeedConfig) -> None:
        self.core, self.cfg = core, cfg

    def fuse(self, meas: AirspeedSample, assume_now: bool = False) -> Iterator[None]:
        core, c = self.core, self.cfg
        v = core.ins.state.vel_ned
        if meas.tas_mps < c.min_airspeed or math.hypot(float(v[0]) - float(core.wind[0]),
                                                       float(v[1]) - float(core.wind[1])) < c.min_airspeed:  # fmt: skip
            return
        sd = meas.sigma if meas.sigma > 0.0 else c.std
        z, H = true_airspeed(core.idx, v, core.wind, meas.tas_mps)
        bias, var = self._second_order(v, meas.tas_mps - float(z[0]))
        core._apply(Measurement("airspeed", z - bias, H, np.array((sd * sd + var,)), c.gate), meas.t)
        yield from ()

    def _second_order(self, v: Vec, u_norm: float) -> tuple[float, float]:
        """The second-order terms of TAS = |u|, u = v − w, in the uncertainty of u across its direction (σ_c²: the
        horizontal velocity's and the wind's covariance, across û): the expected |u| is larger by σ_c²/(2|u|) and
        its linearisation misses ½(σ_c²/|u|)² of variance (a Gaussian second-order filter; the Hessian of |u| is
        (I − ûûᵀ)/|u|). Both vanish once the wind is learnt; before, with a wind prior of metres per second at a
        low airspeed, the first-order update is overconfident: the wind σ fell to 0.1 m/s with the wind 5 m/s off
        and the pulled velocity made the GNSS drift monitor exclude the receiver (simulated fixed-wing, seed 2).
        Returns (bias m/s, variance m²/s²)."""
        core = self.core
        iw, iv = core.idx.wind, core.idx.vel
        P = core.kf.P
        uh = np.array((float(v[0]) - float(core.wind[0]), float(v[1]) - float(core.wind[1])))
        n = float(np.linalg.norm(uh))
        if iw is None or n <= 0.0:
            return 0.0, 0.0
        e = np.array((-uh[1], uh[0])) / n
        pv, pw, pvw = P[iv : iv + 2, iv : iv + 2], P[iw : iw + 2, iw : iw + 2], P[iv : iv + 2, iw : iw + 2]
        sc2 = float(e @ (pv + pw - pvw - pvw.T) @ e)
        return 0.5 * sc2 / u_norm, 0.5 * (sc2 / u_norm) ** 2


class AirspeedSource(AidSource):
    name = "airspeed"
    sample = AirspeedSample
    record = 6
    record_fmt = "3dqB"  # t, tas_mps, sigma, t_arrival_ns, source
    reasons = ("airspeed_nonfinite", "airspeed_range")
    kinds = ("airspeed",)
    section = AirspeedConfig

    def check(self, s: AirspeedSample) -> None:
        super().check(s)
        if not abs(s.tas_mps) < math.inf:
            raise ValueError(f"NavCore.fuse: AirspeedSample.tas_mps = {s.tas_mps!r}: must be a finite number")

    def validate(self, v: Any, s: AirspeedSample) -> str | None:
        """Time and airspeed finite, σ NaN or finite > 0; 0 ≤ TAS ≤ :data:`TAS_MAX`."""
        if not (math.isfinite(s.t) and math.isfinite(s.tas_mps)) or not (math.isnan(s.sigma) or s.sigma > 0.0):
            return "airspeed_nonfinite"
        if s.sigma == math.inf:
            return "airspeed_nonfinite"
        if not 0.0 <= s.tas_mps <= TAS_MAX:
            return "airspeed_range"
        return None

    csv_kind, csv_columns, csv_required = "airspeed", ("tas", "sigma"), 1
    ulog_topics = ("airspeed", "airspeed_validated")
    dataflash_messages: ClassVar[Mapping[str, tuple[str, ...]]] = {"ARSP": ("TimeUS", "Airspeed"), "BARO": ("TimeUS",)}

    def from_ulog(self, topics: Mapping[str, Mapping[str, Vec]], time: Callable[[Any], Vec]) -> tuple[list[Any], str]:
        """True airspeeds (``true_airspeed_m_s``): the sensor's ``airspeed`` topic (instance 0, ``timestamp_sample``),
        else ``airspeed_validated``'s rows from a pitot tube (``airspeed_source`` or, before PX4 1.14,
        ``selected_airspeed_index`` 1–3; not the ground-minus-wind or synthetic estimates)."""
        for name in self.ulog_topics:
            t = topics.get(name)
            if t is None or "true_airspeed_m_s" not in t:
                continue
            tas = np.asarray(t["true_airspeed_m_s"], dtype=np.float64)
            ts = time(t)
            keep = np.isfinite(tas) & np.isfinite(ts)
            src = next((t[c] for c in ("airspeed_source", "selected_airspeed_index") if c in t), None)
            if name == "airspeed_validated" and src is not None:
                src = np.asarray(src, dtype=np.float64)
                keep &= (src >= 1) & (src <= 3)
            out = [AirspeedSample(float(ts[k]), float(tas[k])) for k in np.nonzero(keep)[0]]
            return out, f"airspeed: {len(out)} true airspeeds from {name}"
        return [], ""

    def from_dataflash(self, rows: Mapping[str, list[dict[str, Any]]]) -> tuple[list[Any], str]:
        """True airspeeds of the first airspeed sensor's ``ARSP`` rows (``Airspeed``: ArduPilot's EAS, m/s; rows with
        ``H``, 3.x ``Health``, 0 left out) with the density of the ``BARO`` static pressure ``Press`` (Pa) and
        ``ARSP``'s ``Temp`` (°C): :func:`tas_from_eas`."""

        def num(x: Any) -> float:
            return float(x) if isinstance(x, int | float) else math.nan

        arsp = [d for d in rows.get("ARSP", ()) if num(d.get("H", d.get("Health", 1))) != 0]
        bp = sorted((num(d["TimeUS"]) * 1e-6, num(d.get("Press"))) for d in rows.get("BARO", ()))
        if not arsp or not bp:
            return [], ""
        t_p, p = zip(*bp, strict=True)
        out = tas_from_eas(np.array([num(d["TimeUS"]) * 1e-6 for d in arsp]),
                           np.array([num(d["Airspeed"]) for d in arsp]), np.array(t_p), np.array(p),
                           np.array([num(d.get("Temp")) for d in arsp]))  # fmt: skip
        return out, ""

    def from_csv(self, row: list[float]) -> AirspeedSample:
        return AirspeedSample(row[0], row[1], row[2])

    def to_csv(self, s: AirspeedSample) -> tuple[float, ...]:
        return (s.t, s.tas_mps, s.sigma)

    def fields(self, s: AirspeedSample) -> tuple[Any, ...]:
        return (s.t, s.tas_mps, s.sigma, s.t_arrival_ns, s.source & 0xFF)

    def build(self, vals: tuple[Any, ...]) -> AirspeedSample:
        t, tas, sd, arr, src = vals
        return AirspeedSample(t, tas, sd, src, arr)

    def bind(self, core: Any) -> Aid:
        c = self.config(core.cfg)
        if not c.enabled:
            return Aid()
        if core.idx.wind is None:
            raise ValueError("NavConfig.airspeed.enabled=True needs filter.wind_states=True (the wind states)")
        return AirspeedAid(core, c)

    def decoders(self, protocol: str, cfg: Any) -> dict[Any, Any]:
        if protocol == "mavlink":
            return _MavlinkAirspeed(cfg).table()
        if protocol == "dronecan":
            return {"uavcan.equipment.air_data.TrueAirspeed": _dronecan_true_airspeed}
        return {}


SOURCE = AirspeedSource()
