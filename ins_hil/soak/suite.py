"""A soak campaign: the main run, optional null-relay run, rate sweep per core and loaded run, one report.

With ``interleave`` > 0 the main run is the interleaved A/B run (``interleave/block-NN-gateway|floor/``,
:mod:`ins_hil.soak.interleave`), ``main/`` the optional continuous gateway run after it, ``profile/`` an
optional profiled gateway run (the loop's cost by stage), and each sweep point is interleaved too.

Layout of ``out``: ``main/`` (raw files + plots of the main run), ``relay/`` (the null relay right
after the main run with the same settings: the platform floor, :mod:`ins_hil.soak.relay`),
``sweep-<core>-<rate>/``, ``loaded/``, and at the top ``metrics.json`` and ``report.md``. With ``docs`` the report
is also written there (PNG plots copied next to it in ``<docs stem>/``).
"""

from __future__ import annotations

import json
import shutil
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

from ins_hil.runtime.mqtt_out import clean_json
from ins_hil.soak.analysis import analyse
from ins_hil.soak.baseline import cyclictest
from ins_hil.soak.baseline import section as baseline_section
from ins_hil.soak.interleave import analyse_blocks, block_dirs, dump, run_blocks, sweep_point
from ins_hil.soak.orchestrate import SoakOptions, cpus, run_soak
from ins_hil.soak.report import (
    floor_comparison,
    interleave_section,
    machine,
    plots,
    profile_section,
    run_section,
    sweep_interleaved_section,
    sweep_section,
)


def one(opt: SoakOptions, progress: Callable[[str], None] | None) -> tuple[dict[str, Any], list[str]]:
    """Run, analyse and plot one soak; (metrics, PNG names in opt.out)."""
    return reanalyse(run_soak(opt, progress))


