"""Exact offline replay of a recorder log (``.ihlog``) through the same pipeline.

The recorder writes every input in the order the live loop handed it to the
pipeline, as float64, and stores the pipeline config in the log header; the
replay builds the same :class:`~ins_hil.runtime.pipeline.Pipeline` and calls
it in the same order, so it reproduces the online fused states bit for bit
(the live loop only adds timing and I/O around these calls).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, overload

import numpy as np

from ins_hil.runtime.pipeline import Pipeline, PipelineConfig
from ins_hil.runtime.recorder import LogReader, parts_of, read_header
from ins_hil.types import FaultEvent, ImuSample, NavState


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
    names = {f.name for f in dataclasses.fields(PipelineConfig)}
    cfg = PipelineConfig(**{k: v for k, v in d.items() if k in names})
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
        if isinstance(rec, ImuSample):
            st = pipe.imu(rec)
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


def replay_cli(path: str | Path, args: argparse.Namespace | None = None) -> int:
    """``ins-hil replay LOG.ihlog``: replay and print what came out (exit status 0, 2 on a bad log)."""
    from ins_hil.nav.rotation import euler_from_quat

    seen: list[Any] = [None, 0]  # last state, count

    def keep(st: NavState) -> None:
        seen[0] = st
        seen[1] += 1

    try:
        res = replay_log(path, keep_states=False, on_state=keep)
    except (OSError, ValueError) as err:
        print(f"ins-hil replay: {path}: {err}", file=sys.stderr)
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
    return 2 if res.read_error else 0
