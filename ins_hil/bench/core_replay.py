"""Replays on the Python core and on the C core side by side (``ins-hil bench-core``, the dataset section).

Each shipped dataset config whose recording is on disk is read and prepared once (``ins_hil.datasets.run.prepare``,
as ``ins-hil replay``), then replayed through ``NavCore`` and through ``CNavCore`` (double, per-sample step,
roll-back on): every aid after its IMU step in time order, the magnetometer as a heading (``run_dataset``'s feed).
Figures are CPU seconds of this process (``time.process_time``: stable under other load); "whole" adds the
reading and preparation to the replay. A config the C core refuses is reported with the reason.
The synthetic row: 200 Hz IMU, 20 Hz GNSS with a 0.1-s velocity delay (a roll-back per fix).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
CONFIGS = ROOT / "configs" / "datasets"


def feed(p: Any, core: Any) -> None:
    """Replay a prepared log through ``core`` (NavCore or CNavCore) as ``run_dataset`` feeds it (no outages).
    On the C core, once it navigates, the IMU samples between two aids go in one call (``CNavCore.run``)."""
    from ins_hil.datasets.run import heading_only
    from ins_hil.types import MagSample

    meas = sorted([(f.t, 0, f) for f in p.gnss] + [(m.t, 2, m) for m in p.aux], key=lambda x: (x[0], x[1]))
    ref = p.nav.mag.ref_ned
    is_c = not hasattr(core, "ins")
    imu = p.imu
    if is_c:
        dth = np.array([s.dtheta for s in imu])
        dv = np.array([s.dvel for s in imu])
        t = np.array([s.t for s in imu])
        dts = np.array([s.dt for s in imu])
    j, n, k, n_imu = 0, len(meas), 0, len(imu)
    while k < n_imu:
        s = imu[k]
        if is_c and core.phase == "nav" and core.dt is not None:
            # every sample up to the next aid's time in one call
            t_next = meas[j][0] if j < n else math.inf
            k_end = max(k + 1, int(np.searchsorted(t, t_next, side="left")) + 1) if j < n else n_imu
            k_end = min(k_end, n_imu)
            core.run(dth[k:k_end], dv[k:k_end], t[k:k_end], every=0, dt=dts[k:k_end])
            s = imu[k_end - 1]
            k = k_end
        else:
            core.step(s)
            k += 1
        while j < n and meas[j][0] <= s.t:
            m = meas[j][2]
            j += 1
            if p.mag_heading_only and isinstance(m, MagSample) and core.phase == "nav":
                m = heading_only(m, core.state().q_nb if is_c else core.ins.state.q_nb, ref)
            core.fuse(m)


def _cores(nav: Any) -> tuple[Any, Any, str]:
    from ins_hil.core import NavCore
    from ins_hil.cref import CNavCore

    try:
        c = CNavCore(None, nav, fixed_step=False)
    except ValueError as e:
        return NavCore(None, nav), None, str(e).split(": ", 1)[-1]
    return NavCore(None, nav), c, ""


def dataset_rows(say: Callable[[str], None] | None = None) -> list[dict[str, Any]]:
    """One row per shipped dataset config with its recording on disk."""
    from ins_hil.datasets import config
    from ins_hil.datasets.dataset import read_dataset
    from ins_hil.datasets.run import prepare

    rows = []
    for path in sorted(CONFIGS.glob("*.toml")):
        cfg = config.load(path)
        if cfg.path is None or not cfg.path.exists():
            continue
        t0 = time.process_time()
        p = prepare(read_dataset(cfg.path, cfg.format, cfg), cfg)
        t_read = time.process_time() - t0
        span = float(p.imu[-1].t - p.imu[0].t)
        py, c, why = _cores(p.nav)
        row: dict[str, Any] = {"name": path.stem, "span_s": span, "imu": len(p.imu), "read_s": t_read, "why": why}
        t0 = time.process_time()
        feed(p, py)
        row["python_s"] = time.process_time() - t0
        if c is not None:
            t0 = time.process_time()
            feed(p, c)
            row["c_s"] = time.process_time() - t0
        rows.append(row)
        if say:
            say("  " + dataset_line(row))
    return rows


def dataset_line(r: dict[str, Any]) -> str:
    py_rt = r["span_s"] / r["python_s"]
    head = f"{r['name']}: {r['span_s']:.0f} s, {r['imu']} IMU samples; read {r['read_s']:.2f} s; Python {py_rt:.0f}×"
    if "c_s" not in r:
        return head + f" real time; C refused ({r['why']})"
    c_rt = r["span_s"] / r["c_s"]
    whole_py = r["read_s"] + r["python_s"]
    whole_c = r["read_s"] + r["c_s"]
    return (head + f", C {c_rt:.0f}× real time (replay {r['python_s'] / r['c_s']:.1f}× the Python; whole process"
            f" {whole_py / whole_c:.1f}×)")  # fmt: skip


def synthetic_rows(seconds: float = 60.0, say: Callable[[str], None] | None = None) -> list[dict[str, Any]]:
    """200 Hz IMU with 20 Hz GNSS and a 0.1-s velocity delay on both cores (process time, real-time factor)."""
    from ins_hil.bench.replay_cost import _vel_at
    from ins_hil.datasets import config as dcfg
    from ins_hil.datasets.dataset import Dataset
    from ins_hil.datasets.run import prepare
    from ins_hil.sim import sensors as se
    from ins_hil.sim import trajectory as tr

    rng = np.random.default_rng(1)
    truth = tr.generate(tr.mission_profile(), seconds, 1.0 / 200.0, math.radians(45.0), math.radians(7.0), 100.0)
    imu = se.corrupt_imu(truth, se.mems_gyro(rng), se.mems_accel(rng), seed=rng).samples()
    fixes = list(se.gnss_fixes(truth, se.GnssModel(rate=20.0, std_ne=0.02, std_d=0.04, std_vel=0.02), seed=1))
    fixes = [dataclasses.replace(f, vel_ned=_vel_at(truth, f.t - 0.1)) for f in fixes]
    c = dcfg.from_dict({"dataset": {"name": "bench"}, "nav": {"gnss": {"vel_delay": 0.1}}})
    c.use_mag = c.use_baro = False
    p = prepare(Dataset(imu, fixes), c)
    py, cc, _ = _cores(p.nav)
    row: dict[str, Any] = {"name": "200 Hz IMU, 20 Hz GNSS, 0.1-s velocity delay", "span_s": seconds}
    for key, core in (("python_s", py), ("c_s", cc)):
        t0 = time.process_time()
        feed(p, core)
        row[key] = time.process_time() - t0
    row["rollbacks"] = int(cc._hist.rollbacks)
    if say:
        say(f"  {row['name']}: Python {seconds / row['python_s']:.0f}×, C {seconds / row['c_s']:.0f}× real time"
            f" ({row['rollbacks']} roll-backs on C)")  # fmt: skip
    return [row]


def report_md(rows: list[dict[str, Any]], synth: list[dict[str, Any]]) -> str:
    """The Markdown section of docs/ref_core.md."""
    out = [
        "",
        "## Replays on the C core",
        "",
        "Each shipped dataset config, read and prepared once as `ins-hil replay` does, then replayed through"
        " `NavCore` and `CNavCore` (double, per-sample step, delayed fusion by roll-back) in the same process;"
        " CPU seconds of the process (`time.process_time`). The replay figures include the per-step Python"
        " around the core (the loop, `NavState` per step, the magnetometer heading); the alignment phase runs"
        " in Python on both.",
        "",
        "| config | log [s] | read + prepare [s] | Python [× real time] | C [× real time] | C / Python, replay |"
        " C / Python, whole process |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        py = r["span_s"] / r["python_s"]
        if "c_s" in r:
            c = r["span_s"] / r["c_s"]
            whole = (r["read_s"] + r["python_s"]) / (r["read_s"] + r["c_s"])
            cells = [f"{c:.0f}", f"{r['python_s'] / r['c_s']:.1f}×", f"{whole:.1f}×"]
        else:
            cells = [f"refused: {r['why']}", "—", "—"]
        out.append(f"| {r['name']} | {r['span_s']:.0f} | {r['read_s']:.2f} | {py:.0f} | " + " | ".join(cells) + " |")
    for r in synth:
        out += [
            "",
            f"Synthetic: {r['name']}, {r['span_s']:.0f} s: Python {r['span_s'] / r['python_s']:.0f}× real time,"
            f" C {r['span_s'] / r['c_s']:.0f}× real time ({r['rollbacks']} roll-backs), through `CNavCore.step`/"
            "`fuse` one call per sample.",
        ]
    out.append("")
    return "\n".join(out)
