"""Batch replays on Dask: many logs, each with its dataset config, times Monte-Carlo seeds.

A job is one (log, dataset config, seed): the replay of :func:`ins_hil.datasets.report.replay` with its
report written to its own folder. Seed 0 runs the outage protocol as configured; seed k > 0 shifts the
protocol's start by a draw from U(0, on + off) s (``numpy.random.default_rng(k)``), so the seeds of one
log put the outages at other phases of the flight: the spread over seeds is how much the outage figure
owes to where the outages fell. Jobs run on a ``dask.distributed`` LocalCluster of ``workers``
processes (one thread each: a replay is CPU-bound Python) or on an existing scheduler; ``workers = 0``
runs them one after the other in this process (the serial reference for the speed-up). A job that fails
is a row with its error; the others go on.

Config variants and selection windows: a variants file (:func:`load_variants`, ``configs/variants/*.toml``)
names sets of dataset-config tables merged over each log's own config, and ``shifts`` moves the outage
protocol by fixed seconds (the selection windows a setting is chosen on, away from the scored protocol).
Every log then runs as configured and with each variant, at each shift; :func:`variant_table` puts their
outage errors side by side.

Scheduling: the job sizes are very unequal (a log with an outage protocol replays twice), so the jobs are
handed out longest-first (:func:`order`, by :func:`cost`, or by the replay times an earlier run of the same logs
measured, :func:`measured`: ``batch.json`` in the output folder; the seeds of one log together) with at most one
job in flight per worker thread: the long jobs do not come last, leaving one worker busy while the other
idles. Each process keeps its last :data:`CACHE_SIZE` parsed logs (:func:`load_cached`), and a freed worker
is handed (:func:`pick`) the next job of a log it has parsed, else of a log no worker has started, else the
longest left: each log is parsed about once in the whole batch, not once per worker. Each row carries its
load / replay / plot times (:func:`breakdown` sums them).
"""

from __future__ import annotations

import contextlib
import dataclasses
import glob
import os
import re
import signal
import sys
import time
from collections import OrderedDict
from collections.abc import Callable, Hashable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ins_hil.datasets.accuracy_md import fmt_value
from ins_hil.datasets.config import DatasetConfig, from_dict, merged
from ins_hil.datasets.config import load as load_config
from ins_hil.datasets.dataset import Dataset, DatasetError, detect_format


@dataclass(frozen=True)
class Job:
    """One replay: ``source`` (a log; None = the config's ``dataset.path``), ``config`` (a dataset TOML;
    None = the defaults), ``seed``, the folder ``out`` for its report, whether it writes its ``plots``, and the
    navigation ``core`` ("python" or "c")."""

    source: str | None
    config: str | None
    seed: int
    out: str
    plots: bool = True
    #: the variant's name and its tables (None: the config as it is); the protocol's shift (s)
    variant: str | None = None
    overrides: dict[str, Any] | None = field(default=None, hash=False)
    shift_s: float = 0.0
    core: str = "python"

    @property
    def log(self) -> str:
        """The log's short name."""
        return Path(self.source).name if self.source else Path(self.config or "dataset").stem

    @property
    def name(self) -> str:
        var = f"[{self.variant}]" if self.variant else ""
        shift = f"{self.shift_s:+g}s" if self.shift_s else ""
        return f"{self.log}{var}{shift}#{self.seed}"


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


#: the dataset-config tables a variant may set (not ``[dataset]``: the log, its format and name stay)
VARIANT_TABLES = ("sensor", "mounting", "aiding", "nav", "outages", "score", "rtklib")
#: the name of the config as it is, first among the variants
BASELINE = "config"


