"""The sections of :class:`ins_hil.core.NavConfig` (``[core.nav.gnss]``, ``[core.nav.baro]``, ...).

SI units, gates in σ, times in s; the unit, range and help of each key are in the ``core.nav.*`` tables of
:mod:`ins_hil.config_schema` (``ins-hil config --docs`` prints them per key, docs/configuration.md). Each
section checks its own values; the checks across sections are in ``NavConfig.__post_init__``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

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

    lever_arm_b: Vec = field(default_factory=lambda: np.zeros(3))
    min_std: tuple[float, float, float] = (0.01, 0.01, 0.02)  # NE, D, vel
    std_scale: float = 1.0
    use_vel: bool = True
    vel_delay: float = 0.0
    gate: float = 5.0
    reset_after: int = 10

    def __post_init__(self) -> None:
        if self.vel_delay < 0.0:
            raise ValueError(f"NavConfig.gnss.vel_delay={self.vel_delay}: expected >= 0 s")


@dataclass
class BaroConfig:
    """Barometric height (``[core.nav.baro]``): noise ``std`` (m), gate (σ). The datum offset (baro altitude →
    ellipsoidal height) is ``offset`` (m) if given, else taken from the first sample and then calibrated with
    time constant ``offset_tau`` (s) while GNSS is accepted."""

    std: float = 0.5
    gate: float = 5.0
    offset: float | None = None
    offset_tau: float = 10.0


@dataclass
class MagConfig:
    """Magnetometer (``[core.nav.mag]``): noise ``std`` (unit-vector component, book σ_m); ``ref_ned``: reference
    field (NED, any unit, e.g. from WMM: the declination is in it; None = no magnetometer aiding); gate (σ)."""

    std: float = 0.0524
    ref_ned: Vec | None = None
    gate: float = 5.0


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

    nhc: bool = False
    nhc_std: float = 0.1
    nhc_rate: float = 10.0
    nhc_min_speed: float = 0.5
    nhc_vertical: bool = True
    nhc_std_vertical: float = 0.1
    nhc_lever_b: Vec = field(default_factory=lambda: np.zeros(3))
    nhc_pitch_per_accel: float = 0.0
    nhc_omega_lp_hz: float = 0.0
    zupt: bool = False
    zupt_std: float = 0.02
    zupt_gyro: float = 0.02
    zupt_accel: float = 0.15
    zupt_time: float = 0.5
    zupt_tau: float = 0.3
    zupt_max_speed: float = 1.0
    zaru: bool = True
    zaru_std: float = 0.002
    drag: bool = False
    drag_coef: float = 0.15
    drag_std: float = 0.2
    drag_tau: float = 0.25
    drag_rate: float = 5.0
    gate: float = 5.0

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

    enabled: bool = False
    after: float = 5.0
    std: float = 10.0
    vel_std: float = 1.0
    rate: float = 5.0
    gate: float = 5.0


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

    mode: str = "given"
    time: float = 2.0
    level_only: bool = False
    gyrocompass: bool = False
    gyrocompass_max_std: float = 10.0 * DEG
    level_tilt_prior: bool = True
    still_speed: float = 0.3
    still_delay: float = 1.5
    still_gyro: float = 3.0 * DEG
    still_accel: float = 1.0
    still_tau: float = 0.2
    gyro_bias_std: float = 0.02 * DEG
    mag_yaw_std: float = 3.0 * DEG
    gnss_yaw_speed: float = 1.0
    gnss_yaw_std: float = 3.0 * DEG
    gnss_yaw_vel_floor: float = 0.0
    aligned_yaw_std: float = 5.0 * DEG
    yaw_gsf: bool = False
    position: tuple[float, float, float] | None = None

    def __post_init__(self) -> None:
        if self.mode not in ("given", "static"):
            raise ValueError(f"NavConfig.alignment.mode={self.mode!r}: expected 'given' or 'static'")


@dataclass
class DelayConfig:
    """Delayed fusion (``[core.nav.delay]``): with ``compensation`` a late measurement is fused at its time of
    validity by rolling the filter back (history ``max_delay`` s); without, at the current step, shifted by v·Δt."""

    compensation: bool = True
    max_delay: float = 0.3

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
