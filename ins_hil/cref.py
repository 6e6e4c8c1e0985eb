"""The C99 reference core (``firmware_ref/``) behind the :class:`ins_hil.core.NavCore` interface.

``CNavCore(initial)`` has the same ``step(imu) -> NavState``, ``fuse(meas)`` and
``state()`` as the Python ``NavCore``, so the runtime and replay can run on
either core (``make_core("python" | "c", initial)``). The C sources are
compiled at install time by cffi (``firmware_ref/cffi_build.py``) into
``ins_hil._cref`` (double) and ``ins_hil._cref_f32`` (float).

The C core steps at a fixed period, set at initialisation (``dt``, or the first
sample's ``dt``); a sample whose ``dt`` differs from it by more than
``dt_tolerance`` (relative) is rejected with ``ValueError``. Measurements are
applied at the current IMU time (no delayed fusion in the C core); GNSS
position (+ velocity if present) and baro altitude are used; magnetometer
samples are ignored (the C core has no magnetometer update).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from ins_hil.nav.mechanization import StrapdownState
from ins_hil.types import BaroSample, GnssFix, ImuSample, MagSample, NavState, Vec

Precision = Literal["double", "float"]


def _lib(precision: Precision) -> tuple[Any, Any]:
    try:
        if precision == "double":
            from ins_hil import _cref as mod  # type: ignore[attr-defined]
        elif precision == "float":
            from ins_hil import _cref_f32 as mod  # type: ignore[attr-defined]
        else:
            raise ValueError(f"precision must be 'double' or 'float', not {precision!r}")
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


@dataclass
class EkfConfig:
    """Noise model and initial uncertainty of the C core's 15-state EKF (SI units, 1-σ).

    Defaults: the MEMS grade of ``ins_hil.sim.sensors.mems_gyro``/``mems_accel``.
    ``*_bias_tau`` ≤ 0 selects a random-walk bias (then ``*_bias_sigma`` is a rate density).
    ``baro_offset``: ellipsoidal height (m) of the baro altitude datum.
    """

    gyro_arw: float = math.radians(0.15) / 60.0
    accel_vrw: float = 70e-6 * 9.80665
    gyro_bias_sigma: float = math.radians(10.0) / 3600.0
    gyro_bias_tau: float = 300.0
    accel_bias_sigma: float = 0.1e-3 * 9.80665
    accel_bias_tau: float = 300.0
    p0_pos: float = 5.0
    p0_vel: float = 0.5
    p0_att: float = math.radians(2.0)
    p0_bg: float = math.radians(0.2)
    p0_ba: float = 20e-3 * 9.80665
    baro_offset: float = 0.0
    baro_std: float = 0.5

    def to_c(self, ffi: Any) -> Any:
        cfg = ffi.new("ins_ekf_cfg_t *")
        for name in (
            "gyro_arw",
            "accel_vrw",
            "gyro_bias_sigma",
            "gyro_bias_tau",
            "accel_bias_sigma",
            "accel_bias_tau",
            "p0_pos",
            "p0_vel",
            "p0_att",
            "p0_bg",
            "p0_ba",
            "baro_offset",
        ):
            value = float(getattr(self, name))
            if not math.isfinite(value):
                raise ValueError(f"EkfConfig.{name} must be finite, got {value!r}")
            setattr(cfg, name, value)
        return cfg


#: columns of CNavCore.run's output array
RUN_COLUMNS = ("t", "q0", "q1", "q2", "q3", "vN", "vE", "vD", "lat", "lon", "h")


class CNavCore:
    """The C reference core with the ``NavCore`` interface.

    initial: the starting state (as for ``NavCore``). dt: the fixed step (s);
    None = take it from the first IMU sample. precision: ``"double"`` or
    ``"float"`` (the C scalar type). filter: run the 15-state EKF predict on
    every step (needed for ``fuse``); False = mechanization only.
    """

    def __init__(
        self,
        initial: StrapdownState,
        dt: float | None = None,
        *,
        precision: Precision = "double",
        filter: bool = True,
        ekf: EkfConfig | None = None,
        dt_tolerance: float = 0.05,
    ) -> None:
        self._ffi, self._lib_ = _lib(precision)
        self.precision = precision
        self.filter = filter
        self.ekf_config = ekf or EkfConfig()
        self.dt_tolerance = dt_tolerance
        self._initial = initial.copy()
        self._core = self._ffi.new("ins_core_t *")
        self._out = self._ffi.new("double[23]")
        self._out_np = np.frombuffer(self._ffi.buffer(self._out), dtype=np.float64)
        self._cfg = self.ekf_config.to_c(self._ffi)
        self.dt: float | None = None
        if dt is not None:
            self._init(dt)

    def _init(self, dt: float) -> None:
        if not (dt > 0.0 and math.isfinite(dt)):
            raise ValueError(f"CNavCore: the fixed step dt must be positive, got {dt!r}")
        s = self._initial
        q = np.ascontiguousarray(s.q_nb, dtype=np.float64)
        v = np.ascontiguousarray(s.vel_ned, dtype=np.float64)
        ffi = self._ffi
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
        self.dt = dt

    def step(self, imu: ImuSample) -> NavState:
        """Propagate with one IMU interval (mechanization + EKF predict); returns the state."""
        if self.dt is None:
            self._init(imu.dt)
        elif abs(imu.dt - self.dt) > self.dt_tolerance * self.dt:
            raise ValueError(f"CNavCore: sample dt {imu.dt!r} s differs from the fixed step {self.dt} s")
        ffi = self._ffi
        dth, dv = imu.dtheta, imu.dvel
        if dth.dtype != np.float64 or not dth.flags.c_contiguous:
            dth = np.ascontiguousarray(dth, dtype=np.float64)
        if dv.dtype != np.float64 or not dv.flags.c_contiguous:
            dv = np.ascontiguousarray(dv, dtype=np.float64)
        self._lib_.cref_step(self._core, ffi.from_buffer("double[]", dth), ffi.from_buffer("double[]", dv), imu.t)
        return self.state()

    def fuse(self, meas: GnssFix | BaroSample | MagSample) -> None:
        """Apply a GNSS fix (position, + velocity if given) or a baro altitude at the current time.

        Magnetometer samples are ignored (no magnetometer update in the C core).
        """
        if self.dt is None or not self.filter:
            return None
        if isinstance(meas, GnssFix):
            vel = meas.vel_ned if meas.vel_ned is not None else np.full(3, np.nan)
            vel = np.ascontiguousarray(vel, dtype=np.float64)
            for name in ("std_ne", "std_d", "std_vel"):
                sd = getattr(meas, name)
                if not sd > 0.0:
                    raise ValueError(f"GnssFix.{name} must be positive, got {sd!r}")
            self._lib_.cref_fuse_gnss(
                self._core,
                meas.t,
                meas.lat,
                meas.lon,
                meas.h,
                self._ffi.from_buffer("double[]", vel),
                meas.std_ne,
                meas.std_d,
                meas.std_vel,
            )
        elif isinstance(meas, BaroSample):
            alt = meas.altitude
            if not math.isfinite(alt):
                if not meas.pressure > 0.0:
                    return None
                from ins_hil.sim.sensors import altitude_from_pressure

                alt = altitude_from_pressure(meas.pressure)
            self._lib_.cref_fuse_baro(self._core, alt, self.ekf_config.baro_std)
        return None

    def state(self) -> NavState:
        """The current navigation state (biases and 1-σ from the C filter)."""
        if self.dt is None:
            s = self._initial
            return NavState(t=s.t, q_nb=s.q_nb.copy(), vel_ned=s.vel_ned.copy(), lat=s.lat, lon=s.lon, h=s.h)
        self._lib_.cref_state(self._core, self._out)
        o = self._out_np.copy()
        return NavState(
            t=float(o[0]),
            q_nb=o[1:5],
            vel_ned=o[5:8],
            lat=float(o[8]),
            lon=float(o[9]),
            h=float(o[10]),
            gyro_bias=o[11:14],
            accel_bias=o[14:17],
            std_pos=o[17:20],
            std_vel=o[20:23],
            aligned=True,
        )

    def run(self, dtheta: Vec, dvel: Vec, t_end: Vec | None = None, *, every: int = 1) -> Vec:
        """Run a whole log of n IMU intervals in ONE C call (the core must have its dt).

        dtheta, dvel: (n, 3) increments (rad, m/s, body FRD); t_end: (n,) sensor times or None
        (t advances by dt). Returns an (n, 11) array of states, columns ``RUN_COLUMNS``
        (every=0: no output, returns an empty array).
        """
        if self.dt is None:
            raise ValueError("CNavCore.run: the fixed step is unknown; pass dt to the constructor")
        dtheta = np.asarray(dtheta, dtype=np.float64)
        dvel = np.asarray(dvel, dtype=np.float64)
        if dtheta.ndim != 2 or dtheta.shape[1] != 3 or dvel.shape != dtheta.shape:
            raise ValueError(f"CNavCore.run: dtheta and dvel must both be (n, 3), got {dtheta.shape} and {dvel.shape}")
        n = dtheta.shape[0]
        inc = np.ascontiguousarray(np.hstack((dtheta, dvel)))
        ffi = self._ffi
        tp = ffi.NULL
        if t_end is not None:
            t_arr = np.ascontiguousarray(t_end, dtype=np.float64)
            if t_arr.shape != (n,):
                raise ValueError(f"CNavCore.run: t_end must be ({n},), got {t_arr.shape}")
            tp = ffi.from_buffer("double[]", t_arr)
        if every == 0:
            self._lib_.cref_run(self._core, ffi.from_buffer("double[]", inc), tp, n, ffi.NULL, 0)
            return np.empty((0, len(RUN_COLUMNS)))
        out = np.empty((n, len(RUN_COLUMNS)))
        self._lib_.cref_run(
            self._core, ffi.from_buffer("double[]", inc), tp, n, ffi.from_buffer("double[]", out), len(RUN_COLUMNS)
        )
        return out[every - 1 :: every] if every > 1 else out

    def covariance(self) -> Vec:
        """The EKF covariance P (15 × 15; order δr NED, δv NED, ψ NED, δb_g, δb_a)."""
        p = self._core.ekf.P
        return np.array([[float(p[i][j]) for j in range(15)] for i in range(15)])


def make_core(kind: str, initial: StrapdownState, **kwargs: Any) -> Any:
    """The navigation core by name: ``"python"`` (ins_hil.core.NavCore) or ``"c"`` (CNavCore)."""
    if kind == "python":
        from ins_hil.core import NavCore

        return NavCore(initial)
    if kind == "c":
        return CNavCore(initial, **kwargs)
    raise ValueError(f"unknown core {kind!r}: choose 'python' or 'c'")