def load_variants(path: str | Path) -> list[tuple[str, dict[str, Any]]]:
    """The variants of a TOML file, in its order: each top-level table is one, named by its key, holding
    dataset-config tables (:data:`VARIANT_TABLES`, e.g. ``nav.aids.drag = true``). DatasetConfigError (one
    line) on a bad file; each variant's keys are checked against each log's config by :func:`jobs`."""
    from ins_hil.datasets.config import DatasetConfigError, read_toml

    d = read_toml(path, "variants file")
    if not d:
        raise DatasetConfigError(f"{path}: no variants (expected tables, e.g. [drag] with nav.aids.drag = true)")
    out = []
    for name, v in d.items():
        if not isinstance(v, dict):
            raise DatasetConfigError(f"{path}: {name} = {v!r}: a variant is a table [{name}]")
        if name == BASELINE or not re.fullmatch(r"[\w.+-]+", name):
            raise DatasetConfigError(f"{path}: [{name}]: a variant name is letters, digits, _ . + - and not "
                                     f"{BASELINE!r} (the config as it is)")  # fmt: skip
        bad = [k for k in v if k not in VARIANT_TABLES]
        if bad:
            hint = ' (a dot in a table name nests: quote the name, ["a-0.5"])' if isinstance(v[bad[0]], dict) else ""
            raise DatasetConfigError(f"{path}: [{name}] {bad[0]}: a variant sets {', '.join(VARIANT_TABLES)}{hint}")
        out.append((name, v))
    return out


def jobs(
    pairs: list[tuple[str | None, str | None]],
    seeds: int,
    out: Path,
    plots: bool = True,
    variants: list[tuple[str, dict[str, Any]]] | None = None,
    shifts: list[float] | None = None,
    core: str = "python",
) -> list[Job]:
    """Every pair times seeds 0 … seeds − 1, each with its folder under ``out``; with ``variants``, each
    also with every variant (the config as it is first), and with ``shifts``, each at every shift of its
    outage protocol (s; a config without one runs once, unshifted). DatasetConfigError when a variant does
    not fit a log's config (checked here, before anything runs). ``core``: every job's navigation core."""
    vs: list[tuple[str | None, dict[str, Any] | None]] = [(None, None)]
    vs += [(n, v) for n, v in variants or []]
    js = []
    for i, (src, cfg) in enumerate(pairs):
        for name, over in vs:
            base = Job(src, cfg, 0, "", plots, name, over, core=core)
            has_outages = _config(base).outages is not None  # the variant checked against this config
            for sh in (shifts or [0.0]) if has_outages else [0.0]:
                for s in range(seeds):
                    j = dataclasses.replace(base, seed=s, shift_s=float(sh))
                    parts = [f"{i:02d}", j.log, name or "", f"shift{sh:+g}s" if sh else "", f"seed{s}"]
                    folder = re.sub(r"[^\w.+-]+", "_", "-".join(q for q in parts if q))
                    js.append(dataclasses.replace(j, out=str(out / folder)))
    return js


def shifted(cfg: DatasetConfig, shift_s: float) -> DatasetConfig:
    """The config with its outage protocol's start moved by ``shift_s`` s (0 or no protocol: unchanged)."""
    if shift_s == 0.0 or cfg.outages is None:
        return cfg
    return dataclasses.replace(cfg, outages=dataclasses.replace(cfg.outages, start_s=cfg.outages.start_s + shift_s))


def seeded(cfg: DatasetConfig, seed: int) -> DatasetConfig:
    """The config with its outage protocol shifted by the seed's draw (seed 0: unchanged)."""
    if seed == 0 or cfg.outages is None:
        return cfg
    o = cfg.outages
    shift = float(np.random.default_rng(seed).uniform(0.0, o.on_s + o.off_s))
    return dataclasses.replace(cfg, outages=dataclasses.replace(o, start_s=o.start_s + shift))


def _config(job: Job) -> DatasetConfig:
    """The job's dataset config: its variant's tables merged over it, shifted, seeded."""
    label = f" with variant [{job.variant}]" if job.variant else ""
    if job.config:
        cfg = load_config(job.config, job.overrides, label)
    elif job.overrides:
        stem = Path(job.source or "dataset").stem
        cfg = from_dict(merged({"dataset": {"name": stem}}, job.overrides), f"{stem}{label}")
    else:
        cfg = DatasetConfig(name=Path(job.source or "dataset").stem)
    return seeded(shifted(cfg, job.shift_s), job.seed)


def _log_path(job: Job, cfg: DatasetConfig) -> Path:
    path = job.source if job.source is not None else cfg.path
    if path is None:
        raise DatasetError(f"{job.config}: no dataset.path")
    return Path(path)


