"""A dataset config where a gateway config is expected (or the reverse) is one line that says which kind it is
and where it goes, before any work."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from ins_hil.cli import main

ROOT = Path(__file__).resolve().parents[1]
DATASET = str(ROOT / "configs" / "datasets" / "px4_hover.toml")
GATEWAY = str(ROOT / "configs" / "default.toml")
LOG = "/nonexistent/hover.ulg"  # never read: the config is refused first


def _one_line(capsys: pytest.CaptureFixture[str]) -> str:
    err = [x for x in capsys.readouterr().err.splitlines() if x.strip()]
    assert len(err) == 1, err
    return err[0]


def test_config_check_of_a_dataset_config_says_where_it_goes(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["config", "--check", DATASET]) == 2
    line = _one_line(capsys)
    assert "unknown section 'dataset'" in line and line.endswith(
        "(a dataset config: ins-hil replay LOG --dataset FILE)"
    )


def test_run_with_a_dataset_config_says_where_it_goes(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["run", "--config", DATASET, "--duration", "1", "--no-status", "--no-mqtt"]) == 2
    assert _one_line(capsys).endswith("(a dataset config: ins-hil replay LOG --dataset FILE)")


@pytest.mark.parametrize(
    "argv, says",
    [
        ([LOG, "--dataset", GATEWAY], f"--dataset {GATEWAY}: a gateway config: ins-hil run --config FILE"),
        (["sim", "--config", DATASET], f"--config {DATASET}: a dataset config: ins-hil replay LOG --dataset FILE"),
    ],
)
def test_replay_with_the_other_kind_of_config_is_refused_before_any_work(
    argv: list[str], says: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from ins_hil.commands import replay
    from ins_hil.datasets import report

    calls: list[str] = []

    def work(*a: Any, **k: Any) -> Any:
        calls.append("work")
        raise AssertionError("the work started")

    monkeypatch.setattr(report, "replay_to_dir", work)
    monkeypatch.setattr(replay, "_runtime_replay", work)
    rc = main(["replay", *argv, "--out", str(tmp_path / "o")])
    line = _one_line(capsys)
    assert rc == 2 and calls == [] and line.startswith(f"ins-hil replay: {says}"), line
