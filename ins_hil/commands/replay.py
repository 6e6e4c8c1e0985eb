"""`ins-hil replay`: run the navigation core offline and report its accuracy (argument parsing and printing;
the library is :mod:`ins_hil.datasets`).

SOURCE is one of
* a simulated scenario name (``static``, ``example32``, ``example32_gnss``, ``coning``, ``uav``;
  see :mod:`ins_hil.sim.scenarios`), replayed against its truth (:mod:`ins_hil.datasets.simulated`),
* ``drive``: the protocol study of the real drive through its dataset config
  (``configs/datasets/drive0708.toml``, :mod:`ins_hil.datasets.study`): the outage protocol with and without
  ground-vehicle aids plus a run with GNSS all the time,
* a flight log / dataset file or folder (PX4 .ulg, PX4 ulog2csv folder, ArduPilot .bin or .log, an RTKLIB folder,
  an ins-hil dataset CSV, a gateway log with ``--dataset``), with ``--dataset CONFIG`` (:mod:`ins_hil.datasets.report`),
* a recorded gateway log (``*.ihlog``) without ``--dataset``, handed to ``ins_hil.evaluation.sim_flight.replay_log``,
* ``sim``: the ``[sim]`` flight of ``--config`` (default ``configs/default.toml``) through its pipeline,
  offline, over ``--runs`` seeds: bias, RMS, NEES, 3σ coverage (``ins_hil.evaluation.sim_flight.sim_cli``).

Writes ``metrics.json`` and PNG plots to ``--out`` and prints a summary table. ``--docs``
runs the full report (real drive, Example 3.2, UAV mission, Monte-Carlo NEES/NIS, hot-path
timing) and regenerates ``docs/accuracy.md`` with its plots in ``docs/accuracy/``.
"""

from __future__ import annotations

import argparse
import functools
import importlib
import json
import math
import os
import sys
import time
import tomllib
from pathlib import Path
from typing import Any

from ins_hil.commands._inputs import HINTS, config_kind
from ins_hil.commands._outputs import out_dir, out_file
from ins_hil.datasets.config import DatasetConfigError
from ins_hil.datasets.config import load as load_dataset_config
from ins_hil.datasets.dataset import DatasetError

# The simulator, the scenarios, the drive study, the accuracy report and the plots are imported where they run:
# a flight log / dataset replay (``--dataset``) does not load them.

NAME = "replay"
HELP = "run the core offline on a scenario, the real drive, a flight log or a gateway log; write metrics and plots"

