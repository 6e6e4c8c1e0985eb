"""Aiding-sensor (GNSS, baro) drift and slow-pull detection from outside the filter.

The filter's per-measurement χ² gate (``NavCore``) catches jumps and outliers, but a
slow drift or a spoofing-like pull (position moved at 0.1–1 m/s) is followed by the
filter and never trips a per-sample gate. :class:`AidingMonitor` sees every GNSS fix and
baro sample together with the navigation state propagated to (about) the measurement
time *before* the measurement is fused, and runs sequential tests:

* **GNSS position vs GNSS velocity** (receiver-internal consistency, independent of the
  INS): e_k = Σ (Δp_k − ½(v_{k−1}+v_k)Δt_k) (NED, m) should be constant plus noise; the
  least-squares slope of e over a sliding window of ``window`` s is the pull rate (m/s)
  of a pull that moves the position without matching velocity. Its variance is
  σ_p²/Σ(t−t̄)² (white position noise) + 6·q/(5T) (the trapezoid-integrated velocity
  noise is a random walk of diffusion q = σ_v²Δt; OLS slope of a Brownian motion over
  T) + ``rate_floor``² (margin for time-correlated receiver errors). Statistic
  Σ slope²/var ~ χ²₃.
* **GNSS vs INS innovations**: the normalised innovations ν/√(σ_ins² + σ_meas²) of
  position (3) and velocity (3) (horizontal only unless ``vertical_cusum``: with a baro fused, the filter
  height follows the baro, so a drifting baro would be blamed on the GNSS), with σ_ins from the
  pre-fusion ``NavState.std_pos`` / ``std_vel``, feed a two-sided CUSUM per axis (Page's test, reference ``cusum_k`` σ).
  A pull with consistent velocity shows here (the INS disagrees with the GNSS velocity).
* **Baro vs GNSS height** at every healthy GNSS fix (the latest baro sample moved to the
  fix time with the GNSS vertical velocity): the LS slope of d = h_baro − h_gnss over the
  window is the baro drift rate; variance (σ_b² + σ_d²)/Σ(t−t̄)² inflated by (1+ρ)/(1−ρ) for
  residuals correlated in time (AR(1), ρ their lag-1 correlation: :func:`baro_slope_var`) + ``rate_floor``²; χ²₁.

Thresholds come from ``p_fa_hour`` (false-alarm probability per hour, per sensor), not
hand-picked constants:

* window tests are evaluated at every GNSS fix and counted as that many trials an hour
  (conservative: consecutive windows overlap), p = P_fa / (3600·f_gnss);
* the CUSUM threshold h solves Siegmund's approximation of the in-control average run
  length ARL₀(h) = (e^{2k(h+1.166)} − 2k(h+1.166) − 1)/(2k²) ≥ (samples an hour × 6 one-sided
  tests)/P_fa (Siegmund 1985, the standard ARL approximation for a N(0,1) CUSUM).

A fault is reported once as ``FaultEvent(sensor, FaultMode.DRIFT, magnitude=rate m/s)``;
the event with ``cleared=True`` follows after every statistic has stayed below its
threshold (and every normalised innovation below ``clear_gate``) for ``clear_time`` s.
With ``exclude`` the caller should not fuse the sensor while :meth:`AidingMonitor.check`
returns True. Pure, deterministic, no I/O; O(window) work per GNSS fix, O(1) per baro sample.
Normalised innovations are clipped at ``jump_gate`` in the CUSUM and a single-epoch position step is
left out of the consistency sum: a jump is reported first by the filter's own gate (JUMP); only a
persisting offset accumulates to a DRIFT alarm. Clearing uses hysteresis (``clear_fraction`` of the
threshold).
Late fixes (the live gateway: GNSS delivered 50 ms after its time of validity, checked
against the current state): the fix is compared with the state the way the core fuses it:
moved back to the time of validity (p − v·lag + ½a·lag², v − a·lag, a = C_b^n f_b + g of the
state: a second-order interpolation with no history to keep on the IMU path), or, with
``late_fix_as_current`` (NavCore with ``delay.compensation = false`` fuses a late fix as
current, so its state lags the truth by ≈ the latency: ≈ 1 m along track at 20 m/s), with the
current state. What the lag can still cause in manoeuvres (the filter's residual time offset
is unknown within [0, lag]) is a dead zone of the CUSUM inputs.
The INS velocity σ in the CUSUM has a floor of ``ins_vel_floor`` × the fix's velocity σ: after
fusing the GNSS the filter's velocity error is GNSS-driven and correlated over seconds in turns
(the live 1 kHz flights: RMS 0.03 m/s, close to its σ, but episodes of 0.10 m/s lasting seconds,
with or without delay compensation), which a white-noise CUSUM at the filter's own σ accumulates.
The INS is compared at the antenna (the core's lever arm, ``AidingMonitor(gnss_lever_arm_b=)``):
compared at the IMU point, the antenna turning about it on a slow, turning trajectory with RTK (a 0.3 m
lever arm against a 1-cm σ) reads as a pull; a simulated 150-s walk with 1 Hz RTK had 131 of 151 good
fixes excluded that way (tests/test_aiding_walk.py).
A position outlier is bridged in the consistency sum (the next fix is compared with the last accepted one), so the
sum stays a telescoping sum of the position noise; an outlier the filter fused restarts the CUSUMs. Each fix's σ is
taken as the core weighs it (its ``gnss.min_std`` floors and ``std_scale``; velocity at ``gnss.vel_delay``).
With ``gnss.vel_delay`` the position/velocity sum integrates each velocity at its own time (Δp − v̄Δt − Δv·delay),
and for ``clear_time`` s after the state is first aligned the velocity innovations have a dead zone of
|a|·delay: the core's first velocities are older than its delayed-fusion history and fused as current.
Simplifications: a vertical GNSS pull with matching vertical velocity is blamed on the baro by the
baro/GNSS test (the GNSS CUSUM usually fires first).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np

from ins_hil.fdi.thresholds import chi2_threshold
from ins_hil.nav import earth
from ins_hil.nav.rotation import dcm_from_quat
from ins_hil.settings import check_fields, setting
from ins_hil.types import BaroSample, FaultEvent, FaultMode, GnssFix, NavState, Vec


@dataclass(frozen=True)
class AidingConfig:
    """Settings of :class:`AidingMonitor` (SI units; times in s; ``cusum_k``/``clear_gate`` in σ).

    ``gnss_rate``/``baro_rate`` (Hz) are the nominal rates used only to count trials an hour
    for the thresholds. ``baro_std`` (m) is the baro noise (a BaroSample carries no σ).
    ``min_span`` is the shortest filled window (s) a slope test runs on; ``max_gap`` (s) a
    GNSS gap that restarts the windows. A fix older than the state it is checked against
    (lag ≤ ``max_lag`` s) is compared at its time of validity, or with the current state when
    ``late_fix_as_current`` (the core fuses late fixes as current), with dead zones
    ``lag_margin``·(½·lag·|a|, lag·|v − v̄|) (``lag_tau``: time constant of v̄); see ``_lag``.
    ``ins_vel_floor``: the INS velocity σ used by the CUSUM is at least this × the fix's σ_vel."""

    p_fa_hour: float = setting(
        1e-3, "per hour", "[1e-12, 1)", "false-alarm probability per hour (thresholds are derived from it)"
    )
    window: float = setting(20.0, "s", "(0, 3600]", "sliding window of the slope tests")
    min_span: float = setting(8.0, "s", "(0, 3600]", "shortest filled window a slope test runs on (≤ window)")
    cusum_k: float = setting(0.5, "σ", "[0.01, 100]", "CUSUM allowance")
    clear_gate: float = setting(3.0, "σ", "(0, 100]", "a flag clears below this")
    clear_time: float = setting(10.0, "s", "[0, 3600]", "time below clear_gate to clear")
    rate_floor: float = setting(0.005, "m/s", "[0, 100]", "floor of the drift-rate σ (time-correlated receiver errors)")
    baro_std: float = setting(0.5, "m", "(0, 100]", "barometer noise")
    gnss_rate: float = setting(5.0, "Hz", "(0, 1000]", "nominal GNSS rate (counts trials per hour)")
    baro_rate: float = setting(25.0, "Hz", "(0, 1000]", "nominal baro rate (counts trials per hour)")
    min_std: float = setting(0.01, "m", "(0, 100]", "floor on a fix's σ")
    jump_gate: float = setting(5.0, "σ", "(0, 1e6]", "normalised innovations are clipped here in the CUSUM")
    vertical_cusum: bool = setting(False, help="CUSUM on the vertical axis as well")
    clear_fraction: float = setting(
        0.25, "", "[0, 1]", "hysteresis: a CUSUM clears below this fraction of its threshold"
    )
    max_gap: float = setting(2.0, "s", "(0, 3600]", "a GNSS gap that restarts the windows")
    exclude: bool = setting(True, help="stop fusing a sensor while it is flagged")
    lag_margin: float = setting(1.0, "", "[0, 100]", "dead zone factor on the error a late fix's lag can cause")
    lag_tau: float = setting(10.0, "s", "(0, 3600]", "time constant of the mean velocity in the lag dead zone")
    max_lag: float = setting(0.5, "s", "[0, 10]", "a fix up to this late is compared at its time (or as current)")
    late_fix_as_current: bool = setting(
        False, help="compare a late fix with the current state; default follows the core"
    )
    ins_vel_floor: float = setting(
        1.0, "", "[0, 100]", "the INS velocity σ in the CUSUM is at least this × the fix's σ_vel"
    )
    diverged_speed: float = setting(
        2.0, "m/s", "(0, 1000]",
        "a GNSS excluded by the CUSUM alone, self-consistent, is re-admitted when the INS is this far off it"
    )  # fmt: skip

    def __post_init__(self) -> None:
        check_fields(self, "AidingConfig")  # each field against its [fdi.aiding] metadata
        if self.min_span > self.window:
            raise ValueError(f"min_span = {self.min_span} must not exceed window = {self.window}")


