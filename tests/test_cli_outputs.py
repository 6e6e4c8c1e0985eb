"""Every command refuses an output path it cannot write before any work, in one line naming the flag and the
path (``ins_hil.commands._outputs``): not after a long run, not once per job of a batch."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import pytest

from ins_hil.cli import main
from ins_hil.commands._outputs import OutputPathError, out_dir, out_file

ROOT = Path(__file__).resolve().parents[1]
HOVER_CFG = ROOT / "configs" / "datasets" / "px4_hover.toml"


def _work(calls: list[str], name: str) -> Any:
    def started(*a: Any, **k: Any) -> Any:
        calls.append(name)
        raise AssertionError(f"the work started: {name}")

    return started


def _one_line(err: str) -> str:
    lines = [x for x in err.splitlines() if x.strip()]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]


@pytest.fixture()
def blocker(tmp_path: Path) -> Path:
    f = tmp_path / "a_file"
    f.write_text("x")
    return f


def test_batch_into_an_existing_file_is_refused_before_any_replay(
    blocker: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """The bug of ``--batch … --out FILE``: every replay ran and failed (NotADirectoryError), then 'File exists'."""
    from ins_hil.evaluation import batch

    calls: list[str] = []
    monkeypatch.setattr(batch, "run_job", _work(calls, "run_job"))
    monkeypatch.setattr(batch, "run_batch", _work(calls, "run_batch"))
    rc = main(["replay", "--batch", str(HOVER_CFG), str(HOVER_CFG), "--seeds", "2", "--workers", "0",
               "--no-plots", "--quiet", "--out", str(blocker)])  # fmt: skip
    line = _one_line(capsys.readouterr().err)
    assert rc == 2 and calls == []
    assert line == f"ins-hil replay: --out {blocker}: cannot write: it exists and is not a folder"
    assert blocker.read_text() == "x"


def test_batch_with_a_job_folder_taken_by_a_file_is_refused_before_any_replay(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from ins_hil.evaluation import batch

    calls: list[str] = []
    monkeypatch.setattr(batch, "run_batch", _work(calls, "run_batch"))
    (tmp_path / "00-px4_hover-seed1").write_text("x")  # the folder of the second job
    rc = main(["replay", "--batch", str(HOVER_CFG), "--seeds", "2", "--workers", "0", "--no-plots", "--quiet",
               "--out", str(tmp_path)])  # fmt: skip
    line = _one_line(capsys.readouterr().err)
    assert rc == 2 and calls == []
    assert "00-px4_hover-seed1: cannot write: it exists and is not a folder" in line


@pytest.mark.parametrize(
    "argv, flag, patch",
    [
        (
            ["replay", "LOG", "--dataset", str(HOVER_CFG), "--no-plots", "--out", "BLOCK/x"],
            "--out",
            ("ins_hil.datasets.report", "replay_to_dir"),
        ),
        (
            ["replay", "LOG", "--dataset", str(HOVER_CFG), "--no-plots", "--out", "TMP/o", "--export", "TMP"],
            "--export",
            ("ins_hil.datasets.report", "replay_to_dir"),
        ),
        (
            ["replay", "static", "--duration", "5", "--no-plots", "--out", "BLOCK"],
            "--out",
            ("ins_hil.commands.replay", "run_scenario"),
        ),
        (["soak", "--duration", "1", "--out", "BLOCK"], "--out", ("ins_hil.soak.suite", "campaign")),
        (
            ["soak", "--duration", "1", "--out", "TMP/s", "--docs", "BLOCK/soak.md"],
            "--docs",
            ("ins_hil.soak.suite", "campaign"),
        ),
        (["bench-drivers", "--out", "TMP"], "--out", ("ins_hil.bench.drivers", "decode_costs")),
        (["bench-fdi", "--out", "BLOCK/fdi.md"], "--out", ("ins_hil.bench.fdi", "book_section")),
        (
            ["reproduce", "--quiet", "--no-plots", "--output", "BLOCK/r.md"],
            "--output",
            ("ins_hil.commands.reproduce", "groups"),
        ),
        (
            ["calibrate", "gyro", "LOGCSV", "--output", "BLOCK/c.toml"],
            "--output",
            ("ins_hil.commands.calibrate", "read_log"),
        ),
        (
            ["calibrate", "gyro", "LOGCSV", "--output", "TMP/c.toml", "--report", "BLOCK"],
            "--report",
            ("ins_hil.commands.calibrate", "read_log"),
        ),
        (["calibrate", "bench", "--docs", "TMP"], "--docs", ("ins_hil.commands.calibrate", "bench")),
        (["fuzz", "--budget", "100", "--doc", "TMP"], "--doc", ("ins_hil.commands.fuzz", "run_target")),
        (
            ["fuzz", "--budget", "100", "--no-doc", "--state", "BLOCK/s.json"],
            "--state",
            ("ins_hil.commands.fuzz", "run_target"),
        ),
        (["config", "--docs", "TMP"], "--docs", ("ins_hil.config_schema", "write_docs")),
        (["demo", "platform-ins", "--out", "BLOCK"], "--out", ("ins_hil.platform_ins.testbed", "simulate")),
        (["run", "--duration", "1", "--json", "TMP"], "--json", ("ins_hil.config", "load_outputs")),
        (["run", "--duration", "1", "--record", "BLOCK/r.ihlog"], "--record", ("ins_hil.config", "load_outputs")),
    ],
    ids=lambda v: " ".join(v) if isinstance(v, list) else None,
)
def test_an_unwritable_output_is_one_line_before_any_work(
    argv: list[str], flag: str, patch: tuple[str, str], tmp_path: Path, blocker: Path,
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
) -> None:  # fmt: skip
    import importlib

    calls: list[str] = []
    monkeypatch.setattr(importlib.import_module(patch[0]), patch[1], _work(calls, patch[1]))
    log = tmp_path / "log.ulg"
    log.write_bytes(b"")
    (tmp_path / "log.csv").write_text("t,dt\n")
    sub = {"BLOCK": str(blocker), "TMP": str(tmp_path), "LOGCSV": str(tmp_path / "log.csv"), "LOG": str(log)}
    args = [next((a.replace(k, v, 1) for k, v in sub.items() if a.startswith(k)), a) for a in argv]
    rc = main(args)
    line = _one_line(capsys.readouterr().err)
    assert rc == 2 and calls == [], line
    assert line.startswith(f"ins-hil {argv[0]}: {flag} ") and ": cannot write: " in line, line


def test_out_dir_and_out_file_accept_what_can_be_written_and_create_nothing(tmp_path: Path) -> None:
    assert out_dir(tmp_path / "a" / "b") == tmp_path / "a" / "b"
    assert out_file(tmp_path / "a" / "b" / "c.md") == tmp_path / "a" / "b" / "c.md"
    assert out_dir(tmp_path) == tmp_path
    (tmp_path / "f").write_text("x")
    assert out_file(tmp_path / "f") == tmp_path / "f"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f"]
    with pytest.raises(OutputPathError, match="is a file, not a folder"):
        out_file(tmp_path / "f" / "g" / "h.md", "--x")
    with pytest.raises(OutputPathError, match="it is a folder, not a file"):
        out_file(tmp_path, "--x")


def test_a_folder_without_write_access_is_refused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """(os.access says no: as root a chmod 0500 folder is writable, so the refusal is simulated.)"""
    from ins_hil.commands import _outputs

    monkeypatch.setattr(_outputs.os, "access", lambda p, mode: Path(p) != tmp_path)
    with pytest.raises(OutputPathError, match=f"cannot write: {tmp_path} is not writable"):
        out_dir(tmp_path / "out", "--out")
    with pytest.raises(OutputPathError, match="the folder is not writable"):
        out_dir(tmp_path, "--out")


def test_a_folder_the_file_system_refuses_is_one_line_and_leaves_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Permission bits do not tell everything (a read-only or virtual file system, root): --out /sys/foo passed
    the check and failed after the replay, as 'the replay failed (PermissionError …)', exit 1."""
    import errno

    real_mkdir = Path.mkdir

    def mkdir(self: Path, *a: Any, **k: Any) -> None:
        if self.name == "deep":
            raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(self))
        real_mkdir(self, *a, **k)

    monkeypatch.setattr(Path, "mkdir", mkdir)
    with pytest.raises(OutputPathError, match=f"--out {tmp_path}/a/deep/out: cannot write: Read-only file system"):
        out_dir(tmp_path / "a" / "deep" / "out")
    with pytest.raises(OutputPathError, match="cannot write: Read-only file system"):
        out_file(tmp_path / "a" / "deep" / "r.md")
    assert list(tmp_path.iterdir()) == []  # the folder "a" made on the way was removed again


def test_the_report_commands_write_the_checkouts_docs_by_default_from_any_folder() -> None:
    """bench-drivers, bench-fdi, calibrate bench and reproduce default to this checkout's docs/ pages (as bench-core
    and fuzz do), not to a docs/ folder under wherever they are run."""
    import argparse

    from ins_hil.commands import bench_drivers, bench_fdi, calibrate, reproduce
    from ins_hil.commands._outputs import DOCS

    repo_docs = Path(__file__).resolve().parents[1] / "docs"
    assert DOCS == repo_docs
    for mod, dest, page in ((bench_drivers, "out", "drivers.md"), (bench_fdi, "out", "fdi.md"),
                            (reproduce, "output", "reproduction.md")):  # fmt: skip
        p = argparse.ArgumentParser()
        mod.add_arguments(p)
        assert Path(getattr(p.parse_args([]), dest)) == repo_docs / page, mod.__name__
        assert (repo_docs / page).is_file()
    p = argparse.ArgumentParser()
    calibrate.add_arguments(p)
    docs = [a.default for a in p._actions if a.dest == "docs"]
    assert docs == [repo_docs / "calibration.md"]
