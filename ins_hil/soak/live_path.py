"""Per-stage cost of the live gateway's per-sample path, without the soak: ``python -m ins_hil.soak.live_path``.

The soak's gateway (:func:`ins_hil.soak.gateway.gateway_config`: 1 kHz × 2 IMUs on one serial link, FDI,
GNSS/baro over MAVLink, one ground-station output with ODOMETRY at 47 Hz; ``--core c`` by default) built as
:class:`~ins_hil.runtime.loop.Gateway` and driven synchronously, as fast as it goes, with the soak simulator's
samples (:func:`ins_hil.soak.simproc.chunks`, the same seed): each epoch's two frames are encoded
(:func:`ins_hil.drivers.serial_frame.encode`) and handed to the serial driver's ``feed`` with the gateway's sink,
as one read of the pty would; the fixes and baro samples go to the gateway's sink at their arrival. No event
loop: the slack (the aiding segments, the recorder) runs right after each read. The output's transport is a
stand-in that keeps the bytes; the endpoints' clock is the simulated arrival clock, so the messages go out at
their configured rates in sensor time (deterministic).

Two measurements of the same run of ``--seconds`` of sensor time (the first ``--warmup`` seconds not counted):

* ``total``: process time (``time.process_time``) of the whole driven path per IMU epoch, without probes;
* a second run with probes (``time.perf_counter_ns`` around each stage, nested stages subtracted): the mean time
  per epoch of each stage (calls with the top 1 % of durations trimmed: a preemption inside a probe is not
  the stage's cost), and the calls per epoch.

``--instructions`` counts instead the instructions per epoch of the counted window under valgrind's callgrind
(host-independent: what to compare two versions of the code by on a shared host). ``--profile FILE`` writes a
cProfile of a third run (call counts). The ``digest`` printed is a SHA-256 of the bytes on the wire, the fault
events, the pipeline's counts and the last state: two versions of the code whose digests agree sent the same bytes
and made the same decisions.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import math
import os
import sys
import time
import types
from collections.abc import Callable, Iterator
from typing import Any

#: stages probed: (name, dotted owner, attribute, parent stage whose time it is part of)
_PROBES: tuple[tuple[str, str, str, str], ...] = (
    ("read → sink (driver decode)", "ins_hil.drivers.serial_imu:SerialImuDriver", "feed", ""),
    ("  loop bookkeeping", "ins_hil.runtime.loop:Gateway", "_process_queue", "read → sink (driver decode)"),
    ("  pipeline.imu", "ins_hil.runtime.pipeline:Pipeline", "imu", "  loop bookkeeping"),
    ("  pipeline.imu_pair", "ins_hil.runtime.pipeline:Pipeline", "imu_pair", "  loop bookkeeping"),
    ("    validation", "ins_hil.validation:SampleValidator", "imu", "  pipeline.imu"),
    ("    grouping", "ins_hil.runtime.pipeline:Pipeline", "_group", "  pipeline.imu"),
    ("    epoch glue", "ins_hil.runtime.pipeline:Pipeline", "_epoch", "    grouping"),
    ("      FDI parity (2 IMUs)", "ins_hil.fdi.monitor:FdiMonitor", "process", "    epoch glue"),
    ("      core step (C) + state", "ins_hil.cref:CNavCore", "step_begin", "    epoch glue"),
    ("        NavState building", "ins_hil.cref:CNavCore", "_nav_state", "      core step (C) + state"),
    ("      core guard (state_ok)", "ins_hil.runtime.pipeline:", "state_ok", "    epoch glue"),
    ("  publishers: offer", "ins_hil.runtime.mavlink_out:MavlinkEndpoint", "offer", "  loop bookkeeping"),
    ("    ODOMETRY (build)", "ins_hil.runtime.mavlink_msgs.fc:FcMessages", "_send_odometry", "  publishers: offer"),
    ("    ATTITUDE (build)", "ins_hil.runtime.mavlink_msgs.gcs:GcsMessages", "_send_attitude", "  publishers: offer"),
    (
        "    GLOBAL_POSITION_INT (build)",
        "ins_hil.runtime.mavlink_msgs.gcs:GcsMessages",
        "_send_global_position_int",
        "  publishers: offer",
    ),
    (
        "    SYS_STATUS (build)",
        "ins_hil.runtime.mavlink_msgs.gcs:GcsMessages",
        "_send_sys_status",
        "  publishers: offer",
    ),
    (
        "    HEARTBEAT (build)",
        "ins_hil.runtime.mavlink_msgs.common:MessageBase",
        "_send_heartbeat",
        "  publishers: offer",
    ),
    ("      encode + CRC (all messages)", "ins_hil.runtime.mavlink_msgs.common:_Frame", "frame", ""),
    ("      write", "ins_hil.runtime.mavlink_out:MavlinkEndpoint", "write", ""),
    ("  slack (recorder, aiding)", "ins_hil.runtime.loop:Gateway", "_slack", "read → sink (driver decode)"),
)


class _Wire:
    """The output's transport: keeps a hash of the bytes handed to it."""

    connected = True
    last_error = ""
    errors: dict[str, int] = {}  # noqa: RUF012

    def __init__(self) -> None:
        self.h = hashlib.sha256()
        self.n = 0

    def write(self, buf: bytes) -> bool:
        self.h.update(buf)
        self.n += 1
        return True

    def close(self) -> None:
        pass