def cusum_arl0(h: float, k: float) -> float:
    """Siegmund's approximation of the in-control ARL (samples) of a one-sided N(0,1) CUSUM."""
    b = 2.0 * k * (h + 1.166)
    return (math.exp(b) - b - 1.0) / (2.0 * k * k)


def cusum_threshold(arl0: float, k: float) -> float:
    """The CUSUM decision threshold h (σ) with ARL₀(h) = ``arl0`` samples (bisection)."""
    lo, hi = 0.0, 1.0
    while cusum_arl0(hi, k) < arl0:
        hi *= 2.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if cusum_arl0(mid, k) < arl0:
            lo = mid
        else:
            hi = mid
    return hi


def _dead_zone(x: np.ndarray, dz: np.ndarray) -> np.ndarray:
    """x shrunk towards 0 by dz ≥ 0 per element (0 inside the zone): a bounded unknown bias
    within dz adds nothing to a CUSUM, the noise only shrinks (the ARL₀ stays conservative)."""
    return np.sign(x) * np.maximum(0.0, np.abs(x) - dz)


def _dead_zone1(x: float, dz: float) -> float:
    """:func:`_dead_zone` of one float (the same number: np.sign's 0 for ±0 and NaN for NaN, np.maximum's NaN)."""
    m = abs(x) - dz
    return (1.0 if x > 0.0 else -1.0 if x < 0.0 else 0.0 if x == 0.0 else x) * (0.0 if m <= 0.0 else m)


def _max1(a: float, b: float) -> float:
    """np.maximum of two floats (``a`` when equal; NaN in ``a`` propagates, as for a float ``b`` in numpy)."""
    return a if (a >= b or a != a) else b


