"""The IMU–GNSS time offset from the data: short GNSS outages scored over a grid of offsets.

An IMU whose time stamps are off by δ against the GNSS lags (or leads) the motion: the attitude and
velocity the INS carries into an outage are those of δ earlier, so the dead-reckoned position drifts
faster than it would. Fix-to-fix innovations hardly show it (a 5 Hz fix resets the velocity every
0.2 s, so the lag costs only δ times the change of acceleration in between); a few seconds without
GNSS do. :func:`estimate_imu_offset` replays a selection window with outages of ``on_s`` every
``on_s + off_s`` s, for each candidate offset, sums the squared horizontal error at the fixes withheld,
and takes the vertex of a parabola through the lowest points of that cost. The uncertainty is the
spread of the vertex when the outages are resampled (bootstrap): what the data say, not a model's σ.

The cost is taken on the dataset config as given (its mounting, lever arms, grade, aids), so the
estimate answers "which offset makes this filter dead-reckon best on this log"; that is also the
offset to set for replays. Mounting yaw is not estimated here.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ins_hil.datasets.config import DatasetConfig
from ins_hil.datasets.dataset import Dataset
from ins_hil.datasets.run import prepare, run_dataset
from ins_hil.types import Vec

#: progress(k done, n) over the candidate offsets
Progress = Callable[[int, int], None]


@dataclass
class OffsetEstimate:
    """The result: ``offset_s`` to set as ``imu_time_offset_s`` (NaN when the minimum lies at the edge of
    the search, ``reason`` says so), its bootstrap σ ``std_s``, the cost curve (``grid_s`` absolute
    offsets, ``cost_m2`` mean squared horizontal outage error), the outages used and the window (s)."""

    offset_s: float
    std_s: float
    base_s: float
    grid_s: Vec
    cost_m2: Vec
    outages: list[tuple[float, float]]
    window: tuple[float, float]
    reason: str = ""
    per_outage: Vec = field(default_factory=lambda: np.zeros((0, 0)))

    def summary(self) -> str:
        """One line for the terminal."""
        if math.isnan(self.offset_s):
            return f"IMU time offset: not found ({self.reason})"
        return (
            f"IMU time offset: {self.offset_s * 1e3:+.1f} ms ± {self.std_s * 1e3:.1f} ms (1σ, bootstrap over "
            f"{len(self.outages)} outages of the window {self.window[0]:.0f}–{self.window[1]:.0f} s; "
            f"the config has {self.base_s * 1e3:+.1f} ms)"
        )


def outage_windows(t0: float, t1: float, on_s: float, off_s: float) -> list[tuple[float, float]]:
    """Outages of ``on_s`` s every ``on_s + off_s`` s inside [t0, t1] (s)."""
    out = []
    a = t0
    while a + on_s <= t1:
        out.append((a, a + on_s))
        a += on_s + off_s
    return out


def _vertex(grid: Vec, cost: Vec, edge: bool = False) -> float:
    """The offset at the vertex of the parabola through the lowest cost and its two neighbours each side;
    when the lowest cost is at either end of the grid, that end with ``edge``, else NaN."""
    i = int(np.argmin(cost))
    if i == 0 or i == len(cost) - 1:
        return float(grid[i]) if edge else math.nan
    lo, hi = max(0, i - 2), min(len(cost), i + 3)
    a, b, _ = np.polyfit(grid[lo:hi], cost[lo:hi], 2)
    if a <= 0.0:
        return float(grid[i])
    return float(np.clip(-b / (2.0 * a), grid[lo], grid[hi - 1]))


def estimate_imu_offset(
    ds: Dataset,
    cfg: DatasetConfig,
    span_s: float = 0.2,
    step_s: float = 0.02,
    window: tuple[float, float] | None = None,
    settle_s: float = 30.0,
    on_s: float = 5.0,
    off_s: float = 7.0,
    bootstrap: int = 200,
    seed: int = 0,
    progress: Progress | None = None,
) -> OffsetEstimate:
    """Estimate the IMU time offset (s, added to the IMU times as ``imu_time_offset_s``) of ``ds``.

    Candidates: the config's offset ± ``span_s`` in steps of ``step_s``. ``window`` (s, absolute): the
    selection window replayed (default the whole log; outages start ``settle_s`` after its start, or
    after take-off where the log has one). Needs GNSS in the window."""
    if not ds.gnss:
        raise ValueError("time offset: the log has no GNSS fixes to score outages against")
    if step_s <= 0.0 or span_s < 2 * step_s:
        raise ValueError(f"time offset: need span ≥ 2 steps (span {span_s} s, step {step_s} s)")
    t_from, t_to = window if window is not None else (ds.t0, ds.t1)
    t_from = max(t_from, ds.t0)
    t_to = min(t_to, ds.t1)
    sub = dataclasses.replace(
        ds,
        imu=[s for s in ds.imu if t_from <= s.t <= t_to],
        gnss=[f for f in ds.gnss if t_from <= f.t <= t_to],
        baro=[b for b in ds.baro if t_from <= b.t <= t_to],
        mag=[m for m in ds.mag if t_from <= m.t <= t_to],
    )
    takeoff = ds.event("takeoff")
    start = max(t_from, takeoff if takeoff is not None else t_from) + settle_s
    outages = outage_windows(start, t_to - 1.0, on_s, off_s)
    if len(outages) < 3:
        raise ValueError(
            f"time offset: the window {t_from:.0f}–{t_to:.0f} s leaves {len(outages)} outages of {on_s:g} s "
            f"after {settle_s:g} s of settling; need at least 3 (a longer window or shorter outages)"
        )
    base = cfg.imu_time_offset
    n = round(span_s / step_s)
    grid = base + step_s * np.arange(-n, n + 1)
    per = np.zeros((len(grid), len(outages)))
    counts = np.zeros(len(outages))
    for k, d in enumerate(grid):
        r = run_dataset(prepare(sub, dataclasses.replace(cfg, imu_time_offset=float(d))), outages=outages)
        for j, (a, b) in enumerate(outages):
            sel = r.gnss_inside & (r.gnss_t >= a) & (r.gnss_t < b)
            e = r.gnss_err[sel]
            per[k, j] = float(np.sum(e[:, 0] ** 2 + e[:, 1] ** 2))
            counts[j] = max(counts[j], float(sel.sum()))
        if progress is not None:
            progress(k + 1, len(grid))
    scored = counts > 0
    if scored.sum() < 3:
        raise ValueError("time offset: fewer than 3 outages were scored (the core did not navigate in time)")
    per = per[:, scored]
    outs = [o for o, s in zip(outages, scored, strict=True) if s]
    cost = per.sum(axis=1) / counts[scored].sum()
    est = _vertex(grid, cost)
    if math.isnan(est):
        edge = "below" if int(np.argmin(cost)) == 0 else "above"
        reason = (
            f"the lowest cost is at the edge of the search ({base * 1e3:+.0f} ± {span_s * 1e3:.0f} ms): "
            f"the offset is {edge} it; widen the span"
        )
        return OffsetEstimate(math.nan, math.nan, base, grid, cost, outs, (t_from, t_to), reason, per)
    rng = np.random.default_rng(seed)
    m = per.shape[1]
    # a resample whose minimum falls on the edge counts at the edge (its spread is then a lower bound)
    bs = [_vertex(grid, per[:, rng.integers(0, m, m)].sum(axis=1), edge=True) for _ in range(bootstrap)]
    std = float(np.std(bs))
    return OffsetEstimate(est, std, base, grid, cost, outs, (t_from, t_to), "", per)


def write_offset(config: str | Path, offset_s: float) -> None:
    """Set ``[mounting] imu_time_offset_s`` in the dataset TOML ``config`` (the rest of the file, comments
    included, unchanged; the table is added when missing)."""
    import re

    p = Path(config)
    text = p.read_text()
    line = f"imu_time_offset_s = {offset_s:.4f}"
    key = re.compile(r"^imu_time_offset_s\s*=.*$", re.M)
    table = re.compile(r"^\[mounting\]\s*$", re.M)
    m = table.search(text)
    if m is None:
        text = text.rstrip("\n") + f"\n\n[mounting]\n{line}\n"
    else:
        nxt = re.compile(r"^\[", re.M).search(text, m.end())
        end = nxt.start() if nxt else len(text)
        body = text[m.end() : end]
        body = key.sub(line, body, count=1) if key.search(body) else f"\n{line}" + body
        text = text[: m.end()] + body + text[end:]
    p.write_text(text)
