"""The C99 reference core (``firmware_ref/``) behind the :class:`ins_hil.core.NavCore` interface.

``CNavCore(initial)`` has the same ``step(imu) -> NavState``, ``fuse(meas)`` and
``state()`` as the Python ``NavCore``, so the runtime and replay can run on
either core (``make_core("python" | "c", initial)``). The C sources are
compiled at install time by cffi (``firmware_ref/cffi_build.py``) into
``ins_hil._cref`` (double) and ``ins_hil._cref_f32`` (float).

The C filter mirrors ``ins_hil.fusion`` (15 states, or 21 with ``filter.scale_factors``; Joseph sequential
scalar updates, the same gates and feedback) for the ``NavConfig`` settings it supports: GNSS
position/velocity with lever arm and σ scale, baro, the vibration noise, ``cov_every``, NHC and ZUPT/ZARU,
the magnetometer, the no-aid hold and the alignment (in NavCore, then handed over). Others raise
``ValueError`` naming them (the list and the reasons: docs/ref_core.md). Delayed fusion
(``delay.compensation``) rolls back as NavCore does (``ins_hist_t``: a snapshot per step, the log replayed).

The C core steps at a fixed period, set at initialisation (``dt``, or the first
sample's ``dt``), as firmware does: a sample whose ``dt`` differs from it by more
than ``dt_tolerance`` (relative) is counted in ``n_off_step`` and integrated over
the fixed period (``on_dt_mismatch="count"``, the default, so a gateway keeps
running), or rejected with ``ValueError`` (``on_dt_mismatch="raise"``).
"""

from __future__ import annotations

import bisect
import dataclasses
import importlib
import math
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from typing import Any, Generic, Literal, NoReturn, TypeVar, cast, overload

import numpy as np

from ins_hil import aids
from ins_hil.core import RESET_GATE_FACTOR, NavConfig, gnss_fixes_agree, imu_lost, imu_lost_v, ins_off_track
from ins_hil.core_parts.alignment import MAX_FROZEN_S, Alignment
from ins_hil.core_parts.sensor_check import SensorCheck
from ins_hil.core_parts.yaw_reset import YawReset
from ins_hil.fusion.innovation import GateStats
from ins_hil.fusion.yaw_gsf import GsfConfig
from ins_hil.nav.mechanization import StrapdownNED, StrapdownState
from ins_hil.types import AidSample, BaroSample, FaultEvent, FaultMode, GnssFix, ImuSample, MagSample, NavState, Vec

Precision = Literal["double", "float"]
_T = TypeVar("_T")


def _lib(precision: Precision) -> tuple[Any, Any]:
    try:
        if precision not in ("double", "float"):
            raise ValueError(f"precision must be 'double' or 'float', not {precision!r}")
        mod: Any = importlib.import_module("ins_hil._cref" if precision == "double" else "ins_hil._cref_f32")
    except ImportError as exc:  # pragma: no cover - depends on the install
        raise ImportError(
            "the C reference core extension (ins_hil._cref) is not built: reinstall the package "
            "(pip install -e .) with a C compiler and cffi available"
        ) from exc
    return mod.ffi, mod.lib


def available() -> bool:
    """True if the compiled C core can be imported."""
    try:
        _lib("double")
    except ImportError:
        return False
    return True


def _c_config(ffi: Any, cfg: NavConfig) -> Any:
    """The C filter configuration from a NavConfig; ValueError for what the C core lacks."""
    f = cfg.filter
    a = cfg.aids
    # what stays Python-only (docs/ref_core.md, "What the C core runs"): the extra error states (g-sensitivity,
    # magnetometer hard iron, wind, mounting), other numerics, the model switches, adaptive R, the NHC at a lever
    # arm / with suspension pitch, the drag aid, the longitudinal-acceleration prior
    unsupported = {
        "filter.gyro_bias": not f.gyro_bias,
        "filter.accel_bias": not f.accel_bias,
        "filter.gyro_gsens": f.gyro_gsens,
        "filter.mag_bias": f.mag_bias,
        "filter.wind_states": f.wind_states,
        "filter.mount_states": f.mount_states,
        "filter.numerics": f.numerics != "joseph",
        "filter.earth_terms": not f.earth_terms,
        "filter.omega_rv_terms": f.omega_rv_terms,
        "adaptive": cfg.adaptive,
        "aids.nhc_lever_b": a.nhc and bool(np.any(np.asarray(a.nhc_lever_b) != 0.0)),
        "aids.nhc_pitch_per_accel": a.nhc and a.nhc_pitch_per_accel != 0.0,
        "aids.drag": a.drag,
        "aids.long_accel_std": a.long_accel_std > 0.0,
        # the aid modules with their own section (ins_hil.aids: odometer, airspeed) are Python-only
        **{f"{src.name}.enabled": src.enabled(cfg) for src in aids.sources() if src.section is not None},
    }
    bad = [k for k, v in unsupported.items() if v]
    if bad:
        raise ValueError(f"CNavCore: NavConfig setting(s) not supported by the C core: {', '.join(bad)}")
    c = ffi.new("ins_ekf_cfg_t *")
    pairs = {
        "gyro_arw": f.gyro_arw,
        "accel_vrw": f.accel_vrw,
        "gyro_bias_sigma": f.gyro_bias_sigma,
        "gyro_bias_tau": f.gyro_bias_tau,
        "accel_bias_sigma": f.accel_bias_sigma,
        "accel_bias_tau": f.accel_bias_tau,
        "p0_pos": f.init_pos,
        "p0_vel": f.init_vel,
        "p0_att": f.init_att,
        "p0_yaw": f.init_yaw,
        "p0_bg": f.init_gyro_bias,
        "p0_ba": f.init_accel_bias,
        "gate_gnss": cfg.gnss.gate,
        "gate_baro": cfg.baro.gate,
        "gnss_min_std_ne": cfg.gnss.min_std[0],
        "gnss_min_std_d": cfg.gnss.min_std[1],
        "gnss_min_std_vel": cfg.gnss.min_std[2],
        "baro_std": cfg.baro.std,
        "gnss_std_scale": cfg.gnss.std_scale,
        "gyro_vib_gain": f.gyro_vib_gain,
        "accel_vib_gain": f.accel_vib_gain,
        "vib_tau": f.vib_tau,
        "nhc_std": a.nhc_std,
        "nhc_std_vertical": a.nhc_std_vertical,
        "nhc_rate": a.nhc_rate,
        "nhc_min_speed": a.nhc_min_speed,
        "zupt_std": a.zupt_std,
        "zupt_gyro": a.zupt_gyro,
        "zupt_accel": a.zupt_accel,
        "zupt_time": a.zupt_time,
        "zupt_tau": a.zupt_tau,
        "zupt_max_speed": a.zupt_max_speed,
        "zaru_std": a.zaru_std,
        "aids_gate": a.gate,
        "mag_std": cfg.mag.std,
        "mag_gate": cfg.mag.gate,
        "hold_after": cfg.hold.after,
        "hold_std": cfg.hold.std,
        "hold_vel_std": cfg.hold.vel_std,
        "hold_rate": cfg.hold.rate,
        "hold_gate": cfg.hold.gate,
        "gap_accel_sigma": f.gap_accel_sigma,
        "gap_rate_sigma": f.gap_rate_sigma,
        "gyro_sf_sigma": f.gyro_sf_sigma,
        "accel_sf_sigma": f.accel_sf_sigma,
        "sf_tau": f.sf_tau,
        "p0_sg": f.init_sf,
    }
    for name, value in pairs.items():
        if not (math.isfinite(value) and value >= 0.0):
            raise ValueError(f"CNavCore: config value {name}={value!r} must be finite and >= 0")
        setattr(c, name, float(value))
    for name in ("gyro_bias_tau", "accel_bias_tau", "vib_tau", "nhc_rate", "zupt_tau", "hold_rate", "sf_tau"):
        if not pairs[name] > 0.0:
            raise ValueError(f"CNavCore: {name}={pairs[name]!r} must be > 0")
    lever = np.asarray(cfg.gnss.lever_arm_b, dtype=np.float64)
    if lever.shape != (3,) or not np.all(np.isfinite(lever)):
        raise ValueError(f"CNavCore: gnss.lever_arm_b={cfg.gnss.lever_arm_b!r} must be 3 finite numbers")
    for i in range(3):
        c.lever_arm[i] = float(lever[i])
    c.cov_every = int(f.cov_every)
    c.scale_factors = 1 if f.scale_factors else 0  # the 21-state layout: + gyro and accelerometer scale factors
    sa0 = (f.init_sf,) * 3 if f.init_accel_sf is None else tuple(f.init_accel_sf)
    if len(sa0) != 3 or not all(math.isfinite(x) and x >= 0.0 for x in sa0):
        raise ValueError(f"CNavCore: filter.init_accel_sf={f.init_accel_sf!r} must be 3 finite numbers >= 0")
    for i in range(3):
        c.p0_sa[i] = float(sa0[i])
    c.nhc, c.nhc_vertical, c.zupt = int(a.nhc), int(a.nhc_vertical), int(a.zupt)
    c.zaru = int(a.zaru and f.gyro_bias)
    c.g_local = 9.80665  # NavCore's gravity of the rest detector with alignment.mode = "given"
    if cfg.mag.ref_ned is not None:
        ref = np.asarray(cfg.mag.ref_ned, dtype=np.float64)
        if ref.shape != (3,) or not np.all(np.isfinite(ref)) or not float(np.linalg.norm(ref)) > 0.0:
            raise ValueError(f"CNavCore: mag.ref_ned={cfg.mag.ref_ned!r} must be 3 finite numbers, not all 0")
        c.have_mag = 1
        for i in range(3):
            c.mag_ref[i] = float(ref[i])
    c.hold = int(cfg.hold.enabled)
    if cfg.alignment.position is not None:
        lat, lon, h = cfg.alignment.position
        c.have_hold_pos, c.hold_lat, c.hold_lon, c.hold_h = 1, math.radians(lat), math.radians(lon), float(h)
    c.second_order = 1 if f.second_order else 0
    c.have_baro_offset = 0 if cfg.baro.offset is None else 1
    c.baro_offset = 0.0 if cfg.baro.offset is None else float(cfg.baro.offset)
    if not math.isfinite(cfg.baro.offset_tau) or not math.isfinite(c.baro_offset):
        raise ValueError("CNavCore: baro.offset / baro.offset_tau must be finite")
    c.baro_offset_tau = float(cfg.baro.offset_tau)
    c.gnss_reset_after = int(cfg.gnss.reset_after)
    c.use_gnss_vel = 1 if cfg.gnss.use_vel else 0
    return c