def _namespace(core: str, rate: float, imus: int, seconds: float, seed: int) -> argparse.Namespace:
    chunk = seconds / max(1, math.ceil(seconds / 10.0))  # ≤ 10 s, whole chunks ending at ``seconds``
    return argparse.Namespace(
        imu=["/dev/null"], gnss_port=1, gcs_port=1, gcs_rate=47.0, rate=rate, core=core, duration=seconds,
        out="/tmp", cpu=-1, record=False, imus=imus, rt=0, imu_transport="serial", profile="uav", seed=seed,
        faults="none", gnss_rate=5.0, gnss_latency=0.05, baro_rate=25.0, chunk_s=chunk, lat_deg=50.45,
        lon_deg=30.52, h=180.0,
    )  # fmt: skip


def events(a: argparse.Namespace) -> Iterator[tuple[int, str, Any]]:
    """(arrival ns, input name, payload) in arrival order: the bytes of an epoch's frames ("imu0"), the fixes
    and baro samples ("gnss") at their time of validity + the GNSS latency (host clock = sensor clock + 0.2 ms)."""
    import heapq

    from ins_hil.drivers.serial_frame import encode
    from ins_hil.soak.simproc import chunks
    from ins_hil.types import ImuSample

    dt = 1.0 / a.rate
    n_chunks = max(1, math.ceil(a.duration / a.chunk_s))
    for k, ((t, dth, dv, fl), _tr, fixes, baro) in enumerate(chunks(a)):
        if k >= n_chunks:
            break
        aid = [(round((f.t + a.gnss_latency) * 1e9) + 200_000, i, f) for i, f in enumerate(fixes)]
        aid += [(round((b.t + 0.01) * 1e9) + 200_000, len(aid) + i, b) for i, b in enumerate(baro)]
        heapq.heapify(aid)
        for i in range(len(t)):
            ti = float(t[i])
            arr = round(ti * 1e9) + 200_000
            while aid and aid[0][0] <= arr:
                at, _, s = heapq.heappop(aid)
                yield at, "gnss", s
            data = b"".join(
                encode(ImuSample(ti, dt, dth[i, u], dv[i, u], imu_id=u, seq=i & 0xFFFF, flags=int(fl[i, u])))
                for u in range(dth.shape[1])
            )
            yield arr, "imu0", data


