"""``ins-hil fuzz``: the fuzz campaign over every decoder, the config loader, the recorder reader, the dataset
readers and the dataset config.

Runs each target of :data:`ins_hil.fuzz.targets.TARGETS` for its share of ``--budget`` seconds, or until
``--inputs`` inputs each (``--to-goal``: each its own goal, 1 M per decoder and reader), in chunks of
``--progress`` seconds with a progress line after each; the process runs under an address-space cap
(``--memory-mib``, RLIMIT_AS: an input that needs more is a blow-up) and an input that uses more than
:data:`ins_hil.fuzz.STEP_CPU_LIMIT` CPU seconds is a hang. With ``--state FILE`` the counts so far are kept
in FILE after every chunk, and ``--resume`` goes on from them (an interrupted campaign loses at most the chunk
that was running; Ctrl-C or SIGTERM still writes the report of what ran). Prints per target the inputs
tried, escaped exceptions, accepted-bad samples, NaN states, blow-ups and hangs, and writes
``docs/robustness.md`` (``--doc``). Exit status 0 when no target failed, 1 otherwise, 2 on bad arguments,
130 when interrupted.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shlex
import signal
import sys
import time
from pathlib import Path
from typing import Any

from ins_hil import fuzz, machine
from ins_hil.fuzz import TargetResult, run_target

NAME = "fuzz"
HELP = "fuzz campaign: decoders, config loader, recorder reader, dataset readers (writes docs/robustness.md)"

ROOT = Path(__file__).resolve().parent.parent.parent


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--budget", type=float, default=120.0, metavar="S", help="total wall-clock seconds (default 120)")
    p.add_argument("--inputs", type=int, metavar="N", help="run each target until N inputs (no time budget)")
    p.add_argument(
        "--to-goal",
        action="store_true",
        help="run each target until its goal (1 M per decoder and reader, 100 k dataset configs)",
    )
    p.add_argument("--targets", nargs="*", metavar="NAME", help="only these targets (default: all)")
    p.add_argument("--seed", type=int, default=1, help="random seed (the campaign is reproducible per seed)")
    p.add_argument(
        "--memory-mib",
        type=int,
        default=2048,
        metavar="MIB",
        help="address-space cap of the campaign's process (RLIMIT_AS, default 2048; 0: none)",
    )
    p.add_argument(
        "--progress",
        type=float,
        default=60.0,
        metavar="S",
        help="chunk length: a progress line (and the --state file) every S seconds (default 60)",
    )
    p.add_argument(
        "--jobs",
        type=int,
        default=1,
        metavar="N",
        help="worker processes running chunks side by side, each under --memory-mib (default 1); their counts are "
        "added in this process and in --state as one campaign's",
    )
    p.add_argument("--state", type=Path, metavar="FILE", help="keep the counts so far in FILE (JSON) after every chunk")
    p.add_argument("--resume", action="store_true", help="go on from the counts in --state (targets done are skipped)")
    p.add_argument("--doc", type=Path, default=ROOT / "docs" / "robustness.md", help="report to write")
    p.add_argument("--no-doc", action="store_true", help="print only, do not write the report")  # fmt: skip


def _rate(r: TargetResult) -> tuple[float, float]:
    """(inputs per wall-clock second, inputs per CPU second) of a result."""
    return (r.inputs / r.seconds if r.seconds else 0.0, r.inputs / r.cpu_seconds if r.cpu_seconds else 0.0)


def _to_go(r: TargetResult) -> str:
    """The CPU time one free core needs for the rest of the target's goal at its measured rate."""
    left = r.goal - r.inputs
    cpu = _rate(r)[1]
    if r.goal <= 0 or left <= 0:
        return "met" if r.goal > 0 else "—"
    if not cpu:
        return "?"
    h = left / cpu / 3600.0
    return f"{h:.1f} h" if h >= 1 else f"{h * 60:.0f} min"


def _row(r: TargetResult) -> str:
    wall, cpu = _rate(r)
    return (
        f"| {r.name} | {r.inputs:,} | {r.goal:,} | {wall:,.0f} | {cpu:,.0f} | {_to_go(r)} | {r.escaped} | "
        f"{r.accepted:,} | {r.decoded_bad:,} | {r.accepted_bad:,} | {r.nav_states:,} | {r.nan_states} | "
        f"{r.nav_exceptions} | {r.nav_stalls} | {r.blowups} | {r.hangs} |"
    )