def campaign(
    opt: SoakOptions,
    sweep_rates: list[float],
    sweep_cores: list[str],
    sweep_duration: float,
    loaded_duration: float,
    note: str,
    docs: str | None,
    progress: Callable[[str], None] | None = None,
    baseline_s: float = 0.0,
    relay_duration: float = 0.0,
    interleave: float = 0.0,
    continuous: float = 0.0,
    profile_duration: float = 0.0,
    can_duration: float = 0.0,
) -> dict[str, Any]:
    """Every run of the campaign and the report; returns the top-level metrics (``pass`` = main run).
    ``baseline_s`` > 0: first measure the platform's wake-up latency (cyclictest) on the soak's CPUs.
    ``relay_duration`` > 0: right after the main run, the null relay in the gateway's place for that
    long with the same settings (the platform floor; ``runs.relay``, compared in ``relay``)."""
    out = Path(opt.out)
    out.mkdir(parents=True, exist_ok=True)
    started = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime())
    mach_before = machine()
    base: dict[str, Any] | None = None
    if baseline_s > 0:
        if progress:
            progress(f"[soak] platform baseline: cyclictest on both CPUs, {baseline_s:.0f} s")
        base = cyclictest(baseline_s, sorted(set(cpus())))  # the soak's sensor and gateway CPUs
    runs: list[tuple[str, str, dict[str, Any], list[str]]] = []
    inter: dict[str, Any] | None = None
    if interleave > 0:
        d = run_blocks(replace(opt, out=str(out / "interleave")), interleave, progress)
        inter = analyse_blocks(d, analyse_only)
        dump(d, inter)
        if continuous > 0:
            if progress:
                progress(f"[soak] continuous gateway run (memory trend, one long flight): {continuous:.0f} s")
            m, p = one(replace(opt, duration=continuous, out=str(out / "main")), progress)
            runs.append(("main", CONTINUOUS_TITLE, m, p))
    else:
        main_opt = replace(opt, out=str(out / "main"))
        m, p = one(main_opt, progress)
        runs.append(("main", "Main run", m, p))
    can: dict[str, Any] | None = None
    if can_duration > 0 and interleave > 0:
        if progress:
            progress(f"[soak] DroneCAN over slcan, interleaved against its floor: {can_duration:.0f} s per side")
        co = replace(opt, transports="can,udp", imus=1, faults="none", links="shared", duration=can_duration,
                     out=str(out / "can"))  # fmt: skip
        cd = run_blocks(co, min(interleave, can_duration), None)
        can = analyse_blocks(cd, analyse_only)
        can["pass"] = bool(can["checks"]["ratio_p99"]["ok"] and can["checks"]["lost_frames"]["ok"])
        dump(cd, can)
    if profile_duration > 0:
        if progress:
            progress(f"[soak] profiled gateway run (cProfile: the loop's cost by stage): {profile_duration:.0f} s")
        pm, _ = one(replace(opt, duration=profile_duration, profile=True, out=str(out / "profile")), None)
        prof_table = pm.get("profile")
    else:
        prof_table = None
    if relay_duration > 0 and opt.gateway != "relay":
        ro = replace(opt, gateway="relay", duration=relay_duration, out=str(out / "relay"))
        if progress:
            progress(f"[soak] platform floor: the null relay in the gateway's place, {relay_duration:.0f} s")
        rm, rp = one(ro, progress)
        runs.append(("relay", RELAY_TITLE, rm, rp))
    sweep: list[dict[str, Any]] = []
    for core in sweep_cores:
        for rate in sweep_rates:
            so = replace(opt, core=core, rate=rate, duration=sweep_duration, out=str(out / f"sweep-{core}-{rate:.0f}"))
            if progress:
                progress(f"[soak] sweep: core {core}, {rate:.0f} Hz, {sweep_duration:.0f} s"
                         + (" per side, interleaved" if interleave > 0 else ""))  # fmt: skip
            if interleave > 0:
                sd = run_blocks(so, min(interleave, sweep_duration), None)
                sm = analyse_blocks(sd, analyse_only)
                dump(sd, sm)
                sweep.append(sweep_point(sm))
            else:
                sm, _ = one(so, None)
                sweep.append(sweep_row(sm))
    if loaded_duration > 0:
        lo = replace(opt, load=2, duration=loaded_duration, out=str(out / "loaded"))
        if progress:
            progress(f"[soak] loaded run: a busy process on each CPU, {loaded_duration:.0f} s")
        lm, lp = one(lo, progress)
        runs.append(("loaded", LOADED_TITLE, lm, lp))
    mach = machine()
    passed = [inter["pass"]] if inter is not None else []
    passed += [m["pass"] for k, _, m, _ in runs if k == "main"]
    if can is not None:
        passed.append(can["pass"])
    top = {"started": started, "machine_at_start": mach_before, "machine_at_end": mach, "note": note,
           "runs": {k: m for k, _, m, _ in runs}, "sweep": sweep, "pass": all(passed),
           "platform_baseline": base, "relay": relay_summary(runs), "interleave": inter,
           "profile": prof_table, "can": can}  # fmt: skip
    cmd = note_command(opt, sweep_rates, sweep_cores, sweep_duration, loaded_duration, docs, baseline_s,
                       relay_duration, interleave, continuous, profile_duration, can_duration)  # fmt: skip
    top["command"] = cmd
    write(out, top, runs, sweep, docs)
    return top


def analyse_only(d: Path) -> tuple[dict[str, Any], list[str], dict[str, Any]]:
    """Analyse one block of an interleaved run (no plots); (metrics, [], series), metrics.json written."""
    m, series = analyse(d)
    (d / "metrics.json").write_text(json.dumps(clean_json(m), indent=1))
    return m, [], series


def relay_summary(runs: list[tuple[str, str, dict[str, Any], list[str]]]) -> dict[str, Any] | None:
    """``relay`` of metrics.json: the null relay's end-to-end latency (the platform floor) beside the main
    run's, and the difference per percentile (µs); None without a relay run after a gateway main run."""
    by = {k: m for k, _, m, _ in runs}
    if "relay" not in by or "main" not in by or by["main"].get("gateway") == "relay":
        return None
    a, b = by["main"]["latency"]["end_to_end"], by["relay"]["latency"]["end_to_end"]
    keys = ("p50_us", "p99_us", "p999_us", "max_us")
    return {"label": by["relay"]["label"], "duration_s": by["relay"]["duration_s"], "end_to_end": b,
            "gateway_end_to_end": a, "gateway_minus_floor_us": {k: a[k] - b[k] for k in keys},
            "lost_frames": by["relay"]["frames"]["lost"], "pass": by["relay"]["pass"]}  # fmt: skip


