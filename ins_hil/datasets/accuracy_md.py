"""``docs/accuracy.md``: the Markdown of ``ins-hil replay --docs`` from its metrics (the drive's protocol study,
:mod:`ins_hil.datasets.study`; the simulated scenarios and Monte Carlo, :mod:`ins_hil.datasets.simulated`)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from ins_hil import machine
from ins_hil.datasets.run import preceded_text


def fmt_value(x: Any, nd: int = 3, missing: str | None = None) -> str:
    """A float with ``nd`` decimals, a list of them in brackets, anything else as str; with ``missing``, that
    for None and a non-finite float."""
    if missing is not None and (x is None or (isinstance(x, float) and not math.isfinite(x))):
        return missing
    if isinstance(x, float):
        return f"{x:.{nd}f}"
    if isinstance(x, list):
        return "[" + ", ".join(fmt_value(v, nd, missing) for v in x) + "]"
    return str(x)


def _per_outage(pw: list[dict[str, float]]) -> str:
    """'RMS/max, …' (m) of each outage, as the report's tables give them."""
    return ", ".join(f"{x['rms_m']:.2f}/{x['max_m']:.2f}" for x in pw)


def _whatif_baro_md(
    wb: list[dict[str, Any]],
    pw: list[dict[str, float]],
    windows: list[list[float]],
    base: dict[str, Any],
    targets: dict[str, float],
) -> str:
    """The what-if section: the protocol with a synthetic barometer (rows from ``ins_hil.datasets.study``);
    ``targets``: the protocol's ``outage_h_rms_m`` / ``outage_h_max_m`` targets (m)."""
    rows = [("none (the protocol, table above)", "", f"{base['outage_h_rms_m']:.2f} / {base['outage_h_max_m']:.2f}",
             f"{base['outage_v_rms_m']:.2f}", _per_outage(pw))]  # fmt: skip
    for r in wb:
        rows.append((f"{r['baro']}: {r['white_m']:g} m white, {r['drift_m_sqrt_s']:g} m/√s drift", str(r["seed"]),
                     f"{r['outage_h_rms_m']:.2f} / {r['outage_h_max_m']:.2f}", f"{r['outage_v_rms_m']:.2f}",
                     _per_outage(r["per_window"])))  # fmt: skip
    w = max(range(len(pw)), key=lambda i: pw[i]["max_m"])
    with_b = [r["per_window"][w]["max_m"] for r in wb]
    t_rms, t_max = targets.get("outage_h_rms_m", math.inf), targets.get("outage_h_max_m", math.inf)
    meets = all(r["outage_h_rms_m"] <= t_rms and r["outage_h_max_m"] <= t_max for r in wb)
    worst_b = [int(np.argmax([x["max_m"] for x in r["per_window"]])) for r in wb]
    head = ("synthetic barometer", "seed", "outage h RMS / max (m)", "outage v RMS (m)", "per outage h RMS / max (m)")
    return (
        "### What a barometer would do (a what-if with a synthetic sensor, not a protocol figure)\n\n"
        "The drive has no barometer. Its worst outage is an along-track error from a pitch "
        "(gyro-y bias) that nothing measures during the outage: the vertical NHC ties the pitch to the vertical "
        "velocity, which is free without a height reference. To test that reading, `ins-hil replay --docs` also runs "
        "the protocol (drive settings, ZUPT + NHC) with a barometer made from the RTK height at the RTK-fixed "
        "epochs (4 Hz) plus white noise and a random-walk drift (`ins_hil.datasets.study.synthetic_baro`, seeded), "
        "fused the whole time, outages included (`run_drive(aux=...)`), its datum learnt against GNSS as the gateway "
        "does (`baro.offset_tau`) and `baro.std` set to the white noise. It is built from the truth, so it is a study "
        "for choosing a sensor, never a protocol result.\n\n"
        + _md_table(head, tuple(rows))
        + f"\n\nThe worst protocol outage ({windows[w][0]:.0f} s, {pw[w]['max_m']:.2f} m) has a worst case of "
        + ", ".join(f"{x:.2f}" for x in with_b)
        + " m with the barometers. With a barometer the worst outage of each run is "
        + ", ".join(f"{windows[i][0]:.0f} s" for i in worst_b)
        + " (the first outage starts 0.25 s after the in-motion yaw alignment; the baro datum is learnt against "
        "GNSS during the rest before it). The spread between the two seeds of one barometer is as large as the "
        "difference between the barometers: two seeds show the size of the effect, not a ranking. "
        + ("Every" if meets else "Not every")
        + f" barometer run meets both targets (≤ {t_rms:g} m RMS, ≤ {t_max:g} m worst)"
        + "; the drive's own data hold no pitch or height reference.\n"
    )