def _line(r: TargetResult) -> str:
    wall, cpu = _rate(r)
    goal = f" / {r.goal:,}" if r.goal else ""
    return (
        f"{r.name:20s} {r.inputs:>10,}{goal} inputs in {r.seconds:6.0f} s ({wall:,.0f}/s, {cpu:,.0f} per CPU s; "
        f"to go {_to_go(r)}): escaped {r.escaped}, accepted-bad {r.accepted_bad:,}, "
        f"NaN states/figures {r.nan_states}, pipeline exceptions {r.nav_exceptions}, stalls {r.nav_stalls}, "
        f"blow-ups {r.blowups}, hangs {r.hangs}"
        + (f", replays navigating {r.replays_nav:,} / {r.replays:,}" if r.replays else "")
    )


def _ranges() -> list[str]:
    z = fuzz
    return [
        f"Physical ranges (the campaign's oracle): IMU dt in [{z.DT_RANGE[0]:g}, {z.DT_RANGE[1]:g}] s,",
        f"|ω| ≤ {z.MAX_RATE:g}·√3 rad/s, |f| ≤ {z.MAX_ACCEL:g}·√3 m/s², finite; GNSS with a fix ≥ 2-D,",
        f"|lat| ≤ 90°, |lon| ≤ 180°, h in [{z.H_RANGE[0]:g}, {z.H_RANGE[1]:g}] m, |v| ≤ {z.MAX_SPEED:g} m/s,",
        f"0 < σ ≤ {z.MAX_STD:g}; pressure in [{z.P_RANGE[0]:g}, {z.P_RANGE[1]:g}] Pa; |B| ≤ {z.MAX_FIELD:g} T.",
    ]


