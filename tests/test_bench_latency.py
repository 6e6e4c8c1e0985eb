"""The latency report: its prose is package data (``ins_hil/bench/latency_report.md``) filled from the metrics."""

from __future__ import annotations

import re
from types import SimpleNamespace
from typing import Any

from ins_hil.bench import latency


def _gateway(late: int = 3) -> Any:
    h = {"count": 1000, "p50_us": 51.2, "p99_us": 120.7, "p999_us": 800.1, "max_us": 2500.0}
    snap = {
        "latency": {k: h for k in ("arrival_to_state", "state_to_sent", "arrival_to_sent", "core_step")},
        "sources": {"imu0": {"received": 29990, "dropped": {"seq_gap": 2}}},
        "imu_epochs": 29990,
        "late": late,
        "late_threshold_ms": 5.0,
        "queue_depth_max": 7,
        "outputs": {"gcs": {"ATTITUDE": 1500}},
    }
    return SimpleNamespace(metrics=SimpleNamespace(snapshot=lambda: snap, late=late))


def test_template_is_package_data_with_every_field_filled(monkeypatch: Any) -> None:
    text = latency.template()
    assert text.startswith("# Runtime: the real-time gateway\n") and text.endswith("\n")
    fields = set(re.findall(r"\{([a-z_]+)", text))
    assert fields == {"machine", "commit", "duration", "wall", "epochs", "received", "rate", "late", "late_ms"} | {
        "drops",
        "qmax",
        "rows",
        "sent",
        "c_section",
    }
    monkeypatch.setattr(latency, "summary", lambda: "test machine")
    out = latency.report(_gateway(), 30.4, 30.0, _gateway(late=4), 0.25)
    assert "{" not in out.replace("{}", "")
    assert "Machine: test machine; host steal time during the runs 0.25 s" in out
    assert "30.4 s wall, 29990 IMU samples received (987 Hz), 29990 IMU\nepochs processed, 3 late (> 5 ms)" in out
    assert "drops: seq_gap 2, largest FIFO depth 7,\n1500 ATTITUDE messages sent." in out
    assert out.count("| arrival → state ready | 1000 | 51 | 121 | 800 | 2500 |") == 2  # Python and C tables
    assert "(`--core c`, `ins_hil.cref.CNavCore`, covariance propagated every step), late 4:" in out
    assert "`ins_hil/bench/latency_report.md`" in out
    plain = latency.report(_gateway(), 30.4, 30.0)
    assert "--core c" not in plain and plain.count("| arrival → state ready |") == 1
