"""The IMU–GNSS time offset and the IMU mounting yaw from the data: short GNSS outages scored over a grid.

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
offset to set for replays.

The mounting yaw (:func:`estimate_mounting_yaw`, a rotation about the body z axis after the config's
``imu_to_body`` rotations) is searched the same way. It is observable where something ties the body axes to
the motion: a ground vehicle's non-holonomic constraint (``[nav.aids] nhc``) turns a yaw misalignment into a
lateral velocity and a dead-reckoned heading error. Where nothing does (a multirotor without the drag aid)
the cost is flat; the bootstrap then spreads the minimum over the whole search and the estimate says that
the log cannot tell (:data:`UNOBSERVABLE`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypedDict, Unpack

import numpy as np

from ins_hil.datasets.config import DatasetConfig
from ins_hil.datasets.dataset import Dataset
from ins_hil.datasets.run import prepare, run_dataset
from ins_hil.types import Vec

#: progress(k done, n) over the candidate offsets
Progress = Callable[[int, int], None]


#: a search whose bootstrap σ exceeds this fraction of its span, or whose cost changes by less than
#: ``FLAT`` (relative) over the whole search, has found no minimum the data support
UNOBSERVABLE = 0.5
FLAT = 0.1
#: the coarse stage of a search: the IMU rate (Hz) its replays are decimated to, and their covariance update period
COARSE_HZ = 50.0
COARSE_COV_EVERY = 5
#: ... and the rate (Hz) its baro and magnetometer are thinned to
COARSE_AID_HZ = 10.0


@dataclass
class GridEstimate:
    """The result of a search over a grid of one config value: ``value`` to set (NaN when the data do not
    give one, ``reason`` says why), its bootstrap σ ``std``, the config's own ``base``, the cost curve (``grid``
    absolute values, ``cost_m2`` mean squared horizontal outage error), the outages used and the window (s, absolute).
    Values in the setting's unit (s, rad); ``what``, ``unit`` and ``scale`` print them (ms: 1e3, °: 180/π)."""

    value: float
    std: float
    base: float
    grid: Vec
    cost_m2: Vec
    outages: list[tuple[float, float]]
    window: tuple[float, float]
    reason: str = ""
    per_outage: Vec = field(default_factory=lambda: np.zeros((0, 0)))
    what: str = "IMU time offset"
    unit: str = "ms"
    scale: float = 1e3
    log_t0: float = 0.0  # the log's first time (s): the window is printed from it
    #: the coarse stage of a coarse-to-fine search (every other candidate, a decimated replay); empty: none
    coarse_grid: Vec = field(default_factory=lambda: np.zeros(0))
    coarse_cost_m2: Vec = field(default_factory=lambda: np.zeros(0))

    def summary(self) -> str:
        """One line for the terminal."""
        if math.isnan(self.value):
            return f"{self.what}: not found ({self.reason})"
        u, k = self.unit, self.scale
        return (
            f"{self.what}: {self.value * k:+.1f} {u} ± {self.std * k:.1f} {u} (1σ, bootstrap over "
            f"{len(self.outages)} outages of {self.window[0] - self.log_t0:.0f}–{self.window[1] - self.log_t0:.0f} s "
            "into the log; "
            f"the config has {self.base * k:+.1f} {u})"
        )

    def table(self) -> list[str]:
        """The cost curve, a line per candidate."""
        k, u = self.scale, self.unit
        lines = [f"  {g * k:+7.1f} {u}  {c:10.4f} m²" for g, c in zip(self.grid, self.cost_m2, strict=True)]
        if len(self.coarse_grid):
            lines = ["  coarse (decimated replays):"] + [
                f"  {g * k:+7.1f} {u}  {c:10.4f} m²" for g, c in zip(self.coarse_grid, self.coarse_cost_m2, strict=True)
            ] + ["  fine (full replays):"] + lines  # fmt: skip
        return lines


