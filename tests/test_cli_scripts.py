"""The diagnostics scripts refuse bad arguments with argparse's error (exit status 2) before any work, instead
of a traceback after it (scripts/diagnostics/*.py)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _script(name: str) -> ModuleType:
    spec = importlib.util.spec_from_file_location(f"diag_{name}", ROOT / "scripts" / "diagnostics" / f"{name}.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.parametrize(
    "argv, says",
    [
        (["compare", "TMP/none.npz", "TMP/none2.npz"], "TMP/none.npz: no such file"),
        (["compare", "TMP/none.npz"], "compare takes 2 file(s), got 1"),
        (["dump", "TMP/a_file/x.npz", "--seconds", "1"], "dump TMP/a_file/x.npz: cannot write"),
        (["dump", "TMP/x.npz", "--seconds", "-5"], "--seconds -5: must be a positive number of seconds"),
    ],
)
def test_drive_states_refuses_bad_arguments_before_the_replay(
    argv: list[str], says: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    mod = _script("drive_states")
    calls: list[str] = []

    def work(*a: Any, **k: Any) -> Any:
        calls.append("work")
        raise AssertionError("the work started")

    monkeypatch.setattr(mod, "dump", work)
    monkeypatch.setattr(mod, "compare", work)
    (tmp_path / "a_file").write_text("x")
    with pytest.raises(SystemExit) as e:
        mod.main([a.replace("TMP", str(tmp_path)) for a in argv])
    err = capsys.readouterr().err
    assert e.value.code == 2 and calls == [] and says.replace("TMP", str(tmp_path)) in err.splitlines()[-1], err


@pytest.mark.parametrize("argv", [["--seconds", "-1"], ["--repeat", "0"], ["--seconds", "nan"]])
def test_rollback_cost_refuses_bad_arguments(
    argv: list[str], monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--seconds -1`` ran and printed figures of nothing; ``--repeat 0`` an IndexError."""
    mod = _script("rollback_cost")
    monkeypatch.setattr(mod, "run", lambda *a, **k: pytest.fail("the work started"))
    monkeypatch.setattr(sys, "argv", ["rollback_cost.py", *argv])
    with pytest.raises(SystemExit) as e:
        mod.main()
    assert e.value.code == 2 and "--seconds must be a positive number" in capsys.readouterr().err