def _files(path: Path) -> list[Path]:
    """The files a log is read from: the file, or the files directly inside a folder (ulog2csv, RTKLIB)."""
    return sorted(q for q in path.iterdir() if q.is_file()) if path.is_dir() else [path]


def missing_logs(js: list[Job]) -> list[str]:
    """One line per log of ``js`` that cannot run at all (a config without ``dataset.path``, a log that does not
    exist), each log once: checked before a batch starts rather than failing its jobs one by one."""
    out: list[str] = []
    first: dict[tuple[str | None, str | None], Job] = {}
    for j in js:
        first.setdefault((j.source, j.config), j)
    for job in first.values():
        try:
            path = _log_path(job, _config(job))
        except ValueError as e:  # DatasetError (no dataset.path), DatasetConfigError
            out.append(str(e))
            continue
        if not path.exists():
            where = f" (dataset.path of {job.config})" if job.source is None and job.config else ""
            out.append(f"{path}: no such file or folder{where}")
    return out


def cost(job: Job) -> float:
    """The job's expected replay cost (arbitrary units, for the order only): the log's size in bytes, times
    2 when the config has an outage protocol (a second replay); 0 when the log or its config cannot be
    read (the job fails fast)."""
    try:
        cfg = _config(job)
        size = sum(q.stat().st_size for q in _files(_log_path(job, cfg)))
    except (OSError, ValueError):  # DatasetError and DatasetConfigError are ValueErrors
        return 0.0
    return float(size) * (2.0 if cfg.outages is not None else 1.0)


def measured(rows: list[dict[str, Any]]) -> dict[tuple[str | None, str | None], float]:
    """Each log's (source, config) mean replay + plot time (s) over the ``rows`` of an earlier run of it that did
    not fail: a better cost for :func:`order` than the log's size (a log's bytes per replay second differ by
    format and by config: a GNSS velocity delay rolls back at every fix)."""
    acc: dict[tuple[str | None, str | None], list[float]] = {}
    for r in rows:
        if "error" not in r and isinstance(r.get("replay_s"), (int, float)):
            acc.setdefault((r.get("source"), r.get("config")), []).append(r["replay_s"] + r.get("plot_s", 0.0))
    return {k: sum(v) / len(v) for k, v in acc.items()}


def order(js: list[Job], known: dict[tuple[str | None, str | None], float] | None = None) -> list[int]:
    """The indices of ``js`` longest-first by :func:`cost` (longest-processing-time list scheduling): the
    seeds of one log stay together, in seed order; equal costs keep the batch's order. ``known``: each log's
    measured cost (:func:`measured`), used when it covers every log of ``js`` (seconds and bytes do not mix)."""
    keys = {(j.source, j.config) for j in js}
    if known is not None and keys <= known.keys():
        costs = {k: known[k] for k in keys}
    else:
        costs = {(j.source, j.config): cost(j) for j in js}
    first: dict[tuple[str | None, str | None], int] = {}
    for i, j in enumerate(js):
        first.setdefault((j.source, j.config), i)
    return sorted(range(len(js)), key=lambda i: (-costs[(js[i].source, js[i].config)],
                                                 first[(js[i].source, js[i].config)], js[i].seed))  # fmt: skip


def pick(keys: list[Hashable], held: list[Hashable], started: set[Hashable]) -> int:
    """Which of the jobs left (their logs' ``keys``, in :func:`order`) a freed worker takes: the first of a
    log in ``held`` (the logs it parsed, its cache), else the first of a log not in ``started`` (no worker
    has parsed it yet), else the first (the longest left). ``keys`` is not empty."""
    for want in (lambda k: k in held, lambda k: k not in started):
        for n, k in enumerate(keys):
            if want(k):
                return n
    return 0


#: parsed logs kept per process by :func:`load_cached`
CACHE_SIZE = 4
_CACHE: OrderedDict[Hashable, Dataset] = OrderedDict()


