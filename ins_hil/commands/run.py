"""`ins-hil run`: the real-time gateway (default: configs/default.toml, simulated sensors)."""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import math
import os
import sys
from typing import Any

EXIT_NO_INPUT = 3  # an input delivered nothing within gateway.input_timeout

NAME = "run"
HELP = "run the gateway (default: configs/default.toml, simulated sensors, MAVLink to udpout:127.0.0.1:14550)"
DESCRIPTION = (
    "Run the real-time gateway. With no arguments it runs configs/default.toml: simulated IMU (1 kHz serial "
    "frames over a pty), GNSS and baro (MAVLink over UDP), publishing MAVLink to udpout:127.0.0.1:14550 "
    "(QGroundControl) and MQTT to 127.0.0.1:1883 when a broker is running, with a live status view. "
    "At start it says where each input comes from, where MAVLink goes, the MQTT broker and the recording; "
    "an input or output that fails is reported once with its error (config path, e.g. inputs[0] (imu0)). "
    "Ctrl-C stops cleanly (recorder flushed); a second Ctrl-C exits at once. Exit status: 0 after a clean "
    "stop, 1 on a runtime error, 2 on a bad config or argument, 3 when an input delivered nothing within "
    "gateway.input_timeout (default 10 s; 0 = wait for ever)."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", metavar="TOML", help="configuration file (default: configs/default.toml)")
    p.add_argument("--core", choices=["python", "c"], help="navigation core (overrides core.kind)")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds (default: until Ctrl-C)")
    p.add_argument(
        "--no-status", action="store_true", help="no live view: one status line every 5 s, warnings as they occur"
    )
    p.add_argument("--record", metavar="PATH", help="recorder file (default: recorder.dir/ins-hil-<time>.ihlog)")
    p.add_argument("--no-mqtt", action="store_true", help="do not publish MQTT")
    p.add_argument("--json", metavar="PATH", help="write the final metrics snapshot as JSON")


def _fmt(v: float, unit: str = "") -> str:
    return "—" if v is None or not math.isfinite(v) else f"{v:,.0f}{unit}" if abs(v) >= 100 else f"{v:.2f}{unit}"


def _waiting(gw: Any) -> str:
    """The core's alignment status ("" when it navigates or there is no core)."""
    core = getattr(gw.pipeline, "core", None)
    return core.align_status() if core is not None else ""


STOP_HINT = "Ctrl-C to stop"  # on the live view's first line


def _output_counters(d: dict[str, int]) -> str:
    """One output's counters in a line: the MAVLink messages sent (upper-case keys) as their total, then
    the rest (link errors, MQTT states, …) by name; bytes left out."""
    sent = sum(v for k, v in d.items() if k.isupper())
    rest = [f"{k} {v:,}" for k, v in sorted(d.items()) if not k.isupper() and k != "bytes"]
    return "  ".join(([f"{sent:,} msgs"] if sent else []) + rest) or "—"


def render(gw: Any) -> Any:
    """The live status view of a running gateway: one screen of an 80-column terminal (cells fold,
    nothing is cut at the edge), the stop hint on its first line, the solution and problems before the
    counters (a terminal shorter than the view loses the bottom: the latency table)."""
    from pathlib import Path

    from rich import box
    from rich.console import Group
    from rich.table import Table
    from rich.text import Text

    snap = gw.metrics.snapshot()
    st = gw.pipeline.last_state

    def table(*cols: str) -> Table:
        t = Table(box=box.SIMPLE_HEAD, show_edge=False, pad_edge=False, padding=(0, 1), header_style="bold")
        for i, c in enumerate(cols):
            t.add_column(c, overflow="fold", justify="left" if i == 0 or c in ("dropped", "counters") else "right")
        return t

    head = Table.grid(expand=True, padding=(0, 1))
    head.add_column(overflow="fold")
    head.add_column(justify="right", no_wrap=True)
    align = "[green]aligned[/green]" if snap["aligned"] else "[yellow]aligning[/yellow]"
    up = int(snap["uptime_s"])
    head.add_row(
        f"[b]ins-hil[/b]  up {up // 3600}:{up // 60 % 60:02d}:{up % 60:02d}  core {gw.cfg.pipeline.core}  {align}  "
        f"FDI {snap['fdi_state']}",
        f"[b]{STOP_HINT}[/b]",
    )
    parts: list[Any] = [head]
    waiting = "" if snap["aligned"] else _waiting(gw)
    if waiting:
        parts.append(Text(waiting, style="yellow"))
    if st is not None:
        from ins_hil.nav.rotation import euler_from_quat

        e = [math.degrees(float(x)) for x in euler_from_quat(st.q_nb)]
        v = st.vel_ned
        parts.append(f"t {st.t:.2f} s  lat {math.degrees(st.lat):.6f}  lon {math.degrees(st.lon):.6f}  h {st.h:.1f} m")
        parts.append(f"v {v[0]:.1f} {v[1]:.1f} {v[2]:.1f} m/s  rpy {e[0]:.1f} {e[1]:.1f} {e[2]:.1f}°")
        parts.append("test ratios  " + ("  ".join(f"{k} {x:.2f}" for k, x in snap["test_ratios"].items()) or "—"))
    config = Path(gw.cfg.source).name if gw.cfg.source else "—"
    parts.append(
        f"faults {snap['faults']}  late {snap['late']:,}  queue max {snap['queue_depth_max']}  config {config}"
    )
    bad = _rejections(snap)
    if bad:
        parts.append("rejected / recovered: " + ", ".join(f"{k} {x}" for k, x in bad.items()))
    if snap["warnings"]:
        parts.append(Text(snap["warnings"][-1], style="yellow"))  # (Text: brackets in a warning are no markup)
    last = snap["warnings"][-1] if snap["warnings"] else ""
    for path, text in getattr(gw, "problems", {}).items():  # unresolved input/output errors, each with its text
        if f"{path}: {text}" != last:
            parts.append(Text(f"{path}: {text}", style="red"))
    t_in = table("input", "rate Hz", "received", "dropped")
    for name, src in snap["sources"].items():
        drops = ", ".join(f"{k} {x}" for k, x in src["dropped"].items() if x) or "0"
        t_in.add_row(name, f"{src['rate_hz']:.1f}", f"{src['received']:,}", drops)
    t_out = table("output", "counters")
    for name, d in snap["outputs"].items():
        t_out.add_row(name, _output_counters(d))
    if gw.mqtt is not None:
        t_out.add_row("mqtt link", "connected" if gw.mqtt.connected else f"offline {gw.mqtt.last_error}")
    t_lat = table("latency µs", "p50 5 s/all", "p99 5 s/all", "p99.9", "max", "count")
    for k, label in (("arrival_to_state", "arrival→state"), ("state_to_sent", "state→sent"),
                     ("arrival_to_sent", "arrival→sent"), ("core_step", "core step")):  # fmt: skip
        w, tot = snap["latency_window"][k], snap["latency"][k]
        t_lat.add_row(
            label,
            f"{_fmt(w['p50_us'])} / {_fmt(tot['p50_us'])}",
            f"{_fmt(w['p99_us'])} / {_fmt(tot['p99_us'])}",
            _fmt(tot["p999_us"]),
            _fmt(tot["max_us"]),
            f"{tot['count']:,}",
        )
    return Group(*parts, t_in, t_out, t_lat)


def _rejections(snap: dict[str, Any]) -> dict[str, int]:
    """The pipeline's validation rejections (``reject_*``) and core recoveries (``core_*``, ``pipeline_error``)."""
    return {k: v for k, v in sorted(snap.get("fused", {}).items())
            if v and (k.startswith(("reject_", "core_")) or k == "pipeline_error")}  # fmt: skip


def _summary_line(gw: Any) -> str:
    s = gw.metrics.snapshot()
    lat = s["latency"]["arrival_to_sent"]
    rates = " ".join(f"{n} {v['rate_hz']:.0f}Hz" for n, v in s["sources"].items())
    return (
        f"[ins-hil] {s['uptime_s']:.0f} s  {rates}  epochs {s['imu_epochs']}  late {s['late']}  "
        f"dropped {gw.metrics.dropped_total()}  arrival→sent p50 {_fmt(lat['p50_us'])} µs "
        f"p99 {_fmt(lat['p99_us'])} µs  aligned {s['aligned']}  faults {s['faults']}"
        f"  rejected {sum(v for k, v in _rejections(s).items() if k.startswith('reject_'))}"
    )


def _final_line(gw: Any) -> str:
    """The summary printed once at the end: the status line with why the run stopped."""
    why = gw.stopped_reason or "stop"
    return _summary_line(gw).replace("[ins-hil] ", f"[ins-hil] summary (stopped: {why}) after ", 1)


async def _status_live(gw: Any) -> None:
    from rich.live import Live

    with Live(render(gw), auto_refresh=False, transient=False) as live:  # (taller than the terminal: bottom cut)
        while True:
            await asyncio.sleep(gw.cfg.gateway.status_period)
            live.update(render(gw), refresh=True)


async def _status_lines(gw: Any) -> None:
    """``--no-status``: a status line every 5 s (warnings are logged as they occur, see :class:`_Stderr`)."""
    while True:
        await asyncio.sleep(5.0)
        if gw.stopped_reason:  # stopping: the summary follows
            return
        print(_summary_line(gw), file=sys.stderr, flush=True)


async def _watch_inputs(gw: Any, timeout: float, missing: list[str]) -> None:
    """After ``timeout`` s (``gateway.input_timeout``; 0 = never), every configured input that delivered
    nothing goes to ``missing`` (its config path; its error, if any, was reported when it occurred) and
    the gateway is stopped."""
    if timeout <= 0:
        return
    await asyncio.sleep(timeout)
    for i, ic in enumerate(gw.cfg.inputs):
        src = gw.metrics.sources.get(ic.name)
        if src is None or src.received == 0:
            path = f"inputs[{i}] ({ic.name})"
            missing.append(path if path in gw.problems else f"{path} (no error, nothing received)")
    if missing:
        gw.request_stop(f"no data from {len(missing)} input(s) within {timeout:g} s")


class _Stderr(logging.Handler):
    """The gateway's log (logger ``ins_hil``) on the current ``sys.stderr``: under the live view that is
    rich's redirection, so a line appears above the view instead of breaking it."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            level = "" if record.levelno < logging.WARNING else record.levelname.lower() + ": "
            print(f"[ins-hil] {level}{record.getMessage()}", file=sys.stderr, flush=True)
        except Exception:
            self.handleError(record)


def _prepare(args: argparse.Namespace, path: Any) -> tuple[Any, Any]:
    """The whole configuration, validated (the core built once: its imports), with the command's
    overrides, and the simulator's devices factory when ``[sim]`` is enabled (ConfigError)."""
    from ins_hil import config as config_mod

    cfg = config_mod.load(path)
    if args.core:
        cfg.pipeline.core = args.core
    if args.no_mqtt:
        cfg.mqtt.enabled = False
    devices = None
    if cfg.sim_enabled:  # the simulated sensors: their process is started and stopped by the gateway run
        from functools import partial

        from ins_hil.sim.devices import SimDevices

        devices = partial(SimDevices, cfg.sim)
    return cfg, devices


def _config_error(e: Exception, path: Any) -> str:
    """The one line of a bad config; a dataset config given as the gateway's says so."""
    from ins_hil.commands._inputs import HINTS, config_kind

    hint = f" ({HINTS['dataset']})" if config_kind(path) == "dataset" else ""
    return f"ins-hil run: config error: {e}{hint}"


async def _start(args: argparse.Namespace, path: Any, outputs: list[Any]) -> Any:
    """Start-up in the order a ground station sees it: the MAVLink outputs open and send their first
    HEARTBEAT, then the whole config is validated (in a thread, its heavy imports too, while the
    heartbeat goes on), then the gateway is built (core, recorder, MQTT; its run starts the simulator
    and the inputs). Returns the gateway, or the exit status of a bad config (2)."""
    from ins_hil import config as config_mod
    from ins_hil.runtime.loop import Gateway, open_outputs

    opened = await open_outputs(outputs)
    try:
        cfg, devices = await asyncio.to_thread(_prepare, args, path)
        return Gateway(cfg, record_path=args.record, devices=devices, outputs=opened)
    except config_mod.ConfigError as e:
        print(_config_error(e, path), file=sys.stderr)
    except (RuntimeError, ValueError) as e:
        print(f"ins-hil run: {e}", file=sys.stderr)
    except BaseException:  # another error, Ctrl-C: the outputs closed before it goes on
        await opened.close()
        raise
    await opened.close()
    return 2


def run(args: argparse.Namespace) -> int:
    from ins_hil import config as config_mod

    path = args.config or config_mod.default_path()
    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        print(f"ins-hil run: --duration {args.duration:g}: must be a positive number of seconds (leave it out to run "
              "until Ctrl-C)", file=sys.stderr)  # fmt: skip
        return 2
    from ins_hil.commands._outputs import out_file

    if args.record:  # the files written during or after the run: refused before it starts
        out_file(args.record, "--record")
        if os.path.lexists(args.record):  # the recorder truncates: an earlier recording would be lost
            print(f"ins-hil run: --record {args.record}: exists (an earlier recording?): give a new name or remove "
                  "it", file=sys.stderr)  # fmt: skip
            return 2
    if args.json:
        out_file(args.json, "--json")
    try:
        outputs = config_mod.load_outputs(path)  # only the [[outputs]]: they open first (see _start)
    except config_mod.ConfigError as e:
        print(_config_error(e, path), file=sys.stderr)
        return 2
    interactive = not args.no_status and sys.stdout.isatty()
    view = _status_live if interactive else _status_lines
    missing: list[str] = []

    async def status(g: Any) -> None:
        await asyncio.gather(view(g), _watch_inputs(g, g.cfg.gateway.input_timeout, missing))

    async def main() -> Any:
        gw = await _start(args, path, outputs)
        if not isinstance(gw, int):
            await gw.run(duration=args.duration, status=status)
        return gw

    log = logging.getLogger("ins_hil")
    handler = _Stderr()
    log.addHandler(handler)
    log.setLevel(logging.INFO)
    log.propagate = False
    try:
        gw = asyncio.run(main())
    except (OSError, RuntimeError, ValueError) as e:  # e.g. a device or URL that cannot be opened
        print(f"ins-hil run: {e}", file=sys.stderr)
        return 1
    finally:
        log.removeHandler(handler)
        log.propagate = True
    if isinstance(gw, int):
        return gw
    print(_final_line(gw), file=sys.stderr)
    if gw.recorder is not None:
        print(f"[ins-hil] recorded {gw.recorder.records} inputs to {gw.recorder.paths[0]}", file=sys.stderr)
    if args.json:
        from ins_hil.runtime.mqtt_out import clean_json

        with open(args.json, "w") as f:
            json.dump(clean_json(gw.metrics.snapshot()), f, indent=1)
    if missing:
        t = gw.cfg.gateway.input_timeout
        print(f"ins-hil run: no data within gateway.input_timeout = {t:g} s from {', '.join(missing)}", file=sys.stderr)
        return EXIT_NO_INPUT
    return 0
