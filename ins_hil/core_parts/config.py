"""The navigation core's configuration, :class:`NavConfig`, and its sections (``[core.nav.gnss]``, ...).

SI units, gates in σ, times in s. Each key's unit, range, default and help are its field's metadata
(:func:`ins_hil.settings.setting`), the one description docs/configuration.md and the TOML loader read; each
section checks its fields against it when built (:func:`ins_hil.settings.check_fields`), and ``NavConfig`` the
checks across sections.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ins_hil.fusion.ekf import FilterConfig
from ins_hil.nav import earth
from ins_hil.settings import check_fields, setting
from ins_hil.types import Vec

DEG = math.pi / 180.0


@dataclass
class GnssConfig:
    """GNSS position/velocity aiding (``[core.nav.gnss]``). A velocity valid ``vel_delay`` before its fix's position
    time (RTKLIB .pos velocities lag by ~0.13 s) is fused at its own time (delayed fusion). After ``reset_after``
    rejected positions in a row the position/velocity σ may be reset, only when the rejected fixes agree among
    themselves (:meth:`ins_hil.core_parts.gnss.GnssReset.ok`). Units, ranges and help: the fields' metadata."""

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
        check_fields(self, "NavConfig.gnss")


@dataclass
class BaroConfig:
    """Barometric height (``[core.nav.baro]``). The datum offset (baro altitude → ellipsoidal height) is ``offset``
    if given, else taken from the first sample and calibrated against accepted GNSS with time constant
    ``offset_tau``. Units, ranges and help: the fields' metadata."""

    std: float = setting(0.5, "m", "(0, 1000]", "barometer noise")
    gate: float = setting(5.0, "σ", "(0, 1e6]", "innovation gate of the barometer")
    offset: float | None = setting(
        None, "m", "[-10000, 10000]", "fixed baro datum offset (baro altitude → ellipsoidal height); not set = learnt"
    )
    offset_tau: float = setting(10.0, "s", "(0, 1e6]", "time constant of the baro datum calibration against GNSS")

    def __post_init__(self) -> None:
        check_fields(self, "NavConfig.baro")


@dataclass
class MagConfig:
    """Magnetometer (``[core.nav.mag]``): the reference field ``ref_ned`` (NED, any unit, e.g. from WMM; the
    declination is in it) switches the aiding on. Units, ranges and help: the fields' metadata."""

    std: float = setting(0.0524, "", "(0, 10]", "magnetometer noise (unit-vector component, book σ_m)")
    ref_ned: Vec | None = setting(
        None,
        "any unit",
        "[-1e6, 1e6]",
        "reference magnetic field, NED (e.g. from WMM); not set = no heading from it",
        nonzero=True,
    )
    gate: float = setting(5.0, "σ", "(0, 1e6]", "innovation gate of the magnetometer")

    def __post_init__(self) -> None:
        check_fields(self, "NavConfig.mag")