def _parse_key(path: Path, cfg: DatasetConfig) -> Hashable:
    """What the parsed log depends on: each file's resolved path, mtime (ns) and size, and the config parts
    the readers use (the format; the rtklib reader's ``[rtklib]`` options, IMU time offset and mounting)."""
    stamp = tuple((str(q.resolve()), st.st_mtime_ns, st.st_size) for q in _files(path) for st in [q.stat()])
    parts = (cfg.format, repr(sorted(cfg.rtklib.items())), cfg.imu_time_offset, cfg.imu_to_body.tobytes(),
             cfg.imu_to_body.shape)  # fmt: skip
    return stamp, parts


def load_cached(path: Path, cfg: DatasetConfig) -> tuple[Dataset, bool]:
    """(the log at ``path`` read with ``cfg`` (:func:`ins_hil.datasets.report.load`), whether it came from
    this process's cache). The cache holds the last :data:`CACHE_SIZE` logs by :func:`_parse_key`: a log
    whose file changes (mtime or size) is read again. A replay does not modify its dataset (``prepare``
    copies what it shifts or rotates), so the seeds of one log share it."""
    from ins_hil.datasets import report

    key = _parse_key(path, cfg)
    ds = _CACHE.get(key)
    if ds is not None:
        _CACHE.move_to_end(key)
        return ds, True
    ds = report.load(path, cfg)
    _CACHE[key] = ds
    while len(_CACHE) > CACHE_SIZE:
        _CACHE.popitem(last=False)
    return ds, False


def clear_cache() -> None:
    """Forget this process's parsed logs."""
    _CACHE.clear()


def warm_up(ignore_sigint: bool = False) -> int:
    """Import what every job needs (the core, the readers, the plots' module) in this (worker) process; its pid.
    Not the simulator (``ins_hil.evaluation.sim_flight``, 0.12 CPU s): only a simulated gateway log's truth needs
    it, and :func:`run_job` imports it on demand (``sim_truth_on_demand``). ``ignore_sigint`` (our LocalCluster's
    workers): Ctrl-C in the terminal is the batch's, which collects the jobs that finished and then closes them."""
    from ins_hil.datasets import report  # noqa: F401
    from ins_hil.datasets.plots import plot_series  # noqa: F401

    if ignore_sigint:  # and SIGTERM as Dask's nanny expects it (a forked worker may inherit the CLI's handler)
        try:
            signal.signal(signal.SIGINT, signal.SIG_IGN)
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
        except ValueError:  # not the process's main thread: left as it is
            pass
    return os.getpid()


def run_job(job: Job) -> dict[str, Any]:
    """Replay one job and write its ``metrics.json`` and plots into ``job.out``; its summary row.
    Never raises: an error is the row's ``error``."""
    import json

    from ins_hil.datasets import ihlog, report
    from ins_hil.evaluation import sim_truth_on_demand

    ihlog.set_truth_source(sim_truth_on_demand)  # in this (worker) process: simulated gateway logs get their truth

    t0, c0 = time.perf_counter(), time.process_time()
    row: dict[str, Any] = {"job": job.name, "source": job.source, "config": job.config, "seed": job.seed,
                           "log": job.log, "variant": job.variant or BASELINE, "shift_s": job.shift_s, "core": job.core,
                           "pid": os.getpid()}  # fmt: skip
    try:
        cfg = _config(job)
        ds, row["cached"] = load_cached(_log_path(job, cfg), cfg)
        t1 = time.perf_counter()
        row["load_s"] = t1 - t0
        m, runs = report.replay(ds, cfg, core=job.core)
        t2 = time.perf_counter()
        row["replay_s"] = t2 - t1
        out = Path(job.out)
        out.mkdir(parents=True, exist_ok=True)
        m["plots"] = [str(p) for p in report.plot(m, runs, ds, out)] if job.plots else []
        row["plot_s"] = time.perf_counter() - t2
        m["seed"] = job.seed
        (out / "metrics.json").write_text(json.dumps(report.jsonable(m), indent=2))
        row.update(_row(m))
    except Exception as e:  # a failing log is reported and does not stop the others
        row["error"] = f"{type(e).__name__}: {e}"
    row["elapsed_s"] = time.perf_counter() - t0
    row["cpu_s"] = time.process_time() - c0  # this process's CPU: below elapsed_s when the job waited for a core
    return row


