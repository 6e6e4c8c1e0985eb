"""``ins-hil replay --export``: the trajectory CSV of a gateway log's pipeline replay (bit for bit the states the
live pipeline published) and of a dataset replay."""

from __future__ import annotations

import copy
import math
import tomllib
from pathlib import Path

import numpy as np

from ins_hil.cli import main
from ins_hil.config import default_path, from_dict
from ins_hil.datasets import export
from ins_hil.runtime.pipeline import Pipeline
from ins_hil.runtime.recorder import Recorder
from ins_hil.sim.devices import send_order
from ins_hil.types import ImuSample, NavState


def _live_run(log: Path, seconds: float) -> list[NavState]:
    """The default config's simulated flight through a pipeline as the live loop drives it, every input recorded
    (the gateway's header: its config and pipeline table); the states the pipeline published."""
    d = tomllib.loads(default_path().read_text())
    d = copy.deepcopy(d)
    d.setdefault("sim", {})["enabled"] = True
    cfg = from_dict(d, "live")
    pipe = Pipeline(cfg.pipeline)
    rec = Recorder(log, header={"config": cfg.to_dict(), "pipeline": cfg.to_dict()["pipeline"]})
    states: list[NavState] = []
    for s in send_order(cfg.sim, seconds):
        rec.write(s)
        if isinstance(s, ImuSample):
            st = pipe.imu(s)
            if st is not None:
                states.append(st)
        else:
            pipe.aid(s)
        pipe.work()  # a live loop with time to spare runs a segment in each gap
    rec.close()
    return states


def test_replay_of_a_gateway_log_exports_the_live_states_bit_for_bit(tmp_path: Path, capsys):
    log = tmp_path / "flight.ihlog"
    live = _live_run(log, 12.0)
    assert len(live) > 1000 and any(s.aligned for s in live)
    csv = tmp_path / "traj.csv"
    assert main(["replay", str(log), "--export", str(csv), "--out", str(tmp_path / "out"), "--quiet"]) == 0
    assert f"trajectory: {csv} ({len(live)} states)" in capsys.readouterr().out
    got = export.read_csv(csv)
    want = export.rows_from_states(live)
    assert got.shape == want.shape == (len(live), len(export.COLUMNS))
    assert np.array_equal(got, want)  # every value, every state: the same bits
    # and the columns are what they say: degrees, metres, m/s, 1-σ
    st = live[-1]
    assert got[-1, 0] == st.t and got[-1, 1] == math.degrees(st.lat) and got[-1, 3] == st.h
    assert np.all(got[:, 10:] >= 0.0)


def test_dataset_replay_exports_its_trajectory():
    """A dataset replay's export: the GNSS-present run's states at every navigating IMU epoch, with their σ."""
    from test_datasets_boundary import _cfg, _ds, _rest

    from ins_hil.datasets import report

    _, runs = report.replay(_ds(_rest()), _cfg())
    r = runs["gnss"]
    rows = export.rows_from_run(r)
    assert rows.shape == (len(r.t), len(export.COLUMNS)) and len(r.t) > 1000
    assert np.array_equal(rows[:, 0], r.t)
    assert np.allclose(rows[:, 1], 45.0, atol=1e-5) and np.allclose(rows[:, 2], 7.0, atol=1e-5)
    assert np.all(np.abs(rows[:, 4:7]) < 0.05)  # at rest
    assert np.allclose(rows[:, 9], 0.0, atol=3.0)  # heading north from the magnetometer
    assert np.all(rows[:, 10:] > 0.0)