def sweep_row(m: dict[str, Any]) -> dict[str, Any]:
    """One line of the rate sweep from a run's metrics."""
    o, e, c = m["options"], m["latency"]["end_to_end"], m["checks"]
    return {"core": o["core"], "rate": float(o["rate"]), "load": o["load"], "p99_us": e["p99_us"],
            "p999_us": e["p999_us"], "lost": m["frames"]["lost"],
            "ok": c["e2e_p999_steal_free"]["ok"] is not False and c["lost_frames"]["ok"]}  # fmt: skip


def rerender(out: str | Path, docs: str | None) -> dict[str, Any]:
    """Analyse the raw files of an earlier campaign in ``out`` again and rewrite its report (no new run)."""
    out = Path(out)
    try:
        old = json.loads((out / "metrics.json").read_text())
    except (OSError, ValueError) as e:
        raise RuntimeError(f"{out}: not a soak output directory (metrics.json: {e})") from None
    runs: list[tuple[str, str, dict[str, Any], list[str]]] = []
    main_title = CONTINUOUS_TITLE if (out / "interleave").is_dir() else "Main run"
    for key, title in (("main", main_title), ("relay", RELAY_TITLE), ("loaded", LOADED_TITLE)):
        if (out / key / "options.json").exists():
            m, pngs = reanalyse(out / key)
            runs.append((key, title, m, pngs))
    sweep = []
    for d in sorted(out.glob("sweep-*"), key=lambda p: (p.name.split("-")[1], float(p.name.split("-")[2]))):
        if block_dirs(d):
            sm = analyse_blocks(d, analyse_only)
            dump(d, sm)
            sweep.append(sweep_point(sm))
        else:
            m, _ = reanalyse(d)
            sweep.append(sweep_row(m))
    inter = None
    if block_dirs(out / "interleave"):
        inter = analyse_blocks(out / "interleave", analyse_only)
        dump(out / "interleave", inter)
    old.pop("can", None)
    if block_dirs(out / "can"):
        can = analyse_blocks(out / "can", analyse_only)
        can["pass"] = bool(can["checks"]["ratio_p99"]["ok"] and can["checks"]["lost_frames"]["ok"])
        dump(out / "can", can)
        old["can"] = can
    if (out / "profile" / "options.json").exists():
        old["profile"] = analyse(out / "profile")[0].get("profile")
    passed = [inter["pass"]] if inter is not None else []
    passed += [m["pass"] for k, _, m, _ in runs if k == "main"]
    if old.get("can") is not None:
        passed.append(old["can"]["pass"])
    top = {**old, "runs": {k: m for k, _, m, _ in runs}, "sweep": sweep, "pass": all(passed),
           "relay": relay_summary(runs), "interleave": inter}  # fmt: skip
    write(out, top, runs, sweep, docs)
    return top


def reanalyse(d: Path) -> tuple[dict[str, Any], list[str]]:
    """Analyse and plot the raw files of one run in ``d``; (metrics, PNG names), metrics.json written."""
    m, series = analyse(d)
    pngs = plots(d, series, relay=m["gateway"] == "relay")
    (d / "metrics.json").write_text(json.dumps(clean_json(m), indent=1))
    return m, pngs


LOADED_TITLE = "Under background load (one busy-loop process on each of the 2 CPUs)"
RELAY_TITLE = "Platform floor: null relay"
CAN_TITLE = "DroneCAN over slcan: the CAN path against its floor"
CONTINUOUS_TITLE = "Continuous gateway run (memory trend, accuracy over one long flight)"


