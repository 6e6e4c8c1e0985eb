"""``ins-hil fuzz``: the fuzz campaign over every decoder, the config loader and the recorder reader.

Runs each target of :data:`ins_hil.fuzz.targets.TARGETS` for its share of ``--budget`` seconds
(structure-aware mutational inputs), prints per target the inputs tried, escaped exceptions,
accepted-bad samples and NaN states, and writes ``docs/robustness.md`` (``--doc``).
Exit status 0 when no target escaped an exception, delivered an implausible sample or gave a NaN
state; 1 otherwise; 2 on bad arguments.
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from pathlib import Path

from ins_hil import fuzz, machine
from ins_hil.fuzz import TargetResult, run_target

NAME = "fuzz"
HELP = "fuzz campaign: decoders, config loader, recorder reader (writes docs/robustness.md)"

ROOT = Path(__file__).resolve().parent.parent.parent


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--budget", type=float, default=120.0, metavar="S", help="total wall-clock seconds (default 120)")
    p.add_argument("--targets", nargs="*", metavar="NAME", help="only these targets (default: all)")
    p.add_argument("--seed", type=int, default=1, help="random seed (the campaign is reproducible per seed)")
    p.add_argument("--doc", type=Path, default=ROOT / "docs" / "robustness.md", help="report to write")
    p.add_argument("--no-doc", action="store_true", help="print only, do not write the report")


def _row(r: TargetResult) -> str:
    rate = r.inputs / r.seconds if r.seconds else 0.0
    return (
        f"| {r.name} | {r.inputs:,} | {rate:,.0f} | {r.escaped} | {r.accepted:,} | {r.decoded_bad:,} | "
        f"{r.accepted_bad:,} | "
        f"{r.nav_fed:,} | {r.nav_states:,} | {r.nan_states} | {r.nav_exceptions} | {r.nav_stalls} |"
    )


def _line(r: TargetResult) -> str:
    return (
        f"{r.name:16s} {r.inputs:>10,} inputs in {r.seconds:6.1f} s: escaped {r.escaped}, accepted {r.accepted:,}, "
        f"decoded out of range {r.decoded_bad:,}, accepted-bad {r.accepted_bad:,}, "
        f"NaN states {r.nan_states} (of {r.nav_states:,}), "
        f"pipeline exceptions {r.nav_exceptions}, stalls {r.nav_stalls}"
    )


def _ranges() -> list[str]:
    z = fuzz
    return [
        f"Physical ranges (the campaign's oracle): IMU dt in [{z.DT_RANGE[0]:g}, {z.DT_RANGE[1]:g}] s,",
        f"|ω| ≤ {z.MAX_RATE:g}·√3 rad/s, |f| ≤ {z.MAX_ACCEL:g}·√3 m/s², finite; GNSS with a fix ≥ 2-D,",
        f"|lat| ≤ 90°, |lon| ≤ 180°, h in [{z.H_RANGE[0]:g}, {z.H_RANGE[1]:g}] m, |v| ≤ {z.MAX_SPEED:g} m/s,",
        f"0 < σ ≤ {z.MAX_STD:g}; pressure in [{z.P_RANGE[0]:g}, {z.P_RANGE[1]:g}] Pa; |B| ≤ {z.MAX_FIELD:g} T.",
    ]


def report(results: list[TargetResult], budget: float, seed: int, command: str, machine_line: str, load: str) -> str:
    """The markdown report of a campaign."""
    per_s = {r.name: r.inputs / r.seconds for r in results if r.seconds}
    out = [
        "# Robustness: the fuzz campaign",
        "",
        "Structure-aware mutational fuzzing in process (`ins_hil/fuzz`): each target starts from valid",
        "input (a sensor stream with advancing time and sequence, the shipped `configs/*.toml`, a recording),",
        "mutates fields and bytes and recomputes the checksums (serial CRC-16, DroneCAN transfer CRC and",
        "tail bytes, DBC CRC-8, MAVLink CRC with CRC_EXTRA), so most inputs reach the checks behind the",
        "checksum; a share stays raw (flips after the checksum, truncation, garbage).",
        "",
        f"Command: `{command}` (budget {budget:.0f} s, seed {seed}).",
        "",
        f"Machine: {machine_line}; {load}.",
        "",
        "## Per target",
        "",
        "| target | inputs | inputs/s | escaped exceptions | accepted samples | decoded out of range | accepted-bad | "
        "IMU samples to the pipeline | states | NaN states | pipeline exceptions | pipeline stalls |",
        "|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|",
        *(_row(r) for r in results),
        "",
        "- **escaped exceptions**: anything raised out of the target (for the config loader anything but",
        "  `ConfigError`, for the recorder reader anything but `RecordError`);",
        "- **decoded out of range**: a sample the decoder delivered outside the physical ranges below, which",
        "  the gateway's validation boundary (`ins_hil.validation.SampleValidator`, default limits) must stop;",
        "- **accepted-bad**: such a sample that the validation boundary let through too (what would reach the",
        "  core; for the recorder reader: a record read back that was not the one recorded);",
        "- **NaN states**: the accepted IMU samples of a decoder go, per IMU id, through two pipelines",
        "  (`Pipeline` with the default `PipelineConfig`, a fixed 3-D GNSS fix every 100th sample): one as",
        "  delivered, one retimed 5 ms apart (their dt kept) so the values reach the core even when the",
        "  decoder's time is poisoned; a non-finite state; **pipeline exceptions**: raised by them;",
        f"  **stalls** (as delivered): {fuzz.STALL} samples in a row without a state ({2 * fuzz.STALL} before",
        "  the first), after which the pipeline is rebuilt.",
        "",
        *_ranges(),
        "",
    ]
    dec = [r for r in results if r.decoder]
    if dec:
        out += ["Inputs per decoder at `--budget 1200` at the rates measured here (same share of the budget):", ""]
        weight = {r.name: r.seconds for r in results}
        total = sum(weight.values()) or 1.0
        for r in dec:
            proj = per_s[r.name] * 1200.0 * weight[r.name] / total if r.name in per_s else 0.0
            out.append(f"- {r.name}: {proj:,.0f}")
        out.append("")
    out += [
        "Against the targets (issue 18: ≥ 1 million inputs per decoder and 10,000 config documents, with 0",
        "escaped exceptions, 0 accepted samples outside the physical ranges, 0 NaN states):",
        "",
    ]
    for r in results:
        need = 1_000_000 if r.decoder else 10_000 if r.name == "config" else 0
        checks = [
            f"inputs {r.inputs:,}" + (f" {'≥' if r.inputs >= need else '<'} {need:,}" if need else ""),
            f"escaped {r.escaped}",
            f"accepted-bad {r.accepted_bad}",
            f"NaN states {r.nan_states}, pipeline exceptions {r.nav_exceptions}",
        ]
        ok = r.inputs >= need and not (r.escaped or r.accepted_bad or r.nan_states or r.nav_exceptions)
        out.append(f"- {r.name}: {'met' if ok else 'NOT met'} ({'; '.join(checks)})")
    out += [
        "",
        "## Findings",
        "",
        "One line per kind, with the first example (the campaign changes no decoder: these are for their owners).",
        "",
    ]
    for r in results:
        out.append(f"### {r.name} (`{r.what}`)")
        out.append("")
        if not r.findings:
            out.append("Nothing found.")
        for f in sorted(r.findings.values(), key=lambda f: -f.count):
            ex = f.example.replace("|", "/").replace("\n", " ")
            out.append(f"- **{f.kind}** × {f.count:,}: `{ex}`")
        out.append("")
    return "\n".join(out)


def run(args: argparse.Namespace) -> int:
    from ins_hil.fuzz.targets import by_name

    try:
        targets = by_name(args.targets)
    except ValueError as e:
        print(f"ins-hil fuzz: {e}", file=sys.stderr)
        return 2
    if not args.budget > 0:
        print(f"ins-hil fuzz: --budget {args.budget}: must be > 0 s", file=sys.stderr)
        return 2
    total_w = sum(t.weight for t in targets)
    results = []
    t0 = time.perf_counter()
    for i, t in enumerate(targets):
        share = args.budget * t.weight / total_w
        print(f"[fuzz] {t.name}: {share:.0f} s on {t.what}", file=sys.stderr, flush=True)
        r = run_target(t, share, seed=args.seed * 1000 + i)
        results.append(r)
        print(_line(r), flush=True)
    print(f"[fuzz] {time.perf_counter() - t0:.0f} s in all", file=sys.stderr)
    cmd = f"scripts/fuzz --budget {args.budget:g}"
    if args.targets:
        cmd += " --targets " + " ".join(shlex.quote(t) for t in args.targets)
    if args.seed != 1:
        cmd += f" --seed {args.seed}"
    if not args.no_doc:
        text = report(results, args.budget, args.seed, cmd, machine.describe(), machine.load_note(own=1.0))
        args.doc.parent.mkdir(parents=True, exist_ok=True)
        args.doc.write_text(text + "\n")
        print(f"[fuzz] wrote {args.doc}", file=sys.stderr)
    bad = any(r.escaped or r.accepted_bad or r.nan_states or r.nav_exceptions for r in results)
    return 1 if bad else 0
