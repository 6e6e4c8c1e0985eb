"""One registry style (ins_hil.registry): drivers, dataset readers, commands and attitude algorithms by name,
each module imported when its name is first used, an unknown name one line."""

from __future__ import annotations

import subprocess
import sys

import pytest

from ins_hil.registry import Registry


def _imports(code: str) -> set[str]:
    """The ins_hil modules a fresh interpreter has imported after ``code``."""
    out = subprocess.run([sys.executable, "-c", f"{code}\nimport sys\nprint(' '.join(sorted(sys.modules)))"],
                         capture_output=True, text=True, timeout=120, check=True).stdout  # fmt: skip
    return {m for m in out.split() if m.startswith("ins_hil")}


def test_an_entry_is_imported_when_first_named_and_an_unknown_name_is_one_line() -> None:
    reg: Registry[object] = Registry("thing", {"dumps": ("json", "dumps"), "pi": ("math", "pi")})
    assert list(reg) == ["dumps", "pi"] and reg.where("pi") == ("math", "pi") and not reg.loaded("pi")
    import math

    assert reg["pi"] == math.pi and reg.loaded("pi") and reg.where("pi") is None
    reg.register("e", math.e)
    assert reg.load("e") == math.e and "e" in reg and len(reg) == 3
    for bad in ("tau", ["pi"], None, 3):
        with pytest.raises(ValueError, match=r"^unknown thing .*\(known: dumps, pi, e\)$"):
            reg.load(bad)
        assert bad not in reg


def test_naming_one_entry_imports_that_module_only() -> None:
    readers = _imports("from ins_hil.datasets.dataset import READERS\nREADERS['csv']")
    assert "ins_hil.datasets.generic_csv" in readers
    assert not {"ins_hil.datasets.px4", "ins_hil.datasets.dataflash", "ins_hil.datasets.rtklib"} & readers
    drivers = _imports("from ins_hil.drivers.factory import driver_class\ndriver_class('serial_imu')")
    assert "ins_hil.drivers.serial_imu" in drivers and "ins_hil.drivers.can_imu" not in drivers
    att = _imports("from ins_hil.nav.attitude import make_attitude\nmake_attitude('poisson')")
    assert "ins_hil.nav.poisson" in att and "ins_hil.nav.onestep" not in att


def test_every_built_in_entry_loads() -> None:
    from ins_hil.drivers.factory import DRIVERS

    from ins_hil.datasets.dataset import READERS
    from ins_hil.nav.attitude import ALGORITHMS, attitude_names

    assert [READERS[n].name for n in READERS] == list(READERS)
    assert all(hasattr(DRIVERS[n], "from_config") for n in DRIVERS)
    assert set(attitude_names()) == set(ALGORITHMS) and len(ALGORITHMS) == 14