@contextlib.contextmanager
def simulated_clock(clock: list[int]) -> Iterator[None]:
    """The runtime modules' ``time.monotonic_ns`` / ``time.monotonic`` read ``clock[0]`` (ns) inside the block."""
    from ins_hil.runtime import loop, mavlink_out, metrics
    from ins_hil.runtime.mavlink_msgs import common, gcs, requests

    fake = types.SimpleNamespace(**{k: getattr(time, k) for k in dir(time) if not k.startswith("_")})
    fake.monotonic_ns = lambda: clock[0]
    fake.monotonic = lambda: clock[0] * 1e-9
    mods = (mavlink_out, common, gcs, requests, loop, metrics)
    for mod in mods:
        mod.time = fake  # type: ignore[attr-defined]
    try:
        yield
    finally:
        for mod in mods:
            mod.time = time  # type: ignore[attr-defined]


def build(a: argparse.Namespace) -> tuple[Any, Any, _Wire]:
    """The soak's gateway for ``a`` (not started), its serial driver and the output's stand-in transport."""
    from ins_hil.config import from_dict
    from ins_hil.drivers.serial_imu import SerialImuDriver
    from ins_hil.runtime.loop import Gateway
    from ins_hil.soak.gateway import gateway_config

    cfg = from_dict(gateway_config(a), source="bench")
    gw = Gateway(cfg)
    wire = _Wire()
    for ep in gw.mav_outputs:
        ep.tr = wire
        ep.reset_counter = 0  # (random at start: the digest wants it fixed)
        ep._t0_ns = 0
    gw.metrics.expect_inputs([("imu0", "serial_imu"), ("gnss", "mavlink")])
    return gw, SerialImuDriver("/dev/null", name="imu0"), wire


def drive(a: argparse.Namespace, probe: Callable[[int], None] | None = None, batch: bool = True,
          mark: Callable[[], Any] | None = None) -> dict[str, Any]:  # fmt: skip
    """One run; returns epochs counted, process time (s) over them, and the digest parts. ``batch`` False: the
    driver hands the samples of a read to the gateway one call each (a sink without ``many``). ``mark``: the
    simulator's samples made before the run, and ``mark()`` called where the counted window starts and where it
    ends (``--instructions``: a C function callgrind dumps its counts at)."""
    clock = [0]
    with simulated_clock(clock):
        return _drive(a, clock, probe, batch, mark)


def _drive(a: argparse.Namespace, clock: list[int], probe: Callable[[int], None] | None, batch: bool,
           mark: Callable[[], Any] | None = None) -> dict[str, Any]:  # fmt: skip
    gw, drv, wire = build(a)
    evs: Any = events(a)
    if mark is not None:
        evs = list(evs)
        inner = probe

        def probe(k: int) -> None:
            mark()
            if inner is not None:
                inner(k)

    sink_imu = gw._sink_for("imu0")
    if not batch:
        one = sink_imu
        sink_imu = lambda s: one(s)
    sink_aid = gw._sink_for("gnss")
    warm_ns = round(a.warmup * 1e9)
    n = 0
    cpu = 0.0
    pt = time.process_time
    feed = drv.feed
    counting = False
    for arr, name, payload in evs:
        clock[0] = arr
        if name == "gnss":
            payload.t = arr * 1e-9  # the MAVLink driver's stamp: host monotonic (the loop maps it)
            sink_aid(payload)
            continue
        if not counting and arr >= warm_ns:
            counting = True
            if probe is not None:
                probe(1)
        if counting:
            t0 = pt()
            feed(payload, sink_imu, arr)
            cpu += pt() - t0
            n += 1
        else:
            feed(payload, sink_imu, arr)
    if mark is not None:
        mark()
    pipe = gw.pipeline
    st = pipe.last_state
    ev = [(e.t, e.sensor, e.mode.name, e.isolated, e.cleared) for e in (gw.pipeline._fdi.events if pipe._fdi else [])]
    h = hashlib.sha256()
    h.update(wire.h.digest())
    h.update(json.dumps(ev).encode())
    h.update(json.dumps(sorted(pipe.counts.items())).encode())
    if st is not None:
        h.update(
            repr((st.t, st.lat, st.lon, st.h, st.q_nb.tolist(), st.vel_ned.tolist(), st.std_pos.tolist())).encode()
        )
    return {"epochs": n, "cpu_s": cpu, "digest": h.hexdigest(), "messages": wire.n, "counts": dict(pipe.counts),
            "received": gw.metrics.source("imu0").received, "dropped": gw.metrics.dropped_total(),
            "sent": {k: v for ep in gw.mav_outputs for k, v in ep.sent.items()}, "fdi_events": len(ev)}  # fmt: skip


