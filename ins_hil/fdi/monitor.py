"""Runtime FDI monitor for redundant inertial sensors: detect, isolate, exclude, reconstruct, re-admit.

Called by the runtime on every IMU epoch, before the navigation core::

    mon = FdiMonitor(FdiConfig(geometry=skewed6(), dt=0.005, gyro_noise=..., accel_noise=...))
    imu, events = mon.process(samples)   # samples: one ImuSample per unit (imu_id = unit index)

Input layout: see :mod:`ins_hil.fdi.geometry` (a skewed single-axis array carries one
gyro scalar in ``dtheta[0]`` and one accelerometer scalar in ``dvel[0]`` per unit; a
full IMU carries its triad in its own frame). A unit absent from the epoch, or NaN
values, is a dropout. Output: the body-frame (FRD) :class:`ImuSample` by weighted least
squares from the healthy sensors, ω̂ = Z_h y_h (book eq. 5.26), plus new
:class:`FaultEvent` s.

Per group (gyros, accelerometers), with outputs whitened by their noise:

* parity vector p = U₂ᵀ y/σ of the healthy rows (book eqs. 5.9–5.12);
* fast test ‖p‖² > χ² threshold on ``persistence`` consecutive samples (steps,
  noise bursts, scale jumps in motion); slow test on the exponential average
  p̄ (time constant ``slow_tau``) for drifts and small biases; thresholds from
  the noise and ``p_false_alarm`` (:mod:`ins_hil.fdi.thresholds`);
* isolation: argmax over candidates of Σ (u_kᵀp)²/‖u_k‖² over the run (fast) or
  (u_kᵀp̄)²/‖u_k‖² (slow): the generalised-likelihood form of the corrected
  eq. 5.17 (argmin J(k) = argmax (u_kᵀp)²/‖u_k‖²);
* direct checks: NaN/missing → DROPOUT; the same value ``stuck_samples`` times
  in a row → STUCK (a noisy sensor never repeats exactly; raise the count or set
  0 to disable for coarsely quantised sensors);
* exclusion: the row leaves the parity space and the least squares at once; the
  :class:`FaultEvent` (``t`` = exclusion time) is emitted after ``classify_time``
  more seconds, when the failure mode has been classified from the residual of
  the excluded sensor against the healthy solution (step, ramp, noise burst,
  saturation plateau, scale factor, by least-squares fits);
* re-admission (``readmit_after`` > 0): an excluded sensor whose residual passes
  both tests for ``readmit_after`` seconds is taken back (event with ``cleared=True``).

With m = n_healthy − 3 = 1 a fault is detected (event with ``isolated=False``)
but cannot be isolated; with m = 0 nothing is monitored. Pure and deterministic
(no clock, no I/O); cost per 2-IMU epoch about 4 µs with the common epoch in C (:class:`_Group`), about
20 µs all in Python (``python -m ins_hil.soak.live_path``; ``ins-hil bench-fdi``).
"""

from __future__ import annotations

import importlib
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ins_hil.fdi.geometry import SensorGeometry
from ins_hil.fdi.parity import parity_basis
from ins_hil.fdi.thresholds import fast_threshold, increment_sigma, slow_threshold, slow_variance
from ins_hil.settings import check_fields, setting
from ins_hil.types import FaultEvent, FaultMode, ImuSample, Vec

try:  # the common case of a group's epoch in C (firmware_ref/src/live.c, live_fdi_step); None without the extension
    _live: Any = importlib.import_module("ins_hil._cref")  # (by name: the extension is no module of the layers)
    _ffi, _lib = _live.ffi, _live.lib
except ImportError:  # pragma: no cover - the extension is built at every install
    _ffi = _lib = None
#: rows a group may have for the C step (LIVE_FDI_MAX_ROWS of firmware_ref/src/live.h)
_C_MAX_ROWS = 16

# ufuncs/reductions called directly on the hot path (the ndarray methods add Python-level wrappers)
_equal = np.equal
_add_reduce = np.add.reduce
_max_reduce = np.maximum.reduce
_any = np.logical_or.reduce
_isnan = math.isnan


