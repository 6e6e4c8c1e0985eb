"""`ins-hil bench-fdi`: Monte-Carlo benchmark of inertial-sensor FDI (:mod:`ins_hil.bench.fdi`); writes docs/fdi.md.

Per configuration (book's 5-gyro cone, 6-sensor skewed array, dual and triple IMU), failure mode and
size: detection, isolation, time to isolate, mode classification; false alarms over simulated nominal
flight (≥ 1 h per configuration by default); navigation error after isolation, free inertial and
GNSS-aided; µs per ``FdiMonitor.process`` call; the book's ch. 5 reproductions; GNSS/baro drift.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

from ins_hil.bench import fdi
from ins_hil.commands._outputs import DOCS, out_file
from ins_hil.fdi.geometry import CONFIGS

NAME = "bench-fdi"
HELP = "Monte-Carlo benchmark of inertial-sensor fault detection and isolation (writes docs/fdi.md)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--rate", type=float, default=200.0, help="IMU rate in Hz (default 200)")
    p.add_argument("--trials", type=int, default=10, help="Monte-Carlo runs per mode and size (default 10)")
    p.add_argument("--nominal-hours", type=float, default=1.0, help="nominal flight per configuration (default 1 h)")
    p.add_argument("--configs", default=",".join(CONFIGS), help=f"comma list from {sorted(CONFIGS)}")
    p.add_argument("--p-fa", type=float, default=1e-3, help="false-alarm probability per hour and test (1e-3)")
    p.add_argument("--out", default=str(DOCS / "fdi.md"), help="report path (default: the checkout's docs/fdi.md)")
    p.add_argument("--seed", type=int, default=1, help="base random seed")
    p.add_argument("--aiding-trials", type=int, default=5, help="closed-loop runs per GNSS/baro fault (default 5)")
    p.add_argument(
        "--aiding-live-trials",
        type=int,
        default=3,
        help="flights per row of the live-configuration GNSS/baro table (1 kHz, ~15 s CPU each; 0 = skip; default 3)",
    )
    p.add_argument(
        "--aiding-only",
        action="store_true",
        help="run only the GNSS/baro drift table and replace its section in --out (fast)",
    )


def _say(line: str) -> None:
    print(line, flush=True)


def _aiding_only(args: argparse.Namespace, cfg: fdi.FdiBench) -> int:
    sec: list[str] = []
    fdi.bench_aiding(cfg, sec)
    out = Path(args.out)
    text = out.read_text(encoding="utf-8") if out.exists() else "# FDI benchmark\n"
    out.write_text(fdi.splice_aiding(text, "\n".join(sec)), encoding="utf-8")
    print(f"wrote the GNSS/baro section of {out}")
    return 0


def _bad_arguments(args: argparse.Namespace) -> str | None:
    """Why the arguments cannot run (one line naming the flag), or None: checked before the first trial."""
    if args.aiding_trials < 1:
        return "--aiding-trials must be ≥ 1"
    if args.aiding_live_trials < 0:
        return "--aiding-live-trials must be ≥ 0"
    if not (math.isfinite(args.rate) and args.rate > 0) or args.trials < 1:
        return "--rate, --trials and --nominal-hours must be positive"
    if not (math.isfinite(args.nominal_hours) and args.nominal_hours > 0):
        return "--rate, --trials and --nominal-hours must be positive"
    if not (math.isfinite(args.p_fa) and 1e-12 <= args.p_fa < 1.0):
        return f"--p-fa {args.p_fa:g}: a false-alarm probability per hour in [1e-12, 1)"
    names = [n.strip() for n in args.configs.split(",") if n.strip()]
    if not names:
        return f"--configs {args.configs!r}: name at least one of {sorted(CONFIGS)}"
    for n in names:
        if n not in CONFIGS:
            return f"unknown configuration {n!r} in --configs; choose from {sorted(CONFIGS)}"
    return None


def run(args: argparse.Namespace) -> int:
    why = _bad_arguments(args)
    if why is not None:
        print(f"ins-hil bench-fdi: {why}", file=sys.stderr)
        return 2
    out_file(args.out, "--out")
    cfg = fdi.FdiBench(
        rate=args.rate,
        trials=args.trials,
        nominal_hours=args.nominal_hours,
        p_fa=args.p_fa,
        seed=args.seed,
        aiding_trials=args.aiding_trials,
        aiding_live_trials=args.aiding_live_trials,
        log=_say,
    )
    if args.aiding_only:
        return _aiding_only(args, cfg)
    names = [n.strip() for n in args.configs.split(",") if n.strip()]
    t_start = time.perf_counter()
    dt = 1.0 / args.rate
    lines = fdi.header(cfg)
    body: list[str] = []
    print("book reproductions ...")
    fdi.book_section(body)
    print(f"fault trials ... ({time.perf_counter() - t_start:.0f} s)")
    summ = fdi.bench_faults(names, fdi.flight(25.0, dt), cfg, body)
    print(f"nominal data ... ({time.perf_counter() - t_start:.0f} s)")
    nom = fdi.bench_nominal(names, cfg, body)
    print("navigation after isolation ...")
    nav = fdi.bench_nav(names, cfg, body)
    print("GNSS-aided closed loop ...")
    aided = fdi.bench_aided(names, cfg, body)
    print("cost per call ...")
    fdi.bench_timing(names, cfg, body)
    print("GNSS/baro drift ...")
    fdi.bench_aiding(cfg, body)
    tg = fdi.targets(names, summ, nom, nav, aided, dt)
    lines += tg + body
    lines.append(f"Total benchmark time {time.perf_counter() - t_start:.0f} s.")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("\n".join(lines) + "\n", encoding="utf-8")
    print("\n".join(tg))
    print(f"wrote {out}")
    return 0
