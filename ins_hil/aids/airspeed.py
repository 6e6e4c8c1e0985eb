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
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

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

    def __post_init__(self) -> None:
        check_fields(self, "NavConfig.airspeed")  # the ranges of the fields' metadata (docs/configuration.md)


def true_airspeed(idx: StateIndex, vel: Vec, wind_ne: Vec, tas: float) -> tuple[Vec, Vec]:
    """(z, H) of a true airspeed ``tas`` (m/s) with the velocity ``vel`` (NED m/s) and wind ``wind_ne`` (m/s)."""
    u = np.array((float(vel[0]) - float(wind_ne[0]), float(vel[1]) - float(wind_ne[1]), float(vel[2])))
    n = float(np.linalg.norm(u))
    H = np.zeros((1, idx.n))
    H[0, idx.vel : idx.vel + 3] = u / n
    if idx.wind is not None:
        H[0, idx.wind : idx.wind + 2] = -u[0:2] / n
    return np.array((tas - n,)), H


class AirspeedAid(Aid):
    def __init__(self, core: Any, cfg: AirspeedConfig) -> None:
        self.core, self.cfg = core, cfg

    def fuse(self, meas: AirspeedSample, assume_now: bool = False) -> Iterator[None]:
        core, c = self.core, self.cfg
        v = core.ins.state.vel_ned
        if meas.tas_mps < c.min_airspeed or math.hypot(float(v[0]) - float(core.wind[0]),
                                                       float(v[1]) - float(core.wind[1])) < c.min_airspeed:  # fmt: skip
            return
        z, H = true_airspeed(core.idx, v, core.wind, meas.tas_mps)
        sd = meas.sigma if meas.sigma > 0.0 else c.std
        core._apply(Measurement("airspeed", z, H, np.array((sd * sd,)), c.gate), meas.t)
        yield from ()


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


SOURCE = AirspeedSource()