REPO = Path(__file__).resolve().parents[2]
#: the dataset config of ``ins-hil replay drive``
DRIVE_CONFIG = REPO / "configs" / "datasets" / "drive0708.toml"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("source", nargs="?", default="drive",
                   help="scenario name, 'drive' (configs/datasets/drive0708.toml), 'sim', a *.ihlog, or a flight "
                   "log / dataset file or folder (PX4 .ulg, PX4 ulog2csv folder, ArduPilot .bin or .log, RTKLIB "
                   "folder, ins-hil dataset CSV; a *.ihlog with --dataset)")  # fmt: skip
    p.add_argument("--dataset", type=Path, default=None, metavar="CONFIG",
                   help="dataset config (configs/datasets/*.toml): format, mounting, lever arms, time offsets, "
                   "sensor grade, [nav] overrides, outage protocol")  # fmt: skip
    p.add_argument("--core", choices=("python", "c"), default="python",
                   help="navigation core of a flight log / dataset replay (and --batch): python (default) or c, the "
                   "C reference core (aligned by the Python core, then handed over; a setting it lacks is refused "
                   "in one line)")  # fmt: skip
    p.add_argument("--out", type=Path, default=Path("replay_out"), help="output directory (default ./replay_out)")
    p.add_argument("--seed", type=int, default=0, help="random seed of a simulated scenario")
    p.add_argument("--duration", type=float, default=None, help="scenario length in s (default: the scenario's)")
    p.add_argument("--runs", type=int, default=0, help="Monte-Carlo runs for the NEES/NIS check (simulations)")
    p.add_argument("--no-aids", action="store_true", help="real drive: skip the run with ZUPT/NHC")
    p.add_argument("--no-plots", action="store_true", help="do not write PNG plots")
    p.add_argument("--export", type=Path, default=None, metavar="CSV",
                   help="write the trajectory (a flight log / dataset: its GNSS-present replay; a *.ihlog: every "
                   "state of the pipeline replay) as CSV: time, lat, lon, h, vN, vE, vD, roll, pitch, yaw and the "
                   "1-sigma of each (ins_hil.datasets.export)")  # fmt: skip
    p.add_argument("--docs", action="store_true", help="full report: regenerate docs/accuracy.md and its plots")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    p.add_argument(
        "--config", type=Path, default=None, help="source 'sim': the config whose [sim] flight is flown (default.toml)"
    )
    b = p.add_argument_group("batch replays on Dask (ins_hil.evaluation.batch)")
    b.add_argument(
        "--batch",
        nargs="+",
        metavar="ENTRY",
        default=None,
        help="replay many: dataset TOMLs (with their dataset.path), logs, folders or globs; each log with "
        "--dataset (else the defaults); reports in --out, one folder per job, plus batch.md/batch.json",
    )
    b.add_argument(
        "--seeds",
        type=int,
        default=1,
        metavar="N",
        help="batch: Monte-Carlo seeds per log (seed k > 0 shifts the outage protocol; default 1)",
    )
    b.add_argument(
        "--workers",
        type=int,
        default=2,
        metavar="N",
        help="batch: LocalCluster worker processes (default 2; 0 = one after the other, in-process)",
    )
    b.add_argument(
        "--scheduler",
        default=None,
        metavar="ADDR",
        help="batch: an existing Dask scheduler (e.g. tcp://host:8786) instead of a LocalCluster",
    )
    b.add_argument(
        "--variants",
        type=Path,
        default=None,
        metavar="FILE",
        help="batch: config variants (configs/variants/*.toml: each table a name and dataset-config tables "
        "merged over each log's config); every log runs as configured and with each, side by side",
    )
    b.add_argument(
        "--shifts",
        type=float,
        nargs="+",
        default=None,
        metavar="S",
        help="batch: run the outage protocol moved by each of these s (selection windows, e.g. -10 15)",
    )
    b.add_argument(
        "--compare-serial",
        action="store_true",
        help="batch: first run the same jobs one after the other in this process (reports in OUT/serial), then "
        "on Dask; print both wall times, their ratio and whether every job gave the same results",
    )
    b.add_argument(
        "--compare-dask-defaults",
        action="store_true",
        help="batch: also run the jobs on a LocalCluster with Dask's own worker settings (profiler, 20-ms "
        "tick) and print both wall times side by side (with --compare-serial: both ratios)",
    )
    o = p.add_argument_group("IMU time offset and mounting yaw from the data (ins_hil.datasets.offset)")
    o.add_argument(
        "--estimate-offset",
        action="store_true",
        help="estimate the IMU-GNSS time offset of a log (needs GNSS): 5-s outages scored over a grid",
    )
    o.add_argument("--offset-span", type=float, default=0.2, metavar="S", help="search ± this around the config's")
    o.add_argument("--offset-step", type=float, default=0.02, metavar="S", help="grid step of the search")
    o.add_argument(
        "--write-offset",
        action="store_true",
        help="write the estimate into the --dataset config ([mounting] imu_time_offset_s)",
    )
    o.add_argument(
        "--estimate-mounting",
        action="store_true",
        help="estimate the IMU mounting yaw (about body z, after the config's rotations): 5-s outages scored "
        "over a grid; observable with a ground vehicle's NHC, said when the log cannot tell",
    )
    o.add_argument("--mounting-span", type=float, default=5.0, metavar="DEG", help="search ± this around the config's")
    o.add_argument("--mounting-step", type=float, default=0.5, metavar="DEG", help="grid step of the search")
    o.add_argument(
        "--write-mounting",
        action="store_true",
        help="write the estimate into the --dataset config (the yaw of [mounting] imu_to_body_deg's last rotation)",
    )


