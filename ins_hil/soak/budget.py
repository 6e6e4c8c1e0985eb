"""The loop's own latency budget: steal-free quantiles of the loop histograms, and its cost by stage.

The gateway process of a soak (:mod:`ins_hil.soak.gateway`) writes, once a second, the bucket deltas of
the runtime's loop histograms (``arrival_to_state``, ``state_to_sent``, ``core_step``; the log buckets of
:class:`~ins_hil.runtime.metrics.LatencyHistogram`, 4 % wide) into ``gateway_ts.jsonl``. Merging the
seconds without host steal gives the loop's quantiles free of the hypervisor (:func:`loop_budget`).

With ``--profile`` it also writes a cProfile of the whole run (``profile.pstats``): :func:`profile_table`
sums the functions' own time (``tottime``) by stage of the loop (decode, FDI, core step, publishers,
recorder, event loop, ...) per IMU epoch. cProfile slows every Python call, so the table gives each
stage's share of the loop, not its latency.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from ins_hil.runtime.metrics import _BASE_NS, _RATIO, LatencyHistogram

#: loop histograms judged in steal-free seconds (the gateway's HIST_KEYS)
KEYS = ("arrival_to_state", "state_to_sent", "core_step")


def merged(rows: list[dict[str, int]]) -> LatencyHistogram:
    """One histogram from sparse bucket-delta rows ({bucket index: count}); min/max are bucket edges."""
    h = LatencyHistogram()
    for r in rows:
        for k, c in r.items():
            h.buckets[int(k)] += int(c)
    h.count = sum(h.buckets)
    nz = [k for k, c in enumerate(h.buckets) if c]
    if nz:
        h.min_ns = 0
        h.max_ns = int(_BASE_NS * _RATIO ** (nz[-1] + 1))  # upper edge of the highest occupied bucket
    return h


def summary(h: LatencyHistogram) -> dict[str, float]:
    """count, p50, p99, p99.9 (µs, bucket centres) of a merged histogram."""
    return {"count": h.count, "p50_us": h.percentile(50) * 1e-3, "p99_us": h.percentile(99) * 1e-3,
            "p999_us": h.percentile(99.9) * 1e-3}  # fmt: skip


def loop_budget(ts: list[dict[str, Any]], calm: np.ndarray) -> dict[str, Any]:
    """The loop histograms over all seconds and over the seconds without host steal.

    ``ts``: the gateway's per-second rows (those with ``hist``); ``calm``: per row, True when its second
    had no host steal on either CPU (:func:`ins_hil.soak.analysis.calm_mask` at the row's time).
    Returns ``{key: {"all": summary, "steal_free": summary}}`` and ``seconds`` / ``steal_free_seconds``;
    empty when the rows carry no histograms (an older run, the null relay)."""
    idx = [i for i, r in enumerate(ts) if "hist" in r]
    if not idx:
        return {}
    out: dict[str, Any] = {"seconds": len(idx), "steal_free_seconds": int(sum(bool(calm[i]) for i in idx))}
    for key in KEYS:
        rows = [ts[i]["hist"].get(key, {}) for i in idx]
        out[key] = {
            "all": summary(merged(rows)),
            "steal_free": summary(merged([r for i, r in zip(idx, rows, strict=True) if calm[i]])),
        }
    return out


#: stages of the loop by the module a function lives in (first match wins; "other" = the rest)
STAGES: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("decode: IMU drivers (frame parser, pyserial)", ("/drivers/serial", "/drivers/base.py", "/drivers/clock.py",
                                                      "/serial/", "serial_asyncio")),
    ("aiding input (GNSS/baro MAVLink driver)", ("/drivers/mavlink",)),
    ("pymavlink (input parsing, output packing)", ("pymavlink/",)),
    ("FDI", ("ins_hil/fdi/",)),
    ("core step (INS/EKF)", ("ins_hil/nav/", "ins_hil/fusion/", "ins_hil/core.py", "ins_hil/cref", "_cref")),
    ("publishers (MAVLink out, MQTT)", ("ins_hil/runtime/mavlink_out", "ins_hil/runtime/mqtt_out")),
    ("recorder", ("ins_hil/runtime/recorder",)),
    ("pipeline (grouping, aiding)", ("ins_hil/runtime/pipeline",)),
    ("loop and metrics", ("ins_hil/runtime/loop", "ins_hil/runtime/metrics", "ins_hil/runtime/clock")),
    ("event loop (asyncio, selectors)", ("asyncio/", "selectors.py")),
    ("soak taps", ("ins_hil/soak/",)),
    ("start-up (imports)", ("<frozen importlib",)),
    ("numpy", ("numpy/",)),
)  # fmt: skip


def stage_of(filename: str, func: str) -> str:
    """The stage of one profiled function (``filename`` as cProfile records it; ``~`` = a builtin)."""
    f = filename.replace("\\", "/")
    for name, keys in STAGES:
        if any(k in f for k in keys):
            return name
    if f == "~":
        return "builtins (" + _builtin_kind(func) + ")"
    return "other"


def _builtin_kind(func: str) -> str:
    if "numpy" in func or "ndarray" in func:
        return "numpy"
    if "select" in func or "epoll" in func or "poll" in func:
        return "waiting in poll"
    if any(k in func for k in ("posix.read", "posix.write", "send", "recv")):
        return "system calls: read, write, send"
    return "C functions"


def profile_table(path: str | Path, epochs: int) -> dict[str, Any]:
    """The loop's cost by stage from a cProfile dump: per stage the functions' own time (s), its share
    of the profiled time (waiting in poll excluded), µs per IMU epoch, and the stage's costliest function.
    ``epochs``: IMU epochs of the run (the per-sample divisor)."""
    import pstats

    st = pstats.Stats(str(path))
    stats: dict[Any, Any] = st.stats  # type: ignore[attr-defined]
    by: dict[str, dict[str, Any]] = {}
    for (fn, line, func), (_cc, _nc, tt, _ct, _callers) in stats.items():
        stage = stage_of(fn, func)
        d = by.setdefault(stage, {"s": 0.0, "top": ("", 0.0)})
        d["s"] += tt
        if tt > d["top"][1]:
            d["top"] = (f"{Path(fn).name}:{line} {func}" if fn != "~" else func, tt)
    busy = sum(v["s"] for k, v in by.items() if "waiting" not in k)
    rows = []
    for stage, v in sorted(by.items(), key=lambda kv: -kv[1]["s"]):
        waiting = "waiting" in stage
        rows.append({
            "stage": stage,
            "seconds": v["s"],
            "share": (v["s"] / busy) if busy > 0 and not waiting else math.nan,
            "us_per_epoch": v["s"] / max(1, epochs) * 1e6,
            "top_function": v["top"][0],
        })  # fmt: skip
    largest = next((r for r in rows if "waiting" not in r["stage"]), None)
    return {"epochs": epochs, "busy_s": busy, "rows": rows, "largest": largest["stage"] if largest else ""}