def report(results: list[TargetResult], command: str, machine_line: str, load: str, memory_mib: int) -> str:
    """The markdown report of a campaign."""
    cap = f"{memory_mib} MiB address-space cap (RLIMIT_AS)" if memory_mib else "no memory cap"
    out = [
        "# Robustness: the fuzz campaign",
        "",
        "Structure-aware mutational fuzzing in process (`ins_hil/fuzz`): each target starts from valid",
        "input (a sensor stream with advancing time and sequence, the shipped `configs/*.toml`, a recording,",
        "small logs cut record by record from the shipped logs at the campaign's start), mutates fields, records",
        "and bytes and recomputes the checksums (serial CRC-16, DroneCAN transfer CRC and tail bytes, DBC CRC-8,",
        "MAVLink CRC with CRC_EXTRA), so most inputs reach the checks behind the checksum; a share stays raw",
        "(flips after the checksum, truncation, garbage).",
        "",
        f"Command: `{command}`; the process under a {cap}, an input stopped after "
        f"{fuzz.STEP_CPU_LIMIT:g} CPU seconds (a hang).",
        "",
        f"Machine: {machine_line}; {load}.",
        "",
        "## Per target",
        "",
        "| target | inputs | goal | inputs/s | inputs per CPU s | rest of the goal on one core | escaped exceptions | "
        "accepted samples | decoded out of range | accepted-bad | states | NaN states or figures | "
        "pipeline exceptions | pipeline stalls | blow-ups | hangs |",
        "|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|",
        *(_row(r) for r in results),
        "",
        "- **inputs per CPU s**: inputs over the CPU time of the campaign's process and its child replays (the rate on",
        "  one core);",
        "  **rest of the goal**: the CPU time one core needs for the inputs still missing at that rate;",
        "- **escaped exceptions**: anything raised out of the target (for the config loader anything but",
        "  `ConfigError`, for the recorder reader anything but `RecordError`, for a dataset reader anything but",
        "  `DatasetError`, for the replay anything but a one-line refusal naming the file);",
        "- **decoded out of range**: a sample the decoder delivered outside the physical ranges below, which",
        "  the gateway's validation boundary (`ins_hil.validation.SampleValidator`, default limits) must stop;",
        "- **accepted-bad**: such a sample that the validation boundary let through too (what would reach the",
        "  core; for the recorder reader: a record read back that was not the one recorded);",
        "- **NaN states**: the accepted IMU samples of a decoder go, per IMU id, through two pipelines",
        "  (`Pipeline` with the default `PipelineConfig`, a fixed 3-D GNSS fix every 100th sample): one as",
        "  delivered, one retimed 5 ms apart (their dt kept) so the values reach the core even when the",
        "  decoder's time is poisoned; a non-finite state; for the dataset targets, a `nan` printed as a figure",
        "  by a replay of an accepted input, or its replay refused for non-finite states or a pipeline error;",
        "  **pipeline exceptions**: raised by them;",
        f"  **stalls** (as delivered): {fuzz.STALL} samples in a row without a state ({2 * fuzz.STALL} before",
        "  the first), after which the pipeline is rebuilt;",
        "- **blow-ups**: a MemoryError out of one input under the cap; **hangs**: one input over the CPU limit.",
        "",
        *_ranges(),
        "",
        *[
            f"Measured in {r.name} (the largest of {r.inputs:,} runs): "
            + ", ".join(f"{k} {v:,.1f}" for k, v in sorted(r.maxima.items()))
            + "."
            for r in results
            if r.maxima
        ],
        *([""] if any(r.maxima for r in results) else []),
        *(
            [
                "Replays of accepted inputs (the dataset targets; the NaN-state oracle sees a navigating filter in",
                "those whose core left its alignment): "
                + "; ".join(
                    f"{r.name} {r.replays_nav:,} of {r.replays:,} navigating ({r.replays_nav / r.replays:.0%})"
                    for r in results
                    if r.replays
                )
                + ".",
                "",
            ]
            if any(r.replays for r in results)
            else []
        ),
        "Against the goals (≥ 1 million inputs per decoder and per dataset reader, 10,000 gateway config",
        "documents, 100,000 dataset configs; 0 escaped exceptions, 0 accepted samples outside the physical ranges,",
        "0 NaN states or figures, 0 blow-ups, 0 hangs):",
        "",
    ]
    for r in results:
        checks = [
            f"inputs {r.inputs:,}" + (f" {'≥' if r.inputs >= r.goal else '<'} {r.goal:,}" if r.goal else ""),
            f"escaped {r.escaped}",
            f"accepted-bad {r.accepted_bad}",
            f"NaN {r.nan_states}, pipeline exceptions {r.nav_exceptions}",
            f"blow-ups {r.blowups}, hangs {r.hangs}",
        ]
        ok = r.inputs >= r.goal and not r.failures()
        out.append(f"- {r.name}: {'met' if ok else 'NOT met'} ({'; '.join(checks)})")
    out += [
        "",
        "## Findings",
        "",
        "One line per kind, with the first example.",
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


#: chunks a campaign discards for an environment fault (an import that fails) before it stops, and the wait (s)
MAX_FAULTS = 5
FAULT_WAIT = 30.0


class _Stop(BaseException):
    """SIGTERM: stop after writing what ran (like Ctrl-C)."""


def _on_term(signum: int, frame: Any) -> None:
    raise _Stop()


def _cap_memory(mib: int) -> tuple[int, int] | None:
    """Cap this process's address space at ``mib`` MiB (the soft RLIMIT_AS); returns the limits to restore."""
    import resource

    if mib <= 0:
        return None
    old = resource.getrlimit(resource.RLIMIT_AS)
    hard = old[1]
    want = mib * 1024 * 1024
    resource.setrlimit(resource.RLIMIT_AS, (want if hard == resource.RLIM_INFINITY else min(want, hard), hard))
    return old


def _uncap_memory(old: tuple[int, int] | None) -> None:
    import resource

    if old is not None:
        resource.setrlimit(resource.RLIMIT_AS, old)


def _load_state(path: Path) -> dict[str, Any]:
    try:
        d = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise ValueError(f"--state {path}: cannot read ({e})") from None
    if not isinstance(d, dict) or not isinstance(d.get("results"), dict):
        raise ValueError(f"--state {path}: not a campaign state (expected a 'results' table)")
    return d


def _save_state(path: Path, results: dict[str, TargetResult], chunks: dict[str, int]) -> None:
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps({"results": {k: r.to_dict() for k, r in results.items()}, "chunks": chunks}))
    tmp.replace(path)