@dataclass
class FdiConfig:
    """Monitor configuration.

    geometry: the redundant set; dt: nominal IMU interval (s);
    gyro_noise / accel_noise: white-noise density of one sensor (rad/s/√Hz, m/s²/√Hz);
    gyro_bias / accel_bias: 1-σ residual bias of one sensor after calibration (rad/s, m/s²),
    e.g. its bias instability; p_false_alarm: allowed false-alarm probability per hour and
    test; persistence: consecutive exceedances to trip (samples); slow_tau: averaging time
    constant of the slow test (s); classify_time: post-exclusion time used to classify the
    mode (s); readmit_after: healthy time before re-admission (s, 0 = never);
    stuck_samples: identical consecutive outputs that mean STUCK (0 = off);
    dropout_samples: consecutive missing epochs that mean DROPOUT; a shorter gap (a frame lost
    on its link) is bridged: that epoch's output is the least-squares estimate of the rows present;
    exclude_unit: exclude every row of the failed unit (whole IMU), not only the axis;
    history: pre-isolation residual history kept for classification (s);
    isolation_margin: after a trip, the best candidate's likelihood score must exceed the
    second best by this much (in χ² units, i.e. a 4-σ separation) before it is excluded;
    compensate_leak: on exclusion, subtract once from the next output what the fault put into the
    least-squares output since its onset (residual of the excluded sensor against the others,
    summed over the history, times its column of Z), so the integrated attitude/velocity is repaired.
    """

    geometry: SensorGeometry
    dt: float = setting(
        unit="s", range="(0, 1]", help="nominal IMU interval", required=False, doc_default="required with FDI"
    )
    gyro_noise: float = setting(
        unit="rad/s/√Hz",
        range="(0, 1]",
        help="white-noise density of one gyro",
        required=False,
        doc_default="required with FDI",
    )
    accel_noise: float = setting(
        unit="m/s²/√Hz",
        range="(0, 10]",
        help="white-noise density of one accelerometer",
        required=False,
        doc_default="required with FDI",
    )
    gyro_bias: float = setting(0.0, "rad/s", "[0, 1]", "1-σ residual bias of one gyro after calibration")
    accel_bias: float = setting(0.0, "m/s²", "[0, 10]", "1-σ residual bias of one accelerometer after calibration")
    p_false_alarm: float = setting(1e-3, "per hour", "[1e-12, 1)", "false-alarm probability per hour and test")
    persistence: int = setting(3, "samples", "[1, 1000000]", "consecutive exceedances to trip")
    slow_tau: float = setting(1.0, "s", "(0, 3600]", "averaging time constant of the slow test")
    classify_time: float = setting(1.0, "s", "[0, 3600]", "post-exclusion time used to classify the failure mode")
    readmit_after: float = setting(0.0, "s", "[0, 1e6]", "healthy time before re-admission; 0 = never")
    stuck_samples: int = setting(
        10, "samples", "[0, 1000000]", "identical consecutive outputs that mean STUCK; 0 = off"
    )
    dropout_samples: int = setting(3, "samples", "[1, 1000000]", "consecutive missing epochs that mean DROPOUT")
    exclude_unit: bool = setting(False, help="exclude every row of the failed unit (whole IMU), not only the axis")
    history: float = setting(5.0, "s", "(0, 3600]", "pre-isolation residual history kept for classification")
    isolation_margin: float = setting(
        16.0, "χ²", "[0, 1e6]", "best candidate's score margin over the second before excluding"
    )
    compensate_leak: bool = setting(
        True, help="on exclusion, remove what the fault put into the output since its onset"
    )

    def __post_init__(self) -> None:
        check_fields(self, "FdiConfig")  # each field against its [fdi.options] metadata


@dataclass
class _Pending:
    row: int
    t_iso: float
    test: str
    t: list[float]
    y: list[float]
    yhat: list[float]


class _Scalars:
    """The group's counters without the C extension (with it: the ``live_fdi_group_t`` the C step shares)."""

    __slots__ = ("onset", "pos", "run", "srun")

    def __init__(self) -> None:
        self.pos = self.run = self.srun = 0
        self.onset = math.nan


def _shared(name: str) -> property:
    """An attribute of the group kept in its ``_st`` (the C step's struct, or :class:`_Scalars`)."""

    def get(self: _Group) -> Any:
        return getattr(self._st, name)

    def put(self: _Group, v: Any) -> None:
        setattr(self._st, name, v)

    return property(get, put)