_GROUPS = ("gnss_pos", "gnss_vel", "baro", "nhc", "zupt", "mag", "hold")


#: columns of CNavCore.run's output array
RUN_COLUMNS = ("t", "q0", "q1", "q2", "q3", "vN", "vE", "vD", "lat", "lon", "h")


class _NoYawReset(YawReset):
    """The emergency yaw reset's bank of an alignment whose NavCore never navigates (CNavCore's): not fed."""

    def imu(self, imu: ImuSample, bg: Vec) -> None:
        """Not fed (nothing reads the bank before the hand-over)."""

    def gnss(self, meas: GnssFix) -> None:
        """Not fed."""


class _CField(Generic[_T]):
    """A read-only attribute of an object over a C struct (its ``_g``): the struct's field of the same name, as
    ``conv`` (``bool``, ``int``, ``float``) gives it; ``doc`` its docstring (a ``@property`` per field, in one
    line)."""

    def __init__(self, conv: Callable[[Any], _T], doc: str) -> None:
        self.conv, self.__doc__, self.name = conv, doc, ""

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name

    @overload
    def __get__(self, obj: None, owner: type | None = None) -> _CField[_T]: ...
    @overload
    def __get__(self, obj: object, owner: type | None = None) -> _T: ...
    def __get__(self, obj: object | None, owner: type | None = None) -> _T | _CField[_T]:
        return self if obj is None else self.conv(getattr(cast(Any, obj)._g, self.name))

    def __set__(self, obj: object, value: object) -> None:
        raise AttributeError(f"{self.name} is read from the C struct: it cannot be set")


class CYawGsf:
    """The GNSS-velocity yaw bank (:class:`ins_hil.fusion.yaw_gsf.YawGsf`, PX4's EKF-GSF) on the C core
    (``ins_gsf_t``, ``firmware_ref/src/gsf.c``, double build): the same interface and numbers to round-off; the
    alignment of a :class:`CNavCore` without magnetometer runs its bank here. Only the default ``GsfConfig``."""

    def __init__(self, cfg: GsfConfig | None = None) -> None:
        self.cfg = cfg if cfg is not None else GsfConfig()
        if self.cfg != GsfConfig(n_models=self.cfg.n_models) or self.cfg.n_models > 8:
            raise ValueError("CYawGsf: the C yaw bank has PX4's settings (GsfConfig defaults, at most 8 models)")
        self._ffi, self._lib_ = _lib("double")
        self._g = self._ffi.new("ins_gsf_t *")
        self._lib_.ins_gsf_init(self._g, self.cfg.n_models)

    started = _CField(bool, "Velocity fusion started (the yaw states are live).")
    tilt_aligned = _CField(bool, "The models' tilt set from a 1-g specific force.")
    yaw = _CField(float, "The composite yaw (rad).")
    yaw_var = _CField(float, "The composite yaw variance (rad², inf before the first velocity).")
    updates = _CField(int, "GNSS velocities fused.")

    @property
    def W(self) -> Vec:
        """The model weights (sum 1)."""
        return np.array([float(self._g.W[i]) for i in range(self.cfg.n_models)])

    def predict(self, dtheta: Vec, dvel: Vec, dt: float, forward_speed: float = 0.0) -> None:
        """One IMU interval (:meth:`YawGsf.predict`): Δθ (rad), Δv (m/s) body FRD over ``dt`` s."""
        fb = self._ffi.from_buffer
        self._lib_.cref_gsf_predict(self._g, fb("double[]", np.ascontiguousarray(dtheta, dtype=np.float64)),
                                    fb("double[]", np.ascontiguousarray(dvel, dtype=np.float64)), float(dt),
                                    float(forward_speed))  # fmt: skip

    def fuse_velocity(self, vel_ne: Vec, std: float) -> None:
        """A GNSS horizontal velocity (m/s, NE; a longer vector's first two) with its σ (m/s)."""
        v = np.ascontiguousarray(np.asarray(vel_ne, dtype=np.float64)[:2])
        self._lib_.cref_gsf_fuse_vel(self._g, self._ffi.from_buffer("double[]", v), float(std))

    def converged(self) -> bool:
        """The composite yaw σ is below :attr:`GsfConfig.converged_std`."""
        return self.started and self.yaw_var < self.cfg.converged_std**2


def _f64(ffi: Any, x: Any) -> Any:
    """A ``double[]`` view of ``x`` (copied first unless it is a C-contiguous float64 array)."""
    return ffi.from_buffer("double[]", np.ascontiguousarray(x, dtype=np.float64))


def _c_mech(ins: StrapdownNED) -> bool:
    """``ins`` (NavCore's StrapdownNED) has the settings the C mechanization mirrors (its defaults)."""
    return bool(ins._att is None and not ins._j2 and ins.coning and ins.sculling and ins.earth_rate
                and ins.renorm_every == 1)  # fmt: skip


def _mech_on_c(ins: StrapdownNED, ffi: Any, m: Any) -> None:
    """Set the C mechanization ``m`` (``ins_mech_t``) from ``ins`` (NavCore's StrapdownNED)."""
    s = ins.state
    lib = _lib("double")[1]
    lib.cref_mech_set(m, _f64(ffi, s.q_nb), _f64(ffi, s.vel_ned), s.lat, s.lon, s.h, s.t, _f64(ffi, ins._dth_prev),
                      _f64(ffi, ins._dv_prev), 1 if ins._have_prev else 0)  # fmt: skip


def _mech_back(ins: StrapdownNED, m: Any, n: int) -> None:
    """``ins`` (NavCore's StrapdownNED) after ``n`` steps of the C mechanization ``m`` from it (velocity held at
    zero: the alignment's steps); its time ``m.t``."""
    s = ins.state
    s.q_nb = np.array([float(m.q[i]) for i in range(4)])
    s.lat, s.lon, s.h, s.t = float(m.lat), float(m.lon), float(m.h), float(m.t)
    s.vel_ned = np.zeros(3)
    ins._dth_prev = np.array([float(m.dth_prev[i]) for i in range(3)])
    ins._dv_prev = np.array([float(m.dv_prev[i]) for i in range(3)])
    ins._have_prev = bool(m.have_prev)
    ins._n += n
    ins.f_ned = np.array([float(m.f_ned[i]) for i in range(3)])
    ins.omega_ie = np.array([float(m.omega_ie[i]) for i in range(3)])
    ins.omega_en = np.array([float(m.omega_en[i]) for i in range(3)])


class _CSensorCheck(SensorCheck):
    """NavCore's start-up check (:class:`SensorCheck`) with its sums on C (``ins_imu_check_t``,
    ``firmware_ref/src/align.c``, double build: the same sums in the same order), so that a run of samples goes
    through it in one C call (``CNavCore.run_states``); the sums reach the Python fields when it judges."""

    def __init__(self, cfg: NavConfig) -> None:
        super().__init__(cfg)
        self._ffi, self._clib = _lib("double")
        self.c = self._ffi.new("ins_imu_check_t *")
        self._clib.ins_imu_check_init(self.c, self.window)

    def add(self, imu: ImuSample) -> bool:
        """One sample (:meth:`SensorCheck.add`); True when the window is full and judged."""
        ffi = self._ffi
        if not self._clib.cref_imu_check_add(self.c, _f64(ffi, imu.dtheta), _f64(ffi, imu.dvel), float(imu.dt)):
            return False
        self.judge()
        return True

    def judge(self) -> None:
        """The window is full (the C sums say so): the sums into the Python fields, then the judging."""
        c, unpack = self.c, self._ffi.unpack
        self.n, self.t = int(c.n), float(c.t)
        self.sf, self.sf2 = np.array(unpack(c.sf, 3)), np.array(unpack(c.sf2, 3))
        self.sw, self.sw2 = np.array(unpack(c.sw, 3)), np.array(unpack(c.sw2, 3))
        self.dt = self.t / self.n
        self._judge()