def run(args: argparse.Namespace) -> int:
    from ins_hil.fuzz.targets import by_name

    try:
        targets = by_name(args.targets)
    except ValueError as e:
        print(f"ins-hil fuzz: {e}", file=sys.stderr)
        return 2
    if not args.budget > 0 or not math.isfinite(args.budget):
        print(f"ins-hil fuzz: --budget {args.budget}: must be > 0 s", file=sys.stderr)
        return 2
    by_count = args.inputs is not None or args.to_goal
    total_w = sum(t.weight for t in targets)
    short = [] if by_count else [t.name for t in targets if args.budget * t.weight / total_w <= 0.5]
    if short:  # a target's share of 0.5 s or less is skipped
        need = int(0.5 * total_w / min(t.weight for t in targets)) + 1
        if len(short) == len(targets):
            print(f"ins-hil fuzz: --budget {args.budget:g}: too short, no target would run (a share of 0.5 s or less "
                  f"is skipped): at least {need} s, or fewer --targets", file=sys.stderr)  # fmt: skip
            return 2
        print(f"[fuzz] --budget {args.budget:g}: {', '.join(short)} skipped (a share of 0.5 s or less; every target "
              f"runs from {need} s)", file=sys.stderr)  # fmt: skip
    if args.memory_mib < 0:
        print(f"ins-hil fuzz: --memory-mib {args.memory_mib}: must be ≥ 0 (0: no cap)", file=sys.stderr)
        return 2
    if args.inputs is not None and args.inputs <= 0:
        print(f"ins-hil fuzz: --inputs {args.inputs}: must be > 0", file=sys.stderr)
        return 2
    if not args.progress > 0 or not math.isfinite(args.progress):
        print(f"ins-hil fuzz: --progress {args.progress}: must be > 0 s", file=sys.stderr)
        return 2
    if args.jobs < 1:
        print(f"ins-hil fuzz: --jobs {args.jobs}: must be >= 1", file=sys.stderr)
        return 2
    cpus = os.cpu_count() or 1
    if args.jobs > 4 * cpus:  # each a process under --memory-mib
        print(f"ins-hil fuzz: --jobs {args.jobs}: at most {4 * cpus} (4 x this machine's {cpus} CPUs)", file=sys.stderr)
        return 2
    if args.resume and args.state is None:
        print("ins-hil fuzz: --resume needs --state FILE", file=sys.stderr)
        return 2
    from ins_hil.commands._outputs import out_file

    if args.state is not None:  # written after every chunk and at the end: refused before the campaign
        out_file(args.state, "--state")
    if not args.no_doc:
        out_file(args.doc, "--doc")
    results: dict[str, TargetResult] = {}
    chunks: dict[str, int] = {}
    if args.resume and args.state.exists():
        try:
            st = _load_state(args.state)
        except ValueError as e:
            print(f"ins-hil fuzz: {e}", file=sys.stderr)
            return 2
        results = {k: TargetResult.from_dict(v) for k, v in st["results"].items()}
        chunks = {k: int(v) for k, v in st.get("chunks", {}).items()}
        print(f"[fuzz] resuming from {args.state}: " + ", ".join(f"{k} {r.inputs:,}" for k, r in results.items()),
              file=sys.stderr)  # fmt: skip
    old_cap = _cap_memory(args.memory_mib)
    old_term = signal.signal(signal.SIGTERM, _on_term)
    interrupted = env_failed = False
    faults = 0
    t0 = time.perf_counter()
    try:
        if args.jobs > 1:
            faults = _run_jobs(args, targets, results, chunks, by_count, total_w)
        for i, t in enumerate(targets if args.jobs == 1 else []):
            acc = results.setdefault(t.name, TargetResult(t.name, t.what, decoder=t.decoder, goal=t.goal))
            acc.goal, acc.decoder = t.goal, t.decoder
            want = (args.inputs if args.inputs is not None else t.goal) if by_count else None
            share = None if by_count else args.budget * t.weight / total_w
            if (want is not None and acc.inputs >= want) or (share is not None and acc.seconds >= share):
                continue
            what = f"until {want:,} inputs" if want is not None else f"{share:.0f} s"
            print(f"[fuzz] {t.name}: {what} on {t.what}", file=sys.stderr, flush=True)
            while True:
                left_s = None if share is None else share - acc.seconds
                left_n = None if want is None else want - acc.inputs
                if (left_s is not None and left_s <= 0.5) or (left_n is not None and left_n <= 0):
                    break
                k = chunks.get(t.name, 0)
                chunks[t.name] = k + 1
                try:
                    r = run_target(t, min(args.progress, left_s) if left_s is not None else args.progress,
                                   seed=args.seed * 1000 + i + 100_003 * k, inputs=left_n)  # fmt: skip
                except fuzz.EnvironmentFault as e:
                    faults = _environment_fault(e, faults)
                    continue
                acc.add(r)
                print(f"[fuzz] {_line(acc)}", file=sys.stderr, flush=True)
                if args.state is not None:
                    _save_state(args.state, results, chunks)
            print(_line(acc), flush=True)
    except fuzz.EnvironmentFault as e:
        print(f"ins-hil fuzz: stopped: {e} (the installation changed under the campaign?)", file=sys.stderr)
        env_failed = True
    except (KeyboardInterrupt, _Stop):
        interrupted = True
        print("[fuzz] interrupted: the counts of the chunks that finished follow (the running chunk is lost)",
              file=sys.stderr)  # fmt: skip
        for r in results.values():
            print(_line(r), flush=True)
    finally:
        signal.signal(signal.SIGTERM, old_term)
        _uncap_memory(old_cap)
    print(f"[fuzz] {time.perf_counter() - t0:.0f} s in all", file=sys.stderr)
    cmd = "scripts/fuzz " + (
        "--to-goal" if args.to_goal and args.inputs is None
        else f"--inputs {args.inputs}" if args.inputs is not None
        else f"--budget {args.budget:g}"
    )  # fmt: skip
    if args.targets:
        cmd += " --targets " + " ".join(shlex.quote(t) for t in args.targets)
    if args.seed != 1:
        cmd += f" --seed {args.seed}"
    if args.memory_mib != 2048:
        cmd += f" --memory-mib {args.memory_mib}"
    # every target with counts: this run's and, with --resume, the earlier runs' kept in --state
    shown = [r for r in _ordered(results) if r.inputs]
    if not args.no_doc and shown:
        text = report(shown, cmd, machine.describe(), machine.load_note(own=1.0), args.memory_mib)
        args.doc.parent.mkdir(parents=True, exist_ok=True)
        args.doc.write_text(text + "\n")
        print(f"[fuzz] wrote {args.doc}", file=sys.stderr)
    if interrupted:
        return 130
    return 1 if env_failed or any(r.failures() for r in shown) else 0


