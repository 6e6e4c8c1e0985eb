"""Replay a dataset with its config and report: metrics (JSON), a summary table, PNG plots.

:func:`replay` runs GNSS present (and, with an outage protocol, the protocol), compares with the onboard
estimate and a reference where the log has them, and returns the metrics; :func:`summary` formats the
table; :func:`plot` writes the figures (ours overlaid on the flight controller's).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ins_hil.datasets import compare as cmp
from ins_hil.datasets import reference as refscore
from ins_hil.datasets.config import DatasetConfig
from ins_hil.datasets.dataset import Dataset, read_dataset, reader_for
from ins_hil.datasets.run import (
    Prepared,
    RunResult,
    euler_series,
    gnss_scores,
    innovation_whiteness,
    outage_scores,
    preceded_text,
    prepare,
    rejection,
    run_dataset,
)

#: warn when the gates reject more than this fraction of a kind of measurement
REJECT_WARN = 0.03
ProgressFactory = Callable[[str], Callable[[int, int], None] | None]


#: the note of a replay without a dataset config (``ins-hil replay LOG`` without ``--dataset``)
NO_CONFIG_NOTE = ("no dataset config: identity mounting (the IMU's axes taken as body FRD), no time offsets, no lever "
                  "arms, the mems preset (--dataset CONFIG sets them)")  # fmt: skip


def load(path: Path, cfg: DatasetConfig) -> Dataset:
    """Read the recording at ``path`` with the config's format (detected when it names none; the same flight
    stack's other form, a text ``.log`` for a ``.bin``, when the file is that: :func:`reader_for`)."""
    return read_dataset(path, reader_for(path, cfg.format), cfg)


