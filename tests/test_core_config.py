"""NavConfig's sections (ins_hil.core_parts.config): the keys before the sections name their new place, a saved
NavConfig loads back, each section checks its own values."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest

from ins_hil.core import NavConfig
from ins_hil.core_parts.config import MOVED, SECTIONS, AidsConfig, AlignmentConfig, DelayConfig, GnssConfig, nest
from ins_hil.fusion.ekf import FilterConfig
from ins_hil.runtime.mavlink_params import NAV_PARAMS, _nav_get, _nav_set
from ins_hil.runtime.pipeline import nav_config
from ins_hil.runtime.replay import pipeline_config_from_header
from ins_hil.settings import table


def _flat(cfg: NavConfig) -> dict[str, Any]:
    """section.key → value (arrays as lists) of every field."""
    out: dict[str, Any] = {}
    for f in dataclasses.fields(cfg):
        v = getattr(cfg, f.name)
        items = (
            {f"{f.name}.{g.name}": getattr(v, g.name) for g in dataclasses.fields(v)}
            if f.name in SECTIONS
            else {f.name: v}
        )
        out.update({k: x.tolist() if isinstance(x, np.ndarray) else x for k, x in items.items()})
    return out


def test_every_old_key_maps_to_one_field_of_its_section() -> None:
    targets = list(MOVED.values())
    assert len(set(targets)) == len(targets)  # no two old keys on one new key
    fields = {(s, f.name) for s, c in SECTIONS.items() for f in dataclasses.fields(c)}
    newer = {
        ("aids", k)
        for k in ("drag", "drag_coef", "drag_std", "drag_tau", "drag_rate", "long_accel_std", "long_accel_rate")
    }  # after the sections
    assert set(targets) == fields - newer  # and every other section key was a flat key before


def test_a_saved_navconfig_loads_back() -> None:
    cfg = NavConfig(
        filter=FilterConfig(scale_factors=True, init_accel_sf=(0.01, 0.002, 0.002)),
        gnss=GnssConfig(lever_arm_b=np.array((0.1, -0.2, 0.3)), min_std=(0.03, 0.06, 0.15), vel_delay=0.13, gate=10.0),
        aids=AidsConfig(nhc=True, zupt=True, nhc_lever_b=np.array((-1.5, 0.0, 0.0))),
        alignment=AlignmentConfig(mode="static", time=30.0, position=(50.0, 8.0, 100.0)),
        adaptive=True,
    )
    saved = table(cfg)  # what a recording's header holds: built back by the one builder, nav_config
    assert isinstance(saved["gnss"], dict) and saved["gnss"]["gate"] == 10.0
    back = nav_config(saved)
    assert isinstance(back.gnss, GnssConfig) and isinstance(back.filter, FilterConfig)
    with pytest.raises(TypeError, match=r"^NavConfig\.filter: expected a FilterConfig, got dict$"):
        NavConfig(**dataclasses.asdict(cfg))  # an untyped table is not re-validated deeper in
    assert _flat(back) == _flat(cfg)
    assert _flat(back) != _flat(NavConfig())


def test_sections_check_their_values_and_navconfig_the_ones_across() -> None:
    with pytest.raises(ValueError, match=r"alignment\.mode='magic'"):
        AlignmentConfig(mode="magic")
    with pytest.raises(ValueError, match=r"delay\.max_delay=3"):
        DelayConfig(max_delay=3.0)
    with pytest.raises(ValueError, match=r"gnss\.vel_delay=-0\.1"):
        GnssConfig(vel_delay=-0.1)
    with pytest.raises(ValueError, match=r"expected 0\.\.delay\.max_delay \(0\.1 s\)"):
        NavConfig(gnss=GnssConfig(vel_delay=0.2), delay=DelayConfig(max_delay=0.1))
    with pytest.raises(ValueError, match=r"needs aids\.nhc=True"):
        NavConfig(filter=FilterConfig(mount_states=True))
    with pytest.raises(TypeError, match=r"NavConfig\.gnss: expected a GnssConfig, got float"):
        NavConfig(gnss=5.0)  # type: ignore[arg-type]


def test_nav_config_reads_the_sections_and_names_a_moved_key() -> None:
    cfg = nav_config({"gnss": {"lever_arm_b": [0, 0, -0.3], "min_std": [0.1, 0.2, 0.3]}, "aids": {"nhc": True}})
    assert isinstance(cfg.gnss.lever_arm_b, np.ndarray) and cfg.gnss.lever_arm_b.tolist() == [0.0, 0.0, -0.3]
    assert cfg.gnss.min_std == (0.1, 0.2, 0.3) and cfg.aids.nhc and not cfg.aids.zupt
    with pytest.raises(ValueError, match=r"^\[core\.nav\] nhc_std moved to \[core\.nav\.aids\] nhc_std$"):
        nav_config({"nhc_std": 0.2})
    # the messages of a configuration file (one builder, ins_hil.settings.build)
    with pytest.raises(ValueError, match=r"^unknown key 'core\.nav\.gnss\.gaet' \(did you mean 'gate'\?\)$"):
        nav_config({"gnss": {"gaet": 1.0}})
    with pytest.raises(ValueError, match=r"core\.nav\.baro = 0\.5: expected a table"):
        nav_config({"baro": 0.5})
    with pytest.raises(
        ValueError, match=r"^core\.nav\.aids\.drag_coef = 20: expected a finite number in \(0, 10\] 1/s$"
    ):
        nav_config({"aids": {"drag_coef": 20}})
    with pytest.raises(
        ValueError, match=r"^core\.nav\.aids\.long_accel_std = -0\.1: expected a finite number in \[0, 100\] m/s²$"
    ):
        nav_config({"aids": {"long_accel_std": -0.1}})


def test_a_recording_with_the_flat_keys_replays_in_the_sections() -> None:
    old = {"gate_gnss": 3.0, "align": "static", "delay_compensation": False, "adaptive": True,
           "filter": {"cov_every": 10}}  # fmt: skip
    cfg = pipeline_config_from_header({"pipeline": {"nav": old}})
    sections = {"gnss": {"gate": 3.0}, "alignment": {"mode": "static"}, "delay": {"compensation": False},
                "adaptive": True, "filter": {"cov_every": 10}}  # fmt: skip
    assert nest(old) == sections and nest(sections) == sections  # the sectioned layout as is
    n = cfg.nav  # built once, typed
    assert n.gnss.gate == 3.0 and n.alignment.mode == "static" and not n.delay.compensation and n.adaptive
    assert table(n) == sections and nav_config(n) is n  # its table (the header a recording writes) gives it back


def test_every_mavlink_parameter_key_is_a_navconfig_value() -> None:
    default = NavConfig()
    for p in NAV_PARAMS:
        v = _nav_get({}, p.key, default)
        assert isinstance(v, bool | int | float), p
        nav: dict[str, Any] = {}
        _nav_set(nav, p.key, v, default)
        assert _nav_get(nav, p.key, default) == v
        nav_config(nav)  # the table it writes is a valid [core.nav]
    nav = {}
    _nav_set(nav, "gnss.min_std[1]", 0.5, default)
    assert nav == {"gnss": {"min_std": [0.01, 0.5, 0.02]}} and nav_config(nav).gnss.min_std == (0.01, 0.5, 0.02)