class _CAlignment(Alignment):
    """NavCore's :class:`Alignment` with its levelling window on C (``ins_level_t``, ``firmware_ref/src/align.c``,
    double build): the same window, sums and IMU motion test in the same order, a sample at a time (:meth:`step`)
    or a run of samples in one C call (``CNavCore.run_states``); the held-back samples after the levelling
    through the C mechanization. The window's samples and sums stay in C (``t_win``, ``moving`` and
    ``imu_moving`` are kept current); they reach the Python fields when the levelling is due (:meth:`_level`
    reads them), or for good when the ring is full (``INS_LEVEL_N`` samples: the levelling goes on in Python)."""

    def __init__(self, old: Alignment) -> None:
        self.__dict__.update(old.__dict__)  # what NavCore set (a configured position)
        self._ffi, self._clib = _lib("double")
        a = self.cfg.alignment
        self.lv = self._ffi.new("ins_level_t *")
        self._clib.ins_level_init(self.lv, a.time, a.still_delay, MAX_FROZEN_S, a.still_tau, a.still_gyro**2,
                                  a.still_accel**2)  # fmt: skip
        #: the window is in C (False: in the Python fields, after the ring was full or before a fresh start)
        self.on_c = not (self.buf or self.pending)
        self._mech: Any = None
        self._mag_ref = self.cfg.mag.ref_ned is not None
        self._yaw_any = a.level_only or a.gyrocompass  # a yaw source that needs no magnetometer sample

    def put(self) -> None:
        """The flags the aiding samples set (a position, a GNSS speed, a yaw source) to the C window."""
        lv = self.lv
        lv.have_pos = 1 if self.have_pos else 0
        lv.moving = 1 if self.moving else 0
        lv.yaw_ready = 1 if self._yaw_any or (self._mag_ref and self.last_mag is not None) else 0

    def get(self) -> None:
        """The window's length and the motion flags from C."""
        lv = self.lv
        self.t_win = lv.t_win
        self.moving = bool(lv.moving)
        self.imu_moving = bool(lv.imu_moving)

    def step(self, imu: ImuSample) -> None:
        """One IMU sample before navigation (:meth:`Alignment.step`); the levelling window on C."""
        if not self.on_c or self.core.phase != "level":
            super().step(imu)
            return
        self.core.ins.state.t = imu.t
        self.put()
        ffi = self._ffi
        r = self._clib.cref_level_step(self.lv, _f64(ffi, imu.dtheta), _f64(ffi, imu.dvel), float(imu.dt),
                                       float(imu.t))  # fmt: skip
        self.get()
        if r == self._clib.INS_LEVEL_FULL:
            self.to_python()
            super().step(imu)
        elif r == self._clib.INS_LEVEL_DUE:
            self.due()

    def due(self) -> None:
        """The levelling is due (after the window's last sample): :meth:`_level` on the window's state."""
        self.to_python(keep=True)
        self._level()

    def to_python(self, keep: bool = False) -> None:
        """The C window into the Python fields (``buf``, ``pending``, the sums, the motion test); from now on the
        window is in Python unless ``keep`` (the levelling is due: the held-back samples are read from C)."""
        lv, ffi = self.lv, self._ffi
        nw, n = int(lv.n_win), int(lv.n_win) + int(lv.n_pend)
        idx = (int(lv.first) + np.arange(n)) % self._clib.INS_LEVEL_N
        t = np.frombuffer(ffi.buffer(lv.t), dtype=np.float64)[idx].tolist()
        dt = np.frombuffer(ffi.buffer(lv.dt), dtype=np.float64)[idx].tolist()
        dth = list(np.frombuffer(ffi.buffer(lv.dth), dtype=np.float64).reshape(-1, 3)[idx])
        dv = list(np.frombuffer(ffi.buffer(lv.dv), dtype=np.float64).reshape(-1, 3)[idx])
        self.buf = deque(zip(dt[:nw], dv[:nw], dth[:nw], strict=True))
        self.pending = deque(ImuSample(t=t[k], dt=dt[k], dtheta=dth[k], dvel=dv[k]) for k in range(nw, n))
        self.f_sum, self.w_sum = np.array(ffi.unpack(lv.f_sum, 3)), np.array(ffi.unpack(lv.w_sum, 3))
        self.t_win, self.dev_w, self.dev_f = float(lv.t_win), float(lv.dev_w), float(lv.dev_f)
        self.moving, self.imu_moving = bool(lv.moving), bool(lv.imu_moving)
        self.on_c = keep

    def _bring_forward(self) -> None:
        """:meth:`Alignment._bring_forward` through the C mechanization (the held-back samples of the C ring, the
        same as ``pending``) when the window was in C and NavCore's mechanization is the one the C mirrors."""
        ins = self.core.ins
        if not self.on_c or not self.pending or not _c_mech(ins):
            super()._bring_forward()
            return
        ffi = self._ffi
        if self._mech is None:
            self._mech = ffi.new("ins_mech_t *")
        m = self._mech
        _mech_on_c(ins, ffi, m)
        self._clib.cref_level_bring_forward(self.lv, m, _f64(ffi, self.core.bg))
        _mech_back(ins, m, len(self.pending))