def outage_windows(t0: float, t1: float, on_s: float, off_s: float) -> list[tuple[float, float]]:
    """Outages of ``on_s`` s every ``on_s + off_s`` s inside [t0, t1] (s)."""
    out = []
    a = t0
    while a + on_s <= t1:
        out.append((a, a + on_s))
        a += on_s + off_s
    return out


def _vertex(grid: Vec, cost: Vec, edge: bool = False) -> float:
    """The value at the vertex of the parabola through the lowest cost and its two neighbours each side;
    when the lowest cost is at either end of the grid, that end with ``edge``, else NaN."""
    i = int(np.argmin(cost))
    if i == 0 or i == len(cost) - 1:
        return float(grid[i]) if edge else math.nan
    lo, hi = max(0, i - 2), min(len(cost), i + 3)
    a, b, _ = np.polyfit(grid[lo:hi], cost[lo:hi], 2)
    if a <= 0.0:
        return float(grid[i])
    return float(np.clip(-b / (2.0 * a), grid[lo], grid[hi - 1]))


class SearchOptions(TypedDict, total=False):
    """The keyword options of a search (:func:`estimate_imu_offset`, :func:`estimate_mounting_yaw`), their
    defaults :func:`_search`'s: ``window`` (s, absolute), ``settle_s``, ``on_s``, ``off_s`` (s), ``bootstrap``
    (resamples), ``seed``, ``progress``, ``exhaustive``."""

    window: tuple[float, float] | None
    settle_s: float
    on_s: float
    off_s: float
    bootstrap: int
    seed: int
    progress: Progress | None
    exhaustive: bool


def estimate_imu_offset(
    ds: Dataset, cfg: DatasetConfig, span_s: float = 0.2, step_s: float = 0.02, **search: Unpack[SearchOptions]
) -> GridEstimate:
    """Estimate the IMU time offset (s, added to the IMU times as ``imu_time_offset_s``) of ``ds``.

    Candidates: the config's offset ± ``span_s`` in steps of ``step_s``. ``window`` (s, absolute): the
    selection window replayed (default the whole log; outages start ``settle_s`` after its start, or
    after take-off where the log has one). Needs GNSS in the window. The search is coarse to fine (every other
    candidate on a decimated replay, then full replays around its minimum: :func:`_search`); ``exhaustive``
    replays every candidate in full (the defaults: :func:`_search`'s)."""
    return _search(ds, cfg, ("IMU time offset", "ms", 1e3), cfg.imu_time_offset, span_s, step_s,
                   lambda c, d: dataclasses.replace(c, imu_time_offset=d), **search)  # fmt: skip


def estimate_mounting_yaw(
    ds: Dataset,
    cfg: DatasetConfig,
    span: float = math.radians(5.0),
    step: float = math.radians(0.5),
    **search: Unpack[SearchOptions],
) -> GridEstimate:
    """Estimate the mounting yaw of ``ds`` (rad): a rotation about the body z axis added to the yaw of the
    config's last ``imu_to_body`` rotation (the one applied last, in body axes), over its value ± ``span``
    in steps of ``step``; the rest as :func:`estimate_imu_offset`."""

    def with_yaw(c: DatasetConfig, y: float) -> DatasetConfig:
        rot = c.imu_to_body.copy()
        rot[-1, 2] = y
        return dataclasses.replace(c, imu_to_body=rot)

    return _search(ds, cfg, ("mounting yaw", "°", 180.0 / math.pi), float(cfg.imu_to_body[-1, 2]), span, step,
                   with_yaw, **search)  # fmt: skip