def write(
    out: Path,
    top: dict[str, Any],
    runs: list[tuple[str, str, dict[str, Any], list[str]]],
    sweep: list[dict[str, Any]],
    docs: str | None,
) -> None:
    """metrics.json and report.md in ``out``; with ``docs`` the report there and its plots beside it."""
    cmd = top.get("command", "")
    (out / "metrics.json").write_text(json.dumps(clean_json(top), indent=1))
    (out / "report.md").write_text(render(top, runs, sweep, cmd, lambda key: f"{key}/"))
    if docs:
        dp = Path(docs)
        img = dp.parent / dp.stem
        img.mkdir(parents=True, exist_ok=True)
        for old in img.glob("*.png"):
            old.unlink()
        for key, _, _, pngs in runs:
            for png in pngs:
                shutil.copy(out / key / png, img / f"{key}-{png}")
        dp.write_text(render(top, runs, sweep, cmd, lambda key: f"{dp.stem}/{key}-"))


def note_command(opt: SoakOptions, rates: list[float], cores: list[str], sd: float, ld: float,
                 docs: str | None, baseline_s: float = 0.0, relay_s: float = 0.0, interleave: float = 0.0,
                 continuous: float = 0.0, profile_s: float = 0.0, can_s: float = 0.0) -> str:  # fmt: skip
    """The command line that reproduces this campaign."""
    parts = [f"scripts/soak --duration {opt.duration:g} --rate {opt.rate:g} --imus {opt.imus} --core {opt.core}"]
    if interleave > 0:
        parts.append(f"--interleave {interleave:g}")
        if continuous > 0:
            parts.append(f"--continuous {continuous:g}")
        if can_s > 0:
            parts.append(f"--can-duration {can_s:g}")
    if profile_s > 0:
        parts.append(f"--profile-duration {profile_s:g}")
    if opt.gateway != "ins-hil":
        parts.append(f"--gateway {opt.gateway}")
    if opt.transports.replace(" ", "") != "serial,udp":
        parts.append(f"--transports {opt.transports}")
    parts.append(f"--baseline {baseline_s:g}")
    if relay_s > 0 and opt.gateway == "ins-hil":
        parts.append(f"--relay-duration {relay_s:g}")
    if opt.imus > 1:
        parts.append(f"--faults {opt.faults}")
    if opt.load:
        parts.append(f"--load {opt.load}")
    if rates:
        parts.append(f"--sweep {','.join(f'{r:g}' for r in rates)} --sweep-cores {','.join(cores)} "
                     f"--sweep-duration {sd:g}")  # fmt: skip
    if ld:
        parts.append(f"--loaded-duration {ld:g}")
    parts.append(f"--out {opt.out}")
    if docs:
        parts.append(f"--docs {docs}")
    return " ".join(parts)


def load_lines(ma: dict[str, Any]) -> list[str]:
    """The report's note on the machine load before the soak (``ma``: ``report.machine()`` at the start)."""
    # The load at the end includes the soak's own processes (~1) and, after a loaded run, its busy
    # loops (+2): only the load before the soak started says whether something else was running.
    lines: list[str] = []
    l1 = float(ma["loadavg"][0])
    if l1 != l1:  # NaN: the OS gives no load average (ins_hil.machine.load_average)
        lines += ["> **Machine load unknown:** the OS gives no load average.", ""]
    elif l1 > 1.0:  # a decaying 1-min average: < 1 on 2 CPUs is a recently finished job
        lines += [
            f"> **Busy machine:** the 1-minute load average was {l1:.2f} before the soak "
            f"started on {ma['nproc']} CPUs, so other processes shared the CPUs "
            "with the pinned soak processes: the timing figures below are contaminated (upper bounds), the "
            "loss, memory, accuracy and fault figures are not timing-sensitive unless frames were lost.",
            "",
        ]
    else:
        lines += [
            f"> **Idle machine:** load average {l1:.2f} before the soak started; the load at "
            "the end is the soak's own processes (and the loaded run's busy loops, if any).",
            "",
        ]
    return lines