def replay(
    ds: Dataset, cfg: DatasetConfig, progress: ProgressFactory | None = None, core: str = "python"
) -> tuple[dict[str, Any], dict[str, RunResult]]:
    """Run ``ds`` through the core (``core``: "python" or "c") with ``cfg``; (metrics, runs by label)."""
    p = prepare(ds, cfg)
    prog = progress or (lambda label: None)
    runs: dict[str, RunResult] = {}
    m: dict[str, Any] = {
        "dataset": cfg.name,
        "source": ds.meta.get("source"),
        "format": ds.meta.get("format"),
        "vehicle": ds.meta.get("vehicle"),
        "rates_hz": ds.meta.get("rates_hz"),
        "samples": {
            "imu": len(p.imu),
            "gnss": len(p.gnss),
            "baro": sum(1 for a in p.aux if not hasattr(a, "field_b")),
            "mag": sum(1 for a in p.aux if hasattr(a, "field_b")),
        },
        "events": [[round(t, 3), e] for t, e in ds.events],
        "t0_s": p.t0,
        "t1_s": p.t1,
        "duration_s": p.t1 - p.t0,
        "sensor_grade": cfg.grade,
        "mag_reference": p.mag_ref_source or None,
        "mag_reference_ned_uT": (p.mag_ref_ned_T * 1e6).round(3).tolist() if p.mag_ref_ned_T is not None else None,
    }
    if core != "python":
        m["core"] = core
    if ds.meta.get("end_of_valid_data"):
        m["end_of_valid_data"] = ds.meta["end_of_valid_data"]
    r = run_dataset(p, [], "gnss", prog("replay (GNSS present)" if p.gnss else "replay"), core=core)
    runs["gnss"] = r
    m["notes"] = r.notes
    m["t_nav_s"] = r.t_nav - p.t0 if math.isfinite(r.t_nav) else None
    m["realtime_factor"] = (p.t1 - p.t0) / max(r.elapsed_s, 1e-9)
    m["rejection"] = rejection(r)
    m["imu_lost"] = {"gaps": r.imu_lost[0], "s": r.imu_lost[1]}
    m["warnings"] = [f"{k}: the gates rejected {v['rejected']} of {v['tested']} ({v['rate']:.1%})"
                     for k, v in m["rejection"].items() if v["rate"] > REJECT_WARN]  # fmt: skip
    if not math.isfinite(r.t_nav):
        m["warnings"].append(f"the core never left its alignment: {r.align_status}")
    for kind, sensor, unit in (("GnssFix", "gnss", "fixes"), ("BaroSample", "baro", "samples")):
        fused, excl = r.counts.get("fused_" + kind, 0), r.counts.get("excluded_" + kind, 0)
        if excl and excl > REJECT_WARN * (fused + excl):
            m["warnings"].append(f"{sensor}: the drift monitor (the gateway's [fdi.aiding]) excluded {excl} of "
                                 f"{fused + excl} {unit} ({excl / (fused + excl):.1%}); [fdi] aiding = false "
                                 "replays without it")  # fmt: skip
    m["warnings"] += r.sensor_warnings  # the core's start-up check: a wrong mounting, a preset below the IMU's noise
    m["divergences"] = [[round(t - p.t0, 3), why] for t, why in r.divergences]
    m["warnings"] += [f"the filter diverged at t = {t - p.t0:.1f} s and was reset to GNSS ({why}): the figures "
                      "include it" for t, why in r.divergences]  # fmt: skip
    m["yaw_resets"] = [[round(t - p.t0, 3), why] for t, why in r.yaw_resets]
    m["warnings"] += [f"the yaw was reset to the GNSS-velocity yaw estimator at t = {t - p.t0:.1f} s ({why}): the "
                      "figures include it" for t, why in r.yaw_resets]  # fmt: skip
    t_from = (r.t_nav if math.isfinite(r.t_nav) else p.t1) + cfg.settle_s
    if "gnss" in cfg.score:
        m["gnss"] = gnss_scores(r, p.gnss, cfg.min_fix_type) if p.gnss else "no GNSS fix in the log"
        if p.gnss:
            m["gnss"]["vel_innovation"] = innovation_whiteness(r)
    if cfg.outages is not None and p.gnss:
        wins = protocol_windows(ds, p, cfg)
        if wins is None:
            m["outages"] = "no take-off event in the log (set outages.relative_to = 'start')"
        else:
            t_ref = _protocol_ref(ds, p, cfg)
            assert t_ref is not None
            refs: list[refscore.ReferenceScore] = []
            tr = ds.reference
            if "reference" in cfg.score and tr is not None and tr.t_pos is not None:
                refs = [refscore.ReferenceScore(tr, p.origin, refscore.lever_of(tr, cfg.reference_lever_arm), wins)]
            ro = run_dataset(p, wins, "outages", prog("replay (outage protocol)"), observers=refs, core=core)
            runs["outages"] = ro
            m["outages"] = outage_scores(ro, p.gnss, cfg.min_fix_type)
            if refs:  # the same windows against the reference trajectory (its lever arm applied)
                m["outages"]["reference"] = refscore.outage_scores(refs[0], ro.t_nav)
                if m["outages"]["reference"] is None:
                    m["outages"]["reference"] = "no reference position inside the windows (or no origin)"
            m["outages"]["protocol"] = {"relative_to": cfg.outages.relative_to, "t_ref_s": t_ref - p.t0,
                                        "start_s": cfg.outages.start_s, "on_s": cfg.outages.on_s,
                                        "off_s": cfg.outages.off_s}  # fmt: skip
            m["outages"]["rejection"] = rejection(ro)
    if "onboard" in cfg.score:
        if ds.onboard is None:
            m["onboard"] = "no onboard estimate in the log"
        else:  # its valid part: in the air, before its own status says invalid
            a, b, why = cmp.valid_span(ds.onboard, t_from, p.t1, ds.event("takeoff"), ds.event("landing"))
            m["onboard"] = cmp.compare(r, ds.onboard, a, b)
            m["onboard"]["trimmed"] = why
    if "reference" in cfg.score:
        if ds.reference is None:
            m["reference"] = "no reference"
        else:
            tr = dataclasses.replace(ds.reference, lever_b=refscore.lever_of(ds.reference, cfg.reference_lever_arm))
            m["reference"] = cmp.compare(r, tr, t_from, p.t1)
    ref = p.nav.mag.ref_ned
    mags = [a for a in p.aux if a.kind == "mag"]
    if ref is not None and mags and len(r.t):
        mh: dict[str, Any] = {"ours": cmp.mag_heading(mags, r.t, r.q_nb, ref, t_from, p.t1)}
        ob = ds.onboard
        if ob is not None and ob.q_nb is not None and ob.t_att is not None:
            mh["onboard"], mh["onboard_name"] = cmp.mag_heading(mags, ob.t_att, ob.q_nb, ref, t_from, p.t1), ob.name
        m["mag_heading"] = mh
    if cfg.rotary_wing if cfg.rotary_wing is not None else ds.meta.get("rotary_wing"):
        m["rotor_drag"] = rotor_drag_check(ds, p, r, t_from)
        if m["rotor_drag"].get("note"):
            m["notes"] = [*m["notes"], m["rotor_drag"]["note"]]
    return m, runs