def _row(m: dict[str, Any]) -> dict[str, Any]:
    """The summary columns of one replay's metrics."""
    r: dict[str, Any] = {"dataset": m.get("dataset"), "duration_s": m.get("duration_s"),
                         "imu": m.get("samples", {}).get("imu"), "realtime": m.get("realtime_factor")}  # fmt: skip
    g = m.get("gnss")
    if isinstance(g, dict):
        r["gnss_h_rms_m"] = g.get("gnss_h_rms_prior_m")
        w = g.get("vel_innovation")
        if isinstance(w, dict):
            r["vel_innov_lag1"] = w["lag1"]
    o = m.get("outages")
    if isinstance(o, dict):
        for k in ("outage_h_rms_m", "outage_h_max_m", "hold_h_rms_m", "cv_h_rms_m", "beats_both_in_every_outage"):
            r[k] = o.get(k)
        w = [x for x in o.get("windows", []) if x.get("scored")]
        for k in ("h_rms_m", "hold_h_rms_m", "cv_h_rms_m"):  # per outage, in order
            r[f"each_{k}"] = [x[k] for x in w]
    ob = m.get("onboard")
    if isinstance(ob, dict):
        att = ob.get("attitude_deg")
        if isinstance(att, dict):
            r["onboard_att_rms_deg"] = [att[k]["rms"] for k in ("roll", "pitch", "yaw") if k in att]
    r["warnings"] = len(m.get("warnings", []))
    return r


#: the workers' settings on our LocalCluster: no statistical profiler (a 10-ms stack sample of every running
#: task) and the event-loop watchdog and system monitor at 1 s / 2 s instead of 20 ms / 500 ms: each wakes the
#: worker's event-loop thread, which then takes the GIL from the replay (docs/datasets.md, "Batch replays").
#: On Linux the worker processes are forked, not spawned: they start with this process's imports (Dask,
#: numpy, the readers and the core, already loaded by a serial run) instead of importing them again: 4 logs x
#: 4 seeds on C, 2 workers, the cluster's start, first-job imports and close take 0.2 s instead of 0.7 s
WORKER_CONFIG: dict[str, Any] = {
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "2s",
    **({"distributed.worker.multiprocessing-method": "fork"} if sys.platform.startswith("linux") else {}),
}


def local_cluster(workers: int, worker_config: dict[str, Any] | None = None) -> Any:
    """A ``dask.distributed`` LocalCluster of ``workers`` processes, one thread each, no memory limit, no
    dashboard, with ``worker_config`` (default :data:`WORKER_CONFIG`; ``{}``: Dask's own settings, spawned
    workers). With 2 workers and 12 replays: 1.43–1.67x the serial throughput with Dask's settings, 1.73–1.76x
    with these (docs/datasets.md; ``ins-hil replay --batch … --compare-serial --compare-dask-defaults``). A
    given scheduler keeps its own settings."""
    import dask
    from dask.distributed import LocalCluster

    with dask.config.set(WORKER_CONFIG if worker_config is None else worker_config):  # the Nanny hands them on
        return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                            memory_limit=0)  # fmt: skip


class SchedulerError(ValueError):
    """The Dask scheduler given to :func:`run_batch` cannot be reached (a bad address, nothing listening)."""


class BatchInterrupted(KeyboardInterrupt):
    """Ctrl-C (SIGINT) during :func:`run_batch`: ``rows`` are the jobs that finished (in job order), ``total`` how
    many jobs the batch had, ``wall_s`` the time until the interrupt. Their reports stay in their folders."""

    def __init__(self, rows: list[dict[str, Any]], total: int, wall_s: float) -> None:
        super().__init__(f"interrupted after {len(rows)} of {total} jobs")
        self.rows, self.total, self.wall_s = rows, total, wall_s


