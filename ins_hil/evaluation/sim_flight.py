"""The simulated flight of a gateway config, scored against the simulator's truth.

:func:`sim_truth` regenerates the truth of a ``[sim]`` table (the simulator is seeded and
deterministic); :func:`replay_log` is ``ins-hil replay LOG.ihlog`` with that truth passed to the
runtime's replay (``ins_hil.runtime.replay.replay_cli``), so a simulated recording is scored.
:func:`fly_sim` runs a config's simulated flight offline (no real time, the devices' send order) and
:func:`monte_carlo_sim` scores it over seeds (``ins_hil.runtime.replay.score``): position bias along
track, horizontal RMS, NEES of position and velocity from the published per-axis σ against the χ²
band, and the fraction of epochs with the horizontal error inside 3σ.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import sys
import time
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ins_hil.config import default_path, from_dict
from ins_hil.datasets.run import replay
from ins_hil.runtime.pipeline import Observer, Pipeline
from ins_hil.runtime.replay import SimTruth, errors, replay_cli, score
from ins_hil.sim.devices import send_order, truth_chunks
from ins_hil.types import ImuSample, NavState, SimConfig


def replay_log(path: str | Path, args: argparse.Namespace, on_state: Callable[[NavState], None] | None = None) -> int:
    """``ins-hil replay LOG.ihlog``: the runtime's replay and summary; a simulated run scored against the
    regenerated truth (:func:`sim_truth`); ``on_state`` sees every state. Exit status 0, 2 on a bad log."""
    return replay_cli(path, args, truth=sim_truth, on_state=on_state)


def sim_truth(sim: SimConfig, duration: float) -> SimTruth:
    """Regenerate the truth of ``sim`` (``ins_hil.sim.devices.truth_chunks``) for ``duration`` s."""
    parts: list[tuple[np.ndarray, ...]] = []
    imu: list[tuple[np.ndarray, ...]] = []
    for truth, ser, _fixes, _baro in truth_chunks(sim):
        k0 = 1 if parts else 0  # row 0 of a chunk is the last row of the previous one
        parts.append((truth.t[k0:], truth.lat[k0:], truth.lon[k0:], truth.h[k0:], truth.vel_ned[k0:]))
        imu.append((ser.t, ser.dtheta, ser.dvel))
        if truth.t[-1] >= duration - 1e-9:
            break
    t, lat, lon, h, vel = (np.concatenate([p[i] for p in parts]) for i in range(5))
    it, ith, iv = (np.concatenate([p[i] for p in imu]) for i in range(3))
    # the serial frame carries float32 increments and a µs time stamp (ins_hil.drivers.serial_frame)
    return SimTruth(
        sim.imu_rate, t, lat, lon, h, vel, np.rint(it * 1e6) * 1e-6,
        ith.astype(np.float32).astype(np.float64), iv.astype(np.float32).astype(np.float64),
    )  # fmt: skip


class _Every(Observer):
    """Every ``every``-th state the pipeline publishes."""

    def __init__(self, every: int) -> None:
        self.every, self.n = every, 0
        self.states: list[NavState] = []

    def epoch(self, pipe: Pipeline, st: NavState) -> None:
        self.n += 1
        if self.n % self.every == 0:
            self.states.append(st)


def fly_sim(
    config: dict[str, Any], seed: int | None = None, duration: float = 60.0, every: int = 100
) -> tuple[list[NavState], SimTruth, dict[str, int]]:
    """Fly the ``[sim]`` flight of ``config`` (a config file as a dict) offline through its pipeline, in
    the devices' send order (``ins_hil.sim.devices.send_order``; no real time, no transports: the
    samples are not quantised by the frames). ``seed`` overrides ``[sim] seed``. Returns every
    ``every``-th state, the truth and the pipeline's counters."""
    d = copy.deepcopy(config)
    d.setdefault("sim", {})["enabled"] = True
    if seed is not None:
        d["sim"]["seed"] = seed
    cfg = from_dict(d, "sim flight")
    # the devices' send order, as the one offline loop (ins_hil.datasets.run.replay) takes it: each aiding
    # sample handed over after the IMU sample sent before it, fused a segment per gap as the live loop does
    imu: list[ImuSample] = []
    aids: list[Any] = []
    hand_at: list[float] = []
    for s in send_order(cfg.sim, duration):
        if s.kind == "imu":
            imu.append(s)
        else:
            aids.append(s)
            hand_at.append(imu[-1].t if imu else -math.inf)
    keep = _Every(every)
    pipe, _ = replay(imu, aids, cfg.pipeline.nav, [keep], hand_at=hand_at, pipeline=cfg.pipeline,
                     source="sim flight", live_schedule=True)  # fmt: skip
    states = keep.states
    return states, sim_truth(cfg.sim, duration), dict(pipe.counts)


