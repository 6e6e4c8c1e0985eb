"""The measurement contract: what an aid hands to the filter update (``NavCore._apply``).

An aid linearises its model at the current nominal state into the innovation, the measurement rows and
the noise (z, H, R), in the spirit of pyins ``Measurement.compute_matrices``; gating, adaptive R, the
update and the feedback are the core's. A new aid is one function that returns a :class:`Measurement`.

The core's input contract (:func:`check_imu`, :func:`check_aid`): ``NavCore.step`` / ``fuse`` refuse, with a
one-line ValueError, a sample they cannot integrate or fuse (non-finite values or times, ``dt`` ≤ 0).
"""

from __future__ import annotations

import math
from typing import NamedTuple

from ins_hil.types import BaroSample, GnssFix, ImuSample, MagSample, Vec


class Measurement(NamedTuple):
    """One linearised measurement.

    kind: names its gate statistics and adaptive R (``gnss_pos``, ``gnss_vel``, ``baro``, ``mag``, ``nhc``,
    ``zupt``); z: innovation, measured − predicted (m,; the aid's units); H: rows (m × n, the error-state
    order of :class:`ins_hil.fusion.ekf.StateIndex`); r: diagonal noise variances (m,; units²);
    gate: the innovation test's gate (σ).
    """

    kind: str
    z: Vec
    H: Vec
    r: Vec
    gate: float


# -- the input contract of NavCore.step / fuse -------------------------------------------------------------
# The core refuses what it cannot integrate or fuse, in one line (ValueError), even though the runtime's
# validation boundary (ins_hil.validation) filters every sample before it: a caller that feeds the core
# directly (a replay, a tool, a test) gets the refusal instead of a NaN state, a math-domain ValueError deep
# in the filter or a ZeroDivisionError. Limits are structural only (finite, dt > 0); the physical ranges are
# the validation boundary's.

_INF = float("inf")


def _vec3(v: object, what: str) -> tuple[float, float, float]:
    """Three finite floats from ``v`` (numpy array or sequence), else ValueError naming ``what``."""
    try:
        x0, x1, x2 = (float(x) for x in v)  # type: ignore[attr-defined]
    except (TypeError, ValueError):
        raise ValueError(f"{what} = {v!r}: must be 3 finite numbers") from None
    if not (abs(x0) < _INF and abs(x1) < _INF and abs(x2) < _INF):
        raise ValueError(f"{what} = ({x0!r}, {x1!r}, {x2!r}): must be 3 finite numbers")
    return x0, x1, x2


def check_imu(imu: ImuSample) -> None:
    """Refuse (ValueError, one line) an IMU sample the core cannot integrate: ``t`` not finite, ``dt`` not a
    finite number > 0 (s), ``dtheta`` / ``dvel`` not 3 finite numbers. The hot path: comparisons only."""
    dt, t = imu.dt, imu.t
    try:
        a0, a1, a2 = imu.dtheta.tolist()
        v0, v1, v2 = imu.dvel.tolist()
    except (AttributeError, TypeError, ValueError):
        a0, a1, a2 = _vec3(imu.dtheta, "NavCore.step: imu.dtheta")
        v0, v1, v2 = _vec3(imu.dvel, "NavCore.step: imu.dvel")
    # NaN fails every comparison: one test for the good case
    if (
        0.0 < dt < _INF and abs(t) < _INF
        and abs(a0) < _INF and abs(a1) < _INF and abs(a2) < _INF
        and abs(v0) < _INF and abs(v1) < _INF and abs(v2) < _INF
    ):  # fmt: skip
        return
    if not 0.0 < dt < _INF:
        raise ValueError(f"NavCore.step: imu.dt = {dt!r}: must be a finite number > 0 (s)")
    if not abs(t) < _INF:
        raise ValueError(f"NavCore.step: imu.t = {t!r}: must be a finite time (s)")
    _vec3(imu.dtheta, "NavCore.step: imu.dtheta")
    _vec3(imu.dvel, "NavCore.step: imu.dvel")


def check_aid(meas: GnssFix | BaroSample | MagSample) -> None:
    """Refuse (ValueError, one line) a measurement the core cannot fuse: a time that is not finite; a GNSS fix
    whose lat/lon/h are not finite (lat = NaN: a velocity-only record, lon and h unused), whose σ
    (``std_ne``, ``std_d``, ``std_vel``) are not finite numbers ≥ 0 or whose velocity (when given) is not
    3 finite numbers; a baro sample with neither a finite pressure nor a finite altitude (NaN = not
    carried; ±inf refused); a magnetometer field that is not 3 finite numbers."""
    name = type(meas).__name__
    if not abs(meas.t) < _INF:
        raise ValueError(f"NavCore.fuse: {name}.t = {meas.t!r}: must be a finite time (s)")
    if isinstance(meas, GnssFix):
        # lat = NaN: a velocity-only record (lon, h unused), as the core itself splits a fix (gnss.vel_delay)
        for k in () if math.isnan(meas.lat) else ("lat", "lon", "h"):
            v = getattr(meas, k)
            if not abs(v) < _INF:
                raise ValueError(f"NavCore.fuse: GnssFix.{k} = {v!r}: must be a finite number")
        for k in ("std_ne", "std_d", "std_vel"):
            v = getattr(meas, k)
            if not 0.0 <= v < _INF:
                raise ValueError(f"NavCore.fuse: GnssFix.{k} = {v!r}: must be a finite number >= 0")
        if meas.vel_ned is not None:
            _vec3(meas.vel_ned, "NavCore.fuse: GnssFix.vel_ned")
    elif isinstance(meas, BaroSample):
        p, alt = meas.pressure, meas.altitude
        if p in (_INF, -_INF) or alt in (_INF, -_INF) or not (abs(p) < _INF or abs(alt) < _INF):
            raise ValueError(
                f"NavCore.fuse: BaroSample pressure = {p!r}, altitude = {alt!r}: one of them must be a finite "
                "number (NaN = not carried)"
            )
    elif isinstance(meas, MagSample):
        _vec3(meas.field_b, "NavCore.fuse: MagSample.field_b")