def run_batch(
    js: list[Job],
    workers: int = 2,
    scheduler: str | None = None,
    on_done: Callable[[dict[str, Any], int, int], None] | None = None,
    worker_config: dict[str, Any] | None = None,
    known: dict[tuple[str | None, str | None], float] | None = None,
) -> tuple[list[dict[str, Any]], float]:
    """Run ``js``; (rows in job order, wall time s). ``scheduler``: a Dask scheduler address (e.g.
    ``tcp://host:8786``); else a LocalCluster of ``workers`` processes (one thread each, no memory limit,
    ``worker_config`` as :func:`local_cluster`);
    ``workers = 0``: serial here. Either way the jobs start in :func:`order`; on Dask at most one job per
    worker thread is in flight, and a freed worker takes the next by :func:`pick`. ``on_done(row, k, n)`` after
    each job (k done of n). ``known``: the logs' measured costs for the order (:func:`order`). Ctrl-C:
    :class:`BatchInterrupted` with the rows of the jobs that finished (the cluster is closed first)."""
    t0 = time.perf_counter()
    rows: dict[int, dict[str, Any]] = {}
    try:
        return _run_batch(js, workers, scheduler, on_done, worker_config, known, rows, t0)
    except KeyboardInterrupt as e:
        if isinstance(e, BatchInterrupted):
            raise
        raise BatchInterrupted([rows[i] for i in sorted(rows)], len(js), time.perf_counter() - t0) from None


def _run_batch(
    js: list[Job],
    workers: int,
    scheduler: str | None,
    on_done: Callable[[dict[str, Any], int, int], None] | None,
    worker_config: dict[str, Any] | None,
    known: dict[tuple[str | None, str | None], float] | None,
    rows: dict[int, dict[str, Any]],
    t0: float,
) -> tuple[list[dict[str, Any]], float]:
    """:func:`run_batch`, each finished row put into ``rows`` (job index → row) as it comes."""
    seq = order(js, known)
    if scheduler is None and workers == 0:
        for i in seq:
            rows[i] = run_job(js[i])
            if on_done:
                on_done(rows[i], len(rows), len(js))
        return [rows[i] for i in range(len(js))], time.perf_counter() - t0
    from dask.distributed import Client, as_completed

    cluster = local_cluster(workers, worker_config) if scheduler is None else None
    try:
        client = Client(scheduler if scheduler is not None else cluster)
    except (OSError, ValueError, TypeError) as e:
        if cluster is not None:
            cluster.close()
            raise
        raise SchedulerError(f"--scheduler {scheduler}: cannot connect ({' '.join(str(e).split())})") from e
    futs: dict[Any, tuple[int, str | None]] = {}
    try:
        client.run(warm_up, cluster is not None)  # the imports on every worker at once, before the first job
        todo = list(seq)
        held: dict[str | None, list[Hashable]] = {}  # each worker's parsed logs, as its cache holds them
        started: set[Hashable] = set()

        def key(i: int) -> Hashable:
            return js[i].source, js[i].config

        def submit(addr: str | None) -> Any:
            mine = held.setdefault(addr, [])
            i = todo.pop(pick([key(t) for t in todo], mine, started))
            started.add(key(i))
            if key(i) in mine:
                mine.remove(key(i))
            mine[:] = [*mine, key(i)][-CACHE_SIZE:]
            # on that worker (where its log may be parsed); elsewhere if it is gone
            f = client.submit(run_job, js[i], pure=False, workers=[addr] if addr else None, allow_other_workers=True)
            futs[f] = i, addr
            return f

        first: list[str | None] = [a for a, n in sorted(client.nthreads().items()) for _ in range(max(1, n))]
        first = first or [None]  # no worker yet (a scheduler's): the first that joins
        ac = as_completed([submit(a) for a in first[: len(todo)]])
        for f in ac:
            i, addr = futs.pop(f)
            if todo:
                ac.add(submit(addr))
            try:
                rows[i] = f.result()
            except Exception as e:  # the worker died (not a failing log: run_job never raises)
                rows[i] = {"job": js[i].name, "seed": js[i].seed, "error": f"worker: {type(e).__name__}: {e}"}
            if on_done:
                on_done(rows[i], len(rows), len(js))
    except KeyboardInterrupt:  # Ctrl-C: the jobs that finished meanwhile are kept; the running ones are dropped
        for f, (i, _) in list(futs.items()):
            if f.status == "finished":
                try:
                    rows[i] = f.result(timeout=2)
                except Exception:  # gone with its worker: not finished after all
                    continue
                if on_done:
                    on_done(rows[i], len(rows), len(js))
        _close_quietly(client, cluster)
        raise
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    return [rows[i] for i in range(len(js))], time.perf_counter() - t0