def render(
    top: dict[str, Any],
    runs: list[tuple[str, str, dict[str, Any], list[str]]],
    sweep: list[dict[str, Any]],
    cmd: str,
    rel: Callable[[str], str],
) -> str:
    """The whole markdown report."""
    ma, mb = top["machine_at_start"], top["machine_at_end"]
    main = runs[0][2] if runs else {}
    inter = top.get("interleave")
    lines = [
        "# Soak test report",
        "",
        "Generated by `ins-hil soak` (ins_hil/soak). Reproduce with:",
        "",
        f"    {cmd}",
        "",
        f"Started {top['started']}. Machine: {ma['nproc']} CPUs, {ma['cpu_model']}, kernel {ma['kernel']}, "
        f"Python {ma['python']}. Load average at start {', '.join(f'{x:.2f}' for x in ma['loadavg'])}, "
        f"at end {', '.join(f'{x:.2f}' for x in mb['loadavg'])}; busiest processes at the end: "
        f"{mb['busiest_processes']}.",
        "",
    ]
    if top["note"]:
        lines += [f"> **Note:** {top['note']}", ""]
    lines += load_lines(ma)
    lines += [
        "Set-up: the simulated sensors (serial IMU frames into a pty — the frames of redundant IMUs "
        "interleaved on one link by imu_id unless `--imu-links separate` —, GNSS GPS_INPUT + baro "
        "SCALED_PRESSURE as MAVLink 2 over UDP) run in their own process pinned to one CPU together with "
        "the ground-station client (pymavlink, receiving the gateway's MAVLink over UDP); the gateway "
        "(ins_hil.runtime, the same code as `ins-hil run`) runs alone on the other CPU. "
        "With `--transports can,udp` the IMUs are DroneCAN nodes (RawIMU at the IMU rate + NodeStatus once a "
        "second, node ids 10, 11, …) whose frames go as slcan lines into one pty, "
        "read by the gateway's CAN driver through python-can's `slcan` interface (no kernel CAN support needed) "
        "and by the null relay with the gateway's DroneCAN decoder. "
        "End-to-end latency = ground-station receive time − the "
        "simulator's emission stamp of the IMU epoch named by the message's sensor time (ODOMETRY "
        "time_usec), both CLOCK_MONOTONIC. The ODOMETRY rate (47 Hz by default) is no multiple of the IMU "
        "or GNSS periods, so the measured epochs sweep every phase of the 200 ms GNSS cycle (at 50 Hz, with "
        "one clock for every process, a run would sample one fixed phase). Unless `--no-rt`, the sensors, "
        "the gateway (`gateway.rt_priority`) and the client run under SCHED_FIFO (60/50/40), as a deployed "
        "gateway would; the sensor data are made ahead of time by a low-priority producer process.",
        "",
        "Targets (1 kHz, Python core, 2 CPUs; the tail judged against the platform floor measured in the same "
        "interleaved run): gateway end-to-end p99 ≤ 1.2 × floor p99 and p99.9 ≤ 1.5 × floor p99.9; in the seconds "
        "without host steal, gateway end-to-end p99.9 ≤ 2 ms and loop arrival → state p99.9 ≤ 1 ms; no lost "
        "frames; gateway RSS growth < 1 MiB/h after warm-up (judged on ≥ 10 min after the warm-up); every "
        "injected fault isolated, no false alarm; horizontal error inside the filter's 3σ (per axis) in ≥ 99 % "
        "of the epochs and horizontal RMS ≤ 0.3 m. "
        f"**Campaign: {'pass' if top['pass'] else 'FAIL'}.**",
        "",
    ]
    bs = baseline_section(top.get("platform_baseline"))
    if bs:
        lines.append(bs)
    if inter is not None:
        lines.append(interleave_section(inter))
    if top.get("can") is not None:
        lines.append(interleave_section(top["can"], CAN_TITLE, can=True))
    prof = top.get("profile")
    if prof:
        lines.append(profile_section(prof))
    for key, title, m, pngs in runs:
        cmp = floor_comparison(main, m) if key == "relay" and main and main.get("gateway") != "relay" else ""
        lines.append(run_section(m, pngs, title, rel(key), preface=cmp))
    if sweep:
        interleaved = "ratio_p99" in sweep[0]
        lines.append(sweep_interleaved_section(sweep) if interleaved else sweep_section(sweep))
    return "\n".join(lines)
