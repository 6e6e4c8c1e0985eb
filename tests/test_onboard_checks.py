"""The sensor-level checks of an estimate (ins_hil.datasets.compare): a multirotor's velocity against its
accelerometers (rotor drag) and a yaw against the magnetometer's own heading; synthetic flights, the vehicle type
from the shipped logs, and the replay's figures on them."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from ins_hil.cli import main
from ins_hil.datasets import compare as cmp
from ins_hil.datasets.dataset import read_dataset
from ins_hil.nav.rotation import dcm_from_quat, quat_from_euler
from ins_hil.types import ImuSample, MagSample

REPO = Path(__file__).resolve().parents[1]


def _flight(mu: float, speed: float, seed: int = 1, dt: float = 0.005, T: float = 60.0):
    """A multirotor at yaw 30° flying a body-x velocity of speed·sin(2π t / 20) (plus a slower body-y one): its
    body specific force −μ v + c + white noise (σ 0.3 m/s² per sample). Returns the IMU and the (t, v_ned, q)."""
    rng = np.random.default_rng(seed)
    q = quat_from_euler(0.0, 0.0, math.radians(30.0))
    C = dcm_from_quat(q)
    t = np.arange(1, int(T / dt) + 1) * dt
    vb = np.column_stack([speed * np.sin(2 * math.pi * t / 20.0), 0.5 * speed * np.sin(2 * math.pi * t / 33.0),
                          np.zeros(len(t))])  # fmt: skip
    f = -mu * vb + np.array((0.1, -0.2, -9.81)) + rng.normal(0.0, 0.3, (len(t), 3))
    imu = [ImuSample(float(tk), dt, np.zeros(3), fk * dt) for tk, fk in zip(t, f, strict=True)]
    tv = t[::20]  # the estimate at 10 Hz
    return imu, tv, vb[::20] @ C.T, np.tile(q, (len(tv), 1))


def test_the_fit_recovers_the_drag_coefficient():
    imu, tv, v, q = _flight(mu=0.18, speed=4.0)
    fit = cmp.rotor_drag(imu, tv, v, tv, q, 1.0, 59.0)
    assert fit is not None and fit["bins"] >= 110
    assert fit["x"]["mu_per_s"] == pytest.approx(0.18, abs=0.01)
    assert fit["y"]["mu_per_s"] == pytest.approx(0.18, abs=0.02)
    assert fit["x"]["corr"] < -0.9 and fit["x"]["span_mps"] > 7.0
    assert cmp.drag_unsensed(fit) is None
    # a hover: too little speed to fit μ
    imu, tv, v, q = _flight(mu=0.18, speed=0.2)
    fit = cmp.rotor_drag(imu, tv, v, tv, q, 1.0, 59.0)
    assert fit is not None and math.isnan(fit["x"]["mu_per_s"]) and cmp.drag_unsensed(fit) is None


def test_a_velocity_the_specific_force_does_not_follow_is_flagged():
    """The accelerometers of a hovering vehicle against an estimate that drifts to 15 m/s: not the vehicle's."""
    imu, tv, _, q = _flight(mu=0.18, speed=0.0)
    ramp = np.column_stack([np.linspace(0.0, 15.0, len(tv)), np.zeros(len(tv)), np.zeros(len(tv))])
    fit = cmp.rotor_drag(imu, tv, ramp @ dcm_from_quat(q[0]).T, tv, q, 1.0, 59.0)
    assert fit is not None and abs(fit["x"]["mu_per_s"]) < 0.01 and fit["x"]["expected_mps2"] > 1.0
    assert cmp.drag_unsensed(fit) == "x"
    # NaN velocities are left out; too few bins give None
    v = ramp.copy()
    v[::2] = math.nan
    assert cmp.rotor_drag(imu, tv, v, tv, q, 1.0, 59.0) is not None
    assert cmp.rotor_drag(imu, tv, ramp, tv, q, 1.0, 9.0) is None


def test_the_logs_name_their_vehicle_type(shared_dir: Path):
    uav = shared_dir / "data" / "uav"
    hover = read_dataset(uav / "px4_hover_92s" / "hover.ulg")  # vehicle_status.vehicle_type (PX4 v1.16)
    assert hover.meta["rotary_wing"] is True
    ob = hover.onboard
    assert ob is not None and ob.vel_ned is not None and ob.vel_ned_unaided is not None
    # EKF2's unaided horizontal velocity: NaN where compared, kept for the drag check
    assert np.all(np.isnan(ob.vel_ned[:, :2])) and np.nanmax(np.hypot(*ob.vel_ned_unaided[:, :2].T)) > 15.0
    assert read_dataset(uav / "px4_quad_157s").meta["rotary_wing"] is True  # is_rotary_wing (ulog2csv, older PX4)
    ardu = read_dataset(uav / "ardupilot_copter_150s" / "flight.bin")
    assert ardu.meta["rotary_wing"] is True and ardu.meta["firmware"].startswith("APM:Copter V3.4")


def test_yaw_against_the_magnetic_heading():
    """Readings of a reference field (declination 5°) seen from a tilted, yawed body: an estimate with the true
    attitude is on the magnetic heading, one with its yaw 10° high is 10° off it."""
    ref = np.array((18.0, 1.6, 42.0))  # µT NED, 5.1° declination
    t = np.arange(30) * 0.5
    q_true = np.array([quat_from_euler(math.radians(4.0), math.radians(-3.0), math.radians(20.0 + k)) for k in t])
    mag = [MagSample(float(tk), dcm_from_quat(q).T @ ref) for tk, q in zip(t, q_true, strict=True)]
    h = cmp.mag_heading(mag, t, q_true, ref, 0.0, 20.0)
    assert h is not None and h["n"] == 30 and h["rms"] < 1e-9
    q_high = np.array([quat_from_euler(math.radians(4.0), math.radians(-3.0), math.radians(30.0 + k)) for k in t])
    h = cmp.mag_heading(mag, t, q_high, ref, 0.0, 20.0)
    assert h is not None and h["mean"] == pytest.approx(10.0, abs=1e-6) and h["max"] == pytest.approx(10.0, abs=1e-6)
    assert cmp.mag_heading(mag, t, q_true, ref, 0.0, 3.0) is None  # fewer than 10 readings


