"""The sections of :class:`ins_hil.core.NavConfig` (``[core.nav.gnss]``, ``[core.nav.baro]``, ...).

SI units, gates in σ, times in s; the unit, range and help of each key are in the ``core.nav.*`` tables of
:mod:`ins_hil.config_schema` (``ins-hil config --docs`` prints them per key, docs/configuration.md). Each
section checks its own values; the checks across sections are in ``NavConfig.__post_init__``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ins_hil.settings import setting
from ins_hil.types import Vec

DEG = math.pi / 180.0


@dataclass
class GnssConfig:
    """GNSS position/velocity aiding (``[core.nav.gnss]``).

    lever_arm_b: IMU → antenna (m, body FRD). min_std: floor on the reported σ (m north/east, m down, m/s).
    std_scale: factor on the reported σ. use_vel: fuse the velocity. vel_delay: the velocity is valid this long (s)
    before the fix's position time (RTKLIB .pos velocities lag their positions by ~0.13 s); it is then fused
    separately at its own time of validity (delayed fusion). gate: innovation gate (σ). reset_after: a position
    rejected this many times in a row may reset the position/velocity σ and be accepted over its gate, only when
    the rejected fixes pass a consistency test of their own (:meth:`ins_hil.core_parts.gnss.GnssReset.ok`).
    """

    lever_arm_b: Vec = setting(
        factory=lambda: np.zeros(3), unit="m", range="[-100, 100]", help="IMU → GNSS antenna, body FRD"
    )
    min_std: tuple[float, float, float] = setting(
        (0.01, 0.01, 0.02), "m, m, m/s", "(0, 1000]", "floor on the reported GNSS σ: north/east, down, velocity"
    )
    std_scale: float = setting(1.0, "", "(0, 1000]", "factor on the reported GNSS σ")
    use_vel: bool = setting(True, help="fuse the GNSS velocity")
    vel_delay: float = setting(
        0.0, "s", "[0, 2]", "the GNSS velocity is valid this long before the fix's position time (≤ delay.max_delay)"
    )
    gate: float = setting(5.0, "σ", "(0, 1e6]", "innovation gate of GNSS")
    reset_after: int = setting(
        10, "fixes", "[0, 1000000]", "consecutive rejected fixes before the GNSS position is reset"
    )

    def __post_init__(self) -> None:
        if self.vel_delay < 0.0:
            raise ValueError(f"NavConfig.gnss.vel_delay={self.vel_delay}: expected >= 0 s")


@dataclass
class BaroConfig:
    """Barometric height (``[core.nav.baro]``): noise ``std`` (m), gate (σ). The datum offset (baro altitude →
    ellipsoidal height) is ``offset`` (m) if given, else taken from the first sample and then calibrated with
    time constant ``offset_tau`` (s) while GNSS is accepted."""

    std: float = setting(0.5, "m", "(0, 1000]", "barometer noise")
    gate: float = setting(5.0, "σ", "(0, 1e6]", "innovation gate of the barometer")
    offset: float | None = setting(
        None, "m", "[-10000, 10000]", "fixed baro datum offset (baro altitude → ellipsoidal height); not set = learnt"
    )
    offset_tau: float = setting(10.0, "s", "(0, 1e6]", "time constant of the baro datum calibration against GNSS")


@dataclass
class MagConfig:
    """Magnetometer (``[core.nav.mag]``): noise ``std`` (unit-vector component, book σ_m); ``ref_ned``: reference
    field (NED, any unit, e.g. from WMM: the declination is in it; None = no magnetometer aiding); gate (σ)."""

    std: float = setting(0.0524, "", "(0, 10]", "magnetometer noise (unit-vector component, book σ_m)")
    ref_ned: Vec | None = setting(
        None,
        "any unit",
        "[-1e6, 1e6]",
        "reference magnetic field, NED (e.g. from WMM); not set = no heading from it",
        nonzero=True,
    )
    gate: float = setting(5.0, "σ", "(0, 1e6]", "innovation gate of the magnetometer")


@dataclass
class AidsConfig:
    """Ground-vehicle aids (``[core.nav.aids]``).

    nhc: non-holonomic constraint at ``nhc_rate`` Hz above ``nhc_min_speed`` m/s (lateral σ ``nhc_std`` m/s,
    optionally the vertical axis, σ ``nhc_std_vertical``). nhc_lever_b: IMU → the vehicle point whose
    lateral/vertical velocity is zero (m, body FRD); with ``filter.mount_states`` the residual IMU → vehicle
    boresight is estimated. nhc_pitch_per_accel: suspension pitch per forward acceleration (rad per m/s²,
    nose-up accelerating): the vertical NHC is applied in the road frame, the body pitched by k a_x from it.
    nhc_omega_lp_hz: corner (Hz) of a causal first-order low-pass of the body rate in the lever-arm term ω × l
    only (0 = the raw rate). zupt: zero velocity (σ ``zupt_std`` m/s) — and zero angular rate on the gyro bias
    with ``zaru`` (σ ``zaru_std`` rad/s) — when the averaged IMU (time constant ``zupt_tau`` s) looks at rest
    (rate < ``zupt_gyro`` rad/s, specific-force change < ``zupt_accel`` m/s²) for ``zupt_time`` s and the speed
    is below ``zupt_max_speed`` m/s. drag: a multirotor's rotor drag on the body x/y specific force (averaged
    over ``drag_tau`` s, σ ``drag_std`` m/s², at ``drag_rate`` Hz, coefficient ``drag_coef`` 1/s: PX4's
    EKF2_MCOEF default) against the air velocity, with the wind states (``filter.wind_states``); not while the
    rest detector sees the vehicle standing (on the ground). gate: innovation gate of these aids (σ).
    """

    nhc: bool = setting(False, help="non-holonomic constraint (ground vehicles)")
    nhc_std: float = setting(0.1, "m/s", "(0, 100]", "NHC lateral velocity σ")
    nhc_rate: float = setting(10.0, "Hz", "(0, 10000]", "NHC update rate")
    nhc_min_speed: float = setting(0.5, "m/s", "[0, 1000]", "NHC only above this speed")
    nhc_vertical: bool = setting(True, help="NHC on the vertical axis as well")
    nhc_std_vertical: float = setting(0.1, "m/s", "(0, 100]", "NHC vertical velocity σ")
    nhc_lever_b: Vec = setting(
        factory=lambda: np.zeros(3),
        unit="m",
        range="[-100, 100]",
        help="IMU → the vehicle point whose lateral/vertical velocity is zero, body FRD",
    )
    nhc_pitch_per_accel: float = setting(
        0.0, "rad/(m/s²)", "[-1, 1]", "suspension pitch per forward acceleration (nose-up accelerating)"
    )
    nhc_omega_lp_hz: float = setting(
        0.0, "Hz", "[0, 10000]", "low-pass corner of the body rate in the NHC lever-arm term; 0 = raw"
    )
    zupt: bool = setting(False, help="zero-velocity update when at rest")
    zupt_std: float = setting(0.02, "m/s", "(0, 100]", "ZUPT velocity σ")
    zupt_gyro: float = setting(0.02, "rad/s", "(0, 10]", "rest detection: averaged rate below this")
    zupt_accel: float = setting(0.15, "m/s²", "(0, 100]", "rest detection: averaged specific-force change below this")
    zupt_time: float = setting(0.5, "s", "(0, 3600]", "rest detection: this long")
    zupt_tau: float = setting(0.3, "s", "(0, 3600]", "averaging time constant of the rest detection")
    zupt_max_speed: float = setting(1.0, "m/s", "[0, 1000]", "ZUPT only below this speed")
    zaru: bool = setting(True, help="zero angular rate update on the gyro bias with ZUPT")
    zaru_std: float = setting(0.002, "rad/s", "(0, 10]", "ZARU σ")
    drag: bool = setting(False, help="multirotor rotor drag on the body x/y specific force (needs filter.wind_states)")
    drag_coef: float = setting(
        0.15, "1/s", "(0, 10]", "drag coefficient: specific force per air speed (PX4 EKF2_MCOEF)"
    )
    drag_std: float = setting(0.2, "m/s²", "(0, 100]", "drag aid σ of the averaged specific force")
    drag_tau: float = setting(0.25, "s", "(0, 60]", "averaging time constant of the specific force for the drag aid")
    drag_rate: float = setting(5.0, "Hz", "(0, 1000]", "drag aid rate")
    gate: float = setting(5.0, "σ", "(0, 1e6]", "innovation gate of the auxiliary aids (NHC, ZUPT, drag)")

    def __post_init__(self) -> None:
        if self.nhc_omega_lp_hz < 0.0:
            raise ValueError(f"NavConfig.aids.nhc_omega_lp_hz={self.nhc_omega_lp_hz}: expected >= 0 (0 = raw rate)")
        for name in ("drag_coef", "drag_std", "drag_tau", "drag_rate"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"NavConfig.aids.{name}={v!r}: expected a finite value > 0")


@dataclass
class HoldConfig:
    """Flight without GNSS (``[core.nav.hold]``, core_parts/hold.py): with ``enabled``, constant-position
    (σ ``std`` m) / zero-velocity (σ ``vel_std`` m/s, 0 = none) pseudo-measurements at ``rate`` Hz once no GNSS
    position has been fused for ``after`` s; gate (σ)."""

    enabled: bool = setting(
        False,
        help=(
            "flight without GNSS: constant-position / zero-velocity pseudo-measurements once no GNSS position has "
            "been fused for `after` s (EKF2's no-aiding mode; for hovers and bench tests, not for a moving car)"
        ),
    )
    after: float = setting(5.0, "s", "[0, 3600]", "seconds without a fused GNSS position before the hold")
    std: float = setting(10.0, "m", "(0, 1e6]", "σ of the constant-position row")
    vel_std: float = setting(1.0, "m/s", "[0, 1e3]", "σ of the zero-velocity row; 0 = none")
    rate: float = setting(5.0, "Hz", "(0, 100]", "pseudo-measurements per second")
    gate: float = setting(5.0, "σ", "(0, 1e6]", "innovation gate of the hold")


@dataclass
class AlignmentConfig:
    """The alignment before navigation (``[core.nav.alignment]``, core_parts/alignment.py).

    mode: ``"given"`` trusts the initial state; ``"static"`` levels from the mean specific force over ``time`` s
    at rest (book §4.1.1), then takes yaw from the magnetometer (σ ``mag_yaw_std`` rad) when a field reference is
    configured, else from the GNSS course once the speed exceeds ``gnss_yaw_speed`` m/s (σ ``gnss_yaw_std`` ⊕
    σ_v/V rad with the receiver's σ_v floored at ``gnss_yaw_vel_floor`` m/s); for a position-only receiver from a
    robust straight-line fit over up to 5 s of fixes once its speed exceeds ``still_speed`` and the yaw σ it gives
    is below ``aligned_yaw_std``. level_only: level only (yaw from the
    initial state). gyrocompass: yaw from the Earth rate when σ_ψ ≤ ``gyrocompass_max_std`` (rad).
    level_tilt_prior: the levelled tilt's prior correlated with the accelerometer error states. At rest: GNSS
    speed below ``still_speed`` m/s for ``still_delay`` s; ``still_gyro`` (rad/s) / ``still_accel`` (m/s²), RMS
    departure of the rate / specific force from the window's mean over ``still_tau`` s, mark motion.
    gyro_bias_std: gyro bias σ after the alignment (rad/s). aligned_yaw_std: ``state().aligned`` once the yaw σ is
    below this (rad). yaw_gsf: the heading phase takes its yaw from the GNSS-velocity yaw bank
    (:mod:`ins_hil.fusion.yaw_gsf`, PX4's EKF-GSF) once its σ is below 15°, instead of the GNSS course: for a
    vehicle whose course is not its heading (a multicopter) and that has no magnetometer. position: [lat °, lon °,
    h m], a known position (levelling and the hold need no GNSS fix).
    """

    mode: str = setting(
        "given",
        help="given: trust the initial state; static: level at rest, yaw from magnetometer or GNSS course",
        choices=("given", "static"),
    )
    time: float = setting(2.0, "s", "(0, 3600]", "static alignment: levelling time at rest")
    level_only: bool = setting(False, help="static alignment: level only (yaw from the initial state)")
    gyrocompass: bool = setting(
        False,
        help=(
            "static alignment: yaw from the Earth rate (book eq. 4.2) when filter.init_gyro_bias allows σ_ψ ≤ "
            "gyrocompass_max_std (navigation-grade gyros; MEMS cannot resolve 15 °/h)"
        ),
    )
    gyrocompass_max_std: float = setting(10.0 * DEG, "rad", "(0, 3.1416]", "gyrocompass: the largest yaw σ it may give")
    level_tilt_prior: bool = setting(True, help="levelled tilt prior correlated with the accelerometer errors")
    still_speed: float = setting(0.3, "m/s", "[0, 100]", "static alignment: at rest below this GNSS speed")
    still_delay: float = setting(1.5, "s", "[0, 3600]", "static alignment: at rest for this long")
    still_gyro: float = setting(
        3.0 * DEG,
        "rad/s",
        "(0, 10]",
        "static alignment: in motion when the rate departs from the window's mean by this much (RMS over still_tau)",
    )
    still_accel: float = setting(
        1.0,
        "m/s^2",
        "(0, 100]",
        (
            "static alignment: in motion when the specific force departs from the window's mean by this much (RMS over "
            "still_tau)"
        ),
    )
    still_tau: float = setting(0.2, "s", "(0, 60]", "static alignment: time constant of the IMU motion test")
    gyro_bias_std: float = setting(0.02 * DEG, "rad/s", "(0, 1]", "gyro bias σ after the alignment")
    mag_yaw_std: float = setting(3.0 * DEG, "rad", "(0, 3.1416]", "yaw σ from the magnetometer alignment")
    gnss_yaw_speed: float = setting(
        1.0,
        "m/s",
        "(0, 1000]",
        "in-motion yaw from a receiver's velocity course above this speed (else a fitted track)",
    )
    gnss_yaw_std: float = setting(3.0 * DEG, "rad", "(0, 3.1416]", "yaw σ of the in-motion alignment (⊕ σ_v/V)")
    gnss_yaw_vel_floor: float = setting(0.0, "m/s", "[0, 100]", "floor on the receiver's σ_v in the in-motion yaw σ")
    aligned_yaw_std: float = setting(
        5.0 * DEG, "rad", "(0, 3.1416]", "the state is 'aligned' when the yaw σ is below this"
    )
    yaw_gsf: bool = setting(
        False,
        help=(
            "heading phase: yaw from the GNSS-velocity yaw bank (PX4 EKF-GSF, σ < 15°) instead of the GNSS course "
            "(a multicopter without magnetometer)"
        ),
    )
    position: tuple[float, float, float] | None = setting(
        None,
        help="[lat deg, lon deg, h m]: a known position (levelling and the hold need no GNSS fix)",
        length=3,
        optional=True,
    )

    def __post_init__(self) -> None:
        if self.mode not in ("given", "static"):
            raise ValueError(f"NavConfig.alignment.mode={self.mode!r}: expected 'given' or 'static'")


@dataclass
class DelayConfig:
    """Delayed fusion (``[core.nav.delay]``): with ``compensation`` a late measurement is fused at its time of
    validity by rolling the filter back (history ``max_delay`` s); without, at the current step, shifted by v·Δt."""

    compensation: bool = setting(
        True, help="fuse a late GNSS fix at its time (roll-back); false: at the current step, shifted by v·Δt"
    )
    max_delay: float = setting(0.3, "s", "[0, 2]", "history kept for delayed fusion")

    def __post_init__(self) -> None:
        if not 0.0 <= self.max_delay <= 2.0:
            raise ValueError(f"NavConfig.delay.max_delay={self.max_delay}: expected 0..2 s")


#: the sections of NavConfig by field name (the order of docs/configuration.md)
SECTIONS: dict[str, type] = {
    "gnss": GnssConfig,
    "baro": BaroConfig,
    "mag": MagConfig,
    "aids": AidsConfig,
    "hold": HoldConfig,
    "alignment": AlignmentConfig,
    "delay": DelayConfig,
}


def _moved(sec: str, keys: str) -> dict[str, tuple[str, str]]:
    """``"old=new old2 ..."`` → {old: (sec, new), old2: (sec, old2)}."""
    return {k.split("=")[0]: (sec, k.split("=")[-1]) for k in keys.split()}


#: the flat NavConfig keys before the sections: old key → (section, key) (the error for an old config names it)
MOVED: dict[str, tuple[str, str]] = {
    **_moved("gnss", "gnss_lever_arm_b=lever_arm_b gnss_min_std=min_std gnss_std_scale=std_scale use_gnss_vel=use_vel "
             "gnss_vel_delay=vel_delay gate_gnss=gate gnss_reset_after=reset_after"),
    **_moved("baro", "baro_std=std gate_baro=gate baro_offset=offset baro_offset_tau=offset_tau"),
    **_moved("mag", "mag_std=std mag_ref_ned=ref_ned gate_mag=gate"),
    **_moved("aids", "nhc nhc_std nhc_rate nhc_min_speed nhc_vertical nhc_std_vertical nhc_lever_b nhc_pitch_per_accel "
             "nhc_omega_lp_hz zupt zupt_std zupt_gyro zupt_accel zupt_time zupt_tau zupt_max_speed zaru zaru_std "
             "gate_aux=gate"),
    **_moved("hold", "hold_without_gnss=enabled hold_after=after hold_std=std hold_vel_std=vel_std hold_rate=rate "
             "gate_hold=gate"),
    **_moved("alignment", "align=mode align_time=time align_level_only=level_only align_gyrocompass=gyrocompass "
             "gyrocompass_max_std level_tilt_prior still_speed still_delay still_gyro still_accel still_tau "
             "align_gyro_bias_std=gyro_bias_std mag_yaw_std gnss_yaw_speed gnss_yaw_std gnss_yaw_vel_floor "
             "aligned_yaw_std align_yaw_gsf=yaw_gsf position"),
    **_moved("delay", "delay_compensation=compensation max_delay"),
}  # fmt: skip


def nest(nav: dict[str, Any]) -> dict[str, Any]:
    """A ``[core.nav]`` table with the flat keys of the layout before the sections (:data:`MOVED`, e.g. in the
    header of an older recording) moved into their sections; a table in the sectioned layout is returned as is."""
    out = {k: dict(v) if isinstance(v, dict) else v for k, v in nav.items() if k not in MOVED}
    for k, v in nav.items():
        if k in MOVED:
            sec, new = MOVED[k]
            out.setdefault(sec, {})[new] = v
    return out