#: the flight-log targets (docs/design/flight_log_findings.md): (config, quantity, value from the replay's
#: metrics, target, bound)
FLIGHT_LOG_TARGETS: tuple[tuple[str, str, str, str, float], ...] = (
    ("px4_hover", "roll vs EKF2, RMS (°)", "onboard.attitude_deg.roll.rms", "≤ 0.7°", 0.7),
    ("px4_hover", "pitch vs EKF2, RMS (°)", "onboard.attitude_deg.pitch.rms", "≤ 0.7°", 0.7),
    ("px4_hover", "yaw vs EKF2, RMS (°)", "onboard.attitude_deg.yaw.rms", "≤ 5°", 5.0),
    ("px4_hover", "height vs EKF2, RMS (m)", "onboard.position_m.down.rms", "≤ 0.5 m", 0.5),
    ("px4_hover", "yaw − the magnetometer's own heading, ours, RMS (°)", "mag_heading.ours.rms", "reported", math.inf),
    (
        "px4_hover",
        "yaw − the magnetometer's own heading, EKF2, RMS (°)",
        "mag_heading.onboard.rms",
        "reported",
        math.inf,
    ),
    (
        "px4_hover",
        "EKF2's body-x velocity in flight, 5–95 % span (m/s)",
        "rotor_drag.onboard.x.span_mps",
        "reported",
        math.inf,
    ),
    (
        "px4_hover",
        "body-x specific force against it: rotor drag μ (1/s)",
        "rotor_drag.onboard.x.mu_per_s",
        "≥ 0.1 for a real velocity",
        math.inf,
    ),
    ("px4_quad", "GNSS-present h error prior, RMS (m)", "gnss.gnss_h_rms_prior_m", "≤ 0.35 m", 0.35),
    ("px4_quad", "10-s outages h error, RMS (m)", "outages.outage_h_rms_m", "≤ 2 m", 2.0),
    ("px4_quad", "10-s outages h error, worst (m)", "outages.outage_h_max_m", "≤ 6 m", 6.0),
    ("px4_quad", "outage NEES (2 dof, mean)", "outages.nees_2dof_mean", "reported", math.inf),
    (
        "px4_quad",
        "body-x specific force against our velocity: rotor drag μ (1/s)",
        "rotor_drag.ours.x.mu_per_s",
        "≥ 0.1 for a real velocity",
        math.inf,
    ),
    ("ardupilot_copter", "roll vs NKF1, RMS (°)", "onboard.attitude_deg.roll.rms", "≤ 1°", 1.0),
    ("ardupilot_copter", "pitch vs NKF1, RMS (°)", "onboard.attitude_deg.pitch.rms", "≤ 1.5°", 1.5),
    ("ardupilot_copter", "yaw vs NKF1, RMS (°)", "onboard.attitude_deg.yaw.rms", "≤ 2°", 2.0),
)


def _dig(m: dict[str, Any], path: str) -> Any:
    for k in path.split("."):
        m = m.get(k) if isinstance(m, dict) else None  # type: ignore[assignment]
    return m


