"""The `ins-hil` entry point."""

from __future__ import annotations

import importlib
import subprocess
import sys
from pathlib import Path

import pytest

from ins_hil.registry import Registry


def test_help_lists_commands() -> None:
    out = subprocess.run([sys.executable, "-m", "ins_hil", "--help"], capture_output=True, text=True, check=True)
    assert "demo" in out.stdout and "run" in out.stdout


def test_demo_short_run_prints_errors() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "ins_hil", "demo", "--duration", "20", "--rate", "100"],
        capture_output=True,
        text=True,
        check=True,
    )
    assert "worst: attitude" in out.stdout
    worst = out.stdout.strip().splitlines()[-1]
    pos = float(worst.split("position")[1].split("m")[0])
    assert pos < 0.01


def test_bad_argument_is_a_clear_error() -> None:
    out = subprocess.run([sys.executable, "-m", "ins_hil", "demo", "--duration", "-1"], capture_output=True, text=True)
    assert out.returncode != 0 and "positive" in out.stderr


@pytest.mark.slow  # two 1 s bench runs, ~20 s with the start-up
def test_runtime_bench_writes_nothing_unless_asked(tmp_path: Path) -> None:
    """`python -m ins_hil.bench.latency` prints the figures; only --out (or --docs) writes a report."""
    docs = Path(__file__).resolve().parent.parent / "docs"
    tracked = {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in (docs / "runtime.md", docs / "runtime_latency.png")}
    cmd = [sys.executable, "-m", "ins_hil.bench.latency", "--duration", "1", "--no-c"]
    r = subprocess.run(cmd, capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "| arrival → state ready |" in r.stdout
    assert {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in tracked} == tracked
    assert list(tmp_path.iterdir()) == []
    out = tmp_path / "report" / "runtime.md"
    r = subprocess.run([*cmd, "--out", str(out)], capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert r.returncode == 0, r.stderr
    assert out.read_text().startswith("# Runtime") and (out.parent / "runtime_latency.png").stat().st_size > 0
    assert {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in tracked} == tracked


_MODULES_AT_EXIT = (
    "import atexit, runpy, sys\n"
    "atexit.register(lambda: print('MODULES', *sorted(sys.modules), file=sys.stderr))\n"
    "sys.argv[0] = 'ins-hil'\n"
    "runpy.run_module('ins_hil', run_name='__main__', alter_sys=True)\n"
)


def _imported(*argv: str) -> tuple[subprocess.CompletedProcess[str], set[str]]:
    """Run ``python -m ins_hil ARGV``; the result and every module loaded when it exits (``sys.modules``)."""
    r = subprocess.run([sys.executable, "-c", _MODULES_AT_EXIT, *argv], capture_output=True, text=True)
    last = r.stderr.strip().splitlines()[-1] if r.stderr.strip() else ""
    assert last.startswith("MODULES "), r.stderr[-2000:]
    return r, set(last.split()[1:])


#: what a command's module may pull in: none of it may load for the command list
HEAVY = ("numpy", "scipy", "pymavlink", "rich", "ins_hil.core", "ins_hil.runtime", "ins_hil.nav", "ins_hil.fdi")


def test_help_lists_every_command_without_importing_any() -> None:
    """`ins-hil --help` reads the commands' NAME and HELP from their source: no command module, nothing
    of numpy, scipy, pymavlink or the core is imported (that made --help take seconds)."""
    from ins_hil.cli import command_table

    r, mods = _imported("--help")
    assert r.returncode == 0, r.stderr[-2000:]
    assert "ins_hil.cli" in mods  # the import log is read right
    assert not {m for m in mods if m.startswith("ins_hil.commands.")}, sorted(mods)
    assert not {m for m in mods if m.split(".")[0] in HEAVY or m.startswith(HEAVY)}, sorted(mods)
    table = command_table()
    assert len(table) >= 10 and {"run", "replay", "demo", "config"} <= set(table)
    flat = " ".join(r.stdout.split())
    for c in table.values():  # every command with its one-line help, as the module states it
        mod = importlib.import_module(c.module)
        assert (c.name, c.help) == (mod.NAME, mod.HELP)
        assert f"{c.name} {' '.join(c.help.replace('%%', '%').split())}" in flat, (c.name, r.stdout)


@pytest.mark.parametrize("command", ["run", "config"])
def test_a_commands_help_imports_that_command_only(command: str) -> None:
    r, mods = _imported(command, "--help")
    assert r.returncode == 0, r.stderr[-2000:]
    assert f"usage: ins-hil {command}" in r.stdout and "--debug" in r.stdout
    assert {m for m in mods if m.startswith("ins_hil.commands.")} == {f"ins_hil.commands.{command}"}
    assert "scipy" not in mods and "ins_hil.core" not in mods


def test_a_new_command_file_is_listed_without_being_imported(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A command added as a module plus one registry line (another helper's, a plugin) is listed by name; its
    heavy imports wait; a module in the folder that is not registered is no command."""
    from ins_hil import cli, commands

    (tmp_path / "zz_new.py").write_text(
        '"""`ins-hil zz-new`."""\nimport argparse\n\nimport no_such_heavy_module\n\nNAME = "zz-new"\n'
        'HELP = (\n    "a new command, "\n    "in two pieces"\n)\n\n\n'
        "def add_arguments(p: argparse.ArgumentParser) -> None:\n"
        '    p.add_argument("--x")\n\n\ndef run(args: argparse.Namespace) -> int:\n    return 0\n'
    )
    (tmp_path / "zz_helper.py").write_text('"""Not a command: not registered."""\n\ndef run() -> None: ...\n')
    monkeypatch.setattr(commands, "__path__", [str(tmp_path)])
    reg = Registry("command", {"zz-new": ("ins_hil.commands.zz_new", "run")})
    monkeypatch.setattr(commands, "COMMANDS", reg)
    table = cli.command_table()
    assert table == {"zz-new": cli.Command("zz-new", "a new command, in two pieces", "ins_hil.commands.zz_new")}
    assert "ins_hil.commands.zz_new" not in sys.modules
    assert "a new command, in two pieces" in cli.build_parser().format_help()
    assert "ins_hil.commands.zz_new" not in sys.modules


def test_every_command_module_is_registered_under_its_name() -> None:
    """One registry line per command module, under the module's NAME (a module left out is no command)."""
    import pkgutil

    from ins_hil import commands

    files = {
        f"ins_hil.commands.{i.name}" for i in pkgutil.iter_modules(commands.__path__) if not i.name.startswith("_")
    }
    where = {n: commands.COMMANDS.where(n) for n in commands.COMMANDS}
    assert {w[0] for w in where.values() if w} == files
    for name, w in where.items():
        assert w is not None and importlib.import_module(w[0]).NAME == name