def _close_quietly(client: Any, cluster: Any) -> None:
    """Close the client and our cluster after Ctrl-C, its workers killed at once (a worker still in a job does
    not stop for a close: Dask waits, then kills it with a warning) and Dask's shutdown warnings not shown."""
    import logging

    log = logging.getLogger("distributed")
    level = log.level
    log.setLevel(logging.CRITICAL)
    try:
        if cluster is not None:
            for w in list(getattr(cluster, "workers", {}).values()):
                pid = getattr(getattr(getattr(w, "process", None), "process", None), "pid", None)  # the Nanny's worker
                if pid:
                    with contextlib.suppress(OSError):
                        os.kill(pid, signal.SIGKILL)
        client.close(timeout=2)
        if cluster is not None:
            cluster.close(timeout=2)
    except Exception:  # closing after an interrupt: what is left goes with this process
        pass
    finally:
        log.setLevel(level)


def breakdown(rows: list[dict[str, Any]], wall_s: float, workers: int) -> str:
    """One line: the jobs' summed load (parsed / from the cache), replay and plot times (s) and how busy the
    ``workers`` were over ``wall_s`` (the rest: start-up, the imports and the tail's idle worker)."""
    tot = {k: sum(r.get(k, 0.0) for r in rows) for k in ("load_s", "replay_s", "plot_s", "elapsed_s", "cpu_s")}
    hits = sum(1 for r in rows if r.get("cached") is True)
    parsed = sum(1 for r in rows if r.get("cached") is False)
    busy = tot["elapsed_s"] / max(wall_s * max(workers, 1), 1e-9)
    return (f"load {tot['load_s']:.1f} s ({parsed} parsed, {hits} from the cache), replay {tot['replay_s']:.1f} s, "
            f"plots {tot['plot_s']:.1f} s over {len(rows)} jobs (their CPU {tot['cpu_s']:.1f} s); {max(workers, 1)}"
            f" worker(s) x {wall_s:.1f} s wall: {busy:.0%} busy")  # fmt: skip


#: the row keys that are timings or places, not results (they differ between two runs of one job)
TIMING_KEYS = ("elapsed_s", "cpu_s", "load_s", "replay_s", "plot_s", "cached", "pid", "realtime")


def differences(a: list[dict[str, Any]], b: list[dict[str, Any]]) -> list[str]:
    """The jobs whose results differ between two runs of one batch (rows in job order; timings ignored,
    NaN equal to NaN through ``repr``)."""

    def res(r: dict[str, Any]) -> str:
        return repr({k: v for k, v in r.items() if k not in TIMING_KEYS})

    if len(a) != len(b):
        return ["(the batches have different jobs)"]
    return [ra["job"] for ra, rb in zip(a, b, strict=True) if res(ra) != res(rb)]


def _f(x: Any, nd: int = 2) -> str:
    return fmt_value(x, nd, missing="—")


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


def _pooled(rows: list[dict[str, Any]]) -> tuple[float, float]:
    """(RMS, worst) of the outage error over rows (RMS pooled as the root mean of their squares; NaN
    when none has outage figures)."""
    ok = [r for r in rows if r.get("outage_h_rms_m") is not None and "error" not in r]
    if not ok:
        return float("nan"), float("nan")
    rms = float(np.sqrt(np.mean([float(r["outage_h_rms_m"]) ** 2 for r in ok])))
    return rms, float(max(float(r["outage_h_max_m"]) for r in ok))


