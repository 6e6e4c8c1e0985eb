"""Soak gateway process: the real :class:`~ins_hil.runtime.loop.Gateway`, pinned, with measurement taps.

Built from a config dict (validated by :func:`ins_hil.config.from_dict`): the serial IMUs
are the soak simulator's ptys, GNSS/baro a ``udpin:`` MAVLink input, one MAVLink output to
the ground-station client. With ``--imus`` > 1 the FDI monitor gets an
:class:`~ins_hil.fdi.monitor.FdiConfig` matching the simulated sensors.

Taps (no change to the runtime): an ``on_state`` callback measures the loop period
(state-ready to state-ready) and its deviation from 1/rate; ``on_fault`` keeps every
FaultEvent; a status task samples the metrics and queue depth every second into
``gateway_ts.jsonl`` (with the per-second bucket deltas of the loop histograms, :data:`HIST_KEYS`).
At the end ``gateway.json`` holds the final metrics snapshot; with ``--profile`` a cProfile of the
whole run goes to ``profile.pstats`` (the loop's cost by function, :mod:`ins_hil.soak.budget`).
Prints ``{"ready": true}`` once every transport is open.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
import time
from pathlib import Path
from typing import Any

from ins_hil.config import from_dict
from ins_hil.runtime.metrics import LatencyHistogram
from ins_hil.soak.simproc import CAN_NODE_BASE, die_with_parent, pin
from ins_hil.types import FaultEvent, NavState


def gateway_config(a: argparse.Namespace) -> dict[str, Any]:
    """The gateway config (TOML layout) of a soak run."""
    period_ms = 1000.0 / a.rate
    rates = {"HEARTBEAT": 1.0, "SYS_STATUS": 1.0, "ATTITUDE": 10.0, "ATTITUDE_QUATERNION": 0.0,
             "GLOBAL_POSITION_INT": 10.0, "LOCAL_POSITION_NED": 0.0, "GPS_RAW_INT": 0.0, "VFR_HUD": 0.0,
             "ESTIMATOR_STATUS": 0.0, "ODOMETRY": a.gcs_rate}  # fmt: skip
    return {
        "gateway": {"name": "ins-hil-soak", "late_threshold_ms": period_ms, "queue_size": 4096, "rt_priority": a.rt},
        # the navigation settings of configs/default.toml (what `ins-hil run` ships: covariance every
        # 10 steps, no delayed-fusion rollback), not NavConfig's offline defaults
        "core": {"kind": a.core, "init": "gnss", "nav": default_nav()},
        "fdi": {
            "enabled": a.imus > 1,
            "imu_ids": [CAN_NODE_BASE + u for u in range(a.imus)] if a.imu_transport == "can" else list(range(a.imus)),
            **({"options": fdi_options(a.imus, a.rate)} if a.imus > 1 else {}),
        },
        "sim": {"enabled": False},
        "inputs": [
            *(imu_inputs(a)),
            {"name": "gnss", "type": "mavlink", "url": f"udpin:127.0.0.1:{a.gnss_port}"},
        ],
        "outputs": [
            {"name": "gcs", "type": "mavlink", "url": f"udpout:127.0.0.1:{a.gcs_port}", "role": "gcs", "rates": rates}
        ],
        "mqtt": {"enabled": False},
        "recorder": {"enabled": a.record, "dir": str(a.out)},
    }


def imu_inputs(a: argparse.Namespace) -> list[dict[str, Any]]:
    """The IMU ``[[inputs]]``: one serial IMU per link, or (``--imu-transport can``) one CAN IMU driver on
    the slcan pty, listen-only (no node id of its own: nothing is written back to the simulator), taking
    the DroneCAN nodes of the simulated units (``imu_id`` = node id)."""
    if a.imu_transport == "can":
        nodes = [CAN_NODE_BASE + u for u in range(a.imus)]
        opts = {"interface": "slcan", "channel": a.imu[0], "sleep_after_open": 0, "bitrate": 1000000,
                "protocol": "dronecan", "nodes": nodes, "node_id": 0}  # fmt: skip
        return [{"name": "imu0", "type": "can_imu", "options": opts}]
    return [{"name": f"imu{j}", "type": "serial_imu", "port": p, "baud": 921600} for j, p in enumerate(a.imu)]


def default_nav() -> dict[str, Any]:
    """The ``[core.nav]`` table of configs/default.toml (the shipped speed settings of the 1 kHz loop)."""
    import tomllib

    from ins_hil.config import default_path

    with open(default_path(), "rb") as f:
        nav = tomllib.load(f).get("core", {}).get("nav", {})
    return dict(nav)


#: fault events kept for the report (the rest are only counted)
MAX_EVENTS = 10000
#: s healthy before an excluded sensor is taken back (FdiConfig.readmit_after)
READMIT_S = 2.0


def fdi_options(n_imus: int, rate: float) -> dict[str, Any]:
    """``[fdi.options]`` for the simulated sensors (stochastic MEMS errors of ins_hil.sim.redundant)."""
    from ins_hil.sim.sensors import mems_accel, mems_gyro
    from ins_hil.soak.faults import geometry_for

    g, ac = mems_gyro(), mems_accel()
    # readmit_after: a unit that dropped out because its frames were lost in transport comes back
    # once healthy again (a faulty sensor's residual never passes, so it stays excluded)
    return {"geometry": geometry_for(n_imus).name, "dt": 1.0 / rate, "gyro_noise": g.noise_density,
            "accel_noise": ac.noise_density, "gyro_bias": g.bias_instability, "accel_bias": ac.bias_instability,
            "readmit_after": READMIT_S}  # fmt: skip


async def _run(a: argparse.Namespace) -> int:
    from ins_hil.runtime.loop import Gateway

    out = Path(a.out)
    cfg = from_dict(gateway_config(a), source="soak")
    gw = Gateway(cfg, record_path=out / "recording.ihlog" if a.record else None)
    period_ns = round(1e9 / a.rate)
    jitter = LatencyHistogram()  # |period − nominal|
    period = LatencyHistogram()
    last = [0]
    mono = time.monotonic_ns
    faults: list[dict[str, Any]] = []
    n_over = [0]

    def on_state(_st: NavState) -> None:
        now = mono()
        if last[0]:
            d = now - last[0]
            period.record(d)
            jitter.record(abs(d - period_ns))
        last[0] = now

    def on_fault(ev: FaultEvent) -> None:
        if len(faults) >= MAX_EVENTS:  # a flood of events must not grow memory over hours
            n_over[0] += 1
            return
        faults.append({"t": ev.t, "sensor": ev.sensor, "mode": ev.mode.name, "isolated": ev.isolated,
                       "cleared": ev.cleared, "detail": ev.detail, "recv_ns": mono()})  # fmt: skip

    gw.on_state.append(on_state)
    gw.on_fault.append(on_fault)
    gc_stats = _gc_probe()

    async def sampler(g: Any) -> None:
        print(json.dumps({"ready": True}), flush=True)
        prev = {key: list(g.metrics.hist[key].buckets) for key in HIST_KEYS}
        with open(out / "gateway_ts.jsonl", "w") as f:
            k = 0
            qmax = 0
            while True:
                await asyncio.sleep(0.1)
                qmax = max(qmax, len(g.queue))
                k += 1
                if k % 10:
                    continue
                s = g.metrics.snapshot()
                row = {
                    "mono_ns": mono(),
                    "epochs": s["imu_epochs"],
                    "late": s["late"],
                    "queue_max_1s": qmax,
                    "queue_depth_max": s["queue_depth_max"],
                    "received": {n: v["received"] for n, v in s["sources"].items()},
                    "dropped": g.metrics.dropped_total(),
                    "aligned": s["aligned"],
                    "faults": s["faults"],
                    "window": {kk: s["latency_window"][kk] for kk in ("arrival_to_state", "core_step")},
                    "hist": {key: _delta(g.metrics.hist[key].buckets, prev[key]) for key in HIST_KEYS},
                }
                f.write(json.dumps(row, default=float) + "\n")
                f.flush()
                qmax = 0

    t0 = time.monotonic()
    prof = None
    if a.profile:
        import cProfile

        prof = cProfile.Profile()
        prof.enable()
    m = await gw.run(duration=a.duration, signals=True, status=sampler)
    if prof is not None:
        prof.disable()
        prof.dump_stats(str(out / "profile.pstats"))
    snap = m.snapshot()
    snap["loop_period"] = period.summary()
    snap["loop_jitter"] = jitter.summary()
    snap["loop_jitter_hist"] = {"buckets": jitter.buckets}
    snap["fault_events"] = faults
    snap["fault_events_not_kept"] = n_over[0]
    snap["wall_s"] = time.monotonic() - t0
    snap["stopped_reason"] = gw.stopped_reason
    snap["gc"] = gc_stats
    from ins_hil.runtime.mqtt_out import clean_json

    (out / "gateway.json").write_text(json.dumps(clean_json(snap), indent=1))
    return 0


#: the loop histograms written per second (bucket deltas) into gateway_ts.jsonl, so that the analysis can
#: take their quantiles over the seconds without host steal (ins_hil.soak.analysis.loop_budget)
HIST_KEYS = ("arrival_to_state", "state_to_sent", "core_step")


def _delta(now: list[int], prev: list[int]) -> dict[str, int]:
    """The buckets that grew since ``prev`` (sparse: bucket index → count), and ``prev`` set to ``now``."""
    d = {str(i): c - p for i, (c, p) in enumerate(zip(now, prev)) if c != p}
    prev[:] = now
    return d


def _gc_probe() -> dict[str, Any]:
    """Time the garbage collector's passes (``gc.callbacks``): per generation count, total and max µs,
    and the number longer than 1 ms (each one delays whatever IMU sample is being processed)."""
    import gc

    stats: dict[str, Any] = {str(g): {"count": 0, "total_us": 0.0, "max_us": 0.0, "over_1ms": 0} for g in range(3)}
    t0 = [0]
    mono = time.perf_counter_ns

    def cb(phase: str, info: dict[str, Any]) -> None:
        if phase == "start":
            t0[0] = mono()
            return
        d = (mono() - t0[0]) * 1e-3
        s = stats[str(info["generation"])]
        s["count"] += 1
        s["total_us"] += d
        s["max_us"] = max(s["max_us"], d)
        s["over_1ms"] += d > 1000.0

    gc.callbacks.append(cb)
    return stats


def build_parser(description: str = "soak gateway process (see ins_hil.soak.gateway)") -> argparse.ArgumentParser:
    """The command line of the gateway process (the null relay, :mod:`ins_hil.soak.relay`, takes the same)."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--imu", action="append", required=True, help="IMU link pty (repeat per link)")
    ap.add_argument("--gnss-port", type=int, required=True)
    ap.add_argument("--gcs-port", type=int, required=True)
    ap.add_argument("--gcs-rate", type=float, default=47.0)
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--core", default="python")
    ap.add_argument("--duration", type=float, required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--cpu", type=int, default=-1)
    ap.add_argument("--record", action="store_true")
    ap.add_argument("--imus", type=int, default=1, help="redundant IMUs (their frames may share one link)")
    ap.add_argument("--rt", type=int, default=0, help="SCHED_FIFO priority (0 = time-shared)")
    ap.add_argument("--imu-transport", choices=["serial", "can"], default="serial", help="serial frames or slcan")
    ap.add_argument("--profile", action="store_true", help="cProfile the gateway run into profile.pstats")
    return ap


def main(argv: list[str] | None = None) -> int:
    die_with_parent()
    a = build_parser().parse_args(argv)
    pin(a.cpu)
    return asyncio.run(_run(a))


if __name__ == "__main__":
    sys.exit(main())
