"""The Jacobians generated from one SymPy derivation (firmware_ref/tools/derive_jacobians.py).

* change indication (as PX4's EKF2 derivation): regenerating gives the checked-in C header and Python module
  byte for byte, so an edit of the derivation without regenerating (or of a generated file by hand) fails;
* the generated Python F and H equal the hand-written ones of ``ins_hil.fusion`` (15-state layout) on random
  states, to rounding; the C core uses the generated header (its parity with NavCore: tests/test_cref_parity.py).
"""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from ins_hil.fusion import generated_jacobians as gj
from ins_hil.fusion import measurements as mm
from ins_hil.fusion.ekf import ErrorStateEKF, FilterConfig
from ins_hil.nav.rotation import dcm_from_quat, quat_normalize

REPO = Path(__file__).resolve().parent.parent
TOOL = REPO / "firmware_ref" / "tools" / "derive_jacobians.py"


def _tool():  # type: ignore[no-untyped-def]
    spec = importlib.util.spec_from_file_location("derive_jacobians", TOOL)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules["derive_jacobians"] = mod
    spec.loader.exec_module(mod)
    return mod


def test_regenerating_gives_the_checked_in_files() -> None:
    tool = _tool()
    c_src, py_src = tool.generate()
    assert tool.C_OUT.read_text() == c_src, "firmware_ref/src/generated/ins_jacobians.h is stale: regenerate"
    assert tool.PY_OUT.read_text() == py_src, "ins_hil/fusion/generated_jacobians.py is stale: regenerate"
    assert tool.main(["--check"]) == 0


def test_the_check_fails_on_an_edited_file(tmp_path: Path) -> None:
    tool = _tool()
    c_src, _ = tool.generate()
    edited = tmp_path / "ins_jacobians.h"
    edited.write_text(c_src.replace("b->vr_dd = g2r;", "b->vr_dd = -g2r;"))
    tool.C_OUT, was = edited, tool.C_OUT
    try:
        assert tool.main(["--check"]) == 1
    finally:
        tool.C_OUT = was


def _random_state(rng: np.random.Generator) -> dict[str, np.ndarray]:
    q = quat_normalize(rng.normal(size=4))
    m = rng.normal(size=3)
    m /= np.linalg.norm(m)
    if m[0] < -0.9:
        m[0] = -m[0]
    return {
        "C": dcm_from_quat(q),
        "f": rng.normal(0.0, 5.0, 3) + np.array((0.0, 0.0, -9.8)),
        "wie": np.array((7.29e-5 * math.cos(0.8), 0.0, -7.29e-5 * math.sin(0.8))),
        "wen": rng.normal(0.0, 3e-6, 3),
        "w": rng.normal(0.0, 0.5, 3),
        "l": rng.normal(0.0, 1.0, 3),
        "v": rng.normal(0.0, 10.0, 3),
        "m": m,
    }


@pytest.mark.parametrize("seed", range(20))
def test_generated_python_equals_the_hand_written_jacobians(seed: int) -> None:
    rng = np.random.default_rng(seed)
    s = _random_state(rng)
    C = s["C"]
    kf = ErrorStateEKF(FilterConfig())
    assert kf.n == gj.NX
    idx = kf.idx
    F_hand = kf.build_F(C, s["f"], s["wie"], s["wen"], C.T @ s["f"], s["w"], 0.8, 100.0).copy()
    itg, ita = 1.0 / kf.cfg.gyro_bias_tau, 1.0 / kf.cfg.accel_bias_tau
    F_gen = gj.F(C, s["f"], s["wie"], s["wen"], itg, ita, kf._g2r)
    np.testing.assert_allclose(F_gen, F_hand, rtol=1e-12, atol=1e-15)

    lat, lon, h = 0.8, 0.5, 100.0
    _, H = mm.gnss_position(idx, C, lat, lon, h, lat, lon, h, s["l"])
    np.testing.assert_allclose(gj.H_gnss_pos(C, s["l"]), H, rtol=1e-12, atol=1e-14)
    _, H = mm.gnss_velocity(idx, C, s["v"], s["w"], s["v"], s["l"])
    np.testing.assert_allclose(gj.H_gnss_vel(C, s["w"], s["l"]), H, rtol=1e-12, atol=1e-14)
    _, H = mm.baro_height(idx, h, h)
    np.testing.assert_array_equal(gj.H_baro(), H)
    _, H = mm.zero_velocity(idx, s["v"])
    np.testing.assert_array_equal(gj.H_zupt(), H)
    _, H = mm.nonholonomic(idx, C, s["v"])
    np.testing.assert_allclose(gj.H_nhc(C, s["v"]), H, rtol=1e-12, atol=1e-13)
    _, H = mm.magnetometer(idx, C, C.T @ s["m"], s["m"])
    np.testing.assert_allclose(gj.H_mag(s["m"]), H, rtol=1e-12, atol=1e-14)
    # the ZARU rows of core_parts/aids.py: −δb_g
    H = np.zeros((3, idx.n))
    H[:, idx.bg : idx.bg + 3] = -np.eye(3)
    np.testing.assert_array_equal(gj.H_zaru(), H)