@dataclass
class AidsConfig:
    """Ground-vehicle and multirotor aids (``[core.nav.aids]``): the non-holonomic constraint (NHC; the vertical one in
    the road frame, the body pitched by ``nhc_pitch_per_accel`` × the forward acceleration; with ``filter.mount_states``
    the IMU → vehicle boresight is estimated), zero velocity (ZUPT) and zero angular rate (ZARU) while the averaged IMU
    looks at rest, the longitudinal-acceleration prior of a wheeled vehicle (its averaged forward kinematic acceleration
    is 0 ± ``long_accel_std``), and the rotor drag on the body x/y specific force against the air velocity (with
    ``filter.wind_states``; not while the rest detector sees the vehicle standing). Units, ranges and help: the fields'
    metadata."""

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
    long_accel_std: float = setting(
        0.0,
        "m/s²",
        "[0, 100]",
        "ground-vehicle motion prior: σ of the forward acceleration (about the vehicle's largest); the averaged "
        "forward kinematic acceleration is fused as 0 ± this and the averaging's vibration; 0 = off",
    )
    long_accel_rate: float = setting(
        1.0, "Hz", "(0, 100]", "longitudinal-acceleration prior rate: the acceleration is averaged over 1/rate s"
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
        check_fields(self, "NavConfig.aids")


@dataclass
class HoldConfig:
    """Flight without GNSS (``[core.nav.hold]``, core_parts/hold.py): constant-position / zero-velocity
    pseudo-measurements once no GNSS position has been fused for ``after`` s. Units, ranges and help: the fields'
    metadata."""

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

    def __post_init__(self) -> None:
        check_fields(self, "NavConfig.hold")


@dataclass
class AlignmentConfig:
    """The alignment before navigation (``[core.nav.alignment]``, core_parts/alignment.py).

    ``mode = "static"`` levels from the mean specific force at rest (book §4.1.1), then takes yaw from the
    magnetometer when a field reference is configured, else from the GNSS course once moving (for a position-only
    receiver from a robust straight-line fit over up to 5 s of fixes), from the gyrocompass, or from the GNSS-velocity
    yaw bank (:mod:`ins_hil.fusion.yaw_gsf`, PX4's EKF-GSF) for a vehicle whose course is not its heading.
    Units, ranges and help: the fields' metadata."""

    mode: str = setting(
        "given",
        help="given: trust the initial state; static: level at rest, yaw from magnetometer or GNSS course",
        choices=("given", "static"),
    )
    time: float = setting(2.0, "s", "(0, 3600]", "static alignment: levelling time at rest")
    level_only: bool = setting(
        False,
        help="static alignment: level at rest without a yaw source (magnetometer or motion); the yaw then comes "
        "from the GNSS course",
    )
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
        check_fields(self, "NavConfig.alignment")


@dataclass
class DelayConfig:
    """Delayed fusion (``[core.nav.delay]``): with ``compensation`` a late measurement is fused at its time of
    validity by rolling the filter back (history ``max_delay``); without, at the current step, shifted by v·Δt."""

    compensation: bool = setting(
        True, help="fuse a late GNSS fix at its time (roll-back); false: at the current step, shifted by v·Δt"
    )
    max_delay: float = setting(0.3, "s", "[0, 2]", "history kept for delayed fusion")

    def __post_init__(self) -> None:
        check_fields(self, "NavConfig.delay")


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


@dataclass
class NavConfig:
    """NavCore configuration in sections (SI units; gates in σ; times in s): ``gnss``, ``baro``, ``mag``, ``aids``
    (NHC/ZUPT/ZARU), ``hold`` (flight without GNSS), ``alignment``, ``delay`` (delayed fusion), ``filter``
    (:class:`~ins_hil.fusion.ekf.FilterConfig`); each section's keys and units are in its class
    (:mod:`ins_hil.core_parts.config`) and in docs/configuration.md. ``sources``: the sections of the aid modules
    that keep their own (``[core.nav.<name>]``, :func:`ins_hil.aids.sections`: ``odometer``, ``airspeed``), by
    name (a missing one is its default, :meth:`ins_hil.aids.AidSource.config`). ``adaptive``: Sage–Husa R on
    GNSS/baro with forgetting factor ``adaptive_b``. ``gravity``: the strapdown's gravity model, ``"normal"``
    (Somigliana with the height series, the default) or ``"j2"`` (J2 field + centrifugal,
    :func:`ins_hil.nav.earth.gravity_j2_ned`).
    """

    filter: FilterConfig = field(default_factory=FilterConfig)
    gnss: GnssConfig = field(default_factory=GnssConfig)
    baro: BaroConfig = field(default_factory=BaroConfig)
    mag: MagConfig = field(default_factory=MagConfig)
    aids: AidsConfig = field(default_factory=AidsConfig)
    hold: HoldConfig = field(default_factory=HoldConfig)
    alignment: AlignmentConfig = field(default_factory=AlignmentConfig)
    delay: DelayConfig = field(default_factory=DelayConfig)
    adaptive: bool = setting(False, help="Sage–Husa adaptive R on GNSS/baro")
    adaptive_b: float = setting(0.97, "", "(0, 1)", "Sage–Husa forgetting factor")
    gravity: str = setting(
        "normal",
        help="strapdown gravity model: 'normal' Somigliana + height series, 'j2' J2 field + centrifugal",
        choices=earth.GRAVITY_MODELS,
    )
    sources: dict[str, Any] = field(default_factory=dict, metadata={"sections": True})

    def __post_init__(self) -> None:
        check_fields(self, "NavConfig")
        for name, cls in (("filter", FilterConfig), *SECTIONS.items()):
            v = getattr(self, name)
            if not isinstance(v, cls):  # a table is built by runtime.pipeline.nav_config (settings.build), once
                raise TypeError(f"NavConfig.{name}: expected a {cls.__name__}, got {type(v).__name__}")
        if self.gnss.vel_delay > self.delay.max_delay:
            raise ValueError(
                f"NavConfig.gnss.vel_delay={self.gnss.vel_delay}: expected 0..delay.max_delay "
                f"({self.delay.max_delay} s)"
            )
        if self.filter.mount_states and not self.aids.nhc:
            raise ValueError(
                "NavConfig.filter.mount_states=True needs aids.nhc=True (the boresight is seen by the NHC only)"
            )
        if self.aids.drag and not self.filter.wind_states:
            raise ValueError("NavConfig.aids.drag=True needs filter.wind_states=True (drag acts on the air velocity)")


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