def rotor_drag_check(ds: Dataset, p: Prepared, r: RunResult, t_from: float) -> dict[str, Any]:
    """A multirotor's velocities against its accelerometers in flight (take-off to landing): the rotor-drag fit
    (:func:`ins_hil.datasets.compare.rotor_drag`) of ours (from ``t_from``, when we navigate) and of the onboard
    estimator's (its unaided samples included), and a note when the onboard velocity is one the specific force
    does not follow."""
    a = ds.event("takeoff") or p.t0
    b = min(ds.event("landing") or p.t1, p.t1)
    out: dict[str, Any] = {"from_s": a - p.t0, "to_s": b - p.t0}
    if len(r.t):
        out["ours"] = cmp.rotor_drag(p.imu, r.t, r.vel_ned, r.t, r.q_nb, max(a, t_from), b)
    ob = ds.onboard
    v = ob.vel_ned_all() if ob is not None else None
    if ob is not None and v is not None and ob.t_vel is not None and ob.q_nb is not None and ob.t_att is not None:
        fit = cmp.rotor_drag(p.imu, ob.t_vel, v, ob.t_att, ob.q_nb, a, b)
        out["onboard"], out["onboard_name"] = fit, ob.name
        ax = cmp.drag_unsensed(fit)
        if fit is not None and ax is not None:
            d = fit[ax]
            out["note"] = (
                f"rotor drag: {ob.name}'s body-{ax} velocity spans {d['span_mps']:.1f} m/s in flight, yet the body "
                f"specific force varies by {d['f_std_mps2']:.2f} m/s² (σ over {fit['avg_s']:g} s) and does not follow "
                f"it (μ {d['mu_per_s']:+.3f} /s, correlation {d['corr']:+.2f}); a rotor drag of "
                f"{cmp.ROTOR_DRAG_MIN:g} /s or more would have moved it by {d['expected_mps2']:.1f} m/s²: "
                f"{ob.name}'s horizontal velocity is not the vehicle's, and the specific-force error that drives it "
                "is in its attitude or its accelerometer bias"
            )
    return out


def _protocol_ref(ds: Dataset, p: Prepared, cfg: DatasetConfig) -> float | None:
    rel = cfg.outages.relative_to if cfg.outages is not None else "start"
    if rel == "takeoff":
        return ds.event("takeoff")
    return p.gnss[0].t if rel == "first_gnss" and p.gnss else p.t0


def protocol_windows(ds: Dataset, p: Prepared, cfg: DatasetConfig) -> list[tuple[float, float]] | None:
    """The config's outage windows (absolute s) on the prepared data; None without the take-off event the
    protocol counts from. They end before the landing or the end of the data ("first_gnss": the last fix)."""
    t_ref = _protocol_ref(ds, p, cfg)
    if cfg.outages is None or t_ref is None:
        return None if t_ref is None else []
    if cfg.outages.relative_to == "first_gnss":
        return cfg.outages.windows(t_ref, p.gnss[-1].t)
    land = ds.event("landing")
    return cfg.outages.windows(t_ref, min(p.t1, land) if land is not None else p.t1)


def num(x: Any, spec: str, why: str = "") -> str:
    """``x`` formatted with ``spec``, or "not scored (why)" when it is missing or not finite: a summary never
    prints NaN as a figure."""
    if isinstance(x, int | float | np.floating) and math.isfinite(float(x)):
        return format(float(x), spec)
    return f"not scored ({why})" if why else "not scored"