def _search(
    ds: Dataset,
    cfg: DatasetConfig,
    label: tuple[str, str, float],
    base: float,
    span: float,
    step: float,
    apply: Callable[[DatasetConfig, float], DatasetConfig],
    window: tuple[float, float] | None = None,
    settle_s: float = 30.0,
    on_s: float = 5.0,
    off_s: float = 7.0,
    bootstrap: int = 200,
    seed: int = 0,
    progress: Progress | None = None,
    exhaustive: bool = False,
) -> GridEstimate:
    """Replay ``ds`` with ``apply(cfg, value)`` for values of ``base`` ± ``span`` in steps of ``step``,
    with outages of ``on_s`` every ``on_s + off_s`` s; the cost's minimum and its bootstrap σ. ``label``: what
    is searched, its printed unit and the scale to it (GridEstimate's ``what``, ``unit``, ``scale``).

    Coarse to fine unless ``exhaustive`` (or fewer than 9 candidates): every other candidate first on a cheap
    replay (IMU decimated to :data:`COARSE_HZ`, covariance every :data:`COARSE_COV_EVERY` steps), then the full
    replay at each step around the coarse minimum, widened until the minimum has two candidates on each side:
    the same vertex as the exhaustive search whenever the coarse stage finds the right basin, in about
    ``(n/2)·cheap + 5`` replays instead of ``n``. Whether the data tell (flat cost, a wandering minimum) is judged
    on the coarse curve over the whole search. ``progress(k, n)``: ``n`` the replays expected so far. The replays
    run without the drift monitor (``[fdi] aiding``)."""
    what = label[0]
    # without the gateway's drift monitor: a candidate whose errors make it exclude fixes would be scored on a
    # run with fewer fixes (its cost jumps by orders of magnitude), not on how it dead-reckons
    cfg = dataclasses.replace(cfg, aiding_fdi=False)
    if not ds.gnss:
        raise ValueError(f"{what}: the log has no GNSS fixes to score outages against")
    if step <= 0.0 or span < 2 * step:
        raise ValueError(f"{what}: need span ≥ 2 steps (span {span:g}, step {step:g})")
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
            f"{what}: the window {t_from:.0f}–{t_to:.0f} s leaves {len(outages)} outages of {on_s:g} s "
            f"after {settle_s:g} s of settling; need at least 3 (a longer window or shorter outages)"
        )
    n = round(span / step)
    full = base + step * np.arange(-n, n + 1)

    def costs(values: Vec, data: Dataset, c0: DatasetConfig, done: int, total: int) -> tuple[Vec, Vec]:
        """Per candidate and outage: the summed squared horizontal error (m²), and the fixes scored per outage."""
        per = np.zeros((len(values), len(outages)))
        counts = np.zeros(len(outages))
        for k, d in enumerate(values):
            r = run_dataset(prepare(data, apply(c0, float(d))), outages=outages)
            for j, (a, b) in enumerate(outages):
                sel = r.gnss_inside & (r.gnss_t >= a) & (r.gnss_t < b)
                e = r.gnss_err[sel]
                per[k, j] = float(np.sum(e[:, 0] ** 2 + e[:, 1] ** 2))
                counts[j] = max(counts[j], float(sel.sum()))
            if progress is not None:
                progress(done + k + 1, total)
        return per, counts

    coarse: tuple[Vec, Vec, Vec, Vec] | None = None
    if exhaustive or n < 4:
        grid = full
        per, counts = costs(grid, sub, cfg, 0, len(grid))
    else:
        # coarse: every other candidate on a cheap replay (the IMU decimated to COARSE_HZ, the covariance
        # propagated every COARSE_COV_EVERY steps); fine: the full replay at the step, around the coarse minimum,
        # widened until the minimum has two candidates each side (what the vertex's parabola needs)
        idx = np.arange(0, 2 * n + 1, 2)
        est_total = len(idx) + 5
        cheap = decimate(sub, COARSE_HZ)
        nav = dict(cfg.nav)
        nav["filter"] = {**dict(nav.get("filter", {})), "cov_every": COARSE_COV_EVERY}
        pc, cc = costs(full[idx], cheap, dataclasses.replace(cfg, nav=nav), 0, est_total)
        ok = cc > 0
        cost_c = pc[:, ok].sum(axis=1) / max(float(cc[ok].sum()), 1.0)
        coarse = (full[idx], cost_c, pc, ok)
        i0 = int(idx[int(np.argmin(cost_c))])
        v = _vertex(full[idx], cost_c)  # the fine candidates centred on the coarse vertex where it has one
        if math.isfinite(v):
            i0 = int(np.clip(round((v - full[0]) / step), 0, 2 * n))
        lo, hi = max(0, i0 - 2), min(2 * n, i0 + 2)
        done = len(idx)
        per_of: dict[int, Vec] = {}
        counts = np.zeros(len(outages))
        while True:
            todo = [i for i in range(lo, hi + 1) if i not in per_of]
            if todo:
                est_total = max(est_total, done + len(todo))
                pf, cf = costs(full[todo], sub, cfg, done, est_total)
                done += len(todo)
                counts = np.maximum(counts, cf)
                per_of.update({i: pf[k] for k, i in enumerate(todo)})
            keys = sorted(per_of)
            cost_f = np.array([per_of[i].sum() for i in keys])
            im = keys[int(np.argmin(cost_f))]
            if im - 2 < lo and lo > 0:
                lo -= 1
            elif im + 2 > hi and hi < 2 * n:
                hi += 1
            else:
                break
        keys = sorted(per_of)
        grid = full[keys]
        per = np.array([per_of[i] for i in keys])
    scored = counts > 0
    if scored.sum() < 3:
        raise ValueError(f"{what}: fewer than 3 outages were scored (the core did not navigate in time)")
    per = per[:, scored]
    outs = [o for o, s in zip(outages, scored, strict=True) if s]
    cost = per.sum(axis=1) / counts[scored].sum()
    rng = np.random.default_rng(seed)
    m = per.shape[1]
    # a resample whose minimum falls on the edge counts at the edge (its spread is then a lower bound)
    bs = [_vertex(grid, per[:, rng.integers(0, m, m)].sum(axis=1), edge=True) for _ in range(bootstrap)]
    std = float(np.std(bs))
    est = _vertex(grid, cost)
    reason = ""
    spread = float(cost.max()) / max(float(cost.min()), 1e-12) - 1.0
    if coarse is not None:  # the whole search's shape is the coarse curve's: flat, or a minimum that wanders
        cg, cc, pc, ok = coarse
        spread = max(spread, float(cc.max()) / max(float(cc.min()), 1e-12) - 1.0)
        std_c = float(np.std([_vertex(cg, b, edge=True) for b in _boot(pc, ok, rng, bootstrap)]))
        if std_c > 0.5 * (grid[-1] - grid[0]):  # the fine candidates do not hold the resampled minima
            std = max(std, std_c)
    if std > UNOBSERVABLE * span or spread < FLAT:
        how = ("its minimum moves across it when the outages are resampled" if std > UNOBSERVABLE * span
               else f"less than the {FLAT:.0%} a setting that matters moves it")  # fmt: skip
        reason = f"not observable on this log: the cost changes by {100 * spread:.1f} % over the search, {how}"
        est = math.nan
    elif math.isnan(est):
        edge = "below" if int(np.argmin(cost)) == 0 else "above"
        reason = (f"the lowest cost is at the edge of the search (the config's ± the span): the {what} is {edge} "
                  "it; widen the span")  # fmt: skip
    g = GridEstimate(est, math.nan if reason else std, base, grid, cost, outs, (t_from, t_to), reason, per,
                     *label, log_t0=ds.t0)  # fmt: skip
    if coarse is not None:
        g.coarse_grid, g.coarse_cost_m2 = coarse[0], coarse[1]
    return g


