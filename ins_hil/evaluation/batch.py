"""Batch replays on Dask: many logs, each with its dataset config, times Monte-Carlo seeds.

A job is one (log, dataset config, seed): the replay of :func:`ins_hil.datasets.report.replay` with its
report written to its own folder. Seed 0 runs the outage protocol as configured; seed k > 0 shifts the
protocol's start by a draw from U(0, on + off) s (``numpy.random.default_rng(k)``), so the seeds of one
log put the outages at other phases of the flight: the spread over seeds is how much the outage figure
owes to where the outages fell. Jobs run on a ``dask.distributed`` LocalCluster of ``workers``
processes (one thread each: a replay is CPU-bound Python) or on an existing scheduler; ``workers = 0``
runs them one after the other in this process (the serial reference for the speed-up). A job that fails
is a row with its error; the others go on.
"""

from __future__ import annotations

import dataclasses
import glob
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ins_hil.datasets.config import DatasetConfig
from ins_hil.datasets.config import load as load_config
from ins_hil.datasets.dataset import DatasetError, detect_format


@dataclass(frozen=True)
class Job:
    """One replay: ``source`` (a log; None = the config's ``dataset.path``), ``config`` (a dataset TOML;
    None = the defaults), ``seed``, and the folder ``out`` for its report."""

    source: str | None
    config: str | None
    seed: int
    out: str

    @property
    def name(self) -> str:
        stem = Path(self.source).name if self.source else Path(self.config or "dataset").stem
        return f"{stem}#{self.seed}"


def expand(entries: list[str], config: str | None = None) -> list[tuple[str | None, str | None]]:
    """(source, config) pairs of the batch's entries: a dataset TOML (its own ``dataset.path``), a log
    (with ``config``), a folder (every log or TOML directly inside it; the folder itself when it is a
    dataset, e.g. a ulog2csv set) or a glob of these. DatasetError when an entry matches nothing."""
    out: list[tuple[str | None, str | None]] = []
    for e in entries:
        paths = sorted(glob.glob(e)) if any(c in e for c in "*?[") else [e]
        if not paths:
            raise DatasetError(f"batch: {e!r} matches no file")
        for p in map(Path, paths):
            if p.suffix == ".toml":
                out.append((None, str(p)))
            elif p.is_dir() and not _is_log(p):
                inside = [q for q in sorted(p.iterdir()) if q.suffix == ".toml" or _is_log(q)]
                if not inside:
                    raise DatasetError(f"batch: {p}: no dataset config or supported log inside")
                out += [(None, str(q)) if q.suffix == ".toml" else (str(q), config) for q in inside]
            elif p.exists():
                out.append((str(p), config))
            else:
                raise DatasetError(f"batch: {p}: no such file or folder")
    return out


def _is_log(p: Path) -> bool:
    try:
        detect_format(p)
    except (DatasetError, OSError):
        return False
    return True


def jobs(pairs: list[tuple[str | None, str | None]], seeds: int, out: Path) -> list[Job]:
    """Every pair times seeds 0 … seeds − 1, each with its folder under ``out``."""
    js = []
    for i, (src, cfg) in enumerate(pairs):
        for s in range(seeds):
            j = Job(src, cfg, s, "")
            js.append(dataclasses.replace(j, out=str(out / f"{i:02d}-{j.name.replace('#', '-seed')}")))
    return js


def seeded(cfg: DatasetConfig, seed: int) -> DatasetConfig:
    """The config with its outage protocol shifted by the seed's draw (seed 0: unchanged)."""
    if seed == 0 or cfg.outages is None:
        return cfg
    o = cfg.outages
    shift = float(np.random.default_rng(seed).uniform(0.0, o.on_s + o.off_s))
    return dataclasses.replace(cfg, outages=dataclasses.replace(o, start_s=o.start_s + shift))


def run_job(job: Job) -> dict[str, Any]:
    """Replay one job and write its ``metrics.json`` and plots into ``job.out``; its summary row.
    Never raises: an error is the row's ``error``."""
    import json

    from ins_hil.datasets import ihlog, report
    from ins_hil.evaluation.sim_flight import sim_truth

    ihlog.set_truth_source(sim_truth)  # in this (worker) process: simulated gateway logs get their truth

    t0 = time.perf_counter()
    row: dict[str, Any] = {"job": job.name, "source": job.source, "config": job.config, "seed": job.seed}
    try:
        cfg = load_config(job.config) if job.config else DatasetConfig(name=Path(job.source or "dataset").stem)
        cfg = seeded(cfg, job.seed)
        path = job.source if job.source is not None else cfg.path
        if path is None:
            raise DatasetError(f"{job.config}: no dataset.path")
        ds = report.load(Path(path), cfg)
        m, runs = report.replay(ds, cfg)
        out = Path(job.out)
        out.mkdir(parents=True, exist_ok=True)
        m["plots"] = [str(p) for p in report.plot(m, runs, ds, out)]
        m["seed"] = job.seed
        (out / "metrics.json").write_text(json.dumps(report.jsonable(m), indent=2))
        row.update(_row(m))
    except Exception as e:  # a failing log is reported and does not stop the others
        row["error"] = f"{type(e).__name__}: {e}"
    row["elapsed_s"] = time.perf_counter() - t0
    return row