def summary(m: dict[str, Any]) -> list[tuple[str, str, str]]:
    """The summary table (quantity, value / RMS, max) of :func:`replay`'s metrics; a figure that could not be
    scored reads "not scored (why)", never "nan"."""
    rows: list[tuple[str, str, str]] = [("quantity", "RMS / value", "max")]
    never = "the core never navigated" if m.get("t_nav_s") is None else ""
    rows.append(("data", f"{m['format']}, {m['duration_s']:.1f} s", ""))
    tn = m.get("t_nav_s")
    rows.append(("navigating from", f"{tn:.2f} s" if tn is not None else "never", ""))
    g = m.get("gnss")
    if isinstance(g, dict):
        why = never or ("no fix while navigating" if not g.get("gnss_epochs") else "")
        rows.append(("GNSS present: h error prior (m)", num(g["gnss_h_rms_prior_m"], ".3f", why),
                     num(g["gnss_h_max_prior_m"], ".3f", why) if not why else ""))  # fmt: skip
        rows.append(("GNSS present: h error post (m)", num(g["gnss_h_rms_post_m"], ".3f", why), ""))
        w = g.get("vel_innovation")
        if isinstance(w, dict):
            lag1 = " / ".join(num(x, "+.2f", "too few pairs") for x in w["lag1"])
            rows.append(("GNSS vel innovations N / E (m/s)", " / ".join(num(x, ".3f") for x in w["rms_mps"]), ""))
            rows.append(("  lag-1 autocorrelation N / E", lag1, f"white: ±{w['white_band']:.2f}"))
    elif g:
        rows.append(("GNSS", str(g), ""))
    o = m.get("outages")
    if isinstance(o, dict) and not o.get("outages_scored"):
        why = never or ("no window in the data" if not o.get("windows") else "no window opened while navigating "
                        "with fixes inside it")  # fmt: skip
        rows.append(("outages: h error (m)", f"not scored ({why})", ""))
    elif isinstance(o, dict):
        rows.append((f"outages ({o['outages_scored']} scored): h error (m)", num(o["outage_h_rms_m"], ".2f"),
                     num(o["outage_h_max_m"], ".2f")))  # fmt: skip
        rows.append(("  hold the last fix (m)", num(o["hold_h_rms_m"], ".2f"), num(o["hold_h_max_m"], ".2f")))
        rows.append(("  constant-velocity extrapolation (m)", num(o["cv_h_rms_m"], ".2f"), num(o["cv_h_max_m"], ".2f")))
        rows.append(("  NEES (2 dof, mean)", num(o["nees_2dof_mean"], ".2f"), ""))
        if math.isfinite(o.get("sf_err_rms_mps2", math.nan)):
            rows.append(("  fitted: start velocity error (m/s)", f"{o['start_vel_err_rms_mps']:.3f}",
                         f"{o['start_vel_err_max_mps']:.3f}"))  # fmt: skip
            tilt = o["sf_err_rms_tilt_deg"]
            rows.append(("  fitted: specific-force error (m/s²)", f"{o['sf_err_rms_mps2']:.3f} ({tilt:.2f}° tilt)",
                         f"{o['sf_err_max_mps2']:.3f}"))  # fmt: skip
            if math.isfinite(o.get("start_tilt_std_rms_deg", math.nan)):
                rows.append(("  filter's tilt σ at the starts (°)", f"{o['start_tilt_std_rms_deg']:.2f}",
                             f"{o['start_tilt_std_max_deg']:.2f}"))  # fmt: skip
        rows.append(("  below both predictors in every outage", "yes" if o["beats_both_in_every_outage"] else "no", ""))
        rf = o.get("reference")
        if isinstance(rf, dict):
            rows.append((f"  vs reference ({rf['outages_scored']} scored): h error (m)", num(rf["h_rms_m"], ".2f"),
                         num(rf["h_max_m"], ".2f")))  # fmt: skip
            rows.append(("  vs reference: v error RMS (m), NEES", f"{num(rf['v_rms_m'], '.2f')}, "
                         f"{num(rf['nees_2dof_mean'], '.2f')}", ""))  # fmt: skip
        elif rf:
            rows.append(("  vs reference", str(rf), ""))
        scored = [w for w in o["windows"] if w.get("scored")]
        for k, w in enumerate(scored, 1):
            if w["beats_both"] or "before" not in w:
                continue
            rows.append((f"  outage {k}: ours / hold / cv (m)", f"{w['h_rms_m']:.2f} / {w['hold_h_rms_m']:.2f} / "
                         f"{w['cv_h_rms_m']:.2f}", "opened " + preceded_text(w["before"])))  # fmt: skip
    elif o:
        rows.append(("outages", str(o), ""))
    for key in ("onboard", "reference"):
        c = m.get(key)
        if isinstance(c, dict):
            if c.get("trimmed") and c["to_s"] > c["from_s"]:  # an empty span (never navigated in the air): no row
                span = f"{c['from_s'] - m['t0_s']:.1f}–{c['to_s'] - m['t0_s']:.1f} s"
                rows.append((f"vs {c['against']}: compared", span, c["trimmed"]))
            rows += [(f"vs {c['against']}: {a}", b, x) for a, b, x in cmp.summary_rows(c)]
        elif c:
            rows.append((key, str(c), ""))
    mh = m.get("mag_heading")
    if isinstance(mh, dict):
        for key, who in (("ours", "ours"), ("onboard", mh.get("onboard_name", ""))):
            h = mh.get(key)
            if h is not None:
                rows.append((f"yaw − magnetic heading (°), {who}", num(h["rms"], ".2f", "no sample"),
                             num(h["max"], ".2f", "no sample")))  # fmt: skip
    rd = m.get("rotor_drag")
    if isinstance(rd, dict):
        for key, who in (("ours", "ours"), ("onboard", rd.get("onboard_name", ""))):
            fit = rd.get(key)
            if fit is None:
                continue
            mu = " / ".join("n/a" if not math.isfinite(fit[a]["mu_per_s"]) else f"{fit[a]['mu_per_s']:+.3f}"
                            for a in ("x", "y"))  # fmt: skip
            span = " / ".join(num(fit[a]["span_mps"], ".1f") for a in ("x", "y"))
            rows.append((f"rotor drag μ x / y (1/s), {who}", mu, f"speed span {span} m/s"))
    lost = m.get("imu_lost")
    if isinstance(lost, dict) and lost.get("gaps"):
        rows.append(("IMU data lost (coasted)", f"{lost['gaps']} gaps, {lost['s']:.2f} s", ""))
    for k, v in m.get("rejection", {}).items():
        rows.append((f"gate rejections {k}", f"{v['rejected']} / {v['tested']} ({v['rate']:.1%})", ""))
    rows.append(("replay speed", f"{m['realtime_factor']:.0f}x real time", ""))
    return rows


