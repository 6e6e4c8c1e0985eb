"""Latency report of the real-time loop at 1 kHz: ``python -m ins_hil.bench.latency``.

Runs configs/default.toml (simulated 1 kHz IMU over a pty, GNSS/baro over
UDP, MAVLink out to udpout:127.0.0.1:14550, recorder on, MQTT off) for
``--duration`` seconds and prints the latency figures. Only when asked it
writes the report: ``--docs`` regenerates ``docs/runtime.md`` (the runtime
note with the measured table) and ``docs/runtime_latency.png`` (the latency
distributions); ``--out PATH`` writes them to PATH and ``runtime_latency.png``
beside it.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import subprocess
import tempfile
import time
from functools import partial
from importlib import resources
from pathlib import Path
from typing import Any

from ins_hil.config import default_path, load
from ins_hil.machine import CLK_TCK, steal_ticks, summary
from ins_hil.runtime.loop import Gateway
from ins_hil.runtime.metrics import _BASE_NS, _RATIO, LatencyHistogram
from ins_hil.sim.devices import SimDevices

REPO = Path(__file__).resolve().parent.parent.parent


def measure(duration: float, core: str = "python") -> tuple[Gateway, float]:
    """Run configs/default.toml (its simulator, MQTT off) for ``duration`` s on ``core``: the gateway
    (its metrics) and the wall time (s)."""
    cfg = load(default_path())
    cfg.mqtt.enabled = False
    cfg.pipeline.core = core
    with tempfile.TemporaryDirectory() as tmp:
        gw = Gateway(cfg, record_path=Path(tmp) / "bench.ihlog", devices=partial(SimDevices, cfg.sim))
        t0 = time.monotonic()
        asyncio.run(gw.run(duration=duration, signals=False))
        return gw, time.monotonic() - t0


def _plot(hists: dict[str, LatencyHistogram], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4.5))
    for name, h in hists.items():
        if not h.count:
            continue
        xs = [_BASE_NS * _RATIO ** (k + 0.5) * 1e-3 for k in range(len(h.buckets))]
        acc, ccdf = 0, []
        for c in h.buckets:
            acc += c
            ccdf.append(max(1.0 - acc / h.count, 1e-6))
        ax.loglog(xs, ccdf, label=name.replace("_", " "))
    ax.set_xlabel("latency (µs)")
    ax.set_ylabel("fraction of samples above")
    ax.set_xlim(10, 1e5)
    ax.set_ylim(1e-5, 1.1)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    ax.set_title("ins-hil loop latency at 1 kHz (complementary CDF)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _row(name: str, s: dict[str, Any]) -> str:
    return f"| {name} | {s['count']} | {s['p50_us']:.0f} | {s['p99_us']:.0f} | {s['p999_us']:.0f} | {s['max_us']:.0f} |"


_PATHS = (
    ("arrival_to_state", "arrival → state ready"),
    ("state_to_sent", "state ready → MAVLink sent"),
    ("arrival_to_sent", "arrival → MAVLink sent"),
    ("core_step", "pipeline call (core step)"),
)


def _rows(lat: dict[str, dict[str, Any]]) -> str:
    """The latency table's body rows from a metrics snapshot's ``latency`` entry (µs)."""
    return "\n".join(_row(label, lat[k]) for k, label in _PATHS)


def _table(gw: Gateway) -> str:
    return "| path | samples | p50 µs | p99 µs | p99.9 µs | max µs |\n|---|---:|---:|---:|---:|---:|\n" + _rows(
        gw.metrics.snapshot()["latency"]
    )


def template() -> str:
    """The report's Markdown prose with ``str.format`` fields (``latency_report.md``, package data)."""
    return resources.files("ins_hil.bench").joinpath("latency_report.md").read_text(encoding="utf-8")


def report(gw: Gateway, wall: float, duration: float, gw_c: Gateway | None = None, steal_s: float | None = None) -> str:
    """The Markdown report (``latency_report.md`` filled in) of a run of ``duration`` s taking ``wall`` s; ``gw_c``:
    the same run on the C core; ``steal_s``: host steal time during the runs (s)."""
    snap = gw.metrics.snapshot()
    lat = snap["latency"]
    imu = snap["sources"]["imu0"]
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True, text=True).stdout
    rows = _rows(lat)
    drops = ", ".join(f"{k} {v}" for k, v in imu["dropped"].items()) or "none"
    return template().format(
        machine=summary()
        + (
            ""
            if steal_s is None
            else f"; host steal time during the runs {steal_s:.2f} s over the {os.cpu_count()} CPUs (/proc/stat: "
            "the hypervisor ran other work on this virtual machine's CPUs, which no priority inside it prevents)"
        ),
        commit=commit.strip() or "?",
        duration=duration,
        wall=wall,
        epochs=snap["imu_epochs"],
        received=imu["received"],
        rate=imu["received"] / max(wall, 1e-9),
        late=snap["late"],
        late_ms=snap["late_threshold_ms"],
        drops=drops,
        qmax=snap["queue_depth_max"],
        rows=rows,
        sent=snap["outputs"].get("gcs", {}).get("ATTITUDE", 0),
        c_section=(
            ""
            if gw_c is None
            else "\nThe same run with the C reference core (`--core c`, `ins_hil.cref.CNavCore`, covariance "
            f"propagated every step), late {gw_c.metrics.late}:\n\n{_table(gw_c)}\n"
        ),
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--duration", type=float, default=30.0, help="seconds to run (default 30)")
    ap.add_argument("--no-c", action="store_true", help="skip the second run with the C core")
    where = ap.add_mutually_exclusive_group()
    where.add_argument("--out", metavar="PATH", help="write the report to PATH (and runtime_latency.png beside it)")
    where.add_argument("--docs", action="store_true", help="regenerate docs/runtime.md and docs/runtime_latency.png")
    a = ap.parse_args(argv)
    if a.docs:
        a.out = str(REPO / "docs" / "runtime.md")
    print(f"ins-hil bench: {a.duration:.0f} s of configs/default.toml at 1 kHz …", flush=True)
    cpus = tuple(range(os.cpu_count() or 1))
    st0 = sum(steal_ticks(cpus))
    gw, wall = measure(a.duration, "python")
    gw_c = None
    if not a.no_c:
        print(f"… and {a.duration:.0f} s with --core c", flush=True)
        try:
            gw_c, _ = measure(a.duration, "c")
        except RuntimeError as e:
            print(f"C core not measured: {e}")
    steal_s = (sum(steal_ticks(cpus)) - st0) / CLK_TCK
    text = report(gw, wall, a.duration, gw_c, steal_s)
    table = text[text.index("| path |") : text.index("\n\nArrival")]
    print(table)
    if gw_c is not None:
        print("C core:\n" + _table(gw_c))
    if a.out:
        out = Path(a.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(text)
        _plot(gw.metrics.hist, out.with_name("runtime_latency.png"))
        print(f"wrote {out} and {out.with_name('runtime_latency.png')}")
    else:
        print("(figures only: --out PATH or --docs writes the report)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