def _row(m: dict[str, Any]) -> dict[str, Any]:
    """The summary columns of one replay's metrics."""
    r: dict[str, Any] = {"dataset": m.get("dataset"), "duration_s": m.get("duration_s"),
                         "imu": m.get("samples", {}).get("imu"), "realtime": m.get("realtime_factor")}  # fmt: skip
    g = m.get("gnss")
    if isinstance(g, dict):
        r["gnss_h_rms_m"] = g.get("gnss_h_rms_prior_m")
    o = m.get("outages")
    if isinstance(o, dict):
        for k in ("outage_h_rms_m", "outage_h_max_m", "hold_h_rms_m", "cv_h_rms_m", "beats_both_in_every_outage"):
            r[k] = o.get(k)
    ob = m.get("onboard")
    if isinstance(ob, dict):
        att = ob.get("attitude_deg")
        if isinstance(att, dict):
            r["onboard_att_rms_deg"] = [att[k]["rms"] for k in ("roll", "pitch", "yaw") if k in att]
    r["warnings"] = len(m.get("warnings", []))
    return r


def run_batch(
    js: list[Job],
    workers: int = 2,
    scheduler: str | None = None,
    on_done: Callable[[dict[str, Any], int, int], None] | None = None,
) -> tuple[list[dict[str, Any]], float]:
    """Run ``js``; (rows in job order, wall time s). ``scheduler``: a Dask scheduler address (e.g.
    ``tcp://host:8786``); else a LocalCluster of ``workers`` processes; ``workers = 0``: serial here.
    ``on_done(row, k, n)`` after each job (k done of n)."""
    t0 = time.perf_counter()
    rows: dict[int, dict[str, Any]] = {}
    if scheduler is None and workers == 0:
        for i, j in enumerate(js):
            rows[i] = run_job(j)
            if on_done:
                on_done(rows[i], len(rows), len(js))
        return [rows[i] for i in range(len(js))], time.perf_counter() - t0
    from dask.distributed import Client, LocalCluster, as_completed

    cluster = None
    if scheduler is None:
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None)
    client = Client(scheduler if scheduler is not None else cluster)
    try:
        futs = {client.submit(run_job, j, pure=False): i for i, j in enumerate(js)}
        for f in as_completed(futs):
            i = futs[f]
            try:
                rows[i] = f.result()
            except Exception as e:  # the worker died (not a failing log: run_job never raises)
                rows[i] = {"job": js[i].name, "seed": js[i].seed, "error": f"worker: {type(e).__name__}: {e}"}
            if on_done:
                on_done(rows[i], len(rows), len(js))
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    return [rows[i] for i in range(len(js))], time.perf_counter() - t0


def _f(x: Any, nd: int = 2) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "—"
    return f"{x:.{nd}f}" if isinstance(x, float) else str(x)


def table(rows: list[dict[str, Any]]) -> str:
    """The batch's summary table (Markdown), one row per job."""
    head = ("job", "duration s", "GNSS h RMS m", "outage h RMS / max m", "hold / CV RMS m", "× real time",
            "wall s", "status")  # fmt: skip
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        status = r["error"] if "error" in r else ("ok" if not r.get("warnings") else f"{r['warnings']} warning(s)")
        outage = (f"{_f(r.get('outage_h_rms_m'))} / {_f(r.get('outage_h_max_m'))}"
                  if r.get("outage_h_rms_m") is not None else "—")  # fmt: skip
        triv = (f"{_f(r.get('hold_h_rms_m'))} / {_f(r.get('cv_h_rms_m'))}"
                if r.get("hold_h_rms_m") is not None else "—")  # fmt: skip
        cells = (r["job"], _f(r.get("duration_s"), 0), _f(r.get("gnss_h_rms_m")), outage, triv,
                 _f(r.get("realtime"), 0), _f(r.get("elapsed_s"), 1), status)  # fmt: skip
        lines.append("| " + " | ".join(str(c) for c in cells) + " |")
    return "\n".join(lines)