def _boot(per: Vec, ok: Vec, rng: np.random.Generator, n: int) -> list[Vec]:
    """``n`` bootstrap resamples (over the scored outages) of the summed cost per candidate."""
    p = per[:, ok]
    m = p.shape[1]
    return [p[:, rng.integers(0, m, m)].sum(axis=1) for _ in range(n)]


def decimate(ds: Dataset, hz: float) -> Dataset:
    """``ds`` with its IMU samples summed in consecutive groups to about ``hz`` Hz (the angle and velocity
    increments and the intervals added, the time of the last; the IMU unchanged when it is not faster than
    ``2 hz``) and its baro and magnetometer thinned to :data:`COARSE_AID_HZ`: a cheaper replay of the same motion
    (the coning and sculling inside a group are lost)."""
    imu = ds.imu
    if len(imu) < 3:
        return ds
    dt = float(np.median([s.dt for s in imu]))
    k = int(1.0 / (hz * dt)) if dt > 0 else 1
    if k < 2:
        return dataclasses.replace(ds, baro=_thin(ds.baro, COARSE_AID_HZ), mag=_thin(ds.mag, COARSE_AID_HZ))
    out = []
    for i in range(0, len(imu) - k + 1, k):
        g = imu[i : i + k]
        last = g[-1]
        if last.t - g[0].t > 1.5 * (k - 1) * dt:  # a gap inside the group: keep its samples as they are
            out.extend(g)
            continue
        out.append(dataclasses.replace(last, dt=float(sum(s.dt for s in g)),
                                       dtheta=np.sum([s.dtheta for s in g], axis=0),
                                       dvel=np.sum([s.dvel for s in g], axis=0)))  # fmt: skip
    return dataclasses.replace(ds, imu=out, baro=_thin(ds.baro, COARSE_AID_HZ), mag=_thin(ds.mag, COARSE_AID_HZ))