class _Group:
    """Parity monitor of one sensor group (gyros or accelerometers).

    Its common epoch (at least 4 healthy rows, none missing or repeating, no test about to trip) runs in C
    (``live_fdi_step``, firmware_ref/src/live.c) on the same arrays when the extension is there: the products
    ``[V; Z] y``, ``p·p`` and ``p̄·p̄`` are summed in row order (numpy's BLAS sums in its kernel's order: the
    estimate may differ from the all-Python step's in the last bits (≤ 1e-13 relative in tests/test_live_c.py), so
    a test statistic within a few ulps of a threshold may decide otherwise; no event of the tests moved); every
    other epoch runs :meth:`step` in Python as before, and so does a group of more than 16 rows."""

    # the counters the C step updates (in the shared struct)
    pos = _shared("pos")
    run = _shared("run")
    srun = _shared("srun")
    onset = _shared("onset")

    def __init__(self, cfg: FdiConfig, name: str, A: Vec, noise: float, bias: float) -> None:
        n_rows = int(np.asarray(A).shape[0])
        self._st: Any = _ffi.new("live_fdi_group_t *") if _lib is not None and n_rows <= _C_MAX_ROWS else _Scalars()
        self._keep: list[Any] = []  # the buffers the struct points into
        self._c_ok = False  # the C step may run (set by _rebuild)
        self.cfg = cfg
        self.name = name
        self.geo = cfg.geometry
        self.A = np.asarray(A, dtype=np.float64)
        self.n = self.A.shape[0]
        self.sig = increment_sigma(noise, cfg.dt)  # increment σ (rad or m/s)
        self.sig_rate = self.sig / cfg.dt
        self.bias_ratio = bias * cfg.dt / self.sig
        self.alpha = min(1.0, cfg.dt / cfg.slow_tau)
        self.var_slow = slow_variance(cfg.dt, cfg.slow_tau, self.bias_ratio)
        self.healthy = np.ones(self.n, dtype=bool)
        self.prev = np.full(self.n, np.nan)
        self.miss = np.zeros(self.n, dtype=np.int64)  # consecutive missing epochs per row
        self._miss_nz = False
        self.same = np.zeros(self.n, dtype=np.int64)
        self._same_nz = False  # some entry of ``same`` is non-zero
        self._one_minus_alpha = 1.0 - self.alpha
        L = max(4, round(cfg.history / cfg.dt))
        self._L = L
        self.buf = np.full((L, self.n), np.nan)
        self.tbuf = np.full(L, np.nan)
        self.pos = 0
        self.pending: list[_Pending] = []
        self.mode: dict[int, FaultMode] = {}
        self.readmit_start: dict[int, float | None] = {}
        self.readmit_ema: dict[int, float] = {}
        self.detect_latched = False
        self.est: Vec = np.zeros(3)
        self.leak: Vec = np.zeros(3)
        self.leak_on = False
        if not isinstance(self._st, _Scalars):  # what the C step reads that never changes (arrays: filled in place)
            st = self._st
            st.n, st.L, st.persistence = self.n, L, cfg.persistence
            st.alpha, st.oma = self.alpha, self._one_minus_alpha
            st.prev, st.buf, st.tbuf = self._ptr("prev"), self._ptr("buf"), self._ptr("tbuf")
        self._rebuild()

    def _ptr(self, name: str) -> Any:
        """A C pointer to the float64 array attribute ``name`` (kept alive with the struct)."""
        a = getattr(self, name)
        assert a.dtype == np.float64 and a.flags.c_contiguous
        p = _ffi.from_buffer("double[]", a)
        self._keep.append(p)
        return p

    # -- configuration of the healthy subset --------------------------------------------------
    def _rebuild(self) -> None:
        self.hidx = np.flatnonzero(self.healthy)
        self._all_healthy = len(self.hidx) == self.n
        Ah = self.A[self.hidx]
        self.Z = np.linalg.pinv(Ah)  # book eq. 5.26 on the healthy rows
        self.P = np.linalg.inv(Ah.T @ Ah)
        self.m = len(self.hidx) - 3
        if self.m >= 1:
            U2 = parity_basis(Ah)
            self.V = U2.T / self.sig
            norms = np.linalg.norm(U2, axis=1)
            self.Un = U2 / np.where(norms > 1e-12, norms, np.inf)[:, None]
            self.thr_fast = fast_threshold(self.cfg.p_false_alarm, self.cfg.dt, self.cfg.persistence, self.m)
            self.thr_slow = slow_threshold(self.cfg.p_false_alarm, self.cfg.slow_tau, self.m) * self.var_slow
            self.ema = np.zeros(self.m)
            self.M = np.vstack([self.V, self.Z])
        self.run = 0
        self.srun = 0
        self.score = np.zeros(len(self.hidx))
        self.onset = math.nan
        # excluded rows and the σ of their residual against the healthy solution (re-admission test)
        self._excl = [int(k) for k in np.flatnonzero(~self.healthy)]
        self._resid_sig = {k: self.sig * math.sqrt(1.0 + float(self.A[k] @ self.P @ self.A[k])) for k in self._excl}
        thr1 = fast_threshold(self.cfg.p_false_alarm, self.cfg.dt, self.cfg.persistence, 1)
        self.thr_fast1 = thr1
        self.thr_slow1 = slow_threshold(self.cfg.p_false_alarm, self.cfg.slow_tau, 1) * self.var_slow
        self._c_ok = not isinstance(self._st, _Scalars) and self.m >= 1
        self._watch = len(self.hidx) < self.n  # excluded rows: watched after each epoch (_watch_excluded)
        if self._c_ok:  # the C step reads the healthy subset's matrices and the test's state from the struct
            st = self._st
            self._keep = self._keep[:3]  # prev, buf, tbuf (set once); the rest is rebuilt here
            self._hidx_c = np.ascontiguousarray(self.hidx, dtype=np.intc)
            st.nh, st.m, st.thr_fast, st.thr_slow = len(self.hidx), self.m, self.thr_fast, self.thr_slow
            st.hidx = _ffi.from_buffer("int[]", self._hidx_c)
            self._keep.append(st.hidx)
            st.M, st.Un, st.ema, st.score = self._ptr("M"), self._ptr("Un"), self._ptr("ema"), self._ptr("score")

    # -- one epoch --------------------------------------------------------------------------------
    def step(self, t: float, y: Vec, events: list[FaultEvent]) -> Vec:
        # hot path (every IMU epoch, per group): ufuncs called directly, no work for the common case
        cfg = self.cfg
        t = float(t)
        pos = self.pos
        self.buf[pos] = y
        self.tbuf[pos] = t
        pos += 1
        self.pos = 0 if pos == self._L else pos
        # stuck counter (NaN never compares equal): only touched when some output repeats
        same = self.same
        eq = _equal(y, self.prev)
        self.prev[:] = y
        if _any(eq):
            same += 1
            same *= eq
            self._same_nz = True
        elif self._same_nz:
            same.fill(0)
            self._same_nz = False
        if _isnan(_add_reduce(y)):
            nan = np.isnan(y)
            miss = self.miss
            miss += nan
            miss *= nan
            self._miss_nz = True
            bad = np.flatnonzero((miss >= cfg.dropout_samples) & self.healthy)
            if len(bad):
                self._exclude_now(bad, t, FaultMode.DROPOUT, "no output (dropout)", events)
            if _any(nan[self.hidx]):
                return self._bridge(y, nan)
        elif self._miss_nz:
            self.miss.fill(0)
            self._miss_nz = False
        if cfg.stuck_samples and self._same_nz and _max_reduce(same) >= cfg.stuck_samples:
            for k in np.flatnonzero((same >= cfg.stuck_samples) & self.healthy):
                if int(self.healthy.sum()) > 3:
                    self._isolate(int(k), t, "stuck-output", t - cfg.stuck_samples * cfg.dt)
        yh = y if self._all_healthy else y[self.hidx]
        if self.m < 1:
            est = self.Z @ yh
        else:
            m = self.m
            out = self.M @ yh  # [parity p (whitened, eq. 5.12); LS estimate (eq. 5.26)] in one product
            p = out[:m]
            est = out[m:]
            s = float(p @ p)
            ema = self.ema
            ema *= self._one_minus_alpha
            ema += self.alpha * p
            if s > self.thr_fast:
                if self.run == 0:
                    self.onset = t
                self.run += 1
                g = self.Un @ p
                self.score += g * g
            elif self.run:
                self.run = 0
                self.score[:] = 0.0
            self.srun = self.srun + 1 if float(ema @ ema) > self.thr_slow else 0
            tripped = False
            if self.run >= cfg.persistence:
                tripped = self._trip(t, self.score, 1.0, "fast", self.onset, events)
            elif self.srun >= cfg.persistence:
                g = self.Un @ self.ema
                tripped = self._trip(t, g * g, self.var_slow, "slow", t - cfg.history, events)
            if tripped:
                est = self.Z @ y[self.hidx]
        if len(self.hidx) < self.n:
            self._watch_excluded(t, y, est, events)
        if self.leak_on:
            est = est - self.leak
            self.leak[:] = 0.0
            self.leak_on = False
        self.est = est
        return est

    def _bridge(self, y: Vec, nan: Vec) -> Vec:
        """A healthy row missing for fewer than ``dropout_samples`` epochs (a frame lost on its link):
        this epoch's output is the least-squares estimate (eq. 5.26) of the rows present, healthy ones
        first, else those excluded only for a dropout; no parity test this epoch. NaN if < 3 rows."""
        present = ~nan
        rows = np.flatnonzero(present & self.healthy)
        if len(rows) < 3:
            dropped = np.array([self.mode.get(int(r)) == FaultMode.DROPOUT for r in range(self.n)])
            rows = np.flatnonzero(present & (self.healthy | dropped))
        if len(rows) < 3:
            self.est = np.full(3, np.nan)
            return self.est
        self.est = np.linalg.pinv(self.A[rows]) @ y[rows]
        return self.est

    def _trip(self, t: float, score: Vec, scale: float, test: str, onset: float, events: list[FaultEvent]) -> bool:
        """A test has tripped: isolate and exclude if the best candidate is clear; True if excluded."""
        if self.m < 2:
            if not self.detect_latched:
                self.detect_latched = True
                events.append(
                    FaultEvent(t, self.name, FaultMode.UNKNOWN, math.nan, isolated=False, detail=f"{test} parity test")
                )
            return False
        top2 = np.partition(score, len(score) - 2)[-2:]
        if (top2[1] - top2[0]) < self.cfg.isolation_margin * scale:
            return False  # not yet separable: keep accumulating
        self._isolate(int(self.hidx[int(np.argmax(score))]), t, test, onset)
        return True

    def _isolate(self, k: int, t: float, test: str, onset: float) -> None:
        """Exclude row k (and its unit if configured); classification follows after classify_time."""
        rows = [k]
        if self.cfg.exclude_unit:
            u = self.geo.unit_of(k)
            rows = [int(r) for r in self.hidx if self.geo.unit_of(int(r)) == u]
        if len(self.hidx) - len(rows) < 3:
            rows = [k]
        # residual history since the onset (against the others) for the classifier
        others = np.array([r for r in self.hidx if r != k])
        order = np.argsort(self.tbuf)
        tb = self.tbuf[order]
        sel = np.isfinite(tb) & (tb >= onset - 1e-9)
        Yb = self.buf[order[sel]]  # the rows since the onset only (no copy of the whole history)
        yhat = (Yb[:, others] @ np.linalg.pinv(self.A[others]).T) @ self.A[k]
        # classification looks at the last ≤ 2 s before the exclusion (a slow fault's shape), the leak at all of it
        csel = tb[sel] >= max(onset, t - 2.0) - 1e-9
        pend = _Pending(k, t, test, list(tb[sel][csel]), list(Yb[csel, k]), list(yhat[csel]))
        if self.cfg.compensate_leak:
            # the fault leaked into the output through column k of the LS matrix since the onset:
            # take it back once from the next output (the navigation integrates increments)
            pos_k = int(np.searchsorted(self.hidx, k))
            resid = Yb[:, k] - yhat
            self.leak += self.Z[:, pos_k] * float(np.nansum(resid))
            self.leak_on = True
        for r in rows:
            self.healthy[int(r)] = False
        self._rebuild()
        self.pending.append(pend)
        for r in rows:
            if int(r) != k:
                self.mode[int(r)] = FaultMode.UNKNOWN
                self.readmit_start[int(r)] = None
                self.readmit_ema[int(r)] = 0.0

    def _exclude_now(self, rows: Vec, t: float, mode: FaultMode, detail: str, events: list[FaultEvent]) -> None:
        units: dict[int, list[int]] = {}
        for r in rows:
            units.setdefault(self.geo.unit_of(int(r)), []).append(int(r))
        for u, rs in units.items():
            if int(self.healthy.sum()) - len(rs) < 3:
                events.append(
                    FaultEvent(t, self.name, mode, math.nan, isolated=False, detail=detail + "; too few left")
                )
                continue
            for r in rs:
                self.healthy[r] = False
                self.mode[r] = mode
                self.readmit_start[r] = None
                self.readmit_ema[r] = 0.0
            self._rebuild()
            if len(rs) == 1:
                name = self.geo.row_name(self.name, rs[0])
            else:
                name = f"imu{u}.{self.name}" if self.geo.kind == "imus" else self.name
            events.append(FaultEvent(t, name, mode, math.nan, isolated=True, detail=detail))

    def _watch_excluded(self, t: float, y: Vec, est: Vec, events: list[FaultEvent]) -> None:
        cfg = self.cfg
        for pend in list(self.pending):
            yk = float(y[pend.row])
            pend.t.append(t)
            pend.y.append(yk)
            pend.yhat.append(float(self.A[pend.row] @ est))
            if t >= pend.t_iso + cfg.classify_time - 1e-9:
                self.pending.remove(pend)
                mode, mag = classify(np.array(pend.t), np.array(pend.y), np.array(pend.yhat), cfg.dt, self.sig_rate)
                self.mode[pend.row] = mode
                self.readmit_start[pend.row] = None
                self.readmit_ema[pend.row] = 0.0
                events.append(
                    FaultEvent(
                        pend.t_iso,
                        self.geo.row_name(self.name, pend.row),
                        mode,
                        mag,
                        isolated=True,
                        detail=f"{pend.test} parity test",
                    )
                )
        if cfg.readmit_after <= 0:
            return
        waiting = {p.row for p in self.pending} if self.pending else ()
        for k in self._excl:
            if k in waiting:
                continue
            a = self.A[k]
            r = float(y[k] - a @ est)
            ok = math.isfinite(r) and (cfg.stuck_samples == 0 or self.same[k] < cfg.stuck_samples)
            if ok:
                z = r / self._resid_sig[k]
                e = self.readmit_ema[k] + self.alpha * (z - self.readmit_ema[k])
                self.readmit_ema[k] = e
                ok = z * z < self.thr_fast1 and e * e < self.thr_slow1
            if not ok:
                self.readmit_start[k] = None
                continue
            t0 = self.readmit_start.get(k)
            if t0 is None:
                self.readmit_start[k] = t
            elif t - t0 >= cfg.readmit_after:
                self.healthy[k] = True
                mode = self.mode.pop(k, FaultMode.UNKNOWN)
                self.readmit_start.pop(k, None)
                self.readmit_ema.pop(k, None)
                self._rebuild()
                self.detect_latched = False
                events.append(
                    FaultEvent(
                        t,
                        self.geo.row_name(self.name, k),
                        mode,
                        math.nan,
                        isolated=True,
                        cleared=True,
                        detail=f"re-admitted after {cfg.readmit_after:g} s healthy",
                    )
                )


