"""Wheel odometer / body-velocity aid: the speed along the body x axis with a scale-factor state.

The odometer measures s̃ = (1 + k) (C_nb v)_x + noise (m/s; the wheel speed at the IMU, the vehicle's x axis
along the body x axis, as the non-holonomic constraint assumes), with an unknown scale factor k (tyre radius,
pressure, load) estimated as one error state ``odo_sf`` (a random walk), as pyins' odometer. With the NHC it
gives the whole body velocity, so the position drift in a GNSS outage is the scale-factor and heading error
only instead of the integrated accelerometer error.

Linearisation (error conventions of :mod:`ins_hil.fusion.measurements`: δv = true − computed,
Ĉ_bn = (I + [μ×]) C_bn, δk = k − k̂), with v_b = Ĉ^T v̂ and the true C^T v = v_b + Ĉ^T δv − Ĉ^T [v̂×] μ:
z = s̃ − (1 + k̂) v_b,x = (1 + k̂) (Ĉ^T δv − Ĉ^T [v̂×] μ)_x + v_b,x δk,
H_v = (1 + k̂) (Ĉ^T)_x, H_μ = −(1 + k̂) (Ĉ^T [v̂×])_x, H_k = v_b,x.

Config ``[core.nav.odometer]`` (:class:`OdometerConfig`); sample :class:`OdometerSample`; record type 5.

Inputs (:meth:`OdometerSource.decoders`, handed to the drivers by the runtime when the aid is enabled): MAVLink
``WHEEL_DISTANCE`` (9000: ``time_usec``, ``count``, ``distance[count]`` m, forward rotations increasing; ArduPilot
Rover's ``Rover::send_wheel_encoder_distance``, PX4's ``streams/WHEEL_DISTANCE.hpp`` left/right): the speed is
the mean of the wheels' distance increments over the time between two messages (at most
:data:`MAX_GAP_S`), valid at the middle of that interval. DroneCAN has no standard wheel-speed message: none.
The generic CSV's ``odo`` record.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar, Literal

import numpy as np

from ins_hil.core_parts.contract import Measurement
from ins_hil.nav.rotation import dcm_from_quat
from ins_hil.settings import check_fields
from ins_hil.types import Vec

from . import Aid, AidSource

if TYPE_CHECKING:
    from ins_hil.fusion.ekf import StateIndex

#: the validation boundary's speed limit (m/s; a car's odometer reads ≥ 0, a reversing one negative)
SPEED_MAX = 150.0


@dataclass(slots=True)
class OdometerSample:
    """Speed along the vehicle's forward (body x) axis (m/s, negative reversing) valid at ``t`` (s); ``sigma``:
    its 1-σ (m/s; NaN = the configured ``odometer.std``)."""

    kind: ClassVar[Literal["odometer"]] = "odometer"
    t: float
    speed_mps: float
    sigma: float = math.nan
    source: int = 0
    t_arrival_ns: int = 0


@dataclass
class OdometerConfig:
    """The wheel odometer (``[core.nav.odometer]``): ``enabled``; ``std``: speed noise (m/s, 1-σ, when the sample
    carries none); ``gate`` (σ); ``init_scale_std``: the scale factor's initial 1-σ (ratio, e.g. 0.02 = 2 %);
    ``scale_rw``: its random walk (1/√s; 0 = a constant)."""

    enabled: bool = field(default=False, metadata={"help": "fuse the wheel odometer's speed (body x)"})
    std: float = field(
        default=0.05,
        metadata={"unit": "m/s", "range": "(0, 100)", "help": "speed noise (1-σ) when the sample carries none"},
    )
    gate: float = field(default=5.0, metadata={"unit": "σ", "range": "(0, 100)", "help": "innovation gate"})
    init_scale_std: float = field(
        default=0.02, metadata={"range": "(0, 1)", "help": "initial 1-σ of the scale factor (ratio)"}
    )
    scale_rw: float = field(
        default=0.0,
        metadata={"unit": "1/√s", "range": "[0, 1)", "help": "random walk of the scale factor (0 = a constant)"},
    )

    def __post_init__(self) -> None:
        check_fields(self, "NavConfig.odometer")  # the ranges of the fields' metadata (docs/configuration.md)


def odometer_speed(idx: StateIndex, C_bn: Vec, vel: Vec, scale: float, speed: float) -> tuple[Vec, Vec]:
    """(z, H) of an odometer speed ``speed`` (m/s) with the scale factor k̂ = ``scale`` (see the module doc)."""
    from ins_hil.fusion import generated_jacobians as gj  # the models: not at import (as aids/vehicle.py)
    from ins_hil.fusion import measurements as mm

    vb_x = float(C_bn.T[0] @ vel)
    H = mm.placed_ext(gj.H_odometer(C_bn, vel, scale), idx, (idx.extra["odo_sf"], 1))
    return np.array((speed - (1.0 + scale) * vb_x,)), H


#: the longest interval (s) between two WHEEL_DISTANCE messages a speed is taken over
MAX_GAP_S = 1.0


class _WheelDistance:
    """One MAVLink link's WHEEL_DISTANCE → speed: the previous message's time and distances."""

    def __init__(self) -> None:
        self.last: tuple[float, tuple[float, ...]] | None = None

    def __call__(self, m: Any, t: float, arrival_ns: int) -> OdometerSample | str | None:
        n = int(m.count)
        d = tuple(float(x) for x in m.distance[: max(0, min(n, len(m.distance)))])
        if not d or not all(math.isfinite(x) for x in d):
            self.last = None
            return "nonfinite" if d else "odometer_no_wheels"
        last, self.last = self.last, (t, d)
        if last is None or len(last[1]) != len(d):
            return None
        dt = t - last[0]
        if not 0.0 < dt <= MAX_GAP_S:
            return None
        speed = sum(a - b for a, b in zip(d, last[1], strict=True)) / (len(d) * dt)
        return OdometerSample(0.5 * (t + last[0]), speed, t_arrival_ns=arrival_ns)


class OdometerAid(Aid):
    stateful = True

    def __init__(self, core: Any, cfg: OdometerConfig) -> None:
        self.core, self.cfg = core, cfg
        self.scale = 0.0  # k̂, the estimated scale factor (ratio)
        self.i = core.idx.extra["odo_sf"]

    def fuse(self, meas: OdometerSample, assume_now: bool = False) -> Iterator[None]:
        core, c = self.core, self.cfg
        s = core.ins.state
        z, H = odometer_speed(core.idx, dcm_from_quat(s.q_nb), s.vel_ned, self.scale, meas.speed_mps)
        sd = meas.sigma if meas.sigma > 0.0 else c.std
        core._apply(Measurement("odometer", z, H, np.array((sd * sd,)), c.gate), meas.t)
        yield from ()

    def feedback(self, x: Vec) -> None:
        self.scale += float(x[self.i])

    def snapshot(self) -> float:
        return self.scale

    def restore(self, d: float) -> None:
        self.scale = d


class _Disabled(Aid):
    """An odometer sample with ``odometer.enabled`` false: not fused."""


class OdometerSource(AidSource):
    name = "odometer"
    sample = OdometerSample
    record = 5
    record_fmt = "3dqB"  # t, speed_mps, sigma, t_arrival_ns, source
    reasons = ("odometer_nonfinite", "odometer_range")
    kinds = ("odometer",)
    section = OdometerConfig

    def check(self, s: OdometerSample) -> None:
        super().check(s)
        if not abs(s.speed_mps) < math.inf:
            raise ValueError(f"NavCore.fuse: OdometerSample.speed_mps = {s.speed_mps!r}: must be a finite number")

    def validate(self, v: Any, s: OdometerSample) -> str | None:
        """Time and speed finite, σ NaN or finite > 0; |speed| ≤ :data:`SPEED_MAX`."""
        if not (math.isfinite(s.t) and math.isfinite(s.speed_mps)) or not (math.isnan(s.sigma) or s.sigma > 0.0):
            return "odometer_nonfinite"
        if s.sigma == math.inf:
            return "odometer_nonfinite"
        if not abs(s.speed_mps) <= SPEED_MAX:
            return "odometer_range"
        return None

    csv_kind, csv_columns, csv_required = "odo", ("speed", "sigma"), 1

    def from_csv(self, row: list[float]) -> OdometerSample:
        return OdometerSample(row[0], row[1], row[2])

    def to_csv(self, s: OdometerSample) -> tuple[float, ...]:
        return (s.t, s.speed_mps, s.sigma)

    def fields(self, s: OdometerSample) -> tuple[Any, ...]:
        return (s.t, s.speed_mps, s.sigma, s.t_arrival_ns, s.source & 0xFF)

    def build(self, vals: tuple[Any, ...]) -> OdometerSample:
        t, sp, sd, arr, src = vals
        return OdometerSample(t, sp, sd, src, arr)

    def blocks(self, nav: Any) -> tuple[tuple[str, int, float, float], ...]:
        c = self.config(nav)
        return (("odo_sf", 1, c.init_scale_std, c.scale_rw),) if c.enabled else ()

    def bind(self, core: Any) -> Aid:
        c = self.config(core.cfg)
        return OdometerAid(core, c) if c.enabled else _Disabled()

    def decoders(self, protocol: str, cfg: Any) -> dict[Any, Any]:
        return {"WHEEL_DISTANCE": _WheelDistance()} if protocol == "mavlink" else {}


SOURCE = OdometerSource()