def _resolve(owner: str) -> Any:
    import importlib

    mod, _, cls = owner.partition(":")
    m = importlib.import_module(mod)
    return getattr(m, cls) if cls else m


@contextlib.contextmanager
def probes() -> Iterator[dict[str, list[int]]]:
    """Wrap each stage of :data:`_PROBES` (its own time: nested probed stages subtracted)."""
    times: dict[str, list[int]] = {name: [] for name, *_ in _PROBES}
    stack: list[int] = []  # child time accumulated in the running probe
    pc = time.perf_counter_ns
    saved: list[tuple[Any, str, Any]] = []
    on = [False]

    def wrap(name: str, fn: Callable[..., Any]) -> Callable[..., Any]:
        rec = times[name]

        def w(*args: Any, **kw: Any) -> Any:
            if not on[0]:
                return fn(*args, **kw)
            stack.append(0)
            t0 = pc()
            try:
                return fn(*args, **kw)
            finally:
                d = pc() - t0
                child = stack.pop()
                rec.append(d - child)
                if stack:
                    stack[-1] += d

        return w

    for name, owner, attr, _parent in _PROBES:
        obj = _resolve(owner)
        if not hasattr(obj, attr):
            continue
        orig = obj.__dict__.get(attr) if isinstance(obj, type) else getattr(obj, attr)
        if orig is None:
            continue
        saved.append((obj, attr, orig))
        setattr(obj, attr, wrap(name, orig))
    times["_on"] = on  # type: ignore[assignment]
    try:
        yield times
    finally:
        for obj, attr, orig in reversed(saved):
            setattr(obj, attr, orig)