class CNavCore:
    """The C reference core with the ``NavCore`` interface.

    initial, config: as for ``NavCore`` (``NavConfig``; settings the C core lacks raise
    ``ValueError``; ``initial`` may be None with an alignment). dt: the fixed step (s); None = take it
    from the first IMU sample. With ``alignment.mode`` other than "given" the alignment (levelling,
    gyrocompass, magnetometer/GNSS yaw, the GNSS-velocity yaw bank) runs in the Python ``NavCore``, a
    one-off start-up, with its per-sample work on C (the levelling window and start-up check: ``_CAlignment``,
    ``_CSensorCheck``; the heading phase's steps; the yaw bank: ``CYawGsf``; a run of samples in one call:
    :meth:`run_states`); at its end the C core takes over its state, covariance, noise densities and biases.
    precision: ``"double"`` or ``"float"`` (the C scalar type). filter: run the 15-state
    EKF predict on every step (needed for ``fuse``); False = mechanization only.
    dt_tolerance / on_dt_mismatch: see the module docstring. fixed_step=False: each sample is integrated over
    its own ``dt`` (a log's jittering periods, as NavCore), and lost IMU data is coasted across as NavCore does.
    """

    def __init__(
        self,
        initial: StrapdownState | None,
        config: NavConfig | None = None,
        *,
        dt: float | None = None,
        precision: Precision = "double",
        filter: bool = True,
        dt_tolerance: float = 0.05,
        on_dt_mismatch: Literal["count", "raise"] = "count",
        fixed_step: bool = True,
    ) -> None:
        if on_dt_mismatch not in ("count", "raise"):
            raise ValueError(f"on_dt_mismatch must be 'count' or 'raise', not {on_dt_mismatch!r}")
        self._ffi, self._lib_ = _lib(precision)
        self.precision = precision
        self.filter = filter
        self.cfg = config if config is not None else NavConfig()
        self.dt_tolerance = dt_tolerance
        self.on_dt_mismatch = on_dt_mismatch
        self.n_off_step = 0
        self.fixed_step = fixed_step
        self._cfg = _c_config(self._ffi, self.cfg)
        # the alignment (Python NavCore) until it navigates, then the C core from its state
        self._align: Any = None
        if self.cfg.alignment.mode != "given":
            from ins_hil.core import NavCore

            self._align = NavCore(initial, self.cfg)
            # the alignment's GNSS-velocity yaw bank on C; the emergency yaw reset's bank is not run (the C core has
            # no yaw reset, and the alignment's NavCore never checks one: it goes at the hand-over)
            if self._align.yaw_gsf is not None:
                self._align.yaw_gsf = CYawGsf()
            self._align.yaw_reset = _NoYawReset(self.cfg)
            # its levelling window and start-up check on C (a run of samples in one call: run_states)
            self._align.align = _CAlignment(self._align.align)
            if self._align.sensor_check is not None:
                self._align.sensor_check = _CSensorCheck(self.cfg)
            initial = self._align.ins.state
        elif initial is None:
            raise ValueError("CNavCore: alignment.mode='given' needs an initial state")
        self._initial = initial.copy()
        self._core = self._ffi.new("ins_core_t *")
        # delayed fusion by roll-back (delay.compensation, as NavCore): the C history, else NULL
        self._delayed = self.cfg.delay.compensation and self.cfg.delay.max_delay > 0
        self._hist = self._ffi.new("ins_hist_t *") if self._delayed else self._ffi.NULL
        if self._delayed:
            self._lib_.cref_hist_init(self._hist, float(self.cfg.delay.max_delay))
        self._out = self._ffi.new("double[32]")
        self._gate = self._ffi.new("double[8]")  # the gates of the last update (cref_gfuse_*)
        self._e_cons = self._core.ekf.consecutive  # the C counters of rejections in a row (a view into _core)
        g = self.cfg.gnss
        self._vel_delay, self._reset_after, self._use_vel = float(g.vel_delay), int(g.reset_after), bool(g.use_vel)
        self._have_mag = self.cfg.mag.ref_ned is not None
        self._aligned_std = float(self.cfg.alignment.aligned_yaw_std)
        self._pub: Any = None  # ins_out_t the C step writes its post-mechanization state to (step_begin)
        self._hmech: Any = None  # ins_mech_t of the alignment's heading phase on C (run_states before the hand-over)
        self._done: Any = None  # size_t * of the levelling runs on C (cref_level_run)
        self._out_np = np.frombuffer(self._ffi.buffer(self._out), dtype=np.float64)
        # the last NavState built by state(), until the core changes (a step, an update, the hand-over): the
        # runtime asks for the same state several times per step (the guard, the observers)
        self._st: NavState | None = None
        #: the rows of the last run_states call that had lost IMU data before them (one DROPOUT event each)
        self.run_gap_rows: list[int] = []
        #: the state records of the last run_states call, (n, 32) (the core guard: :meth:`first_bad`, ``cref_guard``)
        self.run_out: Vec = np.zeros((0, 32))
        self._ratios: dict[str, float] = {}
        self._events: list[FaultEvent] = []
        # the last rejected GNSS positions with their test ratios: the C core's forced acceptance after
        # gnss.reset_after rejections is let through only when they pass NavCore's consistency test
        self._rejected: deque[tuple[GnssFix, float]] = deque(maxlen=max(1, int(self.cfg.gnss.reset_after)))
        self.dt: float | None = None
        self._dt_fixed = dt
        # what the offline replay reads of a core (NavCore's attributes): the C core keeps no innovation log and
        # does not coast IMU gaps itself; the gate counters are the C core's plus the alignment's
        self.imu_lost: tuple[int, float] = (0, 0.0)
        self.innov_log: list[tuple[float, str, Vec]] = []
        self.divergences: list[tuple[float, str]] = []
        self.sensor_warnings: list[str] = []
        self._align_stats: dict[str, GateStats] = dict(self._align.stats) if self._align is not None else {}
        if dt is not None and self._align is None:
            self._init(dt)

    def _handover(self, dt: float) -> None:
        """The alignment navigates: the C core starts from its state, covariance, biases and baro datum."""
        a = self._align
        self._align = None
        self._st = None
        self._initial = a.ins.state.copy()
        self._align_stats = {k: dataclasses.replace(v) for k, v in a.stats.items()}
        self.sensor_warnings = list(a.sensor_warnings)
        self.imu_lost = a.imu_lost
        self._init(self._dt_fixed if self._dt_fixed is not None else dt)
        c = self._core
        ins = a.ins
        for i in range(3):
            c.mech.dth_prev[i] = float(ins._dth_prev[i])
            c.mech.dv_prev[i] = float(ins._dv_prev[i])
            c.ekf.bg[i] = float(a.bg[i])
            c.ekf.ba[i] = float(a.ba[i])
            c.ekf.sg[i] = float(a.sg[i])
            c.ekf.sa[i] = float(a.sa[i])
        c.mech.have_prev = 1 if ins._have_prev else 0
        P = np.asarray(a.kf.P, dtype=np.float64)
        n = int(c.ekf.nx)
        if P.shape != (n, n):  # the layouts agree by construction (_c_config refuses the others)
            raise ValueError(f"CNavCore: the alignment's covariance is {P.shape}, the C core's {n} states")
        for i in range(n):
            for j in range(n):
                c.ekf.P[i][j] = float(P[i, j])
        qc = np.asarray(a.kf.qc, dtype=np.float64)  # with the start-up check's inflation (NavCore._sensor_checked)
        for i in range(n):
            c.ekf.qc[i] = float(qc[i])
        c.ekf.g_local = float(a.g_local)
        b = a.baro
        if b.offset is not None:
            c.ekf.baro_offset = float(b.offset)
            c.ekf.have_baro_offset = 1
        c.ekf.baro_offset_var = float(b.offset_var)
        c.ekf.t_baro = float(b.t_baro)
        c.ekf.baro_dt = float(b.baro_dt)
        c.ekf.t_gnss_ok = float(b.t_gnss_ok) if math.isfinite(b.t_gnss_ok) else -1e300
        c.ekf.h_gnss = float(b.h_gnss)
        c.ekf.gnss_var_d = float(b.gnss_var_d)
        c.ekf.gnss_dt = float(b.gnss_dt)
        self._events += a.drain_events()

    def _init(self, dt: float) -> None:
        if not (dt > 0.0 and math.isfinite(dt)):
            raise ValueError(f"CNavCore: the fixed step dt must be positive, got {dt!r}")
        s = self._initial
        q = np.ascontiguousarray(s.q_nb, dtype=np.float64)
        v = np.ascontiguousarray(s.vel_ned, dtype=np.float64)
        ffi = self._ffi
        self._st = None
        self._lib_.cref_init(
            self._core,
            ffi.from_buffer("double[]", q),
            ffi.from_buffer("double[]", v),
            s.lat,
            s.lon,
            s.h,
            s.t,
            dt,
            self._cfg,
            1 if self.filter else 0,
        )
        if self._pub is not None:
            self._core.pub = self._pub
        self.dt = dt

    def step(self, imu: ImuSample) -> NavState:
        """Propagate with one IMU interval (mechanization + EKF predict); returns the state."""
        if self._align is not None:
            st = self._align.step(imu)
            if self._align.phase != "nav":
                return st
            self._handover(imu.dt)
            return self.state()
        self._advance(imu)
        return self.state()

    def _advance(self, imu: ImuSample) -> None:
        """One IMU interval through the C core once it navigates (:meth:`step` without building the state)."""
        if self.dt is None:
            self._init(imu.dt)
        elif not self.fixed_step:
            pass
        elif abs(imu.dt - self.dt) > self.dt_tolerance * self.dt:
            if self.on_dt_mismatch == "raise":
                raise ValueError(f"CNavCore: sample dt {imu.dt!r} s differs from the fixed step {self.dt} s")
            self.n_off_step += 1
        if not self.fixed_step:  # the C core coasts across lost IMU data (core.c): NavCore's record of it
            lost = imu_lost(imu.t, imu.dt, float(self._core.mech.t))
            if lost is not None and int(self._core.steps) > 0:
                self.imu_lost = (self.imu_lost[0] + 1, self.imu_lost[1] + lost)
                self._events.append(
                    FaultEvent(imu.t - imu.dt, "imu", FaultMode.DROPOUT, lost, True, True,
                               f"IMU data lost for {lost:.3f} s: coasted at constant velocity, covariance grown")
                )  # fmt: skip
        fb = self._ffi.from_buffer
        dth, dv = imu.dtheta, imu.dvel
        try:  # the sample's own arrays when they are C doubles (a reader's, a driver's): no copy
            a, b = fb("double[]", dth), fb("double[]", dv)
            if dth.dtype != np.float64 or dv.dtype != np.float64:
                raise TypeError
        except (TypeError, ValueError, AttributeError):  # not contiguous float64 arrays
            dth = np.ascontiguousarray(dth, dtype=np.float64)
            dv = np.ascontiguousarray(dv, dtype=np.float64)
            a, b = fb("double[]", dth), fb("double[]", dv)
        self._st = None
        self._lib_.cref_hstep(self._core, self._hist, a, b, imu.t, 0.0 if self.fixed_step else float(imu.dt))

    def step_begin(self, imu: ImuSample) -> NavState:
        """:meth:`step`, returning the state after the mechanization, as ``NavCore.step_begin`` does: before the
        filter time update, the ground aids and the hold of this step (σ of the previous step). The C step is one
        piece (it writes that state to ``ins_core_t.pub`` on its way); :meth:`state` is the state after it all."""
        if self._align is not None:
            return self.step(imu)
        self._publish()  # from the first step on (a roll-back keeps the target: core.c, hist_fuse)
        if self.dt is None:
            return self.step(imu)
        self._advance(imu)  # (no NavState of the state after the whole step: nobody asks for it here)
        self._lib_.cref_pub_state(self._core, self._out)
        return self._nav_state(self._out_np.copy())

    def _publish(self) -> None:
        """Let the C step write its post-mechanization state to ``ins_core_t.pub`` (from now on)."""
        if self._pub is None:
            self._pub = self._ffi.new("ins_out_t *")
            self._core.pub = self._pub

    def step_end(self) -> None:
        """Nothing left of the step :meth:`step_begin` ran (the ``RealTimeCore`` split step)."""

    def fuse_steps(self, meas: AidSample) -> Iterator[None]:
        """:meth:`fuse` as one segment (the ``RealTimeCore`` interface; it runs on the first ``next``)."""
        self.fuse(meas)
        yield from ()

    def fuse(self, meas: AidSample) -> None:
        """Apply a GNSS fix (position, then velocity if given) or a baro altitude valid at ``meas.t``.

        Gated like NavCore (per-component test ratio, ``gnss.gate``/``baro.gate``). With
        ``delay.compensation`` a measurement older than half a step is fused at its step by the C
        roll-back (as NavCore); without it, a late fix is shifted by v·Δt to the current step.
        With ``gnss.vel_delay`` the velocity is a second measurement at its own, earlier time.
        Magnetometer samples are fused with ``mag.ref_ned`` (ignored without it).
        """
        if self._align is not None:
            self._align.fuse(meas)
            if self._align.phase == "nav":
                self._handover(self._align._dt)
            return None
        if self.dt is None or not self.filter:
            return None
        try:
            if meas.kind == "gnss":
                self._fuse_gnss(cast(GnssFix, meas))
            else:
                self._fuse_one(meas)
        finally:
            self._st = None  # the state changed (a roll-back too)
        return None

    def _fuse_gnss(self, meas: GnssFix) -> None:
        """A GNSS fix into the C core (through the roll-back history): its position and velocity at its time, or
        with ``gnss.vel_delay`` its position at its time and its velocity at its own earlier time (two updates in
        one C call). The C call returns each group's gate (``cref_gfuse_*``: its test ratio, rejected or not, the
        rejections in a row before and after it), from which the ratios and NavCore's gate events follow."""
        if not (meas.std_ne >= 0.0 and meas.std_d >= 0.0 and meas.std_vel >= 0.0):
            _refuse_gnss_std(meas)
        g = self._gate
        v = meas.vel_ned
        split = v is not None and self._vel_delay > 0.0
        if v is not None:
            vn, ve, vd = (v if type(v) is np.ndarray else np.asarray(v, dtype=np.float64)).tolist()
        else:
            vn = ve = vd = math.nan
        lat = meas.lat
        pos = math.isfinite(lat)  # NaN: a velocity-only fix
        if pos and self._e_cons[0] >= self._reset_after:
            self._hold_reset(meas, strip_vel=split)
        t = t_vel = meas.t
        if split:
            t_vel = t - self._vel_delay
            self._lib_.cref_gfuse_gnss_split(self._core, self._hist, t, self._vel_delay, lat if pos else math.nan,
                                             meas.lon, meas.h, vn, ve, vd, meas.std_ne, meas.std_d, meas.std_vel,
                                             g)  # fmt: skip
        else:
            self._lib_.cref_gfuse_gnss(self._core, self._hist, t, lat if pos else math.nan, meas.lon, meas.h, vn, ve,
                                       vd, meas.std_ne, meas.std_d, meas.std_vel, g)  # fmt: skip
        self._gnss_gates(meas, self._ffi.unpack(g, 8), pos, split, t_vel)

    def _gnss_gates(self, meas: GnssFix, r: Sequence[float], pos: bool, split: bool, t_vel: float) -> None:
        """After a fix's C update (:meth:`_fuse_gnss`, :meth:`run_gnss`), from its gates ``r`` (``cref_gfuse_gnss``'s
        8 values): the ratios, the rejected positions kept for a reset, NavCore's gate events."""
        ratios = self._ratios
        if pos:
            ratios = dict(ratios)
            ratios["gnss_pos"] = r[0]
            if r[1]:  # the fix as the position update saw it (the position alone of a split)
                self._rejected.append((dataclasses.replace(meas, vel_ned=None) if split else meas, r[0]))
            elif self._rejected:
                self._rejected.clear()
            self._gate_event(meas.t, "gnss_pos", r)
        if meas.vel_ned is not None and self._use_vel:
            ratios = dict(ratios) if ratios is self._ratios else ratios
            ratios["gnss_vel"] = r[4]
            self._gate_event(t_vel, "gnss_vel", r[4:])
        self._ratios = ratios

    def _fuse_one(self, meas: AidSample) -> None:
        """A baro altitude or a magnetometer field into the C core (through the roll-back history), with its gate
        (``cref_gfuse_*``) for the ratios and NavCore's gate events."""
        kind = meas.kind  # the C core's functions of the aids it supports (the others: its "not supported" list)
        g = self._gate
        tt = meas.t
        if kind == "baro":
            meas = cast(BaroSample, meas)
            alt = meas.altitude
            if not math.isfinite(alt):
                if not meas.pressure > 0.0:
                    return None
                from ins_hil.nav.earth import altitude_from_pressure

                alt = altitude_from_pressure(meas.pressure)
            self._lib_.cref_gfuse_baro(self._core, self._hist, tt, alt, g)
            r = self._ffi.unpack(g, 4)
            ratios = dict(self._ratios)
            ratios["baro"] = r[0]
            self._ratios = ratios
            self._gate_event(tt, "baro", r)
        elif kind == "mag" and self._have_mag:
            meas = cast(MagSample, meas)
            fx, fy, fz = np.asarray(meas.field_b, dtype=np.float64).tolist()
            self._lib_.cref_gfuse_mag(self._core, self._hist, tt, fx, fy, fz, g)
            ratios = dict(self._ratios)
            ratios["mag"] = g[0]  # no gate events for the magnetometer (as NavCore)
            self._ratios = ratios
        return None

    def _gate_event(self, t: float, kind: str, r: Sequence[float]) -> None:
        """NavCore's event of a GNSS or baro gate (group ``kind``, its ``cref_gfuse_*`` gate ``r``: test ratio,
        rejected, rejections in a row before and after): its first rejection, or accepted again after some; else
        nothing."""
        sensor = "gnss" if kind.startswith("gnss") else "baro"
        if r[1] and r[2] == 0:
            self._events.append(FaultEvent(t, sensor, FaultMode.JUMP, float("nan"), True, False,
                                           f"{kind} innovation test ratio {r[0]:.2f}"))  # fmt: skip
        elif r[3] == 0 and r[2] > 0:
            self._events.append(FaultEvent(t, sensor, FaultMode.JUMP, 0.0, True, True,
                                           f"{kind} accepted again after {int(r[2])} rejections"))  # fmt: skip

    def _hold_reset(self, meas: GnssFix, strip_vel: bool = False) -> None:
        """Before a fix reaches the C core: when its count of rejected positions would force this one in (a
        GNSS reset), allow it only if the rejected fixes and this one pass the consistency test of the Python
        core (``ins_hil.core.gnss_fixes_agree``, each rejected one within ``RESET_GATE_FACTOR`` gates unless
        no position was ever accepted); otherwise hold the count one below the reset, so the fix is gated."""
        e = self._core.ekf
        n = int(self.cfg.gnss.reset_after)
        if int(e.consecutive[0]) < n:
            return
        if strip_vel:  # the position alone of a gnss.vel_delay split
            meas = dataclasses.replace(meas, vel_ned=None)
        fixes = [(f, q) for f, q in self._rejected if f.t < meas.t]
        ok = len(fixes) >= n
        if ok:
            ok = gnss_fixes_agree([f for f, _ in fixes] + [meas], self.cfg)
        if ok and int(e.accepted[0]) > 0 and max(q for _, q in fixes) > RESET_GATE_FACTOR**2:
            st = self.state()  # far beyond the gate: a reset only for a diverged filter (NavCore's rule)
            var = np.asarray(st.std_vel, dtype=float) ** 2
            ok = ins_off_track([f for f, _ in fixes] + [meas], st.vel_ned, var, self.cfg) is not None  # no _recover
        if not ok:
            e.consecutive[0] = n - 1

    @property
    def stats(self) -> dict[str, GateStats]:
        """Accepted / rejected counts per measurement kind (NavCore's ``stats``): the alignment's, then the C
        core's gate counters added."""
        if self._align is not None:
            return dict(self._align.stats)
        e = self._core.ekf
        out = {k: dataclasses.replace(v) for k, v in self._align_stats.items()}
        for g, kind in enumerate(_GROUPS):
            a, r = int(e.accepted[g]), int(e.rejected[g])
            if kind in out or a or r:
                st = out.setdefault(kind, GateStats())
                st.accepted += a
                st.rejected += r
                st.last_ratio = self._ratios.get(kind, st.last_ratio)
        return out

    def align_status(self) -> str:
        """Why the core is not navigating yet ("" once the C core runs)."""
        return "" if self._align is None else str(self._align.align_status())

    @property
    def phase(self) -> str:
        """The alignment phase ("level", "heading") or "nav" (NavCore's)."""
        return "nav" if self._align is None else str(self._align.phase)

    def has_events(self) -> bool:
        """Whether :meth:`drain_events` may have events to give (True while the Python alignment runs)."""
        return self._align is not None or bool(self._events)

    def drain_events(self) -> list[FaultEvent]:
        """GNSS/baro fault events raised by the innovation gates since the last call."""
        if self._align is not None:
            return list(self._align.drain_events())
        ev, self._events = self._events, []
        return ev

    def state(self) -> NavState:
        """The current navigation state (biases and 1-σ from the C filter)."""
        if self._align is not None:
            return self._align.state()
        if self.dt is None:
            s = self._initial
            return NavState(t=s.t, q_nb=s.q_nb.copy(), vel_ned=s.vel_ned.copy(), lat=s.lat, lon=s.lon, h=s.h)
        st = self._st
        if st is not None and st.test_ratios is self._ratios:
            return st
        self._lib_.cref_state(self._core, self._out)
        st = self._st = self._nav_state(self._out_np.copy())
        return st

    def _nav_state(self, o: Vec) -> NavState:
        """The NavState of a 32-value C state record (``cref_state``): t, q_nb, vel_ned, lat, lon, h, gyro_bias,
        accel_bias, std_pos, std_vel, std_att, omega_b and accel_b (the bias-compensated rate and specific force
        of the last interval), the arrays views of ``o``."""
        x = o.tolist()  # the scalars as Python floats in one call
        return NavState(x[0], o[1:5], o[5:8], x[8], x[9], x[10], o[11:14], o[14:17], o[17:20], o[20:23], o[23:26],
                        o[26:29], o[29:32], x[25] < self._aligned_std, self._ratios)  # fmt: skip

    def run(self, dtheta: Vec, dvel: Vec, t_end: Vec | None = None, *, every: int = 1, dt: Vec | None = None) -> Vec:
        """Run n IMU intervals in ONE C call (the core must have its dt; through the roll-back history).

        dtheta, dvel: (n, 3) increments (rad, m/s, body FRD); t_end: (n,) sensor times or None
        (t advances by dt); dt: (n,) each interval's length (s; ``fixed_step=False``) or None (the fixed
        step). Returns an (n, 11) array of states, columns ``RUN_COLUMNS`` (every=0: no output, returns an
        empty array).
        """
        if self.dt is None:
            raise ValueError("CNavCore.run: the fixed step is unknown; pass dt to the constructor")
        dtheta = np.asarray(dtheta, dtype=np.float64)
        dvel = np.asarray(dvel, dtype=np.float64)
        if dtheta.ndim != 2 or dtheta.shape[1] != 3 or dvel.shape != dtheta.shape:
            raise ValueError(f"CNavCore.run: dtheta and dvel must both be (n, 3), got {dtheta.shape} and {dvel.shape}")
        n = dtheta.shape[0]
        self._st = None
        inc = np.ascontiguousarray(np.hstack((dtheta, dvel)))
        ffi = self._ffi
        tp = dp = ffi.NULL
        if t_end is not None:
            t_arr = np.ascontiguousarray(t_end, dtype=np.float64)
            if t_arr.shape != (n,):
                raise ValueError(f"CNavCore.run: t_end must be ({n},), got {t_arr.shape}")
            tp = ffi.from_buffer("double[]", t_arr)
        if dt is not None:
            d_arr = np.ascontiguousarray(dt, dtype=np.float64)
            if d_arr.shape != (n,) or not np.all(d_arr > 0.0):
                raise ValueError(f"CNavCore.run: dt must be ({n},) positive values")
            dp = ffi.from_buffer("double[]", d_arr)
        if every == 0:
            self._lib_.cref_run(self._core, self._hist, ffi.from_buffer("double[]", inc), tp, dp, n, ffi.NULL, 0, 0)
            return np.empty((0, len(RUN_COLUMNS)))
        out = np.empty((n, len(RUN_COLUMNS)))
        self._lib_.cref_run(
            self._core,
            self._hist,
            ffi.from_buffer("double[]", inc),
            tp,
            dp,
            n,
            ffi.from_buffer("double[]", out),
            len(RUN_COLUMNS),
            0,
        )
        return out[every - 1 :: every] if every > 1 else out

    def can_run(self) -> bool:
        """True when :meth:`run_states` may take the next samples: the C core navigates (the alignment has
        handed over) and steps each sample over its own ``dt`` (``fixed_step=False``); or the alignment waits for
        its yaw with nothing but gyro-only steps to run (:meth:`_heading_runs`)."""
        if self._align is not None:
            return not self.fixed_step and (self._level_runs() or self._heading_runs())
        return self.dt is not None and not self.fixed_step and self.filter

    def _level_runs(self) -> bool:
        """The alignment is levelling with its window on C (:class:`_CAlignment`), its start-up check and yaw bank
        (if any) on C: its IMU samples may run on C (``cref_level_run``)."""
        a = self._align
        if a is None or a.phase != "level":
            return False
        al = a.align
        return bool(
            isinstance(al, _CAlignment) and al.on_c and a.pending_end is None
            and not a.replaying and (a.sensor_check is None or isinstance(a.sensor_check, _CSensorCheck))
            and (a.yaw_gsf is None or isinstance(a.yaw_gsf, CYawGsf))
        )  # fmt: skip

    def _heading_runs(self) -> bool:
        """The alignment is in its heading phase (levelled, waiting for the GNSS course or the yaw bank), its
        start-up sensor check judged, with the mechanization the C step mirrors (NavCore's default StrapdownNED)
        and its yaw bank on C (or none): its IMU steps may run on C (``ins_align_heading_step``)."""
        a = self._align
        if a is None or a.phase != "heading" or a.sensor_check is not None or a.pending_end is not None:
            return False
        ins = a.ins
        return bool(
            ins._att is None and not ins._j2 and ins.coning and ins.sculling and ins.earth_rate
            and ins.renorm_every == 1 and not a.replaying and (a.yaw_gsf is None or isinstance(a.yaw_gsf, CYawGsf))
        )  # fmt: skip

    def _heading_states(self, inc: Vec, t_end: Vec, dt: Vec) -> RunStates:
        """:meth:`run_states` in the alignment's heading phase: the n gyro-only steps (and the yaw bank) of the
        alignment's ``NavCore`` in one C call (``cref_heading_run``, the double build: the alignment's numbers),
        its StrapdownNED set before and read back after; per step the state ``NavCore.step`` returns (as the rows
        of the C state record: each ``NavState`` built when asked for)."""
        a = self._align
        ffi, lib = _lib("double")
        fb = ffi.from_buffer
        if self._hmech is None:
            self._hmech = ffi.new("ins_mech_t *")
        m = self._hmech
        _mech_on_c(a.ins, ffi, m)
        n = len(t_end)
        out = np.empty((n, 11))  # t, q[4], lat, lon, h, omega_b[3]
        gsf = a.yaw_gsf._g if a.yaw_gsf is not None else ffi.NULL
        lib.cref_heading_run(m, gsf, fb("double[]", inc), fb("double[]", t_end), fb("double[]", dt), n, _f64(ffi, a.bg),
                             _f64(ffi, a.ba), fb("double[]", out))  # fmt: skip
        _mech_back(a.ins, m, n)
        a.omega_b = out[-1, 8:11].copy()
        a._dt = float(dt[-1])
        st = a.state()  # the σ (P does not change before the hand-over), the biases, f_b and the gate ratios
        ro = np.empty((n, 32))  # the C record layout (the core guard: first_bad; RunStates)
        ro[:, 0:5] = out[:, 0:5]
        ro[:, 5:8] = 0.0  # the velocity held at zero
        ro[:, 8:11] = out[:, 5:8]
        ro[:, 11:14], ro[:, 14:17], ro[:, 17:20], ro[:, 20:23] = a.bg, a.ba, st.std_pos, st.std_vel
        ro[:, 23:26], ro[:, 26:29], ro[:, 29:32] = st.std_att, out[:, 8:11], a.f_b
        self.run_out = ro
        return RunStates(ro, -math.inf, st.test_ratios)  # never "aligned" before navigation

    def _level_states(self, inc: Vec, t_end: Vec, dt: Vec) -> Sequence[NavState]:
        """:meth:`run_states` while the alignment levels: the samples through its start-up check, yaw bank and
        levelling window in one C call (``cref_level_run``) up to the sample at which the check judges (its Python
        then: ``SensorCheck._judge``) or the levelling is due; per step the state ``NavCore.step`` returns. The
        run stops before the sample at which the levelling is due, unless it is the run's first: that one is
        levelled with one :meth:`step` (``Alignment._level``, and the hand-over if it navigates), the rest of the
        run in the phase it leads to (:meth:`_after_level`). So a run never holds states from before and after
        the start of navigation."""
        a = self._align
        al = a.align
        ffi, lib = al._ffi, al._clib
        fb = ffi.from_buffer
        n = len(t_end)
        done = self._done
        if done is None:
            done = self._done = ffi.new("size_t *")
        parts: list[Any] = []  # RunStates of the levelling samples, lists of the others
        rows: list[Vec] = []
        k, first = 0, True  # (run_states has checked _level_runs for the first pass)
        while k < n:
            if not first and not self._level_runs():  # levelled (at the run's first sample), or the window left C
                st, ro, gaps = self._after_level(inc[k:], t_end[k:], dt[k:])
                self.run_gap_rows = [k + g for g in gaps]
                parts.append(st)
                rows.append(ro)
                break
            first = False
            chk = a.sensor_check
            al.put()
            r = lib.cref_level_run(al.lv, chk.c if chk is not None else ffi.NULL,
                                   a.yaw_gsf._g if a.yaw_gsf is not None else ffi.NULL, fb("double[]", a.bg),
                                   fb("double[]", inc[k:]), fb("double[]", t_end[k:]), fb("double[]", dt[k:]), n - k,
                                   done)  # fmt: skip
            m = int(done[0])
            al.get()
            if m:
                a.ins.state.t = float(t_end[k + m - 1])
                a._dt = float(dt[k + m - 1])
                if r & lib.CREF_LEVEL_CHECKED:
                    chk.judge()
                    a._sensor_checked(chk)
                ro = np.empty((m, 32))
                ro[:] = _record(a.state())
                ro[:, 0] = t_end[k : k + m]
                rows.append(ro)
                parts.append(RunStates(ro, -math.inf, a._ratios))  # never "aligned" before navigation
                k += m
            if r & lib.INS_LEVEL_DUE and k:  # levelled at the next call (its first sample)
                break
            if r & (lib.INS_LEVEL_DUE | lib.CREF_LEVEL_BAD):
                # levelled one sample at a time (Alignment._level; the hand-over); a bad one: NavCore.step's
                # check_imu refuses it (ValueError, one line)
                st1 = self.step(ImuSample(t=float(t_end[k]), dt=float(dt[k]), dtheta=inc[k, :3], dvel=inc[k, 3:]))
                parts.append([st1])
                rows.append(_record(st1)[None, :])
                k += 1
            elif r & lib.INS_LEVEL_FULL:
                al.to_python()
        self.run_out = rows[0] if len(rows) == 1 else np.concatenate(rows)
        if len(parts) == 1:
            return cast(Sequence[NavState], parts[0])
        return [st for p in parts for st in p]

    def _after_level(self, inc: Vec, t_end: Vec, dt: Vec) -> tuple[Sequence[NavState], Vec, list[int]]:
        """The samples of a :meth:`run_states` call after the levelling (or after its window left C): through
        :meth:`run_states` when :meth:`can_run`, else one :meth:`step_begin` each. Their states, records and the
        rows with lost IMU data before them (each a DROPOUT event)."""
        if not len(t_end):
            return [], np.zeros((0, 32)), []
        if self.can_run():
            st = self.run_states(inc, t_end, dt)
            return st, self.run_out, self.run_gap_rows
        out: list[NavState] = []
        gaps = []
        for k in range(len(t_end)):
            ev = len(self._events)
            out.append(self.step_begin(ImuSample(t=float(t_end[k]), dt=float(dt[k]), dtheta=inc[k, :3],
                                                 dvel=inc[k, 3:])))  # fmt: skip
            if len(self._events) > ev:
                gaps.append(k)
        return out, np.array([_record(st) for st in out]), gaps

    def run_states(self, inc: Vec, t_end: Vec, dt: Vec) -> Sequence[NavState]:
        """:meth:`step` on n samples in ONE C call (through the roll-back history): ``inc`` (n, 6) float64 dθ, dv
        (rad, m/s, body FRD), ``t_end``, ``dt`` (n,) s. Returns, per step, the state :meth:`step_begin` returns
        (the one published after the mechanization, the same C record), and records the IMU data lost before a
        sample as :meth:`step` does (``imu_lost``, a DROPOUT event); :meth:`state` is the state after the last
        step (time update included). Only when :meth:`can_run`. While the alignment levels, the states of the
        first m ≤ n samples: a run stops before the sample at which the levelling is due (unless it is its first;
        :meth:`_level_states`): the caller hands the rest over again."""
        n = len(t_end)
        self.run_gap_rows = []
        inc = np.ascontiguousarray(inc, dtype=np.float64)
        t_end = np.ascontiguousarray(t_end, dtype=np.float64)
        dt = np.ascontiguousarray(dt, dtype=np.float64)
        if inc.shape != (n, 6) or dt.shape != (n,) or not self.can_run():
            raise ValueError("CNavCore.run_states: (n, 6) increments, (n,) times and steps, on a navigating core "
                             "with fixed_step=False")  # fmt: skip
        if self._align is not None:
            if not n:
                return []
            if self._align.phase == "level":
                return self._level_states(inc, t_end, dt)
            return self._heading_states(inc, t_end, dt)
        if n:  # the IMU data lost before each sample (step()'s record; none before the first step)
            t0 = float(self._core.mech.t)
            if n <= 16:  # a short run (a replay's samples between two aiding measurements): in Python floats
                tl = t_end.tolist()
                lost_l: list[Any] = list(map(imu_lost, tl, dt.tolist(), [t0, *tl[:-1]]))  # (None: no data lost)
                rows = [k for k, x in enumerate(lost_l) if x is not None]
            else:  # in one numpy pass
                prev = np.empty(n)
                prev[0] = t0
                prev[1:] = t_end[:-1]
                lost, gap = imu_lost_v(t_end, dt, prev)
                rows = np.nonzero(gap)[0].tolist()
                lost_l = lost.tolist()
            if rows and rows[0] == 0 and int(self._core.steps) == 0:
                rows = rows[1:]
            self.run_gap_rows = rows
            for k in rows:
                lk = cast(float, lost_l[k])
                tk = float(t_end[k] - dt[k])
                self.imu_lost = (self.imu_lost[0] + 1, self.imu_lost[1] + lk)
                self._events.append(
                    FaultEvent(tk, "imu", FaultMode.DROPOUT, lk, True, True,
                               f"IMU data lost for {lk:.3f} s: coasted at constant velocity, covariance grown")
                )  # fmt: skip
        out = np.empty((n, 32))
        fb = self._ffi.from_buffer
        self._st = None  # the state after the time update: built by state() when asked
        self._publish()
        self._lib_.cref_run(self._core, self._hist, fb("double[]", inc), fb("double[]", t_end),
                            fb("double[]", dt), n, fb("double[]", out), 32, 1)  # fmt: skip
        self.run_out = out
        return RunStates(out, self.cfg.alignment.aligned_yaw_std, self._ratios)

    def first_bad(self, rows: Vec, qnorm_tol: float, speed_max: float, h_min: float, h_max: float) -> int:
        """The index of the first of ``rows`` ((n, ≥ 26) C state records, e.g. :attr:`run_out`) that fails the core
        guard whose bounds are given (``ins_hil.runtime.pipeline.state_ok``'s: | |q|² − 1 | < ``qnorm_tol``,
        |v| < ``speed_max`` m/s, ``h_min`` < h < ``h_max`` m, latitude, longitude and every σ), in one C call
        (``cref_guard``: the same comparisons, NaN fails each); n when every row passes."""
        rows = np.ascontiguousarray(rows, dtype=np.float64)
        if rows.ndim != 2 or rows.shape[1] < 26:
            raise ValueError(f"CNavCore.first_bad: expected (n, >= 26) C state records, got shape {rows.shape}")
        n = len(rows)
        if not n:
            return 0
        return int(self._lib_.cref_guard(self._ffi.from_buffer("double[]", rows), n, rows.shape[1], qnorm_tol,
                                         speed_max * speed_max, h_min, h_max))  # fmt: skip

    def state_guard(self, qnorm_tol: float, speed_max: float, h_min: float, h_max: float) -> bool | None:
        """Whether :meth:`state` passes the core guard whose bounds are given (:meth:`first_bad`'s), from the C
        state record in one call, no ``NavState`` built; None while the Python alignment runs (or before the
        fixed step is known): the caller checks :meth:`state` itself."""
        if self._align is not None or self.dt is None:
            return None
        lib = self._lib_
        lib.cref_state(self._core, self._out)  # (cref_guard: the index of the first that fails, 1 = none)
        return bool(lib.cref_guard(self._out, 1, 32, qnorm_tol, speed_max * speed_max, h_min, h_max) == 1)

    def run_increments(self, inc: Vec, t_end: Vec, dt: Vec) -> None:
        """:meth:`run` without output for a caller that has its increments stacked already: ``inc`` (n, 6)
        C-contiguous float64 (dθ rad, dv m/s, body FRD), ``t_end`` and ``dt`` (n,) float64 (s); slices of the
        whole log's arrays (no copy). The delayed-fusion replay loop of a log (``ins_hil.bench.core_replay``)."""
        n = len(t_end)
        if self.dt is None or inc.shape != (n, 6) or len(dt) != n or not inc.flags.c_contiguous:
            self.run(inc[:, :3], inc[:, 3:], t_end, every=0, dt=dt)  # checks and says what is wrong
            return
        fb = self._ffi.from_buffer
        self._st = None
        self._lib_.cref_run(self._core, self._hist, fb("double[]", inc), fb("double[]", t_end), fb("double[]", dt), n,
                            self._ffi.NULL, 0, 0)  # fmt: skip

    def lost_before(self, t_end: float, dt: float) -> bool:
        """Whether :meth:`run_states` would record IMU data lost before a next sample ending at ``t_end`` s, ``dt``
        s long (its DROPOUT record)."""
        return int(self._core.steps) > 0 and imu_lost(t_end, dt, float(self._core.mech.t)) is not None

    def _groups_ok(self, inc: Vec, t_end: Vec, dt: Vec, k0: int, end: Vec, ab: Vec, n_upd: int) -> bool:
        """Whether the core navigates with its own steps and the groups of :meth:`run_baro` / :meth:`run_gnss` are
        well formed: C-contiguous float64 (n, 6) ``inc``, (n,) ``t_end`` and ``dt``; int64 ``end`` rising from ``k0``
        to at most n; int64 ``ab`` (len(end) + 1) rising within the ``n_upd`` updates."""
        ng = len(end)
        return bool(
            self.can_run() and self._align is None and len(ab) == ng + 1 and inc.shape == (len(t_end), 6)
            and len(dt) == len(t_end) and all(a.dtype == np.float64 and a.flags.c_contiguous for a in (inc, t_end, dt))
            and end.dtype == np.int64 and ab.dtype == np.int64
            and (not ng or (end[0] > k0 >= 0 and end[-1] <= len(t_end) and ab[0] >= 0 and ab[-1] <= n_upd
                            and bool(np.all(np.diff(end) > 0)) and bool(np.all(np.diff(ab) >= 0))))
        )  # fmt: skip

    def run_baro(self, inc: Vec, t_end: Vec, dt: Vec, k0: int, end: Vec, ab: Vec, bt: Vec, alt: Vec,
                 bounds: tuple[float, float, float, float]) -> AidRun:  # fmt: skip
        """:meth:`run_states` and :meth:`fuse` of baro altitudes alternately in ONE C call (``cref_run_baro``; an
        offline replay's stretch of baro samples between two other measurements): group g is the IMU samples
        ``[end[g - 1], end[g])`` of the whole log's ``inc`` (n, 6), ``t_end``, ``dt`` (n,) (C-contiguous float64;
        ``end[-1]`` = ``k0``), then the baro updates ``[ab[g], ab[g + 1])`` at times ``bt`` (s) with altitudes
        ``alt`` (m, finite) (``end``, ``ab`` int64). The samples must have no IMU data lost before them (the
        caller's check: no DROPOUT record). ``bounds``: the core guard's (:meth:`first_bad`'s qnorm_tol, speed_max,
        h_min, h_max). The call stops after a group whose states fail the guard (its updates not run), or after an
        update whose gate is not a plain acceptance (its gate event raised here, as :meth:`fuse`) or whose state then
        fails the guard (:class:`AidRun` says which). The ratios and the gate counters as :meth:`fuse` leaves
        them."""
        ng = len(end)
        if not self._groups_ok(inc, t_end, dt, k0, end, ab, len(bt)) or len(alt) != len(bt) or any(
            a.dtype != np.float64 or not a.flags.c_contiguous for a in (bt, alt)
        ):  # fmt: skip
            raise ValueError("CNavCore.run_baro: a navigating core with fixed_step=False, C-contiguous float64 "
                             "(n, 6) increments, times and steps, baro times and altitudes; int64 end rising from "
                             "k0 to at most n, ab = len(end) + 1 bounds rising within the baro samples")  # fmt: skip
        n_imu = int(end[-1]) - k0 if ng else 0
        n_upd = int(ab[-1] - ab[0]) if ng else 0
        out = np.empty((n_imu, 32))
        pre = np.empty((n_upd, 2))
        gate = np.empty((n_upd, 4))
        ffi = self._ffi
        fb = ffi.from_buffer
        groups = ffi.new("size_t *")
        why = ffi.new("int *")
        q, v, h0, h1 = bounds
        self._st = None
        self._publish()
        u = int(self._lib_.cref_run_baro(
            self._core, self._hist, fb("double[]", inc), fb("double[]", t_end), fb("double[]", dt), k0,
            fb("int64_t[]", end), fb("int64_t[]", ab), ng, fb("double[]", bt), fb("double[]", alt), fb("double[]", out),
            fb("double[]", pre), fb("double[]", gate), q, v * v, h0, h1, groups, why,
        ))  # fmt: skip
        g = int(groups[0])
        rows = out[: (int(end[g - 1]) - k0) if g else 0]
        self.run_out = rows
        self.run_gap_rows = []
        # each group's states carry the ratios in force when it ran (one fuse per sample: each run its own):
        # group gi's are those after the baro update before it, ab[gi] - ab[0] - 1
        at, r = [(0, self._ratios)], self._ratios
        for gi in range(1, g):
            done = int(ab[gi] - ab[0])
            if 0 < done <= u:
                r = {**r, "baro": float(gate[done - 1, 0])}
                at.append((int(end[gi - 1]) - k0, r))
        if u:
            self._ratios = {**self._ratios, "baro": float(gate[u - 1, 0])}
            if why[0] >= 2:  # the last update's gate (_gate_event decides whether it raises an event)
                self._gate_event(float(bt[int(ab[0]) + u - 1]), "baro", gate[u - 1].tolist())
        aligned = (pre[:u, 1] < self._aligned_std).tolist()
        states = RunStates(rows, self.cfg.alignment.aligned_yaw_std, at[-1][1], ratios_from=at)
        return AidRun(states, g, u, int(why[0]), pre[:u, 0].tolist(), aligned)

    def run_gnss(self, inc: Vec, t_end: Vec, dt: Vec, k0: int, end: Vec, ab: Vec, fixes: Sequence[GnssFix],
                 bounds: tuple[float, float, float, float] | None = None, records: bool = True) -> AidRun:  # fmt: skip
        """:meth:`run_baro` with GNSS fixes: :meth:`run_states` and :meth:`fuse` of ``fixes`` alternately in ONE C
        call (``cref_run_gnss``; an offline replay's stretch of fixes between two other measurements): group g is
        the IMU samples ``[end[g - 1], end[g])`` of ``inc`` (n, 6), ``t_end``, ``dt`` (n,), then the fixes
        ``[ab[g], ab[g + 1])``, each as :meth:`fuse` takes it (with ``gnss.vel_delay`` its velocity at its own earlier
        time). Each fix's velocity is None or finite; no rejected fix is held for a reset (:meth:`fuse` does the
        rest). Stops as :meth:`run_baro` (a fix whose position or velocity gate is not a plain acceptance: its events
        raised here, as :meth:`fuse`); the ratios, the rejected fixes and the gate counters as :meth:`fuse` leaves
        them. ``bounds``: the core guard's (:meth:`first_bad`), None: none (every state passes but NaN).
        ``records=False``: no states (an empty ``states``, ``t_pre``, ``aligned``) and no guard: the runs as
        :meth:`run_increments`."""
        ng = len(end)
        if self._rejected or not self._groups_ok(inc, t_end, dt, k0, end, ab, len(fixes)):
            raise ValueError("CNavCore.run_gnss: a navigating core with fixed_step=False and no rejected fix held, "
                             "C-contiguous float64 (n, 6) increments, times and steps; int64 end rising from k0 to "
                             "at most n, ab = len(end) + 1 bounds rising within the fixes")  # fmt: skip
        nan3 = (math.nan, math.nan, math.nan)
        fix = np.array([(f.t, f.lat, f.lon, f.h, *(nan3 if f.vel_ned is None else f.vel_ned), f.std_ne, f.std_d,
                         f.std_vel) for f in fixes], dtype=np.float64).reshape(len(fixes), 10)  # fmt: skip
        has_vel = np.array([f.vel_ned is not None for f in fixes], dtype=bool)
        if not bool(np.all(np.isfinite(fix[has_vel, 4:7]))):
            raise ValueError("CNavCore.run_gnss: a fix's velocity must be None or finite (fuse takes the others)")
        if not bool(np.all(fix[:, 7:] >= 0.0)):
            _refuse_gnss_std(fixes[int(np.argmin(np.all(fix[:, 7:] >= 0.0, axis=1)))])  # the first that fails
        pos = np.isfinite(fix[:, 1])
        fix[~pos, 1] = math.nan  # as fuse: a latitude that is not finite is no position
        if ng and self._e_cons[0] >= self._reset_after and bool(pos[int(ab[0]) : int(ab[-1])].any()):
            raise ValueError("CNavCore.run_gnss: a GNSS reset is due (fuse the next fix on its own)")
        n_upd = int(ab[-1] - ab[0]) if ng else 0
        gate = np.empty((n_upd, 8))
        ffi = self._ffi
        fb = ffi.from_buffer
        groups = ffi.new("size_t *")
        why = ffi.new("int *")
        q, vmax, h0, h1 = bounds if bounds is not None and records else (math.inf, math.inf, -math.inf, math.inf)
        self._st = None
        if records:
            out = np.empty(((int(end[-1]) - k0) if ng else 0, 32))
            pre = np.empty((n_upd, 2))
            self._publish()
            out_p, pre_p = fb("double[]", out), fb("double[]", pre)
        else:
            out, pre = np.empty((0, 32)), np.empty((0, 2))
            out_p = pre_p = ffi.NULL
        u = int(self._lib_.cref_run_gnss(
            self._core, self._hist, fb("double[]", inc), fb("double[]", t_end), fb("double[]", dt), k0,
            fb("int64_t[]", end), fb("int64_t[]", ab), ng, fb("double[]", fix), self._vel_delay, int(self._use_vel),
            out_p, pre_p, fb("double[]", gate), q, vmax * vmax, h0, h1, groups, why,
        ))  # fmt: skip
        g = int(groups[0])
        a0 = int(ab[0]) if ng else 0
        # the fixes before the last were plain acceptances: they set the ratios only (the last fix as fuse leaves it)
        use_vel = has_vel & self._use_vel
        at: list[tuple[int, dict[str, float]]] = [(0, self._ratios)]

        def ratios_after(j: int, base: dict[str, float]) -> dict[str, float]:
            """The ratios after fix a0 + j of a run of plain acceptances from ``base`` (the ratios before it)."""
            r = dict(base)
            ip = np.flatnonzero(pos[a0 : a0 + j + 1])
            iv = np.flatnonzero(use_vel[a0 : a0 + j + 1])
            if len(ip):
                r["gnss_pos"] = float(gate[ip[-1], 0])
            if len(iv):
                r["gnss_vel"] = float(gate[iv[-1], 4])
            return r

        if records:  # each group's states carry the ratios in force when it ran: those after the fix before it
            base = self._ratios
            for gi in range(1, g):
                done = int(ab[gi]) - a0
                if 0 < done <= u:
                    at.append((int(end[gi - 1]) - k0, ratios_after(done - 1, base)))
        if u:
            if u > 1:
                self._ratios = ratios_after(u - 2, self._ratios)
            i = a0 + u - 1
            split = bool(has_vel[i]) and self._vel_delay > 0.0
            t_vel = fixes[i].t - self._vel_delay if split else fixes[i].t
            self._gnss_gates(fixes[i], gate[u - 1].tolist(), bool(pos[i]), split, t_vel)
        rows = out[: (int(end[g - 1]) - k0) if g else 0] if records else out
        self.run_out = rows
        self.run_gap_rows = []
        aligned = (pre[:u, 1] < self._aligned_std).tolist()
        states = RunStates(rows, self.cfg.alignment.aligned_yaw_std, at[-1][1], ratios_from=at)
        return AidRun(states, g, u, int(why[0]), pre[:u, 0].tolist(), aligned)

    def covariance(self) -> Vec:
        """The EKF covariance P (15 × 15, order δr NED, δv NED, ψ NED, δb_g, δb_a; 21 × 21 with the scale factors
        δs_g, δs_a after them, as ``NavCore.kf.P``)."""
        p = self._core.ekf.P
        n = int(self._core.ekf.nx)
        return np.array([[float(p[i][j]) for j in range(n)] for i in range(n)])


