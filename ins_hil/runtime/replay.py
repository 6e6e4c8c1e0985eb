"""Exact offline replay of a recorder log (``.ihlog``) through the same pipeline.

The recorder writes every input in the order the live loop handed it to the
pipeline, as float64, and stores the pipeline config in the log header; the
replay builds the same :class:`~ins_hil.runtime.pipeline.Pipeline` and calls
it in the same order, so it reproduces the online fused states bit for bit
(the live loop only adds timing and I/O around these calls).

A log of a simulated run (``[sim] enabled`` in the header's config) is also scored against the
simulator's truth, regenerated from the header's ``[sim]`` table (the simulator is seeded and
deterministic) by the caller, which passes it in (``ins_hil.evaluation.sim_flight``: the runtime
never imports the simulator): :func:`check_imu`, :func:`errors`, :func:`score` (position bias along
track, horizontal RMS, NEES of position and velocity from the published per-axis σ, the fraction of
epochs with the horizontal error inside 3σ; σ_h = hypot(σ_N, σ_E), the ``pos_horiz_accuracy`` of
ESTIMATOR_STATUS).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast, overload

import numpy as np

from ins_hil.core_parts.config import nest
from ins_hil.runtime.pipeline import Pipeline, PipelineConfig
from ins_hil.runtime.recorder import LogReader, RecordError, parts_of, read_header, read_records
from ins_hil.types import FaultEvent, ImuSample, NavState, SimConfig
from ins_hil.validation import Limits

#: regenerates the simulator's truth of a ``[sim]`` table for ``duration`` s (``sim_flight.sim_truth``)
TruthSource = Callable[[SimConfig, float], "SimTruth"]


@dataclass
class ReplayResult:
    """States produced by the replay (one per processed IMU epoch) and the fault events."""

    header: dict[str, Any]
    states: list[NavState] = field(default_factory=list)
    events: list[FaultEvent] = field(default_factory=list)
    records: int = 0
    counts: dict[str, int] = field(default_factory=dict)
    parts: int = 1
    read_error: str = ""  # the reader's one line when the log is damaged, cut or has a missing part
    read_notes: list[str] = field(default_factory=list)  # not damage: a kill's cut tail, parts deleted by retention

    def arrays(self) -> dict[str, np.ndarray]:
        """t (N,), q_nb (N,4), vel_ned (N,3), lat/lon/h (N,) of the states."""
        st = self.states
        return {
            "t": np.array([s.t for s in st]),
            "q_nb": np.array([s.q_nb for s in st]).reshape(-1, 4),
            "vel_ned": np.array([s.vel_ned for s in st]).reshape(-1, 3),
            "lat": np.array([s.lat for s in st]),
            "lon": np.array([s.lon for s in st]),
            "h": np.array([s.h for s in st]),
        }


def pipeline_config_from_header(header: dict[str, Any], core: str | None = None) -> PipelineConfig:
    """The PipelineConfig stored in a log header (``core`` overrides the core kind)."""
    d = dict(header.get("pipeline", {}))
    names = {f.name for f in dataclasses.fields(PipelineConfig) if f.init} - {"limits"}
    lim = {f.name for f in dataclasses.fields(Limits)}
    # the validation limits: a table, or (logs written before PipelineConfig.limits) flat pipeline keys
    table = d.get("limits")
    limits = {k: v for k, v in {**d, **(table if isinstance(table, dict) else {})}.items() if k in lim}
    nav = dict(d.get("nav") or {})
    held = nav.pop("sources", None)  # a header written with dataclasses.asdict (before PipelineConfig.to_dict)
    if isinstance(held, dict):
        nav.update(held)  # its aid sections back at [core.nav.<aid>]
    d["nav"] = nest(nav)  # a recording made before the [core.nav] sections: its flat keys moved
    cfg = PipelineConfig(**{k: v for k, v in d.items() if k in names}, limits=Limits(**limits))
    if core is not None:
        cfg.core = core
    return cfg


@overload
def replay_log(
    path: str | Path,
    core: str | None = None,
    on_state: Callable[[NavState], None] | None = None,
    keep_states: bool = True,
) -> ReplayResult: ...


@overload
def replay_log(path: str | Path, core: argparse.Namespace) -> int: ...


def replay_log(
    path: str | Path,
    core: str | argparse.Namespace | None = None,
    on_state: Callable[[NavState], None] | None = None,
    keep_states: bool = True,
) -> ReplayResult | int:
    """Run the log's inputs through a fresh pipeline; returns every state (``keep_states``) and event.

    ``core`` overrides the recorded core kind (``python``/``c``) to compare cores on
    the same inputs; with the recorded kind the states equal the online ones exactly.
    Called as ``replay_log(path, args)`` with the ``ins-hil replay`` arguments, it prints a
    summary and returns the exit status (the command's ``.ihlog`` dispatch).
    """
    if isinstance(core, argparse.Namespace):
        return replay_cli(path, core)
    header = read_header(path)
    pipe = Pipeline(pipeline_config_from_header(header, core))
    res = ReplayResult(header=header, parts=len(parts_of(path)))
    reader = LogReader(path)  # stops at the first damaged record: the intact prefix is replayed
    for rec in reader:
        res.records += 1
        if rec.kind == "imu":
            st = pipe.imu(cast(ImuSample, rec))
            if st is not None:
                if keep_states:
                    res.states.append(st)
                if on_state is not None:
                    on_state(st)
        else:
            pipe.aid(rec)
        if pipe.events:
            res.events.extend(pipe.drain_events())
    pipe.flush()  # as the live loop does at its end
    if pipe.events:
        res.events.extend(pipe.drain_events())
    res.counts = dict(pipe.counts)
    res.read_error = reader.message()
    res.read_notes = list(reader.stats.notes)
    return res


def replay_cli(
    path: str | Path, args: argparse.Namespace | None = None, truth: TruthSource | None = None,
    on_state: Callable[[NavState], None] | None = None,
) -> int:  # fmt: skip
    """``ins-hil replay LOG.ihlog``: replay and print what came out (exit status 0, 2 on a bad log); a
    simulated run is scored against ``truth`` of its ``[sim]`` table when given (:func:`truth_report`).
    ``on_state``: called with every state (the command's ``--export``)."""
    from ins_hil.nav.rotation import euler_from_quat

    seen: list[Any] = [None, 0]  # last state, count
    scored: list[NavState] = []  # every SCORE_EVERY-th state (the truth comparison of a simulated run)

    def keep(st: NavState) -> None:
        seen[0] = st
        seen[1] += 1
        if on_state is not None:
            on_state(st)
        if seen[1] % SCORE_EVERY == 0:
            scored.append(st)

    try:
        res = replay_log(path, keep_states=False, on_state=keep)
    except (OSError, ValueError) as err:  # a RecordError names the file (and part, byte) itself
        print(f"ins-hil replay: {err if isinstance(err, RecordError) else f'{path}: {err}'}", file=sys.stderr)
        return 2
    pipe = res.header.get("pipeline", {})
    print(f"{path}: {res.records} inputs in {res.parts} part(s), core {pipe.get('core', '?')}")
    last: NavState | None = seen[0]
    if last is not None:
        rpy = [math.degrees(float(x)) for x in euler_from_quat(last.q_nb)]
        print(
            f"final state t {last.t:.3f} s: lat {math.degrees(last.lat):.7f} lon {math.degrees(last.lon):.7f} "
            f"h {last.h:.2f} m, roll/pitch/yaw {rpy[0]:.2f} {rpy[1]:.2f} {rpy[2]:.2f} deg, aligned {last.aligned}"
        )
    print(f"IMU epochs processed {seen[1]}, counters {res.counts}")
    print(f"fault events {len(res.events)}")
    for note in res.read_notes:
        print(f"note: {note}")
    if res.read_error:
        print(f"ins-hil replay: {res.read_error}", file=sys.stderr)
    if not getattr(args, "quiet", False):
        for ev in res.events[:50]:
            print(f"  t {ev.t:.3f} {ev.sensor} {ev.mode.name}{' cleared' if ev.cleared else ''} {ev.detail}")
    sim = sim_config_from_header(res.header)
    if sim is not None and scored and truth is not None:
        for line in truth_report(path, sim, scored, truth(sim, scored[-1].t + 1.0)):
            print(line)
    return 2 if res.read_error else 0


#: a simulated run's states are scored at this decimation (1 kHz → 10 Hz) ...
SCORE_EVERY = 100
#: ... from this long after the first state (the rest before the default flight's take-off, yaw unobservable)
SETTLE_S = 10.0


def sim_config_from_header(header: dict[str, Any]) -> SimConfig | None:
    """The ``[sim]`` table of a log header's config when the run used the simulator, else None."""
    conf = header.get("config")
    if not isinstance(conf, dict) or not conf.get("sim_enabled") or not isinstance(conf.get("sim"), dict):
        return None
    names = {f.name for f in dataclasses.fields(SimConfig)}
    return SimConfig(**{k: v for k, v in conf["sim"].items() if k in names and k != "sign_key"})


def truth_report(path: str | Path, sim: SimConfig, states: list[NavState], truth: SimTruth) -> list[str]:
    """Lines for ``ins-hil replay LOG`` of a simulated run: the recorded IMU samples against the regenerated
    ones, then the error of ``states`` against the regenerated ``truth`` of ``sim`` (:func:`score`; the
    truth covers the states, ``ins_hil.evaluation.sim_flight.sim_truth(sim, states[-1].t + 1)``)."""
    imu = [cast(ImuSample, r) for r in read_records(path) if r.kind == "imu"]
    chk = check_imu(truth, imu)
    same = "all equal" if chk["equal"] == chk["samples"] else f"{chk['samples'] - chk['equal']} differ"
    out = [
        f"simulated run (profile {sim.profile}, seed {sim.seed}): truth regenerated from the header's [sim]; "
        f"recorded IMU samples against the regenerated ones: {chk['matched']}/{chk['samples']} matched, {same} "
        f"(max |difference| {chk['max_abs_diff']:.3g})"
    ]
    t0 = states[0].t + SETTLE_S
    sel = [s for s in states if s.t >= t0]
    if not sel:
        return [*out, f"error against truth: no state {SETTLE_S:g} s after the first (run too short)"]
    m = score(errors(sel, truth))
    out.append(
        f"error against truth, t {sel[0].t:.1f}–{sel[-1].t:.1f} s ({m['epochs']} epochs at "
        f"{sim.imu_rate / SCORE_EVERY:g} Hz): along-track bias {_bias(m['along_bias_m'])}, horizontal RMS "
        f"{m['horiz_rms_m']:.3f} m (published σ_h RMS {m['horiz_sigma_rms_m']:.3f} m), NEES position "
        f"{m['nees_pos']:.2f} velocity {m['nees_vel']:.2f} (3 when σ is consistent), horizontal error inside "
        f"3σ_h {100 * m['cover_3sigma']:.1f} % of epochs"
    )
    return out


# ---------------------------------------------------------------------------------------------- truth
@dataclass
class SimTruth:
    """The simulator's truth at its IMU rate (row k at ``t = t0 + k / rate``), and its IMU samples as
    the devices emit them (float32 increments of the serial frame, µs time stamps)."""

    rate: float
    t: np.ndarray  # (N,) s
    lat: np.ndarray  # (N,) rad
    lon: np.ndarray
    h: np.ndarray  # m
    vel_ned: np.ndarray  # (N, 3) m/s
    imu_t: np.ndarray  # (M,) s: the end time of each IMU interval
    imu_dtheta: np.ndarray  # (M, 3) rad
    imu_dvel: np.ndarray  # (M, 3) m/s

    def rows(self, t: np.ndarray) -> np.ndarray:
        """The truth rows of times ``t`` (s); ValueError if a time is outside or off the IMU grid."""
        k = np.rint((np.asarray(t) - self.t[0]) * self.rate).astype(np.int64)
        if len(k) and (k.min() < 0 or k.max() >= len(self.t)):
            raise ValueError(f"time outside the regenerated truth ({self.t[0]:.3f}..{self.t[-1]:.3f} s)")
        if len(k) and float(np.max(np.abs(self.t[k] - t))) > 0.25 / self.rate:
            raise ValueError("state times are not on the simulator's IMU grid")
        return k


def check_imu(truth: SimTruth, samples: list[ImuSample]) -> dict[str, Any]:
    """Compare recorded IMU samples with the regenerated ones: matched by time stamp, the increments must be
    equal (bit for bit after the frame's float32). Returns counts and the largest difference."""
    if not samples:
        return {"samples": 0, "matched": 0, "equal": 0, "max_abs_diff": 0.0}
    t = np.array([s.t for s in samples])
    k = np.rint((t - truth.imu_t[0]) * truth.rate).astype(np.int64)
    ok = (k >= 0) & (k < len(truth.imu_t))
    ok[ok] &= np.abs(truth.imu_t[k[ok]] - t[ok]) < 0.25 / truth.rate
    th = np.array([s.dtheta for s in samples])[ok]
    dv = np.array([s.dvel for s in samples])[ok]
    kk = k[ok]
    eq = np.all(th == truth.imu_dtheta[kk], axis=1) & np.all(dv == truth.imu_dvel[kk], axis=1)
    d = max(float(np.max(np.abs(th - truth.imu_dtheta[kk]), initial=0.0)),
            float(np.max(np.abs(dv - truth.imu_dvel[kk]), initial=0.0)))  # fmt: skip
    return {"samples": len(samples), "matched": int(ok.sum()), "equal": int(eq.sum()), "max_abs_diff": d}


@dataclass
class Errors:
    """State − truth at the scored states: position NED (m), velocity NED (m/s), their published σ, the
    truth velocity (m/s) for the along-track direction."""

    t: np.ndarray
    pos: np.ndarray
    vel: np.ndarray
    std_pos: np.ndarray
    std_vel: np.ndarray
    vel_true: np.ndarray


def errors(states: list[NavState], truth: SimTruth) -> Errors:
    """The errors of ``states`` against ``truth`` (local NED at the truth position)."""
    from ins_hil.nav import earth

    t = np.array([s.t for s in states])
    k = truth.rows(t)
    lat = np.array([s.lat for s in states])
    lon = np.array([s.lon for s in states])
    h = np.array([s.h for s in states])
    sl = np.sin(truth.lat[k])
    w2 = 1.0 - earth.E2_WGS84 * sl * sl
    n = earth.A_WGS84 / np.sqrt(w2)  # earth.radii, element-wise
    m = n * (1.0 - earth.E2_WGS84) / w2
    # small differences of geodetic coordinates to NED metres (the errors are metres, not kilometres)
    pos = np.stack([(lat - truth.lat[k]) * (m + truth.h[k]),
                    (lon - truth.lon[k]) * (n + truth.h[k]) * np.cos(truth.lat[k]),
                    -(h - truth.h[k])], axis=1)  # fmt: skip
    vel = np.array([s.vel_ned for s in states]) - truth.vel_ned[k]
    return Errors(t, pos, vel, np.array([s.std_pos for s in states]), np.array([s.std_vel for s in states]),
                  truth.vel_ned[k])  # fmt: skip


def score(e: Errors, min_speed: float = 5.0) -> dict[str, float]:
    """Accuracy and consistency of one run: ``along_bias_m`` (mean position error along the truth's
    horizontal velocity, epochs faster than ``min_speed`` m/s; negative = behind), ``horiz_rms_m``,
    ``nees_pos`` / ``nees_vel`` (mean of Σ (e_i/σ_i)² over N, E, D: 3 for a consistent filter),
    ``cover_3sigma`` (fraction of epochs with |e_NE| ≤ 3 hypot(σ_N, σ_E)), ``epochs``."""
    vh = e.vel_true[:, :2]
    sp = np.hypot(vh[:, 0], vh[:, 1])
    mv = sp > min_speed
    along = np.sum(e.pos[mv, :2] * vh[mv], axis=1) / sp[mv]
    eh = np.hypot(e.pos[:, 0], e.pos[:, 1])
    sh = np.hypot(e.std_pos[:, 0], e.std_pos[:, 1])
    return {
        "epochs": len(e.t),
        "along_bias_m": float(np.mean(along)) if len(along) else math.nan,
        "horiz_rms_m": float(np.sqrt(np.mean(eh**2))),
        "horiz_sigma_rms_m": float(np.sqrt(np.mean(sh**2))),
        "nees_pos": float(np.mean(np.sum((e.pos / e.std_pos) ** 2, axis=1))),
        "nees_vel": float(np.mean(np.sum((e.vel / e.std_vel) ** 2, axis=1))),
        "cover_3sigma": float(np.mean(eh <= 3.0 * sh)),
    }


def _bias(b: float) -> str:
    """The along-track bias for a report line ("n/a" when the truth never moved: no track to be along)."""
    return f"{b:+.3f} m" if math.isfinite(b) else "n/a (the vehicle did not move)"
