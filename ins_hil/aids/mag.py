"""Magnetometer aid (:class:`~ins_hil.types.MagSample`, ``[core.nav.mag]`` in :mod:`ins_hil.core_parts.config`).

The book's reduced two-component measurement (+ the magnitude row with the hard-iron states,
:func:`ins_hil.fusion.measurements.magnetometer`) against the reference field ``mag.ref_ned`` (none: the
sample only feeds the alignment's magnetometer yaw); the validation boundary's check and the ``.ihlog``
record (type 4).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import numpy as np

from ins_hil.core_parts.contract import Measurement, _vec3
from ins_hil.nav.rotation import dcm_from_quat
from ins_hil.types import MagSample

from . import Aid, AidSource


class MagAid(Aid):
    def __init__(self, core: Any) -> None:
        from ins_hil.fusion import measurements  # the model: not at import (see the registry)

        self.core = core
        self.model = measurements.magnetometer

    def align(self, meas: MagSample) -> None:
        self.core.align.meas(meas)

    def fuse(self, meas: MagSample, assume_now: bool = False) -> Iterator[None]:
        core = self.core
        core.align.last_mag = np.asarray(meas.field_b)
        c = core.cfg.mag
        if c.ref_ned is None:
            return
        C = dcm_from_quat(core.ins.state.q_nb)
        z, H = self.model(core.idx, C, np.asarray(meas.field_b), c.ref_ned, core.mb)
        core._apply(Measurement("mag", z, H, np.full(len(z), c.std**2), c.gate), meas.t)
        yield from ()


class MagSource(AidSource):
    name = "mag"
    sample = MagSample
    record = 4
    record_fmt = "4dqB"  # t, field[3], t_arrival_ns, source
    reasons = ("mag_nonfinite", "mag_range")
    kinds = ("mag",)

    def enabled(self, nav: Any) -> bool:
        return nav.mag.ref_ned is not None

    def check(self, meas: MagSample) -> None:
        """A finite time; the field 3 finite numbers."""
        super().check(meas)
        _vec3(meas.field_b, "NavCore.fuse: MagSample.field_b")

    def validate(self, v: Any, m: MagSample) -> str | None:
        """The field finite, |B| < ``mag_max_t`` (T)."""
        try:
            b0, b1, b2 = (float(x) for x in m.field_b)
        except (TypeError, ValueError):
            return "mag_nonfinite"
        if not (math.isfinite(m.t) and math.isfinite(b0) and math.isfinite(b1) and math.isfinite(b2)):
            return "mag_nonfinite"
        if not b0 * b0 + b1 * b1 + b2 * b2 < v.limits.mag_max_t**2:
            return "mag_range"
        return None

    def fields(self, s: MagSample) -> tuple[Any, ...]:
        g = s.field_b
        return (s.t, float(g[0]), float(g[1]), float(g[2]), s.t_arrival_ns, s.source & 0xFF)

    def build(self, vals: tuple[Any, ...]) -> MagSample:
        t, f0, f1, f2, arr, src = vals
        return MagSample(t, np.array((f0, f1, f2)), src, arr)

    def stat_kinds(self, nav: Any) -> tuple[str, ...]:
        return self.kinds

    def bind(self, core: Any) -> MagAid:
        return MagAid(core)


SOURCE = MagSource()