def classify(t: Vec, y: Vec, yhat: Vec, dt: float, sig_rate: float) -> tuple[FaultMode, float]:
    """Failure mode and size from an excluded sensor's output ``y`` and its value ``yhat``
    predicted by the healthy sensors (increments over ``dt``; times ``t`` in s).

    Size units: STEP_BIAS rate (rad/s, m/s²), RAMP rate per second, NOISE_BURST rate σ,
    SATURATION clip level (rate), SCALE_FACTOR dimensionless, STUCK the frozen rate.
    """
    ok = np.isfinite(y) & np.isfinite(yhat)
    if not ok.any():
        return FaultMode.DROPOUT, math.nan
    t, y, yhat = t[ok], y[ok] / dt, yhat[ok] / dt
    r = y - yhat
    n = len(r)
    if n >= 3 and np.all(y == y[-1]):
        # held constant: a saturation if the true value lies beyond it (same sign) throughout
        beyond = (np.abs(yhat) > abs(y[-1]) + 2.0 * sig_rate) & (yhat * y[-1] > 0)
        if float(np.mean(beyond)) >= 0.9:
            return FaultMode.SATURATION, abs(float(y[-1]))
        return FaultMode.STUCK, float(y[-1])
    ymax = float(np.max(np.abs(y)))
    at_max = int(np.sum(np.abs(y) >= ymax * (1 - 1e-12)))
    if at_max >= 3 and float(np.max(np.abs(yhat))) > ymax + 3 * sig_rate:
        return FaultMode.SATURATION, ymax
    c = float(np.mean(r))
    rss0 = float(np.sum((r - c) ** 2))
    if n >= 4:
        tt = t - t.mean()
        slope = float(tt @ r / max(float(tt @ tt), 1e-300))
        rss1 = float(np.sum((r - c - slope * tt) ** 2))
    else:
        slope, rss1 = 0.0, rss0
    yy = float(yhat @ yhat)
    sf = float(yhat @ r) / yy if yy > 0 else 0.0
    rss2 = float(np.sum((r - sf * yhat) ** 2))
    best = min(rss0, rss1, rss2)
    resid_sd = math.sqrt(best / max(n - 1, 1))
    # the healthy prediction has its own noise; the sensor's own noise is sig_rate
    if resid_sd > 3.0 * sig_rate:
        return FaultMode.NOISE_BURST, resid_sd
    # F-tests against the constant (step) model: 25 ≈ a 5-σ improvement
    f_sf = (rss0 - rss2) / max(rss2 / max(n - 1, 1), 1e-300)
    f_ramp = (rss0 - rss1) / max(rss1 / max(n - 2, 1), 1e-300)
    if rss2 <= 1.05 * rss1 and f_sf > 25.0:
        return FaultMode.SCALE_FACTOR, sf
    if f_ramp > 25.0:
        return FaultMode.RAMP, slope
    return FaultMode.STEP_BIAS, c


