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
import signal
import threading
import time
import traceback
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ins_hil.types import FixType, GnssFix, ImuSample

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


class Measure:
    """A figure a step measured (e.g. a child's peak memory): the campaign keeps its maximum per target, it is not a
    sample."""

    def __init__(self, name: str, value: float) -> None:
        self.name = name
        self.value = value


class Checked:
    """Samples a step checked against the physical ranges itself (:func:`suspects`) and found plausible: the campaign
    counts them as accepted samples without taking them one by one (a sample the step's check doubts is returned
    as itself and goes through :func:`bad_sample` and the validation boundary as before)."""

    def __init__(self, n: int) -> None:
        self.n = n


class Replayed:
    """A step replayed an accepted input through the dataset replay (prepare, the core, the scores);
    ``navigating``: the core left its alignment (the NaN-state oracle saw a navigating filter)."""

    def __init__(self, navigating: bool) -> None:
        self.navigating = navigating


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
    kind = s.kind  # the oracle's own ranges per sample kind (independent of ins_hil.validation)
    if kind == "imu":
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
    if kind == "gnss":
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
    if kind == "baro":
        if not fin(s.t):
            return "baro_t_nonfinite"
        if not (fin(s.pressure) and P_RANGE[0] <= s.pressure <= P_RANGE[1]):
            return "baro_pressure"
        if not (math.isnan(s.altitude) or (fin(s.altitude) and H_RANGE[0] <= s.altitude <= H_RANGE[1])):
            return "baro_altitude"
        return ""
    if kind == "mag":
        f = [float(x) for x in s.field_b]
        if not fin(s.t):
            return "mag_t_nonfinite"
        if not all(fin(x) for x in f) or math.sqrt(sum(x * x for x in f)) > MAX_FIELD:
            return "mag_field"
        return ""
    return ""


def suspects(samples: list[Any]) -> list[Any]:
    """The samples of ``samples`` that may be outside the physical ranges, IMU samples checked all at once (numpy): a
    superset of those :func:`bad_sample` flags (the bounds taken 1e-9 tighter; a sample whose values do not form
    3-vectors, and every sample of another type that :func:`bad_sample` flags, included). The rest are plausible."""
    imu = [s for s in samples if type(s) is ImuSample]
    out = [s for s in samples if type(s) is not ImuSample and bad_sample(s)]
    if not imu:
        return out
    try:
        t = np.array([s.t for s in imu], dtype=float)
        dt = np.array([s.dt for s in imu], dtype=float)
        th = np.array([s.dtheta for s in imu], dtype=float).reshape(len(imu), 3)
        dv = np.array([s.dvel for s in imu], dtype=float).reshape(len(imu), 3)
    except (TypeError, ValueError):
        return out + [s for s in imu if bad_sample(s)]
    tight = 1.0 - 1e-9
    ok = np.isfinite(t) & np.isfinite(dt) & (dt >= DT_RANGE[0] / tight) & (dt <= DT_RANGE[1] * tight)
    ok &= np.isfinite(th).all(axis=1) & np.isfinite(dv).all(axis=1)
    with np.errstate(all="ignore"):
        lim = dt * math.sqrt(3) * tight
        ok &= np.sqrt((th * th).sum(axis=1)) <= MAX_RATE * lim
        ok &= np.sqrt((dv * dv).sum(axis=1)) <= MAX_ACCEL * lim
    return out + [imu[i] for i in np.flatnonzero(~ok)]