def _refuse_gnss_std(meas: GnssFix) -> NoReturn:
    """ValueError (one line) naming the first of ``meas``'s σ (``std_ne``, ``std_d``, ``std_vel``) that is not a
    number >= 0 (:meth:`CNavCore.fuse`, :meth:`CNavCore.run_gnss`; the caller found one)."""
    for name in ("std_ne", "std_d", "std_vel"):
        sd = getattr(meas, name)
        if not sd >= 0.0:
            raise ValueError(f"GnssFix.{name} must be >= 0, got {sd!r}")
    raise ValueError("GnssFix: every σ must be >= 0")


def _record(st: NavState) -> Vec:
    """The 32-value C state record (``cref_state``'s layout) of ``st``."""
    return np.concatenate(((st.t,), st.q_nb, st.vel_ned, (st.lat, st.lon, st.h), st.gyro_bias, st.accel_bias,
                           st.std_pos, st.std_vel, st.std_att, st.omega_b, st.accel_b))  # fmt: skip


@dataclasses.dataclass
class AidRun:
    """What :meth:`CNavCore.run_baro` or :meth:`CNavCore.run_gnss` ran: the IMU states of its groups (``states``:
    those of the first ``groups`` groups), the updates run (``updates``, from the first), why it stopped (``why``: 0
    all ran, 1 a state of the last group's run failed the core guard, its updates not run, 2 the last update's gate
    was not a plain acceptance, 3 the state after the last update failed the core guard) and per update the time (s)
    of the state it was fused into (``t_pre``) and whether that state was aligned (``aligned``:
    ``NavState.aligned``)."""

    states: RunStates
    groups: int
    updates: int
    why: int
    t_pre: list[float]
    aligned: list[bool]