def monte_carlo_sim(
    config: dict[str, Any], seeds: list[int], duration: float = 60.0, t_from: float = 20.0,
    on_run: Callable[[int, int, dict[str, Any]], None] | None = None,
) -> dict[str, Any]:  # fmt: skip
    """:func:`fly_sim` over ``seeds``, scored from ``t_from`` s: per seed :func:`score`; over the runs the
    mean along-track bias, the RMS, the mean NEES (position, velocity) with the two-sided 95 % band of
    χ²(3 R)/R for R runs (the mean over runs at each epoch, averaged over the epochs), and the coverage.
    ``on_run(k, n, row)`` after each run (k of n done; its seed and :func:`score`)."""
    from scipy.stats import chi2

    runs = []
    nees: dict[str, list[np.ndarray]] = {}
    for seed in seeds:
        states, truth, _ = fly_sim(config, seed, duration)
        e = errors([s for s in states if s.t >= t_from], truth)
        runs.append({"seed": seed, **score(e)})
        if on_run is not None:
            on_run(len(runs), len(seeds), runs[-1])
        for name, err, sd in (("pos", e.pos, e.std_pos), ("vel", e.vel, e.std_vel)):
            q = (err / sd) ** 2
            nees.setdefault(name, []).append(np.sum(q, axis=1))
            nees.setdefault(name + "_ne", []).append(q[:, 0] + q[:, 1])
            nees.setdefault(name + "_d", []).append(q[:, 2])
    r = len(seeds)
    L = min(len(x) for x in nees["pos"])
    out: dict[str, Any] = {
        "seeds": list(seeds),
        "duration_s": duration,
        "from_s": t_from,
        "along_bias_m": float(np.mean([x["along_bias_m"] for x in runs])),
        "horiz_rms_m": float(np.sqrt(np.mean([x["horiz_rms_m"] ** 2 for x in runs]))),
        "cover_3sigma": float(np.mean([x["cover_3sigma"] for x in runs])),
        "cover_3sigma_min": float(np.min([x["cover_3sigma"] for x in runs])),
    }
    for name, per_run in nees.items():
        dof = 2 if name.endswith("_ne") else 1 if name.endswith("_d") else 3
        avg = np.mean([x[:L] for x in per_run], axis=0)  # over the runs at each epoch
        lo, hi = (float(x) for x in chi2.ppf([0.025, 0.975], dof * r) / r)
        out[f"nees_{name}"] = float(np.mean(avg))
        out[f"nees_{name}_band_95"] = [lo, hi]
        out[f"nees_{name}_inside"] = float(np.mean((avg >= lo) & (avg <= hi)))
    out["runs"] = runs
    return out


def mc_lines(r: dict[str, Any]) -> list[str]:
    """The figures of :func:`monte_carlo_sim` as text lines."""

    def nees(name: str, label: str) -> str:
        lo, hi = r[f"nees_{name}_band_95"]
        return f"{label} {r[f'nees_{name}']:.2f} (band {lo:.2f}–{hi:.2f})"

    return [
        f"simulated flight, seeds {r['seeds'][0]}..{r['seeds'][-1]} ({len(r['seeds'])} runs of {r['duration_s']:g} s, "
        f"scored from {r['from_s']:g} s): along-track bias {r['along_bias_m']:+.3f} m, horizontal RMS "
        f"{r['horiz_rms_m']:.3f} m, horizontal error inside 3σ_h {100 * r['cover_3sigma']:.2f} % of epochs "
        f"(worst run {100 * r['cover_3sigma_min']:.2f} %)",
        "mean NEES over the runs against the two-sided 95 % χ² band: "
        + ", ".join((nees("pos", "position (3 dof)"), nees("pos_ne", "N/E"), nees("pos_d", "D"))),
        "  " + ", ".join((nees("vel", "velocity (3 dof)"), nees("vel_ne", "N/E"), nees("vel_d", "D"))),
    ]


def sim_cli(args: argparse.Namespace) -> int:
    """``ins-hil replay sim [--config C] [--runs N] [--seed S] [--duration D]``: :func:`monte_carlo_sim` of the
    config's ``[sim]`` flight over seeds S..S+N−1 (D s each, default 60, scored from 20 s or D/2); prints the
    figures, writes ``metrics.json`` to ``--out``. Exit status 2 on a bad config."""
    path = Path(args.config) if getattr(args, "config", None) else default_path()
    try:
        d = tomllib.loads(Path(path).read_text())
    except (OSError, tomllib.TOMLDecodeError) as err:
        print(f"ins-hil replay sim: {path}: {err}", file=sys.stderr)
        return 2
    duration = float(args.duration) if args.duration else 60.0
    seeds = list(range(int(args.seed), int(args.seed) + max(1, int(args.runs))))
    t0 = time.perf_counter()

    def progress(k: int, n: int, row: dict[str, Any]) -> None:  # one line a run (each flies `duration` s)
        print(f"  [{k}/{n}] seed {row['seed']}: horizontal RMS {row['horiz_rms_m']:.3f} m"
              f" ({time.perf_counter() - t0:.0f} s)", file=sys.stderr, flush=True)  # fmt: skip

    try:
        r = monte_carlo_sim(d, seeds, duration, min(20.0, 0.5 * duration), on_run=progress)
    except ValueError as err:
        print(f"ins-hil replay sim: {path}: {err}", file=sys.stderr)
        return 2
    for line in mc_lines(r):
        print(line)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "metrics.json").write_text(json.dumps({"sim": r, "config": str(path)}, indent=2))
    print(f"metrics: {out / 'metrics.json'}")
    return 0
