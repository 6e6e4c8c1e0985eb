"""Issue 40: the start-up check of the IMU against the configuration — a wrong mounting is named in one line,
a noise preset far below the IMU's measured noise is said and inflated to the measured density."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ins_hil.core import NavConfig, NavCore
from ins_hil.fusion.ekf import FilterConfig
from ins_hil.nav.mechanization import StrapdownState
from ins_hil.types import ImuSample

DEG = math.pi / 180
G = 9.80665


def _core_at_rest(f_b: tuple[float, float, float], gyro_sd: float, accel_sd: float, cfg: NavConfig) -> NavCore:
    """3 s at rest at 200 Hz with the given mean specific force (body, m/s²) and white noise (per-sample σ)."""
    rng = np.random.default_rng(3)
    q = np.array((1.0, 0.0, 0.0, 0.0))
    core = NavCore(StrapdownState(q, np.zeros(3), math.radians(47.0), math.radians(8.0), 400.0), cfg)
    dt = 0.005
    for k in range(1, 601):
        w = rng.normal(0.0, gyro_sd, 3)
        f = np.asarray(f_b) + rng.normal(0.0, accel_sd, 3)
        core.step(ImuSample(k * dt, dt, w * dt, f * dt))
    return core


def test_an_upside_down_imu_is_named_with_its_missing_rotation() -> None:
    """Issue 40's handheld walk: identity mounting on an IMU whose z reads +1 g (upside down)."""
    core = _core_at_rest((0.0, 0.0, +G), 0.001, 0.01, NavConfig())
    assert len(core.sensor_warnings) == 1
    w = core.sensor_warnings[0]
    assert w.startswith("mounting:") and "roll 180°" in w and "\n" not in w


@pytest.mark.parametrize("f_b", [(0.0, 0.0, -G), (G * math.sin(0.2), 0.0, -G * math.cos(0.2))])
def test_a_level_or_parked_on_a_slope_imu_gives_no_mounting_warning(f_b: tuple[float, float, float]) -> None:
    core = _core_at_rest(f_b, 0.001, 0.01, NavConfig())
    assert not [w for w in core.sensor_warnings if w.startswith("mounting")]


def test_an_imu_on_its_side_names_a_roll_of_90() -> None:
    core = _core_at_rest((0.0, -G, 0.0), 0.001, 0.01, NavConfig())
    assert any("roll 90°" in w for w in core.sensor_warnings), core.sensor_warnings


def test_a_tactical_preset_on_a_mems_imu_is_said_and_inflated() -> None:
    """The default FilterConfig is the tactical preset (gyro ARW 0.15 °/√h, no vibration gain); a MEMS IMU at
    rest with 0.5 °/s and 0.05 m/s² per-sample noise at 200 Hz is ≈ 150× / 50× its densities: warned about and the
    filter's white-noise densities raised to the measured ones."""
    cfg = NavConfig()
    core = _core_at_rest((0.0, 0.0, -G), 0.5 * DEG, 0.05, cfg)
    w = [x for x in core.sensor_warnings if x.startswith("noise")]
    assert len(w) == 1 and "\n" not in w[0]
    fc = cfg.filter
    meas_g = 0.5 * DEG * math.sqrt(0.005)
    assert core.kf.qc[6] == pytest.approx(meas_g**2, rel=0.15)  # the measured density, not the preset's
    assert core.kf.qc[3] == pytest.approx((0.05 * math.sqrt(0.005)) ** 2, rel=0.15)
    assert core.kf.qc[6] > 100 * fc.gyro_arw**2


def test_a_preset_that_matches_the_imu_is_left_alone() -> None:
    cfg = NavConfig(filter=FilterConfig(gyro_arw=0.5 * DEG * math.sqrt(0.005), accel_vrw=0.05 * math.sqrt(0.005)))
    core = _core_at_rest((0.0, 0.0, -G), 0.5 * DEG, 0.05, cfg)
    assert core.sensor_warnings == []
    assert core.kf.qc[6] == cfg.filter.gyro_arw**2


def test_the_gateway_says_each_start_up_finding_once() -> None:
    """Live, each finding is a warning (log, status view, MQTT health) and one STATUSTEXT, once."""
    from types import SimpleNamespace

    from ins_hil.runtime.loop import Gateway
    from ins_hil.runtime.metrics import RuntimeMetrics

    core = _core_at_rest((0.0, 0.0, +G), 0.001, 0.01, NavConfig())
    texts: list[tuple[int, str]] = []
    gw = Gateway.__new__(Gateway)
    gw.pipeline = SimpleNamespace(core=core)  # type: ignore[assignment]
    gw.metrics = RuntimeMetrics()
    gw.mav_outputs = [SimpleNamespace(cfg=SimpleNamespace(role="gcs"), statustext=lambda s, t: texts.append((s, t)))]  # type: ignore[list-item]
    gw._core_said = set()
    for _ in range(3):
        gw._core_warnings()
    assert texts == [(4, "IMU check: mounting looks wrong")]
    assert [w for w in gw.metrics.warnings if "roll 180°" in w] == core.sensor_warnings


def test_a_replay_with_a_wrong_mounting_warns_in_its_summary(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """Issue 40's walk replayed upside down: the replay's summary names the missing rotation (and metrics.json
    keeps it), instead of a run with 20 % of fixes rejected and no hint."""
    import json

    from test_datasets_replay import GOOD, _static_csv

    from ins_hil.cli import main

    data = tmp_path / "static.csv"
    _static_csv(data, seconds=20.0)
    cfg = tmp_path / "upside_down.toml"
    cfg.write_text(GOOD + "[mounting]\nimu_to_body_deg = [180.0, 0.0, 0.0]\n")
    out = tmp_path / "out"
    assert main(["replay", str(data), "--dataset", str(cfg), "--out", str(out), "--no-plots", "--quiet"]) == 0
    warns = json.loads((out / "metrics.json").read_text())["warnings"]
    assert any(w.startswith("mounting:") and "roll 180°" in w for w in warns), warns