def _trimmed_sum(v: list[int]) -> float:
    if not v:
        return 0.0
    s = sorted(v)
    k = len(s) - len(s) // 100
    return float(sum(s[:k])) * len(s) / max(k, 1)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--core", default="c", choices=["c", "python"])
    ap.add_argument("--seconds", type=float, default=40.0, help="sensor time driven (s)")
    ap.add_argument("--warmup", type=float, default=10.0, help="sensor time not counted (s)")
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--faults", default="none", help="the soak's fault schedule (ins_hil.soak.faults), e.g. auto")
    ap.add_argument("--profile", metavar="FILE", help="also write a cProfile of a run (call counts)")
    ap.add_argument("--json", metavar="FILE", help="write the figures as JSON")
    ap.add_argument("--instructions", action="store_true",
                    help="count the instructions per epoch of the counted window under valgrind's callgrind instead "
                         "(host-independent; the simulator's samples made before the run)")  # fmt: skip
    ap.add_argument("--mark", action="store_true", help=argparse.SUPPRESS)  # the run --instructions counts
    a = ap.parse_args(argv)
    ns = _namespace(a.core, a.rate, 2, a.seconds, a.seed)
    ns.faults = a.faults
    ns.warmup = a.warmup
    import gc

    if (a.instructions or a.mark) and not 0.0 <= a.warmup < a.seconds:
        print("live_path: --warmup must be >= 0 and below --seconds (the counted window)", file=sys.stderr)
        return 2
    gc.collect()
    gc.freeze()
    if a.instructions:
        return _instructions(a)
    if a.mark:  # one run, the counted window between two getppid() calls (callgrind --dump-before=getppid)
        r = drive(ns, mark=os.getppid)
        print(json.dumps({"epochs": r["epochs"], "digest": r["digest"]}))
        return 0
    plain = drive(ns)
    with probes() as times:
        on = times.pop("_on")

        def start(_: int) -> None:
            on[0] = True
            for v in times.values():
                v.clear()

        probed = drive(ns, start)
    n = plain["epochs"]
    rows = []
    for name, *_ in _PROBES:
        v = times.get(name, [])
        rows.append((name, _trimmed_sum(v) / n / 1e3 if n else 0.0, len(v) / n if n else 0.0))
    print(f"live path, core {a.core}, 1 kHz x 2 IMUs, faults {a.faults}, {n} epochs counted; load {_load()}")
    print(f"digest {plain['digest']} (probed run {'same' if probed['digest'] == plain['digest'] else 'DIFFERS'})")
    print(f"messages sent: {plain['sent']}; FDI events {plain['fdi_events']}")
    print(f"total (process time, no probes): {plain['cpu_s'] / n * 1e6:.1f} us per epoch")
    print("| stage (own time) | us per epoch | calls per epoch |")
    print("|---|---:|---:|")
    for name, us, calls in rows:
        print(f"| {name} | {us:.2f} | {calls:.3f} |")
    print(f"| sum of the stages | {sum(r[1] for r in rows):.2f} | |")
    if a.profile:
        import cProfile

        pr = cProfile.Profile()
        pr.enable()
        drive(ns)
        pr.disable()
        pr.dump_stats(a.profile)
    if a.json:
        with open(a.json, "w") as f:
            json.dump({"epochs": n, "total_us": plain["cpu_s"] / n * 1e6, "digest": plain["digest"],
                       "stages": {r[0].strip(): {"us": r[1], "calls": r[2]} for r in rows}}, f, indent=1)  # fmt: skip
    return 0


def _instructions(a: argparse.Namespace) -> int:
    """``--instructions``: this benchmark's run (``--mark``) under ``valgrind --tool=callgrind``, which dumps its
    counts at each ``getppid`` call: the second part is the counted window. Prints instructions per IMU epoch."""
    import shutil
    import subprocess
    import tempfile
    from pathlib import Path

    vg = shutil.which("valgrind")
    if vg is None:
        print("live_path --instructions: valgrind not found (apt-get install valgrind)", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "cg.out"
        cmd = [vg, "--tool=callgrind", "--dump-before=getppid", f"--callgrind-out-file={out}", sys.executable, "-m",
               "ins_hil.soak.live_path", "--mark", "--core", a.core, "--seconds", str(a.seconds), "--warmup",
               str(a.warmup), "--rate", str(a.rate), "--seed", str(a.seed), "--faults", a.faults]  # fmt: skip
        r = subprocess.run(cmd, capture_output=True, text=True, check=False)
        part = out.with_name(out.name + ".2")
        if r.returncode != 0 or not part.exists():
            why = r.stderr.strip()[-300:]
            print(f"live_path --instructions: the run under valgrind failed: {why}", file=sys.stderr)
            return 1
        res = json.loads(r.stdout.strip().splitlines()[-1])
        n = int(res["epochs"])
        lines = part.read_text().splitlines()
        total = next((int(x.split()[1]) for x in lines if x.startswith(("summary:", "totals:"))), None)
        if total is None:
            print(f"live_path --instructions: no instruction count in {part.name}", file=sys.stderr)
            return 1
    print(f"live path, core {a.core}, {a.rate:g} Hz x 2 IMUs, faults {a.faults}, {n} epochs counted; digest"
          f" {res['digest']}")  # fmt: skip
    print(f"instructions (callgrind): {total / max(n, 1):,.0f} per epoch ({total:,} in all)")
    return 0


def _load() -> str:
    try:
        with open("/proc/loadavg") as f:
            return " ".join(f.read().split()[:3])
    except OSError:
        return "?"


if __name__ == "__main__":
    sys.exit(main())
