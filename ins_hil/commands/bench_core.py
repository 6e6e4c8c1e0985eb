"""`ins-hil bench-core`: per-step cost of the Python core and the C reference core, side by side.

The measurements are :mod:`ins_hil.bench.core` (Python ``NavCore``, the C core through the extension
per step, bare, and whole log in one call; the mechanization alone; callgrind instruction counts; the
C-vs-Python and float-vs-double accuracy). Prints the table and writes ``docs/ref_core.md`` with the
machine noted. Timings are the minimum over ``--repeat`` runs with the median shown too.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ins_hil.bench import core as bench

NAME = "bench-core"
HELP = "benchmark the Python core against the C reference core (per step, per GNSS update, callgrind)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--duration", type=float, default=60.0, help="simulated flight, s (default 60)")
    p.add_argument("--rate", type=float, default=100.0, help="IMU rate, Hz (default 100)")
    p.add_argument("--repeat", type=int, default=3, help="timed repetitions, the minimum is reported (default 3)")
    p.add_argument("--out", type=Path, default=bench.ROOT / "docs" / "ref_core.md", help="report file (markdown)")
    p.add_argument("--no-callgrind", action="store_true", help="skip the valgrind instruction count")
    p.add_argument(
        "--no-datasets",
        action="store_true",
        help="skip the replays of the shipped dataset configs (and the 200 Hz synthetic) on Python and C",
    )
    p.add_argument(
        "--no-batch",
        action="store_true",
        help="skip the Dask batch on the C core (the dataset configs x --batch-seeds, 2 workers vs serial)",
    )
    p.add_argument("--batch-seeds", type=int, default=4, help="seeds per log of the Dask batch (default 4)")
    p.add_argument(
        "--replay",
        action="store_true",
        help="only the offline replay's cost: 200 Hz IMU with 5 / 20 Hz GNSS and a velocity delay (printed)",
    )
    p.add_argument(
        "--accuracy-duration",
        type=float,
        default=600.0,
        help="length (s) of the 50 Hz flight of the accuracy section (C vs Python, float vs double); 0 = skip",
    )


def _say(line: str) -> None:
    print(line, flush=True)


def run(args: argparse.Namespace) -> int:
    if args.replay:
        from ins_hil import machine
        from ins_hil.bench.replay_cost import replay_cost

        _say(f"ins-hil bench-core --replay: simulated UAV mission, 120 s, process time ({machine.summary()})")
        replay_cost(say=_say)
        return 0
    if args.duration <= 0 or args.rate <= 0:
        raise SystemExit("ins-hil bench-core: --duration and --rate must be positive")
    if args.repeat < 1:
        raise SystemExit("ins-hil bench-core: --repeat must be >= 1")
    from ins_hil import cref

    if not cref.available():
        raise SystemExit("ins-hil bench-core: the C core extension is not built (pip install -e . with a C compiler)")
    _say(f"ins-hil bench-core: simulating {args.duration:.0f} s of UAV flight at {args.rate:.0f} Hz ...")
    rows, n, m = bench.time_cores(args.duration, args.rate, args.repeat, _say)

    cg: dict[str, float] | str = "skipped (--no-callgrind)"
    if not args.no_callgrind:
        _say("callgrind: instruction counts of firmware_ref/build/double/ins_ref_bench ...")
        cg = bench.callgrind(2000, 200)
        if isinstance(cg, str):
            print(f"  {cg}")
        else:
            for k, v in cg.items():
                print(f"  {k:<22} {v:10.0f} instructions per call")

    acc: list[str] = []
    if args.accuracy_duration > 0:
        print(f"accuracy: {args.accuracy_duration:.0f} s flight at 50 Hz, C vs Python and float vs double ...")
        acc = bench.accuracy(args.accuracy_duration)
        for line in acc:
            print("  " + line.lstrip("- "))
    text = bench.report(rows, cg, args.duration, args.rate, args.repeat, n, m)
    text += bench.accuracy_md(acc, args.accuracy_duration)
    if not args.no_datasets:
        from ins_hil.bench import core_replay

        print("replays: each shipped dataset config on Python and on C (CPU seconds of this process) ...")
        drows = core_replay.dataset_rows(_say)
        synth = core_replay.synthetic_rows(say=_say)
        text += core_replay.report_md(drows, synth)
        text += core_replay.cli_md(core_replay.cli_rows(_say))
        if not args.no_batch:
            print(f"batch: the dataset configs x {args.batch_seeds} seeds on C, serial then 2 Dask workers ...")
            text += core_replay.batch_md(core_replay.batch_row(args.batch_seeds, 2, _say))
    from ins_hil.bench import core_replay as _cr

    text += _cr.live_md()
    text += _cr.scope_md()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(run(argparse.ArgumentParser().parse_args()))