Xyz = tuple[float, float, float]
_Z3: Xyz = (0.0, 0.0, 0.0)


def _xyz(v: Any) -> Xyz:
    """A 3-vector as three Python floats (float64 values: the numbers numpy computes with)."""
    x, y, z = np.asarray(v, dtype=np.float64).tolist()
    return x, y, z


#: s a CUSUM-excluded, self-consistent GNSS must be ``diverged_speed`` off the INS before it is re-admitted
DIVERGED_PERSIST_S = 2.0

_N_ANCHORS = 3  # accepted fixes an outlier run can be bridged from (outliers up to 2 fixes long)

_sum = np.add.reduce  # the reduction ``ndarray.mean``/``sum`` call, without their Python-level wrappers
_max = np.maximum.reduce  # ``ndarray.max``'s reduction (NaN propagates), without its wrapper


def baro_slope_var(a: np.ndarray, rate: float, sxx: float) -> float:
    """The variance ((m/s)²) of the OLS slope ``rate`` of baro − GNSS height over a window ``a`` (rows t s, d m,
    nominal white variance m²; Σ(t − t̄)² = ``sxx``) with time-correlated errors: the residuals as a first-order
    Gauss–Markov (AR(1)) sequence of lag-1 correlation ρ (measured on the window's own residuals, ≥ 0) inflate it by
    (1 + ρ)/(1 − ρ) (the effective number of independent samples of a smooth regressor); their variance is the
    larger of the nominal one and the residuals' own. A steady drift leaves white residuals (ρ ≈ 0): unchanged.
    A baro's errors from airflow and temperature are correlated over seconds (an ArduCopter flight: residuals
    0.40 m RMS, ρ 0.74 at 5 Hz), which a white-noise slope variance reads as a drift."""
    t, d = a[:, 0], a[:, 1]
    n = len(t)
    r = d - _sum(d) / n - rate * (t - _sum(t) / n)
    rr = float(r @ r)
    var = max(float(_sum(a[:, 2])) / n, rr / max(1, n - 2))
    rho = min(0.95, max(0.0, float(r[1:] @ r[:-1]) / rr)) if rr > 0.0 else 0.0
    return var / sxx * (1.0 + rho) / (1.0 - rho)


def _slope(t: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, float]:
    """OLS slopes of the columns of y (N, m) against t (N,), and Σ(t − t̄)²."""
    n = len(t)
    tc = t - _sum(t) / n  # the numbers of t.mean(), y.mean(axis=0)
    sxx = float(tc @ tc)
    return (tc @ (y - _sum(y, axis=0) / n)) / sxx, sxx


class _RowWindow:
    """FIFO of fixed-width float rows kept in one numpy buffer, oldest first: :meth:`array` is a view
    with the layout ``np.array(list_of_rows)`` would have (the same numbers from the same sums), without
    building an array from ~100 tuples at every fix (~0.2 ms on the GNSS path of the live loop)."""

    def __init__(self, width: int, capacity: int = 128) -> None:
        self._buf = np.empty((capacity, width))
        self._i0 = 0
        self._i1 = 0

    def __len__(self) -> int:
        return self._i1 - self._i0

    def append(self, row: tuple[float, ...]) -> None:
        if self._i1 == len(self._buf):
            n = len(self)
            if 2 * n > len(self._buf):
                buf = np.empty((2 * len(self._buf), self._buf.shape[1]))
                buf[:n] = self._buf[self._i0 : self._i1]
                self._buf = buf
            else:
                self._buf[:n] = self._buf[self._i0 : self._i1].copy()
            self._i0, self._i1 = 0, n
        self._buf[self._i1] = row
        self._i1 += 1

    def popleft(self) -> None:
        self._i0 += 1

    def first_t(self) -> float:
        return float(self._buf[self._i0, 0])

    def clear(self) -> None:
        self._i0 = self._i1 = 0

    def array(self) -> np.ndarray:
        return self._buf[self._i0 : self._i1]


class _Status:
    __slots__ = ("faulted", "t_fault", "t_ok")

    def __init__(self) -> None:
        self.faulted = False
        self.t_fault = 0.0
        self.t_ok = math.nan  # start of the current healthy stretch while faulted