def _environment_fault(e: Exception, faults: int) -> int:
    """An environment fault (an import that fails) of one chunk: the chunk is discarded and retried after
    ``FAULT_WAIT`` s; the fault is raised again once ``MAX_FAULTS`` have been met. Returns the faults so far."""
    faults += 1
    print(f"[fuzz] environment: {e}; the chunk is discarded ({faults} of {MAX_FAULTS}), retried in {FAULT_WAIT:g} s",
          file=sys.stderr, flush=True)  # fmt: skip
    if faults >= MAX_FAULTS:
        raise e
    time.sleep(FAULT_WAIT)
    return faults


#: with --jobs, a rest of fewer inputs than this per worker runs as one chunk
JOB_MIN_INPUTS = 2000


def _worker_exit(signum: int, frame: Any) -> None:
    raise SystemExit(0)  # not caught by a harness (a BaseException): the worker exits, its scratch folders removed


def _worker_init() -> None:
    """A worker of ``--jobs``: SIGTERM ends it (the campaign's process stops its workers), Ctrl-C is the campaign's."""
    signal.signal(signal.SIGTERM, _worker_exit)
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _chunk(name: str, seconds: float, seed: int, inputs: int | None) -> TargetResult:
    """One chunk of the target ``name`` in a worker (a Target's setup is a closure: found again by its name)."""
    from ins_hil.fuzz.targets import by_name

    return run_target(by_name([name])[0], seconds, seed=seed, inputs=inputs)