def flight_logs_md(logs: dict[str, dict[str, Any]]) -> str:
    """The flight-log section: each shipped log's target quantities (``ins-hil replay --dataset
    configs/datasets/NAME.toml``), measured against :data:`FLIGHT_LOG_TARGETS`."""
    rows = []
    for name, quantity, path, target, bound in FLIGHT_LOG_TARGETS:
        m = logs.get(name, {})
        if "error" in m:
            rows.append((name, quantity, f"failed: {m['error']}", target, "—"))
            continue
        v = _dig(m, path)
        ok = "reported" if not math.isfinite(bound) else ("met" if v is not None and v <= bound else "falls short")
        nd = 3 if bound < 0.5 or path.endswith("mu_per_s") else 2
        rows.append((name, quantity, fmt_value(v, nd, missing="—"), target, ok))
    for name in sorted(logs):
        m = logs[name]
        o = m.get("outages")
        if isinstance(o, dict) and "beats_both_in_every_outage" in o:
            n = sum(1 for w in o["windows"] if w.get("scored") and w.get("beats_both"))
            rows.append((name, "outages below hold-last-fix and constant velocity", f"{n} of {o['outages_scored']}",
                         "every outage", "met" if o["beats_both_in_every_outage"] else "falls short"))  # fmt: skip
            for k, w in enumerate((w for w in o["windows"] if w.get("scored")), 1):
                if not w["beats_both"] and "before" in w:
                    rows.append((name, f"outage {k}, opened {preceded_text(w['before'])}: ours / hold / cv h RMS (m)",
                                 f"{w['h_rms_m']:.2f} / {w['hold_h_rms_m']:.2f} / {w['cv_h_rms_m']:.2f}",
                                 "below both", "falls short"))  # fmt: skip
        rej = [v["rate"] for v in m.get("rejection", {}).values()]
        if rej:
            rows.append((name, "gate rejections, worst kind", f"{max(rej):.1%}", "reported", "reported"))
    return (
        "## Flight logs (`configs/datasets/`)\n\n"
        "Each shipped flight log replayed with its dataset config (only the sensor grade, mounting, lever arms and "
        "time offsets set; `ins-hil replay --dataset configs/datasets/NAME.toml`); what the figures mean and why "
        "some fall short: docs/design/flight_log_findings.md.\n\n"
        + _md_table(("log", "quantity", "measured", "target", ""), tuple(rows))
        + "\n"
    )


def _md_table(head: tuple[str, ...], rows: tuple[tuple[str, ...], ...]) -> str:
    """A markdown table."""
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def odometer_md(od: dict[str, Any]) -> str:
    """The odometer study (``ins_hil.datasets.simulated.odometer_outages``) as a table and its protocol."""
    w, wo = od["with"], od["without"]
    o = ", ".join(f"{a:.0f}–{b:.0f} s" for a, b in od["outages_s"])
    sc = od.get("scale_learnt") or []
    rows = (
        ("RMS over the outage, mean", w["rms_mean_m"], wo["rms_mean_m"]),
        ("RMS over the outage, median", w["rms_median_m"], wo["rms_median_m"]),
        ("at the outage's end, mean", w["end_mean_m"], wo["end_mean_m"]),
        ("at the outage's end, median", w["end_median_m"], wo["end_median_m"]),
    )
    lines = [
        "### Wheel odometer (simulated car)\n",
        "The simulated car (`ins_hil.sim.scenarios.odometer_car`: 12 m/s, weaving, 100 s) with a consumer-grade IMU "
        "(100 °/h gyro and 5 mg accelerometer bias instability, τ 60 s), GNSS 5 Hz (σ 0.1 m) withheld in "
        f"{o}, NHC + ZUPT in both runs, the odometer at 10 Hz (σ 0.05 m/s, reading {od['scale_true']:.0%} fast), "
        f"seeds {od['seeds'][0]}–{od['seeds'][-1]} ({od['runs']} outages in all), through the gateway's Pipeline "
        "(`ins_hil.datasets.simulated.odometer_outages`):\n",
        "| horizontal error in the 30-s outage | with the odometer (m) | without (m) |",
        "|---|---|---|",
        *(f"| {n} | {a:.2f} | {b:.2f} |" for n, a, b in rows),
        "",
    ]
    if sc:
        lines.append(f"The scale factor learnt before the first outage: {min(sc):.4f}–{max(sc):.4f} "
                     f"(true {od['scale_true']:g}).\n")  # fmt: skip
    return "\n".join(lines)