def variant_table(rows: list[dict[str, Any]]) -> str:
    """The variants side by side (Markdown), one table per log, a row per variant (the config as it is
    first): the outage error RMS / worst (m) at each shift of the protocol over its seeds (RMS pooled, the
    worst of the worst), all shifts pooled, in how many jobs the filter beat both trivial predictors in
    every outage; the GNSS-present error (prior, m RMS), the lag-1 autocorrelation of the GNSS velocity
    innovations (N / E; ``innovation_whiteness``) and the attitude difference to the onboard estimator
    (roll / pitch / yaw, ° RMS), as the mean over the jobs, where the log has them. Empty when the batch has
    neither variants nor shifts."""
    if all(r.get("variant", BASELINE) == BASELINE and not r.get("shift_s") for r in rows):
        return ""
    out: list[str] = []

    def key(r: dict[str, Any]) -> tuple[Any, ...]:  # one log with one config (two folders may share a name)
        return r.get("log", r["job"]), r.get("source"), r.get("config")

    for k in dict.fromkeys(key(r) for r in rows):
        log = k[0]
        mine = [r for r in rows if key(r) == k]
        shifts = sorted({float(r.get("shift_s", 0.0)) for r in mine})
        names = list(dict.fromkeys(r.get("variant", BASELINE) for r in mine))
        outages = any(r.get("outage_h_rms_m") is not None for r in mine)
        gnss = any(r.get("gnss_h_rms_m") is not None for r in mine)
        lag1 = any(r.get("vel_innov_lag1") for r in mine)
        onboard = any(r.get("onboard_att_rms_deg") for r in mine)
        # one protocol (one shift, one seed: a seed moves the outages too): each outage's error as well
        each = (
            len(shifts) == 1
            and any(r.get("each_h_rms_m") for r in mine)
            and all(sum(1 for r in mine if r.get("variant", BASELINE) == n) == 1 for n in names)
        )
        head = ["variant"]
        if outages:
            head += [f"outage shift {s:+g} s" for s in shifts] if len(shifts) > 1 or shifts[0] else ["outage"]
            head += ["pooled", "beats both"] if len(shifts) > 1 else ["beats both"]
            head += ["each outage h RMS m"] * each
        head += ["GNSS h RMS m"] * gnss + ["vel innov lag-1 N / E"] * lag1 + ["vs onboard r / p / y °"] * onboard
        head += ["failed"]
        lines = [f"**{log}**" + (": outage h error RMS / worst (m)" if outages else ""), "",
                 "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]  # fmt: skip
        for n in names:
            vrows = [r for r in mine if r.get("variant", BASELINE) == n]
            ok = [r for r in vrows if "error" not in r]
            cells = [n]
            if outages:
                groups = [[r for r in vrows if r.get("shift_s", 0.0) == sh] for sh in shifts]
                groups += [vrows] if len(shifts) > 1 else []
                for g in groups:
                    rms, mx = _pooled(g)
                    cells.append(f"{_f(rms)} / {_f(mx)}" if not np.isnan(rms) else "—")
                beats = sum(1 for r in ok if r.get("beats_both_in_every_outage") is True)
                cells.append(f"{beats} of {len(vrows)}")
                if each:
                    cells.append(_each(ok[0] if ok else None, "each_h_rms_m"))
            if gnss:
                gh = [float(r["gnss_h_rms_m"]) for r in ok if r.get("gnss_h_rms_m") is not None]
                cells.append(_f(float(np.mean(gh))) if gh else "—")
            if lag1:
                a1 = [r["vel_innov_lag1"] for r in ok if r.get("vel_innov_lag1")]
                cells.append(" / ".join(f"{float(x):+.2f}" for x in np.mean(a1, axis=0)) if a1 else "—")
            if onboard:
                a = [r["onboard_att_rms_deg"] for r in ok if r.get("onboard_att_rms_deg")]
                cells.append(" / ".join(_f(float(x)) for x in np.mean(a, axis=0)) if a else "—")
            cells.append(str(len(vrows) - len(ok)))
            lines.append("| " + " | ".join(cells) + " |")
        one = next((r for r in mine if "error" not in r and r.get("each_h_rms_m")), None)
        if each and one:  # the trivial predictors use the GNSS only: one line for every variant
            lines += ["", f"Each outage, hold the last fix: {_each(one, 'each_hold_h_rms_m')} m; constant-velocity "
                          f"extrapolation: {_each(one, 'each_cv_h_rms_m')} m (h RMS)."]  # fmt: skip
        out.append("\n".join(lines))
    return "\n\n".join(out)


def _each(row: dict[str, Any] | None, key: str) -> str:
    """A job row's ``key`` list (m, per outage) as "a / b / c"; "—" without."""
    x = row.get(key) if row else None
    return " / ".join(_f(float(v)) for v in x) if x else "—"