def _thin(samples: list[Any], hz: float) -> list[Any]:
    """Every sample at least 1/``hz`` s after the last one kept."""
    out: list[Any] = []
    for s in samples:
        if not out or s.t - out[-1].t >= 1.0 / hz - 1e-9:
            out.append(s)
    return out


def write_offset(config: str | Path, offset_s: float) -> None:
    """Set ``[mounting] imu_time_offset_s`` in the dataset TOML ``config`` (the rest of the file, comments
    included, unchanged; the table is added when missing)."""
    _write_mounting(config, "imu_time_offset_s", f"{offset_s:.4f}")


def write_mounting_yaw(config: str | Path, cfg: DatasetConfig, yaw: float) -> None:
    """Set the yaw (rad) of the last ``[mounting] imu_to_body_deg`` rotation in the dataset TOML ``config``, the
    other angles as ``cfg`` has them (one rotation: ``[r, p, y]``, several: ``[[…], […]]``; the rest of the file
    unchanged)."""
    rot = np.degrees(cfg.imu_to_body)
    rot[-1, 2] = math.degrees(yaw)
    rows = ["[" + ", ".join(f"{float(x):.2f}" for x in r) + "]" for r in rot]
    _write_mounting(config, "imu_to_body_deg", rows[0] if len(rows) == 1 else "[" + ", ".join(rows) + "]")


def _write_mounting(config: str | Path, key: str, value: str) -> None:
    """Set ``[mounting] key = value`` (TOML text) in ``config``: the key's line replaced (a comment after it
    kept), or added at the top of the table, or the table added at the end."""
    import re

    p = Path(config)
    text = p.read_text()
    pat = re.compile(rf"^{key}\s*=[^#\n]*(#.*)?$", re.M)
    table = re.compile(r"^\[mounting\]\s*$", re.M)
    m = table.search(text)
    if m is None:
        text = text.rstrip("\n") + f"\n\n[mounting]\n{key} = {value}\n"
    else:
        nxt = re.compile(r"^\[", re.M).search(text, m.end())
        end = nxt.start() if nxt else len(text)
        body = text[m.end() : end]
        if pat.search(body):
            body = pat.sub(lambda g: f"{key} = {value}" + (f"  {g.group(1)}" if g.group(1) else ""), body, count=1)
        else:
            body = f"\n{key} = {value}" + body
        text = text[: m.end()] + body + text[end:]
    p.write_text(text)
