"""``ins-hil replay … --core c``: a dataset config replayed on the C core through the same offline loop
(``ins_hil.datasets.run.replay``: the Pipeline with ``make_core("c", None, nav)``, the C core aligned by the
Python core's alignment and handed over) gives the Python core's figures; a config the C core lacks a setting
of is refused in one line naming it."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from ins_hil.commands import replay as cmd
from ins_hil.cref import CNavCore
from ins_hil.datasets import config, report
from ins_hil.evaluation import batch
from ins_hil.runtime.pipeline import make_core

REPO = Path(__file__).resolve().parent.parent
CONFIGS = REPO / "configs" / "datasets"
#: what differs by design: the run's speed; the GNSS velocity innovation whiteness (the C core keeps no
#: innovation log: None on C)
SKIP = {"realtime_factor", "vel_innovation", "core"}


def _compare(a: Any, b: Any, path: str, out: list[str], n: list[int]) -> None:
    if isinstance(a, dict):
        assert isinstance(b, dict), path
        assert set(a) - SKIP == set(b) - SKIP, path
        for k in a:
            if k not in SKIP:
                _compare(a[k], b[k], f"{path}/{k}", out, n)
    elif isinstance(a, (list, tuple)):
        assert isinstance(b, (list, tuple)) and len(a) == len(b), path
        for i, (u, v) in enumerate(zip(a, b)):
            _compare(u, v, f"{path}[{i}]", out, n)
    elif isinstance(a, float) and isinstance(b, float):
        n[0] += 1
        if math.isnan(a) or math.isnan(b):
            if not (math.isnan(a) and math.isnan(b)):
                out.append(f"{path}: {a} vs {b}")
        elif abs(a - b) > 1e-6 * max(abs(a), 1e-9):
            out.append(f"{path}: {a} vs {b}")
    elif a != b:
        out.append(f"{path}: {a!r} vs {b!r}")


@pytest.mark.slow
@pytest.mark.parametrize("name", ["ardupilot_copter", "px4_hover", "px4_quad", "drive0708"])
def test_config_on_c_gives_the_python_figures(name: str) -> None:
    """Every figure of ``ins-hil replay`` (GNSS present, the outage protocol where the config has one) within
    1e-6 relative: px4_hover's hold / magnetometer and px4_quad's outage NEES and specific-force corrections
    included (they differed by 1.6e-3 and 0.56 % while the C core published its state after the time update);
    drive0708 on the 21-state C filter (248 figures)."""
    cfg = config.load(CONFIGS / f"{name}.toml")
    assert cfg.path is not None
    ds = report.load(cfg.path, cfg)
    m_py, runs_py = report.replay(ds, cfg)
    m_c, runs_c = report.replay(ds, cfg, core="c")
    diffs: list[str] = []
    n = [0]
    _compare(report.jsonable(m_py), report.jsonable(m_c), "", diffs, n)
    assert not diffs, diffs[:10]
    assert n[0] > 50  # figures compared (errors vs the fixes, vs the onboard EKF, gate counts, …)
    assert set(runs_py) == set(runs_c)
    for label, r_py in runs_py.items():
        r_c = runs_c[label]
        assert len(r_c.t) == len(r_py.t) > 1000
        assert r_c.stats == r_py.stats and sum(v["accepted"] for v in r_c.stats.values()) > 100
        assert float(np.abs(r_c.ned - r_py.ned).max()) < 1e-9 * max(1.0, float(np.abs(r_py.ned).max()))
        assert float(np.abs(r_c.q_nb - r_py.q_nb).max()) < 1e-9


def test_make_core_c_without_an_initial_state_aligns_through_the_python_core() -> None:
    cfg = config.load(CONFIGS / "ardupilot_copter.toml")
    core = make_core("c", None, cfg.nav_config())
    assert isinstance(core, CNavCore)
    assert core.phase != "nav" and core.align_status() != ""
    assert core.stats == {} or all(v.accepted == 0 for v in core.stats.values())


def test_a_config_the_c_core_lacks_a_setting_of_is_refused_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    text = (CONFIGS / "drive0708.toml").read_text()
    text = text.replace('path = "../../../', f'path = "{(CONFIGS / "../../..").resolve()}/').replace(
        "scale_factors = true", "scale_factors = true\nwind_states = true"
    )
    assert "wind_states = true" in text
    (tmp_path / "wind.toml").write_text(text)
    cfg = config.load(tmp_path / "wind.toml")
    with pytest.raises(RuntimeError, match=r"^core 'c': .*not supported by the C core: filter\.wind_states$"):
        make_core("c", None, cfg.nav_config())
    p = argparse.ArgumentParser()
    cmd.add_arguments(p)
    args = p.parse_args(["--dataset", str(tmp_path / "wind.toml"), "--core", "c", "--out", str(tmp_path / "x")])
    assert cmd.run(args) == 2
    err = capsys.readouterr().err
    assert "core 'c'" in err and "filter.wind_states" in err and err.count("\n") == 1


def test_every_shipped_dataset_config_builds_on_c() -> None:
    """No shipped dataset config is refused by the C core (drive0708's scale factors included)."""
    for path in sorted(CONFIGS.glob("*.toml")):
        core = make_core("c", None, config.load(path).nav_config())
        assert isinstance(core, CNavCore), path.name


@pytest.mark.slow
def test_batch_jobs_carry_the_core(tmp_path: Path) -> None:
    js = batch.jobs([(None, str(CONFIGS / "ardupilot_copter.toml"))], 2, tmp_path, False, core="c")
    assert [j.core for j in js] == ["c", "c"]
    assert batch.jobs([(None, str(CONFIGS / "ardupilot_copter.toml"))], 1, tmp_path, False)[0].core == "python"
    row = batch.run_job(js[0])
    assert row.get("error") is None and row["core"] == "c"
    m = json.loads((Path(js[0].out) / "metrics.json").read_text())
    assert m["core"] == "c" and m["samples"]["gnss"] > 500


def test_the_c_core_records_the_imu_gaps_it_coasts_across() -> None:
    """With per-sample steps the C core coasts across lost IMU data; its record (``imu_lost`` and a DROPOUT
    event) is NavCore's, which the replay's figures take (px4_quad: 6 gaps, 5.64 s)."""
    from ins_hil.core import NavCore
    from ins_hil.nav.mechanization import StrapdownState
    from ins_hil.types import FaultMode, ImuSample

    nav = config.from_dict({"dataset": {"name": "t"}, "nav": {"alignment": {"mode": "given"}}}).nav_config()
    init = StrapdownState(np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(3), 0.8, 0.5, 100.0, 0.0)
    dv = np.array([0.0, 0.0, -9.80665 * 0.01])
    cores = [CNavCore(init.copy(), nav, fixed_step=False), NavCore(init.copy(), nav)]
    for core in cores:
        t = 0.0
        for k in range(200):
            t += 0.5 if k == 120 else 0.01  # 0.49 s lost before sample 120
            core.step(ImuSample(t, 0.01, np.zeros(3), dv))
    c, py = cores
    assert c.imu_lost[0] == py.imu_lost[0] == 1
    assert c.imu_lost[1] == pytest.approx(py.imu_lost[1], rel=1e-12) and c.imu_lost[1] == pytest.approx(0.49)
    ev = [e for e in c.drain_events() if e.sensor == "imu" and e.mode == FaultMode.DROPOUT]
    assert len(ev) == 1 and ev[0].magnitude == pytest.approx(0.49)