# ---------------------------------------------------------------------------------------------- helpers
class _Progress:
    """A minimal progress line on stderr (long runs): a bar redrawn every 5 % on a terminal; in a log (stderr not a
    terminal) a line at 0, 25, 50, 75 and 100 %."""

    def __init__(self, label: str, quiet: bool) -> None:
        self.label = label
        self.quiet = quiet
        self.t0 = time.perf_counter()
        self.last = -1
        self.tty = sys.stderr.isatty()

    def __call__(self, k: int, n: int) -> None:
        if self.quiet:
            return
        pct = int(100 * k / max(n, 1))
        step = 5 if self.tty else 25
        if pct // step != self.last // step or (k == n and self.last != 100):
            self.last = pct
            bar = "#" * (pct // 5) + "." * (20 - pct // 5)
            el = time.perf_counter() - self.t0
            line = f"{self.label:<28} [{bar}] {pct:3d}% {el:6.1f} s"
            sys.stderr.write(f"\r{line}" + ("\n" if k == n else "") if self.tty else line + "\n")
            sys.stderr.flush()


def _progress(quiet: bool) -> Any:
    """A ``ins_hil.datasets.simulated.ProgressFactory`` of :class:`_Progress` lines."""
    return lambda label: _Progress(label, quiet)


def _is_scenario(src: str) -> bool:
    """``src`` names a simulated scenario (``ins_hil.sim.scenarios.NAMES``; imported only for a bare name)."""
    if src == "drive" or "/" in src or "." in src:
        return False
    from ins_hil.sim import scenarios

    return src in scenarios.NAMES


def run_scenario(name: str, seed: int, duration: float | None, quiet: bool) -> tuple[dict[str, Any], Any, Any]:
    """A simulated scenario against its truth (:func:`ins_hil.datasets.simulated.run_scenario`)."""
    from ins_hil.datasets import simulated
    from ins_hil.sim import scenarios

    sc = scenarios.build(name, seed=seed, duration=duration)
    return simulated.run_scenario(sc, name, seed, _Progress(f"{name} seed {seed}", quiet))


def monte_carlo(name: str, runs: int, duration: float | None, quiet: bool) -> dict[str, Any]:
    """:func:`ins_hil.datasets.simulated.monte_carlo` over ``runs`` seeds of the scenario ``name``."""
    from ins_hil.datasets import simulated
    from ins_hil.sim import scenarios

    return simulated.monte_carlo(lambda seed: scenarios.build(name, seed=seed, duration=duration), name, runs,
                                 _progress(quiet))  # fmt: skip


def replay_drive(aids_variants: tuple[bool, ...], quiet: bool, full: bool = False) -> tuple[dict[str, Any], Any]:
    """The drive's protocol study through :data:`DRIVE_CONFIG` (:func:`ins_hil.datasets.study.study`)."""
    from ins_hil.datasets import study

    cfg = load_dataset_config(DRIVE_CONFIG)
    res, series = study.study(cfg, None, aids_variants, _progress(quiet), full)
    res["config"] = str(DRIVE_CONFIG.relative_to(REPO))
    res["source_rel"] = os.path.relpath(str(res["source"]), REPO)
    return res, series


# ---------------------------------------------------------------------------------------------- main
def _print_table(rows: list[tuple[str, str, str, str]]) -> None:
    w = [max(len(r[i]) for r in rows) for i in range(4)]
    for r in rows:
        print("  ".join(c.ljust(w[i]) for i, c in enumerate(r)))


def _runtime_replay() -> Any:
    """The gateway-log replayer (``ins_hil.runtime.replay``, with the simulator's truth for a simulated
    run: ``ins_hil.evaluation.sim_flight``), imported on demand."""
    return importlib.import_module("ins_hil.evaluation.sim_flight")


def _last_costs(path: Path) -> dict[tuple[str | None, str | None], float] | None:
    """The logs' measured replay times of the batch summary at ``path`` (``batch.measured`` of its rows), or None
    (no summary, or one this cannot read: the jobs are then ordered by the logs' sizes)."""
    from ins_hil.evaluation import batch

    try:
        rows = json.loads(path.read_text()).get("rows")
    except (OSError, ValueError, AttributeError):
        return None
    return batch.measured(rows) if isinstance(rows, list) and all(isinstance(r, dict) for r in rows) else None


def _batch(args: argparse.Namespace) -> int:
    """``--batch``: every entry × ``--seeds`` on Dask; a summary table and each job's report
    (``--compare-serial``: the same jobs serially first, and the speed-up)."""
    from ins_hil.evaluation import batch

    seeds = args.seeds
    try:
        pairs = batch.expand(list(args.batch), str(args.dataset) if args.dataset else None)
        variants = batch.load_variants(args.variants) if args.variants is not None else None
        js = batch.jobs(
            pairs, seeds, args.out, not args.no_plots, variants, args.shifts, getattr(args, "core", "python")
        )
    except (DatasetError, DatasetConfigError) as e:
        print(f"ins-hil replay: {e}", file=sys.stderr)
        return 2
    if args.dataset is not None and pairs and all(src is None for src, _ in pairs):
        print(f"ins-hil replay: --dataset {args.dataset}: every --batch entry is a dataset config with its own "
              "settings (--dataset is for logs given to --batch)", file=sys.stderr)  # fmt: skip
        return 2
    missing = batch.missing_logs(js)
    if missing:
        more = f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""
        print(f"ins-hil replay: batch: {missing[0]}{more}", file=sys.stderr)
        return 2
    subs = ["serial"] * args.compare_serial + ["dask_defaults"] * args.compare_dask_defaults
    for folder in [j.out for j in js] + [str(args.out / s) for s in subs]:  # each job's folder: before any job runs
        out_dir(folder, "--out")
    for name in ("batch.md", "batch.json"):
        out_file(args.out / name, "--out")
    parallel = args.scheduler is not None or args.workers > 0
    if args.compare_serial and not parallel:
        print("ins-hil replay: --compare-serial needs --workers > 0 or --scheduler", file=sys.stderr)
        return 2
    if args.compare_dask_defaults and (args.scheduler is not None or args.workers == 0):
        print("ins-hil replay: --compare-dask-defaults needs our LocalCluster (--workers > 0, no --scheduler)",
              file=sys.stderr)  # fmt: skip
        return 2
    where = args.scheduler or (f"LocalCluster of {args.workers} workers" if args.workers > 0 else "serially")
    if not args.quiet:
        what = f"{len(pairs)} logs x {seeds} seeds"
        if variants:
            what += f" x {len(variants) + 1} variants"
        if args.shifts:
            what += f" x {len(args.shifts)} shifts"
        print(f"batch: {len(js)} replays ({what}), {where}", file=sys.stderr)

    def done(row: dict[str, Any], k: int, n: int) -> None:
        if not args.quiet:
            status = row.get("error") or "ok"
            print(f"  [{k}/{n}] {row['job']}: {status} ({row.get('elapsed_s', 0.0):.1f} s)", file=sys.stderr)

    def reference_run(what: str, sub: str, workers: int, worker_config: dict[str, Any] | None) -> dict[str, Any]:
        """The same jobs once more, for a comparison (in ``--out``/``sub``): their rows, wall time, breakdown."""
        if not args.quiet:
            print(f"batch: {what}", file=sys.stderr)
        ref_jobs = batch.jobs(
            pairs, seeds, args.out / sub, not args.no_plots, variants, args.shifts, getattr(args, "core", "python")
        )
        ref_rows, ref_wall = batch.run_batch(ref_jobs, workers, None, done, worker_config=worker_config,
                                             known=known)  # fmt: skip
        return {"rows": ref_rows, "wall_s": ref_wall, "breakdown": batch.breakdown(ref_rows, ref_wall, max(workers, 1))}

    # the logs' replay times of the last run into this folder (its batch.json): the order of the jobs
    known = _last_costs(args.out / "batch.json")
    serial: dict[str, Any] | None = None
    defaults: dict[str, Any] | None = None
    phase = ""
    try:
        if args.compare_serial:
            phase = f"serially: --compare-serial's reference run, reports in {args.out / 'serial'}"
            serial = reference_run("serially first (--compare-serial)", "serial", 0, None)
            batch.clear_cache()  # the parallel run parses in its own workers; free this process's copies
            known = batch.measured(serial["rows"])  # the same jobs' times, just measured
        if args.compare_dask_defaults:
            phase = f"Dask's worker settings: --compare-dask-defaults' run, reports in {args.out / 'dask_defaults'}"
            defaults = reference_run("on a LocalCluster with Dask's own worker settings (--compare-dask-defaults)",
                                     "dask_defaults", args.workers, {})  # fmt: skip
        phase = ""
        rows, wall = batch.run_batch(js, args.workers, args.scheduler, done, known=known)
    except batch.BatchInterrupted as e:
        return _batch_interrupted(args, e, phase or where)
    except batch.SchedulerError as e:
        print(f"ins-hil replay: {e}", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    text = batch.table(rows)
    failed = sum("error" in r for r in rows)
    n_workers = args.workers if args.scheduler is None else len({r.get("pid") for r in rows})
    tail = f"{len(rows)} replays in {wall:.1f} s wall ({where}); {failed} failed"
    lines = [tail, batch.breakdown(rows, wall, n_workers if parallel else 1)]
    summary: dict[str, Any] = {"rows": rows, "wall_s": wall, "where": where}
    if serial is not None:
        diff = batch.differences(serial["rows"], rows)
        ratio = serial["wall_s"] / max(wall, 1e-9)
        same = "every job the same results" if not diff else f"results differ: {', '.join(diff)}"
        lines += [f"serial {serial['wall_s']:.1f} s, parallel {wall:.1f} s ({where}): {ratio:.2f}x; {same}",
                  f"serial: {serial['breakdown']}"]  # fmt: skip
        summary["compare_serial"] = {"serial_wall_s": serial["wall_s"], "parallel_wall_s": wall, "ratio": ratio,
                                     "differences": diff, "serial_rows": serial["rows"]}  # fmt: skip
    side = batch.variant_table(rows)
    if side:
        text += "\n\n" + side
        summary["variants"] = [batch.BASELINE] + [n for n, _ in variants or []]
        summary["shifts_s"] = args.shifts or [0.0]
    if defaults is not None:
        diff = batch.differences(defaults["rows"], rows)

        def vs_serial(w: float) -> str:
            return f" ({serial['wall_s'] / max(w, 1e-9):.2f}x serial)" if serial is not None else ""

        same = "the same results" if not diff else f"results differ: {', '.join(diff)}"
        lines += [f"Dask's worker settings {defaults['wall_s']:.1f} s{vs_serial(defaults['wall_s'])}, ours "
                  f"(batch.WORKER_CONFIG) {wall:.1f} s{vs_serial(wall)}: {defaults['wall_s'] / max(wall, 1e-9):.2f}x; "
                  f"{same}", f"Dask's worker settings: {defaults['breakdown']}"]  # fmt: skip
        summary["compare_dask_defaults"] = {"defaults_wall_s": defaults["wall_s"], "ours_wall_s": wall,
                                            "differences": diff, "defaults_rows": defaults["rows"]}  # fmt: skip
    (args.out / "batch.md").write_text("# Batch replay\n\n" + text + "\n\n" + "\n\n".join(lines) + "\n")
    (args.out / "batch.json").write_text(json.dumps(summary, indent=2, default=str))
    print(text)
    print("\n".join(lines))
    print(f"summary: {args.out / 'batch.md'}")
    differ = any(summary.get(k, {}).get("differences") for k in ("compare_serial", "compare_dask_defaults"))
    return 1 if failed or differ else 0


def _batch_interrupted(args: argparse.Namespace, e: Any, where: str) -> int:
    """Ctrl-C during a batch: the jobs that finished (``e``: ``batch.BatchInterrupted``) kept as its summary
    (``batch.md``, ``batch.json`` with ``"interrupted": true``; each job's report stays in its folder), their
    table printed, one line on stderr; exit status 130."""
    from ins_hil.evaluation import batch

    rows = e.rows
    head = f"Interrupted (Ctrl-C) after {e.wall_s:.1f} s ({where}): {len(rows)} of {e.total} replays finished."
    text = batch.table(rows) if rows else "(no replay finished)"
    summary = {"rows": rows, "wall_s": e.wall_s, "where": where, "interrupted": True, "jobs": e.total}
    try:
        if not rows:  # an earlier summary in --out (the jobs' measured costs) is not replaced by an empty one
            raise OSError("no replay finished")
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "batch.md").write_text("# Batch replay\n\n" + head + "\n\n" + text + "\n")
        (args.out / "batch.json").write_text(json.dumps(summary, indent=2, default=str))
        kept = f"kept in {args.out / 'batch.md'}"
    except OSError as err:
        kept = f"no summary written ({err})"
    if rows:
        print(text)
    print(f"ins-hil replay: interrupted: {len(rows)} of {e.total} replays finished, {kept}", file=sys.stderr)
    return 130


def _estimate(src: str, args: argparse.Namespace) -> int:
    """``--estimate-offset`` / ``--estimate-mounting``: the IMU time offset or mounting yaw of one log, optionally
    written into its dataset config."""
    from ins_hil.datasets import report
    from ins_hil.datasets.config import DatasetConfig
    from ins_hil.datasets.offset import estimate_imu_offset, estimate_mounting_yaw, write_mounting_yaw, write_offset

    mounting = args.estimate_mounting
    write, flag = (args.write_mounting, "--write-mounting") if mounting else (args.write_offset, "--write-offset")
    try:
        cfg = load_dataset_config(args.dataset) if args.dataset else DatasetConfig(name=Path(src).stem)
        path = cfg.path if (src == "drive" and args.dataset is not None) or not src else Path(src)
        if path is None:
            raise DatasetConfigError(f"{args.dataset}: no dataset.path and no FILE|DIR given")
        ds = report.load(Path(path), cfg)
        if mounting:
            est = estimate_mounting_yaw(ds, cfg, span=math.radians(args.mounting_span),
                                        step=math.radians(args.mounting_step),
                                        progress=_Progress("mounting grid", args.quiet))  # fmt: skip
        else:
            est = estimate_imu_offset(ds, cfg, span_s=args.offset_span, step_s=args.offset_step,
                                      progress=_Progress("offset grid", args.quiet))  # fmt: skip
    except (DatasetError, ValueError) as e:
        print(f"ins-hil replay: {e}", file=sys.stderr)
        return 2
    print(est.summary())
    print("\n".join(est.table()))
    if write:
        if args.dataset is None or math.isnan(est.value):
            print(f"ins-hil replay: {flag} needs --dataset and an estimate", file=sys.stderr)
            return 2
        if mounting:
            write_mounting_yaw(args.dataset, cfg, est.value)
            print(f"written: {args.dataset} [mounting] imu_to_body_deg, yaw {math.degrees(est.value):.2f}°")
        else:
            write_offset(args.dataset, est.value)
            print(f"written: {args.dataset} [mounting] imu_time_offset_s = {est.value:.4f}")
    return 0


#: the longest simulated scenario (s): its truth is held in memory, ~0.25 MB per simulated s at 100 Hz (static,
#: 60 s vs 200 s: 56 vs 90 MB peak RSS), ~0.5 MB/s for coning at 200 Hz; 1 h is ~1-2 GB and ~2 min of CPU
MAX_SIM_DURATION_S = 3600.0


def _argument_error(src: str, args: argparse.Namespace) -> str | None:
    """Why these arguments cannot run as given (one line naming the flag), or None: values out of range and
    options the chosen mode would ignore silently, refused before anything is loaded."""
    batch = bool(args.batch) or args.variants is not None or bool(args.shifts)
    estimate = args.estimate_offset or args.estimate_mounting
    simulated = not batch and not estimate and not args.docs and (src == "sim" or _is_scenario(src))
    if args.batch and src != "drive":
        return f"a SOURCE ({src}) and --batch: give every log to --batch"
    if args.seeds < 1:
        return f"--seeds {args.seeds}: must be ≥ 1"
    if args.workers < 0:
        return f"--workers {args.workers}: must be ≥ 0 (0 = one after the other, in this process)"
    cpus = os.cpu_count() or 1
    if args.workers > 4 * cpus:  # each a process with the readers, the core and a parsed log (~0.2 GB)
        return f"--workers {args.workers}: at most {4 * cpus} (4 x this machine's {cpus} CPUs)"
    if not batch:
        given = [f for f, on in (("--seeds", args.seeds != 1), ("--workers", args.workers != 2),
                                 ("--scheduler", args.scheduler is not None), ("--compare-serial", args.compare_serial),
                                 ("--compare-dask-defaults", args.compare_dask_defaults)) if on]  # fmt: skip
        if given:
            return f"{given[0]}: only with --batch (or --variants / --shifts)"
    elif args.export is not None:
        return "--export: one log's trajectory, not with --batch / --variants / --shifts"
    elif estimate or args.docs:
        flag = "--docs" if args.docs else "--estimate-offset" if args.estimate_offset else "--estimate-mounting"
        return f"{flag}: not with --batch / --variants / --shifts"
    if args.export is not None and (simulated or estimate or args.docs or (src == "drive" and args.dataset is None)):
        return "--export: the trajectory of a flight log / dataset replay or of a *.ihlog only"
    if args.shifts and not all(math.isfinite(x) for x in args.shifts):
        return f"--shifts {' '.join(f'{x:g}' for x in args.shifts)}: must be finite"
    if args.duration is not None:
        if not simulated:
            return "--duration: only for a simulated scenario or 'sim' (a log replays whole)"
        if not 0.0 < args.duration <= MAX_SIM_DURATION_S:
            return (f"--duration {args.duration:g}: must be > 0 and at most {MAX_SIM_DURATION_S:g} s (a simulated "
                    "scenario keeps its whole truth in memory)")  # fmt: skip
    if args.runs < 0:
        return f"--runs {args.runs}: must be ≥ 0"
    if args.runs and not simulated:
        return "--runs: only for a simulated scenario or 'sim' (--batch --seeds for a log)"
    if args.write_offset and not args.estimate_offset:
        return "--write-offset: only with --estimate-offset"
    if args.write_mounting and not args.estimate_mounting:
        return "--write-mounting: only with --estimate-mounting"
    grids = (("offset", args.offset_span, args.offset_step, args.estimate_offset),
             ("mounting", args.mounting_span, args.mounting_step, args.estimate_mounting))  # fmt: skip
    for flag, span, step, on in grids:
        if on and not (math.isfinite(span) and math.isfinite(step) and step > 0 and span >= 2 * step):
            return f"--{flag}-span {span:g} --{flag}-step {step:g}: need a step > 0 and a span ≥ 2 steps"
    if args.config is not None:
        if src != "sim" or batch:
            return "--config: only for 'sim' (a gateway config's [sim] flight); a log's settings: --dataset CONFIG"
        if not args.config.is_file():
            return f"--config {args.config}: " + ("a folder" if args.config.is_dir() else "no such file")
        try:
            tomllib.loads(args.config.read_text(encoding="utf-8"))
        except (OSError, ValueError) as e:  # (the sim flight's own message goes to stdout)
            return f"--config {args.config}: not a readable TOML file ({' '.join(str(e).split())})"
    if args.dataset is not None and args.dataset.is_dir():
        return f"--dataset {args.dataset}: a folder; give a dataset config (configs/datasets/*.toml)"
    if args.dataset is not None and config_kind(args.dataset) == "gateway":
        return f"--dataset {args.dataset}: {HINTS['gateway']}; a dataset config has a [dataset] table"
    if src == "sim" and args.config is not None and config_kind(args.config) == "dataset":
        return f"--config {args.config}: {HINTS['dataset']}"
    return None


def run(args: argparse.Namespace) -> int:
    src = str(args.source)
    why = _argument_error(src, args)
    if why is not None:
        print(f"ins-hil replay: {why}", file=sys.stderr)
        return 2
    if not args.batch and (args.variants is not None or args.shifts):  # one log's variants: a batch of one
        args.batch = [str(args.dataset) if args.dataset is not None and src == "drive" else src]
        if args.dataset is not None and src == "drive":
            args.dataset = None
    _check_outputs(src, args)
    if args.batch:
        return _batch(args)
    core = getattr(args, "core", "python")
    if core != "python" and ((src == "drive" and args.dataset is None) or src == "sim" or _is_scenario(src)
                             or args.estimate_offset or args.estimate_mounting
                             or (src.endswith(".ihlog") and args.dataset is None)):  # fmt: skip
        print(f"ins-hil replay: --core {core}: only a flight log / dataset replay (--dataset) or --batch runs "
              "on it", file=sys.stderr)  # fmt: skip
        return 2
    if args.estimate_offset or args.estimate_mounting:
        if args.estimate_offset and args.estimate_mounting:
            print("ins-hil replay: --estimate-offset and --estimate-mounting: one at a time", file=sys.stderr)
            return 2
        return _estimate(src, args)
    if src.endswith(".ihlog") and args.dataset is None:  # the exact pipeline replay (with --dataset: a data set)
        try:
            mod = _runtime_replay()
        except ImportError:
            print("ins-hil replay: gateway-log replay needs ins_hil.runtime.replay (not installed)", file=sys.stderr)
            return 2
        if args.export is None:
            return int(mod.replay_log(Path(src), args) or 0)
        from ins_hil.datasets import export

        states: list[Any] = []
        rc = int(mod.replay_log(Path(src), args, on_state=states.append) or 0)
        path = export.write_csv(args.export, export.rows_from_states(states))
        print(f"trajectory: {path} ({len(states)} states)")
        return rc
    if src == "sim":  # the [sim] flight of a config through its pipeline, over --runs seeds from --seed
        return int(_runtime_replay().sim_cli(args))
    if args.docs:
        return full_report(args)
    if _is_dataset(src, args):
        return _replay_dataset(src, args)
    args.out.mkdir(parents=True, exist_ok=True)
    from ins_hil.datasets import study
    from ins_hil.datasets.accuracy_md import fmt_value
    from ins_hil.datasets.plots import plot_series
    from ins_hil.sim import scenarios

    if src in scenarios.NAMES:
        m, ser, _ = run_scenario(src, args.seed, args.duration, args.quiet)
        out: dict[str, Any] = {"scenario": m}
        if args.runs > 0:
            out["monte_carlo"] = monte_carlo(src, args.runs, args.duration, args.quiet)
        if not args.no_plots:
            out["plots"] = [str(p) for p in plot_series(ser, src, args.out / src)]
        rows = [("quantity", "N/roll", "E/pitch", "D/yaw")]
        for k in ("att_rms_deg", "att_max_deg", "vel_rms_mps", "pos_rms_m", "pos_max_m"):
            if k in m:
                rows.append((k, fmt_value(m[k][0], 4), fmt_value(m[k][1], 4), fmt_value(m[k][2], 4)))
        _print_table(rows)
        print(f"realtime factor {m['realtime_factor']:.1f}x, NEES mean (9 dof) {m['nees_mean_9dof']:.2f}")
        if "monte_carlo" in out:
            mc = out["monte_carlo"]
            lo, hi = mc["anees_bounds_95"]
            print(f"Monte-Carlo {mc['runs']} runs: ANEES {mc['anees_mean']:.2f} (95 % bounds {lo:.2f}–{hi:.2f}), "
                  f"inside {mc['fraction_inside']:.0%}")  # fmt: skip
    elif src == "drive":
        try:
            res, series = replay_drive((False,) if args.no_aids else (True, False), args.quiet)
        except (DatasetError, DatasetConfigError, ValueError) as e:
            print(f"ins-hil replay: {e}", file=sys.stderr)
            return 2
        out = {"drive": res}
        if not args.no_plots:
            out["plots"] = []
            outs = study.absolute_windows(res)
            for label, ser in series.items():
                out["plots"] += [str(p) for p in plot_series(ser, f"drive {label}", args.out / f"drive_{label}", outs)]
        _print_drive(res)
    else:
        print(f"ins-hil replay: unknown source {src!r} (scenarios: {', '.join(scenarios.NAMES)}, 'drive', 'sim', "
              "a flight log or dataset file or folder, or a *.ihlog)", file=sys.stderr)  # fmt: skip
        return 2
    (args.out / "metrics.json").write_text(json.dumps(out, indent=2, default=float))
    print(f"metrics: {args.out / 'metrics.json'}")
    return 0


def _check_outputs(src: str, args: argparse.Namespace) -> None:
    """Refuse, before any work, an ``--out`` folder or ``--export`` file this run would write and cannot
    (:mod:`ins_hil.commands._outputs`, one line). A gateway-log replay (``*.ihlog`` without ``--dataset``), an
    estimate and ``--docs`` write no ``--out``."""
    if args.export is not None:
        out_file(args.export, "--export")
    if args.batch or not (args.docs or args.estimate_offset or args.estimate_mounting
                          or (src.endswith(".ihlog") and args.dataset is None)):  # fmt: skip
        out_dir(args.out, "--out")


def _is_dataset(src: str, args: argparse.Namespace) -> bool:
    """A flight log / dataset source: a --dataset config, or any file or folder (a reader detects it, else the
    dataset path says what is expected), or a path that does not exist (the dataset path says so)."""
    if getattr(args, "dataset", None) is not None:
        return True
    if src == "drive" or _is_scenario(src):
        return False
    return Path(src).exists() or "/" in src or Path(src).suffix != ""


def _replay_dataset(src: str, args: argparse.Namespace) -> int:
    from ins_hil.datasets import ihlog, report
    from ins_hil.datasets.dataset import DatasetError
    from ins_hil.evaluation import sim_truth_on_demand

    ihlog.set_truth_source(sim_truth_on_demand)  # a simulated gateway log is scored against its regenerated truth

    from ins_hil.datasets.run import ReplayError

    source = None if (args.dataset is not None and src == "drive") else Path(src)
    try:
        _, text = report.replay_to_dir(source, args.dataset, args.out, not args.no_plots,
                                       lambda label: _Progress(label, args.quiet), export=args.export,
                                       core=getattr(args, "core", "python"))  # fmt: skip
    except ReplayError as e:  # read, but no figures: non-finite states, a numerical failure, no valid IMU data
        print(f"ins-hil replay: {_one_line(e)}", file=sys.stderr)
        return 1
    except (DatasetError, ValueError) as e:
        print(f"ins-hil replay: {_one_line(e)}", file=sys.stderr)
        return 2
    except RuntimeError as e:  # the core cannot be built (--core c: a setting the C core lacks)
        if not str(e).startswith("core "):
            raise
        print(f"ins-hil replay: {_one_line(e)}", file=sys.stderr)
        return 2
    except (KeyboardInterrupt, SystemExit):
        raise
    except Exception as e:  # still one line naming the recording (INS_HIL_DEBUG=1 / --debug: the traceback)
        if getattr(args, "debug", False) or os.environ.get("INS_HIL_DEBUG", "") not in ("", "0"):
            raise
        what = source if source is not None else args.dataset
        print(f"ins-hil replay: {what}: the replay failed ({type(e).__name__}: {_one_line(e)})", file=sys.stderr)
        return 1
    print(text)
    return 0


def _one_line(e: BaseException) -> str:
    t = " ".join(str(e).split()) or type(e).__name__
    return t if len(t) <= 300 else t[:297] + "..."


def _print_drive(res: dict[str, Any]) -> None:
    rows = [("run", "outage h RMS / max (m)", "GNSS-present h RMS prior/post (m)", "speed (x real time)")]
    for tag in ("aids", "no_aids"):
        o, g = res.get(f"outages_{tag}"), res.get(f"gnss_{tag}")
        if o is None or g is None:
            continue
        rows.append(
            (tag, f"{o['outage_h_rms_m']:.2f} / {o['outage_h_max_m']:.2f}",
             f"{g['gnss_h_rms_prior_m']:.3f} / {g['gnss_h_rms_post_m']:.3f}",
             f"{o['realtime_factor']:.1f}")
        )  # fmt: skip
    _print_table(rows)


#: the shipped flight logs of docs/accuracy.md (configs/datasets/NAME.toml)
FLIGHT_LOGS = ("px4_hover", "px4_quad", "ardupilot_copter")


def _log_progress(name: str, quiet: bool, label: str) -> _Progress:
    return _Progress(f"{name}: {label}", quiet)


def flight_logs(quiet: bool) -> dict[str, dict[str, Any]]:
    """Replay each of :data:`FLIGHT_LOGS` with its dataset config; its metrics (or ``{"error": line}``) by name."""
    from ins_hil.datasets import report as dsreport
    from ins_hil.datasets.dataset import DatasetError

    out: dict[str, dict[str, Any]] = {}
    for name in FLIGHT_LOGS:
        try:
            cfg = load_dataset_config(REPO / "configs" / "datasets" / f"{name}.toml")
            if cfg.path is None:
                raise DatasetError(f"{name}.toml: no dataset.path")
            m, _ = dsreport.replay(dsreport.load(cfg.path, cfg), cfg, functools.partial(_log_progress, name, quiet))
            out[name] = dsreport.jsonable(m)
        except (DatasetError, ValueError) as e:
            out[name] = {"error": str(e)}
    return out


def odometer_study(quiet: bool) -> dict[str, Any]:
    """The simulated car with and without its wheel odometer in 30-s GNSS outages (docs/accuracy.md):
    :func:`ins_hil.datasets.simulated.odometer_outages` of :func:`ins_hil.sim.scenarios.odometer_car`, seeds 1–5."""
    from ins_hil.datasets import simulated
    from ins_hil.sim.scenarios import odometer_car

    if not quiet:
        print("odometer car: seeds 1-5, outages 30-60 s and 60-90 s, with and without the odometer", file=sys.stderr)
    return simulated.odometer_outages(odometer_car)


def full_report(args: argparse.Namespace) -> int:
    """Regenerate docs/accuracy.md and docs/accuracy/*.png."""
    from ins_hil.datasets import simulated, study
    from ins_hil.datasets.accuracy_md import render_markdown
    from ins_hil.datasets.plots import plot_series

    docs = REPO / "docs"
    figdir = docs / "accuracy"
    figdir.mkdir(parents=True, exist_ok=True)
    quiet = args.quiet
    report: dict[str, Any] = {}
    t_start = time.perf_counter()
    report["hot_path"] = simulated.benchmark_hot_path()
    res, series = replay_drive((True, False), quiet, full=True)
    report["drive"] = res
    plots: dict[str, list[Path]] = {}
    outs = study.absolute_windows(res)
    for label in ("outages_aids", "outages_no_aids", "gnss_aids"):
        plots[f"drive_{label}"] = plot_series(series[label], f"drive {label}", figdir / f"drive_{label}", outs)
    sims: dict[str, Any] = {}
    for name in ("example32_gnss", "example32", "uav", "coning", "static"):
        m, ser, _ = run_scenario(name, 0, None, quiet)
        sims[name] = m
        plots[name] = plot_series(ser, name, figdir / name)
    report["scenarios"] = sims
    report["flight_logs"] = flight_logs(quiet)
    report["monte_carlo"] = monte_carlo("example32_gnss", 10, None, quiet)
    report["monte_carlo_uav"] = monte_carlo("uav_modelled", 10, 140.0, quiet)
    report["odometer"] = odometer_study(quiet)
    report["elapsed_s"] = time.perf_counter() - t_start
    (figdir / "metrics.json").write_text(json.dumps(report, indent=2, default=float))
    (docs / "accuracy.md").write_text(render_markdown(report, plots, docs))
    print(f"wrote {docs / 'accuracy.md'} ({report['elapsed_s']:.0f} s)")
    return 0