class RunStates(Sequence[NavState]):
    """The states of one :meth:`CNavCore.run_states` call as a sequence: each ``NavState`` built from its row of
    the C state record (``rows``, (n, 32): ``cref_state``'s layout) when asked for, as ``CNavCore._nav_state``
    builds it (the arrays views of the row), with ``resets`` set; an observer that only keeps the arrays reads
    ``rows`` (and ``times``) and builds none."""

    def __init__(self, rows: Vec, aligned_yaw_std: float, ratios: dict[str, float], resets: int = 0,
                 ratios_from: list[tuple[int, dict[str, float]]] | None = None) -> None:  # fmt: skip
        """``ratios``: every state's test ratios; or ``ratios_from`` [(first row, ratios), …] ascending from row 0:
        each row those of the last entry at or before it (the groups of :meth:`CNavCore.run_baro`)."""
        self.rows = rows
        self.resets = resets
        self._thr = aligned_yaw_std
        self._ratios = ratios
        self._from = ratios_from if ratios_from is not None and len(ratios_from) > 1 else None

    def _ratios_at(self, i: int) -> dict[str, float]:
        if self._from is None:
            return self._ratios
        i = i + len(self.rows) if i < 0 else i
        return self._from[bisect.bisect_right(self._from, i, key=lambda e: e[0]) - 1][1]

    def __len__(self) -> int:
        return len(self.rows)

    def times(self) -> list[float]:
        """Each state's time (s)."""
        return cast(list[float], self.rows[:, 0].tolist())

    def head(self, n: int) -> RunStates:
        """The first ``n`` states."""
        return RunStates(self.rows[:n], self._thr, self._ratios, self.resets, self._from)

    def tail(self, k: int) -> RunStates:
        """The states from the ``k``-th on."""
        k = len(self.rows) if k > len(self.rows) else (max(0, k + len(self.rows)) if k < 0 else k)
        at = None if self._from is None else [(0, self._ratios_at(k))] + [(s - k, r) for s, r in self._from if s > k]
        return RunStates(self.rows[k:], self._thr, self._ratios, self.resets, at)

    @overload
    def __getitem__(self, i: int) -> NavState: ...

    @overload
    def __getitem__(self, i: slice) -> Sequence[NavState]: ...

    def __getitem__(self, i: int | slice) -> NavState | Sequence[NavState]:
        if isinstance(i, slice):
            return [self[k] for k in range(*i.indices(len(self.rows)))]
        o = self.rows[i]
        x = o.tolist()  # the scalars as Python floats in one call (CNavCore._nav_state)
        st = NavState(x[0], o[1:5], o[5:8], x[8], x[9], x[10], o[11:14], o[14:17], o[17:20], o[20:23], o[23:26],
                      o[26:29], o[29:32], x[25] < self._thr, self._ratios_at(i))  # fmt: skip
        st.resets = self.resets
        return st


def make_core(kind: str, initial: StrapdownState, config: NavConfig | None = None, **kwargs: Any) -> Any:
    """The navigation core by name: ``"python"`` (ins_hil.core.NavCore) or ``"c"`` (CNavCore)."""
    if kind == "python":
        from ins_hil.core import NavCore

        return NavCore(initial, config)
    if kind == "c":
        return CNavCore(initial, config, **kwargs)
    raise ValueError(f"unknown core {kind!r}: choose 'python' or 'c'")