def format_table(rows: list[tuple[str, str, str]]) -> str:
    w = [max(len(r[i]) for r in rows) for i in range(3)]
    return "\n".join("  ".join(c.ljust(w[i]) for i, c in enumerate(r)).rstrip() for r in rows)


def plot(m: dict[str, Any], runs: dict[str, RunResult], ds: Dataset, out: Path) -> list[Path]:
    """PNG plots into ``out``: attitude and velocity, ours over the onboard estimate; the GNSS error with the
    outages. No error curves against a reference the log does not have."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    r = runs["gnss"]
    paths: list[Path] = []
    if not len(r.t):
        return paths
    t0 = m["t0_s"]
    tt = r.t - t0
    eul = np.degrees(euler_series(r.q_nb))
    c = m.get("onboard") if isinstance(m.get("onboard"), dict) else None
    s = c["_series"] if c else {}
    fig, ax = plt.subplots(3, 1, figsize=(10, 8), sharex=True)
    for k, name in enumerate(("roll", "pitch", "yaw")):
        ax[k].plot(tt, eul[:, k], lw=0.8, label="ins_hil")
        if "att_t" in s:
            ax[k].plot(s["att_t"] - t0, s["att_theirs_deg"][:, k], lw=0.8, label=c["against"])  # type: ignore[index]
        ax[k].set_ylabel(f"{name} (°)")
        ax[k].grid(alpha=0.3)
    mh = m.get("mag_heading", {}).get("ours") if isinstance(m.get("mag_heading"), dict) else None
    if mh is not None and "_t" in mh:
        ax[2].plot(mh["_t"] - t0, mh["_heading_deg"], ".", ms=2, color="0.4",
                   label="magnetometer heading (levelled with ours)")  # fmt: skip
        ax[2].legend(loc="best")
    ax[0].legend(loc="upper right")
    ax[0].set_title(f"{m['dataset']}: attitude" + ("" if c else " (no onboard estimate in the log)"))
    ax[2].set_xlabel("time from the start of the log (s)")
    paths.append(out / "attitude.png")
    fig.tight_layout()
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)
    fig, ax = plt.subplots(3, 1, figsize=(10, 8), sharex=True)
    for k, name in enumerate(("north", "east", "down")):
        ax[k].plot(tt, r.vel_ned[:, k], lw=0.8, label="ins_hil")
        if "vel_t" in s:
            ax[k].plot(s["vel_t"] - t0, s["vel_theirs"][:, k], lw=0.8, label=c["against"])  # type: ignore[index]
        ax[k].set_ylabel(f"v {name} (m/s)")
        ax[k].grid(alpha=0.3)
    ax[0].legend(loc="upper right")
    ax[0].set_title(f"{m['dataset']}: velocity")
    ax[2].set_xlabel("time from the start of the log (s)")
    paths.append(out / "velocity.png")
    fig.tight_layout()
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)
    ro = runs.get("outages")
    if ro is not None and len(ro.gnss_t):
        fig, ax = plt.subplots(2, 1, figsize=(10, 7))
        h = np.hypot(ro.gnss_err[:, 0], ro.gnss_err[:, 1])
        ax[0].plot(ro.gnss_t - t0, h, ".", ms=2, label="ins_hil, prior to each fix")
        for a, b in ro.outages:
            ax[0].axvspan(a - t0, b - t0, color="0.85")
        ax[0].set_ylabel("horizontal error vs GNSS (m)")
        ax[0].set_xlabel("time from the start of the log (s)")
        ax[0].set_title(f"{m['dataset']}: outage protocol (grey: GNSS removed)")
        ax[0].grid(alpha=0.3)
        ax[0].legend()
        ax[1].plot(ro.gnss_ref[:, 1], ro.gnss_ref[:, 0], "k.", ms=2, label="GNSS")
        ax[1].plot(ro.ned[:, 1], ro.ned[:, 0], lw=0.8, label="ins_hil (outage protocol)")
        ax[1].set_xlabel("east (m)")
        ax[1].set_ylabel("north (m)")
        ax[1].axis("equal")
        ax[1].grid(alpha=0.3)
        ax[1].legend()
        paths.append(out / "outages.png")
        fig.tight_layout()
        fig.savefig(paths[-1], dpi=110)
        plt.close(fig)
    return paths


def jsonable(m: Any) -> Any:
    """The metrics without the plot series (``_series``), numbers as plain floats."""
    if isinstance(m, dict):
        return {k: jsonable(v) for k, v in m.items() if not k.startswith("_")}
    if isinstance(m, (list, tuple)):
        return [jsonable(v) for v in m]
    if isinstance(m, (np.floating, np.integer)):
        return m.item()
    if isinstance(m, np.ndarray):
        return m.tolist()
    if isinstance(m, float) and not math.isfinite(m):
        return None
    return m


def replay_to_dir(
    source: Path | None, config: Path | None, out: Path, plots: bool = True, progress: ProgressFactory | None = None,
    export: Path | None = None, core: str = "python",
) -> tuple[dict[str, Any], str]:  # fmt: skip
    """``ins-hil replay FILE|DIR [--dataset CONFIG]``: read, replay, write ``metrics.json`` and the plots into
    ``out``; (metrics, the summary text). ``source`` None: the config's ``dataset.path``. ``export``: the GNSS-present
    replay's trajectory as CSV (:mod:`ins_hil.datasets.export`). ``core``: "python" or "c". DatasetError /
    DatasetConfigError (one line) on bad input."""
    import json

    from ins_hil.datasets.config import DatasetConfig, DatasetConfigError
    from ins_hil.datasets.config import load as load_config

    if config is not None:
        cfg = load_config(config)
    else:
        cfg = DatasetConfig(name=Path(source).stem if source is not None else "dataset")
    path = source if source is not None else cfg.path
    if path is None:
        raise DatasetConfigError(f"{config}: no dataset.path and no FILE|DIR given")
    ds = load(Path(path), cfg)
    m, runs = replay(ds, cfg, progress, core)
    notes = m.setdefault("notes", [])
    if config is None and not any(str(n).startswith("no dataset config") for n in notes):
        notes.insert(0, NO_CONFIG_NOTE)
    out.mkdir(parents=True, exist_ok=True)
    if plots:
        m["plots"] = [str(p) for p in plot(m, runs, ds, out)]
    (out / "metrics.json").write_text(json.dumps(jsonable(m), indent=2))
    lines = [f"{cfg.name}: {ds.meta.get('source')} ({ds.meta.get('format')}, sensor grade {cfg.grade}"
             + (", default dataset config" if config is None else f", {config}") + ")"]  # fmt: skip
    lines += [f"note: {n}" for n in m.get("notes", [])]
    if m.get("end_of_valid_data"):
        lines.append(f"end of valid data: {m['end_of_valid_data']}")
    if m.get("mag_reference"):
        lines.append(f"magnetic reference: {m['mag_reference']}")
    lines.append(format_table(summary(m)))
    lines += [f"WARNING: {w}" for w in m.get("warnings", [])]
    lines.append(f"metrics: {out / 'metrics.json'}")
    if export is not None:
        from ins_hil.datasets import export as ex

        r = runs["gnss"]
        lines.append(f"trajectory: {ex.write_csv(export, ex.rows_from_run(r))} ({len(r.t)} states)")
    return m, "\n".join(lines)
