"""The import layers (pyproject.toml [tool.importlinter], ARCHITECTURE.md "Layers") hold on the tree, and the
check fails on a back-import: scripts/lint-imports run on this checkout and on a copy with one import added."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _venv() -> Path:
    v = Path(sys.prefix)
    if not (v / "bin" / "lint-imports").exists():
        pytest.fail(f"lint-imports is not installed in {v} (pip install -e '.[dev]')")
    return v


def _lint(root: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "INS_HIL_VENV": str(_venv())}
    env.pop("PYTHONPATH", None)
    return subprocess.run([str(root / "scripts" / "lint-imports")], capture_output=True, text=True, env=env,
                          timeout=120)  # fmt: skip


def _copy(tmp: Path) -> Path:
    dst = tmp / "repo"
    ignore = shutil.ignore_patterns("__pycache__", "*.so", "*.pyc")
    for d in ("ins_hil", "drivers", "scripts"):
        shutil.copytree(ROOT / d, dst / d, ignore=ignore)
    shutil.copy(ROOT / "pyproject.toml", dst / "pyproject.toml")
    return dst


def test_contract_holds_on_the_tree() -> None:
    r = _lint(ROOT)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "broken" not in r.stdout.lower().replace("0 broken", "")
    for name in ("ins_hil layers run one way", "the simulator is a client", "the production path", "no I/O"):
        assert name in r.stdout, r.stdout
    assert "KEPT" in r.stdout


def test_contract_sees_the_drivers(tmp_path: Path) -> None:
    """ins_hil.drivers lives in drivers/: a back-import there (a codec importing the runtime) is caught too."""
    repo = _copy(tmp_path)
    f = repo / "drivers" / "serial_frame.py"
    f.write_text(f.read_text() + "\nimport ins_hil.runtime.pipeline  # noqa: E402\n")
    r = _lint(repo)
    assert r.returncode == 1, r.stdout + r.stderr
    assert "ins_hil.drivers.serial_frame -> ins_hil.runtime.pipeline" in r.stdout, r.stdout


def test_back_import_breaks_the_contract(tmp_path: Path) -> None:
    repo = _copy(tmp_path)
    assert _lint(repo).returncode == 0
    earth = repo / "ins_hil" / "nav" / "earth.py"
    earth.write_text(earth.read_text() + "\nimport ins_hil.sim  # noqa: E402\n")
    r = _lint(repo)
    assert r.returncode == 1, r.stdout + r.stderr
    assert "BROKEN" in r.stdout
    assert "ins_hil.nav is not allowed to import ins_hil.sim" in r.stdout, r.stdout
    assert "ins_hil.nav.earth -> ins_hil.sim" in r.stdout, r.stdout


def test_io_in_the_core_breaks_the_contract(tmp_path: Path) -> None:
    repo = _copy(tmp_path)
    ekf = repo / "ins_hil" / "fusion" / "ekf.py"
    ekf.write_text(ekf.read_text() + "\nimport asyncio  # noqa: E402\n")
    r = _lint(repo)
    assert r.returncode == 1, r.stdout + r.stderr
    assert "ins_hil.fusion.ekf -> asyncio" in r.stdout, r.stdout


def test_no_known_exceptions() -> None:
    """Every contract holds without an ignore list (ARCHITECTURE.md "Layers": known exceptions none)."""
    import tomllib

    contracts = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"]
    assert len(contracts) == 6
    assert {c["id"]: c.get("ignore_imports", []) for c in contracts} == {c["id"]: [] for c in contracts}


def test_the_import_circles_break_the_contract(tmp_path: Path) -> None:
    """config_schema importing config, and a core part importing the core, break a contract, even when the import
    is for type checking only (NavConfig used to be imported so by every core part)."""
    repo = _copy(tmp_path)
    for rel, line in (
        ("ins_hil/config_schema.py", "import ins_hil.config"),
        ("ins_hil/core_parts/gnss.py", "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import ins_hil.core"),
    ):
        f = repo / rel
        f.write_text(f.read_text() + f"\n{line}  # noqa: E402\n")
    r = _lint(repo)
    assert r.returncode == 1, r.stdout + r.stderr
    for imp in ("ins_hil.config_schema -> ins_hil.config", "ins_hil.core_parts.gnss -> ins_hil.core"):
        assert imp in r.stdout, r.stdout


def test_the_former_exceptions_break_the_contract(tmp_path: Path) -> None:
    """The imports that used to be ignored (the gateway's fallback simulator, scenarios building NavConfig,
    the runtime reading the config back) are violations again when added back."""
    repo = _copy(tmp_path)
    for rel, line in (
        ("ins_hil/runtime/loop.py", "import ins_hil.sim.devices"),
        ("ins_hil/sim/scenarios.py", "import ins_hil.core"),
        ("ins_hil/runtime/mavlink_params.py", "import ins_hil.config"),
    ):
        f = repo / rel
        f.write_text(f.read_text() + f"\n{line}  # noqa: E402\n")
    r = _lint(repo)
    assert r.returncode == 1, r.stdout + r.stderr
    for imp in (
        "ins_hil.runtime.loop -> ins_hil.sim.devices",
        "ins_hil.sim.scenarios -> ins_hil.core",
        "ins_hil.runtime.mavlink_params -> ins_hil.config",
    ):
        assert imp in r.stdout, r.stdout


def test_the_architecture_picture_is_the_contract() -> None:
    """ARCHITECTURE.md's layer picture lists the layers of the contract, in its order (bench, calibration and
    core_parts placed)."""
    import re
    import tomllib

    contracts = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"]
    layers = next(c["layers"] for c in contracts if c["id"] == "layers")
    text = (ROOT / "ARCHITECTURE.md").read_text()
    picture = re.search(r"## Layers.*?```\n(.*?)```", text, re.S)
    assert picture is not None
    drawn = [" | ".join(x.strip() for x in p.split("|")) for p in " ".join(picture[1].split()).split(" > ")]
    assert [" | ".join(x.strip() for x in layer.split("|")) for layer in layers] == drawn
    for name in ("bench", "core_parts", "calibration.files", "calibration.bench"):
        assert any(name in layer.split(" | ") for layer in drawn), name