@pytest.mark.slow
def test_replay_checks_ekf2s_hover_velocity_against_the_accelerometers(tmp_path: Path, capsys):
    """The hover log: EKF2's unaided velocity spans more than 15 m/s in body x and the specific force does not
    follow it: the replay says so, with the figures; ours stays within a hover's speeds. EKF2's yaw departs from
    the magnetometer's own heading (measured 16.2° RMS), ours follows it (3.3°)."""
    out = tmp_path / "hover"
    cfgp = REPO / "configs" / "datasets" / "px4_hover.toml"
    assert main(["replay", "--dataset", str(cfgp), "--out", str(out)]) == 0  # with plots: the heading's dots
    text = capsys.readouterr().out
    rd = json.loads((out / "metrics.json").read_text())["rotor_drag"]
    ob = rd["onboard"]["x"]
    assert ob["span_mps"] > 15.0 and abs(ob["mu_per_s"]) < 0.01 and ob["f_std_mps2"] < 0.1
    assert rd["ours"]["x"]["span_mps"] < 1.0 and rd["ours"]["y"]["span_mps"] < 1.0
    assert "rotor drag: EKF2's body-x velocity spans" in text and "rotor drag μ x / y (1/s), EKF2" in text
    mh = json.loads((out / "metrics.json").read_text())["mag_heading"]
    assert mh["ours"]["rms"] < 5.0 and mh["onboard"]["rms"] > 10.0 and mh["onboard_name"] == "EKF2"
    assert "yaw − magnetic heading (°), EKF2" in text and (out / "attitude.png").stat().st_size > 10_000


@pytest.mark.slow
def test_replay_measures_the_quadrotors_rotor_drag(tmp_path: Path):
    """The GNSS-aided quadrotor: its specific force follows our body velocity at a multirotor's μ. Its second
    outage, the one not below both trivial predictors, opened 5 s after 2.5 s of lost IMU data while the fixes
    were still moving the filter's tilt several times more than they do on the rest of the flight."""
    out = tmp_path / "quad"
    cfgp = REPO / "configs" / "datasets" / "px4_quad.toml"
    assert main(["replay", "--dataset", str(cfgp), "--out", str(out), "--quiet", "--no-plots"]) == 0
    w = [x for x in json.loads((out / "metrics.json").read_text())["outages"]["windows"] if x["scored"]]
    typ = w[0]["before"]["sf_corr_typical_mps2"]
    assert [x["beats_both"] for x in w] == [True, False, True, True]
    assert w[1]["before"]["imu_lost_s"] > 2.0 and w[1]["before"]["sf_corr_mps2"] > 5.0 * typ
    assert all(x["before"]["imu_lost_s"] == 0.0 and x["before"]["sf_corr_mps2"] < 2.0 * typ for x in w[::2] + w[3:])
    rd = json.loads((out / "metrics.json").read_text())["rotor_drag"]
    assert "onboard" not in rd  # no EKF2 output in this log
    for ax in ("x", "y"):
        assert 0.1 < rd["ours"][ax]["mu_per_s"] < 0.3 and rd["ours"][ax]["corr"] < -0.4


@pytest.mark.slow
def test_the_config_says_multirotor_where_the_log_cannot(tmp_path: Path, shared_dir: Path, capsys):
    """A generic CSV holds no vehicle type: `[dataset] rotary_wing = true` turns the rotor-drag check on (the
    quadrotor written as CSV gives the μ of its own log); `false` turns it off for a log that says multirotor; a
    wrong type is a one-line error."""
    from ins_hil.datasets.generic_csv import write_generic_csv

    csv = tmp_path / "flight.csv"
    write_generic_csv(csv, read_dataset(shared_dir / "data" / "uav" / "px4_quad_157s"))
    cfg = tmp_path / "quad.toml"
    cfg.write_text('[dataset]\nname = "q"\npath = "flight.csv"\nrotary_wing = true\n'
                   "[mounting]\ngnss_time_offset_s = -0.11\n")  # fmt: skip
    assert main(["replay", "--dataset", str(cfg), "--out", str(tmp_path / "q"), "--quiet", "--no-plots"]) == 0
    rd = json.loads((tmp_path / "q" / "metrics.json").read_text())["rotor_drag"]
    assert 0.1 < rd["ours"]["x"]["mu_per_s"] < 0.3
    hover = tmp_path / "hover.toml"
    src = (REPO / "configs" / "datasets" / "px4_hover.toml").read_text()
    path = shared_dir / "data" / "uav" / "px4_hover_92s" / "hover.ulg"
    old = 'path = "../../../shared/data/uav/px4_hover_92s/hover.ulg"'
    src = src.replace(old, f'path = "{path}"\nrotary_wing = false')
    hover.write_text(src)
    assert main(["replay", "--dataset", str(hover), "--out", str(tmp_path / "h"), "--quiet", "--no-plots"]) == 0
    assert "rotor_drag" not in json.loads((tmp_path / "h" / "metrics.json").read_text())
    capsys.readouterr()
    hover.write_text(src.replace("rotary_wing = false", 'rotary_wing = "yes"'))
    assert main(["replay", "--dataset", str(hover), "--out", str(tmp_path / "h")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "dataset.rotary_wing = 'yes': wrong type" in err
