"""`ins-hil bench-drivers`: decode cost, maximum loss-free frame rate, and behaviour under 1 % corruption
for every driver transport (:mod:`ins_hil.bench.drivers`); writes docs/drivers.md."""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from ins_hil.bench import drivers as bench
from ins_hil.commands._outputs import DOCS, out_file
from ins_hil.machine import summary

NAME = "bench-drivers"
HELP = "measure driver decode cost, max loss-free frame rate (pty, vcan) and 1%% corruption handling"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", default=str(DOCS / "drivers.md"),
                   help="report file (default: the checkout's docs/drivers.md)")  # fmt: skip
    p.add_argument("--samples", type=int, default=3000, help="samples per decode-cost run, best of 7 (default 3000)")
    p.add_argument("--no-vcan", action="store_true", help="skip the vcan measurement (guest boot costs ~1 min)")
    p.add_argument("--only", choices=["vcan"], help=argparse.SUPPRESS)  # internal: run inside scripts/vcan
    p.add_argument("--json", help=argparse.SUPPRESS)


def _say(line: str) -> None:
    print(line, flush=True)


def run(args: argparse.Namespace) -> int:
    if args.only == "vcan":
        rows = bench.vcan_max_rate(_say)
        where = "QEMU guest (TCG emulation)" if os.uname().nodename == "vcan-vm" else "native vcan"
        Path(args.json).write_text(json.dumps({"rows": rows, "where": where}))
        return 0
    if args.samples < 100:
        print("ins-hil bench-drivers: --samples must be ≥ 100", file=sys.stderr)
        return 2
    out_file(args.out, "--out")
    machine = summary() + "."
    _say("decode cost ...")
    costs = bench.decode_costs(args.samples)
    for name, us, _ in costs:
        _say(f"  {name}: {us:.1f} µs/sample")
    _say("1% corruption ...")
    corr = bench.corruption()
    for c in corr:
        _say(f"  {c['transport']}: {c}")
    _say("max loss-free rate on a pty ...")
    pty_rows = bench.pty_max_rate(_say)
    vcan_rows: list[tuple[str, float, float, int, int]] = []
    if args.no_vcan:
        vcan_where = "skipped (--no-vcan)"
    else:
        _say("max loss-free rate on vcan (scripts/vcan; a QEMU guest where the kernel has no CAN) ...")
        vcan_rows, vcan_where = bench.vcan_in_guest()
        for v in vcan_rows:
            _say(f"  vcan: {v}")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(bench.report(machine, args.samples, costs, corr, pty_rows, vcan_rows, vcan_where))
    print(f"wrote {out}")
    return 0