class AidingMonitor:
    """GNSS / baro drift monitor (see module doc). Call :meth:`check` before fusing.

    ``gnss_min_std`` (m NE, m D, m/s) and ``gnss_std_scale``: the core's ``NavConfig.gnss`` σ floors and scale,
    applied to each fix's σ as the core does; ``gnss_vel_delay`` (s): its ``gnss.vel_delay`` (a fix's velocity is
    valid that long before its position). ``gnss_lever_arm_b`` (m, body FRD): IMU → antenna, the core's
    ``NavConfig.gnss.lever_arm_b`` (not a
    setting of its own: the monitor must compare the fix where the core fuses it); the INS is moved to the
    antenna (p + C_b^n l, v + C_b^n (ω × l)) before it is compared with the fix."""

    def __init__(
        self,
        cfg: AidingConfig | None = None,
        gnss_lever_arm_b: Vec | None = None,
        gnss_min_std: Vec | tuple[float, float, float] | None = None,
        gnss_std_scale: float = 1.0,
        gnss_vel_delay: float = 0.0,
    ) -> None:
        c = cfg or AidingConfig()
        mn = (0.0, 0.0, 0.0) if gnss_min_std is None else tuple(float(x) for x in gnss_min_std)
        if len(mn) != 3 or not all(math.isfinite(x) and x >= 0.0 for x in mn):
            raise ValueError(f"gnss_min_std = {gnss_min_std!r}: expected three finite σ ≥ 0 (m, m, m/s)")
        if not (math.isfinite(gnss_std_scale) and gnss_std_scale > 0.0):
            raise ValueError(f"gnss_std_scale = {gnss_std_scale!r}: expected a finite factor > 0")
        self._core_min_std = mn
        self._core_std_scale = float(gnss_std_scale)
        if not (math.isfinite(gnss_vel_delay) and 0.0 <= gnss_vel_delay <= 10.0):
            raise ValueError(f"gnss_vel_delay = {gnss_vel_delay!r}: expected 0..10 s")
        self._vel_delay = float(gnss_vel_delay)
        lever = np.zeros(3) if gnss_lever_arm_b is None else np.array(gnss_lever_arm_b, dtype=np.float64)
        if lever.shape != (3,) or not np.all(np.isfinite(lever)):
            raise ValueError(f"gnss_lever_arm_b = {gnss_lever_arm_b!r}: expected three finite numbers (m)")
        self.cfg = c
        trials = 3600.0 * c.gnss_rate
        self.thr_gnss = chi2_threshold(min(0.5, c.p_fa_hour / trials), 3)
        self.thr_baro = chi2_threshold(min(0.5, c.p_fa_hour / trials), 1)
        self.h_cusum = cusum_threshold(6.0 * trials / c.p_fa_hour, c.cusum_k)
        self.events: list[FaultEvent] = []
        self.gnss = _Status()
        self.baro = _Status()
        self.stats: dict[str, float] = {"gnss_consistency": 0.0, "gnss_cusum": 0.0, "baro_slope": 0.0}
        self._cp = np.zeros(6)  # CUSUM S⁺ (pos N,E,D, vel N,E,D)
        self._cn = np.zeros(6)  # CUSUM S⁻
        self._prev: GnssFix | None = None
        self._e: Xyz = _Z3  # accumulated position − integrated velocity (m, NED)
        #: the last ``_N_ANCHORS`` accepted fixes: [fix, its e, velocity integrated since, its dead zone (m, NED)]
        self._anchors: deque[list[Any]] = deque(maxlen=_N_ANCHORS)
        self._win = _RowWindow(6)  # rows t, e(3), σ_p², σ_v²Δt
        self._cp_len = np.zeros(6)  # samples since S⁺ was last zero
        self._cn_len = np.zeros(6)
        self._sv = np.ones(3)  # σ of the velocity innovation (m/s)
        self._baro_last: BaroSample | None = None
        self._bwin = _RowWindow(3)  # rows t, h_baro − h_gnss, var
        self._v_ema: Xyz = _Z3  # slow average of the state velocity (m/s, NED; time constant lag_tau)
        self._v_t = math.nan
        self._ins_hold = -math.inf  # INS-innovation CUSUMs held until this time (see ins_disturbed)
        self._gnss_by_cusum = False
        self._st_prev: NavState | None = None  # the state the previous fix was checked against
        self._prev_outlier = False  # the previous fix was a position outlier (see _gnss)
        self._t_div = math.nan  # since when a CUSUM-excluded, self-consistent GNSS is diverged_speed off the INS
        self._t_nav = math.nan  # the first aligned state's time (s), again after a reset of the solution
        self._resets = 0
        self._lever = lever
        self._has_lever = bool(np.any(self._lever != 0.0))

    # ---------------------------------------------------------------- public
    def check(self, meas: GnssFix | BaroSample, state: NavState) -> bool:
        """Test one measurement against ``state`` (the navigation state at about ``meas.t``,
        before the measurement is fused). Returns True if the caller should NOT fuse it.
        Nothing is tested (False) until ``state.aligned``: the INS is not trustworthy before."""
        if not self._state_seen(state.t, state.aligned, state.resets):
            return False
        if meas.kind == "gnss":
            self._gnss(meas, state)
            return self.cfg.exclude and self.gnss.faulted
        if meas.kind == "baro":
            return self._baro_seen(meas)
        return False

    def check_baro(self, meas: BaroSample, t: float, aligned: bool, resets: int = 0) -> bool:
        """:meth:`check` of a baro sample against a state given by its time ``t`` (s), ``aligned`` and ``resets``
        (``NavState``'s) instead of the state itself (a baro sample is only kept for the next GNSS fix's test)."""
        return self._state_seen(t, aligned, resets) and self._baro_seen(meas)

    def _state_seen(self, t: float, aligned: bool, resets: int) -> bool:
        """Whether a measurement is tested against the state at ``t`` (s): only once it is ``aligned``; the first
        aligned time is kept (again after a reset of the solution: ``resets`` changed)."""
        if not aligned:
            return False
        if math.isnan(self._t_nav) or resets != self._resets:
            self._t_nav, self._resets = t, resets
        return True

    def _baro_seen(self, meas: BaroSample) -> bool:
        if math.isfinite(meas.altitude):
            self._baro_last = meas
        return self.cfg.exclude and self.baro.faulted

    def ins_disturbed(self, t: float, why: str = "re-admitted: the INS lost IMU samples") -> None:
        """The INS missed IMU samples at about ``t`` (s) (e.g. lost frames, no FDI output): for
        ``clear_time`` s its innovations are no evidence against the GNSS, so the INS-innovation
        CUSUMs restart and hold (the position/velocity and baro slope tests go on). A GNSS flagged
        by those CUSUMs alone is re-admitted (it may well have been the INS)."""
        self._cp[:] = 0.0
        self._cn[:] = 0.0
        self._ins_hold = max(self._ins_hold, t + self.cfg.clear_time)
        if self.gnss.faulted and self._gnss_by_cusum:
            s = self.gnss
            s.faulted, s.t_ok = False, math.nan
            self.events.append(FaultEvent(t, "gnss", FaultMode.DRIFT, 0.0, True, True, why))

    def faulted(self, sensor: str) -> bool:
        """True while ``"gnss"`` or ``"baro"`` is flagged."""
        return (self.gnss if sensor == "gnss" else self.baro).faulted

    def drain_events(self) -> list[FaultEvent]:
        """Events raised since the last call."""
        ev, self.events = self.events, []
        return ev

    # ---------------------------------------------------------------- GNSS
    def _gnss(self, g: GnssFix, st: NavState) -> None:
        # The 3-vectors of one fix are Python floats (numpy's elementwise numbers, op for op; ~1 µs less per
        # operation than a numpy call on 3 elements); the matrix products and the windows stay numpy.
        c = self.cfg
        # the fix's σ as the core weighs it (floors ``gnss.min_std``, ``gnss.std_scale``): normalised by the
        # reported RTK σ alone (1 cm/s velocity where the core assumes 6 cm/s), the filter's own innovations
        # read as a pull (the drive: its east-velocity CUSUM tripped 14 s into navigation)
        mn, sc = self._core_min_std, self._core_std_scale
        sp_ne = max(max(g.std_ne, mn[0]) * sc, c.min_std)
        sp_d = max(max(g.std_d, mn[1]) * sc, c.min_std)
        vp_ne, vp_d = sp_ne * sp_ne, sp_d * sp_d
        sp0, self._st_prev = self._st_prev, st
        # --- innovations against the INS at the fix's time of validity
        C = dcm_from_quat(st.q_nb) if self._has_lever else None  # (once: the lever arm's and _lag's)
        lag, a_n, dz_p, dz_v = self._lag(g, st, C)
        v0, v1, v2 = _xyz(st.vel_ned)
        d0 = d1 = d2 = 0.0
        if C is not None:
            # the INS at the antenna: p + C_b^n l, v + C_b^n (ω_ib × l) (book eq. 3.3 with lever arm, as
            # fusion.measurements); the lever arm turns with the heading, by up to 2|l| on a turn of 180°
            d0, d1, d2 = (C @ self._lever).tolist()
            # ω × l in Python floats (numpy's cross of two 3-vectors: the same products and differences)
            w0, w1, w2 = _xyz(st.omega_b)
            l0, l1, l2 = self._lever.tolist()
            e0, e1, e2 = (C @ np.array((w1 * l2 - w2 * l1, w2 * l0 - w0 * l2, w0 * l1 - w1 * l0))).tolist()
            v0, v1, v2 = v0 + e0, v1 + e1, v2 + e2
        # p(t_g) = p(t) − v·lag + ½·a·lag², v(t_g) = v(t) − a·lag: the state moved back to the fix time
        # with its own velocity/acceleration, unless the core fuses late fixes as current (see _lag)
        back = 0.0 if c.late_fix_as_current else lag
        bb = back * back
        a0, a1, a2 = a_n
        n0, n1, n2 = earth.ned_delta_small_xyz(g.lat - st.lat, g.lon - st.lon, g.h - st.h, st.lat, st.h)
        n0 = n0 + (v0 * back - 0.5 * a0 * bb - d0)
        n1 = n1 + (v1 * back - 0.5 * a1 * bb - d1)
        n2 = n2 + (v2 * back - 0.5 * a2 * bb - d2)
        s0, s1, s2 = _xyz(st.std_pos)
        z_p = (_dead_zone1(n0, dz_p[0]) / math.sqrt(s0 * s0 + vp_ne),
               _dead_zone1(n1, dz_p[1]) / math.sqrt(s1 * s1 + vp_ne),
               _dead_zone1(n2, dz_p[2]) / math.sqrt(s2 * s2 + vp_d))  # fmt: skip
        if g.vel_ned is not None:
            sv = max(max(g.std_vel, mn[2]) * sc, c.min_std)
            back_v = back
            if self._vel_delay > 0.0:
                # the fix's velocity is valid ``gnss_vel_delay`` before its position (the core fuses it there):
                # the state's velocity moved back by that much more (v − a·(lag + delay))
                if lag <= 0.0:
                    a0, a1, a2 = self._accel_ned(st, C)
                back_v = back + self._vel_delay
                if st.t - self._t_nav < c.clear_time:
                    # the core's first velocities are older than its delayed-fusion history and fused as current
                    # (NavCore and the C core alike): its velocity is off by up to a·vel_delay while it settles
                    vd = self._vel_delay
                    dz_v = (dz_v[0] + vd * abs(a0), dz_v[1] + vd * abs(a1), dz_v[2] + vd * abs(a2))
            gv0, gv1, gv2 = _xyz(g.vel_ned)
            nu_v = (gv0 - (v0 - back_v * a0), gv1 - (v1 - back_v * a1), gv2 - (v2 - back_v * a2))
            floor = c.ins_vel_floor * sv
            q0, q1, q2 = (_max1(x, floor) for x in _xyz(st.std_vel))
            sd_v = (math.sqrt(q0 * q0 + sv * sv), math.sqrt(q1 * q1 + sv * sv), math.sqrt(q2 * q2 + sv * sv))
            z_v = tuple(_dead_zone1(nu_v[i], dz_v[i]) / sd_v[i] for i in range(3))
        else:
            sv = math.nan
            z_v = _Z3
            nu_v = _Z3
        # --- position vs velocity consistency window
        prev = self._prev
        if prev is not None and (g.t - prev.t > c.max_gap or g.t <= prev.t):
            self._reset_windows()
            prev = None
        fix_ok = True  # False: an outlier in position (the baro/GNSS test leaves it out too)
        bridged = False  # accepted against an anchor older than the previous fix (that one was an outlier)
        if prev is not None and prev.vel_ned is not None and g.vel_ned is not None:
            fix_ok = False
            dt = g.t - prev.t
            pv0, pv1, pv2 = _xyz(prev.vel_ned)
            trap = (0.5 * (pv0 + gv0) * dt, 0.5 * (pv1 + gv1) * dt, 0.5 * (pv2 + gv2) * dt)
            # the trapezoid rule's error on the real motion: up to about ½·|v − v_prev|·Δt per axis (a walk's
            # gait at 1 Hz: ~0.1 m, beyond the jump gate of RTK); a dead zone of the outlier test
            dz = (0.5 * abs(gv0 - pv0) * dt, 0.5 * abs(gv1 - pv1) * dt, 0.5 * abs(gv2 - pv2) * dt)
            p0, p1, p2 = earth.ned_delta_small_xyz(g.lat - prev.lat, g.lon - prev.lon, g.h - prev.h, g.lat, g.h)
            # velocities valid ``gnss_vel_delay`` before their positions integrate to the positions at those times:
            # p(t − d) ≈ p − v·d (else an acceleration a reads as a pull of a·d: 0.2 m/s at 2 m/s², d = 0.1 s)
            vd = self._vel_delay
            de = (p0 - trap[0] - (gv0 - pv0) * vd, p1 - trap[1] - (gv1 - pv1) * vd, p2 - trap[2] - (gv2 - pv2) * vd)
            # Outliers: the fix is bridged from the newest of the last accepted fixes (anchors) its
            # position agrees with (p_k − p_a − ∫v within the jump gate), so that e_k = n_k − n_0 − ∫w
            # stays a telescoping sum of the position noise over an outlier. Dropping the outlier's
            # steps instead (or one of them, when the other is within the gate) leaves a step
            # ~ N(0, 2σ_p²) in e that the slope test reads as a pull for a whole window.
            for anc in self._anchors:
                i2, z2 = anc[2], anc[3]
                anc[2] = (i2[0] + trap[0], i2[1] + trap[1], i2[2] + trap[2])
                anc[3] = (z2[0] + dz[0], z2[1] + dz[1], z2[2] + dz[2])
            for a_fix, a_e, a_int, a_dz in reversed(self._anchors):
                b0, b1, b2 = earth.ned_delta_small_xyz(g.lat - a_fix.lat, g.lon - a_fix.lon, g.h - a_fix.h, g.lat, g.h)
                b0, b1, b2 = b0 - a_int[0], b1 - a_int[1], b2 - a_int[2]
                if vd > 0.0:
                    av0, av1, av2 = _xyz(a_fix.vel_ned)
                    b0, b1, b2 = b0 - (gv0 - av0) * vd, b1 - (gv1 - av1) * vd, b2 - (gv2 - av2) * vd
                if self._step_ok((b0, b1, b2), sp_ne, sp_d, a_dz):
                    self._e = (a_e[0] + b0, a_e[1] + b1, a_e[2] + b2)
                    bridged = a_fix is not prev
                    self._push_anchor(g)
                    fix_ok = True
                    break
            else:
                if self._step_ok(de, sp_ne, sp_d, dz):  # a persisting jump: its level is accepted (the filter gates it)
                    e = self._e
                    self._e = (e[0] + de[0], e[1] + de[1], e[2] + de[2])
                    self._anchors.clear()
                    self._push_anchor(g)
                    fix_ok = True
                # else a single-epoch jump is left to the filter's gate (JUMP)
            self._win.append((g.t, *self._e, vp_ne, sv * sv * dt))
        elif g.vel_ned is not None:
            self._e = _Z3
            self._anchors.clear()
            self._push_anchor(g)
            self._win.append((g.t, 0.0, 0.0, 0.0, vp_ne, 0.0))
        self._prev = g
        while self._win and self._win.first_t() < g.t - c.window:
            self._win.popleft()
        cons, rate_c = self._consistency(sp_d / sp_ne)
        self.stats["gnss_consistency"] = cons
        # --- CUSUM on the normalised innovations (frozen while the GNSS is excluded)
        zl = [*z_p, *z_v]
        if not c.vertical_cusum:  # the filter height follows the baro: vertical GNSS checked by the slope tests
            zl[2] = zl[5] = 0.0
        jg = c.jump_gate
        # np.minimum(np.maximum(z, −g), g) (np.clip's numbers; NaN stays NaN): an outlier adds ≤ jump_gate − k
        zl = [-jg if x < -jg else jg if x > jg else x for x in zl]
        if bridged and self._prev_outlier and sp0 is not None and 0.0 < st.t - sp0.t <= c.max_gap:
            # The previous fix was a position outlier (it agreed with none of the last accepted fixes, this one
            # agrees with one before it) and the horizontal state stepped after it: p − p₀ − ½(v₀ + v)Δt, the
            # corrections fused in between, beyond
            # ``jump_gate`` × their σ (a correction K·ν has covariance P Hᵀ S⁻¹ H P ≤ P: at most the prior σ_pos
            # of that fix, the state ``sp0`` it was checked against). The filter fused the outlier (its gate is
            # wide while it converges): its innovations now measure that step, not the GNSS, so the CUSUMs
            # restart as after lost IMU samples (excluding the GNSS would keep the filter on the outlier).
            step = earth.ned_delta_small(st.lat - sp0.lat, st.lon - sp0.lon, st.h - sp0.h, st.lat, st.h) - 0.5 * (
                np.asarray(sp0.vel_ned, dtype=np.float64) + np.asarray(st.vel_ned, dtype=np.float64)
            ) * (st.t - sp0.t)
            s_corr = np.maximum(np.asarray(sp0.std_pos, dtype=np.float64)[:2], c.min_std)
            if float(np.max(np.abs(step[:2]) / s_corr)) > c.jump_gate:
                self.ins_disturbed(g.t)
        self._prev_outlier = not fix_ok
        if g.t < self._ins_hold:
            zl = [0.0] * 6  # the INS lost samples: its innovations are no evidence (ins_disturbed)
        if not (self.gnss.faulted and c.exclude):
            k = c.cusum_k
            # np.maximum(0, S ± z − k): 0 where ≤ 0, NaN stays NaN
            cp = [0.0 if v <= 0.0 else v for v in [x + y - k for x, y in zip(self._cp.tolist(), zl)]]
            cn = [0.0 if v <= 0.0 else v for v in [x - y - k for x, y in zip(self._cn.tolist(), zl)]]
            self._cp_len = np.array([n + 1 if x > 0 else 0.0 for x, n in zip(cp, self._cp_len.tolist())])
            self._cn_len = np.array([n + 1 if x > 0 else 0.0 for x, n in zip(cn, self._cn_len.tolist())])
            self._cp, self._cn = np.array(cp), np.array(cn)
            if g.vel_ned is not None:
                self._sv = np.array(sd_v)
            else:
                self._sv = np.asarray(st.std_vel, dtype=np.float64).copy()
        cus = float(max(_max(self._cp), _max(self._cn)))
        self.stats["gnss_cusum"] = cus
        bad_c = cons > self.thr_gnss
        bad_u = cus > self.h_cusum
        if not self.gnss.faulted:
            if bad_c or bad_u:
                which = "position/velocity consistency" if bad_c else "INS innovation CUSUM"
                axis = int(np.argmax(np.maximum(self._cp, self._cn)))
                rate = rate_c
                n = max(1.0, self._cn_len[axis] if self._cn[axis] > self._cp[axis] else self._cp_len[axis])
                if not bad_c and axis < 3 and len(self._win) >= 3:
                    # position pull: slope of the consistency sum since the CUSUM's change point (n fixes)
                    a = self._win.array()[-max(3, int(n) + 1) :]
                    rate = float(np.linalg.norm(_slope(a[:, 0], a[:, 1:4])[0]))
                elif not bad_c:  # velocity shift: Page's estimate (k + S/n)·σ_v
                    rate = max(rate_c, float((c.cusum_k + cus / n) * self._sv[axis - 3]))
                det = (
                    f"{which}: χ²={cons:.1f} (thr {self.thr_gnss:.1f})"
                    if bad_c
                    else f"{which}: {('pos', 'vel')[axis // 3]}.{'NED'[axis % 3]} S={cus:.1f} (h {self.h_cusum:.1f})"
                )
                self._gnss_by_cusum = not bad_c
                self._raise(self.gnss, "gnss", g.t, rate, det)
        else:
            # The INS, not the GNSS, diverged: a GNSS flagged by the INS-innovation CUSUM alone that stays
            # consistent with itself while the INS velocity is more than ``diverged_speed`` off it (a pull the CUSUM
            # guards against is slower) for DIVERGED_PERSIST_S is re-admitted, so that the core sees its rejections
            # and resets (a tactical preset on the ArduCopter flight: excluded for good at 25 s, 1 km off)
            off = math.hypot(nu_v[0], nu_v[1]) if g.vel_ned is not None else 0.0
            if self._gnss_by_cusum and cons < c.clear_fraction * self.thr_gnss and off > c.diverged_speed:
                if math.isnan(self._t_div):
                    self._t_div = g.t
                if g.t - self._t_div >= DIVERGED_PERSIST_S:
                    self._t_div = math.nan
                    self.ins_disturbed(g.t, f"re-admitted: the INS is {off:.1f} m/s off a self-consistent GNSS")
                    return
            else:
                self._t_div = math.nan
            healthy = cons < c.clear_fraction * self.thr_gnss and float(_max(np.abs(np.array(zl)))) < c.clear_gate
            if not healthy:
                self.gnss.t_ok = math.nan
            elif math.isnan(self.gnss.t_ok):
                self.gnss.t_ok = g.t
            if healthy and g.t - self.gnss.t_ok >= c.clear_time:
                self._cp[:] = 0.0
                self._cn[:] = 0.0
                self._clear(self.gnss, "gnss", g.t)
        # --- baro vs GNSS height (only against a healthy GNSS)
        if fix_ok:
            self._baro_vs_gnss(g, sp_d)

    def _lag(self, g: GnssFix, st: NavState, C: np.ndarray | None = None) -> tuple[float, Xyz, Xyz, Xyz]:
        """Lag of the fix behind the state (s, ≥ 0), the state's NED acceleration (m/s²) and the
        dead zones (m, m/s per NED axis) of the position and velocity innovations that the lag
        alone can cause.

        A delay-compensating core holds the state at the fix time: the monitor moves the current
        state back by ``lag`` (p − v·lag + ½a·lag², v − a·lag; a = C_b^n f_b + g from the state,
        to second order the same as interpolating a state history, at no cost per IMU step).
        A core that fuses a late fix as current (``NavConfig.delay.compensation = false``:
        ``NavCore.fuse`` drops the time alignment when the fix is > 1.5 steps late) is pulled
        towards the fix's past: its state becomes ≈ the truth at t − λ, λ ≤ lag, so there the
        fix is compared with the current state (``late_fix_as_current``) like the core does.
        Either way the state's residual time offset is unknown within [0, lag] while the
        velocity changes (the filter adapts with its own time constant): the innovations get
        dead zones ``lag_margin``·½·lag·|a| (velocity) and ``lag_margin``·lag·|v − v̄|
        (position; v̄ = EMA of v over ``lag_tau`` s, the velocity change the filter is still
        catching up with). With a timely fix (lag ≈ 0) both vanish. ``C``: ``dcm_from_quat(st.q_nb)`` if the
        caller has it."""
        c = self.cfg
        v0, v1, v2 = _xyz(st.vel_ned)
        if math.isnan(self._v_t):
            self._v_ema, self._v_t = (v0, v1, v2), st.t
        else:
            w = 1.0 - math.exp(-max(0.0, st.t - self._v_t) / c.lag_tau)
            e0, e1, e2 = self._v_ema
            self._v_ema = (e0 + w * (v0 - e0), e1 + w * (v1 - e1), e2 + w * (v2 - e2))
            self._v_t = st.t
        lag = st.t - g.t
        if lag <= 0.0 or lag > c.max_lag:
            return 0.0, _Z3, _Z3, _Z3
        a0, a1, a2 = a_n = self._accel_ned(st, C)
        k = c.lag_margin * 0.5 * lag
        dz_v = (k * abs(a0), k * abs(a1), k * abs(a2))
        k = c.lag_margin * lag
        e0, e1, e2 = self._v_ema
        dz_p = (k * abs(v0 - e0), k * abs(v1 - e1), k * abs(v2 - e2))
        return lag, a_n, dz_p, dz_v

    @staticmethod
    def _accel_ned(st: NavState, C: np.ndarray | None = None) -> Xyz:
        """The state's NED acceleration C_b^n·f_b + g (m/s²; Coriolis/transport terms < 0.01 m/s² here), the numbers
        of ``dcm_from_quat(q) @ f_b + gravity_ned(lat, h)`` (``C``: that DCM if the caller has it)."""
        if C is None:
            C = dcm_from_quat(st.q_nb)
        x0, x1, x2 = (C @ np.asarray(st.accel_b, dtype=np.float64)).tolist()
        return x0 + 0.0, x1 + 0.0, x2 + earth.normal_gravity(st.lat, st.h)

    def _consistency(self, ratio_d: float) -> tuple[float, float]:
        """χ²₃ statistic of the position-vs-velocity slope and its norm (m/s)."""
        w = self._win
        if len(w) < 3:
            return 0.0, 0.0
        a = w.array()
        if a[-1, 0] - a[0, 0] < self.cfg.min_span:
            return 0.0, 0.0
        t = a[:, 0]
        b, sxx = _slope(t, a[:, 1:4])
        span = float(t[-1] - t[0])
        var_ne = float(_sum(a[:, 4]) / len(a)) / sxx
        q = float(_sum(a[1:, 5])) / span  # diffusion of the integrated velocity noise (m²/s)
        var_v = 1.2 * q / span
        fl = self.cfg.rate_floor**2
        b0, b1, b2 = float(b[0]), float(b[1]), float(b[2])
        v_h = var_ne + var_v + fl
        stat = b0 * b0 / v_h + b1 * b1 / v_h + b2 * b2 / (var_ne * ratio_d * ratio_d + var_v + fl)
        return stat, math.sqrt(b0 * b0 + b1 * b1 + b2 * b2)

    def _push_anchor(self, g: GnssFix) -> None:
        self._anchors.append([g, self._e, _Z3, _Z3])

    def _step_ok(self, de: Xyz, sp_ne: float, sp_d: float, dz: Xyz) -> bool:
        """A position-minus-integrated-velocity step (m, NED) within the jump gate (√2 σ_p per axis) beyond
        the dead zone ``dz`` (m, NED: the trapezoid rule's error on the motion)."""
        g = self.cfg.jump_gate * 1.4142
        x0, x1, x2 = _dead_zone1(de[0], dz[0]), _dead_zone1(de[1], dz[1]), _dead_zone1(de[2], dz[2])
        lim = g * sp_ne  # max(|x0|, |x1|) < lim, NaN failing as in np.max
        return abs(x0) < lim and abs(x1) < lim and abs(x2) < g * sp_d

    def _reset_windows(self) -> None:
        self._win.clear()
        self._e = _Z3
        self._anchors.clear()

    # ---------------------------------------------------------------- baro
    def _baro_vs_gnss(self, g: GnssFix, sp_d: float) -> None:
        c = self.cfg
        b = self._baro_last
        if self.gnss.faulted or b is None or abs(b.t - g.t) > 0.25:
            if self.gnss.faulted:
                self._bwin.clear()
            return
        vd = float(g.vel_ned[2]) if g.vel_ned is not None else 0.0
        h_b = b.altitude + vd * (b.t - g.t)  # h(t_g) = h(t_b) − ḣ·(t_b − t_g), ḣ = −v_D
        bw = self._bwin
        bw.append((g.t, h_b - g.h, c.baro_std**2 + sp_d * sp_d))
        while bw and bw.first_t() < g.t - c.window:
            bw.popleft()
        stat, rate, tested = 0.0, 0.0, False
        if len(bw) >= 3 and g.t - bw.first_t() >= c.min_span:
            a = bw.array()
            s, sxx = _slope(a[:, 0], a[:, 1:2])
            rate = float(s[0])
            stat = rate * rate / (baro_slope_var(a, rate, sxx) + c.rate_floor**2)
            tested = True
        self.stats["baro_slope"] = stat
        bad = stat > self.thr_baro
        if not self.baro.faulted:
            if bad:
                self._raise(
                    self.baro, "baro", g.t, abs(rate), f"baro−GNSS height slope χ²={stat:.1f} (thr {self.thr_baro:.1f})"
                )
                # the baro pulled the filter height: the GNSS vertical CUSUMs saw the baro, not the GNSS
                self._cp[[2, 5]] = 0.0
                self._cn[[2, 5]] = 0.0
        else:
            if stat > c.clear_fraction * self.thr_baro or not tested:
                self.baro.t_ok = math.nan
            elif math.isnan(self.baro.t_ok):
                self.baro.t_ok = g.t
            if not math.isnan(self.baro.t_ok) and g.t - self.baro.t_ok >= c.clear_time:
                self._clear(self.baro, "baro", g.t)

    # ---------------------------------------------------------------- events
    def _raise(self, s: _Status, sensor: str, t: float, rate: float, detail: str) -> None:
        s.faulted, s.t_fault, s.t_ok = True, t, math.nan
        excl = " (excluded)" if self.cfg.exclude else ""
        self.events.append(FaultEvent(t, sensor, FaultMode.DRIFT, rate, True, False, detail + excl))

    def _clear(self, s: _Status, sensor: str, t: float) -> None:
        s.faulted, s.t_ok = False, math.nan
        self.events.append(
            FaultEvent(t, sensor, FaultMode.DRIFT, 0.0, True, True, f"healthy again after {t - s.t_fault:.1f} s")
        )
