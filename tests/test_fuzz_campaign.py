"""The campaign runner (``ins-hil fuzz``): counts by input budget, a progress line per chunk, a state file to resume
from, partial counts when interrupted, blow-ups and hangs counted instead of ending the campaign."""

from __future__ import annotations

import json
import random
import time
from pathlib import Path
from typing import Any

import pytest

from ins_hil import fuzz
from ins_hil.cli import main
from ins_hil.fuzz import Target, TargetResult, run_target


def _target(name: str, step_of: Any, goal: int = 40) -> Target:
    return Target(name, f"test {name}", lambda rng: step_of(), decoder=False, goal=goal)


def test_a_hang_and_a_blow_up_are_counted_and_the_target_goes_on() -> None:
    calls = [0]

    def make() -> Any:
        def step() -> tuple[int, list[Any]]:
            calls[0] += 1
            if calls[0] == 3:
                while True:  # a parser that never advances
                    pass
            if calls[0] == 5:
                raise MemoryError()
            return 1, []

        return step

    r = run_target(_target("t", make), None, inputs=10, step_cpu_limit=0.2)
    assert r.inputs == 10 and r.hangs == 1 and r.blowups == 1 and r.escaped == 0
    assert r.failures() == 2 and set(r.findings) == {"hang", "blow-up (MemoryError)"}


def test_results_add_and_survive_json() -> None:
    a = TargetResult("x", "w", inputs=5, escaped=1, seconds=2.0, goal=9)
    a.note("escaped KeyError", "e1")
    b = TargetResult("x", "w", inputs=7, hangs=1, seconds=1.0)
    b.note("escaped KeyError", "e2")
    b.note("hang", "h")
    a.add(b)
    assert (a.inputs, a.escaped, a.hangs, a.seconds) == (12, 1, 1, 3.0)
    assert a.findings["escaped KeyError"].count == 2 and a.findings["escaped KeyError"].example == "e1"
    c = TargetResult.from_dict(json.loads(json.dumps(a.to_dict())))
    assert c.to_dict() == a.to_dict()


def test_inputs_budget_state_and_resume(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    state = tmp_path / "state.json"
    args = ["fuzz", "--targets", "dbc", "--no-doc", "--state", str(state), "--progress", "0.05"]
    assert main([*args, "--inputs", "30"]) == 0
    err = capsys.readouterr().err
    assert "[fuzz] dbc" in err and "inputs in" in err  # a progress line per chunk
    st = json.loads(state.read_text())
    first = st["results"]["dbc"]["inputs"]
    assert first >= 30
    assert main([*args, "--inputs", str(first + 50), "--resume"]) == 0
    assert "resuming from" in capsys.readouterr().err
    st = json.loads(state.read_text())
    assert st["results"]["dbc"]["inputs"] >= first + 50 and st["chunks"]["dbc"] >= 2
    assert main(["fuzz", "--resume", "--targets", "dbc"]) == 2  # --resume needs --state


def test_an_interrupted_campaign_reports_what_ran(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                  capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    from ins_hil.fuzz import targets

    calls = [0]

    def make() -> Any:
        def step() -> tuple[int, list[Any]]:
            calls[0] += 1
            if calls[0] == 60:
                raise KeyboardInterrupt
            time.sleep(0.002)
            return 1, []

        return step

    monkeypatch.setattr(targets, "TARGETS", [_target("slow", make, goal=1000)])
    doc, state = tmp_path / "r.md", tmp_path / "s.json"
    rc = main(["fuzz", "--to-goal", "--progress", "0.01", "--doc", str(doc), "--state", str(state)])
    assert rc == 130
    assert "interrupted" in capsys.readouterr().err
    done = json.loads(state.read_text())["results"]["slow"]["inputs"]
    assert 0 < done < 60  # the chunks that finished, the running one lost
    assert f"| slow | {done:,} | 1,000 |" in doc.read_text()


def test_the_campaign_caps_its_memory_and_gives_it_back(monkeypatch: pytest.MonkeyPatch) -> None:
    import resource

    from ins_hil.commands import fuzz as cmd

    seen: list[tuple[int, int]] = []
    real = cmd.run_target

    def spy(*a: Any, **k: Any) -> TargetResult:
        seen.append(resource.getrlimit(resource.RLIMIT_AS))
        return real(*a, **k)

    monkeypatch.setattr(cmd, "run_target", spy)
    before = resource.getrlimit(resource.RLIMIT_AS)
    assert main(["fuzz", "--targets", "dbc", "--inputs", "5", "--no-doc", "--memory-mib", "1536"]) == 0
    assert seen and seen[0][0] == 1536 * 1024 * 1024
    assert resource.getrlimit(resource.RLIMIT_AS) == before
    assert random.Random(1).random() == random.Random(1).random() and fuzz.STEP_CPU_LIMIT > 0


def test_an_import_that_fails_discards_the_chunk_and_is_retried(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from ins_hil.commands import fuzz as cmd
    from ins_hil.fuzz import targets

    chunks = [0]

    def make() -> Any:
        chunks[0] += 1
        broken = chunks[0] == 1

        def step() -> tuple[int, list[Any]]:
            if broken:
                raise ModuleNotFoundError("No module named 'pyulog'")
            return 1, []

        return step

    monkeypatch.setattr(targets, "TARGETS", [_target("env", make, goal=20)])
    monkeypatch.setattr(cmd, "FAULT_WAIT", 0.0)
    assert main(["fuzz", "--to-goal", "--no-doc"]) == 0  # not an escaped exception of the code under test
    err = capsys.readouterr().err
    assert "environment: env: ModuleNotFoundError" in err and "retried" in err
    with pytest.raises(fuzz.EnvironmentFault):
        run_target(_target("env2", lambda: (_ for _ in ()).throw(ImportError("x"))), None, inputs=3)


def test_jobs_run_chunks_side_by_side_into_one_resumable_state(tmp_path: Path) -> None:
    """--jobs 2: two worker processes, their counts added into the one state file (the format a single process
    writes), resumable by either mode; each target ends on its input budget exactly."""
    state = tmp_path / "state.json"
    args = ["fuzz", "--targets", "dbc", "serial_frame", "--no-doc", "--state", str(state), "--progress", "0.3"]
    assert main([*args, "--inputs", "300", "--jobs", "2"]) == 0
    d = json.loads(state.read_text())
    assert {k: v["inputs"] for k, v in d["results"].items()} == {"dbc": 300, "serial_frame": 300}
    assert all(n >= 1 for n in d["chunks"].values())
    assert main([*args, "--inputs", "500", "--resume"]) == 0  # one process goes on from the workers' counts
    assert main([*args, "--inputs", "900", "--resume", "--jobs", "2"]) == 0
    d = json.loads(state.read_text())
    assert {k: v["inputs"] for k, v in d["results"].items()} == {"dbc": 900, "serial_frame": 900}
    assert all(r["cpu_seconds"] > 0 and r["escaped"] == 0 for r in d["results"].values())
    assert main([*args, "--inputs", "10", "--jobs", "0"]) == 2