@dataclass
class Target:
    """One fuzz target: ``setup(rng)`` builds a fresh harness and returns its ``step``."""

    name: str
    what: str  # the code under test, for the report
    setup: Callable[[random.Random], Step]
    weight: float = 1.0  # share of the budget
    nav: bool = False  # feed accepted IMU samples through a Pipeline
    decoder: bool = True  # counts toward the "≥ 1 million inputs per decoder" target
    goal: int = 1_000_000  # inputs a full campaign must reach (0: none)


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
    cpu_seconds: float = 0.0  # CPU time of the process and its children while it ran (the rate on one core)
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
    blowups: int = 0  # a MemoryError out of one input (the campaign runs under an address-space cap)
    hangs: int = 0  # one input that used more than the step's CPU-time limit
    replays: int = 0  # accepted inputs a dataset target replayed (prepare, the core, the scores, the summary)
    replays_nav: int = 0  # ... whose core navigated (left its alignment)
    findings: dict[str, Finding] = field(default_factory=dict)
    maxima: dict[str, float] = field(default_factory=dict)  # the largest of each Measure the steps returned
    decoder: bool = True
    goal: int = 0  # inputs the target must reach in a full campaign (0: none)

    def note(self, kind: str, example: str) -> None:
        f = self.findings.get(kind)
        if f is None:
            f = self.findings[kind] = Finding(kind, 0, example[:300])
        f.count += 1

    def failures(self) -> int:
        """What fails the campaign: escaped exceptions, accepted-bad samples, NaN states, pipeline exceptions,
        blow-ups and hangs."""
        return self.escaped + self.accepted_bad + self.nan_states + self.nav_exceptions + self.blowups + self.hangs

    def add(self, other: TargetResult) -> None:
        """Add ``other`` (a later run of the same target) into this one: counts summed, findings merged."""
        for k in COUNTS:
            setattr(self, k, getattr(self, k) + getattr(other, k))
        for kind, f in other.findings.items():
            mine = self.findings.setdefault(kind, Finding(kind, 0, f.example))
            mine.count += f.count
        for k, v in other.maxima.items():
            self.maxima[k] = max(v, self.maxima.get(k, v))

    def to_dict(self) -> dict[str, Any]:
        d = {k: getattr(self, k) for k in ("name", "what", "decoder", "goal", *COUNTS)}
        d["findings"] = [[f.kind, f.count, f.example] for f in self.findings.values()]
        d["maxima"] = dict(self.maxima)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TargetResult:
        r = cls(d["name"], d["what"], decoder=bool(d.get("decoder", True)), goal=int(d.get("goal", 0)))
        for k in COUNTS:
            setattr(r, k, type(getattr(r, k))(d.get(k, 0)))
        r.findings = {k: Finding(k, int(n), str(ex)) for k, n, ex in d.get("findings", [])}
        r.maxima = {str(k): float(v) for k, v in d.get("maxima", {}).items()}
        return r


#: the summed fields of a TargetResult
COUNTS = ("seconds", "cpu_seconds", "inputs", "escaped", "accepted", "decoded_bad", "accepted_bad", "nav_fed",
          "nav_states", "nan_states", "nav_exceptions", "nav_stalls", "blowups", "hangs", "replays",
          "replays_nav")  # fmt: skip
#: CPU seconds one input may use before it counts as a hang (SIGVTALRM; the main thread only)
STEP_CPU_LIMIT = 20.0


class EnvironmentFault(RuntimeError):
    """A step could not import a module (the installation changed under the campaign): not a finding of the code
    under test; the campaign's runner discards the chunk and retries it later."""


