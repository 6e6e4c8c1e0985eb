"""Fuzz campaign engine: structure-aware mutational inputs per target, within a time or an input budget.

A :class:`Target` is one entry of :data:`ins_hil.fuzz.targets.TARGETS`: a name and a ``setup(rng)``
that returns a ``step()``; each call of ``step()`` makes one or more inputs, feeds them to the
code under test and returns ``(inputs, delivered samples)``. Any exception out of ``step()`` is an
*escaped exception* (the harness is then rebuilt). Every delivered sample is checked against the
physical ranges below (*accepted-bad*), and a target with ``nav=True`` feeds its accepted IMU
samples, with a fixed GNSS fix now and then, through a default
:class:`~ins_hil.runtime.pipeline.Pipeline` and counts non-finite states (*NaN states*) and
exceptions out of the pipeline.
"""

from __future__ import annotations

import math
import random
import time
import traceback
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ins_hil.types import BaroSample, FixType, GnssFix, ImuSample, MagSample

Step = Callable[[], tuple[int, list[Any]]]

# Physical ranges of a delivered sample (the campaign's oracle; SI units)
MAX_RATE = 40.0  # rad/s (≈ 2,300 °/s): the largest navigation-IMU range
MAX_ACCEL = 400.0  # m/s² (≈ 40 g)
DT_RANGE = (1e-5, 1.0)  # s: IMU integration interval
H_RANGE = (-1000.0, 100_000.0)  # m: GNSS height
MAX_SPEED = 1000.0  # m/s: GNSS velocity norm
MAX_STD = 1e5  # m or m/s: GNSS σ
P_RANGE = (100.0, 120_000.0)  # Pa: static pressure
MAX_FIELD = 1e-3  # T (10 gauss): magnetic field norm


class Wrong:
    """A record the recorder reader returned that is not the one recorded (a silent misread)."""

    def __init__(self, what: str) -> None:
        self.what = what

    def __repr__(self) -> str:
        return f"Wrong({self.what})"


def bad_sample(s: Any) -> str:
    """Why a delivered sample is outside the physical ranges ("" when it is plausible)."""
    fin = math.isfinite
    if isinstance(s, Wrong):
        return "recorder_misread"
    if isinstance(s, ImuSample):
        if not fin(s.t):
            return "imu_t_nonfinite"
        if not (fin(s.dt) and DT_RANGE[0] <= s.dt <= DT_RANGE[1]):
            return "imu_dt"
        a = [float(x) for x in s.dtheta]
        v = [float(x) for x in s.dvel]
        if not all(fin(x) for x in a + v):
            return "imu_nonfinite"
        if math.sqrt(sum(x * x for x in a)) > MAX_RATE * s.dt * math.sqrt(3):
            return "imu_rate_range"
        if math.sqrt(sum(x * x for x in v)) > MAX_ACCEL * s.dt * math.sqrt(3):
            return "imu_accel_range"
        return ""
    if isinstance(s, GnssFix):
        if not fin(s.t):
            return "gnss_t_nonfinite"
        if s.fix_type < FixType.FIX_2D:
            return "gnss_no_fix_delivered"
        if not (fin(s.lat) and fin(s.lon) and abs(s.lat) <= math.pi / 2 and abs(s.lon) <= math.pi):
            return "gnss_latlon"
        if not (fin(s.h) and H_RANGE[0] <= s.h <= H_RANGE[1]):
            return "gnss_height"
        for x in (s.std_ne, s.std_d, s.std_vel):
            if not (fin(x) and 0 < x <= MAX_STD):
                return "gnss_std"
        if s.vel_ned is not None:
            vel = [float(x) for x in s.vel_ned]
            if not all(fin(x) for x in vel) or math.sqrt(sum(x * x for x in vel)) > MAX_SPEED:
                return "gnss_velocity"
        return ""
    if isinstance(s, BaroSample):
        if not fin(s.t):
            return "baro_t_nonfinite"
        if not (fin(s.pressure) and P_RANGE[0] <= s.pressure <= P_RANGE[1]):
            return "baro_pressure"
        if not (math.isnan(s.altitude) or (fin(s.altitude) and H_RANGE[0] <= s.altitude <= H_RANGE[1])):
            return "baro_altitude"
        return ""
    if isinstance(s, MagSample):
        f = [float(x) for x in s.field_b]
        if not fin(s.t):
            return "mag_t_nonfinite"
        if not all(fin(x) for x in f) or math.sqrt(sum(x * x for x in f)) > MAX_FIELD:
            return "mag_field"
        return ""
    return ""


