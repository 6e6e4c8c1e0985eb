"""The one machine-description helper used by every generated report."""

import os
import platform

from ins_hil import machine


def test_summary_names_cpus_python_and_load() -> None:
    s = machine.summary()
    assert s.startswith(f"{os.cpu_count()} CPUs (`nproc`), {machine.cpu_model()}, Python {platform.python_version()}; ")
    assert "load average" in s and ("timings are" in s or "unknown" in s)


def test_info_fields() -> None:
    m = machine.info()
    assert m["nproc"] == str(os.cpu_count()) and m["python"] == platform.python_version()
    assert len(m["load"].split(", ")) == 3 and m["os"].startswith(platform.system())
    assert m["cc"] == "n/a" or m["cc"].strip() != ""
