"""Barometric height aid (:class:`~ins_hil.types.BaroSample`, ``[core.nav.baro]`` in
:mod:`ins_hil.core_parts.config`).

The model and the learnt datum (baro altitude → ellipsoidal height, calibrated against the accepted GNSS
heights) are :class:`ins_hil.core_parts.baro_datum.BaroDatum` (``NavCore.baro``, its snapshot kept for delayed
fusion); here: the datum's learning before navigation, the validation boundary's baro checks and the
``.ihlog`` record (type 3).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any

from ins_hil.types import BaroSample

from . import _INF, Aid, AidSource

if TYPE_CHECKING:
    from ins_hil.core_parts.baro_datum import BaroSnapshot


class BaroAid(Aid):
    stateful = True

    def __init__(self, core: Any) -> None:
        from ins_hil.core_parts.baro_datum import BaroDatum  # the model: not at import (see the registry)

        self.core = core
        c = core.cfg
        self.datum = BaroDatum(c.baro.std, c.baro.offset_tau, c.baro.offset, c.gnss.lever_arm_b)
        core.baro = self.datum  # the GNSS aid and the alignment feed it the GNSS heights

    def align(self, meas: BaroSample) -> None:
        self.core.align.meas(meas)  # the datum starts learning before navigation

    def fuse(self, meas: BaroSample, assume_now: bool = False) -> Iterator[None]:
        core = self.core
        core._apply(self.datum.measurement(meas, core.ins, core.kf, core.cfg.baro.gate), meas.t)
        yield from ()

    def snapshot(self) -> BaroSnapshot:
        return self.datum.snapshot()

    def restore(self, d: BaroSnapshot) -> None:
        self.datum.restore(d)


class BaroSource(AidSource):
    name = "baro"
    sample = BaroSample
    record = 3
    record_fmt = "4dqB"  # t, pressure, altitude, temperature, t_arrival_ns, source
    reasons = ("baro_nonfinite", "baro_range")
    kinds = ("baro",)
    drift_monitor = True

    def enabled(self, nav: Any) -> bool:
        return True

    def check(self, meas: BaroSample) -> None:
        """A finite time; a finite pressure or a finite altitude (NaN = not carried; ±inf refused)."""
        super().check(meas)
        p, alt = meas.pressure, meas.altitude
        if p in (_INF, -_INF) or alt in (_INF, -_INF) or not (abs(p) < _INF or abs(alt) < _INF):
            raise ValueError(
                f"NavCore.fuse: BaroSample pressure = {p!r}, altitude = {alt!r}: one of them must be a finite "
                "number (NaN = not carried)"
            )

    def validate(self, v: Any, b: BaroSample) -> str | None:
        """The altitude, when carried, in [``baro_alt_min_m``, ``baro_alt_max_m``]; the pressure, when carried,
        in [``baro_pressure_min_pa``, ``baro_pressure_max_pa``]; at least one of them carried."""
        lim = v.limits
        alt, p = b.altitude, b.pressure
        if not math.isfinite(b.t):
            return "baro_nonfinite"
        has_alt, has_p = not math.isnan(alt), not math.isnan(p)
        if not (has_alt or has_p) or (has_alt and not math.isfinite(alt)) or (has_p and not math.isfinite(p)):
            return "baro_nonfinite"
        if has_alt and not lim.baro_alt_min_m <= alt <= lim.baro_alt_max_m:
            return "baro_range"
        if has_p and not lim.baro_pressure_min_pa <= p <= lim.baro_pressure_max_pa:
            return "baro_range"
        return None

    def fields(self, s: BaroSample) -> tuple[Any, ...]:
        return (s.t, s.pressure, s.altitude, s.temperature, s.t_arrival_ns, s.source & 0xFF)

    def build(self, vals: tuple[Any, ...]) -> BaroSample:
        t, p, alt, temp, arr, src = vals
        return BaroSample(t, p, alt, temp, src, arr)

    def stat_kinds(self, nav: Any) -> tuple[str, ...]:
        return self.kinds

    def bind(self, core: Any) -> BaroAid:
        return BaroAid(core)


SOURCE = BaroSource()