@dataclass
class Target:
    """One fuzz target: ``setup(rng)`` builds a fresh harness and returns its ``step``."""

    name: str
    what: str  # the code under test, for the report
    setup: Callable[[random.Random], Step]
    weight: float = 1.0  # share of the budget
    nav: bool = False  # feed accepted IMU samples through a Pipeline
    decoder: bool = True  # counts toward the "≥ 1 million inputs per decoder" target


@dataclass
class Finding:
    kind: str
    count: int = 0
    example: str = ""


@dataclass
class TargetResult:
    name: str
    what: str
    seconds: float = 0.0
    cpu_seconds: float = 0.0  # CPU time of the process while it ran (what the rate on one free core is based on)
    inputs: int = 0
    escaped: int = 0
    accepted: int = 0
    decoded_bad: int = 0  # delivered by the decoder outside the physical ranges (the validation boundary's job)
    accepted_bad: int = 0  # ... and passed by the validation boundary too (what would reach the core)
    nav_fed: int = 0  # samples fed, counted once per pipeline (each sample goes to two)
    nav_states: int = 0
    nan_states: int = 0
    nav_exceptions: int = 0
    nav_stalls: int = 0  # the pipeline produced no state for STALL samples in a row after its start
    findings: dict[str, Finding] = field(default_factory=dict)
    decoder: bool = True

    def note(self, kind: str, example: str) -> None:
        f = self.findings.get(kind)
        if f is None:
            f = self.findings[kind] = Finding(kind, 0, example[:300])
        f.count += 1


STALL = 500


class NavCheck:
    """A default Pipeline fed with one IMU's accepted samples (as IMU 0) and a fixed GNSS fix every 100th sample.

    As delivered (``retime=False``): a pipeline that stops producing states (e.g. every sample
    ``imu_time_backwards`` after one accepted sample far ahead in time) for :data:`STALL` samples
    (twice that before its first state) is counted as a stall and rebuilt. Retimed: the samples get
    times 5 ms apart (their own ``dt`` kept), so the values (dθ, dv, dt) keep reaching the core when
    the decoder's time is poisoned; its NaN states and exceptions count the same way.
    """

    def __init__(self, retime: bool = False) -> None:
        self.retime = retime
        self._new()

    def _new(self) -> None:
        from ins_hil.runtime.pipeline import Pipeline, PipelineConfig

        self.pipe = Pipeline(PipelineConfig())
        self.n = 0
        self.since_state = 0
        self.started = False
        self.t = 0.0

    def feed(self, s: ImuSample, res: TargetResult) -> None:
        res.nav_fed += 1
        self.n += 1
        if self.retime:
            self.t += 0.005
            s = ImuSample(self.t, s.dt, s.dtheta, s.dvel, 0, s.seq, s.temperature, s.flags, s.t_arrival_ns)
        elif s.imu_id != 0:  # the default pipeline navigates with IMU 0
            s = ImuSample(s.t, s.dt, s.dtheta, s.dvel, 0, s.seq, s.temperature, s.flags, s.t_arrival_ns)
        try:
            st = self.pipe.imu(s)
            if self.n % 100 == 0 and math.isfinite(s.t):
                fix = GnssFix(s.t, 0.8, 0.2, 100.0, None, 1.0, 2.0, 0.3, FixType.FIX_3D, 10, 0, s.t_arrival_ns)
                self.pipe.aid(fix)
        except Exception as e:
            res.nav_exceptions += 1
            res.note(f"pipeline {type(e).__name__}", f"{_where(e)}: {e} (after {s!r})")
            self._new()
            return
        if st is None:
            self.since_state += 1
            limit = STALL if self.started else 2 * STALL  # 2×: room for the alignment
            if not self.retime and self.since_state >= limit:
                res.nav_stalls += 1
                res.note("pipeline stall", f"{STALL} samples without a state, counters {self.pipe.counts}; last {s!r}")
                self._new()
            return
        self.started = True
        self.since_state = 0
        res.nav_states += 1
        vals = [*map(float, st.q_nb), *map(float, st.vel_ned), st.lat, st.lon, st.h]
        if not all(math.isfinite(x) for x in vals):
            res.nan_states += 1
            res.note("NaN state", f"t {st.t} after {s!r}")
            self._new()