def render_markdown(r: dict[str, Any], plots: dict[str, list[Path]], docs: Path) -> str:
    """The report: ``r`` as written by ``ins-hil replay --docs``, ``plots`` by section, paths relative to ``docs``."""
    d = r["drive"]
    L: list[str] = []
    a = L.append
    a("# Accuracy report (generated by `ins-hil replay --docs`)\n")
    a(f"Machine: {machine.summary()}.\n")
    a("All processing is causal (no smoothing, no look-back); GNSS is fused at its time of validity.\n")
    a(f"## Real drive (`{d.get('source_rel', d.get('source', ''))}`)\n")
    a("All its settings (file names, mounting, lever arm, IMU time offset, noise, filter and aid overrides, outage "
      f"protocol and held-out checks) are in its dataset config, `{d.get('config', '')}`; `ins-hil replay drive` "
      "runs it.\n")  # fmt: skip
    a(f"{d['imu_samples']} IMU samples, {d['gnss_epochs']} GNSS epochs, {d['outages']} outages of "
      f"{d.get('outage_on_s', 15.0):g} s "
      f"(README protocol), {d['csv_bad_lines']} unparseable csv lines skipped.\n")  # fmt: skip
    a("| run | outage h RMS (m) | outage h max (m) | outage v RMS (m) | GNSS-present h RMS prior / post (m) |"
      " replay speed (× real time) |")  # fmt: skip
    a("|---|---|---|---|---|---|")
    for tag, name in (("aids", "with ZUPT + NHC"), ("no_aids", "no ground-vehicle aids (UAV-like)")):
        o, g = d[f"outages_{tag}"], d[f"gnss_{tag}"]
        a(f"| {name} | {o['outage_h_rms_m']:.2f} | {o['outage_h_max_m']:.2f} | {o['outage_v_rms_m']:.2f} | "
          f"{g['gnss_h_rms_prior_m']:.3f} / {g['gnss_h_rms_post_m']:.3f} | {o['realtime_factor']:.1f} |")  # fmt: skip
    c5 = d.get("outages_aids_cov5")
    if c5:
        a(f"| with aids, P propagated every 5 IMU steps | {c5['outage_h_rms_m']:.2f} | {c5['outage_h_max_m']:.2f} | "
          f"{c5['outage_v_rms_m']:.2f} | | {c5['realtime_factor']:.1f} |")  # fmt: skip
    for tag, name in (("aids", "with ZUPT + NHC"), ("no_aids", "no aids")):
        v = d.get(f"validation_{tag}")
        if v:
            a(f"| held-out validation outages (3 × 11 shifted windows), {name} | {v['outage_h_rms_m']:.2f} | "
              f"{v['outage_h_max_m']:.2f} | | | |")  # fmt: skip
    su = d.get("startup_aids")
    if su:
        w = d["startup_window_s"]
        a(f"| start-up outage (restart {d['startup_restart_s']:.0f} s, outage {w[0]:.2f}–{w[1]:.2f} s), ZUPT + NHC | "
          f"{su['outage_h_rms_m']:.2f} | {su['outage_h_max_m']:.2f} | | | |")  # fmt: skip
    tg, up = d.get("targets", {}), d.get("upstream", {})
    if tg:
        v_up = f"(upstream {up['outage_v_rms_m']:g})" if "outage_v_rms_m" in up else ""
        a(f"| target | ≤ {tg['outage_h_rms_m']:g} | ≤ {tg['outage_h_max_m']:g} | {v_up} | ≤ {tg['gnss_h_rms_m']:g} | "
          f"≥ {tg['realtime_factor']:g} |")  # fmt: skip
    if up:
        a(f"| upstream filter, causal | {up['outage_h_rms_m']:g} | {up['outage_h_max_m']:g} | "
          f"{up['outage_v_rms_m']:g} | | |")  # fmt: skip
    a("")
    a("GNSS-present RMS: every RTK-fixed epoch of a run with GNSS all the time, antenna position; 'prior' is the "
      "state propagated to the epoch before that epoch is fused (what a consumer sees between fixes), 'post' "
      "after the update.\n")  # fmt: skip
    pw = d.get("per_window_aids")
    if pw:
        a(
            "Per protocol outage, with ZUPT + NHC (h RMS / max, m): "
            + ", ".join(f"{w[0]:.0f} s {r['rms_m']:.2f}/{r['max_m']:.2f}" for w, r in zip(d["outage_windows_s"], pw))
            + ".\n"
        )
    wb = d.get("whatif_baro")
    if wb and pw:
        a(_whatif_baro_md(wb, pw, d["outage_windows_s"], d["outages_aids"], tg))
    a("How the drive's settings were chosen on the held-out validation and start-up outages, what each "
      "modelling choice does and what limits the worst outage: `docs/design/drive-tuning.md`.\n")  # fmt: skip
    for k in ("drive_outages_aids", "drive_outages_no_aids", "drive_gnss_aids"):
        for p in plots.get(k, []):
            a(f"![{p.stem}]({p.relative_to(docs)})")
    a("")
    if r.get("flight_logs"):
        a(flight_logs_md(r["flight_logs"]))
    a("## Simulations\n")
    a("| scenario | attitude RMS (°, r/p/y) | attitude max (°) | velocity RMS (m/s) | position RMS (m) |"
      " position max (m) | mean NEES (9 dof) | × real time |")  # fmt: skip
    a("|---|---|---|---|---|---|---|---|")
    for name, m in r["scenarios"].items():
        if not m.get("att_rms_deg"):
            continue
        a(f"| {name} (from {m['steady_from_s']:.0f} s) | {fmt_value(m['att_rms_deg'], 3)} | "
          f"{fmt_value(m['att_max_deg'], 3)} | {fmt_value(m['vel_rms_mps'], 3)} | {fmt_value(m['pos_rms_m'], 2)} | "
          f"{fmt_value(m['pos_max_m'], 2)} | "
          f"{m['nees_mean_9dof']:.1f} | {m['realtime_factor']:.0f} |")  # fmt: skip
    a("\nTargets (Example 3.2 steady state): attitude < 0.1°, velocity < 0.1 m/s, position < 1 m "
      "(book: ~0.2 m/s, < 1 m). `example32` is the book's schedule and sensors (GNSS 50 m / 0.1 m/s every 2 s, "
      "magnetometer σ_m = 0.0524, altimeter 1 m; GNSS off in [180, 420] s); `example32_gnss` is the same "
      "motion and IMU with a 5 Hz GNSS (0.5 m, 0.02 m/s). Circle interpretation: DIGEST_000 §10 item 18, "
      "aircraft angles, level circle with the roll oscillation φ = 0.3 sin(10ψ) superposed. `static` is 120 s at "
      "rest with a MEMS IMU: the levelling takes the accelerometer's horizontal bias as tilt (bias/g, book §4.1.1) "
      "and the magnetometer gives the yaw only (tilt-compensated with that tilt), so the attitude error lies about "
      "the field's direction, where neither the magnetometer nor anything at rest can see it; it is the bias the "
      "sensor model draws, not a filter fault.\n")  # fmt: skip
    for mc in (r["monte_carlo"], r["monte_carlo_uav"]):
        a(f"Monte-Carlo consistency, `{mc['scenario']}`, {mc['runs']} runs (from {mc['from_s']:.0f} s): "
          f"average NEES {mc['anees_mean']:.2f} for 9 dof, two-sided 95 % χ² bounds "
          f"[{mc['anees_bounds_95'][0]:.2f}, {mc['anees_bounds_95'][1]:.2f}], inside the bounds "
          f"{mc['fraction_inside']:.0%} of the time; mean NIS/dof "
          + ", ".join(f"{k} {v:.2f}" for k, v in mc["nis_mean_over_dof"].items())
          + " (1.0 = consistent); yaw error RMS over the runs "
          + f"{mc['yaw_err_rms_deg']:.3f}° against the filter's own yaw σ (RMS) "
          + f"{mc['yaw_std_rms_deg']:.3f}°.\n")  # fmt: skip
    a("The Example 3.2 yaw floor with the book's sensors (the filter's own steady-state yaw σ ≈ 0.18°): "
      "`docs/design/drive-tuning.md`, last section.\n")  # fmt: skip
    for name in r["scenarios"]:
        for p in plots.get(name, []):
            if p.stem.endswith("errors"):
                a(f"![{p.stem}]({p.relative_to(docs)})")
    a("")
    od = r.get("odometer")
    if od:
        a(odometer_md(od))
    a("## Hot path (µs per IMU step, Python)\n")
    hp = r["hot_path"]
    scale = 21.0 / hp["mechanization_us"]
    a("| measurement | µs (measured, loaded machine) | µs scaled to a 21 µs mechanization (estimate) |")
    a("|---|---|---|")
    for k, v in hp.items():
        a(f"| {k} | {v:.1f} | {v * scale:.1f} |")
    a("\nTarget: mechanization + 15-state predict ≤ 150 µs (mechanization alone ~21 µs on an idle machine; the "
      "scaled column divides out the machine load measured on the mechanization itself). "
      "`with_delay_history` keeps the state snapshots for delayed GNSS fusion (rollback and forward "
      "propagation).\n")  # fmt: skip
    a(f"Report generated in {r['elapsed_s']:.0f} s.\n")
    return "\n".join(L)