_warmed = False  # the exclusion path has run once in this process (see _warm_up)


def _warm_up(cfg: FdiConfig, A: Vec, noise: float, bias: float) -> int:
    """Run the isolation/exclusion/classification path once on a throwaway group with synthetic data.

    The first exclusion otherwise calls numpy kernels the per-epoch path never uses (argsort of
    the history's times, partition of the candidate scores): their machine code (~0.5 MiB of
    ``_multiarray_umath``'s sort/select kernels) is paged in at that moment and stays resident,
    so a long-running gateway's RSS stepped up at its first fault. Doing it here moves that
    one-time step to start-up. Nothing of the throwaway group is kept: decisions are unchanged.
    Returns the number of throwaway exclusions classified (0 when no sensor can be excluded).
    """
    done = 0
    for filled in (1.0, 0.5):  # a full history ring (wrapped at a third) and a half-filled one (NaN times)
        g = _Group(cfg, "warm-up", A, noise, bias)
        if len(g.hidx) <= 3:
            return done
        L, n = g.buf.shape
        k = np.arange(L, dtype=np.float64)
        g.tbuf[:] = np.roll(k * cfg.dt, L // 3)
        g.tbuf[g.tbuf >= filled * L * cfg.dt] = np.nan
        g.buf[:] = np.sin(np.outer(k, np.arange(1, n + 1))) * g.sig  # deterministic stand-in for noise
        t = float(np.nanmax(g.tbuf))
        score = np.zeros(len(g.hidx))
        score[0] = 1e9  # one clear candidate
        onset = t - 0.5 * cfg.classify_time
        if g.m >= 2:
            g._trip(t, score, 1.0, "fast", onset, [])  # partition of the scores, then _isolate
        else:  # 4 rows: only the STUCK check excludes
            g._isolate(0, t, "stuck-output", onset)
        for pend in g.pending:
            tt, yy, yh = np.array(pend.t), np.array(pend.y), np.array(pend.yhat)
            classify(tt, yy, yh, cfg.dt, g.sig_rate)
            classify(tt, np.full(len(yy), yy[-1]), yh, cfg.dt, g.sig_rate)  # the held-output branch
            done += 1
    return done


class FdiMonitor:
    """Runtime monitor: ``process(samples)`` → (reconstructed body ImuSample, new FaultEvents)."""

    def __init__(self, config: FdiConfig) -> None:
        global _warmed
        self.cfg = config
        g = config.geometry
        self.geo = g
        self.gyro = _Group(config, "gyro", g.gyro_axes, config.gyro_noise, config.gyro_bias)
        self.accel = _Group(config, "accel", g.accel_axes, config.accel_noise, config.accel_bias)
        if not _warmed:
            _warm_up(config, g.gyro_axes, config.gyro_noise, config.gyro_bias)
            _warmed = self.gyro.m >= 2  # every kernel of the exclusion path has run
        self._yg = np.empty(g.n)
        self._ya = np.empty(g.n)
        if _ffi is not None:  # (their C pointers for live_fdi_step)
            self._pyg, self._pya = _ffi.from_buffer("double[]", self._yg), _ffi.from_buffer("double[]", self._ya)
        self._unit_size, self._units = g.unit_size, g.units  # (properties of the geometry: read once)
        self._seq = 0
        self.events: list[FaultEvent] = []  # every event so far

    @property
    def excluded(self) -> list[str]:
        """Names of the sensors currently excluded."""
        out = []
        for grp in (self.gyro, self.accel):
            out += [self.geo.row_name(grp.name, int(k)) for k in np.flatnonzero(~grp.healthy)]
        return out

    def process(self, samples: Sequence[ImuSample]) -> tuple[ImuSample, list[FaultEvent]]:
        """One epoch: the samples of all units (matched by ``imu_id``); missing units are dropouts."""
        if not samples:
            raise ValueError("FdiMonitor.process: empty epoch")
        yg, ya = self._yg, self._ya
        us = self._unit_size
        nu = self._units
        if len(samples) != nu or len({s.imu_id for s in samples}) != nu:
            yg.fill(math.nan)  # a missing unit is a dropout (NaN); all present: every row is overwritten
            ya.fill(math.nan)
        t = -math.inf
        for s in samples:
            j = s.imu_id
            if not 0 <= j < nu:
                raise ValueError(f"FdiMonitor.process: imu_id {j} outside 0..{nu - 1} for {self.geo.name}")
            if us == 1:
                yg[j] = s.dtheta[0]
                ya[j] = s.dvel[0]
            else:
                yg[3 * j : 3 * j + 3] = s.dtheta
                ya[3 * j : 3 * j + 3] = s.dvel
            if s.t > t:
                t = s.t
        events: list[FaultEvent] = []
        dth, dv = self._steps(t, events)
        if events:
            self.events.extend(events)
        self._seq = (self._seq + 1) & 0xFFFF
        return ImuSample(t=t, dt=samples[0].dt, dtheta=dth, dvel=dv, seq=self._seq), events

    def _steps(self, t: float, events: list[FaultEvent]) -> tuple[Vec, Vec]:
        """Both groups' epoch on the stacked outputs in ``_yg``/``_ya``: Δθ, Δv. A group's common epoch runs in C
        (``live_fdi_step``), any other in its Python step."""
        gy, ac = self.gyro, self.accel
        if not (gy._c_ok and ac._c_ok):
            return gy.step(t, self._yg, events), ac.step(t, self._ya, events)
        out = np.empty(6)
        po = _ffi.from_buffer("double[]", out)
        step = _lib.live_fdi_step
        if gy._same_nz or gy._miss_nz or gy.leak_on or step(gy._st, t, self._pyg, po):
            dth = gy.step(t, self._yg, events)
        else:
            dth = gy.est = out[:3]
            if gy._watch:  # as the Python step: the excluded rows against this estimate (classification, re-admission)
                gy._watch_excluded(t, self._yg, dth, events)
        if ac._same_nz or ac._miss_nz or ac.leak_on or step(ac._st, t, self._pya, po + 3):
            dv = ac.step(t, self._ya, events)
        else:
            dv = ac.est = out[3:]
            if ac._watch:
                ac._watch_excluded(t, self._ya, dv, events)
        return dth, dv

    def process_arrays(self, t: float, dt: float, yg: Vec, ya: Vec) -> tuple[Vec, Vec, list[FaultEvent]]:
        """Same as :meth:`process` on stacked outputs (n,) (benchmarks, replay); returns Δθ, Δv, events."""
        events: list[FaultEvent] = []
        self._yg[:] = yg
        self._ya[:] = ya
        dth, dv = self._steps(float(t), events)
        if events:
            self.events.extend(events)
        return dth, dv, events