class _Hang(BaseException):
    """Raised in a step by the CPU-time alarm (a BaseException: the code under test does not catch it)."""


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
    t: Target,
    seconds: float | None,
    seed: int = 0,
    nav_share: float = 0.3,
    inputs: int | None = None,
    step_cpu_limit: float | None = STEP_CPU_LIMIT,
) -> TargetResult:
    """Fuzz one target for ``seconds`` (wall clock) or until ``inputs`` inputs (a count: the same inputs on any
    machine and under any load), whichever comes first; ``nav_share``: at most this part of the time in the
    pipeline.

    Overflow warnings of junk values (numpy, Python) are silenced: what they lead to is counted. A MemoryError out
    of a step is a *blow-up*; a step that uses more than ``step_cpu_limit`` CPU seconds is stopped and counted as a
    *hang* (a CPU-time alarm, in the main thread only; None: no limit). Both rebuild the harness. An ImportError
    (in the setup or a step) is :class:`EnvironmentFault`, raised: the installation, not the input.
    """
    if seconds is None and inputs is None:
        raise ValueError("run_target: give a time budget (seconds) or an input budget (inputs)")
    alarm = step_cpu_limit is not None and threading.current_thread() is threading.main_thread()
    old = signal.signal(signal.SIGVTALRM, _on_alarm) if alarm else None
    try:
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            return _run_target(t, seconds, seed, nav_share, inputs, step_cpu_limit if alarm else None)
    except ImportError as e:  # in a target's setup
        raise EnvironmentFault(f"{t.name}: {type(e).__name__}: {e}") from e
    finally:
        if alarm:
            signal.setitimer(signal.ITIMER_VIRTUAL, 0)
            signal.signal(signal.SIGVTALRM, old)


def _cpu() -> float:
    """CPU seconds (user + system) of this process and of its children that were waited for (a child replay)."""
    import resource

    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def _on_alarm(signum: int, frame: Any) -> None:
    raise _Hang()


def _run_target(
    t: Target, seconds: float | None, seed: int, nav_share: float, inputs: int | None, limit: float | None
) -> TargetResult:
    rng = random.Random(seed)
    res = TargetResult(t.name, t.what, decoder=t.decoder, goal=t.goal)
    step = t.setup(rng)
    from ins_hil.validation import SampleValidator

    boundary = SampleValidator()  # the gateway's one validation boundary, default limits (ins_hil.validation)
    # two pipelines per IMU id (its own clock): as delivered and retimed
    navs: dict[int, tuple[NavCheck, NavCheck]] | None = {} if t.nav else None
    if navs is not None:
        NavCheck()  # imports and first-build costs outside the measured share
    mono = time.perf_counter
    cpu0 = _cpu()
    t0 = mono()
    end = math.inf if seconds is None else t0 + seconds
    most = math.inf if inputs is None else inputs
    nav_s = 0.0
    now = t0
    while now < end and res.inputs < most:
        try:
            if limit is not None:
                signal.setitimer(signal.ITIMER_VIRTUAL, limit)
            try:
                n, out = step()
            finally:
                if limit is not None:
                    signal.setitimer(signal.ITIMER_VIRTUAL, 0)
        except _Hang:
            res.hangs += 1
            res.inputs += 1
            res.note("hang", f"one input used more than {limit:g} s of CPU time")
            step = t.setup(rng)
            now = mono()
            continue
        except ImportError as e:  # ModuleNotFoundError too: the environment, not the input
            raise EnvironmentFault(f"{t.name}: {type(e).__name__}: {e}") from e
        except MemoryError:
            res.blowups += 1
            res.inputs += 1
            res.note("blow-up (MemoryError)", "one input exceeded the address-space cap")
            step = t.setup(rng)
            now = mono()
            continue
        except Exception as e:
            res.escaped += 1
            res.inputs += 1
            res.note(f"escaped {type(e).__name__}", f"{_where(e)}: {str(e)[:200]}")
            step = t.setup(rng)
            now = mono()
            continue
        res.inputs += n
        if out and any(isinstance(s, Measure | Checked | Replayed) for s in out):
            for s in out:
                if isinstance(s, Replayed):
                    res.replays += 1
                    res.replays_nav += s.navigating
                if isinstance(s, Measure):
                    res.maxima[s.name] = max(s.value, res.maxima.get(s.name, s.value))
                elif isinstance(s, Checked):
                    res.accepted += s.n
            out = [s for s in out if not isinstance(s, Measure | Checked | Replayed)]
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
                    if s.kind == "imu":
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
    res.cpu_seconds = _cpu() - cpu0
    return res
