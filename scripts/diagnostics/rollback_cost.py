"""Cost of delayed fusion (rollback) in the Python core at the gateway's rate, configs/default.toml.

Runs the default simulator's flight offline in the devices' send order through the default Pipeline
(1 kHz, ``cov_every = 10``) with ``[core.nav.delay] compensation`` true and false, timing every core call with
``time.perf_counter_ns``: per IMU step (median) (``step_begin`` + ``step_end``), per aiding measurement (all the
segments of its ``fuse_steps``) and the longest single segment (what one gap between IMU steps must hold).
Each call's best of ``--repeat`` runs (:func:`best_of`).

    python scripts/diagnostics/rollback_cost.py [--seconds 40] [--repeat 3]
"""

from __future__ import annotations

import argparse
import sys
import time
import tomllib
from collections.abc import Iterator
from typing import Any

import numpy as np

from ins_hil.config import default_path, from_dict
from ins_hil.runtime.pipeline import Pipeline
from ins_hil.sim.devices import send_order
from ins_hil.types import BaroSample, GnssFix, ImuSample


def run(dc: bool, seconds: float) -> dict[str, float]:
    d = tomllib.loads(default_path().read_text())
    d["core"]["nav"]["delay"] = {"compensation": dc}
    cfg = from_dict(d, "bench")
    pipe = Pipeline(cfg.pipeline)
    ns = time.perf_counter_ns
    step_t: list[int] = []
    fix_t: dict[str, list[int]] = {"GnssFix": [], "BaroSample": []}
    segs: list[int] = []
    wrapped = [False]
    acc = [0]

    def wrap(core: Any) -> None:
        sb, se, fs = core.step_begin, core.step_end, core.fuse_steps

        def step_begin(imu: ImuSample) -> Any:
            t0 = ns()
            out = sb(imu)
            acc[0] = ns() - t0
            return out

        def step_end() -> None:
            t0 = ns()
            se()
            step_t.append(acc[0] + ns() - t0)
            acc[0] = 0

        def fuse_steps(m: GnssFix | BaroSample) -> Iterator[None]:
            g = fs(m)
            tot = 0
            while True:
                t0 = ns()
                try:
                    next(g)
                except StopIteration:
                    dt = ns() - t0
                    tot += dt
                    segs.append(dt)
                    fix_t[type(m).__name__].append(tot)
                    return
                dt = ns() - t0
                tot += dt
                segs.append(dt)
                yield

        core.step_begin, core.step_end, core.fuse_steps = step_begin, step_end, fuse_steps
        pipe._split = core
        wrapped[0] = True

    for s in send_order(cfg.sim, seconds):
        if s.kind == "imu":
            pipe.imu(s)
            if not wrapped[0] and pipe.core is not None:
                wrap(pipe.core)
        else:
            pipe.aid(s)
            if not wrapped[0] and pipe.core is not None:
                wrap(pipe.core)
        pipe.work()
    pipe.flush()
    return {
        "step": np.array(step_t[1000:]),
        "gnss": np.array(fix_t["GnssFix"]),  # from the 2nd s of navigation
        "baro": np.array(fix_t["BaroSample"]),
        "seg": np.array(segs),
    }


def best_of(runs: list[dict[str, np.ndarray]]) -> dict[str, float]:
    """Every call's lowest time over the runs (the runs are deterministic: call k does the same work in each),
    then the median/mean over the calls, in µs: what the work costs without the other load of the machine."""
    b = {k: np.min([r[k] for r in runs], axis=0) / 1e3 for k in runs[0]}
    n_meas = len(b["gnss"]) + len(b["baro"])
    return {
        "step_med": float(np.median(b["step"])),
        "step_mean": float(np.mean(b["step"])),
        "gnss_med": float(np.median(b["gnss"])),
        "gnss_max": float(np.max(b["gnss"])),
        "baro_med": float(np.median(b["baro"])),
        "seg_max": float(np.max(b["seg"])),
        "segs_per_meas": len(b["seg"]) / n_meas,
        "steps": len(b["step"]),
        "fixes": len(b["gnss"]),
    }


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=40.0)
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    if not 0 < a.seconds < float("inf") or a.repeat < 1:
        ap.error("--seconds must be a positive number of seconds and --repeat at least 1")
    for dc in (False, True):
        best = best_of([run(dc, a.seconds) for _ in range(a.repeat)])
        print(
            f"delay.compensation={str(dc).lower():5}: IMU step median {best['step_med']:.1f} µs"
            f" (mean {best['step_mean']:.1f}), GNSS fix median {best['gnss_med']:.0f} µs"
            f" (max {best['gnss_max']:.0f}), baro median {best['baro_med']:.0f} µs;"
            f" longest segment {best['seg_max']:.0f} µs, {best['segs_per_meas']:.1f} segments per measurement;"
            f" {best['steps']:.0f} steps, {best['fixes']:.0f} fixes (best of {a.repeat})"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
