"""The validation boundary: one physical-range check for every sample that leaves a driver.

:class:`SampleValidator` decides, for each IMU, GNSS, baro and magnetometer sample, whether it is a
physically possible reading, and returns the reason when it is not (``None`` when it is). The
pipeline calls it at its entry (:meth:`ins_hil.runtime.pipeline.Pipeline.imu` / ``aid``), which the
live loop and the replay both use, so a rejection made there is counted once and reproduced from a
recording; drivers and the simulator can call the same routine (:meth:`SampleValidator.check`).

Checks (limits in :class:`Limits`, SI units inside, configured with units in their names):

- IMU (increment form, ``dtheta`` rad and ``dvel`` m/s over ``dt`` s): every component finite; the
  mean rate |dθ_i|/dt and specific force |dv_i|/dt of each axis within the sensor range (a per-axis
  full scale, ``gyro_range_dps``, ``accel_range_g``) × ``range_margin``; ``dt`` within
  [``imu_dt_min_periods``, ``imu_dt_max_periods``] × the nominal period (configured ``imu_period_s``, or
  learnt per IMU id as the median of its first 8 intervals) and never outside [1e-5 s, 1 s]; the
  sensor time strictly increasing per IMU id.
- GNSS: fix type ≥ ``gnss_min_fix_type`` (3 = 3-D); lat in [−90°, 90°], lon in [−180°, 180°],
  height in [``gnss_h_min_m``, ``gnss_h_max_m``]; the velocity (when present) finite with
  |v| < ``gnss_speed_max_mps``; σ (``std_ne``, ``std_d`` m, ``std_vel`` m/s) finite, > 0 and below
  ``gnss_std_max_m`` / ``gnss_std_vel_max_mps``; the time strictly increasing per receiver
  (``source``): a re-sent fix is not fused twice.
- Baro: the altitude, when carried (not NaN), finite and in [``baro_alt_min_m``, ``baro_alt_max_m``];
  the pressure, when carried (not NaN), in [``baro_pressure_min_pa``, ``baro_pressure_max_pa``]; at
  least one of them carried.
- Magnetometer: finite, |B| < ``mag_max_t`` (T).
- Every other aiding sample: its aid source's check (:meth:`ins_hil.aids.AidSource.validate`, in the aid's
  module; e.g. the odometer's and the airspeed's).

The aiding checks live in their aid modules (:mod:`ins_hil.aids`); :meth:`SampleValidator.check` dispatches
on the registry by sample type (the GNSS, baro and magnetometer checks above read the limits of this module).

Reasons are short names (``imu_rate``, ``gnss_fix_type``, ...); the pipeline counts them as
``reject_<reason>``. The IMU check is a few float comparisons, no allocation (after the learning
of the nominal period).

Pure: imports only :mod:`ins_hil.types`, the aid registry (:mod:`ins_hil.aids`), the standard library and numpy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, cast

import numpy as np

from ins_hil import aids
from ins_hil.settings import dataclass_keys, setting
from ins_hil.types import BaroSample, GnssFix, ImuSample, MagSample, Sample

#: absolute bounds of an IMU interval (s), whatever the nominal period
DT_FLOOR = 1e-5
DT_CEIL = 1.0
#: IMU intervals the nominal period is learnt from (their median) when it is not configured
LEARN_SAMPLES = 8
G0 = 9.80665  # m/s² per g
_INF = math.inf

#: every reason a sample can be rejected for (counted as ``reject_<reason>``): the IMU's, then the aid sources'
REASONS = ("imu_nonfinite", "imu_dt", "imu_rate", "imu_accel", "imu_time", *aids.reasons())


@dataclass(frozen=True)
class Limits:
    """Physical ranges of the validation boundary (units in the names; see the module doc)."""

    gyro_range_dps: float = setting(
        2000.0, "°/s", "(0, inf)", "per-axis gyro full scale; beyond range × range_margin: rejected"
    )
    accel_range_g: float = setting(16.0, "g", "(0, inf)", "per-axis accelerometer full scale (g = 9.80665 m/s²)")
    range_margin: float = setting(1.5, "", "[1, 100]", "factor on the full scales before a reading is rejected")
    imu_period_s: float = setting(
        0.0, "s", "0 | [1e-05, 1]", "nominal IMU interval; 0 = learnt per IMU id (median of its first 8)"
    )
    imu_dt_min_periods: float = setting(
        0.2, "", "(0, 1]", "shortest accepted dt, in nominal periods (never below 1e-5 s)"
    )
    imu_dt_max_periods: float = setting(
        5.0, "", "[1, 1000]", "longest accepted dt, in nominal periods (never above 1 s)"
    )
    gnss_min_fix_type: int = setting(
        3, "", "[2, 6]", "lowest GNSS fix type fused (MAVLink GPS_FIX_TYPE: 2 = 2-D, 3 = 3-D, 6 = RTK fixed)"
    )
    gnss_h_min_m: float = setting(-1000.0, "m", "[-100000, 100000]", "lowest plausible GNSS ellipsoidal height")
    gnss_h_max_m: float = setting(50000.0, "m", "[-100000, 1000000]", "highest plausible GNSS ellipsoidal height")
    gnss_speed_max_mps: float = setting(600.0, "m/s", "(0, 100000]", "highest plausible GNSS speed")
    gnss_std_max_m: float = setting(1000.0, "m", "(0, 1000000]", "a fix reporting a larger position σ is rejected")
    gnss_std_vel_max_mps: float = setting(
        100.0, "m/s", "(0, 100000]", "a fix reporting a larger velocity σ is rejected"
    )
    baro_pressure_min_pa: float = setting(1000.0, "Pa", "(0, 1000000]", "lowest plausible static pressure")
    baro_pressure_max_pa: float = setting(120000.0, "Pa", "(0, 10000000]", "highest plausible static pressure")
    baro_alt_min_m: float = setting(-1000.0, "m", "[-100000, 100000]", "lowest plausible barometric altitude")
    baro_alt_max_m: float = setting(50000.0, "m", "[-100000, 1000000]", "highest plausible barometric altitude")
    mag_max_t: float = setting(1e-3, "T", "(0, 1]", "a magnetometer reading with a larger field magnitude is rejected")

    def check(self, where: str = "") -> None:
        """Raise ValueError (one line naming the key, its value and what is allowed) for a bad limit."""
        pre = f"{where}." if where else ""

        def need(name: str, ok: bool, allowed: str) -> None:
            v = getattr(self, name)
            if not ok:
                raise ValueError(f"{pre}{name} = {v!r}: must be {allowed}")

        for key in dataclass_keys(Limits).values():  # each key against its metadata, as in a config file
            key.check(getattr(self, key.name), f"{pre}{key.name}")

        def num(name: str) -> float:
            return float(getattr(self, name))

        need("gnss_h_max_m", num("gnss_h_max_m") > num("gnss_h_min_m"), "> gnss_h_min_m")
        need("baro_pressure_max_pa", num("baro_pressure_max_pa") > num("baro_pressure_min_pa"),
             "> baro_pressure_min_pa")  # fmt: skip
        need("baro_alt_max_m", num("baro_alt_max_m") > num("baro_alt_min_m"), "> baro_alt_min_m")


class _Imu:
    """Per-IMU-id state: last accepted time (s), nominal period (s, 0 while learning), dt band (s)."""

    __slots__ = ("hi", "learn", "lo", "t")

    def __init__(self, period: float, lo_k: float, hi_k: float) -> None:
        self.t = -math.inf
        self.learn: list[float] | None = None if period > 0 else []
        if period > 0:
            self.lo, self.hi = max(DT_FLOOR, lo_k * period), min(DT_CEIL, hi_k * period)
        else:
            self.lo, self.hi = DT_FLOOR, DT_CEIL


class SampleValidator:
    """The one validation routine for every sample kind (see the module doc).

    :meth:`imu` / :meth:`gnss` / :meth:`baro` / :meth:`mag` return ``None`` for a sample that may be
    used, else the reason; :meth:`check` dispatches on the type. An accepted IMU sample or GNSS fix
    advances its per-id time (a rejected one does not), so call each sample once. ``reset_time``
    forgets the per-source times (a source whose clock the runtime has re-anchored backwards).
    """

    def __init__(self, limits: Limits | None = None) -> None:
        lim = limits if limits is not None else Limits()
        lim.check()
        self.limits = lim
        self._w = lim.gyro_range_dps * math.pi / 180.0 * lim.range_margin  # rad/s per axis
        self._f = lim.accel_range_g * G0 * lim.range_margin  # m/s² per axis
        self._imus: dict[int, _Imu] = {}
        self._times: dict[tuple[str, int], float] = {}  # (aid source, source id) → last accepted time (s)
        #: the check of each sample type: the IMU's, then the aid sources' (the registry)
        self._checks: dict[type, Any] = {ImuSample: self.imu}
        for t, src in aids.by_sample().items():
            self._checks[t] = _bind(src, self)

    def reset_time(self, source: int | None = None) -> None:
        """Forget the last time of every IMU id and GNSS receiver (``source``: only that id)."""
        if source is None:
            for st in self._imus.values():
                st.t = -math.inf
            self._times.clear()
        else:
            if source in self._imus:
                self._imus[source].t = -math.inf
            for k in [k for k in self._times if k[1] == source]:
                del self._times[k]

    def imu_time(self, imu_id: int) -> float:
        """The time (s) of the last IMU sample of ``imu_id`` that passed (−inf before the first)."""
        st = self._imus.get(imu_id)
        return st.t if st is not None else -math.inf

    def imu_screened(self, imu_id: int, t: float) -> bool:
        """IMU samples of ``imu_id`` up to time ``t`` (s) passed this check already in another validator with the
        same limits (an offline replay's screen, ``ins_hil.datasets.run.screen``): once this validator has learnt
        the nominal period (or was given it), ``t`` becomes its last time and True is returned (each sample
        checked once); before, False and nothing changes: the caller checks the samples here."""
        st = self._imus.get(imu_id)
        if st is None or st.learn is not None or not st.t < t:
            return False
        st.t = t
        return True

    def imu_in_range(self, imu_id: int, dt: np.ndarray, inc: np.ndarray) -> np.ndarray | None:
        """Per IMU sample of ``imu_id`` (steps ``dt`` (n,) s, increments ``inc`` (n, 6): dθ rad, dv m/s) whether
        :meth:`imu`'s step and range comparisons pass it (the same comparisons, in one numpy pass; NaN fails),
        or None while this validator still learns that IMU's period. Its time order is the caller's and nothing
        changes here (an offline replay's screen, ``ins_hil.datasets.run.screen``: each sample that fails is
        then checked by :meth:`imu` for the reason)."""
        st = self._imus.get(imu_id)
        if st is None or st.learn is not None:
            return None
        w = self._w * dt
        f = self._f * dt
        ok = (st.lo <= dt) & (dt <= st.hi)
        for i in range(3):
            a, v = inc[:, i], inc[:, 3 + i]
            ok &= (-w <= a) & (a <= w) & (-f <= v) & (v <= f)
        return ok

    def last_time(self, kind: str, source: int) -> float:
        """The time (s) of the last accepted sample of aid source ``kind`` (e.g. ``"gnss"``) from ``source``
        (−inf before the first): an aid's check that wants strictly increasing times per source reads it."""
        return self._times.get((kind, source), -math.inf)

    def set_time(self, kind: str, source: int, t: float) -> None:
        """Remember ``t`` (s) as the last accepted time of aid source ``kind`` from ``source``."""
        self._times[(kind, source)] = t

    def check(self, s: Sample) -> str | None:
        """The reason ``s`` is rejected, or None (any sample kind: the IMU's check or its aid source's)."""
        fn = self._checks.get(type(s))
        if fn is None:
            raise TypeError(f"SampleValidator: unsupported sample {type(s).__name__}")
        return fn(s)

    # -- IMU (the hot path: comparisons only) -----------------------------------------
    def imu(self, s: ImuSample) -> str | None:
        """None if the IMU sample is possible, else ``imu_nonfinite`` / ``imu_dt`` / ``imu_rate`` /
        ``imu_accel`` / ``imu_time``."""
        st = self._imus.get(s.imu_id)
        if st is None:
            lim = self.limits
            st = self._imus[s.imu_id] = _Imu(lim.imu_period_s, lim.imu_dt_min_periods, lim.imu_dt_max_periods)
        dt = s.dt
        t = s.t
        # NaN fails every comparison below, so the fast path also rejects non-finite values
        if st.lo <= dt <= st.hi and st.t < t < _INF:
            try:
                a0, a1, a2 = s.dtheta.tolist()
                v0, v1, v2 = s.dvel.tolist()
            except (AttributeError, TypeError, ValueError):
                return self._imu_slow(s, st)  # not numpy 3-vectors: the general path
            w, f = self._w * dt, self._f * dt
            if (
                -w <= a0 <= w and -w <= a1 <= w and -w <= a2 <= w
                and -f <= v0 <= f and -f <= v1 <= f and -f <= v2 <= f
            ):  # fmt: skip
                st.t = t
                if st.learn is not None:
                    self._learn(st, dt)
                return None
        return self._imu_slow(s, st)

    def _learn(self, st: _Imu, dt: float) -> None:
        """Nominal period = median of the first LEARN_SAMPLES accepted intervals; then the band."""
        learn = st.learn
        assert learn is not None
        learn.append(dt)
        if len(learn) >= LEARN_SAMPLES:
            p = sorted(learn)[LEARN_SAMPLES // 2]
            lim = self.limits
            st.lo, st.hi = max(DT_FLOOR, lim.imu_dt_min_periods * p), min(DT_CEIL, lim.imu_dt_max_periods * p)
            st.learn = None

    def imu_unordered(self, s: ImuSample) -> str:
        """The reason :meth:`imu` gives an IMU sample whose time does not go forward (an offline replay's sample
        out of the log's time order, ``ins_hil.datasets.run.screen``): ``imu_nonfinite`` or ``imu_dt``, the checks
        before the time's, else ``imu_time``. Nothing changes here."""
        st = self._imus.get(s.imu_id)
        if st is None:
            lim = self.limits
            st = _Imu(lim.imu_period_s, lim.imu_dt_min_periods, lim.imu_dt_max_periods)
        return cast(str, self._imu_slow(s, st, late=True))

    def _imu_slow(self, s: ImuSample, st: _Imu, late: bool = False) -> str | None:
        """The same test as :meth:`imu` for any sequence type; names the first failed check (``late``: the time
        fails its check)."""
        fin = math.isfinite
        try:
            a = [float(x) for x in s.dtheta]
            v = [float(x) for x in s.dvel]
        except (TypeError, ValueError):
            return "imu_nonfinite"
        if not (fin(s.t) and fin(s.dt) and len(a) == 3 and len(v) == 3 and all(map(fin, a)) and all(map(fin, v))):
            return "imu_nonfinite"
        if not st.lo <= s.dt <= st.hi:
            return "imu_dt"
        if late or not s.t > st.t:
            return "imu_time"
        w, f = self._w * s.dt, self._f * s.dt
        if any(abs(x) > w for x in a):
            return "imu_rate"
        if any(abs(x) > f for x in v):
            return "imu_accel"
        st.t = s.t
        if st.learn is not None:
            self._learn(st, s.dt)
        return None

    # -- aiding (the checks are the aid sources', :mod:`ins_hil.aids`) -------------------------------------
    def gnss(self, g: GnssFix) -> str | None:
        """None if the fix may be fused, else ``gnss_fix_type`` / ``gnss_nonfinite`` / ``gnss_position``
        / ``gnss_height`` / ``gnss_velocity`` / ``gnss_std`` / ``gnss_time``."""
        return self.check(g)

    def baro(self, b: BaroSample) -> str | None:
        """None if the sample may be fused, else ``baro_nonfinite`` / ``baro_range``."""
        return self.check(b)

    def mag(self, m: MagSample) -> str | None:
        """None if the sample may be fused, else ``mag_nonfinite`` / ``mag_range``."""
        return self.check(m)


def _bind(src: aids.AidSource, v: SampleValidator) -> Any:
    """The aid source's check of one sample, with this validator's limits and per-source times."""
    validate = src.validate

    def check(s: Any) -> str | None:
        return validate(v, s)

    return check
