"""NavCore: the one synchronous entry point the runtime and replay call.

``step(imu)`` runs the strapdown mechanization on the bias/scale-compensated
increments and the error-state EKF time update; ``fuse(meas)`` applies an
aiding measurement (GNSS, baro, magnetometer, odometer, airspeed: any aid source's
of :mod:`ins_hil.aids`) at its time of validity; ``state()``
returns the current :class:`NavState`; ``drain_events()`` returns the
GNSS/baro fault events raised by the innovation tests since the last call.

Pure and deterministic: no I/O, no clock, no asyncio; the same input sequence
gives the same output, bit for bit.

NavCore is a facade: it compensates the increments, runs the time update, gates and
applies each :class:`~ins_hil.core_parts.contract.Measurement` and feeds the error back;
the aids are the aid sources of :mod:`ins_hil.aids` (one module each: sample, model, validation,
record, snapshot), dispatched by sample type through its registry; the other jobs are its
collaborators in :mod:`ins_hil.core_parts` (alignment, GNSS reset, baro datum, delayed-fusion
history).

Filter: closed-loop error-state EKF (:mod:`ins_hil.fusion.ekf`, conventions of
DIGEST_000 §9), measurement models of :mod:`ins_hil.fusion.measurements`,
chi-square gating and Sage–Husa adaptive R (:mod:`ins_hil.fusion.innovation`).

Time alignment and latency: a measurement is fused at the IMU step nearest to
its validity time ``t``. A measurement from the future is queued; one from the
past (a delayed GNSS fix) is, with ``delay.compensation``, fused by rolling the
filter back to the stored snapshot of that step and re-running the logged IMU
samples and measurements up to now (delayed fusion with forward
propagation; history ``delay.max_delay`` s). The position measurement is shifted by
v̂·(t_step − t) to the step time (interpolation between IMU samples).

Alignment (``NavConfig.alignment.mode``): ``"given"`` trusts the initial state;
``"static"`` levels from the mean specific force over ``alignment.time`` s at rest
(book §4.1.1), takes yaw from the magnetometer (refined alignment, §4.1.2,
Example 4.1) when a field reference is configured, or else from the GNSS course
once the speed exceeds ``gnss_yaw_speed`` (in-motion yaw; yaw σ = ``gnss_yaw_std`` ⊕ σ_v/V with the
receiver's σ_v, floored at ``gnss_yaw_vel_floor``). With ``level_tilt_prior`` the levelled tilt's prior
is correlated with the accelerometer error states (the levelling absorbs the horizontal accelerometer
error, :meth:`ErrorStateEKF.level_tilt`). ``state().aligned`` stays False until the attitude is known
and the filter's yaw σ is below ``aligned_yaw_std``.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any, NamedTuple

import numpy as np

from ins_hil import aids as registry
from ins_hil.aids import Aid
from ins_hil.aids.vehicle import VehicleAids
from ins_hil.core_parts.alignment import Alignment
from ins_hil.core_parts.baro_datum import BaroDatum
from ins_hil.core_parts.config import NavConfig as NavConfig  # re-exported (defined beside its sections)
from ins_hil.core_parts.contract import Measurement, check_imu
from ins_hil.core_parts.gnss import RESET_GATE_FACTOR as RESET_GATE_FACTOR
from ins_hil.core_parts.gnss import GnssReset, gnss_position
from ins_hil.core_parts.gnss import gnss_fixes_agree as gnss_fixes_agree  # re-exported (ins_hil.cref)
from ins_hil.core_parts.gnss import ins_off_track as ins_off_track  # re-exported (ins_hil.cref)
from ins_hil.core_parts.history import DelayedHistory
from ins_hil.core_parts.hold import NoAidHold
from ins_hil.core_parts.sensor_check import SensorCheck
from ins_hil.core_parts.yaw_reset import YawReset
from ins_hil.fusion.ekf import EkfSnapshot, ErrorStateEKF
from ins_hil.fusion.innovation import GateStats, SageHusa, test_ratio
from ins_hil.fusion.yaw_gsf import YawGsf
from ins_hil.nav import alignment, earth
from ins_hil.nav.mechanization import StrapdownNED, StrapdownSnapshot, StrapdownState
from ins_hil.nav.rotation import dcm_from_quat, quat_from_euler, quat_from_rotvec, quat_mul
from ins_hil.types import AidSample, FaultEvent, FaultMode, GnssFix, ImuSample, NavState, Vec

DEG = math.pi / 180.0
#: lost IMU data is coasted across for at most this long (s; NavCore._coast: a sensor time gone far ahead)
GAP_MAX_S = 10.0


def imu_lost(t_end: float, dt: float, prev_end: float) -> float | None:
    """The IMU data lost (s) before a sample ending at ``t_end`` s, ``dt`` s long, whose previous sample (or the
    core's state) ended at ``prev_end`` s: the time from ``prev_end`` to the sample's start (``t_end - dt``) when
    that exceeds half the sample's step, ``0.5 * dt`` (exactly half is jitter, not a loss), else None. The rule
    of both cores (``NavCore._mechanize``, ``core.c``) and of every caller that predicts their record;
    :func:`imu_lost_v` is the same on arrays."""
    lost = t_end - dt - prev_end
    return lost if lost > 0.5 * dt else None


def imu_lost_v(t_end: Vec, dt: Vec, prev_end: Vec) -> tuple[Vec, Vec]:
    """:func:`imu_lost` element-wise on (n,) arrays (s): the time from each ``prev_end`` to the sample's start
    (``t_end - dt``, whether lost or not) and where it exceeds half the sample's step (bool, the lost data)."""
    lost = t_end - dt - prev_end
    return lost, lost > 0.5 * dt


def initial_state(f_b: Vec, fix: GnssFix, t: float, yaw: float, cfg: NavConfig) -> StrapdownState:
    """The state a core starts from at a GNSS fix (the runtime's ``init = "gnss"``): roll and pitch levelled from
    the mean specific force ``f_b`` (m/s², body FRD; :func:`ins_hil.nav.alignment.coarse_level`, the core's own
    levelling), the fix's position and velocity, and the yaw from the GNSS course
    (:func:`~ins_hil.nav.alignment.yaw_from_course`) once the horizontal speed exceeds ``alignment.gnss_yaw_speed``
    (the threshold of the core's in-motion yaw), else ``yaw`` (rad); valid at ``t`` (s)."""
    roll, pitch = alignment.coarse_level(f_b)
    vel = np.array(fix.vel_ned, dtype=np.float64) if fix.vel_ned is not None else np.zeros(3)
    if math.hypot(float(vel[0]), float(vel[1])) > cfg.alignment.gnss_yaw_speed:
        yaw = alignment.yaw_from_course(vel)
    return StrapdownState(quat_from_euler(roll, pitch, yaw), vel, fix.lat, fix.lon, fix.h, t)


#: builds a NamedTuple from a tuple without its generated ``__new__`` (half the cost: a snapshot per IMU step)
_new = tuple.__new__


class CoreSnapshot(NamedTuple):
    """NavCore's state at one step (:meth:`NavCore.snapshot`): references only (every array is replaced, never
    mutated in place, by the mechanization, the filter and the feedback), so one per step is cheap."""

    ins: StrapdownSnapshot
    kf: EkfSnapshot
    bg: Vec
    ba: Vec
    sg: Vec
    sa: Vec
    G: Vec
    q_mount: Vec
    mb: Vec
    wind: Vec
    omega_b: Vec
    f_b: Vec
    #: the snapshots of the stateful aid sources (NavCore._stateful order)
    sources: tuple[Any, ...]


class NavCore:
    """Strapdown INS + error-state EKF (+ alignment, gating, adaptive R, delayed fusion)."""

    def __init__(self, initial: StrapdownState | None = None, config: NavConfig | None = None) -> None:
        self.cfg = config if config is not None else NavConfig()
        registry.check_sources(self.cfg)
        if initial is None:
            if self.cfg.alignment.mode == "given":
                raise ValueError("NavCore: alignment.mode='given' needs an initial state")
            initial = StrapdownState(np.array([1.0, 0, 0, 0]), np.zeros(3), 0.0, 0.0, 0.0)
        self.ins = StrapdownNED(initial.copy(), gravity=self.cfg.gravity)
        srcs = registry.sources()
        self.kf = ErrorStateEKF(self.cfg.filter, tuple(b for a in srcs for b in a.blocks(self.cfg)))
        self.idx = self.kf.idx
        self.bg = np.zeros(3)
        self.ba = np.zeros(3)
        self.sg = np.zeros(3)
        self.sa = np.zeros(3)
        self.G = np.zeros((3, 3))  # gyro g-sensitivity (rad/s per m/s², FilterConfig.gyro_gsens)
        self.q_mount = np.array((1.0, 0.0, 0.0, 0.0))  # residual IMU body → vehicle rotation (NHC frame)
        self.mb = np.zeros(3)  # magnetometer hard iron (body, units of |mag.ref_ned|; FilterConfig.mag_bias)
        self.wind = np.zeros(2)  # horizontal wind north, east (m/s; FilterConfig.wind_states)
        self.omega_b = np.zeros(3)
        self.f_b = np.zeros(3)
        self.stats = {k: GateStats() for a in srcs for k in a.stat_kinds(self.cfg)}
        self.adapt = {k: SageHusa(b=self.cfg.adaptive_b) for k in ("gnss_pos", "gnss_vel", "baro")}
        self._events: list[FaultEvent] = []
        self._ratios: dict[str, float] = {}
        self.step_n = 0  # IMU steps mechanized (the delayed-fusion history counts by it)
        self._dt = 0.01
        self.imu_lost = (0, 0.0)  # IMU gaps coasted across (count, s)
        self._pending: list[AidSample] = []
        self.replaying = False  # a roll-back replays the log: no counting, no events, no logging
        self._delayed = self.cfg.delay.compensation and self.cfg.delay.max_delay > 0
        self.history = DelayedHistory(self, self.cfg.delay.max_delay)
        c = self.cfg
        self.aids: VehicleAids  # the vehicle aids (set by their source's bind)
        self.baro: BaroDatum  # the baro datum (set by the baro source's bind; the GNSS aid and alignment feed it)
        #: the aid sources bound to this core: by the sample type they read, those run after each IMU step, and
        #: those whose state the delayed-fusion snapshots keep
        bound = [(a, a.bind(self)) for a in srcs]
        self._by_type: dict[type, tuple[registry.AidSource, Aid]] = {a.sample: (a, b) for a, b in bound if a.sample}
        self._per_step = tuple(b for _, b in bound if b.per_step)
        self._stateful = tuple(b for _, b in bound if b.stateful)
        self._feedback_aids = tuple(b for a, b in bound if a.blocks(c))
        self._aid_by_name = {a.name: b for a, b in bound}
        self.g_local = 9.80665  # normal gravity at the aligned position (m/s²; the ground aids)
        self.phase = "nav" if self.cfg.alignment.mode == "given" else "level"  # alignment: level → heading → nav
        self.align = Alignment(self)
        self.yaw_gsf = YawGsf() if c.alignment.yaw_gsf else None  # yaw from GNSS velocity, before navigation
        pos0 = c.alignment.position
        if pos0 is not None and self.phase == "level":  # a known position: levelling needs no GNSS fix
            st = self.ins.state
            st.lat, st.lon, st.h = math.radians(pos0[0]), math.radians(pos0[1]), float(pos0[2])
            self.align.have_pos = True
        self.nis_log: list[tuple[float, str, float, int]] = []
        #: (t s, kind, innovation z) of every tested measurement of the kinds in ``innov_kinds`` (none by default;
        #: a replay's whiteness check keeps "gnss_vel")
        self.innov_log: list[tuple[float, str, Vec]] = []
        self.innov_kinds: frozenset[str] = frozenset()
        self._sd_of: Any = None  # the P whose σ is in _sd (state() cache)
        self._sd: Vec = np.zeros(9)
        self.keep_nis = False
        self.pending_end: ImuSample | None = None  # step_begin ran, step_end not yet
        self.gnss_reset = GnssReset(self.cfg)  # the run of rejected fixes that may reset the filter
        self.gnss_resets = 0  # GNSS position resets done (the position steps: NavState.resets)
        self.divergences: list[tuple[float, str]] = []  # (t s, why): the resets of a diverged filter to GNSS
        #: the start-up check of the IMU against the mounting and the noise preset (core_parts/sensor_check.py);
        #: its one-line findings in ``sensor_warnings`` once judged
        self.sensor_check: SensorCheck | None = SensorCheck(self.cfg)
        self.sensor_warnings: list[str] = []
        #: the GNSS-velocity yaw bank run from the first sample and the emergency yaw reset it allows
        #: (core_parts/yaw_reset.py, EKF2's); the resets done: (t s, why)
        self.yaw_reset = YawReset(self.cfg)
        self.yaw_resets: list[tuple[float, str]] = []
        # no absolute aiding: constant-position / zero-velocity pseudo-measurements (core_parts/hold.py)
        self.hold = NoAidHold(self.cfg) if self.cfg.hold.enabled else None
        if self.hold is not None:
            self.stats["hold"] = GateStats()

    # ------------------------------------------------------------------ IMU path
    def step(self, imu: ImuSample) -> NavState:
        """Propagate with one IMU interval; returns the current state. A sample with a non-finite value or
        time, or ``dt`` ≤ 0, is refused with a one-line ValueError (the core's contract,
        :func:`~ins_hil.core_parts.contract.check_imu`); ``fuse`` likewise
        (the aid source's :meth:`~ins_hil.aids.AidSource.check`)."""
        if self._begin(imu):
            self.step_end()
        return self.state()

    def step_begin(self, imu: ImuSample) -> NavState:
        """The first part of :meth:`step` for a real-time caller: the strapdown mechanization only.
        Returns the propagated state at once (its σ are those of the previous step); the caller must
        call :meth:`step_end` (the filter time update, ground-vehicle aids, delayed-fusion history)
        before anything else touches the core. ``step_begin`` + ``step_end`` = :meth:`step`, bit for bit,
        except the σ of the returned state."""
        self._begin(imu)
        return self.state()

    def _begin(self, imu: ImuSample) -> bool:
        """Mechanization (or an alignment step); True when a time update (:meth:`step_end`) is pending.
        ValueError (one line, nothing changed) for a sample the core cannot integrate (:func:`check_imu`)."""
        check_imu(imu)
        if self.pending_end is not None:
            self.step_end()
        if not self.replaying and self._delayed and self.phase == "nav":
            self.history.log_imu(self.step_n, imu)
        self._dt = imu.dt
        if self.sensor_check is not None and not self.replaying and self.sensor_check.add(imu):
            self._sensor_checked(self.sensor_check)
        if not self.replaying:
            self.yaw_reset.imu(imu, self.bg)
        if self.phase != "nav":
            if self.yaw_gsf is not None:
                self.yaw_gsf.predict(imu.dtheta - self.bg * imu.dt, imu.dvel, imu.dt)
            self.align.step(imu)
            return False
        self._mechanize(imu)
        self.pending_end = imu
        return True

    def step_end(self) -> None:
        """Finish the step begun by :meth:`step_begin` (no-op if none is pending)."""
        imu = self.pending_end
        if imu is None:
            return
        self.pending_end = None
        self._time_update(imu)
        if not self.replaying:
            self._after_step()

    def propagate(self, imu: ImuSample) -> None:
        """Mechanization and filter time update of one IMU interval, nothing else (the history's replays)."""
        self._mechanize(imu)
        self._time_update(imu)

    def _mechanize(self, imu: ImuSample) -> None:
        """Compensate the increments (bias, g-sensitivity, scale factor) and run the strapdown step, in
        scalar floats on the hot path (the same element-wise numbers as the array expressions)."""
        dt = imu.dt
        lost = imu_lost(imu.t, dt, self.ins.state.t)
        if lost is not None and self.step_n > 0:
            self._coast(lost)
        a, v, bg, ba = imu.dtheta, imu.dvel, self.bg, self.ba
        x0, x1, x2 = (
            float(a[0]) - float(bg[0]) * dt,
            float(a[1]) - float(bg[1]) * dt,
            float(a[2]) - float(bg[2]) * dt,
        )
        u0, u1, u2 = (
            float(v[0]) - float(ba[0]) * dt,
            float(v[1]) - float(ba[1]) * dt,
            float(v[2]) - float(ba[2]) * dt,
        )
        if self.idx.gs is not None:
            g = self.G @ v  # gyro g-sensitivity: ω̃ = ω + b_g + G f^b (FilterConfig.gyro_gsens)
            x0, x1, x2 = x0 - float(g[0]), x1 - float(g[1]), x2 - float(g[2])
        if self.idx.sg is not None:
            sg, sa = self.sg, self.sa
            x0, x1, x2 = x0 / (1.0 + float(sg[0])), x1 / (1.0 + float(sg[1])), x2 / (1.0 + float(sg[2]))
            u0, u1, u2 = u0 / (1.0 + float(sa[0])), u1 / (1.0 + float(sa[1])), u2 / (1.0 + float(sa[2]))
        ins = self.ins
        ins.step(np.array((x0, x1, x2)), np.array((u0, u1, u2)), dt)
        self.omega_b = np.array((x0 / dt, x1 / dt, x2 / dt))
        self.f_b = np.array((u0 / dt, u1 / dt, u2 / dt))
        ins.state.t = imu.t
        self.step_n += 1

    def _coast(self, lost: float) -> None:
        """Cross ``lost`` s of lost IMU data (the sample's interval starts after the last state): the position
        advances at the held velocity, the attitude is held, and the covariance grows by the unknown motion of
        the gap (:meth:`ErrorStateEKF.predict_gap`); so the next fixes pull the state back at once. A gap longer
        than ``GAP_MAX_S`` (a sensor time gone far ahead) is coasted for that long only; the time jumps anyway."""
        ins = self.ins
        ins.reset_history()
        C = dcm_from_quat(ins.state.q_nb)
        d = min(lost, GAP_MAX_S)
        g = np.array((0.0, 0.0, -self.g_local * d))  # the specific force of no acceleration (NED), over the gap
        t_end = ins.state.t + lost
        ins.step(np.zeros(3), C.T @ g, d)
        ins.reset_history()
        s = ins.state
        s.t = t_end
        self.kf.predict_gap(d, C, ins.f_ned, ins.omega_ie, ins.omega_en, s.lat, s.h)
        if not self.replaying:
            self.imu_lost = (self.imu_lost[0] + 1, self.imu_lost[1] + lost)
            self._events.append(
                FaultEvent(s.t, "imu", FaultMode.DROPOUT, lost, True, True,
                           f"IMU data lost for {lost:.3f} s: coasted at constant velocity, covariance grown")
            )  # fmt: skip

    def _time_update(self, imu: ImuSample) -> None:
        ins = self.ins
        C = dcm_from_quat(ins.state.q_nb)
        self.kf.predict(
            imu.dt, C, ins.f_ned, ins.omega_ie, ins.omega_en, self.f_b, self.omega_b, ins.state.lat, ins.state.h
        )
        for a in self._per_step:  # the vehicle aids (ZUPT/ZARU, NHC, drag)
            a.after_step(imu)

    def _after_step(self) -> None:
        if self.hold is not None and self.phase == "nav" and self.hold.due(self.ins.state.t):
            s = self.ins.state
            for hm in self.hold.measurements(s.t, s, dcm_from_quat(s.q_nb), self.idx):
                self._apply(hm, s.t)
        if self._delayed:
            self.history.after_step(self.step_n, self.ins.state.t, self._dt)
        if self._pending:
            t = self.ins.state.t
            due = [m for m in self._pending if m.t <= t + 0.5 * self._dt]
            if due:
                self.history.finish_rollback()
                self._pending = [m for m in self._pending if m.t > t + 0.5 * self._dt]
                for m in due:
                    self.fuse_now(m)

    # ------------------------------------------------------------------ snapshots (delayed fusion)
    def snapshot(self) -> CoreSnapshot:
        """The state at this step, by reference (the delayed-fusion history takes one per step). With the baro
        datum and the GNSS height it learns from: a replay re-fuses the logged baro samples from the same datum."""
        return _new(CoreSnapshot, (
            self.ins.snapshot(), self.kf.snapshot(), self.bg, self.ba, self.sg, self.sa, self.G, self.q_mount, self.mb,
            self.wind, self.omega_b, self.f_b, tuple([a.snapshot() for a in self._stateful]),
        ))  # fmt: skip

    def restore(self, d: CoreSnapshot) -> None:
        """Put back the state of a :meth:`snapshot` (the error estimate zero)."""
        self.ins.restore(d.ins)
        self.kf.restore(d.kf)
        self.bg, self.ba, self.sg, self.sa, self.G = d.bg, d.ba, d.sg, d.sa, d.G
        self.q_mount, self.mb, self.wind, self.omega_b, self.f_b = d.q_mount, d.mb, d.wind, d.omega_b, d.f_b
        for a, sd in zip(self._stateful, d.sources, strict=True):
            a.restore(sd)

    #: IMU steps a roll-back replays per segment of :meth:`fuse_steps` (about 0.3 ms in Python; set on DelayedHistory)
    REPLAY_SEGMENT = DelayedHistory.REPLAY_SEGMENT

    # ------------------------------------------------------------------ aiding
    def fuse(self, meas: AidSample) -> None:
        """Apply an aiding measurement valid at ``meas.t`` (queued if in the future, fused
        on the past step's snapshot if delayed and ``delay.compensation``)."""
        for _ in self.fuse_steps(meas):
            pass

    def fuse_steps(self, meas: AidSample) -> Iterator[None]:
        """:meth:`fuse` in parts, for a real-time caller: yields between the GNSS position and
        velocity updates (each about 0.2 ms in Python), so that they can run in separate gaps
        between IMU steps. Exhausted with no step in between, it is exactly :meth:`fuse`.
        ValueError (one line, at the first segment, nothing changed) for a measurement the core cannot fuse
        (the aid source's ``check``)."""
        src, aid = self._aid_of(meas)
        src.check(meas)
        if self.pending_end is not None:
            self.step_end()
        self.history.finish_rollback()  # a roll-back of an earlier measurement left suspended: it comes first
        aid.arrive(meas)
        if self.phase != "nav":
            aid.align(meas)
            return
        # e.g. a GNSS fix with gnss.vel_delay: position at t, velocity at its own (earlier) time of validity
        for k, part in enumerate(aid.parts(meas)):
            if k:
                yield
            yield from self._fuse_one(part)

    def _aid_of(self, meas: AidSample) -> tuple[registry.AidSource, Aid]:
        """The aid source reading ``meas`` and its part of this core (TypeError, one line: none)."""
        r = self._by_type.get(type(meas))
        if r is None:
            registry.source_of(meas)  # raises: no aid source reads it
            raise TypeError(f"NavCore.fuse: unsupported measurement {type(meas).__name__}")
        return r

    def _fuse_one(self, meas: AidSample) -> Iterator[None]:
        t = self.ins.state.t
        if meas.t > t + 0.5 * self._dt:
            self._pending.append(meas)
            return
        h = self.history
        if meas.t < t - 0.5 * self._dt and self._delayed:
            gen = h.rb_gen = h.fuse_delayed_steps(meas, self._dt)
            done = yield from gen  # None: run to its end by finish_rollback (it returns False only at once)
            h.rb_gen = None
            if done is not False:
                return
        # uncompensated (or beyond the history): treat a late measurement as valid now
        step_n = self.step_n
        yield from self.fuse_now_steps(meas, assume_now=meas.t < t - 1.5 * self._dt)
        if self._delayed:
            h.log.append((step_n, "meas", meas))

    def fuse_now(self, meas: AidSample, assume_now: bool = False) -> None:
        """Fuse ``meas`` at the current step (no delay handling): :meth:`fuse_now_steps` run to its end."""
        for _ in self.fuse_now_steps(meas, assume_now):
            pass

    def fuse_now_steps(self, meas: AidSample, assume_now: bool = False) -> Iterator[None]:
        """Fuse at the current step (the aid source's model, :meth:`ins_hil.aids.Aid.fuse`); yields between the
        updates of one sample (a GNSS fix's position and velocity)."""
        yield from self._aid_of(meas)[1].fuse(meas, assume_now)

    def _sensor_checked(self, chk: SensorCheck) -> None:
        """The start-up check has judged: keep its warnings, inflate the white-noise densities it found too small
        (the filter's ``qc``: accelerometer → velocity, gyro → attitude)."""
        self.sensor_check = None
        self.sensor_warnings = list(chk.warnings)
        kg, ka = chk.inflate
        if kg > 1.0 or ka > 1.0:
            qc = self.kf.qc.copy()
            qc[3:6] *= ka * ka
            qc[6:9] *= kg * kg
            self.kf.qc = qc

    def _recover(self, meas: GnssFix, v_track: Vec) -> None:
        """A diverged filter (:meth:`GnssReset.ok`: the INS velocity off the rejected fixes' own track): take the
        track's velocity ``v_track`` (NED m/s); when both speeds exceed ``alignment.gnss_yaw_speed`` and agree
        within half, turn the yaw by the angle between the INS velocity and the track (the dead-reckoned velocity
        turned with the yaw error); re-open the attitude and bias σ to their initial values so the filter learns
        them again (EKF2's reset to GNSS after ``EKF2_GPS_TOUT``, with its GSF's yaw). Counted in
        :attr:`divergences`, reported as a FaultEvent (sensor "nav")."""
        s = self.ins.state
        c, f = self.cfg, self.cfg.filter
        sp_i = math.hypot(float(s.vel_ned[0]), float(s.vel_ned[1]))
        sp_t = math.hypot(float(v_track[0]), float(v_track[1]))
        dpsi = 0.0
        if min(sp_i, sp_t) >= c.alignment.gnss_yaw_speed and abs(sp_i - sp_t) <= 0.5 * sp_t:
            dpsi = math.remainder(
                math.atan2(float(v_track[1]), float(v_track[0])) - math.atan2(float(s.vel_ned[1]), float(s.vel_ned[0])),
                math.tau,
            )
            s.q_nb = quat_mul(quat_from_rotvec(np.array((0.0, 0.0, dpsi))), s.q_nb)  # C ← R_down(Δψ) C
        s.vel_ned = np.asarray(v_track, dtype=np.float64).copy()
        self.kf.set_state_sigma("att", np.array((f.init_att, f.init_att, max(f.init_yaw, abs(dpsi)))))
        if self.idx.bg is not None:
            self.kf.set_state_sigma("bg", f.init_gyro_bias)
        if self.idx.ba is not None:
            self.kf.set_state_sigma("ba", f.init_accel_bias)
        if not self.replaying:
            why = self.gnss_reset.diverged + (f", yaw turned {math.degrees(dpsi):+.0f}°" if dpsi else "")
            self.divergences.append((meas.t, why))
            self._events.append(
                FaultEvent(meas.t, "nav", FaultMode.DRIFT, math.nan, True, True,
                           f"filter diverged: reset to GNSS ({why})")
            )  # fmt: skip

    def _yaw_check(self, meas: GnssFix) -> None:
        """After a fix: EKF2's emergency yaw reset (:class:`~ins_hil.core_parts.yaw_reset.YawReset`). When due, the
        attitude is turned about down onto the yaw bank's yaw (its σ the bank's), the tilt, z gyro bias and
        accelerometer bias σ reopened, and the velocity and position reset to the fix. Counted in
        :attr:`yaw_resets`, a FaultEvent (sensor "nav")."""
        c, f, i = self.cfg, self.cfg.filter, self.idx
        kind = "gnss_vel" if c.gnss.use_vel and meas.vel_ned is not None else "gnss_pos"
        s = self.ins.state
        P = self.kf.P
        # the GNSS velocity fails its test (YawReset.check needs one), or on a ground vehicle the NHC (a yaw that is
        # off turns the accepted GNSS velocity sideways in the body)
        st = self.stats
        rejected = st[kind].consecutive_rejects > 0 or (c.aids.nhc and st["nhc"].consecutive_rejects > 0)
        dpsi = self.yaw_reset.check(meas, rejected, s.q_nb, float(P[i.att + 2, i.att + 2]))
        if dpsi is None:
            return
        sd = np.sqrt(np.abs(P.diagonal()))
        s.q_nb = quat_mul(quat_from_rotvec(np.array((0.0, 0.0, dpsi))), s.q_nb)  # C ← R_down(Δψ) C
        # the tilt and the accelerometer bias took in the wrong yaw's innovations: they re-open with the yaw
        self.kf.set_state_sigma("att", np.array((f.init_att, f.init_att, math.sqrt(self.yaw_reset.gsf.yaw_var))))
        if i.bg is not None:
            self.kf.set_state_sigma("bg", np.array((sd[i.bg], sd[i.bg + 1], f.init_gyro_bias)))
        if i.ba is not None:
            self.kf.set_state_sigma("ba", f.init_accel_bias)
        assert meas.vel_ned is not None  # YawReset.check resets only with a GNSS velocity
        s.vel_ned = np.asarray(meas.vel_ned, dtype=np.float64).copy()
        self.kf.set_state_sigma("vel", max(meas.std_vel, c.gnss.min_std[2]) * c.gnss.std_scale + 0.1)
        m = gnss_position(meas, s, dcm_from_quat(s.q_nb), i, c, True)
        self.kf.set_state_sigma("pos", np.sqrt(m.z * m.z + m.r))
        self._apply(m, meas.t, True)
        self.stats["gnss_vel"].consecutive_rejects = 0
        self.stats["gnss_pos"].consecutive_rejects = 0
        self.gnss_reset.rejected.clear()
        why = f"yaw {math.degrees(dpsi):+.0f}° off the GNSS-velocity yaw estimator"
        self.yaw_resets.append((meas.t, why))
        self._events.append(
            FaultEvent(meas.t, "nav", FaultMode.JUMP, abs(dpsi), True, True, f"yaw reset to the yaw estimator ({why})")
        )

    def _apply(self, m: Measurement, t: float, force: bool = False) -> bool:
        """Gate, (adapt R), update, feed back one measurement valid at ``t`` (s). Returns True if accepted
        (``force``: over the gate, a GNSS reset that passed :meth:`GnssReset.ok`)."""
        kf = self.kf
        kind, z, H, r, gate = m
        HPHt = H @ kf.P @ H.T
        ad = self.adapt.get(kind) if self.cfg.adaptive else None
        if ad is not None:
            r = r * ad.scale
        S = HPHt + np.diag(r)
        ratio, nis = test_ratio(z, S, gate)
        st = self.stats[kind]
        st.last_ratio = ratio
        self._ratios = dict(self._ratios)
        self._ratios[kind] = ratio
        st.last_nis = nis
        if kind in self.innov_kinds and not self.replaying:
            self.innov_log.append((t, kind, z.copy()))
        if ratio > 1.0 and not force:
            if not self.replaying:
                st.rejected += 1
                st.consecutive_rejects += 1
                if st.consecutive_rejects == 1 and kind in ("gnss_pos", "gnss_vel", "baro"):
                    self._events.append(
                        FaultEvent(t, "gnss" if kind.startswith("gnss") else "baro", FaultMode.JUMP,
                                   float(np.max(np.abs(z))), True, False, f"{kind} innovation test ratio {ratio:.2f}")
                    )  # fmt: skip
            return False
        if self.keep_nis and not self.replaying:
            self.nis_log.append((t, kind, nis, len(z)))  # accepted innovations only (consistency check)
        if ad is not None:
            ad.update(z, np.diag(HPHt), r / ad.scale)
        if not self.replaying:
            if st.consecutive_rejects > 0 and kind in ("gnss_pos", "gnss_vel", "baro"):
                self._events.append(
                    FaultEvent(t, "gnss" if kind.startswith("gnss") else "baro", FaultMode.JUMP, 0.0, True, True,
                               f"{kind} accepted again after {st.consecutive_rejects} rejections")
                )  # fmt: skip
            st.accepted += 1
            st.consecutive_rejects = 0
        kf.update(z, H, r)
        self._feedback(kf.reset())
        return True

    def _feedback(self, x: Vec) -> None:
        """Apply the error estimate to the nominal state (DIGEST_000 §9 corrections)."""
        i = self.idx
        s = self.ins.state
        m, n = earth.radii(s.lat)
        s.lat += x[0] / (m + s.h)
        s.lon += x[1] / ((n + s.h) * math.cos(s.lat))
        s.h -= x[2]
        s.vel_ned = s.vel_ned + x[3:6]
        s.q_nb = quat_mul(quat_from_rotvec(-x[6:9]), s.q_nb)  # Ĉ ← (I − [μ×]) Ĉ
        if i.bg is not None:
            self.bg = self.bg + x[i.bg : i.bg + 3]
        if i.ba is not None:
            self.ba = self.ba + x[i.ba : i.ba + 3]
        if i.sg is not None and i.sa is not None:
            self.sg = self.sg + x[i.sg : i.sg + 3]
            self.sa = self.sa + x[i.sa : i.sa + 3]
        if i.gs is not None:
            self.G = self.G + x[i.gs : i.gs + 9].reshape(3, 3)
        if i.mnt is not None:
            self.q_mount = quat_mul(quat_from_rotvec(-x[i.mnt : i.mnt + 3]), self.q_mount)  # R̂ ← (I − [δε×]) R̂
        if i.mb is not None:
            self.mb = self.mb + x[i.mb : i.mb + 3]  # b̂_m += δb_m
        if i.wind is not None:
            self.wind = self.wind + x[i.wind : i.wind + 2]  # ŵ += δw
        for a in self._feedback_aids:  # the aid sources' own states (e.g. the odometer scale factor)
            a.feedback(x)

    # ------------------------------------------------------------------ outputs
    def aid(self, name: str) -> Aid:
        """This core's part of the aid source ``name`` (:mod:`ins_hil.aids`; e.g. ``"odometer"``, its scale factor)."""
        return self._aid_by_name[name]

    def align_status(self) -> str:
        """Why the core is not navigating yet, in one line ("" once it navigates)."""
        return "" if self.phase == "nav" else self.align.waiting_for()

    def drain_events(self) -> list[FaultEvent]:
        """GNSS/baro fault events raised by the innovation tests since the last call."""
        ev, self._events = self._events, []
        return ev

    def state(self) -> NavState:
        """The current navigation solution (arrays are fresh: the core never mutates them later)."""
        s = self.ins.state
        P = self.kf.P
        if P is not self._sd_of:  # P is replaced, never mutated in place: σ only when it changed
            self._sd_of = P
            self._sd = np.sqrt(np.abs(P.diagonal()[:9]))
        sd = self._sd  # shared by the states until P changes (never mutated)
        att_ok = self.phase == "nav" and float(sd[8]) < self.cfg.alignment.aligned_yaw_std
        return NavState(
            s.t, s.q_nb, s.vel_ned, s.lat, s.lon, s.h, self.bg, self.ba, sd[0:3], sd[3:6], sd[6:9],
            self.omega_b, self.f_b, att_ok, self._ratios,
        )  # fmt: skip