def _run_jobs(
    args: argparse.Namespace,
    targets: list[Any],
    results: dict[str, TargetResult],
    chunks: dict[str, int],
    by_count: bool,
    total_w: float,
) -> int:
    """The campaign's chunks on ``args.jobs`` worker processes (a fork server's: each under the memory cap): the
    targets in order, a free worker taking the next chunk of the first target whose rest is not yet running (an input
    budget or a time share split between the chunks in flight), the counts added here as they come, the state saved
    after each. Returns the environment faults met (raises EnvironmentFault after ``MAX_FAULTS``)."""
    import multiprocessing as mp

    order = {t.name: i for i, t in enumerate(targets)}
    want: dict[str, float] = {}
    for t in targets:
        acc = results.setdefault(t.name, TargetResult(t.name, t.what, decoder=t.decoder, goal=t.goal))
        acc.goal, acc.decoder = t.goal, t.decoder
        want[t.name] = (
            float(args.inputs if args.inputs is not None else t.goal) if by_count else args.budget * t.weight / total_w
        )
    flight: dict[str, float] = {t.name: 0.0 for t in targets}  # inputs (or seconds) the running chunks may add
    announced: set[str] = set()
    faults = 0

    def done(name: str) -> float:
        r = results[name]
        return float(r.inputs) if by_count else r.seconds

    def next_chunk() -> tuple[str, float, int, int | None] | None:
        for t in targets:
            left = want[t.name] - done(t.name) - flight[t.name]
            if left <= (0 if by_count else 0.5):
                continue
            if t.name not in announced:
                announced.add(t.name)
                what = f"until {want[t.name]:,.0f} inputs" if by_count else f"{want[t.name]:.0f} s"
                print(f"[fuzz] {t.name}: {what} on {t.what} ({args.jobs} jobs)", file=sys.stderr, flush=True)
            k = chunks.get(t.name, 0)
            chunks[t.name] = k + 1
            seed = args.seed * 1000 + order[t.name] + 100_003 * k
            if by_count:
                # split between the workers while there is much left; the rest in one chunk (no tail of tiny ones)
                n = math.ceil(left / args.jobs) if left >= JOB_MIN_INPUTS * args.jobs else math.ceil(left)
                flight[t.name] += n
                return t.name, args.progress, seed, n
            sec = min(args.progress, left)
            flight[t.name] += sec
            return t.name, sec, seed, None
        return None

    # forkserver, not fork: a fork copies the campaign's threads' held locks (a worker forked while another thread
    # held one waited for ever: seen in a test process); the server process inherits the memory cap (RLIMIT_AS)
    ctx = mp.get_context("forkserver")
    pool = ctx.Pool(args.jobs, initializer=_worker_init)
    running: list[tuple[Any, str, float]] = []
    try:
        while True:
            while len(running) < args.jobs and (job := next_chunk()) is not None:
                name, sec, seed, n = job
                running.append((pool.apply_async(_chunk, (name, sec, seed, n)), name, n if n is not None else sec))
            if not running:
                break
            ready = [j for j in running if j[0].ready()]
            if not ready:
                time.sleep(0.05)
                continue
            for j in ready:
                running.remove(j)
                fut, name, held = j
                flight[name] -= held
                try:
                    r = fut.get()
                except fuzz.EnvironmentFault as e:
                    faults = _environment_fault(e, faults)
                    continue
                acc = results[name]
                acc.add(r)
                print(f"[fuzz] {_line(acc)}", file=sys.stderr, flush=True)
                if args.state is not None:
                    _save_state(args.state, results, chunks)
                if done(name) + flight[name] >= want[name] - (0 if by_count else 0.5) and not flight[name]:
                    print(_line(acc), flush=True)
        # the clean end: the workers take their end-of-work sentinels and exit. Not terminate() here: it takes the
        # task queue's read lock for good and drains the queue, then joins the workers; once (a full test run)
        # a worker stayed blocked on that lock, alive, and the join never returned.
        pool.close()
        pool.join()
    except BaseException:
        pool.terminate()  # an error or Ctrl-C: the workers are stopped (SIGTERM)
        pool.join()
        raise
    return faults


def _ordered(results: dict[str, TargetResult]) -> list[TargetResult]:
    """The results in the order of :data:`ins_hil.fuzz.targets.TARGETS` (unknown names last)."""
    from ins_hil.fuzz.targets import TARGETS

    rank = {t.name: i for i, t in enumerate(TARGETS)}
    return sorted(results.values(), key=lambda r: rank.get(r.name, len(rank)))
