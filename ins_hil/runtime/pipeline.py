"""The synchronous navigation pipeline shared by the live loop and replay.

calibration → (redundant-IMU epoch grouping →) FDI monitor → core.step, and
aiding measurements held until the IMU time reaches their time of validity,
then checked by the drift monitor and fused (``core.fuse``). Pure and
deterministic: no I/O, no clock, no asyncio. The loop records every input in
the order it hands them to :meth:`Pipeline.imu` / :meth:`Pipeline.aid`;
replaying that order through a fresh pipeline built from the same config gives
the same states bit for bit.

Aiding work is split into segments run one per gap between IMU epochs: a GNSS
fix costs about 1 ms in the Python core (drift-monitor check, position update,
velocity update, each 0.2–0.4 ms), more than the slack of a 1 kHz loop, so it is
spread over three gaps instead of delaying the next IMU sample. A measurement
handed over in one gap has its first segment in the next (after the next
epoch), so an IMU sample already queued behind it is not delayed. The live loop
runs the segment of a gap right after publishing the epoch's state
(:meth:`Pipeline.work`); one that has not run by the next epoch (a backlog)
runs at its start. The schedule depends only on the input order, so replay
(which never calls :meth:`work`) performs the same operations in the same order.

The IMU step itself is split the same way (:class:`RealTimeCore` ``step_begin`` / ``step_end``; the C
core's step is one piece and its ``step_end`` a no-op): the strapdown mechanization runs on the IMU path
and its state is published; the filter's time update (covariance propagation, ground-vehicle aids, about
0.1 ms) runs after publishing, before anything else touches the core. The published state is the
mechanized state: its σ are those of the previous step (1 ms older at 1 kHz), and a
ground-vehicle aid (NHC/ZUPT) applied in this step's time update shows in the next state.

Every sample passes the validation boundary first (:class:`ins_hil.validation.SampleValidator`,
limits from the ``[core]`` keys ``gyro_range_dps``, ``accel_range_g``, ...): a rejected sample is
counted once as ``reject_<reason>`` and never reaches the core. An IMU whose clock restarted (its times
going back, passed through by a driver) is re-anchored on the second such sample (``imu_clock_reanchor``,
:meth:`Pipeline._clock_restart`): its later times continue the old time base, so it is never refused for
good. The core guard: after every core
step and fusion segment the state is checked (:func:`state_ok`: finite and plausible position and
velocity, |q| = 1, σ finite and ≥ 0); a failed check or any exception inside the core is counted
(``core_bad_state`` / ``core_exception``), reported as a ``FaultEvent`` with sensor ``core`` (cleared
after ``FAULT_CLEAR_S`` of good states), and recovered from: the core restarts from the last good
state with the initial covariance (``core_restart``), or re-aligns from the next 3-D GNSS fix
(``core_realign``) when there is none or a second fault comes before the first cleared.
:meth:`Pipeline.imu` and :meth:`Pipeline.aid` never raise (anything else: ``pipeline_error``).

Observers (:class:`Observer`: scoring and recording of an offline replay, ``ins_hil.datasets.run.replay``)
are called after each IMU epoch with its published state and around each aiding fusion (before the drift
monitor's check, after the core's update or the exclusion); they read, never change, the core.

Initialisation (until the core aligns itself): ``init = "core"`` (offline replay) creates the core at
the first IMU sample and leaves the whole alignment to it (``ins_hil.core_parts.alignment``: levelling,
yaw from the course, the magnetometer or the GNSS yaw bank), or starts it at a given ``initial`` state
(a simulated scenario). ``init = "gnss"``: the core is created at the
first 3-D GNSS fix (the fix an aid source may start a core from,
:meth:`ins_hil.aids.AidSource.starts_core`) by the core's own initialisation,
:func:`ins_hil.core.initial_state`: at the fix's position and velocity, with
roll/pitch levelled from the mean specific force of the last ``level_samples``
IMU intervals (the core's levelling, :func:`ins_hil.nav.alignment.coarse_level`)
and yaw from the config, or from the GNSS course when faster than the core's
``[core.nav.alignment] gnss_yaw_speed``. ``init = "config"`` starts at a
configured state instead.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol, cast

import numpy as np

from ins_hil import aids
from ins_hil.core_parts.config import MOVED, NavConfig
from ins_hil.nav.mechanization import StrapdownState
from ins_hil.nav.rotation import quat_from_euler
from ins_hil.settings import ConfigError, build, setting, table
from ins_hil.types import AidSample, FaultEvent, FaultMode, GnssFix, ImuSample, NavState, Sample
from ins_hil.validation import Limits, SampleValidator

#: an aiding sample (any aid source's, :mod:`ins_hil.aids`)
Aid = AidSample
_DONE = object()


class RealTimeCore(Protocol):
    """What the runtime needs of a navigation core (Python ``NavCore`` or C ``CNavCore``).

    The step runs in two parts: ``step_begin`` (the mechanization; its state is published) and
    ``step_end`` (the filter time update, after publishing; a no-op for a core whose step is one
    piece); ``fuse_steps`` is ``fuse`` as a generator of segments, one per gap between IMU epochs."""

    def step(self, imu: ImuSample) -> NavState: ...

    def step_begin(self, imu: ImuSample) -> NavState: ...

    def step_end(self) -> None: ...

    def fuse(self, meas: Aid) -> None: ...

    def fuse_steps(self, meas: Aid) -> Iterator[None]: ...

    def state(self) -> NavState: ...

    def drain_events(self) -> list[FaultEvent]: ...

    def align_status(self) -> str: ...


CORE_KINDS = ("python", "c")


class Observer:
    """Read-only callbacks of a :class:`Pipeline` (an offline replay's scoring and recording; no-ops here).

    ``epoch``: after each IMU epoch, with the state it published; ``before_fuse``: an aiding measurement's
    fusion begins (the core has not seen it: the a-priori state); ``segment``: around each segment of the
    core's update; ``after_fuse``: it ended, ``fused`` False when the drift monitor excluded it. They must not
    change the core (``pipe.core``)."""

    def epoch(self, pipe: Pipeline, st: NavState) -> None:
        """An IMU epoch ran and published ``st``."""

    def epochs(self, pipe: Pipeline, states: Sequence[NavState]) -> None:
        """A run of IMU epochs ran (the C core's samples up to the next aiding measurement, ``Pipeline.imu_run``)
        and published ``states``: :meth:`epoch` on each, in order. An observer that overrides it takes the run at
        once (the pipeline then calls it once per run, after the run's states, counts and events; a sequence that
        builds each ``NavState`` when indexed, its rows ``states.rows`` in the C state record when it has them)."""
        for st in states:
            self.epoch(pipe, st)

    def before_fuse(self, pipe: Pipeline, m: Aid) -> None:
        """The fusion of ``m`` begins."""

    def segment(self, pipe: Pipeline, m: Aid, start: bool) -> None:
        """A segment of the core's update of ``m`` begins (``start``) or ends: no IMU step runs inside one."""

    def after_fuse(self, pipe: Pipeline, m: Aid, fused: bool) -> None:
        """The fusion of ``m`` ended (``fused`` False: excluded by the drift monitor)."""


def nav_config(options: dict[str, Any] | NavConfig) -> NavConfig:
    """``ins_hil.core.NavConfig`` from the ``[core.nav]`` table (its sections as sub-tables: ``gnss``, ``baro``,
    ``mag``, ``aids``, ``hold``, ``alignment``, ``delay``, ``filter``, and the aid modules' own sections,
    ``[core.nav.odometer]``, ... into ``NavConfig.sources``), built by the one builder of every settings table
    (:func:`ins_hil.settings.build`, the key checks of docs/configuration.md). Raises ConfigError (a ValueError) in
    one line naming the bad key (an old flat key: where it moved). A ``NavConfig`` is returned as it is."""
    if isinstance(options, NavConfig):
        return options
    for k in options:
        if k in MOVED:
            sec, new = MOVED[k]
            raise ConfigError(f"[core.nav] {k} moved to [core.nav.{sec}] {new}")
    own = aids.sections()  # the aid modules' own sections: NavConfig.sources
    opts = {k: v for k, v in options.items() if k not in own}
    src = {k: build(own[k], v, f"core.nav.{k}") for k, v in options.items() if k in own}
    cfg: NavConfig = build(NavConfig, opts, "core.nav", sources=src) if src else build(NavConfig, opts, "core.nav")
    return cfg


def _initial_placeholder() -> StrapdownState:
    return StrapdownState(np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(3), 0.9, 0.5, 100.0)


def check_core(kind: str, nav: NavConfig | None = None) -> None:
    """Raise now (before anything starts) if the core ``kind`` cannot be built with ``nav`` (None: the
    defaults)."""
    if kind not in CORE_KINDS:
        raise ValueError(f"unknown core {kind!r} (choose from {', '.join(CORE_KINDS)})")
    make_core(kind, _initial_placeholder(), nav)


def make_core(kind: str, initial: StrapdownState | None, nav: NavConfig | None = None) -> RealTimeCore:
    """The navigation core by name: ``python`` (ins_hil.core.NavCore) or ``c`` (ins_hil.cref.CNavCore; a
    setting the C core lacks is refused in one line naming it). ``nav``: the built ``NavConfig`` (None: the
    defaults); ``initial`` None: the core aligns itself (the C core through the Python core's alignment,
    handed over when it navigates, and stepping with each sample's own dt: ``CNavCore(None, nav,
    fixed_step=False)``)."""
    cfg = nav if nav is not None else NavConfig()
    from ins_hil.core import NavCore

    try:
        from ins_hil import cref
    except ImportError as e:
        if kind == "c":
            raise RuntimeError(f"core 'c': the C reference core (ins_hil.cref) is not available: {e}") from e
        return NavCore(initial, cfg)
    try:
        core: RealTimeCore
        if kind == "c" and initial is None:
            core = cref.CNavCore(None, cfg, fixed_step=False)
        elif kind == "c":
            core = cref.CNavCore(initial, cfg)
        else:
            core = NavCore(initial, cfg)
    except (ImportError, OSError) as e:
        raise RuntimeError(f"core {kind!r}: cannot load the C reference core: {e}") from e
    except ValueError as e:
        raise RuntimeError(f"core {kind!r}: {e}") from e
    return core


@dataclass
class PipelineConfig:
    """Settings of the pipeline (the ``[core]`` table of a config, plus FDI and calibration)."""

    core: str = setting(
        "python",
        help="navigation core: python (ins_hil.core) or c (the C reference core, ins_hil.cref)",
        choices=("python", "c"),
    )
    init: str = setting(
        "gnss",
        help="gnss: start at the first 3-D fix, levelled from the accelerometers; config: the init_* keys; "
        "core: the core aligns itself from the first IMU sample (offline replay)",
        choices=("gnss", "config", "core"),
    )
    init_lat_deg: float = setting(
        0.0, "°", "[-89, 89]", "initial latitude (init = 'config'); the NED mechanization is singular at the poles"
    )
    init_lon_deg: float = setting(0.0, "°", "[-180, 180]", "initial longitude (init = 'config')")
    init_h: float = setting(0.0, "m", "[-1000, 100000]", "initial height above the WGS84 ellipsoid (init = 'config')")
    init_roll_deg: float = setting(0.0, "°", "[-180, 180]", "initial roll (init = 'config')")
    init_pitch_deg: float = setting(0.0, "°", "[-90, 90]", "initial pitch (init = 'config')")
    init_yaw_deg: float = setting(
        0.0, "°", "[-360, 360]", "initial yaw (init = 'config'; with gnss: when not moving at the first fix)"
    )
    level_samples: int = setting(200, "IMU intervals", "[1, 100000]", "intervals averaged for the levelling")
    imu_ids: list[int] = field(default_factory=lambda: [0])
    # redundant IMUs: an epoch (one sensor time) waits at most this many IMU periods of arrival time
    # for the units that have not delivered yet, then runs with what is there (imu_epoch_incomplete)
    epoch_wait_periods: float = setting(
        3.0, "IMU periods", "(0, 1000]", "redundant IMUs: how long an epoch waits (arrival time) for a missing unit"
    )
    fdi: bool = False
    fdi_options: dict[str, Any] = field(default_factory=dict)
    calibration: str = setting(
        "", help="IMU calibration file (ins-hil calibrate; ins_hil.nav.calibration); '' = none", file=True
    )
    aiding_fdi: bool = True  # GNSS/baro drift monitor (ins_hil.fdi.aiding), the [fdi.aiding] table
    aiding_options: dict[str, Any] = field(default_factory=dict)  # AidingConfig fields
    # the [core.nav] table, built once (settings.build); a table given here (a recording's header, a test) is built
    nav: NavConfig = field(default_factory=NavConfig)
    # the validation boundary: every sample is checked at the pipeline's entry (its keys sit in [core], flat)
    limits: Limits = field(default_factory=Limits)
    # the typed FDI / aiding-monitor configs of the tables above, each built once (fdi_config, aiding_config)
    _built: dict[str, tuple[Any, Any]] = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not isinstance(self.nav, NavConfig):
            self.nav = nav_config(self.nav)

    def fdi_config(self) -> Any:
        """The ``FdiConfig`` of :attr:`fdi_options` (``[fdi.options]``), built once: the loader's check builds it,
        the pipeline's monitor uses the same object (built again only if the table changed)."""
        return self._once("fdi", self.fdi_options, lambda: fdi_config(self.fdi_options))

    def aiding_config(self) -> Any:
        """The ``AidingConfig`` of :attr:`aiding_options` (``[fdi.aiding]``) under :attr:`nav`, built once."""
        key = (self.aiding_options, self.nav.delay.compensation)
        return self._once("aiding", key, lambda: aiding_config(self.aiding_options, self.nav))

    def _once(self, name: str, key: Any, make: Callable[[], Any]) -> Any:
        hit = self._built.get(name)
        if hit is None or hit[0] != key:
            hit = self._built[name] = (copy.deepcopy(key), make())
        return hit[1]

    def to_dict(self) -> dict[str, Any]:
        """Plain values (a recording's header, read back by ``ins_hil.runtime.replay.pipeline_config_from_header``):
        ``nav`` as its ``[core.nav]`` table, the keys that differ from the defaults (:func:`ins_hil.settings.table`)."""
        d = dataclasses.asdict(self)
        del d["_built"]
        d["nav"] = table(self.nav)
        return d


def limits_of(cfg: PipelineConfig) -> Limits:
    """The validation limits of a pipeline config, checked (ValueError names the bad ``core.*`` key)."""
    cfg.limits.check("core")
    return cfg.limits


#: a unit missing from this many epochs in a row is not waited for until it delivers again
GONE_EPOCHS = 20
#: aiding jobs queued beyond this many run at the next epoch without waiting for a gap each
MAX_AID_JOBS = 8
#: a restarted core is trusted again (its fault cleared) after this long of good states (s, sensor time);
#: a second fault before that re-aligns from the next GNSS fix instead of restarting again
FAULT_CLEAR_S = 1.0
#: plausibility of a navigation state (the core guard): speed (m/s), height (m), |q| − 1
STATE_SPEED_MAX = 1.0e4
STATE_H_MIN, STATE_H_MAX = -1.0e5, 1.0e6
QNORM_TOL = 1e-3
_INF = math.inf
#: ``Pipeline.last_state`` / ``_good`` stand for the last state of the last C run (built when read)
_RUN_LAST = object()


def state_ok(st: NavState) -> bool:
    """The core guard: position, velocity finite and plausible, |q_nb| = 1 (± QNORM_TOL), every σ finite and ≥ 0.

    A few float comparisons (NaN fails each of them)."""
    try:
        q0, q1, q2, q3 = st.q_nb.tolist()
        v0, v1, v2 = st.vel_ned.tolist()
        p0, p1, p2 = st.std_pos.tolist()
        u0, u1, u2 = st.std_vel.tolist()
        a0, a1, a2 = st.std_att.tolist()
    except (AttributeError, TypeError, ValueError):
        return False
    return _plausible(q0, q1, q2, q3, v0, v1, v2, st.lat, st.lon, st.h, p0, p1, p2, u0, u1, u2, a0, a1, a2)


def _plausible(q0: float, q1: float, q2: float, q3: float, v0: float, v1: float, v2: float, lat: float, lon: float,
               h: float, p0: float, p1: float, p2: float, u0: float, u1: float, u2: float, a0: float, a1: float,
               a2: float) -> bool:  # fmt: skip
    """The core guard's comparisons on one state's numbers (q_nb, v NED m/s, lat/lon rad, h m, then the nine σ of
    position, velocity, attitude), in Python floats: NaN fails each of them."""
    return bool(
        abs(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3 - 1.0) < QNORM_TOL
        and v0 * v0 + v1 * v1 + v2 * v2 < STATE_SPEED_MAX * STATE_SPEED_MAX
        and -1.5707963267948966 <= lat <= 1.5707963267948966
        and -1e3 < lon < 1e3
        and STATE_H_MIN < h < STATE_H_MAX
        and 0.0 <= p0 < _INF and 0.0 <= p1 < _INF and 0.0 <= p2 < _INF
        and 0.0 <= u0 < _INF and 0.0 <= u1 < _INF and 0.0 <= u2 < _INF
        and 0.0 <= a0 < _INF and 0.0 <= a1 < _INF and 0.0 <= a2 < _INF
    )  # fmt: skip


def _guard_now(core: Any) -> bool | None:
    """:func:`state_ok` of ``core.state()`` from a core that checks its own state record (the C core's
    ``state_guard``: the same comparisons, no ``NavState`` built); None when it cannot (the caller checks
    ``core.state()``)."""
    g = getattr(core, "state_guard", None)
    return None if g is None else cast("bool | None", g(QNORM_TOL, STATE_SPEED_MAX, STATE_H_MIN, STATE_H_MAX))


class Pipeline:
    """calibration → FDI → core on every IMU epoch; aiding at its time of validity."""

    def __init__(
        self, cfg: PipelineConfig, observers: Iterable[Observer] = (), nav: NavConfig | None = None,
        initial: StrapdownState | None = None,
    ) -> None:  # fmt: skip
        """``observers``: :class:`Observer` callbacks; ``nav``: a built ``NavConfig`` used instead of ``cfg.nav``
        (an offline replay's); ``initial``: with ``cfg.init = "core"``, the state the core starts from (None: it
        aligns itself from the first IMU sample)."""
        self._nav: NavConfig = nav if nav is not None else cfg.nav
        if nav is None:
            check_core(cfg.core, cfg.nav)
        elif cfg.core not in CORE_KINDS:
            raise ValueError(f"unknown core {cfg.core!r} (choose from {', '.join(CORE_KINDS)})")
        if cfg.init not in ("gnss", "config", "core"):
            raise ValueError(f"core.init = {cfg.init!r}: expected 'gnss', 'config' or 'core'")
        self.observers: list[Observer] = list(observers)
        if not (isinstance(cfg.epoch_wait_periods, int | float) and 0 < cfg.epoch_wait_periods < math.inf):
            raise ValueError(f"core.epoch_wait_periods = {cfg.epoch_wait_periods!r}: must be a number > 0")
        self.cfg = cfg
        self.validator = SampleValidator(limits_of(cfg))  # the one validation boundary (ValueError: bad limit)
        self._val_imu = self.validator.imu
        # IMU clock restarts passed through by a driver (defence in depth; drivers/clock.py re-anchors its own):
        # per imu_id, the offset (s) added to its sensor times since a restart, and the last sample refused
        # for its time (the candidate of a restart, as in SourceClock: a second one consistent with it confirms)
        self._t_off: dict[int, float] = {}
        self._t_cand: dict[int, ImuSample] = {}
        self._last_arrival = 0  # host arrival (ns) of the last IMU epoch run (0: unknown)
        #: the time (s) of the last IMU sample handed to :meth:`imu` if it passed the validation boundary (after a
        #: clock re-anchoring: its new time), None if it was refused: the live loop maps aiding times with it
        self.imu_t: float | None = None
        self._imu_rejects = 0  # IMU samples rejected by the validator
        self._core_faults = 0  # core exceptions / bad states recovered from
        self._fault_open = False  # a core fault is reported and not cleared yet
        self._fault_clear_t = _INF  # sensor time (s) at which it clears
        self.core: RealTimeCore | None = None
        self._resets = 0  # NavState.resets of the cores before this one (each new core counts one)
        self.events: list[FaultEvent] = []
        self.counts: dict[str, int] = {}
        self._held: list[Aid] = []  # aiding samples newer than the IMU time, sorted by t
        self._t_imu = -math.inf
        self._lvl: deque[tuple[np.ndarray, float]] = deque(maxlen=max(1, cfg.level_samples))
        self._lvl_sum = np.zeros(3)
        self._lvl_dt = 0.0
        self._multi = len(cfg.imu_ids) > 1
        self._ids = frozenset(cfg.imu_ids)
        self._n_ids = len(self._ids)
        # epochs waiting for units, by sensor time (µs): (first arrival ns, {imu_id: sample})
        self._pending: dict[int, tuple[int, dict[int, ImuSample]]] = {}
        self._last_key = -(1 << 62)  # sensor time (µs) of the last epoch run
        self._miss: dict[int, int] = {}  # imu_id → consecutive epochs run without it
        self._unit_key: dict[int, int] = {}  # imu_id → newest sensor time (µs) it delivered
        self._calib = _load_calibration(cfg.calibration) if cfg.calibration else None
        self._pair = self._n_ids == 2 and self._calib is None  # imu_pair may run (see pair_ready)
        self._fdi = fdi_monitor(cfg.fdi_config()) if cfg.fdi else None
        # the validator checked the raw sample: only calibration or FDI can make it non-finite again
        self._recheck = self._calib is not None or self._fdi is not None
        self._aid_mon = aiding_monitor(cfg.aiding_config(), self._nav) if cfg.aiding_fdi else None
        self._aid_lost = 0  # skipped IMU epochs seen by the aiding monitor
        self._jobs: deque[Iterator[None]] = deque()  # aiding fusions in progress, one segment per gap
        self._new_jobs: list[Iterator[None]] = []  # handed over in this gap: their first segment is in the next
        self._seg_ok: NavState | None = None  # the last state a segment's core guard passed
        self._gap_free = False  # no aiding segment has run since the last IMU step
        self._step_pending = False  # core.step_end of the last step has not run yet
        # the last state published and the last one the core guard passed (``last_state``, ``_good``): a NavState,
        # or _RUN_LAST, the last state of the C run ``_run_last`` (states, index), built when first read
        self._last: Any = None
        self._good_st: Any = None
        self._run_last: tuple[Any, int] | None = None
        self._run_last_st: NavState | None = None
        if cfg.init == "core":
            self._start(initial)
        elif cfg.init == "config":
            self._start(
                StrapdownState(
                    quat_from_euler(
                        *(math.radians(a) for a in (cfg.init_roll_deg, cfg.init_pitch_deg, cfg.init_yaw_deg))
                    ),
                    np.zeros(3),
                    math.radians(cfg.init_lat_deg),
                    math.radians(cfg.init_lon_deg),
                    cfg.init_h,
                    0.0,
                )
            )

    @property
    def last_state(self) -> NavState | None:
        """The state of the last IMU epoch published (None before the first)."""
        return self._resolved(self._last)

    @last_state.setter
    def last_state(self, st: NavState | None) -> None:
        self._last = st

    @property
    def _good(self) -> NavState | None:
        """The last state that passed the core guard (None: none since the last restart)."""
        return self._resolved(self._good_st)

    @_good.setter
    def _good(self, st: NavState | None) -> None:
        self._good_st = st

    def _resolved(self, st: object) -> NavState | None:
        """``st`` itself, or for ``_RUN_LAST`` the NavState of the last C run's state, built once."""
        if st is not _RUN_LAST:
            return cast("NavState | None", st)
        r = self._run_last
        if r is not None:
            self._run_last = None
            self._run_last_st = r[0][r[1]]
        st = self._run_last_st
        assert st is not None
        return st

    def _count(self, key: str) -> None:
        self.counts[key] = self.counts.get(key, 0) + 1

    def _imu_error(self, t: float, e: Exception) -> None:
        """An exception outside the core on the IMU path (sensor time ``t``, s): counted (``pipeline_error``) and
        handed to :meth:`_core_fault` (the core kept unless its state is bad); the gateway keeps running."""
        self._count("pipeline_error")
        self._core_fault(t, f"pipeline error on an IMU sample: {type(e).__name__}: {e}", "pipeline")

    def _reject(self, why: str) -> None:
        """Count a sample the validation boundary rejected (``reject_<reason>``, once per sample)."""
        self._count("reject_" + why)
        if why.startswith("imu"):
            self._imu_rejects += 1

    def _start(self, initial: StrapdownState | None, nav: NavConfig | None = None) -> None:
        old = self.core
        self._resets += 1 + (getattr(old, "gnss_resets", 0) if old is not None else 0)
        self.core = make_core(self.cfg.core, initial, self._nav if nav is None else nav)

    # -- IMU ------------------------------------------------------------------
    def imu(self, s: ImuSample) -> NavState | None:
        """Consume one IMU sample; returns the new state when an epoch was processed.

        The sample passes the validation boundary first (a rejection is counted as ``reject_<reason>``);
        an exception inside the core is caught and recovered from (:meth:`_core_fault`); any other
        exception is counted (``pipeline_error``) and the sample dropped: this never raises."""
        a = self._admit(s)
        return None if a is None else self._take(a)

    def _admit(self, s: ImuSample) -> ImuSample | None:
        """The validation boundary of :meth:`imu`: the sample (at its re-anchored time after a clock restart), or
        None when refused (counted); sets :attr:`imu_t`."""
        off = self._t_off
        if off and s.imu_id in off:  # this IMU's clock restarted: its times continue the old time base
            s = dataclasses.replace(s, t=s.t + off[s.imu_id])
        why = self._val_imu(s)
        if why is not None:
            r = self._clock_restart(s) if why == "imu_time" else None
            if r is None:
                self.imu_t = None
                self._reject(why)
                return None
            s = r
        self.imu_t = s.t
        return s

    def _take(self, s: ImuSample) -> NavState | None:
        """An admitted sample: calibrated, then grouped into its epoch (or its epoch, one IMU)."""
        try:
            if self._calib is not None:
                s = self._calib.apply(s)
            if not self._multi:
                return self._epoch([s])
            return self._group(s)
        except Exception as e:  # counted; the gateway keeps running
            self._imu_error(s.t, e)
            return None

    def pair_ready(self, a: Sample, b: Sample) -> bool:
        """Whether :meth:`imu_pair` may take ``a`` and ``b`` (no side effect): two IMU samples of one sensor time
        (after the units' clock offsets) from the two units of a two-unit group, e.g. the two frames of one read of
        a serial link; no epoch waiting, none later than the last epoch run, the second unit not gone (missing
        ``GONE_EPOCHS`` epochs), no calibration file, an epoch wait of at least a nanosecond. Then the grouping
        would keep ``a`` waiting for ``b`` (never run it alone), so one call may do both."""
        if not (self._pair and a.kind == "imu" and b.kind == "imu") or self._pending:
            return False
        a = cast(ImuSample, a)
        b = cast(ImuSample, b)
        ia, ib, ids = a.imu_id, b.imu_id, self._ids
        if ia == ib or ia not in ids or ib not in ids or self._miss.get(ib, 0) >= GONE_EPOCHS:
            return False
        ta, tb, off = a.t, b.t, self._t_off
        if off:
            ta, tb = ta + off.get(ia, 0.0), tb + off.get(ib, 0.0)
        if not (-_INF < ta < _INF and -_INF < tb < _INF and 0.0 < a.dt < _INF):  # not validated yet: no arithmetic
            return False
        key = round(ta * 1e6)
        return key == round(tb * 1e6) and key > self._last_key and round(self.cfg.epoch_wait_periods * a.dt * 1e9) > 0

    def imu_pair(self, a: ImuSample, b: ImuSample) -> tuple[float | None, NavState | None]:
        """:meth:`imu` on ``a``, then on ``b``, when :meth:`pair_ready`: the same validation, counts, events and
        states. When both pass the validation boundary at one sensor time, their epoch runs at once (what the
        grouping does: ``a`` opens it and waits, ``b`` completes it); else each as :meth:`imu` takes it. Returns
        (:attr:`imu_t` after ``a``, the state of ``b``): ``a`` gives none either way."""
        a2 = self._admit(a)
        t_a = self.imu_t
        if a2 is None:
            return t_a, self.imu(b)
        b2 = self._admit(b)
        key = round(a2.t * 1e6)
        if b2 is None or round(b2.t * 1e6) != key or key <= self._last_key:  # e.g. a clock re-anchored just now
            self._take(a2)  # opens its epoch, or is late: no state (no epoch was waiting)
            return t_a, None if b2 is None else self._take(b2)
        try:  # one complete epoch, as the grouping runs it (_group, _run_pending)
            miss = self._miss
            if miss:
                miss.pop(a2.imu_id, None)
                miss.pop(b2.imu_id, None)
            uk = self._unit_key
            uk[a2.imu_id] = uk[b2.imu_id] = self._last_key = key
            return t_a, self._epoch([a2, b2] if a2.imu_id < b2.imu_id else [b2, a2])
        except Exception as e:  # counted; the gateway keeps running
            self._imu_error(b2.t, e)
            return t_a, None

    def imu_run(self, samples: list[ImuSample], screened: bool = False,
                arrays: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
                ordered: bool = False) -> None:  # fmt: skip
        """:meth:`imu` on each of ``samples`` in order, with nothing handed over in between (an offline replay's
        IMU samples up to the next aiding measurement). The same states, counts, events and observer calls; on
        the C core, once it navigates, the samples that pass the validation boundary go into the core in one
        call (``CNavCore.run_states``; before it navigates, the alignment's levelling and heading phases too)
        instead of one call each.

        ``screened``: the samples passed a validator with this pipeline's limits already (an offline replay's
        screen, ``ins_hil.datasets.run.screen``): once this pipeline's validator knows the IMU's period, a run of
        them in time order is taken without a second check (``SampleValidator.imu_screened``: each sample is
        checked once); every other sample is checked here as without it. ``arrays``: the (n, 6) increments, times
        and steps of ``samples`` as ``CNavCore.run_states`` takes them, when the caller has them (an offline replay:
        slices of the whole log's, not built again here). ``ordered`` (with ``screened``): the samples are of one
        IMU and their times increase (a screened log of one IMU): only the first one's time is compared here."""
        k, n = 0, len(samples)
        vd = self.validator
        while k < n:
            if not self._can_run():
                self.imu(samples[k])
                k += 1
                continue
            j = k
            val, t_prev = self._val_imu, self._t_imu
            if screened:  # checked by the screen: only their time order here (the run a clock restart would end)
                iid = samples[k].imu_id
                tp = max(t_prev, vd.imu_time(iid))
                if ordered:
                    if samples[k].t > tp:
                        j, tp = n, samples[n - 1].t
                else:
                    while j < n and samples[j].t > tp and samples[j].imu_id == iid:
                        tp = samples[j].t
                        j += 1
                if j > k and not vd.imu_screened(iid, tp):
                    j = k  # the validator still learns the period: checked below
            if j == k:
                while j < n:  # the run that passes the validation boundary as it is (no clock re-anchoring)
                    s = samples[j]
                    if s.t <= t_prev or val(s) is not None:
                        break
                    t_prev = s.t
                    j += 1
            if j == k:  # refused (or re-anchored): the per-sample path says why
                self.imu(samples[k])
                k += 1
                continue
            try:
                run = samples[k:j]
                off = k
                while run:  # validated (the validator has seen them): the core may take them in parts
                    m = self._epochs_c(run, None if arrays is None else tuple(a[off : off + len(run)] for a in arrays))
                    run = run[m:]
                    off += m
                    if run and not self._can_run():
                        self._epochs_validated(run)
                        break
            except Exception as e:  # counted; the gateway keeps running (as imu())
                self._imu_error(samples[j - 1].t, e)
            k = j

    def _can_run(self) -> bool:
        """The batched C path of :meth:`imu_run` applies: one IMU, no calibration, FDI, clock offset, held
        aiding or queued work, no open core fault, and a C core that navigates (``CNavCore.can_run``)."""
        core = self.core
        return (core is not None and not self._multi and self._calib is None and self._fdi is None
                and not self._t_off and not self._held and not self._jobs and not self._new_jobs
                and not self._fault_open and not self._step_pending and hasattr(core, "run_states")
                and cast(Any, core).can_run())  # fmt: skip

    def _epochs_c(self, run: list[ImuSample], arrays: tuple[np.ndarray, ...] | None = None) -> int:
        """The epochs of ``run`` (validated, in time order) through the C core in one call: each state checked
        by the core guard, published to the observers; at the first bad state the core fault as in
        :meth:`_epoch` and the rest of the run sample by sample. Returns the samples taken: all, or those up to
        the one at which the core's alignment started navigating (``CNavCore.run_states``: the states before it
        are published while the core aligns, as one sample at a time)."""
        core = cast(Any, self.core)
        n = len(run)
        if arrays is not None:  # (``run``'s, from the caller)
            inc, t, dt = arrays
        else:
            inc = np.empty((n, 6))
            t = np.empty(n)
            dt = np.empty(n)
            for i, s in enumerate(run):
                inc[i, :3] = s.dtheta
                inc[i, 3:] = s.dvel
                t[i] = s.t
                dt[i] = s.dt
        self.imu_t = run[-1].t
        pre = core.drain_events()  # what the core raised since the last epoch (an update's gate events)
        states = core.run_states(inc, t, dt)
        if len(states) < n:
            n = len(states)
            run = run[:n]
            self.imu_t = run[-1].t
        ev = core.drain_events()  # the lost-data events of the run, one per row of core.run_gap_rows
        by_row: dict[int, list[FaultEvent]] = {}
        for r, e in zip(core.run_gap_rows, ev, strict=True):
            by_row.setdefault(r, []).append(e)
        resets = self._resets + getattr(core, "gnss_resets", 0)
        obs = self.observers
        # the core guard of every state: the first that fails it (n: none)
        bad = core.first_bad(core.run_out, QNORM_TOL, STATE_SPEED_MAX, STATE_H_MIN, STATE_H_MAX)
        if hasattr(states, "rows") and all(type(o).epochs is not Observer.epochs for o in obs):
            self._epochs_rows(run, states, bad, pre, by_row, resets)
            return n
        for i, st in enumerate(states):
            s = run[i]
            self._t_imu = s.t
            self._last_arrival = s.t_arrival_ns
            if i == bad:  # as _epoch: the core restarts (its events since the last good state dropped)
                self._core_fault(s.t, "core step: non-finite or implausible state", "state")
                self._epochs_validated(run[i + 1 :])
                return n
            st.resets = resets
            self._good = st
            self._gap_free = True
            if i == 0 and pre:
                self.events.extend(pre)
            if i in by_row:
                self.events.extend(by_row[i])
            self.last_state = st
            try:
                for o in obs:
                    o.epoch(self, st)
            except Exception as e:  # counted, as imu() does for an epoch
                self._imu_error(s.t, e)
        return n

    def _epochs_rows(self, run: list[ImuSample], states: Any, bad: int, pre: list[FaultEvent],
                     by_row: dict[int, list[FaultEvent]], resets: int) -> None:  # fmt: skip
        """:meth:`_epochs_c`'s publication when every observer takes a run at once (:meth:`Observer.epochs`) and
        the core gives its states as rows (``ins_hil.cref.RunStates``): the same counts, events, states and
        observer calls (each observer's in the order of the states), a ``NavState`` built only for the last
        state (``last_state``) and for what an observer asks for. ``bad``: the first state the core guard
        failed (``len(run)``: none)."""
        n = len(run)
        states.resets = resets
        if bad:
            if pre:
                self.events.extend(pre)
            for row in sorted(by_row):
                if row < bad:
                    self.events.extend(by_row[row])
            # the run's last good state: built only when read (``last_state``, ``_good``)
            self._run_last = (states, bad - 1)
            self._good_st = self._last = _RUN_LAST
            self._gap_free = True
            part = states if bad == n else states.head(bad)
            for o in self.observers:
                try:
                    o.epochs(self, part)
                except Exception as e:  # counted, as imu() does for an epoch
                    self._imu_error(run[bad - 1].t, e)
        s = run[min(bad, n - 1)]
        self._t_imu = s.t
        self._last_arrival = s.t_arrival_ns
        if bad < n:  # as _epoch: the core restarts (its events since the last good state dropped)
            self._core_fault(s.t, "core step: non-finite or implausible state", "state")
            self._epochs_validated(run[bad + 1 :])

    def _epochs_validated(self, rest: list[ImuSample]) -> None:
        """Samples of a C run, validated already, each straight to the epoch as :meth:`imu` would: the rest of the
        run after a state the core guard failed (the core restarts, its events since the last good state dropped),
        or the samples the core did not take in one call that may no longer run on C (:meth:`imu_run`)."""
        for r in rest:
            self.imu_t = r.t
            try:
                self._epoch([r])
            except Exception as e:
                self._imu_error(r.t, e)

    def baro_runs(self, imu: list[ImuSample], arrays: tuple[np.ndarray, np.ndarray, np.ndarray], k0: int,
                  end: np.ndarray, ab: np.ndarray, baro: Sequence[Any], bt: np.ndarray,
                  alt: np.ndarray) -> tuple[int, int]:  # fmt: skip
        """An offline replay's :meth:`imu_run` (``screened``) and :meth:`aid` + :meth:`flush` of baro samples
        alternately on the C core in one C call (``CNavCore.run_baro``): group g is the IMU samples
        ``imu[end[g - 1]:end[g]]`` (``end[-1]`` = ``k0``; ``arrays``: the whole log's (n, 6) increments, times and
        steps, as ``CNavCore.run_states`` takes them), then the baro samples ``baro[ab[g]:ab[g + 1]]`` (times ``bt``,
        finite altitudes ``alt``), none with IMU data lost before its samples. The same states, counts, events,
        drift-monitor records and observer calls as those calls one by one, under the conditions this checks (one
        IMU, screened samples, a navigating C core, nothing queued, observers whose fusion hooks ignore baro
        samples, a drift monitor that does not exclude the baro). Returns the index of the next IMU sample and that of
        the next baro sample to hand over (``k0``, ``ab[0]``: nothing ran, the caller goes on one call at a time).
        When a state fails the core guard or an update's gate is not a plain acceptance, the call stops there: the
        baro samples of that group not taken yet are the caller's (their IMU samples have run; after a core fault
        in an update they are dropped with it, as :meth:`flush` drops them)."""
        core = cast(Any, self.core)
        mon = self._aid_mon
        j0 = int(ab[0]) if len(ab) else 0
        if not (len(end) and self._can_run() and hasattr(core, "run_baro") and not core.has_events()):
            return k0, j0
        if mon is not None:
            c = self.counts
            lost = c.get("imu_nonfinite", 0) + c.get("imu_epoch_incomplete", 0) + c.get("imu_time_backwards", 0)
            if (
                lost + self._imu_rejects + self._core_faults != self._aid_lost
                or (mon.cfg.exclude and mon.baro.faulted)
                or mon.events
            ):  # (a baro sample's flush drains its events)
                return k0, j0
        for o in self.observers:  # each takes runs of states; its fusion hooks are none or pass baro samples by
            oc = type(o)
            none = oc.before_fuse is Observer.before_fuse and oc.segment is Observer.segment and (
                oc.after_fuse is Observer.after_fuse)  # fmt: skip
            if oc.epochs is Observer.epochs or not (none or "baro" not in getattr(o, "fuse_kinds", ("baro",))):
                return k0, j0
        iid = imu[k0].imu_id
        if core.lost_before(imu[k0].t, imu[k0].dt) or not (
            self._t_imu < imu[k0].t and self.validator.imu_screened(iid, imu[k0].t)
        ):
            return k0, j0
        inc, t, dt = arrays
        r = core.run_baro(inc, t, dt, k0, end, ab, bt, alt, (QNORM_TOL, STATE_SPEED_MAX, STATE_H_MIN, STATE_H_MAX))
        states, g, u = r.states, r.groups, r.updates
        k1 = int(end[g - 1])
        # the runs whose states passed the guard end at kg (imu_run's _epochs_rows, in one piece)
        kg = (int(end[g - 2]) if g > 1 else k0) if r.why == 1 else k1
        resets = self._resets + getattr(core, "gnss_resets", 0)
        if kg > k0:
            self._epochs_rows(imu[k0:kg], states if kg == k1 else states.head(kg - k0), kg - k0, [], {}, resets)
        if r.why == 1:  # the last group's run: a state failed the guard (its baro samples left to the caller)
            run = imu[kg:k1]
            self.imu_t = run[-1].t
            part = states.tail(kg - k0)
            bad = core.first_bad(part.rows, QNORM_TOL, STATE_SPEED_MAX, STATE_H_MIN, STATE_H_MAX)
            self._epochs_rows(run, part, bad, [], {}, resets)
        self.validator.imu_screened(iid, imu[k1 - 1].t)
        self.imu_t = imu[k1 - 1].t
        if u:
            a0 = j0
            if mon is not None:
                for i in range(u):
                    mon.check_baro(baro[a0 + i], r.t_pre[i], r.aligned[i])
            self._gap_free = False
            key = "fused_" + type(baro[a0]).__name__
            self.counts[key] = self.counts.get(key, 0) + u
            if r.why == 3:  # as _segment: the core fault, the group's later samples dropped with it (as flush)
                rest = baro[a0 + u : int(ab[g])]
                self._jobs.extend(self._fuse(m) for m in rest)
                self._core_fault(self._t_imu, "aiding update: non-finite or implausible state", "state")
                self.flush()
                return k1, int(ab[g])
        return k1, j0 + u

    def _clock_restart(self, s: ImuSample) -> ImuSample | None:
        """A sample refused because its time did not increase: the IMU's clock may have restarted (a driver
        passed the restarted times through). The rule of :class:`ins_hil.drivers.clock.SourceClock`: the
        sample is dropped and kept as the candidate; when the next sample refused for its time follows the
        candidate by one interval (± max(0.1 s, 10 intervals)), the clock really restarted and is
        re-anchored there: this IMU's times continue from the last accepted one plus the host time elapsed
        (its ``t_arrival_ns``; without it, the intervals the sensor counted), never backwards, and the
        sample is taken (``imu_clock_reanchor``; the candidate counts once as ``reject_imu_time``). A lone
        sample with a bad time costs that sample only; a restart costs one sample, never all that follow."""
        iid = s.imu_id
        cand = self._t_cand.get(iid)
        self._t_cand[iid] = s
        if cand is None:
            return None
        el = s.t - cand.t
        ok = 0.0 < el and abs(el - s.dt) <= max(0.1, 10.0 * s.dt)
        if ok and s.t_arrival_ns and cand.t_arrival_ns:  # no further than the host saw time pass
            ok = el <= (s.t_arrival_ns - cand.t_arrival_ns) * 1e-9 + 0.1
        if not ok:
            return None
        last = self.validator.imu_time(iid)
        if not -_INF < last < _INF:
            return None
        own = el + cand.dt  # the intervals the sensor counted since the last accepted sample, at least
        hs = (s.t_arrival_ns - self._last_arrival) * 1e-9 if s.t_arrival_ns and self._last_arrival else -1.0
        t = last + (hs if hs > own else own)
        self._t_off[iid] = self._t_off.get(iid, 0.0) + (t - s.t)
        del self._t_cand[iid]
        r = dataclasses.replace(s, t=t)
        if self._val_imu(r) is not None:  # e.g. its dt out of band: refused after all, the offset kept
            return None
        self._count("imu_clock_reanchor")
        return r

    def _group(self, s: ImuSample) -> NavState | None:
        """Redundant IMUs: group samples into epochs by sensor time.

        An epoch is complete when every configured imu_id has delivered its sample for that sensor
        time. Each link delivers in order, so once a unit has delivered a later sample, its sample
        for an older pending epoch is lost: that epoch runs (oldest first) as soon as every unit
        has delivered it or a later one. An epoch also runs incomplete once a sample
        arrives ``epoch_wait_periods`` IMU periods (arrival time, ``t_arrival_ns``: recorded, so
        replay groups the same way) after its first sample; samples without an arrival stamp use
        the same bound in sensor time. A sample for an epoch that already ran is dropped
        (``imu_epoch_late_sample``). A unit missing from ``GONE_EPOCHS`` epochs in a row (dead
        link) is not waited for until it delivers again, so the others do not each wait the bound."""
        if s.imu_id not in self._ids:
            self._count("imu_unknown_id")
            return None
        if self._miss:
            self._miss.pop(s.imu_id, None)  # the unit delivers (again): wait for it
        key = round(s.t * 1e6)
        if key <= self._last_key:
            self._count("imu_epoch_late_sample")
            return None
        pending = self._pending
        entry = pending.get(key)
        opened = entry is None
        if entry is None:
            entry = pending[key] = (s.t_arrival_ns, {})
        pend = entry[1]
        if s.imu_id in pend:
            self._count("imu_duplicate")
            return None
        pend[s.imu_id] = s
        uk = self._unit_key
        if key > uk.get(s.imu_id, -(1 << 62)):
            uk[s.imu_id] = key
        out: NavState | None = None
        wait = self.cfg.epoch_wait_periods * s.dt
        miss, ids = self._miss, self._ids
        if len(pending) == 1:  # the common case, the one epoch waiting: what the general rule below does, directly
            if len(pend) == self._n_ids:  # complete
                return self._run_pending(key)
            if opened and s.t_arrival_ns and round(wait * 1e9) > 0:
                # just opened by this sample: it waits for the others unless each has passed it or is gone
                for i in ids:
                    if not (i in pend or uk.get(i, key) > key or miss.get(i, 0) >= GONE_EPOCHS):
                        return None
        # run, oldest first, every epoch that can no longer gain a sample: each unit has delivered
        # it, or a later one (links deliver in order: its sample is lost), or is gone
        for k in sorted(pending):
            have = pending[k][1]
            if len(have) == self._n_ids or all(
                i in have or uk.get(i, k) > k or miss.get(i, 0) >= GONE_EPOCHS for i in ids
            ):
                out = self._run_pending(k) or out
            else:
                break
        if not pending:
            return out
        now = s.t_arrival_ns
        if now:
            limit = now - round(wait * 1e9)
            due = max((k for k, (a, _) in pending.items() if a <= limit), default=None)
        else:
            due = max((k for k in pending if k < key - wait * 1e6), default=None)
        if due is not None:
            for k in sorted(pending):
                if k > due:
                    break
                out = self._run_pending(k) or out
        if len(pending) > 64:  # e.g. arrival stamps that never advance: do not grow without bound
            out = self._run_pending(min(pending)) or out
        return out

    def _run_pending(self, key: int) -> NavState | None:
        pend = self._pending.pop(key)[1]
        self._last_key = key
        if len(pend) < self._n_ids:
            self._count("imu_epoch_incomplete")
            miss = self._miss
            for i in self._ids:
                if i not in pend:
                    miss[i] = miss.get(i, 0) + 1
        return self._epoch([pend[i] for i in sorted(pend)])

    def _epoch(self, samples: list[ImuSample]) -> NavState | None:
        if self._step_pending:
            self._finish_step()
        if self._jobs:
            if self._gap_free:  # the loop had no slack in this gap: the segment runs now
                self._segment()
            while len(self._jobs) > MAX_AID_JOBS:
                self._segment()
        if self._fdi is not None:
            s, ev = self._fdi.process(samples)
            if ev:
                self.events.extend(ev)
        else:
            s = samples[0]
        if self._recheck:
            fin = math.isfinite
            a, v = s.dtheta, s.dvel
            if not (fin(s.dt) and fin(a[0]) and fin(a[1]) and fin(a[2]) and fin(v[0]) and fin(v[1]) and fin(v[2])):
                # e.g. FDI with too few healthy units left after lost frames: never feed NaN to the core
                self._count("imu_nonfinite")
                return None
        if s.t <= self._t_imu:
            self._count("imu_time_backwards")
            return None
        self._t_imu = s.t
        self._last_arrival = s.t_arrival_ns
        core = self.core
        if core is None:
            self._level_add(s)
            self._count("imu_before_init")
            return None
        try:
            st = core.step_begin(s)  # mechanization only: published before the time update (step_end)
            self._step_pending = True
        except Exception as e:  # e.g. a singular update: recovered, never fatal
            self._core_fault(s.t, f"core step: {type(e).__name__}: {e}")
            return None
        if not state_ok(st):
            self._core_fault(s.t, "core step: non-finite or implausible state", "state")
            return None
        st.resets = self._resets + getattr(core, "gnss_resets", 0)
        self._good = st
        if self._fault_open and s.t >= self._fault_clear_t:
            self._fault_open = False
            self.events.append(FaultEvent(s.t, "core", FaultMode.JUMP, math.nan, True, True, "core recovered"))
        self._gap_free = True
        if self._new_jobs:
            self._jobs.extend(self._new_jobs)
            self._new_jobs.clear()
        ev2 = core.drain_events()
        if ev2:
            self.events.extend(ev2)
        if self._held:
            while self._held and self._held[0].t <= s.t:
                self._jobs.append(self._fuse(self._held.pop(0)))
        self.last_state = st
        if self.observers:
            for o in self.observers:
                o.epoch(self, st)
        return st

    def work(self) -> bool:
        """Run one segment of queued aiding work in the current gap between IMU epochs (at most one
        per gap; the live loop calls this when it has published a state and has nothing waiting).
        Returns True when a segment ran."""
        if self._step_pending:
            self._finish_step()
        if not (self._gap_free and self._jobs):
            return False
        self._segment()
        return True

    def has_work(self) -> bool:
        """Whether :meth:`work` has something to do now: the rest of the last IMU step, or an aiding segment
        in this gap."""
        return self._step_pending or (self._gap_free and bool(self._jobs))

    def pending_work(self) -> int:
        """Aiding measurements handed over but not completely fused yet."""
        return len(self._jobs) + len(self._new_jobs)

    def flush(self) -> None:
        """Finish every queued aiding fusion now (end of a run or of a replay)."""
        if self._step_pending:
            self._finish_step()
        self._jobs.extend(self._new_jobs)
        self._new_jobs.clear()
        while self._jobs:
            self._segment()
        core = self.core
        # the last time update, unchecked until now (unless the state is the one the last segment checked: a core
        # that hands out the same NavState while it does not change; the C core's guard in one C call)
        if core is not None:
            ok = _guard_now(core)
            if ok is None:
                ok = (st := core.state()) is self._seg_ok or state_ok(st)
            if not ok:
                self._core_fault(self._t_imu, "core time update: non-finite or implausible state", "state")

    def _finish_step(self) -> None:
        """The rest of the last IMU step (the filter time update, ``core.step_end``): runs before
        anything else touches the core, after the state has been published."""
        self._step_pending = False
        core = self.core
        assert core is not None
        try:
            core.step_end()
        except Exception as e:  # the next state is guarded; the core is restarted now
            self._core_fault(self._t_imu, f"core time update: {type(e).__name__}: {e}")
            return
        ev = core.drain_events()
        if ev:
            self.events.extend(ev)

    def _segment(self) -> None:
        if self._step_pending:
            self._finish_step()
        self._gap_free = False
        job = self._jobs[0]
        try:
            done = next(job, _DONE) is _DONE
        except Exception as e:  # e.g. LinAlgError in an update: recovered, never fatal
            self._core_fault(self._t_imu, f"aiding update: {type(e).__name__}: {e}")
            return
        if done:
            self._jobs.popleft()
        core = self.core
        if core is not None:
            ok = _guard_now(core)  # the C core: no NavState built
            if ok is None:
                st = core.state()
                ok = state_ok(st)
                if ok:
                    self._seg_ok = st
            if not ok:
                self._core_fault(self._t_imu, "aiding update: non-finite or implausible state", "state")

    def _level_add(self, s: ImuSample) -> None:
        if len(self._lvl) == self._lvl.maxlen:
            dv, dt = self._lvl[0]
            self._lvl_sum -= dv
            self._lvl_dt -= dt
        self._lvl.append((s.dvel, s.dt))
        self._lvl_sum += s.dvel
        self._lvl_dt += s.dt

    # -- aiding -------------------------------------------------------------------
    def aid(self, m: Aid, screened: bool = False) -> None:
        """Consume one aiding measurement: fused now if its time of validity has passed, else held.

        It passes the validation boundary first (``reject_<reason>``); never raises. ``screened``: ``m`` passed
        a validator with this pipeline's limits already (an offline replay's screen,
        ``ins_hil.datasets.run.screen``) and is not checked a second time."""
        try:
            why = None if screened else self.validator.check(m)
        except Exception:  # not a sample at all
            why = "aid_malformed"
        if why is not None:
            self._reject(why)
            return
        if self.core is None:
            if self._lvl_dt > 0 and aids.source_of(m).starts_core(m):
                try:
                    self._init_from_gnss(cast(GnssFix, m))
                except Exception as e:
                    self.core = None
                    self._count("pipeline_error")
                    self._core_fault(m.t, f"initialisation: {type(e).__name__}: {e}", "pipeline")
            else:
                self._count("aid_before_init")
            return
        if m.t <= self._t_imu:
            self._new_jobs.append(self._fuse(m))
            return
        i = len(self._held)
        while i > 0 and self._held[i - 1].t > m.t:
            i -= 1
        self._held.insert(i, m)
        if len(self._held) > 256:  # IMU stopped: do not grow without bound
            self._held.pop(0)
            self._count("aid_held_overflow")

    def _fuse(self, m: Aid) -> Iterator[None]:
        """The fusion of one measurement as a job of segments (see the module doc): the drift
        monitor's check, then the core's update(s) (``core.fuse_steps``)."""
        core = self.core
        assert core is not None
        obs = self.observers
        for o in obs:
            o.before_fuse(self, m)
        mon = self._aid_mon
        src = aids.source_of(m)
        if mon is not None and src.drift_monitor:
            # IMU epochs skipped since the last check: the INS is not evidence against the GNSS for a while
            c = self.counts
            lost = c.get("imu_nonfinite", 0) + c.get("imu_epoch_incomplete", 0) + c.get("imu_time_backwards", 0)
            lost += self._imu_rejects + self._core_faults
            if lost != self._aid_lost:
                self._aid_lost = lost
                mon.ins_disturbed(m.t)
            # the drift monitor sees the state before this measurement is fused (GNSS/baro rate only)
            excluded = mon.check(m, core.state())
            if mon.events:
                self.events.extend(mon.drain_events())
            if excluded:
                self._count("excluded_" + type(m).__name__)
                for o in obs:
                    o.after_fuse(self, m, False)
                return
            if src.split_check:
                yield  # the check of a fix (O(window) work) and its update in separate gaps
        if not obs:
            yield from core.fuse_steps(m)
        else:  # each segment of the core's update bracketed by the observers (no IMU step inside one)
            steps = core.fuse_steps(m)
            while True:
                for o in obs:
                    o.segment(self, m, True)
                more = next(steps, _DONE) is not _DONE
                for o in obs:
                    o.segment(self, m, False)
                if not more:
                    break
                yield
        self._count("fused_" + type(m).__name__)
        for o in obs:
            o.after_fuse(self, m, True)

    def _init_from_gnss(self, g: GnssFix) -> None:
        from ins_hil.core import initial_state

        f_b = self._lvl_sum / self._lvl_dt
        yaw = math.radians(self.cfg.init_yaw_deg)
        self._start(initial_state(f_b, g, self._t_imu, yaw, self.cfg.nav))
        self._count("init_gnss")
        if self._fault_open:  # re-aligned after a core fault: cleared after FAULT_CLEAR_S of good states
            self._fault_clear_t = self._t_imu + FAULT_CLEAR_S

    # -- the core guard -------------------------------------------------------------------
    def _core_fault(self, t: float, what: str, kind: str = "exception") -> None:
        """An exception inside the core (``kind="exception"``) or a state that failed :func:`state_ok`
        (``"state"``): count it (``core_exception`` / ``core_bad_state``), report a ``FaultEvent``
        (sensor ``core``) when no core fault is open, drop the aiding work bound to the failed core, and
        recover: restart the core from the last good state (its position, velocity and attitude, with
        the initial covariance) or, with no usable good state or a second fault before the first
        cleared, re-align from the next 3-D GNSS fix (levelling on the IMU samples from now on).
        ``"pipeline"``: an error outside the core (counted ``pipeline_error`` by the caller): the core
        is kept unless its state is bad."""
        if kind == "pipeline":
            core = self.core
            try:
                if core is None or state_ok(core.state()):
                    return
            except Exception:
                pass
            kind = "state"
        self._count("core_exception" if kind == "exception" else "core_bad_state")
        self._core_faults += 1
        if not self._fault_open:
            self.events.append(FaultEvent(t, "core", FaultMode.JUMP, math.nan, True, False, what))
        dropped = len(self._jobs) + len(self._new_jobs)
        if dropped:
            self.counts["aid_dropped_core_fault"] = self.counts.get("aid_dropped_core_fault", 0) + dropped
        self._jobs.clear()
        self._new_jobs.clear()
        self._step_pending = False
        if self._aid_mon is not None:
            self._aid_mon.ins_disturbed(t)
        g = self._good
        nav = self._nav
        restart = g is not None and not self._fault_open and (g.aligned or nav.alignment.mode == "given")
        self._fault_open = True
        self._fault_clear_t = t + FAULT_CLEAR_S
        if restart:
            assert g is not None
            q = np.array(g.q_nb, dtype=np.float64)
            given = dataclasses.replace(nav, alignment=dataclasses.replace(nav.alignment, mode="given"))
            try:
                self._start(StrapdownState(q / math.sqrt(float(q @ q)), np.array(g.vel_ned, dtype=np.float64),
                                           g.lat, g.lon, g.h, g.t), given)  # fmt: skip
                self._count("core_restart")
                return
            except Exception:  # fall back to a re-alignment
                pass
        self._resets += getattr(self.core, "gnss_resets", 0) if self.core is not None else 0
        self.core = None
        self._good = None
        self._lvl.clear()
        self._lvl_sum = np.zeros(3)
        self._lvl_dt = 0.0
        self._count("core_realign")

    def drain_events(self) -> list[FaultEvent]:
        ev, self.events = self.events, []
        return ev


def _load_calibration(path: str) -> Any:
    """A calibration file (``ins_hil.nav.calibration``): an object with ``apply(imu) -> ImuSample``."""
    from ins_hil.calibration.files import load_calibration

    return load_calibration(path)


def fdi_config(options: dict[str, Any]) -> Any:
    """``FdiConfig`` from the ``[fdi.options]`` table: ``geometry`` (a name of ``ins_hil.fdi.geometry.CONFIGS``)
    plus ``FdiConfig`` fields (dt, gyro_noise, accel_noise, ...), built by :func:`ins_hil.settings.build`."""
    from ins_hil.fdi.geometry import by_name
    from ins_hil.fdi.monitor import FdiConfig

    opts = dict(options)
    name = opts.pop("geometry", "triple_imu")
    try:
        geo = by_name(str(name))
    except (KeyError, ValueError) as e:
        raise ConfigError(f"fdi.options.geometry = {name!r}: {e}") from None
    return build(FdiConfig, opts, "fdi.options", geometry=geo)


def fdi_monitor(cfg: Any) -> Any:
    """The IMU ``FdiMonitor`` of a built ``FdiConfig`` (:meth:`PipelineConfig.fdi_config`)."""
    from ins_hil.fdi.monitor import FdiMonitor

    return FdiMonitor(cfg)


def aiding_config(options: dict[str, Any], nav: NavConfig | None = None) -> Any:
    """``AidingConfig`` from the ``[fdi.aiding]`` table (built by :func:`ins_hil.settings.build`).

    Unless the table sets ``late_fix_as_current``, it follows ``nav``'s ``[core.nav.delay] compensation``: without
    it either core (Python or C) fuses a late GNSS fix as current (shifted by v·Δt), so the monitor compares it
    with the current state; with it (the default) at the fix's time of validity (both roll back)."""
    from ins_hil.fdi.aiding import AidingConfig

    opts = dict(options)
    if "late_fix_as_current" not in opts:
        opts["late_fix_as_current"] = not (nav if nav is not None else NavConfig()).delay.compensation
    return build(AidingConfig, opts, "fdi.aiding")


def aiding_monitor(cfg: Any, nav: NavConfig | None = None) -> Any:
    """The GNSS/baro drift monitor (``AidingMonitor``) of a built ``AidingConfig``
    (:meth:`PipelineConfig.aiding_config`), comparing fixes as the core under ``nav`` weighs them (its GNSS
    lever arm, σ floors, σ scale and velocity delay)."""
    from ins_hil.fdi.aiding import AidingMonitor

    g = (nav if nav is not None else NavConfig()).gnss
    return AidingMonitor(cfg, g.lever_arm_b, g.min_std, g.std_scale, g.vel_delay)