def _where(e: BaseException) -> str:
    tb = traceback.extract_tb(e.__traceback__)
    if not tb:
        return "?"
    fr = tb[-1]
    return f"{fr.filename.rsplit('/', 2)[-1] if '/' in fr.filename else fr.filename}:{fr.lineno}"


def run_target(
    t: Target, seconds: float | None, seed: int = 0, nav_share: float = 0.3, inputs: int | None = None
) -> TargetResult:
    """Fuzz one target for ``seconds`` (wall clock) or until ``inputs`` inputs (a count: the same inputs on any
    machine and under any load), whichever comes first; ``nav_share``: at most this part of the time in the
    pipeline.

    Overflow warnings of junk values (numpy, Python) are silenced: what they lead to is counted.
    """
    if seconds is None and inputs is None:
        raise ValueError("run_target: give a time budget (seconds) or an input budget (inputs)")
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")
        return _run_target(t, seconds, seed, nav_share, inputs)


def _run_target(t: Target, seconds: float | None, seed: int, nav_share: float, inputs: int | None) -> TargetResult:
    rng = random.Random(seed)
    res = TargetResult(t.name, t.what, decoder=t.decoder)
    step = t.setup(rng)
    from ins_hil.validation import SampleValidator

    boundary = SampleValidator()  # the gateway's one validation boundary, default limits (ins_hil.validation)
    # two pipelines per IMU id (its own clock): as delivered and retimed
    navs: dict[int, tuple[NavCheck, NavCheck]] | None = {} if t.nav else None
    if navs is not None:
        NavCheck()  # imports and first-build costs outside the measured share
    mono = time.perf_counter
    cpu0 = time.process_time()
    t0 = mono()
    end = math.inf if seconds is None else t0 + seconds
    most = math.inf if inputs is None else inputs
    nav_s = 0.0
    now = t0
    while now < end and res.inputs < most:
        try:
            n, out = step()
        except Exception as e:
            res.escaped += 1
            res.inputs += 1
            res.note(f"escaped {type(e).__name__}", f"{_where(e)}: {str(e)[:200]}")
            step = t.setup(rng)
            now = mono()
            continue
        res.inputs += n
        if out:
            res.accepted += len(out)
            for s in out:
                why = bad_sample(s)
                if not why:
                    if not isinstance(s, Wrong):
                        boundary.check(s)  # keeps its per-source times in step with the stream
                    continue
                if isinstance(s, Wrong):  # a recorder misread has no boundary behind it
                    res.accepted_bad += 1
                    res.note(f"accepted-bad {why}", repr(s))
                    continue
                res.decoded_bad += 1
                res.note(f"decoded out of range {why}", repr(s))
                if boundary.check(s) is None:
                    res.accepted_bad += 1
                    res.note(f"accepted-bad {why} (passed the validation boundary)", repr(s))
            if navs is not None and nav_s <= nav_share * (now - t0 + 1e-3):
                n0 = mono()
                for s in out:
                    if isinstance(s, ImuSample):
                        pair = navs.get(s.imu_id)
                        if pair is None:
                            if len(navs) >= 8:
                                navs.clear()
                            pair = navs[s.imu_id] = (NavCheck(), NavCheck(retime=True))
                        pair[0].feed(s, res)
                        pair[1].feed(s, res)
                nav_s += mono() - n0
        now = mono()
    res.seconds = now - t0
    res.cpu_seconds = time.process_time() - cpu0
    return res
